//! Criterion benchmarks of m6p-orbit (short measurement times; figures go in the issue's
//! closing note).
//!
//! Groups, one per model, each a `criterion_group!` listed in `criterion_main!` at the end:
//! - `sgp4_frames`: SGP4 propagations per second (one satellite over a day at 1 s steps),
//!   TEME -> J2000 conversions per second, the full `Propagator::state_j2000` step, TEME ->
//!   ECEF and look angles. Compare the SGP4 figure with `benches/python_sgp4_bench.py`
//!   (python-sgp4's `SatrecArray`, Vallado's C++) run on the same machine.
//!
//! - `environment`: IGRF-14 evaluations per second, sun + eclipse per step, Cowell RK4
//!   steps per second (with and without drag), and one full environment step (SGP4, TEME ->
//!   J2000, Earth orientation, IGRF-14 at the satellite, sun, eclipse).

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use m6p_orbit::frames::{teme_to_ecef, teme_to_j2000};
use m6p_orbit::passes::GroundSite;
use m6p_orbit::propagate::{Propagator, Sgp4Propagator};
use m6p_orbit::time::UtcTime;
use m6p_orbit::tle::{ChecksumMode, Tle};

/// Short measurements: these benches report rates, not fine regressions.
fn short() -> Criterion {
    Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
        .sample_size(10)
}

// ---------------------------------------------------------------------------------------
// SGP4 and frames
// ---------------------------------------------------------------------------------------

/// The reference 6U cubesat TLE (`CUBESAT-6U` in tests/data/teme_to_j2000.csv).
const TLE_6U: (&str, &str) = (
    "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
    "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
);
const DAY_S: usize = 86_400;

fn cubesat() -> Sgp4Propagator {
    let tle = Tle::parse(TLE_6U.0, TLE_6U.1, ChecksumMode::Strict).expect("reference TLE");
    Sgp4Propagator::new(&tle).expect("reference TLE initialises")
}

fn bench_sgp4_day(c: &mut Criterion) {
    let p = cubesat();
    let mut g = c.benchmark_group("sgp4_frames");
    g.throughput(Throughput::Elements(DAY_S as u64));
    g.bench_function("sgp4_teme_one_day_1s_steps", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..DAY_S {
                let s = p.state_teme(k as f64 / 60.0).expect("propagates");
                acc += s.r_km.x;
            }
            black_box(acc)
        })
    });
    // The `sgp4` crate alone, without this crate's checks (decay, finiteness).
    let el = sgp4::Elements::from_tle(None, TLE_6U.0.as_bytes(), TLE_6U.1.as_bytes())
        .expect("reference TLE");
    let constants = sgp4::Constants::from_elements_afspc_compatibility_mode(&el).expect("init");
    g.bench_function("sgp4_crate_raw_one_day_1s_steps", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..DAY_S {
                let s = constants
                    .propagate(sgp4::MinutesSinceEpoch(k as f64 / 60.0))
                    .expect("propagates");
                acc += s.position[0];
            }
            black_box(acc)
        })
    });
    g.finish();
}

fn bench_frames(c: &mut Criterion) {
    let mut p = cubesat();
    let t0 = p.epoch();
    let states: Vec<_> = (0..1000)
        .map(|k| p.state_teme(f64::from(k) / 60.0).expect("propagates"))
        .collect();
    let mut g = c.benchmark_group("sgp4_frames");
    g.throughput(Throughput::Elements(states.len() as u64));
    g.bench_function("teme_to_j2000_1000_steps", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for (k, s) in states.iter().enumerate() {
                let t = t0.plus_ns(k as i64 * 1_000_000_000);
                acc += teme_to_j2000(s, t).r_km.x;
            }
            black_box(acc)
        })
    });
    g.bench_function("teme_to_ecef_1000_steps", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for (k, s) in states.iter().enumerate() {
                let t = t0.plus_ns(k as i64 * 1_000_000_000);
                acc += teme_to_ecef(s, t, None).r_km.x;
            }
            black_box(acc)
        })
    });
    let site = GroundSite::from_deg(54.6872, 25.2797, 100.0);
    g.bench_function("look_angles_1000_steps", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for s in &states {
                acc += site.look_angles(&s.r_km).elevation_rad;
            }
            black_box(acc)
        })
    });
    g.bench_function("state_j2000_sgp4_plus_frames_1000_steps", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..1000 {
                let t: UtcTime = t0.plus_ns(k * 1_000_000_000);
                acc += p.state_j2000(t).expect("propagates").r_km.x;
            }
            black_box(acc)
        })
    });
    g.finish();
}

criterion_group! {
    name = sgp4_frames;
    config = short();
    targets = bench_sgp4_day, bench_frames
}

// ---------------------------------------------------------------------------------------
// Environment: IGRF-14, sun + eclipse, Cowell steps, one full environment step
// ---------------------------------------------------------------------------------------

fn bench_igrf14(c: &mut Criterion) {
    use m6p_orbit::igrf::{GaussCoefficients, field_geodetic};
    use nalgebra::Vector3;
    let mut g = c.benchmark_group("environment");
    g.throughput(Throughput::Elements(1));
    // The date's coefficients and the field at a geodetic point, as one call.
    g.bench_function("igrf14_field_geodetic", |b| {
        let mut k = 0u32;
        b.iter(|| {
            k = k.wrapping_add(1);
            let lat_rad = (f64::from(k % 180) - 89.5).to_radians();
            black_box(field_geodetic(black_box(lat_rad), 0.44, 500.0, 2026.4))
        })
    });
    // The field at an ECEF point with the date's coefficients computed once.
    let coeffs = GaussCoefficients::igrf14(2026.4).expect("in range");
    g.bench_function("igrf14_field_ecef_cached_coefficients", |b| {
        let r_ecef_km = Vector3::new(3602.5, 1701.4, 5589.3);
        b.iter(|| black_box(coeffs.field_ecef(black_box(&r_ecef_km))))
    });
    g.finish();
}

fn bench_sun_eclipse(c: &mut Criterion) {
    use m6p_orbit::eclipse::illumination_at;
    use nalgebra::Vector3;
    let t0 = cubesat().epoch();
    let mut g = c.benchmark_group("environment");
    g.throughput(Throughput::Elements(1));
    // One step: the sun vector at a new time and the shadow at a LEO position.
    g.bench_function("sun_plus_eclipse_per_step", |b| {
        let r_eci_km = Vector3::new(-1221.0, 6117.1, 2652.1);
        let mut k = 0i64;
        b.iter(|| {
            k += 1;
            let t = t0.plus_ns(k * 1_000_000_000);
            black_box(illumination_at(black_box(t), black_box(&r_eci_km)))
        })
    });
    g.finish();
}

fn bench_cowell(c: &mut Criterion) {
    use m6p_orbit::cowell::{CowellConfig, CowellPropagator, Drag};
    let mut p = cubesat();
    let t0 = p.epoch();
    let s0 = p.state_j2000(t0).expect("propagates");
    let mut g = c.benchmark_group("environment");
    // A day at the default 10 s step: 8640 RK4 steps per iteration.
    g.throughput(Throughput::Elements(8640));
    let with_drag = CowellConfig {
        drag: Some(Drag {
            cd_area_over_mass_m2_kg: 0.02,
        }),
        ..CowellConfig::default()
    };
    for (name, config) in [
        ("cowell_rk4_steps_j2_one_day_10s", CowellConfig::default()),
        ("cowell_rk4_steps_j2_drag_one_day_10s", with_drag),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut cowell = CowellPropagator::new(t0, s0, config);
                black_box(cowell.state_j2000(t0.plus_seconds(86_400.0)))
            })
        });
    }
    g.finish();
}

fn bench_environment_step(c: &mut Criterion) {
    use m6p_orbit::eclipse::illumination;
    use m6p_orbit::frames::a_ecef_from_eci;
    use m6p_orbit::igrf::GaussCoefficients;
    use m6p_orbit::sun::sun_eci_km;
    let mut p = cubesat();
    let t0 = p.epoch();
    let mut g = c.benchmark_group("environment");
    g.throughput(Throughput::Elements(1));
    // Everything the twin needs per simulation step, at a new time each iteration: SGP4 and
    // TEME -> J2000, the Earth's orientation, the IGRF-14 coefficients for the date and the
    // field at the satellite (NED, ECEF, ECI), the sun vector and the shadow.
    g.bench_function("full_environment_step", |b| {
        let mut k = 0i64;
        b.iter(|| {
            k = (k + 1) % 86_400;
            let t = t0.plus_ns(k * 1_000_000_000);
            let s = p.state_j2000(black_box(t)).expect("propagates");
            let a_ecef_from_eci = a_ecef_from_eci(t, None);
            let field = GaussCoefficients::igrf14(t.decimal_year())
                .and_then(|c| c.field_eci(&s.r_km, &a_ecef_from_eci))
                .expect("in range");
            let sun = sun_eci_km(t);
            let ill = illumination(&s.r_km, &sun);
            black_box((s, field, sun, ill))
        })
    });
    g.finish();
}

criterion_group! {
    name = environment;
    config = short();
    targets = bench_igrf14, bench_sun_eclipse, bench_cowell, bench_environment_step
}

criterion_main!(sgp4_frames, environment);
