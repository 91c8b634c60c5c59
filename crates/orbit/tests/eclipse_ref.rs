//! The conical shadow model against `tests/data/eclipse.csv` (Montenbruck & Gill 3.4.2
//! computed independently in Python; see `tests/data/README.md`). The bar: state
//! identical everywhere, visible fraction within 1e-3.

use m6p_orbit::eclipse::{EARTH_RADIUS_KM, SUN_RADIUS_KM, ShadowState, illumination};
use nalgebra::Vector3;

fn column<'a>(header: &[&str], row: &[&'a str], name: &str) -> &'a str {
    let i = header
        .iter()
        .position(|h| *h == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    row[i]
}

fn num(header: &[&str], row: &[&str], name: &str) -> f64 {
    column(header, row, name).parse().expect("a number")
}

#[test]
fn conical_state_identical_and_visible_fraction_within_1e_3() {
    let text = include_str!("data/eclipse.csv");
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let mut worst = 0.0_f64;
    let mut rows = 0;
    let mut states = [0usize; 3];
    for line in lines {
        let row: Vec<&str> = line.split(',').collect();
        let v = |p: &str| {
            Vector3::new(
                num(&header, &row, &format!("{p}_x_km")),
                num(&header, &row, &format!("{p}_y_km")),
                num(&header, &row, &format!("{p}_z_km")),
            )
        };
        assert_eq!(num(&header, &row, "r_earth_km"), EARTH_RADIUS_KM);
        assert_eq!(num(&header, &row, "r_sun_km"), SUN_RADIUS_KM);
        let ill = illumination(&v("sat"), &v("sun"));
        let expected = match column(&header, &row, "conical_state") {
            "sunlit" => ShadowState::Sunlit,
            "penumbra" => ShadowState::Penumbra,
            "umbra" => ShadowState::Umbra,
            other => panic!("unknown state {other}"),
        };
        let case = column(&header, &row, "case");
        assert_eq!(ill.state, expected, "case {case}");
        states[expected as usize] += 1;
        let err = (ill.visible_fraction - num(&header, &row, "conical_visible_fraction")).abs();
        assert!(err < 1e-3, "case {case}: fraction error {err}");
        worst = worst.max(err);
        rows += 1;
    }
    println!("eclipse: {rows} rows, states {states:?}, worst fraction error {worst:.3e}");
    assert_eq!(rows, 35);
    assert!(states.iter().all(|&n| n > 0), "every state is exercised");
    // Measured: rounding only. Keep it there.
    assert!(worst < 1e-9, "fraction error {worst}");
}
