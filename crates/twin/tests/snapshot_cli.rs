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
            "a run from a snapshot is not recorded yet",
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
