//! Criterion benchmarks of the flight computer alone, in virtual time: the FC's
//! [`Host`] is driven by calling [`Host::handle_timeout`] at [`Host::poll_timeout`] in a
//! loop (no tokio, no bus), with the default scenario's TLE and start time.
//!
//! Groups, each a `criterion_group!` listed in `criterion_main!` at the end:
//! - `fc/adcs_step`: one ADCS tick (environment at the true orbit, sensors, flight software,
//!   RK4 truth step), the throughput in ticks per second. `nadir`: warmed up until TMGEN
//!   reports nadir in effect (estimate initialised, detumble left) plus five minutes of
//!   settling. `detumble`: B-dot from a 3 deg/s per axis tumble, estimator running. The
//!   spacecraft keeps flying across iterations, so a figure averages over the sunlit and
//!   eclipsed parts of the orbits flown during the measurement.
//! - `fc/sim_seconds`: 600 s of FC from boot (detumble, then nadir) at 10 Hz, without a
//!   publisher, with a publisher at the default 1 Hz and at 10 Hz that clones each
//!   snapshot pair into a `Vec` (the cost of building and handing over the snapshots). The
//!   throughput is in simulated seconds per wall second.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
use csp::router::Route;
use csp::{Header, Packet, SimTime};
use m6p_nodes_fc::wire::{Repr, TargetMode, TmGen};
use m6p_nodes_fc::{FcApp, FcConfig, InitialState};
use nalgebra::Vector3;

/// The default scenario's 6U TLE (scenarios/default.toml).
const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
/// 2026-04-30T18:00:00Z, the default scenario's `start`.
const START: u64 = 1_777_572_000;
/// Simulated duration of one `fc/sim_seconds` iteration.
const SIM_S: u64 = 600;

/// Short measurements: these benches report rates, not fine regressions.
fn short() -> Criterion {
    Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .sample_size(20)
}

/// The FC of the default scenario asking for `mode` from boot, turning at `w_deg_s` per
/// body axis, publishing at `publish_hz`.
fn config(mode: TargetMode, w_deg_s: f64, publish_hz: u32) -> FcConfig {
    FcConfig {
        epoch_unix_s: START,
        tle: Some((L1.to_owned(), L2.to_owned())),
        initial_mode: mode,
        publish_hz,
        initial: InitialState {
            w_body_rad_s: Vector3::new(w_deg_s, -w_deg_s, w_deg_s).map(f64::to_radians),
            ..InitialState::default()
        },
        ..FcConfig::default()
    }
}

/// The FC node (address 3, one packet interface) booted at time zero.
fn host(app: FcApp) -> Host<FcApp> {
    let mut c = NodeConfig::new("FC", 3);
    c.ifaces = vec![IfaceConfig::packet("p")];
    c.routes.set_default(Route::direct(0));
    c.epoch_unix_s = START;
    Host::new(c, app, SimTime::ZERO)
}

/// Run the next due timer (one ADCS tick); returns its time.
fn step(h: &mut Host<FcApp>) -> SimTime {
    let t = h.poll_timeout().expect("the FC always has a next tick");
    h.handle_timeout(t);
    t
}

/// Run every timer before `end`.
fn run_until(h: &mut Host<FcApp>, end: SimTime) {
    while h.poll_timeout().is_some_and(|t| t < end) {
        step(h);
    }
}

/// The mode in effect, as the ground sees it in TMGEN (port 10, command 1).
fn mode_in_effect(h: &mut Host<FcApp>, now: SimTime) -> u8 {
    h.handle_packet(0, Packet::new(Header::new(16, 3, 10, 40), vec![1]), now);
    let Some(Transmit::Packet { packet, .. }) = h.node.poll_transmit() else {
        panic!("no TMGEN reply")
    };
    TmGen::parse(&packet.data[2..])
        .expect("TMGEN reply")
        .current_mode
}

/// An FC flying in `mode` at `now`: stepped until TMGEN reports `mode`, then `settle_s`.
fn warmed_up(mode: TargetMode, w_deg_s: f64, settle_s: u64) -> Host<FcApp> {
    let mut h = host(FcApp::new(config(mode, w_deg_s, 0)));
    let mut now = SimTime::ZERO;
    // Two orbits at most: TRIAD needs the sun, the exit from detumble 60 s of low rate.
    while mode_in_effect(&mut h, now) != mode as u8 {
        assert!(
            now < SimTime::from_secs(2 * 5700),
            "{mode:?} never in effect"
        );
        now = step(&mut h);
    }
    run_until(&mut h, now + Duration::from_secs(settle_s));
    assert!(h.app.estimate().is_some(), "estimator initialised");
    assert_eq!(h.app.target().mode, mode);
    h
}

fn bench_adcs_step(c: &mut Criterion) {
    let mut g = c.benchmark_group("fc/adcs_step");
    g.throughput(Throughput::Elements(1));
    for (name, mode, w_deg_s) in [
        ("nadir", TargetMode::Nadir, 0.2),
        ("detumble", TargetMode::Detumble, 3.0),
    ] {
        let mut h = warmed_up(mode, w_deg_s, 300);
        g.bench_function(name, |b| b.iter(|| black_box(step(&mut h))));
        // The mode held through the measurement.
        let now = h.poll_timeout().expect("next tick");
        assert_eq!(mode_in_effect(&mut h, now), mode as u8, "{name}");
    }
    g.finish();
}

/// A fresh FC in nadir publishing at `publish_hz` (0: nothing).
fn fresh(publish_hz: u32) -> Host<FcApp> {
    host(FcApp::new(config(TargetMode::Nadir, 0.2, publish_hz)))
}

/// Run to `end`, pulling the published pairs as the node's task does; returns them.
fn run_pulling(h: &mut Host<FcApp>, end: SimTime) -> Vec<m6p_nodes_fc::Published> {
    let mut kept = Vec::new();
    while let Some(t) = h.poll_timeout().filter(|&t| t <= end) {
        h.handle_timeout(t);
        kept.extend(std::iter::from_fn(|| h.poll_event()));
    }
    kept
}

fn bench_sim_seconds(c: &mut Criterion) {
    let end = SimTime::from_secs(SIM_S);
    let mut g = c.benchmark_group("fc/sim_seconds");
    // Elements per second = simulated seconds per wall second.
    g.throughput(Throughput::Elements(SIM_S));
    g.sample_size(10);
    for (name, publish_hz) in [
        ("600s_no_publisher", 0),
        ("600s_publish_1hz_clone", 1),
        ("600s_publish_10hz_clone", 10),
    ] {
        // Once outside the measurement: every snapshot pair is pulled.
        let mut h = fresh(publish_hz);
        let n = run_pulling(&mut h, end).len() as u64;
        assert_eq!(n, SIM_S * u64::from(publish_hz), "{name}");
        g.bench_function(name, |b| {
            b.iter_batched(
                || fresh(publish_hz),
                |mut h| {
                    let kept = run_pulling(&mut h, end);
                    // Returned, so that dropping the kept snapshots is not timed.
                    (h, kept)
                },
                BatchSize::PerIteration,
            )
        });
    }
    g.finish();
}

criterion_group! {
    name = adcs_step;
    config = short();
    targets = bench_adcs_step
}

criterion_group! {
    name = sim_seconds;
    config = short();
    targets = bench_sim_seconds
}

criterion_main!(adcs_step, sim_seconds);
