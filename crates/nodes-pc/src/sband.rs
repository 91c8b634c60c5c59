//! The S-band transmitter model: a FIFO of payload bytes sent in fixed-size frames at a
//! constant bit rate.
//!
//! # Model
//! - Bytes handed to the transmitter wait in a FIFO of segments, each tagged with the
//!   session slot it belongs to.
//! - When the transmitter is on, healthy and idle and the FIFO is not empty, it starts a
//!   frame at once: it takes up to `frame_data_bytes` bytes from the head of the FIFO, all of
//!   the same slot (a frame never mixes two sessions; a short frame is padded with idle fill,
//!   so every frame has the same length). The frame occupies the link for
//!   `ceil((frame_data_bytes + frame_overhead_bytes) * 8 / rate_bps)` seconds (integer
//!   nanoseconds); its bytes reach the ground when its last bit has left, at the end of that
//!   time ([`Sband::complete`]).
//! - Default framing (CCSDS 131.0-B-4 and 132.0-B-3): a 1115-byte TM transfer frame (6-byte
//!   primary header, 1109-byte data field, no OCF/FECF) protected by Reed-Solomon (255,223)
//!   with interleaving depth 5 (160 parity bytes) behind a 4-byte attached sync marker: 1279
//!   bytes on the air per 1109 payload bytes, so `frame_data_bytes` 1109 and
//!   `frame_overhead_bytes` 170. At the default 1 Mbit/s a frame lasts 10.232 ms.
//! - Off ([`Sband::set_on`]`(false)`): nothing is sent; the frame on the air is cut and its
//!   bytes go back to the head of the FIFO; the FIFO is kept.
//! - Failure ([`Sband::fail`]): the frame on the air and the whole FIFO are lost; the caller
//!   records them as dropped. Nothing is sent until [`Sband::restore`].
//!
//! The transmitter is pure: the PC calls [`Sband::start_frame`] whenever it may start one
//! and [`Sband::complete`] at [`Sband::poll_timeout`].

use std::collections::VecDeque;
use std::time::Duration;

use csp::SimTime;

/// Configuration of the S-band transmitter (fixed for a run).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SbandConfig {
    /// Bit rate on the air, bit/s (0: the transmitter never sends).
    pub rate_bps: u64,
    /// Payload bytes carried by one frame (at least 1).
    pub frame_data_bytes: u32,
    /// Bytes on the air per frame besides the payload bytes (headers, coding, sync marker).
    pub frame_overhead_bytes: u32,
    /// Switched on at boot.
    pub on: bool,
}

impl Default for SbandConfig {
    fn default() -> Self {
        SbandConfig {
            // The M6P S-band downlink rate the twin models (INTERPRETATION.md section 7 makes
            // it a scenario setting; 1 Mbit/s is the default of the brief for issue #6).
            rate_bps: 1_000_000,
            // CCSDS 132.0-B-3 TM frame of 1115 bytes minus its 6-byte primary header.
            frame_data_bytes: 1109,
            // 6 header + 160 RS(255,223) I=5 parity (CCSDS 131.0-B-4) + 4 ASM.
            frame_overhead_bytes: 170,
            on: true,
        }
    }
}

/// Bytes of one session slot waiting in the transmitter.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Segment {
    slot: usize,
    bytes: VecDeque<u8>,
}

/// A frame on the air or just delivered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// The session slot whose bytes it carries.
    pub slot: usize,
    /// The payload bytes (padding excluded).
    pub bytes: Vec<u8>,
    /// When its last bit leaves (the bytes reach the ground).
    pub done_at: SimTime,
}

/// The S-band transmitter (see the module doc).
#[derive(Debug, Clone)]
pub struct Sband {
    cfg: SbandConfig,
    on: bool,
    failed: bool,
    queue: VecDeque<Segment>,
    queued_bytes: u64,
    in_flight: Option<Frame>,
}

impl Sband {
    /// A transmitter with an empty FIFO, on or off as configured.
    pub fn new(cfg: SbandConfig) -> Self {
        Sband {
            on: cfg.on,
            failed: false,
            queue: VecDeque::new(),
            queued_bytes: 0,
            in_flight: None,
            cfg,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &SbandConfig {
        &self.cfg
    }
    /// Set the bit rate (a parameter): the frame on the air keeps its end, the next frames
    /// go at the new rate.
    pub fn set_rate(&mut self, rate_bps: u64) {
        self.cfg.rate_bps = rate_bps;
    }
    /// Whether it is switched on.
    pub fn is_on(&self) -> bool {
        self.on
    }
    /// Whether it has failed.
    pub fn is_failed(&self) -> bool {
        self.failed
    }
    /// Whether it can send at all (on, healthy, non-zero rate).
    pub fn can_send(&self) -> bool {
        self.on && !self.failed && self.cfg.rate_bps > 0
    }
    /// Whether a frame is on the air.
    pub fn is_transmitting(&self) -> bool {
        self.in_flight.is_some()
    }
    /// Whether the FIFO is empty (the frame on the air aside).
    pub fn queue_is_empty(&self) -> bool {
        self.queue.is_empty()
    }
    /// Bytes in the FIFO (the frame on the air aside).
    pub fn queued_bytes(&self) -> u64 {
        self.queued_bytes
    }
    /// Payload bytes of one frame.
    pub fn frame_data_bytes(&self) -> usize {
        usize::try_from(self.cfg.frame_data_bytes.max(1)).unwrap_or(usize::MAX)
    }
    /// Air time of one frame; `None` at rate 0.
    pub fn frame_time(&self) -> Option<Duration> {
        if self.cfg.rate_bps == 0 {
            return None;
        }
        let bits = (u128::from(self.cfg.frame_data_bytes.max(1))
            + u128::from(self.cfg.frame_overhead_bytes))
            * 8;
        let rate = u128::from(self.cfg.rate_bps);
        let ns = (bits * 1_000_000_000).div_ceil(rate);
        Some(Duration::from_nanos(u64::try_from(ns).unwrap_or(u64::MAX)))
    }

    /// Hand `bytes` of session slot `slot` to the transmitter.
    pub fn push(&mut self, slot: usize, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        self.queued_bytes += bytes.len() as u64;
        match self.queue.back_mut() {
            Some(seg) if seg.slot == slot => seg.bytes.extend(bytes),
            _ => self.queue.push_back(Segment {
                slot,
                bytes: bytes.iter().copied().collect(),
            }),
        }
    }

    /// Bytes of `slot` not yet on the ground (FIFO and frame on the air).
    pub fn pending_bytes(&self, slot: usize) -> u64 {
        let q: u64 = self
            .queue
            .iter()
            .filter(|s| s.slot == slot)
            .map(|s| s.bytes.len() as u64)
            .sum();
        let f = self
            .in_flight
            .as_ref()
            .filter(|f| f.slot == slot)
            .map_or(0, |f| f.bytes.len() as u64);
        q + f
    }
    /// All bytes not yet on the ground.
    pub fn total_pending_bytes(&self) -> u64 {
        self.queued_bytes + self.in_flight.as_ref().map_or(0, |f| f.bytes.len() as u64)
    }

    /// Start a frame at `now` if the transmitter can send, is idle and has bytes.
    pub fn start_frame(&mut self, now: SimTime) -> bool {
        if !self.can_send() || self.in_flight.is_some() {
            return false;
        }
        let Some(frame_time) = self.frame_time() else {
            return false;
        };
        let max = self.frame_data_bytes();
        let Some(slot) = self.queue.front().map(|s| s.slot) else {
            return false;
        };
        let mut bytes = Vec::with_capacity(max);
        while bytes.len() < max {
            let Some(seg) = self.queue.front_mut() else {
                break;
            };
            if seg.slot != slot {
                break;
            }
            let n = (max - bytes.len()).min(seg.bytes.len());
            // By slices (a byte at a time through `drain` was 1.5 % of a full day).
            let (a, b) = seg.bytes.as_slices();
            let from_a = n.min(a.len());
            bytes.extend_from_slice(&a[..from_a]);
            bytes.extend_from_slice(&b[..n - from_a]);
            seg.bytes.drain(..n);
            if seg.bytes.is_empty() {
                self.queue.pop_front();
            }
        }
        self.queued_bytes -= bytes.len() as u64;
        self.in_flight = Some(Frame {
            slot,
            bytes,
            done_at: now + frame_time,
        });
        true
    }

    /// When the frame on the air completes.
    pub fn poll_timeout(&self) -> Option<SimTime> {
        self.in_flight.as_ref().map(|f| f.done_at)
    }
    /// The frame whose last bit has left by `now`.
    pub fn complete(&mut self, now: SimTime) -> Option<Frame> {
        if self.in_flight.as_ref().is_some_and(|f| f.done_at <= now) {
            self.in_flight.take()
        } else {
            None
        }
    }

    /// Switch on or off; off cuts the frame on the air and requeues its bytes at the head.
    pub fn set_on(&mut self, on: bool) {
        self.on = on;
        if !on {
            self.requeue_in_flight();
        }
    }

    fn requeue_in_flight(&mut self) {
        if let Some(f) = self.in_flight.take() {
            self.queued_bytes += f.bytes.len() as u64;
            match self.queue.front_mut() {
                Some(seg) if seg.slot == f.slot => {
                    for b in f.bytes.into_iter().rev() {
                        seg.bytes.push_front(b);
                    }
                }
                _ => self.queue.push_front(Segment {
                    slot: f.slot,
                    bytes: f.bytes.into(),
                }),
            }
        }
    }

    /// Fail: every byte not on the ground is lost; returns the lost bytes per slot, in slot
    /// order.
    pub fn fail(&mut self) -> Vec<(usize, u64)> {
        self.failed = true;
        self.clear()
    }
    /// Recover from a failure (on/off unchanged).
    pub fn restore(&mut self) {
        self.failed = false;
    }
    /// Empty the FIFO and the frame on the air; returns the lost bytes per slot, in slot
    /// order (power loss, failure).
    pub fn clear(&mut self) -> Vec<(usize, u64)> {
        self.requeue_in_flight();
        let mut lost: std::collections::BTreeMap<usize, u64> = Default::default();
        for seg in self.queue.drain(..) {
            *lost.entry(seg.slot).or_default() += seg.bytes.len() as u64;
        }
        self.queued_bytes = 0;
        lost.into_iter().collect()
    }
    /// Back to the boot state of a PC reboot: empty, switched as configured; a hardware
    /// failure persists.
    pub fn reboot(&mut self) -> Vec<(usize, u64)> {
        let lost = self.clear();
        self.on = self.cfg.on;
        lost
    }
}

snap::fields!(SbandConfig {
    rate_bps,
    frame_data_bytes,
    frame_overhead_bytes,
    on
});
snap::fields!(Segment { slot, bytes });
snap::fields!(Frame {
    slot,
    bytes,
    done_at
});
// The configuration too: a parameter changes the rate.
snap::fields!(Sband {
    cfg,
    on,
    failed,
    queue,
    queued_bytes,
    in_flight
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn small() -> Sband {
        Sband::new(SbandConfig {
            rate_bps: 8_000,
            frame_data_bytes: 10,
            frame_overhead_bytes: 5,
            on: true,
        })
    }

    #[test]
    fn default_frame_is_ccsds_rs_1279_bytes_at_1_mbps() {
        let s = Sband::new(SbandConfig::default());
        assert_eq!(s.frame_time(), Some(Duration::from_nanos(10_232_000)));
    }

    #[test]
    fn frames_are_fixed_length_and_deliver_at_their_end() {
        let mut s = small();
        // 15 bytes at 8000 bit/s = 15 ms per frame, padded or not.
        s.push(0, &[1, 2, 3]);
        assert!(s.start_frame(SimTime::ZERO));
        assert_eq!(s.poll_timeout(), Some(SimTime::from_ms(15)));
        assert!(s.complete(SimTime::from_ms(14)).is_none());
        let f = s.complete(SimTime::from_ms(15)).unwrap();
        assert_eq!(f.bytes, vec![1, 2, 3]);
        s.push(0, &[7; 25]);
        assert!(s.start_frame(SimTime::from_ms(15)));
        assert!(!s.start_frame(SimTime::from_ms(15)), "one frame at a time");
        assert_eq!(s.complete(SimTime::from_ms(30)).unwrap().bytes.len(), 10);
        assert_eq!(s.total_pending_bytes(), 15);
    }

    #[test]
    fn frames_carry_the_fifo_in_order_across_its_ring_buffers_wrap() {
        // Pushes of 13 between frames of 10, with a frame cut and requeued now and then: the
        // FIFO's ring buffer wraps, so frames are taken from both of its slices.
        let mut s = small();
        let mut sent = Vec::new();
        let mut got = Vec::new();
        let mut next = 0u8;
        let mut wrapped = false;
        for round in 0..200u32 {
            let chunk: Vec<u8> = (0..13).map(|i| next.wrapping_add(i)).collect();
            next = next.wrapping_add(13);
            s.push(0, &chunk);
            sent.extend_from_slice(&chunk);
            wrapped |= s
                .queue
                .front()
                .is_some_and(|g| !g.bytes.as_slices().1.is_empty());
            if s.start_frame(SimTime::ZERO) && round % 13 == 5 {
                s.set_on(false);
                s.set_on(true);
                assert!(s.start_frame(SimTime::ZERO));
            }
            if let Some(f) = s.complete(SimTime::MAX) {
                assert!(f.bytes.len() <= 10);
                got.extend(f.bytes);
            }
        }
        while s.start_frame(SimTime::ZERO) {
            got.extend(s.complete(SimTime::MAX).unwrap().bytes);
        }
        assert!(wrapped, "the test never took a frame across the wrap");
        assert_eq!(got, sent);
    }

    #[test]
    fn a_frame_never_mixes_slots() {
        let mut s = small();
        s.push(0, &[1, 2]);
        s.push(1, &[3, 4]);
        s.start_frame(SimTime::ZERO);
        assert_eq!(s.complete(SimTime::MAX).unwrap().bytes, vec![1, 2]);
        s.start_frame(SimTime::ZERO);
        let f = s.complete(SimTime::MAX).unwrap();
        assert_eq!((f.slot, f.bytes), (1, vec![3, 4]));
    }

    #[test]
    fn off_requeues_and_fail_loses_everything() {
        let mut s = small();
        s.push(0, &[1; 12]);
        s.start_frame(SimTime::ZERO);
        s.set_on(false);
        assert!(!s.is_transmitting());
        assert!(!s.start_frame(SimTime::ZERO));
        assert_eq!(s.pending_bytes(0), 12);
        s.set_on(true);
        s.start_frame(SimTime::ZERO);
        assert_eq!(s.complete(SimTime::MAX).unwrap().bytes, vec![1; 10]);
        s.push(1, &[2; 4]);
        s.start_frame(SimTime::ZERO);
        assert_eq!(s.fail(), vec![(0, 2), (1, 4)]);
        assert_eq!(s.total_pending_bytes(), 0);
        s.push(0, &[1]);
        assert!(!s.start_frame(SimTime::ZERO));
        s.restore();
        assert!(s.start_frame(SimTime::ZERO));
    }

    #[test]
    fn rate_zero_never_sends() {
        let mut s = Sband::new(SbandConfig {
            rate_bps: 0,
            ..SbandConfig::default()
        });
        s.push(0, &[1]);
        assert!(!s.start_frame(SimTime::ZERO));
        assert_eq!(s.frame_time(), None);
    }
}
