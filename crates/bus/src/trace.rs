//! The trace of everything that crossed a medium: the raw material of recordings and of
//! the determinism check (two runs of one configuration give the same trace).

use std::sync::Arc;

use csp::SimTime;
use csp::cfp::CanFrame;
use tokio::sync::mpsc;

/// Why a frame was lost by its sender ([`TraceFrame::CanLost`]: it never went on the wire)
/// or by every endpoint it was addressed to ([`TraceFrame::CanUnreceived`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FrameLoss {
    /// The sender's transmit queue was full ([`crate::can::PortStats::tx_overflow`]).
    QueueFull = 0,
    /// The controller was, or went, bus-off ([`crate::can::PortStats::bus_off_drops`] for a sender).
    BusOff = 1,
    /// The endpoint was off the bus: unpowered, or an outside link gone
    /// ([`crate::can::PortStats::off_drops`] for a sender).
    Off = 2,
}

impl FrameLoss {
    /// Why a sender lost it, in words (`sender's transmit queue full`, `sender bus-off`,
    /// `sender off the bus`).
    pub fn sender(self) -> &'static str {
        match self {
            FrameLoss::QueueFull => "sender's transmit queue full",
            FrameLoss::BusOff => "sender bus-off",
            FrameLoss::Off => "sender off the bus",
        }
    }
    /// Why its receiver did not take it, in words (`receiver bus-off`, `receiver off the
    /// bus`).
    pub fn receiver(self) -> &'static str {
        match self {
            FrameLoss::QueueFull => "receiver's inbox full",
            FrameLoss::BusOff => "receiver bus-off",
            FrameLoss::Off => "receiver off the bus",
        }
    }
}

/// A CAN controller's fault confinement state (ISO 11898-1).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord)]
pub enum ErrorState {
    /// TEC and REC at most 127: it signals errors with active (dominant) error flags.
    #[default]
    Active,
    /// TEC or REC above 127.
    Passive,
    /// TEC above 255: off the bus until it has seen 128 x 11 recessive bits.
    BusOff,
}

impl ErrorState {
    /// A short name (`error-active`, `error-passive`, `bus-off`).
    pub fn name(self) -> &'static str {
        match self {
            ErrorState::Active => "error-active",
            ErrorState::Passive => "error-passive",
            ErrorState::BusOff => "bus-off",
        }
    }
}

/// What happened to a controller, for the trace (`/can/<bus>/errors`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CanErrorKind {
    /// An error frame destroyed its transmission of frame `can_id` (it is retransmitted
    /// unless the controller went bus-off).
    ErrorFrame {
        /// The destroyed frame's id.
        can_id: u32,
    },
    /// Its state changed (to error-passive, bus-off, or back to error-active).
    State(ErrorState),
}

/// An error frame or a change of a controller's state, with its counters after it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CanErrorEvent {
    /// The controller (the endpoint's name).
    pub node: Arc<str>,
    /// What happened.
    pub kind: CanErrorKind,
    /// Its transmit error counter after it.
    pub tec: u16,
    /// Its receive error counter after it.
    pub rec: u16,
}

/// What crossed the medium.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TraceFrame {
    /// A CAN frame, as it went on the wire (after any corruption).
    Can(CanFrame),
    /// A CSP packet's wire bytes (`header | data`).
    Packet(Vec<u8>),
    /// An error frame or a change of a CAN controller's error state.
    CanError(CanErrorEvent),
    /// A CAN frame its sender queued that never went on the wire, and why (not recorded as
    /// a frame on the bus; the accounting of what was lost in transit uses it).
    CanLost(CanFrame, FrameLoss),
    /// A CAN frame that crossed the bus (as [`TraceFrame::Can`]) but that none of the
    /// endpoints it was addressed to could take, and why (they were bus-off or off).
    CanUnreceived(CanFrame, FrameLoss),
}

impl TraceFrame {
    /// The CAN frame that went on the wire, if this is one (taken or not).
    pub fn can_on_wire(&self) -> Option<&CanFrame> {
        match self {
            TraceFrame::Can(f) | TraceFrame::CanUnreceived(f, _) => Some(f),
            _ => None,
        }
    }
}

/// One frame or packet on a medium.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TraceEvent {
    /// When it finished crossing the medium.
    pub t: SimTime,
    /// The medium (bus or network name).
    pub medium: Arc<str>,
    /// The sending endpoint.
    pub from: Arc<str>,
    /// The frame.
    pub frame: TraceFrame,
    /// Whether an impairment dropped it.
    pub dropped: bool,
}

impl TraceEvent {
    /// The frame's bytes for comparisons: CAN id (4 bytes big-endian) and data, or the packet.
    pub fn bytes(&self) -> Vec<u8> {
        match &self.frame {
            TraceFrame::Can(f) | TraceFrame::CanUnreceived(f, _) => {
                let mut v = f.id.to_be_bytes().to_vec();
                v.extend_from_slice(f.data());
                v
            }
            TraceFrame::Packet(p) => p.clone(),
            TraceFrame::CanLost(f, why) => {
                let mut v = vec![0xFF, *why as u8];
                v.extend_from_slice(&f.id.to_be_bytes());
                v.extend_from_slice(f.data());
                v
            }
            TraceFrame::CanError(e) => {
                let (what, id) = match &e.kind {
                    CanErrorKind::ErrorFrame { can_id } => (0u8, *can_id),
                    CanErrorKind::State(s) => (1 + *s as u8, 0),
                };
                let mut v = vec![what];
                v.extend_from_slice(&id.to_be_bytes());
                v.extend_from_slice(&e.tec.to_be_bytes());
                v.extend_from_slice(&e.rec.to_be_bytes());
                v
            }
        }
    }
}

/// Where media send their trace: called for every frame or packet, in order, while the
/// medium holds its own lock (keep it short: push into a channel).
#[derive(Clone)]
pub struct TraceTx(Arc<dyn Fn(TraceEvent) + Send + Sync>);

impl TraceTx {
    /// A sink calling `f` for every event.
    pub fn new(f: impl Fn(TraceEvent) + Send + Sync + 'static) -> Self {
        TraceTx(Arc::new(f))
    }
    /// A sink that sends into a channel.
    pub fn channel(tx: mpsc::UnboundedSender<TraceEvent>) -> Self {
        TraceTx::new(move |ev| {
            let _ = tx.send(ev);
        })
    }
    /// Hand one event to the sink.
    pub fn emit(&self, ev: TraceEvent) {
        (self.0)(ev)
    }
}

impl std::fmt::Debug for TraceTx {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TraceTx")
    }
}

// The state a snapshot saves (docs/snapshots.md): error events on their way.
snap::unit_enum!(ErrorState {
    Active,
    Passive,
    BusOff
});
snap::tagged_enum!(CanErrorKind {
    ErrorFrame { can_id },
    State(s)
});
snap::fields!(CanErrorEvent {
    node,
    kind,
    tec,
    rec
});
snap::unit_enum!(FrameLoss {
    QueueFull,
    BusOff,
    Off
});
snap::tagged_enum!(TraceFrame {
    Can(f),
    Packet(bytes),
    CanError(e),
    CanLost(f, why),
    CanUnreceived(f, why)
});
snap::fields!(TraceEvent {
    t,
    medium,
    from,
    frame,
    dropped
});
