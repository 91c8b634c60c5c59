//! A campaign's failure file reproduces its failure by itself: the invariants the campaign
//! checks are written into it (`[invariants] check = "all"`), `m6p-twin test` checks them,
//! and its "Reproduce:" line works from where the campaign was run (not relative to the
//! campaign's output folder). Were the invariants not in the file, `m6p-twin test` would
//! pass a run that broke one.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;

fn twin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
}

/// Three runs whose GS16 pings the FC 20 times a second (drawn: 20 or 30 pings), against a
/// `no-reply-storm` bound of 1 packet a second over 10 s: every run breaks it.
const CAMPAIGN: &str = r#"
runs = 3
seed = 5

[dispersions]
"commands[0].count" = { choice = [20, 30] }

[scenario]
name = "storm"
duration = "12s"

[invariants.no_reply_storm]
packets_per_s = 1
window = "10s"

[[scenario.commands]]
name = "pings"
at = "1s"
every = "50ms"
count = 20
to = "FC"
request = "ping"
"#;

#[test]
fn every_failure_file_fails_m6p_twin_test_the_same_way_from_the_users_directory() {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("campaign-reproduce-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The table goes to the scenario, as a campaign's base scenario holds it.
    let campaign = CAMPAIGN.replace("[invariants.", "[scenario.invariants.");
    std::fs::write(dir.join("storm.toml"), campaign).unwrap();
    let out = twin()
        .current_dir(&dir)
        .args(["campaign", "run", "storm.toml", "--out", "results"])
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the campaign passed:\n{text}");
    let failures: Vec<PathBuf> = std::fs::read_dir(dir.join("results/failures"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    assert_eq!(failures.len(), 3, "{text}");
    for f in failures {
        let body = std::fs::read_to_string(&f).unwrap();
        let line = body
            .lines()
            .find_map(|l| l.strip_prefix("# Reproduce: "))
            .unwrap();
        let words: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(words[..2], ["m6p-twin", "test"], "{line}");
        let again = twin().current_dir(&dir).args(&words[1..]).output().unwrap();
        let said = String::from_utf8_lossy(&again.stdout).into_owned()
            + &String::from_utf8_lossy(&again.stderr);
        assert!(
            !again.status.success()
                && said.contains(": invariant no-reply-storm (t = ")
                && said.lines().any(|l| l.starts_with("FAIL ")),
            "{line}:\n{said}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
