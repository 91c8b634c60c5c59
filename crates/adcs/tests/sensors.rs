//! The FC's sensor models (`adcs::sensors`): determinism, noise statistics, geometry of
//! each sensor, faults, text forms, telemetry and saturation.
#![allow(clippy::unwrap_used)]

use icd::fc::{Repr, TmRawSens, TmSens};
use m6p_adcs::sensors::{
    ACC_LSB_M_S2, CSS_FULL_SCALE_COUNTS, G0_M_S2, GYRO_LSB_RAD_S, MAG_LSB_NT, SensorConfig,
    SensorFault, SensorId, SensorInputs, SensorReadings, Sensors, TEMP_BATTERY, TEMP_IMU,
    TEMP_LSB_C, TEMP_PANEL_MX, TEMP_PANEL_PX, TEMP_RWA, sun_from_counts,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

const DEG: f64 = core::f64::consts::PI / 180.0;
const DT: f64 = 0.1;

/// A made-up IGRF-like field in ECI, nT (about 45 000 nT, a mid-latitude LEO magnitude).
fn field_eci_nt() -> Vector3<f64> {
    Vector3::new(18_000.0, -7_500.0, 40_500.0)
}

/// Sunlit, identity attitude, Sun along ECI +X, a typical LEO state.
fn base_inputs() -> SensorInputs {
    SensorInputs {
        q_eci_from_body: UnitQuaternion::identity(),
        w_body_rad_s: Vector3::new(0.5, -1.0, 2.0) * DEG,
        b_eci_nt: field_eci_nt(),
        sun_eci_unit: Vector3::x(),
        sun_visible_fraction: 1.0,
        r_eci_m: Vector3::new(6_878_000.0, 0.0, 0.0),
        v_eci_m_s: Vector3::new(0.0, 1_000.0, 7_540.0),
        nongrav_acc_body_m_s2: Vector3::new(2.0e-6, 0.0, -1.0e-6),
    }
}

/// The default configuration without the gyro bias walk (white-noise statistics).
fn no_walk() -> SensorConfig {
    SensorConfig {
        gyro_bias_walk_rad_s_per_sqrt_s: 0.0,
        gps_enabled: true,
        ..SensorConfig::default()
    }
}

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

fn unit(r: &mut ChaCha8Rng) -> f64 {
    (r.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// A direction uniform on the sphere.
fn random_dir(r: &mut ChaCha8Rng) -> Vector3<f64> {
    let z = 2.0 * unit(r) - 1.0;
    let phi = core::f64::consts::TAU * unit(r);
    let s = (1.0 - z * z).sqrt();
    Vector3::new(s * phi.cos(), s * phi.sin(), z)
}

fn random_attitude(r: &mut ChaCha8Rng) -> UnitQuaternion<f64> {
    let axis = random_dir(r);
    let angle = core::f64::consts::PI * unit(r);
    UnitQuaternion::from_scaled_axis(axis * angle)
}

fn run(s: &mut Sensors, inputs: &SensorInputs, n: usize) -> Vec<SensorReadings> {
    (0..n).map(|_| s.sample(inputs, DT)).collect()
}

/// Mean and (population) standard deviation.
fn stats(xs: impl IntoIterator<Item = f64>) -> (f64, f64) {
    let xs: Vec<f64> = xs.into_iter().collect();
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

fn varying_inputs(k: usize) -> SensorInputs {
    let t = k as f64 * DT;
    SensorInputs {
        q_eci_from_body: UnitQuaternion::from_scaled_axis(Vector3::new(0.01, 0.02, -0.015) * t),
        w_body_rad_s: Vector3::new(0.01, 0.02, -0.015),
        sun_visible_fraction: if k % 50 < 10 { 0.0 } else { 1.0 },
        ..base_inputs()
    }
}

#[test]
fn same_seed_same_readings_other_seed_differs() {
    let go = |seed| {
        let mut s = Sensors::new(no_walk(), seed);
        s.set_fault(SensorId::SunSensor(2), Some(SensorFault::Noisy(3.0)));
        (0..300)
            .map(|k| s.sample(&varying_inputs(k), DT))
            .collect::<Vec<_>>()
    };
    let a = go(7);
    assert_eq!(a, go(7));
    let b = go(8);
    assert_ne!(a, b);
    // Every noisy field differs with another seed.
    assert_ne!(a[5].gyro_raw, b[5].gyro_raw);
    assert_ne!(a[5].mag_raw, b[5].mag_raw);
    assert_ne!(a[15].css_counts, b[15].css_counts);
    assert_ne!(a[5].gps_r_eci_m, b[5].gps_r_eci_m);
    assert_ne!(a[5].temps_raw, b[5].temps_raw);
}

#[test]
fn noise_std_within_10_percent_of_configured_and_mean_is_truth_plus_bias() {
    let cfg = no_walk();
    let mut s = Sensors::new(cfg.clone(), 1);
    // The Sun between +X and +Y, 45 deg from each: two lit faces at 2896 counts.
    let inputs = SensorInputs {
        sun_eci_unit: Vector3::new(1.0, 1.0, 0.0).normalize(),
        ..base_inputs()
    };
    let r = run(&mut s, &inputs, 20_000);
    let check = |name: &str, xs: Vec<f64>, want_mean: f64, sigma: f64, lsb: f64| {
        let (mean, std) = stats(xs);
        let ratio = std / sigma;
        assert!((0.9..1.1).contains(&ratio), "{name}: std {std} vs {sigma}");
        // The quantisation adds lsb^2 / 12 of variance: with it the match is within 3 %.
        let with_q = (sigma * sigma + lsb * lsb / 12.0).sqrt();
        assert!(
            (std / with_q - 1.0).abs() < 0.03,
            "{name}: std {std} vs {with_q}"
        );
        assert!(
            (mean - want_mean).abs() < 4.0 * with_q / (20_000f64).sqrt() + lsb / 2.0,
            "{name}: mean {mean} vs {want_mean}"
        );
        eprintln!(
            "{name}: std/sigma {ratio:.4}, mean err {:.3e}",
            mean - want_mean
        );
    };
    for i in 0..3 {
        check(
            "gyro",
            r.iter().map(|x| x.gyro_body_rad_s.unwrap()[i]).collect(),
            inputs.w_body_rad_s[i] + cfg.gyro_bias_initial_rad_s[i],
            cfg.gyro_noise_rad_s,
            GYRO_LSB_RAD_S,
        );
        check(
            "mag",
            r.iter().map(|x| x.mag_body_nt.unwrap()[i]).collect(),
            field_eci_nt()[i] + cfg.mag_bias_nt[i],
            cfg.mag_noise_nt,
            MAG_LSB_NT,
        );
        check(
            "acc",
            r.iter().map(|x| x.acc_body_m_s2.unwrap()[i]).collect(),
            inputs.nongrav_acc_body_m_s2[i] + cfg.acc_bias_m_s2[i],
            cfg.acc_noise_m_s2,
            ACC_LSB_M_S2,
        );
        check(
            "gps r",
            r.iter().map(|x| x.gps_r_eci_m.unwrap()[i]).collect(),
            inputs.r_eci_m[i],
            cfg.gps_position_noise_m,
            0.0,
        );
        check(
            "gps v",
            r.iter().map(|x| x.gps_v_eci_m_s.unwrap()[i]).collect(),
            inputs.v_eci_m_s[i],
            cfg.gps_velocity_noise_m_s,
            0.0,
        );
    }
    for face in [0, 2] {
        check(
            "css",
            r.iter().map(|x| f64::from(x.css_counts[face])).collect(),
            4095.0 * (45.0 * DEG).cos(),
            cfg.css_noise_counts,
            1.0,
        );
    }
    // Temperatures: the IMU at its sunlit equilibrium from the start (no drift).
    let mut c = no_walk();
    c.thermal[TEMP_IMU].initial_c = c.thermal[TEMP_IMU].sunlit_equilibrium_c;
    let mut s = Sensors::new(c.clone(), 2);
    let r = run(&mut s, &base_inputs(), 20_000);
    check(
        "temp",
        r.iter().map(|x| x.temps_c[TEMP_IMU]).collect(),
        c.thermal[TEMP_IMU].sunlit_equilibrium_c,
        c.temp_noise_c,
        TEMP_LSB_C,
    );
}

#[test]
fn processed_values_are_raw_counts_times_lsb() {
    let mut s = Sensors::new(SensorConfig::default(), 3);
    for k in 0..200 {
        let r = s.sample(&varying_inputs(k), DT);
        let v = |raw: [i16; 3], lsb: f64| {
            Vector3::new(
                f64::from(raw[0]) * lsb,
                f64::from(raw[1]) * lsb,
                f64::from(raw[2]) * lsb,
            )
        };
        assert_eq!(r.gyro_body_rad_s, Some(v(r.gyro_raw, GYRO_LSB_RAD_S)));
        assert_eq!(r.mag_body_nt, Some(v(r.mag_raw, MAG_LSB_NT)));
        assert_eq!(r.acc_body_m_s2, Some(v(r.acc_raw, ACC_LSB_M_S2)));
        for i in 0..6 {
            assert_eq!(r.temps_c[i], f64::from(r.temps_raw[i]) * TEMP_LSB_C);
        }
        assert_eq!(
            r.sun_body_unit,
            sun_from_counts(&r.css_counts, s.config().css_min_total_counts)
        );
        assert_eq!(r.gps_r_eci_m, None, "GPS off by default");
        assert_eq!(r.gps_v_eci_m_s, None);
    }
    assert!((ACC_LSB_M_S2 - G0_M_S2 / 1000.0).abs() < 1e-15);
    assert!((GYRO_LSB_RAD_S - 0.01 * DEG).abs() < 1e-18);
}

#[test]
fn gyro_bias_walk_grows_as_sqrt_time_and_turn_on_bias_follows_seed() {
    let cfg = SensorConfig::default();
    let sigma = cfg.gyro_bias_walk_rad_s_per_sqrt_s;
    let (steps, dt) = (100, 10.0);
    let drift: Vec<Vector3<f64>> = (0..400)
        .map(|seed| {
            let mut s = Sensors::new(cfg.clone(), seed);
            assert_eq!(s.true_gyro_bias_rad_s(), cfg.gyro_bias_initial_rad_s);
            for _ in 0..steps {
                s.sample(&base_inputs(), dt);
            }
            s.true_gyro_bias_rad_s() - cfg.gyro_bias_initial_rad_s
        })
        .collect();
    let want = sigma * (steps as f64 * dt).sqrt();
    for i in 0..3 {
        let (mean, std) = stats(drift.iter().map(|d| d[i]));
        assert!((std / want - 1.0).abs() < 0.12, "axis {i}: {std} vs {want}");
        assert!(mean.abs() < 4.0 * want / 20.0, "axis {i}: mean {mean}");
    }
    // The reading follows the walked bias: with a consumer-grade walk of 1e-4 deg/s/sqrt(s)
    // at 10 s steps it wanders 0.022 deg/s (two sigma of the noise) in 5000 samples, yet
    // reading - rate - true bias stays zero-mean.
    let cfg = SensorConfig {
        gyro_bias_walk_rad_s_per_sqrt_s: 1.0e-4 * DEG,
        ..cfg
    };
    let mut s = Sensors::new(cfg.clone(), 5);
    let (mut sum, mut wander) = (0.0, 0.0f64);
    for _ in 0..5000 {
        let r = s.sample(&base_inputs(), 10.0);
        let b = s.true_gyro_bias_rad_s().x;
        sum += r.gyro_body_rad_s.unwrap().x - base_inputs().w_body_rad_s.x - b;
        wander = wander.max((b - cfg.gyro_bias_initial_rad_s.x).abs());
    }
    assert!(
        (sum / 5000.0).abs() < 4.0 * 0.0105 * DEG / 5000f64.sqrt(),
        "{sum}"
    );
    assert!(wander > 0.005 * DEG, "{wander}");

    // A random turn-on part: differs per seed with the configured spread.
    let c = SensorConfig {
        gyro_bias_turn_on_sigma_rad_s: 0.05 * DEG,
        ..SensorConfig::default()
    };
    let b0: Vec<f64> = (0..1000)
        .map(|seed| {
            (Sensors::new(c.clone(), seed).true_gyro_bias_rad_s() - c.gyro_bias_initial_rad_s).y
        })
        .collect();
    let (mean, std) = stats(b0);
    assert!((std / (0.05 * DEG) - 1.0).abs() < 0.1, "{std}");
    assert!(mean.abs() < 0.01 * DEG, "{mean}");
}

#[test]
fn magnetometer_reads_the_rotated_field_within_noise() {
    let cfg = SensorConfig::default();
    let mut s = Sensors::new(cfg.clone(), 11);
    let mut r = rng(99);
    let mut err_sq = 0.0;
    let n = 3000;
    for _ in 0..n {
        let q = random_attitude(&mut r);
        let inputs = SensorInputs {
            q_eci_from_body: q,
            ..base_inputs()
        };
        let b = s.sample(&inputs, DT).mag_body_nt.unwrap();
        let want = q.inverse() * field_eci_nt() + cfg.mag_bias_nt;
        let e = b - want;
        for i in 0..3 {
            assert!(e[i].abs() < 5.0 * cfg.mag_noise_nt, "{e}");
        }
        // The measured field rotated back to ECI is the ECI field, to noise and bias.
        let back = q * (b - cfg.mag_bias_nt);
        assert!((back - field_eci_nt()).norm() < 6.0 * cfg.mag_noise_nt);
        err_sq += e.norm_squared();
    }
    let rms_per_axis = (err_sq / (3.0 * n as f64)).sqrt();
    assert!(
        (rms_per_axis / cfg.mag_noise_nt - 1.0).abs() < 0.1,
        "{rms_per_axis}"
    );
}

#[test]
fn sun_along_plus_x_saturates_plus_x_and_leaves_minus_x_dark() {
    let cfg = SensorConfig::default();
    let mut s = Sensors::new(cfg.clone(), 2);
    let noise = cfg.css_noise_counts;
    for r in run(&mut s, &base_inputs(), 500) {
        let c = r.css_counts;
        assert!(f64::from(c[0]) > 4095.0 - 5.0 * noise, "{c:?}");
        // The other five are dark (90 deg or more: outside the field of view): noise only,
        // clamped at zero.
        for dark in &c[1..] {
            assert!(f64::from(*dark) < 5.0 * noise, "{c:?}");
        }
        let sun = r.sun_body_unit.unwrap();
        assert!(sun.angle(&Vector3::x()) < 1.0 * DEG, "{sun}");
    }
    // The noise-free response: exactly full scale and zero.
    let quiet = SensorConfig {
        css_noise_counts: 0.0,
        ..SensorConfig::default()
    };
    let r = Sensors::new(quiet, 2).sample(&base_inputs(), DT);
    assert_eq!(r.css_counts, [CSS_FULL_SCALE_COUNTS, 0, 0, 0, 0, 0]);
    assert_eq!(r.sun_body_unit, Some(Vector3::x()));
}

/// Sun-vector errors, degrees, for `n` random directions and attitudes.
fn css_errors_deg(cfg: &SensorConfig, n: usize) -> Vec<(f64, Vector3<f64>)> {
    let mut s = Sensors::new(cfg.clone(), 21);
    let mut r = rng(5);
    (0..n)
        .map(|_| {
            let q = random_attitude(&mut r);
            let sun_eci = random_dir(&mut r);
            let inputs = SensorInputs {
                q_eci_from_body: q,
                sun_eci_unit: sun_eci,
                ..base_inputs()
            };
            let sun_body_true = q.inverse() * sun_eci;
            let got = s.sample(&inputs, DT).sun_body_unit.unwrap();
            (got.angle(&sun_body_true) / DEG, sun_body_true)
        })
        .collect()
}

fn percentile(mut xs: Vec<f64>, p: f64) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[((xs.len() - 1) as f64 * p).round() as usize]
}

#[test]
fn css_recovers_random_sun_directions() {
    // A full cosine field of view: only noise and quantisation, well under a degree.
    let wide = SensorConfig {
        css_fov_half_angle_rad: 90.0 * DEG,
        ..SensorConfig::default()
    };
    let e = css_errors_deg(&wide, 2000);
    let worst = e.iter().map(|x| x.0).fold(0.0, f64::max);
    assert!(worst < 1.0, "90 deg fov: worst {worst} deg");
    eprintln!("90 deg fov sun error: max {worst:.2} deg");

    // A baffled 80 deg field of view: directions with every component outside the blind
    // band (|s_i| > cos 80 deg = 0.174) stay within 1 degree; the others err by the
    // geometry (an axis that reads zero), bounded by about 10 deg per blind axis.
    let baffled = SensorConfig {
        css_fov_half_angle_rad: 80.0 * DEG,
        ..SensorConfig::default()
    };
    let e = css_errors_deg(&baffled, 2000);
    let cut = (80.0 * DEG).cos();
    let seen: Vec<f64> = e
        .iter()
        .filter(|(_, s)| s.iter().all(|c| c.abs() > cut + 0.01))
        .map(|x| x.0)
        .collect();
    assert!(seen.len() > 900, "{}", seen.len());
    let worst_seen = seen.iter().copied().fold(0.0, f64::max);
    assert!(
        worst_seen < 1.0,
        "80 deg fov, all axes seen: worst {worst_seen} deg"
    );
    let all: Vec<f64> = e.iter().map(|x| x.0).collect();
    let worst = all.iter().copied().fold(0.0, f64::max);
    assert!(worst < 15.0, "80 deg fov: worst {worst} deg");
    eprintln!(
        "80 deg fov sun error: median {:.2} deg, 95 % {:.2} deg, max {worst:.2} deg; \
         all axes seen: max {worst_seen:.2} deg",
        percentile(all.clone(), 0.5),
        percentile(all, 0.95)
    );
}

#[test]
fn css_is_blind_in_eclipse_and_scales_in_penumbra() {
    let mut s = Sensors::new(SensorConfig::default(), 4);
    let sun = Vector3::new(1.0, 1.0, 1.0).normalize();
    let at = |f: f64| SensorInputs {
        sun_eci_unit: sun,
        sun_visible_fraction: f,
        ..base_inputs()
    };
    for r in run(&mut s, &at(0.0), 200) {
        assert_eq!(r.sun_body_unit, None, "{:?}", r.css_counts);
        assert!(r.css_counts.iter().all(|c| *c < 40), "{:?}", r.css_counts);
    }
    let lit = 4095.0 / 3f64.sqrt();
    for f in [0.3, 0.5, 1.0] {
        let r = run(&mut s, &at(f), 200);
        let (mean, _) = stats(r.iter().map(|x| f64::from(x.css_counts[0])));
        assert!((mean - f * lit).abs() < 3.0, "f {f}: {mean}");
        // The angular noise is about sigma / (f 4095) rad per axis across the line of sight
        // (Rayleigh): 5 sigma bounds 200 samples.
        let bound = 5.0 * s.config().css_noise_counts / (f * 4095.0);
        for x in &r {
            let e = x.sun_body_unit.unwrap().angle(&sun);
            assert!(e < bound, "f {f}: {} deg", e / DEG);
        }
    }
    // A sliver of sun (below 10 % of full scale in total) gives no vector either.
    assert!(
        run(&mut s, &at(0.03), 50)
            .iter()
            .all(|r| r.sun_body_unit.is_none())
    );
}

#[test]
fn css_field_of_view_cuts_off_at_80_degrees() {
    // A baffled 80-degree sensor (the default is a bare 90-degree cosine detector).
    let quiet = SensorConfig {
        css_noise_counts: 0.0,
        css_fov_half_angle_rad: 80.0 * DEG,
        ..SensorConfig::default()
    };
    let mut s = Sensors::new(quiet, 4);
    let at = |deg: f64| SensorInputs {
        sun_eci_unit: Vector3::new((deg * DEG).cos(), (deg * DEG).sin(), 0.0),
        ..base_inputs()
    };
    let c79 = s.sample(&at(79.0), DT).css_counts;
    assert_eq!(c79[0], (4095.0 * (79.0 * DEG).cos()).round() as u16);
    assert!(c79[0] > 700, "{c79:?}");
    let c81 = s.sample(&at(81.0), DT);
    assert_eq!(c81.css_counts[0], 0, "{:?}", c81.css_counts);
    // +Y sees the Sun at 9 deg: the vector collapses onto +Y, 9 deg off.
    let sun = c81.sun_body_unit.unwrap();
    assert!(
        (sun.angle(&at(81.0).sun_eci_unit) / DEG - 9.0).abs() < 0.1,
        "{sun}"
    );
    // Symmetric on the -X face.
    let c = s.sample(&at(180.0 - 79.0), DT).css_counts;
    assert!(c[1] > 700 && c[0] == 0, "{c:?}");
    assert_eq!(s.sample(&at(180.0 - 81.0), DT).css_counts[1], 0);
}

#[test]
fn dead_sensors_give_none_and_raw_zeros() {
    let mut s = Sensors::new(no_walk(), 6);
    for id in [
        SensorId::Gyro,
        SensorId::Magnetometer,
        SensorId::Accelerometer,
        SensorId::Gps,
        SensorId::SunSensor(0),
    ] {
        s.set_fault(id, Some(SensorFault::Dead));
    }
    let r = s.sample(&base_inputs(), DT);
    assert_eq!(r.gyro_body_rad_s, None);
    assert_eq!(r.mag_body_nt, None);
    assert_eq!(r.acc_body_m_s2, None);
    assert_eq!(r.gps_r_eci_m, None);
    assert_eq!(r.gps_v_eci_m_s, None);
    assert_eq!((r.gyro_raw, r.mag_raw, r.acc_raw), ([0; 3], [0; 3], [0; 3]));
    // The +X face is dead with the Sun on it: no other face sees it, no vector.
    assert_eq!(r.css_counts[0], 0);
    assert_eq!(r.sun_body_unit, None);
    let tm = r.tm_sens(1);
    assert_eq!(
        (
            tm.rate_body_rad_s,
            tm.acc_body_m_s2,
            tm.b_body_nt,
            tm.sun_body
        ),
        ([0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3])
    );
    // All six faces dead: blind in full sun.
    let mut s = Sensors::new(no_walk(), 6);
    s.set_fault(SensorId::SunSensors, Some(SensorFault::Dead));
    let r = s.sample(
        &SensorInputs {
            sun_eci_unit: Vector3::new(1.0, -1.0, 1.0).normalize(),
            ..base_inputs()
        },
        DT,
    );
    assert_eq!((r.css_counts, r.sun_body_unit), ([0; 6], None));
    // Clearing brings them back.
    s.set_fault(SensorId::SunSensors, None);
    assert!(s.sample(&base_inputs(), DT).sun_body_unit.is_some());
}

#[test]
fn stuck_sensors_hold_their_last_output() {
    let mut s = Sensors::new(no_walk(), 8);
    let before = s.sample(&varying_inputs(20), DT);
    assert!(before.sun_body_unit.is_some());
    for id in [
        SensorId::Gyro,
        SensorId::Magnetometer,
        SensorId::Accelerometer,
        SensorId::Gps,
        SensorId::SunSensors,
    ] {
        s.set_fault(id, Some(SensorFault::Stuck));
    }
    for k in 21..120 {
        let mut inputs = varying_inputs(k);
        inputs.sun_eci_unit = Vector3::new(-1.0, 0.5, 0.2).normalize();
        inputs.w_body_rad_s *= 10.0;
        let r = s.sample(&inputs, DT);
        assert_eq!(r.gyro_raw, before.gyro_raw);
        assert_eq!(r.gyro_body_rad_s, before.gyro_body_rad_s);
        assert_eq!(r.mag_raw, before.mag_raw);
        assert_eq!(r.mag_body_nt, before.mag_body_nt);
        assert_eq!(r.acc_raw, before.acc_raw);
        assert_eq!(r.acc_body_m_s2, before.acc_body_m_s2);
        assert_eq!(r.gps_r_eci_m, before.gps_r_eci_m);
        assert_eq!(r.gps_v_eci_m_s, before.gps_v_eci_m_s);
        assert_eq!(r.css_counts, before.css_counts);
        assert_eq!(r.sun_body_unit, before.sun_body_unit);
        // Temperatures have no faults: still fresh.
        assert_eq!(r.temps_raw.len(), 6);
    }
    // One face stuck overrides nothing else: the others follow the Sun.
    let mut s = Sensors::new(no_walk(), 8);
    s.sample(&base_inputs(), DT);
    s.set_fault(SensorId::SunSensor(0), Some(SensorFault::Stuck));
    let r = s.sample(
        &SensorInputs {
            sun_eci_unit: -Vector3::x(),
            ..base_inputs()
        },
        DT,
    );
    assert!(
        r.css_counts[0] > 4000 && r.css_counts[1] > 4000,
        "{:?}",
        r.css_counts
    );
    // Stuck before any sample: holds the first output.
    let mut s = Sensors::new(no_walk(), 8);
    s.set_fault(SensorId::Gyro, Some(SensorFault::Stuck));
    let first = s.sample(&base_inputs(), DT).gyro_raw;
    assert_eq!(s.sample(&varying_inputs(30), DT).gyro_raw, first);
}

#[test]
fn bias_fault_shifts_the_mean_in_the_processed_unit() {
    let cfg = no_walk();
    let n = 4000;
    let inputs = SensorInputs {
        sun_eci_unit: Vector3::new(1.0, 1.0, 0.0).normalize(),
        ..base_inputs()
    };
    let means = |fault: Option<SensorFault>| {
        let mut s = Sensors::new(cfg.clone(), 9);
        for id in [
            SensorId::Gyro,
            SensorId::Magnetometer,
            SensorId::Accelerometer,
            SensorId::Gps,
            SensorId::SunSensor(2),
        ] {
            s.set_fault(id, fault);
        }
        let r = run(&mut s, &inputs, n);
        let m = |f: &dyn Fn(&SensorReadings) -> f64| stats(r.iter().map(f)).0;
        [
            m(&|x| x.gyro_body_rad_s.unwrap().y),
            m(&|x| x.mag_body_nt.unwrap().z),
            m(&|x| x.acc_body_m_s2.unwrap().x),
            m(&|x| x.gps_r_eci_m.unwrap().y),
            m(&|x| x.gps_v_eci_m_s.unwrap().y),
            m(&|x| f64::from(x.css_counts[2])),
            m(&|x| f64::from(x.css_counts[0])),
        ]
    };
    let base = means(None);
    // Bias values in each sensor's processed unit.
    for (i, (b, sigma)) in [
        (0.5 * DEG, cfg.gyro_noise_rad_s),
        (1000.0, cfg.mag_noise_nt),
        (0.1, cfg.acc_noise_m_s2),
        (50.0, cfg.gps_position_noise_m),
    ]
    .into_iter()
    .enumerate()
    {
        let shifted = means(Some(SensorFault::Bias(b)));
        let d = shifted[i] - base[i];
        assert!(
            (d - b).abs() < 0.05 * b.abs() + 0.1 * sigma,
            "sensor {i}: {d} vs {b}"
        );
    }
    let shifted = means(Some(SensorFault::Bias(-300.0)));
    assert!((shifted[5] - base[5] + 300.0).abs() < 2.0, "css+y");
    // The GPS bias is on the position only; the unfaulted +X face is untouched.
    assert_eq!(shifted[4], base[4]);
    assert_eq!(shifted[6], base[6]);
}

#[test]
fn noisy_fault_scales_the_std_and_leaves_other_sensors_alone() {
    let cfg = no_walk();
    let inputs = SensorInputs {
        sun_eci_unit: Vector3::new(1.0, 1.0, 0.0).normalize(),
        ..base_inputs()
    };
    let go = |fault: Option<SensorFault>| {
        let mut s = Sensors::new(cfg.clone(), 10);
        s.set_fault(SensorId::Gyro, fault);
        s.set_fault(SensorId::Magnetometer, fault);
        s.set_fault(SensorId::SunSensors, fault);
        s.set_fault(SensorId::Gps, fault);
        run(&mut s, &inputs, 10_000)
    };
    let (a, b) = (go(None), go(Some(SensorFault::Noisy(5.0))));
    let std = |r: &[SensorReadings], f: &dyn Fn(&SensorReadings) -> f64| stats(r.iter().map(f)).1;
    let ratio = |f: &dyn Fn(&SensorReadings) -> f64| std(&b, f) / (5.0 * std(&a, f));
    for (name, r) in [
        ("gyro", ratio(&|x| x.gyro_body_rad_s.unwrap().z)),
        ("mag", ratio(&|x| x.mag_body_nt.unwrap().x)),
        ("css", ratio(&|x| f64::from(x.css_counts[2]))),
        ("gps r", ratio(&|x| x.gps_r_eci_m.unwrap().z)),
        ("gps v", ratio(&|x| x.gps_v_eci_m_s.unwrap().x)),
    ] {
        // The unfaulted std includes quantisation (gyro: 1.04 sigma), the faulted one hardly.
        assert!((0.9..1.1).contains(&r), "{name}: {r}");
    }
    // The accelerometer and the temperatures had no fault: identical, draw for draw.
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.acc_raw, y.acc_raw);
        assert_eq!(x.temps_raw, y.temps_raw);
    }
}

#[test]
fn a_fault_never_changes_another_sensors_noise_and_clearing_resumes() {
    let clean: Vec<SensorReadings> = {
        let mut s = Sensors::new(no_walk(), 12);
        (0..200).map(|k| s.sample(&varying_inputs(k), DT)).collect()
    };
    for (id, fault) in [
        (SensorId::Gyro, SensorFault::Dead),
        (SensorId::Magnetometer, SensorFault::Stuck),
        (SensorId::SunSensor(3), SensorFault::Noisy(10.0)),
        (SensorId::Gps, SensorFault::Bias(100.0)),
        (SensorId::Accelerometer, SensorFault::Dead),
    ] {
        let mut s = Sensors::new(no_walk(), 12);
        for (k, want) in clean.iter().enumerate() {
            let faulted = (50..100).contains(&k);
            s.set_fault(id, faulted.then_some(fault));
            let r = s.sample(&varying_inputs(k), DT);
            if !faulted {
                assert_eq!(r, *want, "{id} {fault} at {k}");
                continue;
            }
            if id != SensorId::Gyro {
                assert_eq!(r.gyro_raw, want.gyro_raw, "{id}");
            }
            if id != SensorId::Magnetometer {
                assert_eq!(r.mag_raw, want.mag_raw, "{id}");
            }
            if id != SensorId::Accelerometer {
                assert_eq!(r.acc_raw, want.acc_raw, "{id}");
            }
            if id != SensorId::Gps {
                assert_eq!(r.gps_r_eci_m, want.gps_r_eci_m, "{id}");
            }
            for f in 0..6 {
                if id != SensorId::SunSensor(f as u8) {
                    assert_eq!(r.css_counts[f], want.css_counts[f], "{id} face {f}");
                }
            }
            assert_eq!(r.temps_raw, want.temps_raw);
        }
    }
}

#[test]
fn faults_are_listed_in_order_and_cleared() {
    let mut s = Sensors::new(SensorConfig::default(), 0);
    s.set_fault(SensorId::Gps, Some(SensorFault::Dead));
    s.set_fault(SensorId::SunSensor(4), Some(SensorFault::Stuck));
    s.set_fault(SensorId::Gyro, Some(SensorFault::Bias(0.01)));
    s.set_fault(SensorId::SunSensor(1), Some(SensorFault::Noisy(2.0)));
    s.set_fault(SensorId::SunSensor(9), Some(SensorFault::Dead));
    s.set_fault(SensorId::Gyro, Some(SensorFault::Bias(0.02)));
    let got: Vec<_> = s.faults().collect();
    assert_eq!(
        got,
        vec![
            (SensorId::Gyro, SensorFault::Bias(0.02)),
            (SensorId::SunSensor(1), SensorFault::Noisy(2.0)),
            (SensorId::SunSensor(4), SensorFault::Stuck),
            (SensorId::Gps, SensorFault::Dead),
        ]
    );
    s.set_fault(SensorId::SunSensor(1), None);
    s.set_fault(SensorId::Magnetometer, None);
    assert_eq!(s.faults().count(), 3);
    assert_eq!(s.fault(SensorId::SunSensor(1)), None);
    assert_eq!(s.fault(SensorId::Gps), Some(SensorFault::Dead));
}

#[test]
fn sensor_names_parse_display_and_reject_junk() {
    let want = [
        ("gyro", SensorId::Gyro),
        ("magnetometer", SensorId::Magnetometer),
        ("sun-sensors", SensorId::SunSensors),
        ("css+x", SensorId::SunSensor(0)),
        ("css-x", SensorId::SunSensor(1)),
        ("css+y", SensorId::SunSensor(2)),
        ("css-y", SensorId::SunSensor(3)),
        ("css+z", SensorId::SunSensor(4)),
        ("css-z", SensorId::SunSensor(5)),
        ("accelerometer", SensorId::Accelerometer),
        ("gps", SensorId::Gps),
        ("horizon", SensorId::Horizon),
    ];
    for (name, id) in want {
        assert_eq!(name.parse::<SensorId>(), Ok(id), "{name}");
        assert_eq!(id.to_string(), name);
        assert!(SensorId::NAMES.contains(&name));
    }
    assert_eq!(" GYRO ".parse::<SensorId>(), Ok(SensorId::Gyro));
    assert_eq!(SensorId::NAMES.len(), want.len());
    for junk in ["", "gyros", "css", "css+w", "css0", "sun", "mag", "gps:1"] {
        let e = junk.parse::<SensorId>().unwrap_err().to_string();
        assert!(e.contains(&format!("`{junk}`")), "{e}");
        for name in SensorId::NAMES {
            assert!(e.contains(name), "{e} lacks {name}");
        }
    }
}

#[test]
fn sensor_faults_parse_display_and_reject_junk() {
    for (text, want) in [
        ("dead", SensorFault::Dead),
        ("stuck", SensorFault::Stuck),
        ("bias:0.5", SensorFault::Bias(0.5)),
        ("bias:-300", SensorFault::Bias(-300.0)),
        ("bias:1e-3", SensorFault::Bias(1e-3)),
        ("noisy:3", SensorFault::Noisy(3.0)),
        ("noisy:0", SensorFault::Noisy(0.0)),
        (" Noisy: 2.5 ", SensorFault::Noisy(2.5)),
        ("DEAD", SensorFault::Dead),
    ] {
        let got: SensorFault = text.parse().unwrap();
        assert_eq!(got, want, "{text}");
        assert_eq!(got.to_string().parse::<SensorFault>(), Ok(got));
    }
    for (junk, says) in [
        ("", "expected dead, stuck, bias:<number>"),
        ("broken", "expected dead, stuck, bias:<number>"),
        ("bias", "needs a number"),
        ("bias:", "needs a number"),
        ("bias:x", "`x` is not a number"),
        ("bias:nan", "must be finite"),
        ("noisy", "needs a factor"),
        ("noisy:-1", "must not be negative"),
        ("noisy:inf", "must be finite"),
        ("dead:1", "takes no value"),
        ("stuck:", "takes no value"),
    ] {
        let e = junk.parse::<SensorFault>().unwrap_err().to_string();
        assert!(e.contains(says), "{junk:?}: {e}");
    }
}

#[test]
fn telemetry_carries_the_readings_and_round_trips() {
    let mut s = Sensors::new(no_walk(), 13);
    let inputs = SensorInputs {
        sun_eci_unit: Vector3::new(0.3, -0.5, 0.8).normalize(),
        ..base_inputs()
    };
    let r = s.sample(&inputs, DT);
    let tm = r.tm_sens(1_777_572_000);
    let g = r.gyro_body_rad_s.unwrap();
    let m = r.mag_body_nt.unwrap();
    let a = r.acc_body_m_s2.unwrap();
    let sun = r.sun_body_unit.unwrap();
    assert_eq!(tm.rtc_timestamp, 1_777_572_000);
    assert_eq!(tm.sun_body, [sun.x, sun.y, sun.z]);
    assert_eq!(tm.rate_body_rad_s, [g.x as f32, g.y as f32, g.z as f32]);
    assert_eq!(tm.b_body_nt, [m.x as f32, m.y as f32, m.z as f32]);
    assert_eq!(tm.acc_body_m_s2, [a.x as f32, a.y as f32, a.z as f32]);
    for i in 0..6 {
        assert_eq!(f64::from(tm.temps_c[i]), r.temps_c[i].round());
    }
    assert_eq!(TmSens::parse(&tm.to_vec()).unwrap(), tm);
    assert_eq!(tm.to_vec().len(), 70);

    let raw = r.tm_raw_sens(42);
    assert_eq!(
        raw,
        TmRawSens {
            rtc_timestamp: 42,
            css_counts: r.css_counts,
            gyro_raw: r.gyro_raw,
            acc_raw: r.acc_raw,
            mag_raw: r.mag_raw,
            temps_raw: r.temps_raw,
            horizon_raw: r.horizon_raw,
            horizon_status: r.horizon_status,
        }
    );
    let bytes = raw.to_vec();
    assert_eq!(bytes.len(), 53);
    assert_eq!(TmRawSens::parse(&bytes).unwrap(), raw);
    // The layout: css +X at byte 4, gyro x at 16 (0.01 deg/s), temps from 34.
    assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), r.css_counts[0]);
    assert_eq!(i16::from_le_bytes([bytes[16], bytes[17]]), r.gyro_raw[0]);
    assert_eq!(i16::from_le_bytes([bytes[34], bytes[35]]), r.temps_raw[0]);
    // The gyro raw is the rate in 0.01 deg/s: 0.5 deg/s + 0.1 deg/s bias = about 60 LSB.
    assert!((r.gyro_raw[0] - 60).abs() <= 4, "{:?}", r.gyro_raw);

    // Eclipse: no sun vector, zeros in TMSENS.
    let dark = s.sample(
        &SensorInputs {
            sun_visible_fraction: 0.0,
            ..inputs
        },
        DT,
    );
    assert_eq!(dark.tm_sens(0).sun_body, [0.0; 3]);
    assert_eq!(r.mcu_temp_i8_c(), r.mcu_temp_c.round() as i8);
}

#[test]
fn thermal_model_heats_toward_sunlit_equilibrium_and_cools_in_eclipse() {
    let cfg = SensorConfig::default();
    let mut s = Sensors::new(cfg.clone(), 14);
    let sunlit = base_inputs(); // Sun on +X.
    let eclipse = SensorInputs {
        sun_visible_fraction: 0.0,
        ..base_inputs()
    };
    let px = cfg.thermal[TEMP_PANEL_PX];
    let hot = px.sunlit_equilibrium_c + px.face_sun_gain_c;
    // One time constant in the sun: 63.2 % of the way from 20 C toward 70 C.
    let mut r = s.sample(&sunlit, 0.0);
    assert!((r.temps_c[TEMP_PANEL_PX] - 20.0).abs() < 0.5);
    let steps = (px.time_constant_s / 10.0) as usize;
    for _ in 0..steps {
        r = s.sample(&sunlit, 10.0);
    }
    let want = 20.0 + (hot - 20.0) * (1.0 - (-1.0f64).exp());
    assert!((s.true_temps_c()[TEMP_PANEL_PX] - want).abs() < 1e-9);
    assert!((r.temps_c[TEMP_PANEL_PX] - want).abs() < 0.5, "{r:?}");
    // Seven time constants: at the sunlit equilibria; the shaded -X panel much colder.
    for _ in 0..6 * steps {
        r = s.sample(&sunlit, 10.0);
    }
    assert!(
        (r.temps_c[TEMP_PANEL_PX] - hot).abs() < 1.0,
        "{:?}",
        r.temps_c
    );
    let mx = cfg.thermal[TEMP_PANEL_MX];
    assert!((r.temps_c[TEMP_PANEL_MX] - mx.sunlit_equilibrium_c).abs() < 1.0);
    // The reaction wheels (tau 4000 s; seven panel time constants are 8400 s) are still on
    // their way, exactly on the exponential.
    let rwa = cfg.thermal[TEMP_RWA];
    let want = 20.0 + (rwa.sunlit_equilibrium_c - 20.0) * (1.0 - (-8400.0 / 4000.0f64).exp());
    assert!((s.true_temps_c()[TEMP_RWA] - want).abs() < 1e-9);
    assert!(r.temps_c[TEMP_RWA] < rwa.sunlit_equilibrium_c - 0.5);
    // The battery starts at its sunlit equilibrium and stays there.
    let bat = cfg.thermal[TEMP_BATTERY];
    assert!((s.true_temps_c()[TEMP_BATTERY] - bat.sunlit_equilibrium_c).abs() < 1e-9);
    let mcu_hot = s.true_mcu_temp_c();
    assert!(mcu_hot > 30.0, "{mcu_hot}");
    // Eclipse: every channel falls toward its eclipse equilibrium.
    let before = r.temps_c;
    let mut last = s.true_temps_c();
    for _ in 0..2 * steps {
        s.sample(&eclipse, 10.0);
        let now = s.true_temps_c();
        for i in 0..6 {
            let eq = cfg.thermal[i].eclipse_equilibrium_c;
            assert!(
                (now[i] - eq).abs() <= (last[i] - eq).abs() + 1e-12,
                "channel {i}"
            );
        }
        last = now;
    }
    let r = s.sample(&eclipse, 10.0);
    assert!(
        r.temps_c[TEMP_PANEL_PX] < before[TEMP_PANEL_PX] - 50.0,
        "{:?}",
        r.temps_c
    );
    assert!(r.temps_c[TEMP_PANEL_PX] < px.eclipse_equilibrium_c + 15.0);
    assert!(s.true_mcu_temp_c() < mcu_hot);
}

#[test]
fn raw_values_saturate_at_their_limits() {
    let mut c = SensorConfig::default();
    c.thermal[0].eclipse_equilibrium_c = 5000.0;
    c.thermal[0].sunlit_equilibrium_c = 5000.0;
    c.thermal[0].time_constant_s = 0.0;
    c.thermal[1].eclipse_equilibrium_c = -5000.0;
    c.thermal[1].sunlit_equilibrium_c = -5000.0;
    c.thermal[1].time_constant_s = 0.0;
    let mut s = Sensors::new(c, 15);
    s.set_fault(SensorId::SunSensor(2), Some(SensorFault::Bias(10_000.0)));
    s.set_fault(SensorId::SunSensor(3), Some(SensorFault::Bias(-10_000.0)));
    let inputs = SensorInputs {
        w_body_rad_s: Vector3::new(400.0, -400.0, 300.0) * DEG,
        b_eci_nt: Vector3::new(400_000.0, -400_000.0, 0.0),
        nongrav_acc_body_m_s2: Vector3::new(40.0, -40.0, 0.0) * G0_M_S2,
        ..base_inputs()
    };
    let r = s.sample(&inputs, DT);
    assert_eq!(r.gyro_raw[..2], [i16::MAX, i16::MIN]);
    // 300 deg/s plus the default z bias of 0.06 deg/s: 30 006 counts, noise 1 count (1 sigma).
    assert!((r.gyro_raw[2] - 30_006).abs() <= 4, "{:?}", r.gyro_raw);
    assert_eq!(r.gyro_body_rad_s.unwrap().x, 327.67 * DEG);
    assert_eq!(r.mag_raw[..2], [i16::MAX, i16::MIN]);
    assert_eq!(r.mag_body_nt.unwrap().x, 327_670.0);
    assert_eq!(r.acc_raw[..2], [i16::MAX, i16::MIN]);
    assert_eq!(r.css_counts[2], CSS_FULL_SCALE_COUNTS);
    assert_eq!(r.css_counts[3], 0);
    assert_eq!(r.temps_raw[..2], [i16::MAX, i16::MIN]);
    let tm = r.tm_sens(0);
    assert_eq!(tm.temps_c[..2], [127, -128]);
    // Non-finite inputs do not panic: raw 0 (NaN), no sun vector.
    let nan = SensorInputs {
        w_body_rad_s: Vector3::repeat(f64::NAN),
        sun_visible_fraction: f64::NAN,
        ..base_inputs()
    };
    let r = Sensors::new(SensorConfig::default(), 15).sample(&nan, f64::NAN);
    assert_eq!(r.gyro_raw, [0; 3]);
    assert_eq!(r.sun_body_unit, None);
}

/// The Earth-horizon sensor on +Z at 500 km: the whole limb when +Z points within about 12
/// degrees of nadir (80 - 67.9), part of it further off, none beyond 80 + 67.9 degrees; its
/// nadir vector is within its noise (0.2 deg 1-sigma per axis, three times that with part
/// of the limb) of the true one; dead, it gives nothing.
#[test]
fn the_horizon_sensor_sees_the_limb_and_gives_nadir_within_its_noise() {
    use m6p_adcs::sensors::{
        HORIZON_FULL_LIMB, HORIZON_NO_LIMB, HORIZON_PARTIAL_LIMB, SensorFault, SensorId,
    };
    // The body's +Z turned `off_deg` from nadir (-X in ECI at r = +X).
    let tilted = |off_deg: f64| {
        let to_nadir = UnitQuaternion::rotation_between(&Vector3::z(), &-Vector3::x()).unwrap();
        let tilt = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), off_deg * DEG);
        SensorInputs {
            q_eci_from_body: to_nadir * tilt,
            ..base_inputs()
        }
    };
    let mut s = Sensors::new(SensorConfig::default(), 11);
    let mut err_deg = Vec::new();
    for _ in 0..2000 {
        let r = s.sample(&tilted(0.0), DT);
        assert_eq!(r.horizon_status, HORIZON_FULL_LIMB);
        let n = r.horizon_nadir_body.unwrap();
        err_deg.push(n.angle(&Vector3::z()).to_degrees());
    }
    // The angle of a 2-D Gaussian error (Rayleigh): mean sigma * sqrt(pi / 2) = 0.25 deg.
    let mean = err_deg.iter().sum::<f64>() / err_deg.len() as f64;
    assert!((0.2..0.3).contains(&mean), "mean error {mean} deg");
    for (off, status) in [
        (10.0, HORIZON_FULL_LIMB),
        (30.0, HORIZON_PARTIAL_LIMB),
        (140.0, HORIZON_PARTIAL_LIMB),
        (150.0, HORIZON_NO_LIMB),
        (180.0, HORIZON_NO_LIMB),
    ] {
        let inp = tilted(off);
        let r = s.sample(&inp, DT);
        assert_eq!(r.horizon_status, status, "{off} deg off nadir");
        let truth = inp.q_eci_from_body.inverse_transform_vector(&-Vector3::x());
        match r.horizon_nadir_body {
            Some(n) => assert!(n.angle(&truth).to_degrees() < 3.0, "{off}: {n:?} {truth:?}"),
            None => assert_eq!((status, r.horizon_raw), (HORIZON_NO_LIMB, [0; 3])),
        }
    }
    s.set_fault(SensorId::Horizon, Some(SensorFault::Dead));
    let r = s.sample(&tilted(0.0), DT);
    assert_eq!(
        (r.horizon_nadir_body, r.horizon_raw, r.horizon_status),
        (None, [0; 3], HORIZON_NO_LIMB)
    );
    assert_eq!("horizon".parse::<SensorId>(), Ok(SensorId::Horizon));
}
