//! Checking a scenario's expectations against what a run did.

use csp::SimTime;

use crate::ground::{Outcome, RequestResult};
use crate::plan::{Check, CounterTarget, Expectation};
use crate::runtime::RunReport;
use crate::scenario::Occurrence;

/// The verdict on one expectation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verdict {
    /// The expectation's name.
    pub name: String,
    /// Whether it held.
    pub passed: bool,
    /// The simulated time the verdict refers to (the failing occurrence, or the end).
    pub t: SimTime,
    /// What was observed, for example `reply after 1.204 s (limit 1.000 s)`.
    pub observed: String,
}

/// Check every expectation.
pub fn check_all(expectations: &[Expectation], report: &RunReport) -> Vec<Verdict> {
    expectations.iter().map(|x| check(x, report)).collect()
}

fn secs(d: std::time::Duration) -> String {
    format!("{:.3} s", d.as_secs_f64())
}

/// Why one occurrence fails a reply check, or `None` if it passes.
fn reply_problem(r: &RequestResult, check: &Check) -> Option<String> {
    let Check::Reply {
        within,
        result,
        data,
        data_len,
        ..
    } = check
    else {
        return None;
    };
    match &r.outcome {
        Outcome::Timeout => Some(format!(
            "no reply within the {} timeout",
            secs(r.request.timeout)
        )),
        Outcome::SendFailed(e) => Some(format!("not sent: {e}")),
        Outcome::Reply { data: got, rtt } => {
            if let Some(w) = within
                && rtt > w
            {
                return Some(format!("reply after {} (limit {})", secs(*rtt), secs(*w)));
            }
            if let Some(code) = result
                && got.get(1) != Some(code)
            {
                return Some(format!(
                    "result code {} (expected {code}), reply {}",
                    got.get(1).map_or("missing".to_owned(), u8::to_string),
                    hex::encode(got)
                ));
            }
            if let Some(want) = data
                && got != want
            {
                return Some(format!(
                    "reply {} (expected {})",
                    hex::encode(got),
                    hex::encode(want)
                ));
            }
            if let Some(n) = data_len
                && got.len() != *n
            {
                return Some(format!("reply of {} bytes (expected {n})", got.len()));
            }
            None
        }
    }
}

fn check(x: &Expectation, report: &RunReport) -> Verdict {
    let verdict = |passed, t, observed: String| Verdict {
        name: x.name.clone(),
        passed,
        t,
        observed,
    };
    match &x.check {
        Check::Reply {
            command,
            occurrence,
            ..
        }
        | Check::NoReply {
            command,
            occurrence,
        } => {
            let mut runs: Vec<&RequestResult> = report
                .results
                .iter()
                .filter(|r| &r.request.label == command)
                .collect();
            runs.sort_by_key(|r| r.sent);
            if runs.is_empty() {
                return verdict(
                    false,
                    report.sim_time,
                    format!("command `{command}` was never sent before the end of the run"),
                );
            }
            let problems: Vec<(SimTime, String)> = runs
                .iter()
                .filter_map(|r| {
                    let p = if matches!(x.check, Check::NoReply { .. }) {
                        match &r.outcome {
                            Outcome::Reply { data, rtt } => Some(format!(
                                "answered after {}: {}",
                                secs(*rtt),
                                hex::encode(data)
                            )),
                            _ => None,
                        }
                    } else {
                        reply_problem(r, &x.check)
                    };
                    p.map(|p| (r.sent, p))
                })
                .collect();
            let n = runs.len();
            match occurrence {
                Occurrence::Every => match problems.first() {
                    Some((t, p)) => verdict(
                        false,
                        *t,
                        format!(
                            "{} of {n} occurrences failed; first, sent at {t}: {p}",
                            problems.len()
                        ),
                    ),
                    None => verdict(
                        true,
                        report.sim_time,
                        format!("{n} of {n} occurrences held"),
                    ),
                },
                Occurrence::Any => {
                    if problems.len() < n {
                        verdict(
                            true,
                            report.sim_time,
                            format!("{} of {n} occurrences held", n - problems.len()),
                        )
                    } else {
                        let (t, p) = problems
                            .last()
                            .cloned()
                            .unwrap_or((report.sim_time, String::new()));
                        verdict(
                            false,
                            t,
                            format!("none of {n} occurrences held; last, sent at {t}: {p}"),
                        )
                    }
                }
            }
        }
        Check::Counter {
            target,
            counter,
            min,
            max,
        } => {
            let value = counter_value(report, target, counter);
            let t = report.sim_time;
            match value {
                None => verdict(
                    false,
                    t,
                    format!("counter `{counter}` not found on {target:?}"),
                ),
                Some(v) => {
                    let low = min.is_some_and(|m| v < m);
                    let high = max.is_some_and(|m| v > m);
                    let bounds = match (min, max) {
                        (Some(a), Some(b)) => format!("{a}..={b}"),
                        (Some(a), None) => format!(">= {a}"),
                        (None, Some(b)) => format!("<= {b}"),
                        (None, None) => "any".into(),
                    };
                    verdict(
                        !(low || high),
                        t,
                        format!("{counter} = {v} (expected {bounds})"),
                    )
                }
            }
        }
    }
}

/// A counter's value at the end of the run.
pub fn counter_value(report: &RunReport, target: &CounterTarget, counter: &str) -> Option<u64> {
    match target {
        CounterTarget::Node(a) => {
            let c = &report.nodes.iter().find(|n| n.addr == *a)?.counters;
            Some(match counter {
                "rx_packets" => c.rx_packets,
                "tx_packets" => c.tx_packets,
                "forwarded" => c.forwarded,
                "delivered" => c.delivered,
                "service_replies" => c.service_replies,
                "reboots" => c.reboots,
                "drops" => c.total_drops(),
                other => {
                    let reason = other.strip_prefix("drops.")?;
                    c.drops.get(reason).copied().unwrap_or(0)
                }
            })
        }
        CounterTarget::Medium(m) if m == "ground" => {
            let g = &report.ground;
            match counter {
                "packets" | "frames" => Some(g.packets),
                "bytes" => Some(g.bytes),
                "dropped" => Some(g.dropped),
                _ => None,
            }
        }
        CounterTarget::Medium(m) => {
            let b = report.buses.iter().find(|b| &b.name == m)?;
            match counter {
                "frames" | "packets" => Some(b.frames),
                "bytes" => Some(b.bytes),
                "dropped" => Some(b.dropped),
                "corrupted" => Some(b.corrupted),
                _ => None,
            }
        }
    }
}
