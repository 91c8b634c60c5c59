//! Electrical power system (CSP 4): solar arrays, battery, loads, switched power channels
//! and low-battery protection, with its telemetry and control on port 10.
//!
//! [`EpsApp`] is a pure core ([`csp::node::App`]) driven by packets and timers; the physics
//! is [`eps::Eps`], built from [`solar`], [`battery`], [`loads`] and [`protect`] (each
//! module's doc gives its model, defaults and sources).
//!
//! # Time
//! The EPS integrates energy over intervals of integer simulated time: at every tick
//! (default 1 s, on multiples of the tick since the run start), and also up to the instant
//! of every request, scenario event and reboot, so that a channel switched between ticks
//! draws exactly until the switch. Over an interval `[t0, t1)` the inputs are held:
//! - the FC's truth `TruthBoard::latest_before(t1)`: sun direction in the body frame (from
//!   `q_eci_from_body`), visible fraction of the sun (eclipse), wheel speeds, magnetorquer
//!   dipoles. With no truth yet (no board, or nothing published before `t1`) the arrays
//!   give nothing (as in umbra), the wheels are at rest and the magnetorquers off;
//! - the activity duties `ActivityBoard::duty(what, t0, t1)`: S-band and UHF transmitting,
//!   thruster heaters, firing, and the time a power fault held each switched node off
//!   (`Activity::PowerFault`: the node draws nothing meanwhile, whatever its channel says);
//! - the channel states (a channel switched off draws nothing).
//!
//! At each tick, after the integration, the protection compares the state of charge with
//! its thresholds ([`protect`]) and the EPS hands the twin an [`EpsOutput::Sample`]; every
//! channel switch (command, scenario, protection) is an [`EpsOutput::Channel`]: the twin
//! powers the node off (it leaves its bus, its state is lost) or on (it boots, uptime from
//! zero). At its first boot the EPS reports every channel configured off, so that the twin
//! starts those nodes unpowered.
//!
//! # Reboot
//! The battery and the channel states are physical, and the protection's memory is
//! non-volatile: all survive an EPS reboot ([`App::reset`]), and the energy is integrated
//! up to the reboot. Volatile: the energy counters of TMEPS (from zero), the
//! refused-request counter, and the running parameters: thresholds set by THRSET or PSET
//! and the charge limit return at boot to the saved parameter table (PSAVE) or the
//! factory defaults ([`config`]).
//!
//! # Port 10
//! TMEPS 1, CHGET 2, CHSET 3, THRGET 4, THRSET 5 ([`wire`] has the layouts and sizes).
//!
//! # Platform port 14
//! The parameter table and self-test of [`config`] (`csp::params`): the thresholds are the
//! same values THRGET reads and THRSET sets.

pub mod battery;
pub mod config;
pub mod eps;
pub mod loads;
pub mod protect;
pub mod solar;
pub use icd::eps as wire;

use std::time::Duration;

use csp::node::{App, Node, NodeEvent, Outbox};
use csp::reqrep::serve;
use csp::{Packet, SimTime};
use platform::board::{Activity, ActivityBoard, TruthBoard};

pub use crate::battery::{Battery, BatteryConfig, BatteryConfigError};
pub use crate::eps::{Eps, EpsInputs, StepState, SwitchRefused};
pub use crate::loads::{ALL_CHANNELS, CHANNELS, Channel, Duties, LoadConfig, LoadInputs};
pub use crate::protect::{Group, Protection, Thresholds};
pub use crate::solar::{Panel, SolarArray, SolarConfigError, SunInput};
use crate::wire::{EpsCommand, Repr};

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[wire::PORT_EPS];

/// Default EPS tick.
pub const DEFAULT_TICK: Duration = Duration::from_secs(1);
/// Default initial state of charge (a battery charged before launch, after some days of
/// commissioning).
pub const DEFAULT_INITIAL_SOC: f64 = 0.8;
/// Bound on the timer steps of one `handle_timeout` call (work left over runs at the next).
const MAX_STEPS: usize = 1 << 20;

/// Something a scenario does to the EPS at a time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EpsEvent {
    /// Switch a channel, as CHSET would (refused while its group is shed).
    Channel {
        /// The channel.
        channel: Channel,
        /// On or off.
        on: bool,
    },
    /// Set the state of charge (0..=1).
    SetSoc(f64),
    /// Panel `i` (index in [`SolarArray::panels`]) fails: it gives nothing.
    PanelFail(usize),
    /// Panel `i` works again.
    PanelRestore(usize),
    /// The battery loses this fraction (0..1) of its capacity, for good
    /// ([`Battery::fade`]).
    BatteryFade(f64),
    /// The channel's switch stops obeying commands (CHSET and the scenario's channel
    /// events) in whatever state it is; the protection still sheds and restores it. Holds
    /// compose: the switch obeys again when every hold is freed.
    ChannelStuck(Channel),
    /// One hold of [`EpsEvent::ChannelStuck`] on the channel ends.
    ChannelFreed(Channel),
}

/// An [`EpsEvent`] at a simulated time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedEpsEvent {
    /// When.
    pub at: SimTime,
    /// What.
    pub event: EpsEvent,
}

/// What the EPS needs from the scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct EpsConfig {
    /// The solar arrays.
    pub panels: SolarArray,
    /// The battery.
    pub battery: BatteryConfig,
    /// Consumption of every node by state.
    pub loads: LoadConfig,
    /// Protection thresholds at boot.
    pub thresholds: Thresholds,
    /// State of charge at the start of the run, 0..=1.
    pub initial_soc: f64,
    /// EPS tick (integration, protection and samples).
    pub tick: Duration,
    /// Channels on at the start of the run (mask, bit = [`Channel::id`]).
    pub channels_on: u16,
    /// Port of telemetry and control (10).
    pub port: u8,
    /// Scenario events (sorted by time when the app is built).
    pub timeline: Vec<TimedEpsEvent>,
}

impl Default for EpsConfig {
    /// The default 6U arrays, the 77 Wh battery, the load table, thresholds 30/40 and
    /// 20/30 %, 80 % charged, 1 s tick, every channel on.
    fn default() -> Self {
        EpsConfig {
            panels: SolarArray::default(),
            battery: BatteryConfig::default(),
            loads: LoadConfig::default(),
            thresholds: Thresholds::default(),
            initial_soc: DEFAULT_INITIAL_SOC,
            tick: DEFAULT_TICK,
            channels_on: ALL_CHANNELS,
            port: wire::PORT_EPS,
            timeline: Vec::new(),
        }
    }
}

/// What is wrong with an EPS configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EpsConfigError {
    /// The solar array's geometry.
    #[error(transparent)]
    Solar(#[from] SolarConfigError),
    /// The battery's figures.
    #[error(transparent)]
    Battery(#[from] BatteryConfigError),
    /// Load-shedding thresholds that break THRSET's rule (the threshold named).
    #[error("thresholds: {0}")]
    Thresholds(&'static str),
    /// An initial state of charge outside 0..=1.
    #[error("initial soc {initial_soc} not in 0..=1")]
    InitialSoc {
        /// The fraction given.
        initial_soc: f64,
    },
    /// A zero integration step.
    #[error("EPS tick 0")]
    ZeroTick,
    /// Channels switched on that the EPS does not have.
    #[error("channels_on {channels_on:#06x} has bits past channel {}", CHANNELS - 1)]
    ChannelsOn {
        /// The channel mask.
        channels_on: u16,
    },
    /// The EPS's port is in the ephemeral range.
    #[error("EPS port {port} must be below 32")]
    Port {
        /// The port.
        port: u8,
    },
}

impl EpsConfig {
    /// Check the configuration (for the scenario loader); the error names the problem.
    pub fn validate(&self) -> Result<(), EpsConfigError> {
        self.panels.validate()?;
        self.battery.validate()?;
        self.thresholds
            .validate()
            .map_err(EpsConfigError::Thresholds)?;
        if !(0.0..=1.0).contains(&self.initial_soc) {
            return Err(EpsConfigError::InitialSoc {
                initial_soc: self.initial_soc,
            });
        }
        if self.tick.is_zero() {
            return Err(EpsConfigError::ZeroTick);
        }
        if self.channels_on & !ALL_CHANNELS != 0 {
            return Err(EpsConfigError::ChannelsOn {
                channels_on: self.channels_on,
            });
        }
        if self.port >= csp::header::EPHEMERAL_PORT_MIN {
            return Err(EpsConfigError::Port { port: self.port });
        }
        Ok(())
    }
}

/// Why a channel switched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwitchCause {
    /// Configured off at the start of the run (reported once, at the first boot).
    Initial,
    /// CHSET.
    Command,
    /// A scenario event.
    Timeline,
    /// The protection shed it.
    Shed(Group),
    /// The protection restored it.
    Restore(Group),
}

/// What the EPS tells the twin.
#[derive(Debug, Clone, PartialEq)]
pub enum EpsOutput {
    /// The state after each tick.
    Sample {
        /// When (a tick).
        t: SimTime,
        /// State of charge, 0..=1.
        soc: f64,
        /// Battery terminal voltage, V.
        battery_v: f64,
        /// Battery current, A (positive charging).
        battery_a: f64,
        /// Array power available, W.
        solar_w: f64,
        /// Total load, W.
        load_w: f64,
        /// Power of each panel, W.
        panels_w: Vec<f64>,
        /// Channels on (bit = [`Channel::id`]).
        channels: u16,
    },
    /// A channel switched: the twin powers the node(s) on or off.
    Channel {
        /// When.
        t: SimTime,
        /// Which.
        channel: Channel,
        /// On or off.
        on: bool,
        /// Why.
        cause: SwitchCause,
    },
}

/// The EPS's application (see the module doc).
#[derive(Debug)]
pub struct EpsApp {
    cfg: EpsConfig,
    eps: Eps,
    truth: Option<TruthBoard>,
    activity: Option<ActivityBoard>,
    out: Outbox<EpsOutput>,
    /// The power system is integrated up to here.
    last_t: SimTime,
    next_tick: SimTime,
    timeline_next: usize,
    booted: bool,
    cut_off: bool,
    refused: u64,
    /// Between a reset and the start: the boot applies the parameter table, whose values
    /// are taken whole ([`config`]).
    booting: bool,
    /// Holds of [`EpsEvent::ChannelStuck`] on each channel (by [`Channel::id`]): a fault of
    /// the switch, so an EPS reboot keeps them.
    stuck: [u16; CHANNELS],
    log: Vec<NodeEvent>,
}

impl EpsApp {
    /// An EPS with `cfg` (the timeline is sorted; a zero tick is taken as 1 s).
    pub fn new(mut cfg: EpsConfig) -> Self {
        cfg.timeline.sort_by_key(|e| e.at);
        if cfg.tick.is_zero() {
            cfg.tick = DEFAULT_TICK;
        }
        EpsApp {
            eps: Eps::new(&cfg),
            cfg,
            truth: None,
            activity: None,
            out: Outbox::default(),
            last_t: SimTime::ZERO,
            next_tick: SimTime::ZERO,
            timeline_next: 0,
            booted: false,
            cut_off: false,
            refused: 0,
            booting: true,
            stuck: [0; CHANNELS],
            log: Vec::new(),
        }
    }

    /// Read the FC's truth from `b`.
    pub fn with_truth(mut self, b: TruthBoard) -> Self {
        self.truth = Some(b);
        self
    }
    /// Read the activity duties from `b`.
    pub fn with_activity(mut self, b: ActivityBoard) -> Self {
        self.activity = Some(b);
        self
    }

    /// The configuration in use.
    pub fn config(&self) -> &EpsConfig {
        &self.cfg
    }
    /// The power system.
    pub fn eps(&self) -> &Eps {
        &self.eps
    }
    /// Requests refused since boot.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    fn emit(&mut self, o: EpsOutput) {
        self.out.push(o);
    }

    fn flush_log(&mut self, node: &mut Node) {
        for e in self.log.drain(..) {
            node.push_event(e);
        }
    }

    fn next_tick_after(&self, now: SimTime) -> SimTime {
        let tick = self.cfg.tick.as_nanos().max(1);
        let k = u128::from(now.as_ns()) / tick + 1;
        SimTime::from_ns(u64::try_from(k * tick).unwrap_or(u64::MAX))
    }

    /// Integrate the power system up to `to`.
    fn advance(&mut self, to: SimTime) {
        if to <= self.last_t {
            return;
        }
        let (t0, t1) = (self.last_t, to);
        let truth = self.truth.as_ref().and_then(|b| b.latest_before(t1));
        let duties = match &self.activity {
            Some(a) => Duties {
                sband_tx: a.duty(Activity::SbandTx, t0, t1),
                uhf_tx: a.duty(Activity::UhfTx, t0, t1),
                uhf_tx_secondary: a.duty(Activity::UhfTxSecondary, t0, t1),
                thruster_heater: a.duty(Activity::ThrusterHeater, t0, t1),
                firing: a.duty(Activity::Firing, t0, t1),
                fault_off: Channel::ALL.map(|c| {
                    c.node_addr()
                        .map_or(0.0, |addr| a.duty(Activity::PowerFault(addr), t0, t1))
                }),
            },
            None => Duties::default(),
        };
        let x = EpsInputs::from_truth(truth.as_ref(), duties);
        let unmet_w = self
            .eps
            .step((t1 - t0).as_nanos() as u64, &x)
            .battery
            .unmet_w;
        self.last_t = to;
        let cut_off = unmet_w > 0.0;
        if cut_off != self.cut_off {
            self.cut_off = cut_off;
            self.log.push(NodeEvent::info(
                to,
                if cut_off {
                    format!("eps: battery empty: {unmet_w:.2} W of load unsupplied")
                } else {
                    "eps: loads supplied again".to_owned()
                },
            ));
        }
    }

    fn switched(&mut self, t: SimTime, channel: Channel, on: bool, cause: SwitchCause) {
        self.log.push(NodeEvent::info(
            t,
            format!(
                "eps: channel {} {} ({cause:?}, soc {:.1} %)",
                channel.name(),
                if on { "on" } else { "off" },
                self.eps.soc() * 100.0
            ),
        ));
        self.emit(EpsOutput::Channel {
            t,
            channel,
            on,
            cause,
        });
    }

    /// Whether `channel`'s switch ignores commands now.
    pub fn is_stuck(&self, channel: Channel) -> bool {
        self.stuck
            .get(usize::from(channel.id()))
            .is_some_and(|&n| n > 0)
    }

    /// Switch a channel for a command or a scenario event; `false` if refused.
    fn switch(&mut self, t: SimTime, channel: Channel, on: bool, cause: SwitchCause) -> bool {
        // A stuck switch is not refused: the EPS drives it, it does not move, and the
        // reply's channel states say so. The protection's refusal comes first, as it
        // would for a working switch.
        if self.is_stuck(channel)
            && self.eps.is_on(channel) != on
            && (!on || self.eps.protection().allows_on(channel))
        {
            let state = |on: bool| if on { "on" } else { "off" };
            self.log.push(NodeEvent::warning(
                t,
                format!(
                    "eps: channel {} stuck {}: switching it {} ({cause:?}) had no effect",
                    channel.name(),
                    state(!on),
                    state(on)
                ),
            ));
            return true;
        }
        match self.eps.switch(channel, on) {
            Ok(true) => {
                self.switched(t, channel, on, cause);
                true
            }
            Ok(false) => true,
            Err(SwitchRefused::GroupShed(g)) => {
                self.log.push(NodeEvent::info(
                    t,
                    format!(
                        "eps: refused to switch {} on: {g:?} group shed (soc {:.1} %)",
                        channel.name(),
                        self.eps.soc() * 100.0
                    ),
                ));
                false
            }
        }
    }

    fn apply_event(&mut self, ev: EpsEvent, t: SimTime) {
        match ev {
            EpsEvent::Channel { channel, on } => {
                self.switch(t, channel, on, SwitchCause::Timeline);
            }
            EpsEvent::SetSoc(soc) => {
                self.eps.set_soc(soc);
                self.log.push(NodeEvent::info(
                    t,
                    format!("eps: state of charge set to {:.1} %", soc * 100.0),
                ));
            }
            EpsEvent::PanelFail(i) => {
                self.eps.set_panel_failed(i, true);
                self.log
                    .push(NodeEvent::info(t, format!("eps: panel {i} failed")));
            }
            EpsEvent::PanelRestore(i) => {
                self.eps.set_panel_failed(i, false);
                self.log
                    .push(NodeEvent::info(t, format!("eps: panel {i} restored")));
            }
            EpsEvent::ChannelStuck(c) | EpsEvent::ChannelFreed(c) => {
                let stuck = matches!(ev, EpsEvent::ChannelStuck(_));
                if let Some(n) = self.stuck.get_mut(usize::from(c.id())) {
                    *n = if stuck {
                        n.saturating_add(1)
                    } else {
                        n.saturating_sub(1)
                    };
                }
                self.log.push(NodeEvent::info(
                    t,
                    if self.is_stuck(c) {
                        format!(
                            "eps: channel {} stuck {}",
                            c.name(),
                            if self.eps.is_on(c) { "on" } else { "off" }
                        )
                    } else {
                        format!("eps: channel {} obeys again", c.name())
                    },
                ));
            }
            EpsEvent::BatteryFade(f) => {
                self.eps.fade_battery(f);
                self.log.push(NodeEvent::info(
                    t,
                    format!(
                        "eps: battery lost {:.1} % of its capacity: {:.1} Wh left at {:.1} %",
                        f * 100.0,
                        self.eps.battery().config().capacity_wh,
                        self.eps.soc() * 100.0
                    ),
                ));
            }
        }
    }

    fn tick(&mut self, t: SimTime) {
        for (c, on, g) in self.eps.protect() {
            let cause = if on {
                SwitchCause::Restore(g)
            } else {
                SwitchCause::Shed(g)
            };
            self.switched(t, c, on, cause);
        }
        let l = self.eps.last();
        let sample = EpsOutput::Sample {
            t,
            soc: self.eps.soc(),
            battery_v: l.battery.voltage_v,
            battery_a: l.battery.current_a,
            solar_w: l.solar_w,
            load_w: l.loads.total_w(),
            panels_w: l.panels_w.clone(),
            channels: self.eps.channels_on(),
        };
        self.emit(sample);
    }

    fn next_due(&self) -> SimTime {
        match self.cfg.timeline.get(self.timeline_next) {
            Some(e) if e.at <= self.next_tick => e.at,
            _ => self.next_tick,
        }
    }

    fn command(&mut self, c: EpsCommand, now: SimTime) -> Result<Vec<u8>, u8> {
        match c {
            EpsCommand::TmEps => Ok(self.eps.tm().to_vec()),
            EpsCommand::ChGet => Ok(self.eps.channel_states().to_vec()),
            EpsCommand::ChSet { channel, on } => {
                if self.switch(now, channel, on, SwitchCause::Command) {
                    Ok(self.eps.channel_states().to_vec())
                } else {
                    Err(csp::reqrep::RESULT_FAILURE)
                }
            }
            EpsCommand::ThrGet => Ok(self.eps.thresholds().to_vec()),
            EpsCommand::ThrSet(t) => {
                self.eps.set_thresholds(t);
                self.log.push(NodeEvent::info(
                    now,
                    format!("eps: thresholds set to {t:?}"),
                ));
                Ok(Vec::new())
            }
        }
    }
}

impl App for EpsApp {
    type Event = EpsOutput;
    fn poll_event(&mut self) -> Option<EpsOutput> {
        self.out.pop()
    }
    fn start(&mut self, node: &mut Node, now: SimTime) {
        node.bind(self.cfg.port);
        if !self.booted {
            self.booted = true;
            self.last_t = now;
            for c in Channel::ALL {
                if !self.eps.is_on(c) {
                    self.switched(now, c, false, SwitchCause::Initial);
                }
            }
        }
        self.next_tick = self.next_tick_after(now);
        self.booting = false;
        if let Err(f) = self.eps.thresholds().validate() {
            // The parameter table at boot broke a rule (only a bad scenario can): the
            // documented defaults instead.
            node.warn(
                now,
                format!("eps: thresholds at boot refused ({f}): the defaults instead"),
            );
            self.cfg.thresholds = Thresholds::default();
            self.eps.set_configured_thresholds(Thresholds::default());
        }
        self.flush_log(node);
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        if packet.header.dport != self.cfg.port {
            return;
        }
        self.advance(now);
        // A payload may read the EPS, not switch it (ICD 4.1).
        let open = [wire::cmd::TMEPS, wire::cmd::CHGET, wire::cmd::THRGET];
        let (reply, refused) = match csp::node::payload_refusal(node, &packet, &open, now) {
            Some(r) => (r, None),
            None => serve::<EpsCommand>(&packet.data, |c| self.command(c, now)),
        };
        if let Some(e) = refused {
            self.log
                .push(NodeEvent::info(now, format!("eps: request refused: {e}")));
        }
        if reply.get(1) != Some(&csp::reqrep::RESULT_SUCCESS) {
            self.refused += 1;
        }
        // A send failure is already counted by the node.
        let _ = node.send(Packet::new(packet.header.reply(node.addr()), reply), now);
        self.flush_log(node);
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        Some(self.next_due())
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        for _ in 0..MAX_STEPS {
            let due = self.next_due();
            if due > now {
                break;
            }
            self.advance(due);
            match self.cfg.timeline.get(self.timeline_next).copied() {
                Some(ev) if ev.at <= due => {
                    self.timeline_next += 1;
                    self.apply_event(ev.event, due);
                }
                _ => {
                    self.tick(due);
                    self.next_tick = due + self.cfg.tick;
                }
            }
        }
        self.flush_log(node);
    }

    fn reset(&mut self, now: SimTime) {
        self.advance(now);
        self.eps.reset_volatile();
        self.refused = 0;
        self.booting = true;
        self.log.push(NodeEvent::info(
            now,
            "eps: reboot: battery and channels kept".to_owned(),
        ));
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
        // As TMEPS on port 10 at `now`.
        self.advance(now);
        let bytes = self
            .command(EpsCommand::TmEps, now)
            .map_err(|_| ConsoleError::Refused("TMEPS"))?;
        Ok(csp::console::lines(
            <wire::TmEps as csp::icd::Describe>::FIELDS,
            &bytes,
        )?)
    }

    fn self_test(&mut self, _node: &Node, now: SimTime) -> Vec<csp::params::Check> {
        // As a request on port 10 would: the power system up to now.
        self.advance(now);
        self.checks(now)
    }

    fn finish(&mut self, node: &mut Node, now: SimTime) {
        self.advance(now);
        let (solar, load) = self.eps.energy_since_boot_wh();
        self.log.push(NodeEvent::info(
            now,
            format!(
                "eps: final: soc {:.1} %, solar {solar:.1} Wh and load {load:.1} Wh since boot, channels {:#06x}",
                self.eps.soc() * 100.0,
                self.eps.channels_on()
            ),
        ));
        self.flush_log(node);
    }
}

/// The EPS with the default configuration ([`EpsConfig::default`]).
pub fn app() -> EpsApp {
    EpsApp::new(EpsConfig::default())
}

// What a snapshot keeps of the EPS (docs/snapshots.md): the configuration too (the
// parameters change it in flight), the model, the timeline's place; the boards are the
// run's (saved with the platform).
snap::fields!(TimedEpsEvent { at, event });
snap::fields!(EpsConfig {
    panels,
    battery,
    loads,
    thresholds,
    initial_soc,
    tick,
    channels_on,
    port,
    timeline
});
snap::fields!(EpsApp {
    cfg,
    eps,
    out,
    last_t,
    next_tick,
    timeline_next,
    booted,
    cut_off,
    refused,
    booting,
    stuck,
    log;
    skip truth, activity
});

snap::tagged_enum!(EpsEvent {
    Channel { channel, on },
    SetSoc(soc),
    PanelFail(panel),
    PanelRestore(panel),
    BatteryFade(fade),
    ChannelStuck(channel),
    ChannelFreed(channel)
});

#[cfg(test)]
mod tests;
