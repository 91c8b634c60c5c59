//! The run's control channel (`run --control`, `gs --control`): faults injected into a
//! real-time run while it goes on, at instants the run defines, recorded on `/control` and
//! `/faults`, and reproduced by `replay`.
#![allow(clippy::unwrap_used)]

mod common;

use common::on;
use common::twin_process::{Twin, output_text, test_dir, twin};

/// `gs --control ADDR ARGS...`: (exit success, stdout and stderr).
fn gs(addr: &str, args: &[&str]) -> (bool, String) {
    let o = twin()
        .args(["gs", "--control", addr])
        .args(args)
        .output()
        .unwrap();
    (o.status.success(), output_text(&o))
}

/// The snapshot file a reply to `gs snapshot` names.
fn snapshot_named(said: &str) -> String {
    said.split_whitespace()
        .find(|w| w.starts_with("snapshot-") && w.ends_with("ns.snap"))
        .unwrap_or_else(|| panic!("no file named: {said}"))
        .to_owned()
}

/// A real-time run of the default scenario takes a power-off of PL12 from 20 s for 5 s, a
/// hang of PL13 now, cleared at once, and refuses what it cannot take; each fault is on
/// `/faults` at its instants with its origin, each request on `/control` with its reply,
/// and `replay` reproduces the run.
#[test]
fn faults_from_the_control_channel_are_recorded_and_replayed() {
    let dir = test_dir("control", "faults");
    let rec = dir.join("run.mcap");
    let scenario = common::repo_root().join("scenarios/default.toml");
    let twin_run = Twin::start(
        &[
            scenario.to_str().unwrap(),
            "--duration",
            "40s",
            "--speed",
            "5",
            "--no-checks",
            "--control",
            "127.0.0.1:0",
            "--record",
            rec.to_str().unwrap(),
        ],
        1,
    );
    let addr = twin_run.addrs[0].to_string();
    let (ok, out) = gs(&addr, &["time"]);
    assert!(ok, "{out}");
    assert!(out.trim().ends_with(" s"), "{out}");
    let (ok, out) = gs(
        &addr,
        &["fault", "power-off", "PL12", "--at", "20s", "--for", "5s"],
    );
    assert!(ok, "{out}");
    assert!(
        out.contains("control[0]: PowerOff on PL12 (id 0): from 20.000 s until 25.000 s"),
        "{out}"
    );
    let (ok, out) = gs(&addr, &["fault", "hang", "PL13"]);
    assert!(ok, "{out}");
    let (ok, out) = gs(&addr, &["clear", "1"]);
    assert!(ok && out.contains("control[1] cleared"), "{out}");
    for (args, why) in [
        (&["fault", "melt", "PL12"][..], "unknown fault kind `melt`"),
        (&["fault", "power-off", "PL99"], "PL99"),
        (&["fault", "reboot", "FC", "--for", "1s"], "instantaneous"),
        (
            &["fault", "battery-fade", "EPS", "fraction=0.1"],
            "own timeline",
        ),
        (&["fault", "power-off", "PL12", "--at", "0s"], "has passed"),
        (&["clear", "7"], "no live fault 7"),
    ] {
        let (ok, out) = gs(&addr, args);
        assert!(!ok, "{args:?} was taken: {out}");
        assert!(out.contains(why), "{args:?}: {out}");
    }
    let (_, out, err) = twin_run.finish();
    assert!(rec.exists(), "no recording: {out}{err}");

    let faults: Vec<(u64, String)> = on(&rec, "/faults")
        .iter()
        .map(|m| {
            let f: m6p_twin::record::FaultMsg = m.decode().unwrap();
            (f.t_ns, f.what)
        })
        .collect();
    let s = |secs: u64| secs * 1_000_000_000;
    assert!(
        faults.contains(&(s(20), "control[0]: PowerOff on PL12".into())),
        "{faults:?}"
    );
    assert!(
        faults.contains(&(s(25), "control[0]: PowerOff on PL12 (power on)".into())),
        "{faults:?}"
    );
    let hang: Vec<_> = faults
        .iter()
        .filter(|(_, w)| w.starts_with("control[1]: Hang on PL13"))
        .collect();
    assert_eq!(hang.len(), 2, "the hang and its lift: {faults:?}");
    assert!(hang[1].1.ends_with("(recovered)"), "{hang:?}");
    let control: Vec<m6p_twin::record::ControlMsg> = on(&rec, "/control")
        .iter()
        .map(|m| m.decode().unwrap())
        .collect();
    assert_eq!(
        control.len(),
        10,
        "every request, refusals included: {control:?}"
    );
    assert!(control[1].reply.contains(r#""ok":true"#), "{control:?}");
    assert!(control[4].reply.contains(r#""ok":false"#), "{control:?}");

    let again = dir.join("replay.mcap");
    let o = twin()
        .args([
            "replay",
            rec.to_str().unwrap(),
            "--record",
            again.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "replay differs: {}", output_text(&o));
    // `diff` compares what crossed the media; the faults and the requests are the same too.
    for topic in ["/faults", "/control"] {
        let data = |p: &std::path::Path| -> Vec<(u64, Vec<u8>)> {
            on(p, topic)
                .iter()
                .map(|m| (m.log_time, m.data.clone()))
                .collect()
        };
        assert_eq!(data(&rec), data(&again), "{topic}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The channel's bounds, each counted and answered: a fifth connection while four are
/// open is told why and closed; a line over 4 096 bytes is refused whole and the
/// connection goes on; the run's table counts both.
#[test]
fn a_fifth_connection_and_a_long_line_are_refused_and_counted() {
    use std::io::{BufRead as _, BufReader, Write as _};
    let scenario = common::repo_root().join("scenarios/default.toml");
    let twin_run = Twin::start(
        &[
            scenario.to_str().unwrap(),
            "--duration",
            "20s",
            "--speed",
            "4",
            "--no-checks",
            "--control",
            "127.0.0.1:0",
        ],
        1,
    );
    let addr = twin_run.addrs[0];
    let connect = || {
        let s = std::net::TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(std::time::Duration::from_secs(10)))
            .unwrap();
        s
    };
    let line_of = |s: &std::net::TcpStream| {
        let mut line = String::new();
        BufReader::new(s).read_line(&mut line).unwrap();
        line
    };
    let mut open: Vec<_> = (0..4).map(|_| connect()).collect();
    // Each of the four is served (a request answered), so all four are open in the run.
    for s in &mut open {
        s.write_all(b"{\"op\":\"time\"}\n").unwrap();
        assert!(line_of(s).contains("\"ok\":true"));
    }
    let fifth = connect();
    let refused = line_of(&fifth);
    assert!(
        refused.contains("4 control connections are open already"),
        "{refused}"
    );
    let long = format!("{{\"op\":\"time\",\"pad\":\"{}\"}}\n", "x".repeat(5000));
    open[0].write_all(long.as_bytes()).unwrap();
    let reply = line_of(&open[0]);
    assert!(reply.contains("line longer than 4096 bytes"), "{reply}");
    open[0].write_all(b"{\"op\":\"time\"}\n").unwrap();
    assert!(
        line_of(&open[0]).contains("\"ok\":true"),
        "the connection goes on"
    );
    drop(open);
    // A web page's `fetch` to the port: its body is no request, the connection is closed
    // unanswered.
    std::thread::sleep(std::time::Duration::from_millis(300));
    let mut page = connect();
    page.write_all(
        b"POST / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: text/plain\r\n\r\n\
          {\"op\":\"fault\",\"kind\":\"power-off\",\"target\":\"PL12\"}\n",
    )
    .unwrap();
    let mut answer = String::new();
    let read = BufReader::new(&page).read_line(&mut answer);
    assert!(matches!(read, Ok(0) | Err(_)), "{read:?} {answer}");
    let (_, out, err) = twin_run.finish();
    assert!(
        out.contains("control channel: 5 connections (1 refused: 4 open), 5 requests, 1 lines over 4096 bytes refused, 1 HTTP requests closed"),
        "{out}{err}"
    );
    assert!(!err.contains("PowerOff"), "{err}");
}

/// `gs snapshot`: the run takes a snapshot where it settles at the request's instant and
/// writes it to its `--snapshot-dir`, named by the instant (never by the request); a run
/// goes on from it. A run without `--snapshot-dir` refuses the request, saying so.
#[test]
fn a_snapshot_asked_over_the_control_channel_is_written_to_the_runs_dir() {
    let dir = test_dir("control", "snapshot");
    let snaps = dir.join("snaps");
    let scenario = common::repo_root().join("scenarios/default.toml");
    let scenario = scenario.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec![
            scenario,
            "--duration",
            "20s",
            "--speed",
            "5",
            "--no-checks",
            "--control",
            "127.0.0.1:0",
        ];
        args.extend_from_slice(extra);
        Twin::start(&args, 1)
    };
    let twin_run = run(&["--snapshot-dir", snaps.to_str().unwrap()]);
    let addr = twin_run.addrs[0].to_string();
    let (ok, out) = gs(&addr, &["snapshot"]);
    assert!(ok, "{out}");
    let name = snapshot_named(&out);
    let (ok, out, err) = twin_run.finish();
    assert!(ok, "{out}{err}");
    let file = snaps.join(&name);
    assert!(
        err.contains(&format!("snapshot: {}", file.display())),
        "{err}"
    );
    let o = twin()
        .args([
            "run",
            scenario,
            "--duration",
            "20s",
            "--no-checks",
            "--from-snapshot",
        ])
        .arg(&file)
        .output()
        .unwrap();
    let text = output_text(&o);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("from snapshot "), "{text}");

    let twin_run = run(&[]);
    let (ok, out) = gs(&twin_run.addrs[0].to_string(), &["snapshot"]);
    assert!(!ok, "{out}");
    assert!(out.contains("start it with --snapshot-dir"), "{out}");
    let _ = twin_run.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

/// Ground station 16 simulated up to 2 s, saved there; a run from that snapshot with a
/// program taking GS16's place (`--kiss-addr 16`) is answered, and with the program
/// connected takes a snapshot on request; a run from that one begins with the program gone
/// (a connection is no state a run can take up again) and GS16's place its link's again:
/// the program connects and is answered. Without the program, that snapshot is refused:
/// GS16's state is not in it.
#[test]
fn a_program_in_a_nodes_place_from_a_snapshot_is_saved_and_connects_again() {
    use common::twin_process::Client;
    use std::time::Duration;
    let dir = test_dir("control", "snapshot-connected");
    let (snaps, at_2s) = (dir.join("snaps"), dir.join("at-2s.snap"));
    // A bare scenario: the ground reaches the FC all the time.
    let scenario = common::twin_process::bare("connected", 20);
    let scenario = scenario.to_str().unwrap();
    let o = twin()
        .args(["run", scenario, "--snapshot-at", "2s", "--snapshot"])
        .arg(&at_2s)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", output_text(&o));
    let args = [scenario, "--duration", "20s", "--speed", "5", "--no-checks"];
    let link = ["--kiss-listen", "127.0.0.1:0", "--kiss-addr", "16"];
    let first = Twin::start(
        &[
            &args[..],
            &link,
            &["--from-snapshot", at_2s.to_str().unwrap()],
            &[
                "--control",
                "127.0.0.1:0",
                "--snapshot-dir",
                snaps.to_str().unwrap(),
            ],
        ]
        .concat(),
        2,
    );
    // The control channel's line may come first: which is which, from the KISS line.
    let log = first.stderr.lock().unwrap().clone();
    let (kiss, control) = match first.addrs[..] {
        [a, b] if log.contains(&format!("KISS/TCP: listening on {a} ")) => (a, b),
        [a, b] => (b, a),
        _ => unreachable!(),
    };
    let mut program = Client::connect(kiss);
    assert!(program.ping(16, 3, 1, Duration::from_secs(5)).is_some());
    let (ok, out) = gs(&control.to_string(), &["snapshot"]);
    assert!(ok, "{out}");
    let file = snaps.join(snapshot_named(&out));
    let (ok, out, err) = first.finish();
    assert!(ok, "{out}{err}");
    assert!(err.contains("from snapshot "), "{err}");
    drop(program);

    let from = ["--from-snapshot", file.to_str().unwrap()];
    let second = Twin::start(&[&args[..], &link, &from].concat(), 1);
    let mut program = Client::connect(second.addrs[0]);
    assert!(program.ping(16, 3, 2, Duration::from_secs(5)).is_some());
    let (ok, out, err) = second.finish();
    assert!(ok, "{out}{err}");
    assert!(out.contains(": 1 connections (0 closed idle"), "{out}");

    let o = twin().arg("run").args(args).args(from).output().unwrap();
    let text = output_text(&o);
    assert!(!o.status.success(), "{text}");
    assert!(
        text.contains("an outside program had node 16's place when it was taken"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
