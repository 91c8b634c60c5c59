//! Orbit propagation behind one trait, so the FC can switch from SGP4 to numerical
//! integration after a manoeuvre.
//!
//! # SGP4/SDP4
//! [`Sgp4Propagator`] wraps the `sgp4` crate (2.4, a pure-Rust implementation of the revised
//! SGP4 of Vallado et al., "Revisiting Spacetrack Report #3", AIAA 2006-6753) configured as the
//! Vallado verification run (`tcppver.out`): WGS-72 constants, opsmode `'i'` (IAU sidereal time
//! at epoch from the TLE epoch as Julian years since J2000, and the non-AFSPC Lyddane branch).
//! It gives TEME states ([`Sgp4Propagator::state_teme`]) and, through
//! [`crate::frames::teme_to_j2000`], ECI J2000 states ([`Propagator::state_j2000`]).
//!
//! # Error codes
//! Vallado's `satrec.error` codes are surfaced as [`PropagationError::Sgp4`] with the same
//! number and python-sgp4's text ([`SGP4_ERROR_MESSAGES`]):
//! - 1: mean eccentricity outside [-0.001, 1) (the `sgp4` crate's `OutOfRangeEccentricity`,
//!   or an epoch eccentricity outside [0, 1) at initialisation);
//! - 2: mean motion not positive (the crate checks it at initialisation only, as
//!   `KozaiElementsError`; during propagation a non-finite state is reported as code 2);
//! - 3: perturbed eccentricity outside [0, 1] (`OutOfRangePerturbedEccentricity`);
//! - 4: semi-latus rectum negative (`NegativeSemiLatusRectum`);
//! - 5: epoch elements sub-orbital: Vallado's `sgp4init` sets it but the t = 0 propagation
//!   that ends `sgp4init` overwrites it, so it never reaches a caller; it is not produced here
//!   either;
//! - 6: decayed: Vallado's `mrt < 1` (the osculating radius below one Earth radius, WGS-72
//!   6378.135 km). The crate does not check it; this module does, on the returned position,
//!   whose norm is `mrt` times the Earth radius.
//!
//! Like `sgp4init`, [`Sgp4Propagator::new`] propagates to t = 0 and fails with the code of that
//! propagation (the verification case 33334 fails with code 3 there).
//!
//! # Accuracy (tests/sgp4_vallado.rs)
//! All 666 expected states of the Vallado verification set within 2.1e-7 km and 5.3e-10 km/s
//! (the file prints 8 and 9 decimals: rounding alone is 5e-9 km and 5e-10 km/s); at full
//! precision the `sgp4` crate differs from python-sgp4 (Vallado's C++) by at most 1.5e-7 km,
//! for case 20413 3.5 years after epoch, just before decay. That agreement needs the epoch
//! rounding described in [`Sgp4Propagator::new`]: with the exact epoch, case 23333
//! (e = 0.97, deep space) is 4.2e-6 km off.
//!
//! # Invariants
//! Propagation is stateless: the deep-space resonance integrator restarts from epoch on every
//! call (the crate's `propagate`; Vallado's `dspace` keeps its state between calls but steps
//! on the same 720 min grid from epoch, so the results agree). It is allocation free on
//! success and deterministic.

use nalgebra::Vector3;

use crate::frames;
use crate::time::UtcTime;
use crate::tle::Tle;

pub use crate::frames::StateVector;

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

impl PropagationError {
    /// Vallado's SGP4 error code, if this is an SGP4 error.
    pub fn sgp4_code(&self) -> Option<u8> {
        match self {
            PropagationError::Sgp4 { code, .. } => Some(*code),
            _ => None,
        }
    }

    /// Whether the satellite has decayed (SGP4 code 6 or a numerical propagator's decay).
    pub fn is_decayed(&self) -> bool {
        matches!(self, PropagationError::Decayed) || self.sgp4_code() == Some(6)
    }
}

/// The meaning of Vallado's SGP4 error codes 1-6 (python-sgp4's `SGP4_ERRORS` text), index
/// `code - 1`.
pub const SGP4_ERROR_MESSAGES: [&str; 6] = [
    "mean eccentricity is outside the range 0.0 to 1.0",
    "nm is less than zero",
    "perturbed eccentricity is outside the range 0.0 to 1.0",
    "semilatus rectum is less than zero",
    "epoch elements are sub-orbital",
    "mrt is less than 1.0 which indicates the satellite has decayed",
];

/// The [`PropagationError::Sgp4`] for a Vallado error code (1-6).
pub fn sgp4_error(code: u8) -> PropagationError {
    let message = SGP4_ERROR_MESSAGES
        .get(usize::from(code).wrapping_sub(1))
        .copied()
        .unwrap_or("unknown SGP4 error");
    PropagationError::Sgp4 {
        code,
        message: message.to_owned(),
    }
}

fn map_gp_error(e: &sgp4::Error) -> PropagationError {
    match e {
        sgp4::Error::OutOfRangeEccentricity { .. } => sgp4_error(1),
        sgp4::Error::OutOfRangePerturbedEccentricity { .. } => sgp4_error(3),
        sgp4::Error::NegativeSemiLatusRectum { .. } => sgp4_error(4),
    }
}

/// WGS-72 equatorial radius used by SGP4 (km): the decay threshold of error code 6.
pub const SGP4_EARTH_RADIUS_KM: f64 = sgp4::WGS72.ae;

/// SGP4/SDP4 for one TLE: WGS-72, opsmode `'i'`, TEME output.
#[derive(Debug, Clone)]
pub struct Sgp4Propagator {
    constants: sgp4::Constants,
    epoch: UtcTime,
    satnum: u32,
}

impl Sgp4Propagator {
    /// Initialise from a TLE, as Vallado's `sgp4init` (including its t = 0 propagation).
    ///
    /// The epoch reaches the lunar-solar terms as Vallado's `jdsatepoch + jdsatepochF`, one
    /// f64 rounded at 2.4e6 days (4.7e-10 day), not the exact epoch, to reproduce the
    /// verification set.
    pub fn new(tle: &Tle) -> Result<Self, PropagationError> {
        let deg = std::f64::consts::PI / 180.0;
        let geo = sgp4::WGS72;
        let orbit = sgp4::Orbit::from_kozai_elements(
            &geo,
            tle.inclination_deg * deg,
            tle.raan_deg * deg,
            tle.eccentricity,
            tle.arg_perigee_deg * deg,
            tle.mean_anomaly_deg * deg,
            // rev/day -> rad/min, as Vallado's `no_kozai / xpdotp`.
            tle.mean_motion_rev_day / (1440.0 / (2.0 * std::f64::consts::PI)),
        )
        .map_err(|_| sgp4_error(2))?;
        // Julian years since J2000 (UTC), the crate's epoch argument. Vallado's `sgp4init`
        // receives `jdsatepoch + jdsatepochF - 2433281.5`, a sum rounded to the f64 spacing
        // at 2.4e6 days (4.7e-10 day, 40 µs); the lunar-solar terms of very eccentric deep
        // space orbits are that sensitive (case 23333 moves 4e-6 km), so the same rounding
        // is reproduced here rather than the exact epoch.
        let jd = tle.epoch.jd_utc();
        let epoch_years = ((jd.day + jd.frac) - crate::time::JD_J2000) / 365.25;
        let constants = sgp4::Constants::new(
            geo,
            sgp4::iau_epoch_to_sidereal_time,
            epoch_years,
            tle.bstar_per_earth_radii,
            orbit,
        )
        .map_err(|_| sgp4_error(1))?;
        let p = Sgp4Propagator {
            constants,
            epoch: tle.epoch,
            satnum: tle.satnum,
        };
        p.state_teme(0.0)?;
        Ok(p)
    }

    /// The TLE epoch (UTC).
    pub fn epoch(&self) -> UtcTime {
        self.epoch
    }

    /// The satellite catalogue number.
    pub fn satnum(&self) -> u32 {
        self.satnum
    }

    /// TEME position (km) and velocity (km/s) `tsince_min` minutes after the TLE epoch.
    pub fn state_teme(&self, tsince_min: f64) -> Result<StateVector, PropagationError> {
        let p = self
            .constants
            .propagate(sgp4::MinutesSinceEpoch(tsince_min))
            .map_err(|e| map_gp_error(&e))?;
        let r_km = Vector3::from(p.position);
        let v_km_s = Vector3::from(p.velocity);
        if !(r_km.iter().chain(v_km_s.iter()).all(|x| x.is_finite())) {
            return Err(sgp4_error(2));
        }
        // Vallado's `mrt < 1.0`: mrt is |r| in Earth radii.
        if r_km.norm() < SGP4_EARTH_RADIUS_KM {
            return Err(sgp4_error(6));
        }
        Ok(StateVector { r_km, v_km_s })
    }

    /// TEME state at a UTC instant.
    pub fn state_teme_at(&self, t: UtcTime) -> Result<StateVector, PropagationError> {
        self.state_teme(t.seconds_since(self.epoch) / 60.0)
    }
}

impl Propagator for Sgp4Propagator {
    fn state_j2000(&mut self, t: UtcTime) -> Result<StateVector, PropagationError> {
        let teme = self.state_teme_at(t)?;
        Ok(frames::teme_to_j2000(&teme, t))
    }
}
