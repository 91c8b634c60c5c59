//! Propulsion unit (ECU, CSP 5): one thruster along body +Z with a blow-down tank
//! ([`thruster`]), armed, fired and safed on port 10 ([`wire`]).
//!
//! [`EcuApp`] is a pure core ([`csp::node::App`]) driven by packets and one timer (the end
//! of a burn, and the end of the warm-up for its log line).
//!
//! # States and commands (docs/protocol.md, "ECU port")
//! - **SAFE** after boot: heaters off. `ARM` switches the heaters on (the catalyst-bed
//!   preheat of a monopropellant thruster) and starts the warm-up ([`EcuConfig::warmup`],
//!   60 s by default); ARM when already armed changes nothing.
//! - **WARMING** until the warm-up is over, then **ARMED**: `FIRE duration_ms` is accepted
//!   only now, with 1 ms <= duration <= [`EcuConfig::max_burn`] (60 s by default) and
//!   propellant left; a burn that would need more propellant than is left is shortened to
//!   what is left (the reply gives the granted duration). FIRE while firing is refused.
//! - **FIRING** for the granted duration, then back to ARMED (heaters stay on).
//! - `SAFE` at any time: stops a burn at once, heaters off, disarmed.
//!
//! Refused and malformed requests get the failure reply `cmd | 00` and a log line, and are
//! counted in TMECU.
//!
//! # The burn reaches the true orbit
//! A FIRE at `now` posts a [`Burn`] `{ posted: now, start: now, end: now +
//! granted, thrust_n, mass_flow_kg_s, mass_kg: dry + propellant, dir_body: +Z }` on the
//! [`BurnBoard`] the twin gives ([`EcuApp::with_burns`]); the FC applies it to the true
//! orbit. SAFE during a burn re-posts it with `end = now` and its original `posted`,
//! so that the FC, which integrates thrust up to each tick from the burns posted strictly
//! before the tick, gets the same answer whichever of the two nodes runs first at an
//! instant. The [`ActivityBoard`] ([`EcuApp::with_activity`]) gets
//! [`Activity::ThrusterHeater`] on from ARM to SAFE (or power loss) and [`Activity::Firing`]
//! from the start to the end of each burn (the EPS charges their power).
//!
//! # Bookkeeping
//! Thrust and mass flow are fixed for a burn at its start (the tank pressure then); the
//! propellant falls by `mass_flow x duration` (TMECU reports it falling during the burn),
//! the total impulse grows by `thrust x duration`.
//!
//! # Reboot and power loss
//! The tank's contents are physical and survive anything; the burn count, the last burn's
//! duration and the total impulse are kept in non-volatile memory and survive too. The
//! rest is volatile: the ECU comes back SAFE (heaters off, not armed, refusal counter 0).
//! A burn in progress stops at the instant power goes: the node's task calls
//! [`App::power_lost`], and the ECU charges the burn up to then, re-posts it with that end
//! and switches its heater and firing activities off there (the EPS stops charging them).
//! A software reboot while firing cuts the burn at the reboot the same way
//! ([`App::reset`]). The running parameters (the longest burn, the warm-up) return at boot
//! to the saved table (PSAVE) or the factory defaults.
//!
//! # Platform port 14
//! The parameter table and self-test of [`config`] (`csp::params`).

pub mod config;
pub mod thruster;
pub use icd::ecu as wire;

use std::time::Duration;

use csp::node::{App, Node, NodeEvent, Outbox};
use csp::reqrep::{RESULT_FAILURE, RESULT_SUCCESS, serve};
use csp::{Packet, SimTime};
use platform::board::{Activity, ActivityBoard, Burn, BurnBoard};

pub use crate::thruster::{ThrusterConfig, ThrusterConfigError};
use crate::wire::{ArmReply, EcuCommand, FireReply, Repr};
pub use crate::wire::{EcuState, TmEcu};

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[wire::PORT_ECU];

/// Default longest burn: a minute, 18 N s at the full-tank thrust (the twin's choice: long
/// enough for a few m/s of delta-v per command, short enough that a lost SAFE cannot empty
/// the tank).
pub const DEFAULT_MAX_BURN: Duration = Duration::from_secs(60);

/// Default warm-up from ARM to FIRE allowed: a minute (the twin's choice; a real catalyst
/// bed preheats for many minutes; scenarios set their own).
pub const DEFAULT_WARMUP: Duration = Duration::from_secs(60);

/// What the ECU needs from the scenario (fixed for the run).
#[derive(Debug, Clone, PartialEq)]
pub struct EcuConfig {
    /// Thruster, tank and dry mass.
    pub thruster: ThrusterConfig,
    /// Longest burn one FIRE may ask for.
    pub max_burn: Duration,
    /// Heater warm-up from ARM until FIRE is accepted.
    pub warmup: Duration,
    /// The telemetry and control port (10).
    pub port: u8,
}

impl Default for EcuConfig {
    fn default() -> Self {
        EcuConfig {
            thruster: ThrusterConfig::default(),
            max_burn: DEFAULT_MAX_BURN,
            warmup: DEFAULT_WARMUP,
            port: wire::PORT_ECU,
        }
    }
}

/// What is wrong with an ECU configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EcuConfigError {
    /// The thruster's figures.
    #[error(transparent)]
    Thruster(#[from] ThrusterConfigError),
    /// A burn limit the 32-bit millisecond field cannot hold, or zero.
    #[error("ECU max_burn {max_burn:?}: must be between 1 ms and 2^32 ms")]
    MaxBurn {
        /// The limit.
        max_burn: Duration,
    },
    /// The ECU's port is in the ephemeral range.
    #[error("ECU port {port}: must be below 32")]
    Port {
        /// The port.
        port: u8,
    },
}

impl EcuConfig {
    /// Check the configuration (for the scenario loader); the message names the problem.
    pub fn validate(&self) -> Result<(), EcuConfigError> {
        self.thruster.validate()?;
        if self.max_burn < Duration::from_millis(1)
            || self.max_burn.as_millis() > u128::from(u32::MAX)
        {
            return Err(EcuConfigError::MaxBurn {
                max_burn: self.max_burn,
            });
        }
        if self.port >= csp::header::EPHEMERAL_PORT_MIN {
            return Err(EcuConfigError::Port { port: self.port });
        }
        Ok(())
    }
}

/// What the ECU tells the twin (for the record and the expectations).
#[derive(Debug, Clone, PartialEq)]
pub enum EcuOutput {
    /// ARM accepted from SAFE: heaters on.
    Armed {
        /// When.
        t: SimTime,
    },
    /// A burn started (as posted on the board).
    BurnStarted {
        /// When.
        t: SimTime,
        /// The burn.
        burn: Burn,
    },
    /// A burn ended (its planned end, SAFE, or a reboot).
    BurnEnded {
        /// When it ended.
        t: SimTime,
        /// Its start.
        start: SimTime,
        /// Whether it was cut short (SAFE, reboot, power loss).
        cut: bool,
        /// Propellant used, kg.
        propellant_used_kg: f64,
        /// Impulse delivered, N s.
        impulse_n_s: f64,
    },
    /// SAFE: heaters off, disarmed.
    Safed {
        /// When.
        t: SimTime,
    },
    /// The run ended ([`App::finish`]): the final telemetry.
    Final {
        /// When.
        t: SimTime,
        /// TMECU at the end.
        telemetry: TmEcu,
    },
}

/// A burn in progress.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Firing {
    start: SimTime,
    end: SimTime,
    burn: Burn,
}

/// The ECU's application (see the module doc).
#[derive(Debug)]
pub struct EcuApp {
    cfg: EcuConfig,
    burn_board: Option<BurnBoard>,
    activity: Option<ActivityBoard>,
    out: Outbox<EcuOutput>,
    // --- physical and non-volatile (survive reboots) ---
    propellant_kg: f64,
    total_impulse_n_s: f64,
    burns: u32,
    last_burn_ms: u32,
    // --- volatile ---
    armed_at: Option<SimTime>,
    ready_logged: bool,
    firing: Option<Firing>,
    refused: u32,
    log: Vec<NodeEvent>,
}

impl EcuApp {
    /// An ECU with a full tank. An invalid configuration is replaced by the default (with a
    /// log line), never a panic; the scenario loader checks [`EcuConfig::validate`] first.
    pub fn new(cfg: EcuConfig) -> Self {
        let mut log = Vec::new();
        let cfg = match cfg.validate() {
            Ok(()) => cfg,
            Err(why) => {
                log.push(NodeEvent::info(
                    SimTime::ZERO,
                    format!("ecu: config: {why}; using the default"),
                ));
                EcuConfig::default()
            }
        };
        EcuApp {
            propellant_kg: cfg.thruster.propellant_kg,
            cfg,
            burn_board: None,
            activity: None,
            out: Outbox::default(),
            total_impulse_n_s: 0.0,
            burns: 0,
            last_burn_ms: 0,
            armed_at: None,
            ready_logged: false,
            firing: None,
            refused: 0,
            log,
        }
    }

    /// Post burns on `b` (the FC takes them from there).
    pub fn with_burns(mut self, b: BurnBoard) -> Self {
        self.burn_board = Some(b);
        self
    }

    /// Post heater and firing switches on `a` (the EPS reads them).
    pub fn with_activity(mut self, a: ActivityBoard) -> Self {
        self.activity = Some(a);
        self
    }

    /// The configuration in use.
    pub fn config(&self) -> &EcuConfig {
        &self.cfg
    }

    /// Propellant left at `now`, kg (falling during a burn).
    pub fn propellant_kg(&self, now: SimTime) -> f64 {
        match &self.firing {
            Some(f) => {
                let dt_s = (now.min(f.end)).saturating_since(f.start).as_secs_f64();
                (self.propellant_kg - f.burn.mass_flow_kg_s * dt_s).max(0.0)
            }
            None => self.propellant_kg,
        }
    }

    /// Total impulse delivered by finished burns, N s.
    pub fn total_impulse_n_s(&self) -> f64 {
        self.total_impulse_n_s
    }

    /// The burn in progress, as posted.
    pub fn current_burn(&self) -> Option<Burn> {
        self.firing.map(|f| f.burn)
    }

    /// The state at `now`.
    pub fn state(&self, now: SimTime) -> EcuState {
        match (self.firing, self.armed_at) {
            (Some(_), _) => EcuState::Firing,
            (None, None) => EcuState::Safe,
            (None, Some(a)) if now < a + self.cfg.warmup => EcuState::Warming,
            (None, Some(_)) => EcuState::Armed,
        }
    }

    /// TMECU at `now`.
    pub fn telemetry(&self, now: SimTime) -> TmEcu {
        let prop = self.propellant_kg(now);
        let th = &self.cfg.thruster;
        let thrust = match &self.firing {
            Some(f) => f.burn.thrust_n,
            None => th.thrust_at_n(prop),
        };
        let ms = |d: Duration| u32::try_from(d.as_millis()).unwrap_or(u32::MAX);
        TmEcu {
            state: self.state(now).to_u8(),
            heater: u8::from(self.armed_at.is_some()),
            warmup_left_ms: self
                .armed_at
                .map_or(0, |a| ms((a + self.cfg.warmup).saturating_since(now))),
            burn_left_ms: self.firing.map_or(0, |f| ms(f.end.saturating_since(now))),
            propellant_kg: prop as f32,
            tank_pressure_kpa: th.pressure_kpa(prop) as f32,
            thrust_n: thrust as f32,
            mass_kg: (th.dry_mass_kg + prop) as f32,
            total_impulse_n_s: self.total_impulse_n_s as f32,
            burns: self.burns,
            last_burn_ms: self.last_burn_ms,
            refused: self.refused,
        }
    }

    fn emit(&mut self, o: EcuOutput) {
        self.out.push(o);
    }

    fn set_activity(&mut self, what: Activity, t: SimTime, on: bool) {
        if let Some(a) = &self.activity
            && let Err(e) = a.set(what, t, on)
        {
            self.log.push(NodeEvent::warning(
                t,
                format!("ecu: activity {what:?}: {e}"),
            ));
        }
    }

    /// End the burn in progress at `end` (its planned end or earlier), charge it, and
    /// re-post it if it was cut short.
    fn end_burn(&mut self, end: SimTime) {
        let Some(f) = self.firing.take() else {
            return;
        };
        let end = end.clamp(f.start, f.end);
        let cut = end < f.end;
        let dur = end.saturating_since(f.start);
        let used = (f.burn.mass_flow_kg_s * dur.as_secs_f64()).min(self.propellant_kg);
        let impulse = f.burn.thrust_n * dur.as_secs_f64();
        self.propellant_kg = (self.propellant_kg - used).max(0.0);
        self.total_impulse_n_s += impulse;
        self.last_burn_ms = u32::try_from(dur.as_millis()).unwrap_or(u32::MAX);
        if cut
            && let Some(b) = &self.burn_board
            && let Err(e) = b.post(Burn { end, ..f.burn })
        {
            // The original `posted`: see the module doc.
            self.log.push(NodeEvent::warning(
                end,
                format!("ecu: cutting the burn: {e}"),
            ));
        }
        self.set_activity(Activity::Firing, end, false);
        self.log.push(NodeEvent::info(
            end,
            format!(
                "ecu: burn {} after {} ms: {:.3} g used, {:.3} N s, {:.4} kg left",
                if cut { "cut" } else { "ended" },
                self.last_burn_ms,
                used * 1e3,
                impulse,
                self.propellant_kg
            ),
        ));
        self.emit(EcuOutput::BurnEnded {
            t: end,
            start: f.start,
            cut,
            propellant_used_kg: used,
            impulse_n_s: impulse,
        });
    }

    fn refuse(&mut self, now: SimTime, why: String) -> Result<Vec<u8>, u8> {
        self.log
            .push(NodeEvent::info(now, format!("ecu: refused: {why}")));
        Err(RESULT_FAILURE)
    }

    fn command(&mut self, c: EcuCommand, now: SimTime) -> Result<Vec<u8>, u8> {
        match c {
            EcuCommand::Telemetry => Ok(self.telemetry(now).to_vec()),
            EcuCommand::Arm => {
                if self.armed_at.is_none() {
                    self.armed_at = Some(now);
                    self.ready_logged = false;
                    self.set_activity(Activity::ThrusterHeater, now, true);
                    self.log.push(NodeEvent::info(
                        now,
                        format!("ecu: armed, warm-up {:?}", self.cfg.warmup),
                    ));
                    self.emit(EcuOutput::Armed { t: now });
                }
                Ok(ArmReply {
                    warmup_left_ms: self.telemetry(now).warmup_left_ms,
                }
                .to_vec())
            }
            EcuCommand::Fire(req) => self.fire(req.duration_ms, now),
            EcuCommand::Safe => {
                if self.firing.is_some() {
                    self.end_burn(now);
                }
                if self.armed_at.take().is_some() {
                    self.set_activity(Activity::ThrusterHeater, now, false);
                    self.log.push(NodeEvent::info(now, "ecu: safe".to_owned()));
                    self.emit(EcuOutput::Safed { t: now });
                }
                Ok(Vec::new())
            }
        }
    }

    fn fire(&mut self, duration_ms: u32, now: SimTime) -> Result<Vec<u8>, u8> {
        match self.state(now) {
            EcuState::Armed => {}
            s => return self.refuse(now, format!("FIRE {duration_ms} ms in state {s:?}")),
        }
        let max_ms = self.cfg.max_burn.as_millis();
        if u128::from(duration_ms) > max_ms {
            return self.refuse(
                now,
                format!("FIRE {duration_ms} ms longer than the maximum {max_ms} ms"),
            );
        }
        let th = self.cfg.thruster;
        let thrust_n = th.thrust_at_n(self.propellant_kg);
        let mdot = th.mass_flow_kg_s(thrust_n);
        // Whole milliseconds the propellant lasts (floor: the tank never goes negative).
        let lasts_ms = if mdot > 0.0 {
            (self.propellant_kg / mdot * 1e3).floor()
        } else {
            0.0
        };
        let granted_ms = (f64::from(duration_ms).min(lasts_ms)).max(0.0) as u32;
        if granted_ms == 0 {
            return self.refuse(
                now,
                format!(
                    "FIRE {duration_ms} ms: tank empty ({} kg)",
                    self.propellant_kg
                ),
            );
        }
        let end = now + Duration::from_millis(u64::from(granted_ms));
        let burn = Burn {
            posted: now,
            start: now,
            end,
            thrust_n,
            mass_flow_kg_s: mdot,
            mass_kg: th.dry_mass_kg + self.propellant_kg,
            dir_body: th.dir_unit_body(),
        };
        if let Some(b) = &self.burn_board
            && let Err(e) = b.post(burn)
        {
            self.log.push(NodeEvent::warning(
                now,
                format!("ecu: posting the burn: {e}"),
            ));
        }
        self.set_activity(Activity::Firing, now, true);
        self.firing = Some(Firing {
            start: now,
            end,
            burn,
        });
        self.burns = self.burns.saturating_add(1);
        self.log.push(NodeEvent::info(
            now,
            format!(
                "ecu: FIRE {granted_ms} ms (asked {duration_ms}): {thrust_n:.4} N, {:.3e} kg/s, mass {:.4} kg",
                mdot, burn.mass_kg
            ),
        ));
        self.emit(EcuOutput::BurnStarted { t: now, burn });
        Ok(FireReply {
            granted_ms,
            thrust_n: thrust_n as f32,
        }
        .to_vec())
    }

    fn next_due(&self) -> Option<SimTime> {
        let ready = self
            .armed_at
            .filter(|_| !self.ready_logged)
            .map(|a| a + self.cfg.warmup);
        match (self.firing.map(|f| f.end), ready) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn flush_log(&mut self, node: &mut Node) {
        for e in self.log.drain(..) {
            node.push_event(e);
        }
    }
}

impl App for EcuApp {
    type Event = EcuOutput;
    fn poll_event(&mut self) -> Option<EcuOutput> {
        self.out.pop()
    }
    fn start(&mut self, node: &mut Node, _now: SimTime) {
        node.bind(self.cfg.port);
        self.flush_log(node);
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        if packet.header.dport != self.cfg.port {
            return;
        }
        // A payload may read the ECU's telemetry, never arm or fire it (ICD 4.1).
        let open = [wire::cmd::TMECU];
        let (reply, malformed) = match csp::node::payload_refusal(node, &packet, &open, now) {
            Some(r) => (r, None),
            None => serve::<EcuCommand>(&packet.data, |c| self.command(c, now)),
        };
        if let Some(e) = malformed {
            self.log
                .push(NodeEvent::info(now, format!("ecu: request refused: {e}")));
        }
        if reply.get(1) != Some(&RESULT_SUCCESS) {
            self.refused = self.refused.saturating_add(1);
        }
        // A send failure is already counted by the node.
        let _ = node.send(Packet::new(packet.header.reply(node.addr()), reply), now);
        self.flush_log(node);
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        self.next_due()
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        if let Some(f) = self.firing
            && f.end <= now
        {
            self.end_burn(f.end);
        }
        if let Some(a) = self.armed_at
            && !self.ready_logged
            && a + self.cfg.warmup <= now
        {
            self.ready_logged = true;
            self.log.push(NodeEvent::info(
                a + self.cfg.warmup,
                "ecu: warm, ready to fire".to_owned(),
            ));
        }
        self.flush_log(node);
    }

    fn power_lost(&mut self, node: &mut Node, now: SimTime) {
        // The valves close and the heaters go cold at the instant power goes.
        let firing = self.firing.is_some();
        self.end_burn(now);
        if self.armed_at.take().is_some() {
            self.set_activity(Activity::ThrusterHeater, now, false);
        }
        self.log.push(NodeEvent::info(
            now,
            format!(
                "ecu: power lost{}: heaters off",
                if firing { ", burn cut" } else { "" }
            ),
        ));
        self.flush_log(node);
    }

    fn params(&mut self) -> Option<&mut dyn csp::params::Table> {
        Some(self)
    }

    fn console_commands(&self) -> &'static [csp::console::Command] {
        &[csp::console::TM]
    }

    fn console(
        &mut self,
        _node: &mut Node,
        words: &[&str],
        now: SimTime,
    ) -> Result<String, csp::console::ConsoleError> {
        use csp::console::ConsoleError;
        if words != ["tm"] {
            return Err(ConsoleError::Usage("tm".to_owned()));
        }
        let bytes = self
            .command(EcuCommand::Telemetry, now)
            .map_err(|_| ConsoleError::Refused("TMECU"))?;
        Ok(csp::console::lines(
            <wire::TmEcu as csp::icd::Describe>::FIELDS,
            &bytes,
        )?)
    }

    fn self_test(&mut self, _node: &Node, now: SimTime) -> Vec<csp::params::Check> {
        self.checks(now)
    }

    fn reset(&mut self, now: SimTime) {
        // A software reboot while firing cuts the burn at the reboot (a loss of power has
        // already ended it, in `power_lost`).
        self.end_burn(now);
        if self.armed_at.take().is_some() {
            self.set_activity(Activity::ThrusterHeater, now, false);
        }
        self.ready_logged = false;
        self.refused = 0;
        self.log.push(NodeEvent::info(
            now,
            format!(
                "ecu: boot: SAFE, {:.4} kg propellant, {} burns, {:.3} N s so far",
                self.propellant_kg, self.burns, self.total_impulse_n_s
            ),
        ));
    }

    fn finish(&mut self, node: &mut Node, now: SimTime) {
        let telemetry = self.telemetry(now);
        self.log.push(NodeEvent::info(
            now,
            format!(
                "ecu: final: {:.4} kg propellant, {} burns, {:.3} N s",
                telemetry.propellant_kg, telemetry.burns, telemetry.total_impulse_n_s
            ),
        ));
        self.emit(EcuOutput::Final { t: now, telemetry });
        self.flush_log(node);
    }
}

/// The ECU with the default configuration ([`EcuConfig::default`]), not wired to any board.
pub fn app() -> EcuApp {
    EcuApp::new(EcuConfig::default())
}

// What a snapshot keeps of the ECU (docs/snapshots.md): its configuration (the parameters
// change it), the propellant and the burns so far, an arming or a firing under way; the
// boards are the run's.
snap::fields!(EcuConfig {
    thruster,
    max_burn,
    warmup,
    port
});
snap::fields!(Firing { start, end, burn });
snap::fields!(EcuApp {
    cfg,
    out,
    propellant_kg,
    total_impulse_n_s,
    burns,
    last_burn_ms,
    armed_at,
    ready_logged,
    firing,
    refused,
    log;
    skip burn_board, activity
});
