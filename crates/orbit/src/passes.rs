//! Ground-station geometry: azimuth, elevation and range from a geodetic site, and pass
//! prediction (rise, culmination, set above an elevation mask) over a time window.
//!
//! # Model
//! - Look angles are topocentric in the site's local ENU frame on the WGS-84 ellipsoid
//!   ([`crate::geodetic`]): elevation above the ellipsoid's tangent plane (geodetic, no
//!   refraction), azimuth from north through east in `[0, 2π)`, slant range. The satellite's
//!   position is ECEF (the same Earth-fixed frame as the site).
//! - Pass prediction scans `elevation - mask` at a coarse step ([`PassOptions::step_s`]),
//!   brackets every sign change, and also every local maximum of the samples (a pass shorter
//!   than two steps that peaks between samples is found by maximising there); rise and set
//!   are then bisected to [`PassOptions::tolerance_s`] and the culmination is found by golden
//!   section search. A pass under way at the window's start or end is clipped to the window
//!   and flagged.
//! - Positions come from any source: a closure `FnMut(UtcTime) -> Result<r_ecef_km, E>`
//!   ([`predict_passes`]) or a [`Propagator`] with optional EOP
//!   ([`predict_passes_propagator`]).
//!
//! # Invariants
//! Times are integer nanoseconds ([`UtcTime`]); the search never evaluates outside the
//! window; it allocates only the returned list of passes; the first error from the position
//! source ends the search and is returned.

use nalgebra::{Matrix3, Vector3};

use crate::frames;
use crate::geodetic::{Geodetic, a_enu_from_ecef, geodetic_to_ecef_m};
use crate::propagate::{PropagationError, Propagator, StateVector};
use crate::time::{Eop, UtcTime};

/// Azimuth, elevation and range of a target seen from a site.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LookAngles {
    /// Azimuth from north through east, rad, in `[0, 2π)`.
    pub azimuth_rad: f64,
    /// Elevation above the local horizontal plane (geodetic), rad.
    pub elevation_rad: f64,
    /// Slant range, km.
    pub range_km: f64,
}

/// A ground site on the WGS-84 ellipsoid with its ECEF position and local frame cached.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundSite {
    /// Geodetic position.
    pub geodetic: Geodetic,
    r_ecef_km: Vector3<f64>,
    a_enu_from_ecef: Matrix3<f64>,
}

impl GroundSite {
    /// A site at a geodetic position.
    pub fn new(geodetic: Geodetic) -> Self {
        GroundSite {
            geodetic,
            r_ecef_km: geodetic_to_ecef_m(&geodetic) * 1e-3,
            a_enu_from_ecef: a_enu_from_ecef(geodetic.lat_rad, geodetic.lon_rad),
        }
    }

    /// A site from latitude and longitude in degrees and height above the ellipsoid in metres.
    pub fn from_deg(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Self {
        GroundSite::new(Geodetic::from_deg(lat_deg, lon_deg, alt_m))
    }

    /// The site's ECEF position, km.
    pub fn r_ecef_km(&self) -> Vector3<f64> {
        self.r_ecef_km
    }

    /// The target's position relative to the site in local east-north-up, km.
    pub fn enu_km(&self, r_ecef_km: &Vector3<f64>) -> Vector3<f64> {
        self.a_enu_from_ecef * (r_ecef_km - self.r_ecef_km)
    }

    /// Elevation of an ECEF position, rad.
    pub fn elevation_rad(&self, r_ecef_km: &Vector3<f64>) -> f64 {
        let enu = self.enu_km(r_ecef_km);
        enu.z.atan2(enu.x.hypot(enu.y))
    }

    /// Azimuth, elevation and range of an ECEF position (km).
    pub fn look_angles(&self, r_ecef_km: &Vector3<f64>) -> LookAngles {
        let enu = self.enu_km(r_ecef_km);
        let horizontal = enu.x.hypot(enu.y);
        LookAngles {
            azimuth_rad: enu.x.atan2(enu.y).rem_euclid(std::f64::consts::TAU),
            elevation_rad: enu.z.atan2(horizontal),
            range_km: enu.norm(),
        }
    }

    /// Range rate (km/s, positive when receding) of an ECEF state (velocity relative to the
    /// rotating Earth).
    pub fn range_rate_km_s(&self, state_ecef: &StateVector) -> f64 {
        let los = state_ecef.r_km - self.r_ecef_km;
        los.dot(&state_ecef.v_km_s) / los.norm()
    }
}

/// How passes are searched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassOptions {
    /// Elevation mask, rad: a pass is the time above it.
    pub mask_rad: f64,
    /// Coarse scan step, s (20 s suits LEO; shorter passes are still found when their peak
    /// lies between samples).
    pub step_s: f64,
    /// Accuracy of rise, set and culmination times, s.
    pub tolerance_s: f64,
}

impl Default for PassOptions {
    fn default() -> Self {
        PassOptions {
            mask_rad: 0.0,
            step_s: 20.0,
            tolerance_s: 1e-3,
        }
    }
}

/// One pass over a site.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pass {
    /// Rise above the mask (the window's start if `rise_clipped`).
    pub rise: UtcTime,
    /// Maximum elevation.
    pub culmination: UtcTime,
    /// Set below the mask (the window's end if `set_clipped`).
    pub set: UtcTime,
    /// Elevation at culmination, rad.
    pub max_elevation_rad: f64,
    /// Azimuth at rise, rad.
    pub rise_azimuth_rad: f64,
    /// Azimuth at set, rad.
    pub set_azimuth_rad: f64,
    /// The satellite was already above the mask at the window's start.
    pub rise_clipped: bool,
    /// The satellite was still above the mask at the window's end.
    pub set_clipped: bool,
}

impl Pass {
    /// Duration above the mask, s.
    pub fn duration_s(&self) -> f64 {
        self.set.seconds_since(self.rise)
    }
}

/// Elevation minus mask at a time, through the position source.
struct Scanner<'a, F> {
    site: &'a GroundSite,
    mask_rad: f64,
    position: F,
}

impl<F, E> Scanner<'_, F>
where
    F: FnMut(UtcTime) -> Result<Vector3<f64>, E>,
{
    fn f(&mut self, t: UtcTime) -> Result<f64, E> {
        let r = (self.position)(t)?;
        Ok(self.site.elevation_rad(&r) - self.mask_rad)
    }

    /// The crossing in `(lo, hi]` where f changes sign (f(lo) and f(hi) of opposite signs),
    /// bisected to `tol_ns`; returns the first time with f >= 0 for a rise, f < 0 for a set.
    fn crossing(&mut self, mut lo: i64, mut hi: i64, rising: bool, tol_ns: i64) -> Result<i64, E> {
        while hi - lo > tol_ns {
            let mid = lo + (hi - lo) / 2;
            let above = self.f(UtcTime::from_unix_ns(mid))? >= 0.0;
            if above == rising {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Ok(hi)
    }

    /// The time of maximum f in `[lo, hi]` by golden section search, and the maximum.
    fn maximum(&mut self, mut lo: i64, mut hi: i64, tol_ns: i64) -> Result<(i64, f64), E> {
        const INV_PHI: f64 = 0.618_033_988_749_894_8; // (sqrt(5) - 1) / 2
        let split = |lo: i64, hi: i64| ((hi - lo) as f64 * INV_PHI).round() as i64;
        let mut a = hi - split(lo, hi);
        let mut b = lo + split(lo, hi);
        let mut fa = self.f(UtcTime::from_unix_ns(a))?;
        let mut fb = self.f(UtcTime::from_unix_ns(b))?;
        while hi - lo > tol_ns && b > a {
            if fa < fb {
                lo = a;
                a = b;
                fa = fb;
                b = lo + split(lo, hi);
                fb = self.f(UtcTime::from_unix_ns(b))?;
            } else {
                hi = b;
                b = a;
                fb = fa;
                a = hi - split(lo, hi);
                fa = self.f(UtcTime::from_unix_ns(a))?;
            }
        }
        let mut best = if fa >= fb { (a, fa) } else { (b, fb) };
        for t in [lo, hi] {
            let ft = self.f(UtcTime::from_unix_ns(t))?;
            if ft > best.1 {
                best = (t, ft);
            }
        }
        Ok(best)
    }
}

/// Passes of a satellite over `site` between `start` and `end`, with positions (ECEF, km)
/// from `r_ecef_km_at`.
pub fn predict_passes<F, E>(
    site: &GroundSite,
    start: UtcTime,
    end: UtcTime,
    options: &PassOptions,
    r_ecef_km_at: F,
) -> Result<Vec<Pass>, E>
where
    F: FnMut(UtcTime) -> Result<Vector3<f64>, E>,
{
    let mut passes = Vec::new();
    let (t0, t1) = (start.unix_ns(), end.unix_ns());
    if t1 <= t0 {
        return Ok(passes);
    }
    let step_ns = ((options.step_s.max(1e-3)) * 1e9).round() as i64;
    let tol_ns = ((options.tolerance_s.max(1e-9)) * 1e9).round().max(1.0) as i64;
    let mut s = Scanner {
        site,
        mask_rad: options.mask_rad,
        position: r_ecef_km_at,
    };
    let mut rise: Option<(i64, bool)> = None; // (time, clipped)
    let finish = |s: &mut Scanner<'_, F>,
                  rise_ns: i64,
                  rise_clipped: bool,
                  set_ns: i64,
                  set_clipped: bool,
                  passes: &mut Vec<Pass>|
     -> Result<(), E> {
        let (tc, _) = s.maximum(rise_ns, set_ns, tol_ns)?;
        let look = |s: &mut Scanner<'_, F>, t: i64| -> Result<LookAngles, E> {
            let r = (s.position)(UtcTime::from_unix_ns(t))?;
            Ok(s.site.look_angles(&r))
        };
        let at_rise = look(s, rise_ns)?;
        let at_set = look(s, set_ns)?;
        let at_max = look(s, tc)?;
        passes.push(Pass {
            rise: UtcTime::from_unix_ns(rise_ns),
            culmination: UtcTime::from_unix_ns(tc),
            set: UtcTime::from_unix_ns(set_ns),
            max_elevation_rad: at_max.elevation_rad,
            rise_azimuth_rad: at_rise.azimuth_rad,
            set_azimuth_rad: at_set.azimuth_rad,
            rise_clipped,
            set_clipped,
        });
        Ok(())
    };

    let mut prev_t = t0;
    let mut prev_f = s.f(start)?;
    if prev_f >= 0.0 {
        rise = Some((t0, true));
    }
    // The sample before `prev` (for local maxima below the mask).
    let mut before: Option<(i64, f64)> = None;
    loop {
        let t = (prev_t.saturating_add(step_ns)).min(t1);
        let f = s.f(UtcTime::from_unix_ns(t))?;
        if prev_f < 0.0 && f >= 0.0 {
            rise = Some((s.crossing(prev_t, t, true, tol_ns)?, false));
        } else if prev_f >= 0.0 && f < 0.0 {
            let set_ns = s.crossing(prev_t, t, false, tol_ns)?;
            if let Some((r, clipped)) = rise.take() {
                finish(&mut s, r, clipped, set_ns, false, &mut passes)?;
            }
        } else if let Some((tb, fb)) = before {
            // A peak below the mask at the middle sample may hide a short pass.
            if fb < prev_f && prev_f >= f && prev_f < 0.0 && f < 0.0 {
                let (tm, fm) = s.maximum(tb, t, tol_ns)?;
                if fm >= 0.0 {
                    let r = s.crossing(tb, tm, true, tol_ns)?;
                    let st = s.crossing(tm, t, false, tol_ns)?;
                    finish(&mut s, r, false, st, false, &mut passes)?;
                }
            }
        }
        before = Some((prev_t, prev_f));
        prev_t = t;
        prev_f = f;
        if t >= t1 {
            break;
        }
    }
    if let Some((r, clipped)) = rise {
        if prev_f >= 0.0 {
            finish(&mut s, r, clipped, t1, true, &mut passes)?;
        }
    }
    passes.sort_by_key(|p| p.rise);
    Ok(passes)
}

/// Passes over `site` for any [`Propagator`] (ECI J2000 -> ECEF with `eop`, UT1 = UTC and no
/// polar motion without it).
pub fn predict_passes_propagator(
    site: &GroundSite,
    start: UtcTime,
    end: UtcTime,
    options: &PassOptions,
    propagator: &mut dyn Propagator,
    eop: Option<&Eop>,
) -> Result<Vec<Pass>, PropagationError> {
    predict_passes(site, start, end, options, |t| {
        let s = propagator.state_j2000(t)?;
        Ok(frames::a_ecef_from_eci(t, eop) * s.r_km)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_angles_of_simple_geometry() {
        let site = GroundSite::from_deg(0.0, 0.0, 0.0);
        // Straight up.
        let up = site.look_angles(&Vector3::new(7000.0, 0.0, 0.0));
        assert!((up.elevation_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((up.range_km - (7000.0 - 6378.137)).abs() < 1e-9);
        // Due north on the horizon plane: azimuth 0; due east: 90 deg.
        let north = site.look_angles(&Vector3::new(6378.137, 0.0, 1000.0));
        assert!(north.azimuth_rad.abs() < 1e-12 && north.elevation_rad.abs() < 1e-12);
        let east = site.look_angles(&Vector3::new(6378.137, 1000.0, 0.0));
        assert!((east.azimuth_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let west = site.look_angles(&Vector3::new(6378.137, -1000.0, -1e-9));
        assert!((west.azimuth_rad - 1.5 * std::f64::consts::PI).abs() < 1e-9);
    }

    /// A target circling the site's zenith: elevation `e(t) = sin(2π t / period)` rad.
    fn synthetic(
        site: GroundSite,
        t0: UtcTime,
        period_s: f64,
    ) -> impl FnMut(UtcTime) -> Result<Vector3<f64>, ()> {
        let a = a_enu_from_ecef(site.geodetic.lat_rad, site.geodetic.lon_rad).transpose();
        move |t: UtcTime| {
            let x = t.seconds_since(t0) / period_s * std::f64::consts::TAU;
            let el = 0.5 * x.sin();
            let enu = Vector3::new(0.0, el.cos(), el.sin()) * 1000.0;
            Ok(site.r_ecef_km() + a * enu)
        }
    }

    #[test]
    fn finds_clipped_and_short_passes() {
        let site = GroundSite::from_deg(54.0, 25.0, 0.0);
        let t0 = UtcTime::from_unix_ns(0);
        let end = t0.plus_seconds(3000.0);
        // Elevation 0.5 sin(2π t / 1000): above 0 for t in (0, 500), (1000, 1500), ...
        let passes = predict_passes(
            &site,
            t0.plus_seconds(100.0),
            end,
            &PassOptions::default(),
            synthetic(site, t0, 1000.0),
        )
        .unwrap_or_default();
        assert_eq!(passes.len(), 3);
        assert!(passes[0].rise_clipped && !passes[0].set_clipped);
        assert!((passes[0].set.seconds_since(t0) - 500.0).abs() < 2e-3);
        assert!((passes[1].rise.seconds_since(t0) - 1000.0).abs() < 2e-3);
        assert!((passes[1].culmination.seconds_since(t0) - 1250.0).abs() < 0.1);
        assert!((passes[1].max_elevation_rad - 0.5).abs() < 1e-9);
        // A mask of 0.499 rad leaves passes of 1000 acos(0.998) / π = 20 s, a third of the
        // 60 s step: most fall between samples and are found at the sampled maxima.
        let opts = PassOptions {
            mask_rad: 0.499,
            step_s: 60.0,
            ..PassOptions::default()
        };
        let passes =
            predict_passes(&site, t0, end, &opts, synthetic(site, t0, 1000.0)).unwrap_or_default();
        assert_eq!(passes.len(), 3, "{passes:?}");
        assert!(passes.iter().all(|p| {
            (p.duration_s() - 1000.0 * (0.998f64).acos() / std::f64::consts::PI).abs() < 0.01
        }));
        // An error from the source is returned.
        let r: Result<Vec<Pass>, &str> = predict_passes(&site, t0, end, &opts, |_| Err("no"));
        assert_eq!(r, Err("no"));
    }
}
