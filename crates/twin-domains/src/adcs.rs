//! The flight computer and its ADCS in a scenario: the `[fc]` table (initial state,
//! models, scripts, sensor and wheel faults), its validation and compilation into the FC's
//! configuration, the attitude samples a run publishes, and the `attitude` expectation.
//!
//! See docs/scenarios.md ("The FC") and docs/adcs.md.

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{
    CheckCx, ExpectCx, ExpectKind, Extremes, Judgement, Occurrence, Watch, WatchCx, When,
};
use crate::faults::{FaultAction, TimedFault};
use twin_core::events::RunEvent;
use twin_core::network::NetworkSpec;
use twin_scenario::scenario::{Dur, PathStep, Scenario};

fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

pub use twin_scenario::fc::*;

/// Check the `[fc]` table.
pub fn validate(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let fc = &s.fc;
    let p = |n: &str| vec![key("fc"), key(n)];
    if let Some(Err((field, e))) = fc.periodic.as_ref().map(|sp| sp.periodic(net)) {
        err(vec![key("fc"), key("periodic"), key(field)], e);
    }
    if fc.adcs_hz.is_some_and(|h| !(1..=100).contains(&h)) {
        err(p("adcs_hz"), "must be 1-100".into());
    }
    if let Some(h) = fc.publish_hz
        && h > fc.adcs_hz.unwrap_or(10)
    {
        err(p("publish_hz"), "must not exceed `adcs_hz`".into());
    }
    if let Some(e) = fc.safe.and_then(|sf| sf.config().validate().err()) {
        err(p("safe"), e.to_string());
    }
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    let nonzero = |v: &[f64]| finite(v) && v.iter().any(|x| *x != 0.0);
    if fc
        .initial_rate_deg_s
        .is_some_and(|r| !(r.is_finite() && (0.0..=360.0).contains(&r)))
    {
        err(p("initial_rate_deg_s"), "must be 0-360 deg/s".into());
    }
    for (f, v) in [
        (
            "initial_rate_axis",
            fc.initial_rate_axis.map(|a| a.to_vec()),
        ),
        ("initial_attitude", fc.initial_attitude.map(|a| a.to_vec())),
        ("target_attitude", fc.target_attitude.map(|a| a.to_vec())),
        (
            "panel_normal_body",
            fc.panel_normal_body.map(|a| a.to_vec()),
        ),
    ] {
        if v.is_some_and(|v| !nonzero(&v)) {
            err(p(f), "must be finite and not all zero".into());
        }
    }
    for (f, v) in [
        (
            "initial_wheel_rpm",
            fc.initial_wheel_rpm.map(|a| a.to_vec()),
        ),
        (
            "residual_dipole_am2",
            fc.residual_dipole_am2.map(|a| a.to_vec()),
        ),
        ("target_point", fc.target_point.map(|a| a.to_vec())),
    ] {
        if v.is_some_and(|v| !finite(&v)) {
            err(p(f), "must be finite".into());
        }
    }
    if let Some(rpm) = fc.initial_wheel_rpm
        && rpm.iter().any(|r| r.abs() > 6000.0)
    {
        err(
            p("initial_wheel_rpm"),
            "the wheels' limit is 6000 rpm".into(),
        );
    }
    if let Some(m) = fc.inertia_kg_m2 {
        let i = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
        let symmetric = (i - i.transpose()).abs().max() <= 1e-12 * i.abs().max();
        let positive = i.iter().all(|x| x.is_finite())
            && symmetric
            && i.symmetric_eigenvalues().iter().all(|&e| e > 0.0);
        if !positive {
            err(
                p("inertia_kg_m2"),
                "must be a symmetric positive-definite 3x3 matrix (rows)".into(),
            );
        }
    }
    for (i, sc) in fc.scripts.iter().enumerate() {
        if let Err(e) = nodes_fc::scripts::Script::parse(&sc.line) {
            err(
                vec![key("fc"), key("scripts"), PathStep::Index(i), key("line")],
                format!("the script does not parse: {e}"),
            );
        }
    }
    for (i, f) in fc.faults.iter().enumerate() {
        let q = |n: &str| vec![key("fc"), key("faults"), PathStep::Index(i), key(n)];
        if f.until.is_some_and(|u| u <= f.at) {
            err(q("until"), "must be after `at`".into());
        }
        match (&f.sensor, f.wheel) {
            (Some(name), None) => {
                if let Err(e) = name.parse::<nodes_fc::sensors::SensorId>() {
                    err(q("sensor"), e.to_string());
                }
                if let Err(e) = f.fault.parse::<nodes_fc::sensors::SensorFault>() {
                    err(q("fault"), e.to_string());
                }
            }
            (None, Some(w)) => {
                if w > 3 {
                    err(q("wheel"), format!("wheel {w} is not 0-3"));
                }
                if let Err(e) = f.fault.parse::<nodes_fc::WheelFault>() {
                    err(q("fault"), e.to_string());
                }
            }
            _ => err(
                q("fault"),
                "give exactly one of `sensor` and `wheel`".into(),
            ),
        }
    }
}

/// A unit vector drawn from `seed` (uniform on the sphere).
fn random_unit(seed: u64, salt: u64) -> nalgebra::Vector3<f64> {
    let u = |k: u64| (twin_core::seed::mix(seed, salt + k) >> 11) as f64 / (1u64 << 53) as f64;
    let z = 2.0 * u(0) - 1.0;
    let phi = std::f64::consts::TAU * u(1);
    let r = (1.0 - z * z).max(0.0).sqrt();
    nalgebra::Vector3::new(r * phi.cos(), r * phi.sin(), z)
}

/// A rotation drawn uniformly from SO(3) (Shoemake, "Uniform random rotations", Graphics
/// Gems III, 1992): three uniforms from the seed.
fn random_rotation(seed: u64, salt: u64) -> nalgebra::UnitQuaternion<f64> {
    let u = |k: u64| (twin_core::seed::mix(seed, salt + k) >> 11) as f64 / (1u64 << 53) as f64;
    let (u1, u2, u3) = (u(0), u(1), u(2));
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let tau = std::f64::consts::TAU;
    nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        b * (tau * u3).cos(),
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
    ))
}

/// The FC's configuration from the `[fc]` table (validated), its faults added to the
/// recorded fault timeline.
pub fn compile(
    s: &Scenario,
    net: &NetworkSpec,
    faults: &mut Vec<TimedFault>,
) -> nodes_fc::FcConfig {
    use nalgebra::{Quaternion, UnitQuaternion, Vector3};
    use nodes_fc::{FcEvent, TimedFcEvent};
    let f = &s.fc;
    let mut c = nodes_fc::FcConfig::default();
    if let Some(h) = f.adcs_hz {
        c.adcs_hz = h;
    }
    if let Some(h) = f.publish_hz {
        c.publish_hz = h;
    }
    if let Some(m) = f.mode {
        c.initial_mode = m.mode();
    }
    if let Some(q) = f.target_attitude {
        let n = (q.iter().map(|x| x * x).sum::<f64>()).sqrt();
        c.initial_target_attitude = Some(q.map(|x| x / n));
    }
    c.initial_target_point = f.target_point;
    c.tle_uploaded = f.tle_uploaded.unwrap_or(true);
    c.sensors.gps_enabled = f.gps.unwrap_or(false);
    let axis = f
        .initial_rate_axis
        .map(|a| Vector3::from(a).normalize())
        .unwrap_or_else(|| random_unit(s.seed, 0x310));
    c.initial.w_body_rad_s = axis * f.initial_rate_deg_s.unwrap_or(0.0).to_radians();
    c.initial.q_eci_from_body = match f.initial_attitude {
        Some([r, i, j, k]) => UnitQuaternion::from_quaternion(Quaternion::new(r, i, j, k)),
        None => random_rotation(s.seed, 0x320),
    };
    if let Some(rpm) = f.initial_wheel_rpm {
        c.initial.wheel_speed_rad_s = rpm.map(|r| r * std::f64::consts::TAU / 60.0);
    }
    if let Some(m) = f.inertia_kg_m2 {
        c.body.inertia_kg_m2 = nalgebra::Matrix3::from_fn(|r, k| m[r][k]);
        // The gains follow the body (and the orbit's rate), as the default's do.
        let n_rad_s = match s.satellite.tle.as_slice() {
            [.., l1, l2] => orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict)
                .map(|t| t.mean_motion_rev_day * std::f64::consts::TAU / 86_400.0)
                .unwrap_or(nodes_fc::control::DEFAULT_MEAN_MOTION_RAD_S),
            _ => nodes_fc::control::DEFAULT_MEAN_MOTION_RAD_S,
        };
        c.adcs.control = nodes_fc::control::ControlConfig::for_body(&c.body, n_rad_s);
    }
    if let Some(d) = f.residual_dipole_am2 {
        c.residual_dipole_am2 = Vector3::from(d);
    }
    if f.drag == Some(false) {
        c.drag = None;
    }
    if let Some(g) = f.gravity_gradient {
        c.gravity_gradient = g;
    }
    if let Some(n) = f.panel_normal_body {
        c.adcs.panel_normal_body = Vector3::from(n).normalize();
    }
    if let Some(sf) = f.safe {
        c.safe = sf.config();
    }
    c.periodic = f.periodic.as_ref().and_then(|sp| sp.periodic(net).ok());
    if let Some(p) = f.ports {
        let d = nodes_fc::FcPorts::default();
        c.ports = nodes_fc::FcPorts {
            telemetry: p.telemetry.unwrap_or(d.telemetry),
            rtc: p.rtc.unwrap_or(d.rtc),
            attitude: p.attitude.unwrap_or(d.attitude),
            scripts: p.scripts.unwrap_or(d.scripts),
        };
    }
    for sc in &f.scripts {
        c.timeline.push(TimedFcEvent {
            at: SimTime::ZERO + sc.at.0,
            event: FcEvent::Script(sc.line.clone()),
        });
    }
    compile_faults(f, &mut c, faults);
    c
}

/// `[[fc.faults]]`: each sensor or wheel fault on the FC's own timeline (set, and cleared
/// at `until`), and recorded on the fault timeline.
fn compile_faults(f: &FcSpec, c: &mut nodes_fc::FcConfig, faults: &mut Vec<TimedFault>) {
    use nodes_fc::{FcEvent, TimedFcEvent};
    for (i, fault) in f.faults.iter().enumerate() {
        let (set, clear) = match (&fault.sensor, fault.wheel) {
            (Some(name), _) => {
                let (Ok(id), Ok(kind)) = (
                    name.parse::<nodes_fc::sensors::SensorId>(),
                    fault.fault.parse::<nodes_fc::sensors::SensorFault>(),
                ) else {
                    continue;
                };
                (FcEvent::Sensor(id, Some(kind)), FcEvent::Sensor(id, None))
            }
            (None, Some(w)) => {
                let Ok(kind) = fault.fault.parse::<nodes_fc::WheelFault>() else {
                    continue;
                };
                (
                    FcEvent::Wheel(usize::from(w), Some(kind)),
                    FcEvent::Wheel(usize::from(w), None),
                )
            }
            (None, None) => continue,
        };
        let what = match (&fault.sensor, fault.wheel) {
            (Some(n), _) => format!("fc.faults[{i}]: {n} {}", fault.fault),
            _ => format!(
                "fc.faults[{i}]: wheel {} {}",
                fault.wheel.unwrap_or(0),
                fault.fault
            ),
        };
        let at = SimTime::ZERO + fault.at.0;
        c.timeline.push(TimedFcEvent { at, event: set });
        faults.push(TimedFault {
            at,
            action: FaultAction::Record,
            what: what.clone(),
        });
        if let Some(u) = fault.until {
            let until = SimTime::ZERO + u.0;
            c.timeline.push(TimedFcEvent {
                at: until,
                event: clear,
            });
            faults.push(TimedFault {
                at: until,
                action: FaultAction::Record,
                what: format!("{what} (cleared)"),
            });
        }
    }
}

pub use twin_report::observe::attitude::*;

/// The figures an `attitude` expectation can check (each published FC snapshot).
pub const ATTITUDE_QUANTITIES: &[&str] = &[
    "rate_deg_s",
    "pointing_error_deg",
    "axis_error_deg",
    "estimation_error_deg",
    "max_wheel_rpm",
    "mode",
    "state",
    "tle_offset_m",
];

/// `attitude`: every FC snapshot in a window (or, with `occurrence = "any"`, one) has a
/// figure below / above a bound.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct AttitudeExpect {
    /// The figure checked (see [`ATTITUDE_QUANTITIES`]).
    pub quantity: String,
    /// Every selected sample (default) or at least one (`any`) must be within bounds.
    #[serde(default)]
    pub occurrence: Option<Occurrence>,
    /// Every sample in the window must be below this.
    #[serde(default)]
    pub below: Option<f64>,
    /// Every sample in the window must be above this.
    #[serde(default)]
    pub above: Option<f64>,
    /// Start of the window (default: the start of the run).
    #[serde(default)]
    pub from: Option<Dur>,
    /// End of the window (default: the end of the run).
    #[serde(default)]
    pub to: Option<Dur>,
    /// Which samples count: `always` (default), `sunlit`, `eclipse`, `target-visible`.
    #[serde(default)]
    pub when: Option<When>,
    /// Elevation for `target-visible`, deg (default 10).
    #[serde(default)]
    pub min_elevation_deg: Option<f64>,
}

impl ExpectKind for AttitudeExpect {
    const NAME: &'static str = "attitude";
    const ABOUT: &'static str = "every FC snapshot in a window has a figure below / above a bound";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if !ATTITUDE_QUANTITIES.contains(&self.quantity.as_str()) {
            err(
                "quantity",
                format!(
                    "unknown quantity `{}` ({})",
                    self.quantity,
                    ATTITUDE_QUANTITIES.join(", ")
                ),
            );
        }
        if self.below.is_none() && self.above.is_none() {
            err(
                "kind",
                "an `attitude` expectation needs `below` or `above`".into(),
            );
        }
        for (f, v) in [("below", self.below), ("above", self.above)] {
            if v.is_some_and(|v| !v.is_finite()) {
                err(f, "must be a finite number".into());
            }
        }
        cx.window(self.from, self.to, err);
        if self.min_elevation_deg.is_some() && self.when != Some(When::TargetVisible) {
            err(
                "min_elevation_deg",
                "only `when = \"target-visible\"` takes `min_elevation_deg`".into(),
            );
        }
    }

    fn check(&self, cx: &CheckCx<'_>) -> Judgement {
        let mut tally = AttitudeTally::default();
        for s in &cx.report.attitude {
            self.tally(&mut tally, s);
        }
        self.judge(&tally, cx.report.sim_time)
    }

    fn watch(&self, cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        // Only the distance from the TLE's orbit needs its propagation.
        let tle = cx.tle.filter(|_| self.quantity == "tle_offset_m");
        Some(Box::new(AttitudeWatch {
            expect: self.clone(),
            sampler: AttitudeSampler::new(tle),
            tally: AttitudeTally::default(),
        }))
    }

    fn describe(&self) -> String {
        format!("attitude {}", self.quantity)
    }
}

/// An `attitude` expectation's figures over the samples it selected so far.
#[derive(Debug, Clone, Default)]
struct AttitudeTally {
    n: usize,
    /// Of the selected samples that have the quantity.
    range: Extremes,
    failures: usize,
    /// The first failing sample: when, and why.
    first: Option<(SimTime, String)>,
}

/// An `attitude` expectation judged as the run goes: its samples are not kept.
struct AttitudeWatch {
    expect: AttitudeExpect,
    sampler: AttitudeSampler,
    tally: AttitudeTally,
}

impl Watch for AttitudeWatch {
    fn kinds(&self) -> twin_core::events::Kinds {
        twin_core::events::Kinds::of(&[twin_core::events::EventKind::Truth])
    }

    fn observe(&mut self, ev: &RunEvent) {
        if let Some(s) = self.sampler.sample(ev) {
            self.expect.tally(&mut self.tally, &s);
        }
    }

    fn judge(&self, cx: &CheckCx<'_>) -> Judgement {
        self.expect.judge(&self.tally, cx.report.sim_time)
    }
}

/// The named figure of a sample (`None`: it does not apply, for example no target).
fn quantity(s: &AttitudeSample, name: &str) -> Option<f64> {
    match name {
        "rate_deg_s" => Some(s.rate_deg_s),
        "pointing_error_deg" => s.pointing_error_deg,
        "axis_error_deg" => s.axis_error_deg,
        "estimation_error_deg" => s.estimation_error_deg,
        "max_wheel_rpm" => Some(s.max_wheel_rpm),
        "mode" => Some(f64::from(s.mode)),
        "state" => Some(f64::from(s.state)),
        "tle_offset_m" => s.tle_offset_m,
        _ => None,
    }
}

impl AttitudeExpect {
    /// Take in the next sample, if the window (`from` to `to`; without `to`, to the end
    /// of the run, after which no sample comes) and `when` select it.
    fn tally(&self, k: &mut AttitudeTally, s: &AttitudeSample) {
        let from = self.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0);
        let min_elevation_deg = self.min_elevation_deg.unwrap_or(10.0);
        let selected = s.t >= from
            && self.to.is_none_or(|d| s.t <= SimTime::ZERO + d.0)
            && match self.when.unwrap_or(When::Always) {
                When::Always => true,
                When::Sunlit => s.sun_visible_fraction >= 1.0,
                When::Eclipse => s.sun_visible_fraction <= 0.0,
                When::TargetVisible => s
                    .target_elevation_deg
                    .is_some_and(|e| e >= min_elevation_deg),
            };
        if !selected {
            return;
        }
        k.n += 1;
        let v = quantity(s, &self.quantity);
        let problem = match v {
            None => Some(format!("no `{}` at this time", self.quantity)),
            Some(v) if self.below.is_some_and(|b| v.is_nan() || v >= b) => Some(format!(
                "{} = {v:.4} (expected below {})",
                self.quantity,
                self.below.unwrap_or_default()
            )),
            Some(v) if self.above.is_some_and(|a| v.is_nan() || v <= a) => Some(format!(
                "{} = {v:.4} (expected above {})",
                self.quantity,
                self.above.unwrap_or_default()
            )),
            Some(_) => None,
        };
        if let Some(v) = v {
            k.range.add(v);
        }
        if let Some(p) = problem {
            k.failures += 1;
            k.first.get_or_insert((s.t, p));
        }
    }

    /// Every selected sample in the window within bounds (or, with `any`, one), the run
    /// having ended at `end`: the end, or the first failing time, and what was seen.
    fn judge(&self, k: &AttitudeTally, end: SimTime) -> Judgement {
        let from = self.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0);
        let to = self.to.map_or(end, |d| SimTime::ZERO + d.0);
        let window = format!("{from} to {to} ({:?})", self.when.unwrap_or(When::Always));
        let n = k.n;
        if n == 0 {
            return Judgement::fail(to, format!("no FC samples in {window}"));
        }
        let range = format!(
            "{n} samples in {window}, {} from {:.4} to {:.4}",
            self.quantity, k.range.lo, k.range.hi
        );
        if self.occurrence.unwrap_or(Occurrence::Every) == Occurrence::Any {
            return if k.failures < n {
                Judgement::pass(to, format!("{} of {range} within bounds", n - k.failures))
            } else {
                Judgement::fail(to, format!("none of {range} within bounds"))
            };
        }
        match &k.first {
            Some((t, p)) => {
                Judgement::fail(*t, format!("{} of {range}; first at {t}: {p}", k.failures))
            }
            None => Judgement::pass(to, range),
        }
    }
}

// What a snapshot saves (docs/snapshots.md): the tally so far (the sampler is the
// scenario's orbit and a cache).
snap::fields!(AttitudeTally {
    n,
    range,
    failures,
    first
});
snap::fields!(AttitudeWatch {
    tally;
    skip expect, sampler
});

#[cfg(test)]
mod tests {
    use super::*;

    /// The TLE offset measures from the TLE's orbit in J2000 within 1e-5 m of the exact
    /// conversion (the sampler turns TEME to J2000 with the minute's chord).
    #[test]
    #[allow(clippy::unwrap_used)]
    fn the_tle_offset_is_the_distance_from_the_tle_orbit_in_j2000() {
        use orbit::propagate::Propagator as _;
        let tle = (
            "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996".to_owned(),
            "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009".to_owned(),
        );
        let mut sampler = AttitudeSampler::new(Some(&tle));
        let parsed =
            orbit::tle::Tle::parse(&tle.0, &tle.1, orbit::tle::ChecksumMode::Strict).unwrap();
        let mut exact = orbit::propagate::Sgp4Propagator::new(&parsed).unwrap();
        let epoch_ns = 1_777_572_000_000_000_000i64;
        let off_m = nalgebra::Vector3::new(60.0, -80.0, 0.0);
        for k in 0..2000i64 {
            let unix_ns = epoch_ns + k * 7_300_000_000;
            let s = exact
                .state_j2000(orbit::time::UtcTime::from_unix_ns(unix_ns))
                .unwrap();
            let truth = platform::truth::TruthSnapshot {
                unix_ns,
                r_eci_m: s.r_km * 1e3 + off_m,
                ..Default::default()
            };
            let ev = RunEvent::Truth {
                t: SimTime::from_secs(k as u64),
                truth: Box::new(truth),
                adcs: Default::default(),
            };
            let got = sampler.sample(&ev).unwrap().tle_offset_m.unwrap();
            assert!((got - 100.0).abs() < 1e-5, "{got} m at sample {k}");
        }
    }

    #[test]
    fn seeded_initial_attitudes_are_uniform_over_rotations() {
        // For rotations uniform on SO(3) every quaternion component has E[x^2] = 1/4, and
        // the rotation angle has density (1 - cos a) / pi: mean angle pi/2 + 2/pi.
        let n = 4000;
        let mut sq = [0.0f64; 4];
        let mut angle = 0.0;
        for seed in 0..n {
            let q = random_rotation(seed, 0x320);
            for (k, x) in [q.w, q.i, q.j, q.k].into_iter().enumerate() {
                sq[k] += x * x / n as f64;
            }
            angle += q.angle() / n as f64;
        }
        for (k, m) in sq.iter().enumerate() {
            assert!((m - 0.25).abs() < 0.02, "component {k}: E[x^2] = {m}");
        }
        let want = std::f64::consts::FRAC_PI_2 + 2.0 / std::f64::consts::PI;
        assert!(
            (angle - want).abs() < 0.03,
            "mean angle {angle}, want {want}"
        );
    }
}
