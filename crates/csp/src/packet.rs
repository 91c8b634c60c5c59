//! A CSP packet: header plus data, the unit every interface moves.

use crate::Error;
use crate::header::{HEADER_LEN, Header};

/// A CSP packet as the router sees it: a header and the data bytes that follow it on the
/// wire (including any CRC32 trailer the originating node appended).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Packet {
    /// The CSP header.
    pub header: Header,
    /// The data bytes.
    pub data: Vec<u8>,
}

impl Packet {
    /// Build a packet.
    pub fn new(header: Header, data: impl Into<Vec<u8>>) -> Self {
        Packet {
            header,
            data: data.into(),
        }
    }

    /// Parse `header | data` wire bytes.
    pub fn parse(buf: &[u8]) -> Result<Self, Error> {
        let header = Header::parse(buf)?;
        Ok(Packet {
            header,
            data: buf[HEADER_LEN..].to_vec(),
        })
    }

    /// The wire bytes `header | data`.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER_LEN + self.data.len());
        out.extend_from_slice(&self.header.to_bytes());
        out.extend_from_slice(&self.data);
        out
    }
}
