//! How fast the PC core runs in virtual time: whole sessions per wall second and payload
//! bytes per wall second through to the sink, against the in-process scripted payloads of
//! tests/util (no CSP links: packets go straight between the hosts).
//!
//! - `polling_session`: one 5 s polling session at maximum rate (poll period 0, 254-byte
//!   frames, the payload answering after 1 ms): about 5000 POLL cycles, 1.27 MB; S-band at
//!   1 Gbit/s so that it does not limit. Throughput is the bytes downlinked.
//! - `polling_session_sband_1mbps`: the same session with the default 1 Mbit/s S-band (the
//!   queue drains after the session).
//! - `buffering_session`: 1 MB pushed in 256-byte ingest packets, then one session
//!   streaming it at 1 Gbit/s.
#![allow(clippy::unwrap_used, missing_docs)]

#[path = "../tests/util/mod.rs"]
mod util;

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use csp::SimTime;
use m6p_nodes_pc::{PcConfig, SessionMode, SessionSpec};
use util::{FakePayload, Sim, session};

fn cfg(rate_bps: u64) -> PcConfig {
    let mut c = PcConfig {
        sessions: vec![SessionSpec::polling(1, 12), SessionSpec::buffering(2, 13)],
        ..PcConfig::default()
    };
    c.sessions[0].mode = SessionMode::Polling {
        poll_period: Duration::ZERO,
        reply_timeout: Duration::from_millis(200),
    };
    c.sband.rate_bps = rate_bps;
    c
}

fn polling(rate_bps: u64) -> u64 {
    let mut p = FakePayload::normal(12);
    p.latency = Duration::from_millis(1);
    let mut s = Sim::new(cfg(rate_bps), vec![p]);
    assert_eq!(s.setup(&session(1, 0, 5, 0, 254, b"go")), 1);
    s.run_until(SimTime::from_secs(30));
    let a = s.host.app.accounting();
    assert!(a.is_balanced());
    a.total().downlinked
}

fn buffering() -> u64 {
    let mut s = Sim::new(cfg(1_000_000_000), vec![]);
    let chunk = vec![0x5a; 256];
    for _ in 0..4096 {
        s.send_from(13, 40, 11, &chunk);
    }
    assert_eq!(s.setup(&session(2, 0, 10, 0, 254, b"")), 1);
    s.run_until(SimTime::from_secs(11));
    let a = s.host.app.accounting();
    assert!(a.is_balanced());
    a.total().downlinked
}

fn benches(c: &mut Criterion) {
    let mut g = c.benchmark_group("pc");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    let bytes = polling(1_000_000_000);
    g.throughput(Throughput::Bytes(bytes));
    g.bench_function("polling_session", |b| {
        b.iter(|| black_box(polling(1_000_000_000)))
    });
    let bytes = polling(1_000_000);
    g.throughput(Throughput::Bytes(bytes));
    g.bench_function("polling_session_sband_1mbps", |b| {
        b.iter(|| black_box(polling(1_000_000)))
    });
    let bytes = buffering();
    g.throughput(Throughput::Bytes(bytes));
    g.bench_function("buffering_session", |b| b.iter(|| black_box(buffering())));
    g.finish();
}

criterion_group!(pc, benches);
criterion_main!(pc);
