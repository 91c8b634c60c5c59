//! Checking a scenario's expectations against what a run did.

use csp::SimTime;

use crate::ground::{Outcome, RequestResult};
use crate::plan::{Check, CounterTarget, Expectation};
use crate::runtime::{AttitudeSample, RunReport};
use crate::scenario::{Occurrence, When};

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
        Check::Attitude {
            quantity,
            occurrence,
            below,
            above,
            from,
            to,
            when,
            min_elevation_deg,
        } => check_attitude(
            report,
            AttitudeCheck {
                quantity,
                occurrence: *occurrence,
                below: *below,
                above: *above,
                from: *from,
                to: to.unwrap_or(report.sim_time),
                when: *when,
                min_elevation_deg: *min_elevation_deg,
            },
        )
        .map_or_else(
            |(t, why)| verdict(false, t, why),
            |(t, ok)| verdict(true, t, ok),
        ),
        Check::Session { .. } | Check::Downlink { .. } | Check::Accounting { .. } => {
            let (passed, t, observed) = crate::sessions::check(&x.check, report);
            verdict(passed, t, observed)
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

struct AttitudeCheck<'a> {
    quantity: &'a str,
    occurrence: Occurrence,
    below: Option<f64>,
    above: Option<f64>,
    from: SimTime,
    to: SimTime,
    when: When,
    min_elevation_deg: f64,
}

/// The named figure of a sample (`None`: it does not apply, for example no target).
fn quantity(s: &AttitudeSample, name: &str) -> Option<f64> {
    match name {
        "rate_deg_s" => Some(s.rate_deg_s),
        "pointing_error_deg" => s.pointing_error_deg,
        "axis_error_deg" => s.axis_error_deg,
        "estimation_error_deg" => s.estimation_error_deg,
        "max_wheel_rpm" => Some(s.max_wheel_rpm),
        "mode" => Some(f64::from(s.mode)),
        "state" => Some(f64::from(s.state)),
        _ => None,
    }
}

/// Every selected sample in the window within bounds: `Ok((end, summary))` or
/// `Err((first failing time, why))`.
fn check_attitude(
    report: &RunReport,
    c: AttitudeCheck<'_>,
) -> Result<(SimTime, String), (SimTime, String)> {
    let selected = report.attitude.iter().filter(|s| {
        s.t >= c.from
            && s.t <= c.to
            && match c.when {
                When::Always => true,
                When::Sunlit => s.sun_visible_fraction >= 1.0,
                When::Eclipse => s.sun_visible_fraction <= 0.0,
                When::TargetVisible => s
                    .target_elevation_deg
                    .is_some_and(|e| e >= c.min_elevation_deg),
            }
    });
    let (mut n, mut lo, mut hi) = (0usize, f64::INFINITY, f64::NEG_INFINITY);
    let mut failures = 0usize;
    let mut first: Option<(SimTime, String)> = None;
    for s in selected {
        n += 1;
        let v = quantity(s, c.quantity);
        let problem = match v {
            None => Some(format!("no `{}` at this time", c.quantity)),
            Some(v) if c.below.is_some_and(|b| v.is_nan() || v >= b) => Some(format!(
                "{} = {v:.4} (expected below {})",
                c.quantity,
                c.below.unwrap_or_default()
            )),
            Some(v) if c.above.is_some_and(|a| v.is_nan() || v <= a) => Some(format!(
                "{} = {v:.4} (expected above {})",
                c.quantity,
                c.above.unwrap_or_default()
            )),
            Some(_) => None,
        };
        if let Some(v) = v {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if let Some(p) = problem {
            failures += 1;
            first.get_or_insert((s.t, p));
        }
    }
    let window = format!("{} to {} ({:?})", c.from, c.to, c.when);
    if n == 0 {
        return Err((c.to, format!("no FC samples in {window}")));
    }
    let range = format!(
        "{n} samples in {window}, {} from {lo:.4} to {hi:.4}",
        c.quantity
    );
    if c.occurrence == Occurrence::Any {
        return if failures < n {
            Ok((c.to, format!("{} of {range} within bounds", n - failures)))
        } else {
            Err((c.to, format!("none of {range} within bounds")))
        };
    }
    match first {
        Some((t, p)) => Err((t, format!("{failures} of {range}; first at {t}: {p}"))),
        None => Ok((c.to, range)),
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
