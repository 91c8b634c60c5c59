//! The ECU's port 10 (INTERPRETATION.md section 4: "the twin defines them"): command ids,
//! request and reply data as wire representations, and the port's command table.
//!
//! # Contract
//! Every [`Repr`] here is the request or reply *data* of one command: the bytes after the
//! `command` byte of a request, or after the `command | result` head of a reply
//! (`csp::reqrep`). [`Repr::parse`] accepts exactly [`Repr::LEN`] bytes and never panics;
//! [`Repr::emit`] appends exactly `LEN` bytes. Multi-byte fields are little-endian, floats
//! IEEE-754 binary32 (ICD 1.8). A `Repr` round-trips any bytes of its length (the state byte
//! included); range checks belong to [`EcuCommand::parse`] and to the ECU itself.
//!
//! # Sizes
//! | command | request data | reply data (result 1) |
//! |---|---|---|
//! | TMECU 1 | 0 | [`TmEcu`] 42 |
//! | ARM 2 | 0 | [`ArmReply`] 4 |
//! | FIRE 3 | [`FireRequest`] 4 | [`FireReply`] 8 |
//! | SAFE 4 | 0 | 0 |
//!
//! A refused or malformed request gets `cmd | 00` and no data.

use csp::icd::{Command, Data, Port};
use csp::reqrep::{CommandSet, Request, RequestError, expect_len};

/// Default port of the ECU's telemetry and control (INTERPRETATION.md section 4).
pub const PORT_ECU: u8 = 10;

/// Command ids of port 10.
pub mod cmd {
    /// ECU telemetry.
    pub const TMECU: u8 = 1;
    /// Heaters on; firing allowed after the warm-up.
    pub const ARM: u8 = 2;
    /// Fire for a duration.
    pub const FIRE: u8 = 3;
    /// Stop firing, heaters off, disarm.
    pub const SAFE: u8 = 4;
}

/// The ECU's state as TMECU reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum EcuState {
    /// Disarmed, heaters off (after boot and SAFE).
    #[default]
    Safe = 0,
    /// Armed, heaters on, warming up: FIRE is refused.
    Warming = 1,
    /// Armed and warm: FIRE is accepted.
    Armed = 2,
    /// Firing.
    Firing = 3,
}

impl EcuState {
    /// The wire value.
    pub fn to_u8(self) -> u8 {
        self as u8
    }
    /// From the wire value.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            0 => Some(EcuState::Safe),
            1 => Some(EcuState::Warming),
            2 => Some(EcuState::Armed),
            3 => Some(EcuState::Firing),
            _ => None,
        }
    }
}

pub use csp::reqrep::le::Repr;

/// [`EcuState`]'s values by name (TMECU `state`).
pub const ECU_STATES: &[(i64, &str)] = &[(0, "safe"), (1, "warming"), (2, "armed"), (3, "firing")];

/// Port 10 as data (`csp::icd`).
pub const ICD_PORT: Port = Port {
    port: PORT_ECU,
    name: "ecu",
    commands: &[
        Command::new(cmd::TMECU, "TMECU", "the ECU's state, tank and totals")
            .reply(Data::of::<TmEcu>())
            .twin(),
        Command::new(
            cmd::ARM,
            "ARM",
            "heaters on; FIRE is accepted after the warm-up (ARM when armed changes nothing)",
        )
        .reply(Data::of::<ArmReply>())
        .no_payloads()
        .twin(),
        Command::new(
            cmd::FIRE,
            "FIRE",
            "fire for a duration (granted less when the propellant left lasts less)",
        )
        .refused_when(
            "0 ms; longer than max_burn (60 000 ms by default); not ARMED (SAFE, WARMING, \
             FIRING); the tank empty",
        )
        .request(Data::of::<FireRequest>())
        .reply(Data::of::<FireReply>())
        .examples(&[&[0x10, 0x27, 0, 0]])
        .no_payloads()
        .twin(),
        Command::new(
            cmd::SAFE,
            "SAFE",
            "stop firing, heaters off, disarm (always succeeds)",
        )
        .no_payloads()
        .twin(),
    ],
};

csp::wire_struct! {
    /// TMECU reply data (42 bytes): the ECU's state, tank and totals.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TmEcu {
        /// The ECU's state: 0 safe, 1 warming, 2 armed, 3 firing.
        pub state: u8 { values: ECU_STATES },
        /// Heaters: 0 off, 1 on (on while armed, firing included).
        pub heater: u8 { values: csp::icd::OFF_ON },
        /// Warm-up left before FIRE is accepted, ms (0 unless warming).
        pub warmup_left_ms: u32 { unit: "ms" },
        /// Time left of the current burn, ms (0 unless firing).
        pub burn_left_ms: u32 { unit: "ms" },
        /// Propellant left, kg.
        pub propellant_kg: f32 { unit: "kg" },
        /// Tank pressure, kPa.
        pub tank_pressure_kpa: f32 { unit: "kPa" },
        /// Thrust now if firing, else the thrust the next burn would start with, N.
        pub thrust_n: f32 { unit: "N" },
        /// Spacecraft mass (dry + propellant), kg.
        pub mass_kg: f32 { unit: "kg" },
        /// Total impulse delivered since the start of the run, N s.
        pub total_impulse_n_s: f32 { unit: "N s" },
        /// Burns started since the start of the run.
        pub burns: u32,
        /// Duration of the last finished burn, ms.
        pub last_burn_ms: u32 { unit: "ms" },
        /// Requests refused since the ECU's last boot.
        pub refused: u32,
    }
}

csp::wire_struct! {
    /// ARM reply data (4 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct ArmReply {
        /// Warm-up left before FIRE is accepted, ms (0: ready now).
        pub warmup_left_ms: u32 { unit: "ms" },
    }
}

csp::wire_struct! {
    /// FIRE request data (4 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct FireRequest {
        /// Burn duration, ms (1 to the configured maximum, 60 000 by default).
        pub duration_ms: u32 { unit: "ms", range: (1.0, 4294967295.0) },
    }
}

csp::wire_struct! {
    /// FIRE reply data (8 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct FireReply {
        /// The duration granted, ms: the one asked for, or shorter when the propellant left
        /// lasts less.
        pub granted_ms: u32 { unit: "ms" },
        /// Thrust of this burn, N.
        pub thrust_n: f32 { unit: "N" },
    }
}

/// The commands of port 10.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EcuCommand {
    /// TMECU 1.
    Telemetry,
    /// ARM 2.
    Arm,
    /// FIRE 3 (duration at least 1 ms; the maximum is the ECU's).
    Fire(FireRequest),
    /// SAFE 4.
    Safe,
}

impl CommandSet for EcuCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        match r.command {
            cmd::TMECU => expect_len(r, 0, "0").map(|()| EcuCommand::Telemetry),
            cmd::ARM => expect_len(r, 0, "0").map(|()| EcuCommand::Arm),
            cmd::SAFE => expect_len(r, 0, "0").map(|()| EcuCommand::Safe),
            cmd::FIRE => {
                expect_len(r, FireRequest::LEN, "4")?;
                let f = FireRequest::parse(r.data).map_err(|_| RequestError::WrongLength {
                    command: r.command,
                    expected: "4",
                    got: r.data.len(),
                })?;
                if f.duration_ms == 0 {
                    return Err(RequestError::OutOfRange {
                        command: r.command,
                        field: "duration_ms",
                    });
                }
                Ok(EcuCommand::Fire(f))
            }
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use csp::Error;
    use proptest::prelude::*;

    #[test]
    fn the_icd_description_agrees_with_the_parser() {
        let bad = csp::icd::range_disagreements(&ICD_PORT, |c, d| {
            let mut b = vec![c];
            b.extend_from_slice(d);
            EcuCommand::parse(&Request::parse(&b).unwrap()).is_ok()
        });
        assert!(bad.is_empty(), "{bad:#?}");
    }

    #[test]
    fn sizes_are_fixed() {
        assert_eq!(TmEcu::default().to_vec().len(), TmEcu::LEN);
        assert_eq!(TmEcu::LEN, 42);
        assert_eq!(ArmReply::default().to_vec().len(), 4);
        assert_eq!(FireRequest::default().to_vec().len(), 4);
        assert_eq!(FireReply::default().to_vec().len(), 8);
    }

    #[test]
    fn fire_request_bytes() {
        let f = FireRequest {
            duration_ms: 10_000,
        };
        assert_eq!(f.to_vec(), vec![0x10, 0x27, 0, 0]);
        assert_eq!(FireRequest::parse(&[0x10, 0x27, 0, 0]).unwrap(), f);
        assert_eq!(FireRequest::parse(&[0x10, 0x27, 0]), Err(Error::Truncated));
        assert_eq!(FireRequest::parse(&[0; 5]), Err(Error::TooLong));
    }

    #[test]
    fn tmecu_field_offsets() {
        let t = TmEcu {
            state: 3,
            heater: 1,
            warmup_left_ms: 0x0403_0201,
            burn_left_ms: 9_000,
            propellant_kg: 0.5,
            tank_pressure_kpa: 2200.0,
            thrust_n: 0.3,
            mass_kg: 12.5,
            total_impulse_n_s: 3.0,
            burns: 7,
            last_burn_ms: 10_000,
            refused: 2,
        };
        let b = t.to_vec();
        assert_eq!(&b[..6], &[3, 1, 1, 2, 3, 4]);
        assert_eq!(&b[6..10], &9_000u32.to_le_bytes());
        assert_eq!(&b[10..14], &0.5f32.to_le_bytes());
        assert_eq!(&b[22..26], &12.5f32.to_le_bytes());
        assert_eq!(&b[30..34], &7u32.to_le_bytes());
        assert_eq!(&b[38..42], &2u32.to_le_bytes());
        assert_eq!(TmEcu::parse(&b).unwrap(), t);
    }

    #[test]
    fn command_table() {
        let p = |b: &[u8]| EcuCommand::parse(&Request::parse(b).unwrap());
        assert_eq!(p(&[1]), Ok(EcuCommand::Telemetry));
        assert_eq!(p(&[2]), Ok(EcuCommand::Arm));
        assert_eq!(p(&[4]), Ok(EcuCommand::Safe));
        assert_eq!(
            p(&[3, 0xe8, 3, 0, 0]),
            Ok(EcuCommand::Fire(FireRequest { duration_ms: 1000 }))
        );
        assert!(matches!(
            p(&[3, 0, 0, 0, 0]),
            Err(RequestError::OutOfRange { .. })
        ));
        assert!(matches!(
            p(&[3, 1, 0, 0]),
            Err(RequestError::WrongLength { .. })
        ));
        assert!(matches!(p(&[1, 0]), Err(RequestError::WrongLength { .. })));
        assert!(matches!(p(&[2, 0]), Err(RequestError::WrongLength { .. })));
        assert!(matches!(p(&[4, 0]), Err(RequestError::WrongLength { .. })));
        assert!(matches!(p(&[0]), Err(RequestError::UnknownCommand(0))));
        assert!(matches!(p(&[5]), Err(RequestError::UnknownCommand(5))));
        for v in 0..=3 {
            assert_eq!(EcuState::from_u8(v).unwrap().to_u8(), v);
        }
        assert_eq!(EcuState::from_u8(4), None);
    }

    proptest! {
        #[test]
        fn tmecu_round_trip(b in proptest::collection::vec(any::<u8>(), 42)) {
            prop_assert_eq!(TmEcu::parse(&b).unwrap().to_vec(), b);
        }

        #[test]
        fn fire_reply_round_trip(b in proptest::collection::vec(any::<u8>(), 8)) {
            prop_assert_eq!(FireReply::parse(&b).unwrap().to_vec(), b);
        }

        #[test]
        fn decoders_never_panic(b in proptest::collection::vec(any::<u8>(), 0..80)) {
            let _ = TmEcu::parse(&b);
            let _ = ArmReply::parse(&b);
            let _ = FireRequest::parse(&b);
            let _ = FireReply::parse(&b);
            if let Ok(r) = Request::parse(&b) {
                let _ = EcuCommand::parse(&r);
            }
        }
    }
}
