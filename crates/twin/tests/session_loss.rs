//! A session run lost with the PC's memory (power loss, reboot) ends there: the invariants
//! see one ACTIVE session at a time when the same session is set up again, and the session
//! expectation counts the lost run and names it. A lost run left ACTIVE in the observer's
//! books would fail `one-active-session` at the next SETUP of the same session, and
//! `session_result = "done"` would not see the lost run at all.
#![allow(clippy::unwrap_used)]

use m6p_twin::campaign::Campaign;
use m6p_twin::campaign_run::{RunVerdict, run_all};
use m6p_twin::exec::execute_keeping;
use m6p_twin::invariants::Invariants;
use m6p_twin::plan::compile;
use m6p_twin::runtime::build_runtime;

const CAMPAIGN: &str = include_str!("data/campaign-pc-power-cycle.toml");

/// The campaign's scenario with the power off from 30 s, and a session expectation that
/// every run of session 1 ends DONE.
fn scenario() -> String {
    let base = CAMPAIGN
        .split_once("[scenario]\n")
        .unwrap()
        .1
        .replace("[[scenario.", "[[");
    format!(
        "{base}\n[[expectations]]\nname = \"every-run-done\"\nkind = \"session\"\nsession = 1\nsession_result = \"done\"\n"
    )
}

#[test]
fn a_run_lost_to_a_pc_power_cycle_is_counted_named_and_ends_the_active_session() {
    let s = m6p_twin::scenario::parse("pc-power-cycle.toml", &scenario()).unwrap();
    let compiled = compile(&s);
    let mut invariants = Invariants::for_run(&compiled.opts, &compiled.invariants);
    let rt = build_runtime().unwrap();
    let out = rt
        .block_on(execute_keeping(compiled, true, &mut |ev| {
            invariants.observe(ev)
        }))
        .unwrap();
    let v = invariants.finish(&out.report);
    assert!(v.is_empty(), "{v:?}");
    let by_name = |n: &str| out.verdicts.iter().find(|v| v.name == n).unwrap();
    assert!(by_name("both-setups-accepted").passed);
    assert!(
        by_name("a-run-is-done").passed,
        "{}",
        by_name("a-run-is-done").observed
    );
    let every = by_name("every-run-done");
    assert!(!every.passed);
    assert!(
        every
            .observed
            .starts_with("1 of 2 runs held: run 1 lost (power) at 30.000000000s after ")
            && every
                .observed
                .contains("(lost (power), expected done); run 2 done at "),
        "{}",
        every.observed
    );
}

/// A hundred runs, the power going at an instant drawn from 20 s to 40 s: every run passes,
/// its invariants included.
#[test]
fn a_pc_power_cycle_campaign_holds_one_active_session_in_every_run() {
    let c = Campaign::parse("campaign-pc-power-cycle.toml", CAMPAIGN).unwrap();
    let runs: Vec<u64> = (0..100).collect();
    let rows = run_all(&c, &runs, 2, &|_| {});
    let failed: Vec<_> = rows
        .iter()
        .filter(|r| r.verdict != RunVerdict::Pass)
        .collect();
    assert!(
        failed.is_empty(),
        "{} of 100 runs failed; first: {:?}",
        failed.len(),
        failed.first().map(|r| (&r.draws, &r.verdict))
    );
}
