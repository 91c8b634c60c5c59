//! SGP4 against the official Vallado verification set (`tests/data/sgp4_vallado*.csv`: the
//! SGP4-VER.TLE cases and `tcppver.out` expected TEME states, WGS-72, opsmode 'i'; see
//! `tests/data/README.md`).

mod ref_csv;

use m6p_orbit::propagate::{PropagationError, Sgp4Propagator};
use m6p_orbit::tle::{ChecksumMode, Tle, TleError};
use ref_csv::Csv;

fn tles() -> Csv {
    Csv::parse(
        "sgp4_vallado_tles.csv",
        include_str!("data/sgp4_vallado_tles.csv"),
    )
}
fn expected() -> Csv {
    Csv::parse("sgp4_vallado.csv", include_str!("data/sgp4_vallado.csv"))
}
fn errors() -> Csv {
    Csv::parse(
        "sgp4_vallado_errors.csv",
        include_str!("data/sgp4_vallado_errors.csv"),
    )
}

/// The propagator of a case (lenient parsing: some cases have bad checksums on purpose).
fn propagator(tles: &Csv, case: &str) -> Result<Sgp4Propagator, PropagationError> {
    let row = tles
        .rows
        .iter()
        .find(|r| tles.s(r, "case") == case)
        .unwrap_or_else(|| panic!("no case {case}"));
    let tle = Tle::parse(
        tles.s(row, "line1"),
        tles.s(row, "line2"),
        ChecksumMode::Lenient,
    )
    .unwrap_or_else(|e| panic!("case {case}: {e}"));
    Sgp4Propagator::new(&tle)
}

#[test]
fn sgp4_vallado_within_1e6_km_and_1e9_km_s() {
    let tles = tles();
    let exp = expected();
    let (mut worst_r, mut worst_v, mut n) = (0.0_f64, 0.0_f64, 0);
    let mut worst_case = String::new();
    for row in &exp.rows {
        if exp.s(row, "row_kind") == "stale_artifact" {
            continue;
        }
        let case = exp.s(row, "case");
        let p = propagator(&tles, case).unwrap_or_else(|e| panic!("case {case}: {e}"));
        let t = exp.f(row, "tsince_min");
        let s = p
            .state_teme(t)
            .unwrap_or_else(|e| panic!("case {case} t={t}: {e}"));
        let dr = (s.r_km - exp.v3(row, "", "_km")).amax();
        let dv = (s.v_km_s - exp.v3(row, "v", "_km_s")).amax();
        if dr > worst_r {
            worst_case = format!("case {case} sat {} t={t}", exp.s(row, "satnum"));
        }
        worst_r = worst_r.max(dr);
        worst_v = worst_v.max(dv);
        n += 1;
    }
    println!(
        "{n} states: worst |dr| {worst_r:.3e} km ({worst_case}), worst |dv| {worst_v:.3e} km/s"
    );
    assert_eq!(n, 666);
    assert!(
        worst_r <= 1e-6,
        "worst position error {worst_r:e} km at {worst_case}"
    );
    assert!(worst_v <= 1e-9, "worst velocity error {worst_v:e} km/s");
}

#[test]
fn sgp4_vallado_error_cases_return_the_right_code_at_the_right_time() {
    let tles = tles();
    let errs = errors();
    assert_eq!(errs.rows.len(), 7);
    for row in &errs.rows {
        let case = errs.s(row, "case");
        let code = errs.f(row, "error_code") as u8;
        let init_error = errs.f(row, "init_error") as u8;
        let result = propagator(&tles, case);
        if init_error != 0 {
            let e = result.err();
            assert_eq!(
                e.as_ref().and_then(|e| e.sgp4_code()),
                Some(init_error),
                "case {case}: {e:?}"
            );
            continue;
        }
        let p = result.unwrap_or_else(|e| panic!("case {case}: {e}"));
        let last_ok = errs.f(row, "last_valid_tsince_min");
        let first_err = errs.f(row, "first_error_tsince_min");
        assert!(
            p.state_teme(last_ok).is_ok(),
            "case {case}: t={last_ok} must propagate"
        );
        let e = p.state_teme(first_err).err();
        assert_eq!(
            e.as_ref().and_then(|e| e.sgp4_code()),
            Some(code),
            "case {case} t={first_err}: {e:?}"
        );
        let msg = e.map(|e| e.to_string()).unwrap_or_default();
        assert!(
            msg.contains(errs.s(row, "error_message")),
            "case {case}: {msg}"
        );
        if code == 6 {
            assert!(
                p.state_teme(first_err)
                    .err()
                    .is_some_and(|e| e.is_decayed())
            );
        }
    }
}

#[test]
fn sgp4_vallado_error_cases_are_the_ones_the_tle_file_names() {
    // Every case whose status is `error` is covered by sgp4_vallado_errors.csv, and every
    // `ok` case propagates over its whole grid (checked in the accuracy test).
    let tles = tles();
    let errs = errors();
    for row in &tles.rows {
        let case = tles.s(row, "case");
        let listed = errs.rows.iter().any(|r| errs.s(r, "case") == case);
        assert_eq!(tles.s(row, "status") == "error", listed, "case {case}");
    }
}

#[test]
fn bad_checksums_rejected_strict_accepted_lenient() {
    let tles = tles();
    let mut rejected = Vec::new();
    for row in &tles.rows {
        let (l1, l2) = (tles.s(row, "line1"), tles.s(row, "line2"));
        let ok1 = tles.s(row, "line1_checksum_ok") == "True";
        let ok2 = tles.s(row, "line2_checksum_ok") == "True";
        let strict = Tle::parse(l1, l2, ChecksumMode::Strict);
        match strict {
            Ok(_) => assert!(
                ok1 && ok2,
                "case {}: strict accepted a bad checksum",
                tles.s(row, "case")
            ),
            Err(TleError::Checksum { line, .. }) => {
                assert_eq!(line, if ok1 { 2 } else { 1 }, "the first bad line is named");
                rejected.push(tles.s(row, "satnum").to_owned());
            }
            Err(e) => panic!("case {}: strict: {e}", tles.s(row, "case")),
        }
        assert!(Tle::parse(l1, l2, ChecksumMode::Lenient).is_ok());
    }
    assert_eq!(rejected, ["33333", "33334", "33335"]);
}
