//! The expectation kinds' registry: every kind by name, each domain's beside the others
//! (a new kind is one line here), and what the registry does with a scenario's
//! `[[expectations]]`: parse each entry into its kind, check it, compile it, and give the
//! JSON schema of every kind's fields. The kinds' common vocabulary is [`crate::expectations`].

use crate::expectations::{
    AnyExpect, COMMON, Common, ExpectCx, ExpectEntry, ExpectKind, Expectation,
};
use twin_core::network::NetworkSpec;
use twin_core::tagged::Tagged;
use twin_scenario::scenario::{PathStep, Scenario};

fn typed<K: ExpectKind>(e: &Tagged) -> Result<std::sync::Arc<dyn AnyExpect>, (String, String)> {
    let what = format!(
        "{} `{}` expectation",
        if K::NAME.starts_with(['a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        },
        K::NAME
    );
    e.params::<K>(&what, COMMON)
        .map(|k| std::sync::Arc::new(k) as std::sync::Arc<dyn AnyExpect>)
}

/// The registry: every expectation kind, by name (see the module doc).
macro_rules! registry {
    ($($kind:ty),* $(,)?) => {
        /// The kinds' names.
        pub const KINDS: &[&str] = &[$(<$kind as ExpectKind>::NAME),*];

        fn parse_kind(e: &Tagged) -> Result<std::sync::Arc<dyn AnyExpect>, (String, String)> {
            let kind = e.kind().unwrap_or("");
            $(if kind == <$kind as ExpectKind>::NAME {
                return typed::<$kind>(e);
            })*
            Err((
                "kind".to_owned(),
                if e.0.contains_key("kind") {
                    format!("unknown expectation kind `{kind}` (kinds: {})", KINDS.join(", "))
                } else {
                    format!("an expectation needs `kind` ({})", KINDS.join(", "))
                },
            ))
        }

        /// The JSON schema of an entry: one of the kinds, each with the common fields
        /// (the scenario's schema takes it as its `Expectation` definition).
        pub fn entry_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
            let common = serde_json::to_value(schemars::schema_for!(Common))
                .unwrap_or_default();
            let kinds = vec![$((
                <$kind as ExpectKind>::NAME,
                <$kind as ExpectKind>::ABOUT,
                serde_json::to_value(schemars::schema_for!($kind)).unwrap_or_default(),
            )),*];
            twin_core::tagged::one_of(generator, common, kinds)
        }
    };
}

registry! {
    crate::commands::ReplyExpect,
    crate::commands::NoReplyExpect,
    crate::latency::LatencyExpect,
    crate::counters::CounterExpect,
    crate::adcs::AttitudeExpect,
    crate::sessions::SessionExpect,
    crate::sessions::DownlinkExpect,
    crate::sessions::AccountingExpect,
    crate::eps::PowerExpect,
    crate::comm::BeaconExpect,
    crate::can::CanExpect,
    crate::fields::FieldExpect,
}

type Parsed = (Common, std::sync::Arc<dyn AnyExpect>);

fn parse(e: &ExpectEntry) -> Result<Parsed, Vec<(String, String)>> {
    let kind = parse_kind(&e.0);
    let common = e.0.common::<Common>(COMMON);
    match (common, kind) {
        (Ok(c), Ok(k)) => Ok((c, k)),
        (c, k) => Err([c.err(), k.err()].into_iter().flatten().collect()),
    }
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
    s.expectations
        .iter()
        .enumerate()
        .filter_map(|(i, e)| {
            let (common, kind) = parse(e).ok()?;
            Some(Expectation::of_any(
                common.name.unwrap_or_else(|| format!("expectations[{i}]")),
                kind,
            ))
        })
        .collect()
}
