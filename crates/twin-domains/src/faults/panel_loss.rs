//! `panel-loss`: a solar panel gives nothing from `at` to `until` (a failed string, a
//! broken harness, a wing that did not deploy). The EPS applies it from its own timeline:
//! the arrays' power, the battery's charge and, below the thresholds, the protection's
//! shedding follow.

use nodes_eps::{EpsEvent, TimedEpsEvent};
use schemars::JsonSchema;
use serde::Deserialize;

use super::{FaultAction, FaultCx, FaultKind, FaultPlan};

/// `panel-loss`: `target` is the EPS.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PanelLoss {
    /// The panel, by name (`+X`, `wing+Y`, `wing-Y`, `-X`, `+Y`, `-Y` on the default
    /// arrays).
    pub panel: String,
}

/// The index of panel `name` in the EPS's arrays.
fn panel_index(panels: &nodes_eps::SolarArray, name: &str) -> Option<usize> {
    panels
        .panels
        .iter()
        .position(|p| p.name.eq_ignore_ascii_case(name))
}

impl FaultKind for PanelLoss {
    const NAME: &'static str = "panel-loss";
    const LABEL: &'static str = "PanelLoss";
    const ABOUT: &'static str = "a solar panel gives nothing";
    const LIVE: bool = false;

    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if cx.node().ok() != Some(twin_core::network::EPS) {
            err(
                "target",
                format!("a panel belongs to the EPS, not `{}`", cx.common.target),
            );
        }
        let panels = nodes_eps::SolarArray::default();
        if panel_index(&panels, &self.panel).is_none() {
            let names: Vec<&str> = panels.panels.iter().map(|p| p.name.as_str()).collect();
            err(
                "panel",
                format!("no panel `{}` (panels: {})", self.panel, names.join(", ")),
            );
        }
    }

    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        let Some(i) = panel_index(&plan.opts.eps.panels, &self.panel) else {
            return;
        };
        let timeline = &mut plan.opts.eps.timeline;
        timeline.push(TimedEpsEvent {
            at: cx.at(),
            event: EpsEvent::PanelFail(i),
        });
        if let Some(u) = cx.until() {
            timeline.push(TimedEpsEvent {
                at: u,
                event: EpsEvent::PanelRestore(i),
            });
        }
        plan.window(cx, " (restored)", |_| FaultAction::Record);
    }
}
