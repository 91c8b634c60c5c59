//! What a scenario means, checked: every slice's check of its tables, in one table
//! ([`CHECKS`]), run after the scenario's own fields (m6p-twin-scenario); and the scenario's
//! JSON schema with every fault and expectation kind's fields.
//!
//! A slice with a table adds its check here (one line).

use twin_scenario::entries::{EXPECT_SCHEMA_NAME, FAULT_SCHEMA_NAME};
use twin_scenario::scenario::{Check, Scenario, ScenarioErrors};

/// Every slice's check, in the order their problems are reported.
pub const CHECKS: &[Check] = &[
    |s, net, err| {
        for i in 0..s.links.len() {
            crate::outside::validate(s, net, i, err);
        }
    },
    crate::commands::validate,
    crate::faults::validate,
    crate::adcs::validate,
    |s, _, err| crate::sessions::validate(s, err),
    |s, _, err| crate::eps::validate(s, err),
    |s, _, err| crate::comm::validate(s, err),
    |s, _, err| crate::clock::validate(s, err),
    crate::rules::validate,
    |s, _, err| crate::invariants::validate(s, err),
    crate::params::validate,
    crate::expectation_kinds::validate,
];

/// Parse and validate a scenario (its fields, then [`CHECKS`]); `file` names it in errors.
pub fn parse(file: &str, text: &str) -> Result<Scenario, ScenarioErrors> {
    Scenario::parse_with(file, text, CHECKS)
}

/// The scenario's JSON schema (`m6p-twin schema`), every fault and expectation kind with its
/// fields.
pub fn schema() -> schemars::Schema {
    let mut root = schemars::schema_for!(Scenario);
    let mut kinds = schemars::SchemaGenerator::default();
    let faults = crate::faults::entry_schema(&mut kinds);
    let expectations = crate::expectation_kinds::entry_schema(&mut kinds);
    if let Some(defs) = root.get_mut("$defs").and_then(|d| d.as_object_mut()) {
        defs.insert(FAULT_SCHEMA_NAME.to_owned(), faults.to_value());
        defs.insert(EXPECT_SCHEMA_NAME.to_owned(), expectations.to_value());
        for (name, def) in kinds.definitions() {
            defs.insert(name.clone(), def.clone());
        }
    }
    root
}
