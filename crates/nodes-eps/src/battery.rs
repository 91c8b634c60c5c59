//! The battery: stored energy, open-circuit voltage from a table of state of charge,
//! internal resistance, charge and discharge efficiency, rate limits, full and empty.
//!
//! # Model
//! The state is the energy stored in the cells, Wh; state of charge `soc = energy /
//! capacity` (0..=1). One step of `dt` (integer nanoseconds from the EPS's tick, converted
//! once per step) takes the bus balance `net = solar - load`, W:
//! - surplus (`net >= 0`): the battery accepts `min(net, max_charge_w, room)` at its
//!   terminals, and the cells gain `accepted * charge_efficiency * dt`; whatever is not
//!   accepted (battery full, or above the charge limit) is left on the arrays (the MPPT
//!   moves off its maximum power point: `spilled_w`). No charge beyond 100 %; no
//!   constant-voltage taper near full (the charge power is the limit up to 100 %).
//! - deficit (`net < 0`): the battery delivers `min(-net, max_discharge_w, what is left)`
//!   and the cells lose `delivered / discharge_efficiency * dt`; at 0 % (cut-off) it
//!   delivers nothing and the rest is `unmet_w` (the loads brown out: the twin logs it; the
//!   protection has shed every switchable load long before).
//! - terminal current `I` (positive charging) and voltage `V = OCV(soc) + I R` satisfy
//!   `V I = P` at the terminals: `R I^2 + OCV I - P = 0`. The efficiencies carry the
//!   energy losses; `R` only shapes the voltage the telemetry reports.
//!
//! # Default: 2S4P Li-ion, 77 Wh
//! Eight 18650 cells of 2.6 Ah (LG ICR18650 C2 class, NMC): 2 in series, 4 in parallel,
//! 10.4 Ah at 7.4 V nominal = 77 Wh. OCV per cell at C/20, 25 C, doubled for the pack
//! ([`DEFAULT_OCV_TABLE`]; typical NMC curve, 3.0 V empty to 4.18 V full). Pack resistance
//! 0.05 ohm: cell DC resistance ~35 mohm (2 x 35 / 4 = 17.5 mohm) plus protection FETs,
//! shunt and harness. Charge efficiency 0.93 (MPPT converter 0.95 x coulombic 0.98),
//! discharge efficiency 0.95 (cell and regulator losses): round trip 0.88. Charge limit
//! 40 W (0.5 C at 7.7 V), discharge limit 60 W (about 0.8 C). No temperature model: the
//! cells sit in a heated box near 20 C (the heater's power is in the EPS's own load).

/// Open-circuit voltage of the default 2S pack against state of charge (soc, volts).
pub const DEFAULT_OCV_TABLE: [(f64, f64); 12] = [
    (0.00, 6.00),
    (0.05, 6.60),
    (0.10, 6.90),
    (0.20, 7.12),
    (0.30, 7.26),
    (0.40, 7.38),
    (0.50, 7.50),
    (0.60, 7.64),
    (0.70, 7.80),
    (0.80, 7.96),
    (0.90, 8.14),
    (1.00, 8.36),
];

/// The battery's fixed properties.
#[derive(Debug, Clone, PartialEq)]
pub struct BatteryConfig {
    /// Usable energy from 100 % to 0 %, Wh.
    pub capacity_wh: f64,
    /// Open-circuit voltage table: (soc 0..=1, volts), soc strictly increasing from 0 to 1,
    /// voltage increasing.
    pub ocv_table: Vec<(f64, f64)>,
    /// Pack internal resistance, ohm.
    pub internal_resistance_ohm: f64,
    /// Fraction of the terminal charge power stored in the cells.
    pub charge_efficiency: f64,
    /// Fraction of the energy taken from the cells that reaches the terminals.
    pub discharge_efficiency: f64,
    /// Largest charge power at the terminals, W.
    pub max_charge_w: f64,
    /// Largest discharge power at the terminals, W.
    pub max_discharge_w: f64,
}

impl Default for BatteryConfig {
    /// The 2S4P 77 Wh pack of the module doc.
    fn default() -> Self {
        BatteryConfig {
            capacity_wh: 77.0,
            ocv_table: DEFAULT_OCV_TABLE.to_vec(),
            internal_resistance_ohm: 0.05,
            charge_efficiency: 0.93,
            discharge_efficiency: 0.95,
            max_charge_w: 40.0,
            max_discharge_w: 60.0,
        }
    }
}

/// What is wrong with a battery configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum BatteryConfigError {
    /// A capacity that is not positive.
    #[error("battery capacity {capacity_wh} Wh")]
    Capacity {
        /// The capacity, Wh.
        capacity_wh: f64,
    },
    /// An OCV table that does not cover the whole charge range.
    #[error("OCV table must run from soc 0 to soc 1")]
    OcvEnds,
    /// An OCV table out of order.
    #[error("OCV table: soc must increase and voltage must not fall")]
    OcvOrder,
    /// An OCV table with a voltage that is not positive.
    #[error("OCV table: voltages must be positive")]
    OcvVoltage,
    /// An efficiency outside (0, 1].
    #[error("battery {what} {value} not in (0, 1]")]
    Efficiency {
        /// Which (`charge efficiency`, `discharge efficiency`).
        what: &'static str,
        /// Its value.
        value: f64,
    },
    /// A resistance or power limit that is negative or not finite.
    #[error("battery {what} {value}")]
    Negative {
        /// Which (`internal resistance`, `max charge power`, `max discharge power`).
        what: &'static str,
        /// Its value.
        value: f64,
    },
}

impl BatteryConfig {
    /// Check the configuration (for the scenario loader); the error names the problem.
    pub fn validate(&self) -> Result<(), BatteryConfigError> {
        if !(self.capacity_wh.is_finite() && self.capacity_wh > 0.0) {
            return Err(BatteryConfigError::Capacity {
                capacity_wh: self.capacity_wh,
            });
        }
        let t = &self.ocv_table;
        if t.len() < 2 || t.first().map(|p| p.0) != Some(0.0) || t.last().map(|p| p.0) != Some(1.0)
        {
            return Err(BatteryConfigError::OcvEnds);
        }
        if t.windows(2).any(|w| !(w[1].0 > w[0].0 && w[1].1 >= w[0].1)) {
            return Err(BatteryConfigError::OcvOrder);
        }
        if t.iter().any(|p| !(p.1.is_finite() && p.1 > 0.0)) {
            return Err(BatteryConfigError::OcvVoltage);
        }
        for (what, v) in [
            ("charge efficiency", self.charge_efficiency),
            ("discharge efficiency", self.discharge_efficiency),
        ] {
            if !(v > 0.0 && v <= 1.0) {
                return Err(BatteryConfigError::Efficiency { what, value: v });
            }
        }
        for (what, v) in [
            ("internal resistance", self.internal_resistance_ohm),
            ("max charge power", self.max_charge_w),
            ("max discharge power", self.max_discharge_w),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(BatteryConfigError::Negative { what, value: v });
            }
        }
        Ok(())
    }

    /// Open-circuit voltage at `soc` (linear between table points, clamped to the ends), V.
    pub fn ocv_v(&self, soc: f64) -> f64 {
        let t = &self.ocv_table;
        let (Some(first), Some(last)) = (t.first(), t.last()) else {
            return 0.0;
        };
        if soc <= first.0 {
            return first.1;
        }
        if soc >= last.0 {
            return last.1;
        }
        for w in t.windows(2) {
            let (a, b) = (w[0], w[1]);
            if soc <= b.0 {
                return a.1 + (b.1 - a.1) * (soc - a.0) / (b.0 - a.0);
            }
        }
        last.1
    }
}

/// What one battery step did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BatteryStep {
    /// Power at the terminals, W (positive charging).
    pub terminal_w: f64,
    /// Terminal current, A (positive charging).
    pub current_a: f64,
    /// Terminal voltage, V.
    pub voltage_v: f64,
    /// Array power the battery could not take (full, or above the charge limit), W.
    pub spilled_w: f64,
    /// Load power nobody supplied (battery empty or above its discharge limit), W.
    pub unmet_w: f64,
}

/// The battery's state (physical: it survives an EPS reboot).
#[derive(Debug, Clone, PartialEq)]
pub struct Battery {
    cfg: BatteryConfig,
    energy_wh: f64,
}

impl Battery {
    /// A battery at state of charge `soc` (clamped to 0..=1).
    pub fn new(cfg: BatteryConfig, soc: f64) -> Self {
        let energy_wh = cfg.capacity_wh
            * if soc.is_finite() {
                soc.clamp(0.0, 1.0)
            } else {
                0.0
            };
        Battery { cfg, energy_wh }
    }
    /// The configuration.
    pub fn config(&self) -> &BatteryConfig {
        &self.cfg
    }
    /// Set the largest charge power at the terminals, W (the charge regulator's limit; a
    /// parameter, [`crate::config`]).
    pub fn set_max_charge_w(&mut self, w: f64) {
        if w.is_finite() && w >= 0.0 {
            self.cfg.max_charge_w = w;
        }
    }
    /// Energy stored, Wh.
    pub fn energy_wh(&self) -> f64 {
        self.energy_wh
    }
    /// State of charge, 0..=1.
    pub fn soc(&self) -> f64 {
        if self.cfg.capacity_wh > 0.0 {
            (self.energy_wh / self.cfg.capacity_wh).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
    /// Set the state of charge (a scenario's fault injection), clamped to 0..=1.
    pub fn set_soc(&mut self, soc: f64) {
        *self = Battery::new(self.cfg.clone(), soc);
    }
    /// The cells lose `fraction` (0..1) of their capacity (lithium inventory lost to
    /// ageing, a failed cell string): the energy they hold shrinks in proportion, so the
    /// state of charge is unchanged at that instant, and from then on the battery fills and
    /// empties that much sooner. A fraction outside 0..1 changes nothing.
    pub fn fade(&mut self, fraction: f64) {
        if !(fraction.is_finite() && (0.0..1.0).contains(&fraction)) {
            return;
        }
        let keep = 1.0 - fraction;
        self.cfg.capacity_wh *= keep;
        self.energy_wh *= keep;
    }
    /// Open-circuit voltage now, V.
    pub fn ocv_v(&self) -> f64 {
        self.cfg.ocv_v(self.soc())
    }

    /// Terminal current and voltage for terminal power `p_w` (positive charging).
    pub fn terminal(&self, p_w: f64) -> (f64, f64) {
        let ocv = self.ocv_v();
        let r = self.cfg.internal_resistance_ohm;
        let disc = ocv * ocv + 4.0 * r * p_w;
        let i = if ocv <= 0.0 {
            0.0
        } else if disc <= 0.0 {
            // Beyond the pack's maximum power: the current of maximum power.
            -ocv / (2.0 * r)
        } else {
            // The root near P / OCV, in the form that stays accurate as r -> 0.
            2.0 * p_w / (ocv + disc.sqrt())
        };
        (i, ocv + i * r)
    }

    /// Integrate `dt_s` seconds of bus balance `net_w` (solar minus load, W).
    pub fn step(&mut self, net_w: f64, dt_s: f64) -> BatteryStep {
        if dt_s.is_nan() || dt_s <= 0.0 || !net_w.is_finite() {
            let (current_a, voltage_v) = self.terminal(0.0);
            return BatteryStep {
                current_a,
                voltage_v,
                ..BatteryStep::default()
            };
        }
        let c = &self.cfg;
        let h = dt_s / 3600.0;
        let (terminal_w, spilled_w, unmet_w) = if net_w >= 0.0 {
            let room_w = (c.capacity_wh - self.energy_wh).max(0.0) / (c.charge_efficiency * h);
            let accepted = net_w.min(c.max_charge_w).min(room_w);
            self.energy_wh =
                (self.energy_wh + accepted * c.charge_efficiency * h).min(c.capacity_wh);
            (accepted, net_w - accepted, 0.0)
        } else {
            let demand = -net_w;
            let left_w = self.energy_wh.max(0.0) * c.discharge_efficiency / h;
            let delivered = demand.min(c.max_discharge_w).min(left_w);
            self.energy_wh = if delivered >= left_w {
                0.0
            } else {
                (self.energy_wh - delivered / c.discharge_efficiency * h).max(0.0)
            };
            (-delivered, 0.0, demand - delivered)
        };
        let (current_a, voltage_v) = self.terminal(terminal_w);
        BatteryStep {
            terminal_w,
            current_a,
            voltage_v,
            spilled_w,
            unmet_w,
        }
    }
}

snap::fields!(BatteryConfig {
    capacity_wh,
    ocv_table,
    internal_resistance_ohm,
    charge_efficiency,
    discharge_efficiency,
    max_charge_w,
    max_discharge_w
});
snap::fields!(BatteryStep {
    terminal_w,
    current_a,
    voltage_v,
    spilled_w,
    unmet_w
});
// The configuration too: a battery fade and the parameters change it in flight.
snap::fields!(Battery { cfg, energy_wh });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_voltage_table_is_monotone_and_interpolated() {
        let c = BatteryConfig::default();
        assert!(c.validate().is_ok());
        let mut last = 0.0;
        for k in 0..=1000 {
            let v = c.ocv_v(k as f64 / 1000.0);
            assert!(v >= last, "OCV falls at soc {}", k as f64 / 1000.0);
            last = v;
        }
        assert_eq!(c.ocv_v(0.0), 6.0);
        assert_eq!(c.ocv_v(1.0), 8.36);
        assert!((c.ocv_v(0.45) - 7.44).abs() < 1e-12);
        assert_eq!(c.ocv_v(-1.0), 6.0);
        assert_eq!(c.ocv_v(2.0), 8.36);
        let mut bad = c.clone();
        bad.ocv_table[3].1 = 5.0;
        assert!(bad.validate().is_err());
    }

    #[test]
    fn surplus_charges_with_the_charge_efficiency() {
        let mut b = Battery::new(BatteryConfig::default(), 0.5);
        // 10 W for one hour: 9.3 Wh stored.
        let mut s = BatteryStep::default();
        for _ in 0..3600 {
            s = b.step(10.0, 1.0);
        }
        assert!((b.energy_wh() - (38.5 + 9.3)).abs() < 1e-9);
        assert_eq!(s.terminal_w, 10.0);
        assert!(s.current_a > 0.0 && s.voltage_v > b.ocv_v());
        assert!((s.voltage_v * s.current_a - 10.0).abs() < 1e-9);
    }

    #[test]
    fn deficit_discharges_with_the_discharge_efficiency() {
        let mut b = Battery::new(BatteryConfig::default(), 0.5);
        let s = b.step(-9.5, 3600.0);
        assert!((b.energy_wh() - (38.5 - 10.0)).abs() < 1e-9);
        assert!(s.current_a < 0.0 && s.voltage_v < b.ocv_v());
        assert_eq!(s.unmet_w, 0.0);
    }

    #[test]
    fn no_charge_above_full_and_cut_off_at_empty() {
        let mut b = Battery::new(BatteryConfig::default(), 0.999);
        let s = b.step(30.0, 600.0);
        assert_eq!(b.soc(), 1.0);
        assert!(s.spilled_w > 29.0, "{s:?}");
        let s = b.step(30.0, 1.0);
        assert_eq!((s.terminal_w, s.spilled_w), (0.0, 30.0));
        // The charge limit.
        let mut b = Battery::new(BatteryConfig::default(), 0.2);
        let s = b.step(55.0, 1.0);
        assert_eq!((s.terminal_w, s.spilled_w), (40.0, 15.0));

        let mut b = Battery::new(BatteryConfig::default(), 0.001);
        let s = b.step(-10.0, 600.0);
        assert_eq!(b.soc(), 0.0);
        assert!(s.unmet_w > 0.0);
        let s = b.step(-10.0, 1.0);
        assert_eq!((s.terminal_w, s.unmet_w), (0.0, 10.0));
        assert_eq!(s.current_a, 0.0);
    }

    #[test]
    fn a_faded_battery_keeps_its_charge_and_fills_and_empties_sooner() {
        let mut b = Battery::new(BatteryConfig::default(), 0.8);
        let full = b.config().capacity_wh;
        b.fade(0.25);
        assert!((b.soc() - 0.8).abs() < 1e-12);
        assert!((b.config().capacity_wh - 0.75 * full).abs() < 1e-9);
        assert!((b.energy_wh() - 0.6 * full).abs() < 1e-9);
        // The same 10 W for an hour takes 10/0.95 Wh out of a smaller battery.
        let mut fresh = Battery::new(BatteryConfig::default(), 0.8);
        b.step(-10.0, 3600.0);
        fresh.step(-10.0, 3600.0);
        assert!(b.soc() < fresh.soc());
        assert!(((0.8 - b.soc()) * 0.75 - (0.8 - fresh.soc())).abs() < 1e-9);
        // Nonsense changes nothing.
        let before = b.clone();
        b.fade(1.5);
        b.fade(f64::NAN);
        assert_eq!(b, before);
    }
}
