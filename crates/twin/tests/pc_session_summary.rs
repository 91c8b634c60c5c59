//! `/pc/sessions/summary`: one message per PC session run when it ends or is lost, read back
//! from a recorded run and checked against the run's own report and the recorded downlink.
//! A run without sessions has no such channel.
#![allow(clippy::unwrap_used)]

mod common;

use common::TempFile;

use m6p_twin::exec::{Loaded, RecordTo, execute_recorded_without_files};
use m6p_twin::plan::compile;
use m6p_twin::record::{DownlinkMsg, PcSessionSummaryMsg, TOPIC_PC_SESSION_SUMMARY};
use m6p_twin::runtime::build_runtime;
use m6p_twin::sessions::RunEnd;

/// Session 4 (payload 14) runs 5 s to DONE; then session 1 (payload 12) (the PC runs one
/// session at a time) is lost to a PC power cut at 30 s and set up again at 60 s for 30 s,
/// to DONE.
const SCENARIO: &str = r#"
name = "pc-session-summary"
duration = "120s"
seed = 3

[network]
payloads = [12, 14]

[[pc.sessions]]
id = 1
payload = 12
mode = "polling"

[[pc.sessions]]
id = 4
payload = 14
mode = "polling"

[[commands]]
name = "setup-1"
at = "12s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 1, timestamp = "now", duration_s = 40, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }

[[commands]]
name = "setup-4"
at = "5s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 4, timestamp = "now", duration_s = 5, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }

[[commands]]
name = "setup-1-again"
at = "60s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 1, timestamp = "now", duration_s = 30, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }

[[faults]]
at = "30s"
until = "45s"
kind = "power-off"
target = "PC"
"#;

/// Run `text` recorded to `rec`; the run's report.
fn run_recorded(text: &str, rec: &TempFile) -> m6p_twin::report::RunReport {
    let scenario = m6p_twin::scenario::parse("pc-session-summary.toml", text).unwrap();
    let loaded = Loaded {
        file: "pc-session-summary.toml".into(),
        text: text.into(),
        scenario,
    };
    let compiled = compile(&loaded.scenario);
    let rt = build_runtime().unwrap();
    let (out, stats) = rt
        .block_on(execute_recorded_without_files(
            &loaded,
            compiled,
            Some(RecordTo::replacing(rec.path())),
        ))
        .unwrap();
    stats.unwrap().unwrap();
    out.report
}

#[test]
fn each_session_run_is_summed_up_once_when_it_ends_or_is_lost() {
    let rec = TempFile::new("pc-summary");
    let report = run_recorded(SCENARIO, &rec);
    let summaries: Vec<PcSessionSummaryMsg> = common::on(rec.path(), TOPIC_PC_SESSION_SUMMARY)
        .iter()
        .map(|m| m.decode().unwrap())
        .collect();
    let downlinks: Vec<DownlinkMsg> = common::on(rec.path(), "/pc/downlink")
        .iter()
        .map(|m| m.decode().unwrap())
        .collect();

    // Three runs, in the order they ended: session 4 DONE, session 1 lost, session 1 DONE.
    let how: Vec<(u8, Option<u8>, &str, Option<&str>)> = summaries
        .iter()
        .map(|s| (s.session, s.payload, &*s.result, s.cause.as_deref()))
        .collect();
    assert_eq!(
        how,
        [
            (4, Some(14), "done", None),
            (1, Some(12), "lost", Some("power")),
            (1, Some(12), "done", None),
        ],
        "{summaries:#?}"
    );
    let s = |n: u64| n * 1_000_000_000;
    // The lost run ended when the power went; each run started when its SETUP arrived.
    assert_eq!(summaries[1].t_ns, s(30));
    for (summary, setup_s) in summaries.iter().zip([5, 12, 60]) {
        let start = summary.start_ns.unwrap();
        assert!((s(setup_s)..s(setup_s + 1)).contains(&start), "{summary:?}");
    }

    // What the run's report saw of each run: the same start, end and packets.
    let mut runs = report.sessions.runs.clone();
    runs.sort_by_key(|r| r.ended.map(|(t, ..)| t));
    assert_eq!(runs.len(), 3, "{runs:?}");
    for (summary, run) in summaries.iter().zip(&runs) {
        let (end, result, packets) = run.ended.unwrap();
        assert_eq!(summary.session, run.session);
        assert_eq!(summary.start_ns, run.started.map(|t| t.as_ns()));
        assert_eq!(summary.t_ns, end.as_ns());
        assert_eq!(summary.packets, packets);
        assert!(summary.packets > 0, "{summary:?}");
        let named = match result {
            RunEnd::Result(r) => m6p_twin::sessions::result_name(r.to_u8()).to_owned(),
            RunEnd::Lost(_) => "lost".to_owned(),
        };
        assert_eq!(summary.result, named);
        // The bytes of the session the ground received between the run's start and its end.
        let start = summary.start_ns.unwrap();
        let downlinked: u64 = downlinks
            .iter()
            .filter(|d| d.session == summary.session && (start..=summary.t_ns).contains(&d.t_ns))
            .map(|d| u64::from(d.len))
            .sum();
        assert_eq!(summary.downlinked_bytes, downlinked, "{summary:?}");
        assert!(summary.downlinked_bytes > 0, "{summary:?}");
        // The report counts, as the run's, what reached the ground until the next run began.
        assert!(summary.downlinked_bytes <= run.len, "{summary:?} {run:?}");
    }
}

#[test]
fn a_run_without_pc_sessions_records_no_summary_channel() {
    let rec = TempFile::new("pc-summary-none");
    let text = "name = \"quiet\"\nduration = \"5s\"\nseed = 3\n";
    run_recorded(text, &rec);
    let summary = m6p_twin::recording::read_summary(rec.path()).unwrap();
    assert!(
        !summary
            .channels
            .iter()
            .any(|c| c.topic == TOPIC_PC_SESSION_SUMMARY),
        "{:?}",
        summary.channels
    );
    assert_eq!(summary.count(TOPIC_PC_SESSION_SUMMARY), 0);
}
