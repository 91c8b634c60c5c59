//! IGRF-14 against `tests/data/igrf.csv` (ppigrf 2.1.0 and pyigrf14 1.0.4; see
//! `tests/data/README.md`). The bar: every component within 1 nT; the aim, 0.01 nT
//! (it is the same model).

use m6p_orbit::igrf::{FieldError, field_ecef, field_geodetic, field_geodetic_at};
use m6p_orbit::time::UtcTime;
use nalgebra::Vector3;

struct Row<'a> {
    header: &'a [&'a str],
    fields: Vec<&'a str>,
}

impl Row<'_> {
    fn s(&self, name: &str) -> &str {
        let i = self
            .header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("no column {name}"));
        self.fields[i]
    }
    fn f(&self, name: &str) -> f64 {
        self.s(name).parse().expect("a number")
    }
    fn v(&self, names: [&str; 3]) -> Vector3<f64> {
        Vector3::new(self.f(names[0]), self.f(names[1]), self.f(names[2]))
    }
}

fn for_each_row(mut check: impl FnMut(&Row<'_>)) -> usize {
    let text = include_str!("data/igrf.csv");
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let mut n = 0;
    for line in lines {
        check(&Row {
            header: &header,
            fields: line.split(',').collect(),
        });
        n += 1;
    }
    n
}

fn max_abs(v: Vector3<f64>) -> f64 {
    v.iter().fold(0.0_f64, |m, x| m.max(x.abs()))
}

const NED: [&str; 3] = ["b_north_nT", "b_east_nT", "b_down_nT"];
const ECEF: [&str; 3] = ["b_ecef_x_nT", "b_ecef_y_nT", "b_ecef_z_nT"];
const RTP: [&str; 3] = ["b_r_nT", "b_theta_nT", "b_phi_nT"];

#[test]
fn igrf14_every_component_within_1_nt_at_geodetic_points() {
    let mut worst = [0.0_f64; 3];
    let rows = for_each_row(|row| {
        let f = field_geodetic(
            row.f("lat_gd_deg").to_radians(),
            row.f("lon_deg").to_radians(),
            row.f("alt_km"),
            row.f("decimal_year"),
        )
        .expect("in range");
        let errs = [
            max_abs(f.b_ned_nt - row.v(NED)),
            max_abs(f.b_ecef_nt - row.v(ECEF)),
            max_abs(f.b_rtp_nt - row.v(RTP)),
        ];
        for (w, e) in worst.iter_mut().zip(errs) {
            *w = w.max(e);
        }
        assert!(
            errs.iter().all(|&e| e < 1.0),
            "{}: {errs:?}",
            row.s("point")
        );
    });
    println!(
        "igrf geodetic, {rows} points: worst |dB| NED {:.2e}, ECEF {:.2e}, r/theta/phi {:.2e} nT",
        worst[0], worst[1], worst[2]
    );
    assert_eq!(rows, 50);
    assert!(
        worst.iter().all(|&w| w < 0.01),
        "aim: 0.01 nT, got {worst:?}"
    );
    // Measured: 2.5e-4 nT in NED/ECEF (the reference's geodetic conversion), 2.5e-10 nT in
    // the geocentric components (the same sums). Keep it there.
    assert!(
        worst[0] < 1e-3 && worst[1] < 1e-3 && worst[2] < 1e-6,
        "{worst:?}"
    );
}

#[test]
fn igrf14_every_component_within_1_nt_at_ecef_points() {
    let mut worst = 0.0_f64;
    for_each_row(|row| {
        let r = row.v(["ecef_x_km", "ecef_y_km", "ecef_z_km"]);
        let f = field_ecef(&r, row.f("decimal_year")).expect("in range");
        let err = max_abs(f.b_ned_nt - row.v(NED)).max(max_abs(f.b_ecef_nt - row.v(ECEF)));
        assert!(err < 1.0, "{}: {err}", row.s("point"));
        worst = worst.max(err);
    });
    println!("igrf ECEF input: worst |dB| {worst:.2e} nT");
    assert!(worst < 0.01, "aim: 0.01 nT, got {worst}");
}

#[test]
fn igrf14_from_utc_time_uses_the_reference_decimal_year() {
    let mut worst = 0.0_f64;
    for_each_row(|row| {
        let t = UtcTime::from_iso8601(row.s("utc_iso")).expect("ISO-8601");
        assert!((t.decimal_year() - row.f("decimal_year")).abs() < 1e-12);
        let f = field_geodetic_at(
            t,
            row.f("lat_gd_deg").to_radians(),
            row.f("lon_deg").to_radians(),
            row.f("alt_km"),
        )
        .expect("in range");
        worst = worst.max(max_abs(f.b_ned_nt - row.v(NED)));
    });
    assert!(worst < 0.01, "{worst}");
}

#[test]
fn igrf14_pole_points_are_finite() {
    for_each_row(|row| {
        if row.s("point").contains("pole") {
            let f = field_geodetic(
                row.f("lat_gd_deg").to_radians(),
                row.f("lon_deg").to_radians(),
                row.f("alt_km"),
                row.f("decimal_year"),
            )
            .expect("in range");
            assert!(f.b_ned_nt.iter().all(|v| v.is_finite()));
        }
    });
    for lat_deg in [90.0_f64, -90.0] {
        let f = field_geodetic(lat_deg.to_radians(), 0.3, 600.0, 2027.5).expect("in range");
        assert!(
            f.b_ned_nt
                .iter()
                .chain(f.b_ecef_nt.iter())
                .all(|v| v.is_finite())
        );
        // Near the geographic poles the field is mostly vertical, tens of microtesla.
        assert!(f.b_ned_nt.norm() > 30_000.0 && f.b_ned_nt.norm() < 70_000.0);
    }
}

#[test]
fn igrf14_outside_2020_2030_says_so() {
    let err = field_geodetic(0.0, 0.0, 500.0, 2031.0).expect_err("out of range");
    assert_eq!(
        err,
        FieldError::OutOfRange {
            decimal_year: 2031.0
        }
    );
    assert!(err.to_string().contains("2020.0-2030.0"));
}

#[test]
fn igrf14_eci_within_the_earth_orientation_bound_of_gcrs() {
    use m6p_orbit::frames::a_ecef_from_eci;
    use m6p_orbit::igrf::field_eci_at;
    let mut worst_nt = 0.0_f64;
    let mut worst_rad = 0.0_f64;
    for_each_row(|row| {
        let t = UtcTime::from_iso8601(row.s("utc_iso")).expect("ISO-8601");
        let a = a_ecef_from_eci(t, None);
        let r_ecef = row.v(["ecef_x_km", "ecef_y_km", "ecef_z_km"]);
        let r_eci = a.tr_mul(&r_ecef);
        let f = field_eci_at(t, &r_eci, None).expect("in range");
        // The same point and field as the geodetic evaluation, rotated.
        assert!(max_abs(f.sample.b_ecef_nt - row.v(ECEF)) < 1e-3);
        assert!((f.sample.b_eci_nt(&a.transpose()) - f.b_eci_nt).norm() < 1e-9);
        let b_gcrs = row.v(["b_gcrs_x_nT", "b_gcrs_y_nT", "b_gcrs_z_nT"]);
        let err = max_abs(f.b_eci_nt - b_gcrs);
        worst_nt = worst_nt.max(err);
        worst_rad = worst_rad.max(f.b_eci_nt.angle(&b_gcrs));
    });
    println!(
        "igrf ECI J2000 (no EOP) vs GCRS (IERS EOP): worst {worst_nt:.3} nT, {worst_rad:.2e} rad"
    );
    // Without EOP the Earth's rotation angle is off by UT1 - UTC (|UT1 - UTC| < 0.9 s, at
    // most 6.6e-5 rad); J2000 vs GCRS adds about 1e-7 rad.
    assert!(worst_rad < 6.6e-5 + 2e-7, "{worst_rad} rad");
}
