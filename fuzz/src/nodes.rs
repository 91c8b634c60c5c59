//! The six node cores of the M6P network as [`NodeKind`]s, each with a generator of
//! well-formed ICD requests (command id and fields of the right length and mostly in range)
//! beside the harness's raw packets.

use std::time::Duration;

use csp::SimTime;
use m6p_twin::network::Role;
use platform::board::Boards;

use crate::harness::{CmdCtx, NodeKind, START_UNIX_S};

/// The default scenario's 6U (scenarios/default.toml, crates/twin/src/plan.rs tests).
pub const TLE_6U: (&str, &str) = (
    "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
    "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
);

/// `[cmd] + data`.
fn req(cmd: u8, data: &[u8]) -> Vec<u8> {
    let mut v = Vec::with_capacity(1 + data.len());
    v.push(cmd);
    v.extend_from_slice(data);
    v
}

/// Any command on one of the node's ICD ports.
fn unknown(ports: &[u8], port_i: u8, id: u8, data: &[u8]) -> (u8, Vec<u8>) {
    (ports[usize::from(port_i) % ports.len()], req(id, data))
}

// ---------------------------------------------------------------------------------------
// FC
// ---------------------------------------------------------------------------------------

fuzz_struct! {
    /// Two TLE lines of the fixed-column format with correct checksums, built from fields
    /// (each mapped into or near its valid range); `base` keeps the 6U's lines.
    pub struct TleGen {
        pub base: bool,
        pub satnum: u16,
        pub year: u8,
        pub day_offset_cday: i16,
        pub ndot: i16,
        pub bstar: i16,
        pub bstar_exp: u8,
        pub incl_cdeg: u16,
        pub raan_cdeg: u16,
        pub ecc: u32,
        pub argp_cdeg: u16,
        pub ma_cdeg: u16,
        pub mm_urev: u32,
        pub revs: u16,
    }
}

impl TleGen {
    /// The two lines.
    pub fn lines(&self) -> (String, String) {
        if self.base {
            return (TLE_6U.0.to_owned(), TLE_6U.1.to_owned());
        }
        let satnum = u32::from(self.satnum) % 100_000;
        // 2026 mostly (the run's year); sometimes any two-digit year.
        let yy = if self.year < 200 {
            26
        } else {
            u32::from(self.year) % 100
        };
        let day = 120.75 + f64::from(self.day_offset_cday) / 100.0;
        let day_txt = format!("{:012.8}", day);
        let ndot = f64::from(self.ndot) * 1e-8;
        let ndot_txt = format!("{:+.8}", ndot)
            .replace("+0.", " .")
            .replace("-0.", "-.");
        let bstar_txt = format!(
            "{}{:05}-{}",
            if self.bstar < 0 { '-' } else { ' ' },
            self.bstar.unsigned_abs(),
            self.bstar_exp % 10
        );
        let l1 = format!(
            "1 {satnum:05}U 26012AC  {yy:02}{day_txt} {ndot_txt:>10}  00000-0 {bstar_txt:>8} 0  999"
        );
        let incl = f64::from(self.incl_cdeg % 18_100) / 100.0;
        let raan = f64::from(self.raan_cdeg % 36_000) / 100.0;
        let ecc = self.ecc % 10_000_000;
        let argp = f64::from(self.argp_cdeg % 36_000) / 100.0;
        let ma = f64::from(self.ma_cdeg % 36_000) / 100.0;
        // 0-20 rev/day: LEO is 14-16, GEO 1, and out of range both ways.
        let mm = f64::from(self.mm_urev % 20_000_000) * 1e-6;
        let revs = u32::from(self.revs) % 100_000;
        let l2 = format!(
            "2 {satnum:05} {incl:8.4} {raan:8.4} {ecc:07} {argp:8.4} {ma:8.4} {mm:11.8}{revs:5}"
        );
        (with_checksum(&l1), with_checksum(&l2))
    }
}

/// Pad or cut to 68 columns and append the TLE checksum.
fn with_checksum(l: &str) -> String {
    let mut s: String = format!("{l:<68}").chars().take(68).collect();
    s.push(char::from(b'0' + orbit::tle::checksum(&s)));
    s
}

fuzz_struct! {
    /// An ICD 1.5 mission-controller script line: `adcs START END pointXXX ...`, with its
    /// times relative to the FC's clock now and a few of the tolerated spellings.
    pub struct ScriptGen {
        pub frame: u8,
        pub start_rel_ds: i16,
        pub dur_ds: u16,
        pub q: [i16; 4],
        pub lat_cdeg: i16,
        pub lon_cdeg: i16,
        pub alt_m: i32,
        pub axis: [i8; 3],
        pub style: u8,
    }
}

impl ScriptGen {
    /// The line, as bytes (it may end in `;`, a NUL or CR LF).
    pub fn line(&self, ctx: &CmdCtx) -> Vec<u8> {
        let start = (ctx.unix_s() + f64::from(self.start_rel_ds) / 10.0).round();
        let end = start + f64::from(self.dur_ds) / 10.0;
        let upper = self.style & 1 != 0;
        let sep = if self.style & 2 != 0 { "\t" } else { " " };
        let kw = ["pointECI", "pointLVLH", "pointTNW", "pointGEO"][usize::from(self.frame % 4)];
        let q = self.q.map(|x| f64::from(x) / 32767.0);
        let mut fields: Vec<String> = vec![
            "adcs".to_owned(),
            if self.style & 32 != 0 {
                format!("{start:e}")
            } else {
                format!("{start}")
            },
            format!("{end}"),
            kw.to_owned(),
        ];
        if self.frame % 4 == 3 {
            fields.push(format!("{}", f64::from(self.lat_cdeg) / 100.0 % 91.0));
            fields.push(format!("{}", f64::from(self.lon_cdeg) / 100.0));
            fields.push(format!("{}", f64::from(self.alt_m) / 10.0));
            fields.extend(self.axis.iter().map(|x| format!("{x}")));
        } else {
            fields.extend(q.iter().map(|x| format!("{x}")));
        }
        let mut line = fields.join(sep);
        if upper {
            line = line.to_ascii_uppercase();
        }
        if self.style & 4 != 0 {
            line.push(';');
        }
        if self.style & 8 != 0 {
            line.push('\0');
        }
        if self.style & 16 != 0 {
            line.push_str("\r\n");
        }
        line.into_bytes()
    }
}

fuzz_enum! {
    /// The FC's requests (ICD 4.2, the twin's ATCTLE* extension, ICD 1.5 scripts).
    pub enum FcCmd {
        /// Port 10: TMGEN ... TMALL (1 + id % 6).
        Telemetry { id: u8 },
        /// Port 11: RTCSTMSET to any time.
        RtcSet { t: u32 },
        /// Port 11: RTCSTMSET near the true time.
        RtcSetNear { dt_s: i32 },
        /// Port 11: RTCSTMGET.
        RtcGet,
        /// Port 12: ATCATGET.
        GetAttitude,
        /// Port 12: ATCATSET with a quaternion from small integers (all zero is refused).
        SetAttitude { q: [i16; 4] },
        /// Port 12: ATCATSET with any bit patterns (NaN, infinities, huge).
        SetAttitudeRaw { q: [u64; 4] },
        /// Port 12: ATCPTGET.
        GetPoint,
        /// Port 12: ATCPTSET with a plausible point (lat, lon deg; alt m, or an ECI vector).
        SetPoint { a_cdeg: i16, b_cdeg: i16, c_m: i32 },
        /// Port 12: ATCPTSET with any bit patterns.
        SetPointRaw { p: [u64; 3] },
        /// Port 12: ATCMDGET.
        GetMode,
        /// Port 12: ATCMDSET (mode % 12: 10 and 11 are not modes).
        SetMode { m: u8 },
        /// Port 12: ATCTLESET.
        SetTle { tle: TleGen },
        /// Port 12: ATCTLEGET.
        GetTle,
        /// Port 13: a script line.
        Script { s: ScriptGen },
        /// Any command id and data on an FC port.
        Unknown { port_i: u8, id: u8, data: Vec<u8> },
    }
}

fuzz_struct! {
    /// The FC's configuration choices. `orbit`: the 6U's TLE, held onboard at boot
    /// (commissioning done), except [`FC_TLE_NOT_UPLOADED`] (the FC has no orbit until
    /// ATCTLESET or a GPS fix) and [`FC_NO_TLE`] (no true orbit either).
    pub struct FcSetup {
        pub orbit: u8,
        pub mode: u8,
        pub hz: u8,
    }
}

/// [`FcSetup::orbit`]: the TLE is not uploaded at boot.
pub const FC_TLE_NOT_UPLOADED: u8 = 0xfe;
/// [`FcSetup::orbit`]: no TLE at all.
pub const FC_NO_TLE: u8 = 0xff;

/// The flight computer (CSP 3).
#[derive(Debug)]
pub struct Fc;

impl NodeKind for Fc {
    type App = nodes_fc::FcApp;
    type Setup = FcSetup;
    type Cmd = FcCmd;
    const ROLE: Role = Role::Fc;
    const ADDR: u8 = platform::addr::FC;
    const ICD_PORTS: &'static [u8] = nodes_fc::PORTS;
    const TIME_BUDGET: Duration = Duration::from_secs(120);
    const WORK_BUDGET: usize = 40;

    fn app(s: &FcSetup, boards: &Boards) -> nodes_fc::FcApp {
        let mode = nodes_fc::wire::TargetMode::try_from(s.mode % 10).unwrap_or_default();
        let cfg = nodes_fc::FcConfig {
            epoch_unix_s: START_UNIX_S,
            tle: (s.orbit != FC_NO_TLE).then(|| (TLE_6U.0.to_owned(), TLE_6U.1.to_owned())),
            tle_uploaded: s.orbit != FC_TLE_NOT_UPLOADED,
            seed: 0x300,
            // 10 Hz (the default) mostly; 1 and 5 Hz sometimes.
            adcs_hz: [10, 10, 1, 5][usize::from(s.hz % 4)],
            initial_mode: mode,
            ..nodes_fc::FcConfig::default()
        };
        nodes_fc::FcApp::new(cfg)
            .with_truth_board(boards.truth.clone())
            .with_burns(boards.burns.clone())
    }

    fn command(cmd: &FcCmd, ctx: &CmdCtx) -> (u8, Vec<u8>) {
        use nodes_fc::wire::{PORT_ATTITUDE, PORT_RTC, PORT_SCRIPTS, PORT_TELEMETRY, cmd as c};
        match cmd {
            FcCmd::Telemetry { id } => (PORT_TELEMETRY, vec![1 + id % 6]),
            FcCmd::RtcSet { t } => (PORT_RTC, req(c::RTCSTMSET, &t.to_le_bytes())),
            FcCmd::RtcSetNear { dt_s } => {
                let t = (ctx.unix_s() as i64 + i64::from(*dt_s)).clamp(0, i64::from(u32::MAX));
                (PORT_RTC, req(c::RTCSTMSET, &(t as u32).to_le_bytes()))
            }
            FcCmd::RtcGet => (PORT_RTC, vec![c::RTCSTMGET]),
            FcCmd::GetAttitude => (PORT_ATTITUDE, vec![c::ATCATGET]),
            FcCmd::SetAttitude { q } => {
                let d: Vec<u8> = q
                    .iter()
                    .flat_map(|x| (f64::from(*x) / 1000.0).to_le_bytes())
                    .collect();
                (PORT_ATTITUDE, req(c::ATCATSET, &d))
            }
            FcCmd::SetAttitudeRaw { q } => {
                let d: Vec<u8> = q.iter().flat_map(|x| x.to_le_bytes()).collect();
                (PORT_ATTITUDE, req(c::ATCATSET, &d))
            }
            FcCmd::GetPoint => (PORT_ATTITUDE, vec![c::ATCPTGET]),
            FcCmd::SetPoint {
                a_cdeg,
                b_cdeg,
                c_m,
            } => {
                let p = [
                    f64::from(*a_cdeg) / 100.0 % 90.0,
                    f64::from(*b_cdeg) / 100.0,
                    f64::from(*c_m) / 100.0,
                ];
                let d: Vec<u8> = p.iter().flat_map(|x| x.to_le_bytes()).collect();
                (PORT_ATTITUDE, req(c::ATCPTSET, &d))
            }
            FcCmd::SetPointRaw { p } => {
                let d: Vec<u8> = p.iter().flat_map(|x| x.to_le_bytes()).collect();
                (PORT_ATTITUDE, req(c::ATCPTSET, &d))
            }
            FcCmd::GetMode => (PORT_ATTITUDE, vec![c::ATCMDGET]),
            FcCmd::SetMode { m } => (PORT_ATTITUDE, vec![c::ATCMDSET, m % 12]),
            FcCmd::SetTle { tle } => {
                let (l1, l2) = tle.lines();
                let mut d = l1.into_bytes();
                d.extend_from_slice(l2.as_bytes());
                (PORT_ATTITUDE, req(c::ATCTLESET, &d))
            }
            FcCmd::GetTle => (PORT_ATTITUDE, vec![c::ATCTLEGET]),
            FcCmd::Script { s } => (PORT_SCRIPTS, s.line(ctx)),
            FcCmd::Unknown { port_i, id, data } => unknown(Self::ICD_PORTS, *port_i, *id, data),
        }
    }
}

// ---------------------------------------------------------------------------------------
// PC
// ---------------------------------------------------------------------------------------

fuzz_enum! {
    /// The PC's requests (ICD 3.1.8 SETUP, STATUS, ABORT; ingest; TMPC).
    pub enum PcCmd {
        /// Port 10: SETUP. The duration is 5-900 s unless its top bit is set (then raw);
        /// the start is relative to now (`i16::MIN`: 0, at once).
        Setup { session: u8, start_rel_s: i16, duration_s: u16, max_packets: u16, frame: u8, sync: Vec<u8> },
        /// Port 10: STATUS.
        Status { session: u8 },
        /// Port 10: ABORT.
        Abort { session: u8 },
        /// Port 12: TMPC.
        Tmpc,
        /// Port 11: raw ingest data.
        Ingest { data: Vec<u8> },
        /// Any command id and data on a PC port.
        Unknown { port_i: u8, id: u8, data: Vec<u8> },
    }
}

/// The payload controller (CSP 6).
#[derive(Debug)]
pub struct Pc;

impl NodeKind for Pc {
    type App = nodes_pc::PcApp;
    type Setup = ();
    type Cmd = PcCmd;
    const ROLE: Role = Role::Pc;
    const ADDR: u8 = platform::addr::PC;
    const ICD_PORTS: &'static [u8] = nodes_pc::PORTS;
    const TIME_BUDGET: Duration = Duration::from_secs(600);
    const WORK_BUDGET: usize = 200;

    fn app(_: &(), boards: &Boards) -> nodes_pc::PcApp {
        nodes_pc::PcApp::new(nodes_pc::PcConfig::default()).with_activity(boards.activity.clone())
    }

    fn command(cmd: &PcCmd, ctx: &CmdCtx) -> (u8, Vec<u8>) {
        use nodes_pc::wire::{PORT_CONTROL, PORT_INGEST, PORT_TELEMETRY, cmd as c};
        match cmd {
            PcCmd::Setup {
                session,
                start_rel_s,
                duration_s,
                max_packets,
                frame,
                sync,
            } => {
                let ts = if *start_rel_s == i16::MIN {
                    0
                } else {
                    (ctx.unix_s() as i64 + i64::from(*start_rel_s)).clamp(0, i64::from(u32::MAX))
                        as u32
                };
                let dur = if duration_s & 0x8000 == 0 {
                    5 + duration_s % 896
                } else {
                    duration_s & 0x7fff
                };
                let mut d = vec![session % 4];
                d.extend_from_slice(&ts.to_le_bytes());
                d.extend_from_slice(&dur.to_le_bytes());
                d.extend_from_slice(&max_packets.to_le_bytes());
                d.push(*frame);
                d.extend_from_slice(&sync[..sync.len().min(130)]);
                (PORT_CONTROL, req(c::SETUP, &d))
            }
            PcCmd::Status { session } => (PORT_CONTROL, vec![c::STATUS, session % 4]),
            PcCmd::Abort { session } => (PORT_CONTROL, vec![c::ABORT, session % 4]),
            PcCmd::Tmpc => (PORT_TELEMETRY, vec![c::TMPC]),
            PcCmd::Ingest { data } => (PORT_INGEST, data.clone()),
            PcCmd::Unknown { port_i, id, data } => unknown(Self::ICD_PORTS, *port_i, *id, data),
        }
    }
}

// ---------------------------------------------------------------------------------------
// EPS
// ---------------------------------------------------------------------------------------

fuzz_enum! {
    /// The EPS's requests on port 10.
    pub enum EpsCmd {
        /// TMEPS.
        Tmeps,
        /// CHGET.
        Chget,
        /// CHSET (channel % 10: 9 is no channel; on % 3: 2 is refused).
        Chset { ch: u8, on: u8 },
        /// THRGET.
        Thrget,
        /// THRSET (percentages % 128).
        Thrset { t: [u8; 4] },
        /// Any command id and data on port 10.
        Unknown { id: u8, data: Vec<u8> },
    }
}

/// The power system (CSP 4).
#[derive(Debug)]
pub struct Eps;

impl NodeKind for Eps {
    type App = nodes_eps::EpsApp;
    type Setup = ();
    type Cmd = EpsCmd;
    const ROLE: Role = Role::Eps;
    const ADDR: u8 = platform::addr::EPS;
    const ICD_PORTS: &'static [u8] = nodes_eps::PORTS;
    const TIME_BUDGET: Duration = Duration::from_secs(600);
    const WORK_BUDGET: usize = 200;

    fn app(_: &(), boards: &Boards) -> nodes_eps::EpsApp {
        nodes_eps::EpsApp::new(nodes_eps::EpsConfig::default())
            .with_truth(boards.truth.clone())
            .with_activity(boards.activity.clone())
    }

    fn command(cmd: &EpsCmd, _: &CmdCtx) -> (u8, Vec<u8>) {
        use nodes_eps::wire::{PORT_EPS, cmd as c};
        match cmd {
            EpsCmd::Tmeps => (PORT_EPS, vec![c::TMEPS]),
            EpsCmd::Chget => (PORT_EPS, vec![c::CHGET]),
            EpsCmd::Chset { ch, on } => (PORT_EPS, vec![c::CHSET, ch % 10, on % 3]),
            EpsCmd::Thrget => (PORT_EPS, vec![c::THRGET]),
            EpsCmd::Thrset { t } => (PORT_EPS, req(c::THRSET, &t.map(|x| x % 128))),
            EpsCmd::Unknown { id, data } => (PORT_EPS, req(*id, data)),
        }
    }
}

// ---------------------------------------------------------------------------------------
// ECU
// ---------------------------------------------------------------------------------------

fuzz_enum! {
    /// The ECU's requests on port 10.
    pub enum EcuCmd {
        /// TMECU.
        Tmecu,
        /// ARM.
        Arm,
        /// FIRE: `ms % 70000` unless the top bit is set (then raw).
        Fire { ms: u32 },
        /// SAFE.
        Safe,
        /// Any command id and data on port 10.
        Unknown { id: u8, data: Vec<u8> },
    }
}

/// The propulsion unit (CSP 5).
#[derive(Debug)]
pub struct Ecu;

impl NodeKind for Ecu {
    type App = nodes_ecu::EcuApp;
    type Setup = ();
    type Cmd = EcuCmd;
    const ROLE: Role = Role::Ecu;
    const ADDR: u8 = platform::addr::ECU;
    const ICD_PORTS: &'static [u8] = nodes_ecu::PORTS;
    const TIME_BUDGET: Duration = Duration::from_secs(600);
    const WORK_BUDGET: usize = 300;

    fn app(_: &(), boards: &Boards) -> nodes_ecu::EcuApp {
        nodes_ecu::EcuApp::new(nodes_ecu::EcuConfig::default())
            .with_burns(boards.burns.clone())
            .with_activity(boards.activity.clone())
    }

    fn command(cmd: &EcuCmd, _: &CmdCtx) -> (u8, Vec<u8>) {
        use nodes_ecu::wire::{PORT_ECU, cmd as c};
        match cmd {
            EcuCmd::Tmecu => (PORT_ECU, vec![c::TMECU]),
            EcuCmd::Arm => (PORT_ECU, vec![c::ARM]),
            EcuCmd::Fire { ms } => {
                let ms = if ms & 0x8000_0000 == 0 {
                    ms % 70_000
                } else {
                    *ms
                };
                (PORT_ECU, req(c::FIRE, &ms.to_le_bytes()))
            }
            EcuCmd::Safe => (PORT_ECU, vec![c::SAFE]),
            EcuCmd::Unknown { id, data } => (PORT_ECU, req(*id, data)),
        }
    }
}

// ---------------------------------------------------------------------------------------
// COMM
// ---------------------------------------------------------------------------------------

fuzz_enum! {
    /// COMM's requests on port 10.
    pub enum CommCmd {
        /// TMCOMM.
        Tmcomm,
        /// BEACONSET: 0 or 10-3600 s unless the top bit is set (then raw).
        BeaconSet { s: u16 },
        /// BEACONGET.
        BeaconGet,
        /// BEACON.
        Beacon,
        /// Any command id and data on port 10.
        Unknown { id: u8, data: Vec<u8> },
    }
}

/// The primary UHF radio (CSP 1).
#[derive(Debug)]
pub struct Comm;

impl NodeKind for Comm {
    type App = nodes_comm::CommApp;
    type Setup = ();
    type Cmd = CommCmd;
    const ROLE: Role = Role::CommPrimary;
    const ADDR: u8 = platform::addr::COMM1;
    const ICD_PORTS: &'static [u8] = nodes_comm::PORTS;
    const TIME_BUDGET: Duration = Duration::from_secs(600);
    const WORK_BUDGET: usize = 300;

    fn app(_: &(), boards: &Boards) -> nodes_comm::CommApp {
        nodes_comm::CommApp::new(nodes_comm::CommConfig::default()).with_truth(boards.truth.clone())
    }

    fn command(cmd: &CommCmd, _: &CmdCtx) -> (u8, Vec<u8>) {
        use nodes_comm::wire::{PORT, cmd as c};
        match cmd {
            CommCmd::Tmcomm => (PORT, vec![c::TMCOMM]),
            CommCmd::BeaconSet { s } => {
                let s = match s {
                    x if x & 0x8000 != 0 => x & 0x7fff,
                    x if x % 16 == 0 => 0,
                    x => 10 + x % 3591,
                };
                (PORT, req(c::BEACONSET, &s.to_le_bytes()))
            }
            CommCmd::BeaconGet => (PORT, vec![c::BEACONGET]),
            CommCmd::Beacon => (PORT, vec![c::BEACON]),
            CommCmd::Unknown { id, data } => (PORT, req(*id, data)),
        }
    }
}

// ---------------------------------------------------------------------------------------
// Payload
// ---------------------------------------------------------------------------------------

fuzz_enum! {
    /// A payload's requests (ICD 3.1.8.2 SYNC and POLL).
    pub enum PayloadCmd {
        /// SYNC with a message (cut at 140 bytes: more than 128 is refused).
        Sync { msg: Vec<u8> },
        /// POLL with a frame size (0 and 255 are refused).
        Poll { frame: u8 },
        /// Any command id and data on port 10.
        Unknown { id: u8, data: Vec<u8> },
    }
}

fuzz_struct! {
    /// A payload's configuration choices: its behaviour at boot and one change, and
    /// whether it pushes data to the PC (buffering mode).
    pub struct PayloadSetup {
        pub behaviour: u8,
        pub param: u16,
        pub later: u8,
        pub later_at_s: u16,
        pub push: bool,
        pub rate: Option<u16>,
    }
}

fn behaviour(b: u8, param: u16) -> nodes_payload::Behaviour {
    use nodes_payload::Behaviour as B;
    match b % 9 {
        0 => B::Normal,
        1 => B::NoAck,
        2 => B::WrongEcho,
        3 => B::Slow {
            extra: Duration::from_millis(u64::from(param)),
        },
        4 => B::SilentFor {
            polls: u32::from(param % 64),
        },
        5 => B::Silent,
        6 => B::Oversize {
            extra_bytes: param as u8,
        },
        7 => B::Garbage,
        _ => B::ZeroLength,
    }
}

/// A simulated payload (CSP 12).
#[derive(Debug)]
pub struct Payload;

impl NodeKind for Payload {
    type App = nodes_payload::PayloadApp;
    type Setup = PayloadSetup;
    type Cmd = PayloadCmd;
    const ROLE: Role = Role::Payload;
    const ADDR: u8 = 12;
    const ICD_PORTS: &'static [u8] = nodes_payload::PORTS;
    const TIME_BUDGET: Duration = Duration::from_secs(600);
    const WORK_BUDGET: usize = 200;

    fn app(s: &PayloadSetup, _: &Boards) -> nodes_payload::PayloadApp {
        let cfg = nodes_payload::PayloadConfig {
            behaviour: behaviour(s.behaviour, s.param),
            timeline: vec![(
                SimTime::ZERO + Duration::from_secs(u64::from(s.later_at_s % 600)),
                behaviour(s.later, s.param),
            )],
            push: s.push.then(nodes_payload::PushConfig::default),
            rate_bytes_per_s: s.rate.map(u64::from),
            seed: 7,
            ..nodes_payload::PayloadConfig::default()
        };
        nodes_payload::PayloadApp::new(cfg)
    }

    fn command(cmd: &PayloadCmd, _: &CmdCtx) -> (u8, Vec<u8>) {
        use nodes_payload::wire::PORT;
        use nodes_pc::wire::cmd as c;
        match cmd {
            PayloadCmd::Sync { msg } => (PORT, req(c::SYNC, &msg[..msg.len().min(140)])),
            PayloadCmd::Poll { frame } => (PORT, vec![c::POLL, *frame]),
            PayloadCmd::Unknown { id, data } => (PORT, req(*id, data)),
        }
    }
}
