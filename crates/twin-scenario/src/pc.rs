//! `[pc]` and `[[payload]]`: the payload controller's sessions and the simulated payloads as a
//! scenario writes them (docs/scenarios.md, "The PC and the payloads").

use schemars::JsonSchema;
use serde::Deserialize;

use crate::dur::Dur;

/// The payload controller (`[pc]`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PcSpec {
    /// One session per payload (`[[pc.sessions]]`); none: session 1 polls payload 12 and
    /// session 2 buffers payload 13 (the ICD's SETUP example works at once).
    #[serde(default)]
    pub sessions: Vec<PcSessionSpec>,
    /// S-band data rate, bit/s (default 1 000 000).
    #[serde(default)]
    pub sband_rate_bps: Option<u64>,
    /// Payload bytes per S-band frame.
    #[serde(default)]
    pub sband_frame_data_bytes: Option<u32>,
    /// Framing bytes per S-band frame (sync marker, header, check).
    #[serde(default)]
    pub sband_frame_overhead_bytes: Option<u32>,
    /// Whether the transmitter is on at boot (default true).
    #[serde(default)]
    pub sband_on: Option<bool>,
    /// S-band events (`[[pc.events]]`: `at`, `sband = "fail" | "restore" | "off" | "on"`).
    #[serde(default)]
    pub events: Vec<PcEventSpec>,
    /// Port numbers of the PC's services.
    #[serde(default)]
    pub ports: Option<PcPortsSpec>,
    /// Directory for the downlinked files, one per session run (default: beside the
    /// recording, `<recording>.downlink/`; no recording: none).
    #[serde(default)]
    pub downlink_dir: Option<String>,
}

/// One session of the PC (fixed for the run).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PcSessionSpec {
    /// Session id (the SETUP's `sessionId`).
    pub id: u8,
    /// The payload's CSP address, 12-15.
    pub payload: u8,
    /// The payload's SYNC/POLL port (default 10).
    #[serde(default)]
    pub port: Option<u8>,
    /// `polling` or `buffering`.
    pub mode: SessionModeName,
    /// Polling: time between POLLs.
    #[serde(default)]
    pub poll_period: Option<Dur>,
    /// Polling: how long to wait for a reply before repeating.
    #[serde(default)]
    pub reply_timeout: Option<Dur>,
    /// Buffering: file capacity, bytes (default 256 MiB).
    #[serde(default)]
    pub buffer_capacity_bytes: Option<u64>,
}

/// How a session collects data (ICD 3.1.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum SessionModeName {
    /// The PC polls the payload.
    Polling,
    /// The payload pushes to the PC's file.
    Buffering,
}

/// An S-band event at a time.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PcEventSpec {
    /// When.
    pub at: Dur,
    /// `fail` (an ACTIVE session ends with S-BAND FAILURE), `restore`, `off`, `on`.
    pub sband: SbandEventName,
}

/// S-band events.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum SbandEventName {
    /// The transmitter fails.
    Fail,
    /// The failure is repaired.
    Restore,
    /// Switched off.
    Off,
    /// Switched on.
    On,
}

/// The PC's port numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PcPortsSpec {
    /// Session control (default 10).
    #[serde(default)]
    pub control: Option<u8>,
    /// Buffered data ingest (default 11).
    #[serde(default)]
    pub ingest: Option<u8>,
    /// The PC's telemetry (default 12).
    #[serde(default)]
    pub telemetry: Option<u8>,
    /// The buffer files (default 13).
    #[serde(default)]
    pub files: Option<u8>,
}

/// A simulated payload (`[[payload]]`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PayloadSpec {
    /// Its CSP address (one of `[network] payloads`).
    pub addr: u8,
    /// SYNC/POLL port (default 10).
    #[serde(default)]
    pub port: Option<u8>,
    /// Where the data comes from: `counter` (default; self-checking frames) or a file.
    #[serde(default)]
    pub file: Option<String>,
    /// Data becomes available at this rate, bytes/s (default: all at once).
    #[serde(default)]
    pub rate_bytes_per_s: Option<u64>,
    /// Delay between a request and its reply (default 5 ms).
    #[serde(default)]
    pub reply_latency: Option<Dur>,
    /// Behaviour at boot: `normal`, `no-ack`, `wrong-echo`, `slow:<duration>`,
    /// `silent-for:<polls>`, `silent`, `oversize:<bytes>`, `garbage`, `zero-length`.
    #[serde(default)]
    pub behaviour: Option<String>,
    /// Behaviour changes (`[[payload.changes]]`: `at`, `behaviour`).
    #[serde(default)]
    pub changes: Vec<BehaviourChangeSpec>,
    /// Buffering: push data to the PC's ingest port.
    #[serde(default)]
    pub push: Option<PushSpec>,
}

/// A behaviour change at a time.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BehaviourChangeSpec {
    /// When.
    pub at: Dur,
    /// The new behaviour (as `behaviour`).
    pub behaviour: String,
}

/// Pushing data to the PC (buffering mode).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PushSpec {
    /// Bytes per second.
    pub rate_bytes_per_s: u64,
    /// Data bytes per packet, 1-256 (default 200).
    #[serde(default)]
    pub packet_bytes: Option<u16>,
    /// First packet (default: at the start).
    #[serde(default)]
    pub start: Option<Dur>,
    /// No packet from this time on (default: never stops).
    #[serde(default)]
    pub stop: Option<Dur>,
}

/// Session results by name (ICD 3.1.6 table 3), and `lost`: a run the PC lost with its
/// memory (power loss, reboot), which has no ICD result.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum SessionResultName {
    /// 0: finished (or never executed).
    Done,
    /// 1: ABORT command.
    Aborted,
    /// 2: the payload did not acknowledge the SYNC.
    NoAck,
    /// 3: the S-band transmitter failed.
    SBandFailure,
    /// Lost with the PC's memory.
    Lost,
}

impl SessionResultName {
    /// Whether a run that ended `end` ended this way.
    pub fn matches(self, end: RunEnd) -> bool {
        use nodes_pc::SessionResult as R;
        matches!(
            (self, end),
            (Self::Done, RunEnd::Result(R::Done))
                | (Self::Aborted, RunEnd::Result(R::Aborted))
                | (Self::NoAck, RunEnd::Result(R::NoAck))
                | (Self::SBandFailure, RunEnd::Result(R::SbandFailure))
                | (Self::Lost, RunEnd::Lost(_))
        )
    }
    /// Its name in scenarios (`done`, `no-ack`, `lost`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Done => "done",
            Self::Aborted => "aborted",
            Self::NoAck => "no-ack",
            Self::SBandFailure => "s-band-failure",
            Self::Lost => "lost",
        }
    }
}

/// How a session run ended: with the PC's result, or lost with its memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    /// The PC ended it, with this ICD result.
    Result(nodes_pc::SessionResult),
    /// The PC lost it (power loss, reboot): no result, nothing after.
    Lost(nodes_pc::LostCause),
}

impl std::fmt::Display for RunEnd {
    /// `done`, `no-ack`, ..., `lost (power)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunEnd::Result(r) => f.write_str(result_name(r.to_u8())),
            RunEnd::Lost(c) => write!(f, "lost ({})", c.as_str()),
        }
    }
}

/// The scenario name of a session result value.
pub fn result_name(r: u8) -> &'static str {
    match r {
        0 => "done",
        1 => "aborted",
        2 => "no-ack",
        3 => "s-band-failure",
        _ => "?",
    }
}

snap::tagged_enum!(RunEnd { Result(r), Lost(c) });
