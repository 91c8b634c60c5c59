//! Which channels a recording holds (`[record] channels`, `m6p-twin run --channels`): every
//! channel by default; rules leave some out or thin them to a rate, so that the recording's
//! size (and the recorder's work) is the user's choice.
//!
//! A rule is a topic pattern (a topic, or a prefix ending in `*`) with what to do:
//! - `TOPIC`: keep every message (the default for every channel);
//! - `-TOPIC`: leave the channel out (not in the file at all);
//! - `TOPIC@PERIOD`: keep at most one message per `PERIOD` of simulated time (the first, then
//!   the first at least `PERIOD` after the last kept).
//!
//! Rules apply in order and the last that matches a topic decides, so that
//! `-/fc/*,/fc/adcs` keeps only `/fc/adcs` of the FC's channels. A rule matching no channel
//! of the run is not an error (a bus or a link the run does not have).

use std::fmt;
use std::str::FromStr;
use std::time::Duration;

use schemars::JsonSchema;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use twin_core::duration::parse_duration;

/// What a rule does to the channels it matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelAction {
    /// Every message.
    Keep,
    /// None: the channel is not in the file.
    Omit,
    /// At most one message per period of simulated time.
    Every(Duration),
}

/// One rule: a topic pattern and its action.
#[derive(Debug, Clone, PartialEq, Eq, JsonSchema)]
#[schemars(
    with = "String",
    description = "a recording channel rule: TOPIC (keep), -TOPIC (leave out) or TOPIC@PERIOD (at most one message per PERIOD); TOPIC may end in * (a prefix)"
)]
pub struct ChannelRule {
    /// The topic, or the prefix before a final `*`.
    pattern: String,
    /// Whether `pattern` is a prefix (the rule ended in `*`).
    prefix: bool,
    /// What it does.
    pub action: ChannelAction,
}

/// Why a rule was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ChannelRuleError {
    /// The pattern does not start with `/`.
    #[error(
        "`{0}`: a channel rule names a topic, starting with `/` (as `/csp/packets` or `/fc/*`)"
    )]
    NotATopic(String),
    /// A `*` elsewhere than at the end.
    #[error("`{0}`: `*` may only end a topic pattern")]
    Star(String),
    /// The period after `@` is no duration, or zero.
    #[error("`{0}`: the period after `@` must be a duration above zero (as `1s`, `500ms`, `10m`)")]
    Period(String),
}

impl ChannelRule {
    /// Whether the rule is about `topic`.
    pub fn matches(&self, topic: &str) -> bool {
        if self.prefix {
            topic.starts_with(&self.pattern)
        } else {
            topic == self.pattern
        }
    }
}

impl FromStr for ChannelRule {
    type Err = ChannelRuleError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let s = text.trim();
        let (omit, s) = match s.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, s),
        };
        let (pattern, period) = match s.split_once('@') {
            Some((p, d)) if !omit => (p, Some(d)),
            _ => (s, None),
        };
        if !pattern.starts_with('/') {
            return Err(ChannelRuleError::NotATopic(text.to_owned()));
        }
        let (pattern, prefix) = match pattern.strip_suffix('*') {
            Some(p) => (p, true),
            None => (pattern, false),
        };
        if pattern.contains('*') {
            return Err(ChannelRuleError::Star(text.to_owned()));
        }
        let action = match period {
            _ if omit => ChannelAction::Omit,
            None => ChannelAction::Keep,
            Some(d) => match parse_duration(d) {
                Ok(d) if !d.is_zero() => ChannelAction::Every(d),
                _ => return Err(ChannelRuleError::Period(text.to_owned())),
            },
        };
        Ok(ChannelRule {
            pattern: pattern.to_owned(),
            prefix,
            action,
        })
    }
}

impl fmt::Display for ChannelRule {
    /// As written, in canonical form (`-/csp/packets`, `/fc/*@10s`): parses back to itself.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.action == ChannelAction::Omit {
            f.write_str("-")?;
        }
        f.write_str(&self.pattern)?;
        if self.prefix {
            f.write_str("*")?;
        }
        if let ChannelAction::Every(d) = self.action {
            // In the units the scenario's durations take (no `ns`).
            let (s, ns) = (d.as_secs(), d.subsec_nanos());
            if ns == 0 {
                write!(f, "@{s}s")?;
            } else if ns % 1_000_000 == 0 {
                write!(f, "@{}ms", d.as_millis())?;
            } else {
                write!(f, "@{s}.{ns:09}s")?;
            }
        }
        Ok(())
    }
}

impl<'de> Deserialize<'de> for ChannelRule {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

impl Serialize for ChannelRule {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// What `rules` do to `topic`: the last matching rule's action, else [`ChannelAction::Keep`].
pub fn action(rules: &[ChannelRule], topic: &str) -> ChannelAction {
    rules
        .iter()
        .rev()
        .find(|r| r.matches(topic))
        .map_or(ChannelAction::Keep, |r| r.action)
}

/// Rules written in one line, comma-separated (the command line's `--channels`, the
/// recording's metadata); empty: none.
pub fn parse_rules(text: &str) -> Result<Vec<ChannelRule>, ChannelRuleError> {
    text.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::parse)
        .collect()
}

/// `rules` in one line, as [`parse_rules`] reads them.
pub fn format_rules(rules: &[ChannelRule]) -> String {
    rules
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_last_matching_rule_decides_and_everything_else_is_kept() {
        let rules = parse_rules("-/fc/*, /fc/adcs, /fc/truth/*@10s").unwrap();
        assert_eq!(action(&rules, "/fc/adcs"), ChannelAction::Keep);
        assert_eq!(action(&rules, "/fc/scene"), ChannelAction::Omit);
        assert_eq!(
            action(&rules, "/fc/truth/tf"),
            ChannelAction::Every(Duration::from_secs(10))
        );
        assert_eq!(action(&rules, "/csp/packets"), ChannelAction::Keep);
        // A prefix is a prefix of the topic, not of a path segment only.
        assert_eq!(action(&rules, "/fcx"), ChannelAction::Keep);
    }

    #[test]
    fn rules_print_as_they_parse() {
        let rules =
            parse_rules("-/csp/packets,/fc/*@1s,/can/main/frames,/x@250ms,/y@1m,/z@1.5ms").unwrap();
        let line = format_rules(&rules);
        assert_eq!(
            line,
            "-/csp/packets,/fc/*@1s,/can/main/frames,/x@250ms,/y@60s,/z@0.001500000s"
        );
        assert_eq!(parse_rules(&line).unwrap(), rules);
        assert!(parse_rules("").unwrap().is_empty());
    }

    #[test]
    fn bad_rules_are_refused_with_why() {
        assert_eq!(
            "csp/packets".parse::<ChannelRule>(),
            Err(ChannelRuleError::NotATopic("csp/packets".into()))
        );
        assert_eq!(
            "/fc/*/tf".parse::<ChannelRule>(),
            Err(ChannelRuleError::Star("/fc/*/tf".into()))
        );
        for bad in ["/fc/adcs@0s", "/fc/adcs@soon", "/fc/adcs@"] {
            assert_eq!(
                bad.parse::<ChannelRule>(),
                Err(ChannelRuleError::Period(bad.into()))
            );
        }
    }
}
