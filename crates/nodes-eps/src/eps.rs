//! The EPS's pure core: arrays, battery, loads, channels and protection, stepped with the
//! inputs of one interval. No clock, no boards, no network: [`crate::EpsApp`] assembles
//! [`EpsInputs`] and calls [`Eps::step`] and [`Eps::protect`].

use platform::truth::TruthSnapshot;

use crate::EpsConfig;
use crate::battery::{Battery, BatteryStep};
use crate::loads::{CHANNELS, Channel, Duties, LoadBreakdown, LoadConfig, LoadInputs};
use crate::protect::{Group, Protection, Thresholds};
use crate::solar::{MAX_PANELS, SolarArray, SunInput};
use crate::wire::{ChannelStates, PROTECTION_CUT_OFF, TmEps};

/// Everything one step of the power system depends on besides its own state.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EpsInputs {
    /// The sun as the arrays see it.
    pub sun: SunInput,
    /// Wheels, magnetorquers and activity duties.
    pub loads: LoadInputs,
}

impl Default for SunInput {
    fn default() -> Self {
        SunInput::DARK
    }
}

impl EpsInputs {
    /// From the FC's truth (none yet: no sun, wheels at rest, magnetorquers off) and the
    /// activity duties of the interval.
    pub fn from_truth(truth: Option<&TruthSnapshot>, duties: Duties) -> Self {
        match truth {
            Some(s) => EpsInputs {
                sun: SunInput::from_eci(
                    &s.sun_eci_unit,
                    &s.q_eci_from_body,
                    s.in_eclipse_fraction_visible,
                ),
                loads: LoadInputs {
                    wheel_speed_rad_s: s.wheel_speed_rad_s,
                    mtq_dipole_am2: s.mtq_dipole_am2,
                    duties,
                },
            },
            None => EpsInputs {
                sun: SunInput::DARK,
                loads: LoadInputs {
                    duties,
                    ..LoadInputs::default()
                },
            },
        }
    }
}

/// The result of the latest step.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepState {
    /// Power of each panel, W.
    pub panels_w: Vec<f64>,
    /// Total array power available, W.
    pub solar_w: f64,
    /// Where the load power went.
    pub loads: LoadBreakdown,
    /// What the battery did.
    pub battery: BatteryStep,
}

/// Why a channel switch was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwitchRefused {
    /// The channel's protection group is shed.
    GroupShed(Group),
}

/// The power system (see the crate doc).
#[derive(Debug, Clone)]
pub struct Eps {
    array: SolarArray,
    loads: LoadConfig,
    battery: Battery,
    configured_thresholds: Thresholds,
    thresholds: Thresholds,
    channels_on: u16,
    protection: Protection,
    failed_panels: Vec<bool>,
    last: StepState,
    solar_wh: f64,
    load_wh: f64,
}

impl Eps {
    /// The power system of `cfg` at its initial state of charge and channel states.
    pub fn new(cfg: &EpsConfig) -> Self {
        let mut eps = Eps {
            array: cfg.panels.clone(),
            loads: cfg.loads.clone(),
            battery: Battery::new(cfg.battery.clone(), cfg.initial_soc),
            configured_thresholds: cfg.thresholds,
            thresholds: cfg.thresholds,
            channels_on: cfg.channels_on & crate::loads::ALL_CHANNELS,
            protection: Protection::default(),
            failed_panels: vec![false; cfg.panels.panels.len().min(MAX_PANELS)],
            last: StepState::default(),
            solar_wh: 0.0,
            load_wh: 0.0,
        };
        eps.step(0, &EpsInputs::default());
        eps
    }

    /// Integrate `dt_ns` nanoseconds with inputs `x` (held over the interval).
    pub fn step(&mut self, dt_ns: u64, x: &EpsInputs) -> &StepState {
        let dt_s = dt_ns as f64 * 1e-9;
        let panels_w = self.array.panels_w(&x.sun, &self.failed_panels);
        let solar_w: f64 = panels_w.iter().sum();
        let loads = self.loads.loads(self.channels_on, &x.loads);
        let load_w = loads.total_w();
        let battery = self.battery.step(solar_w - load_w, dt_s);
        self.solar_wh += solar_w * dt_s / 3600.0;
        self.load_wh += load_w * dt_s / 3600.0;
        self.last = StepState {
            panels_w,
            solar_w,
            loads,
            battery,
        };
        &self.last
    }

    /// Apply the low-battery protection to the state of charge now; returns the switches.
    pub fn protect(&mut self) -> Vec<(Channel, bool, Group)> {
        let soc = self.battery.soc();
        self.protection
            .update(soc, &self.thresholds, &mut self.channels_on)
    }

    /// Switch `c` (a command or a scenario): `Ok(true)` if its state changed.
    pub fn switch(&mut self, c: Channel, on: bool) -> Result<bool, SwitchRefused> {
        if on && !self.protection.allows_on(c) {
            if let Some(g) = Group::of(c) {
                return Err(SwitchRefused::GroupShed(g));
            }
        }
        if !on {
            self.protection.forget(c);
        }
        let was = self.channels_on & c.bit() != 0;
        if on {
            self.channels_on |= c.bit();
        } else {
            self.channels_on &= !c.bit();
        }
        Ok(was != on)
    }

    /// Set the thresholds (checked by the caller: [`Thresholds::validate`]).
    pub fn set_thresholds(&mut self, t: Thresholds) {
        self.thresholds = t;
    }
    /// The thresholds in use.
    pub fn thresholds(&self) -> Thresholds {
        self.thresholds
    }
    /// Set the thresholds in use and the ones a reboot returns to (the parameter table's
    /// set, [`crate::config`]; checked by the caller).
    pub fn set_configured_thresholds(&mut self, t: Thresholds) {
        self.configured_thresholds = t;
        self.thresholds = t;
    }
    /// Set the battery's charge power limit, W ([`Battery::set_max_charge_w`]).
    pub fn set_max_charge_w(&mut self, w: f64) {
        self.battery.set_max_charge_w(w);
    }
    /// Which panels have failed (by index in the array, the panels in use).
    pub fn failed_panels(&self) -> &[bool] {
        &self.failed_panels
    }
    /// Mark panel `i` failed or working (ignored past the panels in use).
    pub fn set_panel_failed(&mut self, i: usize, failed: bool) {
        if let Some(f) = self.failed_panels.get_mut(i) {
            *f = failed;
        }
    }
    /// Set the state of charge (a scenario's fault injection).
    pub fn set_soc(&mut self, soc: f64) {
        self.battery.set_soc(soc);
    }
    /// The battery loses `fraction` of its capacity ([`Battery::fade`]).
    pub fn fade_battery(&mut self, fraction: f64) {
        self.battery.fade(fraction);
    }

    /// The EPS software rebooted: thresholds back to the configuration, energy counters
    /// from zero. Battery, channels and the protection's memory are physical or
    /// non-volatile and stay.
    pub fn reset_volatile(&mut self) {
        self.thresholds = self.configured_thresholds;
        self.solar_wh = 0.0;
        self.load_wh = 0.0;
    }

    /// The battery.
    pub fn battery(&self) -> &Battery {
        &self.battery
    }
    /// State of charge, 0..=1.
    pub fn soc(&self) -> f64 {
        self.battery.soc()
    }
    /// Channels on (mask).
    pub fn channels_on(&self) -> u16 {
        self.channels_on
    }
    /// Whether `c` is on.
    pub fn is_on(&self, c: Channel) -> bool {
        self.channels_on & c.bit() != 0
    }
    /// The protection's state.
    pub fn protection(&self) -> Protection {
        self.protection
    }
    /// The latest step.
    pub fn last(&self) -> &StepState {
        &self.last
    }
    /// Solar and load energy since the EPS booted, Wh.
    pub fn energy_since_boot_wh(&self) -> (f64, f64) {
        (self.solar_wh, self.load_wh)
    }
    /// CHGET's reply.
    pub fn channel_states(&self) -> ChannelStates {
        ChannelStates {
            on: self.channels_on,
            shed: self.protection.shed,
        }
    }

    /// TMEPS's reply.
    pub fn tm(&self) -> TmEps {
        let l = &self.last;
        let v = l.battery.voltage_v;
        let mut panels_w = [0.0f32; MAX_PANELS];
        for (slot, p) in panels_w.iter_mut().zip(&l.panels_w) {
            *slot = *p as f32;
        }
        let mut channel_ma = [0u16; CHANNELS];
        for (slot, w) in channel_ma.iter_mut().zip(&l.loads.channel_w) {
            let ma = if v > 0.0 { w / v * 1000.0 } else { 0.0 };
            // `as` saturates: a negative or NaN value is 0, a huge one 65535.
            *slot = ma.round() as u16;
        }
        let mut protection = self.protection.groups;
        if l.battery.unmet_w > 0.0 {
            protection |= PROTECTION_CUT_OFF;
        }
        TmEps {
            battery_v: v as f32,
            battery_a: l.battery.current_a as f32,
            soc: self.battery.soc() as f32,
            battery_wh: self.battery.energy_wh() as f32,
            solar_w: l.solar_w as f32,
            load_w: l.loads.total_w() as f32,
            panel_count: l.panels_w.len() as u8,
            panels_w,
            channels_on: self.channels_on,
            channels_shed: self.protection.shed,
            channel_ma,
            protection,
            solar_wh: self.solar_wh as f32,
            load_wh: self.load_wh as f32,
        }
    }
}
snap::fields!(StepState {
    panels_w,
    solar_w,
    loads,
    battery
});
snap::fields!(Eps {
    array,
    loads,
    battery,
    configured_thresholds,
    thresholds,
    channels_on,
    protection,
    failed_panels,
    last,
    solar_wh,
    load_wh
});
