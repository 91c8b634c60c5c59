//! Robustness: SGP4 on arbitrary element values, the ISO-8601 and IERS finals parsers on
//! arbitrary text: errors, never panics.

use m6p_orbit::propagate::Sgp4Propagator;
use m6p_orbit::time::{EopTable, UtcTime};
use m6p_orbit::tle::{ChecksumMode, Tle};
use proptest::prelude::*;

fn base() -> Tle {
    Tle::parse(
        "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
        "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
        ChecksumMode::Strict,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    #[test]
    fn sgp4_never_panics_on_any_elements(
        incl in 0.0f64..180.0,
        raan in 0.0f64..360.0,
        ecc in 0.0f64..0.9999999,
        argp in 0.0f64..360.0,
        ma in 0.0f64..360.0,
        n in prop_oneof![0.0f64..20.0, 0.0f64..1e-3, 15.0f64..100.0],
        bstar in -1.0f64..1.0,
        t in prop_oneof![-1e6f64..1e6, -1e3f64..1e3],
    ) {
        let mut tle = base();
        tle.inclination_deg = incl;
        tle.raan_deg = raan;
        tle.eccentricity = ecc;
        tle.arg_perigee_deg = argp;
        tle.mean_anomaly_deg = ma;
        tle.mean_motion_rev_day = n;
        tle.bstar_per_earth_radii = bstar;
        if let Ok(p) = Sgp4Propagator::new(&tle) {
            match p.state_teme(t) {
                Ok(s) => prop_assert!(s.r_km.norm() >= 6378.135 && s.r_km.iter().all(|x| x.is_finite())),
                Err(e) => prop_assert!(matches!(e.sgp4_code(), Some(1..=6))),
            }
        }
    }

    #[test]
    fn iso8601_never_panics(s in ".*") {
        let _ = UtcTime::from_iso8601(&s);
    }

    #[test]
    fn iso8601_round_trips(ns in -5_000_000_000_000_000_000i64..5_000_000_000_000_000_000) {
        // Display keeps microseconds.
        let t = UtcTime::from_unix_ns(ns / 1000 * 1000);
        let back = UtcTime::from_iso8601(&t.to_string());
        prop_assert_eq!(back, Ok(t));
    }

    #[test]
    fn finals_parser_never_panics(s in "([ -~]{0,190}\n){0,4}") {
        let _ = EopTable::parse_finals(&s);
    }

    #[test]
    fn plus_seconds_saturates(ns in any::<i64>(), s in any::<f64>()) {
        let _ = UtcTime::from_unix_ns(ns).plus_seconds(s);
        let _ = UtcTime::from_unix_s(s).jd_tt();
        let _ = UtcTime::from_unix_ns(ns).decimal_year();
    }
}
