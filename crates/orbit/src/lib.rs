//! Where the satellite is, where the sun is, and what the geomagnetic field is: a pure
//! library (no tokio, no I/O at run time) validated against reference data from trusted
//! libraries (`tests/data/`, with their sources).
//!
//! - [`time`]: UTC, TT (leap seconds), UT1 (optional EOP), Julian dates, GMST (IAU-82).
//! - [`tle`]: two-line elements, strict and lenient checksums.
//! - [`propagate`]: the [`propagate::Propagator`] trait, SGP4/SDP4 (the `sgp4` crate) and
//!   Cowell with J2 and optional drag.
//! - [`frames`]: TEME -> J2000 (IAU-76/80), ECI <-> ECEF, LVLH, TNW, BCF helpers.
//! - [`geodetic`]: WGS-84 geodetic <-> ECEF.
//! - [`sun`], [`eclipse`]: geometric sun vector; conical umbra/penumbra.
//! - [`igrf`]: IGRF-14 main field, degree 13, with secular variation.
//! - [`passes`]: azimuth, elevation, range and pass prediction for a ground site.

pub mod cowell;
pub mod eclipse;
pub mod frames;
pub mod geodetic;
pub mod igrf;
pub mod passes;
pub mod propagate;
pub mod sun;
pub mod time;
pub mod tle;
