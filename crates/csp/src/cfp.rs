//! CAN Fragmentation Protocol (CFP) of libcsp 1.4 (`src/interfaces/csp_if_can.c`).
//!
//! 29-bit extended CAN id, MSB first:
//! ```text
//! 28 .. 24 | 23 .. 19 | 18   | 17 .. 10 | 9 .. 0
//!   src    |   dst    | type |  remain  | ident
//! ```
//! `dst` is the next-hop MAC, not necessarily the CSP destination.
//!
//! Frame data: the BEGIN frame carries the CSP header (4 bytes, big-endian), the CSP data
//! length (u16, big-endian) and the first min(len, 2) data bytes; each MORE frame carries
//! the next min(remaining, 8) bytes. DLC is the exact byte count. `remain` is the number
//! of frames still to come after this one; the CAN interface adds no CRC.
//!
//! # Contract
//!
//! - [`fragment_with_ident`] and [`Fragmenter`] produce exactly `csp_can_tx`'s frames;
//!   the caller picks the next-hop MAC (the routing table's, or the CSP dst).
//! - [`Reassembler`] reproduces `csp_can_process_frame` (see its documentation for the
//!   exact rules and the one deliberate deviation). It is a pure state machine: time
//!   comes in with every call, stale partial packets are purged by
//!   [`Reassembler::handle_timeout`], whose due time [`Reassembler::poll_timeout`] reports.
//! - Nothing here panics on any input; state is bounded by the configured slots and MTU.

use std::fmt;
use std::time::Duration;

use crate::Error;
use crate::header::{HEADER_LEN, Header, MAX_ADDR};
use crate::packet::Packet;
use crate::time::SimTime;

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
        Some(CanFrame {
            id,
            dlc: data.len() as u8,
            data: buf,
        })
    }

    /// The meaningful data bytes.
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.dlc.min(CAN_MAX_DLC as u8))]
    }
}

/// libcsp 1.4's CAN interface MTU (`CSP_CAN_MTU`).
pub const CSP_CAN_MTU: usize = 256;
/// Largest data length the CFP fields can describe (256 frames, 8-bit `remain`).
pub const CFP_MAX_DATA: usize = 2042;
/// Bytes of a BEGIN frame taken by the CSP header and the u16 data length.
pub const BEGIN_OVERHEAD: usize = HEADER_LEN + 2;
/// Mask of the 10-bit ident.
pub const IDENT_MASK: u16 = 0x3FF;
/// Mask of the can id bits that identify a packet under reassembly: src, dst, ident
/// (`CFP_ID_CONN_MASK`).
pub const CFP_ID_CONN_MASK: u32 = (0x1F << 24) | (0x1F << 19) | IDENT_MASK as u32;

/// CFP frame type (can id bit 18).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameType {
    /// First frame of a packet (`CFP_BEGIN`).
    Begin = 0,
    /// Any later frame (`CFP_MORE`).
    More = 1,
}

/// The decoded fields of a CFP can id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CfpId {
    /// CSP source address (5 bits).
    pub src: u8,
    /// Next-hop MAC (5 bits), not necessarily the CSP destination.
    pub dst: u8,
    /// BEGIN or MORE.
    pub kind: FrameType,
    /// Frames still to come after this one.
    pub remain: u8,
    /// Per-sender packet counter (10 bits).
    pub ident: u16,
}

impl CfpId {
    /// Decode a can id (bits above 29 are ignored).
    pub fn from_can_id(id: u32) -> CfpId {
        CfpId {
            src: ((id >> 24) & 0x1F) as u8,
            dst: ((id >> 19) & 0x1F) as u8,
            kind: if (id >> 18) & 1 == 0 {
                FrameType::Begin
            } else {
                FrameType::More
            },
            remain: ((id >> 10) & 0xFF) as u8,
            ident: (id as u16) & IDENT_MASK,
        }
    }

    /// Encode the 29-bit can id; fields wider than their bit width are masked, as
    /// libcsp's `CFP_MAKE_*` macros do.
    pub fn to_can_id(&self) -> u32 {
        (u32::from(self.src) & 0x1F) << 24
            | (u32::from(self.dst) & 0x1F) << 19
            | (self.kind as u32) << 18
            | u32::from(self.remain) << 10
            | u32::from(self.ident & IDENT_MASK)
    }
}

/// The CSP header and data length a BEGIN frame carries; `None` for a MORE frame or a
/// BEGIN too short to hold them.
pub fn begin_fields(frame: &CanFrame) -> Option<(Header, usize)> {
    if CfpId::from_can_id(frame.id).kind != FrameType::Begin {
        return None;
    }
    let &[h0, h1, h2, h3, l0, l1] = frame.data().get(..BEGIN_OVERHEAD)? else {
        return None;
    };
    let header = Header::from_word(u32::from_be_bytes([h0, h1, h2, h3]));
    Some((header, usize::from(u16::from_be_bytes([l0, l1]))))
}

/// Fragment `packet` into CAN frames with the given ident, appending them to `out` in
/// transmit order, as `csp_can_tx` does.
///
/// `next_hop_mac` goes into the CFP dst field. Fails with [`Error::TooLong`] when the data
/// exceeds [`CFP_MAX_DATA`] and [`Error::FieldRange`] when an address or port does not fit
/// its field; `out` is untouched on error.
pub fn fragment_with_ident(
    packet: &Packet,
    next_hop_mac: u8,
    ident: u16,
    out: &mut Vec<CanFrame>,
) -> Result<(), Error> {
    let len = packet.data.len();
    if len > CFP_MAX_DATA {
        return Err(Error::TooLong);
    }
    packet.header.validate()?;
    if next_hop_mac > MAX_ADDR {
        return Err(Error::FieldRange("next_hop_mac"));
    }
    if ident > IDENT_MASK {
        return Err(Error::FieldRange("ident"));
    }
    let mut id = CfpId {
        src: packet.header.src,
        dst: next_hop_mac,
        kind: FrameType::Begin,
        // Total frames - 1; fits 8 bits because len <= CFP_MAX_DATA.
        remain: ((len + BEGIN_OVERHEAD - 1) / CAN_MAX_DLC) as u8,
        ident,
    };
    let first = len.min(CAN_MAX_DLC - BEGIN_OVERHEAD);
    let (head, mut rest) = packet.data.split_at(first);
    let mut buf = [0u8; CAN_MAX_DLC];
    buf[..HEADER_LEN].copy_from_slice(&packet.header.to_bytes());
    buf[HEADER_LEN..BEGIN_OVERHEAD].copy_from_slice(&(len as u16).to_be_bytes());
    buf[BEGIN_OVERHEAD..BEGIN_OVERHEAD + first].copy_from_slice(head);
    out.reserve(usize::from(id.remain) + 1);
    out.push(CanFrame {
        id: id.to_can_id(),
        dlc: (BEGIN_OVERHEAD + first) as u8,
        data: buf,
    });
    id.kind = FrameType::More;
    while !rest.is_empty() {
        let n = rest.len().min(CAN_MAX_DLC);
        let (chunk, tail) = rest.split_at(n);
        rest = tail;
        id.remain = rest.len().div_ceil(CAN_MAX_DLC) as u8;
        let mut data = [0u8; CAN_MAX_DLC];
        data[..n].copy_from_slice(chunk);
        out.push(CanFrame {
            id: id.to_can_id(),
            dlc: n as u8,
            data,
        });
    }
    Ok(())
}

/// A sender's CFP fragmenter: owns the 10-bit ident counter.
#[derive(Debug, Clone)]
pub struct Fragmenter {
    next_ident: u16,
    mtu: usize,
}

impl Fragmenter {
    /// A fragmenter whose first packet uses `first_ident` (masked to 10 bits) and which
    /// refuses data longer than `mtu` (capped at [`CFP_MAX_DATA`]).
    ///
    /// libcsp 1.4 starts the counter at `rand()`; the caller picks it from its seeded RNG.
    pub fn new(first_ident: u16, mtu: usize) -> Self {
        Fragmenter {
            next_ident: first_ident & IDENT_MASK,
            mtu: mtu.min(CFP_MAX_DATA),
        }
    }

    /// The ident the next packet will use.
    pub fn next_ident(&self) -> u16 {
        self.next_ident
    }

    /// The MTU.
    pub fn mtu(&self) -> usize {
        self.mtu
    }

    /// Fragment `packet` for `next_hop_mac`, appending the frames to `out`; returns the
    /// ident used. The counter advances only on success and wraps at 1024.
    pub fn fragment(
        &mut self,
        packet: &Packet,
        next_hop_mac: u8,
        out: &mut Vec<CanFrame>,
    ) -> Result<u16, Error> {
        if packet.data.len() > self.mtu {
            return Err(Error::TooLong);
        }
        let ident = self.next_ident;
        fragment_with_ident(packet, next_hop_mac, ident, out)?;
        self.next_ident = (ident + 1) & IDENT_MASK;
        Ok(ident)
    }
}

/// Reassembler options.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReassemblerConfig {
    /// Packets under reassembly at once (`PBUF_ELEMENTS`, 10 in 1.4).
    pub slots: usize,
    /// Idle time after which a partial packet is stale (`PBUF_TIMEOUT_MS`, 10 s in 1.4).
    pub timeout: Duration,
    /// Largest data length accepted in a BEGIN frame.
    pub mtu: usize,
}

impl Default for ReassemblerConfig {
    fn default() -> Self {
        ReassemblerConfig {
            slots: 10,
            timeout: Duration::from_secs(10),
            mtu: CSP_CAN_MTU,
        }
    }
}

/// Why the reassembler dropped a frame or a partial packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum CfpDrop {
    /// A BEGIN frame with DLC < 6; it also discards a partial packet with its key.
    BeginTooShort,
    /// A BEGIN frame announcing more data than the MTU (libcsp 1.4 does not check this).
    LengthExceedsMtu,
    /// A BEGIN frame found every slot busy.
    NoBufferFree,
    /// A MORE frame without a partial packet for its key.
    UnexpectedMore,
    /// A MORE frame whose `remain` is not one less than the previous frame's (a lost or
    /// reordered frame); the partial packet is dropped.
    RemainMismatch,
    /// A frame carries more bytes than the BEGIN's length field announced; the partial
    /// packet is dropped.
    Overflow,
    /// A BEGIN replaced an incomplete partial packet with its key (libcsp "Incomplete
    /// frame"); reassembly continues with the new BEGIN.
    Restarted,
    /// A partial packet went stale and was purged.
    Timeout,
    /// The node rebooted with the packet partly reassembled (its memory is gone; libcsp
    /// loses it without a word, the twin says so for the ledgers).
    Reset,
}

impl fmt::Display for CfpDrop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CfpDrop::BeginTooShort => "short BEGIN frame",
            CfpDrop::LengthExceedsMtu => "BEGIN length exceeds MTU",
            CfpDrop::NoBufferFree => "no free reassembly buffer",
            CfpDrop::UnexpectedMore => "MORE frame without BEGIN",
            CfpDrop::RemainMismatch => "CAN frame lost in CSP packet",
            CfpDrop::Overflow => "RX buffer overflow",
            CfpDrop::Restarted => "incomplete packet restarted by BEGIN",
            CfpDrop::Timeout => "partial packet timed out",
            CfpDrop::Reset => "partial packet lost to a reboot",
        })
    }
}

/// Reassembler counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CfpStats {
    /// Frames handled.
    pub frames: u64,
    /// Packets completed.
    pub packets_ok: u64,
    /// [`CfpDrop::BeginTooShort`] drops.
    pub begin_too_short: u64,
    /// [`CfpDrop::LengthExceedsMtu`] drops.
    pub length_exceeds_mtu: u64,
    /// [`CfpDrop::NoBufferFree`] drops.
    pub no_buffer_free: u64,
    /// [`CfpDrop::UnexpectedMore`] drops.
    pub unexpected_more: u64,
    /// [`CfpDrop::RemainMismatch`] drops.
    pub remain_mismatch: u64,
    /// [`CfpDrop::Overflow`] drops.
    pub overflow: u64,
    /// [`CfpDrop::Restarted`] partial packets.
    pub restarted: u64,
    /// [`CfpDrop::Timeout`] purges.
    pub timeout: u64,
    /// [`CfpDrop::Reset`] partial packets.
    pub reset: u64,
}

/// One packet under reassembly (libcsp's `csp_can_pbuf_element_t`).
#[derive(Debug, Clone)]
struct Slot {
    /// `can_id & CFP_ID_CONN_MASK` of the BEGIN frame.
    key: u32,
    header: Header,
    /// Data length announced by the BEGIN frame.
    length: usize,
    data: Vec<u8>,
    /// Frames still expected, counting the next one (libcsp's `remain`).
    remain: u32,
    /// Time of the last frame for this key.
    last_used: SimTime,
}

/// CFP receiver reproducing libcsp 1.4's `csp_can_process_frame`.
///
/// - Partial packets are keyed by src + dst + ident ([`CFP_ID_CONN_MASK`]) in a fixed
///   array of slots searched in index order, as libcsp's `csp_can_pbuf`; there is no
///   filtering on dst (the caller decides which frames to accept).
/// - Each frame's `remain` must be exactly one less than the previous one's; anything
///   else drops the partial packet ([`CfpDrop::RemainMismatch`]). A packet completes as
///   soon as the announced number of data bytes has arrived.
/// - A BEGIN for a key that already has a partial packet discards it and restarts
///   reassembly with the new BEGIN (v1.4 reuses the buffer, logs "Incomplete frame").
/// - Deviation from 1.4: a BEGIN announcing more than the MTU is dropped
///   ([`CfpDrop::LengthExceedsMtu`]); 1.4 does not check and would overrun its buffer.
/// - Every frame for a key refreshes its timestamp; stale slots are purged only by
///   [`Reassembler::handle_timeout`] (libcsp purges only when its RX queue is idle).
/// - Never panics; memory is bounded by `slots * mtu`.
#[derive(Debug, Clone)]
pub struct Reassembler {
    config: ReassemblerConfig,
    slots: Vec<Option<Slot>>,
    stats: CfpStats,
    /// No partial packet goes stale before this instant ([`SimTime::MAX`]: none held): a
    /// lower bound of the earliest `last_used + timeout`, so that the purge called for every
    /// frame scans the slots only when one may be due.
    stale_from: SimTime,
    /// Slots holding a partial packet (`slots`' `Some`s), so that a node with none skips
    /// the walk over them for its next timeout, done at every frame.
    held: usize,
    /// The slot the last frame went to: the next frame's (a packet's frames come in a
    /// train), and, with one slot held, the one whose timeout is next. Keys are unique
    /// among the slots, so looking here first finds what the walk in index order finds.
    last: usize,
}

impl Default for Reassembler {
    fn default() -> Self {
        Reassembler::new(ReassemblerConfig::default())
    }
}

impl Reassembler {
    /// An empty reassembler.
    pub fn new(config: ReassemblerConfig) -> Self {
        Reassembler {
            config,
            slots: vec![None; config.slots],
            stats: CfpStats::default(),
            stale_from: SimTime::MAX,
            held: 0,
            last: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> ReassemblerConfig {
        self.config
    }

    /// The counters so far.
    pub fn stats(&self) -> CfpStats {
        self.stats
    }

    /// Number of partial packets held.
    pub fn partial_count(&self) -> usize {
        self.held
    }

    /// Handle one received frame at `now`.
    ///
    /// Returns `Some(Ok(packet))` when it completes a packet, `Some(Err(reason))` when the
    /// frame or a partial packet was dropped, `None` when the frame was absorbed. A BEGIN
    /// that restarts a partial packet and itself completes one returns the packet; the
    /// restart is still counted in [`CfpStats::restarted`].
    pub fn handle(&mut self, frame: &CanFrame, now: SimTime) -> Option<Result<Packet, CfpDrop>> {
        self.stats.frames += 1;
        let id = frame.id & CAN_EFF_MASK;
        let cfp = CfpId::from_can_id(id);
        let key = id & CFP_ID_CONN_MASK;
        let bytes = frame.data();

        let is_key = |s: &Option<Slot>| matches!(s, Some(s) if s.key == key);
        let held = if self.held == 0 {
            None
        } else if self.slots.get(self.last).is_some_and(is_key) {
            Some(self.last)
        } else {
            self.slots.iter().position(is_key)
        };
        let (idx, existing) = match held {
            Some(i) => (i, true),
            None if cfp.kind == FrameType::More => {
                return Some(Err(self.count(CfpDrop::UnexpectedMore)));
            }
            None => match self.slots.iter().position(Option::is_none) {
                Some(i) => (i, false),
                None => return Some(Err(self.count(CfpDrop::NoBufferFree))),
            },
        };

        let mut restarted = false;
        let payload = match cfp.kind {
            FrameType::Begin => {
                let Some(&[h0, h1, h2, h3, l0, l1]) = bytes.get(..BEGIN_OVERHEAD) else {
                    return Some(Err(self.free(idx, CfpDrop::BeginTooShort)));
                };
                let header = Header::from_word(u32::from_be_bytes([h0, h1, h2, h3]));
                let length = usize::from(u16::from_be_bytes([l0, l1]));
                if existing {
                    restarted = true;
                    self.stats.restarted += 1;
                }
                if length > self.config.mtu {
                    return Some(Err(self.free(idx, CfpDrop::LengthExceedsMtu)));
                }
                let slot = self.slots.get_mut(idx)?;
                self.held += usize::from(!existing);
                *slot = Some(Slot {
                    key,
                    header,
                    length,
                    data: Vec::with_capacity(length),
                    // Count the BEGIN itself, so the check below passes for it.
                    remain: u32::from(cfp.remain) + 1,
                    last_used: now,
                });
                bytes.get(BEGIN_OVERHEAD..).unwrap_or_default()
            }
            FrameType::More => bytes,
        };

        self.stale_from = self.stale_from.min(now + self.config.timeout);
        let slot = self.slots.get_mut(idx)?.as_mut()?;
        slot.last_used = now;
        self.last = idx;
        if u32::from(cfp.remain) != slot.remain.wrapping_sub(1) {
            return Some(Err(self.free(idx, CfpDrop::RemainMismatch)));
        }
        slot.remain -= 1;
        if slot.data.len() + payload.len() > slot.length {
            return Some(Err(self.free(idx, CfpDrop::Overflow)));
        }
        slot.data.extend_from_slice(payload);
        if slot.data.len() != slot.length {
            return restarted.then_some(Err(CfpDrop::Restarted));
        }
        let done = self.slots.get_mut(idx)?.take()?;
        self.held -= 1;
        self.stats.packets_ok += 1;
        Some(Ok(Packet {
            header: done.header,
            data: done.data,
        }))
    }

    /// The earliest time a partial packet goes stale, if any is held.
    pub fn poll_timeout(&self) -> Option<SimTime> {
        if self.held == 0 {
            return None;
        }
        if self.held == 1
            && let Some(Some(s)) = self.slots.get(self.last)
        {
            return Some(s.last_used + self.config.timeout);
        }
        self.slots
            .iter()
            .flatten()
            .map(|s| s.last_used + self.config.timeout)
            .min()
    }

    /// Purge partial packets idle for at least the timeout at `now`; returns how many.
    pub fn handle_timeout(&mut self, now: SimTime) -> usize {
        self.purge_stale(now, |_, _, _| {})
    }

    /// As [`Reassembler::handle_timeout`], telling `on_purge` each purged packet: its CFP
    /// key (the can id bits of [`CFP_ID_CONN_MASK`]), CSP header and data length.
    pub fn purge_stale(
        &mut self,
        now: SimTime,
        mut on_purge: impl FnMut(u32, Header, usize),
    ) -> usize {
        if now < self.stale_from {
            return 0;
        }
        let timeout = self.config.timeout;
        let mut purged = 0;
        let mut stale_from = SimTime::MAX;
        for slot in &mut self.slots {
            let Some(s) = slot.as_ref() else { continue };
            let due = s.last_used + timeout;
            if now >= due {
                if let Some(s) = slot.take() {
                    on_purge(s.key, s.header, s.length);
                }
                purged += 1;
            } else {
                stale_from = stale_from.min(due);
            }
        }
        self.stale_from = stale_from;
        self.held -= purged;
        self.stats.timeout += purged as u64;
        purged
    }

    /// Empty every slot (a reboot), telling `on_clear` each partial packet as
    /// [`Reassembler::purge_stale`] does.
    pub fn clear(&mut self, mut on_clear: impl FnMut(u32, Header, usize)) -> usize {
        let mut cleared = 0;
        for slot in &mut self.slots {
            if let Some(s) = slot.take() {
                on_clear(s.key, s.header, s.length);
                cleared += 1;
            }
        }
        self.stale_from = SimTime::MAX;
        self.held = 0;
        self.stats.reset += cleared as u64;
        cleared
    }

    /// Free slot `idx` and count `why`.
    fn free(&mut self, idx: usize, why: CfpDrop) -> CfpDrop {
        if let Some(slot) = self.slots.get_mut(idx)
            && slot.take().is_some()
        {
            self.held -= 1;
        }
        self.count(why)
    }

    /// Count a drop and return it.
    fn count(&mut self, why: CfpDrop) -> CfpDrop {
        let c = &mut self.stats;
        match why {
            CfpDrop::BeginTooShort => c.begin_too_short += 1,
            CfpDrop::LengthExceedsMtu => c.length_exceeds_mtu += 1,
            CfpDrop::NoBufferFree => c.no_buffer_free += 1,
            CfpDrop::UnexpectedMore => c.unexpected_more += 1,
            CfpDrop::RemainMismatch => c.remain_mismatch += 1,
            CfpDrop::Overflow => c.overflow += 1,
            CfpDrop::Restarted => c.restarted += 1,
            CfpDrop::Timeout => c.timeout += 1,
            CfpDrop::Reset => c.reset += 1,
        }
        why
    }
}

// Saved whole (docs/snapshots.md): the configuration is plain data and small.
snap::fields!(Fragmenter { next_ident, mtu });
snap::fields!(Slot {
    key,
    header,
    length,
    data,
    remain,
    last_used
});
snap::fields!(Reassembler {
    config,
    slots,
    stats,
    stale_from,
    held,
    last
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn ramp(n: usize) -> Vec<u8> {
        (0..n).map(|i| i as u8).collect()
    }

    /// The 20-byte worked example of libcsp-1.4.md section d.
    fn example() -> Packet {
        Packet::new(Header::new(6, 3, 7, 10), ramp(20))
    }

    fn frames(p: &Packet, ident: u16) -> Vec<CanFrame> {
        let mut out = Vec::new();
        fragment_with_ident(p, p.header.dst, ident, &mut out).unwrap();
        out
    }

    #[test]
    fn worked_example() {
        let want: [(u32, &[u8]); 4] = [
            (
                0x0618_0C00,
                &[0x8c, 0x31, 0xca, 0x00, 0x00, 0x14, 0x00, 0x01],
            ),
            (
                0x061C_0800,
                &[0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09],
            ),
            (
                0x061C_0400,
                &[0x0a, 0x0b, 0x0c, 0x0d, 0x0e, 0x0f, 0x10, 0x11],
            ),
            (0x061C_0000, &[0x12, 0x13]),
        ];
        for ident in [0u16, 5, 1023] {
            let got = frames(&example(), ident);
            assert_eq!(got.len(), 4);
            for (f, (id, data)) in got.iter().zip(want) {
                assert_eq!(f.id, id | u32::from(ident));
                assert_eq!(f.data(), data);
            }
            let mut r = Reassembler::default();
            let t = SimTime::ZERO;
            assert_eq!(r.handle(&got[0], t), None);
            assert_eq!(r.handle(&got[1], t), None);
            assert_eq!(r.handle(&got[2], t), None);
            assert_eq!(r.handle(&got[3], t), Some(Ok(example())));
            assert_eq!(r.partial_count(), 0);
            assert_eq!(r.stats().packets_ok, 1);
        }
        let id = CfpId::from_can_id(0x0618_0C00);
        assert_eq!(
            id,
            CfpId {
                src: 6,
                dst: 3,
                kind: FrameType::Begin,
                remain: 3,
                ident: 0
            }
        );
        assert_eq!(id.to_can_id(), 0x0618_0C00);
    }

    #[test]
    fn fragmenter_counter_and_limits() {
        let mut f = Fragmenter::new(1023, CSP_CAN_MTU);
        let mut out = Vec::new();
        assert_eq!(f.fragment(&example(), 3, &mut out), Ok(1023));
        assert_eq!(f.fragment(&example(), 3, &mut out), Ok(0));
        let big = Packet::new(Header::new(6, 3, 7, 10), ramp(257));
        let n = out.len();
        assert_eq!(f.fragment(&big, 3, &mut out), Err(Error::TooLong));
        assert_eq!(out.len(), n);
        assert_eq!(f.next_ident(), 1);
        assert_eq!(
            f.fragment(&example(), 32, &mut out),
            Err(Error::FieldRange("next_hop_mac"))
        );
        assert_eq!(f.next_ident(), 1);
        // The field limit: 2042 bytes is 256 frames, remain 255 in the BEGIN.
        let max = Packet::new(Header::new(6, 3, 7, 10), ramp(CFP_MAX_DATA));
        let mut out = Vec::new();
        fragment_with_ident(&max, 3, 0, &mut out).unwrap();
        assert_eq!(out.len(), 256);
        assert_eq!(CfpId::from_can_id(out[0].id).remain, 255);
        let over = Packet::new(Header::new(6, 3, 7, 10), ramp(CFP_MAX_DATA + 1));
        assert_eq!(
            fragment_with_ident(&over, 3, 0, &mut out),
            Err(Error::TooLong)
        );
    }

    #[test]
    fn begin_restarts_a_partial_packet() {
        // v1.4: a BEGIN whose key has a partial packet reuses the buffer ("Incomplete
        // frame") and reassembly continues with the new packet.
        let f = frames(&example(), 7);
        let mut r = Reassembler::default();
        let t = SimTime::ZERO;
        assert_eq!(r.handle(&f[0], t), None);
        assert_eq!(r.handle(&f[1], t), None);
        assert_eq!(r.handle(&f[0], t), Some(Err(CfpDrop::Restarted)));
        for fr in &f[1..3] {
            assert_eq!(r.handle(fr, t), None);
        }
        assert_eq!(r.handle(&f[3], t), Some(Ok(example())));
        assert_eq!(r.stats().restarted, 1);
        // A short BEGIN kills the partial packet with its key.
        assert_eq!(r.handle(&f[0], t), None);
        let short = CanFrame::new(f[0].id, &f[0].data()[..5]).unwrap();
        assert_eq!(r.handle(&short, t), Some(Err(CfpDrop::BeginTooShort)));
        assert_eq!(r.partial_count(), 0);
        assert_eq!(r.handle(&f[1], t), Some(Err(CfpDrop::UnexpectedMore)));
    }

    #[test]
    fn gaps_overflow_and_slots() {
        let f = frames(&example(), 1);
        let t = SimTime::ZERO;
        let mut r = Reassembler::default();
        assert_eq!(r.handle(&f[0], t), None);
        assert_eq!(r.handle(&f[2], t), Some(Err(CfpDrop::RemainMismatch)));
        assert_eq!(r.handle(&f[3], t), Some(Err(CfpDrop::UnexpectedMore)));
        // A last frame one byte longer than announced.
        assert_eq!(r.handle(&f[0], t), None);
        assert_eq!(r.handle(&f[1], t), None);
        assert_eq!(r.handle(&f[2], t), None);
        let long = CanFrame::new(f[3].id, &[0x12, 0x13, 0x14]).unwrap();
        assert_eq!(r.handle(&long, t), Some(Err(CfpDrop::Overflow)));
        // Length above the MTU.
        let mut huge = f[0];
        huge.data[4..6].copy_from_slice(&257u16.to_be_bytes());
        assert_eq!(r.handle(&huge, t), Some(Err(CfpDrop::LengthExceedsMtu)));
        // Slots run out after `slots` distinct keys.
        let mut r = Reassembler::new(ReassemblerConfig {
            slots: 2,
            ..Default::default()
        });
        for ident in 0..2 {
            assert_eq!(r.handle(&frames(&example(), ident)[0], t), None);
        }
        assert_eq!(
            r.handle(&frames(&example(), 2)[0], t),
            Some(Err(CfpDrop::NoBufferFree))
        );
        let s = r.stats();
        assert_eq!((s.no_buffer_free, s.frames), (1, 3));
    }

    #[test]
    fn timeout_counts_from_the_last_frame() {
        let f = frames(&example(), 1);
        let mut r = Reassembler::default();
        assert_eq!(r.poll_timeout(), None);
        r.handle(&f[0], SimTime::from_secs(1));
        r.handle(&f[1], SimTime::from_secs(5));
        assert_eq!(r.poll_timeout(), Some(SimTime::from_secs(15)));
        assert_eq!(r.handle_timeout(SimTime::from_ns(15_000_000_000 - 1)), 0);
        assert_eq!(r.handle_timeout(SimTime::from_secs(15)), 1);
        assert_eq!(r.stats().timeout, 1);
        assert_eq!(r.poll_timeout(), None);
    }

    /// The purge skips its scan while nothing can be stale, and still purges each partial
    /// packet at its own instant: packets begun at different times, one refreshed, one
    /// begun after a purge, and a frame stamped earlier than the last.
    #[test]
    fn each_partial_packet_is_purged_at_its_own_instant() {
        let s = SimTime::from_secs;
        let mut r = Reassembler::default();
        let (a, b, c, d) = (
            frames(&example(), 1),
            frames(&example(), 2),
            frames(&example(), 3),
            frames(&example(), 4),
        );
        r.handle(&a[0], s(1));
        r.handle(&b[0], s(3));
        r.handle(&a[1], s(6)); // a now stale at 16, b at 13
        assert_eq!(r.handle_timeout(s(12)), 0);
        assert_eq!(r.handle_timeout(s(13)), 1, "b at 13");
        assert_eq!(r.partial_count(), 1);
        r.handle(&c[0], s(14)); // c at 24
        r.handle(&d[0], s(2)); // stamped late: d at 12, already due
        assert_eq!(r.handle_timeout(s(14)), 1, "d, due at 12");
        assert_eq!(r.handle_timeout(s(15)), 0);
        assert_eq!(r.handle_timeout(s(16)), 1, "a at 16");
        assert_eq!(r.handle_timeout(s(23)), 0);
        assert_eq!(r.handle_timeout(s(24)), 1, "c at 24");
        assert_eq!(r.partial_count(), 0);
        assert_eq!(r.stats().timeout, 4);
        assert_eq!(r.handle_timeout(s(100)), 0);
    }
    #[test]
    fn strange_frames_do_not_panic() {
        let mut r = Reassembler::default();
        let t = SimTime::ZERO;
        let weird = CanFrame {
            id: u32::MAX,
            dlc: 200,
            data: [0xff; 8],
        };
        assert_eq!(r.handle(&weird, t), Some(Err(CfpDrop::UnexpectedMore)));
        let begin = CanFrame {
            id: 0x0618_0000,
            dlc: 0,
            data: [0; 8],
        };
        assert_eq!(r.handle(&begin, t), Some(Err(CfpDrop::BeginTooShort)));
    }

    /// The count of held slots against the slots themselves, and the next timeout against
    /// the walk over them, through random interleavings of fragments of several packets
    /// (some frames lost, doubled or cut short), with purges, on 3 slots so that they run
    /// out: every path that fills or frees a slot.
    #[test]
    fn the_held_count_is_the_slots_in_use() {
        let mut x = 0x2545_f491_u32;
        let mut rand = |n: u32| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x % n
        };
        let timeout = Duration::from_millis(50);
        let mut r = Reassembler::new(ReassemblerConfig {
            slots: 3,
            timeout,
            ..Default::default()
        });
        let trains: Vec<Vec<CanFrame>> = (0..6u16)
            .map(|ident| {
                let p = Packet::new(Header::new(6, 3, 7, 10), ramp(6 + 9 * usize::from(ident)));
                frames(&p, ident)
            })
            .collect();
        let mut next = vec![0usize; trains.len()];
        let mut t = SimTime::ZERO;
        let (mut completed, mut purged) = (0, 0);
        for _ in 0..20_000 {
            t = t + Duration::from_millis(u64::from(rand(8)));
            let k = rand(trains.len() as u32) as usize;
            let train = &trains[k];
            let mut f = train[next[k] % train.len()];
            let fate = rand(10);
            // 0: lost; 1: cut short or made longer; 2: doubled (the next one is the same
            // frame again); 3: a BEGIN announcing more than the MTU.
            if fate != 2 {
                next[k] += 1;
            }
            if fate == 1 {
                f.dlc = rand(9) as u8;
            }
            if fate == 3 && CfpId::from_can_id(f.id).kind == FrameType::Begin {
                f.data[4..6].copy_from_slice(&u16::MAX.to_be_bytes());
            }
            if fate != 0 && matches!(r.handle(&f, t), Some(Ok(_))) {
                completed += 1;
            }
            if rand(20) == 0 {
                purged += r.handle_timeout(t);
            }
            let in_use = r.slots.iter().filter(|s| s.is_some()).count();
            assert_eq!(r.partial_count(), in_use);
            let walked = r
                .slots
                .iter()
                .flatten()
                .map(|s| s.last_used + timeout)
                .min();
            assert_eq!(r.poll_timeout(), walked);
        }
        let s = r.stats();
        assert!(completed > 100 && purged > 10, "{completed} {purged}");
        assert!(
            s.no_buffer_free > 0 && s.restarted > 0 && s.remain_mismatch > 0,
            "{s:?}"
        );
        assert!(
            s.begin_too_short > 0 && s.length_exceeds_mtu > 0 && s.overflow > 0,
            "{s:?}"
        );
    }
}
