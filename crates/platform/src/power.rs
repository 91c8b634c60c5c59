//! One truth for power, and the radio take-over that follows from it: a pure core (no
//! clock, no I/O) that the runtime feeds with the EPS's channel switches and the scenario's
//! power and hang faults, and whose [`Effect`]s it applies at the instant of the input.
//!
//! # Power
//! A node is **powered exactly while its EPS channel is on and no power fault holds it
//! off**. Faults compose: each `power-off` fault is a hold with its own id, and the node is
//! powered again only when every hold is released *and* its channel is on (a fault that
//! ends while the EPS holds the channel off leaves the node off). Nodes on unswitched
//! outputs (FC, EPS) have no channel: only faults switch them. Each change of a node's
//! power is one [`Effect::Power`]: the runtime tells the node's task, which takes it off
//! its buses and runs its core's power-loss hook (the ECU stops firing at that instant), or
//! boots it.
//!
//! The EPS charges a node's load while its channel is on; a power fault holding a node off
//! with its channel on is posted for the EPS as [`Activity::PowerFault`]
//! ([`Effect::Board`]), so the EPS stops charging it for exactly that time.
//!
//! # Hangs
//! A hung node is powered but silent (alive on the bus, answering nothing). Hang faults
//! compose like power holds; a power cycle ends every hang (the node reboots).
//!
//! # The radio take-over
//! COMM1 carries the UHF link while it is up (powered and not hung); while it is down and
//! COMM2 is up, COMM2 carries it; while both are down nobody can, and nothing is switched
//! until one comes back ([`Effect::Radio`]). The routing tables never change (ICD 1.7):
//! the runtime makes the carrier answer to COMM1's link address on the main bus, points the
//! ground's uplink at its radio and makes its radio the active one (docs/platform.md).

use std::collections::{BTreeMap, BTreeSet};

use crate::addr::{COMM1, COMM2};
use crate::board::Activity;

/// What the runtime must do after an input, in order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Effect {
    /// Node `addr` gains (`on`) or loses power now.
    Power {
        /// The node.
        addr: u8,
        /// Powered or not.
        on: bool,
    },
    /// Node `addr` hangs (`hung`) or recovers now.
    Hang {
        /// The node.
        addr: u8,
        /// Hung or not.
        hung: bool,
    },
    /// COMM `carrier` (1 or 2) now carries the radio link.
    Radio {
        /// The COMM's address.
        carrier: u8,
    },
    /// Post a switch of `what` on the activity board now.
    Board {
        /// The activity.
        what: Activity,
        /// On or off.
        on: bool,
    },
    /// Outside link `link` (its index among the run's outside links) gains (`on`) or
    /// loses power now.
    LinkPower {
        /// The link.
        link: u16,
        /// Powered or not.
        on: bool,
    },
    /// A line for the run's log (source `radio`).
    Log(String),
}

/// The supply of one node.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct Supply {
    /// Its EPS channel is off (`false` for nodes without a channel).
    channel_off: bool,
    /// Power faults holding it off, by fault id.
    holds: BTreeSet<u32>,
    /// Hang faults holding it hung, by fault id.
    hangs: BTreeSet<u32>,
}

/// The supply of one outside link: the EPS channel that powers it, if one does, and the
/// power faults holding it off.
#[derive(Debug, Clone, PartialEq, Eq)]
struct LinkSupply {
    /// The address of the node whose channel powers it.
    channel_of: Option<u8>,
    /// That channel is on (`true` without one).
    channel_on: bool,
    /// Power faults holding it off, by fault id.
    holds: BTreeSet<u32>,
}

impl LinkSupply {
    fn powered(&self) -> bool {
        self.channel_on && self.holds.is_empty()
    }
}

impl Supply {
    fn powered(&self) -> bool {
        !self.channel_off && self.holds.is_empty()
    }
    fn up(&self) -> bool {
        self.powered() && self.hangs.is_empty()
    }
}

/// The rules (see the module doc).
#[derive(Debug, Clone, Default)]
pub struct PowerRules {
    nodes: BTreeMap<u8, Supply>,
    /// Whether both COMMs exist (the take-over needs two radios).
    radio: bool,
    /// Which COMM carries the link: 1, 2, or 0 (nobody: both down).
    carrier: u8,
    /// Whose radio is the active one (1 or 2): the switches as they stand.
    active: u8,
    /// Outside links powered by a channel or held off by a power fault.
    links: BTreeMap<u16, LinkSupply>,
}

impl PowerRules {
    /// Rules for the nodes at `addrs`, every one powered, COMM1 carrying the link.
    pub fn new(addrs: impl IntoIterator<Item = u8>) -> Self {
        let nodes: BTreeMap<u8, Supply> =
            addrs.into_iter().map(|a| (a, Supply::default())).collect();
        let radio = nodes.contains_key(&COMM1) && nodes.contains_key(&COMM2);
        PowerRules {
            nodes,
            radio,
            carrier: COMM1,
            active: COMM1,
            links: BTreeMap::new(),
        }
    }

    /// Outside link `link` is powered by the EPS channel of node `channel_of`, which is on
    /// (`on`) or off now.
    pub fn power_link(&mut self, link: u16, channel_of: u8, on: bool) {
        self.links.insert(
            link,
            LinkSupply {
                channel_of: Some(channel_of),
                channel_on: on,
                holds: BTreeSet::new(),
            },
        );
    }

    /// Whether outside link `link` is powered (links without a channel are, unless a
    /// power fault holds them off).
    pub fn link_powered(&self, link: u16) -> bool {
        self.links.get(&link).is_none_or(LinkSupply::powered)
    }

    /// Whether the channel powering outside link `link` is on (links without one: yes).
    pub fn link_channel_on(&self, link: u16) -> bool {
        self.links.get(&link).is_none_or(|l| l.channel_on)
    }

    /// Power fault `fault` holds outside link `link` off (`off`) or releases it: the
    /// program behind it loses power as a node of the twin would (a payload the twin does
    /// not simulate, cut by a fault on its supply).
    pub fn hold_link(&mut self, link: u16, fault: u32, off: bool) -> Vec<Effect> {
        let l = self.links.entry(link).or_insert(LinkSupply {
            channel_of: None,
            channel_on: true,
            holds: BTreeSet::new(),
        });
        let was = l.powered();
        if off {
            l.holds.insert(fault);
        } else {
            l.holds.remove(&fault);
        }
        if l.powered() == was {
            Vec::new()
        } else {
            vec![Effect::LinkPower {
                link,
                on: l.powered(),
            }]
        }
    }

    /// Whether node `addr` is powered (unknown nodes: no).
    pub fn powered(&self, addr: u8) -> bool {
        self.nodes.get(&addr).is_some_and(Supply::powered)
    }

    /// Whether node `addr` is powered and not hung.
    pub fn up(&self, addr: u8) -> bool {
        self.nodes.get(&addr).is_some_and(Supply::up)
    }

    /// Which COMM carries the radio link (0: none can).
    pub fn carrier(&self) -> u8 {
        self.carrier
    }

    /// Node `addr`'s EPS channel switched on or off (and the outside links it powers).
    pub fn channel(&mut self, addr: u8, on: bool) -> Vec<Effect> {
        let mut out = self.change(addr, |s| s.channel_off = !on);
        for (link, l) in &mut self.links {
            if l.channel_of == Some(addr) && l.channel_on != on {
                let was = l.powered();
                l.channel_on = on;
                if l.powered() != was {
                    out.push(Effect::LinkPower {
                        link: *link,
                        on: l.powered(),
                    });
                }
            }
        }
        out
    }

    /// Power fault `fault` starts holding node `addr` off.
    pub fn hold(&mut self, addr: u8, fault: u32) -> Vec<Effect> {
        let mut out = self.change(addr, |s| {
            s.holds.insert(fault);
        });
        if self.nodes.get(&addr).is_some_and(|s| s.holds.len() == 1) {
            out.insert(
                0,
                Effect::Board {
                    what: Activity::PowerFault(addr),
                    on: true,
                },
            );
        }
        out
    }

    /// Power fault `fault` releases node `addr`.
    pub fn release(&mut self, addr: u8, fault: u32) -> Vec<Effect> {
        let held = self
            .nodes
            .get(&addr)
            .is_some_and(|s| s.holds.contains(&fault));
        let mut out = self.change(addr, |s| {
            s.holds.remove(&fault);
        });
        if held && self.nodes.get(&addr).is_some_and(|s| s.holds.is_empty()) {
            out.insert(
                0,
                Effect::Board {
                    what: Activity::PowerFault(addr),
                    on: false,
                },
            );
        }
        out
    }

    /// Hang fault `fault` starts (`hung`) or ends on node `addr`.
    pub fn hang(&mut self, addr: u8, fault: u32, hung: bool) -> Vec<Effect> {
        self.change(addr, |s| {
            if hung {
                s.hangs.insert(fault);
            } else {
                s.hangs.remove(&fault);
            }
        })
    }

    /// Apply `f` to node `addr`'s supply and derive the effects.
    fn change(&mut self, addr: u8, f: impl FnOnce(&mut Supply)) -> Vec<Effect> {
        let Some(s) = self.nodes.get_mut(&addr) else {
            return Vec::new();
        };
        let (was_powered, was_hung) = (s.powered(), !s.hangs.is_empty());
        f(s);
        let mut out = Vec::new();
        if s.powered() != was_powered {
            if s.powered() {
                // Power cycling ends a hang: the node boots afresh.
                s.hangs.clear();
            }
            out.push(Effect::Power {
                addr,
                on: s.powered(),
            });
        } else if s.powered() && was_hung == s.hangs.is_empty() {
            out.push(Effect::Hang {
                addr,
                hung: !s.hangs.is_empty(),
            });
        } else if !s.powered() {
            // Nothing to hang while the node is off; power coming back boots it afresh.
            s.hangs.clear();
        }
        self.take_over(&mut out);
        out
    }

    /// The radio take-over after a change.
    fn take_over(&mut self, out: &mut Vec<Effect>) {
        if !self.radio {
            return;
        }
        let carrier = if self.up(COMM1) {
            COMM1
        } else if self.up(COMM2) {
            COMM2
        } else {
            0
        };
        if carrier == self.carrier {
            return;
        }
        let message = match carrier {
            COMM1 => "COMM1 has the radio link back".to_owned(),
            COMM2 => format!(
                "COMM2 takes the radio link over (COMM1 {})",
                if self.powered(COMM1) {
                    "failed"
                } else {
                    "powered off"
                }
            ),
            // Nobody can carry it: the switches stay as they are until one comes back.
            _ => "no COMM can carry the radio link (COMM1 and COMM2 down)".to_owned(),
        };
        self.carrier = carrier;
        if carrier != 0 && carrier != self.active {
            self.active = carrier;
            out.push(Effect::Radio { carrier });
        }
        out.push(Effect::Log(message));
    }
}

// What a snapshot keeps of the rules: every node's supply, the links', the carrier.
snap::fields!(Supply {
    channel_off,
    holds,
    hangs
});
snap::fields!(LinkSupply {
    channel_of,
    channel_on,
    holds
});
snap::fields!(PowerRules {
    nodes,
    radio,
    carrier,
    active,
    links
});

#[cfg(test)]
mod tests {
    use super::*;
    use crate::addr::{ECU, FC, PC};

    fn rules() -> PowerRules {
        PowerRules::new([COMM1, COMM2, FC, 4, ECU, PC, 12])
    }

    /// Rules saved with holds, hangs, a link and the radio taken over, loaded into fresh
    /// rules, give the same effects from there on.
    #[test]
    fn rules_saved_and_loaded_go_on_as_the_originals() {
        let mut a = rules();
        a.power_link(0, 12, true);
        a.hold(COMM1, 4);
        a.hang(ECU, 5, true);
        a.hold_link(0, 6, true);
        let bytes = snap::to_bytes(&a);
        let mut b = rules();
        snap::load_from(&mut b, &bytes).expect("the saved rules load");
        assert_eq!(snap::to_bytes(&b), bytes);
        assert_eq!(b.carrier(), COMM2);
        for step in [
            |r: &mut PowerRules| r.release(COMM1, 4),
            |r: &mut PowerRules| r.hold_link(0, 6, false),
            |r: &mut PowerRules| r.channel(12, false),
            |r: &mut PowerRules| r.hold(COMM2, 9),
        ] {
            assert_eq!(step(&mut a), step(&mut b));
        }
    }

    #[test]
    fn a_node_is_powered_while_its_channel_is_on_and_no_fault_holds_it() {
        let mut r = rules();
        assert_eq!(
            r.hold(PC, 7),
            vec![
                Effect::Board {
                    what: Activity::PowerFault(PC),
                    on: true
                },
                Effect::Power {
                    addr: PC,
                    on: false
                },
            ]
        );
        // The EPS switches the channel off meanwhile: nothing changes for the node.
        assert_eq!(r.channel(PC, false), vec![]);
        // The fault ends while the channel is off: the PC stays off.
        assert_eq!(
            r.release(PC, 7),
            vec![Effect::Board {
                what: Activity::PowerFault(PC),
                on: false
            }]
        );
        assert!(!r.powered(PC));
        assert_eq!(
            r.channel(PC, true),
            vec![Effect::Power { addr: PC, on: true }]
        );
        assert!(r.powered(PC));
    }

    #[test]
    fn an_outside_link_follows_only_the_channel_that_powers_it() {
        let mut r = rules();
        r.power_link(0, 12, true);
        // Link 1 has no channel: nothing switches it.
        assert!(r.link_powered(0) && r.link_powered(1));
        assert_eq!(
            r.channel(12, false),
            vec![
                Effect::Power {
                    addr: 12,
                    on: false
                },
                Effect::LinkPower { link: 0, on: false }
            ]
        );
        assert!(!r.link_powered(0) && r.link_powered(1));
        assert_eq!(r.channel(12, false), vec![], "no change");
        assert_eq!(
            r.channel(ECU, false).len(),
            1,
            "another channel: the ECU only"
        );
        // A power fault on the twin's own node 12 leaves the outside program alone.
        r.channel(12, true);
        let effects = r.hold(12, 3);
        assert!(
            !effects
                .iter()
                .any(|e| matches!(e, Effect::LinkPower { .. }))
        );
        assert!(r.link_powered(0));
    }

    /// A power fault on a link holds the program off whatever its channel does, and
    /// composes with the channel: powered again only when both allow.
    #[test]
    fn a_power_fault_holds_a_link_off_and_composes_with_its_channel() {
        let mut r = rules();
        r.power_link(0, 12, true);
        assert_eq!(
            r.hold_link(0, 5, true),
            vec![Effect::LinkPower { link: 0, on: false }]
        );
        assert_eq!(
            r.channel(12, false).len(),
            1,
            "the node only: the link is off already"
        );
        assert_eq!(r.hold_link(0, 5, false), vec![], "the channel is still off");
        assert!(!r.link_powered(0));
        assert_eq!(
            r.channel(12, true),
            vec![
                Effect::Power { addr: 12, on: true },
                Effect::LinkPower { link: 0, on: true }
            ]
        );
        // A link no channel powers: only its faults.
        assert_eq!(
            r.hold_link(1, 6, true),
            vec![Effect::LinkPower { link: 1, on: false }]
        );
        assert_eq!(r.hold_link(1, 7, true), vec![], "a second hold");
        assert_eq!(r.hold_link(1, 6, false), vec![]);
        assert_eq!(
            r.hold_link(1, 7, false),
            vec![Effect::LinkPower { link: 1, on: true }]
        );
        assert!(r.link_powered(1));
    }

    #[test]
    fn overlapping_power_faults_compose() {
        let mut r = rules();
        assert_eq!(r.hold(ECU, 1).len(), 2);
        assert_eq!(r.hold(ECU, 2), vec![]);
        assert_eq!(r.release(ECU, 1), vec![]);
        assert!(!r.powered(ECU));
        assert_eq!(
            r.release(ECU, 2),
            vec![
                Effect::Board {
                    what: Activity::PowerFault(ECU),
                    on: false
                },
                Effect::Power {
                    addr: ECU,
                    on: true
                },
            ]
        );
        // Releasing a fault that holds nothing changes nothing.
        assert_eq!(r.release(ECU, 2), vec![]);
        // Unknown nodes (an address the run does not have) are ignored.
        assert_eq!(r.hold(9, 3), vec![]);
    }

    #[test]
    fn a_power_cycle_ends_a_hang() {
        let mut r = rules();
        assert_eq!(
            r.hang(FC, 1, true),
            vec![Effect::Hang {
                addr: FC,
                hung: true
            }]
        );
        assert!(r.powered(FC) && !r.up(FC));
        assert_eq!(
            r.hold(FC, 2).last(),
            Some(&Effect::Power {
                addr: FC,
                on: false
            })
        );
        assert_eq!(
            r.release(FC, 2).last(),
            Some(&Effect::Power { addr: FC, on: true })
        );
        assert!(r.up(FC));
        // The hang's own end later changes nothing.
        assert_eq!(r.hang(FC, 1, false), vec![]);
    }

    #[test]
    fn comm2_takes_the_link_while_comm1_is_down_and_nobody_while_both_are() {
        let mut r = rules();
        let e = r.channel(COMM1, false);
        assert_eq!(
            e,
            vec![
                Effect::Power {
                    addr: COMM1,
                    on: false
                },
                Effect::Radio { carrier: COMM2 },
                Effect::Log("COMM2 takes the radio link over (COMM1 powered off)".into()),
            ]
        );
        assert_eq!(r.carrier(), COMM2);
        // Both down: nobody, and the switches stay where they are.
        let e = r.hold(COMM2, 1);
        assert_eq!(
            e.last(),
            Some(&Effect::Log(
                "no COMM can carry the radio link (COMM1 and COMM2 down)".into()
            ))
        );
        assert!(!e.iter().any(|x| matches!(x, Effect::Radio { .. })));
        // COMM2 back first: it carries again without a switch (its radio is still active).
        let e = r.release(COMM2, 1);
        assert!(!e.iter().any(|x| matches!(x, Effect::Radio { .. })));
        assert_eq!(r.carrier(), COMM2);
        // COMM1 back: it has the link back.
        let e = r.channel(COMM1, true);
        assert_eq!(
            &e[1..],
            &[
                Effect::Radio { carrier: COMM1 },
                Effect::Log("COMM1 has the radio link back".into()),
            ]
        );
        // A hang of COMM1 is a failure.
        let e = r.hang(COMM1, 4, true);
        assert_eq!(
            e.last(),
            Some(&Effect::Log(
                "COMM2 takes the radio link over (COMM1 failed)".into()
            ))
        );
    }
}
