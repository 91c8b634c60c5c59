//! A campaign's results, as its runs leave them and its outputs read them: a row per run
//! with its verdict, its key figures and what its payload sessions did, and what the output
//! files say about their campaign. Running ([`crate::campaign_run`]) makes them; the files
//! and the report ([`crate::campaign_report`]) are made of them.

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use crate::campaign::Campaign;

/// How a run ended.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RunVerdict {
    /// Every expectation held.
    Pass,
    /// Expectations failed: their names and what was observed.
    Fail(Vec<(String, String)>),
    /// The run could not run, crashed or went over a limit: why.
    Error(String),
    /// The campaign was stopped (SIGINT, SIGTERM) before the run ended, or before it began:
    /// no result. `campaign run --resume` runs it.
    #[serde(rename = "not-run")]
    NotRun(String),
}

impl RunVerdict {
    /// `pass`, `fail`, `error` or `not run`.
    pub fn word(&self) -> &'static str {
        match self {
            RunVerdict::Pass => "pass",
            RunVerdict::Fail(_) => "fail",
            RunVerdict::Error(_) => "error",
            RunVerdict::NotRun(_) => "not run",
        }
    }
    /// Whether it is a result (pass, fail or error), not a run cut or never started.
    pub fn is_result(&self) -> bool {
        !matches!(self, RunVerdict::NotRun(_))
    }
}

/// What a failed check was: one of the scenario's expectations, or an invariant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CheckKind {
    /// One of the scenario's expectations.
    Expectation,
    /// An invariant the run checked (`[invariants] check`).
    Invariant,
}

impl CheckKind {
    /// `expectation` or `invariant`.
    pub fn word(self) -> &'static str {
        match self {
            CheckKind::Expectation => "expectation",
            CheckKind::Invariant => "invariant",
        }
    }
}

impl From<crate::expectations::VerdictKind> for CheckKind {
    fn from(k: crate::expectations::VerdictKind) -> CheckKind {
        match k {
            crate::expectations::VerdictKind::Expectation => CheckKind::Expectation,
            crate::expectations::VerdictKind::Invariant(_) => CheckKind::Invariant,
        }
    }
}

/// One run's row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRow {
    /// The run's index.
    pub run: u64,
    /// The run's scenario seed.
    pub seed: u64,
    /// What was drawn, by path.
    pub draws: BTreeMap<String, String>,
    /// How it ended.
    pub verdict: RunVerdict,
    /// The kind of each check the run failed, by its name in [`RunVerdict::Fail`]; empty
    /// for any other verdict (and in rows written before kinds were kept).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub failed_kinds: BTreeMap<String, CheckKind>,
    /// Key figures of the run ([`crate::campaign_run::metrics`]), by name; absent where they do not apply.
    #[serde(default)]
    pub metrics: BTreeMap<String, f64>,
    /// What each payload session did in the run ([`session_tallies`]), by session id;
    /// empty when none ran, or the run did not run to its end (and in rows written before
    /// sessions were kept).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub sessions: BTreeMap<u8, SessionTally>,
    /// The resolved scenario (written out for failures; `rows.jsonl` keeps it for them only).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub scenario: String,
}

/// How a session run ended, as a campaign keeps it: the PC's ICD result (ICD 3.1.6 table
/// 3), lost with the PC's memory, or still active when the run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SessionEnd {
    /// 0: finished.
    Done,
    /// 1: ABORT command.
    Aborted,
    /// 2: the payload did not acknowledge the SYNC.
    NoAck,
    /// 3: the S-band transmitter failed.
    SBandFailure,
    /// Lost with the PC's memory when its power went.
    LostPower,
    /// Lost with the PC's memory when it rebooted.
    LostReboot,
    /// Still ACTIVE (or PENDING) at the end of the run.
    StillActive,
}

impl SessionEnd {
    /// Every end, in the order tables list them.
    pub const ALL: [SessionEnd; 7] = [
        SessionEnd::Done,
        SessionEnd::Aborted,
        SessionEnd::NoAck,
        SessionEnd::SBandFailure,
        SessionEnd::LostPower,
        SessionEnd::LostReboot,
        SessionEnd::StillActive,
    ];

    /// How a session run the run's report holds ended (`None`: it had not).
    pub fn of(end: Option<twin_scenario::pc::RunEnd>) -> SessionEnd {
        use nodes_pc::{LostCause, SessionResult as R};
        use twin_scenario::pc::RunEnd;
        match end {
            Some(RunEnd::Result(R::Done)) => SessionEnd::Done,
            Some(RunEnd::Result(R::Aborted)) => SessionEnd::Aborted,
            Some(RunEnd::Result(R::NoAck)) => SessionEnd::NoAck,
            Some(RunEnd::Result(R::SbandFailure)) => SessionEnd::SBandFailure,
            Some(RunEnd::Lost(LostCause::PowerLoss)) => SessionEnd::LostPower,
            Some(RunEnd::Lost(LostCause::Reboot)) => SessionEnd::LostReboot,
            None => SessionEnd::StillActive,
        }
    }

    /// Its name in reports, as the end-of-run table writes it: `done`, `no-ack`,
    /// `lost (power)`, `still active`.
    pub fn word(self) -> &'static str {
        match self {
            SessionEnd::Done => "done",
            SessionEnd::Aborted => "aborted",
            SessionEnd::NoAck => "no-ack",
            SessionEnd::SBandFailure => "s-band-failure",
            SessionEnd::LostPower => "lost (power)",
            SessionEnd::LostReboot => "lost (reboot)",
            SessionEnd::StillActive => "still active",
        }
    }

    /// Its name in a column's name: `done`, `no_ack`, `lost_power`.
    pub fn column(self) -> &'static str {
        match self {
            SessionEnd::Done => "done",
            SessionEnd::Aborted => "aborted",
            SessionEnd::NoAck => "no_ack",
            SessionEnd::SBandFailure => "s_band_failure",
            SessionEnd::LostPower => "lost_power",
            SessionEnd::LostReboot => "lost_reboot",
            SessionEnd::StillActive => "still_active",
        }
    }
}

/// What one payload session did in one run of a campaign: its session runs by how they
/// ended, the packets the PC counted and the bytes that reached the ground.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SessionTally {
    /// The payloads its runs polled (a run that ended without starting polled none).
    #[serde(default, skip_serializing_if = "BTreeSet::is_empty")]
    pub payloads: BTreeSet<u8>,
    /// Its session runs, by how each ended: every run the run's report lists, one that
    /// ended without starting (an ABORT of a PENDING session) included.
    pub ends: BTreeMap<SessionEnd, u32>,
    /// Packets the PC counted over its runs that ended (a run still active has no count).
    pub packets: u64,
    /// Bytes downlinked over its runs.
    pub downlinked_bytes: u64,
}

impl SessionTally {
    /// How many session runs it had.
    pub fn runs(&self) -> u32 {
        self.ends.values().sum()
    }

    /// Whether any of its runs ended other than `done`.
    pub fn any_not_done(&self) -> bool {
        self.ends
            .iter()
            .any(|(e, n)| *e != SessionEnd::Done && *n > 0)
    }
}

/// What each session did in a run, by session id, from the run's report.
pub fn session_tallies(
    report: &crate::observe::sessions::SessionsReport,
) -> BTreeMap<u8, SessionTally> {
    let mut by: BTreeMap<u8, SessionTally> = BTreeMap::new();
    for r in &report.runs {
        let t = by.entry(r.session).or_default();
        t.payloads.extend(r.payload);
        *t.ends
            .entry(SessionEnd::of(r.ended.map(|(_, end, _)| end)))
            .or_default() += 1;
        t.packets += r.ended.map_or(0, |(_, _, packets)| u64::from(packets));
        t.downlinked_bytes += r.len;
    }
    by
}

/// What the output files say about their campaign (`campaign.json`): shards of one
/// campaign agree on it, and `merge` checks that they do.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CampaignMeta {
    /// The campaign's name.
    pub name: String,
    /// Its file, as given.
    pub file: String,
    /// Its seed.
    pub seed: u64,
    /// Runs 0..runs were asked for (over all shards).
    pub runs: u64,
}

impl CampaignMeta {
    /// The meta of `c` asked for `runs` runs.
    pub fn of(c: &Campaign, runs: u64) -> CampaignMeta {
        CampaignMeta {
            name: c.name(),
            file: c.file.clone(),
            seed: c.spec.seed,
            runs,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::observe::sessions::{SessionRun, SessionsReport};
    use csp::SimTime;
    use twin_scenario::pc::RunEnd;

    fn run(session: u8, started: bool, end: Option<RunEnd>, packets: u32, len: u64) -> SessionRun {
        SessionRun {
            session,
            payload: started.then_some(12),
            started: started.then(|| SimTime::from_secs(1)),
            ended: end.map(|e| (SimTime::from_secs(2), e, packets)),
            bytes: Vec::new(),
            len,
            stream: Default::default(),
        }
    }

    /// Each session id's runs are counted by how they ended (one that ended without
    /// starting, and one still active, included), packets over the runs that ended, bytes
    /// over all; and the tallies go through `rows.jsonl` (what `merge` and `--resume` read)
    /// unchanged.
    #[test]
    fn a_runs_sessions_are_tallied_by_id_and_end_and_read_back_from_json() {
        use nodes_pc::{LostCause, SessionResult as R};
        let report = SessionsReport {
            runs: vec![
                run(1, false, Some(RunEnd::Result(R::Aborted)), 0, 0),
                run(1, true, Some(RunEnd::Result(R::Done)), 90, 9000),
                run(2, true, Some(RunEnd::Lost(LostCause::Reboot)), 10, 1000),
                run(1, true, Some(RunEnd::Result(R::Done)), 80, 8000),
                run(2, true, None, 0, 500),
            ],
            ..Default::default()
        };
        let t = session_tallies(&report);
        assert_eq!(
            t,
            BTreeMap::from([
                (
                    1,
                    SessionTally {
                        payloads: [12].into(),
                        ends: [(SessionEnd::Aborted, 1), (SessionEnd::Done, 2)].into(),
                        packets: 170,
                        downlinked_bytes: 17_000,
                    }
                ),
                (
                    2,
                    SessionTally {
                        payloads: [12].into(),
                        ends: [(SessionEnd::LostReboot, 1), (SessionEnd::StillActive, 1)].into(),
                        packets: 10,
                        downlinked_bytes: 1500,
                    }
                ),
            ])
        );
        assert_eq!((t[&1].runs(), t[&1].any_not_done()), (3, true));
        let done = SessionTally {
            ends: [(SessionEnd::Done, 2)].into(),
            ..Default::default()
        };
        assert!(!done.any_not_done());
        let row = RunRow {
            run: 3,
            seed: 4,
            draws: BTreeMap::new(),
            verdict: RunVerdict::Pass,
            failed_kinds: BTreeMap::new(),
            metrics: BTreeMap::new(),
            sessions: t,
            scenario: String::new(),
        };
        let json = serde_json::to_string(&row).unwrap();
        assert!(
            json.contains(r#""ends":{"done":2,"aborted":1}"#),
            "typed ends, by name: {json}"
        );
        assert_eq!(serde_json::from_str::<RunRow>(&json).unwrap(), row);
        // A row without sessions writes none, and a row written before they were kept reads.
        let none = RunRow {
            sessions: BTreeMap::new(),
            ..row
        };
        let json = serde_json::to_string(&none).unwrap();
        assert!(!json.contains("sessions"), "{json}");
        assert_eq!(serde_json::from_str::<RunRow>(&json).unwrap(), none);
    }

    #[test]
    fn every_end_has_a_word_and_a_column_name() {
        for e in SessionEnd::ALL {
            let json = serde_json::to_string(&e).unwrap();
            assert_eq!(json.trim_matches('"').replace('-', "_"), e.column());
        }
        assert_eq!(SessionEnd::of(None).word(), "still active");
        assert_eq!(
            SessionEnd::of(Some(RunEnd::Lost(nodes_pc::LostCause::PowerLoss))).word(),
            "lost (power)"
        );
    }
}
