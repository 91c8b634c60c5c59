//! Expectations: what the kinds of `[[expectations]]` have in common, and their verdicts on
//! a run.
//!
//! Each kind is a struct of its own fields in the domain slice it judges (`crate::commands`
//! the replies, `crate::adcs` the attitude, `crate::eps` the power, `crate::comm` the
//! beacons, `crate::sessions` the payload data, `crate::counters` the counters), with its
//! meaning (`validate`) and its verdict (`check`) ([`ExpectKind`]); the registry
//! ([`crate::expectation_kinds`]) names it. Every expectation takes a `name` (default
//! `expectations[i]`). Adding a kind is its struct and code in its slice and one line in
//! the registry.

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;
use serde::de::DeserializeOwned;

use twin_core::events::RunEvent;
use twin_core::network::NetworkSpec;
use twin_report::RunReport;
use twin_scenario::scenario::{Dur, Scenario};

/// The verdict on one expectation of the scenario, or on one invariant it checks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verdict {
    /// What was judged.
    pub kind: VerdictKind,
    /// The expectation's name, or `invariant <name>`.
    pub name: String,
    /// Whether it held.
    pub passed: bool,
    /// The simulated time the verdict refers to (the failing occurrence, or the end).
    pub t: SimTime,
    /// What was observed, for example `reply after 1.204 s (limit 1.000 s)`.
    pub observed: String,
}

/// What a verdict judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VerdictKind {
    /// One of the scenario's expectations.
    Expectation,
    /// An invariant the scenario checks (`[invariants] check`).
    Invariant(twin_scenario::invariants::InvariantName),
}

/// Whether a check held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grade {
    /// It held.
    Pass,
    /// It did not.
    Fail,
}

impl Grade {
    /// `Pass` if `held`, else `Fail`.
    pub fn of(held: bool) -> Grade {
        if held { Grade::Pass } else { Grade::Fail }
    }
}

/// What a check found: whether it held, when (the failing occurrence, or the end), and what
/// was observed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Judgement {
    /// Whether it held.
    pub grade: Grade,
    /// The simulated time it refers to: the failing occurrence, or the end of the run.
    pub at: SimTime,
    /// What was observed, for example `reply after 1.204 s (limit 1.000 s)`.
    pub detail: String,
}

impl Judgement {
    /// A check of grade `grade` at `at` that observed `detail`.
    pub fn new(grade: Grade, at: SimTime, detail: impl Into<String>) -> Self {
        Judgement {
            grade,
            at,
            detail: detail.into(),
        }
    }

    /// A check that held at `at`.
    pub fn pass(at: SimTime, detail: impl Into<String>) -> Self {
        Judgement::new(Grade::Pass, at, detail)
    }

    /// A check that failed at `at`.
    pub fn fail(at: SimTime, detail: impl Into<String>) -> Self {
        Judgement::new(Grade::Fail, at, detail)
    }

    /// Whether it held.
    pub fn passed(&self) -> bool {
        self.grade == Grade::Pass
    }
}

/// The lowest and highest of the values a [`Watch`] (or a check) took in so far: infinite
/// before the first.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extremes {
    /// The lowest.
    pub lo: f64,
    /// The highest.
    pub hi: f64,
}

impl Default for Extremes {
    fn default() -> Self {
        Extremes {
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }
}

impl Extremes {
    /// Take in one more value.
    pub fn add(&mut self, v: f64) {
        self.lo = self.lo.min(v);
        self.hi = self.hi.max(v);
    }
}

/// Which occurrences of a repeated command (or which samples) an expectation covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Occurrence {
    /// Every occurrence must satisfy it.
    Every,
    /// At least one must.
    Any,
}

/// Which samples a window of samples looks at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum When {
    /// Every sample.
    Always,
    /// Sun fully visible.
    Sunlit,
    /// Sun not visible at all.
    Eclipse,
    /// The ground target at or above `min_elevation_deg`.
    TargetVisible,
}

/// Where an expectation is judged for its meaning: the scenario and its network.
#[derive(Debug)]
pub struct ExpectCx<'a> {
    /// The whole scenario.
    pub scenario: &'a Scenario,
    /// The network.
    pub net: &'a NetworkSpec,
}

impl ExpectCx<'_> {
    /// A window `from`..`to`: `from` before the end of the run, `to` after `from`.
    pub fn window(&self, from: Option<Dur>, to: Option<Dur>, err: &mut dyn FnMut(&str, String)) {
        let end = self.scenario.duration.0;
        if let Some(from) = from
            && from.0 >= end
        {
            err(
                "from",
                format!(
                    "the window starts at or after the end of the run ({})",
                    twin_core::duration::format_duration(end)
                ),
            );
        }
        if let (Some(a), Some(b)) = (from, to)
            && b <= a
        {
            err("to", "must be after `from`".into());
        }
    }
}

/// Where an expectation is checked: the run's report and the network.
#[derive(Debug)]
pub struct CheckCx<'a> {
    /// What the run did.
    pub report: &'a RunReport,
    /// The network.
    pub net: &'a NetworkSpec,
}

/// What an expectation watching a run may need besides its events.
#[derive(Debug, Clone, Copy, Default)]
pub struct WatchCx<'a> {
    /// The satellite's two TLE lines (the truth's distance from their orbit).
    pub tle: Option<&'a (String, String)>,
    /// The run's network, the nodes that run (those outside programs replaced left out;
    /// default: the M6P's).
    pub net: Option<&'a NetworkSpec>,
    /// The ICD on the run's ports (default: the ICD's ports).
    pub icd: Option<&'a twin_core::icd::IcdMap>,
}

/// An expectation judged while the run goes, from its events, so that what it looks at
/// (a sample every second, for days) need not be kept in the report.
pub trait Watch: Send + snap::Snap {
    /// Take in one event of the run, in the order they happen (only those of
    /// [`Watch::kinds`]).
    fn observe(&mut self, ev: &RunEvent);
    /// The kinds of event `observe` looks at; it is handed no other (default: every kind).
    fn kinds(&self) -> twin_core::events::Kinds {
        twin_core::events::Kinds::ALL
    }
    /// The verdict, once the run has ended.
    fn judge(&self, cx: &CheckCx<'_>) -> Judgement;
}

/// A kind of expectation (see the module doc).
pub trait ExpectKind:
    DeserializeOwned + JsonSchema + std::fmt::Debug + Clone + Send + Sync + 'static
{
    /// Its name in scenarios (`reply`).
    const NAME: &'static str;
    /// One line on what it checks.
    const ABOUT: &'static str;
    /// Check its meaning in the scenario; `err(field, message)`.
    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String));
    /// Judge the run.
    fn check(&self, cx: &CheckCx<'_>) -> Judgement;
    /// Judge the run as it goes instead ([`Watch`]; the same verdict as `check` on a
    /// report that kept everything). `None`: `check` judges it from the report.
    fn watch(&self, _cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        None
    }
    /// What it is about in a few words (`reply to ping-eps`): the name of an expectation
    /// the scenario leaves unnamed.
    fn describe(&self) -> String;
}

/// An expectation of any kind.
pub(crate) trait AnyExpect: std::fmt::Debug + Send + Sync {
    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String));
    fn check(&self, cx: &CheckCx<'_>) -> Judgement;
    fn watch(&self, cx: &WatchCx<'_>) -> Option<Box<dyn Watch>>;
    fn describe(&self) -> String;
}

impl<K: ExpectKind> AnyExpect for K {
    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        ExpectKind::validate(self, cx, err)
    }
    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        ExpectKind::check(self, cx)
    }
    fn watch(&self, cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        ExpectKind::watch(self, cx)
    }
    fn describe(&self) -> String {
        ExpectKind::describe(self)
    }
}

/// The fields every expectation takes.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Common {
    /// Name for reports (default `expectations[i]`).
    #[serde(default)]
    pub name: Option<String>,
}

/// The names of [`Common`]'s fields.
pub const COMMON: &[&str] = &["name"];

pub use twin_scenario::entries::ExpectEntry;

/// A compiled expectation: its name and its kind's check.
#[derive(Debug, Clone)]
pub struct Expectation {
    /// Its name.
    pub name: String,
    kind: std::sync::Arc<dyn AnyExpect>,
}

impl Expectation {
    /// An expectation named `name` of a kind the registry parsed.
    pub(crate) fn of_any(name: String, kind: std::sync::Arc<dyn AnyExpect>) -> Self {
        Expectation { name, kind }
    }

    /// An expectation of kind `K` named `name`.
    pub fn new<K: ExpectKind>(name: &str, kind: K) -> Self {
        Expectation {
            name: name.to_owned(),
            kind: std::sync::Arc::new(kind),
        }
    }

    /// The verdict on `report`.
    pub fn check(&self, report: &RunReport, net: &NetworkSpec) -> Verdict {
        self.verdict(self.kind.check(&CheckCx { report, net }))
    }

    /// Its [`Watch`], when its kind judges a run as it goes: feed it every event of the
    /// run of its [`Watch::kinds`], then [`check_watched`] takes its verdict.
    pub fn watch(&self, cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        self.kind.watch(cx)
    }

    fn verdict(&self, j: Judgement) -> Verdict {
        Verdict {
            kind: VerdictKind::Expectation,
            name: self.name.clone(),
            passed: j.passed(),
            t: j.at,
            observed: j.detail,
        }
    }
}

/// Check every expectation on a report that kept everything it looks at
/// (`RunOptions::keep_series`).
pub fn check_all(
    expectations: &[Expectation],
    report: &RunReport,
    net: &NetworkSpec,
) -> Vec<Verdict> {
    check_watched(expectations, &[], report, net)
}

/// Check every expectation: by its watch when it has one (`watches[i]`, from
/// [`Expectation::watch`], fed the run's events), else on the report.
pub fn check_watched(
    expectations: &[Expectation],
    watches: &[Option<Box<dyn Watch>>],
    report: &RunReport,
    net: &NetworkSpec,
) -> Vec<Verdict> {
    expectations
        .iter()
        .enumerate()
        .map(|(i, x)| match watches.get(i).and_then(|w| w.as_deref()) {
            Some(w) => x.verdict(w.judge(&CheckCx { report, net })),
            None => x.check(report, net),
        })
        .collect()
}

/// `a..=b`, `>= a`, `<= b` or `any`.
pub fn bounds(min: Option<u64>, max: Option<u64>) -> String {
    match (min, max) {
        (Some(a), Some(b)) => format!("{a}..={b}"),
        (Some(a), None) => format!(">= {a}"),
        (None, Some(b)) => format!("<= {b}"),
        (None, None) => "any".into(),
    }
}

// What a snapshot saves of a watch: its tally so far (what it judges is the scenario's).
snap::fields!(Extremes { lo, hi });

impl snap::Snap for Box<dyn Watch> {
    fn save(&self, w: &mut snap::Writer) {
        (**self).save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        (**self).load(r)
    }
}
