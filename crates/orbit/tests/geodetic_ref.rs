//! WGS-84 geodetic <-> ECEF against `tests/data/geodetic.csv` (pymap3d forward, erfa.gc2gd
//! inverse; see `tests/data/README.md`).

mod ref_csv;

use m6p_orbit::geodetic::{Geodetic, ecef_m_to_geodetic, geodetic_to_ecef_m};
use ref_csv::Csv;

fn points() -> Csv {
    Csv::parse("geodetic.csv", include_str!("data/geodetic.csv"))
}

#[test]
fn geodetic_to_ecef_within_1_mm() {
    let csv = points();
    let mut worst = 0.0_f64;
    for row in &csv.rows {
        let g = Geodetic::from_deg(
            csv.f(row, "lat_deg"),
            csv.f(row, "lon_deg"),
            csv.f(row, "alt_m"),
        );
        let d = (geodetic_to_ecef_m(&g) - csv.v3(row, "", "_m")).norm();
        assert!(d <= 1e-3, "{}: {d} m", csv.s(row, "point"));
        if d > 1e-5 {
            println!(
                "{} ({}): {d:.2e} m",
                csv.s(row, "point"),
                csv.s(row, "defined_by")
            );
        }
        worst = worst.max(d);
    }
    println!(
        "geodetic -> ECEF: worst {worst:.3e} m over {} points",
        csv.rows.len()
    );
}

#[test]
fn ecef_to_geodetic_within_1_mm() {
    let csv = points();
    let mut worst = 0.0_f64;
    for row in &csv.rows {
        let name = csv.s(row, "point");
        let g = ecef_m_to_geodetic(&csv.v3(row, "", "_m"));
        let lat = csv.f(row, "lat_deg").to_radians();
        let alt = csv.f(row, "alt_m");
        // Angular errors as metres along the meridian and the parallel at this height.
        let radius = 6.4e6 + alt.abs();
        let d_lat = (g.lat_rad - lat).abs() * radius;
        let d_h = (g.alt_m - alt).abs();
        let d_lon = if lat.abs() < std::f64::consts::FRAC_PI_2 - 1e-12 {
            let dl =
                (g.lon_rad - csv.f(row, "lon_deg").to_radians()).rem_euclid(std::f64::consts::TAU);
            dl.min(std::f64::consts::TAU - dl) * radius * lat.cos()
        } else {
            0.0 // longitude is arbitrary on the axis
        };
        let d = d_lat.max(d_h).max(d_lon);
        assert!(d <= 1e-3, "{name}: lat {d_lat} m, lon {d_lon} m, h {d_h} m");
        if d > 1e-5 {
            println!(
                "{name} ({}): lat {d_lat:.2e} m, lon {d_lon:.2e} m, h {d_h:.2e} m",
                csv.s(row, "defined_by")
            );
        }
        worst = worst.max(d);
    }
    println!(
        "ECEF -> geodetic: worst {worst:.3e} m over {} points",
        csv.rows.len()
    );
}
