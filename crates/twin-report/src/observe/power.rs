//! The EPS's samples a run publishes, summed up as they come ([`PowerObserver`]).

use csp::SimTime;
use twin_core::events::RunEvent;

/// The figures of one EPS sample that expectations check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PowerSample {
    /// When.
    pub t: SimTime,
    /// State of charge, 0..1.
    pub soc: f64,
    /// Battery voltage, V.
    pub battery_v: f64,
    /// Battery current, A (positive charging).
    pub battery_a: f64,
    /// Solar array power, W.
    pub solar_w: f64,
    /// Total load, W.
    pub load_w: f64,
}

impl PowerSample {
    /// The sample an event carries, if it is the EPS's.
    pub fn of(ev: &RunEvent) -> Option<Self> {
        if let RunEvent::Eps(o) = ev
            && let nodes_eps::EpsOutput::Sample {
                t,
                soc,
                battery_v,
                battery_a,
                solar_w,
                load_w,
                ..
            } = **o
        {
            Some(PowerSample {
                t,
                soc,
                battery_v,
                battery_a,
                solar_w,
                load_w,
            })
        } else {
            None
        }
    }
}

/// What every EPS sample of a run adds up to (kept whether or not the samples are).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PowerSummary {
    /// Samples published.
    pub samples: u64,
    /// The lowest state of charge.
    pub min_soc: Option<f64>,
}

impl PowerSummary {
    fn add(&mut self, s: &PowerSample) {
        self.samples += 1;
        self.min_soc = Some(self.min_soc.map_or(s.soc, |m| m.min(s.soc)));
    }
}

/// The EPS's samples of a run, gathered from its events.
#[derive(Debug, Default)]
pub struct PowerObserver {
    samples: Vec<PowerSample>,
    summary: PowerSummary,
    /// Keep only the summary (one sample a second is 170 kB per simulated hour).
    pub forget_samples: bool,
}

impl PowerObserver {
    /// Take in one event.
    pub fn observe(&mut self, ev: &RunEvent) {
        if let Some(s) = PowerSample::of(ev) {
            self.summary.add(&s);
            if !self.forget_samples {
                self.samples.push(s);
            }
        }
    }

    /// The samples, in time order (none if forgotten), and their summary.
    pub fn finish(self) -> (Vec<PowerSample>, PowerSummary) {
        (self.samples, self.summary)
    }
}

// What a snapshot saves (docs/snapshots.md).
snap::fields!(PowerSample {
    t,
    soc,
    battery_v,
    battery_a,
    solar_w,
    load_w
});
snap::fields!(PowerSummary { samples, min_soc });
snap::fields!(PowerObserver {
    samples,
    summary;
    skip forget_samples
});
