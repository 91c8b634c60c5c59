//! Faults of a medium (`target` = `main`, `payload` or `uhf`): frames or packets lost,
//! corrupted or delayed, or the medium down. Each active fault is one part of the medium's
//! impairments (`bus::impair::ImpairmentSet`): they compose while they overlap, and lifting
//! one leaves the others. The chances are drawn from the medium's generator, seeded from the
//! run's seed.
//!
//! `drop`, `delay` and `link-down` also act on an outside link (`target` = the link's
//! `name`): the twin holds back what crosses it in either direction (`bus::gate`).

use bus::impair::Impairments;
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};
use twin_scenario::scenario::Dur;

/// The target must be a medium or an outside link.
fn medium_target(cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
    if cx.medium().is_none() {
        err(
            "target",
            format!(
                "`{}` is not a medium (main, payload, uhf) or a named link",
                cx.common.target
            ),
        );
    }
}

fn probability(p: f64, err: &mut dyn FnMut(&str, String)) {
    if !(0.0..=1.0).contains(&p) {
        err("probability", format!("{p} is not in 0..=1"));
    }
}

/// Impair the target medium with `imp` from `at` to `until`.
fn impair(cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>, imp: Impairments) {
    let Some(medium) = cx.medium() else { return };
    let fault = cx.id();
    plan.window(cx, " (lifted)", |on| FaultAction::Impair {
        medium,
        fault,
        imp: on.then_some(imp),
    });
}

/// `drop`: every frame or packet is lost with `probability`.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Drop {
    /// The chance that a frame or packet is lost, 0-1.
    pub probability: f64,
}

impl FaultKind for Drop {
    const NAME: &'static str = "drop";
    const LABEL: &'static str = "Drop";
    const ABOUT: &'static str = "lose frames or packets of a medium with a probability";
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        medium_target(cx, err);
        probability(self.probability, err);
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        impair(
            cx,
            plan,
            Impairments {
                drop_prob: self.probability,
                ..Default::default()
            },
        );
    }
}

/// `corrupt`: one bit of a frame's or packet's data is flipped with `probability`. On a CAN
/// bus the CRC-15 catches it: an error frame and a retransmission (`bus::can`); on the UHF
/// channel, which has no such check, the corrupted packet is delivered.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Corrupt {
    /// The chance that a frame or packet is corrupted, 0-1.
    pub probability: f64,
}

impl FaultKind for Corrupt {
    const NAME: &'static str = "corrupt";
    const LABEL: &'static str = "Corrupt";
    const ABOUT: &'static str = "flip one bit of frames or packets of a medium with a probability";
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if cx.link().is_some() {
            err(
                "target",
                format!(
                    "`{}` is an outside link: the twin does not corrupt what crosses one (drop, delay, link-down or hang do act on it)",
                    cx.common.target
                ),
            );
        } else {
            medium_target(cx, err);
        }
        probability(self.probability, err);
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        impair(
            cx,
            plan,
            Impairments {
                corrupt_prob: self.probability,
                ..Default::default()
            },
        );
    }
}

/// `delay`: every frame or packet arrives `delay` later.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Delay {
    /// The extra latency.
    pub delay: Dur,
}

impl FaultKind for Delay {
    const NAME: &'static str = "delay";
    const LABEL: &'static str = "Delay";
    const ABOUT: &'static str = "delay every frame or packet of a medium";
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        medium_target(cx, err);
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        impair(
            cx,
            plan,
            Impairments {
                delay: self.delay.0,
                ..Default::default()
            },
        );
    }
}

/// `link-down`: the medium carries nothing.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LinkDown {}

impl FaultKind for LinkDown {
    const NAME: &'static str = "link-down";
    const LABEL: &'static str = "LinkDown";
    const ABOUT: &'static str = "the medium carries nothing";
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        medium_target(cx, err);
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        impair(
            cx,
            plan,
            Impairments {
                down: true,
                ..Default::default()
            },
        );
    }
}
