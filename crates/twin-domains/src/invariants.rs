//! Invariants: what must hold in every run, whatever the scenario (a campaign checks them on
//! every run, beside the scenario's own expectations). Each violation names the invariant,
//! the instant and the values.
//!
//! Checked while the run goes ([`Invariants::observe`], every event) and on its report
//! ([`Invariants::finish`]):
//! - `unit-quaternion`: the true attitude and the ADCS's estimate are unit quaternions
//!   (|q| within 1e-6 of 1);
//! - `finite-state`: the true position, velocity and body rate are finite;
//! - `soc-range`: the battery's state of charge stays within [0, 1];
//! - `one-active-session`: at most one PC session is ACTIVE at any time;
//! - `pc-balanced`: the PC's byte accounting balances (produced = downlinked + dropped by
//!   reason + held) when it reports it;
//! - `frames-accounted`: every CAN frame a node handed to its controller was sent, lost for
//!   a counted reason (transmit queue full, bus-off, off the bus), or is still queued;
//! - `silent-while-off`: no node hands its controller a frame while it is off the bus
//!   (unpowered);
//! - `icd-reply-length`: every reply of a platform node has the length the ICD's table
//!   gives its command ([`twin_core::icd_lengths`]; with [`Invariants::for_run`]);
//! - `no-reply-storm`: no two addresses exchange more than a bounded number of packets a
//!   second each way on one medium, counted over fixed windows (default 200 a second over
//!   10 s; the scenario's `[invariants.no_reply_storm]`). Two nodes that take each other's
//!   answers for requests answer each other for ever, at whatever rate the bus allows: the
//!   loop fails the run by name, whatever made it. A flow one way (a payload's push, a
//!   beacon) is not an exchange, however fast.
//!
//! ```toml
//! [invariants.no_reply_storm]
//! packets_per_s = 200   # the most packets a second between two addresses on one medium
//! window = "10s"        # counted over consecutive windows of this length
//! ```

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use csp::SimTime;

use twin_core::events::RunEvent;
use twin_report::RunReport;
use twin_scenario::scenario::{PathStep, Scenario};

pub use twin_scenario::invariants::*;

/// The invariants' settings for a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InvariantSettings {
    /// The invariants the run checks (its verdicts include them).
    pub check: Vec<InvariantName>,
    /// `no-reply-storm`: at most this many packets each way between two addresses on one
    /// medium...
    pub storm_packets_per_s: u32,
    /// ... a second, counted over consecutive windows of this length.
    pub storm_window: Duration,
}

impl Default for InvariantSettings {
    /// The bound is well above anything a shipped scenario does (its busiest pair, a
    /// payload pushing to the PC, is near 20 packets a second) and well below a loop between
    /// two nodes (thousands a second on the main bus).
    fn default() -> Self {
        InvariantSettings {
            check: Vec::new(),
            storm_packets_per_s: 200,
            storm_window: Duration::from_secs(10),
        }
    }
}

/// Check `[invariants]`: a rate of at least 1 a second, a window of 1 s to 1 h.
pub fn validate(s: &Scenario, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let Some(storm) = &s.invariants.no_reply_storm else {
        return;
    };
    let path = |key: &str| {
        vec![
            PathStep::Key("invariants".into()),
            PathStep::Key("no_reply_storm".into()),
            PathStep::Key(key.into()),
        ]
    };
    if storm.packets_per_s == Some(0) {
        err(path("packets_per_s"), "at least 1 packet a second".into());
    }
    if let Some(w) = storm.window
        && !(Duration::from_secs(1)..=Duration::from_secs(3600)).contains(&w.0)
    {
        err(path("window"), "from 1s to 1h".into());
    }
}

/// The run's settings from the scenario's `[invariants]`.
pub fn compile(s: &Scenario) -> InvariantSettings {
    let check = match &s.invariants.check {
        None => Vec::new(),
        Some(InvariantCheck::All(_)) => InvariantName::ALL.to_vec(),
        Some(InvariantCheck::Names(n)) => {
            let mut n = n.clone();
            n.sort();
            n.dedup();
            n
        }
    };
    let mut out = InvariantSettings {
        check,
        ..InvariantSettings::default()
    };
    if let Some(storm) = &s.invariants.no_reply_storm {
        if let Some(n) = storm.packets_per_s {
            out.storm_packets_per_s = n;
        }
        if let Some(w) = storm.window {
            out.storm_window = w.0;
        }
    }
    out
}

/// One invariant broken: the first instant it was seen.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation {
    /// The invariant.
    pub name: InvariantName,
    /// When.
    pub t: SimTime,
    /// The values that break it.
    pub detail: String,
}

/// The invariants' state over one run: the first violation of each.
#[derive(Debug, Default)]
pub struct Invariants {
    first: BTreeMap<InvariantName, Violation>,
    icd: Option<twin_core::icd_lengths::IcdTable>,
    /// Platform replies checked against the ICD's table so far.
    pub replies_checked: u64,
    settings: InvariantSettings,
    /// Packets in the current window, by medium and pair of addresses (lower first).
    exchanged: BTreeMap<(Arc<str>, u8, u8), Exchange>,
}

/// The packets two addresses sent each other in one window of `no-reply-storm`.
#[derive(Debug, Default, Clone, Copy)]
struct Exchange {
    /// The window's number (its start over its length).
    window: u64,
    /// From the lower address to the higher.
    up: u64,
    /// From the higher address to the lower.
    down: u64,
}

/// How far from 1 a unit quaternion's norm may be.
const UNIT_TOLERANCE: f64 = 1e-6;

impl Invariants {
    /// Every invariant with `settings`, the ICD's reply lengths with the ports of `opts`.
    pub fn for_run(opts: &twin_runtime::RunOptions, settings: &InvariantSettings) -> Self {
        Invariants {
            icd: Some(twin_core::icd_lengths::IcdTable::of(&opts.icd_map())),
            settings: settings.clone(),
            ..Invariants::default()
        }
    }

    /// A packet on a medium (a CAN BEGIN frame carries its header) counted between its two
    /// addresses.
    fn exchanged(&mut self, m: &bus::trace::TraceEvent) {
        use bus::trace::TraceFrame;
        let header = match &m.frame {
            TraceFrame::Packet(bytes) => csp::Packet::parse(bytes).ok().map(|p| p.header),
            frame => frame
                .can_on_wire()
                .and_then(csp::cfp::begin_fields)
                .map(|(h, _)| h),
        };
        // Between two addresses: a babbling controller's frames (eight zero bytes, read as
        // from 0 to 0) are a fault of the medium, not an exchange.
        let Some(h) = header.filter(|h| h.src != h.dst) else {
            return;
        };
        let window_ns = u64::try_from(self.settings.storm_window.as_nanos())
            .unwrap_or(u64::MAX)
            .max(1);
        let window = m.t.0 / window_ns;
        let limit =
            u128::from(self.settings.storm_packets_per_s) * u128::from(window_ns) / 1_000_000_000;
        let limit = u64::try_from(limit).unwrap_or(u64::MAX);
        let (a, b) = (h.src.min(h.dst), h.src.max(h.dst));
        let key = (m.medium.clone(), a, b);
        let entry = self.exchanged.entry(key).or_default();
        if entry.window != window {
            *entry = Exchange {
                window,
                ..Exchange::default()
            };
        }
        // Each way on its own: a storm is an exchange (each answering the other), not a
        // flow one way (a payload's push, a beacon), however fast.
        if h.src == a {
            entry.up += 1;
        } else {
            entry.down += 1;
        }
        if entry.up.min(entry.down) == limit + 1 {
            let from = SimTime(window * window_ns);
            let (window, rate) = (
                self.settings.storm_window,
                self.settings.storm_packets_per_s,
            );
            self.broken(InvariantName::NoReplyStorm, m.t, || {
                format!(
                    "{} bus: more than {limit} packets each way between {a} and {b} in the {:?} from {from} (at most {} a second)",
                    m.medium, window, rate
                )
            });
        }
    }

    /// A packet on a medium (a CAN BEGIN frame carries the header, the length and the
    /// command and result): a platform node's reply against the ICD's table.
    fn reply_length(&mut self, m: &bus::trace::TraceEvent) {
        use bus::trace::TraceFrame;
        let Some(icd) = &self.icd else {
            return;
        };
        if m.dropped {
            return;
        }
        let checked = match &m.frame {
            TraceFrame::Packet(bytes) => match csp::Packet::parse(bytes) {
                Ok(p) => icd.check(&p.header, p.data.len(), &p.data),
                Err(_) => Ok(false),
            },
            frame => match frame.can_on_wire().and_then(|f| {
                let (h, len) = csp::cfp::begin_fields(f)?;
                Some((
                    h,
                    len,
                    f.data().get(csp::cfp::BEGIN_OVERHEAD..).unwrap_or_default(),
                ))
            }) {
                Some((h, len, head)) => icd.check(&h, len, head),
                None => Ok(false),
            },
        };
        match checked {
            Ok(true) => self.replies_checked += 1,
            Ok(false) => {}
            Err(_) => self.replies_checked += 1,
        }
        if let Err(e) = checked {
            self.broken(InvariantName::IcdReplyLength, m.t, || {
                format!("{} bus: {e}", m.medium)
            });
        }
    }

    fn broken(&mut self, name: InvariantName, t: SimTime, detail: impl FnOnce() -> String) {
        self.first.entry(name).or_insert_with(|| Violation {
            name,
            t,
            detail: detail(),
        });
    }

    /// Look at one event of the run.
    pub fn observe(&mut self, ev: &RunEvent) {
        if let RunEvent::Medium(m) = ev
            && !m.dropped
        {
            self.reply_length(m);
            self.exchanged(m);
        }
        // As the samples come: a run's report need not keep them.
        if let Some(p) = twin_report::observe::power::PowerSample::of(ev)
            && !(0.0..=1.0).contains(&p.soc)
        {
            self.broken(InvariantName::SocRange, p.t, || {
                format!("state of charge {}", p.soc)
            });
        }
        if let RunEvent::Truth { t, truth, adcs } = ev {
            let norm = truth.q_eci_from_body.quaternion().norm();
            if (norm - 1.0).abs() > UNIT_TOLERANCE || !norm.is_finite() {
                self.broken(InvariantName::UnitQuaternion, *t, || {
                    format!("true attitude |q| = {norm}")
                });
            }
            if let Some(q) = &adcs.q_eci_from_body_est {
                let norm = q.quaternion().norm();
                if (norm - 1.0).abs() > UNIT_TOLERANCE || !norm.is_finite() {
                    self.broken(InvariantName::UnitQuaternion, *t, || {
                        format!("estimated attitude |q| = {norm}")
                    });
                }
            }
            let finite = truth.r_eci_m.iter().all(|x| x.is_finite())
                && truth.v_eci_m_s.iter().all(|x| x.is_finite())
                && truth.w_body_rad_s.iter().all(|x| x.is_finite());
            if !finite {
                self.broken(InvariantName::FiniteState, *t, || {
                    format!(
                        "r = {:?} m, v = {:?} m/s, w = {:?} rad/s",
                        truth.r_eci_m.as_slice(),
                        truth.v_eci_m_s.as_slice(),
                        truth.w_body_rad_s.as_slice()
                    )
                });
            }
        }
    }

    /// The verdicts on the invariants `settings.check` names, in name order: each broken one
    /// at its first violation, each kept at `end`.
    pub fn verdicts(self, report: &RunReport) -> Vec<crate::expectations::Verdict> {
        let check = self.settings.check.clone();
        let broken = self.finish(report);
        check
            .into_iter()
            .map(|name| {
                let v = broken.iter().find(|v| v.name == name);
                crate::expectations::Verdict {
                    kind: crate::expectations::VerdictKind::Invariant(name),
                    name: format!("invariant {name}"),
                    passed: v.is_none(),
                    t: v.map_or(report.sim_time, |v| v.t),
                    observed: v.map_or_else(|| "held".to_owned(), |v| v.detail.clone()),
                }
            })
            .collect()
    }

    /// Check the run's report and give every violation, in name order.
    pub fn finish(mut self, report: &RunReport) -> Vec<Violation> {
        if let Some(p) = report.power.iter().find(|p| !(0.0..=1.0).contains(&p.soc)) {
            self.broken(InvariantName::SocRange, p.t, || {
                format!("state of charge {}", p.soc)
            });
        }
        // ACTIVE intervals (a run lost with the PC's memory ends there); one still running at
        // the end lasts to the end. Each with its session and its run of that session.
        let mut run_of = BTreeMap::<u8, usize>::new();
        let mut spans: Vec<(SimTime, SimTime, u8, usize)> = report
            .sessions
            .runs
            .iter()
            .filter_map(|r| {
                let k = run_of.entry(r.session).or_default();
                *k += 1;
                let start = r.started?;
                Some((start, r.ended.map_or(SimTime::MAX, |e| e.0), r.session, *k))
            })
            .collect();
        spans.sort();
        for w in spans.windows(2) {
            if w[1].0 < w[0].1 {
                let (a, b) = (w[0], w[1]);
                self.broken(InvariantName::OneActiveSession, b.0, || {
                    format!(
                        "session {} run {} became ACTIVE at {} while session {} run {}, ACTIVE since {}, had not ended",
                        b.2, b.3, b.0, a.2, a.3, a.0
                    )
                });
            }
        }
        for bus in &report.buses {
            for p in &bus.ports {
                let n = p.unaccounted();
                if n != 0 {
                    self.broken(InvariantName::FramesAccounted, report.sim_time, || {
                        format!(
                            "{} bus, {}: {n} of {} frames offered neither sent ({} of {} by a babble), lost for a reason ({} queue full, {} bus-off, {} off) nor queued ({})",
                            bus.name,
                            p.name,
                            p.offered,
                            p.frames_tx,
                            p.babbled,
                            p.tx_overflow,
                            p.bus_off_drops,
                            p.off_drops,
                            p.queued
                        )
                    });
                }
                if let Some(t) = p.first_sent_while_off {
                    self.broken(InvariantName::SilentWhileOff, t, || {
                        format!(
                            "{} handed its {} bus controller {} frames while off",
                            p.name, bus.name, p.sent_while_off
                        )
                    });
                }
            }
        }
        if report.sessions.pc_balanced == Some(false) {
            self.broken(InvariantName::PcBalanced, report.sim_time, || {
                format!(
                    "produced {:?}, downlinked {:?}, dropped {:?}, held {:?}",
                    report.sessions.produced,
                    report.sessions.downlinked,
                    report.sessions.dropped,
                    report.sessions.held
                )
            });
        }
        self.first.into_values().collect()
    }
}

// What a snapshot saves (docs/snapshots.md): the first violations and what the checks
// carry from event to event (the ICD's table and the settings are the scenario's).
snap::fields!(Violation { name, t, detail });
snap::fields!(Exchange { window, up, down });
snap::fields!(Invariants {
    first,
    replies_checked,
    exchanged;
    skip icd, settings
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::eps::PowerSample;
    use crate::sessions::SessionRun;

    #[test]
    fn each_invariant_names_its_first_violation() {
        let mut report = RunReport::default();
        let sample = |t: u64, soc: f64| PowerSample {
            t: SimTime(t),
            soc,
            battery_v: 7.4,
            battery_a: 0.0,
            solar_w: 0.0,
            load_w: 0.0,
        };
        report.power = vec![sample(1, 0.5), sample(2, 1.2), sample(3, -0.1)];
        let run = |session: u8, from: u64, to: Option<u64>| SessionRun {
            session,
            payload: Some(12),
            started: Some(SimTime(from)),
            ended: to.map(|t| {
                (
                    SimTime(t),
                    crate::sessions::RunEnd::Result(nodes_pc::SessionResult::Done),
                    0,
                )
            }),
            bytes: Vec::new(),
            len: 0,
            stream: Default::default(),
        };
        report.sessions.runs = vec![run(1, 10, Some(20)), run(2, 20, Some(30)), run(3, 25, None)];
        report.sessions.pc_balanced = Some(false);
        let port = |name: &str, offered, tx, off_at: Option<u64>| bus::can::PortStats {
            name: name.into(),
            offered,
            frames_tx: tx,
            sent_while_off: u64::from(off_at.is_some()),
            off_drops: u64::from(off_at.is_some()),
            first_sent_while_off: off_at.map(SimTime),
            ..Default::default()
        };
        report.buses = vec![bus::can::BusStats {
            name: "payload".into(),
            ports: vec![port("PC", 5, 5, None), port("PL12", 9, 7, Some(40))],
            ..Default::default()
        }];
        let v = Invariants::default().finish(&report);
        let names: Vec<_> = v.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "frames-accounted",
                "one-active-session",
                "pc-balanced",
                "silent-while-off",
                "soc-range"
            ]
        );
        assert!(
            v[0].detail.starts_with("payload bus, PL12: 1 of 9 frames"),
            "{}",
            v[0].detail
        );
        assert_eq!(v[3].t, SimTime(40));
        let v: Vec<_> = v
            .into_iter()
            .filter(|v| {
                !matches!(
                    v.name,
                    InvariantName::FramesAccounted | InvariantName::SilentWhileOff
                )
            })
            .collect();
        assert_eq!(v[0].t, SimTime(25));
        assert!(
            v[0].detail
                == "session 3 run 1 became ACTIVE at 0.000000025s while session 2 run 1, ACTIVE since 0.000000020s, had not ended",
            "{}",
            v[0].detail
        );
        assert_eq!(v[2].t, SimTime(2));
        // Back to back sessions and a balanced PC break nothing.
        report.power.truncate(1);
        report.sessions.runs.pop();
        report.sessions.pc_balanced = Some(true);
        report.buses[0].ports[1] = port("PL12", 9, 9, None);
        assert_eq!(Invariants::default().finish(&report), vec![]);
    }

    /// Two nodes that take each other's answers for requests (the FC's periodic telemetry
    /// from its telemetry port, read by the PC as a SETUP and answered, that answer read by
    /// the FC as a TMGEN request and answered, ...) answer each other as fast as the bus
    /// allows: `no-reply-storm`, by name, between the two. The same exchange at 20 a second
    /// (a session's polls) and a babbling controller's frames break nothing.
    #[test]
    fn a_loop_between_two_nodes_fails_no_reply_storm() {
        use bus::trace::{TraceEvent, TraceFrame};
        use csp::{Header, Packet};
        let on_main = |t: u64, frame: TraceFrame| {
            RunEvent::Medium(TraceEvent {
                t: SimTime(t),
                medium: "main".into(),
                from: "x".into(),
                frame,
                dropped: false,
            })
        };
        let tm = Packet::new(Header::new(3, 6, 10, 10), vec![1, 1, 0, 0, 0, 0]);
        let answer = Packet::new(Header::new(6, 3, 10, 10), vec![1, 0]);
        let exchange = |inv: &mut Invariants, from_ns: u64, every_ns: u64, n: u64| {
            for k in 0..n {
                let p = if k % 2 == 0 { &tm } else { &answer };
                let mut frames = Vec::new();
                csp::cfp::fragment_with_ident(p, p.header.dst, (k % 1024) as u16, &mut frames)
                    .unwrap();
                for f in frames {
                    inv.observe(&on_main(from_ns + k * every_ns, TraceFrame::Can(f)));
                }
            }
        };
        let mut calm = Invariants::default();
        exchange(&mut calm, 0, 50_000_000, 1200);
        // A payload pushing 1000 packets a second to the PC, one way: not an exchange.
        let push = Packet::new(Header::new(13, 6, 11, 40), vec![7; 64]);
        for k in 0..20_000u64 {
            let mut frames = Vec::new();
            csp::cfp::fragment_with_ident(&push, 6, (k % 1024) as u16, &mut frames).unwrap();
            for f in frames {
                calm.observe(&on_main(k * 1_000_000, TraceFrame::Can(f)));
            }
        }
        for k in 0..100_000u64 {
            let babble = csp::cfp::CanFrame::new(0, &[0; 8]).unwrap();
            calm.observe(&on_main(k * 10_000, TraceFrame::Can(babble)));
        }
        assert_eq!(calm.finish(&RunReport::default()), vec![]);
        // The loop: 1 800 packets a second from 60 s, 900 each way.
        let mut storm = Invariants::default();
        exchange(&mut storm, 60_000_000_000, 555_555, 10_000);
        let v = storm.finish(&RunReport::default());
        assert_eq!(
            v.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(),
            ["no-reply-storm"]
        );
        assert!(
            v[0].detail.starts_with(
                "main bus: more than 2000 packets each way between 3 and 6 in the 10s from 60"
            ),
            "{}",
            v[0].detail
        );
        // The 2001st each way: the 4002nd packet, 2.2 s in.
        assert!(v[0].t > SimTime(62_000_000_000) && v[0].t < SimTime(62_300_000_000));
    }
}
