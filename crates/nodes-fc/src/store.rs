//! The FC's on-board telemetry store (ICD 1.1 "platform telemetry storage"; the layout is
//! the twin's, docs/protocol.md "Telemetry store").
//!
//! Every `period` the FC records the telemetry its `mask` chooses: its own (TMGEN, TMATP,
//! TMACD, TMSENS, TMRAWSENS: the bytes a request would get at that instant) at once, and
//! the EPS's TMEPS and the primary COMM's TMCOMM when their answers to its requests come
//! back. A record is `u32 rtc_s, u8 kind, u8 len, data[len]` (`kind` as the mask bit's
//! number: 1-5 the FC's telemetry commands, 7 TMEPS, 8 TMCOMM). The store is the FC's
//! non-volatile memory: it survives reboots and power loss. It is bounded by bytes
//! ([`StoreConfig::capacity_bytes`]): the oldest records go first, counted.
//!
//! Retrieval on the telemetry port: TMSTOREINFO 9 and TMSTOREGET 10 (`u32 from_rtc, u32
//! to_rtc, u32 skip`: the records whose RTC is within `from..=to`, from the `skip`-th on,
//! as many as fit in 200 bytes; the client asks again with `skip + count` until it has
//! `matching`); TMSTORECLEAR 11. The period and mask are platform parameters
//! (`store_period`, `store_mask`), so they are saved with the table.

use std::collections::VecDeque;
use std::time::Duration;

use csp::node::Node;
use csp::{Header, Packet, SimTime};

/// Mask bit of TMGEN (bit `n - 1` for the FC's telemetry command `n`, as TMPERSET's).
pub const MASK_TMGEN: u8 = 0x01;
/// Mask bit of TMACD.
pub const MASK_TMACD: u8 = 0x04;
/// Mask bit of the EPS's TMEPS.
pub const MASK_EPS: u8 = 0x40;
/// Mask bit of the primary COMM's TMCOMM.
pub const MASK_COMM: u8 = 0x80;
/// Every bit the mask may have: TMGEN..TMRAWSENS (TMALL is their sum, so not offered), the
/// EPS and the COMM.
pub const MASK_ALL: u8 = 0x1f | MASK_EPS | MASK_COMM;
/// Largest TMSTOREGET reply data (a wire limit, declared with the command).
pub use crate::wire::STORE_CHUNK_BYTES as CHUNK_BYTES;

/// What the store collects and keeps.
#[derive(Debug, Clone, PartialEq)]
pub struct StoreConfig {
    /// How often (`None`: not collecting).
    pub period: Option<Duration>,
    /// What ([`MASK_ALL`]'s bits).
    pub mask: u8,
    /// Bytes of records kept (record headers included); the oldest go first.
    pub capacity_bytes: usize,
    /// The EPS's address and port (TMEPS).
    pub eps: (u8, u8),
    /// The COMM's address and port (TMCOMM).
    pub comm: (u8, u8),
}

impl Default for StoreConfig {
    /// TMGEN and TMACD every minute, into 256 KiB (about two months of them). The EPS's and
    /// the COMM's telemetry cost two requests on the main bus each time: the `store_mask`
    /// parameter adds them.
    fn default() -> Self {
        StoreConfig {
            period: Some(Duration::from_secs(60)),
            mask: MASK_TMGEN | MASK_TMACD,
            capacity_bytes: 256 * 1024,
            eps: (platform::addr::EPS, icd::eps::PORT_EPS),
            comm: (platform::addr::COMM1, icd::comm::PORT),
        }
    }
}

/// One stored telemetry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record {
    /// The FC's RTC when it was taken, unix seconds.
    pub rtc_s: u32,
    /// Its kind (the mask bit's number, 1-8).
    pub kind: u8,
    /// The telemetry's reply data.
    pub data: Vec<u8>,
}

impl Record {
    fn wire_len(&self) -> usize {
        6 + self.data.len()
    }
    fn emit(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.rtc_s.to_le_bytes());
        out.push(self.kind);
        out.push(self.data.len() as u8);
        out.extend_from_slice(&self.data);
    }
}

/// The store and its collection.
#[derive(Debug, Clone)]
pub struct Store {
    cfg: StoreConfig,
    records: VecDeque<Record>,
    bytes: usize,
    /// Records pushed out by newer ones since the run began.
    pub overwritten: u64,
    /// Records taken since the run began.
    pub taken: u64,
    next: Option<SimTime>,
    port: Option<u8>,
}

impl Store {
    /// An empty store collecting by `cfg`.
    pub fn new(cfg: StoreConfig) -> Self {
        Store {
            cfg,
            records: VecDeque::new(),
            bytes: 0,
            overwritten: 0,
            taken: 0,
            next: None,
            port: None,
        }
    }

    /// The running configuration (the `store_period` and `store_mask` parameters).
    pub fn config(&self) -> &StoreConfig {
        &self.cfg
    }

    /// Change the period and mask at `now`: the next collection is one new period later.
    pub fn set(&mut self, period: Option<Duration>, mask: u8, now: Option<SimTime>) {
        self.cfg.period = period;
        self.cfg.mask = mask & MASK_ALL;
        self.next = match (period, now) {
            (Some(p), Some(t)) if self.port.is_some() => Some(t + p),
            _ => None,
        };
    }

    /// At boot: a port for the EPS's and COMM's answers, the first collection one period
    /// on. The records stay (non-volatile).
    pub fn start(&mut self, node: &mut Node, now: SimTime) {
        self.port = node.alloc_port();
        self.next = self
            .cfg
            .period
            .filter(|_| self.port.is_some())
            .map(|p| now + p);
    }

    /// When the next collection is due.
    pub fn due(&self) -> Option<SimTime> {
        self.next
    }

    /// Whether a collection is due at `now` (and move the schedule on).
    pub fn take_due(&mut self, now: SimTime) -> bool {
        match (self.next, self.cfg.period) {
            (Some(t), Some(p)) if t <= now => {
                self.next = Some(now + p);
                true
            }
            _ => false,
        }
    }

    /// Ask the EPS and the COMM for their telemetry, as the mask says.
    pub fn ask_others(&mut self, node: &mut Node, now: SimTime) {
        let Some(port) = self.port else { return };
        for (bit, (dst, dport), cmd) in [
            (MASK_EPS, self.cfg.eps, icd::eps::cmd::TMEPS),
            (MASK_COMM, self.cfg.comm, icd::comm::cmd::TMCOMM),
        ] {
            if self.cfg.mask & bit != 0 {
                // A send failure is counted by the node.
                let _ = node.send(
                    Packet::new(Header::new(node.addr(), dst, dport, port), vec![cmd]),
                    now,
                );
            }
        }
    }

    /// Take `packet` if it answers [`Store::ask_others`] (stored when it is a success);
    /// `false` if it is not for the store.
    pub fn handle_reply(&mut self, packet: &Packet, rtc_s: u32) -> bool {
        if self.port.is_none() || Some(packet.header.dport) != self.port {
            return false;
        }
        let h = &packet.header;
        let kind = if (h.src, h.sport) == self.cfg.eps {
            8 - 1
        } else if (h.src, h.sport) == self.cfg.comm {
            8
        } else {
            return true;
        };
        if let [_, 1, data @ ..] = packet.data.as_slice()
            && !data.is_empty()
            && data.len() <= usize::from(u8::MAX)
        {
            self.push(rtc_s, kind, data.to_vec());
        }
        true
    }

    /// Keep one record, pushing out the oldest beyond the capacity.
    pub fn push(&mut self, rtc_s: u32, kind: u8, data: Vec<u8>) {
        let r = Record { rtc_s, kind, data };
        self.bytes += r.wire_len();
        self.records.push_back(r);
        self.taken += 1;
        while self.bytes > self.cfg.capacity_bytes {
            let Some(old) = self.records.pop_front() else {
                break;
            };
            self.bytes -= old.wire_len();
            self.overwritten += 1;
        }
    }

    /// TMSTOREINFO's data (20 bytes): `u32 records, u32 bytes, u32 oldest_rtc, u32
    /// newest_rtc, u32 overwritten`.
    pub fn info(&self) -> Vec<u8> {
        use csp::reqrep::le::Repr;
        crate::wire::StoreInfo {
            records: self.records.len() as u32,
            bytes: self.bytes as u32,
            oldest_rtc: self.records.front().map_or(0, |r| r.rtc_s),
            newest_rtc: self.records.back().map_or(0, |r| r.rtc_s),
            overwritten: u32::try_from(self.overwritten).unwrap_or(u32::MAX),
        }
        .to_vec()
    }

    /// TMSTOREGET's data: `u32 matching, u8 count, count x record`, the records within
    /// `from..=to` from the `skip`-th on that fit in [`CHUNK_BYTES`]; `None` when `from >
    /// to`.
    pub fn get(&self, from: u32, to: u32, skip: u32) -> Option<Vec<u8>> {
        if from > to {
            return None;
        }
        let mut out = vec![0; 5];
        let mut matching = 0u32;
        let mut count = 0u8;
        let mut full = false;
        for r in self
            .records
            .iter()
            .filter(|r| (from..=to).contains(&r.rtc_s))
        {
            matching += 1;
            if matching <= skip || full {
                continue;
            }
            if out.len() + r.wire_len() > CHUNK_BYTES || count == u8::MAX {
                full = true;
                continue;
            }
            r.emit(&mut out);
            count += 1;
        }
        out[..4].copy_from_slice(&matching.to_le_bytes());
        out[4] = count;
        Some(out)
    }

    /// Erase every record; how many there were.
    pub fn clear(&mut self) -> u32 {
        let n = self.records.len() as u32;
        self.records.clear();
        self.bytes = 0;
        n
    }

    /// The records (oldest first).
    pub fn records(&self) -> impl Iterator<Item = &Record> {
        self.records.iter()
    }
}

snap::fields!(StoreConfig {
    period,
    mask,
    capacity_bytes,
    eps,
    comm
});
snap::fields!(Record { rtc_s, kind, data });
snap::fields!(Store {
    cfg,
    records,
    bytes,
    overwritten,
    taken,
    next,
    port
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn bounded_by_bytes_and_read_by_time_range_in_chunks() {
        let mut s = Store::new(StoreConfig {
            capacity_bytes: 10 * 22,
            ..StoreConfig::default()
        });
        for i in 0..12u32 {
            s.push(1000 + i, 1, vec![i as u8; 16]);
        }
        assert_eq!(s.records().count(), 10);
        assert_eq!(s.overwritten, 2);
        let info = s.info();
        assert_eq!(info[..4], 10u32.to_le_bytes());
        assert_eq!(info[8..12], 1002u32.to_le_bytes());
        assert_eq!(info[12..16], 1011u32.to_le_bytes());
        // 1003..=1010: 8 records of 22 bytes; 195 bytes hold 8 (5 + 176)... and a chunk
        // of 200 holds 8: all in one.
        let all = s.get(1003, 1010, 0).unwrap();
        assert_eq!(all[..4], 8u32.to_le_bytes());
        assert_eq!(all[4], 8);
        assert_eq!(all.len(), 5 + 8 * 22);
        assert_eq!(all[5..9], 1003u32.to_le_bytes());
        // Skip 6: the last two.
        let tail = s.get(1003, 1010, 6).unwrap();
        assert_eq!(tail[4], 2);
        assert_eq!(tail[5..9], 1009u32.to_le_bytes());
        assert!(s.get(5, 4, 0).is_none());
        assert_eq!(s.get(0, 10, 0).unwrap(), vec![0, 0, 0, 0, 0]);
        assert_eq!(s.clear(), 10);
        assert_eq!(s.info()[..4], [0; 4]);
    }

    #[test]
    fn a_big_range_comes_in_chunks_that_fit() {
        let mut s = Store::new(StoreConfig::default());
        for i in 0..20u32 {
            s.push(i, 7, vec![0; 88]);
        }
        let c = s.get(0, u32::MAX, 0).unwrap();
        assert_eq!(c[..4], 20u32.to_le_bytes());
        assert_eq!(c[4], 2, "two TMEPS records of 94 bytes in 200");
        assert!(c.len() <= CHUNK_BYTES);
    }
}
