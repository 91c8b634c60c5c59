//! `kiss_decoder`: libcsp 1.4's KISS receiver (`csp::kiss::Decoder`) on an arbitrary byte
//! stream fed in arbitrary chunks (the input's first bytes choose the chunk sizes, see
//! `m6p_twin_fuzz::kiss_input`), under both receive limits (`libcsp14_rx_limit` on and off),
//! and the encoder (`csp::kiss::encode`).
//!
//! Asserts:
//! - the events and counters do not depend on the chunking: one-shot `push`, the chosen
//!   chunks and byte-at-a-time `push_byte` give the same;
//! - the counters add up (`frames_ok` = packets, `rx_error` = drops = bad CRC + short +
//!   oversize) and no packet exceeds the configuration's limit;
//! - every decoded packet, encoded again, decodes back to itself alone;
//! - a packet made of the stream (header + up to 256 data bytes), encoded, decodes back to
//!   itself with the twin's limit, and with v1.4's limit exactly when it has at most 248
//!   data bytes (otherwise one oversize drop).
#![no_main]

use csp::Packet;
use csp::kiss::{self, Decoder, DecoderConfig, KISS_MTU, KissDrop, KissEvent};
use libfuzzer_sys::fuzz_target;
use m6p_twin_fuzz::kiss_input;

fn decode(cfg: DecoderConfig, bytes: &[u8]) -> Vec<KissEvent> {
    let mut d = Decoder::new(cfg);
    let mut ev = Vec::new();
    d.push(bytes, &mut ev);
    ev
}

fuzz_target!(|data: &[u8]| {
    let (sizes, stream) = kiss_input::split(data);
    for limit in [false, true] {
        let cfg = DecoderConfig {
            libcsp14_rx_limit: limit,
        };
        let mut one = Decoder::new(cfg);
        let mut ev_one = Vec::new();
        one.push(stream, &mut ev_one);

        let mut chunked = Decoder::new(cfg);
        let mut ev_chunked = Vec::new();
        let (mut i, mut k) = (0, 0);
        while i < stream.len() {
            let n = sizes[k % sizes.len()].min(stream.len() - i);
            chunked.push(&stream[i..i + n], &mut ev_chunked);
            i += n;
            k += 1;
        }

        let mut bytewise = Decoder::new(cfg);
        let ev_bytewise: Vec<KissEvent> = stream
            .iter()
            .filter_map(|&b| bytewise.push_byte(b))
            .collect();

        assert_eq!(
            ev_one, ev_chunked,
            "chunking changed the events (limit {limit})"
        );
        assert_eq!(
            ev_one, ev_bytewise,
            "push_byte differs from push (limit {limit})"
        );
        let st = one.stats();
        assert_eq!(st, chunked.stats());
        assert_eq!(st, bytewise.stats());

        let packets = ev_one
            .iter()
            .filter(|e| matches!(e, KissEvent::Packet(_)))
            .count() as u64;
        let drops = ev_one.len() as u64 - packets;
        assert_eq!(st.frames_ok, packets);
        assert_eq!(st.rx_error, drops);
        assert_eq!(st.bad_crc + st.short + st.oversize, st.rx_error);

        for e in &ev_one {
            if let KissEvent::Packet(p) = e {
                assert!(
                    4 + p.data.len() + 4 <= cfg.max_body(),
                    "{} data bytes",
                    p.data.len()
                );
                let mut wire = Vec::new();
                kiss::encode(p, &mut wire);
                assert_eq!(decode(cfg, &wire), vec![KissEvent::Packet(p.clone())]);
            }
        }
    }

    if let Ok(mut p) = Packet::parse(stream) {
        p.data.truncate(KISS_MTU);
        let mut wire = Vec::new();
        kiss::encode(&p, &mut wire);
        assert_eq!(
            decode(DecoderConfig::default(), &wire),
            vec![KissEvent::Packet(p.clone())]
        );
        let v14 = decode(
            DecoderConfig {
                libcsp14_rx_limit: true,
            },
            &wire,
        );
        if p.data.len() <= 248 {
            assert_eq!(v14, vec![KissEvent::Packet(p)]);
        } else {
            assert_eq!(v14, vec![KissEvent::Dropped(KissDrop::Oversize)]);
        }
    }
});
