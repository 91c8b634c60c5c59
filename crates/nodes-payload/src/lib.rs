//! Simulated payloads (CSP 12-15): the SYNC/POLL port of ICD 3.1.8.2, a data stream cut
//! into POLL replies or pushed to the PC's ingest port (ICD 3.1.5), and fault behaviours.
//!
//! [`PayloadApp`] is a pure core ([`csp::node::App`]). On its port (10 by default,
//! INTERPRETATION.md section 4) it answers:
//! - SYNC `01 | msg[0..=128]` with `01 01 | msg` (the identical echo the PC waits for);
//! - POLL `02 | frameSize` (1..=254) with `02 01 | data`, the next at most `frameSize`
//!   bytes of its [`stream`] (fewer when the rate or the end of a file limits it, none when
//!   nothing is available);
//! - anything else with `cmd 00` and no data ([`wire`]).
//!
//! Every reply waits `reply_latency` (5 ms by default, plus `extra` under
//! [`Behaviour::Slow`]) and is sent from [`App::handle_timeout`]; replies leave in the
//! order their requests arrived (a reply is never due before the one queued ahead of it).
//! The behaviour in force when a request *arrives* decides how it is answered; POLL data is
//! cut from the stream when the reply is *sent*. At most [`MAX_QUEUED_REPLIES`] replies
//! wait; a request beyond that is dropped (counted, logged).
//!
//! In buffering mode ([`PushConfig`]) the payload also sends packets of raw stream bytes
//! (no command byte) to the PC's ingest port on its own timer, session or not.
//!
//! # What "produced" means
//! Produced bytes are stream bytes that left the payload: in a POLL reply or a push
//! packet that was handed to the CSP node. The stream's read position always equals
//! [`PayloadCounters::produced_bytes`], so what left is exactly
//! `counter_stream(addr, 0, produced_bytes)` in send order. Data in a reply the PC rejects
//! (too long, too late, wrong id) still counts as produced. Per behaviour:
//! - `Normal`, `NoAck`, `WrongEcho`, `Slow`, `SilentFor`: POLL replies carry stream bytes,
//!   all produced; an ignored POLL produces nothing and the stream does not move.
//! - `Oversize { extra_bytes }`: the reply carries `min(frameSize + extra_bytes, 254)` bytes:
//!   the stream bytes available (produced), then zero padding up to that length (not
//!   produced, counted in [`PayloadCounters::padding_bytes`]). With frameSize 254 no reply
//!   can be longer (CAN MTU): the reply is a normal full frame.
//! - `Garbage`: random bytes, no stream bytes: nothing produced.
//! - `ZeroLength`, `Silent`: nothing produced.
//! - Pushes are not affected by behaviours (stop them with [`PushConfig::stop`]).
//!
//! # Reboot
//! [`App::reset`] loses the queued replies (counted in
//! [`PayloadCounters::lost_on_reset`]; their data was never cut, so the stream has no gap).
//! The stream position, the rate clock (started at the first boot), the behaviour, the
//! timeline and the `SilentFor` count survive: the payload's data is its own, and the
//! scenario's fault timeline is not the payload's memory. Push slots that fell while the
//! payload was off are skipped, not sent in a burst. The running parameters return to the
//! saved table (PSAVE) or the factory defaults.
//!
//! # Platform port 14
//! The parameter table and self-test of [`config`] (`csp::params`): the push (filling)
//! rate and packet size, the stream's rate, the reply latency (ICD 3.1.5: "a payload
//! should be able to change its filling rate").

pub mod config;
pub mod stream;
pub use icd::payload as wire;

use std::collections::VecDeque;
use std::time::Duration;

use csp::node::{App, Node, Outbox};
use csp::reqrep::{self, RequestError};
use csp::{Header, Packet, SimTime};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

use crate::stream::DataStream;
pub use crate::stream::{
    Generator, StreamCheck, StreamChecker, StreamEnd, check_counter_stream, counter_frame,
    counter_stream,
};
use crate::wire::{CMD_POLL, CMD_SYNC, MAX_PUSH_BYTES, MAX_REPLY_DATA_BYTES, PayloadCommand};

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[wire::PORT];

/// Default reply latency: a payload's request handling time (the twin's choice).
pub const DEFAULT_REPLY_LATENCY: Duration = Duration::from_millis(5);
/// Replies waiting at most (the twin's choice; a payload's request queue is finite).
pub const MAX_QUEUED_REPLIES: usize = 32;
/// The PC's address (INTERPRETATION.md section 1).
pub const PC_ADDR: u8 = 6;
/// The PC's buffered-data ingest port (INTERPRETATION.md section 4).
pub const PC_INGEST_PORT: u8 = 11;
/// Push slots sent at most per timer call before the schedule skips ahead.
const MAX_PUSH_BURST: usize = 64;

/// How the payload answers requests (fault injection).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum Behaviour {
    /// As the ICD says.
    #[default]
    Normal,
    /// Never answers SYNC (the PC ends the session with NO ACK); POLL as normal.
    NoAck,
    /// Answers SYNC with different bytes (every byte inverted; `FF` for an empty message).
    WrongEcho,
    /// Adds `extra` to the latency of every reply.
    Slow {
        /// Added latency.
        extra: Duration,
    },
    /// Ignores the next `polls` POLLs, then answers normally.
    SilentFor {
        /// POLLs to ignore.
        polls: u32,
    },
    /// Ignores every request, malformed ones included.
    Silent,
    /// Answers POLL with `frameSize + extra_bytes` bytes (at most 254).
    Oversize {
        /// Bytes beyond the frame size.
        extra_bytes: u8,
    },
    /// Answers SYNC and POLL with a wrong command id, a random result and random data
    /// (seeded).
    Garbage,
    /// Answers every POLL `02 01` with no data.
    ZeroLength,
}

impl std::fmt::Display for Behaviour {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Behaviour::Normal => f.write_str("normal"),
            Behaviour::NoAck => f.write_str("no-ack"),
            Behaviour::WrongEcho => f.write_str("wrong-echo"),
            Behaviour::Slow { extra } => write!(f, "slow:{}ms", extra.as_millis()),
            Behaviour::SilentFor { polls } => write!(f, "silent-for:{polls}"),
            Behaviour::Silent => f.write_str("silent"),
            Behaviour::Oversize { extra_bytes } => write!(f, "oversize:{extra_bytes}"),
            Behaviour::Garbage => f.write_str("garbage"),
            Behaviour::ZeroLength => f.write_str("zero-length"),
        }
    }
}

/// Why a text is not a [`Behaviour`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum BehaviourError {
    /// A behaviour that takes a value without one.
    #[error("`{name}` needs a value: `{name}:<{what}>`")]
    NeedsValue {
        /// The behaviour's name as written.
        name: String,
        /// What the value is (`ms`, `polls`, `bytes`).
        what: &'static str,
    },
    /// The value is not a whole number.
    #[error("`{text}`: bad {what}: {source}")]
    BadNumber {
        /// The whole text.
        text: String,
        /// What the value is.
        what: &'static str,
        /// Why it did not parse.
        source: std::num::ParseIntError,
    },
    /// The value is too large for the behaviour.
    #[error("`{text}`: {source}")]
    TooLarge {
        /// The whole text.
        text: String,
        /// The conversion's error.
        source: std::num::TryFromIntError,
    },
    /// Not one of the behaviours.
    #[error(
        "unknown payload behaviour `{name}`: expected normal, no-ack, wrong-echo, \
         slow:<ms>, silent-for:<n>, silent, oversize:<n>, garbage or zero-length"
    )]
    Unknown {
        /// The name as written.
        name: String,
    },
}

impl std::str::FromStr for Behaviour {
    type Err = BehaviourError;
    /// Parse `normal`, `no-ack`, `wrong-echo`, `slow:<ms>[ms]`, `silent-for:<n>`, `silent`,
    /// `oversize:<n>`, `garbage` or `zero-length`.
    fn from_str(s: &str) -> Result<Self, BehaviourError> {
        let (name, arg) = match s.split_once(':') {
            Some((n, a)) => (n, Some(a.trim())),
            None => (s, None),
        };
        let num = |what: &'static str| -> Result<u64, BehaviourError> {
            let a = arg.ok_or_else(|| BehaviourError::NeedsValue {
                name: name.to_owned(),
                what,
            })?;
            a.trim_end_matches("ms")
                .parse::<u64>()
                .map_err(|source| BehaviourError::BadNumber {
                    text: s.to_owned(),
                    what,
                    source,
                })
        };
        let too_large = |source| BehaviourError::TooLarge {
            text: s.to_owned(),
            source,
        };
        let b = match name.trim() {
            "normal" => Behaviour::Normal,
            "no-ack" => Behaviour::NoAck,
            "wrong-echo" => Behaviour::WrongEcho,
            "slow" => Behaviour::Slow {
                extra: Duration::from_millis(num("ms")?),
            },
            "silent-for" => Behaviour::SilentFor {
                polls: u32::try_from(num("polls")?).map_err(too_large)?,
            },
            "silent" => Behaviour::Silent,
            "oversize" => Behaviour::Oversize {
                extra_bytes: u8::try_from(num("bytes")?).map_err(too_large)?,
            },
            "garbage" => Behaviour::Garbage,
            "zero-length" => Behaviour::ZeroLength,
            other => {
                return Err(BehaviourError::Unknown {
                    name: other.to_owned(),
                });
            }
        };
        Ok(b)
    }
}

/// Buffering mode: push stream data to the PC (ICD 3.1.5).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PushConfig {
    /// The PC's address (6).
    pub pc_addr: u8,
    /// The PC's ingest port (11).
    pub pc_port: u8,
    /// Data bytes per packet, 1..=256 (larger values are sent as 256; 0 pushes nothing).
    pub packet_bytes: u16,
    /// Push rate: a packet every `packet_bytes / rate_bytes_per_s` seconds (0 pushes nothing).
    pub rate_bytes_per_s: u64,
    /// First packet.
    pub start: SimTime,
    /// No packet at or after this time.
    pub stop: Option<SimTime>,
}

impl Default for PushConfig {
    fn default() -> Self {
        PushConfig {
            pc_addr: PC_ADDR,
            pc_port: PC_INGEST_PORT,
            packet_bytes: MAX_PUSH_BYTES,
            rate_bytes_per_s: 1024,
            start: SimTime::ZERO,
            stop: None,
        }
    }
}

impl PushConfig {
    fn packet_len(&self) -> usize {
        usize::from(self.packet_bytes.min(MAX_PUSH_BYTES))
    }

    /// When push slot `k` falls, `None` when there is none.
    fn slot_time(&self, k: u64) -> Option<SimTime> {
        let bytes = self.packet_len() as u128;
        if bytes == 0 || self.rate_bytes_per_s == 0 {
            return None;
        }
        let offset_ns = u128::from(k) * bytes * 1_000_000_000 / u128::from(self.rate_bytes_per_s);
        let t = SimTime::from_ns(
            self.start
                .as_ns()
                .saturating_add(u64::try_from(offset_ns).unwrap_or(u64::MAX)),
        );
        match self.stop {
            Some(stop) if t >= stop => None,
            _ => Some(t),
        }
    }

    /// The first slot at or after `now`.
    fn first_slot_from(&self, now: SimTime) -> u64 {
        let bytes = self.packet_len() as u128;
        let elapsed = u128::from(now.as_ns().saturating_sub(self.start.as_ns()));
        let denom = bytes * 1_000_000_000;
        if denom == 0 {
            return 0;
        }
        let mut k = u64::try_from((elapsed * u128::from(self.rate_bytes_per_s)).div_ceil(denom))
            .unwrap_or(u64::MAX);
        // Guard against rounding: step back while the previous slot is still >= now.
        while k > 0 && self.slot_time(k - 1).is_some_and(|t| t >= now) {
            k -= 1;
        }
        k
    }
}

/// What a payload is (fixed for the run, from the scenario).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PayloadConfig {
    /// SYNC/POLL port (10).
    pub port: u8,
    /// Where the data comes from.
    pub generator: Generator,
    /// Data becomes available at this rate from the first boot; `None`: all at once.
    pub rate_bytes_per_s: Option<u64>,
    /// Delay between a request and its reply.
    pub reply_latency: Duration,
    /// Behaviour at boot.
    pub behaviour: Behaviour,
    /// Behaviour changes at their times (sorted by the app; equal times apply in order).
    pub timeline: Vec<(SimTime, Behaviour)>,
    /// Buffering mode: push data to the PC.
    pub push: Option<PushConfig>,
    /// Seed of the `Garbage` bytes.
    pub seed: u64,
}

impl Default for PayloadConfig {
    fn default() -> Self {
        PayloadConfig {
            port: wire::PORT,
            generator: Generator::Counter,
            rate_bytes_per_s: None,
            reply_latency: DEFAULT_REPLY_LATENCY,
            behaviour: Behaviour::Normal,
            timeline: Vec::new(),
            push: None,
            seed: 0,
        }
    }
}

/// How produced bytes left the payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum How {
    /// In a POLL reply.
    PollReply,
    /// In a buffering-mode push.
    Push,
}

/// What the payload tells the twin.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PayloadOutput {
    /// `bytes` (> 0) stream bytes left the payload at `t`.
    Produced {
        /// When.
        t: SimTime,
        /// How many stream bytes.
        bytes: u64,
        /// Reply or push.
        how: How,
    },
    /// A well-formed SYNC arrived (whatever the behaviour does with it).
    SyncReceived {
        /// When.
        t: SimTime,
        /// The synchronisation message.
        msg: Vec<u8>,
    },
}

/// The payload's counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PayloadCounters {
    /// Well-formed SYNCs received.
    pub syncs: u64,
    /// Well-formed POLLs received.
    pub polls: u64,
    /// Requests that did not parse.
    pub malformed: u64,
    /// Reply packets sent.
    pub replies: u64,
    /// Requests left unanswered on purpose (the behaviour).
    pub ignored: u64,
    /// Requests dropped because [`MAX_QUEUED_REPLIES`] replies were waiting.
    pub queue_full: u64,
    /// Queued replies lost to a reboot.
    pub lost_on_reset: u64,
    /// Replies or pushes the node refused to send (no route).
    pub send_failures: u64,
    /// Stream bytes that left the payload (replies and pushes): the stream position.
    pub produced_bytes: u64,
    /// Stream bytes in POLL replies.
    pub poll_bytes: u64,
    /// Stream bytes pushed.
    pub pushed_bytes: u64,
    /// Push packets sent.
    pub pushed_packets: u64,
    /// Push slots with no data available (nothing sent).
    pub push_empty_slots: u64,
    /// Zero bytes padding `Oversize` replies (not stream data).
    pub padding_bytes: u64,
}

/// A reply decided when its request arrived.
#[derive(Debug, Clone)]
enum ReplyKind {
    /// Fixed bytes: SYNC echo, wrong echo, failure, zero-length, garbage.
    Fixed(Vec<u8>),
    /// POLL data: up to `take` stream bytes cut at send time, zero-padded to `pad_to`.
    Poll { take: usize, pad_to: usize },
}

#[derive(Debug, Clone)]
struct Queued {
    due: SimTime,
    header: Header,
    kind: ReplyKind,
}

/// A simulated payload (see the module doc).
#[derive(Debug)]
pub struct PayloadApp {
    cfg: PayloadConfig,
    stream: DataStream,
    behaviour: Behaviour,
    silent_polls_left: u32,
    next_event: usize,
    queue: VecDeque<Queued>,
    rng: ChaCha8Rng,
    push_slot: u64,
    addr: u8,
    counters: PayloadCounters,
    out: Outbox<PayloadOutput>,
    /// The latest instant the payload was called at.
    last_now: SimTime,
    /// The stream's rate parameter changed: re-anchor it at the next call with a time.
    stream_rate_pending: bool,
    /// The push parameters changed: restart the push schedule at the next call with a time.
    push_pending: bool,
}

impl PayloadApp {
    /// A payload with configuration `cfg`.
    pub fn new(mut cfg: PayloadConfig) -> Self {
        cfg.timeline.sort_by_key(|(t, _)| *t);
        let behaviour = cfg.behaviour.clone();
        let silent_polls_left = match behaviour {
            Behaviour::SilentFor { polls } => polls,
            _ => 0,
        };
        PayloadApp {
            stream: DataStream::new(cfg.generator.clone(), cfg.rate_bytes_per_s),
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            behaviour,
            silent_polls_left,
            next_event: 0,
            queue: VecDeque::new(),
            push_slot: 0,
            addr: 0,
            counters: PayloadCounters::default(),
            out: Outbox::default(),
            last_now: SimTime::ZERO,
            stream_rate_pending: false,
            push_pending: false,
            cfg,
        }
    }

    /// Apply parameter changes that count from an instant ([`config`]) at `now`: the
    /// stream's new rate from `now`, the push schedule restarted one new period after
    /// `now` (unless it has not started yet).
    fn apply_pending(&mut self, now: SimTime) {
        self.last_now = self.last_now.max(now);
        if std::mem::take(&mut self.stream_rate_pending) {
            self.stream.set_rate(self.cfg.rate_bytes_per_s, now);
        }
        if std::mem::take(&mut self.push_pending)
            && let Some(p) = &mut self.cfg.push
        {
            if p.start <= now {
                let bytes = p.packet_len() as u128;
                let period_ns = if p.rate_bytes_per_s > 0 {
                    bytes * 1_000_000_000 / u128::from(p.rate_bytes_per_s)
                } else {
                    0
                };
                p.start = SimTime::from_ns(
                    now.as_ns()
                        .saturating_add(u64::try_from(period_ns).unwrap_or(u64::MAX)),
                );
            }
            self.push_slot = 0;
        }
    }

    /// The counters.
    pub fn counters(&self) -> &PayloadCounters {
        &self.counters
    }

    /// The configuration.
    pub fn config(&self) -> &PayloadConfig {
        &self.cfg
    }

    /// The behaviour in force.
    pub fn behaviour(&self) -> &Behaviour {
        &self.behaviour
    }

    /// Replies waiting to be sent.
    pub fn queued_replies(&self) -> usize {
        self.queue.len()
    }

    /// Stream bytes available to a POLL or push at `now`.
    pub fn available_bytes(&self, now: SimTime) -> u64 {
        self.stream.available(now)
    }

    fn emit(&mut self, out: PayloadOutput) {
        self.out.push(out);
    }

    fn set_behaviour(&mut self, node: &mut Node, b: Behaviour, now: SimTime) {
        self.silent_polls_left = match b {
            Behaviour::SilentFor { polls } => polls,
            _ => 0,
        };
        node.log(now, format!("payload behaviour -> {b}"));
        self.behaviour = b;
    }

    fn apply_timeline(&mut self, node: &mut Node, now: SimTime) {
        while let Some((t, b)) = self.cfg.timeline.get(self.next_event).cloned() {
            if t > now {
                break;
            }
            self.next_event += 1;
            self.set_behaviour(node, b, now);
        }
    }

    fn latency(&self) -> Duration {
        match self.behaviour {
            Behaviour::Slow { extra } => self.cfg.reply_latency.saturating_add(extra),
            _ => self.cfg.reply_latency,
        }
    }

    fn enqueue(&mut self, node: &mut Node, header: Header, kind: ReplyKind, now: SimTime) {
        if self.queue.len() >= MAX_QUEUED_REPLIES {
            self.counters.queue_full += 1;
            node.log_drop(
                now,
                csp::drop::DropCause::app("payload reply queue full"),
                header.to_string(),
            );
            return;
        }
        let earliest = now + self.latency();
        let due = self.queue.back().map_or(earliest, |q| q.due.max(earliest));
        self.queue.push_back(Queued { due, header, kind });
    }

    fn garbage(&mut self, command: u8, max_data: usize) -> Vec<u8> {
        let r = self.rng.next_u64();
        let mut id = r as u8;
        if id == command {
            id = id.wrapping_add(1);
        }
        let result = (r >> 8) as u8;
        let len = ((r >> 16) % (max_data as u64 + 1)) as usize;
        let mut out = vec![id, result];
        while out.len() < 2 + len {
            out.extend(self.rng.next_u64().to_le_bytes());
        }
        out.truncate(2 + len);
        out
    }

    fn on_sync(&mut self, node: &mut Node, header: Header, msg: Vec<u8>, now: SimTime) {
        self.counters.syncs += 1;
        self.emit(PayloadOutput::SyncReceived {
            t: now,
            msg: msg.clone(),
        });
        let reply = match self.behaviour {
            Behaviour::Silent | Behaviour::NoAck => {
                self.counters.ignored += 1;
                node.log(now, format!("SYNC ignored ({})", self.behaviour));
                return;
            }
            Behaviour::WrongEcho => {
                let wrong: Vec<u8> = if msg.is_empty() {
                    vec![0xFF]
                } else {
                    msg.iter().map(|b| !b).collect()
                };
                reqrep::success(CMD_SYNC, &wrong)
            }
            Behaviour::Garbage => self.garbage(CMD_SYNC, wire::SYNC_MSG_MAX_BYTES),
            _ => reqrep::success(CMD_SYNC, &msg),
        };
        self.enqueue(node, header, ReplyKind::Fixed(reply), now);
    }

    fn on_poll(&mut self, node: &mut Node, header: Header, frame_size: u8, now: SimTime) {
        self.counters.polls += 1;
        let frame = usize::from(frame_size);
        let kind = match self.behaviour {
            Behaviour::Silent => None,
            Behaviour::SilentFor { .. } if self.silent_polls_left > 0 => {
                self.silent_polls_left -= 1;
                None
            }
            Behaviour::ZeroLength => Some(ReplyKind::Fixed(reqrep::success(CMD_POLL, &[]))),
            Behaviour::Garbage => Some(ReplyKind::Fixed(self.garbage(CMD_POLL, frame))),
            Behaviour::Oversize { extra_bytes } => {
                let len = (frame + usize::from(extra_bytes)).min(MAX_REPLY_DATA_BYTES);
                Some(ReplyKind::Poll {
                    take: len,
                    pad_to: len,
                })
            }
            _ => Some(ReplyKind::Poll {
                take: frame,
                pad_to: 0,
            }),
        };
        match kind {
            Some(k) => self.enqueue(node, header, k, now),
            None => self.counters.ignored += 1,
        }
    }

    fn send_reply(&mut self, node: &mut Node, q: Queued, now: SimTime) {
        let (data, cut) = match q.kind {
            ReplyKind::Fixed(d) => (d, 0),
            ReplyKind::Poll { take, pad_to } => {
                let mut data = self.stream.take(take, now);
                let cut = data.len();
                if data.len() < pad_to {
                    self.counters.padding_bytes += (pad_to - data.len()) as u64;
                    data.resize(pad_to, 0);
                }
                (reqrep::success(CMD_POLL, &data), cut)
            }
        };
        match node.send(Packet::new(q.header, data), now) {
            Ok(()) => {
                self.counters.replies += 1;
                if cut > 0 {
                    self.counters.poll_bytes += cut as u64;
                    self.produced(cut, How::PollReply, now);
                }
            }
            Err(e) => {
                self.stream.untake(cut);
                self.counters.send_failures += 1;
                node.log_drop(
                    now,
                    csp::drop::DropCause::app("payload reply"),
                    format!("{}: {e}", q.header),
                );
            }
        }
    }

    fn produced(&mut self, n: usize, how: How, now: SimTime) {
        self.counters.produced_bytes += n as u64;
        self.emit(PayloadOutput::Produced {
            t: now,
            bytes: n as u64,
            how,
        });
    }

    fn push(&mut self, node: &mut Node, push: &PushConfig, now: SimTime) {
        let data = self.stream.take(push.packet_len(), now);
        if data.is_empty() {
            self.counters.push_empty_slots += 1;
            return;
        }
        let n = data.len();
        let header = node.own_header(push.pc_addr, push.pc_port);
        match node.send(Packet::new(header, data), now) {
            Ok(()) => {
                self.counters.pushed_packets += 1;
                self.counters.pushed_bytes += n as u64;
                self.produced(n, How::Push, now);
            }
            Err(e) => {
                self.stream.untake(n);
                self.counters.send_failures += 1;
                node.log_drop(
                    now,
                    csp::drop::DropCause::app("payload push"),
                    format!("{header}: {e}"),
                );
            }
        }
    }

    fn next_push(&self) -> Option<SimTime> {
        self.cfg.push.as_ref()?.slot_time(self.push_slot)
    }
}

impl App for PayloadApp {
    type Event = PayloadOutput;
    fn poll_event(&mut self) -> Option<PayloadOutput> {
        self.out.pop()
    }
    fn start(&mut self, node: &mut Node, now: SimTime) {
        node.bind(self.cfg.port);
        self.addr = node.addr();
        self.stream.begin(self.addr, now);
        self.apply_pending(now);
        self.apply_timeline(node, now);
        if let Some(p) = &self.cfg.push {
            // Slots that fell while the payload was off are skipped.
            self.push_slot = self.push_slot.max(p.first_slot_from(now));
        }
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        self.last_now = self.last_now.max(now);
        if packet.header.dport != self.cfg.port {
            return;
        }
        self.apply_timeline(node, now);
        let header = packet.header.reply(node.addr());
        match PayloadCommand::parse_bytes(&packet.data) {
            Ok(PayloadCommand::Sync(msg)) => self.on_sync(node, header, msg, now),
            Ok(PayloadCommand::Poll { frame_size }) => self.on_poll(node, header, frame_size, now),
            Err(e) => {
                self.counters.malformed += 1;
                if self.behaviour == Behaviour::Silent {
                    self.counters.ignored += 1;
                    return;
                }
                let command = match e {
                    RequestError::Empty => 0,
                    _ => packet.data.first().copied().unwrap_or(0),
                };
                node.log(now, format!("payload refused request from {header}: {e}"));
                self.enqueue(
                    node,
                    header,
                    ReplyKind::Fixed(reqrep::failure(command)),
                    now,
                );
            }
        }
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        let pending = self.stream_rate_pending || self.push_pending;
        [
            pending.then_some(self.last_now),
            self.queue.front().map(|q| q.due),
            self.next_push(),
            self.cfg.timeline.get(self.next_event).map(|(t, _)| *t),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        self.apply_pending(now);
        self.apply_timeline(node, now);
        while self.queue.front().is_some_and(|q| q.due <= now) {
            if let Some(q) = self.queue.pop_front() {
                self.send_reply(node, q, now);
            }
        }
        if let Some(push) = self.cfg.push.clone() {
            let mut sent = 0;
            while push.slot_time(self.push_slot).is_some_and(|t| t <= now) {
                if sent == MAX_PUSH_BURST {
                    self.push_slot = push.first_slot_from(now);
                    break;
                }
                self.push(node, &push, now);
                self.push_slot += 1;
                sent += 1;
            }
        }
    }

    fn reset(&mut self, now: SimTime) {
        self.last_now = self.last_now.max(now);
        self.counters.lost_on_reset += self.queue.len() as u64;
        self.queue.clear();
    }

    fn params(&mut self) -> Option<&mut dyn csp::params::Table> {
        Some(self)
    }

    fn self_test(&mut self, _node: &Node, now: SimTime) -> Vec<csp::params::Check> {
        self.checks(now)
    }
}

/// The node's application with the defaults: Counter stream, no rate limit, 5 ms latency,
/// Normal behaviour, no pushes.
pub fn app() -> PayloadApp {
    PayloadApp::new(PayloadConfig::default())
}

// What a snapshot keeps of a payload (docs/snapshots.md): its configuration (the
// parameters change it), the stream's position, the replies queued, the generator where it
// is in its stream, counts.
snap::fields!(PushConfig {
    pc_addr,
    pc_port,
    packet_bytes,
    rate_bytes_per_s,
    start,
    stop
});
snap::fields!(PayloadConfig {
    port,
    generator,
    rate_bytes_per_s,
    reply_latency,
    behaviour,
    timeline,
    push,
    seed
});
snap::fields!(PayloadCounters {
    syncs,
    polls,
    malformed,
    replies,
    ignored,
    queue_full,
    lost_on_reset,
    send_failures,
    produced_bytes,
    poll_bytes,
    pushed_bytes,
    pushed_packets,
    push_empty_slots,
    padding_bytes
});
snap::fields!(Queued { due, header, kind });
snap::fields!(PayloadApp {
    cfg,
    stream,
    behaviour,
    silent_polls_left,
    next_event,
    queue,
    rng,
    push_slot,
    counters,
    out,
    last_now,
    stream_rate_pending,
    push_pending;
    skip addr
});

snap::tagged_enum!(ReplyKind {
    Fixed(bytes),
    Poll { take, pad_to }
});

snap::tagged_enum!(Behaviour {
    Normal,
    NoAck,
    WrongEcho,
    Slow { extra },
    SilentFor { polls },
    Silent,
    Oversize { extra_bytes },
    Garbage,
    ZeroLength
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn behaviour_strings_round_trip() {
        for b in [
            Behaviour::Normal,
            Behaviour::NoAck,
            Behaviour::WrongEcho,
            Behaviour::Slow {
                extra: Duration::from_millis(250),
            },
            Behaviour::SilentFor { polls: 3 },
            Behaviour::Silent,
            Behaviour::Oversize { extra_bytes: 10 },
            Behaviour::Garbage,
            Behaviour::ZeroLength,
        ] {
            assert_eq!(b.to_string().parse::<Behaviour>().unwrap(), b);
        }
        assert_eq!(
            "slow:300".parse::<Behaviour>().unwrap(),
            Behaviour::Slow {
                extra: Duration::from_millis(300)
            }
        );
        let e = "slow".parse::<Behaviour>().unwrap_err();
        assert_eq!(e.to_string(), "`slow` needs a value: `slow:<ms>`");
        let e = "oversize:300".parse::<Behaviour>().unwrap_err();
        assert!(matches!(e, BehaviourError::TooLarge { .. }));
        assert_eq!(
            e.to_string(),
            "`oversize:300`: out of range integral type conversion attempted"
        );
        assert!(matches!(
            "silent-for:x".parse::<Behaviour>(),
            Err(BehaviourError::BadNumber { what: "polls", .. })
        ));
        assert!(matches!(
            "loud".parse::<Behaviour>(),
            Err(BehaviourError::Unknown { name }) if name == "loud"
        ));
    }

    #[test]
    fn push_slots_follow_the_rate() {
        let p = PushConfig {
            packet_bytes: 100,
            rate_bytes_per_s: 1000,
            start: SimTime::from_secs(2),
            stop: Some(SimTime::from_secs(3)),
            ..PushConfig::default()
        };
        assert_eq!(p.slot_time(0), Some(SimTime::from_secs(2)));
        assert_eq!(p.slot_time(1), Some(SimTime::from_ms(2100)));
        assert_eq!(p.slot_time(9), Some(SimTime::from_ms(2900)));
        assert_eq!(p.slot_time(10), None, "stop is exclusive");
        assert_eq!(p.first_slot_from(SimTime::ZERO), 0);
        assert_eq!(p.first_slot_from(SimTime::from_ms(2100)), 1);
        assert_eq!(p.first_slot_from(SimTime::from_ms(2101)), 2);
        let off = PushConfig {
            rate_bytes_per_s: 0,
            ..p.clone()
        };
        assert_eq!(off.slot_time(0), None);
        let big = PushConfig {
            packet_bytes: 1000,
            ..p
        };
        assert_eq!(big.packet_len(), 256);
    }
}
