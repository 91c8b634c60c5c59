//! `m6p-twin gs` and the PC (issue 42): a refused request prints the PC's reason, which `gs`
//! asks with WHY (control port, command 4: the twin's own), on every path that sends a PC
//! command (`setup`, `status`, `abort`, a command by name, the console); and `gs
//! setup|status|abort` print a reply as the command by name prints it.
#![allow(clippy::unwrap_used)]

use std::io::Write;
use std::net::SocketAddr;
use std::process::{Command, Stdio};

mod common;

use common::twin_process::{Twin, output_text, twin_bin};

/// The default scenario's start (2026-04-30T18:00:00Z), unix seconds: the PC's clock then.
const START_UNIX_S: u32 = 1_777_572_000;

/// `m6p-twin gs --connect addr ARGS`: success and what it printed.
fn gs(addr: SocketAddr, args: &[&str]) -> (bool, String) {
    let out = Command::new(twin_bin())
        .args(["gs", "--connect", &addr.to_string(), "--timeout", "4s"])
        .args(args)
        .output()
        .unwrap();
    (out.status.success(), output_text(&out))
}

/// The default scenario (session 1 for payload 12, session 2 for payload 13), in real time
/// with a KISS server.
fn twin() -> (Twin, SocketAddr) {
    let twin = Twin::start(
        &[
            "--realtime",
            "--no-checks",
            "--duration",
            "60s",
            "--kiss-listen",
            "127.0.0.1:0",
        ],
        1,
    );
    let addr = twin.addrs[0];
    (twin, addr)
}

fn assert_reason(ok: bool, text: &str, head: &str) {
    assert!(!ok, "a refusal is a failure\n{text}");
    assert!(
        text.starts_with(head) && text.contains(" (result 0) ("),
        "wanted `{head} (result 0) (.. ms)`\n{text}"
    );
    assert!(!text.contains("the reason is in the run log"), "{text}");
}

#[test]
fn gs_prints_the_pcs_reason_for_a_refusal_and_replies_as_by_name() {
    let (twin, addr) = twin();
    // A session that is not configured.
    let (ok, text) = gs(addr, &["setup", "9"]);
    assert_reason(
        ok,
        &text,
        "PC.SETUP from 6: refused: no session 9 is configured",
    );
    // Session 1 an hour ahead, then session 2 in its window.
    let at = |s: u32| (START_UNIX_S + s).to_string();
    let (ok, text) = gs(addr, &["setup", "1", "--start", &at(3600)]);
    assert!(ok, "{text}");
    assert!(text.starts_with("PC.SETUP from 6: ok, 0 bytes ("), "{text}");
    let (ok, text) = gs(addr, &["setup", "2", "--start", &at(3630)]);
    assert_reason(
        ok,
        &text,
        "PC.SETUP from 6: refused: window overlaps session 1",
    );
    // STATUS as `gs pc status session_id=1` prints it: a head line, then a field a line.
    let (ok, text) = gs(addr, &["status", "1"]);
    assert!(ok, "{text}");
    let lines: Vec<&str> = text.lines().collect();
    assert!(
        lines[0].starts_with("PC.STATUS from 6: ok, 11 bytes ("),
        "{text}"
    );
    assert!(
        text.contains("\n  state                                1 (PENDING)\n"),
        "{text}"
    );
    assert!(!text.contains("STATUS: state"), "{text}");
    let (ok, by_name) = gs(addr, &["pc", "status", "session_id=1"]);
    assert!(ok, "{by_name}");
    let fields = |t: &str| t.lines().skip(1).map(str::to_owned).collect::<Vec<_>>();
    assert_eq!(fields(&text), fields(&by_name));
    // ABORT of a session that is not running.
    let (ok, text) = gs(addr, &["abort", "2"]);
    assert_reason(
        ok,
        &text,
        "PC.ABORT from 6: refused: session 2 is NOT ACTIVE",
    );
    // A command by name, and the console (its lines from standard input).
    let (ok, text) = gs(
        addr,
        &[
            "pc",
            "setup",
            "session_id=9",
            "timestamp=now",
            "duration_s=10",
            "max_packets=0",
            "poll_frame_size=64",
        ],
    );
    assert_reason(
        ok,
        &text,
        "PC.SETUP from 6: refused: no session 9 is configured",
    );
    let mut console = Command::new(twin_bin())
        .args(["gs", "--connect", &addr.to_string(), "--timeout", "4s"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    console
        .stdin
        .take()
        .unwrap()
        .write_all(b"pc status session_id=7\n")
        .unwrap();
    let out = console.wait_with_output().unwrap();
    let text = output_text(&out);
    assert!(
        text.contains("PC.STATUS from 6: refused: no session 7 is configured (result 0) ("),
        "{text}"
    );
    assert!(!text.contains("the reason is in the run log"), "{text}");
    // Another node's refusal keeps its words: the FC has no WHY (TMPERSET to the FC's own
    // address is refused).
    let (ok, text) = gs(
        addr,
        &[
            "fc",
            "tmperset",
            "dst=3",
            "dport=10",
            "period_ms=1000",
            "mask=1",
        ],
    );
    assert!(
        !ok && text
            .starts_with("FC.TMPERSET from 3: refused (result 0; the reason is in the run log"),
        "{text}"
    );
    let _ = twin.finish_now();
}

/// WHY in the ICD the twin prints: on the PC's control port, the twin's own, open to
/// payloads, its reply a 5-byte head and at most 64 bytes of text.
#[test]
fn the_printed_icd_marks_why_as_the_twins_own() {
    let text = m6p_twin::icd::to_text(Some("PC")).unwrap();
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("4 WHY"))
        .unwrap();
    assert!(
        line.contains("(the twin's): the twin's own, not the spacecraft's"),
        "{line}"
    );
    let json: serde_json::Value = serde_json::from_str(&m6p_twin::icd::to_json()).unwrap();
    let pc = json["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == "PC")
        .unwrap();
    let c = pc["ports"][0]["commands"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "WHY")
        .unwrap();
    assert_eq!(
        (c["id"].as_u64(), c["origin"].as_str(), c["access"].as_str()),
        (Some(4), Some("twin"), Some("any"))
    );
    assert_eq!(pc["ports"][0]["port"], 10);
    assert_eq!(c["reply"]["layout"], "WhyHead");
    assert_eq!(
        (
            c["reply"]["min_bytes"].as_u64(),
            c["reply"]["max_bytes"].as_u64()
        ),
        (Some(5), Some(5 + 64))
    );
}
