//! The EPS's port 10 (telemetry and control; the twin's design, INTERPRETATION.md
//! sections 2 and 4) as wire representations and a command table.
//!
//! # Contract
//! Every type implementing [`Repr`] is the request or reply *data* of a command (the bytes
//! after the `command` byte of a request, or after `command | result` of a reply), with a
//! fixed size [`Repr::LEN`]. `parse` accepts exactly `LEN` bytes and never panics; `emit`
//! appends exactly `LEN` bytes. Multi-byte fields are little-endian, floats IEEE-754 (ICD
//! 1.8). A `Repr` round-trips any bytes of its length; range checks (a known channel, an
//! on/off of 0 or 1, thresholds `shed < restore <= 100`) belong to [`EpsCommand`], whose
//! refusals are answered `command 00` with no data.
//!
//! # Port 10
//! | id | command | request data | reply data |
//! |---|---|---|---|
//! | 1 | TMEPS | 0 | [`TmEps`] 88 |
//! | 2 | CHGET | 0 | [`ChannelStates`] 4 |
//! | 3 | CHSET | [`ChannelSwitch`] 2 | [`ChannelStates`] 4 (after the switch) |
//! | 4 | THRGET | 0 | [`Thresholds`] 4 |
//! | 5 | THRSET | [`Thresholds`] 4 | 0 |
//!
//! CHSET fails (result 0) for an unknown channel (id > 8), an `on` other than 0 or 1, and
//! for switching on a channel whose protection group is shed. Switching a channel to the
//! state it already has succeeds and changes nothing.

use csp::icd::{Command, Data, Port};
use csp::reqrep::{CommandSet, Request, RequestError, expect_len};

/// Default port of the EPS's telemetry and control (INTERPRETATION.md section 4).
pub const PORT_EPS: u8 = 10;

/// Command ids of port 10.
pub mod cmd {
    /// Telemetry: battery, arrays, loads, channels.
    pub const TMEPS: u8 = 1;
    /// Read the channel states.
    pub const CHGET: u8 = 2;
    /// Switch one channel on or off.
    pub const CHSET: u8 = 3;
    /// Read the protection thresholds.
    pub const THRGET: u8 = 4;
    /// Set the protection thresholds.
    pub const THRSET: u8 = 5;
}

pub use csp::reqrep::le::Repr;

/// Channel ids and names (ICD 4.3's power channels, in id order).
pub const CHANNEL_NAMES: &[(i64, &str)] = &[
    (0, "COMM1"),
    (1, "COMM2"),
    (2, "ECU"),
    (3, "PC"),
    (4, "PL12"),
    (5, "PL13"),
    (6, "PL14"),
    (7, "PL15"),
    (8, "SBAND"),
];

/// Channel masks: bit = channel id (the same names).
pub const CHANNEL_BITS: &[(i64, &str)] = CHANNEL_NAMES;

/// TMEPS protection flags.
pub const PROTECTION_BITS: &[(i64, &str)] = &[
    (0, "payload group shed"),
    (1, "platform group shed"),
    (2, "battery empty (cut-off)"),
];

csp::wire_struct! {
    /// TMEPS reply (88 bytes): the EPS's telemetry.
    ///
    /// | offset | field | type |
    /// |---|---|---|
    /// | 0 | battery voltage, V | f32 |
    /// | 4 | battery current, A (positive charging) | f32 |
    /// | 8 | state of charge, 0..=1 | f32 |
    /// | 12 | stored energy, Wh | f32 |
    /// | 16 | solar array power, W | f32 |
    /// | 20 | total load, W | f32 |
    /// | 24 | panels in use (0..=8) | u8 |
    /// | 25 | power of panel 0..7, W (0 past the count) | f32 x 8 |
    /// | 57 | channels on (bit = channel id) | u16 |
    /// | 59 | channels shed by the protection | u16 |
    /// | 61 | current of channel 0..8, mA at the battery voltage | u16 x 9 |
    /// | 79 | protection: bit 0 payload group shed, bit 1 platform group shed, bit 2 battery empty (cut-off) | u8 |
    /// | 80 | solar energy since the EPS booted, Wh | f32 |
    /// | 84 | load energy since the EPS booted, Wh | f32 |
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TmEps {
        /// Battery terminal voltage.
        pub battery_v: f32 { unit: "V" },
        /// Battery current (positive charging).
        pub battery_a: f32 { unit: "A" },
        /// State of charge, 0..=1.
        pub soc: f32,
        /// Energy stored.
        pub battery_wh: f32 { unit: "Wh" },
        /// Power of the arrays.
        pub solar_w: f32 { unit: "W" },
        /// Total load.
        pub load_w: f32 { unit: "W" },
        /// Panels in use (0..=8).
        pub panel_count: u8,
        /// Power of each panel (0 past the count).
        pub panels_w: [f32; MAX_PANELS] { unit: "W" },
        /// Channels on (bit = channel id).
        pub channels_on: u16 { bits: CHANNEL_BITS },
        /// Channels switched off by the protection, to be restored.
        pub channels_shed: u16 { bits: CHANNEL_BITS },
        /// Current of each channel at the battery voltage.
        pub channel_ma: [u16; CHANNELS] { unit: "mA" },
        /// Protection flags.
        pub protection: u8 { bits: PROTECTION_BITS },
        /// Solar energy since the EPS booted.
        pub solar_wh: f32 { unit: "Wh" },
        /// Load energy since the EPS booted.
        pub load_wh: f32 { unit: "Wh" },
    }
}

/// TMEPS protection flag: the battery is empty and the loads are not all supplied.
pub const PROTECTION_CUT_OFF: u8 = 1 << 2;

csp::wire_struct! {
    /// CHGET and CHSET reply (4 bytes): `on u16 | shed u16`, channel masks.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct ChannelStates {
        /// Channels on (bit = channel id).
        pub on: u16 { bits: CHANNEL_BITS },
        /// Channels switched off by the protection, to be restored.
        pub shed: u16 { bits: CHANNEL_BITS },
    }
}

csp::wire_struct! {
    /// CHSET request (2 bytes): `channel u8 | on u8`.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct ChannelSwitch {
        /// Channel id.
        pub channel: u8 { range: (0.0, 8.0), values: CHANNEL_NAMES },
        /// 1 on, 0 off.
        pub on: u8 { range: (0.0, 1.0), values: csp::icd::OFF_ON },
    }
}

/// Port 10 as data (`csp::icd`): the commands, their layouts and who may send them.
pub const ICD_PORT: Port = Port {
    port: PORT_EPS,
    name: "eps",
    commands: &[
        Command::new(
            cmd::TMEPS,
            "TMEPS",
            "the EPS's telemetry: battery, arrays, loads, channels",
        )
        .reply(Data::of::<TmEps>())
        .twin(),
        Command::new(cmd::CHGET, "CHGET", "read the channel states")
            .reply(Data::of::<ChannelStates>())
            .twin(),
        Command::new(
            cmd::CHSET,
            "CHSET",
            "switch one channel on or off; the reply is the channels after the switch \
             (switching to the state it has succeeds and changes nothing)",
        )
        .refused_when("switching on a channel whose group the protection has shed")
        .request(Data::of::<ChannelSwitch>())
        .reply(Data::of::<ChannelStates>())
        .examples(&[&[3, 1]])
        .no_payloads()
        .twin(),
        Command::new(cmd::THRGET, "THRGET", "read the protection thresholds")
            .reply(Data::of::<Thresholds>())
            .twin(),
        Command::new(cmd::THRSET, "THRSET", "set the protection thresholds")
            .refused_when("a group's shed threshold not below its restore threshold")
            .request(Data::of::<Thresholds>())
            .examples(&[&[30, 40, 20, 30], &[0, 1, 0, 1], &[99, 100, 99, 100]])
            .no_payloads()
            .twin(),
    ],
};

/// A request on port 10, checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpsCommand {
    /// TMEPS.
    TmEps,
    /// CHGET.
    ChGet,
    /// CHSET.
    ChSet {
        /// The channel.
        channel: Channel,
        /// On or off.
        on: bool,
    },
    /// THRGET.
    ThrGet,
    /// THRSET.
    ThrSet(Thresholds),
}

fn data<T: Repr>(r: &Request<'_>, expected: &'static str) -> Result<T, RequestError> {
    expect_len(r, T::LEN, expected)?;
    T::parse(r.data).map_err(|_| RequestError::WrongLength {
        command: r.command,
        expected,
        got: r.data.len(),
    })
}

impl CommandSet for EpsCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        let range = |field| RequestError::OutOfRange {
            command: r.command,
            field,
        };
        match r.command {
            cmd::TMEPS => expect_len(r, 0, "0").map(|_| EpsCommand::TmEps),
            cmd::CHGET => expect_len(r, 0, "0").map(|_| EpsCommand::ChGet),
            cmd::CHSET => {
                let s: ChannelSwitch = data(r, "2")?;
                let channel = Channel::from_id(s.channel).ok_or_else(|| range("channel"))?;
                let on = match s.on {
                    0 => false,
                    1 => true,
                    _ => return Err(range("on")),
                };
                Ok(EpsCommand::ChSet { channel, on })
            }
            cmd::THRGET => expect_len(r, 0, "0").map(|_| EpsCommand::ThrGet),
            cmd::THRSET => {
                let t: Thresholds = data(r, "4")?;
                t.validate().map_err(range)?;
                Ok(EpsCommand::ThrSet(t))
            }
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

/// A switched power channel (the wire id is the value; the mask bit is `1 << id`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Channel {
    /// COMM primary (CSP 1). Never shed by the protection.
    Comm1 = 0,
    /// COMM secondary (CSP 2). Never shed by the protection.
    Comm2 = 1,
    /// ECU, propulsion (CSP 5).
    Ecu = 2,
    /// Payload controller (CSP 6).
    Pc = 3,
    /// Payload 12.
    Payload12 = 4,
    /// Payload 13.
    Payload13 = 5,
    /// Payload 14.
    Payload14 = 6,
    /// Payload 15.
    Payload15 = 7,
    /// The S-band transmitter (the PC's downlink; not a CSP node).
    Sband = 8,
}

/// Number of channels.
pub const CHANNELS: usize = 9;
/// Mask of every channel.
pub const ALL_CHANNELS: u16 = (1 << CHANNELS) - 1;

impl Channel {
    /// Every channel, in id order.
    pub const ALL: [Channel; CHANNELS] = [
        Channel::Comm1,
        Channel::Comm2,
        Channel::Ecu,
        Channel::Pc,
        Channel::Payload12,
        Channel::Payload13,
        Channel::Payload14,
        Channel::Payload15,
        Channel::Sband,
    ];
    /// The wire id.
    pub fn id(self) -> u8 {
        self as u8
    }
    /// From the wire id.
    pub fn from_id(id: u8) -> Option<Self> {
        Self::ALL.get(usize::from(id)).copied()
    }
    /// The bit in a channel mask.
    pub fn bit(self) -> u16 {
        1 << (self as u16)
    }
    /// The CSP node this channel powers (`None` for the S-band transmitter).
    pub fn node_addr(self) -> Option<u8> {
        match self {
            Channel::Comm1 => Some(1),
            Channel::Comm2 => Some(2),
            Channel::Ecu => Some(5),
            Channel::Pc => Some(6),
            Channel::Payload12 => Some(12),
            Channel::Payload13 => Some(13),
            Channel::Payload14 => Some(14),
            Channel::Payload15 => Some(15),
            Channel::Sband => None,
        }
    }
    /// The channel of CSP node `addr`, if it has one.
    pub fn of_node(addr: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.node_addr() == Some(addr))
    }
    /// A short name (`COMM1`, `PL12`, `SBAND`).
    pub fn name(self) -> &'static str {
        match self {
            Channel::Comm1 => "COMM1",
            Channel::Comm2 => "COMM2",
            Channel::Ecu => "ECU",
            Channel::Pc => "PC",
            Channel::Payload12 => "PL12",
            Channel::Payload13 => "PL13",
            Channel::Payload14 => "PL14",
            Channel::Payload15 => "PL15",
            Channel::Sband => "SBAND",
        }
    }
    /// The channel of a name as [`Channel::name`] gives it (case-insensitive).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|c| c.name().eq_ignore_ascii_case(name))
    }
}

/// A group of channels shed together.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Group {
    /// Payloads 12-15 and the S-band.
    Payload = 0,
    /// The PC and the ECU.
    Platform = 1,
}

impl Group {
    /// Both groups.
    pub const ALL: [Group; 2] = [Group::Payload, Group::Platform];
    /// The channel mask of the group.
    pub fn channels(self) -> u16 {
        match self {
            Group::Payload => {
                Channel::Payload12.bit()
                    | Channel::Payload13.bit()
                    | Channel::Payload14.bit()
                    | Channel::Payload15.bit()
                    | Channel::Sband.bit()
            }
            Group::Platform => Channel::Pc.bit() | Channel::Ecu.bit(),
        }
    }
    /// The group of a channel (`None` for COMM1 and COMM2).
    pub fn of(c: Channel) -> Option<Group> {
        Self::ALL.into_iter().find(|g| g.channels() & c.bit() != 0)
    }
    /// The bit in the telemetry's protection byte.
    pub fn bit(self) -> u8 {
        1 << (self as u8)
    }
}

csp::wire_struct! {
    /// Shed and restore thresholds, percent of state of charge (the wire layout of THRGET
    /// and THRSET, 4 bytes). A group is shed below its shed threshold and restored at or
    /// above its restore threshold; `shed < restore <= 100` for each group.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub struct Thresholds {
        /// Shed the payload group below this.
        pub payload_shed_pct: u8 { unit: "%", range: (0.0, 99.0) },
        /// Restore it at or above this.
        pub payload_restore_pct: u8 { unit: "%", range: (1.0, 100.0) },
        /// Shed the platform group below this.
        pub platform_shed_pct: u8 { unit: "%", range: (0.0, 99.0) },
        /// Restore it at or above this.
        pub platform_restore_pct: u8 { unit: "%", range: (1.0, 100.0) },
    }
}

impl Default for Thresholds {
    /// 30/40 % for the payload group, 20/30 % for the platform group.
    fn default() -> Self {
        Thresholds {
            payload_shed_pct: 30,
            payload_restore_pct: 40,
            platform_shed_pct: 20,
            platform_restore_pct: 30,
        }
    }
}

impl Thresholds {
    /// Check `shed < restore <= 100` for each group; the error names the field.
    pub fn validate(&self) -> Result<(), &'static str> {
        if self.payload_restore_pct > 100 {
            return Err("payload restore threshold");
        }
        if self.payload_shed_pct >= self.payload_restore_pct {
            return Err("payload shed threshold");
        }
        if self.platform_restore_pct > 100 {
            return Err("platform restore threshold");
        }
        if self.platform_shed_pct >= self.platform_restore_pct {
            return Err("platform shed threshold");
        }
        Ok(())
    }
    /// A group's (shed, restore) thresholds, percent.
    pub fn of(&self, g: Group) -> (u8, u8) {
        match g {
            Group::Payload => (self.payload_shed_pct, self.payload_restore_pct),
            Group::Platform => (self.platform_shed_pct, self.platform_restore_pct),
        }
    }
}

/// At most this many solar panels (the telemetry's fixed slots).
pub const MAX_PANELS: usize = 8;

/// By its wire id.
impl snap::Snap for Channel {
    fn save(&self, w: &mut snap::Writer) {
        snap::Snap::save(&(*self as u8), w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = snap::SnapNew::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for Channel {
    const MIN_BYTES: usize = 1;
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let at = r.at();
        let id = <u8 as snap::SnapNew>::read(r)?;
        Channel::ALL
            .get(usize::from(id))
            .copied()
            .ok_or(snap::SnapError::Bad {
                what: "Channel",
                at,
            })
    }
}

snap::fields!(Thresholds {
    payload_shed_pct,
    payload_restore_pct,
    platform_shed_pct,
    platform_restore_pct
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use csp::Error;
    use proptest::prelude::*;

    fn parse(b: &[u8]) -> Result<EpsCommand, RequestError> {
        EpsCommand::parse(&Request::parse(b).unwrap())
    }

    #[test]
    fn the_icd_description_agrees_with_the_parser() {
        let bad = csp::icd::range_disagreements(&ICD_PORT, |c, d| {
            let mut b = vec![c];
            b.extend_from_slice(d);
            parse(&b).is_ok()
        });
        assert!(bad.is_empty(), "{bad:#?}");
        for c in ICD_PORT.commands {
            assert!(
                parse(&[c.id]).is_ok() || c.request.fixed_len() != Some(0),
                "{}",
                c.name
            );
        }
    }

    #[test]
    fn sizes_are_fixed() {
        assert_eq!(TmEps::LEN, 6 * 4 + 1 + 8 * 4 + 2 + 2 + 9 * 2 + 1 + 2 * 4);
        assert_eq!(TmEps::default().to_vec().len(), 88);
        assert_eq!(ChannelStates::default().to_vec().len(), 4);
        assert_eq!(ChannelSwitch::default().to_vec().len(), 2);
        assert_eq!(Thresholds::default().to_vec().len(), 4);
    }

    #[test]
    fn tmeps_byte_layout() {
        let t = TmEps {
            battery_v: 7.5,
            battery_a: -1.25,
            soc: 0.5,
            battery_wh: 38.5,
            solar_w: 20.0,
            load_w: 8.0,
            panel_count: 6,
            panels_w: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0, 0.0],
            channels_on: 0x01ff,
            channels_shed: 0x0100,
            channel_ma: [66, 67, 40, 80, 67, 67, 67, 67, 160],
            protection: 0b101,
            solar_wh: 100.0,
            load_wh: 50.0,
        };
        let b = t.to_vec();
        assert_eq!(&b[0..4], &7.5f32.to_le_bytes());
        assert_eq!(&b[4..8], &(-1.25f32).to_le_bytes());
        assert_eq!(&b[8..12], &0.5f32.to_le_bytes());
        assert_eq!(&b[20..24], &8.0f32.to_le_bytes());
        assert_eq!(b[24], 6);
        assert_eq!(&b[25..29], &1.0f32.to_le_bytes());
        assert_eq!(&b[45..49], &6.0f32.to_le_bytes());
        assert_eq!(&b[57..61], &[0xff, 0x01, 0x00, 0x01]);
        assert_eq!(&b[61..63], &[66, 0]);
        assert_eq!(&b[77..79], &[160, 0]);
        assert_eq!(b[79], 0b101);
        assert_eq!(&b[80..84], &100.0f32.to_le_bytes());
        assert_eq!(&b[84..88], &50.0f32.to_le_bytes());
        assert_eq!(TmEps::parse(&b).unwrap(), t);
        assert_eq!(TmEps::parse(&b[..87]), Err(Error::Truncated));
    }

    #[test]
    fn commands_parse_with_exact_sizes() {
        assert_eq!(parse(&[1]), Ok(EpsCommand::TmEps));
        assert_eq!(parse(&[2]), Ok(EpsCommand::ChGet));
        assert_eq!(
            parse(&[3, 3, 0]),
            Ok(EpsCommand::ChSet {
                channel: Channel::Pc,
                on: false
            })
        );
        assert_eq!(
            parse(&[3, 8, 1]),
            Ok(EpsCommand::ChSet {
                channel: Channel::Sband,
                on: true
            })
        );
        assert_eq!(parse(&[4]), Ok(EpsCommand::ThrGet));
        assert_eq!(
            parse(&[5, 25, 35, 10, 20]),
            Ok(EpsCommand::ThrSet(Thresholds {
                payload_shed_pct: 25,
                payload_restore_pct: 35,
                platform_shed_pct: 10,
                platform_restore_pct: 20
            }))
        );
    }

    #[test]
    fn malformed_requests_are_refused() {
        for bad in [
            &[1, 0][..],           // TMEPS with data
            &[2, 0, 0],            // CHGET with data
            &[3, 1],               // CHSET short
            &[3, 1, 1, 0],         // CHSET long
            &[3, 9, 1],            // no channel 9
            &[3, 1, 2],            // on must be 0 or 1
            &[4, 1],               // THRGET with data
            &[5, 30, 40, 20],      // THRSET short
            &[5, 40, 40, 20, 30],  // shed == restore
            &[5, 30, 40, 20, 101], // restore above 100
            &[6],                  // unknown
            &[0],                  // unknown
        ] {
            assert!(parse(bad).is_err(), "{bad:?}");
        }
    }

    proptest! {
        /// Every bit pattern of every layout parses and emits back to the same bytes.
        #[test]
        fn any_bytes_of_the_right_length_round_trip(b in proptest::collection::vec(any::<u8>(), 88)) {
            prop_assert_eq!(TmEps::parse(&b).unwrap().to_vec(), b.clone());
            prop_assert_eq!(ChannelStates::parse(&b[..4]).unwrap().to_vec(), b[..4].to_vec());
            prop_assert_eq!(ChannelSwitch::parse(&b[..2]).unwrap().to_vec(), b[..2].to_vec());
            prop_assert_eq!(Thresholds::parse(&b[..4]).unwrap().to_vec(), b[..4].to_vec());
        }

        /// The command table never panics and accepts only the listed shapes.
        #[test]
        fn any_request_parses_or_is_refused(b in proptest::collection::vec(any::<u8>(), 1..100)) {
            if let Ok(c) = parse(&b) {
                let expected_len = match c {
                    EpsCommand::TmEps | EpsCommand::ChGet | EpsCommand::ThrGet => 1,
                    EpsCommand::ChSet { .. } => 3,
                    EpsCommand::ThrSet(_) => 5,
                };
                prop_assert_eq!(b.len(), expected_len);
            }
        }
    }
}
