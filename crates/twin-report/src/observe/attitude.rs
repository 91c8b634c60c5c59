//! The attitude a run publishes: the FC's truth and estimate sampled, summed up as they
//! come ([`AttitudeObserver`]).

use csp::SimTime;
use twin_core::events::RunEvent;

/// The figures of one published FC snapshot that expectations check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeSample {
    /// When.
    pub t: SimTime,
    /// True body rate magnitude, deg/s.
    pub rate_deg_s: f64,
    /// True attitude to target attitude, deg.
    pub pointing_error_deg: Option<f64>,
    /// The mode's pointing axis to its target direction, deg.
    pub axis_error_deg: Option<f64>,
    /// True attitude to estimate, deg.
    pub estimation_error_deg: Option<f64>,
    /// Elevation of the satellite at the ground target, deg.
    pub target_elevation_deg: Option<f64>,
    /// Fastest wheel, rpm (magnitude).
    pub max_wheel_rpm: f64,
    /// Visible fraction of the sun.
    pub sun_visible_fraction: f64,
    /// Mode in effect.
    pub mode: u8,
    /// Distance of the true position from the scenario TLE's SGP4 position, m (grows after
    /// a burn, when the truth follows the numerical orbit).
    pub tle_offset_m: Option<f64>,
    /// ADCS state.
    pub state: u8,
}

impl AttitudeSample {
    /// The sample of one published snapshot pair.
    pub fn of(
        t: SimTime,
        truth: &platform::truth::TruthSnapshot,
        adcs: &platform::truth::AdcsSnapshot,
    ) -> Self {
        AttitudeSample {
            t,
            rate_deg_s: truth.w_body_rad_s.norm().to_degrees(),
            pointing_error_deg: adcs.pointing_error_deg,
            axis_error_deg: adcs.axis_error_deg,
            estimation_error_deg: adcs.estimation_error_deg,
            target_elevation_deg: adcs.target_elevation_deg,
            max_wheel_rpm: truth
                .wheel_speed_rad_s
                .iter()
                .fold(0.0_f64, |m, w| m.max(w.abs()))
                * 60.0
                / std::f64::consts::TAU,
            sun_visible_fraction: truth.in_eclipse_fraction_visible,
            mode: adcs.mode_in_effect,
            state: adcs.state,
            tle_offset_m: None,
        }
    }
}

/// The FC's published snapshots as [`AttitudeSample`]s.
#[derive(Debug, Default)]
pub struct AttitudeSampler {
    /// The scenario TLE's own SGP4 orbit, to measure how far the truth has left it.
    tle_orbit: Option<orbit::propagate::Sgp4Propagator>,
    /// Its TEME positions turned to J2000 (within 1e-6 m of the exact rotation, the
    /// nutation series once a minute rather than at each sample).
    j2000_from_teme: orbit::frames::J2000FromTemeByMinute,
}

impl AttitudeSampler {
    /// A sampler measuring the truth's distance from the orbit of `tle` (if any).
    pub fn new(tle: Option<&(String, String)>) -> Self {
        AttitudeSampler {
            tle_orbit: tle.and_then(|(l1, l2)| {
                orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict)
                    .ok()
                    .and_then(|t| orbit::propagate::Sgp4Propagator::new(&t).ok())
            }),
            j2000_from_teme: Default::default(),
        }
    }

    /// The sample of an event, if it is a published snapshot.
    pub fn sample(&mut self, ev: &RunEvent) -> Option<AttitudeSample> {
        let RunEvent::Truth { t, truth, adcs } = ev else {
            return None;
        };
        let mut sample = AttitudeSample::of(*t, truth, adcs);
        if let Some(p) = self.tle_orbit.as_ref() {
            let a_j2000_from_teme = self.j2000_from_teme.at(truth.unix_ns);
            sample.tle_offset_m = p
                .state_teme_at(orbit::time::UtcTime::from_unix_ns(truth.unix_ns))
                .ok()
                .map(|s| (truth.r_eci_m - a_j2000_from_teme * s.r_km * 1e3).norm());
        }
        Some(sample)
    }
}

/// Below this body rate (deg/s) a run that started tumbling has detumbled (a campaign's
/// `detumble_s`).
pub const DETUMBLED_DEG_S: f64 = 0.5;

/// What every published FC sample of a run adds up to (kept whether or not the samples
/// are).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AttitudeSummary {
    /// Samples published.
    pub samples: u64,
    /// The first sample.
    pub first: Option<AttitudeSample>,
    /// The highest body rate, deg/s.
    pub max_rate_deg_s: Option<f64>,
    /// When the body rate was first below [`DETUMBLED_DEG_S`].
    pub first_detumbled: Option<SimTime>,
}

impl AttitudeSummary {
    fn add(&mut self, s: &AttitudeSample) {
        self.samples += 1;
        self.first.get_or_insert(*s);
        self.max_rate_deg_s = Some(
            self.max_rate_deg_s
                .map_or(s.rate_deg_s, |m| m.max(s.rate_deg_s)),
        );
        if self.first_detumbled.is_none() && s.rate_deg_s < DETUMBLED_DEG_S {
            self.first_detumbled = Some(s.t);
        }
    }
}

/// The FC's published samples of a run, gathered from its events.
#[derive(Default)]
pub struct AttitudeObserver {
    samples: Vec<AttitudeSample>,
    summary: AttitudeSummary,
    sampler: AttitudeSampler,
    /// Keep only the summary (one sample a second is 430 kB per simulated hour).
    pub forget_samples: bool,
}

impl std::fmt::Debug for AttitudeObserver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AttitudeObserver")
            .field("samples", &self.samples.len())
            .field("summary", &self.summary)
            .field("forget_samples", &self.forget_samples)
            .finish_non_exhaustive()
    }
}

impl AttitudeObserver {
    /// An observer measuring the truth's distance from the orbit of `tle` (if any).
    pub fn new(tle: Option<&(String, String)>) -> Self {
        AttitudeObserver {
            sampler: AttitudeSampler::new(tle),
            ..AttitudeObserver::default()
        }
    }

    /// Take in one event.
    pub fn observe(&mut self, ev: &RunEvent) {
        if let Some(sample) = self.sampler.sample(ev) {
            self.summary.add(&sample);
            if !self.forget_samples {
                self.samples.push(sample);
            }
        }
    }

    /// The samples, in time order (none if forgotten), and their summary.
    pub fn finish(self) -> (Vec<AttitudeSample>, AttitudeSummary) {
        (self.samples, self.summary)
    }
}

// What a snapshot saves (docs/snapshots.md); the sampler is the scenario's orbit and a
// cache of rotations, the same whenever it is built.
snap::fields!(AttitudeSample {
    t,
    rate_deg_s,
    pointing_error_deg,
    axis_error_deg,
    estimation_error_deg,
    target_elevation_deg,
    max_wheel_rpm,
    sun_visible_fraction,
    mode,
    tle_offset_m,
    state
});
snap::fields!(AttitudeSummary {
    samples,
    first,
    max_rate_deg_s,
    first_detumbled
});
snap::fields!(AttitudeObserver {
    samples,
    summary;
    skip sampler, forget_samples
});
