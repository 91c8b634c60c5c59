//! Shrinking a failing run: the smallest scenario that still fails the same way, as
//! property-testing tools shrink a failing input.
//!
//! A candidate "still fails" when it fails at least one of the checks (expectations or
//! invariants) that the original failed, or, when the original ended in an error, when it
//! still does. Greedy and deterministic, each step kept only when the candidate still fails:
//! 1. remove each fault (last first);
//! 2. narrow each remaining fault's window: bisect `until` towards `at`, then `at` towards
//!    `until` (8 steps each);
//! 3. with the campaign's base scenario, set each field the run drew back to the base's
//!    value (or remove it where the base has none).
//!
//! Every candidate is a full virtual-time run: shrinking costs one run per step tried.

use std::collections::BTreeSet;

use anyhow::bail;

use crate::campaign::get_path;
use crate::campaign_run::{RunVerdict, run_text};
use twin_scenario::scenario::{PathStep, path_string};

/// What shrinking produced.
#[derive(Debug, Clone, PartialEq)]
pub struct Shrunk {
    /// The smallest failing scenario found.
    pub text: String,
    /// The checks it fails (or its error).
    pub failed: Vec<String>,
    /// The steps kept, in order (`removed faults[2] (clock)`, ...).
    pub steps: Vec<String>,
    /// Runs made.
    pub runs: usize,
}

/// The checks a verdict failed; `None` when it passed.
fn failed_checks(v: &RunVerdict) -> Option<BTreeSet<String>> {
    match v {
        RunVerdict::Pass => None,
        RunVerdict::Fail(f) => Some(f.iter().map(|(n, _)| n.clone()).collect()),
        RunVerdict::Error(_) => Some(BTreeSet::from(["error".to_owned()])),
        RunVerdict::NotRun(_) => Some(BTreeSet::from(["not run".to_owned()])),
    }
}

struct Shrinker<'a> {
    file: &'a str,
    target: BTreeSet<String>,
    runs: usize,
}

impl Shrinker<'_> {
    /// Whether `table` still fails one of the original's checks.
    fn fails(&mut self, table: &toml::Table) -> bool {
        let Ok(text) = toml::to_string(table) else {
            return false;
        };
        self.runs += 1;
        failed_checks(&run_text(self.file, &text))
            .is_some_and(|f| f.intersection(&self.target).next().is_some())
    }
}

/// A duration field's value in ms (`"90s"`, `90`).
fn millis(v: &toml::Value) -> Option<u64> {
    let text = match v {
        toml::Value::String(s) => s.clone(),
        toml::Value::Integer(i) => i.to_string(),
        toml::Value::Float(f) => f.to_string(),
        _ => return None,
    };
    crate::duration::parse_duration(&text)
        .ok()
        .map(|d| d.as_millis() as u64)
}

/// Every leaf path where `run` differs from `base` (tables recursed, lists of one length
/// recursed index by index), skipping `skip` at the top.
fn differences(run: &toml::Table, base: &toml::Table, skip: &[&str]) -> Vec<Vec<PathStep>> {
    fn walk(
        a: &toml::Value,
        b: Option<&toml::Value>,
        path: &mut Vec<PathStep>,
        out: &mut Vec<Vec<PathStep>>,
    ) {
        match (a, b) {
            (toml::Value::Table(x), Some(toml::Value::Table(y))) => {
                for (k, v) in x {
                    path.push(PathStep::Key(k.clone()));
                    walk(v, y.get(k), path, out);
                    path.pop();
                }
            }
            (toml::Value::Array(x), Some(toml::Value::Array(y))) if x.len() == y.len() => {
                for (i, (v, w)) in x.iter().zip(y).enumerate() {
                    path.push(PathStep::Index(i));
                    walk(v, Some(w), path, out);
                    path.pop();
                }
            }
            (a, Some(b)) if a == b => {}
            _ => out.push(path.clone()),
        }
    }
    let mut out = Vec::new();
    for (k, v) in run {
        if skip.contains(&k.as_str()) {
            continue;
        }
        let mut path = vec![PathStep::Key(k.clone())];
        walk(v, base.get(k), &mut path, &mut out);
    }
    out
}

/// `t` with the value at `path` replaced by `value` (`None`: removed).
fn with(t: &toml::Table, path: &[PathStep], value: Option<toml::Value>) -> toml::Table {
    fn put(node: &mut toml::Value, path: &[PathStep], value: Option<toml::Value>) {
        let Some((step, rest)) = path.split_first() else {
            return;
        };
        match (step, rest.is_empty()) {
            (PathStep::Key(k), true) => {
                if let Some(t) = node.as_table_mut() {
                    match value {
                        Some(v) => {
                            t.insert(k.clone(), v);
                        }
                        None => {
                            t.remove(k);
                        }
                    }
                }
            }
            (PathStep::Index(i), true) => {
                if let (Some(a), Some(v)) = (node.as_array_mut(), value)
                    && let Some(slot) = a.get_mut(*i)
                {
                    *slot = v;
                }
            }
            (PathStep::Key(k), false) => {
                if let Some(n) = node.get_mut(k.as_str()) {
                    put(n, rest, value);
                }
            }
            (PathStep::Index(i), false) => {
                if let Some(n) = node.get_mut(*i) {
                    put(n, rest, value);
                }
            }
        }
    }
    let mut whole = toml::Value::Table(t.clone());
    put(&mut whole, path, value);
    match whole {
        toml::Value::Table(t) => t,
        _ => t.clone(),
    }
}

/// Shrink the failing scenario `text` (`file` names it), moving values towards `base` when
/// given. An error when the scenario does not fail.
pub fn shrink(file: &str, text: &str, base: Option<&toml::Table>) -> anyhow::Result<Shrunk> {
    let mut table: toml::Table = text.parse().map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    let original = run_text(file, text);
    let Some(target) = failed_checks(&original) else {
        bail!("{file} passes: there is no failure to shrink");
    };
    let mut s = Shrinker {
        file,
        target,
        runs: 1,
    };
    let mut steps = Vec::new();
    // 1. Faults, last first.
    let n = table
        .get("faults")
        .and_then(toml::Value::as_array)
        .map_or(0, Vec::len);
    for i in (0..n).rev() {
        let mut candidate = table.clone();
        let Some(faults) = candidate
            .get_mut("faults")
            .and_then(toml::Value::as_array_mut)
        else {
            break;
        };
        let removed = faults.remove(i);
        if s.fails(&candidate) {
            let kind = removed
                .get("kind")
                .and_then(toml::Value::as_str)
                .unwrap_or("?");
            steps.push(format!("removed faults[{i}] ({kind})"));
            table = candidate;
        }
    }
    // 2. Windows: bisect `until` down towards `at`, then `at` up towards `until`.
    let n = table
        .get("faults")
        .and_then(toml::Value::as_array)
        .map_or(0, Vec::len);
    for i in 0..n {
        let field = |name: &str| {
            [
                PathStep::Key("faults".into()),
                PathStep::Index(i),
                PathStep::Key(name.into()),
            ]
        };
        for (moved, towards) in [("until", "at"), ("at", "until")] {
            let (Some(mut from), Some(other)) = (
                get_path(&table, &field(moved)).and_then(millis),
                get_path(&table, &field(towards)).and_then(millis),
            ) else {
                break;
            };
            // `from` fails; `bound` is as far as it may go (a window of at least 1 ms).
            let mut bound = if moved == "until" {
                other + 1
            } else {
                other.saturating_sub(1)
            };
            let start = from;
            for _ in 0..8 {
                if from.abs_diff(bound) <= 1 {
                    break;
                }
                let mid = (from + bound) / 2;
                let candidate = with(
                    &table,
                    &field(moved),
                    Some(toml::Value::String(format!("{mid}ms"))),
                );
                if s.fails(&candidate) {
                    from = mid;
                    table = candidate;
                } else {
                    bound = mid;
                }
            }
            if from != start {
                steps.push(format!("faults[{i}].{moved} {start} ms -> {from} ms"));
            }
        }
    }
    // 3. Towards the base.
    if let Some(base) = base {
        for path in differences(&table, base, &["seed", "name", "faults"]) {
            let to = get_path(base, &path).cloned();
            let candidate = with(&table, &path, to.clone());
            if s.fails(&candidate) {
                steps.push(match &to {
                    Some(v) => format!("{} back to the base's {v}", path_string(&path)),
                    None => format!("{} removed (the base has none)", path_string(&path)),
                });
                table = candidate;
            }
        }
    }
    let text = toml::to_string(&table)?;
    let failed = match run_text(file, &text) {
        RunVerdict::Fail(f) => f.into_iter().map(|(n, o)| format!("{n}: {o}")).collect(),
        RunVerdict::Error(e) => vec![format!("error: {e}")],
        RunVerdict::NotRun(e) => bail!("{file}: the shrunk scenario did not run: {e}"),
        RunVerdict::Pass => {
            bail!("{file}: the shrunk scenario passes (a run that is not deterministic?)")
        }
    };
    Ok(Shrunk {
        text,
        failed,
        steps,
        runs: s.runs + 1,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A failing run with three irrelevant faults shrinks to the one that matters: the EPS
    /// hung over the ping, its window cut down to what the failure needs.
    #[test]
    fn three_irrelevant_faults_go_and_the_one_that_matters_stays() {
        let text = r#"
name = "shrink-me"
duration = "20s"

[[commands]]
name = "ping-eps"
at = "10s"
to = "EPS"
request = "ping"
timeout = "2s"

[[expectations]]
name = "eps-answers"
kind = "reply"
command = "ping-eps"

[[faults]]
at = "1s"
until = "2s"
kind = "clock"
target = "FC"
jump_s = 10

[[faults]]
at = "2s"
until = "18s"
kind = "hang"
target = "EPS"

[[faults]]
at = "1s"
until = "3s"
kind = "power-off"
target = "PC"

[[faults]]
at = "1s"
until = "19s"
kind = "panel-loss"
target = "EPS"
panel = "wing+Y"
"#;
        let r = shrink("shrink.toml", text, None).unwrap();
        let s = crate::validate::parse("shrunk", &r.text).unwrap();
        assert_eq!(s.faults.len(), 1, "{}\n{:?}", r.text, r.steps);
        let t: toml::Table = r.text.parse().unwrap();
        let fault = &t["faults"][0];
        assert_eq!(fault["kind"].as_str(), Some("hang"), "{}", r.text);
        // The hang must still cover the ping at 10 s: its end moved in from 18 s.
        let until = millis(&fault["until"]).unwrap();
        assert!(
            (10_000..18_000).contains(&until),
            "{until} ms: {:?}",
            r.steps
        );
        assert!(
            r.failed.iter().any(|f| f.starts_with("eps-answers")),
            "{:?}",
            r.failed
        );
        assert!(
            r.steps.iter().filter(|s| s.starts_with("removed")).count() == 3,
            "{:?}",
            r.steps
        );
        // A passing scenario has nothing to shrink.
        let passing = text.replace(
            "at = \"2s\"\nuntil = \"18s\"\nkind = \"hang\"",
            "at = \"2s\"\nuntil = \"3s\"\nkind = \"hang\"",
        );
        assert!(shrink("p.toml", &passing, None).is_err());
    }

    #[test]
    fn values_move_back_to_the_base_when_that_keeps_the_failure() {
        let base: toml::Table = "duration = \"20s\"\n[fc]\ninitial_rate_deg_s = 3.0\n"
            .parse()
            .unwrap();
        let run: toml::Table =
            "duration = \"20s\"\nseed = 5\n[fc]\ninitial_rate_deg_s = 7.5\nmode = \"detumble\"\n"
                .parse()
                .unwrap();
        let d: Vec<String> = differences(&run, &base, &["seed"])
            .iter()
            .map(|p| path_string(p))
            .collect();
        assert_eq!(d, ["fc.initial_rate_deg_s", "fc.mode"]);
        let back = with(
            &run,
            &[PathStep::Key("fc".into()), PathStep::Key("mode".into())],
            None,
        );
        assert_eq!(back["fc"].as_table().unwrap().len(), 1);
    }
}
