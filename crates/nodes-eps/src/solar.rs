//! Solar arrays: flat panels fixed in the body frame (BCF, ICD 1.4), each with an outward
//! normal, an area, a packing factor and a cell efficiency.
//!
//! # Model
//! Power of one panel, W:
//! `S * A * pf * eta * max(0, n . s_body) * f_vis`, with `S` the solar constant
//! ([`SOLAR_CONSTANT_W_M2`]), `A` the panel area, `pf` the fraction of it covered by cells,
//! `eta` the cell efficiency at the maximum power point, `n` the panel's unit normal and
//! `s_body` the unit sun direction in the body frame (`q_eci_from_body^-1 * sun_eci_unit`
//! of the FC's truth), `f_vis` the visible fraction of the solar disc (1 sunlit, 0 umbra,
//! between in penumbra: crates/orbit's eclipse model through the truth snapshot).
//!
//! Left out, on purpose: Earth albedo and Earth infrared (a few percent of orbit-average
//! power on body panels, zero on sun-pointed wings), the +-3.3 % yearly change of the flux
//! with the Earth-Sun distance (the truth carries a unit sun vector only), cell
//! temperature, the cosine law's departure near grazing incidence, shadowing of one panel
//! by another (the wings do not shade the body panels in the default geometry), MPPT
//! conversion loss (folded into the battery charge efficiency) and degradation.
//!
//! # Default geometry (a 6U with two deployable wings)
//! ICD 1.4's BCF: X "up" along the 200 mm edge, Z "forward" along the 300 mm edge (the
//! propulsion exhaust face is -Z), Y completes: the body is 0.2 (X) x 0.1 (Y) x 0.3 (Z) m.
//! - +X body face, 0.1 x 0.3 m = 0.030 m^2, cells.
//! - Two wings, hinged on the +X face's long edges and deployed flat beside it, each two
//!   3U-size panels (0.1 x 0.3 m), cells on the sun side only, normal +X: 0.060 m^2 each.
//!   With the +X face that is 0.150 m^2 facing +X, the sun max power panel normal
//!   (nodes-fc `DEFAULT_PANEL_NORMAL_BODY`).
//! - -X face 0.1 x 0.3 m (0.030 m^2); +Y and -Y faces 0.2 x 0.3 m (0.060 m^2 each): body
//!   cells.
//! - +Z (the nadir face in nadir pointing: payload apertures, antennas) and -Z (thruster
//!   exhaust) carry no cells.
//!
//! Cells: triple-junction GaAs, 29.5 % at beginning of life (Azur Space 3G30C, 28 C, AM0);
//! packing factor 0.85 on body faces (cut-outs for sun sensors, antennas, hinges) and 0.90
//! on the wings. Full sun on +X gives 53.6 W; the same flux on a +-Y face 20.5 W.

use nalgebra::{UnitQuaternion, Vector3};

/// Solar constant at 1 AU, W/m^2 (Kopp & Lean 2011, TSI at solar minimum: 1360.8).
pub const SOLAR_CONSTANT_W_M2: f64 = 1361.0;
/// Triple-junction GaAs efficiency, beginning of life (Azur Space 3G30C datasheet: 29.5 %).
pub const CELL_EFFICIENCY: f64 = 0.295;
/// Packing factor of a body face (cut-outs for sensors, antennas and hinges).
pub const BODY_PACKING_FACTOR: f64 = 0.85;
/// Packing factor of a deployable wing panel (cells only).
pub const WING_PACKING_FACTOR: f64 = 0.90;
/// At most this many panels (the telemetry's fixed slots).
pub use icd::eps::MAX_PANELS;

/// One flat panel fixed in the body frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    /// A short name for logs and tables (`+X`, `wing+Y`, ...).
    pub name: String,
    /// Outward normal (the cell side), body frame; normalised when used.
    pub normal_body: Vector3<f64>,
    /// Panel area, m^2.
    pub area_m2: f64,
    /// Fraction of the area covered by cells, 0..=1.
    pub packing_factor: f64,
    /// Cell efficiency at the maximum power point, 0..=1.
    pub efficiency: f64,
}

impl Panel {
    /// A panel of `area_m2` with normal `normal_body` and the default cells.
    pub fn new(name: &str, normal_body: Vector3<f64>, area_m2: f64, packing_factor: f64) -> Self {
        Panel {
            name: name.to_owned(),
            normal_body,
            area_m2,
            packing_factor,
            efficiency: CELL_EFFICIENCY,
        }
    }

    /// Power at normal incidence in full sun, W.
    pub fn peak_w(&self, solar_constant_w_m2: f64) -> f64 {
        solar_constant_w_m2 * self.area_m2 * self.packing_factor * self.efficiency
    }

    /// Power for the unit sun direction `sun_body_unit` and visible fraction `visible`, W.
    pub fn power_w(
        &self,
        solar_constant_w_m2: f64,
        sun_body_unit: &Vector3<f64>,
        visible: f64,
    ) -> f64 {
        let n = self
            .normal_body
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::zeros);
        let cos_incidence = n.dot(sun_body_unit).max(0.0);
        self.peak_w(solar_constant_w_m2) * cos_incidence * visible.clamp(0.0, 1.0)
    }
}

/// The solar arrays: every panel and the flux.
#[derive(Debug, Clone, PartialEq)]
pub struct SolarArray {
    /// Panels (at most [`MAX_PANELS`] are used).
    pub panels: Vec<Panel>,
    /// Solar flux, W/m^2.
    pub solar_constant_w_m2: f64,
}

impl Default for SolarArray {
    /// The 6U with two deployable wings of the module doc.
    fn default() -> Self {
        let x = Vector3::x();
        let y = Vector3::y();
        SolarArray {
            panels: vec![
                Panel::new("+X", x, 0.1 * 0.3, BODY_PACKING_FACTOR),
                Panel::new("wing+Y", x, 2.0 * 0.1 * 0.3, WING_PACKING_FACTOR),
                Panel::new("wing-Y", x, 2.0 * 0.1 * 0.3, WING_PACKING_FACTOR),
                Panel::new("-X", -x, 0.1 * 0.3, BODY_PACKING_FACTOR),
                Panel::new("+Y", y, 0.2 * 0.3, BODY_PACKING_FACTOR),
                Panel::new("-Y", -y, 0.2 * 0.3, BODY_PACKING_FACTOR),
            ],
            solar_constant_w_m2: SOLAR_CONSTANT_W_M2,
        }
    }
}

/// The sun as the arrays see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunInput {
    /// Unit direction to the sun, body frame (zero when unknown: no power).
    pub sun_body_unit: Vector3<f64>,
    /// Visible fraction of the solar disc, 0..=1.
    pub visible_fraction: f64,
}

impl SunInput {
    /// No sun at all (no truth yet, or umbra).
    pub const DARK: SunInput = SunInput {
        sun_body_unit: Vector3::new(0.0, 0.0, 0.0),
        visible_fraction: 0.0,
    };

    /// From the truth's ECI sun direction, attitude and visible fraction (a zero or
    /// non-finite sun vector gives [`SunInput::DARK`]).
    pub fn from_eci(
        sun_eci_unit: &Vector3<f64>,
        q_eci_from_body: &UnitQuaternion<f64>,
        visible_fraction: f64,
    ) -> Self {
        let s = q_eci_from_body.inverse_transform_vector(sun_eci_unit);
        match s.try_normalize(1e-9) {
            Some(u) if u.iter().all(|c| c.is_finite()) && visible_fraction.is_finite() => {
                SunInput {
                    sun_body_unit: u,
                    visible_fraction: visible_fraction.clamp(0.0, 1.0),
                }
            }
            _ => Self::DARK,
        }
    }
}

/// What is wrong with a solar array's geometry (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SolarConfigError {
    /// More panels than TMEPS reports.
    #[error("{count} panels; the EPS reports at most {}", MAX_PANELS)]
    TooManyPanels {
        /// Panels configured.
        count: usize,
    },
    /// A panel facing no direction.
    #[error("panel {panel}: zero normal")]
    ZeroNormal {
        /// The panel's name.
        panel: String,
    },
    /// A negative or non-finite area.
    #[error("panel {panel}: area {area_m2} m^2")]
    Area {
        /// The panel's name.
        panel: String,
        /// Its area, m^2.
        area_m2: f64,
    },
    /// A packing factor or efficiency outside 0..=1.
    #[error("panel {panel}: {what} {value} not in 0..=1")]
    Fraction {
        /// The panel's name.
        panel: String,
        /// Which (`packing factor`, `efficiency`).
        what: &'static str,
        /// Its value.
        value: f64,
    },
    /// A negative or non-finite solar constant.
    #[error("solar constant {value}")]
    SolarConstant {
        /// The value, W/m^2.
        value: f64,
    },
}

impl SolarArray {
    /// Power of each panel (the first [`MAX_PANELS`]), W; `failed` panels give 0.
    pub fn panels_w(&self, sun: &SunInput, failed: &[bool]) -> Vec<f64> {
        self.panels
            .iter()
            .take(MAX_PANELS)
            .enumerate()
            .map(|(i, p)| {
                if failed.get(i).copied().unwrap_or(false) {
                    0.0
                } else {
                    p.power_w(
                        self.solar_constant_w_m2,
                        &sun.sun_body_unit,
                        sun.visible_fraction,
                    )
                }
            })
            .collect()
    }

    /// Check the geometry (for the scenario loader); the message names the problem.
    pub fn validate(&self) -> Result<(), SolarConfigError> {
        if self.panels.len() > MAX_PANELS {
            return Err(SolarConfigError::TooManyPanels {
                count: self.panels.len(),
            });
        }
        for p in &self.panels {
            if p.normal_body.try_normalize(1e-9).is_none() {
                return Err(SolarConfigError::ZeroNormal {
                    panel: p.name.clone(),
                });
            }
            if !(p.area_m2.is_finite() && p.area_m2 >= 0.0) {
                return Err(SolarConfigError::Area {
                    panel: p.name.clone(),
                    area_m2: p.area_m2,
                });
            }
            for (what, v) in [
                ("packing factor", p.packing_factor),
                ("efficiency", p.efficiency),
            ] {
                if !(0.0..=1.0).contains(&v) {
                    return Err(SolarConfigError::Fraction {
                        panel: p.name.clone(),
                        what,
                        value: v,
                    });
                }
            }
        }
        if !(self.solar_constant_w_m2.is_finite() && self.solar_constant_w_m2 >= 0.0) {
            return Err(SolarConfigError::SolarConstant {
                value: self.solar_constant_w_m2,
            });
        }
        Ok(())
    }
}

snap::fields!(Panel {
    name,
    normal_body,
    area_m2,
    packing_factor,
    efficiency
});
snap::fields!(SolarArray {
    panels,
    solar_constant_w_m2
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn sun(v: Vector3<f64>, vis: f64) -> SunInput {
        SunInput::from_eci(&v, &UnitQuaternion::identity(), vis)
    }

    #[test]
    fn sun_on_the_wing_normal_gives_peak_and_edge_on_gives_nothing() {
        let a = SolarArray::default();
        let on = a.panels_w(&sun(Vector3::x(), 1.0), &[]);
        let total: f64 = on.iter().sum();
        // 1361 * (0.03 * 0.85 + 0.12 * 0.90) * 0.295 = 53.6 W, all from the +X side.
        assert!((total - 1361.0 * (0.03 * 0.85 + 0.12 * 0.9) * 0.295).abs() < 1e-9);
        assert!((50.0..56.0).contains(&total), "{total}");
        assert_eq!(on[3..], [0.0, 0.0, 0.0]);
        // Edge-on to +X and -X (sun along +Z): nothing at all (no cells on +-Z).
        let edge: f64 = a.panels_w(&sun(Vector3::z(), 1.0), &[]).iter().sum();
        assert_eq!(edge, 0.0);
        // 60 deg off the normal: half.
        let tilted = Vector3::new(0.5, 0.0, 0.75f64.sqrt());
        let half: f64 = a.panels_w(&sun(tilted, 1.0), &[]).iter().sum();
        assert!((half - total / 2.0).abs() < 1e-9);
    }

    #[test]
    fn umbra_is_zero_and_penumbra_scales() {
        let a = SolarArray::default();
        let full: f64 = a.panels_w(&sun(Vector3::x(), 1.0), &[]).iter().sum();
        let umbra: f64 = a.panels_w(&sun(Vector3::x(), 0.0), &[]).iter().sum();
        let pen: f64 = a.panels_w(&sun(Vector3::x(), 0.3), &[]).iter().sum();
        assert_eq!(umbra, 0.0);
        assert!((pen - 0.3 * full).abs() < 1e-9);
    }

    #[test]
    fn the_attitude_turns_the_sun_into_the_body_frame() {
        let a = SolarArray::default();
        // Body +X points along ECI +Y: a sun along ECI +Y is on the wings.
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let s = SunInput::from_eci(&Vector3::y(), &q, 1.0);
        assert!((s.sun_body_unit - Vector3::x()).norm() < 1e-12);
        let p = a.panels_w(&s, &[]);
        assert!(p[1] > 20.0 && p[4] < 1e-9);
        // A failed wing gives nothing.
        let p2 = a.panels_w(&s, &[false, true]);
        assert_eq!(p2[1], 0.0);
        assert_eq!(p2[2], p[2]);
    }

    #[test]
    fn no_sun_vector_is_dark() {
        assert_eq!(
            SunInput::from_eci(&Vector3::zeros(), &UnitQuaternion::identity(), 1.0),
            SunInput::DARK
        );
        assert!(SolarArray::default().validate().is_ok());
    }
}
