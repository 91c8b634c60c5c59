//! Payload bytes lost between a payload and the PC are accounted, with where and why:
//! runs of `campaigns/pc-sessions.toml` that failed `every-byte-accounted` because such
//! bytes were in no ledger (tests/data/lost-in-transit/, one per way of losing them).

use std::collections::BTreeSet;
use std::path::Path;

use m6p_twin::exec;

/// Run a scenario of tests/data/lost-in-transit; its verdicts and the reasons payload 12's
/// bytes were dropped for.
fn run(file: &str) -> (exec::Outcome, BTreeSet<String>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/lost-in-transit")
        .join(file);
    let loaded = exec::load(&path).unwrap_or_else(|e| panic!("{e:#}"));
    let compiled = exec::compile_loaded(&loaded);
    let rt = m6p_twin::runtime::build_runtime().unwrap_or_else(|e| panic!("{e:#}"));
    let o = rt
        .block_on(exec::execute(compiled, &mut |_| {}))
        .unwrap_or_else(|e| panic!("{e:#}"));
    let reasons = o
        .report
        .sessions
        .dropped
        .keys()
        .filter(|(a, _)| *a == 12)
        .map(|(_, r)| r.clone())
        .collect();
    (o, reasons)
}

#[track_caller]
fn accounted(file: &str, reasons: &[&str]) {
    let (o, seen) = run(file);
    assert!(o.passed(), "{file}:{}", o.verdict_table());
    for r in reasons {
        assert!(seen.contains(*r), "{file}: no `{r}` in {seen:?}");
    }
}

/// Frames dropped on the payload bus (`drop`, probability 0.34): 17,000 bytes were in no
/// ledger.
#[test]
fn replies_that_lost_a_frame_on_the_bus() {
    accounted(
        "pc-sessions-run-13.toml",
        &["lost on the payload bus (dropped on the bus)"],
    );
}

/// `corrupt` drives the payload bus-off again and again (its queue lost), and the PC's
/// reassembly buffers, full of partial packets, refuse replies whose frames all crossed.
#[test]
fn replies_lost_to_bus_off_and_to_a_full_reassembly() {
    for f in ["pc-sessions-run-4.toml", "pc-sessions-run-123.toml"] {
        accounted(
            f,
            &[
                "lost on the payload bus (sender bus-off)",
                "lost on the payload bus (the receiver's CAN reassembly refused it)",
            ],
        );
    }
}

/// A babbler starves the payload: its transmit queue overflows, and a reply whose last
/// frames waited more than 10 s behind the babble times out in the PC's reassembly.
#[test]
fn replies_lost_behind_a_babbler() {
    accounted(
        "pc-sessions-run-187.toml",
        &[
            "lost on the payload bus (sender's transmit queue full)",
            "lost on the payload bus (the receiver's CAN reassembly timed out)",
        ],
    );
}

/// The PC reboots while a reply's frames are half across: the partial packet goes with the
/// PC's memory, and its bytes are lost there (they were in no ledger).
#[test]
fn a_reply_half_reassembled_when_the_pc_reboots() {
    accounted(
        "pc-sessions-run-216.toml",
        &["lost on the payload bus (the receiver rebooted during its reassembly)"],
    );
}

/// The PC hangs for 95 s; when it comes back it sends every POLL it missed at once, and
/// the payload's replies overflow its transmit queue.
#[test]
fn replies_to_a_burst_of_polls_after_a_hang() {
    accounted(
        "pc-sessions-run-152.toml",
        &["lost on the payload bus (sender's transmit queue full)"],
    );
}

/// The invariants hold on shipped scenarios that send every kind of platform request
/// (telemetry, clock, attitude, EPS, ECU, COMM, PC sessions), and the ICD's reply lengths
/// are really checked there.
#[test]
fn shipped_scenarios_keep_the_invariants_and_their_replies_are_checked() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
    for name in ["fc-ports", "ecu-burn", "pc-polling", "platform-faults"] {
        let loaded =
            exec::load(&root.join(format!("{name}.toml"))).unwrap_or_else(|e| panic!("{e:#}"));
        let compiled = exec::compile_loaded(&loaded);
        let mut inv =
            m6p_twin::invariants::Invariants::for_run(&compiled.opts, &compiled.invariants);
        let rt = m6p_twin::runtime::build_runtime().unwrap_or_else(|e| panic!("{e:#}"));
        let o = rt
            .block_on(exec::execute(compiled, &mut |ev| inv.observe(ev)))
            .unwrap_or_else(|e| panic!("{e:#}"));
        let checked = inv.replies_checked;
        let broken = inv.finish(&o.report);
        assert!(broken.is_empty(), "{name}: {broken:?}");
        let least = if name == "fc-ports" { 50 } else { 4 };
        assert!(checked >= least, "{name}: {checked} replies checked");
        eprintln!("{name}: {checked} replies checked");
    }
}
