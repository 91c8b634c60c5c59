//! What media deliver to an attached endpoint: a time-stamped frame or packet, tagged
//! with the endpoint's interface index.
//!
//! An inbox holds at most [`INBOX_DEPTH`] arrivals not yet taken, like a controller's
//! receive FIFO or a socket's receive buffer: a medium delivering to a full inbox loses the
//! arrival, and counts it as the endpoint's `rx_overflow`.

use csp::cfp::CanFrame;
use csp::{Packet, SimTime};
use tokio::sync::mpsc;

/// A frame or packet arriving at an endpoint.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arrival {
    /// A CAN frame (CFP fragment).
    Can(CanFrame),
    /// A whole CSP packet.
    Packet(Packet),
}

/// An arrival with its exact simulated time and the receiving interface.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Inbound {
    /// When the last bit arrived.
    pub t: SimTime,
    /// Interface index of the receiving endpoint.
    pub iface: usize,
    /// What arrived.
    pub what: Arrival,
}

/// Arrivals an inbox holds before it loses more: 1024 frames are about 130 ms of a
/// saturated 1 Mbit/s bus, several times what a node's task takes to catch up.
pub const INBOX_DEPTH: usize = 1024;

/// The sending half of an endpoint's inbox.
#[derive(Debug, Clone)]
pub struct InboxTx(mpsc::Sender<Inbound>);

/// The receiving half of an endpoint's inbox.
pub type InboxRx = mpsc::Receiver<Inbound>;

/// Why an arrival did not get into an inbox.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum InboxError {
    /// The inbox holds [`INBOX_DEPTH`] arrivals: the arrival is lost.
    #[error("inbox full")]
    Full,
    /// Nobody reads the inbox any more.
    #[error("inbox closed")]
    Closed,
}

impl InboxTx {
    /// Put an arrival in the inbox, never waiting: lost when the inbox is full.
    pub fn send(&self, a: Inbound) -> Result<(), InboxError> {
        self.0.try_send(a).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => InboxError::Full,
            mpsc::error::TrySendError::Closed(_) => InboxError::Closed,
        })
    }
}

/// A new inbox of [`INBOX_DEPTH`] arrivals.
pub fn inbox() -> (InboxTx, InboxRx) {
    inbox_with(INBOX_DEPTH)
}

/// A new inbox of `depth` arrivals.
pub fn inbox_with(depth: usize) -> (InboxTx, InboxRx) {
    let (tx, rx) = mpsc::channel(depth.max(1));
    (InboxTx(tx), rx)
}
