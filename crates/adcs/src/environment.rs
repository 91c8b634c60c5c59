//! The space environment at the satellite: orbit state, sun, shadow, geomagnetic field, the
//! Earth's orientation and the disturbance torques of the truth model.
//!
//! [`EnvModel`] evaluates the same `orbit` models the rest of the twin uses (SGP4 -> ECI J2000,
//! Meeus/Vallado sun, conical shadow, IGRF-14) and caches what varies slowly, so that a
//! 10 Hz ADCS loop stays cheap:
//! - `A(J2000 <- TEME)` (precession and nutation, below 1e-11 rad/s) is recomputed every
//!   [`SLOW_REFRESH_S`] of UTC; the Earth's rotation (GMST) is evaluated at every call.
//! - The IGRF-14 Gauss coefficients (secular variation of a few nT per year) are recomputed
//!   every [`SLOW_REFRESH_S`].
//! - The field itself is evaluated over knots [`FIELD_KNOT_NS`] (10 s) long: at the state
//!   where a knot starts and 5 s and 10 s ahead on the two-body path from it, quadratic in
//!   time in between, as long as the state stays within [`FIELD_PATH_TOLERANCE_M`] of that
//!   path (a burn, a new onboard orbit or a GPS jump starts a new knot). Along a 500 km
//!   orbit the error is below 0.1 nT (seen: 0.027 nT), thousands of times below the
//!   magnetometer's noise (`field_between_knots_is_within_its_bound_of_the_exact_model`;
//!   docs/adcs.md), for 3 IGRF evaluations per 100 at 10 Hz.
//!
//! The FC's flight software uses the same models for its references (onboard orbit from the
//! uploaded TLE, sun and field models): the twin's sensor errors come from the sensor models,
//! not from a mismatch of environment models (documented in docs/adcs.md).
//!
//! # The orbit after a manoeuvre
//! The orbit is an [`OrbitModel`]: SGP4 from the TLE until the first burn, then `orbit`'s
//! Cowell integrator ([`CowellPropagator`], J2 and optionally drag per the model's
//! [`CowellConfig`]) started from SGP4's exact J2000 state at the instant of the switch
//! ([`EnvModel::switch_to_numerical`]); every burn after that is an impulsive delta-v
//! ([`EnvModel::apply_delta_v`], see nodes-fc's `burns` for how a finite burn becomes
//! impulses). [`EnvModel::at`] and [`EnvModel::state_j2000`] work for both. Cowell
//! integrates forward from its last burn (its anchor): a query between grid points takes
//! one partial step, a query earlier than the last grid point re-integrates from the anchor
//! (correct, only slower), and a query before the anchor fails ("time before the start of
//! the propagation"). The FC queries at its ticks and between them (TMATP) and applies
//! burns up to its tick time only, so its queries never precede the anchor
//! (`tests/burns.rs` checks the FC's pattern).

use nalgebra::{Matrix3, Vector3};
use orbit::cowell::{CowellConfig, CowellPropagator};
use orbit::eclipse;
use orbit::frames;
use orbit::igrf::GaussCoefficients;
use orbit::propagate::{PropagationError, Propagator, Sgp4Propagator, StateVector};
use orbit::sun;
use orbit::time::UtcTime;

/// How long the slowly varying rotations and field coefficients are reused, s.
pub const SLOW_REFRESH_S: f64 = 60.0;

/// The Earth's rotation rate, rad/s (WGS-84, NIMA TR8350.2).
pub const OMEGA_EARTH_RAD_S: f64 = 7.292_115e-5;

/// The environment at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Environment {
    /// UTC, ns since the Unix epoch.
    pub unix_ns: i64,
    /// Position, ECI J2000, m.
    pub r_eci_m: Vector3<f64>,
    /// Velocity, ECI J2000, m/s.
    pub v_eci_m_s: Vector3<f64>,
    /// Unit vector from the satellite to the sun, ECI J2000.
    pub sun_eci_unit: Vector3<f64>,
    /// Visible fraction of the solar disc (1 sunlit, 0 umbra).
    pub sun_visible_fraction: f64,
    /// Geomagnetic field, ECI J2000, nT (zero when the model cannot be evaluated).
    pub b_eci_nt: Vector3<f64>,
    /// Rotation `A(ECEF <- ECI J2000)`.
    pub a_ecef_from_eci: Matrix3<f64>,
}

/// Where the orbit comes from: the TLE through SGP4, or numerical integration after a burn.
#[derive(Debug, Clone)]
pub enum OrbitModel {
    /// SGP4 from the TLE (TEME, rotated to J2000; boxed: it is three times Cowell's size).
    Sgp4(Box<Sgp4Propagator>),
    /// Cowell's method in J2000 from the state at the first burn.
    Cowell(CowellPropagator),
}

/// Cached environment models for one orbit.
#[derive(Debug, Clone)]
pub struct EnvModel {
    orbit: OrbitModel,
    /// The force model used once the orbit is numerical.
    cowell: CowellConfig,
    slow: SlowModels,
}

/// Knots of the geomagnetic field along the path, this far apart in time.
pub const FIELD_KNOT_NS: i64 = 10_000_000_000;
/// How far a state may be from the path the knots were taken on (the two-body path from the
/// state where they start) before new knots start: the field changes by about 0.02 nT per
/// metre at 500 km, so at most 1 nT, and the path itself is within 3 m of the orbit over a
/// knot (J2 and the two-body jerk).
pub const FIELD_PATH_TOLERANCE_M: f64 = 50.0;

/// The slowly varying parts of the environment models, cached for [`SLOW_REFRESH_S`], and
/// the field's knots along the path: the environment at any ECI state (a GPS fix, say)
/// without a propagator.
#[derive(Debug, Clone, Default)]
pub struct SlowModels {
    cached: Option<Slow>,
    field: Option<FieldKnots>,
}

/// The field at the start, the middle and the end of a knot, ECI J2000, and the two-body
/// path from the state at its start.
#[derive(Debug, Clone)]
struct FieldKnots {
    t0_unix_ns: i64,
    r0_eci_m: Vector3<f64>,
    v0_eci_m_s: Vector3<f64>,
    a0_eci_m_s2: Vector3<f64>,
    b_eci_nt: [Vector3<f64>; 3],
}

impl FieldKnots {
    fn path_m(&self, dt_s: f64) -> Vector3<f64> {
        self.r0_eci_m + self.v0_eci_m_s * dt_s + self.a0_eci_m_s2 * (0.5 * dt_s * dt_s)
    }

    /// The field at `unix_ns` for a satellite at `r_eci_m`, if both are within the knot.
    fn at(&self, unix_ns: i64, r_eci_m: &Vector3<f64>) -> Option<Vector3<f64>> {
        let dt_ns = unix_ns.checked_sub(self.t0_unix_ns)?;
        if !(0..FIELD_KNOT_NS).contains(&dt_ns) {
            return None;
        }
        let off_m = (self.path_m(dt_ns as f64 * 1e-9) - r_eci_m).norm();
        (off_m <= FIELD_PATH_TOLERANCE_M).then(|| {
            // Lagrange's quadratic through the three.
            let f = dt_ns as f64 / FIELD_KNOT_NS as f64;
            let [b0, bm, b1] = self.b_eci_nt;
            b0 * (2.0 * (f - 0.5) * (f - 1.0)) - bm * (4.0 * f * (f - 1.0))
                + b1 * (2.0 * f * (f - 0.5))
        })
    }
}

#[derive(Debug, Clone)]
struct Slow {
    valid_from_unix_s: f64,
    a_j2000_from_teme: Matrix3<f64>,
    igrf: Option<GaussCoefficients>,
    /// The sun (km, ECI J2000) at the start and the end of the window: linear in between.
    /// The sun moves 1.2e-5 rad in 60 s, so the chord is within 1e-11 rad of the arc.
    sun_km: [Vector3<f64>; 2],
}

impl SlowModels {
    fn get(cached: &mut Option<Slow>, t: UtcTime) -> &Slow {
        let unix_s = t.unix_s();
        let fresh = cached.as_ref().is_some_and(|s| {
            unix_s >= s.valid_from_unix_s && unix_s < s.valid_from_unix_s + SLOW_REFRESH_S
        });
        if !fresh {
            let end = UtcTime::from_unix_ns(t.unix_ns() + (SLOW_REFRESH_S * 1e9) as i64);
            *cached = Some(Slow {
                valid_from_unix_s: unix_s,
                a_j2000_from_teme: frames::a_j2000_from_teme(t),
                igrf: GaussCoefficients::igrf14(t.decimal_year()).ok(),
                sun_km: [sun::sun_eci_km(t), sun::sun_eci_km(end)],
            });
        }
        cached.get_or_insert_with(|| Slow {
            valid_from_unix_s: unix_s,
            a_j2000_from_teme: Matrix3::identity(),
            igrf: None,
            sun_km: [Vector3::zeros(); 2],
        })
    }

    /// New field knots from the state at `unix_ns` (none where the model cannot be
    /// evaluated: the field is then zero).
    fn knots(
        slow: &Slow,
        unix_ns: i64,
        r0_eci_m: Vector3<f64>,
        v0_eci_m_s: Vector3<f64>,
        a_ecef_from_eci: &Matrix3<f64>,
    ) -> Option<FieldKnots> {
        let g = slow.igrf.as_ref()?;
        let b0 = g
            .field_eci(&(r0_eci_m / 1e3), a_ecef_from_eci)
            .ok()?
            .b_eci_nt;
        let r = r0_eci_m.norm();
        let a0_eci_m_s2 = -r0_eci_m * (orbit::cowell::MU_EARTH_KM3_S2 * 1e9 / (r * r * r));
        let mut k = FieldKnots {
            t0_unix_ns: unix_ns,
            r0_eci_m,
            v0_eci_m_s,
            a0_eci_m_s2: if a0_eci_m_s2.iter().all(|x| x.is_finite()) {
                a0_eci_m_s2
            } else {
                Vector3::zeros()
            },
            b_eci_nt: [b0; 3],
        };
        for (i, dt_ns) in [(1, FIELD_KNOT_NS / 2), (2, FIELD_KNOT_NS)] {
            let t = UtcTime::from_unix_ns(unix_ns.saturating_add(dt_ns));
            let a = frames::a_ecef_from_teme(t, None) * slow.a_j2000_from_teme.transpose();
            let r_km = k.path_m(dt_ns as f64 * 1e-9) / 1e3;
            if let Ok(f) = g.field_eci(&r_km, &a) {
                k.b_eci_nt[i] = f.b_eci_nt;
            }
        }
        Some(k)
    }

    /// The sun from the cached window (linear between its ends).
    fn sun_km(slow: &Slow, unix_s: f64) -> Vector3<f64> {
        let f = ((unix_s - slow.valid_from_unix_s) / SLOW_REFRESH_S).clamp(0.0, 1.0);
        slow.sun_km[0] + (slow.sun_km[1] - slow.sun_km[0]) * f
    }

    /// The environment at an ECI J2000 state (m, m/s) at `unix_ns`.
    pub fn at_state(
        &mut self,
        unix_ns: i64,
        r_eci_m: Vector3<f64>,
        v_eci_m_s: Vector3<f64>,
    ) -> Environment {
        let t = UtcTime::from_unix_ns(unix_ns);
        let slow = Self::get(&mut self.cached, t);
        let a_ecef_from_eci =
            frames::a_ecef_from_teme(t, None) * slow.a_j2000_from_teme.transpose();
        let r_km = r_eci_m / 1e3;
        let b_eci_nt = match self.field.as_ref().and_then(|k| k.at(unix_ns, &r_eci_m)) {
            Some(b) => b,
            None => {
                self.field = Self::knots(slow, unix_ns, r_eci_m, v_eci_m_s, &a_ecef_from_eci);
                self.field
                    .as_ref()
                    .map_or_else(Vector3::zeros, |k| k.b_eci_nt[0])
            }
        };
        let sun_km = Self::sun_km(slow, t.unix_s());
        let ill = eclipse::illumination(&r_km, &sun_km);
        Environment {
            unix_ns,
            r_eci_m,
            v_eci_m_s,
            sun_eci_unit: (sun_km - r_km).try_normalize(0.0).unwrap_or_default(),
            sun_visible_fraction: ill.visible_fraction,
            b_eci_nt,
            a_ecef_from_eci,
        }
    }
}

/// Why an impulsive delta-v was not applied to the orbit.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DeltaVError {
    /// The orbit cannot be propagated to the impulse (decay, or a time before the last
    /// burn).
    #[error(transparent)]
    Propagation(#[from] PropagationError),
    /// The orbit stayed SGP4 after the switch to numerical propagation.
    #[error("the orbit did not switch to numerical")]
    NotNumerical,
}

impl EnvModel {
    /// Models for the orbit of `propagator`; after a burn, Cowell with the default force
    /// model (J2, no drag; see [`EnvModel::with_cowell_config`]).
    pub fn new(propagator: Sgp4Propagator) -> Self {
        EnvModel {
            orbit: OrbitModel::Sgp4(Box::new(propagator)),
            cowell: CowellConfig::default(),
            slow: SlowModels::default(),
        }
    }

    /// Use `config` (step, J2, drag) for the numerical orbit after the first burn.
    pub fn with_cowell_config(mut self, config: CowellConfig) -> Self {
        self.cowell = config;
        self
    }

    /// The orbit model in use.
    pub fn orbit(&self) -> &OrbitModel {
        &self.orbit
    }

    /// Whether the orbit is numerical (a burn has been applied).
    pub fn is_numerical(&self) -> bool {
        matches!(self.orbit, OrbitModel::Cowell(_))
    }

    /// The environment at `unix_ns`, or why the orbit cannot be propagated (decay, bad
    /// elements, a time before the last burn).
    pub fn at(&mut self, unix_ns: i64) -> Result<Environment, PropagationError> {
        let t = UtcTime::from_unix_ns(unix_ns);
        let (r_eci_m, v_eci_m_s) = match &mut self.orbit {
            OrbitModel::Sgp4(p) => {
                let teme = p.state_teme_at(t)?;
                let a = SlowModels::get(&mut self.slow.cached, t).a_j2000_from_teme;
                (a * teme.r_km * 1e3, a * teme.v_km_s * 1e3)
            }
            OrbitModel::Cowell(p) => {
                let s = p.state_j2000(t)?;
                (s.r_km * 1e3, s.v_km_s * 1e3)
            }
        };
        Ok(self.slow.at_state(unix_ns, r_eci_m, v_eci_m_s))
    }

    /// The exact ECI J2000 state (no cache), as `orbit`'s propagator gives it.
    pub fn state_j2000(&mut self, unix_ns: i64) -> Result<StateVector, PropagationError> {
        let t = UtcTime::from_unix_ns(unix_ns);
        match &mut self.orbit {
            OrbitModel::Sgp4(p) => p.as_mut().state_j2000(t),
            OrbitModel::Cowell(p) => p.state_j2000(t),
        }
    }

    /// Switch to numerical propagation at `unix_ns`, from SGP4's J2000 state there; nothing
    /// happens if the orbit is numerical already.
    pub fn switch_to_numerical(&mut self, unix_ns: i64) -> Result<(), PropagationError> {
        if let OrbitModel::Sgp4(p) = &mut self.orbit {
            let c = CowellPropagator::from_propagator(
                p.as_mut(),
                UtcTime::from_unix_ns(unix_ns),
                self.cowell,
            )?;
            self.orbit = OrbitModel::Cowell(c);
        }
        Ok(())
    }

    /// Add the impulsive `dv_eci_m_s` (ECI J2000, m/s) to the velocity at `unix_ns`,
    /// switching to numerical propagation there first if needed; returns the state just
    /// after. Fails for a time before the last burn.
    pub fn apply_delta_v(
        &mut self,
        unix_ns: i64,
        dv_eci_m_s: Vector3<f64>,
    ) -> Result<StateVector, DeltaVError> {
        self.switch_to_numerical(unix_ns)?;
        match &mut self.orbit {
            OrbitModel::Cowell(p) => {
                Ok(p.apply_delta_v(UtcTime::from_unix_ns(unix_ns), dv_eci_m_s / 1e3)?)
            }
            OrbitModel::Sgp4(_) => Err(DeltaVError::NotNumerical),
        }
    }
}

/// Atmospheric density, kg/m^3, at altitude `alt_m`: `orbit`'s exponential model
/// (Vallado 2013 table 8-4); zero for a non-finite altitude.
pub fn density_kg_m3(alt_m: f64) -> f64 {
    if alt_m.is_finite() {
        orbit::cowell::exponential_density_kg_m3(alt_m / 1e3)
    } else {
        0.0
    }
}

/// The bus's outer shape for drag: six faces of a box, normals and centres in BCF.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DragConfig {
    /// Box edges along BCF X, Y, Z, m.
    pub size_m: Vector3<f64>,
    /// Centre of mass relative to the box's geometric centre, BCF, m.
    pub cm_offset_m: Vector3<f64>,
    /// Drag coefficient (2.2, the usual free-molecular flat-plate figure).
    pub cd: f64,
}

impl Default for DragConfig {
    /// The 6U box of `truth::BodyConfig::default` (0.2 x 0.1 x 0.3 m) with the centre of mass
    /// 10 mm towards the propulsion face (-Z: tank and thruster), Cd 2.2. Deployable wings
    /// are not modelled for drag.
    fn default() -> Self {
        DragConfig {
            size_m: Vector3::new(0.2, 0.1, 0.3),
            cm_offset_m: Vector3::new(0.0, 0.0, -0.01),
            cd: 2.2,
        }
    }
}

/// Aerodynamic torque about the centre of mass, body frame, N m: flat-plate drag on each
/// face that sees the flow, `F = -rho Cd A cos(theta) |v|^2 / 2 v_hat`, applied at the face
/// centre. The flow is the velocity relative to the co-rotating atmosphere.
pub fn drag_torque_body_nm(
    cfg: &DragConfig,
    q_eci_from_body: &nalgebra::UnitQuaternion<f64>,
    r_eci_m: &Vector3<f64>,
    v_eci_m_s: &Vector3<f64>,
) -> Vector3<f64> {
    let alt_m = r_eci_m.norm() - eclipse::EARTH_RADIUS_KM * 1e3;
    let rho = density_kg_m3(alt_m);
    let v_rel_eci = v_eci_m_s - Vector3::z().cross(r_eci_m) * OMEGA_EARTH_RAD_S;
    let speed = v_rel_eci.norm();
    if rho == 0.0 || speed == 0.0 || !speed.is_finite() {
        return Vector3::zeros();
    }
    let v_hat = q_eci_from_body.inverse_transform_vector(&v_rel_eci) / speed;
    let s = cfg.size_m;
    let mut torque = Vector3::zeros();
    for axis in 0..3 {
        let area = s[(axis + 1) % 3] * s[(axis + 2) % 3];
        for sign in [1.0, -1.0] {
            let mut n = Vector3::zeros();
            n[axis] = sign;
            let cos = n.dot(&v_hat);
            if cos <= 0.0 {
                continue;
            }
            let force = -v_hat * (0.5 * rho * cfg.cd * area * cos * speed * speed);
            let centre = n * (0.5 * s[axis]) - cfg.cm_offset_m;
            torque += centre.cross(&force);
        }
    }
    torque
}

// What a snapshot keeps of the environment model: the orbit once a burn made it numerical
// (an SGP4 orbit is the scenario's TLE, rebuilt), and the caches, whose contents depend on
// when they were refreshed (a restored run reads the same bits, never a recomputation).
snap::fields!(Environment {
    unix_ns,
    r_eci_m,
    v_eci_m_s,
    sun_eci_unit,
    sun_visible_fraction,
    b_eci_nt,
    a_ecef_from_eci
});
snap::fields!(FieldKnots {
    t0_unix_ns,
    r0_eci_m,
    v0_eci_m_s,
    a0_eci_m_s2,
    b_eci_nt
});
snap::fields!(Slow {
    valid_from_unix_s,
    a_j2000_from_teme,
    igrf,
    sun_km
});
snap::fields!(SlowModels { cached, field });

impl snap::Snap for EnvModel {
    fn save(&self, w: &mut snap::Writer) {
        let EnvModel {
            orbit,
            cowell: _,
            slow,
        } = self;
        match orbit {
            OrbitModel::Sgp4(_) => snap::Snap::save(&0u8, w),
            OrbitModel::Cowell(p) => {
                snap::Snap::save(&1u8, w);
                snap::Snap::save(p, w);
            }
        }
        snap::Snap::save(slow, w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        let EnvModel {
            orbit,
            cowell: _,
            slow,
        } = self;
        let at = r.at();
        match <u8 as snap::SnapNew>::read(r)? {
            // The scenario's SGP4 orbit, as built.
            0 if matches!(orbit, OrbitModel::Sgp4(_)) => {}
            1 => *orbit = OrbitModel::Cowell(snap::SnapNew::read(r)?),
            _ => {
                return Err(snap::SnapError::Bad {
                    what: "OrbitModel",
                    at,
                });
            }
        }
        snap::Snap::load(slow, r)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use orbit::tle::{ChecksumMode, Tle};

    const L1: &str = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996";
    const L2: &str = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009";
    const START_NS: i64 = 1_777_572_000 * 1_000_000_000;

    fn model() -> EnvModel {
        EnvModel::new(
            Sgp4Propagator::new(&Tle::parse(L1, L2, ChecksumMode::Strict).unwrap()).unwrap(),
        )
    }

    #[test]
    fn cached_environment_matches_the_exact_models() {
        let mut m = model();
        for k in 0..200 {
            let unix_ns = START_NS + k * 7_300_000_000;
            let e = m.at(unix_ns).unwrap();
            let t = UtcTime::from_unix_ns(unix_ns);
            let exact = m.state_j2000(unix_ns).unwrap();
            // Precession-nutation held for up to a minute (7.7e-12 rad/s of precession at
            // 6900 km: 3 mm a minute): below a centimetre.
            let dr = (e.r_eci_m - exact.r_km * 1e3).norm();
            assert!(dr < 5e-3, "k {k}: {dr} m");
            let b = orbit::igrf::field_eci_at(t, &exact.r_km, None)
                .unwrap()
                .b_eci_nt;
            // Within the knots' bound (below).
            assert!(
                (e.b_eci_nt - b).norm() < 0.1,
                "k {k}: {}",
                (e.b_eci_nt - b).norm()
            );
            let ill = eclipse::illumination_at(t, &exact.r_km);
            assert!((e.sun_visible_fraction - ill.visible_fraction).abs() < 1e-6);
            let sun = (orbit::sun::sun_eci_km(t) - exact.r_km).normalize();
            let d_sun_rad = e.sun_eci_unit.cross(&sun).norm();
            assert!(d_sun_rad < 1e-9, "k {k}: sun off by {d_sun_rad} rad");
            let a = frames::a_ecef_from_eci(t, None);
            assert!((e.a_ecef_from_eci - a).norm() < 1e-9);
        }
    }

    /// The field between knots against IGRF evaluated at every instant: sampled every
    /// 0.3 s for an orbit (the FC asks at 10 Hz), it is within 0.1 nT (seen: 0.027 nT), and
    /// exact where a knot starts.
    #[test]
    fn field_between_knots_is_within_its_bound_of_the_exact_model() {
        let mut m = model();
        let mut worst: f64 = 0.0;
        let mut knots = 0;
        let mut last_t0 = None;
        for k in 0..19_000 {
            let unix_ns = START_NS + k * 300_000_000;
            let e = m.at(unix_ns).unwrap();
            let t = UtcTime::from_unix_ns(unix_ns);
            let b = orbit::igrf::field_eci_at(t, &(e.r_eci_m / 1e3), None)
                .unwrap()
                .b_eci_nt;
            let err = (e.b_eci_nt - b).norm();
            worst = worst.max(err);
            let t0 = m.slow.field.as_ref().unwrap().t0_unix_ns;
            if last_t0 != Some(t0) {
                knots += 1;
                last_t0 = Some(t0);
                assert!(err < 1e-3, "k {k}: a knot's start is exact ({err} nT)");
            }
        }
        assert!(worst < 0.1, "worst {worst} nT");
        // One knot per 10 s (34 samples), no more.
        assert_eq!(knots, 19_000 / 34 + 1);
    }

    /// A state off the knots' path (a GPS jump, a burn) starts new knots there.
    #[test]
    fn a_state_off_the_path_starts_new_knots() {
        let mut m = model();
        let e = m.at(START_NS).unwrap();
        let mut slow = SlowModels::default();
        let a = slow.at_state(START_NS, e.r_eci_m, e.v_eci_m_s);
        let t0 = slow.field.as_ref().unwrap().t0_unix_ns;
        let later = START_NS + 1_000_000_000;
        let on = m.at(later).unwrap();
        slow.at_state(later, on.r_eci_m, on.v_eci_m_s);
        assert_eq!(slow.field.as_ref().unwrap().t0_unix_ns, t0, "on the path");
        let off = on.r_eci_m + Vector3::new(0.0, 0.0, 2.0 * FIELD_PATH_TOLERANCE_M);
        let b = slow.at_state(later, off, on.v_eci_m_s).b_eci_nt;
        assert_eq!(slow.field.as_ref().unwrap().t0_unix_ns, later, "new knots");
        let exact = orbit::igrf::field_eci_at(UtcTime::from_unix_ns(later), &(off / 1e3), None)
            .unwrap()
            .b_eci_nt;
        assert!((b - exact).norm() < 1e-3);
        assert!((a.b_eci_nt - e.b_eci_nt).norm() < 1e-9);
    }

    #[test]
    fn switching_to_numerical_continues_the_sgp4_orbit() {
        let mut m = model();
        let mut sgp4 = model();
        let t0 = START_NS + 600_000_000_000;
        assert!(!m.is_numerical());
        m.switch_to_numerical(t0).unwrap();
        assert!(m.is_numerical());
        // At the switch: SGP4's exact J2000 state.
        let s0 = sgp4.state_j2000(t0).unwrap();
        assert_eq!(m.state_j2000(t0).unwrap(), s0);
        // `at` agrees with `state_j2000` for the numerical orbit.
        let e = m.at(t0 + 5_000_000_000).unwrap();
        let s = m.state_j2000(t0 + 5_000_000_000).unwrap();
        assert_eq!(e.r_eci_m, s.r_km * 1e3);
        // J2-only Cowell from an SGP4 state drifts from SGP4 slowly: metres after a minute.
        for (dt_s, tol_m) in [(1i64, 0.1), (60, 20.0)] {
            let t = t0 + dt_s * 1_000_000_000;
            let d = (m.at(t).unwrap().r_eci_m - sgp4.at(t).unwrap().r_eci_m).norm();
            assert!(d < tol_m, "{dt_s} s: {d} m");
        }
        // A second switch changes nothing; a query before the switch fails.
        m.switch_to_numerical(t0 + 1_000_000_000).unwrap();
        assert_eq!(m.state_j2000(t0).unwrap(), s0);
        assert_eq!(m.at(t0 - 1).unwrap_err(), PropagationError::BeforeStart);
    }

    #[test]
    fn a_delta_v_changes_the_velocity_at_its_instant_only() {
        let mut m = model();
        let t0 = START_NS + 60_000_000_000;
        let before = m.state_j2000(t0).unwrap();
        let dv = Vector3::new(0.1, -0.2, 0.3);
        let after = m.apply_delta_v(t0, dv).unwrap();
        assert_eq!(after.r_km, before.r_km);
        assert!(((after.v_km_s - before.v_km_s) * 1e3 - dv).norm() < 1e-12);
        // Earlier than the burn: refused, never a silent answer from the old orbit.
        assert_eq!(
            m.apply_delta_v(t0 - 1_000, dv).unwrap_err(),
            DeltaVError::Propagation(PropagationError::BeforeStart)
        );
        assert!(m.state_j2000(t0 - 1_000).is_err());
        // Later queries, forwards and back to the anchor, keep working.
        let later = m.state_j2000(t0 + 100_000_000_000).unwrap();
        assert!(m.state_j2000(t0 + 1_000_000_000).is_ok());
        assert_eq!(m.state_j2000(t0 + 100_000_000_000).unwrap(), later);
    }

    #[test]
    fn density_follows_the_table_and_decreases_with_altitude() {
        assert!((density_kg_m3(500e3) - 6.967e-13).abs() < 1e-18);
        let mut last = f64::INFINITY;
        for h in (150..1200).step_by(10) {
            let d = density_kg_m3(f64::from(h) * 1e3);
            assert!(d > 0.0 && d < last, "{h} km");
            last = d;
        }
        assert_eq!(density_kg_m3(f64::NAN), 0.0);
    }

    #[test]
    fn drag_torque_is_small_and_vanishes_with_a_centred_mass_facing_the_flow() {
        let r = Vector3::new(6_878_137.0, 0.0, 0.0);
        let v = Vector3::new(0.0, 7_600.0, 0.0);
        let q = nalgebra::UnitQuaternion::identity();
        let centred = DragConfig {
            cm_offset_m: Vector3::zeros(),
            ..DragConfig::default()
        };
        assert!(drag_torque_body_nm(&centred, &q, &r, &v).norm() < 1e-15);
        let t = drag_torque_body_nm(&DragConfig::default(), &q, &r, &v);
        // 500 km: rho 7e-13, q = rho v^2 / 2 = 2e-5 Pa; 0.06 m^2, 2.2, 10 mm arm: ~3e-8 N m.
        assert!(t.norm() > 1e-9 && t.norm() < 1e-7, "{t}");
    }

    /// The model saved after a burn (numerical since) and loaded into one fresh from the
    /// TLE gives the same environment to the bit, caches included.
    #[test]
    fn a_model_saved_after_a_burn_goes_on_to_the_same_bits() {
        let mut a = model();
        a.at(START_NS).unwrap();
        a.apply_delta_v(START_NS + 60_000_000_000, Vector3::new(0.0, 0.5, 0.0))
            .unwrap();
        a.at(START_NS + 61_000_000_000).unwrap();
        let bytes = snap::to_bytes(&a);
        let mut b = model();
        snap::load_from(&mut b, &bytes).unwrap();
        assert!(b.is_numerical());
        assert_eq!(snap::to_bytes(&b), bytes);
        for k in 0..50 {
            let unix_ns = START_NS + 61_000_000_000 + k * 3_700_000_000;
            assert_eq!(a.at(unix_ns).unwrap(), b.at(unix_ns).unwrap());
        }
        // An SGP4 model loads over an SGP4 model only as built.
        let sgp4 = snap::to_bytes(&model());
        snap::load_from(&mut model(), &sgp4).unwrap();
    }
}
