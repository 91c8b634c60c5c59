//! Orbit propagation behind one trait, so the FC can switch from SGP4 to numerical
//! integration after a manoeuvre.

use nalgebra::Vector3;

use crate::time::UtcTime;

/// A Cartesian position and velocity in an inertial frame (the frame is the caller's
/// contract: [`Propagator::state_j2000`] returns ECI J2000).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateVector {
    /// Position, km.
    pub r_km: Vector3<f64>,
    /// Velocity, km/s.
    pub v_km_s: Vector3<f64>,
}

/// Why a state could not be produced.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PropagationError {
    /// SGP4 returned an error (code 1-6 as in Vallado's SGP4).
    #[error("SGP4 error {code}: {message}")]
    Sgp4 {
        /// Vallado's error code.
        code: u8,
        /// What it means.
        message: String,
    },
    /// The orbit decayed (radius below the Earth's surface).
    #[error("the orbit decayed")]
    Decayed,
    /// The requested time is before the propagator's start and it cannot go backwards.
    #[error("time before the start of the propagation")]
    BeforeStart,
    /// The numerical integration failed (non-finite state).
    #[error("numerical integration diverged")]
    Diverged,
}

/// Anything that gives the satellite's ECI J2000 state at a UTC time.
pub trait Propagator: Send {
    /// ECI J2000 position and velocity at `t`.
    fn state_j2000(&mut self, t: UtcTime) -> Result<StateVector, PropagationError>;
}
