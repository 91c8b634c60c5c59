//! `tle_parser`: the orbit crate's TLE parser (`orbit::tle::Tle::parse`) on arbitrary text
//! taken as two lines (the input up to the first newline, and the rest up to the next), in
//! both checksum modes, then SGP4 (`orbit::propagate::Sgp4Propagator`) and the FC's
//! environment model (`nodes_fc::environment::EnvModel`, what ATCTLESET uploads) over a few
//! minutes from the epoch.
//!
//! Asserts: nothing panics; a TLE the strict mode accepts, the lenient mode accepts too and
//! reads the same; an accepted TLE's epoch is a real instant.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nodes_fc::environment::EnvModel;
use orbit::propagate::{Propagator, Sgp4Propagator};
use orbit::tle::{ChecksumMode, Tle};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let mut lines = text.splitn(3, '\n');
    let l1 = lines.next().unwrap_or_default();
    let l2 = lines.next().unwrap_or_default();

    let strict = Tle::parse(l1, l2, ChecksumMode::Strict);
    let lenient = Tle::parse(l1, l2, ChecksumMode::Lenient);
    if let Ok(s) = &strict {
        assert_eq!(
            lenient.as_ref().ok(),
            Some(s),
            "strict accepts, lenient differs"
        );
    }
    for tle in [strict, lenient].into_iter().flatten() {
        let _ = tle.epoch_jd_utc();
        let Ok(mut p) = Sgp4Propagator::new(&tle) else {
            continue;
        };
        for min in [0.0, 1.0, 5.0, 10.0, -3.0] {
            let _ = p.state_teme(min);
        }
        let epoch_ns = tle.epoch.unix_ns();
        for dt_s in [0i64, 60, 300] {
            let t =
                orbit::time::UtcTime::from_unix_ns(epoch_ns.saturating_add(dt_s * 1_000_000_000));
            let _ = p.state_j2000(t);
        }
        let mut env = EnvModel::new(p);
        for dt_s in [0i64, 120] {
            let _ = env.at(epoch_ns.saturating_add(dt_s * 1_000_000_000));
        }
    }
});
