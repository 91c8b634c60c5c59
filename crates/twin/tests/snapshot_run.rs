//! A run resumed from the runtime's part of a snapshot (docs/snapshots.md) goes on as the
//! run it was taken from: every event from the snapshot's instant on is the same, in the
//! same order; and a run that takes snapshots is the run that takes none.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::time::Duration;

use csp::SimTime;
use m6p_twin::events::RunEvent;
use m6p_twin::exec::{compile_seeded, load};
use m6p_twin::runtime::build_runtime;
use m6p_twin::runtime::counters::RunSink;
use m6p_twin::runtime::{Resume, RunOptions, run_with};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A run's events as text, and the snapshots it took with how many events came before
/// each.
#[derive(Default)]
struct Collect {
    events: Vec<String>,
    snapshots: Vec<(SimTime, Vec<u8>, usize)>,
}

impl RunSink for Collect {
    fn event(&mut self, ev: &RunEvent) {
        self.events.push(format!("{ev:?}"));
    }
    fn contact(&mut self, t: SimTime, on: bool) {
        self.events.push(format!("contact {t} {on}"));
    }
    fn snapshot(&mut self, t: SimTime, run_state: Vec<u8>) {
        self.snapshots.push((t, run_state, self.events.len()));
    }
}

fn run(opts: RunOptions) -> Collect {
    let mut sink = Collect::default();
    build_runtime()
        .unwrap()
        .block_on(run_with(opts, None, &mut sink))
        .unwrap();
    sink
}

/// Scenario `name` cut to `span` (`None`: its own length), with packet events (the run's
/// packet tap is saved too).
fn options(name: &str, span: Option<Duration>) -> RunOptions {
    let loaded = load(&repo().join("scenarios").join(name)).unwrap();
    let mut opts = compile_seeded(&loaded, None).opts;
    if span.is_some() {
        opts.duration = span;
    }
    opts.packet_events = true;
    opts
}

fn resumes_the_same(name: &str, span: Option<Duration>, at: &[SimTime]) {
    let plain = run(options(name, span));
    let mut opts = options(name, span);
    opts.snapshot_at = at.to_vec();
    let taken = run(opts);
    assert_eq!(
        taken.events.len(),
        plain.events.len(),
        "{name}: taking snapshots changes nothing"
    );
    assert!(taken.events == plain.events, "{name}: the same events");
    assert_eq!(taken.snapshots.len(), at.len());
    for (t, state, before) in taken.snapshots {
        let mut opts = options(name, span);
        opts.resume = Some(Resume {
            t,
            run_state: state,
        });
        let resumed = run(opts);
        let expected = &plain.events[before..];
        let first_diff = resumed
            .events
            .iter()
            .zip(expected)
            .position(|(a, b)| a != b);
        assert!(
            first_diff.is_none() && resumed.events.len() == expected.len(),
            "{name} from {t}: {} events, {} expected; first difference at {first_diff:?}:\n  {:?}\n  {:?}",
            resumed.events.len(),
            expected.len(),
            first_diff.and_then(|i| resumed.events.get(i)),
            first_diff.and_then(|i| expected.get(i)),
        );
    }
}

#[test]
fn the_default_scenario_resumed_from_snapshots_goes_on_the_same() {
    resumes_the_same(
        "default.toml",
        Some(Duration::from_secs(1200)),
        &[SimTime::from_secs(300), SimTime::from_ms(777_777)],
    );
}

/// Every shipped scenario, resumed from its midpoint (the runtime's part of the snapshot:
/// the events are the run's whole story; what the sink keeps is its own part).
#[test]
fn every_shipped_scenario_resumed_from_its_midpoint_goes_on_the_same() {
    let mut names: Vec<String> = std::fs::read_dir(repo().join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 25);
    for name in names {
        let length = options(&name, None).duration.unwrap();
        let mid = SimTime::from_ns(u64::try_from(length.as_nanos() / 2).unwrap());
        let started = std::time::Instant::now();
        resumes_the_same(&name, None, &[mid]);
        eprintln!("{name}: {:.1} s", started.elapsed().as_secs_f64());
    }
}
