//! The M6P network's address table (INTERPRETATION.md section 1), in one place: which CSP
//! address is which node, and which segment an address belongs to.
//!
//! | node | CSP id | segment |
//! |---|---|---|
//! | COMM primary / secondary | 1 / 2 | main CAN (and the UHF radio) |
//! | FC (flight computer, ADCS) | 3 | main CAN |
//! | EPS | 4 | main CAN |
//! | ECU (propulsion) | 5 | main CAN |
//! | PC (payload controller) | 6 | main CAN and payload CAN (it routes between them) |
//! | reserved | 7-11 | nothing answers |
//! | payloads | 12-15 | payload CAN |
//! | main ground station / payload ground stations | 16 / 17-20 | ground segment, reached through COMM (UHF) |
//! | broadcast | 31 | |

use std::ops::RangeInclusive;

/// Address of the primary COMM.
pub const COMM1: u8 = 1;
/// Address of the secondary COMM.
pub const COMM2: u8 = 2;
/// Address of the flight computer.
pub const FC: u8 = 3;
/// Address of the EPS.
pub const EPS: u8 = 4;
/// Address of the ECU.
pub const ECU: u8 = 5;
/// Address of the payload controller.
pub const PC: u8 = 6;
/// The platform's nodes: COMM1, COMM2, FC, EPS, ECU, PC.
pub const PLATFORM: RangeInclusive<u8> = COMM1..=PC;
/// Reserved addresses (nothing answers).
pub const RESERVED: RangeInclusive<u8> = 7..=11;
/// Payload addresses (the payload CAN bus).
pub const PAYLOADS: RangeInclusive<u8> = 12..=15;
/// Ground segment addresses (the main station is 16).
pub const GROUND: RangeInclusive<u8> = 16..=20;
/// The main ground station.
pub const MAIN_GROUND_STATION: u8 = 16;
/// CSP broadcast (libcsp 1.4 `CSP_BROADCAST_ADDR`).
pub const BROADCAST: u8 = 31;

/// The media of the network an address can sit on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Segment {
    /// The main CAN bus (COMM, FC, EPS, ECU, PC; any address not below).
    Main,
    /// The payload CAN bus (PC, payloads 12-15).
    Payload,
    /// The ground segment (16-20), behind COMM's UHF radio.
    Ground,
}

impl Segment {
    /// The segment of `addr` by the table: 12-15 the payload bus, 16-20 the ground,
    /// anything else the main bus.
    pub fn of(addr: u8) -> Segment {
        if PAYLOADS.contains(&addr) {
            Segment::Payload
        } else if GROUND.contains(&addr) {
            Segment::Ground
        } else {
            Segment::Main
        }
    }

    /// The CAN next hop for a packet from this segment to `dst` (CFP destination), by the
    /// static routing of the table: the PC joins the two buses, COMM1 is the main bus's way
    /// to the ground. `None` off the CAN buses.
    pub fn next_hop(self, dst: u8) -> Option<u8> {
        match (self, Segment::of(dst)) {
            (Segment::Ground, _) => None,
            (Segment::Payload, Segment::Payload) | (Segment::Main, Segment::Main) => Some(dst),
            (Segment::Payload, _) | (Segment::Main, Segment::Payload) => Some(PC),
            (Segment::Main, Segment::Ground) => Some(COMM1),
        }
    }
}

/// What the platform lets a payload (12-15) ask of it.
///
/// ICD 4.1 stars the FC commands available to a payload (TMGEN, TMATP, TMACD, TMSENS,
/// RTCSTMGET, the service handler's ping and uptime), and ICD 3.1.1 keeps session
/// configuration (the PC's SETUP and ABORT) on the mission side. Under [`Icd`](Self::Icd)
/// any other command from a payload gets the failure reply, counted and logged, and any
/// other service of a platform node's service handler (reboot, CMP, ps, memfree, buf_free)
/// is dropped, counted and logged, as libcsp drops what it does not serve; a lab bench may
/// open everything ([`Open`](Self::Open)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PayloadAccess {
    /// The ICD's rules (the default).
    #[default]
    Icd,
    /// A payload may use every command (a lab bench).
    Open,
}

impl PayloadAccess {
    /// Whether a request from `src` is refused, given whether its command is open to
    /// payloads.
    pub fn refuses(self, src: u8, open_to_payloads: bool) -> bool {
        self == PayloadAccess::Icd && PAYLOADS.contains(&src) && !open_to_payloads
    }
}

/// The name of a platform node by its address (`COMM1`, `FC`, `PL12`, `GS16`), `None` for
/// reserved and unused addresses.
pub fn node_name(addr: u8) -> Option<String> {
    Some(match addr {
        COMM1 => "COMM1".to_owned(),
        COMM2 => "COMM2".to_owned(),
        FC => "FC".to_owned(),
        EPS => "EPS".to_owned(),
        ECU => "ECU".to_owned(),
        PC => "PC".to_owned(),
        a if PAYLOADS.contains(&a) => format!("PL{a}"),
        a if GROUND.contains(&a) => format!("GS{a}"),
        _ => return None,
    })
}

snap::unit_enum!(PayloadAccess { Icd, Open });

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_and_next_hops_follow_the_table() {
        assert_eq!(Segment::of(3), Segment::Main);
        assert_eq!(Segment::of(9), Segment::Main);
        assert_eq!(Segment::of(12), Segment::Payload);
        assert_eq!(Segment::of(20), Segment::Ground);
        assert_eq!(Segment::Payload.next_hop(13), Some(13));
        assert_eq!(Segment::Payload.next_hop(3), Some(PC));
        assert_eq!(Segment::Payload.next_hop(16), Some(PC));
        assert_eq!(Segment::Main.next_hop(12), Some(PC));
        assert_eq!(Segment::Main.next_hop(17), Some(COMM1));
        assert_eq!(Segment::Main.next_hop(4), Some(4));
        assert_eq!(Segment::Ground.next_hop(3), None);
        assert_eq!(node_name(14).as_deref(), Some("PL14"));
        assert_eq!(node_name(8), None);
    }
}
