//! The payload controller's sessions and the simulated payloads in a scenario: the `[pc]`
//! table, the `[[payload]]` tables, their validation and compilation into the node
//! configurations, and what a run reports about them (session ends, downlinked bytes per
//! session, drops by reason, the accounting of every payload byte) for the `session`,
//! `downlink` and `accounting` expectations.
//!
//! See docs/scenarios.md ("The PC and the payloads") and docs/payload-guide.md.

use std::collections::BTreeMap;
use std::time::Duration;

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Grade, Judgement, Occurrence, bounds};
use twin_scenario::scenario::{PathStep, Scenario};

pub use twin_scenario::pc::*;

/// Why a text is not a payload behaviour; each names the text (trimmed).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum BehaviourError {
    /// A behaviour that takes an argument, without it.
    #[error("behaviour `{text}`: {keyword} needs a {what}, as {keyword}:<{what}>")]
    NeedsArgument {
        /// The text.
        text: String,
        /// The behaviour's name, in lower case.
        keyword: String,
        /// What it takes (`duration`, `count`).
        what: &'static str,
    },
    /// `slow:` with no duration. The duration's message is part of this one's, so it is
    /// not also its `source()`.
    #[error("behaviour `{text}`: {duration}")]
    NotADuration {
        /// The text.
        text: String,
        /// Why the argument is not a duration.
        duration: twin_core::duration::DurationError,
    },
    /// `silent-for:` with no whole number.
    #[error("behaviour `{text}`: the count must be a whole number")]
    CountNotWhole {
        /// The text.
        text: String,
    },
    /// `oversize:` with no count of 1-255.
    #[error("behaviour `{text}`: the extra bytes must be 1-255")]
    ExtraBytes {
        /// The text.
        text: String,
    },
    /// No such behaviour.
    #[error(
        "unknown behaviour `{text}`: expected normal, no-ack, wrong-echo, slow:<duration>, \
         silent-for:<polls>, silent, oversize:<bytes>, garbage or zero-length"
    )]
    Unknown {
        /// The text.
        text: String,
    },
    /// An argument to a behaviour that takes none.
    #[error("behaviour `{text}`: {keyword} takes no argument")]
    TakesNoArgument {
        /// The text.
        text: String,
        /// The behaviour's name, in lower case.
        keyword: String,
    },
}

/// Parse a payload behaviour name (see [`PayloadSpec::behaviour`]).
pub fn parse_behaviour(s: &str) -> Result<nodes_payload::Behaviour, BehaviourError> {
    use nodes_payload::Behaviour as B;
    let t = s.trim();
    let text = || t.to_owned();
    let (kw, arg) = match t.split_once(':') {
        Some((k, a)) => (k.trim().to_ascii_lowercase(), Some(a.trim())),
        None => (t.to_ascii_lowercase(), None),
    };
    let need = |what: &'static str| {
        arg.filter(|a| !a.is_empty())
            .ok_or_else(|| BehaviourError::NeedsArgument {
                text: text(),
                keyword: kw.clone(),
                what,
            })
    };
    let b = match kw.as_str() {
        "normal" => B::Normal,
        "no-ack" => B::NoAck,
        "wrong-echo" => B::WrongEcho,
        "silent" => B::Silent,
        "garbage" => B::Garbage,
        "zero-length" => B::ZeroLength,
        "slow" => B::Slow {
            extra: twin_core::duration::parse_duration(need("duration")?).map_err(|duration| {
                BehaviourError::NotADuration {
                    text: text(),
                    duration,
                }
            })?,
        },
        "silent-for" => B::SilentFor {
            polls: need("count")?
                .parse()
                .map_err(|_| BehaviourError::CountNotWhole { text: text() })?,
        },
        "oversize" => B::Oversize {
            extra_bytes: need("count")?
                .parse()
                .ok()
                .filter(|n: &u8| *n > 0)
                .ok_or_else(|| BehaviourError::ExtraBytes { text: text() })?,
        },
        _ => return Err(BehaviourError::Unknown { text: text() }),
    };
    if arg.is_some() && !matches!(kw.as_str(), "slow" | "silent-for" | "oversize") {
        return Err(BehaviourError::TakesNoArgument {
            text: text(),
            keyword: kw,
        });
    }
    Ok(b)
}

fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

/// Check the `[pc]` and `[[payload]]` tables.
pub fn validate(s: &Scenario, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let pc = &s.pc;
    let mut ids = BTreeMap::new();
    let mut served = BTreeMap::new();
    if pc.sessions.len() > 4 {
        err(
            vec![key("pc"), key("sessions")],
            format!(
                "{} sessions: the PC has one per payload, at most 4",
                pc.sessions.len()
            ),
        );
    }
    for (i, x) in pc.sessions.iter().enumerate() {
        let q = |n: &str| vec![key("pc"), key("sessions"), PathStep::Index(i), key(n)];
        if let Some(j) = ids.insert(x.id, i) {
            err(
                q("id"),
                format!("session {} is also pc.sessions[{j}]", x.id),
            );
        }
        if !(12..=15).contains(&x.payload) {
            err(
                q("payload"),
                format!("{} is not a payload address (12-15)", x.payload),
            );
        } else if let Some(j) = served.insert(x.payload, i) {
            err(
                q("payload"),
                format!(
                    "payload {} already has pc.sessions[{j}]: one session per payload",
                    x.payload
                ),
            );
        }
        if x.port.is_some_and(|p| p > 63) {
            err(q("port"), "must be 0-63".into());
        }
        match x.mode {
            SessionModeName::Polling => {
                if x.reply_timeout.is_some_and(|d| d.0.is_zero()) {
                    err(q("reply_timeout"), "must be longer than zero".into());
                }
                if x.buffer_capacity_bytes.is_some() {
                    err(
                        q("buffer_capacity_bytes"),
                        "only for buffering sessions".into(),
                    );
                }
            }
            SessionModeName::Buffering => {
                for f in ["poll_period", "reply_timeout"] {
                    let given = if f == "poll_period" {
                        x.poll_period.is_some()
                    } else {
                        x.reply_timeout.is_some()
                    };
                    if given {
                        err(q(f), "only for polling sessions".into());
                    }
                }
            }
        }
    }
    if pc.sband_rate_bps == Some(0) {
        err(
            vec![key("pc"), key("sband_rate_bps")],
            "must be above zero".into(),
        );
    }
    if pc.sband_frame_data_bytes == Some(0) {
        err(
            vec![key("pc"), key("sband_frame_data_bytes")],
            "must be above zero".into(),
        );
    }
    if let Some(p) = pc.ports {
        for (f, v) in [
            ("control", p.control),
            ("ingest", p.ingest),
            ("telemetry", p.telemetry),
            ("files", p.files),
        ] {
            if v.is_some_and(|v| v > 63) {
                err(vec![key("pc"), key("ports"), key(f)], "must be 0-63".into());
            }
        }
    }
    for (i, e) in pc.events.iter().enumerate() {
        if e.at.0 > s.duration.0 {
            err(
                vec![key("pc"), key("events"), PathStep::Index(i), key("at")],
                "is after the end of the run".into(),
            );
        }
    }
    validate_payloads(s, err);
}

/// The `[[payload]]` tables: addresses of simulated payloads, each once; files, behaviours,
/// pushes.
fn validate_payloads(s: &Scenario, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let mut seen = BTreeMap::new();
    for (i, p) in s.payload.iter().enumerate() {
        let q = |n: &str| vec![key("payload"), PathStep::Index(i), key(n)];
        if !s.network.payloads.contains(&p.addr) {
            err(
                q("addr"),
                format!(
                    "{} is not a simulated payload: add it to [network] payloads {:?}",
                    p.addr, s.network.payloads
                ),
            );
        }
        if let Some(j) = seen.insert(p.addr, i) {
            err(
                q("addr"),
                format!("payload {} is also payload[{j}]", p.addr),
            );
        }
        if p.port.is_some_and(|p| p > 63) {
            err(q("port"), "must be 0-63".into());
        }
        if let Some(f) = &p.file
            && let Err(e) = std::fs::metadata(f)
        {
            err(q("file"), format!("cannot read `{f}`: {e}"));
        }
        if let Some(b) = &p.behaviour
            && let Err(e) = parse_behaviour(b)
        {
            err(q("behaviour"), e.to_string());
        }
        for (k, c) in p.changes.iter().enumerate() {
            if let Err(e) = parse_behaviour(&c.behaviour) {
                err(
                    vec![
                        key("payload"),
                        PathStep::Index(i),
                        key("changes"),
                        PathStep::Index(k),
                        key("behaviour"),
                    ],
                    e.to_string(),
                );
            }
        }
        if let Some(push) = &p.push {
            let r = |n: &str| vec![key("payload"), PathStep::Index(i), key("push"), key(n)];
            if push.rate_bytes_per_s == 0 {
                err(r("rate_bytes_per_s"), "must be above zero".into());
            }
            if push.packet_bytes.is_some_and(|b| !(1..=256).contains(&b)) {
                err(
                    r("packet_bytes"),
                    "must be 1-256 (ICD 3.1.5: at most 256 data bytes per packet)".into(),
                );
            }
            if let (Some(a), Some(b)) = (push.start, push.stop)
                && b <= a
            {
                err(r("stop"), "must be after `start`".into());
            }
        }
    }
}

/// The PC's configuration from the `[pc]` table.
pub fn compile_pc(s: &Scenario) -> nodes_pc::PcConfig {
    use nodes_pc::{PcConfig, PcEvent, SessionMode, SessionSpec, TimedPcEvent};
    let mut c = PcConfig::default();
    let pc = &s.pc;
    if !pc.sessions.is_empty() {
        c.sessions = pc
            .sessions
            .iter()
            .map(|x| {
                let d = SessionSpec::polling(x.id, x.payload);
                SessionSpec {
                    payload_port: x.port.unwrap_or(d.payload_port),
                    mode: match x.mode {
                        SessionModeName::Buffering => SessionMode::Buffering,
                        SessionModeName::Polling => SessionMode::Polling {
                            poll_period: x
                                .poll_period
                                .map_or(nodes_pc::DEFAULT_POLL_PERIOD, |d| d.0),
                            reply_timeout: x
                                .reply_timeout
                                .map_or(nodes_pc::DEFAULT_REPLY_TIMEOUT, |d| d.0),
                        },
                    },
                    buffer_capacity_bytes: x
                        .buffer_capacity_bytes
                        .unwrap_or(d.buffer_capacity_bytes),
                    ..d
                }
            })
            .collect();
    }
    if let Some(r) = pc.sband_rate_bps {
        c.sband.rate_bps = r;
    }
    if let Some(b) = pc.sband_frame_data_bytes {
        c.sband.frame_data_bytes = b;
    }
    if let Some(b) = pc.sband_frame_overhead_bytes {
        c.sband.frame_overhead_bytes = b;
    }
    if let Some(on) = pc.sband_on {
        c.sband.on = on;
    }
    if let Some(p) = pc.ports {
        c.control_port = p.control.unwrap_or(c.control_port);
        c.ingest_port = p.ingest.unwrap_or(c.ingest_port);
        c.telemetry_port = p.telemetry.unwrap_or(c.telemetry_port);
        c.files_port = p.files.unwrap_or(c.files_port);
    }
    c.timeline = pc
        .events
        .iter()
        .map(|e| TimedPcEvent {
            at: SimTime::ZERO + e.at.0,
            event: match e.sband {
                SbandEventName::Fail => PcEvent::SbandFail,
                SbandEventName::Restore => PcEvent::SbandRestore,
                SbandEventName::Off => PcEvent::SbandOff,
                SbandEventName::On => PcEvent::SbandOn,
            },
        })
        .collect();
    c.timeline.sort_by_key(|e| e.at);
    c
}

/// The simulated payloads' configurations, by address (every address of `[network]
/// payloads`; those without a `[[payload]]` table get the defaults).
pub fn compile_payloads(s: &Scenario) -> BTreeMap<u8, nodes_payload::PayloadConfig> {
    use nodes_payload::{Generator, PayloadConfig, PushConfig};
    let mut out = BTreeMap::new();
    for &addr in &s.network.payloads {
        let mut c = PayloadConfig {
            seed: twin_core::seed::mix(s.seed, 0x600 + u64::from(addr)),
            ..PayloadConfig::default()
        };
        if let Some(p) = s.payload.iter().find(|p| p.addr == addr) {
            c.port = p.port.unwrap_or(c.port);
            if let Some(f) = &p.file {
                // Validated readable; a file that vanished since gives an empty generator.
                c.generator = Generator::Bytes(std::fs::read(f).unwrap_or_default().into());
            }
            c.rate_bytes_per_s = p.rate_bytes_per_s;
            if let Some(l) = p.reply_latency {
                c.reply_latency = l.0;
            }
            if let Some(b) = p.behaviour.as_deref().and_then(|b| parse_behaviour(b).ok()) {
                c.behaviour = b;
            }
            c.timeline = p
                .changes
                .iter()
                .filter_map(|x| {
                    parse_behaviour(&x.behaviour)
                        .ok()
                        .map(|b| (SimTime::ZERO + x.at.0, b))
                })
                .collect();
            if let Some(push) = &p.push {
                let d = PushConfig::default();
                c.push = Some(PushConfig {
                    rate_bytes_per_s: push.rate_bytes_per_s,
                    packet_bytes: push.packet_bytes.unwrap_or(d.packet_bytes),
                    start: SimTime::ZERO + push.start.map_or(Duration::ZERO, |d| d.0),
                    stop: push.stop.map(|d| SimTime::ZERO + d.0),
                    ..d
                });
            }
        }
        out.insert(addr, c);
    }
    out
}

/// The session ids the PC will have: `[[pc.sessions]]`, or the defaults.
pub fn session_ids(s: &Scenario) -> Vec<(u8, u8)> {
    if s.pc.sessions.is_empty() {
        nodes_pc::PcConfig::default()
            .sessions
            .iter()
            .map(|x| (x.session_id, x.payload_addr))
            .collect()
    } else {
        s.pc.sessions.iter().map(|x| (x.id, x.payload)).collect()
    }
}

pub use twin_report::observe::sessions::*;

/// `session`: every (or any) run of a PC session ended with `session_result`, counting
/// `min`..=`max` packets.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SessionExpect {
    /// The session id.
    pub session: u8,
    /// The result every (or any) run ended with: `done`, `aborted`, `no-ack`,
    /// `s-band-failure`.
    #[serde(default)]
    pub session_result: Option<SessionResultName>,
    /// `every` run (default) or `any`.
    #[serde(default)]
    pub occurrence: Option<Occurrence>,
    /// Fewest packets counted.
    #[serde(default)]
    pub min: Option<u64>,
    /// Most packets counted.
    #[serde(default)]
    pub max: Option<u64>,
}

/// `downlink`: a PC session's bytes at the ground over the whole run, `min`..=`max`, and
/// with `intact` the payload's counter frames undamaged (`true`: none missing either).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DownlinkExpect {
    /// The session id.
    pub session: u8,
    /// `false`: no damaged frame; `true`: also no missing sequence number.
    #[serde(default)]
    pub intact: Option<bool>,
    /// Fewest bytes.
    #[serde(default)]
    pub min: Option<u64>,
    /// Most bytes.
    #[serde(default)]
    pub max: Option<u64>,
}

/// `accounting`: every byte a payload produced was downlinked, dropped with a reason, or is
/// still held by the PC at the end (at most `max` dropped, if given).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct AccountingExpect {
    /// The payload (default every simulated payload).
    #[serde(default)]
    pub payload: Option<u8>,
    /// Most bytes dropped.
    #[serde(default)]
    pub max: Option<u64>,
}

/// The session must be one of the PC's.
fn known_session(id: u8, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
    let ids = session_ids(cx.scenario);
    if !ids.iter().any(|(i, _)| *i == id) {
        err(
            "session",
            format!(
                "the PC has no session {id} (sessions: {})",
                ids.iter()
                    .map(|(i, a)| format!("{i} for payload {a}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        );
    }
}

fn min_max(min: Option<u64>, max: Option<u64>, err: &mut dyn FnMut(&str, String)) {
    if let (Some(a), Some(b)) = (min, max)
        && a > b
    {
        err("min", format!("min {a} is above max {b}"));
    }
}

impl ExpectKind for SessionExpect {
    const NAME: &'static str = "session";
    const ABOUT: &'static str = "a PC session's runs ended with a result (and a packet count)";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        known_session(self.session, cx, err);
        if self.session_result.is_none() && self.min.is_none() && self.max.is_none() {
            err(
                "kind",
                "a `session` expectation needs `session_result`, `min` or `max`".into(),
            );
        }
        min_max(self.min, self.max, err);
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let report = cx.report;
        let r = &report.sessions;
        let end = report.sim_time;
        let session = &self.session;
        let result = &self.session_result;
        let occurrence = &self.occurrence.unwrap_or(Occurrence::Every);
        let (min, max) = (&self.min, &self.max);

        let ended: Vec<(SimTime, RunEnd, u32)> = r
            .runs
            .iter()
            .filter(|x| x.session == *session)
            .filter_map(|x| x.ended)
            .collect();
        if ended.is_empty() {
            let started = r.runs.iter().any(|x| x.session == *session);
            return Judgement::fail(
                end,
                format!(
                    "session {session} never ended{}",
                    if started {
                        " (still ACTIVE at the end of the run)"
                    } else {
                        " (it never started)"
                    }
                ),
            );
        }
        let problem = |(_, end, packets): &(SimTime, RunEnd, u32)| -> Option<String> {
            if let Some(want) = result
                && !want.matches(*end)
            {
                return Some(format!("{end}, expected {}", want.as_str()));
            }
            let p = u64::from(*packets);
            if min.is_some_and(|m| p < m) || max.is_some_and(|m| p > m) {
                return Some(format!("{p} packets, expected {}", bounds(*min, *max)));
            }
            None
        };
        // Every run, each with what it is compared with when it fails: "run 1 lost (power)
        // at 30.000s after 14 packets: lost (power), expected done; run 2 done at ...".
        let runs = ended
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let what = format!("run {} {} at {} after {} packets", i + 1, e.1, e.0, e.2);
                match problem(e) {
                    Some(p) => format!("{what} ({p})"),
                    None => what,
                }
            })
            .collect::<Vec<_>>()
            .join("; ");
        let bad: Vec<SimTime> = ended
            .iter()
            .filter(|e| problem(e).is_some())
            .map(|e| e.0)
            .collect();
        let n = ended.len();
        let held = n - bad.len();
        match occurrence {
            Occurrence::Every => match bad.first() {
                Some(t) => Judgement::fail(*t, format!("{held} of {n} runs held: {runs}")),
                None => Judgement::pass(ended[n - 1].0, format!("{n} of {n} runs held: {runs}")),
            },
            Occurrence::Any => match ended.iter().find(|e| problem(e).is_none()) {
                Some(e) => Judgement::pass(e.0, format!("{held} of {n} runs held: {runs}")),
                None => Judgement::fail(ended[n - 1].0, format!("none of {n} runs held: {runs}")),
            },
        }
    }

    fn describe(&self) -> String {
        format!("session {}", self.session)
    }
}

impl ExpectKind for DownlinkExpect {
    const NAME: &'static str = "downlink";
    const ABOUT: &'static str =
        "a PC session downlinked `min`..`max` bytes over the run (intact, if asked)";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        known_session(self.session, cx, err);
        if self.intact.is_none() && self.min.is_none() && self.max.is_none() {
            err(
                "kind",
                "a `downlink` expectation needs `min`, `max` or `intact`".into(),
            );
        }
        min_max(self.min, self.max, err);
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let report = cx.report;
        let r = &report.sessions;
        let end = report.sim_time;
        let session = &self.session;
        let (min, max, intact) = (&self.min, &self.max, &self.intact);

        // Counted, not gathered: a copy of every byte would double the peak memory.
        let n: u64 = r
            .runs
            .iter()
            .filter(|x| x.session == *session)
            .map(|x| x.len)
            .sum();
        let mut why = Vec::new();
        if min.is_some_and(|m| n < m) || max.is_some_and(|m| n > m) {
            why.push(format!("expected {} bytes", bounds(*min, *max)));
        }
        let mut seen = format!("session {session}: {n} bytes downlinked");
        if let Some(strict) = intact {
            // Each run is checked on its own (a run's stream ends where the next one's
            // begins only if nothing was lost between them); the seqs lost between
            // runs count as missing. A frame cut by a run's end is whole when that
            // run's tail and the next run's head join into it.
            let (mut ok, mut bad, mut missing) = (0u64, 0u64, 0u64);
            let (mut first, mut last) = (None, None::<u32>);
            let mut examples = Vec::new();
            let mut tail: Vec<u8> = Vec::new();
            // Whether `tail` holds all its bytes: a run's lead bytes beyond what its
            // checker keeps (more than a frame) can never join two runs anyway.
            let mut tail_whole = true;
            for run in r.runs.iter().filter(|x| x.session == *session) {
                let end = run.stream.end();
                let c = &end.check;
                if c.first_seq.is_none() && c.frames_bad == 0 {
                    // No whole frame: all of it (its lead and its tail) belongs to the
                    // frame the runs around it cut (a short run between two others).
                    tail.extend_from_slice(&end.lead);
                    tail.extend_from_slice(end.tail);
                    tail_whole &= end.lead_whole();
                    continue;
                }
                ok += c.frames_ok;
                bad += c.frames_bad;
                missing += c.missing_count;
                examples.extend(c.missing_seqs.iter().take(8).copied());
                if let (Some(prev), Some(a)) = (last, c.first_seq) {
                    // Whole when the bytes between the runs' whole frames are exactly
                    // the frames in between (one cut by a run's end, or more when a short
                    // run in the middle held no whole frame).
                    let gap = u64::from(a.saturating_sub(prev).saturating_sub(1));
                    let spanned = gap > 0 && tail_whole && end.lead_whole() && {
                        let joined = nodes_payload::check_counter_stream(
                            &[tail.as_slice(), end.lead.as_slice()].concat(),
                        );
                        joined.frames_ok == gap
                            && joined.first_seq == Some(prev.wrapping_add(1))
                            && joined.missing_count == 0
                            && joined.lead_bytes == 0
                            && joined.tail_bytes == 0
                            && joined.skipped_bytes == 0
                    };
                    if spanned {
                        ok += gap;
                    } else if gap > 0 {
                        missing += gap;
                        examples.push(prev + 1);
                    }
                }
                tail = end.tail.to_vec();
                tail_whole = true;
                first = first.or(c.first_seq);
                last = c.last_seq.or(last);
            }
            seen.push_str(&format!(
                "; {ok} frames intact, {bad} damaged, {missing} missing"
            ));
            if let (Some(a), Some(b)) = (first, last) {
                seen.push_str(&format!(" (seq {a}..={b})"));
            }
            if bad > 0 {
                why.push("damaged frames".to_owned());
            }
            if *strict && missing > 0 {
                why.push(format!(
                    "missing seqs, from {:?}",
                    &examples[..examples.len().min(8)]
                ));
            }
            if ok == 0 {
                why.push("no intact frame".to_owned());
            }
        }
        if why.is_empty() {
            Judgement::pass(end, seen)
        } else {
            Judgement::fail(end, format!("{seen} ({})", why.join("; ")))
        }
    }

    fn describe(&self) -> String {
        format!("downlink of session {}", self.session)
    }
}

impl ExpectKind for AccountingExpect {
    const NAME: &'static str = "accounting";
    const ABOUT: &'static str =
        "every byte a payload produced was downlinked, dropped with a reason, or is held";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        let s = cx.scenario;
        if let Some(a) = self.payload
            && !s.network.payloads.contains(&a)
        {
            err(
                "payload",
                format!("{a} is not a simulated payload ({:?})", s.network.payloads),
            );
        }
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let report = cx.report;
        let r = &report.sessions;
        let end = report.sim_time;
        let (payload, max) = (&self.payload, &self.max);

        let Some(held) = &r.held else {
            return Judgement::fail(end, "the PC gave no final accounting (was it running?)");
        };
        let addrs: Vec<u8> = match payload {
            Some(a) => vec![*a],
            None => r.produced.keys().copied().collect(),
        };
        let mut lines = Vec::new();
        let mut ok = r.pc_balanced != Some(false);
        if !ok {
            lines.push("the PC's own ledgers do not balance".to_owned());
        }
        for a in addrs {
            let produced = r.produced.get(&a).copied().unwrap_or(0);
            let down = r.downlinked.get(&a).copied().unwrap_or(0);
            let dropped = r.dropped_total(a);
            let h = held.get(&a).copied().unwrap_or(0);
            let missing = produced as i128 - (down + dropped + h) as i128;
            let reasons: Vec<String> = r
                .dropped
                .iter()
                .filter(|((x, _), _)| *x == a)
                .map(|((_, why), n)| format!("{why} {n}"))
                .collect();
            let mut line = format!(
                "payload {a}: produced {produced} = downlinked {down} + dropped {dropped}{} + held {h}",
                if reasons.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", reasons.join(", "))
                }
            );
            if missing != 0 {
                ok = false;
                line.push_str(&format!(" -- {missing} bytes unaccounted for"));
            }
            if max.is_some_and(|m| dropped > m) {
                ok = false;
                line.push_str(&format!(" -- more than {} dropped", max.unwrap_or(0)));
            }
            lines.push(line);
        }
        Judgement::new(Grade::of(ok), end, lines.join("; "))
    }

    fn describe(&self) -> String {
        match self.payload {
            Some(p) => format!("accounting of payload {p}"),
            None => "accounting".to_owned(),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use nodes_payload::Behaviour as B;
    use twin_core::events::RunEvent;

    /// Whether `k` held on `report` in the default network, and what it observed.
    fn check<K: ExpectKind>(k: &K, report: &twin_report::RunReport) -> (bool, String) {
        let j = k.check(&CheckCx {
            report,
            net: &twin_core::network::NetworkSpec::default_m6p(),
        });
        (j.passed(), j.detail)
    }

    #[test]
    fn behaviour_names() {
        let ok = [
            ("normal", B::Normal),
            ("No-Ack", B::NoAck),
            ("wrong-echo", B::WrongEcho),
            ("silent", B::Silent),
            ("garbage", B::Garbage),
            ("zero-length", B::ZeroLength),
            (
                "slow:250ms",
                B::Slow {
                    extra: Duration::from_millis(250),
                },
            ),
            ("silent-for: 3", B::SilentFor { polls: 3 }),
            ("oversize:10", B::Oversize { extra_bytes: 10 }),
        ];
        for (s, want) in ok {
            assert_eq!(parse_behaviour(s), Ok(want), "{s}");
        }
        for (s, part) in [
            ("slow", "needs a duration"),
            ("slow:fast", "not a duration"),
            ("silent-for:-1", "whole number"),
            ("oversize:0", "1-255"),
            ("oversize:256", "1-255"),
            ("normal:1", "takes no argument"),
            ("grumpy", "unknown behaviour"),
        ] {
            let e = parse_behaviour(s).unwrap_err().to_string();
            assert!(e.contains(part), "{s}: {e}");
        }
        assert_eq!(
            parse_behaviour(" Oversize:0 "),
            Err(BehaviourError::ExtraBytes {
                text: "Oversize:0".into()
            })
        );
        assert_eq!(
            parse_behaviour("slow").unwrap_err().to_string(),
            "behaviour `slow`: slow needs a duration, as slow:<duration>"
        );
        assert_eq!(
            parse_behaviour("normal:1").unwrap_err().to_string(),
            "behaviour `normal:1`: normal takes no argument"
        );
    }

    fn report_of(events: Vec<RunEvent>) -> twin_report::RunReport {
        let mut r = SessionsReport::default();
        for e in &events {
            r.observe(e);
        }
        twin_report::RunReport {
            sim_time: SimTime::from_secs(100),
            sessions: r,
            ..Default::default()
        }
    }

    fn produced(addr: u8, bytes: u64) -> RunEvent {
        RunEvent::Payload {
            addr,
            out: nodes_payload::PayloadOutput::Produced {
                t: SimTime::from_secs(1),
                bytes,
                how: nodes_payload::How::PollReply,
            },
        }
    }

    fn pc(o: nodes_pc::PcOutput) -> RunEvent {
        RunEvent::Pc(Box::new(o))
    }

    /// The ground sink's files grow with each downlink, hold exactly the report's bytes per
    /// run, and exist before the run ends (an operator follows them while it runs).
    #[test]
    fn downlink_files_grow_as_the_bytes_arrive_and_match_the_report() {
        let dir = std::env::temp_dir().join(format!("m6p-dl-files-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let t = SimTime::from_secs(1);
        let down = |s: u8, b: &[u8]| {
            pc(nodes_pc::PcOutput::Downlinked {
                t,
                session_id: s,
                payload_addr: 12,
                bytes: b.to_vec(),
            })
        };
        let end = |s: u8| {
            pc(nodes_pc::PcOutput::SessionEnded {
                t,
                session_id: s,
                result: nodes_pc::SessionResult::Done,
                packets: 1,
            })
        };
        let events = vec![
            pc(nodes_pc::PcOutput::SessionStarted {
                t,
                session_id: 1,
                payload_addr: 12,
            }),
            down(1, b"abc"),
            down(1, b"de"),
            end(1),
            // Bytes still queued for S-band after the end belong to that run.
            down(1, b"f"),
            pc(nodes_pc::PcOutput::SessionStarted {
                t,
                session_id: 1,
                payload_addr: 12,
            }),
            down(1, b"xyz"),
            // An end without a start is a run of its own, as in the report.
            end(2),
        ];
        let mut files = DownlinkFiles::new(&dir);
        let run1 = dir.join("session-1-run1.bin");
        for (i, e) in events.iter().enumerate() {
            files.observe(e);
            if i == 2 {
                assert_eq!(std::fs::read(&run1).unwrap(), b"abcde", "before the end");
            }
        }
        let report = report_of(events);
        assert_eq!(files.files.len(), report.sessions.runs.len());
        let mut runs = report.sessions.runs.clone();
        runs.sort_by_key(|r| r.session);
        let names = [
            "session-1-run1.bin",
            "session-1-run2.bin",
            "session-2-run1.bin",
        ];
        for (r, name) in runs.iter().zip(names) {
            assert_eq!(std::fs::read(dir.join(name)).unwrap(), r.bytes, "{name}");
        }
        assert_eq!(files.errors, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn final_held(addr: u8, held: u64) -> RunEvent {
        let ledger = nodes_pc::Ledger {
            received: held,
            buffered_now: held,
            ..Default::default()
        };
        pc(nodes_pc::PcOutput::Final {
            t: SimTime::from_secs(100),
            accounting: nodes_pc::Accounting {
                sessions: vec![nodes_pc::SessionAccounting {
                    session_id: 1,
                    payload_addr: addr,
                    bytes: ledger,
                }],
                unattributed: Default::default(),
            },
        })
    }

    /// A POLL reply that reached the PC after the PC forgot its request is dropped by CSP
    /// (`unbound port`): its data counts as dropped with that reason, and the books
    /// balance. Found by the pc-sessions campaign (a 1.5 s delay on the payload bus left
    /// 34,100 bytes unaccounted for); before, such bytes were in no ledger.
    #[test]
    fn a_reply_the_pc_forgot_is_dropped_with_its_reason() {
        let t = SimTime::from_secs(2);
        let stream = nodes_payload::counter_stream(12, 0, 500);
        let late = |src: u8, sport: u8| RunEvent::PacketDropped {
            log: Box::new(RunEvent::Log {
                t,
                source: "PC".into(),
                level: twin_core::events::Level::Debug,
                message: "drop (unbound port)".into(),
            }),
            node: "PC".into(),
            reason: csp::drop::DropReason::UnboundPort,
            packet: csp::node::DroppedPacket {
                cfp: None,
                header: csp::Header::new(src, 6, 40, sport),
                data_len: 2 + 100,
            },
        };
        let events = vec![
            pc(nodes_pc::PcOutput::SessionStarted {
                t,
                session_id: 1,
                payload_addr: 12,
            }),
            produced(12, 600),
            pc(nodes_pc::PcOutput::Downlinked {
                t,
                session_id: 1,
                payload_addr: 12,
                bytes: stream,
            }),
            late(12, nodes_payload::wire::PORT),
            // Another port's packet, or another node's, is not a payload reply.
            late(12, 11),
            late(3, nodes_payload::wire::PORT),
            final_held(12, 0),
        ];
        let report = report_of(events);
        let acc = AccountingExpect {
            payload: Some(12),
            max: None,
        };
        let (ok, seen) = check(&acc, &report);
        assert!(ok, "{seen}");
        assert!(seen.contains(&format!("{LATE_AT_CSP} 100")), "{seen}");
    }

    #[test]
    fn accounting_finds_bytes_that_went_nowhere() {
        let t = SimTime::from_secs(2);
        let stream = nodes_payload::counter_stream(12, 0, 500);
        let events = vec![
            pc(nodes_pc::PcOutput::SessionStarted {
                t,
                session_id: 1,
                payload_addr: 12,
            }),
            produced(12, 600),
            pc(nodes_pc::PcOutput::Downlinked {
                t,
                session_id: 1,
                payload_addr: 12,
                bytes: stream.clone(),
            }),
            pc(nodes_pc::PcOutput::Dropped {
                t,
                session_id: Some(1),
                payload_addr: 12,
                reason: nodes_pc::DropReason::Oversize,
                bytes: 40,
            }),
            final_held(12, 50),
        ];
        let report = report_of(events);
        let acc = AccountingExpect {
            payload: Some(12),
            max: None,
        };
        let (ok, seen) = check(&acc, &report);
        assert!(!ok, "{seen}");
        assert!(seen.contains("10 bytes unaccounted for"), "{seen}");
        assert!(seen.contains("oversize 40"), "{seen}");
        // The same, with the 10 bytes dropped for a reason: it balances; max bounds drops.
        let mut events2 = vec![pc(nodes_pc::PcOutput::Dropped {
            t,
            session_id: Some(1),
            payload_addr: 12,
            reason: nodes_pc::DropReason::Late,
            bytes: 10,
        })];
        events2.extend([
            pc(nodes_pc::PcOutput::SessionStarted {
                t,
                session_id: 1,
                payload_addr: 12,
            }),
            produced(12, 600),
            pc(nodes_pc::PcOutput::Downlinked {
                t,
                session_id: 1,
                payload_addr: 12,
                bytes: stream,
            }),
            pc(nodes_pc::PcOutput::Dropped {
                t,
                session_id: Some(1),
                payload_addr: 12,
                reason: nodes_pc::DropReason::Oversize,
                bytes: 40,
            }),
            final_held(12, 50),
        ]);
        let report = report_of(events2);
        assert!(check(&acc, &report).0, "{}", check(&acc, &report).1);
        let strict = AccountingExpect {
            payload: Some(12),
            max: Some(49),
        };
        assert!(!check(&strict, &report).0);
        // The downlinked counter stream is intact.
        let dl = DownlinkExpect {
            session: 1,
            min: Some(500),
            max: Some(500),
            intact: Some(true),
        };
        let (ok, seen) = check(&dl, &report);
        assert!(ok, "{seen}");
    }

    #[test]
    fn downlink_with_a_hole_is_not_intact_and_a_damaged_byte_is_damage() {
        let t = SimTime::from_secs(2);
        let mut bytes = nodes_payload::counter_stream(12, 0, 3000);
        bytes.drain(1000..1400);
        let mk = |b: Vec<u8>| {
            report_of(vec![
                pc(nodes_pc::PcOutput::SessionStarted {
                    t,
                    session_id: 1,
                    payload_addr: 12,
                }),
                pc(nodes_pc::PcOutput::Downlinked {
                    t,
                    session_id: 1,
                    payload_addr: 12,
                    bytes: b,
                }),
            ])
        };
        let strict = DownlinkExpect {
            session: 1,
            min: None,
            max: None,
            intact: Some(true),
        };
        let lenient = DownlinkExpect {
            session: 1,
            min: None,
            max: None,
            intact: Some(false),
        };
        let report = mk(bytes.clone());
        assert!(!check(&strict, &report).0);
        // A cut inside the stream damages the frame it falls in.
        assert!(
            !check(&lenient, &report).0,
            "{}",
            check(&lenient, &report).1
        );
        let mut flipped = nodes_payload::counter_stream(12, 0, 3000);
        flipped[1500] ^= 1;
        let (ok, seen) = check(&lenient, &mk(flipped));
        assert!(!ok && seen.contains("1 damaged"), "{seen}");
    }

    #[test]
    fn a_frame_cut_between_two_runs_is_whole_when_nothing_was_lost_between_them() {
        let t = SimTime::from_secs(2);
        let bytes = nodes_payload::counter_stream(12, 0, 3000);
        // Session 1 run once per part, each downlinking that part.
        let runs = |parts: &[&[u8]]| {
            let mut ev = Vec::new();
            for part in parts {
                ev.push(pc(nodes_pc::PcOutput::SessionStarted {
                    t,
                    session_id: 1,
                    payload_addr: 12,
                }));
                ev.push(pc(nodes_pc::PcOutput::Downlinked {
                    t,
                    session_id: 1,
                    payload_addr: 12,
                    bytes: part.to_vec(),
                }));
            }
            report_of(ev)
        };
        let strict = DownlinkExpect {
            session: 1,
            min: None,
            max: None,
            intact: Some(true),
        };
        // Split mid-frame (byte 1000 is inside a frame): every frame is intact.
        let (ok, seen) = check(&strict, &runs(&[&bytes[..1000], &bytes[1000..]]));
        assert!(ok && seen.contains("0 missing"), "{seen}");
        // 30 bytes lost between the runs: the frames they cut into are missing (13 and 14
        // here), none is taken for damaged.
        let (ok, seen) = check(&strict, &runs(&[&bytes[..1000], &bytes[1030..]]));
        assert!(!ok && seen.contains("0 damaged, 2 missing"), "{seen}");
        // A short run holding no whole frame between two others: still whole.
        let (ok, seen) = check(
            &strict,
            &runs(&[&bytes[..1000], &bytes[1000..1060], &bytes[1060..]]),
        );
        assert!(ok && seen.contains("0 missing"), "{seen}");
        // Split exactly between two frames: nothing to join, nothing missing.
        let first = nodes_payload::stream::frame_len(0) + nodes_payload::stream::frame_len(1);
        let (ok, seen) = check(&strict, &runs(&[&bytes[..first], &bytes[first..]]));
        assert!(ok && seen.contains("0 missing"), "{seen}");
    }

    #[test]
    fn a_session_that_never_ran_fails_its_expectation() {
        let report = report_of(Vec::new());
        let c = SessionExpect {
            session: 1,
            session_result: Some(SessionResultName::Done),
            occurrence: Some(Occurrence::Every),
            min: None,
            max: None,
        };
        let (ok, seen) = check(&c, &report);
        assert!(!ok);
        assert!(seen.contains("never started"), "{seen}");
    }
}
