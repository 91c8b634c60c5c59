//! The ground's requests in a scenario: the `[[commands]]` (pings, services, raw ICD
//! requests from a ground station at times, or after another command's outcome), their
//! validation and compilation into the stations' plans, and the `reply` and `no-reply`
//! expectations on their outcomes.
//!
//! See docs/scenarios.md ("Commands").

use std::collections::BTreeMap;
use std::time::Duration;

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Judgement, Occurrence, Watch, WatchCx};
use twin_core::events::{EventKind, Kinds, RunEvent};
use twin_core::network::NetworkSpec;
use twin_report::RunReport;
use twin_runtime::ground::{Outcome, PlannedRequest, Recurring};
use twin_scenario::scenario::{Dur, NodeRef, PathStep, Scenario};

fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

pub use twin_scenario::commands::*;

/// The names of the commands (`name`, default `commands[i]`), in file order.
fn names(s: &Scenario) -> Vec<String> {
    s.commands
        .iter()
        .enumerate()
        .map(|(i, c)| c.name.clone().unwrap_or_else(|| format!("commands[{i}]")))
        .collect()
}

/// Check the `[[commands]]`.
pub fn validate(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    // Each command's name, and the first command of each name: looked up, never searched
    // (a scenario of a hundred thousand commands is checked in linear time).
    let names: Vec<String> = s
        .commands
        .iter()
        .enumerate()
        .map(|(i, c)| c.name.clone().unwrap_or_else(|| format!("commands[{i}]")))
        .collect();
    let mut first_of: std::collections::HashMap<&str, usize> =
        std::collections::HashMap::with_capacity(names.len());
    for (i, n) in names.iter().enumerate() {
        first_of.entry(n.as_str()).or_insert(i);
    }
    // The sending station, GS16 when not given.
    let station = |c: &CommandSpec| c.from.as_ref().map_or(Some(16), |r| net.resolve(r).ok());
    for (i, c) in s.commands.iter().enumerate() {
        if let Some(a) = &c.after {
            let own = &names[i];
            match first_of
                .get(a.as_str())
                .and_then(|&j| s.commands.get(j).map(|o| (j, o)))
            {
                None => err(
                    vec![key("commands"), PathStep::Index(i), key("after")],
                    format!("no command is named `{a}`"),
                ),
                Some(_) if a == own => err(
                    vec![key("commands"), PathStep::Index(i), key("after")],
                    "a command cannot wait for itself".into(),
                ),
                Some((_, o)) if station(o) != station(c) => err(
                    vec![key("commands"), PathStep::Index(i), key("after")],
                    format!("`{a}` is sent from another ground station"),
                ),
                Some(_) => {}
            }
        }
    }
    for (i, c) in s.commands.iter().enumerate() {
        let p = |f: &str| vec![key("commands"), PathStep::Index(i), key(f)];
        let name = &names[i];
        if first_of.get(name.as_str()) != Some(&i) {
            err(
                p("name"),
                format!("another command is already named `{name}`"),
            );
        }
        check_endpoints(c, net, &p, err);
        match (&c.request, &c.command) {
            (Some(_), Some(_)) => err(
                p("command"),
                "give `request` or `command`, not both".into(),
            ),
            (None, None) => err(
                p("request"),
                "missing: `request` (ping, uptime, ident, memfree, buf-free, ps, reboot, raw) or `command` (an ICD command, NODE.COMMAND)".into(),
            ),
            _ => {}
        }
        if c.args.is_some() && c.command.is_none() {
            err(p("args"), "only a typed `command` takes `args`".into());
        }
        if let Some(name) = &c.command {
            check_typed(c, name, net, &p, err);
        }
        check_request_fields(c, &p, err);
    }
}

/// A command's sender (a ground station) and destination.
fn check_endpoints(
    c: &CommandSpec,
    net: &NetworkSpec,
    p: &dyn Fn(&str) -> Vec<PathStep>,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    match c.from.as_ref().map(|r| net.resolve(r)) {
        None => {
            if !net
                .nodes
                .iter()
                .any(|n| n.role == twin_core::network::Role::Ground)
            {
                err(
                    p("to"),
                    "there is no ground station to send from (network.ground_stations is empty)"
                        .into(),
                );
            }
        }
        Some(Err(e)) => err(p("from"), e.to_string()),
        Some(Ok(a)) if !(16..=20).contains(&a) => err(
            p("from"),
            format!("commands are sent from a ground station (16-20), not from {a}"),
        ),
        Some(Ok(_)) => {}
    }
    match &c.to {
        Some(NodeRef::Addr(a)) if *a >= 31 => {
            err(p("to"), format!("{a} is not a unicast CSP address"))
        }
        Some(NodeRef::Addr(_)) => {}
        Some(r @ NodeRef::Name(_)) => {
            if let Err(e) = net.resolve(r) {
                err(p("to"), e.to_string());
            }
        }
        None if c.command.is_none() => err(
            {
                // The command itself: its table, not one of its fields.
                let mut whole = p("to");
                whole.pop();
                whole
            },
            "missing field `to` (the destination node)".into(),
        ),
        None => {}
    }
}

/// A typed ICD command `name`: it exists, goes to its node, and its `args` encode.
fn check_typed(
    c: &CommandSpec,
    name: &str,
    net: &NetworkSpec,
    p: &dyn Fn(&str) -> Vec<PathStep>,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    if c.data.is_some() || c.text.is_some() {
        err(
            p(if c.data.is_some() { "data" } else { "text" }),
            "a typed `command` takes `args`; raw bytes go with `request = \"raw\"`".into(),
        );
    }
    match twin_core::icd::find_command(name) {
        Err(e) => err(p("command"), e.to_string()),
        Ok((node, _, cmd)) => {
            let to = c.to.as_ref().and_then(|r| match r {
                NodeRef::Addr(a) => Some(*a),
                r => net.resolve(r).ok(),
            });
            match to {
                Some(a) if !node.addrs.contains(&a) => err(
                    p("to"),
                    format!(
                        "{name} goes to the {} ({}), not to {a}",
                        node.name,
                        node.addrs
                            .iter()
                            .map(u8::to_string)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ),
                None if c.to.is_none() && node.name == "payload" => err(
                    p("to"),
                    format!("missing: which payload {name} goes to (12-15)"),
                ),
                _ => {}
            }
            let args = c.args.clone().unwrap_or_default();
            if let Err((field, e)) = twin_core::icd::encode_args(cmd, &args) {
                let mut at = p("args");
                if !field.is_empty() && args.contains_key(&field) {
                    at.push(key(&field));
                } else if c.args.is_none() {
                    at = p("command");
                }
                err(at, e);
            }
        }
    }
}

/// A command's repetition and its request's fields (port, data, text, size).
fn check_request_fields(
    c: &CommandSpec,
    p: &dyn Fn(&str) -> Vec<PathStep>,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    if c.every.is_some() != c.count.is_some() {
        err(
            p(if c.every.is_some() { "every" } else { "count" }),
            "`every` and `count` go together".into(),
        );
    }
    if c.every.is_some_and(|e| e.0.is_zero()) {
        err(p("every"), "must be longer than zero".into());
    }
    if c.count == Some(0) {
        err(p("count"), "must be at least 1".into());
    }
    if c.count.unwrap_or(1) > 1_000_000 {
        err(p("count"), "at most 1000000 repetitions".into());
    }
    let raw = c.request == Some(RequestKind::Raw);
    if raw && c.port.is_none() {
        err(p("request"), "a `raw` request needs `port`".into());
    }
    if !raw && c.command.is_none() && (c.port.is_some() || c.data.is_some() || c.text.is_some()) {
        err(
            p(if c.port.is_some() {
                "port"
            } else if c.data.is_some() {
                "data"
            } else {
                "text"
            }),
            "only a `raw` request takes `port`, `data` and `text`".into(),
        );
    }
    if c.data.is_some() && c.text.is_some() {
        err(p("text"), "give `data` or `text`, not both".into());
    }
    if c.text.as_ref().is_some_and(|t| t.len() > 256) {
        err(p("text"), "more than the CSP MTU of 256 bytes".into());
    }
    if c.port.is_some_and(|port| port > 63) {
        err(
            p("port"),
            format!("{} is not a CSP port (0-63)", c.port.unwrap_or(0)),
        );
    }
    if let Some(d) = &c.data
        && let Err(e) = parse_hex(d)
    {
        err(p("data"), e.to_string());
    }
    if c.size.is_some() && c.request != Some(RequestKind::Ping) {
        err(p("size"), "only a `ping` takes `size`".into());
    }
    if c.size.is_some_and(|s| s > 256) {
        err(
            p("size"),
            format!("{} bytes exceed the CSP MTU of 256", c.size.unwrap_or(0)),
        );
    }
}

/// The ground stations' plans of a validated scenario's `[[commands]]`, by station address.
pub fn compile(s: &Scenario, net: &NetworkSpec) -> BTreeMap<u8, Vec<Recurring>> {
    let mut plans: BTreeMap<u8, Vec<Recurring>> = BTreeMap::new();
    let default_gs = net
        .nodes
        .iter()
        .find(|n| n.role == twin_core::network::Role::Ground)
        .map(|n| n.addr);
    for (i, c) in s.commands.iter().enumerate() {
        let name = c.name.clone().unwrap_or_else(|| format!("commands[{i}]"));
        let from = c
            .from
            .as_ref()
            .and_then(|r| net.resolve(r).ok())
            .or(default_gs)
            .unwrap_or(16);
        let typed = c
            .command
            .as_deref()
            .and_then(|n| twin_core::icd::find_command(n).ok());
        let to = match (&c.to, &typed) {
            (Some(NodeRef::Addr(a)), _) => *a,
            (Some(r), _) => net.resolve(r).unwrap_or(0),
            (None, Some((node, _, _))) => node.addrs.first().copied().unwrap_or(0),
            (None, None) => 0,
        };
        let (dport, data) = match (c.request, typed) {
            (_, Some((_, port, cmd))) => {
                let mut data = vec![cmd.id];
                data.extend(
                    twin_core::icd::encode_args(cmd, &c.args.clone().unwrap_or_default())
                        .unwrap_or_default(),
                );
                (c.port.unwrap_or(port.port), data)
            }
            (None, None) => (0, Vec::new()),
            (Some(kind), None) => match kind {
                RequestKind::Ping => (1, twin_runtime::ground::ping_payload(c.size.unwrap_or(16))),
                RequestKind::Uptime => (6, vec![]),
                RequestKind::Ident => (0, vec![0x00, 0x01]),
                RequestKind::Memfree => (3, vec![]),
                RequestKind::BufFree => (5, vec![]),
                RequestKind::Ps => (2, vec![]),
                RequestKind::Reboot => (4, csp::service::REBOOT_MAGIC.to_be_bytes().to_vec()),
                RequestKind::Raw => (
                    c.port.unwrap_or(0),
                    match &c.text {
                        Some(t) => t.as_bytes().to_vec(),
                        None => c
                            .data
                            .as_deref()
                            .map(parse_hex)
                            .and_then(Result::ok)
                            .unwrap_or_default(),
                    },
                ),
            },
        };
        let timeout = c.timeout.map_or(Duration::from_secs(5), |d| d.0);
        let every = c.every.map_or(Duration::ZERO, |d| d.0);
        // One entry however many times it repeats: the station makes each occurrence when
        // it is due.
        plans.entry(from).or_default().push(Recurring {
            first: PlannedRequest {
                at: SimTime::ZERO + c.at.0,
                dst: to,
                dport,
                data,
                timeout,
                label: name,
                after: c.after.clone(),
            },
            every,
            count: c.count.unwrap_or(1),
        });
    }
    plans
}

/// An expected reply: hex bytes where `??` stands for any byte, and a final `...` for any
/// further bytes (`"01 01 02 01 ..."`: a TMCOMM reply from COMM2 with its radio active).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplyPattern {
    /// Each byte, `None` for any.
    pub bytes: Vec<Option<u8>>,
    /// Whether more bytes may follow.
    pub open_end: bool,
}

/// Why a text is not hex bytes (or a reply pattern); each names the text.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum HexBytesError {
    /// An odd number of digits.
    #[error("`{text}` is not hex bytes: an odd number of digits")]
    OddDigits {
        /// The text.
        text: String,
    },
    /// A character beyond ASCII.
    #[error("`{text}` is not hex bytes: `{found}`")]
    NotAscii {
        /// The text.
        text: String,
        /// The first such character.
        found: char,
    },
    /// Two characters that are neither a hex byte nor `??`.
    #[error("`{text}` is not hex bytes: `{pair}` (use ?? for any byte)")]
    NotAByte {
        /// The text.
        text: String,
        /// The pair.
        pair: String,
    },
    /// Not hex ([`parse_hex`]). The decoder's message is part of this one's, so it is not
    /// also its `source()`.
    #[error("`{text}` is not hex bytes: {hex}")]
    NotHex {
        /// The text.
        text: String,
        /// The decoder's error.
        hex: hex::FromHexError,
    },
}

impl ReplyPattern {
    /// Parse `"01 ?? ff ..."`.
    pub fn parse(s: &str) -> Result<Self, HexBytesError> {
        let compact: String = s.chars().filter(|c| !c.is_whitespace()).collect();
        let (body, open_end) = match compact.strip_suffix("...") {
            Some(b) => (b.to_owned(), true),
            None => (compact, false),
        };
        if body.len() % 2 != 0 {
            return Err(HexBytesError::OddDigits { text: s.to_owned() });
        }
        // By bytes, not by string slices: a character of several bytes is not hex, and a
        // slice through it would panic.
        if let Some(found) = body.chars().find(|c| !c.is_ascii()) {
            return Err(HexBytesError::NotAscii {
                text: s.to_owned(),
                found,
            });
        }
        let bytes = body
            .as_bytes()
            .chunks(2)
            .map(|pair| match pair {
                b"??" => Ok(None),
                _ => std::str::from_utf8(pair)
                    .ok()
                    .filter(|p| p.bytes().all(|c| c.is_ascii_hexdigit()))
                    .and_then(|p| u8::from_str_radix(p, 16).ok())
                    .map(Some)
                    .ok_or_else(|| HexBytesError::NotAByte {
                        text: s.to_owned(),
                        pair: String::from_utf8_lossy(pair).into_owned(),
                    }),
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(ReplyPattern { bytes, open_end })
    }

    /// Whether `got` matches.
    pub fn matches(&self, got: &[u8]) -> bool {
        let len_ok = if self.open_end {
            got.len() >= self.bytes.len()
        } else {
            got.len() == self.bytes.len()
        };
        len_ok
            && self
                .bytes
                .iter()
                .zip(got)
                .all(|(want, g)| want.is_none_or(|w| w == *g))
    }
}

impl std::fmt::Display for ReplyPattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for b in &self.bytes {
            match b {
                Some(b) => write!(f, "{b:02x}")?,
                None => f.write_str("??")?,
            }
        }
        if self.open_end {
            f.write_str("...")?;
        }
        Ok(())
    }
}

/// Parse hex bytes, with optional spaces (`"06 01 00"` or `"060100"`).
pub fn parse_hex(s: &str) -> Result<Vec<u8>, HexBytesError> {
    let compact: String = s.chars().filter(|c| !c.is_whitespace()).collect();
    hex::decode(&compact).map_err(|hex| HexBytesError::NotHex {
        text: s.to_owned(),
        hex,
    })
}

/// `reply`: every (or any) occurrence of a command is answered, within `within`, with
/// `result`, `data` and `data_len` if given.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ReplyExpect {
    /// The command, by name.
    pub command: String,
    /// For repeated commands: `every` occurrence must hold (default), or `any`.
    #[serde(default)]
    pub occurrence: Option<Occurrence>,
    /// Longest acceptable round trip.
    #[serde(default)]
    pub within: Option<Dur>,
    /// Result code (second reply byte) for ICD requests.
    #[serde(default)]
    pub result: Option<u8>,
    /// The reply bytes as hex (`??` any byte, a final `...` any further bytes).
    #[serde(default)]
    pub data: Option<String>,
    /// Reply length in bytes (the two head bytes included).
    #[serde(default)]
    pub data_len: Option<usize>,
}

/// `no-reply`: every (or any) occurrence of a command goes unanswered.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NoReplyExpect {
    /// The command, by name.
    pub command: String,
    /// For repeated commands: `every` occurrence must hold (default), or `any`.
    #[serde(default)]
    pub occurrence: Option<Occurrence>,
}

/// The command must exist.
fn known_command(command: &str, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
    let _ = command_named(command, cx, err);
}

/// The `[[commands]]` entry an expectation's `command` names (`name`, or `commands[i]`);
/// `err("command", ...)` listing the names when there is none.
pub(crate) fn command_named<'a>(
    command: &str,
    cx: &ExpectCx<'a>,
    err: &mut dyn FnMut(&str, String),
) -> Option<&'a CommandSpec> {
    let names = names(cx.scenario);
    let found = names
        .iter()
        .position(|n| n == command)
        .and_then(|i| cx.scenario.commands.get(i));
    if found.is_none() {
        err(
            "command",
            format!(
                "no command is named `{command}` (commands: {})",
                names.join(", ")
            ),
        );
    }
    found
}

impl ExpectKind for ReplyExpect {
    const NAME: &'static str = "reply";
    const ABOUT: &'static str =
        "the command is answered (within `within`, with `result` and `data` if given)";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        known_command(&self.command, cx, err);
        if let Some(d) = &self.data
            && let Err(e) = ReplyPattern::parse(d)
        {
            err("data", e.to_string());
        }
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        judge(cx.report, &self.command, self.occurrence, |o, t| {
            reply_problem(o, t, self)
        })
    }

    fn watch(&self, _cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        let x = self.clone();
        Some(Box::new(CommandWatch::new(
            &self.command,
            self.occurrence,
            move |o, t| reply_problem(o, t, &x),
        )))
    }

    fn describe(&self) -> String {
        format!("reply to {}", self.command)
    }
}

impl ExpectKind for NoReplyExpect {
    const NAME: &'static str = "no-reply";
    const ABOUT: &'static str = "the command is not answered";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        known_command(&self.command, cx, err);
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        judge(cx.report, &self.command, self.occurrence, no_reply_problem)
    }

    fn watch(&self, _cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        Some(Box::new(CommandWatch::new(
            &self.command,
            self.occurrence,
            no_reply_problem,
        )))
    }

    fn describe(&self) -> String {
        format!("no reply to {}", self.command)
    }
}

/// Why one occurrence fails a `no-reply` check, or `None` if it passes.
fn no_reply_problem(outcome: &Outcome, timeout: Duration) -> Option<String> {
    match outcome {
        Outcome::Reply { data, rtt } => Some(format!(
            "answered after {}: {}",
            secs(*rtt),
            hex::encode(data)
        )),
        Outcome::Unfinished => Some(unfinished(timeout)),
        _ => None,
    }
}

/// Why one occurrence of a command (its outcome, its timeout) fails a check (`None`: it
/// held).
type Problem = dyn Fn(&Outcome, Duration) -> Option<String> + Send;

/// A command's occurrences judged one by one, in any order: each comes with when it was
/// sent and a number that orders those sent at the same time (the order their outcomes
/// came in).
#[derive(Debug, Clone, Default)]
struct OccurrenceTally {
    n: usize,
    problems: usize,
    /// The first failing occurrence by (sent, order), and its problem.
    first: Option<((SimTime, u64), String)>,
    /// The last failing one.
    last: Option<((SimTime, u64), String)>,
}

impl OccurrenceTally {
    fn add(&mut self, sent: SimTime, order: u64, problem: Option<String>) {
        self.n += 1;
        let Some(p) = problem else {
            return;
        };
        self.problems += 1;
        let key = (sent, order);
        if self.first.as_ref().is_none_or(|(k, _)| key < *k) {
            self.first = Some((key, p.clone()));
        }
        if self.last.as_ref().is_none_or(|(k, _)| key > *k) {
            self.last = Some((key, p));
        }
    }

    /// Every (or any) occurrence of `command` held; `end` is the run's end.
    fn verdict(&self, command: &str, occurrence: Option<Occurrence>, end: SimTime) -> Judgement {
        let n = self.n;
        if n == 0 {
            return Judgement::fail(
                end,
                format!("command `{command}` was never sent before the end of the run"),
            );
        }
        match occurrence.unwrap_or(Occurrence::Every) {
            Occurrence::Every => match &self.first {
                Some(((t, _), p)) => Judgement::fail(
                    *t,
                    format!(
                        "{} of {n} occurrences failed; first, sent at {t}: {p}",
                        self.problems
                    ),
                ),
                None => Judgement::pass(end, format!("{n} of {n} occurrences held")),
            },
            Occurrence::Any => match &self.last {
                Some(((t, _), p)) if self.problems == n => Judgement::fail(
                    *t,
                    format!("none of {n} occurrences held; last, sent at {t}: {p}"),
                ),
                _ => Judgement::pass(
                    end,
                    format!("{} of {n} occurrences held", n - self.problems),
                ),
            },
        }
    }
}

/// Judge every occurrence of `command` in the report's results with `problem`.
fn judge(
    report: &RunReport,
    command: &str,
    occurrence: Option<Occurrence>,
    problem: impl Fn(&Outcome, Duration) -> Option<String>,
) -> Judgement {
    let mut tally = OccurrenceTally::default();
    for (i, r) in report.results.iter().enumerate() {
        if r.request.label == command {
            tally.add(r.sent, i as u64, problem(&r.outcome, r.request.timeout));
        }
    }
    tally.verdict(command, occurrence, report.sim_time)
}

/// A `reply` or `no-reply` expectation judged as the run goes, from the command's events:
/// its outcomes are not kept. A request sent and without an outcome at the end is
/// unfinished, as the station reports it.
struct CommandWatch {
    command: String,
    occurrence: Option<Occurrence>,
    problem: Box<Problem>,
    tally: OccurrenceTally,
    /// Sent and waiting for an outcome: (sent, send order) -> timeout.
    waiting: BTreeMap<(SimTime, u64), Duration>,
    sends: u64,
    outcomes: u64,
}

impl CommandWatch {
    fn new(
        command: &str,
        occurrence: Option<Occurrence>,
        problem: impl Fn(&Outcome, Duration) -> Option<String> + Send + 'static,
    ) -> CommandWatch {
        CommandWatch {
            command: command.to_owned(),
            occurrence,
            problem: Box::new(problem),
            tally: OccurrenceTally::default(),
            waiting: BTreeMap::new(),
            sends: 0,
            outcomes: 0,
        }
    }
}

impl Watch for CommandWatch {
    fn kinds(&self) -> Kinds {
        Kinds::of(&[EventKind::Command, EventKind::CommandResult])
    }

    fn observe(&mut self, ev: &RunEvent) {
        match ev {
            RunEvent::Command {
                t, name, timeout, ..
            } if *name == self.command => {
                self.waiting.insert((*t, self.sends), *timeout);
                self.sends += 1;
            }
            RunEvent::CommandResult(r) if r.name == self.command => {
                let twin_core::events::CommandResult {
                    reply,
                    rtt_ns,
                    sent,
                    failed,
                    ..
                } = &**r;
                // The oldest request sent then: those sent at one time are alike.
                let timeout = if failed.is_some() {
                    None
                } else {
                    self.waiting
                        .range((*sent, 0)..=(*sent, u64::MAX))
                        .next()
                        .map(|(k, _)| *k)
                        .and_then(|k| self.waiting.remove(&k))
                };
                let outcome = Outcome::of_result(reply.as_deref(), *rtt_ns, failed.as_deref());
                let timeout = timeout.unwrap_or_default();
                let p = (self.problem)(&outcome, timeout);
                self.tally.add(*sent, self.outcomes, p);
                self.outcomes += 1;
            }
            _ => {}
        }
    }

    fn judge(&self, cx: &CheckCx<'_>) -> Judgement {
        let mut tally = self.tally.clone();
        for (i, (&(sent, _), &timeout)) in self.waiting.iter().enumerate() {
            let p = (self.problem)(&Outcome::Unfinished, timeout);
            tally.add(sent, self.outcomes + i as u64, p);
        }
        tally.verdict(&self.command, self.occurrence, cx.report.sim_time)
    }
}

fn secs(d: std::time::Duration) -> String {
    format!("{:.3} s", d.as_secs_f64())
}

/// Why one occurrence (its outcome, its timeout) fails a reply check, or `None` if it
/// passes.
fn reply_problem(outcome: &Outcome, timeout: Duration, x: &ReplyExpect) -> Option<String> {
    let within = x.within.map(|d| d.0);
    let result = x.result;
    let data = x.data.as_deref().and_then(|d| ReplyPattern::parse(d).ok());
    let data_len = x.data_len;
    match outcome {
        Outcome::Timeout => Some(format!("no reply within the {} timeout", secs(timeout))),
        Outcome::SendFailed(e) => Some(format!("not sent: {e}")),
        Outcome::Unfinished => Some(unfinished(timeout)),
        Outcome::Reply { data: got, rtt } => {
            if let Some(w) = within
                && *rtt > w
            {
                return Some(format!("reply after {} (limit {})", secs(*rtt), secs(w)));
            }
            if let Some(code) = result
                && got.get(1) != Some(&code)
            {
                return Some(format!(
                    "result code {} (expected {code}), reply {}",
                    got.get(1).map_or("missing".to_owned(), u8::to_string),
                    hex::encode(got)
                ));
            }
            if let Some(want) = &data
                && !want.matches(got)
            {
                return Some(format!("reply {} (expected {want})", hex::encode(got)));
            }
            if let Some(n) = data_len
                && got.len() != n
            {
                return Some(format!("reply of {} bytes (expected {n})", got.len()));
            }
            None
        }
    }
}

/// Why a request the run ended on is no verdict either way.
fn unfinished(timeout: Duration) -> String {
    format!(
        "sent, but the run ended before its reply or its {} timeout",
        secs(timeout)
    )
}

// What a snapshot saves (docs/snapshots.md): the tally so far.
snap::fields!(OccurrenceTally {
    n,
    problems,
    first,
    last
});
snap::fields!(CommandWatch {
    tally,
    waiting,
    sends,
    outcomes;
    skip command, occurrence, problem
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::{HexBytesError, ReplyPattern, parse_hex};

    #[test]
    fn a_reply_pattern_takes_any_bytes_and_an_open_end() {
        let p = ReplyPattern::parse("01 01 ?? 01 ...").unwrap();
        assert!(p.matches(&[1, 1, 2, 1]));
        assert!(p.matches(&[1, 1, 9, 1, 7, 7]));
        assert!(!p.matches(&[1, 1, 2, 0, 7]));
        assert!(!p.matches(&[1, 1, 2]));
        assert_eq!(p.to_string(), "0101??01...");
        let exact = ReplyPattern::parse("ff00").unwrap();
        assert!(exact.matches(&[0xff, 0]) && !exact.matches(&[0xff, 0, 0]));
        for bad in ["0", "zz", "01 0?", "... 01", "+f"] {
            assert!(ReplyPattern::parse(bad).is_err(), "{bad}");
        }
        let e = ReplyPattern::parse("01 0?").unwrap_err();
        assert_eq!(
            e,
            HexBytesError::NotAByte {
                text: "01 0?".into(),
                pair: "0?".into()
            }
        );
        assert_eq!(
            e.to_string(),
            "`01 0?` is not hex bytes: `0?` (use ?? for any byte)"
        );
        assert_eq!(
            ReplyPattern::parse("0").unwrap_err().to_string(),
            "`0` is not hex bytes: an odd number of digits"
        );
        assert_eq!(
            ReplyPattern::parse("\u{45d}").unwrap_err(),
            HexBytesError::NotAscii {
                text: "\u{45d}".into(),
                found: '\u{45d}'
            }
        );
    }

    #[test]
    fn hex_bytes_take_spaces_and_name_the_text_when_wrong() {
        assert_eq!(parse_hex("06 01 00").unwrap(), vec![6, 1, 0]);
        let e = parse_hex("06 0g").unwrap_err();
        assert!(matches!(&e, HexBytesError::NotHex { text, .. } if text == "06 0g"));
        assert_eq!(
            e.to_string(),
            "`06 0g` is not hex bytes: Invalid character 'g' at position 3"
        );
    }

    /// A character of more than one byte is an error, not a panic (the fuzzer's
    /// scenario_parser found `data = "... f\u{45d}0506 ..."` slicing inside the character).
    #[test]
    fn a_reply_pattern_with_a_multibyte_character_is_an_error() {
        for bad in ["f\u{45d}0506b9", "\u{45d}", "0\u{e9}", "01 \u{1f600} ..."] {
            let e = ReplyPattern::parse(bad).unwrap_err();
            assert!(e.to_string().contains("not hex bytes"), "{bad}: {e}");
        }
    }
}
