//! SIGINT and SIGTERM stop a run the same way, and an interruption never looks like a
//! result: the report says `interrupted at T of D`, the exit status is not 0, JUnit marks
//! the case as an error, the recording is complete up to the stop. A campaign keeps its
//! finished runs, marks the others `not run` (no failure file) and `--resume` completes it
//! as an uninterrupted run would have. A run over its limit is an error row, never a hang.
//! SIGTERM is what Slurm, Kubernetes, systemd and docker send; an interrupted run whose
//! checks held so far is not a pass.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

mod common;

use common::twin_process::{output_text as text, twin};

fn dir(name: &str) -> PathBuf {
    common::twin_process::test_dir("interruption", name)
}

/// Start `cmd`, send it `signal` after `after`, and collect it.
fn signalled(mut cmd: Command, signal: &str, after: Duration) -> Output {
    let child: Child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(after);
    Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    child.wait_with_output().unwrap()
}

/// A scenario in real time for 60 s (GS16 pings the FC every second), which holds so far
/// whenever it is stopped.
fn realtime(d: &Path) -> PathBuf {
    let p = d.join("realtime.toml");
    std::fs::write(
        &p,
        r#"name = "realtime"
duration = "60s"

[clock]
mode = "realtime"

[[commands]]
name = "ping-fc"
at = "1s"
every = "1s"
count = 50
to = "FC"
request = "ping"

[[expectations]]
kind = "reply"
command = "ping-fc"
occurrence = "any"
"#,
    )
    .unwrap();
    p
}

#[test]
fn sigterm_and_sigint_stop_a_recorded_run_with_its_report_a_failure_status_and_a_whole_file() {
    let d = dir("run");
    let scenario = realtime(&d);
    for signal in ["-TERM", "-INT"] {
        let rec = d.join(format!("run{signal}.mcap"));
        let mut cmd = twin();
        cmd.args([
            "run",
            scenario.to_str().unwrap(),
            "--record",
            rec.to_str().unwrap(),
        ]);
        let out = signalled(cmd, signal, Duration::from_secs(3));
        let said = text(&out);
        let name = if signal == "-TERM" {
            "SIGTERM"
        } else {
            "SIGINT"
        };
        assert!(!out.status.success(), "{signal}: exit 0\n{said}");
        assert!(
            said.contains("interrupted at ") && said.contains(&format!("of 1m ({name})")),
            "{signal}:\n{said}"
        );
        let summary = m6p_twin::recording::read_summary(&rec).unwrap();
        assert!(
            summary.incomplete.is_none(),
            "{signal}: {:?}",
            summary.incomplete
        );
        let last = m6p_twin::recording::messages(&rec)
            .unwrap()
            .map(Result::unwrap)
            .map(|m| m.log_time)
            .max()
            .unwrap();
        assert!(
            last >= 2_000_000_000,
            "{signal}: the last message at {last} ns"
        );
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn an_interrupted_test_is_an_error_case_in_junit_and_fails() {
    let d = dir("test");
    let scenario = realtime(&d);
    let junit = d.join("junit.xml");
    let mut cmd = twin();
    cmd.args([
        "test",
        scenario.to_str().unwrap(),
        "--junit",
        junit.to_str().unwrap(),
    ]);
    let out = signalled(cmd, "-TERM", Duration::from_secs(3));
    let said = text(&out);
    assert!(!out.status.success(), "exit 0\n{said}");
    let xml = std::fs::read_to_string(&junit).unwrap();
    assert!(
        xml.contains("<error") && xml.contains("interrupted at ") && !xml.contains(r#"errors="0""#),
        "{xml}"
    );
    std::fs::remove_dir_all(&d).ok();
}

/// Thirty runs of 2 simulated hours on one job (a few tenths of a second each): SIGTERM
/// after 3 s keeps the finished ones, marks the others not run (no failure file), and
/// `--resume` completes it; the outputs are then those of a campaign never stopped.
#[test]
fn a_stopped_campaign_keeps_its_results_and_resumes_to_the_uninterrupted_outputs() {
    let d = dir("campaign");
    std::fs::write(
        d.join("c.toml"),
        r#"runs = 30
seed = 2

[dispersions]
"commands[0].at" = { choice = ["1s", "5s"] }

[scenario]
name = "long"
duration = "2h"

[[scenario.commands]]
name = "ping-fc"
at = "1s"
to = "FC"
request = "ping"

[[scenario.expectations]]
kind = "reply"
command = "ping-fc"
within = "3s"
"#,
    )
    .unwrap();
    let campaign = |out: &str, resume: bool| {
        let mut c = twin();
        c.current_dir(&d)
            .args(["campaign", "run", "c.toml", "--jobs", "1", "--out", out]);
        if resume {
            c.arg("--resume");
        }
        c
    };
    let stopped = signalled(campaign("stopped", false), "-TERM", Duration::from_secs(3));
    let said = text(&stopped);
    assert!(!stopped.status.success(), "{said}");
    let csv = std::fs::read_to_string(d.join("stopped/results.csv")).unwrap();
    let not_run = csv.lines().filter(|l| l.contains(",not run,")).count();
    assert!((1..30).contains(&not_run), "{csv}\n{said}");
    for f in std::fs::read_dir(d.join("stopped/failures"))
        .into_iter()
        .flatten()
    {
        let run: u64 = f.unwrap().file_name().to_str().unwrap()[4..]
            .split('.')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        let row = csv
            .lines()
            .find(|l| l.starts_with(&format!("{run},")))
            .unwrap();
        assert!(row.contains(",fail,") || row.contains(",error,"), "{row}");
    }
    let resumed = campaign("stopped", true).output().unwrap();
    assert!(
        text(&resumed).contains("results kept"),
        "{}",
        text(&resumed)
    );
    let whole = campaign("whole", false).output().unwrap();
    assert_eq!(resumed.status.code(), whole.status.code());
    for f in [
        "results.csv",
        "rows.jsonl",
        "junit.xml",
        "report.html",
        "campaign.json",
    ] {
        assert_eq!(
            std::fs::read(d.join("stopped").join(f)).unwrap(),
            std::fs::read(d.join("whole").join(f)).unwrap(),
            "{f}"
        );
    }
    std::fs::remove_dir_all(&d).ok();
}

/// A run drawn to last ten years: an error row at once (over the campaign's simulated
/// limit of 30 days); one drawn to last 20 days, under it, is stopped at its wall-clock
/// limit (2 s here), an error row; the others pass.
#[test]
fn runs_over_the_campaigns_limits_are_error_rows() {
    let d = dir("limits");
    std::fs::write(
        d.join("c.toml"),
        r#"runs = 4
seed = 4

[dispersions]
duration = { choice = ["3650d", "20d", "10s", "10s"] }

[limits]
simulated = "30d"
wall = "2s"

[scenario]
name = "limits"
duration = "10s"
"#,
    )
    .unwrap();
    let out = twin()
        .current_dir(&d)
        .args(["campaign", "run", "c.toml", "--out", "out"])
        .output()
        .unwrap();
    let csv = std::fs::read_to_string(d.join("out/results.csv")).unwrap();
    let long: Vec<&str> = csv.lines().filter(|l| l.contains("3650d")).collect();
    assert!(!long.is_empty(), "{csv}");
    for l in &long {
        assert!(
            l.contains(",error,") && l.contains("over the campaign's limit"),
            "{l}"
        );
    }
    let stopped: Vec<&str> = csv.lines().filter(|l| l.contains(",20d,")).collect();
    for l in &stopped {
        assert!(
            l.contains(",error,") && l.contains("([limits] wall)"),
            "{l}"
        );
    }
    assert_eq!(
        csv.lines().filter(|l| l.contains(",pass,")).count(),
        4 - long.len() - stopped.len(),
        "{csv}\n{}",
        text(&out)
    );
    assert!(!stopped.is_empty(), "no run drew 20 days: {csv}");
    std::fs::remove_dir_all(&d).ok();
}
