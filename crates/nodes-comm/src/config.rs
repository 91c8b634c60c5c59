//! COMM's platform parameters and self-test (the platform port, [`csp::params`]).
//!
//! # Parameters
//! | id | name | type | unit | range | what it sets |
//! |---|---|---|---|---|---|
//! | 1 | beacon_period | u16 | s | 0, 10..=3600 | the beacon period (BEACONGET/BEACONSET's; 0 off) |
//! | 2 | beacon_dest | u8 | | 16..=20 | the ground station address beacons go to |
//! | 3 | tx_eirp | f32 | dBm | 10..=37 | the transmitter's EIRP in the downlink budget |
//!
//! `beacon_period` is the value BEACONGET reads and BEACONSET sets; a PSET restarts the
//! schedule from that instant, as BEACONSET does. `tx_eirp` moves the RSSI and SNR that
//! TMCOMM and the beacon report ([`crate::link`]); the air link itself (`bus::net`) and the
//! EPS's transmit load do not depend on it. The elevation mask and the UHF rate are not
//! parameters: the twin's pass timeline and air link use the scenario's values, and COMM
//! only reports them.
//!
//! # Self-test (wire order)
//! | # | component | reading |
//! |---|---|---|
//! | 1 | radio | EIRP, dBm (off: standby) |
//! | 2 | link | RSSI of the downlink, dBm (the noise floor out of contact) |
//! | 3 | beacons | beacons sent since boot |
//!
//! The radio has no temperature model.

use std::time::Duration;

use csp::params::{Check, Health, ParamDef, ParamError, ParamType, Table, def};

use crate::{CommApp, SimTime, wire};

/// COMM's parameter table.
pub const PARAMS: &[ParamDef] = &[
    def(
        1,
        "beacon_period",
        ParamType::U16,
        "s",
        0.0,
        wire::BEACON_PERIOD_MAX_S as f64,
        "beacon period, 0 (off) or 10..=3600 s; BEACONSET's value; the schedule restarts now",
    ),
    def(
        2,
        "beacon_dest",
        ParamType::U8,
        "",
        16.0,
        20.0,
        "CSP address of the ground station the beacons go to",
    ),
    def(
        3,
        "tx_eirp",
        ParamType::F32,
        "dBm",
        10.0,
        37.0,
        "transmitter EIRP (29 dBm: 1 W, 0 dBi, 1 dB line loss): the reported downlink RSSI and SNR",
    ),
];

/// Why COMM refuses a parameter value the table's range lets through.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CommParamError {
    /// A beacon period below BEACONSET's shortest (other than 0, off).
    #[error(
        "beacon_period {period_s} s: 0 (off) or {min_s}..={} s",
        wire::BEACON_PERIOD_MAX_S
    )]
    BeaconPeriod {
        /// The period asked for.
        period_s: u64,
        /// The shortest period other than off.
        min_s: u64,
    },
}

impl Table for CommApp {
    fn defs(&self) -> &'static [ParamDef] {
        PARAMS
    }

    fn get(&self, id: u8) -> Option<f64> {
        Some(match id {
            1 => self.period.as_secs() as f64,
            2 => f64::from(self.cfg.ground_addr),
            3 => self.cfg.link.eirp_dbm,
            _ => return None,
        })
    }

    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
        match id {
            1 => {
                let s = v as u64;
                let min = u64::from(wire::BEACON_PERIOD_MIN_S);
                if s != 0 && s < min {
                    return Err(ParamError::refused(CommParamError::BeaconPeriod {
                        period_s: s,
                        min_s: min,
                    }));
                }
                let p = Duration::from_secs(s);
                self.cfg.beacon_period = p;
                self.period = p;
                // As BEACONSET: the schedule restarts from now (the next timer; at boot,
                // the start arms it).
                self.arm_pending = true;
            }
            2 => self.cfg.ground_addr = v as u8,
            3 => self.cfg.link.eirp_dbm = v,
            _ => return Err(ParamError::Unknown { id }),
        }
        Ok(())
    }
}

impl CommApp {
    /// COMM's self-test at `now`: radio, link, beacons (the module doc gives the order).
    pub(crate) fn checks(&self, now: SimTime) -> Vec<Check> {
        use csp::params::check;
        let role = match self.cfg.role {
            crate::CommRole::Primary => "primary",
            crate::CommRole::Secondary => "secondary",
        };
        let eirp = self.cfg.link.eirp_dbm;
        let mut v = Vec::with_capacity(3);
        v.push(if self.active {
            check("radio", Health::Ok, eirp, "dBm", format!("{role}, active"))
        } else {
            check(
                "radio",
                Health::Off,
                eirp,
                "dBm",
                format!("{role}, standby"),
            )
        });
        let noise = self.cfg.link.noise_dbm();
        v.push(match (self.active, self.link_state(now)) {
            (false, _) => check("link", Health::Off, noise, "dBm", "standby".to_owned()),
            (true, None) => check(
                "link",
                Health::Degraded,
                noise,
                "dBm",
                "no position from the FC (or no station): no link budget".to_owned(),
            ),
            (true, Some(l)) => {
                let name = self
                    .cfg
                    .stations
                    .get(l.station)
                    .map_or("?", |s| s.name.as_str());
                let detail = if l.in_contact {
                    format!(
                        "in contact with {name} at {:.1} deg, {:.0} km, SNR {:.1} dB",
                        l.elevation_deg, l.range_km, l.snr_db
                    )
                } else {
                    format!(
                        "no contact: {name} at {:.1} deg (mask {:.1} deg)",
                        l.elevation_deg, self.cfg.mask_deg
                    )
                };
                check("link", Health::Ok, l.rssi_dbm, "dBm", detail)
            }
        });
        let sent = f64::from(self.seq);
        let failures = self.counters.beacon_failures;
        v.push(if !self.active || self.period.is_zero() {
            let why = if self.active {
                "period 0"
            } else {
                "radio on standby"
            };
            check("beacons", Health::Off, sent, "", why.to_owned())
        } else if failures > 0 {
            check(
                "beacons",
                Health::Degraded,
                sent,
                "",
                format!("{failures} beacons could not be sent this run"),
            )
        } else {
            check(
                "beacons",
                Health::Ok,
                sent,
                "",
                format!("every {} s", self.period.as_secs()),
            )
        });
        v
    }
}
