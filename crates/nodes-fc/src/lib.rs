//! Flight computer (CSP 3): the spacecraft's truth, its sensors and actuators, the ADCS
//! flight software of ICD 1.3, the mission-controller scripts of ICD 1.5, and the FC ports
//! of ICD 4.
//!
//! [`FcApp`] is a pure core driven by the node driver's timers: every ADCS tick
//! (`1 / adcs_hz`, 10 Hz by default) it
//! 1. evaluates the environment at the true orbit ([`environment`]: the scenario's TLE
//!    through `orbit`'s SGP4, sun, shadow, IGRF-14);
//! 2. samples the sensors ([`sensors`], seeded noise);
//! 3. runs the flight software ([`adcs`]: detumble, MEKF, guidance, control) against the
//!    onboard orbit (the uploaded TLE, or GPS) and the requested pointing (a running script,
//!    else the ATCMDSET mode);
//! 4. steps the rigid-body truth ([`truth`]) over the tick with the commanded actuators and
//!    the disturbances (gravity gradient, residual dipole, drag);
//! 5. every `adcs_hz / publish_hz` ticks puts a [`TruthSnapshot`] and an [`AdcsSnapshot`]
//!    in its outbox as a [`Published`] event (`App::poll_event`; the twin records them and
//!    checks expectations against them).
//!
//! The truth (orbit, attitude, wheels) survives FC reboots; the flight software (estimate,
//! mode, target, scripts) does not. While the FC is off or hung nothing runs; when it comes
//! back the truth is stepped over the gap without publishing, the actuators off after a
//! power cycle and as last commanded after a hang.
//!
//! Byte layouts and decisions are in `docs/protocol.md` ("FC ports"); the models and the
//! ADCS in `docs/adcs.md`. The ADCS modules (environment, sensors, the flight software, the
//! truth) are the crate `m6p-adcs`'s, re-exported here under their old paths.

// The ADCS (m6p-adcs) under the paths it had when it lived here: `nodes_fc::control`, ...
pub use ::adcs::{adcs, control, environment, estimator, guidance, sensors, truth};

pub mod burns;
pub mod config;
pub mod safe;
pub mod scripts;
mod state;
pub mod store;
pub mod timesync;
pub use icd::fc as wire;

use csp::console::ConsoleError;
use csp::node::{App, Node, NodeEvent, Outbox};
use csp::reqrep::{self, CommandSet, RESULT_FAILURE, RESULT_SUCCESS, Request, serve};
use csp::{Packet, SimTime};
use nalgebra::{UnitQuaternion, Vector3};
use orbit::propagate::{PropagationError, Sgp4Propagator};
use orbit::tle::{ChecksumMode, Tle, TleError};
use platform::truth::{AdcsSnapshot, TruthSnapshot};

use crate::adcs::{Adcs, AdcsConfig};
use crate::environment::{DragConfig, EnvModel, Environment, SlowModels};
use crate::guidance::Pointing;
use crate::scripts::{Schedule, Script, ScriptAttitude, ScriptError};
use crate::sensors::{SensorConfig, SensorFault, SensorId, SensorInputs, SensorReadings, Sensors};
use crate::truth::{AttitudeState, BodyConfig, Torques};
use crate::wire::{
    AttitudeCommand, Repr, RtcCommand, RtcTimestamp, TargetAttitude, TargetMode, TargetModeRepr,
    TargetPoint, TelemetryCommand, TleLines, TmAcd, TmAll, TmAtp, TmGen, TmRawSens, TmSens,
};

/// The ports this node binds for its ICD services by default (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[
    wire::PORT_TELEMETRY,
    wire::PORT_RTC,
    wire::PORT_ATTITUDE,
    wire::PORT_SCRIPTS,
];

/// Reset cause in TMGEN: power-on (the start of the run, or power back after a loss).
pub const RESET_POWER_ON: u8 = 0;
/// Reset cause in TMGEN: software reboot (CSP reboot service or a scenario fault).
pub const RESET_SOFTWARE: u8 = 1;

/// A gap between ticks longer than this means the FC was off or hung: the missed ticks step
/// the truth only.
const GAP_NS: u64 = 500_000_000;

/// How old a GPS fix may be and still give TMATP's position (a receiver reports at 1 Hz;
/// older than this the FC falls back to its TLE).
pub const GPS_FIX_MAX_AGE_NS: i64 = 10_000_000_000;

/// How far from the FC's time an uploaded TLE's epoch may be (ATCTLESET), s: 30 days (a
/// month-old TLE is hundreds of kilometres off; the ground uploads fresh ones).
pub const TLE_MAX_AGE_S: f64 = 30.0 * 86_400.0;

/// The longest window a script may hold the ADCS for, s (the twin's: a day; the ground
/// renews the schedule on the next pass).
pub const MAX_SCRIPT_WINDOW_S: f64 = 86_400.0;

/// The FC's ICD ports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FcPorts {
    /// Telemetry (TMGEN ... TMALL).
    pub telemetry: u8,
    /// Real-time clock.
    pub rtc: u8,
    /// Attitude target control.
    pub attitude: u8,
    /// Mission-controller scripts.
    pub scripts: u8,
}

impl FcPorts {
    /// Whether ICD 4.1 stars `command` on `port` for payloads: TMGEN, TMATP, TMACD and
    /// TMSENS on the telemetry port and RTCSTMGET on the RTC port. The attitude port is
    /// starred but none of its commands, and the scripts port is not in 4.1.
    pub fn open_to_payloads(&self, port: u8, command: Option<u8>) -> bool {
        match command {
            Some(c) if port == self.telemetry => [
                wire::cmd::TMGEN,
                wire::cmd::TMATP,
                wire::cmd::TMACD,
                wire::cmd::TMSENS,
            ]
            .contains(&c),
            Some(c) if port == self.rtc => c == wire::cmd::RTCSTMGET,
            _ => false,
        }
    }
}

impl Default for FcPorts {
    fn default() -> Self {
        FcPorts {
            telemetry: wire::PORT_TELEMETRY,
            rtc: wire::PORT_RTC,
            attitude: wire::PORT_ATTITUDE,
            scripts: wire::PORT_SCRIPTS,
        }
    }
}

/// The spacecraft's state at the start of the run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialState {
    /// Attitude, body in ECI.
    pub q_eci_from_body: UnitQuaternion<f64>,
    /// Body rate, rad/s, body frame.
    pub w_body_rad_s: Vector3<f64>,
    /// Wheel speeds, rad/s.
    pub wheel_speed_rad_s: [f64; 4],
}

impl Default for InitialState {
    fn default() -> Self {
        InitialState {
            q_eci_from_body: UnitQuaternion::identity(),
            w_body_rad_s: Vector3::zeros(),
            wheel_speed_rad_s: [0.0; 4],
        }
    }
}

/// A reaction wheel failure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WheelFault {
    /// Seized bearing: the wheel stops at once (its momentum goes to the body) and stays at
    /// zero speed.
    Stuck,
    /// Dead drive: no motor torque; the wheel coasts down on its friction.
    Off,
}

/// A text that is not a [`WheelFault`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WheelFaultError {
    /// Neither `stuck` nor `off` (the name trimmed and lower-cased).
    #[error("unknown wheel fault `{name}`: expected `stuck` or `off`")]
    Unknown {
        /// The name.
        name: String,
    },
}

impl std::str::FromStr for WheelFault {
    type Err = WheelFaultError;
    fn from_str(s: &str) -> Result<Self, WheelFaultError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "stuck" => Ok(WheelFault::Stuck),
            "off" => Ok(WheelFault::Off),
            other => Err(WheelFaultError::Unknown {
                name: other.to_owned(),
            }),
        }
    }
}

/// Something a scenario does to the FC at a time.
#[derive(Debug, Clone, PartialEq)]
pub enum FcEvent {
    /// A mission-controller script line, submitted as if stored onboard.
    Script(String),
    /// A sensor fault applied (`Some`) or cleared (`None`).
    Sensor(SensorId, Option<SensorFault>),
    /// A wheel fault applied or cleared.
    Wheel(usize, Option<WheelFault>),
}

/// An [`FcEvent`] at a simulated time.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedFcEvent {
    /// When.
    pub at: SimTime,
    /// What.
    pub event: FcEvent,
}

/// What the FC needs from the scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct FcConfig {
    /// UTC unix seconds at simulated time zero.
    pub epoch_unix_s: u64,
    /// The two TLE lines of the true orbit, if the scenario gives one.
    pub tle: Option<(String, String)>,
    /// Whether the FC holds the scenario's TLE at boot (commissioning done); otherwise it
    /// has no orbit until ATCTLESET or a GPS fix.
    pub tle_uploaded: bool,
    /// Port numbers.
    pub ports: FcPorts,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// The run's seed, which TWINSIM reports (the sensor noise's `seed` is drawn from it and
    /// does not give it back).
    pub run_seed: u64,
    /// ADCS loop rate, Hz (1-100).
    pub adcs_hz: u32,
    /// Truth publication rate, Hz (0: none; at most `adcs_hz`).
    pub publish_hz: u32,
    /// Mass properties and actuators.
    pub body: BodyConfig,
    /// Initial attitude, rate and wheel speeds.
    pub initial: InitialState,
    /// Sensor models.
    pub sensors: SensorConfig,
    /// Flight software settings.
    pub adcs: AdcsConfig,
    /// Residual magnetic dipole of the bus, body frame, A m^2.
    pub residual_dipole_am2: Vector3<f64>,
    /// Aerodynamic drag torque; `None` switches it off.
    pub drag: Option<DragConfig>,
    /// Gravity-gradient torque on or off.
    pub gravity_gradient: bool,
    /// The target mode commanded at the first boot (as if by ATCMDSET at time zero).
    pub initial_mode: TargetMode,
    /// The target attitude commanded at the first boot (as if by ATCATSET), unit.
    pub initial_target_attitude: Option<[f64; 4]>,
    /// The target point commanded at the first boot (as if by ATCPTSET).
    pub initial_target_point: Option<[f64; 3]>,
    /// Scripts and faults at their times.
    pub timeline: Vec<TimedFcEvent>,
    /// What a payload (12-15) may ask of the FC (ICD 4.1's stars by default).
    pub payload_access: platform::addr::PayloadAccess,
    /// Where the FC sends its RTC (CMP CLOCK), and how often.
    pub time_sync: timesync::TimeSyncConfig,
    /// When the FC goes SAFE (TMGEN `current_state`).
    pub safe: safe::SafeConfig,
    /// Periodic real-time telemetry from boot (TMPERSET changes it until the next boot).
    pub periodic: Option<wire::Periodic>,
    /// The on-board telemetry store's collection.
    pub store: store::StoreConfig,
}

impl Default for FcConfig {
    fn default() -> Self {
        FcConfig {
            epoch_unix_s: 0,
            tle: None,
            tle_uploaded: true,
            ports: FcPorts::default(),
            seed: 0,
            run_seed: 0,
            adcs_hz: 10,
            publish_hz: 1,
            body: BodyConfig::default(),
            initial: InitialState::default(),
            sensors: SensorConfig::default(),
            adcs: AdcsConfig::default(),
            // A few mA m^2: a well-built 6U (harness loops, battery, magnetic parts).
            residual_dipole_am2: Vector3::new(0.002, 0.002, 0.005),
            drag: Some(DragConfig::default()),
            gravity_gradient: true,
            initial_mode: TargetMode::Detumble,
            initial_target_attitude: None,
            initial_target_point: None,
            timeline: Vec::new(),
            payload_access: platform::addr::PayloadAccess::default(),
            time_sync: timesync::TimeSyncConfig::default(),
            safe: safe::SafeConfig::default(),
            periodic: None,
            store: store::StoreConfig::default(),
        }
    }
}

/// The commanded attitude target (ATC* commands).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Target mode.
    pub mode: TargetMode,
    /// Target quaternion, unit norm, scalar first.
    pub attitude: [f64; 4],
    /// Whether ATCATSET set it since boot.
    pub attitude_set: bool,
    /// Target point.
    pub point: [f64; 3],
    /// Whether ATCPTSET set it since boot.
    pub point_set: bool,
}

impl Default for Target {
    fn default() -> Self {
        Target {
            mode: TargetMode::Detumble,
            attitude: [1.0, 0.0, 0.0, 0.0],
            attitude_set: false,
            point: [0.0; 3],
            point_set: false,
        }
    }
}

/// What the FC tells the run: every `publish_hz` the true state and what its ADCS believes
/// and does at that instant (the twin records them and checks expectations against them).
#[derive(Debug, Clone, PartialEq)]
pub struct Published {
    /// The true state.
    pub truth: Box<TruthSnapshot>,
    /// The ADCS's estimate, target and commands.
    pub adcs: Box<AdcsSnapshot>,
}

/// Why the FC has no orbit model for a TLE.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum OrbitError {
    /// The scenario gives no TLE.
    #[error("no TLE")]
    NoTle,
    /// The TLE does not parse.
    #[error("TLE: {0}")]
    Tle(TleError),
    /// SGP4 does not initialise from the elements.
    #[error("SGP4: {0}")]
    Sgp4(PropagationError),
}

/// Why the FC cannot tell its position.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PositionError {
    /// Neither a TLE uploaded nor a recent GPS fix.
    #[error("no TLE uploaded and no GPS fix")]
    NoKnowledge,
    /// The TLE gives no orbit model.
    #[error(transparent)]
    Orbit(#[from] OrbitError),
    /// The orbit cannot be propagated to the instant (decay, bad elements, a time before
    /// the last burn).
    #[error(transparent)]
    Propagation(#[from] PropagationError),
}

/// Why a script line was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SubmitError {
    /// The line does not parse, or the schedule refuses it.
    #[error(transparent)]
    Script(#[from] ScriptError),
    /// Its window is longer than the FC lets one script hold the ADCS.
    #[error(
        "window of {window_s} s is longer than the FC's {} s (a day)",
        MAX_SCRIPT_WINDOW_S
    )]
    WindowTooLong {
        /// The window, s.
        window_s: f64,
    },
    /// Its end is after the last time the RTC can hold.
    #[error(
        "END {end_unix_s} is after the RTC's range (2100-01-01, {})",
        wire::RTC_MAX_UNIX_S
    )]
    EndAfterRtc {
        /// The end, UTC unix s.
        end_unix_s: f64,
    },
}

/// The onboard orbit knowledge: the uploaded TLE.
#[derive(Debug, Clone)]
struct OnboardOrbit {
    lines: TleLines,
    model: Result<EnvModel, OrbitError>,
    /// The same elements as the true orbit: reuse the truth's environment.
    same_as_truth: bool,
}

/// The flight software's volatile state.
#[derive(Debug, Clone)]
struct Fsw {
    adcs: Adcs,
    target: Target,
    scripts: Schedule,
    output: Option<adcs::Output>,
    /// The mode the software asked the ADCS for at the last tick (a script's or ATCMDSET's).
    request_mode: Option<TargetMode>,
    /// The latest GPS fix: UTC unix ns, ECI J2000 position (m) and velocity (m/s).
    gps_fix: Option<(i64, Vector3<f64>, Vector3<f64>)>,
}

/// The flight computer's application (see the module doc).
#[derive(Debug)]
pub struct FcApp {
    cfg: FcConfig,
    dt_ns: u64,
    publish_every: u64,
    // --- truth (survives reboots) ---
    truth_orbit: Result<EnvModel, OrbitError>,
    att: AttitudeState,
    sensors: Sensors,
    wheel_fault: [Option<WheelFault>; 4],
    mtq_applied_am2: Vector3<f64>,
    wheel_cmd_nm: [f64; 4],
    next_tick: Option<SimTime>,
    ticks: u64,
    timeline: std::collections::VecDeque<TimedFcEvent>,
    env: Option<Environment>,
    readings: Option<SensorReadings>,
    // --- non-volatile FC state ---
    onboard: Option<OnboardOrbit>,
    gps_models: SlowModels,
    rtc_offset_ns: i128,
    /// The errors of the node's clock (its oscillator's), refreshed at every entry.
    clock: csp::node::ClockErrors,
    power_on: Option<SimTime>,
    reset_cause: u8,
    /// Power was lost since the last boot: the next boot is a power-on.
    power_was_lost: bool,
    // --- flight software (volatile) ---
    fsw: Fsw,
    refused: u64,
    denied: u64,
    periodic: wire::Periodic,
    periodic_next: Option<SimTime>,
    time_sync: timesync::TimeSync,
    safe: safe::SafeMonitor,
    /// The telemetry store (non-volatile: not reset by a reboot).
    store: store::Store,
    /// The last instant of an input (a parameter set counts the store's period from it).
    store_now: Option<SimTime>,
    log: Vec<NodeEvent>,
    out: Outbox<Published>,
    truth_board: Option<platform::board::TruthBoard>,
    /// Writes to the truth board refused in a row (a reader ran ahead of a late tick, as
    /// after a hang): one warning when a streak starts, one line when it ends, not one per
    /// tick (a campaign of hangs logged 22,000 lines). The board counts them all.
    truth_refused_in_a_row: u64,
    // --- truth: the ECU's burns (not reset by a reboot) ---
    burns: Option<platform::board::BurnBoard>,
    burns_applied_until_ns: u64,
}

fn truth_model(tle: Option<&(String, String)>) -> Result<EnvModel, OrbitError> {
    match tle {
        None => Err(OrbitError::NoTle),
        Some((l1, l2)) => Tle::parse(l1, l2, ChecksumMode::Strict)
            .map_err(OrbitError::Tle)
            .and_then(|tle| {
                Sgp4Propagator::new(&tle)
                    .map_err(OrbitError::Sgp4)
                    .map(|p| EnvModel::new(p).with_cowell_config(burns::cowell_config_for(&tle)))
            }),
    }
}

impl FcApp {
    /// An FC for `cfg`; a TLE that does not parse or initialise leaves the FC without an
    /// orbit (TMATP failing, no environment), never a panic.
    pub fn new(cfg: FcConfig) -> Self {
        let truth_orbit = truth_model(cfg.tle.as_ref());
        let hz = u64::from(cfg.adcs_hz.clamp(1, 100));
        let dt_ns = 1_000_000_000 / hz;
        let publish_every = if cfg.publish_hz == 0 {
            0
        } else {
            (hz / u64::from(cfg.publish_hz).min(hz)).max(1)
        };
        let onboard = if cfg.tle_uploaded {
            cfg.tle
                .as_ref()
                .and_then(|(a, b)| TleLines::from_text(a, b))
                .map(|lines| OnboardOrbit {
                    lines,
                    model: truth_model(cfg.tle.as_ref()),
                    same_as_truth: true,
                })
        } else {
            None
        };
        let sensors = Sensors::new(cfg.sensors.clone(), cfg.seed);
        let mut timeline: Vec<TimedFcEvent> = cfg.timeline.clone();
        timeline.sort_by_key(|e| e.at);
        let att = AttitudeState {
            q_eci_from_body: cfg.initial.q_eci_from_body,
            w_body_rad_s: cfg.initial.w_body_rad_s,
            wheel_speed_rad_s: cfg.initial.wheel_speed_rad_s,
        };
        let fsw = Fsw {
            adcs: Adcs::new(cfg.adcs.clone(), cfg.body.clone()),
            target: Target {
                mode: cfg.initial_mode,
                attitude: cfg.initial_target_attitude.unwrap_or([1.0, 0.0, 0.0, 0.0]),
                attitude_set: cfg.initial_target_attitude.is_some(),
                point: cfg.initial_target_point.unwrap_or([0.0; 3]),
                point_set: cfg.initial_target_point.is_some(),
            },
            scripts: Schedule::new(),
            output: None,
            request_mode: None,
            gps_fix: None,
        };
        FcApp {
            dt_ns,
            publish_every,
            truth_orbit,
            att,
            sensors,
            wheel_fault: [None; 4],
            mtq_applied_am2: Vector3::zeros(),
            wheel_cmd_nm: [0.0; 4],
            next_tick: None,
            ticks: 0,
            timeline: timeline.into(),
            env: None,
            readings: None,
            onboard,
            gps_models: SlowModels::default(),
            rtc_offset_ns: 0,
            clock: csp::node::ClockErrors::default(),
            power_on: None,
            reset_cause: RESET_POWER_ON,
            power_was_lost: false,
            fsw,
            refused: 0,
            denied: 0,
            periodic: wire::Periodic::default(),
            periodic_next: None,
            time_sync: timesync::TimeSync::new(cfg.time_sync.clone()),
            safe: safe::SafeMonitor::new(cfg.safe.clone()),
            store: store::Store::new(cfg.store.clone()),
            store_now: None,
            log: Vec::new(),
            out: Outbox::default(),
            truth_board: None,
            truth_refused_in_a_row: 0,
            burns: None,
            burns_applied_until_ns: 0,
            cfg,
        }
    }

    /// Post the true state of every tick to `board` for the other nodes (EPS, COMM, ECU).
    pub fn with_truth_board(mut self, board: platform::board::TruthBoard) -> Self {
        self.truth_board = Some(board);
        self
    }

    /// Apply the ECU's burns posted on `board` to the true orbit ([`burns`]).
    pub fn with_burns(mut self, board: platform::board::BurnBoard) -> Self {
        self.burns = Some(board);
        self
    }

    /// Why the FC has no true orbit, if it has none.
    pub fn orbit_error(&self) -> Option<&OrbitError> {
        self.truth_orbit.as_ref().err()
    }

    /// The commanded target.
    pub fn target(&self) -> &Target {
        &self.fsw.target
    }

    /// Requests answered with the failure reply (malformed, out of range or denied).
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// Requests from payloads refused by [`FcConfig::payload_access`] (also in
    /// [`refused`](Self::refused)).
    pub fn denied(&self) -> u64 {
        self.denied
    }

    /// The true attitude state.
    pub fn attitude(&self) -> &AttitudeState {
        &self.att
    }

    /// The flight software's attitude estimate, if initialised.
    pub fn estimate(&self) -> Option<UnitQuaternion<f64>> {
        self.fsw.adcs.estimate()
    }

    /// The scripts accepted and not yet ended.
    pub fn scripts(&self) -> &Schedule {
        &self.fsw.scripts
    }

    /// Hand the FC's log lines (script verdicts, mode changes, faults) to the node's log.
    fn flush_log(&mut self, node: &mut Node) {
        for e in self.log.drain(..) {
            node.push_event(e);
        }
    }

    /// True UTC time at `now` (the run's clock, not the RTC), nanoseconds.
    fn true_unix_ns(&self, now: SimTime) -> i128 {
        i128::from(self.cfg.epoch_unix_s) * 1_000_000_000 + i128::from(now.as_ns())
    }

    fn true_unix_ns_i64(&self, now: SimTime) -> i64 {
        i64::try_from(self.true_unix_ns(now)).unwrap_or(i64::MAX)
    }

    /// The RTC at `now`, UTC unix nanoseconds: true time, the offset RTCSTMSET set, and
    /// the node's clock errors.
    fn rtc_unix_ns(&self, now: SimTime) -> i128 {
        self.true_unix_ns(now) + self.rtc_offset_ns + self.clock.error_ns(now)
    }

    /// The RTC at `now`, UTC unix seconds (saturating to the u32 range).
    pub fn rtc_unix_s(&self, now: SimTime) -> u32 {
        let s = self.rtc_unix_ns(now).div_euclid(1_000_000_000);
        u32::try_from(s.max(0)).unwrap_or(u32::MAX)
    }

    /// The RTC at `now` as UTC unix seconds with its fraction (scripts run on it).
    fn rtc_unix_s_f64(&self, now: SimTime) -> f64 {
        self.rtc_unix_ns(now) as f64 * 1e-9
    }

    /// The FC's knowledge of its ECI J2000 position in metres at `now`: the latest GPS fix
    /// (when younger than [`GPS_FIX_MAX_AGE_NS`]) carried to `now` under two-body gravity,
    /// else the onboard TLE through `orbit`'s SGP4, or why there is neither.
    pub fn position_eci_m(&mut self, now: SimTime) -> Result<[f64; 3], PositionError> {
        let t = self.true_unix_ns_i64(now);
        if let Some((t_fix, r, v)) = self.fsw.gps_fix
            && (t - t_fix).abs() <= GPS_FIX_MAX_AGE_NS
        {
            let dt_s = (t - t_fix) as f64 * 1e-9;
            // r + v dt + a dt^2 / 2 with a = -mu r / |r|^3: over at most a few seconds the
            // error is centimetres (the jerk term, ~|a| n dt^3 / 6).
            let a = -r * (orbit::cowell::MU_EARTH_KM3_S2 * 1e9 / r.norm().powi(3));
            let p = r + v * dt_s + a * (0.5 * dt_s * dt_s);
            return Ok([p.x, p.y, p.z]);
        }
        let onboard = self.onboard.as_mut().ok_or(PositionError::NoKnowledge)?;
        if onboard.same_as_truth {
            // The onboard orbit is the truth's: after a burn, its numerical continuation.
            let model = self.truth_orbit.as_mut().map_err(|e| e.clone())?;
            let s = model.state_j2000(t)?;
            return Ok([s.r_km[0] * 1e3, s.r_km[1] * 1e3, s.r_km[2] * 1e3]);
        }
        let model = onboard.model.as_mut().map_err(|e| e.clone())?;
        let s = model.state_j2000(t)?;
        Ok([s.r_km[0] * 1e3, s.r_km[1] * 1e3, s.r_km[2] * 1e3])
    }

    /// The onboard references at the tick's time: GPS fix, else the onboard TLE.
    fn onboard_env(&mut self, unix_ns: i64) -> Option<Environment> {
        if let (Some(r), Some(v)) = self
            .readings
            .as_ref()
            .map_or((None, None), |x| (x.gps_r_eci_m, x.gps_v_eci_m_s))
        {
            return Some(self.gps_models.at_state(unix_ns, r, v));
        }
        let onboard = self.onboard.as_mut()?;
        if onboard.same_as_truth {
            return self.env;
        }
        onboard.model.as_mut().ok()?.at(unix_ns).ok()
    }

    /// The pointing a script attitude asks for, and its mode.
    fn script_request(s: &Script) -> adcs::Request {
        let (mode, pointing) = match s.attitude {
            ScriptAttitude::Eci(q) => (TargetMode::FixedEci, Pointing::FixedEci(q)),
            ScriptAttitude::Lvlh(q) => (TargetMode::FixedLvlh, Pointing::FixedLvlh(q)),
            ScriptAttitude::Tnw(q) => (TargetMode::FixedTnw, Pointing::FixedTnw(q)),
            ScriptAttitude::Geo {
                lat_deg,
                lon_deg,
                alt_m,
                axis_body,
            } => (
                TargetMode::EarthTarget,
                Pointing::EarthTarget {
                    lat_deg,
                    lon_deg,
                    alt_m,
                    axis_body,
                },
            ),
        };
        adcs::Request {
            mode,
            pointing: Some(pointing),
        }
    }

    /// The pointing of the ATCMDSET mode.
    /// The ADCS request for `mode` with the commanded attitude and point.
    fn request_for(&self, mode: TargetMode) -> adcs::Request {
        let t = &self.fsw.target;
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            t.attitude[0],
            t.attitude[1],
            t.attitude[2],
            t.attitude[3],
        ));
        let p = Vector3::new(t.point[0], t.point[1], t.point[2]);
        let z = Vector3::z();
        let pointing = match mode {
            TargetMode::Idle | TargetMode::Detumble => None,
            TargetMode::VelocityPointing => Some(Pointing::Velocity),
            TargetMode::Nadir => Some(Pointing::Nadir),
            TargetMode::SunMaxPower => Some(Pointing::SunMaxPower {
                panel_normal_body: self.cfg.adcs.panel_normal_body,
            }),
            TargetMode::EarthTarget => Some(Pointing::EarthTarget {
                lat_deg: p.x,
                lon_deg: p.y,
                alt_m: p.z,
                axis_body: z,
            }),
            TargetMode::EciVector => Some(Pointing::EciVector {
                dir_eci: p,
                axis_body: z,
            }),
            TargetMode::FixedEci => Some(Pointing::FixedEci(q)),
            TargetMode::FixedLvlh => Some(Pointing::FixedLvlh(q)),
            TargetMode::FixedTnw => Some(Pointing::FixedTnw(q)),
        };
        adcs::Request { mode, pointing }
    }

    /// Submit a script line to the mission controller at `now`.
    fn submit_script(&mut self, bytes: &[u8], now: SimTime) -> Result<(), SubmitError> {
        let script = Script::parse_bytes(bytes)?;
        // The FC's own limits: one script holds the ADCS for at most a day, and its window
        // ends within the RTC's range (a line cannot take the attitude for ever).
        let window_s = script.end_unix_s - script.start_unix_s;
        if window_s > MAX_SCRIPT_WINDOW_S {
            return Err(SubmitError::WindowTooLong { window_s });
        }
        if script.end_unix_s > f64::from(wire::RTC_MAX_UNIX_S) {
            return Err(SubmitError::EndAfterRtc {
                end_unix_s: script.end_unix_s,
            });
        }
        let now_s = self.rtc_unix_s_f64(now);
        self.fsw.scripts.add(script, now_s)?;
        self.log
            .push(NodeEvent::info(now, format!("script accepted: {script}")));
        Ok(())
    }

    fn apply_event(&mut self, e: FcEvent, now: SimTime, fsw: bool) {
        match e {
            FcEvent::Script(line) if !fsw => {
                // The FC is off or hung: nothing receives the line.
                self.log.push(NodeEvent::info(
                    now,
                    format!("script lost (FC not running): {line:?}"),
                ));
            }
            FcEvent::Script(line) => {
                if let Err(why) = self.submit_script(line.as_bytes(), now) {
                    self.log.push(NodeEvent::info(
                        now,
                        format!("script rejected: {why}: {line:?}"),
                    ));
                }
            }
            FcEvent::Sensor(id, fault) => {
                self.sensors.set_fault(id, fault);
                self.log.push(NodeEvent::info(
                    now,
                    format!("sensor fault {id:?}: {fault:?}"),
                ));
            }
            FcEvent::Wheel(i, fault) => {
                if let Some(slot) = self.wheel_fault.get_mut(i) {
                    *slot = fault;
                    self.log
                        .push(NodeEvent::info(now, format!("wheel {i} fault: {fault:?}")));
                }
            }
        }
    }

    /// One tick at `t`: environment, sensors, flight software (when `fsw`), truth step.
    fn tick(&mut self, t: SimTime, fsw: bool) {
        while self.timeline.front().is_some_and(|e| e.at <= t) {
            if let Some(e) = self.timeline.pop_front() {
                self.apply_event(e.event, t, fsw);
            }
        }
        let dt_s = self.dt_ns as f64 * 1e-9;
        let unix_ns = self.true_unix_ns_i64(t);
        // The ECU's burns up to now, before the orbit is evaluated at now (docs/adcs.md).
        self.apply_burns(t, unix_ns);
        let env = self
            .truth_orbit
            .as_mut()
            .ok()
            .and_then(|m| m.at(unix_ns).ok());
        self.env = env;
        let inputs = SensorInputs {
            q_eci_from_body: self.att.q_eci_from_body,
            w_body_rad_s: self.att.w_body_rad_s,
            b_eci_nt: env.map_or_else(Vector3::zeros, |e| e.b_eci_nt),
            sun_eci_unit: env.map_or_else(Vector3::zeros, |e| e.sun_eci_unit),
            sun_visible_fraction: env.map_or(0.0, |e| e.sun_visible_fraction),
            r_eci_m: env.map_or_else(Vector3::zeros, |e| e.r_eci_m),
            v_eci_m_s: env.map_or_else(Vector3::zeros, |e| e.v_eci_m_s),
            nongrav_acc_body_m_s2: Vector3::zeros(),
        };
        let readings = self.sensors.sample(&inputs, dt_s);
        self.readings = Some(readings);
        if fsw && let (Some(r), Some(v)) = (readings.gps_r_eci_m, readings.gps_v_eci_m_s) {
            self.fsw.gps_fix = Some((unix_ns, r, v));
        }
        let healthy: [bool; 4] = std::array::from_fn(|i| self.wheel_fault[i].is_none());

        if fsw {
            self.run_fsw(t, unix_ns, &readings, healthy, dt_s);
        }
        for (i, f) in self.wheel_fault.iter().enumerate() {
            if f.is_some() {
                self.wheel_cmd_nm[i] = 0.0;
            }
        }

        // Without an orbit (no TLE, or SGP4 failing at this instant) there is no true state
        // to tell: publishing one would put the satellite at the Earth's centre.
        if self.publish_every > 0 && fsw && env.is_some() && self.ticks % self.publish_every == 0 {
            self.publish(t, unix_ns);
        }
        // The other nodes' view of the truth: every tick, whether the FC software runs or not
        // (the truth is physics).
        if let Some(board) = &self.truth_board {
            match board.publish(&self.truth_snapshot(t, unix_ns)) {
                Err(e) => {
                    if self.truth_refused_in_a_row == 0 {
                        self.log.push(NodeEvent::warning(
                            t,
                            format!("truth not posted: {e}; later refusals in a row are counted, not logged"),
                        ));
                    }
                    self.truth_refused_in_a_row += 1;
                }
                Ok(()) if self.truth_refused_in_a_row > 0 => {
                    let n = std::mem::take(&mut self.truth_refused_in_a_row);
                    self.log.push(NodeEvent::info(
                        t,
                        format!("truth posted again, after {n} refused write(s)"),
                    ));
                }
                Ok(()) => {}
            }
        }

        self.step_truth(env, dt_s);
        self.ticks += 1;
    }

    /// The ECU's burns up to `t` applied to the truth orbit before the tick evaluates it.
    fn apply_burns(&mut self, t: SimTime, unix_ns: i64) {
        if let (Some(board), Ok(model)) = (&self.burns, self.truth_orbit.as_mut()) {
            match burns::apply(
                model,
                board,
                &self.att.q_eci_from_body,
                t.as_ns(),
                unix_ns,
                &mut self.burns_applied_until_ns,
            ) {
                Ok(a) if a.switched => self.log.push(NodeEvent::info(
                    t,
                    "truth orbit: numerical (Cowell) from the first burn".to_owned(),
                )),
                Ok(_) => {}
                Err(e) => self
                    .log
                    .push(NodeEvent::info(t, format!("burn not applied: {e}"))),
            }
        }
    }

    /// The flight software's part of a tick, only while the FC runs: request, ADCS, SAFE.
    fn run_fsw(
        &mut self,
        t: SimTime,
        unix_ns: i64,
        readings: &SensorReadings,
        healthy: [bool; 4],
        dt_s: f64,
    ) {
        let onboard = self.onboard_env(unix_ns);
        let rtc_s = self.rtc_unix_s_f64(t);
        self.fsw.scripts.expire(rtc_s);
        let request = match self.fsw.scripts.active(rtc_s) {
            // A low battery points the arrays at the sun whatever was asked (safe.rs).
            _ if self.safe.low_battery() => self.request_for(TargetMode::SunMaxPower),
            Some(s) => Self::script_request(s),
            None => self.request_for(self.fsw.target.mode),
        };
        self.fsw.request_mode = Some(request.mode);
        let before = self.fsw.output.map(|o| o.mode_in_effect);
        let out = self.fsw.adcs.step(
            &adcs::Inputs {
                readings,
                wheel_speed_rad_s: self.att.wheel_speed_rad_s,
                wheel_healthy: healthy,
                onboard: onboard.as_ref(),
                request,
            },
            dt_s,
        );
        if before != Some(out.mode_in_effect) {
            let why = self
                .fsw
                .adcs
                .fallback_reason()
                .map_or(String::new(), |r| format!(" (safe fallback: {r})"));
            self.log.push(NodeEvent::info(
                t,
                format!("ADCS mode in effect: {:?}{why}", out.mode_in_effect),
            ));
        }
        self.fsw.output = Some(out);
        if let Some((warn, line)) = self.safe.update(self.fsw.adcs.fallback_reason()) {
            self.log.push(if warn {
                NodeEvent::warning(t, line)
            } else {
                NodeEvent::info(t, line)
            });
        }
        self.wheel_cmd_nm = out.wheel_torque_cmd_nm;
        self.mtq_applied_am2 =
            truth::mtq_dipole_applied_am2(&self.cfg.body, &out.mtq_dipole_cmd_am2);
    }

    /// The truth step over [t, t + dt]: physics, run whether the FC software does or not.
    fn step_truth(&mut self, env: Option<Environment>, dt_s: f64) {
        let b_body_t = env.map_or_else(Vector3::zeros, |e| {
            self.att
                .q_eci_from_body
                .inverse_transform_vector(&e.b_eci_nt)
                * 1e-9
        });
        let mut disturbance = self.cfg.residual_dipole_am2.cross(&b_body_t);
        if let (Some(d), Some(e)) = (&self.cfg.drag, env) {
            disturbance += environment::drag_torque_body_nm(
                d,
                &self.att.q_eci_from_body,
                &e.r_eci_m,
                &e.v_eci_m_s,
            );
        }
        let torques = Torques {
            wheel_torque_cmd_nm: self.wheel_cmd_nm,
            mtq_dipole_cmd_am2: self.mtq_applied_am2,
            b_body_t,
            r_eci_m: env.filter(|_| self.cfg.gravity_gradient).map(|e| e.r_eci_m),
            disturbance_body_nm: disturbance,
        };
        self.att = truth::step(&self.att, &self.cfg.body, &torques, dt_s);
        for (i, f) in self.wheel_fault.iter().enumerate() {
            if *f == Some(WheelFault::Stuck) {
                truth::lock_wheel(&mut self.att, &self.cfg.body, i);
            }
        }
    }

    /// The true state at the tick `t` (environment of the tick, attitude before the step).
    fn truth_snapshot(&self, t: SimTime, unix_ns: i64) -> TruthSnapshot {
        let env = self.env;
        TruthSnapshot {
            t,
            unix_ns,
            r_eci_m: env.map_or_else(Vector3::zeros, |e| e.r_eci_m),
            v_eci_m_s: env.map_or_else(Vector3::zeros, |e| e.v_eci_m_s),
            q_eci_from_body: self.att.q_eci_from_body,
            w_body_rad_s: self.att.w_body_rad_s,
            sun_eci_unit: env.map_or_else(Vector3::zeros, |e| e.sun_eci_unit),
            in_eclipse_fraction_visible: env.map_or(0.0, |e| e.sun_visible_fraction),
            b_eci_nt: env.map_or_else(Vector3::zeros, |e| e.b_eci_nt),
            wheel_speed_rad_s: self.att.wheel_speed_rad_s,
            mtq_dipole_am2: self.mtq_applied_am2.into(),
        }
    }

    fn publish(&mut self, t: SimTime, unix_ns: i64) {
        let truth = self.truth_snapshot(t, unix_ns);
        let q_true = self.att.q_eci_from_body;
        let out = self.fsw.output;
        let target = out.and_then(|o| o.target);
        let est = self.fsw.adcs.estimate();
        let deg = f64::to_degrees;
        let adcs = AdcsSnapshot {
            t,
            mode_in_effect: out.map_or(TargetMode::Detumble as u8, |o| o.mode_in_effect as u8),
            mode_commanded: self.fsw.request_mode.unwrap_or(self.fsw.target.mode) as u8,
            state: out.map_or(adcs::STATE_DETUMBLING, |o| o.state),
            q_eci_from_body_est: est,
            w_body_rad_s_est: out.map_or_else(Vector3::zeros, |o| o.w_body_rad_s_est),
            gyro_bias_rad_s_est: self.fsw.adcs.gyro_bias_rad_s(),
            q_eci_from_body_target: target.map(|g| g.q_eci_from_body),
            pointing_error_deg: target.map(|g| deg(q_true.angle_to(&g.q_eci_from_body))),
            axis_error_deg: target.map(|g| deg((q_true * g.axis_body).angle(&g.axis_target_eci))),
            target_elevation_deg: target.and_then(|g| g.target_elevation_deg),
            estimation_error_deg: est.map(|q| deg(q_true.angle_to(&q))),
            rw_state: self.rw_state(),
            wheel_torque_cmd_nm: self.wheel_cmd_nm,
            mtq_dipole_cmd_am2: out.map_or([0.0; 3], |o| o.mtq_dipole_cmd_am2.into()),
            mtq_state: self.mtq_state(),
        };
        self.out.push(Published {
            truth: Box::new(truth),
            adcs: Box::new(adcs),
        });
    }

    fn rw_state(&self) -> [u8; 4] {
        let running = self
            .fsw
            .output
            .is_some_and(|o| o.state != adcs::STATE_OFF && o.state != adcs::STATE_DETUMBLING);
        std::array::from_fn(|i| match self.wheel_fault[i] {
            Some(_) => 2,
            None => u8::from(running),
        })
    }

    fn mtq_state(&self) -> [u8; 3] {
        std::array::from_fn(|i| {
            let m = self.mtq_applied_am2[i];
            if m > 1e-6 {
                1
            } else if m < -1e-6 {
                2
            } else {
                0
            }
        })
    }

    /// Step the truth (physics only) over a gap up to `now`, then align the next tick.
    fn catch_up(&mut self, now: SimTime) {
        let Some(mut next) = self.next_tick else {
            self.next_tick = Some(now);
            return;
        };
        while next + std::time::Duration::from_nanos(GAP_NS) < now {
            self.tick(next, false);
            next = next + std::time::Duration::from_nanos(self.dt_ns);
        }
        self.next_tick = Some(next);
    }

    fn tm_gen(&self, node: &Node, now: SimTime) -> TmGen {
        let secs = |d: std::time::Duration| u32::try_from(d.as_secs()).unwrap_or(u32::MAX);
        let on = self
            .power_on
            .map_or(std::time::Duration::ZERO, |t| now.saturating_since(t));
        let mode = self
            .fsw
            .output
            .map_or(TargetMode::Detumble, |o| o.mode_in_effect);
        TmGen {
            rtc_timestamp: self.rtc_unix_s(now),
            uptime_s: secs(node.uptime(now)),
            global_on_time_s: secs(on),
            current_mode: mode as u8,
            current_state: self.safe.state(),
            mcu_temp_c: self.readings.as_ref().map_or(20, |r| sat_i8(r.mcu_temp_c)),
            reset_cause: self.reset_cause,
        }
    }

    fn tm_atp(&mut self, now: SimTime) -> Result<TmAtp, PositionError> {
        let q = self
            .fsw
            .adcs
            .estimate()
            .map_or([1.0, 0.0, 0.0, 0.0], |q| [q.w, q.i, q.j, q.k]);
        Ok(TmAtp {
            rtc_timestamp: self.rtc_unix_s(now),
            q_eci_from_body: q,
            r_eci_m: self.position_eci_m(now)?,
        })
    }

    fn tm_acd(&self, now: SimTime) -> TmAcd {
        let rpm = |w: f64| {
            let r = (w.abs() * 60.0 / std::f64::consts::TAU / 100.0).round();
            if r >= 255.0 { 255 } else { r as u8 }
        };
        TmAcd {
            rtc_timestamp: self.rtc_unix_s(now),
            state: self.fsw.output.map_or(adcs::STATE_DETUMBLING, |o| o.state),
            rw_state: self.rw_state(),
            rw_rpm_100: self.att.wheel_speed_rad_s.map(rpm),
            mtq_state: self.mtq_state(),
            target_mode: self.fsw.target.mode as u8,
            target_attitude: u8::from(self.fsw.target.attitude_set),
            target_point: u8::from(self.fsw.target.point_set),
        }
    }

    fn tm_sens(&self, now: SimTime) -> TmSens {
        let rtc = self.rtc_unix_s(now);
        self.readings.as_ref().map_or(
            TmSens {
                rtc_timestamp: rtc,
                ..TmSens::default()
            },
            |r| r.tm_sens(rtc),
        )
    }

    fn tm_raw_sens(&self, now: SimTime) -> TmRawSens {
        let rtc = self.rtc_unix_s(now);
        self.readings.as_ref().map_or(
            TmRawSens {
                rtc_timestamp: rtc,
                ..TmRawSens::default()
            },
            |r| r.tm_raw_sens(rtc),
        )
    }

    fn telemetry(&mut self, node: &Node, c: TelemetryCommand, now: SimTime) -> Result<Vec<u8>, u8> {
        let fail = |_| RESULT_FAILURE;
        Ok(match c {
            TelemetryCommand::TmGen => self.tm_gen(node, now).to_vec(),
            TelemetryCommand::TmAtp => self.tm_atp(now).map_err(fail)?.to_vec(),
            TelemetryCommand::TmAcd => self.tm_acd(now).to_vec(),
            TelemetryCommand::TmSens => self.tm_sens(now).to_vec(),
            TelemetryCommand::TmRawSens => self.tm_raw_sens(now).to_vec(),
            TelemetryCommand::TmAll => {
                let atp = self.tm_atp(now).map_err(fail)?;
                // Nadir in the body by the estimate: the Earth-horizon vector the FC knows.
                let nadir_body = self
                    .estimate()
                    .and_then(|q| {
                        q.inverse_transform_vector(&-Vector3::from(atp.r_eci_m))
                            .try_normalize(0.0)
                    })
                    .map_or([0.0; 3], |v| [v.x as f32, v.y as f32, v.z as f32]);
                TmAll {
                    general: self.tm_gen(node, now),
                    attitude_position: atp,
                    attitude_control: self.tm_acd(now),
                    sensors: self.tm_sens(now),
                    nadir_body,
                }
                .to_vec()
            }
            TelemetryCommand::SetPeriodic(p) => {
                if p.out_of_range(node.addr()).is_some() {
                    return Err(RESULT_FAILURE);
                }
                self.set_periodic(p, now);
                Vec::new()
            }
            TelemetryCommand::GetPeriodic => self.periodic.to_vec(),
            TelemetryCommand::StoreInfo => self.store.info(),
            TelemetryCommand::StoreGet { from, to, skip } => {
                self.store.get(from, to, skip).ok_or(RESULT_FAILURE)?
            }
            TelemetryCommand::StoreClear => {
                let n = self.store.clear();
                self.log.push(NodeEvent::info(
                    now,
                    format!("fc: telemetry store erased ({n} records)"),
                ));
                n.to_le_bytes().to_vec()
            }
            TelemetryCommand::TwinSim => twin_sim(&self.cfg, now).to_vec(),
        })
    }

    /// The store's collection due at `now`: the FC's own telemetry at once, the EPS's and the
    /// COMM's when they answer.
    fn collect(&mut self, node: &mut Node, now: SimTime) {
        if !self.store.take_due(now) {
            return;
        }
        let mask = self.store.config().mask;
        let rtc_s = self.rtc_unix_s(now);
        for (kind, c) in [
            (1, TelemetryCommand::TmGen),
            (2, TelemetryCommand::TmAtp),
            (3, TelemetryCommand::TmAcd),
            (4, TelemetryCommand::TmSens),
            (5, TelemetryCommand::TmRawSens),
        ] {
            if mask & (1 << (kind - 1)) != 0
                && let Ok(data) = self.telemetry(node, c, now)
            {
                self.store.push(rtc_s, kind, data);
            }
        }
        self.store.ask_others(node, now);
    }

    /// Send `p`'s telemetry from `now` on (the first one period later).
    fn set_periodic(&mut self, p: wire::Periodic, now: SimTime) {
        self.periodic = p;
        self.periodic_next = (p.period_ms > 0)
            .then(|| now + std::time::Duration::from_millis(u64::from(p.period_ms)));
        self.log.push(NodeEvent::info(
            now,
            match self.periodic_next {
                Some(_) => format!(
                    "fc: periodic telemetry {:#04x} to {}:{} every {} ms",
                    p.mask, p.dst, p.dport, p.period_ms
                ),
                None => "fc: periodic telemetry off".to_owned(),
            },
        ));
    }

    /// The periodic telemetry due by `now`: each of its commands as the bytes a request
    /// would get, from the FC's own port. Periods missed (the FC was off or hung) are not
    /// made up.
    fn send_periodic(&mut self, node: &mut Node, now: SimTime) {
        let Some(due) = self.periodic_next.filter(|&t| t <= now) else {
            return;
        };
        let p = self.periodic;
        let period = std::time::Duration::from_millis(u64::from(p.period_ms.max(1)));
        let mut next = due + period;
        while next <= now {
            next = next + period;
        }
        self.periodic_next = Some(next);
        for c in p.commands() {
            let data = match Request::parse(&[c])
                .ok()
                .and_then(|r| TelemetryCommand::parse(&r).ok())
            {
                Some(cmd) => match self.telemetry(node, cmd, now) {
                    Ok(d) => reqrep::success(c, &d),
                    Err(code) => vec![c, code],
                },
                None => reqrep::failure(c),
            };
            // From the FC's own port: nobody asked, so whatever answers it (a node reading
            // the telemetry as a request at `dport`) is dropped there, never served.
            let header = node.own_header(p.dst, p.dport);
            // A send failure is counted by the node.
            let _ = node.send(Packet::new(header, data), now);
        }
    }

    fn rtc(&mut self, c: RtcCommand, now: SimTime) -> Vec<u8> {
        match c {
            RtcCommand::Set(t) => {
                // Set against the clock as it runs (its errors keep running).
                self.rtc_offset_ns = i128::from(t.rtc_timestamp) * 1_000_000_000
                    - self.true_unix_ns(now)
                    - self.clock.error_ns(now);
                self.time_sync.soon(now);
                Vec::new()
            }
            RtcCommand::Get => RtcTimestamp {
                rtc_timestamp: self.rtc_unix_s(now),
            }
            .to_vec(),
        }
    }

    fn attitude_cmd(&mut self, c: AttitudeCommand, now: SimTime) -> Result<Vec<u8>, u8> {
        let now_ns = self.true_unix_ns_i64(now);
        let target = &mut self.fsw.target;
        Ok(match c {
            AttitudeCommand::GetAttitude => TargetAttitude { q: target.attitude }.to_vec(),
            AttitudeCommand::SetAttitude(q) => {
                target.attitude = q;
                target.attitude_set = true;
                Vec::new()
            }
            AttitudeCommand::GetPoint => TargetPoint { p: target.point }.to_vec(),
            AttitudeCommand::SetPoint(p) => {
                if !point_fits_mode(p, target.mode) {
                    return Err(RESULT_FAILURE);
                }
                target.point = p;
                target.point_set = true;
                Vec::new()
            }
            AttitudeCommand::GetMode => TargetModeRepr { mode: target.mode }.to_vec(),
            AttitudeCommand::SetMode(m) => {
                // The held point must make sense in the mode that reads it; earth target and
                // ECI vector tracking have no target before one is set (the default point
                // would be latitude 0, longitude 0).
                let needs_point = matches!(m, TargetMode::EarthTarget | TargetMode::EciVector);
                if (needs_point && !target.point_set)
                    || (target.point_set && !point_fits_mode(target.point, m))
                {
                    return Err(RESULT_FAILURE);
                }
                target.mode = m;
                Vec::new()
            }
            AttitudeCommand::SetTle(lines) => {
                let (l1, l2) = lines.text();
                let mut model = truth_model(Some(&(l1.clone(), l2.clone())));
                // A TLE the FC can fly with now: its epoch within TLE_MAX_AGE_S of the FC's
                // time (SGP4's error grows by kilometres a day), and SGP4 propagating to now
                // (not decayed).
                let fresh = Tle::parse(&l1, &l2, ChecksumMode::Strict).is_ok_and(|t| {
                    (t.epoch.unix_ns() - now_ns).unsigned_abs() as f64 * 1e-9 <= TLE_MAX_AGE_S
                });
                let flies = model.as_mut().is_ok_and(|m| m.state_j2000(now_ns).is_ok());
                if !(fresh && flies) {
                    return Err(RESULT_FAILURE);
                }
                let same = self
                    .cfg
                    .tle
                    .as_ref()
                    .is_some_and(|(a, b)| *a == l1 && *b == l2);
                self.onboard = Some(OnboardOrbit {
                    lines,
                    model,
                    same_as_truth: same,
                });
                Vec::new()
            }
            AttitudeCommand::GetTle => match &self.onboard {
                Some(o) => o.lines.to_vec(),
                None => return Err(RESULT_FAILURE),
            },
        })
    }
}

/// Whether target point `p` is valid in `mode`: ECI vector tracking reads it as a
/// direction (any non-zero length); every other mode as a geodetic point for earth target
/// (latitude -90..=90 deg, longitude -180..<360 deg, height -1 km..=100 km: the ranges of
/// the ICD 1.5 script's pointGEO).
fn point_fits_mode(p: [f64; 3], mode: TargetMode) -> bool {
    if mode == TargetMode::EciVector {
        p.iter().any(|&x| x != 0.0)
    } else {
        let [lat_deg, lon_deg, height_m] = p;
        (-90.0..=90.0).contains(&lat_deg)
            && (-180.0..360.0).contains(&lon_deg)
            && (-1_000.0..=100_000.0).contains(&height_m)
    }
}

fn sat_i8(x: f64) -> i8 {
    if x.is_nan() {
        0
    } else {
        x.round().clamp(-128.0, 127.0) as i8
    }
}

impl App for FcApp {
    type Event = Published;
    fn poll_event(&mut self) -> Option<Published> {
        self.out.pop()
    }
    fn start(&mut self, node: &mut Node, now: SimTime) {
        self.clock = node.clock_errors().clone();
        self.power_on.get_or_insert(now);
        let p = self.cfg.ports;
        for port in [p.telemetry, p.rtc, p.attitude, p.scripts] {
            node.bind(port);
        }
        self.catch_up(now);
        self.time_sync.start(node, now);
        self.time_sync.run(node, now, self.rtc_unix_ns(now));
        self.safe.start(node, now);
        self.safe.run(node, now);
        self.store.start(node, now);
        self.store_now = Some(now);
        self.periodic_next = None;
        self.periodic = wire::Periodic::default();
        if let Some(p) = self.cfg.periodic {
            self.set_periodic(p, now);
        }
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        self.clock = node.clock_errors().clone();
        self.store_now = Some(now);
        let p = self.cfg.ports;
        let dport = packet.header.dport;
        let src = packet.header.src;
        let command = packet.data.first().copied();
        let rtc_s = self.rtc_unix_s(now);
        if self.time_sync.handle_reply(&packet)
            || self.safe.handle_reply(&packet)
            || self.store.handle_reply(&packet, rtc_s)
        {
            return;
        }
        let (reply, refused) = if ![p.telemetry, p.rtc, p.attitude, p.scripts].contains(&dport) {
            return;
        } else if self
            .cfg
            .payload_access
            .refuses(src, p.open_to_payloads(dport, command))
        {
            self.denied += 1;
            self.log.push(NodeEvent::warning(
                now,
                format!(
                    "fc: payload {src} refused port {dport} command {}: not available to payloads (ICD 4.1)",
                    command.map_or("(none)".to_owned(), |c| c.to_string())
                ),
            ));
            (
                reqrep::failure(command.unwrap_or(0)),
                Some(reqrep::RequestError::Empty),
            )
        } else if dport == p.telemetry {
            serve::<TelemetryCommand>(&packet.data, |c| self.telemetry(node, c, now))
        } else if dport == p.rtc {
            serve::<RtcCommand>(&packet.data, |c| Ok(self.rtc(c, now)))
        } else if dport == p.attitude {
            serve::<AttitudeCommand>(&packet.data, |c| self.attitude_cmd(c, now))
        } else {
            // Scripts (ICD 1.5 text); the first byte stands for the command id in the reply.
            let command = command.unwrap_or(0);
            match self.submit_script(&packet.data, now) {
                Ok(()) => (vec![command, RESULT_SUCCESS], None),
                Err(why) => {
                    self.log.push(NodeEvent::info(
                        now,
                        format!(
                            "script rejected: {why}: {:?}",
                            String::from_utf8_lossy(&packet.data)
                        ),
                    ));
                    (reqrep::failure(command), Some(reqrep::RequestError::Empty))
                }
            }
        };
        if refused.is_some() {
            self.refused += 1;
        }
        // A send failure is already counted by the node.
        let _ = node.send(Packet::new(packet.header.reply(node.addr()), reply), now);
        // After an RTCSTMSET, the new time goes out at once.
        self.time_sync.run(node, now, self.rtc_unix_ns(now));
        self.flush_log(node);
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        [
            self.next_tick,
            self.time_sync.due(),
            self.safe.due(),
            self.store.due(),
            self.periodic_next,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        self.clock = node.clock_errors().clone();
        self.store_now = Some(now);
        self.catch_up(now);
        while let Some(t) = self.next_tick.filter(|&t| t <= now) {
            self.tick(t, true);
            self.next_tick = Some(t + std::time::Duration::from_nanos(self.dt_ns));
        }
        self.time_sync.run(node, now, self.rtc_unix_ns(now));
        self.safe.run(node, now);
        self.send_periodic(node, now);
        self.collect(node, now);
        self.flush_log(node);
    }

    fn reset(&mut self, _now: SimTime) {
        self.fsw = Fsw {
            adcs: Adcs::new(self.cfg.adcs.clone(), self.cfg.body.clone()),
            target: Target::default(),
            scripts: Schedule::new(),
            output: None,
            request_mode: None,
            gps_fix: None,
        };
        // A power cycle or reboot leaves the actuators off until the software commands them.
        self.wheel_cmd_nm = [0.0; 4];
        self.mtq_applied_am2 = Vector3::zeros();
        self.reset_cause = if std::mem::take(&mut self.power_was_lost) {
            RESET_POWER_ON
        } else {
            RESET_SOFTWARE
        };
    }

    fn power_lost(&mut self, _node: &mut Node, _now: SimTime) {
        self.power_was_lost = true;
    }

    fn params(&mut self) -> Option<&mut dyn csp::params::Table> {
        Some(self)
    }

    fn self_test(&mut self, _node: &Node, now: SimTime) -> Vec<csp::params::Check> {
        self.checks(now)
    }

    fn console_commands(&self) -> &'static [csp::console::Command] {
        config::COMMANDS
    }

    fn console(
        &mut self,
        node: &mut Node,
        words: &[&str],
        now: SimTime,
    ) -> Result<String, ConsoleError> {
        // As a CSP request at `now` would see the FC.
        self.clock = node.clock_errors().clone();
        self.store_now = Some(now);
        let r = match words {
            ["tm"] => self.console_tm(node, "gen", now).map_err(ConsoleError::app),
            ["tm", which] => self.console_tm(node, which, now).map_err(ConsoleError::app),
            ["store"] => {
                let i = self.store.info();
                let w = |k: usize| u32::from_le_bytes([i[k], i[k + 1], i[k + 2], i[k + 3]]);
                Ok(format!(
                    "records {} bytes {} oldest_rtc {} newest_rtc {} overwritten {} (period {} s, mask {:#04x})\n",
                    w(0),
                    w(4),
                    w(8),
                    w(12),
                    w(16),
                    self.store.config().period.map_or(0, |p| p.as_secs()),
                    self.store.config().mask
                ))
            }
            ["mode"] => {
                let t = self.fsw.target;
                let state = self.fsw.output.map_or(0, |o| o.state);
                Ok(format!(
                    "target mode {:?} (attitude set {}, point set {}), ADCS state {state}, FC state {}\n",
                    t.mode,
                    t.attitude_set,
                    t.point_set,
                    if self.safe.state() == safe::STATE_SAFE {
                        "safe"
                    } else {
                        "nominal"
                    },
                ))
            }
            _ => Err(ConsoleError::Usage(words.join(" "))),
        };
        self.flush_log(node);
        r
    }
}

/// TWINSIM's reply at `now` (the twin's own command): the true simulated time, not the RTC,
/// so that ground software finds the instant in the recording whatever RTCSTMSET or a
/// clock fault did to the FC's time.
fn twin_sim(cfg: &FcConfig, now: SimTime) -> wire::TwinSim {
    // The workspace's version, which every crate of the twin shares; Cargo's parts are
    // decimal numbers.
    let part = |p: &str| p.parse().unwrap_or(u8::MAX);
    wire::TwinSim {
        sim_time_ns: now.as_ns(),
        seed: cfg.run_seed,
        start_unix_s: cfg.epoch_unix_s,
        version_major: part(env!("CARGO_PKG_VERSION_MAJOR")),
        version_minor: part(env!("CARGO_PKG_VERSION_MINOR")),
        version_patch: part(env!("CARGO_PKG_VERSION_PATCH")),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    // 0.707106 is the ICD 1.5 example's value, deliberately not FRAC_1_SQRT_2.
    #![allow(clippy::approx_constant)]
    use super::*;
    use csp::Header;
    use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
    use csp::router::Route;
    use orbit::propagate::Propagator;
    use orbit::time::UtcTime;

    /// The default scenario's 6U TLE (scenarios/default.toml).
    const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
    const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
    /// 2026-04-30T18:00:00Z, the default scenario's `start`.
    const START: u64 = 1_777_572_000;

    /// The FC's node on one packet interface with a default route.
    fn node_cfg() -> NodeConfig {
        let mut c = NodeConfig::new("FC", 3);
        c.ifaces = vec![IfaceConfig::packet("p")];
        c.routes.set_default(Route::direct(0));
        c.epoch_unix_s = START;
        c
    }

    /// The FC without time distribution and EPS housekeeping: every packet it sends is a
    /// reply.
    fn host(tle: Option<(&str, &str)>) -> Host<FcApp> {
        let c = node_cfg();
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: tle.map(|(a, b)| (a.to_owned(), b.to_owned())),
            time_sync: timesync::TimeSyncConfig {
                to: Vec::new(),
                period: None,
            },
            safe: safe::SafeConfig {
                eps_poll: None,
                ..safe::SafeConfig::default()
            },
            ..FcConfig::default()
        });
        Host::new(c, app, SimTime::ZERO)
    }

    /// The CMP CLOCK requests the FC sent: (time sent, destination, tv_sec, tv_nsec).
    fn clock_sets(h: &mut Host<FcApp>, t: SimTime) -> Vec<(SimTime, u8, u32, u32)> {
        std::iter::from_fn(|| h.node.poll_transmit())
            .filter_map(|tx| match tx {
                Transmit::Packet { packet, .. } if packet.header.dport == 0 => {
                    let d = &packet.data;
                    assert_eq!(d[..2], [0, 6], "CMP CLOCK request");
                    assert_eq!(d.len(), 10);
                    let be = |i: usize| u32::from_be_bytes(d[i..i + 4].try_into().unwrap());
                    Some((t, packet.header.dst, be(2), be(6)))
                }
                _ => None,
            })
            .collect()
    }

    #[test]
    fn the_rtc_goes_to_the_pc_at_boot_after_rtcstmset_and_every_period() {
        let mut h = Host::new(
            node_cfg(),
            FcApp::new(FcConfig {
                epoch_unix_s: START,
                ..FcConfig::default()
            }),
            SimTime::ZERO,
        );
        let start = u32::try_from(START).unwrap();
        assert_eq!(
            clock_sets(&mut h, SimTime::ZERO),
            vec![(SimTime::ZERO, 6, start, 0)]
        );
        // RTCSTMSET +1000 s at 12.5 s: the reply, then the new time at once.
        let t = SimTime::from_ms(12_500);
        let set = [vec![1], (start + 1_012).to_le_bytes().to_vec()].concat();
        h.handle_packet(0, Packet::new(Header::new(16, 3, 11, 40), set), t);
        let Some(Transmit::Packet { packet, .. }) = h.node.poll_transmit() else {
            panic!("no reply")
        };
        assert_eq!(packet.data, vec![1, 1]);
        assert_eq!(clock_sets(&mut h, t), vec![(t, 6, start + 1_012, 0)]);
        // The period runs from the last send: 72.5 s, 132.5 s; the RTC runs on from its set.
        let mut sent = Vec::new();
        while let Some(due) = h.poll_timeout().filter(|&d| d <= SimTime::from_secs(135)) {
            h.handle_timeout(due);
            sent.extend(clock_sets(&mut h, due));
        }
        assert_eq!(
            sent,
            vec![
                (SimTime::from_ms(72_500), 6, start + 1_072, 0),
                (SimTime::from_ms(132_500), 6, start + 1_132, 0),
            ]
        );
        // The PC's answer is taken on the FC's port, not refused or dropped.
        let port = 32;
        let mut reply = vec![0xff, 6];
        reply.extend_from_slice(&[0; 8]);
        h.handle_packet(
            0,
            Packet::new(Header::new(6, 3, port, 0), reply),
            SimTime::from_secs(133),
        );
        assert!(h.node.poll_transmit().is_none());
        assert_eq!(h.node.counters().total_drops(), 0);
        assert_eq!((h.app.time_sync.sent, h.app.time_sync.replies), (4, 1));
    }

    fn ask(h: &mut Host<FcApp>, port: u8, req: &[u8], t: SimTime) -> Vec<u8> {
        ask_from(h, 16, port, req, t)
    }

    fn ask_from(h: &mut Host<FcApp>, src: u8, port: u8, req: &[u8], t: SimTime) -> Vec<u8> {
        h.handle_packet(
            0,
            Packet::new(Header::new(src, 3, port, 40), req.to_vec()),
            t,
        );
        // The time sent to the PC (CMP CLOCK) and the EPS housekeeping are not replies.
        // (They go to ports 0 and 10; replies come back to the asker's port 40.)
        let mut out = std::iter::from_fn(|| h.node.poll_transmit()).filter(
            |tx| !matches!(tx, Transmit::Packet { packet, .. } if packet.header.dport != 40),
        );
        let Some(Transmit::Packet { packet, .. }) = out.next() else {
            panic!("no reply to port {port} {req:02x?}")
        };
        assert_eq!(packet.header, Header::new(3, src, 40, port));
        assert!(out.next().is_none(), "one reply per request");
        packet.data
    }

    /// A console line's `key value...` answer lines.
    fn console_fields(text: &str) -> std::collections::BTreeMap<String, String> {
        text.lines()
            .filter_map(|l| l.split_once(' '))
            .map(|(k, v)| (k.to_owned(), v.to_owned()))
            .collect()
    }

    #[test]
    fn the_console_reads_the_telemetry_a_csp_request_gets_at_the_same_instant() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_ms(95_300);
        run_until(&mut h, t);
        let csp = wire::TmGen::parse(&ask(&mut h, 10, &[1], t)[2..]).unwrap();
        let text = h.console("tm gen", t);
        let f = console_fields(&text);
        // The ICD's names and units, one field a line, as `gs` prints the same reply.
        assert_eq!(
            f["rtc_timestamp"],
            format!("{} s", csp.rtc_timestamp),
            "{text}"
        );
        assert_eq!(f["uptime_s"], format!("{} s", csp.uptime_s));
        assert_eq!(
            f["current_mode"],
            format!("{} (detumble)", csp.current_mode)
        );
        assert_eq!(f["current_state"], "0 (nominal)");
        assert_eq!(f["reset_cause"], "0 (power-on)");
        assert_eq!(f["mcu_temp_c"], format!("{} degC", csp.mcu_temp_c));
        assert_eq!(
            text.lines().count(),
            <wire::TmGen as csp::icd::Describe>::FIELDS.len(),
            "{text}"
        );
        let sens = wire::TmSens::parse(&ask(&mut h, 10, &[4], t)[2..]).unwrap();
        let text = h.console("tm sens", t);
        let f = console_fields(&text);
        for (i, k) in sens.b_body_nt.iter().enumerate() {
            let c: f64 = f[&format!("b_body_nt[{i}]")]
                .strip_suffix(" nT")
                .unwrap()
                .parse()
                .unwrap();
            assert!((c - f64::from(*k)).abs() < 1e-3, "{text}");
        }
        let atp = wire::TmAtp::parse(&ask(&mut h, 10, &[2], t)[2..]).unwrap();
        let f = console_fields(&h.console("tm atp", t));
        for (i, k) in atp.q_eci_from_body.iter().enumerate() {
            let c: f64 = f[&format!("q_eci_from_body[{i}]")].parse().unwrap();
            assert!((c - k).abs() < 1e-6);
        }
        for (i, k) in atp.r_eci_m.iter().enumerate() {
            let c: f64 = f[&format!("r_eci_m[{i}]")]
                .strip_suffix(" m")
                .unwrap()
                .parse()
                .unwrap();
            assert!((c - k).abs() < 1e-6);
        }
        // Every telemetry has its readout; a bad one is a one-line error.
        for w in ["acd", "rawsens", "all"] {
            assert!(
                !h.console(&format!("tm {w}"), t).starts_with("error"),
                "{w}"
            );
        }
        assert_eq!(
            h.console("tm nothing", t),
            "error: tm: no telemetry \"nothing\" (gen, atp, acd, sens, rawsens, all)\n"
        );
        assert!(
            h.console("frobnicate", t)
                .starts_with("error: frobnicate: unknown command")
        );
    }

    #[test]
    fn help_lists_every_command_and_the_console_and_csp_share_one_parameter_table() {
        let mut h = host(Some((L1, L2)));
        let help = h.console("help", SimTime::ZERO);
        for c in csp::console::NODE_COMMANDS.iter().chain(config::COMMANDS) {
            assert!(
                help.lines().any(|l| l.starts_with(c.name)),
                "{} in {help}",
                c.name
            );
        }
        let t = SimTime::from_secs(5);
        // Set on the console, read over CSP (PGET bdot_gain, id 1, f32).
        assert!(h.console("param set bdot_gain 0.25", t).contains("0.25"));
        let got = ask(&mut h, csp::params::PORT, &[1, 1], t);
        assert_eq!(got[..4], [1, 1, 1, 5]);
        assert_eq!(f32::from_le_bytes(got[4..8].try_into().unwrap()), 0.25);
        assert_eq!(h.app.fsw.adcs.config().control.bdot_gain, 0.25, "in effect");
        // Out of range: one line naming the range; a rule between two parameters.
        let e = h.console("param set bdot_gain 7", t);
        assert!(
            e.starts_with("error: param: bdot_gain: 7 out of range 0..=1"),
            "{e}"
        );
        let e = h.console("param set safe_exit_soc 10", t);
        assert!(e.contains("below safe_enter_soc"), "{e}");
        // Not saved: a reboot restores the default.
        h.reboot(SimTime::from_secs(6));
        let d = ask(&mut h, csp::params::PORT, &[1, 1], SimTime::from_secs(6));
        assert_ne!(f32::from_le_bytes(d[4..8].try_into().unwrap()), 0.25);
        // Saved: it survives a reboot and a power cycle; `defaults` brings the factory value.
        h.console("param set bdot_gain 0.25", SimTime::from_secs(7));
        assert_eq!(h.console("param save", SimTime::from_secs(7)), "saved\n");
        h.power_lost(SimTime::from_secs(8));
        h.reboot(SimTime::from_secs(9));
        let got = ask(&mut h, csp::params::PORT, &[1, 1], SimTime::from_secs(9));
        assert_eq!(f32::from_le_bytes(got[4..8].try_into().unwrap()), 0.25);
        assert_eq!(
            h.app.fsw.adcs.config().control.bdot_gain,
            0.25,
            "in effect after boot"
        );
        assert_eq!(
            ask(&mut h, csp::params::PORT, &[6], SimTime::from_secs(9)),
            [6, 1]
        );
        assert_eq!(
            ask(&mut h, csp::params::PORT, &[1, 1], SimTime::from_secs(9)),
            d
        );
        // A payload may not configure the FC (ICD 4.1).
        let r = ask_from(
            &mut h,
            14,
            csp::params::PORT,
            &[2, 7, 0],
            SimTime::from_secs(9),
        );
        assert_eq!(r, [2, 0]);
        assert_eq!(h.node.counters().platform_refused, 1);
        // A lab bench opens it.
        let mut open = node_cfg();
        open.payload_access = platform::addr::PayloadAccess::Open;
        let mut bench = Host::new(open, FcApp::new(FcConfig::default()), SimTime::ZERO);
        let r = ask_from(&mut bench, 14, csp::params::PORT, &[2, 7, 0], SimTime::ZERO);
        assert_eq!(r, [2, 1, 7, 6, 0]);
        // The self-test: one line per component, the wire in the same order.
        let st = ask(&mut h, csp::params::PORT, &[7], SimTime::from_secs(9));
        let checks = h.app.checks(SimTime::from_secs(9));
        assert_eq!(st[3] as usize, checks.len());
        assert_eq!(st.len(), 4 + 5 * checks.len());
        let text = h.console("selftest", SimTime::from_secs(9));
        assert_eq!(text.lines().count(), 1 + checks.len(), "{text}");
    }

    #[test]
    fn the_store_keeps_the_telemetry_over_reboots_and_gives_it_by_time_range() {
        let mut h = host(Some((L1, L2)));
        // Every second: TMGEN and the EPS's TMEPS.
        let p = csp::params::PORT;
        assert_eq!(
            ask(&mut h, p, &[2, 14, 1, 0, 0, 0], SimTime::ZERO)[..2],
            [2, 1]
        );
        assert_eq!(ask(&mut h, p, &[2, 15, 0x41], SimTime::ZERO)[..2], [2, 1]);
        // TMALL's bit is refused.
        assert_eq!(ask(&mut h, p, &[2, 15, 0x20], SimTime::ZERO), [2, 0]);
        let mut eps_asks = Vec::new();
        let end = SimTime::from_ms(3_500);
        while let Some(t) = h.poll_timeout().filter(|&t| t <= end) {
            h.handle_timeout(t);
            while let Some(tx) = h.node.poll_transmit() {
                if let Transmit::Packet { packet, .. } = tx
                    && packet.header.dst == 4
                {
                    eps_asks.push((t, packet));
                }
            }
        }
        assert_eq!(eps_asks.len(), 3, "at 1, 2 and 3 s");
        // The EPS answers the last one.
        let (t, ask_eps) = &eps_asks[2];
        let mut reply = vec![1, 1];
        reply.extend([7u8; 88]);
        h.handle_packet(0, Packet::new(ask_eps.header.reply(4), reply), *t);
        let start = u32::try_from(START).unwrap();
        let info = ask(&mut h, 10, &[9], end);
        assert_eq!(info[2..6], 4u32.to_le_bytes(), "3 TMGEN and a TMEPS");
        assert_eq!(info[10..14], (start + 1).to_le_bytes());
        // Reboot: the records stay; TMGEN's uptime says which boot took them.
        h.reboot(end);
        let mut req = vec![10];
        for v in [start + 2, start + 3, 0] {
            req.extend(v.to_le_bytes());
        }
        let got = ask(&mut h, 10, &req, end);
        assert_eq!(got[..2], [10, 1]);
        assert_eq!(
            got[2..6],
            3u32.to_le_bytes(),
            "2 s: TMGEN; 3 s: TMGEN and TMEPS"
        );
        assert_eq!(got[6], 3, "5 + 22 + 22 + 94 bytes fit in 200");
        let rec = &got[7..];
        assert_eq!(
            rec[..6],
            [(start + 2).to_le_bytes().as_slice(), &[1, 16]].concat()
        );
        let g = wire::TmGen::parse(&rec[6..22]).unwrap();
        assert_eq!(g.uptime_s, 2);
        assert_eq!(rec[22 + 4..22 + 6], [1, 16]);
        req[9..13].copy_from_slice(&2u32.to_le_bytes());
        let rest = ask(&mut h, 10, &req, end);
        assert_eq!(rest[2..7], [3, 0, 0, 0, 1], "skipping two: the TMEPS");
        assert_eq!(rest[7 + 4..7 + 6], [7, 88]);
        assert_eq!(rest[7 + 6..], [7u8; 88]);
        // A range backwards, a payload: refused. Clear: the count.
        let mut back = vec![10];
        for v in [start + 3, start + 2, 0] {
            back.extend(v.to_le_bytes());
        }
        assert_eq!(ask(&mut h, 10, &back, end), [10, 0]);
        assert_eq!(ask_from(&mut h, 13, 10, &req, end), [10, 0]);
        assert_eq!(ask(&mut h, 10, &[11], end), [11, 1, 4, 0, 0, 0]);
        assert!(h.console("store", end).starts_with("records 0 "));
    }

    #[test]
    fn a_dead_wheel_and_an_unused_sensor_show_in_the_self_test() {
        let mut h = host(Some((L1, L2)));
        run_until(&mut h, SimTime::from_secs(2));
        h.app.wheel_fault[2] = Some(WheelFault::Stuck);
        h.console("param set use_mag off", SimTime::from_secs(2));
        let text = h.console("selftest", SimTime::from_secs(2));
        let line = |name: &str| {
            text.lines()
                .find(|l| l.starts_with(name))
                .unwrap()
                .to_owned()
        };
        assert!(line("wheel3").contains("FAILED"), "{text}");
        assert!(line("wheel1").contains(" ok "), "{text}");
        assert!(line("magnetometer").contains(" off "), "{text}");
        assert!(text.starts_with("overall FAILED"), "{text}");
    }

    #[test]
    fn a_low_battery_makes_the_fc_safe_and_points_the_arrays_at_the_sun_until_it_recovers() {
        let mut h = Host::new(
            node_cfg(),
            FcApp::new(FcConfig {
                epoch_unix_s: START,
                tle: Some((L1.to_owned(), L2.to_owned())),
                ..FcConfig::default()
            }),
            SimTime::ZERO,
        );
        // The FC's TMEPS requests to the EPS (4, port 10): the port each came from.
        let polls = |h: &mut Host<FcApp>| -> Vec<u8> {
            std::iter::from_fn(|| h.node.poll_transmit())
                .filter_map(|tx| match tx {
                    Transmit::Packet { packet, .. } if packet.header.dst == 4 => {
                        assert_eq!((packet.header.dport, packet.data.clone()), (10, vec![1]));
                        Some(packet.header.sport)
                    }
                    _ => None,
                })
                .collect()
        };
        let answer = |h: &mut Host<FcApp>, port: u8, soc: f32, t: SimTime| {
            let mut d = vec![1, 1];
            icd::eps::TmEps {
                soc,
                ..Default::default()
            }
            .emit(&mut d);
            h.handle_packet(0, Packet::new(Header::new(4, 3, port, 10), d), t);
        };
        let run_to = |h: &mut Host<FcApp>, until: SimTime| {
            while let Some(due) = h.poll_timeout().filter(|&d| d <= until) {
                h.handle_timeout(due);
            }
        };
        let state = |h: &mut Host<FcApp>, t| {
            TmGen::parse(&ask(h, 10, &[1], t)[2..])
                .unwrap()
                .current_state
        };
        let port = polls(&mut h)[0];
        ask(&mut h, 12, &[6, 3], SimTime::from_ms(1));
        answer(&mut h, port, 0.12, SimTime::from_ms(5));
        run_to(&mut h, SimTime::from_secs(2));
        assert_eq!(state(&mut h, SimTime::from_secs(2)), safe::STATE_SAFE);
        assert_eq!(h.app.fsw.request_mode, Some(TargetMode::SunMaxPower));
        // The commanded mode stays nadir (TMACD trgt_mode), and comes back with the battery.
        assert_eq!(ask(&mut h, 12, &[5], SimTime::from_secs(2)), vec![5, 1, 3]);
        // Every 30 s; 25 % is not yet back (the way back is at 30 %).
        run_to(&mut h, SimTime::from_secs(30));
        assert_eq!(polls(&mut h), vec![port]);
        answer(&mut h, port, 0.25, SimTime::from_ms(30_005));
        run_to(&mut h, SimTime::from_secs(31));
        assert_eq!(state(&mut h, SimTime::from_secs(31)), safe::STATE_SAFE);
        run_to(&mut h, SimTime::from_secs(60));
        polls(&mut h);
        answer(&mut h, port, 0.31, SimTime::from_ms(60_005));
        run_to(&mut h, SimTime::from_secs(61));
        assert_eq!(state(&mut h, SimTime::from_secs(61)), safe::STATE_NOMINAL);
        assert_eq!(h.app.fsw.request_mode, Some(TargetMode::Nadir));
        assert_eq!((h.app.safe.polls, h.app.safe.replies), (3, 3));
    }

    #[test]
    fn periodic_telemetry_goes_where_tmperset_says_until_it_is_stopped_or_the_fc_reboots() {
        let mut h = host(Some((L1, L2)));
        let set = |dst: u8, dport: u8, period_ms: u32, mask: u8| {
            let mut v = vec![wire::cmd::TMPERSET];
            wire::Periodic {
                dst,
                dport,
                period_ms,
                mask,
            }
            .emit(&mut v);
            v
        };
        // Out of range: period, destination (broadcast, the FC itself), a service port, mask.
        for bad in [
            set(16, 20, 99, 1),
            set(16, 20, 3_600_001, 1),
            set(31, 20, 500, 1),
            set(3, 20, 500, 1),
            set(16, 6, 500, 1),
            set(16, 20, 500, 0),
            set(16, 20, 500, 0x40),
        ] {
            assert_eq!(
                ask(&mut h, 10, &bad, SimTime::ZERO),
                vec![7, 0],
                "{bad:02x?}"
            );
        }
        assert_eq!(
            ask(&mut h, 10, &set(16, 20, 500, 0x03), SimTime::ZERO),
            vec![7, 1]
        );
        assert_eq!(
            ask(&mut h, 10, &[8], SimTime::ZERO),
            vec![8, 1, 16, 20, 0xf4, 1, 0, 0, 3]
        );
        let mut sent = Vec::new();
        let run_to = |h: &mut Host<FcApp>, until: SimTime, sent: &mut Vec<(SimTime, Packet)>| {
            while let Some(due) = h.poll_timeout().filter(|&d| d <= until) {
                h.handle_timeout(due);
                while let Some(tx) = h.node.poll_transmit() {
                    if let Transmit::Packet { packet, .. } = tx {
                        sent.push((due, packet));
                    }
                }
            }
        };
        run_to(&mut h, SimTime::from_ms(2_100), &mut sent);
        let own = h.node.own_port();
        assert!(own >= csp::header::EPHEMERAL_PORT_MIN, "{own}");
        let got: Vec<(u64, u8, usize)> = sent
            .iter()
            .map(|(t, p)| {
                assert_eq!(p.header, Header::new(3, 16, 20, own));
                assert_eq!(p.data[1], 1);
                (t.as_ms(), p.data[0], p.data.len())
            })
            .collect();
        let want: Vec<(u64, u8, usize)> = [500, 1000, 1500, 2000]
            .into_iter()
            .flat_map(|t| [(t, 1, 2 + TmGen::LEN), (t, 2, 2 + TmAtp::LEN)])
            .collect();
        assert_eq!(got, want);
        // The TMGEN sent is the one a request gets at that instant.
        let g = TmGen::parse(&sent[6].1.data[2..]).unwrap();
        assert_eq!(g.uptime_s, 2);
        // Stopped: nothing more. A reboot returns to the configuration (none here).
        assert_eq!(
            ask(&mut h, 10, &set(0, 0, 0, 0), SimTime::from_ms(2_100)),
            vec![7, 1]
        );
        sent.clear();
        run_to(&mut h, SimTime::from_secs(4), &mut sent);
        assert!(sent.is_empty(), "{sent:?}");
        ask(&mut h, 10, &set(16, 20, 500, 0x01), SimTime::from_secs(4));
        h.reboot(SimTime::from_secs(5));
        run_to(&mut h, SimTime::from_secs(7), &mut sent);
        assert!(sent.iter().all(|(_, p)| p.header.dport != 20), "{sent:?}");
        assert_eq!(
            ask(&mut h, 10, &[8], SimTime::from_secs(7)),
            vec![8, 1, 0, 0, 0, 0, 0, 0, 0]
        );
    }

    /// Periodic telemetry to a port where a node serves requests (the PC's control port 10,
    /// which reads TMGEN's `01 01 ...` as a SETUP) is answered there; that answer reaches
    /// the FC's own port, where it is dropped and counted, never served. Sent from the
    /// telemetry port, the answer would be read as a TMGEN request and answered, and the two
    /// nodes would answer each other for ever (a reply storm on the main bus).
    #[test]
    fn an_answer_to_periodic_telemetry_is_dropped_not_served() {
        let mut h = host(Some((L1, L2)));
        let mut set = vec![wire::cmd::TMPERSET];
        wire::Periodic {
            dst: 6,
            dport: 10,
            period_ms: 500,
            mask: 0x01,
        }
        .emit(&mut set);
        assert_eq!(ask(&mut h, 10, &set, SimTime::ZERO), vec![7, 1]);
        let t = SimTime::from_ms(500);
        h.handle_timeout(t);
        let mut sent = Vec::new();
        while let Some(tx) = h.node.poll_transmit() {
            if let Transmit::Packet { packet, .. } = tx {
                sent.push(packet);
            }
        }
        let tm = sent.iter().find(|p| p.header.dst == 6).unwrap();
        assert_eq!(tm.data[..2], [1, 1], "TMGEN, success");
        // The PC's answer, from its control port to where the telemetry came from.
        let answer = Packet::new(tm.header.reply(6), vec![1, 1]);
        h.handle_packet(0, answer, SimTime::from_ms(510));
        let mut out = Vec::new();
        while let Some(tx) = h.node.poll_transmit() {
            out.push(tx);
        }
        assert!(out.is_empty(), "the FC answered the answer: {out:?}");
        assert_eq!(
            h.node.counters().drops.get(&csp::drop::DropReason::OwnPort),
            Some(&1)
        );
    }

    #[test]
    fn atcptset_is_range_checked_in_the_reading_of_the_commanded_mode() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(1);
        // ECI vector tracking with no direction set is refused.
        assert_eq!(ask(&mut h, 12, &[6, 6], t), vec![6, 0]);
        let set = |p: [f64; 3]| {
            let mut v = vec![4];
            for x in p {
                v.extend_from_slice(&x.to_le_bytes());
            }
            v
        };
        // Geodetic (every mode but ECI vector tracking): lat, lon deg, height m.
        for (p, ok) in [
            ([954.7, 0.0, 0.0], false),
            ([90.5, 0.0, 0.0], false),
            ([-90.5, 0.0, 0.0], false),
            ([0.0, 360.5, 0.0], false),
            ([0.0, 360.0, 0.0], false),
            ([0.0, -180.5, 0.0], false),
            ([0.0, 0.0, 100_001.0], false),
            ([0.0, 0.0, -1_001.0], false),
            ([54.7, 25.3, 120.0], true),
            ([-90.0, 359.0, -400.0], true),
        ] {
            assert_eq!(ask(&mut h, 12, &set(p), t), vec![4, u8::from(ok)], "{p:?}");
        }
        assert_eq!(h.app.target().point, [-90.0, 359.0, -400.0]);
        // ECI vector tracking (6): any non-zero direction.
        assert_eq!(ask(&mut h, 12, &[6, 6], t), vec![6, 1]);
        assert_eq!(ask(&mut h, 12, &set([954.7, 3.0, 1.0]), t), vec![4, 1]);
        assert_eq!(ask(&mut h, 12, &set([0.0; 3]), t), vec![4, 0]);
        // Earth target (5) refuses the direction held: the mode stays.
        assert_eq!(ask(&mut h, 12, &[6, 5], t), vec![6, 0]);
        assert_eq!(ask(&mut h, 12, &[5], t), vec![5, 1, 6]);
        assert_eq!(ask(&mut h, 12, &set([54.7, 25.3, 0.0]), t), vec![4, 1]);
        assert_eq!(ask(&mut h, 12, &[6, 5], t), vec![6, 1]);
    }

    #[test]
    fn a_payload_gets_only_the_commands_icd_4_1_stars_unless_access_is_open() {
        use platform::addr::PayloadAccess;
        let starred: [(u8, Vec<u8>); 5] = [
            (10, vec![1]),
            (10, vec![2]),
            (10, vec![3]),
            (10, vec![4]),
            (11, vec![2]),
        ];
        let others: [(u8, Vec<u8>); 10] = [
            (10, vec![5]),
            (10, vec![6]),
            (10, vec![8]),
            (10, vec![wire::cmd::TWINSIM]),
            (11, [vec![1], 1_000u32.to_le_bytes().to_vec()].concat()),
            (12, vec![1]),
            (12, vec![5]),
            (12, vec![6, 3]),
            (12, vec![8]),
            (13, b"adcs 1 2 pointECI 1 0 0 0".to_vec()),
        ];
        for access in [PayloadAccess::Icd, PayloadAccess::Open] {
            let mut h = host(Some((L1, L2)));
            h.app.cfg.payload_access = access;
            let t = SimTime::from_secs(10);
            for (port, req) in &starred {
                let r = ask_from(&mut h, 12, *port, req, t);
                assert_eq!(r[..2], [req[0], 1], "{access:?} port {port} {req:02x?}");
            }
            for (port, req) in &others {
                for pl in [12, 13, 14, 15] {
                    let r = ask_from(&mut h, pl, *port, req, t);
                    let ground = ask(&mut h, *port, req, t);
                    match access {
                        PayloadAccess::Icd => assert_eq!(r, vec![req[0], 0], "{port} {req:02x?}"),
                        PayloadAccess::Open => assert_eq!(r[1], ground[1], "{port} {req:02x?}"),
                    }
                }
            }
            // An empty request is refused either way; no other node is a payload.
            assert_eq!(ask_from(&mut h, 13, 10, &[], t), vec![0, 0]);
            for src in [1, 2, 4, 5, 6, 16, 20] {
                assert_eq!(ask_from(&mut h, src, 10, &[6], t)[..2], [6, 1]);
            }
            let denied = match access {
                PayloadAccess::Icd => 4 * others.len() as u64 + 1,
                PayloadAccess::Open => 0,
            };
            assert_eq!(h.app.denied(), denied, "{access:?}");
        }
        // Refused, a payload's ATCMDSET changes nothing.
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(10);
        let before = *h.app.target();
        assert_eq!(ask_from(&mut h, 12, 12, &[6, 3], t), vec![6, 0]);
        assert_eq!(*h.app.target(), before);
    }

    /// TWINSIM (the twin's own) answers the true simulated time since the run's start, the
    /// run's seed, the run's start and the twin's version, whatever RTCSTMSET did to the RTC.
    #[test]
    fn twinsim_answers_the_simulated_time_the_run_seed_and_the_version() {
        let mut h = host(Some((L1, L2)));
        h.app.cfg.run_seed = 0xfeed_0000_0000_0042;
        let t = SimTime::from_ns(95_300_000_123);
        let r = ask(&mut h, 10, &[wire::cmd::TWINSIM], t);
        assert_eq!(r[..2], [wire::cmd::TWINSIM, 1]);
        assert_eq!(r.len(), 2 + 27);
        let sim = wire::TwinSim::parse(&r[2..]).unwrap();
        let version: Vec<u8> = env!("CARGO_PKG_VERSION")
            .split('.')
            .map(|p| p.parse().unwrap())
            .collect();
        assert_eq!(
            sim,
            wire::TwinSim {
                sim_time_ns: 95_300_000_123,
                seed: 0xfeed_0000_0000_0042,
                start_unix_s: START,
                version_major: version[0],
                version_minor: version[1],
                version_patch: version[2],
            }
        );
        // The bytes: the time first, little-endian.
        assert_eq!(r[2..10], 95_300_000_123u64.to_le_bytes());
        // An RTC set a day ahead moves TMGEN's time, not TWINSIM's.
        let t2 = SimTime::from_secs(100);
        let ahead = u32::try_from(START + 100 + 86_400).unwrap();
        let set = [vec![wire::cmd::RTCSTMSET], ahead.to_le_bytes().to_vec()].concat();
        assert_eq!(ask(&mut h, 11, &set, t2), [wire::cmd::RTCSTMSET, 1]);
        let tm_gen = wire::TmGen::parse(&ask(&mut h, 10, &[1], t2)[2..]).unwrap();
        assert_eq!(tm_gen.rtc_timestamp, ahead);
        let sim = wire::TwinSim::parse(&ask(&mut h, 10, &[wire::cmd::TWINSIM], t2)[2..]).unwrap();
        assert_eq!(sim.sim_time_ns, t2.as_ns());
        // A request with data is refused, as the port's other reads.
        assert_eq!(
            ask(&mut h, 10, &[wire::cmd::TWINSIM, 0], t2),
            [wire::cmd::TWINSIM, 0]
        );
    }

    #[test]
    fn start_is_the_default_scenario_start() {
        assert_eq!(
            UtcTime::from_iso8601("2026-04-30T18:00:00Z").unwrap(),
            UtcTime::from_unix_ns(START as i64 * 1_000_000_000)
        );
    }

    #[test]
    fn tmatp_position_is_the_orbit_crate_j2000_position_in_metres() {
        let mut h = host(Some((L1, L2)));
        let mut prop =
            Sgp4Propagator::new(&Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()).unwrap();
        for t_s in [0u64, 1, 600, 5432, 3 * 3600] {
            let t = SimTime::from_secs(t_s);
            let reply = ask(&mut h, 10, &[2], t);
            assert_eq!(&reply[..2], &[2, 1]);
            let atp = TmAtp::parse(&reply[2..]).unwrap();
            let want = prop
                .state_j2000(UtcTime::from_unix_ns(
                    ((START + t_s) * 1_000_000_000) as i64,
                ))
                .unwrap()
                .r_km
                * 1e3;
            for i in 0..3 {
                assert_eq!(atp.r_eci_m[i], want[i], "t = {t_s} s, axis {i}");
            }
            let r = want.norm();
            assert!((6.6e6..7.0e6).contains(&r), "{r}");
            assert_eq!(atp.rtc_timestamp as u64, START + t_s);
            assert_eq!(atp.q_eci_from_body, [1.0, 0.0, 0.0, 0.0]);
        }
    }

    #[test]
    fn tmgen_counts_uptime_and_on_time_across_a_reboot() {
        let mut h = host(Some((L1, L2)));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_secs(100))[2..]).unwrap();
        assert_eq!(
            g,
            TmGen {
                rtc_timestamp: (START + 100) as u32,
                uptime_s: 100,
                global_on_time_s: 100,
                current_mode: TargetMode::Detumble as u8,
                current_state: 0,
                mcu_temp_c: 20,
                reset_cause: RESET_POWER_ON,
            }
        );
        ask(&mut h, 12, &[6, 3], SimTime::from_secs(150));
        h.reboot(SimTime::from_secs(200));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_secs(230))[2..]).unwrap();
        assert_eq!(
            (g.uptime_s, g.global_on_time_s, g.reset_cause),
            (30, 230, RESET_SOFTWARE)
        );
        assert_eq!(
            g.current_mode,
            TargetMode::Detumble as u8,
            "target is volatile"
        );
        // A power cycle is a power-on (it read as a software reset); a reboot after it is
        // a software reset again.
        h.power_lost(SimTime::from_secs(300));
        h.reboot(SimTime::from_secs(310));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_secs(320))[2..]).unwrap();
        assert_eq!((g.uptime_s, g.reset_cause), (10, RESET_POWER_ON));
        h.reboot(SimTime::from_secs(400));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_secs(401))[2..]).unwrap();
        assert_eq!(g.reset_cause, RESET_SOFTWARE);
    }

    #[test]
    fn rtc_set_then_get() {
        let mut h = host(None);
        let t = SimTime::from_ms(10_500);
        assert_eq!(ask(&mut h, 11, &[1, 0x80, 0x3e, 0x0c, 0x5e], t), vec![1, 1]);
        // 0x5e0c3e80 = 1577860736
        assert_eq!(ask(&mut h, 11, &[2], t), vec![2, 1, 0x80, 0x3e, 0x0c, 0x5e]);
        let later = ask(&mut h, 11, &[2], SimTime::from_ms(20_499));
        assert_eq!(
            RtcTimestamp::parse(&later[2..]).unwrap().rtc_timestamp,
            1_577_860_736 + 9
        );
        // The RTC survives a reboot; TMGEN and TMATP carry it.
        h.reboot(SimTime::from_secs(30));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_ms(30_500))[2..]).unwrap();
        assert_eq!(g.rtc_timestamp, 1_577_860_736 + 20);
    }

    #[test]
    fn attitude_point_and_mode_set_then_get() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(5);
        let q = TargetAttitude {
            q: [0.5, -0.5, 0.5, 0.5],
        };
        let mut req = vec![2];
        q.emit(&mut req);
        assert_eq!(ask(&mut h, 12, &req, t), vec![2, 1]);
        let got = ask(&mut h, 12, &[1], t);
        assert_eq!(got[..2], [1, 1]);
        assert_eq!(TargetAttitude::parse(&got[2..]).unwrap(), q);

        // An ICD-style, not quite unit, quaternion is normalised.
        let mut req = vec![2];
        TargetAttitude {
            q: [0.707106, 0.0, 0.0, -0.707106],
        }
        .emit(&mut req);
        assert_eq!(ask(&mut h, 12, &req, t), vec![2, 1]);
        let n = TargetAttitude::parse(&ask(&mut h, 12, &[1], t)[2..]).unwrap();
        assert!((n.q[0] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);
        assert!((n.q[3] + std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);

        let mut req = vec![4];
        TargetPoint {
            p: [54.6872, 25.2797, 100.0],
        }
        .emit(&mut req);
        assert_eq!(ask(&mut h, 12, &req, t), vec![4, 1]);
        assert_eq!(ask(&mut h, 12, &[3], t)[2..], req[1..]);

        assert_eq!(ask(&mut h, 12, &[5], t), vec![5, 1, 1], "boots in detumble");
        assert_eq!(ask(&mut h, 12, &[6, 7], t), vec![6, 1]);
        assert_eq!(ask(&mut h, 12, &[5], t), vec![5, 1, 7]);

        // TMATP reports the ADCS estimate: none yet (no tick has run), so the identity.
        let atp = TmAtp::parse(&ask(&mut h, 10, &[2], t)[2..]).unwrap();
        assert_eq!(atp.q_eci_from_body, [1.0, 0.0, 0.0, 0.0]);
        let acd = TmAcd::parse(&ask(&mut h, 10, &[3], t)[2..]).unwrap();
        assert_eq!(
            (acd.target_mode, acd.target_attitude, acd.target_point),
            (7, 1, 1)
        );
        let all = ask(&mut h, 10, &[6], t);
        assert_eq!(all.len(), 2 + 177);
        let all = TmAll::parse(&all[2..]).unwrap();
        assert_eq!(all.attitude_position, atp);
        assert_eq!(all.attitude_control, acd);
    }

    #[test]
    fn every_reply_has_its_icd_size() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(1);
        for (port, req, len) in [
            (10, vec![1], 16),
            (10, vec![2], 60),
            (10, vec![3], 19),
            (10, vec![4], 70),
            (10, vec![5], 53),
            (10, vec![6], 177),
            (11, vec![2], 4),
            (12, vec![1], 32),
            (12, vec![3], 24),
            (12, vec![5], 1),
        ] {
            let r = ask(&mut h, port, &req, t);
            assert_eq!(r[..2], [req[0], 1], "port {port} {req:?}");
            assert_eq!(r.len(), 2 + len, "port {port} {req:?}");
        }
    }

    #[test]
    fn every_malformed_request_gets_the_failure_reply() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(1);
        let nan_q = {
            let mut v = vec![2];
            TargetAttitude {
                q: [f64::NAN, 0.0, 0.0, 1.0],
            }
            .emit(&mut v);
            v
        };
        let inf_p = {
            let mut v = vec![4];
            TargetPoint {
                p: [0.0, f64::INFINITY, 0.0],
            }
            .emit(&mut v);
            v
        };
        let cases: Vec<(u8, Vec<u8>)> = vec![
            (10, vec![0]),
            (10, vec![7]),
            (10, vec![0xff]),
            (10, vec![1, 0]),
            (10, vec![2, 0, 0]),
            (11, vec![0]),
            (11, vec![3]),
            (11, vec![1]),
            (11, vec![1, 1, 2, 3]),
            (11, vec![1, 1, 2, 3, 4, 5]),
            (11, vec![2, 0]),
            (12, vec![0]),
            (12, vec![7]),
            (12, vec![1, 0]),
            (12, [vec![2], vec![0; 16]].concat()),
            (12, [vec![2], vec![0; 32]].concat()),
            (12, nan_q),
            (12, [vec![4], vec![0; 16]].concat()),
            (12, inf_p),
            (12, vec![6]),
            (12, vec![6, 10]),
            (12, vec![6, 0xff]),
            (12, vec![6, 1, 1]),
            (13, vec![1, b'a']),
            (13, b"adcs 1 2 pointECI 1 0 0 0".to_vec()),
        ];
        for (port, req) in cases {
            assert_eq!(
                ask(&mut h, port, &req, t),
                vec![req[0], 0],
                "port {port} {req:02x?}"
            );
        }
        assert_eq!(ask(&mut h, 10, &[], t), vec![0, 0]);
        assert_eq!(ask(&mut h, 12, &[], t), vec![0, 0]);
        // Nothing malformed changed the target.
        assert_eq!(*h.app.target(), Target::default());
        assert!(h.app.refused() >= 20);
    }

    #[test]
    fn no_tle_or_a_decayed_orbit_fails_tmatp_and_tmall_only() {
        let mut h = host(None);
        let t = SimTime::from_secs(1);
        assert_eq!(h.app.orbit_error(), Some(&OrbitError::NoTle));
        assert_eq!(ask(&mut h, 10, &[2], t), vec![2, 0]);
        assert_eq!(ask(&mut h, 10, &[6], t), vec![6, 0]);
        assert_eq!(ask(&mut h, 10, &[1], t)[..2], [1, 1]);

        let mut h = host(Some((
            L1,
            "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 5000",
        )));
        let e = h.app.orbit_error().unwrap();
        assert!(matches!(e, OrbitError::Tle(_)), "{e:?}");
        assert!(e.to_string().starts_with("TLE: "), "{e}");
        assert_eq!(ask(&mut h, 10, &[2], t), vec![2, 0]);

        // A very low, high-drag orbit decays within days: propagation errors, no panic.
        let l1 = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  99999-0 0  9990";
        let l2 = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 16.40000000 50002";
        let fix = |l: &str| {
            let body = &l[..68];
            format!("{body}{}", orbit::tle::checksum(body))
        };
        let (l1, l2) = (fix(l1), fix(l2));
        let mut h = host(Some((&l1, &l2)));
        assert_eq!(h.app.orbit_error(), None, "{:?}", h.app.orbit_error());
        let late = SimTime::from_secs(200 * 86_400);
        let why = h.app.position_eci_m(late).unwrap_err();
        assert!(
            matches!(
                why,
                PositionError::Propagation(
                    PropagationError::Sgp4 { .. } | PropagationError::Decayed
                )
            ),
            "{why:?}"
        );
        assert_eq!(ask(&mut h, 10, &[2], late), vec![2, 0]);
        assert_eq!(ask(&mut h, 10, &[1], late)[..2], [1, 1]);
    }

    /// A nadir-pointing FC with the default TLE, flown for `secs` seconds.
    fn flown(secs: u64) -> Host<FcApp> {
        let c = node_cfg();
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: Some((L1.to_owned(), L2.to_owned())),
            initial_mode: TargetMode::Nadir,
            initial: InitialState {
                w_body_rad_s: Vector3::new(0.0, 0.005, 0.0),
                ..InitialState::default()
            },
            ..FcConfig::default()
        });
        let mut h = Host::new(c, app, SimTime::ZERO);
        let end = SimTime::from_secs(secs);
        while let Some(t) = h.poll_timeout().filter(|&t| t <= end) {
            h.handle_timeout(t);
        }
        while h.node.poll_event().is_some() {}
        h
    }

    fn run_until(h: &mut Host<FcApp>, end: SimTime) {
        while let Some(t) = h.poll_timeout().filter(|&t| t <= end) {
            h.handle_timeout(t);
        }
    }

    /// The FC saved 90 s into a flight (nadir commanded, a parameter set, the store
    /// recording) and loaded into one fresh from the same configuration goes on as the
    /// original: the same published truth, events and telemetry to the bit, the same bytes.
    #[test]
    fn an_fc_saved_mid_flight_and_loaded_into_a_fresh_one_goes_on_the_same() {
        let drain = |h: &mut Host<FcApp>| {
            let mut seen = Vec::new();
            while let Some(e) = h.poll_event() {
                seen.push(format!("{e:?}"));
            }
            while let Some(e) = h.node.poll_event() {
                seen.push(format!("{e:?}"));
            }
            seen
        };
        let mut a = host(Some((L1, L2)));
        ask(&mut a, 12, &[6, 3], SimTime::from_ms(1));
        // Parameter 4 (max rate, deg/s) set through the platform port.
        let set = [2u8, 4, 0, 0, 0x40, 0x40];
        ask(&mut a, csp::params::PORT, &set, SimTime::from_ms(2));
        run_until(&mut a, SimTime::from_secs(90));
        drain(&mut a);
        let bytes = snap::to_bytes(&a);
        let mut b = host(Some((L1, L2)));
        drain(&mut b);
        snap::load_from(&mut b, &bytes).unwrap();
        assert_eq!(snap::to_bytes(&b), bytes);
        for h in [&mut a, &mut b] {
            run_until(h, SimTime::from_secs(180));
        }
        let (ea, eb) = (drain(&mut a), drain(&mut b));
        assert!(ea.len() >= 90, "{}", ea.len());
        assert_eq!(ea, eb);
        let t = SimTime::from_secs(180);
        assert_eq!(ask(&mut a, 10, &[1], t), ask(&mut b, 10, &[1], t));
        assert_eq!(snap::to_bytes(&a), snap::to_bytes(&b));
    }

    #[test]
    fn tmatp_with_gps_and_no_tle_gives_the_latest_fix_between_ticks() {
        let mut cfg = FcConfig {
            epoch_unix_s: START,
            tle: Some((L1.to_owned(), L2.to_owned())),
            tle_uploaded: false,
            ..FcConfig::default()
        };
        cfg.sensors.gps_enabled = true;
        let mut h = Host::new(node_cfg(), FcApp::new(cfg), SimTime::ZERO);
        let mut prop =
            Sgp4Propagator::new(&Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()).unwrap();
        run_until(&mut h, SimTime::from_secs(30));
        // Between ticks (30.05 s) and a few seconds after the last one: the fix carried on.
        for t_ms in [30_050u64, 30_099, 33_000] {
            let t = SimTime(t_ms * 1_000_000);
            let reply = ask(&mut h, 10, &[2], t);
            assert_eq!(&reply[..2], &[2, 1], "t = {t_ms} ms");
            let atp = TmAtp::parse(&reply[2..]).unwrap();
            let want = prop
                .state_j2000(UtcTime::from_unix_ns(
                    (START * 1_000_000_000 + t_ms * 1_000_000) as i64,
                ))
                .unwrap()
                .r_km
                * 1e3;
            let err_m = (Vector3::from(atp.r_eci_m) - want).norm();
            // GPS noise 10 m per axis (1 sigma): 100 m is far outside it.
            assert!(err_m < 100.0, "t = {t_ms} ms: {err_m} m from the truth");
        }
        // No fix for longer than the limit and no TLE: the failure reply.
        assert_eq!(ask(&mut h, 10, &[2], SimTime::from_secs(60)), vec![2, 0]);
    }

    #[test]
    fn the_published_commanded_mode_is_the_running_scripts() {
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: Some((L1.to_owned(), L2.to_owned())),
            initial_mode: TargetMode::Nadir,
            timeline: vec![TimedFcEvent {
                at: SimTime::from_secs(5),
                event: FcEvent::Script(format!(
                    "adcs {} {} pointLVLH 1 0 0 0",
                    START + 10,
                    START + 20
                )),
            }],
            ..FcConfig::default()
        });
        let mut h = Host::new(node_cfg(), app, SimTime::ZERO);
        run_until(&mut h, SimTime::from_secs(25));
        let seen: Vec<(u64, u8)> = std::iter::from_fn(|| h.poll_event())
            .map(|p| (p.adcs.t.as_secs(), p.adcs.mode_commanded))
            .collect();
        let at = |s: u64| seen.iter().find(|(t, _)| *t == s).map(|x| x.1);
        assert_eq!(at(8), Some(TargetMode::Nadir as u8));
        assert_eq!(at(15), Some(TargetMode::FixedLvlh as u8));
        assert_eq!(at(22), Some(TargetMode::Nadir as u8));
    }

    #[test]
    fn a_timeline_script_due_while_the_fc_is_off_is_lost() {
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: Some((L1.to_owned(), L2.to_owned())),
            timeline: vec![TimedFcEvent {
                at: SimTime::from_secs(5),
                event: FcEvent::Script(format!(
                    "adcs {} {} pointLVLH 1 0 0 0",
                    START + 100,
                    START + 200
                )),
            }],
            ..FcConfig::default()
        });
        let mut h = Host::new(node_cfg(), app, SimTime::ZERO);
        run_until(&mut h, SimTime::from_secs(1));
        // The driver does not run the FC from 1 s to 10 s (off); it catches up at 10 s.
        h.handle_timeout(SimTime::from_secs(10));
        assert_eq!(h.app.scripts().len(), 0);
        let mut lines = Vec::new();
        while let Some(e) = h.node.poll_event() {
            lines.push(e.to_string());
        }
        assert!(lines.iter().any(|l| l.contains("script lost")), "{lines:?}");
    }

    #[test]
    fn tmatp_follows_the_orbit_after_a_burn() {
        let board = platform::board::BurnBoard::new();
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: Some((L1.to_owned(), L2.to_owned())),
            ..FcConfig::default()
        })
        .with_burns(board.clone());
        let mut h = Host::new(node_cfg(), app, SimTime::ZERO);
        let mut prop =
            Sgp4Propagator::new(&Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()).unwrap();
        let sgp4_m = |prop: &mut Sgp4Propagator, t_s: u64| {
            prop.state_j2000(UtcTime::from_unix_ns(
                ((START + t_s) * 1_000_000_000) as i64,
            ))
            .unwrap()
            .r_km
                * 1e3
        };
        run_until(&mut h, SimTime::from_secs(10));
        let at10 = TmAtp::parse(&ask(&mut h, 10, &[2], SimTime::from_secs(10))[2..]).unwrap();
        assert_eq!(Vector3::from(at10.r_eci_m), sgp4_m(&mut prop, 10));
        // 0.3 N for 10 s on 12.5 kg (Isp 200 s) along body +Z, posted at 10 s.
        board
            .post(platform::board::Burn {
                posted: SimTime::from_ns(10_000_000_000),
                start: SimTime::from_ns(10_000_000_000),
                end: SimTime::from_ns(20_000_000_000),
                thrust_n: 0.3,
                mass_flow_kg_s: 0.3 / (200.0 * 9.806_65),
                mass_kg: 12.5,
                dir_body: Vector3::z(),
            })
            .unwrap();
        let half_orbit_s = 2850;
        run_until(&mut h, SimTime::from_secs(half_orbit_s));
        let t = SimTime::from_secs(half_orbit_s);
        let atp = TmAtp::parse(&ask(&mut h, 10, &[2], t)[2..]).unwrap();
        let off_m = (Vector3::from(atp.r_eci_m) - sgp4_m(&mut prop, half_orbit_s)).norm();
        // 0.24 m/s in some direction moves the satellite by up to ~2 km in half an orbit
        // (Clohessy-Wiltshire; nodes-fc/tests/burns.rs checks the exact figure); SGP4 and the
        // numerical model alone stay within ~160 m of each other over that time.
        assert!(off_m > 300.0, "TMATP {off_m} m from SGP4 after the burn");
        assert!(off_m < 5000.0, "TMATP {off_m} m from SGP4 after the burn");
        // TMATP is the truth's (numerical) position.
        let truth = h
            .app
            .truth_orbit
            .as_mut()
            .unwrap()
            .state_j2000(((START + half_orbit_s) * 1_000_000_000) as i64)
            .unwrap();
        assert_eq!(Vector3::from(atp.r_eci_m), truth.r_km * 1e3);
    }

    #[test]
    fn tmatp_reports_the_estimate_which_agrees_with_the_truth() {
        let mut h = flown(1800);
        let t = SimTime::from_secs(1800);
        let atp = TmAtp::parse(&ask(&mut h, 10, &[2], t)[2..]).unwrap();
        let est = h.app.estimate().unwrap();
        assert_eq!(atp.q_eci_from_body, [est.w, est.i, est.j, est.k]);
        let err_deg = est.angle_to(&h.app.attitude().q_eci_from_body).to_degrees();
        assert!(err_deg < 0.5, "estimation error {err_deg} deg");
        let g = TmGen::parse(&ask(&mut h, 10, &[1], t)[2..]).unwrap();
        assert_eq!(g.current_mode, TargetMode::Nadir as u8);
        let acd = TmAcd::parse(&ask(&mut h, 10, &[3], t)[2..]).unwrap();
        assert_eq!(acd.state, adcs::STATE_TRACKING);
        assert_eq!(acd.rw_state, [1; 4]);
    }

    /// The FC's own limits on set commands: a script window of more than a day or ending
    /// after the RTC's range, earth target before a target point, an RTC beyond 2100.
    #[test]
    fn scripts_modes_and_the_rtc_are_held_to_the_fcs_ranges() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(10);
        let start = START;
        let line = |a: u64, b: u64| format!("adcs {a} {b} pointECI 1 0 0 0");
        let day = 86_400;
        assert_eq!(
            ask(
                &mut h,
                13,
                line(start + 60, start + 60 + day + 1).as_bytes(),
                t
            ),
            [b'a', 0]
        );
        assert_eq!(
            ask(&mut h, 13, line(4_102_444_000, 4_102_445_000).as_bytes(), t),
            [b'a', 0]
        );
        assert_eq!(
            ask(&mut h, 13, line(start + 60, start + 60 + day).as_bytes(), t),
            [b'a', 1]
        );
        // Earth target needs a target point first.
        assert_eq!(ask(&mut h, 12, &[6, 5], t), [6, 0]);
        let mut p = vec![4];
        for v in [54.6872f64, 25.2797, 100.0] {
            p.extend(v.to_le_bytes());
        }
        assert_eq!(ask(&mut h, 12, &p, t), [4, 1]);
        assert_eq!(ask(&mut h, 12, &[6, 5], t), [6, 1]);
        // RTCSTMSET: an all-ones word is refused, 2099 is taken.
        assert_eq!(ask(&mut h, 11, &[1, 0xff, 0xff, 0xff, 0xff], t), [1, 0]);
        let mut set = vec![1];
        set.extend(4_070_908_800u32.to_le_bytes());
        assert_eq!(ask(&mut h, 11, &set, t), [1, 1]);
    }

    /// The ICD 1.5 examples, verbatim, on port 13, with the RTC set to their 2020 times.
    #[test]
    fn the_four_icd_script_examples_are_flown_on_the_rtc() {
        let examples = [
            (
                "adcs 1577836800 1577836920 pointECI 1 0 0 0",
                TargetMode::FixedEci,
            ),
            (
                "adcs 1577836800 1577836920 pointECI 0.707106 0 0 -0.707106",
                TargetMode::FixedEci,
            ),
            (
                "adcs 1577836800 1577836920 pointLVLH 1 0 0 0",
                TargetMode::FixedLvlh,
            ),
            (
                "adcs 1577836800 1577836920 pointGEO 54.6872 25.2797 100 0 0 1",
                TargetMode::EarthTarget,
            ),
        ];
        for (line, mode) in examples {
            let mut h = flown(900);
            let t0 = SimTime::from_secs(900);
            // RTCSTMSET 1577836790: the script starts 10 s later on the FC's clock.
            let mut set = vec![1];
            set.extend_from_slice(&1_577_836_790u32.to_le_bytes());
            assert_eq!(ask(&mut h, 11, &set, t0), vec![1, 1]);
            assert_eq!(
                ask(&mut h, 13, line.as_bytes(), t0),
                vec![b'a', 1],
                "{line}"
            );
            assert_eq!(h.app.scripts().len(), 1);
            // The same line again overlaps itself: refused.
            assert_eq!(
                ask(&mut h, 13, line.as_bytes(), t0),
                vec![b'a', 0],
                "{line}"
            );
            let during = SimTime::from_secs(900 + 20);
            while let Some(t) = h.poll_timeout().filter(|&t| t <= during) {
                h.handle_timeout(t);
            }
            let g = TmGen::parse(&ask(&mut h, 10, &[1], during)[2..]).unwrap();
            assert_eq!(g.current_mode, mode as u8, "{line}");
            // After END (120 s on the RTC) the ATCMDSET mode, nadir, is back.
            let after = SimTime::from_secs(900 + 10 + 121);
            while let Some(t) = h.poll_timeout().filter(|&t| t <= after) {
                h.handle_timeout(t);
            }
            let g = TmGen::parse(&ask(&mut h, 10, &[1], after)[2..]).unwrap();
            assert_eq!(g.current_mode, TargetMode::Nadir as u8, "{line}");
            assert!(h.app.scripts().is_empty());
        }
    }

    #[test]
    fn tle_upload_gives_the_fc_its_orbit() {
        let c = node_cfg();
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: Some((L1.to_owned(), L2.to_owned())),
            tle_uploaded: false,
            ..FcConfig::default()
        });
        let mut h = Host::new(c, app, SimTime::ZERO);
        let t = SimTime::from_secs(10);
        assert_eq!(
            ask(&mut h, 10, &[2], t),
            vec![2, 0],
            "no orbit before the upload"
        );
        assert_eq!(ask(&mut h, 12, &[8], t), vec![8, 0]);
        let mut req = vec![7];
        req.extend_from_slice(L1.as_bytes());
        req.extend_from_slice(L2.as_bytes());
        assert_eq!(ask(&mut h, 12, &req, t), vec![7, 1]);
        assert_eq!(ask(&mut h, 12, &[8], t)[2..], req[1..]);
        assert_eq!(ask(&mut h, 10, &[2], t)[..2], [2, 1]);
        // A line with a bad checksum or the wrong length is refused.
        let mut bad = req.clone();
        bad[69] = b'7';
        assert_eq!(ask(&mut h, 12, &bad, t), vec![7, 0]);
        assert_eq!(ask(&mut h, 12, &req[..100], t), vec![7, 0]);
        // A TLE 40 days old (epoch day 080 instead of 120, checksum redone) is refused;
        // 20 days old is taken.
        let with_day = |day: &str| {
            let mut l1 = L1.replace("26120.75000000", &format!("26{day}.75000000"));
            let sum: u32 = l1[..68]
                .chars()
                .map(|c| c.to_digit(10).unwrap_or(u32::from(c == '-')))
                .sum();
            l1.replace_range(68..69, &(sum % 10).to_string());
            let mut r = vec![7];
            r.extend_from_slice(l1.as_bytes());
            r.extend_from_slice(L2.as_bytes());
            r
        };
        assert_eq!(ask(&mut h, 12, &with_day("080"), t), vec![7, 0]);
        assert_eq!(ask(&mut h, 12, &with_day("100"), t), vec![7, 1]);
    }

    #[test]
    fn truth_refused_in_a_row_is_one_warning_and_one_line_when_it_ends() {
        // A reader already at 5 s (as after the FC hung): the ticks before it are refused.
        let board = platform::board::TruthBoard::new();
        let _ = board.latest_before(SimTime::from_secs(5));
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            ..FcConfig::default()
        })
        .with_truth_board(board.clone());
        let mut h = Host::new(node_cfg(), app, SimTime::ZERO);
        while let Some(due) = h.poll_timeout().filter(|&d| d <= SimTime::from_secs(6)) {
            h.handle_timeout(due);
        }
        let lines: Vec<String> = std::iter::from_fn(|| h.node.poll_event())
            .map(|e| e.to_string())
            .filter(|l| l.contains("truth"))
            .collect();
        let refused = board.stats().refused;
        assert!(refused > 10, "{refused} refused");
        assert_eq!(lines.len(), 2, "{lines:#?}");
        assert!(lines[0].starts_with("truth not posted"), "{lines:#?}");
        assert_eq!(
            lines[1],
            format!("truth posted again, after {refused} refused write(s)")
        );
    }
}
