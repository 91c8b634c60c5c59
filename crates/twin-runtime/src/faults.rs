//! Fault mechanisms: what a fault does to the media, the nodes and the power rules at its
//! instant ([`FaultAction`], applied by the [`Director`]). The kinds that a scenario names
//! and how they compile into actions are the twin's `faults` module.

use crate::power::PowerShell;
use bus::driver::{CtlTx, NodeCtl};
use bus::impair::Impairments;
use bus::outside::Segments;
use csp::SimTime;
use std::collections::BTreeMap;
use twin_core::events::RunEvent;
use twin_scenario::scenario::NodeRef;

/// A medium a fault applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MediumId {
    /// Main CAN bus.
    Main,
    /// Payload CAN bus.
    Payload,
    /// The UHF air channel of the ground segment.
    Uhf,
    /// The scenario's outside link `[[links]][i]` (faults act on its gate, `bus::gate`).
    Link(u16),
}

impl MediumId {
    /// The medium a fault's `target` names (`main`, `payload`, `uhf`).
    pub fn of(target: &NodeRef) -> Option<MediumId> {
        match target {
            NodeRef::Name(n) if n == "main" => Some(MediumId::Main),
            NodeRef::Name(n) if n == "payload" => Some(MediumId::Payload),
            NodeRef::Name(n) if n == "uhf" => Some(MediumId::Uhf),
            _ => None,
        }
    }

    /// Whether it is a CAN bus of the twin.
    pub fn is_can(self) -> bool {
        matches!(self, MediumId::Main | MediumId::Payload)
    }
}

/// One change the fault director applies at an instant. `fault` is the scenario fault's
/// index: faults on one medium or node compose, and each start or end changes only its own
/// part.
#[derive(Debug, Clone, PartialEq)]
pub enum FaultAction {
    /// Fault `fault` starts impairing a medium (`Some`) or is lifted (`None`).
    Impair {
        /// The medium.
        medium: MediumId,
        /// The fault.
        fault: u32,
        /// Its impairments while active.
        imp: Option<Impairments>,
    },
    /// Fault `fault` starts acting on a CAN bus as CAN faults do (`Some`) or is lifted.
    Can {
        /// The bus (`Main` or `Payload`).
        medium: MediumId,
        /// The fault.
        fault: u32,
        /// What it does while active.
        can: Option<bus::can::CanFault>,
    },
    /// Power fault `fault` holds node `addr` off (`off`) or releases it.
    Power {
        /// The node.
        addr: u8,
        /// The fault.
        fault: u32,
        /// Held off or released.
        off: bool,
    },
    /// Power fault `fault` holds outside link `link` off (`off`) or releases it: the twin
    /// forwards nothing to or from the program behind it meanwhile.
    LinkPower {
        /// The link (`MediumId::Link`'s index).
        link: u16,
        /// The fault.
        fault: u32,
        /// Held off or released.
        off: bool,
    },
    /// Hang fault `fault` starts (`hung`) or ends on outside link `link`: the twin
    /// forwards nothing to or from it.
    LinkHang {
        /// The link (`MediumId::Link`'s index).
        link: u16,
        /// The fault.
        fault: u32,
        /// Hung or recovered.
        hung: bool,
    },
    /// Node reboot.
    Reboot(u8),
    /// Hang fault `fault` starts (`hung`) or ends on node `addr`.
    Hang {
        /// The node.
        addr: u8,
        /// The fault.
        fault: u32,
        /// Hung or recovered.
        hung: bool,
    },
    /// A fault of node `addr`'s core starts (`Some`) or ends, under fault id `fault`.
    Node {
        /// The node.
        addr: u8,
        /// The fault.
        fault: u32,
        /// What it does while active.
        what: Option<csp::node::NodeFault>,
    },
    /// A fault a node applies itself from its own timeline: recorded only.
    Record,
    /// The UHF link's contact with the ground (a pass begins or ends).
    Contact(bool),
}

/// A fault action at a time, with a description for logs and recordings.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedFault {
    /// When.
    pub at: SimTime,
    /// What.
    pub action: FaultAction,
    /// Human-readable, for example `faults[0]: Drop on main`.
    pub what: String,
}

/// What the runtime's fault director acts on.
#[derive(Debug)]
pub struct Director<'a> {
    /// The media.
    pub segs: &'a Segments,
    /// Every node's control channel.
    pub ctls: &'a BTreeMap<u8, CtlTx>,
    /// The power rules.
    pub power: &'a mut PowerShell,
    /// The gates of the outside links, by index.
    pub links: &'a [bus::gate::LinkGate],
}

impl Director<'_> {
    /// Apply one fault action at its instant; returns the events of the power rules.
    pub fn apply(&mut self, f: &TimedFault) -> Vec<RunEvent> {
        let ctl = |addr: &u8, c: NodeCtl| {
            if let Some(tx) = self.ctls.get(addr) {
                let _ = tx.send((f.at, c));
            }
        };
        match &f.action {
            FaultAction::Impair { medium, fault, imp } => {
                match medium {
                    MediumId::Main => self.segs.main.set_fault(*fault, *imp),
                    MediumId::Payload => self.segs.payload.set_fault(*fault, *imp),
                    MediumId::Uhf => self.segs.ground.set_fault(*fault, *imp),
                    MediumId::Link(i) => {
                        if let Some(g) = self.links.get(usize::from(*i)) {
                            g.set_fault(*fault, *imp);
                        }
                    }
                }
                Vec::new()
            }
            FaultAction::LinkHang { link, fault, hung } => {
                if let Some(g) = self.links.get(usize::from(*link)) {
                    g.set_hang(*fault, *hung);
                }
                Vec::new()
            }
            FaultAction::Can { medium, fault, can } => {
                match medium {
                    MediumId::Main => self.segs.main.set_can_fault(*fault, can.clone()),
                    MediumId::Payload => self.segs.payload.set_can_fault(*fault, can.clone()),
                    MediumId::Uhf | MediumId::Link(_) => {}
                }
                Vec::new()
            }
            FaultAction::Power { addr, fault, off } => {
                self.power.power_fault(f.at, *addr, *fault, *off)
            }
            FaultAction::LinkPower { link, fault, off } => {
                self.power.power_link_fault(f.at, *link, *fault, *off)
            }
            FaultAction::Reboot(a) => {
                // A node that is off or hung does not reboot (its task ignores it then).
                ctl(a, NodeCtl::Reboot);
                Vec::new()
            }
            FaultAction::Hang { addr, fault, hung } => {
                self.power.hang_fault(f.at, *addr, *fault, *hung)
            }
            FaultAction::Node { addr, fault, what } => {
                ctl(addr, NodeCtl::Fault(*fault, what.clone()));
                Vec::new()
            }
            // The node applies it from its own timeline.
            FaultAction::Record => Vec::new(),
            FaultAction::Contact(on) => {
                self.segs.ground.set_contact(*on);
                Vec::new()
            }
        }
    }
}

// The state a snapshot saves (docs/snapshots.md): the fault timeline's actions to come.
snap::tagged_enum!(MediumId {
    Main,
    Payload,
    Uhf,
    Link(link)
});
snap::tagged_enum!(FaultAction {
    Impair { medium, fault, imp },
    Can { medium, fault, can },
    Power { addr, fault, off },
    LinkPower { link, fault, off },
    LinkHang { link, fault, hung },
    Reboot(addr),
    Hang { addr, fault, hung },
    Node { addr, fault, what },
    Record,
    Contact(on)
});
snap::fields!(TimedFault { at, action, what });
