//! Cowell propagation: conservation laws, agreement with analytic Kepler motion, the J2
//! secular nodal rate, vis-viva after a burn, and the drag decay rate. Bounds are in the test
//! names; the measured values are printed (`--nocapture`).

use m6p_orbit::cowell::{
    CowellConfig, CowellPropagator, Drag, EARTH_RADIUS_KM, J2, MU_EARTH_KM3_S2,
    exponential_density_kg_m3,
};
use m6p_orbit::frames::OMEGA_EARTH_RAD_S;
use m6p_orbit::propagate::{PropagationError, Propagator, StateVector};
use m6p_orbit::time::UtcTime;
use nalgebra::Vector3;

const MU: f64 = MU_EARTH_KM3_S2;

fn t0() -> UtcTime {
    UtcTime::from_iso8601("2026-03-01T00:00:00Z").expect("ISO-8601")
}

/// A state from classical elements (a km, e, i, RAAN, argument of perigee, true anomaly; rad).
fn state_from_elements(a: f64, e: f64, i: f64, raan: f64, argp: f64, nu: f64) -> StateVector {
    let p = a * (1.0 - e * e);
    let r = p / (1.0 + e * nu.cos());
    let r_pqw = Vector3::new(r * nu.cos(), r * nu.sin(), 0.0);
    let v_pqw = Vector3::new(-nu.sin(), e + nu.cos(), 0.0) * (MU / p).sqrt();
    let rot = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), raan)
        * nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), i)
        * nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), argp);
    StateVector {
        r_km: rot * r_pqw,
        v_km_s: rot * v_pqw,
    }
}

fn sma_km(s: &StateVector) -> f64 {
    1.0 / (2.0 / s.r_km.norm() - s.v_km_s.norm_squared() / MU)
}

/// (semi-major axis km, eccentricity, inclination rad, RAAN rad) of an osculating state.
fn elements(s: &StateVector) -> (f64, f64, f64, f64) {
    let h = s.r_km.cross(&s.v_km_s);
    let e_vec = s.v_km_s.cross(&h) / MU - s.r_km.normalize();
    (
        sma_km(s),
        e_vec.norm(),
        (h.z / h.norm()).acos(),
        h.x.atan2(-h.y),
    )
}

/// Two-body state after `dt_s` seconds by Kepler's equation in the eccentric-anomaly
/// difference (f and g functions; Vallado 2013 algorithm 8 in its elliptic form).
fn kepler(s: &StateVector, dt_s: f64) -> StateVector {
    let r0 = s.r_km.norm();
    let a = sma_km(s);
    let sigma0 = s.r_km.dot(&s.v_km_s) / MU.sqrt();
    let n = (MU / (a * a * a)).sqrt();
    let m = n * dt_s;
    let mut de = m;
    for _ in 0..50 {
        let f = de + sigma0 / a.sqrt() * (1.0 - de.cos()) - (1.0 - r0 / a) * de.sin() - m;
        let fp = 1.0 + sigma0 / a.sqrt() * de.sin() - (1.0 - r0 / a) * de.cos();
        de -= f / fp;
    }
    let r = a + (r0 - a) * de.cos() + sigma0 * a.sqrt() * de.sin();
    let f = 1.0 - a / r0 * (1.0 - de.cos());
    let g = dt_s + (a * a * a / MU).sqrt() * (de.sin() - de);
    let fdot = -(MU * a).sqrt() / (r * r0) * de.sin();
    let gdot = 1.0 - a / r * (1.0 - de.cos());
    StateVector {
        r_km: f * s.r_km + g * s.v_km_s,
        v_km_s: fdot * s.r_km + gdot * s.v_km_s,
    }
}

/// Specific energy including the J2 potential, km^2/s^2.
fn energy_j2(s: &StateVector, with_j2: bool) -> f64 {
    let r = s.r_km.norm();
    let mut u = -MU / r;
    if with_j2 {
        let sin_lat = s.r_km.z / r;
        u += MU / r * J2 * (EARTH_RADIUS_KM / r).powi(2) * 0.5 * (3.0 * sin_lat * sin_lat - 1.0);
    }
    0.5 * s.v_km_s.norm_squared() + u
}

fn leo_500() -> StateVector {
    state_from_elements(
        EARTH_RADIUS_KM + 500.0,
        0.001,
        97.4_f64.to_radians(),
        0.3,
        1.0,
        0.5,
    )
}

const DAY_S: i64 = 86_400;

#[test]
fn energy_and_angular_momentum_conserved_to_1e_9_over_a_day_without_drag() {
    for with_j2 in [false, true] {
        let config = CowellConfig {
            j2: with_j2,
            ..CowellConfig::default()
        };
        let s0 = leo_500();
        let mut prop = CowellPropagator::new(t0(), s0, config);
        let (e0, h0) = (energy_j2(&s0, with_j2), s0.r_km.cross(&s0.v_km_s));
        let (mut worst_e, mut worst_h) = (0.0_f64, 0.0_f64);
        for k in 1..=(DAY_S / 600) {
            let s = prop
                .state_j2000(t0().plus_seconds((k * 600) as f64))
                .expect("propagates");
            let h = s.r_km.cross(&s.v_km_s);
            worst_e = worst_e.max(((energy_j2(&s, with_j2) - e0) / e0).abs());
            // Two-body: the whole vector; with J2 only its polar component is conserved.
            let dh = if with_j2 {
                (h.z - h0.z).abs()
            } else {
                (h - h0).norm()
            };
            worst_h = worst_h.max(dh / h0.norm());
        }
        println!(
            "J2 {with_j2}: worst relative energy drift {worst_e:.2e}, angular momentum {worst_h:.2e}"
        );
        assert!(worst_e < 1e-9, "energy drift {worst_e}");
        assert!(worst_h < 1e-9, "angular momentum drift {worst_h}");
    }
}

#[test]
fn two_body_agrees_with_kepler_within_1_m_over_a_day() {
    for s0 in [
        leo_500(),
        state_from_elements(7000.0, 0.05, 0.9, 1.0, 2.0, 3.0),
    ] {
        let mut prop = CowellPropagator::new(t0(), s0, CowellConfig::two_body());
        let mut worst_m = 0.0_f64;
        for k in 1..=(DAY_S / 3600) {
            let dt = (k * 3600) as f64;
            let s = prop.state_j2000(t0().plus_seconds(dt)).expect("propagates");
            worst_m = worst_m.max((s.r_km - kepler(&s0, dt).r_km).norm() * 1000.0);
        }
        println!("two-body vs Kepler: worst position difference {worst_m:.3} m over a day");
        assert!(worst_m < 1.0, "{worst_m} m");
    }
}

#[test]
fn j2_nodal_regression_matches_the_secular_rate_within_1_percent() {
    for inc_deg in [97.4_f64, 51.6, 30.0] {
        let s0 = state_from_elements(
            EARTH_RADIUS_KM + 500.0,
            0.001,
            inc_deg.to_radians(),
            0.3,
            1.0,
            0.5,
        );
        let mut prop = CowellPropagator::new(t0(), s0, CowellConfig::default());
        // Least-squares slope of the osculating node over five days (its twice-per-orbit
        // oscillation averages out), and the mean a, e, i over the same samples.
        let (mut sum_t, mut sum_o, mut sum_tt, mut sum_to) = (0.0, 0.0, 0.0, 0.0);
        let (mut sum_a, mut sum_e, mut sum_i) = (0.0, 0.0, 0.0);
        let (mut n, mut last_raan, mut unwrap) = (0.0, 0.3, 0.0);
        for k in 0..=(5 * DAY_S / 60) {
            let t = (k * 60) as f64;
            let s = prop.state_j2000(t0().plus_seconds(t)).expect("propagates");
            let (a, e, i, raan) = elements(&s);
            let mut o = raan + unwrap;
            if o - last_raan > std::f64::consts::PI {
                unwrap -= 2.0 * std::f64::consts::PI;
                o -= 2.0 * std::f64::consts::PI;
            } else if o - last_raan < -std::f64::consts::PI {
                unwrap += 2.0 * std::f64::consts::PI;
                o += 2.0 * std::f64::consts::PI;
            }
            last_raan = o;
            sum_t += t;
            sum_o += o;
            sum_tt += t * t;
            sum_to += t * o;
            sum_a += a;
            sum_e += e;
            sum_i += i;
            n += 1.0;
        }
        let rate = (n * sum_to - sum_t * sum_o) / (n * sum_tt - sum_t * sum_t);
        let (a, e, i) = (sum_a / n, sum_e / n, sum_i / n);
        let p = a * (1.0 - e * e);
        let analytic =
            -1.5 * (MU / (a * a * a)).sqrt() * J2 * (EARTH_RADIUS_KM / p).powi(2) * i.cos();
        let rel = (rate / analytic - 1.0).abs();
        println!(
            "i = {inc_deg} deg: node rate {:.6} deg/day, analytic {:.6} deg/day, relative difference {rel:.2e}",
            rate.to_degrees() * 86_400.0,
            analytic.to_degrees() * 86_400.0
        );
        assert!(rel < 0.01, "{rel}");
    }
}

#[test]
fn along_track_delta_v_raises_the_semi_major_axis_by_vis_viva_within_1_m() {
    let r0 = EARTH_RADIUS_KM + 500.0;
    let s0 = state_from_elements(r0, 0.0, 0.9, 0.1, 0.0, 0.0);
    let mut prop = CowellPropagator::new(t0(), s0, CowellConfig::two_body());
    let t_burn = t0().plus_seconds(1000.0);
    let before = prop.state_j2000(t_burn).expect("propagates");
    let dv_km_s = 0.010;
    let after = prop
        .apply_delta_v(t_burn, before.v_km_s.normalize() * dv_km_s)
        .expect("burns");
    assert_eq!(prop.anchor_epoch(), t_burn);
    assert_eq!(
        prop.state_j2000(t0().plus_seconds(999.0)),
        Err(PropagationError::BeforeStart)
    );
    // Vis-viva: 1/a = 2/r - v^2/mu with the new speed at the same radius.
    let r = before.r_km.norm();
    let v = before.v_km_s.norm() + dv_km_s;
    let a_expected = 1.0 / (2.0 / r - v * v / MU);
    assert!((sma_km(&after) - a_expected).abs() < 1e-9);
    // Half an orbit later the satellite is at apogee, 2a - r from the centre, and a is
    // still the vis-viva value.
    let period_s = 2.0 * std::f64::consts::PI * (a_expected.powi(3) / MU).sqrt();
    let s = prop
        .state_j2000(t_burn.plus_seconds(period_s / 2.0))
        .expect("propagates");
    let da_m = (sma_km(&s) - a_expected).abs() * 1000.0;
    let dapogee_m = (s.r_km.norm() - (2.0 * a_expected - r)).abs() * 1000.0;
    println!(
        "burn of {dv_km_s} km/s: a raised by {:.3} km; after half an orbit |da| = {da_m:.2e} m, |d apogee| = {dapogee_m:.2e} m",
        a_expected - sma_km(&before)
    );
    // About 2 a dv / v = 18 km for 10 m/s.
    assert!((a_expected - r - 18.1).abs() < 0.1);
    assert!(da_m < 1.0 && dapogee_m < 1.0, "{da_m} {dapogee_m}");
}

#[test]
fn drag_decay_rate_matches_the_circular_orbit_formula_within_1_percent() {
    // Equatorial circular orbit at 400 km: the height is exact, and the atmosphere's
    // co-rotation reduces the relative speed by the factor (1 - w r / v).
    let r0 = EARTH_RADIUS_KM + 400.0;
    let s0 = state_from_elements(r0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let b_m2_kg = 0.02;
    let config = CowellConfig {
        j2: false,
        drag: Some(Drag {
            cd_area_over_mass_m2_kg: b_m2_kg,
        }),
        ..CowellConfig::default()
    };
    let mut prop = CowellPropagator::new(t0(), s0, config);
    let period_s = 2.0 * std::f64::consts::PI * (r0.powi(3) / MU).sqrt();
    let orbits = 5.0;
    let s = prop
        .state_j2000(t0().plus_seconds(orbits * period_s))
        .expect("propagates");
    let rate = (sma_km(&s) - r0) / (orbits * period_s);
    let v = (MU / r0).sqrt();
    let corotation = 1.0 - OMEGA_EARTH_RAD_S * r0 / v;
    let rho_per_km = exponential_density_kg_m3(400.0) * b_m2_kg * 1000.0;
    let analytic = -rho_per_km * (MU * r0).sqrt() * corotation * corotation;
    let rel = (rate / analytic - 1.0).abs();
    println!(
        "drag at 400 km: da/dt {:.4} m/orbit, analytic {:.4} m/orbit, relative difference {rel:.2e}",
        rate * period_s * 1000.0,
        analytic * period_s * 1000.0
    );
    assert!(rel < 0.01, "{rel}");
}

#[test]
fn initialised_from_another_propagator_and_decay_is_reported() {
    struct Fixed(StateVector);
    impl Propagator for Fixed {
        fn state_j2000(&mut self, _t: UtcTime) -> Result<StateVector, PropagationError> {
            Ok(self.0)
        }
    }
    let mut source = Fixed(leo_500());
    let mut prop = CowellPropagator::from_propagator(&mut source, t0(), CowellConfig::default())
        .expect("initialises");
    assert_eq!(prop.state_j2000(t0()), Ok(leo_500()));

    // Straight down at 1 km/s from 100 km: below the surface within two minutes.
    let falling = StateVector {
        r_km: Vector3::new(EARTH_RADIUS_KM + 100.0, 0.0, 0.0),
        v_km_s: Vector3::new(-1.0, 0.0, 0.0),
    };
    let mut prop = CowellPropagator::new(t0(), falling, CowellConfig::default());
    assert_eq!(
        prop.state_j2000(t0().plus_seconds(300.0)),
        Err(PropagationError::Decayed)
    );
}

#[test]
fn from_an_sgp4_state_cowell_stays_within_2_km_of_sgp4_over_an_orbit() {
    use m6p_orbit::propagate::Sgp4Propagator;
    use m6p_orbit::tle::{ChecksumMode, Tle};
    // The ISS-like TLE of `tests/data/teme_to_j2000.csv`.
    let tle = Tle::parse(
        "1 99901U 24001A   24075.50000000  .00016717  00000-0  30270-3 0  9995",
        "2 99901  51.6416 247.4627 0006703 130.5360 325.0288 15.49812345440007",
        ChecksumMode::Strict,
    )
    .expect("a valid TLE");
    let mut sgp4 = Sgp4Propagator::new(&tle).expect("initialises");
    let start = tle.epoch.plus_seconds(600.0);
    let mut cowell = CowellPropagator::from_propagator(&mut sgp4, start, CowellConfig::default())
        .expect("initialises");
    let mut worst_km = 0.0_f64;
    for k in 1..=93 {
        let t = start.plus_seconds(f64::from(k) * 60.0);
        let d = cowell.state_j2000(t).expect("propagates").r_km
            - sgp4.state_j2000(t).expect("propagates").r_km;
        worst_km = worst_km.max(d.norm());
    }
    // SGP4 adds J3, J4, drag and mean-element theory; J2-only Cowell from an osculating state
    // drifts from it (measured: 0.48 km in one orbit). A frame or unit error would be thousands of km.
    println!("Cowell (J2) vs SGP4 over one orbit from an SGP4 state: worst {worst_km:.3} km");
    assert!(worst_km < 2.0, "{worst_km} km");
}
