//! Packets a node sends on its own never start a loop: the FC's periodic telemetry
//! (TMPERSET) to a port where another node serves requests is answered there once, and
//! that answer is dropped at the FC's own port. From the FC's telemetry port it was read as
//! a TMGEN request and answered, the other node answered that, and so on for ever: the
//! main bus at ~90 % load, outliving TMPERSET off and reboots.
#![allow(clippy::unwrap_used)]

use bus::trace::TraceFrame;
use csp::SimTime;
use m6p_twin::events::RunEvent;
use m6p_twin::exec::execute_keeping;
use m6p_twin::invariants::Invariants;
use m6p_twin::plan::compile;
use m6p_twin::runtime::build_runtime;

/// The targets TMPERSET is pointed at in turn, each on for 5 s from `20 s * k + 5 s`:
/// the PC's control port, the EPS's, COMM1's, the PC's telemetry port, payload 12's.
const TARGETS: [(u8, u8); 5] = [(6, 10), (4, 10), (1, 10), (6, 12), (12, 10)];

fn scenario() -> String {
    let mut text = String::from("name = \"tmperset-targets\"\nduration = \"105s\"\n");
    for (k, (dst, dport)) in TARGETS.iter().enumerate() {
        let on = 20 * k + 5;
        // TMPERSET: to dst:dport every 1000 ms, TMGEN; then period 0 (off).
        text += &format!(
            "[[commands]]\nname = \"on-{k}\"\nat = \"{on}s\"\nto = \"FC\"\nrequest = \"raw\"\nport = 10\ndata = \"07{dst:02x}{dport:02x}e803000001\"\n\n\
             [[commands]]\nname = \"off-{k}\"\nat = \"{}s\"\nto = \"FC\"\nrequest = \"raw\"\nport = 10\ndata = \"0700000000000000\"\n\n",
            on + 5
        );
    }
    text
}

/// TMPERSET to each target for 5 s, then off: in the 10 s after each off fewer than 50
/// frames cross the main bus (its own traffic: the FC's housekeeping, a beacon), and
/// `no-reply-storm` holds over the whole run.
#[test]
fn periodic_telemetry_to_a_serving_port_never_starts_a_loop() {
    let s = m6p_twin::scenario::parse("t.toml", &scenario()).unwrap();
    let compiled = compile(&s);
    let mut invariants = Invariants::for_run(&compiled.opts, &compiled.invariants);
    let rt = build_runtime().unwrap();
    let mut main_frames = Vec::new();
    let out = rt
        .block_on(execute_keeping(compiled, true, &mut |ev| {
            invariants.observe(ev);
            if let RunEvent::Medium(m) = ev
                && &*m.medium == "main"
                && matches!(m.frame, TraceFrame::Can(_) | TraceFrame::CanUnreceived(..))
            {
                main_frames.push(m.t);
            }
        }))
        .unwrap();
    let v = invariants.finish(&out.report);
    println!("invariants: {v:?}");
    for (k, target) in TARGETS.iter().enumerate() {
        let off = SimTime::from_secs(20 * k as u64 + 10);
        let after = main_frames
            .iter()
            .filter(|&&t| t >= off && t < off + std::time::Duration::from_secs(10))
            .count();
        println!("TMPERSET to {target:?}: {after} main-bus frames in the 10 s after off");
        assert!(
            after < 50,
            "TMPERSET to {target:?}: {after} frames on the main bus in the 10 s after it was stopped"
        );
    }
    // Each TMPERSET was accepted.
    let accepted = out
        .report
        .results
        .iter()
        .filter(|r| r.request.label.starts_with("on-") || r.request.label.starts_with("off-"))
        .filter(|r| {
            matches!(&r.outcome, m6p_twin::ground::Outcome::Reply { data, .. } if data[..] == [7, 1])
        })
        .count();
    assert_eq!(accepted, 10);
    assert!(v.is_empty(), "{v:?}");
}
