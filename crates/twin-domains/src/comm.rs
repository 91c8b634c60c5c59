//! The radio link to the ground in a scenario: the `[comm]` table (passes over the ground
//! stations, COMM's beacon period), its validation and compilation (COMM's configuration
//! and the contact timeline of the passes), the beacons a run receives, and the `beacon`
//! expectation.
//!
//! See docs/scenarios.md ("The radio link") and docs/platform.md.

use std::time::Duration;

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Judgement, bounds};
use crate::faults::{FaultAction, TimedFault};
use twin_report::RunReport;
use twin_scenario::scenario::{Dur, NodeRef, PathStep, Scenario};

fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

pub use twin_scenario::comm::*;

/// Check the `[comm]` table.
pub fn validate(s: &Scenario, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let c = &s.comm;
    if !(c.elevation_mask_deg.is_finite() && (-5.0..=80.0).contains(&c.elevation_mask_deg)) {
        err(
            vec![key("comm"), key("elevation_mask_deg")],
            "must be -5 to 80 deg".into(),
        );
    }
    if let Some(p) = c.beacon_period
        && !p.0.is_zero()
        && !(Duration::from_secs(10)..=Duration::from_secs(3600)).contains(&p.0)
    {
        err(
            vec![key("comm"), key("beacon_period")],
            "must be 0 (off) or 10 s to 1 h".into(),
        );
    }
    if c.passes && c.stations.is_empty() {
        err(
            vec![key("comm"), key("stations")],
            "pass modelling needs at least one station".into(),
        );
    }
    for (i, st) in c.stations.iter().enumerate() {
        let q = |n: &str| vec![key("comm"), key("stations"), PathStep::Index(i), key(n)];
        if !(st.lat_deg.is_finite() && (-90.0..=90.0).contains(&st.lat_deg)) {
            err(q("lat_deg"), "must be -90 to 90".into());
        }
        if !(st.lon_deg.is_finite() && (-180.0..=360.0).contains(&st.lon_deg)) {
            err(q("lon_deg"), "must be -180 to 360".into());
        }
        if !(st.alt_m.is_finite() && (-500.0..=10_000.0).contains(&st.alt_m)) {
            err(q("alt_m"), "must be -500 to 10000 m".into());
        }
    }
    if c.passes && s.satellite.tle.len() < 2 {
        err(
            vec![key("comm"), key("passes")],
            "pass modelling needs the satellite's TLE ([satellite] tle)".into(),
        );
    }
}

/// COMM1's configuration from the `[comm]` table (validated).
pub fn compile(s: &Scenario) -> nodes_comm::CommConfig {
    let c = &s.comm;
    let mut cfg = nodes_comm::CommConfig {
        mask_deg: c.elevation_mask_deg,
        stations: c
            .stations
            .iter()
            .map(|st| nodes_comm::Station {
                name: st.name.clone(),
                lat_deg: st.lat_deg,
                lon_deg: st.lon_deg,
                alt_m: st.alt_m,
            })
            .collect(),
        ..nodes_comm::CommConfig::default()
    };
    if let Some(p) = c.beacon_period {
        cfg.beacon_period = p.0;
    }
    cfg
}

/// Why a station name names none of the scenario's.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum StationError {
    /// `[comm] stations` has none of the name (any case).
    #[error("no station `{name}` in [comm] stations ({})", .known.join(", "))]
    NotListed {
        /// The name.
        name: String,
        /// The scenario's stations.
        known: Vec<String>,
    },
}

/// `Ok` when `[comm] stations` has one named `name` (any case), else the error naming them.
pub fn check_station(s: &Scenario, name: &str) -> Result<(), StationError> {
    let c = &s.comm;
    if c.stations
        .iter()
        .any(|st| st.name.eq_ignore_ascii_case(name))
    {
        return Ok(());
    }
    Err(StationError::NotListed {
        name: name.to_owned(),
        known: c.stations.iter().map(|st| st.name.clone()).collect(),
    })
}

/// One pass of the scenario's orbit over one of its stations, in simulated time.
#[derive(Debug, Clone, PartialEq)]
pub struct StationPass {
    /// The station's name.
    pub station: String,
    /// Rise above the elevation mask, ns of simulated time (0 when the run starts in it).
    pub rise_ns: i64,
    /// Maximum elevation, ns.
    pub culmination_ns: i64,
    /// Set below the mask, ns (the end of the window when the run ends in it).
    pub set_ns: i64,
    /// Elevation at culmination, deg.
    pub max_elevation_deg: f64,
}

/// The passes over the scenario's stations (`[comm] stations`, above its elevation mask)
/// from simulated time 0 for `span`, from its TLE through `orbit`'s SGP4 and pass
/// prediction, in time order; only `station`'s when given (by name, any case). Empty
/// without a TLE.
pub fn station_passes(
    s: &Scenario,
    epoch_unix_s: u64,
    span: Duration,
    station: Option<&str>,
) -> Vec<StationPass> {
    use orbit::passes::{GroundSite, PassOptions, predict_passes_propagator};
    use orbit::propagate::Sgp4Propagator;
    use orbit::time::UtcTime;
    let c = &s.comm;
    let epoch_ns = epoch_unix_s as i64 * 1_000_000_000;
    let ns = |t: UtcTime| t.unix_ns() - epoch_ns;
    let start = UtcTime::from_unix_ns(epoch_ns);
    let end =
        UtcTime::from_unix_ns(epoch_ns + i64::try_from(span.as_nanos()).unwrap_or(i64::MAX / 2));
    let mut out = Vec::new();
    if let [.., l1, l2] = s.satellite.tle.as_slice()
        && let Ok(tle) = orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict)
        && let Ok(mut prop) = Sgp4Propagator::new(&tle)
    {
        let opts = PassOptions {
            mask_rad: c.elevation_mask_deg.to_radians(),
            ..PassOptions::default()
        };
        let wanted = c
            .stations
            .iter()
            .filter(|st| station.is_none_or(|n| st.name.eq_ignore_ascii_case(n)));
        for st in wanted {
            let site = GroundSite::from_deg(st.lat_deg, st.lon_deg, st.alt_m);
            if let Ok(passes) = predict_passes_propagator(&site, start, end, &opts, &mut prop, None)
            {
                out.extend(passes.into_iter().map(|p| StationPass {
                    station: st.name.clone(),
                    rise_ns: ns(p.rise),
                    culmination_ns: ns(p.culmination),
                    set_ns: ns(p.set),
                    max_elevation_deg: p.max_elevation_rad.to_degrees(),
                }));
            }
        }
    }
    out.sort_by_key(|p| (p.rise_ns, p.station.clone()));
    out
}

/// The UHF contact timeline of `[comm] passes = true`: passes over every station above the
/// mask ([`station_passes`]), merged; the link is down outside them. Computed before the
/// run from the TLE: a burn during the run (which changes the true orbit slightly) does
/// not move them.
pub fn compile_passes(s: &Scenario, epoch_unix_s: u64) -> Vec<TimedFault> {
    if !s.comm.passes {
        return Vec::new();
    }
    let mut windows: Vec<(i64, i64, String)> = station_passes(s, epoch_unix_s, s.duration.0, None)
        .into_iter()
        .map(|p| {
            (
                p.rise_ns,
                p.set_ns,
                format!("{} (max {:.1} deg)", p.station, p.max_elevation_deg),
            )
        })
        .collect();
    windows.sort_by_key(|w| w.0);
    // Merge overlapping windows (two stations in view at once).
    let mut merged: Vec<(i64, i64, String)> = Vec::new();
    for w in windows {
        match merged.last_mut() {
            Some(m) if w.0 <= m.1 => {
                m.1 = m.1.max(w.1);
                m.2 = format!("{} + {}", m.2, w.2);
            }
            _ => merged.push(w),
        }
    }
    let at = |t: i64| SimTime::from_ns(t.max(0) as u64);
    let mut out = Vec::new();
    if merged.first().is_none_or(|m| m.0 > 0) {
        out.push(TimedFault {
            at: SimTime::ZERO,
            action: FaultAction::Contact(false),
            what: "comm: no pass in progress: UHF out of contact".to_owned(),
        });
    }
    for (rise, set, what) in merged {
        out.push(TimedFault {
            at: at(rise),
            action: FaultAction::Contact(true),
            what: format!("comm: pass over {what}: acquisition of signal"),
        });
        out.push(TimedFault {
            at: at(set),
            action: FaultAction::Contact(false),
            what: format!("comm: pass over {what}: loss of signal"),
        });
    }
    out
}

pub use twin_report::observe::link::*;

/// `beacon`: beacons reach the ground at least every `within` while in contact (and
/// `min`..=`max` of them in all), from one COMM or either, in a window.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BeaconExpect {
    /// Longest gap in contact (from acquisition, between beacons, to loss).
    #[serde(default)]
    pub within: Option<Dur>,
    /// Fewest beacons.
    #[serde(default)]
    pub min: Option<u64>,
    /// Most beacons.
    #[serde(default)]
    pub max: Option<u64>,
    /// Only beacons from this COMM (`COMM1` or `COMM2`); default either.
    #[serde(default)]
    pub target: Option<NodeRef>,
    /// Start of the window (default: the start of the run).
    #[serde(default)]
    pub from: Option<Dur>,
    /// End of the window (default: the end of the run).
    #[serde(default)]
    pub to: Option<Dur>,
}

impl ExpectKind for BeaconExpect {
    const NAME: &'static str = "beacon";
    const ABOUT: &'static str =
        "beacons reach the ground at least every `within` while in contact, `min`..`max` in all";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if self.within.is_none() && self.min.is_none() && self.max.is_none() {
            err(
                "kind",
                "a `beacon` expectation needs `within`, `min` or `max`".into(),
            );
        }
        if let Some(r) = &self.target
            && !matches!(
                cx.net.resolve(r),
                Ok(twin_core::network::COMM1 | twin_core::network::COMM2)
            )
        {
            err(
                "target",
                "a `beacon` expectation's `target` is the sending COMM: COMM1 or COMM2".into(),
            );
        }
        cx.window(self.from, self.to, err);
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let report = cx.report;
        check_beacons(
            report,
            self.within.map(|d| d.0),
            (self.min, self.max),
            self.target.as_ref().and_then(|r| cx.net.resolve(r).ok()),
            (
                self.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0),
                self.to.map_or(report.sim_time, |d| SimTime::ZERO + d.0),
            ),
        )
    }

    fn describe(&self) -> String {
        match &self.target {
            Some(t) => format!("beacons from {t}"),
            None => "beacons".to_owned(),
        }
    }
}

/// The contact windows of a run: from each acquisition to the next loss (the whole run
/// without pass modelling).
fn contact_windows(report: &RunReport) -> Vec<(SimTime, SimTime)> {
    let mut out = Vec::new();
    let mut open = Some(SimTime::ZERO);
    for &(t, on) in &report.contact {
        match (on, open) {
            (true, None) => open = Some(t),
            (false, Some(a)) => {
                if t > a {
                    out.push((a, t));
                }
                open = None;
            }
            _ => {}
        }
    }
    if let Some(a) = open {
        out.push((a, report.sim_time));
    }
    out
}

/// Judge a `beacon` expectation.
fn check_beacons(
    report: &RunReport,
    within: Option<std::time::Duration>,
    (min, max): (Option<u64>, Option<u64>),
    sender: Option<u8>,
    (from, to): (SimTime, SimTime),
) -> Judgement {
    let end = to;
    let beacons: Vec<(SimTime, u8, u32)> = report
        .beacons
        .iter()
        .copied()
        .filter(|&(t, s, _)| t >= from && t <= to && sender.is_none_or(|w| w == s))
        .collect();
    let n = beacons.len() as u64;
    // Contact windows cut to [from, to].
    let windows: Vec<(SimTime, SimTime)> = contact_windows(report)
        .into_iter()
        .map(|(a, b)| (a.max(from), b.min(to)))
        .filter(|(a, b)| b > a)
        .collect();
    // (+ 0.0: an empty sum is -0.0.)
    let contact_s: f64 = windows
        .iter()
        .map(|(a, b)| (*b - *a).as_secs_f64())
        .sum::<f64>()
        + 0.0;
    let mut seen = format!(
        "{n} beacons{} on the ground over {:.0} s of contact in {} window(s)",
        sender.map_or(String::new(), |a| format!(" from CSP {a}")),
        contact_s,
        windows.len()
    );
    if min.is_some_and(|m| n < m) || max.is_some_and(|m| n > m) {
        return Judgement::fail(end, format!("{seen} (expected {})", bounds(min, max)));
    }
    if let Some(gap) = within {
        for &(a, b) in &windows {
            // Only windows long enough to hold a beacon are judged.
            if (b - a) <= gap {
                continue;
            }
            let mut last = a;
            for &(t, _, _) in beacons.iter().filter(|(t, _, _)| *t >= a && *t <= b) {
                if t - last > gap {
                    return Judgement::fail(
                        t,
                        format!(
                            "{seen}; no beacon from {last} to {t} in contact (longer than {gap:?})"
                        ),
                    );
                }
                last = t;
            }
            if b - last > gap {
                return Judgement::fail(
                    b,
                    format!(
                        "{seen}; no beacon from {last} to the loss of contact at {b} (longer than {gap:?})"
                    ),
                );
            }
        }
        seen.push_str(&format!("; every gap in contact within {gap:?}"));
    }
    if let Some(&(t, _, _)) = beacons
        .iter()
        // A beacon sent just before the loss of contact lands up to its air time later.
        .find(|(t, _, _)| {
            !windows
                .iter()
                .any(|(a, b)| t >= a && *t <= *b + std::time::Duration::from_secs(1))
        })
    {
        return Judgement::fail(t, format!("{seen}; a beacon arrived out of contact at {t}"));
    }
    Judgement::pass(end, seen)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    const TLE: &str = r#"
[satellite]
tle = [
  "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
  "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
]
"#;

    #[test]
    fn the_contact_timeline_is_orbits_pass_prediction() {
        use orbit::passes::{GroundSite, PassOptions, predict_passes_propagator};
        let text = format!(
            "name = \"t\"\nstart = \"2026-04-30T18:00:00Z\"\nduration = \"13800s\"\n{TLE}\n[comm]\npasses = true\n"
        );
        let s = crate::validate::parse("t.toml", &text).unwrap();
        let c = crate::plan::compile(&s);
        let contact: Vec<(u64, bool)> = c
            .faults
            .iter()
            .filter_map(|f| match f.action {
                FaultAction::Contact(on) => Some((f.at.as_ns(), on)),
                _ => None,
            })
            .collect();
        // Independently: orbit's passes over Vilnius above 10 deg.
        let tle = orbit::tle::Tle::parse(
            s.satellite.tle[0].as_str(),
            s.satellite.tle[1].as_str(),
            orbit::tle::ChecksumMode::Strict,
        )
        .unwrap();
        let mut prop = orbit::propagate::Sgp4Propagator::new(&tle).unwrap();
        let epoch_ns = c.opts.epoch_unix_s as i64 * 1_000_000_000;
        let start = orbit::time::UtcTime::from_unix_ns(epoch_ns);
        let end = orbit::time::UtcTime::from_unix_ns(epoch_ns + 13_800_000_000_000);
        let passes = predict_passes_propagator(
            &GroundSite::from_deg(54.6872, 25.2797, 112.0),
            start,
            end,
            &PassOptions {
                mask_rad: 10f64.to_radians(),
                ..PassOptions::default()
            },
            &mut prop,
            None,
        )
        .unwrap();
        assert_eq!(passes.len(), 2);
        let mut want = vec![(0, false)];
        for p in &passes {
            want.push(((p.rise.unix_ns() - epoch_ns) as u64, true));
            want.push(((p.set.unix_ns() - epoch_ns) as u64, false));
        }
        assert_eq!(contact, want);
        // The second pass of the comm-passes scenario: 13149.9 s to 13587.6 s.
        assert_eq!(contact[3].0 / 100_000_000, 131_499);
        assert_eq!(contact[4].0 / 100_000_000, 135_875);
    }
}
