//! `run --snapshot-at T --snapshot FILE` and `run --from-snapshot FILE` (docs/snapshots.md):
//! a run started from a snapshot reports what the uninterrupted run reports (its nodes'
//! counts, its media, its requests, its verdicts), and a snapshot that is not this run's
//! (cut short, corrupted, of another scenario or seed) is refused naming the file and why.
#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::process::{Command, Output};

fn twin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
}

fn run(args: &[&str]) -> Output {
    twin().arg("run").args(args).output().unwrap()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The report without the line that says how fast it ran.
fn report(o: &Output) -> String {
    stdout(o)
        .lines()
        .filter(|l| !l.starts_with("simulated "))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn a_run_from_a_snapshot_reports_what_the_whole_run_reports() {
    let dir = tempfile::tempdir().unwrap();
    let snap = dir.path().join("default.snap");
    let snap = snap.to_str().unwrap();
    let plain = run(&["--duration", "20m"]);
    assert!(plain.status.success(), "{}", stderr(&plain));
    let taken = run(&[
        "--duration",
        "20m",
        "--snapshot-at",
        "7m,13m",
        "--snapshot",
        snap,
    ]);
    assert!(taken.status.success(), "{}", stderr(&taken));
    assert_eq!(
        report(&taken),
        report(&plain),
        "taking snapshots changes nothing"
    );
    for ns in ["420000000000", "780000000000"] {
        let file = dir.path().join(format!("default.{ns}ns.snap"));
        assert!(
            stderr(&taken).contains(&format!("snapshot: {}", file.display())),
            "{}",
            stderr(&taken)
        );
        let resumed = run(&[
            "--duration",
            "20m",
            "--from-snapshot",
            file.to_str().unwrap(),
        ]);
        assert!(resumed.status.success(), "{}", stderr(&resumed));
        assert!(report(&resumed).contains("11 passed, 0 failed"));
        assert_eq!(report(&resumed), report(&plain), "from {ns} ns");
    }
}

/// `run --record` from a snapshot taken by a recorded run: `diff --from T` finds the
/// recording the same as the whole run's from T on, and says it is identical.
#[test]
fn a_recorded_run_from_a_snapshot_records_what_the_whole_run_recorded_from_there() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let (snap, whole, resumed) = (path("w.snap"), path("w.mcap"), path("r.mcap"));
    let taken = run(&[
        "--duration",
        "20m",
        "--record",
        &whole,
        "--snapshot-at",
        "10m",
        "--snapshot",
        &snap,
    ]);
    assert!(taken.status.success(), "{}", stderr(&taken));
    let from = run(&[
        "--duration",
        "20m",
        "--record",
        &resumed,
        "--from-snapshot",
        &snap,
    ]);
    assert!(from.status.success(), "{}", stderr(&from));
    // The same report but for the recording's line (the resumed file holds the second half).
    assert_eq!(without_recorded(&from), without_recorded(&taken));
    identical_from(&["diff", &whole, &resumed, "--from", "10m"], "10m");
    // Compared from the start, the resumed recording lacks the first ten minutes.
    let diff = twin().args(["diff", &whole, &resumed]).output().unwrap();
    assert!(!diff.status.success(), "{}", stdout(&diff));
    // The recorded run's snapshot serves a run that does not record, too.
    let plain = run(&["--duration", "20m", "--from-snapshot", &snap]);
    assert!(plain.status.success(), "{}", stderr(&plain));
    assert_eq!(
        without_recorded(&plain).trim(),
        without_recorded(&taken).trim()
    );
    // It carries the snapshot it started from: `replay` starts there and compares from it.
    identical_from(&["replay", &resumed], "10m");
}

/// `m6p-twin ARGS` succeeds, saying the two recordings are identical from `from` on.
fn identical_from(args: &[&str], from: &str) -> Output {
    let o = twin().args(args).output().unwrap();
    let out = stdout(&o);
    assert!(o.status.success(), "{args:?}: {out}{}", stderr(&o));
    assert!(
        out.contains(&format!("from t = {from} on\nidentical")),
        "{args:?}: {out}"
    );
    o
}

/// Every message of a recording (channel, sequence, times, bytes), in file order.
fn messages(path: &str) -> Vec<(u16, u32, u64, u64, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            let head = (m.channel.id, m.sequence, m.log_time, m.publish_time);
            (head.0, head.1, head.2, head.3, m.data.to_vec())
        })
        .collect()
}

/// A recording carrying snapshots (`--snapshot-every`) holds the same messages as one
/// without; `replay --from T` starts from the latest one at or before T and compares from T.
#[test]
fn replay_from_starts_at_the_recordings_latest_snapshot_before_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let (plain, carrying) = (path("plain.mcap"), path("carrying.mcap"));
    let o = run(&["--duration", "20m", "--record", &plain]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(&[
        "--duration",
        "20m",
        "--record",
        &carrying,
        "--snapshot-every",
        "5m",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        messages(&plain) == messages(&carrying),
        "carrying snapshots changes no message"
    );
    let replay = identical_from(&["replay", &carrying, "--from", "12m"], "12m");
    assert!(
        stderr(&replay).contains("replaying from its snapshot at 600.000000000s"),
        "{}",
        stderr(&replay)
    );
    // Before the first snapshot: from the start.
    let replay = twin()
        .args(["replay", &carrying, "--from", "4m"])
        .output()
        .unwrap();
    assert!(replay.status.success(), "{}", stdout(&replay));
    assert!(!stderr(&replay).contains("replaying from its snapshot"));
    // Too many snapshots for the run are refused, naming the setting.
    let o = run(&[
        "--duration",
        "20m",
        "--record",
        &path("x.mcap"),
        "--snapshot-every",
        "1s",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("record.snapshot_every: would carry 1200 snapshots"),
        "{}",
        stderr(&o)
    );
}

/// The report without its line about the recording.
fn without_recorded(o: &Output) -> String {
    report(o)
        .lines()
        .filter(|l| !l.starts_with("recorded "))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Each refused with the file's name and why; nothing runs.
#[test]
fn a_snapshot_not_of_this_run_is_refused_naming_the_file_and_why() {
    let dir = tempfile::tempdir().unwrap();
    let snap = dir.path().join("x.snap");
    let taken = run(&[
        "--duration",
        "5m",
        "--snapshot-at",
        "2m",
        "--snapshot",
        snap.to_str().unwrap(),
    ]);
    assert!(taken.status.success(), "{}", stderr(&taken));
    let bytes = std::fs::read(&snap).unwrap();
    let write = |name: &str, b: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, b).unwrap();
        p
    };
    let cut = write("cut.snap", &bytes[..bytes.len() / 2]);
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x10;
    let corrupted = write("corrupted.snap", &flipped);
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/eps-day.toml");
    let cases: [(Vec<String>, &Path, &str); 5] = [
        (vec![], &cut, "cut short or padded"),
        (vec![], &corrupted, "corrupted: CRC-32C"),
        (
            vec![scenario.display().to_string()],
            &snap,
            "a snapshot of scenario `default`, not of `eps-day`",
        ),
        (
            vec!["--seed".into(), "7".into()],
            &snap,
            "a snapshot of the run with seed 1, not 7",
        ),
        (
            vec![
                "--record".into(),
                dir.path().join("r.mcap").display().to_string(),
            ],
            &snap,
            "taken by a run that did not record",
        ),
    ];
    for (args, file, why) in cases {
        let o = twin()
            .arg("run")
            .args(&args)
            .args(["--duration", "5m", "--from-snapshot"])
            .arg(file)
            .output()
            .unwrap();
        let err = stderr(&o);
        assert!(!o.status.success(), "{why}: refused");
        assert!(
            err.contains(&format!(
                "{}: ",
                file.file_name().unwrap().to_string_lossy()
            )) && err.contains(why),
            "{why}: {err}"
        );
        assert!(!stdout(&o).contains("simulated "), "{why}: nothing ran");
    }
}

/// Two runs of a session (set up at 20 s and at 40 s), each downlinking to
/// `DIR/session-1-run<k>.bin`; `{DIR}` is the downlink folder.
const TWO_RUNS: &str = r#"name = "two-runs"
duration = "50s"

[network]
payloads = [12, 13]

[pc]
downlink_dir = "{DIR}"

[[pc.sessions]]
id = 1
payload = 12
mode = "polling"
poll_period = "100ms"
reply_timeout = "1s"

[[commands]]
at = "20s"
to = "PC"
request = "raw"
port = 10
data = "01 01 00000000 0a00 1900 c8 68656c6c6f2066726f6d20746865205043"

[[commands]]
at = "40s"
to = "PC"
request = "raw"
port = 10
data = "01 01 00000000 0a00 1900 c8 68656c6c6f2066726f6d20746865205043"
"#;

/// A run from a snapshot numbers its session runs' downlink files on from the snapshot's
/// (the second run is `run2`, whatever the process), and a run under way at the snapshot
/// goes on in its file, cut back to what it held then: the files end as the whole run's.
#[test]
fn a_run_from_a_snapshot_goes_on_with_the_downlink_files_where_they_were() {
    let dir = tempfile::tempdir().unwrap();
    let down = dir.path().join("down");
    let file = dir.path().join("two-runs.toml");
    std::fs::write(&file, TWO_RUNS.replace("{DIR}", down.to_str().unwrap())).unwrap();
    let (file, snap) = (file.to_str().unwrap(), dir.path().join("s.snap"));
    let whole = run(&[
        file,
        "--snapshot-at",
        "30s,41s",
        "--snapshot",
        snap.to_str().unwrap(),
    ]);
    assert!(whole.status.success(), "{}", stderr(&whole));
    let read = |k: u32| std::fs::read(down.join(format!("session-1-run{k}.bin"))).unwrap();
    let (run1, run2) = (read(1), read(2));
    assert!(!run1.is_empty() && !run2.is_empty());

    // Between the runs: the second run's file is run2, and the first is not written.
    std::fs::remove_dir_all(&down).unwrap();
    let between = dir.path().join("s.30000000000ns.snap");
    let o = run(&[file, "--from-snapshot", between.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(read(2), run2);
    assert!(!down.join("session-1-run1.bin").exists());

    // Mid-run, over the whole run's files: run2 is cut back and goes on to the same bytes,
    // run1 is left as it was.
    std::fs::write(down.join("session-1-run1.bin"), &run1).unwrap();
    std::fs::write(down.join("session-1-run2.bin"), &run2).unwrap();
    let mid = dir.path().join("s.41000000000ns.snap");
    let o = run(&[file, "--from-snapshot", mid.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!((read(1), read(2)), (run1, run2.clone()));
    // Without the file, it holds what came after the snapshot: the run's tail.
    std::fs::remove_dir_all(&down).unwrap();
    let o = run(&[file, "--from-snapshot", mid.to_str().unwrap()]);
    assert!(
        stderr(&o).contains("holds only what is downlinked from the snapshot on"),
        "{}",
        stderr(&o)
    );
    let tail = read(2);
    assert!(!tail.is_empty() && tail.len() < run2.len());
    assert!(run2.ends_with(&tail));
    // Another run's file of that name is not taken for this one's: it starts afresh.
    std::fs::write(down.join("session-1-run2.bin"), vec![0xAA; run2.len()]).unwrap();
    let o = run(&[file, "--from-snapshot", mid.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(read(2), tail);
}
