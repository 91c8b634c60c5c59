//! A campaign's payload sessions reach its report: `report.html`'s Sessions section counts,
//! per session id, the runs it ran in and its session runs by how they ended (as each run's
//! end-of-run table would), with the runs where one ended other than done; `campaign run`
//! prints the same on the terminal; `results.csv` has a column per session and end; and
//! shards merged give the same page.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// Six runs of two polling sessions one after the other: session 1 with payload 12, whose
/// behaviour is drawn (`no-ack`: the session ends NO ACK at once), then session 4 with
/// payload 14, always healthy.
const CAMPAIGN: &str = r#"
name = "sessions"
runs = 6
seed = 2

[dispersions]
"payload[0].behaviour" = { choice = ["normal", "no-ack"] }

[scenario]
name = "sessions"
duration = "30s"
network.payloads = [12, 14]

[[scenario.pc.sessions]]
id = 1
payload = 12
mode = "polling"

[[scenario.pc.sessions]]
id = 4
payload = 14
mode = "polling"

[[scenario.payload]]
addr = 12
behaviour = "normal"

[[scenario.commands]]
name = "setup-1"
at = "2s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 1, timestamp = "now", duration_s = 8, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }

[[scenario.commands]]
name = "setup-4"
at = "14s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 4, timestamp = "now", duration_s = 8, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }
"#;

fn twin(dir: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .current_dir(dir)
        .args(args)
        .env_remove("RUST_LOG")
        .env_remove("CI")
        // Not a shard of a cluster job this test may run in.
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
    )
}

#[test]
fn the_campaign_report_counts_each_sessions_runs_by_how_they_ended() {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("campaign-sessions-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("sessions.toml"), CAMPAIGN).unwrap();
    let (ok, text) = twin(
        &dir,
        &[
            "campaign",
            "run",
            "sessions.toml",
            "--jobs",
            "1",
            "--out",
            "all",
        ],
    );
    assert!(ok, "every run passes:\n{text}");

    // What each run drew, from its row.
    let rows = std::fs::read_to_string(dir.join("all/rows.jsonl")).unwrap();
    let no_ack: Vec<u64> = rows
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|r| r["draws"]["payload[0].behaviour"] == "no-ack")
        .map(|r| r["run"].as_u64().unwrap())
        .collect();
    let (n_no_ack, n_done) = (no_ack.len(), 6 - no_ack.len());
    assert!(
        n_no_ack > 0 && n_done > 0,
        "the seed draws both behaviours: {rows}"
    );

    let html = std::fs::read_to_string(dir.join("all/report.html")).unwrap();
    let section: String = html
        .lines()
        .skip_while(|l| *l != "<h2>Sessions</h2>")
        .take_while(|l| *l != "</table>")
        .collect::<Vec<_>>()
        .join("\n");
    assert!(!section.is_empty(), "no Sessions section:\n{html}");
    assert!(
        section.contains(
            "<th>session</th><th>payload</th><th>ran in</th><th>done</th><th>no-ack</th><th>packets"
        ),
        "a column per end that happened:\n{section}"
    );
    // Session 1 ran in every run: done where the payload was healthy, NO ACK elsewhere,
    // and those runs listed (they passed: no failure file, no link).
    let listed = format!(
        "<b>no-ack</b>: {}",
        no_ack
            .iter()
            .map(|k| format!("run {k}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let one = format!(
        "<tr><td>1</td><td>12</td><td>6 of 6 runs</td><td>{n_done}</td><td>{n_no_ack}</td><td>0 / "
    );
    assert!(section.contains(&one), "{one}\n{section}");
    assert!(
        section.contains(&format!("<td>{listed}</td></tr>")),
        "{listed}\n{section}"
    );
    // Its packets and bytes: none in a NO ACK run, some in a healthy one.
    let cells = |session: &str| -> Vec<String> {
        let row = section
            .lines()
            .find(|l| l.starts_with(&format!("<tr><td>{session}</td>")))
            .unwrap();
        row.trim_start_matches("<tr><td>")
            .trim_end_matches("</td></tr>")
            .split("</td><td")
            .map(|c| c.rsplit('>').next().unwrap().to_owned())
            .collect()
    };
    let s1 = cells("1");
    let figures = |c: &str| -> Vec<u64> {
        c.split(" / ")
            .map(|x| x.split_whitespace().next().unwrap().parse().unwrap())
            .collect()
    };
    let (packets, bytes) = (figures(&s1[5]), figures(&s1[6]));
    assert!(
        s1[5].ends_with(" packets") && s1[6].ends_with(" B"),
        "{s1:?}"
    );
    assert_eq!((packets[0], bytes[0]), (0, 0), "{s1:?}");
    assert!(packets[2] > 0 && bytes[2] >= 100 * packets[2] / 2, "{s1:?}");
    // Session 4 ran in every run, done each time.
    let s4 = cells("4");
    assert_eq!(s4[..5], ["4", "14", "6 of 6 runs", "6", "0"], "{s4:?}");
    assert_eq!(s4[7], "-", "{s4:?}");

    // The terminal says the same.
    let line = text
        .lines()
        .skip_while(|l| *l != "sessions:")
        .nth(2)
        .unwrap_or_default();
    let words: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(
        words[..7],
        [
            "1",
            "12",
            "6",
            "of",
            "6",
            &n_done.to_string(),
            &n_no_ack.to_string()
        ],
        "{text}"
    );

    // results.csv: the session's columns, a count per end.
    let csv = std::fs::read_to_string(dir.join("all/results.csv")).unwrap();
    let head: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    for c in [
        "session_1_runs",
        "session_1_done",
        "session_1_no_ack",
        "session_1_packets",
        "session_1_downlinked_bytes",
        "session_4_done",
    ] {
        assert!(head.contains(&c), "{c}: {csv}");
    }
    let col = head.iter().position(|c| *c == "session_1_no_ack").unwrap();
    let sum: usize = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(col).unwrap().parse::<usize>().unwrap())
        .sum();
    assert_eq!(sum, n_no_ack, "{csv}");

    // Two shards merged: the same page.
    for i in 0..2 {
        let (ok, text) = twin(
            &dir,
            &[
                "campaign",
                "run",
                "sessions.toml",
                "--jobs",
                "1",
                "--shard",
                &format!("{i}/2"),
                "--out",
                &format!("shard-{i}"),
            ],
        );
        assert!(ok, "{text}");
    }
    let (ok, text) = twin(
        &dir,
        &["campaign", "merge", "shard-0", "shard-1", "--out", "merged"],
    );
    assert!(ok && text.contains("sessions:"), "{text}");
    for f in ["report.html", "results.csv", "rows.jsonl"] {
        assert_eq!(
            std::fs::read(dir.join("all").join(f)).unwrap(),
            std::fs::read(dir.join("merged").join(f)).unwrap(),
            "{f}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
