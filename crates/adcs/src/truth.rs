//! Rigid-body attitude dynamics of the M6P bus: the truth the ADCS flies against.
//!
//! A pure, deterministic core: [`step`] advances an [`AttitudeState`] by `dt_s` with a
//! fixed-step classical RK4; no allocation, no randomness, no clock. Frames follow ICD 1.4
//! and the house style: body is the BCF (Z along the 300 mm edge away from the propulsion
//! face, X along the 200 mm edge, Y completing the triad), ECI is J2000, and
//! `q_eci_from_body` is active (`q_eci_from_body * v_body = v_eci`).
//!
//! Model (a gyrostat with four reaction wheels):
//! - Total angular momentum about the centre of mass, body frame:
//!   `H = I w + sum_i(J_i Omega_i a_i)`, with `I` the whole spacecraft's inertia (wheels
//!   included), `w` the body rate relative to ECI, `Omega_i` wheel `i`'s speed relative to the
//!   body about its unit axis `a_i`, and `J_i` its axial inertia.
//! - Euler's equations: `I dw/dt = tau_ext - w x H - sum_i(tau_wheel_i a_i)`, where
//!   `tau_wheel_i` is the net axial torque on wheel `i` (motor minus viscous friction),
//!   and `J_i dOmega_i/dt = tau_wheel_i`. The wheel torques are internal: they exchange
//!   momentum with the body and leave `H` in ECI unchanged.
//! - Kinematics: `dq/dt = q (0, w) / 2`, the quaternion renormalised after every step.
//! - External torques: magnetorquers `m x B` (each axis clamped to the dipole limit),
//!   gravity gradient `3 mu / |r|^5 (r_b x I r_b)` with `r_b` the position in the body frame,
//!   and an optional disturbance torque (residual dipole, drag, ... computed by the caller).
//! - Wheel limits: the commanded motor torque is clamped to the torque limit; a wheel at its
//!   speed limit at the start of a step gets no motor torque that would push it further
//!   (decided once per step, so the right-hand side is smooth within it). After the step any
//!   wheel past its limit is clamped, and the momentum clipped from it is returned to the
//!   body (the motor could not have delivered it), so `H` stays conserved through saturation.
//!
//! Within one step, the field, position and commands are held constant (a zero-order hold
//! at the ADCS rate).

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// The Earth's gravitational parameter, m^3/s^2 (WGS-84 / EGM96, NIMA TR8350.2), as
/// `orbit::cowell::MU_EARTH_KM3_S2`.
pub const MU_EARTH_M3_S2: f64 = orbit::cowell::MU_EARTH_KM3_S2 * 1.0e9;

/// Angle between each pyramid wheel axis and body +Z, rad: arccos(1/sqrt(3)) = 54.7356 deg,
/// the NASA standard pyramid (equal momentum envelope along X, Y and Z; the four axes are the
/// directions of a cube's body diagonals through the +Z face).
pub const PYRAMID_BETA_RAD: f64 = 0.955_316_618_124_509_2;

/// One reaction wheel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelConfig {
    /// Spin axis in the body frame (BCF), unit vector.
    pub axis_body: Vector3<f64>,
    /// Rotor axial inertia, kg m^2.
    pub inertia_kg_m2: f64,
    /// Speed limit (magnitude), rad/s.
    pub max_speed_rad_s: f64,
    /// Motor torque limit (magnitude), N m.
    pub max_torque_nm: f64,
    /// Viscous friction coefficient: friction torque = -coefficient * speed, N m s/rad.
    pub friction_nm_s_rad: f64,
}

impl WheelConfig {
    /// A small-satellite wheel on `axis_body`: 1.0e-5 kg m^2, 6000 rpm, 2 mN m, and viscous
    /// friction of 1.0e-8 N m s/rad (6.3 uN m at full speed, 0.3 % of the torque limit).
    pub fn small(axis_body: Vector3<f64>) -> Self {
        Self {
            axis_body: axis_body.normalize(),
            inertia_kg_m2: 1.0e-5,
            max_speed_rad_s: 6000.0 * core::f64::consts::TAU / 60.0,
            max_torque_nm: 2.0e-3,
            friction_nm_s_rad: 1.0e-8,
        }
    }

    /// Wheel `i` (0..4) of the NASA pyramid about body +Z: axis at [`PYRAMID_BETA_RAD`] from
    /// +Z (35.26 deg elevation from the X-Y plane), azimuths 0, 90, 180, 270 deg from +X.
    pub fn pyramid_axis_body(i: usize) -> Vector3<f64> {
        let (s, c) = PYRAMID_BETA_RAD.sin_cos();
        match i % 4 {
            0 => Vector3::new(s, 0.0, c),
            1 => Vector3::new(0.0, s, c),
            2 => Vector3::new(-s, 0.0, c),
            _ => Vector3::new(0.0, -s, c),
        }
    }
}

/// The bus's mass properties and actuators.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyConfig {
    /// Inertia tensor about the centre of mass in BCF (wheels included), kg m^2.
    pub inertia_kg_m2: Matrix3<f64>,
    /// The four reaction wheels.
    pub wheels: [WheelConfig; 4],
    /// Magnetorquer dipole limit per body axis (magnitude), A m^2.
    pub mtq_max_dipole_am2: f64,
}

impl Default for BodyConfig {
    /// A 6U-class bus: a uniform 12 kg box of 0.2 m (X) x 0.1 m (Y) x 0.3 m (Z) (BCF axes of
    /// ICD 1.4), so `I = m/12 diag(y^2+z^2, x^2+z^2, x^2+y^2) = diag(0.10, 0.13, 0.05)` kg m^2;
    /// four [`WheelConfig::small`] wheels in the NASA pyramid; 0.2 A m^2 magnetorquers.
    fn default() -> Self {
        let (m, x, y, z) = (12.0_f64, 0.2_f64, 0.1_f64, 0.3_f64);
        let inertia_kg_m2 = Matrix3::from_diagonal(&Vector3::new(
            m / 12.0 * (y * y + z * z),
            m / 12.0 * (x * x + z * z),
            m / 12.0 * (x * x + y * y),
        ));
        Self {
            inertia_kg_m2,
            wheels: core::array::from_fn(|i| WheelConfig::small(WheelConfig::pyramid_axis_body(i))),
            mtq_max_dipole_am2: 0.2,
        }
    }
}

/// The attitude part of the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeState {
    /// Attitude: active rotation from body (BCF) to ECI.
    pub q_eci_from_body: UnitQuaternion<f64>,
    /// Body rate relative to ECI, in the body frame, rad/s.
    pub w_body_rad_s: Vector3<f64>,
    /// Wheel speeds relative to the body about their axes, rad/s.
    pub wheel_speed_rad_s: [f64; 4],
}

impl Default for AttitudeState {
    fn default() -> Self {
        Self {
            q_eci_from_body: UnitQuaternion::identity(),
            w_body_rad_s: Vector3::zeros(),
            wheel_speed_rad_s: [0.0; 4],
        }
    }
}

impl AttitudeState {
    /// Total angular momentum (body plus wheels) in the body frame, N m s.
    pub fn h_body_nms(&self, cfg: &BodyConfig) -> Vector3<f64> {
        cfg.inertia_kg_m2 * self.w_body_rad_s
            + wheel_momentum_body_nms(cfg, &self.wheel_speed_rad_s)
    }

    /// Total angular momentum (body plus wheels) in ECI, N m s.
    pub fn h_eci_nms(&self, cfg: &BodyConfig) -> Vector3<f64> {
        self.q_eci_from_body * self.h_body_nms(cfg)
    }

    /// Rotational kinetic energy of the body, `w . I w / 2` (wheel spin excluded), J.
    pub fn body_energy_j(&self, cfg: &BodyConfig) -> f64 {
        0.5 * self
            .w_body_rad_s
            .dot(&(cfg.inertia_kg_m2 * self.w_body_rad_s))
    }
}

/// Actuator commands and environment, held constant over one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Torques {
    /// Commanded motor torque on each wheel about its axis (positive spins it up along its
    /// axis; the body feels the opposite), N m. Clamped to the wheel's torque limit.
    pub wheel_torque_cmd_nm: [f64; 4],
    /// Commanded magnetorquer dipole in body axes, A m^2. Each axis clamped to the limit.
    pub mtq_dipole_cmd_am2: Vector3<f64>,
    /// Geomagnetic field in the body frame, T.
    pub b_body_t: Vector3<f64>,
    /// Position in ECI for the gravity-gradient torque, m; `None` switches it off.
    pub r_eci_m: Option<Vector3<f64>>,
    /// Any further external torque in the body frame (residual dipole, drag), N m.
    pub disturbance_body_nm: Vector3<f64>,
}

impl Default for Torques {
    /// No commands, no field, no gravity gradient, no disturbance: torque-free.
    fn default() -> Self {
        Self {
            wheel_torque_cmd_nm: [0.0; 4],
            mtq_dipole_cmd_am2: Vector3::zeros(),
            b_body_t: Vector3::zeros(),
            r_eci_m: None,
            disturbance_body_nm: Vector3::zeros(),
        }
    }
}

/// Wheel momentum `sum_i(J_i Omega_i a_i)` in the body frame, N m s.
pub fn wheel_momentum_body_nms(cfg: &BodyConfig, wheel_speed_rad_s: &[f64; 4]) -> Vector3<f64> {
    cfg.wheels
        .iter()
        .zip(wheel_speed_rad_s)
        .fold(Vector3::zeros(), |h, (w, &s)| {
            h + w.axis_body * (w.inertia_kg_m2 * s)
        })
}

/// The magnetorquer dipole actually produced for a command: each axis clamped, A m^2.
pub fn mtq_dipole_applied_am2(cfg: &BodyConfig, cmd_am2: &Vector3<f64>) -> Vector3<f64> {
    let m = cfg.mtq_max_dipole_am2;
    cmd_am2.map(|c| c.clamp(-m, m))
}

/// Gravity-gradient torque `3 mu / |r|^5 (r_b x I r_b)` in the body frame, N m.
pub fn gravity_gradient_body_nm(
    cfg: &BodyConfig,
    q_eci_from_body: &UnitQuaternion<f64>,
    r_eci_m: &Vector3<f64>,
) -> Vector3<f64> {
    let r = r_eci_m.norm();
    if r == 0.0 {
        return Vector3::zeros();
    }
    let r_body_m = q_eci_from_body.inverse_transform_vector(r_eci_m);
    let k = 3.0 * MU_EARTH_M3_S2 / (r * r * r * r * r);
    r_body_m.cross(&(cfg.inertia_kg_m2 * r_body_m)) * k
}

/// The motor torque a wheel gets for a command at `speed_rad_s` (after the torque limit, and
/// none that would push it past its speed limit), N m.
fn wheel_motor_torque_nm(w: &WheelConfig, speed_rad_s: f64, cmd_nm: f64) -> f64 {
    let motor = cmd_nm.clamp(-w.max_torque_nm, w.max_torque_nm);
    if (speed_rad_s >= w.max_speed_rad_s && motor > 0.0)
        || (speed_rad_s <= -w.max_speed_rad_s && motor < 0.0)
    {
        0.0
    } else {
        motor
    }
}

/// Time derivative of (q, w, Omega) at a state.
#[derive(Clone, Copy)]
struct Deriv {
    q: Quaternion<f64>,
    w: Vector3<f64>,
    omega: [f64; 4],
}

/// What stays fixed over one step: configuration, inverse inertia and held inputs.
struct StepConsts<'a> {
    cfg: &'a BodyConfig,
    i_inv: Matrix3<f64>,
    /// Magnetorquer plus disturbance torque, body frame, N m.
    torque_fixed_nm: Vector3<f64>,
    /// Motor torque per wheel after limits, N m.
    motor_nm: [f64; 4],
    r_eci_m: Option<Vector3<f64>>,
}

fn derivative(
    q: &Quaternion<f64>,
    w: &Vector3<f64>,
    omega: &[f64; 4],
    k: &StepConsts<'_>,
) -> Deriv {
    let cfg = k.cfg;
    let mut tau_ext = k.torque_fixed_nm;
    if let Some(r_eci_m) = &k.r_eci_m {
        // The stage quaternion is not exactly unit inside RK4; normalise for the direction.
        let qn = UnitQuaternion::new_normalize(*q);
        tau_ext += gravity_gradient_body_nm(cfg, &qn, r_eci_m);
    }
    let mut h = cfg.inertia_kg_m2 * w;
    let mut tau_wheels_body = Vector3::zeros();
    let mut omega_dot = [0.0; 4];
    for i in 0..4 {
        let wc = &cfg.wheels[i];
        h += wc.axis_body * (wc.inertia_kg_m2 * omega[i]);
        let t = k.motor_nm[i] - wc.friction_nm_s_rad * omega[i];
        tau_wheels_body += wc.axis_body * t;
        omega_dot[i] = t / wc.inertia_kg_m2;
    }
    let w_dot = k.i_inv * (tau_ext - w.cross(&h) - tau_wheels_body);
    let q_dot = q * Quaternion::from_imag(*w) * 0.5;
    Deriv {
        q: q_dot,
        w: w_dot,
        omega: omega_dot,
    }
}

fn add_scaled(
    q: &Quaternion<f64>,
    w: &Vector3<f64>,
    omega: &[f64; 4],
    d: &Deriv,
    h: f64,
) -> (Quaternion<f64>, Vector3<f64>, [f64; 4]) {
    (
        q + d.q * h,
        w + d.w * h,
        core::array::from_fn(|i| omega[i] + d.omega[i] * h),
    )
}

/// Advance the attitude by `dt_s` with one classical RK4 step, the inputs held constant.
///
/// The quaternion is renormalised after the step, and wheel speeds past their limit are
/// clamped with the clipped momentum returned to the body. A singular inertia tensor leaves
/// the state unchanged (a configuration error, not a panic).
pub fn step(state: &AttitudeState, cfg: &BodyConfig, inputs: &Torques, dt_s: f64) -> AttitudeState {
    let Some(i_inv) = cfg.inertia_kg_m2.try_inverse() else {
        return *state;
    };
    let m_body_am2 = mtq_dipole_applied_am2(cfg, &inputs.mtq_dipole_cmd_am2);
    let torque_fixed_nm = m_body_am2.cross(&inputs.b_body_t) + inputs.disturbance_body_nm;

    let q0 = *state.q_eci_from_body.quaternion();
    let w0 = state.w_body_rad_s;
    let o0 = state.wheel_speed_rad_s;
    // The motor torques are decided once per step, from the speeds at its start, so that the
    // right-hand side is smooth within the step (RK4 keeps its order through saturation).
    let motor_nm: [f64; 4] = core::array::from_fn(|i| {
        wheel_motor_torque_nm(&cfg.wheels[i], o0[i], inputs.wheel_torque_cmd_nm[i])
    });
    let consts = StepConsts {
        cfg,
        i_inv,
        torque_fixed_nm,
        motor_nm,
        r_eci_m: inputs.r_eci_m,
    };
    let f = |q: &Quaternion<f64>, w: &Vector3<f64>, o: &[f64; 4]| derivative(q, w, o, &consts);

    let k1 = f(&q0, &w0, &o0);
    let (q, w, o) = add_scaled(&q0, &w0, &o0, &k1, 0.5 * dt_s);
    let k2 = f(&q, &w, &o);
    let (q, w, o) = add_scaled(&q0, &w0, &o0, &k2, 0.5 * dt_s);
    let k3 = f(&q, &w, &o);
    let (q, w, o) = add_scaled(&q0, &w0, &o0, &k3, dt_s);
    let k4 = f(&q, &w, &o);

    let s = dt_s / 6.0;
    let q1 = q0 + (k1.q + k2.q * 2.0 + k3.q * 2.0 + k4.q) * s;
    let mut w1 = w0 + (k1.w + k2.w * 2.0 + k3.w * 2.0 + k4.w) * s;
    let mut o1: [f64; 4] = core::array::from_fn(|i| {
        o0[i] + (k1.omega[i] + 2.0 * k2.omega[i] + 2.0 * k3.omega[i] + k4.omega[i]) * s
    });

    // Speed limits: the momentum a wheel could not have taken stays in the body.
    for (i, wc) in cfg.wheels.iter().enumerate() {
        let clamped = o1[i].clamp(-wc.max_speed_rad_s, wc.max_speed_rad_s);
        let excess = o1[i] - clamped;
        if excess != 0.0 {
            w1 += i_inv * (wc.axis_body * (wc.inertia_kg_m2 * excess));
            o1[i] = clamped;
        }
    }

    AttitudeState {
        q_eci_from_body: UnitQuaternion::new_normalize(q1),
        w_body_rad_s: w1,
        wheel_speed_rad_s: o1,
    }
}

/// Lock wheel `i` (a seized bearing): its speed relative to the body drops to zero at once
/// and its momentum goes to the body, so the total momentum is unchanged.
pub fn lock_wheel(state: &mut AttitudeState, cfg: &BodyConfig, i: usize) {
    let (Some(wc), Some(speed)) = (cfg.wheels.get(i), state.wheel_speed_rad_s.get(i).copied())
    else {
        return;
    };
    if speed == 0.0 {
        return;
    }
    if let Some(i_inv) = cfg.inertia_kg_m2.try_inverse() {
        state.w_body_rad_s += i_inv * (wc.axis_body * (wc.inertia_kg_m2 * speed));
        state.wheel_speed_rad_s[i] = 0.0;
    }
}

snap::fields!(AttitudeState {
    q_eci_from_body,
    w_body_rad_s,
    wheel_speed_rad_s
});
