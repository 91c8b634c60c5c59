//! The ECU on its node: ARM/FIRE/SAFE over port 10, refusals, the burns it posts for the FC,
//! the activities it posts for the EPS, propellant bookkeeping, reboots, and robustness.
#![allow(clippy::unwrap_used)]

use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
use csp::router::Route;
use csp::{Header, Packet, SimTime};
use m6p_nodes_ecu::wire::{ArmReply, FireReply, Repr, TmEcu};
use m6p_nodes_ecu::{EcuApp, EcuConfig, EcuOutput, EcuState};
use nalgebra::Vector3;
use platform::board::{Activity, ActivityBoard, BurnBoard};
use proptest::prelude::*;

const G0: f64 = 9.806_65;

struct Sim {
    host: Host<EcuApp>,
    burns: BurnBoard,
    activity: ActivityBoard,
    outputs: Arc<Mutex<Vec<EcuOutput>>>,
    now: SimTime,
}

impl Sim {
    fn new(cfg: EcuConfig) -> Self {
        let mut c = NodeConfig::new("ECU", 5);
        c.ifaces = vec![IfaceConfig::packet("p")];
        c.routes.set_default(Route::direct(0));
        let burns = BurnBoard::new();
        let activity = ActivityBoard::new();
        let outputs = Arc::new(Mutex::new(Vec::new()));
        let app = EcuApp::new(cfg)
            .with_burns(burns.clone())
            .with_activity(activity.clone());
        Sim {
            host: Host::new(c, app, SimTime::ZERO),
            burns,
            activity,
            outputs,
            now: SimTime::ZERO,
        }
    }

    /// Send a request to port 10 now and return the reply payload.
    fn ask(&mut self, req: &[u8]) -> Vec<u8> {
        self.ask_port(10, req).expect("a reply")
    }

    fn ask_port(&mut self, port: u8, req: &[u8]) -> Option<Vec<u8>> {
        self.host.handle_packet(
            0,
            Packet::new(Header::new(16, 5, port, 40), req.to_vec()),
            self.now,
        );
        self.drain();
        let Some(Transmit::Packet { packet, .. }) = self.host.node.poll_transmit() else {
            return None;
        };
        assert_eq!(packet.header, Header::new(5, 16, 40, port));
        assert!(
            self.host.node.poll_transmit().is_none(),
            "one reply per request"
        );
        Some(packet.data)
    }

    fn run_to(&mut self, t: SimTime) {
        while let Some(d) = self.host.poll_timeout().filter(|&d| d <= t) {
            self.host.handle_timeout(d);
        }
        self.drain();
        self.now = t;
    }

    /// Pull the ECU's events into `outputs`.
    fn drain(&mut self) {
        while let Some(o) = self.host.poll_event() {
            self.outputs.lock().unwrap().push(o);
        }
    }

    fn tm(&mut self) -> TmEcu {
        let r = self.ask(&[1]);
        assert_eq!(&r[..2], &[1, 1]);
        TmEcu::parse(&r[2..]).unwrap()
    }

    fn fire(&mut self, ms: u32) -> Vec<u8> {
        let mut req = vec![3];
        req.extend_from_slice(&ms.to_le_bytes());
        self.ask(&req)
    }

    fn arm_and_warm(&mut self) {
        let r = self.ask(&[2]);
        assert_eq!(&r[..2], &[2, 1]);
        let warm = ArmReply::parse(&r[2..]).unwrap().warmup_left_ms;
        self.run_to(self.now + Duration::from_millis(u64::from(warm)));
    }
}

fn fast() -> EcuConfig {
    EcuConfig {
        warmup: Duration::from_secs(5),
        ..EcuConfig::default()
    }
}

#[test]
fn command_layouts_and_sizes() {
    let mut s = Sim::new(fast());
    // TMECU: 1 | 1 | 42 bytes.
    let r = s.ask(&[1]);
    assert_eq!(r.len(), 2 + 42);
    // ARM: 2 | 1 | warm-up left u32 = 5000 ms.
    assert_eq!(s.ask(&[2]), vec![2, 1, 0x88, 0x13, 0, 0]);
    s.run_to(SimTime::from_secs(5));
    // FIRE 10 000 ms: 3 | 1 | granted u32 | thrust f32.
    let r = s.fire(10_000);
    assert_eq!(r.len(), 2 + 8);
    assert_eq!(&r[..6], &[3, 1, 0x10, 0x27, 0, 0]);
    assert_eq!(&r[6..], &0.3f32.to_le_bytes());
    // SAFE: 4 | 1, no data.
    assert_eq!(s.ask(&[4]), vec![4, 1]);
}

/// Decode TMECU by byte offsets, independently of `TmEcu::parse`.
#[test]
fn tmecu_decoded_by_offsets() {
    let mut s = Sim::new(fast());
    s.arm_and_warm();
    s.fire(20_000);
    s.now = SimTime::from_secs(15);
    let r = s.ask(&[1]);
    let u32_at = |o: usize| u32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]);
    let f32_at = |o: usize| f32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]);
    assert_eq!((r[0], r[1]), (1, 1));
    let d = 2;
    assert_eq!(r[d], 3, "state firing");
    assert_eq!(r[d + 1], 1, "heater on");
    assert_eq!(u32_at(d + 2), 0, "warm-up over");
    assert_eq!(u32_at(d + 6), 10_000, "10 s of the 20 s burn left");
    let mdot = 0.3 / (200.0 * G0);
    let prop = f64::from(f32_at(d + 10));
    assert!((prop - (0.5 - mdot * 10.0)).abs() < 1e-6, "{prop}");
    let p = f64::from(f32_at(d + 14));
    assert!(p < 2200.0 && p > 2000.0, "{p} kPa");
    assert_eq!(f32_at(d + 18), 0.3);
    assert!((f64::from(f32_at(d + 22)) - (12.0 + prop)).abs() < 1e-5);
    assert_eq!(f32_at(d + 26), 0.0, "total impulse counts finished burns");
    assert_eq!(u32_at(d + 30), 1, "burns");
    assert_eq!(u32_at(d + 34), 0, "last burn");
    assert_eq!(u32_at(d + 38), 0, "refused");
}

#[test]
fn refusals_fire_unarmed_warming_too_long_while_firing_empty() {
    let mut s = Sim::new(fast());
    assert_eq!(s.fire(1000), vec![3, 0], "unarmed");
    s.ask(&[2]);
    s.now = SimTime::from_secs(4);
    assert_eq!(s.fire(1000), vec![3, 0], "still warming");
    assert_eq!(s.tm().state, EcuState::Warming.to_u8());
    s.run_to(SimTime::from_secs(5));
    assert_eq!(s.tm().state, EcuState::Armed.to_u8());
    assert_eq!(s.fire(60_001), vec![3, 0], "longer than the maximum");
    assert_eq!(s.fire(0).as_slice(), &[3, 0], "zero duration");
    assert_eq!(&s.fire(60_000)[..2], &[3, 1], "the maximum itself");
    assert_eq!(s.fire(1000), vec![3, 0], "while firing");
    assert_eq!(s.tm().refused, 5);
    assert!(s.burns.all().len() == 1, "refusals post nothing");

    // An empty tank refuses.
    let mut e = Sim::new(EcuConfig {
        thruster: m6p_nodes_ecu::ThrusterConfig {
            propellant_kg: 0.0,
            ..Default::default()
        },
        ..fast()
    });
    e.arm_and_warm();
    assert_eq!(e.fire(1000), vec![3, 0], "no propellant");
    assert!(e.burns.all().is_empty());
}

#[test]
fn malformed_requests_get_failure_replies() {
    let table: Vec<(Vec<u8>, Vec<u8>)> = vec![
        (vec![], vec![0, 0]),
        (vec![0], vec![0, 0]),
        (vec![5], vec![5, 0]),
        (vec![255, 1, 2], vec![255, 0]),
        (vec![1, 0], vec![1, 0]),
        (vec![2, 0], vec![2, 0]),
        (vec![4, 0], vec![4, 0]),
        (vec![3], vec![3, 0]),
        (vec![3, 1, 0, 0], vec![3, 0]),
        (vec![3, 1, 0, 0, 0, 0], vec![3, 0]),
    ];
    for (req, want) in table {
        let mut s = Sim::new(fast());
        assert_eq!(s.ask(&req), want, "{req:02x?}");
        assert_eq!(s.tm().refused, 1);
        assert_eq!(s.tm().state, 0, "nothing changed");
    }
}

#[test]
fn a_fire_posts_the_right_burn_and_activities() {
    let mut s = Sim::new(fast());
    s.arm_and_warm();
    assert!(
        s.activity
            .on_before(Activity::ThrusterHeater, SimTime::from_ns(1))
    );
    s.now = SimTime::from_ms(7_250);
    let r = s.fire(10_000);
    assert_eq!(FireReply::parse(&r[2..]).unwrap().granted_ms, 10_000);
    let b = s.burns.all();
    assert_eq!(b.len(), 1);
    let b = b[0];
    assert_eq!(b.posted.as_ns(), 7_250_000_000);
    assert_eq!(b.start.as_ns(), 7_250_000_000);
    assert_eq!(b.end.as_ns(), 17_250_000_000);
    assert_eq!(b.thrust_n, 0.3);
    assert!((b.mass_flow_kg_s - 0.3 / (200.0 * G0)).abs() < 1e-15);
    assert_eq!(b.mass_kg, 12.5);
    assert_eq!(b.dir_body, Vector3::z());
    assert!(
        s.burns
            .pending(SimTime::from_ms(7_250), SimTime::ZERO)
            .is_empty(),
        "the FC takes it after"
    );
    assert!(
        s.activity
            .on_before(Activity::Firing, SimTime::from_ns(7_250_000_001))
    );
    // Firing exactly over [start, end): 10 s of the 20 s window.
    s.run_to(SimTime::from_secs(30));
    let duty = s.activity.duty(
        Activity::Firing,
        SimTime::from_ms(7_250),
        SimTime::from_ms(27_250),
    );
    assert!((duty - 0.5).abs() < 1e-12, "{duty}");
    let tm = s.tm();
    assert_eq!(
        tm.state,
        EcuState::Armed.to_u8(),
        "back to armed after the burn"
    );
    assert_eq!(tm.heater, 1);
    assert_eq!(tm.last_burn_ms, 10_000);
    assert!((f64::from(tm.total_impulse_n_s) - 3.0).abs() < 1e-6);
}

#[test]
fn safe_cuts_the_burn_and_keeps_when_it_was_posted() {
    let mut s = Sim::new(fast());
    s.arm_and_warm();
    s.now = SimTime::from_secs(10);
    s.fire(30_000);
    s.now = SimTime::from_ms(14_500);
    assert_eq!(s.ask(&[4]), vec![4, 1]);
    let b = s.burns.all();
    assert_eq!(b.len(), 1, "re-posted, not added");
    assert_eq!(b[0].end.as_ns(), 14_500_000_000);
    assert_eq!(b[0].posted.as_ns(), 10_000_000_000);
    let tm = s.tm();
    assert_eq!(tm.state, 0);
    assert_eq!(tm.heater, 0);
    assert_eq!(tm.last_burn_ms, 4_500);
    assert!(
        !s.activity
            .on_before(Activity::Firing, SimTime::from_ns(14_500_000_001))
    );
    assert!(
        !s.activity
            .on_before(Activity::ThrusterHeater, SimTime::from_ns(14_500_000_001))
    );
    assert!(
        s.activity
            .on_before(Activity::Firing, SimTime::from_ns(14_500_000_000))
    );
    // Nothing more happens at the planned end.
    s.run_to(SimTime::from_secs(60));
    assert_eq!(s.burns.all()[0].end.as_ns(), 14_500_000_000);
    let ended: Vec<_> = s
        .outputs
        .lock()
        .unwrap()
        .iter()
        .filter_map(|o| match o {
            EcuOutput::BurnEnded { t, cut, .. } => Some((*t, *cut)),
            _ => None,
        })
        .collect();
    assert_eq!(ended, vec![(SimTime::from_ms(14_500), true)]);
}

#[test]
fn propellant_bookkeeping_over_many_burns_and_the_blow_down() {
    let mut s = Sim::new(fast());
    s.arm_and_warm();
    let mut expected = 0.5f64;
    let mut impulse = 0.0;
    let mut last_thrust = f64::INFINITY;
    for k in 0..20 {
        let r = s.fire(60_000);
        let rep = FireReply::parse(&r[2..]).unwrap();
        assert_eq!(rep.granted_ms, 60_000);
        let f = f64::from(rep.thrust_n);
        assert!(f < last_thrust, "burn {k}: thrust falls with the pressure");
        last_thrust = f;
        // The thrust of the tank's pressure now (Boyle, ratio 4).
        let x = (0.5 - expected) / 0.5;
        let want_f = 0.3 / (1.0 + 3.0 * x);
        assert!((f - want_f).abs() < 1e-6, "burn {k}: {f} vs {want_f}");
        s.run_to(s.now + Duration::from_secs(61));
        expected -= want_f / (200.0 * G0) * 60.0;
        impulse += want_f * 60.0;
        let tm = s.tm();
        assert!(
            (f64::from(tm.propellant_kg) - expected).abs() < 1e-6,
            "burn {k}: {} vs {expected}",
            tm.propellant_kg
        );
        assert!((f64::from(tm.total_impulse_n_s) - impulse).abs() < 1e-3);
        assert_eq!(tm.burns, k + 1);
    }
    // Total impulse is the exhaust velocity times the propellant used.
    assert!((impulse - (0.5 - expected) * 200.0 * G0).abs() < 1e-6);
}

#[test]
fn the_last_propellant_shortens_the_burn() {
    let cfg = EcuConfig {
        thruster: m6p_nodes_ecu::ThrusterConfig {
            propellant_kg: 0.002,
            blowdown_ratio: 1.0,
            ..Default::default()
        },
        ..fast()
    };
    let mut s = Sim::new(cfg);
    s.arm_and_warm();
    let r = s.fire(60_000);
    // 2 g at 1.5296e-4 kg/s lasts 13.075 s.
    let granted = FireReply::parse(&r[2..]).unwrap().granted_ms;
    assert_eq!(granted, 13_075);
    s.run_to(s.now + Duration::from_secs(20));
    let tm = s.tm();
    assert!(
        tm.propellant_kg >= 0.0 && tm.propellant_kg < 2e-7,
        "{}",
        tm.propellant_kg
    );
    assert_eq!(s.fire(1000), vec![3, 0], "now empty");
}

#[test]
fn power_loss_mid_burn_stops_it_at_that_instant_and_comes_back_safe() {
    let mut s = Sim::new(fast());
    s.arm_and_warm();
    s.now = SimTime::from_secs(10);
    s.fire(30_000);
    // Power goes at 12 s (the node's task calls the power-loss hook at that instant) and
    // comes back at 100 s (the node boots).
    s.host.power_lost(SimTime::from_secs(12));
    s.host.reboot(SimTime::from_secs(100));
    s.now = SimTime::from_secs(100);
    let tm = s.tm();
    assert_eq!(tm.state, 0);
    assert_eq!(tm.heater, 0);
    assert_eq!(tm.burns, 1, "survives");
    assert_eq!(tm.last_burn_ms, 2_000, "charged to the cut");
    let mdot = 0.3 / (200.0 * G0);
    assert!((f64::from(tm.propellant_kg) - (0.5 - 2.0 * mdot)).abs() < 1e-7);
    assert!((f64::from(tm.total_impulse_n_s) - 0.6).abs() < 1e-6);
    assert_eq!(s.burns.all()[0].end.as_ns(), 12_000_000_000);
    assert!(
        !s.activity
            .on_before(Activity::Firing, SimTime::from_ns(12_000_000_001))
    );
    assert!(
        !s.activity
            .on_before(Activity::ThrusterHeater, SimTime::from_ns(12_000_000_001))
    );
    assert_eq!(s.fire(1000), vec![3, 0], "safe after boot");
    assert!(s.host.poll_timeout().is_none(), "no timer left");

    // A software reboot while firing cuts the burn at the reboot.
    let mut r = Sim::new(fast());
    r.arm_and_warm();
    r.now = SimTime::from_secs(10);
    r.fire(30_000);
    r.host.reboot(SimTime::from_secs(13));
    r.now = SimTime::from_secs(13);
    assert_eq!(r.burns.all()[0].end.as_ns(), 13_000_000_000);
    assert_eq!(r.tm().last_burn_ms, 3_000);
}

#[test]
fn arm_is_idempotent_and_safe_always_succeeds() {
    let mut s = Sim::new(fast());
    assert_eq!(s.ask(&[4]), vec![4, 1], "SAFE when safe");
    s.ask(&[2]);
    s.now = SimTime::from_secs(3);
    let r = s.ask(&[2]);
    assert_eq!(
        ArmReply::parse(&r[2..]).unwrap().warmup_left_ms,
        2_000,
        "the warm-up is not restarted"
    );
    let armed = s
        .outputs
        .lock()
        .unwrap()
        .iter()
        .filter(|o| matches!(o, EcuOutput::Armed { .. }))
        .count();
    assert_eq!(armed, 1);
}

#[test]
fn invalid_config_falls_back_to_the_default() {
    let cfg = EcuConfig {
        thruster: m6p_nodes_ecu::ThrusterConfig {
            isp_s: f64::NAN,
            ..Default::default()
        },
        ..EcuConfig::default()
    };
    assert!(cfg.validate().is_err());
    let app = EcuApp::new(cfg);
    assert_eq!(app.config(), &EcuConfig::default());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Any sequence of requests (valid or not) at any times, with reboots: never a panic,
    /// exactly one reply per request on port 10, propellant never negative or rising, and
    /// at most one burn in progress.
    #[test]
    fn random_requests_never_panic(
        steps in proptest::collection::vec(
            (prop_oneof![
                Just(vec![1u8]), Just(vec![2u8]), Just(vec![4u8]),
                (0u32..70_000).prop_map(|d| { let mut v = vec![3u8]; v.extend(d.to_le_bytes()); v }),
                proptest::collection::vec(any::<u8>(), 0..12),
            ], 0u64..20_000, 0u8..20),
            1..40),
    ) {
        let mut s = Sim::new(fast());
        let mut last_prop = 0.5f32;
        for (req, dt_ms, what) in steps {
            let t = s.now + Duration::from_millis(dt_ms);
            s.run_to(t);
            if what == 0 {
                s.host.reboot(t);
            }
            let r = s.ask(&req);
            prop_assert!(r.len() >= 2);
            prop_assert_eq!(r[0], req.first().copied().unwrap_or(0));
            let tm = s.tm();
            prop_assert!(tm.propellant_kg >= 0.0 && tm.propellant_kg <= last_prop);
            last_prop = tm.propellant_kg;
            let now_ns = s.now.as_ns();
            let running = s.burns.all().iter()
                .filter(|b| b.start.as_ns() <= now_ns && b.end.as_ns() > now_ns).count();
            prop_assert!(running <= 1);
        }
    }
}

/// The ECU saved in the middle of a burn (armed, firing, propellant part-spent) and loaded
/// into one built from another configuration ends the burn as the original: the same
/// outputs, telemetry and propellant, to the bit.
#[test]
fn an_ecu_saved_mid_burn_and_loaded_into_a_fresh_one_ends_it_the_same() {
    let mut a = Sim::new(fast());
    a.arm_and_warm();
    let r = a.fire(4_000);
    assert_eq!(&r[..2], &[3, 1], "{r:?}");
    a.run_to(a.now + Duration::from_millis(1_500));
    let bytes = snap::to_bytes(&a.host);
    let mut b = Sim::new(EcuConfig::default());
    snap::load_from(&mut b.host, &bytes).unwrap();
    assert_eq!(snap::to_bytes(&b.host), bytes);
    b.now = a.now;
    b.outputs.lock().unwrap().clear();
    let n = a.outputs.lock().unwrap().len();
    let end = a.now + Duration::from_secs(10);
    a.run_to(end);
    b.run_to(end);
    assert_eq!(
        format!("{:?}", &a.outputs.lock().unwrap()[n..]),
        format!("{:?}", &*b.outputs.lock().unwrap())
    );
    assert_eq!(format!("{:?}", a.tm()), format!("{:?}", b.tm()));
    assert_eq!(snap::to_bytes(&a.host), snap::to_bytes(&b.host));
}
