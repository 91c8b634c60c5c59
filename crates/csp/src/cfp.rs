//! CAN Fragmentation Protocol (CFP) of libcsp 1.4 (`src/interfaces/csp_if_can.c`).
//!
//! 29-bit extended CAN id, MSB first:
//! ```text
//! 28 .. 24 | 23 .. 19 | 18   | 17 .. 10 | 9 .. 0
//!   src    |   dst    | type |  remain  | ident
//! ```
//! `dst` is the next-hop MAC, not necessarily the CSP destination.

/// Largest CAN data length.
pub const CAN_MAX_DLC: usize = 8;
/// Mask of a 29-bit extended CAN id.
pub const CAN_EFF_MASK: u32 = 0x1FFF_FFFF;

/// A classic CAN 2.0B frame with an extended (29-bit) id, as CFP uses it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    /// 29-bit extended identifier (without SocketCAN's `CAN_EFF_FLAG`).
    pub id: u32,
    /// Number of data bytes, 0..=8.
    pub dlc: u8,
    /// Data bytes; only the first `dlc` are meaningful, the rest are zero.
    pub data: [u8; CAN_MAX_DLC],
}

impl CanFrame {
    /// Build a frame; `None` if `data` is longer than 8 bytes or `id` wider than 29 bits.
    pub fn new(id: u32, data: &[u8]) -> Option<Self> {
        if data.len() > CAN_MAX_DLC || id > CAN_EFF_MASK {
            return None;
        }
        let mut buf = [0u8; CAN_MAX_DLC];
        buf[..data.len()].copy_from_slice(data);
        Some(CanFrame { id, dlc: data.len() as u8, data: buf })
    }

    /// The meaningful data bytes.
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.dlc.min(CAN_MAX_DLC as u8))]
    }
}
