//! ADCS acceptance beyond the single-seed scenario runs: the detumble scenario holds for
//! every one of 20 seeds (each seed draws another tumble axis, initial attitude and sensor
//! noise).
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use m6p_twin::exec::{compile_seeded, execute, load};
use m6p_twin::runtime::build_runtime;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Run `scenarios/adcs-detumble.toml` with `seeds`, returning the failures.
fn detumble_failures(seeds: std::ops::RangeInclusive<u64>) -> Vec<String> {
    let loaded = load(&repo().join("scenarios/adcs-detumble.toml")).unwrap();
    let mut failures = Vec::new();
    for seed in seeds {
        // The seed also draws the FC's initial attitude and tumble axis.
        let compiled = compile_seeded(&loaded, Some(seed));
        let rt = build_runtime().unwrap();
        let outcome = rt.block_on(execute(compiled, &mut |_| {})).unwrap();
        for v in outcome.verdicts.iter().filter(|v| !v.passed) {
            failures.push(format!("seed {seed}: {}: {}", v.name, v.observed));
        }
        let axis = outcome.report.attitude_summary.first.map(|a| a.rate_deg_s);
        assert!(
            axis.is_some_and(|r| (r - 10.0).abs() < 0.5),
            "seed {seed}: the run starts at 10 deg/s ({axis:?})"
        );
    }
    failures
}

#[test]
fn detumble_holds_for_20_seeds() {
    // Two threads: the CI machine has two cores.
    let a = std::thread::spawn(|| detumble_failures(1..=10));
    let b = std::thread::spawn(|| detumble_failures(11..=20));
    let mut failures = a.join().unwrap();
    failures.extend(b.join().unwrap());
    assert!(failures.is_empty(), "{failures:#?}");
}
