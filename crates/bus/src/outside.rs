//! Attaching a program outside the twin (over KISS/TCP or SocketCAN) to the right segment.
//!
//! Which segment an outside CSP address sits on is decided by its range (INTERPRETATION.md
//! section 1): 12-15 the payload CAN bus, 16-20 the ground segment, anything else the main
//! CAN bus. On a CAN bus the outside endpoint fragments and reassembles with CFP like any
//! libcsp CAN interface; on the ground segment it exchanges whole packets. An outside
//! address is claimed exclusively, and only if nobody holds it: a node of the twin (unless
//! the scenario replaced it, so it was never attached) or another outside connection keeps
//! its address, and the claim is refused ([`OutsideError::Held`]).

use csp::cfp::{CfpDrop, Fragmenter, Reassembler, ReassemblerConfig};
use csp::{Packet, SimTime};

use crate::can::{CanBus, CanPort, TxBudget};
use crate::inbox::{Arrival, Inbound, InboxTx};
use crate::net::{NetPort, PacketNet};

/// The media an outside program can join.
#[derive(Debug, Clone)]
pub struct Segments {
    /// The main CAN bus (COMM, FC, EPS, ECU, PC).
    pub main: CanBus,
    /// The payload CAN bus (PC, payloads 12-15).
    pub payload: CanBus,
    /// The ground segment (16-20, behind COMM's UHF radio).
    pub ground: PacketNet,
}

pub use crate::reserve::{ClaimError, LinkId};

impl Segments {
    /// Reserve `addr` on its segment for outside link `link` (labelled `label`) for the
    /// whole run (an address the link is configured with): only that link's connections
    /// may claim it, its program connected or not. Refused with the holder's name.
    pub fn reserve(&self, addr: u8, link: LinkId, label: &str) -> Result<(), ClaimError> {
        match SegmentKind::of(addr) {
            SegmentKind::Main => self.main.reserve(addr, link, label),
            SegmentKind::Payload => self.payload.reserve(addr, link, label),
            SegmentKind::Ground => self.ground.reserve(addr, link, label),
        }
    }

    /// The node of the twin attached with `addr` on its segment, if one is.
    pub fn node_holding(&self, addr: u8) -> Option<String> {
        match SegmentKind::of(addr) {
            SegmentKind::Main => self.main.node_holding(addr),
            SegmentKind::Payload => self.payload.node_holding(addr),
            SegmentKind::Ground => self.ground.node_holding(addr),
        }
    }
}

/// Counters of a bridge between a CAN segment and a real CAN interface
/// (`m6p_links::socketcan::bridge`, cargo feature `socketcan`). Defined here, outside the
/// feature, so that run reports can carry them whatever the build.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BridgeStats {
    /// Extended data frames read from the interface (put on the segment unless the link's
    /// gate holds them back: `crate::gate`).
    pub frames_in: u64,
    /// Frames of the segment written to the interface.
    pub frames_out: u64,
    /// Frames read from the interface that CFP does not use (standard id, remote, error).
    pub skipped: u64,
    /// Failed reads from the interface.
    pub recv_errors: u64,
    /// Failed writes to the interface (the frame is lost).
    pub send_errors: u64,
    /// Why the bridge stopped before the end of the run (the interface went away).
    pub ended: Option<String>,
}

/// Which medium an address belongs to (the address table of `platform::addr`).
pub use platform::addr::Segment as SegmentKind;

#[derive(Debug)]
enum Port {
    Can {
        port: CanPort,
        frag: Fragmenter,
        reasm: Reassembler,
    },
    Net(NetPort),
}

/// An outside program's place in the twin.
#[derive(Debug)]
pub struct OutsideEndpoint {
    kind: SegmentKind,
    port: Port,
    addrs: Vec<u8>,
}

/// Why an outside packet was not taken into the twin.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum OutsideError {
    /// The packet's source is on another segment than the link's first address.
    #[error("source {src} is not on the {kind:?} segment of this link")]
    WrongSegment {
        /// The source address.
        src: u8,
        /// The link's segment.
        kind: SegmentKind,
    },
    /// Broadcast or out of range source.
    #[error("source address {0} cannot be claimed")]
    BadSource(u8),
    /// The link has configured addresses and this is not one of them.
    #[error("source address {0} is not one of the link's addresses")]
    NotConfigured(u8),
    /// The packet does not fit the CAN MTU.
    #[error("packet does not fit the CAN MTU: {0}")]
    TooLong(csp::Error),
    /// Another endpoint holds the address: a node of the twin or another outside
    /// connection.
    #[error("address {addr} is held by {holder}")]
    Held {
        /// The address.
        addr: u8,
        /// Who holds it.
        holder: ClaimError,
    },
    /// The link's CAN transmit queue cannot take the whole packet now: it is dropped rather
    /// than sent in part.
    #[error("transmit queue full ({room} frames free, {need} needed)")]
    QueueFull {
        /// Frames the queue could still take.
        room: usize,
        /// Frames of the packet.
        need: usize,
    },
}

/// The interface index of an endpoint on `kind`.
fn iface_of(kind: SegmentKind) -> usize {
    match kind {
        SegmentKind::Main => 0,
        SegmentKind::Payload => 1,
        SegmentKind::Ground => 2,
    }
}

impl OutsideEndpoint {
    /// Attach connection `name` of outside link `link` for `addr` on its segment,
    /// delivering to `inbox`; on a CAN bus with the transmit budget `budget`.
    pub fn attach(
        segs: &Segments,
        name: &str,
        link: LinkId,
        addr: u8,
        inbox: InboxTx,
        seed_ident: u16,
        budget: Option<TxBudget>,
    ) -> Result<Self, OutsideError> {
        if addr >= csp::header::BROADCAST {
            return Err(OutsideError::BadSource(addr));
        }
        let kind = SegmentKind::of(addr);
        let port = match kind {
            SegmentKind::Main | SegmentKind::Payload => {
                let bus = if kind == SegmentKind::Main {
                    &segs.main
                } else {
                    &segs.payload
                };
                let port = bus
                    .attach_claimed(name, link, addr, inbox, iface_of(kind))
                    .map_err(|holder| OutsideError::Held { addr, holder })?;
                bus.set_tx_budget(&port, budget);
                Port::Can {
                    port,
                    frag: Fragmenter::new(seed_ident % 1024, csp::cfp::CSP_CAN_MTU),
                    reasm: Reassembler::new(ReassemblerConfig::default()),
                }
            }
            SegmentKind::Ground => {
                let port = segs
                    .ground
                    .attach_claimed(name, link, addr, inbox, iface_of(kind))
                    .map_err(|holder| OutsideError::Held { addr, holder })?;
                Port::Net(port)
            }
        };
        Ok(OutsideEndpoint {
            kind,
            port,
            addrs: vec![addr],
        })
    }

    /// The segment the link sits on.
    pub fn kind(&self) -> SegmentKind {
        self.kind
    }
    /// The interface index its arrivals carry (`Inbound::iface`): one per segment, so that
    /// endpoints of one program on several segments can share an inbox.
    pub fn iface(&self) -> usize {
        iface_of(self.kind)
    }
    /// Addresses claimed by the link.
    pub fn addrs(&self) -> &[u8] {
        &self.addrs
    }

    /// Claim another address on the same segment.
    pub fn claim(&mut self, addr: u8) -> Result<(), OutsideError> {
        if self.addrs.contains(&addr) {
            return Ok(());
        }
        if addr >= csp::header::BROADCAST {
            return Err(OutsideError::BadSource(addr));
        }
        if SegmentKind::of(addr) != self.kind {
            return Err(OutsideError::WrongSegment {
                src: addr,
                kind: self.kind,
            });
        }
        match &self.port {
            Port::Can { port, .. } => port.bus().claim(port, addr),
            Port::Net(p) => p.net().claim(p, addr),
        }
        .map_err(|holder| OutsideError::Held { addr, holder })?;
        self.addrs.push(addr);
        Ok(())
    }

    /// Send a packet from the outside program into the twin at `t`.
    pub fn send(&mut self, t: SimTime, packet: &Packet) -> Result<(), OutsideError> {
        match &mut self.port {
            Port::Can { port, frag, .. } => {
                let mut frames = Vec::new();
                // The outside node is a CAN node of its own: CFP dst is the CSP destination
                // unless it needs the PC as next hop (payload bus to anything off it).
                let dst = packet.header.dst;
                let via = self.kind.next_hop(dst).unwrap_or(dst);
                frag.fragment(packet, via, &mut frames)
                    .map_err(OutsideError::TooLong)?;
                let room = port.room();
                if room < frames.len() {
                    return Err(OutsideError::QueueFull {
                        room,
                        need: frames.len(),
                    });
                }
                for f in frames {
                    port.send(t, f);
                }
            }
            Port::Net(p) => p.send(t, packet.clone()),
        }
        Ok(())
    }

    /// Turn an arrival into a packet for the outside program (CAN frames are reassembled;
    /// an error is the reassembler's drop).
    pub fn receive(&mut self, arrival: Inbound) -> Option<Result<Packet, CfpDrop>> {
        match (arrival.what, &mut self.port) {
            (Arrival::Packet(p), _) => Some(Ok(p)),
            (Arrival::Can(f), Port::Can { reasm, .. }) => reasm.handle(&f, arrival.t),
            (Arrival::Can(_), Port::Net(_)) => None,
        }
    }

    /// Leave the segment, giving back every claim.
    pub fn release(&self) {
        match &self.port {
            Port::Can { port, .. } => port.bus().release(port),
            Port::Net(p) => p.net().release(p),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::can::CanBusConfig;
    use crate::inbox::inbox;
    use crate::net::PacketNetConfig;

    fn segments() -> Segments {
        Segments {
            main: CanBus::new(CanBusConfig::new("main"), 1),
            payload: CanBus::new(CanBusConfig::new("payload"), 1),
            ground: PacketNet::new(PacketNetConfig::ground(), 1),
        }
    }

    /// A refused claim leaves nothing behind on any segment: ten thousand outside attempts
    /// at addresses nodes of the twin hold add no endpoint. A disabled one left per attempt
    /// would stay for the rest of the run: a flood of impostor packets, one attempt each,
    /// would grow the twin by gigabytes in seconds and slow every arbitration.
    #[test]
    fn a_refused_claim_leaves_no_endpoint_behind() {
        let segs = segments();
        let (tx, _rx) = inbox();
        let _fc = segs.main.attach("FC", &[3], false, tx.clone(), 0);
        let _pl = segs.payload.attach("PL12", &[12], false, tx.clone(), 0);
        let _gs = segs
            .ground
            .attach("GS16", &[16], false, false, tx.clone(), 0);
        for n in 0..10_000u16 {
            for (addr, holder) in [(3, "FC"), (12, "PL12"), (16, "GS16")] {
                let e = OutsideEndpoint::attach(
                    &segs,
                    "impostor",
                    LinkId(0),
                    addr,
                    tx.clone(),
                    n,
                    None,
                );
                assert_eq!(
                    e.err(),
                    Some(OutsideError::Held {
                        addr,
                        holder: ClaimError::Node(holder.to_owned())
                    })
                );
            }
        }
        assert_eq!(segs.main.stats().ports.len(), 1);
        assert_eq!(segs.payload.stats().ports.len(), 1);
        assert_eq!(segs.ground.stats().endpoints.len(), 1);
        // A free address is still taken, and given back.
        let ep = OutsideEndpoint::attach(&segs, "honest", LinkId(0), 7, tx, 1, None).unwrap();
        assert_eq!(segs.main.stats().ports.len(), 2);
        ep.release();
    }

    /// A link's connections coming and going leave nothing behind: a thousand connects and
    /// disconnects on each segment end with one place of the link on each (a departed
    /// connection's place is the next one's), not a disabled endpoint per connection.
    #[test]
    fn connections_coming_and_going_leave_one_place_each() {
        let segs = segments();
        let (tx, _rx) = inbox();
        for n in 0..1000u16 {
            for addr in [7, 13, 17] {
                let ep = OutsideEndpoint::attach(&segs, "c", LinkId(0), addr, tx.clone(), n, None)
                    .unwrap();
                ep.release();
            }
        }
        assert_eq!(segs.main.stats().ports.len(), 1);
        assert_eq!(segs.payload.stats().ports.len(), 1);
        assert_eq!(segs.ground.stats().endpoints.len(), 1);
        // Another link's connection has a place of its own; two of the first link's at once
        // have two.
        let a = OutsideEndpoint::attach(&segs, "c#1", LinkId(0), 7, tx.clone(), 1, None).unwrap();
        let b = OutsideEndpoint::attach(&segs, "c#2", LinkId(0), 8, tx.clone(), 2, None).unwrap();
        let d = OutsideEndpoint::attach(&segs, "d#1", LinkId(1), 9, tx, 3, None).unwrap();
        assert_eq!(segs.main.stats().ports.len(), 3);
        for ep in [a, b, d] {
            ep.release();
        }
    }
}
