//! The ECU's platform parameters and self-test (the platform port, [`csp::params`]).
//!
//! # Parameters
//! | id | name | type | unit | range | what it sets |
//! |---|---|---|---|---|---|
//! | 1 | max_burn | u32 | ms | 1..=3600000 | the longest burn one FIRE may ask for |
//! | 2 | warmup | u32 | ms | 0..=3600000 | heater warm-up from ARM until FIRE is accepted |
//!
//! Both act at once: a FIRE is checked against `max_burn` when it arrives, and a warm-up in
//! progress ends `warmup` after its ARM. An hour covers a burn that empties the default
//! tank (0.5 kg at 0.15 g/s or less: at least 55 min). The thruster, the tank and the
//! masses are hardware, not parameters; the ECU models no temperature, so it has no
//! temperature limit.
//!
//! # Self-test (wire order)
//! | # | component | reading |
//! |---|---|---|
//! | 1 | tank | propellant left, kg |
//! | 2 | tank_pressure | tank pressure, kPa |
//! | 3 | heater | warm-up left, s (off: disarmed) |
//! | 4 | thruster | thrust (of the burn, or available at the tank pressure), N (off: disarmed) |

use std::time::Duration;

use csp::params::{Check, Health, ParamDef, ParamError, ParamType, Table, def};

use crate::{EcuApp, EcuState, SimTime};

/// The ECU's parameter table.
pub const PARAMS: &[ParamDef] = &[
    def(
        1,
        "max_burn",
        ParamType::U32,
        "ms",
        1.0,
        3_600_000.0,
        "longest burn one FIRE may ask for (a longer one is refused)",
    ),
    def(
        2,
        "warmup",
        ParamType::U32,
        "ms",
        0.0,
        3_600_000.0,
        "heater warm-up from ARM until FIRE is accepted",
    ),
];

/// Below this fraction of the load the tank is reported degraded.
const LOW_PROPELLANT: f64 = 0.1;

fn ms(d: Duration) -> f64 {
    (d.as_secs_f64() * 1e3).round()
}

impl Table for EcuApp {
    fn defs(&self) -> &'static [ParamDef] {
        PARAMS
    }

    fn get(&self, id: u8) -> Option<f64> {
        Some(match id {
            1 => ms(self.cfg.max_burn),
            2 => ms(self.cfg.warmup),
            _ => return None,
        })
    }

    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
        let d = Duration::from_millis(v as u64);
        match id {
            1 => self.cfg.max_burn = d,
            2 => self.cfg.warmup = d,
            _ => return Err(ParamError::Unknown { id }),
        }
        Ok(())
    }
}

impl EcuApp {
    /// The ECU's self-test at `now`: tank, heater, thruster (the module doc gives the order).
    pub(crate) fn checks(&self, now: SimTime) -> Vec<Check> {
        use csp::params::check;
        let th = &self.cfg.thruster;
        let prop = self.propellant_kg(now);
        let load = th.propellant_kg;
        let tm = self.telemetry(now);
        let mut v = Vec::with_capacity(4);
        let share = if load > 0.0 { prop / load } else { 0.0 };
        let detail = format!("{:.0} % of the {load} kg load", share * 100.0);
        v.push(if prop <= 0.0 {
            check(
                "tank",
                Health::Failed,
                prop,
                "kg",
                "empty: FIRE is refused".into(),
            )
        } else if share < LOW_PROPELLANT {
            check(
                "tank",
                Health::Degraded,
                prop,
                "kg",
                format!("low: {detail}"),
            )
        } else {
            check("tank", Health::Ok, prop, "kg", detail)
        });
        v.push(check(
            "tank_pressure",
            Health::Ok,
            th.pressure_kpa(prop),
            "kPa",
            format!(
                "blow-down {:.0} to {:.0} kPa",
                th.full_pressure_kpa,
                th.full_pressure_kpa / th.blowdown_ratio
            ),
        ));
        let state = self.state(now);
        let warm_left_s = f64::from(tm.warmup_left_ms) / 1e3;
        v.push(match state {
            EcuState::Safe => check("heater", Health::Off, 0.0, "s", "disarmed".into()),
            EcuState::Warming => check("heater", Health::Ok, warm_left_s, "s", "warming".into()),
            _ => check("heater", Health::Ok, 0.0, "s", "warm".into()),
        });
        let thrust = f64::from(tm.thrust_n);
        v.push(match state {
            EcuState::Safe => check(
                "thruster",
                Health::Off,
                thrust,
                "N",
                "disarmed, valve closed".into(),
            ),
            EcuState::Firing => check(
                "thruster",
                Health::Ok,
                thrust,
                "N",
                format!("firing, {} ms left", tm.burn_left_ms),
            ),
            s => check(
                "thruster",
                Health::Ok,
                thrust,
                "N",
                format!("{s:?}, valve closed").to_lowercase(),
            ),
        });
        v
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
    use csp::router::Route;
    use csp::{Header, Packet, SimTime};

    use crate::{EcuApp, EcuConfig};

    fn host() -> Host<EcuApp> {
        let mut c = NodeConfig::new("ECU", 5);
        c.ifaces = vec![IfaceConfig::packet("p")];
        c.routes.set_default(Route::direct(0));
        Host::new(c, EcuApp::new(EcuConfig::default()), SimTime::ZERO)
    }

    /// `req` from the ground to `port` at `t`: the one reply's data.
    fn ask_port(h: &mut Host<EcuApp>, port: u8, req: &[u8], t: SimTime) -> Vec<u8> {
        h.handle_packet(
            0,
            Packet::new(Header::new(16, 5, port, 41), req.to_vec()),
            t,
        );
        let out: Vec<Packet> = std::iter::from_fn(|| h.node.poll_transmit())
            .filter_map(|x| match x {
                Transmit::Packet { packet, .. } => Some(packet),
                Transmit::Can { .. } => None,
            })
            .collect();
        assert_eq!(out.len(), 1, "exactly one reply to {req:?}");
        out[0].data.clone()
    }

    fn ask(h: &mut Host<EcuApp>, req: &[u8], t: SimTime) -> Vec<u8> {
        ask_port(h, csp::params::PORT, req, t)
    }

    fn u32_req(cmd: u8, id: Option<u8>, v: u32) -> Vec<u8> {
        let mut r = vec![cmd];
        r.extend(id);
        r.extend_from_slice(&v.to_le_bytes());
        r
    }

    fn u32_reply(cmd: u8, id: u8, v: u32) -> Vec<u8> {
        let mut r = vec![cmd, 1, id, 3];
        r.extend_from_slice(&v.to_le_bytes());
        r
    }

    #[test]
    fn platform_parameters_limit_fire_and_revert_at_reboot_unless_saved() {
        let mut h = host();
        let s = SimTime::from_secs;
        assert_eq!(ask(&mut h, &[1, 1], s(1)), u32_reply(1, 1, 60_000));
        assert_eq!(ask(&mut h, &[1, 2], s(1)), u32_reply(1, 2, 60_000));
        // Longest burn 1 s, no warm-up.
        assert_eq!(
            ask(&mut h, &u32_req(2, Some(1), 1000), s(1)),
            u32_reply(2, 1, 1000)
        );
        assert_eq!(
            ask(&mut h, &u32_req(2, Some(2), 0), s(1)),
            u32_reply(2, 2, 0)
        );
        // Out of range (0 ms, above an hour), wrong size: refused.
        assert_eq!(ask(&mut h, &u32_req(2, Some(1), 0), s(1)), [2, 0]);
        assert_eq!(ask(&mut h, &u32_req(2, Some(2), 3_600_001), s(1)), [2, 0]);
        assert_eq!(ask(&mut h, &[2, 1, 0, 1], s(1)), [2, 0]);
        assert_eq!(ask(&mut h, &[1, 1], s(1)), u32_reply(1, 1, 1000));
        // Their effect: armed and warm at once, a 2 s burn refused, a 1 s one granted.
        assert_eq!(ask_port(&mut h, 10, &[2], s(2)), [2, 1, 0, 0, 0, 0]);
        assert_eq!(ask_port(&mut h, 10, &u32_req(3, None, 2000), s(2)), [3, 0]);
        let r = ask_port(&mut h, 10, &u32_req(3, None, 1000), s(2));
        assert_eq!(r[..6], [3, 1, 0xe8, 3, 0, 0]);
        // A reboot without PSAVE: the factory table.
        h.reboot(s(10));
        assert_eq!(ask(&mut h, &[1, 1], s(10)), u32_reply(1, 1, 60_000));
        assert_eq!(h.app.config().warmup, std::time::Duration::from_secs(60));
        // Saved: kept over the reboot.
        assert_eq!(
            ask(&mut h, &u32_req(2, Some(1), 5000), s(11)),
            u32_reply(2, 1, 5000)
        );
        assert_eq!(ask(&mut h, &[5], s(11)), [5, 1]);
        h.reboot(s(12));
        assert_eq!(ask(&mut h, &[1, 1], s(12)), u32_reply(1, 1, 5000));
        assert_eq!(h.app.config().max_burn, std::time::Duration::from_secs(5));
    }

    #[test]
    fn selftest_reports_tank_heater_and_thruster() {
        let mut h = host();
        let s = SimTime::from_secs;
        let r = ask(&mut h, &[7], s(1));
        assert_eq!(r[..4], [7, 1, 0, 4]);
        assert_eq!(r.len(), 4 + 4 * 5);
        let entry = |r: &[u8], i: usize| {
            let at = 4 + 5 * i;
            (
                r[at],
                f32::from_le_bytes(r[at + 1..at + 5].try_into().unwrap()),
            )
        };
        assert_eq!(entry(&r, 0), (0, 0.5), "full tank");
        assert_eq!(entry(&r, 1), (0, 2200.0));
        assert_eq!(entry(&r, 2), (3, 0.0), "heater off: disarmed");
        assert_eq!(entry(&r, 3), (3, 0.3));
        // Armed: the heater warms (60 s left), the thruster is ready.
        ask_port(&mut h, 10, &[2], s(2));
        let r = ask(&mut h, &[7], s(2));
        assert_eq!(entry(&r, 2), (0, 60.0));
        assert_eq!(entry(&r, 3).0, 0);
    }

    /// The console's `tm` is TMECU of the same instant, one `name value unit` line per field
    /// with the ICD's names, units and state names.
    #[test]
    fn console_tm_is_tmecu_one_field_a_line() {
        let mut h = host();
        let s = SimTime::from_secs;
        assert_eq!(ask_port(&mut h, 10, &[2], s(1))[..2], [2, 1]);
        let text = h.console("tm", s(2));
        let r = ask_port(&mut h, 10, &[1], s(2));
        let tm = <crate::wire::TmEcu as csp::reqrep::le::Repr>::parse(&r[2..]).unwrap();
        let fields = <crate::wire::TmEcu as csp::icd::Describe>::FIELDS;
        let names: Vec<&str> = fields.iter().map(|f| f.name).collect();
        let got: Vec<&str> = text.lines().filter_map(|l| l.split(' ').next()).collect();
        assert_eq!(got, names, "{text}");
        for want in [
            "state 1 (warming)".to_owned(),
            "heater 1 (on)".to_owned(),
            format!("warmup_left_ms {} ms", tm.warmup_left_ms),
            format!("propellant_kg {} kg", tm.propellant_kg),
            format!("tank_pressure_kpa {} kPa", tm.tank_pressure_kpa),
            format!("total_impulse_n_s {} N s", tm.total_impulse_n_s),
        ] {
            assert!(text.lines().any(|l| l == want), "{want:?} in\n{text}");
        }
    }
}
