//! The 32-bit CSP 1.x header (libcsp 1.4 `csp_id_t`, `include/csp/csp_types.h`).
//!
//! ```text
//!  31 30 | 29 .. 25 | 24 .. 20 | 19 .. 14 | 13 .. 8 | 7 .. 0
//!  prio  |   src    |   dst    |  dport   |  sport  | flags
//! ```
//!
//! On every wire the twin speaks (KISS, CFP) the word is big-endian, as libcsp's
//! `csp_hton32(id.ext)` makes it. [`Header`] is the representation; [`Header::parse`] reads
//! the 4 wire bytes and [`Header::emit`] writes them. Every 32-bit word is a valid header,
//! so parsing only fails on a short buffer.

use crate::Error;

/// Length of the header on the wire, in bytes.
pub const HEADER_LEN: usize = 4;
/// The broadcast address (`CSP_BROADCAST_ADDR`).
pub const BROADCAST: u8 = 31;
/// Largest address (5 bits).
pub const MAX_ADDR: u8 = 31;
/// Largest port (6 bits).
pub const MAX_PORT: u8 = 63;
/// First ephemeral source port in libcsp 1.4 (`CSP_MAX_BIND_PORT + 1`).
pub const EPHEMERAL_PORT_MIN: u8 = 32;

/// Header flag bits (wire byte 3).
pub mod flags {
    /// CRC32-C over the data, appended big-endian (`CSP_FCRC32`).
    pub const CRC32: u8 = 0x01;
    /// Reliable datagram protocol (`CSP_FRDP`).
    pub const RDP: u8 = 0x02;
    /// XTEA encryption (`CSP_FXTEA`).
    pub const XTEA: u8 = 0x04;
    /// HMAC-SHA1 authentication (`CSP_FHMAC`).
    pub const HMAC: u8 = 0x08;
    /// Fragmentation (unused in 1.4, `CSP_FFRAG`).
    pub const FRAG: u8 = 0x10;
}

/// Packet priority (2 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum Priority {
    /// `CSP_PRIO_CRITICAL` (0).
    Critical = 0,
    /// `CSP_PRIO_HIGH` (1).
    High = 1,
    /// `CSP_PRIO_NORM` (2), libcsp's default.
    #[default]
    Norm = 2,
    /// `CSP_PRIO_LOW` (3).
    Low = 3,
}

impl Priority {
    /// Map the two priority bits to a priority.
    pub fn from_bits(bits: u8) -> Self {
        match bits & 0x3 {
            0 => Priority::Critical,
            1 => Priority::High,
            2 => Priority::Norm,
            _ => Priority::Low,
        }
    }
}

/// A decoded CSP 1.x header.
///
/// Field values wider than their bit field are masked by [`Header::to_word`]; use
/// [`Header::validate`] to reject them instead.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Header {
    /// Priority.
    pub prio: Priority,
    /// Source address, 0..=31.
    pub src: u8,
    /// Destination address, 0..=31 (31 = broadcast).
    pub dst: u8,
    /// Destination port, 0..=63.
    pub dport: u8,
    /// Source port, 0..=63.
    pub sport: u8,
    /// Flag bits (see [`flags`]).
    pub flags: u8,
}

impl Header {
    /// Build a header with normal priority and no flags.
    pub fn new(src: u8, dst: u8, dport: u8, sport: u8) -> Self {
        Header {
            prio: Priority::Norm,
            src,
            dst,
            dport,
            sport,
            flags: 0,
        }
    }

    /// Decode the 32-bit header word.
    pub fn from_word(word: u32) -> Self {
        Header {
            prio: Priority::from_bits((word >> 30) as u8),
            src: ((word >> 25) & 0x1f) as u8,
            dst: ((word >> 20) & 0x1f) as u8,
            dport: ((word >> 14) & 0x3f) as u8,
            sport: ((word >> 8) & 0x3f) as u8,
            flags: (word & 0xff) as u8,
        }
    }

    /// Encode the 32-bit header word (fields masked to their widths).
    pub fn to_word(&self) -> u32 {
        (self.prio as u32) << 30
            | (u32::from(self.src) & 0x1f) << 25
            | (u32::from(self.dst) & 0x1f) << 20
            | (u32::from(self.dport) & 0x3f) << 14
            | (u32::from(self.sport) & 0x3f) << 8
            | u32::from(self.flags)
    }

    /// Check that every field fits its bit width.
    pub fn validate(&self) -> Result<(), Error> {
        if self.src > MAX_ADDR || self.dst > MAX_ADDR {
            return Err(Error::FieldRange("address"));
        }
        if self.dport > MAX_PORT || self.sport > MAX_PORT {
            return Err(Error::FieldRange("port"));
        }
        Ok(())
    }

    /// Parse the first 4 bytes of `buf` (big-endian word).
    pub fn parse(buf: &[u8]) -> Result<Self, Error> {
        let bytes: [u8; HEADER_LEN] = buf
            .get(..HEADER_LEN)
            .and_then(|b| b.try_into().ok())
            .ok_or(Error::Truncated)?;
        Ok(Self::from_word(u32::from_be_bytes(bytes)))
    }

    /// Write the 4 wire bytes (big-endian).
    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        self.to_word().to_be_bytes()
    }

    /// Write the 4 wire bytes into the start of `buf`, which must hold at least 4 bytes.
    pub fn emit(&self, buf: &mut [u8]) -> Result<(), Error> {
        let out = buf.get_mut(..HEADER_LEN).ok_or(Error::Truncated)?;
        out.copy_from_slice(&self.to_bytes());
        Ok(())
    }

    /// The header of a reply to this packet, as libcsp's server connections build it:
    /// source and destination (and ports) swapped, priority and flags kept.
    pub fn reply(&self, my_addr: u8) -> Self {
        Header {
            prio: self.prio,
            src: my_addr,
            dst: self.src,
            dport: self.sport,
            sport: self.dport,
            flags: self.flags,
        }
    }

    /// Whether the CRC32 flag is set.
    pub fn has_crc(&self) -> bool {
        self.flags & flags::CRC32 != 0
    }
}

impl std::fmt::Display for Header {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}:{} -> {}:{} prio {} flags {:#04x}",
            self.src, self.sport, self.dst, self.dport, self.prio as u8, self.flags
        )
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn ping_example_from_libcsp_doc() {
        // Ping 6 -> 3:1 from sport 59 is `8c 30 7b 00` (libcsp-1.4.md section a).
        let h = Header::new(6, 3, 1, 59);
        assert_eq!(h.to_bytes(), [0x8c, 0x30, 0x7b, 0x00]);
        assert_eq!(Header::parse(&[0x8c, 0x30, 0x7b, 0x00]).unwrap(), h);
    }

    #[test]
    fn short_buffer_is_an_error() {
        assert_eq!(Header::parse(&[0x8c, 0x30, 0x7b]), Err(Error::Truncated));
    }

    #[test]
    fn reply_keeps_prio_and_flags() {
        let mut h = Header::new(16, 3, 1, 40);
        h.flags = flags::CRC32;
        h.prio = Priority::High;
        let r = h.reply(3);
        assert_eq!((r.src, r.dst, r.sport, r.dport), (3, 16, 1, 40));
        assert_eq!((r.prio, r.flags), (Priority::High, flags::CRC32));
    }
}
