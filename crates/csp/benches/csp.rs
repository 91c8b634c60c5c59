//! Throughput of the wire codecs: KISS encode + decode, CFP fragment + reassemble, CRC-32C.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use m6p_csp::cfp::{CanFrame, Fragmenter, Reassembler};
use m6p_csp::kiss::{self, Decoder, KissEvent};
use m6p_csp::{Header, Packet, SimTime};

fn ramp(n: usize) -> Vec<u8> {
    // Includes 0xC0 and 0xDB, so the KISS path escapes a realistic share of bytes.
    (0..n).map(|i| i as u8).collect()
}

fn kiss_encode_decode(c: &mut Criterion) {
    let packet = Packet::new(Header::new(6, 3, 10, 40), ramp(200));
    let mut g = c.benchmark_group("kiss_encode_decode");
    g.throughput(Throughput::Bytes(packet.data.len() as u64));
    let mut wire = Vec::with_capacity(512);
    let mut decoder = Decoder::default();
    let mut events = Vec::with_capacity(1);
    g.bench_function("200B", |b| {
        b.iter(|| {
            wire.clear();
            events.clear();
            kiss::encode(black_box(&packet), &mut wire);
            decoder.push(black_box(&wire), &mut events);
            assert!(matches!(events.first(), Some(KissEvent::Packet(_))));
        })
    });
    g.finish();
}

fn cfp_fragment_reassemble(c: &mut Criterion) {
    let mut g = c.benchmark_group("cfp_fragment_reassemble");
    g.throughput(Throughput::Elements(1));
    for len in [64usize, 256] {
        let packet = Packet::new(Header::new(6, 3, 7, 10), ramp(len));
        let mut fragmenter = Fragmenter::new(0, 256);
        let mut reassembler = Reassembler::default();
        let mut frames: Vec<CanFrame> = Vec::with_capacity(40);
        g.bench_function(format!("{len}B"), |b| {
            b.iter(|| {
                frames.clear();
                fragmenter
                    .fragment(black_box(&packet), 3, &mut frames)
                    .unwrap();
                let mut done = None;
                for f in &frames {
                    done = reassembler.handle(f, SimTime::ZERO);
                }
                assert!(matches!(done, Some(Ok(_))));
            })
        });
    }
    g.finish();
}

fn crc32c(c: &mut Criterion) {
    let mut g = c.benchmark_group("crc32c");
    for len in [64usize, 256] {
        let data = ramp(len);
        g.throughput(Throughput::Bytes(len as u64));
        g.bench_function(format!("{len}B"), |b| {
            b.iter(|| m6p_csp::crc32::crc32c(black_box(&data)))
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    targets = kiss_encode_decode, cfp_fragment_reassemble, crc32c
}
criterion_main!(benches);
