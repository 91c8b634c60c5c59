//! A pure, byte-exact CSP 1.4 stack for m6p-twin.
//!
//! Everything here is a deterministic state machine without I/O, async or a clock of its
//! own (the style of quinn-proto): inputs carry the simulated time, outputs are pulled.
//! The wire facts follow libcsp 1.4 (tag `v1.4`, commit `cd44a620`), as collected in the
//! project's `docs/protocol.md`; the golden vectors produced by libcsp's own code are in
//! `tests/data/`.
//!
//! - [`header`]: the 32-bit CSP 1.x header.
//! - [`crc32`]: CRC-32C as libcsp appends and verifies it.
//! - [`kiss`]: KISS framing exactly as libcsp 1.4's KISS interface.
//! - [`cfp`]: CAN fragmentation protocol (CFP) of libcsp 1.4.
//! - [`router`], [`service`], [`node`]: a node's routing, service handler and port logic.
//! - [`reqrep`]: the ICD's request-reply framing (command id, result code, little-endian).

pub mod cfp;
pub mod client;
pub mod console;
pub mod crc32;
pub mod drop;
pub mod header;
pub mod icd;
pub mod kiss;
pub mod node;
pub mod node_console;
pub mod packet;
pub mod params;
pub mod reqrep;
pub mod router;
pub mod service;
pub mod state;
pub mod time;
pub mod udp;
pub mod zmqhub;

pub use header::{Header, Priority};
pub use packet::Packet;
pub use time::SimTime;

/// Errors of the wire decoders and encoders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The buffer is shorter than the structure needs.
    #[error("buffer too short")]
    Truncated,
    /// The data does not fit the protocol's maximum size.
    #[error("data too long")]
    TooLong,
    /// A field is outside its range.
    #[error("field out of range: {0}")]
    FieldRange(&'static str),
    /// A frame or packet is malformed.
    #[error("malformed: {0}")]
    Malformed(&'static str),
}
