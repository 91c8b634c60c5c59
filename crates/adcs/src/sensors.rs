//! The FC's attitude and housekeeping sensors: a pure, deterministic model with seeded noise.
//!
//! [`Sensors::sample`] turns the truth ([`SensorInputs`]: attitude, rate, field, Sun,
//! position, velocity, non-gravitational acceleration) into what the flight computer reads
//! ([`SensorReadings`]), the way a real FC's pipeline does: each sensor produces **raw**
//! counts at its native resolution (the TMRAWSENS layout, docs/protocol.md "TMRAWSENS"),
//! saturating at its range, and the **processed** values (TMSENS, and what the ADCS uses) are
//! computed from those quantised counts (`raw * LSB`), never from the truth directly.
//!
//! # Models (all vectors in the body frame, BCF, unless named otherwise)
//! - **Gyroscope**: `w_meas = w_true + b + n`, with `n` white, [`SensorConfig::gyro_noise_rad_s`]
//!   1-sigma per sample per axis, and `b` the bias: the configured turn-on bias
//!   ([`SensorConfig::gyro_bias_initial_rad_s`], plus an optional per-seed random part of
//!   [`SensorConfig::gyro_bias_turn_on_sigma_rad_s`], drawn once in [`Sensors::new`]) that then
//!   follows a random walk, `b += sigma_rrw sqrt(dt) N(0, 1)` per axis each sample.
//!   Raw 0.01 deg/s per LSB (range +-327.67 deg/s).
//! - **Magnetometer**: `B_meas = R_body_from_eci B_eci + bias + n`, noise 1-sigma per axis.
//!   Raw 10 nT per LSB (range +-327 670 nT).
//! - **Coarse sun sensors**: six photodiodes with normals +X -X +Y -Y +Z -Z (that order
//!   everywhere), cosine response: `count = 4095 f cos(theta) + n`, with `theta` the angle
//!   between the Sun and the normal, `f` the visible fraction of the solar disc (0 in umbra,
//!   between 0 and 1 in penumbra), and zero outside the field of view (`theta` greater than
//!   [`SensorConfig::css_fov_half_angle_rad`]: a hard cut, as a housing baffle). Noise is
//!   added to every face, lit or dark, and the count is rounded and clamped to 0..=4095
//!   (12-bit ADC). The FC's sun vector is the difference of opposite faces,
//!   `(c+x - c-x, c+y - c-y, c+z - c-z)`, normalised; it is `None` when the sum of the six
//!   counts is below [`SensorConfig::css_min_total_counts`] (eclipse, all faces blind or
//!   dead). **Not modelled**: Earth albedo (a real nadir-facing face sees up to about 30 % of
//!   the solar flux reflected by the Earth, which biases the sun vector towards nadir), the
//!   1/r^2 variation of the solar flux over the year (+-3.3 %; it scales all faces alike and
//!   leaves the direction unchanged), and any non-cosine (Fresnel) roll-off near grazing.
//!   With the 80 degree field of view, a Sun direction with a component smaller than
//!   cos(80 deg) = 0.17 reads zero on that axis: the recovered direction then errs by up to
//!   about 10 degrees per such axis; that is the geometry of the sensor, not noise.
//! - **Accelerometer**: in free fall it reads only the non-gravitational acceleration
//!   (drag, thrust), given as an input, plus bias and noise. Raw 1 mg per LSB with
//!   g0 = 9.80665 m/s^2 (range +-32.767 g).
//! - **GPS** (off by default): ECI J2000 position and velocity plus white noise per axis.
//!   Real receiver errors are correlated in time over minutes; white noise is the simple
//!   bound. No raw counts (the receiver reports engineering units).
//! - **Temperatures**: six channels (index order of TMSENS `sensor_temps` and TMRAWSENS
//!   `temps`, see [`TEMP_CHANNELS`]): 0 IMU (gyro and accelerometer), 1 magnetometer,
//!   2 +X panel, 3 -X panel, 4 reaction-wheel assembly, 5 battery; plus the MCU temperature
//!   for TMGEN. Each is a first-order lag `T += (T_eq - T)(1 - exp(-dt / tau))` toward an
//!   equilibrium `T_eq = T_eclipse + f (T_sunlit - T_eclipse + gain max(0, s . n_face))`
//!   ([`ThermalChannel`]), with `f` the visible solar fraction and `s` the body Sun
//!   direction: the two panels are hotter when the Sun is on their face. The sensor reads
//!   `T + n`, raw 0.1 degrees C per LSB.
//!
//! # Time
//! `dt_s` is the simulated time since the previous sample (0 for the first): each call first
//! advances the gyro bias walk and the thermal states by `dt_s`, then samples. Noise is
//! 1-sigma **per sample**, independent of `dt_s` (a sensor's output filter is set for its
//! sample rate; the ADCS samples at 10 Hz).
//!
//! # Determinism and faults
//! Same seed, same configuration and same inputs give identical readings. Each sensor draws
//! from its own ChaCha8 stream (the run seed, stream number per sensor: gyro 1,
//! magnetometer 2, sun sensors 3, accelerometer 4, GPS 5, temperatures 6), and each draws
//! the same numbers in the same order every sample whatever its fault or enable state, so a
//! fault (or the GPS switch) never changes another sensor's noise, and clearing a fault
//! resumes the sequence it would have had. Gaussian noise is Box-Muller from two 53-bit
//! uniforms.
//!
//! Faults ([`SensorFault`], set per [`SensorId`]): `Dead` gives no output (processed `None`,
//! raw zeros; a dead sun-sensor face reads 0 counts); `Stuck` repeats the output of the
//! previous sample (raw and processed; a sensor stuck before its first sample holds its
//! first output); `Bias(x)` adds `x` to every axis before quantisation, in the processed
//! unit (rad/s, nT, m/s^2, counts, and metres on the GPS position only); `Noisy(k)`
//! multiplies the noise 1-sigma by `|k|` (both GPS noises). A face's own fault
//! (`SunSensor(i)`) takes precedence over the all-faces fault (`SunSensors`). The
//! temperatures have no faults.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use icd::fc::{TmRawSens, TmSens};
use nalgebra::{UnitQuaternion, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_core::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

/// Standard gravity, m/s^2 (CGPM 1901; the accelerometer's 1 mg LSB is g0 / 1000).
pub const G0_M_S2: f64 = 9.806_65;
/// Gyroscope raw resolution: 0.01 deg/s per LSB (TMRAWSENS, docs/protocol.md), in rad/s.
pub const GYRO_LSB_RAD_S: f64 = 0.01 * core::f64::consts::PI / 180.0;
/// Accelerometer raw resolution: 1 mg per LSB (TMRAWSENS), m/s^2.
pub const ACC_LSB_M_S2: f64 = 1.0e-3 * G0_M_S2;
/// Magnetometer raw resolution: 10 nT per LSB (TMRAWSENS), nT.
pub const MAG_LSB_NT: f64 = 10.0;
/// Temperature raw resolution: 0.1 degrees C per LSB (TMRAWSENS), degrees C.
pub const TEMP_LSB_C: f64 = 0.1;
/// Coarse sun sensor full scale: 12-bit ADC, full sun on the normal (TMRAWSENS).
pub const CSS_FULL_SCALE_COUNTS: u16 = 4095;

/// The six temperature channels, in TMSENS/TMRAWSENS order.
pub const TEMP_CHANNELS: [&str; 6] = [
    "imu",
    "magnetometer",
    "panel+x",
    "panel-x",
    "reaction-wheels",
    "battery",
];
/// Temperature channel index: IMU (gyroscope and accelerometer).
pub const TEMP_IMU: usize = 0;
/// Temperature channel index: magnetometer.
pub const TEMP_MAGNETOMETER: usize = 1;
/// Temperature channel index: +X panel.
pub const TEMP_PANEL_PX: usize = 2;
/// Temperature channel index: -X panel.
pub const TEMP_PANEL_MX: usize = 3;
/// Temperature channel index: reaction-wheel assembly.
pub const TEMP_RWA: usize = 4;
/// Temperature channel index: battery.
pub const TEMP_BATTERY: usize = 5;

/// The sun-sensor face names, in +X -X +Y -Y +Z -Z order (the `SensorId` text form).
pub const CSS_NAMES: [&str; 6] = ["css+x", "css-x", "css+y", "css-y", "css+z", "css-z"];

/// The sun-sensor face normals in BCF, in +X -X +Y -Y +Z -Z order.
pub fn css_normal_body(i: usize) -> Vector3<f64> {
    let s = if i % 2 == 0 { 1.0 } else { -1.0 };
    match (i / 2) % 3 {
        0 => Vector3::new(s, 0.0, 0.0),
        1 => Vector3::new(0.0, s, 0.0),
        _ => Vector3::new(0.0, 0.0, s),
    }
}

/// First-order thermal model of one temperature channel (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalChannel {
    /// Temperature at the first sample, degrees C.
    pub initial_c: f64,
    /// Equilibrium in full eclipse, degrees C.
    pub eclipse_equilibrium_c: f64,
    /// Equilibrium in full sun with the Sun off `face_normal_body`, degrees C.
    pub sunlit_equilibrium_c: f64,
    /// Extra equilibrium with full sun along `face_normal_body`, scaled by the cosine, deg C.
    pub face_sun_gain_c: f64,
    /// Outward normal of the face this channel sits on, BCF (zero for internal units).
    pub face_normal_body: Vector3<f64>,
    /// Time constant, s (zero or less: the temperature is its equilibrium at once).
    pub time_constant_s: f64,
}

impl ThermalChannel {
    /// An internal unit: no face, equilibria `eclipse_c` / `sunlit_c`, time constant `tau_s`,
    /// starting at 20 degrees C.
    pub fn internal(eclipse_c: f64, sunlit_c: f64, tau_s: f64) -> Self {
        Self {
            initial_c: 20.0,
            eclipse_equilibrium_c: eclipse_c,
            sunlit_equilibrium_c: sunlit_c,
            face_sun_gain_c: 0.0,
            face_normal_body: Vector3::zeros(),
            time_constant_s: tau_s,
        }
    }

    /// The equilibrium for a visible solar fraction and a body Sun direction, degrees C.
    pub fn equilibrium_c(&self, visible_fraction: f64, sun_body_unit: &Vector3<f64>) -> f64 {
        let cos = sun_body_unit.dot(&self.face_normal_body).max(0.0);
        self.eclipse_equilibrium_c
            + visible_fraction
                * (self.sunlit_equilibrium_c - self.eclipse_equilibrium_c
                    + self.face_sun_gain_c * cos)
    }

    /// The temperature after `dt_s` from `t_c` toward `eq_c` (exact for a constant `eq_c`).
    fn advance(&self, t_c: f64, eq_c: f64, dt_s: f64) -> f64 {
        if self.time_constant_s <= 0.0 {
            return eq_c;
        }
        t_c + (eq_c - t_c) * (1.0 - (-dt_s / self.time_constant_s).exp())
    }
}

/// Sensor parameters. `Default` is a plausible 6U ADCS sensor set; each default's source is
/// in its comment.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorConfig {
    /// Gyro white noise, 1-sigma per sample per axis, rad/s.
    pub gyro_noise_rad_s: f64,
    /// Gyro turn-on bias, rad/s (fixed, the same for every seed).
    pub gyro_bias_initial_rad_s: Vector3<f64>,
    /// Per-seed random part of the turn-on bias, 1-sigma per axis, rad/s (drawn in `new`).
    pub gyro_bias_turn_on_sigma_rad_s: f64,
    /// Gyro bias random walk (rate random walk), rad/s per sqrt(s).
    pub gyro_bias_walk_rad_s_per_sqrt_s: f64,
    /// Magnetometer white noise, 1-sigma per axis, nT.
    pub mag_noise_nt: f64,
    /// Magnetometer bias (residual hard iron), nT.
    pub mag_bias_nt: Vector3<f64>,
    /// Sun-sensor field-of-view half-angle from the face normal, rad.
    pub css_fov_half_angle_rad: f64,
    /// Sun-sensor noise, 1-sigma per face, counts.
    pub css_noise_counts: f64,
    /// Sum of the six counts below which the FC reports no sun vector, counts.
    pub css_min_total_counts: f64,
    /// Accelerometer white noise, 1-sigma per axis, m/s^2.
    pub acc_noise_m_s2: f64,
    /// Accelerometer bias, m/s^2.
    pub acc_bias_m_s2: Vector3<f64>,
    /// Whether a GPS receiver is fitted and on.
    pub gps_enabled: bool,
    /// GPS position noise, 1-sigma per ECI axis, m.
    pub gps_position_noise_m: f64,
    /// GPS velocity noise, 1-sigma per ECI axis, m/s.
    pub gps_velocity_noise_m_s: f64,
    /// Earth-horizon sensor boresight, body, unit.
    pub horizon_boresight_body: Vector3<f64>,
    /// Earth-horizon sensor field of view, half-angle, rad.
    pub horizon_fov_half_angle_rad: f64,
    /// Earth-horizon sensor nadir direction noise, 1-sigma per axis, rad, with the whole
    /// limb in view (three times that with part of it).
    pub horizon_noise_rad: f64,
    /// The six temperature channels ([`TEMP_CHANNELS`] order).
    pub thermal: [ThermalChannel; 6],
    /// The MCU temperature (TMGEN).
    pub mcu_thermal: ThermalChannel,
    /// Temperature sensor noise, 1-sigma, degrees C.
    pub temp_noise_c: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        let deg = core::f64::consts::PI / 180.0;
        let panel = |normal: Vector3<f64>| ThermalChannel {
            initial_c: 20.0,
            eclipse_equilibrium_c: -40.0,
            sunlit_equilibrium_c: 0.0,
            face_sun_gain_c: 70.0,
            face_normal_body: normal,
            time_constant_s: 1200.0,
        };
        Self {
            // 0.01 deg/s per 0.1 s sample = angle random walk 0.01 * sqrt(0.1) deg/sqrt(s)
            // = 0.19 deg/sqrt(h): a good MEMS gyro (ADIS16460 datasheet: 0.12 deg/sqrt(h);
            // consumer BMG160 class: about 0.3 deg/sqrt(h)). Equals one raw LSB.
            gyro_noise_rad_s: 0.01 * deg,
            // Turn-on bias of order 0.1 deg/s per axis (MEMS datasheets give +-0.1 to
            // +-0.5 deg/s after calibration); different per axis so an estimator that mixes
            // axes is caught.
            gyro_bias_initial_rad_s: Vector3::new(0.10, -0.08, 0.06) * deg,
            // Fixed by default: the same bias for every seed, so runs differ only by noise.
            gyro_bias_turn_on_sigma_rad_s: 0.0,
            // 1e-5 deg/s/sqrt(s): the bias wanders about 0.0008 deg/s (2.7 deg/h) in one
            // 95-minute orbit, a tactical-grade MEMS gyro of the kind 6U ADCS units carry
            // (Sensonor STIM210: 0.5 deg/h bias instability; ADIS16460: 8 deg/h). With a
            // consumer-grade walk (1e-4) the eclipse estimate drifts by degrees (measured).
            gyro_bias_walk_rad_s_per_sqrt_s: 1.0e-5 * deg,
            // 75 nT: between a PNI RM3100 (about 15 nT at 200 cycle counts) and an HMC5883L
            // class part (about 200 nT), plus unmodelled bus-current disturbances.
            mag_noise_nt: 75.0,
            // Residual hard-iron bias after ground calibration: a few hundred nT.
            mag_bias_nt: Vector3::new(300.0, -200.0, 150.0),
            // 90 degrees: bare cosine photodiodes (hemispherical view). A baffled 80-degree
            // sensor is a setting away, but the six-face difference then loses the component
            // of a sun near a face's edge (errors up to ~14 deg; measured in the tests).
            css_fov_half_angle_rad: 90.0 * deg,
            // 10 counts = 0.25 % of full scale: 12-bit ADC noise plus photodiode shot noise.
            css_noise_counts: 10.0,
            // 10 % of full scale: far above the dark noise of six faces (about 24 counts on
            // average with 10-count noise clamped at zero), and far below the smallest sunlit
            // total (the Sun is within 54.7 degrees of some face: at least 2364 counts).
            css_min_total_counts: 0.1 * f64::from(CSS_FULL_SCALE_COUNTS),
            // 2 mg: MEMS accelerometer noise density of about 200 ug/sqrt(Hz) over a 100 Hz
            // internal bandwidth (LSM6DS/BMI160 class), i.e. two raw LSB.
            acc_noise_m_s2: 2.0e-3 * G0_M_S2,
            // Zero-g offset after calibration of order 10 mg (datasheets: +-20 to +-40 mg).
            acc_bias_m_s2: Vector3::new(10.0, -5.0, 8.0) * 1.0e-3 * G0_M_S2,
            // The M6P's GPS is an option (ICD 1.2); the default scenario flies without one.
            gps_enabled: false,
            // 10 m and 0.1 m/s 1-sigma: a spaceborne single-frequency receiver's navigation
            // solution (NovAtel OEM7 / SkyTraq Venus838 class, unaided).
            gps_position_noise_m: 10.0,
            gps_velocity_noise_m_s: 0.1,
            // A static infrared Earth sensor (thermopile array) on the +Z face, the face that
            // nadir pointing turns to the Earth: an 80-degree half-angle sees the whole limb
            // (the Earth's angular radius is 66-70 degrees at 400-700 km) within about
            // 10 degrees of nadir, part of it up to 150 degrees off. 0.2 degrees 1-sigma with
            // the whole limb: the class of CubeSense Earth or MAI-SES sensors in their specs.
            horizon_boresight_body: Vector3::z(),
            horizon_fov_half_angle_rad: 80.0 * deg,
            horizon_noise_rad: 0.2 * deg,
            thermal: [
                // IMU on the ADCS board inside the bus: swings about 10 degrees, slow.
                ThermalChannel::internal(15.0, 25.0, 3000.0),
                // Magnetometer, also internal but near the structure wall.
                ThermalChannel::internal(10.0, 22.0, 2500.0),
                // Body-mounted panels: -40 C toward the end of eclipse, about 70 C facing the
                // Sun, 20-minute time constant: the classic LEO panel swing (-40 to +70 C).
                panel(Vector3::x()),
                panel(-Vector3::x()),
                // Reaction-wheel assembly: internal, heavy (motor heat not modelled).
                ThermalChannel::internal(18.0, 28.0, 4000.0),
                // Battery: heavy and heater-kept above about 10 C.
                ThermalChannel::internal(12.0, 20.0, 6000.0),
            ],
            // MCU: self-heated, a little above the bus average.
            mcu_thermal: ThermalChannel::internal(25.0, 32.0, 2000.0),
            // 0.1 C: thermistor plus 12-bit ADC; one raw LSB.
            temp_noise_c: 0.1,
        }
    }
}

/// A sensor a fault can be set on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SensorId {
    /// The three-axis gyroscope.
    Gyro,
    /// The three-axis magnetometer.
    Magnetometer,
    /// One coarse sun-sensor face, 0..6 in +X -X +Y -Y +Z -Z order.
    SunSensor(u8),
    /// All six coarse sun-sensor faces.
    SunSensors,
    /// The three-axis accelerometer.
    Accelerometer,
    /// The GPS receiver.
    Gps,
    /// The Earth-horizon sensor.
    Horizon,
}

impl SensorId {
    /// The text names [`FromStr`] accepts, in [`SensorId`] order.
    pub const NAMES: [&'static str; 12] = [
        "gyro",
        "magnetometer",
        "css+x",
        "css-x",
        "css+y",
        "css-y",
        "css+z",
        "css-z",
        "sun-sensors",
        "accelerometer",
        "gps",
        "horizon",
    ];

    /// Whether the id names a real sensor (a sun-sensor face index below 6).
    pub fn is_valid(&self) -> bool {
        !matches!(self, SensorId::SunSensor(i) if *i >= 6)
    }
}

impl fmt::Display for SensorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SensorId::Gyro => f.write_str("gyro"),
            SensorId::Magnetometer => f.write_str("magnetometer"),
            SensorId::SunSensor(i) => match CSS_NAMES.get(usize::from(*i)) {
                Some(n) => f.write_str(n),
                None => write!(f, "css#{i}"),
            },
            SensorId::SunSensors => f.write_str("sun-sensors"),
            SensorId::Accelerometer => f.write_str("accelerometer"),
            SensorId::Gps => f.write_str("gps"),
            SensorId::Horizon => f.write_str("horizon"),
        }
    }
}

/// Why a sensor name or fault did not parse; the message says what is accepted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParseSensorError(String);

impl fmt::Display for ParseSensorError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ParseSensorError {}

impl FromStr for SensorId {
    type Err = ParseSensorError;

    /// Parse a sensor name (ASCII case-insensitive, surrounding blanks ignored).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let name = s.trim().to_ascii_lowercase();
        if let Some(i) = CSS_NAMES.iter().position(|n| *n == name) {
            // i < 6: the cast cannot truncate.
            return Ok(SensorId::SunSensor(i as u8));
        }
        match name.as_str() {
            "gyro" => Ok(SensorId::Gyro),
            "magnetometer" => Ok(SensorId::Magnetometer),
            "sun-sensors" => Ok(SensorId::SunSensors),
            "accelerometer" => Ok(SensorId::Accelerometer),
            "gps" => Ok(SensorId::Gps),
            "horizon" => Ok(SensorId::Horizon),
            _ => Err(ParseSensorError(format!(
                "unknown sensor `{}`: expected one of {}",
                s.trim(),
                SensorId::NAMES.join(", ")
            ))),
        }
    }
}

/// A fault injected into a sensor (see the module doc for exactly what each does).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorFault {
    /// No output: processed value `None`, raw zeros.
    Dead,
    /// Holds the last value it produced.
    Stuck,
    /// Extra bias on every axis in the sensor's processed unit: rad/s, nT, m/s^2, counts, m.
    Bias(f64),
    /// Noise 1-sigma multiplied by the factor.
    Noisy(f64),
}

impl fmt::Display for SensorFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SensorFault::Dead => f.write_str("dead"),
            SensorFault::Stuck => f.write_str("stuck"),
            SensorFault::Bias(b) => write!(f, "bias:{b}"),
            SensorFault::Noisy(k) => write!(f, "noisy:{k}"),
        }
    }
}

impl FromStr for SensorFault {
    type Err = ParseSensorError;

    /// Parse `dead`, `stuck`, `bias:<number>` or `noisy:<factor>` (ASCII case-insensitive
    /// keyword; the number finite, the factor finite and not negative).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        let (kw, arg) = match t.split_once(':') {
            Some((k, a)) => (k.trim().to_ascii_lowercase(), Some(a.trim())),
            None => (t.to_ascii_lowercase(), None),
        };
        let number = |what: &str, a: Option<&str>| -> Result<f64, ParseSensorError> {
            let a = a.filter(|a| !a.is_empty()).ok_or_else(|| {
                ParseSensorError(format!(
                    "sensor fault `{t}`: {kw} needs a {what}, as {kw}:<{what}>"
                ))
            })?;
            let x: f64 = a.parse().map_err(|_| {
                ParseSensorError(format!("sensor fault `{t}`: `{a}` is not a number"))
            })?;
            if !x.is_finite() {
                return Err(ParseSensorError(format!(
                    "sensor fault `{t}`: the {what} must be finite"
                )));
            }
            Ok(x)
        };
        let no_arg = |f: SensorFault| match arg {
            None => Ok(f),
            Some(_) => Err(ParseSensorError(format!(
                "sensor fault `{t}`: {kw} takes no value"
            ))),
        };
        match kw.as_str() {
            "dead" => no_arg(SensorFault::Dead),
            "stuck" => no_arg(SensorFault::Stuck),
            "bias" => number("number", arg).map(SensorFault::Bias),
            "noisy" => {
                let k = number("factor", arg)?;
                if k < 0.0 {
                    return Err(ParseSensorError(format!(
                        "sensor fault `{t}`: the noise factor must not be negative"
                    )));
                }
                Ok(SensorFault::Noisy(k))
            }
            _ => Err(ParseSensorError(format!(
                "unknown sensor fault `{t}`: expected dead, stuck, bias:<number> \
                 (processed unit: rad/s, nT, m/s^2, counts or m) or noisy:<factor>"
            ))),
        }
    }
}

/// The truth a sample is taken from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorInputs {
    /// Attitude, active rotation body -> ECI J2000.
    pub q_eci_from_body: UnitQuaternion<f64>,
    /// Body rate relative to ECI, body frame, rad/s.
    pub w_body_rad_s: Vector3<f64>,
    /// Geomagnetic field, ECI J2000, nT.
    pub b_eci_nt: Vector3<f64>,
    /// Direction to the Sun, ECI J2000 (normalised here; zero means no Sun).
    pub sun_eci_unit: Vector3<f64>,
    /// Visible fraction of the solar disc, 0 (umbra) ..= 1 (full sun).
    pub sun_visible_fraction: f64,
    /// Position, ECI J2000, m.
    pub r_eci_m: Vector3<f64>,
    /// Velocity, ECI J2000, m/s.
    pub v_eci_m_s: Vector3<f64>,
    /// Non-gravitational acceleration (drag, thrust), body frame, m/s^2.
    pub nongrav_acc_body_m_s2: Vector3<f64>,
}

/// What the FC reads in one sample: raw counts and the processed values derived from them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorReadings {
    /// Rate, body, rad/s (`None` when the gyro is dead).
    pub gyro_body_rad_s: Option<Vector3<f64>>,
    /// Field, body, nT (`None` when the magnetometer is dead).
    pub mag_body_nt: Option<Vector3<f64>>,
    /// Sun-sensor counts, +X -X +Y -Y +Z -Z, 0..=4095.
    pub css_counts: [u16; 6],
    /// Sun direction from the counts, body, unit (`None` below the total-signal threshold).
    pub sun_body_unit: Option<Vector3<f64>>,
    /// Non-gravitational acceleration, body, m/s^2 (`None` when the accelerometer is dead).
    pub acc_body_m_s2: Option<Vector3<f64>>,
    /// GPS position, ECI J2000, m (`None` when disabled or dead).
    pub gps_r_eci_m: Option<Vector3<f64>>,
    /// GPS velocity, ECI J2000, m/s (`None` when disabled or dead).
    pub gps_v_eci_m_s: Option<Vector3<f64>>,
    /// The six temperatures ([`TEMP_CHANNELS`] order), degrees C (from the 0.1 C counts).
    pub temps_c: [f64; 6],
    /// MCU temperature, degrees C (0.1 C resolution).
    pub mcu_temp_c: f64,
    /// Gyro counts, 0.01 deg/s per LSB.
    pub gyro_raw: [i16; 3],
    /// Accelerometer counts, 1 mg per LSB.
    pub acc_raw: [i16; 3],
    /// Magnetometer counts, 10 nT per LSB.
    pub mag_raw: [i16; 3],
    /// Temperature counts, 0.1 degrees C per LSB.
    pub temps_raw: [i16; 6],
    /// Nadir (the Earth's centre) from the horizon sensor, body, unit (`None` with no limb
    /// in view or the sensor dead).
    pub horizon_nadir_body: Option<Vector3<f64>>,
    /// Horizon sensor counts, [`HORIZON_LSB`] per LSB.
    pub horizon_raw: [i16; 3],
    /// Horizon sensor status: [`HORIZON_NO_LIMB`], [`HORIZON_FULL_LIMB`] or
    /// [`HORIZON_PARTIAL_LIMB`].
    pub horizon_status: u8,
}

/// Horizon sensor nadir vector resolution, per LSB (unit vector components).
pub const HORIZON_LSB: f64 = 1.0e-4;
/// Horizon sensor status: no limb in view (or dead): no nadir vector.
pub const HORIZON_NO_LIMB: u8 = 0;
/// Horizon sensor status: the whole limb in view.
pub const HORIZON_FULL_LIMB: u8 = 1;
/// Horizon sensor status: part of the limb in view (three times the noise).
pub const HORIZON_PARTIAL_LIMB: u8 = 2;
/// Mean Earth radius for the limb, m (the oblate limb moves the apparent nadir by up to
/// about 0.1 degree; not modelled).
pub const EARTH_MEAN_RADIUS_M: f64 = 6_371_000.0;

/// What a horizon sensor with boresight `boresight` and field of view `fov_rad` (half-angle)
/// sees of the Earth whose centre is in direction `nadir` (unit) at angular radius
/// `earth_rad`: [`HORIZON_NO_LIMB`] when no part of the limb is in view (the disc outside
/// the field, or the field inside the disc), [`HORIZON_FULL_LIMB`] when all of it is.
pub fn horizon_view(
    boresight: &Vector3<f64>,
    nadir: &Vector3<f64>,
    earth_rad: f64,
    fov_rad: f64,
) -> u8 {
    let theta = boresight.dot(nadir).clamp(-1.0, 1.0).acos();
    if theta - earth_rad >= fov_rad || earth_rad - theta >= fov_rad {
        HORIZON_NO_LIMB
    } else if theta + earth_rad <= fov_rad {
        HORIZON_FULL_LIMB
    } else {
        HORIZON_PARTIAL_LIMB
    }
}

/// A temperature as TMSENS/TMGEN carry it: whole degrees C, rounded, saturating (NaN 0).
pub fn temp_i8_c(t_c: f64) -> i8 {
    // `as` saturates at the i8 limits and maps NaN to 0.
    t_c.round() as i8
}

fn f32s(v: Option<Vector3<f64>>) -> [f32; 3] {
    v.map_or([0.0; 3], |v| [v.x as f32, v.y as f32, v.z as f32])
}

impl SensorReadings {
    /// The TMSENS reply for these readings at RTC `rtc` (zeros for dead sensors and no Sun).
    pub fn tm_sens(&self, rtc: u32) -> TmSens {
        TmSens {
            rtc_timestamp: rtc,
            sun_body: self.sun_body_unit.map_or([0.0; 3], |s| [s.x, s.y, s.z]),
            rate_body_rad_s: f32s(self.gyro_body_rad_s),
            acc_body_m_s2: f32s(self.acc_body_m_s2),
            b_body_nt: f32s(self.mag_body_nt),
            temps_c: self.temps_c.map(temp_i8_c),
        }
    }

    /// The TMRAWSENS reply for these readings at RTC `rtc`.
    pub fn tm_raw_sens(&self, rtc: u32) -> TmRawSens {
        TmRawSens {
            rtc_timestamp: rtc,
            css_counts: self.css_counts,
            gyro_raw: self.gyro_raw,
            acc_raw: self.acc_raw,
            mag_raw: self.mag_raw,
            temps_raw: self.temps_raw,
            horizon_raw: self.horizon_raw,
            horizon_status: self.horizon_status,
        }
    }

    /// The MCU temperature as TMGEN carries it, whole degrees C.
    pub fn mcu_temp_i8_c(&self) -> i8 {
        temp_i8_c(self.mcu_temp_c)
    }
}

/// One sensor's seeded Gaussian noise source.
#[derive(Debug, Clone)]
struct Noise {
    rng: ChaCha8Rng,
}

impl Noise {
    fn new(seed: u64, stream: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream);
        Noise { rng }
    }

    /// One standard normal draw: the ziggurat (`rand_distr`), one 64-bit draw and a table
    /// look-up nearly every time, where Box-Muller took a logarithm, a square root, a sine
    /// and a cosine per pair (4 % of a full-day run).
    fn gauss(&mut self) -> f64 {
        StandardNormal.sample(&mut self.rng)
    }

    fn gauss3(&mut self) -> Vector3<f64> {
        let x = self.gauss();
        let y = self.gauss();
        let z = self.gauss();
        Vector3::new(x, y, z)
    }
}

/// Quantise to an i16 count of `lsb`, rounding, saturating at the i16 limits (NaN 0).
fn quantise_i16(x: f64, lsb: f64) -> i16 {
    (x / lsb).round() as i16
}

fn quantise3(v: &Vector3<f64>, lsb: f64) -> [i16; 3] {
    [
        quantise_i16(v.x, lsb),
        quantise_i16(v.y, lsb),
        quantise_i16(v.z, lsb),
    ]
}

fn from_raw3(raw: [i16; 3], lsb: f64) -> Vector3<f64> {
    Vector3::new(
        f64::from(raw[0]) * lsb,
        f64::from(raw[1]) * lsb,
        f64::from(raw[2]) * lsb,
    )
}

/// A three-axis sensor's last output: raw counts and whether it produced a value.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Held3 {
    raw: [i16; 3],
    present: bool,
}

/// Extra bias and noise factor of a fault.
fn fault_bias_and_noise(f: Option<SensorFault>) -> (f64, f64) {
    match f {
        Some(SensorFault::Bias(b)) => (b, 1.0),
        Some(SensorFault::Noisy(k)) => (0.0, k.abs()),
        _ => (0.0, 1.0),
    }
}

/// Apply dead/stuck to a fresh three-axis output and remember what was produced.
fn three_axis(
    fault: Option<SensorFault>,
    fresh: [i16; 3],
    last: &mut Option<Held3>,
    lsb: f64,
) -> (Option<Vector3<f64>>, [i16; 3]) {
    let out = match fault {
        Some(SensorFault::Dead) => Held3 {
            raw: [0; 3],
            present: false,
        },
        Some(SensorFault::Stuck) => last.unwrap_or(Held3 {
            raw: fresh,
            present: true,
        }),
        _ => Held3 {
            raw: fresh,
            present: true,
        },
    };
    *last = Some(out);
    (out.present.then(|| from_raw3(out.raw, lsb)), out.raw)
}

/// The FC's sensor set: configuration, seeded noise, gyro bias, thermal state and faults.
#[derive(Debug, Clone)]
pub struct Sensors {
    cfg: SensorConfig,
    gyro_rng: Noise,
    mag_rng: Noise,
    css_rng: Noise,
    acc_rng: Noise,
    gps_rng: Noise,
    temp_rng: Noise,
    horizon_rng: Noise,
    gyro_bias_rad_s: Vector3<f64>,
    temps_true_c: [f64; 6],
    mcu_true_c: f64,
    faults: BTreeMap<SensorId, SensorFault>,
    last_gyro: Option<Held3>,
    last_mag: Option<Held3>,
    last_acc: Option<Held3>,
    last_css: Option<[u16; 6]>,
    last_gps: Option<Option<(Vector3<f64>, Vector3<f64>)>>,
    last_horizon: Option<(Held3, u8)>,
}

impl Sensors {
    /// The running configuration (the `gps_enabled` platform parameter changes it).
    pub fn config_mut(&mut self) -> &mut SensorConfig {
        &mut self.cfg
    }
    /// A sensor set for `cfg` whose noise (and random turn-on bias) comes from `seed`.
    pub fn new(cfg: SensorConfig, seed: u64) -> Self {
        let mut gyro_rng = Noise::new(seed, 1);
        // Always drawn, so the gyro stream does not depend on the configured sigma.
        let turn_on = gyro_rng.gauss3() * cfg.gyro_bias_turn_on_sigma_rad_s;
        let gyro_bias_rad_s = cfg.gyro_bias_initial_rad_s + turn_on;
        let temps_true_c = cfg.thermal.map(|c| c.initial_c);
        let mcu_true_c = cfg.mcu_thermal.initial_c;
        Self {
            cfg,
            gyro_rng,
            mag_rng: Noise::new(seed, 2),
            css_rng: Noise::new(seed, 3),
            acc_rng: Noise::new(seed, 4),
            gps_rng: Noise::new(seed, 5),
            temp_rng: Noise::new(seed, 6),
            horizon_rng: Noise::new(seed, 7),
            gyro_bias_rad_s,
            temps_true_c,
            mcu_true_c,
            faults: BTreeMap::new(),
            last_gyro: None,
            last_mag: None,
            last_acc: None,
            last_css: None,
            last_gps: None,
            last_horizon: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &SensorConfig {
        &self.cfg
    }

    /// Set (`Some`) or clear (`None`) the fault on `id`; an invalid face index is ignored.
    pub fn set_fault(&mut self, id: SensorId, fault: Option<SensorFault>) {
        if !id.is_valid() {
            return;
        }
        match fault {
            Some(f) => {
                self.faults.insert(id, f);
            }
            None => {
                self.faults.remove(&id);
            }
        }
    }

    /// The fault set on `id`, if any.
    pub fn fault(&self, id: SensorId) -> Option<SensorFault> {
        self.faults.get(&id).copied()
    }

    /// The faults in effect, in [`SensorId`] order.
    pub fn faults(&self) -> impl Iterator<Item = (SensorId, SensorFault)> + '_ {
        self.faults.iter().map(|(id, f)| (*id, *f))
    }

    /// The gyro's true bias now (in the last sample), rad/s, without any fault bias.
    pub fn true_gyro_bias_rad_s(&self) -> Vector3<f64> {
        self.gyro_bias_rad_s
    }

    /// The six channels' true temperatures now, degrees C (before sensor noise).
    pub fn true_temps_c(&self) -> [f64; 6] {
        self.temps_true_c
    }

    /// The MCU's true temperature now, degrees C.
    pub fn true_mcu_temp_c(&self) -> f64 {
        self.mcu_true_c
    }

    /// Advance the bias walk and thermal state by `dt_s` (time since the previous sample;
    /// negative or non-finite counts as 0), then sample every sensor.
    pub fn sample(&mut self, inputs: &SensorInputs, dt_s: f64) -> SensorReadings {
        let dt_s = if dt_s.is_finite() { dt_s.max(0.0) } else { 0.0 };
        let sun_body_true = {
            let s = inputs
                .q_eci_from_body
                .inverse_transform_vector(&inputs.sun_eci_unit);
            s.try_normalize(0.0).unwrap_or_else(Vector3::zeros)
        };
        let visible =
            if inputs.sun_visible_fraction.is_finite() && sun_body_true != Vector3::zeros() {
                inputs.sun_visible_fraction.clamp(0.0, 1.0)
            } else {
                0.0
            };

        // Gyro: noise (x, y, z) then the bias walk (x, y, z), every sample.
        let gyro_fault = self.fault(SensorId::Gyro);
        let (extra, k) = fault_bias_and_noise(gyro_fault);
        let n = self.gyro_rng.gauss3();
        let walk = self.gyro_rng.gauss3();
        self.gyro_bias_rad_s += walk * (self.cfg.gyro_bias_walk_rad_s_per_sqrt_s * dt_s.sqrt());
        let w = inputs.w_body_rad_s
            + self.gyro_bias_rad_s
            + Vector3::repeat(extra)
            + n * (self.cfg.gyro_noise_rad_s * k);
        let (gyro_body_rad_s, gyro_raw) = three_axis(
            gyro_fault,
            quantise3(&w, GYRO_LSB_RAD_S),
            &mut self.last_gyro,
            GYRO_LSB_RAD_S,
        );

        // Magnetometer.
        let mag_fault = self.fault(SensorId::Magnetometer);
        let (extra, k) = fault_bias_and_noise(mag_fault);
        let n = self.mag_rng.gauss3();
        let b = inputs
            .q_eci_from_body
            .inverse_transform_vector(&inputs.b_eci_nt)
            + self.cfg.mag_bias_nt
            + Vector3::repeat(extra)
            + n * (self.cfg.mag_noise_nt * k);
        let (mag_body_nt, mag_raw) = three_axis(
            mag_fault,
            quantise3(&b, MAG_LSB_NT),
            &mut self.last_mag,
            MAG_LSB_NT,
        );

        // Coarse sun sensors.
        let (css_counts, sun_body_unit) = self.sample_css(&sun_body_true, visible);

        // Accelerometer.
        let acc_fault = self.fault(SensorId::Accelerometer);
        let (extra, k) = fault_bias_and_noise(acc_fault);
        let n = self.acc_rng.gauss3();
        let a = inputs.nongrav_acc_body_m_s2
            + self.cfg.acc_bias_m_s2
            + Vector3::repeat(extra)
            + n * (self.cfg.acc_noise_m_s2 * k);
        let (acc_body_m_s2, acc_raw) = three_axis(
            acc_fault,
            quantise3(&a, ACC_LSB_M_S2),
            &mut self.last_acc,
            ACC_LSB_M_S2,
        );

        let gps = self.sample_gps(inputs);
        let (temps_raw, mcu_raw) = self.sample_temps(visible, &sun_body_true, dt_s);

        let (horizon_nadir_body, horizon_raw, horizon_status) = self.sample_horizon(inputs);

        SensorReadings {
            gyro_body_rad_s,
            mag_body_nt,
            css_counts,
            sun_body_unit,
            acc_body_m_s2,
            gps_r_eci_m: gps.map(|(r, _)| r),
            gps_v_eci_m_s: gps.map(|(_, v)| v),
            temps_c: temps_raw.map(|r| f64::from(r) * TEMP_LSB_C),
            mcu_temp_c: f64::from(mcu_raw) * TEMP_LSB_C,
            gyro_raw,
            acc_raw,
            mag_raw,
            temps_raw,
            horizon_nadir_body,
            horizon_raw,
            horizon_status,
        }
    }

    /// The GPS fix; its noise is drawn even when off, so the stream does not depend on the switch.
    fn sample_gps(&mut self, inputs: &SensorInputs) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let gps_fault = self.fault(SensorId::Gps);
        let (extra, k) = fault_bias_and_noise(gps_fault);
        let nr = self.gps_rng.gauss3();
        let nv = self.gps_rng.gauss3();
        let fresh = self.cfg.gps_enabled.then(|| {
            (
                inputs.r_eci_m + Vector3::repeat(extra) + nr * (self.cfg.gps_position_noise_m * k),
                inputs.v_eci_m_s + nv * (self.cfg.gps_velocity_noise_m_s * k),
            )
        });
        let gps = match gps_fault {
            Some(SensorFault::Dead) => None,
            Some(SensorFault::Stuck) => self.last_gps.unwrap_or(fresh),
            _ => fresh,
        };
        self.last_gps = Some(gps);
        gps
    }

    /// The temperatures' counts (six channels, then MCU), the thermal state advanced first.
    fn sample_temps(
        &mut self,
        visible: f64,
        sun_body_true: &Vector3<f64>,
        dt_s: f64,
    ) -> ([i16; 6], i16) {
        for (t, ch) in self.temps_true_c.iter_mut().zip(&self.cfg.thermal) {
            *t = ch.advance(*t, ch.equilibrium_c(visible, sun_body_true), dt_s);
        }
        let mcu = &self.cfg.mcu_thermal;
        self.mcu_true_c = mcu.advance(
            self.mcu_true_c,
            mcu.equilibrium_c(visible, sun_body_true),
            dt_s,
        );
        let sigma = self.cfg.temp_noise_c;
        let temps_raw: [i16; 6] = core::array::from_fn(|i| {
            quantise_i16(
                self.temps_true_c[i] + self.temp_rng.gauss() * sigma,
                TEMP_LSB_C,
            )
        });
        let mcu_raw = quantise_i16(self.mcu_true_c + self.temp_rng.gauss() * sigma, TEMP_LSB_C);
        (temps_raw, mcu_raw)
    }

    /// The horizon sensor: the nadir direction from the limb it sees, with noise (three
    /// draws every sample, seen or not).
    fn sample_horizon(&mut self, inputs: &SensorInputs) -> (Option<Vector3<f64>>, [i16; 3], u8) {
        let fault = self.fault(SensorId::Horizon);
        let (extra, k) = fault_bias_and_noise(fault);
        let n = self.horizon_rng.gauss3();
        let r = inputs.r_eci_m.norm();
        let nadir_body = inputs
            .q_eci_from_body
            .inverse_transform_vector(&(-inputs.r_eci_m))
            .try_normalize(0.0);
        let boresight = self
            .cfg
            .horizon_boresight_body
            .try_normalize(0.0)
            .unwrap_or_else(Vector3::z);
        let seen = match nadir_body {
            Some(nadir) if r > EARTH_MEAN_RADIUS_M && r.is_finite() => {
                let earth_rad = (EARTH_MEAN_RADIUS_M / r).asin();
                let status = horizon_view(
                    &boresight,
                    &nadir,
                    earth_rad,
                    self.cfg.horizon_fov_half_angle_rad,
                );
                let sigma = self.cfg.horizon_noise_rad
                    * k
                    * if status == HORIZON_PARTIAL_LIMB {
                        3.0
                    } else {
                        1.0
                    };
                let m = (nadir + n * sigma + Vector3::repeat(extra)).try_normalize(0.0);
                m.filter(|_| status != HORIZON_NO_LIMB).map(|m| (m, status))
            }
            _ => None,
        };
        let fresh = match seen {
            Some((m, status)) => (
                Held3 {
                    raw: quantise3(&m, HORIZON_LSB),
                    present: true,
                },
                status,
            ),
            None => (
                Held3 {
                    raw: [0; 3],
                    present: false,
                },
                HORIZON_NO_LIMB,
            ),
        };
        let out = match fault {
            Some(SensorFault::Dead) => (
                Held3 {
                    raw: [0; 3],
                    present: false,
                },
                HORIZON_NO_LIMB,
            ),
            Some(SensorFault::Stuck) => self.last_horizon.unwrap_or(fresh),
            _ => fresh,
        };
        self.last_horizon = Some(out);
        let (h, status) = out;
        let v = h
            .present
            .then(|| from_raw3(h.raw, HORIZON_LSB).try_normalize(0.0))
            .flatten();
        (v, h.raw, status)
    }

    /// The six counts and the sun vector the FC derives from them.
    fn sample_css(
        &mut self,
        sun_body_true: &Vector3<f64>,
        visible: f64,
    ) -> ([u16; 6], Option<Vector3<f64>>) {
        let all = self.fault(SensorId::SunSensors);
        let cos_fov = self.cfg.css_fov_half_angle_rad.cos();
        let full = f64::from(CSS_FULL_SCALE_COUNTS);
        let last = self.last_css;
        // Six draws in face order, every sample.
        let noise: [f64; 6] = core::array::from_fn(|_| self.css_rng.gauss());
        // i < 6: the cast cannot truncate.
        let faults: [Option<SensorFault>; 6] =
            core::array::from_fn(|i| self.fault(SensorId::SunSensor(i as u8)).or(all));
        let counts: [u16; 6] = core::array::from_fn(|i| {
            let (n, fault) = (noise[i], faults[i]);
            let (extra, k) = fault_bias_and_noise(fault);
            let cos = sun_body_true.dot(&css_normal_body(i));
            let signal = if cos > 0.0 && cos >= cos_fov {
                visible * cos
            } else {
                0.0
            };
            let x = full * signal + extra + n * (self.cfg.css_noise_counts * k);
            // `as` maps NaN to 0; the clamp keeps the 12-bit range.
            let fresh = x.round().clamp(0.0, full) as u16;
            match fault {
                Some(SensorFault::Dead) => 0,
                Some(SensorFault::Stuck) => last.map_or(fresh, |l| l[i]),
                _ => fresh,
            }
        });
        self.last_css = Some(counts);
        (
            counts,
            sun_from_counts(&counts, self.cfg.css_min_total_counts),
        )
    }
}

/// The FC's sun vector from six counts (+X -X +Y -Y +Z -Z): opposite-face differences,
/// normalised; `None` when the total is below `min_total_counts` or the difference is zero.
pub fn sun_from_counts(counts: &[u16; 6], min_total_counts: f64) -> Option<Vector3<f64>> {
    let total: f64 = counts.iter().map(|c| f64::from(*c)).sum();
    if total < min_total_counts {
        return None;
    }
    let d = |p: usize| f64::from(counts[p]) - f64::from(counts[p + 1]);
    Vector3::new(d(0), d(2), d(4)).try_normalize(0.0)
}

// What a snapshot keeps of the sensors: every generator where it is in its stream, the
// hidden truths (bias walk, temperatures), the faults and the held values, and the
// configuration (an FC parameter switches the GPS).
snap::fields!(ThermalChannel {
    initial_c,
    eclipse_equilibrium_c,
    sunlit_equilibrium_c,
    face_sun_gain_c,
    face_normal_body,
    time_constant_s
});
snap::fields!(SensorConfig {
    gyro_noise_rad_s,
    gyro_bias_initial_rad_s,
    gyro_bias_turn_on_sigma_rad_s,
    gyro_bias_walk_rad_s_per_sqrt_s,
    mag_noise_nt,
    mag_bias_nt,
    css_fov_half_angle_rad,
    css_noise_counts,
    css_min_total_counts,
    acc_noise_m_s2,
    acc_bias_m_s2,
    gps_enabled,
    gps_position_noise_m,
    gps_velocity_noise_m_s,
    horizon_boresight_body,
    horizon_fov_half_angle_rad,
    horizon_noise_rad,
    thermal,
    mcu_thermal,
    temp_noise_c
});
snap::fields!(SensorReadings {
    gyro_body_rad_s,
    mag_body_nt,
    css_counts,
    sun_body_unit,
    acc_body_m_s2,
    gps_r_eci_m,
    gps_v_eci_m_s,
    temps_c,
    mcu_temp_c,
    gyro_raw,
    acc_raw,
    mag_raw,
    temps_raw,
    horizon_nadir_body,
    horizon_raw,
    horizon_status
});
snap::fields!(Noise { rng });
snap::fields!(Held3 { raw, present });
snap::fields!(Sensors {
    cfg,
    gyro_rng,
    mag_rng,
    css_rng,
    acc_rng,
    gps_rng,
    temp_rng,
    horizon_rng,
    gyro_bias_rad_s,
    temps_true_c,
    mcu_true_c,
    faults,
    last_gyro,
    last_mag,
    last_acc,
    last_css,
    last_gps,
    last_horizon
});

impl snap::Snap for SensorId {
    fn save(&self, w: &mut snap::Writer) {
        let (tag, face): (u8, u8) = match *self {
            SensorId::Gyro => (0, 0),
            SensorId::Magnetometer => (1, 0),
            SensorId::SunSensor(f) => (2, f),
            SensorId::SunSensors => (3, 0),
            SensorId::Accelerometer => (4, 0),
            SensorId::Gps => (5, 0),
            SensorId::Horizon => (6, 0),
        };
        snap::Snap::save(&(tag, face), w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = snap::SnapNew::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for SensorId {
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let at = r.at();
        let (tag, face): (u8, u8) = snap::SnapNew::read(r)?;
        Ok(match tag {
            0 => SensorId::Gyro,
            1 => SensorId::Magnetometer,
            2 => SensorId::SunSensor(face),
            3 => SensorId::SunSensors,
            4 => SensorId::Accelerometer,
            5 => SensorId::Gps,
            6 => SensorId::Horizon,
            _ => {
                return Err(snap::SnapError::Bad {
                    what: "SensorId",
                    at,
                });
            }
        })
    }
}

impl snap::Snap for SensorFault {
    fn save(&self, w: &mut snap::Writer) {
        let (tag, x): (u8, f64) = match *self {
            SensorFault::Dead => (0, 0.0),
            SensorFault::Stuck => (1, 0.0),
            SensorFault::Bias(b) => (2, b),
            SensorFault::Noisy(k) => (3, k),
        };
        snap::Snap::save(&(tag, x), w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = snap::SnapNew::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for SensorFault {
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let at = r.at();
        let (tag, x): (u8, f64) = snap::SnapNew::read(r)?;
        Ok(match tag {
            0 => SensorFault::Dead,
            1 => SensorFault::Stuck,
            2 => SensorFault::Bias(x),
            3 => SensorFault::Noisy(x),
            _ => {
                return Err(snap::SnapError::Bad {
                    what: "SensorFault",
                    at,
                });
            }
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn gauss_has_zero_mean_unit_variance_and_tails() {
        let mut n = Noise::new(42, 9);
        let xs: Vec<f64> = (0..200_000).map(|_| n.gauss()).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.01, "{var}");
        // P(|x| > 2) = 4.55 %, P(|x| > 3) = 0.27 %.
        let beyond = |k: f64| xs.iter().filter(|x| x.abs() > k).count() as f64 / xs.len() as f64;
        assert!((beyond(2.0) - 0.0455).abs() < 0.002, "{}", beyond(2.0));
        assert!((beyond(3.0) - 0.0027).abs() < 0.0006, "{}", beyond(3.0));
        assert!(xs.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn gaussian_draws_are_standard_and_successive_pairs_uncorrelated() {
        let mut n = Noise::new(7, 1);
        let k = 40_000;
        let xs: Vec<f64> = (0..k).map(|_| n.gauss()).collect();
        let mean = xs.iter().sum::<f64>() / k as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / k as f64;
        // Cosine and sine branches of one pair come out one after the other.
        let lag1 = xs.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (k - 1) as f64;
        let fourth = xs.iter().map(|x| x.powi(4)).sum::<f64>() / k as f64;
        assert!(mean.abs() < 0.02, "mean {mean}");
        assert!((var - 1.0).abs() < 0.03, "variance {var}");
        assert!(lag1.abs() < 0.02, "lag-1 correlation {lag1}");
        assert!((fourth - 3.0).abs() < 0.2, "fourth moment {fourth}");
    }

    #[test]
    fn streams_differ_per_sensor_and_seed() {
        let a = Noise::new(1, 1).gauss();
        assert_eq!(a, Noise::new(1, 1).gauss());
        assert_ne!(a, Noise::new(1, 2).gauss());
        assert_ne!(a, Noise::new(2, 1).gauss());
    }

    #[test]
    fn quantise_saturates_and_maps_nan_to_zero() {
        assert_eq!(quantise_i16(1e12, 1.0), i16::MAX);
        assert_eq!(quantise_i16(-1e12, 1.0), i16::MIN);
        assert_eq!(quantise_i16(f64::NAN, 1.0), 0);
        assert_eq!(quantise_i16(2.5, 1.0), 3);
        assert_eq!(quantise_i16(-0.04, 0.1), 0);
        assert_eq!(temp_i8_c(300.0), 127);
        assert_eq!(temp_i8_c(-300.0), -128);
        assert_eq!(temp_i8_c(-2.5), -3);
    }

    #[test]
    fn css_normals_are_in_face_order() {
        let want = [
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ];
        for (i, w) in want.iter().enumerate() {
            assert_eq!(css_normal_body(i), *w);
        }
    }
}
