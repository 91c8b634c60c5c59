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
//!   reason + held) when it reports it.

use std::collections::BTreeMap;

use csp::SimTime;

use crate::events::RunEvent;
use crate::runtime::RunReport;

/// One invariant broken: the first instant it was seen.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation {
    /// The invariant's name.
    pub name: &'static str,
    /// When.
    pub t: SimTime,
    /// The values that break it.
    pub detail: String,
}

/// The invariants' state over one run: the first violation of each.
#[derive(Debug, Default)]
pub struct Invariants {
    first: BTreeMap<&'static str, Violation>,
}

/// How far from 1 a unit quaternion's norm may be.
const UNIT_TOLERANCE: f64 = 1e-6;

impl Invariants {
    fn broken(&mut self, name: &'static str, t: SimTime, detail: impl FnOnce() -> String) {
        self.first.entry(name).or_insert_with(|| Violation {
            name,
            t,
            detail: detail(),
        });
    }

    /// Look at one event of the run.
    pub fn observe(&mut self, ev: &RunEvent) {
        if let RunEvent::Truth { t, truth, adcs } = ev {
            let norm = truth.q_eci_from_body.quaternion().norm();
            if (norm - 1.0).abs() > UNIT_TOLERANCE || !norm.is_finite() {
                self.broken("unit-quaternion", *t, || {
                    format!("true attitude |q| = {norm}")
                });
            }
            if let Some(q) = &adcs.q_eci_from_body_est {
                let norm = q.quaternion().norm();
                if (norm - 1.0).abs() > UNIT_TOLERANCE || !norm.is_finite() {
                    self.broken("unit-quaternion", *t, || {
                        format!("estimated attitude |q| = {norm}")
                    });
                }
            }
            let finite = truth.r_eci_m.iter().all(|x| x.is_finite())
                && truth.v_eci_m_s.iter().all(|x| x.is_finite())
                && truth.w_body_rad_s.iter().all(|x| x.is_finite());
            if !finite {
                self.broken("finite-state", *t, || {
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

    /// Check the run's report and give every violation, in name order.
    pub fn finish(mut self, report: &RunReport) -> Vec<Violation> {
        if let Some(p) = report.power.iter().find(|p| !(0.0..=1.0).contains(&p.soc)) {
            self.broken("soc-range", p.t, || format!("state of charge {}", p.soc));
        }
        // ACTIVE intervals; one still running at the end lasts to the end.
        let mut spans: Vec<(SimTime, SimTime, u8)> = report
            .sessions
            .runs
            .iter()
            .filter_map(|r| {
                let start = r.started?;
                Some((start, r.ended.map_or(SimTime::MAX, |e| e.0), r.session))
            })
            .collect();
        spans.sort();
        for w in spans.windows(2) {
            if w[1].0 < w[0].1 {
                self.broken("one-active-session", w[1].0, || {
                    format!("session {} ACTIVE while session {} is", w[1].2, w[0].2)
                });
            }
        }
        if report.sessions.pc_balanced == Some(false) {
            self.broken("pc-balanced", report.sim_time, || {
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
            started: Some(SimTime(from)),
            ended: to.map(|t| (SimTime(t), 0, 0)),
            bytes: Vec::new(),
        };
        report.sessions.runs = vec![run(1, 10, Some(20)), run(2, 20, Some(30)), run(3, 25, None)];
        report.sessions.pc_balanced = Some(false);
        let v = Invariants::default().finish(&report);
        let names: Vec<_> = v.iter().map(|v| v.name).collect();
        assert_eq!(names, ["one-active-session", "pc-balanced", "soc-range"]);
        assert_eq!(v[0].t, SimTime(25));
        assert!(
            v[0].detail.contains("session 3 ACTIVE while session 2"),
            "{}",
            v[0].detail
        );
        assert_eq!(v[2].t, SimTime(2));
        // Back to back sessions and a balanced PC break nothing.
        report.power.truncate(1);
        report.sessions.runs.pop();
        report.sessions.pc_balanced = Some(true);
        assert_eq!(Invariants::default().finish(&report), vec![]);
    }
}
