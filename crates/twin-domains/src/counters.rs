//! The `counter` expectation: a node's or a medium's counter at the end of the run.

use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Grade, Judgement, bounds};
use twin_report::RunReport;
use twin_scenario::scenario::NodeRef;

/// Node counters an expectation can name.
pub const NODE_COUNTERS: &[&str] = &[
    "rx_packets",
    "tx_packets",
    "forwarded",
    "delivered",
    "service_replies",
    "reboots",
    "platform_requests",
    "platform_refused",
    "drops",
];
/// Medium counters an expectation can name.
pub const MEDIUM_COUNTERS: &[&str] = &[
    "frames",
    "packets",
    "bytes",
    "dropped",
    "corrupted",
    "error_frames",
    "bus_off",
    "no_contact",
];

/// Where a counter lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CounterTarget {
    /// A node.
    Node(u8),
    /// A medium.
    Medium(String),
}

/// `counter`: a counter of a node or a medium at the end of the run is within
/// `min`..=`max`.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CounterExpect {
    /// The node (name or address), or a medium: `main`, `payload`, `ground`.
    pub target: NodeRef,
    /// Node: `rx_packets`, `tx_packets`, `forwarded`, `delivered`, `service_replies`,
    /// `reboots`, `platform_requests`, `platform_refused` (the platform port: parameters and
    /// self-test), `drops`, `drops.<reason>`; medium: `frames`, `packets`, `bytes`,
    /// `dropped`, `corrupted`, CAN `error_frames` and `bus_off` (ground also `no_contact`).
    pub counter: String,
    /// Smallest acceptable value.
    #[serde(default)]
    pub min: Option<u64>,
    /// Largest acceptable value.
    #[serde(default)]
    pub max: Option<u64>,
}

fn is_medium(r: &NodeRef) -> bool {
    matches!(r, NodeRef::Name(n) if ["main", "payload", "ground"].contains(&n.as_str()))
}

impl ExpectKind for CounterExpect {
    const NAME: &'static str = "counter";
    const ABOUT: &'static str = "a counter is within `min`..=`max` at the end of the run";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        let c = &self.counter;
        if is_medium(&self.target) {
            if !MEDIUM_COUNTERS.contains(&c.as_str()) {
                err(
                    "counter",
                    format!(
                        "unknown medium counter `{c}` ({})",
                        MEDIUM_COUNTERS.join(", ")
                    ),
                );
            }
        } else {
            if let Err(e) = cx.net.resolve(&self.target) {
                err("target", e.to_string());
            }
            match c.strip_prefix("drops.") {
                Some(reason) if csp::drop::DropReason::from_name(reason).is_none() => {
                    let reasons: Vec<&str> = csp::drop::DropReason::ALL
                        .iter()
                        .map(|r| r.name())
                        .collect();
                    err(
                        "counter",
                        format!(
                            "unknown drop reason `{reason}` (reasons: {})",
                            reasons.join(", ")
                        ),
                    );
                }
                Some(_) => {}
                None if !NODE_COUNTERS.contains(&c.as_str()) => err(
                    "counter",
                    format!(
                        "unknown node counter `{c}` ({}, drops.<reason>)",
                        NODE_COUNTERS.join(", ")
                    ),
                ),
                None => {}
            }
        }
        if self.min.is_none() && self.max.is_none() {
            err(
                "kind",
                "a `counter` expectation needs `min` or `max`".into(),
            );
        }
        if let (Some(a), Some(b)) = (self.min, self.max)
            && a > b
        {
            err("min", format!("min {a} is above max {b}"));
        }
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let target = match &self.target {
            NodeRef::Name(n) if is_medium(&self.target) => CounterTarget::Medium(n.clone()),
            r => CounterTarget::Node(cx.net.resolve(r).unwrap_or(0)),
        };
        let counter = &self.counter;
        let t = cx.report.sim_time;
        match counter_value(cx.report, &target, counter) {
            None => Judgement::fail(t, format!("counter `{counter}` not found on {target:?}")),
            Some(v) => {
                let low = self.min.is_some_and(|m| v < m);
                let high = self.max.is_some_and(|m| v > m);
                Judgement::new(
                    Grade::of(!(low || high)),
                    t,
                    format!("{counter} = {v} (expected {})", bounds(self.min, self.max)),
                )
            }
        }
    }

    fn describe(&self) -> String {
        format!("{} {}", self.target, self.counter)
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
                "platform_requests" => c.platform_requests,
                "platform_refused" => c.platform_refused,
                "drops" => c.total_drops(),
                other => {
                    let reason = csp::drop::DropReason::from_name(other.strip_prefix("drops.")?)?;
                    c.drops.get(&reason).copied().unwrap_or(0)
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
                "error_frames" => Some(b.error_frames),
                "bus_off" => Some(b.bus_off),
                _ => None,
            }
        }
    }
}
