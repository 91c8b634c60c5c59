//! The message format of libcsp 1.4's ZMQ hub interface (`csp_if_zmqhub.c`).
//!
//! A node's PUB socket sends, and its SUB socket receives, one ZMQ message per packet:
//!
//! ```text
//! via (1 byte) | CSP header (4 bytes, the sender's host byte order) | data
//! ```
//!
//! - `via` is the next hop's address, which subscribers filter on (each node subscribes to
//!   its own address byte, 255 to everything): `csp_rtable_find_mac(dst)`, or the
//!   destination itself when the route has no MAC (`CSP_NODE_MAC`, the usual default
//!   route).
//! - The header is the packet's memory as it is (`csp_id_t` is a bit-field union over a
//!   `uint32_t`), unlike KISS and CAN, which convert it to network order: on the little-
//!   endian hosts libcsp programs run on (x86-64, ARM) it is the header word
//!   little-endian. The twin reads and writes it little-endian ([`encode`], [`decode`]).
//! - There is no KISS CRC and no framing; a packet with the CSP CRC32 flag carries its CRC
//!   at the end of its data as on any interface.
//! - libcsp 1.4 copies a received message into a `csp_buffer_get(256)` buffer without a
//!   length check, so the twin never sends more than [`HUB_MTU`] data bytes to the hub;
//!   it accepts at most that much from it too.

use std::fmt;

use crate::header::{HEADER_LEN, Header};
use crate::packet::Packet;

/// Largest data a hub message carries each way (libcsp 1.4's 256-byte buffers).
pub const HUB_MTU: usize = 256;

/// Why a hub message was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HubDrop {
    /// Shorter than the via byte and the header (libcsp's own check: fewer than 5 bytes).
    Short,
    /// More data than [`HUB_MTU`].
    Oversize,
}

impl fmt::Display for HubDrop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            HubDrop::Short => "ZMQ hub message shorter than 5 bytes",
            HubDrop::Oversize => "ZMQ hub message over the 256-byte MTU",
        })
    }
}

/// The via byte and the packet of a hub message.
pub fn decode(msg: &[u8]) -> Result<(u8, Packet), HubDrop> {
    let (&via, rest) = msg.split_first().ok_or(HubDrop::Short)?;
    let (word, data) = rest
        .split_first_chunk::<HEADER_LEN>()
        .ok_or(HubDrop::Short)?;
    if data.len() > HUB_MTU {
        return Err(HubDrop::Oversize);
    }
    let header = Header::from_word(u32::from_le_bytes(*word));
    Ok((via, Packet::new(header, data.to_vec())))
}

/// Append the hub message of `packet` to `out`, for the subscriber `via` (the
/// destination, or the next hop towards it).
pub fn encode(packet: &Packet, via: u8, out: &mut Vec<u8>) {
    out.reserve(1 + HEADER_LEN + packet.data.len());
    out.push(via);
    out.extend_from_slice(&packet.header.to_word().to_le_bytes());
    out.extend_from_slice(&packet.data);
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A ping 10:50 -> 3:1 of 64 bytes as libcsp 1.4's zmqhub sent it (captured from the
    /// vendored libcsp, third_party/libcsp-1.4, `csp_ping(3, 1000, 64, CSP_O_NONE)` at
    /// address 10 with the default route `CSP_NODE_MAC`): via 3, then `00 72 30 94`, the
    /// header word 0x94307200 little-endian, then the data 00..3f.
    #[test]
    fn a_libcsp_ping_on_the_hub() {
        let mut msg = vec![0x03, 0x00, 0x72, 0x30, 0x94];
        msg.extend(0u8..64);
        let (via, p) = decode(&msg).unwrap();
        assert_eq!(via, 3);
        assert_eq!(p.header, Header::new(10, 3, 1, 50));
        assert_eq!(p.data, (0u8..64).collect::<Vec<_>>());
        let mut out = Vec::new();
        encode(&p, 3, &mut out);
        assert_eq!(out, msg);
    }

    #[test]
    fn short_and_oversize_messages_are_refused() {
        assert_eq!(decode(&[]), Err(HubDrop::Short));
        assert_eq!(decode(&[3, 0, 0, 0]), Err(HubDrop::Short));
        assert!(decode(&[3, 0, 0, 0, 0]).is_ok());
        let mut big = vec![3, 0, 0, 0, 0];
        big.resize(5 + HUB_MTU, 0);
        assert!(decode(&big).is_ok());
        big.push(0);
        assert_eq!(decode(&big), Err(HubDrop::Oversize));
    }
}
