//! Frames against `tests/data/teme_to_j2000.csv` (ERFA/astropy, see `tests/data/README.md`)
//! and `tests/data/frames.csv`, with the issue's tolerances in the test names.

mod ref_csv;

use m6p_orbit::frames::{
    a_lvlh_from_eci, a_tnw_from_eci, nutation_iau80, q_eci_from_lvlh, q_eci_from_tnw, teme_to_ecef,
    teme_to_j2000,
};
use m6p_orbit::propagate::{Propagator, Sgp4Propagator, StateVector};
use m6p_orbit::time::{Eop, UtcTime, gmst82};
use m6p_orbit::tle::{ChecksumMode, Tle};
use nalgebra::{Matrix3, Quaternion, UnitQuaternion};
use ref_csv::Csv;

fn samples() -> Csv {
    Csv::parse("teme_to_j2000.csv", include_str!("data/teme_to_j2000.csv"))
}

fn time(csv: &Csv, row: &[String]) -> UtcTime {
    UtcTime::from_iso8601(csv.s(row, "utc_iso")).unwrap_or_else(|e| panic!("{e}"))
}

fn teme(csv: &Csv, row: &[String]) -> StateVector {
    StateVector {
        r_km: csv.v3(row, "teme_r", "_km"),
        v_km_s: csv.v3(row, "teme_v", "_km_s"),
    }
}

fn eop(csv: &Csv, row: &[String]) -> Eop {
    Eop {
        ut1_minus_utc_s: csv.f(row, "ut1_minus_utc_s"),
        xp_arcsec: csv.f(row, "xp_arcsec"),
        yp_arcsec: csv.f(row, "yp_arcsec"),
    }
}

/// Difference of two angles, wrapped to [-pi, pi].
fn dangle(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    if d > std::f64::consts::PI {
        d - std::f64::consts::TAU
    } else {
        d
    }
}

#[test]
fn teme_to_j2000_within_0_05_m() {
    let csv = samples();
    let (mut worst_m, mut worst_v_mm_s) = (0.0_f64, 0.0_f64);
    for row in &csv.rows {
        let t = time(&csv, row);
        let j = teme_to_j2000(&teme(&csv, row), t);
        let dr_m = (j.r_km - csv.v3(row, "j2000fk5_r", "_km")).norm() * 1e3;
        let dv = (j.v_km_s - csv.v3(row, "j2000fk5_v", "_km_s")).norm() * 1e6;
        worst_m = worst_m.max(dr_m);
        worst_v_mm_s = worst_v_mm_s.max(dv);
    }
    println!("TEME->J2000: worst position {worst_m:.3e} m, velocity {worst_v_mm_s:.3e} mm/s");
    assert!(worst_m <= 0.05, "{worst_m} m");
    assert!(worst_v_mm_s <= 0.05, "{worst_v_mm_s} mm/s");
}

#[test]
fn equation_of_equinoxes_matches_erfa_within_1e_12_rad() {
    let csv = samples();
    let mut worst = 0.0_f64;
    for row in &csv.rows {
        let n = nutation_iau80(time(&csv, row).jd_tt());
        worst = worst.max((n.eqeq_geometric_rad() - csv.f(row, "eqeq80_nokin_rad")).abs());
    }
    println!("eqeq80 (no kinematic terms): worst {worst:.3e} rad");
    assert!(worst <= 1e-12, "{worst}");
}

#[test]
fn tt_minus_utc_matches_reference() {
    let csv = samples();
    for row in &csv.rows {
        let d = time(&csv, row).tt_minus_utc_s() - csv.f(row, "tt_minus_utc_s");
        assert!(d.abs() < 1e-8, "{d}");
    }
}

#[test]
fn gmst82_within_1e9_rad() {
    let csv = samples();
    let mut worst = 0.0_f64;
    for row in &csv.rows {
        let t = time(&csv, row);
        let g = gmst82(t.jd_ut1_from_dut1(csv.f(row, "ut1_minus_utc_s")));
        let g0 = gmst82(t.jd_ut1(None));
        worst = worst
            .max(dangle(g, csv.f(row, "gmst82_rad")).abs())
            .max(dangle(g0, csv.f(row, "gmst82_ut1equtc_rad")).abs());
    }
    println!("GMST82: worst {worst:.3e} rad");
    assert!(worst <= 1e-9, "{worst}");
}

#[test]
fn ecef_without_eop_within_100_m_of_itrs() {
    // Without EOP, UT1 = UTC and no polar motion: the 2020s samples (|UT1-UTC| <= 0.17 s)
    // stay within 100 m. The 2004 Vallado sample has UT1-UTC = -0.44 s, i.e. 0.44 s of Earth
    // rotation = 3.2e-5 rad x 7967 km = 256 m at its 10 200 km radius: no EOP-free model can
    // meet 100 m there, so it is held to that physical bound instead (300 m).
    let csv = samples();
    let (mut worst_2020s, mut worst_2004, mut worst_noeop) = (0.0_f64, 0.0_f64, 0.0_f64);
    for row in &csv.rows {
        let e = teme_to_ecef(&teme(&csv, row), time(&csv, row), None);
        let d_m = (e.r_km - csv.v3(row, "itrs_r", "_km")).norm() * 1e3;
        if csv.s(row, "source").starts_with("VALLADO") {
            worst_2004 = worst_2004.max(d_m);
        } else {
            worst_2020s = worst_2020s.max(d_m);
        }
        worst_noeop = worst_noeop.max((e.r_km - csv.v3(row, "itrs_noeop_r", "_km")).norm() * 1e3);
    }
    println!(
        "ECEF without EOP: worst {worst_2020s:.3} m (2020s samples), {worst_2004:.3} m (2004 \
         sample, UT1-UTC -0.44 s), {worst_noeop:.3e} m from itrs_noeop_*"
    );
    assert!(worst_2020s <= 100.0, "{worst_2020s} m");
    assert!(worst_2004 <= 300.0, "{worst_2004} m");
    assert!(worst_noeop <= 0.05, "{worst_noeop} m");
}

#[test]
fn ecef_with_sample_eop_within_0_05_m() {
    let csv = samples();
    let (mut worst_m, mut worst_v) = (0.0_f64, 0.0_f64);
    for row in &csv.rows {
        let e = teme_to_ecef(&teme(&csv, row), time(&csv, row), Some(&eop(&csv, row)));
        worst_m = worst_m.max((e.r_km - csv.v3(row, "itrs_r", "_km")).norm() * 1e3);
        worst_v = worst_v.max((e.v_km_s - csv.v3(row, "itrs_v", "_km_s")).norm() * 1e6);
    }
    println!("ECEF with EOP: worst {worst_m:.3e} m, velocity {worst_v:.3e} mm/s");
    assert!(worst_m <= 0.05, "{worst_m} m");
    assert!(worst_v <= 1.0, "{worst_v} mm/s");
}

#[test]
fn sgp4_reproduces_the_sample_teme_states_within_1e_6_km() {
    // The samples' TEME states come from python-sgp4; ours must agree, and the full
    // Propagator chain (SGP4 then TEME -> J2000) must land on `j2000fk5_*`.
    let csv = samples();
    let mut worst = 0.0_f64;
    for row in &csv.rows {
        let l1 = csv.s(row, "tle_line1");
        if l1.is_empty() {
            continue;
        }
        let tle = Tle::parse(l1, csv.s(row, "tle_line2"), ChecksumMode::Strict)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut p = Sgp4Propagator::new(&tle).unwrap_or_else(|e| panic!("{e}"));
        let t = time(&csv, row);
        let s = p
            .state_teme(csv.f(row, "tsince_min"))
            .unwrap_or_else(|e| panic!("{e}"));
        worst = worst.max((s.r_km - csv.v3(row, "teme_r", "_km")).norm());
        let j = p.state_j2000(t).unwrap_or_else(|e| panic!("{e}"));
        worst = worst.max((j.r_km - csv.v3(row, "j2000fk5_r", "_km")).norm());
    }
    println!("SGP4 samples: worst {worst:.3e} km");
    assert!(worst <= 1e-6, "{worst} km");
}

fn rows(csv: &Csv, row: &[String], f: &str) -> Matrix3<f64> {
    let m = |i: usize, j: usize| csv.f(row, &format!("{f}_m{i}{j}"));
    Matrix3::new(
        m(1, 1),
        m(1, 2),
        m(1, 3),
        m(2, 1),
        m(2, 2),
        m(2, 3),
        m(3, 1),
        m(3, 2),
        m(3, 3),
    )
}

fn quat(csv: &Csv, row: &[String], p: &str) -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(Quaternion::new(
        csv.f(row, &format!("{p}w")),
        csv.f(row, &format!("{p}x")),
        csv.f(row, &format!("{p}y")),
        csv.f(row, &format!("{p}z")),
    ))
}

/// Rotation angle between two rotation matrices, `atan2(|sin|, cos)` of the relative
/// rotation (accurate for tiny angles, unlike `acos` of the trace).
fn matrix_angle(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let r = a * b.transpose();
    let s = nalgebra::Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    );
    (0.5 * s.norm()).atan2(0.5 * (r.trace() - 1.0))
}

#[test]
fn lvlh_and_tnw_within_1e9_rad_of_frames_csv() {
    let csv = Csv::parse("frames.csv", include_str!("data/frames.csv"));
    let mut worst = 0.0_f64;
    for row in &csv.rows {
        let r = csv.v3(row, "r", "_km");
        let v = csv.v3(row, "v", "_km_s");
        for (name, a, q) in [
            ("lvlh", a_lvlh_from_eci(&r, &v), q_eci_from_lvlh(&r, &v)),
            ("tnw", a_tnw_from_eci(&r, &v), q_eci_from_tnw(&r, &v)),
        ] {
            let a_ref = rows(&csv, row, name);
            let q_ref = quat(&csv, row, &format!("{name}_q"));
            let att_ref = quat(&csv, row, &format!("{name}_att"));
            let e_matrix = matrix_angle(&a, &a_ref);
            let e_att = q.angle_to(&att_ref);
            let e_q = q.inverse().angle_to(&q_ref);
            // Same sign convention as the file (w >= 0), component by component.
            let e_comp = (q.into_inner().coords - att_ref.into_inner().coords).amax();
            assert!(q.w >= 0.0);

            worst = worst.max(e_matrix).max(e_att).max(e_q).max(e_comp);
        }
    }
    println!("LVLH/TNW: worst {worst:.3e} rad");
    assert!(worst <= 1e-9, "{worst}");
}
