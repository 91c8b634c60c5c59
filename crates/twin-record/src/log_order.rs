//! Messages into the file in log-time order.
//!
//! The encoder hands most messages out at their own simulated time, in order, but not all:
//! a train of CAN frames (`/can/<bus>/frames`) carries the time of its first frame and is
//! handed out when it closes, up to [`crate::record::TRAIN_MAX_SPAN_NS`] later; a node that
//! was hung hands out the samples it owes when it recovers (the EPS's `/eps/power` of a
//! 30 s hang, 29 s late); nodes' tasks interleave a little (a packet a fraction of a
//! millisecond late). MCAP readers that check order (the mcap tooling's `doctor
//! --strict-message-order`) and players that stream a file front to back want the file's
//! messages in log-time order, so the recorder holds here the messages that are not due
//! yet: those less than [`REORDER_WINDOW_NS`] of simulated time old, and those at or after
//! the first frame of a train still open. When they are due they go to the file sorted by
//! log time, ties in the order they were handed out. The same events give the same order,
//! so the same bytes. (A message later than the window is written when it comes, with the
//! latest log time written: `record`'s module docs.)
//!
//! The bytes are kept in one arena, reused; what is held spans the window, and [`HOLD_MAX`]
//! bounds it in messages whatever the events (the recorder then writes it all).

use std::collections::VecDeque;

/// Messages held at most before the recorder closes its open trains and writes them all.
pub const HOLD_MAX: usize = 1 << 16;

/// How late (simulated time) a message may be handed out and still be written in order.
pub const REORDER_WINDOW_NS: u64 = 60_000_000_000;

/// One held message: its channel (an index of the recorder's), log time and bytes in the
/// arena.
#[derive(Debug, Clone, Copy)]
struct Held {
    chan: usize,
    log_time: u64,
    start: usize,
    len: usize,
}

/// Messages waiting for their turn, sorted by log time (ties: arrival).
///
/// Every operation is cheap whatever is held (a minute of messages): a message goes in at
/// the back (a late one a binary search from it), due ones leave from the front, and the
/// arena is compacted only when most of it is released (amortised: each byte is copied at
/// most once more).
#[derive(Debug, Default)]
pub struct LogOrder {
    held: VecDeque<Held>,
    arena: Vec<u8>,
    /// The next arena, swapped in when the live bytes are compacted.
    spare: Vec<u8>,
    /// Bytes of the held messages.
    live: usize,
}

impl LogOrder {
    /// Messages held.
    pub fn len(&self) -> usize {
        self.held.len()
    }

    /// True when nothing is held.
    pub fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// The held messages in the order they will be written: channel, log time, bytes (a
    /// snapshot keeps them; holding them again in this order gives the same order).
    pub fn held(&self) -> impl Iterator<Item = (usize, u64, &[u8])> + '_ {
        self.held
            .iter()
            .map(|h| (h.chan, h.log_time, &self.arena[h.start..h.start + h.len]))
    }

    /// Hold a copy of a message, after every held message of its log time or earlier.
    pub fn hold(&mut self, chan: usize, log_time: u64, data: &[u8]) {
        let h = Held {
            chan,
            log_time,
            start: self.arena.len(),
            len: data.len(),
        };
        self.arena.extend_from_slice(data);
        self.live += data.len();
        // Most messages come in order: they go at the back.
        match self.held.back() {
            Some(last) if last.log_time > log_time => {
                let at = self.held.partition_point(|x| x.log_time <= log_time);
                self.held.insert(at, h);
            }
            _ => self.held.push_back(h),
        }
    }

    /// Write the held messages earlier than `due_before` (all of them for `None`), in
    /// order, and drop them; stops at `write`'s first error.
    pub fn release<E>(
        &mut self,
        due_before: Option<u64>,
        mut write: impl FnMut(usize, u64, &[u8]) -> Result<(), E>,
    ) -> Result<(), E> {
        // From the front, not a binary search: this runs for every message, and nearly
        // always finds none or a few due (each is written once).
        let n = match due_before {
            Some(t) => self
                .held
                .iter()
                .position(|x| x.log_time >= t)
                .unwrap_or(self.held.len()),
            None => self.held.len(),
        };
        if n == 0 {
            return Ok(());
        }
        for _ in 0..n {
            let Some(h) = self.held.pop_front() else {
                break;
            };
            self.live -= h.len;
            if let Err(e) = write(h.chan, h.log_time, &self.arena[h.start..h.start + h.len]) {
                self.compact();
                return Err(e);
            }
        }
        self.compact();
        Ok(())
    }

    /// Reuse the arena: empty it when nothing is held, or copy what is still held to the
    /// spare one when most of it is released.
    fn compact(&mut self) {
        if self.held.is_empty() {
            self.arena.clear();
            return;
        }
        if self.arena.len() < 64 * 1024 || self.live * 2 > self.arena.len() {
            return;
        }
        self.spare.clear();
        for h in &mut self.held {
            let start = self.spare.len();
            self.spare
                .extend_from_slice(&self.arena[h.start..h.start + h.len]);
            h.start = start;
        }
        std::mem::swap(&mut self.arena, &mut self.spare);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn drain(o: &mut LogOrder, before: Option<u64>) -> Vec<(usize, u64, Vec<u8>)> {
        let mut out = Vec::new();
        o.release::<()>(before, |c, t, d| {
            out.push((c, t, d.to_vec()));
            Ok(())
        })
        .unwrap();
        out
    }

    #[test]
    fn a_late_message_goes_before_later_ones_and_after_its_equals() {
        let mut o = LogOrder::default();
        o.hold(1, 10, b"a");
        o.hold(1, 20, b"b");
        o.hold(2, 30, b"c");
        // A train from t = 20, handed out now.
        o.hold(3, 20, b"train");
        assert!(drain(&mut o, Some(20)).iter().map(|m| m.1).eq([10]));
        let rest = drain(&mut o, None);
        let order: Vec<&[u8]> = rest.iter().map(|m| m.2.as_slice()).collect();
        assert_eq!(order, [&b"b"[..], b"train", b"c"]);
        assert!(o.is_empty());
    }

    #[test]
    fn the_arena_is_compacted_and_bytes_survive() {
        let mut o = LogOrder::default();
        let big = vec![7u8; 1000];
        for t in 0..200u64 {
            o.hold(0, t, &big);
        }
        o.hold(0, 500, b"last");
        let first = drain(&mut o, Some(199));
        assert_eq!(first.len(), 199);
        assert!(o.arena.len() < 10_000, "compacted: {}", o.arena.len());
        let rest = drain(&mut o, None);
        assert_eq!(rest.len(), 2);
        assert_eq!(rest[0].2, big);
        assert_eq!(rest[1].2, b"last");
    }
}
