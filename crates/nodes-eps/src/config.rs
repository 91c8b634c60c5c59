//! The EPS's platform parameters and self-test (the platform port, [`csp::params`]).
//!
//! # Parameters
//! | id | name | type | unit | range | what it sets |
//! |---|---|---|---|---|---|
//! | 1 | payload_shed_soc | u8 | % | 0..=99 | THRSET's payload shed threshold |
//! | 2 | payload_restore_soc | u8 | % | 1..=100 | THRSET's payload restore threshold |
//! | 3 | platform_shed_soc | u8 | % | 0..=99 | THRSET's platform shed threshold |
//! | 4 | platform_restore_soc | u8 | % | 1..=100 | THRSET's platform restore threshold |
//! | 5 | max_charge_power | f32 | W | 1..=100 | the battery's charge power limit |
//!
//! The thresholds are the very values THRGET reads and THRSET sets, with THRSET's rule: a
//! group's shed threshold stays below its restore threshold (a PSET that would break it is
//! refused; set the thresholds in the order that keeps it, or use THRSET for all four at
//! once). A shed threshold of 0 never sheds that group. At boot the saved table (or the
//! defaults) is taken whole, whatever the order of its values.
//!
//! # Self-test (wire order)
//! | # | component | reading |
//! |---|---|---|
//! | 1 | battery | state of charge, % |
//! | 2 | battery_capacity | usable capacity now, Wh |
//! | 3 | solar_array | array power, W |
//! | 4..=12 | ch_comm1, ch_comm2, ch_ecu, ch_pc, ch_pl12, ch_pl13, ch_pl14, ch_pl15, ch_sband | channel current at the battery voltage, mA |
//!
//! The battery has no temperature model (a heated box near 20 C, [`crate::battery`]): the
//! self-test reports none.

use csp::params::{Check, Health, ParamDef, ParamError, ParamType, Table, check, def};
use platform::board::Activity;

use crate::loads::{CHANNELS, Channel};
use crate::protect::{Group, Thresholds};
use crate::{EpsApp, SimTime};

/// The EPS's parameter table.
pub const PARAMS: &[ParamDef] = &[
    def(
        1,
        "payload_shed_soc",
        ParamType::U8,
        "%",
        0.0,
        99.0,
        "charge below which payloads 12-15 and the S-band are shed (0: never); below payload_restore_soc (THRSET byte 0)",
    ),
    def(
        2,
        "payload_restore_soc",
        ParamType::U8,
        "%",
        1.0,
        100.0,
        "charge at which the shed payload group is restored; above payload_shed_soc (THRSET byte 1)",
    ),
    def(
        3,
        "platform_shed_soc",
        ParamType::U8,
        "%",
        0.0,
        99.0,
        "charge below which the PC and the ECU are shed (0: never); below platform_restore_soc (THRSET byte 2)",
    ),
    def(
        4,
        "platform_restore_soc",
        ParamType::U8,
        "%",
        1.0,
        100.0,
        "charge at which the shed platform group is restored; above platform_shed_soc (THRSET byte 3)",
    ),
    def(
        5,
        "max_charge_power",
        ParamType::F32,
        "W",
        1.0,
        100.0,
        "largest battery charge power at its terminals; the surplus is left on the arrays",
    ),
];

/// Self-test names of the channels, in [`Channel::ALL`] order.
const CHANNEL_CHECKS: [&str; CHANNELS] = [
    "ch_comm1", "ch_comm2", "ch_ecu", "ch_pc", "ch_pl12", "ch_pl13", "ch_pl14", "ch_pl15",
    "ch_sband",
];

impl Table for EpsApp {
    fn defs(&self) -> &'static [ParamDef] {
        PARAMS
    }

    fn get(&self, id: u8) -> Option<f64> {
        let t = self.eps.thresholds();
        Some(match id {
            1 => f64::from(t.payload_shed_pct),
            2 => f64::from(t.payload_restore_pct),
            3 => f64::from(t.platform_shed_pct),
            4 => f64::from(t.platform_restore_pct),
            5 => self.eps.battery().config().max_charge_w,
            _ => return None,
        })
    }

    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
        match id {
            1..=4 => {
                let mut t = self.eps.thresholds();
                let pct = v.round().clamp(0.0, 100.0) as u8;
                match id {
                    1 => t.payload_shed_pct = pct,
                    2 => t.payload_restore_pct = pct,
                    3 => t.platform_shed_pct = pct,
                    _ => t.platform_restore_pct = pct,
                }
                // At boot the table is taken whole (it kept the rule when it was saved);
                // one value at a time it could cross the one in force before.
                if !self.booting {
                    rule(&t).map_err(ParamError::refused)?;
                }
                self.cfg.thresholds = t;
                self.eps.set_configured_thresholds(t);
            }
            5 => {
                self.cfg.battery.max_charge_w = v;
                self.eps.set_max_charge_w(v);
            }
            _ => return Err(ParamError::Unknown { id }),
        }
        Ok(())
    }
}

/// A parameter value that breaks THRSET's rule, with the parameters' names.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ThresholdRuleError {
    /// A group's shed threshold at or above its restore threshold, or a restore above 100 %.
    #[error("{group}_shed_soc {shed_pct} % must stay below {group}_restore_soc {restore_pct} %")]
    ShedNotBelowRestore {
        /// The group's name in the parameters' (`payload`, `platform`).
        group: &'static str,
        /// Its shed threshold, % SOC.
        shed_pct: u8,
        /// Its restore threshold, % SOC.
        restore_pct: u8,
    },
}

/// THRSET's rule, with the parameters' names.
fn rule(t: &Thresholds) -> Result<(), ThresholdRuleError> {
    for g in Group::ALL {
        let (shed, restore) = t.of(g);
        if shed >= restore || restore > 100 {
            let group = match g {
                Group::Payload => "payload",
                Group::Platform => "platform",
            };
            return Err(ThresholdRuleError::ShedNotBelowRestore {
                group,
                shed_pct: shed,
                restore_pct: restore,
            });
        }
    }
    Ok(())
}

impl EpsApp {
    /// The EPS's self-test at `now` (integrated up to `now` by the caller): battery,
    /// arrays, channels (the module doc gives the order).
    pub(crate) fn checks(&self, now: SimTime) -> Vec<Check> {
        let mut v = Vec::with_capacity(3 + CHANNELS);
        let last = self.eps.last();
        let b = &last.battery;
        let prot = self.eps.protection();
        v.push(self.battery_check());
        let rated = self.cfg.battery.capacity_wh;
        let now_wh = self.eps.battery().config().capacity_wh;
        v.push(check(
            "battery_capacity",
            if now_wh < 0.8 * rated {
                Health::Degraded
            } else {
                Health::Ok
            },
            now_wh,
            "Wh",
            format!("{:.0} % of the rated {rated:.1} Wh", 100.0 * now_wh / rated),
        ));
        v.push(self.solar_array_check());
        let volts = b.voltage_v;
        for (c, name) in Channel::ALL.into_iter().zip(CHANNEL_CHECKS) {
            let w = last
                .loads
                .channel_w
                .get(usize::from(c.id()))
                .copied()
                .unwrap_or(0.0);
            let ma = if volts > 0.0 { w / volts * 1000.0 } else { 0.0 };
            let held = c.node_addr().is_some_and(|addr| {
                self.activity
                    .as_ref()
                    .is_some_and(|a| a.on_before(Activity::PowerFault(addr), now))
            });
            v.push(if !self.eps.is_on(c) {
                let why = if prot.shed & c.bit() != 0 {
                    "shed by the protection"
                } else {
                    "switched off"
                };
                check(name, Health::Off, ma, "mA", why.to_owned())
            } else if held {
                check(
                    name,
                    Health::Failed,
                    ma,
                    "mA",
                    "on, but a power fault holds its node off".to_owned(),
                )
            } else {
                check(name, Health::Ok, ma, "mA", String::new())
            });
        }
        v
    }

    /// The battery's check: empty fails; a shed group or a charge below payload shed degrades.
    fn battery_check(&self) -> Check {
        let b = &self.eps.last().battery;
        let soc_pct = self.eps.soc() * 100.0;
        let t = self.eps.thresholds();
        let prot = self.eps.protection();
        let shed: Vec<&str> = Group::ALL
            .into_iter()
            .filter(|g| prot.is_shed(*g))
            .map(|g| match g {
                Group::Payload => "payload",
                Group::Platform => "platform",
            })
            .collect();
        let volts = format!("{:.2} V, {:+.2} A", b.voltage_v, b.current_a);
        if b.unmet_w > 0.0 {
            check(
                "battery",
                Health::Failed,
                soc_pct,
                "%",
                format!("empty: {:.2} W of load unsupplied, {volts}", b.unmet_w),
            )
        } else if !shed.is_empty() || soc_pct < f64::from(t.payload_shed_pct) {
            let groups = if shed.is_empty() {
                "none yet".to_owned()
            } else {
                shed.join(", ")
            };
            check(
                "battery",
                Health::Degraded,
                soc_pct,
                "%",
                format!("low: groups shed: {groups}; {volts}"),
            )
        } else {
            check("battery", Health::Ok, soc_pct, "%", volts)
        }
    }

    /// The solar array's check: which panels failed, and whether the working ones see the Sun.
    fn solar_array_check(&self) -> Check {
        let last = self.eps.last();
        let failed: Vec<&str> = self
            .eps
            .failed_panels()
            .iter()
            .zip(&self.cfg.panels.panels)
            .filter(|(f, _)| **f)
            .map(|(_, p)| p.name.as_str())
            .collect();
        let n = self.eps.failed_panels().len();
        match failed.len() {
            0 => check(
                "solar_array",
                Health::Ok,
                last.solar_w,
                "W",
                if last.solar_w > 0.0 {
                    format!("{n} panels")
                } else {
                    format!("{n} panels, no sun on them")
                },
            ),
            k if k == n => check(
                "solar_array",
                Health::Failed,
                last.solar_w,
                "W",
                "every panel failed".to_owned(),
            ),
            _ => check(
                "solar_array",
                Health::Degraded,
                last.solar_w,
                "W",
                format!("failed: {}", failed.join(", ")),
            ),
        }
    }
}
