//! The thin shell around the platform's power rules ([`platform::power::PowerRules`]): it
//! feeds them the EPS's channel switches and the scenario's power and hang faults, and
//! applies their effects at the input's instant: a node's control channel (power, hang,
//! radio switch), the main bus's alias and the ground's uplink (the radio take-over), the
//! activity board (power faults for the EPS, the S-band's power for the PC), and the run's
//! log.
//!
//! Everything here runs in the main loop, in the order the inputs come; the rules decide.

use std::collections::BTreeMap;

use bus::can::CanPort;
use bus::driver::{Attachment, CtlTx, NodeCtl};
use bus::gate::LinkGate;
use bus::net::NetPort;
use bus::outside::Segments;
use csp::SimTime;
use platform::addr::{COMM1, COMM2};
use platform::board::{Activity, ActivityBoard};
use platform::power::{Effect, PowerRules};

use twin_core::events::{Level, RunEvent};

/// The rules and what their effects act on.
#[derive(Debug)]
pub struct PowerShell {
    rules: PowerRules,
    ctls: BTreeMap<u8, CtlTx>,
    activity: ActivityBoard,
    segs: Segments,
    /// COMM2's main-bus port (it answers to COMM1's link address while it carries).
    comm2_can: Option<CanPort>,
    /// COMM1's and COMM2's radio endpoints.
    radios: [Option<NetPort>; 2],
    /// The outside links of the scenario: name, the channel that powers it if one does,
    /// and gate, by link index.
    links: BTreeMap<u16, (String, Option<nodes_eps::Channel>, LinkGate)>,
}

impl PowerShell {
    /// The shell for the nodes whose control channels are `ctls`.
    pub fn new(ctls: BTreeMap<u8, CtlTx>, activity: ActivityBoard, segs: Segments) -> Self {
        PowerShell {
            rules: PowerRules::new(ctls.keys().copied()),
            ctls,
            activity,
            segs,
            comm2_can: None,
            radios: [None, None],
            links: BTreeMap::new(),
        }
    }

    /// Outside link `link` (named `name`, behind `gate`) is powered by EPS channel
    /// `channel`, which is on (`on`) at the start.
    pub fn power_link(
        &mut self,
        link: usize,
        name: String,
        channel: nodes_eps::Channel,
        gate: LinkGate,
        on: bool,
    ) {
        let (Ok(link), Some(addr)) = (u16::try_from(link), channel.node_addr()) else {
            return;
        };
        gate.set_powered(on);
        self.rules.power_link(link, addr, on);
        self.links.insert(link, (name, Some(channel), gate));
    }

    /// Outside link `link` (named `name`, behind `gate`), which power faults may hold off;
    /// [`PowerShell::power_link`] if a channel powers it.
    pub fn register_link(&mut self, link: usize, name: String, gate: LinkGate) {
        if let Ok(link) = u16::try_from(link) {
            self.links.entry(link).or_insert((name, None, gate));
        }
    }

    /// Power fault `fault` holds outside link `link` off (`off`) or releases it at `t`.
    pub fn power_link_fault(
        &mut self,
        t: SimTime,
        link: u16,
        fault: u32,
        off: bool,
    ) -> Vec<RunEvent> {
        let effects = self.rules.hold_link(link, fault, off);
        self.apply(t, effects)
    }

    /// Register a COMM's attachments (for the take-over).
    pub fn register_comm(&mut self, addr: u8, ports: &[Attachment]) {
        let i = match addr {
            COMM1 => 0,
            COMM2 => 1,
            _ => return,
        };
        for p in ports {
            match p {
                Attachment::Can(c) if i == 1 => self.comm2_can = Some(c.clone()),
                Attachment::Net(n) => self.radios[i] = Some(n.clone()),
                Attachment::Can(_) => {}
            }
        }
    }

    /// The rules as they stand.
    pub fn rules(&self) -> &PowerRules {
        &self.rules
    }

    /// The EPS switched `channel` at `t`; returns the log events.
    pub fn eps_channel(
        &mut self,
        t: SimTime,
        channel: nodes_eps::Channel,
        on: bool,
    ) -> Vec<RunEvent> {
        let effects = match channel.node_addr() {
            Some(addr) => self.rules.channel(addr, on),
            // The S-band transmitter is the PC's: it follows this at its next frame boundary.
            None => vec![Effect::Board {
                what: Activity::SbandPowerOff,
                on: !on,
            }],
        };
        self.apply(t, effects)
    }

    /// Power fault `fault` holds node `addr` off (`off`) or releases it at `t`.
    pub fn power_fault(&mut self, t: SimTime, addr: u8, fault: u32, off: bool) -> Vec<RunEvent> {
        let effects = if off {
            self.rules.hold(addr, fault)
        } else {
            self.rules.release(addr, fault)
        };
        self.apply(t, effects)
    }

    /// Hang fault `fault` starts or ends on node `addr` at `t`.
    pub fn hang_fault(&mut self, t: SimTime, addr: u8, fault: u32, hung: bool) -> Vec<RunEvent> {
        let effects = self.rules.hang(addr, fault, hung);
        self.apply(t, effects)
    }

    fn ctl(&self, addr: u8, t: SimTime, c: NodeCtl) {
        if let Some(tx) = self.ctls.get(&addr) {
            let _ = tx.send((t, c));
        }
    }

    fn apply(&mut self, t: SimTime, effects: Vec<Effect>) -> Vec<RunEvent> {
        let mut events = Vec::new();
        for e in effects {
            match e {
                Effect::Power { addr, on } => self.ctl(addr, t, NodeCtl::Power(on)),
                Effect::Hang { addr, hung } => self.ctl(addr, t, NodeCtl::Hang(hung)),
                Effect::Radio { carrier } => {
                    if let Some(port) = &self.comm2_can {
                        self.segs.main.set_alias(port, COMM1, carrier == COMM2);
                    }
                    let i = usize::from(carrier == COMM2);
                    if let Some(radio) = &self.radios[i] {
                        self.segs.ground.set_default(radio);
                    }
                    for addr in [COMM1, COMM2] {
                        self.ctl(
                            addr,
                            t,
                            NodeCtl::Switch(
                                nodes_comm::RADIO_SWITCH,
                                csp::node::SwitchPosition::on_if(addr == carrier),
                            ),
                        );
                    }
                }
                Effect::Board { what, on } => {
                    if let Err(e) = self.activity.set(what, t, on) {
                        tracing::warn!(%t, "activity {what:?}: {e}");
                        events.push(RunEvent::Log {
                            t,
                            source: "run".to_owned(),
                            level: Level::Warning,
                            message: format!("activity {what:?}: {e}"),
                        });
                    }
                }
                Effect::LinkPower { link, on } => {
                    let Some((name, channel, gate)) = self.links.get(&link) else {
                        continue;
                    };
                    gate.set_powered(on);
                    // Why, in the words of what switched it: its channel, or a fault.
                    let cause = match channel {
                        Some(c) if on || !self.rules.link_channel_on(link) => {
                            format!("{} {}", c.name(), if on { "on" } else { "off" })
                        }
                        _ if on => "the power-off fault lifted".to_owned(),
                        _ => "a power-off fault".to_owned(),
                    };
                    let message = if on {
                        format!("link {name}: powered again ({cause})")
                    } else {
                        format!(
                            "link {name}: unpowered ({cause}): the twin forwards nothing to or from it"
                        )
                    };
                    tracing::info!(%t, "{message}");
                    events.push(RunEvent::Log {
                        t,
                        source: "power".to_owned(),
                        level: Level::Info,
                        message,
                    });
                }
                Effect::Log(message) => {
                    tracing::info!(%t, "{message}");
                    events.push(RunEvent::Log {
                        t,
                        source: "radio".to_owned(),
                        level: Level::Info,
                        message,
                    });
                }
            }
        }
        events
    }
}

/// The rules' state (what they act on is the run's wiring; the links' gates and the
/// activity board are saved with the media and the boards).
impl snap::Snap for PowerShell {
    fn save(&self, w: &mut snap::Writer) {
        self.rules.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.rules.load(r)
    }
}
