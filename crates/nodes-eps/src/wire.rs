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

use csp::Error;
use csp::reqrep::le::{Reader, Writer};
use csp::reqrep::{CommandSet, Request, RequestError, expect_len};

use crate::loads::{CHANNELS, Channel};
pub use crate::protect::Thresholds;
use crate::solar::MAX_PANELS;

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
    /// Battery terminal voltage, V.
    pub battery_v: f32,
    /// Battery current, A (positive charging).
    pub battery_a: f32,
    /// State of charge, 0..=1.
    pub soc: f32,
    /// Energy stored, Wh.
    pub battery_wh: f32,
    /// Power of the arrays, W.
    pub solar_w: f32,
    /// Total load, W.
    pub load_w: f32,
    /// Panels in use.
    pub panel_count: u8,
    /// Power of each panel, W.
    pub panels_w: [f32; MAX_PANELS],
    /// Channels on.
    pub channels_on: u16,
    /// Channels shed.
    pub channels_shed: u16,
    /// Channel currents, mA.
    pub channel_ma: [u16; CHANNELS],
    /// Protection flags.
    pub protection: u8,
    /// Solar energy since boot, Wh.
    pub solar_wh: f32,
    /// Load energy since boot, Wh.
    pub load_wh: f32,
}

/// TMEPS protection flag: the battery is empty and the loads are not all supplied.
pub const PROTECTION_CUT_OFF: u8 = 1 << 2;

impl Repr for TmEps {
    const LEN: usize = 88;
    fn read(r: &mut Reader<'_>) -> Result<Self, Error> {
        let mut t = TmEps {
            battery_v: r.f32()?,
            battery_a: r.f32()?,
            soc: r.f32()?,
            battery_wh: r.f32()?,
            solar_w: r.f32()?,
            load_w: r.f32()?,
            panel_count: r.u8()?,
            ..TmEps::default()
        };
        for p in &mut t.panels_w {
            *p = r.f32()?;
        }
        t.channels_on = r.u16()?;
        t.channels_shed = r.u16()?;
        for c in &mut t.channel_ma {
            *c = r.u16()?;
        }
        t.protection = r.u8()?;
        t.solar_wh = r.f32()?;
        t.load_wh = r.f32()?;
        Ok(t)
    }
    fn write(&self, w: &mut Writer) {
        w.f32(self.battery_v)
            .f32(self.battery_a)
            .f32(self.soc)
            .f32(self.battery_wh)
            .f32(self.solar_w)
            .f32(self.load_w)
            .u8(self.panel_count);
        for p in &self.panels_w {
            w.f32(*p);
        }
        w.u16(self.channels_on).u16(self.channels_shed);
        for c in &self.channel_ma {
            w.u16(*c);
        }
        w.u8(self.protection).f32(self.solar_wh).f32(self.load_wh);
    }
}

/// CHGET and CHSET reply (4 bytes): `on u16 | shed u16`, channel masks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ChannelStates {
    /// Channels on (bit = channel id).
    pub on: u16,
    /// Channels switched off by the protection, to be restored.
    pub shed: u16,
}

impl Repr for ChannelStates {
    const LEN: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, Error> {
        Ok(ChannelStates {
            on: r.u16()?,
            shed: r.u16()?,
        })
    }
    fn write(&self, w: &mut Writer) {
        w.u16(self.on).u16(self.shed);
    }
}

/// CHSET request (2 bytes): `channel u8 | on u8`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ChannelSwitch {
    /// Channel id (0..=8: COMM1, COMM2, ECU, PC, PL12, PL13, PL14, PL15, SBAND).
    pub channel: u8,
    /// 1 on, 0 off.
    pub on: u8,
}

impl Repr for ChannelSwitch {
    const LEN: usize = 2;
    fn read(r: &mut Reader<'_>) -> Result<Self, Error> {
        Ok(ChannelSwitch {
            channel: r.u8()?,
            on: r.u8()?,
        })
    }
    fn write(&self, w: &mut Writer) {
        w.u8(self.channel).u8(self.on);
    }
}

/// THRGET reply and THRSET request (4 bytes): payload shed, payload restore, platform shed,
/// platform restore, each u8 percent of state of charge.
impl Repr for Thresholds {
    const LEN: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, Error> {
        Ok(Thresholds {
            payload_shed_pct: r.u8()?,
            payload_restore_pct: r.u8()?,
            platform_shed_pct: r.u8()?,
            platform_restore_pct: r.u8()?,
        })
    }
    fn write(&self, w: &mut Writer) {
        w.u8(self.payload_shed_pct)
            .u8(self.payload_restore_pct)
            .u8(self.platform_shed_pct)
            .u8(self.platform_restore_pct);
    }
}

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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use proptest::prelude::*;

    fn parse(b: &[u8]) -> Result<EpsCommand, RequestError> {
        EpsCommand::parse(&Request::parse(b).unwrap())
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
