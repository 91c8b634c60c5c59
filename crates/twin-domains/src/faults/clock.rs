//! `clock`: a node's clock jumps and/or drifts from `at`, until `until` (the clock is
//! corrected). What runs on that clock follows: the FC's RTC (its scripts start and stop
//! early or late, TMGEN and RTCSTMGET report it), the PC's session start times (ICD 3.1:
//! SETUP's timestamps are the PC's clock), COMM's beacon times, and the CMP clock.

use csp::node::NodeFault;
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};

/// `clock`: `target` is a node.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Clock {
    /// The step the clock takes at `at`, s (positive: ahead of true time); default 0.
    #[serde(default)]
    pub jump_s: Option<f64>,
    /// How fast it runs wrong from `at`, parts per million (positive: it gains); default 0.
    #[serde(default)]
    pub drift_ppm: Option<f64>,
}

impl FaultKind for Clock {
    const NAME: &'static str = "clock";
    const LABEL: &'static str = "Clock";
    const ABOUT: &'static str = "a node's clock jumps and/or drifts until corrected";

    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if let Err(e) = cx.node() {
            err("target", e.to_string());
        }
        if self.jump_s.is_none() && self.drift_ppm.is_none() {
            err(
                "kind",
                "a `clock` fault needs `jump_s` or `drift_ppm`".into(),
            );
        }
        if self
            .jump_s
            .is_some_and(|j| !(j.is_finite() && j.abs() <= 1e9))
        {
            err("jump_s", "must be finite, at most 1e9 s either way".into());
        }
        if self
            .drift_ppm
            .is_some_and(|d| !(d.is_finite() && d.abs() <= 1e6))
        {
            err("drift_ppm", "must be finite, at most 1e6 either way".into());
        }
    }

    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let Ok(addr) = cx.node() else { return };
        let what = NodeFault::Clock {
            jump_ns: (self.jump_s.unwrap_or(0.0) * 1e9).round() as i64,
            drift_ppm: self.drift_ppm.unwrap_or(0.0),
        };
        let fault = cx.id();
        plan.window(cx, " (corrected)", |on| FaultAction::Node {
            addr,
            fault,
            what: on.then(|| what.clone()),
        });
    }
}
