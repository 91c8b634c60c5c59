//! `[fc]`: the flight computer's and its ADCS's settings as a scenario writes them (docs/scenarios.md, "The FC").

use schemars::JsonSchema;
use serde::Deserialize;

use crate::dur::Dur;
use twin_core::network::NetworkSpec;
use twin_core::network::NodeRef;

/// The flight computer's settings (docs/scenarios.md, "The FC").
#[derive(Debug, Clone, PartialEq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcSpec {
    /// ADCS loop rate, Hz (default 10).
    #[serde(default)]
    pub adcs_hz: Option<u32>,
    /// Truth and ADCS snapshot rate for recording and expectations, Hz (default 1; 0: none).
    #[serde(default)]
    pub publish_hz: Option<u32>,
    /// Target mode commanded at the start (as by ATCMDSET at time zero; default `detumble`).
    #[serde(default)]
    pub mode: Option<ModeName>,
    /// Target attitude (r, i, j, k) for the fixed-quaternion modes (as by ATCATSET).
    #[serde(default)]
    pub target_attitude: Option<[f64; 4]>,
    /// Target point (as by ATCPTSET): lat deg, lon deg, alt m for `earth-target`, an ECI
    /// direction for `eci-vector`.
    #[serde(default)]
    pub target_point: Option<[f64; 3]>,
    /// Whether the FC holds the satellite's TLE at boot (default true).
    #[serde(default)]
    pub tle_uploaded: Option<bool>,
    /// Whether the GPS receiver gives fixes (default false).
    #[serde(default)]
    pub gps: Option<bool>,
    /// Initial body rate magnitude, deg/s (default 0).
    #[serde(default)]
    pub initial_rate_deg_s: Option<f64>,
    /// Axis of the initial rate, body frame (default: a random axis drawn from the seed).
    #[serde(default)]
    pub initial_rate_axis: Option<[f64; 3]>,
    /// Initial attitude, body in ECI (r, i, j, k) (default: drawn from the seed).
    #[serde(default)]
    pub initial_attitude: Option<[f64; 4]>,
    /// Initial wheel speeds, rpm (default 0).
    #[serde(default)]
    pub initial_wheel_rpm: Option<[f64; 4]>,
    /// Inertia tensor, kg m^2, rows (default the 6U box diag(0.10, 0.13, 0.05)).
    #[serde(default)]
    pub inertia_kg_m2: Option<[[f64; 3]; 3]>,
    /// Residual magnetic dipole, body frame, A m^2 (default [0.002, 0.002, 0.005]).
    #[serde(default)]
    pub residual_dipole_am2: Option<[f64; 3]>,
    /// Aerodynamic drag torque (default true).
    #[serde(default)]
    pub drag: Option<bool>,
    /// Gravity-gradient torque (default true).
    #[serde(default)]
    pub gravity_gradient: Option<bool>,
    /// Solar panel normal for sun max power, body frame (default +X).
    #[serde(default)]
    pub panel_normal_body: Option<[f64; 3]>,
    /// Port numbers of the FC's services.
    #[serde(default)]
    pub ports: Option<FcPortsSpec>,
    /// Mission-controller script lines (ICD 1.5) submitted onboard at their times.
    #[serde(default)]
    pub scripts: Vec<FcScriptSpec>,
    /// Sensor and wheel faults.
    #[serde(default)]
    pub faults: Vec<FcFaultSpec>,
    /// When the FC goes SAFE on a low battery (`nodes_fc::safe`).
    #[serde(default)]
    pub safe: Option<FcSafeSpec>,
    /// Periodic real-time telemetry from boot (as TMPERSET sets it).
    #[serde(default)]
    pub periodic: Option<FcPeriodicSpec>,
}

/// `[fc.periodic]`: the FC sends chosen telemetry to a node and port at a period.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcPeriodicSpec {
    /// The destination node (a ground station or a payload).
    pub to: NodeRef,
    /// Its port, 7-63.
    pub port: u8,
    /// The period, 100 ms to 1 h.
    pub every: Dur,
    /// Telemetry commands by name: TMGEN, TMATP, TMACD, TMSENS, TMRAWSENS, TMALL.
    pub telemetry: Vec<String>,
}

impl FcPeriodicSpec {
    /// The TMPERSET contents, or the first field that is wrong (its key and why).
    pub fn periodic(
        &self,
        net: &NetworkSpec,
    ) -> Result<nodes_fc::wire::Periodic, (&'static str, String)> {
        const NAMES: [&str; 6] = ["TMGEN", "TMATP", "TMACD", "TMSENS", "TMRAWSENS", "TMALL"];
        let dst = net.resolve(&self.to).map_err(|e| ("to", e.to_string()))?;
        let mut mask = 0u8;
        for name in &self.telemetry {
            let i = NAMES
                .iter()
                .position(|n| n.eq_ignore_ascii_case(name))
                .ok_or_else(|| {
                    (
                        "telemetry",
                        format!("`{name}` is not one of {}", NAMES.join(", ")),
                    )
                })?;
            mask |= 1 << i;
        }
        let p = nodes_fc::wire::Periodic {
            dst,
            dport: self.port,
            period_ms: u32::try_from(self.every.0.as_millis()).unwrap_or(u32::MAX),
            mask,
        };
        match p.out_of_range(platform::addr::FC) {
            None if p.period_ms > 0 => Ok(p),
            None | Some("period_ms") => Err(("every", "must be 100 ms to 1 h".into())),
            Some("dst") => Err(("to", "must be a node other than the FC".into())),
            Some("dport") => Err(("port", "must be 7-63 (0-6 are the service ports)".into())),
            Some(_) => Err((
                "telemetry",
                "must name at least one telemetry command".into(),
            )),
        }
    }
}

/// `[fc.safe]`: the FC's low-battery SAFE state.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcSafeSpec {
    /// State of charge below which the battery is low, 0-1 (default 0.15).
    #[serde(default)]
    pub enter_soc: Option<f64>,
    /// State of charge at which it is no longer low, 0-1, not below `enter_soc` (default
    /// 0.30).
    #[serde(default)]
    pub exit_soc: Option<f64>,
    /// How often the FC reads the EPS's TMEPS (default 30 s; "0s": never, no low-battery
    /// SAFE).
    #[serde(default)]
    pub eps_poll: Option<Dur>,
}

impl FcSafeSpec {
    pub fn config(&self) -> nodes_fc::safe::SafeConfig {
        let d = nodes_fc::safe::SafeConfig::default();
        nodes_fc::safe::SafeConfig {
            enter_soc: self.enter_soc.unwrap_or(d.enter_soc),
            exit_soc: self.exit_soc.unwrap_or(d.exit_soc),
            eps_poll: match self.eps_poll {
                Some(p) => Some(p.0).filter(|p| !p.is_zero()),
                None => d.eps_poll,
            },
            ..d
        }
    }
}

/// Target modes by name (docs/protocol.md, "Target modes").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum ModeName {
    /// 0.
    Idle,
    /// 1.
    Detumble,
    /// 2.
    Velocity,
    /// 3.
    Nadir,
    /// 4.
    SunMaxPower,
    /// 5.
    EarthTarget,
    /// 6.
    EciVector,
    /// 7.
    FixedEci,
    /// 8.
    FixedLvlh,
    /// 9.
    FixedTnw,
}

impl ModeName {
    /// The wire enumeration value.
    pub fn mode(self) -> nodes_fc::wire::TargetMode {
        use nodes_fc::wire::TargetMode as M;
        match self {
            ModeName::Idle => M::Idle,
            ModeName::Detumble => M::Detumble,
            ModeName::Velocity => M::VelocityPointing,
            ModeName::Nadir => M::Nadir,
            ModeName::SunMaxPower => M::SunMaxPower,
            ModeName::EarthTarget => M::EarthTarget,
            ModeName::EciVector => M::EciVector,
            ModeName::FixedEci => M::FixedEci,
            ModeName::FixedLvlh => M::FixedLvlh,
            ModeName::FixedTnw => M::FixedTnw,
        }
    }
}

/// FC port overrides (INTERPRETATION.md section 4: every port overridable).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcPortsSpec {
    /// Telemetry (default 10).
    #[serde(default)]
    pub telemetry: Option<u8>,
    /// RTC (default 11).
    #[serde(default)]
    pub rtc: Option<u8>,
    /// Attitude target control (default 12).
    #[serde(default)]
    pub attitude: Option<u8>,
    /// Mission-controller scripts (default 13).
    #[serde(default)]
    pub scripts: Option<u8>,
}

/// A script line submitted onboard at a time.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcScriptSpec {
    /// When it is submitted (simulated time since the start).
    pub at: Dur,
    /// The ICD 1.5 line, for example `adcs 1577836800 1577836920 pointECI 1 0 0 0`.
    pub line: String,
}

/// A sensor or wheel fault.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FcFaultSpec {
    /// When it starts.
    pub at: Dur,
    /// When it is cleared (default: never).
    #[serde(default)]
    pub until: Option<Dur>,
    /// The sensor: `gyro`, `magnetometer`, `sun-sensors`, `css+x` ... `css-z`,
    /// `accelerometer`, `gps`.
    #[serde(default)]
    pub sensor: Option<String>,
    /// The wheel, 0-3.
    #[serde(default)]
    pub wheel: Option<u8>,
    /// Sensors: `dead`, `stuck`, `bias:<value>`, `noisy:<factor>`; wheels: `stuck`, `off`.
    pub fault: String,
}
