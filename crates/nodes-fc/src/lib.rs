//! Flight computer (CSP 3): the FC ports of ICD 4 answering from the FC's state.
//!
//! This is the first increment of the FC issue: every FC command of ICD 4.2.1-4.2.3 has its
//! exact wire type ([`wire`]) and an answer, from a simple state that already flies the real
//! orbit:
//! - **Orbit**: the scenario's TLE through `orbit`'s SGP4 ([`orbit::propagate::Sgp4Propagator`]),
//!   evaluated at the run's true UTC time (`epoch_unix_s` + simulated time), ECI J2000,
//!   metres. No TLE, or a propagation error (decay, bad elements): TMATP and TMALL answer
//!   the failure reply; nothing panics.
//! - **Attitude**: until the ADCS lands, TMATP's quaternion is the commanded target, not an
//!   estimate: the ATCATSET quaternion when the target mode is fixed quaternion in ECI (7),
//!   the identity otherwise.
//! - **Clock**: the RTC is the true UTC time plus an offset set by RTCSTMSET; it survives
//!   reboots (a real-time clock), as do the global on-time and the reset cause.
//! - **Target**: mode, attitude and point as set by ATCMDSET/ATCATSET/ATCPTSET; volatile
//!   (a reboot restores detumble, identity and zero, as the ADCS boots in detumble, ICD 1.3).
//! - **Sensors and actuators**: no models yet. TMSENS, TMRAWSENS and the wheel and
//!   magnetorquer fields of TMACD are zeros; temperatures are a constant 20 degrees C.
//!
//! [`truth`] holds the attitude dynamics (rigid body, four wheels, magnetorquers, gravity
//! gradient) that a later increment steps and publishes; the app above does not use it yet.
//!
//! Port 13 (mission-controller scripts, ICD 1.5) is bound and answers every request with
//! the failure reply until a later increment. Byte layouts and decisions are in
//! `docs/protocol.md`, section "FC ports".

pub mod truth;
pub mod wire;

use csp::node::{App, Node};
use csp::reqrep::{self, RESULT_FAILURE, serve};
use csp::{Packet, SimTime};
use orbit::propagate::{Propagator, Sgp4Propagator};
use orbit::time::UtcTime;
use orbit::tle::{ChecksumMode, Tle};

use crate::wire::{
    AttitudeCommand, Repr, RtcCommand, RtcTimestamp, TargetAttitude, TargetMode, TargetModeRepr,
    TargetPoint, TelemetryCommand, TmAcd, TmAll, TmAtp, TmGen, TmRawSens, TmSens,
};

/// The ports this node binds for its ICD services by default (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[
    wire::PORT_TELEMETRY,
    wire::PORT_RTC,
    wire::PORT_ATTITUDE,
    wire::PORT_SCRIPTS,
];

/// Placeholder temperature of the MCU and every sensor until thermal models land, deg C.
pub const PLACEHOLDER_TEMP_C: i8 = 20;

/// Reset cause in TMGEN: power-on (the start of the run).
pub const RESET_POWER_ON: u8 = 0;
/// Reset cause in TMGEN: software reboot (CSP reboot service or a scenario fault).
pub const RESET_SOFTWARE: u8 = 1;

/// The FC's ICD ports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FcPorts {
    /// Telemetry (TMGEN ... TMALL).
    pub telemetry: u8,
    /// Real-time clock.
    pub rtc: u8,
    /// Attitude target control.
    pub attitude: u8,
    /// Mission-controller scripts.
    pub scripts: u8,
}

impl Default for FcPorts {
    fn default() -> Self {
        FcPorts {
            telemetry: wire::PORT_TELEMETRY,
            rtc: wire::PORT_RTC,
            attitude: wire::PORT_ATTITUDE,
            scripts: wire::PORT_SCRIPTS,
        }
    }
}

/// What the FC needs from the scenario.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct FcConfig {
    /// UTC unix seconds at simulated time zero.
    pub epoch_unix_s: u64,
    /// The two TLE lines, if the scenario gives an orbit.
    pub tle: Option<(String, String)>,
    /// Port numbers.
    pub ports: FcPorts,
}

/// The commanded attitude target (ATC* commands).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Target mode.
    pub mode: TargetMode,
    /// Target quaternion, unit norm, scalar first.
    pub attitude: [f64; 4],
    /// Whether ATCATSET set it since boot.
    pub attitude_set: bool,
    /// Target point.
    pub point: [f64; 3],
    /// Whether ATCPTSET set it since boot.
    pub point_set: bool,
}

impl Default for Target {
    fn default() -> Self {
        Target {
            mode: TargetMode::Detumble,
            attitude: [1.0, 0.0, 0.0, 0.0],
            attitude_set: false,
            point: [0.0; 3],
            point_set: false,
        }
    }
}

/// The flight computer's application (see the module doc).
#[derive(Debug)]
pub struct FcApp {
    cfg: FcConfig,
    propagator: Result<Sgp4Propagator, String>,
    rtc_offset_ns: i128,
    power_on: Option<SimTime>,
    reset_cause: u8,
    target: Target,
    refused: u64,
}

impl FcApp {
    /// An FC for `cfg`; a TLE that does not parse or initialise leaves TMATP failing.
    pub fn new(cfg: FcConfig) -> Self {
        let propagator = match &cfg.tle {
            None => Err("no TLE".to_owned()),
            Some((l1, l2)) => Tle::parse(l1, l2, ChecksumMode::Strict)
                .map_err(|e| format!("TLE: {e}"))
                .and_then(|tle| Sgp4Propagator::new(&tle).map_err(|e| format!("SGP4: {e}"))),
        };
        FcApp {
            cfg,
            propagator,
            rtc_offset_ns: 0,
            power_on: None,
            reset_cause: RESET_POWER_ON,
            target: Target::default(),
            refused: 0,
        }
    }

    /// Why the FC has no orbit, if it has none.
    pub fn orbit_error(&self) -> Option<&str> {
        self.propagator.as_ref().err().map(String::as_str)
    }

    /// The commanded target.
    pub fn target(&self) -> &Target {
        &self.target
    }

    /// Requests answered with the failure reply because they did not parse.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// True UTC time at `now` (the run's clock, not the RTC), nanoseconds.
    fn true_unix_ns(&self, now: SimTime) -> i128 {
        i128::from(self.cfg.epoch_unix_s) * 1_000_000_000 + i128::from(now.as_ns())
    }

    /// The RTC at `now`, UTC unix seconds (saturating to the u32 range).
    pub fn rtc_unix_s(&self, now: SimTime) -> u32 {
        let s = (self.true_unix_ns(now) + self.rtc_offset_ns).div_euclid(1_000_000_000);
        u32::try_from(s.max(0)).unwrap_or(u32::MAX)
    }

    /// ECI J2000 position in metres at `now`, or why there is none.
    pub fn position_eci_m(&mut self, now: SimTime) -> Result<[f64; 3], String> {
        let t =
            i64::try_from(self.true_unix_ns(now)).map_err(|_| "time out of range".to_owned())?;
        let p = self.propagator.as_mut().map_err(|e| e.clone())?;
        let s = p
            .state_j2000(UtcTime::from_unix_ns(t))
            .map_err(|e| e.to_string())?;
        Ok([s.r_km[0] * 1e3, s.r_km[1] * 1e3, s.r_km[2] * 1e3])
    }

    /// The attitude TMATP reports: until the ADCS lands, the commanded target.
    fn reported_attitude(&self) -> [f64; 4] {
        match self.target.mode {
            TargetMode::FixedEci => self.target.attitude,
            _ => [1.0, 0.0, 0.0, 0.0],
        }
    }

    fn tm_gen(&self, node: &Node, now: SimTime) -> TmGen {
        let secs = |d: std::time::Duration| u32::try_from(d.as_secs()).unwrap_or(u32::MAX);
        let on = self
            .power_on
            .map_or(std::time::Duration::ZERO, |t| now.saturating_since(t));
        TmGen {
            rtc_timestamp: self.rtc_unix_s(now),
            uptime_s: secs(node.uptime(now)),
            global_on_time_s: secs(on),
            current_mode: self.target.mode as u8,
            current_state: 0,
            mcu_temp_c: PLACEHOLDER_TEMP_C,
            reset_cause: self.reset_cause,
        }
    }

    fn tm_atp(&mut self, now: SimTime) -> Result<TmAtp, String> {
        Ok(TmAtp {
            rtc_timestamp: self.rtc_unix_s(now),
            q_eci_from_body: self.reported_attitude(),
            r_eci_m: self.position_eci_m(now)?,
        })
    }

    fn tm_acd(&self, now: SimTime) -> TmAcd {
        TmAcd {
            rtc_timestamp: self.rtc_unix_s(now),
            state: 0,
            rw_state: [0; 4],
            rw_rpm_100: [0; 4],
            mtq_state: [0; 3],
            target_mode: self.target.mode as u8,
            target_attitude: u8::from(self.target.attitude_set),
            target_point: u8::from(self.target.point_set),
        }
    }

    fn tm_sens(&self, now: SimTime) -> TmSens {
        TmSens {
            rtc_timestamp: self.rtc_unix_s(now),
            temps_c: [PLACEHOLDER_TEMP_C; 6],
            ..TmSens::default()
        }
    }

    fn tm_raw_sens(&self, now: SimTime) -> TmRawSens {
        TmRawSens {
            rtc_timestamp: self.rtc_unix_s(now),
            // 0.1 degrees C per LSB.
            temps_raw: [i16::from(PLACEHOLDER_TEMP_C) * 10; 6],
            ..TmRawSens::default()
        }
    }

    fn telemetry(&mut self, node: &Node, c: TelemetryCommand, now: SimTime) -> Result<Vec<u8>, u8> {
        let fail = |_| RESULT_FAILURE;
        Ok(match c {
            TelemetryCommand::TmGen => self.tm_gen(node, now).to_vec(),
            TelemetryCommand::TmAtp => self.tm_atp(now).map_err(fail)?.to_vec(),
            TelemetryCommand::TmAcd => self.tm_acd(now).to_vec(),
            TelemetryCommand::TmSens => self.tm_sens(now).to_vec(),
            TelemetryCommand::TmRawSens => self.tm_raw_sens(now).to_vec(),
            TelemetryCommand::TmAll => TmAll {
                general: self.tm_gen(node, now),
                attitude_position: self.tm_atp(now).map_err(fail)?,
                attitude_control: self.tm_acd(now),
                sensors: self.tm_sens(now),
            }
            .to_vec(),
        })
    }

    fn rtc(&mut self, c: RtcCommand, now: SimTime) -> Vec<u8> {
        match c {
            RtcCommand::Set(t) => {
                self.rtc_offset_ns =
                    i128::from(t.rtc_timestamp) * 1_000_000_000 - self.true_unix_ns(now);
                Vec::new()
            }
            RtcCommand::Get => RtcTimestamp {
                rtc_timestamp: self.rtc_unix_s(now),
            }
            .to_vec(),
        }
    }

    fn attitude(&mut self, c: AttitudeCommand) -> Vec<u8> {
        match c {
            AttitudeCommand::GetAttitude => TargetAttitude {
                q: self.target.attitude,
            }
            .to_vec(),
            AttitudeCommand::SetAttitude(q) => {
                self.target.attitude = q;
                self.target.attitude_set = true;
                Vec::new()
            }
            AttitudeCommand::GetPoint => TargetPoint {
                p: self.target.point,
            }
            .to_vec(),
            AttitudeCommand::SetPoint(p) => {
                self.target.point = p;
                self.target.point_set = true;
                Vec::new()
            }
            AttitudeCommand::GetMode => TargetModeRepr {
                mode: self.target.mode,
            }
            .to_vec(),
            AttitudeCommand::SetMode(m) => {
                self.target.mode = m;
                Vec::new()
            }
        }
    }
}

impl App for FcApp {
    fn start(&mut self, node: &mut Node, now: SimTime) {
        self.power_on.get_or_insert(now);
        let p = self.cfg.ports;
        for port in [p.telemetry, p.rtc, p.attitude, p.scripts] {
            node.bind(port);
        }
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        let p = self.cfg.ports;
        let dport = packet.header.dport;
        let (reply, refused) = if dport == p.telemetry {
            serve::<TelemetryCommand>(&packet.data, |c| self.telemetry(node, c, now))
        } else if dport == p.rtc {
            serve::<RtcCommand>(&packet.data, |c| Ok(self.rtc(c, now)))
        } else if dport == p.attitude {
            serve::<AttitudeCommand>(&packet.data, |c| Ok(self.attitude(c)))
        } else if dport == p.scripts {
            // Scripts (ICD 1.5) are a later increment: a well-formed packet still gets an answer.
            let command = packet.data.first().copied().unwrap_or(0);
            (reqrep::failure(command), None)
        } else {
            return;
        };
        if refused.is_some() {
            self.refused += 1;
        }
        // A send failure is already counted by the node.
        let _ = node.send(Packet::new(packet.header.reply(node.addr()), reply), now);
    }

    fn reset(&mut self, _now: SimTime) {
        self.target = Target::default();
        self.reset_cause = RESET_SOFTWARE;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    // 0.707106 is the ICD 1.5 example's value, deliberately not FRAC_1_SQRT_2.
    #![allow(clippy::approx_constant)]
    use super::*;
    use csp::Header;
    use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
    use csp::router::Route;

    /// The default scenario's 6U TLE (scenarios/default.toml).
    const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
    const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
    /// 2026-04-30T18:00:00Z, the default scenario's `start`.
    const START: u64 = 1_777_572_000;

    fn host(tle: Option<(&str, &str)>) -> Host<FcApp> {
        let mut c = NodeConfig::new("FC", 3);
        c.ifaces = vec![IfaceConfig::packet("p")];
        c.routes.set_default(Route::direct(0));
        c.epoch_unix_s = START;
        let app = FcApp::new(FcConfig {
            epoch_unix_s: START,
            tle: tle.map(|(a, b)| (a.to_owned(), b.to_owned())),
            ports: FcPorts::default(),
        });
        Host::new(c, app, SimTime::ZERO)
    }

    fn ask(h: &mut Host<FcApp>, port: u8, req: &[u8], t: SimTime) -> Vec<u8> {
        h.handle_packet(
            0,
            Packet::new(Header::new(16, 3, port, 40), req.to_vec()),
            t,
        );
        let Some(Transmit::Packet { packet, .. }) = h.node.poll_transmit() else {
            panic!("no reply to port {port} {req:02x?}")
        };
        assert_eq!(packet.header, Header::new(3, 16, 40, port));
        assert!(h.node.poll_transmit().is_none(), "one reply per request");
        packet.data
    }

    #[test]
    fn start_is_the_default_scenario_start() {
        assert_eq!(
            UtcTime::from_iso8601("2026-04-30T18:00:00Z").unwrap(),
            UtcTime::from_unix_ns(START as i64 * 1_000_000_000)
        );
    }

    #[test]
    fn tmatp_position_is_the_orbit_crate_j2000_position_in_metres() {
        let mut h = host(Some((L1, L2)));
        let mut prop =
            Sgp4Propagator::new(&Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()).unwrap();
        for t_s in [0u64, 1, 600, 5432, 3 * 3600] {
            let t = SimTime::from_secs(t_s);
            let reply = ask(&mut h, 10, &[2], t);
            assert_eq!(&reply[..2], &[2, 1]);
            let atp = TmAtp::parse(&reply[2..]).unwrap();
            let want = prop
                .state_j2000(UtcTime::from_unix_ns(
                    ((START + t_s) * 1_000_000_000) as i64,
                ))
                .unwrap()
                .r_km
                * 1e3;
            for i in 0..3 {
                assert_eq!(atp.r_eci_m[i], want[i], "t = {t_s} s, axis {i}");
            }
            let r = want.norm();
            assert!((6.6e6..7.0e6).contains(&r), "{r}");
            assert_eq!(atp.rtc_timestamp as u64, START + t_s);
            assert_eq!(atp.q_eci_from_body, [1.0, 0.0, 0.0, 0.0]);
        }
    }

    #[test]
    fn tmgen_counts_uptime_and_on_time_across_a_reboot() {
        let mut h = host(Some((L1, L2)));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_secs(100))[2..]).unwrap();
        assert_eq!(
            g,
            TmGen {
                rtc_timestamp: (START + 100) as u32,
                uptime_s: 100,
                global_on_time_s: 100,
                current_mode: TargetMode::Detumble as u8,
                current_state: 0,
                mcu_temp_c: 20,
                reset_cause: RESET_POWER_ON,
            }
        );
        ask(&mut h, 12, &[6, 3], SimTime::from_secs(150));
        h.reboot(SimTime::from_secs(200));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_secs(230))[2..]).unwrap();
        assert_eq!(
            (g.uptime_s, g.global_on_time_s, g.reset_cause),
            (30, 230, RESET_SOFTWARE)
        );
        assert_eq!(
            g.current_mode,
            TargetMode::Detumble as u8,
            "target is volatile"
        );
    }

    #[test]
    fn rtc_set_then_get() {
        let mut h = host(None);
        let t = SimTime::from_ms(10_500);
        assert_eq!(ask(&mut h, 11, &[1, 0x80, 0x3e, 0x0c, 0x5e], t), vec![1, 1]);
        // 0x5e0c3e80 = 1577860736
        assert_eq!(ask(&mut h, 11, &[2], t), vec![2, 1, 0x80, 0x3e, 0x0c, 0x5e]);
        let later = ask(&mut h, 11, &[2], SimTime::from_ms(20_499));
        assert_eq!(
            RtcTimestamp::parse(&later[2..]).unwrap().rtc_timestamp,
            1_577_860_736 + 9
        );
        // The RTC survives a reboot; TMGEN and TMATP carry it.
        h.reboot(SimTime::from_secs(30));
        let g = TmGen::parse(&ask(&mut h, 10, &[1], SimTime::from_ms(30_500))[2..]).unwrap();
        assert_eq!(g.rtc_timestamp, 1_577_860_736 + 20);
    }

    #[test]
    fn attitude_point_and_mode_set_then_get() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(5);
        let q = TargetAttitude {
            q: [0.5, -0.5, 0.5, 0.5],
        };
        let mut req = vec![2];
        q.emit(&mut req);
        assert_eq!(ask(&mut h, 12, &req, t), vec![2, 1]);
        let got = ask(&mut h, 12, &[1], t);
        assert_eq!(got[..2], [1, 1]);
        assert_eq!(TargetAttitude::parse(&got[2..]).unwrap(), q);

        // An ICD-style, not quite unit, quaternion is normalised.
        let mut req = vec![2];
        TargetAttitude {
            q: [0.707106, 0.0, 0.0, -0.707106],
        }
        .emit(&mut req);
        assert_eq!(ask(&mut h, 12, &req, t), vec![2, 1]);
        let n = TargetAttitude::parse(&ask(&mut h, 12, &[1], t)[2..]).unwrap();
        assert!((n.q[0] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);
        assert!((n.q[3] + std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);

        let mut req = vec![4];
        TargetPoint {
            p: [54.6872, 25.2797, 100.0],
        }
        .emit(&mut req);
        assert_eq!(ask(&mut h, 12, &req, t), vec![4, 1]);
        assert_eq!(ask(&mut h, 12, &[3], t)[2..], req[1..]);

        assert_eq!(ask(&mut h, 12, &[5], t), vec![5, 1, 1], "boots in detumble");
        assert_eq!(ask(&mut h, 12, &[6, 7], t), vec![6, 1]);
        assert_eq!(ask(&mut h, 12, &[5], t), vec![5, 1, 7]);

        // In fixed-ECI mode TMATP reports the commanded quaternion.
        let atp = TmAtp::parse(&ask(&mut h, 10, &[2], t)[2..]).unwrap();
        assert_eq!(atp.q_eci_from_body, n.q);
        let acd = TmAcd::parse(&ask(&mut h, 10, &[3], t)[2..]).unwrap();
        assert_eq!(
            (acd.target_mode, acd.target_attitude, acd.target_point),
            (7, 1, 1)
        );
        let all = ask(&mut h, 10, &[6], t);
        assert_eq!(all.len(), 2 + 165);
        let all = TmAll::parse(&all[2..]).unwrap();
        assert_eq!(all.attitude_position, atp);
        assert_eq!(all.attitude_control, acd);
    }

    #[test]
    fn every_reply_has_its_icd_size() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(1);
        for (port, req, len) in [
            (10, vec![1], 16),
            (10, vec![2], 60),
            (10, vec![3], 19),
            (10, vec![4], 70),
            (10, vec![5], 46),
            (10, vec![6], 165),
            (11, vec![2], 4),
            (12, vec![1], 32),
            (12, vec![3], 24),
            (12, vec![5], 1),
        ] {
            let r = ask(&mut h, port, &req, t);
            assert_eq!(r[..2], [req[0], 1], "port {port} {req:?}");
            assert_eq!(r.len(), 2 + len, "port {port} {req:?}");
        }
    }

    #[test]
    fn every_malformed_request_gets_the_failure_reply() {
        let mut h = host(Some((L1, L2)));
        let t = SimTime::from_secs(1);
        let nan_q = {
            let mut v = vec![2];
            TargetAttitude {
                q: [f64::NAN, 0.0, 0.0, 1.0],
            }
            .emit(&mut v);
            v
        };
        let inf_p = {
            let mut v = vec![4];
            TargetPoint {
                p: [0.0, f64::INFINITY, 0.0],
            }
            .emit(&mut v);
            v
        };
        let cases: Vec<(u8, Vec<u8>)> = vec![
            (10, vec![0]),
            (10, vec![7]),
            (10, vec![0xff]),
            (10, vec![1, 0]),
            (10, vec![2, 0, 0]),
            (11, vec![0]),
            (11, vec![3]),
            (11, vec![1]),
            (11, vec![1, 1, 2, 3]),
            (11, vec![1, 1, 2, 3, 4, 5]),
            (11, vec![2, 0]),
            (12, vec![0]),
            (12, vec![7]),
            (12, vec![1, 0]),
            (12, [vec![2], vec![0; 16]].concat()),
            (12, [vec![2], vec![0; 32]].concat()),
            (12, nan_q),
            (12, [vec![4], vec![0; 16]].concat()),
            (12, inf_p),
            (12, vec![6]),
            (12, vec![6, 10]),
            (12, vec![6, 0xff]),
            (12, vec![6, 1, 1]),
            (13, vec![1, b'a']),
            (13, b"adcs 1 2 pointECI 1 0 0 0".to_vec()),
        ];
        for (port, req) in cases {
            assert_eq!(
                ask(&mut h, port, &req, t),
                vec![req[0], 0],
                "port {port} {req:02x?}"
            );
        }
        assert_eq!(ask(&mut h, 10, &[], t), vec![0, 0]);
        assert_eq!(ask(&mut h, 12, &[], t), vec![0, 0]);
        // Nothing malformed changed the target.
        assert_eq!(*h.app.target(), Target::default());
        assert!(h.app.refused() >= 20);
    }

    #[test]
    fn no_tle_or_a_decayed_orbit_fails_tmatp_and_tmall_only() {
        let mut h = host(None);
        let t = SimTime::from_secs(1);
        assert_eq!(h.app.orbit_error(), Some("no TLE"));
        assert_eq!(ask(&mut h, 10, &[2], t), vec![2, 0]);
        assert_eq!(ask(&mut h, 10, &[6], t), vec![6, 0]);
        assert_eq!(ask(&mut h, 10, &[1], t)[..2], [1, 1]);

        let mut h = host(Some((
            L1,
            "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 5000",
        )));
        assert!(h.app.orbit_error().unwrap().starts_with("TLE"));
        assert_eq!(ask(&mut h, 10, &[2], t), vec![2, 0]);

        // A very low, high-drag orbit decays within days: propagation errors, no panic.
        let l1 = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  99999-0 0  9990";
        let l2 = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 16.40000000 50002";
        let fix = |l: &str| {
            let body = &l[..68];
            format!("{body}{}", orbit::tle::checksum(body))
        };
        let (l1, l2) = (fix(l1), fix(l2));
        let mut h = host(Some((&l1, &l2)));
        assert_eq!(h.app.orbit_error(), None, "{:?}", h.app.orbit_error());
        let late = SimTime::from_secs(200 * 86_400);
        let why = h.app.position_eci_m(late).unwrap_err();
        assert!(
            why.contains("SGP4 error") || why.contains("decayed"),
            "{why}"
        );
        assert_eq!(ask(&mut h, 10, &[2], late), vec![2, 0]);
        assert_eq!(ask(&mut h, 10, &[1], late)[..2], [1, 1]);
    }
}
