//! The FC's platform parameters, self-test and console commands (the platform port,
//! [`csp::params`]; the console, [`csp::console`]). docs/protocol.md "Platform port" lists
//! the table.

use csp::console::Command;
use csp::icd::Describe as _;
use csp::node::Node;
use csp::params::{Check, Health, ParamDef, ParamError, ParamType, Table, check, def};

use crate::sensors::SensorReadings;
use crate::wire::{self, TelemetryCommand, TmAcd, TmAtp, TmGen, TmRawSens, TmSens};
use crate::{FcApp, SimTime};

/// The FC's parameter table.
pub const PARAMS: &[ParamDef] = &[
    def(
        1,
        "bdot_gain",
        ParamType::F32,
        "N m s",
        0.0,
        1.0,
        "B-dot detumbling gain",
    ),
    def(
        2,
        "natural_freq",
        ParamType::F32,
        "rad/s",
        0.001,
        1.0,
        "attitude loop natural frequency",
    ),
    def(
        3,
        "damping_ratio",
        ParamType::F32,
        "",
        0.1,
        3.0,
        "attitude loop damping ratio",
    ),
    def(
        4,
        "max_rate",
        ParamType::F32,
        "deg/s",
        0.1,
        10.0,
        "slew rate limit",
    ),
    def(
        5,
        "desat_gain",
        ParamType::F32,
        "1/s",
        0.0,
        1.0,
        "wheel desaturation gain",
    ),
    def(
        6,
        "detumble_exit_rate",
        ParamType::F32,
        "deg/s",
        0.05,
        5.0,
        "rate below which detumbling may end",
    ),
    def(
        7,
        "use_gyro",
        ParamType::Bool,
        "",
        0.0,
        1.0,
        "the determination uses the gyroscope",
    ),
    def(
        8,
        "use_mag",
        ParamType::Bool,
        "",
        0.0,
        1.0,
        "the determination uses the magnetometer",
    ),
    def(
        9,
        "use_sun",
        ParamType::Bool,
        "",
        0.0,
        1.0,
        "the determination uses the sun sensors",
    ),
    def(
        10,
        "gps_enabled",
        ParamType::Bool,
        "",
        0.0,
        1.0,
        "the GPS receiver is on",
    ),
    def(
        11,
        "safe_enter_soc",
        ParamType::U8,
        "%",
        0.0,
        100.0,
        "battery charge below which the FC goes SAFE",
    ),
    def(
        12,
        "safe_exit_soc",
        ParamType::U8,
        "%",
        0.0,
        100.0,
        "battery charge at which SAFE ends (not below safe_enter_soc)",
    ),
    def(
        13,
        "time_sync_period",
        ParamType::U16,
        "s",
        0.0,
        3600.0,
        "RTC distribution period (0: at boot and RTCSTMSET only)",
    ),
    def(
        14,
        "store_period",
        ParamType::U32,
        "s",
        0.0,
        86400.0,
        "telemetry store collection period (0: not collecting)",
    ),
    def(
        15,
        "store_mask",
        ParamType::U8,
        "",
        0.0,
        255.0,
        "what the store collects: 0x01 TMGEN 0x02 TMATP 0x04 TMACD 0x08 TMSENS 0x10 TMRAWSENS 0x40 EPS 0x80 COMM",
    ),
    def(
        16,
        "use_horizon",
        ParamType::Bool,
        "",
        0.0,
        1.0,
        "the determination uses the Earth-horizon sensor's nadir vector",
    ),
];

fn flag(b: bool) -> f64 {
    if b { 1.0 } else { 0.0 }
}

/// Why the FC refuses a parameter value the table's range lets through.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FcParamError {
    /// Safe mode would be left below the charge it is entered at.
    #[error(
        "safe_exit_soc {:.0} % would be below safe_enter_soc {:.0} %",
        .exit_soc * 100.0,
        .enter_soc * 100.0
    )]
    SafeExitBelowEnter {
        /// The exit threshold, fraction of full.
        exit_soc: f64,
        /// The entry threshold, fraction of full.
        enter_soc: f64,
    },
    /// A store mask with bits the store does not offer.
    #[error(
        "store_mask {mask:#04x}: bit 0x20 (TMALL) is not offered (it is the sum of the others)"
    )]
    StoreMask {
        /// The mask.
        mask: u8,
    },
}

/// An error as text, `-` for none.
fn or_dash(e: Option<&crate::OrbitError>) -> String {
    e.map_or_else(|| "-".to_owned(), ToString::to_string)
}

/// Why the console's `tm` printed nothing.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TmConsoleError {
    /// Not one of the FC's telemetries.
    #[error("no telemetry {which:?} (gen, atp, acd, sens, rawsens, all)")]
    NoTelemetry {
        /// The word given.
        which: String,
    },
    /// The request was refused: the FC has no orbit to report.
    #[error("{which}: refused (no onboard orbit: {})", or_dash(.orbit.as_ref()))]
    Refused {
        /// The telemetry.
        which: String,
        /// Why the FC has no true orbit, if it has none.
        orbit: Option<crate::OrbitError>,
    },
    /// The reply did not decode as its telemetry.
    #[error("{which}: {source}")]
    Decode {
        /// The telemetry.
        which: String,
        /// The decoder's error.
        source: csp::Error,
    },
}

impl Table for FcApp {
    fn defs(&self) -> &'static [ParamDef] {
        PARAMS
    }

    fn get(&self, id: u8) -> Option<f64> {
        let a = &self.cfg.adcs;
        let c = &a.control;
        let s = &self.cfg.safe;
        Some(match id {
            1 => c.bdot_gain,
            2 => c.natural_freq_rad_s,
            3 => c.damping_ratio,
            4 => c.max_rate_rad_s.to_degrees(),
            5 => c.desat_gain,
            6 => a.detumble_exit_rate_rad_s.to_degrees(),
            7 => flag(a.use_sensors.gyro),
            8 => flag(a.use_sensors.mag),
            9 => flag(a.use_sensors.sun),
            10 => flag(self.cfg.sensors.gps_enabled),
            11 => (s.enter_soc * 100.0).round(),
            12 => (s.exit_soc * 100.0).round(),
            13 => self
                .cfg
                .time_sync
                .period
                .map_or(0.0, |p| p.as_secs() as f64),
            14 => self.cfg.store.period.map_or(0.0, |p| p.as_secs() as f64),
            15 => f64::from(self.cfg.store.mask),
            16 => flag(a.use_sensors.horizon),
            _ => return None,
        })
    }

    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
        let on = v != 0.0;
        // The scenario's configuration and the running software, together: a reboot
        // rebuilds the software from the first, and the boot then applies the saved table.
        let adcs = |app: &mut FcApp, f: &dyn Fn(&mut crate::adcs::AdcsConfig)| {
            f(&mut app.cfg.adcs);
            f(app.fsw.adcs.config_mut());
        };
        match id {
            1 => adcs(self, &|a| a.control.bdot_gain = v),
            2 => adcs(self, &|a| a.control.natural_freq_rad_s = v),
            3 => adcs(self, &|a| a.control.damping_ratio = v),
            4 => adcs(self, &|a| a.control.max_rate_rad_s = v.to_radians()),
            5 => adcs(self, &|a| a.control.desat_gain = v),
            6 => adcs(self, &|a| a.detumble_exit_rate_rad_s = v.to_radians()),
            7 => adcs(self, &|a| a.use_sensors.gyro = on),
            8 => adcs(self, &|a| a.use_sensors.mag = on),
            9 => adcs(self, &|a| a.use_sensors.sun = on),
            16 => adcs(self, &|a| a.use_sensors.horizon = on),
            10 => {
                self.cfg.sensors.gps_enabled = on;
                self.sensors.config_mut().gps_enabled = on;
            }
            11 | 12 => {
                let (mut enter, mut exit) = (self.cfg.safe.enter_soc, self.cfg.safe.exit_soc);
                if id == 11 {
                    enter = v / 100.0;
                } else {
                    exit = v / 100.0;
                }
                if exit < enter {
                    return Err(ParamError::refused(FcParamError::SafeExitBelowEnter {
                        exit_soc: exit,
                        enter_soc: enter,
                    }));
                }
                for s in [&mut self.cfg.safe, self.safe.config_mut()] {
                    s.enter_soc = enter;
                    s.exit_soc = exit;
                }
                // The FC's state follows at its next tick.
                self.safe.rejudge();
            }
            13 => {
                let p = (v > 0.0).then(|| std::time::Duration::from_secs(v as u64));
                self.cfg.time_sync.period = p;
                self.time_sync.config_mut().period = p;
            }
            14 | 15 => {
                let mut period = self.cfg.store.period;
                let mut mask = self.cfg.store.mask;
                if id == 14 {
                    period = (v > 0.0).then(|| std::time::Duration::from_secs(v as u64));
                } else {
                    mask = v as u8;
                    if mask & !crate::store::MASK_ALL != 0 {
                        return Err(ParamError::refused(FcParamError::StoreMask { mask }));
                    }
                }
                self.cfg.store.period = period;
                self.cfg.store.mask = mask;
                // From the last instant the FC saw; a boot sets its own schedule after this.
                let now = self.store_now;
                self.store.set(period, mask, now);
            }
            _ => return Err(ParamError::Unknown { id }),
        }
        Ok(())
    }
}

/// The FC's console commands.
pub const COMMANDS: &[Command] = &[
    Command {
        name: "tm",
        args: "[gen|atp|acd|sens|rawsens|all]",
        help: "telemetry (the bytes a CSP request gets now, one `name value unit` line per field; default gen)",
    },
    Command {
        name: "store",
        args: "",
        help: "the telemetry store: records, bytes, oldest and newest RTC, overwritten",
    },
    Command {
        name: "mode",
        args: "",
        help: "the commanded target and the ADCS state",
    },
];

impl FcApp {
    /// The console's `tm`: the telemetry a CSP request would get at `now`, one `name value
    /// unit` line per field ([`csp::console::lines`]).
    pub(crate) fn console_tm(
        &mut self,
        node: &Node,
        which: &str,
        now: SimTime,
    ) -> Result<String, TmConsoleError> {
        let c = match which {
            "gen" => TelemetryCommand::TmGen,
            "atp" => TelemetryCommand::TmAtp,
            "acd" => TelemetryCommand::TmAcd,
            "sens" => TelemetryCommand::TmSens,
            "rawsens" => TelemetryCommand::TmRawSens,
            "all" => TelemetryCommand::TmAll,
            other => {
                return Err(TmConsoleError::NoTelemetry {
                    which: other.to_owned(),
                });
            }
        };
        let bytes = self
            .telemetry(node, c, now)
            .map_err(|_| TmConsoleError::Refused {
                which: which.to_owned(),
                orbit: self.orbit_error().cloned(),
            })?;
        let bad = |source: csp::Error| TmConsoleError::Decode {
            which: which.to_owned(),
            source,
        };
        let fields = match c {
            TelemetryCommand::TmGen => TmGen::FIELDS,
            TelemetryCommand::TmAtp => TmAtp::FIELDS,
            TelemetryCommand::TmAcd => TmAcd::FIELDS,
            TelemetryCommand::TmSens => TmSens::FIELDS,
            TelemetryCommand::TmRawSens => TmRawSens::FIELDS,
            _ => wire::TmAll::FIELDS,
        };
        csp::console::lines(fields, &bytes).map_err(bad)
    }

    /// The FC's self-test: sensors, wheels, magnetorquers, the estimator and the orbit.
    pub(crate) fn checks(&self, now: SimTime) -> Vec<Check> {
        let mut v = Vec::new();
        let r = self.readings.as_ref();
        let used = self.cfg.adcs.use_sensors;
        let sensor = |name, present: Option<f64>, used: bool, unit| match (present, used) {
            (Some(x), true) => check(name, Health::Ok, x, unit, String::new()),
            (Some(x), false) => check(name, Health::Off, x, unit, "not used (parameter)".into()),
            (None, _) => check(name, Health::Failed, 0.0, unit, "no reading".into()),
        };
        v.push(sensor(
            "gyro",
            r.and_then(|r| r.gyro_body_rad_s)
                .map(|w| w.norm().to_degrees()),
            used.gyro,
            "deg/s",
        ));
        v.push(sensor(
            "magnetometer",
            r.and_then(|r| r.mag_body_nt).map(|b| b.norm()),
            used.mag,
            "nT",
        ));
        v.push(self.sun_sensors_check(r, used.sun));
        v.push(sensor(
            "accelerometer",
            r.and_then(|r| r.acc_body_m_s2).map(|a| a.norm()),
            true,
            "m/s2",
        ));
        v.push(self.horizon_check(r));
        v.push(self.gps_check(now));
        for (i, name) in ["wheel1", "wheel2", "wheel3", "wheel4"]
            .into_iter()
            .enumerate()
        {
            let rpm = self.att.wheel_speed_rad_s[i] * 60.0 / std::f64::consts::TAU;
            v.push(match self.wheel_fault[i] {
                Some(f) => check(
                    name,
                    Health::Failed,
                    rpm,
                    "rpm",
                    format!("{f:?}").to_lowercase(),
                ),
                None => check(name, Health::Ok, rpm, "rpm", String::new()),
            });
        }
        v.push(check(
            "magnetorquers",
            Health::Ok,
            self.mtq_applied_am2.norm(),
            "A m2",
            String::new(),
        ));
        v.push(self.estimator_check());
        v.push(match self.orbit_error() {
            None => check("orbit", Health::Ok, 0.0, "", String::new()),
            Some(e) => check("orbit", Health::Failed, 0.0, "", e.to_string()),
        });
        let t = r.map_or(f64::NAN, |r| r.mcu_temp_c);
        v.push(check(
            "mcu_temp",
            if (-40.0..=85.0).contains(&t) {
                Health::Ok
            } else {
                Health::Failed
            },
            t,
            "degC",
            String::new(),
        ));
        v
    }

    /// The sun sensors' check: no sun vector is a fault only while the Sun is in view.
    fn sun_sensors_check(&self, r: Option<&SensorReadings>, used: bool) -> Check {
        let sunlit = self
            .env
            .as_ref()
            .is_some_and(|e| e.sun_visible_fraction > 0.5);
        let css_total = r.map_or(0.0, |r| r.css_counts.iter().map(|&c| f64::from(c)).sum());
        match (r.and_then(|r| r.sun_body_unit), sunlit, used) {
            (_, _, false) => check(
                "sun_sensors",
                Health::Off,
                css_total,
                "counts",
                "not used (parameter)".into(),
            ),
            (Some(_), _, true) => check(
                "sun_sensors",
                Health::Ok,
                css_total,
                "counts",
                String::new(),
            ),
            (None, false, true) => check(
                "sun_sensors",
                Health::Ok,
                css_total,
                "counts",
                "in eclipse".into(),
            ),
            (None, true, true) => check(
                "sun_sensors",
                Health::Degraded,
                css_total,
                "counts",
                "sunlit but no sun vector".into(),
            ),
        }
    }

    /// The horizon sensor's check: how much of the limb it sees, or dead.
    fn horizon_check(&self, r: Option<&SensorReadings>) -> Check {
        let limb = r.map_or(crate::sensors::HORIZON_NO_LIMB, |r| r.horizon_status);
        let fault = self.sensors.fault(crate::sensors::SensorId::Horizon);
        match (fault, limb) {
            (Some(crate::sensors::SensorFault::Dead), _) => {
                check("horizon", Health::Failed, 0.0, "", "no output".into())
            }
            (_, crate::sensors::HORIZON_FULL_LIMB) => {
                check("horizon", Health::Ok, 1.0, "", "whole limb in view".into())
            }
            (_, crate::sensors::HORIZON_PARTIAL_LIMB) => check(
                "horizon",
                Health::Degraded,
                2.0,
                "",
                "part of the limb in view".into(),
            ),
            _ => check("horizon", Health::Ok, 0.0, "", "no limb in view".into()),
        }
    }

    /// The GPS check: the last fix's age against what the ADCS still takes.
    fn gps_check(&self, now: SimTime) -> Check {
        if !self.cfg.sensors.gps_enabled {
            check("gps", Health::Off, 0.0, "s", "receiver off".into())
        } else {
            let age_s = self
                .fsw
                .gps_fix
                .map(|(t_fix, _, _)| (self.true_unix_ns_i64(now) - t_fix) as f64 * 1e-9);
            match age_s {
                Some(a) if a * 1e9 <= crate::GPS_FIX_MAX_AGE_NS as f64 => {
                    check("gps", Health::Ok, a, "s", "fix age".into())
                }
                Some(a) => check("gps", Health::Degraded, a, "s", "last fix too old".into()),
                None => check("gps", Health::Degraded, 0.0, "s", "no fix".into()),
            }
        }
    }

    /// The estimator's check: why it last fell back to detumble, or whether it runs.
    fn estimator_check(&self) -> Check {
        let adcs = &self.fsw.adcs;
        match (adcs.estimate(), adcs.fallback_reason()) {
            (_, Some(why)) => check(
                "estimator",
                Health::Degraded,
                adcs.estimator_restarts() as f64,
                "restarts",
                why.to_string(),
            ),
            (None, None) => check(
                "estimator",
                Health::Degraded,
                adcs.estimator_restarts() as f64,
                "restarts",
                "not initialised".into(),
            ),
            (Some(_), None) => check(
                "estimator",
                Health::Ok,
                adcs.estimator_restarts() as f64,
                "restarts",
                String::new(),
            ),
        }
    }
}
