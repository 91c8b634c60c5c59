//! COMM port 10 (the twin's command table; INTERPRETATION.md sections 2 and 4,
//! docs/protocol.md "COMM port 10") and the beacon layout, as wire representations.
//!
//! # Contract
//! Every type implementing [`Repr`] is the request or reply *data* of a command (the bytes
//! after `command` of a request, or after `command | result` of a reply; `csp::reqrep`),
//! with a fixed size [`Repr::LEN`]. [`Repr::parse`] accepts exactly `LEN` bytes and never
//! panics; [`Repr::emit`] appends exactly [`Repr::buffer_len`] bytes. Multi-byte fields are
//! little-endian, floats IEEE-754 single (ICD 1.8). A `Repr` is a byte-level view: any bit
//! pattern parses and emits back to the same bytes; range checks (the beacon period) belong
//! to [`CommCommand`], so every malformed request becomes the failure reply `cmd | 00`.
//!
//! # Sizes
//! | command | request data | reply data |
//! |---|---|---|
//! | TMCOMM 1 | 0 | [`TmComm`] 58 |
//! | BEACONSET 2 | [`BeaconPeriod`] 2 (0 = off, else 10..=3600 s) | 0 |
//! | BEACONGET 3 | 0 | [`BeaconPeriod`] 2 |
//! | BEACON 4 | 0 | [`Beacon`] 171 |
//!
//! The periodic beacon is an unsolicited BEACON 4 "reply": the packet data is
//! `04 | 01 | Beacon` (173 bytes), so a ground decoder of request-reply handles it as is.

use csp::icd::{Command, Data, Port};
use csp::reqrep::{CommandSet, Request, RequestError, expect_len};

/// Default port of the COMM commands (INTERPRETATION.md section 4).
pub const PORT: u8 = 10;

/// Command ids of COMM port 10 (the twin's table, docs/protocol.md).
pub mod cmd {
    /// Link state, beacon state and counters.
    pub const TMCOMM: u8 = 1;
    /// Set the beacon period.
    pub const BEACONSET: u8 = 2;
    /// Read the beacon period.
    pub const BEACONGET: u8 = 3;
    /// The beacon now (also the command id of the periodic beacon packets).
    pub const BEACON: u8 = 4;
}

/// Shortest beacon period other than off, s (the twin's choice: a 173-byte beacon takes
/// 0.15 s of air at 9600 bit/s, so 10 s keeps the beacon under 1.5 % of the channel).
pub const BEACON_PERIOD_MIN_S: u16 = 10;
/// Longest beacon period, s (one hour: at least one beacon in every LEO pass is then up to
/// the operator; longer periods are "off" in practice).
pub const BEACON_PERIOD_MAX_S: u16 = 3600;

/// [`TmComm::role`] and [`Beacon`] role values.
pub mod role {
    /// COMM1, the radio on the UHF route.
    pub const PRIMARY: u8 = 1;
    /// COMM2, the radio on standby.
    pub const SECONDARY: u8 = 2;
}

/// [`TmComm::station`] and [`Beacon::station`] when there is no truth yet (or no station).
pub const NO_STATION: u8 = 0xff;

/// [`Beacon::flags`]: the position, attitude and link fields come from a truth snapshot
/// (clear: no snapshot yet, those fields are zero).
pub const BEACON_TRUTH_VALID: u8 = 0x01;
/// [`Beacon::flags`]: a configured station sees the satellite above the mask.
pub const BEACON_IN_CONTACT: u8 = 0x02;
/// [`Beacon::flags`]: sent by the secondary COMM (after a take-over).
pub const BEACON_SECONDARY: u8 = 0x04;

pub use csp::reqrep::le::Repr;

/// TMCOMM and beacon `role` by name.
pub const ROLES: &[(i64, &str)] = &[(1, "primary"), (2, "secondary")];

/// Beacon `flags` by bit.
pub const BEACON_FLAG_BITS: &[(i64, &str)] =
    &[(0, "truth valid"), (1, "in contact"), (2, "secondary")];

/// Port 10 as data (`csp::icd`).
pub const ICD_PORT: Port = Port {
    port: PORT,
    name: "comm",
    commands: &[
        Command::new(
            cmd::TMCOMM,
            "TMCOMM",
            "link state, beacon state and counters",
        )
        .reply(Data::of::<TmComm>())
        .twin(),
        Command::new(cmd::BEACONSET, "BEACONSET", "set the beacon period")
            .request(Data::of::<BeaconPeriod>())
            .examples(&[&[60, 0]])
            .no_payloads()
            .twin(),
        Command::new(cmd::BEACONGET, "BEACONGET", "read the beacon period")
            .reply(Data::of::<BeaconPeriod>())
            .twin(),
        Command::new(
            cmd::BEACON,
            "BEACON",
            "the beacon now (also the periodic beacon's data; `seq` is the last one sent)",
        )
        .reply(Data::of::<Beacon>())
        .twin(),
    ],
};

csp::wire_struct! {
    /// TMCOMM reply (58 bytes): link state towards the best ground station, beacon state and
    /// traffic counters.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct TmComm {
        /// Which radio answers: 1 the primary (COMM1), 2 the secondary (COMM2).
        pub role: u8 { values: ROLES },
        /// 1: the radio is active (on the UHF route, beaconing); 0: standby.
        pub radio_active: u8 { values: &[(0, "standby"), (1, "active")] },
        /// 1: a configured station sees the satellite at or above the elevation mask.
        pub in_contact: u8 { values: &[(0, "no"), (1, "yes")] },
        /// Index of the station reported below (configuration order), 255 if none.
        pub station: u8,
        /// Elevation of the satellite over that station, deg.
        pub elevation_deg: f32 { unit: "deg" },
        /// Azimuth of the satellite from that station, deg from north through east.
        pub azimuth_deg: f32 { unit: "deg" },
        /// Slant range to that station, km.
        pub range_km: f32 { unit: "km" },
        /// Received signal strength estimate at that station, dBm (the noise floor out of
        /// contact).
        pub rssi_dbm: f32 { unit: "dBm" },
        /// Signal-to-noise ratio in the receiver bandwidth, dB (0 out of contact).
        pub snr_db: f32 { unit: "dB" },
        /// COMM uptime, s.
        pub uptime_s: u32 { unit: "s" },
        /// Beacons sent since boot.
        pub beacons_sent: u32,
        /// Beacon period in effect, s (0 = off).
        pub beacon_period_s: u16 { unit: "s" },
        /// UHF transmitter time spent on beacons since boot, ms.
        pub beacon_air_ms: u32 { unit: "ms" },
        /// CSP packets received by the node (local and to forward), since the run started.
        pub rx_packets: u32,
        /// CSP packets sent by the node (originated and forwarded).
        pub tx_packets: u32,
        /// CSP packets forwarded between the main bus and the radio.
        pub forwarded: u32,
        /// CSP packets and frames dropped by the node, any reason.
        pub drops: u32,
        /// Port 10 requests answered with failure since boot.
        pub refused: u32,
    }
}

csp::wire_struct! {
    /// BEACONSET request and BEACONGET reply (2 bytes).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub struct BeaconPeriod {
        /// Beacon period, s: 0 = off, else 10..=3600 (one beacon every 10 s at the most,
        /// every hour at the least).
        pub period_s: u16 { unit: "s", range: (0.0, 3600.0), except: (1.0, 9.0), values: &[(0, "off")] },
    }
}

csp::wire_struct! {
    /// The beacon (171 bytes, sized like the FC's TMALL): a one-packet summary of the
    /// spacecraft for the ground, from COMM's clock and counters and the FC's latest truth
    /// snapshot. Order on the wire is the field order here.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct Beacon {
        /// Beacon sequence number: 1 for the first beacon after boot, +1 per beacon sent.
        /// BEACON 4 requests report the number of the last beacon sent.
        pub seq: u32,
        /// COMM's clock, UTC unix seconds.
        pub utc_s: u32 { unit: "s" },
        /// COMM uptime, s.
        pub uptime_s: u32 { unit: "s" },
        /// Flags: bit 0 the fields below come from a truth snapshot (clear: none yet, they
        /// are zero), bit 1 a configured station sees the satellite, bit 2 sent by the
        /// secondary COMM.
        pub flags: u8 { bits: BEACON_FLAG_BITS },
        /// UTC unix seconds of the truth snapshot the fields below come from.
        pub truth_utc_s: u32 { unit: "s" },
        /// Position, ECI J2000, km.
        pub r_eci_km: [f32; 3] { unit: "km" },
        /// Velocity, ECI J2000, km/s.
        pub v_eci_km_s: [f32; 3] { unit: "km/s" },
        /// Sub-satellite point: geodetic latitude, deg (WGS-84).
        pub lat_deg: f32 { unit: "deg" },
        /// Sub-satellite point: longitude, deg, in (-180, 180].
        pub lon_deg: f32 { unit: "deg" },
        /// Height above the WGS-84 ellipsoid, km.
        pub alt_km: f32 { unit: "km" },
        /// Reported attitude: the active rotation body -> ECI J2000, scalar first (r, i, j, k).
        pub q_eci_from_body: [f32; 4],
        /// Body rate relative to ECI in the body frame, deg/s.
        pub w_body_deg_s: [f32; 3] { unit: "deg/s" },
        /// Unit vector to the sun in the body frame.
        pub sun_body_unit: [f32; 3],
        /// Visible fraction of the solar disc, percent (0 umbra .. 100 sunlit).
        pub sun_visible_pct: u8 { unit: "%" },
        /// Geomagnetic field in the body frame, nT.
        pub b_body_nt: [f32; 3] { unit: "nT" },
        /// Reaction wheel speeds, rpm.
        pub wheel_speed_rpm: [f32; 4] { unit: "rpm" },
        /// Magnetorquer dipoles along body X, Y, Z, A m^2.
        pub mtq_dipole_am2: [f32; 3] { unit: "A m^2" },
        /// The station of the link fields below (255 if none).
        pub station: u8,
        /// Elevation over that station, deg.
        pub elevation_deg: f32 { unit: "deg" },
        /// Azimuth from that station, deg.
        pub azimuth_deg: f32 { unit: "deg" },
        /// Slant range, km.
        pub range_km: f32 { unit: "km" },
        /// RSSI estimate at that station, dBm (as TMCOMM's `rssi_dbm`).
        pub rssi_dbm: f32 { unit: "dBm" },
        /// CSP packets received by COMM.
        pub rx_packets: u32,
        /// CSP packets sent by COMM.
        pub tx_packets: u32,
        /// CSP packets forwarded.
        pub forwarded: u32,
        /// CSP packets and frames dropped.
        pub drops: u32,
        /// COMM reboots since the run started (saturating).
        pub reboots: u16,
        /// Beacon period in effect, s.
        pub beacon_period_s: u16 { unit: "s" },
    }
}

impl Beacon {
    /// The whole beacon packet data: `04 | 01 | beacon` ([`Beacon::PACKET_LEN`] bytes).
    pub fn to_packet_data(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(Self::PACKET_LEN);
        v.push(cmd::BEACON);
        v.push(csp::reqrep::RESULT_SUCCESS);
        self.emit(&mut v);
        v
    }
    /// Bytes of a beacon packet's data (head included, CSP header excluded).
    pub const PACKET_LEN: usize = 2 + Self::LEN;
}

/// A command on COMM port 10, parsed and range-checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommCommand {
    /// TMCOMM 1.
    TmComm,
    /// BEACONSET 2 (range-checked).
    BeaconSet(BeaconPeriod),
    /// BEACONGET 3.
    BeaconGet,
    /// BEACON 4.
    Beacon,
}

impl CommandSet for CommCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        match r.command {
            cmd::TMCOMM => expect_len(r, 0, "0").map(|_| CommCommand::TmComm),
            cmd::BEACONSET => {
                let p = BeaconPeriod::parse(r.data).map_err(|_| RequestError::WrongLength {
                    command: r.command,
                    expected: "2",
                    got: r.data.len(),
                })?;
                if p.period_s != 0
                    && !(BEACON_PERIOD_MIN_S..=BEACON_PERIOD_MAX_S).contains(&p.period_s)
                {
                    return Err(RequestError::OutOfRange {
                        command: r.command,
                        field: "period_s",
                    });
                }
                Ok(CommCommand::BeaconSet(p))
            }
            cmd::BEACONGET => expect_len(r, 0, "0").map(|_| CommCommand::BeaconGet),
            cmd::BEACON => expect_len(r, 0, "0").map(|_| CommCommand::Beacon),
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
            req(&b).is_ok()
        });
        assert!(bad.is_empty(), "{bad:#?}");
    }

    fn req(b: &[u8]) -> Result<CommCommand, RequestError> {
        CommCommand::parse(&Request::parse(b).unwrap())
    }

    #[test]
    fn sizes_are_fixed() {
        assert_eq!(TmComm::LEN, 58);
        assert_eq!(TmComm::default().to_vec().len(), 58);
        assert_eq!(BeaconPeriod::LEN, 2);
        assert_eq!(Beacon::LEN, 171);
        assert_eq!(Beacon::default().to_vec().len(), 171);
        assert_eq!(Beacon::PACKET_LEN, 173);
        assert_eq!(Beacon::default().to_packet_data()[..2], [4, 1]);
    }

    #[test]
    fn tmcomm_bytes_in_order() {
        let t = TmComm {
            role: 1,
            radio_active: 1,
            in_contact: 1,
            station: 0,
            elevation_deg: 90.0,
            azimuth_deg: 0.5,
            range_km: 600.0,
            rssi_dbm: -100.0,
            snr_db: 28.5,
            uptime_s: 0x0403_0201,
            beacons_sent: 10,
            beacon_period_s: 60,
            beacon_air_ms: 1475,
            rx_packets: 1,
            tx_packets: 2,
            forwarded: 3,
            drops: 4,
            refused: 5,
        };
        let b = t.to_vec();
        assert_eq!(&b[..4], &[1, 1, 1, 0]);
        assert_eq!(&b[4..8], &90.0f32.to_le_bytes());
        assert_eq!(&b[16..20], &(-100.0f32).to_le_bytes());
        assert_eq!(&b[24..28], &[1, 2, 3, 4]);
        assert_eq!(&b[28..32], &[10, 0, 0, 0]);
        assert_eq!(&b[32..34], &[60, 0]);
        assert_eq!(&b[34..38], &1475u32.to_le_bytes());
        assert_eq!(
            &b[38..],
            &[1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 4, 0, 0, 0, 5, 0, 0, 0]
        );
        assert_eq!(TmComm::parse(&b).unwrap(), t);
        assert_eq!(TmComm::parse(&b[..57]), Err(Error::Truncated));
        let mut long = b.clone();
        long.push(0);
        assert_eq!(TmComm::parse(&long), Err(Error::TooLong));
    }

    #[test]
    fn beacon_offsets() {
        let bc = Beacon {
            seq: 7,
            flags: BEACON_TRUTH_VALID | BEACON_IN_CONTACT,
            q_eci_from_body: [1.0, 0.0, 0.0, 0.0],
            sun_visible_pct: 100,
            station: 0,
            reboots: 2,
            beacon_period_s: 60,
            ..Beacon::default()
        };
        let b = bc.to_vec();
        assert_eq!(&b[..4], &[7, 0, 0, 0]);
        assert_eq!(b[12], 3);
        // q at 4+4+4+1+4 + 12 + 12 + 12 = 53.
        assert_eq!(&b[53..57], &1.0f32.to_le_bytes());
        // sun_visible_pct at 53 + 16 + 12 + 12 = 93, station at 93 + 1 + 12 + 16 + 12 = 134.
        assert_eq!(b[93], 100);
        assert_eq!(b[134], 0);
        assert_eq!(&b[167..], &[2, 0, 60, 0]);
        assert_eq!(Beacon::parse(&b).unwrap(), bc);
    }

    #[test]
    fn command_table_checks_lengths_and_ranges() {
        assert_eq!(req(&[1]), Ok(CommCommand::TmComm));
        assert_eq!(req(&[3]), Ok(CommCommand::BeaconGet));
        assert_eq!(req(&[4]), Ok(CommCommand::Beacon));
        assert_eq!(
            req(&[2, 60, 0]),
            Ok(CommCommand::BeaconSet(BeaconPeriod { period_s: 60 }))
        );
        assert_eq!(
            req(&[2, 0, 0]),
            Ok(CommCommand::BeaconSet(BeaconPeriod { period_s: 0 }))
        );
        assert_eq!(
            req(&[2, 0x10, 0x0e]),
            Ok(CommCommand::BeaconSet(BeaconPeriod { period_s: 3600 }))
        );
        for bad in [&[2u8, 9, 0][..], &[2, 0x11, 0x0e], &[2, 1, 0]] {
            assert!(matches!(req(bad), Err(RequestError::OutOfRange { .. })));
        }
        for bad in [
            &[2u8][..],
            &[2, 60],
            &[2, 60, 0, 0],
            &[1, 0],
            &[3, 0],
            &[4, 0, 0],
        ] {
            assert!(matches!(req(bad), Err(RequestError::WrongLength { .. })));
        }
        assert_eq!(req(&[0]), Err(RequestError::UnknownCommand(0)));
        assert_eq!(req(&[5]), Err(RequestError::UnknownCommand(5)));
    }

    proptest! {
        #[test]
        fn tmcomm_round_trip(b in proptest::collection::vec(any::<u8>(), 58)) {
            prop_assert_eq!(TmComm::parse(&b).unwrap().to_vec(), b);
        }

        #[test]
        fn beacon_round_trip(b in proptest::collection::vec(any::<u8>(), 171)) {
            prop_assert_eq!(Beacon::parse(&b).unwrap().to_vec(), b);
        }

        #[test]
        fn decoders_never_panic(b in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = TmComm::parse(&b);
            let _ = Beacon::parse(&b);
            let _ = BeaconPeriod::parse(&b);
            if let Ok(r) = Request::parse(&b) {
                let _ = CommCommand::parse(&r);
            }
        }
    }
}
