//! ADCS guidance: the target attitude, its rate and its pointing axis for each pointing mode.
//!
//! A pure, deterministic core: [`target`] maps a [`Pointing`] and the onboard references
//! ([`GuidanceInputs`]: orbit state, sun direction, Earth orientation) to a
//! [`GuidanceTarget`]. No clock, no allocation, no panic; degenerate geometry (zero or
//! non-finite vectors, a primary direction exactly along its secondary) gives `None`.
//!
//! # Frames (ICD 1.4, INTERPRETATION.md section 5)
//! ECI is J2000; body is the BCF; `q_eci_from_body * v_body = v_eci`. LVLH: Z to the Earth's
//! centre, Y opposite the orbit angular momentum `h = r x v`, X completes (along motion).
//! TNW: X along velocity, Y along `h`, Z = X x Y. The fixed modes' quaternions are
//! `q_ref_from_body` (ICD 1.5 `pointECI/LVLH/TNW r i j k`: `v_ref = q v_body`).
//!
//! # Modes
//! Every mode but the fixed ones aligns one body axis exactly with one direction (the
//! primary) and turns a second body axis as close as possible to a second direction (the
//! secondary): the TRIAD construction, which puts the secondary body axis in the plane of
//! the two reference directions, on the secondary's side. That is the attitude with the
//! smallest secondary angle among those that meet the primary exactly.
//! - [`Pointing::Nadir`]: body = LVLH (`orbit::frames::q_eci_from_lvlh`): +Z to the Earth's
//!   centre, +X along motion, +Y opposite `h`.
//! - [`Pointing::Velocity`]: body +Z along the velocity; body +X as close as possible to
//!   zenith (`r`).
//! - [`Pointing::SunMaxPower`]: the panel normal on the sun; body +Z as close as possible
//!   to nadir (body +X instead when the panel normal is within 25.8 deg of body +-Z, where
//!   +Z is no usable secondary).
//! - [`Pointing::EarthTarget`] and [`Pointing::EciVector`]: `axis_body` along the line of
//!   sight to the geodetic point (fixed in ECEF, so it turns with the Earth; WGS-84 via
//!   `orbit::geodetic`) or along the ECI direction. Secondary: **body +Y as close as
//!   possible to the negative orbit normal `-h`** (LVLH +Y), so that with `axis_body` = +Z
//!   and a target straight below, the attitude is nadir's (body X near the velocity, the
//!   usual yaw of an imaging pass). When `axis_body` is within 25.8 deg of body +-Y
//!   (`|axis . y| > 0.9`), the secondary is instead **body +X as close as possible to the
//!   velocity** (again LVLH-like). A line of sight exactly along the secondary direction is
//!   degenerate (`None`).
//! - [`Pointing::FixedEci`], [`Pointing::FixedLvlh`], [`Pointing::FixedTnw`]: the quaternion
//!   composed with the reference frame's attitude; the pointing axis is body +Z.
//!
//! # Target rate (feed-forward)
//! [`GuidanceTarget::w_body_rad_s`] is the rate of the target frame relative to ECI, in
//! target body axes, by a central difference: the target is evaluated at `t - h` and
//! `t + h` (`h` = [`RATE_STEP_S`]) with the inputs extrapolated (two-body:
//! `r + v dt + a dt^2 / 2`, `v + a dt`, `a = -mu r / |r|^3`; the ECEF rotation advanced by
//! the Earth's rotation rate, `A(t + dt) = R3(omega dt) A(t)`; the sun held fixed, as it
//! moves 1 deg a day), and `w = (log(q0^-1 q+) - log(q0^-1 q-)) / 2h`. The error is second
//! order in `h`: below 1e-5 relative for nadir, and for an Earth target 500 km away at
//! the top of a pass (rate 0.015 rad/s, changing over ~30 s) about 1e-4 relative. The
//! second difference gives the angular acceleration,
//! [`GuidanceTarget::dw_body_rad_s2`] `= (log(q0^-1 q+) + log(q0^-1 q-)) / h^2` (the rotation
//! vector's second derivative is the rate's derivative at the origin). If one neighbour is
//! degenerate the one-sided difference is used and the acceleration is zero; if both are,
//! both are zero.
//!
//! # Elevation
//! For an Earth target, [`GuidanceTarget::target_elevation_deg`] is the elevation of the
//! satellite above the target's local (geodetic, WGS-84) horizon: `asin(up . d / |d|)` with
//! `d` the target-to-satellite vector in ECEF and `up` the ellipsoid normal.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use orbit::frames::{self, OMEGA_EARTH_RAD_S, canonical, quaternion_from_matrix};
use orbit::geodetic::{Geodetic, a_enu_from_ecef};

use crate::truth::MU_EARTH_M3_S2;

/// Default solar panel normal, body frame: +X, the twin's default solar wing normal (the
/// 200 mm "up" edge of ICD 1.4's BCF; EPS uses the same for its panel power).
pub const DEFAULT_PANEL_NORMAL_BODY: Vector3<f64> = Vector3::new(1.0, 0.0, 0.0);

/// Half-step of the central difference that gives the target rate, s.
pub const RATE_STEP_S: f64 = 0.5;

/// `|axis . preferred|` above which the preferred secondary body axis is replaced by the
/// fallback (0.9: within 25.8 deg of the primary axis, the secondary would be ill-defined).
const SECONDARY_SWITCH_COS: f64 = 0.9;

/// Smallest cross-product norm (of unit vectors) that still defines a secondary plane:
/// sin(2e-7 deg). Anything closer to parallel is degenerate.
const PARALLEL_EPS: f64 = 1e-9;

/// The onboard references guidance needs at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceInputs {
    /// UTC unix seconds (informational; the geometry comes from the other fields).
    pub unix_s: f64,
    /// Position, ECI J2000, m.
    pub r_eci_m: Vector3<f64>,
    /// Velocity, ECI J2000, m/s.
    pub v_eci_m_s: Vector3<f64>,
    /// Unit vector from the spacecraft to the sun, ECI J2000.
    pub sun_eci_unit: Vector3<f64>,
    /// A(ECEF <- ECI) at `unix_s` (`orbit::frames::a_ecef_from_eci`).
    pub a_ecef_from_eci: Matrix3<f64>,
}

/// A pointing request (one per ICD 1.3 mode and ICD 1.5 script command).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pointing {
    /// Body = LVLH: body +Z to the Earth's centre, +X along motion.
    Nadir,
    /// Body +Z along the orbital velocity; body +X as close as possible to zenith.
    Velocity,
    /// The panel normal on the sun; body +Z as close as possible to nadir.
    SunMaxPower {
        /// Solar panel normal, body frame.
        panel_normal_body: Vector3<f64>,
    },
    /// `axis_body` along the line of sight to a geodetic point (ICD 1.5 `pointGEO`); body +Y
    /// as close as possible to `-h` (see the module doc).
    EarthTarget {
        /// Geodetic latitude, deg.
        lat_deg: f64,
        /// Longitude (east), deg.
        lon_deg: f64,
        /// Height above the WGS-84 ellipsoid, m.
        alt_m: f64,
        /// The body axis to point.
        axis_body: Vector3<f64>,
    },
    /// `axis_body` along an ECI direction; same secondary as [`Pointing::EarthTarget`].
    EciVector {
        /// The direction, ECI J2000 (any length but zero).
        dir_eci: Vector3<f64>,
        /// The body axis to point.
        axis_body: Vector3<f64>,
    },
    /// Hold `q_eci_from_body` (ICD 1.5 `pointECI`).
    FixedEci(UnitQuaternion<f64>),
    /// Hold `q_lvlh_from_body` (ICD 1.5 `pointLVLH`).
    FixedLvlh(UnitQuaternion<f64>),
    /// Hold `q_tnw_from_body` (ICD 1.5 `pointTNW`).
    FixedTnw(UnitQuaternion<f64>),
}

/// The target attitude for one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceTarget {
    /// Target attitude, w >= 0.
    pub q_eci_from_body: UnitQuaternion<f64>,
    /// Rate of the target frame relative to ECI, in target body axes, rad/s (feed-forward).
    pub w_body_rad_s: Vector3<f64>,
    /// Angular acceleration of the target frame, in target body axes, rad/s^2
    /// (feed-forward; it matters for Earth targets near the top of a pass).
    pub dw_body_rad_s2: Vector3<f64>,
    /// The mode's pointing axis, body frame, unit (fixed modes: +Z).
    pub axis_body: Vector3<f64>,
    /// Where the pointing axis should point, ECI, unit (fixed modes: `q * +Z`).
    pub axis_target_eci: Vector3<f64>,
    /// Earth target: elevation of the satellite above the target's local horizon, deg.
    pub target_elevation_deg: Option<f64>,
}

impl GuidanceTarget {
    /// Angle between the pointing axis at `q_eci_from_body` and its target direction, rad.
    pub fn axis_error_rad(&self, q_eci_from_body: &UnitQuaternion<f64>) -> f64 {
        let a = q_eci_from_body * self.axis_body;
        a.cross(&self.axis_target_eci)
            .norm()
            .atan2(a.dot(&self.axis_target_eci))
    }
}

/// The target attitude, rate and pointing axis for `p` at the instant of `g`; `None` for
/// degenerate geometry or non-finite input.
pub fn target(p: &Pointing, g: &GuidanceInputs) -> Option<GuidanceTarget> {
    let a0 = attitude(p, g)?;
    let h = RATE_STEP_S;
    let log = |a: &Attitude| (a0.q.inverse() * a.q).scaled_axis();
    let (w, dw) = match (attitude(p, &advance(g, h)), attitude(p, &advance(g, -h))) {
        (Some(ap), Some(am)) => {
            let (lp, lm) = (log(&ap), log(&am));
            ((lp - lm) / (2.0 * h), (lp + lm) / (h * h))
        }
        (Some(ap), None) => (log(&ap) / h, Vector3::zeros()),
        (None, Some(am)) => (-log(&am) / h, Vector3::zeros()),
        (None, None) => (Vector3::zeros(), Vector3::zeros()),
    };
    let ok = finite(&w) && finite(&dw);
    let (w_body_rad_s, dw_body_rad_s2) = if ok {
        (w, dw)
    } else {
        (Vector3::zeros(), Vector3::zeros())
    };
    Some(GuidanceTarget {
        q_eci_from_body: a0.q,
        w_body_rad_s,
        dw_body_rad_s2,
        axis_body: a0.axis_body,
        axis_target_eci: a0.axis_target_eci,
        target_elevation_deg: a0.elevation_deg,
    })
}

/// The inputs extrapolated by `dt_s`: two-body orbit, Earth rotation, sun fixed.
pub fn advance(g: &GuidanceInputs, dt_s: f64) -> GuidanceInputs {
    let r = g.r_eci_m;
    let r_norm = r.norm();
    let a = -r * (MU_EARTH_M3_S2 / (r_norm * r_norm * r_norm));
    GuidanceInputs {
        unix_s: g.unix_s + dt_s,
        r_eci_m: r + g.v_eci_m_s * dt_s + a * (0.5 * dt_s * dt_s),
        v_eci_m_s: g.v_eci_m_s + a * dt_s,
        sun_eci_unit: g.sun_eci_unit,
        a_ecef_from_eci: frames::rot3(OMEGA_EARTH_RAD_S * dt_s) * g.a_ecef_from_eci,
    }
}

/// The attitude part of a target (no rate).
#[derive(Debug, Clone, Copy)]
struct Attitude {
    q: UnitQuaternion<f64>,
    axis_body: Vector3<f64>,
    axis_target_eci: Vector3<f64>,
    elevation_deg: Option<f64>,
}

fn finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// `v` scaled to unit length, or `None` if it is zero or not finite.
fn unit(v: &Vector3<f64>) -> Option<Vector3<f64>> {
    if !finite(v) {
        return None;
    }
    let n = v.norm();
    (n > 0.0 && n.is_finite()).then(|| v / n)
}

fn finite_q(q: &UnitQuaternion<f64>) -> Option<UnitQuaternion<f64>> {
    let c = q.coords;
    let n = c.norm();
    (c.iter().all(|x| x.is_finite()) && n > 0.0)
        .then(|| UnitQuaternion::new_unchecked(nalgebra::Quaternion::from(c / n)))
}

/// Orbit geometry: unit position, velocity and orbit normal.
struct Orbit {
    r_hat: Vector3<f64>,
    v_hat: Vector3<f64>,
    h_hat: Vector3<f64>,
}

fn orbit_geometry(g: &GuidanceInputs) -> Option<Orbit> {
    let r_hat = unit(&g.r_eci_m)?;
    let v_hat = unit(&g.v_eci_m_s)?;
    let h = r_hat.cross(&v_hat);
    (h.norm() > PARALLEL_EPS).then(|| Orbit {
        r_hat,
        v_hat,
        h_hat: h.normalize(),
    })
}

/// TRIAD: the attitude that puts `p_body` on `p_ref` and `s_body` as close as possible to
/// `s_ref`; `None` if either pair is (nearly) parallel or a vector is degenerate.
fn two_vector(
    p_body: &Vector3<f64>,
    s_body: &Vector3<f64>,
    p_ref: &Vector3<f64>,
    s_ref: &Vector3<f64>,
) -> Option<UnitQuaternion<f64>> {
    let triad = |p: &Vector3<f64>, s: &Vector3<f64>| -> Option<Matrix3<f64>> {
        let t1 = unit(p)?;
        let c = t1.cross(&unit(s)?);
        let n = c.norm();
        if n <= PARALLEL_EPS {
            return None;
        }
        let t2 = c / n;
        Some(Matrix3::from_columns(&[t1, t2, t1.cross(&t2)]))
    };
    let a_eci_from_body = triad(p_ref, s_ref)? * triad(p_body, s_body)?.transpose();
    let q = quaternion_from_matrix(&a_eci_from_body);
    finite_q(&q).map(canonical)
}

/// The secondary body axis for a primary `axis` (unit): `preferred` unless the primary is
/// within 25.8 deg of it, then `fallback`.
fn secondary_body(
    axis: &Vector3<f64>,
    preferred: Vector3<f64>,
    fallback: Vector3<f64>,
) -> (Vector3<f64>, bool) {
    if axis.dot(&preferred).abs() > SECONDARY_SWITCH_COS {
        (fallback, false)
    } else {
        (preferred, true)
    }
}

/// Point `axis_body` along `dir_eci` with the Earth-target/ECI-vector secondary.
fn point_axis(axis_body: &Vector3<f64>, dir_eci: &Vector3<f64>, o: &Orbit) -> Option<Attitude> {
    let axis = unit(axis_body)?;
    let dir = unit(dir_eci)?;
    let (s_body, preferred) = secondary_body(&axis, Vector3::y(), Vector3::x());
    let s_ref = if preferred { -o.h_hat } else { o.v_hat };
    Some(Attitude {
        q: two_vector(&axis, &s_body, &dir, &s_ref)?,
        axis_body: axis,
        axis_target_eci: dir,
        elevation_deg: None,
    })
}

/// A fixed attitude in a reference frame: pointing axis +Z.
fn fixed(q_eci_from_ref: UnitQuaternion<f64>, q_ref_from_body: &UnitQuaternion<f64>) -> Attitude {
    let q = canonical(q_eci_from_ref * q_ref_from_body);
    Attitude {
        q,
        axis_body: Vector3::z(),
        axis_target_eci: q * Vector3::z(),
        elevation_deg: None,
    }
}

fn attitude(p: &Pointing, g: &GuidanceInputs) -> Option<Attitude> {
    if let Pointing::FixedEci(q) = p {
        return Some(fixed(UnitQuaternion::identity(), &finite_q(q)?));
    }
    let o = orbit_geometry(g)?;
    let (r_km, v_km_s) = (g.r_eci_m * 1e-3, g.v_eci_m_s * 1e-3);
    let att = match p {
        Pointing::Nadir => Attitude {
            q: finite_q(&frames::q_eci_from_lvlh(&r_km, &v_km_s))?,
            axis_body: Vector3::z(),
            axis_target_eci: -o.r_hat,
            elevation_deg: None,
        },
        Pointing::Velocity => Attitude {
            q: two_vector(&Vector3::z(), &Vector3::x(), &o.v_hat, &o.r_hat)?,
            axis_body: Vector3::z(),
            axis_target_eci: o.v_hat,
            elevation_deg: None,
        },
        Pointing::SunMaxPower { panel_normal_body } => {
            let n = unit(panel_normal_body)?;
            let sun = unit(&g.sun_eci_unit)?;
            let (s_body, _) = secondary_body(&n, Vector3::z(), Vector3::x());
            Attitude {
                q: two_vector(&n, &s_body, &sun, &-o.r_hat)?,
                axis_body: n,
                axis_target_eci: sun,
                elevation_deg: None,
            }
        }
        Pointing::EarthTarget {
            lat_deg,
            lon_deg,
            alt_m,
            axis_body,
        } => {
            let a = &g.a_ecef_from_eci;
            if !a.iter().all(|x| x.is_finite()) {
                return None;
            }
            let site = Geodetic::from_deg(*lat_deg, *lon_deg, *alt_m);
            let site_ecef_m = site.to_ecef_m();
            let sat_ecef_m = a * g.r_eci_m;
            let d_ecef = sat_ecef_m - site_ecef_m;
            let up = a_enu_from_ecef(site.lat_rad, site.lon_rad)
                .row(2)
                .transpose();
            let elevation_deg = (up.dot(&d_ecef) / d_ecef.norm()).asin().to_degrees();
            let los_eci = a.tr_mul(&-d_ecef);
            let mut att = point_axis(axis_body, &los_eci, &o)?;
            att.elevation_deg = elevation_deg.is_finite().then_some(elevation_deg);
            att
        }
        Pointing::EciVector { dir_eci, axis_body } => point_axis(axis_body, dir_eci, &o)?,
        Pointing::FixedLvlh(q) => fixed(frames::q_eci_from_lvlh(&r_km, &v_km_s), &finite_q(q)?),
        Pointing::FixedTnw(q) => fixed(frames::q_eci_from_tnw(&r_km, &v_km_s), &finite_q(q)?),
        Pointing::FixedEci(_) => return None,
    };
    (finite_q(&att.q).is_some() && finite(&att.axis_target_eci)).then_some(att)
}

snap::fields!(GuidanceTarget {
    q_eci_from_body,
    w_body_rad_s,
    dw_body_rad_s2,
    axis_body,
    axis_target_eci,
    target_elevation_deg
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A circular-ish orbit state at 7000 km.
    fn inputs() -> GuidanceInputs {
        GuidanceInputs {
            unix_s: 0.0,
            r_eci_m: Vector3::new(7.0e6, 0.0, 0.0),
            v_eci_m_s: Vector3::new(0.0, 5.0e3, 5.6e3),
            sun_eci_unit: Vector3::new(0.3, -0.8, 0.4).normalize(),
            a_ecef_from_eci: Matrix3::identity(),
        }
    }

    #[test]
    fn two_vector_puts_the_primary_exactly_and_the_secondary_in_plane() {
        let (pb, sb) = (Vector3::new(1.0, 2.0, 0.5), Vector3::new(-0.3, 0.2, 1.0));
        let (pr, sr) = (Vector3::new(0.0, -1.0, 0.2), Vector3::new(0.7, 0.1, 0.1));
        let q = two_vector(&pb, &sb, &pr, &sr).unwrap();
        assert!((q * pb.normalize() - pr.normalize()).norm() < 1e-14);
        // The secondary lies in the plane of the reference pair, on the secondary's side.
        let s = q * sb.normalize();
        assert!(s.dot(&pr.cross(&sr).normalize()).abs() < 1e-14);
        assert!(s.dot(&sr) > 0.0);
        assert!(two_vector(&pb, &pb, &pr, &sr).is_none());
        assert!(two_vector(&pb, &sb, &pr, &(pr * 3.0)).is_none());
    }

    #[test]
    fn non_finite_or_zero_inputs_give_none_never_a_panic() {
        let modes = [
            Pointing::Nadir,
            Pointing::Velocity,
            Pointing::SunMaxPower {
                panel_normal_body: DEFAULT_PANEL_NORMAL_BODY,
            },
            Pointing::EarthTarget {
                lat_deg: 54.6872,
                lon_deg: 25.2797,
                alt_m: 100.0,
                axis_body: Vector3::z(),
            },
            Pointing::EciVector {
                dir_eci: Vector3::new(1.0, 1.0, 0.0),
                axis_body: Vector3::z(),
            },
            Pointing::FixedLvlh(UnitQuaternion::identity()),
            Pointing::FixedTnw(UnitQuaternion::identity()),
        ];
        for p in &modes {
            assert!(target(p, &inputs()).is_some(), "{p:?}");
            for bad in [f64::NAN, f64::INFINITY] {
                let mut g = inputs();
                g.r_eci_m.y = bad;
                assert!(target(p, &g).is_none(), "{p:?}");
                let mut g = inputs();
                g.v_eci_m_s.x = bad;
                assert!(target(p, &g).is_none(), "{p:?}");
            }
            let mut g = inputs();
            g.r_eci_m = Vector3::zeros();
            assert!(target(p, &g).is_none(), "{p:?}");
            let mut g = inputs();
            g.v_eci_m_s = g.r_eci_m;
            assert!(target(p, &g).is_none(), "{p:?}");
        }
        let mut g = inputs();
        g.sun_eci_unit = Vector3::new(f64::NAN, 0.0, 0.0);
        assert!(target(&modes[2], &g).is_none());
        g.sun_eci_unit = Vector3::zeros();
        assert!(target(&modes[2], &g).is_none());
        let mut g = inputs();
        g.a_ecef_from_eci[(1, 1)] = f64::NAN;
        assert!(target(&modes[3], &g).is_none());
        let nan_q = UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(f64::NAN, 0., 0., 1.));
        assert!(target(&Pointing::FixedEci(nan_q), &inputs()).is_none());
        assert!(target(&Pointing::FixedLvlh(nan_q), &inputs()).is_none());
        let zero_axis = Pointing::EciVector {
            dir_eci: Vector3::x(),
            axis_body: Vector3::zeros(),
        };
        assert!(target(&zero_axis, &inputs()).is_none());
        // FixedEci needs no orbit at all.
        let mut g = inputs();
        g.r_eci_m = Vector3::repeat(f64::NAN);
        assert!(target(&Pointing::FixedEci(UnitQuaternion::identity()), &g).is_some());
    }

    #[test]
    fn a_direction_exactly_along_the_secondary_is_degenerate() {
        let g = inputs();
        let h = g.r_eci_m.cross(&g.v_eci_m_s);
        for dir in [h, -h] {
            let p = Pointing::EciVector {
                dir_eci: dir,
                axis_body: Vector3::z(),
            };
            assert!(target(&p, &g).is_none());
        }
        // Sun along nadir: no secondary plane for sun max power.
        let mut g = inputs();
        g.sun_eci_unit = -g.r_eci_m.normalize();
        let p = Pointing::SunMaxPower {
            panel_normal_body: DEFAULT_PANEL_NORMAL_BODY,
        };
        assert!(target(&p, &g).is_none());
    }

    #[test]
    fn eci_vector_secondary_is_body_y_towards_minus_h_or_x_towards_velocity() {
        let g = inputs();
        let h_hat = g.r_eci_m.cross(&g.v_eci_m_s).normalize();
        let v_hat = g.v_eci_m_s.normalize();
        let dir = Vector3::new(0.2, -0.5, 0.9);
        let t = target(
            &Pointing::EciVector {
                dir_eci: dir,
                axis_body: Vector3::z(),
            },
            &g,
        )
        .unwrap();
        assert!((t.q_eci_from_body * Vector3::z() - dir.normalize()).norm() < 1e-12);
        let y = t.q_eci_from_body * Vector3::y();
        // Best possible: -h's component perpendicular to the pointing direction.
        let best = (1.0 - dir.normalize().dot(&h_hat).powi(2)).sqrt();
        assert!((y.dot(&-h_hat) - best).abs() < 1e-12);
        // Axis along body Y: body X towards the velocity instead.
        let t = target(
            &Pointing::EciVector {
                dir_eci: dir,
                axis_body: Vector3::y(),
            },
            &g,
        )
        .unwrap();
        assert!((t.q_eci_from_body * Vector3::y() - dir.normalize()).norm() < 1e-12);
        let x = t.q_eci_from_body * Vector3::x();
        let best = (1.0 - dir.normalize().dot(&v_hat).powi(2)).sqrt();
        assert!((x.dot(&v_hat) - best).abs() < 1e-12);
        assert!(t.axis_error_rad(&t.q_eci_from_body) < 1e-12);
    }

    #[test]
    fn advance_keeps_the_two_body_energy_and_turns_the_earth() {
        let g = inputs();
        let energy = |g: &GuidanceInputs| {
            g.v_eci_m_s.norm_squared() / 2.0 - MU_EARTH_M3_S2 / g.r_eci_m.norm()
        };
        let g1 = advance(&g, 0.5);
        // Second order in dt: |a|^2 dt^2 / 2 of 2.8e7 J/kg, 3e-7.
        assert!(((energy(&g1) - energy(&g)) / energy(&g)).abs() < 1e-6);
        // The radius follows the Taylor series: r'' = -mu/r^2 + v_t^2/r.
        let r = g.r_eci_m.norm();
        let v_t2 = g.v_eci_m_s.norm_squared();
        let r1_want = r + 0.5 * 0.25 * (v_t2 / r - MU_EARTH_M3_S2 / (r * r));
        assert!((g1.r_eci_m.norm() - r1_want).abs() < 1e-3);
        // A point on the ECEF x axis stays fixed in ECEF: in ECI it moves east by omega dt.
        let x_eci = g1.a_ecef_from_eci.tr_mul(&Vector3::x());
        assert!((x_eci.y - (OMEGA_EARTH_RAD_S * 0.5).sin()).abs() < 1e-15);
    }
}
