//! The media of the twin and the thin async shells around pure cores.
//!
//! - [`clock`]: virtual or real time.
//! - [`can`]: an in-process CAN segment (bit timing, arbitration, acceptance, impairments).
//! - [`net`]: a packet network (the ground segment and the UHF air channel).
//! - [`driver`]: the task that runs one node.
//! - [`outside`], [`kiss_tcp`], [`kiss_pty`]: programs outside the twin over KISS (TCP or a
//!   pseudo-terminal).
//! - [`zmq_hub`]: libcsp 1.4's ZMQ hub, played by the twin.
//! - [`gate`]: what the twin lets across an outside link (its faults and power).
//! - `socketcan` (cargo feature `socketcan`, Linux): a bridge to a real CAN interface.

pub mod can;
pub mod clock;
pub mod console;
pub mod driver;
pub mod gate;
pub mod impair;
pub mod inbox;
#[cfg(unix)]
pub mod kiss_pty;
pub mod kiss_tcp;
pub mod net;
pub mod outside;
pub mod pace;
mod reserve;
#[cfg(all(feature = "socketcan", target_os = "linux"))]
pub mod socketcan;
pub mod trace;
pub mod zmq_hub;

pub use can::{CanBus, CanBusConfig, CanPort};
pub use clock::{Clock, ClockMode};
pub use net::{NetPort, PacketNet, PacketNetConfig};

/// Count a loss in `counter` and log it at WARN the 1st, 2nd, 4th, 8th, ... time, so that
/// a flood logs a few lines, not one per loss; `what` describes it given the count so far.
pub(crate) fn count_loss(counter: &mut u64, what: impl FnOnce(u64) -> String) {
    *counter += 1;
    if counter.is_power_of_two() {
        tracing::warn!("{}", what(*counter));
    }
}
