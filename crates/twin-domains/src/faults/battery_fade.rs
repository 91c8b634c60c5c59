//! `battery-fade`: the battery loses a fraction of its capacity at `at`, for good (cells
//! aged or a string lost). The EPS applies it from its own timeline: the state of charge is
//! kept at that instant, and from then on the battery fills and empties that much sooner,
//! so eclipses take it lower and the protection sheds sooner.

use nodes_eps::{EpsEvent, TimedEpsEvent};
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};

/// `battery-fade`: `target` is the EPS.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BatteryFade {
    /// The fraction of the capacity lost, above 0 and below 1.
    pub fraction: f64,
}

impl FaultKind for BatteryFade {
    const NAME: &'static str = "battery-fade";
    const LABEL: &'static str = "BatteryFade";
    const ABOUT: &'static str = "the battery loses a fraction of its capacity, for good";
    const LIVE: bool = false;
    const LASTS: bool = false;

    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if cx.node().ok() != Some(twin_core::network::EPS) {
            err(
                "target",
                format!("the battery belongs to the EPS, not `{}`", cx.common.target),
            );
        }
        if !(self.fraction > 0.0 && self.fraction < 1.0) {
            err("fraction", format!("{} is not in (0, 1)", self.fraction));
        }
    }

    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        plan.opts.eps.timeline.push(TimedEpsEvent {
            at: cx.at(),
            event: EpsEvent::BatteryFade(self.fraction),
        });
        plan.at(cx.at(), FaultAction::Record, "");
    }
}
