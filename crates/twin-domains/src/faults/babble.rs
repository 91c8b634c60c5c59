//! `babble`: a babbling idiot. A node's CAN controller floods its bus with one frame, back
//! to back or at a period, from `at` to `until`. Its frames enter arbitration like any
//! other: every frame with a lower CAN id (a lower CFP source address first: libcsp 1.4's
//! CFP id begins with the source) still wins, every frame with a higher id waits for a gap
//! the babbler never leaves. With the default id 0 nothing else gets through.

use std::time::Duration;

use bus::can::CanFault;
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};
use twin_scenario::scenario::{Dur, NodeRef};

/// `babble`: `target` is the bus (`main` or `payload`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Babble {
    /// The node whose controller babbles.
    pub node: NodeRef,
    /// Its frame's 29-bit CAN id (default 0: the highest priority, it wins every
    /// arbitration); the frame carries 8 zero bytes.
    #[serde(default)]
    pub can_id: Option<u32>,
    /// Time between the starts of two of its frames (default: back to back, as often as
    /// the bus allows).
    #[serde(default)]
    pub period: Option<Dur>,
}

impl FaultKind for Babble {
    const NAME: &'static str = "babble";
    const LABEL: &'static str = "Babble";
    const ABOUT: &'static str = "a node's CAN controller floods its bus with one frame";

    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        let bus = cx.medium().filter(|m| m.is_can());
        if bus.is_none() {
            err(
                "target",
                format!("`{}` is not a CAN bus (main, payload)", cx.common.target),
            );
        }
        match cx.net.resolve(&self.node) {
            Err(e) => err("node", e.to_string()),
            Ok(a) if bus.is_some_and(|b| !cx.on_bus(a, b)) => err(
                "node",
                format!("{} is not on the `{}` bus", self.node, cx.common.target),
            ),
            Ok(_) => {}
        }
        if let Some(id) = self.can_id
            && id >= 1 << 29
        {
            err("can_id", format!("{id:#x} is not a 29-bit CAN id"));
        }
        if self.period.is_some_and(|p| p.0.is_zero()) {
            err("period", "must be longer than zero".into());
        }
    }

    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let Some(medium) = cx.medium() else { return };
        let Some(node) = cx.node_name(&self.node) else {
            return;
        };
        let can = CanFault::Babble {
            node,
            can_id: self.can_id.unwrap_or(0),
            period: self.period.map(|p| p.0).filter(|p| *p > Duration::ZERO),
            from: cx.at(),
            until: cx.until(),
        };
        let fault = cx.id();
        plan.window(cx, " (lifted)", |on| FaultAction::Can {
            medium,
            fault,
            can: on.then(|| can.clone()),
        });
    }
}
