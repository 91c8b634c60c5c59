//! The FC's ICD commands and replies (ICD 4.2.1-4.2.3, INTERPRETATION.md sections 2, 4, 5)
//! as wire representations, and the command tables of its ports.
//!
//! # Contract
//! Every type implementing [`Repr`] is the request or reply *data* of one or more ICD
//! commands (the bytes after `command | result` of `csp::reqrep`), with a fixed size
//! [`Repr::LEN`] taken from the ICD tables. [`Repr::parse`] accepts exactly `LEN` bytes and
//! never panics; [`Repr::emit`] appends exactly [`Repr::buffer_len`] bytes. All multi-byte
//! fields are little-endian, floats IEEE-754 (ICD 1.8). A `Repr` is a byte-level view: any
//! bit pattern of a float field parses (NaN included) and emits back to the same bytes;
//! range checks (a normalisable quaternion, a finite point) belong to the port's
//! [`CommandSet`]. The one exception is [`TargetMode`], an enumeration whose unknown values
//! cannot be represented and fail to parse.
//!
//! # Sizes (ICD tables 4.2.1-4.2.3)
//! | command | request | reply |
//! |---|---|---|
//! | TMGEN 1 | - | [`TmGen`] 16 |
//! | TMATP 2 | - | [`TmAtp`] 60 |
//! | TMACD 3 | - | [`TmAcd`] 19 |
//! | TMSENS 4 | - | [`TmSens`] 70 |
//! | TMRAWSENS 5 | - | [`TmRawSens`] 53 (the twin's layout) |
//! | TMALL 6 | - | [`TmAll`] 177 (the twin's layout) |
//! | TMPERSET 7 / TMPERGET 8 (the twin's) | [`Periodic`] 7 / - | - / [`Periodic`] 7 |
//! | TMSTOREINFO 9 / TMSTOREGET 10 / TMSTORECLEAR 11 (the twin's) | - / 12: `u32 from_rtc, u32 to_rtc, u32 skip` / - | `nodes_fc::store` |
//! | TWINSIM 12 (the twin's own: a spacecraft's FC has no such command) | - | [`TwinSim`] 27 |
//! | RTCSTMSET 1 | [`RtcTimestamp`] 4 | - |
//! | RTCSTMGET 2 | - | [`RtcTimestamp`] 4 |
//! | ATCATGET 1 / ATCATSET 2 | - / [`TargetAttitude`] 32 | [`TargetAttitude`] 32 / - |
//! | ATCPTGET 3 / ATCPTSET 4 | - / [`TargetPoint`] 24 | [`TargetPoint`] 24 / - |
//! | ATCMDGET 5 / ATCMDSET 6 | - / [`TargetModeRepr`] 1 | [`TargetModeRepr`] 1 / - |
//!
//! ATCAT*/ATCPT* carry `float64 q[4]` (32 bytes) and `float64 p[3]` (24 bytes): the ICD's
//! "16" size column contradicts its own types, and the types win (INTERPRETATION.md 5).

use csp::Error;
use csp::icd::{Command, Data, Port};
use csp::reqrep::le::{Reader, Writer};
use csp::reqrep::{CommandSet, Request, RequestError, expect_len};

/// Default port of the telemetry commands (INTERPRETATION.md section 4).
pub const PORT_TELEMETRY: u8 = 10;
/// Default port of the real-time clock commands.
pub const PORT_RTC: u8 = 11;
/// Default port of the attitude target control commands.
pub const PORT_ATTITUDE: u8 = 12;
/// Default port of the mission-controller scripts (ICD 1.5; a later increment).
pub const PORT_SCRIPTS: u8 = 13;
/// Largest TMSTOREGET reply data.
pub const STORE_CHUNK_BYTES: usize = 200;

/// Command ids of the FC ports (ICD tables 4.2.1-4.2.3, INTERPRETATION.md section 4).
pub mod cmd {
    /// Telemetry port: general telemetry.
    pub const TMGEN: u8 = 1;
    /// Telemetry port: attitude and position.
    pub const TMATP: u8 = 2;
    /// Telemetry port: attitude control data.
    pub const TMACD: u8 = 3;
    /// Telemetry port: pre-processed sensor data.
    pub const TMSENS: u8 = 4;
    /// Telemetry port: raw sensor data.
    pub const TMRAWSENS: u8 = 5;
    /// Telemetry port: all beacon telemetry.
    pub const TMALL: u8 = 6;
    /// Telemetry port: set the periodic real-time telemetry (the twin's).
    pub const TMPERSET: u8 = 7;
    /// Telemetry port: get the periodic real-time telemetry (the twin's).
    pub const TMPERGET: u8 = 8;
    /// Telemetry port: the telemetry store's fill (the twin's).
    pub const TMSTOREINFO: u8 = 9;
    /// Telemetry port: stored telemetry by time range (the twin's).
    pub const TMSTOREGET: u8 = 10;
    /// Telemetry port: erase the telemetry store (the twin's).
    pub const TMSTORECLEAR: u8 = 11;
    /// Telemetry port: the simulation's own state (the twin's own: a spacecraft's FC has no
    /// such command).
    pub const TWINSIM: u8 = 12;
    /// RTC port: set the RTC.
    pub const RTCSTMSET: u8 = 1;
    /// RTC port: get the RTC.
    pub const RTCSTMGET: u8 = 2;
    /// Attitude port: get the target attitude.
    pub const ATCATGET: u8 = 1;
    /// Attitude port: set the target attitude.
    pub const ATCATSET: u8 = 2;
    /// Attitude port: get the target point.
    pub const ATCPTGET: u8 = 3;
    /// Attitude port: set the target point.
    pub const ATCPTSET: u8 = 4;
    /// Attitude port: get the target mode.
    pub const ATCMDGET: u8 = 5;
    /// Attitude port: set the target mode.
    pub const ATCMDSET: u8 = 6;
    /// Attitude port: upload the onboard TLE (the twin's extension, docs/protocol.md).
    pub const ATCTLESET: u8 = 7;
    /// Attitude port: read the onboard TLE (the twin's extension).
    pub const ATCTLEGET: u8 = 8;
}

pub use csp::reqrep::le::Repr;
csp::wire_struct! {
    /// TMGEN reply (ICD 4.2.1, 16 bytes): general telemetry.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct TmGen {
        /// RTC, UTC unix seconds.
        pub rtc_timestamp: u32 { unit: "s" },
        /// Seconds since the FC's last boot.
        pub uptime_s: u32 { unit: "s" },
        /// Seconds the FC has been powered since the start of the run (reboots included).
        pub global_on_time_s: u32 { unit: "s" },
        /// Mode in effect (the target modes of ATCMDSET).
        pub current_mode: u8 { values: TARGET_MODES },
        /// FC state (0 nominal; see docs/protocol.md "FC ports").
        pub current_state: u8 { values: &[(0, "nominal"), (1, "SAFE")] },
        /// MCU temperature, degrees C.
        pub mcu_temp_c: i8 { unit: "degC" },
        /// Cause of the last reset (0 power-on, 1 software reboot).
        pub reset_cause: u8 { values: &[(0, "power-on"), (1, "software reboot")] },
    }
}

csp::wire_struct! {
    /// TMATP reply (ICD 4.2.1, 60 bytes): attitude and position.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TmAtp {
        /// RTC, UTC unix seconds.
        pub rtc_timestamp: u32 { unit: "s" },
        /// Attitude of the body in ECI J2000, scalar first (r, i, j, k).
        pub q_eci_from_body: [f64; 4],
        /// Position, ECI J2000, metres.
        pub r_eci_m: [f64; 3] { unit: "m" },
    }
}

csp::wire_struct! {
    /// TMACD reply (ICD 4.2.1, 19 bytes): attitude control data.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct TmAcd {
        /// RTC, UTC unix seconds.
        pub rtc_timestamp: u32 { unit: "s" },
        /// ADCS algorithm state (0 off, 1 detumbling, 2 acquiring, 3 tracking).
        pub state: u8 { values: &[(0, "off"), (1, "detumbling"), (2, "acquiring"), (3, "tracking")] },
        /// Reaction wheel states (0 off, 1 on, 2 fault).
        pub rw_state: [u8; 4] { values: &[(0, "off"), (1, "on"), (2, "fault")] },
        /// Reaction wheel |speed| in units of 100 rpm, saturating at 255.
        pub rw_rpm_100: [u8; 4] { unit: "100 rpm" },
        /// Magnetorquer states (0 off, 1 positive, 2 negative).
        pub mtq_state: [u8; 3] { values: &[(0, "off"), (1, "positive"), (2, "negative")] },
        /// Target mode commanded (ATCMDSET's).
        pub target_mode: u8 { values: TARGET_MODES },
        /// 1 when a target attitude was commanded (ATCATSET) since boot, else 0.
        pub target_attitude: u8 { values: &[(0, "no"), (1, "yes")] },
        /// 1 when a target point was commanded (ATCPTSET) since boot, else 0.
        pub target_point: u8 { values: &[(0, "no"), (1, "yes")] },
    }
}

/// The TMACD `rwrpm` byte for a wheel speed: |rpm| / 100, rounded, saturating at 255.
pub fn rw_rpm_byte(rpm: f64) -> u8 {
    if rpm.is_nan() {
        return 0;
    }
    // `as` saturates: anything at or above 255.5 hundreds of rpm gives 255.
    (rpm.abs() / 100.0).round() as u8
}

csp::wire_struct! {
    /// TMSENS reply (ICD 4.2.1, 70 bytes): pre-processed sensor data.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TmSens {
        /// RTC, UTC unix seconds.
        pub rtc_timestamp: u32 { unit: "s" },
        /// Sun direction, unit vector in BCF (zero when no sun sensor sees the sun).
        pub sun_body: [f64; 3],
        /// Angular rate, rad/s, BCF.
        pub rate_body_rad_s: [f32; 3] { unit: "rad/s" },
        /// Acceleration, m/s^2, BCF.
        pub acc_body_m_s2: [f32; 3] { unit: "m/s^2" },
        /// Magnetic field, nT, BCF.
        pub b_body_nt: [f32; 3] { unit: "nT" },
        /// Sensor temperatures, degrees C.
        pub temps_c: [i8; 6] { unit: "degC" },
    }
}

csp::wire_struct! {
    /// TMRAWSENS reply (the twin's layout, 53 bytes; docs/protocol.md "FC ports"): raw sensor
    /// counts at each sensor's native resolution.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct TmRawSens {
        /// RTC, UTC unix seconds.
        pub rtc_timestamp: u32 { unit: "s" },
        /// Coarse sun sensors on +X -X +Y -Y +Z -Z, 12-bit ADC counts (4095 full sun on the normal).
        pub css_counts: [u16; 6] { unit: "counts" },
        /// Gyroscope, BCF, 0.01 deg/s per LSB.
        pub gyro_raw: [i16; 3] { unit: "0.01 deg/s" },
        /// Accelerometer, BCF, 1 mg per LSB.
        pub acc_raw: [i16; 3] { unit: "mg" },
        /// Magnetometer, BCF, 10 nT per LSB.
        pub mag_raw: [i16; 3] { unit: "10 nT" },
        /// Sensor temperatures (the six of TMSENS), 0.1 degrees C per LSB.
        pub temps_raw: [i16; 6] { unit: "0.1 degC" },
        /// Earth-horizon sensor nadir vector, BCF, 1e-4 per LSB (zeros with no limb in view).
        pub horizon_raw: [i16; 3] { unit: "1e-4" },
        /// Earth-horizon sensor status: 0 no limb in view, 1 the whole limb, 2 part of it.
        pub horizon_status: u8 { values: &[(0, "no limb"), (1, "whole limb"), (2, "part of the limb")] },
    }
}

csp::wire_struct! {
    /// TMALL reply (the twin's layout, 177 bytes; docs/protocol.md "FC ports"): the beacon,
    /// the data of TMGEN, TMATP, TMACD and TMSENS from one instant, in that order.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TmAll {
        /// TMGEN data.
        pub general: TmGen,
        /// TMATP data.
        pub attitude_position: TmAtp,
        /// TMACD data.
        pub attitude_control: TmAcd,
        /// TMSENS data.
        pub sensors: TmSens,
        /// The estimated nadir (Earth's centre) direction, BCF, unit: the onboard position
        /// turned into the body by the estimated attitude (zeros without either).
        pub nadir_body: [f32; 3],
    }
}

csp::wire_struct! {
    /// RTCSTMGET reply and RTCSTMSET request (ICD 4.2.2, 4 bytes): UTC unix seconds.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct RtcTimestamp {
        /// UTC unix seconds (a set: 2000-01-01 to 2100-01-01).
        pub rtc_timestamp: u32 { unit: "s", range: (946684800.0, 4102444800.0) },
    }
}

csp::wire_struct! {
    /// ATCATGET reply and ATCATSET request (ICD 4.2.3, 32 bytes): the target attitude.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TargetAttitude {
        /// Target quaternion, scalar first (r, i, j, k), body in the mode's reference frame.
        pub q: [f64; 4],
    }
}

impl TargetAttitude {
    /// The quaternion scaled to unit norm, or `None` if it has a non-finite component or
    /// is zero (not normalisable). Safe from overflow: it scales by the largest component
    /// first.
    pub fn normalised(&self) -> Option<[f64; 4]> {
        if !self.q.iter().all(|x| x.is_finite()) {
            return None;
        }
        let m = self.q.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
        if m == 0.0 {
            return None;
        }
        let s = self.q.map(|x| x / m);
        let n = s.iter().map(|x| x * x).sum::<f64>().sqrt();
        Some(s.map(|x| x / n))
    }
}

csp::wire_struct! {
    /// ATCPTGET reply and ATCPTSET request (ICD 4.2.3, 24 bytes): the target point.
    ///
    /// Read by the mode in effect: in earth target mode (5) geodetic latitude (deg), longitude
    /// (deg) and altitude (m), as ICD 1.5's GeoLocation; in ECI vector tracking (6) a direction
    /// in ECI J2000 (any non-zero length).
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TargetPoint {
        /// The three values.
        pub p: [f64; 3],
    }
}

/// Attitude target modes (INTERPRETATION.md section 5; the twin's enumeration, one per
/// ICD 1.3 mode plus idle and the fixed-quaternion modes of ICD 1.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum TargetMode {
    /// No control: actuators off.
    Idle = 0,
    /// B-dot detumbling with the magnetorquers (the mode the ADCS boots in, ICD 1.3).
    #[default]
    Detumble = 1,
    /// Body +Z along the orbital velocity.
    VelocityPointing = 2,
    /// Body +Z towards the Earth's centre.
    Nadir = 3,
    /// Solar panel normal towards the sun.
    SunMaxPower = 4,
    /// Track the geodetic target point (ATCPTSET: lat deg, lon deg, alt m).
    EarthTarget = 5,
    /// Track the ECI direction of the target point (ATCPTSET: x, y, z).
    EciVector = 6,
    /// Hold the target attitude (ATCATSET) in ECI J2000.
    FixedEci = 7,
    /// Hold the target attitude in LVLH.
    FixedLvlh = 8,
    /// Hold the target attitude in TNW.
    FixedTnw = 9,
}

impl TryFrom<u8> for TargetMode {
    type Error = Error;
    fn try_from(v: u8) -> Result<Self, Error> {
        use TargetMode::*;
        Ok(match v {
            0 => Idle,
            1 => Detumble,
            2 => VelocityPointing,
            3 => Nadir,
            4 => SunMaxPower,
            5 => EarthTarget,
            6 => EciVector,
            7 => FixedEci,
            8 => FixedLvlh,
            9 => FixedTnw,
            _ => return Err(Error::FieldRange("target mode")),
        })
    }
}

/// [`TargetMode`]'s values by name (TMGEN `current_mode`, TMACD `target_mode`, ATCMDSET).
pub const TARGET_MODES: &[(i64, &str)] = &[
    (0, "idle"),
    (1, "detumble"),
    (2, "velocity pointing"),
    (3, "nadir"),
    (4, "sun max power"),
    (5, "earth target"),
    (6, "ECI vector"),
    (7, "fixed ECI"),
    (8, "fixed LVLH"),
    (9, "fixed TNW"),
];

/// A target mode on the wire: one byte, 0..=9; any other byte does not read.
impl csp::icd::WireField for TargetMode {
    const WIRE_LEN: usize = 1;
    const SHAPE: (csp::icd::Ty, usize) = (csp::icd::Ty::U8, 1);
    fn read_le(r: &mut Reader<'_>) -> Result<Self, Error> {
        TargetMode::try_from(r.u8()?)
    }
    fn write_le(&self, w: &mut Writer) {
        w.u8(*self as u8);
    }
}

csp::wire_struct! {
    /// ATCMDGET reply and ATCMDSET request (ICD 4.2.3, 1 byte): the target mode.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct TargetModeRepr {
        /// The mode.
        pub mode: TargetMode { range: (0.0, 9.0), values: TARGET_MODES },
    }
}

/// TMPERSET `mask` and `store_mask` bits: bit `n - 1` for telemetry command `n`.
pub const TELEMETRY_BITS: &[(i64, &str)] = &[
    (0, "TMGEN"),
    (1, "TMATP"),
    (2, "TMACD"),
    (3, "TMSENS"),
    (4, "TMRAWSENS"),
    (5, "TMALL"),
];

csp::wire_struct! {
    /// TMSTOREINFO reply (the twin's, 20 bytes): what the telemetry store holds.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct StoreInfo {
        /// Records held.
        pub records: u32,
        /// Bytes they take.
        pub bytes: u32 { unit: "B" },
        /// RTC of the oldest record (0: none).
        pub oldest_rtc: u32 { unit: "s" },
        /// RTC of the newest record (0: none).
        pub newest_rtc: u32 { unit: "s" },
        /// Records dropped to make room since the store was last erased.
        pub overwritten: u32,
    }
}

csp::wire_struct! {
    /// TMSTOREGET request (the twin's, 12 bytes): the records with an RTC in
    /// `from_rtc..=to_rtc`, from the `skip`-th on.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct StoreQuery {
        /// First RTC, UTC unix seconds.
        pub from_rtc: u32 { unit: "s" },
        /// Last RTC, UTC unix seconds.
        pub to_rtc: u32 { unit: "s" },
        /// Matching records to skip (the cursor of a chunked read).
        pub skip: u32,
    }
}

csp::wire_struct! {
    /// TWINSIM reply (the twin's own, 27 bytes; a spacecraft's FC has no such command):
    /// enough for ground software to tell that it talks to the twin, to find the instant in
    /// the run's recording and to run the same run again.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct TwinSim {
        /// Simulated time since the run's start, ns: a recording's `t_ns` (the true time,
        /// whatever the FC's RTC or clock faults say).
        pub sim_time_ns: u64 { unit: "ns" },
        /// The run's seed (a recording's `seed`; `m6p-twin run --seed`).
        pub seed: u64,
        /// UTC at the run's start (simulated time zero), unix seconds: a recording's
        /// `start_utc`.
        pub start_unix_s: u64 { unit: "s" },
        /// The twin's version, major (`m6p-twin --version`).
        pub version_major: u8,
        /// The twin's version, minor.
        pub version_minor: u8,
        /// The twin's version, patch.
        pub version_patch: u8,
    }
}

csp::wire_struct! {
    /// TMSTORECLEAR reply (the twin's, 4 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct StoreCleared {
        /// Records erased.
        pub records: u32,
    }
}

/// Port 10, telemetry, as data (`csp::icd`).
pub const ICD_TELEMETRY: Port = Port {
    port: PORT_TELEMETRY,
    name: "telemetry",
    commands: &[
        Command::new(cmd::TMGEN, "TMGEN", "general telemetry").reply(Data::of::<TmGen>()),
        Command::new(cmd::TMATP, "TMATP", "attitude and position").reply(Data::of::<TmAtp>()),
        Command::new(cmd::TMACD, "TMACD", "attitude control data").reply(Data::of::<TmAcd>()),
        Command::new(cmd::TMSENS, "TMSENS", "pre-processed sensor data")
            .reply(Data::of::<TmSens>()),
        Command::new(cmd::TMRAWSENS, "TMRAWSENS", "raw sensor counts")
            .reply(Data::of::<TmRawSens>())
            .no_payloads(),
        Command::new(cmd::TMALL, "TMALL", "TMGEN, TMATP, TMACD and TMSENS at one instant, and the estimated nadir")
            .reply(Data::of::<TmAll>())
            .no_payloads(),
        Command::new(cmd::TMPERSET, "TMPERSET", "send telemetry periodically to a node and port")
            .request(Data::of::<Periodic>())
            .examples(&[&[16, 20, 0xe8, 0x03, 0, 0, 0x01], &[0, 7, 100, 0, 0, 0, 0x3f], &[30, 63, 0x80, 0xee, 0x36, 0, 0x01]])
            .no_payloads()
            .twin(),
        Command::new(cmd::TMPERGET, "TMPERGET", "read the periodic telemetry setting")
            .reply(Data::of::<Periodic>())
            .no_payloads()
            .twin(),
        Command::new(cmd::TMSTOREINFO, "TMSTOREINFO", "what the telemetry store holds")
            .reply(Data::of::<StoreInfo>())
            .no_payloads()
            .twin(),
        Command::new(cmd::TMSTOREGET, "TMSTOREGET", "stored records in an RTC range, in chunks")
            .request(Data::of::<StoreQuery>())
            .reply(Data::Variable(
                "u32 matching, u8 count, count x (u32 rtc, u8 kind, u8 len, data[len]), at most 200 bytes",
                5,
                STORE_CHUNK_BYTES,
            ))
            .examples(&[&[0, 0, 0, 0, 0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0]])
            .no_payloads()
            .twin(),
        Command::new(cmd::TMSTORECLEAR, "TMSTORECLEAR", "erase the telemetry store")
            .reply(Data::of::<StoreCleared>())
            .no_payloads()
            .twin(),
        Command::new(
            cmd::TWINSIM,
            "TWINSIM",
            "the twin's own, not the spacecraft's: simulated time since the run's start, the run's seed and start, the twin's version",
        )
        .reply(Data::of::<TwinSim>())
        .no_payloads()
        .twin(),
    ],
};

/// Port 11, RTC, as data (`csp::icd`).
pub const ICD_RTC: Port = Port {
    port: PORT_RTC,
    name: "rtc",
    commands: &[
        Command::new(cmd::RTCSTMSET, "RTCSTMSET", "set the RTC")
            .request(Data::of::<RtcTimestamp>())
            .examples(&[&[0x00, 0x6e, 0x98, 0x69]])
            .no_payloads(),
        Command::new(cmd::RTCSTMGET, "RTCSTMGET", "read the RTC").reply(Data::of::<RtcTimestamp>()),
    ],
};

/// Port 12, attitude, as data (`csp::icd`). ATCPTSET's values are read by the mode in
/// effect (earth target: latitude -90..=90 deg, longitude -180..<360 deg, height -1..=100
/// km; ECI vector: any non-zero direction); those checks are the FC's, at the command.
pub const ICD_ATTITUDE: Port = Port {
    port: PORT_ATTITUDE,
    name: "attitude",
    commands: &[
        Command::new(cmd::ATCATGET, "ATCATGET", "read the target attitude")
            .reply(Data::of::<TargetAttitude>())
            .no_payloads(),
        Command::new(
            cmd::ATCATSET,
            "ATCATSET",
            "set the target attitude (normalised; not all zeros)",
        )
        .request(Data::of::<TargetAttitude>())
        .examples(&[&[
            0, 0, 0, 0, 0, 0, 0xf0, 0x3f, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
            0, 0, 0, 0, 0,
        ]])
        .no_payloads(),
        Command::new(cmd::ATCPTGET, "ATCPTGET", "read the target point")
            .reply(Data::of::<TargetPoint>())
            .no_payloads(),
        Command::new(
            cmd::ATCPTSET,
            "ATCPTSET",
            "set the target point (read by the mode: geodetic or an ECI direction)",
        )
        .request(Data::of::<TargetPoint>())
        .examples(&[&[0; 24]])
        .no_payloads(),
        Command::new(cmd::ATCMDGET, "ATCMDGET", "read the target mode")
            .reply(Data::of::<TargetModeRepr>())
            .no_payloads(),
        Command::new(cmd::ATCMDSET, "ATCMDSET", "set the target mode")
            .request(Data::of::<TargetModeRepr>())
            .examples(&[&[3]])
            .no_payloads(),
        Command::new(
            cmd::ATCTLESET,
            "ATCTLESET",
            "give the FC a TLE (valid, within 30 days of its time)",
        )
        .request(Data::of::<TleLines>())
        .examples(&[TLE_EXAMPLE])
        .no_payloads()
        .twin(),
        Command::new(cmd::ATCTLEGET, "ATCTLEGET", "read the TLE the FC holds")
            .reply(Data::of::<TleLines>())
            .no_payloads()
            .twin(),
    ],
};

/// ATCTLESET's example: the ISS's TLE of ICD 1.5's era (2008), as 69 + 69 bytes.
const TLE_EXAMPLE: &[u8] = b"1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927\
2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537";

/// Port 13, scripts (ICD 1.5), as data: one text line per request, answered with no data.
pub const ICD_SCRIPTS: Port = Port {
    port: PORT_SCRIPTS,
    name: "scripts",
    commands: &[],
};

fn no_data<T>(r: &Request<'_>, v: T) -> Result<T, RequestError> {
    expect_len(r, 0, "0").map(|_| v)
}

fn data<T: Repr>(r: &Request<'_>, expected: &'static str) -> Result<T, RequestError> {
    expect_len(r, T::LEN, expected)?;
    T::parse(r.data).map_err(|_| RequestError::OutOfRange {
        command: r.command,
        field: "data",
    })
}

/// Shortest period of the periodic telemetry, ms.
pub const PERIODIC_MIN_MS: u32 = 100;
/// Longest period of the periodic telemetry, ms (an hour).
pub const PERIODIC_MAX_MS: u32 = 3_600_000;

csp::wire_struct! {
    /// TMPERSET request and TMPERGET reply (the twin's, 7 bytes): the FC sends the telemetry of
    /// `mask` (bit `n - 1` for telemetry command `n`: TMGEN 0x01 ... TMALL 0x20) to `dst`:`dport`
    /// every `period_ms`, each as the bytes a request for it would get (`cmd | result | data`),
    /// from the telemetry port. `period_ms` 0 stops it.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct Periodic {
        /// Destination address (0-30, not the FC's own).
        pub dst: u8 { range: (0.0, 30.0) },
        /// Destination port (7-63: not a service port).
        pub dport: u8 { range: (7.0, 63.0) },
        /// Period, ms: 0 (off) or 100..=3600000 (ten times a second at the most, once an
        /// hour at the least).
        pub period_ms: u32 { unit: "ms", range: (0.0, 3600000.0), except: (1.0, 99.0), values: &[(0, "off")] },
        /// Telemetry sent: bit `n - 1` for command `n` (1-6).
        pub mask: u8 { range: (1.0, 63.0), bits: TELEMETRY_BITS },
    }
}

impl Periodic {
    /// The telemetry command ids of `mask`, in order.
    pub fn commands(&self) -> impl Iterator<Item = u8> + '_ {
        (cmd::TMGEN..=cmd::TMALL).filter(|c| self.mask & (1 << (c - 1)) != 0)
    }
    /// The field out of range, if any (`own`: the FC's address).
    pub fn out_of_range(&self, own: u8) -> Option<&'static str> {
        if self.period_ms == 0 {
            None
        } else if !(PERIODIC_MIN_MS..=PERIODIC_MAX_MS).contains(&self.period_ms) {
            Some("period_ms")
        } else if self.dst > 30 || self.dst == own {
            Some("dst")
        } else if !(7..=63).contains(&self.dport) {
            Some("dport")
        } else if self.mask == 0 || self.mask > 0x3f {
            Some("mask")
        } else {
            None
        }
    }
}

/// The telemetry port's commands (port 10).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TelemetryCommand {
    /// TMGEN 1.
    TmGen,
    /// TMATP 2.
    TmAtp,
    /// TMACD 3.
    TmAcd,
    /// TMSENS 4.
    TmSens,
    /// TMRAWSENS 5.
    TmRawSens,
    /// TMALL 6.
    TmAll,
    /// TMPERSET 7 (ranges checked against the FC's address by the FC).
    SetPeriodic(Periodic),
    /// TMPERGET 8.
    GetPeriodic,
    /// TMSTOREINFO 9.
    StoreInfo,
    /// TMSTOREGET 10: records with an RTC in `from..=to`, from the `skip`-th on.
    StoreGet {
        /// First RTC, unix s.
        from: u32,
        /// Last RTC, unix s.
        to: u32,
        /// Matching records already read.
        skip: u32,
    },
    /// TMSTORECLEAR 11.
    StoreClear,
    /// TWINSIM 12 (the twin's own).
    TwinSim,
}

impl CommandSet for TelemetryCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        use TelemetryCommand::*;
        match r.command {
            cmd::TMGEN => no_data(r, TmGen),
            cmd::TMATP => no_data(r, TmAtp),
            cmd::TMACD => no_data(r, TmAcd),
            cmd::TMSENS => no_data(r, TmSens),
            cmd::TMRAWSENS => no_data(r, TmRawSens),
            cmd::TMALL => no_data(r, TmAll),
            cmd::TMPERSET => data(r, "7").map(SetPeriodic),
            cmd::TMPERGET => no_data(r, GetPeriodic),
            cmd::TMSTOREINFO => no_data(r, StoreInfo),
            cmd::TMSTOREGET => data::<StoreQuery>(r, "12").map(|q| StoreGet {
                from: q.from_rtc,
                to: q.to_rtc,
                skip: q.skip,
            }),
            cmd::TMSTORECLEAR => no_data(r, StoreClear),
            cmd::TWINSIM => no_data(r, TwinSim),
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// The earliest time RTCSTMSET accepts: 2000-01-01T00:00:00Z. An RTC set before the mission
/// is a mistake (a zero or a byte-order slip), and 0 is also CMP CLOCK's "read", so the
/// time the FC distributes could not be 0.
pub const RTC_MIN_UNIX_S: u32 = 946_684_800;

/// The latest time RTCSTMSET accepts: 2100-01-01T00:00:00Z. Later is a mistake too (an
/// all-ones word), and an RTC near the u32 limit would stop there and send that time on.
pub const RTC_MAX_UNIX_S: u32 = 4_102_444_800;

/// The RTC port's commands (port 11).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RtcCommand {
    /// RTCSTMSET 1: set the RTC ([`RTC_MIN_UNIX_S`]..=[`RTC_MAX_UNIX_S`]).
    Set(RtcTimestamp),
    /// RTCSTMGET 2.
    Get,
}

impl CommandSet for RtcCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        match r.command {
            cmd::RTCSTMSET => data::<RtcTimestamp>(r, "4").and_then(|t| {
                if (RTC_MIN_UNIX_S..=RTC_MAX_UNIX_S).contains(&t.rtc_timestamp) {
                    Ok(RtcCommand::Set(t))
                } else {
                    Err(RequestError::OutOfRange {
                        command: r.command,
                        field: "rtc_timestamp",
                    })
                }
            }),
            cmd::RTCSTMGET => no_data(r, RtcCommand::Get),
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// The attitude target control port's commands (port 12), validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AttitudeCommand {
    /// ATCATGET 1.
    GetAttitude,
    /// ATCATSET 2: the quaternion, already normalised.
    SetAttitude([f64; 4]),
    /// ATCPTGET 3.
    GetPoint,
    /// ATCPTSET 4: three finite values.
    SetPoint([f64; 3]),
    /// ATCMDGET 5.
    GetMode,
    /// ATCMDSET 6.
    SetMode(TargetMode),
    /// ATCTLESET 7 (the twin's extension): two 69-character TLE lines, ASCII, that pass
    /// the strict checksum.
    SetTle(TleLines),
    /// ATCTLEGET 8 (the twin's extension).
    GetTle,
}

csp::wire_struct! {
    /// Two TLE lines as they travel in ATCTLESET / ATCTLEGET: 69 + 69 ASCII bytes, no
    /// separators.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub struct TleLines {
        /// Line 1.
        pub line1: [u8; 69] { text: true },
        /// Line 2.
        pub line2: [u8; 69] { text: true },
    }
}

impl TleLines {
    /// The lines from text; `None` unless each is exactly 69 ASCII bytes.
    pub fn from_text(line1: &str, line2: &str) -> Option<Self> {
        let arr = |l: &str| -> Option<[u8; 69]> {
            if l.is_ascii() {
                l.as_bytes().try_into().ok()
            } else {
                None
            }
        };
        Some(TleLines {
            line1: arr(line1)?,
            line2: arr(line2)?,
        })
    }

    /// The lines as text.
    pub fn text(&self) -> (String, String) {
        (
            String::from_utf8_lossy(&self.line1).into_owned(),
            String::from_utf8_lossy(&self.line2).into_owned(),
        )
    }
}

impl CommandSet for AttitudeCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        use AttitudeCommand::*;
        let out_of_range = |field| RequestError::OutOfRange {
            command: r.command,
            field,
        };
        match r.command {
            cmd::ATCATGET => no_data(r, GetAttitude),
            cmd::ATCATSET => data::<TargetAttitude>(r, "32")?
                .normalised()
                .map(SetAttitude)
                .ok_or_else(|| out_of_range("quaternion")),
            cmd::ATCPTGET => no_data(r, GetPoint),
            cmd::ATCPTSET => {
                let p = data::<TargetPoint>(r, "24")?.p;
                if p.iter().all(|x| x.is_finite()) {
                    Ok(SetPoint(p))
                } else {
                    Err(out_of_range("point"))
                }
            }
            cmd::ATCMDGET => no_data(r, GetMode),
            cmd::ATCMDSET => {
                expect_len(r, 1, "1")?;
                TargetModeRepr::parse(r.data)
                    .map(|m| SetMode(m.mode))
                    .map_err(|_| out_of_range("target mode"))
            }
            cmd::ATCTLESET => {
                expect_len(r, <TleLines as Repr>::LEN, "138")?;
                let (a, b) = r.data.split_at(69);
                let text = |x: &[u8]| std::str::from_utf8(x).ok().map(str::to_owned);
                match (text(a), text(b)) {
                    (Some(l1), Some(l2))
                        if orbit::tle::Tle::parse(&l1, &l2, orbit::tle::ChecksumMode::Strict)
                            .is_ok() =>
                    {
                        TleLines::from_text(&l1, &l2)
                            .map(SetTle)
                            .ok_or_else(|| out_of_range("tle"))
                    }
                    _ => Err(out_of_range("tle")),
                }
            }
            cmd::ATCTLEGET => no_data(r, GetTle),
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// By its wire byte.
impl snap::Snap for TargetMode {
    fn save(&self, w: &mut snap::Writer) {
        snap::Snap::save(&(*self as u8), w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = snap::SnapNew::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for TargetMode {
    const MIN_BYTES: usize = 1;
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let at = r.at();
        let v = <u8 as snap::SnapNew>::read(r)?;
        TargetMode::try_from(v).map_err(|_| snap::SnapError::Bad {
            what: "TargetMode",
            at,
        })
    }
}

snap::fields!(Periodic {
    dst,
    dport,
    period_ms,
    mask
});
snap::fields!(TleLines { line1, line2 });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    // 0.707106 is the ICD 1.5 example's value, deliberately not FRAC_1_SQRT_2.
    #![allow(clippy::approx_constant)]
    use super::*;

    #[test]
    fn the_icd_description_agrees_with_the_parsers() {
        fn req(c: u8, d: &[u8]) -> Vec<u8> {
            let mut b = vec![c];
            b.extend_from_slice(d);
            b
        }
        let telemetry = csp::icd::range_disagreements(&ICD_TELEMETRY, |c, d| {
            let b = req(c, d);
            match TelemetryCommand::parse(&Request::parse(&b).unwrap()) {
                // The FC's own address (3) is refused as a destination at the command.
                Ok(TelemetryCommand::SetPeriodic(p)) => p.out_of_range(3).is_none(),
                r => r.is_ok(),
            }
        });
        assert!(telemetry.is_empty(), "{telemetry:#?}");
        let rtc = csp::icd::range_disagreements(&ICD_RTC, |c, d| {
            RtcCommand::parse(&Request::parse(&req(c, d)).unwrap()).is_ok()
        });
        assert!(rtc.is_empty(), "{rtc:#?}");
        let attitude = csp::icd::range_disagreements(&ICD_ATTITUDE, |c, d| {
            AttitudeCommand::parse(&Request::parse(&req(c, d)).unwrap()).is_ok()
        });
        assert!(attitude.is_empty(), "{attitude:#?}");
    }
    use proptest::prelude::*;

    /// Sizes of ICD tables 4.2.1-4.2.3 (with INTERPRETATION.md 5's 32 and 24 for ATC*).
    #[test]
    fn sizes_match_the_icd_tables() {
        assert_eq!(TmGen::LEN, 4 + 4 + 4 + 1 + 1 + 1 + 1);
        assert_eq!(TmGen::LEN, 16);
        assert_eq!(TmAtp::LEN, 60);
        assert_eq!(TmAcd::LEN, 19);
        assert_eq!(TmSens::LEN, 70);
        assert_eq!(TmRawSens::LEN, 53);
        assert_eq!(TmAll::LEN, 177);
        assert_eq!(RtcTimestamp::LEN, 4);
        assert_eq!(TargetAttitude::LEN, 32);
        assert_eq!(TargetPoint::LEN, 24);
        assert_eq!(TargetModeRepr::LEN, 1);
        // Emitted lengths agree with the constants.
        assert_eq!(TmGen::default().to_vec().len(), 16);
        assert_eq!(TmAtp::default().to_vec().len(), 60);
        assert_eq!(TmAcd::default().to_vec().len(), 19);
        assert_eq!(TmSens::default().to_vec().len(), 70);
        assert_eq!(TmRawSens::default().to_vec().len(), 53);
        assert_eq!(TmAll::default().to_vec().len(), 177);
        assert_eq!(TargetAttitude::default().to_vec().len(), 32);
        assert_eq!(TargetPoint::default().to_vec().len(), 24);
        assert_eq!(TargetModeRepr::default().to_vec().len(), 1);
    }

    #[test]
    fn tmgen_bytes() {
        let v = TmGen {
            rtc_timestamp: 0x6a13_a5a0,
            uptime_s: 0x0102_0304,
            global_on_time_s: 7,
            current_mode: 3,
            current_state: 0,
            mcu_temp_c: -5,
            reset_cause: 1,
        };
        let bytes = [
            0xa0, 0xa5, 0x13, 0x6a, 0x04, 0x03, 0x02, 0x01, 7, 0, 0, 0, 3, 0, 0xfb, 1,
        ];
        assert_eq!(v.to_vec(), bytes);
        assert_eq!(TmGen::parse(&bytes).unwrap(), v);
        assert_eq!(TmGen::parse(&bytes[..15]), Err(Error::Truncated));
        let mut long = bytes.to_vec();
        long.push(0);
        assert_eq!(TmGen::parse(&long), Err(Error::TooLong));
    }

    /// TWINSIM's reply: three little-endian u64 and the version's three bytes, 27 in all;
    /// in the port's table as the twin's own, refused to payloads as every command ICD 4.1
    /// does not star.
    #[test]
    fn twinsim_bytes_and_table_entry() {
        assert_eq!(TwinSim::LEN, 8 + 8 + 8 + 1 + 1 + 1);
        let v = TwinSim {
            sim_time_ns: 0x0102_0304_0506_0708,
            seed: u64::MAX - 1,
            start_unix_s: 1_777_572_000,
            version_major: 1,
            version_minor: 2,
            version_patch: 3,
        };
        let mut bytes = vec![8, 7, 6, 5, 4, 3, 2, 1, 0xfe];
        bytes.extend_from_slice(&[0xff; 7]);
        bytes.extend_from_slice(&1_777_572_000u64.to_le_bytes());
        bytes.extend_from_slice(&[1, 2, 3]);
        assert_eq!(v.to_vec(), bytes);
        assert_eq!(TwinSim::parse(&bytes).unwrap(), v);
        assert_eq!(TwinSim::parse(&bytes[..26]), Err(Error::Truncated));
        let c = ICD_TELEMETRY.command(cmd::TWINSIM).unwrap();
        assert_eq!(c.name, "TWINSIM");
        assert!(c.twin);
        assert!(c.doc.starts_with("the twin's own, not the spacecraft's"));
        assert_eq!(c.access, csp::icd::Access::NoPayloads);
        assert_eq!(c.request.fixed_len(), Some(0));
        assert_eq!(c.reply.fixed_len(), Some(27));
    }

    #[test]
    fn tmatp_bytes() {
        let v = TmAtp {
            rtc_timestamp: 1,
            q_eci_from_body: [1.0, 0.0, 0.0, -0.5],
            r_eci_m: [7e6, -2.0, 0.25],
        };
        let b = v.to_vec();
        assert_eq!(&b[..4], &[1, 0, 0, 0]);
        assert_eq!(&b[4..12], &1.0f64.to_le_bytes());
        assert_eq!(&b[28..36], &(-0.5f64).to_le_bytes());
        assert_eq!(&b[36..44], &7e6f64.to_le_bytes());
        assert_eq!(&b[52..60], &0.25f64.to_le_bytes());
        assert_eq!(TmAtp::parse(&b).unwrap(), v);
    }

    #[test]
    fn tmacd_bytes() {
        let v = TmAcd {
            rtc_timestamp: 0x0403_0201,
            state: 3,
            rw_state: [1, 1, 1, 2],
            rw_rpm_100: [10, 20, 30, 255],
            mtq_state: [0, 1, 2],
            target_mode: 7,
            target_attitude: 1,
            target_point: 0,
        };
        let b = [1, 2, 3, 4, 3, 1, 1, 1, 2, 10, 20, 30, 255, 0, 1, 2, 7, 1, 0];
        assert_eq!(v.to_vec(), b);
        assert_eq!(TmAcd::parse(&b).unwrap(), v);
        assert_eq!(rw_rpm_byte(-1234.0), 12);
        assert_eq!(rw_rpm_byte(6000.0), 60);
        assert_eq!(rw_rpm_byte(1e9), 255);
        assert_eq!(rw_rpm_byte(f64::NAN), 0);
    }

    #[test]
    fn tmsens_bytes() {
        let v = TmSens {
            rtc_timestamp: 9,
            sun_body: [0.0, 0.6, 0.8],
            rate_body_rad_s: [0.001, -0.002, 0.0],
            acc_body_m_s2: [0.0; 3],
            b_body_nt: [20000.0, -1500.5, 3.0],
            temps_c: [20, -40, 85, 0, 1, -1],
        };
        let b = v.to_vec();
        assert_eq!(&b[12..20], &0.6f64.to_le_bytes());
        assert_eq!(&b[28..32], &0.001f32.to_le_bytes());
        assert_eq!(&b[52..56], &20000.0f32.to_le_bytes());
        assert_eq!(&b[64..70], &[20, 0xd8, 85, 0, 1, 0xff]);
        assert_eq!(TmSens::parse(&b).unwrap(), v);
    }

    #[test]
    fn tmrawsens_and_tmall_bytes() {
        let v = TmRawSens {
            rtc_timestamp: 2,
            css_counts: [4095, 0, 1, 2, 3, 0x0102],
            gyro_raw: [-1, 2, 3],
            acc_raw: [100, 0, -100],
            mag_raw: [2000, -2000, 0],
            temps_raw: [200, 210, -400, 0, 0, 1],
            horizon_raw: [0, -3, 10000],
            horizon_status: 2,
        };
        let b = v.to_vec();
        assert_eq!(&b[4..6], &[0xff, 0x0f]);
        assert_eq!(&b[14..16], &[0x02, 0x01]);
        assert_eq!(&b[16..18], &[0xff, 0xff]);
        assert_eq!(&b[46..53], &[0, 0, 0xfd, 0xff, 0x10, 0x27, 2]);
        assert_eq!(TmRawSens::parse(&b).unwrap(), v);

        let all = TmAll {
            general: TmGen {
                rtc_timestamp: 5,
                ..Default::default()
            },
            attitude_position: TmAtp {
                rtc_timestamp: 5,
                q_eci_from_body: [1.0, 0.0, 0.0, 0.0],
                r_eci_m: [1.0, 2.0, 3.0],
            },
            ..Default::default()
        };
        let b = all.to_vec();
        assert_eq!(&b[..16], &all.general.to_vec()[..]);
        assert_eq!(&b[16..76], &all.attitude_position.to_vec()[..]);
        assert_eq!(&b[76..95], &all.attitude_control.to_vec()[..]);
        assert_eq!(&b[95..165], &all.sensors.to_vec()[..]);
        assert_eq!(TmAll::parse(&b).unwrap(), all);
    }

    #[test]
    fn rtc_attitude_point_mode_bytes() {
        let t = RtcTimestamp {
            rtc_timestamp: 1_777_572_000,
        };
        assert_eq!(t.to_vec(), 1_777_572_000u32.to_le_bytes());
        assert_eq!(RtcTimestamp::parse(&t.to_vec()).unwrap(), t);

        let q = TargetAttitude {
            q: [0.707106, 0.0, 0.0, -0.707106],
        };
        let b = q.to_vec();
        assert_eq!(&b[24..32], &(-0.707106f64).to_le_bytes());
        assert_eq!(TargetAttitude::parse(&b).unwrap(), q);

        let p = TargetPoint {
            p: [54.6872, 25.2797, 100.0],
        };
        let b = p.to_vec();
        assert_eq!(&b[16..24], &100.0f64.to_le_bytes());
        assert_eq!(TargetPoint::parse(&b).unwrap(), p);

        for v in 0..=9u8 {
            let m = TargetModeRepr::parse(&[v]).unwrap();
            assert_eq!(m.to_vec(), vec![v]);
        }
        assert_eq!(
            TargetModeRepr::parse(&[10]),
            Err(Error::FieldRange("target mode"))
        );
        assert_eq!(TargetModeRepr::parse(&[]), Err(Error::Truncated));
    }

    #[test]
    fn quaternion_normalisation() {
        let n = TargetAttitude {
            q: [0.707106, 0.0, 0.0, -0.707106],
        }
        .normalised()
        .unwrap();
        assert!((n.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((n[0] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-15);
        let big = TargetAttitude {
            q: [1e300, 1e300, 0.0, 0.0],
        };
        assert!(big.normalised().is_some());
        for bad in [
            [0.0; 4],
            [f64::NAN, 1.0, 0.0, 0.0],
            [f64::INFINITY, 0.0, 0.0, 0.0],
        ] {
            assert_eq!(TargetAttitude { q: bad }.normalised(), None);
        }
        assert_eq!(
            TargetAttitude {
                q: [1.0, 0.0, 0.0, 0.0]
            }
            .normalised(),
            Some([1.0, 0.0, 0.0, 0.0])
        );
    }

    fn req(command: u8, data: &[u8]) -> Request<'_> {
        Request { command, data }
    }

    #[test]
    fn command_tables() {
        assert_eq!(
            TelemetryCommand::parse(&req(2, &[])),
            Ok(TelemetryCommand::TmAtp)
        );
        // TWINSIM 12, the twin's own, takes no data; 13 is nothing.
        assert_eq!(
            TelemetryCommand::parse(&req(12, &[])),
            Ok(TelemetryCommand::TwinSim)
        );
        assert!(matches!(
            TelemetryCommand::parse(&req(12, &[0])),
            Err(RequestError::WrongLength { .. })
        ));
        assert_eq!(
            TelemetryCommand::parse(&req(13, &[])),
            Err(RequestError::UnknownCommand(13))
        );
        // TMPERSET takes 7 bytes, TMPERGET none.
        assert!(matches!(
            TelemetryCommand::parse(&req(7, &[])),
            Err(RequestError::WrongLength { .. })
        ));
        assert_eq!(
            TelemetryCommand::parse(&req(7, &[16, 20, 0xf4, 1, 0, 0, 3])),
            Ok(TelemetryCommand::SetPeriodic(Periodic {
                dst: 16,
                dport: 20,
                period_ms: 500,
                mask: 3
            }))
        );
        assert_eq!(
            TelemetryCommand::parse(&req(8, &[])),
            Ok(TelemetryCommand::GetPeriodic)
        );
        assert!(matches!(
            TelemetryCommand::parse(&req(1, &[0])),
            Err(RequestError::WrongLength { .. })
        ));
        // From 2000-01-01 to 2100-01-01: 0, 1 and an all-ones word refused, 946684800 taken.
        for t in [0u32, 1, RTC_MIN_UNIX_S - 1, RTC_MAX_UNIX_S + 1, u32::MAX] {
            assert!(matches!(
                RtcCommand::parse(&req(1, &t.to_le_bytes())),
                Err(RequestError::OutOfRange { .. })
            ));
        }
        assert_eq!(
            RtcCommand::parse(&req(1, &RTC_MIN_UNIX_S.to_le_bytes())),
            Ok(RtcCommand::Set(RtcTimestamp {
                rtc_timestamp: RTC_MIN_UNIX_S
            }))
        );
        assert!(RtcCommand::parse(&req(1, &[1, 0, 0])).is_err());
        assert!(RtcCommand::parse(&req(2, &[0])).is_err());
        assert!(RtcCommand::parse(&req(3, &[])).is_err());
        assert_eq!(
            AttitudeCommand::parse(&req(6, &[9])),
            Ok(AttitudeCommand::SetMode(TargetMode::FixedTnw))
        );
        assert!(matches!(
            AttitudeCommand::parse(&req(6, &[10])),
            Err(RequestError::OutOfRange { .. })
        ));
        assert!(AttitudeCommand::parse(&req(2, &[0; 32])).is_err());
        assert!(AttitudeCommand::parse(&req(2, &[0; 24])).is_err());
        let nan_point = TargetPoint {
            p: [1.0, f64::NAN, 0.0],
        }
        .to_vec();
        assert!(AttitudeCommand::parse(&req(4, &nan_point)).is_err());
        let point = TargetPoint { p: [1.0, 2.0, 3.0] }.to_vec();
        assert_eq!(
            AttitudeCommand::parse(&req(4, &point)),
            Ok(AttitudeCommand::SetPoint([1.0, 2.0, 3.0]))
        );
        assert!(AttitudeCommand::parse(&req(0, &[])).is_err());
        assert!(AttitudeCommand::parse(&req(7, &[])).is_err());
    }

    fn bytes_round_trip<T: Repr>(b: &[u8]) {
        let v = T::parse(b).unwrap();
        assert_eq!(v.to_vec(), b);
    }

    fn finite_f64() -> impl Strategy<Value = f64> {
        -1e12..1e12
    }

    proptest! {
        /// Every bit pattern of every layout parses and emits back to the same bytes.
        #[test]
        fn any_bytes_of_the_right_length_round_trip(b in proptest::collection::vec(any::<u8>(), 177)) {
            bytes_round_trip::<TmGen>(&b[..16]);
            bytes_round_trip::<TmAtp>(&b[..60]);
            bytes_round_trip::<TmAcd>(&b[..19]);
            bytes_round_trip::<TmSens>(&b[..70]);
            bytes_round_trip::<TmRawSens>(&b[..53]);
            bytes_round_trip::<TmAll>(&b[..177]);
            bytes_round_trip::<RtcTimestamp>(&b[..4]);
            bytes_round_trip::<TargetAttitude>(&b[..32]);
            bytes_round_trip::<TargetPoint>(&b[..24]);
            bytes_round_trip::<TwinSim>(&b[..27]);
        }

        /// Values survive emit then parse.
        #[test]
        fn values_round_trip(
            rtc in any::<u32>(), up in any::<u32>(), mode in 0u8..10, temp in any::<i8>(),
            q in proptest::array::uniform4(finite_f64()), r in proptest::array::uniform3(finite_f64()),
            rpm in proptest::array::uniform4(any::<u8>()), f in proptest::array::uniform3(any::<f32>().prop_filter("not NaN", |x| !x.is_nan())),
            raw in proptest::array::uniform3(any::<i16>()),
        ) {
            let g = TmGen { rtc_timestamp: rtc, uptime_s: up, global_on_time_s: up / 2, current_mode: mode, current_state: 0, mcu_temp_c: temp, reset_cause: 1 };
            prop_assert_eq!(TmGen::parse(&g.to_vec()).unwrap(), g);
            let a = TmAtp { rtc_timestamp: rtc, q_eci_from_body: q, r_eci_m: r };
            prop_assert_eq!(TmAtp::parse(&a.to_vec()).unwrap(), a);
            let c = TmAcd { rtc_timestamp: rtc, rw_rpm_100: rpm, target_mode: mode, ..Default::default() };
            prop_assert_eq!(TmAcd::parse(&c.to_vec()).unwrap(), c);
            let s = TmSens { rtc_timestamp: rtc, sun_body: r, rate_body_rad_s: f, acc_body_m_s2: f, b_body_nt: f, temps_c: [temp; 6] };
            prop_assert_eq!(TmSens::parse(&s.to_vec()).unwrap(), s);
            let w = TmRawSens { rtc_timestamp: rtc, gyro_raw: raw, acc_raw: raw, mag_raw: raw, horizon_raw: raw, ..Default::default() };
            prop_assert_eq!(TmRawSens::parse(&w.to_vec()).unwrap(), w);
            let all = TmAll { general: g, attitude_position: a, attitude_control: c, sensors: s, nadir_body: f };
            prop_assert_eq!(TmAll::parse(&all.to_vec()).unwrap(), all);
            let t = TargetAttitude { q };
            prop_assert_eq!(TargetAttitude::parse(&t.to_vec()).unwrap(), t);
            let p = TargetPoint { p: r };
            prop_assert_eq!(TargetPoint::parse(&p.to_vec()).unwrap(), p);
            let m = TargetModeRepr { mode: TargetMode::try_from(mode).unwrap() };
            prop_assert_eq!(TargetModeRepr::parse(&m.to_vec()).unwrap(), m);
        }

        /// Arbitrary bytes of any length never panic a parser or a command table.
        #[test]
        fn arbitrary_bytes_never_panic(command in any::<u8>(), b in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = TmGen::parse(&b);
            let _ = TmAtp::parse(&b);
            let _ = TmAcd::parse(&b);
            let _ = TmSens::parse(&b);
            let _ = TmRawSens::parse(&b);
            let _ = TmAll::parse(&b);
            let _ = RtcTimestamp::parse(&b);
            let _ = TargetAttitude::parse(&b);
            let _ = TargetPoint::parse(&b);
            let _ = TargetModeRepr::parse(&b);
            let _ = TwinSim::parse(&b);
            let r = req(command, &b);
            let _ = TelemetryCommand::parse(&r);
            let _ = RtcCommand::parse(&r);
            if let Ok(AttitudeCommand::SetAttitude(q)) = AttitudeCommand::parse(&r) {
                let n: f64 = q.iter().map(|x| x * x).sum();
                prop_assert!((n - 1.0).abs() < 1e-12, "{:?}", q);
            }
        }
    }
}
