//! Entries tagged with `kind` (`[[faults]]`, `[[expectations]]`), typed through a registry
//! of kinds: the scenario keeps each entry as its TOML table, and the registry deserializes
//! the kind's own fields into the kind's struct, every error with the field it is about
//! (so that the scenario's errors name the file, the line and the field).

use std::collections::BTreeSet;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer};

/// One `kind`-tagged entry as written: a TOML table.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tagged(pub toml::Table);

impl<'de> Deserialize<'de> for Tagged {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        toml::Table::deserialize(d).map(Tagged)
    }
}

impl Tagged {
    /// The entry's `kind`, if it is a string.
    pub fn kind(&self) -> Option<&str> {
        self.0.get("kind").and_then(toml::Value::as_str)
    }

    /// The entry without `kind` and the `common` fields, deserialized into `T` (the kind's
    /// own fields, `deny_unknown_fields`); `what` names the kind in messages (`a \`drop\`
    /// fault`), `common` are the fields every kind takes. An error is (field, message).
    pub fn params<T: DeserializeOwned>(
        &self,
        what: &str,
        common: &[&str],
    ) -> Result<T, (String, String)> {
        let mut rest = self.0.clone();
        rest.remove("kind");
        for c in common {
            rest.remove(*c);
        }
        serde_path_to_error::deserialize::<_, T>(rest).map_err(|e| {
            let path = e.path().to_string();
            let message = e.into_inner().message().trim().to_owned();
            explain(what, common, &path, &message)
        })
    }

    /// The `common` fields alone, deserialized into `T`.
    pub fn common<T: DeserializeOwned>(&self, common: &[&str]) -> Result<T, (String, String)> {
        let keep: BTreeSet<&str> = common.iter().copied().collect();
        let mut only = self.0.clone();
        only.retain(|k, _| keep.contains(k));
        serde_path_to_error::deserialize::<_, T>(only).map_err(|e| {
            let path = e.path().to_string();
            let message = e.into_inner().message().trim().to_owned();
            explain("this entry", &[], &path, &message)
        })
    }
}

/// How a kind types an entry, given the words naming it in messages; an error is (field,
/// message).
pub type TypeEntry<P> = fn(&Tagged, &str) -> Result<P, (String, String)>;

/// An entry parsed: its common fields `C` and its kind `P`, or every problem of both as
/// (field, message).
pub type Parsed<C, P> = Result<(C, P), Vec<(String, String)>>;

/// One kind of a registry: its name in scenarios (`drop`), one line on what it does, how an
/// entry of it is typed (given the words naming it in messages: ``a `drop` fault``), and its
/// own fields' JSON schema.
pub struct Kind<P> {
    name: &'static str,
    about: &'static str,
    typed: TypeEntry<P>,
    schema: fn() -> serde_json::Value,
}

impl<P> Kind<P> {
    /// A kind of the registry (see [`Kind`]).
    pub const fn new(
        name: &'static str,
        about: &'static str,
        typed: TypeEntry<P>,
        schema: fn() -> serde_json::Value,
    ) -> Self {
        Kind {
            name,
            about,
            typed,
            schema,
        }
    }
}

impl<P> std::fmt::Debug for Kind<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Kind")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

/// The JSON schema of `T` as a value (a [`Kind`]'s fields, a registry's common fields).
pub fn schema_of<T: schemars::JsonSchema>() -> serde_json::Value {
    serde_json::to_value(schemars::schema_for!(T)).unwrap_or_default()
}

/// Every kind of one tagged table (`[[faults]]`, `[[expectations]]`), each entry typed as
/// `P` (the table's kind-erased form): how an entry is parsed into its common fields and its
/// kind, the kinds' names for messages, and the table's JSON schema. A new kind is one line
/// of its table's registry.
pub struct Registry<P: 'static> {
    /// What an entry is called in messages (`fault`).
    noun: &'static str,
    /// The fields every kind takes.
    common: &'static [&'static str],
    kinds: &'static [Kind<P>],
}

impl<P> Registry<P> {
    /// The registry of the table whose entries are `noun`s, with the `common` fields.
    pub const fn new(
        noun: &'static str,
        common: &'static [&'static str],
        kinds: &'static [Kind<P>],
    ) -> Self {
        Registry {
            noun,
            common,
            kinds,
        }
    }

    /// The kinds' names, in registry order.
    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.kinds.iter().map(|k| k.name)
    }

    /// The entry's kind, typed; an error is (field, message).
    pub fn kind_of(&self, e: &Tagged) -> Result<P, (String, String)> {
        let kind = e.kind().unwrap_or("");
        if let Some(k) = self.kinds.iter().find(|k| k.name == kind) {
            let what = format!("{} `{}` {}", article(k.name), k.name, self.noun);
            return (k.typed)(e, &what);
        }
        let kinds = self.names().collect::<Vec<_>>().join(", ");
        let noun = self.noun;
        Err((
            "kind".to_owned(),
            if e.0.contains_key("kind") {
                format!("unknown {noun} kind `{kind}` (kinds: {kinds})")
            } else {
                format!("{} {noun} needs `kind` ({kinds})", article(noun))
            },
        ))
    }

    /// The entry's common fields `C` and its kind; every problem of both, as (field,
    /// message).
    pub fn parse<C: DeserializeOwned>(&self, e: &Tagged) -> Parsed<C, P> {
        let kind = self.kind_of(e);
        let common = e.common::<C>(self.common);
        match (common, kind) {
            (Ok(c), Ok(k)) => Ok((c, k)),
            (c, k) => Err([c.err(), k.err()].into_iter().flatten().collect()),
        }
    }

    /// The JSON schema of an entry, one of the kinds, each with the common fields `C` (a
    /// scenario schema's definition of the table's entry).
    pub fn entry_schema<C: schemars::JsonSchema>(
        &self,
        generator: &mut schemars::SchemaGenerator,
    ) -> schemars::Schema {
        let kinds = self
            .kinds
            .iter()
            .map(|k| (k.name, k.about, (k.schema)()))
            .collect();
        one_of(generator, schema_of::<C>(), kinds)
    }
}

impl<P> std::fmt::Debug for Registry<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Registry")
            .field("noun", &self.noun)
            .field("kinds", &self.kinds)
            .finish_non_exhaustive()
    }
}

/// The indefinite article of `word` as messages spell it.
fn article(word: &str) -> &'static str {
    if word.starts_with(['a', 'e', 'i', 'o', 'u']) {
        "an"
    } else {
        "a"
    }
}

/// A serde error as the scenario reports it: the field it is about and a message that says
/// what the kind takes.
fn explain(what: &str, common: &[&str], path: &str, message: &str) -> (String, String) {
    if let Some(rest) = message.strip_prefix("unknown field `")
        && let Some((field, expected)) = rest.split_once('`')
    {
        let mut takes: Vec<String> = common.iter().map(|c| (*c).to_owned()).collect();
        takes.extend(expected_fields(expected));
        let takes = if takes.is_empty() {
            "no other field".to_owned()
        } else {
            takes.join(", ")
        };
        return (
            field.to_owned(),
            format!("{what} takes no `{field}` (it takes {takes})"),
        );
    }
    if let Some(rest) = message.strip_prefix("missing field `")
        && let Some((field, _)) = rest.split_once('`')
    {
        return ("kind".to_owned(), format!("{what} needs `{field}`"));
    }
    let field = if path == "." { "kind" } else { path };
    (field.to_owned(), message.to_owned())
}

/// The field names of serde's "expected ..." (`one of `a`, `b``, `` `a` or `b` ``).
fn expected_fields(expected: &str) -> Vec<String> {
    expected
        .split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_owned)
        .collect()
}

/// A JSON Schema for a tagged entry: one of each kind's object, `kind` set to its name and
/// the `common` fields' schemas (`common_schema`'s properties) merged in.
pub fn one_of(
    generator: &mut schemars::SchemaGenerator,
    common_schema: serde_json::Value,
    kinds: Vec<(&'static str, &'static str, serde_json::Value)>,
) -> schemars::Schema {
    let common_props = common_schema
        .get("properties")
        .cloned()
        .unwrap_or_else(|| serde_json::json!({}));
    let common_required = common_schema
        .get("required")
        .cloned()
        .unwrap_or_else(|| serde_json::json!([]));
    let mut defs = serde_json::Map::new();
    let mut one_of = Vec::new();
    for (name, about, mut schema) in kinds {
        if let Some(d) = schema.get_mut("$defs").and_then(|d| d.as_object_mut()) {
            defs.append(d);
        }
        if let Some(o) = schema.as_object_mut() {
            o.remove("$defs");
            o.remove("$schema");
            o.remove("title");
            o.insert("description".into(), about.into());
            let props = o
                .entry("properties")
                .or_insert_with(|| serde_json::json!({}));
            if let (Some(p), Some(c)) = (props.as_object_mut(), common_props.as_object()) {
                for (k, v) in c {
                    p.insert(k.clone(), v.clone());
                }
                p.insert("kind".into(), serde_json::json!({ "const": name }));
            }
            let req = o.entry("required").or_insert_with(|| serde_json::json!([]));
            if let Some(r) = req.as_array_mut() {
                r.push("kind".into());
                if let Some(c) = common_required.as_array() {
                    r.extend(c.iter().cloned());
                }
            }
            o.insert("additionalProperties".into(), false.into());
        }
        one_of.push(schema);
    }
    for (k, v) in defs {
        generator.definitions_mut().insert(k, v);
    }
    schemars::Schema::try_from(serde_json::json!({ "oneOf": one_of }))
        .unwrap_or_else(|_| schemars::Schema::default())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serde_messages_become_what_the_kind_takes() {
        let (f, m) = explain(
            "a `beacon` expectation",
            &[],
            ".",
            "unknown field `quantity`, expected one of `within`, `min`, `max`",
        );
        assert_eq!(f, "quantity");
        assert_eq!(
            m,
            "a `beacon` expectation takes no `quantity` (it takes within, min, max)"
        );
        let (f, m) = explain(
            "a `drop` fault",
            &["at"],
            ".",
            "missing field `probability`",
        );
        assert_eq!(
            (f.as_str(), m.as_str()),
            ("kind", "a `drop` fault needs `probability`")
        );
        let (f, _) = explain(
            "x",
            &[],
            "delay",
            "invalid type: integer `3`, expected a string",
        );
        assert_eq!(f, "delay");
        assert_eq!(
            expected_fields("`a` or `b`"),
            vec!["a".to_owned(), "b".to_owned()]
        );
    }
}
