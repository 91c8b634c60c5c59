//! What was lost in transit on the CAN buses, packet by packet, from the buses' trace:
//! every frame a controller queued ends in the trace exactly once, as a frame that crossed
//! the bus, one an impairment dropped on it, one that crossed but that its receiver could
//! not take ([`TraceFrame::CanUnreceived`]: bus-off, off the bus), or one that never went
//! on the wire ([`TraceFrame::CanLost`]: transmit queue full, bus-off, off the bus). Grouping the frames
//! of each CFP packet (sender, next hop, ident) gives the packets that lost a frame, with
//! the first loss's reason: the truth the session accounting needs when a payload's reply
//! never reaches the PC, which a receiver cannot know.
//!
//! Pure and bounded: at most [`MAX_PARTIAL`] packets in progress (the oldest goes first,
//! counted); a packet whose frames are still queued at the end of the run is in transit,
//! not lost.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use bus::trace::{TraceEvent, TraceFrame};
use csp::SimTime;
use csp::cfp::{BEGIN_OVERHEAD, CFP_ID_CONN_MASK, CfpId, FrameType};
use csp::header::Header;

/// Packets in progress kept at most.
pub const MAX_PARTIAL: usize = 1024;

/// A CSP packet of which at least one frame did not cross the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LostPacket {
    /// When its last frame's fate was known.
    pub t: SimTime,
    /// The bus.
    pub bus: Arc<str>,
    /// Its CSP header (from its BEGIN frame).
    pub header: Header,
    /// Its CSP data length.
    pub data_len: usize,
    /// Its first data bytes (those of the BEGIN frame: up to 2, zeros after).
    pub head: [u8; 2],
    /// Why its first lost frame was lost (`dropped on the bus`, `sender's transmit queue
    /// full`, `sender bus-off`, `receiver off the bus`, ...).
    pub reason: &'static str,
}

#[derive(Debug, Clone, Default)]
struct Partial {
    first: SimTime,
    /// Header, data length, first data bytes and frame count, once the BEGIN is seen.
    begin: Option<(Header, usize, [u8; 2], usize)>,
    /// Each frame's fate by its `remain`.
    fates: Fates,
    /// Why its receiver dropped it, if it did.
    receiver: Option<&'static str>,
}

/// The fates of a packet's frames, by `remain` (0..=255): which were seen, and the first
/// loss in sending order (the highest `remain` of a frame that did not cross). A packet's
/// frames cost no allocation; a frame is seen once (a second sighting starts the packet
/// over, in [`Transit::observe`]).
#[derive(Debug, Clone, Copy, Default)]
struct Fates {
    seen: [u64; 4],
    count: usize,
    first_lost: Option<(u8, &'static str)>,
}

impl Fates {
    fn contains(&self, remain: u8) -> bool {
        self.seen[usize::from(remain >> 6)] >> (remain & 63) & 1 == 1
    }

    /// Frame `remain` crossed (`fate` `None`) or was lost (`Some(why)`).
    fn insert(&mut self, remain: u8, fate: Option<&'static str>) {
        if self.contains(remain) {
            return;
        }
        self.seen[usize::from(remain >> 6)] |= 1 << (remain & 63);
        self.count += 1;
        if let Some(why) = fate
            && self.first_lost.is_none_or(|(r, _)| remain > r)
        {
            self.first_lost = Some((remain, why));
        }
    }

    fn len(&self) -> usize {
        self.count
    }

    /// Why the first frame lost (in sending order) was lost.
    fn first_lost(&self) -> Option<&'static str> {
        self.first_lost.map(|(_, why)| why)
    }
}

/// Packets remembered after their last frame, for a receiver's drop reported after it
/// (a partial packet times out 10 s after its last frame).
const RECENT: usize = 1024;

/// A bus's name as a key: ordered as the name, and equal at once when it is the same
/// allocation (the bus hands out one `Arc` for all its frames), so that a frame's lookups
/// do not compare the names' bytes.
#[derive(Debug, Clone, Eq)]
struct BusName(Arc<str>);

impl PartialEq for BusName {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0) || self.0 == other.0
    }
}

impl Ord for BusName {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        if Arc::ptr_eq(&self.0, &other.0) {
            std::cmp::Ordering::Equal
        } else {
            self.0.cmp(&other.0)
        }
    }
}

impl PartialOrd for BusName {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// The packets in progress on every CAN bus.
#[derive(Debug, Clone, Default)]
pub struct Transit {
    partial: BTreeMap<(u32, BusName), Partial>,
    /// The last packets completed: key, what they were, and whether already reported.
    recent: VecDeque<(u32, LostPacket, bool)>,
    /// Packets dropped by their receiver before their BEGIN's crossing was seen (by CFP
    /// key), and why.
    refusals: VecDeque<(u32, &'static str)>,
    /// Packets given up because [`MAX_PARTIAL`] were in progress.
    pub evicted: u64,
}

impl Transit {
    /// Take in one trace event; returns the packet it completes if that packet lost a frame.
    pub fn observe(&mut self, ev: &TraceEvent) -> Option<LostPacket> {
        let (frame, fate) = match &ev.frame {
            TraceFrame::Can(f) => (f, ev.dropped.then_some("dropped on the bus")),
            TraceFrame::CanLost(f, why) => (f, Some(why.sender())),
            TraceFrame::CanUnreceived(f, why) => (f, Some(why.receiver())),
            _ => return None,
        };
        let cfp = CfpId::from_can_id(frame.id);
        let key = (frame.id & CFP_ID_CONN_MASK, BusName(ev.medium.clone()));
        let begin = match cfp.kind {
            FrameType::Begin => {
                let (header, len) = csp::cfp::begin_fields(frame)?;
                let mut head = [0; 2];
                for (h, b) in head
                    .iter_mut()
                    .zip(frame.data().iter().skip(BEGIN_OVERHEAD))
                {
                    *h = *b;
                }
                Some((header, len, head, usize::from(cfp.remain) + 1))
            }
            FrameType::More => None,
        };
        if !self.partial.contains_key(&key) && self.partial.len() >= MAX_PARTIAL {
            let oldest = self
                .partial
                .iter()
                .min_by_key(|(_, p)| p.first)
                .map(|(k, _)| k.clone());
            if let Some(k) = oldest {
                self.partial.remove(&k);
                self.evicted += 1;
            }
        }
        let p = self.partial.entry(key.clone()).or_insert_with(|| Partial {
            first: ev.t,
            ..Partial::default()
        });
        // A second BEGIN, or a frame seen twice: the ident came round again; start over.
        if (begin.is_some() && p.begin.is_some()) || p.fates.contains(cfp.remain) {
            *p = Partial {
                first: ev.t,
                ..Partial::default()
            };
        }
        if begin.is_some() {
            p.begin = begin;
            if let Some(i) = self.refusals.iter().position(|&(k, _)| k == key.0) {
                p.receiver = self.refusals.remove(i).map(|(_, why)| why);
            }
        }
        p.fates.insert(cfp.remain, fate);
        let (_, _, _, frames) = p.begin.as_ref()?;
        if p.fates.len() < *frames {
            return None;
        }
        let p = self.partial.remove(&key)?;
        let (header, data_len, head, _) = p.begin?;
        // The first frame lost, in sending order (the highest `remain`), else the
        // receiver's drop.
        let reason = p.fates.first_lost().or(p.receiver);
        let packet = LostPacket {
            t: ev.t,
            bus: key.1.0.clone(),
            header,
            data_len,
            head,
            reason: reason.unwrap_or_default(),
        };
        if self.recent.len() >= RECENT {
            self.recent.pop_front();
        }
        self.recent
            .push_back((key.0, packet.clone(), reason.is_some()));
        reason.is_some().then_some(packet)
    }

    /// A receiver's CFP reassembly dropped the packet of `can_id` at `t` (`why`: its BEGIN
    /// refused, or the partial packet timed out): it is lost there unless a frame of it was
    /// lost on the way. Returns the packet if its last frame was already seen and it had
    /// lost none (otherwise it is reported when complete, or was already).
    pub fn receiver_dropped(
        &mut self,
        can_id: u32,
        t: SimTime,
        why: &'static str,
    ) -> Option<LostPacket> {
        let conn = can_id & CFP_ID_CONN_MASK;
        if let Some((_, p)) = self.partial.iter_mut().find(|((k, _), _)| *k == conn) {
            p.receiver = p.receiver.or(Some(why));
            return None;
        }
        if let Some((_, packet, reported)) =
            self.recent.iter_mut().rev().find(|(k, _, _)| *k == conn)
        {
            if *reported {
                return None;
            }
            *reported = true;
            packet.t = t;
            packet.reason = why;
            return Some(packet.clone());
        }
        if self.refusals.len() >= RECENT {
            self.refusals.pop_front();
        }
        self.refusals.push_back((conn, why));
        None
    }
}

// What a snapshot saves (docs/snapshots.md): the packets in progress, the recent ones and
// the refusals not matched yet.
snap::fields!(LostPacket {
    t,
    bus,
    header,
    data_len,
    head,
    reason
});
snap::fields!(Partial {
    first,
    begin,
    fates,
    receiver
});
snap::fields!(Fates {
    seen,
    count,
    first_lost
});
snap::fields!(Transit {
    partial,
    recent,
    refusals,
    evicted
});

impl snap::Snap for BusName {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.0.load(r)
    }
}

impl snap::SnapNew for BusName {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        snap::SnapNew::read(r).map(BusName)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use bus::can::FrameLoss;
    use csp::cfp::{CanFrame, fragment_with_ident};
    use csp::packet::Packet;

    fn frames(data_len: usize, ident: u16) -> (Header, Vec<CanFrame>) {
        let header = Header::new(12, 6, 40, 10);
        let mut out = Vec::new();
        let p = Packet::new(header, (0..data_len).map(|i| i as u8).collect::<Vec<u8>>());
        fragment_with_ident(&p, 6, ident, &mut out).unwrap();
        (header, out)
    }

    fn ev(t: u64, frame: TraceFrame, dropped: bool) -> TraceEvent {
        TraceEvent {
            t: SimTime::from_secs(t),
            medium: "payload".into(),
            from: "PL12".into(),
            frame,
            dropped,
        }
    }

    #[test]
    fn a_packet_that_lost_a_frame_is_reported_once_with_its_first_loss() {
        let mut tr = Transit::default();
        // 102 bytes: 14 frames. All cross: nothing lost.
        let (_, f) = frames(102, 1);
        assert_eq!(f.len(), 14);
        for x in &f {
            assert_eq!(tr.observe(&ev(1, TraceFrame::Can(*x), false)), None);
        }
        // Frame 5 dropped on the bus, the last ones lost in the queue before the BEGIN's
        // crossing is traced (queue losses are traced at once, crossings at the end of
        // the frame): reported when the last fate is known, with the first loss.
        let (header, f) = frames(102, 2);
        let mut out = Vec::new();
        for x in &f[10..] {
            out.extend(tr.observe(&ev(2, TraceFrame::CanLost(*x, FrameLoss::QueueFull), true)));
        }
        for (i, x) in f[..10].iter().enumerate() {
            out.extend(tr.observe(&ev(3, TraceFrame::Can(*x), i == 5)));
        }
        assert_eq!(
            out,
            [LostPacket {
                t: SimTime::from_secs(3),
                bus: "payload".into(),
                header,
                data_len: 102,
                head: [0, 1],
                reason: "dropped on the bus",
            }]
        );
        // Still in a queue at the end: in transit, nothing reported; the same ident later
        // starts a new packet.
        let (_, f) = frames(20, 3);
        assert_eq!(tr.observe(&ev(4, TraceFrame::Can(f[0]), false)), None);
        for x in &f {
            assert_eq!(tr.observe(&ev(5, TraceFrame::Can(*x), false)), None);
        }
        assert!(tr.partial.is_empty());
    }

    /// The same CFP key on two buses is two packets, whether a bus's frames share one name
    /// allocation (as a bus's do) or each brings its own.
    #[test]
    fn the_same_key_on_two_buses_is_two_packets() {
        let mut tr = Transit::default();
        let (header, f) = frames(30, 7);
        let main: Arc<str> = "main".into();
        let on = |bus: &Arc<str>, x: &CanFrame, dropped: bool| TraceEvent {
            medium: bus.clone(),
            ..ev(1, TraceFrame::Can(*x), dropped)
        };
        let mut out = Vec::new();
        for (i, x) in f.iter().enumerate() {
            out.extend(tr.observe(&on(&main, x, false)));
            // `ev` names the payload bus with a new allocation each time.
            out.extend(tr.observe(&ev(1, TraceFrame::Can(*x), i == 2)));
        }
        assert_eq!(
            out,
            [LostPacket {
                t: SimTime::from_secs(1),
                bus: "payload".into(),
                header,
                data_len: 30,
                head: [0, 1],
                reason: "dropped on the bus",
            }]
        );
        assert!(tr.partial.is_empty());
    }

    /// A receiver's drop counts once: after the packet crossed whole (reported then),
    /// while it is in progress (reported when complete), before its BEGIN is seen, and not
    /// at all when a frame of it was already lost.
    #[test]
    fn a_receivers_drop_counts_once_whenever_it_is_reported() {
        let mut tr = Transit::default();
        let all = |tr: &mut Transit, f: &[CanFrame]| -> Vec<LostPacket> {
            f.iter()
                .filter_map(|x| tr.observe(&ev(1, TraceFrame::Can(*x), false)))
                .collect()
        };
        let why = "the receiver's CAN reassembly refused it";
        // After: the packet had crossed whole.
        let (_, f) = frames(30, 1);
        assert!(all(&mut tr, &f).is_empty());
        let lost = tr
            .receiver_dropped(f[0].id, SimTime::from_secs(2), why)
            .unwrap();
        assert_eq!((lost.data_len, lost.reason), (30, why));
        assert_eq!(
            tr.receiver_dropped(f[0].id, SimTime::from_secs(2), why),
            None
        );
        // While in progress: reported with its last frame.
        let (_, f) = frames(30, 2);
        assert!(all(&mut tr, &f[..2]).is_empty());
        let timeout = "the receiver's CAN reassembly timed out";
        assert_eq!(
            tr.receiver_dropped(f[0].id, SimTime::from_secs(1), timeout),
            None
        );
        assert_eq!(all(&mut tr, &f[2..])[0].reason, timeout);
        // Before its BEGIN is seen.
        let (_, f) = frames(30, 3);
        assert_eq!(
            tr.receiver_dropped(f[0].id, SimTime::from_secs(1), why),
            None
        );
        assert_eq!(all(&mut tr, &f)[0].reason, why);
        // A frame already lost on the bus: that loss, once.
        let (_, f) = frames(30, 4);
        let mut out = Vec::new();
        for (i, x) in f.iter().enumerate() {
            out.extend(tr.observe(&ev(1, TraceFrame::Can(*x), i == 1)));
        }
        assert_eq!(out[0].reason, "dropped on the bus");
        assert_eq!(
            tr.receiver_dropped(f[0].id, SimTime::from_secs(2), timeout),
            None
        );
    }

    /// The bit set gives what a map from `remain` to fate gave: the count, what was seen,
    /// and the loss of the highest `remain`, whatever the order and the fates.
    #[test]
    fn fates_agree_with_a_map_of_every_frame() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let whys = [
            "dropped on the bus",
            "sender bus-off",
            "receiver off the bus",
        ];
        for _ in 0..2000 {
            let mut fates = Fates::default();
            let mut map: BTreeMap<u8, Option<&'static str>> = BTreeMap::new();
            for _ in 0..(next() % 300) {
                let remain = (next() % 256) as u8;
                let fate = (next() % 5 == 0).then(|| whys[(next() % 3) as usize]);
                assert_eq!(fates.contains(remain), map.contains_key(&remain));
                fates.insert(remain, fate);
                map.entry(remain).or_insert(fate);
            }
            assert_eq!(fates.len(), map.len());
            assert_eq!(
                fates.first_lost(),
                map.values().rev().find_map(|f| *f),
                "{map:?}"
            );
        }
    }

    #[test]
    fn packets_in_progress_are_bounded() {
        let mut tr = Transit::default();
        for i in 0..(MAX_PARTIAL as u16 + 5) {
            let (_, f) = frames(20, i % 1024);
            let mut e = ev(u64::from(i), TraceFrame::Can(f[0]), false);
            e.medium = if i < 1024 { "a" } else { "b" }.into();
            tr.observe(&e);
        }
        assert_eq!(tr.partial.len(), MAX_PARTIAL);
        assert_eq!(tr.evicted, 5);
    }
}
