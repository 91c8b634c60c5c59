//! What media deliver to an attached endpoint: a time-stamped frame or packet, tagged
//! with the endpoint's interface index.

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

/// The sending half of an endpoint's inbox.
pub type InboxTx = mpsc::UnboundedSender<Inbound>;
/// The receiving half of an endpoint's inbox.
pub type InboxRx = mpsc::UnboundedReceiver<Inbound>;

/// A new inbox.
pub fn inbox() -> (InboxTx, InboxRx) {
    mpsc::unbounded_channel()
}
