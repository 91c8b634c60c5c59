//! The `outside_link` target's input: a configuration byte, up to two configured addresses,
//! then the chunks and stream of [`crate::kiss_input`].
//!
//! The configuration byte: bit 0 the framing (0 KISS, 1 the ZMQ hub: each chunk one
//! message), bit 1 libcsp 1.4's KISS receive limit, bits 2-3 how many configured addresses
//! follow (0-2; 3 counts as 2), bit 4 a transmit budget of 100 frames a second, bit 5 an
//! empty hub message before the first chunk (the hub only).

use crate::kiss_input;

/// A decoded input.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkInput<'a> {
    /// The ZMQ hub's framing (else KISS).
    pub hub: bool,
    /// libcsp 1.4's 248-byte KISS receive limit.
    pub libcsp14_rx_limit: bool,
    /// The link's configured addresses (each masked to 5 bits).
    pub addrs: Vec<u8>,
    /// A transmit budget (frames a second) for its connections on a CAN bus.
    pub tx_frames_per_s: Option<u32>,
    /// The chunks read from the socket (the hub: messages), in order.
    pub chunks: Vec<&'a [u8]>,
}

/// Decode an input.
pub fn split(data: &[u8]) -> LinkInput<'_> {
    let (&config, rest) = data.split_first().unwrap_or((&0, &[]));
    let n = usize::from((config >> 2) & 3).min(2).min(rest.len());
    let (addrs, rest) = rest.split_at(n);
    let (sizes, stream) = kiss_input::split(rest);
    let hub = config & 1 != 0;
    let mut chunks = Vec::new();
    if hub && config & 0x20 != 0 {
        chunks.push(&stream[..0]);
    }
    let mut at = 0;
    for size in sizes.iter().cycle() {
        if at >= stream.len() {
            break;
        }
        let end = (at + size).min(stream.len());
        chunks.push(&stream[at..end]);
        at = end;
    }
    LinkInput {
        hub,
        libcsp14_rx_limit: config & 2 != 0,
        addrs: addrs.iter().map(|a| a & 0x1f).collect(),
        tx_frames_per_s: (config & 0x10 != 0).then_some(100),
        chunks,
    }
}

/// The input of a configuration byte, configured addresses, chunk sizes (each 1..=64, at
/// most 15) and a stream.
pub fn join(config: u8, addrs: &[u8], sizes: &[u8], stream: &[u8]) -> Vec<u8> {
    assert!(addrs.len() <= 2);
    let config = (config & !0x0c) | ((addrs.len() as u8) << 2);
    let mut out = vec![config];
    out.extend_from_slice(addrs);
    out.extend(kiss_input::join(sizes, stream));
    out
}
