//! Reference frames: TEME, ECI J2000, ECEF, LVLH, TNW and the body frame (BCF).
//!
//! # Frames (ICD 1.4, INTERPRETATION.md section 5)
//! - **TEME**: SGP4's true equator, mean equinox of date.
//! - **ECI** is J2000 (mean equator and equinox of J2000.0) realised the classic FK5 way, as
//!   Vallado's `teme2eci` (Vallado et al. 2006, AIAA 2006-6753, and Vallado, *Fundamentals of
//!   Astrodynamics and Applications*, 4th ed., 3.7): `r_j2000 = P76ᵀ N80ᵀ R3(-eqe) r_teme`,
//!   with IAU-76 precession `P76` (Lieske et al. 1977; ERFA `pmat76`), IAU-80 nutation `N80`
//!   with the full 106-term series and no dPsi/dEps corrections (ERFA `nut80`, `numat`), and
//!   the geometric equation of the equinoxes `eqe = dPsi cos(eps_mean)` (no kinematic terms:
//!   TEME is defined that way). Time argument: TT.
//! - **ECEF** (PEF, or ITRF when polar motion is given): `r_ecef = W R3(GMST82(UT1)) r_teme`,
//!   i.e. the Earth rotation of Vallado's `teme2ecef` and astropy's TEME -> ITRS. UT1 = UTC and
//!   W = I unless an [`Eop`] is given; then `W = R1(-yp) R2(-xp)` (ERFA `pom00` with s' = 0).
//!   Velocities include the Earth-rotation term `-ω x r` with ω = 7.292115146706979e-5 rad/s.
//! - **LVLH** (ICD 1.4): Z = -r̂ (to Earth's centre), Y = -ĥ (h = r x v), X = Y x Z.
//! - **TNW** (ICD 1.4, axes taken literally per INTERPRETATION.md): X = v̂, Y = ĥ, Z = X x Y
//!   (close to zenith, not nadir as the ICD's note says).
//! - **BCF**: the body frame; attitudes are `q_<ref>_from_body`.
//!
//! # Conventions
//! - Rotation matrices are named `a_<to>_from_<from>`: `v_to = a_to_from_from * v_from`. A
//!   matrix's rows are the `to` axes written in the `from` frame.
//! - Quaternions are nalgebra `UnitQuaternion`s, scalar first, active: `q_eci_from_body *
//!   v_body = v_eci` (= q (0, v) q*). The ICD's `pointECI r i j k` is `q_eci_from_body`, so
//!   `pointECI 0.707106 0 0 -0.707106` puts body y on the mean equinox (a unit test). Returned
//!   quaternions have w >= 0.
//! - The elementary rotations `rot1/rot2/rot3` are ERFA's passive (frame) rotations:
//!   `rot3(θ) = [[c, s, 0], [-s, c, 0], [0, 0, 1]]`.
//!
//! # Accuracy (tests/frames_ref.rs against tests/data/teme_to_j2000.csv and frames.csv)
//! TEME -> J2000 within 1.3e-9 m and 1e-12 m/s of ERFA's `j2000fk5_*` (rounding only);
//! equation of the equinoxes within 7e-21 rad; GMST within 3.8e-12 rad; ECEF within 2.5e-5 m
//! of astropy's ITRS with the sample's EOP, within 84 m without EOP for the 2020s samples
//! (262 m for the 2004 sample, whose UT1 - UTC is -0.44 s); LVLH and TNW within 4.4e-16 rad.
//!
//! # Invariants
//! Pure functions of their arguments, no allocation, no panics.

use std::f64::consts::TAU;

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::time::{Eop, JulianDate, UtcTime, gmst82};

/// A Cartesian position and velocity in a frame the caller names (the frame is its
/// contract: [`crate::propagate::Propagator::state_j2000`] returns ECI J2000, the
/// conversions here say theirs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateVector {
    /// Position, km.
    pub r_km: Vector3<f64>,
    /// Velocity, km/s.
    pub v_km_s: Vector3<f64>,
}

/// Arcseconds to radians.
pub const ARCSEC_TO_RAD: f64 = std::f64::consts::PI / (180.0 * 3600.0);

/// Nominal Earth rotation rate, rad/s (Vallado, *Fundamentals*, 4th ed., `omegaearth`;
/// IERS Conventions 2010, 1.1).
pub const OMEGA_EARTH_RAD_S: f64 = 7.292_115_146_706_979e-5;

/// ERFA-style passive rotation about x by `a` (rad).
pub fn rot1(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, s, 0.0, -s, c)
}

/// ERFA-style passive rotation about y by `a` (rad).
pub fn rot2(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c)
}

/// ERFA-style passive rotation about z by `a` (rad).
pub fn rot3(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0)
}

/// IAU-76 precession: A(mean of date <- J2000) for a TT date (Lieske et al. 1977, ERFA
/// `prec76` with the start epoch J2000 and `pmat76`).
pub fn precession_iau76(jd_tt: JulianDate) -> Matrix3<f64> {
    let t = jd_tt.centuries_since_j2000();
    let tas2r = t * ARCSEC_TO_RAD;
    let w = 2306.2181;
    let zeta = (w + (0.30188 + 0.017998 * t) * t) * tas2r;
    let z = (w + (1.09468 + 0.018203 * t) * t) * tas2r;
    let theta = (2004.3109 + (-0.42665 - 0.041833 * t) * t) * tas2r;
    rot3(-z) * rot2(theta) * rot3(-zeta)
}

/// Mean obliquity of the ecliptic, IAU 1980 (Lieske et al. 1977, ERFA `obl80`), rad.
pub fn mean_obliquity_iau80(jd_tt: JulianDate) -> f64 {
    let t = jd_tt.centuries_since_j2000();
    ARCSEC_TO_RAD * (84_381.448 + (-46.8150 + (-0.00059 + 0.001_813 * t) * t) * t)
}

/// IAU-80 nutation angles at a date.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nutation80 {
    /// Nutation in longitude, rad.
    pub dpsi_rad: f64,
    /// Nutation in obliquity, rad.
    pub deps_rad: f64,
    /// Mean obliquity of date (IAU 1980), rad.
    pub eps_mean_rad: f64,
}

impl Nutation80 {
    /// The nutation matrix A(true of date <- mean of date) (ERFA `numat`).
    pub fn a_tod_from_mod(&self) -> Matrix3<f64> {
        rot1(-(self.eps_mean_rad + self.deps_rad)) * rot3(-self.dpsi_rad) * rot1(self.eps_mean_rad)
    }

    /// The equation of the equinoxes without the kinematic terms, `dPsi cos(eps_mean)`, rad:
    /// the angle from the TEME x axis to the true equinox (Vallado's `teme2eci`).
    pub fn eqeq_geometric_rad(&self) -> f64 {
        self.dpsi_rad * self.eps_mean_rad.cos()
    }
}

/// One term of the IAU 1980 nutation series: multipliers of (l, l', F, D, Ω), then the
/// longitude sine coefficient and its rate and the obliquity cosine coefficient and its rate,
/// in 0.1 mas and 0.1 mas per Julian century.
#[derive(Debug, Clone, Copy)]
struct NutTerm([i8; 5], f64, f64, f64, f64);

/// The 106 terms of the IAU 1980 theory of nutation (Seidelmann 1982; Explanatory Supplement
/// to the Astronomical Almanac, 1992, Table 3.222.1), in the order of SOFA/ERFA `nut80.c`,
/// which is also the content of Vallado's `nut80.dat` (there in a different order and in
/// units of 0.0001 arcsec, the same unit as here).
#[rustfmt::skip]
const NUT80: [NutTerm; 106] = [
    NutTerm([ 0,  0,  0,  0,  1], -171996.0,    -174.2,   92025.0,       8.9), // 1
    NutTerm([ 0,  0,  0,  0,  2],    2062.0,       0.2,    -895.0,       0.5), // 2
    NutTerm([-2,  0,  2,  0,  1],      46.0,       0.0,     -24.0,       0.0), // 3
    NutTerm([ 2,  0, -2,  0,  0],      11.0,       0.0,       0.0,       0.0), // 4
    NutTerm([-2,  0,  2,  0,  2],      -3.0,       0.0,       1.0,       0.0), // 5
    NutTerm([ 1, -1,  0, -1,  0],      -3.0,       0.0,       0.0,       0.0), // 6
    NutTerm([ 0, -2,  2, -2,  1],      -2.0,       0.0,       1.0,       0.0), // 7
    NutTerm([ 2,  0, -2,  0,  1],       1.0,       0.0,       0.0,       0.0), // 8
    NutTerm([ 0,  0,  2, -2,  2],  -13187.0,      -1.6,    5736.0,      -3.1), // 9
    NutTerm([ 0,  1,  0,  0,  0],    1426.0,      -3.4,      54.0,      -0.1), // 10
    NutTerm([ 0,  1,  2, -2,  2],    -517.0,       1.2,     224.0,      -0.6), // 11
    NutTerm([ 0, -1,  2, -2,  2],     217.0,      -0.5,     -95.0,       0.3), // 12
    NutTerm([ 0,  0,  2, -2,  1],     129.0,       0.1,     -70.0,       0.0), // 13
    NutTerm([ 2,  0,  0, -2,  0],      48.0,       0.0,       1.0,       0.0), // 14
    NutTerm([ 0,  0,  2, -2,  0],     -22.0,       0.0,       0.0,       0.0), // 15
    NutTerm([ 0,  2,  0,  0,  0],      17.0,      -0.1,       0.0,       0.0), // 16
    NutTerm([ 0,  1,  0,  0,  1],     -15.0,       0.0,       9.0,       0.0), // 17
    NutTerm([ 0,  2,  2, -2,  2],     -16.0,       0.1,       7.0,       0.0), // 18
    NutTerm([ 0, -1,  0,  0,  1],     -12.0,       0.0,       6.0,       0.0), // 19
    NutTerm([-2,  0,  0,  2,  1],      -6.0,       0.0,       3.0,       0.0), // 20
    NutTerm([ 0, -1,  2, -2,  1],      -5.0,       0.0,       3.0,       0.0), // 21
    NutTerm([ 2,  0,  0, -2,  1],       4.0,       0.0,      -2.0,       0.0), // 22
    NutTerm([ 0,  1,  2, -2,  1],       4.0,       0.0,      -2.0,       0.0), // 23
    NutTerm([ 1,  0,  0, -1,  0],      -4.0,       0.0,       0.0,       0.0), // 24
    NutTerm([ 2,  1,  0, -2,  0],       1.0,       0.0,       0.0,       0.0), // 25
    NutTerm([ 0,  0, -2,  2,  1],       1.0,       0.0,       0.0,       0.0), // 26
    NutTerm([ 0,  1, -2,  2,  0],      -1.0,       0.0,       0.0,       0.0), // 27
    NutTerm([ 0,  1,  0,  0,  2],       1.0,       0.0,       0.0,       0.0), // 28
    NutTerm([-1,  0,  0,  1,  1],       1.0,       0.0,       0.0,       0.0), // 29
    NutTerm([ 0,  1,  2, -2,  0],      -1.0,       0.0,       0.0,       0.0), // 30
    NutTerm([ 0,  0,  2,  0,  2],   -2274.0,      -0.2,     977.0,      -0.5), // 31
    NutTerm([ 1,  0,  0,  0,  0],     712.0,       0.1,      -7.0,       0.0), // 32
    NutTerm([ 0,  0,  2,  0,  1],    -386.0,      -0.4,     200.0,       0.0), // 33
    NutTerm([ 1,  0,  2,  0,  2],    -301.0,       0.0,     129.0,      -0.1), // 34
    NutTerm([ 1,  0,  0, -2,  0],    -158.0,       0.0,      -1.0,       0.0), // 35
    NutTerm([-1,  0,  2,  0,  2],     123.0,       0.0,     -53.0,       0.0), // 36
    NutTerm([ 0,  0,  0,  2,  0],      63.0,       0.0,      -2.0,       0.0), // 37
    NutTerm([ 1,  0,  0,  0,  1],      63.0,       0.1,     -33.0,       0.0), // 38
    NutTerm([-1,  0,  0,  0,  1],     -58.0,      -0.1,      32.0,       0.0), // 39
    NutTerm([-1,  0,  2,  2,  2],     -59.0,       0.0,      26.0,       0.0), // 40
    NutTerm([ 1,  0,  2,  0,  1],     -51.0,       0.0,      27.0,       0.0), // 41
    NutTerm([ 0,  0,  2,  2,  2],     -38.0,       0.0,      16.0,       0.0), // 42
    NutTerm([ 2,  0,  0,  0,  0],      29.0,       0.0,      -1.0,       0.0), // 43
    NutTerm([ 1,  0,  2, -2,  2],      29.0,       0.0,     -12.0,       0.0), // 44
    NutTerm([ 2,  0,  2,  0,  2],     -31.0,       0.0,      13.0,       0.0), // 45
    NutTerm([ 0,  0,  2,  0,  0],      26.0,       0.0,      -1.0,       0.0), // 46
    NutTerm([-1,  0,  2,  0,  1],      21.0,       0.0,     -10.0,       0.0), // 47
    NutTerm([-1,  0,  0,  2,  1],      16.0,       0.0,      -8.0,       0.0), // 48
    NutTerm([ 1,  0,  0, -2,  1],     -13.0,       0.0,       7.0,       0.0), // 49
    NutTerm([-1,  0,  2,  2,  1],     -10.0,       0.0,       5.0,       0.0), // 50
    NutTerm([ 1,  1,  0, -2,  0],      -7.0,       0.0,       0.0,       0.0), // 51
    NutTerm([ 0,  1,  2,  0,  2],       7.0,       0.0,      -3.0,       0.0), // 52
    NutTerm([ 0, -1,  2,  0,  2],      -7.0,       0.0,       3.0,       0.0), // 53
    NutTerm([ 1,  0,  2,  2,  2],      -8.0,       0.0,       3.0,       0.0), // 54
    NutTerm([ 1,  0,  0,  2,  0],       6.0,       0.0,       0.0,       0.0), // 55
    NutTerm([ 2,  0,  2, -2,  2],       6.0,       0.0,      -3.0,       0.0), // 56
    NutTerm([ 0,  0,  0,  2,  1],      -6.0,       0.0,       3.0,       0.0), // 57
    NutTerm([ 0,  0,  2,  2,  1],      -7.0,       0.0,       3.0,       0.0), // 58
    NutTerm([ 1,  0,  2, -2,  1],       6.0,       0.0,      -3.0,       0.0), // 59
    NutTerm([ 0,  0,  0, -2,  1],      -5.0,       0.0,       3.0,       0.0), // 60
    NutTerm([ 1, -1,  0,  0,  0],       5.0,       0.0,       0.0,       0.0), // 61
    NutTerm([ 2,  0,  2,  0,  1],      -5.0,       0.0,       3.0,       0.0), // 62
    NutTerm([ 0,  1,  0, -2,  0],      -4.0,       0.0,       0.0,       0.0), // 63
    NutTerm([ 1,  0, -2,  0,  0],       4.0,       0.0,       0.0,       0.0), // 64
    NutTerm([ 0,  0,  0,  1,  0],      -4.0,       0.0,       0.0,       0.0), // 65
    NutTerm([ 1,  1,  0,  0,  0],      -3.0,       0.0,       0.0,       0.0), // 66
    NutTerm([ 1,  0,  2,  0,  0],       3.0,       0.0,       0.0,       0.0), // 67
    NutTerm([ 1, -1,  2,  0,  2],      -3.0,       0.0,       1.0,       0.0), // 68
    NutTerm([-1, -1,  2,  2,  2],      -3.0,       0.0,       1.0,       0.0), // 69
    NutTerm([-2,  0,  0,  0,  1],      -2.0,       0.0,       1.0,       0.0), // 70
    NutTerm([ 3,  0,  2,  0,  2],      -3.0,       0.0,       1.0,       0.0), // 71
    NutTerm([ 0, -1,  2,  2,  2],      -3.0,       0.0,       1.0,       0.0), // 72
    NutTerm([ 1,  1,  2,  0,  2],       2.0,       0.0,      -1.0,       0.0), // 73
    NutTerm([-1,  0,  2, -2,  1],      -2.0,       0.0,       1.0,       0.0), // 74
    NutTerm([ 2,  0,  0,  0,  1],       2.0,       0.0,      -1.0,       0.0), // 75
    NutTerm([ 1,  0,  0,  0,  2],      -2.0,       0.0,       1.0,       0.0), // 76
    NutTerm([ 3,  0,  0,  0,  0],       2.0,       0.0,       0.0,       0.0), // 77
    NutTerm([ 0,  0,  2,  1,  2],       2.0,       0.0,      -1.0,       0.0), // 78
    NutTerm([-1,  0,  0,  0,  2],       1.0,       0.0,      -1.0,       0.0), // 79
    NutTerm([ 1,  0,  0, -4,  0],      -1.0,       0.0,       0.0,       0.0), // 80
    NutTerm([-2,  0,  2,  2,  2],       1.0,       0.0,      -1.0,       0.0), // 81
    NutTerm([-1,  0,  2,  4,  2],      -2.0,       0.0,       1.0,       0.0), // 82
    NutTerm([ 2,  0,  0, -4,  0],      -1.0,       0.0,       0.0,       0.0), // 83
    NutTerm([ 1,  1,  2, -2,  2],       1.0,       0.0,      -1.0,       0.0), // 84
    NutTerm([ 1,  0,  2,  2,  1],      -1.0,       0.0,       1.0,       0.0), // 85
    NutTerm([-2,  0,  2,  4,  2],      -1.0,       0.0,       1.0,       0.0), // 86
    NutTerm([-1,  0,  4,  0,  2],       1.0,       0.0,       0.0,       0.0), // 87
    NutTerm([ 1, -1,  0, -2,  0],       1.0,       0.0,       0.0,       0.0), // 88
    NutTerm([ 2,  0,  2, -2,  1],       1.0,       0.0,      -1.0,       0.0), // 89
    NutTerm([ 2,  0,  2,  2,  2],      -1.0,       0.0,       0.0,       0.0), // 90
    NutTerm([ 1,  0,  0,  2,  1],      -1.0,       0.0,       0.0,       0.0), // 91
    NutTerm([ 0,  0,  4, -2,  2],       1.0,       0.0,       0.0,       0.0), // 92
    NutTerm([ 3,  0,  2, -2,  2],       1.0,       0.0,       0.0,       0.0), // 93
    NutTerm([ 1,  0,  2, -2,  0],      -1.0,       0.0,       0.0,       0.0), // 94
    NutTerm([ 0,  1,  2,  0,  1],       1.0,       0.0,       0.0,       0.0), // 95
    NutTerm([-1, -1,  0,  2,  1],       1.0,       0.0,       0.0,       0.0), // 96
    NutTerm([ 0,  0, -2,  0,  1],      -1.0,       0.0,       0.0,       0.0), // 97
    NutTerm([ 0,  0,  2, -1,  2],      -1.0,       0.0,       0.0,       0.0), // 98
    NutTerm([ 0,  1,  0,  2,  0],      -1.0,       0.0,       0.0,       0.0), // 99
    NutTerm([ 1,  0, -2, -2,  0],      -1.0,       0.0,       0.0,       0.0), // 100
    NutTerm([ 0, -1,  2,  0,  1],      -1.0,       0.0,       0.0,       0.0), // 101
    NutTerm([ 1,  1,  0, -2,  1],      -1.0,       0.0,       0.0,       0.0), // 102
    NutTerm([ 1,  0, -2,  2,  0],      -1.0,       0.0,       0.0,       0.0), // 103
    NutTerm([ 2,  0,  0,  2,  0],       1.0,       0.0,       0.0,       0.0), // 104
    NutTerm([ 0,  0,  2,  4,  2],      -1.0,       0.0,       0.0,       0.0), // 105
    NutTerm([ 0,  1,  0,  1,  0],       1.0,       0.0,       0.0,       0.0), // 106
];

/// `e^{i k x}` for k = -4..=4 of one fundamental argument, as (cos, sin) pairs.
fn multiples(x: f64) -> [(f64, f64); 9] {
    let (s1, c1) = x.sin_cos();
    let mut out = [(1.0, 0.0); 9];
    // Positive multiples by complex multiplication; negative ones are conjugates.
    for k in 1..=4 {
        let (c, s) = out[4 + k - 1];
        out[4 + k] = (c * c1 - s * s1, s * c1 + c * s1);
        out[4 - k] = (out[4 + k].0, -out[4 + k].1);
    }
    out
}

/// IAU-80 nutation (106 terms, no corrections) and IAU-80 mean obliquity at a TT date.
///
/// The fundamental arguments are those of ERFA `nut80` (Explanatory Supplement 3.222); the
/// sines and cosines of each term come from products of the arguments' multiples, which
/// equals `sin`/`cos` of the summed argument to rounding.
pub fn nutation_iau80(jd_tt: JulianDate) -> Nutation80 {
    let t = jd_tt.centuries_since_j2000();
    let arg = |a0: f64, a1: f64, a2: f64, a3: f64, revs: f64| {
        ((a0 + (a1 + (a2 + a3 * t) * t) * t) * ARCSEC_TO_RAD + (revs * t % 1.0) * TAU) % TAU
    };
    // Mean anomaly of the Moon.
    let el = arg(485_866.733, 715_922.633, 31.310, 0.064, 1325.0);
    // Mean anomaly of the Sun.
    let elp = arg(1_287_099.804, 1_292_581.224, -0.577, -0.012, 99.0);
    // Mean argument of latitude of the Moon.
    let f = arg(335_778.877, 295_263.137, -13.257, 0.011, 1342.0);
    // Mean elongation of the Moon from the Sun.
    let d = arg(1_072_261.307, 1_105_601.328, -6.891, 0.019, 1236.0);
    // Longitude of the Moon's mean ascending node.
    let om = arg(450_160.280, -482_890.539, 7.455, 0.008, -5.0);
    let m = [
        multiples(el),
        multiples(elp),
        multiples(f),
        multiples(d),
        multiples(om),
    ];
    let (mut dp, mut de) = (0.0, 0.0);
    // Smallest terms first, as ERFA.
    for NutTerm(n, sp, spt, ce, cet) in NUT80.iter().rev() {
        let (mut c, mut s) = (1.0, 0.0);
        for (mult, table) in n.iter().zip(m.iter()) {
            if *mult != 0 {
                let (ck, sk) = table[(i32::from(*mult) + 4) as usize];
                (c, s) = (c * ck - s * sk, s * ck + c * sk);
            }
        }
        dp += (sp + spt * t) * s;
        de += (ce + cet * t) * c;
    }
    let u2r = ARCSEC_TO_RAD / 1e4;
    Nutation80 {
        dpsi_rad: dp * u2r,
        deps_rad: de * u2r,
        eps_mean_rad: mean_obliquity_iau80(jd_tt),
    }
}

/// A(J2000 <- TEME) at a UTC instant: `P76ᵀ N80ᵀ R3(-eqe)` (Vallado's `teme2eci`).
pub fn a_j2000_from_teme(t: UtcTime) -> Matrix3<f64> {
    a_j2000_from_teme_tt(t.jd_tt())
}

/// A(J2000 <- TEME) at a TT Julian date.
pub fn a_j2000_from_teme_tt(jd_tt: JulianDate) -> Matrix3<f64> {
    let p = precession_iau76(jd_tt);
    let n = nutation_iau80(jd_tt);
    p.transpose() * n.a_tod_from_mod().transpose() * rot3(-n.eqeq_geometric_rad())
}

/// A(J2000 <- TEME) for a stream of instants, interpolated linearly between its values at
/// the two ends of the UTC minute each instant falls in. Precession and nutation turn it
/// by about 1e-9 rad in a minute, smoothly (the shortest nutation periods are days), so
/// the chord is within 1e-6 m of the exact rotation at 7000 km (a test; in the minute that
/// ends at a leap second, whose end takes the new TT - UTC, about 5e-5 m), and the IAU-80
/// nutation series runs once a minute (twice for a jump to another minute) instead of at
/// every instant. For a once-a-second sampler; the FC's own environment steps its own
/// window.
#[derive(Debug, Default, Clone)]
pub struct J2000FromTemeByMinute {
    /// The minute (`unix_ns` / 60 s, rounded down) and the matrix at its start and end.
    minute: Option<(i64, [Matrix3<f64>; 2])>,
}

impl J2000FromTemeByMinute {
    const MINUTE_NS: i64 = 60_000_000_000;

    /// A(J2000 <- TEME) at `unix_ns` (UTC ns since the Unix epoch).
    pub fn at(&mut self, unix_ns: i64) -> Matrix3<f64> {
        let minute = unix_ns.div_euclid(Self::MINUTE_NS);
        let edge =
            |m: i64| a_j2000_from_teme(UtcTime::from_unix_ns(m.saturating_mul(Self::MINUTE_NS)));
        let [a0, a1] = match self.minute {
            Some((m, ends)) if m == minute => ends,
            // The next minute starts where the last one ended.
            Some((m, [_, end])) if m.checked_add(1) == Some(minute) => {
                [end, edge(minute.saturating_add(1))]
            }
            _ => [edge(minute), edge(minute.saturating_add(1))],
        };
        self.minute = Some((minute, [a0, a1]));
        let f = unix_ns.rem_euclid(Self::MINUTE_NS) as f64 / Self::MINUTE_NS as f64;
        a0 + (a1 - a0) * f
    }
}

/// Rotate a TEME state to ECI J2000 (Vallado's `teme2eci`; the rotation's own rate,
/// precession and nutation, is below 1e-11 rad/s and is neglected as in `teme2eci`).
pub fn teme_to_j2000(state_teme: &StateVector, t: UtcTime) -> StateVector {
    let a = a_j2000_from_teme(t);
    StateVector {
        r_km: a * state_teme.r_km,
        v_km_s: a * state_teme.v_km_s,
    }
}

/// Rotate an ECI J2000 state to TEME (Vallado's `eci2teme`).
pub fn j2000_to_teme(state_j2000: &StateVector, t: UtcTime) -> StateVector {
    let a = a_j2000_from_teme(t).transpose();
    StateVector {
        r_km: a * state_j2000.r_km,
        v_km_s: a * state_j2000.v_km_s,
    }
}

/// GMST (IAU-82) at `t` with UT1 - UTC from `eop` (UT1 = UTC without it), rad.
pub fn gmst82_at(t: UtcTime, eop: Option<&Eop>) -> f64 {
    gmst82(t.jd_ut1_from_dut1(eop.map_or(0.0, |e| e.ut1_minus_utc_s)))
}

/// Polar motion A(ITRF <- PEF) = `R1(-yp) R2(-xp)` (ERFA `pom00` with s' = 0); identity
/// without EOP.
pub fn a_ecef_from_pef(eop: Option<&Eop>) -> Matrix3<f64> {
    match eop {
        Some(e) => rot1(-e.yp_arcsec * ARCSEC_TO_RAD) * rot2(-e.xp_arcsec * ARCSEC_TO_RAD),
        None => Matrix3::identity(),
    }
}

/// A(ECEF <- TEME) = `W R3(GMST82)` at `t`.
pub fn a_ecef_from_teme(t: UtcTime, eop: Option<&Eop>) -> Matrix3<f64> {
    a_ecef_from_pef(eop) * rot3(gmst82_at(t, eop))
}

/// A(ECEF <- ECI J2000) at `t`.
pub fn a_ecef_from_eci(t: UtcTime, eop: Option<&Eop>) -> Matrix3<f64> {
    a_ecef_from_teme(t, eop) * a_j2000_from_teme(t).transpose()
}

/// A TEME state in ECEF (position, and velocity relative to the rotating Earth).
pub fn teme_to_ecef(state_teme: &StateVector, t: UtcTime, eop: Option<&Eop>) -> StateVector {
    let r3 = rot3(gmst82_at(t, eop));
    let w = a_ecef_from_pef(eop);
    let r_pef = r3 * state_teme.r_km;
    let v_pef = r3 * state_teme.v_km_s - Vector3::z().cross(&r_pef) * OMEGA_EARTH_RAD_S;
    StateVector {
        r_km: w * r_pef,
        v_km_s: w * v_pef,
    }
}

/// An ECEF state (velocity relative to the rotating Earth) in TEME.
pub fn ecef_to_teme(state_ecef: &StateVector, t: UtcTime, eop: Option<&Eop>) -> StateVector {
    let r3t = rot3(gmst82_at(t, eop)).transpose();
    let wt = a_ecef_from_pef(eop).transpose();
    let r_pef = wt * state_ecef.r_km;
    let v_pef = wt * state_ecef.v_km_s + Vector3::z().cross(&r_pef) * OMEGA_EARTH_RAD_S;
    StateVector {
        r_km: r3t * r_pef,
        v_km_s: r3t * v_pef,
    }
}

/// An ECI J2000 state in ECEF.
pub fn eci_to_ecef(state_eci: &StateVector, t: UtcTime, eop: Option<&Eop>) -> StateVector {
    teme_to_ecef(&j2000_to_teme(state_eci, t), t, eop)
}

/// An ECEF state in ECI J2000.
pub fn ecef_to_eci(state_ecef: &StateVector, t: UtcTime, eop: Option<&Eop>) -> StateVector {
    teme_to_j2000(&ecef_to_teme(state_ecef, t, eop), t)
}

/// A rotation matrix (orthonormal by construction) as a unit quaternion with w >= 0.
pub fn quaternion_from_matrix(a: &Matrix3<f64>) -> UnitQuaternion<f64> {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*a));
    canonical(q)
}

/// The same rotation with w >= 0.
pub fn canonical(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    if q.w < 0.0 {
        UnitQuaternion::new_unchecked(-q.into_inner())
    } else {
        q
    }
}

/// A(LVLH <- ECI) for an inertial state (ICD 1.4): rows Z = -r̂, Y = -ĥ, X = Y x Z.
pub fn a_lvlh_from_eci(r_eci_km: &Vector3<f64>, v_eci_km_s: &Vector3<f64>) -> Matrix3<f64> {
    let z = -r_eci_km.normalize();
    let y = -r_eci_km.cross(v_eci_km_s).normalize();
    let x = y.cross(&z);
    Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()])
}

/// A(TNW <- ECI) for an inertial state (ICD 1.4 axes): rows X = v̂, Y = ĥ, Z = X x Y.
pub fn a_tnw_from_eci(r_eci_km: &Vector3<f64>, v_eci_km_s: &Vector3<f64>) -> Matrix3<f64> {
    let x = v_eci_km_s.normalize();
    let y = r_eci_km.cross(v_eci_km_s).normalize();
    let z = x.cross(&y);
    Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()])
}

/// The attitude of LVLH in ECI, `q_eci_from_lvlh` (v_eci = q v_lvlh q*; frames.csv `lvlh_att`).
pub fn q_eci_from_lvlh(r_eci_km: &Vector3<f64>, v_eci_km_s: &Vector3<f64>) -> UnitQuaternion<f64> {
    quaternion_from_matrix(&a_lvlh_from_eci(r_eci_km, v_eci_km_s).transpose())
}

/// The attitude of TNW in ECI, `q_eci_from_tnw` (v_eci = q v_tnw q*; frames.csv `tnw_att`).
pub fn q_eci_from_tnw(r_eci_km: &Vector3<f64>, v_eci_km_s: &Vector3<f64>) -> UnitQuaternion<f64> {
    quaternion_from_matrix(&a_tnw_from_eci(r_eci_km, v_eci_km_s).transpose())
}

/// The body attitude in ECI from an ICD `pointECI r i j k` quaternion (normalised; `None` if
/// it is zero or not finite).
pub fn q_eci_from_body_point_eci(r: f64, i: f64, j: f64, k: f64) -> Option<UnitQuaternion<f64>> {
    let q = nalgebra::Quaternion::new(r, i, j, k);
    let n = q.norm();
    (n.is_finite() && n > 0.0).then(|| UnitQuaternion::new_unchecked(q / n))
}

/// The body attitude in ECI for an attitude given in LVLH (`pointLVLH`):
/// `q_eci_from_lvlh * q_lvlh_from_body`.
pub fn q_eci_from_body_via_lvlh(
    q_lvlh_from_body: &UnitQuaternion<f64>,
    r_eci_km: &Vector3<f64>,
    v_eci_km_s: &Vector3<f64>,
) -> UnitQuaternion<f64> {
    canonical(q_eci_from_lvlh(r_eci_km, v_eci_km_s) * q_lvlh_from_body)
}

/// The body attitude in ECI for an attitude given in TNW (`pointTNW`):
/// `q_eci_from_tnw * q_tnw_from_body`.
pub fn q_eci_from_body_via_tnw(
    q_tnw_from_body: &UnitQuaternion<f64>,
    r_eci_km: &Vector3<f64>,
    v_eci_km_s: &Vector3<f64>,
) -> UnitQuaternion<f64> {
    canonical(q_eci_from_tnw(r_eci_km, v_eci_km_s) * q_tnw_from_body)
}

/// A body vector in ECI: `q_eci_from_body * v_body`.
pub fn body_to_eci(q_eci_from_body: &UnitQuaternion<f64>, v_body: &Vector3<f64>) -> Vector3<f64> {
    q_eci_from_body * v_body
}

/// An ECI vector in the body frame: `q_eci_from_body⁻¹ * v_eci`.
pub fn eci_to_body(q_eci_from_body: &UnitQuaternion<f64>, v_eci: &Vector3<f64>) -> Vector3<f64> {
    q_eci_from_body.inverse_transform_vector(v_eci)
}

/// The smallest rotation `q_eci_from_body` that turns `axis_body` onto `target_eci`
/// (`pointGEO`'s body vector onto the line of sight); a half turn about a perpendicular axis
/// if they are opposite; `None` if either is zero or not finite.
pub fn q_eci_from_body_pointing(
    axis_body: &Vector3<f64>,
    target_eci: &Vector3<f64>,
) -> Option<UnitQuaternion<f64>> {
    let a = axis_body.try_normalize(0.0)?;
    let b = target_eci.try_normalize(0.0)?;
    if !(a.iter().chain(b.iter()).all(|x| x.is_finite())) {
        return None;
    }
    match UnitQuaternion::rotation_between(&a, &b) {
        Some(q) => Some(canonical(q)),
        None => {
            // Opposite: turn half a revolution about any axis perpendicular to `a`.
            let other = if a.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            let axis = nalgebra::Unit::new_normalize(a.cross(&other));
            Some(canonical(UnitQuaternion::from_axis_angle(
                &axis,
                std::f64::consts::PI,
            )))
        }
    }
}

/// The angle of the rotation between two attitudes, rad (0 when equal, sign-insensitive).
pub fn angle_between(q1: &UnitQuaternion<f64>, q2: &UnitQuaternion<f64>) -> f64 {
    q1.rotation_to(q2).angle()
}

snap::fields!(StateVector { r_km, v_km_s });
// The memo of the last minute's matrices: saved, so that a restored run multiplies by
// the same bits (a recomputation would give them, but a snapshot does not rely on it).
snap::fields!(J2000FromTemeByMinute { minute });

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Vector3<f64>, b: &Vector3<f64>, tol: f64) -> bool {
        (a - b).norm() < tol
    }

    /// The minute's chord is within 1e-6 m of the exact A(J2000 <- TEME) at 7000 km: every
    /// second of two hours across a year's end and before 1970 (where the minute rounds
    /// down), and near the end and in the middle of a minute every 20 minutes for 30 days
    /// (every phase of the fortnightly nutation), the minutes taken in order and out of it.
    #[test]
    fn the_minute_chord_is_within_a_micrometre_of_the_exact_rotation() {
        let mut a = J2000FromTemeByMinute::default();
        let r_teme_m = Vector3::new(4_000_000.0, -5_000_000.0, 4_747_000.0);
        let year_end = 1_798_761_600_000_000_000i64;
        let mut times: Vec<i64> = Vec::new();
        for start in [year_end - 3_600_000_000_000, -86_400_000_000_000] {
            times.extend((0..7200).map(|k| start + k * 1_000_000_000 + k % 7 * 123_456_789));
        }
        let every_20_min = |k: i64, at_ns: i64| year_end + k * 1_200_000_000_000 + at_ns;
        times.extend((0..2160).map(|k| every_20_min(k, 59_900_000_000)));
        times.extend((0..2160).rev().map(|k| every_20_min(k, 30_000_000_000)));
        let mut worst_m: f64 = 0.0;
        for unix_ns in times {
            let exact = a_j2000_from_teme(UtcTime::from_unix_ns(unix_ns));
            worst_m = worst_m.max((a.at(unix_ns) * r_teme_m - exact * r_teme_m).norm());
        }
        assert!(worst_m < 1e-6, "{worst_m} m");
        assert!(worst_m > 0.0, "interpolated, not exact");
    }

    #[test]
    #[allow(clippy::approx_constant)] // the ICD's literal digits
    fn icd_point_eci_example_puts_body_y_on_the_equinox() {
        // ICD 1.5: `pointECI 0.707106 0 0 -0.707106` = body y along the mean equinox, body z
        // along the celestial north pole.
        let q = q_eci_from_body_point_eci(0.707106, 0.0, 0.0, -0.707106)
            .unwrap_or_else(UnitQuaternion::identity);
        assert!(close(&body_to_eci(&q, &Vector3::y()), &Vector3::x(), 1e-12));
        assert!(close(&body_to_eci(&q, &Vector3::z()), &Vector3::z(), 1e-12));
        // And body x goes to -y (right-handed).
        assert!(close(
            &body_to_eci(&q, &Vector3::x()),
            &-Vector3::y(),
            1e-12
        ));
        assert!(close(&eci_to_body(&q, &Vector3::x()), &Vector3::y(), 1e-12));
        // `pointECI 1 0 0 0` is the identity.
        let id = q_eci_from_body_point_eci(1.0, 0.0, 0.0, 0.0).unwrap_or_default();
        assert_eq!(angle_between(&id, &UnitQuaternion::identity()), 0.0);
        assert!(q_eci_from_body_point_eci(0.0, 0.0, 0.0, 0.0).is_none());
    }

    #[test]
    fn lvlh_and_tnw_axes() {
        let r = Vector3::new(7000.0, 0.0, 0.0);
        let v = Vector3::new(0.0, 7.5, 0.0);
        let q = q_eci_from_lvlh(&r, &v);
        // LVLH z to the Earth's centre, x along velocity, y opposite the momentum.
        assert!(close(&(q * Vector3::z()), &-Vector3::x(), 1e-12));
        assert!(close(&(q * Vector3::x()), &Vector3::y(), 1e-12));
        assert!(close(&(q * Vector3::y()), &-Vector3::z(), 1e-12));
        let q = q_eci_from_tnw(&r, &v);
        assert!(close(&(q * Vector3::x()), &Vector3::y(), 1e-12));
        assert!(close(&(q * Vector3::y()), &Vector3::z(), 1e-12));
        // TNW z = x cross y points to zenith here.
        assert!(close(&(q * Vector3::z()), &Vector3::x(), 1e-12));
        // pointLVLH 1 0 0 0 is the LVLH frame itself.
        let body = q_eci_from_body_via_lvlh(&UnitQuaternion::identity(), &r, &v);
        assert!(angle_between(&body, &q_eci_from_lvlh(&r, &v)) < 1e-12);
    }

    #[test]
    fn pointing_turns_the_axis_onto_the_target() {
        let target = Vector3::new(1.0, 2.0, -3.0);
        for axis in [Vector3::z(), Vector3::new(0.0, 0.0, -1.0), -target] {
            let q = q_eci_from_body_pointing(&axis, &target).unwrap_or_default();
            assert!(close(&(q * axis.normalize()), &target.normalize(), 1e-12));
        }
        assert!(q_eci_from_body_pointing(&Vector3::zeros(), &target).is_none());
    }

    #[test]
    fn teme_j2000_round_trip() {
        let t = UtcTime::from_iso8601("2024-03-15T12:00:00").unwrap_or_default();
        let s = StateVector {
            r_km: Vector3::new(4123.0, -1003.0, 5293.0),
            v_km_s: Vector3::new(2.5, 7.2, -0.58),
        };
        let back = j2000_to_teme(&teme_to_j2000(&s, t), t);
        assert!(close(&back.r_km, &s.r_km, 1e-9));
        let back = ecef_to_eci(&eci_to_ecef(&s, t, None), t, None);
        assert!(close(&back.r_km, &s.r_km, 1e-9));
        assert!(close(&back.v_km_s, &s.v_km_s, 1e-12));
    }
}
