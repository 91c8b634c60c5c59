//! Earth shadow: conical umbra and penumbra with the visible fraction of the solar disk
//! (Montenbruck & Gill, *Satellite Orbits*, 2000, section 3.4.2).
//!
//! Model: the Sun and the Earth are spheres (radii [`SUN_RADIUS_KM`] and
//! [`EARTH_RADIUS_KM`], the WGS-84 equatorial radius). Seen from the satellite the Sun's disk
//! has apparent radius `a = asin(R_sun / |r_sun - r|)`, the Earth's `b = asin(R_E / |r|)`,
//! and their centres are `c` apart. Then:
//! - `c >= a + b`: [`ShadowState::Sunlit`], visible fraction 1;
//! - `c < b - a`: [`ShadowState::Umbra`], fraction 0;
//! - `c < a - b` (an annular eclipse, impossible below about 1.4 million km):
//!   [`ShadowState::Penumbra`], fraction `1 - b^2 / a^2`;
//! - otherwise [`ShadowState::Penumbra`], fraction `1 - A / (pi a^2)` with `A` the area of
//!   overlap of two flat disks of radii `a` and `b` at distance `c` (M&G eq. 3.87-3.92).
//!
//! The flat-disk overlap is M&G's approximation; the exact spherical geometry differs by at
//! most 2.3e-4 in the fraction on the reference set (`tests/data/eclipse.csv`). A position on
//! or inside the Earth's sphere is reported as umbra. Positions are in any frame centred on
//! the Earth (ECI J2000 in the twin), in km. No allocation.

use nalgebra::Vector3;

pub use crate::sun::SUN_RADIUS_KM;
use crate::sun::sun_eci_km;
use crate::time::UtcTime;

/// The Earth's radius for the shadow, km (WGS-84 equatorial radius, NIMA TR8350.2).
pub const EARTH_RADIUS_KM: f64 = 6378.137;

/// Where the satellite is with respect to the Earth's shadow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ShadowState {
    /// The whole solar disk is visible.
    Sunlit,
    /// Part of the solar disk is visible (partial or annular eclipse).
    Penumbra,
    /// No part of the solar disk is visible.
    Umbra,
}

/// The shadow state and the visible fraction of the solar disk at a position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Illumination {
    /// Umbra, penumbra or sunlit.
    pub state: ShadowState,
    /// Visible fraction of the solar disk's area, 0 (umbra) to 1 (sunlit).
    pub visible_fraction: f64,
}

impl Illumination {
    /// Full Sun.
    pub const SUNLIT: Illumination = Illumination {
        state: ShadowState::Sunlit,
        visible_fraction: 1.0,
    };
    /// No Sun.
    pub const UMBRA: Illumination = Illumination {
        state: ShadowState::Umbra,
        visible_fraction: 0.0,
    };
}

/// Classify the satellite at `r_sat_km` given the Sun at `r_sun_km` (both from the Earth's
/// centre, same frame) with the conical model of Montenbruck & Gill 3.4.2.
pub fn illumination(r_sat_km: &Vector3<f64>, r_sun_km: &Vector3<f64>) -> Illumination {
    illumination_with_radii(r_sat_km, r_sun_km, EARTH_RADIUS_KM, SUN_RADIUS_KM)
}

/// Classify the satellite at the ECI J2000 position `r_sat_eci_km` at the UTC instant `t`,
/// with the Sun from [`crate::sun::sun_eci_km`].
pub fn illumination_at(t: UtcTime, r_sat_eci_km: &Vector3<f64>) -> Illumination {
    illumination(r_sat_eci_km, &sun_eci_km(t))
}

/// As [`illumination`], with explicit occulting-body and Sun radii, km.
pub fn illumination_with_radii(
    r_sat_km: &Vector3<f64>,
    r_sun_km: &Vector3<f64>,
    earth_radius_km: f64,
    sun_radius_km: f64,
) -> Illumination {
    let r_norm = r_sat_km.norm();
    if r_norm <= earth_radius_km {
        return Illumination::UMBRA;
    }
    let to_sun = r_sun_km - r_sat_km;
    let to_sun_norm = to_sun.norm();
    let a = (sun_radius_km / to_sun_norm).min(1.0).asin();
    let b = (earth_radius_km / r_norm).asin();
    // Angle between the directions to the Earth's centre (-r) and to the Sun; atan2 keeps
    // full precision near 0 and pi, where acos would not.
    let to_earth = -r_sat_km;
    let c = to_earth.cross(&to_sun).norm().atan2(to_earth.dot(&to_sun));

    if c >= a + b {
        Illumination::SUNLIT
    } else if c < b - a {
        Illumination::UMBRA
    } else if c < a - b {
        Illumination {
            state: ShadowState::Penumbra,
            visible_fraction: 1.0 - (b * b) / (a * a),
        }
    } else {
        // Overlap of two disks of radii a (Sun) and b (Earth) at distance c (M&G 3.4.2).
        let x = (c * c + a * a - b * b) / (2.0 * c);
        let y = (a * a - x * x).max(0.0).sqrt();
        let area = a * a * (x / a).clamp(-1.0, 1.0).acos()
            + b * b * ((c - x) / b).clamp(-1.0, 1.0).acos()
            - c * y;
        let visible_fraction = (1.0 - area / (std::f64::consts::PI * a * a)).clamp(0.0, 1.0);
        Illumination {
            state: ShadowState::Penumbra,
            visible_fraction,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn behind_the_earth_is_umbra_and_in_front_is_sunlit() {
        let sun = Vector3::new(1.496e8, 0.0, 0.0);
        assert_eq!(
            illumination(&Vector3::new(-7000.0, 0.0, 0.0), &sun),
            Illumination::UMBRA
        );
        assert_eq!(
            illumination(&Vector3::new(7000.0, 0.0, 0.0), &sun),
            Illumination::SUNLIT
        );
        assert_eq!(
            illumination(&Vector3::new(0.0, 7000.0, 0.0), &sun),
            Illumination::SUNLIT
        );
    }

    #[test]
    fn at_the_june_solstice_the_north_pole_side_is_lit() {
        let t = UtcTime::from_iso8601("2025-06-21T02:42:00Z").expect("ISO-8601");
        let over_north_pole = Vector3::new(0.0, 0.0, 7000.0);
        let over_south_pole = Vector3::new(0.0, 0.0, -6600.0);
        assert_eq!(illumination_at(t, &over_north_pole), Illumination::SUNLIT);
        // Over the south pole the Sun is 66.6 deg from the Earth's centre; at 6600 km the
        // Earth's disk has a radius of 75 deg and hides it.
        assert_eq!(
            illumination_at(t, &over_south_pole).state,
            ShadowState::Umbra
        );
    }

    #[test]
    fn inside_the_earth_is_umbra_not_nan() {
        let sun = Vector3::new(1.496e8, 0.0, 0.0);
        assert_eq!(illumination(&Vector3::zeros(), &sun), Illumination::UMBRA);
        assert_eq!(
            illumination(&Vector3::new(100.0, 0.0, 0.0), &sun),
            Illumination::UMBRA
        );
    }

    #[test]
    fn far_beyond_the_umbra_cone_is_annular() {
        // The umbra cone ends about 1.38 million km behind the Earth; beyond it, the Earth
        // covers only the middle of the solar disk.
        let sun = Vector3::new(1.496e8, 0.0, 0.0);
        let ill = illumination(&Vector3::new(-3.0e6, 0.0, 0.0), &sun);
        assert_eq!(ill.state, ShadowState::Penumbra);
        let a = (SUN_RADIUS_KM / (1.496e8 + 3.0e6)).asin();
        let b = (EARTH_RADIUS_KM / 3.0e6).asin();
        assert!((ill.visible_fraction - (1.0 - b * b / (a * a))).abs() < 1e-15);
        assert!(ill.visible_fraction > 0.0 && ill.visible_fraction < 1.0);
    }
}
