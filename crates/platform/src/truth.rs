//! The flight computer's published truth: one snapshot per FC step that the other nodes
//! (EPS, COMM, the recorder) read without importing `nodes-fc` (through
//! [`crate::board::TruthBoard`]), and what its ADCS believes and does.
//!
//! Plain data types, no behaviour beyond [`Default`] (everything zero, identity attitude).
//! Frames and units are in the field names: ECI is J2000 (ICD 1.4), body is the BCF of
//! ICD 1.4, and `q_eci_from_body` is active (`q_eci_from_body * v_body = v_eci`).

use nalgebra::{UnitQuaternion, Vector3};

use crate::time::SimTime;

/// The spacecraft's true state at one instant, as published by the FC.
#[derive(Debug, Clone, PartialEq)]
pub struct TruthSnapshot {
    /// Simulated time of the snapshot.
    pub t: SimTime,
    /// UTC time as nanoseconds since the Unix epoch (1970-01-01T00:00:00 UTC), ns.
    pub unix_ns: i64,
    /// Position in ECI (J2000), m.
    pub r_eci_m: Vector3<f64>,
    /// Velocity in ECI (J2000), m/s.
    pub v_eci_m_s: Vector3<f64>,
    /// Attitude: the active rotation taking body (BCF) vectors to ECI.
    pub q_eci_from_body: UnitQuaternion<f64>,
    /// Body angular rate relative to ECI, expressed in the body frame, rad/s.
    pub w_body_rad_s: Vector3<f64>,
    /// Unit vector from the satellite to the sun in ECI (dimensionless).
    pub sun_eci_unit: Vector3<f64>,
    /// Visible fraction of the solar disc: 1 in sunlight, 0 in umbra, between in penumbra.
    pub in_eclipse_fraction_visible: f64,
    /// Geomagnetic field at the satellite in ECI, nT.
    pub b_eci_nt: Vector3<f64>,
    /// Reaction wheel speeds relative to the body about their spin axes, rad/s.
    pub wheel_speed_rad_s: [f64; 4],
    /// Magnetorquer dipoles along body X, Y, Z (as applied, after limits), A m^2.
    pub mtq_dipole_am2: [f64; 3],
}

impl Default for TruthSnapshot {
    fn default() -> Self {
        Self {
            t: SimTime::ZERO,
            unix_ns: 0,
            r_eci_m: Vector3::zeros(),
            v_eci_m_s: Vector3::zeros(),
            q_eci_from_body: UnitQuaternion::identity(),
            w_body_rad_s: Vector3::zeros(),
            sun_eci_unit: Vector3::zeros(),
            in_eclipse_fraction_visible: 0.0,
            b_eci_nt: Vector3::zeros(),
            wheel_speed_rad_s: [0.0; 4],
            mtq_dipole_am2: [0.0; 3],
        }
    }
}

/// What the FC's ADCS flight software believes and does at one instant, published with each
/// [`TruthSnapshot`] (same `t`) for the recorder and the scenario expectations.
///
/// Angles that compare the estimate or the target with the truth are computed by the FC,
/// which knows all three; they are `None` when they do not apply (no target, no estimate).
#[derive(Debug, Clone, PartialEq)]
pub struct AdcsSnapshot {
    /// Simulated time (equals the truth snapshot's).
    pub t: SimTime,
    /// The mode in effect (the target-mode enumeration of docs/protocol.md; 1 detumble while
    /// the ADCS detumbles, whatever the commanded mode).
    pub mode_in_effect: u8,
    /// The commanded target mode (ATCMDSET or a script).
    pub mode_commanded: u8,
    /// ADCS state as TMACD reports it: 0 off, 1 detumbling, 2 acquiring, 3 tracking.
    pub state: u8,
    /// Estimated attitude (body in ECI J2000), when the estimator is initialised.
    pub q_eci_from_body_est: Option<UnitQuaternion<f64>>,
    /// Estimated body rate (gyro minus estimated bias), rad/s, body frame.
    pub w_body_rad_s_est: Vector3<f64>,
    /// Estimated gyro bias, rad/s, body frame.
    pub gyro_bias_rad_s_est: Vector3<f64>,
    /// Target attitude of the mode in effect (body in ECI), when the mode has one.
    pub q_eci_from_body_target: Option<UnitQuaternion<f64>>,
    /// Angle of the rotation from the true attitude to the target attitude, deg.
    pub pointing_error_deg: Option<f64>,
    /// Angle between the mode's pointing axis (true attitude) and its target direction, deg:
    /// body +Z to nadir / velocity / ECI vector, the panel normal to the sun, the script's
    /// body vector to the ground target; for fixed-quaternion modes the body +Z axis to its
    /// target direction.
    pub axis_error_deg: Option<f64>,
    /// Elevation of the satellite seen from the ground target, deg (earth-target modes only).
    pub target_elevation_deg: Option<f64>,
    /// Angle of the rotation from the true attitude to the estimate, deg.
    pub estimation_error_deg: Option<f64>,
    /// Reaction wheel states as TMACD reports them: 0 off, 1 on, 2 fault.
    pub rw_state: [u8; 4],
    /// Commanded wheel motor torques, N m.
    pub wheel_torque_cmd_nm: [f64; 4],
    /// Commanded magnetorquer dipoles along body X, Y, Z, A m^2.
    pub mtq_dipole_cmd_am2: [f64; 3],
    /// Magnetorquer states as TMACD reports them: 0 off, 1 positive, 2 negative.
    pub mtq_state: [u8; 3],
}

impl Default for AdcsSnapshot {
    fn default() -> Self {
        Self {
            t: SimTime::ZERO,
            mode_in_effect: 1,
            mode_commanded: 1,
            state: 1,
            q_eci_from_body_est: None,
            w_body_rad_s_est: Vector3::zeros(),
            gyro_bias_rad_s_est: Vector3::zeros(),
            q_eci_from_body_target: None,
            pointing_error_deg: None,
            axis_error_deg: None,
            target_elevation_deg: None,
            estimation_error_deg: None,
            rw_state: [1; 4],
            wheel_torque_cmd_nm: [0.0; 4],
            mtq_dipole_cmd_am2: [0.0; 3],
            mtq_state: [0; 3],
        }
    }
}
snap::fields!(TruthSnapshot {
    t,
    unix_ns,
    r_eci_m,
    v_eci_m_s,
    q_eci_from_body,
    w_body_rad_s,
    sun_eci_unit,
    in_eclipse_fraction_visible,
    b_eci_nt,
    wheel_speed_rad_s,
    mtq_dipole_am2,
});
