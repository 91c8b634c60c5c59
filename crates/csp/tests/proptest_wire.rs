//! Property tests of the wire codecs: round trips, robustness on arbitrary input, and CFP
//! reassembly under interleaving, loss and timeouts.
#![allow(clippy::unwrap_used)]

use std::time::Duration;

use m6p_csp::cfp::{self, CanFrame, CfpDrop, CfpId, FrameType, Reassembler, ReassemblerConfig};
use m6p_csp::kiss::{self, Decoder, DecoderConfig, KISS_MTU, KissEvent};
use m6p_csp::{Header, Packet, Priority, SimTime};
use proptest::prelude::*;

fn header() -> impl Strategy<Value = Header> {
    (0u8..4, 0u8..32, 0u8..32, 0u8..64, 0u8..64, any::<u8>()).prop_map(
        |(prio, src, dst, dport, sport, flags)| Header {
            prio: Priority::from_bits(prio),
            src,
            dst,
            dport,
            sport,
            flags,
        },
    )
}

fn packet(max_len: usize) -> impl Strategy<Value = Packet> {
    (header(), prop::collection::vec(any::<u8>(), 0..=max_len)).prop_map(|(h, d)| Packet::new(h, d))
}

/// Arbitrary CAN frames, biased towards valid CFP ids of a few senders so that some
/// frames find partial packets.
fn can_frame() -> impl Strategy<Value = CanFrame> {
    let id = prop_oneof![
        any::<u32>(),
        (0u8..3, 0u8..3, any::<bool>(), 0u8..6, 0u16..3).prop_map(|(s, d, more, remain, ident)| {
            CfpId {
                src: s,
                dst: d,
                kind: if more {
                    FrameType::More
                } else {
                    FrameType::Begin
                },
                remain,
                ident,
            }
            .to_can_id()
        }),
    ];
    (id, any::<u8>(), any::<[u8; 8]>()).prop_map(|(id, dlc, data)| CanFrame { id, dlc, data })
}

fn fragments(p: &Packet, ident: u16) -> Vec<CanFrame> {
    let mut out = Vec::new();
    cfp::fragment_with_ident(p, p.header.dst, ident, &mut out).unwrap();
    out
}

fn decode_all(d: &mut Decoder, bytes: &[u8]) -> Vec<KissEvent> {
    let mut out = Vec::new();
    d.push(bytes, &mut out);
    out
}

proptest! {
    #[test]
    fn header_round_trip(h in header()) {
        prop_assert!(h.validate().is_ok());
        let bytes = h.to_bytes();
        prop_assert_eq!(Header::parse(&bytes).unwrap(), h);
        prop_assert_eq!(Header::from_word(h.to_word()), h);
        prop_assert_eq!(u32::from_be_bytes(bytes), h.to_word());
    }

    #[test]
    fn kiss_round_trip(p in packet(KISS_MTU)) {
        let mut wire = Vec::new();
        kiss::encode(&p, &mut wire);
        // Only the delimiters are FENDs.
        prop_assert_eq!(wire.iter().filter(|&&b| b == kiss::FEND).count(), 2);
        let mut d = Decoder::default();
        prop_assert_eq!(decode_all(&mut d, &wire), vec![KissEvent::Packet(p.clone())]);
        prop_assert_eq!(d.stats().frames_ok, 1);
        // The v1.4 limit accepts exactly the bodies of at most 256 bytes.
        let mut d = Decoder::new(DecoderConfig { libcsp14_rx_limit: true });
        let ok = decode_all(&mut d, &wire).contains(&KissEvent::Packet(p.clone()));
        prop_assert_eq!(ok, p.data.len() <= KISS_MTU - 8);
    }

    #[test]
    fn kiss_stream_in_random_chunks(
        packets in prop::collection::vec(packet(KISS_MTU), 1..6),
        garbage in prop::collection::vec(any::<u8>().prop_filter("not FEND", |b| *b != kiss::FEND), 0..8),
        chunks in prop::collection::vec(1usize..80, 1..40),
    ) {
        // Garbage before the first frame is discarded, not mistaken for a frame.
        let mut wire = garbage.clone();
        for p in &packets {
            kiss::encode(p, &mut wire);
        }
        let mut d = Decoder::default();
        let mut events = Vec::new();
        let mut rest = wire.as_slice();
        for &n in chunks.iter().cycle() {
            if rest.is_empty() {
                break;
            }
            let (chunk, tail) = rest.split_at(n.min(rest.len()));
            d.push(chunk, &mut events);
            rest = tail;
        }
        let want: Vec<KissEvent> = packets.iter().cloned().map(KissEvent::Packet).collect();
        prop_assert_eq!(events, want);
        prop_assert_eq!(d.stats().discarded_bytes, garbage.len() as u64);
        prop_assert_eq!(d.stats().rx_error, 0);
    }

    #[test]
    fn cfp_round_trip(p in packet(cfp::CSP_CAN_MTU), ident in 0u16..1024, mac in 0u8..32) {
        let mut frames = Vec::new();
        cfp::fragment_with_ident(&p, mac, ident, &mut frames).unwrap();
        prop_assert_eq!(frames.len(), (p.data.len() + 6).div_ceil(8));
        let mut r = Reassembler::default();
        let (last, init) = frames.split_last().unwrap();
        for (k, f) in init.iter().enumerate() {
            let id = CfpId::from_can_id(f.id);
            prop_assert_eq!((id.src, id.dst, id.ident), (p.header.src, mac, ident));
            prop_assert_eq!(usize::from(id.remain), frames.len() - 1 - k);
            prop_assert_eq!(r.handle(f, SimTime::ZERO), None);
        }
        prop_assert_eq!(r.handle(last, SimTime::ZERO), Some(Ok(p)));
        prop_assert_eq!(r.partial_count(), 0);
    }

    #[test]
    fn fragmenter_counts_idents(first in any::<u16>(), n in 1usize..40) {
        let mut f = cfp::Fragmenter::new(first, cfp::CSP_CAN_MTU);
        let p = Packet::new(Header::new(1, 2, 3, 4), vec![7; 9]);
        let mut out = Vec::new();
        for k in 0..n {
            let used = f.fragment(&p, 2, &mut out).unwrap();
            prop_assert_eq!(used, ((usize::from(first & 0x3ff) + k) % 1024) as u16);
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..700)) {
        let _ = Header::parse(&bytes);
        if let Ok(p) = Packet::parse(&bytes) {
            prop_assert_eq!(p.to_bytes(), bytes.clone());
        }
        for config in [DecoderConfig::default(), DecoderConfig { libcsp14_rx_limit: true }] {
            let mut d = Decoder::new(config);
            let events = decode_all(&mut d, &bytes);
            let st = d.stats();
            let delivered = events.iter().filter(|e| matches!(e, KissEvent::Packet(_))).count();
            prop_assert_eq!(st.frames_ok, delivered as u64);
            prop_assert_eq!(st.rx_error, (events.len() - delivered) as u64);
            prop_assert_eq!(st.rx_error, st.bad_crc + st.short + st.oversize);
            for e in &events {
                if let KissEvent::Packet(p) = e {
                    prop_assert!(p.data.len() + 8 <= config.max_body());
                }
            }
        }
    }

    #[test]
    fn arbitrary_frames_never_panic(
        frames in prop::collection::vec((can_frame(), 0u64..30_000), 0..200),
        slots in 0usize..4,
    ) {
        let mut r = Reassembler::new(ReassemblerConfig { slots, ..Default::default() });
        let mut now = SimTime::ZERO;
        for (f, dt) in &frames {
            now = now + Duration::from_millis(*dt);
            if let Some(Ok(p)) = r.handle(f, now) {
                prop_assert!(p.data.len() <= cfp::CSP_CAN_MTU);
            }
            prop_assert!(r.partial_count() <= slots);
            if let Some(t) = r.poll_timeout() {
                if t <= now {
                    prop_assert!(r.handle_timeout(now) > 0);
                }
            }
        }
        let s = r.stats();
        prop_assert_eq!(s.frames, frames.len() as u64);
    }

    #[test]
    fn interleaved_senders_all_arrive(
        packets in prop::collection::vec(packet(cfp::CSP_CAN_MTU), 2..=4),
        idents in prop::collection::vec(0u16..1024, 4),
        picks in prop::collection::vec(any::<prop::sample::Index>(), 0..300),
    ) {
        // Give every sender its own source address.
        let packets: Vec<Packet> = packets
            .into_iter()
            .enumerate()
            .map(|(i, mut p)| {
                p.header.src = i as u8 + 1;
                p
            })
            .collect();
        let mut queues: Vec<std::collections::VecDeque<CanFrame>> = packets
            .iter()
            .zip(&idents)
            .map(|(p, &ident)| fragments(p, ident).into())
            .collect();
        // Interleave: pick a sender for each step, keeping each sender's own order.
        let mut wire = Vec::new();
        let mut picks = picks.iter();
        while queues.iter().any(|q| !q.is_empty()) {
            let live: Vec<usize> = (0..queues.len()).filter(|&i| !queues[i].is_empty()).collect();
            let i = picks.next().map_or(live[0], |ix| live[ix.index(live.len())]);
            wire.push(queues[i].pop_front().unwrap());
        }
        let mut r = Reassembler::default();
        let mut got = Vec::new();
        for f in &wire {
            match r.handle(f, SimTime::ZERO) {
                Some(Ok(p)) => got.push(p),
                Some(Err(e)) => prop_assert!(false, "unexpected drop {e}"),
                None => {}
            }
        }
        got.sort_by_key(|p| p.header.src);
        prop_assert_eq!(got, packets);
        prop_assert_eq!(r.partial_count(), 0);
    }

    #[test]
    fn lost_fragment_is_detected(
        p in packet(cfp::CSP_CAN_MTU).prop_filter("needs a MORE frame", |p| p.data.len() > 2),
        ident in 0u16..1024,
        which in any::<prop::sample::Index>(),
    ) {
        let mut frames = fragments(&p, ident);
        let lost = 1 + which.index(frames.len() - 1);
        let was_last = lost == frames.len() - 1;
        frames.remove(lost);
        let mut r = Reassembler::default();
        let mut drops = Vec::new();
        for f in &frames {
            match r.handle(f, SimTime::ZERO) {
                Some(Ok(q)) => prop_assert!(false, "packet delivered despite a lost frame: {q:?}"),
                Some(Err(e)) => drops.push(e),
                None => {}
            }
        }
        if was_last {
            // Nothing follows the gap: the partial packet waits for the timeout.
            prop_assert!(drops.is_empty());
            prop_assert_eq!(r.partial_count(), 1);
            prop_assert_eq!(r.handle_timeout(SimTime::ZERO + Duration::from_secs(10)), 1);
        } else {
            prop_assert_eq!(drops.first(), Some(&CfpDrop::RemainMismatch));
            prop_assert!(drops[1..].iter().all(|d| *d == CfpDrop::UnexpectedMore));
            prop_assert_eq!(r.stats().remain_mismatch, 1);
        }
        prop_assert_eq!(r.partial_count(), 0);
    }

    #[test]
    fn stale_partials_are_purged(
        starts in prop::collection::vec(0u64..20_000, 1..10),
        timeout_ms in 1u64..20_000,
    ) {
        let timeout = Duration::from_millis(timeout_ms);
        let mut r = Reassembler::new(ReassemblerConfig { timeout, ..Default::default() });
        // One 20-byte packet per start time, only its BEGIN delivered; distinct idents.
        let p = Packet::new(Header::new(6, 3, 7, 10), vec![1; 20]);
        let mut starts = starts;
        starts.sort_unstable();
        for (ident, &t) in starts.iter().enumerate() {
            prop_assert_eq!(r.handle(&fragments(&p, ident as u16)[0], SimTime::from_ms(t)), None);
        }
        let n = starts.len();
        prop_assert_eq!(r.partial_count(), n);
        let first = SimTime::from_ms(starts[0]) + timeout;
        prop_assert_eq!(r.poll_timeout(), Some(first));
        // Just before the earliest deadline nothing is stale.
        prop_assert_eq!(r.handle_timeout(SimTime::from_ns(first.as_ns() - 1)), 0);
        let mut purged = 0;
        while let Some(t) = r.poll_timeout() {
            let k = r.handle_timeout(t);
            prop_assert!(k > 0);
            purged += k;
        }
        prop_assert_eq!(purged, n);
        prop_assert_eq!(r.stats().timeout, n as u64);
        prop_assert_eq!(r.partial_count(), 0);
    }
}
