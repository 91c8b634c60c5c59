//! A payload team's first day (issue 42): lab mode, a test runner that talks, hints that
//! are true when followed.

#![allow(clippy::unwrap_used)]

use std::io::{BufRead, BufReader, Read, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};

mod common;

use common::twin_cli as twin;

fn repo() -> PathBuf {
    common::repo_root()
}

fn tmp(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("first-day-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A shortened run of the default scenario fails its own checks (commands never sent
/// before the end); in lab mode nothing is judged and the run that reaches its end passes.
#[test]
fn lab_mode_runs_the_platform_without_the_scenarios_checks() {
    let (code, out, err) = twin(&["run", "--duration", "5s"]);
    assert_eq!(
        code, 1,
        "a shortened default run fails its checks\n{out}\n{err}"
    );
    assert!(out.contains("FAIL "), "{out}");

    let (code, out, err) = twin(&["run", "--duration", "5s", "--no-checks"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(!out.contains("FAIL"), "{out}");
    assert!(!out.contains("expectations:"), "{out}");
    assert!(
        err.contains("lab mode (--no-checks)") && err.contains("not checked"),
        "{err}"
    );
}

/// `test` says how each scenario went as it ends (a progress line when stderr is not a
/// terminal), prints its failures on stdout with their reason, ends with a totals line,
/// keeps the runs' INFO logs off stderr unless asked (`-v`), and its JUnit report carries
/// times.
#[test]
fn the_test_runner_talks_and_its_junit_has_times() {
    let failing = tmp("failing.toml");
    std::fs::write(
        &failing,
        r#"name = "failing"
duration = "60s"
[[commands]]
name = "ping-fc"
at = "10s"
to = "FC"
request = "ping"
[[commands]]
name = "ping-late"
at = "90s"
to = "FC"
request = "ping"
[[expectations]]
name = "FC answers"
kind = "reply"
command = "ping-fc"
[[expectations]]
name = "never sent"
kind = "reply"
command = "ping-late"
"#,
    )
    .unwrap();
    let junit = tmp("junit.xml");
    let (code, out, err) = twin(&[
        "test",
        "--junit",
        junit.to_str().unwrap(),
        failing.to_str().unwrap(),
    ]);
    assert_eq!(code, 1, "{out}\n{err}");
    assert!(
        out.lines()
            .any(|l| l.starts_with("FAIL failing: never sent (t = ")),
        "{out}"
    );
    assert!(
        out.contains("\n1 passed, 1 failed (1 scenario(s)) in "),
        "a totals line\n{out}"
    );
    assert!(err.contains("[1/1] failing: 1 passed, 1 failed ("), "{err}");
    assert!(!err.contains(" INFO "), "logs at WARN by default\n{err}");
    let xml = std::fs::read_to_string(&junit).unwrap();
    assert!(
        xml.contains(r#"<testsuite name="failing""#) && xml.contains(" time=\""),
        "{xml}"
    );
    assert!(
        xml.matches("<testcase ").count() == 2
            && xml.split("<testcase ").skip(1).all(|c| c
                .split('>')
                .next()
                .unwrap_or("")
                .contains(" time=\"")),
        "every case has its time\n{xml}"
    );

    let (_, _, err) = twin(&["test", "-v", failing.to_str().unwrap()]);
    assert!(err.contains(" INFO "), "-v shows the runs' news\n{err}");
}

/// The twin's run started with `args` (in real time), its stderr lines read until `until`
/// says it is ready; the child, those lines, and the rest drained.
fn started(args: &[&str], until: &str) -> (std::process::Child, Vec<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .current_dir(repo())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = Vec::new();
    for l in lines.by_ref().map_while(Result::ok) {
        let done = l.contains(until);
        seen.push(l);
        if done {
            break;
        }
    }
    std::thread::spawn(move || lines.for_each(drop));
    (child, seen)
}

/// The command a hint line suggests, as arguments of the twin's binary.
fn hint(line: &str) -> Vec<String> {
    let cmd = line
        .split("(try: ")
        .nth(1)
        .and_then(|r| r.split(')').next())
        .unwrap_or_else(|| panic!("no hint in {line:?}"));
    cmd.split(" then ")
        .next()
        .unwrap_or(cmd)
        .trim_end_matches(',')
        .split_whitespace()
        .map(str::to_owned)
        .collect()
}

/// A KISS link that holds payload 12's address: its hint names an address the link lets
/// `gs` send from and a node that answers there, and following it works. A node's console
/// is announced as a console, with a hint that reaches it.
#[test]
fn the_hints_work_when_followed() {
    let (mut child, lines) = started(
        &[
            "run",
            "--realtime",
            "--no-checks",
            "--duration",
            "60s",
            "--kiss-listen",
            "127.0.0.1:0",
            "--kiss-addr",
            "12",
            "--uart",
            "FC=127.0.0.1:0",
        ],
        "console of FC (UART)",
    );
    let kiss = lines
        .iter()
        .find(|l| l.starts_with("KISS/TCP: listening on "))
        .expect("the KISS server is announced");
    let console = lines
        .iter()
        .find(|l| l.starts_with("console of FC (UART)"))
        .expect("the console is announced as one");
    assert!(
        !console.contains("KISS") && !console.contains("gs --connect"),
        "{console}"
    );
    let gs = hint(kiss);
    assert_eq!(gs[..2], ["m6p-twin", "gs"], "{kiss}");
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(&gs[1..])
        .args(["--count", "2", "--interval", "100ms"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && said.contains("2 answered"),
        "following `{kiss}`: {said}{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let nc = hint(console);
    assert_eq!(nc[0], "nc", "{console}");
    let mut s = std::net::TcpStream::connect(format!("{}:{}", nc[1], nc[2])).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(5)))
        .unwrap();
    s.write_all(b"help\n").unwrap();
    let mut buf = [0u8; 256];
    let n = s.read(&mut buf).unwrap();
    assert!(n > 0, "the console answers");
    let _ = child.kill();
    let _ = child.wait();
}

/// A session run appears in the end-of-run table (session, payload, times, result,
/// packets, bytes), and `--downlink-dir` puts its bytes where asked.
#[test]
fn the_end_of_run_table_lists_the_sessions_and_the_downlink_goes_where_asked() {
    let scenario = tmp("session.toml");
    std::fs::write(&scenario, common::ONE_SESSION_SCENARIO).unwrap();
    let dir = tmp("downlink");
    let _ = std::fs::remove_dir_all(&dir);
    let (code, out, err) = twin(&[
        "run",
        scenario.to_str().unwrap(),
        "--downlink-dir",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    let table: Vec<&str> = out
        .lines()
        .skip_while(|l| *l != "payload sessions:")
        .skip(2)
        .take_while(|l| !l.is_empty())
        .collect();
    assert_eq!(table.len(), 1, "{out}");
    let cells: Vec<&str> = table[0].split_whitespace().collect();
    assert_eq!(cells[..3], ["4", "14", "1"], "session, payload, run: {out}");
    assert_eq!(cells[5], "done", "{out}");
    let bytes: u64 = cells[7].parse().unwrap();
    assert!(bytes > 0, "{out}");
    let file = dir.join("session-4-run1.bin");
    assert_eq!(
        std::fs::metadata(&file).map(|m| m.len()).ok(),
        Some(bytes),
        "{} holds the run's bytes\n{err}",
        file.display()
    );
}

/// A program that sends from an address a simulated node holds (a payload program at 12 on
/// a link given no address) is refused, and the warning names the flag that would give it
/// that node's place.
#[test]
fn a_program_refused_a_nodes_address_is_told_the_flag_that_gives_it() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args([
            "run",
            "--realtime",
            "--no-checks",
            "--duration",
            "60s",
            "--kiss-listen",
            "127.0.0.1:0",
        ])
        .current_dir(repo())
        .env_remove("RUST_LOG")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let at = lines
        .by_ref()
        .map_while(Result::ok)
        .find_map(|l| {
            l.strip_prefix("KISS/TCP: listening on ")
                .and_then(|r| r.split_whitespace().next())
                .map(str::to_owned)
        })
        .expect("the KISS server is announced");
    let rest = std::thread::spawn(move || lines.map_while(Result::ok).collect::<Vec<_>>());
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(["gs", "--connect", &at, "--as", "12", "--timeout", "300ms"])
        .args(["ping", "6", "--count", "1"])
        .output()
        .unwrap();
    assert!(
        !out.status.success(),
        "PL12 runs: the program's ping is refused"
    );
    let _ = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status();
    let _ = child.wait();
    let err = rest.join().unwrap().join("\n");
    assert!(
        err.contains("address 12 is held by PL12, a node of the twin")
            && err.contains("`--kiss-addr 12` after the link's flag")
            && err.contains(r#"`replaces = ["PL12"]`"#),
        "{err}"
    );
}
