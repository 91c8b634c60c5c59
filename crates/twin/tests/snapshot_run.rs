//! A run resumed from the runtime's part of a snapshot (docs/snapshots.md) goes on as the
//! run it was taken from: every event from the snapshot's instant on is the same, in the
//! same order; and a run that takes snapshots is the run that takes none. (Every shipped
//! scenario, at the recording's level: `snapshot_recording.rs`.)
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::time::Duration;

use csp::SimTime;
use m6p_twin::events::RunEvent;
use m6p_twin::exec::{compile_seeded, load};
use m6p_twin::runtime::build_runtime;
use m6p_twin::runtime::counters::RunSink;
use m6p_twin::runtime::{Resume, RunOptions, Sections, run_with};
use snap::Snap as _;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A run's events as text, and the snapshots it took with how many events came before
/// each.
#[derive(Default)]
struct Collect {
    events: Vec<String>,
    snapshots: Vec<(SimTime, Sections, usize)>,
}

impl RunSink for Collect {
    fn event(&mut self, ev: &RunEvent) {
        self.events.push(format!("{ev:?}"));
    }
    fn contact(&mut self, t: SimTime, on: bool) {
        self.events.push(format!("contact {t} {on}"));
    }
    fn snapshot(&mut self, t: SimTime, _: m6p_twin::runtime::AskedBy, sections: &mut Sections) {
        self.snapshots
            .push((t, std::mem::take(sections), self.events.len()));
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
            sections: state,
            faults: m6p_twin::runtime::FaultsToCome::Saved,
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

/// The sink's part of a snapshot: the report's observers, the expectations' watches and the
/// invariants, saved part way through a run's events and loaded into ones built fresh from
/// the scenario, see the rest of the events and end in the same state, with the same report
/// and the same verdicts, as those that saw every event.
#[test]
fn the_sinks_observers_watches_and_invariants_saved_mid_run_end_the_same() {
    use m6p_twin::expectations::{Watch, WatchCx, check_watched};
    use m6p_twin::invariants::Invariants;
    use m6p_twin::report::observe::{Keep, Observer};

    type Sink = (Observer, Vec<Option<Box<dyn Watch>>>, Invariants);
    let mut watched = 0;
    for name in [
        "default.toml",
        "eps-day.toml",
        "pc-buffering.toml",
        "adcs-nadir.toml",
    ] {
        let loaded = load(&repo().join("scenarios").join(name)).unwrap();
        let compiled = compile_seeded(&loaded, None);
        let mut opts = compiled.opts.clone();
        opts.packet_events = true;
        let mut seen = Vec::new();
        let report = build_runtime()
            .unwrap()
            .block_on(m6p_twin::report::run_with(
                opts.clone(),
                None,
                &mut |ev: &RunEvent| seen.push(ev.clone()),
            ))
            .unwrap();
        let icd = opts.icd_map();
        let cx = WatchCx {
            tle: opts.tle.as_ref(),
            net: Some(&opts.network),
            icd: Some(&icd),
        };
        let fresh = || -> Sink {
            (
                Observer::new(
                    Keep {
                        trace: false,
                        series: true,
                    },
                    opts.tle.as_ref(),
                ),
                compiled.expectations.iter().map(|x| x.watch(&cx)).collect(),
                Invariants::for_run(&opts, &compiled.invariants),
            )
        };
        let feed = |s: &mut Sink, seen: &[RunEvent]| {
            for ev in seen {
                s.0.observe(ev);
                for w in s.1.iter_mut().flatten() {
                    if w.kinds().has(ev.kind()) {
                        w.observe(ev);
                    }
                }
                s.2.observe(ev);
            }
        };
        let save = |s: &Sink| {
            let mut w = snap::Writer::new();
            s.0.save(&mut w);
            s.1.iter().flatten().for_each(|x| x.save(&mut w));
            s.2.save(&mut w);
            w.into_bytes()
        };
        let mid = seen.len() / 2;
        let mut whole = fresh();
        feed(&mut whole, &seen[..mid]);
        let bytes = save(&whole);
        feed(&mut whole, &seen[mid..]);
        let mut resumed = fresh();
        let mut r = snap::Reader::new(&bytes);
        resumed.0.load(&mut r).unwrap();
        for x in resumed.1.iter_mut().flatten() {
            x.load(&mut r).unwrap();
        }
        resumed.2.load(&mut r).unwrap();
        r.finish().unwrap();
        feed(&mut resumed, &seen[mid..]);
        assert!(
            save(&resumed) == save(&whole),
            "{name}: the same state at the end"
        );
        let net = &opts.network;
        assert_eq!(
            check_watched(&compiled.expectations, &resumed.1, &report, net),
            check_watched(&compiled.expectations, &whole.1, &report, net),
            "{name}: the same verdicts"
        );
        assert_eq!(resumed.2.verdicts(&report), whole.2.verdicts(&report));
        assert_eq!(
            format!("{:?}", resumed.0.finish()),
            format!("{:?}", whole.0.finish()),
            "{name}: the same report"
        );
        watched += whole.1.iter().flatten().count();
    }
    assert!(
        watched >= 4,
        "expectations judged as the run goes: {watched}"
    );
}
