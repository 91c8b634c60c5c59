//! `[[faults]]` and `[[expectations]]` entries as written: a kind and its fields, kept with
//! where each was written ([`Tagged`]). What the kinds are, their fields and their meaning is
//! the twin's (its fault and expectation registries, which also give the JSON schema each
//! kind's fields: here an entry's schema is only "an object with a `kind`").

use schemars::JsonSchema;
use serde::{Deserialize, Deserializer};
use twin_core::tagged::Tagged;

/// One `[[faults]]` entry as written (typed through the twin's fault registry).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultEntry(pub Tagged);

impl<'de> Deserialize<'de> for FaultEntry {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Tagged::deserialize(d).map(FaultEntry)
    }
}

/// One `[[expectations]]` entry as written (typed through the twin's expectation registry).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExpectEntry(pub Tagged);

impl<'de> Deserialize<'de> for ExpectEntry {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Tagged::deserialize(d).map(ExpectEntry)
    }
}

/// An entry's schema here: an object with a `kind`. The twin's schema replaces the
/// definition by [`FAULT_SCHEMA_NAME`] or [`EXPECT_SCHEMA_NAME`] with every kind's fields.
fn kinded(about: &str) -> schemars::Schema {
    schemars::json_schema!({
        "type": "object",
        "description": about,
        "required": ["kind"],
    })
}

/// The definition name of a fault entry in a scenario's JSON schema.
pub const FAULT_SCHEMA_NAME: &str = "Fault";
/// The definition name of an expectation entry.
pub const EXPECT_SCHEMA_NAME: &str = "Expectation";

impl JsonSchema for FaultEntry {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        FAULT_SCHEMA_NAME.into()
    }
    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        kinded("a fault: its `kind` and that kind's fields")
    }
}

impl JsonSchema for ExpectEntry {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        EXPECT_SCHEMA_NAME.into()
    }
    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        kinded("an expectation: its `kind` and that kind's fields")
    }
}
