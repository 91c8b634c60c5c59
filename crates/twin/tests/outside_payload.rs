//! A payload outside the twin: `examples/outside_payload.py`, plain Python speaking KISS and
//! CSP 1.4 from the spec, joins a real-time run as payload 12 over KISS/TCP and serves a
//! whole polling session driven by the twin (SETUP from the ground station, SYNC, 25 POLLs,
//! S-band downlink). The scenario is the one `examples/README.md` tells users to run, taken
//! from that file so the two cannot drift apart. What reached the ground must be, byte for
//! byte, what the script logged as sent and the stream its `frame_data` defines.
//!
//! Real time: about 8 s of wall clock.
#![allow(clippy::unwrap_used)]

use std::process::Command;

use m6p_twin::expectations::check_all;
use m6p_twin::plan::compile;
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::build_runtime;

mod common;

use common::{expected_stream, readme_scenario, repo_root, same_bytes};

#[test]
fn python_payload_over_kiss_serves_a_polling_session_and_its_bytes_reach_the_ground() {
    let scenario = m6p_twin::scenario::parse("examples/README.md", &readme_scenario()).unwrap();
    let compiled = compile(&scenario);
    let mut opts = compiled.opts;
    // The README's link claims CSP 12 before the payload has sent anything; here it listens
    // on an ephemeral port instead of 52001.
    assert_eq!(opts.kiss_links.len(), 1);
    assert_eq!(opts.kiss_links[0].cfg.addrs, vec![12]);
    opts.kiss_links[0].mode = m6p_twin::runtime::KissMode::Listen("127.0.0.1:0".parse().unwrap());
    assert!(matches!(opts.clock, bus::ClockMode::Realtime { .. }));

    let dir = std::env::temp_dir().join(format!("m6p-outside-payload-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sent_path = dir.join("sent.bin");
    let sent_arg = sent_path.clone();

    let rt = build_runtime().unwrap();
    let (report, (status, output)): (RunReport, _) = rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        let addr = rx.await.unwrap()[0];
        // The script stops 1.5 s after the last POLL. `--seconds` only bounds a failing
        // run: the twin's socket stays open until this runtime is dropped, after the script.
        let payload = common::outside::on_thread(move || {
            let out = Command::new("python3")
                .arg(repo_root().join("examples/outside_payload.py"))
                .args(["--connect", &addr.to_string(), "--sent"])
                .arg(&sent_arg)
                .args(["--idle", "1.5", "--seconds", "12", "--wait", "5"])
                .output()
                .expect("python3 is needed for this test");
            let text = format!(
                "{}{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
            (out.status, text)
        });
        let py = payload.await.unwrap();
        (twin.await.unwrap().unwrap(), py)
    });
    println!("{output}");

    // The script served one session and ended on its own.
    assert!(
        status.success(),
        "the payload exited with {status}:\n{output}"
    );
    assert!(
        output.contains("1 SYNC, 25 POLL, 3416 data bytes sent, 0 refused, 0 damaged frames"),
        "{output}"
    );
    assert!(
        output.contains("SYNC b'hello from the PC': acknowledged"),
        "{output}"
    );
    let sent = std::fs::read(&sent_path).unwrap();
    same_bytes(
        "the script's log",
        &sent,
        "frame_data's stream",
        &expected_stream(25, 200),
    );

    // The PC ran the session to DONE after 25 packets (maxNumOfPackets).
    common::assert_one_session_done(&report, 1, 25);

    // What reached the ground is exactly what the payload sent: nothing dropped, nothing
    // still held by the PC, nothing else mixed in.
    let down = report.sessions.session_bytes(1);
    same_bytes("downlinked", &down, "sent by the payload", &sent);
    assert_eq!(
        report.sessions.dropped_total(12),
        0,
        "{:?}",
        report.sessions.dropped
    );
    let held = report
        .sessions
        .held
        .as_ref()
        .expect("the PC's final accounting");
    assert_eq!(held.get(&12).copied().unwrap_or(0), 0, "{held:?}");
    assert_eq!(report.sessions.pc_balanced, Some(true));

    // The KISS link: one connection, the SYNC reply and 25 POLL replies, all intact.
    let (_, k) = &report.kiss[0];
    assert_eq!(k.connections, 1, "{k:?}");
    assert_eq!(k.packets_in, 26, "{k:?}");
    assert_eq!(
        (k.bad_crc, k.short, k.oversize, k.refused, k.garbage_bytes),
        (0, 0, 0, 0, 0),
        "{k:?}"
    );

    // And the README's own expectations.
    let net = m6p_twin::network::NetworkSpec::default_m6p();
    let verdicts = check_all(&compiled.expectations, &report, &net);
    assert_eq!(verdicts.len(), 3);
    for v in &verdicts {
        assert!(v.passed, "{} failed: {}", v.name, v.observed);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn expected_stream_matches_the_documented_sizes() {
    // 9 full frames of 200, 8 of 134 and 8 of 68 (the README's downlink expectation).
    let s = expected_stream(25, 200);
    assert_eq!(s.len(), 9 * 200 + 8 * 134 + 8 * 68);
    assert_eq!(&s[..4], &[0, 0, 0, 1]);
    // Frame 1 starts after frame 0's 200 bytes: seq 1 LE, then the counter from 1 cut to
    // 134 bytes.
    assert_eq!(&s[200..204], &[1, 0, 1, 2]);
    // The KISS special bytes occur in the data, so the framing's escapes are exercised.
    assert!(s.contains(&0xc0) && s.contains(&0xdb));
}
