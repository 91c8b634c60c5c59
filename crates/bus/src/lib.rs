//! The media of the twin and the thin async shells around pure cores.
//!
//! - [`clock`]: virtual or real time.
//! - [`can`]: an in-process CAN segment (bit timing, arbitration, acceptance, impairments).
//! - [`net`]: a packet network (the ground segment and the UHF air channel).
//! - [`driver`]: the task that runs one node.
//! - [`exec`]: the run's executor, which orders the tasks due at one instant.
//! - [`outside`]: what a link to a program outside the twin attaches to (segments,
//!   endpoints, counters); the links themselves (KISS over TCP and ptys, the ZMQ hub,
//!   SocketCAN, node consoles) are the `m6p-links` crate's.
//! - [`gate`]: what the twin lets across an outside link (its faults and power).

pub mod can;
pub mod clock;
pub mod driver;
pub mod exec;
pub mod gate;
pub mod impair;
pub mod inbox;
pub mod net;
pub mod outside;
pub mod pace;
mod reserve;
pub mod trace;

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
