//! The twin over a real TCP socket: an outside libcsp-style KISS peer (a Python script
//! written from the spec, and the `gs` client) pings nodes through the twin, and garbage on
//! the port is counted without stopping it. These tests run in real time.
#![allow(clippy::unwrap_used)]

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use bus::ClockMode;

#[path = "common/outside.rs"]
mod outside;
use m6p_twin::network::NetworkSpec;
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::{RunOptions, build_runtime};

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Run the twin in real time for `secs` with a KISS server on an ephemeral port, and
/// call `client(addr)` on a thread while it runs.
fn with_twin(secs: u64, client: impl FnOnce(SocketAddr) + Send + 'static) -> RunReport {
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(secs));
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.kiss_links = vec![m6p_twin::runtime::KissLink::listen(
        "127.0.0.1:0".parse().unwrap(),
    )];
    let rt = build_runtime().unwrap();
    rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        let addr = rx.await.unwrap()[0];
        let th = outside::on_thread(move || client(addr));
        th.await.unwrap();
        twin.await.unwrap().unwrap()
    })
}

fn python_peer(addr: SocketAddr, extra: &[&str]) -> (bool, String) {
    let out = Command::new("python3")
        .arg(repo_root().join("tests/kiss_peer.py"))
        .arg("--connect")
        .arg(addr.to_string())
        .args(extra)
        .output()
        .expect("python3 is needed for this test");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn libcsp_style_python_peer_pings_fc_and_payload_from_the_ground() {
    let report = with_twin(12, |addr| {
        let (ok, text) = python_peer(addr, &["--as", "17", "--targets", "3,12"]);
        println!("{text}");
        assert!(ok, "{text}");
        assert_eq!(text.matches("PASS").count(), 12, "{text}");
    });
    assert_eq!(report.kiss[0].1.bad_crc, 0);
    assert!(report.kiss[0].1.packets_in >= 12);
}

#[test]
fn python_peer_on_the_payload_bus_reaches_the_fc_through_the_pc() {
    // Longer than the ground's: the FC and the PC leave a payload's ident unanswered (ICD
    // 4.1), and the peer waits out 3 s for each.
    let report = with_twin(14, |addr| {
        let (ok, text) = python_peer(addr, &["--as", "14", "--targets", "3,6"]);
        println!("{text}");
        assert!(ok, "{text}");
    });
    // Through the PC: the six requests to the FC (four pings, uptime, ident) and the five
    // replies (the ident is dropped unanswered, as the PC drops its own).
    let pc = report.nodes.iter().find(|n| n.name == "PC").unwrap();
    assert!(pc.counters.forwarded >= 11, "{:?}", pc.counters);
    assert_eq!(
        pc.counters.drops.get(&csp::drop::DropReason::PayloadCmp),
        Some(&1)
    );
}

/// `m6p-twin gs --connect ADDR ping 3 ARGS...`: its standard output, after asserting it
/// succeeded.
fn gs_ping_fc(addr: SocketAddr, args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(["gs", "--connect", &addr.to_string(), "ping", "3"])
        .args(args)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{text}");
    text
}

#[test]
fn gs_client_binary_pings_the_fc_over_a_real_socket() {
    with_twin(6, |addr| {
        let text = gs_ping_fc(addr, &["--count", "2", "--interval", "100ms"]);
        assert!(text.contains("2 sent, 2 answered"), "{text}");
    });
}

/// Issue 19: `gs NODE COMMAND [NAME=VALUE ...]` sends any ICD command by name and prints
/// the reply decoded with units and value names; arguments outside the ICD's range, a
/// ground address that is not one, and a ping larger than a packet are refused before
/// anything is sent.
#[test]
fn gs_sends_icd_commands_by_name_and_decodes_the_replies() {
    let gs = |addr: SocketAddr, args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
            .args(["gs", "--connect", &addr.to_string(), "--timeout", "4s"])
            .args(args)
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned()
                + &String::from_utf8_lossy(&out.stderr),
        )
    };
    with_twin(8, move |addr| {
        let (ok, text) = gs(addr, &["fc", "tmgen"]);
        assert!(ok, "{text}");
        assert!(text.starts_with("FC.TMGEN from 3: ok, 16 bytes"), "{text}");
        assert!(
            text.contains("current_state                        0 (nominal)"),
            "{text}"
        );
        let (ok, text) = gs(addr, &["eps", "tmeps"]);
        assert!(
            ok && text.contains("battery_v") && text.contains(" V\n"),
            "{text}"
        );
        let (ok, text) = gs(addr, &["fc", "atcmdset", "mode=nadir"]);
        assert!(ok, "{text}");
        let (ok, text) = gs(addr, &["fc", "atcmdget"]);
        assert!(
            ok && text.contains("mode                                 3 (nadir)"),
            "{text}"
        );
        let (ok, text) = gs(
            addr,
            &[
                "pc",
                "setup",
                "session_id=1",
                "timestamp=now",
                "duration_s=1000",
                "max_packets=0",
                "poll_frame_size=200",
            ],
        );
        assert!(
            !ok && text.contains("SETUP.duration_s: 1000 is outside the ICD's range 5..=900"),
            "{text}"
        );
        let (ok, text) = gs(addr, &["setup", "1", "--frame", "300"]);
        assert!(
            !ok && text.contains("--frame: 300 is outside the ICD's range 1..=254"),
            "{text}"
        );
        let (ok, text) = gs(addr, &["--as", "40", "fc", "tmgen"]);
        assert!(!ok && text.contains("0..=30"), "{text}");
        let (ok, text) = gs(addr, &["ping", "3", "--size", "300", "--count", "1"]);
        assert!(!ok && text.contains("at most 256 bytes"), "{text}");
        let (ok, text) = gs(addr, &["fc", "nope"]);
        assert!(!ok && text.contains("TMGEN, TMATP"), "{text}");
    });
}

#[test]
fn thirty_seconds_of_random_bytes_then_pings_still_answered() {
    let report = with_twin(45, |addr| {
        let (ok, text) = python_peer(addr, &["--garbage", "30", "--targets", "3"]);
        println!("{text}");
        assert!(ok, "{text}");
    });
    let k = &report.kiss[0].1;
    println!("{k:?}");
    assert!(k.connections >= 2);
    assert!(k.garbage_bytes + k.bad_crc + k.short + k.oversize > 0);
    assert!(k.bytes_in > 1_000_000, "{k:?}");
}

#[test]
fn kiss_connect_reaches_the_payload_server_and_reconnects_after_a_drop() {
    use csp::kiss::{Decoder, KissEvent};
    use csp::{Header, Packet};
    use std::io::{Read, Write};
    // ICD 2.3: the payload runs the TCP server, the platform connects to it.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let server = listener.local_addr().unwrap();
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(6));
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.kiss_links = vec![m6p_twin::runtime::KissLink::connect(server)];
    let rt = build_runtime().unwrap();
    let report = rt.block_on(async move {
        let twin = tokio::spawn(run(opts, None));
        let outside = outside::on_thread(move || {
            for round in 0..2u8 {
                let (mut s, _) = listener.accept().unwrap();
                s.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
                let ping = Packet::new(Header::new(14, 3, 1, 40 + round), vec![round, 0xc0, 0xdb]);
                let mut wire = Vec::new();
                csp::kiss::encode(&ping, &mut wire);
                s.write_all(&wire).unwrap();
                let mut dec = Decoder::default();
                let mut events = Vec::new();
                let mut buf = [0u8; 512];
                let reply = loop {
                    let n = s.read(&mut buf).expect("a reply within 3 s");
                    assert!(n > 0, "twin closed the connection");
                    dec.push(&buf[..n], &mut events);
                    if let Some(KissEvent::Packet(p)) = events.pop() {
                        break p;
                    }
                };
                assert_eq!(reply.header, Header::new(3, 14, 40 + round, 1));
                assert_eq!(reply.data, ping.data);
                // Dropping the stream closes the connection; the twin must come back.
            }
        });
        outside.await.unwrap();
        twin.await.unwrap().unwrap()
    });
    let k = &report.kiss[0].1;
    assert!(k.connections >= 2 && k.disconnects >= 1, "{k:?}");
    assert_eq!(k.packets_in, 2);
}

/// An outside ground program's address is its own only while it is connected: after it
/// leaves, another program can claim it (the claims were once not given back when the peer
/// closed first), and the twin's own GS16 is answered throughout.
#[test]
fn a_departed_outside_program_gives_its_address_back() {
    use m6p_twin::ground::{Outcome, PlannedRequest, ping_payload};
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(5));
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.kiss_links = vec![m6p_twin::runtime::KissLink::listen(
        "127.0.0.1:0".parse().unwrap(),
    )];
    opts.ground_plan.insert(
        16,
        vec![
            PlannedRequest {
                at: csp::SimTime::from_secs(4),
                dst: 3,
                dport: 1,
                data: ping_payload(8),
                timeout: Duration::from_millis(900),
                label: "after".into(),
                after: None,
            }
            .into(),
        ],
    );
    let rt = build_runtime().unwrap();
    let report = rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        let addr = rx.await.unwrap()[0];
        let gs = outside::on_thread(move || {
            (0..2)
                .map(|_| {
                    Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
                        .args([
                            "gs",
                            "--connect",
                            &addr.to_string(),
                            "ping",
                            "3",
                            "--count",
                            "1",
                        ])
                        .output()
                        .unwrap()
                })
                .collect::<Vec<_>>()
        });
        for out in gs.await.unwrap() {
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
        twin.await.unwrap().unwrap()
    });
    assert_eq!(report.results.len(), 1);
    assert!(
        matches!(report.results[0].outcome, Outcome::Reply { .. }),
        "{:?}",
        report.results[0].outcome
    );
}

/// Issue 19: `gs --connect ADDR` without a request is the console. On a terminal (a pty
/// here, typed into by tests/pty_console.py) Tab completes commands and value names from
/// the ICD and the lines go to the history file; from a pipe it takes one request per
/// line, echoes each, answers a bad line with one `error:` line and goes on, and exits 1
/// when a line was refused.
#[test]
fn the_gs_console_completes_remembers_and_takes_scripts() {
    with_twin(12, move |addr| {
        let dir = std::env::temp_dir().join(format!("m6p-gs-console-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let history = dir.join("history");
        let out = Command::new("python3")
            .arg(repo_root().join("tests/pty_console.py"))
            .args([
                r"fc tmg\t\r",
                r"fc atcmdset mode=velocity_p\t\r",
                r"fc atcmdget\r",
                r"\x04",
            ])
            .arg("--")
            .arg(env!("CARGO_BIN_EXE_m6p-twin"))
            .args(["gs", "--connect", &addr.to_string(), "--timeout", "4s"])
            .env("M6P_GS_HISTORY", &history)
            .output()
            .expect("python3 is needed for this test");
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(out.status.success(), "{text}");
        assert!(text.contains("FC.TMGEN from 3: ok, 16 bytes"), "{text}");
        assert!(text.contains("FC.ATCMDSET from 3: ok"), "{text}");
        assert!(text.contains("2 (velocity pointing)"), "{text}");
        let saved = std::fs::read_to_string(&history).unwrap();
        assert!(
            saved.contains("fc tmgen\nfc atcmdset mode=velocity_pointing\nfc atcmdget"),
            "{saved}"
        );

        let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
            .args(["gs", "--connect", &addr.to_string(), "--timeout", "4s"])
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        use std::io::Write as _;
        child
            .stdin
            .take()
            .unwrap()
            .write_all(b"eps tmeps\nfc atcmdset mode=sideways\nping fc 64\nquit\nfc tmgen\n")
            .unwrap();
        let out = child.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        assert_eq!(out.status.code(), Some(1), "{text}");
        assert!(
            text.starts_with("> eps tmeps\nEPS.TMEPS from 4: ok, 88 bytes"),
            "{text}"
        );
        assert!(
            text.contains(
                "> fc atcmdset mode=sideways\nerror: ATCMDSET.mode: `sideways` is not a number"
            ),
            "{text}"
        );
        assert!(text.contains("reply from 3: seq=1 size=64"), "{text}");
        assert!(!text.contains("FC.TMGEN"), "nothing after quit: {text}");
        std::fs::remove_dir_all(&dir).ok();
    });
}
