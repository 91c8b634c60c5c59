//! CSP over UDP: one packet per datagram, as libcsp's UDP interface sends it and as YAMCS's
//! CSP support (`org.yamcs.tctm.csp`) reads and writes it:
//!
//! ```text
//! CSP header (4 bytes, network byte order) | data
//! ```
//!
//! - The header is in network order, as on KISS and CAN (not the hub's host order).
//! - No framing and no link CRC: a packet with the CSP CRC32 flag carries its CRC at the
//!   end of its data as on any interface.
//! - At most [`UDP_MTU`] data bytes each way, the twin's packet size on every link (KISS's
//!   and the hub's 256).

use std::fmt;

use crate::header::{HEADER_LEN, Header};
use crate::packet::Packet;

/// Largest data a datagram carries each way.
pub const UDP_MTU: usize = 256;

/// Why a datagram was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UdpDrop {
    /// Shorter than the header.
    Short,
    /// More data than [`UDP_MTU`].
    Oversize,
}

impl fmt::Display for UdpDrop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            UdpDrop::Short => "CSP/UDP datagram shorter than the 4-byte header",
            UdpDrop::Oversize => "CSP/UDP datagram over the 256-byte MTU",
        })
    }
}

/// The packet of a datagram.
pub fn decode(datagram: &[u8]) -> Result<Packet, UdpDrop> {
    let (word, data) = datagram
        .split_first_chunk::<HEADER_LEN>()
        .ok_or(UdpDrop::Short)?;
    if data.len() > UDP_MTU {
        return Err(UdpDrop::Oversize);
    }
    Ok(Packet::new(
        Header::from_word(u32::from_be_bytes(*word)),
        data.to_vec(),
    ))
}

/// Append the datagram of `packet` to `out`.
pub fn encode(packet: &Packet, out: &mut Vec<u8>) {
    out.reserve(HEADER_LEN + packet.data.len());
    out.extend_from_slice(&packet.header.to_word().to_be_bytes());
    out.extend_from_slice(&packet.data);
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A ping 17:40 -> 3:1 of 4 bytes: the header word of `Header::new(17, 3, 1, 40)`,
    /// priority 2, is 0xa230_6800 (pri 2 << 30 | src 17 << 25 | dst 3 << 20 | dport 1 <<
    /// 14 | sport 40 << 8), sent big-endian, as YAMCS's `CspPacket` reads it.
    #[test]
    fn a_ping_in_a_datagram() {
        let msg = [0xa2, 0x30, 0x68, 0x00, 1, 2, 3, 4];
        let p = decode(&msg).unwrap();
        assert_eq!(p.header, Header::new(17, 3, 1, 40));
        assert_eq!(p.data, [1, 2, 3, 4]);
        let mut out = Vec::new();
        encode(&p, &mut out);
        assert_eq!(out, msg);
    }

    #[test]
    fn short_and_oversize_datagrams_are_refused() {
        assert_eq!(decode(&[]), Err(UdpDrop::Short));
        assert_eq!(decode(&[0, 0, 0]), Err(UdpDrop::Short));
        assert!(decode(&[0, 0, 0, 0]).is_ok());
        let mut big = vec![0; HEADER_LEN + UDP_MTU];
        assert!(decode(&big).is_ok());
        big.push(0);
        assert_eq!(decode(&big), Err(UdpDrop::Oversize));
    }
}
