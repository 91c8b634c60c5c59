//! The thruster and its blow-down tank: pure functions of the propellant left.
//!
//! # Model
//! One thruster on the propulsion face (-Z) pushing the spacecraft along body **+Z** (ICD
//! 1.4: +Z points away from the propulsion face). The default is a green-monopropellant
//! (ADN-blend) thruster of the class NanoAvionics flies on its 6U buses, with round figures
//! of that class rather than a datasheet: 0.3 N at the full-tank pressure, specific impulse
//! 200 s (the small-spacecraft survey gives 220-250 s steady state for green monopropellants
//! and 65-70 s for cold gas, NASA *Small Spacecraft Technology State of the Art* 2018,
//! table 4-1; 200 s allows for the pulsed, blow-down operation of a small thruster), 0.5 kg
//! of propellant, a 12 kg dry spacecraft (the FC's body mass). Total impulse at full load
//! `m Isp g0` = 981 N s, a delta-v of about 80 m/s.
//!
//! **Blow-down tank.** The pressurant gas above the propellant expands isothermally as
//! propellant leaves: with a fraction `x` of the load used and the blow-down ratio
//! `B = p_full / p_empty` (the gas volume grows from `V_g0` to `B V_g0` as the tank
//! empties), `p = p_full / (1 + (B - 1) x)` (Boyle's law; the propellant density cancels).
//! The default 2200 kPa full and `B` = 4 (550 kPa empty) are typical of small blow-down
//! monopropellant tanks. Thrust is proportional to the feed pressure (fixed throat, chamber
//! pressure following the feed pressure, constant thrust coefficient) and the specific
//! impulse is held constant, so the mass flow `F / (Isp g0)` falls with the thrust. `B` = 1
//! models a regulated tank (constant thrust).
//!
//! **Within one burn** the thrust and mass flow are those at the burn's start: a burn of at
//! most 60 s uses at most 9.2 g (1.8 % of the load), and the pressure changes by less than
//! 6 % over it in the worst case (a full tank); the next burn starts at the new pressure.

use nalgebra::Vector3;

/// Standard gravity, m/s^2 (3rd CGPM, 1901): converts specific impulse to exhaust velocity.
pub const G0_M_S2: f64 = 9.806_65;

/// The thruster, the tank and the spacecraft's dry mass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrusterConfig {
    /// Thrust at the full-tank pressure, N.
    pub thrust_n: f64,
    /// Specific impulse, s (held constant).
    pub isp_s: f64,
    /// Propellant loaded (full tank), kg.
    pub propellant_kg: f64,
    /// Spacecraft mass without propellant, kg.
    pub dry_mass_kg: f64,
    /// Tank pressure with the full load, kPa.
    pub full_pressure_kpa: f64,
    /// Full over empty tank pressure (>= 1; 1 = regulated, constant thrust).
    pub blowdown_ratio: f64,
    /// Thrust direction in the body frame (unit; +Z by ICD 1.4).
    pub dir_body: Vector3<f64>,
}

impl Default for ThrusterConfig {
    /// 0.3 N, 200 s, 0.5 kg, 12 kg dry, 2200 kPa, blow-down 4, along +Z (see the module doc).
    fn default() -> Self {
        ThrusterConfig {
            thrust_n: 0.3,
            isp_s: 200.0,
            propellant_kg: 0.5,
            dry_mass_kg: 12.0,
            full_pressure_kpa: 2200.0,
            blowdown_ratio: 4.0,
            dir_body: Vector3::z(),
        }
    }
}

/// What is wrong with a thruster configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ThrusterConfigError {
    /// A figure that must be positive (thrust, Isp, dry mass, full pressure) is not.
    #[error("ECU {name} = {value}: must be finite and > 0")]
    NotPositive {
        /// The field's name.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A negative or non-finite propellant mass.
    #[error("ECU propellant_kg = {propellant_kg}: must be finite and >= 0")]
    Propellant {
        /// The mass, kg.
        propellant_kg: f64,
    },
    /// A blowdown ratio below 1 (the pressure would rise as the tank empties).
    #[error("ECU blowdown_ratio = {blowdown_ratio}: must be finite and >= 1")]
    BlowdownRatio {
        /// The ratio.
        blowdown_ratio: f64,
    },
    /// A thrust direction without a direction.
    #[error("ECU dir_body = {dir_body:?}: must be a non-zero vector")]
    Direction {
        /// The direction, body frame.
        dir_body: Vector3<f64>,
    },
}

impl ThrusterConfig {
    /// Check the configuration (for the scenario loader); the message names the problem.
    pub fn validate(&self) -> Result<(), ThrusterConfigError> {
        let positive = [
            ("thrust_n", self.thrust_n),
            ("isp_s", self.isp_s),
            ("dry_mass_kg", self.dry_mass_kg),
            ("full_pressure_kpa", self.full_pressure_kpa),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ThrusterConfigError::NotPositive { name, value: v });
            }
        }
        if !(self.propellant_kg.is_finite() && self.propellant_kg >= 0.0) {
            return Err(ThrusterConfigError::Propellant {
                propellant_kg: self.propellant_kg,
            });
        }
        if !(self.blowdown_ratio.is_finite() && self.blowdown_ratio >= 1.0) {
            return Err(ThrusterConfigError::BlowdownRatio {
                blowdown_ratio: self.blowdown_ratio,
            });
        }
        let n = self.dir_body.norm();
        if !(n.is_finite() && n > 0.0) {
            return Err(ThrusterConfigError::Direction {
                dir_body: self.dir_body,
            });
        }
        Ok(())
    }

    /// Exhaust velocity `Isp g0`, m/s.
    pub fn exhaust_velocity_m_s(&self) -> f64 {
        self.isp_s * G0_M_S2
    }

    /// Tank pressure with `propellant_kg` left, kPa (Boyle's law, see the module doc).
    pub fn pressure_kpa(&self, propellant_kg: f64) -> f64 {
        let used = if self.propellant_kg > 0.0 {
            ((self.propellant_kg - propellant_kg) / self.propellant_kg).clamp(0.0, 1.0)
        } else {
            1.0
        };
        self.full_pressure_kpa / (1.0 + (self.blowdown_ratio - 1.0) * used)
    }

    /// Thrust with `propellant_kg` left, N (proportional to the tank pressure).
    pub fn thrust_at_n(&self, propellant_kg: f64) -> f64 {
        self.thrust_n * self.pressure_kpa(propellant_kg) / self.full_pressure_kpa
    }

    /// Propellant mass flow at thrust `thrust_n`, kg/s (`F / (Isp g0)`).
    pub fn mass_flow_kg_s(&self, thrust_n: f64) -> f64 {
        thrust_n / self.exhaust_velocity_m_s()
    }

    /// The unit thrust direction in the body frame (+Z if the configured one is degenerate).
    pub fn dir_unit_body(&self) -> Vector3<f64> {
        self.dir_body
            .try_normalize(0.0)
            .filter(|v| v.iter().all(|x| x.is_finite()))
            .unwrap_or_else(Vector3::z)
    }
}

snap::fields!(ThrusterConfig {
    thrust_n,
    isp_s,
    propellant_kg,
    dry_mass_kg,
    full_pressure_kpa,
    blowdown_ratio,
    dir_body
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn blow_down_pressure_and_thrust_fall_with_the_propellant() {
        let c = ThrusterConfig::default();
        assert_eq!(c.pressure_kpa(0.5), 2200.0);
        assert!((c.pressure_kpa(0.0) - 550.0).abs() < 1e-9);
        // Half used: the gas volume is 1 + 3/2 = 2.5 times the initial one.
        assert!((c.pressure_kpa(0.25) - 880.0).abs() < 1e-9);
        assert!((c.thrust_at_n(0.25) - 0.12).abs() < 1e-12);
        let mut last = f64::INFINITY;
        for k in 0..=50 {
            let p = c.pressure_kpa(0.5 - 0.01 * f64::from(k));
            assert!(p < last);
            last = p;
        }
        let regulated = ThrusterConfig {
            blowdown_ratio: 1.0,
            ..c
        };
        assert_eq!(regulated.thrust_at_n(0.01), 0.3);
    }

    #[test]
    fn mass_flow_is_thrust_over_exhaust_velocity() {
        let c = ThrusterConfig::default();
        // 0.3 / (200 * 9.80665) = 1.52957e-4 kg/s: 9.18 g a minute.
        let mdot = c.mass_flow_kg_s(0.3);
        assert!((mdot - 1.529_574e-4).abs() < 1e-9, "{mdot}");
        assert!((c.propellant_kg * c.exhaust_velocity_m_s() - 980.665).abs() < 1e-9);
    }

    #[test]
    fn validation_names_the_bad_field() {
        assert!(ThrusterConfig::default().validate().is_ok());
        let bad = ThrusterConfig {
            isp_s: 0.0,
            ..ThrusterConfig::default()
        };
        let e = bad.validate().unwrap_err();
        assert!(matches!(
            e,
            ThrusterConfigError::NotPositive { name: "isp_s", .. }
        ));
        assert_eq!(e.to_string(), "ECU isp_s = 0: must be finite and > 0");
        let bad = ThrusterConfig {
            blowdown_ratio: 0.5,
            ..ThrusterConfig::default()
        };
        assert_eq!(
            bad.validate(),
            Err(ThrusterConfigError::BlowdownRatio {
                blowdown_ratio: 0.5
            })
        );
        let bad = ThrusterConfig {
            dir_body: Vector3::zeros(),
            ..ThrusterConfig::default()
        };
        assert!(bad.validate().is_err());
        assert_eq!(bad.dir_unit_body(), Vector3::z());
    }
}
