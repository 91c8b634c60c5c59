//! Everything a run emits for recording, in the order it happens: the stream the MCAP
//! recorder writes and `replay`/`diff` compare.

use std::time::Duration;

use bus::trace::TraceEvent;
use csp::SimTime;

/// Direction of a frame on an outside link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// From the outside program into the twin.
    In,
    /// From the twin to the outside program.
    Out,
}

/// Severity of a log line (the levels of `foxglove.Log`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    /// Debug detail (drops, refusals).
    Debug = 1,
    /// Normal events.
    Info = 2,
    /// Something went wrong but the run goes on.
    Warning = 3,
    /// Something failed.
    Error = 4,
}

/// A whole packet a medium delivered ([`RunEvent::Packet`]), reassembled by the run's
/// [`crate::packets::PacketTap`].
#[derive(Debug, Clone, PartialEq)]
pub struct SeenPacket {
    /// When its last frame (or the packet itself) arrived.
    pub t: SimTime,
    /// The medium (`main`, `payload`, `ground`).
    pub medium: std::sync::Arc<str>,
    /// Who sent it on that medium (a node's name, or an outside link's).
    pub from: std::sync::Arc<str>,
    /// The packet.
    pub packet: csp::Packet,
}

/// The outcome of a scenario command, with the command as it was sent (or tried to be):
/// the one way a command's outcome reaches the report, the expectations and the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandResult {
    /// When it was decided (reply arrival or timeout).
    pub t: SimTime,
    /// Command name.
    pub name: String,
    /// Destination node.
    pub dst: u8,
    /// Destination port.
    pub dport: u8,
    /// Request bytes.
    pub data: Vec<u8>,
    /// How long it waited for its reply.
    pub timeout: Duration,
    /// Reply bytes, or `None` on timeout.
    pub reply: Option<Vec<u8>>,
    /// Round-trip time in nanoseconds, when answered.
    pub rtt_ns: Option<u64>,
    /// When it was sent (or failed to be).
    pub sent: SimTime,
    /// Why it could not be sent, when it could not (`reply` and `rtt_ns` are `None`).
    pub failed: Option<String>,
}

/// One thing that happened during a run. Its kinds ([`EventKind`], one per variant, same
/// name) are derived from it.
#[derive(Debug, Clone, PartialEq, strum::EnumDiscriminants)]
#[strum_discriminants(
    name(EventKind),
    derive(Hash, strum::EnumIter),
    doc = "The kinds of [`RunEvent`], one per variant (what [`Kinds`] selects)."
)]
pub enum RunEvent {
    /// A CAN frame on a bus or a packet on the ground network (see [`TraceEvent`]).
    Medium(TraceEvent),
    /// A whole CSP packet a medium delivered: a ground packet as it is, or the CFP packet a
    /// CAN frame completed, right after that frame's `Medium` event. The run's one
    /// reassembly ([`crate::packets::PacketTap`]), in a run asked for packets (a recording,
    /// the live view, a `field` expectation: `RunOptions::packet_events`).
    Packet(std::sync::Arc<SeenPacket>),
    /// Raw bytes of one KISS frame on an outside link.
    Kiss {
        /// When.
        t: SimTime,
        /// Link name, for example `listen 127.0.0.1:52001`.
        link: String,
        /// Direction.
        dir: Direction,
        /// The KISS frame as it crossed the socket (FENDs and escapes included).
        bytes: Vec<u8>,
    },
    /// A log line from a node or the run.
    Log {
        /// When.
        t: SimTime,
        /// Who (node name, `run`, a link name).
        source: String,
        /// Severity.
        level: Level,
        /// Text.
        message: String,
    },
    /// A whole CSP packet a node dropped (recorded as the debug log line it also is; the
    /// sessions' accounting counts a payload's replies lost this way).
    PacketDropped {
        /// The log line.
        log: Box<RunEvent>,
        /// The dropping node's name.
        node: String,
        /// Why.
        reason: csp::drop::DropReason,
        /// The packet.
        packet: csp::node::DroppedPacket,
    },
    /// A scenario fault applied or lifted.
    Fault {
        /// When.
        t: SimTime,
        /// What, for example `faults[0]: Drop on main`.
        what: String,
    },
    /// A request on the run's control channel (`run --control`), at the instant the run
    /// took it in, with the reply it got: what `replay` feeds again.
    Control {
        /// When the run took it in.
        t: SimTime,
        /// The connection it came on (numbered from 1 in the run).
        conn: u32,
        /// The request line as it came (JSON).
        request: String,
        /// The reply line (JSON).
        reply: String,
    },
    /// A scenario command sent by a ground station.
    Command {
        /// When it was sent.
        t: SimTime,
        /// Command name.
        name: String,
        /// Destination node.
        dst: u8,
        /// Destination port.
        dport: u8,
        /// Request bytes.
        data: Vec<u8>,
        /// How long it waits for its reply.
        timeout: Duration,
    },
    /// The outcome of a scenario command (boxed: the largest event, and rare).
    CommandResult(Box<CommandResult>),
    /// The FC's published truth and what its ADCS believes and does, at one instant.
    Truth {
        /// When (equals `truth.t_ns`).
        t: SimTime,
        /// The true state.
        truth: Box<platform::truth::TruthSnapshot>,
        /// The ADCS's estimate, target and commands.
        adcs: Box<platform::truth::AdcsSnapshot>,
    },
    /// What the payload controller did: a session started or ended, bytes reached the
    /// ground, bytes were dropped, the final accounting.
    Pc(Box<nodes_pc::PcOutput>),
    /// A beacon from a COMM received by a ground station.
    Beacon {
        /// When it arrived.
        t: SimTime,
        /// The COMM that sent it (1 or 2).
        from: u8,
        /// The packet data (`04 01 | Beacon`, docs/protocol.md).
        data: Vec<u8>,
    },
    /// What the EPS did: a sample of the power state each tick, a channel switched.
    Eps(Box<nodes_eps::EpsOutput>),
    /// What a simulated payload did: bytes produced, a SYNC received.
    Payload {
        /// The payload's address.
        addr: u8,
        /// What.
        out: nodes_payload::PayloadOutput,
    },
    /// The verdict on an expectation (at the end of the run).
    Expectation {
        /// When the verdict refers to.
        t: SimTime,
        /// Expectation name.
        name: String,
        /// Whether it held.
        passed: bool,
        /// What was observed.
        observed: String,
    },
}

/// A set of [`EventKind`]s: what an observer of the run looks at, so that it is not handed
/// the rest (a run has hundreds of thousands of events an hour, most of them frames).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kinds(u16);

impl Kinds {
    /// Every kind.
    pub const ALL: Kinds = Kinds(u16::MAX);

    /// The kinds listed.
    pub const fn of(kinds: &[EventKind]) -> Kinds {
        let mut bits = 0;
        let mut i = 0;
        while i < kinds.len() {
            bits |= 1 << kinds[i] as u16;
            i += 1;
        }
        Kinds(bits)
    }

    /// Whether `kind` is one of them.
    pub const fn has(self, kind: EventKind) -> bool {
        self.0 & (1 << kind as u16) != 0
    }
}

impl RunEvent {
    /// Its kind.
    pub fn kind(&self) -> EventKind {
        EventKind::from(self)
    }

    /// The simulated time of the event.
    pub fn t(&self) -> SimTime {
        match self {
            RunEvent::Medium(e) => e.t,
            RunEvent::Packet(p) => p.t,
            RunEvent::CommandResult(r) => r.t,
            RunEvent::PacketDropped { log, .. } => log.t(),
            RunEvent::Kiss { t, .. }
            | RunEvent::Log { t, .. }
            | RunEvent::Fault { t, .. }
            | RunEvent::Control { t, .. }
            | RunEvent::Command { t, .. }
            | RunEvent::Truth { t, .. }
            | RunEvent::Beacon { t, .. }
            | RunEvent::Expectation { t, .. } => *t,
            RunEvent::Pc(o) => match **o {
                nodes_pc::PcOutput::SessionStarted { t, .. }
                | nodes_pc::PcOutput::SessionEnded { t, .. }
                | nodes_pc::PcOutput::SessionLost { t, .. }
                | nodes_pc::PcOutput::Downlinked { t, .. }
                | nodes_pc::PcOutput::Dropped { t, .. }
                | nodes_pc::PcOutput::Final { t, .. } => t,
            },
            RunEvent::Eps(o) => match **o {
                nodes_eps::EpsOutput::Sample { t, .. }
                | nodes_eps::EpsOutput::Channel { t, .. } => t,
            },
            RunEvent::Payload { out, .. } => match out {
                nodes_payload::PayloadOutput::Produced { t, .. }
                | nodes_payload::PayloadOutput::SyncReceived { t, .. } => *t,
            },
        }
    }
}

impl From<bus::driver::NodeLog> for RunEvent {
    /// A node's drop (debug detail) or log line (news, or a warning), under its name.
    fn from(l: bus::driver::NodeLog) -> Self {
        use csp::node::{NodeEvent, Severity};
        let level = match &l.event {
            NodeEvent::Drop { .. } => Level::Debug,
            NodeEvent::Log {
                severity: Severity::Info,
                ..
            } => Level::Info,
            NodeEvent::Log { .. } => Level::Warning,
        };
        let log = RunEvent::Log {
            t: l.event.t(),
            source: l.node.to_string(),
            level,
            message: l.event.to_string(),
        };
        match l.event {
            NodeEvent::Drop {
                reason: csp::drop::DropCause::Node(reason),
                packet: Some(packet),
                ..
            } => RunEvent::PacketDropped {
                log: Box::new(log),
                node: l.node.to_string(),
                reason,
                packet,
            },
            _ => log,
        }
    }
}

impl From<nodes_fc::Published> for RunEvent {
    fn from(p: nodes_fc::Published) -> Self {
        RunEvent::Truth {
            t: p.truth.t,
            truth: p.truth,
            adcs: p.adcs,
        }
    }
}

impl From<nodes_eps::EpsOutput> for RunEvent {
    fn from(o: nodes_eps::EpsOutput) -> Self {
        RunEvent::Eps(Box::new(o))
    }
}

impl From<nodes_pc::PcOutput> for RunEvent {
    fn from(o: nodes_pc::PcOutput) -> Self {
        RunEvent::Pc(Box::new(o))
    }
}

impl From<nodes_ecu::EcuOutput> for RunEvent {
    /// The ECU's news as a log line of `ECU` (ARM, the burns, SAFE, the final telemetry).
    fn from(out: nodes_ecu::EcuOutput) -> Self {
        use nodes_ecu::EcuOutput as O;
        let (t, message) = match &out {
            O::Armed { t } => (*t, "armed: heaters on".to_owned()),
            O::BurnStarted { t, burn } => (
                *t,
                format!(
                    "burn started: {:.3} N for {:.3} s, mass {:.3} kg",
                    burn.thrust_n,
                    (burn.end - burn.start).as_secs_f64(),
                    burn.mass_kg
                ),
            ),
            O::BurnEnded {
                t,
                cut,
                propellant_used_kg,
                impulse_n_s,
                ..
            } => (
                *t,
                format!(
                    "burn ended{}: {impulse_n_s:.4} N s, {:.3} g of propellant",
                    if *cut { " (cut)" } else { "" },
                    propellant_used_kg * 1e3
                ),
            ),
            O::Safed { t } => (*t, "safe: heaters off".to_owned()),
            O::Final { t, telemetry } => (*t, format!("at the end: {telemetry:?}")),
        };
        RunEvent::Log {
            t,
            source: "ECU".to_owned(),
            level: Level::Info,
            message,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every kind, from the enum.
    fn every() -> Vec<EventKind> {
        <EventKind as strum::IntoEnumIterator>::iter().collect()
    }

    #[test]
    fn a_set_of_kinds_holds_exactly_those_listed() {
        let every = every();
        assert!(every.len() <= 16, "Kinds holds 16");
        for (i, &k) in every.iter().enumerate() {
            assert!(Kinds::ALL.has(k));
            assert!(!Kinds::of(&[]).has(k));
            let one = Kinds::of(&[k]);
            let rest: Vec<EventKind> = every
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, &k)| k)
                .collect();
            let others = Kinds::of(&rest);
            for &m in &every {
                assert_eq!(one.has(m), m == k, "{k:?} {m:?}");
                assert_eq!(others.has(m), m != k, "{k:?} {m:?}");
            }
        }
    }

    #[test]
    fn an_event_says_its_kind() {
        let log = RunEvent::Log {
            t: SimTime::ZERO,
            source: "run".into(),
            level: Level::Info,
            message: String::new(),
        };
        assert_eq!(log.kind(), EventKind::Log);
        let cmd = RunEvent::CommandResult(Box::new(CommandResult {
            t: SimTime::ZERO,
            name: "x".into(),
            dst: 3,
            dport: 1,
            data: Vec::new(),
            timeout: Duration::from_secs(1),
            reply: None,
            rtt_ns: None,
            sent: SimTime::ZERO,
            failed: None,
        }));
        assert_eq!(cmd.kind(), EventKind::CommandResult);
    }

    /// Every event of a run is moved through the run's channel and its sinks: the enum
    /// stays the size of its common variants (a trace event and its tag), the rare large
    /// ones boxed.
    #[test]
    fn an_event_is_no_bigger_than_a_trace_event_and_its_tag() {
        let size = std::mem::size_of::<RunEvent>();
        eprintln!("RunEvent: {size} bytes");
        assert!(
            size <= std::mem::size_of::<TraceEvent>() + 8,
            "{size} bytes"
        );
    }
}
