//! CommApp driven through a `Host`: beacons, port 10, link state, the radio switch.

#![allow(clippy::unwrap_used)]

use super::*;
use csp::Header;
use csp::node::{Host, IfaceConfig, NodeConfig, SwitchPosition, Transmit};
use csp::router::Route;
use nalgebra::{UnitQuaternion, Vector3};
use orbit::frames::a_ecef_from_eci;
use orbit::geodetic::a_enu_from_ecef;
use orbit::time::UtcTime;
use proptest::prelude::*;

/// 2025-06-21T12:00:00Z.
const EPOCH_UNIX_S: u64 = 1_750_507_200;
/// Beacon air time: (4 + 173) bytes x 8 / 9600 bit/s = 147.5 ms.
const BEACON_AIR: Duration = Duration::from_micros(147_500);

/// COMM1 as the twin builds it: main CAN (iface 0, default) and the UHF radio (iface 1,
/// ground 16-20).
fn host_with(app: CommApp, addr: u8) -> Host<CommApp> {
    let mut c = NodeConfig::new(if addr == 1 { "COMM1" } else { "COMM2" }, addr);
    c.ifaces = vec![IfaceConfig::can("main-can"), IfaceConfig::packet("uhf")];
    c.routes
        .set_default(Route::direct(0))
        .set_range(16..=20, Route::direct(1));
    c.epoch_unix_s = EPOCH_UNIX_S;
    Host::new(c, app, SimTime::ZERO)
}

fn host(cfg: CommConfig) -> Host<CommApp> {
    let addr = if cfg.role == CommRole::Primary { 1 } else { 2 };
    host_with(CommApp::new(cfg), addr)
}

/// Packets the node put on the UHF interface.
fn uhf_out(h: &mut Host<CommApp>) -> Vec<Packet> {
    std::iter::from_fn(|| h.node.poll_transmit())
        .filter_map(|t| match t {
            Transmit::Packet { iface: 1, packet } => Some(packet),
            _ => None,
        })
        .collect()
}

/// Run the host's timers up to `until`; the beacons sent, with their times.
fn drive(h: &mut Host<CommApp>, until: SimTime) -> Vec<(SimTime, Packet)> {
    let mut out = Vec::new();
    while let Some(t) = h.poll_timeout().filter(|&t| t <= until) {
        h.handle_timeout(t);
        out.extend(uhf_out(h).into_iter().map(|p| (t, p)));
    }
    out
}

/// Send `req` from the ground (16, port 40) to COMM port 10 at `t`; the one reply's data.
fn request(h: &mut Host<CommApp>, req: &[u8], t: SimTime) -> Vec<u8> {
    let addr = h.node.addr();
    h.handle_packet(
        1,
        Packet::new(Header::new(16, addr, 10, 40), req.to_vec()),
        t,
    );
    let out = uhf_out(h);
    assert_eq!(out.len(), 1, "exactly one reply to {req:?}");
    assert_eq!(out[0].header, Header::new(addr, 16, 40, 10));
    out[0].data.clone()
}

fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
fn le_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes(b[at..at + 2].try_into().unwrap())
}
fn le_f32(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

/// A truth snapshot at t = 0 with the satellite seen from Vilnius at the given look angles.
fn truth_seen_from_vilnius(el_deg: f64, az_deg: f64, range_km: f64) -> TruthSnapshot {
    let st = Station::vilnius();
    let site = st.site();
    let (el, az) = (el_deg.to_radians(), az_deg.to_radians());
    let enu = Vector3::new(el.cos() * az.sin(), el.cos() * az.cos(), el.sin()) * range_km;
    let a_enu = a_enu_from_ecef(st.lat_deg.to_radians(), st.lon_deg.to_radians());
    let r_ecef_km = site.r_ecef_km() + a_enu.transpose() * enu;
    let unix_ns = EPOCH_UNIX_S as i64 * 1_000_000_000;
    let a = a_ecef_from_eci(UtcTime::from_unix_ns(unix_ns), None);
    TruthSnapshot {
        t: SimTime::ZERO,
        unix_ns,
        r_eci_m: a.transpose() * r_ecef_km * 1e3,
        v_eci_m_s: Vector3::new(0.0, 7600.0, 0.0),
        q_eci_from_body: UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        w_body_rad_s: Vector3::new(0.01, 0.0, -0.02),
        sun_eci_unit: Vector3::x(),
        in_eclipse_fraction_visible: 0.5,
        b_eci_nt: Vector3::new(20_000.0, 0.0, -40_000.0),
        wheel_speed_rad_s: [100.0, -100.0, 0.0, 50.0],
        mtq_dipole_am2: [0.1, 0.0, -0.1],
    }
}

fn board_with(t: &TruthSnapshot) -> TruthBoard {
    let b = TruthBoard::new();
    b.publish(t).unwrap();
    b
}

fn tmcomm(h: &mut Host<CommApp>, t: SimTime) -> TmComm {
    let r = request(h, &[wire::cmd::TMCOMM], t);
    assert_eq!(&r[..2], &[1, 1]);
    TmComm::parse(&r[2..]).unwrap()
}

#[test]
fn beacons_every_period_to_ground_station_16_port_10() {
    let mut h = host(CommConfig::default());
    let beacons = drive(&mut h, SimTime::from_secs(600));
    assert_eq!(beacons.len(), 10);
    for (k, (t, p)) in beacons.iter().enumerate() {
        let k = k as u32 + 1;
        assert_eq!(*t, SimTime::from_secs(60 * u64::from(k)));
        // Unsolicited: from COMM's own port, so an answer is never taken for a request.
        assert_eq!(p.header, Header::new(1, 16, 10, h.node.own_port()));
        assert_eq!(p.data.len(), 173);
        assert_eq!(&p.data[..2], &[4, 1], "an unsolicited BEACON 4 reply");
        let b = &p.data[2..];
        assert_eq!(le_u32(b, 0), k, "sequence");
        assert_eq!(le_u32(b, 4), EPOCH_UNIX_S as u32 + 60 * k, "UTC");
        assert_eq!(le_u32(b, 8), 60 * k, "uptime");
        assert_eq!(b[12], 0, "no truth: flags clear");
        assert_eq!(b[134], wire::NO_STATION);
        assert_eq!(le_u16(b, 169), 60);
    }
    assert_eq!(h.app.counters().beacons_sent, 10);
    assert_eq!(h.app.next_beacon(), Some(SimTime::from_secs(660)));
}

/// The console's `tm` is TMCOMM of the same instant, one `name value unit` line per field
/// with the ICD's names, units and value names.
#[test]
fn console_tm_is_tmcomm_one_field_a_line() {
    let mut h = host(CommConfig::default());
    let t = SimTime::from_secs(600);
    drive(&mut h, t);
    let text = h.console("tm", t);
    let tm = tmcomm(&mut h, t);
    let fields = <TmComm as csp::icd::Describe>::FIELDS;
    let names: Vec<&str> = fields.iter().map(|f| f.name).collect();
    let got: Vec<&str> = text.lines().filter_map(|l| l.split(' ').next()).collect();
    assert_eq!(got, names, "{text}");
    for want in [
        "role 1 (primary)".to_owned(),
        "radio_active 1 (active)".to_owned(),
        "station 255".to_owned(),
        "uptime_s 600 s".to_owned(),
        "beacons_sent 10".to_owned(),
        "beacon_period_s 60 s".to_owned(),
        format!("beacon_air_ms {} ms", tm.beacon_air_ms),
        format!("rssi_dbm {} dBm", tm.rssi_dbm),
        "elevation_deg 0 deg".to_owned(),
    ] {
        assert!(text.lines().any(|l| l == want), "{want:?} in\n{text}");
    }
}

#[test]
fn beaconset_changes_the_period_and_zero_stops_them() {
    let mut h = host(CommConfig::default());
    let mut times = Vec::new();
    let mut run = |h: &mut Host<CommApp>, s: u64| {
        times.extend(
            drive(h, SimTime::from_secs(s))
                .into_iter()
                .map(|(t, _)| t.as_secs()),
        )
    };
    run(&mut h, 125);
    assert_eq!(
        request(&mut h, &[2, 30, 0], SimTime::from_secs(125)),
        vec![2, 1]
    );
    run(&mut h, 230);
    assert_eq!(
        request(&mut h, &[3], SimTime::from_secs(230)),
        vec![3, 1, 30, 0]
    );
    assert_eq!(
        request(&mut h, &[2, 0, 0], SimTime::from_secs(231)),
        vec![2, 1]
    );
    assert_eq!(h.poll_timeout(), None);
    run(&mut h, 3600);
    assert_eq!(times, vec![60, 120, 155, 185, 215]);
    assert_eq!(
        request(&mut h, &[3], SimTime::from_secs(3600)),
        vec![3, 1, 0, 0]
    );
    // Out of range: refused, the period stays off.
    assert_eq!(
        request(&mut h, &[2, 9, 0], SimTime::from_secs(3601)),
        vec![2, 0]
    );
    assert_eq!(
        request(&mut h, &[3], SimTime::from_secs(3602)),
        vec![3, 1, 0, 0]
    );
    // Back on: the schedule starts from the command.
    assert_eq!(
        request(&mut h, &[2, 10, 0], SimTime::from_secs(4000)),
        vec![2, 1]
    );
    let more: Vec<_> = drive(&mut h, SimTime::from_secs(4030))
        .into_iter()
        .map(|(t, p)| (t.as_secs(), le_u32(&p.data[2..], 0)))
        .collect();
    assert_eq!(more, vec![(4010, 6), (4020, 7), (4030, 8)]);
}

#[test]
fn secondary_sends_no_beacon_until_set_active() {
    let mut h = host(CommConfig::secondary());
    assert!(drive(&mut h, SimTime::from_secs(600)).is_empty());
    let tm = tmcomm(&mut h, SimTime::from_secs(600));
    assert_eq!((tm.role, tm.radio_active, tm.beacons_sent), (2, 0, 0));
    assert_eq!(tm.beacon_period_s, 60, "the period is kept for a take-over");
    // The twin hands the radio route over at 600 s: beacons from 660 s, flagged secondary.
    h.app.set_active(true);
    let b = drive(&mut h, SimTime::from_secs(780));
    let times: Vec<_> = b.iter().map(|(t, _)| t.as_secs()).collect();
    assert_eq!(times, vec![660, 720, 780]);
    assert_eq!(b[0].1.header, Header::new(2, 16, 10, h.node.own_port()));
    assert_eq!(b[0].1.data[2 + 12], wire::BEACON_SECONDARY);
    assert_eq!(tmcomm(&mut h, SimTime::from_secs(781)).radio_active, 1);
    h.app.set_active(false);
    assert!(drive(&mut h, SimTime::from_secs(2000)).is_empty());
    // The flag is hardware state: a reboot keeps standby.
    h.reboot(SimTime::from_secs(2000));
    assert!(drive(&mut h, SimTime::from_secs(3000)).is_empty());
}

#[test]
fn link_overhead_vilnius_at_600_km() {
    let truth = truth_seen_from_vilnius(90.0, 0.0, 600.0);
    let mut h = host_with(
        CommApp::new(CommConfig::default()).with_truth(board_with(&truth)),
        1,
    );
    let tm = tmcomm(&mut h, SimTime::from_secs(1));
    assert_eq!((tm.in_contact, tm.station), (1, 0));
    assert!(
        (tm.elevation_deg - 90.0).abs() < 0.01,
        "{}",
        tm.elevation_deg
    );
    assert!((tm.range_km - 600.0).abs() < 0.01, "{}", tm.range_km);
    // Signal 29 + 14 - 3 - 140.820 = -100.820 dBm; noise -128.599 dBm (computed by hand).
    assert!((tm.snr_db - 27.779).abs() < 0.01, "{}", tm.snr_db);
    let rssi = 10.0 * (10f64.powf(-10.0820) + 10f64.powf(-12.8599)).log10();
    assert!(
        (f64::from(tm.rssi_dbm) - rssi).abs() < 0.01,
        "{}",
        tm.rssi_dbm
    );
    // The beacon says the same, and the sub-satellite point is Vilnius, 600 km up.
    let r = request(&mut h, &[wire::cmd::BEACON], SimTime::from_secs(1));
    let b = Beacon::parse(&r[2..]).unwrap();
    assert_eq!(b.flags, wire::BEACON_TRUTH_VALID | wire::BEACON_IN_CONTACT);
    assert!((b.lat_deg - 54.6872).abs() < 1e-3 && (b.lon_deg - 25.2797).abs() < 1e-3);
    assert!((b.alt_km - 600.112).abs() < 0.01, "{}", b.alt_km);
    assert!((b.rssi_dbm - tm.rssi_dbm).abs() < 1e-6);
}

#[test]
fn link_state_follows_elevation_and_the_mask() {
    let tm_for = |el: f64, range: f64| {
        let truth = truth_seen_from_vilnius(el, 135.0, range);
        let mut h = host_with(
            CommApp::new(CommConfig::default()).with_truth(board_with(&truth)),
            1,
        );
        tmcomm(&mut h, SimTime::from_secs(1))
    };
    let low = tm_for(5.0, 2000.0);
    assert_eq!(low.in_contact, 0, "below the 10 deg mask");
    assert!((low.elevation_deg - 5.0).abs() < 0.01);
    assert!((low.azimuth_deg - 135.0).abs() < 0.01);
    assert!((low.range_km - 2000.0).abs() < 0.01);
    assert!((low.rssi_dbm - -128.599).abs() < 0.01, "noise floor only");
    assert_eq!(low.snr_db, 0.0);
    let mid = tm_for(30.0, 1000.0);
    assert_eq!(mid.in_contact, 1);
    // 29 + 14 - 3 - 145.257 + 128.599 = 23.342 dB.
    assert!((mid.snr_db - 23.342).abs() < 0.01, "{}", mid.snr_db);
    let edge = tm_for(10.01, 1700.0);
    assert_eq!(edge.in_contact, 1, "at the mask");
}

#[test]
fn nearest_station_above_the_mask_is_reported() {
    let truth = truth_seen_from_vilnius(90.0, 0.0, 600.0);
    let svalbard = Station {
        name: "Svalbard".to_owned(),
        lat_deg: 78.23,
        lon_deg: 15.39,
        alt_m: 500.0,
    };
    for (stations, want) in [
        (vec![Station::vilnius(), svalbard.clone()], 0),
        (vec![svalbard.clone(), Station::vilnius()], 1),
    ] {
        let cfg = CommConfig {
            stations,
            ..CommConfig::default()
        };
        let mut h = host_with(CommApp::new(cfg).with_truth(board_with(&truth)), 1);
        let tm = tmcomm(&mut h, SimTime::from_secs(1));
        assert_eq!((tm.station, tm.in_contact), (want, 1));
    }
    // Only Svalbard: it is reported (nearest), out of contact.
    let cfg = CommConfig {
        stations: vec![svalbard],
        ..CommConfig::default()
    };
    let mut h = host_with(CommApp::new(cfg).with_truth(board_with(&truth)), 1);
    let tm = tmcomm(&mut h, SimTime::from_secs(1));
    assert_eq!((tm.station, tm.in_contact), (0, 0));
    assert!(tm.elevation_deg < 10.0);
}

#[test]
fn beacon_air_time_is_counted_at_the_radio_rate() {
    assert_eq!(air_time(173, 9600, 0), BEACON_AIR);
    let mut h = host_with(CommApp::new(CommConfig::default()), 1);
    drive(&mut h, SimTime::from_secs(600));
    let tm = tmcomm(&mut h, SimTime::from_secs(601));
    assert_eq!(tm.beacon_air_ms, 1475);
    assert_eq!(h.app.counters().beacon_air, BEACON_AIR * 10);
    // A faster radio: air time scales with the rate.
    let cfg = CommConfig {
        air_rate_bps: 19_200,
        ..CommConfig::default()
    };
    let mut h = host_with(CommApp::new(cfg), 1);
    drive(&mut h, SimTime::from_secs(60));
    assert_eq!(h.app.counters().beacon_air, BEACON_AIR / 2);
}

#[test]
fn the_radio_switch_activates_the_secondary_at_its_instant() {
    let cfg = CommConfig {
        role: CommRole::Secondary,
        ..CommConfig::default()
    };
    let mut h = host_with(CommApp::new(cfg), 2);
    drive(&mut h, SimTime::from_secs(100));
    assert_eq!(h.app.counters().beacons_sent, 0);
    assert!(!h.app.is_active());
    h.switch(RADIO_SWITCH, SwitchPosition::On, SimTime::from_secs(105));
    assert!(h.app.is_active());
    assert_eq!(h.app.next_beacon(), Some(SimTime::from_secs(165)));
    drive(&mut h, SimTime::from_secs(230));
    assert_eq!(h.app.counters().beacons_sent, 2);
    h.switch(RADIO_SWITCH, SwitchPosition::Off, SimTime::from_secs(230));
    assert_eq!(h.app.next_beacon(), None);
    drive(&mut h, SimTime::from_secs(400));
    assert_eq!(h.app.counters().beacons_sent, 2);
}

#[test]
fn beacon_decoded_by_an_independent_decoder() {
    let truth = truth_seen_from_vilnius(45.0, 200.0, 800.0);
    let mut h = host_with(
        CommApp::new(CommConfig::default()).with_truth(board_with(&truth)),
        1,
    );
    let (_, p) = drive(&mut h, SimTime::from_secs(60)).pop().unwrap();
    let d = &p.data;
    assert_eq!((d[0], d[1], d.len()), (4, 1, 173));
    let b = &d[2..];
    assert_eq!(le_u32(b, 0), 1);
    assert_eq!(b[12], 3);
    assert_eq!(le_u32(b, 13), EPOCH_UNIX_S as u32, "truth instant");
    for i in 0..3 {
        let want = (truth.r_eci_m[i] * 1e-3) as f32;
        assert_eq!(le_f32(b, 17 + 4 * i), want);
        assert_eq!(le_f32(b, 29 + 4 * i), (truth.v_eci_m_s[i] * 1e-3) as f32);
    }
    let q = truth.q_eci_from_body;
    let q_wire: Vec<f32> = (0..4).map(|i| le_f32(b, 53 + 4 * i)).collect();
    assert_eq!(q_wire, vec![q.w as f32, q.i as f32, q.j as f32, q.k as f32]);
    assert!((le_f32(b, 69) - 0.01f64.to_degrees() as f32).abs() < 1e-6);
    // Sun along ECI +X seen in the body: the inverse rotation.
    let sun_body = q.inverse() * Vector3::x();
    assert!((le_f32(b, 81) - sun_body.x as f32).abs() < 1e-6);
    assert_eq!(b[93], 50, "half the sun visible");
    // 100 rad/s = 954.93 rpm.
    assert!((le_f32(b, 106) - 954.93).abs() < 0.01);
    assert!((le_f32(b, 122) - 0.1).abs() < 1e-7);
    assert_eq!(b[134], 0);
    assert!((le_f32(b, 135) - 45.0).abs() < 0.01);
    assert!((le_f32(b, 139) - 200.0).abs() < 0.01);
    assert!((le_f32(b, 143) - 800.0).abs() < 0.01);
    assert_eq!(
        le_u32(b, 155),
        0,
        "counters as they were before this beacon"
    );
    assert_eq!(le_u16(b, 167), 0, "reboots");
    assert_eq!(le_u16(b, 169), 60);
    let (_, p2) = drive(&mut h, SimTime::from_secs(120)).pop().unwrap();
    assert_eq!(
        le_u32(&p2.data[2..], 155),
        1,
        "the first beacon counted as sent"
    );
}

#[test]
fn reboot_restarts_sequence_and_period() {
    let mut h = host(CommConfig::default());
    drive(&mut h, SimTime::from_secs(120));
    assert_eq!(
        request(&mut h, &[2, 20, 0], SimTime::from_secs(130)),
        vec![2, 1]
    );
    assert_eq!(request(&mut h, &[9], SimTime::from_secs(131)), vec![9, 0]);
    assert_eq!(tmcomm(&mut h, SimTime::from_secs(132)).refused, 1);
    h.reboot(SimTime::from_secs(140));
    assert_eq!(
        request(&mut h, &[3], SimTime::from_secs(140)),
        vec![3, 1, 60, 0]
    );
    let b = drive(&mut h, SimTime::from_secs(200));
    assert_eq!(b.len(), 1);
    assert_eq!(b[0].0, SimTime::from_secs(200));
    let body = &b[0].1.data[2..];
    assert_eq!((le_u32(body, 0), le_u32(body, 8)), (1, 60));
    assert_eq!(le_u16(body, 167), 1, "reboots");
    let tm = tmcomm(&mut h, SimTime::from_secs(201));
    assert_eq!((tm.beacons_sent, tm.refused, tm.uptime_s), (1, 0, 61));
    assert_eq!(h.app.counters().beacons_sent, 3);
    assert_eq!(h.app.counters().refused, 1);
}

#[test]
fn config_validation() {
    assert!(CommConfig::default().validate().is_ok());
    assert!(CommConfig::secondary().validate().is_ok());
    let bad = [
        CommConfig {
            beacon_period: Duration::from_secs(5),
            ..CommConfig::default()
        },
        CommConfig {
            beacon_period: Duration::from_millis(60_500),
            ..CommConfig::default()
        },
        CommConfig {
            ground_addr: 3,
            ..CommConfig::default()
        },
        CommConfig {
            port: 40,
            ..CommConfig::default()
        },
        CommConfig {
            air_rate_bps: 0,
            ..CommConfig::default()
        },
    ];
    for c in bad {
        assert!(c.validate().is_err(), "{c:?}");
    }
}

/// What the port table says about a request, decided independently of `CommCommand`.
fn well_formed(req: &[u8]) -> bool {
    match req {
        [1] | [3] | [4] => true,
        [2, lo, hi] => {
            let p = u16::from_le_bytes([*lo, *hi]);
            p == 0 || (10..=3600).contains(&p)
        }
        _ => false,
    }
}

proptest! {
    #[test]
    fn any_request_gets_exactly_one_reply(req in proptest::collection::vec(any::<u8>(), 0..200),
                                          cmd in 0u8..6, short in proptest::collection::vec(any::<u8>(), 0..3)) {
        let mut h = host(CommConfig::default());
        for r in [req, std::iter::once(cmd).chain(short).collect::<Vec<_>>()] {
            let reply = request(&mut h, &r, SimTime::from_secs(1));
            prop_assert_eq!(reply[0], r.first().copied().unwrap_or(0));
            if well_formed(&r) {
                prop_assert_eq!(reply[1], 1);
            } else {
                prop_assert_eq!(reply, vec![r.first().copied().unwrap_or(0), 0]);
            }
        }
    }
}

/// Send `req` from the ground (16, port 41) to the platform port (14) at `t`; the one
/// reply's data.
fn platform(h: &mut Host<CommApp>, req: &[u8], t: SimTime) -> Vec<u8> {
    let addr = h.node.addr();
    let port = csp::params::PORT;
    h.handle_packet(
        1,
        Packet::new(Header::new(16, addr, port, 41), req.to_vec()),
        t,
    );
    let out = uhf_out(h);
    assert_eq!(out.len(), 1, "exactly one reply to {req:?}");
    assert_eq!(out[0].header, Header::new(addr, 16, 41, port));
    out[0].data.clone()
}

#[test]
fn platform_beacon_period_is_beaconsets_and_reverts_at_reboot_unless_saved() {
    let mut h = host(CommConfig::default());
    let s = SimTime::from_secs;
    // PGET: id 1, type u16, 60 s.
    assert_eq!(platform(&mut h, &[1, 1], s(1)), [1, 1, 1, 2, 60, 0]);
    // PSET 120 s at 10 s: BEACONGET agrees, and the schedule restarts from then.
    assert_eq!(
        platform(&mut h, &[2, 1, 120, 0], s(10)),
        [2, 1, 1, 2, 120, 0]
    );
    assert_eq!(request(&mut h, &[3], s(10)), [3, 1, 120, 0]);
    h.handle_timeout(s(10));
    assert_eq!(h.app.next_beacon(), Some(s(130)));
    let b = drive(&mut h, s(130));
    assert_eq!(b.iter().map(|x| x.0).collect::<Vec<_>>(), [s(130)]);
    // BEACONSET: PGET agrees.
    assert_eq!(request(&mut h, &[2, 30, 0], s(140)), [2, 1]);
    assert_eq!(platform(&mut h, &[1, 1], s(140)), [1, 1, 1, 2, 30, 0]);
    // Out of range (above 3600), and between 0 and 10: refused, unchanged.
    assert_eq!(platform(&mut h, &[2, 1, 0x11, 0x0e], s(141)), [2, 0]);
    assert_eq!(platform(&mut h, &[2, 1, 5, 0], s(141)), [2, 0]);
    assert_eq!(platform(&mut h, &[2, 2, 21], s(141)), [2, 0]);
    assert_eq!(request(&mut h, &[3], s(141)), [3, 1, 30, 0]);
    // The beacon destination and the EIRP (f32).
    assert_eq!(platform(&mut h, &[2, 2, 17], s(142)), [2, 1, 2, 1, 17]);
    let mut set = vec![2, 3];
    set.extend_from_slice(&33.0f32.to_le_bytes());
    let mut echo = vec![2, 1, 3, 5];
    echo.extend_from_slice(&33.0f32.to_le_bytes());
    assert_eq!(platform(&mut h, &set, s(142)), echo);
    // A reboot without PSAVE: the factory table.
    h.reboot(s(150));
    assert_eq!(request(&mut h, &[3], s(150)), [3, 1, 60, 0]);
    assert_eq!(platform(&mut h, &[1, 2], s(150)), [1, 1, 2, 1, 16]);
    assert_eq!(h.app.config().link.eirp_dbm, 29.0);
    // Set, saved, reboot: kept, and the first beacon a period after the boot.
    assert_eq!(
        platform(&mut h, &[2, 1, 20, 0], s(160)),
        [2, 1, 1, 2, 20, 0]
    );
    assert_eq!(platform(&mut h, &[5], s(160)), [5, 1]);
    h.reboot(s(170));
    assert_eq!(request(&mut h, &[3], s(170)), [3, 1, 20, 0]);
    let b = drive(&mut h, s(190));
    assert_eq!(b.len(), 1);
    assert_eq!(b[0].0, s(190));
    assert_eq!(b[0].1.header.dst, 16);
}

#[test]
fn selftest_reports_radio_link_and_beacons() {
    let at = |el| truth_seen_from_vilnius(el, 0.0, 700.0);
    let mut h = host_with(
        CommApp::new(CommConfig::default()).with_truth(board_with(&at(45.0))),
        1,
    );
    drive(&mut h, SimTime::from_secs(120));
    let r = platform(&mut h, &[7], SimTime::from_secs(121));
    assert_eq!(r[..2], [7, 1]);
    assert_eq!(r[3], 3);
    assert_eq!(r.len(), 4 + 3 * 5);
    let entry = |i: usize| {
        let at = 4 + 5 * i;
        (
            r[at],
            f32::from_le_bytes(r[at + 1..at + 5].try_into().unwrap()),
        )
    };
    assert_eq!(entry(0), (0, 29.0), "radio active, EIRP");
    let tm = tmcomm(&mut h, SimTime::from_secs(121));
    assert_eq!(entry(1), (0, tm.rssi_dbm), "in contact: TMCOMM's RSSI");
    assert_eq!(entry(2), (0, 2.0), "two beacons");
    assert_eq!(r[2], 0);
    // A stronger transmitter: a stronger signal at the ground.
    let mut set = vec![2, 3];
    set.extend_from_slice(&35.0f32.to_le_bytes());
    assert_eq!(platform(&mut h, &set, SimTime::from_secs(122))[..2], [2, 1]);
    let louder = tmcomm(&mut h, SimTime::from_secs(122));
    assert!((louder.snr_db - tm.snr_db - 6.0).abs() < 1e-3, "{louder:?}");
    // The secondary on standby without truth: radio, link and beacons off, overall ok.
    let mut h = host(CommConfig::secondary());
    let r = platform(&mut h, &[7], SimTime::from_secs(1));
    assert_eq!(r[..4], [7, 1, 0, 3]);
    assert_eq!([r[4], r[9], r[14]], [3, 3, 3]);
    // Active without truth: no link budget (degraded).
    h.switch(RADIO_SWITCH, SwitchPosition::On, SimTime::from_secs(2));
    let r = platform(&mut h, &[7], SimTime::from_secs(3));
    assert_eq!([r[2], r[4], r[9], r[14]], [1, 0, 1, 0]);
}

/// COMM saved after a BEACONSET (period 30 s) and loaded into one built from the defaults
/// beacons on the saved schedule: the same beacons at the same instants, the same bytes.
#[test]
fn comm_saved_after_a_beaconset_and_loaded_into_a_fresh_one_beacons_the_same() {
    let mut a = host(CommConfig::default());
    drive(&mut a, SimTime::from_secs(125));
    assert_eq!(
        request(&mut a, &[2, 30, 0], SimTime::from_secs(125)),
        vec![2, 1]
    );
    drive(&mut a, SimTime::from_secs(170));
    let bytes = snap::to_bytes(&a);
    let mut b = host(CommConfig::default());
    snap::load_from(&mut b, &bytes).unwrap();
    assert_eq!(snap::to_bytes(&b), bytes);
    let (ba, bb) = (
        drive(&mut a, SimTime::from_secs(400)),
        drive(&mut b, SimTime::from_secs(400)),
    );
    assert_eq!(ba.len(), 8, "every 30 s from 185 s");
    assert_eq!(ba, bb);
    assert_eq!(snap::to_bytes(&a), snap::to_bytes(&b));
}
