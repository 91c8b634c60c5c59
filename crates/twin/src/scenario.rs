//! Scenario files: one TOML file describes a run (see `docs/scenarios.md`).
//!
//! Parsing is strict: unknown fields, wrong types, out-of-range values and unknown node
//! names are errors that name the file, the line and the field. [`Scenario::parse`] checks
//! the syntax and the types (serde with `deny_unknown_fields`), then [`Scenario::validate`]
//! checks the meaning (node names, ranges, references between entries), locating every
//! problem in the source through the spanned TOML tree.

use std::collections::BTreeMap;
use std::fmt;
use std::time::Duration;

use schemars::JsonSchema;
use serde::{Deserialize, Deserializer};

use crate::duration::parse_duration;

/// A duration written as `90`, `90s`, `500ms`, `10m`, `2h` or `1d`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default, JsonSchema)]
#[schemars(
    with = "String",
    description = "a duration: 90, 90s, 500ms, 10m, 2h, 1d"
)]
pub struct Dur(pub Duration);

impl<'de> Deserialize<'de> for Dur {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Int(u64),
            Float(f64),
            Str(String),
        }
        let text = match Raw::deserialize(d)? {
            Raw::Int(i) => i.to_string(),
            Raw::Float(f) => f.to_string(),
            Raw::Str(s) => s,
        };
        parse_duration(&text)
            .map(Dur)
            .map_err(serde::de::Error::custom)
    }
}

/// A node named by name (`FC`, `PL12`, `GS16`) or by CSP address.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum NodeRef {
    /// A CSP address, 0..=30.
    Addr(u8),
    /// A node name from the network table.
    Name(String),
}

impl fmt::Display for NodeRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeRef::Addr(a) => write!(f, "{a}"),
            NodeRef::Name(n) => f.write_str(n),
        }
    }
}

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
    pub fc: FcSpec,
    /// The payload controller: sessions, S-band, events.
    #[serde(default)]
    pub pc: crate::sessions::PcSpec,
    /// The radio link to the ground: passes over the ground stations.
    #[serde(default)]
    pub comm: CommSpec,
    /// The EPS: battery state and channel switching.
    #[serde(default)]
    pub eps: EpsSpec,
    /// The simulated payloads' data and behaviour (`[[payload]]`, one per address).
    #[serde(default)]
    pub payload: Vec<crate::sessions::PayloadSpec>,
    /// The network.
    #[serde(default)]
    pub network: NetworkCfg,
    /// Per-node options, keyed by node name.
    #[serde(default)]
    pub nodes: BTreeMap<String, NodeOptions>,
    /// Links to programs outside the twin.
    #[serde(default)]
    pub links: Vec<LinkSpec>,
    /// Recording settings.
    #[serde(default)]
    pub record: RecordSpec,
    /// Requests sent during the run.
    #[serde(default)]
    pub commands: Vec<CommandSpec>,
    /// Impairments applied during the run.
    #[serde(default)]
    pub faults: Vec<FaultSpec>,
    /// What must happen.
    #[serde(default)]
    pub expectations: Vec<ExpectationSpec>,
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
}

fn one() -> f64 {
    1.0
}

impl Default for ClockSpec {
    fn default() -> Self {
        ClockSpec {
            mode: ClockKind::Virtual,
            speed: 1.0,
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

/// The flight computer's settings (docs/scenarios.md, "The FC").
#[derive(Debug, Clone, PartialEq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcSpec {
    /// ADCS loop rate, Hz (default 10).
    #[serde(default)]
    pub adcs_hz: Option<u32>,
    /// Truth and ADCS snapshot rate for recording and expectations, Hz (default 1; 0: none).
    #[serde(default)]
    pub publish_hz: Option<u32>,
    /// Target mode commanded at the start (as by ATCMDSET at time zero; default `detumble`).
    #[serde(default)]
    pub mode: Option<ModeName>,
    /// Target attitude (r, i, j, k) for the fixed-quaternion modes (as by ATCATSET).
    #[serde(default)]
    pub target_attitude: Option<[f64; 4]>,
    /// Target point (as by ATCPTSET): lat deg, lon deg, alt m for `earth-target`, an ECI
    /// direction for `eci-vector`.
    #[serde(default)]
    pub target_point: Option<[f64; 3]>,
    /// Whether the FC holds the satellite's TLE at boot (default true).
    #[serde(default)]
    pub tle_uploaded: Option<bool>,
    /// Whether the GPS receiver gives fixes (default false).
    #[serde(default)]
    pub gps: Option<bool>,
    /// Initial body rate magnitude, deg/s (default 0).
    #[serde(default)]
    pub initial_rate_deg_s: Option<f64>,
    /// Axis of the initial rate, body frame (default: a random axis drawn from the seed).
    #[serde(default)]
    pub initial_rate_axis: Option<[f64; 3]>,
    /// Initial attitude, body in ECI (r, i, j, k) (default: drawn from the seed).
    #[serde(default)]
    pub initial_attitude: Option<[f64; 4]>,
    /// Initial wheel speeds, rpm (default 0).
    #[serde(default)]
    pub initial_wheel_rpm: Option<[f64; 4]>,
    /// Inertia tensor, kg m^2, rows (default the 6U box diag(0.10, 0.13, 0.05)).
    #[serde(default)]
    pub inertia_kg_m2: Option<[[f64; 3]; 3]>,
    /// Residual magnetic dipole, body frame, A m^2 (default [0.002, 0.002, 0.005]).
    #[serde(default)]
    pub residual_dipole_am2: Option<[f64; 3]>,
    /// Aerodynamic drag torque (default true).
    #[serde(default)]
    pub drag: Option<bool>,
    /// Gravity-gradient torque (default true).
    #[serde(default)]
    pub gravity_gradient: Option<bool>,
    /// Solar panel normal for sun max power, body frame (default +X).
    #[serde(default)]
    pub panel_normal_body: Option<[f64; 3]>,
    /// Port numbers of the FC's services.
    #[serde(default)]
    pub ports: Option<FcPortsSpec>,
    /// Mission-controller script lines (ICD 1.5) submitted onboard at their times.
    #[serde(default)]
    pub scripts: Vec<FcScriptSpec>,
    /// Sensor and wheel faults.
    #[serde(default)]
    pub faults: Vec<FcFaultSpec>,
}

/// The EPS (`[eps]`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct EpsSpec {
    /// State of charge at the start, 0-1 (default 0.8).
    #[serde(default)]
    pub initial_soc: Option<f64>,
    /// Channels off at the start (`COMM1`, `COMM2`, `ECU`, `PC`, `PL12`-`PL15`, `SBAND`).
    #[serde(default)]
    pub channels_off: Vec<String>,
    /// Events (`[[eps.events]]`): `at` with `channel` and `on`, or `soc`.
    #[serde(default)]
    pub events: Vec<EpsEventSpec>,
}

/// An EPS event at a time: switch a channel (as the CHSET command would) or set the state
/// of charge.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct EpsEventSpec {
    /// When.
    pub at: Dur,
    /// The channel to switch.
    #[serde(default)]
    pub channel: Option<String>,
    /// On or off (with `channel`).
    #[serde(default)]
    pub on: Option<bool>,
    /// Set the state of charge, 0-1.
    #[serde(default)]
    pub soc: Option<f64>,
}

/// The UHF link to the ground (`[comm]`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CommSpec {
    /// Model passes: the link closes only while the satellite is above the elevation mask
    /// of a ground station (default false: always in contact, for development).
    #[serde(default)]
    pub passes: bool,
    /// Elevation mask, deg (default 10).
    #[serde(default = "default_mask_deg")]
    pub elevation_mask_deg: f64,
    /// The ground stations' sites (default: Vilnius).
    #[serde(default = "default_stations")]
    pub stations: Vec<StationSpec>,
    /// COMM's beacon period (default 60 s; `0s` switches beacons off; else 10 s to 1 h).
    #[serde(default)]
    pub beacon_period: Option<Dur>,
}

impl Default for CommSpec {
    fn default() -> Self {
        CommSpec {
            passes: false,
            elevation_mask_deg: default_mask_deg(),
            stations: default_stations(),
            beacon_period: None,
        }
    }
}

fn default_mask_deg() -> f64 {
    10.0
}

fn default_stations() -> Vec<StationSpec> {
    vec![StationSpec {
        name: "Vilnius".to_owned(),
        lat_deg: 54.6872,
        lon_deg: 25.2797,
        alt_m: 112.0,
    }]
}

/// A ground station site (WGS-84).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StationSpec {
    /// Name for logs.
    pub name: String,
    /// Geodetic latitude, deg.
    pub lat_deg: f64,
    /// Longitude, deg (east positive).
    pub lon_deg: f64,
    /// Height above the ellipsoid, m.
    #[serde(default)]
    pub alt_m: f64,
}

/// Target modes by name (docs/protocol.md, "Target modes").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum ModeName {
    /// 0.
    Idle,
    /// 1.
    Detumble,
    /// 2.
    Velocity,
    /// 3.
    Nadir,
    /// 4.
    SunMaxPower,
    /// 5.
    EarthTarget,
    /// 6.
    EciVector,
    /// 7.
    FixedEci,
    /// 8.
    FixedLvlh,
    /// 9.
    FixedTnw,
}

impl ModeName {
    /// The wire enumeration value.
    pub fn mode(self) -> nodes_fc::wire::TargetMode {
        use nodes_fc::wire::TargetMode as M;
        match self {
            ModeName::Idle => M::Idle,
            ModeName::Detumble => M::Detumble,
            ModeName::Velocity => M::VelocityPointing,
            ModeName::Nadir => M::Nadir,
            ModeName::SunMaxPower => M::SunMaxPower,
            ModeName::EarthTarget => M::EarthTarget,
            ModeName::EciVector => M::EciVector,
            ModeName::FixedEci => M::FixedEci,
            ModeName::FixedLvlh => M::FixedLvlh,
            ModeName::FixedTnw => M::FixedTnw,
        }
    }
}

/// FC port overrides (INTERPRETATION.md section 4: every port overridable).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcPortsSpec {
    /// Telemetry (default 10).
    #[serde(default)]
    pub telemetry: Option<u8>,
    /// RTC (default 11).
    #[serde(default)]
    pub rtc: Option<u8>,
    /// Attitude target control (default 12).
    #[serde(default)]
    pub attitude: Option<u8>,
    /// Mission-controller scripts (default 13).
    #[serde(default)]
    pub scripts: Option<u8>,
}

/// A script line submitted onboard at a time.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcScriptSpec {
    /// When it is submitted (simulated time since the start).
    pub at: Dur,
    /// The ICD 1.5 line, for example `adcs 1577836800 1577836920 pointECI 1 0 0 0`.
    pub line: String,
}

/// A sensor or wheel fault.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcFaultSpec {
    /// When it starts.
    pub at: Dur,
    /// When it is cleared (default: never).
    #[serde(default)]
    pub until: Option<Dur>,
    /// The sensor: `gyro`, `magnetometer`, `sun-sensors`, `css+x` ... `css-z`,
    /// `accelerometer`, `gps`.
    #[serde(default)]
    pub sensor: Option<String>,
    /// The wheel, 0-3.
    #[serde(default)]
    pub wheel: Option<u8>,
    /// Sensors: `dead`, `stuck`, `bias:<value>`, `noisy:<factor>`; wheels: `stuck`, `off`.
    pub fault: String,
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
        }
    }
}

/// Options of one node.
#[derive(Debug, Clone, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NodeOptions {
    /// Uptime service format: `libcsp` (u32 BE seconds) or `icd` (u32 LE milliseconds).
    #[serde(default)]
    pub uptime: Option<UptimeKind>,
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
    /// `kiss-listen`, `kiss-connect` or `socketcan`.
    pub kind: LinkKind,
    /// TCP address (KISS) or interface name with an optional `:main`/`:payload` (SocketCAN).
    pub addr: String,
    /// CSP addresses behind the link (default: learned from its packets).
    #[serde(default)]
    pub addrs: Vec<u8>,
    /// Apply libcsp 1.4's 248-byte KISS receive limit.
    #[serde(default)]
    pub libcsp14_rx_limit: bool,
}

/// Link kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum LinkKind {
    /// Listen for outside nodes speaking KISS over TCP.
    KissListen,
    /// Connect to an outside KISS/TCP server.
    KissConnect,
    /// Bridge to a SocketCAN interface.
    Socketcan,
}

/// Recording settings.
#[derive(Debug, Clone, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RecordSpec {
    /// MCAP file to write (relative to the working directory); none = no recording.
    #[serde(default)]
    pub file: Option<String>,
}

/// A request sent during the run.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CommandSpec {
    /// Name for expectations and reports (default `commands[i]`).
    #[serde(default)]
    pub name: Option<String>,
    /// When to send it: simulated time since the start, or, with `after`, since that
    /// command's first outcome.
    pub at: Dur,
    /// Send it only after the first outcome (reply or timeout) of this command, which must
    /// come from the same ground station.
    #[serde(default)]
    pub after: Option<String>,
    /// Repeat every this long (with `count`).
    #[serde(default)]
    pub every: Option<Dur>,
    /// How many times in all (default 1; with `every`).
    #[serde(default)]
    pub count: Option<u32>,
    /// The sending node (a ground station; default GS16).
    #[serde(default)]
    pub from: Option<NodeRef>,
    /// The destination node.
    pub to: NodeRef,
    /// `ping`, `uptime`, `ident`, `memfree`, `buf-free`, `ps`, `reboot` or `raw`.
    pub request: RequestKind,
    /// Ping payload size in bytes (default 16).
    #[serde(default)]
    pub size: Option<usize>,
    /// Destination port (`raw` only).
    #[serde(default)]
    pub port: Option<u8>,
    /// Request bytes as hex (`raw` only), for example `"01"` or `"06 01 00"`.
    #[serde(default)]
    pub data: Option<String>,
    /// Request bytes as text (`raw` only, instead of `data`), for example an ICD 1.5 script
    /// line for FC port 13.
    #[serde(default)]
    pub text: Option<String>,
    /// How long to wait for the reply.
    #[serde(default)]
    pub timeout: Option<Dur>,
}

/// Request kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum RequestKind {
    /// CSP ping (port 1).
    Ping,
    /// CSP uptime (port 6).
    Uptime,
    /// CMP ident (port 0).
    Ident,
    /// CSP memfree (port 3).
    Memfree,
    /// CSP buf_free (port 5).
    BufFree,
    /// CSP ps (port 2).
    Ps,
    /// CSP reboot (port 4, magic 0x80078007).
    Reboot,
    /// Raw bytes to a port.
    Raw,
}

/// An impairment applied at `at` (and lifted at `until`, if given).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FaultSpec {
    /// When it starts.
    pub at: Dur,
    /// When it ends (default: never).
    #[serde(default)]
    pub until: Option<Dur>,
    /// `drop`, `corrupt`, `delay`, `link-down`, `power-off`, `reboot` or `hang`.
    pub kind: FaultKind,
    /// Medium (`main`, `payload`, `uhf`) for link faults; node for node faults.
    pub target: NodeRef,
    /// Probability for `drop` and `corrupt`.
    #[serde(default)]
    pub probability: Option<f64>,
    /// Extra delay for `delay`.
    #[serde(default)]
    pub delay: Option<Dur>,
}

/// Fault kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// Lose frames or packets with a probability.
    Drop,
    /// Flip one bit of frames or packets with a probability.
    Corrupt,
    /// Delay every frame or packet.
    Delay,
    /// The medium carries nothing.
    LinkDown,
    /// The node is powered off (back on at `until`).
    PowerOff,
    /// The node reboots.
    Reboot,
    /// The node is alive on the bus but silent (until `until`).
    Hang,
}

/// Something that must happen.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ExpectationSpec {
    /// Name for reports (default `expectations[i]`).
    #[serde(default)]
    pub name: Option<String>,
    /// What is checked: `reply`, `no-reply`, `counter`, `attitude`, `power`, `beacon`,
    /// `session`, `downlink` or `accounting` (docs/scenarios.md).
    pub kind: ExpectKind,
    /// The command (by name) for `reply` and `no-reply`.
    #[serde(default)]
    pub command: Option<String>,
    /// For repeated commands: `every` occurrence must hold (default), or `any`; for
    /// `attitude`: every selected sample (default), or `any` one.
    #[serde(default)]
    pub occurrence: Option<Occurrence>,
    /// Longest acceptable round trip for `reply`.
    #[serde(default)]
    pub within: Option<Dur>,
    /// Result code (second reply byte) for ICD requests.
    #[serde(default)]
    pub result: Option<u8>,
    /// Exact reply bytes as hex.
    #[serde(default)]
    pub data: Option<String>,
    /// Reply length in bytes.
    #[serde(default)]
    pub data_len: Option<usize>,
    /// The node or medium of a `counter`.
    #[serde(default)]
    pub target: Option<NodeRef>,
    /// Counter name: node `rx_packets`, `tx_packets`, `forwarded`, `delivered`, `reboots`,
    /// `drops`, `drops.<reason>`; medium `frames`, `bytes`, `dropped`, `corrupted`.
    #[serde(default)]
    pub counter: Option<String>,
    /// Smallest acceptable counter value at the end of the run.
    #[serde(default)]
    pub min: Option<u64>,
    /// Largest acceptable counter value at the end of the run.
    #[serde(default)]
    pub max: Option<u64>,
    /// The figure an `attitude` expectation checks (see [`ATTITUDE_QUANTITIES`]).
    #[serde(default)]
    pub quantity: Option<String>,
    /// Every sample in the window must be below this.
    #[serde(default)]
    pub below: Option<f64>,
    /// Every sample in the window must be above this.
    #[serde(default)]
    pub above: Option<f64>,
    /// Start of the window (default: the start of the run).
    #[serde(default)]
    pub from: Option<Dur>,
    /// End of the window (default: the end of the run).
    #[serde(default)]
    pub to: Option<Dur>,
    /// Which samples count: `always` (default), `sunlit`, `eclipse`, `target-visible`.
    #[serde(default)]
    pub when: Option<When>,
    /// Elevation for `target-visible`, deg (default 10).
    #[serde(default)]
    pub min_elevation_deg: Option<f64>,
    /// The PC session of a `session` or `downlink` expectation (its id).
    #[serde(default)]
    pub session: Option<u8>,
    /// `session`: the result every (or any) run of the session ended with: `done`,
    /// `aborted`, `no-ack`, `s-band-failure`.
    #[serde(default)]
    pub session_result: Option<SessionResultName>,
    /// `downlink`: the downlinked bytes, cut into the payload's counter frames, check
    /// without a damaged frame (and, for `true`, without a missing sequence number).
    #[serde(default)]
    pub intact: Option<bool>,
    /// `accounting`: the payload (default every simulated payload).
    #[serde(default)]
    pub payload: Option<u8>,
    /// `power`: what `below`/`above` bound: `every` sample (default), or the window's
    /// `mean`, `min` or `max`.
    #[serde(default)]
    pub statistic: Option<Statistic>,
}

/// Which figure of a window a `power` expectation bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Statistic {
    /// Every sample.
    Every,
    /// The time mean over the window.
    Mean,
    /// The smallest sample.
    Min,
    /// The largest sample.
    Max,
}

/// The figures a `power` expectation can check (each EPS sample).
pub const POWER_QUANTITIES: &[&str] = &[
    "soc",
    "battery_v",
    "battery_a",
    "solar_w",
    "load_w",
    "net_w",
];

/// Session results by name (ICD 3.1.6 table 3).
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
}

impl SessionResultName {
    /// The wire value.
    pub fn value(self) -> u8 {
        self as u8
    }
}

/// The figures an `attitude` expectation can check (each published FC snapshot).
pub const ATTITUDE_QUANTITIES: &[&str] = &[
    "rate_deg_s",
    "pointing_error_deg",
    "axis_error_deg",
    "estimation_error_deg",
    "max_wheel_rpm",
    "mode",
    "state",
    "tle_offset_m",
];

/// Which samples an `attitude` expectation looks at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum When {
    /// Every sample.
    Always,
    /// Sun fully visible.
    Sunlit,
    /// Sun not visible at all.
    Eclipse,
    /// The ground target at or above `min_elevation_deg`.
    TargetVisible,
}

/// Expectation kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum ExpectKind {
    /// The command is answered (within `within`, with `result`/`data` if given).
    Reply,
    /// The command is not answered.
    NoReply,
    /// A counter is within `min`..=`max` at the end of the run.
    Counter,
    /// Every FC snapshot in a window has a figure below / above a bound.
    Attitude,
    /// A PC session's runs ended with a result (and a packet count within `min`..`max`).
    Session,
    /// A PC session downlinked `min`..`max` bytes over the run (intact, if asked).
    Downlink,
    /// Every byte a payload produced was downlinked, dropped with a reason, or is still
    /// held by the PC at the end (at most `max` dropped, if given).
    Accounting,
    /// EPS samples in a window (each, or their mean, min or max) below / above a bound.
    Power,
    /// Beacons reach the ground at least every `within` while in contact (and `min`..`max`
    /// of them over the run).
    Beacon,
}

/// Which occurrences of a repeated command an expectation covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Occurrence {
    /// Every occurrence must satisfy it.
    Every,
    /// At least one must.
    Any,
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

fn line_col(text: &str, offset: usize) -> (usize, usize) {
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

fn path_string(path: &[PathStep]) -> String {
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
fn locate(text: &str, path: &[PathStep]) -> Option<std::ops::Range<usize>> {
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
    /// Parse and validate a scenario; `file` names it in errors.
    pub fn parse(file: &str, text: &str) -> Result<Scenario, ScenarioErrors> {
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
        scenario.validate(file, text)?;
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

    /// Check the meaning of every field, reporting all problems with their location.
    pub fn validate(&self, file: &str, text: &str) -> Result<(), ScenarioErrors> {
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
        if crate::timefmt::parse_utc(&self.start).is_none() {
            err(
                vec![key("start")],
                format!(
                    "`{}` is not a UTC time like 2026-03-20T12:00:00Z",
                    self.start
                ),
            );
        }
        if self.duration.0.is_zero() {
            err(vec![key("duration")], "must be longer than zero".into());
        }
        if !(self.clock.speed.is_finite() && self.clock.speed > 0.0 && self.clock.speed <= 1e6) {
            err(
                vec![key("clock"), key("speed")],
                format!("{} is out of range (0, 1e6]", self.clock.speed),
            );
        }
        let tle = &self.satellite.tle;
        if !tle.is_empty() && !(2..=3).contains(&tle.len()) {
            err(
                vec![key("satellite"), key("tle")],
                "give the two TLE lines (optionally after a title line)".into(),
            );
        } else if let [.., l1, l2] = tle.as_slice() {
            // Strict: checksums and layout are checked, as the FC's TLE upload would.
            if let Err(e) = orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict) {
                err(
                    vec![key("satellite"), key("tle")],
                    format!("the TLE does not parse: {e}"),
                );
            }
        }
        for (i, &p) in self.network.payloads.iter().enumerate() {
            if !(12..=15).contains(&p) {
                err(
                    vec![key("network"), key("payloads"), PathStep::Index(i)],
                    format!("payload address {p} is not in 12-15"),
                );
            }
        }
        for (i, &g) in self.network.ground_stations.iter().enumerate() {
            if !(16..=20).contains(&g) {
                err(
                    vec![key("network"), key("ground_stations"), PathStep::Index(i)],
                    format!("ground station address {g} is not in 16-20"),
                );
            }
        }
        for (field, rate, max) in [
            ("main_bitrate_bps", self.network.main_bitrate_bps, 1_000_000),
            (
                "payload_bitrate_bps",
                self.network.payload_bitrate_bps,
                1_000_000,
            ),
            ("uhf_rate_bps", self.network.uhf_rate_bps, 10_000_000),
        ] {
            if rate == 0 || rate > max {
                err(
                    vec![key("network"), key(field)],
                    format!("{rate} is out of range 1..={max}"),
                );
            }
        }
        let net = self.network_spec_unchecked();
        let names: Vec<String> = net.nodes.iter().map(|n| n.name.clone()).collect();
        for name in self.nodes.keys() {
            if !names.contains(name) {
                err(
                    vec![key("nodes"), key(name)],
                    format!("unknown node `{name}` (nodes: {})", names.join(", ")),
                );
            }
        }
        for (i, l) in self.links.iter().enumerate() {
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
            for (j, &a) in l.addrs.iter().enumerate() {
                if a >= 31 {
                    err(
                        vec![
                            key("links"),
                            PathStep::Index(i),
                            key("addrs"),
                            PathStep::Index(j),
                        ],
                        format!("{a} is not a unicast CSP address"),
                    );
                }
            }
        }
        let mut command_names = Vec::new();
        // The sending station, GS16 when not given.
        let station = |c: &CommandSpec| c.from.as_ref().map_or(Some(16), |r| net.resolve(r).ok());
        for (i, c) in self.commands.iter().enumerate() {
            if let Some(a) = &c.after {
                let own = c.name.clone().unwrap_or_else(|| format!("commands[{i}]"));
                match self
                    .commands
                    .iter()
                    .enumerate()
                    .find(|(j, o)| o.name.clone().unwrap_or_else(|| format!("commands[{j}]")) == *a)
                {
                    None => err(
                        vec![key("commands"), PathStep::Index(i), key("after")],
                        format!("no command is named `{a}`"),
                    ),
                    Some(_) if *a == own => err(
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
        for (i, c) in self.commands.iter().enumerate() {
            let p = |f: &str| vec![key("commands"), PathStep::Index(i), key(f)];
            let name = c.name.clone().unwrap_or_else(|| format!("commands[{i}]"));
            if command_names.contains(&name) {
                err(
                    p("name"),
                    format!("another command is already named `{name}`"),
                );
            }
            command_names.push(name);
            match c.from.as_ref().map(|r| net.resolve(r)) {
                None => {
                    if !net
                        .nodes
                        .iter()
                        .any(|n| n.role == crate::network::Role::Ground)
                    {
                        err(p("to"), "there is no ground station to send from (network.ground_stations is empty)".into());
                    }
                }
                Some(Err(e)) => err(p("from"), e),
                Some(Ok(a)) if !(16..=20).contains(&a) => err(
                    p("from"),
                    format!("commands are sent from a ground station (16-20), not from {a}"),
                ),
                Some(Ok(_)) => {}
            }
            match &c.to {
                NodeRef::Addr(a) if *a >= 31 => {
                    err(p("to"), format!("{a} is not a unicast CSP address"))
                }
                NodeRef::Addr(_) => {}
                r @ NodeRef::Name(_) => {
                    if let Err(e) = net.resolve(r) {
                        err(p("to"), e);
                    }
                }
            }
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
            let raw = c.request == RequestKind::Raw;
            if raw && c.port.is_none() {
                err(p("request"), "a `raw` request needs `port`".into());
            }
            if !raw && (c.port.is_some() || c.data.is_some() || c.text.is_some()) {
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
                err(p("data"), e);
            }
            if c.size.is_some() && c.request != RequestKind::Ping {
                err(p("size"), "only a `ping` takes `size`".into());
            }
            if c.size.is_some_and(|s| s > 256) {
                err(
                    p("size"),
                    format!("{} bytes exceed the CSP MTU of 256", c.size.unwrap_or(0)),
                );
            }
        }
        for (i, f) in self.faults.iter().enumerate() {
            let p = |n: &str| vec![key("faults"), PathStep::Index(i), key(n)];
            if f.until.is_some_and(|u| u <= f.at) {
                err(p("until"), "must be after `at`".into());
            }
            let medium = matches!(
                f.kind,
                FaultKind::Drop | FaultKind::Corrupt | FaultKind::Delay | FaultKind::LinkDown
            );
            if medium {
                if !matches!(&f.target, NodeRef::Name(n) if ["main", "payload", "uhf"].contains(&n.as_str()))
                {
                    err(
                        p("target"),
                        format!("`{}` is not a medium (main, payload, uhf)", f.target),
                    );
                }
            } else if let Err(e) = net.resolve(&f.target) {
                err(p("target"), e);
            }
            let needs_prob = matches!(f.kind, FaultKind::Drop | FaultKind::Corrupt);
            match f.probability {
                Some(x) if !needs_prob => err(
                    p("probability"),
                    format!("a `{:?}` fault takes no probability (got {x})", f.kind),
                ),
                Some(x) if !(0.0..=1.0).contains(&x) => {
                    err(p("probability"), format!("{x} is not in 0..=1"))
                }
                None if needs_prob => err(p("kind"), "this fault needs `probability`".into()),
                _ => {}
            }
            match (f.kind, f.delay) {
                (FaultKind::Delay, None) => err(p("kind"), "a `delay` fault needs `delay`".into()),
                (FaultKind::Delay, Some(_)) | (_, None) => {}
                (_, Some(_)) => err(p("delay"), "only a `delay` fault takes `delay`".into()),
            }
            if f.kind == FaultKind::Reboot && f.until.is_some() {
                err(p("until"), "a reboot is instantaneous".into());
            }
        }
        self.validate_fc(&mut err);
        crate::sessions::validate(self, &mut err);
        let e = &self.eps;
        if e.initial_soc
            .is_some_and(|x| !(x.is_finite() && (0.0..=1.0).contains(&x)))
        {
            err(vec![key("eps"), key("initial_soc")], "must be 0-1".into());
        }
        let channel_names = "COMM1, COMM2, ECU, PC, PL12, PL13, PL14, PL15, SBAND";
        for (i, c) in e.channels_off.iter().enumerate() {
            if nodes_eps::Channel::from_name(c).is_none() {
                err(
                    vec![key("eps"), key("channels_off"), PathStep::Index(i)],
                    format!("unknown channel `{c}` ({channel_names})"),
                );
            }
        }
        for (i, ev) in e.events.iter().enumerate() {
            let q = |n: &str| vec![key("eps"), key("events"), PathStep::Index(i), key(n)];
            match (&ev.channel, ev.on, ev.soc) {
                (Some(c), Some(_), None) => {
                    if nodes_eps::Channel::from_name(c).is_none() {
                        err(
                            q("channel"),
                            format!("unknown channel `{c}` ({channel_names})"),
                        );
                    }
                }
                (None, None, Some(x)) => {
                    if !(x.is_finite() && (0.0..=1.0).contains(&x)) {
                        err(q("soc"), "must be 0-1".into());
                    }
                }
                _ => err(
                    q("at"),
                    "an EPS event is `channel` with `on`, or `soc`".into(),
                ),
            }
        }
        let c = &self.comm;
        if !(c.elevation_mask_deg.is_finite() && (-5.0..=80.0).contains(&c.elevation_mask_deg)) {
            err(
                vec![key("comm"), key("elevation_mask_deg")],
                "must be -5 to 80 deg".into(),
            );
        }
        if let Some(p) = c.beacon_period
            && !p.0.is_zero()
            && !(Duration::from_secs(10)..=Duration::from_secs(3600)).contains(&p.0)
        {
            err(
                vec![key("comm"), key("beacon_period")],
                "must be 0 (off) or 10 s to 1 h".into(),
            );
        }
        if c.passes && c.stations.is_empty() {
            err(
                vec![key("comm"), key("stations")],
                "pass modelling needs at least one station".into(),
            );
        }
        for (i, st) in c.stations.iter().enumerate() {
            let q = |n: &str| vec![key("comm"), key("stations"), PathStep::Index(i), key(n)];
            if !(st.lat_deg.is_finite() && (-90.0..=90.0).contains(&st.lat_deg)) {
                err(q("lat_deg"), "must be -90 to 90".into());
            }
            if !(st.lon_deg.is_finite() && (-180.0..=360.0).contains(&st.lon_deg)) {
                err(q("lon_deg"), "must be -180 to 360".into());
            }
            if !(st.alt_m.is_finite() && (-500.0..=10_000.0).contains(&st.alt_m)) {
                err(q("alt_m"), "must be -500 to 10000 m".into());
            }
        }
        if c.passes && self.satellite.tle.len() < 2 {
            err(
                vec![key("comm"), key("passes")],
                "pass modelling needs the satellite's TLE ([satellite] tle)".into(),
            );
        }
        for (i, x) in self.expectations.iter().enumerate() {
            let p = |n: &str| vec![key("expectations"), PathStep::Index(i), key(n)];
            let allowed = accepted_fields(x.kind);
            for (f, present) in given_fields(x) {
                if present && !allowed.contains(&f) {
                    err(
                        p(f),
                        format!(
                            "a `{}` expectation takes no `{f}` (it takes {})",
                            kebab(x.kind),
                            allowed.join(", ")
                        ),
                    );
                }
            }
            if let Some(from) = x.from
                && from.0 >= self.duration.0
            {
                err(
                    p("from"),
                    format!(
                        "the window starts at or after the end of the run ({})",
                        crate::duration::format_duration(self.duration.0)
                    ),
                );
            }
            match x.kind {
                ExpectKind::Beacon => {
                    if x.within.is_none() && x.min.is_none() && x.max.is_none() {
                        err(
                            p("kind"),
                            "a `beacon` expectation needs `within`, `min` or `max`".into(),
                        );
                    }
                    if let Some(r) = &x.target
                        && !matches!(
                            net.resolve(r),
                            Ok(crate::network::COMM1 | crate::network::COMM2)
                        )
                    {
                        err(
                            p("target"),
                            "a `beacon` expectation's `target` is the sending COMM: COMM1 or COMM2"
                                .into(),
                        );
                    }
                    if let (Some(a), Some(b)) = (x.from, x.to)
                        && b <= a
                    {
                        err(p("to"), "must be after `from`".into());
                    }
                }
                ExpectKind::Power => {
                    match &x.quantity {
                        None => err(p("kind"), "a `power` expectation needs `quantity`".into()),
                        Some(q) if !POWER_QUANTITIES.contains(&q.as_str()) => err(
                            p("quantity"),
                            format!("unknown quantity `{q}` ({})", POWER_QUANTITIES.join(", ")),
                        ),
                        Some(_) => {}
                    }
                    if x.below.is_none() && x.above.is_none() {
                        err(
                            p("kind"),
                            "a `power` expectation needs `below` or `above`".into(),
                        );
                    }
                    if x.when == Some(When::TargetVisible) {
                        err(
                            p("when"),
                            "a `power` expectation takes `always`, `sunlit` or `eclipse`".into(),
                        );
                    }
                    if let (Some(a), Some(b)) = (x.from, x.to)
                        && b <= a
                    {
                        err(p("to"), "must be after `from`".into());
                    }
                }
                ExpectKind::Session | ExpectKind::Downlink | ExpectKind::Accounting => {
                    crate::sessions::validate_expectation(self, x, &p, &mut err);
                }
                ExpectKind::Reply | ExpectKind::NoReply => {
                    match &x.command {
                        None => err(p("kind"), "this expectation needs `command`".into()),
                        Some(c) if !command_names.contains(c) => err(
                            p("command"),
                            format!(
                                "no command is named `{c}` (commands: {})",
                                command_names.join(", ")
                            ),
                        ),
                        Some(_) => {}
                    }
                    if let Some(d) = &x.data
                        && let Err(e) = ReplyPattern::parse(d)
                    {
                        err(p("data"), e);
                    }
                }
                ExpectKind::Attitude => {
                    match &x.quantity {
                        None => err(
                            p("kind"),
                            "an `attitude` expectation needs `quantity`".into(),
                        ),
                        Some(q) if !ATTITUDE_QUANTITIES.contains(&q.as_str()) => err(
                            p("quantity"),
                            format!(
                                "unknown quantity `{q}` ({})",
                                ATTITUDE_QUANTITIES.join(", ")
                            ),
                        ),
                        Some(_) => {}
                    }
                    if x.below.is_none() && x.above.is_none() {
                        err(
                            p("kind"),
                            "an `attitude` expectation needs `below` or `above`".into(),
                        );
                    }
                    for (f, v) in [("below", x.below), ("above", x.above)] {
                        if v.is_some_and(|v| !v.is_finite()) {
                            err(p(f), "must be a finite number".into());
                        }
                    }
                    if let (Some(a), Some(b)) = (x.from, x.to)
                        && b <= a
                    {
                        err(p("to"), "must be after `from`".into());
                    }
                    if x.min_elevation_deg.is_some() && x.when != Some(When::TargetVisible) {
                        err(
                            p("min_elevation_deg"),
                            "only `when = \"target-visible\"` takes `min_elevation_deg`".into(),
                        );
                    }
                }
                ExpectKind::Counter => {
                    match &x.target {
                        None => err(p("kind"), "a `counter` expectation needs `target`".into()),
                        Some(NodeRef::Name(n))
                            if ["main", "payload", "ground"].contains(&n.as_str()) =>
                        {
                            if let Some(c) = &x.counter
                                && !MEDIUM_COUNTERS.contains(&c.as_str())
                            {
                                err(
                                    p("counter"),
                                    format!(
                                        "unknown medium counter `{c}` ({})",
                                        MEDIUM_COUNTERS.join(", ")
                                    ),
                                );
                            }
                        }
                        Some(r) => {
                            if let Err(e) = net.resolve(r) {
                                err(p("target"), e);
                            }
                            if let Some(c) = &x.counter
                                && !NODE_COUNTERS.contains(&c.as_str())
                                && !c.starts_with("drops.")
                            {
                                err(
                                    p("counter"),
                                    format!(
                                        "unknown node counter `{c}` ({}, drops.<reason>)",
                                        NODE_COUNTERS.join(", ")
                                    ),
                                );
                            }
                        }
                    }
                    if x.counter.is_none() {
                        err(p("kind"), "a `counter` expectation needs `counter`".into());
                    }
                    if x.min.is_none() && x.max.is_none() {
                        err(
                            p("kind"),
                            "a `counter` expectation needs `min` or `max`".into(),
                        );
                    }
                    if let (Some(a), Some(b)) = (x.min, x.max)
                        && a > b
                    {
                        err(p("min"), format!("min {a} is above max {b}"));
                    }
                }
            }
        }
        if errs.is_empty() {
            Ok(())
        } else {
            Err(ScenarioErrors(errs))
        }
    }

    /// Check the `[fc]` table.
    fn validate_fc(&self, err: &mut impl FnMut(Vec<PathStep>, String)) {
        let fc = &self.fc;
        let p = |n: &str| vec![key("fc"), key(n)];
        if fc.adcs_hz.is_some_and(|h| !(1..=100).contains(&h)) {
            err(p("adcs_hz"), "must be 1-100".into());
        }
        if let Some(h) = fc.publish_hz
            && h > fc.adcs_hz.unwrap_or(10)
        {
            err(p("publish_hz"), "must not exceed `adcs_hz`".into());
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let nonzero = |v: &[f64]| finite(v) && v.iter().any(|x| *x != 0.0);
        if fc
            .initial_rate_deg_s
            .is_some_and(|r| !(r.is_finite() && (0.0..=360.0).contains(&r)))
        {
            err(p("initial_rate_deg_s"), "must be 0-360 deg/s".into());
        }
        for (f, v) in [
            (
                "initial_rate_axis",
                fc.initial_rate_axis.map(|a| a.to_vec()),
            ),
            ("initial_attitude", fc.initial_attitude.map(|a| a.to_vec())),
            ("target_attitude", fc.target_attitude.map(|a| a.to_vec())),
            (
                "panel_normal_body",
                fc.panel_normal_body.map(|a| a.to_vec()),
            ),
        ] {
            if v.is_some_and(|v| !nonzero(&v)) {
                err(p(f), "must be finite and not all zero".into());
            }
        }
        for (f, v) in [
            (
                "initial_wheel_rpm",
                fc.initial_wheel_rpm.map(|a| a.to_vec()),
            ),
            (
                "residual_dipole_am2",
                fc.residual_dipole_am2.map(|a| a.to_vec()),
            ),
            ("target_point", fc.target_point.map(|a| a.to_vec())),
        ] {
            if v.is_some_and(|v| !finite(&v)) {
                err(p(f), "must be finite".into());
            }
        }
        if let Some(rpm) = fc.initial_wheel_rpm
            && rpm.iter().any(|r| r.abs() > 6000.0)
        {
            err(
                p("initial_wheel_rpm"),
                "the wheels' limit is 6000 rpm".into(),
            );
        }
        if let Some(m) = fc.inertia_kg_m2 {
            let i = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
            let symmetric = (i - i.transpose()).abs().max() <= 1e-12 * i.abs().max();
            let positive = i.iter().all(|x| x.is_finite())
                && symmetric
                && i.symmetric_eigenvalues().iter().all(|&e| e > 0.0);
            if !positive {
                err(
                    p("inertia_kg_m2"),
                    "must be a symmetric positive-definite 3x3 matrix (rows)".into(),
                );
            }
        }
        for (i, sc) in fc.scripts.iter().enumerate() {
            if let Err(e) = nodes_fc::scripts::Script::parse(&sc.line) {
                err(
                    vec![key("fc"), key("scripts"), PathStep::Index(i), key("line")],
                    format!("the script does not parse: {e}"),
                );
            }
        }
        for (i, f) in fc.faults.iter().enumerate() {
            let q = |n: &str| vec![key("fc"), key("faults"), PathStep::Index(i), key(n)];
            if f.until.is_some_and(|u| u <= f.at) {
                err(q("until"), "must be after `at`".into());
            }
            match (&f.sensor, f.wheel) {
                (Some(name), None) => {
                    if let Err(e) = name.parse::<nodes_fc::sensors::SensorId>() {
                        err(q("sensor"), e.to_string());
                    }
                    if let Err(e) = f.fault.parse::<nodes_fc::sensors::SensorFault>() {
                        err(q("fault"), e.to_string());
                    }
                }
                (None, Some(w)) => {
                    if w > 3 {
                        err(q("wheel"), format!("wheel {w} is not 0-3"));
                    }
                    if let Err(e) = f.fault.parse::<nodes_fc::WheelFault>() {
                        err(q("fault"), e);
                    }
                }
                _ => err(
                    q("fault"),
                    "give exactly one of `sensor` and `wheel`".into(),
                ),
            }
        }
    }

    /// The network the scenario describes (call after validation).
    pub fn network_spec_unchecked(&self) -> crate::network::NetworkSpec {
        let mut net =
            crate::network::NetworkSpec::m6p(&self.network.payloads, &self.network.ground_stations);
        net.main_bitrate_bps = self.network.main_bitrate_bps;
        net.payload_bitrate_bps = self.network.payload_bitrate_bps;
        net.uhf_rate_bps = self.network.uhf_rate_bps;
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

/// Node counters an expectation can name.
pub const NODE_COUNTERS: &[&str] = &[
    "rx_packets",
    "tx_packets",
    "forwarded",
    "delivered",
    "service_replies",
    "reboots",
    "drops",
];
/// Medium counters an expectation can name.
pub const MEDIUM_COUNTERS: &[&str] = &[
    "frames",
    "packets",
    "bytes",
    "dropped",
    "corrupted",
    "no_contact",
];

/// The optional fields an expectation of `kind` takes (`name` and `kind` always).
fn accepted_fields(kind: ExpectKind) -> &'static [&'static str] {
    match kind {
        ExpectKind::Reply => &[
            "command",
            "occurrence",
            "within",
            "result",
            "data",
            "data_len",
        ],
        ExpectKind::NoReply => &["command", "occurrence"],
        ExpectKind::Counter => &["target", "counter", "min", "max"],
        ExpectKind::Attitude => &[
            "quantity",
            "occurrence",
            "below",
            "above",
            "from",
            "to",
            "when",
            "min_elevation_deg",
        ],
        ExpectKind::Session => &["session", "session_result", "occurrence", "min", "max"],
        ExpectKind::Downlink => &["session", "intact", "min", "max"],
        ExpectKind::Accounting => &["payload", "max"],
        ExpectKind::Power => &[
            "quantity",
            "statistic",
            "below",
            "above",
            "from",
            "to",
            "when",
        ],
        ExpectKind::Beacon => &["within", "min", "max", "target", "from", "to"],
    }
}

/// Every optional field of an expectation, with whether the scenario gives it.
fn given_fields(x: &ExpectationSpec) -> [(&'static str, bool); 22] {
    [
        ("command", x.command.is_some()),
        ("occurrence", x.occurrence.is_some()),
        ("within", x.within.is_some()),
        ("result", x.result.is_some()),
        ("data", x.data.is_some()),
        ("data_len", x.data_len.is_some()),
        ("target", x.target.is_some()),
        ("counter", x.counter.is_some()),
        ("min", x.min.is_some()),
        ("max", x.max.is_some()),
        ("quantity", x.quantity.is_some()),
        ("below", x.below.is_some()),
        ("above", x.above.is_some()),
        ("from", x.from.is_some()),
        ("to", x.to.is_some()),
        ("when", x.when.is_some()),
        ("min_elevation_deg", x.min_elevation_deg.is_some()),
        ("session", x.session.is_some()),
        ("session_result", x.session_result.is_some()),
        ("intact", x.intact.is_some()),
        ("payload", x.payload.is_some()),
        ("statistic", x.statistic.is_some()),
    ]
}

fn kebab(k: ExpectKind) -> &'static str {
    match k {
        ExpectKind::Reply => "reply",
        ExpectKind::NoReply => "no-reply",
        ExpectKind::Counter => "counter",
        ExpectKind::Attitude => "attitude",
        ExpectKind::Session => "session",
        ExpectKind::Downlink => "downlink",
        ExpectKind::Accounting => "accounting",
        ExpectKind::Power => "power",
        ExpectKind::Beacon => "beacon",
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

/// An expected reply: hex bytes where `??` stands for any byte, and a final `...` for any
/// further bytes (`"01 01 02 01 ..."`: a TMCOMM reply from COMM2 with its radio active).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplyPattern {
    /// Each byte, `None` for any.
    pub bytes: Vec<Option<u8>>,
    /// Whether more bytes may follow.
    pub open_end: bool,
}

impl ReplyPattern {
    /// Parse `"01 ?? ff ..."`.
    pub fn parse(s: &str) -> Result<Self, String> {
        let compact: String = s.chars().filter(|c| !c.is_whitespace()).collect();
        let (body, open_end) = match compact.strip_suffix("...") {
            Some(b) => (b.to_owned(), true),
            None => (compact, false),
        };
        if body.len() % 2 != 0 {
            return Err(format!("`{s}` is not hex bytes: an odd number of digits"));
        }
        let bytes = (0..body.len() / 2)
            .map(|i| match &body[2 * i..2 * i + 2] {
                "??" => Ok(None),
                pair => u8::from_str_radix(pair, 16)
                    .map(Some)
                    .map_err(|_| format!("`{s}` is not hex bytes: `{pair}` (use ?? for any byte)")),
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
pub fn parse_hex(s: &str) -> Result<Vec<u8>, String> {
    let compact: String = s.chars().filter(|c| !c.is_whitespace()).collect();
    hex::decode(&compact).map_err(|e| format!("`{s}` is not hex bytes: {e}"))
}

impl crate::network::NetworkSpec {
    /// The address of a node reference, or an error naming the known nodes.
    pub fn resolve(&self, r: &NodeRef) -> Result<u8, String> {
        match r {
            NodeRef::Addr(a) => self
                .nodes
                .iter()
                .find(|n| n.addr == *a)
                .map(|n| n.addr)
                .ok_or_else(|| format!("no node has address {a}")),
            NodeRef::Name(name) => self
                .nodes
                .iter()
                .find(|n| n.name.eq_ignore_ascii_case(name))
                .map(|n| n.addr)
                .ok_or_else(|| {
                    let names: Vec<&str> = self.nodes.iter().map(|n| n.name.as_str()).collect();
                    format!("unknown node `{name}` (nodes: {})", names.join(", "))
                }),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::ReplyPattern;

    /// Every optional field of an expectation is in the validation's list (a field added to
    /// the struct and not to `given_fields` would escape the per-kind check).
    #[test]
    fn every_expectation_field_is_validated() {
        let schema = serde_json::to_value(schemars::schema_for!(super::ExpectationSpec)).unwrap();
        let mut fields: Vec<String> = schema["properties"]
            .as_object()
            .unwrap()
            .keys()
            .filter(|k| *k != "name" && *k != "kind")
            .cloned()
            .collect();
        fields.sort();
        let x: super::ExpectationSpec = toml::from_str("kind = \"reply\"").unwrap();
        let mut listed: Vec<String> = super::given_fields(&x)
            .iter()
            .map(|(f, _)| (*f).to_owned())
            .collect();
        listed.sort();
        assert_eq!(fields, listed);
    }

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
        for bad in ["0", "zz", "01 0?", "... 01"] {
            assert!(ReplyPattern::parse(bad).is_err(), "{bad}");
        }
    }
}
