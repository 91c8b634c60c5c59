//! A recording is never lost, overwritten or mixed without a word: a file at its name is
//! refused unless `--overwrite` (the scenario itself always), two runs onto one name leave
//! one recording and an error, a write error is reported when it happens and the run still
//! prints its report and fails, and a run on the wall clock killed with SIGKILL leaves what
//! it recorded up to its last second (a real-time recording written only as 4 MiB chunks
//! close would reach the disk after 36 simulated minutes of the default scenario).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

mod common;

use common::twin_process::{output_text as text, twin};

fn dir(name: &str) -> PathBuf {
    common::twin_process::test_dir("recording-safety", name)
}

fn scenario(d: &Path, clock: &str, secs: u64) -> PathBuf {
    let p = d.join(format!("s-{clock}-{secs}.toml"));
    std::fs::write(
        &p,
        format!("name = \"s\"\nduration = \"{secs}s\"\n\n[clock]\nmode = \"{clock}\"\n"),
    )
    .unwrap();
    p
}

/// `m6p-twin run SCENARIO --record REC` and `extra` arguments.
fn run_recording(scenario: &Path, rec: &Path, extra: &[&str]) -> Command {
    let mut c = twin();
    c.arg("run")
        .arg(scenario)
        .arg("--record")
        .arg(rec)
        .args(extra);
    c
}

/// The files in `d` whose names start with `prefix`.
fn files(d: &Path, prefix: &str) -> Vec<PathBuf> {
    std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_str().unwrap().starts_with(prefix))
        .collect()
}

#[test]
fn a_file_at_the_recordings_name_is_refused_unless_overwrite_and_the_scenario_always() {
    let d = dir("existing");
    let s = scenario(&d, "virtual", 30);
    let rec = d.join("taken.mcap");
    std::fs::write(&rec, b"precious").unwrap();
    let out = run_recording(&s, &rec, &[]).output().unwrap();
    assert!(!out.status.success(), "{}", text(&out));
    assert!(
        text(&out).contains("exists: not replaced"),
        "{}",
        text(&out)
    );
    assert_eq!(std::fs::read(&rec).unwrap(), b"precious");
    // --overwrite replaces it with a whole recording.
    let out = run_recording(&s, &rec, &["--overwrite"]).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        m6p_twin::recording::read_summary(&rec)
            .unwrap()
            .incomplete
            .is_none()
    );
    // The scenario itself, never.
    let before = std::fs::read(&s).unwrap();
    let out = run_recording(&s, &s, &["--overwrite"]).output().unwrap();
    assert!(!out.status.success());
    assert!(
        text(&out).contains("is the scenario itself"),
        "{}",
        text(&out)
    );
    assert_eq!(std::fs::read(&s).unwrap(), before);
    // Nothing left beside the names.
    assert!(files(&d, ".").is_empty(), "{:?}", files(&d, "."));
    std::fs::remove_dir_all(&d).ok();
}

/// Two runs onto one name at once: one places its recording, the other is refused with an
/// error that says where its own is; the file at the name is one run's whole recording.
#[test]
fn two_runs_onto_one_name_leave_one_recording_and_an_error() {
    let d = dir("two");
    let s = scenario(&d, "realtime", 2);
    let rec = d.join("both.mcap");
    let start = || {
        run_recording(&s, &rec, &[])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (start(), start());
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let ok = [&a, &b].iter().filter(|o| o.status.success()).count();
    assert_eq!(ok, 1, "{}\n{}", text(&a), text(&b));
    let refused = if a.status.success() { &b } else { &a };
    assert!(text(refused).contains("not replaced"), "{}", text(refused));
    assert!(
        m6p_twin::recording::read_summary(&rec)
            .unwrap()
            .incomplete
            .is_none()
    );
    std::fs::remove_dir_all(&d).ok();
}

/// A real-time run killed with SIGKILL (no chance to finish its file) after 3 s leaves its
/// recording beside the name, readable to within its last second.
#[test]
fn a_killed_real_time_run_leaves_what_it_recorded_up_to_its_last_second() {
    let d = dir("killed");
    let s = scenario(&d, "realtime", 60);
    let rec = d.join("killed.mcap");
    let child = run_recording(&s, &rec, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(3500));
    Command::new("kill")
        .args(["-KILL", &child.id().to_string()])
        .status()
        .unwrap();
    let _ = child.wait_with_output();
    assert!(!rec.exists(), "a half-written file at the name");
    let partial = files(&d, ".killed.mcap.");
    assert_eq!(partial.len(), 1, "{partial:?}");
    let last = m6p_twin::recording::messages(&partial[0])
        .unwrap()
        .map_while(Result::ok)
        .map(|m| m.log_time)
        .max()
        .unwrap_or(0);
    assert!(last >= 2_000_000_000, "the last message kept at {last} ns");
    std::fs::remove_dir_all(&d).ok();
}

/// A recording of the default scenario (3 hours, many 4 MiB chunks) onto a file system that
/// fills up (a 64 KiB tmpfs): a warning when the first chunk's write fails, naming the byte
/// and where what was recorded is; the run goes on, prints its report and exits 1.
#[test]
#[cfg_attr(
    not(mount_tmpfs),
    ignore = "needs root on Linux to mount a 64 KiB tmpfs (CI runs as root)"
)]
fn a_full_disk_is_reported_when_it_happens_and_the_run_still_reports() {
    let d = dir("full");
    let mnt = d.join("tiny");
    std::fs::create_dir_all(&mnt).unwrap();
    let mounted = Command::new("mount")
        .args([
            "-t",
            "tmpfs",
            "-o",
            "size=64k",
            "tmpfs",
            mnt.to_str().unwrap(),
        ])
        .status()
        .unwrap();
    assert!(
        mounted.success(),
        "mount a 64 KiB tmpfs at {}",
        mnt.display()
    );
    let out = twin()
        .args(["run", "--record", mnt.join("full.mcap").to_str().unwrap()])
        .output()
        .unwrap();
    let _ = Command::new("umount").arg(&mnt).status();
    let said = text(&out);
    assert!(!out.status.success(), "{said}");
    assert!(
        said.contains("WARN")
            && said.contains("stopped at byte")
            && said.contains("the run goes on"),
        "{said}"
    );
    assert!(said.contains("simulated 10800.000 s"), "the report: {said}");
    assert!(said.contains("the recording failed"), "{said}");
    std::fs::remove_dir_all(&d).ok();
}
