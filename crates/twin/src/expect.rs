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
        Outcome::Unfinished => Some(unfinished(r)),
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
                && !want.matches(got)
            {
                return Some(format!("reply {} (expected {want})", hex::encode(got)));
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
                            Outcome::Unfinished => Some(unfinished(r)),
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
        Check::Power {
            quantity,
            statistic,
            below,
            above,
            from,
            to,
            when,
        } => {
            let (passed, t, observed) = check_power(
                report,
                quantity,
                (*statistic, *when),
                (*below, *above),
                *from,
                to.unwrap_or(report.sim_time),
            );
            verdict(passed, t, observed)
        }
        Check::Beacon {
            within,
            min,
            max,
            sender,
            from,
            to,
        } => {
            let (passed, t, observed) = check_beacons(
                report,
                *within,
                (*min, *max),
                *sender,
                (*from, to.unwrap_or(report.sim_time)),
            );
            verdict(passed, t, observed)
        }
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
        "tle_offset_m" => s.tle_offset_m,
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
                "no_contact" => Some(g.no_contact),
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

/// Judge a `power` expectation over the EPS samples in `[from, to]`.
fn check_power(
    report: &RunReport,
    quantity: &str,
    (statistic, when): (crate::scenario::Statistic, When),
    (below, above): (Option<f64>, Option<f64>),
    from: SimTime,
    to: SimTime,
) -> (bool, SimTime, String) {
    use crate::scenario::Statistic;
    let value = |s: &crate::runtime::PowerSample| match quantity {
        "soc" => s.soc,
        "battery_v" => s.battery_v,
        "battery_a" => s.battery_a,
        "solar_w" => s.solar_w,
        "load_w" => s.load_w,
        _ => s.solar_w - s.load_w,
    };
    let samples: Vec<(SimTime, f64)> = report
        .power
        .iter()
        .filter(|s| s.t >= from && s.t <= to)
        .filter(|s| match when {
            When::Sunlit => s.solar_w > 0.0,
            When::Eclipse => s.solar_w <= 0.0,
            _ => true,
        })
        .map(|s| (s.t, value(s)))
        .collect();
    if samples.is_empty() {
        return (
            false,
            to,
            format!("no EPS sample ({when:?}) between {from} and {to} (is the EPS running?)"),
        );
    }
    let ok = |v: f64| below.is_none_or(|b| v < b) && above.is_none_or(|a| v > a);
    let (lo, hi) = samples
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &(_, v)| {
            (a.min(v), b.max(v))
        });
    let mean = samples.iter().map(|s| s.1).sum::<f64>() / samples.len() as f64;
    let n = samples.len();
    let range = format!(
        "{n} samples in {from} to {to}, {quantity} from {lo:.4} to {hi:.4}, mean {mean:.4}"
    );
    let bounds = match (above, below) {
        (Some(a), Some(b)) => format!("within ({a}, {b})"),
        (Some(a), None) => format!("above {a}"),
        (None, Some(b)) => format!("below {b}"),
        (None, None) => "any".into(),
    };
    match statistic {
        Statistic::Every => match samples.iter().find(|s| !ok(s.1)) {
            Some(&(t, v)) => (
                false,
                t,
                format!("{range}; first at {t}: {quantity} = {v:.4} (expected {bounds})"),
            ),
            None => (true, to, range),
        },
        Statistic::Mean | Statistic::Min | Statistic::Max => {
            let (name, v) = match statistic {
                Statistic::Mean => ("mean", mean),
                Statistic::Min => ("min", lo),
                _ => ("max", hi),
            };
            let held = ok(v);
            (
                held,
                to,
                if held {
                    range
                } else {
                    format!("{range} ({name} {v:.4}, expected {bounds})")
                },
            )
        }
    }
}

/// The contact windows of a run: from each acquisition to the next loss (the whole run
/// without pass modelling).
fn contact_windows(report: &RunReport) -> Vec<(SimTime, SimTime)> {
    let mut out = Vec::new();
    let mut open = Some(SimTime::ZERO);
    for &(t, on) in &report.contact {
        match (on, open) {
            (true, None) => open = Some(t),
            (false, Some(a)) => {
                if t > a {
                    out.push((a, t));
                }
                open = None;
            }
            _ => {}
        }
    }
    if let Some(a) = open {
        out.push((a, report.sim_time));
    }
    out
}

/// Why a request the run ended on is no verdict either way.
fn unfinished(r: &RequestResult) -> String {
    format!(
        "sent, but the run ended before its reply or its {} timeout",
        secs(r.request.timeout)
    )
}

/// Judge a `beacon` expectation.
fn check_beacons(
    report: &RunReport,
    within: Option<std::time::Duration>,
    (min, max): (Option<u64>, Option<u64>),
    sender: Option<u8>,
    (from, to): (SimTime, SimTime),
) -> (bool, SimTime, String) {
    let end = to;
    let beacons: Vec<(SimTime, u8, u32)> = report
        .beacons
        .iter()
        .copied()
        .filter(|&(t, s, _)| t >= from && t <= to && sender.is_none_or(|w| w == s))
        .collect();
    let n = beacons.len() as u64;
    // Contact windows cut to [from, to].
    let windows: Vec<(SimTime, SimTime)> = contact_windows(report)
        .into_iter()
        .map(|(a, b)| (a.max(from), b.min(to)))
        .filter(|(a, b)| b > a)
        .collect();
    // (+ 0.0: an empty sum is -0.0.)
    let contact_s: f64 = windows
        .iter()
        .map(|(a, b)| (*b - *a).as_secs_f64())
        .sum::<f64>()
        + 0.0;
    let mut seen = format!(
        "{n} beacons{} on the ground over {:.0} s of contact in {} window(s)",
        sender.map_or(String::new(), |a| format!(" from CSP {a}")),
        contact_s,
        windows.len()
    );
    if min.is_some_and(|m| n < m) || max.is_some_and(|m| n > m) {
        return (
            false,
            end,
            format!("{seen} (expected {})", crate::sessions::bounds(min, max)),
        );
    }
    if let Some(gap) = within {
        for &(a, b) in &windows {
            // Only windows long enough to hold a beacon are judged.
            if (b - a) <= gap {
                continue;
            }
            let mut last = a;
            for &(t, _, _) in beacons.iter().filter(|(t, _, _)| *t >= a && *t <= b) {
                if t - last > gap {
                    return (
                        false,
                        t,
                        format!(
                            "{seen}; no beacon from {last} to {t} in contact (longer than {gap:?})"
                        ),
                    );
                }
                last = t;
            }
            if b - last > gap {
                return (
                    false,
                    b,
                    format!(
                        "{seen}; no beacon from {last} to the loss of contact at {b} (longer than {gap:?})"
                    ),
                );
            }
        }
        seen.push_str(&format!("; every gap in contact within {gap:?}"));
    }
    if let Some(&(t, _, _)) = beacons
        .iter()
        // A beacon sent just before the loss of contact lands up to its air time later.
        .find(|(t, _, _)| {
            !windows
                .iter()
                .any(|(a, b)| t >= a && *t <= *b + std::time::Duration::from_secs(1))
        })
    {
        return (
            false,
            t,
            format!("{seen}; a beacon arrived out of contact at {t}"),
        );
    }
    (true, end, seen)
}
