//! Pass prediction for the reference 6U cubesat TLE (`CUBESAT-6U` in
//! `tests/data/teme_to_j2000.csv`) over Vilnius (54.6872 N, 25.2797 E, 100 m) for one day,
//! against a brute-force elevation scan at 0.1 s steps.

mod ref_csv;

use m6p_orbit::frames::teme_to_ecef;
use m6p_orbit::passes::{GroundSite, Pass, PassOptions, predict_passes, predict_passes_propagator};
use m6p_orbit::propagate::{PropagationError, Sgp4Propagator};
use m6p_orbit::time::UtcTime;
use m6p_orbit::tle::{ChecksumMode, Tle};
use nalgebra::Vector3;
use ref_csv::Csv;

fn cubesat() -> Sgp4Propagator {
    let csv = Csv::parse("teme_to_j2000.csv", include_str!("data/teme_to_j2000.csv"));
    let row = csv
        .rows
        .iter()
        .find(|r| csv.s(r, "source") == "CUBESAT-6U")
        .unwrap_or_else(|| panic!("no 6U sample"));
    let tle = Tle::parse(
        csv.s(row, "tle_line1"),
        csv.s(row, "tle_line2"),
        ChecksumMode::Strict,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    Sgp4Propagator::new(&tle).unwrap_or_else(|e| panic!("{e}"))
}

fn vilnius() -> GroundSite {
    GroundSite::from_deg(54.6872, 25.2797, 100.0)
}

/// Rise and set times (unix ns) of the brute-force scan: the first 0.1 s sample at or above
/// the mask after one below it, and the first below it after one at or above.
fn scan_events(
    elevations: &[f64],
    t0_ns: i64,
    step_ns: i64,
    mask_rad: f64,
) -> (Vec<i64>, Vec<i64>) {
    let (mut rises, mut sets) = (Vec::new(), Vec::new());
    for (k, w) in elevations.windows(2).enumerate() {
        let t = t0_ns + (k as i64 + 1) * step_ns;
        if w[0] < mask_rad && w[1] >= mask_rad {
            rises.push(t);
        } else if w[0] >= mask_rad && w[1] < mask_rad {
            sets.push(t);
        }
    }
    (rises, sets)
}

#[test]
fn passes_over_vilnius_within_1_s_of_a_0_1_s_scan() {
    let p = cubesat();
    let site = vilnius();
    let start = p.epoch();
    let end = start.plus_seconds(86_400.0);
    let r_ecef_km = |t: UtcTime| -> Result<Vector3<f64>, PropagationError> {
        Ok(teme_to_ecef(&p.state_teme_at(t)?, t, None).r_km)
    };

    // The brute-force scan (the same position model, 864 001 samples).
    let step_ns = 100_000_000;
    let n = (end.unix_ns() - start.unix_ns()) / step_ns + 1;
    let elevations: Vec<f64> = (0..n)
        .map(|k| {
            let t = UtcTime::from_unix_ns(start.unix_ns() + k * step_ns);
            site.elevation_rad(&r_ecef_km(t).unwrap_or_else(|e| panic!("{e}")))
        })
        .collect();

    let mut worst_s = 0.0_f64;
    let mut total = 0;
    for mask_deg in [0.0, 10.0] {
        let mask_rad = f64::to_radians(mask_deg);
        let (rises, sets) = scan_events(&elevations, start.unix_ns(), step_ns, mask_rad);
        let options = PassOptions {
            mask_rad,
            ..PassOptions::default()
        };
        let passes: Vec<Pass> = predict_passes(&site, start, end, &options, r_ecef_km)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(passes.iter().all(|p| !p.rise_clipped && !p.set_clipped));
        assert_eq!(
            passes.len(),
            rises.len(),
            "mask {mask_deg} deg: {passes:#?}"
        );
        assert_eq!(passes.len(), sets.len());
        for (pass, (&r, &s)) in passes.iter().zip(rises.iter().zip(sets.iter())) {
            let dr = (pass.rise.unix_ns() - r) as f64 * 1e-9;
            let ds = (pass.set.unix_ns() - s) as f64 * 1e-9;
            worst_s = worst_s.max(dr.abs()).max(ds.abs());
            assert!(
                dr.abs() <= 1.0 && ds.abs() <= 1.0,
                "mask {mask_deg}: rise {dr} s, set {ds} s"
            );
            // The culmination is the scan's maximum within the pass (to the scan's step).
            let k0 = ((r - start.unix_ns()) / step_ns) as usize;
            let k1 = ((s - start.unix_ns()) / step_ns) as usize;
            let scan_max = elevations[k0..k1].iter().cloned().fold(f64::MIN, f64::max);
            assert!(pass.max_elevation_rad >= scan_max - 1e-9);
            assert!(pass.max_elevation_rad - scan_max < 1e-4, "culmination");
        }
        println!(
            "mask {mask_deg} deg: {} passes; max elevations {:?} deg",
            passes.len(),
            passes
                .iter()
                .map(|p| (p.max_elevation_rad.to_degrees() * 10.0).round() / 10.0)
                .collect::<Vec<_>>()
        );
        total += passes.len();
    }
    println!("worst rise/set difference from the 0.1 s scan: {worst_s:.3} s");
    assert!(
        total >= 4,
        "a sun-synchronous LEO passes over Vilnius several times a day"
    );
}

#[test]
fn the_propagator_path_gives_the_same_passes() {
    // Through `Propagator::state_j2000` and J2000 -> ECEF instead of TEME -> ECEF.
    let mut p = cubesat();
    let site = vilnius();
    let start = p.epoch();
    let end = start.plus_seconds(86_400.0);
    let options = PassOptions::default();
    let direct = predict_passes(&site, start, end, &options, |t| {
        Ok::<_, PropagationError>(teme_to_ecef(&p.state_teme_at(t)?, t, None).r_km)
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let via = predict_passes_propagator(&site, start, end, &options, &mut p, None)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(direct.len(), via.len());
    for (a, b) in direct.iter().zip(&via) {
        assert!(a.rise.seconds_since(b.rise).abs() < 2e-3);
        assert!(a.set.seconds_since(b.set).abs() < 2e-3);
    }
}
