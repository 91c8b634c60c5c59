//! WGS-84 geodetic coordinates (latitude, longitude, height above the ellipsoid) and ECEF.
//!
//! # Model
//! - Ellipsoid: WGS-84, a = 6 378 137 m, 1/f = 298.257 223 563 (NGA.STND.0036, 2014).
//! - Forward: the closed form `x = (N + h) cos φ cos λ`, `y = (N + h) cos φ sin λ`,
//!   `z = (N (1 - e²) + h) sin φ`, `N = a / sqrt(1 - e² sin²φ)`.
//! - Inverse: Bowring's (1976) parametric-latitude iteration, run to convergence (|Δ| below
//!   1e-15 rad, two to four passes above the evolute; at most 16), then the height from
//!   `h = p cos φ + z sin φ - a sqrt(1 - e² sin²φ)`, which holds at every latitude. This is
//!   exact to floating-point rounding (well under 1 mm, also at GEO heights and at the poles,
//!   where p = 0 gives φ = ±90° and h = |z| - b).
//! - Longitude is `atan2(y, x)` in (-π, π]; on the polar axis it is 0 (arbitrary there).
//!
//! # Frames
//! ECEF here is the Earth-fixed frame of [`crate::frames`] (ITRF when polar motion is given,
//! PEF otherwise). [`a_ned_from_ecef`] and [`a_enu_from_ecef`] give the local level frames.
//!
//! # Invariants
//! Pure, allocation free, never panics; the inverse of the forward is the identity to
//! rounding everywhere except inside about 43 km of the Earth's centre (the evolute), where
//! geodetic coordinates are not unique.

use nalgebra::{Matrix3, Vector3};

/// WGS-84 semi-major axis, m (NGA.STND.0036).
pub const WGS84_A_M: f64 = 6_378_137.0;
/// WGS-84 flattening (NGA.STND.0036).
pub const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// WGS-84 first eccentricity squared, `f (2 - f)`.
pub const WGS84_E2: f64 = WGS84_F * (2.0 - WGS84_F);
/// WGS-84 semi-minor axis, m.
pub const WGS84_B_M: f64 = WGS84_A_M * (1.0 - WGS84_F);

/// A WGS-84 geodetic position.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Geodetic {
    /// Geodetic latitude, rad (north positive).
    pub lat_rad: f64,
    /// Longitude, rad (east positive).
    pub lon_rad: f64,
    /// Height above the ellipsoid, m.
    pub alt_m: f64,
}

impl Geodetic {
    /// From latitude and longitude in degrees and height in metres.
    pub fn from_deg(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Self {
        Geodetic {
            lat_rad: lat_deg.to_radians(),
            lon_rad: lon_deg.to_radians(),
            alt_m,
        }
    }

    /// Latitude, deg.
    pub fn lat_deg(&self) -> f64 {
        self.lat_rad.to_degrees()
    }

    /// Longitude, deg.
    pub fn lon_deg(&self) -> f64 {
        self.lon_rad.to_degrees()
    }

    /// ECEF position, m.
    pub fn to_ecef_m(&self) -> Vector3<f64> {
        geodetic_to_ecef_m(self)
    }

    /// ECEF position, km.
    pub fn to_ecef_km(&self) -> Vector3<f64> {
        geodetic_to_ecef_m(self) * 1e-3
    }
}

/// ECEF position (m) of a geodetic position.
pub fn geodetic_to_ecef_m(g: &Geodetic) -> Vector3<f64> {
    let (sin_lat, cos_lat) = g.lat_rad.sin_cos();
    let (sin_lon, cos_lon) = g.lon_rad.sin_cos();
    let n = WGS84_A_M / (1.0 - WGS84_E2 * sin_lat * sin_lat).sqrt();
    Vector3::new(
        (n + g.alt_m) * cos_lat * cos_lon,
        (n + g.alt_m) * cos_lat * sin_lon,
        (n * (1.0 - WGS84_E2) + g.alt_m) * sin_lat,
    )
}

/// Geodetic position of an ECEF position (m).
pub fn ecef_m_to_geodetic(r_ecef_m: &Vector3<f64>) -> Geodetic {
    let (x, y, z) = (r_ecef_m.x, r_ecef_m.y, r_ecef_m.z);
    let p = x.hypot(y);
    let lon_rad = if p > 0.0 { y.atan2(x) } else { 0.0 };
    // Second eccentricity squared, e'² = e² / (1 - e²).
    let ep2 = WGS84_E2 / (1.0 - WGS84_E2);
    let one_minus_f = 1.0 - WGS84_F;
    // Parametric (reduced) latitude β; start from the spherical guess.
    let mut beta = z.atan2(one_minus_f * p);
    let mut lat_rad = beta;
    for _ in 0..16 {
        let (sb, cb) = beta.sin_cos();
        lat_rad =
            (z + ep2 * WGS84_B_M * sb * sb * sb).atan2(p - WGS84_E2 * WGS84_A_M * cb * cb * cb);
        let next = (one_minus_f * lat_rad.sin()).atan2(lat_rad.cos());
        let done = (next - beta).abs() < 1e-15;
        beta = next;
        if done {
            break;
        }
    }
    let (sin_lat, cos_lat) = lat_rad.sin_cos();
    let alt_m = p * cos_lat + z * sin_lat - WGS84_A_M * (1.0 - WGS84_E2 * sin_lat * sin_lat).sqrt();
    Geodetic {
        lat_rad,
        lon_rad,
        alt_m,
    }
}

/// Geodetic position of an ECEF position (km).
pub fn ecef_km_to_geodetic(r_ecef_km: &Vector3<f64>) -> Geodetic {
    ecef_m_to_geodetic(&(r_ecef_km * 1e3))
}

/// A(NED <- ECEF) at a geodetic latitude and longitude: rows are north, east, down in ECEF.
pub fn a_ned_from_ecef(lat_rad: f64, lon_rad: f64) -> Matrix3<f64> {
    let (sl, cl) = lat_rad.sin_cos();
    let (so, co) = lon_rad.sin_cos();
    Matrix3::new(
        -sl * co,
        -sl * so,
        cl, //
        -so,
        co,
        0.0, //
        -cl * co,
        -cl * so,
        -sl,
    )
}

/// A(ENU <- ECEF) at a geodetic latitude and longitude: rows are east, north, up in ECEF.
pub fn a_enu_from_ecef(lat_rad: f64, lon_rad: f64) -> Matrix3<f64> {
    let (sl, cl) = lat_rad.sin_cos();
    let (so, co) = lon_rad.sin_cos();
    Matrix3::new(
        -so,
        co,
        0.0, //
        -sl * co,
        -sl * so,
        cl, //
        cl * co,
        cl * so,
        sl,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_everywhere_outside_the_evolute() {
        let mut worst = 0.0_f64;
        for lat in (-90..=90).step_by(5) {
            for h in [-5_000.0, 0.0, 400e3, 20_200e3, 35_786e3] {
                let g = Geodetic::from_deg(f64::from(lat), 33.0, h);
                let r = geodetic_to_ecef_m(&g);
                let back = geodetic_to_ecef_m(&ecef_m_to_geodetic(&r));
                worst = worst.max((back - r).norm());
            }
        }
        assert!(worst < 1e-6, "{worst} m");
    }

    #[test]
    fn poles_and_centre() {
        let g = ecef_m_to_geodetic(&Vector3::new(0.0, 0.0, -7_000e3));
        assert_eq!(g.lat_rad, -std::f64::consts::FRAC_PI_2);
        assert!((g.alt_m - (7_000e3 - WGS84_B_M)).abs() < 1e-6);
        let c = ecef_m_to_geodetic(&Vector3::zeros());
        assert!(c.alt_m.is_finite() && c.lat_rad.is_finite());
        let n = ecef_m_to_geodetic(&Vector3::new(f64::NAN, 0.0, 0.0));
        assert!(n.alt_m.is_nan());
    }

    #[test]
    fn local_frames_are_consistent() {
        let a = a_ned_from_ecef(0.3, -1.2);
        let e = a_enu_from_ecef(0.3, -1.2);
        assert!((a.row(0) - e.row(1)).norm() < 1e-15);
        assert!((a.row(2) + e.row(2)).norm() < 1e-15);
        assert!((a * a.transpose() - Matrix3::identity()).norm() < 1e-15);
    }
}
