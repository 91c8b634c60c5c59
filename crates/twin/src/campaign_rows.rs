//! A campaign's results, as its runs leave them and its outputs read them: a row per run
//! with its verdict, and what the output files say about their campaign. Running
//! ([`crate::campaign_run`]) makes them; the files and the report ([`crate::campaign_report`])
//! are made of them.

use std::collections::BTreeMap;

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
    /// The resolved scenario (written out for failures; `rows.jsonl` keeps it for them only).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub scenario: String,
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
