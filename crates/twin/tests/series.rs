//! A run judged as it goes keeps no per-sample data: `exec::execute` leaves the report's
//! attitude and power samples, the sessions' bytes and the ground requests' outcomes
//! empty, and its verdicts, campaign
//! metrics and invariants are those of the same run judged on a report that kept them all
//! (`RunOptions::keep_series`, as `runtime::run` does by default).
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use m6p_twin::campaign_run::metrics;
use m6p_twin::exec::{compile_seeded, execute, load};
use m6p_twin::expectations::check_all;
use m6p_twin::invariants::Invariants;
use m6p_twin::report::{RunReport, run_with};
use m6p_twin::runtime::build_runtime;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The campaign metrics as they were computed from the kept samples.
fn metrics_from_samples(r: &RunReport) -> Vec<(&'static str, f64)> {
    let mut m = Vec::new();
    if let Some(min) = r.power.iter().map(|p| p.soc).reduce(f64::min) {
        m.push(("min_soc", min));
    }
    if let Some(max) = r.attitude.iter().map(|a| a.rate_deg_s).reduce(f64::max) {
        m.push(("max_rate_deg_s", max));
        if r.attitude.first().is_some_and(|a| a.rate_deg_s >= 0.5)
            && let Some(a) = r.attitude.iter().find(|a| a.rate_deg_s < 0.5)
        {
            m.push(("detumble_s", a.t.as_secs_f64()));
        }
    }
    m
}

#[test]
fn a_run_judged_as_it_goes_keeps_no_samples_and_says_the_same() {
    let loaded = load(&repo().join("crates/twin/tests/data/judged-as-it-goes.toml")).unwrap();
    let compiled = compile_seeded(&loaded, None);
    assert!(
        compiled.opts.keep_series,
        "runtime::run keeps them by default"
    );

    // Judged on the kept samples and bytes.
    let rt = build_runtime().unwrap();
    let mut inv = Invariants::for_run(&compiled.opts, &compiled.invariants);
    let kept = rt
        .block_on(run_with(
            compiled.opts.clone(),
            None,
            &mut |ev: &m6p_twin::events::RunEvent| inv.observe(ev),
        ))
        .unwrap();
    let kept_broken = inv.finish(&kept);
    let kept_verdicts = check_all(&compiled.expectations, &kept, &compiled.opts.network);

    // Judged as it goes.
    let rt = build_runtime().unwrap();
    let mut inv = Invariants::for_run(&compiled.opts, &compiled.invariants);
    let expectations = compiled.expectations.clone();
    let outcome = rt
        .block_on(execute(compiled, &mut |ev| inv.observe(ev)))
        .unwrap();
    let broken = inv.finish(&outcome.report);
    let r = &outcome.report;

    // Nothing per sample or per byte is left.
    assert!(
        r.attitude.is_empty(),
        "{} attitude samples",
        r.attitude.len()
    );
    assert!(r.power.is_empty(), "{} power samples", r.power.len());
    assert!(r.sessions.runs.iter().all(|x| x.bytes.is_empty()));
    assert!(r.sessions.session_bytes(1).is_empty());
    assert!(r.results.is_empty(), "{} request outcomes", r.results.len());

    // The same run: what was kept is what was summed up.
    assert_eq!(kept.attitude.len(), 5400, "one sample a second");
    assert_eq!(r.attitude_summary, kept.attitude_summary);
    assert_eq!(r.attitude_summary.samples, kept.attitude.len() as u64);
    assert_eq!(r.attitude_summary.first, kept.attitude.first().copied());
    assert_eq!(r.requests, kept.requests);
    assert_eq!(kept.requests.requests, kept.results.len() as u64);
    assert_eq!(
        (
            kept.requests.requests,
            kept.requests.answered,
            kept.requests.unfinished
        ),
        (84, 19, 1),
        "replies, timeouts, requests not sent and one the run ended on"
    );
    assert_eq!(r.power_summary, kept.power_summary);
    assert_eq!(r.power_summary.samples, kept.power.len() as u64);
    assert!(kept.power.len() > 5000);
    assert_eq!(r.sessions.runs.len(), kept.sessions.runs.len());
    assert_eq!(r.sessions.runs.len(), 4, "two runs of each session");
    for (a, b) in r.sessions.runs.iter().zip(&kept.sessions.runs) {
        assert!(b.len > 0);
        assert_eq!(a.len, b.len);
        assert_eq!(b.len, b.bytes.len() as u64);
        assert_eq!(a.stream, b.stream);
        // The check made piece by piece is the check of the kept bytes.
        let end = b.stream.end();
        assert_eq!(end.check, nodes_payload::check_counter_stream(&b.bytes));
    }

    // Every verdict word for word, with its time; so are the metrics and invariants.
    assert_eq!(outcome.verdicts.len(), expectations.len());
    for (a, b) in outcome.verdicts.iter().zip(&kept_verdicts) {
        assert_eq!(
            (&a.name, a.passed, a.t, &a.observed),
            (&b.name, b.passed, b.t, &b.observed)
        );
    }
    // Both ways of passing and failing are covered.
    assert_eq!(outcome.verdicts.iter().filter(|v| v.passed).count(), 13);
    let m = metrics(r);
    assert_eq!(m, metrics(&kept));
    let old: Vec<(String, f64)> = metrics_from_samples(&kept)
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect();
    for (k, v) in &old {
        assert_eq!(m.get(k), Some(v), "{k}");
    }
    assert!(
        m.contains_key("detumble_s") && m.contains_key("min_soc"),
        "{m:?}"
    );
    assert_eq!(broken, kept_broken);
}
