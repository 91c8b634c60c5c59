//! The flight computer's published truth: one snapshot per FC step that the other nodes
//! (EPS, COMM, the recorder) read without importing `nodes-fc`.
//!
//! A plain data type, no behaviour beyond [`Default`] (everything zero, identity attitude).
//! Frames and units are in the field names: ECI is J2000 (ICD 1.4), body is the BCF of
//! ICD 1.4, and `q_eci_from_body` is active (`q_eci_from_body * v_body = v_eci`).

use nalgebra::{UnitQuaternion, Vector3};

/// The spacecraft's true state at one instant, as published by the FC.
#[derive(Debug, Clone, PartialEq)]
pub struct TruthSnapshot {
    /// Simulated time since run start, ns.
    pub t_ns: u64,
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
            t_ns: 0,
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
