//! Thruster burns on the true orbit: the ECU posts [`Burn`]s on a [`BurnBoard`] (through the
//! twin's wiring), and the FC, which owns the truth, applies them at its ticks.
//!
//! # Model
//! A burn pushes with `thrust_n` along `q_eci_from_body * dir_body` from `start_ns` to
//! `end_ns` on a spacecraft whose mass falls as `m(t) = mass_kg - mass_flow_kg_s (t -
//! start)`. Over an interval `[t1, t2)` inside the burn the velocity change is the rocket
//! equation's `F / mdot ln(m(t1) / m(t2))` (`F / m dt` without mass flow). The integration
//! is a train of impulses: the burn's part in each call's interval is cut into pieces of at
//! most [`MAX_IMPULSE_SPACING_NS`] (1 s), and each piece's exact velocity change is added at
//! its midpoint ([`EnvModel::apply_delta_v`]). For a constant acceleration the midpoint
//! impulse gives the exact velocity and position at the piece's end; the rest (gravity
//! changing over a piece) is of order `g dv dt^2 / r`, micrometres. At the FC's 10 Hz that is
//! one impulse per tick.
//!
//! The first impulse switches the truth from SGP4 to Cowell from SGP4's exact J2000 state at
//! that instant ([`EnvModel::switch_to_numerical`]); from then on the truth's position and
//! velocity (and so GPS, the environment, the published snapshots) are numerical.
//!
//! The thrust direction is the attitude passed in (the truth at the tick) for the whole
//! interval: at 10 Hz that is 0.1 s of attitude motion; under ADCS control the attitude is
//! held during a burn.
//!
//! # Timing ([`apply`])
//! At a tick at `now`, the FC applies the burns posted strictly before `now`
//! ([`BurnBoard::pending`]) over `[applied_until, now)`, then evaluates the environment at
//! `now`. So every state the FC computes at or after `now` includes all thrust before `now`;
//! the part of a burn between its start and the FC's first tick after it is applied at that
//! tick (late by at most one tick, with its effect on the state exact); a burn cut short
//! (SAFE, power loss) is never over-applied, since its new end is known before any tick
//! past it (the ECU keeps the burn's `posted_ns` when it re-posts a cut). The order of the
//! FC's and the ECU's tasks at one instant does not matter. Impulses never precede the
//! Cowell anchor, since `applied_until` only grows.
//!
//! # Drag after the switch
//! [`cowell_config_for`] derives the ballistic coefficient from the TLE's B*
//! (`Cd A / m = 12.741621 B*`, B* per Earth radius: Vallado, *Fundamentals of Astrodynamics
//! and Applications*, 4th ed. 2013, section 9.6 "BC = 1 / (12.741621 B*)"), so that the
//! numerical truth keeps roughly the decay SGP4 had.

use nalgebra::{UnitQuaternion, Vector3};
use orbit::cowell::{CowellConfig, Drag};
use orbit::tle::Tle;
use platform::SimTime;
use platform::board::{Burn, BurnBoard};

use crate::environment::{DeltaVError, EnvModel};

/// Longest interval applied as one impulse, ns.
pub const MAX_IMPULSE_SPACING_NS: u64 = 1_000_000_000;

/// `Cd A / m` (m^2/kg) per unit B* (1/Earth radius) (Vallado 2013, section 9.6).
pub const CD_AREA_OVER_MASS_PER_BSTAR: f64 = 12.741_621;

/// What one [`apply`] call did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Applied {
    /// Impulses added to the truth orbit.
    pub impulses: u32,
    /// Their sum, ECI J2000, m/s.
    pub dv_eci_m_s: Vector3<f64>,
    /// Burns ignored because their figures are unusable (not finite, no mass, ...).
    pub rejected: u32,
    /// Whether this call switched the truth from SGP4 to numerical propagation.
    pub switched: bool,
}

/// Whether a burn's figures can be integrated: finite, thrust and mass flow >= 0, positive
/// mass until its end, a non-zero direction, and an end not before its start.
pub fn is_valid(b: &Burn) -> bool {
    let dur_s = b.end.as_ns().saturating_sub(b.start.as_ns()) as f64 * 1e-9;
    let finite = [b.thrust_n, b.mass_flow_kg_s, b.mass_kg]
        .iter()
        .chain(b.dir_body.iter())
        .all(|x| x.is_finite());
    finite
        && b.thrust_n >= 0.0
        && b.mass_flow_kg_s >= 0.0
        && b.mass_kg > 0.0
        && b.end.as_ns() >= b.start.as_ns()
        && b.mass_kg - b.mass_flow_kg_s * dur_s > 0.0
        && b.dir_body.norm() > 0.0
}

/// The speed the burn adds over `[from_ns, to_ns)` (clipped to the burn), m/s: the rocket
/// equation on the burn's mass; 0 for an invalid burn or an empty interval.
pub fn delta_v_m_s(b: &Burn, from_ns: u64, to_ns: u64) -> f64 {
    let (lo, hi) = (from_ns.max(b.start.as_ns()), to_ns.min(b.end.as_ns()));
    if hi <= lo || !is_valid(b) {
        return 0.0;
    }
    let t = |ns: u64| (ns - b.start.as_ns()) as f64 * 1e-9;
    let m1 = b.mass_kg - b.mass_flow_kg_s * t(lo);
    let m2 = b.mass_kg - b.mass_flow_kg_s * t(hi);
    if b.mass_flow_kg_s > 0.0 {
        b.thrust_n / b.mass_flow_kg_s * (m1 / m2).ln()
    } else {
        b.thrust_n / m1 * (t(hi) - t(lo))
    }
}

/// The impulses that stand for `burns` over `[from_ns, to_ns)` with the attitude
/// `q_eci_from_body`: (simulated time ns, ECI J2000 delta-v m/s), in time order (see the
/// module doc). Invalid burns are left out.
pub fn impulses(
    burns: &[Burn],
    q_eci_from_body: &UnitQuaternion<f64>,
    from_ns: u64,
    to_ns: u64,
) -> Vec<(u64, Vector3<f64>)> {
    let mut out = Vec::new();
    for b in burns.iter().filter(|b| is_valid(b)) {
        let (lo, hi) = (from_ns.max(b.start.as_ns()), to_ns.min(b.end.as_ns()));
        if hi <= lo {
            continue;
        }
        let dir_eci = q_eci_from_body * b.dir_body.normalize();
        let span = hi - lo;
        let n = span.div_ceil(MAX_IMPULSE_SPACING_NS);
        for k in 0..n {
            // Even pieces in integer ns (u128: no overflow for any span).
            let at = |j: u64| lo + (u128::from(span) * u128::from(j) / u128::from(n)) as u64;
            let (p_lo, p_hi) = (at(k), at(k + 1));
            let dv = delta_v_m_s(b, p_lo, p_hi);
            if dv > 0.0 {
                out.push((p_lo + (p_hi - p_lo) / 2, dir_eci * dv));
            }
        }
    }
    out.sort_by_key(|(t, _)| *t);
    out
}

/// Apply the thrust of the burns on `board` to the true orbit up to the tick at `now_ns`.
///
/// Takes the burns posted strictly before `now_ns` that have not ended by
/// `*applied_until_ns`, integrates their thrust over `[*applied_until_ns, now_ns)` as
/// impulses ([`impulses`]) with the attitude `q_eci_from_body`, and sets
/// `*applied_until_ns = now_ns`. `unix_ns_at_now` is the UTC of `now_ns` (the truth's
/// clock); a simulated instant `t` maps to `unix_ns_at_now - (now_ns - t)`. Call it at every
/// tick **before** evaluating the orbit at `now_ns`, whether the flight software runs or
/// not (the truth's own bookkeeping). A time at or before `*applied_until_ns` does nothing.
///
/// Errors: the orbit cannot be propagated to an impulse (decay, or an impulse before the
/// last one, which this function never produces); `*applied_until_ns` still advances, so a
/// broken orbit is reported once per tick at most, never retried over the same interval.
pub fn apply(
    model: &mut EnvModel,
    board: &BurnBoard,
    q_eci_from_body: &UnitQuaternion<f64>,
    now_ns: u64,
    unix_ns_at_now: i64,
    applied_until_ns: &mut u64,
) -> Result<Applied, DeltaVError> {
    let from_ns = *applied_until_ns;
    if now_ns <= from_ns {
        return Ok(Applied::default());
    }
    *applied_until_ns = now_ns;
    let burns = board.pending(SimTime::from_ns(now_ns), SimTime::from_ns(from_ns));
    let mut applied = Applied {
        rejected: burns.iter().filter(|b| !is_valid(b)).count() as u32,
        ..Applied::default()
    };
    let was_numerical = model.is_numerical();
    for (t_ns, dv) in impulses(&burns, q_eci_from_body, from_ns, now_ns) {
        let unix_ns = unix_ns_at_now - (now_ns - t_ns) as i64;
        model.apply_delta_v(unix_ns, dv)?;
        applied.impulses += 1;
        applied.dv_eci_m_s += dv;
    }
    applied.switched = !was_numerical && model.is_numerical();
    Ok(applied)
}

/// The numerical truth's force model for a TLE: `orbit`'s default (10 s RK4 steps, J2) and
/// drag with the ballistic coefficient of the TLE's B* (none when B* <= 0).
pub fn cowell_config_for(tle: &Tle) -> CowellConfig {
    let b = tle.bstar_per_earth_radii;
    CowellConfig {
        drag: (b.is_finite() && b > 0.0).then_some(Drag {
            cd_area_over_mass_m2_kg: CD_AREA_OVER_MASS_PER_BSTAR * b,
        }),
        ..CowellConfig::default()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn burn() -> Burn {
        Burn {
            posted: SimTime::from_ns(0),
            start: SimTime::from_ns(1_000_000_000),
            end: SimTime::from_ns(11_000_000_000),
            thrust_n: 0.3,
            mass_flow_kg_s: 0.3 / (200.0 * 9.806_65),
            mass_kg: 12.5,
            dir_body: Vector3::z(),
        }
    }

    #[test]
    fn rocket_equation_over_pieces_adds_up() {
        let b = burn();
        let whole = delta_v_m_s(&b, 0, u64::MAX);
        let m_end = 12.5 - b.mass_flow_kg_s * 10.0;
        let want = 200.0 * 9.806_65 * (12.5 / m_end).ln();
        assert!((whole - want).abs() < 1e-12, "{whole} vs {want}");
        assert!((whole - 0.24).abs() < 1e-4, "about F t / m: {whole}");
        let parts: f64 = (0..7)
            .map(|k| delta_v_m_s(&b, k * 1_700_000_000, (k + 1) * 1_700_000_000))
            .sum();
        assert!((parts - whole).abs() < 1e-12);
        assert_eq!(delta_v_m_s(&b, 11_000_000_000, 20_000_000_000), 0.0);
        let no_flow = Burn {
            mass_flow_kg_s: 0.0,
            ..b
        };
        assert!((delta_v_m_s(&no_flow, 0, u64::MAX) - 0.24).abs() < 1e-12);
    }

    #[test]
    fn impulses_are_at_most_a_second_apart_along_the_attitude() {
        let b = burn();
        let q = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
        let imp = impulses(&[b], &q, 0, 20_000_000_000);
        assert_eq!(imp.len(), 10);
        assert_eq!(imp[0].0, 1_500_000_000);
        assert_eq!(imp[9].0, 10_500_000_000);
        // Body +Z rotated 90 deg about X is -Y in ECI.
        for (_, dv) in &imp {
            assert!(dv.x.abs() < 1e-15 && dv.z.abs() < 1e-15 && dv.y < 0.0);
        }
        let total: f64 = imp.iter().map(|(_, d)| d.norm()).sum();
        assert!((total - delta_v_m_s(&b, 0, u64::MAX)).abs() < 1e-12);
        // A tick's worth: one impulse at the middle of the part inside the burn.
        let one = impulses(&[b], &q, 10_950_000_000, 11_050_000_000);
        assert_eq!(one.len(), 1);
        assert_eq!(one[0].0, 10_975_000_000);
    }

    #[test]
    fn invalid_burns_are_rejected() {
        let b = burn();
        for bad in [
            Burn {
                thrust_n: f64::NAN,
                ..b
            },
            Burn { mass_kg: 0.0, ..b },
            Burn {
                mass_flow_kg_s: 2.0,
                ..b
            },
            Burn {
                dir_body: Vector3::zeros(),
                ..b
            },
            Burn {
                end: SimTime::from_ns(0),
                ..b
            },
        ] {
            assert!(!is_valid(&bad), "{bad:?}");
            assert_eq!(delta_v_m_s(&bad, 0, u64::MAX), 0.0);
            assert!(impulses(&[bad], &UnitQuaternion::identity(), 0, u64::MAX).is_empty());
        }
    }
}
