//! The environment models allocate nothing per step: sun, eclipse, IGRF-14 (after the
//! one-time parse of the embedded coefficient file) and Cowell integration steps, counted
//! with a global allocator.

use m6p_orbit::cowell::{CowellConfig, CowellPropagator, Drag};
use m6p_orbit::eclipse::illumination_at;
use m6p_orbit::frames::a_ecef_from_eci;
use m6p_orbit::igrf::{GaussCoefficients, field_eci_at, field_geodetic};
use m6p_orbit::propagate::{Propagator, StateVector};
use m6p_orbit::sun::sun_eci_km;
use m6p_orbit::time::UtcTime;
use nalgebra::Vector3;

mod counting_alloc;
use counting_alloc::allocations;

#[test]
fn environment_steps_do_not_allocate() {
    let t0 = UtcTime::from_unix_ns(1_780_000_000_000_000_000); // 2026-05-28
    let s0 = StateVector {
        r_km: Vector3::new(6878.137, 0.0, 0.0),
        v_km_s: Vector3::new(0.0, 1.0, 7.5),
    };
    let config = CowellConfig {
        drag: Some(Drag {
            cd_area_over_mass_m2_kg: 0.02,
        }),
        ..CowellConfig::default()
    };
    let mut cowell = CowellPropagator::new(t0, s0, config);
    // One-time initialisation (the coefficient file's parse) before counting.
    let year = t0.decimal_year();
    field_geodetic(0.1, 0.2, 500.0, year).unwrap_or_else(|e| panic!("{e}"));

    // Another thread allocating meanwhile (as the test harness does) is not counted.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let noise = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut n = 0usize;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                n += std::hint::black_box(vec![1u8; 16]).len();
            }
            n
        })
    };
    let before = allocations();
    let mut acc = 0.0;
    for k in 0..1000 {
        let t = t0.plus_ns(k * 1_000_000_000);
        let s = cowell.state_j2000(t).unwrap_or_else(|_| unreachable!());
        let sun = sun_eci_km(t);
        let ill = illumination_at(t, &s.r_km);
        let b = field_eci_at(t, &s.r_km, None).unwrap_or_else(|_| unreachable!());
        let coeffs = GaussCoefficients::igrf14(year).unwrap_or_else(|_| unreachable!());
        let a = a_ecef_from_eci(t, None);
        let f = coeffs
            .field_ecef(&(a * s.r_km))
            .unwrap_or_else(|_| unreachable!());
        acc += sun.x + ill.visible_fraction + b.b_eci_nt.x + f.b_ned_nt.z;
    }
    let after = allocations();
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    assert!(noise.join().is_ok_and(|n| n > 0));
    assert!(acc.is_finite());
    assert_eq!(after - before, 0, "allocations in the environment loop");
    // The counter itself works.
    let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(4));
    assert!(allocations() > after && v.capacity() >= 4);
}
