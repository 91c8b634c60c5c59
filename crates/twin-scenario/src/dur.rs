//! A duration as a scenario writes it: `90`, `90s`, `500ms`, `10m`, `2h`, `1d`.

use std::time::Duration;

use schemars::JsonSchema;
use serde::{Deserialize, Deserializer};
use twin_core::duration::parse_duration;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default, JsonSchema)]
#[schemars(
    with = "String",
    description = "a duration: 90, 90s, 500ms, 10m, 2h, 1d"
)]
pub struct Dur(pub Duration);

impl<'de> Deserialize<'de> for Dur {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Int(u64),
            Float(f64),
            Str(String),
        }
        let text = match Raw::deserialize(d)? {
            Raw::Int(i) => i.to_string(),
            Raw::Float(f) => f.to_string(),
            Raw::Str(s) => s,
        };
        parse_duration(&text)
            .map(Dur)
            .map_err(serde::de::Error::custom)
    }
}
