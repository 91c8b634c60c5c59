//! Burns on the true orbit: an [`EnvModel`] driven like the FC drives it (10 Hz ticks,
//! [`burns::apply`] before each evaluation, TMATP-like queries between ticks) through a
//! 10 s burn posted on a [`BurnBoard`] as the ECU posts it.
//!
//! Checks: the semi-major axis rises as the rocket equation and Gauss's variational
//! equation say (`da = 2 a^2 v dv / mu`, tangential burn), the position afterwards departs
//! from SGP4's (and from an unburnt numerical twin) as Clohessy-Wiltshire predicts, a burn
//! cut short is applied exactly to its cut, and the task order at the cut does not matter.
#![allow(clippy::unwrap_used)]

use m6p_nodes_fc::burns;
use m6p_nodes_fc::environment::EnvModel;
use nalgebra::{UnitQuaternion, Vector3};
use orbit::cowell::{CowellConfig, MU_EARTH_KM3_S2};
use orbit::propagate::{Sgp4Propagator, StateVector};
use orbit::tle::{ChecksumMode, Tle};
use platform::SimTime;
use platform::board::{Burn, BurnBoard};

/// The default scenario's 6U TLE (scenarios/default.toml).
const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
/// 2026-04-30T18:00:00Z at simulated time 0.
const START_UNIX_NS: i64 = 1_777_572_000 * 1_000_000_000;
const TICK_NS: u64 = 100_000_000;
const S: u64 = 1_000_000_000;
/// The burn: the ECU's defaults (0.3 N, Isp 200 s, 12 kg dry + 0.5 kg propellant), 10 s.
const THRUST_N: f64 = 0.3;
const ISP_S: f64 = 200.0;
const G0: f64 = 9.806_65;
const MASS_KG: f64 = 12.5;
const BURN_START_NS: u64 = 600 * S + 30_000_000;
const BURN_NS: u64 = 10 * S;

fn tle() -> Tle {
    Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()
}

fn sgp4_model() -> EnvModel {
    EnvModel::new(Sgp4Propagator::new(&tle()).unwrap())
}

fn unix(t_ns: u64) -> i64 {
    START_UNIX_NS + t_ns as i64
}

/// Osculating two-body semi-major axis, km.
fn sma_km(s: &StateVector) -> f64 {
    1.0 / (2.0 / s.r_km.norm() - s.v_km_s.norm_squared() / MU_EARTH_KM3_S2)
}

/// An attitude with body +Z along `dir_eci`.
fn z_along(dir_eci: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(&Vector3::z(), dir_eci).unwrap()
}

fn the_burn(posted_ns: u64, end_ns: u64) -> Burn {
    Burn {
        posted: SimTime::from_ns(posted_ns),
        start: SimTime::from_ns(BURN_START_NS),
        end: SimTime::from_ns(end_ns),
        thrust_n: THRUST_N,
        mass_flow_kg_s: THRUST_N / (ISP_S * G0),
        mass_kg: MASS_KG,
        dir_body: Vector3::z(),
    }
}

/// The rocket equation's delta-v of the whole 10 s burn, m/s.
fn rocket_dv_m_s() -> f64 {
    let m_end = MASS_KG - THRUST_N / (ISP_S * G0) * (BURN_NS as f64 * 1e-9);
    ISP_S * G0 * (MASS_KG / m_end).ln()
}

/// Drive `model` like the FC from `from_ns` to `to_ns` at 10 Hz: apply the board's burns,
/// evaluate the environment at the tick, and ask for the state in the middle of the tick
/// interval (a TMATP between ticks); `before_tick(t)` runs first at each tick (another
/// task acting at the same instant). Every evaluation must succeed.
fn drive(
    model: &mut EnvModel,
    board: &BurnBoard,
    q: &UnitQuaternion<f64>,
    from_ns: u64,
    to_ns: u64,
    applied_until_ns: &mut u64,
    mut before_tick: impl FnMut(u64),
) -> burns::Applied {
    let mut total = burns::Applied::default();
    let mut t = from_ns;
    while t <= to_ns {
        before_tick(t);
        let a = burns::apply(model, board, q, t, unix(t), applied_until_ns).unwrap();
        total.impulses += a.impulses;
        total.dv_eci_m_s += a.dv_eci_m_s;
        total.switched |= a.switched;
        model.at(unix(t)).unwrap();
        model.state_j2000(unix(t + TICK_NS / 2)).unwrap();
        t += TICK_NS;
    }
    total
}

/// Prograde attitude at the start of the burn (the velocity turns by 0.011 rad during the
/// 10 s: a cosine loss of 1.6e-5).
fn prograde() -> UnitQuaternion<f64> {
    let v = sgp4_model()
        .state_j2000(unix(BURN_START_NS))
        .unwrap()
        .v_km_s;
    z_along(&v)
}

#[test]
fn a_10_s_burn_raises_the_semi_major_axis_as_gauss_says() {
    // Two-body after the switch, so that the osculating a is constant but for the burn.
    let mut m = sgp4_model().with_cowell_config(CowellConfig::two_body());
    let before = m.state_j2000(unix(BURN_START_NS)).unwrap();
    let board = BurnBoard::new();
    board
        .post(the_burn(BURN_START_NS, BURN_START_NS + BURN_NS))
        .unwrap();
    let q = prograde();
    // Ticks on the whole 0.1 s grid; the burn starts 30 ms after one.
    let mut applied_until = 598 * S;
    let a = drive(
        &mut m,
        &board,
        &q,
        598 * S,
        BURN_START_NS + 20 * S,
        &mut applied_until,
        |_| {},
    );
    assert!(a.switched && m.is_numerical());
    // 100 ticks of 0.1 s inside the burn: 0.03 s of it before the first tick after the
    // start and 0.07 s at the end, so 101 impulses.
    assert_eq!(a.impulses, 101);
    let dv = rocket_dv_m_s();
    assert!(
        (a.dv_eci_m_s.norm() - dv).abs() < 1e-6 * dv,
        "{} vs {dv}",
        a.dv_eci_m_s.norm()
    );

    let after = m.state_j2000(unix(BURN_START_NS + 20 * S)).unwrap();
    let a0_km = sma_km(&before);
    let da_m = (sma_km(&after) - a0_km) * 1e3;
    let v_m_s = before.v_km_s.norm() * 1e3;
    let a0_m = a0_km * 1e3;
    let mu_m3_s2 = MU_EARTH_KM3_S2 * 1e9;
    let want_m = 2.0 * a0_m * a0_m * v_m_s * dv / mu_m3_s2;
    eprintln!("dv {dv:.5} m/s, da {da_m:.2} m, Gauss {want_m:.2} m");
    assert!(
        (da_m / want_m - 1.0).abs() < 0.02,
        "da {da_m} m vs Gauss {want_m} m"
    );
}

/// Position of `s` relative to `reference` in the reference's radial / along-track /
/// cross-track frame, m.
fn rtn_m(s: &StateVector, reference: &StateVector) -> Vector3<f64> {
    let r = reference.r_km.normalize();
    let n = reference.r_km.cross(&reference.v_km_s).normalize();
    let t = n.cross(&r);
    let d = (s.r_km - reference.r_km) * 1e3;
    Vector3::new(d.dot(&r), d.dot(&t), d.dot(&n))
}

#[test]
fn after_the_burn_the_position_departs_from_sgp4_as_clohessy_wiltshire_says() {
    let mut m = sgp4_model().with_cowell_config(burns::cowell_config_for(&tle()));
    let board = BurnBoard::new();
    board
        .post(the_burn(BURN_START_NS, BURN_START_NS + BURN_NS))
        .unwrap();
    let q = prograde();
    let mut applied_until = 599 * S;
    drive(
        &mut m,
        &board,
        &q,
        599 * S,
        BURN_START_NS + 11 * S,
        &mut applied_until,
        |_| {},
    );
    // The unburnt numerical twin: switched at the instant of the first impulse.
    let mut twin = sgp4_model().with_cowell_config(burns::cowell_config_for(&tle()));
    twin.switch_to_numerical(unix(BURN_START_NS + 50_000_000))
        .unwrap();
    let mut sgp4 = sgp4_model();

    let s0 = sgp4.state_j2000(unix(BURN_START_NS)).unwrap();
    let a_m = sma_km(&s0) * 1e3;
    let n = (MU_EARTH_KM3_S2 * 1e9 / a_m.powi(3)).sqrt();
    let dv = rocket_dv_m_s();
    let mid_ns = BURN_START_NS + BURN_NS / 2;
    // Half an orbit and a whole one after the burn's middle.
    let period_s = 2.0 * std::f64::consts::PI / n;
    for frac in [0.5, 1.0] {
        let tau_s = frac * period_s;
        let t_ns = mid_ns + (tau_s * 1e9) as u64;
        let burnt = m.state_j2000(unix(t_ns)).unwrap();
        let nt = n * tau_s;
        // CW, tangential impulse dv at tau = 0: radial, along-track.
        let cw = Vector3::new(
            2.0 * dv / n * (1.0 - nt.cos()),
            dv / n * (4.0 * nt.sin() - 3.0 * nt),
            0.0,
        );
        let vs_twin = rtn_m(&burnt, &twin.state_j2000(unix(t_ns)).unwrap());
        let sgp4_state = sgp4.state_j2000(unix(t_ns)).unwrap();
        let vs_sgp4 = rtn_m(&burnt, &sgp4_state);
        let twin_vs_sgp4 = rtn_m(&twin.state_j2000(unix(t_ns)).unwrap(), &sgp4_state);
        eprintln!(
            "{frac} orbit: CW {:.1} m {cw:.1?}; burnt - twin {:.1} m {vs_twin:.1?}; \
             burnt - SGP4 {:.1} m; twin - SGP4 {:.1} m",
            cw.norm(),
            vs_twin.norm(),
            vs_sgp4.norm(),
            twin_vs_sgp4.norm()
        );
        // Against the unburnt twin: the burn alone, within 2 % of CW.
        assert!(
            (vs_twin - cw).norm() < 0.02 * cw.norm(),
            "{frac}: {vs_twin:?} vs CW {cw:?}"
        );
        // Against SGP4: the same, up to the numerical-vs-SGP4 model difference.
        assert!(
            (vs_sgp4 - cw).norm() < 0.02 * cw.norm() + twin_vs_sgp4.norm(),
            "{frac}: {vs_sgp4:?} vs CW {cw:?} (model difference {twin_vs_sgp4:?})"
        );
        assert!(twin_vs_sgp4.norm() < 0.1 * cw.norm(), "{twin_vs_sgp4:?}");
        // Raised orbit, slower: behind the unburnt satellite.
        assert!(vs_sgp4.y < -1000.0, "{vs_sgp4:?}");
    }
}

#[test]
fn a_cut_burn_is_applied_exactly_to_its_cut_whichever_task_runs_first() {
    // `ecu_first`: at the tick where the cut is due, the ECU's SAFE (re-posting the burn with
    // its original posted_ns and the new end) runs before the FC's tick; otherwise after.
    // A cut between ticks is posted before the next tick in any case.
    let run = |cut: u64, ecu_first: bool| {
        let mut m = sgp4_model();
        let board = BurnBoard::new();
        board
            .post(the_burn(BURN_START_NS, BURN_START_NS + BURN_NS))
            .unwrap();
        let q = prograde();
        let mut applied_until = 599 * S;
        let mut posted_cut = false;
        let mut t = 599 * S;
        let mut dv = Vector3::zeros();
        while t <= BURN_START_NS + 12 * S {
            let due = !posted_cut && t >= cut;
            if due && (ecu_first || t > cut) {
                board.post(the_burn(BURN_START_NS, cut)).unwrap();
                posted_cut = true;
            }
            let a = burns::apply(&mut m, &board, &q, t, unix(t), &mut applied_until).unwrap();
            dv += a.dv_eci_m_s;
            m.at(unix(t)).unwrap();
            if due && !posted_cut {
                board.post(the_burn(BURN_START_NS, cut)).unwrap();
                posted_cut = true;
            }
            t += TICK_NS;
        }
        (dv, m.state_j2000(unix(BURN_START_NS + 60 * S)).unwrap())
    };
    let cut_between = BURN_START_NS + 4 * S + 330_000_000;
    let cut_at_tick = cut_between - cut_between % TICK_NS;
    assert_eq!(cut_at_tick % TICK_NS, 0);
    for cut in [cut_at_tick, cut_between] {
        let want = burns::delta_v_m_s(&the_burn(0, cut), 0, u64::MAX);
        let (dv_a, s_a) = run(cut, true);
        let (dv_b, s_b) = run(cut, false);
        assert!(
            (dv_a.norm() - want).abs() < 1e-10,
            "cut {cut}: {} vs {want}",
            dv_a.norm()
        );
        assert_eq!(dv_a, dv_b, "task order at the cut");
        assert_eq!(s_a, s_b, "task order at the cut");
    }
    // And the cut matters: a burn left to run gives more.
    let (dv_full, _) = run(u64::MAX, true);
    assert!((dv_full.norm() - rocket_dv_m_s()).abs() < 1e-9);
}

#[test]
fn no_burn_leaves_sgp4_alone_and_a_burn_posted_at_a_tick_waits_for_the_next() {
    let mut m = sgp4_model();
    let board = BurnBoard::new();
    let q = UnitQuaternion::identity();
    let mut until = 0;
    for k in 0..50u64 {
        let t = k * TICK_NS;
        assert_eq!(
            burns::apply(&mut m, &board, &q, t, unix(t), &mut until).unwrap(),
            burns::Applied::default()
        );
    }
    assert!(!m.is_numerical());
    // Posted at a tick's instant: not taken at that tick, all of it at the next.
    let t = 50 * TICK_NS;
    board
        .post(Burn {
            posted: SimTime::from_ns(t),
            start: SimTime::from_ns(t),
            end: SimTime::from_ns(t + 50_000_000),
            ..the_burn(0, 0)
        })
        .unwrap();
    let a = burns::apply(&mut m, &board, &q, t, unix(t), &mut until).unwrap();
    assert_eq!(a.impulses, 0);
    let t2 = t + TICK_NS;
    let a = burns::apply(&mut m, &board, &q, t2, unix(t2), &mut until).unwrap();
    assert_eq!(a.impulses, 1);
    assert!(a.switched);
    assert_eq!(until, t2);
    // Going back does nothing.
    let a = burns::apply(&mut m, &board, &q, t, unix(t), &mut until).unwrap();
    assert_eq!(a, burns::Applied::default());
    assert_eq!(until, t2);
}
