//! The FC distributes its RTC over the platform: libcsp 1.4's CMP CLOCK set
//! (`csp_cmp_clock`: service port 0, `00 06 | tv_sec u32 BE | tv_nsec u32 BE`) to each
//! node of [`TimeSyncConfig::to`] (the PC by default), from an ephemeral port of its own,
//! at every boot, right after an RTCSTMSET, and every [`TimeSyncConfig::period`].
//!
//! The receiving node's service handler sets its CSP clock, the clock the PC reads session
//! start times against (ICD 3.1.3: "synchronized with internal M6P time"), and answers with
//! the clock it now reads; the FC counts the answers. The value sent is the RTC at the
//! instant the request leaves the FC, so the receiver lags by the bus transit (well under a
//! millisecond on CAN), and its own clock errors run on from there.

use std::time::Duration;

use csp::node::Node;
use csp::service::{CMP_CLOCK, CMP_REPLY, CMP_REQUEST, PORT_CMP};
use csp::{Header, Packet, SimTime};

/// Where and how often the FC sends its time.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TimeSyncConfig {
    /// The nodes whose clocks follow the FC's RTC (empty: none).
    pub to: Vec<u8>,
    /// Resend period; `None`: only at boot and after an RTCSTMSET.
    pub period: Option<Duration>,
}

impl Default for TimeSyncConfig {
    /// The PC, every 60 s.
    fn default() -> Self {
        TimeSyncConfig {
            to: vec![platform::addr::PC],
            period: Some(Duration::from_secs(60)),
        }
    }
}

/// The distribution's state (volatile: a reboot starts it again).
#[derive(Debug, Clone, Default)]
pub struct TimeSync {
    cfg: TimeSyncConfig,
    port: Option<u8>,
    next: Option<SimTime>,
    /// CMP CLOCK requests sent.
    pub sent: u64,
    /// CMP CLOCK replies received.
    pub replies: u64,
}

impl TimeSync {
    /// The running configuration (platform parameters change it; a new period counts from
    /// the next distribution).
    pub fn config_mut(&mut self) -> &mut TimeSyncConfig {
        &mut self.cfg
    }
    /// Distribution by `cfg`, not started.
    pub fn new(cfg: TimeSyncConfig) -> Self {
        TimeSync {
            cfg,
            ..TimeSync::default()
        }
    }

    /// At boot: take a port for the replies and send at once.
    pub fn start(&mut self, node: &mut Node, now: SimTime) {
        if self.cfg.to.is_empty() {
            return;
        }
        self.port = node.alloc_port();
        self.next = Some(now);
    }

    /// Send at the next opportunity (the RTC was set).
    pub fn soon(&mut self, now: SimTime) {
        if self.port.is_some() {
            self.next = Some(now);
        }
    }

    /// When the next requests are due.
    pub fn due(&self) -> Option<SimTime> {
        self.next
    }

    /// Send if due, with the RTC reading `rtc_unix_ns` (UTC unix nanoseconds) now.
    pub fn run(&mut self, node: &mut Node, now: SimTime, rtc_unix_ns: i128) {
        let (Some(port), Some(t)) = (self.port, self.next) else {
            return;
        };
        if t > now {
            return;
        }
        self.next = self.cfg.period.map(|p| now + p);
        let ns = rtc_unix_ns.max(0);
        let tv_sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
        let tv_nsec = (ns % 1_000_000_000) as u32;
        let mut data = vec![CMP_REQUEST, CMP_CLOCK];
        data.extend_from_slice(&tv_sec.to_be_bytes());
        data.extend_from_slice(&tv_nsec.to_be_bytes());
        for &dst in &self.cfg.to {
            let header = Header::new(node.addr(), dst, PORT_CMP, port);
            // A send failure is counted by the node.
            if node.send(Packet::new(header, data.clone()), now).is_ok() {
                self.sent += 1;
            }
        }
    }

    /// Take `packet` if it is the answer to a request; `false` if it is not for us.
    pub fn handle_reply(&mut self, packet: &Packet) -> bool {
        if Some(packet.header.dport) != self.port || packet.header.sport != PORT_CMP {
            return false;
        }
        if packet.data.get(..2) == Some(&[CMP_REPLY, CMP_CLOCK][..]) {
            self.replies += 1;
        }
        true
    }
}

snap::fields!(TimeSyncConfig { to, period });
snap::fields!(TimeSync {
    cfg,
    port,
    next,
    sent,
    replies
});
