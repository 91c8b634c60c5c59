//! KISS framing exactly as libcsp 1.4's KISS interface (`src/interfaces/csp_if_kiss.c`).
//!
//! # Wire format
//!
//! ```text
//! C0 00  esc( header[4, big-endian] | data[n] | CRC32C(data)[4, big-endian] )  C0
//! esc: C0 -> DB DC, DB -> DB DD   (FEND=C0 FESC=DB TFEND=DC TFESC=DD)
//! ```
//!
//! libcsp's KISS driver *always* appends its own CRC-32C over the data (never the
//! header), whatever the CSP CRC flag says; with [`crate::header::flags::CRC32`] set the
//! packet data already ends in an inner CRC and the frame carries two.
//!
//! # Contract
//!
//! - [`encode`] appends one complete frame and never fails. It does not check the MTU:
//!   the caller (the router, as `csp_send_direct` does) keeps data within [`KISS_MTU`].
//! - [`Decoder`] is a byte-at-a-time state machine reproducing `csp_kiss_rx`:
//!   - every frame needs its own leading FEND; after a closing FEND the decoder is "not
//!     started" again and bytes before the next FEND are discarded (counted in
//!     [`KissStats::discarded_bytes`], libcsp's discard callback), so frames sharing one
//!     FEND (`C0 00 f1 C0 00 f2 C0`) lose the second;
//!   - repeated FENDs between frames are ignored, garbage before a FEND is discarded;
//!   - the byte after the opening FEND (the KISS command byte) is skipped unchecked;
//!   - FESC followed by anything but TFEND/TFESC drops both bytes (the CRC check then
//!     fails), and a FEND right after FESC is swallowed the same way;
//!   - a body shorter than header + 4 CRC bytes is dropped ([`KissDrop::Short`]); the
//!     KISS CRC is verified and stripped, a mismatch drops the frame
//!     ([`KissDrop::BadCrc`]);
//!   - a body longer than the receive limit is dropped ([`KissDrop::Oversize`]). As in
//!     libcsp the check runs when the byte *after* the limit was exceeded arrives: the
//!     decoder falls back to "not started", so the rest of the frame is discarded and
//!     its closing FEND opens a new frame.
//!   - `rx_error` counts every drop (short, bad CRC, oversize), as libcsp's interface
//!     counter does.
//! - Receive limit, chosen by [`DecoderConfig::libcsp14_rx_limit`]:
//!   - `true`: v1.4's check `rx_length > KISS_MTU`, where `rx_length` counts the header,
//!     the data and the KISS CRC. A v1.4 receiver therefore accepts at most 248 data
//!     bytes (244 with an inner CRC) although a v1.4 sender sends up to 256 (libcsp
//!     issue #854).
//!   - `false` (the default, the twin's choice): data up to [`KISS_MTU`] bytes is
//!     accepted, i.e. an unescaped body of up to 4 + 256 + 4 bytes.
//! - The decoder never panics and its buffer is bounded (limit + 1 bytes); memory use
//!   does not depend on the input.

use std::fmt;

use crate::crc32;
use crate::header::{HEADER_LEN, Header};
use crate::packet::Packet;

/// libcsp 1.4's KISS interface MTU (`KISS_MTU`).
pub const KISS_MTU: usize = 256;
/// Frame end.
pub const FEND: u8 = 0xC0;
/// Frame escape.
pub const FESC: u8 = 0xDB;
/// Transposed frame end (follows FESC to stand for FEND).
pub const TFEND: u8 = 0xDC;
/// Transposed frame escape (follows FESC to stand for FESC).
pub const TFESC: u8 = 0xDD;
/// The KISS command byte libcsp sends (`TNC_DATA`).
pub const TNC_DATA: u8 = 0x00;
/// Length of the KISS CRC trailer.
const CRC_LEN: usize = 4;
/// Shortest body the receiver accepts: header + CRC.
const MIN_BODY: usize = HEADER_LEN + CRC_LEN;

/// Append the KISS frame of `packet` to `out`: `C0 00 esc(header | data | CRC32C) C0`.
pub fn encode(packet: &Packet, out: &mut Vec<u8>) {
    let crc = crc32::crc32c(&packet.data).to_be_bytes();
    // Worst case every byte is escaped; reserving once avoids growth on the hot path.
    out.reserve(2 * (HEADER_LEN + packet.data.len() + CRC_LEN) + 3);
    out.extend_from_slice(&[FEND, TNC_DATA]);
    escape_bytes(&packet.header.to_bytes(), out);
    escape_into(&packet.data, out);
    escape_bytes(&crc, out);
    out.push(FEND);
}

/// Bytes [`escape_into`] checks at a time.
const SCAN_CHUNK: usize = 16;

/// Append `bytes` escaped: each [`SCAN_CHUNK`] bytes holding neither FEND nor FESC (the
/// common case) are copied whole, the others byte by byte. The check has no early exit,
/// so the compiler turns it into a few vector compares.
fn escape_into(bytes: &[u8], out: &mut Vec<u8>) {
    let mut chunks = bytes.chunks_exact(SCAN_CHUNK);
    for chunk in &mut chunks {
        if chunk
            .iter()
            .fold(false, |any, &b| any | (b == FEND) | (b == FESC))
        {
            escape_bytes(chunk, out);
        } else {
            out.extend_from_slice(chunk);
        }
    }
    escape_bytes(chunks.remainder(), out);
}

/// Append `bytes` escaped, one at a time.
fn escape_bytes(bytes: &[u8], out: &mut Vec<u8>) {
    for &b in bytes {
        match b {
            FEND => out.extend_from_slice(&[FESC, TFEND]),
            FESC => out.extend_from_slice(&[FESC, TFESC]),
            _ => out.push(b),
        }
    }
}

/// Receiver options.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DecoderConfig {
    /// Reproduce v1.4's receive limit (at most 248 data bytes) instead of accepting the
    /// full 256-byte MTU.
    pub libcsp14_rx_limit: bool,
}

impl DecoderConfig {
    /// Largest unescaped body (header + data + KISS CRC) this configuration accepts.
    pub fn max_body(&self) -> usize {
        if self.libcsp14_rx_limit {
            KISS_MTU
        } else {
            HEADER_LEN + KISS_MTU + CRC_LEN
        }
    }
}

/// Why the decoder dropped a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum KissDrop {
    /// The KISS CRC did not match.
    BadCrc,
    /// The body was shorter than header + CRC.
    Short,
    /// The body exceeded the receive limit.
    Oversize,
}

impl fmt::Display for KissDrop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            KissDrop::BadCrc => "KISS invalid CRC",
            KissDrop::Short => "KISS short frame",
            KissDrop::Oversize => "KISS RX overflow",
        })
    }
}

/// What one input byte produced.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum KissEvent {
    /// A frame was received intact (KISS CRC stripped).
    Packet(Packet),
    /// A frame was dropped.
    Dropped(KissDrop),
}

/// Decoder counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct KissStats {
    /// Frames delivered as packets.
    pub frames_ok: u64,
    /// Frames dropped for any reason (libcsp's interface `rx_error`).
    pub rx_error: u64,
    /// Frames dropped because of a CRC mismatch.
    pub bad_crc: u64,
    /// Frames dropped as too short.
    pub short: u64,
    /// Frames dropped as too long.
    pub oversize: u64,
    /// Bytes outside frames (libcsp's discard callback).
    pub discarded_bytes: u64,
}

/// Receiver state, as libcsp's `rx_mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Waiting for a FEND; other bytes are discarded.
    NotStarted,
    /// Inside a frame.
    Started,
    /// Inside a frame, right after FESC.
    Escaped,
}

/// Streaming KISS receiver reproducing libcsp 1.4's `csp_kiss_rx`.
#[derive(Debug, Clone)]
pub struct Decoder {
    config: DecoderConfig,
    mode: Mode,
    /// Whether the next plain byte is the command byte to skip (`rx_first`).
    first: bool,
    /// The unescaped body so far; its length is libcsp's `rx_length`.
    buf: Vec<u8>,
    stats: KissStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder::new(DecoderConfig::default())
    }
}

impl Decoder {
    /// A decoder in the "not started" state.
    pub fn new(config: DecoderConfig) -> Self {
        Decoder {
            config,
            mode: Mode::NotStarted,
            first: false,
            // The length check keeps the body at most one byte over the limit.
            buf: Vec::with_capacity(config.max_body() + 1),
            stats: KissStats::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> DecoderConfig {
        self.config
    }

    /// The counters so far.
    pub fn stats(&self) -> KissStats {
        self.stats
    }

    /// Feed a chunk of bytes, appending every event to `out`.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<KissEvent>) {
        out.extend(bytes.iter().filter_map(|&b| self.push_byte(b)));
    }

    /// Feed one byte; returns the event it completed, if any.
    pub fn push_byte(&mut self, b: u8) -> Option<KissEvent> {
        let mut event = None;
        // libcsp checks the length before looking at the byte, so the overflow fires on
        // the byte after the one that crossed the limit, and that byte is then handled in
        // "not started" mode (a FEND opens a frame, anything else is discarded).
        if self.buf.len() > self.config.max_body() {
            self.buf.clear();
            self.mode = Mode::NotStarted;
            event = Some(self.drop_frame(KissDrop::Oversize));
        }
        match self.mode {
            Mode::NotStarted => {
                if b == FEND {
                    self.buf.clear();
                    self.mode = Mode::Started;
                    self.first = true;
                } else {
                    self.stats.discarded_bytes += 1;
                }
            }
            Mode::Started => match b {
                FESC => self.mode = Mode::Escaped,
                // An empty frame (repeated FEND) is ignored and keeps `first` as it is.
                FEND if self.buf.is_empty() => {}
                FEND => {
                    self.mode = Mode::NotStarted;
                    // `event` is None here: an overflow leaves the decoder not started.
                    event = Some(self.finish_frame());
                }
                _ if self.first => self.first = false,
                _ => self.buf.push(b),
            },
            Mode::Escaped => {
                match b {
                    TFESC => self.buf.push(FESC),
                    TFEND => self.buf.push(FEND),
                    // Anything else (FEND included) is dropped together with the FESC.
                    _ => {}
                }
                self.mode = Mode::Started;
            }
        }
        event
    }

    /// Check and deliver the body collected so far (closing FEND seen).
    fn finish_frame(&mut self) -> KissEvent {
        if self.buf.len() < MIN_BODY {
            return self.drop_frame(KissDrop::Short);
        }
        let mut data = self.buf.split_off(HEADER_LEN);
        if !crc32::verify_and_strip(&mut data) {
            return self.drop_frame(KissDrop::BadCrc);
        }
        match Header::parse(&self.buf) {
            Ok(header) => {
                self.stats.frames_ok += 1;
                KissEvent::Packet(Packet { header, data })
            }
            // Unreachable (the body holds at least a header), but never panic.
            Err(_) => self.drop_frame(KissDrop::Short),
        }
    }

    /// Count a dropped frame and build its event.
    fn drop_frame(&mut self, why: KissDrop) -> KissEvent {
        self.stats.rx_error += 1;
        match why {
            KissDrop::BadCrc => self.stats.bad_crc += 1,
            KissDrop::Short => self.stats.short += 1,
            KissDrop::Oversize => self.stats.oversize += 1,
        }
        KissEvent::Dropped(why)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn ping() -> Packet {
        Packet::new(Header::new(6, 3, 1, 59), vec![0, 1, 2, 3])
    }

    const PING_WIRE: [u8; 15] = [
        0xc0, 0x00, 0x8c, 0x30, 0x7b, 0x00, 0x00, 0x01, 0x02, 0x03, 0xd9, 0x33, 0x1a, 0xa3, 0xc0,
    ];

    fn decode_all(config: DecoderConfig, bytes: &[u8]) -> (Vec<KissEvent>, KissStats) {
        let mut d = Decoder::new(config);
        let mut out = Vec::new();
        d.push(bytes, &mut out);
        (out, d.stats())
    }

    /// The byte-at-a-time encoder [`encode`] replaced, kept as the reference.
    fn encode_reference(packet: &Packet) -> Vec<u8> {
        let crc = crc32::crc32c(&packet.data).to_be_bytes();
        let mut out = vec![FEND, TNC_DATA];
        for &b in packet
            .header
            .to_bytes()
            .iter()
            .chain(&packet.data)
            .chain(&crc)
        {
            match b {
                FEND => out.extend_from_slice(&[FESC, TFEND]),
                FESC => out.extend_from_slice(&[FESC, TFESC]),
                _ => out.push(b),
            }
        }
        out.push(FEND);
        out
    }

    proptest::proptest! {
        #[test]
        fn encode_matches_the_byte_at_a_time_reference(
            word in proptest::prelude::any::<u32>(),
            // Half the bytes FEND, FESC or their transposed forms, at every offset.
            data in proptest::collection::vec(
                proptest::prop_oneof![
                    proptest::prelude::any::<u8>(),
                    proptest::sample::select(vec![FEND, FESC, TFEND, TFESC]),
                ],
                0..=300,
            ),
            prefix in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..4),
        ) {
            let p = Packet::new(Header::from_word(word), data);
            // Appends after what `out` already holds.
            let mut out = prefix.clone();
            encode(&p, &mut out);
            let mut want = prefix;
            want.extend(encode_reference(&p));
            proptest::prop_assert_eq!(out, want);
        }
    }

    #[test]
    fn ping_example() {
        let mut out = Vec::new();
        encode(&ping(), &mut out);
        assert_eq!(out, PING_WIRE);
        let (ev, st) = decode_all(DecoderConfig::default(), &out);
        assert_eq!(ev, vec![KissEvent::Packet(ping())]);
        assert_eq!(st.frames_ok, 1);
        assert_eq!(st.rx_error, 0);
    }

    #[test]
    fn escaped_fend_after_opening_fend_is_kept_and_shifts_the_command_byte() {
        // libcsp checks FESC before the command-byte skip: `C0 DB DC 00 ...` stores C0 and
        // then skips the 00 as the command byte.
        let (ev, st) = decode_all(DecoderConfig::default(), &[0xc0, 0xdb, 0xdc, 0x00, 0xc0]);
        assert_eq!(ev, vec![KissEvent::Dropped(KissDrop::Short)]);
        assert_eq!(st.short, 1);
    }

    #[test]
    fn fend_after_fesc_is_swallowed() {
        // The FEND after FESC does not close the frame; the real closing FEND does.
        let mut wire = PING_WIRE.to_vec();
        wire.insert(6, FESC);
        wire.insert(7, FEND);
        let (ev, _) = decode_all(DecoderConfig::default(), &wire);
        assert_eq!(ev, vec![KissEvent::Packet(ping())]);
    }

    #[test]
    fn empty_frame_after_command_byte_keeps_decoder_started_without_skip() {
        // `C0 00 C0 00 <body> C0`: the second 00 is taken as the first body byte.
        let mut wire = vec![0xc0, 0x00];
        wire.extend_from_slice(&PING_WIRE);
        let (ev, st) = decode_all(DecoderConfig::default(), &wire);
        assert_eq!(ev, vec![KissEvent::Dropped(KissDrop::BadCrc)]);
        assert_eq!(st.bad_crc, 1);
    }

    #[test]
    fn limits() {
        for (len, v14_ok) in [(248usize, true), (249, false), (256, false), (257, false)] {
            let p = Packet::new(Header::new(6, 3, 10, 40), vec![0x55; len]);
            let mut wire = Vec::new();
            encode(&p, &mut wire);
            // A following frame must survive the oversize drop.
            encode(&ping(), &mut wire);
            let (ev, st) = decode_all(
                DecoderConfig {
                    libcsp14_rx_limit: true,
                },
                &wire,
            );
            assert_eq!(
                ev.first() == Some(&KissEvent::Packet(p.clone())),
                v14_ok,
                "{len}"
            );
            assert_eq!(ev.last(), Some(&KissEvent::Packet(ping())), "{len}");
            assert_eq!(st.oversize, u64::from(!v14_ok), "{len}");
            let (ev, st) = decode_all(DecoderConfig::default(), &wire);
            assert_eq!(
                ev.first() == Some(&KissEvent::Packet(p)),
                len <= KISS_MTU,
                "{len}"
            );
            assert_eq!(st.oversize, u64::from(len > KISS_MTU), "{len}");
            assert_eq!(ev.last(), Some(&KissEvent::Packet(ping())), "{len}");
        }
    }

    #[test]
    fn endless_garbage_inside_a_frame_stays_bounded() {
        let mut d = Decoder::default();
        d.push_byte(FEND);
        let mut drops = 0;
        for i in 0..10_000u32 {
            if let Some(KissEvent::Dropped(KissDrop::Oversize)) = d.push_byte((i % 0xc0) as u8) {
                drops += 1;
            }
            assert!(d.buf.len() <= d.config.max_body() + 1);
        }
        // One overflow, then the rest is discarded outside a frame.
        assert_eq!(drops, 1);
        assert_eq!(d.stats().discarded_bytes, 10_000 - 1 - 265);
    }
}
