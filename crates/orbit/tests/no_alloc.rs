//! The per-step hot paths allocate nothing: SGP4 propagation, TEME -> J2000 / ECEF, the
//! `Propagator` step, geodetic conversion and look angles, counted with a global allocator.

use m6p_orbit::frames::{a_j2000_from_teme, teme_to_ecef, teme_to_j2000};
use m6p_orbit::geodetic::{ecef_km_to_geodetic, geodetic_to_ecef_m};
use m6p_orbit::passes::GroundSite;
use m6p_orbit::propagate::{Propagator, Sgp4Propagator};
use m6p_orbit::time::{Eop, gmst82};
use m6p_orbit::tle::{ChecksumMode, Tle};

mod counting_alloc;
use counting_alloc::allocations;

#[test]
fn hot_paths_do_not_allocate() {
    let tle = Tle::parse(
        "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
        "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
        ChecksumMode::Strict,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let mut p = Sgp4Propagator::new(&tle).unwrap_or_else(|e| panic!("{e}"));
    let site = GroundSite::from_deg(54.6872, 25.2797, 100.0);
    let eop = Eop {
        ut1_minus_utc_s: 0.03,
        xp_arcsec: 0.15,
        yp_arcsec: 0.41,
    };
    let t0 = p.epoch();
    let before = allocations();
    let mut acc = 0.0;
    for k in 0..1000 {
        let t = t0.plus_ns(k * 1_000_000_000);
        let s = p.state_teme_at(t).unwrap_or_else(|_| unreachable!());
        let j = teme_to_j2000(&s, t);
        let e = teme_to_ecef(&s, t, Some(&eop));
        let g = ecef_km_to_geodetic(&e.r_km);
        let back = geodetic_to_ecef_m(&g);
        let look = site.look_angles(&e.r_km);
        let via = p.state_j2000(t).unwrap_or_else(|_| unreachable!());
        acc += j.r_km.x + back.x + look.elevation_rad + via.r_km.y + gmst82(t.jd_ut1(None));
        acc += a_j2000_from_teme(t)[(0, 0)];
    }
    let after = allocations();
    assert!(acc.is_finite());
    assert_eq!(after - before, 0, "allocations in the hot loop");
    // The counter itself works.
    let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(4));
    assert!(allocations() > after && v.capacity() >= 4);
}
