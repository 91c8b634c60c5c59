//! The payload's data stream: what POLL replies and buffering pushes are cut from.
//!
//! # The Counter stream
//! An endless byte stream of self-checking frames, so that the ground can verify what it
//! received byte for byte and name what it lost. Frame `seq` of payload `addr`:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | sync marker `1A CF FC 1D` (the CCSDS attached sync marker 0x1ACFFC1D, CCSDS 131.0-B, sent most significant byte first) |
//! | 4 | 1 | payload CSP address |
//! | 5 | 4 | `seq`, u32 little-endian (frame 0 is the first byte of the stream) |
//! | 9 | 1 | `len`, the data length: `32 + (7 * seq mod 64)`, so 32..=95 |
//! | 10 | `len` | data: a xorshift32 pattern seeded by `seq` and `addr`, with 0x1A replaced by 0x1B so the marker's first byte never occurs in data |
//! | 10 + `len` | 4 | CRC-32C (Castagnoli, `crc::CRC_32_ISCSI`) of bytes `0 .. 10 + len`, little-endian |
//!
//! Frames are 46..=109 bytes; the lengths repeat every 64 frames ([`CYCLE_BYTES`] bytes), so
//! byte `n` of the stream is found without generating what comes before it
//! ([`counter_stream`]). `seq` wraps at 2^32 (after some 330 GB). POLL replies and pushes
//! cut the stream at any byte boundary: a frame may span several replies.
//!
//! [`check_counter_stream`] verifies a received stream: it walks frame by frame, compares
//! each frame with the one the generator makes for its `seq`, and after a damaged frame
//! hunts byte by byte for the next sync marker that starts a valid frame.
//!
//! # Generators and rate
//! [`Generator::Counter`] is the stream above; [`Generator::Bytes`] is a file's bytes, sent
//! once, after which the stream is exhausted. [`DataStream`] adds the rate limit: with a
//! rate, byte `n` (counting from 0) is available once `n + 1 <= rate * (now - t0)`, `t0`
//! being the payload's first boot; without one, everything is available at once. A new
//! rate ([`DataStream::set_rate`]) counts from its instant: what the old rate made by then
//! stays made.

use std::sync::Arc;

use csp::SimTime;

/// The frame sync marker (CCSDS attached sync marker 0x1ACFFC1D, most significant byte first).
pub const SYNC_MARKER: [u8; 4] = [0x1A, 0xCF, 0xFC, 0x1D];
/// Bytes before the data: sync 4, addr 1, seq 4, len 1.
pub const FRAME_HEADER_BYTES: usize = 10;
/// Header and CRC-32C trailer.
pub const FRAME_OVERHEAD_BYTES: usize = FRAME_HEADER_BYTES + 4;
/// Shortest frame data.
pub const DATA_LEN_MIN: usize = 32;
/// Frames in one cycle of lengths.
const CYCLE_FRAMES: u64 = 64;
/// Bytes in one cycle of 64 frames: 64 * 14 + (32 + 33 + ... + 95).
pub const CYCLE_BYTES: u64 = 4960;
/// At most this many missing seqs are listed in a [`StreamCheck`] (all are counted).
pub const MAX_LISTED_MISSING: usize = 1024;
/// The longest frame: header, 95 data bytes, CRC.
pub const MAX_FRAME_BYTES: usize = FRAME_OVERHEAD_BYTES + DATA_LEN_MIN + 63;
/// Bytes before the first good frame that a [`StreamChecker`] keeps (it counts them all).
/// More than a frame of them can never be the end of a frame cut by the stream's start.
pub const KEPT_LEAD_BYTES: usize = 2 * MAX_FRAME_BYTES;

/// Data length of frame `seq`: 32..=95, a permutation over every 64 frames.
pub fn data_len(seq: u32) -> usize {
    DATA_LEN_MIN + (seq.wrapping_mul(7) % 64) as usize
}

/// Total length of frame `seq`.
pub fn frame_len(seq: u32) -> usize {
    FRAME_OVERHEAD_BYTES + data_len(seq)
}

/// Append frame `seq` of payload `addr` to `out`.
pub fn emit_counter_frame(addr: u8, seq: u32, out: &mut Vec<u8>) {
    let start = out.len();
    let len = data_len(seq);
    out.extend_from_slice(&SYNC_MARKER);
    out.push(addr);
    out.extend_from_slice(&seq.to_le_bytes());
    // len <= 95 by construction.
    out.push(len as u8);
    // The data into a buffer on the stack, then in one copy (a push per byte was 3 % of a
    // full day: the payload and the session checks both make these frames).
    let mut data = [0u8; MAX_FRAME_BYTES];
    let mut x = (seq ^ (u32::from(addr) << 24)).wrapping_mul(0x9E37_79B9) | 1;
    for d in &mut data[..len] {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let b = x as u8;
        *d = if b == SYNC_MARKER[0] { b + 1 } else { b };
    }
    out.extend_from_slice(&data[..len]);
    // CRC-32C by the CPU's instruction where it has one (csp's, as CSP's own CRC).
    let crc = csp::crc32::crc32c(&out[start..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// Frame `seq` of payload `addr`.
pub fn counter_frame(addr: u8, seq: u32) -> Vec<u8> {
    let mut v = Vec::with_capacity(frame_len(seq));
    emit_counter_frame(addr, seq, &mut v);
    v
}

/// The exact bytes `from_byte .. from_byte + len` of payload `addr`'s Counter stream.
pub fn counter_stream(addr: u8, from_byte: u64, len: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(len);
    let mut frame_index = from_byte / CYCLE_BYTES * CYCLE_FRAMES;
    let mut skip = from_byte % CYCLE_BYTES;
    // Walk at most 64 frames to the one holding `from_byte`; seq = frame index mod 2^32,
    // consistent with the cycle because 64 divides 2^32.
    loop {
        let fl = frame_len(frame_index as u32) as u64;
        if skip < fl {
            break;
        }
        skip -= fl;
        frame_index += 1;
    }
    let mut skip = skip as usize;
    let mut frame = Vec::with_capacity(128);
    while out.len() < len {
        frame.clear();
        emit_counter_frame(addr, frame_index as u32, &mut frame);
        let take = (frame.len() - skip).min(len - out.len());
        out.extend_from_slice(&frame[skip..skip + take]);
        skip = 0;
        frame_index = frame_index.wrapping_add(1);
    }
    out
}

/// What [`check_counter_stream`] found in a received stream.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StreamCheck {
    /// Frames identical to the generator's.
    pub frames_ok: u64,
    /// Places where a frame should have started (right after a good frame) but no valid
    /// frame did: a damaged, cut or spliced frame.
    pub frames_bad: u64,
    /// Address in the first good frame.
    pub addr: Option<u8>,
    /// Seq of the first good frame.
    pub first_seq: Option<u32>,
    /// Highest seq of the good frames (in stream order).
    pub last_seq: Option<u32>,
    /// Seqs absent between the good frames (the first [`MAX_LISTED_MISSING`] of them).
    pub missing_seqs: Vec<u32>,
    /// Number of absent seqs.
    pub missing_count: u64,
    /// Good frames whose seq is not after `last_seq` (duplicates or reordering).
    pub out_of_order: u64,
    /// Bytes of good frames.
    pub good_bytes: u64,
    /// Bytes before the first good frame (a stream cut from the middle starts mid-frame).
    pub lead_bytes: u64,
    /// Bytes after the first good frame that belong to no good frame.
    pub skipped_bytes: u64,
    /// A frame cut by the end of the input (not an error: the next bytes come later).
    pub tail_bytes: u64,
}

impl StreamCheck {
    /// Whether the stream after its first good frame is whole: no bad frame, no gap, no
    /// reordering, no stray bytes.
    pub fn is_clean(&self) -> bool {
        self.frames_bad == 0
            && self.missing_count == 0
            && self.out_of_order == 0
            && self.skipped_bytes == 0
    }

    fn record(&mut self, addr: u8, seq: u32, len: usize) {
        self.frames_ok += 1;
        self.good_bytes += len as u64;
        match self.last_seq {
            None => {
                self.addr = Some(addr);
                self.first_seq = Some(seq);
                self.last_seq = Some(seq);
            }
            Some(last) => {
                let expected = last.wrapping_add(1);
                let gap = seq.wrapping_sub(expected);
                if gap < 1 << 31 {
                    self.missing_count += u64::from(gap);
                    let room = MAX_LISTED_MISSING.saturating_sub(self.missing_seqs.len());
                    self.missing_seqs
                        .extend((0..gap.min(room as u32)).map(|i| expected.wrapping_add(i)));
                    self.last_seq = Some(seq);
                } else {
                    self.out_of_order += 1;
                }
            }
        }
    }
}

enum Candidate {
    /// A valid frame: its address, seq and length.
    Good(u8, u32, usize),
    /// The input ends inside what may be a frame.
    Incomplete,
    /// No valid frame starts here.
    Bad,
}

fn candidate(rest: &[u8]) -> Candidate {
    if rest.len() < SYNC_MARKER.len() {
        return if SYNC_MARKER.starts_with(rest) {
            Candidate::Incomplete
        } else {
            Candidate::Bad
        };
    }
    if rest[..4] != SYNC_MARKER {
        return Candidate::Bad;
    }
    let [_, _, _, _, addr, s0, s1, s2, s3, len, ..] = *rest else {
        return Candidate::Incomplete;
    };
    let seq = u32::from_le_bytes([s0, s1, s2, s3]);
    if usize::from(len) != data_len(seq) {
        return Candidate::Bad;
    }
    let flen = frame_len(seq);
    let Some(got) = rest.get(..flen) else {
        return Candidate::Incomplete;
    };
    if got == counter_frame(addr, seq) {
        Candidate::Good(addr, seq, flen)
    } else {
        Candidate::Bad
    }
}

/// The walk of [`check_counter_stream`]: what it found so far.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct Walk {
    check: StreamCheck,
    /// Whether the previous bytes were a good frame, so a frame must start here.
    synced: bool,
    /// The first [`KEPT_LEAD_BYTES`] bytes before the first good frame.
    lead: Vec<u8>,
}

impl Walk {
    /// One step at the start of `rest` (not empty): the bytes walked, or `None` when
    /// `rest` ends inside what may be a frame (never with [`MAX_FRAME_BYTES`] or more).
    fn step(&mut self, rest: &[u8]) -> Option<usize> {
        match candidate(rest) {
            Candidate::Good(addr, seq, flen) => {
                self.check.record(addr, seq, flen);
                self.synced = true;
                Some(flen)
            }
            Candidate::Incomplete => None,
            Candidate::Bad => {
                if self.synced {
                    self.check.frames_bad += 1;
                    self.synced = false;
                }
                if self.check.frames_ok == 0 {
                    self.check.lead_bytes += 1;
                    if self.lead.len() < KEPT_LEAD_BYTES {
                        self.lead.extend_from_slice(&rest[..1]);
                    }
                } else {
                    self.check.skipped_bytes += 1;
                }
                Some(1)
            }
        }
    }

    /// Walk `bytes` to their end: the index where the frame cut by their end starts
    /// (`bytes.len()` when none is).
    fn walk_to_end(&mut self, bytes: &[u8]) -> usize {
        let mut i = 0;
        while let Some(rest) = bytes.get(i..).filter(|r| !r.is_empty()) {
            match self.step(rest) {
                Some(n) => i += n,
                None => {
                    self.check.tail_bytes = rest.len() as u64;
                    break;
                }
            }
        }
        i
    }
}

/// Verify a received Counter stream (see the module doc); never panics.
pub fn check_counter_stream(bytes: &[u8]) -> StreamCheck {
    let mut walk = Walk::default();
    walk.walk_to_end(bytes);
    walk.check
}

/// [`check_counter_stream`] of a stream received in pieces, as they arrive: it holds the
/// bytes it cannot judge yet (less than a frame, beside the last piece), the first
/// [`KEPT_LEAD_BYTES`] bytes before the first good frame, and the listed missing seqs, so
/// that a long stream costs no memory.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StreamChecker {
    walk: Walk,
    /// Bytes received and not walked yet.
    pending: Vec<u8>,
}

/// What a [`StreamChecker`] found in every byte it was given.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StreamEnd<'a> {
    /// The check, as [`check_counter_stream`] of all the bytes gives it.
    pub check: StreamCheck,
    /// The bytes before the first good frame (`check.lead_bytes` of them), or the first
    /// [`KEPT_LEAD_BYTES`] when there were more.
    pub lead: Vec<u8>,
    /// The frame cut by the end (`check.tail_bytes` bytes).
    pub tail: &'a [u8],
}

impl StreamEnd<'_> {
    /// Whether `lead` holds every byte before the first good frame.
    pub fn lead_whole(&self) -> bool {
        self.lead.len() as u64 == self.check.lead_bytes
    }
}

impl StreamChecker {
    /// The next bytes of the stream.
    pub fn push(&mut self, bytes: &[u8]) {
        self.pending.extend_from_slice(bytes);
        let mut i = 0;
        // With a longest frame's bytes ahead, each step is the one the whole stream takes.
        while self.pending.len() - i >= MAX_FRAME_BYTES {
            match self.walk.step(&self.pending[i..]) {
                Some(n) => i += n,
                None => break,
            }
        }
        self.pending.drain(..i);
    }

    /// The check of every byte so far (the stream may go on).
    pub fn end(&self) -> StreamEnd<'_> {
        let mut walk = self.walk.clone();
        let cut = walk.walk_to_end(&self.pending);
        StreamEnd {
            check: walk.check,
            lead: walk.lead,
            tail: &self.pending[cut..],
        }
    }
}

/// Where the payload's data comes from.
#[derive(Clone, PartialEq, Eq, Default)]
pub enum Generator {
    /// The endless self-checking Counter stream (module doc).
    #[default]
    Counter,
    /// A file's bytes (read by the twin), sent once; afterwards the stream is exhausted.
    Bytes(Arc<[u8]>),
}

impl std::fmt::Debug for Generator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Generator::Counter => f.write_str("Counter"),
            Generator::Bytes(b) => write!(f, "Bytes({} bytes)", b.len()),
        }
    }
}

impl Generator {
    /// Total length of the stream; `None` for an endless one.
    pub fn total_bytes(&self) -> Option<u64> {
        match self {
            Generator::Counter => None,
            Generator::Bytes(b) => Some(b.len() as u64),
        }
    }

    /// Bytes `from .. from + len` of the stream of payload `addr`, clipped at its end.
    pub fn bytes_at(&self, addr: u8, from: u64, len: usize) -> Vec<u8> {
        match self {
            Generator::Counter => counter_stream(addr, from, len),
            Generator::Bytes(b) => {
                let start = usize::try_from(from).unwrap_or(usize::MAX).min(b.len());
                let end = start.saturating_add(len).min(b.len());
                b[start..end].to_vec()
            }
        }
    }
}

/// A generator with its read position and rate limit (module doc).
#[derive(Debug, Clone)]
pub struct DataStream {
    generator: Generator,
    rate_bytes_per_s: Option<u64>,
    addr: u8,
    t0: Option<SimTime>,
    /// Bytes made before `t0` (by earlier rates).
    made_before_t0: u64,
    position: u64,
}

impl DataStream {
    /// A stream at position 0, producing nothing until [`DataStream::begin`].
    pub fn new(generator: Generator, rate_bytes_per_s: Option<u64>) -> Self {
        DataStream {
            generator,
            rate_bytes_per_s,
            addr: 0,
            t0: None,
            made_before_t0: 0,
            position: 0,
        }
    }

    /// The rate limit in force, bytes/s (`None`: everything at once).
    pub fn rate(&self) -> Option<u64> {
        self.rate_bytes_per_s
    }

    /// Change the rate at `now`: bytes made until `now` stay made, the new rate makes the
    /// next ones from `now` on. From no limit, the new rate starts from what was taken.
    pub fn set_rate(&mut self, rate_bytes_per_s: Option<u64>, now: SimTime) {
        if let Some(t0) = self.t0 {
            let made = match self.rate_bytes_per_s {
                None => self.position,
                Some(_) => self.made(t0, now),
            };
            self.made_before_t0 = made;
            self.t0 = Some(now.max(t0));
        }
        self.rate_bytes_per_s = rate_bytes_per_s;
    }

    /// Bytes made by the rate from `t0` to `now` (saturating).
    fn made(&self, t0: SimTime, now: SimTime) -> u64 {
        match self.rate_bytes_per_s {
            None => u64::MAX,
            Some(rate) => {
                let made = u128::from(rate) * now.saturating_since(t0).as_nanos() / 1_000_000_000;
                u64::try_from(made)
                    .unwrap_or(u64::MAX)
                    .saturating_add(self.made_before_t0)
            }
        }
    }

    /// Whether a finite stream has been taken whole.
    pub fn is_exhausted(&self) -> bool {
        self.generator
            .total_bytes()
            .is_some_and(|n| self.position >= n)
    }

    /// The payload booted at `now` with address `addr`: the first call starts the rate clock.
    pub fn begin(&mut self, addr: u8, now: SimTime) {
        self.addr = addr;
        self.t0.get_or_insert(now);
    }

    /// Bytes taken so far (the next byte's index in the stream).
    pub fn position(&self) -> u64 {
        self.position
    }

    /// Bytes that may be taken at `now`.
    pub fn available(&self, now: SimTime) -> u64 {
        let Some(t0) = self.t0 else {
            return 0;
        };
        let by_rate = self.made(t0, now);
        let by_end = self.generator.total_bytes().unwrap_or(u64::MAX);
        by_rate.min(by_end).saturating_sub(self.position)
    }

    /// Take up to `max` bytes at `now` (fewer when the rate or the end limits it).
    pub fn take(&mut self, max: usize, now: SimTime) -> Vec<u8> {
        let n = usize::try_from(self.available(now))
            .unwrap_or(usize::MAX)
            .min(max);
        let out = self.generator.bytes_at(self.addr, self.position, n);
        self.position += out.len() as u64;
        out
    }

    /// Give back the last `n` bytes taken (their packet could not be sent).
    pub fn untake(&mut self, n: usize) {
        self.position = self.position.saturating_sub(n as u64);
    }
}

/// A generator: the counter, or the scenario's bytes (saved with it: a parameter never
/// changes them, but a configuration is saved whole).
impl snap::Snap for Generator {
    fn save(&self, w: &mut snap::Writer) {
        match self {
            Generator::Counter => snap::Snap::save(&0u8, w),
            Generator::Bytes(b) => {
                snap::Snap::save(&1u8, w);
                snap::Snap::save(&b.to_vec(), w);
            }
        }
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = snap::SnapNew::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for Generator {
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let at = r.at();
        match <u8 as snap::SnapNew>::read(r)? {
            0 => Ok(Generator::Counter),
            1 => Ok(Generator::Bytes(
                <Vec<u8> as snap::SnapNew>::read(r)?.into(),
            )),
            _ => Err(snap::SnapError::Bad {
                what: "Generator",
                at,
            }),
        }
    }
}

// Where the stream is: its start and position (the generator, rate and address are the
// configuration's, saved with it).
snap::fields!(DataStream {
    generator,
    rate_bytes_per_s,
    addr,
    t0,
    made_before_t0,
    position
});

// What a snapshot saves of a stream being checked (docs/snapshots.md).
snap::fields!(StreamCheck {
    frames_ok,
    frames_bad,
    addr,
    first_seq,
    last_seq,
    missing_seqs,
    missing_count,
    out_of_order,
    good_bytes,
    lead_bytes,
    skipped_bytes,
    tail_bytes
});
snap::fields!(Walk {
    check,
    synced,
    lead
});
snap::fields!(StreamChecker { walk, pending });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn cycle_bytes_is_the_sum_of_64_frame_lengths() {
        let sum: u64 = (0..64u32).map(|s| frame_len(s) as u64).sum();
        assert_eq!(sum, CYCLE_BYTES);
        let mut lens: Vec<usize> = (0..64u32).map(data_len).collect();
        lens.sort_unstable();
        assert_eq!(lens, (32..96).collect::<Vec<_>>());
    }

    #[test]
    fn frame_layout_and_crc() {
        let f = counter_frame(12, 0x0403_0201);
        let len = data_len(0x0403_0201);
        assert_eq!(f.len(), 14 + len);
        assert_eq!(f[..4], [0x1A, 0xCF, 0xFC, 0x1D]);
        assert_eq!(f[4], 12);
        assert_eq!(f[5..9], [1, 2, 3, 4]);
        assert_eq!(usize::from(f[9]), len);
        assert!(!f[10..10 + len].contains(&0x1A));
        let crc = u32::from_le_bytes(f[10 + len..].try_into().unwrap());
        // The table CRC of the `crc` crate's catalogue (CRC-32/ISCSI) over the same bytes,
        // and its check value ("123456789" -> 0xE3069283, RFC 3720 B.4).
        let table = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);
        assert_eq!(crc, table.checksum(&f[..10 + len]));
        assert_eq!(csp::crc32::crc32c(b"123456789"), 0xE306_9283);
    }

    #[test]
    fn counter_stream_matches_concatenated_frames_at_any_offset() {
        let mut whole = Vec::new();
        for seq in 0..200u32 {
            emit_counter_frame(13, seq, &mut whole);
        }
        for from in [0usize, 1, 45, 46, 4959, 4960, 4961, 7000, 9919, 9920] {
            assert_eq!(
                counter_stream(13, from as u64, 500),
                whole[from..from + 500],
                "from {from}"
            );
        }
        assert!(counter_stream(13, 17, 0).is_empty());
    }

    #[test]
    fn counter_stream_wraps_seq_consistently() {
        // Frame 2^32 (seq 0 again) starts exactly 2^32 / 64 cycles in.
        let at = (1u64 << 32) / 64 * CYCLE_BYTES;
        assert_eq!(counter_stream(12, at, 60), counter_stream(12, 0, 60));
        let before = counter_stream(12, at - 20, 20);
        let last = counter_frame(12, u32::MAX);
        assert_eq!(before, last[last.len() - 20..]);
    }

    #[test]
    fn check_clean_stream() {
        let s = counter_stream(14, 0, 10_000);
        let c = check_counter_stream(&s);
        assert!(c.is_clean(), "{c:?}");
        assert_eq!(c.first_seq, Some(0));
        assert_eq!(c.addr, Some(14));
        assert_eq!(c.lead_bytes, 0);
        assert_eq!(c.good_bytes + c.tail_bytes, 10_000);
        assert!(c.tail_bytes > 0 && c.tail_bytes < 109);
    }

    #[test]
    fn check_from_the_middle_skips_the_lead() {
        let s = counter_stream(14, 3000, 5000);
        let c = check_counter_stream(&s);
        assert!(c.is_clean(), "{c:?}");
        assert!(c.lead_bytes > 0 && c.lead_bytes < 109);
        assert_eq!(c.lead_bytes + c.good_bytes + c.tail_bytes, 5000);
    }

    #[test]
    fn check_names_missing_seqs() {
        let s = counter_stream(12, 0, 20_000);
        // Remove frames 10..13 whole, and a chunk from the middle of frame 40.
        let off = |seq: u32| (0..seq).map(frame_len).sum::<usize>();
        let mut cut = s[..off(10)].to_vec();
        cut.extend_from_slice(&s[off(13)..off(40) + 20]);
        cut.extend_from_slice(&s[off(40) + 30..]);
        let c = check_counter_stream(&cut);
        assert_eq!(c.missing_seqs, vec![10, 11, 12, 40]);
        assert_eq!(c.missing_count, 4);
        assert_eq!(c.frames_bad, 1);
        assert!(c.skipped_bytes > 0);
        assert!(!c.is_clean());
    }

    #[test]
    fn check_flags_a_flipped_bit() {
        let mut s = counter_stream(12, 0, 3000);
        s[500] ^= 0x10;
        let c = check_counter_stream(&s);
        assert_eq!(c.frames_bad, 1);
        assert_eq!(c.missing_count, 1);
    }

    #[test]
    fn check_counts_duplicates() {
        let a = counter_stream(12, 0, off_of(5));
        let mut s = a.clone();
        s.extend_from_slice(&a);
        let c = check_counter_stream(&s);
        assert_eq!(c.frames_ok, 10);
        assert_eq!(c.out_of_order, 5);
        assert_eq!(c.missing_count, 0);
    }

    fn off_of(seq: u32) -> usize {
        (0..seq).map(frame_len).sum()
    }

    #[test]
    fn max_frame_bytes_is_the_longest_frame() {
        assert_eq!(MAX_FRAME_BYTES, (0..64u32).map(frame_len).max().unwrap());
    }

    #[test]
    fn a_stream_checked_in_pieces_is_checked_as_a_whole() {
        // Clean, from the middle, with frames missing, a flipped bit, garbage before the
        // first frame (more than is kept), and garbage only.
        let clean = counter_stream(12, 0, 20_000);
        let middle = counter_stream(12, 3000, 9000);
        let mut holes = clean[..off_of(10)].to_vec();
        holes.extend_from_slice(&clean[off_of(13)..off_of(40) + 20]);
        holes.extend_from_slice(&clean[off_of(40) + 30..]);
        let mut flipped = clean.clone();
        flipped[5000] ^= 0x10;
        let mut garbage_first = vec![0x55; 1000];
        garbage_first.extend_from_slice(&middle);
        let garbage: Vec<u8> = (0..3000u32).map(|i| (i * 7) as u8).collect();
        for s in [clean, middle, holes, flipped, garbage_first, garbage] {
            let whole = check_counter_stream(&s);
            let lead = &s[..(whole.lead_bytes as usize).min(KEPT_LEAD_BYTES)];
            let tail = &s[s.len() - whole.tail_bytes as usize..];
            for piece in [1, 7, 108, 109, 200, 254, 4096, s.len()] {
                let mut c = StreamChecker::default();
                for p in s.chunks(piece) {
                    c.push(p);
                    assert!(c.pending.len() < MAX_FRAME_BYTES);
                }
                let end = c.end();
                assert_eq!(end.check, whole, "pieces of {piece}");
                assert_eq!(end.lead, lead, "pieces of {piece}");
                assert_eq!(end.tail, tail, "pieces of {piece}");
                assert_eq!(
                    end.lead_whole(),
                    whole.lead_bytes as usize <= KEPT_LEAD_BYTES
                );
            }
        }
    }

    /// One damage to a clean stream: where (a fraction of its length) and what.
    #[derive(Debug, Clone)]
    enum Damage {
        Flip(u8),
        Cut(usize),
        Insert(Vec<u8>),
    }

    fn damage() -> impl proptest::strategy::Strategy<Value = (f64, Damage)> {
        use proptest::prelude::*;
        let what = prop_oneof![
            any::<u8>().prop_map(Damage::Flip),
            (1usize..300).prop_map(Damage::Cut),
            // Garbage, sync markers among it (false starts of frames).
            proptest::collection::vec(prop_oneof![any::<u8>(), Just(0x1A), Just(0xCF)], 1..300)
                .prop_map(Damage::Insert),
        ];
        (0.0..1.0f64, what)
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(128))]

        #[test]
        fn any_stream_in_any_pieces_is_checked_as_a_whole(
            addr in 1u8..32,
            from in proptest::prop_oneof![0u64..20_000, (u64::from(u32::MAX) - 10) * CYCLE_BYTES / 64..(u64::from(u32::MAX) + 10) * CYCLE_BYTES / 64],
            len in 0usize..4000,
            damages in proptest::collection::vec(damage(), 0..6),
            pieces in proptest::collection::vec(1usize..400, 1..8),
        ) {
            let mut s = counter_stream(addr, from, len);
            for (at, d) in damages {
                let i = ((s.len() as f64) * at) as usize;
                match d {
                    Damage::Flip(m) if i < s.len() => s[i] ^= m.max(1),
                    Damage::Flip(_) => {}
                    Damage::Cut(n) => {
                        s.drain(i..(i + n).min(s.len()));
                    }
                    Damage::Insert(g) => {
                        s.splice(i..i, g);
                    }
                }
            }
            let mut c = StreamChecker::default();
            let mut given = 0;
            for &p in pieces.iter().cycle() {
                if given == s.len() {
                    break;
                }
                let next = (given + p).min(s.len());
                c.push(&s[given..next]);
                given = next;
                proptest::prop_assert!(c.pending.len() < MAX_FRAME_BYTES);
                // What it says so far is the check of the stream so far.
                let so_far = &s[..given];
                let whole = check_counter_stream(so_far);
                let end = c.end();
                proptest::prop_assert_eq!(&end.check, &whole);
                let lead = &so_far[..(whole.lead_bytes as usize).min(KEPT_LEAD_BYTES)];
                proptest::prop_assert_eq!(end.lead.as_slice(), lead);
                proptest::prop_assert_eq!(end.tail, &so_far[given - whole.tail_bytes as usize..]);
            }
            proptest::prop_assert_eq!(c.end().check, check_counter_stream(&s));
        }
    }

    #[test]
    fn rate_limits_availability() {
        let mut s = DataStream::new(Generator::Counter, Some(1000));
        assert_eq!(s.available(SimTime::from_secs(5)), 0, "before begin");
        s.begin(12, SimTime::from_secs(1));
        assert_eq!(s.available(SimTime::from_secs(1)), 0);
        assert_eq!(s.available(SimTime::from_ms(1500)), 500);
        assert_eq!(s.take(300, SimTime::from_ms(1500)).len(), 300);
        assert_eq!(s.take(300, SimTime::from_ms(1500)).len(), 200);
        assert_eq!(s.position(), 500);
        s.untake(100);
        assert_eq!(s.position(), 400);
    }

    #[test]
    fn a_new_rate_counts_from_its_instant() {
        let mut s = DataStream::new(Generator::Counter, Some(1000));
        s.set_rate(Some(500), SimTime::ZERO);
        s.begin(12, SimTime::ZERO);
        assert_eq!(s.available(SimTime::from_secs(2)), 1000);
        s.set_rate(Some(100), SimTime::from_secs(2));
        assert_eq!(s.available(SimTime::from_secs(2)), 1000, "made stays made");
        assert_eq!(s.available(SimTime::from_secs(4)), 1200);
        assert_eq!(s.take(1100, SimTime::from_secs(4)).len(), 1100);
        s.set_rate(None, SimTime::from_secs(5));
        assert_eq!(s.available(SimTime::from_secs(5)), u64::MAX - 1100);
        s.set_rate(Some(10), SimTime::from_secs(6));
        assert_eq!(s.available(SimTime::from_secs(6)), 0, "from what was taken");
        assert_eq!(s.available(SimTime::from_secs(7)), 10);
        assert_eq!(s.rate(), Some(10));
    }

    #[test]
    fn bytes_generator_is_sent_once() {
        let file: Arc<[u8]> = (0..=99u8).collect::<Vec<_>>().into();
        let mut s = DataStream::new(Generator::Bytes(file.clone()), None);
        s.begin(12, SimTime::ZERO);
        assert_eq!(s.take(60, SimTime::ZERO), file[..60]);
        assert_eq!(s.take(60, SimTime::ZERO), file[60..]);
        assert!(s.take(60, SimTime::ZERO).is_empty());
        assert_eq!(format!("{:?}", Generator::Bytes(file)), "Bytes(100 bytes)");
    }
}
