//! `m6p-twin gs --help` and `m6p-twin inspect` as a user meets them: the help shows the
//! ICD-by-name form and the console, each with an example; `inspect` of a recording lists
//! its PC session runs with their downlink files; `inspect --csv ... | head` ends quietly.
#![allow(clippy::unwrap_used)]

use std::io::BufRead as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

mod common;

use common::ONE_SESSION_SCENARIO as SESSION_SCENARIO;

fn twin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
}

/// A directory of this test's own under the target directory.
fn tmp_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("gs-inspect-cli-{}-{name}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The session scenario recorded to `dir/run.mcap` (its downlink beside it).
fn recorded(dir: &Path) -> PathBuf {
    let scenario = dir.join("inspect-sessions.toml");
    std::fs::write(&scenario, SESSION_SCENARIO).unwrap();
    let rec = dir.join("run.mcap");
    let out = twin()
        .arg("run")
        .arg(&scenario)
        .arg("--record")
        .arg(&rec)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    rec
}

#[test]
fn gs_help_shows_icd_commands_by_name_and_the_console_with_examples() {
    let out = twin().args(["gs", "--help"]).output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for shown in [
        // The ICD-by-name form and an example of it.
        "m6p-twin gs --connect ADDR NODE COMMAND [NAME=VALUE ...]",
        "m6p-twin gs --connect 127.0.0.1:52001 fc tmgen\n",
        "pc setup session_id=1 timestamp=now",
        // The console, how to start it, and an example line.
        "The console (interactive): give no request.",
        "    m6p-twin gs --connect 127.0.0.1:52001\n",
        "Tab",
        "`raw 6 12 01`",
    ] {
        assert!(help.contains(shown), "`gs --help` lacks {shown:?}:\n{help}");
    }
}

#[test]
fn inspect_lists_each_pc_session_run_with_its_downlink_file() {
    let dir = tmp_dir("sessions");
    let rec = recorded(&dir);
    let out = twin().arg("inspect").arg(&rec).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    let head = "PC session runs (/pc/sessions/summary, in the order they ended):";
    let mut lines = text.lines().skip_while(|l| *l != head);
    assert_eq!(lines.next(), Some(head), "{text}");
    let columns = lines.next().unwrap();
    for c in [
        "session",
        "payload",
        "result",
        "packets",
        "downlinked",
        "downlink file",
    ] {
        assert!(columns.contains(c), "{columns}");
    }
    let file = dir.join("run.downlink").join("session-4-run1.bin");
    let bytes = std::fs::metadata(&file).unwrap().len();
    assert_eq!(bytes, 60_000);
    let row: Vec<&str> = lines.next().unwrap().split_whitespace().collect();
    // session, payload, result, packets, bytes B, start s, end s, file (its size B).
    assert_eq!(row[..3], ["4", "14", "done"], "{text}");
    assert_eq!(row[3], "600", "{text}");
    assert_eq!(row[4..6], ["60000", "B"], "{text}");
    assert_eq!(row[8], file.display().to_string(), "{text}");
    assert_eq!(row[9], format!("({bytes}"), "{text}");
    assert_eq!(lines.next(), None, "one run only:\n{text}");

    // Without the downlink directory the run is still listed, without a file.
    std::fs::remove_dir_all(dir.join("run.downlink")).unwrap();
    let out = twin().arg("inspect").arg(&rec).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let row = text.lines().last().unwrap();
    assert!(
        row.trim_start().starts_with("4 ") && row.ends_with("  -"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn inspect_csv_into_a_reader_that_stops_early_ends_quietly_with_success() {
    let dir = tmp_dir("pipe");
    let rec = recorded(&dir);
    // `inspect --csv /csp/packets REC | head -1`: some 270 kB for a pipe of 64 kB.
    let mut child = twin()
        .args(["inspect", "--csv", "/csp/packets"])
        .arg(&rec)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    // The reader (and with it the pipe) is gone here, long before the last row.
    assert!(first.starts_with("log_time_ns,"), "{first}");
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert_eq!(err, "");
    std::fs::remove_dir_all(&dir).ok();
}
