//! The `m6p-twin` binary on scenarios: the repository's own scenarios pass under
//! `m6p-twin test`, a failing expectation fails the run naming it with time and observed
//! value, the JUnit report lists it, and runs are deterministic.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;

mod common;

/// The standard output of a finished process, after asserting it succeeded.
fn succeeded(out: &std::process::Output) -> String {
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn twin(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn tmp(name: &str) -> PathBuf {
    // Under the target directory (cargo clean takes it), not left behind in /tmp.
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("scenario-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A minute of the default scenario's 6U from 2026-04-30T18:00:00Z, seed 1.
const MINUTE_6U: &str = r#"start = "2026-04-30T18:00:00Z"
duration = "60s"
seed = 1

[satellite]
tle = [
  "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
  "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
]
"#;

#[test]
fn repository_scenarios_pass_under_m6p_twin_test() {
    let mut files: Vec<String> = std::fs::read_dir(repo().join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| p.strip_prefix(repo()).unwrap().display().to_string())
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    let junit = tmp("repo.xml");
    let mut args = vec!["test", "--junit", junit.to_str().unwrap()];
    args.extend(files.iter().map(String::as_str));
    let (code, out, err) = twin(&args);
    assert_eq!(code, 0, "{out}\n{err}");
    for f in &files {
        let name = std::path::Path::new(f)
            .file_stem()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        assert!(out.contains(&name), "{name} missing from\n{out}");
    }
    let xml = std::fs::read_to_string(junit).unwrap();
    assert!(xml.contains("failures=\"0\""), "{xml}");
}

const FAILING: &str = r#"
name = "failing"
duration = "2m"
[[faults]]
at = "30s"
until = "90s"
kind = "power-off"
target = "FC"
[[commands]]
name = "ping-fc"
at = "10s"
every = "20s"
count = 5
to = "FC"
request = "ping"
[[expectations]]
name = "FC always answers"
kind = "reply"
command = "ping-fc"
[[expectations]]
name = "EPS never drops"
kind = "counter"
target = "EPS"
counter = "drops"
max = 0
"#;

#[test]
fn a_failing_expectation_fails_the_run_and_is_named_with_time_and_value() {
    let file = tmp("failing.toml");
    std::fs::write(&file, FAILING).unwrap();
    let junit = tmp("failing.xml");
    let (code, out, err) = twin(&[
        "test",
        "--junit",
        junit.to_str().unwrap(),
        file.to_str().unwrap(),
    ]);
    assert_eq!(code, 1, "{out}\n{err}");
    // Failures on stdout, with their reason, before the table.
    assert!(
        out.contains("FAIL failing: FC always answers (t = 30s)"),
        "{out}"
    );
    assert!(out.contains("no reply within the 5.000 s timeout"), "{out}");
    assert!(
        out.contains("failing") && out.contains("     1      1"),
        "{out}"
    );
    let xml = std::fs::read_to_string(&junit).unwrap();
    assert!(xml.starts_with("<?xml"), "{xml}");
    assert!(
        xml.contains("failures=\"1\"") && xml.contains("tests=\"2\""),
        "{xml}"
    );
    assert!(
        xml.contains("<failure") && xml.contains("FC always answers"),
        "{xml}"
    );
    // The file is well-formed XML: python's parser is the independent check.
    let py = Command::new("python3")
        .args(["-c", "import sys, xml.dom.minidom as m; d = m.parse(sys.argv[1]); print(len(d.getElementsByTagName('testcase')))"])
        .arg(&junit)
        .output()
        .unwrap();
    assert!(
        py.status.success(),
        "{}",
        String::from_utf8_lossy(&py.stderr)
    );
    assert_eq!(String::from_utf8_lossy(&py.stdout).trim(), "2");
    // `run` on the same file also exits non-zero and prints the verdicts.
    let (code, out, _) = twin(&["run", file.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(out.contains("FAIL FC always answers"), "{out}");
}

/// `m6p-twin test`'s table rows (no header) without their wall-time columns (wall s and
/// real-time x).
fn rows_without_wall(out: &str) -> Vec<String> {
    out.lines()
        .skip_while(|l| !l.starts_with("scenario "))
        .skip(1)
        .take_while(|l| !l.is_empty())
        .map(|l| {
            let (row, note) = match l.strip_suffix("  (did not run)") {
                Some(row) => (row, " (did not run)"),
                None => (l, ""),
            };
            let cells: Vec<&str> = row.split_whitespace().collect();
            cells[..cells.len().saturating_sub(2)].join(" ") + note
        })
        .collect()
}

#[test]
fn scenarios_tested_side_by_side_report_as_one_after_the_other() {
    let passing = tmp("jobs-passing.toml");
    std::fs::write(
        &passing,
        MINUTE_6U.replace("seed = 1", "seed = 1\nname = \"minute\""),
    )
    .unwrap();
    let failing = tmp("jobs-failing.toml");
    std::fs::write(&failing, FAILING).unwrap();
    let broken = tmp("jobs-broken.toml");
    std::fs::write(
        &broken,
        "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FCC\"\n",
    )
    .unwrap();
    let again = tmp("jobs-again.toml");
    std::fs::write(
        &again,
        MINUTE_6U.replace("seed = 1", "seed = 2\nname = \"again\""),
    )
    .unwrap();
    let files = [&passing, &failing, &broken, &again].map(|p| p.to_str().unwrap().to_owned());
    let tested = |jobs: &str| {
        let junit = tmp(&format!("jobs-{jobs}.xml"));
        let mut args = vec!["test", "--jobs", jobs, "--junit", junit.to_str().unwrap()];
        args.extend(files.iter().map(String::as_str));
        let (code, out, err) = twin(&args);
        (code, out, err, std::fs::read_to_string(junit).unwrap())
    };
    let (code1, out1, err1, xml1) = tested("1");
    let (code4, out4, err4, xml4) = tested("4");
    assert_eq!((code1, code4), (1, 1), "{out1}\n{err1}\n{out4}\n{err4}");
    // The table and the report are in the files' order, whichever run ended first.
    let rows = rows_without_wall(&out4);
    assert_eq!(rows_without_wall(&out1), rows);
    let names: Vec<&str> = rows.iter().map(|r| r.split(' ').next().unwrap()).collect();
    assert_eq!(
        names,
        ["minute", "failing", broken.to_str().unwrap(), "again"],
        "{out4}"
    );
    assert!(rows[2].ends_with(" 0 1 0.0 (did not run)"), "{out4}");
    // The same report but for the times it took.
    let without_times = |xml: &str| {
        xml.split(" time=\"")
            .enumerate()
            .map(|(i, part)| {
                if i == 0 {
                    part
                } else {
                    part.split_once('"').map_or(part, |p| p.1)
                }
            })
            .collect::<String>()
    };
    assert_eq!(without_times(&xml1), without_times(&xml4));
    // What they say on stdout is the same lines (printed in the order the runs ended): the
    // failures and the broken file's located errors, not its table row (a wall time).
    let said = |err: &str| {
        let mut lines: Vec<String> = err
            .lines()
            .filter(|l| l.starts_with("FAIL ") || l.contains("jobs-broken.toml:"))
            .map(str::to_owned)
            .collect();
        lines.sort();
        lines
    };
    assert_eq!(said(&out1), said(&out4), "{err1}{err4}");
    let said = said(&out4).join("\n");
    assert!(
        said.contains("FAIL failing: FC always answers (t = 30s)"),
        "{out4}"
    );
    assert!(said.contains("unknown node `FCC`"), "{out4}");
}

#[test]
fn scenarios_tested_side_by_side_take_turns_at_a_port() {
    // Two scenarios listening on one port: each runs in real time, one at a time, so both
    // bind it (side by side, the second would find it taken).
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let text = MINUTE_6U.replace("duration = \"60s\"", "duration = \"1s\"")
        + &format!("[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:{port}\"\n");
    let (a, b) = (tmp("port-a.toml"), tmp("port-b.toml"));
    std::fs::write(&a, &text).unwrap();
    std::fs::write(&b, &text).unwrap();
    let (code, out, err) = twin(&[
        "test",
        "--jobs",
        "2",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(!out.contains("did not run"), "{out}\n{err}");
}

#[test]
fn check_reports_file_line_and_field_and_schema_is_json() {
    let file = tmp("bad.toml");
    std::fs::write(
        &file,
        "duration = \"1m\"\n[[commands]]\nat = \"1s\"\nto = \"FCC\"\nrequest = \"ping\"\n",
    )
    .unwrap();
    let (code, _, err) = twin(&["check", file.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(
        err.contains("bad.toml:4:")
            && err.contains("commands[0].to")
            && err.contains("unknown node `FCC`"),
        "{err}"
    );
    let (code, out, _) = twin(&["check", "scenarios/default.toml"]);
    assert_eq!(code, 0, "{out}");
    let (code, out, _) = twin(&["schema"]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["title"], "Scenario");
    assert!(v["properties"]["commands"].is_object());
}

#[test]
fn run_output_is_the_same_for_the_same_seed() {
    let strip = |s: String| {
        s.lines()
            .filter(|l| !l.starts_with("simulated"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    let a = strip(twin(&["run", "scenarios/node-faults.toml"]).1);
    let b = strip(twin(&["run", "scenarios/node-faults.toml"]).1);
    assert_eq!(a, b);
    assert!(a.contains("8 passed, 0 failed"), "{a}");
}

#[test]
fn recordings_are_byte_identical_replay_is_identical_and_a_changed_node_diverges() {
    let a = tmp("a.mcap");
    let b = tmp("b.mcap");
    let c = tmp("c.mcap");
    let (code, out, err) = twin(&[
        "run",
        "scenarios/node-faults.toml",
        "--record",
        a.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.contains("recorded") && out.contains("chunks"), "{out}");
    assert_eq!(
        twin(&[
            "run",
            "scenarios/node-faults.toml",
            "--record",
            b.to_str().unwrap()
        ])
        .0,
        0
    );
    assert_eq!(
        std::fs::read(&a).unwrap(),
        std::fs::read(&b).unwrap(),
        "same scenario and seed, different bytes"
    );
    // Another seed changes what randomness drives (CFP idents, ports), so the files differ.
    assert_eq!(
        twin(&[
            "run",
            "scenarios/node-faults.toml",
            "--seed",
            "2",
            "--record",
            c.to_str().unwrap()
        ])
        .0,
        0
    );
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&c).unwrap());
    let (code, out, _) = twin(&["diff", a.to_str().unwrap(), b.to_str().unwrap()]);
    assert_eq!(code, 0, "{out}");
    assert!(out.starts_with("identical"), "{out}");
    let (code, out, _) = twin(&["diff", a.to_str().unwrap(), c.to_str().unwrap()]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("first divergence"), "{out}");
    // Replay re-runs the recorded scenario and seed.
    let (code, out, err) = twin(&["replay", a.to_str().unwrap()]);
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.starts_with("identical"), "{out}");
}

#[test]
fn replay_names_the_first_divergence_after_a_behaviour_change() {
    let a = tmp("default.mcap");
    assert_eq!(
        twin(&["run", "--duration", "60s", "--record", a.to_str().unwrap()]).0,
        0
    );
    let (code, out, _) = twin(&["replay", a.to_str().unwrap()]);
    assert_eq!(code, 0, "a replay keeps the recorded --duration: {out}");
    // The FC answers uptime in the ICD's format under the knob: the first uptime request
    // of the default scenario is sent at 22 s, so the first different frame is the FC's
    // reply a few milliseconds later, on the main bus.
    let (code, out, err) = twin(&[
        "replay",
        a.to_str().unwrap(),
        "--test-knob",
        "fc-uptime-icd",
    ]);
    assert_eq!(code, 1, "{out}{err}");
    assert!(out.contains("first divergence"), "{out}");
    assert!(out.contains("t = 22.0"), "{out}");
    assert!(
        out.contains("/can/main/frames") && out.contains("from FC"),
        "{out}"
    );
    assert!(
        out.contains("3:6 -> 16:"),
        "the uptime reply header is decoded: {out}"
    );
}

#[test]
#[cfg_attr(
    not(python_mcap),
    ignore = "needs python3 with the `mcap` package (pip install mcap; .ci/run installs it)"
)]
fn a_real_recording_decodes_with_the_python_mcap_package() {
    let ok = Command::new("python3")
        .args(["-c", "import mcap.reader, mcap_protobuf.decoder"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "this test needs python3 with the `mcap` and `mcap-protobuf-support` packages: \
         pip install mcap mcap-protobuf-support (.ci/run installs them)"
    );
    let f = tmp("py.mcap");
    assert_eq!(
        twin(&[
            "run",
            "scenarios/uhf-loss.toml",
            "--record",
            f.to_str().unwrap()
        ])
        .0,
        0
    );
    let out = Command::new("python3")
        .arg(repo().join("tests/decode_mcap.py"))
        .arg(&f)
        .output()
        .unwrap();
    let text = succeeded(&out);
    assert!(
        text.contains("/csp/packets") && text.trim_end().ends_with("ok"),
        "{text}"
    );
    // And with Google's protobuf, as Foxglove reads it: every message decodes.
    let out = Command::new("python3")
        .arg(repo().join("tests/decode_mcap_protobuf.py"))
        .arg(&f)
        .output()
        .unwrap();
    let text = succeeded(&out);
    assert!(
        text.contains("/can/main/frames") && text.trim_end().ends_with("ok"),
        "{text}"
    );
}

/// Issue 19: `/csp/packets` carries every ICD request and reply decoded (command name and
/// fields), so a plot of TMGEN's `current_mode` from the recording shows a mode change, read
/// with nothing but the Python `mcap` package and the schemas in the file.
#[test]
#[cfg_attr(
    not(python_mcap),
    ignore = "needs python3 with the `mcap` package (pip install mcap; .ci/run installs it)"
)]
fn a_recorded_tmgen_mode_change_shows_in_the_decoded_packets() {
    let scenario = tmp("mode-change.toml");
    std::fs::write(
        &scenario,
        format!("name = \"mode-change\"\n{MINUTE_6U}")
            + r#"

[[commands]]
name = "tmgen"
at = "5s"
every = "5s"
count = 10
to = "FC"
request = "raw"
port = 10
data = "01"

[[commands]]
name = "idle"
at = "27s"
to = "FC"
request = "raw"
port = 12
data = "06 00"
"#,
    )
    .unwrap();
    let rec = tmp("mode-change.mcap");
    let (code, out, err) = twin(&[
        "run",
        scenario.to_str().unwrap(),
        "--record",
        rec.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    let out = Command::new("python3")
        .arg(repo().join("tests/icd_fields_mcap.py"))
        .args([rec.to_str().unwrap(), "FC.TMGEN", "current_mode"])
        .output()
        .unwrap();
    let text = succeeded(&out);
    let rows: Vec<(f64, f64, String)> = text
        .lines()
        .map(|l| {
            let mut w = l.splitn(3, ' ');
            (
                w.next().unwrap().parse().unwrap(),
                w.next().unwrap().parse().unwrap(),
                w.next().unwrap_or_default().to_owned(),
            )
        })
        .collect();
    assert_eq!(rows.len(), 10, "{text}");
    let (before, after): (Vec<_>, Vec<_>) = rows.iter().partition(|r| r.0 < 27.0);
    assert!(before.iter().all(|r| r.1 != 0.0), "{text}");
    assert!(
        after.iter().all(|r| r.1 == 0.0 && r.2 == "idle"),
        "after ATCMDSET idle the mode in effect is 0 (idle): {text}"
    );
}

/// `m6p-twin args --record rec` started in the repository; the child, the address its
/// (first) KISS server announced, and the thread draining the rest of its stderr (so the
/// child never blocks on a full pipe).
fn recorded_run_with_kiss(
    args: &[&str],
    rec: &std::path::Path,
) -> (std::process::Child, String, std::thread::JoinHandle<()>) {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .arg("--record")
        .arg(rec)
        .current_dir(repo())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let addr = lines
        .by_ref()
        .map_while(Result::ok)
        .find_map(|l| {
            l.split("listening on ")
                .nth(1)
                .and_then(|r| r.split_whitespace().next())
                .map(str::to_owned)
        })
        .expect("the twin announces its KISS address");
    let drain = std::thread::spawn(move || lines.for_each(drop));
    (child, addr, drain)
}

/// One real-time run with two outside connections, recorded, then replayed: the replay's
/// verdict (`Ok` when identical) and the recording's summary.
fn outside_run_and_replay(rec: &std::path::Path) -> (Result<(), String>, String) {
    let (mut child, addr, drain) = recorded_run_with_kiss(
        &[
            "run",
            "scenarios/node-faults.toml",
            "--duration",
            "6s",
            "--kiss-listen",
            "127.0.0.1:0",
        ],
        rec,
    );
    // Two connections of an outside ground node (16), one after the other.
    for extra in [&["--targets", "3,12"][..], &["--targets", "6,13"][..]] {
        let out = Command::new("python3")
            .arg(repo().join("tests/kiss_peer.py"))
            .args(["--connect", &addr])
            .args(extra)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stdout)
        );
    }
    assert!(child.wait().unwrap().code().is_some());
    drain.join().unwrap();
    // Replay feeds the two connections' recorded bytes again, in virtual time.
    let (code, out, err) = twin(&["replay", rec.to_str().unwrap()]);
    let (_, summary, _) = twin(&["inspect", rec.to_str().unwrap()]);
    let verdict = if code == 0 && out.starts_with("identical") {
        Ok(())
    } else {
        Err(format!("{out}{err}"))
    };
    (verdict, summary)
}

/// A real-time run with outside programs replays exactly, whatever the machine's load: in
/// real time the twin is the virtual-time machine held to the wall clock, and outside input
/// is taken in at the run's own idle points with their instants (`bus::pace`), so the
/// recording's inputs determine the run. A frame stamped when its task happened to run
/// would make replays diverge (a frame at 0.700138 s instead of 0.699270738 s), more
/// often under load: one try, no retries.
#[test]
fn a_run_with_outside_programs_replays_identically_from_its_recorded_input() {
    let rec = tmp("outside.mcap");
    let (verdict, summary) = outside_run_and_replay(&rec);
    assert!(
        summary.contains("/kiss/listen_127.0.0.1:0_1/in")
            && summary.contains("/kiss/listen_127.0.0.1:0_2/out"),
        "{summary}"
    );
    if let Err(why) = verdict {
        panic!("the replay diverged from the real-time original: {why}");
    }
}

/// An outside payload on the payload CAN bus (the README's Python payload, answering the PC's
/// polls within a millisecond of the bus's own traffic) in a real-time run replays exactly:
/// its frames meet the PC's and the EPS's on the bus in the same order. An original that
/// picked frames for arbitration by when tasks happened to run could diverge from its
/// replay at the payload's frames.
#[test]
fn a_real_time_session_with_an_outside_payload_replays_identically() {
    let rec = tmp("outside-payload.mcap");
    let scenario = tmp("outside-payload.toml");
    let downlink = tmp("outside-payload.downlink");
    let text = common::readme_scenario()
        .replace("127.0.0.1:52001", "127.0.0.1:0")
        .replace("/tmp/outside_payload.downlink", downlink.to_str().unwrap());
    std::fs::write(&scenario, text).unwrap();
    let (mut child, addr, drain) =
        recorded_run_with_kiss(&["run", scenario.to_str().unwrap()], &rec);
    let out = Command::new("python3")
        .arg(repo().join("examples/outside_payload.py"))
        .args([
            "--connect",
            &addr,
            "--idle",
            "1.5",
            "--seconds",
            "12",
            "--wait",
            "5",
        ])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(said.contains("1 SYNC, 25 POLL"), "{said}");
    assert_eq!(
        child.wait().unwrap().code(),
        Some(0),
        "the README's expectations hold"
    );
    drain.join().unwrap();
    let (code, out, err) = twin(&["replay", rec.to_str().unwrap()]);
    assert!(
        code == 0 && out.starts_with("identical"),
        "the replay diverged from the real-time original: {out}{err}"
    );
}

#[test]
fn ctrl_c_finishes_the_recording_cleanly() {
    let rec = tmp("interrupted.mcap");
    let args = [
        "run",
        "--realtime",
        "--forever",
        "--kiss-listen",
        "127.0.0.1:0",
    ];
    let out = interrupted_run(&args, &rec, "listening on", 0);
    // Stopped early, the default scenario's later commands were never sent: exit 1, but
    // the table, the verdicts and a complete file are there.
    assert_eq!(out.status.code(), Some(1));
    assert_complete(&out, &rec);
}

/// Run the twin with `args` recording to `rec`, send it SIGINT `after_ms` after it printed
/// a line containing `ready` on stderr, and return its output.
fn interrupted_run(
    args: &[&str],
    rec: &std::path::Path,
    ready: &str,
    after_ms: u64,
) -> std::process::Output {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .arg("--record")
        .arg(rec)
        .current_dir(repo())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    assert!(
        lines
            .by_ref()
            .map_while(Result::ok)
            .any(|l| l.contains(ready)),
        "the twin started"
    );
    let drain = std::thread::spawn(move || lines.collect::<Vec<_>>());
    std::thread::sleep(std::time::Duration::from_millis(after_ms));
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let mut out = child.wait_with_output().unwrap();
    let rest: Vec<String> = drain
        .join()
        .unwrap()
        .into_iter()
        .map_while(Result::ok)
        .collect();
    out.stderr = rest.join("\n").into_bytes();
    out
}

/// The interrupted run printed its table and verdicts and left a complete recording.
fn assert_complete(out: &std::process::Output, rec: &std::path::Path) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("expectations:") && stdout.contains("recorded"),
        "{stdout}"
    );
    let (code, summary, err) = twin(&["inspect", rec.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(
        !summary.contains("incomplete") && !summary.contains("truncated"),
        "{summary}"
    );
    assert!(summary.contains("/expectations"), "{summary}");
}

/// `bench` measures and reports, and leaves nothing behind: no recording and no S-band
/// downlink files from a scenario with a payload session (it left a `.downlink` folder of
/// session files in the temp dir before).
#[test]
fn bench_reports_its_figures_and_leaves_no_files() {
    let dir = tmp("bench-tmp");
    std::fs::create_dir_all(&dir).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args([
            "bench",
            "scenarios/eps-pc-off.toml",
            "--duration",
            "200s",
            "--runs",
            "1",
        ])
        .current_dir(repo())
        .env("TMPDIR", &dir)
        .output()
        .unwrap();
    let text = succeeded(&out);
    // Quiet: the runs' news would repeat once per run.
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains(" INFO "), "{err}");
    for figure in [
        "plain ",
        "recorded ",
        "adcs_floor ",
        "recorded / plain CPU",
        "peak RSS",
        "MCAP:",
    ] {
        assert!(text.contains(figure), "{figure} missing from\n{text}");
    }
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// `bench --json` prints one object with the figures dashboards read, consistent with each
/// other: the recorded run costs more than the plain one, which costs more than the FC's
/// physics alone, and the ratios are the ratios of the medians.
#[test]
fn bench_json_has_the_dashboard_keys() {
    let (code, out, err) = twin(&[
        "bench",
        "scenarios/adcs-nadir.toml",
        "--duration",
        "300s",
        "--runs",
        "3",
        "--json",
    ]);
    assert_eq!(code, 0, "{out}{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let num = |k: &str| {
        v[k].as_f64()
            .unwrap_or_else(|| panic!("{k} missing or not a number in {out}"))
    };
    for k in [
        "cpu_s_plain",
        "cpu_s_recorded",
        "cpu_s_adcs_floor",
        "rtf_plain",
        "rtf_recorded",
        "mcap_bytes_per_hour",
        "messages_per_hour",
        "peak_rss_mib",
    ] {
        assert!(num(k) > 0.0, "{k} = {} in {out}", num(k));
    }
    assert!(num("cpu_s_recorded") > num("cpu_s_adcs_floor"), "{out}");
    let ratio = num("cpu_s_recorded") / num("cpu_s_plain");
    assert!((num("ratio_recorded_plain") - ratio).abs() < 1e-9, "{out}");
    for variant in ["plain", "recorded", "adcs_floor"] {
        let s = &v["variants"][variant]["cpu_s"];
        let (min, med, max) = (s["min"].as_f64(), s["median"].as_f64(), s["max"].as_f64());
        assert!(min <= med && med <= max, "{variant}: {s}");
    }
    assert_eq!(v["runs"], 3);
    // Every run is a process of its own: the FC alone never shows the memory of a recorded
    // run (in one process, the floor after a recorded run kept its heap: 12.95 MiB against
    // the recorded run's 12.72; separately 9.6 against 12.7).
    let rss = |variant: &str, k: &str| {
        v["variants"][variant]["peak_rss_mib"][k]
            .as_f64()
            .unwrap_or_else(|| panic!("{variant} peak_rss_mib {k} in {out}"))
    };
    assert!(
        rss("adcs_floor", "max") < rss("recorded", "min"),
        "{}",
        v["variants"]
    );
}

/// A beacon verdict reads like the others: bounds as `>= 2`, and no contact as `0 s` (it
/// printed `Some(2)..=None` and `-0 s`).
#[test]
fn a_beacon_verdict_prints_plain_bounds_and_no_contact_as_zero() {
    let f = tmp("beacon-verdict.toml");
    std::fs::write(
        &f,
        r#"duration = "1300s"
start = "2026-04-30T18:00:00Z"
[satellite]
tle = [
  "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
  "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
]
[fc]
publish_hz = 0
[comm]
passes = true
[[expectations]]
kind = "beacon"
min = 2
"#,
    )
    .unwrap();
    let (code, out, _) = twin(&["run", f.to_str().unwrap()]);
    assert_eq!(code, 1, "{out}");
    assert!(
        out.contains("0 beacons on the ground over 0 s of contact in 0 window(s) (expected >= 2)"),
        "{out}"
    );
}

/// `m6p-twin run | head -1`: the reader goes away early and the twin ends quietly with
/// the status of a process killed by SIGPIPE (it panicked with "failed printing to stdout").
#[test]
fn a_reader_that_stops_early_ends_the_twin_quietly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(["run", "--duration", "10m"])
        .current_dir(repo())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before the twin prints its table (a few hundred ms of run).
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(141), "{err}");
}

/// The first ```toml block after `heading` in docs/scenarios.md, with `header` in front.
fn doc_example(heading: &str, header: &str) -> PathBuf {
    let doc = std::fs::read_to_string(repo().join("docs/scenarios.md")).unwrap();
    let from = doc.find(heading).unwrap();
    let start = doc[from..].find("```toml\n").unwrap() + from + 8;
    let end = doc[start..].find("```").unwrap() + start;
    let f = tmp(&format!("doc-{}.toml", heading.len()));
    std::fs::write(&f, format!("{header}{}", &doc[start..end])).unwrap();
    f
}

/// The docs' examples stay true: the annotated example is a valid scenario, and the FC
/// example passes with the start, duration and seed the text gives (it had rotted: its
/// detumble window failed).
#[test]
fn the_scenario_docs_examples_check_and_the_fc_example_passes() {
    let annotated = doc_example("## An annotated example", "");
    let (code, out, err) = twin(&["check", annotated.to_str().unwrap()]);
    assert_eq!(code, 0, "{out}{err}");
    let fc = doc_example(
        "## The FC",
        "start = \"2026-04-30T18:00:00Z\"\nduration = \"3h\"\nseed = 3\n",
    );
    let (code, out, err) = twin(&["run", fc.to_str().unwrap()]);
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.contains("4 passed, 0 failed"), "{out}");
}

/// A passive payload (`examples/outside_payload.py`, on the README's link with `addrs = [12]`)
/// whose program first connects and drops the connection at once, then connects again and
/// serves the session: the replay opens each recorded connection when the original opened
/// (the open is recorded as the connection's first empty input chunk), so the second one
/// holds 12 when the PC's SYNC comes, as it did in the original. Were every replayed
/// connection opened at time 0, the second's claim of 12 would be refused (the first held
/// it), the SYNC would find no route, and the replay would diverge.
#[test]
fn a_replayed_connection_opens_when_the_recorded_one_did() {
    let dir = tmp("reconnect.downlink");
    let text = common::readme_scenario()
        .replace("127.0.0.1:52001", "127.0.0.1:0")
        .replace("/tmp/outside_payload.downlink", dir.to_str().unwrap());
    let scenario = tmp("reconnect.toml");
    std::fs::write(&scenario, text).unwrap();
    let ok = served_and_replayed(&scenario, &[], "reconnect", |addr| {
        drop(std::net::TcpStream::connect(addr).unwrap());
        std::thread::sleep(std::time::Duration::from_millis(300));
    });
    std::fs::remove_file(&scenario).ok();
    std::fs::remove_dir_all(&dir).ok();
    ok.unwrap_or_else(|failures| {
        panic!("three real-time originals diverged from their replays: {failures:#?}")
    });
}

/// Run `scenario` in real time and recorded (with `args`), `before(addr)`, then
/// `examples/outside_payload.py` serving its session over the announced KISS address, then
/// replay the recording: `Ok` once a replay is identical, else after three tries the three
/// divergences. Real-time originals can be stamped a fraction of a millisecond late (see
/// the test above); anything else than a divergence fails at once.
fn served_and_replayed(
    scenario: &std::path::Path,
    args: &[&str],
    name: &str,
    before: impl Fn(&str),
) -> Result<(), Vec<String>> {
    let mut failures = Vec::new();
    for attempt in 0..3 {
        let rec = tmp(&format!("{name}-{attempt}.mcap"));
        let mut run = vec!["run", scenario.to_str().unwrap()];
        run.extend(args);
        let (mut child, addr, drain) = recorded_run_with_kiss(&run, &rec);
        before(&addr);
        let out = Command::new("python3")
            .arg(repo().join("examples/outside_payload.py"))
            .args(["--connect", &addr, "--idle", "1.5", "--seconds", "12"])
            .output()
            .unwrap();
        let py = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(py.contains("1 SYNC, 25 POLL"), "{py}");
        assert!(child.wait().unwrap().success());
        drain.join().unwrap();
        let (code, out, err) = twin(&["replay", rec.to_str().unwrap()]);
        std::fs::remove_file(&rec).ok();
        if code == 0 && out.starts_with("identical") {
            return Ok(());
        }
        assert!(out.contains("first divergence"), "{out}{err}");
        failures.push(format!("{out}{err}"));
    }
    Err(failures)
}

/// Payload 12 from the command line (`--kiss-listen ... --kiss-addr 12`) on a scenario that
/// simulates PL12: the link's program takes PL12's place (it serves the session; before, its
/// claim of 12 was refused and PL12 answered), and the replay replaces PL12 too (the
/// recording keeps the replaced nodes), so it is identical.
#[test]
fn a_command_line_payload_replaces_pl12_in_the_run_and_in_its_replay() {
    let dir = tmp("cli-payload.downlink");
    let link = "[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:52001\"\naddrs = [12]           # route CSP 12 to this link from the start\n";
    let readme = common::readme_scenario();
    assert!(readme.contains(link), "the README's link block changed");
    let text = readme
        .replace(link, "")
        .replace("payloads = [13]", "payloads = [12, 13]")
        .replace("/tmp/outside_payload.downlink", dir.to_str().unwrap());
    let scenario = tmp("cli-payload.toml");
    std::fs::write(&scenario, text).unwrap();
    let ok = served_and_replayed(
        &scenario,
        &["--kiss-listen", "127.0.0.1:0", "--kiss-addr", "12"],
        "cli-payload",
        |_| {},
    );
    std::fs::remove_file(&scenario).ok();
    std::fs::remove_dir_all(&dir).ok();
    ok.unwrap_or_else(|failures| {
        panic!("three real-time originals diverged from their replays: {failures:#?}")
    });
}

/// `campaign run`: a draw that makes a run's scenario invalid is an error naming the
/// campaign file, line and field, before anything runs (no output directory); a good
/// campaign writes its files, and a failure file reproduces under `m6p-twin test`.
#[test]
fn campaign_run_checks_every_draw_first_and_its_failures_reproduce() {
    let dir = tmp("campaign");
    std::fs::create_dir_all(&dir).unwrap();
    // Runs pass or fail by a drawn ping time.
    let good_text =
        std::fs::read_to_string(repo().join("crates/twin/tests/data/campaign-ping.toml")).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        good_text.replace(
            "[dispersions]\n",
            "[dispersions]\n\"fc.initial_rate_deg_s\" = { uniform = [300.0, 900.0] }\n",
        ),
    )
    .unwrap();
    let out = dir.join("out-bad");
    let (code, _, err) = twin(&[
        "campaign",
        "run",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(
        err.contains("bad.toml:7:") && err.contains("0-360"),
        "{err}"
    );
    assert!(!out.exists());

    let good = dir.join("good.toml");
    std::fs::write(&good, &good_text).unwrap();
    let out = dir.join("out-good");
    let (code, stdout, err) = twin(&[
        "campaign",
        "run",
        good.to_str().unwrap(),
        "--jobs",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7, "{csv}");
    let failures: Vec<_> = std::fs::read_dir(out.join("failures"))
        .map(|d| d.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    // Seed 3 draws `5s` (a ping after the end: never answered) for some of the 6 runs.
    assert!(!failures.is_empty() && code == 1, "{stdout}{err}");
    for f in &failures {
        let (code, text, err) = twin(&["test", f.to_str().unwrap()]);
        assert_eq!(code, 1, "{text}{err}");
        assert!(text.contains("short run"), "{text}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A replay writes its downlink beside its own recording: the files of the original run,
/// in the scenario's `[pc] downlink_dir`, are left as they are: the replay never writes
/// over the original's files.
#[test]
fn a_replay_writes_its_downlink_beside_its_recording_never_over_the_originals() {
    let orig = tmp("replay-downlink-orig");
    let _ = std::fs::remove_dir_all(&orig);
    let scenario = tmp("replay-downlink.toml");
    std::fs::write(
        &scenario,
        format!(
            "name = \"replay-downlink\"\nduration = \"5s\"\n[pc]\ndownlink_dir = \"{}\"\n\
             [[commands]]\nname = \"setup\"\nat = \"1s\"\nto = \"PC\"\nrequest = \"raw\"\nport = 10\n\
             data = \"01 01 00000000 0500 0300 40 53656e642074656c656d65747279\"\n",
            orig.display()
        ),
    )
    .unwrap();
    let rec = tmp("replay-downlink.mcap");
    let (code, _, err) = twin(&[
        "run",
        scenario.to_str().unwrap(),
        "--record",
        rec.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let file = orig.join("session-1-run1.bin");
    let original = std::fs::read(&file).unwrap();
    assert_eq!(original.len(), 3 * 64, "3 packets of 64 bytes");
    // Mark the original's file: a replay writing there would replace it.
    std::fs::write(&file, b"the original run's file").unwrap();
    let again = tmp("replay-downlink-again.mcap");
    let (code, out, err) = twin(&[
        "replay",
        rec.to_str().unwrap(),
        "--record",
        again.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    assert_eq!(std::fs::read(&file).unwrap(), b"the original run's file");
    let replayed =
        std::fs::read(again.with_extension("downlink").join("session-1-run1.bin")).unwrap();
    assert_eq!(replayed, original);
}

/// `passes` lists the default orbit's passes over Vilnius, the one at 13,150 s among them,
/// and names the stations when asked for one that is not there.
#[test]
fn passes_lists_rise_culmination_set_and_elevation() {
    let (code, out, err) = twin(&["passes", "--duration", "4h"]);
    assert_eq!(code, 0, "{err}");
    let rows: Vec<&str> = out.lines().filter(|l| l.starts_with("Vilnius")).collect();
    assert_eq!(rows.len(), 2, "{out}");
    let cols: Vec<&str> = rows[1].split_whitespace().collect();
    // station, rise, culmination, set, max elevation, length, rise in UTC
    assert_eq!(cols[1], "13149.9", "{out}");
    let (rise, culm, set): (f64, f64, f64) = (
        cols[1].parse().unwrap(),
        cols[2].parse().unwrap(),
        cols[3].parse().unwrap(),
    );
    assert!(rise < culm && culm < set, "{out}");
    assert!(cols[6].starts_with("2026-04-30T21:39:09"), "{out}");
    let (code, _, err) = twin(&["passes", "--station", "Kaunas"]);
    assert_ne!(code, 0);
    assert!(
        err.contains("no station `Kaunas`") && err.contains("Vilnius"),
        "{err}"
    );
}

/// Ctrl-C also stops a run in virtual time, which has no IO driver of its own (the signal
/// is watched by one thread for the process): a week of simulated time stops within
/// seconds, with its table, verdicts and a complete recording.
#[test]
fn ctrl_c_stops_a_virtual_run_and_finishes_its_recording() {
    let rec = tmp("interrupted-virtual.mcap");
    let out = interrupted_run(&["run", "--duration", "7d"], &rec, "running scenario", 500);
    assert_complete(&out, &rec);
    // Stopped long before the week's end: "simulated X s in Y s wall" gives where, never
    // the whole week.
    let all = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let secs: f64 = all
        .lines()
        .find_map(|l| l.trim().strip_prefix("simulated "))
        .and_then(|l| l.split_whitespace().next())
        .unwrap_or_else(|| panic!("no `simulated` line:\n{all}"))
        .parse()
        .unwrap();
    assert!(secs < 7.0 * 86_400.0, "{all}");
}

/// Issue 19: `field` expectations judge TMGEN's decoded mode over time (every reply of the
/// scenario's polls: the FC detumbles, then idles after ATCMDSET at 27 s): `at`,
/// `eventually` and `always` hold where they should and fail, naming the reply, where they
/// should not.
#[test]
fn field_expectations_follow_tmgens_mode_over_time() {
    let scenario = tmp("field-over-time.toml");
    std::fs::write(
        &scenario,
        format!("name = \"field-over-time\"\n{MINUTE_6U}")
            + r#"

[[commands]]
name = "tmgen"
at = "5s"
every = "5s"
count = 10
command = "FC.TMGEN"

[[commands]]
name = "idle"
at = "27s"
command = "FC.ATCMDSET"
args = { mode = "idle" }

[[expectations]]
name = "detumbling at 20 s"
kind = "field"
field = "FC.TMGEN.current_mode"
when = "at"
at = "20s"
equals = "detumble"

[[expectations]]
name = "idle at 40 s"
kind = "field"
field = "FC.TMGEN.current_mode"
when = "at"
at = "40s"
equals = 0

[[expectations]]
name = "eventually idle"
kind = "field"
field = "FC.TMGEN.current_mode"
when = "eventually"
equals = "idle"

[[expectations]]
name = "always detumbling (fails)"
kind = "field"
field = "FC.TMGEN.current_mode"
equals = "detumble"

[[expectations]]
name = "never nadir (fails)"
kind = "field"
field = "FC.TMGEN.current_mode"
when = "eventually"
equals = "nadir"

[[expectations]]
name = "no TMATP polled (fails)"
kind = "field"
field = "FC.TMATP.rtc_timestamp"
above = 0
"#,
    )
    .unwrap();
    let (code, out, err) = twin(&["run", scenario.to_str().unwrap()]);
    std::fs::remove_file(&scenario).ok();
    assert_eq!(code, 1, "{out}{err}");
    let line = |name: &str| {
        out.lines()
            .find(|l| l.contains(name))
            .unwrap_or_else(|| panic!("no verdict `{name}`:\n{out}"))
            .trim()
            .to_owned()
    };
    assert!(line("detumbling at 20 s").starts_with("PASS"), "{out}");
    assert!(
        line("detumbling at 20 s").contains("= 1 (detumble) in the latest reply, at 15.0"),
        "{out}"
    );
    assert!(line("idle at 40 s").starts_with("PASS"), "{out}");
    let eventually = line("eventually idle");
    assert!(eventually.starts_with("PASS"), "{out}");
    assert!(eventually.contains("= 0 (idle) at 30.0"), "{eventually}");
    assert!(
        eventually.contains("10 replies, seen: 0..=1"),
        "{eventually}"
    );
    let always = line("always detumbling");
    assert!(always.starts_with("FAIL"), "{out}");
    assert!(
        always.contains("FC.TMGEN.current_mode = 0 (idle) at 30.0"),
        "{always}"
    );
    assert!(always.contains("not = 1 (detumble)"), "{always}");
    let never = line("never nadir");
    assert!(
        never.starts_with("FAIL") && never.contains("never = 3 (nadir) (10 replies"),
        "{never}"
    );
    let none = line("no TMATP polled");
    assert!(
        none.starts_with("FAIL") && none.contains("no successful FC.TMATP reply in the window"),
        "{none}"
    );
    assert!(out.contains("3 passed, 3 failed"), "{out}");
}
