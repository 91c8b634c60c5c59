//! The PC's platform parameters and self-test (the platform port, [`csp::params`]).
//!
//! # Parameters
//! | id | name | type | unit | range | what it sets |
//! |---|---|---|---|---|---|
//! | 1 | buffer_capacity | u32 | bytes | 256..=268435456 | each buffering session's file capacity |
//! | 2 | poll_period | u16 | ms | 0..=60000 | each polling session's POLL cycle period |
//! | 3 | reply_timeout | u16 | ms | 1..=10000 | each polling session's SYNC/POLL reply timeout |
//! | 4 | sband_rate | u32 | bit/s | 1000..=10000000 | the S-band transmitter's bit rate |
//!
//! The session settings are per payload in the scenario; a parameter reads the first
//! session of its mode (configuration order) and a set applies to every session of that
//! mode. Without such a session the parameter does not exist on this PC (PGET and PSET
//! fail, PLIST leaves it out). A smaller capacity keeps what the file holds (new packets
//! are dropped until it fits again); a new period or timeout applies from the next cycle
//! or request; a new rate from the next frame.
//!
//! # Self-test (wire order)
//! | # | component | reading |
//! |---|---|---|
//! | 1..=4 | session_pl12, session_pl13, session_pl14, session_pl15 | packets of the current or last session |
//! | 5..=8 | buffer_pl12, buffer_pl13, buffer_pl14, buffer_pl15 | buffer file fill, % of its capacity |
//! | 9 | sband | bytes queued in the transmitter |
//!
//! A payload without a session (or without a buffering one, for its file) is reported off.

use std::time::Duration;

use csp::params::{Check, Health, ParamDef, ParamError, ParamType, Table, def};

use crate::{PcApp, SessionMode, SessionResult, SessionState, SimTime};

/// The PC's parameter table.
pub const PARAMS: &[ParamDef] = &[
    def(
        1,
        "buffer_capacity",
        ParamType::U32,
        "bytes",
        256.0,
        268_435_456.0,
        "capacity of each buffering session's file (ICD 3.1.5: 256 MB of memory)",
    ),
    def(
        2,
        "poll_period",
        ParamType::U16,
        "ms",
        0.0,
        60_000.0,
        "polling: from the start of one POLL cycle to the next (0: as fast as replies come)",
    ),
    def(
        3,
        "reply_timeout",
        ParamType::U16,
        "ms",
        1.0,
        10_000.0,
        "polling: wait for a SYNC or POLL reply before a retry (ICD 3.1.4)",
    ),
    def(
        4,
        "sband_rate",
        ParamType::U32,
        "bit/s",
        1_000.0,
        10_000_000.0,
        "S-band transmitter bit rate (from the next frame)",
    ),
];

/// Payload addresses, in self-test order.
const PAYLOADS: [u8; 4] = [12, 13, 14, 15];
const SESSION_CHECKS: [&str; 4] = [
    "session_pl12",
    "session_pl13",
    "session_pl14",
    "session_pl15",
];
const BUFFER_CHECKS: [&str; 4] = ["buffer_pl12", "buffer_pl13", "buffer_pl14", "buffer_pl15"];

fn ms(d: Duration) -> f64 {
    (d.as_secs_f64() * 1e3).round()
}

impl PcApp {
    /// Indices of the sessions with `f` true of their mode.
    fn slots_where(&self, f: impl Fn(&SessionMode) -> bool) -> Vec<usize> {
        self.cfg
            .sessions
            .iter()
            .enumerate()
            .filter(|(_, s)| f(&s.mode))
            .map(|(i, _)| i)
            .collect()
    }

    /// Change session `i`'s specification, in the configuration and in the running table.
    fn respec(&mut self, i: usize, f: impl Fn(&mut crate::SessionSpec)) {
        if let Some(s) = self.cfg.sessions.get_mut(i) {
            f(s);
        }
        if let Some(s) = self.table.slot_mut(i) {
            f(&mut s.spec);
        }
    }

    fn polling(&self) -> Option<(Duration, Duration)> {
        self.cfg.sessions.iter().find_map(|s| match s.mode {
            SessionMode::Polling {
                poll_period,
                reply_timeout,
            } => Some((poll_period, reply_timeout)),
            SessionMode::Buffering => None,
        })
    }
}

/// Why the PC refuses a parameter value the table's range lets through: nothing running
/// that the parameter sets.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PcParamError {
    /// `buffer_capacity` without a buffering session.
    #[error("buffer_capacity: no buffering session")]
    NoBuffering,
    /// `poll_period` or `reply_timeout` without a polling session.
    #[error("{name}: no polling session")]
    NoPolling {
        /// The parameter's name.
        name: &'static str,
    },
}

impl Table for PcApp {
    fn defs(&self) -> &'static [ParamDef] {
        PARAMS
    }

    fn get(&self, id: u8) -> Option<f64> {
        Some(match id {
            1 => {
                self.cfg
                    .sessions
                    .iter()
                    .find(|s| s.mode == SessionMode::Buffering)?
                    .buffer_capacity_bytes as f64
            }
            2 => ms(self.polling()?.0),
            3 => ms(self.polling()?.1),
            4 => self.sband.config().rate_bps as f64,
            _ => return None,
        })
    }

    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
        let d = Duration::from_millis(v as u64);
        match id {
            1 => {
                let slots = self.slots_where(|m| *m == SessionMode::Buffering);
                if slots.is_empty() {
                    return Err(ParamError::refused(PcParamError::NoBuffering));
                }
                for i in slots {
                    self.respec(i, |s| s.buffer_capacity_bytes = v as u64);
                }
            }
            2 | 3 => {
                let slots = self.slots_where(|m| matches!(m, SessionMode::Polling { .. }));
                if slots.is_empty() {
                    let name = if id == 2 {
                        "poll_period"
                    } else {
                        "reply_timeout"
                    };
                    return Err(ParamError::refused(PcParamError::NoPolling { name }));
                }
                for i in slots {
                    self.respec(i, |s| {
                        if let SessionMode::Polling {
                            poll_period,
                            reply_timeout,
                        } = &mut s.mode
                        {
                            if id == 2 {
                                *poll_period = d;
                            } else {
                                *reply_timeout = d;
                            }
                        }
                    });
                }
            }
            4 => {
                self.cfg.sband.rate_bps = v as u64;
                self.sband.set_rate(v as u64);
            }
            _ => return Err(ParamError::Unknown { id }),
        }
        Ok(())
    }
}

impl PcApp {
    /// The PC's self-test: sessions, buffer files, S-band (the module doc gives the order).
    pub(crate) fn checks(&self, _now: SimTime) -> Vec<Check> {
        use csp::params::check;
        let mut v = Vec::with_capacity(2 * PAYLOADS.len() + 1);
        let slot_of = |addr: u8| {
            self.table
                .slots()
                .iter()
                .position(|s| s.spec.payload_addr == addr)
        };
        for (addr, name) in PAYLOADS.into_iter().zip(SESSION_CHECKS) {
            let Some(s) = slot_of(addr).and_then(|i| self.table.slot(i)) else {
                v.push(check(
                    name,
                    Health::Off,
                    0.0,
                    "packets",
                    "no session".into(),
                ));
                continue;
            };
            let mode = match s.spec.mode {
                SessionMode::Polling { .. } => "polling",
                SessionMode::Buffering => "buffering",
            };
            let state = match s.state {
                SessionState::NotActive => "NOT ACTIVE",
                SessionState::Pending => "PENDING",
                SessionState::Active => "ACTIVE",
            };
            let detail = format!(
                "session {} {mode}, {state}, last result {:?}",
                s.spec.session_id, s.last_result
            );
            let health = match (s.state, s.last_result) {
                (SessionState::NotActive, SessionResult::NoAck | SessionResult::SbandFailure) => {
                    Health::Degraded
                }
                _ => Health::Ok,
            };
            v.push(check(name, health, f64::from(s.packets), "packets", detail));
        }
        for (addr, name) in PAYLOADS.into_iter().zip(BUFFER_CHECKS) {
            let Some(i) = self.file_slot(addr) else {
                v.push(check(name, Health::Off, 0.0, "%", "no buffer file".into()));
                continue;
            };
            let len = self.runs.get(i).map_or(0, |r| r.file.len() as u64);
            let cap = self.spec(i).map_or(0, |s| s.buffer_capacity_bytes);
            let pct = if cap > 0 {
                100.0 * len as f64 / cap as f64
            } else {
                100.0
            };
            let detail = format!("{len} of {cap} bytes");
            v.push(if pct >= 90.0 {
                check(
                    name,
                    Health::Degraded,
                    pct,
                    "%",
                    format!("nearly full: {detail}"),
                )
            } else {
                check(name, Health::Ok, pct, "%", detail)
            });
        }
        let sb = &self.sband;
        let queued = sb.total_pending_bytes() as f64;
        let rate = sb.config().rate_bps;
        v.push(if sb.is_failed() {
            check(
                "sband",
                Health::Failed,
                queued,
                "bytes",
                "transmitter failed".into(),
            )
        } else if !sb.is_on() {
            let why = if self.unpowered {
                "power channel off"
            } else {
                "switched off"
            };
            check("sband", Health::Off, queued, "bytes", why.into())
        } else {
            let what = if sb.is_transmitting() {
                "transmitting"
            } else {
                "idle"
            };
            check(
                "sband",
                Health::Ok,
                queued,
                "bytes",
                format!("{what} at {rate} bit/s"),
            )
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

    use crate::{DropReason, PcApp, PcConfig, SessionMode};

    fn host() -> Host<PcApp> {
        let mut c = NodeConfig::new("PC", 6);
        c.ifaces = vec![IfaceConfig::packet("p")];
        c.routes.set_default(Route::direct(0));
        Host::new(c, PcApp::new(PcConfig::default()), SimTime::ZERO)
    }

    /// `req` from `src` to the platform port at `t`: the one reply's data.
    fn ask_from(h: &mut Host<PcApp>, src: u8, req: &[u8], t: SimTime) -> Vec<u8> {
        let port = csp::params::PORT;
        h.handle_packet(
            0,
            Packet::new(Header::new(src, 6, port, 41), req.to_vec()),
            t,
        );
        let out: Vec<Packet> = std::iter::from_fn(|| h.node.poll_transmit())
            .filter_map(|x| match x {
                Transmit::Packet { packet, .. } => Some(packet),
                Transmit::Can { .. } => None,
            })
            .collect();
        assert_eq!(out.len(), 1, "exactly one reply to {req:?}");
        assert_eq!(out[0].header, Header::new(6, src, 41, port));
        out[0].data.clone()
    }

    fn ask(h: &mut Host<PcApp>, req: &[u8], t: SimTime) -> Vec<u8> {
        ask_from(h, 16, req, t)
    }

    fn u32_set(id: u8, v: u32) -> Vec<u8> {
        let mut r = vec![2, id];
        r.extend_from_slice(&v.to_le_bytes());
        r
    }

    fn u32_reply(cmd: u8, id: u8, v: u32) -> Vec<u8> {
        let mut r = vec![cmd, 1, id, 3];
        r.extend_from_slice(&v.to_le_bytes());
        r
    }

    #[test]
    fn platform_parameters_set_the_sessions_and_revert_at_reboot_unless_saved() {
        let mut h = host();
        let s = SimTime::from_secs;
        assert_eq!(
            ask(&mut h, &[1, 1], s(1)),
            u32_reply(1, 1, 256 * 1024 * 1024)
        );
        assert_eq!(ask(&mut h, &[1, 2], s(1)), [1, 1, 2, 2, 100, 0]);
        assert_eq!(ask(&mut h, &[1, 3], s(1)), [1, 1, 3, 2, 200, 0]);
        assert_eq!(ask(&mut h, &[1, 4], s(1)), u32_reply(1, 4, 1_000_000));
        // A 1000-byte file: the fourth 256-byte packet of payload 13 no longer fits.
        assert_eq!(ask(&mut h, &u32_set(1, 1000), s(2)), u32_reply(2, 1, 1000));
        for _ in 0..4 {
            h.handle_packet(
                0,
                Packet::new(Header::new(13, 6, 11, 10), vec![7; 256]),
                s(3),
            );
        }
        let a = h.app.accounting();
        let l = a.session(2).unwrap();
        assert_eq!(
            (l.buffered_now, l.dropped(DropReason::BufferFull)),
            (768, 256)
        );
        // Out of range (capacity below 256 bytes, timeout 0), wrong size: refused.
        assert_eq!(ask(&mut h, &u32_set(1, 100), s(4)), [2, 0]);
        assert_eq!(ask(&mut h, &[2, 3, 0, 0], s(4)), [2, 0]);
        assert_eq!(ask(&mut h, &[2, 2, 1], s(4)), [2, 0]);
        assert_eq!(ask(&mut h, &[1, 1], s(4)), u32_reply(1, 1, 1000));
        // The polling session's period, and the S-band rate.
        assert_eq!(ask(&mut h, &[2, 2, 0xf4, 1], s(5)), [2, 1, 2, 2, 0xf4, 1]);
        assert_eq!(
            h.app.config().sessions[0].mode,
            SessionMode::Polling {
                poll_period: std::time::Duration::from_millis(500),
                reply_timeout: std::time::Duration::from_millis(200),
            }
        );
        assert_eq!(
            ask(&mut h, &u32_set(4, 250_000), s(5)),
            u32_reply(2, 4, 250_000)
        );
        assert_eq!(h.app.sband().config().rate_bps, 250_000);
        // A payload may not use the port (ICD 4.1), not even to read.
        assert_eq!(ask_from(&mut h, 12, &[1, 1], s(5)), [1, 0]);
        // A reboot without PSAVE: the factory table.
        h.reboot(s(6));
        assert_eq!(
            ask(&mut h, &[1, 1], s(6)),
            u32_reply(1, 1, 256 * 1024 * 1024)
        );
        assert_eq!(ask(&mut h, &[1, 2], s(6)), [1, 1, 2, 2, 100, 0]);
        assert_eq!(h.app.sband().config().rate_bps, 1_000_000);
        // Saved: kept over the reboot, in the running table too.
        assert_eq!(ask(&mut h, &u32_set(1, 4096), s(7)), u32_reply(2, 1, 4096));
        assert_eq!(ask(&mut h, &[5], s(7)), [5, 1]);
        h.reboot(s(8));
        assert_eq!(ask(&mut h, &[1, 1], s(8)), u32_reply(1, 1, 4096));
        assert_eq!(
            h.app.table.slot(1).unwrap().spec.buffer_capacity_bytes,
            4096
        );
    }

    #[test]
    fn selftest_reports_sessions_files_and_the_sband() {
        let mut h = host();
        let s = SimTime::from_secs;
        h.handle_packet(
            0,
            Packet::new(Header::new(13, 6, 11, 10), vec![7; 200]),
            s(1),
        );
        assert_eq!(
            ask(&mut h, &u32_set(1, 220), s(1))[..2],
            [2, 0],
            "below 256"
        );
        assert_eq!(ask(&mut h, &u32_set(1, 256), s(1))[..2], [2, 1]);
        let r = ask(&mut h, &[7], s(2));
        assert_eq!(r[..2], [7, 1]);
        assert_eq!(r[3], 9);
        assert_eq!(r.len(), 4 + 9 * 5);
        let entry = |i: usize| {
            let at = 4 + 5 * i;
            (
                r[at],
                f32::from_le_bytes(r[at + 1..at + 5].try_into().unwrap()),
            )
        };
        // Sessions: 12 polling and 13 buffering, none for 14 and 15.
        assert_eq!([entry(0), entry(1)], [(0, 0.0), (0, 0.0)]);
        assert_eq!([entry(2).0, entry(3).0], [3, 3]);
        // Files: only payload 13's, 200 of 256 bytes (78 %).
        assert_eq!(entry(4).0, 3);
        assert_eq!(entry(5), (0, 78.125));
        assert_eq!([entry(6).0, entry(7).0], [3, 3]);
        // The S-band: on, nothing queued.
        assert_eq!(entry(8), (0, 0.0));
        assert_eq!(r[2], 0);
        // Fuller than 90 %: degraded.
        h.handle_packet(
            0,
            Packet::new(Header::new(13, 6, 11, 10), vec![7; 40]),
            s(3),
        );
        let r = ask(&mut h, &[7], s(3));
        assert_eq!((r[2], r[4 + 5 * 5]), (1, 1));
    }
}
