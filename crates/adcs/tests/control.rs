//! Guidance and control (`adcs::guidance`, `adcs::control`) on the default
//! scenario's orbit, closed loop against the attitude truth (`adcs::truth::step`, RK4 at
//! 0.1 s) with perfect knowledge. The environment (SGP4 orbit, IGRF-14 field, sun, Earth
//! orientation) is sampled every second and interpolated linearly in between.
#![allow(clippy::unwrap_used)]

use m6p_adcs::control::{
    self, ControlConfig, allocate_wheel_torques, attitude_torque_nm, bdot_dipole_am2,
    desat_dipole_am2, mtq_torque_body_nm, wheel_commands_nm,
};
use m6p_adcs::guidance::{
    self, DEFAULT_PANEL_NORMAL_BODY, GuidanceInputs, GuidanceTarget, Pointing,
};
use m6p_adcs::truth::{
    AttitudeState, BodyConfig, Torques, WheelConfig, step, wheel_momentum_body_nms,
};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use orbit::frames::{self, OMEGA_EARTH_RAD_S};
use orbit::geodetic::{Geodetic, ecef_m_to_geodetic};
use orbit::igrf::GaussCoefficients;
use orbit::propagate::{Propagator, Sgp4Propagator};
use orbit::time::UtcTime;
use orbit::tle::{ChecksumMode, Tle};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

/// The default scenario's 6U TLE (scenarios/default.toml).
const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
/// 2026-04-30T18:00:00Z, the default scenario's `start`.
const START_UNIX_S: i64 = 1_777_572_000;
/// The ADCS and truth step, s.
const DT_S: f64 = 0.1;
/// Orbital period of the default orbit, s (86400 / 15.145).
const PERIOD_S: f64 = 86_400.0 / 15.145;

/// The environment at one instant.
#[derive(Debug, Clone, Copy)]
struct Env {
    r_eci_m: Vector3<f64>,
    v_eci_m_s: Vector3<f64>,
    b_eci_nt: Vector3<f64>,
    sun_eci_unit: Vector3<f64>,
    a_ecef_from_eci: Matrix3<f64>,
}

impl Env {
    fn guidance_inputs(&self, unix_s: f64) -> GuidanceInputs {
        GuidanceInputs {
            unix_s,
            r_eci_m: self.r_eci_m,
            v_eci_m_s: self.v_eci_m_s,
            sun_eci_unit: self.sun_eci_unit,
            a_ecef_from_eci: self.a_ecef_from_eci,
        }
    }
}

fn utc(t_s: f64) -> UtcTime {
    UtcTime::from_unix_ns(START_UNIX_S * 1_000_000_000 + (t_s * 1e9).round() as i64)
}

/// The environment sampled every second from the start for `duration_s`.
struct Orbit {
    samples: Vec<Env>,
}

impl Orbit {
    fn new(duration_s: usize) -> Self {
        let mut prop =
            Sgp4Propagator::new(&Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()).unwrap();
        let coeffs = GaussCoefficients::igrf14(utc(0.0).decimal_year()).unwrap();
        let samples = (0..=duration_s + 1)
            .map(|k| {
                let t = utc(k as f64);
                let s = prop.state_j2000(t).unwrap();
                let a = frames::a_ecef_from_eci(t, None);
                Env {
                    r_eci_m: s.r_km * 1e3,
                    v_eci_m_s: s.v_km_s * 1e3,
                    b_eci_nt: coeffs.field_eci(&s.r_km, &a).unwrap().b_eci_nt,
                    sun_eci_unit: orbit::sun::sun_eci_km(t).normalize(),
                    a_ecef_from_eci: a,
                }
            })
            .collect();
        Orbit { samples }
    }

    /// Linear interpolation between the samples (the Earth's rotation applied exactly).
    fn at(&self, t_s: f64) -> Env {
        let k = (t_s.floor() as usize).min(self.samples.len() - 2);
        let f = t_s - k as f64;
        let (a, b) = (&self.samples[k], &self.samples[k + 1]);
        let lerp = |x: &Vector3<f64>, y: &Vector3<f64>| x + (y - x) * f;
        Env {
            r_eci_m: lerp(&a.r_eci_m, &b.r_eci_m),
            v_eci_m_s: lerp(&a.v_eci_m_s, &b.v_eci_m_s),
            b_eci_nt: lerp(&a.b_eci_nt, &b.b_eci_nt),
            sun_eci_unit: a.sun_eci_unit,
            a_ecef_from_eci: frames::rot3(OMEGA_EARTH_RAD_S * f) * a.a_ecef_from_eci,
        }
    }
}

/// What the loop flies.
#[derive(Debug, Clone, Copy)]
enum Mode {
    Detumble,
    Point(Pointing),
}

/// The closed loop: perfect knowledge, the flight laws, the truth.
struct Sim<'a> {
    orbit: &'a Orbit,
    body: BodyConfig,
    cfg: ControlConfig,
    s: AttitudeState,
    t_s: f64,
    b_prev_body_nt: Option<Vector3<f64>>,
    disturbance_body_nm: Vector3<f64>,
    healthy: [bool; 4],
    /// Use `wheel_commands_nm` (null motion, friction feed-forward) rather than the plain
    /// allocation.
    null_motion: bool,
    /// Subtract the magnetorquer torque from the wheel request.
    mtq_feedforward: bool,
    /// The last target, and the attitude error from it at the start of the last step, deg.
    last_target: Option<GuidanceTarget>,
    last_error_deg: f64,
    peak_wheel_speed_rad_s: f64,
    peak_dipole_am2: f64,
}

impl<'a> Sim<'a> {
    fn new(orbit: &'a Orbit, s: AttitudeState) -> Self {
        Sim {
            orbit,
            body: BodyConfig::default(),
            cfg: ControlConfig::default(),
            s,
            t_s: 0.0,
            b_prev_body_nt: None,
            disturbance_body_nm: Vector3::zeros(),
            healthy: [true; 4],
            null_motion: false,
            mtq_feedforward: true,
            last_target: None,
            last_error_deg: f64::NAN,
            peak_wheel_speed_rad_s: 0.0,
            peak_dipole_am2: 0.0,
        }
    }

    fn step(&mut self, mode: Mode) {
        let env = self.orbit.at(self.t_s);
        let b_body_nt = self
            .s
            .q_eci_from_body
            .inverse_transform_vector(&env.b_eci_nt);
        let max_dipole = self.body.mtq_max_dipole_am2;
        let mut wheel_torque_cmd_nm = [0.0; 4];
        let mut mtq = Vector3::zeros();
        match mode {
            Mode::Detumble => {
                if let Some(prev) = self.b_prev_body_nt {
                    mtq = bdot_dipole_am2(&b_body_nt, &prev, DT_S, &self.cfg, max_dipole);
                }
            }
            Mode::Point(p) => {
                let g = env.guidance_inputs(START_UNIX_S as f64 + self.t_s);
                let target = guidance::target(&p, &g).unwrap();
                let h_w = wheel_momentum_body_nms(&self.body, &self.s.wheel_speed_rad_s);
                let mut torque = attitude_torque_nm(
                    &self.s.q_eci_from_body,
                    &self.s.w_body_rad_s,
                    &target,
                    &h_w,
                    &self.body.inertia_kg_m2,
                    &self.cfg,
                );
                mtq = desat_dipole_am2(&h_w, &b_body_nt, &self.cfg, max_dipole);
                if self.mtq_feedforward {
                    torque -= mtq_torque_body_nm(&mtq, &b_body_nt);
                }
                wheel_torque_cmd_nm = if self.null_motion {
                    wheel_commands_nm(
                        &torque,
                        &self.body.wheels,
                        self.healthy,
                        &self.s.wheel_speed_rad_s,
                        &self.cfg,
                    )
                } else {
                    allocate_wheel_torques(&torque, &self.body.wheels, self.healthy)
                };
                self.last_target = Some(target);
                self.last_error_deg = self
                    .s
                    .q_eci_from_body
                    .angle_to(&target.q_eci_from_body)
                    .to_degrees();
            }
        }
        self.b_prev_body_nt = Some(b_body_nt);
        self.peak_dipole_am2 = self.peak_dipole_am2.max(mtq.amax());
        let inputs = Torques {
            wheel_torque_cmd_nm,
            mtq_dipole_cmd_am2: mtq,
            b_body_t: b_body_nt * 1e-9,
            r_eci_m: Some(env.r_eci_m),
            disturbance_body_nm: self.disturbance_body_nm,
        };
        self.s = step(&self.s, &self.body, &inputs, DT_S);
        self.t_s += DT_S;
        for w in self.s.wheel_speed_rad_s {
            self.peak_wheel_speed_rad_s = self.peak_wheel_speed_rad_s.max(w.abs());
        }
    }

    /// Angle between the attitude and the target, both at the start of the last step, deg.
    fn error_deg(&self) -> f64 {
        self.last_error_deg
    }

    fn rate_deg_s(&self) -> f64 {
        self.s.w_body_rad_s.norm().to_degrees()
    }

    fn wheel_momentum_nms(&self) -> f64 {
        wheel_momentum_body_nms(&self.body, &self.s.wheel_speed_rad_s).norm()
    }
}

fn max_speed(body: &BodyConfig) -> f64 {
    body.wheels[0].max_speed_rad_s
}

fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::from_fn(|_, _| 2.0 * uniform(rng) - 1.0);
        let n = v.norm();
        if n > 0.1 && n <= 1.0 {
            return v / n;
        }
    }
}

fn body_torque(tau: &[f64; 4], wheels: &[WheelConfig; 4]) -> Vector3<f64> {
    -wheels
        .iter()
        .zip(tau)
        .fold(Vector3::zeros(), |s, (w, t)| s + w.axis_body * *t)
}

// ---------------------------------------------------------------------------------------
// Guidance
// ---------------------------------------------------------------------------------------

#[test]
fn nadir_target_is_lvlh_with_the_orbital_rate_within_1_percent() {
    let orbit = Orbit::new(120);
    for t_s in [0.0, 37.5, 100.0] {
        let e = orbit.at(t_s);
        let g = e.guidance_inputs(0.0);
        let t = guidance::target(&Pointing::Nadir, &g).unwrap();
        let lvlh = frames::q_eci_from_lvlh(&(e.r_eci_m * 1e-3), &(e.v_eci_m_s * 1e-3));
        assert!(t.q_eci_from_body.angle_to(&lvlh) < 1e-12);
        assert!((t.q_eci_from_body * Vector3::z() + e.r_eci_m.normalize()).norm() < 1e-12);
        // LVLH turns about -h, i.e. about its own -Y, at |r x v| / |r|^2.
        let n = e.r_eci_m.cross(&e.v_eci_m_s).norm() / e.r_eci_m.norm_squared();
        let w = t.w_body_rad_s;
        assert!((w.norm() - n).abs() < 0.01 * n, "{w} vs {n}");
        assert!((w.normalize() + Vector3::y()).norm() < 1e-3, "{w}");
        // Measured: the central difference is far better than the 1 % asked.
        assert!((w.norm() - n).abs() < 1e-5 * n, "{} vs {n}", w.norm());
    }
}

#[test]
fn target_rate_predicts_the_next_second_of_sgp4() {
    let orbit = Orbit::new(400);
    // A pass over a point near the ground track: evaluate while it is in view.
    let e0 = orbit.at(300.0);
    let sub = ecef_m_to_geodetic(&(e0.a_ecef_from_eci * e0.r_eci_m));
    let modes = [
        Pointing::Nadir,
        Pointing::Velocity,
        Pointing::FixedTnw(UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3)),
        Pointing::SunMaxPower {
            panel_normal_body: DEFAULT_PANEL_NORMAL_BODY,
        },
        Pointing::EarthTarget {
            lat_deg: sub.lat_deg() + 1.0,
            lon_deg: sub.lon_deg() + 1.0,
            alt_m: 0.0,
            axis_body: Vector3::z(),
        },
    ];
    for p in &modes {
        for t_s in [250.0, 290.0, 300.0, 330.0] {
            let t0 = guidance::target(p, &orbit.at(t_s).guidance_inputs(0.0)).unwrap();
            let t1 = guidance::target(p, &orbit.at(t_s + 1.0).guidance_inputs(0.0)).unwrap();
            let predicted =
                t0.q_eci_from_body * UnitQuaternion::from_scaled_axis(t0.w_body_rad_s * 1.0);
            let miss = predicted.angle_to(&t1.q_eci_from_body);
            let moved = t0.q_eci_from_body.angle_to(&t1.q_eci_from_body);
            assert!(moved > 1e-4, "{p:?} {moved}");
            // Within 2 % of the motion over the second (the rest is the change of rate).
            assert!(miss < 0.02 * moved, "{p:?} at {t_s}: {miss} of {moved}");
            // With the acceleration, second order: better still where the rate changes.
            let predicted2 = t0.q_eci_from_body
                * UnitQuaternion::from_scaled_axis(t0.w_body_rad_s + t0.dw_body_rad_s2 * 0.5);
            let miss2 = predicted2.angle_to(&t1.q_eci_from_body);
            if let Pointing::EarthTarget { .. } = p {
                assert!(miss2 < 0.1 * miss, "{t_s}: {miss2} vs {miss}");
            } else {
                assert!(miss2 < miss + 1e-9, "{p:?} at {t_s}: {miss2} vs {miss}");
            }
        }
    }
}

#[test]
#[allow(clippy::approx_constant)] // the ICD's literal digits
fn point_eci_example_puts_body_y_on_eci_x_and_z_on_z() {
    let q =
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(0.707106, 0.0, 0.0, -0.707106));
    let orbit = Orbit::new(2);
    let t = guidance::target(&Pointing::FixedEci(q), &orbit.at(0.0).guidance_inputs(0.0)).unwrap();
    assert!((t.q_eci_from_body * Vector3::y() - Vector3::x()).norm() < 1e-12);
    assert!((t.q_eci_from_body * Vector3::z() - Vector3::z()).norm() < 1e-12);
    assert_eq!(t.w_body_rad_s, Vector3::zeros());
    assert_eq!(t.axis_body, Vector3::z());
    assert!((t.axis_target_eci - Vector3::z()).norm() < 1e-12);
    // pointLVLH identity is nadir; pointTNW identity is TNW.
    let e = orbit.at(0.0);
    let g = e.guidance_inputs(0.0);
    let lvlh = guidance::target(&Pointing::FixedLvlh(UnitQuaternion::identity()), &g).unwrap();
    let nadir = guidance::target(&Pointing::Nadir, &g).unwrap();
    assert!(lvlh.q_eci_from_body.angle_to(&nadir.q_eci_from_body) < 1e-12);
    assert!((lvlh.w_body_rad_s - nadir.w_body_rad_s).norm() < 1e-12);
    let tnw = guidance::target(&Pointing::FixedTnw(UnitQuaternion::identity()), &g).unwrap();
    let (r_km, v_km_s) = (e.r_eci_m * 1e-3, e.v_eci_m_s * 1e-3);
    assert!(
        tnw.q_eci_from_body
            .angle_to(&frames::q_eci_from_tnw(&r_km, &v_km_s))
            < 1e-12
    );
}

#[test]
fn earth_target_line_of_sight_and_elevation() {
    let orbit = Orbit::new(2);
    let e = orbit.at(0.0);
    let g = e.guidance_inputs(0.0);
    let sat_ecef = e.a_ecef_from_eci * e.r_eci_m;
    // The point straight below the satellite (geodetic nadir): elevation 90 deg, and with
    // +Z as the axis the attitude is nadir's up to the deflection of the vertical.
    let sub = ecef_m_to_geodetic(&sat_ecef);
    let p = Pointing::EarthTarget {
        lat_deg: sub.lat_deg(),
        lon_deg: sub.lon_deg(),
        alt_m: 0.0,
        axis_body: Vector3::z(),
    };
    let t = guidance::target(&p, &g).unwrap();
    let el = t.target_elevation_deg.unwrap();
    assert!(el > 89.999, "{el}");
    let nadir = guidance::target(&Pointing::Nadir, &g).unwrap();
    let dev = t
        .q_eci_from_body
        .angle_to(&nadir.q_eci_from_body)
        .to_degrees();
    // Geodetic vs geocentric vertical: at most 0.19 deg at 45 deg latitude.
    assert!(dev < 0.2, "{dev}");

    // Vilnius (ICD 1.5 example) with an oblique axis: the axis is on the line of sight.
    let axis = Vector3::new(0.3, -0.2, 1.0);
    let p = Pointing::EarthTarget {
        lat_deg: 54.6872,
        lon_deg: 25.2797,
        alt_m: 100.0,
        axis_body: axis,
    };
    let t = guidance::target(&p, &g).unwrap();
    let site_ecef = Geodetic::from_deg(54.6872, 25.2797, 100.0).to_ecef_m();
    let los_eci = e.a_ecef_from_eci.transpose() * (site_ecef - sat_ecef);
    assert!((t.q_eci_from_body * axis.normalize() - los_eci.normalize()).norm() < 1e-12);
    assert!((t.axis_target_eci - los_eci.normalize()).norm() < 1e-12);
    assert!(t.axis_error_rad(&t.q_eci_from_body) < 1e-12);
    // Elevation, independently: 90 deg minus the angle between the local vertical and the
    // direction to the satellite.
    let up = Geodetic::from_deg(54.6872, 25.2797, 0.0).to_ecef_m()
        - Geodetic::from_deg(54.6872, 25.2797, -1000.0).to_ecef_m();
    let d = sat_ecef - site_ecef;
    let want = 90.0 - up.angle(&d).to_degrees();
    assert!((t.target_elevation_deg.unwrap() - want).abs() < 1e-6);
}

#[test]
fn sun_max_power_puts_the_panel_on_the_sun_and_z_closest_to_nadir() {
    let orbit = Orbit::new(3000);
    for t_s in [0.0, 1000.0, 2500.0] {
        let e = orbit.at(t_s);
        let t = guidance::target(
            &Pointing::SunMaxPower {
                panel_normal_body: DEFAULT_PANEL_NORMAL_BODY,
            },
            &e.guidance_inputs(0.0),
        )
        .unwrap();
        let q = t.q_eci_from_body;
        assert!((q * DEFAULT_PANEL_NORMAL_BODY - e.sun_eci_unit).norm() < 1e-12);
        let nadir = -e.r_eci_m.normalize();
        let best = (1.0 - e.sun_eci_unit.dot(&nadir).powi(2)).sqrt();
        assert!(((q * Vector3::z()).dot(&nadir) - best).abs() < 1e-12);
    }
}

#[test]
fn velocity_pointing_puts_z_on_velocity_and_x_closest_to_zenith() {
    let orbit = Orbit::new(2);
    let e = orbit.at(0.0);
    let t = guidance::target(&Pointing::Velocity, &e.guidance_inputs(0.0)).unwrap();
    let q = t.q_eci_from_body;
    let v = e.v_eci_m_s.normalize();
    let r = e.r_eci_m.normalize();
    assert!((q * Vector3::z() - v).norm() < 1e-12);
    let best = (1.0 - r.dot(&v).powi(2)).sqrt();
    assert!(((q * Vector3::x()).dot(&r) - best).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------
// Allocation
// ---------------------------------------------------------------------------------------

#[test]
fn allocation_gives_the_requested_body_torque_with_four_or_three_wheels() {
    let body = BodyConfig::default();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut sets = vec![[true; 4]];
    for failed in 0..4 {
        let mut h = [true; 4];
        h[failed] = false;
        sets.push(h);
    }
    for healthy in sets {
        for _ in 0..200 {
            // Up to 1 mN m: below every limit with three or four wheels.
            let req = random_unit(&mut rng) * (1e-3 * uniform(&mut rng));
            let tau = allocate_wheel_torques(&req, &body.wheels, healthy);
            let got = body_torque(&tau, &body.wheels);
            assert!((got - req).norm() < 1e-15, "{healthy:?} {req} {got}");
            for i in 0..4 {
                assert!(tau[i].abs() <= body.wheels[i].max_torque_nm);
                if !healthy[i] {
                    assert_eq!(tau[i], 0.0);
                }
            }
        }
    }
    // Four wheels: the minimum-norm solution has no null-space component.
    let tau = allocate_wheel_torques(&Vector3::new(3e-4, -1e-4, 2e-4), &body.wheels, [true; 4]);
    assert!((tau[0] - tau[1] + tau[2] - tau[3]).abs() < 1e-18);
}

#[test]
fn allocation_scales_uniformly_at_the_limit() {
    let body = BodyConfig::default();
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    for healthy in [[true; 4], [true, true, false, true]] {
        for _ in 0..100 {
            let req = random_unit(&mut rng) * 0.05;
            let tau = allocate_wheel_torques(&req, &body.wheels, healthy);
            let got = body_torque(&tau, &body.wheels);
            // Direction kept, one wheel exactly at its limit.
            assert!((got.normalize() - req.normalize()).norm() < 1e-12);
            let peak = tau.iter().fold(0.0_f64, |a, b| a.max(b.abs()));
            assert!((peak - 2e-3).abs() < 1e-15, "{peak}");
        }
    }
}

#[test]
fn allocation_with_two_wheels_is_the_least_squares_best_effort() {
    let body = BodyConfig::default();
    let healthy = [true, true, false, false];
    let req = Vector3::new(2e-4, -3e-4, 1e-4);
    let got = body_torque(
        &allocate_wheel_torques(&req, &body.wheels, healthy),
        &body.wheels,
    );
    // The projection on the plane of the two healthy axes.
    let n = body.wheels[0]
        .axis_body
        .cross(&body.wheels[1].axis_body)
        .normalize();
    let want = req - n * n.dot(&req);
    assert!((got - want).norm() < 1e-15, "{got} {want}");
    assert_eq!(
        allocate_wheel_torques(&req, &body.wheels, [false; 4]),
        [0.0; 4]
    );
    let nan = Vector3::new(f64::NAN, 0.0, 0.0);
    assert_eq!(
        allocate_wheel_torques(&nan, &body.wheels, [true; 4]),
        [0.0; 4]
    );
}

#[test]
fn null_motion_spreads_the_wheels_without_disturbing_the_body() {
    let body = BodyConfig::default();
    let cfg = ControlConfig::default();
    let mut s = AttitudeState {
        wheel_speed_rad_s: [3.0, -1.0, 2.0, 0.5],
        ..Default::default()
    };
    let h0 = s.h_body_nms(&body);
    let zero = Vector3::zeros();
    for _ in 0..3000 {
        let cmd = wheel_commands_nm(&zero, &body.wheels, [true; 4], &s.wheel_speed_rad_s, &cfg);
        let inputs = Torques {
            wheel_torque_cmd_nm: cmd,
            ..Default::default()
        };
        s = step(&s, &body, &inputs, DT_S);
    }
    // After 300 s (6 time constants of 1/0.02 s... at the torque cap, 5 % of 2 mN m), every
    // wheel sits near the bias, the body has not moved.
    for w in s.wheel_speed_rad_s {
        assert!(
            (w.abs() - cfg.null_speed_rad_s).abs() < 0.05 * cfg.null_speed_rad_s,
            "{:?}",
            s.wheel_speed_rad_s
        );
    }
    assert!(s.w_body_rad_s.norm() < 1e-9, "{}", s.w_body_rad_s);
    assert!((s.h_body_nms(&body) - h0).norm() < 1e-12);
    // With a wheel failed there is no null space: no null torque.
    let cmd = wheel_commands_nm(
        &zero,
        &body.wheels,
        [true, false, true, true],
        &[0.0; 4],
        &cfg,
    );
    assert_eq!(cmd, [0.0; 4]);
}

// ---------------------------------------------------------------------------------------
// Closed loop
// ---------------------------------------------------------------------------------------

/// B-dot from 10 deg/s about a random axis. The bound: the initial momentum over the
/// average magnetorquer torque. With a dipole of 0.2 A m^2 per axis in a field of
/// 20-50 uT (30 uT typical), and the useful part of the torque (the rate perpendicular to
/// the field, the dipole along `dB/dt`) about half of `m |B|` on average, the torque is
/// about 0.5 x 0.2 x 30e-6 = 3 uN m, so `|H0| / 3e-6` s (7500 s for 0.0226 N m s). The
/// slow linear end (below 1.6 deg/s the dipole is unsaturated and the rate decays with a
/// time constant of `I / k`, 0.13 / 2.2e-4 = 590 s) fits inside it: the saturated phase
/// does better than the average, as the per-axis clamp gives up to 0.35 A m^2.
#[test]
fn bdot_detumbles_10_deg_s_to_below_0_5_deg_s_within_the_momentum_bound() {
    let duration = 3.0 * PERIOD_S;
    let orbit = Orbit::new(duration as usize);
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    let mut times = Vec::new();
    for _ in 0..2 {
        let axis = random_unit(&mut rng);
        let s0 = AttitudeState {
            q_eci_from_body: UnitQuaternion::from_scaled_axis(random_unit(&mut rng) * 2.0),
            w_body_rad_s: axis * 10.0_f64.to_radians(),
            ..Default::default()
        };
        let body = BodyConfig::default();
        let h0 = s0.h_body_nms(&body).norm();
        let bound_s = h0 / (0.5 * body.mtq_max_dipole_am2 * 30e-6);
        let mut sim = Sim::new(&orbit, s0);
        let mut below_at = None;
        let mut e_prev = sim.s.body_energy_j(&body);
        let mut energy_rises = 0;
        while sim.t_s < duration {
            sim.step(Mode::Detumble);
            let e = sim.s.body_energy_j(&body);
            if e > e_prev * (1.0 + 1e-9) {
                energy_rises += 1;
            }
            e_prev = e;
            if below_at.is_none() && sim.rate_deg_s() < 0.5 {
                below_at = Some(sim.t_s);
                break;
            }
        }
        let t = below_at.unwrap_or(f64::INFINITY);
        eprintln!(
            "detumble: axis {axis:.3?}, |H0| {h0:.4} N m s, below 0.5 deg/s after {t:.0} s \
             (bound {bound_s:.0} s), peak dipole {:.3} A m^2, energy rose in {energy_rises} steps",
            sim.peak_dipole_am2
        );
        assert!(t < bound_s, "{t} s vs bound {bound_s} s");
        times.push(t);
    }
    assert!(times.iter().all(|t| t.is_finite()));
}

/// 150 deg from nadir, at rest in ECI, slewing to nadir: (settle time s, final error deg,
/// peak rate deg/s, peak wheel speed rad/s).
fn slew_run(null_motion: bool) -> (f64, f64, f64, f64) {
    let duration = 600.0;
    let orbit = Orbit::new(duration as usize);
    let e = orbit.at(0.0);
    let nadir = guidance::target(&Pointing::Nadir, &e.guidance_inputs(0.0)).unwrap();
    let off = UnitQuaternion::from_scaled_axis(
        Vector3::new(0.3, 1.0, -0.5).normalize() * 150.0_f64.to_radians(),
    );
    let s0 = AttitudeState {
        q_eci_from_body: nadir.q_eci_from_body * off,
        ..Default::default()
    };
    let mut sim = Sim::new(&orbit, s0);
    sim.null_motion = null_motion;
    let mut settled_at = None;
    let mut peak_rate = 0.0_f64;
    while sim.t_s < duration {
        sim.step(Mode::Point(Pointing::Nadir));
        peak_rate = peak_rate.max(sim.rate_deg_s());
        let err = sim.error_deg();
        match settled_at {
            None if err < 0.1 => settled_at = Some(sim.t_s),
            Some(_) if err >= 0.1 => settled_at = None,
            _ => {}
        }
    }
    let settled = settled_at.unwrap_or(f64::INFINITY);
    let max_w = max_speed(&sim.body);
    eprintln!(
        "slew 150 deg (null motion and friction feed-forward {null_motion}): settled \
         (< 0.1 deg for good) after {settled:.1} s, final error {:.2e} deg, peak rate \
         {peak_rate:.3} deg/s (limit {:.3}), peak wheel speed {:.0} rad/s ({:.0} % of \
         {max_w:.0}), final speeds {:.1?} rad/s",
        sim.error_deg(),
        sim.cfg.max_rate_rad_s.to_degrees(),
        sim.peak_wheel_speed_rad_s,
        100.0 * sim.peak_wheel_speed_rad_s / max_w,
        sim.s.wheel_speed_rad_s
    );
    (
        settled,
        sim.error_deg(),
        peak_rate,
        sim.peak_wheel_speed_rad_s,
    )
}

#[test]
fn slew_150_deg_to_nadir_settles_below_0_1_deg_without_wheel_saturation() {
    let cfg = ControlConfig::default();
    let max_w = max_speed(&BodyConfig::default());
    for null_motion in [false, true] {
        let (settled, final_err, peak_rate, peak_speed) = slew_run(null_motion);
        // 150 deg at 1.5 deg/s is 100 s, plus the approach.
        assert!(settled < 150.0, "{settled}");
        assert!(peak_speed < 0.6 * max_w, "{peak_speed}");
        // The rate limit holds (plus the orbital rate and the rate loop's overshoot).
        assert!(
            peak_rate < 1.05 * cfg.max_rate_rad_s.to_degrees(),
            "{peak_rate}"
        );
        if null_motion {
            // Friction fed forward: nothing left but the discretisation.
            assert!(final_err < 1e-3, "{final_err}");
        } else {
            // The friction of the wheels holding the stored momentum (~3e-7 N m) is a
            // disturbance the proportional loop leaves as a small offset.
            assert!(final_err < 0.01, "{final_err}");
        }
    }
}

/// One orbit of nadir with gravity gradient, starting on target with the LVLH rate.
#[test]
fn nadir_holds_within_0_1_deg_for_one_orbit_with_gravity_gradient() {
    let duration = PERIOD_S;
    let orbit = Orbit::new(duration as usize);
    let t0 = guidance::target(&Pointing::Nadir, &orbit.at(0.0).guidance_inputs(0.0)).unwrap();
    let s0 = AttitudeState {
        q_eci_from_body: t0.q_eci_from_body,
        w_body_rad_s: t0.w_body_rad_s,
        ..Default::default()
    };
    let mut sim = Sim::new(&orbit, s0);
    let mut worst = 0.0_f64;
    while sim.t_s < duration {
        sim.step(Mode::Point(Pointing::Nadir));
        worst = worst.max(sim.error_deg());
    }
    eprintln!(
        "nadir one orbit: worst error {worst:.2e} deg, peak wheel speed {:.2} rad/s, final \
         wheel momentum {:.2e} N m s",
        sim.peak_wheel_speed_rad_s,
        sim.wheel_momentum_nms()
    );
    assert!(worst < 0.1, "{worst}");
    // Measured far better than asked.
    assert!(worst < 0.005, "{worst}");
}

/// An Earth-target pass: a site 1 deg of longitude off the ground track, tracked for ten
/// minutes around the closest approach (elevation about 75 deg), starting on target.
#[test]
fn earth_target_pass_is_tracked_within_0_1_deg() {
    let duration = 600.0;
    let orbit = Orbit::new(duration as usize);
    let e_mid = orbit.at(300.0);
    let sub = ecef_m_to_geodetic(&(e_mid.a_ecef_from_eci * e_mid.r_eci_m));
    let p = Pointing::EarthTarget {
        lat_deg: sub.lat_deg(),
        lon_deg: sub.lon_deg() + 1.0,
        alt_m: 0.0,
        axis_body: Vector3::z(),
    };
    let t0 = guidance::target(&p, &orbit.at(0.0).guidance_inputs(0.0)).unwrap();
    let s0 = AttitudeState {
        q_eci_from_body: t0.q_eci_from_body,
        w_body_rad_s: t0.w_body_rad_s,
        ..Default::default()
    };
    let mut sim = Sim::new(&orbit, s0);
    let (mut worst, mut max_el, mut peak_rate) = (0.0_f64, -90.0_f64, 0.0_f64);
    while sim.t_s < duration {
        sim.step(Mode::Point(p));
        let t = sim.last_target.unwrap();
        let el = t.target_elevation_deg.unwrap();
        max_el = max_el.max(el);
        peak_rate = peak_rate.max(t.w_body_rad_s.norm().to_degrees());
        if el > 10.0 {
            worst = worst.max(sim.error_deg());
        }
    }
    eprintln!(
        "earth target pass: max elevation {max_el:.1} deg, peak target rate {peak_rate:.3} \
         deg/s, worst error above 10 deg elevation {worst:.2e} deg, peak wheel speed {:.0} \
         rad/s",
        sim.peak_wheel_speed_rad_s
    );
    assert!(max_el > 60.0, "{max_el}");
    assert!(worst < 0.1, "{worst}");
    // Measured 0.013 deg with the acceleration feed-forward (0.16 deg without).
    assert!(worst < 0.03, "{worst}");
}

/// A constant 1 uN m disturbance in body axes while holding nadir: desaturation keeps the
/// wheel momentum bounded, well below the envelope, and the pointing holds.
fn desat_run(orbits: f64, null_motion: bool, desat: bool) -> (f64, f64, f64, f64) {
    let duration = orbits * PERIOD_S;
    let orbit = Orbit::new(duration as usize);
    let t0 = guidance::target(&Pointing::Nadir, &orbit.at(0.0).guidance_inputs(0.0)).unwrap();
    let s0 = AttitudeState {
        q_eci_from_body: t0.q_eci_from_body,
        w_body_rad_s: t0.w_body_rad_s,
        ..Default::default()
    };
    let mut sim = Sim::new(&orbit, s0);
    sim.null_motion = null_motion;
    if !desat {
        sim.cfg.desat_gain = 0.0;
    }
    sim.disturbance_body_nm = Vector3::new(0.6, -0.5, 0.62).normalize() * 1e-6;
    let mut worst_err = 0.0_f64;
    let mut peak_h = 0.0_f64;
    let mut h_last_orbit = 0.0_f64;
    while sim.t_s < duration {
        sim.step(Mode::Point(Pointing::Nadir));
        // Skip the first minute (the null-motion spin-up when on).
        if sim.t_s > 60.0 {
            worst_err = worst_err.max(sim.error_deg());
        }
        let h = sim.wheel_momentum_nms();
        peak_h = peak_h.max(h);
        if sim.t_s > duration - PERIOD_S {
            h_last_orbit = h_last_orbit.max(h);
        }
    }
    let h_env = control::envelope_radius(&sim.body.wheels, |w| w.inertia_kg_m2 * w.max_speed_rad_s);
    eprintln!(
        "desat {desat} {orbits} orbits (null motion {null_motion}): worst error {worst_err:.4} deg, \
         peak wheel momentum {peak_h:.2e} N m s ({:.1} % of the envelope), in the last orbit \
         {h_last_orbit:.2e}, peak wheel speed {:.1} rad/s, peak dipole {:.3} A m^2",
        100.0 * peak_h / h_env,
        sim.peak_wheel_speed_rad_s,
        sim.peak_dipole_am2
    );
    (
        worst_err,
        peak_h / h_env,
        h_last_orbit / h_env,
        sim.peak_wheel_speed_rad_s,
    )
}

#[test]
fn desaturation_bounds_the_momentum_under_a_constant_disturbance_one_orbit() {
    let (err, peak, last, _) = desat_run(1.0, false, true);
    assert!(peak < 0.15, "{peak}");
    assert!(last < 0.15, "{last}");
    assert!(err < 0.1, "{err}");
}

#[test]
fn desaturation_bounds_the_momentum_under_a_constant_disturbance_four_orbits() {
    let max_w = max_speed(&BodyConfig::default());
    let (err, peak, last, peak_speed) = desat_run(4.0, true, true);
    assert!(peak < 0.15, "{peak}");
    assert!(last < 0.15, "{last}");
    assert!(err < 0.1, "{err}");
    assert!(peak_speed < 0.3 * max_w, "{peak_speed}");
    // Without desaturation the part of the disturbance along the orbit normal (fixed in
    // body axes while nadir pointing) piles up: 0.48 uN m for four orbits is 0.011 N m s,
    // past the wheels' envelope.
    let (_, peak_off, last_off, _) = desat_run(4.0, true, false);
    assert!(
        last_off > 0.5 && peak_off > 4.0 * peak,
        "{peak_off} {last_off}"
    );
}
