//! Low-battery protection: load shedding at state-of-charge thresholds, restoration with
//! hysteresis.
//!
//! Two groups, each with a shed threshold and a higher restore threshold (percent of state
//! of charge):
//! - **payload** group: payloads 12-15 and the S-band transmitter; default shed below 30 %,
//!   restore at 40 %;
//! - **platform** group: the PC and the ECU; default shed below 20 %, restore at 30 %.
//!
//! When the state of charge falls below a group's shed threshold, every channel of the
//! group that is on is switched off and remembered as *shed*; when it comes back to the
//! restore threshold, exactly the shed channels are switched on again (a channel that was
//! off, or that an operator switched off meanwhile, stays off). While a group is shed, a
//! command to switch one of its channels on is refused (lower the thresholds with THRSET to
//! override). COMM1 and COMM2 are never shed: the link to the ground is how an operator
//! recovers the spacecraft, and the receivers cost 0.5 W each. The FC and the EPS have no
//! switched channel at all. A shed threshold of 0 never sheds that group.
//!
//! The protection state (which groups are shed, which channels to restore) lives in the
//! EPS's non-volatile memory like the channel states themselves: it survives an EPS reboot,
//! so a reboot in a low-power state never strands a load off.

use crate::loads::Channel;

pub use icd::eps::{Group, Thresholds};

/// The protection's state: which groups are shed and which channels it switched off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Protection {
    /// Shed groups ([`Group::bit`]).
    pub groups: u8,
    /// Channels switched off by the protection, to be restored.
    pub shed: u16,
}

impl Protection {
    /// Whether `g` is shed now.
    pub fn is_shed(&self, g: Group) -> bool {
        self.groups & g.bit() != 0
    }
    /// Whether a command may switch `c` on (not while its group is shed).
    pub fn allows_on(&self, c: Channel) -> bool {
        Group::of(c).is_none_or(|g| !self.is_shed(g))
    }
    /// An operator switched `c` off: it is no longer restored.
    pub fn forget(&mut self, c: Channel) {
        self.shed &= !c.bit();
    }

    /// Apply the thresholds at state of charge `soc` (0..=1) to the channel mask `on`;
    /// returns the switches made, in channel order, and why.
    pub fn update(
        &mut self,
        soc: f64,
        t: &Thresholds,
        on: &mut u16,
    ) -> Vec<(Channel, bool, Group)> {
        let pct = soc * 100.0;
        let mut out = Vec::new();
        for g in Group::ALL {
            let (shed_at, restore_at) = t.of(g);
            if !self.is_shed(g) && pct < f64::from(shed_at) {
                self.groups |= g.bit();
                let off = *on & g.channels();
                self.shed |= off;
                *on &= !off;
                out.extend(
                    Channel::ALL
                        .into_iter()
                        .filter(|c| off & c.bit() != 0)
                        .map(|c| (c, false, g)),
                );
            } else if self.is_shed(g) && pct >= f64::from(restore_at) {
                self.groups &= !g.bit();
                let back = self.shed & g.channels();
                self.shed &= !back;
                *on |= back;
                out.extend(
                    Channel::ALL
                        .into_iter()
                        .filter(|c| back & c.bit() != 0)
                        .map(|c| (c, true, g)),
                );
            }
        }
        out
    }
}

snap::fields!(Protection { groups, shed });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::loads::ALL_CHANNELS;

    #[test]
    fn sheds_below_and_restores_with_hysteresis() {
        let t = Thresholds::default();
        let mut p = Protection::default();
        let mut on = ALL_CHANNELS & !Channel::Payload15.bit();
        assert!(p.update(0.31, &t, &mut on).is_empty());
        let s = p.update(0.299, &t, &mut on);
        assert_eq!(
            s.iter().map(|x| x.0).collect::<Vec<_>>(),
            vec![
                Channel::Payload12,
                Channel::Payload13,
                Channel::Payload14,
                Channel::Sband
            ]
        );
        assert!(s.iter().all(|x| !x.1 && x.2 == Group::Payload));
        assert_eq!(on & Group::Payload.channels(), 0);
        assert!(!p.allows_on(Channel::Payload13));
        assert!(p.allows_on(Channel::Pc));
        // Between the thresholds: nothing happens, in either direction.
        for soc in [0.30, 0.35, 0.399, 0.25] {
            assert!(p.update(soc, &t, &mut on).is_empty(), "{soc}");
        }
        // An operator switches payload 14 off while shed: it is not restored.
        p.forget(Channel::Payload14);
        let r = p.update(0.40, &t, &mut on);
        assert_eq!(r.len(), 3);
        assert!(r.iter().all(|x| x.1));
        assert_eq!(
            on,
            ALL_CHANNELS & !Channel::Payload15.bit() & !Channel::Payload14.bit()
        );
        assert_eq!(p, Protection::default());
    }

    #[test]
    fn both_groups_fall_together_and_comm_is_never_shed() {
        let t = Thresholds::default();
        let mut p = Protection::default();
        let mut on = ALL_CHANNELS;
        let s = p.update(0.05, &t, &mut on);
        assert_eq!(s.len(), 7);
        assert_eq!(on, Channel::Comm1.bit() | Channel::Comm2.bit());
        // 30 %: only the platform group returns.
        let r = p.update(0.30, &t, &mut on);
        assert_eq!(
            r.iter().map(|x| x.0).collect::<Vec<_>>(),
            vec![Channel::Ecu, Channel::Pc]
        );
        assert!(p.is_shed(Group::Payload) && !p.is_shed(Group::Platform));
    }

    #[test]
    fn thresholds_validate() {
        assert!(Thresholds::default().validate().is_ok());
        let bad = Thresholds {
            payload_shed_pct: 40,
            ..Thresholds::default()
        };
        assert_eq!(bad.validate(), Err("payload shed threshold"));
        let bad = Thresholds {
            platform_restore_pct: 101,
            ..Thresholds::default()
        };
        assert!(bad.validate().is_err());
        // Shed 0 disables a group.
        let off = Thresholds {
            payload_shed_pct: 0,
            platform_shed_pct: 0,
            ..Thresholds::default()
        };
        assert!(off.validate().is_ok());
        let mut on = ALL_CHANNELS;
        assert!(Protection::default().update(0.0, &off, &mut on).is_empty());
    }
}
