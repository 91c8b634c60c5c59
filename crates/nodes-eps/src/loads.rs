//! Power channels and the platform's loads.
//!
//! # Channels
//! One switched output per switchable node ([`Channel`]); the wire id is the enumeration's
//! value and the telemetry's bit in the channel masks. The FC (3, with the ADCS sensors,
//! wheels and magnetorquers) and the EPS (4) sit on unswitched outputs: they are never
//! switched. A channel that is off draws nothing, and its node's activities (transmitting,
//! heating, firing) draw nothing either.
//!
//! # Loads (defaults; every figure is a scenario setting)
//! | load | on | W | reasoning |
//! |---|---|---|---|
//! | FC + ADCS sensors + GPS | always | 1.60 | OBC MCU 0.4, GNSS receiver 0.8, sun sensors, magnetometer, IMU 0.4 |
//! | EPS itself | always | 0.40 | MCU, converters' quiescent draw, battery heater duty |
//! | reaction wheels | always | 4 x 0.10 + `c w^2` | electronics 0.1 W each; bearing and windage drag `c w^2`, c = 1.5e-6 W/(rad/s)^2: 0.41 W per wheel at 5000 rpm |
//! | magnetorquers | always | 1.0 W per A m^2, per axis | PWM drive from a fixed voltage: power in proportion to the duty, so to the dipole: 0.2 W per rod at 0.2 A m^2 |
//! | COMM1, COMM2 receiving | channel | 0.50 each | UHF transceiver RX (both radios powered: hot standby) |
//! | UHF transmitting | UHF TX duty | +3.5 | 1 W RF at ~30 % PA efficiency; on COMM1 when it is on, else COMM2 |
//! | ECU idle | channel | 0.30 | valve driver and pressure sensor electronics |
//! | thruster heaters | heater duty | +6.0 | propellant line and thruster pre-heat while armed |
//! | firing | firing duty | +4.0 | valve hold and thruster electronics |
//! | PC idle | channel | 0.60 | payload controller MCU, CAN transceivers, buffer memory |
//! | payloads 12-15 idle | channel | 0.50 each | a payload's own board between sessions (the payload's real figure belongs in the scenario) |
//! | S-band standby | channel | 1.20 | transmitter powered, not radiating |
//! | S-band transmitting | S-band TX duty | +9.0 | 2 W RF at ~22 % efficiency |
//!
//! With every channel on and nothing transmitting the platform draws 7.5 W (wheels at
//! zero speed). Orbit average in a 520 km SSO (35 % of the orbit in eclipse at beta 20 deg;
//! the crate's test `default_6u_in_a_520_km_sso_has_a_positive_balance_in_nadir`), the
//! default arrays give 14 / 18 / 20 W in nadir pointing at beta 0 / 20 / 40 deg and
//! 34 / 34 / 36 W in sun max power: the balance is positive in both with the payloads idle
//! (nadir gains about 10 % of charge per orbit from 60 %); an hour of S-band transmission
//! takes 9 Wh more (9.5 Wh from the battery in eclipse).

pub use icd::eps::{ALL_CHANNELS, CHANNELS, Channel};

/// The fraction of a step each switched activity was on (`platform::board::ActivityBoard::duty`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Duties {
    /// S-band transmitting.
    pub sband_tx: f64,
    /// COMM1's UHF radio transmitting.
    pub uhf_tx: f64,
    /// COMM2's UHF radio transmitting.
    pub uhf_tx_secondary: f64,
    /// Thruster heaters on.
    pub thruster_heater: f64,
    /// Thruster firing.
    pub firing: f64,
    /// Each channel's node held off by a power fault (indexed by [`Channel::id`]): the
    /// channel draws nothing for this fraction of the step.
    pub fault_off: [f64; CHANNELS],
}

/// What the loads depend on, for one step (the EPS assembles it from the truth and the
/// activity board; the channel states are its own).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LoadInputs {
    /// Reaction wheel speeds, rad/s.
    pub wheel_speed_rad_s: [f64; 4],
    /// Magnetorquer dipoles along body X, Y, Z, A m^2.
    pub mtq_dipole_am2: [f64; 3],
    /// Activity duties over the step.
    pub duties: Duties,
}

/// Consumption figures of every node by state (see the module doc's table).
#[derive(Debug, Clone, PartialEq)]
pub struct LoadConfig {
    /// FC with the ADCS sensors and the GNSS receiver, W.
    pub fc_w: f64,
    /// The EPS's own consumption, W.
    pub eps_w: f64,
    /// Electronics of one reaction wheel, W.
    pub wheel_idle_w: f64,
    /// Drag power coefficient of one wheel, W/(rad/s)^2.
    pub wheel_drag_w_per_rad2_s2: f64,
    /// Magnetorquer power per unit |dipole|, per axis, W/(A m^2).
    pub mtq_w_per_am2: f64,
    /// One COMM receiving, W.
    pub comm_rx_w: f64,
    /// Extra while the UHF transmits, W.
    pub uhf_tx_w: f64,
    /// ECU idle, W.
    pub ecu_idle_w: f64,
    /// Extra while the thruster heaters are on, W.
    pub thruster_heater_w: f64,
    /// Extra while firing, W.
    pub firing_w: f64,
    /// PC idle, W.
    pub pc_idle_w: f64,
    /// Payloads 12-15 idle, W.
    pub payload_w: [f64; 4],
    /// S-band standby, W.
    pub sband_standby_w: f64,
    /// Extra while the S-band transmits, W.
    pub sband_tx_w: f64,
}

impl Default for LoadConfig {
    /// The module doc's table.
    fn default() -> Self {
        LoadConfig {
            fc_w: 1.6,
            eps_w: 0.4,
            wheel_idle_w: 0.1,
            wheel_drag_w_per_rad2_s2: 1.5e-6,
            mtq_w_per_am2: 1.0,
            comm_rx_w: 0.5,
            uhf_tx_w: 3.5,
            ecu_idle_w: 0.3,
            thruster_heater_w: 6.0,
            firing_w: 4.0,
            pc_idle_w: 0.6,
            payload_w: [0.5; 4],
            sband_standby_w: 1.2,
            sband_tx_w: 9.0,
        }
    }
}

/// Where the power goes in one step, W.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LoadBreakdown {
    /// The FC's output: FC, sensors, wheels, magnetorquers.
    pub fc_w: f64,
    /// The EPS itself.
    pub eps_w: f64,
    /// Each channel (indexed by [`Channel::id`]; 0 when off).
    pub channel_w: [f64; CHANNELS],
}

impl LoadBreakdown {
    /// Everything, W.
    pub fn total_w(&self) -> f64 {
        self.fc_w + self.eps_w + self.channel_w.iter().sum::<f64>()
    }
}

impl LoadConfig {
    /// The loads with channels `on` (a [`Channel`] mask) and inputs `x`.
    pub fn loads(&self, on: u16, x: &LoadInputs) -> LoadBreakdown {
        let is_on = |c: Channel| on & c.bit() != 0;
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        let duty = |d: f64| finite(d).clamp(0.0, 1.0);
        let wheels: f64 = x
            .wheel_speed_rad_s
            .iter()
            .map(|&w| self.wheel_idle_w + self.wheel_drag_w_per_rad2_s2 * finite(w) * finite(w))
            .sum();
        let mtq: f64 = x
            .mtq_dipole_am2
            .iter()
            .map(|&m| self.mtq_w_per_am2 * finite(m).abs())
            .sum();
        let mut b = LoadBreakdown {
            fc_w: self.fc_w + wheels + mtq,
            eps_w: self.eps_w,
            channel_w: [0.0; CHANNELS],
        };
        let d = &x.duties;
        for c in Channel::ALL {
            if !is_on(c) {
                continue;
            }
            let w = match c {
                Channel::Comm1 => self.comm_rx_w + self.uhf_tx_w * duty(d.uhf_tx),
                Channel::Comm2 => self.comm_rx_w + self.uhf_tx_w * duty(d.uhf_tx_secondary),
                Channel::Ecu => {
                    self.ecu_idle_w
                        + self.thruster_heater_w * duty(d.thruster_heater)
                        + self.firing_w * duty(d.firing)
                }
                Channel::Pc => self.pc_idle_w,
                Channel::Payload12 => self.payload_w[0],
                Channel::Payload13 => self.payload_w[1],
                Channel::Payload14 => self.payload_w[2],
                Channel::Payload15 => self.payload_w[3],
                Channel::Sband => self.sband_standby_w + self.sband_tx_w * duty(d.sband_tx),
            };
            let id = usize::from(c.id());
            let held = d.fault_off.get(id).copied().map_or(0.0, duty);
            if let Some(slot) = b.channel_w.get_mut(id) {
                *slot = if held > 0.0 { w * (1.0 - held) } else { w };
            }
        }
        b
    }
}

snap::fields!(LoadConfig {
    fc_w,
    eps_w,
    wheel_idle_w,
    wheel_drag_w_per_rad2_s2,
    mtq_w_per_am2,
    comm_rx_w,
    uhf_tx_w,
    ecu_idle_w,
    thruster_heater_w,
    firing_w,
    pc_idle_w,
    payload_w,
    sband_standby_w,
    sband_tx_w
});
snap::fields!(LoadBreakdown {
    fc_w,
    eps_w,
    channel_w
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn channel_ids_bits_and_nodes() {
        for (i, c) in Channel::ALL.into_iter().enumerate() {
            assert_eq!(usize::from(c.id()), i);
            assert_eq!(Channel::from_id(c.id()), Some(c));
            assert_eq!(c.bit(), 1 << i);
            assert_eq!(Channel::from_name(&c.name().to_lowercase()), Some(c));
        }
        assert_eq!(Channel::from_id(9), None);
        assert_eq!(Channel::of_node(6), Some(Channel::Pc));
        assert_eq!(Channel::of_node(3), None, "the FC is never switched");
        assert_eq!(Channel::of_node(4), None, "nor the EPS");
        assert_eq!(ALL_CHANNELS, 0x1ff);
    }

    #[test]
    fn idle_platform_draws_the_table_total() {
        let l = LoadConfig::default();
        let b = l.loads(ALL_CHANNELS, &LoadInputs::default());
        // 1.6 + 0.4 + 0.4 (wheels) + 2 x 0.5 + 0.3 + 0.6 + 4 x 0.5 + 1.2
        assert!((b.total_w() - 7.5).abs() < 1e-12, "{}", b.total_w());
        let none = l.loads(0, &LoadInputs::default());
        assert!((none.total_w() - 2.4).abs() < 1e-12);
        assert_eq!(none.channel_w, [0.0; CHANNELS]);
    }

    #[test]
    fn activities_cost_power_only_on_a_powered_channel() {
        let l = LoadConfig::default();
        let x = LoadInputs {
            wheel_speed_rad_s: [500.0, -500.0, 0.0, 0.0],
            mtq_dipole_am2: [0.2, -0.1, 0.0],
            duties: Duties {
                sband_tx: 0.5,
                uhf_tx: 1.0,
                uhf_tx_secondary: 0.5,
                thruster_heater: 1.0,
                firing: 0.25,
                fault_off: [0.0; CHANNELS],
            },
        };
        let b = l.loads(ALL_CHANNELS, &x);
        assert!((b.fc_w - (1.6 + 0.4 + 2.0 * 1.5e-6 * 250_000.0 + 0.3)).abs() < 1e-12);
        assert!((b.channel_w[8] - (1.2 + 4.5)).abs() < 1e-12);
        // Each radio's transmissions on its own channel.
        assert!((b.channel_w[0] - 4.0).abs() < 1e-12);
        assert!((b.channel_w[1] - (0.5 + 1.75)).abs() < 1e-12);
        assert!((b.channel_w[2] - (0.3 + 6.0 + 1.0)).abs() < 1e-12);
        // COMM1 off: nothing on its channel; COMM2's own transmissions on its own.
        let b = l.loads(ALL_CHANNELS & !Channel::Comm1.bit(), &x);
        assert_eq!(b.channel_w[0], 0.0);
        assert!((b.channel_w[1] - (0.5 + 1.75)).abs() < 1e-12);
        // ECU and S-band off: no heater, no firing, no S-band.
        let b = l.loads(
            ALL_CHANNELS & !Channel::Ecu.bit() & !Channel::Sband.bit(),
            &x,
        );
        assert_eq!((b.channel_w[2], b.channel_w[8]), (0.0, 0.0));
    }
}
