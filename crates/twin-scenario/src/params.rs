//! `[nodes.NAME] params`: a platform parameter's value as a scenario writes it.

use schemars::JsonSchema;
use serde::Deserialize;

/// A parameter's value in a scenario: `true`/`false`, or a number.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum ParamValue {
    /// A bool parameter's value.
    Bool(bool),
    /// An integer.
    Int(i64),
    /// A number.
    Float(f64),
}
