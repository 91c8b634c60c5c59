//! What a run observes for its report and expectations, one event at a time ([`Observer`]):
//! each domain's observer beside the others.

pub mod attitude;
pub mod commands;
pub mod link;
pub mod power;
pub mod sessions;

use bus::trace::TraceEvent;
use csp::SimTime;

use attitude::AttitudeSample;
use power::PowerSample;
use twin_core::events::RunEvent;

/// Gathers the report's samples from the run's events, one event at a time in the order
/// they happen (the main loop hands it every event after the sink): each domain slice
/// observes what its expectations judge.
#[derive(Debug)]
pub struct Observer {
    trace: Option<Vec<TraceEvent>>,
    attitude: attitude::AttitudeObserver,
    power: power::PowerObserver,
    link: link::LinkObserver,
    sessions: sessions::SessionsReport,
    commands: commands::CommandObserver,
}

/// What an [`Observer`] gathered.
#[derive(Debug, Clone, Default)]
pub struct Observed {
    /// Every frame and packet, when kept.
    pub trace: Vec<TraceEvent>,
    /// The FC's published attitude samples (if kept).
    pub attitude: Vec<AttitudeSample>,
    /// Their summary.
    pub attitude_summary: attitude::AttitudeSummary,
    /// The PC's sessions and the payloads' bytes.
    pub sessions: sessions::SessionsReport,
    /// The EPS's samples (if kept).
    pub power: Vec<PowerSample>,
    /// Their summary.
    pub power_summary: power::PowerSummary,
    /// Beacons received on the ground.
    pub beacons: Vec<(SimTime, u8, u32)>,
    /// UHF contact switches.
    pub contact: Vec<(SimTime, bool)>,
    /// Outcomes of the ground stations' requests (if kept).
    pub results: Vec<commands::RequestResult>,
    /// What the ground stations' requests came to, counted.
    pub requests: commands::RequestSummary,
}

/// What an [`Observer`] keeps beyond the run's summaries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Keep {
    /// The trace of every frame.
    pub trace: bool,
    /// Every sample, downlinked byte and command outcome.
    pub series: bool,
}

impl Observer {
    /// An observer keeping what `keep` says beyond the summaries; `tle` is the scenario's
    /// orbit (for the truth's distance from it).
    pub fn new(keep: Keep, tle: Option<&(String, String)>) -> Self {
        let keep_series = keep.series;
        let mut attitude = attitude::AttitudeObserver::new(tle);
        attitude.forget_samples = !keep_series;
        let mut power = power::PowerObserver::default();
        power.forget_samples = !keep_series;
        Observer {
            trace: keep.trace.then(Vec::new),
            attitude,
            power,
            link: link::LinkObserver::default(),
            sessions: sessions::SessionsReport {
                forget_bytes: !keep_series,
                ..Default::default()
            },
            commands: commands::CommandObserver::new(keep_series),
        }
    }

    /// Take in one event.
    pub fn observe(&mut self, ev: &RunEvent) {
        if let (RunEvent::Medium(m), Some(trace)) = (ev, self.trace.as_mut()) {
            trace.push(m.clone());
        }
        self.attitude.observe(ev);
        self.power.observe(ev);
        self.link.observe(ev);
        self.sessions.observe(ev);
        self.commands.observe(ev);
    }

    /// The UHF link's contact with the ground switched at `t` (a pass began or ended).
    pub fn contact(&mut self, t: SimTime, on: bool) {
        self.link.contact(t, on);
    }

    /// Everything gathered.
    pub fn finish(self) -> Observed {
        let (beacons, contact) = self.link.finish();
        let (attitude, attitude_summary) = self.attitude.finish();
        let (power, power_summary) = self.power.finish();
        let (results, requests) = self.commands.finish();
        Observed {
            trace: self.trace.unwrap_or_default(),
            attitude,
            attitude_summary,
            sessions: self.sessions,
            power,
            power_summary,
            beacons,
            contact,
            results,
            requests,
        }
    }
}

// What a snapshot saves (docs/snapshots.md): everything gathered so far.
snap::fields!(Observer {
    trace,
    attitude,
    power,
    link,
    sessions,
    commands;
    in_place
});
