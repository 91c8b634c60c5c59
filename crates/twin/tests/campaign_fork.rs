//! A campaign's fork (docs/campaigns.md, "Forking"): runs that share their prefix start
//! from its snapshot and give the rows, and `results.csv`, of the runs from the start; the
//! fork's instant is found from the runs, and a campaign whose runs differ earlier does not
//! fork, saying why.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;

use m6p_twin::campaign::Campaign;
use m6p_twin::campaign_fork::{self, NoFork};
use m6p_twin::campaign_run::{results_csv, run_all, run_all_from};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The catalogue's entries kept in a node's configuration rather than on the run's fault
/// timeline: the FC's sensor and wheel faults, the EPS's panel and battery faults.
const IN_A_NODES_CONFIGURATION: [&str; 3] = [
    "into = \"fc.faults\"",
    "kind = \"panel-loss\"",
    "kind = \"battery-fade\"",
];

/// The shipped fault catalogue (`campaigns/fault-catalogue.toml`), `runs` runs, with one
/// scenario seed for all and every drawn fault starting between 30 s and 60 s (in the PC session of 10-70 s) (the
/// entries kept in a node's configuration left out unless `every_kind`).
fn catalogue(runs: u64, every_kind: bool) -> Campaign {
    let text = std::fs::read_to_string(repo().join("campaigns/fault-catalogue.toml")).unwrap();
    let text = text
        .replace(
            "runs = 1000\n",
            &format!("runs = {runs}\nrun_seeds = \"shared\"\n"),
        )
        .replace("[\"15s\", \"120s\"]", "[\"30s\", \"60s\"]")
        .replace("[\"15s\", \"150s\"]", "[\"30s\", \"60s\"]");
    assert!(!text.contains("\"15s\""), "every draw moved");
    let mut blocks = text.split("[[faults.catalogue]]\n");
    let mut kept = blocks.next().unwrap().to_owned();
    for b in blocks {
        if every_kind || !IN_A_NODES_CONFIGURATION.iter().any(|k| b.contains(k)) {
            kept.push_str("[[faults.catalogue]]\n");
            kept.push_str(b);
        }
    }
    Campaign::parse("fork.toml", &kept).unwrap()
}

#[test]
fn runs_from_the_fork_are_the_runs_from_the_start() {
    let c = catalogue(12, false);
    let runs: Vec<u64> = (0..12).collect();
    let at = campaign_fork::plan(&c, &runs).unwrap().unwrap();
    assert!(
        at >= csp::SimTime::from_secs(29) && at < csp::SimTime::from_secs(60),
        "forks just before the earliest drawn fault: {at}"
    );
    let fork = campaign_fork::take(&c, 0, at).unwrap();
    let forked = run_all_from(&c, &runs, 2, Some(&fork), &|_| {});
    let whole = run_all(&c, &runs, 2, &|_| {});
    let (a, b) = (results_csv(&forked), results_csv(&whole));
    assert!(a == b, "results.csv differs:\n{a}\n---\n{b}");
    // The runs drew different faults, and the faults acted: their figures differ.
    let texts: std::collections::BTreeSet<_> = whole.iter().map(|r| r.scenario.clone()).collect();
    assert_eq!(texts.len(), 12);
    let figures: std::collections::BTreeSet<String> =
        whole.iter().map(|r| format!("{:?}", r.metrics)).collect();
    assert!(figures.len() > 6, "{a}");
    // A fork_at before the found instant is taken; after it, refused naming both.
    let mut early = c.clone();
    early.spec.fork_at = Some(twin_scenario::scenario::Dur(
        std::time::Duration::from_secs(20),
    ));
    assert_eq!(
        campaign_fork::plan(&early, &runs).unwrap(),
        Ok(csp::SimTime::from_secs(20))
    );
    let mut late = c;
    late.spec.fork_at = Some(twin_scenario::scenario::Dur(
        std::time::Duration::from_secs(150),
    ));
    let e = campaign_fork::plan(&late, &runs).unwrap_err().to_string();
    assert!(
        e.contains("fork_at = 150s: run ") && e.contains("fork_at must be before it"),
        "{e}"
    );
}

#[test]
fn runs_that_differ_earlier_do_not_fork_and_say_why() {
    let runs: Vec<u64> = (0..12).collect();
    // Some faults are in a node's configuration: the runs differ from the start.
    let c = catalogue(12, true);
    assert!(matches!(
        campaign_fork::plan(&c, &runs).unwrap(),
        Err(NoFork::Differs { first: 0, .. })
    ));
    // The shipped campaign: a seed per run.
    let c = Campaign::load(&repo().join("campaigns/fault-catalogue.toml")).unwrap();
    assert_eq!(
        campaign_fork::plan(&c, &runs).unwrap(),
        Err(NoFork::SeedsPerRun)
    );
}
