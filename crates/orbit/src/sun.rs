//! Geometric Earth-to-Sun vector in ECI J2000 (the ICD's frame; INTERPRETATION.md section 5:
//! the sun vector is geometric, with no light time and no aberration).
//!
//! Model: the Earth's heliocentric ecliptic position from VSOP87D (Bretagnon & Francou
//! 1988, *Astron. Astrophys.* 202, 309), truncated as in Meeus, *Astronomical Algorithms*,
//! 2nd ed., appendix III (the same table as NREL's SPA, Reda & Andreas 2004, table A4.2);
//! Meeus' correction to the FK5 system (eq. 32.3, as used in chapter 25); the mean obliquity of date
//! (IAU 1980, Lieske et al. 1977); and IAU-76 precession from the mean equator and equinox of
//! date back to J2000 (Lieske et al. 1977), both from [`crate::frames`] (the same
//! precession as its TEME -> J2000 chain). The theory's time argument is TT (TDB - TT < 2 ms, negligible).
//!
//! Accuracy: against `erfa.epv00` (the reference `sun_geom_*` of `tests/data/sun.csv`,
//! 25 epochs over 2000-2035) the worst errors are 0.28 arcsec in direction and 1.1e-6 in
//! distance (160 km), far inside the 0.01 deg and 0.01 % (`tests/sun_ref.rs`).
//! The Astronomical Almanac's low-precision series was not used: it is only good to about
//! 0.01 deg and refers to the equinox of date with aberration included.
//!
//! Validity: the truncated series holds for several centuries around J2000; the twin uses
//! it for 2000-2035, where it is tested. No allocation; about 200 cosines per call.

use nalgebra::Vector3;

use crate::frames::{ARCSEC_TO_RAD, mean_obliquity_iau80, precession_iau76};
use crate::time::{JulianDate, UtcTime};

/// The astronomical unit, km (IAU 2012 Resolution B2, exact).
pub const AU_KM: f64 = 149_597_870.7;

/// The Sun's nominal radius, km (IAU 2015 Resolution B3; the eclipse reference's value).
pub const SUN_RADIUS_KM: f64 = 695_700.0;

/// One periodic term: amplitude (1e-8 rad or 1e-8 AU), phase (rad), frequency (rad per
/// Julian millennium).
type Term = (f64, f64, f64);

// VSOP87D, Earth, Meeus appendix III (units 1e-8 rad and 1e-8 AU). Phases such as 3.142
// and 3.14 are the published, rounded values (they are pi to the table's precision).
const L0: [Term; 64] = [
    (175_347_046.0, 0.0, 0.0),
    (3_341_656.0, 4.669_256_8, 6_283.075_85),
    (34_894.0, 4.626_1, 12_566.151_7),
    (3_497.0, 2.744_1, 5_753.384_9),
    (3_418.0, 2.828_9, 3.523_1),
    (3_136.0, 3.627_7, 77_713.771_5),
    (2_676.0, 4.418_1, 7_860.419_4),
    (2_343.0, 6.135_2, 3_930.209_7),
    (1_324.0, 0.742_5, 11_506.769_8),
    (1_273.0, 2.037_1, 529.691),
    (1_199.0, 1.109_6, 1_577.343_5),
    (990.0, 5.233, 5_884.927),
    (902.0, 2.045, 26.298),
    (857.0, 3.508, 398.149),
    (780.0, 1.179, 5_223.694),
    (753.0, 2.533, 5_507.553),
    (505.0, 4.583, 18_849.228),
    (492.0, 4.205, 775.523),
    (357.0, 2.92, 0.067),
    (317.0, 5.849, 11_790.629),
    (284.0, 1.899, 796.298),
    (271.0, 0.315, 10_977.079),
    (243.0, 0.345, 5_486.778),
    (206.0, 4.806, 2_544.314),
    (205.0, 1.869, 5_573.143),
    (202.0, 2.458, 6_069.777),
    (156.0, 0.833, 213.299),
    (132.0, 3.411, 2_942.463),
    (126.0, 1.083, 20.775),
    (115.0, 0.645, 0.98),
    (103.0, 0.636, 4_694.003),
    (102.0, 0.976, 15_720.839),
    (102.0, 4.267, 7.114),
    (99.0, 6.21, 2_146.17),
    (98.0, 0.68, 155.42),
    (86.0, 5.98, 161_000.69),
    (85.0, 1.3, 6_275.96),
    (85.0, 3.67, 71_430.7),
    (80.0, 1.81, 17_260.15),
    (79.0, 3.04, 12_036.46),
    (75.0, 1.76, 5_088.63),
    (74.0, 3.5, 3_154.69),
    (74.0, 4.68, 801.82),
    (70.0, 0.83, 9_437.76),
    (62.0, 3.98, 8_827.39),
    (61.0, 1.82, 7_084.9),
    (57.0, 2.78, 6_286.6),
    (56.0, 4.39, 14_143.5),
    (56.0, 3.47, 6_279.55),
    (52.0, 0.19, 12_139.55),
    (52.0, 1.33, 1_748.02),
    (51.0, 0.28, 5_856.48),
    (49.0, 0.49, 1_194.45),
    (41.0, 5.37, 8_429.24),
    (41.0, 2.4, 19_651.05),
    (39.0, 6.17, 10_447.39),
    (37.0, 6.04, 10_213.29),
    (37.0, 2.57, 1_059.38),
    (36.0, 1.71, 2_352.87),
    (36.0, 1.78, 6_812.77),
    (33.0, 0.59, 17_789.85),
    (30.0, 0.44, 83_996.85),
    (30.0, 2.74, 1_349.87),
    (25.0, 3.16, 4_690.48),
];
const L1: [Term; 34] = [
    (628_331_966_747.0, 0.0, 0.0),
    (206_059.0, 2.678_235, 6_283.075_85),
    (4_303.0, 2.635_1, 12_566.151_7),
    (425.0, 1.59, 3.523),
    (119.0, 5.796, 26.298),
    (109.0, 2.966, 1_577.344),
    (93.0, 2.59, 18_849.23),
    (72.0, 1.14, 529.69),
    (68.0, 1.87, 398.15),
    (67.0, 4.41, 5_507.55),
    (59.0, 2.89, 5_223.69),
    (56.0, 2.17, 155.42),
    (45.0, 0.4, 796.3),
    (36.0, 0.47, 775.52),
    (29.0, 2.65, 7.11),
    (21.0, 5.34, 0.98),
    (19.0, 1.85, 5_486.78),
    (19.0, 4.97, 213.3),
    (17.0, 2.99, 6_275.96),
    (16.0, 0.03, 2_544.31),
    (16.0, 1.43, 2_146.17),
    (15.0, 1.21, 10_977.08),
    (12.0, 2.83, 1_748.02),
    (12.0, 3.26, 5_088.63),
    (12.0, 5.27, 1_194.45),
    (12.0, 2.08, 4_694.0),
    (11.0, 0.77, 553.57),
    (10.0, 1.3, 6_286.6),
    (10.0, 4.24, 1_349.87),
    (9.0, 2.7, 242.73),
    (9.0, 5.64, 951.72),
    (8.0, 5.3, 2_352.87),
    (6.0, 2.65, 9_437.76),
    (6.0, 4.67, 4_690.48),
];
const L2: [Term; 20] = [
    (52_919.0, 0.0, 0.0),
    (8_720.0, 1.072_1, 6_283.075_8),
    (309.0, 0.867, 12_566.152),
    (27.0, 0.05, 3.52),
    (16.0, 5.19, 26.3),
    (16.0, 3.68, 155.42),
    (10.0, 0.76, 18_849.23),
    (9.0, 2.06, 77_713.77),
    (7.0, 0.83, 775.52),
    (5.0, 4.66, 1_577.34),
    (4.0, 1.03, 7.11),
    (4.0, 3.44, 5_573.14),
    (3.0, 5.14, 796.3),
    (3.0, 6.05, 5_507.55),
    (3.0, 1.19, 242.73),
    (3.0, 6.12, 529.69),
    (3.0, 0.31, 398.15),
    (3.0, 2.28, 553.57),
    (2.0, 4.38, 5_223.69),
    (2.0, 3.75, 0.98),
];
const L3: [Term; 7] = [
    (289.0, 5.844, 6_283.076),
    (35.0, 0.0, 0.0),
    (17.0, 5.49, 12_566.15),
    (3.0, 5.2, 155.42),
    (1.0, 4.72, 3.52),
    (1.0, 5.3, 18_849.23),
    (1.0, 5.97, 242.73),
];
#[allow(clippy::approx_constant)]
const L4: [Term; 3] = [
    (114.0, 3.142, 0.0),
    (8.0, 4.13, 6_283.08),
    (1.0, 3.84, 12_566.15),
];
#[allow(clippy::approx_constant)]
const L5: [Term; 1] = [(1.0, 3.14, 0.0)];
const B0: [Term; 5] = [
    (280.0, 3.199, 84_334.662),
    (102.0, 5.422, 5_507.553),
    (80.0, 3.88, 5_223.69),
    (44.0, 3.7, 2_352.87),
    (32.0, 4.0, 1_577.34),
];
const B1: [Term; 2] = [(9.0, 3.9, 5_507.55), (6.0, 1.73, 5_223.69)];
const R0: [Term; 40] = [
    (100_013_989.0, 0.0, 0.0),
    (1_670_700.0, 3.098_463_5, 6_283.075_85),
    (13_956.0, 3.055_25, 12_566.151_7),
    (3_084.0, 5.198_5, 77_713.771_5),
    (1_628.0, 1.173_9, 5_753.384_9),
    (1_576.0, 2.846_9, 7_860.419_4),
    (925.0, 5.453, 11_506.77),
    (542.0, 4.564, 3_930.21),
    (472.0, 3.661, 5_884.927),
    (346.0, 0.964, 5_507.553),
    (329.0, 5.9, 5_223.694),
    (307.0, 0.299, 5_573.143),
    (243.0, 4.273, 11_790.629),
    (212.0, 5.847, 1_577.344),
    (186.0, 5.022, 10_977.079),
    (175.0, 3.012, 18_849.228),
    (110.0, 5.055, 5_486.778),
    (98.0, 0.89, 6_069.78),
    (86.0, 5.69, 15_720.84),
    (86.0, 1.27, 161_000.69),
    (65.0, 0.27, 17_260.15),
    (63.0, 0.92, 529.69),
    (57.0, 2.01, 83_996.85),
    (56.0, 5.24, 71_430.7),
    (49.0, 3.25, 2_544.31),
    (47.0, 2.58, 775.52),
    (45.0, 5.54, 9_437.76),
    (43.0, 6.01, 6_275.96),
    (39.0, 5.36, 4_694.0),
    (38.0, 2.39, 8_827.39),
    (37.0, 0.83, 19_651.05),
    (37.0, 4.9, 12_139.55),
    (36.0, 1.67, 12_036.46),
    (35.0, 1.84, 2_942.46),
    (33.0, 0.24, 7_084.9),
    (32.0, 0.18, 5_088.63),
    (32.0, 1.78, 398.15),
    (28.0, 1.21, 6_286.6),
    (28.0, 1.9, 6_279.55),
    (26.0, 4.59, 10_447.39),
];
#[allow(clippy::approx_constant)]
const R1: [Term; 10] = [
    (103_019.0, 1.107_49, 6_283.075_85),
    (1_721.0, 1.064_4, 12_566.151_7),
    (702.0, 3.142, 0.0),
    (32.0, 1.02, 18_849.23),
    (31.0, 2.84, 5_507.55),
    (25.0, 1.32, 5_223.69),
    (18.0, 1.42, 1_577.34),
    (10.0, 5.91, 10_977.08),
    (9.0, 1.42, 6_275.96),
    (9.0, 0.27, 5_486.78),
];
#[allow(clippy::approx_constant)]
const R2: [Term; 6] = [
    (4_359.0, 5.784_6, 6_283.075_8),
    (124.0, 5.579, 12_566.152),
    (12.0, 3.14, 0.0),
    (9.0, 3.63, 77_713.77),
    (6.0, 1.87, 5_573.14),
    (3.0, 5.47, 18_849.23),
];
const R3: [Term; 2] = [(145.0, 4.273, 6_283.076), (7.0, 3.92, 12_566.15)];
const R4: [Term; 1] = [(4.0, 2.56, 6_283.08)];

/// Sum of `A cos(B + C tau)` over one series.
fn series(terms: &[Term], tau: f64) -> f64 {
    terms.iter().map(|&(a, b, c)| a * (b + c * tau).cos()).sum()
}

/// Horner sum of the series `s0 + s1 tau + s2 tau^2 + ...`, in units of 1e-8.
fn power_series(series_list: &[&[Term]], tau: f64) -> f64 {
    series_list
        .iter()
        .rev()
        .fold(0.0, |acc, s| acc * tau + series(s, tau))
}

/// The Earth-to-Sun vector in ECI J2000 (IAU-76/FK5 mean equator and equinox), km, at the
/// TT Julian date `jd_tt`.
pub fn sun_eci_km_tt(jd_tt: JulianDate) -> Vector3<f64> {
    let t_tt_jc = jd_tt.centuries_since_j2000();
    let tau = t_tt_jc / 10.0; // Julian millennia
    // Heliocentric ecliptic longitude, latitude (rad) and distance (AU) of the Earth,
    // referred to the mean ecliptic and equinox of date (VSOP87D).
    let l_rad = power_series(&[&L0, &L1, &L2, &L3, &L4, &L5], tau) * 1e-8;
    let b_rad = power_series(&[&B0, &B1], tau) * 1e-8;
    let r_au = power_series(&[&R0, &R1, &R2, &R3, &R4], tau) * 1e-8;

    // Geocentric Sun: opposite direction.
    let mut lon_rad = l_rad + std::f64::consts::PI;
    let mut lat_rad = -b_rad;
    // Meeus (32.3): from the VSOP87 dynamical frame to FK5.
    let t = t_tt_jc;
    let lp = lon_rad - (1.397 * t + 0.000_31 * t * t).to_radians();
    let (slp, clp) = lp.sin_cos();
    lon_rad += (-0.090_33 + 0.039_16 * (clp + slp) * lat_rad.tan()) * ARCSEC_TO_RAD;
    lat_rad += 0.039_16 * (clp - slp) * ARCSEC_TO_RAD;

    let r_km = r_au * AU_KM;
    let (slon, clon) = lon_rad.sin_cos();
    let (slat, clat) = lat_rad.sin_cos();
    let ecl = Vector3::new(clat * clon, clat * slon, slat) * r_km;

    // Mean obliquity of date (IAU 1980): ecliptic -> mean equator of date; then IAU-76
    // precession back to J2000 (r_j2000 = P^T r_mod).
    let (se, ce) = mean_obliquity_iau80(jd_tt).sin_cos();
    let mod_km = Vector3::new(ecl.x, ce * ecl.y - se * ecl.z, se * ecl.y + ce * ecl.z);
    precession_iau76(jd_tt).tr_mul(&mod_km)
}

/// The Earth-to-Sun vector in ECI J2000, km, at the UTC instant `t` (evaluated in TT).
pub fn sun_eci_km(t: UtcTime) -> Vector3<f64> {
    sun_eci_km_tt(t.jd_tt())
}
