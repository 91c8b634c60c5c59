//! `[rules]`: what the platform lets a payload ask of it, and how the platform's time is
//! distributed, as a scenario writes it (the twin's `rules` module says what each means).

use schemars::JsonSchema;
use serde::Deserialize;

use crate::dur::Dur;
use twin_core::network::NodeRef;

/// The `[rules]` table.
#[derive(Debug, Clone, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RulesSpec {
    /// What payloads may ask of the FC and the PC.
    #[serde(default)]
    pub payload_access: AccessKind,
    /// Nodes whose CSP clock follows the FC's RTC (default: the PC).
    #[serde(default)]
    pub time_sync_to: Option<Vec<NodeRef>>,
    /// How often the FC sends its RTC (default 60 s; 0: at boot and after RTCSTMSET only).
    #[serde(default)]
    pub time_sync_period: Option<Dur>,
}

/// `payload_access`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum AccessKind {
    /// ICD 4.1's starred FC commands and the PC's STATUS only.
    #[default]
    Icd,
    /// Every command (a lab bench).
    Open,
}
