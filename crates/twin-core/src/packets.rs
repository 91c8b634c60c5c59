//! Whole CSP packets from the run's trace of its media: a packet on the ground network as
//! it is, a CAN bus's CFP frames reassembled per bus. The run reassembles once, when asked
//! (`RunOptions::packet_events`), and hands each packet out as a [`RunEvent::Packet`] right
//! after the medium event that completed it: the recorder's `/csp/packets`, the live view
//! and the `field` expectations read that event. (What was lost in transit is another
//! question, of frames' fates rather than packets' contents: `crate::transit`.)
//!
//! Pure and bounded: one reassembler per bus, each with a fixed number of slots (it sees
//! every conversation on its bus, so more than a node's) and libcsp's timeouts; frames it
//! cannot place are counted in [`PacketTap::cfp_drops`].

use std::sync::Arc;

use bus::trace::{TraceEvent, TraceFrame};
use csp::cfp::{CFP_MAX_DATA, Reassembler, ReassemblerConfig};
use csp::packet::Packet;

use crate::events::{RunEvent, SeenPacket};

/// Partial packets each bus's reassembler holds at most.
pub const SLOTS_PER_BUS: usize = 64;

/// The run's packets, as its media deliver them.
#[derive(Debug, Default)]
pub struct PacketTap {
    reassemblers: Vec<(Arc<str>, Reassembler)>,
    cfp_drops: u64,
}

// A snapshot saves the partial packets of every bus (docs/snapshots.md).
snap::fields!(PacketTap {
    reassemblers,
    cfp_drops
});

impl PacketTap {
    /// A tap with no bus seen yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The packet event `m` completes, if any: a ground packet that was not dropped, or a
    /// CAN frame that crossed its bus and ends a CFP packet. Dropped frames, lost ones and
    /// error frames complete nothing.
    pub fn take(&mut self, m: &TraceEvent) -> Option<Packet> {
        if m.dropped {
            return None;
        }
        match &m.frame {
            TraceFrame::Can(f) | TraceFrame::CanUnreceived(f, _) => {
                let r = self.reassembler(&m.medium);
                r.handle_timeout(m.t);
                match r.handle(f, m.t) {
                    Some(Ok(p)) => Some(p),
                    Some(Err(_)) => {
                        self.cfp_drops += 1;
                        None
                    }
                    None => None,
                }
            }
            TraceFrame::Packet(bytes) => Packet::parse(bytes).ok(),
            TraceFrame::CanLost(..) | TraceFrame::CanError(_) => None,
        }
    }

    /// The [`RunEvent::Packet`] the event `ev` completes, if any (see [`PacketTap::take`]).
    pub fn event(&mut self, ev: &RunEvent) -> Option<RunEvent> {
        let RunEvent::Medium(m) = ev else { return None };
        let packet = self.take(m)?;
        Some(RunEvent::Packet(Arc::new(SeenPacket {
            t: m.t,
            medium: m.medium.clone(),
            from: m.from.clone(),
            packet,
        })))
    }

    /// CFP frames or partial packets the reassemblers dropped (lost frames).
    pub fn cfp_drops(&self) -> u64 {
        self.cfp_drops
    }

    /// The reassembler of CAN bus `bus`, created on first use. It keys partial packets by
    /// src, dst and ident like libcsp and accepts whatever length CFP can carry.
    fn reassembler(&mut self, bus: &Arc<str>) -> &mut Reassembler {
        let i = match self
            .reassemblers
            .iter()
            .position(|(b, _)| Arc::ptr_eq(b, bus) || b == bus)
        {
            Some(i) => i,
            None => {
                let cfg = ReassemblerConfig {
                    slots: SLOTS_PER_BUS,
                    mtu: CFP_MAX_DATA,
                    ..ReassemblerConfig::default()
                };
                self.reassemblers.push((bus.clone(), Reassembler::new(cfg)));
                self.reassemblers.len() - 1
            }
        };
        &mut self.reassemblers[i].1
    }
}

/// `events` with the [`RunEvent::Packet`] each completes after it, as a run asked for
/// packets hands them out (for programs and tests that feed a recorder events of their own).
pub fn with_packets(events: impl IntoIterator<Item = RunEvent>) -> Vec<RunEvent> {
    let mut tap = PacketTap::new();
    let mut out = Vec::new();
    for ev in events {
        let p = tap.event(&ev);
        out.push(ev);
        out.extend(p);
    }
    out
}
