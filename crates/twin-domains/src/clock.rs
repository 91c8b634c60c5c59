//! When a run leaves virtual time for the wall clock (`[clock] realtime_from`, the CLI's
//! `--realtime-from`): the spec, its validation and its compilation into the run's
//! [`ClockMode`].
//!
//! Outside programs (your payload software, a libcsp client) are needed only around the
//! moment the scenario is about: a session during a pass 3.6 h in. Until then the run goes
//! as fast as the CPU allows, with the links already open; from then on the wall clock
//! paces it at `[clock] speed` (1 = real time), so the programs see the twin as they would
//! the satellite. `realtime_from` is a simulated time (`"13000s"`, `"3h35m"`) or the rise
//! of a pass over the scenario's stations: `"first pass"` or `"first pass over Vilnius"`
//! (`m6p-twin passes` lists them).

use bus::ClockMode;
use csp::SimTime;

use twin_scenario::scenario::{PathStep, Scenario};

/// What `realtime_from` names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RealtimeFrom {
    /// A simulated time.
    At(std::time::Duration),
    /// The rise of the first pass, over any station or the one named.
    FirstPass(Option<String>),
}

/// Why a text is not a [`RealtimeFrom`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RealtimeFromError {
    /// Neither a pass nor a duration. The duration's message is part of this one's, so it
    /// is not also its `source()`.
    #[error(
        "`{text}`: {duration}; expected a simulated time (\"13000s\", \"3h35m\"), \"first pass\" \
         or \"first pass over STATION\""
    )]
    NotATime {
        /// The text as given.
        text: String,
        /// Why it is not a duration.
        duration: twin_core::duration::DurationError,
    },
}

/// Why `realtime_from` names no time of the scenario.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RealtimeStartError {
    /// A pass with no orbit.
    #[error("\"first pass\" needs an orbit: [satellite] tle")]
    NoOrbit,
    /// A station `[comm] stations` does not have.
    #[error(transparent)]
    Station(#[from] crate::comm::StationError),
    /// No pass (over the station, if one is named) before the end of the run.
    #[error("no pass over {} within the scenario's duration", .station.as_deref().unwrap_or("any station"))]
    NoPass {
        /// The station named, if any.
        station: Option<String>,
    },
}

impl std::str::FromStr for RealtimeFrom {
    type Err = RealtimeFromError;
    fn from_str(s: &str) -> Result<Self, RealtimeFromError> {
        let t = s.trim();
        let lower = t.to_ascii_lowercase();
        if lower == "first pass" {
            return Ok(RealtimeFrom::FirstPass(None));
        }
        if let Some(name) = lower.strip_prefix("first pass over ") {
            let name = t.get(t.len() - name.len()..).unwrap_or(name).trim();
            return Ok(RealtimeFrom::FirstPass(Some(name.to_owned())));
        }
        twin_core::duration::parse_duration(t)
            .map(RealtimeFrom::At)
            .map_err(|duration| RealtimeFromError::NotATime {
                text: s.to_owned(),
                duration,
            })
    }
}

/// The simulated time `from` names in scenario `s` whose time zero is `epoch_unix_s`.
pub fn resolve(
    s: &Scenario,
    epoch_unix_s: u64,
    from: &RealtimeFrom,
) -> Result<SimTime, RealtimeStartError> {
    match from {
        RealtimeFrom::At(d) => Ok(SimTime::ZERO + *d),
        RealtimeFrom::FirstPass(station) => {
            if s.satellite.tle.is_empty() {
                return Err(RealtimeStartError::NoOrbit);
            }
            if let Some(name) = station {
                crate::comm::check_station(s, name)?;
            }
            crate::comm::station_passes(s, epoch_unix_s, s.duration.0, station.as_deref())
                .first()
                .map(|p| SimTime::from_ns(p.rise_ns.max(0) as u64))
                .ok_or_else(|| RealtimeStartError::NoPass {
                    station: station.clone(),
                })
        }
    }
}

/// Check `[clock] realtime_from`.
pub fn validate(s: &Scenario, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let Some(text) = &s.clock.realtime_from else {
        return;
    };
    let at = || {
        vec![
            PathStep::Key("clock".into()),
            PathStep::Key("realtime_from".into()),
        ]
    };
    match text.parse::<RealtimeFrom>() {
        Err(e) => err(at(), e.to_string()),
        Ok(from) => {
            let epoch = twin_core::timefmt::parse_utc(&s.start)
                .map_or(0, |ns| ns.div_euclid(1_000_000_000));
            match resolve(s, epoch.max(0) as u64, &from) {
                Err(e) => err(at(), e.to_string()),
                Ok(t) if t >= SimTime::ZERO + s.duration.0 => err(
                    at(),
                    format!(
                        "{t} is not before the end of the run ({})",
                        s.duration.0.as_secs_f64()
                    ),
                ),
                Ok(_) => {}
            }
        }
    }
}

/// The run's clock mode: virtual until `realtime_from`, then the wall clock at `speed`.
/// `None` without one.
pub fn compile(s: &Scenario, epoch_unix_s: u64) -> Option<ClockMode> {
    let from = s.clock.realtime_from.as_ref()?.parse().ok()?;
    let from = resolve(s, epoch_unix_s, &from).ok()?;
    Some(ClockMode::VirtualThenRealtime {
        from,
        speed: s.clock.speed,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn realtime_from_reads_times_and_passes() {
        assert_eq!(
            "13000s".parse::<RealtimeFrom>(),
            Ok(RealtimeFrom::At(std::time::Duration::from_secs(13_000)))
        );
        assert_eq!(
            "First pass".parse::<RealtimeFrom>(),
            Ok(RealtimeFrom::FirstPass(None))
        );
        assert_eq!(
            "first pass over Vilnius".parse::<RealtimeFrom>(),
            Ok(RealtimeFrom::FirstPass(Some("Vilnius".into())))
        );
        let e = " soon".parse::<RealtimeFrom>().unwrap_err();
        assert!(matches!(&e, RealtimeFromError::NotATime { text, .. } if text == " soon"));
        assert_eq!(
            e.to_string(),
            "` soon`: `soon` is not a duration (try 90, 90s, 10m, 2h, 1h 30m); expected a \
             simulated time (\"13000s\", \"3h35m\"), \"first pass\" or \"first pass over STATION\""
        );
    }

    /// The default scenario's orbit.
    const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
    const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";

    fn scenario(clock: &str) -> Result<Scenario, String> {
        let text = format!(
            "name = \"t\"\nstart = \"2026-04-30T18:00:00Z\"\nduration = \"4h\"\n\
             [satellite]\ntle = [\"{L1}\", \"{L2}\"]\n[clock]\n{clock}\n"
        );
        crate::validate::parse("t.toml", &text).map_err(|e| e.to_string())
    }

    #[test]
    fn a_pass_names_its_rise_and_errors_name_the_field() {
        let s = scenario("realtime_from = \"first pass\"").unwrap();
        let epoch = twin_core::timefmt::parse_utc(&s.start).unwrap() / 1_000_000_000;
        let first = crate::comm::station_passes(&s, epoch as u64, s.duration.0, None)[0].rise_ns;
        assert_eq!(
            compile(&s, epoch as u64),
            Some(ClockMode::VirtualThenRealtime {
                from: SimTime::from_ns(first as u64),
                speed: 1.0
            })
        );
        let e = scenario("realtime_from = \"first pass over Kaunas\"").unwrap_err();
        assert!(
            e.contains("clock.realtime_from") && e.contains("no station `Kaunas`"),
            "{e}"
        );
        let e = scenario("realtime_from = \"5h\"").unwrap_err();
        assert!(e.contains("not before the end of the run"), "{e}");
    }
}
