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
//!   falls back to detumble (the safe mode) when the measured rate exceeds
//!   [`AdcsConfig::safe_rate_rad_s`] for [`AdcsConfig::safe_hold_s`] (a tumble: a stuck
//!   wheel, a controller fighting a bad estimate), or when the estimator has been unhealthy
//!   for [`HealthConfig::dwell_s`] (below); [`Adcs::fallback_reason`] says which.
//! - **Determination**: the MEKF ([`crate::estimator`]) propagated with the gyro and updated
//!   with the magnetometer (every tick) and the sun vector of the coarse sun sensors (when
//!   the onboard model says sunlit); initialised by TRIAD (sun primary, field secondary).
//! - **Without a gyro** (dead, or a non-finite sample) the MEKF carries the body rate as a
//!   state and propagates it with Euler's equations, `I dw/dt = tau - w x (I w + h)`, from
//!   what the flight software knows: the wheels' reaction torque from the tachometers
//!   (`-(h(t) - h(t - dt)) / dt`: exact, it includes friction, clipping and a seized wheel),
//!   the magnetorquer torque of the last command and of the ground-measured residual dipole
//!   ([`AdcsConfig::residual_dipole_am2`]) on the last calibrated field, and the gravity
//!   gradient at the onboard position and the estimated attitude; drag and any unmeasured
//!   dipole (below 1e-7 N m) are the filter's rate random walk. The residual dipole matters:
//!   its 1e-7 N m, unmodelled, turned into 0.05 deg/s of rate error over 15 minutes of
//!   eclipse (magnetometer only) and tens of degrees of drift. The controller and
//!   the safe-rate check use that rate state. (Until this change the attitude was held
//!   between updates and the rate was the finite difference of successive estimates: in
//!   eclipse, with the magnetometer alone, the estimate drifted about the field at the orbit
//!   rate, the controller followed it and the loop diverged to 8 deg/s without the rate
//!   fallback seeing it, since it watched that same estimate.)
//! - **Estimator health** ([`HealthConfig`]): running averages (time constant
//!   [`HealthConfig::window_s`]) of the fraction of vector updates the MEKF gates out and of
//!   their normalised innovation squared, and the MEKF's attitude 1-sigma. Any of them past
//!   its threshold makes the estimator unhealthy; unhealthy for [`HealthConfig::dwell_s`],
//!   the ADCS restarts the filter (TRIAD again, bias forgotten) and, in a pointing mode,
//!   falls back to detumble. It leaves detumble only with a healthy estimator. A flight
//!   ADCS watches its estimator because the rate fallback alone cannot see a confidently
//!   wrong estimate: the rate it watches comes from that estimate.
//! - **Control**: quaternion feedback with rate limit and gyroscopic compensation on the
//!   healthy reaction wheels ([`crate::control`]), momentum desaturation with the
//!   magnetorquers. Idle: every actuator off.
//!
//! The magnetometer is read while the magnetorquers are on (no duty cycling): the twin's
//! magnetometer does not see the magnetorquers' field (documented in docs/adcs.md).

use icd::fc::TargetMode;
use nalgebra::{UnitQuaternion, Vector3};

use crate::control::{self, ControlConfig};
use crate::environment::Environment;
use crate::estimator::{Mekf, MekfConfig, triad};
use crate::guidance::{self, GuidanceInputs, GuidanceTarget, Pointing};
use crate::sensors::SensorReadings;
use crate::truth::BodyConfig;

/// TMACD `state`: the ADCS is off (idle).
pub const STATE_OFF: u8 = 0;
/// TMACD `state`: detumbling.
pub const STATE_DETUMBLING: u8 = 1;
/// TMACD `state`: acquiring (pointing mode, estimate missing or error above the threshold).
pub const STATE_ACQUIRING: u8 = 2;
/// TMACD `state`: tracking the target.
pub const STATE_TRACKING: u8 = 3;

/// Why the ADCS fell back to detumble ([`Adcs::fallback_reason`]), or which threshold of
/// the estimator's health was exceeded ([`EstimatorHealth::unhealthy`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FallbackReason {
    /// The body rate stayed above the safe rate.
    Rate,
    /// The MEKF gated out too many updates.
    Gated,
    /// The accepted innovations were too large for the filter's covariance.
    Innovation,
    /// The attitude uncertainty grew too large.
    Sigma,
}

impl FallbackReason {
    /// What the logs and the health check say.
    pub const fn as_str(self) -> &'static str {
        match self {
            FallbackReason::Rate => "rate above the safe limit",
            FallbackReason::Gated => "estimator unhealthy: updates gated out",
            FallbackReason::Innovation => "estimator unhealthy: innovations too large",
            FallbackReason::Sigma => "estimator unhealthy: attitude uncertainty too large",
        }
    }
}

impl std::fmt::Display for FallbackReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// [`FallbackReason::Rate`].
pub const REASON_RATE: FallbackReason = FallbackReason::Rate;
/// [`FallbackReason::Gated`].
pub const REASON_GATED: FallbackReason = FallbackReason::Gated;
/// [`FallbackReason::Innovation`].
pub const REASON_INNOVATION: FallbackReason = FallbackReason::Innovation;
/// [`FallbackReason::Sigma`].
pub const REASON_SIGMA: FallbackReason = FallbackReason::Sigma;

/// Thresholds of the estimator health monitor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HealthConfig {
    /// Time constant of the running averages (gated fraction, innovation), s.
    pub window_s: f64,
    /// Gated fraction of the vector updates above which the estimator is unhealthy.
    pub max_rejected_fraction: f64,
    /// Mean normalised innovation squared above which the estimator is unhealthy (each
    /// update's value clipped at [`NIS_CLIP`] before averaging).
    pub max_mean_nis: f64,
    /// Attitude 1-sigma (worst axis) above which the estimator is unhealthy, rad.
    pub max_attitude_sigma_rad: f64,
    /// How long the estimator must stay unhealthy before the ADCS acts, s.
    pub dwell_s: f64,
}

/// A single update's normalised innovation squared counts at most this much in the mean
/// (four times the 5-sigma gate's 25): one wild outlier does not make the mean.
pub const NIS_CLIP: f64 = 100.0;

impl Default for HealthConfig {
    /// - `window_s` 60 s: a minute of 10 Hz updates (600-1200), long against one noisy or
    ///   gated sample, short against the 10 s safe-rate hold plus a slew.
    /// - `max_rejected_fraction` 0.5: a consistent filter gates out 4e-6 of its updates; half
    ///   means a sensor (or the estimate) is wrong, not noisy.
    /// - `max_mean_nis` 10: the mean is about 2 for a consistent filter (two degrees of
    ///   freedom per vector); measured nominal runs stay below 1.5 (the 0.25 deg
    ///   magnetometer and 0.5 deg sun sigmas are conservative).
    /// - `max_attitude_sigma_rad` 5 deg: the TRIAD start (10 deg) converges below 1 deg within
    ///   a minute of sun and field updates; 5 deg is half the init sigma, and above the
    ///   detumble exit's own 60 s hold after an initialisation.
    /// - `dwell_s` 10 s, as the safe-rate hold: the averages already filter over a minute,
    ///   and every second a controller spends on a wrong estimate (or a wrong rate) can put
    ///   up to 2 mN m x 3 of wheel torque into the body (a 1 deg/s gyro bias jump trips after
    ///   about 20 s with it; with 30 s a 5.7 deg/s one left the body at 7 deg/s).
    fn default() -> Self {
        HealthConfig {
            window_s: 60.0,
            max_rejected_fraction: 0.5,
            max_mean_nis: 10.0,
            max_attitude_sigma_rad: 5.0_f64.to_radians(),
            dwell_s: 10.0,
        }
    }
}

/// The estimator health monitor's figures at the last tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EstimatorHealth {
    /// Running gated fraction of the vector updates (0 without updates).
    pub rejected_fraction: f64,
    /// Running mean normalised innovation squared (0 without updates).
    pub mean_nis: f64,
    /// The MEKF's attitude 1-sigma, worst axis, rad (`pi` uninitialised).
    pub attitude_sigma_rad: f64,
    /// The first threshold exceeded ([`REASON_GATED`], [`REASON_INNOVATION`],
    /// [`REASON_SIGMA`]); `None` while healthy or uninitialised.
    pub unhealthy: Option<FallbackReason>,
    /// How long it has been unhealthy without a break, s.
    pub unhealthy_s: f64,
}

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
    /// Nadir vector direction 1-sigma for the filter, rad (0.5 deg: the sensor's 0.2 deg
    /// with the whole limb, 0.6 with part of it, and the onboard position's error).
    pub horizon_sigma_rad: f64,
    /// Hard-iron bias the magnetometer calibration removes, nT (ICD 1.3 "sensors
    /// calibration"): by default the sensor model's bias, i.e. calibrated on the ground; a
    /// scenario's `bias:` fault adds an uncalibrated part on top.
    pub mag_calibration_bias_nt: Vector3<f64>,
    /// The bus's residual magnetic dipole as measured on the ground, body, A m^2: its torque
    /// `m x B` on the calibrated field is part of the gyro-less dynamics model. By default
    /// the FC's default residual dipole (2, 2, 5) mA m^2 (a magnetic cleanliness test); a
    /// scenario's other figure is an unmeasured part the filter's rate noise must cover.
    pub residual_dipole_am2: Vector3<f64>,
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
    /// Estimator health thresholds.
    pub health: HealthConfig,
    /// Which sensors the flight software uses (a switched-off one is read as absent).
    pub use_sensors: SensorUse,
}

/// Which sensors the determination uses (platform parameters `use_gyro`, `use_mag`,
/// `use_sun`): an unused sensor's reading is taken as absent, as a dead one's is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorUse {
    /// The gyroscope (without it the MEKF carries the rate, gyro-less).
    pub gyro: bool,
    /// The magnetometer.
    pub mag: bool,
    /// The coarse sun sensors' sun vector.
    pub sun: bool,
    /// The Earth-horizon sensor's nadir vector (off by default: the M6P's reference
    /// determination is sun and field; on, it also holds the attitude in eclipse).
    pub horizon: bool,
}

impl Default for SensorUse {
    fn default() -> Self {
        SensorUse {
            gyro: true,
            mag: true,
            sun: true,
            horizon: false,
        }
    }
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
            horizon_sigma_rad: 0.5_f64.to_radians(),
            mag_calibration_bias_nt: crate::sensors::SensorConfig::default().mag_bias_nt,
            // The FC's default (`FcConfig::default().residual_dipole_am2`).
            residual_dipole_am2: Vector3::new(0.002, 0.002, 0.005),
            detumble_exit_rate_rad_s: 1.0_f64.to_radians(),
            detumble_exit_hold_s: 60.0,
            safe_rate_rad_s: 5.0_f64.to_radians(),
            safe_hold_s: 10.0,
            tracking_threshold_rad: 2.0_f64.to_radians(),
            panel_normal_body: guidance::DEFAULT_PANEL_NORMAL_BODY,
            health: HealthConfig::default(),
            use_sensors: SensorUse::default(),
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
    /// The wheel momentum at the last tick, body, N m s (for the gyro-less dynamics).
    prev_h_wheels_body_nms: Option<Vector3<f64>>,
    /// The known external torque over the step that follows the last tick (magnetorquer
    /// command on the last field, gravity gradient), body, N m.
    known_torque_body_nm: Vector3<f64>,
    /// Running sums of the health monitor (time-weighted exponential averages).
    avg_attempts: f64,
    avg_rejected: f64,
    avg_nis: f64,
    health: EstimatorHealth,
    fallback_reason: Option<FallbackReason>,
    estimator_restarts: u64,
}

impl Adcs {
    /// The running configuration (platform parameters change it in flight).
    pub fn config_mut(&mut self) -> &mut AdcsConfig {
        &mut self.cfg
    }
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
            prev_h_wheels_body_nms: None,
            known_torque_body_nm: Vector3::zeros(),
            avg_attempts: 0.0,
            avg_rejected: 0.0,
            avg_nis: 0.0,
            health: EstimatorHealth::default(),
            fallback_reason: None,
            estimator_restarts: 0,
        }
    }

    /// Why the ADCS last fell back to detumble ([`REASON_RATE`], [`REASON_GATED`],
    /// [`REASON_INNOVATION`], [`REASON_SIGMA`]): `Some` from the fallback until it leaves
    /// detumble again; `None` otherwise (and for a commanded detumble).
    pub fn fallback_reason(&self) -> Option<FallbackReason> {
        self.fallback_reason
    }

    /// The estimator health monitor's figures at the last tick.
    pub fn health(&self) -> &EstimatorHealth {
        &self.health
    }

    /// How many times the health monitor has restarted the estimator.
    pub fn estimator_restarts(&self) -> u64 {
        self.estimator_restarts
    }

    /// The gyro-less body rate estimate (the MEKF's rate state), rad/s; `None` with a gyro.
    pub fn gyroless_rate_rad_s(&self) -> Option<Vector3<f64>> {
        self.mekf.rate_state_rad_s()
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

    /// The body's angular acceleration over the last step for the gyro-less propagation:
    /// Euler's equations with the wheels' reaction torque from the tachometers, the known
    /// external torque and the gyroscopic term at the rate state, rad/s^2.
    fn gyroless_accel_rad_s2(&self, h_wheels_body_nms: &Vector3<f64>, dt_s: f64) -> Vector3<f64> {
        let w = self.mekf.rate_state_rad_s().unwrap_or_default();
        let h_prev = self.prev_h_wheels_body_nms.unwrap_or(*h_wheels_body_nms);
        let wheel_reaction = -(h_wheels_body_nms - h_prev) / dt_s;
        let h_mid = (h_wheels_body_nms + h_prev) * 0.5;
        let i = &self.body.inertia_kg_m2;
        let torque = wheel_reaction + self.known_torque_body_nm - w.cross(&(i * w + h_mid));
        i.try_inverse()
            .map_or_else(Vector3::zeros, |inv| inv * torque)
    }

    fn propagate(&mut self, r: &SensorReadings, h_wheels_body_nms: &Vector3<f64>, dt_s: f64) {
        match r
            .gyro_body_rad_s
            .filter(|g| g.iter().all(|x| x.is_finite()))
        {
            Some(g) => self.mekf.propagate(Some(&g), dt_s),
            None if dt_s > 0.0 => {
                let a = self.gyroless_accel_rad_s2(h_wheels_body_nms, dt_s);
                self.mekf.propagate_without_gyro(&a, dt_s);
            }
            None => {}
        }
    }

    fn determine(
        &mut self,
        r: &SensorReadings,
        env: Option<&Environment>,
        h_wheels_body_nms: &Vector3<f64>,
        dt_s: f64,
    ) -> (u32, u32, f64) {
        let Some(env) = env else {
            // No references: nothing to determine the attitude against.
            if self.mekf.is_initialised() {
                self.propagate(r, h_wheels_body_nms, dt_s);
            }
            return (0, 0, 0.0);
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
            return (0, 0, 0.0);
        }
        self.propagate(r, h_wheels_body_nms, dt_s);
        // Update attempts that reached the gate, rejections, sum of clipped NIS.
        let mut tally = (0u32, 0u32, 0.0f64);
        let nadir_ref = (-env.r_eci_m).try_normalize(0.0);
        let pairs = [
            (r.mag_body_nt.zip(b_ref), self.cfg.mag_sigma_rad),
            (r.sun_body_unit.zip(sun_ref), self.cfg.sun_sigma_rad),
            (
                r.horizon_nadir_body.zip(nadir_ref),
                self.cfg.horizon_sigma_rad,
            ),
        ];
        for (pair, sigma) in pairs {
            let Some((meas, reference)) = pair else {
                continue;
            };
            let rejected_before = self.mekf.rejected_updates();
            let accepted = self.mekf.update_vector(&meas, &reference, sigma);
            let rejected = self.mekf.rejected_updates() > rejected_before;
            if accepted || rejected {
                tally.0 += 1;
                tally.1 += u32::from(rejected);
                tally.2 += self.mekf.last_nis().unwrap_or(0.0).min(NIS_CLIP);
            }
        }
        tally
    }

    /// Update the health monitor with one tick's update tally; restart the estimator after
    /// `dwell_s` unhealthy. Returns the reason when it has just done so.
    fn monitor_health(&mut self, tally: (u32, u32, f64), dt_s: f64) -> Option<FallbackReason> {
        let h = self.cfg.health;
        let a = if h.window_s > 0.0 {
            (dt_s / h.window_s).clamp(0.0, 1.0)
        } else {
            1.0
        };
        // Per-tick sums averaged over the window; their ratios are per-update means.
        self.avg_attempts += (f64::from(tally.0) - self.avg_attempts) * a;
        self.avg_rejected += (f64::from(tally.1) - self.avg_rejected) * a;
        self.avg_nis += (tally.2 - self.avg_nis) * a;
        // Below a tenth of an update per tick on average the ratios mean little.
        let enough = self.avg_attempts > 0.1;
        let ratio = |x: f64| if enough { x / self.avg_attempts } else { 0.0 };
        let rejected_fraction = ratio(self.avg_rejected);
        let accepted = self.avg_attempts - self.avg_rejected;
        let mean_nis = if enough && accepted > 0.05 {
            (self.avg_nis / self.avg_attempts).min(NIS_CLIP)
        } else {
            0.0
        };
        let sigma = self.mekf.attitude_sigma_rad();
        let unhealthy = if !self.mekf.is_initialised() {
            None
        } else if rejected_fraction > h.max_rejected_fraction {
            Some(REASON_GATED)
        } else if mean_nis > h.max_mean_nis {
            Some(REASON_INNOVATION)
        } else if sigma > h.max_attitude_sigma_rad {
            Some(REASON_SIGMA)
        } else {
            None
        };
        let unhealthy_s = if unhealthy.is_some() {
            self.health.unhealthy_s + dt_s
        } else {
            0.0
        };
        self.health = EstimatorHealth {
            rejected_fraction,
            mean_nis,
            attitude_sigma_rad: sigma,
            unhealthy,
            unhealthy_s,
        };
        let why = unhealthy.filter(|_| unhealthy_s >= h.dwell_s)?;
        // Restart: TRIAD again at the next sun and field, bias forgotten, averages cleared.
        self.mekf.reset();
        self.avg_attempts = 0.0;
        self.avg_rejected = 0.0;
        self.avg_nis = 0.0;
        self.health.unhealthy = None;
        self.health.unhealthy_s = 0.0;
        self.estimator_restarts = self.estimator_restarts.saturating_add(1);
        Some(why)
    }

    /// The estimated body rate: gyro minus estimated bias, or without a gyro the MEKF's rate
    /// state.
    fn rate_estimate(&self, r: &SensorReadings) -> Option<Vector3<f64>> {
        let est = self.mekf.attitude();
        match r
            .gyro_body_rad_s
            .filter(|g| g.iter().all(|x| x.is_finite()))
        {
            Some(g) => Some(if est.is_some() {
                self.mekf.rate_body_rad_s(&g)
            } else {
                g
            }),
            None => est.and(self.mekf.rate_state_rad_s()),
        }
    }

    /// One ADCS tick of `dt_s`.
    pub fn step(&mut self, inp: &Inputs<'_>, dt_s: f64) -> Output {
        let h_wheels = crate::truth::wheel_momentum_body_nms(&self.body, &inp.wheel_speed_rad_s);
        let out = self.step_inner(inp, &h_wheels, dt_s);
        // What the gyro-less propagation of the next tick knows of the external torque.
        let b_t = self
            .prev_mag_body_nt
            .map_or_else(Vector3::zeros, |b| b * 1e-9);
        let m = crate::truth::mtq_dipole_applied_am2(&self.body, &out.mtq_dipole_cmd_am2);
        let gg = match (self.mekf.attitude(), inp.onboard) {
            (Some(q), Some(env)) => {
                crate::truth::gravity_gradient_body_nm(&self.body, &q, &env.r_eci_m)
            }
            _ => Vector3::zeros(),
        };
        self.known_torque_body_nm = (m + self.cfg.residual_dipole_am2).cross(&b_t) + gg;
        self.prev_h_wheels_body_nms = Some(h_wheels);
        out
    }

    /// What the determination may use: deselected sensors dropped, the magnetometer calibrated.
    fn calibrated(&self, readings: &SensorReadings) -> SensorReadings {
        let used = self.cfg.use_sensors;
        SensorReadings {
            mag_body_nt: readings
                .mag_body_nt
                .filter(|_| used.mag)
                .map(|b| b - self.cfg.mag_calibration_bias_nt),
            gyro_body_rad_s: readings.gyro_body_rad_s.filter(|_| used.gyro),
            sun_body_unit: readings.sun_body_unit.filter(|_| used.sun),
            horizon_nadir_body: readings.horizon_nadir_body.filter(|_| used.horizon),
            ..*readings
        }
    }

    /// Detumble's exit (slow, orbit known, estimate healthy) and fallback (high rate, restart).
    fn update_detumbling(
        &mut self,
        inp: &Inputs<'_>,
        rate: Option<f64>,
        restarted: Option<FallbackReason>,
        dt_s: f64,
    ) {
        if self.detumbling {
            match rate {
                Some(w) if w < self.cfg.detumble_exit_rate_rad_s => self.below_exit_s += dt_s,
                _ => self.below_exit_s = 0.0,
            }
            if inp.request.mode != TargetMode::Detumble
                && inp.onboard.is_some()
                && self.mekf.is_initialised()
                && self.health.unhealthy.is_none()
                && self.below_exit_s >= self.cfg.detumble_exit_hold_s
            {
                self.detumbling = false;
                self.above_safe_s = 0.0;
                self.fallback_reason = None;
            }
        } else {
            match rate {
                Some(w) if w > self.cfg.safe_rate_rad_s => self.above_safe_s += dt_s,
                _ => self.above_safe_s = 0.0,
            }
            let why = if restarted.is_some() {
                restarted
            } else if self.above_safe_s >= self.cfg.safe_hold_s {
                Some(REASON_RATE)
            } else {
                None
            };
            if inp.request.mode == TargetMode::Detumble || why.is_some() {
                self.detumbling = true;
                self.below_exit_s = 0.0;
                self.fallback_reason = why;
            }
        }
    }

    fn step_inner(&mut self, inp: &Inputs<'_>, h_wheels: &Vector3<f64>, dt_s: f64) -> Output {
        let calibrated = self.calibrated(inp.readings);
        let r = &calibrated;
        let tally = self.determine(r, inp.onboard, h_wheels, dt_s);
        let restarted = self.monitor_health(tally, dt_s);
        let w_est = self.rate_estimate(r);
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

        self.update_detumbling(inp, rate, restarted, dt_s);

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
        let h_wheels = *h_wheels;
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

// What a snapshot keeps of the ADCS (docs/snapshots.md): the configuration too, which the
// FC's parameters change in flight; the body is the scenario's.
snap::unit_enum!(FallbackReason {
    Rate,
    Gated,
    Innovation,
    Sigma
});
snap::fields!(EstimatorHealth {
    rejected_fraction,
    mean_nis,
    attitude_sigma_rad,
    unhealthy,
    unhealthy_s
});
snap::fields!(HealthConfig {
    window_s,
    max_rejected_fraction,
    max_mean_nis,
    max_attitude_sigma_rad,
    dwell_s
});
snap::fields!(SensorUse {
    gyro,
    mag,
    sun,
    horizon
});
snap::fields!(AdcsConfig {
    control,
    mekf,
    mag_sigma_rad,
    sun_sigma_rad,
    horizon_sigma_rad,
    mag_calibration_bias_nt,
    residual_dipole_am2,
    detumble_exit_rate_rad_s,
    detumble_exit_hold_s,
    safe_rate_rad_s,
    safe_hold_s,
    tracking_threshold_rad,
    panel_normal_body,
    health,
    use_sensors
});
snap::fields!(Adcs {
    cfg,
    mekf,
    detumbling,
    below_exit_s,
    above_safe_s,
    prev_mag_body_nt,
    prev_h_wheels_body_nms,
    known_torque_body_nm,
    avg_attempts,
    avg_rejected,
    avg_nis,
    health,
    fallback_reason,
    estimator_restarts;
    skip body
});
snap::fields!(Output {
    wheel_torque_cmd_nm,
    mtq_dipole_cmd_am2,
    mode_in_effect,
    state,
    target,
    w_body_rad_s_est
});
