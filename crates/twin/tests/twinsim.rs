//! TWINSIM (the FC's telemetry port, command 12: the twin's own) in a run: the ground's
//! scenario command gets the simulated time the request reached the FC, the run's seed (the
//! scenario's, or the command line's in its place) and start, and the twin's version; the
//! command is named and marked as the twin's in the ICD the twin prints.
#![allow(clippy::unwrap_used)]

use m6p_twin::events::RunEvent;
use m6p_twin::exec::execute;
use m6p_twin::plan::compile;
use m6p_twin::runtime::build_runtime;
use nodes_fc::wire::{Repr as _, TwinSim};

const SCENARIO: &str = r#"
name = "twinsim"
start = "2026-04-30T18:00:00Z"
duration = "5s"
seed = 77

[[commands]]
name = "twinsim"
at = "2s"
to = "FC"
command = "FC.TWINSIM"
"#;

/// The TWINSIM reply of a run of [`SCENARIO`] with `seed` in place of the scenario's, and
/// when the request went out (ns since the start).
fn twinsim(seed: Option<u64>) -> (TwinSim, u64) {
    let mut s = m6p_twin::scenario::parse("twinsim.toml", SCENARIO).unwrap();
    if let Some(seed) = seed {
        s.seed = seed;
    }
    let compiled = compile(&s);
    let rt = build_runtime().unwrap();
    let mut sent = None;
    let mut reply = None;
    rt.block_on(execute(compiled, &mut |ev| match ev {
        RunEvent::Command { t, name, .. } if name == "twinsim" => sent = Some(t.as_ns()),
        RunEvent::CommandResult(r) if r.name == "twinsim" => {
            reply = r.reply.clone();
        }
        _ => {}
    }))
    .unwrap();
    let reply = reply.expect("TWINSIM answered");
    assert_eq!(reply[..2], [12, 1], "{reply:02x?}");
    (TwinSim::parse(&reply[2..]).unwrap(), sent.unwrap())
}

#[test]
fn twinsim_tells_the_ground_the_runs_time_seed_start_and_version() {
    let (sim, sent_ns) = twinsim(None);
    assert_eq!(sim.seed, 77);
    assert_eq!(sim.start_unix_s, 1_777_572_000, "2026-04-30T18:00:00Z");
    // The request crossed the UHF link and the CAN bus: answered after it was sent, well
    // within a second.
    assert!(
        (sent_ns..sent_ns + 1_000_000_000).contains(&sim.sim_time_ns),
        "sent at {sent_ns} ns, answered at {} ns",
        sim.sim_time_ns
    );
    let version = [sim.version_major, sim.version_minor, sim.version_patch].map(|v| v.to_string());
    assert_eq!(version.join("."), env!("CARGO_PKG_VERSION"));
    // Another seed (as `--seed` gives) is the one reported.
    assert_eq!(twinsim(Some(u64::MAX - 5)).0.seed, u64::MAX - 5);
}

#[test]
fn the_printed_icd_marks_twinsim_as_the_twins_own() {
    let text = m6p_twin::icd::to_text(Some("FC")).unwrap();
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("12 TWINSIM"))
        .unwrap();
    assert!(
        line.contains("(the twin's, refused to payloads): the twin's own, not the spacecraft's"),
        "{line}"
    );
    let json: serde_json::Value = serde_json::from_str(&m6p_twin::icd::to_json()).unwrap();
    let fc = json["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "FC")
        .unwrap();
    let c = fc["ports"][0]["commands"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "TWINSIM")
        .unwrap();
    assert_eq!(
        (c["id"].as_u64(), c["origin"].as_str()),
        (Some(12), Some("twin"))
    );
    assert_eq!(c["access"], "no-payloads");
    assert_eq!(c["reply"]["layout"], "TwinSim");
    assert_eq!(
        (
            c["reply"]["min_bytes"].as_u64(),
            c["reply"]["max_bytes"].as_u64()
        ),
        (Some(27), Some(27))
    );
}
