//! Faults of a node (`target` = a node's name or address): its power, a reboot, a hang.
//! Power and hang faults go through the platform's power rules (`platform::power`): a node
//! is powered exactly while its EPS channel is on and no power fault holds it off, and
//! overlapping faults compose.

use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};

fn node_target(cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
    if let Err(e) = cx.node() {
        err("target", e.to_string());
    }
}

/// `power-off`: the node loses power at `at` (its core meets the loss at that instant) and
/// is powered again at `until` if its EPS channel is on. On an outside link (`target` = its
/// `name`, or the node whose address a link of the scenario holds), the program behind it
/// loses power: the twin forwards nothing to or from it until `until` (and while the
/// channel it is `powered_by`, if any, is off).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PowerOff {}

impl FaultKind for PowerOff {
    const NAME: &'static str = "power-off";
    const LABEL: &'static str = "PowerOff";
    const ABOUT: &'static str =
        "the node is powered off (back on at `until` if its EPS channel is on)";
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if cx.link().or_else(|| cx.link_holding_target()).is_none() {
            node_target(cx, err);
        }
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let fault = cx.id();
        // A link named, or the program a link puts at the node's address: the twin
        // forwards nothing to or from it while the fault holds its power off.
        if let Some(link) = cx.link().or_else(|| cx.link_holding_target()) {
            plan.window(cx, " (power on)", |off| FaultAction::LinkPower {
                link,
                fault,
                off,
            });
            return;
        }
        let Ok(addr) = cx.node() else { return };
        plan.window(cx, " (power on)", |off| FaultAction::Power {
            addr,
            fault,
            off,
        });
    }
}

/// `reboot`: the node reboots at `at` (uptime from zero, volatile state lost).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Reboot {}

impl FaultKind for Reboot {
    const NAME: &'static str = "reboot";
    const LABEL: &'static str = "Reboot";
    const ABOUT: &'static str = "the node reboots";
    const LASTS: bool = false;
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        node_target(cx, err);
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        if let Ok(addr) = cx.node() {
            plan.at(cx.at(), FaultAction::Reboot(addr), "");
        }
    }
}

/// `hang`: the node stays on its buses (frames are acknowledged) but does nothing until
/// `until` or a power cycle. On an outside link (`target` = its `name`), the twin forwards
/// nothing to or from the program behind it, until `until` or a power cycle of the channel
/// that powers it (`powered_by`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Hang {}

impl FaultKind for Hang {
    const NAME: &'static str = "hang";
    const LABEL: &'static str = "Hang";
    const ABOUT: &'static str =
        "the node is alive on the bus but silent (until `until` or a power cycle)";
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if cx.link().is_none() {
            node_target(cx, err);
        }
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let fault = cx.id();
        if let Some(link) = cx.link() {
            plan.window(cx, " (recovered)", |hung| FaultAction::LinkHang {
                link,
                fault,
                hung,
            });
            return;
        }
        let Ok(addr) = cx.node() else { return };
        plan.window(cx, " (recovered)", |hung| FaultAction::Hang {
            addr,
            fault,
            hung,
        });
    }
}
