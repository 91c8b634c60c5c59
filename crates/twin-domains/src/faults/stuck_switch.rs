//! `stuck-switch`: an EPS channel whose switch ignores commands from `at` to `until` (a
//! failed driver, a latched control line). It stays in the state it has at `at`: CHSET
//! answers success with the channel states, which show it unchanged, and the scenario's
//! `[eps] events` on it do nothing; the protection's shedding and restoring still act on
//! it. The EPS applies it from its own timeline (`nodes_eps::EpsEvent::ChannelStuck`).

use nodes_eps::{Channel, EpsEvent, TimedEpsEvent};
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};

/// `stuck-switch`: `target` is the EPS.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StuckSwitch {
    /// The channel, by name: `COMM1`, `COMM2`, `ECU`, `PC`, `PL12`-`PL15`, `SBAND`.
    pub channel: String,
}

impl FaultKind for StuckSwitch {
    const NAME: &'static str = "stuck-switch";
    const LABEL: &'static str = "StuckSwitch";
    const ABOUT: &'static str =
        "an EPS channel ignores commands (CHSET, the scenario's channel events)";
    const LIVE: bool = false;

    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if cx.node().ok() != Some(twin_core::network::EPS) {
            err(
                "target",
                format!(
                    "a channel's switch belongs to the EPS, not `{}`",
                    cx.common.target
                ),
            );
        }
        if Channel::from_name(&self.channel).is_none() {
            let names: Vec<&str> = Channel::ALL.iter().map(|c| c.name()).collect();
            err(
                "channel",
                format!(
                    "no channel `{}` (channels: {})",
                    self.channel,
                    names.join(", ")
                ),
            );
        }
    }

    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let Some(channel) = Channel::from_name(&self.channel) else {
            return;
        };
        let timeline = &mut plan.opts.eps.timeline;
        timeline.push(TimedEpsEvent {
            at: cx.at(),
            event: EpsEvent::ChannelStuck(channel),
        });
        if let Some(u) = cx.until() {
            timeline.push(TimedEpsEvent {
                at: u,
                event: EpsEvent::ChannelFreed(channel),
            });
        }
        plan.window(cx, " (freed)", |_| FaultAction::Record);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    /// The problems of a scenario with the fault `f`, each as (field, message).
    fn problems(f: &str) -> Vec<(String, String)> {
        let text = format!(
            "name = \"t\"\nduration = \"1m\"\n[[faults]]\nkind = \"stuck-switch\"\nat = \"10s\"\n{f}"
        );
        match crate::validate::parse("t.toml", &text) {
            Ok(_) => Vec::new(),
            Err(e) => e.0.into_iter().map(|e| (e.field, e.message)).collect(),
        }
    }

    #[test]
    fn a_stuck_switch_is_a_channel_of_the_eps() {
        assert_eq!(
            problems("target = \"EPS\"\nchannel = \"pl12\"\nuntil = \"20s\"\n"),
            vec![]
        );
        assert_eq!(
            problems("target = \"FC\"\nchannel = \"PL12\"\n"),
            vec![(
                "faults[0].target".to_owned(),
                "a channel's switch belongs to the EPS, not `FC`".to_owned()
            )]
        );
        let p = problems("target = \"EPS\"\nchannel = \"PL16\"\n");
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].0, "faults[0].channel");
        assert!(
            p[0].1
                .starts_with("no channel `PL16` (channels: COMM1, COMM2"),
            "{p:?}"
        );
    }

    #[test]
    fn it_holds_the_channel_on_the_eps_timeline_from_at_to_until() {
        let text = "name = \"t\"\nduration = \"1m\"\n[[faults]]\nkind = \"stuck-switch\"\n\
                    target = \"EPS\"\nchannel = \"PL12\"\nat = \"10s\"\nuntil = \"20s\"\n";
        let c = crate::plan::compile(&crate::validate::parse("t.toml", text).unwrap());
        let stuck: Vec<_> = c
            .opts
            .eps
            .timeline
            .iter()
            .filter(|e| {
                matches!(
                    e.event,
                    nodes_eps::EpsEvent::ChannelStuck(_) | nodes_eps::EpsEvent::ChannelFreed(_)
                )
            })
            .map(|e| (e.at, e.event))
            .collect();
        let pl12 = nodes_eps::Channel::Payload12;
        assert_eq!(
            stuck,
            vec![
                (
                    csp::SimTime::from_secs(10),
                    nodes_eps::EpsEvent::ChannelStuck(pl12)
                ),
                (
                    csp::SimTime::from_secs(20),
                    nodes_eps::EpsEvent::ChannelFreed(pl12)
                ),
            ]
        );
    }
}
