//! `cfp_reassembly`: libcsp 1.4's CAN fragmentation protocol: `csp::cfp::Reassembler` fed
//! arbitrary CAN frames (any 29-bit id, 0-8 data bytes) at increasing times with timeouts
//! in between, and a `csp::cfp::Fragmenter` round trip of an arbitrary packet (input layout:
//! `m6p_twin_fuzz::cfp_input`).
//!
//! Asserts:
//! - the reassembler never panics, never holds more partial packets than slots, never
//!   delivers more than its MTU, counts every frame and every packet it delivers;
//! - `poll_timeout` is set exactly while partial packets are held, and after
//!   `handle_timeout(now)` nothing is due at or before `now`;
//! - the fragmenter's frames (exact count, DLCs, CFP ids with src, MAC, ident and a remain
//!   counting down to 0) reassemble, in a fresh reassembler with a large enough MTU, to the
//!   same packet on the last frame and to nothing before.
#![no_main]

use std::time::Duration;

use csp::cfp::{
    self, BEGIN_OVERHEAD, CFP_MAX_DATA, CSP_CAN_MTU, CanFrame, CfpId, Fragmenter, FrameType,
    Reassembler, ReassemblerConfig,
};
use csp::{Header, Packet, SimTime};
use libfuzzer_sys::fuzz_target;
use m6p_twin_fuzz::cfp_input::{CfpInput, CfpOp};

fuzz_target!(|input: CfpInput| {
    let mtu = if input.config & 0x80 != 0 {
        CFP_MAX_DATA
    } else {
        CSP_CAN_MTU
    };
    let config = ReassemblerConfig {
        slots: 1 + usize::from(input.config % 12),
        timeout: Duration::from_secs(10),
        mtu,
    };
    let mut r = Reassembler::new(config);
    let mut now = SimTime::ZERO;
    let (mut frames, mut delivered) = (0u64, 0u64);
    for op in input.ops.iter().take(4096) {
        match op {
            CfpOp::Frame {
                id,
                dlc,
                data,
                dt_us,
            } => {
                now = now + Duration::from_micros(u64::from(*dt_us));
                let n = usize::from(dlc % 9);
                let Some(frame) = CanFrame::new(id & cfp::CAN_EFF_MASK, &data[..n]) else {
                    unreachable!("a masked id and at most 8 bytes make a frame");
                };
                frames += 1;
                if let Some(Ok(p)) = r.handle(&frame, now) {
                    delivered += 1;
                    assert!(
                        p.data.len() <= mtu,
                        "{} bytes over an MTU of {mtu}",
                        p.data.len()
                    );
                }
            }
            CfpOp::Wait { dt_ms } => {
                now = now + Duration::from_millis(u64::from(*dt_ms));
                if r.poll_timeout().is_some_and(|t| t <= now) {
                    r.handle_timeout(now);
                }
                assert!(
                    r.poll_timeout().is_none_or(|t| t > now),
                    "due after handle_timeout"
                );
            }
        }
        assert!(r.partial_count() <= config.slots);
        assert_eq!(r.poll_timeout().is_some(), r.partial_count() > 0);
    }
    let st = r.stats();
    assert_eq!(st.frames, frames);
    assert_eq!(st.packets_ok, delivered);

    // The fragmenter's round trip.
    let mut data = input.data.clone();
    data.truncate(CFP_MAX_DATA);
    let packet = Packet::new(Header::from_word(input.word), data);
    let mac = input.mac & 0x1f;
    let mut frag = Fragmenter::new(input.ident, CFP_MAX_DATA);
    let first_ident = frag.next_ident();
    let mut out = Vec::new();
    let ident = frag
        .fragment(&packet, mac, &mut out)
        .expect("a header from a word and at most 2042 bytes fragment");
    assert_eq!(ident, first_ident);
    assert_eq!(frag.next_ident(), (ident + 1) & cfp::IDENT_MASK);
    let len = packet.data.len();
    let expected_frames = if len <= 2 {
        1
    } else {
        1 + (len - 2).div_ceil(8)
    };
    assert_eq!(out.len(), expected_frames);
    assert_eq!(
        out.iter().map(|f| usize::from(f.dlc)).sum::<usize>(),
        len + BEGIN_OVERHEAD
    );
    for (i, f) in out.iter().enumerate() {
        let id = CfpId::from_can_id(f.id);
        assert_eq!(id.src, packet.header.src);
        assert_eq!(id.dst, mac);
        assert_eq!(id.ident, ident);
        assert_eq!(usize::from(id.remain), out.len() - 1 - i);
        assert_eq!(id.kind == FrameType::Begin, i == 0);
    }
    let mut fresh = Reassembler::new(ReassemblerConfig {
        mtu: CFP_MAX_DATA,
        ..ReassemblerConfig::default()
    });
    let t = now;
    for (i, f) in out.iter().enumerate() {
        let got = fresh.handle(f, t);
        if i + 1 == out.len() {
            assert_eq!(got, Some(Ok(packet.clone())));
        } else {
            assert_eq!(got, None, "frame {i} of {}", out.len());
        }
    }
    assert_eq!(fresh.partial_count(), 0);
    // libcsp 1.4's own limits: at most 256 bytes reassemble with the default configuration.
    if len <= CSP_CAN_MTU {
        let mut v14 = Reassembler::default();
        let last = out.iter().map(|f| v14.handle(f, t)).last().flatten();
        assert_eq!(last, Some(Ok(packet)));
    }
});
