//! Record a run to an MCAP file: every [`RunEvent`] becomes one message (two for a frame or
//! packet that completes a CSP packet; CAN frames are gathered into trains, below),
//! protobuf-encoded with its `FileDescriptorSet` schema embedded in the file
//! ([`crate::protobuf`]), so any MCAP reader (Foxglove, the `mcap` Python package with a
//! protobuf decoder) decodes every channel without code from this project. `docs/recording.md` describes the channels for users.
//!
//! # Channels
//!
//! | topic | schema | one message per |
//! |---|---|---|
//! | `/can/main/frames`, `/can/payload/frames` (`/can/<bus>/frames`) | `m6p.CanFrames` | train of CAN frames one endpoint sent back to back, dropped ones included ([`TRAIN_MAX_FRAMES`], [`TRAIN_MAX_SPAN_NS`]) |
//! | `/ground/packets` (`/<network>/packets`) | `m6p.NetPacket` | packet on the ground network, dropped ones included |
//! | `/csp/packets` | `m6p.CspPacket` | CSP packet delivered by a medium: CAN frames reassembled per bus, ground packets as they are |
//! | `/kiss/<link>#<n>/in`, `.../out` | `m6p.KissFrame` | bytes read from / frames written to connection n of an outside link |
//! | `/log` | `foxglove.Log` | log line |
//! | `/faults` | `m6p.Fault` | fault applied or lifted |
//! | `/commands` | `m6p.Command` | scenario command sent, and its result |
//! | `/expectations` | `m6p.Expectation` | expectation verdict |
//! | `/fc/truth/tf` | `foxglove.FrameTransform` | FC truth sample: the true attitude, `eci` -> `body` |
//! | `/fc/estimate/tf` | `foxglove.FrameTransform` | FC truth sample with an estimate: `eci` -> `body_est` |
//! | `/fc/truth/location` | `foxglove.LocationFix` | FC truth sample: geodetic position (frame `earth`) |
//! | `/fc/truth/state` | `m6p.TruthState` | FC truth sample: orbit, sun, field, rates, actuators |
//! | `/fc/adcs` | `m6p.Adcs` | FC truth sample: mode, estimate, target, errors, commands |
//! | `/fc/scene` | `foxglove.SceneUpdate` | FC truth sample: the satellite drawn in `body` |
//! | `/pc/sessions/summary` | `m6p.PcSessionSummary` | PC session run, when it ends or is lost (the encoder tallies each session's open run: its start and the bytes downlinked) |
//!
//! The fixed channels ([`FIXED_CHANNELS`]: both CAN buses, the ground network, `/csp/packets`,
//! `/log`, `/faults`, `/commands`, `/expectations`) are registered at creation in that order;
//! a bus, network or KISS link not known in advance, and the `/fc/...` channels, get their
//! channel when their first message comes, so the registration order follows the event order
//! and is deterministic too. A schema is written with the first channel that uses it.
//!
//! # FC truth channels
//!
//! One [`RunEvent::Truth`] (the FC publishes one per second of simulated time by default)
//! gives, in this order: `/fc/truth/tf`, `/fc/estimate/tf` (only while the ADCS has an
//! estimate), `/fc/truth/location`, `/fc/truth/state`, `/fc/adcs`, `/fc/scene`.
//! - The transforms have **zero translation**: `eci` here means the J2000 axes carried along
//!   with the satellite, so Foxglove's 3D panel shows the attitude (true and estimated
//!   overlaid) at the origin without float32 jitter from a 7000 km offset; the position is in
//!   `/fc/truth/state` and on the map. Rotation = `q_eci_from_body` as `{x, y, z, w}`.
//! - `/fc/truth/location` rotates the ECI position to ECEF as
//!   [`orbit::frames::a_ecef_from_eci`] does at the truth's UTC (`unix_ns`, no EOP), with
//!   precession and nutation interpolated within each UTC minute (within 1e-6 m), and
//!   converts it to WGS-84 latitude, longitude and height.
//! - `/fc/scene` is one entity (`m6p`, replaced by each message) in frame `body`: the
//!   0.2 x 0.1 x 0.3 m box (BCF X, Y, Z), the body axes (X red, Y green, Z blue), and the sun
//!   (yellow, dimmed in eclipse) and nadir (magenta) directions in the body frame.
//! - Non-finite numbers: the project's messages (`m6p.TruthState`, `m6p.Adcs`) write NaN in
//!   an array and leave a single optional number out (both read as `null`). A Foxglove message whose numbers would not be
//!   finite is left out instead (a transform with a NaN poisons Foxglove's transform tree):
//!   a transform when its quaternion is not finite, the location when the position is zero
//!   or not finite, a scene arrow when its direction is not defined.
//!
//! # Determinism
//!
//! The same event stream gives a byte-identical file:
//! - message `log_time` and `publish_time` are simulated time (`start_utc` + `t`, in ns since
//!   the Unix epoch); the attachment's times are `start_utc`; nothing reads the wall clock;
//! - messages are in the file in log-time order ([`crate::log_order`]: a CAN frame train,
//!   handed out when it closes, is written among the messages of its first frame's
//!   instant, and so is any message handed out up to [`REORDER_WINDOW_NS`] late); one
//!   handed out later than that (an expectation's verdict, given at the end of a run for
//!   the instant it was decided) has the latest log time written and its own instant as
//!   its publish time;
//! - the header's `library` is `m6p-twin <twin_version>` (not the mcap crate's identifier);
//! - messages come from structs (field order = declaration order, every field written),
//!   schemas from the `foxglove` crate (its derive, and its well-known types);
//! - zstd runs single-threaded at a fixed level, [`ZSTD_LEVEL`] (multithreaded zstd frames
//!   depend on the worker count, which would tie the bytes to the machine's CPU count; the
//!   writer's compressor thread takes one chunk at a time, in order), and
//!   the writer ([`crate::mcap_file`]) orders its summary by id: no clock, no RNG, no
//!   `HashMap` iteration reaches the file.
//!
//! # Memory and streaming
//!
//! Messages are gathered into chunks of [`CHUNK_SIZE`] uncompressed bytes (4 MiB); a full
//! chunk is zstd-compressed in one call (on the writer's compressor thread, while the next
//! one fills) and written to the file with a message index per channel. The recorder
//! itself runs on a thread of its own in a run ([`RecorderThread`]), fed copies of the
//! events in batches. What stays in memory is bounded: the queue of event batches
//! ([`RECORDER_QUEUE_BATCHES`] of [`RECORDER_BATCH`], a run ahead of its recording waits),
//! the open chunk, the one under compression and its compressed copy (about 13 MiB
//! together), one chunk index entry (about 100 bytes) per closed chunk for the
//! summary, one CFP reassembler per bus (bounded slots) and one small buffer. A killed run
//! leaves a file whose complete chunks MCAP's recovery tools (`mcap recover`) and
//! [`crate::recording`] read (a process killed outright, SIGKILL or out of memory, also
//! loses what was queued for the recorder's thread, up to about 3 000 events, and the chunk
//! under compression: up to two chunks' worth; Ctrl-C and errors end the file normally);
//! dropping a [`Recorder`] without [`Recorder::finish`] still
//! writes the summary, unless a write to the file failed (then the file ends after its
//! last complete chunk).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::log_order::{HOLD_MAX, LogOrder, REORDER_WINDOW_NS};
use crate::mcap_file::McapFile;
use crate::protobuf::{Nested, Packed};
use anyhow::{Context as _, bail};
use bus::trace::{TraceEvent, TraceFrame};
use csp::SimTime;
use csp::cfp::{CanFrame, CfpId, FrameType};
use csp::header::{HEADER_LEN, Header};
use serde::{Deserialize, Serialize};

use nalgebra::Matrix3;
use orbit::frames::{a_ecef_from_teme, eci_to_body};
use orbit::geodetic::ecef_m_to_geodetic;
use orbit::time::UtcTime;
use platform::truth::{AdcsSnapshot, TruthSnapshot};

use twin_core::events::SeenPacket;
use twin_core::events::{Direction, RunEvent};
use twin_scenario::channels::ChannelAction;

/// Target uncompressed size of one chunk: 4 MiB. Measured on `scenarios/full-day.toml`
/// (docs/recording.md, "Compression"): smaller files than mcap's default of 1 MiB at the
/// same level, and fewer chunk records to write and index. A run killed without a chance to
/// finish its recording loses at most this much: about four seconds of a saturated 1 Mbit/s
/// bus, about 20 minutes of simulated time of the full day.
pub const CHUNK_SIZE: u64 = 4 * 1024 * 1024;

/// zstd level: 1, zstd's fastest. The compressor runs between the simulation's steps, whose
/// working set evicts its tables, and level 1's hash table is 32 KiB where level 3's (the
/// default) tables are 768 KiB. Level 3 would make the full day's file 6 % smaller
/// (docs/recording.md, "Compression").
pub const ZSTD_LEVEL: i32 = 1;

/// Name of the metadata record that describes the run.
pub const METADATA_NAME: &str = "m6p-twin";
/// Name of the attachment holding the scenario text.
pub const SCENARIO_ATTACHMENT: &str = "scenario.toml";
/// Version of the recording layout (channels and fields), stored in the metadata.
pub const FORMAT_VERSION: &str = "6";
/// The metadata record of a recording that starts from a snapshot (`at_ns`: its instant).
pub const RESUMED_METADATA_NAME: &str = "m6p-twin-resumed";
/// The attachment holding the snapshot a resumed recording starts from.
pub const SNAPSHOT_ATTACHMENT: &str = "snapshot.snap";
/// The name of the recorder's part of a snapshot ([`Recorder::save_state`]).
pub const RECORD_SECTION: &str = "record";

/// Topic of every decoded CSP packet.
pub const TOPIC_CSP: &str = "/csp/packets";
/// Topic of log lines.
pub const TOPIC_LOG: &str = "/log";
/// Topic of faults.
pub const TOPIC_FAULTS: &str = "/faults";
/// Topic of scenario commands and their results.
pub const TOPIC_COMMANDS: &str = "/commands";
/// The run's control channel: each request with its reply (`run --control`).
pub const TOPIC_CONTROL: &str = "/control";
/// Topic of expectation verdicts.
pub const TOPIC_EXPECTATIONS: &str = "/expectations";
/// Topic of the FC's true attitude (`foxglove.FrameTransform`, `eci` -> `body`).
pub const TOPIC_TRUTH_TF: &str = "/fc/truth/tf";
/// Topic of the ADCS's estimated attitude (`foxglove.FrameTransform`, `eci` -> `body_est`).
pub const TOPIC_ESTIMATE_TF: &str = "/fc/estimate/tf";
/// Topic of the satellite's geodetic position (`foxglove.LocationFix`).
pub const TOPIC_TRUTH_LOCATION: &str = "/fc/truth/location";
/// Topic of the FC's true state (`m6p.TruthState`).
pub const TOPIC_TRUTH_STATE: &str = "/fc/truth/state";
/// Topic of the ADCS's view: mode, estimate, target, errors, commands (`m6p.Adcs`).
pub const TOPIC_ADCS: &str = "/fc/adcs";
/// Topic of the 3D scene drawn in the body frame (`foxglove.SceneUpdate`).
pub const TOPIC_SCENE: &str = "/fc/scene";
/// The PC's session events and drops.
pub const TOPIC_PC_SESSIONS: &str = "/pc/sessions";
/// One message per PC session run, when it ends or is lost.
pub const TOPIC_PC_SESSION_SUMMARY: &str = "/pc/sessions/summary";
/// Payload bytes at the ground (the S-band sink).
pub const TOPIC_PC_DOWNLINK: &str = "/pc/downlink";
/// What the simulated payloads did.
pub const TOPIC_PAYLOADS: &str = "/payloads";
/// The EPS's power state, each EPS tick.
pub const TOPIC_EPS: &str = "/eps/power";
/// The EPS's channel switches.
pub const TOPIC_EPS_CHANNELS: &str = "/eps/channels";
/// Beacons received on the ground.
pub const TOPIC_BEACONS: &str = "/ground/beacons";

/// Foxglove frame id of ECI J2000 (axes only: the transforms carry no translation).
pub const FRAME_ECI: &str = "eci";
/// Foxglove frame id of the true body frame (BCF).
pub const FRAME_BODY: &str = "body";
/// Foxglove frame id of the body frame as the ADCS estimates it.
pub const FRAME_BODY_EST: &str = "body_est";
/// Foxglove frame id of `/fc/truth/location` (WGS-84).
pub const FRAME_EARTH: &str = "earth";
/// Id of the one entity of `/fc/scene`.
pub const SCENE_ENTITY_ID: &str = "m6p";

/// Edges of the M6P body along BCF X, Y, Z, m (ICD 1.4: Z along the 300 mm edge, X along the
/// 200 mm edge; 6U, so 100 mm along Y).
pub const BODY_SIZE_M: [f64; 3] = [0.2, 0.1, 0.3];

/// Message encoding of every channel.
pub const MESSAGE_ENCODING: &str = crate::protobuf::MESSAGE_ENCODING;
/// Schema encoding of every schema.
pub const SCHEMA_ENCODING: &str = crate::protobuf::SCHEMA_ENCODING;

/// What makes a recording self-describing: enough to re-run it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecordingMeta {
    /// Scenario name.
    pub scenario_name: String,
    /// The scenario file's exact text (stored as the `scenario.toml` attachment).
    pub scenario_toml: String,
    /// The run seed.
    pub seed: u64,
    /// Start of the run, `YYYY-MM-DDTHH:MM:SS[.fff]Z`; message times count from here.
    pub start_utc: String,
    /// Version of the twin that made the recording.
    pub twin_version: String,
    /// Simulated duration in nanoseconds when the command line overrode the scenario's
    /// (`--duration`), so that `replay` runs exactly as long; `None` keeps the scenario's.
    #[serde(default)]
    pub duration_ns: Option<u64>,
    /// Nodes of the network that outside programs replaced (not started), by address:
    /// the scenario's `replaces` and the command line's `--kiss-addr`, so that `replay`
    /// starts the same nodes (the command line's links are not in the scenario).
    #[serde(default)]
    pub replaced: Vec<u8>,
    /// The CSP addresses configured on each link to outside programs, by the link's label
    /// (`listen 127.0.0.1:0`), so that `replay` claims them as the run did (the command
    /// line's links are not in the scenario).
    #[serde(default)]
    pub link_addrs: BTreeMap<String, Vec<u8>>,
    /// The transmit budget (CAN frames a second) of each link that had one, by label, so
    /// that `replay` holds the same frames back (the command line's `--kiss-tx-budget` is
    /// not in the scenario).
    #[serde(default)]
    pub link_tx_budgets: BTreeMap<String, u32>,
    /// The rules that chose the recording's channels (`[record] channels`, `--channels`),
    /// so that `replay` records the same channels; none: every channel, every message.
    #[serde(default)]
    pub channels: Vec<twin_scenario::channels::ChannelRule>,
}

/// Messages written to one channel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelStats {
    /// Topic.
    pub topic: String,
    /// Messages written.
    pub messages: u64,
}

/// What [`Recorder::finish`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingStats {
    /// Messages per channel, in registration order.
    pub channels: Vec<ChannelStats>,
    /// Messages in all.
    pub messages: u64,
    /// Chunks written.
    pub chunks: u32,
    /// File size in bytes.
    pub bytes: u64,
}

/// The CFP fields of a CAN id.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct CfpFields {
    /// CSP source address.
    pub src: u8,
    /// Next-hop MAC.
    pub dst: u8,
    /// `BEGIN` or `MORE`.
    #[serde(rename = "type")]
    pub kind: String,
    /// Frames still to come after this one.
    pub remain: u8,
    /// Per-sender packet counter (10 bits).
    pub ident: u16,
}

/// A CSP header with the data length a BEGIN frame announces.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct BeginFields {
    /// Priority 0 (critical) .. 3 (low).
    pub prio: u8,
    /// Source address.
    pub src: u8,
    /// Destination address.
    pub dst: u8,
    /// Destination port.
    pub dport: u8,
    /// Source port.
    pub sport: u8,
    /// Flag bits.
    pub flags: u8,
    /// Announced data length.
    pub len: u16,
}

/// `/can/<bus>/frames`: a train of CAN frames, the frames one endpoint put on the bus one
/// after the other (the fragments of a CSP packet, usually), each with its own time.
/// Frame `i` is `can_id[i]`, `dlc[i]` bytes of `data` after those of the frames before it,
/// and ended `end_ns[i]` after `t_ns`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize, foxglove::Encode)]
pub struct CanFramesMsg {
    /// Simulated ns since the start of the run when the first frame's last bit arrived.
    pub t_ns: u64,
    /// Sending endpoint.
    pub from: String,
    /// 29-bit extended CAN ids (CFP: src, dst, BEGIN/MORE, remain, ident).
    pub can_id: Packed<u32>,
    /// Data lengths.
    pub dlc: Packed<u8>,
    /// When each frame ended, ns after `t_ns`.
    pub end_ns: Packed<u32>,
    /// The frames' data bytes, one after the other.
    #[serde(with = "crate::protobuf::hex_bytes")]
    pub data: bytes::Bytes,
    /// Indices of the frames an impairment dropped (empty: none).
    pub dropped: Packed<u32>,
}

impl CanFramesMsg {
    /// The frames, one by one: (end ns since the start, can id, data, dropped).
    pub fn frames(&self) -> impl Iterator<Item = (u64, u32, &[u8], bool)> + '_ {
        let mut at = 0usize;
        (0..self.can_id.len()).map(move |i| {
            let n = usize::from(self.dlc.get(i).copied().unwrap_or(0));
            let start = at.min(self.data.len());
            at = at.saturating_add(n);
            let end = at.min(self.data.len());
            (
                self.t_ns + u64::from(self.end_ns.get(i).copied().unwrap_or(0)),
                self.can_id[i],
                &self.data[start..end],
                self.dropped.contains(&(i as u32)),
            )
        })
    }
}

/// `/<network>/packets`: one packet on a packet network (the ground segment).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct NetPacketMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// Sending endpoint.
    pub from: String,
    /// Wire bytes `header | data`.
    #[serde(with = "crate::protobuf::hex_bytes")]
    pub bytes: bytes::Bytes,
    /// Whether an impairment dropped the packet.
    pub dropped: bool,
    /// Wire length in bytes (header included).
    pub len: u32,
    /// Priority (null when shorter than a header).
    pub prio: Option<u8>,
    /// Source address.
    pub src: Option<u8>,
    /// Destination address.
    pub dst: Option<u8>,
    /// Destination port.
    pub dport: Option<u8>,
    /// Source port.
    pub sport: Option<u8>,
    /// Flag bits.
    pub flags: Option<u8>,
}

/// One field of an ICD request or reply in `/csp/packets` (`twin_core::icd`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, foxglove::Encode)]
pub struct IcdFieldMsg {
    /// Path in the layout: `current_mode`, `panels_w[3]`, `general.uptime_s`.
    pub name: String,
    /// The value (NaN for a text field).
    pub value: f64,
    /// The value's meaning, where the ICD names it: an enumerated value (`nadir`), the set
    /// bits of a mask (`COMM1, PC`), or a text field's text.
    pub text: Option<String>,
}

/// `/csp/packets`: one CSP packet a medium delivered, decoded.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, foxglove::Encode)]
pub struct CspPacketMsg {
    /// Simulated ns since the start of the run (its last frame).
    pub t_ns: u64,
    /// Medium that carried it (`main`, `payload`, `ground`).
    pub medium: String,
    /// Endpoint that sent it (its last frame) on that medium.
    pub from: String,
    /// Priority 0 (critical) .. 3 (low).
    pub prio: u8,
    /// Source address.
    pub src: u8,
    /// Destination address.
    pub dst: u8,
    /// Destination port.
    pub dport: u8,
    /// Source port.
    pub sport: u8,
    /// Flag bits.
    pub flags: u8,
    /// Data bytes (after the header, CRC32 trailer included if any).
    #[serde(with = "crate::protobuf::hex_bytes")]
    pub data: bytes::Bytes,
    /// Data length.
    pub len: u32,
    /// Service name when dport (else sport) is a service port 0-6.
    pub service: Option<String>,
    /// ICD command, `NODE.COMMAND` (`FC.TMGEN`), when the packet goes to or comes from a
    /// port of the ICD (`m6p-twin icd`); else null.
    pub icd: Option<String>,
    /// `request`, `reply` (success) or `failure` (a failure reply), with `icd`.
    pub icd_kind: Option<String>,
    /// The request's or reply's fixed fields, decoded (empty for a failure, a layout of
    /// varying length, or data that does not fit the layout).
    pub fields: Vec<Nested<IcdFieldMsg>>,
}

/// `/kiss/<link>`: one KISS frame on an outside link.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct KissFrameMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// Link name.
    pub link: String,
    /// `in` (into the twin) or `out`.
    pub dir: String,
    /// The frame as it crossed the socket (FENDs and escapes included).
    #[serde(with = "crate::protobuf::hex_bytes")]
    pub bytes: bytes::Bytes,
    /// Length in bytes.
    pub len: u32,
}

/// Foxglove's `time` (`foxglove.Log` and the other Foxglove schemas' `timestamp`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogTime {
    /// Seconds since the Unix epoch (simulated).
    pub sec: u64,
    /// Nanoseconds.
    pub nsec: u32,
}

/// `/log`: Foxglove's `foxglove.Log`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogMsg {
    /// Simulated UTC time.
    pub timestamp: LogTime,
    /// 1 debug, 2 info, 3 warning, 4 error, 5 fatal.
    pub level: u8,
    /// Text.
    pub message: String,
    /// Source (node name, `run`, link).
    pub name: String,
    /// Always empty.
    pub file: String,
    /// Always 0.
    pub line: u32,
}

/// `/faults`: a fault applied or lifted.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct FaultMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// What happened.
    pub what: String,
}

/// `/control`: a request on the run's control channel, at the instant the run took it in,
/// with its reply (what `replay` feeds again).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct ControlMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// The connection it came on (from 1; 0: published by a client of the live view).
    pub conn: u32,
    /// The request line (JSON).
    pub request: String,
    /// The reply line (JSON).
    pub reply: String,
}

/// `/commands`: a scenario command sent (`event` = `sent`) or its outcome (`result`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct CommandMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// `sent` or `result`.
    pub event: String,
    /// Command name.
    pub name: String,
    /// Destination node (sent).
    pub dst: Option<u8>,
    /// Destination port (sent).
    pub dport: Option<u8>,
    /// Request bytes (sent).
    #[serde(with = "crate::protobuf::hex_bytes_opt")]
    pub data: Option<bytes::Bytes>,
    /// Whether a reply arrived (result).
    pub answered: Option<bool>,
    /// Reply bytes (result, when answered).
    #[serde(with = "crate::protobuf::hex_bytes_opt")]
    pub reply: Option<bytes::Bytes>,
    /// Round-trip time in ns (result, when answered).
    pub rtt_ns: Option<u64>,
}

/// `/pc/sessions`: a session started or ended, or payload bytes dropped by the PC.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct PcSessionMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// `started`, `ended`, `dropped` or `final` (the accounting at the end of the run).
    pub event: String,
    /// The session id (none for bytes from an unknown source).
    pub session: Option<u8>,
    /// The payload's address.
    pub payload: Option<u8>,
    /// `ended`: `done`, `aborted`, `no-ack` or `s-band-failure` (the PC's), or `lost` (the
    /// run was lost with the PC's memory; `reason` says how).
    pub result: Option<String>,
    /// `ended`: packets counted.
    pub packets: Option<u32>,
    /// `dropped`: why (`buffer-full`, `oversize`, `late`, `session-ended`, `sband-failure`,
    /// `unknown-source`, `power-loss`, `malformed`); `ended` with `lost`: `power` or
    /// `reboot`.
    pub reason: Option<String>,
    /// `dropped`: how many bytes; `final`: bytes still held (buffer and S-band queue).
    pub bytes: Option<u64>,
}

/// `/pc/sessions/summary`: one run of a PC session, written when the run ended or was lost:
/// how it ended, the packets the PC counted and the bytes of it the ground received.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct PcSessionSummaryMsg {
    /// Simulated ns since the start of the run when the run ended or was lost.
    pub t_ns: u64,
    /// The session id.
    pub session: u8,
    /// The session's payload address (null when the recorder was not given the run's PC
    /// sessions).
    pub payload: Option<u8>,
    /// `done`, `aborted`, `no-ack` or `s-band-failure` (the PC's result, as scenarios name
    /// it: `twin_scenario::pc::result_name`), or `lost` (the run was lost with the PC's
    /// memory; `cause` says how).
    pub result: String,
    /// With `lost`: `power` or `reboot`.
    pub cause: Option<String>,
    /// Packets the PC counted in the run (STATUS's count at its end).
    pub packets: u32,
    /// Payload bytes of the session the ground received from the run's start to its end.
    /// Bytes still in the S-band queue at the end reach the ground after it (`/pc/downlink`,
    /// and the run's downlink file), so they are not in this count.
    pub downlinked_bytes: u64,
    /// When the run became ACTIVE, simulated ns since the start of the run (null: the PC
    /// reported its end without its start).
    pub start_ns: Option<u64>,
}

/// `/pc/downlink`: an S-band frame's worth of payload bytes reached the ground (its length and
/// CRC; the bytes go to the ground sink's files).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct DownlinkMsg {
    /// Simulated ns since the start of the run (the last bit of the S-band frame).
    pub t_ns: u64,
    /// The session.
    pub session: u8,
    /// Its payload.
    pub payload: u8,
    /// Byte count.
    pub len: u32,
    /// CRC-32C (Castagnoli, as CSP's) of the bytes. The bytes themselves are in the ground
    /// sink's file (`<recording>.downlink/session-<id>-run<k>.bin`) and, before that, on the
    /// payload bus: recording them a third time would double the recording of a payload
    /// day with incompressible data (format 6).
    pub crc32c: u32,
}

/// `/payloads`: a simulated payload produced bytes or received a SYNC.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct PayloadMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// The payload's address.
    pub addr: u8,
    /// `produced` or `sync`.
    pub event: String,
    /// `produced`: bytes that left the payload.
    pub bytes: Option<u64>,
    /// `produced`: `poll-reply` or `push`.
    pub how: Option<String>,
    /// `sync`: the message.
    #[serde(with = "crate::protobuf::hex_bytes_opt")]
    pub msg: Option<bytes::Bytes>,
}

/// `/eps/power`: the EPS's state after one of its ticks (single precision: 7 digits).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, foxglove::Encode)]
pub struct EpsPowerMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// State of charge, 0..1.
    pub soc: f32,
    /// Battery terminal voltage, V.
    pub battery_v: f32,
    /// Battery current, A (positive charging).
    pub battery_a: f32,
    /// Solar array power, W.
    pub solar_w: f32,
    /// Total load, W.
    pub load_w: f32,
    /// Power of each panel, W (in the EPS's panel order).
    pub panels_w: Vec<f32>,
    /// Channels on (bit = channel id: COMM1, COMM2, ECU, PC, PL12-PL15, S-band).
    pub channels: u16,
}

/// `/ground/beacons`: a COMM beacon as the ground received it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct BeaconMsg {
    /// Simulated ns since the start of the run (arrival).
    pub t_ns: u64,
    /// The COMM that sent it (1 or 2).
    pub from: u8,
    /// The beacon's sequence number.
    pub seq: u32,
    /// The packet data (`04 01 | Beacon`, docs/protocol.md).
    #[serde(with = "crate::protobuf::hex_bytes")]
    pub data: bytes::Bytes,
}

/// `/eps/channels`: a power channel switched.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct EpsChannelMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// Channel name (`COMM1`, `PC`, `PL12`, `SBAND`, ...).
    pub channel: String,
    /// On or off.
    pub on: bool,
    /// Why: `initial`, `command`, `timeline`, `shed`, `restore`.
    pub cause: String,
}

/// `/expectations`: an expectation's verdict.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct ExpectationMsg {
    /// Simulated ns since the start of the run the verdict refers to.
    pub t_ns: u64,
    /// Expectation name.
    pub name: String,
    /// Whether it held.
    pub passed: bool,
    /// What was observed.
    pub observed: String,
}

/// `foxglove.Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Vec3Msg {
    /// X.
    pub x: f64,
    /// Y.
    pub y: f64,
    /// Z.
    pub z: f64,
}

/// `foxglove.Quaternion`: vector part first, scalar `w` last (Foxglove's order).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QuatMsg {
    /// i component.
    pub x: f64,
    /// j component.
    pub y: f64,
    /// k component.
    pub z: f64,
    /// Scalar component.
    pub w: f64,
}

/// `foxglove.Color`, each component 0..1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ColorMsg {
    /// Red.
    pub r: f64,
    /// Green.
    pub g: f64,
    /// Blue.
    pub b: f64,
    /// Alpha (1 opaque).
    pub a: f64,
}

/// `foxglove.Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseMsg {
    /// Position in the entity's frame, m.
    pub position: Vec3Msg,
    /// Orientation in the entity's frame.
    pub orientation: QuatMsg,
}

/// Foxglove's `duration`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DurationMsg {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nsec: u32,
}

/// `/fc/truth/tf`, `/fc/estimate/tf`: Foxglove's `foxglove.FrameTransform`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameTransformMsg {
    /// Simulated UTC time.
    pub timestamp: LogTime,
    /// Always `eci`.
    pub parent_frame_id: String,
    /// `body` (truth) or `body_est` (estimate).
    pub child_frame_id: String,
    /// Always zero (see the module docs).
    pub translation: Vec3Msg,
    /// `q_eci_from_body`, active: body vectors to ECI.
    pub rotation: QuatMsg,
}

/// `/fc/truth/location`: Foxglove's `foxglove.LocationFix`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LocationFixMsg {
    /// Simulated UTC time.
    pub timestamp: LogTime,
    /// Always `earth`.
    pub frame_id: String,
    /// Geodetic latitude (WGS-84), deg.
    pub latitude: f64,
    /// Longitude, deg east.
    pub longitude: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub altitude: f64,
    /// Always zeros (the truth has no uncertainty).
    pub position_covariance: [f64; 9],
    /// Always 0 (unknown).
    pub position_covariance_type: u8,
    /// Colour of the track on the map.
    pub color: ColorMsg,
}

/// `foxglove.ArrowPrimitive`: an arrow from `pose.position` along the pose's +x axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ArrowMsg {
    /// Tail position and orientation (identity points along +x).
    pub pose: PoseMsg,
    /// Shaft length, m.
    pub shaft_length: f64,
    /// Shaft diameter, m.
    pub shaft_diameter: f64,
    /// Head length, m.
    pub head_length: f64,
    /// Head diameter, m.
    pub head_diameter: f64,
    /// Colour.
    pub color: ColorMsg,
}

/// `foxglove.CubePrimitive`: a box centred on `pose.position`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CubeMsg {
    /// Centre and orientation.
    pub pose: PoseMsg,
    /// Edge lengths along the pose's x, y, z, m.
    pub size: Vec3Msg,
    /// Colour.
    pub color: ColorMsg,
}

/// `foxglove.SceneEntity`, with the primitives this recorder draws (the other kinds are
/// always empty).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneEntityMsg {
    /// Simulated UTC time.
    pub timestamp: LogTime,
    /// Always `body`.
    pub frame_id: String,
    /// Always `m6p`: each message replaces the previous entity.
    pub id: String,
    /// Zero: shown until replaced.
    pub lifetime: DurationMsg,
    /// True: the entity moves with `body`.
    pub frame_locked: bool,
    /// Always empty.
    pub metadata: Vec<serde_json::Value>,
    /// Body axes, then the sun and nadir directions.
    pub arrows: Vec<ArrowMsg>,
    /// The body box.
    pub cubes: Vec<CubeMsg>,
    /// Always empty.
    pub spheres: Vec<serde_json::Value>,
    /// Always empty.
    pub cylinders: Vec<serde_json::Value>,
    /// Always empty.
    pub lines: Vec<serde_json::Value>,
    /// Always empty.
    pub triangles: Vec<serde_json::Value>,
    /// Always empty.
    pub texts: Vec<serde_json::Value>,
    /// Always empty.
    pub models: Vec<serde_json::Value>,
}

/// `/fc/scene`: Foxglove's `foxglove.SceneUpdate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneUpdateMsg {
    /// Always empty (the entity is replaced by id).
    pub deletions: Vec<serde_json::Value>,
    /// The one entity.
    pub entities: Vec<SceneEntityMsg>,
}

/// A quaternion in the project's JSON: scalar first, as nalgebra and the ICD write it;
/// a non-finite component is null. Single precision: 6e-8, about 0.01 arcsecond.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, foxglove::Encode)]
pub struct QuatWxyz {
    /// Scalar component.
    pub w: Option<f32>,
    /// i component.
    pub x: Option<f32>,
    /// j component.
    pub y: Option<f32>,
    /// k component.
    pub z: Option<f32>,
}

/// `/fc/truth/state`: the FC's true state at one instant. Vectors are `[x, y, z]` in the
/// frame their name says; a non-finite number is null. Positions, velocity and the geodetic
/// point are double precision; the rest single (7 digits: 0.01 arcsecond of attitude).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, foxglove::Encode)]
pub struct TruthStateMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// True attitude, body (BCF) to ECI J2000, active.
    pub q_eci_from_body: Nested<QuatWxyz>,
    /// Position, ECI J2000, m.
    #[serde(with = "crate::protobuf::nan_null")]
    pub r_eci_m: [f64; 3],
    /// Velocity, ECI J2000, m/s.
    #[serde(with = "crate::protobuf::nan_null")]
    pub v_eci_m_s: [f64; 3],
    /// Position, ECEF (no polar motion, UT1 = UTC), m.
    #[serde(with = "crate::protobuf::nan_null")]
    pub r_ecef_m: [f64; 3],
    /// Geodetic latitude, WGS-84, deg.
    pub lat_deg: Option<f64>,
    /// Longitude, deg east.
    pub lon_deg: Option<f64>,
    /// Height above the WGS-84 ellipsoid, m.
    pub alt_m: Option<f64>,
    /// Unit vector to the sun, ECI.
    #[serde(with = "crate::protobuf::nan_null")]
    pub sun_eci_unit: [f32; 3],
    /// Unit vector to the sun, body frame.
    #[serde(with = "crate::protobuf::nan_null")]
    pub sun_body_unit: [f32; 3],
    /// Visible fraction of the solar disc: 1 sunlit, 0 umbra.
    pub sun_visible_fraction: Option<f32>,
    /// Geomagnetic field, ECI, nT.
    #[serde(with = "crate::protobuf::nan_null")]
    pub b_eci_nt: [f32; 3],
    /// Geomagnetic field, body frame, nT.
    #[serde(with = "crate::protobuf::nan_null")]
    pub b_body_nt: [f32; 3],
    /// Body rate relative to ECI, body frame, deg/s.
    #[serde(with = "crate::protobuf::nan_null")]
    pub w_body_deg_s: [f32; 3],
    /// Norm of the body rate, deg/s.
    pub rate_deg_s: Option<f32>,
    /// Reaction wheel speeds relative to the body, rpm (wheels 1-4).
    #[serde(with = "crate::protobuf::nan_null")]
    pub wheel_speed_rpm: [f32; 4],
    /// Magnetorquer dipoles as applied, body X, Y, Z, A m^2.
    #[serde(with = "crate::protobuf::nan_null")]
    pub mtq_dipole_am2: [f32; 3],
}

/// `/fc/adcs`: what the ADCS believes and does at one instant; a non-finite number is null.
/// Single precision (7 digits), as flight software computes it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, foxglove::Encode)]
pub struct AdcsMsg {
    /// Simulated ns since the start of the run.
    pub t_ns: u64,
    /// Target mode in effect (docs/protocol.md enumeration; 1 while detumbling).
    pub mode_in_effect: u8,
    /// Target mode commanded.
    pub mode_commanded: u8,
    /// 0 off, 1 detumbling, 2 acquiring, 3 tracking.
    pub state: u8,
    /// Estimated attitude (body to ECI), null until the estimator is initialised.
    pub q_eci_from_body_est: Option<Nested<QuatWxyz>>,
    /// Estimated body rate, body frame, deg/s.
    #[serde(with = "crate::protobuf::nan_null")]
    pub w_body_deg_s_est: [f32; 3],
    /// Estimated gyro bias, body frame, deg/s.
    #[serde(with = "crate::protobuf::nan_null")]
    pub gyro_bias_deg_s_est: [f32; 3],
    /// Target attitude (body to ECI) of the mode in effect, null when it has none.
    pub q_eci_from_body_target: Option<Nested<QuatWxyz>>,
    /// Rotation angle from the true to the target attitude, deg.
    pub pointing_error_deg: Option<f32>,
    /// Angle between the mode's pointing axis and its target direction, deg.
    pub axis_error_deg: Option<f32>,
    /// Elevation of the satellite from the ground target, deg (earth-target modes).
    pub target_elevation_deg: Option<f32>,
    /// Rotation angle from the true to the estimated attitude, deg.
    pub estimation_error_deg: Option<f32>,
    /// Reaction wheel states: 0 off, 1 on, 2 fault.
    pub rw_state: [u8; 4],
    /// Commanded wheel motor torques, N m.
    #[serde(with = "crate::protobuf::nan_null")]
    pub wheel_torque_cmd_nm: [f32; 4],
    /// Commanded magnetorquer dipoles, body X, Y, Z, A m^2.
    #[serde(with = "crate::protobuf::nan_null")]
    pub mtq_dipole_cmd_am2: [f32; 3],
    /// Magnetorquer states: 0 off, 1 positive, 2 negative.
    pub mtq_state: [u8; 3],
}

/// Name of CSP service port `port` (0-6), as libcsp's service handler calls them.
pub fn service_name(port: u8) -> Option<&'static str> {
    Some(match port {
        0 => "cmp",
        1 => "ping",
        2 => "ps",
        3 => "memfree",
        4 => "reboot",
        5 => "buf_free",
        6 => "uptime",
        _ => return None,
    })
}

/// The service a packet belongs to: its dport's if that is a service port, else its sport's.
pub fn packet_service(h: &Header) -> Option<&'static str> {
    service_name(h.dport).or_else(|| service_name(h.sport))
}

/// The channel topic of a KISS link: `/kiss/` and the link name with every character other
/// than `A-Z a-z 0-9 . _ : -` replaced by `_`.
pub fn kiss_topic(link: &str) -> String {
    let clean: String = link
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._:-".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("/kiss/{clean}")
}

/// The decoded CFP fields of a CAN id.
pub fn cfp_fields(can_id: u32) -> CfpFields {
    let id = CfpId::from_can_id(can_id);
    CfpFields {
        src: id.src,
        dst: id.dst,
        kind: match id.kind {
            FrameType::Begin => "BEGIN",
            FrameType::More => "MORE",
        }
        .to_owned(),
        remain: id.remain,
        ident: id.ident,
    }
}

/// The CSP header and length a BEGIN frame carries, if `f` is one with at least 6 bytes.
pub fn begin_fields(f: &CanFrame) -> Option<BeginFields> {
    if CfpId::from_can_id(f.id).kind != FrameType::Begin {
        return None;
    }
    let d = f.data();
    let h = Header::parse(d).ok()?;
    let len = u16::from_be_bytes([*d.get(HEADER_LEN)?, *d.get(HEADER_LEN + 1)?]);
    Some(BeginFields {
        prio: h.prio as u8,
        src: h.src,
        dst: h.dst,
        dport: h.dport,
        sport: h.sport,
        flags: h.flags,
        len,
    })
}

/// The recorded channels, one row each: the kind, its schema's name, the schema (a message
/// type's JSON Schema, or one of Foxglove's), its topic (from the key: the bus, network or
/// `<link>/<dir>`; fixed kinds ignore it), the metadata name of its key, and whether it is a
/// medium channel (`diff` compares those). Adding a channel is a row here, its message type,
/// and the arm of [`EventEncoder`] that emits it.
macro_rules! channels {
    ($($kind:ident => ($schema_name:expr, $schema:expr, $topic:expr, $meta:expr, $medium:expr): $doc:literal,)*) => {
        /// Which kind of channel a message goes to; each kind has one schema.
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum ChannelKind {
            $(#[doc = $doc] $kind,)*
        }

        /// Every kind, in declaration order (`kind as usize` indexes it).
        pub const CHANNEL_KINDS: &[ChannelKind] = &[$(ChannelKind::$kind,)*];

        impl ChannelKind {
            /// The schema's name.
            pub fn schema_name(self) -> &'static str {
                match self {
                    $(ChannelKind::$kind => $schema_name,)*
                }
            }

            /// The schema of the messages: a protobuf `FileDescriptorSet` (schema encoding
            /// [`SCHEMA_ENCODING`]).
            pub fn schema_data(self) -> anyhow::Result<Vec<u8>> {
                match self {
                    $(ChannelKind::$kind => $schema,)*
                }
            }

            /// The topic of this kind's channel for `key` (the bus, network or
            /// `<link>/<dir>`; ignored by the fixed kinds).
            pub fn topic(self, key: &str) -> String {
                let topic: fn(&str) -> String = match self {
                    $(ChannelKind::$kind => $topic,)*
                };
                topic(key)
            }

            /// Whether its messages are what crossed a medium (a bus, a network, an outside
            /// link): the channels `diff` compares.
            pub fn is_medium(self) -> bool {
                match self {
                    $(ChannelKind::$kind => $medium,)*
                }
            }

            /// The channel's metadata: `bus`, `link` or `medium` = `key` when there is a key.
            pub fn metadata(self, key: &str) -> BTreeMap<String, String> {
                let name: &str = match self {
                    $(ChannelKind::$kind => $meta,)*
                };
                let mut metadata = BTreeMap::new();
                if !key.is_empty() {
                    metadata.insert(name.to_owned(), key.to_owned());
                }
                metadata
            }
        }
    };
}

/// Whether a recorded channel with schema `schema` is a medium channel (what crossed a
/// bus, a network or an outside link: the channels `diff` compares), from the table.
pub fn is_medium_schema(schema: &str) -> bool {
    CHANNEL_KINDS
        .iter()
        .any(|k| k.is_medium() && k.schema_name() == schema)
}

/// The schema of the project's message type `T`, named `m6p.<name>`.
fn schema_of<T: foxglove::Encode>(name: &str) -> anyhow::Result<Vec<u8>> {
    crate::protobuf::schema::<T>(name)
}

/// The schema of Foxglove's well-known message type `T`, as the foxglove crate gives it.
fn foxglove_schema<T: foxglove::Encode>() -> anyhow::Result<Vec<u8>> {
    T::get_schema()
        .map(|s| s.data.into_owned())
        .ok_or_else(|| anyhow::anyhow!("no schema"))
}

/// A fixed topic.
fn fixed(topic: &'static str) -> String {
    topic.to_owned()
}

channels! {
    Can => ("m6p.CanFrames", schema_of::<CanFramesMsg>("CanFrames"), |k| format!("/can/{k}/frames"), "bus", true):
        "`/can/<bus>/frames` (`m6p.CanFrames`, a train of frames per message), keyed by bus.",
    Net => ("m6p.NetPacket", schema_of::<NetPacketMsg>("NetPacket"), |k| format!("/{k}/packets"), "medium", true):
        "`/<network>/packets` (`m6p.NetPacket`), keyed by network.",
    Csp => ("m6p.CspPacket", schema_of::<CspPacketMsg>("CspPacket"), |_| fixed(TOPIC_CSP), "medium", false):
        "`/csp/packets` (`m6p.CspPacket`).",
    Kiss => ("m6p.KissFrame", schema_of::<KissFrameMsg>("KissFrame"), |k| match k.rsplit_once('/') {
            Some((link, dir)) => format!("{}/{dir}", kiss_topic(link)),
            None => kiss_topic(k),
        }, "link", true):
        "`/kiss/<link>/in|out` (`m6p.KissFrame`), keyed by `<link name>/<dir>`.",
    Log => ("foxglove.Log", foxglove_schema::<foxglove::messages::Log>(), |_| fixed(TOPIC_LOG), "medium", false):
        "`/log` (`foxglove.Log`).",
    Fault => ("m6p.Fault", schema_of::<FaultMsg>("Fault"), |_| fixed(TOPIC_FAULTS), "medium", false):
        "`/faults` (`m6p.Fault`).",
    Command => ("m6p.Command", schema_of::<CommandMsg>("Command"), |_| fixed(TOPIC_COMMANDS), "medium", false):
        "`/commands` (`m6p.Command`).",
    Expectation => ("m6p.Expectation", schema_of::<ExpectationMsg>("Expectation"), |_| fixed(TOPIC_EXPECTATIONS), "medium", false):
        "`/expectations` (`m6p.Expectation`).",
    TruthTf => ("foxglove.FrameTransform", foxglove_schema::<foxglove::messages::FrameTransform>(), |_| fixed(TOPIC_TRUTH_TF), "medium", false):
        "`/fc/truth/tf` (`foxglove.FrameTransform`).",
    EstimateTf => ("foxglove.FrameTransform", foxglove_schema::<foxglove::messages::FrameTransform>(), |_| fixed(TOPIC_ESTIMATE_TF), "medium", false):
        "`/fc/estimate/tf` (`foxglove.FrameTransform`).",
    TruthLocation => ("foxglove.LocationFix", foxglove_schema::<foxglove::messages::LocationFix>(), |_| fixed(TOPIC_TRUTH_LOCATION), "medium", false):
        "`/fc/truth/location` (`foxglove.LocationFix`).",
    TruthState => ("m6p.TruthState", schema_of::<TruthStateMsg>("TruthState"), |_| fixed(TOPIC_TRUTH_STATE), "medium", false):
        "`/fc/truth/state` (`m6p.TruthState`).",
    Adcs => ("m6p.Adcs", schema_of::<AdcsMsg>("Adcs"), |_| fixed(TOPIC_ADCS), "medium", false):
        "`/fc/adcs` (`m6p.Adcs`).",
    Scene => ("foxglove.SceneUpdate", foxglove_schema::<foxglove::messages::SceneUpdate>(), |_| fixed(TOPIC_SCENE), "medium", false):
        "`/fc/scene` (`foxglove.SceneUpdate`).",
    PcSession => ("m6p.PcSession", schema_of::<PcSessionMsg>("PcSession"), |_| fixed(TOPIC_PC_SESSIONS), "medium", false):
        "`/pc/sessions` (`m6p.PcSession`).",
    Downlink => ("m6p.Downlink", schema_of::<DownlinkMsg>("Downlink"), |_| fixed(TOPIC_PC_DOWNLINK), "medium", false):
        "`/pc/downlink` (`m6p.Downlink`).",
    Payload => ("m6p.Payload", schema_of::<PayloadMsg>("Payload"), |_| fixed(TOPIC_PAYLOADS), "medium", false):
        "`/payloads` (`m6p.Payload`).",
    EpsPower => ("m6p.EpsPower", schema_of::<EpsPowerMsg>("EpsPower"), |_| fixed(TOPIC_EPS), "medium", false):
        "`/eps/power` (`m6p.EpsPower`).",
    EpsChannel => ("m6p.EpsChannel", schema_of::<EpsChannelMsg>("EpsChannel"), |_| fixed(TOPIC_EPS_CHANNELS), "medium", false):
        "`/eps/channels` (`m6p.EpsChannel`).",
    Beacon => ("m6p.Beacon", schema_of::<BeaconMsg>("Beacon"), |_| fixed(TOPIC_BEACONS), "medium", false):
        "`/ground/beacons` (`m6p.Beacon`).",
    CanError => ("m6p.CanError", schema_of::<CanErrorMsg>("CanError"), |k| format!("/can/{k}/errors"), "bus", true):
        "`/can/<bus>/errors` (`m6p.CanError`), keyed by bus.",
    PcSessionSummary => ("m6p.PcSessionSummary", schema_of::<PcSessionSummaryMsg>("PcSessionSummary"), |_| fixed(TOPIC_PC_SESSION_SUMMARY), "medium", false):
        "`/pc/sessions/summary` (`m6p.PcSessionSummary`).",
    Control => ("m6p.Control", schema_of::<ControlMsg>("Control"), |_| fixed(TOPIC_CONTROL), "medium", false):
        "`/control` (`m6p.Control`), registered with its first request.",
}

/// The channels every run has, as (kind, key), in registration order; others (another
/// bus, a KISS link) are registered when their first message comes.
pub const FIXED_CHANNELS: [(ChannelKind, &str); 8] = [
    (ChannelKind::Can, "main"),
    (ChannelKind::Can, "payload"),
    (ChannelKind::Net, "ground"),
    (ChannelKind::Csp, ""),
    (ChannelKind::Log, ""),
    (ChannelKind::Fault, ""),
    (ChannelKind::Command, ""),
    (ChannelKind::Expectation, ""),
];

/// An error frame or a CAN controller's change of error state (`/can/<bus>/errors`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, foxglove::Encode)]
pub struct CanErrorMsg {
    /// Simulated ns since the start (the end of the error frame, or the change).
    pub t_ns: u64,
    /// The controller (node or outside endpoint).
    pub node: String,
    /// `error-frame` (its transmission destroyed), `error-passive`, `bus-off` or
    /// `error-active` (back, or recovered from bus-off).
    pub event: String,
    /// The destroyed frame's CAN id (`error-frame` only).
    pub can_id: Option<u32>,
    /// Its transmit error counter after the event.
    pub tec: u16,
    /// Its receive error counter after the event.
    pub rec: u16,
}

/// One encoded message, as [`EventEncoder::encode`] hands it out.
#[derive(Debug, Clone, Copy)]
pub struct Encoded<'a> {
    /// Its channel's kind.
    pub kind: ChannelKind,
    /// Its channel's key (bus, network, `<link>/<dir>`; empty for the fixed kinds).
    pub key: &'a str,
    /// Simulated time of the event.
    pub t: SimTime,
    /// Log time: `start_utc` + `t`, in ns since the Unix epoch.
    pub log_time: u64,
    /// The message (encoding [`MESSAGE_ENCODING`]).
    pub data: &'a [u8],
}

impl Encoded<'_> {
    /// The channel's topic.
    pub fn topic(&self) -> String {
        self.kind.topic(self.key)
    }
}

/// Turns [`RunEvent`]s into channel messages: the one encoding that both the MCAP
/// [`Recorder`] and the live view (`crate::live`) use. It keeps a CFP reassembler per CAN
/// bus, so a frame that completes a CSP packet gives two messages (the frame, then the
/// `/csp/packets` message).
pub struct EventEncoder {
    /// `start_utc` in ns since the Unix epoch.
    base_ns: u64,
    /// The CAN frame train being gathered on each bus, by bus name, in order of appearance.
    trains: Vec<(Arc<str>, Option<Train>)>,
    /// The run's packets (CFP reassembled per bus), for `/csp/packets`.
    /// The ICD on the run's ports, to decode `/csp/packets` (and the payload of each PC
    /// session, for `/pc/sessions/summary`).
    icd: twin_core::icd::IcdMap,
    /// Each PC session's open run, by session id (at most the PC's sessions), summed up
    /// on `/pc/sessions/summary` when it ends: the events of its end carry no start and no
    /// byte count.
    pc_runs: BTreeMap<u8, PcRunTally>,
    buf: Vec<u8>,
    key: String,
    /// The last `/csp/packets` message, reused for the next.
    csp: CspPacketMsg,
    /// Decoded fields the last packet did not need, reused for the next.
    spare_fields: Vec<Nested<IcdFieldMsg>>,
    /// The ICD field paths are built here.
    path: String,
    /// The truth's ECI -> ECEF rotation.
    ecef: EcefFromEci,
    /// Trains handed out, kept for their vectors.
    spare_trains: Vec<Train>,
    /// The recording's channel rules, to skip encoding what they leave out (the
    /// recorder's [`McapOut`] applies them to what is encoded).
    rules: Vec<twin_scenario::channels::ChannelRule>,
    /// Whether each channel seen so far is left out, by kind and key.
    left_out: Vec<(ChannelKind, Arc<str>, bool)>,
    /// Whether the rules leave out a whole channel at all (else nothing is looked up).
    any_left_out: bool,
    /// Whether the rules leave out each bus's frames, as `trains`.
    train_left_out: Vec<bool>,
}

/// A PC session's open run as far as its summary needs it.
#[derive(Debug, Clone, Copy, Default)]
struct PcRunTally {
    /// When it became ACTIVE.
    started: Option<SimTime>,
    /// Payload bytes of the session the ground received since.
    downlinked_bytes: u64,
}

impl std::fmt::Debug for EventEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EventEncoder")
            .field("base_ns", &self.base_ns)
            .finish_non_exhaustive()
    }
}

/// Frames of one `/can/<bus>/frames` message at most.
pub const TRAIN_MAX_FRAMES: usize = 64;
/// Simulated time one `/can/<bus>/frames` message spans at most (its frames' ends), ns.
pub const TRAIN_MAX_SPAN_NS: u64 = 100_000_000;

/// A train of CAN frames being gathered: consecutive frames one endpoint sent on one bus.
#[derive(Debug, Default)]
struct Train {
    t0: SimTime,
    msg: CanFramesMsg,
    data: Vec<u8>,
    /// The sender's name as its frames carry it (`msg.from`'s text): a bus hands out one
    /// allocation per sender, so a frame continues the train without comparing the bytes.
    from: Option<Arc<str>>,
}

/// Where [`EventEncoder::encode`] hands its messages.
pub type Emit<'e> = dyn FnMut(Encoded<'_>) -> anyhow::Result<()> + 'e;

/// Encode `msg` into `buf` and hand it to `emit`.
fn emit_msg<T: foxglove::Encode>(
    buf: &mut Vec<u8>,
    base_ns: u64,
    (kind, key): (ChannelKind, &str),
    t: SimTime,
    msg: &T,
    emit: &mut Emit<'_>,
) -> anyhow::Result<()> {
    buf.clear();
    msg.encode(buf)
        .map_err(|e| anyhow::anyhow!("encoding a {} message: {e}", kind.schema_name()))?;
    emit(Encoded {
        kind,
        key,
        t,
        log_time: base_ns.saturating_add(t.as_ns()),
        data: buf,
    })
}

/// A scenario command as sent: the `/commands` message with its request.
fn command_sent_msg(t_ns: u64, name: &str, dst: u8, dport: u8, data: &[u8]) -> CommandMsg {
    CommandMsg {
        t_ns,
        event: "sent".to_owned(),
        name: name.to_owned(),
        dst: Some(dst),
        dport: Some(dport),
        data: Some(bytes::Bytes::copy_from_slice(data)),
        answered: None,
        reply: None,
        rtt_ns: None,
    }
}

/// A scenario command's outcome: the `/commands` message with its reply, if any.
fn command_result_msg(
    t_ns: u64,
    name: &str,
    reply: Option<&[u8]>,
    rtt_ns: Option<u64>,
) -> CommandMsg {
    CommandMsg {
        t_ns,
        event: "result".to_owned(),
        name: name.to_owned(),
        dst: None,
        dport: None,
        data: None,
        answered: Some(reply.is_some()),
        reply: reply.map(bytes::Bytes::copy_from_slice),
        rtt_ns,
    }
}

/// Foxglove's `time` of simulated time `t` in a run that started `base_ns` after the epoch.
fn foxglove_time(base_ns: u64, t: SimTime) -> LogTime {
    let unix = base_ns.saturating_add(t.as_ns());
    LogTime {
        sec: unix / 1_000_000_000,
        nsec: (unix % 1_000_000_000) as u32,
    }
}

/// rad/s to rpm: 60 s per minute over 2 pi rad per revolution.
const RAD_S_TO_RPM: f64 = 60.0 / std::f64::consts::TAU;

/// `x` when finite, else `None` (JSON null).
fn num(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// Each element, NaN when not finite (null in the decoded JSON).
fn nums<const N: usize>(xs: [f64; N]) -> [f64; N] {
    xs.map(|x| if x.is_finite() { x } else { f64::NAN })
}

/// `x` in single precision when finite there, else `None` (JSON null).
fn num32(x: f64) -> Option<f32> {
    let y = x as f32;
    y.is_finite().then_some(y)
}

/// Each element in single precision, NaN when not finite there.
fn nums32<const N: usize>(xs: [f64; N]) -> [f32; N] {
    xs.map(|x| num32(x).unwrap_or(f32::NAN))
}

/// The components of a 3-vector (an nalgebra `Vector3<f64>`).
fn xyz<V: std::ops::Index<usize, Output = f64>>(v: &V) -> [f64; 3] {
    [v[0], v[1], v[2]]
}

/// `v` scaled to unit length, `None` when it is zero or not finite.
fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    (n.is_finite() && n > 0.0).then(|| v.map(|c| c / n))
}

/// A quaternion `[w, x, y, z]` (scalar first) in Foxglove's order, `None` if a component
/// is not finite.
fn quat_xyzw([w, x, y, z]: [f64; 4]) -> Option<QuatMsg> {
    [w, x, y, z]
        .iter()
        .all(|c| c.is_finite())
        .then_some(QuatMsg { x, y, z, w })
}

/// A quaternion `[w, x, y, z]` in the project's JSON.
fn quat_wxyz([w, x, y, z]: [f64; 4]) -> Nested<QuatWxyz> {
    Nested(QuatWxyz {
        w: num32(w),
        x: num32(x),
        y: num32(y),
        z: num32(z),
    })
}

/// The `eci` -> `child` transform with rotation `rotation` and no translation.
fn frame_transform(timestamp: LogTime, child: &str, rotation: QuatMsg) -> FrameTransformMsg {
    FrameTransformMsg {
        timestamp,
        parent_frame_id: FRAME_ECI.to_owned(),
        child_frame_id: child.to_owned(),
        translation: Vec3Msg {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        },
        rotation,
    }
}

/// A(ECEF <- ECI J2000) for the truth: the Earth's rotation (GMST) at the instant, and
/// precession and nutation, A(J2000 <- TEME), interpolated linearly between the two ends of
/// the UTC minute the instant falls in ([`orbit::frames::J2000FromTemeByMinute`]: within
/// 1e-6 m of the exact rotation at 7000 km, the IAU-80 nutation series once a minute
/// instead of once a second).
#[derive(Debug, Default)]
struct EcefFromEci {
    j2000_from_teme: orbit::frames::J2000FromTemeByMinute,
}

impl EcefFromEci {
    fn at(&mut self, unix_ns: i64) -> Matrix3<f64> {
        let a_j2000_from_teme = self.j2000_from_teme.at(unix_ns);
        a_ecef_from_teme(UtcTime::from_unix_ns(unix_ns), None) * a_j2000_from_teme.transpose()
    }
}

/// The `/fc/truth/state` message of `truth` at `t_ns`.
fn truth_state(t_ns: u64, truth: &TruthSnapshot, ecef: &mut EcefFromEci) -> TruthStateMsg {
    let q = &truth.q_eci_from_body;
    let r_ecef_m = ecef.at(truth.unix_ns) * truth.r_eci_m;
    // Only a finite position has a place (the conversion maps a NaN x to longitude 0).
    let geo = xyz(&r_ecef_m)
        .iter()
        .all(|c| c.is_finite())
        .then(|| ecef_m_to_geodetic(&r_ecef_m));
    let w_body_deg_s = xyz(&truth.w_body_rad_s).map(f64::to_degrees);
    let rate_deg_s = w_body_deg_s.iter().map(|c| c * c).sum::<f64>().sqrt();
    TruthStateMsg {
        t_ns,
        q_eci_from_body: quat_wxyz([q.w, q.i, q.j, q.k]),
        r_eci_m: nums(xyz(&truth.r_eci_m)),
        v_eci_m_s: nums(xyz(&truth.v_eci_m_s)),
        r_ecef_m: nums(xyz(&r_ecef_m)),
        lat_deg: geo.map(|g| g.lat_deg()).and_then(num),
        lon_deg: geo.map(|g| g.lon_deg()).and_then(num),
        alt_m: geo.map(|g| g.alt_m).and_then(num),
        sun_eci_unit: nums32(xyz(&truth.sun_eci_unit)),
        sun_body_unit: nums32(xyz(&eci_to_body(q, &truth.sun_eci_unit))),
        sun_visible_fraction: num32(truth.in_eclipse_fraction_visible),
        b_eci_nt: nums32(xyz(&truth.b_eci_nt)),
        b_body_nt: nums32(xyz(&eci_to_body(q, &truth.b_eci_nt))),
        w_body_deg_s: nums32(w_body_deg_s),
        rate_deg_s: num32(rate_deg_s),
        wheel_speed_rpm: nums32(truth.wheel_speed_rad_s.map(|w| w * RAD_S_TO_RPM)),
        mtq_dipole_am2: nums32(truth.mtq_dipole_am2),
    }
}

/// Colour of the ground track on the map (orange).
const TRACK_COLOR: ColorMsg = ColorMsg {
    r: 1.0,
    g: 0.5,
    b: 0.0,
    a: 1.0,
};

/// The `/fc/truth/location` message of a true state, `None` when the position is zero or
/// not finite (no place on the map).
fn location_fix(timestamp: LogTime, state: &TruthStateMsg) -> Option<LocationFixMsg> {
    let r = state.r_eci_m;
    let placed = r.iter().all(|c| c.is_finite()) && r.iter().any(|c| *c != 0.0);
    if !placed {
        return None;
    }
    Some(LocationFixMsg {
        timestamp,
        frame_id: FRAME_EARTH.to_owned(),
        latitude: state.lat_deg?,
        longitude: state.lon_deg?,
        altitude: state.alt_m?,
        position_covariance: [0.0; 9],
        position_covariance_type: 0,
        color: TRACK_COLOR,
    })
}

/// The `/fc/adcs` message of `adcs` at `t_ns`.
fn adcs_msg(t_ns: u64, adcs: &AdcsSnapshot) -> AdcsMsg {
    let deg = |v: [f64; 3]| nums32(v.map(f64::to_degrees));
    let fin = |x: Option<f64>| x.and_then(num32);
    AdcsMsg {
        t_ns,
        mode_in_effect: adcs.mode_in_effect,
        mode_commanded: adcs.mode_commanded,
        state: adcs.state,
        q_eci_from_body_est: adcs
            .q_eci_from_body_est
            .as_ref()
            .map(|q| quat_wxyz([q.w, q.i, q.j, q.k])),
        w_body_deg_s_est: deg(xyz(&adcs.w_body_rad_s_est)),
        gyro_bias_deg_s_est: deg(xyz(&adcs.gyro_bias_rad_s_est)),
        q_eci_from_body_target: adcs
            .q_eci_from_body_target
            .as_ref()
            .map(|q| quat_wxyz([q.w, q.i, q.j, q.k])),
        pointing_error_deg: fin(adcs.pointing_error_deg),
        axis_error_deg: fin(adcs.axis_error_deg),
        target_elevation_deg: fin(adcs.target_elevation_deg),
        estimation_error_deg: fin(adcs.estimation_error_deg),
        rw_state: adcs.rw_state,
        wheel_torque_cmd_nm: nums32(adcs.wheel_torque_cmd_nm),
        mtq_dipole_cmd_am2: nums32(adcs.mtq_dipole_cmd_am2),
        mtq_state: adcs.mtq_state,
    }
}

/// The orientation that turns an arrow (identity points along +x) onto unit vector `d`:
/// the shortest rotation, `[1 + x.d, x × d]` normalised, or a half turn about z when `d`
/// is -x.
fn arrow_orientation(d: [f64; 3]) -> QuatMsg {
    let w = 1.0 + d[0];
    if w < 1e-9 {
        return QuatMsg {
            x: 0.0,
            y: 0.0,
            z: 1.0,
            w: 0.0,
        };
    }
    // x × d = (0, -d.z, d.y); adding 0.0 turns -0.0 into 0.0 for tidier JSON.
    let (y, z) = (-d[2] + 0.0, d[1] + 0.0);
    let n = (w * w + y * y + z * z).sqrt();
    QuatMsg {
        x: 0.0,
        y: y / n,
        z: z / n,
        w: w / n,
    }
}

/// Shaft length, head length, shaft diameter and head diameter of the body axis arrows, m.
const AXIS_ARROW_M: [f64; 4] = [0.25, 0.05, 0.01, 0.025];
/// The same for the sun and nadir arrows, m.
const DIRECTION_ARROW_M: [f64; 4] = [0.4, 0.08, 0.015, 0.04];

/// An arrow from the body origin along unit vector `d`.
fn arrow(d: [f64; 3], [shaft, head, shaft_d, head_d]: [f64; 4], color: ColorMsg) -> ArrowMsg {
    ArrowMsg {
        pose: PoseMsg {
            position: Vec3Msg {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
            orientation: arrow_orientation(d),
        },
        shaft_length: shaft,
        shaft_diameter: shaft_d,
        head_length: head,
        head_diameter: head_d,
        color,
    }
}

/// An opaque colour.
const fn rgb(r: f64, g: f64, b: f64) -> ColorMsg {
    ColorMsg { r, g, b, a: 1.0 }
}

/// The `/fc/scene` message of `truth`: the body box, the body axes, and the sun and nadir
/// directions in the body frame (each left out when it is not defined).
fn scene_update(timestamp: LogTime, truth: &TruthSnapshot) -> SceneUpdateMsg {
    let q = &truth.q_eci_from_body;
    let mut arrows = vec![
        arrow([1.0, 0.0, 0.0], AXIS_ARROW_M, rgb(1.0, 0.0, 0.0)),
        arrow([0.0, 1.0, 0.0], AXIS_ARROW_M, rgb(0.0, 0.8, 0.0)),
        arrow([0.0, 0.0, 1.0], AXIS_ARROW_M, rgb(0.0, 0.3, 1.0)),
    ];
    if let Some(sun) = unit(xyz(&eci_to_body(q, &truth.sun_eci_unit))) {
        // Full yellow in sunlight, dimmed towards umbra.
        let lit = truth.in_eclipse_fraction_visible;
        let lit = if lit.is_finite() {
            lit.clamp(0.0, 1.0)
        } else {
            1.0
        };
        let color = ColorMsg {
            a: 0.3 + 0.7 * lit,
            ..rgb(1.0, 0.85, 0.0)
        };
        arrows.push(arrow(sun, DIRECTION_ARROW_M, color));
    }
    if let Some(nadir) = unit(xyz(&eci_to_body(q, &-truth.r_eci_m))) {
        arrows.push(arrow(nadir, DIRECTION_ARROW_M, rgb(1.0, 0.0, 1.0)));
    }
    let [x, y, z] = BODY_SIZE_M;
    let body = CubeMsg {
        pose: PoseMsg {
            position: Vec3Msg {
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
            orientation: QuatMsg {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            },
        },
        size: Vec3Msg { x, y, z },
        color: ColorMsg {
            r: 0.75,
            g: 0.75,
            b: 0.8,
            a: 0.4,
        },
    };
    SceneUpdateMsg {
        deletions: Vec::new(),
        entities: vec![SceneEntityMsg {
            timestamp,
            frame_id: FRAME_BODY.to_owned(),
            id: SCENE_ENTITY_ID.to_owned(),
            lifetime: DurationMsg { sec: 0, nsec: 0 },
            frame_locked: true,
            metadata: Vec::new(),
            arrows,
            cubes: vec![body],
            spheres: Vec::new(),
            cylinders: Vec::new(),
            lines: Vec::new(),
            triangles: Vec::new(),
            texts: Vec::new(),
            models: Vec::new(),
        }],
    }
}

/// Foxglove's time of a [`LogTime`] (seconds fit a `u32` until 2106).
fn fg_time(t: LogTime) -> foxglove::messages::Timestamp {
    foxglove::messages::Timestamp::new(u32::try_from(t.sec).unwrap_or(u32::MAX), t.nsec)
}

fn fg_vec(v: Vec3Msg) -> foxglove::messages::Vector3 {
    foxglove::messages::Vector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

fn fg_quat(q: QuatMsg) -> foxglove::messages::Quaternion {
    foxglove::messages::Quaternion {
        x: q.x,
        y: q.y,
        z: q.z,
        w: q.w,
    }
}

fn fg_color(c: ColorMsg) -> foxglove::messages::Color {
    foxglove::messages::Color {
        r: c.r,
        g: c.g,
        b: c.b,
        a: c.a,
    }
}

fn fg_pose(p: PoseMsg) -> foxglove::messages::Pose {
    foxglove::messages::Pose {
        position: Some(fg_vec(p.position)),
        orientation: Some(fg_quat(p.orientation)),
    }
}

/// `foxglove.FrameTransform` of a transform.
fn fg_transform(m: FrameTransformMsg) -> foxglove::messages::FrameTransform {
    foxglove::messages::FrameTransform {
        timestamp: Some(fg_time(m.timestamp)),
        parent_frame_id: m.parent_frame_id,
        child_frame_id: m.child_frame_id,
        translation: Some(fg_vec(m.translation)),
        rotation: Some(fg_quat(m.rotation)),
    }
}

/// `foxglove.LocationFix` of a location.
fn fg_location(m: LocationFixMsg) -> foxglove::messages::LocationFix {
    foxglove::messages::LocationFix {
        timestamp: Some(fg_time(m.timestamp)),
        frame_id: m.frame_id,
        latitude: m.latitude,
        longitude: m.longitude,
        altitude: m.altitude,
        position_covariance: m.position_covariance.to_vec(),
        position_covariance_type: i32::from(m.position_covariance_type),
        color: Some(fg_color(m.color)),
        ..Default::default()
    }
}

/// `foxglove.SceneUpdate` of a scene.
fn fg_scene(m: SceneUpdateMsg) -> foxglove::messages::SceneUpdate {
    use foxglove::messages::{ArrowPrimitive, CubePrimitive, SceneEntity};
    foxglove::messages::SceneUpdate {
        deletions: Vec::new(),
        entities: m
            .entities
            .into_iter()
            .map(|e| SceneEntity {
                timestamp: Some(fg_time(e.timestamp)),
                frame_id: e.frame_id,
                id: e.id,
                lifetime: Some(foxglove::messages::Duration::new(
                    e.lifetime.sec,
                    e.lifetime.nsec,
                )),
                frame_locked: e.frame_locked,
                arrows: e
                    .arrows
                    .into_iter()
                    .map(|a| ArrowPrimitive {
                        pose: Some(fg_pose(a.pose)),
                        shaft_length: a.shaft_length,
                        shaft_diameter: a.shaft_diameter,
                        head_length: a.head_length,
                        head_diameter: a.head_diameter,
                        color: Some(fg_color(a.color)),
                    })
                    .collect(),
                cubes: e
                    .cubes
                    .into_iter()
                    .map(|c| CubePrimitive {
                        pose: Some(fg_pose(c.pose)),
                        size: Some(fg_vec(c.size)),
                        color: Some(fg_color(c.color)),
                    })
                    .collect(),
                ..SceneEntity::default()
            })
            .collect(),
    }
}

impl EventEncoder {
    /// An encoder for a run that started `base_ns` after the Unix epoch.
    pub fn new(base_ns: u64) -> EventEncoder {
        EventEncoder {
            base_ns,
            trains: Vec::new(),
            icd: twin_core::icd::IcdMap::defaults(),
            buf: Vec::with_capacity(1024),
            key: String::new(),
            csp: CspPacketMsg::default(),
            spare_fields: Vec::new(),
            path: String::new(),
            ecef: EcefFromEci::default(),
            spare_trains: Vec::new(),
            pc_runs: BTreeMap::new(),
            rules: Vec::new(),
            left_out: Vec::new(),
            any_left_out: false,
            train_left_out: Vec::new(),
        }
    }

    /// Leave unencoded what `rules` leave out of the recording ([`twin_scenario::channels`]).
    pub fn set_rules(&mut self, rules: Vec<twin_scenario::channels::ChannelRule>) {
        self.any_left_out = rules.iter().any(|r| r.action == ChannelAction::Omit);
        self.rules = rules;
        self.left_out.clear();
        self.train_left_out = self
            .trains
            .iter()
            .map(|(bus, _)| {
                twin_scenario::channels::action(&self.rules, &ChannelKind::Can.topic(bus))
                    == ChannelAction::Omit
            })
            .collect();
    }

    /// Whether the rules leave the channel of `kind` for `key` out whole.
    fn leaves_out(&mut self, kind: ChannelKind, key: &str) -> bool {
        if !self.any_left_out {
            return false;
        }
        if let Some(&(_, _, out)) = self
            .left_out
            .iter()
            .find(|(k, name, _)| *k == kind && **name == *key)
        {
            return out;
        }
        let out =
            twin_scenario::channels::action(&self.rules, &kind.topic(key)) == ChannelAction::Omit;
        self.left_out.push((kind, key.into(), out));
        out
    }

    /// Decode `/csp/packets` with the ICD on these ports (the run's; default: the ICD's
    /// default ports).
    pub fn set_icd(&mut self, icd: twin_core::icd::IcdMap) {
        self.icd = icd;
    }

    /// The run's start, in ns since the Unix epoch.
    pub fn base_ns(&self) -> u64 {
        self.base_ns
    }

    /// The log time of the first frame of the earliest CAN frame train still being
    /// gathered: every message handed out from now on has that log time or a later one
    /// (events come in time order).
    pub fn open_since(&self) -> Option<u64> {
        self.trains
            .iter()
            .filter_map(|(_, t)| t.as_ref())
            .map(|t| self.base_ns.saturating_add(t.t0.as_ns()))
            .min()
    }

    /// Hand out the CAN frame trains still being gathered (at the end of a run, before
    /// the file is closed), bus by bus.
    pub fn finish(&mut self, emit: &mut Emit<'_>) -> anyhow::Result<()> {
        for i in 0..self.trains.len() {
            self.flush_train(i, emit)?;
        }
        Ok(())
    }

    /// Emit the train of bus number `i`, if there is one.
    fn flush_train(&mut self, i: usize, emit: &mut Emit<'_>) -> anyhow::Result<()> {
        let (bus, train) = &mut self.trains[i];
        let Some(mut train) = train.take() else {
            return Ok(());
        };
        train.msg.data = bytes::Bytes::copy_from_slice(&train.data);
        let chan = (ChannelKind::Can, &**bus);
        let sent = emit_msg(
            &mut self.buf,
            self.base_ns,
            chan,
            train.t0,
            &train.msg,
            emit,
        );
        // Its vectors serve the next train (one spare per bus at most).
        for v in [
            &mut train.msg.can_id,
            &mut train.msg.end_ns,
            &mut train.msg.dropped,
        ] {
            v.clear();
        }
        train.msg.dlc.clear();
        train.data.clear();
        self.spare_trains.push(train);
        sent
    }

    /// Add a frame to its bus's train: the same sender within [`TRAIN_MAX_FRAMES`] and
    /// [`TRAIN_MAX_SPAN_NS`] continues it, anything else hands the train out and starts one.
    fn add_frame(
        &mut self,
        m: &TraceEvent,
        f: &CanFrame,
        emit: &mut Emit<'_>,
    ) -> anyhow::Result<()> {
        let i = match self
            .trains
            .iter()
            .position(|(b, _)| Arc::ptr_eq(b, &m.medium) || *b == m.medium)
        {
            Some(i) => i,
            None => {
                self.trains.push((m.medium.clone(), None));
                let out = self.leaves_out(ChannelKind::Can, &m.medium);
                self.train_left_out.push(out);
                self.trains.len() - 1
            }
        };
        // A bus the rules leave out: no train is gathered (looked up once per bus).
        if self.train_left_out.get(i).copied().unwrap_or(false) {
            return Ok(());
        }
        let continues = self.trains[i].1.as_ref().is_some_and(|tr| {
            tr.from
                .as_ref()
                .is_some_and(|f| Arc::ptr_eq(f, &m.from) || *f == m.from)
                && tr.msg.can_id.len() < TRAIN_MAX_FRAMES
                && m.t.as_ns().saturating_sub(tr.t0.as_ns()) < TRAIN_MAX_SPAN_NS
        });
        if !continues {
            self.flush_train(i, emit)?;
            let mut train = self.spare_trains.pop().unwrap_or_default();
            train.t0 = m.t;
            train.msg.t_ns = m.t.as_ns();
            set_str(&mut train.msg.from, &m.from);
            train.from = Some(m.from.clone());
            self.trains[i].1 = Some(train);
        }
        if let Some(tr) = self.trains[i].1.as_mut() {
            if m.dropped {
                tr.msg.dropped.push(tr.msg.can_id.len() as u32);
            }
            tr.msg.can_id.push(f.id);
            tr.msg.dlc.push(f.dlc);
            let dt = m.t.as_ns().saturating_sub(tr.t0.as_ns());
            tr.msg.end_ns.push(u32::try_from(dt).unwrap_or(u32::MAX));
            tr.data.extend_from_slice(f.data());
        }
        Ok(())
    }

    /// Encode one event, handing each message to `emit` in order; stops at `emit`'s first
    /// error.
    pub fn encode(&mut self, ev: &RunEvent, emit: &mut Emit<'_>) -> anyhow::Result<()> {
        let t_ns = ev.t().as_ns();
        // A train is handed out at the latest [`TRAIN_MAX_SPAN_NS`] after it began, by the
        // first event after that (the live view shows it then, an idle bus does not hold it).
        for i in 0..self.trains.len() {
            let stale = self.trains[i]
                .1
                .as_ref()
                .is_some_and(|tr| t_ns.saturating_sub(tr.t0.as_ns()) >= TRAIN_MAX_SPAN_NS);
            if stale {
                self.flush_train(i, emit)?;
            }
        }
        let base_ns = self.base_ns;
        let buf = &mut self.buf;
        match ev {
            RunEvent::Medium(m) => self.encode_medium(m, emit),
            RunEvent::Packet(p) => self.encode_csp(p, emit),
            // Recorded as the log line it is.
            RunEvent::PacketDropped { log, .. } => self.encode(log, emit),
            RunEvent::Kiss {
                t,
                link,
                dir,
                bytes,
            } => self.encode_kiss(*t, link, *dir, bytes, emit),
            RunEvent::Log {
                t,
                source,
                level,
                message,
            } => {
                let msg = foxglove::messages::Log {
                    timestamp: Some(fg_time(foxglove_time(base_ns, *t))),
                    level: *level as i32,
                    message: message.clone(),
                    name: source.clone(),
                    file: String::new(),
                    line: 0,
                };
                emit_msg(buf, base_ns, (ChannelKind::Log, ""), *t, &msg, emit)
            }
            RunEvent::Fault { t, what } => {
                let msg = FaultMsg {
                    t_ns,
                    what: what.clone(),
                };
                emit_msg(buf, base_ns, (ChannelKind::Fault, ""), *t, &msg, emit)
            }
            RunEvent::Control {
                t,
                conn,
                request,
                reply,
            } => {
                let msg = ControlMsg {
                    t_ns,
                    conn: *conn,
                    request: request.clone(),
                    reply: reply.clone(),
                };
                emit_msg(buf, base_ns, (ChannelKind::Control, ""), *t, &msg, emit)
            }
            RunEvent::Command {
                t,
                name,
                dst,
                dport,
                data,
                ..
            } => {
                let msg = command_sent_msg(t_ns, name, *dst, *dport, data);
                emit_msg(buf, base_ns, (ChannelKind::Command, ""), *t, &msg, emit)
            }
            RunEvent::CommandResult(r) => {
                let msg = command_result_msg(t_ns, &r.name, r.reply.as_deref(), r.rtt_ns);
                emit_msg(buf, base_ns, (ChannelKind::Command, ""), r.t, &msg, emit)
            }
            RunEvent::Expectation {
                t,
                name,
                passed,
                observed,
            } => {
                let msg = ExpectationMsg {
                    t_ns,
                    name: name.clone(),
                    passed: *passed,
                    observed: observed.clone(),
                };
                emit_msg(buf, base_ns, (ChannelKind::Expectation, ""), *t, &msg, emit)
            }
            RunEvent::Truth { t, truth, adcs } => self.encode_truth(*t, truth, adcs, emit),
            RunEvent::Pc(o) => self.encode_pc(ev.t(), o, emit),
            RunEvent::Beacon { t, from, data } => {
                let msg = BeaconMsg {
                    t_ns,
                    from: *from,
                    seq: data
                        .get(2..6)
                        .and_then(|b| <[u8; 4]>::try_from(b).ok())
                        .map_or(0, u32::from_le_bytes),
                    data: bytes::Bytes::copy_from_slice(data),
                };
                emit_msg(buf, base_ns, (ChannelKind::Beacon, ""), *t, &msg, emit)
            }
            RunEvent::Eps(o) => self.encode_eps(t_ns, o, emit),
            RunEvent::Payload { addr, out } => self.encode_payload(ev.t(), *addr, out, emit),
        }
    }

    /// One KISS frame on an outside link, on its link's and direction's own channel.
    fn encode_kiss(
        &mut self,
        t: SimTime,
        link: &str,
        dir: Direction,
        bytes: &[u8],
        emit: &mut Emit<'_>,
    ) -> anyhow::Result<()> {
        let d = match dir {
            Direction::In => "in",
            Direction::Out => "out",
        };
        self.key.clear();
        self.key.push_str(link);
        self.key.push('/');
        self.key.push_str(d);
        let msg = KissFrameMsg {
            t_ns: t.as_ns(),
            link: link.to_owned(),
            dir: d.to_owned(),
            bytes: bytes::Bytes::copy_from_slice(bytes),
            len: bytes.len() as u32,
        };
        emit_msg(
            &mut self.buf,
            self.base_ns,
            (ChannelKind::Kiss, &self.key),
            t,
            &msg,
            emit,
        )
    }

    /// What the payload controller did at `t`: a downlink, the final accounting (one
    /// message per session) or a session's event.
    fn encode_pc(
        &mut self,
        t: SimTime,
        o: &nodes_pc::PcOutput,
        emit: &mut Emit<'_>,
    ) -> anyhow::Result<()> {
        use nodes_pc::PcOutput as O;
        let summary = self.pc_run_summary(t, o);
        let t_ns = t.as_ns();
        let base_ns = self.base_ns;
        let buf = &mut self.buf;
        let none = PcSessionMsg {
            t_ns,
            event: String::new(),
            session: None,
            payload: None,
            result: None,
            packets: None,
            reason: None,
            bytes: None,
        };
        let msg = match o {
            O::Downlinked {
                session_id,
                payload_addr,
                bytes,
                ..
            } => {
                let msg = DownlinkMsg {
                    t_ns,
                    session: *session_id,
                    payload: *payload_addr,
                    len: bytes.len() as u32,
                    crc32c: csp::crc32::crc32c(bytes),
                };
                return emit_msg(buf, base_ns, (ChannelKind::Downlink, ""), t, &msg, emit);
            }
            O::Final { accounting, .. } => {
                // One message per session: bytes still held (buffer and queue).
                for x in &accounting.sessions {
                    let msg = PcSessionMsg {
                        event: "final".into(),
                        session: Some(x.session_id),
                        payload: Some(x.payload_addr),
                        bytes: Some(x.bytes.buffered_now + x.bytes.queued_now),
                        ..none.clone()
                    };
                    emit_msg(buf, base_ns, (ChannelKind::PcSession, ""), t, &msg, emit)?;
                }
                return Ok(());
            }
            O::SessionStarted { session_id, .. } => PcSessionMsg {
                event: "started".into(),
                session: Some(*session_id),
                ..none
            },
            O::SessionEnded {
                session_id,
                result,
                packets,
                ..
            } => PcSessionMsg {
                event: "ended".into(),
                session: Some(*session_id),
                result: Some(twin_scenario::pc::result_name(result.to_u8()).into()),
                packets: Some(*packets),
                ..none
            },
            // A run lost with the PC's memory: ended, with no ICD result.
            O::SessionLost {
                session_id,
                cause,
                packets,
                ..
            } => PcSessionMsg {
                event: "ended".into(),
                session: Some(*session_id),
                result: Some("lost".into()),
                reason: Some(cause.as_str().into()),
                packets: Some(*packets),
                ..none
            },
            O::Dropped {
                session_id,
                payload_addr,
                reason,
                bytes,
                ..
            } => PcSessionMsg {
                event: "dropped".into(),
                session: *session_id,
                payload: Some(*payload_addr),
                reason: Some(reason.as_str().into()),
                bytes: Some(*bytes),
                ..none
            },
        };
        emit_msg(buf, base_ns, (ChannelKind::PcSession, ""), t, &msg, emit)?;
        // A run's summary follows the `/pc/sessions` message of its end.
        match summary {
            Some(s) => emit_msg(
                buf,
                base_ns,
                (ChannelKind::PcSessionSummary, ""),
                t,
                &s,
                emit,
            ),
            None => Ok(()),
        }
    }

    /// Keep each PC session's open run up to date with `o` (at `t`): a start opens it, a
    /// downlink of the session adds its bytes; an end or a loss closes it, and gives its
    /// `/pc/sessions/summary` message.
    fn pc_run_summary(
        &mut self,
        t: SimTime,
        o: &nodes_pc::PcOutput,
    ) -> Option<PcSessionSummaryMsg> {
        use nodes_pc::PcOutput as O;
        let (session, result, cause, packets) = match o {
            O::SessionStarted { session_id, .. } => {
                let run = PcRunTally {
                    started: Some(t),
                    downlinked_bytes: 0,
                };
                self.pc_runs.insert(*session_id, run);
                return None;
            }
            O::Downlinked {
                session_id, bytes, ..
            } => {
                // Bytes that arrive between runs (the queue draining after an end) belong to
                // no open run: the ended run's summary is already written.
                if let Some(run) = self.pc_runs.get_mut(session_id) {
                    run.downlinked_bytes += bytes.len() as u64;
                }
                return None;
            }
            O::SessionEnded {
                session_id,
                result,
                packets,
                ..
            } => (
                *session_id,
                twin_scenario::pc::result_name(result.to_u8()),
                None,
                *packets,
            ),
            O::SessionLost {
                session_id,
                cause,
                packets,
                ..
            } => (*session_id, "lost", Some(cause.as_str()), *packets),
            O::Dropped { .. } | O::Final { .. } => return None,
        };
        let run = self.pc_runs.remove(&session).unwrap_or_default();
        Some(PcSessionSummaryMsg {
            t_ns: t.as_ns(),
            session,
            payload: self.icd.pc_session_payload(session),
            result: result.to_owned(),
            cause: cause.map(str::to_owned),
            packets,
            downlinked_bytes: run.downlinked_bytes,
            start_ns: run.started.map(SimTime::as_ns),
        })
    }

    /// What the EPS did: a power sample or a channel switched (`t_ns` the event's time).
    fn encode_eps(
        &mut self,
        t_ns: u64,
        o: &nodes_eps::EpsOutput,
        emit: &mut Emit<'_>,
    ) -> anyhow::Result<()> {
        let base_ns = self.base_ns;
        let buf = &mut self.buf;
        match o {
            nodes_eps::EpsOutput::Sample {
                t,
                soc,
                battery_v,
                battery_a,
                solar_w,
                load_w,
                panels_w,
                channels,
            } => {
                let msg = EpsPowerMsg {
                    t_ns,
                    soc: *soc as f32,
                    battery_v: *battery_v as f32,
                    battery_a: *battery_a as f32,
                    solar_w: *solar_w as f32,
                    load_w: *load_w as f32,
                    panels_w: panels_w.iter().map(|&w| w as f32).collect(),
                    channels: *channels,
                };
                emit_msg(buf, base_ns, (ChannelKind::EpsPower, ""), *t, &msg, emit)
            }
            nodes_eps::EpsOutput::Channel {
                t,
                channel,
                on,
                cause,
            } => {
                let cause = match cause {
                    nodes_eps::SwitchCause::Initial => "initial",
                    nodes_eps::SwitchCause::Command => "command",
                    nodes_eps::SwitchCause::Timeline => "timeline",
                    nodes_eps::SwitchCause::Shed(_) => "shed",
                    nodes_eps::SwitchCause::Restore(_) => "restore",
                };
                let msg = EpsChannelMsg {
                    t_ns,
                    channel: channel.name().to_owned(),
                    on: *on,
                    cause: cause.to_owned(),
                };
                emit_msg(buf, base_ns, (ChannelKind::EpsChannel, ""), *t, &msg, emit)
            }
        }
    }

    /// What the simulated payload at `addr` did at `t`: bytes produced or a SYNC received.
    fn encode_payload(
        &mut self,
        t: SimTime,
        addr: u8,
        out: &nodes_payload::PayloadOutput,
        emit: &mut Emit<'_>,
    ) -> anyhow::Result<()> {
        use nodes_payload::PayloadOutput as O;
        let t_ns = t.as_ns();
        let msg = match out {
            O::Produced { bytes, how, .. } => PayloadMsg {
                t_ns,
                addr,
                event: "produced".into(),
                bytes: Some(*bytes),
                how: Some(
                    match how {
                        nodes_payload::How::PollReply => "poll-reply",
                        nodes_payload::How::Push => "push",
                    }
                    .into(),
                ),
                msg: None,
            },
            O::SyncReceived { msg, .. } => PayloadMsg {
                t_ns,
                addr,
                event: "sync".into(),
                bytes: None,
                how: None,
                msg: Some(bytes::Bytes::copy_from_slice(msg)),
            },
        };
        emit_msg(
            &mut self.buf,
            self.base_ns,
            (ChannelKind::Payload, ""),
            t,
            &msg,
            emit,
        )
    }

    /// The `/fc/...` messages of one truth sample (see the module docs for what is left out
    /// when a number is not finite).
    fn encode_truth(
        &mut self,
        t: SimTime,
        truth: &TruthSnapshot,
        adcs: &AdcsSnapshot,
        emit: &mut Emit<'_>,
    ) -> anyhow::Result<()> {
        use ChannelKind::{Adcs, EstimateTf, Scene, TruthLocation, TruthState, TruthTf};
        let [tf, est, loc, st, ad, sc] =
            [TruthTf, EstimateTf, TruthLocation, TruthState, Adcs, Scene]
                .map(|k| !self.leaves_out(k, ""));
        let base_ns = self.base_ns;
        let buf = &mut self.buf;
        let stamp = foxglove_time(base_ns, t);
        let q = &truth.q_eci_from_body;
        if let Some(rotation) = quat_xyzw([q.w, q.i, q.j, q.k]).filter(|_| tf) {
            let msg = fg_transform(frame_transform(stamp, FRAME_BODY, rotation));
            emit_msg(buf, base_ns, (TruthTf, ""), t, &msg, emit)?;
        }
        let q_est = adcs.q_eci_from_body_est.as_ref().filter(|_| est);
        if let Some(rotation) = q_est.and_then(|q| quat_xyzw([q.w, q.i, q.j, q.k])) {
            let msg = fg_transform(frame_transform(stamp, FRAME_BODY_EST, rotation));
            emit_msg(buf, base_ns, (EstimateTf, ""), t, &msg, emit)?;
        }
        if loc || st {
            let state = truth_state(t.as_ns(), truth, &mut self.ecef);
            if let Some(msg) = location_fix(stamp, &state).map(fg_location).filter(|_| loc) {
                emit_msg(buf, base_ns, (TruthLocation, ""), t, &msg, emit)?;
            }
            if st {
                emit_msg(buf, base_ns, (TruthState, ""), t, &state, emit)?;
            }
        }
        if ad {
            let msg = adcs_msg(t.as_ns(), adcs);
            emit_msg(buf, base_ns, (Adcs, ""), t, &msg, emit)?;
        }
        if sc {
            let msg = fg_scene(scene_update(stamp, truth));
            emit_msg(buf, base_ns, (Scene, ""), t, &msg, emit)?;
        }
        Ok(())
    }

    /// A frame or packet (the CSP packet it completes comes as its own event after it).
    fn encode_medium(&mut self, m: &TraceEvent, emit: &mut Emit<'_>) -> anyhow::Result<()> {
        let t_ns = m.t.as_ns();
        match &m.frame {
            TraceFrame::Can(f) | TraceFrame::CanUnreceived(f, _) => self.add_frame(m, f, emit),
            TraceFrame::Packet(_) if self.leaves_out(ChannelKind::Net, &m.medium) => Ok(()),
            // Never on the wire: counted by the bus (`tx_overflow`, `bus_off_drops`,
            // `off_drops`), not a frame of `/can/<bus>/frames`.
            TraceFrame::CanLost(..) => Ok(()),
            TraceFrame::CanError(e) => {
                let (event, can_id) = match &e.kind {
                    bus::can::CanErrorKind::ErrorFrame { can_id } => ("error-frame", Some(*can_id)),
                    bus::can::CanErrorKind::State(s) => (s.name(), None),
                };
                let msg = CanErrorMsg {
                    t_ns,
                    node: e.node.to_string(),
                    event: event.to_owned(),
                    can_id,
                    tec: e.tec,
                    rec: e.rec,
                };
                let chan = (ChannelKind::CanError, &*m.medium);
                emit_msg(&mut self.buf, self.base_ns, chan, m.t, &msg, emit)
            }
            TraceFrame::Packet(bytes) => {
                let h = Header::parse(bytes).ok();
                let msg = NetPacketMsg {
                    t_ns,
                    from: m.from.to_string(),
                    bytes: bytes::Bytes::copy_from_slice(bytes),
                    dropped: m.dropped,
                    len: bytes.len() as u32,
                    prio: h.map(|h| h.prio as u8),
                    src: h.map(|h| h.src),
                    dst: h.map(|h| h.dst),
                    dport: h.map(|h| h.dport),
                    sport: h.map(|h| h.sport),
                    flags: h.map(|h| h.flags),
                };
                let chan = (ChannelKind::Net, &*m.medium);
                emit_msg(&mut self.buf, self.base_ns, chan, m.t, &msg, emit)
            }
        }
    }

    /// The `/csp/packets` message of a packet a medium delivered.
    fn encode_csp(&mut self, seen: &SeenPacket, emit: &mut Emit<'_>) -> anyhow::Result<()> {
        if self.leaves_out(ChannelKind::Csp, "") {
            return Ok(());
        }
        let (m, p) = (seen, &seen.packet);
        let h = &p.header;
        let body = if h.has_crc() && p.data.len() >= 4 {
            &p.data[..p.data.len() - 4]
        } else {
            &p.data[..]
        };
        let c = self.icd.classify(h, body);
        // The message of the last packet is reused, its strings and fields with it: a packet
        // costs one allocation (its bytes), and one more for a text or a bit-mask field.
        let msg = &mut self.csp;
        msg.t_ns = m.t.as_ns();
        set_str(&mut msg.medium, &m.medium);
        set_str(&mut msg.from, &m.from);
        msg.prio = h.prio as u8;
        msg.src = h.src;
        msg.dst = h.dst;
        msg.dport = h.dport;
        msg.sport = h.sport;
        msg.flags = h.flags;
        msg.data = bytes::Bytes::copy_from_slice(&p.data);
        msg.len = p.data.len() as u32;
        set_opt_str(&mut msg.service, packet_service(h).map(|s| [s]));
        set_opt_str(
            &mut msg.icd,
            c.as_ref().map(|c| [c.node, ".", c.command.name]),
        );
        set_opt_str(
            &mut msg.icd_kind,
            c.as_ref().map(|c| {
                [match (c.direction, c.result) {
                    (twin_core::icd::Direction::Request, _) => "request",
                    (_, Some(csp::reqrep::RESULT_SUCCESS)) => "reply",
                    _ => "failure",
                }]
            }),
        );
        let spare = &mut self.spare_fields;
        spare.append(&mut msg.fields);
        if let Some(split) = c
            .as_ref()
            .and_then(|c| c.layout().and_then(|l| l.split(c.body)))
        {
            let out = &mut msg.fields;
            let read = csp::icd::decode_each(
                split.fields,
                split.head,
                &mut self.path,
                &mut |path, v, f| {
                    let mut field = spare.pop().unwrap_or_default();
                    icd_field(&mut field, path, v, f);
                    out.push(field);
                },
            );
            if read.is_err() {
                // Data that does not fit the layout: no fields, as for `IcdMap::decode`.
                spare.append(out);
            }
        }
        let chan = (ChannelKind::Csp, "");
        emit_msg(&mut self.buf, self.base_ns, chan, m.t, &self.csp, emit)
    }
}

/// `s` becomes `v`, in the allocation it has.
fn set_str(s: &mut String, v: &str) {
    s.clear();
    s.push_str(v);
}

/// `s` becomes the parts of `v` one after the other (or `None`), in the allocation it has.
fn set_opt_str<const N: usize>(s: &mut Option<String>, v: Option<[&str; N]>) {
    match v {
        None => *s = None,
        Some(parts) => {
            let s = s.get_or_insert_with(String::new);
            s.clear();
            for p in parts {
                s.push_str(p);
            }
        }
    }
}

/// A decoded ICD field as `/csp/packets` records it, written over `out`.
fn icd_field(
    out: &mut IcdFieldMsg,
    path: &str,
    value: csp::icd::Value,
    field: &'static csp::icd::Field,
) {
    use csp::icd::Value;
    set_str(&mut out.name, path);
    out.value = value.as_f64().unwrap_or(f64::NAN);
    match value {
        Value::Text(s) => out.text = Some(s),
        Value::Int(i) => match field.value_name(i) {
            Some(name) => set_opt_str(&mut out.text, Some([name])),
            None => out.text = Some(field.bit_names(i)).filter(|t| !t.is_empty()),
        },
        Value::Float(_) => out.text = None,
    }
}

/// One registered channel.
#[derive(Debug)]
struct Chan {
    id: u16,
    topic: String,
    /// The bus, network or link name it was registered for (empty for fixed channels).
    key: String,
    kind: ChannelKind,
    seq: u32,
    messages: u64,
    /// What the recording's channel rules do to it ([`twin_scenario::channels`]).
    action: ChannelAction,
    /// The log time of the last message kept, for a thinned channel.
    last_kept: Option<u64>,
}

/// The MCAP side of a [`Recorder`]: the writer and its channels.
/// What a recording may do to a file already at its path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Existing {
    /// Refuse it: the recording is not made, the file untouched (`m6p-twin run`'s default).
    Refuse,
    /// Replace it, once the recording is complete (`--overwrite`; files of the twin's own).
    Replace,
}

/// Where a recording goes: written to a temporary file beside its name (created
/// exclusively, never a name another program can plant a link at) and put in place when
/// complete, so that a file at the name is never half-written, mixed with another run's or
/// replaced by accident. A run that fails or is killed leaves its temporary file, with
/// what was recorded, and says where. A name that is a device or a FIFO (`/dev/full`, a
/// pipe to a reader) holds no stored recording: it is written directly, never replaced.
#[derive(Debug)]
struct Target {
    /// The temporary file (`.NAME.XXXXXX.partial`, beside the name), or none when the name
    /// is written directly.
    temp: Option<PathBuf>,
    /// The recording's name.
    path: PathBuf,
    existing: Existing,
}

impl Target {
    fn create(path: &Path, existing: Existing) -> anyhow::Result<(File, Target)> {
        if std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir()) {
            let file = std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .with_context(|| format!("opening {}", path.display()))?;
            return Ok((
                file,
                Target {
                    temp: None,
                    path: path.to_owned(),
                    existing,
                },
            ));
        }
        if existing == Existing::Refuse && path.exists() {
            bail!(
                "{} exists: not replaced (--overwrite replaces it once the new recording is complete)",
                path.display()
            );
        }
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let name = path
            .file_name()
            .map_or_else(|| "recording".into(), |n| n.to_string_lossy());
        let temp = tempfile::Builder::new()
            .prefix(&format!(".{name}."))
            .suffix(".partial")
            .tempfile_in(dir)
            .with_context(|| format!("creating a temporary file in {}", dir.display()))?;
        let (file, temp) = temp.into_parts();
        // Never removed by a drop: a run that fails or is killed leaves what it recorded.
        let temp = temp
            .keep()
            .with_context(|| format!("keeping a temporary file in {}", dir.display()))?;
        Ok((
            file,
            Target {
                temp: Some(temp),
                path: path.to_owned(),
                existing,
            },
        ))
    }

    /// The file being written.
    fn written(&self) -> &Path {
        self.temp.as_deref().unwrap_or(&self.path)
    }

    /// Put the complete recording at its name.
    fn place(&self) -> anyhow::Result<()> {
        let path = &self.path;
        let Some(temp) = &self.temp else {
            return Ok(());
        };
        let kept = || format!("this run's recording is in {}", temp.display());
        match self.existing {
            Existing::Replace => std::fs::rename(temp, path)
                .with_context(|| format!("renaming it to {}; {}", path.display(), kept())),
            // A link fails if the name exists (another run took it meanwhile): never
            // replaced, never mixed.
            Existing::Refuse => match std::fs::hard_link(temp, path) {
                Ok(()) => std::fs::remove_file(temp)
                    .with_context(|| format!("removing {}", temp.display())),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => bail!(
                    "{} appeared while this run recorded (another run?): not replaced; {}",
                    path.display(),
                    kept()
                ),
                // A file system without hard links: the name checked, then renamed.
                Err(_) if !path.exists() => std::fs::rename(temp, path)
                    .with_context(|| format!("renaming it to {}; {}", path.display(), kept())),
                Err(e) => Err(e).with_context(|| format!("placing {}; {}", path.display(), kept())),
            },
        }
    }
}

struct McapOut {
    writer: McapFile<BufWriter<File>>,
    path: PathBuf,
    /// Schema id per kind (`kind as usize`), once written.
    schema_ids: Vec<Option<u16>>,
    chans: Vec<Chan>,
    /// Messages not due yet: the file is in log-time order ([`crate::log_order`]).
    order: LogOrder,
    /// The latest log time written.
    written_max: u64,
    /// The rules that choose the channels ([`twin_scenario::channels`]).
    rules: Vec<twin_scenario::channels::ChannelRule>,
}

impl Drop for McapOut {
    /// Dropped unfinished (the run failed), the recording still holds every message handed
    /// to it: the held ones are written before the writer ends the file.
    fn drop(&mut self) {
        let _ = self.release(None);
    }
}

impl McapOut {
    /// Register a channel, and its schema if it is the first of its kind; returns its index
    /// in `chans`.
    fn add_channel(&mut self, kind: ChannelKind, key: &str) -> anyhow::Result<usize> {
        let topic = kind.topic(key);
        let action = twin_scenario::channels::action(&self.rules, &topic);
        // A channel the rules leave out is known, so that its messages are dropped at once,
        // and never in the file.
        let id = match action {
            ChannelAction::Omit => u16::MAX,
            _ => self.write_channel(kind, key, &topic)?,
        };
        self.chans.push(Chan {
            id,
            topic,
            key: key.to_owned(),
            kind,
            seq: 0,
            messages: 0,
            action,
            last_kept: None,
        });
        Ok(self.chans.len() - 1)
    }

    /// Write a channel's record, and its schema's if it is the first of its kind; its id.
    fn write_channel(&mut self, kind: ChannelKind, key: &str, topic: &str) -> anyhow::Result<u16> {
        let schema = match self.schema_ids[kind as usize] {
            Some(id) => id,
            None => {
                // Two kinds with the same schema (the two transforms) share one record: the
                // writer returns the id of identical content.
                let id = self
                    .writer
                    .add_schema(kind.schema_name(), SCHEMA_ENCODING, &kind.schema_data()?)
                    .with_context(|| format!("writing recording {}", self.path.display()))?;
                self.schema_ids[kind as usize] = Some(id);
                id
            }
        };
        self.writer
            .add_channel(schema, topic, MESSAGE_ENCODING, &kind.metadata(key))
            .with_context(|| format!("writing recording {}", self.path.display()))
    }

    /// Take one message, registering its channel if it is the first; it is written when
    /// due ([`McapOut::release`]).
    fn put(&mut self, m: Encoded<'_>) -> anyhow::Result<()> {
        let chan = match self
            .chans
            .iter()
            .position(|c| c.kind == m.kind && c.key == m.key)
        {
            Some(i) => i,
            None => self.add_channel(m.kind, m.key)?,
        };
        let c = &mut self.chans[chan];
        match c.action {
            ChannelAction::Keep => {}
            ChannelAction::Omit => return Ok(()),
            ChannelAction::Every(period) => {
                let period = u64::try_from(period.as_nanos()).unwrap_or(u64::MAX);
                if c.last_kept
                    .is_some_and(|last| m.log_time < last.saturating_add(period))
                {
                    return Ok(());
                }
                c.last_kept = Some(m.log_time);
            }
        }
        self.order.hold(chan, m.log_time, m.data);
        Ok(())
    }

    /// Write the messages taken that are earlier than `due_before` (all for `None`), in
    /// log-time order.
    fn release(&mut self, due_before: Option<u64>) -> anyhow::Result<()> {
        let McapOut {
            writer,
            path,
            chans,
            order,
            written_max,
            ..
        } = self;
        order.release(due_before, |chan, at, data| {
            let c = &mut chans[chan];
            let (id, seq) = (c.id, c.seq);
            c.seq = c.seq.wrapping_add(1);
            c.messages += 1;
            // A message handed out after later ones were written (an expectation's
            // verdict, given at the end of the run for the instant it was decided) is
            // logged when it is written; its publish time keeps its own instant.
            let log_time = at.max(*written_max);
            *written_max = log_time;
            writer
                .message(id, seq, log_time, at, data)
                .with_context(|| format!("writing recording {}", path.display()))
        })
    }
}

/// Writes a run's events to an MCAP file (see the module docs for the layout).
pub struct Recorder {
    out: McapOut,
    enc: EventEncoder,
    target: Target,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.out.path)
            .field("base_ns", &self.enc.base_ns)
            .field("channels", &self.out.chans)
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// Start a recording for `path`: write the header, the run's metadata and the scenario
    /// attachment to a temporary file beside it, and register the fixed channels (with
    /// their schemas). A file already at `path` is refused or replaced (when the recording
    /// is complete: [`Recorder::finish`]) as `existing` says.
    pub fn create(
        path: &Path,
        meta: RecordingMeta,
        existing: Existing,
    ) -> anyhow::Result<Recorder> {
        let base_ns = start_ns(&meta.start_utc)?;
        let (file, target) = Target::create(path, existing)?;
        let ctx = || format!("writing recording {}", path.display());
        let mut writer = McapFile::new(
            BufWriter::with_capacity(256 * 1024, file),
            "",
            &format!("m6p-twin {}", meta.twin_version),
            CHUNK_SIZE as usize,
            ZSTD_LEVEL,
        )
        .with_context(ctx)?;

        let metadata: BTreeMap<String, String> = [
            ("format", FORMAT_VERSION.to_owned()),
            ("scenario_name", meta.scenario_name.clone()),
            ("seed", meta.seed.to_string()),
            ("start_utc", meta.start_utc.clone()),
            ("twin_version", meta.twin_version.clone()),
            ("scenario_attachment", SCENARIO_ATTACHMENT.to_owned()),
            ("chunk_size", CHUNK_SIZE.to_string()),
            ("zstd_level", ZSTD_LEVEL.to_string()),
            (
                "duration_ns",
                meta.duration_ns.map_or(String::new(), |d| d.to_string()),
            ),
            (
                "replaced",
                meta.replaced
                    .iter()
                    .map(u8::to_string)
                    .collect::<Vec<_>>()
                    .join(","),
            ),
            ("link_addrs", format_link_addrs(&meta.link_addrs)),
            (
                "link_tx_budgets",
                format_link_budgets(&meta.link_tx_budgets),
            ),
        ]
        .into_iter()
        // Only a recording that chose its channels says so (the others' bytes stay).
        .chain((!meta.channels.is_empty()).then(|| {
            (
                "channels",
                twin_scenario::channels::format_rules(&meta.channels),
            )
        }))
        .map(|(k, v)| (k.to_owned(), v))
        .collect();
        writer
            .metadata(METADATA_NAME, &metadata)
            .with_context(ctx)?;
        writer
            .attach(
                base_ns,
                base_ns,
                SCENARIO_ATTACHMENT,
                "application/toml",
                meta.scenario_toml.as_bytes(),
            )
            .with_context(ctx)?;

        let mut out = McapOut {
            writer,
            path: path.to_owned(),
            schema_ids: vec![None; CHANNEL_KINDS.len()],
            chans: Vec::new(),
            order: LogOrder::default(),
            written_max: 0,
            rules: meta.channels,
        };
        for (kind, key) in FIXED_CHANNELS {
            out.add_channel(kind, key)?;
        }
        let mut enc = EventEncoder::new(base_ns);
        enc.set_rules(out.rules.clone());
        Ok(Recorder { out, enc, target })
    }

    /// The temporary file the recording is written to until it is complete (the name
    /// itself when that is a device or a FIFO).
    pub fn partial_path(&self) -> &Path {
        self.target.written()
    }

    /// Bytes written so far.
    pub fn position(&self) -> u64 {
        self.out.writer.position()
    }

    /// Decode `/csp/packets` with the ICD on the run's ports.
    pub fn set_icd(&mut self, icd: twin_core::icd::IcdMap) {
        self.enc.set_icd(icd);
    }

    /// Record one event.
    pub fn write(&mut self, ev: &RunEvent) -> anyhow::Result<()> {
        let out = &mut self.out;
        self.enc.encode(ev, &mut |m| out.put(m))?;
        if out.order.len() > HOLD_MAX {
            // Bounded whatever the events: the trains close early, and all is due.
            self.enc.finish(&mut |m| out.put(m))?;
            return out.release(None);
        }
        let now = self.enc.base_ns().saturating_add(ev.t().as_ns());
        let horizon = now.saturating_sub(REORDER_WINDOW_NS);
        out.release(Some(
            self.enc.open_since().map_or(horizon, |t| t.min(horizon)),
        ))
    }

    /// Close the current chunk and flush it to the file, so a run killed after this loses
    /// nothing written before it (costs compression ratio if called often).
    pub fn flush(&mut self) -> anyhow::Result<()> {
        // What is held goes too (on the wall clock, the reorder window would be a minute of
        // it), but for the open trains' span: a message later than this flush is written
        // at the latest log time written.
        self.out.release(self.enc.open_since())?;
        self.out
            .writer
            .flush()
            .with_context(|| format!("flushing recording {}", self.out.path.display()))
    }

    /// Write the last chunk and the summary (indexes, statistics) and close the file.
    pub fn finish(mut self) -> anyhow::Result<RecordingStats> {
        {
            let out = &mut self.out;
            self.enc.finish(&mut |m| out.put(m))?;
            out.release(None)?;
        }
        let Recorder {
            mut out,
            enc: _,
            target,
        } = self;
        let ctx = || format!("finishing recording {}", out.path.display());
        let written = out.writer.finish().with_context(ctx)?;
        let chans = std::mem::take(&mut out.chans);
        // Closes the file (the writer is finished: its drop writes nothing more).
        drop(out);
        target.place()?;
        let (bytes, chunks) = (written.bytes, written.chunks);
        let channels: Vec<ChannelStats> = chans
            .into_iter()
            // Those left out are not in the file.
            .filter(|c| c.action != ChannelAction::Omit)
            .map(|c| ChannelStats {
                topic: c.topic,
                messages: c.messages,
            })
            .collect();
        Ok(RecordingStats {
            messages: channels.iter().map(|c| c.messages).sum(),
            channels,
            chunks,
            bytes,
        })
    }
}

mod state;

/// Events handed to a [`RecorderThread`] at once.
const RECORDER_BATCH: usize = 512;

/// Batches a [`RecorderThread`] holds queued before the run waits for it.
const RECORDER_QUEUE_BATCHES: usize = 4;

/// What the run sends its recorder's thread.
enum ToRecorder {
    Events(Vec<RunEvent>),
    /// Close the open chunk and flush the file (a run on the wall clock, once a second).
    Flush,
    /// The run ended: finish the file.
    Finish,
    /// Answer with the recorder's state after the events sent before (none: the
    /// recording stopped).
    Snapshot(std::sync::mpsc::SyncSender<Option<Vec<u8>>>),
    /// Carry the snapshot file taken at this instant.
    Attach(SimTime, Vec<u8>),
}

/// A [`Recorder`] on a thread of its own: the run hands it copies of its events in
/// batches, in order, and goes on (the same calls of [`Recorder::write`] in the same order:
/// the same bytes). The queue is bounded ([`RECORDER_QUEUE_BATCHES`] batches of
/// [`RECORDER_BATCH`]): a run faster than its recording waits for it, and nothing is dropped.
/// A write error stops the recording (the file ends after its last complete chunk) and is
/// reported by [`RecorderThread::finish`]; dropping it unfinished (the run failed) drops the
/// recorder there, which ends the file with its summary as [`Recorder`]'s drop does.
#[derive(Debug)]
pub struct RecorderThread {
    tx: Option<std::sync::mpsc::SyncSender<ToRecorder>>,
    batch: Vec<RunEvent>,
    thread: Option<std::thread::JoinHandle<anyhow::Result<Option<RecordingStats>>>>,
    /// How often the file is flushed (its open chunk closed), on the wall clock, and when
    /// it last was.
    flush: Option<(std::time::Duration, std::time::Instant)>,
}

impl RecorderThread {
    /// Start `recorder`'s thread.
    pub fn start(recorder: Recorder) -> anyhow::Result<RecorderThread> {
        Self::start_flushing(recorder, None)
    }

    /// Start `recorder`'s thread, closing its open chunk and flushing the file at least
    /// every `every` of wall-clock time (a run on the wall clock: a process killed loses at
    /// most that much). A write error stops the recording at once, with a warning naming the
    /// byte and the temporary file holding what was recorded; the run goes on.
    pub fn start_flushing(
        recorder: Recorder,
        every: Option<std::time::Duration>,
    ) -> anyhow::Result<RecorderThread> {
        let path = recorder.out.path.clone();
        let partial = recorder.partial_path().to_owned();
        let (tx, rx) = std::sync::mpsc::sync_channel::<ToRecorder>(RECORDER_QUEUE_BATCHES);
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                let mut recorder = Some(recorder);
                let mut failure = None;
                while let Ok(msg) = rx.recv() {
                    match msg {
                        ToRecorder::Events(batch) => {
                            for ev in &batch {
                                if let Some(r) = recorder.as_mut()
                                    && let Err(e) = r.write(ev)
                                {
                                    stopped(&path, &partial, r.position(), &e);
                                    failure = Some(e);
                                    recorder = None;
                                }
                            }
                        }
                        ToRecorder::Flush => {
                            if let Some(r) = recorder.as_mut()
                                && let Err(e) = r.flush()
                            {
                                stopped(&path, &partial, r.position(), &e);
                                failure = Some(e);
                                recorder = None;
                            }
                        }
                        ToRecorder::Snapshot(reply) => {
                            let _ = reply.send(recorder.as_ref().map(Recorder::save_state));
                        }
                        ToRecorder::Attach(t, file) => {
                            if let Some(r) = recorder.as_mut()
                                && let Err(e) = r.attach_snapshot(t, &file)
                            {
                                stopped(&path, &partial, r.position(), &e);
                                failure = Some(e);
                                recorder = None;
                            }
                        }
                        ToRecorder::Finish => {
                            if let Some(e) = failure {
                                return Err(
                                    e.context(format!("recording to {} stopped", path.display()))
                                );
                            }
                            return recorder
                                .map(|r| {
                                    let at = r.position();
                                    r.finish()
                                        .with_context(|| format!("finishing {}", path.display()))
                                        .inspect_err(|e| stopped(&path, &partial, at, e))
                                })
                                .transpose();
                        }
                    }
                }
                Ok(None)
            })
            .context("starting the recorder's thread")?;
        Ok(RecorderThread {
            tx: Some(tx),
            batch: Vec::with_capacity(RECORDER_BATCH),
            thread: Some(thread),
            flush: every.map(|d| (d, std::time::Instant::now())),
        })
    }

    /// Record a copy of `ev` (sent with the next full batch, or with a flush when one is due).
    pub fn write(&mut self, ev: &RunEvent) {
        self.batch.push(ev.clone());
        if self.batch.len() >= RECORDER_BATCH {
            self.send_batch();
        }
        if let Some((every, last)) = &mut self.flush
            && last.elapsed() >= *every
        {
            *last = std::time::Instant::now();
            self.send_batch();
            if let Some(tx) = &self.tx {
                let _ = tx.send(ToRecorder::Flush);
            }
        }
    }

    /// The recorder's state after every event written so far (for a snapshot; the run
    /// waits for the thread to get there); none when the recording stopped.
    pub fn snapshot(&mut self) -> Option<Vec<u8>> {
        self.send_batch();
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        self.tx.as_ref()?.send(ToRecorder::Snapshot(tx)).ok()?;
        rx.recv().ok().flatten()
    }

    /// Carry the snapshot file taken at `t` in the recording (after the events sent before).
    pub fn attach_snapshot(&mut self, t: SimTime, file: Vec<u8>) {
        self.send_batch();
        if let Some(tx) = &self.tx {
            let _ = tx.send(ToRecorder::Attach(t, file));
        }
    }

    fn send_batch(&mut self) {
        let batch = std::mem::replace(&mut self.batch, Vec::with_capacity(RECORDER_BATCH));
        if let Some(tx) = &self.tx {
            // A closed queue: the thread ended (it panicked); `finish` says so.
            let _ = tx.send(ToRecorder::Events(batch));
        }
    }

    /// Record what is left, finish the file and return its figures (or the first error).
    pub fn finish(mut self) -> anyhow::Result<RecordingStats> {
        self.send_batch();
        if let Some(tx) = self.tx.take() {
            let _ = tx.send(ToRecorder::Finish);
        }
        let thread = self
            .thread
            .take()
            .context("the recorder's thread is gone")?;
        match thread.join() {
            Ok(Ok(Some(stats))) => Ok(stats),
            Ok(Ok(None)) => anyhow::bail!("the recorder's thread ended early"),
            Ok(Err(e)) => Err(e),
            Err(panic) => {
                let why = panic
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_owned())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                anyhow::bail!("the recorder's thread panicked: {why}")
            }
        }
    }
}

impl Drop for RecorderThread {
    fn drop(&mut self) {
        // Unfinished: what was sent is written, then the recorder is dropped there.
        if let Some(tx) = self.tx.take() {
            let batch = std::mem::take(&mut self.batch);
            let _ = tx.send(ToRecorder::Events(batch));
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Say, when it happens, that the recording to `path` stopped at byte `at`, and where what
/// it recorded is.
fn stopped(path: &Path, partial: &Path, at: u64, e: &anyhow::Error) {
    tracing::warn!(
        "recording to {} stopped at byte {at}: {e:#}; the run goes on without it (what was recorded is in {})",
        path.display(),
        partial.display()
    );
}

/// A run's start time `start_utc` (`YYYY-MM-DDTHH:MM:SS[.fff]Z`) in ns since the Unix epoch.
pub fn start_ns(start_utc: &str) -> anyhow::Result<u64> {
    let ns = twin_core::timefmt::parse_utc(start_utc)
        .with_context(|| format!("recording start time {start_utc:?} is not a UTC time"))?;
    u64::try_from(ns).with_context(|| {
        format!("recording start time {start_utc} is before 1970 (MCAP times are unsigned)")
    })
}

/// The `link_addrs` metadata: `LABEL=ID,ID;LABEL=ID` (links without addresses left out).
pub fn format_link_addrs(links: &std::collections::BTreeMap<String, Vec<u8>>) -> String {
    links
        .iter()
        .filter(|(_, a)| !a.is_empty())
        .map(|(l, a)| {
            let ids: Vec<String> = a.iter().map(u8::to_string).collect();
            format!("{l}={}", ids.join(","))
        })
        .collect::<Vec<_>>()
        .join(";")
}

/// Read [`format_link_addrs`]' text; what does not parse is left out.
pub fn parse_link_addrs(text: &str) -> std::collections::BTreeMap<String, Vec<u8>> {
    text.split(';')
        .filter_map(|item| {
            let (label, ids) = item.rsplit_once('=')?;
            let ids: Vec<u8> = ids
                .split(',')
                .filter_map(|a| a.trim().parse().ok())
                .collect();
            Some((label.to_owned(), ids))
        })
        .collect()
}

/// The `link_tx_budgets` metadata: `LABEL=N;LABEL=N`.
pub fn format_link_budgets(links: &std::collections::BTreeMap<String, u32>) -> String {
    links
        .iter()
        .map(|(l, n)| format!("{l}={n}"))
        .collect::<Vec<_>>()
        .join(";")
}

/// Read [`format_link_budgets`]' text; what does not parse is left out.
pub fn parse_link_budgets(text: &str) -> std::collections::BTreeMap<String, u32> {
    text.split(';')
        .filter_map(|item| {
            let (label, n) = item.rsplit_once('=')?;
            Some((label.to_owned(), n.trim().parse().ok()?))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A mask's `text` names its set bits, and is null when none is set (it was ""). The
    /// field is written over the one before it, which leaves nothing of its own behind.
    #[test]
    fn an_icd_mask_field_names_its_bits_or_nothing() {
        use csp::icd::Value;
        const F: csp::icd::Field =
            csp::icd::Field::new("mask", (csp::icd::Ty::U8, 1), "").bits(&[(0, "A"), (1, "B")]);
        const E: csp::icd::Field =
            csp::icd::Field::new("mode", (csp::icd::Ty::U8, 1), "").values(&[(2, "on")]);
        let mut f = IcdFieldMsg::default();
        icd_field(&mut f, "mask", Value::Int(3), &F);
        assert_eq!((f.name.as_str(), f.value), ("mask", 3.0));
        assert_eq!(f.text.as_deref(), Some("A, B"));
        icd_field(&mut f, "mask", Value::Int(0), &F);
        assert_eq!(f.text, None);
        icd_field(&mut f, "mode", Value::Int(2), &E);
        assert_eq!(f.text.as_deref(), Some("on"));
        icd_field(&mut f, "v", Value::Float(0.5), &E);
        assert_eq!(
            (f.name.as_str(), f.value, f.text.as_deref()),
            ("v", 0.5, None)
        );
        icd_field(&mut f, "name", Value::Text("ab".into()), &E);
        assert!(f.value.is_nan());
        assert_eq!(f.text.as_deref(), Some("ab"));
    }

    /// `v` rotated by `q` (`v + 2w (q x v) + 2 q x (q x v)`).
    fn rotate(q: QuatMsg, v: [f64; 3]) -> [f64; 3] {
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let u = [q.x, q.y, q.z];
        let t = cross(u, v).map(|c| 2.0 * c);
        let w = cross(u, t);
        [0, 1, 2].map(|i| v[i] + q.w * t[i] + w[i])
    }

    #[test]
    fn arrow_orientation_turns_x_onto_the_direction() {
        let s = 1.0 / 3f64.sqrt();
        for d in [
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, -1.0],
            [s, -s, s],
            [-0.6, 0.0, 0.8],
            [-1.0, 1e-12, 0.0],
        ] {
            let d = unit(d).unwrap();
            let q = arrow_orientation(d);
            let n = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
            assert!((n - 1.0).abs() < 1e-12, "{d:?}: {q:?}");
            let got = rotate(q, [1.0, 0.0, 0.0]);
            for i in 0..3 {
                assert!((got[i] - d[i]).abs() < 1e-9, "{d:?}: {got:?}");
            }
        }
    }

    #[test]
    fn the_medium_channels_are_what_crossed_a_medium() {
        let medium: Vec<&str> = CHANNEL_KINDS
            .iter()
            .filter(|k| k.is_medium())
            .map(|k| k.schema_name())
            .collect();
        assert_eq!(
            medium,
            [
                "m6p.CanFrames",
                "m6p.NetPacket",
                "m6p.KissFrame",
                "m6p.CanError"
            ]
        );
        assert!(is_medium_schema("m6p.CanError"));
        assert!(
            !is_medium_schema("m6p.CspPacket"),
            "decoded, not on the wire"
        );
        assert!(!is_medium_schema("foxglove.Log"));
    }

    #[test]
    fn every_kind_has_a_protobuf_schema_holding_its_message() {
        for &kind in CHANNEL_KINDS {
            let data: Arc<[u8]> = kind.schema_data().unwrap().into();
            // The named message is in the set (what Foxglove looks the schema name up in).
            let fds = <prost_types::FileDescriptorSet as prost::Message>::decode(&*data).unwrap();
            let (package, name) = kind.schema_name().rsplit_once('.').unwrap();
            assert!(
                fds.file
                    .iter()
                    .any(|f| f.package() == package
                        && f.message_type.iter().any(|m| m.name() == name)),
                "{kind:?}"
            );
            assert_eq!(CHANNEL_KINDS[kind as usize], kind);
        }
    }

    /// Each message the encoder writes decodes with its schema alone, into the fields the
    /// tools read; a CAN train holds every frame with its own time.
    #[test]
    fn encoded_messages_decode_with_their_schemas() {
        let truth = TruthSnapshot {
            r_eci_m: nalgebra::Vector3::new(7e6, 0.0, 0.0),
            ..TruthSnapshot::default()
        };
        let mut enc = EventEncoder::new(1_000_000_000);
        let mut got: Vec<(ChannelKind, serde_json::Value)> = Vec::new();
        let mut emit = |m: Encoded<'_>| -> anyhow::Result<()> {
            let data: Arc<[u8]> = m.kind.schema_data()?.into();
            let v = crate::protobuf::decode(m.kind.schema_name(), SCHEMA_ENCODING, &data, m.data)?;
            got.push((m.kind, v));
            Ok(())
        };
        let ev = RunEvent::Truth {
            t: SimTime::from_secs(2),
            truth: Box::new(truth),
            adcs: Box::default(),
        };
        enc.encode(&ev, &mut emit).unwrap();
        let medium: Arc<str> = Arc::from("main");
        for (k, from) in ["FC", "FC", "EPS"].iter().enumerate() {
            let f = CanFrame::new(0x0100_0000 + k as u32, &[k as u8; 8]).unwrap();
            let m = TraceEvent {
                t: SimTime(3_000_000_000 + 100_000 * k as u64),
                medium: medium.clone(),
                from: Arc::from(*from),
                frame: TraceFrame::Can(f),
                dropped: k == 1,
            };
            enc.encode(&RunEvent::Medium(m), &mut emit).unwrap();
        }
        enc.finish(&mut emit).unwrap();
        let of = |kind| got.iter().filter(move |(k, _)| *k == kind).map(|(_, v)| v);
        let tf = of(ChannelKind::TruthTf).next().unwrap();
        assert_eq!(tf["timestamp"]["sec"], 3);
        assert_eq!(tf["child_frame_id"], FRAME_BODY);
        let state = of(ChannelKind::TruthState).next().unwrap();
        assert_eq!(state["t_ns"], 2_000_000_000u64);
        assert_eq!(state["r_eci_m"], serde_json::json!([7e6, 0.0, 0.0]));
        let loc = of(ChannelKind::TruthLocation).next().unwrap();
        assert_eq!(loc["frame_id"], FRAME_EARTH);
        let scene = of(ChannelKind::Scene).next().unwrap();
        assert_eq!(scene["entities"][0]["id"], SCENE_ENTITY_ID);
        let trains: Vec<CanFramesMsg> = of(ChannelKind::Can)
            .map(|v| serde_json::from_value(v.clone()).unwrap())
            .collect();
        assert_eq!(trains.len(), 2, "FC's two frames, then EPS's");
        assert_eq!(trains[0].from, "FC");
        assert_eq!(trains[0].dropped.0, [1]);
        let frames: Vec<_> = trains[0].frames().collect();
        assert_eq!(
            frames,
            [
                (3_000_000_000, 0x0100_0000, &[0u8; 8][..], false),
                (3_000_100_000, 0x0100_0001, &[1u8; 8][..], true),
            ]
        );
        assert_eq!(trains[1].from, "EPS");
        assert_eq!(trains[1].t_ns, 3_000_200_000);
        // The second train reuses the first one's vectors: nothing of the first is left.
        assert!(trains[1].dropped.is_empty());
        let frames: Vec<_> = trains[1].frames().collect();
        assert_eq!(frames, [(3_000_200_000, 0x0100_0002, &[2u8; 8][..], false)]);
    }

    /// The frames of a train, one `/can/main/frames` message each, in the order handed out,
    /// with the other messages' kinds in between.
    fn trains_of(events: &[RunEvent]) -> Vec<Result<Vec<u64>, ChannelKind>> {
        let mut enc = EventEncoder::new(0);
        let mut out = Vec::new();
        let mut emit = |m: Encoded<'_>| -> anyhow::Result<()> {
            if m.kind == ChannelKind::Can {
                let data: Arc<[u8]> = m.kind.schema_data()?.into();
                let v =
                    crate::protobuf::decode(m.kind.schema_name(), SCHEMA_ENCODING, &data, m.data)?;
                let train: CanFramesMsg = serde_json::from_value(v)?;
                out.push(Ok(train.frames().map(|f| f.0).collect()));
            } else {
                out.push(Err(m.kind));
            }
            Ok(())
        };
        for e in events {
            enc.encode(e, &mut emit).unwrap();
        }
        enc.finish(&mut emit).unwrap();
        out
    }

    /// A MORE frame (no CSP packet completes) from `from` on the main bus at `t_ns`.
    fn more_frame(t_ns: u64, from: &str) -> RunEvent {
        // CFP MORE (bit 18), src 3, dst 1, remain 5.
        let f = CanFrame::new(0x0308_0000 | 1 << 18 | 5 << 10, &[0; 8]).unwrap();
        RunEvent::Medium(TraceEvent {
            t: SimTime(t_ns),
            medium: Arc::from("main"),
            from: Arc::from(from),
            frame: TraceFrame::Can(f),
            dropped: false,
        })
    }

    #[test]
    fn a_train_ends_at_64_frames_at_100_ms_and_at_another_sender() {
        // 70 frames from the FC 100 us apart: 64, then 6.
        let ev: Vec<RunEvent> = (0..70)
            .map(|k| more_frame(1_000_000 + 100_000 * k, "FC"))
            .collect();
        let got = trains_of(&ev);
        let sizes: Vec<usize> = got.iter().map(|t| t.as_ref().unwrap().len()).collect();
        assert_eq!(sizes, [64, 6]);
        assert_eq!(got[1].as_ref().unwrap()[0], 1_000_000 + 100_000 * 64);

        // The same sender 100 ms after the train began starts another; another sender too.
        let ev = [
            more_frame(0, "FC"),
            more_frame(TRAIN_MAX_SPAN_NS - 1, "FC"),
            more_frame(TRAIN_MAX_SPAN_NS, "FC"),
            more_frame(TRAIN_MAX_SPAN_NS + 1, "EPS"),
        ];
        let got: Vec<Vec<u64>> = trains_of(&ev).into_iter().map(Result::unwrap).collect();
        assert_eq!(
            got,
            [
                vec![0, TRAIN_MAX_SPAN_NS - 1],
                vec![TRAIN_MAX_SPAN_NS],
                vec![TRAIN_MAX_SPAN_NS + 1]
            ]
        );
    }

    #[test]
    fn an_idle_bus_hands_its_train_out_at_the_next_event_100_ms_on() {
        let log = |t_ns: u64| RunEvent::Log {
            t: SimTime(t_ns),
            source: "run".into(),
            level: twin_core::events::Level::Info,
            message: "tick".into(),
        };
        let ev = [
            more_frame(0, "FC"),
            log(TRAIN_MAX_SPAN_NS - 1), // too early: the train stays open
            log(TRAIN_MAX_SPAN_NS),     // the train goes out before this line
        ];
        let got = trains_of(&ev);
        assert_eq!(
            got,
            [Err(ChannelKind::Log), Ok(vec![0]), Err(ChannelKind::Log)]
        );
    }

    /// The truth's A(ECEF <- ECI) is within 1e-6 m of the exact rotation at 7000 km (the
    /// minute chord of precession and nutation is checked over every phase of the nutation
    /// in `orbit::frames`; here, its use with the Earth's rotation): every 7.3 s for three
    /// hours across a year's end.
    #[test]
    fn the_truth_rotates_to_ecef_within_a_micrometre_of_the_exact_rotation() {
        let mut ecef = EcefFromEci::default();
        let r_eci_m = nalgebra::Vector3::new(4_000_000.0, -5_000_000.0, 4_747_000.0);
        let start = 1_798_761_600_000_000_000i64 - 3_600_000_000_000;
        let mut worst_m: f64 = 0.0;
        for unix_ns in (0..1480).map(|k| start + k * 7_300_000_000) {
            let exact = orbit::frames::a_ecef_from_eci(UtcTime::from_unix_ns(unix_ns), None);
            worst_m = worst_m.max((ecef.at(unix_ns) * r_eci_m - exact * r_eci_m).norm());
        }
        assert!(worst_m < 1e-6, "{worst_m} m");
    }

    /// A session run's end gives its `/pc/sessions` message as before, then one
    /// `/pc/sessions/summary`: its payload from the run's ICD, its start, and the bytes of
    /// the session downlinked from its start to its end (not another session's, not those
    /// arriving after its end); a lost run names its cause; an end without a start has none.
    #[test]
    fn a_session_runs_end_is_summed_up_after_its_session_message() {
        use nodes_pc::PcOutput as O;
        // The default PC's sessions (the run's are `twin_core::icd`'s to map): 1 polls
        // payload 12, 2 buffers payload 13.
        let mut enc = EventEncoder::new(0);
        let s = SimTime::from_secs;
        let down = |t, session_id, n: usize| O::Downlinked {
            t,
            session_id,
            payload_addr: 11 + session_id,
            bytes: vec![7; n],
        };
        let events = [
            O::SessionStarted {
                t: s(10),
                session_id: 1,
                payload_addr: 12,
            },
            down(s(11), 1, 100),
            down(s(12), 2, 50),
            down(s(13), 1, 30),
            O::SessionEnded {
                t: s(20),
                session_id: 1,
                result: nodes_pc::SessionResult::NoAck,
                packets: 9,
            },
            down(s(21), 1, 1000),
            O::SessionStarted {
                t: s(30),
                session_id: 1,
                payload_addr: 12,
            },
            down(s(31), 1, 5),
            O::SessionLost {
                t: s(40),
                session_id: 1,
                cause: nodes_pc::LostCause::Reboot,
                packets: 3,
            },
            O::SessionEnded {
                t: s(50),
                session_id: 2,
                result: nodes_pc::SessionResult::Aborted,
                packets: 0,
            },
        ];
        let mut got: Vec<(ChannelKind, serde_json::Value)> = Vec::new();
        let mut emit = |m: Encoded<'_>| -> anyhow::Result<()> {
            let data: Arc<[u8]> = m.kind.schema_data()?.into();
            let v = crate::protobuf::decode(m.kind.schema_name(), SCHEMA_ENCODING, &data, m.data)?;
            got.push((m.kind, v));
            Ok(())
        };
        for o in events {
            enc.encode(&RunEvent::Pc(Box::new(o)), &mut emit).unwrap();
        }
        use ChannelKind::{Downlink as D, PcSession as P, PcSessionSummary as S};
        let kinds: Vec<ChannelKind> = got.iter().map(|(k, _)| *k).collect();
        assert_eq!(kinds, [P, D, D, D, P, S, D, P, D, P, S, P, S]);
        // The `/pc/sessions` message of an end is what it always was.
        let ended: PcSessionMsg = serde_json::from_value(got[4].1.clone()).unwrap();
        assert_eq!(
            ended,
            PcSessionMsg {
                t_ns: s(20).as_ns(),
                event: "ended".into(),
                session: Some(1),
                payload: None,
                result: Some("no-ack".into()),
                packets: Some(9),
                reason: None,
                bytes: None,
            }
        );
        let summaries: Vec<PcSessionSummaryMsg> = got
            .iter()
            .filter(|(k, _)| *k == S)
            .map(|(_, v)| serde_json::from_value(v.clone()).unwrap())
            .collect();
        let summary =
            |t: SimTime, session, payload, result: &str, cause: Option<&str>| PcSessionSummaryMsg {
                t_ns: t.as_ns(),
                session,
                payload,
                result: result.into(),
                cause: cause.map(str::to_owned),
                packets: 0,
                downlinked_bytes: 0,
                start_ns: None,
            };
        assert_eq!(
            summaries,
            [
                PcSessionSummaryMsg {
                    packets: 9,
                    downlinked_bytes: 130,
                    start_ns: Some(s(10).as_ns()),
                    ..summary(s(20), 1, Some(12), "no-ack", None)
                },
                PcSessionSummaryMsg {
                    packets: 3,
                    downlinked_bytes: 5,
                    start_ns: Some(s(30).as_ns()),
                    ..summary(s(40), 1, Some(12), "lost", Some("reboot"))
                },
                summary(s(50), 2, Some(13), "aborted", None),
            ]
        );
        // Without the run's ICD, the encoder does not guess a session's payload.
        let mut bare = EventEncoder::new(0);
        bare.set_icd(twin_core::icd::IcdMap::default());
        let mut payloads = Vec::new();
        let lost = O::SessionLost {
            t: s(1),
            session_id: 1,
            cause: nodes_pc::LostCause::PowerLoss,
            packets: 0,
        };
        bare.encode(&RunEvent::Pc(Box::new(lost)), &mut |m| {
            if m.kind == S {
                let data: Arc<[u8]> = m.kind.schema_data()?.into();
                let v =
                    crate::protobuf::decode(m.kind.schema_name(), SCHEMA_ENCODING, &data, m.data)?;
                payloads.push((v["payload"].clone(), v["cause"].clone()));
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(
            payloads,
            [(serde_json::Value::Null, serde_json::json!("power"))]
        );
    }

    #[test]
    fn zero_or_non_finite_positions_have_no_location() {
        let stamp = foxglove_time(0, SimTime::ZERO);
        let truth = TruthSnapshot::default();
        let state = truth_state(0, &truth, &mut EcefFromEci::default());
        assert!(location_fix(stamp, &state).is_none(), "the Earth's centre");
        // The default snapshot has no sun and no position: the scene keeps the box and axes.
        let scene = scene_update(stamp, &truth);
        assert_eq!(scene.entities[0].arrows.len(), 3);
        assert_eq!(num(f64::NAN), None);
        assert_eq!(num(f64::NEG_INFINITY), None);
        assert_eq!(num(-0.5), Some(-0.5));
        assert_eq!(
            serde_json::to_string(&quat_wxyz([f64::NAN, 0.0, 1.0, f64::INFINITY])).unwrap(),
            r#"{"w":null,"x":0.0,"y":1.0,"z":null}"#
        );
        assert!(nums([f64::INFINITY, 1.0])[0].is_nan());
        assert_eq!(quat_xyzw([1.0, 0.0, f64::NAN, 0.0]), None);
    }
}
