//! The EPS in a scenario: the `[eps]` table (state of charge, channels, events), its
//! validation and compilation into the EPS's configuration, the power samples a run
//! publishes, and the `power` expectation.
//!
//! See docs/scenarios.md ("The EPS") and docs/platform.md.

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{
    CheckCx, ExpectCx, ExpectKind, Extremes, Judgement, Watch, WatchCx, When,
};
use twin_core::events::RunEvent;
use twin_scenario::scenario::{Dur, PathStep, Scenario};

fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

pub use twin_scenario::eps::*;

/// Check the `[eps]` table.
pub fn validate(s: &Scenario, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let e = &s.eps;
    if e.initial_soc
        .is_some_and(|x| !(x.is_finite() && (0.0..=1.0).contains(&x)))
    {
        err(vec![key("eps"), key("initial_soc")], "must be 0-1".into());
    }
    let channel_names = "COMM1, COMM2, ECU, PC, PL12, PL13, PL14, PL15, SBAND";
    for (i, c) in e.channels_off.iter().enumerate() {
        if nodes_eps::Channel::from_name(c).is_none() {
            err(
                vec![key("eps"), key("channels_off"), PathStep::Index(i)],
                format!("unknown channel `{c}` ({channel_names})"),
            );
        }
    }
    for (i, ev) in e.events.iter().enumerate() {
        let q = |n: &str| vec![key("eps"), key("events"), PathStep::Index(i), key(n)];
        match (&ev.channel, ev.on, ev.soc) {
            (Some(c), Some(_), None) => {
                if nodes_eps::Channel::from_name(c).is_none() {
                    err(
                        q("channel"),
                        format!("unknown channel `{c}` ({channel_names})"),
                    );
                }
            }
            (None, None, Some(x)) => {
                if !(x.is_finite() && (0.0..=1.0).contains(&x)) {
                    err(q("soc"), "must be 0-1".into());
                }
            }
            _ => err(
                q("at"),
                "an EPS event is `channel` with `on`, or `soc`".into(),
            ),
        }
    }
}

/// The EPS's configuration from the `[eps]` table (validated).
pub fn compile(s: &Scenario) -> nodes_eps::EpsConfig {
    use nodes_eps::{Channel, EpsEvent, TimedEpsEvent};
    let mut c = nodes_eps::EpsConfig::default();
    let e = &s.eps;
    // A payload the network does not have draws nothing, unless a program outside the twin
    // is powered by its channel: its channel starts off.
    for addr in 12..=15u8 {
        if let Some(ch) = Channel::of_node(addr)
            && !s.network.payloads.contains(&addr)
            && !s
                .links
                .iter()
                .any(|l| l.powered_by.as_deref().and_then(Channel::from_name) == Some(ch))
        {
            c.channels_on &= !ch.bit();
        }
    }
    if let Some(x) = e.initial_soc {
        c.initial_soc = x;
    }
    for name in &e.channels_off {
        if let Some(ch) = Channel::from_name(name) {
            c.channels_on &= !ch.bit();
        }
    }
    for ev in &e.events {
        let event = match (&ev.channel, ev.on, ev.soc) {
            (Some(name), Some(on), _) => match Channel::from_name(name) {
                Some(channel) => EpsEvent::Channel { channel, on },
                None => continue,
            },
            (_, _, Some(x)) => EpsEvent::SetSoc(x),
            _ => continue,
        };
        c.timeline.push(TimedEpsEvent {
            at: SimTime::ZERO + ev.at.0,
            event,
        });
    }
    c.timeline.sort_by_key(|e| e.at);
    c
}

pub use twin_report::observe::power::*;

/// Which figure of a window a `power` expectation bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Statistic {
    /// Every sample.
    Every,
    /// The time mean over the window.
    Mean,
    /// The smallest sample.
    Min,
    /// The largest sample.
    Max,
}

/// The figures a `power` expectation can check (each EPS sample).
pub const POWER_QUANTITIES: &[&str] = &[
    "soc",
    "battery_v",
    "battery_a",
    "solar_w",
    "load_w",
    "net_w",
];

/// `power`: EPS samples in a window (each, or their mean, min or max) below / above a
/// bound.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PowerExpect {
    /// The figure checked (see [`POWER_QUANTITIES`]).
    pub quantity: String,
    /// What `below`/`above` bound: `every` sample (default), or the window's `mean`, `min`
    /// or `max`.
    #[serde(default)]
    pub statistic: Option<Statistic>,
    /// Upper bound (exclusive).
    #[serde(default)]
    pub below: Option<f64>,
    /// Lower bound (exclusive).
    #[serde(default)]
    pub above: Option<f64>,
    /// Start of the window (default: the start of the run).
    #[serde(default)]
    pub from: Option<Dur>,
    /// End of the window (default: the end of the run).
    #[serde(default)]
    pub to: Option<Dur>,
    /// Which samples count: `always` (default), `sunlit` (array power above zero) or
    /// `eclipse` (none).
    #[serde(default)]
    pub when: Option<When>,
}

impl ExpectKind for PowerExpect {
    const NAME: &'static str = "power";
    const ABOUT: &'static str =
        "EPS samples in a window (each, or their mean, min or max) below / above a bound";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if !POWER_QUANTITIES.contains(&self.quantity.as_str()) {
            err(
                "quantity",
                format!(
                    "unknown quantity `{}` ({})",
                    self.quantity,
                    POWER_QUANTITIES.join(", ")
                ),
            );
        }
        if self.below.is_none() && self.above.is_none() {
            err(
                "kind",
                "a `power` expectation needs `below` or `above`".into(),
            );
        }
        if self.when == Some(When::TargetVisible) {
            err(
                "when",
                "a `power` expectation takes `always`, `sunlit` or `eclipse`".into(),
            );
        }
        cx.window(self.from, self.to, err);
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let mut tally = PowerTally::default();
        for s in &cx.report.power {
            self.tally(&mut tally, s);
        }
        self.judge(&tally, cx.report.sim_time)
    }

    fn watch(&self, _cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        Some(Box::new(PowerWatch {
            expect: self.clone(),
            tally: PowerTally::default(),
        }))
    }

    fn describe(&self) -> String {
        format!("power {}", self.quantity)
    }
}

/// A `power` expectation's figures over the samples it selected so far, in time order.
#[derive(Debug, Clone)]
struct PowerTally {
    n: usize,
    range: Extremes,
    sum: f64,
    /// The first sample out of bounds: when, and its value.
    first_bad: Option<(SimTime, f64)>,
}

impl Default for PowerTally {
    fn default() -> Self {
        PowerTally {
            n: 0,
            range: Extremes::default(),
            // As `Iterator::sum` of f64 starts.
            sum: -0.0,
            first_bad: None,
        }
    }
}

/// A `power` expectation judged as the run goes: its samples are not kept.
#[derive(Debug)]
struct PowerWatch {
    expect: PowerExpect,
    tally: PowerTally,
}

impl Watch for PowerWatch {
    fn kinds(&self) -> twin_core::events::Kinds {
        twin_core::events::Kinds::of(&[twin_core::events::EventKind::Eps])
    }

    fn observe(&mut self, ev: &RunEvent) {
        if let Some(s) = PowerSample::of(ev) {
            self.expect.tally(&mut self.tally, &s);
        }
    }

    fn judge(&self, cx: &CheckCx<'_>) -> Judgement {
        self.expect.judge(&self.tally, cx.report.sim_time)
    }
}

impl PowerExpect {
    fn value(&self, s: &PowerSample) -> f64 {
        match self.quantity.as_str() {
            "soc" => s.soc,
            "battery_v" => s.battery_v,
            "battery_a" => s.battery_a,
            "solar_w" => s.solar_w,
            "load_w" => s.load_w,
            _ => s.solar_w - s.load_w,
        }
    }

    fn ok(&self, v: f64) -> bool {
        self.below.is_none_or(|b| v < b) && self.above.is_none_or(|a| v > a)
    }

    /// Take in the next sample, if the window (`from` to `to`; without `to`, to the end
    /// of the run, after which no sample comes) and `when` select it.
    fn tally(&self, k: &mut PowerTally, s: &PowerSample) {
        let from = self.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0);
        let selected = s.t >= from
            && self.to.is_none_or(|d| s.t <= SimTime::ZERO + d.0)
            && match self.when.unwrap_or(When::Always) {
                When::Sunlit => s.solar_w > 0.0,
                When::Eclipse => s.solar_w <= 0.0,
                _ => true,
            };
        if !selected {
            return;
        }
        let v = self.value(s);
        k.n += 1;
        k.range.add(v);
        k.sum += v;
        if k.first_bad.is_none() && !self.ok(v) {
            k.first_bad = Some((s.t, v));
        }
    }

    /// The verdict on the samples taken in, the run having ended at `end`.
    fn judge(&self, k: &PowerTally, end: SimTime) -> Judgement {
        let (statistic, when) = (
            self.statistic.unwrap_or(Statistic::Every),
            self.when.unwrap_or(When::Always),
        );
        let (below, above) = (self.below, self.above);
        let from = self.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0);
        let to = self.to.map_or(end, |d| SimTime::ZERO + d.0);
        let quantity = &self.quantity;
        if k.n == 0 {
            return Judgement::fail(
                to,
                format!("no EPS sample ({when:?}) between {from} and {to} (is the EPS running?)"),
            );
        }
        let ok = |v: f64| self.ok(v);
        let (lo, hi, n) = (k.range.lo, k.range.hi, k.n);
        let mean = k.sum / n as f64;
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
            Statistic::Every => match k.first_bad {
                Some((t, v)) => Judgement::fail(
                    t,
                    format!("{range}; first at {t}: {quantity} = {v:.4} (expected {bounds})"),
                ),
                None => Judgement::pass(to, range),
            },
            Statistic::Mean | Statistic::Min | Statistic::Max => {
                let (name, v) = match statistic {
                    Statistic::Mean => ("mean", mean),
                    Statistic::Min => ("min", lo),
                    _ => ("max", hi),
                };
                if ok(v) {
                    Judgement::pass(to, range)
                } else {
                    Judgement::fail(to, format!("{range} ({name} {v:.4}, expected {bounds})"))
                }
            }
        }
    }
}

// What a snapshot saves (docs/snapshots.md): the tally so far.
snap::fields!(PowerTally {
    n,
    range,
    sum,
    first_bad
});
snap::fields!(PowerWatch {
    tally;
    skip expect
});
