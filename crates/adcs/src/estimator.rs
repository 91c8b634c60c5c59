//! ADCS attitude determination: a multiplicative extended Kalman filter ([`Mekf`]) that
//! fuses a rate gyro with body-frame unit-vector measurements (magnetometer, coarse sun
//! sensors), and the TRIAD method ([`triad`]) that gives it its first attitude.
//!
//! A pure, deterministic core: inputs carry the step `dt_s`; no clock, no randomness, no
//! allocation (nalgebra fixed-size types only). Frames follow ICD 1.4 and the house style:
//! the attitude is `q_eci_from_body`, active (`q_eci_from_body * v_body = v_eci`), ECI is
//! J2000 and body is the BCF.
//!
//! # The filter
//! The MEKF of Lefferts, Markley & Shuster, "Kalman Filtering for Spacecraft Attitude
//! Estimation", J. Guidance, Control, and Dynamics 5(5), 1982, pp. 417-429, in the form of
//! Markley & Crassidis, "Fundamentals of Spacecraft Attitude Determination and Control",
//! Springer 2014, ch. 6 (section 6.2, the multiplicative EKF):
//! - **State**: the reference attitude `q` (a unit quaternion, kept normalised) and the gyro
//!   bias estimate `b`, rad/s. The filter's six error states are `dx = (dtheta, db)`:
//!   `q_true = q * dq(dtheta)` with `dtheta` a small rotation vector in the *body* frame,
//!   and `b_true = b + db`. [`Mekf::covariance`] is the 6x6 covariance of `dx`, attitude
//!   block first, rad^2 and (rad/s)^2.
//! - **Gyro model**: `gyro = w_true + b_true + v`, with `v` white (per sample, 1-sigma
//!   [`MekfConfig::gyro_noise_rad_s`]) and `db/dt` white (the bias random walk,
//!   [`MekfConfig::gyro_bias_walk_rad_s2`]).
//! - **Propagation** with a gyro sample held constant over `dt_s`: `w = gyro - b`,
//!   `q <- q * exp((0, w dt / 2))`, the rotation by `w dt` (exact for a constant rate), `P <- Phi P Phi^T + Qd` with
//!   `F = [[-[w x], -I], [0, 0]]` and its exact transition matrix
//!   `Phi11 = exp(-[w x] dt)`, `Phi12 = -integral_0^dt exp(-[w x] s) ds` (closed form by
//!   Rodrigues, series for small `|w| dt`), and the discrete process noise of Markley &
//!   Crassidis section 6.2: `Q11 = (sv^2 dt + su^2 dt^3 / 3) I`, `Q12 = -(su^2 dt^2 / 2) I`,
//!   `Q22 = su^2 dt I`, where `sv^2 dt = (gyro_noise_rad_s * dt)^2` (the noise is given per
//!   sample) and `su = gyro_bias_walk_rad_s2 * sqrt(1 s)`.
//! - **Propagation without a gyro** ([`Mekf::propagate_without_gyro`], or `propagate(None)`:
//!   the gyro is dead): the filter switches its second error block from the gyro bias to the
//!   **body rate** (Markley & Crassidis section 6.2.4, "gyroless" attitude estimation with a
//!   dynamics model). The rate state `w` is propagated with the body's angular acceleration
//!   the caller computes from what it knows (Euler's equations with the wheel tachometers,
//!   the magnetorquer command, the gravity gradient: `crate::adcs`), trapezoidally:
//!   `q <- q * exp((0, (w + a dt / 2) dt / 2))`, `w <- w + a dt`. The error state is then
//!   `dx = (dtheta, dw)` with `w_true = w + dw`, `F = [[-[w x], I], [0, 0]]` (the gyroscopic
//!   coupling of `dw` is neglected: at the rates of a pointing bus, 1e-3 rad/s, it acts over
//!   hours), `Phi12 = +integral_0^dt exp(-[w x] s) ds`, and the unmodelled torques (drag,
//!   model errors; some 2e-8 N m on the default 6U, 4e-7 rad/s^2 about its smallest axis) as
//!   a rate random walk [`MekfConfig::no_gyro_accel_sigma_rad_s2`]:
//!   `Q11 = sa^2 dt^3 / 3`, `Q12 = sa^2 dt^2 / 2`, `Q22 = sa^2 dt`. The vector updates are
//!   unchanged; their correction of the second block goes to the rate. Entering this mode the
//!   rate starts at the running average of the gyro rate `gyro - b` (time constant
//!   [`MekfConfig::gyro_rate_smoothing_s`]; its covariance the bias covariance plus the
//!   averaged gyro noise, the cross terms negated as `dw = -db`), or at zero with
//!   [`MekfConfig::no_gyro_rate_sigma_rad_s`] when no gyro rate is known. The gyro bias
//!   estimate is frozen meanwhile and restored with the next gyro sample, its covariance grown
//!   by the bias random walk over the gap (cross terms zero). Why a rate model and not the old
//!   attitude random walk (`w = 0`): a nadir-pointing bus turns at the orbit rate
//!   (0.063 deg/s) and the controller turns it further; holding the attitude makes every
//!   propagation wrong by that, and in eclipse the magnetometer alone cannot see the rotation
//!   about the field, so the estimate drifted about it, the controller followed the wrong
//!   estimate and the loop diverged (the body reached 8 deg/s within 20 minutes of a dead gyro
//!   in eclipse, on every seed of `scenarios/adcs-gyro-dead.toml`'s window).
//! - **Vector update**: `meas_body = q_true^-1 * ref_eci + noise`, both unit-normalised. The
//!   predicted measurement is `r_b = q^-1 * ref_eci`, the innovation `y = meas - r_b`, the
//!   sensitivity `H = [[r_b x], 0]` (because `q_true^-1 ref = r_b + [r_b x] dtheta` to first
//!   order), the noise `R = sigma^2 I3` (Markley & Crassidis's choice: the component of `y`
//!   along `r_b` is second order and `H^T` annihilates it, so the singular direction of the
//!   unit-vector noise does no harm), `S = H P H^T + R`, `K = P H^T S^-1`, `dx = K y`, the
//!   Joseph form `P <- (I - K H) P (I - K H)^T + K R K^T`, then the reset
//!   `q <- q * exp((0, dtheta / 2))` (normalised), `b <- b + db`.
//! - **Gate**: an update whose squared Mahalanobis distance `y^T S^-1 y` exceeds
//!   [`MekfConfig::gate_sigma`]`^2` (25 by default: the innovation has two effective degrees
//!   of freedom, so a consistent filter rejects a good measurement with probability
//!   `exp(-12.5) = 4e-6`) is rejected and leaves the state unchanged.
//! - **Lost lock**: [`MekfConfig::max_consecutive_rejections`] gate rejections in a row,
//!   with no update accepted in between, mean the filter is confidently wrong (every sensor
//!   disagrees with it, e.g. after an unmodelled jump); the attitude block is then reopened
//!   to [`MekfConfig::init_attitude_sigma_rad`] (attitude-bias cross terms zeroed) so the
//!   next measurements can pull it back. A single bad sensor does not trigger this while
//!   another one is still accepted.
//!
//! # Invariants
//! - The quaternion is renormalised after every step; the covariance is symmetrised after
//!   every step.
//! - Every step computes its result aside and commits it only if the quaternion, bias and
//!   covariance are all finite and the covariance diagonal non-negative; otherwise the filter
//!   [`Mekf::reset`]s to uninitialised (bias zero) rather than carry a poisoned state. The
//!   caller re-initialises it (TRIAD).
//! - Invalid inputs are refused before anything is computed: a non-finite or non-positive
//!   `dt_s` makes `propagate` a no-op; a zero or non-finite vector, or a `sigma_rad` outside
//!   `(0, pi]`, makes `update_vector` return `false` with the state unchanged.
//! - Uninitialised, `propagate` does nothing and `update_vector` returns `false`.
//! - The filter does not bound its own attitude uncertainty: with the gyro dead and no
//!   measurements, [`Mekf::attitude_sigma_rad`] grows without limit; the caller decides when
//!   the estimate is too poor to use (and may reset and re-run TRIAD). For that it reads the
//!   filter's health figures: [`Mekf::last_nis`] (the normalised innovation squared of the
//!   last update attempt, accepted or gated), [`Mekf::accepted_updates`] and
//!   [`Mekf::rejected_updates`], [`Mekf::attitude_sigma_rad`] (`crate::adcs` watches them).
//!
//! # Use (the ADCS loop at 10 Hz)
//! While uninitialised, run [`triad`] (sun primary, field secondary) when both are
//! available and [`Mekf::initialise`] with it. Then every step: [`Mekf::propagate`] with the
//! gyro sample (or `None`), [`Mekf::update_vector`] with the magnetometer against the field
//! model (`sigma` = noise / |B| plus the model error, 1-2 deg) and, when sunlit, with the
//! coarse sun vector (2-5 deg). [`Mekf::rate_body_rad_s`] gives the rate for the controller.
//!
//! Measured on the simulated truth of `tests/estimator.rs` (default tuning, 1.5 deg field,
//! 3 deg sun, gyro 0.01 deg/s noise and 0.1 deg/s bias per axis, ten seeds): from a 10 deg
//! error the attitude stays below 0.5 deg after 23-106 s and the bias within 0.01 deg/s
//! after 39-87 s, with a steady error of 0.06-0.23 deg (mean) and 0.12-0.32 deg (max); with
//! the field alone it stays below 1 deg after 243-654 s (0.08-0.36 deg mean later); with the
//! gyro dead (the rate a filter state from zero) it follows a body turning at 0.2 deg/s
//! to 0.09 deg mean, 0.2 deg max over the last 100 s (seed 5; the attitude random walk
//! this replaced gave 0.6-1.1 deg mean). One propagation
//! and two updates take about 1.5-2 us (release build).
//!
//! # TRIAD
//! Black, "A Passive System for Determining the Attitude of a Satellite", AIAA Journal 2(7),
//! 1964; Shuster & Oh, "Three-Axis Attitude Determination from Vector Observations",
//! J. Guidance and Control 4(1), 1981; Markley & Crassidis ch. 5. The primary pair is trusted
//! fully and the secondary only fixes the rotation about it, so the more accurate sensor
//! (the sun, when sunlit) goes first. A field-only initialisation (two field measurements
//! separated in time and joined by the gyro) is deliberately not offered: with the bias
//! still unknown (0.1 deg/s is 6 deg per minute) and the field direction turning at about
//! twice the orbit rate (some 0.13 deg/s), the secondary's error divided by the sine of the
//! small separation gives tens of degrees. The caller waits for the sun instead.

use core::f64::consts::PI;

use nalgebra::{Matrix3, Matrix6, Rotation3, SMatrix, UnitQuaternion, Vector3};

/// One degree, rad.
const DEG: f64 = PI / 180.0;

/// Below this rotation angle `|w| dt`, rad, the transition matrix uses its Taylor series
/// (the closed form loses digits to cancellation; the series' first neglected term is
/// `theta^6 / 5040` relative, below 1e-15 here).
const SMALL_ANGLE_RAD: f64 = 1.0e-2;

/// Filter tuning. `Default` is a MEMS-gyro smallsat at the 10 Hz ADCS rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MekfConfig {
    /// Gyro white noise, 1-sigma per sample at the filter rate, rad/s. The attitude
    /// uncertainty grows by `gyro_noise_rad_s * dt` (1-sigma, per axis) per propagation.
    pub gyro_noise_rad_s: f64,
    /// Gyro bias random walk, rad/s^2: the 1-sigma change of the bias over one second, per
    /// axis, in rad/s (numerically the rate random walk density `su` in rad/s^(3/2)); the
    /// bias variance grows by `gyro_bias_walk_rad_s2^2 * dt * 1 s`.
    pub gyro_bias_walk_rad_s2: f64,
    /// Body rate 1-sigma per axis the gyro-less rate state starts with when no gyro rate is
    /// known (the gyro was dead from the start), rad/s.
    pub no_gyro_rate_sigma_rad_s: f64,
    /// Time constant of the running average of the gyro rate (`gyro - b`) that starts the
    /// gyro-less rate state, s (one sample's noise would otherwise become a rate error that
    /// lasts until the vector updates see it).
    pub gyro_rate_smoothing_s: f64,
    /// Rate random walk of the gyro-less propagation, rad/s^2: the 1-sigma change of the
    /// body rate over one second that the dynamics model does not explain (the rate variance
    /// grows by `no_gyro_accel_sigma_rad_s2^2 * dt * 1 s`).
    pub no_gyro_accel_sigma_rad_s2: f64,
    /// Attitude 1-sigma per axis set by [`Mekf::initialise`] and by a gate reopening, rad.
    pub init_attitude_sigma_rad: f64,
    /// Gyro bias 1-sigma per axis set by [`Mekf::initialise`], rad/s.
    pub init_bias_sigma_rad_s: f64,
    /// Innovation gate, in sigmas of the Mahalanobis distance (the update is rejected when
    /// `y^T S^-1 y > gate_sigma^2`).
    pub gate_sigma: f64,
    /// Gate rejections in a row after which the attitude covariance is reopened to
    /// `init_attitude_sigma_rad`; 0 never reopens.
    pub max_consecutive_rejections: u32,
}

impl Default for MekfConfig {
    /// - `gyro_noise_rad_s` 0.01 deg/s per 0.1 s sample (an angle random walk of
    ///   0.003 deg/sqrt(s) = 0.19 deg/sqrt(h), a good MEMS gyro such as the BMG250 class).
    /// - `gyro_bias_walk_rad_s2` 1e-6 rad/s^2: the bias may wander by 0.003 deg/s (1-sigma)
    ///   over a half orbit (2800 s), a good MEMS gyro's in-run bias instability (a few
    ///   deg/h). Chosen by simulation (tests/estimator.rs, five seeds): 1e-7 to 1e-6 give the
    ///   same convergence and a steady error of 0.12-0.18 deg mean with a 1.5 deg
    ///   magnetometer and a 3 deg sun sensor; 1e-5 doubles the steady error and makes the
    ///   field-only case converge 2-4 times slower. Raise it for a gyro with a stronger
    ///   temperature drift.
    /// - `no_gyro_rate_sigma_rad_s` 0.5 deg/s: a controlled or slowly tumbling bus.
    /// - `gyro_rate_smoothing_s` 10 s: the 0.01 deg/s sample noise averages down to
    ///   0.0007 deg/s per axis; a pointing bus's rate changes far slower (the orbit rate is
    ///   constant in nadir).
    /// - `no_gyro_accel_sigma_rad_s2` 1e-6 rad/s^2: two to three times the angular
    ///   acceleration the ADCS's dynamics model leaves out on the default 6U (drag, up to
    ///   2e-8 N m, over 0.05 kg m^2). Chosen by simulation (`tests/health.rs`, nadir with the
    ///   gyro dead for 30 minutes of eclipse, magnetometer only): 3e-7 to 1e-6 hold the
    ///   estimate within 1 deg; 3e-6 drifts to about 1 deg and 1e-5 to 6 deg (the filter
    ///   then explains the magnetometer noise as rate changes about the unobservable field
    ///   axis). Raise it for a bus whose residual dipole is not measured.
    /// - `init_attitude_sigma_rad` 10 deg: covers a TRIAD from 2-5 deg coarse sun sensors and
    ///   a 1-2 deg field model.
    /// - `init_bias_sigma_rad_s` 0.5 deg/s: an uncalibrated MEMS turn-on bias (datasheet zero
    ///   rate offsets are +-0.5 to +-1 deg/s).
    /// - `gate_sigma` 5; `max_consecutive_rejections` 50 (5 s of 10 Hz updates from one
    ///   sensor, 2.5 s from two).
    fn default() -> Self {
        Self {
            gyro_noise_rad_s: 0.01 * DEG,
            gyro_bias_walk_rad_s2: 1.0e-6,
            no_gyro_rate_sigma_rad_s: 0.5 * DEG,
            gyro_rate_smoothing_s: 10.0,
            no_gyro_accel_sigma_rad_s2: 1.0e-6,
            init_attitude_sigma_rad: 10.0 * DEG,
            init_bias_sigma_rad_s: 0.5 * DEG,
            gate_sigma: 5.0,
            max_consecutive_rejections: 50,
        }
    }
}

impl MekfConfig {
    /// This configuration with every non-finite or negative figure replaced by its default.
    pub fn sanitised(self) -> Self {
        let d = Self::default();
        let pick = |v: f64, dv: f64| if v.is_finite() && v >= 0.0 { v } else { dv };
        Self {
            gyro_noise_rad_s: pick(self.gyro_noise_rad_s, d.gyro_noise_rad_s),
            gyro_bias_walk_rad_s2: pick(self.gyro_bias_walk_rad_s2, d.gyro_bias_walk_rad_s2),
            no_gyro_rate_sigma_rad_s: pick(
                self.no_gyro_rate_sigma_rad_s,
                d.no_gyro_rate_sigma_rad_s,
            ),
            gyro_rate_smoothing_s: pick(self.gyro_rate_smoothing_s, d.gyro_rate_smoothing_s),
            no_gyro_accel_sigma_rad_s2: pick(
                self.no_gyro_accel_sigma_rad_s2,
                d.no_gyro_accel_sigma_rad_s2,
            ),
            init_attitude_sigma_rad: pick(self.init_attitude_sigma_rad, d.init_attitude_sigma_rad),
            init_bias_sigma_rad_s: pick(self.init_bias_sigma_rad_s, d.init_bias_sigma_rad_s),
            gate_sigma: pick(self.gate_sigma, d.gate_sigma),
            max_consecutive_rejections: self.max_consecutive_rejections,
        }
    }

    /// The covariance [`Mekf::initialise`] sets: diagonal, from the init sigmas.
    fn init_covariance(&self) -> Matrix6<f64> {
        let a = self.init_attitude_sigma_rad * self.init_attitude_sigma_rad;
        let b = self.init_bias_sigma_rad_s * self.init_bias_sigma_rad_s;
        Matrix6::from_diagonal(&nalgebra::Vector6::new(a, a, a, b, b, b))
    }
}

/// The multiplicative extended Kalman filter: attitude and gyro bias.
#[derive(Debug, Clone, PartialEq)]
pub struct Mekf {
    cfg: MekfConfig,
    /// `q_eci_from_body`; `None` until initialised.
    q_eci_from_body: Option<UnitQuaternion<f64>>,
    bias_rad_s: Vector3<f64>,
    /// Error-state covariance, `(dtheta, db)`, or `(dtheta, dw)` while gyro-less.
    p: Matrix6<f64>,
    /// The body rate state while gyro-less (`None` with a gyro), rad/s.
    rate_rad_s: Option<Vector3<f64>>,
    /// The bias covariance frozen while gyro-less, and the time spent gyro-less, s.
    frozen_bias_cov: Matrix3<f64>,
    gyroless_s: f64,
    /// The running average of the gyro rate (`gyro - b`), the gyro-less rate state's start,
    /// and its noise variance per axis; `None` until the first gyro propagation.
    last_gyro_rate_rad_s: Option<(Vector3<f64>, f64)>,
    consecutive_rejections: u32,
    rejected_updates: u64,
    accepted_updates: u64,
    gate_reopenings: u64,
    last_nis: Option<f64>,
}

impl Mekf {
    /// Create an uninitialised filter (bias estimate zero); invalid tuning figures are
    /// replaced by their defaults ([`MekfConfig::sanitised`]).
    pub fn new(cfg: MekfConfig) -> Self {
        let cfg = cfg.sanitised();
        Self {
            cfg,
            q_eci_from_body: None,
            bias_rad_s: Vector3::zeros(),
            p: cfg.init_covariance(),
            rate_rad_s: None,
            frozen_bias_cov: Matrix3::zeros(),
            gyroless_s: 0.0,
            last_gyro_rate_rad_s: None,
            consecutive_rejections: 0,
            rejected_updates: 0,
            accepted_updates: 0,
            gate_reopenings: 0,
            last_nis: None,
        }
    }

    /// The tuning in use.
    pub fn config(&self) -> &MekfConfig {
        &self.cfg
    }

    /// Whether the filter holds an attitude.
    pub fn is_initialised(&self) -> bool {
        self.q_eci_from_body.is_some()
    }

    /// Return to uninitialised, bias estimate zero, covariance to the init sigmas, no rate
    /// state. The update counters survive (they are statistics).
    pub fn reset(&mut self) {
        self.q_eci_from_body = None;
        self.bias_rad_s = Vector3::zeros();
        self.p = self.cfg.init_covariance();
        self.rate_rad_s = None;
        self.last_gyro_rate_rad_s = None;
        self.consecutive_rejections = 0;
        self.last_nis = None;
    }

    /// Start (or restart) from `q_eci_from_body` (e.g. [`triad`]'s), the covariance set to the
    /// init sigmas; the bias estimate is kept, a gyro-less rate state dropped (the next
    /// gyro-less step starts it again). A non-finite quaternion is ignored.
    pub fn initialise(&mut self, q_eci_from_body: UnitQuaternion<f64>) {
        let c = q_eci_from_body.coords;
        if !c.iter().all(|x| x.is_finite()) || c.norm() == 0.0 {
            return;
        }
        self.q_eci_from_body = Some(UnitQuaternion::new_normalize(q_eci_from_body.into_inner()));
        self.p = self.cfg.init_covariance();
        self.rate_rad_s = None;
        self.consecutive_rejections = 0;
    }

    /// Advance by `dt_s` with a gyro sample (rad/s, body frame, held over the step), or with
    /// `None` when the gyro is dead: then as [`Mekf::propagate_without_gyro`] with no
    /// angular acceleration (a body turning at its estimated rate). A non-finite sample counts
    /// as `None`; a non-finite or non-positive `dt_s` does nothing; uninitialised, nothing
    /// happens.
    pub fn propagate(&mut self, gyro_body_rad_s: Option<&Vector3<f64>>, dt_s: f64) {
        let Some(q) = self.q_eci_from_body else {
            return;
        };
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return;
        }
        let Some(g) = gyro_body_rad_s.filter(|g| g.iter().all(|x| x.is_finite())) else {
            self.propagate_without_gyro(&Vector3::zeros(), dt_s);
            return;
        };
        let su2 = self.cfg.gyro_bias_walk_rad_s2 * self.cfg.gyro_bias_walk_rad_s2;
        let mut p = self.p;
        if self.rate_rad_s.take().is_some() {
            // The gyro is back: the frozen bias returns, grown by its walk over the gap.
            let grown =
                self.frozen_bias_cov + Matrix3::from_diagonal_element(su2 * self.gyroless_s);
            p.fixed_view_mut::<3, 3>(3, 3).copy_from(&grown);
            p.fixed_view_mut::<3, 3>(0, 3).fill(0.0);
            p.fixed_view_mut::<3, 3>(3, 0).fill(0.0);
            self.gyroless_s = 0.0;
        }
        let w = g - self.bias_rad_s;
        let (phi11, phi12) = transition_blocks(&w, dt_s);
        let sv_dt = self.cfg.gyro_noise_rad_s * dt_s;
        let q11 = sv_dt * sv_dt + su2 * dt_s * dt_s * dt_s / 3.0;
        let q12 = -su2 * dt_s * dt_s / 2.0;
        let q22 = su2 * dt_s;
        let qd = block_noise(q11, q12, q22);
        let q_new = q * UnitQuaternion::from_scaled_axis(w * dt_s);
        if self.commit(
            q_new,
            self.bias_rad_s,
            transition_cov(&phi11, &phi12, &p) + qd,
        ) {
            // Exponential average; its steady noise variance is sv^2 a / (2 - a).
            let tau = self.cfg.gyro_rate_smoothing_s;
            let a = if tau > dt_s { dt_s / tau } else { 1.0 };
            let sv2 = self.cfg.gyro_noise_rad_s * self.cfg.gyro_noise_rad_s;
            self.last_gyro_rate_rad_s = Some(match self.last_gyro_rate_rad_s {
                Some((avg, var)) => (
                    avg + (w - avg) * a,
                    (1.0 - a) * (1.0 - a) * var + a * a * sv2,
                ),
                None => (w, sv2),
            });
        }
    }

    /// Advance by `dt_s` without a gyro, the body rate a filter state: `accel_body_rad_s2` is
    /// the body's angular acceleration over the step as the caller's dynamics model predicts
    /// it (Euler's equations with the known torques; zero for a body left alone at a low
    /// rate). The first such step after gyro steps starts the rate state (module doc). A
    /// non-finite acceleration counts as zero; a non-finite or non-positive `dt_s` does
    /// nothing; uninitialised, nothing happens.
    pub fn propagate_without_gyro(&mut self, accel_body_rad_s2: &Vector3<f64>, dt_s: f64) {
        let Some(q) = self.q_eci_from_body else {
            return;
        };
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return;
        }
        let a = if accel_body_rad_s2.iter().all(|x| x.is_finite()) {
            *accel_body_rad_s2
        } else {
            Vector3::zeros()
        };
        let mut p = self.p;
        let w0 = match self.rate_rad_s {
            Some(w) => w,
            None => {
                // Enter gyro-less: freeze the bias block, start the rate (module doc).
                self.frozen_bias_cov = p.fixed_view::<3, 3>(3, 3).into_owned();
                self.gyroless_s = 0.0;
                match self.last_gyro_rate_rad_s {
                    Some((w, var)) => {
                        let pww = self.frozen_bias_cov + Matrix3::from_diagonal_element(var);
                        p.fixed_view_mut::<3, 3>(3, 3).copy_from(&pww);
                        let c = -p.fixed_view::<3, 3>(0, 3).into_owned();
                        p.fixed_view_mut::<3, 3>(0, 3).copy_from(&c);
                        p.fixed_view_mut::<3, 3>(3, 0).copy_from(&c.transpose());
                        w
                    }
                    None => {
                        let s = self.cfg.no_gyro_rate_sigma_rad_s;
                        p.fixed_view_mut::<3, 3>(3, 3)
                            .copy_from(&Matrix3::from_diagonal_element(s * s));
                        p.fixed_view_mut::<3, 3>(0, 3).fill(0.0);
                        p.fixed_view_mut::<3, 3>(3, 0).fill(0.0);
                        Vector3::zeros()
                    }
                }
            }
        };
        let w_mid = w0 + a * (dt_s / 2.0);
        let (phi11, phi12) = transition_blocks(&w_mid, dt_s);
        let sa2 = self.cfg.no_gyro_accel_sigma_rad_s2 * self.cfg.no_gyro_accel_sigma_rad_s2;
        let q11 = sa2 * dt_s * dt_s * dt_s / 3.0;
        let q12 = sa2 * dt_s * dt_s / 2.0;
        let q22 = sa2 * dt_s;
        let qd = block_noise(q11, q12, q22);
        let q_new = q * UnitQuaternion::from_scaled_axis(w_mid * dt_s);
        let w_new = w0 + a * dt_s;
        let p_new = transition_cov(&phi11, &(-phi12), &p) + qd;
        if self.commit_rate(q_new, w_new, p_new) {
            self.gyroless_s += dt_s;
        }
    }

    /// Fuse one unit-vector measurement: `meas_body` (body frame) of the direction
    /// `ref_eci` (ECI), 1-sigma `sigma_rad` per axis. Both are unit-normalised. Returns
    /// `false`, state unchanged, when uninitialised, on a zero or non-finite vector or a
    /// `sigma_rad` outside `(0, pi]`, or when the innovation fails the gate.
    pub fn update_vector(
        &mut self,
        meas_body: &Vector3<f64>,
        ref_eci: &Vector3<f64>,
        sigma_rad: f64,
    ) -> bool {
        let Some(q) = self.q_eci_from_body else {
            return false;
        };
        if !(sigma_rad.is_finite() && sigma_rad > 0.0 && sigma_rad <= PI) {
            return false;
        }
        let (Some(m_b), Some(r_eci)) = (unit(meas_body), unit(ref_eci)) else {
            return false;
        };
        let r_b = q.inverse_transform_vector(&r_eci);
        let y = m_b - r_b;
        let h = r_b.cross_matrix();
        let r_var = sigma_rad * sigma_rad;
        // P H^T = P[:, 0..3] h^T (H's bias columns are zero).
        let p_ht: SMatrix<f64, 6, 3> = self.p.fixed_view::<6, 3>(0, 0) * h.transpose();
        let s = h * p_ht.fixed_view::<3, 3>(0, 0) + Matrix3::from_diagonal_element(r_var);
        let s = (s + s.transpose()) * 0.5;
        let Some(s_inv) = spd_inverse3(&s) else {
            return false;
        };
        let d2 = y.dot(&(s_inv * y));
        if !d2.is_finite() {
            return false;
        }
        self.last_nis = Some(d2);
        if d2 > self.cfg.gate_sigma * self.cfg.gate_sigma {
            self.note_rejection();
            return false;
        }
        let k: SMatrix<f64, 6, 3> = p_ht * s_inv;
        let dx = k * y;
        let p_new = joseph(&self.p, &k, &(k * h), r_var);
        let dtheta = Vector3::new(dx[0], dx[1], dx[2]);
        let d2nd = Vector3::new(dx[3], dx[4], dx[5]);
        let q_new = q * UnitQuaternion::from_scaled_axis(dtheta);
        let ok = match self.rate_rad_s {
            Some(w) => self.commit_rate(q_new, w + d2nd, p_new),
            None => self.commit(q_new, self.bias_rad_s + d2nd, p_new),
        };
        if ok {
            self.consecutive_rejections = 0;
            self.accepted_updates = self.accepted_updates.saturating_add(1);
        }
        ok
    }

    /// The attitude estimate `q_eci_from_body`; `None` until initialised.
    pub fn attitude(&self) -> Option<UnitQuaternion<f64>> {
        self.q_eci_from_body
    }

    /// The gyro bias estimate, body frame, rad/s.
    pub fn gyro_bias_rad_s(&self) -> Vector3<f64> {
        self.bias_rad_s
    }

    /// The body rate estimate for a gyro sample: the sample minus the bias estimate, rad/s.
    pub fn rate_body_rad_s(&self, gyro_body_rad_s: &Vector3<f64>) -> Vector3<f64> {
        gyro_body_rad_s - self.bias_rad_s
    }

    /// The gyro-less body rate state, rad/s; `None` with a gyro (or before the first
    /// gyro-less step).
    pub fn rate_state_rad_s(&self) -> Option<Vector3<f64>> {
        self.rate_rad_s
    }

    /// Whether the last propagation was without a gyro (the rate is a filter state).
    pub fn is_gyroless(&self) -> bool {
        self.rate_rad_s.is_some()
    }

    /// Attitude 1-sigma about the worst axis: the square root of the largest eigenvalue of
    /// the attitude block of the covariance, rad; `pi` (nothing known) until initialised.
    pub fn attitude_sigma_rad(&self) -> f64 {
        if self.q_eci_from_body.is_none() {
            return PI;
        }
        let a: Matrix3<f64> = self.p.fixed_view::<3, 3>(0, 0).into_owned();
        largest_eigenvalue_sym3(&a).max(0.0).sqrt()
    }

    /// The 6x6 error-state covariance, attitude (rad^2) then bias ((rad/s)^2), or the body
    /// rate while gyro-less; the init covariance while uninitialised.
    pub fn covariance(&self) -> &Matrix6<f64> {
        &self.p
    }

    /// Gate rejections since the last accepted update (or initialisation).
    pub fn consecutive_rejections(&self) -> u32 {
        self.consecutive_rejections
    }

    /// Gate rejections since creation.
    pub fn rejected_updates(&self) -> u64 {
        self.rejected_updates
    }

    /// Accepted vector updates since creation.
    pub fn accepted_updates(&self) -> u64 {
        self.accepted_updates
    }

    /// The normalised innovation squared `y^T S^-1 y` of the last vector update that got as
    /// far as the gate (accepted or rejected); `None` before the first one or after a reset.
    /// For a consistent filter its mean is about 2 (two effective degrees of freedom).
    pub fn last_nis(&self) -> Option<f64> {
        self.last_nis
    }

    /// Times the attitude covariance was reopened after lost lock, since creation.
    pub fn gate_reopenings(&self) -> u64 {
        self.gate_reopenings
    }

    /// Count a gate rejection; reopen the attitude covariance after too many in a row.
    fn note_rejection(&mut self) {
        self.rejected_updates = self.rejected_updates.saturating_add(1);
        self.consecutive_rejections = self.consecutive_rejections.saturating_add(1);
        let max = self.cfg.max_consecutive_rejections;
        if max > 0 && self.consecutive_rejections >= max {
            let a = self.cfg.init_attitude_sigma_rad * self.cfg.init_attitude_sigma_rad;
            let mut p = self.p;
            p.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&Matrix3::from_diagonal_element(a));
            p.fixed_view_mut::<3, 3>(0, 3).fill(0.0);
            p.fixed_view_mut::<3, 3>(3, 0).fill(0.0);
            self.p = p;
            self.consecutive_rejections = 0;
            self.gate_reopenings = self.gate_reopenings.saturating_add(1);
        }
    }

    /// Take a step's result if it is sound (normalised, symmetrised, all finite, covariance
    /// diagonal non-negative); otherwise reset to uninitialised. Returns whether it was taken.
    fn commit(&mut self, q: UnitQuaternion<f64>, b: Vector3<f64>, p: Matrix6<f64>) -> bool {
        let q = UnitQuaternion::new_normalize(q.into_inner());
        let p = (p + p.transpose()) * 0.5;
        // Over the storage as slices: nalgebra's matrix iterator was a tenth of the FC's
        // estimation time here.
        let sound = q.coords.as_slice().iter().all(|x| x.is_finite())
            && b.as_slice().iter().all(|x| x.is_finite())
            && p.as_slice().iter().all(|x| x.is_finite())
            && (0..6).all(|i| p[(i, i)] >= 0.0);
        if sound {
            self.q_eci_from_body = Some(q);
            self.bias_rad_s = b;
            self.p = p;
        } else {
            self.reset();
        }
        sound
    }

    /// [`Mekf::commit`] for a gyro-less step: the second block is the rate state `w`, the
    /// frozen bias is kept.
    fn commit_rate(&mut self, q: UnitQuaternion<f64>, w: Vector3<f64>, p: Matrix6<f64>) -> bool {
        let ok = w.iter().all(|x| x.is_finite()) && self.commit(q, self.bias_rad_s, p);
        if ok {
            self.rate_rad_s = Some(w);
        } else {
            self.reset();
        }
        ok
    }
}

/// The Joseph form `(I - KH) P (I - KH)^T + K R K^T` of an update whose H has zero bias
/// columns (`KH = [kh 0]`, `kh = K h`) and `R = r_var I`, block by block:
/// `(I - KH) P = P - kh P[0..3, :]`, then `A (I - KH)^T = A - A[:, 0..3] kh^T`: half the
/// multiplications of the two full 6x6 products.
fn joseph(
    p: &Matrix6<f64>,
    k: &SMatrix<f64, 6, 3>,
    kh: &SMatrix<f64, 6, 3>,
    r_var: f64,
) -> Matrix6<f64> {
    let a: Matrix6<f64> = p - kh * p.fixed_rows::<3>(0);
    a - a.fixed_columns::<3>(0) * kh.transpose() + k * k.transpose() * r_var
}

/// `Phi P Phi^T` for the transition `Phi = [[a, b], [0, I]]` (3x3 blocks), block by block:
/// with `M = [a b] P`, the top row is `M1 = a P11 + b P21`, `M2 = a P12 + b P22`, and the
/// result `[[M1 a^T + M2 b^T, M2], [P21 a^T + P22 b^T, P22]]`: half the multiplications of
/// the two full 6x6 products.
fn transition_cov(a: &Matrix3<f64>, b: &Matrix3<f64>, p: &Matrix6<f64>) -> Matrix6<f64> {
    let p11 = p.fixed_view::<3, 3>(0, 0);
    let p12 = p.fixed_view::<3, 3>(0, 3);
    let p21 = p.fixed_view::<3, 3>(3, 0);
    let p22 = p.fixed_view::<3, 3>(3, 3);
    let m1: Matrix3<f64> = a * p11 + b * p21;
    let m2: Matrix3<f64> = a * p12 + b * p22;
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(m1 * a.transpose() + m2 * b.transpose()));
    out.fixed_view_mut::<3, 3>(0, 3).copy_from(&m2);
    out.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(p21 * a.transpose() + p22 * b.transpose()));
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&p22);
    out
}

/// The inverse of a symmetric 3x3 matrix by its cofactors, `None` unless it is positive
/// definite (Sylvester's criterion: the leading minors positive) with a finite inverse: what
/// a Cholesky decomposition and its inverse give, without the decomposition.
fn spd_inverse3(s: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let (a, b, c) = (s[(0, 0)], s[(0, 1)], s[(0, 2)]);
    let (d, e, f) = (s[(1, 1)], s[(1, 2)], s[(2, 2)]);
    let minor2 = a * d - b * b;
    let (c00, c01, c02) = (d * f - e * e, c * e - b * f, b * e - c * d);
    let det = a * c00 + b * c01 + c * c02;
    if !(a > 0.0 && minor2 > 0.0 && det > 0.0) {
        return None;
    }
    let (c11, c12) = (a * f - c * c, b * c - a * e);
    let inv = Matrix3::new(c00, c01, c02, c01, c11, c12, c02, c12, minor2) / det;
    inv.as_slice().iter().all(|x| x.is_finite()).then_some(inv)
}

/// The 6x6 discrete process noise with the same 3x3 blocks on each axis: `q11 I` (attitude),
/// `q12 I` (cross terms, both off-diagonal blocks) and `q22 I` (second state).
fn block_noise(q11: f64, q12: f64, q22: f64) -> Matrix6<f64> {
    let mut qd = Matrix6::zeros();
    for i in 0..3 {
        qd[(i, i)] = q11;
        qd[(i, i + 3)] = q12;
        qd[(i + 3, i)] = q12;
        qd[(i + 3, i + 3)] = q22;
    }
    qd
}

/// The attitude rows of the error-state transition matrix over `dt_s` at the constant body
/// rate `w`: `(Phi11, Phi12) = (exp(-[w x] dt), -integral_0^dt exp(-[w x] s) ds)`.
fn transition_blocks(w: &Vector3<f64>, dt_s: f64) -> (Matrix3<f64>, Matrix3<f64>) {
    let wx = w.cross_matrix();
    let wx2 = wx * wx;
    let wn = w.norm();
    let th = wn * dt_s;
    // exp(-[w x] s) = I - sin(|w| s)/|w| [w x] + (1 - cos(|w| s))/|w|^2 [w x]^2.
    let (a, b, c) = if th < SMALL_ANGLE_RAD {
        let t2 = th * th;
        let t4 = t2 * t2;
        (
            dt_s * (1.0 - t2 / 6.0 + t4 / 120.0),
            dt_s * dt_s * (0.5 - t2 / 24.0 + t4 / 720.0),
            dt_s * dt_s * dt_s * (1.0 / 6.0 - t2 / 120.0 + t4 / 5040.0),
        )
    } else {
        let (s, co) = th.sin_cos();
        (s / wn, (1.0 - co) / (wn * wn), (th - s) / (wn * wn * wn))
    };
    let i = Matrix3::identity();
    let phi11 = i - wx * a + wx2 * b;
    let phi12 = -(i * dt_s - wx * b + wx2 * c);
    (phi11, phi12)
}

/// `v` as a unit vector; `None` when zero, subnormal or not finite. Scaled by its largest
/// component first, so huge and tiny vectors normalise without overflow or underflow.
fn unit(v: &Vector3<f64>) -> Option<Vector3<f64>> {
    if !v.iter().all(|x| x.is_finite()) {
        return None;
    }
    let m = v.amax();
    if m < f64::MIN_POSITIVE {
        return None;
    }
    let s = v / m;
    Some(s / s.norm())
}

/// The largest eigenvalue of a symmetric 3x3 matrix, in closed form (the trigonometric
/// solution of the characteristic cubic, Smith, "Eigenvalues of a symmetric 3x3 matrix",
/// Comm. ACM 4(4), 1961): no iteration, no allocation.
fn largest_eigenvalue_sym3(a: &Matrix3<f64>) -> f64 {
    let p1 = a[(0, 1)] * a[(0, 1)] + a[(0, 2)] * a[(0, 2)] + a[(1, 2)] * a[(1, 2)];
    if p1 == 0.0 {
        return a[(0, 0)].max(a[(1, 1)]).max(a[(2, 2)]);
    }
    let q = a.trace() / 3.0;
    let d = a.diagonal().add_scalar(-q);
    let p2 = d.norm_squared() + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    let b = (a - Matrix3::from_diagonal_element(q)) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    q + 2.0 * p * phi.cos()
}

/// TRIAD: the attitude `q_eci_from_body` from two vector pairs, each a body-frame
/// measurement and its ECI reference. The primary pair is matched exactly; the secondary
/// fixes the rotation about it. `None` when a vector is zero or not finite, or when either
/// pair's two vectors are within 1 deg of parallel or antiparallel.
pub fn triad(
    primary_body: &Vector3<f64>,
    primary_eci: &Vector3<f64>,
    secondary_body: &Vector3<f64>,
    secondary_eci: &Vector3<f64>,
) -> Option<UnitQuaternion<f64>> {
    let min_sin = (1.0 * DEG).sin();
    let frame = |p: &Vector3<f64>, s: &Vector3<f64>| -> Option<Matrix3<f64>> {
        let t1 = unit(p)?;
        let c = t1.cross(&unit(s)?);
        let n = c.norm();
        if n < min_sin {
            return None;
        }
        let t2 = c / n;
        let t3 = t1.cross(&t2);
        Some(Matrix3::from_columns(&[t1, t2, t3]))
    };
    let m_body = frame(primary_body, secondary_body)?;
    let m_eci = frame(primary_eci, secondary_eci)?;
    let r = Rotation3::from_matrix_unchecked(m_eci * m_body.transpose());
    let q = UnitQuaternion::new_normalize(UnitQuaternion::from_rotation_matrix(&r).into_inner());
    q.coords.iter().all(|x| x.is_finite()).then_some(q)
}

snap::fields!(MekfConfig {
    gyro_noise_rad_s,
    gyro_bias_walk_rad_s2,
    no_gyro_rate_sigma_rad_s,
    gyro_rate_smoothing_s,
    no_gyro_accel_sigma_rad_s2,
    init_attitude_sigma_rad,
    init_bias_sigma_rad_s,
    gate_sigma,
    max_consecutive_rejections
});
snap::fields!(Mekf {
    cfg,
    q_eci_from_body,
    bias_rad_s,
    p,
    rate_rad_s,
    frozen_bias_cov,
    gyroless_s,
    last_gyro_rate_rad_s,
    consecutive_rejections,
    rejected_updates,
    accepted_updates,
    gate_reopenings,
    last_nis
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Numbers uniform in [-0.5, 0.5) from `seed` (xorshift64).
    fn uniform(mut x: u64) -> impl FnMut() -> f64 {
        move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// The block product is the full `Phi P Phi^T` (to 1e-13 relative), symmetric P or not.
    #[test]
    fn the_block_transition_is_the_full_product() {
        let mut next = uniform(0x9E37_79B9_7F4A_7C15);
        for _ in 0..500 {
            let a = Matrix3::from_fn(|_, _| next());
            let b = Matrix3::from_fn(|_, _| next());
            let p = Matrix6::from_fn(|_, _| next());
            let mut phi = Matrix6::identity();
            phi.fixed_view_mut::<3, 3>(0, 0).copy_from(&a);
            phi.fixed_view_mut::<3, 3>(0, 3).copy_from(&b);
            let want = phi * p * phi.transpose();
            let got = transition_cov(&a, &b, &p);
            assert!((got - want).norm() <= 1e-13 * want.norm(), "{want} {got}");
        }
    }

    /// The block Joseph form is the full one (to 1e-13 relative) for any gain, not only
    /// the optimal one (for which most of its terms cancel).
    #[test]
    fn the_block_joseph_form_is_the_full_one() {
        let mut next = uniform(0x5851_F42D_4C95_7F2D);
        for _ in 0..500 {
            let p = Matrix6::from_fn(|_, _| next());
            let k = SMatrix::<f64, 6, 3>::from_fn(|_, _| next());
            let h = Matrix3::from_fn(|_, _| next());
            let r_var = next() + 1.0;
            let mut h_full = SMatrix::<f64, 3, 6>::zeros();
            h_full.fixed_view_mut::<3, 3>(0, 0).copy_from(&h);
            let i_kh = Matrix6::identity() - k * h_full;
            let want = i_kh * p * i_kh.transpose() + k * k.transpose() * r_var;
            let got = joseph(&p, &k, &(k * h), r_var);
            assert!((got - want).norm() <= 1e-13 * want.norm(), "{want} {got}");
        }
    }

    /// The cofactor inverse agrees with Cholesky's for positive definite matrices (to 1e-9
    /// relative) and refuses what Cholesky refuses: indefinite (with a positive determinant
    /// too), semidefinite, non-finite.
    #[test]
    fn the_spd_inverse_is_choleskys_without_the_decomposition() {
        let mut next = uniform(0x2545_F491_4F6C_DD1D);
        for k in 0..2000 {
            let m = Matrix3::from_fn(|_, _| next());
            // Positive definite, with condition numbers up to about 1e6.
            let scale = 10f64.powi(k % 7 - 3);
            let s = (m * m.transpose() + Matrix3::identity() * 1e-6) * scale;
            let want = s.cholesky().unwrap().inverse();
            let got = spd_inverse3(&s).unwrap();
            assert!((got - want).norm() <= 1e-9 * want.norm(), "{s}");
        }
        let refused = [
            Matrix3::new(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::new(1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::from_diagonal_element(-1.0),
            // Indefinite with det > 0: the leading minors refuse them.
            Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)),
            Matrix3::from_diagonal(&Vector3::new(-1.0, -1.0, 1.0)),
            Matrix3::zeros(),
            Matrix3::from_diagonal_element(f64::NAN),
            Matrix3::new(1.0, 0.0, 0.0, 0.0, f64::INFINITY, 0.0, 0.0, 0.0, 1.0),
        ];
        for s in refused {
            assert!(
                s.cholesky().is_none() || !s.iter().all(|x| x.is_finite()),
                "{s}"
            );
            assert_eq!(spd_inverse3(&s), None, "{s}");
        }
    }

    /// Phi from many tiny first-order steps, for comparison with the closed form.
    fn phi_numeric(w: &Vector3<f64>, dt: f64) -> Matrix6<f64> {
        let n = 20_000;
        let h = dt / n as f64;
        let mut f = Matrix6::zeros();
        f.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-w.cross_matrix()));
        f.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-Matrix3::<f64>::identity()));
        // Fourth-order Taylor step: I + F h + (F h)^2 / 2 + (F h)^3 / 6 + (F h)^4 / 24.
        let fh = f * h;
        let fh2 = fh * fh;
        let step = Matrix6::identity() + fh + fh2 * 0.5 + fh2 * fh / 6.0 + fh2 * fh2 / 24.0;
        let mut phi = Matrix6::identity();
        for _ in 0..n {
            phi = step * phi;
        }
        phi
    }

    #[test]
    fn transition_matches_numeric_exponential_1e9_both_branches() {
        for (w, dt) in [
            (Vector3::new(0.3, -0.2, 0.5), 0.1), // |w| dt = 0.06: closed form
            (Vector3::new(2.0, 1.0, -3.0), 0.5), // large angle
            (Vector3::new(1e-3, 2e-3, -1e-3), 0.1), // series branch
            (Vector3::zeros(), 0.1),
        ] {
            let (p11, p12) = transition_blocks(&w, dt);
            let num = phi_numeric(&w, dt);
            let e11 = (p11 - num.fixed_view::<3, 3>(0, 0)).amax();
            let e12 = (p12 - num.fixed_view::<3, 3>(0, 3)).amax();
            assert!(e11 < 1e-9 && e12 < 1e-9, "w {w:?}: {e11:e} {e12:e}");
        }
    }

    #[test]
    fn series_and_closed_form_agree_at_the_switch_1e12() {
        // The closed form's cancellation costs about 1e-14 here; a wrong series term costs
        // far more (a wrong theta^2 term shifts the blocks by about 1e-7).
        let dir = Vector3::new(0.6, -0.48, 0.64);
        let dt = 0.1;
        let below = dir * (SMALL_ANGLE_RAD * (1.0 - 1e-12) / dt);
        let above = dir * (SMALL_ANGLE_RAD * (1.0 + 1e-12) / dt);
        let (a11, a12) = transition_blocks(&below, dt);
        let (b11, b12) = transition_blocks(&above, dt);
        assert!((a11 - b11).amax() < 1e-12, "{:e}", (a11 - b11).amax());
        assert!((a12 - b12).amax() < 1e-12, "{:e}", (a12 - b12).amax());
    }

    #[test]
    fn largest_eigenvalue_matches_nalgebra_1e12() {
        let mats = [
            Matrix3::new(4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 1.0),
            Matrix3::from_diagonal(&Vector3::new(1.0, 5.0, 2.0)),
            Matrix3::new(1e-6, 2e-7, 0.0, 2e-7, 3e-6, -1e-7, 0.0, -1e-7, 2e-6),
            Matrix3::from_diagonal_element(2.5),
        ];
        for m in mats {
            let ev = m.symmetric_eigenvalues().max();
            let got = largest_eigenvalue_sym3(&m);
            assert!(
                (got - ev).abs() <= 1e-12 * ev.abs().max(1e-300),
                "{got} vs {ev}"
            );
        }
    }

    #[test]
    fn unit_handles_huge_tiny_zero_and_nan() {
        let u = unit(&Vector3::new(1e300, 1e300, 0.0)).unwrap();
        assert!((u.norm() - 1.0).abs() < 1e-15);
        let u = unit(&Vector3::new(1e-300, 0.0, -1e-300)).unwrap();
        assert!((u.norm() - 1.0).abs() < 1e-15);
        assert!(unit(&Vector3::zeros()).is_none());
        assert!(unit(&Vector3::new(f64::NAN, 1.0, 0.0)).is_none());
        assert!(unit(&Vector3::new(f64::INFINITY, 1.0, 0.0)).is_none());
        assert!(unit(&Vector3::new(1e-310, 0.0, 0.0)).is_none());
    }

    #[test]
    fn sanitised_replaces_bad_figures() {
        let c = MekfConfig {
            gyro_noise_rad_s: f64::NAN,
            init_attitude_sigma_rad: -1.0,
            ..MekfConfig::default()
        }
        .sanitised();
        assert_eq!(c, MekfConfig::default());
    }
}
