//! The `latency` expectation: a percentile of a command's round trips is below a bound.
//!
//! A round trip is an answered occurrence's reply time minus its send time (the ground
//! station's `rtt`, as `reply`'s `within` reads it). The percentile is the nearest rank:
//! of the `n` occurrences counted, sorted, the one at rank `ceil(percentile / 100 * n)`
//! (`percentile` to 0.0001), so `p100` is the longest and every value is one that was
//! measured, never an interpolation.
//!
//! An occurrence that timed out, or could not be sent, counts as longer than any bound:
//! it is ranked above every answered one, so a command answered fast only half the time
//! does not meet a p95 bound. One the run ended on (sent, neither its reply nor its timeout
//! come yet) is left out, since its round trip is unknown, and the verdict counts it. Fewer
//! answered occurrences than `min_samples` fail: a percentile of too few samples says
//! nothing. The verdict is at the end of the run, a statistic of the whole run.
//!
//! It is judged as the run goes, from the command's events ([`Watch`]); it keeps each
//! answered occurrence's round trip (8 bytes each, 8 MB for a command of the largest
//! `count`), which an exact percentile needs.
//!
//! See docs/scenarios.md ("Round-trip percentiles").

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Judgement, Watch, WatchCx};
use twin_core::events::{EventKind, Kinds, RunEvent};
use twin_runtime::ground::Outcome;
use twin_scenario::scenario::Dur;

/// The percentile when none is given.
pub const DEFAULT_PERCENTILE: f64 = 95.0;

/// The fewest answered occurrences when `min_samples` is not given.
pub const DEFAULT_MIN_SAMPLES: u64 = 1;

/// `latency`: the `percentile` of a command's round trips is below `below`.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LatencyExpect {
    /// The command, by name.
    pub command: String,
    /// Which percentile, more than 0 and at most 100 (default 95; 100 is the longest).
    #[serde(default)]
    pub percentile: Option<f64>,
    /// The bound the percentile must be strictly below.
    pub below: Dur,
    /// The fewest answered occurrences the verdict needs (default 1).
    #[serde(default)]
    pub min_samples: Option<u64>,
}

impl ExpectKind for LatencyExpect {
    const NAME: &'static str = "latency";
    const ABOUT: &'static str = "a percentile of the command's round trips is below `below` (unanswered ones count as over it)";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if let Some(c) = crate::commands::command_named(&self.command, cx, err) {
            let count = u64::from(c.count.unwrap_or(1));
            if self.min_samples.is_some_and(|m| m > count) {
                err(
                    "min_samples",
                    format!("`{}` is sent at most {count} times", self.command),
                );
            }
        }
        if let Some(p) = self.percentile
            && !(p > 0.0 && p <= 100.0)
        {
            err(
                "percentile",
                format!("must be more than 0 and at most 100 (got {p})"),
            );
        }
        if self.below.0.is_zero() {
            err(
                "below",
                "must be more than 0 (no round trip is below 0)".into(),
            );
        }
        if self.min_samples == Some(0) {
            err("min_samples", "must be at least 1".into());
        }
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let mut trips = RoundTrips::default();
        for r in cx
            .report
            .results
            .iter()
            .filter(|r| r.request.label == self.command)
        {
            match &r.outcome {
                Outcome::Reply { rtt, .. } => trips.answered_ns.push(nanos(*rtt)),
                Outcome::Timeout | Outcome::SendFailed(_) => trips.unanswered += 1,
                Outcome::Unfinished => trips.unfinished += 1,
            }
        }
        self.judge(trips, cx.report.sim_time)
    }

    fn watch(&self, _cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        Some(Box::new(LatencyWatch {
            expect: self.clone(),
            trips: RoundTrips::default(),
            sent: 0,
            decided: 0,
        }))
    }

    fn describe(&self) -> String {
        format!("latency of {}", self.command)
    }
}

/// A `Duration` in nanoseconds (a round trip is shorter than 584 years).
fn nanos(d: std::time::Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// What a command's occurrences came to.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct RoundTrips {
    /// Each answered occurrence's round trip, in the order their replies came.
    answered_ns: Vec<u64>,
    /// Occurrences that timed out or could not be sent.
    unanswered: u64,
    /// Occurrences sent and still waiting when the run ended.
    unfinished: u64,
}

/// The occurrence at a percentile.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum AtRank {
    /// An answered one, its round trip.
    RoundTrip { rtt_ns: u64 },
    /// An unanswered one: longer than any bound.
    Unanswered,
}

impl RoundTrips {
    /// The occurrence at `percentile` (0 < p <= 100) of the answered and unanswered ones,
    /// the unanswered ranked above every answered one; `None` when there is none.
    fn at_percentile(&self, percentile: f64) -> Option<AtRank> {
        let answered = self.answered_ns.len() as u64;
        let n = answered + self.unanswered;
        if n == 0 {
            return None;
        }
        let rank = nearest_rank(percentile, n);
        if rank > answered {
            return Some(AtRank::Unanswered);
        }
        let mut sorted = self.answered_ns.clone();
        let i = usize::try_from(rank - 1).unwrap_or(usize::MAX);
        let (_, &mut rtt_ns, _) = sorted.select_nth_unstable(i);
        Some(AtRank::RoundTrip { rtt_ns })
    }

    /// The occurrences not answered: those counted over the bound, those left out.
    fn others(&self) -> Vec<String> {
        let mut parts = Vec::new();
        if self.unanswered > 0 {
            parts.push(format!(
                "{} unanswered, counted over the bound",
                self.unanswered
            ));
        }
        if self.unfinished > 0 {
            parts.push(format!(
                "{} unfinished at the end, left out",
                self.unfinished
            ));
        }
        parts
    }
}

/// The 1-based nearest rank of `percentile` (0 < p <= 100) among `n` > 0 sorted values:
/// `ceil(p / 100 * n)`, in whole numbers with `p` to 0.0001 so that `p95` of 20 is exactly
/// the 19th (a float product could land a hair above 19 and take the 20th).
fn nearest_rank(percentile: f64, n: u64) -> u64 {
    // 0..=1_000_000 for a valid percentile; the cast saturates on anything else.
    let p_e4 = (percentile * 10_000.0).round() as u64;
    let rank = (u128::from(p_e4) * u128::from(n)).div_ceil(1_000_000);
    u64::try_from(rank).unwrap_or(n).clamp(1, n)
}

/// Milliseconds to the microsecond, without trailing zeros: `41.3 ms`, `250 ms`.
fn ms(ns: u64) -> String {
    let s = format!("{:.3}", ns as f64 / 1e6);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    format!("{s} ms")
}

impl LatencyExpect {
    /// The verdict on the command's occurrences, the run having ended at `end`.
    fn judge(&self, trips: RoundTrips, end: SimTime) -> Judgement {
        let command = &self.command;
        let p = self.percentile.unwrap_or(DEFAULT_PERCENTILE);
        let min = self.min_samples.unwrap_or(DEFAULT_MIN_SAMPLES);
        let answered = trips.answered_ns.len() as u64;
        let n = answered + trips.unanswered;
        if n + trips.unfinished == 0 {
            return Judgement::fail(
                end,
                format!("command `{command}` was never sent before the end of the run"),
            );
        }
        let others = trips.others();
        if answered < min {
            let why: Vec<String> = std::iter::once(format!("min_samples = {min}"))
                .chain(others)
                .collect();
            return Judgement::fail(
                end,
                format!(
                    "{answered} answered occurrences of `{command}`, too few for a p{p} ({})",
                    why.join("; ")
                ),
            );
        }
        let others = if others.is_empty() {
            String::new()
        } else {
            format!(" ({answered} answered; {})", others.join("; "))
        };
        let what = if trips.unanswered == 0 {
            "round trips"
        } else {
            "occurrences"
        };
        let bound = ms(nanos(self.below.0));
        match trips.at_percentile(p) {
            Some(AtRank::RoundTrip { rtt_ns }) if rtt_ns < nanos(self.below.0) => Judgement::pass(
                end,
                format!("p{p} of {n} {what} {} < {bound}{others}", ms(rtt_ns)),
            ),
            Some(AtRank::RoundTrip { rtt_ns }) => Judgement::fail(
                end,
                format!(
                    "p{p} of {n} {what} {}, not below {bound}{others}",
                    ms(rtt_ns)
                ),
            ),
            // `answered >= min >= 1`, so there is an occurrence at every rank.
            Some(AtRank::Unanswered) | None => Judgement::fail(
                end,
                format!("p{p} of {n} {what} falls on an unanswered one, not below {bound}{others}"),
            ),
        }
    }
}

/// A `latency` expectation judged as the run goes, from the command's events.
struct LatencyWatch {
    expect: LatencyExpect,
    trips: RoundTrips,
    /// Occurrences sent (`Command` events).
    sent: u64,
    /// Of those, the ones decided (a reply or a timeout).
    decided: u64,
}

impl Watch for LatencyWatch {
    fn kinds(&self) -> Kinds {
        Kinds::of(&[EventKind::Command, EventKind::CommandResult])
    }

    fn observe(&mut self, ev: &RunEvent) {
        match ev {
            RunEvent::Command { name, .. } if *name == self.expect.command => self.sent += 1,
            RunEvent::CommandResult(r) if r.name == self.expect.command => {
                match (&r.rtt_ns, &r.failed) {
                    // Never sent: no `Command` came before it.
                    (_, Some(_)) => self.trips.unanswered += 1,
                    (Some(rtt_ns), None) => {
                        self.trips.answered_ns.push(*rtt_ns);
                        self.decided += 1;
                    }
                    (None, None) => {
                        self.trips.unanswered += 1;
                        self.decided += 1;
                    }
                }
            }
            _ => {}
        }
    }

    fn judge(&self, cx: &CheckCx<'_>) -> Judgement {
        let mut trips = self.trips.clone();
        trips.unfinished = self.sent.saturating_sub(self.decided);
        self.expect.judge(trips, cx.report.sim_time)
    }
}

#[cfg(test)]
mod tests;

// What a snapshot saves (docs/snapshots.md): the round trips so far.
snap::fields!(RoundTrips {
    answered_ns,
    unanswered,
    unfinished
});
snap::fields!(LatencyWatch {
    trips,
    sent,
    decided;
    skip expect
});
