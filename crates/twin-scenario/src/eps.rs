//! `[eps]`: the EPS's state of charge, channels and events as a scenario writes them
//! (docs/scenarios.md, "The EPS").

use schemars::JsonSchema;
use serde::Deserialize;

use crate::dur::Dur;

/// The EPS (`[eps]`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct EpsSpec {
    /// State of charge at the start, 0-1 (default 0.8).
    #[serde(default)]
    pub initial_soc: Option<f64>,
    /// Channels off at the start (`COMM1`, `COMM2`, `ECU`, `PC`, `PL12`-`PL15`, `SBAND`).
    #[serde(default)]
    pub channels_off: Vec<String>,
    /// Events (`[[eps.events]]`): `at` with `channel` and `on`, or `soc`.
    #[serde(default)]
    pub events: Vec<EpsEventSpec>,
}

/// An EPS event at a time: switch a channel (as the CHSET command would) or set the state
/// of charge.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct EpsEventSpec {
    /// When.
    pub at: Dur,
    /// The channel to switch.
    #[serde(default)]
    pub channel: Option<String>,
    /// On or off (with `channel`).
    #[serde(default)]
    pub on: Option<bool>,
    /// Set the state of charge, 0-1.
    #[serde(default)]
    pub soc: Option<f64>,
}
