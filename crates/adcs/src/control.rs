//! ADCS control laws: B-dot detumbling, quaternion feedback on the reaction wheels, wheel
//! torque allocation and magnetic momentum desaturation.
//!
//! Pure, deterministic functions of their arguments: no state, no clock, no allocation, no
//! panic; non-finite input gives a zero command. Units and frames as the house style: body
//! is the BCF, fields in nT, dipoles in A m^2, torques in N m, momenta in N m s.
//!
//! # Laws
//! - **B-dot** ([`bdot_dipole_am2`]): `m = -k dB/dt / |B|^2`, with `dB/dt` the backward
//!   difference of two magnetometer readings. For a field fixed in ECI,
//!   `dB/dt (body) = B x w`, so the torque `m x B = -k w_perp` (`w_perp` the rate
//!   perpendicular to B): a rate damper whose gain `k` (N m s) does not depend on the field
//!   strength until the dipole saturates. Each axis is clamped separately; every component
//!   keeps the sign of `-dB/dt`, so `m . dB/dt <= 0` and the law stays dissipative
//!   (`d(energy)/dt = w . (m x B) = m . dB/dt`).
//! - **Attitude** ([`attitude_torque_nm`]): quaternion feedback with a slew rate limit (Wie
//!   and Lu, "Feedback control logic for spacecraft eigenaxis rotations under slew rate and
//!   control constraints", JGCD 18(6), 1995). With the error rotation `theta` (the rotation
//!   vector of `q_target^-1 q_est`, shortest way: sign-safe), the relative rate command is
//!   `w_c = sat(-(kp/kd) theta, max_rate)` (the vector scaled, so the slew stays about the
//!   eigenaxis), and the torque is
//!   `tau = I (kd (w_t + w_c - w) + a_t + w_t x w) + w x (I w + h_wheels)`, with `w_t` and
//!   `a_t` the target rate and angular acceleration in body axes. Unsaturated this is
//!   `I (-kp theta - kd (w - w_t))` plus feed-forward: every axis a second-order loop with
//!   natural frequency `wn` and damping ratio `zeta` (`kp = wn^2`, `kd = 2 zeta wn`).
//!   `w x H` cancels the gyroscopic torque and `I (a_t + w_t x w)` is the derivative of the
//!   target rate seen from the body (without `a_t`, an Earth target near the top of a pass
//!   lags by `|a_t| / kp`, 0.15 deg).
//! - **Allocation** ([`allocate_wheel_torques`]): the body feels `-sum(tau_i a_i)` for motor
//!   torques `tau_i` on wheels with axes `a_i` (truth.rs: a positive motor torque spins the
//!   wheel up along its axis). The minimum-norm solution over the healthy wheels is
//!   `tau = -pinv(A) t` with `A` the 3 x 4 axis matrix, failed wheels' columns zeroed; the
//!   pseudo-inverse is the SVD's, so with fewer than three healthy non-coplanar wheels the
//!   result is the least-squares best effort: the requested torque's projection on the
//!   span of the healthy axes, the rest is simply missing. If a wheel would exceed its
//!   torque limit all commands are scaled by the same factor (the direction is kept).
//! - **Desaturation** ([`desat_dipole_am2`]): `m = k (h x B) / |B|^2`, so that the external
//!   torque `m x B = -k h_perp` removes the wheel momentum perpendicular to the field (the
//!   attitude loop holds the attitude, so the wheels give it up). Only the momentum beyond
//!   a deadband is dumped (`h (1 - deadband / |h|)`), which leaves the magnetorquers off
//!   while the wheels are nearly empty. The dipole is scaled uniformly to the limit, so the
//!   torque keeps its direction. The magnetorquer torque is an external disturbance to
//!   the attitude loop: subtract it from the wheel torque request ([`mtq_torque_body_nm`])
//!   so that the wheels cancel it rather than the pointing error.
//! - **Null motion** ([`wheel_commands_nm`], optional): four pyramid wheels have a
//!   one-dimensional null space (`sum(nu_i a_i) = 0`); a slow null-space torque keeps the
//!   wheel speeds' null component at [`ControlConfig::null_speed_rad_s`], away from zero
//!   crossings, without torquing the body. It also feeds the wheels' viscous friction
//!   forward.
//!
//! # Gains ([`ControlConfig::for_body`], `Default` = the default 6U body of
//! [`BodyConfig::default`] on the default scenario's orbit)
//! - B-dot: `k = 2 n (1 + sin xi_m) J_min` (Avanzini and Giulietti, "Magnetic detumbling of a
//!   rigid spacecraft", JGCD 35(4), 2012: the gain of the fastest linear convergence), with
//!   `xi_m`, the orbit's inclination to the geomagnetic equator, taken as 90 deg for the
//!   twin's sun-synchronous orbits: `k = 4 n J_min = 4 x 1.10e-3 x 0.05 = 2.2e-4 N m s`.
//! - Rate limit: a third of the wheels' momentum envelope (the radius of the largest sphere
//!   inside the momentum zonotope: 1.633 x 6.28 mN m s = 10.3 mN m s for the pyramid) over
//!   the largest principal inertia: `10.3e-3 / 3 / 0.13 = 0.026 rad/s` (1.5 deg/s). The
//!   other two thirds are margin for stored momentum.
//! - `kd = tau_max / h_max` of a wheel (1 / 3.14 s: the rate loop's time constant is the time
//!   a wheel needs to spin from rest to full speed at full torque), so that the rate loop
//!   asks at most a third of the torque envelope (3.27 mN m) when the rate error is the rate
//!   limit, whatever the inertia; `zeta = 0.707`, `wn = kd / (2 zeta) = 0.225 rad/s`,
//!   `kp = wn^2 = 0.051 s^-2`. The switch from the rate-limited slew to the proportional
//!   approach is at `max_rate kd / kp = 9.5 deg`. A constant 1 uN m disturbance about the
//!   smallest inertia (0.05) leaves `1e-6 / (0.05 kp) = 0.02 deg`.
//! - Desaturation: `k = 4e-6 N m / 1.03e-3 N m s = 3.9e-3 1/s` (time constant 4.3 min):
//!   the dump torque reaches the magnetorquers' typical authority (0.2 A m^2 x 20 uT =
//!   4 uN m) when the stored momentum is a tenth of the envelope. Deadband: 5 % of the
//!   envelope (0.51 mN m s).
//! - Null motion: bias 600 rpm (a tenth of the speed limit), gain 0.02 1/s, torque at most
//!   5 % of the wheel limit.

use nalgebra::{Matrix3, Matrix3x4, Matrix4x3, UnitQuaternion, Vector3, Vector4};

use crate::guidance::GuidanceTarget;
use crate::truth::{BodyConfig, WheelConfig};

/// Mean motion of the default scenario's orbit, rad/s: 15.145 rev/day (TLE 99903, line 2).
pub const DEFAULT_MEAN_MOTION_RAD_S: f64 = 15.145 * core::f64::consts::TAU / 86_400.0;

/// Field strength the desaturation gain is designed for, T: 20 uT, about the weakest field on
/// a 500 km polar orbit (IGRF-14; 20-50 uT along the default orbit).
const DESAT_DESIGN_FIELD_T: f64 = 20.0e-6;

/// Control gains and limits.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlConfig {
    /// B-dot gain, N m s (the damping torque per unit rate perpendicular to the field).
    pub bdot_gain: f64,
    /// Attitude loop natural frequency, rad/s.
    pub natural_freq_rad_s: f64,
    /// Attitude loop damping ratio.
    pub damping_ratio: f64,
    /// Slew rate limit (relative to the target), rad/s.
    pub max_rate_rad_s: f64,
    /// Desaturation gain, 1/s.
    pub desat_gain: f64,
    /// Wheel momentum left alone by desaturation, N m s.
    pub desat_deadband_nms: f64,
    /// Null-motion gain, 1/s (0 switches null motion off).
    pub null_motion_gain: f64,
    /// Target null-space speed of each wheel, rad/s.
    pub null_speed_rad_s: f64,
    /// Null-motion torque limit as a fraction of each wheel's torque limit.
    pub null_max_torque_fraction: f64,
}

impl Default for ControlConfig {
    /// [`ControlConfig::for_body`] of [`BodyConfig::default`] on the default scenario's
    /// orbit (see the module doc for the numbers).
    fn default() -> Self {
        ControlConfig::for_body(&BodyConfig::default(), DEFAULT_MEAN_MOTION_RAD_S)
    }
}

impl ControlConfig {
    /// Derive the gains from a body and its orbit's mean motion (rad/s), as the module doc.
    pub fn for_body(body: &BodyConfig, mean_motion_rad_s: f64) -> Self {
        let eig = body.inertia_kg_m2.symmetric_eigenvalues();
        let (j_min, j_max) = (eig.min(), eig.max());
        let h_max = body
            .wheels
            .iter()
            .map(|w| w.inertia_kg_m2 * w.max_speed_rad_s);
        let h_env = envelope_radius(&body.wheels, |w| w.inertia_kg_m2 * w.max_speed_rad_s);
        let tau_over_h = body
            .wheels
            .iter()
            .zip(h_max)
            .map(|(w, h)| w.max_torque_nm / h)
            .fold(f64::INFINITY, f64::min);
        let damping_ratio = core::f64::consts::FRAC_1_SQRT_2;
        let speed_max = body
            .wheels
            .iter()
            .map(|w| w.max_speed_rad_s)
            .fold(f64::INFINITY, f64::min);
        ControlConfig {
            bdot_gain: 4.0 * mean_motion_rad_s * j_min,
            natural_freq_rad_s: tau_over_h / (2.0 * damping_ratio),
            damping_ratio,
            max_rate_rad_s: h_env / 3.0 / j_max,
            desat_gain: DESAT_DESIGN_FIELD_T * body.mtq_max_dipole_am2 / (0.1 * h_env),
            desat_deadband_nms: 0.05 * h_env,
            null_motion_gain: 0.02,
            null_speed_rad_s: 0.1 * speed_max,
            null_max_torque_fraction: 0.05,
        }
    }

    /// Proportional gain `wn^2`, 1/s^2 (angular acceleration per radian of error).
    pub fn kp(&self) -> f64 {
        self.natural_freq_rad_s * self.natural_freq_rad_s
    }

    /// Derivative gain `2 zeta wn`, 1/s (angular acceleration per rad/s of rate error).
    pub fn kd(&self) -> f64 {
        2.0 * self.damping_ratio * self.natural_freq_rad_s
    }
}

/// Radius of the largest sphere inside the zonotope `sum([-x_i, x_i] a_i)` (momentum or
/// torque envelope of the wheels, `x_i` per wheel): the smallest support value over the
/// zonotope's face normals `a_i x a_j`.
pub fn envelope_radius(wheels: &[WheelConfig; 4], x: impl Fn(&WheelConfig) -> f64) -> f64 {
    let mut r = f64::INFINITY;
    for i in 0..4 {
        for j in i + 1..4 {
            let Some(n) = wheels[i]
                .axis_body
                .cross(&wheels[j].axis_body)
                .try_normalize(1e-12)
            else {
                continue;
            };
            let support: f64 = wheels
                .iter()
                .map(|w| x(w) * w.axis_body.dot(&n).abs())
                .sum();
            r = r.min(support);
        }
    }
    if r.is_finite() { r } else { 0.0 }
}

fn finite3(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// B-dot dipole `m = -k dB/dt / |B|^2` from two successive field readings (body, nT) `dt_s`
/// apart, each axis clamped to `max_dipole_am2`.
pub fn bdot_dipole_am2(
    b_body_nt: &Vector3<f64>,
    b_prev_body_nt: &Vector3<f64>,
    dt_s: f64,
    cfg: &ControlConfig,
    max_dipole_am2: f64,
) -> Vector3<f64> {
    let b2 = b_body_nt.norm_squared();
    if !(dt_s > 0.0 && b2 > 1.0 && finite3(b_body_nt) && finite3(b_prev_body_nt)) {
        return Vector3::zeros();
    }
    let b_dot_nt_s = (b_body_nt - b_prev_body_nt) / dt_s;
    // m [A m^2] = -k dB/dt [T/s] / |B|^2 [T^2] = -k (dB/dt [nT/s] / |B|^2 [nT^2]) 1e9.
    let m = -b_dot_nt_s * (cfg.bdot_gain * 1e9 / b2);
    clamp_each(&m, max_dipole_am2)
}

fn clamp_each(m: &Vector3<f64>, max: f64) -> Vector3<f64> {
    let max = if max.is_finite() { max.abs() } else { 0.0 };
    let out = m.map(|c| c.clamp(-max, max));
    if finite3(&out) { out } else { Vector3::zeros() }
}

/// The attitude control torque on the body, N m (see the module doc): quaternion feedback
/// with rate limit and gyroscopic compensation, from the estimated attitude and rate, the
/// target, the wheel momentum (body) and the inertia.
pub fn attitude_torque_nm(
    q_est: &UnitQuaternion<f64>,
    w_est_body_rad_s: &Vector3<f64>,
    target: &GuidanceTarget,
    h_wheels_body_nms: &Vector3<f64>,
    inertia_kg_m2: &Matrix3<f64>,
    cfg: &ControlConfig,
) -> Vector3<f64> {
    let w = *w_est_body_rad_s;
    // Target from body; scaled_axis() takes the shortest way whatever the signs of the
    // two quaternions.
    let q_err = target.q_eci_from_body.inverse() * q_est;
    let theta = q_err.scaled_axis();
    let w_t = q_err.inverse_transform_vector(&target.w_body_rad_s);
    let a_t = q_err.inverse_transform_vector(&target.dw_body_rad_s2);
    let (kp, kd) = (cfg.kp(), cfg.kd());
    let mut w_c = if kd > 0.0 {
        -theta * (kp / kd)
    } else {
        Vector3::zeros()
    };
    let n = w_c.norm();
    if n > cfg.max_rate_rad_s {
        w_c *= cfg.max_rate_rad_s / n;
    }
    let w_dot = (w_t + w_c - w) * kd + a_t + w_t.cross(&w);
    let h = inertia_kg_m2 * w + h_wheels_body_nms;
    let tau = inertia_kg_m2 * w_dot + w.cross(&h);
    if finite3(&tau) { tau } else { Vector3::zeros() }
}

/// Null vector of the axis matrix (columns of failed wheels zeroed): the generalised cross
/// product `nu_k = (-1)^k det(A without column k)`, unit; `None` when the healthy axes do
/// not span three dimensions with a one-dimensional null space.
fn null_vector(a: &Matrix3x4<f64>) -> Option<Vector4<f64>> {
    let minor = |k: usize| {
        let cols: [usize; 3] = match k {
            0 => [1, 2, 3],
            1 => [0, 2, 3],
            2 => [0, 1, 3],
            _ => [0, 1, 2],
        };
        Matrix3::from_columns(&[a.column(cols[0]), a.column(cols[1]), a.column(cols[2])])
            .determinant()
    };
    let nu = Vector4::new(minor(0), -minor(1), minor(2), -minor(3));
    nu.try_normalize(1e-9)
}

/// The axis matrix with failed wheels' columns zeroed.
fn axis_matrix(wheels: &[WheelConfig; 4], healthy: [bool; 4]) -> Matrix3x4<f64> {
    Matrix3x4::from_fn(|r, c| {
        if healthy[c] {
            wheels[c].axis_body[r]
        } else {
            0.0
        }
    })
}

/// The minimum-norm pseudo-inverse of the axis matrix, singular values below 1e-9 (axes
/// coplanar to 1e-9 rad) counting as zero. At full rank (three healthy non-coplanar wheels
/// or more: every tick of a healthy ADCS) it is `A^T (A A^T)^-1`, a 3x3 inverse; only near a
/// rank loss does it take the SVD.
fn pseudo_inverse(a: &Matrix3x4<f64>) -> Option<Matrix4x3<f64>> {
    let aat = a * a.transpose();
    let (tr, det) = (aat.trace(), aat.determinant());
    // The smallest eigenvalue of A A^T is at least 4 det / tr^2 (the other two multiply to
    // at most tr^2 / 4): above 1e-12, every singular value is above 1e-6.
    if tr > 0.0 && 4.0 * det / (tr * tr) > 1e-12 {
        if let Some(inv) = aat.try_inverse() {
            return Some(a.transpose() * inv);
        }
    }
    a.pseudo_inverse(1e-9).ok()
}

/// Unscaled minimum-norm motor torques for a body torque (see the module doc).
fn allocate_unscaled(
    torque_body_nm: &Vector3<f64>,
    wheels: &[WheelConfig; 4],
    healthy: [bool; 4],
) -> Vector4<f64> {
    if !finite3(torque_body_nm) || !wheels.iter().all(|w| finite3(&w.axis_body)) {
        return Vector4::zeros();
    }
    let a = axis_matrix(wheels, healthy);
    let Some(pinv) = pseudo_inverse(&a) else {
        return Vector4::zeros();
    };
    let mut tau = -(pinv * torque_body_nm);
    for (t, h) in tau.iter_mut().zip(healthy) {
        if !h {
            *t = 0.0;
        }
    }
    if tau.iter().all(|x| x.is_finite()) {
        tau
    } else {
        Vector4::zeros()
    }
}

/// Scale all commands by one factor so that none exceeds its wheel's torque limit.
fn scale_to_limits(tau: &Vector4<f64>, wheels: &[WheelConfig; 4]) -> [f64; 4] {
    let over = (0..4)
        .map(|i| tau[i].abs() / wheels[i].max_torque_nm.abs())
        .fold(1.0_f64, |a, b| if b.is_nan() { a } else { a.max(b) });
    let out: [f64; 4] = core::array::from_fn(|i| tau[i] / over);
    if out.iter().all(|x| x.is_finite()) {
        out
    } else {
        [0.0; 4]
    }
}

/// Wheel MOTOR torque commands (N m) such that the body feels `torque_body_nm`
/// (`-sum(tau_i a_i)`), minimum norm over the healthy wheels, scaled uniformly to the torque
/// limits; failed wheels get zero. Fewer than three healthy non-coplanar wheels: the
/// least-squares best effort (the request's projection on the healthy axes' span).
pub fn allocate_wheel_torques(
    torque_body_nm: &Vector3<f64>,
    wheels: &[WheelConfig; 4],
    healthy: [bool; 4],
) -> [f64; 4] {
    scale_to_limits(&allocate_unscaled(torque_body_nm, wheels, healthy), wheels)
}

/// Like [`allocate_wheel_torques`], plus the wheels' viscous friction fed forward and the
/// null-motion torque (four healthy wheels only) that drives the speeds' null-space
/// component to `cfg.null_speed_rad_s` per wheel (keeping its sign; positive from zero),
/// all scaled uniformly to the torque limits. The body torque is the same (to friction
/// model accuracy): friction is compensated and the null torque is invisible to the body.
pub fn wheel_commands_nm(
    torque_body_nm: &Vector3<f64>,
    wheels: &[WheelConfig; 4],
    healthy: [bool; 4],
    wheel_speed_rad_s: &[f64; 4],
    cfg: &ControlConfig,
) -> [f64; 4] {
    let mut tau = allocate_unscaled(torque_body_nm, wheels, healthy);
    let speed = Vector4::from_fn(|i, _| {
        let s = wheel_speed_rad_s[i];
        if s.is_finite() && healthy[i] { s } else { 0.0 }
    });
    for i in 0..4 {
        if healthy[i] {
            tau[i] += wheels[i].friction_nm_s_rad * speed[i];
        }
    }
    let all_healthy = healthy.iter().all(|&h| h);
    if let (true, Some(nu)) = (all_healthy, null_vector(&axis_matrix(wheels, healthy))) {
        let c = nu.dot(&speed);
        let nu_min = nu.iter().fold(f64::INFINITY, |a, &b| a.min(b.abs()));
        if nu_min > 1e-6 && cfg.null_motion_gain > 0.0 {
            let c_target = cfg.null_speed_rad_s / nu_min * if c < 0.0 { -1.0 } else { 1.0 };
            // Wheel torque J_i (dOmega_i/dt) with dOmega/dt = gain (c* - c) nu.
            let accel = cfg.null_motion_gain * (c_target - c);
            let mut t_null = Vector4::from_fn(|i, _| wheels[i].inertia_kg_m2 * accel * nu[i]);
            // Equal wheel inertias keep this exactly in the null space; cap its size.
            let over = (0..4)
                .map(|i| t_null[i].abs() / (cfg.null_max_torque_fraction * wheels[i].max_torque_nm))
                .fold(1.0_f64, |a, b| if b.is_nan() { a } else { a.max(b) });
            t_null /= over;
            if t_null.iter().all(|x| x.is_finite()) {
                tau += t_null;
            }
        }
    }
    scale_to_limits(&tau, wheels)
}

/// Desaturation dipole `m = k (h x B) / |B|^2` for the wheel momentum beyond the deadband
/// (body, N m s) in the field `b_body_nt`; scaled uniformly to `max_dipole_am2` per axis.
pub fn desat_dipole_am2(
    h_wheels_body_nms: &Vector3<f64>,
    b_body_nt: &Vector3<f64>,
    cfg: &ControlConfig,
    max_dipole_am2: f64,
) -> Vector3<f64> {
    let b2 = b_body_nt.norm_squared();
    let h_norm = h_wheels_body_nms.norm();
    if !(b2 > 1.0 && finite3(b_body_nt) && finite3(h_wheels_body_nms))
        || h_norm <= cfg.desat_deadband_nms
    {
        return Vector3::zeros();
    }
    let h_excess = h_wheels_body_nms * (1.0 - cfg.desat_deadband_nms.max(0.0) / h_norm);
    // m [A m^2] = k (h x B [T]) / |B [T]|^2 = k (h x B [nT]) / |B [nT]|^2 1e9.
    let m = h_excess.cross(b_body_nt) * (cfg.desat_gain * 1e9 / b2);
    let max = if max_dipole_am2.is_finite() {
        max_dipole_am2.abs()
    } else {
        0.0
    };
    let peak = m.amax();
    let out = if peak > max { m * (max / peak) } else { m };
    if finite3(&out) { out } else { Vector3::zeros() }
}

/// The magnetorquer torque on the body, `m x B`, N m (dipole in A m^2, field in nT): the
/// external torque to take out of the wheel request.
pub fn mtq_torque_body_nm(m_body_am2: &Vector3<f64>, b_body_nt: &Vector3<f64>) -> Vector3<f64> {
    m_body_am2.cross(b_body_nt) * 1e-9
}

snap::fields!(ControlConfig {
    bdot_gain,
    natural_freq_rad_s,
    damping_ratio,
    max_rate_rad_s,
    desat_gain,
    desat_deadband_nms,
    null_motion_gain,
    null_speed_rad_s,
    null_max_torque_fraction
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// The closed form is the SVD's pseudo-inverse wherever it is taken, and the SVD is
    /// taken where the axes are (nearly) coplanar or fewer than three.
    #[test]
    fn the_pseudo_inverse_is_the_svds() {
        let mut seed = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for k in 0..500 {
            let mut a = Matrix3x4::from_fn(|_, _| next());
            // Some with a column dropped, some with the last axis in the first two's plane.
            match k % 5 {
                3 => a.set_column(k % 4, &Vector3::zeros()),
                4 => {
                    let c = a.column(0) * 0.3 + a.column(1) * -0.7;
                    a.set_column(3, &c);
                    a.set_column(2, &(a.column(0) * 2.0));
                }
                _ => {}
            }
            let svd = a.pseudo_inverse(1e-9).unwrap();
            let ours = pseudo_inverse(&a).unwrap();
            assert!(
                (svd - ours).norm() < 1e-9 * (1.0 + svd.norm()),
                "k {k}:\n{svd}\n{ours}"
            );
        }
    }

    fn body_torque(tau: &[f64; 4], wheels: &[WheelConfig; 4]) -> Vector3<f64> {
        -wheels
            .iter()
            .zip(tau)
            .fold(Vector3::zeros(), |s, (w, t)| s + w.axis_body * *t)
    }

    #[test]
    fn default_gains_match_the_documented_derivation() {
        let c = ControlConfig::default();
        let body = BodyConfig::default();
        let h_env = envelope_radius(&body.wheels, |w| w.inertia_kg_m2 * w.max_speed_rad_s);
        // 2 sin(beta) h_max for the NASA pyramid.
        let h_wheel = 1e-5 * 6000.0 * core::f64::consts::TAU / 60.0;
        assert!((h_env - 2.0 * (2.0_f64 / 3.0).sqrt() * h_wheel).abs() < 1e-12);
        assert!((c.bdot_gain - 2.2e-4).abs() < 0.01e-4, "{}", c.bdot_gain);
        assert!(
            (c.max_rate_rad_s.to_degrees() - 1.51).abs() < 0.01,
            "{}",
            c.max_rate_rad_s.to_degrees()
        );
        assert!((c.natural_freq_rad_s - 0.225).abs() < 0.001);
        assert!((c.kd() - 2e-3 / h_wheel).abs() < 1e-12);
        assert!((c.desat_gain - 3.9e-3).abs() < 0.05e-3, "{}", c.desat_gain);
        assert!((c.null_speed_rad_s - 62.83).abs() < 0.01);
    }

    #[test]
    fn bdot_torque_opposes_the_rate() {
        let c = ControlConfig::default();
        let b_eci = Vector3::new(20_000.0, -5_000.0, 30_000.0);
        let w = Vector3::new(0.05, -0.1, 0.02);
        let dt = 0.1;
        let q0 = UnitQuaternion::from_euler_angles(0.3, 0.1, -0.5);
        let q1 = q0 * UnitQuaternion::from_scaled_axis(w * dt);
        let (b0, b1) = (q0.inverse() * b_eci, q1.inverse() * b_eci);
        let m = bdot_dipole_am2(&b1, &b0, dt, &c, 0.2);
        let tau = mtq_torque_body_nm(&m, &b1);
        assert!(tau.dot(&w) < 0.0);
        assert!(m.amax() <= 0.2);
        // Small rate: unsaturated, torque = -k w_perp.
        let w = w * 1e-3;
        let q1 = q0 * UnitQuaternion::from_scaled_axis(w * dt);
        let b1 = q1.inverse() * b_eci;
        let tau = mtq_torque_body_nm(&bdot_dipole_am2(&b1, &b0, dt, &c, 0.2), &b1);
        let bh = b1.normalize();
        let w_perp = w - bh * bh.dot(&w);
        assert!((tau + w_perp * c.bdot_gain).norm() < 0.01 * c.bdot_gain * w_perp.norm());
        for bad in [0.0, -1.0, f64::NAN] {
            assert_eq!(bdot_dipole_am2(&b1, &b0, bad, &c, 0.2), Vector3::zeros());
        }
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(bdot_dipole_am2(&nan, &b0, dt, &c, 0.2), Vector3::zeros());
    }

    #[test]
    fn desat_torque_removes_the_momentum_perpendicular_to_the_field() {
        let c = ControlConfig::default();
        let b = Vector3::new(10_000.0, 20_000.0, -15_000.0);
        let h = Vector3::new(2e-3, -1e-3, 0.5e-3);
        let m = desat_dipole_am2(&h, &b, &c, 10.0);
        let tau = mtq_torque_body_nm(&m, &b);
        let bh = b.normalize();
        let h_perp = h - bh * bh.dot(&h);
        let excess = 1.0 - c.desat_deadband_nms / h.norm();
        assert!((tau + h_perp * (c.desat_gain * excess)).norm() < 1e-12 * h_perp.norm());
        // Clamped: same direction, largest axis at the limit.
        let m_small = desat_dipole_am2(&(h * 100.0), &b, &c, 0.2);
        assert!((m_small.amax() - 0.2).abs() < 1e-15);
        assert!(m_small.normalize().dot(&m.normalize()) > 1.0 - 1e-12);
        // Inside the deadband: off.
        let h_small = h.normalize() * (0.9 * c.desat_deadband_nms);
        assert_eq!(desat_dipole_am2(&h_small, &b, &c, 0.2), Vector3::zeros());
    }

    #[test]
    fn attitude_torque_is_sign_safe_and_restoring() {
        let c = ControlConfig::default();
        let i = BodyConfig::default().inertia_kg_m2;
        let t = GuidanceTarget {
            q_eci_from_body: UnitQuaternion::from_euler_angles(0.2, -0.4, 1.0),
            w_body_rad_s: Vector3::zeros(),
            dw_body_rad_s2: Vector3::zeros(),
            axis_body: Vector3::z(),
            axis_target_eci: Vector3::z(),
            target_elevation_deg: None,
        };
        let err = UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.02, 0.005));
        let q = t.q_eci_from_body * err;
        let neg = UnitQuaternion::new_unchecked(-q.into_inner());
        let zero = Vector3::zeros();
        let tau = attitude_torque_nm(&q, &zero, &t, &zero, &i, &c);
        let tau_neg = attitude_torque_nm(&neg, &zero, &t, &zero, &i, &c);
        assert!((tau - tau_neg).norm() < 1e-15);
        // Small error: tau = -I kp theta.
        assert!((tau + i * err.scaled_axis() * c.kp()).norm() < 1e-9 * tau.norm());
        // The target with its sign flipped gives the same torque too.
        let t_neg = GuidanceTarget {
            q_eci_from_body: UnitQuaternion::new_unchecked(-t.q_eci_from_body.into_inner()),
            ..t
        };
        let tau2 = attitude_torque_nm(&q, &zero, &t_neg, &zero, &i, &c);
        assert!((tau - tau2).norm() < 1e-15);
        // Large error: the rate command is the rate limit about the eigenaxis.
        let big = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 2.5, 0.0));
        let tau = attitude_torque_nm(&(t.q_eci_from_body * big), &zero, &t, &zero, &i, &c);
        let want = -i * Vector3::y() * (c.max_rate_rad_s * c.kd());
        assert!((tau - want).norm() < 1e-12);
        let nan = Vector3::new(f64::NAN, 0.0, 0.0);
        assert_eq!(attitude_torque_nm(&q, &nan, &t, &zero, &i, &c), zero);
    }

    #[test]
    fn null_motion_does_not_torque_the_body_and_friction_is_fed_forward() {
        let body = BodyConfig::default();
        let c = ControlConfig::default();
        let req = Vector3::new(1e-4, -2e-4, 5e-5);
        let speeds = [10.0, -30.0, 5.0, 200.0];
        let tau = wheel_commands_nm(&req, &body.wheels, [true; 4], &speeds, &c);
        // The body feels the request once friction (-f Omega) is subtracted.
        let net: [f64; 4] =
            core::array::from_fn(|i| tau[i] - body.wheels[i].friction_nm_s_rad * speeds[i]);
        assert!((body_torque(&net, &body.wheels) - req).norm() < 1e-15);
        // And the null component moves towards the bias.
        let plain = allocate_wheel_torques(&req, &body.wheels, [true; 4]);
        assert!(tau.iter().zip(plain).any(|(a, b)| (a - b).abs() > 1e-7));
        let nu = null_vector(&axis_matrix(&body.wheels, [true; 4])).unwrap();
        assert!((nu.abs() - Vector4::repeat(0.5)).norm() < 1e-12);
    }
}
