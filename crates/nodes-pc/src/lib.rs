//! Payload controller (CSP 6): runs the ICD 3.1 data sessions between the payloads (CSP
//! 12-15, payload CAN) and the S-band transmitter. (Routing between the main and payload
//! CAN buses is the CSP node's job, configured by the twin.)
//!
//! [`PcApp`] is a pure core ([`csp::node::App`]) driven by packets and timers:
//! - port 10 (control): SETUP 1, STATUS 2, ABORT 3 over the session table ([`session`]),
//!   and WHY 4, the twin's own: why the asker's last refused request was refused ([`why`]);
//! - port 11 (ingest, ICD 3.1.5): raw data packets of buffering payloads, appended to the
//!   payload's file (the CSP packet data as is: there is no command byte);
//! - port 12 (the twin's PC telemetry): TMPC 1 ([`wire::Tmpc`]);
//! - outgoing SYNC 1 and POLL 2 to the payload of an ACTIVE polling session, each from its
//!   own ephemeral port (32-63), as a libcsp transaction would;
//! - the S-band transmitter ([`sband`]) that takes the data to the ground.
//!
//! # Sessions (ICD 3.1, INTERPRETATION.md section 7)
//! A **polling** session sends SYNC once with the configured message; only an identical echo
//! (`01 | any result | message`) within `reply_timeout` starts polling, anything else or
//! silence ends the session with NO ACK (SYNC is not retried: ICD 3.1.4 repeats only POLL).
//! Then one POLL cycle per packet: POLL with the frame size; no reply within
//! `reply_timeout` repeats it, at most [`POLL_ATTEMPTS`] attempts in all, after which the
//! packet counter advances anyway. A reply of more than the frame size is dropped
//! (Oversize) and counts as a failed attempt (the next attempt goes out at once); a
//! zero-length reply advances the counter and sends nothing. The next cycle starts
//! `poll_period` after the previous one started, or when it finished if that is later. A
//! reply that arrives after its request timed out or was answered, or from the wrong source
//! port, is dropped (Late). A reply with the wrong command id or shorter than 2 bytes is
//! dropped whole (Malformed) and the request keeps waiting.
//!
//! A **buffering** session sends nothing to the payload (ICD 3.1.5: "no additional Payload
//! polling"; SYNC belongs to polling, ICD 3.1.4). While it is ACTIVE, the payload's file is
//! streamed to the S-band: whenever the transmitter is about to start a frame and holds less
//! than a frame's worth, the PC cuts packets of `pollFrameSize` bytes (shorter only when the
//! file has less) from the head of the file until it holds a frame's worth; each packet
//! counts towards `maxNumOfPackets`, and the session ends DONE when the count is reached
//! (the packets already handed over are still sent). At the end
//! (duration, packet count, ABORT, S-band failure) the file is flushed: its bytes are dropped
//! (SessionEnded, or SbandFailure when the failure ended it). Ingest keeps filling the file
//! whether a session is active or not; a packet that does not fit whole is dropped whole
//! (BufferFull), so a payload's packets are never torn.
//!
//! Bytes handed to the transmitter belong to it: when a session ends (DONE, ABORTED, NO ACK)
//! the bytes already queued are still sent. An S-band failure loses them (SbandFailure) and
//! ends the ACTIVE session with S-BAND FAILURE; a session that starts while the S-band is
//! failed ends at once with S-BAND FAILURE. Switching the S-band off keeps its queue.
//!
//! # Accounting
//! Payload bytes are the data fields of POLL replies (after the `02 | result` head), the
//! data of ingest packets, and the whole data of malformed replies. Each is, exactly once,
//! downlinked, dropped with a [`DropReason`], in a buffer file or queued in the transmitter
//! ([`PcApp::accounting`], whose [`Accounting::is_balanced`] checks the identity). SYNC
//! replies are protocol, not payload data.
//!
//! # Reboot
//! Sessions, files, the transmitter queue and the outstanding requests are volatile: a
//! reboot ([`App::reset`]) loses them and records the lost bytes as dropped (PowerLoss). An
//! ACTIVE session simply stops (no result is recorded: the table starts empty). An S-band
//! hardware failure persists; on/off returns to the configured state. The accounting itself
//! is the twin's record and survives. The running parameters (below) return to the saved
//! table (PSAVE) or the factory defaults.
//!
//! # Platform port 14
//! The parameter table and self-test of [`config`] (`csp::params`): buffer file capacity,
//! poll period and reply timeout of the sessions, S-band rate. Payloads are refused the
//! port under ICD 4.1 ([`PcConfig::payload_access`]), as they are refused SETUP, ABORT and
//! the files.

pub mod config;
pub mod sband;
pub mod session;
pub mod why;
pub use icd::pc as wire;

use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::time::Duration;

use csp::node::{App, Node, NodeEvent, Outbox};
use csp::reqrep::le::Repr;
use csp::reqrep::{Reply, serve};
use csp::{Header, Packet, SimTime};

pub use crate::sband::{Sband, SbandConfig};
pub use crate::session::{Accepted, Refusal, SessionTable};
pub use crate::why::{Denied, Reason, Refusals};
use crate::wire::{ControlCommand, FileStat, FilesCommand, TelemetryCommand, Tmpc, TmpcSlot, cmd};
pub use crate::wire::{SessionConfig, SessionResult, SessionState, Status};

/// The ports this node binds for its ICD services by default (INTERPRETATION.md section 4,
/// plus the twin's PC telemetry on 12 and buffer files on 13).
pub const PORTS: &[u8] = &[
    wire::PORT_CONTROL,
    wire::PORT_INGEST,
    wire::PORT_TELEMETRY,
    wire::PORT_FILES,
];

/// Sessions the PC serves (one per payload, CSP 12-15).
pub use icd::pc::MAX_SESSIONS;
/// Default buffer file capacity (ICD 3.1.5: "the total available memory size is 256 MB").
pub const DEFAULT_BUFFER_CAPACITY_BYTES: u64 = 256 * 1024 * 1024;
/// POLL attempts per packet (ICD 3.1.4: "the request is repeated two more times").
pub const POLL_ATTEMPTS: u8 = 3;
/// Default poll period: 10 frames a second (the twin's choice; a scenario setting).
pub const DEFAULT_POLL_PERIOD: Duration = Duration::from_millis(100);
/// Default reply timeout: CAN transfer of a 256-byte packet (~5 ms at 1 Mbit/s) and the
/// payload's latency, with a wide margin (the twin's choice; a scenario setting).
pub const DEFAULT_REPLY_TIMEOUT: Duration = Duration::from_millis(200);
/// Shortest reply timeout used (a zero timeout would retry without time passing).
pub const MIN_REPLY_TIMEOUT: Duration = Duration::from_micros(1);
/// Ephemeral ports of answered or timed-out requests kept bound to recognise late replies.
const RETIRED_PORTS_MAX: usize = 8;
/// Bound on the timer steps of one `handle_timeout` call (work left over runs at the next).
const MAX_STEPS: usize = 1 << 20;

/// How a session collects data (ICD 3.1.1; fixed per payload for the run).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionMode {
    /// The PC polls the payload.
    Polling {
        /// Time from the start of one POLL cycle to the start of the next (0: as fast as
        /// replies come).
        poll_period: Duration,
        /// How long the PC waits for a SYNC or POLL reply.
        reply_timeout: Duration,
    },
    /// The payload pushes to port 11; the PC streams its file during the session.
    Buffering,
}

impl SessionMode {
    /// Polling with the default period and timeout.
    pub fn polling() -> Self {
        SessionMode::Polling {
            poll_period: DEFAULT_POLL_PERIOD,
            reply_timeout: DEFAULT_REPLY_TIMEOUT,
        }
    }
}

/// One payload's session, fixed for the run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionSpec {
    /// Session id used by SETUP, STATUS and ABORT.
    pub session_id: u8,
    /// The payload's CSP address (12..=15).
    pub payload_addr: u8,
    /// The payload's SYNC/POLL port (10).
    pub payload_port: u8,
    /// Polling or buffering.
    pub mode: SessionMode,
    /// Capacity of the payload's buffer file, bytes.
    pub buffer_capacity_bytes: u64,
}

impl SessionSpec {
    /// A polling session with the default period and timeout on port 10.
    pub fn polling(session_id: u8, payload_addr: u8) -> Self {
        SessionSpec {
            session_id,
            payload_addr,
            payload_port: wire::PORT_PAYLOAD,
            mode: SessionMode::polling(),
            buffer_capacity_bytes: DEFAULT_BUFFER_CAPACITY_BYTES,
        }
    }
    /// A buffering session with the default file capacity.
    pub fn buffering(session_id: u8, payload_addr: u8) -> Self {
        SessionSpec {
            mode: SessionMode::Buffering,
            ..Self::polling(session_id, payload_addr)
        }
    }
}

/// Something a scenario does to the PC's S-band at a time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcEvent {
    /// The transmitter fails: queue lost, ACTIVE session ends with S-BAND FAILURE.
    SbandFail,
    /// The transmitter recovers.
    SbandRestore,
    /// The transmitter is switched off (queue kept, nothing sent).
    SbandOff,
    /// The transmitter is switched on.
    SbandOn,
}

/// A [`PcEvent`] at a simulated time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimedPcEvent {
    /// When.
    pub at: SimTime,
    /// What.
    pub event: PcEvent,
}

/// What the PC needs from the scenario (fixed for the run).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PcConfig {
    /// At most [`MAX_SESSIONS`], one per payload (extra ones are ignored).
    pub sessions: Vec<SessionSpec>,
    /// The S-band transmitter.
    pub sband: SbandConfig,
    /// Session control port (10).
    pub control_port: u8,
    /// Buffered data ingest port (11).
    pub ingest_port: u8,
    /// PC telemetry port (12).
    pub telemetry_port: u8,
    /// Buffer files port (13, the twin's: FLIST, FSTAT, FREAD, FDELETE).
    pub files_port: u8,
    /// Scenario events (sorted by time when the app is built).
    pub timeline: Vec<TimedPcEvent>,
    /// Whether payloads are refused SETUP and ABORT (ICD 3.1.1) and the buffer files (ICD
    /// 3.1.5), the default, or may use them (a lab bench).
    pub payload_access: platform::addr::PayloadAccess,
}

impl Default for PcConfig {
    /// Session 1: payload 12 port 10, polling; session 2: payload 13 port 10, buffering.
    fn default() -> Self {
        PcConfig {
            sessions: vec![SessionSpec::polling(1, 12), SessionSpec::buffering(2, 13)],
            sband: SbandConfig::default(),
            control_port: wire::PORT_CONTROL,
            ingest_port: wire::PORT_INGEST,
            telemetry_port: wire::PORT_TELEMETRY,
            files_port: wire::PORT_FILES,
            timeline: Vec::new(),
            payload_access: platform::addr::PayloadAccess::default(),
        }
    }
}

/// What is wrong with a PC configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PcConfigError {
    /// More sessions than the PC has slots.
    #[error("{count} sessions configured; the PC serves at most {}", MAX_SESSIONS)]
    TooManySessions {
        /// Sessions configured.
        count: usize,
    },
    /// A session's payload address is not a payload's.
    #[error("session {session_id}: payload address {addr} is not a payload (12-15)")]
    PayloadAddr {
        /// The session.
        session_id: u8,
        /// The address.
        addr: u8,
    },
    /// A session's payload port is beyond CSP's ports.
    #[error("session {session_id}: payload port {port} > 63")]
    PayloadPort {
        /// The session.
        session_id: u8,
        /// The port.
        port: u8,
    },
    /// Two sessions with one id.
    #[error("session id {session_id} repeated")]
    RepeatedId {
        /// The id.
        session_id: u8,
    },
    /// Two sessions for one payload.
    #[error("payload {addr} has two sessions ({first} and {second})")]
    TwoSessions {
        /// The payload's address.
        addr: u8,
        /// The first session's id.
        first: u8,
        /// The second session's id.
        second: u8,
    },
    /// A polling session whose replies could never arrive in time.
    #[error("session {session_id}: reply timeout 0")]
    ZeroTimeout {
        /// The session.
        session_id: u8,
    },
    /// A PC port in the ephemeral range (control, ingest, telemetry).
    #[error("PC ports {ports:?}: each must be below 32")]
    PortRange {
        /// Control, ingest and telemetry ports.
        ports: [u8; 3],
    },
    /// Two of the PC's ports are one (control, ingest, telemetry).
    #[error("PC ports {ports:?} must differ")]
    PortsEqual {
        /// Control, ingest and telemetry ports.
        ports: [u8; 3],
    },
    /// S-band frames that carry nothing.
    #[error("S-band frame_data_bytes 0")]
    ZeroFrame,
}

impl PcConfig {
    /// Check the configuration (for the scenario loader); the error names the problem.
    pub fn validate(&self) -> Result<(), PcConfigError> {
        if self.sessions.len() > MAX_SESSIONS {
            return Err(PcConfigError::TooManySessions {
                count: self.sessions.len(),
            });
        }
        for (i, s) in self.sessions.iter().enumerate() {
            if !(12..=15).contains(&s.payload_addr) {
                return Err(PcConfigError::PayloadAddr {
                    session_id: s.session_id,
                    addr: s.payload_addr,
                });
            }
            if s.payload_port > csp::header::MAX_PORT {
                return Err(PcConfigError::PayloadPort {
                    session_id: s.session_id,
                    port: s.payload_port,
                });
            }
            for o in self.sessions.iter().skip(i + 1) {
                if o.session_id == s.session_id {
                    return Err(PcConfigError::RepeatedId {
                        session_id: s.session_id,
                    });
                }
                if o.payload_addr == s.payload_addr {
                    return Err(PcConfigError::TwoSessions {
                        addr: s.payload_addr,
                        first: s.session_id,
                        second: o.session_id,
                    });
                }
            }
            if let SessionMode::Polling { reply_timeout, .. } = s.mode
                && reply_timeout.is_zero()
            {
                return Err(PcConfigError::ZeroTimeout {
                    session_id: s.session_id,
                });
            }
        }
        let ports = [self.control_port, self.ingest_port, self.telemetry_port];
        if ports.iter().any(|&p| p >= csp::header::EPHEMERAL_PORT_MIN) {
            return Err(PcConfigError::PortRange { ports });
        }
        if ports[0] == ports[1] || ports[0] == ports[2] || ports[1] == ports[2] {
            return Err(PcConfigError::PortsEqual { ports });
        }
        if self.sband.frame_data_bytes == 0 {
            return Err(PcConfigError::ZeroFrame);
        }
        Ok(())
    }
}

/// Why payload bytes were dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum DropReason {
    /// The buffer file had no room for the whole ingest packet.
    BufferFull,
    /// A POLL reply longer than the frame size, or an ingest packet over 256 bytes.
    Oversize,
    /// A POLL reply after its request timed out or was answered, or from the wrong port.
    Late,
    /// Left in the buffer file when the session ended (the file is flushed).
    SessionEnded,
    /// Lost with the S-band transmitter's queue when it failed.
    SbandFailure,
    /// From an address that is not a payload of a matching session.
    UnknownSource,
    /// Lost at a PC reboot (volatile memory).
    PowerLoss,
    /// A reply to a POLL with the wrong command id or without a result byte.
    Malformed,
    /// In a buffer file emptied by FDELETE.
    Deleted,
}

impl DropReason {
    /// Every reason, in order.
    pub const ALL: [DropReason; 9] = [
        DropReason::BufferFull,
        DropReason::Oversize,
        DropReason::Late,
        DropReason::SessionEnded,
        DropReason::SbandFailure,
        DropReason::UnknownSource,
        DropReason::PowerLoss,
        DropReason::Malformed,
        DropReason::Deleted,
    ];
    /// A short name for logs and tables.
    pub fn as_str(self) -> &'static str {
        match self {
            DropReason::BufferFull => "buffer-full",
            DropReason::Oversize => "oversize",
            DropReason::Late => "late",
            DropReason::SessionEnded => "session-ended",
            DropReason::SbandFailure => "sband-failure",
            DropReason::UnknownSource => "unknown-source",
            DropReason::PowerLoss => "power-loss",
            DropReason::Malformed => "malformed",
            DropReason::Deleted => "deleted",
        }
    }
    fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for DropReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Where the payload bytes of one session (or of no session) went.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Ledger {
    /// Payload bytes the PC received.
    pub received: u64,
    /// Bytes that reached the ground.
    pub downlinked: u64,
    /// Bytes dropped, by reason (reasons with no bytes left out).
    pub dropped: BTreeMap<DropReason, u64>,
    /// Bytes in the buffer file now.
    pub buffered_now: u64,
    /// Bytes in the S-band queue or on the air now.
    pub queued_now: u64,
}

impl Ledger {
    /// All dropped bytes.
    pub fn dropped_total(&self) -> u64 {
        self.dropped.values().sum()
    }
    /// Dropped bytes for one reason.
    pub fn dropped(&self, reason: DropReason) -> u64 {
        self.dropped.get(&reason).copied().unwrap_or(0)
    }
    /// Whether `received = downlinked + dropped + buffered + queued`.
    pub fn is_balanced(&self) -> bool {
        self.received
            == self.downlinked + self.dropped_total() + self.buffered_now + self.queued_now
    }
    fn add(&mut self, o: &Ledger) {
        self.received += o.received;
        self.downlinked += o.downlinked;
        for (r, n) in &o.dropped {
            *self.dropped.entry(*r).or_default() += n;
        }
        self.buffered_now += o.buffered_now;
        self.queued_now += o.queued_now;
    }
}

/// The ledger of one configured session.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionAccounting {
    /// Session id.
    pub session_id: u8,
    /// Its payload.
    pub payload_addr: u8,
    /// Its bytes.
    pub bytes: Ledger,
}

/// Where every payload byte went, since the start of the run (reboots included).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Accounting {
    /// Per configured session, in configuration order.
    pub sessions: Vec<SessionAccounting>,
    /// Bytes from sources that match no session (always dropped, UnknownSource).
    pub unattributed: Ledger,
}

impl Accounting {
    /// All sessions and the unattributed bytes together.
    pub fn total(&self) -> Ledger {
        let mut t = self.unattributed.clone();
        for s in &self.sessions {
            t.add(&s.bytes);
        }
        t
    }
    /// Whether every ledger balances.
    pub fn is_balanced(&self) -> bool {
        self.unattributed.is_balanced() && self.sessions.iter().all(|s| s.bytes.is_balanced())
    }
    /// The ledger of a session id.
    pub fn session(&self, session_id: u8) -> Option<&Ledger> {
        self.sessions
            .iter()
            .find(|s| s.session_id == session_id)
            .map(|s| &s.bytes)
    }
}

/// What the PC tells the twin.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PcOutput {
    /// A session became ACTIVE.
    SessionStarted {
        /// When.
        t: SimTime,
        /// Which.
        session_id: u8,
        /// The session's payload.
        payload_addr: u8,
    },
    /// A session ended with its result.
    SessionEnded {
        /// When.
        t: SimTime,
        /// Which.
        session_id: u8,
        /// The recorded result.
        result: SessionResult,
        /// Packets counted.
        packets: u32,
    },
    /// An ACTIVE session's run was lost with the PC's volatile memory (its session table):
    /// it has no ICD result, and nothing follows it; a new SETUP starts a new run.
    SessionLost {
        /// When.
        t: SimTime,
        /// Which.
        session_id: u8,
        /// What took the PC's memory.
        cause: LostCause,
        /// Packets counted before.
        packets: u32,
    },
    /// Payload bytes reached the ground (the last bit of their S-band frame left).
    Downlinked {
        /// When.
        t: SimTime,
        /// The session whose bytes they are.
        session_id: u8,
        /// Its payload.
        payload_addr: u8,
        /// The bytes, in order.
        bytes: Vec<u8>,
    },
    /// Payload bytes were dropped.
    Dropped {
        /// When.
        t: SimTime,
        /// The session they belonged to, if any.
        session_id: Option<u8>,
        /// The payload (or unknown source) they came from.
        payload_addr: u8,
        /// Why.
        reason: DropReason,
        /// How many.
        bytes: u64,
    },
    /// The run ended ([`App::finish`]): where every payload byte went, including the bytes
    /// still held in buffer files and the S-band queue.
    Final {
        /// When.
        t: SimTime,
        /// The ledgers at the end of the run.
        accounting: Accounting,
    },
}

/// A session's state, as STATUS reports it plus what the twin wants to see.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionStatus {
    /// Session id.
    pub session_id: u8,
    /// Its payload.
    pub payload_addr: u8,
    /// ICD state.
    pub state: SessionState,
    /// Result of the last finished session.
    pub last_result: SessionResult,
    /// The last accepted SETUP.
    pub config: Option<SessionConfig>,
    /// Packets counted in the current (or last) session.
    pub packets: u32,
}

/// Event counters of the PC (since the start of the run).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PcCounters {
    /// Requests on ports 10 and 12 answered with failure.
    pub refused: u64,
    /// Of those, requests from payloads refused by [`PcConfig::payload_access`]: SETUP,
    /// ABORT and anything on the files port.
    pub denied: u64,
    /// FREAD requests answered.
    pub file_reads: u64,
    /// Bytes FREAD returned.
    pub file_bytes_read: u64,
    /// FDELETE requests answered.
    pub file_deletes: u64,
    /// SYNC requests sent.
    pub syncs_sent: u64,
    /// POLL requests sent (retries included).
    pub polls_sent: u64,
    /// POLL retries (second and third attempts).
    pub poll_retries: u64,
    /// POLL cycles that failed three times (counter advanced without data).
    pub polls_given_up: u64,
    /// Replies to a SYNC that was already settled (not payload data, not in the ledger).
    pub late_sync_replies: u64,
    /// Ingest packets accepted into a file.
    pub ingest_packets: u64,
    /// S-band frames delivered.
    pub frames_sent: u64,
}

/// A byte FIFO (a payload's buffer file).
#[derive(Debug, Clone, Default)]
struct ByteFifo {
    buf: Vec<u8>,
    head: usize,
    /// Bytes taken or cleared from the head since the start of the run: the stream offset
    /// of the first byte held.
    removed: u64,
}

impl ByteFifo {
    fn len(&self) -> usize {
        self.buf.len() - self.head
    }
    fn head_offset(&self) -> u64 {
        self.removed
    }
    /// Up to `n` bytes from `from` bytes past the head, without taking them.
    fn peek(&self, from: usize, n: usize) -> &[u8] {
        let start = self.head.saturating_add(from).min(self.buf.len());
        let end = start.saturating_add(n).min(self.buf.len());
        self.buf.get(start..end).unwrap_or_default()
    }
    fn push(&mut self, b: &[u8]) {
        if self.head > 4096 && self.head * 2 > self.buf.len() {
            self.buf.drain(..self.head);
            self.head = 0;
        }
        self.buf.extend_from_slice(b);
    }
    fn take(&mut self, n: usize) -> &[u8] {
        let start = self.head;
        let n = n.min(self.len());
        self.head += n;
        self.removed += n as u64;
        self.buf.get(start..self.head).unwrap_or_default()
    }
    fn clear(&mut self) -> u64 {
        let n = self.len() as u64;
        self.buf = Vec::new();
        self.head = 0;
        self.removed += n;
        n
    }
}

/// Byte counts of a ledger, without the "now" parts.
#[derive(Debug, Clone, Copy, Default)]
struct RawLedger {
    received: u64,
    downlinked: u64,
    dropped: [u64; DropReason::ALL.len()],
}

impl RawLedger {
    fn ledger(&self, buffered_now: u64, queued_now: u64) -> Ledger {
        Ledger {
            received: self.received,
            downlinked: self.downlinked,
            dropped: DropReason::ALL
                .iter()
                .filter_map(|&r| {
                    let n = self.dropped.get(r.index()).copied().unwrap_or(0);
                    (n > 0).then_some((r, n))
                })
                .collect(),
            buffered_now,
            queued_now,
        }
    }
}

/// What an ACTIVE polling session waits for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Not polling (buffering, or not ACTIVE).
    Idle,
    /// SYNC sent; `port` is `None` if no port could be allocated (it times out).
    Sync { port: Option<u8>, deadline: SimTime },
    /// Polling: cycle started at `cycle_start`, attempt `attempt` (1-3).
    Poll {
        cycle_start: SimTime,
        attempt: u8,
        wait: Wait,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Wait {
    /// A POLL is out.
    Reply { port: Option<u8>, deadline: SimTime },
    /// The next cycle starts then.
    Next(SimTime),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ReqKind {
    Sync,
    Poll,
}

/// An ephemeral port the PC sent a request from.
#[derive(Debug, Clone, Copy)]
struct PortUse {
    slot: usize,
    kind: ReqKind,
    /// The request waits for its reply on this port.
    live: bool,
}

/// Run-time state of one slot besides the table's.
#[derive(Debug, Clone, Default)]
struct Run {
    phase: Option<Phase>,
    file: ByteFifo,
    ledger: RawLedger,
    tm_downlinked: u64,
    tm_dropped: u64,
}

/// The payload controller's application (see the module doc).
#[derive(Debug)]
pub struct PcApp {
    cfg: PcConfig,
    table: SessionTable,
    runs: Vec<Run>,
    sband: Sband,
    ports: BTreeMap<u8, PortUse>,
    retired: VecDeque<u8>,
    timeline_next: usize,
    unattributed: RawLedger,
    tm_sband_downlinked: u64,
    counters: PcCounters,
    out: Outbox<PcOutput>,
    log: Vec<NodeEvent>,
    /// Where the S-band's transmissions are posted for the EPS and its power is read.
    activity: Option<platform::board::ActivityBoard>,
    /// The transmitter is off because its power channel is (not by a scenario event).
    unpowered: bool,
    /// Each address's last refused request, for WHY.
    refusals: Refusals,
}

impl PcApp {
    /// A PC with `cfg` (at most [`MAX_SESSIONS`] sessions are used; the timeline is sorted).
    pub fn new(mut cfg: PcConfig) -> Self {
        let mut log = Vec::new();
        if cfg.sessions.len() > MAX_SESSIONS {
            log.push(NodeEvent::info(
                SimTime::ZERO,
                format!(
                    "config: {} sessions, only the first {MAX_SESSIONS} are served",
                    cfg.sessions.len()
                ),
            ));
            cfg.sessions.truncate(MAX_SESSIONS);
        }
        cfg.timeline.sort_by_key(|e| e.at);
        PcApp {
            table: SessionTable::new(&cfg.sessions),
            runs: vec![Run::default(); cfg.sessions.len()],
            sband: Sband::new(cfg.sband),
            ports: BTreeMap::new(),
            retired: VecDeque::new(),
            timeline_next: 0,
            unattributed: RawLedger::default(),
            tm_sband_downlinked: 0,
            counters: PcCounters::default(),
            out: Outbox::default(),
            log,
            activity: None,
            unpowered: false,
            refusals: Refusals::default(),
            cfg,
        }
    }

    /// Post the S-band's transmissions (`Activity::SbandTx`, frame by frame) for the EPS,
    /// and follow its power channel (`Activity::SbandPowerOff`, posted by the twin from the
    /// EPS): the transmitter notices a power change at its next frame boundary (a frame is
    /// 10.2 ms at 1 Mbit/s); unpowered it behaves as switched off (the queue is kept).
    pub fn with_activity(mut self, board: platform::board::ActivityBoard) -> Self {
        self.activity = Some(board);
        self
    }

    fn tx_activity(&mut self, t: SimTime, on: bool) {
        if let Some(a) = &self.activity
            && let Err(e) = a.set(platform::board::Activity::SbandTx, t, on)
        {
            self.log
                .push(NodeEvent::warning(t, format!("pc: S-band activity: {e}")));
        }
    }

    /// Follow the S-band power channel (see [`PcApp::with_activity`]).
    fn follow_power(&mut self, t: SimTime) {
        let Some(a) = &self.activity else { return };
        let off = a.on_before(platform::board::Activity::SbandPowerOff, t);
        if off && !self.unpowered {
            self.unpowered = true;
            if self.sband.is_transmitting() {
                self.tx_activity(t, false);
            }
            self.sband.set_on(false);
            self.log.push(NodeEvent::info(
                t,
                "pc: S-band power channel off".to_owned(),
            ));
        } else if !off && self.unpowered {
            self.unpowered = false;
            self.sband.set_on(true);
            self.log
                .push(NodeEvent::info(t, "pc: S-band power channel on".to_owned()));
        }
    }

    /// The configuration in use.
    pub fn config(&self) -> &PcConfig {
        &self.cfg
    }
    /// Event counters.
    pub fn counters(&self) -> &PcCounters {
        &self.counters
    }
    /// The S-band transmitter.
    pub fn sband(&self) -> &Sband {
        &self.sband
    }

    /// Where every payload byte went so far.
    pub fn accounting(&self) -> Accounting {
        Accounting {
            sessions: self
                .table
                .slots()
                .iter()
                .zip(&self.runs)
                .enumerate()
                .map(|(i, (s, r))| SessionAccounting {
                    session_id: s.spec.session_id,
                    payload_addr: s.spec.payload_addr,
                    bytes: r
                        .ledger
                        .ledger(r.file.len() as u64, self.sband.pending_bytes(i)),
                })
                .collect(),
            unattributed: self.unattributed.ledger(0, 0),
        }
    }

    /// The state of session `session_id`; `None` if it is not configured.
    pub fn status(&self, session_id: u8) -> Option<SessionStatus> {
        let s = self.table.slot(self.table.index_of(session_id)?)?;
        Some(SessionStatus {
            session_id,
            payload_addr: s.spec.payload_addr,
            state: s.state,
            last_result: s.last_result,
            config: s.config.clone(),
            packets: s.packets,
        })
    }

    /// The TMPC reply data now.
    pub fn tmpc(&self) -> Tmpc {
        let mut t = Tmpc::default();
        let sat = |v: u64| u32::try_from(v).unwrap_or(u32::MAX);
        for ((slot, s), r) in t.slots.iter_mut().zip(self.table.slots()).zip(&self.runs) {
            *slot = TmpcSlot {
                session_id: s.spec.session_id,
                payload_addr: s.spec.payload_addr,
                state: s.state.to_u8(),
                last_result: s.last_result.to_u8(),
                packets: s.packets,
                downlinked_bytes: sat(r.tm_downlinked),
                dropped_bytes: sat(r.tm_dropped),
                buffer_bytes: sat(r.file.len() as u64),
            };
        }
        let flag = |on: bool, bit: u8| if on { bit } else { 0 };
        t.sband_flags = flag(self.sband.is_on(), wire::SBAND_ON)
            | flag(self.sband.is_failed(), wire::SBAND_FAILED)
            | flag(self.sband.is_transmitting(), wire::SBAND_TRANSMITTING);
        t.sband_queue_bytes = sat(self.sband.total_pending_bytes());
        t.sband_downlinked_bytes = sat(self.tm_sband_downlinked);
        t
    }

    // ---- buffer files (ICD 3.1.5: "a regular file system interface") ----

    /// The slot of `payload_addr`'s buffer file (its buffering session).
    fn file_slot(&self, payload_addr: u8) -> Option<usize> {
        self.table.slots().iter().position(|s| {
            s.spec.payload_addr == payload_addr && s.spec.mode == SessionMode::Buffering
        })
    }

    fn file_stat(&self, i: usize) -> FileStat {
        let sat = |v: u64| u32::try_from(v).unwrap_or(u32::MAX);
        let file = self.runs.get(i).map(|r| &r.file);
        FileStat {
            payload_addr: self.payload_addr(i),
            session_id: self.session_id(i),
            size_bytes: sat(file.map_or(0, |f| f.len() as u64)),
            capacity_bytes: sat(self.spec(i).map_or(0, |s| s.buffer_capacity_bytes)),
            head_offset: file.map_or(0, ByteFifo::head_offset),
        }
    }

    fn files(&mut self, c: FilesCommand, src: u8, now: SimTime) -> Result<Vec<u8>, Reason> {
        let no_file = |payload_addr| Reason::NoFile { payload_addr };
        let slot = |a| self.file_slot(a).ok_or(no_file(a));
        match c {
            FilesCommand::List => {
                let slots: Vec<usize> = (0..self.table.slots().len())
                    .filter(|&i| {
                        self.spec(i)
                            .is_some_and(|s| s.mode == SessionMode::Buffering)
                    })
                    .collect();
                let mut v = vec![u8::try_from(slots.len()).unwrap_or(u8::MAX)];
                for i in slots {
                    self.file_stat(i).emit(&mut v);
                }
                Ok(v)
            }
            FilesCommand::Stat { payload_addr } => Ok(self.file_stat(slot(payload_addr)?).to_vec()),
            FilesCommand::Read(q) => {
                let i = slot(q.payload_addr)?;
                let file = &self.runs.get(i).ok_or(no_file(q.payload_addr))?.file;
                let head = file.head_offset();
                let end = head + file.len() as u64;
                let served = q.offset.clamp(head, end);
                let from = usize::try_from(served - head).unwrap_or(usize::MAX);
                let data = file.peek(from, usize::from(q.length));
                let mut v = served.to_le_bytes().to_vec();
                v.extend_from_slice(data);
                self.counters.file_reads += 1;
                self.counters.file_bytes_read += data.len() as u64;
                Ok(v)
            }
            FilesCommand::Delete { payload_addr } => {
                let i = slot(payload_addr)?;
                let n = self.runs.get_mut(i).map_or(0, |r| r.file.clear());
                self.counters.file_deletes += 1;
                self.log.push(NodeEvent::info(
                    now,
                    format!(
                        "pc: buffer file of payload {payload_addr} deleted by {src}: {n} bytes"
                    ),
                ));
                if n > 0 {
                    self.drop_bytes(now, Some(i), payload_addr, DropReason::Deleted, n);
                }
                Ok(u32::try_from(n).unwrap_or(u32::MAX).to_le_bytes().to_vec())
            }
        }
    }

    // ---- outputs and bookkeeping ----

    fn emit(&mut self, o: PcOutput) {
        self.out.push(o);
    }

    fn session_id(&self, i: usize) -> u8 {
        self.table.slot(i).map_or(0, |s| s.spec.session_id)
    }
    fn payload_addr(&self, i: usize) -> u8 {
        self.table.slot(i).map_or(0, |s| s.spec.payload_addr)
    }

    fn received(&mut self, slot: Option<usize>, n: usize) {
        let l = match slot.and_then(|i| self.runs.get_mut(i)) {
            Some(r) => &mut r.ledger,
            None => &mut self.unattributed,
        };
        l.received += n as u64;
    }

    fn drop_bytes(
        &mut self,
        t: SimTime,
        slot: Option<usize>,
        payload_addr: u8,
        reason: DropReason,
        n: u64,
    ) {
        let run = slot.and_then(|i| self.runs.get_mut(i));
        let l = match run {
            Some(r) => {
                r.tm_dropped += n;
                &mut r.ledger
            }
            None => &mut self.unattributed,
        };
        if let Some(d) = l.dropped.get_mut(reason.index()) {
            *d += n;
        }
        let session_id = slot.map(|i| self.session_id(i));
        self.log.push(NodeEvent::dropped(
            t,
            csp::drop::DropCause::app(format!("pc {reason}")),
            format!(
                "{n} bytes from payload {payload_addr}{}",
                session_id.map_or(String::new(), |id| format!(", session {id}"))
            ),
        ));
        if n > 0 {
            self.emit(PcOutput::Dropped {
                t,
                session_id,
                payload_addr,
                reason,
                bytes: n,
            });
        }
    }

    fn flush_log(&mut self, node: &mut Node) {
        for e in self.log.drain(..) {
            node.push_event(e);
        }
    }

    // ---- ports used for requests ----

    fn send_request(
        &mut self,
        node: &mut Node,
        slot: usize,
        kind: ReqKind,
        data: Vec<u8>,
        t: SimTime,
    ) -> Option<u8> {
        let (dst, dport) = self
            .table
            .slot(slot)
            .map(|s| (s.spec.payload_addr, s.spec.payload_port))?;
        let port = loop {
            if let Some(p) = node.alloc_port() {
                break p;
            }
            // Every ephemeral port is taken: give up the oldest retired one.
            let Some(old) = self.retired.pop_front() else {
                self.log.push(NodeEvent::info(
                    t,
                    "pc: no free ephemeral port for a request".to_owned(),
                ));
                return None;
            };
            node.unbind(old);
            self.ports.remove(&old);
        };
        match kind {
            ReqKind::Sync => self.counters.syncs_sent += 1,
            ReqKind::Poll => self.counters.polls_sent += 1,
        }
        if let Err(e) = node.send(
            Packet::new(Header::new(node.addr(), dst, dport, port), data),
            t,
        ) {
            // The request is lost; it times out like an unanswered one.
            self.log.push(NodeEvent::info(
                t,
                format!("pc: request to {dst}:{dport} not sent: {e}"),
            ));
        }
        self.ports.insert(
            port,
            PortUse {
                slot,
                kind,
                live: true,
            },
        );
        Some(port)
    }

    fn retire(&mut self, node: &mut Node, port: Option<u8>) {
        let Some(port) = port else { return };
        if let Some(u) = self.ports.get_mut(&port)
            && u.live
        {
            u.live = false;
            self.retired.push_back(port);
            while self.retired.len() > RETIRED_PORTS_MAX {
                if let Some(old) = self.retired.pop_front() {
                    node.unbind(old);
                    self.ports.remove(&old);
                }
            }
        }
    }

    // ---- sessions ----

    fn spec(&self, i: usize) -> Option<&SessionSpec> {
        self.table.slot(i).map(|s| &s.spec)
    }
    fn frame_size(&self, i: usize) -> u8 {
        self.table
            .slot(i)
            .and_then(|s| s.config.as_ref())
            .map_or(1, |c| c.poll_frame_size)
    }
    fn max_packets(&self, i: usize) -> u16 {
        self.table
            .slot(i)
            .and_then(|s| s.config.as_ref())
            .map_or(0, |c| c.max_packets)
    }
    fn polling_params(&self, i: usize) -> Option<(Duration, Duration)> {
        match self.spec(i)?.mode {
            SessionMode::Polling {
                poll_period,
                reply_timeout,
            } => Some((poll_period, reply_timeout.max(MIN_REPLY_TIMEOUT))),
            SessionMode::Buffering => None,
        }
    }
    fn set_phase(&mut self, i: usize, p: Phase) {
        if let Some(r) = self.runs.get_mut(i) {
            r.phase = Some(p);
        }
    }
    fn phase(&self, i: usize) -> Phase {
        self.runs
            .get(i)
            .and_then(|r| r.phase)
            .unwrap_or(Phase::Idle)
    }

    fn activate(&mut self, node: &mut Node, i: usize, t: SimTime) {
        self.table.activate(i, t);
        let id = self.session_id(i);
        self.log
            .push(NodeEvent::info(t, format!("pc: session {id} ACTIVE")));
        let payload_addr = self.table.slot(i).map_or(0, |s| s.spec.payload_addr);
        self.emit(PcOutput::SessionStarted {
            t,
            session_id: id,
            payload_addr,
        });
        if self.table.slot(i).is_some_and(|s| s.end_at <= t) {
            self.end_session(node, i, SessionResult::Done, t);
            return;
        }
        if self.sband.is_failed() {
            self.end_session(node, i, SessionResult::SbandFailure, t);
            return;
        }
        if let Some((_, timeout)) = self.polling_params(i) {
            let msg = self
                .table
                .slot(i)
                .and_then(|s| s.config.as_ref())
                .map(|c| c.sync_message.clone())
                .unwrap_or_default();
            let port = self.send_request(node, i, ReqKind::Sync, wire::sync_request(&msg), t);
            self.set_phase(
                i,
                Phase::Sync {
                    port,
                    deadline: t + timeout,
                },
            );
        } else {
            self.set_phase(i, Phase::Idle);
        }
        self.kick(node, t);
    }

    fn end_session(&mut self, node: &mut Node, i: usize, result: SessionResult, t: SimTime) {
        let live: Vec<u8> = self
            .ports
            .iter()
            .filter(|(_, u)| u.slot == i && u.live)
            .map(|(p, _)| *p)
            .collect();
        for p in live {
            self.retire(node, Some(p));
        }
        self.set_phase(i, Phase::Idle);
        self.table.finish(i, result);
        let id = self.session_id(i);
        let packets = self.table.slot(i).map_or(0, |s| s.packets);
        self.log.push(NodeEvent::info(
            t,
            format!("pc: session {id} ended {result:?} after {packets} packets"),
        ));
        self.emit(PcOutput::SessionEnded {
            t,
            session_id: id,
            result,
            packets,
        });
        if self
            .spec(i)
            .is_some_and(|s| s.mode == SessionMode::Buffering)
        {
            let n = self.runs.get_mut(i).map_or(0, |r| r.file.clear());
            let reason = if result == SessionResult::SbandFailure {
                DropReason::SbandFailure
            } else {
                DropReason::SessionEnded
            };
            if n > 0 {
                let addr = self.payload_addr(i);
                self.drop_bytes(t, Some(i), addr, reason, n);
            }
        }
    }

    fn start_cycle(&mut self, node: &mut Node, i: usize, t: SimTime) {
        self.send_poll(node, i, t, t, 1);
    }

    fn send_poll(
        &mut self,
        node: &mut Node,
        i: usize,
        cycle_start: SimTime,
        t: SimTime,
        attempt: u8,
    ) {
        let Some((_, timeout)) = self.polling_params(i) else {
            return;
        };
        let frame = self.frame_size(i);
        let port = self.send_request(node, i, ReqKind::Poll, wire::poll_request(frame), t);
        self.set_phase(
            i,
            Phase::Poll {
                cycle_start,
                attempt,
                wait: Wait::Reply {
                    port,
                    deadline: t + timeout,
                },
            },
        );
    }

    fn failed_attempt(&mut self, node: &mut Node, i: usize, t: SimTime) {
        let Phase::Poll {
            cycle_start,
            attempt,
            ..
        } = self.phase(i)
        else {
            return;
        };
        if attempt < POLL_ATTEMPTS {
            self.counters.poll_retries += 1;
            self.send_poll(node, i, cycle_start, t, attempt + 1);
        } else {
            self.counters.polls_given_up += 1;
            self.complete_cycle(node, i, t);
        }
    }

    fn complete_cycle(&mut self, node: &mut Node, i: usize, t: SimTime) {
        let Phase::Poll {
            cycle_start,
            attempt,
            ..
        } = self.phase(i)
        else {
            return;
        };
        let packets = match self.table.slot_mut(i) {
            Some(s) => {
                s.packets = s.packets.saturating_add(1);
                s.packets
            }
            None => return,
        };
        let max = self.max_packets(i);
        if max > 0 && packets >= u32::from(max) {
            self.end_session(node, i, SessionResult::Done, t);
            return;
        }
        let period = self.polling_params(i).map_or(Duration::ZERO, |p| p.0);
        self.set_phase(
            i,
            Phase::Poll {
                cycle_start,
                attempt,
                wait: Wait::Next((cycle_start + period).max(t)),
            },
        );
    }

    /// Start an S-band frame if possible, first topping the transmitter's queue up to a
    /// frame's worth from the ACTIVE buffering session's file.
    fn kick(&mut self, node: &mut Node, t: SimTime) {
        self.follow_power(t);
        if !self.sband.can_send() || self.sband.is_transmitting() {
            return;
        }
        let mut limit_reached = None;
        let target = self.sband.frame_data_bytes();
        if self.sband.queued_bytes() < target as u64
            && let Some(a) = self.table.active()
            && self
                .spec(a)
                .is_some_and(|s| s.mode == SessionMode::Buffering)
        {
            let frame = usize::from(self.frame_size(a).max(1));
            let max = u32::from(self.max_packets(a));
            let mut moved = usize::try_from(self.sband.queued_bytes()).unwrap_or(usize::MAX);
            let mut packets = self.table.slot(a).map_or(0, |s| s.packets);
            if let Some(run) = self.runs.get_mut(a) {
                while moved < target && run.file.len() > 0 && (max == 0 || packets < max) {
                    let chunk = run.file.take(frame);
                    moved += chunk.len();
                    self.sband.push(a, chunk);
                    packets += 1;
                }
            }
            if let Some(s) = self.table.slot_mut(a) {
                s.packets = packets;
            }
            if max > 0 && packets >= max {
                limit_reached = Some(a);
            }
        }
        if self.sband.start_frame(t) {
            self.tx_activity(t, true);
        }
        if let Some(a) = limit_reached {
            self.end_session(node, a, SessionResult::Done, t);
        }
    }

    fn apply_event(&mut self, node: &mut Node, ev: PcEvent, t: SimTime) {
        self.log
            .push(NodeEvent::info(t, format!("pc: S-band event {ev:?}")));
        match ev {
            PcEvent::SbandFail => {
                if self.sband.is_transmitting() {
                    self.tx_activity(t, false);
                }
                for (slot, n) in self.sband.fail() {
                    let addr = self.payload_addr(slot);
                    self.drop_bytes(t, Some(slot), addr, DropReason::SbandFailure, n);
                }
                if let Some(a) = self.table.active() {
                    self.end_session(node, a, SessionResult::SbandFailure, t);
                }
            }
            PcEvent::SbandRestore => self.sband.restore(),
            PcEvent::SbandOff => {
                if self.sband.is_transmitting() {
                    self.tx_activity(t, false);
                }
                self.sband.set_on(false);
            }
            PcEvent::SbandOn => self.sband.set_on(true),
        }
        self.kick(node, t);
    }

    fn next_due(&self) -> Option<SimTime> {
        let mut due = [
            self.cfg.timeline.get(self.timeline_next).map(|e| e.at),
            self.sband.poll_timeout(),
            self.table.poll_timeout(),
            None,
        ];
        if let Some(a) = self.table.active() {
            due[3] = match self.phase(a) {
                Phase::Idle => None,
                Phase::Sync { deadline, .. } => Some(deadline),
                Phase::Poll { wait, .. } => Some(match wait {
                    Wait::Reply { deadline, .. } => deadline,
                    Wait::Next(n) => n,
                }),
            };
        }
        due.into_iter().flatten().min()
    }

    /// Everything due at `t` (the earliest due time).
    fn step(&mut self, node: &mut Node, t: SimTime) {
        while let Some(ev) = self.cfg.timeline.get(self.timeline_next).copied()
            && ev.at <= t
        {
            self.timeline_next += 1;
            self.apply_event(node, ev.event, t);
        }
        while let Some(frame) = self.sband.complete(t) {
            self.tx_activity(t, false);
            let n = frame.bytes.len() as u64;
            self.counters.frames_sent += 1;
            self.tm_sband_downlinked += n;
            if let Some(r) = self.runs.get_mut(frame.slot) {
                r.ledger.downlinked += n;
                r.tm_downlinked += n;
            }
            let (session_id, payload_addr) =
                (self.session_id(frame.slot), self.payload_addr(frame.slot));
            self.emit(PcOutput::Downlinked {
                t,
                session_id,
                payload_addr,
                bytes: frame.bytes,
            });
            self.kick(node, t);
        }
        if let Some(a) = self.table.active() {
            if self.table.slot(a).is_some_and(|s| s.end_at <= t) {
                self.end_session(node, a, SessionResult::Done, t);
            } else {
                match self.phase(a) {
                    Phase::Sync { port, deadline } if deadline <= t => {
                        self.retire(node, port);
                        self.log
                            .push(NodeEvent::info(t, "pc: no SYNC reply".to_owned()));
                        self.end_session(node, a, SessionResult::NoAck, t);
                    }
                    Phase::Poll {
                        wait: Wait::Reply { port, deadline },
                        ..
                    } if deadline <= t => {
                        self.retire(node, port);
                        self.failed_attempt(node, a, t);
                    }
                    Phase::Poll {
                        wait: Wait::Next(n),
                        ..
                    } if n <= t => self.start_cycle(node, a, t),
                    _ => {}
                }
            }
        }
        while let Some(i) = self.table.due_start(t) {
            self.activate(node, i, t);
        }
        self.kick(node, t);
    }

    // ---- packets ----

    /// A control request of `src`; `Err` the reason for a refusal.
    fn control(
        &mut self,
        node: &mut Node,
        c: ControlCommand,
        src: u8,
        now: SimTime,
        start_now: &mut Option<usize>,
    ) -> Result<Vec<u8>, Reason> {
        let refused = |this: &mut Self, session_id: u8, why: Refusal| {
            this.log
                .push(NodeEvent::info(now, format!("pc: refused: {why}")));
            Reason::Session {
                session_id,
                refusal: why,
            }
        };
        match c {
            ControlCommand::Setup(cfg) => {
                match self.table.setup(&cfg, now, node.clock_unix_ns(now)) {
                    Ok((i, how)) => {
                        self.log.push(NodeEvent::info(
                            now,
                            format!(
                                "pc: session {} set up ({how:?}): start {} duration {} s, max {} packets of {} bytes, sync {} bytes",
                                cfg.session_id,
                                cfg.timestamp,
                                cfg.duration_s,
                                cfg.max_packets,
                                cfg.poll_frame_size,
                                cfg.sync_message.len()
                            ),
                        ));
                        if how == Accepted::StartNow {
                            *start_now = Some(i);
                        }
                        Ok(Vec::new())
                    }
                    Err(why) => Err(refused(self, cfg.session_id, why)),
                }
            }
            ControlCommand::Status { session_id } => match self.table.index_of(session_id) {
                Some(i) => Ok(self
                    .table
                    .slot(i)
                    .map(|s| s.status().to_vec())
                    .unwrap_or_default()),
                None => Err(refused(
                    self,
                    session_id,
                    Refusal::UnknownSession(session_id),
                )),
            },
            ControlCommand::Abort { session_id } => match self.table.abort(session_id) {
                Ok((i, SessionState::Active)) => {
                    self.end_session(node, i, SessionResult::Aborted, now);
                    Ok(Vec::new())
                }
                Ok(_) => {
                    self.log.push(NodeEvent::info(
                        now,
                        format!("pc: PENDING session {session_id} aborted"),
                    ));
                    Ok(Vec::new())
                }
                Err(why) => Err(refused(self, session_id, why)),
            },
            ControlCommand::Why => Ok(self.refusals.why(src).to_vec()),
        }
    }

    fn ingest(&mut self, node: &mut Node, packet: &Packet, now: SimTime) {
        let src = packet.header.src;
        let n = packet.data.len();
        let Some(i) = self.file_slot(src) else {
            self.received(None, n);
            self.drop_bytes(now, None, src, DropReason::UnknownSource, n as u64);
            return;
        };
        self.received(Some(i), n);
        if n > wire::INGEST_MAX_LEN {
            self.drop_bytes(now, Some(i), src, DropReason::Oversize, n as u64);
            return;
        }
        let capacity = self.spec(i).map_or(0, |s| s.buffer_capacity_bytes);
        let Some(run) = self.runs.get_mut(i) else {
            return;
        };
        if run.file.len() as u64 + n as u64 > capacity {
            self.drop_bytes(now, Some(i), src, DropReason::BufferFull, n as u64);
            return;
        }
        run.file.push(&packet.data);
        self.counters.ingest_packets += 1;
        if self.table.active() == Some(i) {
            self.kick(node, now);
        }
    }

    fn session_reply(&mut self, node: &mut Node, use_: PortUse, packet: &Packet, now: SimTime) {
        let port = packet.header.dport;
        let i = use_.slot;
        let Some(spec) = self.spec(i).cloned() else {
            return;
        };
        let h = packet.header;
        if h.src != spec.payload_addr {
            self.received(None, packet.data.len());
            self.drop_bytes(
                now,
                None,
                h.src,
                DropReason::UnknownSource,
                packet.data.len() as u64,
            );
            return;
        }
        let current = use_.live && h.sport == spec.payload_port;
        match use_.kind {
            ReqKind::Sync => {
                if !current {
                    self.counters.late_sync_replies += 1;
                    self.log.push(NodeEvent::info(
                        now,
                        format!("pc: late SYNC reply from {}", h.src),
                    ));
                    return;
                }
                self.retire(node, Some(port));
                let msg = self
                    .table
                    .slot(i)
                    .and_then(|s| s.config.as_ref())
                    .map(|c| c.sync_message.clone())
                    .unwrap_or_default();
                match Reply::parse(&packet.data) {
                    Ok(r) if r.command == cmd::SYNC && r.data == msg.as_slice() => {
                        self.log
                            .push(NodeEvent::info(now, "pc: SYNC acknowledged".to_owned()));
                        self.set_phase(
                            i,
                            Phase::Poll {
                                cycle_start: now,
                                attempt: 0,
                                wait: Wait::Next(now),
                            },
                        );
                        self.start_cycle(node, i, now);
                    }
                    _ => {
                        self.log.push(NodeEvent::info(
                            now,
                            format!("pc: SYNC answered with {:02x?}", packet.data),
                        ));
                        self.end_session(node, i, SessionResult::NoAck, now);
                    }
                }
            }
            ReqKind::Poll => match Reply::parse(&packet.data) {
                Ok(r) if r.command == cmd::POLL => {
                    let n = r.data.len();
                    self.received(Some(i), n);
                    if !current {
                        self.drop_bytes(now, Some(i), h.src, DropReason::Late, n as u64);
                    } else if n > usize::from(self.frame_size(i)) {
                        self.drop_bytes(now, Some(i), h.src, DropReason::Oversize, n as u64);
                        self.retire(node, Some(port));
                        self.failed_attempt(node, i, now);
                    } else {
                        self.retire(node, Some(port));
                        self.sband.push(i, r.data);
                        self.complete_cycle(node, i, now);
                        self.kick(node, now);
                    }
                }
                _ => {
                    self.received(Some(i), packet.data.len());
                    self.drop_bytes(
                        now,
                        Some(i),
                        h.src,
                        DropReason::Malformed,
                        packet.data.len() as u64,
                    );
                }
            },
        }
    }
}

impl App for PcApp {
    type Event = PcOutput;
    fn poll_event(&mut self) -> Option<PcOutput> {
        self.out.pop()
    }
    fn start(&mut self, node: &mut Node, _now: SimTime) {
        for p in [
            self.cfg.control_port,
            self.cfg.ingest_port,
            self.cfg.telemetry_port,
            self.cfg.files_port,
        ] {
            node.bind(p);
        }
        self.flush_log(node);
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        let dport = packet.header.dport;
        let c = &self.cfg;
        if [c.control_port, c.telemetry_port, c.files_port].contains(&dport) {
            let mut start_now = None;
            let src = packet.header.src;
            let command = packet.data.first().copied();
            // What a payload may not ask: session configuration (ICD 3.1.1) and the file
            // system (ICD 3.1.5).
            let closed = if dport == c.control_port {
                match command {
                    Some(wire::cmd::SETUP) => Some(Denied::Setup),
                    Some(wire::cmd::ABORT) => Some(Denied::Abort),
                    _ => None,
                }
            } else if dport == c.files_port {
                Some(Denied::Files)
            } else {
                None
            };
            // Why the request is refused, if it is (for WHY).
            let mut reason = None;
            let mut keep = |r: Reason| {
                reason = Some(r);
                csp::reqrep::RESULT_FAILURE
            };
            let (reply, refused) = if let Some(why) =
                closed.filter(|_| c.payload_access.refuses(src, false))
            {
                self.counters.denied += 1;
                self.log.push(NodeEvent::warning(
                    now,
                    format!("pc: payload {src} refused {}", why.log_text()),
                ));
                keep(Reason::Denied(why));
                (csp::reqrep::failure(command.unwrap_or(0)), None)
            } else if dport == c.control_port {
                serve::<ControlCommand>(&packet.data, |c| {
                    self.control(node, c, src, now, &mut start_now)
                        .map_err(&mut keep)
                })
            } else if dport == c.files_port {
                serve::<FilesCommand>(&packet.data, |c| self.files(c, src, now).map_err(&mut keep))
            } else {
                serve::<TelemetryCommand>(&packet.data, |_| Ok(self.tmpc().to_vec()))
            };
            if let Some(e) = refused {
                self.log
                    .push(NodeEvent::info(now, format!("pc: request refused: {e}")));
                keep(Reason::Request(e));
            }
            if let Some(reason) = reason {
                self.refusals.record(
                    src,
                    why::Refused {
                        port: dport,
                        command: command.unwrap_or(0),
                        reason,
                    },
                );
            }
            if reply.get(1) != Some(&csp::reqrep::RESULT_SUCCESS) {
                self.counters.refused += 1;
            }
            // A send failure is already counted by the node.
            let _ = node.send(Packet::new(packet.header.reply(node.addr()), reply), now);
            if let Some(i) = start_now {
                self.activate(node, i, now);
            }
        } else if dport == self.cfg.ingest_port {
            self.ingest(node, &packet, now);
        } else if let Some(&u) = self.ports.get(&dport) {
            self.session_reply(node, u, &packet, now);
        }
        self.flush_log(node);
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        self.next_due()
    }

    fn clock_set(&mut self, node: &mut Node, now: SimTime) {
        let clock_ns = node.clock_unix_ns(now);
        for id in self.table.reanchor(now, clock_ns) {
            self.log.push(NodeEvent::info(
                now,
                format!(
                    "pc: clock set to {}.{:09} s: PENDING session {id} starts when it reads its timestamp",
                    clock_ns.div_euclid(1_000_000_000),
                    clock_ns.rem_euclid(1_000_000_000)
                ),
            ));
        }
        self.flush_log(node);
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        for _ in 0..MAX_STEPS {
            match self.next_due() {
                Some(t) if t <= now => self.step(node, t),
                _ => break,
            }
        }
        self.flush_log(node);
    }

    fn finish(&mut self, node: &mut Node, now: SimTime) {
        let accounting = self.accounting();
        let t = accounting.total();
        self.log.push(NodeEvent::info(
            now,
            format!(
                "pc: final accounting: received {} = downlinked {} + dropped {} + buffered {} + queued {} ({})",
                t.received,
                t.downlinked,
                t.dropped_total(),
                t.buffered_now,
                t.queued_now,
                if accounting.is_balanced() {
                    "balanced"
                } else {
                    "NOT balanced"
                }
            ),
        ));
        self.emit(PcOutput::Final { t: now, accounting });
        self.flush_log(node);
    }

    fn power_lost(&mut self, node: &mut Node, now: SimTime) {
        // The buffer file, the S-band queue and the session table are volatile: they are
        // lost at the instant power goes, and the transmitter stops with its data.
        self.lose_volatile(now, LostCause::PowerLoss);
        self.flush_log(node);
    }

    fn params(&mut self) -> Option<&mut dyn csp::params::Table> {
        Some(self)
    }

    fn console_commands(&self) -> &'static [csp::console::Command] {
        &[csp::console::TM]
    }

    fn console(
        &mut self,
        _node: &mut Node,
        words: &[&str],
        _now: SimTime,
    ) -> Result<String, csp::console::ConsoleError> {
        if words != ["tm"] {
            return Err(csp::console::ConsoleError::Usage("tm".to_owned()));
        }
        // As TMPC on port 12.
        csp::console::layout(&self.tmpc())
    }

    fn self_test(&mut self, _node: &Node, now: SimTime) -> Vec<csp::params::Check> {
        self.checks(now)
    }

    fn reset(&mut self, now: SimTime) {
        self.lose_volatile(now, LostCause::Reboot);
        // The node unbinds every port at reboot.
        self.ports.clear();
        self.retired.clear();
        self.tm_sband_downlinked = 0;
    }
}

impl PcApp {
    /// What a reboot or a loss of power takes: the buffered data (counted as dropped for
    /// `PowerLoss`), the S-band queue, the sessions' state.
    fn lose_volatile(&mut self, now: SimTime, why: LostCause) {
        self.refusals.clear();
        if self.sband.is_transmitting() {
            self.tx_activity(now, false);
        }
        // The transmitter comes back in its configured state; its power is followed anew.
        self.unpowered = false;
        for i in 0..self.runs.len() {
            let n = self.runs.get_mut(i).map_or(0, |r| r.file.clear());
            if n > 0 {
                let addr = self.payload_addr(i);
                self.drop_bytes(now, Some(i), addr, DropReason::PowerLoss, n);
            }
        }
        for (slot, n) in self.sband.reboot() {
            let addr = self.payload_addr(slot);
            self.drop_bytes(now, Some(slot), addr, DropReason::PowerLoss, n);
        }
        if let Some(a) = self.table.active() {
            let id = self.session_id(a);
            let packets = self.table.slot(a).map_or(0, |s| s.packets);
            self.log.push(NodeEvent::info(
                now,
                format!("pc: {why}: ACTIVE session {id} lost after {packets} packets"),
            ));
            self.emit(PcOutput::SessionLost {
                t: now,
                session_id: id,
                cause: why,
                packets,
            });
        }
        self.table.reset();
        for r in &mut self.runs {
            r.phase = None;
            r.tm_downlinked = 0;
            r.tm_dropped = 0;
        }
    }
}

/// What took the PC's volatile memory (its session table, buffer file and S-band queue).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum LostCause {
    /// Its power went (an EPS channel switched off, a `power-off` fault).
    PowerLoss,
    /// It rebooted (the CSP reboot service, a `reboot` fault).
    Reboot,
}

impl LostCause {
    /// Its name in recordings and reports: `power` or `reboot`.
    pub fn as_str(self) -> &'static str {
        match self {
            LostCause::PowerLoss => "power",
            LostCause::Reboot => "reboot",
        }
    }
}

impl std::fmt::Display for LostCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LostCause::PowerLoss => "power lost",
            LostCause::Reboot => "reboot",
        })
    }
}

/// The PC with the default configuration ([`PcConfig::default`]).
pub fn app() -> PcApp {
    PcApp::new(PcConfig::default())
}

// What a snapshot keeps of the PC (docs/snapshots.md): its configuration (the parameters
// change it), the session table, each session's run (its phase, file and ledger), the
// S-band's queue and frame in flight, the ports in use, the refusals WHY tells, counts; the
// activity board is the run's.
snap::fields!(SessionSpec {
    session_id,
    payload_addr,
    payload_port,
    mode,
    buffer_capacity_bytes
});
snap::unit_enum!(PcEvent {
    SbandFail,
    SbandRestore,
    SbandOff,
    SbandOn
});
snap::fields!(TimedPcEvent { at, event });
snap::fields!(PcConfig {
    sessions,
    sband,
    control_port,
    ingest_port,
    telemetry_port,
    files_port,
    timeline,
    payload_access
});
snap::fields!(PcCounters {
    refused,
    denied,
    file_reads,
    file_bytes_read,
    file_deletes,
    syncs_sent,
    polls_sent,
    poll_retries,
    polls_given_up,
    late_sync_replies,
    ingest_packets,
    frames_sent
});
snap::fields!(ByteFifo { buf, head, removed });
snap::fields!(RawLedger {
    received,
    downlinked,
    dropped
});
snap::unit_enum!(ReqKind { Sync, Poll });
snap::fields!(PortUse { slot, kind, live });
snap::fields!(Run {
    phase,
    file,
    ledger,
    tm_downlinked,
    tm_dropped
});
snap::fields!(PcApp {
    cfg,
    table,
    runs,
    sband,
    ports,
    retired,
    timeline_next,
    unattributed,
    tm_sband_downlinked,
    counters,
    out,
    log,
    unpowered,
    refusals;
    skip activity
});

snap::tagged_enum!(SessionMode {
    Polling {
        poll_period,
        reply_timeout
    },
    Buffering
});

snap::tagged_enum!(Wait {
    Reply { port, deadline },
    Next(t)
});

impl snap::Snap for Phase {
    fn save(&self, w: &mut snap::Writer) {
        match *self {
            Phase::Idle => 0u8.save(w),
            Phase::Sync { port, deadline } => (1u8, port, deadline).save(w),
            Phase::Poll {
                cycle_start,
                attempt,
                wait,
            } => {
                (2u8, cycle_start, attempt).save(w);
                wait.save(w);
            }
        }
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = snap::SnapNew::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for Phase {
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        use snap::SnapNew;
        let at = r.at();
        match u8::read(r)? {
            0 => Ok(Phase::Idle),
            1 => Ok(Phase::Sync {
                port: SnapNew::read(r)?,
                deadline: SnapNew::read(r)?,
            }),
            2 => Ok(Phase::Poll {
                cycle_start: SnapNew::read(r)?,
                attempt: SnapNew::read(r)?,
                wait: SnapNew::read(r)?,
            }),
            _ => Err(snap::SnapError::Bad { what: "Phase", at }),
        }
    }
}

snap::unit_enum!(LostCause { PowerLoss, Reboot });
