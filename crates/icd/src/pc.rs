//! The PC's ICD commands and replies (ICD 3.1.8, INTERPRETATION.md sections 2, 4 and 7) as
//! wire representations, and the command tables of its ports.
//!
//! # Contract
//! Every type here is the request or reply *data* of an ICD command: the bytes after the
//! `command` byte of a request, or after the `command | result` head of a reply
//! (`csp::reqrep`). The "Size" columns of ICD tables 4 and 5 count exactly these bytes,
//! never the command or result byte. `parse` accepts exactly the table's size (or its range
//! for the `N`-byte tails) and never panics; `emit` appends exactly `buffer_len()` bytes.
//! All multi-byte fields are little-endian (ICD 1.8). Range checks (duration 5-900 s,
//! frame size 1-254) belong to the port's [`CommandSet`], so a `Repr` round-trips any bytes
//! of the right length; the enumerations [`SessionState`] and [`SessionResult`] are the
//! exception: unknown values do not parse.
//!
//! # Sizes
//! | port | command | request data | reply data |
//! |---|---|---|---|
//! | 10 | SETUP 1 | [`SessionConfig`] 10 + N (N 0..=128) | 0 |
//! | 10 | STATUS 2 | session id, 1 | [`Status`] 11 + N |
//! | 10 | ABORT 3 | session id, 1 | 0 |
//! | 10 | WHY 4 (the twin's own: a spacecraft's PC has no such command) | 0 | [`Why`] 5 + N (N 0..=64) |
//! | payload | SYNC 1 | message, N (0..=128) | the same N bytes |
//! | payload | POLL 2 | frame size, 1 | 0..=frame size |
//! | 11 | (none: raw data) | 0..=256 bytes, no command byte, no reply | - |
//! | 12 | TMPC 1 | 0 | [`Tmpc`] 89 (the twin's layout) |
//! | 13 | FLIST 1 | 0 | count u8, then count x [`FileStat`] 18 |
//! | 13 | FSTAT 2 | payload address, 1 | [`FileStat`] 18 |
//! | 13 | FREAD 3 | [`FileRead`] 10 | offset u64, then 0..=length bytes |
//! | 13 | FDELETE 4 | payload address, 1 | bytes deleted u32 |
//!
//! So a whole SETUP request is `11 + N` bytes on the wire, a whole STATUS reply `13 + N`.

use csp::Error;
use csp::icd::{Command, Data, Port};
use csp::reqrep::le::{Reader, Repr};
use csp::reqrep::{CommandSet, Request, RequestError, expect_len};

/// Default port of session control (INTERPRETATION.md section 4).
pub const PORT_CONTROL: u8 = 10;
/// Default port of buffered data ingest (INTERPRETATION.md section 4, ICD 3.1.5).
pub const PORT_INGEST: u8 = 11;
/// Default port of the PC's own telemetry (the twin's addition; docs/protocol.md).
pub const PORT_TELEMETRY: u8 = 12;
/// Default port of the buffer files (ICD 3.1.5 "a regular file system interface"; the
/// twin's layout, docs/protocol.md).
pub const PORT_FILES: u8 = 13;
/// Default SYNC/POLL port of a payload (INTERPRETATION.md section 4).
pub const PORT_PAYLOAD: u8 = 10;

/// Command ids (ICD tables 4 and 5; TMPC is the twin's).
pub mod cmd {
    /// Control port: set up a session.
    pub const SETUP: u8 = 1;
    /// Control port: read a session's state, configuration and last result.
    pub const STATUS: u8 = 2;
    /// Control port: abort a PENDING or ACTIVE session.
    pub const ABORT: u8 = 3;
    /// Control port: why the asker's last refused request was refused (the twin's own: a
    /// spacecraft's PC has no such command).
    pub const WHY: u8 = 4;
    /// Payload port: synchronisation message, echoed by the payload.
    pub const SYNC: u8 = 1;
    /// Payload port: poll for one data frame.
    pub const POLL: u8 = 2;
    /// Telemetry port: the PC's sessions and S-band.
    pub const TMPC: u8 = 1;
    /// Files port: every buffer file.
    pub const FLIST: u8 = 1;
    /// Files port: one buffer file.
    pub const FSTAT: u8 = 2;
    /// Files port: read bytes of a buffer file.
    pub const FREAD: u8 = 3;
    /// Files port: empty a buffer file.
    pub const FDELETE: u8 = 4;
}

/// Most bytes one FREAD returns (its reply, 2 + 8 + 200 bytes, stays within libcsp 1.4's
/// 248-byte KISS receive limit).
pub const FREAD_MAX_LEN: u8 = 200;

/// Bytes of SETUP request data before the sync message (ICD table 4: "10 + N").
pub const SETUP_FIXED_LEN: usize = 10;
/// Bytes of STATUS reply data before the sync message (ICD table 4: "11 + N").
pub const STATUS_FIXED_LEN: usize = 11;
/// Longest sync message (ICD 3.1.3 item 6).
pub const SYNC_MAX_LEN: usize = 128;
/// Shortest session (ICD 3.1.3 item 3).
pub const DURATION_MIN_S: u16 = 5;
/// Longest session (ICD 3.1.3 item 3).
pub const DURATION_MAX_S: u16 = 900;
/// Smallest poll frame (ICD 3.1.3 item 5).
pub const FRAME_SIZE_MIN: u8 = 1;
/// Largest poll frame (ICD 3.1.3 item 5).
pub const FRAME_SIZE_MAX: u8 = 254;
/// Largest ingest packet (ICD 3.1.5: "the maximum data size in one CSP packet is 256 bytes").
pub const INGEST_MAX_LEN: usize = 256;
/// Longest reason text in a WHY reply.
pub const WHY_REASON_MAX_LEN: usize = 64;
/// Bytes of WHY reply data before the reason text.
pub const WHY_FIXED_LEN: usize = 5;
/// Session slots in TMPC (one per payload id 12-15).
pub const TMPC_SLOTS: usize = 4;

/// Session state (ICD table 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum SessionState {
    /// Not configured or finished.
    #[default]
    NotActive = 0,
    /// Waiting for its start time.
    Pending = 1,
    /// Running.
    Active = 2,
}

impl SessionState {
    /// The ICD value.
    pub fn to_u8(self) -> u8 {
        self as u8
    }
    /// From the ICD value.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            0 => Some(SessionState::NotActive),
            1 => Some(SessionState::Pending),
            2 => Some(SessionState::Active),
            _ => None,
        }
    }
}

/// Last session result (ICD table 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum SessionResult {
    /// Finished successfully or never executed.
    #[default]
    Done = 0,
    /// Aborted by the ABORT command.
    Aborted = 1,
    /// The payload did not acknowledge the sync message.
    NoAck = 2,
    /// Aborted by an S-band transmitter failure.
    SbandFailure = 3,
}

impl SessionResult {
    /// The ICD value.
    pub fn to_u8(self) -> u8 {
        self as u8
    }
    /// From the ICD value.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            0 => Some(SessionResult::Done),
            1 => Some(SessionResult::Aborted),
            2 => Some(SessionResult::NoAck),
            3 => Some(SessionResult::SbandFailure),
            _ => None,
        }
    }
}

/// Why the PC refused a request: a WHY reply's `code` (the twin's own numbering; a value,
/// once given, keeps its meaning).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[non_exhaustive]
pub enum RefusalCode {
    /// No request of the asker's refused since the PC booted.
    #[default]
    None = 0,
    /// No session with the id is configured.
    UnknownSession = 1,
    /// SETUP of a session that is PENDING or ACTIVE.
    Busy = 2,
    /// The window overlaps a PENDING or ACTIVE session's.
    Overlap = 3,
    /// An immediate start while another session is ACTIVE.
    OtherActive = 4,
    /// ABORT of a session that is NOT ACTIVE.
    NotRunning = 5,
    /// A command refused to payloads (ICD 3.1.1, 3.1.5).
    PayloadDenied = 6,
    /// A buffer file asked of a payload without a buffering session.
    NoFile = 7,
    /// No command id, or request data of the wrong length.
    Malformed = 8,
    /// A field outside its range.
    OutOfRange = 9,
    /// A command id the port does not have.
    UnknownCommand = 10,
}

impl RefusalCode {
    /// Every code, in order of value.
    pub const ALL: [RefusalCode; 11] = [
        RefusalCode::None,
        RefusalCode::UnknownSession,
        RefusalCode::Busy,
        RefusalCode::Overlap,
        RefusalCode::OtherActive,
        RefusalCode::NotRunning,
        RefusalCode::PayloadDenied,
        RefusalCode::NoFile,
        RefusalCode::Malformed,
        RefusalCode::OutOfRange,
        RefusalCode::UnknownCommand,
    ];
    /// The wire value.
    pub fn to_u8(self) -> u8 {
        self as u8
    }
    /// From the wire value.
    pub fn from_u8(v: u8) -> Option<Self> {
        Self::ALL.get(usize::from(v)).copied()
    }
}

/// [`RefusalCode`]'s values by name.
pub const REFUSAL_CODES: &[(i64, &str)] = &[
    (0, "none"),
    (1, "unknown session"),
    (2, "busy"),
    (3, "overlap"),
    (4, "other active"),
    (5, "not running"),
    (6, "payload denied"),
    (7, "no file"),
    (8, "malformed"),
    (9, "out of range"),
    (10, "unknown command"),
];

/// [`SessionState`]'s values by name.
pub const SESSION_STATES: &[(i64, &str)] = &[(0, "NOT ACTIVE"), (1, "PENDING"), (2, "ACTIVE")];

/// [`SessionResult`]'s values by name.
pub const SESSION_RESULTS: &[(i64, &str)] = &[
    (0, "DONE"),
    (1, "ABORTED"),
    (2, "NO ACK"),
    (3, "S-BAND FAILURE"),
];

/// TMPC `sband_flags` by bit.
pub const SBAND_BITS: &[(i64, &str)] = &[(0, "on"), (1, "failed"), (2, "transmitting")];

csp::wire_struct! {
    /// SETUP request data before the sync message (ICD 3.1.3, table 4, 10 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct SetupHead {
        /// Session id (the scenario's `[[pc.sessions]]` id).
        pub session_id: u8,
        /// Start, UTC unix seconds on the PC's clock (0 or a past time: now).
        pub timestamp: u32 { unit: "s", values: &[(0, "now")] },
        /// Session duration.
        pub duration_s: u16 { unit: "s", range: (5.0, 900.0) },
        /// Most packets to poll (0: no limit).
        pub max_packets: u16 { values: &[(0, "no limit")] },
        /// Poll frame size, bytes.
        pub poll_frame_size: u8 { unit: "B", range: (1.0, 254.0) },
    }
}

csp::wire_struct! {
    /// STATUS reply data before the sync message (ICD 3.1.3, table 5, 11 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct StatusHead {
        /// Result of the last finished session.
        pub last_result: u8 { values: SESSION_RESULTS },
        /// The session's state now.
        pub state: u8 { values: SESSION_STATES },
        /// Start, as SETUP gave it.
        pub timestamp: u32 { unit: "s" },
        /// Duration, as SETUP gave it.
        pub duration_s: u16 { unit: "s" },
        /// Most packets, as SETUP gave it.
        pub max_packets: u16,
        /// Poll frame size, as SETUP gave it.
        pub poll_frame_size: u8 { unit: "B" },
    }
}

csp::wire_struct! {
    /// WHY reply data before the reason text (the twin's own, 5 bytes; a spacecraft's PC has
    /// no such command).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct WhyHead {
        /// Why the asker's last refused request was refused (0: none of its requests was
        /// refused since the PC booted).
        pub code: u8 { values: REFUSAL_CODES },
        /// The port that request went to (0 with none).
        pub port: u8,
        /// Its command id (0 with none).
        pub command: u8,
        /// The session it named (SETUP, STATUS or ABORT; 0 with none).
        pub session_id: u8,
        /// The session in its way (overlap, another ACTIVE; 0 with none).
        pub other_session_id: u8,
    }
}

csp::wire_struct! {
    /// STATUS and ABORT request data (1 byte).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct SessionId {
        /// Session id.
        pub session_id: u8,
    }
}

csp::wire_struct! {
    /// FSTAT and FDELETE request data (1 byte).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct PayloadAddr {
        /// The payload whose buffer file it is (12-15).
        pub payload_addr: u8,
    }
}

csp::wire_struct! {
    /// FDELETE reply data (4 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct Deleted {
        /// Bytes deleted.
        pub bytes: u32 { unit: "B" },
    }
}

/// Port 10, session control, as data (`csp::icd`).
pub const ICD_CONTROL: Port = Port {
    port: PORT_CONTROL,
    name: "control",
    commands: &[
        Command::new(cmd::SETUP, "SETUP", "configure a payload session")
            .refused_when(
                "the session id unknown; that session PENDING or ACTIVE (reconfigure after \
                 ABORT); its window overlaps a PENDING or ACTIVE session's; it would start \
                 at once while another session is ACTIVE",
            )
            .request(Data::with_tail::<SetupHead>(
                "sync_message",
                "sent to the payload in SYNC at the session's start",
                0,
                SYNC_MAX_LEN,
            ))
            .examples(&[
                &[1, 0, 0, 0, 0, 60, 0, 30, 0, 64, b'g', b'o'],
                &[1, 0, 0, 0, 0, 5, 0, 0, 0, 1],
                &[1, 0, 0, 0, 0, 0x84, 3, 0, 0, 254],
            ])
            .no_payloads(),
        Command::new(cmd::STATUS, "STATUS", "a session's state and configuration")
            .request(Data::of::<SessionId>())
            .reply(Data::with_tail::<StatusHead>(
                "sync_message",
                "as SETUP gave it",
                0,
                SYNC_MAX_LEN,
            ))
            .examples(&[&[1]]),
        Command::new(cmd::ABORT, "ABORT", "end a session now")
            .refused_when("the session NOT ACTIVE (nothing changes)")
            .request(Data::of::<SessionId>())
            .examples(&[&[1]])
            .no_payloads(),
        Command::new(
            cmd::WHY,
            "WHY",
            "the twin's own, not the spacecraft's: why the PC refused the asker's last refused \
             request (the asker is the request's source address)",
        )
        .reply(Data::with_tail::<WhyHead>(
            "reason",
            "the reason in words (ASCII)",
            0,
            WHY_REASON_MAX_LEN,
        ))
        .twin(),
    ],
};

/// Port 11, buffered ingest, as data: raw payload data with no command byte and no reply.
pub const ICD_INGEST: Port = Port {
    port: PORT_INGEST,
    name: "ingest",
    commands: &[],
};

/// Port 12, PC telemetry, as data (`csp::icd`).
pub const ICD_TELEMETRY: Port = Port {
    port: PORT_TELEMETRY,
    name: "telemetry",
    commands: &[
        Command::new(cmd::TMPC, "TMPC", "sessions, buffers and the S-band")
            .reply(Data::of::<Tmpc>())
            .twin(),
    ],
};

/// Port 13, buffer files, as data (`csp::icd`): refused to payloads.
pub const ICD_FILES: Port = Port {
    port: PORT_FILES,
    name: "files",
    commands: &[
        Command::new(
            cmd::FLIST,
            "FLIST",
            "every buffer file, in configuration order",
        )
        .reply(Data::Variable(
            "count u8, then count x FileStat (18 bytes)",
            1,
            1 + MAX_SESSIONS * <FileStat as Repr>::LEN,
        ))
        .no_payloads()
        .twin(),
        Command::new(cmd::FSTAT, "FSTAT", "one payload's buffer file")
            .refused_when("a payload without a buffering session")
            .request(Data::of::<PayloadAddr>())
            .reply(Data::of::<FileStat>())
            .examples(&[&[12]])
            .no_payloads()
            .twin(),
        Command::new(
            cmd::FREAD,
            "FREAD",
            "read bytes of a buffer file, from the offset moved up to its head (the reply's \
             offset says where they start); takes nothing from it",
        )
        .refused_when("a payload without a buffering session")
        .request(Data::of::<FileRead>())
        .reply(Data::Variable(
            "offset u64, then 0..=length bytes",
            8,
            8 + FREAD_MAX_LEN as usize,
        ))
        .examples(&[
            &[12, 0, 0, 0, 0, 0, 0, 0, 0, 200],
            &[12, 0, 0, 0, 0, 0, 0, 0, 0, 1],
        ])
        .no_payloads()
        .twin(),
        Command::new(cmd::FDELETE, "FDELETE", "empty a buffer file")
            .refused_when("a payload without a buffering session")
            .request(Data::of::<PayloadAddr>())
            .reply(Data::of::<Deleted>())
            .examples(&[&[12]])
            .no_payloads()
            .twin(),
    ],
};

csp::wire_struct! {
    /// POLL request data (ICD 3.1.5, 1 byte).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct PollRequest {
        /// Most bytes the reply may carry.
        pub frame_size: u8 { unit: "B", range: (1.0, 254.0) },
    }
}

/// A payload's port 10 (ICD 3.1.5), the PC's requests to it, as data (`csp::icd`).
pub const ICD_PAYLOAD: Port = Port {
    port: PORT_PAYLOAD,
    name: "payload",
    commands: &[
        Command::new(
            cmd::SYNC,
            "SYNC",
            "the session's sync message; the payload echoes it",
        )
        .request(Data::bytes(
            "message",
            "SETUP's sync message",
            0,
            SYNC_MAX_LEN,
        ))
        .reply(Data::bytes("message", "the same bytes", 0, SYNC_MAX_LEN))
        .examples(&[b"go"]),
        Command::new(cmd::POLL, "POLL", "one packet of payload data")
            .request(Data::of::<PollRequest>())
            .reply(Data::bytes(
                "data",
                "0..=frame_size bytes of payload data",
                0,
                254,
            ))
            .examples(&[&[200]]),
    ],
};

/// SETUP request data (ICD 3.1.3, table 4: `10 + N` bytes): one session's configuration.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct SessionConfig {
    /// Session id (one per payload).
    pub session_id: u8,
    /// Start, UTC unix seconds of the M6P clock; 0 or past = at once.
    pub timestamp: u32,
    /// Duration, seconds (5-900).
    pub duration_s: u16,
    /// Packets after which the session ends (0 = no limit).
    pub max_packets: u16,
    /// POLL frame size, bytes (1-254).
    pub poll_frame_size: u8,
    /// Sync message sent once at the start (0-128 bytes).
    pub sync_message: Vec<u8>,
}

impl SessionConfig {
    /// Parse `10 + N` bytes, N at most 128.
    pub fn parse(buf: &[u8]) -> Result<Self, Error> {
        if buf.len() < SETUP_FIXED_LEN {
            return Err(Error::Truncated);
        }
        if buf.len() > SETUP_FIXED_LEN + SYNC_MAX_LEN {
            return Err(Error::TooLong);
        }
        let mut r = Reader::new(buf);
        let h = SetupHead::read(&mut r)?;
        Ok(SessionConfig {
            session_id: h.session_id,
            timestamp: h.timestamp,
            duration_s: h.duration_s,
            max_packets: h.max_packets,
            poll_frame_size: h.poll_frame_size,
            sync_message: r.remaining().to_vec(),
        })
    }
    /// Length of the emitted bytes.
    pub fn buffer_len(&self) -> usize {
        SETUP_FIXED_LEN + self.sync_message.len()
    }
    /// Append the bytes to `out`.
    pub fn emit(&self, out: &mut Vec<u8>) {
        SetupHead {
            session_id: self.session_id,
            timestamp: self.timestamp,
            duration_s: self.duration_s,
            max_packets: self.max_packets,
            poll_frame_size: self.poll_frame_size,
        }
        .emit(out);
        out.extend_from_slice(&self.sync_message);
    }
    /// The bytes.
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.buffer_len());
        self.emit(&mut v);
        v
    }
    /// The whole SETUP request payload (`01 | data`).
    pub fn to_request(&self) -> Vec<u8> {
        let mut v = vec![cmd::SETUP];
        self.emit(&mut v);
        v
    }
    /// Check the ICD 3.1.3 ranges; the error names the field.
    pub fn check_ranges(&self) -> Result<(), &'static str> {
        if !(DURATION_MIN_S..=DURATION_MAX_S).contains(&self.duration_s) {
            return Err("sessionDuration");
        }
        if !(FRAME_SIZE_MIN..=FRAME_SIZE_MAX).contains(&self.poll_frame_size) {
            return Err("pollFrameSize");
        }
        if self.sync_message.len() > SYNC_MAX_LEN {
            return Err("syncMessage");
        }
        Ok(())
    }
}

/// STATUS reply data (ICD 3.1.7, table 4: `11 + N` bytes).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Status {
    /// Result of the last finished session.
    pub last_result: SessionResult,
    /// Current state.
    pub state: SessionState,
    /// The configuration (all zero and empty when never configured).
    pub timestamp: u32,
    /// Configured duration, seconds.
    pub duration_s: u16,
    /// Configured packet limit.
    pub max_packets: u16,
    /// Configured POLL frame size.
    pub poll_frame_size: u8,
    /// Configured sync message.
    pub sync_message: Vec<u8>,
}

impl Status {
    /// Parse `11 + N` bytes, N at most 128; unknown state or result values fail.
    pub fn parse(buf: &[u8]) -> Result<Self, Error> {
        if buf.len() < STATUS_FIXED_LEN {
            return Err(Error::Truncated);
        }
        if buf.len() > STATUS_FIXED_LEN + SYNC_MAX_LEN {
            return Err(Error::TooLong);
        }
        let mut r = Reader::new(buf);
        let h = StatusHead::read(&mut r)?;
        let last_result =
            SessionResult::from_u8(h.last_result).ok_or(Error::FieldRange("lastSessionResult"))?;
        let state = SessionState::from_u8(h.state).ok_or(Error::FieldRange("currState"))?;
        Ok(Status {
            last_result,
            state,
            timestamp: h.timestamp,
            duration_s: h.duration_s,
            max_packets: h.max_packets,
            poll_frame_size: h.poll_frame_size,
            sync_message: r.remaining().to_vec(),
        })
    }
    /// Length of the emitted bytes.
    pub fn buffer_len(&self) -> usize {
        STATUS_FIXED_LEN + self.sync_message.len()
    }
    /// Append the bytes to `out`.
    pub fn emit(&self, out: &mut Vec<u8>) {
        StatusHead {
            last_result: self.last_result.to_u8(),
            state: self.state.to_u8(),
            timestamp: self.timestamp,
            duration_s: self.duration_s,
            max_packets: self.max_packets,
            poll_frame_size: self.poll_frame_size,
        }
        .emit(out);
        out.extend_from_slice(&self.sync_message);
    }
    /// The bytes.
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.buffer_len());
        self.emit(&mut v);
        v
    }
}

/// WHY reply data (the twin's own: `5 + N` bytes, N at most [`WHY_REASON_MAX_LEN`]): the
/// asker's last refusal, by code and in words.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Why {
    /// Why.
    pub code: RefusalCode,
    /// The port the refused request went to (0 with none).
    pub port: u8,
    /// Its command id (0 with none).
    pub command: u8,
    /// The session it named (0 with none).
    pub session_id: u8,
    /// The session in its way (0 with none).
    pub other_session_id: u8,
    /// The reason in words: ASCII, at most [`WHY_REASON_MAX_LEN`] bytes.
    pub reason: String,
}

impl Why {
    /// Parse `5 + N` bytes, N at most 64; an unknown code or a reason that is not ASCII
    /// fails.
    pub fn parse(buf: &[u8]) -> Result<Self, Error> {
        if buf.len() < WHY_FIXED_LEN {
            return Err(Error::Truncated);
        }
        if buf.len() > WHY_FIXED_LEN + WHY_REASON_MAX_LEN {
            return Err(Error::TooLong);
        }
        let mut r = Reader::new(buf);
        let h = WhyHead::read(&mut r)?;
        let code = RefusalCode::from_u8(h.code).ok_or(Error::FieldRange("code"))?;
        let text = r.remaining();
        if !text.is_ascii() {
            return Err(Error::FieldRange("reason"));
        }
        Ok(Why {
            code,
            port: h.port,
            command: h.command,
            session_id: h.session_id,
            other_session_id: h.other_session_id,
            reason: String::from_utf8_lossy(text).into_owned(),
        })
    }
    /// The reason's bytes as sent: its ASCII characters (others become `?`), at most
    /// [`WHY_REASON_MAX_LEN`].
    fn reason_bytes(&self) -> impl Iterator<Item = u8> + '_ {
        self.reason
            .chars()
            .map(|c| u8::try_from(c).ok().filter(u8::is_ascii).unwrap_or(b'?'))
            .take(WHY_REASON_MAX_LEN)
    }
    /// Length of the emitted bytes.
    pub fn buffer_len(&self) -> usize {
        WHY_FIXED_LEN + self.reason_bytes().count()
    }
    /// Append the bytes to `out`.
    pub fn emit(&self, out: &mut Vec<u8>) {
        WhyHead {
            code: self.code.to_u8(),
            port: self.port,
            command: self.command,
            session_id: self.session_id,
            other_session_id: self.other_session_id,
        }
        .emit(out);
        out.extend(self.reason_bytes());
    }
    /// The bytes.
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.buffer_len());
        self.emit(&mut v);
        v
    }
}

csp::wire_struct! {
    /// One session slot of [`Tmpc`] (20 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct TmpcSlot {
        /// Session id (0 for an unused slot).
        pub session_id: u8,
        /// Payload CSP address (0 for an unused slot).
        pub payload_addr: u8,
        /// The session's state: 0 NOT ACTIVE, 1 PENDING, 2 ACTIVE.
        pub state: u8 { values: SESSION_STATES },
        /// How the last finished session ended: 0 DONE, 1 ABORTED, 2 NO ACK, 3 S-BAND FAILURE.
        pub last_result: u8 { values: SESSION_RESULTS },
        /// Packets counted in the current (or last) session.
        pub packets: u32,
        /// Payload bytes of this slot that reached the ground since the PC booted (saturating).
        pub downlinked_bytes: u32 { unit: "B" },
        /// Payload bytes of this slot dropped since the PC booted, any reason (saturating).
        pub dropped_bytes: u32 { unit: "B" },
        /// Bytes in the payload's buffer file now.
        pub buffer_bytes: u32 { unit: "B" },
    }
}

/// S-band flag in [`Tmpc::sband_flags`]: switched on.
pub const SBAND_ON: u8 = 0x01;
/// S-band flag: failed (hardware fault).
pub const SBAND_FAILED: u8 = 0x02;
/// S-band flag: a frame is on the air.
pub const SBAND_TRANSMITTING: u8 = 0x04;

csp::wire_struct! {
    /// TMPC reply data (the twin's layout, 89 bytes): four session slots in configuration
    /// order (unused slots zero), then the S-band.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct Tmpc {
        /// Session slots.
        pub slots: [TmpcSlot; TMPC_SLOTS],
        /// S-band flags: bit 0 switched on, bit 1 failed (hardware fault), bit 2 a frame on
        /// the air.
        pub sband_flags: u8 { bits: SBAND_BITS },
        /// Bytes waiting in the transmitter (frame on the air included).
        pub sband_queue_bytes: u32 { unit: "B" },
        /// Payload bytes the S-band delivered to the ground since the PC booted (saturating).
        pub sband_downlinked_bytes: u32 { unit: "B" },
    }
}

csp::wire_struct! {
    /// One buffer file (FSTAT's reply, FLIST's entries; 18 bytes). A file holds the bytes of
    /// the stream a buffering payload pushed that are still on board; offsets count the
    /// stream's bytes since the start of the run, so `head_offset` is where the oldest byte
    /// held sits in it and `head_offset + size_bytes` where the next pushed byte will.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct FileStat {
        /// The payload's CSP address (the file's name).
        pub payload_addr: u8,
        /// Its buffering session's id.
        pub session_id: u8,
        /// Bytes held now.
        pub size_bytes: u32 { unit: "B" },
        /// The file's capacity (saturating).
        pub capacity_bytes: u32 { unit: "B" },
        /// Stream offset of the first byte held.
        pub head_offset: u64,
    }
}

csp::wire_struct! {
    /// FREAD request data (10 bytes): up to `length` bytes of `payload_addr`'s file from stream
    /// offset `offset`. The reply is the offset actually served (the request's, moved up to
    /// the file's head if the S-band already took those bytes, and no further than its end)
    /// and the bytes from there.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct FileRead {
        /// The file (its payload's address).
        pub payload_addr: u8,
        /// Stream offset to read from.
        pub offset: u64,
        /// Bytes wanted, 1..=200.
        pub length: u8 { unit: "B", range: (1.0, 200.0) },
    }
}

/// A command on the files port, parsed and range-checked (which files exist is the PC's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilesCommand {
    /// FLIST 1.
    List,
    /// FSTAT 2.
    Stat {
        /// The file.
        payload_addr: u8,
    },
    /// FREAD 3.
    Read(FileRead),
    /// FDELETE 4.
    Delete {
        /// The file.
        payload_addr: u8,
    },
}

impl CommandSet for FilesCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        let addr = |r: &Request<'_>| expect_len(r, 1, "1").map(|_| r.data[0]);
        match r.command {
            cmd::FLIST => expect_len(r, 0, "0").map(|_| FilesCommand::List),
            cmd::FSTAT => addr(r).map(|payload_addr| FilesCommand::Stat { payload_addr }),
            cmd::FREAD => {
                expect_len(r, <FileRead as Repr>::LEN, "10")?;
                let q = FileRead::parse(r.data).map_err(|_| RequestError::Empty)?;
                if (1..=FREAD_MAX_LEN).contains(&q.length) {
                    Ok(FilesCommand::Read(q))
                } else {
                    Err(RequestError::OutOfRange {
                        command: r.command,
                        field: "length",
                    })
                }
            }
            cmd::FDELETE => addr(r).map(|payload_addr| FilesCommand::Delete { payload_addr }),
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// A SYNC request to a payload: `01 | message`.
pub fn sync_request(message: &[u8]) -> Vec<u8> {
    let mut v = Vec::with_capacity(1 + message.len());
    v.push(cmd::SYNC);
    v.extend_from_slice(message);
    v
}

/// A POLL request to a payload: `02 | frameSize`.
pub fn poll_request(frame_size: u8) -> Vec<u8> {
    vec![cmd::POLL, frame_size]
}

/// A command on the control port, parsed and range-checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ControlCommand {
    /// SETUP 1.
    Setup(SessionConfig),
    /// STATUS 2.
    Status {
        /// Session id.
        session_id: u8,
    },
    /// ABORT 3.
    Abort {
        /// Session id.
        session_id: u8,
    },
    /// WHY 4 (the twin's own).
    Why,
}

impl CommandSet for ControlCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        match r.command {
            cmd::SETUP => {
                let cfg = SessionConfig::parse(r.data).map_err(|_| RequestError::WrongLength {
                    command: r.command,
                    expected: "10 + N, N <= 128",
                    got: r.data.len(),
                })?;
                cfg.check_ranges()
                    .map_err(|field| RequestError::OutOfRange {
                        command: r.command,
                        field,
                    })?;
                Ok(ControlCommand::Setup(cfg))
            }
            cmd::STATUS => {
                expect_len(r, 1, "1")?;
                Ok(ControlCommand::Status {
                    session_id: r.data.first().copied().unwrap_or(0),
                })
            }
            cmd::ABORT => {
                expect_len(r, 1, "1")?;
                Ok(ControlCommand::Abort {
                    session_id: r.data.first().copied().unwrap_or(0),
                })
            }
            cmd::WHY => expect_len(r, 0, "0").map(|_| ControlCommand::Why),
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// A command on the PC telemetry port.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TelemetryCommand {
    /// TMPC 1: sessions and S-band.
    Tmpc,
}

impl CommandSet for TelemetryCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        match r.command {
            cmd::TMPC => expect_len(r, 0, "0").map(|_| TelemetryCommand::Tmpc),
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// Sessions the PC serves (one per payload, CSP 12-15).
pub const MAX_SESSIONS: usize = 4;

/// [`snap::Snap`] for an enum by its wire byte (its `from_u8` reads it back).
macro_rules! snap_by_wire_byte {
    ($($t:ident),+) => {$(
        impl snap::Snap for $t {
            fn save(&self, w: &mut snap::Writer) {
                snap::Snap::save(&(*self as u8), w);
            }
            fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
                *self = snap::SnapNew::read(r)?;
                Ok(())
            }
        }
        impl snap::SnapNew for $t {
            const MIN_BYTES: usize = 1;
            fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
                let at = r.at();
                let v = <u8 as snap::SnapNew>::read(r)?;
                $t::from_u8(v).ok_or(snap::SnapError::Bad { what: stringify!($t), at })
            }
        }
    )+};
}
snap_by_wire_byte!(SessionState, SessionResult, RefusalCode);
snap::fields!(SessionConfig {
    session_id,
    timestamp,
    duration_s,
    max_packets,
    poll_frame_size,
    sync_message
});
snap::fields!(Why {
    code,
    port,
    command,
    session_id,
    other_session_id,
    reason
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_icd_description_agrees_with_the_parsers() {
        fn req(c: u8, d: &[u8]) -> Vec<u8> {
            let mut b = vec![c];
            b.extend_from_slice(d);
            b
        }
        let control = csp::icd::range_disagreements(&ICD_CONTROL, |c, d| {
            ControlCommand::parse(&Request::parse(&req(c, d)).unwrap()).is_ok()
        });
        assert!(control.is_empty(), "{control:#?}");
        let files = csp::icd::range_disagreements(&ICD_FILES, |c, d| {
            FilesCommand::parse(&Request::parse(&req(c, d)).unwrap()).is_ok()
        });
        assert!(files.is_empty(), "{files:#?}");
        assert_eq!(SetupHead::LEN, SETUP_FIXED_LEN);
        assert_eq!(StatusHead::LEN, STATUS_FIXED_LEN);
        assert_eq!(Tmpc::LEN, 89);
    }
    use proptest::prelude::*;

    /// ICD table 2's example: session 1 at 2020-01-01T00:00:00Z, 60 s, 30 packets of 64.
    fn icd_example() -> SessionConfig {
        SessionConfig {
            session_id: 1,
            timestamp: 1_577_836_800,
            duration_s: 60,
            max_packets: 30,
            poll_frame_size: 64,
            sync_message: b"Send telemetry".to_vec(),
        }
    }

    #[test]
    fn setup_icd_example_bytes() {
        let c = icd_example();
        let b = c.to_vec();
        let mut want = vec![1u8, 0x00, 0xe1, 0x0b, 0x5e, 60, 0, 30, 0, 64];
        want.extend_from_slice(b"Send telemetry");
        assert_eq!(b, want);
        assert_eq!(b.len(), SETUP_FIXED_LEN + 14);
        assert_eq!(c.buffer_len(), b.len());
        assert_eq!(SessionConfig::parse(&b).unwrap(), c);
        assert_eq!(c.to_request()[0], cmd::SETUP);
        assert_eq!(c.to_request().len(), 11 + 14);
    }

    #[test]
    fn setup_sizes_are_10_to_138() {
        assert_eq!(SessionConfig::parse(&[0; 9]), Err(Error::Truncated));
        assert!(SessionConfig::parse(&[0; 10]).is_ok());
        assert!(SessionConfig::parse(&[0; 138]).is_ok());
        assert_eq!(SessionConfig::parse(&[0; 139]), Err(Error::TooLong));
    }

    #[test]
    fn status_layout_is_11_plus_n() {
        let s = Status {
            last_result: SessionResult::NoAck,
            state: SessionState::Pending,
            timestamp: 0x0403_0201,
            duration_s: 0x0605,
            max_packets: 0x0807,
            poll_frame_size: 9,
            sync_message: vec![0xaa, 0xbb],
        };
        assert_eq!(
            s.to_vec(),
            vec![2, 1, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0xaa, 0xbb]
        );
        assert_eq!(s.buffer_len(), STATUS_FIXED_LEN + 2);
        assert_eq!(Status::parse(&s.to_vec()).unwrap(), s);
        assert_eq!(Status::default().to_vec(), vec![0; 11]);
        assert!(Status::parse(&[4, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]).is_err());
        assert!(Status::parse(&[0, 3, 0, 0, 0, 0, 0, 0, 0, 0, 0]).is_err());
        assert_eq!(Status::parse(&[0; 10]), Err(Error::Truncated));
    }

    /// WHY's reply: code, port, command, the two sessions, then at most 64 bytes of ASCII
    /// text; in the control port's table as the twin's own and open to payloads, as STATUS
    /// (it tells the asker of its own refusals only).
    #[test]
    fn why_bytes_and_table_entry() {
        assert_eq!(WhyHead::LEN, WHY_FIXED_LEN);
        let w = Why {
            code: RefusalCode::Overlap,
            port: 10,
            command: cmd::SETUP,
            session_id: 3,
            other_session_id: 1,
            reason: "window overlaps session 1".to_owned(),
        };
        let mut bytes = vec![3, 10, 1, 3, 1];
        bytes.extend_from_slice(b"window overlaps session 1");
        assert_eq!(w.to_vec(), bytes);
        assert_eq!(w.buffer_len(), bytes.len());
        assert_eq!(Why::parse(&bytes).unwrap(), w);
        assert_eq!(Why::parse(&bytes[..4]), Err(Error::Truncated));
        // None: five zeros and no text.
        assert_eq!(Why::default().to_vec(), vec![0; 5]);
        // The text is cut at 64 bytes and sent as ASCII.
        let long = Why {
            reason: "x".repeat(100),
            ..Why::default()
        };
        assert_eq!(long.to_vec().len(), 5 + 64);
        let odd = Why {
            reason: "é!".to_owned(),
            ..Why::default()
        };
        assert_eq!(odd.to_vec()[5..], *b"?!");
        assert_eq!(Why::parse(&[0; 70]), Err(Error::TooLong));
        assert!(Why::parse(&[11, 0, 0, 0, 0]).is_err(), "no code 11");
        assert!(
            Why::parse(&[1, 0, 0, 0, 0, 0xc3, 0xa9]).is_err(),
            "not ASCII"
        );
        // The codes' numbering is the table's.
        for (i, c) in RefusalCode::ALL.iter().enumerate() {
            assert_eq!(usize::from(c.to_u8()), i);
            assert_eq!(REFUSAL_CODES[i].0, i as i64);
        }
        assert_eq!(RefusalCode::ALL.len(), REFUSAL_CODES.len());
        let c = ICD_CONTROL.command(cmd::WHY).unwrap();
        assert_eq!(c.name, "WHY");
        assert!(c.twin);
        assert!(c.doc.starts_with("the twin's own, not the spacecraft's"));
        assert_eq!(c.access, csp::icd::Access::Any);
        assert_eq!(c.request.fixed_len(), Some(0));
        assert_eq!(c.reply.bounds(), (5, 5 + 64));
    }

    #[test]
    fn tmpc_is_89_bytes_with_fields_in_order() {
        assert_eq!(Tmpc::LEN, 89);
        let mut t = Tmpc::default();
        t.slots[1] = TmpcSlot {
            session_id: 2,
            payload_addr: 13,
            state: 2,
            last_result: 3,
            packets: 0x0102_0304,
            downlinked_bytes: 5,
            dropped_bytes: 6,
            buffer_bytes: 7,
        };
        t.sband_flags = SBAND_ON | SBAND_TRANSMITTING;
        t.sband_queue_bytes = 8;
        t.sband_downlinked_bytes = 9;
        let b = t.to_vec();
        assert_eq!(b.len(), 89);
        assert_eq!(
            &b[20..40],
            &[2, 13, 2, 3, 4, 3, 2, 1, 5, 0, 0, 0, 6, 0, 0, 0, 7, 0, 0, 0]
        );
        assert_eq!(&b[80..], &[5, 8, 0, 0, 0, 9, 0, 0, 0]);
        assert_eq!(Tmpc::parse(&b).unwrap(), t);
        assert_eq!(Tmpc::parse(&b[..88]), Err(Error::Truncated));
    }

    #[test]
    fn control_table_checks_lengths_and_ranges() {
        let req = |b: &[u8]| ControlCommand::parse(&Request::parse(b).unwrap());
        assert!(matches!(
            req(&[2, 1]),
            Ok(ControlCommand::Status { session_id: 1 })
        ));
        assert!(matches!(
            req(&[3, 7]),
            Ok(ControlCommand::Abort { session_id: 7 })
        ));
        assert!(matches!(req(&[2]), Err(RequestError::WrongLength { .. })));
        assert!(matches!(
            req(&[3, 1, 2]),
            Err(RequestError::WrongLength { .. })
        ));
        // WHY 4, the twin's own, takes no data; 5 is nothing.
        assert_eq!(req(&[4]), Ok(ControlCommand::Why));
        assert!(matches!(
            req(&[4, 1]),
            Err(RequestError::WrongLength { .. })
        ));
        assert!(matches!(req(&[5, 1]), Err(RequestError::UnknownCommand(5))));
        let mut c = icd_example();
        c.duration_s = 901;
        assert!(matches!(
            req(&c.to_request()),
            Err(RequestError::OutOfRange {
                field: "sessionDuration",
                ..
            })
        ));
        let mut c = icd_example();
        c.poll_frame_size = 0;
        assert!(matches!(
            req(&c.to_request()),
            Err(RequestError::OutOfRange {
                field: "pollFrameSize",
                ..
            })
        ));
        let t = |b: &[u8]| TelemetryCommand::parse(&Request::parse(b).unwrap());
        assert_eq!(t(&[1]), Ok(TelemetryCommand::Tmpc));
        assert!(t(&[1, 0]).is_err());
        assert!(t(&[2]).is_err());
    }

    #[test]
    fn file_port_layouts_and_commands() {
        let st = FileStat {
            payload_addr: 13,
            session_id: 2,
            size_bytes: 0x0403_0201,
            capacity_bytes: 256 << 20,
            head_offset: 0x0102_0304_0506_0708,
        };
        let b = st.to_vec();
        assert_eq!(b.len(), 18);
        assert_eq!(b[..6], [13, 2, 1, 2, 3, 4]);
        assert_eq!(b[10..], [8, 7, 6, 5, 4, 3, 2, 1]);
        assert_eq!(FileStat::parse(&b), Ok(st));
        let f = |c: u8, d: &[u8]| {
            let mut v = vec![c];
            v.extend_from_slice(d);
            FilesCommand::parse(&Request::parse(&v).unwrap())
        };
        assert_eq!(f(1, &[]), Ok(FilesCommand::List));
        assert!(f(1, &[0]).is_err());
        assert_eq!(f(2, &[13]), Ok(FilesCommand::Stat { payload_addr: 13 }));
        assert_eq!(f(4, &[12]), Ok(FilesCommand::Delete { payload_addr: 12 }));
        assert!(f(4, &[]).is_err());
        let read = |len: u8| {
            let q = FileRead {
                payload_addr: 13,
                offset: 1 << 40,
                length: len,
            };
            assert_eq!(q.to_vec()[..2], [13, 0]);
            f(3, &q.to_vec())
        };
        assert!(
            matches!(read(200), Ok(FilesCommand::Read(q)) if q.offset == 1 << 40 && q.length == 200)
        );
        for bad in [0, 201, 255] {
            assert!(
                matches!(read(bad), Err(RequestError::OutOfRange { .. })),
                "{bad}"
            );
        }
        assert!(f(3, &[13; 9]).is_err());
        assert_eq!(f(5, &[]), Err(RequestError::UnknownCommand(5)));
    }

    #[test]
    fn payload_requests() {
        assert_eq!(sync_request(b"hi"), vec![1, b'h', b'i']);
        assert_eq!(sync_request(&[]), vec![1]);
        assert_eq!(poll_request(64), vec![2, 64]);
    }

    proptest! {
        #[test]
        fn setup_round_trip(id: u8, ts: u32, d: u16, m: u16, f: u8,
                            msg in proptest::collection::vec(any::<u8>(), 0..=128)) {
            let c = SessionConfig { session_id: id, timestamp: ts, duration_s: d,
                max_packets: m, poll_frame_size: f, sync_message: msg };
            prop_assert_eq!(SessionConfig::parse(&c.to_vec()).unwrap(), c);
        }

        #[test]
        fn why_round_trip(code in 0u8..11, port: u8, command: u8, a: u8, b: u8,
                          reason in "[ -~]{0,64}") {
            let w = Why { code: RefusalCode::from_u8(code).unwrap(), port, command,
                session_id: a, other_session_id: b, reason };
            prop_assert_eq!(Why::parse(&w.to_vec()).unwrap(), w);
        }

        #[test]
        fn tmpc_round_trip(b in proptest::collection::vec(any::<u8>(), 89)) {
            prop_assert_eq!(Tmpc::parse(&b).unwrap().to_vec(), b);
        }

        #[test]
        fn decoders_never_panic(b in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = SessionConfig::parse(&b);
            let _ = Status::parse(&b);
            let _ = Tmpc::parse(&b);
            let _ = Why::parse(&b);
            if let Ok(r) = Request::parse(&b) {
                let _ = ControlCommand::parse(&r);
                let _ = TelemetryCommand::parse(&r);
            }
        }
    }
}
