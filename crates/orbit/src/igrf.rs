//! The geomagnetic main field from IGRF-14 (degree and order 13) with its secular
//! variation, evaluated at a geodetic or an Earth-fixed point and returned in NED (relative to
//! the WGS-84 ellipsoid), ECEF and, given the Earth's rotation, ECI.
//!
//! Model: the 14th generation International Geomagnetic Reference Field (IAGA Working Group
//! V-MOD, Alken et al. 2025, <https://doi.org/10.5281/zenodo.14012302>), Schmidt
//! semi-normalised Gauss coefficients `g_n^m`, `h_n^m` in nT for a reference sphere of radius
//! 6371.2 km. The coefficient file `igrf14coeffs.txt` is embedded unmodified from
//! `crates/orbit/data/` (official source:
//! <https://www.ngdc.noaa.gov/IAGA/vmod/coeffs/igrf14coeffs.txt>; see `data/README.md` for
//! the copy's provenance and checksum) and parsed once, at first use, into an immutable
//! table ([`std::sync::OnceLock`]; no mutable global state).
//!
//! Time: `decimal_year` is the year Y plus the elapsed fraction of year Y (as
//! [`crate::time::UtcTime::decimal_year`]). Between the 2020.0 (DGRF) and 2025.0 (IGRF)
//! epochs the coefficients are interpolated linearly; from 2025.0 to 2030.0 they follow the
//! predictive secular variation (nT/yr, degree 8). These are the IGRF-14 rules.
//!
//! Validity: 2020.0 to 2030.0 inclusive. Outside it every function returns
//! [`FieldError::OutOfRange`]: nothing is extrapolated silently. (IGRF-14 itself starts in
//! 1900; the twin embeds it whole but evaluates only its own mission window, where it is
//! tested.) A caller who wants a field anyway must clamp the year itself and say so.
//!
//! ECI: ECI J2000 as in [`crate::frames`] ([`field_eci_at`], or [`GaussCoefficients::field_eci`]
//! with a rotation the caller computes once per step). The reference's GCRS components differ
//! from it by the frame realisation (about 0.1 microradian) and, without Earth-orientation
//! data, by UT1 - UTC (up to 0.9 s of Earth rotation, 6.6e-5 rad, i.e. up to 3 nT).
//!
//! Invariants: the field is finite everywhere outside the Earth's centre, poles included (the
//! `P_n^m / sin(theta)` terms are computed by their own recursion, never by division); the
//! NED frame is that of the geodetic latitude (down along the ellipsoid normal; WGS-84
//! conversions from [`crate::geodetic`]); ECEF is the Earth-fixed frame of the coefficients
//! (ITRS). No allocation per evaluation.
//!
//! Accuracy (`tests/igrf_ref.rs`, 50 points of ppigrf/pyigrf14): geocentric components
//! within 2.5e-10 nT, NED and ECEF within 2.5e-4 nT (the reference's own geodetic
//! conversion), against the 1 nT.

use std::sync::OnceLock;

use nalgebra::{Matrix3, Vector3};

use crate::frames;
use crate::geodetic::{Geodetic, a_ned_from_ecef, ecef_km_to_geodetic};
use crate::time::{Eop, UtcTime};

/// Maximum degree and order of the main field.
pub const MAX_DEGREE: usize = 13;

/// IGRF reference radius, km (the "magnetic reference spherical radius" of IGRF).
pub const REFERENCE_RADIUS_KM: f64 = 6371.2;

/// First decimal year at which the field is evaluated (the DGRF-2020 epoch).
pub const VALID_FROM_YEAR: f64 = 2020.0;

/// Last decimal year at which the field is evaluated (end of IGRF-14's predictive secular
/// variation).
pub const VALID_UNTIL_YEAR: f64 = 2030.0;

/// The official IGRF-14 coefficient file, unmodified.
const IGRF14_COEFFS: &str = include_str!("../data/igrf14coeffs.txt");

const N: usize = MAX_DEGREE + 1;

/// Why the field could not be evaluated.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FieldError {
    /// The time is outside IGRF-14's 2020.0-2030.0 window as the twin uses it.
    #[error("decimal year {decimal_year} is outside the IGRF-14 window 2020.0-2030.0")]
    OutOfRange {
        /// The requested decimal year.
        decimal_year: f64,
    },
    /// The position is at the Earth's centre or not finite.
    #[error("position at the Earth's centre or not finite")]
    BadPosition,
}

/// Schmidt semi-normalised Gauss coefficients at one epoch, nT, indexed `[n][m]`.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussCoefficients {
    g_nt: [[f64; N]; N],
    h_nt: [[f64; N]; N],
    /// `g_nt` and `h_nt` times the Schmidt factors, for Gauss-normalised Legendre functions.
    g_gauss_nt: [[f64; N]; N],
    h_gauss_nt: [[f64; N]; N],
}

/// The parsed coefficient file: the two epochs the twin needs and the secular variation.
#[derive(Debug)]
struct Igrf14 {
    epoch_2020: GaussCoefficients,
    epoch_2025: GaussCoefficients,
    /// Secular variation 2025-2030, nT/yr.
    sv_2025: GaussCoefficients,
}

/// The field at one point, in three frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldSample {
    /// North, east, down relative to the WGS-84 ellipsoid at the point, nT.
    pub b_ned_nt: Vector3<f64>,
    /// Earth-fixed (ITRS) components, nT.
    pub b_ecef_nt: Vector3<f64>,
    /// Geocentric spherical components (radial up, colatitude south, longitude east), nT.
    pub b_rtp_nt: Vector3<f64>,
}

impl FieldSample {
    /// The field in ECI, nT, given the rotation `a_eci_from_ecef` (v_eci = A v_ecef; the
    /// transpose of [`frames::a_ecef_from_eci`]).
    pub fn b_eci_nt(&self, a_eci_from_ecef: &Matrix3<f64>) -> Vector3<f64> {
        a_eci_from_ecef * self.b_ecef_nt
    }
}

/// The field at an inertial point: the Earth-fixed sample and its ECI J2000 components.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldSampleEci {
    /// ECI J2000 components, nT.
    pub b_eci_nt: Vector3<f64>,
    /// The same field in NED, ECEF and geocentric spherical components.
    pub sample: FieldSample,
}

impl GaussCoefficients {
    const ZERO: GaussCoefficients = GaussCoefficients {
        g_nt: [[0.0; N]; N],
        h_nt: [[0.0; N]; N],
        g_gauss_nt: [[0.0; N]; N],
        h_gauss_nt: [[0.0; N]; N],
    };

    /// IGRF-14 coefficients at `decimal_year` (2020.0 to 2030.0).
    pub fn igrf14(decimal_year: f64) -> Result<GaussCoefficients, FieldError> {
        if !(VALID_FROM_YEAR..=VALID_UNTIL_YEAR).contains(&decimal_year) {
            return Err(FieldError::OutOfRange { decimal_year });
        }
        let model = model();
        let mut out = GaussCoefficients::ZERO;
        for n in 1..N {
            for m in 0..=n {
                let (g, h) = if decimal_year < 2025.0 {
                    let w = (decimal_year - 2020.0) / 5.0;
                    let lerp = |a: f64, b: f64| a + w * (b - a);
                    (
                        lerp(model.epoch_2020.g_nt[n][m], model.epoch_2025.g_nt[n][m]),
                        lerp(model.epoch_2020.h_nt[n][m], model.epoch_2025.h_nt[n][m]),
                    )
                } else {
                    let dt = decimal_year - 2025.0;
                    (
                        model.epoch_2025.g_nt[n][m] + dt * model.sv_2025.g_nt[n][m],
                        model.epoch_2025.h_nt[n][m] + dt * model.sv_2025.h_nt[n][m],
                    )
                };
                out.g_nt[n][m] = g;
                out.h_nt[n][m] = h;
                out.g_gauss_nt[n][m] = g * schmidt_factors()[n][m];
                out.h_gauss_nt[n][m] = h * schmidt_factors()[n][m];
            }
        }
        Ok(out)
    }

    /// The coefficient `g_n^m`, nT (0 outside 1 <= n <= 13, m <= n).
    pub fn g_nt(&self, n: usize, m: usize) -> f64 {
        self.g_nt
            .get(n)
            .and_then(|r| r.get(m))
            .copied()
            .unwrap_or(0.0)
    }

    /// The coefficient `h_n^m`, nT (0 outside 1 <= n <= 13, 1 <= m <= n).
    pub fn h_nt(&self, n: usize, m: usize) -> f64 {
        self.h_nt
            .get(n)
            .and_then(|r| r.get(m))
            .copied()
            .unwrap_or(0.0)
    }

    /// The field at an Earth-fixed position, km; NED is relative to the WGS-84 ellipsoid.
    pub fn field_ecef(&self, r_ecef_km: &Vector3<f64>) -> Result<FieldSample, FieldError> {
        let g = ecef_km_to_geodetic(r_ecef_km);
        self.field_at(r_ecef_km, g.lat_rad, g.lon_rad)
    }

    /// The field at an ECI J2000 position, km, given A(ECEF <- ECI) at that instant (for
    /// example [`frames::a_ecef_from_eci`], computed once per step and shared).
    pub fn field_eci(
        &self,
        r_eci_km: &Vector3<f64>,
        a_ecef_from_eci: &Matrix3<f64>,
    ) -> Result<FieldSampleEci, FieldError> {
        let sample = self.field_ecef(&(a_ecef_from_eci * r_eci_km))?;
        Ok(FieldSampleEci {
            b_eci_nt: a_ecef_from_eci.tr_mul(&sample.b_ecef_nt),
            sample,
        })
    }

    /// The field at a WGS-84 geodetic point: latitude and longitude (east) in radians,
    /// height above the ellipsoid in km.
    pub fn field_geodetic(
        &self,
        lat_gd_rad: f64,
        lon_rad: f64,
        alt_km: f64,
    ) -> Result<FieldSample, FieldError> {
        let g = Geodetic {
            lat_rad: lat_gd_rad,
            lon_rad,
            alt_m: alt_km * 1e3,
        };
        self.field_at(&g.to_ecef_km(), lat_gd_rad, lon_rad)
    }

    fn field_at(
        &self,
        r_ecef_km: &Vector3<f64>,
        lat_gd_rad: f64,
        lon_rad: f64,
    ) -> Result<FieldSample, FieldError> {
        let r_km = r_ecef_km.norm();
        if !(r_km.is_finite() && r_km > 0.0) {
            return Err(FieldError::BadPosition);
        }
        let rho = r_ecef_km.x.hypot(r_ecef_km.y);
        let (sin_t, cos_t) = (rho / r_km, r_ecef_km.z / r_km);
        // On the polar axis the longitude is arbitrary: use the caller's.
        let (sin_p, cos_p) = if rho > 0.0 {
            (r_ecef_km.y / rho, r_ecef_km.x / rho)
        } else {
            lon_rad.sin_cos()
        };
        let b_rtp_nt = self.field_spherical(r_km, sin_t, cos_t, sin_p, cos_p);
        let r_hat = Vector3::new(sin_t * cos_p, sin_t * sin_p, cos_t);
        let t_hat = Vector3::new(cos_t * cos_p, cos_t * sin_p, -sin_t);
        let p_hat = Vector3::new(-sin_p, cos_p, 0.0);
        let b_ecef_nt = r_hat * b_rtp_nt.x + t_hat * b_rtp_nt.y + p_hat * b_rtp_nt.z;

        let b_ned_nt = a_ned_from_ecef(lat_gd_rad, lon_rad) * b_ecef_nt;
        Ok(FieldSample {
            b_ned_nt,
            b_ecef_nt,
            b_rtp_nt,
        })
    }

    /// Geocentric spherical components (B_r, B_theta, B_phi), nT, at radius `r_km` > 0,
    /// colatitude theta and longitude phi given by their sines and cosines.
    fn field_spherical(&self, r_km: f64, st: f64, ct: f64, sp: f64, cp: f64) -> Vector3<f64> {
        let k = recursion_factors();

        // Gauss-normalised associated Legendre functions P[n][m](cos theta), their theta
        // derivatives dP, and Q[n][m] = P[n][m] / sin(theta) for m >= 1 (its own
        // recursion: finite at the poles).
        let mut p = [[0.0; N]; N];
        let mut dp = [[0.0; N]; N];
        let mut q = [[0.0; N]; N];
        p[0][0] = 1.0;
        for n in 1..N {
            for m in 0..=n {
                if m == n {
                    p[n][n] = st * p[n - 1][n - 1];
                    dp[n][n] = st * dp[n - 1][n - 1] + ct * p[n - 1][n - 1];
                    q[n][n] = if n == 1 { 1.0 } else { st * q[n - 1][n - 1] };
                } else {
                    let (p2, dp2, q2) = if n >= 2 {
                        (p[n - 2][m], dp[n - 2][m], q[n - 2][m])
                    } else {
                        (0.0, 0.0, 0.0)
                    };
                    p[n][m] = ct * p[n - 1][m] - k[n][m] * p2;
                    dp[n][m] = ct * dp[n - 1][m] - st * p[n - 1][m] - k[n][m] * dp2;
                    q[n][m] = ct * q[n - 1][m] - k[n][m] * q2;
                }
            }
        }

        // cos(m phi), sin(m phi) by the angle-addition recursion.
        let mut cos_m = [0.0; N];
        let mut sin_m = [0.0; N];
        cos_m[0] = 1.0;
        for m in 1..N {
            cos_m[m] = cos_m[m - 1] * cp - sin_m[m - 1] * sp;
            sin_m[m] = sin_m[m - 1] * cp + cos_m[m - 1] * sp;
        }

        let ratio = REFERENCE_RADIUS_KM / r_km;
        let mut ratio_pow = ratio * ratio; // (a/r)^(n+2) for n = 0
        let (mut b_r, mut b_t, mut b_p) = (0.0, 0.0, 0.0);
        for n in 1..N {
            ratio_pow *= ratio;
            let (mut sr, mut st_, mut sp_) = (0.0, 0.0, 0.0);
            for m in 0..=n {
                let (g, h) = (self.g_gauss_nt[n][m], self.h_gauss_nt[n][m]);
                let gh_cos = g * cos_m[m] + h * sin_m[m];
                sr += gh_cos * p[n][m];
                st_ += gh_cos * dp[n][m];
                if m > 0 {
                    sp_ += m as f64 * (g * sin_m[m] - h * cos_m[m]) * q[n][m];
                }
            }
            b_r += (n as f64 + 1.0) * ratio_pow * sr;
            b_t -= ratio_pow * st_;
            b_p += ratio_pow * sp_;
        }
        Vector3::new(b_r, b_t, b_p)
    }
}

/// `K[n][m] = ((n-1)^2 - m^2) / ((2n-1)(2n-3))` for the Gauss-normalised Legendre recursion.
fn recursion_factors() -> &'static [[f64; N]; N] {
    static K: OnceLock<[[f64; N]; N]> = OnceLock::new();
    K.get_or_init(|| {
        let mut k = [[0.0; N]; N];
        for (n, row) in k.iter_mut().enumerate().skip(2) {
            for (m, v) in row.iter_mut().enumerate().take(n + 1) {
                let (nf, mf) = (n as f64, m as f64);
                *v = ((nf - 1.0).powi(2) - mf * mf) / ((2.0 * nf - 1.0) * (2.0 * nf - 3.0));
            }
        }
        k
    })
}

/// Factors from Gauss-normalised to Schmidt semi-normalised Legendre functions.
fn schmidt_factors() -> &'static [[f64; N]; N] {
    static S: OnceLock<[[f64; N]; N]> = OnceLock::new();
    S.get_or_init(|| {
        let mut s = [[0.0; N]; N];
        s[0][0] = 1.0;
        for n in 1..N {
            let nf = n as f64;
            s[n][0] = s[n - 1][0] * (2.0 * nf - 1.0) / nf;
            for m in 1..=n {
                let mf = m as f64;
                let delta = if m == 1 { 2.0 } else { 1.0 };
                s[n][m] = s[n][m - 1] * ((nf - mf + 1.0) * delta / (nf + mf)).sqrt();
            }
        }
        s
    })
}

/// The parsed embedded coefficient file.
fn model() -> &'static Igrf14 {
    static MODEL: OnceLock<Igrf14> = OnceLock::new();
    MODEL.get_or_init(|| {
        parse(IGRF14_COEFFS).expect("the embedded IGRF-14 file parses (checked by unit tests)")
    })
}

/// Why the coefficient file did not parse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
enum CoeffFileError {
    #[error("no `g/h n m` header line")]
    NoHeader,
    #[error("no column {0}")]
    NoColumn(String),
    /// A `g`/`h` row is malformed; `what` names the part.
    #[error("line {line}: {what}")]
    BadRow { line: usize, what: &'static str },
    #[error("{seen} coefficient rows, expected 195")]
    RowCount { seen: usize },
}

/// Parse `igrf14coeffs.txt`: find the 2020.0, 2025.0 and `2025-30` columns by their header
/// and read every `g`/`h` row.
fn parse(text: &str) -> Result<Igrf14, CoeffFileError> {
    let header = text
        .lines()
        .find(|l| l.starts_with("g/h"))
        .ok_or(CoeffFileError::NoHeader)?;
    let cols: Vec<&str> = header.split_whitespace().collect();
    let find = |name: &str| {
        cols.iter()
            .position(|c| *c == name)
            .ok_or_else(|| CoeffFileError::NoColumn(name.to_owned()))
    };
    let (i2020, i2025, isv) = (find("2020.0")?, find("2025.0")?, find("2025-30")?);
    let mut model = Igrf14 {
        epoch_2020: GaussCoefficients::ZERO,
        epoch_2025: GaussCoefficients::ZERO,
        sv_2025: GaussCoefficients::ZERO,
    };
    let mut seen = 0;
    for (line_no, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let kind = match fields.first() {
            Some(&"g") => 'g',
            Some(&"h") => 'h',
            _ => continue,
        };
        let bad = |what: &'static str| CoeffFileError::BadRow {
            line: line_no + 1,
            what,
        };
        if fields.len() != cols.len() {
            return Err(bad("wrong number of columns"));
        }
        let n: usize = fields[1].parse().map_err(|_| bad("degree"))?;
        let m: usize = fields[2].parse().map_err(|_| bad("order"))?;
        if !(1..=MAX_DEGREE).contains(&n) || m > n || (kind == 'h' && m == 0) {
            return Err(bad("degree/order out of range"));
        }
        let value = |i: usize| fields[i].parse::<f64>().map_err(|_| bad("coefficient"));
        for (target, i) in [
            (&mut model.epoch_2020, i2020),
            (&mut model.epoch_2025, i2025),
            (&mut model.sv_2025, isv),
        ] {
            let table = if kind == 'g' {
                &mut target.g_nt
            } else {
                &mut target.h_nt
            };
            table[n][m] = value(i)?;
        }
        seen += 1;
    }
    // 104 g (n = 1..13, m = 0..n) and 91 h (m = 1..n) coefficients.
    if seen != 195 {
        return Err(CoeffFileError::RowCount { seen });
    }
    Ok(model)
}

/// The field at a WGS-84 geodetic point (lat, lon east in rad, height in km) and decimal year.
pub fn field_geodetic(
    lat_gd_rad: f64,
    lon_rad: f64,
    alt_km: f64,
    decimal_year: f64,
) -> Result<FieldSample, FieldError> {
    GaussCoefficients::igrf14(decimal_year)?.field_geodetic(lat_gd_rad, lon_rad, alt_km)
}

/// The field at an Earth-fixed position (km) and decimal year.
pub fn field_ecef(r_ecef_km: &Vector3<f64>, decimal_year: f64) -> Result<FieldSample, FieldError> {
    GaussCoefficients::igrf14(decimal_year)?.field_ecef(r_ecef_km)
}

/// The field at a WGS-84 geodetic point at the UTC instant `t`.
pub fn field_geodetic_at(
    t: UtcTime,
    lat_gd_rad: f64,
    lon_rad: f64,
    alt_km: f64,
) -> Result<FieldSample, FieldError> {
    field_geodetic(lat_gd_rad, lon_rad, alt_km, t.decimal_year())
}

/// The field at an Earth-fixed position (km) at the UTC instant `t`.
pub fn field_ecef_at(t: UtcTime, r_ecef_km: &Vector3<f64>) -> Result<FieldSample, FieldError> {
    field_ecef(r_ecef_km, t.decimal_year())
}

/// The field at an ECI J2000 position (km) at the UTC instant `t`, with the Earth's
/// orientation from [`frames::a_ecef_from_eci`] (UT1 = UTC and no polar motion without `eop`).
pub fn field_eci_at(
    t: UtcTime,
    r_eci_km: &Vector3<f64>,
    eop: Option<&Eop>,
) -> Result<FieldSampleEci, FieldError> {
    GaussCoefficients::igrf14(t.decimal_year())?
        .field_eci(r_eci_km, &frames::a_ecef_from_eci(t, eop))
}

snap::fields!(GaussCoefficients {
    g_nt,
    h_nt,
    g_gauss_nt,
    h_gauss_nt
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_file_parses_with_known_values() {
        let m = parse(IGRF14_COEFFS).expect("parses");
        // Spot values from the file (g 1 0 at 2020 and 2025, its SV; h 13 13 at 2025).
        assert_eq!(m.epoch_2020.g_nt[1][0], -29403.41);
        assert_eq!(m.epoch_2025.h_nt[13][13], -0.5);
        assert!(m.sv_2025.g_nt[1][0] != 0.0);
        // Secular variation stops at degree 8.
        assert!(m.sv_2025.g_nt[9].iter().all(|&v| v == 0.0));
    }

    #[test]
    fn outside_2020_2030_is_an_error_not_an_extrapolation() {
        for y in [2019.999, 2030.001, f64::NAN] {
            assert!(matches!(
                field_geodetic(0.0, 0.0, 500.0, y),
                Err(FieldError::OutOfRange { .. })
            ));
        }
        assert!(field_geodetic(0.0, 0.0, 500.0, 2020.0).is_ok());
        assert!(field_geodetic(0.0, 0.0, 500.0, 2030.0).is_ok());
    }

    #[test]
    fn continuous_at_2025() {
        let before = field_geodetic(0.5, 0.3, 500.0, 2025.0 - 1e-9).expect("in range");
        let after = field_geodetic(0.5, 0.3, 500.0, 2025.0).expect("in range");
        assert!((before.b_ned_nt - after.b_ned_nt).norm() < 1e-4);
    }

    #[test]
    fn exact_poles_are_finite_and_agree_with_ecef_input() {
        for lat in [std::f64::consts::FRAC_PI_2, -std::f64::consts::FRAC_PI_2] {
            for lon in [0.0, 1.0, -2.5] {
                let f = field_geodetic(lat, lon, 500.0, 2026.0).expect("in range");
                assert!(
                    f.b_ned_nt
                        .iter()
                        .chain(f.b_ecef_nt.iter())
                        .all(|v| v.is_finite())
                );
                // The ECEF field at the pole does not depend on the longitude label.
                let f0 = field_geodetic(lat, 0.0, 500.0, 2026.0).expect("in range");
                assert!((f.b_ecef_nt - f0.b_ecef_nt).norm() < 1e-6);
            }
            let r = Vector3::new(0.0, 0.0, lat.signum() * 6856.752);
            let f = field_ecef(&r, 2026.0).expect("in range");
            assert!(f.b_ned_nt.iter().all(|v| v.is_finite()));
        }
        assert_eq!(
            field_ecef(&Vector3::zeros(), 2026.0),
            Err(FieldError::BadPosition)
        );
    }
}
