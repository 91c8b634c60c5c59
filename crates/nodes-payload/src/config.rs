//! The simulated payload's platform parameters and self-test (the platform port,
//! [`csp::params`]).
//!
//! # Parameters
//! | id | name | type | unit | range | what it sets |
//! |---|---|---|---|---|---|
//! | 1 | push_rate | u32 | bytes/s | 0..=125000 | the filling rate of the PC's file (buffering payloads; 0 stops) |
//! | 2 | push_packet_bytes | u16 | bytes | 1..=256 | data bytes per pushed packet (buffering payloads) |
//! | 3 | stream_rate | u32 | bytes/s | 0..=10000000 | the rate the payload makes data at (0: no limit) |
//! | 4 | reply_latency | u16 | ms | 0..=10000 | delay from a SYNC or POLL to its reply |
//!
//! ICD 3.1.5: "a payload should be able to change its filling rate". A payload that does
//! not push (polling) has no parameters 1 and 2 (PGET and PSET fail, PLIST leaves them
//! out). A new push rate or packet size restarts the push schedule: the next packet one new
//! period after the change. A new stream rate counts from its instant (what was made stays
//! made). 125000 bytes/s is the payload CAN bus's 1 Mbit/s: a push cannot go faster.
//!
//! # Self-test (wire order)
//! | # | component | reading |
//! |---|---|---|
//! | 1 | stream | bytes produced so far |
//! | 2 | responder | replies waiting |
//! | 3 | push | bytes pushed this run (off: not pushing) |

use std::time::Duration;

use csp::params::{Check, Health, ParamDef, ParamError, ParamType, Table, def};

use crate::{Behaviour, MAX_QUEUED_REPLIES, PayloadApp, SimTime};

/// The payload's parameter table.
pub const PARAMS: &[ParamDef] = &[
    def(
        1,
        "push_rate",
        ParamType::U32,
        "bytes/s",
        0.0,
        125_000.0,
        "buffering: bytes per second pushed to the PC's file (the filling rate; 0 stops)",
    ),
    def(
        2,
        "push_packet_bytes",
        ParamType::U16,
        "bytes",
        1.0,
        256.0,
        "buffering: data bytes per pushed packet (ICD 3.1.5: at most 256)",
    ),
    def(
        3,
        "stream_rate",
        ParamType::U32,
        "bytes/s",
        0.0,
        10_000_000.0,
        "rate the payload makes data at, for POLL replies and pushes (0: no limit)",
    ),
    def(
        4,
        "reply_latency",
        ParamType::U16,
        "ms",
        0.0,
        10_000.0,
        "delay from a SYNC or POLL to its reply",
    ),
];

/// Why a payload refuses a parameter value the table's range lets through.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PushParamError {
    /// `push_rate` or `push_packet_bytes` on a payload that is polled, not pushing.
    #[error("push: this payload does not push (polling)")]
    Polling,
}

impl Table for PayloadApp {
    fn defs(&self) -> &'static [ParamDef] {
        PARAMS
    }

    fn get(&self, id: u8) -> Option<f64> {
        Some(match id {
            1 => self.cfg.push.as_ref()?.rate_bytes_per_s as f64,
            2 => f64::from(self.cfg.push.as_ref()?.packet_bytes),
            3 => self.cfg.rate_bytes_per_s.map_or(0.0, |r| r as f64),
            4 => (self.cfg.reply_latency.as_secs_f64() * 1e3).round(),
            _ => return None,
        })
    }

    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
        match id {
            1 | 2 => {
                let Some(p) = &mut self.cfg.push else {
                    return Err(ParamError::refused(PushParamError::Polling));
                };
                if id == 1 {
                    p.rate_bytes_per_s = v as u64;
                } else {
                    p.packet_bytes = v as u16;
                }
                self.push_pending = true;
            }
            3 => {
                self.cfg.rate_bytes_per_s = (v > 0.0).then_some(v as u64);
                self.stream_rate_pending = true;
            }
            4 => self.cfg.reply_latency = Duration::from_millis(v as u64),
            _ => return Err(ParamError::Unknown { id }),
        }
        Ok(())
    }
}

impl PayloadApp {
    /// The payload's self-test at `now`: stream, responder, push (the module doc gives the
    /// order).
    pub(crate) fn checks(&self, now: SimTime) -> Vec<Check> {
        use csp::params::check;
        let mut v = Vec::with_capacity(3);
        let produced = self.counters.produced_bytes as f64;
        let rate = match self.stream.rate() {
            Some(r) => format!("{r} bytes/s"),
            None => "no rate limit".to_owned(),
        };
        v.push(if self.stream.is_exhausted() {
            check(
                "stream",
                Health::Off,
                produced,
                "bytes",
                "file sent whole".into(),
            )
        } else {
            let ready = self.stream.available(now);
            let ready = if ready > 1 << 53 {
                "unlimited".to_owned()
            } else {
                ready.to_string()
            };
            check(
                "stream",
                Health::Ok,
                produced,
                "bytes",
                format!("{rate}, {ready} bytes ready"),
            )
        });
        let queued = self.queue.len();
        let b = &self.behaviour;
        let health = match b {
            Behaviour::Normal => Health::Ok,
            Behaviour::Silent | Behaviour::Garbage => Health::Failed,
            _ => Health::Degraded,
        };
        let health = if queued >= MAX_QUEUED_REPLIES {
            health.max(Health::Degraded)
        } else {
            health
        };
        v.push(check(
            "responder",
            health,
            queued as f64,
            "",
            format!("behaviour {b}, {queued} replies waiting"),
        ));
        let pushed = self.counters.pushed_bytes as f64;
        v.push(match &self.cfg.push {
            None => check(
                "push",
                Health::Off,
                pushed,
                "bytes",
                "polling payload".into(),
            ),
            Some(p) if p.rate_bytes_per_s == 0 => {
                check("push", Health::Off, pushed, "bytes", "rate 0".into())
            }
            Some(p) if p.stop.is_some_and(|s| s <= now) => {
                check("push", Health::Off, pushed, "bytes", "stopped".into())
            }
            Some(p) => check(
                "push",
                Health::Ok,
                pushed,
                "bytes",
                format!(
                    "{} bytes/s in packets of {}, {} packets, {} empty slots",
                    p.rate_bytes_per_s,
                    p.packet_len(),
                    self.counters.pushed_packets,
                    self.counters.push_empty_slots
                ),
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

    use crate::{PayloadApp, PayloadConfig, PushConfig};

    fn host(cfg: PayloadConfig) -> Host<PayloadApp> {
        let mut c = NodeConfig::new("PL13", 13);
        c.ifaces = vec![IfaceConfig::packet("p")];
        c.routes.set_default(Route::direct(0));
        Host::new(c, PayloadApp::new(cfg), SimTime::ZERO)
    }

    fn pushing() -> PayloadConfig {
        PayloadConfig {
            push: Some(PushConfig {
                packet_bytes: 100,
                rate_bytes_per_s: 1000,
                ..PushConfig::default()
            }),
            ..PayloadConfig::default()
        }
    }

    /// Everything the node sent: (destination port, data).
    fn sent(h: &mut Host<PayloadApp>) -> Vec<(u8, Vec<u8>)> {
        std::iter::from_fn(|| h.node.poll_transmit())
            .filter_map(|x| match x {
                Transmit::Packet { packet, .. } => Some((packet.header.dport, packet.data)),
                Transmit::Can { .. } => None,
            })
            .collect()
    }

    /// `req` from the ground to the platform port at `t`: the one reply's data (pushes
    /// pending in the node's queue are left out).
    fn ask(h: &mut Host<PayloadApp>, req: &[u8], t: SimTime) -> Vec<u8> {
        let port = csp::params::PORT;
        h.handle_packet(
            0,
            Packet::new(Header::new(16, 13, port, 41), req.to_vec()),
            t,
        );
        let out: Vec<Vec<u8>> = sent(h)
            .into_iter()
            .filter(|(p, _)| *p == 41)
            .map(|x| x.1)
            .collect();
        assert_eq!(out.len(), 1, "exactly one reply to {req:?}");
        out[0].clone()
    }

    /// Run the timers up to `until`; the push packets sent, with their times.
    fn drive(h: &mut Host<PayloadApp>, until: SimTime) -> Vec<(SimTime, usize)> {
        let mut out = Vec::new();
        while let Some(t) = h.poll_timeout().filter(|&t| t <= until) {
            h.handle_timeout(t);
            out.extend(
                sent(h)
                    .into_iter()
                    .filter(|x| x.0 == 11)
                    .map(|x| (t, x.1.len())),
            );
        }
        out
    }

    fn u32_req(id: u8, v: u32) -> Vec<u8> {
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
    fn platform_push_rate_changes_the_filling_rate_and_reverts_at_reboot_unless_saved() {
        let mut h = host(pushing());
        let ms = SimTime::from_ms;
        assert_eq!(ask(&mut h, &[1, 1], ms(0)), u32_reply(1, 1, 1000));
        assert_eq!(ask(&mut h, &[1, 2], ms(0)), [1, 1, 2, 2, 100, 0]);
        assert_eq!(ask(&mut h, &[1, 3], ms(0)), u32_reply(1, 3, 0));
        // 100-byte packets every 100 ms.
        let p = drive(&mut h, ms(1000));
        assert_eq!(p.len(), 11);
        assert_eq!(p[10], (ms(1000), 100));
        // Filling at 500 bytes/s from 1050 ms: the next packet 200 ms later.
        assert_eq!(
            ask(&mut h, &u32_req(1, 500), ms(1050)),
            u32_reply(2, 1, 500)
        );
        h.handle_timeout(ms(1050));
        let p = drive(&mut h, ms(1700));
        assert_eq!(
            p.iter().map(|x| x.0).collect::<Vec<_>>(),
            [ms(1250), ms(1450), ms(1650)]
        );
        // Out of range (above the bus's 125000 bytes/s, packets of 257), wrong size.
        assert_eq!(ask(&mut h, &u32_req(1, 125_001), ms(1700)), [2, 0]);
        assert_eq!(ask(&mut h, &[2, 2, 1, 1], ms(1700)), [2, 0]);
        assert_eq!(ask(&mut h, &[2, 2, 1], ms(1700)), [2, 0]);
        assert_eq!(ask(&mut h, &[1, 1], ms(1700)), u32_reply(1, 1, 500));
        // A reboot without PSAVE: back to 1000 bytes/s.
        h.reboot(ms(2000));
        assert_eq!(ask(&mut h, &[1, 1], ms(2000)), u32_reply(1, 1, 1000));
        let p = drive(&mut h, ms(2300));
        assert_eq!(
            p.iter().map(|x| x.0).collect::<Vec<_>>(),
            [ms(2100), ms(2200), ms(2300)]
        );
        // Saved: kept over the reboot, the schedule restarted at the boot.
        assert_eq!(
            ask(&mut h, &u32_req(1, 250), ms(2300)),
            u32_reply(2, 1, 250)
        );
        assert_eq!(ask(&mut h, &[5], ms(2300)), [5, 1]);
        h.reboot(ms(3000));
        assert_eq!(ask(&mut h, &[1, 1], ms(3000)), u32_reply(1, 1, 250));
        let p = drive(&mut h, ms(3900));
        assert_eq!(
            p.iter().map(|x| x.0).collect::<Vec<_>>(),
            [ms(3400), ms(3800)]
        );
    }

    #[test]
    fn a_polling_payload_has_no_push_parameters_but_a_stream_rate() {
        let mut h = host(PayloadConfig::default());
        let s = SimTime::from_secs;
        assert_eq!(ask(&mut h, &[1, 1], s(1)), [1, 0]);
        assert_eq!(ask(&mut h, &u32_req(1, 100), s(1)), [2, 0]);
        // The stream made at 1000 bytes/s from 1 s: 1000 bytes ready at 2 s.
        assert_eq!(ask(&mut h, &u32_req(3, 1000), s(1)), u32_reply(2, 3, 1000));
        h.handle_timeout(s(1));
        assert_eq!(h.app.available_bytes(s(2)), 1000);
        // PLIST from 1: stream_rate and reply_latency only.
        let l = ask(&mut h, &[4, 1], s(2));
        assert_eq!(l[..4], [4, 1, 0xFF, 2]);
    }

    #[test]
    fn selftest_reports_stream_responder_and_push() {
        let mut h = host(pushing());
        drive(&mut h, SimTime::from_ms(500));
        let r = ask(&mut h, &[7], SimTime::from_ms(500));
        assert_eq!(r[..4], [7, 1, 0, 3]);
        assert_eq!(r.len(), 4 + 3 * 5);
        let entry = |i: usize| {
            let at = 4 + 5 * i;
            (
                r[at],
                f32::from_le_bytes(r[at + 1..at + 5].try_into().unwrap()),
            )
        };
        assert_eq!(entry(0), (0, 600.0), "six packets of 100 bytes produced");
        assert_eq!(entry(1), (0, 0.0), "normal, nothing waiting");
        assert_eq!(entry(2), (0, 600.0));
        // A polling payload: the push is off; overall still ok.
        let mut h = host(PayloadConfig::default());
        let r = ask(&mut h, &[7], SimTime::from_ms(1));
        assert_eq!([r[2], r[4], r[9], r[14]], [0, 0, 0, 3]);
    }
}
