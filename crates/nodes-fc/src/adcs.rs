//! The ADCS flight software of ICD 1.3: mode logic, attitude determination and control, one
//! pure step per ADCS tick.
//!
//! Each [`Adcs::step`] takes the sensor readings, the wheel tachometers and health flags,
//! the onboard references (the environment at the onboard orbit: uploaded TLE or GPS) and
//! the requested pointing, and returns actuator commands:
//! - **Detumble** (the boot mode, ICD 1.3): B-dot on the magnetometer, wheels off. The ADCS
//!   leaves it for the requested mode once the orbit is known (TLE uploaded or GPS valid),
//!   the attitude estimate is initialised, and the measured rate has stayed below
//!   [`AdcsConfig::detumble_exit_rate_rad_s`] for [`AdcsConfig::detumble_exit_hold_s`]. It
//!   falls back to detumble when the measured rate exceeds
//!   [`AdcsConfig::safe_rate_rad_s`] for [`AdcsConfig::safe_hold_s`] (a tumble: a stuck
//!   wheel, a controller fighting a bad estimate).
//! - **Determination**: the MEKF ([`crate::estimator`]) propagated with the gyro and updated
//!   with the magnetometer (every tick) and the sun vector of the coarse sun sensors (when
//!   the onboard model says sunlit); initialised by TRIAD (sun primary, field secondary).
//!   Without a gyro the rate is the smoothed finite difference of successive estimates.
//! - **Control**: quaternion feedback with rate limit and gyroscopic compensation on the
//!   healthy reaction wheels ([`crate::control`]), momentum desaturation with the
//!   magnetorquers. Idle: every actuator off.
//!
//! The magnetometer is read while the magnetorquers are on (no duty cycling): the twin's
//! magnetometer does not see the magnetorquers' field (documented in docs/adcs.md).

use nalgebra::{UnitQuaternion, Vector3};

use crate::control::{self, ControlConfig};
use crate::environment::Environment;
use crate::estimator::{Mekf, MekfConfig, triad};
use crate::guidance::{self, GuidanceInputs, GuidanceTarget, Pointing};
use crate::sensors::SensorReadings;
use crate::truth::BodyConfig;
use crate::wire::TargetMode;

/// TMACD `state`: the ADCS is off (idle).
pub const STATE_OFF: u8 = 0;
/// TMACD `state`: detumbling.
pub const STATE_DETUMBLING: u8 = 1;
/// TMACD `state`: acquiring (pointing mode, estimate missing or error above the threshold).
pub const STATE_ACQUIRING: u8 = 2;
/// TMACD `state`: tracking the target.
pub const STATE_TRACKING: u8 = 3;

/// Settings of the flight software.
#[derive(Debug, Clone, PartialEq)]
pub struct AdcsConfig {
    /// Control gains and limits.
    pub control: ControlConfig,
    /// Estimator noise figures.
    pub mekf: MekfConfig,
    /// Magnetometer direction 1-sigma for the filter, rad (0.25 deg: sensor noise of 75 nT is
    /// 0.1-0.2 deg at 20-50 uT; the rest covers residual calibration errors).
    pub mag_sigma_rad: f64,
    /// Sun vector direction 1-sigma for the filter, rad (0.5 deg: 10 counts of noise on
    /// 4095 is 0.15 deg with cosine detectors; no albedo in the twin).
    pub sun_sigma_rad: f64,
    /// Hard-iron bias the magnetometer calibration removes, nT (ICD 1.3 "sensors
    /// calibration"): by default the sensor model's bias, i.e. calibrated on the ground; a
    /// scenario's `bias:` fault adds an uncalibrated part on top.
    pub mag_calibration_bias_nt: Vector3<f64>,
    /// Rate below which detumbling may end, rad/s (1 deg/s).
    pub detumble_exit_rate_rad_s: f64,
    /// How long the rate must stay below the exit rate, s.
    pub detumble_exit_hold_s: f64,
    /// Rate above which a pointing mode falls back to detumble, rad/s (5 deg/s).
    pub safe_rate_rad_s: f64,
    /// How long the rate must stay above the safe rate, s.
    pub safe_hold_s: f64,
    /// Estimated pointing error below which the state is "tracking", rad (2 deg).
    pub tracking_threshold_rad: f64,
    /// Solar panel normal for sun max power, body frame.
    pub panel_normal_body: Vector3<f64>,
}

impl Default for AdcsConfig {
    fn default() -> Self {
        AdcsConfig {
            control: ControlConfig::default(),
            mekf: MekfConfig {
                // The sensor model's bias walk (1e-5 deg/s per sqrt(s)).
                gyro_bias_walk_rad_s2: 1.0e-5_f64.to_radians(),
                ..MekfConfig::default()
            },
            mag_sigma_rad: 0.25_f64.to_radians(),
            sun_sigma_rad: 0.5_f64.to_radians(),
            mag_calibration_bias_nt: crate::sensors::SensorConfig::default().mag_bias_nt,
            detumble_exit_rate_rad_s: 1.0_f64.to_radians(),
            detumble_exit_hold_s: 60.0,
            safe_rate_rad_s: 5.0_f64.to_radians(),
            safe_hold_s: 10.0,
            tracking_threshold_rad: 2.0_f64.to_radians(),
            panel_normal_body: guidance::DEFAULT_PANEL_NORMAL_BODY,
        }
    }
}

/// What the ADCS is asked to do this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Request {
    /// The requested mode (a script's or the ATCMDSET mode).
    pub mode: TargetMode,
    /// Its pointing, for pointing modes.
    pub pointing: Option<Pointing>,
}

/// Inputs of one tick.
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    /// The sensors.
    pub readings: &'a SensorReadings,
    /// Wheel tachometers, rad/s.
    pub wheel_speed_rad_s: [f64; 4],
    /// Wheel drive health flags (a failed wheel reports itself).
    pub wheel_healthy: [bool; 4],
    /// Onboard references at the onboard orbit; `None` without orbit knowledge.
    pub onboard: Option<&'a Environment>,
    /// What to do.
    pub request: Request,
}

/// Commands and status of one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Output {
    /// Wheel motor torque commands, N m.
    pub wheel_torque_cmd_nm: [f64; 4],
    /// Magnetorquer dipole command, body, A m^2.
    pub mtq_dipole_cmd_am2: Vector3<f64>,
    /// The mode in effect.
    pub mode_in_effect: TargetMode,
    /// TMACD state.
    pub state: u8,
    /// The guidance target in effect (pointing modes with an orbit).
    pub target: Option<GuidanceTarget>,
    /// Estimated rate, body, rad/s.
    pub w_body_rad_s_est: Vector3<f64>,
}

/// The flight software's state (volatile: a reboot starts a new one).
#[derive(Debug, Clone)]
pub struct Adcs {
    cfg: AdcsConfig,
    body: BodyConfig,
    mekf: Mekf,
    detumbling: bool,
    below_exit_s: f64,
    above_safe_s: f64,
    prev_mag_body_nt: Option<Vector3<f64>>,
    prev_estimate: Option<UnitQuaternion<f64>>,
    w_nogyro_body_rad_s: Vector3<f64>,
}

impl Adcs {
    /// A freshly booted ADCS (detumbling, no estimate).
    pub fn new(cfg: AdcsConfig, body: BodyConfig) -> Self {
        let mekf = Mekf::new(cfg.mekf);
        Adcs {
            cfg,
            body,
            mekf,
            detumbling: true,
            below_exit_s: 0.0,
            above_safe_s: 0.0,
            prev_mag_body_nt: None,
            prev_estimate: None,
            w_nogyro_body_rad_s: Vector3::zeros(),
        }
    }

    /// The attitude estimate, if initialised.
    pub fn estimate(&self) -> Option<UnitQuaternion<f64>> {
        self.mekf.attitude()
    }

    /// The estimated gyro bias, rad/s.
    pub fn gyro_bias_rad_s(&self) -> Vector3<f64> {
        self.mekf.gyro_bias_rad_s()
    }

    /// Whether the ADCS is (still or again) detumbling.
    pub fn is_detumbling(&self) -> bool {
        self.detumbling
    }

    /// The settings.
    pub fn config(&self) -> &AdcsConfig {
        &self.cfg
    }

    fn determine(&mut self, r: &SensorReadings, env: Option<&Environment>, dt_s: f64) {
        let Some(env) = env else {
            // No references: nothing to determine the attitude against.
            if self.mekf.is_initialised() {
                self.mekf.propagate(r.gyro_body_rad_s.as_ref(), dt_s);
            }
            return;
        };
        let sun_ref = (env.sun_visible_fraction > 0.5).then_some(env.sun_eci_unit);
        let b_ref = (env.b_eci_nt.norm() > 0.0).then_some(env.b_eci_nt);
        if !self.mekf.is_initialised() {
            if let (Some(s_body), Some(s_eci), Some(b_body), Some(b_eci)) =
                (r.sun_body_unit, sun_ref, r.mag_body_nt, b_ref)
                && let Some(q) = triad(&s_body, &s_eci, &b_body, &b_eci)
            {
                self.mekf.initialise(q);
            }
            return;
        }
        self.mekf.propagate(r.gyro_body_rad_s.as_ref(), dt_s);
        if let (Some(b_body), Some(b_eci)) = (r.mag_body_nt, b_ref) {
            self.mekf
                .update_vector(&b_body, &b_eci, self.cfg.mag_sigma_rad);
        }
        if let (Some(s_body), Some(s_eci)) = (r.sun_body_unit, sun_ref) {
            self.mekf
                .update_vector(&s_body, &s_eci, self.cfg.sun_sigma_rad);
        }
    }

    /// The estimated body rate: gyro minus estimated bias, or without a gyro the smoothed
    /// finite difference of successive estimates.
    fn rate_estimate(&mut self, r: &SensorReadings, dt_s: f64) -> Option<Vector3<f64>> {
        let est = self.mekf.attitude();
        let w = match r.gyro_body_rad_s {
            Some(g) => Some(if est.is_some() {
                self.mekf.rate_body_rad_s(&g)
            } else {
                g
            }),
            None => match (self.prev_estimate, est) {
                (Some(p), Some(q)) if dt_s > 0.0 => {
                    let d = p.inverse() * q;
                    let raw = d.scaled_axis() / dt_s;
                    // First-order smoothing over ~1 s.
                    let a = (dt_s / 1.0).min(1.0);
                    self.w_nogyro_body_rad_s += (raw - self.w_nogyro_body_rad_s) * a;
                    Some(self.w_nogyro_body_rad_s)
                }
                _ => None,
            },
        };
        self.prev_estimate = est;
        w
    }

    /// One ADCS tick of `dt_s`.
    pub fn step(&mut self, inp: &Inputs<'_>, dt_s: f64) -> Output {
        let calibrated = SensorReadings {
            mag_body_nt: inp
                .readings
                .mag_body_nt
                .map(|b| b - self.cfg.mag_calibration_bias_nt),
            ..*inp.readings
        };
        let r = &calibrated;
        self.determine(r, inp.onboard, dt_s);
        let w_est = self.rate_estimate(r, dt_s);
        let rate = w_est.map(|w| w.norm());

        let mut out = Output {
            wheel_torque_cmd_nm: [0.0; 4],
            mtq_dipole_cmd_am2: Vector3::zeros(),
            mode_in_effect: TargetMode::Detumble,
            state: STATE_DETUMBLING,
            target: None,
            w_body_rad_s_est: w_est.unwrap_or_default(),
        };
        let mag = calibrated.mag_body_nt;
        let prev_mag = std::mem::replace(&mut self.prev_mag_body_nt, mag);

        if inp.request.mode == TargetMode::Idle {
            out.mode_in_effect = TargetMode::Idle;
            out.state = STATE_OFF;
            return out;
        }

        // Mode logic: leave detumble once slow, orbit known and estimate initialised.
        if self.detumbling {
            match rate {
                Some(w) if w < self.cfg.detumble_exit_rate_rad_s => self.below_exit_s += dt_s,
                _ => self.below_exit_s = 0.0,
            }
            if inp.request.mode != TargetMode::Detumble
                && inp.onboard.is_some()
                && self.mekf.is_initialised()
                && self.below_exit_s >= self.cfg.detumble_exit_hold_s
            {
                self.detumbling = false;
                self.above_safe_s = 0.0;
            }
        } else {
            match rate {
                Some(w) if w > self.cfg.safe_rate_rad_s => self.above_safe_s += dt_s,
                _ => self.above_safe_s = 0.0,
            }
            if inp.request.mode == TargetMode::Detumble || self.above_safe_s >= self.cfg.safe_hold_s
            {
                self.detumbling = true;
                self.below_exit_s = 0.0;
            }
        }

        let max_dipole = self.body.mtq_max_dipole_am2;
        if self.detumbling {
            if let (Some(b), Some(pb)) = (mag, prev_mag) {
                out.mtq_dipole_cmd_am2 =
                    control::bdot_dipole_am2(&b, &pb, dt_s, &self.cfg.control, max_dipole);
            }
            return out;
        }

        out.mode_in_effect = inp.request.mode;
        out.state = STATE_ACQUIRING;
        let h_wheels = crate::truth::wheel_momentum_body_nms(&self.body, &inp.wheel_speed_rad_s);
        let target = match (inp.request.pointing, inp.onboard) {
            (Some(p), Some(env)) => guidance::target(
                &p,
                &GuidanceInputs {
                    unix_s: env.unix_ns as f64 * 1e-9,
                    r_eci_m: env.r_eci_m,
                    v_eci_m_s: env.v_eci_m_s,
                    sun_eci_unit: env.sun_eci_unit,
                    a_ecef_from_eci: env.a_ecef_from_eci,
                },
            ),
            _ => None,
        };
        out.target = target;
        let w = w_est.unwrap_or_default();
        // Desaturation first: the wheels then also cancel the magnetorquers' torque, so
        // that it does not become pointing error.
        let mut mtq_torque = Vector3::zeros();
        if let Some(b) = mag {
            out.mtq_dipole_cmd_am2 =
                control::desat_dipole_am2(&h_wheels, &b, &self.cfg.control, max_dipole);
            mtq_torque = control::mtq_torque_body_nm(&out.mtq_dipole_cmd_am2, &b);
        }
        let torque = match (self.mekf.attitude(), &target) {
            (Some(q), Some(t)) => {
                if q.angle_to(&t.q_eci_from_body) < self.cfg.tracking_threshold_rad {
                    out.state = STATE_TRACKING;
                }
                control::attitude_torque_nm(
                    &q,
                    &w,
                    t,
                    &h_wheels,
                    &self.body.inertia_kg_m2,
                    &self.cfg.control,
                )
            }
            // No estimate or no target: damp the rate and wait.
            _ => -(self.body.inertia_kg_m2 * w) * self.cfg.control.kd(),
        };
        out.wheel_torque_cmd_nm = control::wheel_commands_nm(
            &(torque - mtq_torque),
            &self.body.wheels,
            inp.wheel_healthy,
            &inp.wheel_speed_rad_s,
            &self.cfg.control,
        );
        out
    }
}
