//! Scenario files: one TOML file describes a run (see `docs/scenarios.md`).
//!
//! Parsing is strict: unknown fields, wrong types, out-of-range values and unknown node
//! names are errors that name the file, the line and the field. [`Scenario::parse_with`]
//! checks the syntax and the types (serde with `deny_unknown_fields`), then
//! [`Scenario::validate_with`] checks the meaning: the scenario's own fields here, then the
//! checks the twin passes (its slices': node names, ranges, references between entries),
//! locating every problem in the source through the spanned TOML tree.

use std::collections::BTreeMap;
use std::fmt;
use std::time::Duration;

use schemars::JsonSchema;
use serde::{Deserialize, Deserializer};

use twin_core::duration::parse_duration;

/// The most bytes a scenario or campaign file may have: 32 MiB (a hundred thousand commands
/// take about 7 MiB). A longer file, or a device that never ends (`/dev/zero`), is refused
/// at once, never read beyond that.
pub const INPUT_LIMIT_BYTES: u64 = 32 << 20;

/// Why a scenario or campaign file could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    /// Longer than [`INPUT_LIMIT_BYTES`].
    #[error("longer than {} MiB: refused (a scenario or campaign file is at most that)", INPUT_LIMIT_BYTES >> 20)]
    TooLarge,
    /// Not UTF-8 text.
    #[error("not UTF-8 text")]
    NotText,
    /// The file system's error.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// Read a scenario or campaign file, at most [`INPUT_LIMIT_BYTES`] of it.
pub fn read_input(path: &std::path::Path) -> Result<String, ReadError> {
    use std::io::Read as _;
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(INPUT_LIMIT_BYTES + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > INPUT_LIMIT_BYTES {
        return Err(ReadError::TooLarge);
    }
    String::from_utf8(bytes).map_err(|_| ReadError::NotText)
}

/// A duration written as `90`, `90s`, `500ms`, `10m`, `2h` or `1d`.
pub use crate::dur::Dur;
use twin_core::network::NetworkSpec;
pub use twin_core::network::NodeRef;

/// A check of a part of the scenario beyond its fields' syntax: `err(path, message)` for each
/// problem (see [`Scenario::validate_with`]).
pub type Check = fn(&Scenario, &NetworkSpec, &mut dyn FnMut(Vec<PathStep>, String));

/// A whole scenario.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name, used in reports (default: the file name).
    #[serde(default)]
    pub name: Option<String>,
    /// What the scenario shows.
    #[serde(default)]
    pub description: Option<String>,
    /// UTC time of simulated time zero, ISO 8601 (`2026-03-20T12:00:00Z`).
    #[serde(default = "default_start")]
    pub start: String,
    /// Simulated duration.
    pub duration: Dur,
    /// Seed of every random choice.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Virtual or real time.
    #[serde(default)]
    pub clock: ClockSpec,
    /// The satellite.
    #[serde(default)]
    pub satellite: SatelliteSpec,
    /// The flight computer: initial state, models, ADCS, scripts and faults.
    #[serde(default)]
    pub fc: crate::fc::FcSpec,
    /// The payload controller: sessions, S-band, events.
    #[serde(default)]
    pub pc: crate::pc::PcSpec,
    /// The radio link to the ground: passes over the ground stations.
    #[serde(default)]
    pub comm: crate::comm::CommSpec,
    /// The EPS: battery state and channel switching.
    #[serde(default)]
    pub eps: crate::eps::EpsSpec,
    /// The simulated payloads' data and behaviour (`[[payload]]`, one per address).
    #[serde(default)]
    pub payload: Vec<crate::pc::PayloadSpec>,
    /// The network.
    #[serde(default)]
    pub network: NetworkCfg,
    /// Per-node options, keyed by node name.
    #[serde(default)]
    pub nodes: BTreeMap<String, NodeOptions>,
    /// What payloads may ask of the platform (`crate::rules`).
    #[serde(default)]
    pub rules: crate::rules::RulesSpec,
    /// The invariants' settings (`crate::invariants`).
    #[serde(default)]
    pub invariants: crate::invariants::InvariantsSpec,
    /// Links to programs outside the twin.
    #[serde(default)]
    pub links: Vec<LinkSpec>,
    /// Recording settings.
    #[serde(default)]
    pub record: RecordSpec,
    /// Requests sent during the run.
    #[serde(default)]
    pub commands: Vec<crate::commands::CommandSpec>,
    /// Faults during the run (`crate::faults`: each kind's fields).
    #[serde(default)]
    pub faults: Vec<crate::entries::FaultEntry>,
    /// What must happen (`crate::expectations`: each kind's fields).
    #[serde(default)]
    pub expectations: Vec<crate::entries::ExpectEntry>,
}

fn default_start() -> String {
    "2026-03-20T12:00:00Z".to_owned()
}
fn default_seed() -> u64 {
    1
}

/// How simulated time runs.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ClockSpec {
    /// `virtual` (as fast as the CPU allows, deterministic) or `realtime`.
    #[serde(default)]
    pub mode: ClockKind,
    /// Simulated seconds per wall second in real time.
    #[serde(default = "one")]
    pub speed: f64,
    /// Run in virtual time until this moment and in real time (at `speed`) after it: a
    /// simulated time (`"13000s"`), `"first pass"` or `"first pass over STATION"`
    /// (crate::clock). Outside links are open from the start.
    #[serde(default)]
    pub realtime_from: Option<String>,
}

fn one() -> f64 {
    1.0
}

impl Default for ClockSpec {
    fn default() -> Self {
        ClockSpec {
            mode: ClockKind::Virtual,
            speed: 1.0,
            realtime_from: None,
        }
    }
}

/// Clock modes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum ClockKind {
    /// Paused clock jumping to the next timer.
    #[default]
    Virtual,
    /// The wall clock.
    Realtime,
}

/// The satellite's orbit.
#[derive(Debug, Clone, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SatelliteSpec {
    /// Two-line elements: the two lines (a title line may come first).
    #[serde(default)]
    pub tle: Vec<String>,
}

/// The network's shape and link rates.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NetworkCfg {
    /// Simulated payload addresses (12-15).
    #[serde(default = "default_payloads")]
    pub payloads: Vec<u8>,
    /// Internal ground station addresses (16-20).
    #[serde(default = "default_ground")]
    pub ground_stations: Vec<u8>,
    /// Main CAN bus bit rate.
    #[serde(default = "default_can_rate")]
    pub main_bitrate_bps: u32,
    /// Payload CAN bus bit rate.
    #[serde(default = "default_can_rate")]
    pub payload_bitrate_bps: u32,
    /// UHF data rate.
    #[serde(default = "default_uhf_rate")]
    pub uhf_rate_bps: u32,
    /// Frames each CAN controller's transmit queue holds (Linux `txqueuelen`); more are
    /// lost and counted.
    #[serde(default = "default_can_tx_queue")]
    pub can_tx_queue_frames: usize,
    /// Bytes each sender's transmit buffer on the UHF air holds (a radio's or a ground
    /// modem's); a packet that does not fit is lost and counted.
    #[serde(default = "default_uhf_tx_buffer")]
    pub uhf_tx_buffer_bytes: u32,
}

fn default_can_tx_queue() -> usize {
    bus::can::TX_QUEUE_FRAMES
}
fn default_uhf_tx_buffer() -> u32 {
    bus::net::AIR_BUFFER_BYTES
}

fn default_payloads() -> Vec<u8> {
    vec![12, 13]
}
fn default_ground() -> Vec<u8> {
    vec![16]
}
fn default_can_rate() -> u32 {
    1_000_000
}
fn default_uhf_rate() -> u32 {
    9600
}

impl Default for NetworkCfg {
    fn default() -> Self {
        NetworkCfg {
            payloads: default_payloads(),
            ground_stations: default_ground(),
            main_bitrate_bps: default_can_rate(),
            payload_bitrate_bps: default_can_rate(),
            uhf_rate_bps: default_uhf_rate(),
            can_tx_queue_frames: default_can_tx_queue(),
            uhf_tx_buffer_bytes: default_uhf_tx_buffer(),
        }
    }
}

/// Options of one node.
#[derive(Debug, Clone, PartialEq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NodeOptions {
    /// Uptime service format: `libcsp` (u32 BE seconds) or `icd` (u32 LE milliseconds).
    #[serde(default)]
    pub uptime: Option<UptimeKind>,
    /// Factory values of the node's platform parameters by name (`crate::params`).
    #[serde(default)]
    pub params: BTreeMap<String, crate::params::ParamValue>,
}

/// Uptime service formats (INTERPRETATION.md section 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum UptimeKind {
    /// libcsp 1.4: u32 big-endian seconds.
    Libcsp,
    /// The ICD's table: u32 little-endian milliseconds.
    Icd,
}

/// A link to a program outside the twin.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct LinkSpec {
    /// `kiss-listen`, `kiss-connect`, `kiss-pty`, `zmq-hub`, `udp`, `socketcan` or `uart`
    /// (a node's text console).
    pub kind: LinkKind,
    /// TCP address (KISS/TCP, and a `uart` console served over TCP), path (`kiss-pty`:
    /// where the pty is linked), host (`zmq-hub`: `127.0.0.2`, or `127.0.0.2:6000:7000`
    /// with the ports the programs publish to and subscribe at), the UDP address the twin
    /// binds (`udp`) or interface name with an optional `:main`/`:payload` (SocketCAN).
    #[serde(default)]
    pub addr: String,
    /// `udp`: where the twin sends (`127.0.0.1:10016`; default: the source of the latest
    /// datagram received).
    #[serde(default)]
    pub peer: Option<String>,
    /// `uart`: the node whose console this is (`FC`, `EPS`, ...).
    #[serde(default)]
    pub node: Option<String>,
    /// `uart`: serve the console on a pseudo-terminal linked at this path (for `screen`,
    /// `minicom`, `picocom`) instead of on `addr`.
    #[serde(default)]
    pub pty: Option<String>,
    /// CSP addresses behind the link (default: learned from its packets).
    #[serde(default)]
    pub addrs: Vec<u8>,
    /// Apply libcsp 1.4's 248-byte KISS receive limit.
    #[serde(default)]
    pub libcsp14_rx_limit: bool,
    /// The link's name, for faults to target (`target = "payload-sw"`).
    #[serde(default)]
    pub name: Option<String>,
    /// The EPS channel that powers the program behind the link (`PL14`): while it is off,
    /// the twin forwards nothing to or from it. Default: no channel switches it.
    #[serde(default)]
    pub powered_by: Option<String>,
    /// Nodes of the twin the program behind the link takes the place of (`["PC"]`, your own
    /// flight software): they are not started, and on a KISS link their addresses become
    /// the link's.
    #[serde(default)]
    pub replaces: Vec<String>,
    /// KISS: connections a `kiss-listen` link serves at once (default 16).
    #[serde(default)]
    pub max_connections: Option<usize>,
    /// KISS: 4 KiB chunks read ahead of the twin per connection before TCP holds the
    /// program back (default 16).
    #[serde(default)]
    pub input_chunks: Option<usize>,
    /// KISS: frames waiting for a connection's reader before more are dropped (default
    /// 256).
    #[serde(default)]
    pub output_frames: Option<usize>,
    /// KISS listen: how long a connection holding no address may go without a byte
    /// before it is closed (default 60 s; "off": never).
    #[serde(default)]
    pub idle_timeout: Option<IdleLimit>,
    /// KISS, pty, hub: at most this many CAN frames a second from each connection on a CAN
    /// bus (1 to 100000; default: as many as the bus takes).
    #[serde(default)]
    pub tx_frames_per_s: Option<u32>,
}

/// A wall-clock limit that may be turned off: a duration (`"60s"`) or `"off"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, JsonSchema)]
#[schemars(with = "String", description = "a duration (60s, 5m) or \"off\"")]
pub enum IdleLimit {
    /// Never.
    Off,
    /// After this long.
    After(Duration),
}

impl IdleLimit {
    /// The limit, `None` when off.
    pub fn duration(self) -> Option<Duration> {
        match self {
            IdleLimit::Off => None,
            IdleLimit::After(d) => Some(d),
        }
    }
}

/// Why a text is not an [`IdleLimit`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum IdleLimitError {
    /// A duration below 100 ms.
    #[error("`{text}`: at least 100ms, or \"off\"")]
    TooShort {
        /// The text as given.
        text: String,
    },
    /// Neither a duration nor `off`. The duration's message is part of this one's, so it is
    /// not also its `source()`.
    #[error("{duration}, or \"off\"")]
    NotADuration {
        /// Why it is not a duration.
        duration: twin_core::duration::DurationError,
    },
}

impl std::str::FromStr for IdleLimit {
    type Err = IdleLimitError;
    fn from_str(s: &str) -> Result<Self, IdleLimitError> {
        if s.trim().eq_ignore_ascii_case("off") {
            return Ok(IdleLimit::Off);
        }
        match parse_duration(s) {
            Ok(d) if d >= Duration::from_millis(100) => Ok(IdleLimit::After(d)),
            Ok(_) => Err(IdleLimitError::TooShort { text: s.to_owned() }),
            Err(duration) => Err(IdleLimitError::NotADuration { duration }),
        }
    }
}

impl<'de> Deserialize<'de> for IdleLimit {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

/// Link kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum LinkKind {
    /// Listen for outside nodes speaking KISS over TCP.
    KissListen,
    /// Connect to an outside KISS/TCP server.
    KissConnect,
    /// KISS on a pseudo-terminal linked at `addr` (a path), for libcsp's usart driver.
    KissPty,
    /// libcsp 1.4's ZMQ hub bound on `addr` (`HOST` or `HOST:PUB:SUB`).
    ZmqHub,
    /// CSP over UDP, one packet per datagram: the twin binds `addr` and sends to `peer`.
    Udp,
    /// Bridge to a SocketCAN interface.
    Socketcan,
    /// A node's text console (`node`), on a TCP `addr` or a `pty` path.
    Uart,
}

/// Recording settings.
#[derive(Debug, Clone, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RecordSpec {
    /// MCAP file to write (relative to the working directory); none = no recording.
    #[serde(default)]
    pub file: Option<String>,
    /// Which channels the recording holds: rules applied in order, the last matching a
    /// topic deciding (`TOPIC` keeps, `-TOPIC` leaves out, `TOPIC@PERIOD` thins; a topic
    /// may end in `*`); none: every channel, every message (docs/recording.md, "Choosing
    /// the channels").
    #[serde(default)]
    pub channels: Vec<crate::channels::ChannelRule>,
    /// Carry a snapshot of the whole twin every this much simulated time (`"10m"`), as
    /// attachments of the recording, so that `replay --from T` starts at the latest one
    /// before T (docs/snapshots.md, "Seeking a recording"); none: no snapshots.
    #[serde(default)]
    pub snapshot_every: Option<crate::dur::Dur>,
}

/// A problem in a scenario file, located in its source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScenarioError {
    /// The file (as given).
    pub file: String,
    /// 1-based line, when known.
    pub line: Option<usize>,
    /// 1-based column, when known.
    pub column: Option<usize>,
    /// The field path, for example `commands[2].to`.
    pub field: String,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
            if let Some(c) = self.column {
                write!(f, ":{c}")?;
            }
        }
        if self.field.is_empty() {
            write!(f, ": {}", self.message)
        } else {
            write!(f, ": field `{}`: {}", self.field, self.message)
        }
    }
}

impl std::error::Error for ScenarioError {}

/// Every problem found in a file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScenarioErrors(pub Vec<ScenarioError>);

impl fmt::Display for ScenarioErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ScenarioErrors {}

/// The 1-based line and column of byte `offset` of `text`.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let col = before
        .rfind('\n')
        .map_or(before.len(), |i| before.len() - i - 1)
        + 1;
    (line, col)
}

/// One step of a field path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PathStep {
    /// A table key.
    Key(String),
    /// An array index.
    Index(usize),
}

/// `faults[0].at` of a path.
pub fn path_string(path: &[PathStep]) -> String {
    let mut s = String::new();
    for step in path {
        match step {
            PathStep::Key(k) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(k);
            }
            PathStep::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

/// The byte span of the value at `path` in `text`, or of its nearest existing parent.
pub fn locate(text: &str, path: &[PathStep]) -> Option<std::ops::Range<usize>> {
    let root = toml::de::DeTable::parse(text).ok()?;
    let mut span = None;
    let mut node: Option<&toml::de::DeValue<'_>> = None;
    for (i, step) in path.iter().enumerate() {
        let next = match (i, step, node) {
            (0, PathStep::Key(k), _) => root.get_ref().get(k.as_str()),
            (_, PathStep::Key(k), Some(n)) => n.get(k.as_str()),
            (_, PathStep::Index(ix), Some(n)) => n.get(*ix),
            _ => None,
        };
        match next {
            Some(n) => {
                span = Some(n.span());
                node = Some(n.get_ref());
            }
            None => break,
        }
    }
    span
}

/// Helpers to build paths tersely.
fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

impl Scenario {
    /// Parse a scenario and validate it with `checks` (the twin's `scenario::parse` passes
    /// every slice's); `file` names it in errors.
    pub fn parse_with(
        file: &str,
        text: &str,
        checks: &[Check],
    ) -> Result<Scenario, ScenarioErrors> {
        let scenario: Scenario = toml::from_str(text).map_err(|e| {
            let (line, column) = match e.span() {
                Some(s) => {
                    let (l, c) = line_col(text, s.start);
                    (Some(l), Some(c))
                }
                None => (None, None),
            };
            let message = e.message().trim().to_owned();
            ScenarioErrors(vec![ScenarioError {
                file: file.to_owned(),
                line,
                column,
                field: field_from_message(text, e.span()),
                message,
            }])
        })?;
        scenario.validate_with(file, text, checks)?;
        Ok(scenario)
    }

    /// The scenario's name: its `name`, or the file stem.
    pub fn display_name(&self, file: &str) -> String {
        self.name.clone().unwrap_or_else(|| {
            std::path::Path::new(file)
                .file_stem()
                .map_or_else(|| file.to_owned(), |s| s.to_string_lossy().into_owned())
        })
    }

    /// Check the meaning of every field, reporting all problems with their location: the
    /// scenario's own fields here, then each of `checks` (the twin's slices, which know
    /// what their tables mean).
    pub fn validate_with(
        &self,
        file: &str,
        text: &str,
        checks: &[Check],
    ) -> Result<(), ScenarioErrors> {
        let mut errs = Vec::new();
        let mut err = |path: Vec<PathStep>, message: String| {
            let (line, column) = match locate(text, &path) {
                Some(s) => {
                    let (l, c) = line_col(text, s.start);
                    (Some(l), Some(c))
                }
                None => (None, None),
            };
            errs.push(ScenarioError {
                file: file.to_owned(),
                line,
                column,
                field: path_string(&path),
                message,
            });
        };
        let net = self.network_spec_unchecked();
        for check in OWN_CHECKS.iter().chain(checks) {
            check(self, &net, &mut err);
        }
        if errs.is_empty() {
            Ok(())
        } else {
            Err(ScenarioErrors(errs))
        }
    }

    /// The index in `[[links]]` of the link named `name`.
    pub fn link_named(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| {
            l.name
                .as_deref()
                .is_some_and(|n| n.eq_ignore_ascii_case(name))
        })
    }

    /// The network the scenario describes (call after validation).
    pub fn network_spec_unchecked(&self) -> twin_core::network::NetworkSpec {
        let mut net = twin_core::network::NetworkSpec::m6p(
            &self.network.payloads,
            &self.network.ground_stations,
        );
        net.main_bitrate_bps = self.network.main_bitrate_bps;
        net.payload_bitrate_bps = self.network.payload_bitrate_bps;
        net.uhf_rate_bps = self.network.uhf_rate_bps;
        net.can_tx_queue_frames = self.network.can_tx_queue_frames;
        net.uhf_tx_buffer_bytes = self.network.uhf_tx_buffer_bytes;
        for n in &mut net.nodes {
            if let Some(o) = self.nodes.get(&n.name)
                && let Some(u) = o.uptime
            {
                n.uptime = match u {
                    UptimeKind::Libcsp => csp::service::UptimeFormat::LibcspSecondsBe,
                    UptimeKind::Icd => csp::service::UptimeFormat::IcdMillisLe,
                };
            }
        }
        net
    }
}

/// The scenario's own checks, before the twin's (see [`Scenario::validate_with`]).
const OWN_CHECKS: &[Check] = &[
    check_time,
    check_orbit,
    check_network,
    check_nodes,
    check_links,
];

/// `start`, `duration`, `[clock] speed`.
fn check_time(s: &Scenario, _: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    if twin_core::timefmt::parse_utc(&s.start).is_none() {
        err(
            vec![key("start")],
            format!("`{}` is not a UTC time like 2026-03-20T12:00:00Z", s.start),
        );
    }
    if s.duration.0.is_zero() {
        err(vec![key("duration")], "must be longer than zero".into());
    }
    if let Some(every) = s.record.snapshot_every
        && let Err(why) = check_snapshot_every(every.0, s.duration.0)
    {
        err(vec![key("record"), key("snapshot_every")], why);
    }
    if !(s.clock.speed.is_finite() && s.clock.speed > 0.0 && s.clock.speed <= 1e6) {
        err(
            vec![key("clock"), key("speed")],
            format!("{} is out of range (0, 1e6]", s.clock.speed),
        );
    }
}

/// The most snapshots a recording carries (`[record] snapshot_every`): each is about
/// 50-250 kB (docs/snapshots.md).
pub const RECORDED_SNAPSHOTS_MAX: u128 = 1000;

/// Whether a recording of a run `duration` long may carry a snapshot every `every`: at
/// least a second apart, at most [`RECORDED_SNAPSHOTS_MAX`] of them.
pub fn check_snapshot_every(every: Duration, duration: Duration) -> Result<(), String> {
    if every < Duration::from_secs(1) {
        return Err("must be at least 1s".into());
    }
    let count = duration.as_nanos() / every.as_nanos();
    if count > RECORDED_SNAPSHOTS_MAX {
        return Err(format!(
            "would carry {count} snapshots in the run's {}; at most {RECORDED_SNAPSHOTS_MAX}",
            twin_core::duration::format_duration(duration)
        ));
    }
    Ok(())
}

/// `[satellite] tle`: two lines that parse, with an epoch the FC would fly.
fn check_orbit(s: &Scenario, _: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let tle = &s.satellite.tle;
    if !tle.is_empty() && !(2..=3).contains(&tle.len()) {
        err(
            vec![key("satellite"), key("tle")],
            "give the two TLE lines (optionally after a title line)".into(),
        );
    } else if let [.., l1, l2] = tle.as_slice() {
        // Strict: checksums and layout are checked, as the FC's TLE upload would.
        match orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict) {
            Err(e) => err(
                vec![key("satellite"), key("tle")],
                format!("the TLE does not parse: {e}"),
            ),
            // The FC refuses such a TLE over ATCTLESET (SGP4's error grows by kilometres
            // a day); the twin would otherwise fly it silently, far from any real orbit.
            Ok(t) => {
                if let Some(start_ns) = twin_core::timefmt::parse_utc(&s.start) {
                    // In i128: centuries apart do not fit an i64 of nanoseconds.
                    let apart_ns = i128::from(t.epoch.unix_ns()) - i128::from(start_ns);
                    let age_s = apart_ns.unsigned_abs() as f64 * 1e-9;
                    if age_s > nodes_fc::TLE_MAX_AGE_S {
                        err(
                            vec![key("satellite"), key("tle")],
                            format!(
                                "the TLE's epoch {} is {:.1} days from `start` {}; the FC \
                                 flies a TLE at most {:.0} days from its time",
                                twin_core::timefmt::format_utc(t.epoch.unix_ns()),
                                age_s / 86_400.0,
                                s.start,
                                nodes_fc::TLE_MAX_AGE_S / 86_400.0
                            ),
                        );
                    }
                }
            }
        }
    }
}

/// `[network]`: addresses and rates.
fn check_network(s: &Scenario, _: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    for (i, &p) in s.network.payloads.iter().enumerate() {
        if !(12..=15).contains(&p) {
            err(
                vec![key("network"), key("payloads"), PathStep::Index(i)],
                format!("payload address {p} is not in 12-15"),
            );
        }
    }
    for (i, &g) in s.network.ground_stations.iter().enumerate() {
        if !(16..=20).contains(&g) {
            err(
                vec![key("network"), key("ground_stations"), PathStep::Index(i)],
                format!("ground station address {g} is not in 16-20"),
            );
        }
    }
    for (field, rate, max) in [
        ("main_bitrate_bps", s.network.main_bitrate_bps, 1_000_000),
        (
            "payload_bitrate_bps",
            s.network.payload_bitrate_bps,
            1_000_000,
        ),
        ("uhf_rate_bps", s.network.uhf_rate_bps, 10_000_000),
    ] {
        if rate == 0 || rate > max {
            err(
                vec![key("network"), key(field)],
                format!("{rate} is out of range 1..={max}"),
            );
        }
    }
    for (field, v, min, max) in [
        (
            "can_tx_queue_frames",
            s.network.can_tx_queue_frames as u64,
            33,
            65_536,
        ),
        (
            "uhf_tx_buffer_bytes",
            u64::from(s.network.uhf_tx_buffer_bytes),
            260,
            1 << 20,
        ),
    ] {
        // At least one whole packet (33 frames, 260 bytes); at most what is still a
        // bound.
        if !(min..=max).contains(&v) {
            err(
                vec![key("network"), key(field)],
                format!("{v} is out of range {min}..={max} (room for one whole packet at least)"),
            );
        }
    }
}

/// `[nodes.NAME]`: names of the network's nodes.
fn check_nodes(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let names: Vec<String> = net.nodes.iter().map(|n| n.name.clone()).collect();
    for name in s.nodes.keys() {
        if !names.contains(name) {
            err(
                vec![key("nodes"), key(name)],
                format!("unknown node `{name}` (nodes: {})", names.join(", ")),
            );
        }
    }
}

/// `[[links]]`: addresses, names and power channels (what a link does with them is the
/// twin's `outside` check).
fn check_links(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    for (i, l) in s.links.iter().enumerate() {
        let p = |f: &str| vec![key("links"), PathStep::Index(i), key(f)];
        match l.kind {
            LinkKind::KissListen | LinkKind::KissConnect => {
                if l.addr.parse::<std::net::SocketAddr>().is_err() {
                    err(
                        p("addr"),
                        format!("`{}` is not an address like 127.0.0.1:52001", l.addr),
                    );
                }
            }
            LinkKind::KissPty => {
                if l.addr.is_empty() {
                    err(p("addr"), "the path to link the pty at is empty".to_owned());
                }
            }
            LinkKind::ZmqHub => {
                if let Err(e) = l.addr.parse::<links::zmq_hub::HubAddr>() {
                    err(p("addr"), e.to_string());
                }
            }
            LinkKind::Udp => {
                if l.addr.parse::<std::net::SocketAddr>().is_err() {
                    err(
                        p("addr"),
                        format!("`{}` is not an address like 127.0.0.1:10015", l.addr),
                    );
                }
            }
            LinkKind::Uart => match (&l.pty, l.addr.is_empty()) {
                (Some(_), false) => err(
                    p("pty"),
                    "a console is on a TCP `addr` or a `pty` path, not both".to_owned(),
                ),
                (Some(path), true) if path.is_empty() => {
                    err(p("pty"), "the path to link the pty at is empty".to_owned())
                }
                (Some(_), true) => {}
                (None, _) => {
                    if l.addr.parse::<std::net::SocketAddr>().is_err() {
                        err(
                            p("addr"),
                            format!(
                                "`{}` is not an address like 127.0.0.1:5010 (or give `pty`)",
                                l.addr
                            ),
                        );
                    }
                }
            },
            LinkKind::Socketcan => {
                let bus = l.addr.split_once(':').map(|(_, b)| b);
                if l.addr.is_empty() || !matches!(bus, None | Some("main") | Some("payload")) {
                    err(
                        p("addr"),
                        format!(
                            "`{}` is not an interface like vcan0 or vcan0:payload",
                            l.addr
                        ),
                    );
                }
            }
        }
        match (&l.peer, l.kind) {
            (Some(peer), LinkKind::Udp) if peer.parse::<std::net::SocketAddr>().is_err() => err(
                p("peer"),
                format!("`{peer}` is not an address like 127.0.0.1:10016"),
            ),
            (Some(_), kind) if kind != LinkKind::Udp => {
                err(p("peer"), "only a `udp` link has a peer".to_owned())
            }
            _ => {}
        }
        if let Some(name) = &l.name {
            let taken = ["main", "payload", "uhf"]
                .iter()
                .any(|m| m.eq_ignore_ascii_case(name))
                || net.nodes.iter().any(|n| n.name.eq_ignore_ascii_case(name));
            if name.is_empty() || taken {
                err(
                    p("name"),
                    format!("`{name}` names a node or a medium: a link needs a name of its own"),
                );
            } else if s.links[..i].iter().any(|o| {
                o.name
                    .as_deref()
                    .is_some_and(|n| n.eq_ignore_ascii_case(name))
            }) {
                err(p("name"), format!("another link is named `{name}`"));
            }
        }
        if let Some(c) = &l.powered_by
            && nodes_eps::Channel::from_name(c)
                .and_then(nodes_eps::Channel::node_addr)
                .is_none()
        {
            err(
                p("powered_by"),
                format!(
                    "`{c}` is not an EPS channel that powers a node (COMM1, COMM2, ECU, PC, PL12, PL13, PL14, PL15)"
                ),
            );
        }
    }
}

/// The field a serde error is about: the key at the error's span, or the table header
/// the span lies in.
fn field_from_message(text: &str, span: Option<std::ops::Range<usize>>) -> String {
    let Some(span) = span else {
        return String::new();
    };
    let line_start = text
        .get(..span.start)
        .and_then(|t| t.rfind('\n'))
        .map_or(0, |i| i + 1);
    let line = text
        .get(line_start..)
        .and_then(|t| t.lines().next())
        .unwrap_or("");
    let before = text.get(..line_start).unwrap_or("");
    // A table header as a path: `[[ commands ]]  # note` is the array `commands`, indexed by
    // how many of its headers come up to `upto`.
    let header_path = |h: &str, upto: &str| -> Option<String> {
        let (name, array) = table_header(h)?;
        Some(if array {
            let n = upto
                .lines()
                .filter(|l| table_header(l) == Some((name.clone(), true)))
                .count();
            format!("{name}[{}]", n.saturating_sub(1))
        } else {
            name
        })
    };
    if table_header(line).is_some() {
        // The error points at a header (a missing field, say): that table, counted with it.
        let upto = text.get(..line_start + line.len()).unwrap_or(before);
        return header_path(line, upto).unwrap_or_default();
    }
    if let Some((k, _)) = line.split_once('=') {
        let header = before
            .lines()
            .rev()
            .find(|l| table_header(l).is_some())
            .and_then(|h| header_path(h, before));
        let k = k.trim().to_owned();
        return match header {
            Some(h) => format!("{h}.{k}"),
            None => k,
        };
    }
    line.trim().to_owned()
}

/// `[name]` -> (`name`, false), `[[name]]` -> (`name`, true), with spaces and a trailing
/// comment allowed; anything else -> `None`.
fn table_header(line: &str) -> Option<(String, bool)> {
    let l = line.split('#').next().unwrap_or("").trim();
    if let Some(inner) = l.strip_prefix("[[").and_then(|r| r.strip_suffix("]]")) {
        return Some((inner.trim().to_owned(), true));
    }
    let inner = l.strip_prefix('[')?.strip_suffix(']')?;
    Some((inner.trim().to_owned(), false))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A `start` centuries from the TLE's epoch (further apart than an i64 of nanoseconds
    /// holds; found by the scenario parser's fuzz target) is refused as any old TLE is.
    #[test]
    fn a_start_centuries_from_the_tles_epoch_is_refused_not_overflowed() {
        let text = "start = \"1686-04-30T18:00:00Z\"\nduration = \"5m\"\n\n[satellite]\ntle = [\n  \
            \"1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996\",\n  \
            \"2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009\",\n]\n";
        let e = Scenario::parse_with("old.toml", text, &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("satellite.tle") && e.contains("days from `start` 1686-04-30"),
            "{e}"
        );
    }

    /// `[record] snapshot_every`: a second at least, a bounded number in the run.
    #[test]
    fn snapshots_carried_by_a_recording_are_bounded_and_named_by_their_field() {
        let text =
            |every: &str| format!("duration = \"2h\"\n\n[record]\nsnapshot_every = \"{every}\"\n");
        assert!(Scenario::parse_with("s.toml", &text("30m"), &[]).is_ok());
        for (every, why) in [
            ("500ms", "must be at least 1s"),
            (
                "5s",
                "would carry 1440 snapshots in the run's 2h; at most 1000",
            ),
        ] {
            let e = Scenario::parse_with("s.toml", &text(every), &[])
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("record.snapshot_every") && e.contains(why),
                "{e}"
            );
        }
    }

    #[test]
    fn an_idle_limit_is_a_duration_of_100ms_or_more_or_off() {
        assert_eq!("OFF".parse::<IdleLimit>(), Ok(IdleLimit::Off));
        assert_eq!(
            "2m".parse::<IdleLimit>(),
            Ok(IdleLimit::After(Duration::from_secs(120)))
        );
        let e = "50ms".parse::<IdleLimit>().unwrap_err();
        assert_eq!(
            e,
            IdleLimitError::TooShort {
                text: "50ms".into()
            }
        );
        assert_eq!(e.to_string(), "`50ms`: at least 100ms, or \"off\"");
        let e = "soon".parse::<IdleLimit>().unwrap_err();
        assert!(matches!(e, IdleLimitError::NotADuration { .. }), "{e:?}");
        assert_eq!(
            e.to_string(),
            "`soon` is not a duration (try 90, 90s, 10m, 2h, 1h 30m), or \"off\""
        );
    }
}
