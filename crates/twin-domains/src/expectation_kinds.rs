//! The expectation kinds' registry: every kind by name, each domain's beside the others
//! (a new kind is one line here), and what the registry does with a scenario's
//! `[[expectations]]`: parse each entry into its kind, check it, compile it, and give the
//! JSON schema of every kind's fields. The kinds' common vocabulary is [`crate::expectations`].

use crate::expectations::{
    AnyExpect, COMMON, Common, ExpectCx, ExpectEntry, ExpectKind, Expectation,
};
use std::sync::Arc;
use twin_core::network::NetworkSpec;

use twin_core::tagged::{Kind, Parsed, Registry, Tagged, schema_of};
use twin_scenario::scenario::{PathStep, Scenario};

fn typed<K: ExpectKind>(e: &Tagged, what: &str) -> Result<Arc<dyn AnyExpect>, (String, String)> {
    e.params::<K>(what, COMMON)
        .map(|k| Arc::new(k) as Arc<dyn AnyExpect>)
}

const fn kind<K: ExpectKind>() -> Kind<Arc<dyn AnyExpect>> {
    Kind::new(K::NAME, K::ABOUT, typed::<K>, schema_of::<K>)
}

/// The registry: every expectation kind, by name (see the module doc).
static REGISTRY: Registry<Arc<dyn AnyExpect>> = Registry::new(
    "expectation",
    COMMON,
    &[
        kind::<crate::commands::ReplyExpect>(),
        kind::<crate::commands::NoReplyExpect>(),
        kind::<crate::latency::LatencyExpect>(),
        kind::<crate::counters::CounterExpect>(),
        kind::<crate::adcs::AttitudeExpect>(),
        kind::<crate::sessions::SessionExpect>(),
        kind::<crate::sessions::DownlinkExpect>(),
        kind::<crate::sessions::AccountingExpect>(),
        kind::<crate::eps::PowerExpect>(),
        kind::<crate::comm::BeaconExpect>(),
        kind::<crate::can::CanExpect>(),
        kind::<crate::fields::FieldExpect>(),
    ],
);

/// The JSON schema of an entry: one of the kinds, each with the common fields (the
/// scenario's schema takes it as its `Expectation` definition).
pub fn entry_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
    REGISTRY.entry_schema::<Common>(generator)
}

fn parse(e: &ExpectEntry) -> Parsed<Common, Arc<dyn AnyExpect>> {
    REGISTRY.parse(&e.0)
}

/// Check every `[[expectations]]` entry; `err(path, message)` for each problem.
pub fn validate(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let cx = ExpectCx { scenario: s, net };
    for (i, e) in s.expectations.iter().enumerate() {
        let p = |f: &str| {
            vec![
                PathStep::Key("expectations".into()),
                PathStep::Index(i),
                PathStep::Key(f.into()),
            ]
        };
        match parse(e) {
            Ok((_, kind)) => kind.validate(&cx, &mut |f, m| err(p(f), m)),
            Err(errs) => {
                for (f, m) in errs {
                    err(p(&f), m);
                }
            }
        }
    }
}

/// The expectations of a validated scenario, in file order.
pub fn compile(s: &Scenario) -> Vec<Expectation> {
    let parsed: Vec<(usize, Common, Arc<dyn AnyExpect>)> = s
        .expectations
        .iter()
        .enumerate()
        .filter_map(|(i, e)| parse(e).ok().map(|(c, k)| (i, c, k)))
        .collect();
    // An unnamed expectation is named by what it is about (`reply to ping-eps`); one that
    // would take a name already given says where it is in the file as well.
    let mut taken: std::collections::BTreeSet<String> = parsed
        .iter()
        .filter_map(|(_, c, _)| c.name.clone())
        .collect();
    parsed
        .into_iter()
        .map(|(i, common, kind)| {
            let name = common.name.unwrap_or_else(|| {
                let d = kind.describe();
                let name = if taken.contains(&d) {
                    format!("{d} (expectations[{i}])")
                } else {
                    d
                };
                taken.insert(name.clone());
                name
            });
            Expectation::of_any(name, kind)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    /// An unnamed expectation is named by what it is about; a name already taken gets its
    /// place in the file; a given name stays as it is.
    #[test]
    fn an_unnamed_expectation_is_named_by_what_it_is_about() {
        let text = r#"name = "t"
duration = "60s"
[[commands]]
name = "ping-eps"
at = "10s"
to = "EPS"
request = "ping"
[[expectations]]
kind = "reply"
command = "ping-eps"
[[expectations]]
kind = "reply"
command = "ping-eps"
within = "1s"
[[expectations]]
name = "no reply to ping-eps"
kind = "counter"
target = "PC"
counter = "drops"
max = 0
[[expectations]]
kind = "no-reply"
command = "ping-eps"
[[expectations]]
kind = "counter"
target = "PC"
counter = "drops"
max = 0
[[expectations]]
kind = "can"
bus = "main"
node = "ECU"
state = "error-passive"
min = 2
[[expectations]]
kind = "can"
bus = "main"
node = "EPS"
end_state = "error-active"
"#;
        let s = crate::validate::parse("t.toml", text).unwrap();
        let names: Vec<String> = super::compile(&s).into_iter().map(|e| e.name).collect();
        assert_eq!(
            names,
            [
                "reply to ping-eps",
                "reply to ping-eps (expectations[1])",
                "no reply to ping-eps",
                "no reply to ping-eps (expectations[3])",
                "PC drops",
                "ECU error-passive entries on the main bus",
                "EPS error-active at the end on the main bus",
            ]
        );
    }
}
