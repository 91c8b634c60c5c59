//! The attitude truth (`adcs::truth`): conservation laws, momentum exchange, limits and
//! external torques, each with its tolerance in the test name.

use m6p_adcs::truth::{
    AttitudeState, BodyConfig, MU_EARTH_M3_S2, Torques, WheelConfig, gravity_gradient_body_nm, step,
};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// The default bus with frictionless wheels, for the conservation tests.
fn frictionless() -> BodyConfig {
    let mut cfg = BodyConfig::default();
    for w in &mut cfg.wheels {
        w.friction_nm_s_rad = 0.0;
    }
    cfg
}

fn run(
    mut s: AttitudeState,
    cfg: &BodyConfig,
    inputs: &Torques,
    dt_s: f64,
    steps: usize,
    mut each: impl FnMut(&AttitudeState),
) -> AttitudeState {
    for _ in 0..steps {
        s = step(&s, cfg, inputs, dt_s);
        each(&s);
    }
    s
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn principal_spin_stays_and_conserves_h_and_energy_1e9_over_1000s() {
    let cfg = frictionless();
    for axis in 0..3 {
        let mut w = Vector3::zeros();
        w[axis] = 0.1;
        let s0 = AttitudeState {
            q_eci_from_body: UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            w_body_rad_s: w,
            ..Default::default()
        };
        let (h0, e0) = (s0.h_eci_nms(&cfg), s0.body_energy_j(&cfg));
        let s = run(s0, &cfg, &Torques::default(), 0.1, 10_000, |_| {});
        assert!(
            rel(s.h_eci_nms(&cfg).norm(), h0.norm()) < 1e-9,
            "axis {axis}"
        );
        assert!(
            (s.h_eci_nms(&cfg) - h0).norm() / h0.norm() < 1e-9,
            "axis {axis}"
        );
        assert!(rel(s.body_energy_j(&cfg), e0) < 1e-9, "axis {axis}");
        // Still about the same body axis, at the same rate.
        assert!(
            (s.w_body_rad_s - w).norm() < 1e-9 * w.norm(),
            "axis {axis}: {}",
            s.w_body_rad_s
        );
        // The spin axis in ECI has not moved.
        let a_eci_0 = s0.q_eci_from_body * w;
        let a_eci = s.q_eci_from_body * s.w_body_rad_s;
        assert!((a_eci - a_eci_0).norm() < 1e-9 * w.norm());
    }
}

#[test]
fn tumbling_conserves_h_eci_1e8_and_energy_1e8_over_1000s() {
    let cfg = frictionless();
    let s0 = AttitudeState {
        q_eci_from_body: UnitQuaternion::from_euler_angles(0.7, 0.4, -2.0),
        w_body_rad_s: Vector3::new(0.05, -0.08, 0.06),
        ..Default::default()
    };
    let (h0, e0) = (s0.h_eci_nms(&cfg), s0.body_energy_j(&cfg));
    let mut w_moved = 0.0_f64;
    let s = run(s0, &cfg, &Torques::default(), 0.1, 10_000, |s| {
        w_moved = w_moved.max((s.w_body_rad_s - s0.w_body_rad_s).norm());
        assert!((s.h_eci_nms(&cfg) - h0).norm() / h0.norm() < 1e-8);
    });
    assert!(
        w_moved > 0.01,
        "a non-principal spin must tumble: {w_moved}"
    );
    assert!(rel(s.h_eci_nms(&cfg).norm(), h0.norm()) < 1e-8);
    assert!(rel(s.body_energy_j(&cfg), e0) < 1e-8);
}

#[test]
fn tumbling_gyrostat_with_spinning_wheels_conserves_h_eci_1e8() {
    let cfg = frictionless();
    let s0 = AttitudeState {
        q_eci_from_body: UnitQuaternion::from_euler_angles(-0.5, 0.9, 0.1),
        w_body_rad_s: Vector3::new(0.02, 0.03, -0.04),
        wheel_speed_rad_s: [300.0, -150.0, 50.0, 500.0],
    };
    let h0 = s0.h_eci_nms(&cfg);
    run(s0, &cfg, &Torques::default(), 0.1, 10_000, |s| {
        assert!((s.h_eci_nms(&cfg) - h0).norm() / h0.norm() < 1e-8);
        assert_eq!(s.wheel_speed_rad_s, s0.wheel_speed_rad_s);
    });
}

#[test]
fn wheel_torque_exchanges_momentum_h_eci_constant_1e9() {
    let cfg = BodyConfig::default(); // with friction: it is internal too
    let s0 = AttitudeState {
        q_eci_from_body: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        w_body_rad_s: Vector3::new(0.01, -0.02, 0.005),
        wheel_speed_rad_s: [10.0, 0.0, -20.0, 5.0],
    };
    let inputs = Torques {
        wheel_torque_cmd_nm: [2.0e-5, -1.0e-5, 0.5e-5, 3.0e-5],
        ..Default::default()
    };
    let h0 = s0.h_eci_nms(&cfg);
    let s = run(s0, &cfg, &inputs, 0.1, 1_000, |s| {
        assert!((s.h_eci_nms(&cfg) - h0).norm() / h0.norm() < 1e-9);
    });
    // 100 s of tens of uN m: the wheels gain ~1e-3 N m s, the body's rate changes by about
    // as much as it had (0.02 rad/s), below the wheels' speed limit.
    assert!(
        (s.w_body_rad_s - s0.w_body_rad_s).norm() > 0.01,
        "{}",
        s.w_body_rad_s
    );
    assert!((s.wheel_speed_rad_s[0] - s0.wheel_speed_rad_s[0]) > 50.0);
}

#[test]
fn wheel_torque_on_still_body_spins_it_the_opposite_way_1e6() {
    // One wheel torqued: the body's dw/dt = -I^-1 a tau at the first instant.
    let cfg = frictionless();
    let tau = 1.0e-3;
    let inputs = Torques {
        wheel_torque_cmd_nm: [tau, 0.0, 0.0, 0.0],
        ..Default::default()
    };
    let dt = 1.0e-3;
    let s = step(&AttitudeState::default(), &cfg, &inputs, dt);
    let expected = -(cfg
        .inertia_kg_m2
        .try_inverse()
        .expect("the default inertia is invertible")
        * cfg.wheels[0].axis_body
        * tau);
    let alpha = s.w_body_rad_s / dt;
    assert!(
        (alpha - expected).norm() < 1e-6 * expected.norm(),
        "{alpha} vs {expected}"
    );
    assert!(
        rel(
            s.wheel_speed_rad_s[0],
            tau / cfg.wheels[0].inertia_kg_m2 * dt
        ) < 1e-12
    );
}

#[test]
fn wheel_torque_command_is_clamped_to_2mnm_1e12() {
    let cfg = frictionless();
    let inputs = Torques {
        wheel_torque_cmd_nm: [1.0, -1.0, 0.0, 0.0],
        ..Default::default()
    };
    let s = step(&AttitudeState::default(), &cfg, &inputs, 0.1);
    let j = cfg.wheels[0].inertia_kg_m2;
    assert!(rel(s.wheel_speed_rad_s[0], 2.0e-3 / j * 0.1) < 1e-12);
    assert!(rel(s.wheel_speed_rad_s[1], -2.0e-3 / j * 0.1) < 1e-12);
}

#[test]
fn wheel_speed_saturates_at_6000rpm_within_0p1pct_and_h_eci_1e9() {
    let cfg = BodyConfig::default();
    let max = cfg.wheels[0].max_speed_rad_s;
    assert!(rel(max, 6000.0 / 60.0 * 2.0 * std::f64::consts::PI) < 1e-15);
    let inputs = Torques {
        wheel_torque_cmd_nm: [2.0e-3, -2.0e-3, 2.0e-3, -2.0e-3],
        ..Default::default()
    };
    let s0 = AttitudeState {
        w_body_rad_s: Vector3::new(0.0, 0.0, 0.01),
        ..Default::default()
    };
    let h0 = s0.h_eci_nms(&cfg);
    // 2 mN m on 1e-5 kg m^2 reaches 628 rad/s in 3.1 s; run 60 s.
    let s = run(s0, &cfg, &inputs, 0.1, 600, |s| {
        for o in s.wheel_speed_rad_s {
            assert!(o.abs() <= max, "{o}");
        }
        assert!((s.h_eci_nms(&cfg) - h0).norm() / h0.norm() < 1e-9);
    });
    for (i, o) in s.wheel_speed_rad_s.iter().enumerate() {
        let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
        assert!(sign * o > 0.999 * max, "wheel {i}: {o}");
    }
}

#[test]
fn friction_spins_a_free_wheel_down_exponentially_1e3() {
    let cfg = BodyConfig::default();
    let w = &cfg.wheels[2];
    let s0 = AttitudeState {
        wheel_speed_rad_s: [0.0, 0.0, 400.0, 0.0],
        ..Default::default()
    };
    let t = 100.0;
    let s = run(s0, &cfg, &Torques::default(), 0.1, 1_000, |_| {});
    // Body and wheel share the momentum; the body's rate is small, so the wheel's speed
    // relative to the body follows exp(-c t / J) closely but not exactly (coupling through I).
    let expected = 400.0 * (-w.friction_nm_s_rad * t / w.inertia_kg_m2).exp();
    assert!(s.wheel_speed_rad_s[2] < 400.0);
    assert!(
        rel(s.wheel_speed_rad_s[2], expected) < 1e-3,
        "{} vs {expected}",
        s.wheel_speed_rad_s[2]
    );
}

#[test]
fn quaternion_stays_unit_norm_within_1e12() {
    let cfg = BodyConfig::default();
    let inputs = Torques {
        wheel_torque_cmd_nm: [1.0e-4, 2.0e-4, -1.0e-4, 0.0],
        mtq_dipole_cmd_am2: Vector3::new(0.1, -0.2, 0.05),
        b_body_t: Vector3::new(2.0e-5, -1.0e-5, 3.0e-5),
        r_eci_m: Some(Vector3::new(6_878_000.0, 0.0, 0.0)),
        ..Default::default()
    };
    let s0 = AttitudeState {
        w_body_rad_s: Vector3::new(0.17, -0.1, 0.12), // ~13 deg/s tumble
        ..Default::default()
    };
    run(s0, &cfg, &inputs, 0.1, 10_000, |s| {
        assert!((s.q_eci_from_body.quaternion().norm() - 1.0).abs() < 1e-12);
    });
}

#[test]
fn magnetorquer_torque_is_m_cross_b_on_a_still_body_1e9() {
    let cfg = BodyConfig::default();
    let m = Vector3::new(0.1, -0.15, 0.05);
    let b = Vector3::new(2.0e-5, 3.0e-5, -4.0e-5);
    let inputs = Torques {
        mtq_dipole_cmd_am2: m,
        b_body_t: b,
        ..Default::default()
    };
    let dt = 1.0e-3;
    let s = step(&AttitudeState::default(), &cfg, &inputs, dt);
    let expected_alpha = cfg
        .inertia_kg_m2
        .try_inverse()
        .expect("the default inertia is invertible")
        * m.cross(&b);
    let alpha = s.w_body_rad_s / dt;
    assert!(
        (alpha - expected_alpha).norm() < 1e-9 * expected_alpha.norm(),
        "{alpha}"
    );
}

#[test]
fn magnetorquer_dipole_is_clamped_to_0p2am2_1e9() {
    let cfg = BodyConfig::default();
    let b = Vector3::new(0.0, 0.0, 5.0e-5);
    let inputs = Torques {
        mtq_dipole_cmd_am2: Vector3::new(5.0, 0.0, 0.0),
        b_body_t: b,
        ..Default::default()
    };
    let dt = 1.0e-3;
    let s = step(&AttitudeState::default(), &cfg, &inputs, dt);
    let expected = cfg
        .inertia_kg_m2
        .try_inverse()
        .expect("the default inertia is invertible")
        * Vector3::new(0.2, 0.0, 0.0).cross(&b);
    assert!((s.w_body_rad_s / dt - expected).norm() < 1e-9 * expected.norm());
}

#[test]
fn gravity_gradient_is_zero_with_a_principal_axis_on_nadir_1e20nm() {
    let cfg = BodyConfig::default();
    let r = 6_878_000.0;
    for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
        // Body axis along nadir (-r) and along zenith.
        for sign in [-1.0, 1.0] {
            let r_eci = Vector3::new(0.3, -0.8, 0.5).normalize() * r;
            let q = UnitQuaternion::rotation_between(&(axis * sign), &r_eci.normalize())
                .expect("not antiparallel");
            let t = gravity_gradient_body_nm(&cfg, &q, &r_eci);
            assert!(t.norm() < 1e-20, "{axis} {sign}: {t}");
        }
    }
}

#[test]
fn gravity_gradient_restores_min_inertia_axis_to_nadir_and_matches_formula_1e9() {
    let cfg = BodyConfig::default();
    let i = cfg.inertia_kg_m2;
    assert!(
        i[(2, 2)] < i[(0, 0)] && i[(2, 2)] < i[(1, 1)],
        "Z is the minimum axis"
    );
    let r = 6_878_000.0;
    let r_eci = Vector3::new(0.0, 0.0, r); // zenith along ECI Z, nadir along -Z
    for theta in [0.05_f64, -0.05, 0.3] {
        // Body -Z (nadir-pointing at theta = 0) tilted about body X by theta.
        let q = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), theta);
        let t = gravity_gradient_body_nm(&cfg, &q, &r_eci);
        // Restoring: the torque about X opposes the tilt.
        assert!(t.x * theta < 0.0, "theta {theta}: {t}");
        let expected =
            3.0 * MU_EARTH_M3_S2 / r.powi(3) * (i[(2, 2)] - i[(1, 1)]) * theta.sin() * theta.cos();
        assert!(rel(t.x, expected) < 1e-9, "{} vs {expected}", t.x);
        assert!(t.y.abs() < 1e-9 * t.x.abs() && t.z.abs() < 1e-9 * t.x.abs());
    }
    // And the dynamics: released at a tilt, the body swings back toward nadir.
    let s0 = AttitudeState {
        q_eci_from_body: UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.1),
        ..Default::default()
    };
    let inputs = Torques {
        r_eci_m: Some(r_eci),
        ..Default::default()
    };
    let s = run(s0, &cfg, &inputs, 0.1, 100, |_| {});
    assert!(s.w_body_rad_s.x < 0.0);
    assert!(s.q_eci_from_body.angle() < 0.1);
}

#[test]
fn default_bus_is_the_6u_box_and_nasa_pyramid_1e12() {
    let cfg = BodyConfig::default();
    let expected = Matrix3::from_diagonal(&Vector3::new(0.10, 0.13, 0.05));
    assert!((cfg.inertia_kg_m2 - expected).norm() < 1e-12);
    // Pyramid: unit axes, 54.74 deg from +Z, the four summing to 4 cos(beta) z.
    let mut sum = Vector3::zeros();
    for w in &cfg.wheels {
        assert!((w.axis_body.norm() - 1.0).abs() < 1e-12);
        assert!((w.axis_body.z - 1.0 / 3.0_f64.sqrt()).abs() < 1e-12);
        sum += w.axis_body;
    }
    assert!((sum - Vector3::new(0.0, 0.0, 4.0 / 3.0_f64.sqrt())).norm() < 1e-12);
    assert_eq!(
        WheelConfig::pyramid_axis_body(4),
        WheelConfig::pyramid_axis_body(0)
    );
    assert!(rel(cfg.mtq_max_dipole_am2, 0.2) < 1e-15);
}

#[test]
fn step_is_deterministic_bit_for_bit() {
    let cfg = BodyConfig::default();
    let inputs = Torques {
        wheel_torque_cmd_nm: [1.0e-4, 2.0e-4, -1.0e-4, 0.0],
        mtq_dipole_cmd_am2: Vector3::new(0.1, -0.2, 0.05),
        b_body_t: Vector3::new(2.0e-5, -1.0e-5, 3.0e-5),
        r_eci_m: Some(Vector3::new(6_878_000.0, 1.0, 2.0)),
        disturbance_body_nm: Vector3::new(1e-7, 0.0, -1e-7),
    };
    let s0 = AttitudeState {
        w_body_rad_s: Vector3::new(0.1, 0.2, -0.1),
        ..Default::default()
    };
    let a = run(s0, &cfg, &inputs, 0.1, 500, |_| {});
    let b = run(s0, &cfg, &inputs, 0.1, 500, |_| {});
    assert_eq!(a, b);
}

#[test]
fn wheels_driven_into_saturation_under_a_tumble_keep_h_eci_1e8() {
    // Full torque on all four wheels from a slow tumble: the wheels saturate within ~4 s while
    // the body spins up to ~0.14 rad/s. The motor's on/off decision is made once per step, so
    // RK4 keeps its order through the switch (deciding it per stage cost 300x in |H| error).
    let cfg = BodyConfig::default();
    let s0 = AttitudeState {
        q_eci_from_body: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        w_body_rad_s: Vector3::new(0.01, -0.02, 0.005),
        wheel_speed_rad_s: [10.0, 0.0, -20.0, 5.0],
    };
    let inputs = Torques {
        wheel_torque_cmd_nm: [1.0e-3, -0.5e-3, 0.2e-3, 1.5e-3],
        ..Default::default()
    };
    let h0 = s0.h_eci_nms(&cfg);
    let s = run(s0, &cfg, &inputs, 0.1, 1_000, |s| {
        assert!((s.h_eci_nms(&cfg) - h0).norm() / h0.norm() < 1e-8);
    });
    let max = cfg.wheels[0].max_speed_rad_s;
    assert!(s.wheel_speed_rad_s.iter().all(|o| o.abs() > 0.999 * max));
}
