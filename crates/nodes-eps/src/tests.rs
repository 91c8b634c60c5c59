//! The EPS as a node: driven through `csp::node::Host` with truth and activity boards, the
//! sink, the port 10 commands, and orbit-average energy checks on synthetic truth.
#![allow(clippy::unwrap_used)]

use std::f64::consts::PI;

use csp::node::{Host, IfaceConfig, NodeConfig, Tap, Transmit};
use csp::router::Route;
use csp::{Header, Packet, SimTime};
use nalgebra::{UnitQuaternion, Vector3};
use platform::board::{Activity, ActivityBoard, TruthBoard};
use platform::truth::TruthSnapshot;
use proptest::prelude::*;

use super::*;

/// The main ground station, which sends the requests in these tests.
const GS: u8 = 16;

type Outputs = csp::node::Tapped<EpsOutput>;

fn host(app: EpsApp) -> (Host<Tap<EpsApp>>, Outputs) {
    let (app, out) = Tap::new(app);
    let mut c = NodeConfig::new("EPS", 4);
    c.ifaces = vec![IfaceConfig::packet("p")];
    c.routes.set_default(Route::direct(0));
    (Host::new(c, app, SimTime::ZERO), out)
}

fn run_until(h: &mut Host<Tap<EpsApp>>, end: SimTime) {
    while let Some(t) = h.poll_timeout() {
        if t > end {
            break;
        }
        h.handle_timeout(t);
    }
}

/// Send `req` to port 10 at `t`; every reply data that came out.
fn request(h: &mut Host<Tap<EpsApp>>, req: &[u8], t: SimTime) -> Vec<Vec<u8>> {
    run_until(h, t);
    h.handle_packet(0, Packet::new(Header::new(GS, 4, 10, 40), req.to_vec()), t);
    std::iter::from_fn(|| h.node.poll_transmit())
        .map(|x| match x {
            Transmit::Packet { packet, .. } => {
                assert_eq!(packet.header, Header::new(4, GS, 40, 10));
                packet.data
            }
            Transmit::Can { .. } => panic!("no CAN interface"),
        })
        .collect()
}

fn one_reply(h: &mut Host<Tap<EpsApp>>, req: &[u8], t: SimTime) -> Vec<u8> {
    let mut r = request(h, req, t);
    assert_eq!(r.len(), 1, "exactly one reply to {req:?}");
    r.remove(0)
}

fn samples(out: &Outputs) -> Vec<(SimTime, f64, f64, f64, u16)> {
    out.lock()
        .unwrap()
        .iter()
        .filter_map(|o| match o {
            EpsOutput::Sample {
                t,
                soc,
                solar_w,
                load_w,
                channels,
                ..
            } => Some((*t, *soc, *solar_w, *load_w, *channels)),
            EpsOutput::Channel { .. } => None,
        })
        .collect()
}

fn switches(out: &Outputs) -> Vec<(SimTime, Channel, bool, SwitchCause)> {
    out.lock()
        .unwrap()
        .iter()
        .filter_map(|o| match o {
            EpsOutput::Channel {
                t,
                channel,
                on,
                cause,
            } => Some((*t, *channel, *on, *cause)),
            EpsOutput::Sample { .. } => None,
        })
        .collect()
}

fn snapshot(
    t_s: u64,
    sun_eci: Vector3<f64>,
    q: UnitQuaternion<f64>,
    visible: f64,
) -> TruthSnapshot {
    TruthSnapshot {
        t: SimTime::from_secs(t_s),
        q_eci_from_body: q,
        sun_eci_unit: sun_eci,
        in_eclipse_fraction_visible: visible,
        ..TruthSnapshot::default()
    }
}

fn f32_at(b: &[u8], off: usize) -> f32 {
    f32::from_le_bytes(b[off..off + 4].try_into().unwrap())
}
fn u16_at(b: &[u8], off: usize) -> u16 {
    u16::from_le_bytes(b[off..off + 2].try_into().unwrap())
}

#[test]
fn power_follows_the_attitude_and_the_eclipse_through_the_truth_board() {
    let truth = TruthBoard::new();
    let (mut h, out) = host(app().with_truth(truth.clone()));
    // No truth yet: no solar power.
    run_until(&mut h, SimTime::from_secs(3));
    let s = samples(&out);
    assert_eq!(s.len(), 3);
    assert!(s.iter().all(|x| x.2 == 0.0));
    let full = 1361.0 * (0.03 * 0.85 + 0.12 * 0.9) * 0.295;
    // Sun on the wings (body +X along ECI +X), then edge-on (body turned 90 deg about Y so
    // the sun is along body -Z, which has no cells), then the sun on +X in penumbra (0.4),
    // then umbra.
    let edge = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -PI / 2.0);
    let steps = [
        (3, UnitQuaternion::identity(), 1.0, full),
        (6, edge, 1.0, 0.0),
        (9, UnitQuaternion::identity(), 0.4, 0.4 * full),
        (12, UnitQuaternion::identity(), 0.0, 0.0),
    ];
    for (t, q, vis, want) in steps {
        truth.publish(&snapshot(t, Vector3::x(), q, vis)).unwrap();
        run_until(&mut h, SimTime::from_secs(t + 3));
        let s = samples(&out);
        // The ticks after the snapshot (strictly after its instant) see it.
        for x in s.iter().filter(|x| x.0 > SimTime::from_secs(t)) {
            assert!(
                (x.2 - want).abs() < 1e-9,
                "t {:?}: {} W, want {want}",
                x.0,
                x.2
            );
        }
    }
    // Telemetry, decoded independently of `wire::TmEps`: the umbra state.
    let r = one_reply(
        &mut h,
        &[1],
        SimTime::from_secs(15) + Duration::from_millis(500),
    );
    assert_eq!(r.len(), 2 + 88);
    assert_eq!(&r[..2], &[1, 1]);
    let d = &r[2..];
    assert_eq!(f32_at(d, 16), 0.0, "solar");
    assert!((f32_at(d, 20) - 7.5).abs() < 1e-4, "load {}", f32_at(d, 20));
    assert!(f32_at(d, 4) < 0.0, "discharging");
    assert_eq!(d[24], 6, "panels");
    assert_eq!(u16_at(d, 57), 0x1ff, "all channels on");
    // PC channel current: 0.6 W at the battery voltage.
    let v = f32_at(d, 0);
    assert!((7.5..8.3).contains(&v), "{v}");
    assert_eq!(
        u16_at(d, 61 + 2 * 3),
        (0.6 / f64::from(v) * 1000.0).round() as u16
    );
}

#[test]
fn battery_integrates_the_balance_of_a_sunlit_and_a_dark_hour() {
    let truth = TruthBoard::new();
    let cfg = EpsConfig {
        initial_soc: 0.2,
        ..EpsConfig::default()
    };
    let (mut h, out) = host(EpsApp::new(cfg).with_truth(truth.clone()));
    // Sun on the wings from t = 0: 53.6 W of array power, 7.5 W of load; the 46.1 W surplus
    // is above the 40 W charge limit, so the battery takes 40 W (the rest is spilled).
    truth
        .publish(&snapshot(0, Vector3::x(), UnitQuaternion::identity(), 1.0))
        .unwrap();
    run_until(&mut h, SimTime::from_secs(3600));
    let wh = h.app.eps().battery().energy_wh();
    assert!((wh - (15.4 + 40.0 * 0.93)).abs() < 1e-6, "{wh}");
    // Dark: discharge at 7.5 W / 0.95 (the tick after the snapshot sees it).
    truth
        .publish(&snapshot(
            3600,
            Vector3::x(),
            UnitQuaternion::identity(),
            0.0,
        ))
        .unwrap();
    run_until(&mut h, SimTime::from_secs(7200));
    let wh2 = h.app.eps().battery().energy_wh();
    assert!((wh2 - (wh - 7.5 / 0.95)).abs() < 1e-6, "{wh2}");
    let s = samples(&out);
    assert_eq!(s.len(), 7200);
    // Charging current positive in the sun, negative in the dark.
    let currents: Vec<f64> = out
        .lock()
        .unwrap()
        .iter()
        .filter_map(|o| match o {
            EpsOutput::Sample { battery_a, .. } => Some(*battery_a),
            EpsOutput::Channel { .. } => None,
        })
        .collect();
    assert!(currents[..3600].iter().all(|&a| a > 4.0));
    assert!(currents[3600..].iter().all(|&a| a < -0.9));
}

#[test]
fn shedding_and_restoration_with_hysteresis_emit_channel_outputs() {
    let truth = TruthBoard::new();
    let cfg = EpsConfig {
        initial_soc: 0.305,
        channels_on: ALL_CHANNELS & !Channel::Payload15.bit(),
        ..EpsConfig::default()
    };
    let (mut h, out) = host(EpsApp::new(cfg).with_truth(truth.clone()));
    // Payload 15 is configured off: reported at boot.
    assert_eq!(
        switches(&out),
        vec![(
            SimTime::ZERO,
            Channel::Payload15,
            false,
            SwitchCause::Initial
        )]
    );
    // Dark: 7 W drains 0.5 % (0.385 Wh) in about 200 s.
    run_until(&mut h, SimTime::from_secs(400));
    let sw = switches(&out);
    let shed: Vec<_> = sw.iter().skip(1).collect();
    assert_eq!(shed.len(), 4, "{sw:?}");
    let t_shed = shed[0].0;
    assert!(shed.iter().all(|x| x.0 == t_shed && !x.2));
    assert!(
        shed.iter()
            .all(|x| x.3 == SwitchCause::Shed(Group::Payload))
    );
    let s = samples(&out);
    let at = s.iter().find(|x| x.0 == t_shed).unwrap();
    assert!(at.1 < 0.30 && at.4 == 0x00f, "{at:?}");
    let before = s.iter().find(|x| x.0 + DEFAULT_TICK == t_shed).unwrap();
    assert!(before.1 >= 0.30);
    // Switching a shed payload on is refused; CHGET shows the shed mask.
    assert_eq!(
        one_reply(&mut h, &[3, 4, 1], SimTime::from_secs(401)),
        vec![3, 0]
    );
    assert_eq!(
        one_reply(&mut h, &[2], SimTime::from_secs(402)),
        vec![2, 1, 0x0f, 0x00, 0x70, 0x01]
    );
    // An operator switches the S-band off while shed: it will not come back.
    assert_eq!(
        one_reply(&mut h, &[3, 8, 0], SimTime::from_secs(403)),
        vec![3, 1, 0x0f, 0x00, 0x70, 0x00]
    );
    // Sun on the wings: charging at ~40 W, from 30 % to 40 % in ~12 min; nothing comes back
    // before 40 %.
    truth
        .publish(&snapshot(
            403,
            Vector3::x(),
            UnitQuaternion::identity(),
            1.0,
        ))
        .unwrap();
    run_until(&mut h, SimTime::from_secs(2000));
    let sw = switches(&out);
    let back: Vec<_> = sw.iter().filter(|x| x.2).collect();
    assert_eq!(
        back.iter().map(|x| x.1).collect::<Vec<_>>(),
        vec![Channel::Payload12, Channel::Payload13, Channel::Payload14]
    );
    let t_back = back[0].0;
    let s = samples(&out);
    let at = s.iter().find(|x| x.0 == t_back).unwrap();
    assert!(at.1 >= 0.40 && at.4 == 0x07f, "{at:?}");
    let before = s.iter().find(|x| x.0 + DEFAULT_TICK == t_back).unwrap();
    assert!(before.1 < 0.40 && before.1 > 0.30, "{before:?}");
    assert!(
        back.iter()
            .all(|x| x.3 == SwitchCause::Restore(Group::Payload))
    );
}

#[test]
fn channel_commands_switch_and_report() {
    let (mut h, out) = host(app());
    assert!(
        switches(&out).is_empty(),
        "every channel on: nothing to report"
    );
    let t = SimTime::from_secs(5) + Duration::from_millis(250);
    // PC off: the reply carries the new mask; the twin is told at the command's instant.
    assert_eq!(
        one_reply(&mut h, &[3, 3, 0], t),
        vec![3, 1, 0xf7, 0x01, 0, 0]
    );
    assert_eq!(
        switches(&out),
        vec![(t, Channel::Pc, false, SwitchCause::Command)]
    );
    // Again: succeeds, nothing switches.
    assert_eq!(
        one_reply(&mut h, &[3, 3, 0], t),
        vec![3, 1, 0xf7, 0x01, 0, 0]
    );
    assert_eq!(switches(&out).len(), 1);
    // The load drops by the PC's 0.6 W at the next tick.
    run_until(&mut h, SimTime::from_secs(7));
    let s = samples(&out);
    assert!((s[4].3 - 7.5).abs() < 1e-9 && (s[6].3 - 6.9).abs() < 1e-9);
    // Its share of tick 6 is exact: 0.25 s with the PC, 0.75 s without.
    let e = h.app.eps().energy_since_boot_wh().1 * 3600.0;
    assert!((e - (5.25 * 7.5 + 1.75 * 6.9)).abs() < 1e-9, "{e}");
    assert_eq!(
        one_reply(&mut h, &[3, 3, 1], SimTime::from_secs(8)),
        vec![3, 1, 0xff, 0x01, 0, 0]
    );
    assert_eq!(
        switches(&out)[1],
        (
            SimTime::from_secs(8),
            Channel::Pc,
            true,
            SwitchCause::Command
        )
    );
}

/// The console's `tm` is TMEPS of the same instant, one `name value unit` line per field
/// with the ICD's names and units: volts, amps, watts, Wh, mA, and the channel masks in hex
/// with the channels they hold.
#[test]
fn console_tm_is_tmeps_with_units_one_field_a_line() {
    let (mut h, _out) = host(app());
    let t = SimTime::from_secs(60);
    // PC off: a mask that is not every channel.
    one_reply(&mut h, &[3, 3, 0], SimTime::from_secs(5));
    run_until(&mut h, t);
    let text = h.console("tm", t);
    let tm = wire::TmEps::parse(&one_reply(&mut h, &[1], t)[2..]).unwrap();
    let fields = <wire::TmEps as csp::icd::Describe>::FIELDS;
    let names: Vec<String> = csp::icd::leaves(fields).into_iter().map(|l| l.0).collect();
    let got: Vec<&str> = text.lines().filter_map(|l| l.split(' ').next()).collect();
    assert_eq!(got, names, "{text}");
    for want in [
        format!("battery_v {} V", tm.battery_v),
        format!("battery_a {} A", tm.battery_a),
        format!("battery_wh {} Wh", tm.battery_wh),
        format!("load_w {} W", tm.load_w),
        format!("panels_w[0] {} W", tm.panels_w[0]),
        "channel_ma[3] 0 mA".to_owned(),
        format!("channel_ma[8] {} mA", tm.channel_ma[8]),
        format!("load_wh {} Wh", tm.load_wh),
        "channels_on 0x1f7 (COMM1, COMM2, ECU, PL12, PL13, PL14, PL15, SBAND)".to_owned(),
        "channels_shed 0x0 (none)".to_owned(),
        "protection 0x0 (none)".to_owned(),
    ] {
        assert!(text.lines().any(|l| l == want), "{want:?} in\n{text}");
    }
    // No Debug syntax: no braces, no bracketed lists.
    assert!(!text.contains('{') && !text.contains(" ["), "{text}");
}

#[test]
fn thresholds_get_and_set_and_reboot_keeps_the_physics() {
    let cfg = EpsConfig {
        initial_soc: 0.25,
        ..EpsConfig::default()
    };
    let (mut h, out) = host(EpsApp::new(cfg));
    assert_eq!(
        one_reply(&mut h, &[4], SimTime::from_secs(1)),
        vec![4, 1, 30, 40, 20, 30]
    );
    run_until(&mut h, SimTime::from_secs(2));
    // 25 %: the payload group went at the first tick.
    assert_eq!(h.app.eps().channels_on(), 0x00f);
    // Lower the thresholds: the payload group comes back at the next tick (25 >= 20).
    assert_eq!(
        one_reply(&mut h, &[5, 10, 20, 5, 10], SimTime::from_secs(2)),
        vec![5, 1]
    );
    assert_eq!(
        one_reply(&mut h, &[4], SimTime::from_secs(2)),
        vec![4, 1, 10, 20, 5, 10]
    );
    run_until(&mut h, SimTime::from_secs(3));
    assert_eq!(h.app.eps().channels_on(), 0x1ff);
    // Refused settings.
    assert_eq!(
        one_reply(&mut h, &[5, 20, 20, 5, 10], SimTime::from_secs(4)),
        vec![5, 0]
    );
    assert_eq!(
        one_reply(&mut h, &[5, 10, 20, 5], SimTime::from_secs(4)),
        vec![5, 0]
    );
    assert_eq!(h.app.refused(), 2);
    // Switch the PC off, then reboot through CSP port 4: battery and channels stay, the
    // thresholds return to the configuration, the energy counters restart.
    one_reply(&mut h, &[3, 3, 0], SimTime::from_secs(5));
    let soc = h.app.eps().soc();
    let magic = 0x8007_8007u32.to_be_bytes().to_vec();
    h.handle_packet(
        0,
        Packet::new(Header::new(GS, 4, 4, 41), magic),
        SimTime::from_secs(6),
    );
    assert_eq!(h.node.counters().reboots, 1);
    assert_eq!(h.app.eps().channels_on(), 0x1f7);
    assert!(h.app.eps().soc() < soc && h.app.eps().soc() > soc - 0.001);
    assert_eq!(h.app.eps().thresholds(), Thresholds::default());
    assert_eq!(h.app.eps().energy_since_boot_wh(), (0.0, 0.0));
    assert_eq!(h.app.refused(), 0);
    // The port is bound again and ticks go on at whole seconds; the default thresholds
    // shed the payload group again at the next tick.
    assert_eq!(
        one_reply(&mut h, &[4], SimTime::from_secs(6)),
        vec![4, 1, 30, 40, 20, 30]
    );
    run_until(&mut h, SimTime::from_secs(8));
    let s = samples(&out);
    assert_eq!(s.last().unwrap().0, SimTime::from_secs(8));
    assert_eq!(s.last().unwrap().4, 0x007);
}

#[test]
fn activities_draw_power_from_the_activity_board() {
    let act = ActivityBoard::new();
    let (mut h, out) = host(app().with_activity(act.clone()));
    act.set(Activity::SbandTx, SimTime::from_ns(2_500_000_000), true)
        .unwrap();
    act.set(Activity::SbandTx, SimTime::from_ns(4_000_000_000), false)
        .unwrap();
    act.set(Activity::ThrusterHeater, SimTime::from_ns(0), true)
        .unwrap();
    run_until(&mut h, SimTime::from_secs(5));
    let s = samples(&out);
    let base = 7.5 + 6.0;
    let want = [base, base, base + 4.5, base + 9.0, base];
    for (x, w) in s.iter().zip(want) {
        assert!((x.3 - w).abs() < 1e-9, "{x:?} want {w}");
    }
    // The ECU off: its heater costs nothing even if the board says on.
    one_reply(&mut h, &[3, 2, 0], SimTime::from_secs(5));
    run_until(&mut h, SimTime::from_secs(6));
    assert!((samples(&out)[5].3 - (7.5 - 0.3)).abs() < 1e-9);
}

#[test]
fn timeline_events_switch_fail_panels_and_set_the_charge() {
    let truth = TruthBoard::new();
    let cfg = EpsConfig {
        timeline: vec![
            TimedEpsEvent {
                at: SimTime::from_secs(3),
                event: EpsEvent::PanelFail(1),
            },
            TimedEpsEvent {
                at: SimTime::from_ms(1500),
                event: EpsEvent::Channel {
                    channel: Channel::Payload13,
                    on: false,
                },
            },
            TimedEpsEvent {
                at: SimTime::from_secs(4),
                event: EpsEvent::SetSoc(0.1),
            },
        ],
        ..EpsConfig::default()
    };
    let (mut h, out) = host(EpsApp::new(cfg).with_truth(truth.clone()));
    truth
        .publish(&snapshot(0, Vector3::x(), UnitQuaternion::identity(), 1.0))
        .unwrap();
    run_until(&mut h, SimTime::from_secs(5));
    let s = samples(&out);
    let wing = 1361.0 * 0.06 * 0.9 * 0.295;
    assert!((s[2].2 - s[3].2 - wing).abs() < 1e-9, "{s:?}");
    assert_eq!(
        switches(&out)[0],
        (
            SimTime::from_ms(1500),
            Channel::Payload13,
            false,
            SwitchCause::Timeline
        )
    );
    // 10 %: both groups shed at the tick after the event.
    assert_eq!(s[4].4, 0x003);
}

#[test]
fn malformed_requests_get_the_failure_reply() {
    for (req, want) in [
        (vec![], vec![0, 0]),
        (vec![0], vec![0, 0]),
        (vec![6], vec![6, 0]),
        (vec![255, 1, 2], vec![255, 0]),
        (vec![1, 0], vec![1, 0]),
        (vec![2, 9], vec![2, 0]),
        (vec![3, 9, 1], vec![3, 0]),
        (vec![3, 0, 7], vec![3, 0]),
        (vec![3, 0], vec![3, 0]),
        (vec![4, 4], vec![4, 0]),
        (vec![5, 1, 2, 3], vec![5, 0]),
    ] {
        let (mut h, _) = host(app());
        assert_eq!(
            one_reply(&mut h, &req, SimTime::from_secs(1)),
            want,
            "{req:?}"
        );
        assert_eq!(h.app.refused(), 1);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Random requests never panic and always get exactly one reply, failure replies
    /// without data; the physics stays in bounds.
    #[test]
    fn random_requests_get_one_reply(
        reqs in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..12), 0u64..3000), 1..30),
    ) {
        let (mut h, _) = host(app());
        let mut t = SimTime::ZERO;
        for (req, dt_ms) in reqs {
            t = t + Duration::from_millis(dt_ms);
            let r = request(&mut h, &req, t);
            prop_assert_eq!(r.len(), 1);
            let r = &r[0];
            prop_assert_eq!(r[0], req.first().copied().unwrap_or(0));
            prop_assert!(r[1] <= 1);
            if r[1] == 0 {
                prop_assert_eq!(r.len(), 2);
            }
            let soc = h.app.eps().soc();
            prop_assert!((0.0..=1.0).contains(&soc));
        }
    }
}

/// Energy over one orbit of the pure core, 1 s steps, with a truth generator.
fn orbit_energy(
    mut truth_at: impl FnMut(f64) -> TruthSnapshot,
    period_s: u64,
    cfg: &EpsConfig,
) -> (f64, f64, f64) {
    let mut eps = Eps::new(cfg);
    let mut solar_j = 0.0;
    let mut load_j = 0.0;
    for k in 0..period_s {
        let s = truth_at(k as f64);
        let x = EpsInputs::from_truth(Some(&s), Duties::default());
        let st = eps.step(1_000_000_000, &x);
        solar_j += st.solar_w;
        load_j += st.loads.total_w();
    }
    let p = period_s as f64;
    (solar_j / p, load_j / p, eps.soc())
}

/// The sun fixed along ECI +X; eclipse for the last 40 % of the orbit.
fn synthetic(k: f64, period: f64, q: UnitQuaternion<f64>) -> TruthSnapshot {
    TruthSnapshot {
        q_eci_from_body: q,
        sun_eci_unit: Vector3::x(),
        in_eclipse_fraction_visible: if k < 0.6 * period { 1.0 } else { 0.0 },
        ..TruthSnapshot::default()
    }
}

#[test]
fn sun_pointing_yields_more_orbit_energy_than_a_nadir_like_attitude() {
    let period = 5700u64;
    let p = period as f64;
    let cfg = EpsConfig {
        initial_soc: 0.6,
        ..EpsConfig::default()
    };
    // Sun max power: body +X on the sun all orbit.
    let (sun_w, load_w, sun_soc) = orbit_energy(
        |k| synthetic(k, p, UnitQuaternion::identity()),
        period,
        &cfg,
    );
    // Nadir-like: the body turns once per orbit about its Y axis (orbit normal along body
    // Y, beta 0): the sun sweeps the X-Z plane of the body.
    let (nadir_w, _, nadir_soc) = orbit_energy(
        |k| {
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 2.0 * PI * k / p);
            synthetic(k, p, q)
        },
        period,
        &cfg,
    );
    let full = 1361.0 * (0.03 * 0.85 + 0.12 * 0.9) * 0.295;
    assert!((sun_w - 0.6 * full).abs() < 0.01, "{sun_w}");
    assert!(sun_w > 2.0 * nadir_w, "sun {sun_w} W, nadir {nadir_w} W");
    assert!(sun_soc > nadir_soc);
    assert!(sun_w > load_w);
}

/// The attitude whose body axes are the orthonormal `x`, `y`, `z` (in ECI).
fn rotation(x: Vector3<f64>, y: Vector3<f64>, z: Vector3<f64>) -> UnitQuaternion<f64> {
    let m = nalgebra::Matrix3::from_columns(&[x, y, z]);
    UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(m))
}

/// A circular 520 km SSO in nadir pointing (body = LVLH): the sun at `beta` above the orbit
/// plane, the orbit angle `u` from the subsolar point; the shadow is the cylinder behind
/// the Earth.
fn sso(k: f64, period: f64, beta: f64, nadir: bool) -> TruthSnapshot {
    let u = 2.0 * PI * k / period;
    // Orbit frame: x towards the sun's projection, z the orbit normal.
    let r_hat = Vector3::new(u.cos(), u.sin(), 0.0);
    let v_hat = Vector3::new(-u.sin(), u.cos(), 0.0);
    let h_hat = Vector3::z();
    let sun = Vector3::new(beta.cos(), 0.0, beta.sin());
    let r = 6378.137e3 + 520e3;
    let along = r_hat.dot(&sun) * r;
    let perp = (r * r - along * along).max(0.0).sqrt();
    let visible = if along < 0.0 && perp < 6378.137e3 {
        0.0
    } else {
        1.0
    };
    // LVLH: z to the Earth's centre, y opposite h, x completes (along v).
    let (z, y) = (-r_hat, -h_hat);
    let x = y.cross(&z);
    let q_lvlh = rotation(x, y, z);
    assert!((q_lvlh * Vector3::x() - v_hat).norm() < 1e-9);
    let q = if nadir {
        q_lvlh
    } else {
        // Sun max power: +X on the sun, +Z as close to nadir as possible.
        // (Near the subsolar and antisolar points nadir is along the sun: the orbit normal
        // replaces it as the secondary.)
        let xs = sun;
        let ys = xs
            .cross(&-r_hat)
            .try_normalize(1e-3)
            .unwrap_or_else(|| xs.cross(&-h_hat).normalize());
        let zs = xs.cross(&ys);
        rotation(xs, ys, zs)
    };
    TruthSnapshot {
        q_eci_from_body: q,
        sun_eci_unit: sun,
        in_eclipse_fraction_visible: visible,
        ..TruthSnapshot::default()
    }
}

#[test]
fn default_6u_in_a_520_km_sso_has_a_positive_balance_in_nadir() {
    // Period of a 520 km circular orbit: 2 pi sqrt(a^3 / mu) = 5696 s.
    let period = 5696u64;
    let p = period as f64;
    let cfg = EpsConfig {
        initial_soc: 0.6,
        ..EpsConfig::default()
    };
    let mut figures = Vec::new();
    for beta_deg in [0.0f64, 20.0, 40.0] {
        let beta = beta_deg.to_radians();
        let (nadir_w, load_w, nadir_soc) = orbit_energy(|k| sso(k, p, beta, true), period, &cfg);
        let (sun_w, _, sun_soc) = orbit_energy(|k| sso(k, p, beta, false), period, &cfg);
        figures.push(format!(
            "beta {beta_deg:>4.0} deg: nadir {nadir_w:5.1} W, sun max power {sun_w:5.1} W, load {load_w:4.1} W; soc after one orbit from 60 %: nadir {:.1} %, sun {:.1} %",
            nadir_soc * 100.0,
            sun_soc * 100.0
        ));
        assert!(
            nadir_w > load_w / 0.93 / 0.95 + 1.0,
            "beta {beta_deg}: {nadir_w} W"
        );
        assert!(nadir_soc > 0.6, "beta {beta_deg}");
        assert!(
            sun_w > 1.4 * nadir_w,
            "beta {beta_deg}: {sun_w} vs {nadir_w}"
        );
        assert!(sun_soc > nadir_soc);
    }
    println!("{}", figures.join("\n"));
}

/// Send `req` to the platform port (14) at `t`; the one reply's data.
fn platform(h: &mut Host<Tap<EpsApp>>, req: &[u8], t: SimTime) -> Vec<u8> {
    run_until(h, t);
    h.handle_packet(
        0,
        Packet::new(Header::new(GS, 4, csp::params::PORT, 41), req.to_vec()),
        t,
    );
    let out: Vec<Packet> = std::iter::from_fn(|| h.node.poll_transmit())
        .filter_map(|x| match x {
            Transmit::Packet { packet, .. } => Some(packet),
            Transmit::Can { .. } => None,
        })
        .collect();
    assert_eq!(out.len(), 1, "exactly one reply to {req:?}");
    assert_eq!(out[0].header, Header::new(4, GS, 41, csp::params::PORT));
    out[0].data.clone()
}

#[test]
fn platform_parameters_are_the_thrset_thresholds_and_revert_at_reboot_unless_saved() {
    let (mut h, _) = host(app());
    let s = SimTime::from_secs;
    // PGET: id 1, type u8, 30 %.
    assert_eq!(platform(&mut h, &[1, 1], s(1)), [1, 1, 1, 1, 30]);
    // PSET payload shed 25 %: THRGET agrees.
    assert_eq!(platform(&mut h, &[2, 1, 25], s(1)), [2, 1, 1, 1, 25]);
    assert_eq!(one_reply(&mut h, &[4], s(1)), [4, 1, 25, 40, 20, 30]);
    // THRSET: PGET agrees.
    assert_eq!(one_reply(&mut h, &[5, 28, 40, 15, 30], s(2)), [5, 1]);
    assert_eq!(platform(&mut h, &[1, 1], s(2)), [1, 1, 1, 1, 28]);
    assert_eq!(platform(&mut h, &[1, 3], s(2)), [1, 1, 3, 1, 15]);
    // Out of range (max 99), and THRSET's rule (shed below restore 40): refused, unchanged.
    assert_eq!(platform(&mut h, &[2, 1, 100], s(2)), [2, 0]);
    assert_eq!(platform(&mut h, &[2, 1, 40], s(2)), [2, 0]);
    assert_eq!(platform(&mut h, &[2, 4, 15], s(2)), [2, 0]);
    assert_eq!(platform(&mut h, &[2, 1, 25, 0], s(2)), [2, 0], "wrong size");
    assert_eq!(one_reply(&mut h, &[4], s(2)), [4, 1, 28, 40, 15, 30]);
    // The charge limit, f32.
    let mut set = vec![2, 5];
    set.extend_from_slice(&20.0f32.to_le_bytes());
    let mut echo = vec![2, 1, 5, 5];
    echo.extend_from_slice(&20.0f32.to_le_bytes());
    assert_eq!(platform(&mut h, &set, s(3)), echo);
    assert_eq!(h.app.eps().battery().config().max_charge_w, 20.0);
    // A reboot without PSAVE: the factory table again.
    h.reboot(s(4));
    assert_eq!(one_reply(&mut h, &[4], s(4)), [4, 1, 30, 40, 20, 30]);
    assert_eq!(h.app.eps().battery().config().max_charge_w, 40.0);
    // Raised thresholds, saved; then changed again (crossing the saved ones) and not saved:
    // the boot restores the saved table whole.
    assert_eq!(platform(&mut h, &[2, 2, 60], s(5)), [2, 1, 2, 1, 60]);
    assert_eq!(platform(&mut h, &[2, 1, 50], s(5)), [2, 1, 1, 1, 50]);
    assert_eq!(platform(&mut h, &[5], s(5)), [5, 1]);
    assert_eq!(one_reply(&mut h, &[5, 10, 20, 5, 10], s(6)), [5, 1]);
    h.reboot(s(7));
    assert_eq!(h.node.counters().reboots, 2);
    assert_eq!(one_reply(&mut h, &[4], s(7)), [4, 1, 50, 60, 20, 30]);
    assert_eq!(platform(&mut h, &[1, 1], s(7)), [1, 1, 1, 1, 50]);
    // Their effect: at 80 % nothing is shed; raise both payload thresholds above it and the
    // next tick sheds the payload group.
    assert_eq!(h.app.eps().channels_on(), 0x1ff);
    assert_eq!(platform(&mut h, &[2, 2, 95], s(8)), [2, 1, 2, 1, 95]);
    assert_eq!(platform(&mut h, &[2, 1, 90], s(8)), [2, 1, 1, 1, 90]);
    run_until(&mut h, s(9));
    assert_eq!(h.app.eps().channels_on(), 0x00f);
    // PDEFAULTS: the factory table, running and saved.
    assert_eq!(platform(&mut h, &[6], s(10)), [6, 1]);
    assert_eq!(one_reply(&mut h, &[4], s(10)), [4, 1, 30, 40, 20, 30]);
}

#[test]
fn selftest_reports_battery_arrays_and_each_channel() {
    let s = SimTime::from_secs;
    let activity = ActivityBoard::new();
    let cfg = EpsConfig {
        timeline: vec![TimedEpsEvent {
            at: s(1),
            event: EpsEvent::PanelFail(0),
        }],
        ..EpsConfig::default()
    };
    let (mut h, _) = host(EpsApp::new(cfg).with_activity(activity.clone()));
    one_reply(&mut h, &[3, 3, 0], s(1)); // PC off
    // A power fault holds payload 12 off with its channel on.
    activity
        .set(Activity::PowerFault(12), SimTime::from_ms(1500), true)
        .unwrap();
    let r = platform(&mut h, &[7], s(2));
    assert_eq!(r[..2], [7, 1]);
    let count = usize::from(r[3]);
    assert_eq!(count, 3 + CHANNELS);
    assert_eq!(r.len(), 4 + 5 * count);
    let entry = |i: usize| {
        let at = 4 + 5 * i;
        (
            r[at],
            f32::from_le_bytes(r[at + 1..at + 5].try_into().unwrap()),
        )
    };
    // Battery 80 %, full capacity; no truth: no sun, no power; one panel failed.
    assert_eq!(entry(0).0, 0);
    assert!((entry(0).1 - 80.0).abs() < 0.01, "{:?}", entry(0));
    assert_eq!(entry(1), (0, 77.0));
    assert_eq!(entry(2), (1, 0.0));
    // COMM1 on (0.5 W at about 8 V), the PC off (health 3), payload 12 held off (failed,
    // drawing half its 0.5 W over the last second).
    assert_eq!(entry(3).0, 0);
    assert!((entry(3).1 - 62.0).abs() < 3.0, "{:?}", entry(3));
    assert_eq!(entry(3 + 3), (3, 0.0));
    assert_eq!(entry(3 + 4).0, 2);
    assert!((entry(3 + 4).1 - entry(3).1 / 2.0).abs() < 0.5);
    assert_eq!(entry(3 + 5).0, 0);
    // Overall: the worst that is not merely off.
    assert_eq!(r[2], 2);
    let checks = h.app.checks(s(2));
    assert_eq!(checks.len(), count);
    assert_eq!(checks[2].name, "solar_array");
    assert_eq!(checks[3 + 8].name, "ch_sband");
}

/// ICD 4.1: a payload reads the EPS (TMEPS, CHGET, THRGET) but may not switch a channel or
/// move a threshold: the failure reply, nothing changed, a warning; a lab bench opens it.
#[test]
fn a_payload_reads_the_eps_but_may_not_switch_it() {
    let (mut h, out) = host(app());
    let t = SimTime::from_secs(2);
    let ask = |h: &mut Host<Tap<EpsApp>>, req: &[u8]| {
        run_until(h, t);
        h.handle_packet(0, Packet::new(Header::new(14, 4, 10, 40), req.to_vec()), t);
        match h.node.poll_transmit() {
            Some(Transmit::Packet { packet, .. }) => packet.data,
            _ => panic!("no reply"),
        }
    };
    assert_eq!(ask(&mut h, &[3, 3, 0]), [3, 0], "CHSET PC off");
    assert_eq!(ask(&mut h, &[5, 10, 20, 5, 15]), [5, 0], "THRSET");
    assert!(switches(&out).is_empty());
    assert_eq!(ask(&mut h, &[1]).len(), 2 + 88, "TMEPS");
    assert_eq!(ask(&mut h, &[2])[..2], [2, 1], "CHGET");
    assert!(
        h.node.recent_events().any(|e| e
            .to_string()
            .contains("payload 14 refused port 10 command 3")),
        "a warning"
    );
    // A lab bench: payload_access = "open".
    let (app, out) = Tap::new(app());
    let mut c = NodeConfig::new("EPS", 4);
    c.ifaces = vec![IfaceConfig::packet("p")];
    c.routes.set_default(Route::direct(0));
    c.payload_access = platform::addr::PayloadAccess::Open;
    let mut bench = Host::new(c, app, SimTime::ZERO);
    assert_eq!(ask(&mut bench, &[3, 3, 0])[..2], [3, 1]);
    assert_eq!(switches(&out).len(), 1);
}

/// A stuck switch ignores CHSET (a success reply whose channel states show it unchanged)
/// and the scenario's channel events, while the protection still sheds it; holds compose,
/// and once every hold is freed CHSET switches it again.
#[test]
fn a_stuck_channel_ignores_chset_until_it_is_freed() {
    let s = SimTime::from_secs;
    let pl12 = Channel::Payload12;
    let at = |t: SimTime, event: EpsEvent| TimedEpsEvent { at: t, event };
    let cfg = EpsConfig {
        timeline: vec![
            at(s(1), EpsEvent::ChannelStuck(pl12)),
            at(
                s(3),
                EpsEvent::Channel {
                    channel: pl12,
                    on: false,
                },
            ),
            at(s(5), EpsEvent::ChannelFreed(pl12)),
            // Stuck off, twice over; one hold freed.
            at(s(7), EpsEvent::ChannelStuck(pl12)),
            at(s(7), EpsEvent::ChannelStuck(pl12)),
            at(s(8), EpsEvent::ChannelFreed(pl12)),
            at(s(10), EpsEvent::ChannelFreed(pl12)),
            // Stuck on, and the battery low: the protection sheds it all the same.
            at(s(11), EpsEvent::ChannelStuck(pl12)),
            at(s(12), EpsEvent::SetSoc(0.1)),
        ],
        ..EpsConfig::default()
    };
    let (mut h, out) = host(EpsApp::new(cfg));
    let on = |r: &[u8]| u16_at(r, 2) & pl12.bit() != 0;

    // CHSET PL12 off: success, the channel states show it on; nothing switches.
    let r = one_reply(&mut h, &[3, 4, 0], s(2));
    assert_eq!(r[..2], [3, 1]);
    assert!(on(&r), "{r:?}");
    assert!(h.app.is_stuck(pl12));
    assert!(
        h.node.recent_events().any(|e| e
            .to_string()
            .contains("channel PL12 stuck on: switching it off (Command) had no effect")),
        "a warning"
    );
    // The scenario's event at 3 s neither.
    let r = one_reply(&mut h, &[2], s(4));
    assert!(on(&r), "CHGET {r:?}");
    assert!(switches(&out).is_empty(), "{:?}", switches(&out));
    assert_eq!(h.app.eps().channels_on() & pl12.bit(), pl12.bit());

    // Freed: CHSET switches it.
    let r = one_reply(&mut h, &[3, 4, 0], s(6));
    assert!(!h.app.is_stuck(pl12));
    assert!(!on(&r), "{r:?}");
    assert_eq!(
        switches(&out),
        vec![(s(6), pl12, false, SwitchCause::Command)]
    );

    // Two holds, one freed: still stuck (off).
    let r = one_reply(&mut h, &[3, 4, 1], s(9));
    assert_eq!(r[..2], [3, 1]);
    assert!(!on(&r) && h.app.is_stuck(pl12), "{r:?}");
    // Both freed.
    let r = one_reply(&mut h, &[3, 4, 1], s(10) + Duration::from_millis(500));
    assert!(on(&r), "{r:?}");
    assert_eq!(switches(&out).len(), 2);

    // Stuck on at 11 s, 10 % at 12 s: shed at the tick (12 s, after the event) with its
    // group.
    run_until(&mut h, s(13));
    assert!(h.app.is_stuck(pl12));
    assert_eq!(
        switches(&out).get(2),
        Some(&(s(12), pl12, false, SwitchCause::Shed(Group::Payload))),
        "{:?}",
        switches(&out)
    );
    assert_eq!(h.app.eps().channels_on() & pl12.bit(), 0);
    // The group shed, a CHSET on is refused before the switch is driven, as it is for a
    // working one.
    assert_eq!(one_reply(&mut h, &[3, 4, 1], s(14)), [3, 0]);
}

/// The EPS saved mid-run (part-drained in the dark, a channel switched off by command) and
/// loaded into a host built from another configuration goes on as the original: the same
/// samples and switches, to the bit, and the configuration is the saved one.
#[test]
fn an_eps_saved_mid_run_and_loaded_into_a_fresh_one_goes_on_the_same() {
    let cfg = EpsConfig {
        initial_soc: 0.31,
        ..EpsConfig::default()
    };
    let (mut a, out_a) = host(EpsApp::new(cfg));
    let reply = request(
        &mut a,
        &[3, Channel::Payload13 as u8, 0],
        SimTime::from_secs(100),
    );
    assert_eq!(reply.len(), 1, "{reply:?}");
    run_until(&mut a, SimTime::from_secs(300));
    let bytes = snap::to_bytes(&a);
    let (mut b, out_b) = host(EpsApp::new(EpsConfig::default()));
    snap::load_from(&mut b, &bytes).unwrap();
    assert_eq!(snap::to_bytes(&b), bytes);
    out_b.lock().unwrap().clear();
    let n = out_a.lock().unwrap().len();
    for h in [&mut a, &mut b] {
        run_until(h, SimTime::from_secs(3000));
    }
    let after_a = format!("{:?}", &out_a.lock().unwrap()[n..]);
    let after_b = format!("{:?}", &*out_b.lock().unwrap());
    assert!(after_a.contains("Channel"), "shedding happened: {after_a}");
    assert_eq!(after_a, after_b);
    assert_eq!(snap::to_bytes(&a), snap::to_bytes(&b));
}
