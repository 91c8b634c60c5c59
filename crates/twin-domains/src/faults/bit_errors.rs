//! `bit-errors`: a CAN bus suffers bit errors at a rate over a window, on every
//! transmitter's frames or on one node's (its transceiver is failing). Each hit frame is an
//! error frame and a retransmission, and the error counters move as ISO 11898-1 says:
//! a node whose frames fail often enough goes error-passive, then bus-off, and recovers
//! (docs/platform.md, "CAN errors").

use bus::can::CanFault;
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};
use twin_scenario::scenario::NodeRef;

/// `bit-errors`: `target` is the bus (`main` or `payload`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BitErrors {
    /// Bit error rate: the chance that a bit on the wire is wrong, above 0 and at most 1
    /// (1e-3 hits about 12 % of 130-bit frames; above about 1e-3 a busy transmitter's TEC
    /// climbs to bus-off).
    pub ber: f64,
    /// Only the frames this node transmits; default every transmitter's.
    #[serde(default)]
    pub node: Option<NodeRef>,
}

impl FaultKind for BitErrors {
    const NAME: &'static str = "bit-errors";
    const LABEL: &'static str = "BitErrors";
    const ABOUT: &'static str = "bit errors at a rate on a CAN bus (or on one node's frames)";

    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        let bus = cx.medium().filter(|m| m.is_can());
        if bus.is_none() {
            err(
                "target",
                format!("`{}` is not a CAN bus (main, payload)", cx.common.target),
            );
        }
        if !(self.ber > 0.0 && self.ber <= 1.0) {
            err("ber", format!("{} is not in (0, 1]", self.ber));
        }
        if let Some(n) = &self.node {
            match cx.net.resolve(n) {
                Err(e) => err("node", e.to_string()),
                Ok(a) if bus.is_some_and(|b| !cx.on_bus(a, b)) => err(
                    "node",
                    format!("{n} is not on the `{}` bus", cx.common.target),
                ),
                Ok(_) => {}
            }
        }
    }

    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let Some(medium) = cx.medium() else { return };
        let node = self.node.as_ref().and_then(|n| cx.node_name(n));
        let can = CanFault::BitErrors {
            ber: self.ber,
            node,
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
