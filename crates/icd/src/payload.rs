//! The payload's commands (ICD 3.1.8.2 table 5, INTERPRETATION.md sections 2 and 4).
//!
//! # Contract
//! | command | request data | reply data |
//! |---|---|---|
//! | SYNC 1 | `msg[N]`, N 0..=128 | `msg[N]`, the request data byte for byte |
//! | POLL 2 | `frameSize` u8, 1..=254 (1 byte) | `data[M]`, M 0..=frameSize |
//!
//! Request payload `cmd | data`, reply `cmd | result | data` ([`csp::reqrep`]). A request
//! with an unknown command, a wrong length or a frame size of 0 or 255 does not parse and
//! is answered `cmd 00` with no data (an empty request as command 0). [`PayloadCommand::parse`]
//! never panics. The frame size bounds are the SETUP command's (ICD 3.1.3 item 5); 254 is
//! also the largest reply data that fits libcsp 1.4's 256-byte CAN MTU after `cmd | result`.

use csp::reqrep::{CommandSet, Request, RequestError};

/// The payload's SYNC/POLL port (INTERPRETATION.md section 4).
pub const PORT: u8 = 10;
/// SYNC command id.
pub const CMD_SYNC: u8 = 1;
/// POLL command id.
pub const CMD_POLL: u8 = 2;
/// Longest synchronisation message (ICD 3.1.3 item 6).
pub const SYNC_MSG_MAX_BYTES: usize = 128;
/// Smallest POLL frame size (ICD 3.1.3 item 5).
pub const FRAME_SIZE_MIN: u8 = 1;
/// Largest POLL frame size (ICD 3.1.3 item 5).
pub const FRAME_SIZE_MAX: u8 = 254;
/// Largest reply data a payload can send: libcsp 1.4's CAN MTU (256) minus `cmd | result`.
pub const MAX_REPLY_DATA_BYTES: usize = csp::cfp::CSP_CAN_MTU - 2;
/// Largest push packet: ICD 3.1.5 "maximum data size in one CSP packet is 256 bytes".
pub const MAX_PUSH_BYTES: u16 = 256;

/// A request to the payload's port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PayloadCommand {
    /// SYNC: the session's synchronisation message.
    Sync(Vec<u8>),
    /// POLL: send at most `frame_size` bytes of data.
    Poll {
        /// Requested frame size, 1..=254.
        frame_size: u8,
    },
}

impl CommandSet for PayloadCommand {
    fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
        match r.command {
            CMD_SYNC if r.data.len() <= SYNC_MSG_MAX_BYTES => {
                Ok(PayloadCommand::Sync(r.data.to_vec()))
            }
            CMD_SYNC => Err(RequestError::WrongLength {
                command: CMD_SYNC,
                expected: "0-128",
                got: r.data.len(),
            }),
            CMD_POLL => match *r.data {
                [frame_size @ FRAME_SIZE_MIN..=FRAME_SIZE_MAX] => {
                    Ok(PayloadCommand::Poll { frame_size })
                }
                [_] => Err(RequestError::OutOfRange {
                    command: CMD_POLL,
                    field: "frameSize",
                }),
                _ => Err(RequestError::WrongLength {
                    command: CMD_POLL,
                    expected: "1",
                    got: r.data.len(),
                }),
            },
            c => Err(RequestError::UnknownCommand(c)),
        }
    }
}

impl PayloadCommand {
    /// Parse request bytes `cmd | data`.
    pub fn parse_bytes(bytes: &[u8]) -> Result<Self, RequestError> {
        let r = Request::parse(bytes).map_err(|_| RequestError::Empty)?;
        <Self as CommandSet>::parse(&r)
    }
    /// The command id.
    pub fn command(&self) -> u8 {
        match self {
            PayloadCommand::Sync(_) => CMD_SYNC,
            PayloadCommand::Poll { .. } => CMD_POLL,
        }
    }
    /// Length of the emitted request.
    pub fn buffer_len(&self) -> usize {
        match self {
            PayloadCommand::Sync(m) => 1 + m.len(),
            PayloadCommand::Poll { .. } => 2,
        }
    }
    /// Append the request bytes to `out`.
    pub fn emit(&self, out: &mut Vec<u8>) {
        out.push(self.command());
        match self {
            PayloadCommand::Sync(m) => out.extend_from_slice(m),
            PayloadCommand::Poll { frame_size } => out.push(*frame_size),
        }
    }
    /// The request bytes.
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.buffer_len());
        self.emit(&mut v);
        v
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn byte_arrays() {
        assert_eq!(
            PayloadCommand::parse_bytes(b"\x01Send telemetry").unwrap(),
            PayloadCommand::Sync(b"Send telemetry".to_vec())
        );
        assert_eq!(
            PayloadCommand::parse_bytes(&[1]).unwrap(),
            PayloadCommand::Sync(vec![])
        );
        assert_eq!(
            PayloadCommand::parse_bytes(&[2, 64]).unwrap(),
            PayloadCommand::Poll { frame_size: 64 }
        );
        assert_eq!(
            PayloadCommand::Poll { frame_size: 64 }.to_vec(),
            vec![2, 64]
        );
        assert_eq!(PayloadCommand::Poll { frame_size: 1 }.buffer_len(), 2);
    }

    #[test]
    fn sizes_and_ranges() {
        let mut sync = vec![1u8];
        sync.extend([0xAA; 128]);
        assert!(PayloadCommand::parse_bytes(&sync).is_ok());
        sync.push(0);
        assert!(matches!(
            PayloadCommand::parse_bytes(&sync),
            Err(RequestError::WrongLength { got: 129, .. })
        ));
        assert!(PayloadCommand::parse_bytes(&[2, 254]).is_ok());
        for bad in [&[2u8, 0][..], &[2, 255], &[2], &[2, 1, 1], &[3], &[0], &[]] {
            assert!(PayloadCommand::parse_bytes(bad).is_err(), "{bad:?}");
        }
        assert_eq!(MAX_REPLY_DATA_BYTES, 254);
    }

    proptest! {
        #[test]
        fn round_trip(msg in proptest::collection::vec(any::<u8>(), 0..=128), fs in 1u8..=254) {
            for c in [PayloadCommand::Sync(msg.clone()), PayloadCommand::Poll { frame_size: fs }] {
                let b = c.to_vec();
                prop_assert_eq!(b.len(), c.buffer_len());
                prop_assert_eq!(PayloadCommand::parse_bytes(&b).unwrap(), c);
            }
        }

        #[test]
        fn parse_never_panics(b in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = PayloadCommand::parse_bytes(&b);
        }
    }
}
