//! The CAN buses in a scenario: the `can` expectation on a controller's error history
//! (how often it went error-passive or bus-off, and the state it ended the run in), read
//! from the buses' counters at the end of the run (docs/platform.md, "CAN errors").

use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Judgement, bounds};
use twin_scenario::scenario::NodeRef;

/// A controller's fault confinement state, by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum CanStateName {
    /// TEC and REC at most 127.
    ErrorActive,
    /// TEC or REC above 127.
    ErrorPassive,
    /// TEC above 255: off the bus.
    BusOff,
}

impl CanStateName {
    fn state(self) -> bus::can::ErrorState {
        match self {
            CanStateName::ErrorActive => bus::can::ErrorState::Active,
            CanStateName::ErrorPassive => bus::can::ErrorState::Passive,
            CanStateName::BusOff => bus::can::ErrorState::BusOff,
        }
    }
}

/// `can`: a node's CAN controller on `bus` went `state` (`error-passive` or `bus-off`)
/// `min`..=`max` times over the run, and ended it in `end_state`, if given.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CanExpect {
    /// The bus: `main` or `payload`.
    pub bus: String,
    /// The node whose controller is judged.
    pub node: NodeRef,
    /// The state whose entries are counted: `error-passive` or `bus-off` (default).
    #[serde(default)]
    pub state: Option<CanStateName>,
    /// Fewest entries.
    #[serde(default)]
    pub min: Option<u64>,
    /// Most entries.
    #[serde(default)]
    pub max: Option<u64>,
    /// The state it must be in at the end of the run.
    #[serde(default)]
    pub end_state: Option<CanStateName>,
}

impl ExpectKind for CanExpect {
    const NAME: &'static str = "can";
    const ABOUT: &'static str =
        "a CAN controller went error-passive or bus-off `min`..`max` times, and ended in a state";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if !["main", "payload"].contains(&self.bus.as_str()) {
            err(
                "bus",
                format!("`{}` is not a CAN bus (main, payload)", self.bus),
            );
        }
        if let Err(e) = cx.net.resolve(&self.node) {
            err("node", e.to_string());
        }
        if self.state == Some(CanStateName::ErrorActive) {
            err(
                "state",
                "count `error-passive` or `bus-off` entries (error-active is where they end)"
                    .into(),
            );
        }
        if self.min.is_none() && self.max.is_none() && self.end_state.is_none() {
            err(
                "kind",
                "a `can` expectation needs `min`, `max` or `end_state`".into(),
            );
        }
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let end = cx.report.sim_time;
        let name = cx
            .net
            .resolve(&self.node)
            .ok()
            .and_then(|a| cx.net.nodes.iter().find(|n| n.addr == a))
            .map(|n| n.name.clone())
            .unwrap_or_default();
        let Some(p) = cx
            .report
            .buses
            .iter()
            .find(|b| b.name == self.bus)
            .and_then(|b| b.ports.iter().find(|p| p.name == name))
        else {
            return Judgement::fail(end, format!("{name} is not on the {} bus", self.bus));
        };
        let state = self.state.unwrap_or(CanStateName::BusOff);
        let n = match state {
            CanStateName::ErrorPassive => p.passive_count,
            _ => p.bus_off_count,
        };
        let seen = format!(
            "{name} on {}: {} error frames, TEC up to {}, error-passive {}x, bus-off {}x, {} at the end",
            self.bus,
            p.tx_errors,
            p.tec_max,
            p.passive_count,
            p.bus_off_count,
            p.state.name()
        );
        let mut why = Vec::new();
        if self.min.is_some_and(|m| n < m) || self.max.is_some_and(|m| n > m) {
            why.push(format!(
                "{} entries expected {}",
                state.state().name(),
                bounds(self.min, self.max)
            ));
        }
        if let Some(s) = self.end_state
            && s.state() != p.state
        {
            why.push(format!("expected {} at the end", s.state().name()));
        }
        if why.is_empty() {
            Judgement::pass(end, seen)
        } else {
            Judgement::fail(end, format!("{seen} ({})", why.join("; ")))
        }
    }

    fn describe(&self) -> String {
        // What it counts: entries into a state, or only the state at the end.
        let what = match (self.min.or(self.max), self.end_state) {
            (None, Some(s)) => format!("{} at the end", s.state().name()),
            _ => format!(
                "{} entries",
                self.state.unwrap_or(CanStateName::BusOff).state().name()
            ),
        };
        format!("{} {what} on the {} bus", self.node, self.bus)
    }
}
