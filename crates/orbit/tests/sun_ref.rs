//! The geometric sun vector against `tests/data/sun.csv` (erfa.epv00, 2000-2035; see
//! `tests/data/README.md`). The bar: direction within 0.01 deg, distance within
//! 0.01 %.

use m6p_orbit::sun::{sun_eci_km, sun_eci_km_tt};
use m6p_orbit::time::{JulianDate, UtcTime};
use nalgebra::Vector3;

/// Rows of a CSV file as (header, fields) pairs looked up by column name.
struct Csv {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Csv {
    fn parse(text: &str) -> Csv {
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let header = lines
            .next()
            .expect("header")
            .split(',')
            .map(str::to_owned)
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(str::to_owned).collect())
            .collect();
        Csv { header, rows }
    }
    fn col(&self, name: &str) -> usize {
        self.header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name}"))
    }
    fn f(&self, row: &[String], name: &str) -> f64 {
        row[self.col(name)].parse().expect("a number")
    }
}

fn reference() -> Csv {
    Csv::parse(include_str!("data/sun.csv"))
}

/// (worst angle in degrees, worst relative distance error) of `model` over the file.
fn worst(model: impl Fn(&Csv, &[String]) -> Vector3<f64>) -> (f64, f64) {
    let csv = reference();
    let mut worst_deg = 0.0_f64;
    let mut worst_rel = 0.0_f64;
    for row in &csv.rows {
        let u_ref = Vector3::new(
            csv.f(row, "sun_geom_ux"),
            csv.f(row, "sun_geom_uy"),
            csv.f(row, "sun_geom_uz"),
        );
        let dist_ref_km = csv.f(row, "sun_geom_dist_km");
        let r_km = model(&csv, row);
        let angle_deg = r_km.normalize().cross(&u_ref).norm().asin().to_degrees();
        let rel = (r_km.norm() - dist_ref_km).abs() / dist_ref_km;
        worst_deg = worst_deg.max(angle_deg);
        worst_rel = worst_rel.max(rel);
    }
    (worst_deg, worst_rel)
}

#[test]
fn sun_direction_within_0_01_deg_and_distance_within_0_01_percent_from_tt() {
    let (deg, rel) = worst(|csv, row| {
        sun_eci_km_tt(JulianDate::new(csv.f(row, "jd_tt1"), csv.f(row, "jd_tt2")))
    });
    println!(
        "sun from TT: worst direction {:.3e} deg ({:.3} arcsec), worst distance {:.3e} (relative)",
        deg,
        deg * 3600.0,
        rel
    );
    assert!(deg < 0.01, "direction error {deg} deg");
    assert!(rel < 1e-4, "distance error {rel}");
    // What the model really achieves (measured 0.28 arcsec and 1.1e-6): keep it there.
    assert!(deg < 1.0 / 3600.0, "direction error {deg} deg");
    assert!(rel < 3e-6, "distance error {rel}");
}

#[test]
fn sun_direction_within_0_01_deg_and_distance_within_0_01_percent_from_utc() {
    let (deg, rel) = worst(|csv, row| {
        let iso = &row[csv.col("utc_iso")];
        let t = UtcTime::from_iso8601(iso).expect("an ISO-8601 time");
        sun_eci_km(t)
    });
    println!("sun from UTC: worst direction {deg:.3e} deg, worst distance {rel:.3e}");
    assert!(deg < 0.01, "direction error {deg} deg");
    assert!(rel < 1e-4, "distance error {rel}");
}
