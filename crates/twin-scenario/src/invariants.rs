//! `[invariants]`: the invariants by name and their settings as a scenario writes them
//! (the twin's `invariants` module checks them).

use schemars::JsonSchema;
use serde::Deserialize;

use crate::dur::Dur;

/// An invariant, by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum InvariantName {
    /// The true position, velocity and body rate are finite.
    FiniteState,
    /// Every CAN frame offered was sent, lost for a counted reason, or is queued.
    FramesAccounted,
    /// Every platform reply has the length the ICD's table gives.
    IcdReplyLength,
    /// No two addresses exchange more than a bounded number of packets a second.
    NoReplyStorm,
    /// At most one PC session is ACTIVE at any time.
    OneActiveSession,
    /// The PC's byte accounting balances.
    PcBalanced,
    /// No node hands its CAN controller a frame while it is off.
    SilentWhileOff,
    /// The battery's state of charge stays within [0, 1].
    SocRange,
    /// The true and estimated attitudes are unit quaternions.
    UnitQuaternion,
}

impl InvariantName {
    /// Every invariant, in name order.
    pub const ALL: [InvariantName; 9] = [
        InvariantName::FiniteState,
        InvariantName::FramesAccounted,
        InvariantName::IcdReplyLength,
        InvariantName::NoReplyStorm,
        InvariantName::OneActiveSession,
        InvariantName::PcBalanced,
        InvariantName::SilentWhileOff,
        InvariantName::SocRange,
        InvariantName::UnitQuaternion,
    ];
    /// Its name (`one-active-session`).
    pub fn as_str(self) -> &'static str {
        match self {
            InvariantName::FiniteState => "finite-state",
            InvariantName::FramesAccounted => "frames-accounted",
            InvariantName::IcdReplyLength => "icd-reply-length",
            InvariantName::NoReplyStorm => "no-reply-storm",
            InvariantName::OneActiveSession => "one-active-session",
            InvariantName::PcBalanced => "pc-balanced",
            InvariantName::SilentWhileOff => "silent-while-off",
            InvariantName::SocRange => "soc-range",
            InvariantName::UnitQuaternion => "unit-quaternion",
        }
    }
}

impl std::fmt::Display for InvariantName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Which invariants a run checks: `"all"`, or a list of names.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum InvariantCheck {
    /// `"all"`.
    All(AllWord),
    /// These.
    Names(Vec<InvariantName>),
}

/// The word `all`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum AllWord {
    /// `all`.
    All,
}

/// The scenario's `[invariants]` table: which invariants `run`, `test` and a campaign
/// check, and the settings of those that have some.
#[derive(Debug, Clone, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct InvariantsSpec {
    /// The invariants checked: `"all"` or names (default none; a campaign checks all, and
    /// writes `check = "all"` into the scenario of each of its runs).
    #[serde(default)]
    pub check: Option<InvariantCheck>,
    /// `no-reply-storm`'s bound.
    #[serde(default)]
    pub no_reply_storm: Option<ReplyStormSpec>,
}

/// `[invariants.no_reply_storm]`.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ReplyStormSpec {
    /// The most packets a second two addresses may send each other, each way, on one medium
    /// (default 200).
    #[serde(default)]
    pub packets_per_s: Option<u32>,
    /// The windows they are counted over (default 10 s; 1 s to 1 h).
    #[serde(default)]
    pub window: Option<Dur>,
}

snap::unit_enum!(InvariantName {
    FiniteState,
    FramesAccounted,
    IcdReplyLength,
    NoReplyStorm,
    OneActiveSession,
    PcBalanced,
    SilentWhileOff,
    SocRange,
    UnitQuaternion
});
