//! Campaign files: one base scenario run many times with values drawn at random
//! (`docs/campaigns.md`).
//!
//! A campaign names its base scenario (a file, or inline), how many runs, a seed,
//! dispersions over scenario fields by path (`fc.initial_rate_deg_s`, `faults[0].at`) and a
//! catalogue of faults from which each run draws some. Run `k`'s draws depend only on the
//! campaign's seed, `k` and the entry drawn (each dispersion and each catalogue entry has its
//! own random stream), so any subset of the runs, anywhere, draws the same values, and adding
//! a dispersion leaves the others' values alone. A run resolves to a complete scenario text:
//! the base with every draw written in and its own seed, which `m6p-twin run` reproduces.
//!
//! Parsing is strict like a scenario's: unknown fields, bad distributions, paths that the
//! base scenario cannot have, and draws that make the scenario invalid are errors naming the
//! campaign file, the line and the field, found before anything runs ([`Campaign::check`]
//! resolves every run).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng as _, SeedableRng as _};
use schemars::JsonSchema;
use serde::Deserialize;

use crate::seed::mix;
use twin_scenario::scenario::{PathStep, ScenarioError, ScenarioErrors, path_string};

/// A campaign file.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CampaignSpec {
    /// Short name, used in reports (default: the file name).
    #[serde(default)]
    pub name: Option<String>,
    /// What the campaign explores.
    #[serde(default)]
    pub description: Option<String>,
    /// The base scenario: a path (relative to the campaign file) or the scenario inline.
    pub scenario: ScenarioSource,
    /// How many runs (1-1000000); `campaign run --runs` may ask for fewer or more.
    pub runs: u64,
    /// The campaign's seed: every run's draws and its scenario seed derive from it.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Values drawn for scenario fields, by path (`fc.initial_rate_deg_s`,
    /// `faults[0].at`): `{ uniform = [a, b] }`, `{ normal = [mean, sd], min, max }`,
    /// `{ choice = [v, ...], weights = [w, ...] }`. Numbers, or durations (`"60s"`) for
    /// uniform and normal.
    #[serde(default)]
    #[schemars(with = "BTreeMap<String, serde_json::Value>")]
    pub dispersions: BTreeMap<String, toml::Value>,
    /// Faults drawn into every run.
    #[serde(default)]
    pub faults: Option<FaultDraws>,
    /// How long a run may be, in simulated and wall-clock time: a run over either is an
    /// error row, never a hang.
    #[serde(default)]
    pub limits: RunLimits,
    /// Each run's scenario seed: `"per-run"` (from the campaign's seed and the run's
    /// index: the runs differ from the start) or `"shared"` (one for all: the runs differ
    /// only by their draws, and run their common prefix once: docs/campaigns.md,
    /// "Forking").
    #[serde(default)]
    pub run_seeds: RunSeeds,
    /// Start every run from a snapshot taken at this instant of a run of the common prefix
    /// (needs `run_seeds = "shared"`; refused if a draw acts before it); default: the latest
    /// instant before which no draw changes anything.
    #[serde(default)]
    pub fork_at: Option<twin_scenario::scenario::Dur>,
}

/// Where the runs' scenario seeds come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum RunSeeds {
    /// Each run its own, from the campaign's seed and the run's index.
    #[default]
    PerRun,
    /// One for every run, from the campaign's seed.
    Shared,
}

fn default_seed() -> u64 {
    1
}

/// `[limits]`: how long one run of the campaign may be.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RunLimits {
    /// The longest simulated duration a run may draw (default 30 days): a longer one is an
    /// error row, not run.
    #[serde(default = "default_simulated")]
    pub simulated: twin_scenario::scenario::Dur,
    /// The most wall-clock time a run may take (default 10 minutes): it is stopped there,
    /// an error row.
    #[serde(default = "default_wall")]
    pub wall: twin_scenario::scenario::Dur,
}

fn default_simulated() -> twin_scenario::scenario::Dur {
    twin_scenario::scenario::Dur(std::time::Duration::from_secs(30 * 86_400))
}

fn default_wall() -> twin_scenario::scenario::Dur {
    twin_scenario::scenario::Dur(std::time::Duration::from_secs(600))
}

impl Default for RunLimits {
    fn default() -> Self {
        RunLimits {
            simulated: default_simulated(),
            wall: default_wall(),
        }
    }
}

/// Where the base scenario comes from.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum ScenarioSource {
    /// A scenario file, relative to the campaign file.
    Path(String),
    /// The scenario itself.
    Inline(#[schemars(with = "serde_json::Value")] toml::Table),
}

/// The fault catalogue.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FaultDraws {
    /// How many distinct catalogue entries each run draws (at most the catalogue's size).
    pub draw: usize,
    /// Faults as in a scenario's `[[faults]]`, any value of which may be a distribution.
    /// An entry with `into = "fc.faults"` goes into that list instead (the FC's sensor and
    /// wheel faults).
    #[schemars(with = "Vec<serde_json::Value>")]
    pub catalogue: Vec<toml::Table>,
}

/// A distribution of values.
#[derive(Debug, Clone, PartialEq)]
pub enum Dist {
    /// Uniform between two numbers or durations (integers stay integers, inclusive).
    Uniform(Scalar, Scalar),
    /// Normal with a mean and a standard deviation, cut to `[min, max]` when given.
    Normal {
        /// The mean.
        mean: Scalar,
        /// The standard deviation (same unit as the mean).
        sd: f64,
        /// Lower bound.
        min: Option<f64>,
        /// Upper bound.
        max: Option<f64>,
    },
    /// One of the values, with weights (equal when not given).
    Choice(Vec<toml::Value>, Vec<f64>),
}

/// A number or a duration: what uniform and normal draw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scalar {
    /// An integer.
    Int(i64),
    /// A real number.
    Float(f64),
    /// A duration, in ms.
    Millis(f64),
}

/// Why a distribution is not one; shown at the campaign's field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DistError {
    /// Not a table.
    #[error("expected a distribution table, found {found}")]
    NotATable {
        /// What was written.
        found: toml::Value,
    },
    /// A table with none of `uniform`, `normal`, `choice`.
    #[error("expected one of `uniform`, `normal`, `choice`")]
    NoKind,
    /// A key the distribution does not take.
    #[error("unknown key `{key}` (this distribution takes {})", .allowed.join(", "))]
    UnknownKey {
        /// The key.
        key: String,
        /// The keys it takes.
        allowed: &'static [&'static str],
    },
    /// `uniform` or `normal` without two values.
    #[error("`{key}` takes two values: [a, b]")]
    NotAPair {
        /// `uniform` or `normal`.
        key: &'static str,
    },
    /// A number and a duration together.
    #[error("`{key}`: both values must be numbers, or both durations")]
    MixedKinds {
        /// `uniform` or `normal`.
        key: &'static str,
    },
    /// Text that is not a duration. The duration's message is part of this one's, so it
    /// is not also its `source()`.
    #[error("`{text}` is neither a number nor a duration: {duration}")]
    NotNumberOrDuration {
        /// The text.
        text: String,
        /// Why it is not a duration.
        duration: crate::duration::DurationError,
    },
    /// Neither a finite number nor text.
    #[error("expected a number or a duration, found {found}")]
    NotScalar {
        /// What was written.
        found: toml::Value,
    },
    /// `uniform = [a, b]` with a above b.
    #[error("uniform: {low} is above {high}")]
    UniformReversed {
        /// a.
        low: f64,
        /// b.
        high: f64,
    },
    /// A negative standard deviation.
    #[error("normal: the standard deviation must be >= 0")]
    NegativeSd,
    /// `min` above `max`.
    #[error("normal: min {min} is above max {max}")]
    BoundsReversed {
        /// `min`.
        min: f64,
        /// `max`.
        max: f64,
    },
    /// `choice` not a list, or empty.
    #[error("`choice` takes a non-empty list of values")]
    NoChoices,
    /// `weights` not a list.
    #[error("`weights` takes a list of numbers")]
    WeightsNotAList,
    /// Not one weight per choice.
    #[error("{weights} weights for {choices} choices")]
    WeightCount {
        /// Weights given.
        weights: usize,
        /// Choices given.
        choices: usize,
    },
    /// A negative weight, or none above 0.
    #[error("weights must be >= 0 with a positive sum")]
    BadWeights,
}

impl Scalar {
    fn of(v: &toml::Value) -> Result<Scalar, DistError> {
        match v {
            toml::Value::Integer(i) => Ok(Scalar::Int(*i)),
            toml::Value::Float(f) if f.is_finite() => Ok(Scalar::Float(*f)),
            toml::Value::String(s) => crate::duration::parse_duration(s)
                .map(|d| Scalar::Millis(d.as_secs_f64() * 1e3))
                .map_err(|duration| DistError::NotNumberOrDuration {
                    text: s.clone(),
                    duration,
                }),
            other => Err(DistError::NotScalar {
                found: other.clone(),
            }),
        }
    }
    fn value(self) -> f64 {
        match self {
            Scalar::Int(i) => i as f64,
            Scalar::Float(f) | Scalar::Millis(f) => f,
        }
    }
    /// `x` in this scalar's kind, as a TOML value.
    fn like(self, x: f64) -> toml::Value {
        match self {
            Scalar::Int(_) => toml::Value::Integer(x.round() as i64),
            Scalar::Float(_) => toml::Value::Float(x),
            Scalar::Millis(_) => toml::Value::String(format!("{}ms", x.max(0.0).round() as u64)),
        }
    }
    fn same_kind(self, o: Scalar) -> bool {
        matches!(
            (self, o),
            (Scalar::Millis(_), Scalar::Millis(_))
                | (
                    Scalar::Int(_) | Scalar::Float(_),
                    Scalar::Int(_) | Scalar::Float(_)
                )
        )
    }
}

/// The keys that make a table a distribution.
const DIST_KEYS: [&str; 3] = ["uniform", "normal", "choice"];

impl Dist {
    /// Whether `v` is written as a distribution (a table with one of [`DIST_KEYS`]).
    fn is_dist(v: &toml::Value) -> bool {
        v.as_table()
            .is_some_and(|t| DIST_KEYS.iter().any(|k| t.contains_key(*k)))
    }

    /// Parse a distribution table.
    pub fn parse(v: &toml::Value) -> Result<Dist, DistError> {
        let t = v
            .as_table()
            .ok_or_else(|| DistError::NotATable { found: v.clone() })?;
        let allowed: &'static [&'static str] = if t.contains_key("uniform") {
            &["uniform"]
        } else if t.contains_key("normal") {
            &["normal", "min", "max"]
        } else if t.contains_key("choice") {
            &["choice", "weights"]
        } else {
            return Err(DistError::NoKind);
        };
        if let Some(k) = t.keys().find(|k| !allowed.contains(&k.as_str())) {
            return Err(DistError::UnknownKey {
                key: k.clone(),
                allowed,
            });
        }
        let pair = |key: &'static str| -> Result<(Scalar, Scalar), DistError> {
            let a = t[key]
                .as_array()
                .filter(|a| a.len() == 2)
                .ok_or(DistError::NotAPair { key })?;
            let (x, y) = (Scalar::of(&a[0])?, Scalar::of(&a[1])?);
            if !x.same_kind(y) {
                return Err(DistError::MixedKinds { key });
            }
            Ok((x, y))
        };
        let bound = |k: &str| -> Result<Option<f64>, DistError> {
            t.get(k)
                .map(|v| Scalar::of(v).map(Scalar::value))
                .transpose()
        };
        if t.contains_key("uniform") {
            let (a, b) = pair("uniform")?;
            if a.value() > b.value() {
                return Err(DistError::UniformReversed {
                    low: a.value(),
                    high: b.value(),
                });
            }
            Ok(Dist::Uniform(a, b))
        } else if t.contains_key("normal") {
            let (mean, sd) = pair("normal")?;
            if sd.value() < 0.0 {
                return Err(DistError::NegativeSd);
            }
            let (min, max) = (bound("min")?, bound("max")?);
            if let (Some(lo), Some(hi)) = (min, max)
                && lo > hi
            {
                return Err(DistError::BoundsReversed { min: lo, max: hi });
            }
            Ok(Dist::Normal {
                mean,
                sd: sd.value(),
                min,
                max,
            })
        } else {
            let values = t["choice"]
                .as_array()
                .filter(|a| !a.is_empty())
                .ok_or(DistError::NoChoices)?
                .clone();
            let weights = match t.get("weights") {
                None => vec![1.0; values.len()],
                Some(w) => {
                    let w: Vec<f64> = w
                        .as_array()
                        .ok_or(DistError::WeightsNotAList)?
                        .iter()
                        .map(|x| Scalar::of(x).map(Scalar::value))
                        .collect::<Result<_, _>>()?;
                    if w.len() != values.len() {
                        return Err(DistError::WeightCount {
                            weights: w.len(),
                            choices: values.len(),
                        });
                    }
                    if w.iter().any(|x| *x < 0.0) || w.iter().sum::<f64>() <= 0.0 {
                        return Err(DistError::BadWeights);
                    }
                    w
                }
            };
            Ok(Dist::Choice(values, weights))
        }
    }

    /// One draw.
    pub fn sample(&self, rng: &mut ChaCha8Rng) -> toml::Value {
        match self {
            Dist::Uniform(a, b) => match (a, b) {
                (Scalar::Int(x), Scalar::Int(y)) => {
                    let span = (*y - *x) as u64 + 1;
                    toml::Value::Integer(x + (rng.next_u64() % span) as i64)
                }
                _ => a.like(a.value() + unit(rng) * (b.value() - a.value())),
            },
            Dist::Normal { mean, sd, min, max } => {
                // Box-Muller: two uniform draws, one normal.
                let (u1, u2) = (1.0 - unit(rng), unit(rng));
                let z = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                let mut x = mean.value() + sd * z;
                if let Some(lo) = min {
                    x = x.max(*lo);
                }
                if let Some(hi) = max {
                    x = x.min(*hi);
                }
                // An integer mean draws reals: a normal is continuous.
                match mean {
                    Scalar::Int(_) => toml::Value::Float(x),
                    m => m.like(x),
                }
            }
            Dist::Choice(values, weights) => {
                let mut r = unit(rng) * weights.iter().sum::<f64>();
                for (v, w) in values.iter().zip(weights) {
                    if r < *w {
                        return v.clone();
                    }
                    r -= w;
                }
                values[values.len() - 1].clone()
            }
        }
    }
}

/// A uniform draw in [0, 1).
fn unit(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The random stream of one entry of run `k`: its own, whatever else the campaign draws.
fn stream(seed: u64, k: u64, entry: &str) -> ChaCha8Rng {
    // FNV-1a of the entry's name.
    let h = entry.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    ChaCha8Rng::seed_from_u64(mix(mix(seed, k), h))
}

/// Why a text is not a field path; each names the text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FieldPathError {
    /// A key that is empty or not `[A-Za-z0-9_]`, or text after a `]`.
    #[error("`{path}` is not a field path (like `faults[0].at`)")]
    NotAPath {
        /// The text.
        path: String,
    },
    /// A `[` without its `]`.
    #[error("`{path}`: unclosed `[`")]
    Unclosed {
        /// The text.
        path: String,
    },
    /// An index that is not a number.
    #[error("`{path}`: `{index}` is not an index")]
    NotAnIndex {
        /// The text.
        path: String,
        /// What is between the brackets.
        index: String,
    },
}

/// Why a drawn value cannot be written at its path in the base scenario.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SetPathError {
    /// A key under a value that is not a table.
    #[error("`{key}`: its parent is not a table")]
    ParentNotATable {
        /// The key.
        key: String,
    },
    /// An index into what is not a list.
    #[error("[{index}]: not a list in the base scenario")]
    NotAList {
        /// The index.
        index: usize,
    },
    /// An index past the list's end.
    #[error("[{index}]: the base scenario's list has {len} entries")]
    NoEntry {
        /// The index.
        index: usize,
        /// The list's length.
        len: usize,
    },
}

/// Parse a field path: `fc.initial_rate_deg_s`, `faults[0].at`, `payload[1].behaviour`.
pub fn parse_path(s: &str) -> Result<Vec<PathStep>, FieldPathError> {
    let not_a_path = || FieldPathError::NotAPath { path: s.to_owned() };
    let mut out = Vec::new();
    for part in s.split('.') {
        let (name, mut rest) = part.split_once('[').map_or((part, ""), |(n, r)| (n, r));
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(not_a_path());
        }
        out.push(PathStep::Key(name.to_owned()));
        while !rest.is_empty() {
            let (ix, after) = rest
                .split_once(']')
                .ok_or_else(|| FieldPathError::Unclosed { path: s.to_owned() })?;
            out.push(PathStep::Index(ix.parse().map_err(|_| {
                FieldPathError::NotAnIndex {
                    path: s.to_owned(),
                    index: ix.to_owned(),
                }
            })?));
            rest = after.strip_prefix('[').unwrap_or(after);
            if !after.is_empty() && !after.starts_with('[') {
                return Err(not_a_path());
            }
        }
    }
    Ok(out)
}

/// Write `value` at `path` in `root`. Tables on the way are made when missing; an index
/// must exist. (Recursion over the path's steps: a path has a handful.)
fn set_path(
    root: &mut toml::Table,
    path: &[PathStep],
    value: toml::Value,
) -> Result<(), SetPathError> {
    let mut whole = toml::Value::Table(std::mem::take(root));
    let r = set_in(&mut whole, path, value);
    if let toml::Value::Table(t) = whole {
        *root = t;
    }
    r
}

fn set_in(
    node: &mut toml::Value,
    path: &[PathStep],
    value: toml::Value,
) -> Result<(), SetPathError> {
    let Some((step, rest)) = path.split_first() else {
        *node = value;
        return Ok(());
    };
    let next = match step {
        PathStep::Key(k) => node
            .as_table_mut()
            .ok_or_else(|| SetPathError::ParentNotATable { key: k.clone() })?
            .entry(k.clone())
            .or_insert_with(|| toml::Value::Table(toml::Table::new())),
        PathStep::Index(i) => {
            let a = node
                .as_array_mut()
                .ok_or(SetPathError::NotAList { index: *i })?;
            let len = a.len();
            a.get_mut(*i)
                .ok_or(SetPathError::NoEntry { index: *i, len })?
        }
    };
    set_in(next, rest, value)
}

/// The value at `path` in `root`, if there is one.
pub(crate) fn get_path<'a>(root: &'a toml::Table, path: &[PathStep]) -> Option<&'a toml::Value> {
    let (first, rest) = path.split_first()?;
    let PathStep::Key(k) = first else { return None };
    rest.iter().try_fold(root.get(k)?, |v, step| match step {
        PathStep::Key(k) => v.get(k.as_str()),
        PathStep::Index(i) => v.get(*i),
    })
}

/// Resolve every distribution inside `v` (a catalogue entry's fields), drawing from `rng`.
fn draw_inside(v: &toml::Value, rng: &mut ChaCha8Rng) -> Result<toml::Value, DistError> {
    if Dist::is_dist(v) {
        return Ok(Dist::parse(v)?.sample(rng));
    }
    Ok(match v {
        toml::Value::Table(t) => toml::Value::Table(
            t.iter()
                .map(|(k, x)| draw_inside(x, rng).map(|x| (k.clone(), x)))
                .collect::<Result<_, DistError>>()?,
        ),
        toml::Value::Array(a) => toml::Value::Array(
            a.iter()
                .map(|x| draw_inside(x, rng))
                .collect::<Result<_, DistError>>()?,
        ),
        other => other.clone(),
    })
}

/// One run resolved: what was drawn and the complete scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct Resolved {
    /// The run's index.
    pub run: u64,
    /// The run's scenario seed.
    pub seed: u64,
    /// Each dispersion's drawn value (a string as itself, anything else as TOML), by path;
    /// `faults` lists the drawn catalogue entries (`kind#index`).
    pub draws: BTreeMap<String, String>,
    /// The scenario text: the base with every draw written in.
    pub text: String,
}

/// A campaign loaded: its spec, its file and its base scenario as a TOML table.
#[derive(Debug, Clone)]
pub struct Campaign {
    /// The campaign file (as given).
    pub file: String,
    /// The campaign file's text.
    pub text: String,
    /// The parsed file.
    pub spec: CampaignSpec,
    /// The base scenario's table.
    pub base: toml::Table,
    /// Where the base scenario came from (for messages).
    pub base_file: String,
    dists: BTreeMap<String, (Vec<PathStep>, Dist)>,
}

/// An error at `field` of the campaign file, located in its text.
fn err_at(file: &str, text: &str, field: &str, message: String) -> ScenarioError {
    let path = parse_path(field).unwrap_or_default();
    // A dispersion's key contains dots: locate the key itself under `dispersions`.
    let steps: Vec<PathStep> = if let Some(k) = field.strip_prefix("dispersions.") {
        vec![PathStep::Key("dispersions".into()), PathStep::Key(k.into())]
    } else {
        path
    };
    let (line, column) = twin_scenario::scenario::locate(text, &steps)
        .map(|s| twin_scenario::scenario::line_col(text, s.start))
        .map_or((None, None), |(l, c)| (Some(l), Some(c)));
    ScenarioError {
        file: file.to_owned(),
        line,
        column,
        field: field.to_owned(),
        message,
    }
}

impl Campaign {
    /// Parse a campaign; `file` names it in errors and anchors a relative scenario path.
    pub fn parse(file: &str, text: &str) -> Result<Campaign, ScenarioErrors> {
        let one =
            |field: &str, message: String| ScenarioErrors(vec![err_at(file, text, field, message)]);
        let spec: CampaignSpec = toml::from_str(text).map_err(|e| {
            let (line, column) = e
                .span()
                .map(|s| twin_scenario::scenario::line_col(text, s.start))
                .map_or((None, None), |(l, c)| (Some(l), Some(c)));
            ScenarioErrors(vec![ScenarioError {
                file: file.to_owned(),
                line,
                column,
                field: String::new(),
                message: e.message().trim().to_owned(),
            }])
        })?;
        let mut errors = Vec::new();
        if !(1..=1_000_000).contains(&spec.runs) {
            errors.push(err_at(file, text, "runs", "must be 1-1000000".into()));
        }
        let (base, base_file) = match &spec.scenario {
            ScenarioSource::Inline(t) => (t.clone(), format!("{file} (inline scenario)")),
            ScenarioSource::Path(p) => {
                let path = Path::new(file)
                    .parent()
                    .map_or_else(|| PathBuf::from(p), |d| d.join(p));
                let shown = path.display().to_string();
                let base_text = twin_scenario::scenario::read_input(&path)
                    .map_err(|e| one("scenario", format!("cannot read {shown}: {e}")))?;
                // The base must be a valid scenario on its own.
                crate::validate::parse(&shown, &base_text)?;
                let t = base_text
                    .parse::<toml::Table>()
                    .map_err(|e| one("scenario", format!("{shown}: {e}")))?;
                (t, shown)
            }
        };
        if base
            .get("links")
            .and_then(toml::Value::as_array)
            .is_some_and(|l| !l.is_empty())
        {
            errors.push(err_at(
                file,
                text,
                "scenario",
                format!(
                    "{base_file} has outside links: campaign runs are headless, in virtual time"
                ),
            ));
        }
        let mut dists = BTreeMap::new();
        for (k, v) in &spec.dispersions {
            let field = format!("dispersions.{k}");
            match (parse_path(k), Dist::parse(v)) {
                (Ok(p), Ok(d)) => {
                    dists.insert(k.clone(), (p, d));
                }
                (Err(e), _) => errors.push(err_at(file, text, &field, e.to_string())),
                (_, Err(e)) => errors.push(err_at(file, text, &field, e.to_string())),
            }
        }
        if let Some(f) = &spec.faults {
            if f.draw > f.catalogue.len() {
                errors.push(err_at(
                    file,
                    text,
                    "faults.draw",
                    format!("draws {} of a catalogue of {}", f.draw, f.catalogue.len()),
                ));
            }
            for (i, entry) in f.catalogue.iter().enumerate() {
                let mut rng = stream(0, 0, "check");
                if let Err(e) = draw_inside(&toml::Value::Table(entry.clone()), &mut rng) {
                    errors.push(err_at(
                        file,
                        text,
                        &format!("faults.catalogue[{i}]"),
                        e.to_string(),
                    ));
                }
            }
        }
        if !errors.is_empty() {
            return Err(ScenarioErrors(errors));
        }
        Ok(Campaign {
            file: file.to_owned(),
            text: text.to_owned(),
            spec,
            base,
            base_file,
            dists,
        })
    }

    /// Read and parse a campaign file.
    pub fn load(path: &Path) -> anyhow::Result<Campaign> {
        let file = path.display().to_string();
        let text = twin_scenario::scenario::read_input(path)
            .map_err(|e| anyhow::anyhow!("reading campaign {file}: {e}"))?;
        Ok(Campaign::parse(&file, &text)?)
    }

    /// The campaign's name: its `name`, or the file stem.
    pub fn name(&self) -> String {
        self.spec.name.clone().unwrap_or_else(|| {
            Path::new(&self.file)
                .file_stem()
                .map_or_else(|| self.file.clone(), |s| s.to_string_lossy().into_owned())
        })
    }

    /// The scenario of run `k`: every dispersion and fault drawn, validated. An error names
    /// the campaign field whose draw made the scenario invalid, when it can tell.
    pub fn resolve(&self, k: u64) -> Result<Resolved, ScenarioErrors> {
        let seed = self.spec.seed;
        let mut table = self.base.clone();
        let mut draws = BTreeMap::new();
        // Drawn catalogue entries: where each landed in the scenario, and its index.
        let mut appended: Vec<(String, usize)> = Vec::new();
        // The run's own seed (the scenario's `seed`): from the campaign's seed and k too.
        let run_seed = match self.spec.run_seeds {
            RunSeeds::PerRun => mix(mix(seed, k), 0x5eed),
            RunSeeds::Shared => mix(seed, 0x5eed),
        };
        table.insert("seed".into(), toml::Value::Integer((run_seed >> 1) as i64));
        let name = format!(
            "{} run {k}",
            table
                .get("name")
                .and_then(toml::Value::as_str)
                .unwrap_or("campaign")
        );
        table.insert("name".into(), toml::Value::String(name));
        // A campaign checks every invariant (unless its base scenario names its own set):
        // written into the run's scenario, so that its failure file, run by itself, checks
        // the same.
        if let Some(inv) = table
            .entry("invariants")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
        {
            inv.entry("check")
                .or_insert_with(|| toml::Value::String("all".into()));
        }
        for (key, (path, dist)) in &self.dists {
            let v = dist.sample(&mut stream(seed, k, key));
            // A string as itself (`normal`, `60000ms`), anything else as TOML.
            draws.insert(
                key.clone(),
                v.as_str().map_or_else(|| v.to_string(), str::to_owned),
            );
            set_path(&mut table, path, v).map_err(|e| {
                ScenarioErrors(vec![err_at(
                    &self.file,
                    &self.text,
                    &format!("dispersions.{key}"),
                    format!("{e} (base scenario {})", self.base_file),
                )])
            })?;
        }
        if let Some(f) = &self.spec.faults {
            let kinds = self.draw_faults(f, k, &mut table, &mut appended)?;
            draws.insert("faults".into(), kinds);
        }
        let text = toml::to_string(&table).map_err(|e| {
            ScenarioErrors(vec![err_at(
                &self.file,
                &self.text,
                "scenario",
                e.to_string(),
            )])
        })?;
        let shown = format!("{} run {k}", self.file);
        crate::validate::parse(&shown, &text).map_err(|e| {
            // Point at the dispersion whose path the scenario's error names, if any.
            ScenarioErrors(
                e.0.into_iter()
                    .map(|se| self.blame(k, se, &draws, &appended))
                    .collect(),
            )
        })?;
        Ok(Resolved {
            run: k,
            seed: (run_seed >> 1),
            draws,
            text,
        })
    }

    /// Run `k`'s draw from the fault catalogue, each entry appended to the list in `table`
    /// it names (`appended`: where it landed, to blame it if the scenario refuses it); the
    /// kinds drawn, as the run's draws show them.
    fn draw_faults(
        &self,
        f: &FaultDraws,
        k: u64,
        table: &mut toml::Table,
        appended: &mut Vec<(String, usize)>,
    ) -> Result<String, ScenarioErrors> {
        let seed = self.spec.seed;
        let mut pick = stream(seed, k, "faults");
        let mut left: Vec<usize> = (0..f.catalogue.len()).collect();
        let mut chosen = Vec::new();
        for _ in 0..f.draw {
            let i = left.remove((pick.next_u64() % left.len() as u64) as usize);
            chosen.push(i);
        }
        chosen.sort_unstable();
        let mut kinds = Vec::new();
        for i in chosen {
            let at = |e: String| {
                ScenarioErrors(vec![err_at(
                    &self.file,
                    &self.text,
                    &format!("faults.catalogue[{i}]"),
                    e,
                )])
            };
            let mut rng = stream(seed, k, &format!("faults.catalogue[{i}]"));
            let mut entry = draw_inside(&toml::Value::Table(f.catalogue[i].clone()), &mut rng)
                .map_err(|e| at(e.to_string()))?;
            let into = match entry.as_table_mut().and_then(|t| t.remove("into")) {
                None => "faults".to_owned(),
                Some(toml::Value::String(p)) => p,
                Some(other) => {
                    return Err(at(format!("`into` takes a list's path, found {other}")));
                }
            };
            let what = entry
                .get("kind")
                .or_else(|| entry.get("fault"))
                .and_then(toml::Value::as_str)
                .unwrap_or("?");
            kinds.push(format!("{what}#{i}"));
            let path = parse_path(&into).map_err(|e| at(e.to_string()))?;
            let mut list = match get_path(table, &path) {
                Some(toml::Value::Array(a)) => a.clone(),
                None => Vec::new(),
                Some(_) => {
                    return Err(at(format!("`{into}` is not a list in the base scenario")));
                }
            };
            // Where the entry lands (`faults[3]`), to name it if the scenario refuses it.
            appended.push((format!("{}[{}]", path_string(&path), list.len()), i));
            list.push(entry);
            set_path(table, &path, toml::Value::Array(list)).map_err(|e| at(e.to_string()))?;
        }
        Ok(kinds.join(" "))
    }

    /// A run's scenario error told against the campaign: at the dispersion or the drawn
    /// catalogue entry its field falls under, else with every draw of the run listed.
    fn blame(
        &self,
        k: u64,
        se: ScenarioError,
        draws: &BTreeMap<String, String>,
        appended: &[(String, usize)],
    ) -> ScenarioError {
        let key = self
            .dists
            .keys()
            .find(|key| se.field == **key || se.field.starts_with(&format!("{key}.")));
        let entry = appended
            .iter()
            .find(|(at, _)| se.field == *at || se.field.starts_with(&format!("{at}.")));
        if let (None, Some((at, i))) = (key, entry) {
            let field = se.field.strip_prefix(at.as_str()).unwrap_or("");
            return err_at(
                &self.file,
                &self.text,
                &format!("faults.catalogue[{i}]"),
                format!(
                    "run {k} drew this entry (as {}){}: {}",
                    at,
                    if field.is_empty() {
                        String::new()
                    } else {
                        format!(", its `{}`", field.trim_start_matches('.'))
                    },
                    se.message
                ),
            );
        }
        match key {
            Some(key) => err_at(
                &self.file,
                &self.text,
                &format!("dispersions.{key}"),
                format!("run {k} drew {}: {}", draws[key], se.message),
            ),
            None => ScenarioError {
                message: format!(
                    "run {k}: {} (draws: {})",
                    se.message,
                    draws
                        .iter()
                        .map(|(p, v)| format!("{p} = {v}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                ..se
            },
        }
    }

    /// Resolve runs `0..runs` (every problem before anything runs); the first errors found.
    pub fn check(&self, runs: u64) -> Result<(), ScenarioErrors> {
        for k in 0..runs {
            self.resolve(k)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    const BASE: &str = r#"
name = "base"
duration = "60s"

[fc]
initial_rate_deg_s = 3.0

[[faults]]
at = "10s"
until = "20s"
kind = "clock"
target = "FC"
jump_s = 60
"#;

    fn campaign(extra: &str) -> Result<Campaign, ScenarioErrors> {
        let text = format!(
            "runs = 20\nseed = 7\n{extra}\n[scenario]\n{}",
            BASE.replace("[fc]", "[scenario.fc]")
                .replace("[[faults]]", "[[scenario.faults]]")
        );
        Campaign::parse("c.toml", &text)
    }

    #[test]
    fn draws_depend_on_the_seed_the_run_and_the_entry_only() {
        let a = campaign(
            "[dispersions]\n\"fc.initial_rate_deg_s\" = { uniform = [1.0, 9.0] }\n\"faults[0].at\" = { uniform = [\"5s\", \"19s\"] }\n",
        )
        .unwrap();
        let b = campaign("[dispersions]\n\"fc.initial_rate_deg_s\" = { uniform = [1.0, 9.0] }\n")
            .unwrap();
        let r5 = a.resolve(5).unwrap();
        assert_eq!(r5, a.resolve(5).unwrap());
        assert_ne!(r5.draws, a.resolve(6).unwrap().draws);
        // Another dispersion does not change this one's values.
        assert_eq!(
            r5.draws["fc.initial_rate_deg_s"],
            b.resolve(5).unwrap().draws["fc.initial_rate_deg_s"]
        );
        let s = crate::validate::parse("r", &r5.text).unwrap();
        let rate = s.fc.initial_rate_deg_s.unwrap();
        assert!((1.0..=9.0).contains(&rate), "{rate}");
        assert_eq!(r5.draws["fc.initial_rate_deg_s"], rate.to_string());
        assert!(
            r5.text
                .contains(&format!("at = \"{}\"", r5.draws["faults[0].at"]))
        );
        assert_eq!(s.seed, r5.seed);
    }

    #[test]
    fn distributions_stay_in_their_range_and_keep_their_kind() {
        let mut rng = stream(1, 2, "x");
        let u = Dist::parse(&toml::Value::from(toml::toml! { uniform = [3, 5] }.clone())).unwrap();
        let n = Dist::parse(&toml::Value::Table(toml::toml! { normal = [0.5, 0.3]
        min = 0.0
        max = 1.0 }))
        .unwrap();
        let c = Dist::parse(&toml::Value::Table(toml::toml! { choice = ["a", "b"]
        weights = [0, 1] }))
        .unwrap();
        let d = Dist::parse(&toml::Value::Table(toml::toml! { uniform = ["1s", "2s"] })).unwrap();
        for _ in 0..500 {
            let i = u.sample(&mut rng).as_integer().unwrap();
            assert!((3..=5).contains(&i));
            let x = n.sample(&mut rng).as_float().unwrap();
            assert!((0.0..=1.0).contains(&x));
            assert_eq!(c.sample(&mut rng).as_str(), Some("b"));
            let ms = d.sample(&mut rng);
            let ms = crate::duration::parse_duration(ms.as_str().unwrap()).unwrap();
            assert!(ms.as_millis() >= 1000 && ms.as_millis() <= 2000);
        }
    }

    #[test]
    fn bad_distributions_and_paths_say_what_is_wrong() {
        let dist = |t: toml::Table| Dist::parse(&toml::Value::Table(t)).unwrap_err();
        assert_eq!(
            dist(toml::toml! { uniform = [5, 3] }),
            DistError::UniformReversed {
                low: 5.0,
                high: 3.0
            }
        );
        assert_eq!(
            dist(toml::toml! { uniform = [1, "2s"] }).to_string(),
            "`uniform`: both values must be numbers, or both durations"
        );
        assert_eq!(
            dist(toml::toml! { normal = [1, 1]
            weights = [1] })
            .to_string(),
            "unknown key `weights` (this distribution takes normal, min, max)"
        );
        assert_eq!(
            dist(toml::toml! { choice = [1, 2]
            weights = [1] })
            .to_string(),
            "1 weights for 2 choices"
        );
        let e = dist(toml::toml! { uniform = ["1s", "soon"] });
        assert!(
            matches!(&e, DistError::NotNumberOrDuration { text, .. } if text == "soon"),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "`soon` is neither a number nor a duration: `soon` is not a duration (try 90, 90s, \
             10m, 2h, 1h 30m)"
        );
        assert_eq!(
            parse_path("faults[x].at"),
            Err(FieldPathError::NotAnIndex {
                path: "faults[x].at".into(),
                index: "x".into()
            })
        );
        assert_eq!(
            parse_path("faults[0").unwrap_err().to_string(),
            "`faults[0`: unclosed `[`"
        );
        assert_eq!(
            parse_path("a.b-c").unwrap_err().to_string(),
            "`a.b-c` is not a field path (like `faults[0].at`)"
        );
        let mut root: toml::Table = toml::toml! { faults = [1] };
        let to = |p: &str| parse_path(p).unwrap();
        assert_eq!(
            set_path(&mut root, &to("faults[2]"), 1.into()),
            Err(SetPathError::NoEntry { index: 2, len: 1 })
        );
        assert_eq!(
            set_path(&mut root, &to("faults[0].at"), 1.into())
                .unwrap_err()
                .to_string(),
            "`at`: its parent is not a table"
        );
        assert_eq!(root, toml::toml! { faults = [1] });
    }

    #[test]
    fn bad_campaigns_name_the_file_line_and_field() {
        let e = campaign("[dispersions]\n\"fc.initial_rate_deg_s\" = { uniform = [9.0, 1.0] }\n")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("c.toml:4:"), "{e}");
        assert!(
            e.contains("dispersions.fc.initial_rate_deg_s") && e.contains("above"),
            "{e}"
        );
        let e = campaign("[dispersions]\n\"faults[3].at\" = { uniform = [\"1s\", \"2s\"] }\n")
            .unwrap()
            .resolve(0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.toml:4:") && e.contains("1 entries"), "{e}");
        // A draw that makes the scenario invalid (the FC's rate is 0-360 deg/s).
        let e =
            campaign("[dispersions]\n\"fc.initial_rate_deg_s\" = { uniform = [300.0, 900.0] }\n")
                .unwrap()
                .check(20)
                .unwrap_err()
                .to_string();
        assert!(e.contains("c.toml:4:") && e.contains("0-360"), "{e}");
        let e = campaign("bogus = 1\n").unwrap_err().to_string();
        assert!(e.contains("c.toml:3:") && e.contains("bogus"), "{e}");
        let e = campaign("[dispersions]\n\"fc.initial_rate_deg_s\" = { normal = [1.0, -1.0] }\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("standard deviation"), "{e}");
    }

    #[test]
    fn the_fault_catalogue_draws_distinct_entries_with_their_values() {
        let c = campaign(
            r#"
[faults]
draw = 2

[[faults.catalogue]]
kind = "clock"
target = "FC"
at = { uniform = ["1s", "5s"] }
until = "50s"
jump_s = { choice = [10, 20] }

[[faults.catalogue]]
kind = "clock"
target = "EPS"
at = "2s"
until = "3s"
jump_s = 5

[[faults.catalogue]]
kind = "clock"
target = "PC"
at = "2s"
until = "3s"
jump_s = 5
"#,
        )
        .unwrap();
        for k in 0..20 {
            let r = c.resolve(k).unwrap();
            let s = crate::validate::parse("r", &r.text).unwrap();
            // The base's fault and two drawn ones.
            assert_eq!(s.faults.len(), 3, "{}", r.text);
            let kinds: Vec<&str> = r.draws["faults"].split(' ').collect();
            assert_eq!(kinds.len(), 2);
            assert_ne!(kinds[0], kinds[1]);
        }
        // A drawn entry the scenario refuses is named in the campaign file.
        let e = campaign(
            "[faults]\ndraw = 1\n[[faults.catalogue]]\nkind = \"babble\"\ntarget = \"payload\"\nnode = \"ECU\"\nat = \"1s\"\n",
        )
        .unwrap()
        .check(1)
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("c.toml:5:")
                && e.contains("faults.catalogue[0]")
                && e.contains("faults[1]"),
            "{e}"
        );
        assert!(e.contains("its `node`") && e.contains("payload"), "{e}");
        let e = campaign("[faults]\ndraw = 2\n[[faults.catalogue]]\nkind = \"clock\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("faults.draw") && e.contains("catalogue of 1"),
            "{e}"
        );
    }

    /// Every shipped campaign parses and every run of it resolves to a valid scenario.
    #[test]
    fn shipped_campaigns_check() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../campaigns");
        let mut n = 0;
        for e in std::fs::read_dir(&dir).unwrap() {
            let path = e.unwrap().path();
            if path.extension().is_some_and(|x| x == "toml") {
                let c = Campaign::load(&path).unwrap();
                c.check(c.spec.runs).unwrap();
                n += 1;
            }
        }
        assert!(n >= 1);
    }
}
