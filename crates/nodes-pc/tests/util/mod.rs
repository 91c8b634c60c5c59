//! A harness for driving the PC through `csp::node::Host<PcApp>` in virtual time, with
//! scripted fake payloads (no dependency on nodes-payload) and a ground node (16) that sends
//! control requests. In the style of quinn-proto's `tests/util.rs`: `run_until` steps the
//! PC's timers and the payloads' replies in time order.
#![allow(clippy::unwrap_used, dead_code)]

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
use csp::router::Route;
use csp::{Header, Packet, SimTime};
use m6p_nodes_pc::wire::{self, SessionConfig, Status};
use m6p_nodes_pc::{PcApp, PcConfig, PcOutput, SessionResult};

/// The PC's address.
pub const PC: u8 = 6;
/// The ground station's address.
pub const GS: u8 = 16;
/// UTC unix seconds at simulated time zero (2026-04-30T18:00:00Z, the default scenario).
pub const EPOCH: u64 = 1_777_572_000;

/// The unix timestamp of simulated second `s`.
pub fn ts(s: u64) -> u32 {
    u32::try_from(EPOCH + s).unwrap()
}

/// What a fake payload does with a SYNC.
#[derive(Debug, Clone)]
pub enum SyncAct {
    /// `01 01 | msg`.
    Echo,
    /// No reply.
    Silent,
    /// This whole reply payload.
    Raw(Vec<u8>),
}

/// What a fake payload does with one POLL request (retries included).
#[derive(Debug, Clone)]
pub enum PollAct {
    /// `02 01 | the next n bytes of its stream`.
    Data(usize),
    /// `02 01 | the next frameSize bytes of its stream`.
    Full,
    /// No reply.
    Silent,
    /// This whole reply payload, `delay` after the request, from source port `sport`
    /// (`None`: its own port).
    Raw {
        bytes: Vec<u8>,
        delay: Option<Duration>,
        sport: Option<u8>,
    },
    /// `02 01 | the next n bytes`, `delay` after the request.
    DataAfter(usize, Duration),
}

/// A scripted payload: per-request actions, then a default.
#[derive(Debug, Clone)]
pub struct FakePayload {
    pub addr: u8,
    pub port: u8,
    pub latency: Duration,
    pub sync: SyncAct,
    /// Actions for POLL number 0, 1, ... (retries count); then `default_poll`.
    pub polls: Vec<PollAct>,
    pub default_poll: PollAct,
    /// Requests received: (time, data).
    pub requests: Vec<(SimTime, Vec<u8>)>,
    /// Next byte of its stream.
    pub stream_pos: u64,
    /// POLL requests received.
    pub poll_count: usize,
}

impl FakePayload {
    /// A payload that echoes SYNC and answers every POLL with a full frame after 5 ms.
    pub fn normal(addr: u8) -> Self {
        FakePayload {
            addr,
            port: wire::PORT_PAYLOAD,
            latency: Duration::from_millis(5),
            sync: SyncAct::Echo,
            polls: Vec::new(),
            default_poll: PollAct::Full,
            requests: Vec::new(),
            stream_pos: 0,
            poll_count: 0,
        }
    }
    pub fn with_polls(mut self, polls: Vec<PollAct>) -> Self {
        self.polls = polls;
        self
    }
    pub fn with_default(mut self, a: PollAct) -> Self {
        self.default_poll = a;
        self
    }
    pub fn with_sync(mut self, a: SyncAct) -> Self {
        self.sync = a;
        self
    }

    /// The POLL requests received so far.
    pub fn polls_received(&self) -> Vec<SimTime> {
        self.requests
            .iter()
            .filter(|(_, d)| d.first() == Some(&wire::cmd::POLL))
            .map(|(t, _)| *t)
            .collect()
    }
    /// The SYNC requests received so far.
    pub fn syncs_received(&self) -> Vec<Vec<u8>> {
        self.requests
            .iter()
            .filter(|(_, d)| d.first() == Some(&wire::cmd::SYNC))
            .map(|(_, d)| d.clone())
            .collect()
    }

    fn take(&mut self, n: usize) -> Vec<u8> {
        let v = stream_bytes(self.addr, self.stream_pos, n);
        self.stream_pos += n as u64;
        v
    }

    /// The reply (delay, packet) to a request, if any.
    fn answer(&mut self, req: &Packet, now: SimTime) -> Option<(Duration, Packet)> {
        self.requests.push((now, req.data.clone()));
        let mut head = req.header.reply(self.addr);
        let (delay, data) = match req.data.first() {
            Some(&wire::cmd::SYNC) => match &self.sync {
                SyncAct::Echo => {
                    let mut v = vec![wire::cmd::SYNC, 1];
                    v.extend_from_slice(&req.data[1..]);
                    (self.latency, v)
                }
                SyncAct::Silent => return None,
                SyncAct::Raw(b) => (self.latency, b.clone()),
            },
            Some(&wire::cmd::POLL) => {
                let frame = usize::from(*req.data.get(1)?);
                let idx = self.poll_count;
                self.poll_count += 1;
                let act = self
                    .polls
                    .get(idx)
                    .cloned()
                    .unwrap_or_else(|| self.default_poll.clone());
                let ok = |d: Vec<u8>| {
                    let mut v = vec![wire::cmd::POLL, 1];
                    v.extend(d);
                    v
                };
                match act {
                    PollAct::Full => (self.latency, ok(self.take(frame))),
                    PollAct::Data(n) => (self.latency, ok(self.take(n))),
                    PollAct::DataAfter(n, d) => (d, ok(self.take(n))),
                    PollAct::Silent => return None,
                    PollAct::Raw {
                        bytes,
                        delay,
                        sport,
                    } => {
                        if let Some(p) = sport {
                            head.sport = p;
                        }
                        (delay.unwrap_or(self.latency), bytes)
                    }
                }
            }
            _ => return None,
        };
        Some((delay, Packet::new(head, data)))
    }
}

/// The deterministic byte stream of payload `addr` from byte `from`.
pub fn stream_bytes(addr: u8, from: u64, n: usize) -> Vec<u8> {
    (from..from + n as u64)
        .map(|i| (i.wrapping_mul(31).wrapping_add(u64::from(addr)) % 251) as u8)
        .collect()
}

/// The PC under test, its fake payloads and a ground station.
pub struct Sim {
    pub host: Host<PcApp>,
    pub now: SimTime,
    pub payloads: BTreeMap<u8, FakePayload>,
    /// Packets on their way to the PC: (arrival, order, packet).
    in_flight: Vec<(SimTime, u64, Packet)>,
    seq: u64,
    /// Replies the PC sent to the ground.
    pub replies: Vec<Packet>,
    /// Packets the PC sent elsewhere (no such node).
    pub stray: Vec<Packet>,
    out: Arc<Mutex<Vec<PcOutput>>>,
    gs_port: u8,
}

/// The PC's node: one packet interface with a default route, clock at [`EPOCH`].
pub fn node_cfg() -> NodeConfig {
    let mut c = NodeConfig::new("PC", PC);
    c.ifaces = vec![IfaceConfig::packet("p")];
    c.routes.set_default(Route::direct(0));
    c.epoch_unix_s = EPOCH;
    c
}

impl Sim {
    /// A PC with `cfg` and the given payloads, booted at time zero.
    pub fn new(cfg: PcConfig, payloads: Vec<FakePayload>) -> Self {
        let out = Arc::new(Mutex::new(Vec::new()));
        let app = PcApp::new(cfg);
        Sim {
            host: Host::new(node_cfg(), app, SimTime::ZERO),
            now: SimTime::ZERO,
            payloads: payloads.into_iter().map(|p| (p.addr, p)).collect(),
            in_flight: Vec::new(),
            seq: 0,
            replies: Vec::new(),
            stray: Vec::new(),
            out,
            gs_port: 32,
        }
    }

    fn collect(&mut self) {
        while let Some(o) = self.host.poll_event() {
            self.out.lock().unwrap().push(o);
        }
        while let Some(tx) = self.host.node.poll_transmit() {
            let Transmit::Packet { packet, .. } = tx else {
                panic!("the PC's test node has no CAN interface")
            };
            let dst = packet.header.dst;
            if dst == GS {
                self.replies.push(packet);
            } else if let Some(p) = self.payloads.get_mut(&dst) {
                if let Some((delay, reply)) = p.answer(&packet, self.now) {
                    let at = self.now + delay;
                    self.deliver_at(at, reply);
                }
            } else {
                self.stray.push(packet);
            }
        }
    }

    /// Deliver `packet` to the PC at `at`.
    pub fn deliver_at(&mut self, at: SimTime, packet: Packet) {
        self.seq += 1;
        self.in_flight.push((at, self.seq, packet));
    }

    /// Advance to `t`, running every timer and delivery on the way.
    pub fn run_until(&mut self, t: SimTime) {
        // What a direct call on the host (a reboot) produced.
        self.collect();
        for _ in 0..10_000_000 {
            let tp = self.host.poll_timeout();
            let td = self.in_flight.iter().map(|(a, s, _)| (*a, *s)).min();
            let next = match (tp, td.map(|x| x.0)) {
                (Some(a), Some(b)) => a.min(b),
                (a, b) => match a.or(b) {
                    Some(x) => x,
                    None => break,
                },
            };
            if next > t {
                break;
            }
            self.now = self.now.max(next);
            if let Some((at, seq)) = td
                && at <= self.now
            {
                let i = self
                    .in_flight
                    .iter()
                    .position(|(_, s, _)| *s == seq)
                    .unwrap();
                let (_, _, p) = self.in_flight.remove(i);
                self.host.handle_packet(0, p, self.now);
            } else {
                self.host.handle_timeout(self.now);
            }
            self.collect();
        }
        self.collect();
        self.now = self.now.max(t);
    }

    /// Run for `d` more.
    pub fn run_for(&mut self, d: Duration) {
        let t = self.now + d;
        self.run_until(t);
    }

    /// Send `data` from the ground to PC port `port` now; the PC's single reply.
    pub fn request(&mut self, port: u8, data: &[u8]) -> Vec<u8> {
        self.gs_port = if self.gs_port >= 63 {
            32
        } else {
            self.gs_port + 1
        };
        let before = self.replies.len();
        self.host.handle_packet(
            0,
            Packet::new(Header::new(GS, PC, port, self.gs_port), data.to_vec()),
            self.now,
        );
        self.collect();
        let new: Vec<Packet> = self.replies.drain(before..).collect();
        assert_eq!(new.len(), 1, "one reply to {data:02x?} on port {port}");
        let r = &new[0];
        assert_eq!(r.header, Header::new(PC, GS, self.gs_port, port));
        r.data.clone()
    }

    /// Send a packet from `src` to PC port `port` now without expecting a reply.
    pub fn send_from(&mut self, src: u8, sport: u8, port: u8, data: &[u8]) {
        self.host.handle_packet(
            0,
            Packet::new(Header::new(src, PC, port, sport), data.to_vec()),
            self.now,
        );
        self.collect();
    }

    /// SETUP; the result code.
    pub fn setup(&mut self, c: &SessionConfig) -> u8 {
        let r = self.request(wire::PORT_CONTROL, &c.to_request());
        assert_eq!(r.len(), 2, "SETUP reply has no data");
        assert_eq!(r[0], wire::cmd::SETUP);
        r[1]
    }
    /// ABORT; the result code.
    pub fn abort(&mut self, id: u8) -> u8 {
        let r = self.request(wire::PORT_CONTROL, &[wire::cmd::ABORT, id]);
        assert_eq!(r.len(), 2);
        r[1]
    }
    /// STATUS, parsed; `None` on a failure reply.
    pub fn status(&mut self, id: u8) -> Option<Status> {
        let r = self.request(wire::PORT_CONTROL, &[wire::cmd::STATUS, id]);
        assert_eq!(r[0], wire::cmd::STATUS);
        if r[1] == 0 {
            assert_eq!(r.len(), 2);
            return None;
        }
        Some(Status::parse(&r[2..]).unwrap())
    }

    /// Everything the PC handed to its sink.
    pub fn outputs(&self) -> Vec<PcOutput> {
        self.out.lock().unwrap().clone()
    }
    /// The bytes of `session_id` that reached the ground, in order.
    pub fn downlinked(&self, session_id: u8) -> Vec<u8> {
        self.outputs()
            .into_iter()
            .filter_map(|o| match o {
                PcOutput::Downlinked {
                    session_id: s,
                    bytes,
                    ..
                } if s == session_id => Some(bytes),
                _ => None,
            })
            .flatten()
            .collect()
    }
    /// Session ends: (time, id, result, packets).
    pub fn ends(&self) -> Vec<(SimTime, u8, SessionResult, u32)> {
        self.outputs()
            .into_iter()
            .filter_map(|o| match o {
                PcOutput::SessionEnded {
                    t,
                    session_id,
                    result,
                    packets,
                } => Some((t, session_id, result, packets)),
                _ => None,
            })
            .collect()
    }
    /// Session starts: (time, id).
    pub fn starts(&self) -> Vec<(SimTime, u8)> {
        self.outputs()
            .into_iter()
            .filter_map(|o| match o {
                PcOutput::SessionStarted { t, session_id, .. } => Some((t, session_id)),
                _ => None,
            })
            .collect()
    }
    /// The payload `addr`.
    pub fn payload(&self, addr: u8) -> &FakePayload {
        &self.payloads[&addr]
    }
    /// Assert the accounting identity.
    pub fn assert_balanced(&self) {
        let a = self.host.app.accounting();
        assert!(a.is_balanced(), "accounting does not balance: {a:#?}");
    }
}

/// A session configuration: `id`, start `ts`, duration, max packets, frame size, sync message.
pub fn session(
    id: u8,
    timestamp: u32,
    duration_s: u16,
    max: u16,
    frame: u8,
    sync: &[u8],
) -> SessionConfig {
    SessionConfig {
        session_id: id,
        timestamp,
        duration_s,
        max_packets: max,
        poll_frame_size: frame,
        sync_message: sync.to_vec(),
    }
}

/// Sessions 1 (payload 12, polling), 2 (13, buffering) and 3 (14, polling).
pub fn cfg() -> m6p_nodes_pc::PcConfig {
    use m6p_nodes_pc::{PcConfig, SessionSpec};
    PcConfig {
        sessions: vec![
            SessionSpec::polling(1, 12),
            SessionSpec::buffering(2, 13),
            SessionSpec::polling(3, 14),
        ],
        ..PcConfig::default()
    }
}
