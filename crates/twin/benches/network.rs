//! Network benchmarks (criterion): CSP request-reply round trips per second between two
//! nodes over the in-process CAN bus in virtual time, 64-byte payload, the whole
//! default network for a simulated hour, and the embedded default scenario (FC flying its
//! ADCS at 10 Hz, publishing at 1 Hz) for ten simulated minutes with and without the MCAP
//! recorder (`m6p-twin run --record`).

use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use csp::SimTime;
use m6p_twin::network::NetworkSpec;
use m6p_twin::report::run;
use m6p_twin::runtime::{RunOptions, build_runtime_for};

/// Run `n` round trips; returns (wall time, simulated time).
fn round_trips(n: u64) -> (Duration, SimTime) {
    m6p_twin::bench::round_trips(n).expect("round trips")
}

fn bench_round_trips(c: &mut Criterion) {
    let mut g = c.benchmark_group("csp_over_can");
    g.throughput(Throughput::Elements(1000));
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    g.bench_function("ping_64B_round_trips_x1000", |b| {
        b.iter_custom(|iters| (0..iters).map(|_| round_trips(1000).0).sum())
    });
    g.finish();
    let (wall, sim) = round_trips(10_000);
    eprintln!(
        "10000 round trips of 64-byte pings: {:.0} round trips per wall second, {:.3} s simulated ({:.1} us per round trip on the bus)",
        10_000.0 / wall.as_secs_f64(),
        sim.as_secs_f64(),
        sim.as_secs_f64() * 1e6 / 10_000.0
    );
}

fn bench_default_network(c: &mut Criterion) {
    let mut g = c.benchmark_group("network");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    g.bench_function("default_network_1h_virtual", |b| {
        b.iter(|| {
            let net = NetworkSpec::default_m6p();
            let mut opts = RunOptions::new(net.clone(), Duration::from_secs(3600));
            opts.ground_plan
                .insert(16, m6p_twin::default_plan(&net, Duration::from_secs(3600)));
            let rt = build_runtime_for(&opts).expect("runtime");
            rt.block_on(run(opts, None)).expect("run")
        })
    });
    g.finish();
}

/// Ten simulated minutes of the embedded default scenario, as `m6p-twin run` runs it,
/// recording to `record` when given; returns the recording's size in bytes.
fn default_scenario_10min(record: Option<&std::path::Path>) -> u64 {
    use m6p_twin::exec::{compile_loaded, execute_recorded, load_default, with_duration};
    let loaded = load_default().expect("default scenario");
    let mut compiled = compile_loaded(&loaded);
    with_duration(&mut compiled, Duration::from_secs(600));
    let rt = build_runtime_for(&compiled.opts).expect("runtime");
    // Each iteration replaces the last one's file.
    let record = record.map(m6p_twin::exec::RecordTo::replacing);
    let (outcome, stats) = rt
        .block_on(execute_recorded(&loaded, compiled, record))
        .expect("run");
    assert_eq!(outcome.report.sim_time, SimTime::from_secs(600));
    stats.map_or(0, |s| s.expect("recorded").bytes)
}

fn bench_default_scenario(c: &mut Criterion) {
    let path = std::env::temp_dir().join(format!("m6p-twin-bench-{}.mcap", std::process::id()));
    let mut g = c.benchmark_group("network");
    // Elements per second = simulated seconds per wall second.
    g.throughput(Throughput::Elements(600));
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    g.bench_function("default_scenario_10min_virtual", |b| {
        b.iter(|| default_scenario_10min(None))
    });
    g.bench_function("default_scenario_10min_virtual_recorded", |b| {
        b.iter(|| default_scenario_10min(Some(&path)))
    });
    g.finish();
    let bytes = default_scenario_10min(Some(&path));
    eprintln!("10 minutes of the default scenario: recording of {bytes} bytes");
    let _ = std::fs::remove_file(&path);
}

criterion_group!(
    benches,
    bench_round_trips,
    bench_default_network,
    bench_default_scenario
);
criterion_main!(benches);
