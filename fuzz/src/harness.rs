//! The node-core harness: one node of the M6P network (its real `NodeConfig` and
//! application) driven by a sequence of [`Op`]s decoded from the fuzz input, the way
//! `bus::driver` drives it in a run.
//!
//! - The node is built as the twin builds it: `m6p_twin::network::node_config` of the
//!   default network, the application with the run's boards (`platform::board::Boards`),
//!   `Host::new(cfg, app, SimTime::ZERO)`.
//! - Inputs follow the driver's rules: nothing reaches a node that is off or hung, timers
//!   due by an instant run before it (at their own instants), power on is a reboot, power
//!   off is `power_lost` and the queued transmissions are lost.
//! - After every input everything the node queued is drained (`poll_transmit`, the app's
//!   and the node's events).
//! - Work per input is bounded: at most [`MAX_OPS`] operations, the node's simulated time
//!   budget ([`NodeKind::TIME_BUDGET`]) and its work budget ([`NodeKind::WORK_BUDGET`]:
//!   entries into the node, each timer, frame and packet one, and each packet it routes in,
//!   its own to itself included). The work budget keeps the
//!   physics out of most of an input's time: an FC tick (orbit, environment, sensors,
//!   estimator, control, dynamics) costs as much as hundreds of packets, so an input that
//!   spends its budget on time passing ends there, and libFuzzer moves on to the next.
//!
//! Invariants checked (a violation panics, so libFuzzer reports it):
//! - a CAN transmission goes to a CAN interface, a packet to a packet interface; frames
//!   have a 29-bit id and at most 8 bytes; packets fit the interface MTU;
//! - the node's own CFP frames on each CAN interface reassemble (by libcsp's rules) into
//!   packets without a single drop;
//! - timers make progress: at most [`MAX_TIMEOUTS_AT_ONE_INSTANT`] `handle_timeout` calls
//!   at one instant (more would spin the driver's loop for ever).

use std::collections::VecDeque;
use std::fmt::Debug;
use std::time::Duration;

use arbitrary::{Arbitrary, Unstructured};
use csp::cfp::{self, CAN_EFF_MASK, CanFrame, Reassembler};
use csp::header::{BROADCAST, flags};
use csp::node::{App, Host, IfaceKind, NodeFault, Transmit};
use csp::{Header, Packet, Priority, SimTime};
use m6p_twin::network::{NetworkSpec, Role, node_config};
use nalgebra::{UnitQuaternion, Vector3};
use platform::board::{Activity, Boards, Burn};
use platform::truth::TruthSnapshot;

use crate::enc::{Enc, variant};

/// Most operations decoded from one input.
pub const MAX_OPS: usize = 64;
/// Most `handle_timeout` calls at one simulated instant before the harness calls it a
/// livelock.
pub const MAX_TIMEOUTS_AT_ONE_INSTANT: usize = 1000;
/// Largest CSP data length generated (libcsp 1.4's MTU on CAN and KISS).
pub const MAX_DATA: usize = 256;
/// UTC unix seconds at simulated time zero: 2026-04-30T18:00:00Z, the scenarios' `start`.
pub const START_UNIX_S: u64 = 1_777_572_000;
/// The addresses of the default network (INTERPRETATION.md section 1).
pub const NETWORK: [u8; 9] = [1, 2, 3, 4, 5, 6, 12, 13, 16];

fuzz_enum! {
    /// A CSP address, biased towards the node's own.
    pub enum AddrSel {
        /// The node's own address.
        Own,
        /// Broadcast (31).
        Broadcast,
        /// A node of the default network.
        Peer { i: u8 },
        /// Any address (masked to 5 bits).
        Any { a: u8 },
    }
}

fuzz_enum! {
    /// A CSP port, biased towards the node's ICD ports and the service ports.
    pub enum PortSel {
        /// One of the node's ICD ports.
        Icd { i: u8 },
        /// A service port, 0-6.
        Service { p: u8 },
        /// An ephemeral port, 32-63.
        Ephemeral { p: u8 },
        /// Any port (masked to 6 bits).
        Any { p: u8 },
    }
}

fuzz_enum! {
    /// The header flags.
    pub enum FlagSel {
        /// None.
        None,
        /// CRC32 flag with a correct CRC appended.
        Crc,
        /// CRC32 flag, the data taken as it is (its last 4 bytes as the CRC).
        CrcUnchecked,
        /// Any flag byte, data as it is.
        Raw { f: u8 },
    }
}

fuzz_struct! {
    /// A packet with arbitrary header fields.
    pub struct PacketSpec {
        pub prio: u8,
        pub src: AddrSel,
        pub dst: AddrSel,
        pub sport: PortSel,
        pub dport: PortSel,
        pub flags: FlagSel,
        pub data: Vec<u8>,
    }
}

fuzz_enum! {
    /// What happens to the CFP frames of a packet on their way.
    pub enum Mangle {
        /// Nothing.
        Intact,
        /// One frame is lost.
        DropFrame { i: u8 },
        /// One frame arrives twice.
        Duplicate { i: u8 },
        /// One frame swaps places with the next.
        SwapNext { i: u8 },
        /// The frames carry another CFP destination (as a promiscuous receiver sees them).
        OtherMac { mac: u8 },
    }
}

fuzz_enum! {
    /// How a packet reaches the node.
    pub enum Via {
        /// Whole, on interface `iface` (modulo the node's interfaces), through
        /// `handle_packet`.
        Packet { iface: u8 },
        /// As the CFP frames of libcsp 1.4 with this ident on a CAN interface, through
        /// `handle_frame` (a node without CAN gets it whole).
        Cfp { iface: u8, ident: u16, mangle: Mangle },
    }
}

fuzz_enum! {
    /// How much simulated time passes.
    pub enum Step {
        /// Microseconds.
        Micros { n: u16 },
        /// Milliseconds.
        Millis { n: u16 },
        /// Seconds.
        Seconds { n: u8 },
        /// Up to the node's next timer.
        NextTimer,
        /// Minutes (up to 15).
        Minutes { n: u8 },
    }
}

fuzz_enum! {
    /// What the run does to the node outside its network (`bus::driver::NodeCtl`).
    pub enum Ctl {
        /// Reboot (a scenario fault).
        Reboot,
        /// Power off (EPS channel or power fault).
        PowerOff,
        /// Power back on (a reboot).
        PowerOn,
        /// The node hangs: nothing in, no timers.
        Hang,
        /// The hang ends.
        Unhang,
        /// The COMM radio switch (other nodes ignore it).
        Radio { on: bool },
        /// A clock fault begins (jump up to 1e9 s, drift up to 1e6 ppm, as scenarios allow).
        ClockFault { id: u8, jump_ns: i64, drift_milli_ppm: i32 },
        /// A clock fault is corrected.
        ClockFixed { id: u8 },
    }
}

fuzz_enum! {
    /// A write to the run's boards by another node (the FC's truth, an activity, a burn).
    pub enum BoardOp {
        /// The FC posts a true state (plausible values built from the fields).
        Truth {
            q: [i16; 4],
            w: [i8; 3],
            sun: [i16; 3],
            visible: u8,
            wheels: [i16; 4],
            mtq: [i8; 3],
            lat: i16,
            lon: i16,
        },
        /// An activity switches.
        Activity { what: u8, on: bool },
        /// The ECU posts a burn starting now.
        Burn { ms: u16, thrust_mn: u16, mass_dkg: u8, dir: [i8; 3] },
    }
}

/// One step of a node harness; `C` is the node's structured ICD command.
#[derive(Debug, Clone, PartialEq, Eq, Arbitrary)]
pub enum Op<C> {
    /// A packet arrives.
    Deliver { via: Via, packet: PacketSpec },
    /// One raw CAN frame arrives on interface `iface` (modulo the node's interfaces).
    Frame { iface: u8, id: u32, data: Vec<u8> },
    /// Time passes; the timers due run at their instants.
    Advance { step: Step },
    /// A well-formed ICD request to the node (`C` builds port and data).
    Cmd {
        via: Via,
        src: AddrSel,
        sport: u8,
        prio: u8,
        cmd: C,
    },
    /// An answer to the `back`-th latest packet the node sent: from its destination, ports
    /// swapped, `command | result | data`, or the request's data echoed.
    Answer {
        back: u8,
        result: u8,
        echo: bool,
        data: Vec<u8>,
        via: Via,
    },
    /// The run acts on the node.
    Ctl { ctl: Ctl },
    /// Another node writes a board.
    Board { op: BoardOp },
}

impl<C: Enc> Enc for Op<C> {
    fn enc(&self, out: &mut Vec<u8>) {
        const N: usize = 7;
        match self {
            Op::Deliver { via, packet } => {
                variant(out, 0, N);
                via.enc(out);
                packet.enc(out);
            }
            Op::Frame { iface, id, data } => {
                variant(out, 1, N);
                iface.enc(out);
                id.enc(out);
                data.enc(out);
            }
            Op::Advance { step } => {
                variant(out, 2, N);
                step.enc(out);
            }
            Op::Cmd {
                via,
                src,
                sport,
                prio,
                cmd,
            } => {
                variant(out, 3, N);
                via.enc(out);
                src.enc(out);
                sport.enc(out);
                prio.enc(out);
                cmd.enc(out);
            }
            Op::Answer {
                back,
                result,
                echo,
                data,
                via,
            } => {
                variant(out, 4, N);
                back.enc(out);
                result.enc(out);
                echo.enc(out);
                data.enc(out);
                via.enc(out);
            }
            Op::Ctl { ctl } => {
                variant(out, 5, N);
                ctl.enc(out);
            }
            Op::Board { op } => {
                variant(out, 6, N);
                op.enc(out);
            }
        }
    }
}

/// What a node's command builder may look at.
#[derive(Debug, Clone, Copy)]
pub struct CmdCtx {
    /// Simulated now.
    pub now: SimTime,
}

impl CmdCtx {
    /// True UTC unix seconds now (the node's clock, without its errors).
    pub fn unix_s(&self) -> f64 {
        START_UNIX_S as f64 + self.now.as_ns() as f64 * 1e-9
    }
}

/// One kind of node core under the harness.
pub trait NodeKind {
    /// Its application.
    type App: App;
    /// Configuration choices decoded from the start of the input.
    type Setup: for<'a> Arbitrary<'a> + Enc + Debug + Clone + PartialEq;
    /// Its structured ICD requests.
    type Cmd: for<'a> Arbitrary<'a> + Enc + Debug + Clone + PartialEq;
    /// Its role in the default network.
    const ROLE: Role;
    /// Its CSP address.
    const ADDR: u8;
    /// Its ICD ports.
    const ICD_PORTS: &'static [u8];
    /// Most simulated time one input may cover.
    const TIME_BUDGET: Duration;
    /// Most entries into the node (timers run, frames and packets handed to it) one input
    /// may make: when they are spent, the node takes nothing more and the input ends.
    const WORK_BUDGET: usize;
    /// The application, as `m6p_twin::runtime::build::app_for` makes it.
    fn app(setup: &Self::Setup, boards: &Boards) -> Self::App;
    /// The destination port and data of a request.
    fn command(cmd: &Self::Cmd, ctx: &CmdCtx) -> (u8, Vec<u8>);
}

/// A node under test and everything around it.
pub struct Harness<K: NodeKind> {
    host: Host<K::App>,
    boards: Boards,
    kinds: Vec<(IfaceKind, usize)>,
    now: SimTime,
    end: SimTime,
    powered: bool,
    hung: bool,
    /// One reassembler per CAN interface for what the node sends.
    outside: Vec<Option<Reassembler>>,
    /// The latest packets the node sent (newest last).
    sent: VecDeque<Packet>,
    /// The instant of the last `handle_timeout` and how many calls it had.
    last_timeout: (SimTime, usize),
    /// Entries into the node so far ([`NodeKind::WORK_BUDGET`]).
    work: usize,
}

/// How many sent packets [`Op::Answer`] can pick from.
const SENT_KEPT: usize = 8;

impl<K: NodeKind> Harness<K> {
    /// Boot the node at time zero.
    pub fn new(setup: &K::Setup) -> Self {
        let net = NetworkSpec::default_m6p();
        let spec = net
            .nodes
            .iter()
            .find(|n| n.role == K::ROLE && n.addr == K::ADDR)
            .cloned()
            .expect("the node is in the default network");
        let (mut cfg, _media) = node_config(&spec);
        cfg.epoch_unix_s = START_UNIX_S;
        cfg.cfp_first_ident = 0x155;
        cfg.first_ephemeral_port = 40;
        let kinds = cfg
            .ifaces
            .iter()
            .map(|i| (i.kind, i.mtu))
            .collect::<Vec<_>>();
        let outside = kinds
            .iter()
            .map(|(k, _)| (*k == IfaceKind::Can).then(Reassembler::default))
            .collect();
        let boards = Boards::default();
        let app = K::app(setup, &boards);
        let host = Host::new(cfg, app, SimTime::ZERO);
        let mut h = Harness {
            host,
            boards,
            kinds,
            now: SimTime::ZERO,
            end: SimTime::ZERO + K::TIME_BUDGET,
            powered: true,
            hung: false,
            outside,
            sent: VecDeque::new(),
            last_timeout: (SimTime::ZERO, 0),
            work: 0,
        };
        h.drain();
        h
    }

    /// Whether the node takes input now: powered, not hung, and the input's work budget
    /// not spent.
    fn live(&self) -> bool {
        self.powered && !self.hung && !self.spent()
    }

    /// Whether the input's work budget is spent (the input ends): the entries into the node
    /// and the packets it routed in (a packet it sends itself, answered by itself, goes
    /// round up to the node's loopback budget, 64 a entry: each round counts).
    pub fn spent(&self) -> bool {
        let routed = usize::try_from(self.host.node.counters().rx_packets).unwrap_or(usize::MAX);
        self.work.saturating_add(routed) >= K::WORK_BUDGET
    }

    /// Pull everything the node queued and check it.
    fn drain(&mut self) {
        while let Some(tx) = self.host.node.poll_transmit() {
            match tx {
                Transmit::Can { iface, frame } => {
                    let kind = self.kinds.get(iface).map(|k| k.0);
                    assert_eq!(kind, Some(IfaceKind::Can), "CAN frame for iface {iface}");
                    assert!(frame.dlc as usize <= cfp::CAN_MAX_DLC, "DLC {}", frame.dlc);
                    assert!(frame.id <= CAN_EFF_MASK, "can id {:#x}", frame.id);
                    let now = self.now;
                    if let Some(Some(r)) = self.outside.get_mut(iface) {
                        match r.handle(&frame, now) {
                            Some(Ok(p)) => self.remember(p),
                            Some(Err(e)) => panic!(
                                "the node's own CFP frames do not reassemble: {e} (can id {:#010x})",
                                frame.id
                            ),
                            None => {}
                        }
                    }
                }
                Transmit::Packet { iface, packet } => {
                    let kind = self.kinds.get(iface).copied();
                    assert!(
                        matches!(kind, Some((IfaceKind::Packet, _))),
                        "packet for iface {iface}"
                    );
                    let mtu = kind.map_or(0, |k| k.1);
                    assert!(
                        packet.data.len() <= mtu,
                        "{} data bytes on an MTU of {mtu}",
                        packet.data.len()
                    );
                    self.remember(packet);
                }
            }
        }
        while self.host.app.poll_event().is_some() {}
        while self.host.node.poll_event().is_some() {}
    }

    fn remember(&mut self, p: Packet) {
        if self.sent.len() == SENT_KEPT {
            self.sent.pop_front();
        }
        self.sent.push_back(p);
    }

    /// Run the timers due up to `target` at their instants, then move to `target`.
    fn advance_to(&mut self, target: SimTime) {
        let target = target.min(self.end).max(self.now);
        while self.live() {
            let Some(due) = self.host.poll_timeout().filter(|&d| d <= target) else {
                break;
            };
            let t = self.now.max(due);
            if t == self.last_timeout.0 {
                self.last_timeout.1 += 1;
                assert!(
                    self.last_timeout.1 <= MAX_TIMEOUTS_AT_ONE_INSTANT,
                    "timer livelock: poll_timeout stays at {t:?} after {} handle_timeout calls",
                    self.last_timeout.1
                );
            } else {
                self.last_timeout = (t, 1);
            }
            self.now = t;
            self.work += 1;
            self.host.handle_timeout(t);
            self.drain();
        }
        self.now = target;
    }

    fn addr(&self, a: &AddrSel) -> u8 {
        match a {
            AddrSel::Own => K::ADDR,
            AddrSel::Broadcast => BROADCAST,
            AddrSel::Peer { i } => NETWORK[usize::from(*i) % NETWORK.len()],
            AddrSel::Any { a } => a & 0x1f,
        }
    }

    fn port(p: &PortSel) -> u8 {
        match p {
            PortSel::Icd { i } => K::ICD_PORTS[usize::from(*i) % K::ICD_PORTS.len()],
            PortSel::Service { p } => p % 7,
            PortSel::Ephemeral { p } => 32 + p % 32,
            PortSel::Any { p } => p & 0x3f,
        }
    }

    /// The packet a [`PacketSpec`] describes.
    pub fn packet(&self, s: &PacketSpec) -> Packet {
        let mut data = s.data.clone();
        data.truncate(MAX_DATA);
        let mut header = Header {
            prio: Priority::from_bits(s.prio),
            src: self.addr(&s.src),
            dst: self.addr(&s.dst),
            dport: Self::port(&s.dport),
            sport: Self::port(&s.sport),
            flags: 0,
        };
        match s.flags {
            FlagSel::None => {}
            FlagSel::Crc => {
                header.flags = flags::CRC32;
                data.truncate(MAX_DATA - 4);
                csp::crc32::append(&mut data);
            }
            FlagSel::CrcUnchecked => header.flags = flags::CRC32,
            FlagSel::Raw { f } => header.flags = f,
        }
        Packet::new(header, data)
    }

    fn deliver(&mut self, via: &Via, packet: Packet) {
        if !self.live() {
            return;
        }
        let n = self.kinds.len();
        let cans: Vec<usize> = (0..n)
            .filter(|&i| self.kinds[i].0 == IfaceKind::Can)
            .collect();
        match via {
            Via::Cfp {
                iface,
                ident,
                mangle,
            } if !cans.is_empty() => {
                let idx = cans[usize::from(*iface) % cans.len()];
                let mut mac = K::ADDR;
                if let Mangle::OtherMac { mac: m } = mangle {
                    mac = m & 0x1f;
                }
                let mut frames = Vec::new();
                if cfp::fragment_with_ident(&packet, mac, ident & cfp::IDENT_MASK, &mut frames)
                    .is_err()
                {
                    return;
                }
                let len = frames.len();
                match *mangle {
                    Mangle::DropFrame { i } => {
                        frames.remove(usize::from(i) % len);
                    }
                    Mangle::Duplicate { i } => {
                        let i = usize::from(i) % len;
                        frames.insert(i, frames[i]);
                    }
                    Mangle::SwapNext { i } if len > 1 => {
                        let i = usize::from(i) % (len - 1);
                        frames.swap(i, i + 1);
                    }
                    _ => {}
                }
                for f in &frames {
                    if !self.live() {
                        break;
                    }
                    self.work += 1;
                    self.host.handle_frame(idx, f, self.now);
                    self.drain();
                }
            }
            Via::Cfp { iface, .. } | Via::Packet { iface } => {
                let idx = usize::from(*iface) % n.max(1);
                self.work += 1;
                self.host.handle_packet(idx, packet, self.now);
                self.drain();
            }
        }
    }

    fn step(&mut self, s: &Step) {
        let target = match s {
            Step::Micros { n } => self.now + Duration::from_micros(u64::from(*n)),
            Step::Millis { n } => self.now + Duration::from_millis(u64::from(*n)),
            Step::Seconds { n } => self.now + Duration::from_secs(u64::from(*n)),
            Step::Minutes { n } => self.now + Duration::from_secs(60 * u64::from(n % 16)),
            Step::NextTimer => self.host.poll_timeout().unwrap_or(self.now),
        };
        self.advance_to(target);
    }

    fn ctl(&mut self, c: &Ctl) {
        let now = self.now;
        match *c {
            Ctl::Reboot => {
                if self.powered {
                    self.host.reboot(now);
                }
            }
            Ctl::PowerOff => {
                if self.powered {
                    self.powered = false;
                    self.host.power_lost(now);
                    // What it had queued is lost with the power (the driver's flush to no port).
                    while self.host.node.poll_transmit().is_some() {}
                    while self.host.app.poll_event().is_some() {}
                    while self.host.node.poll_event().is_some() {}
                }
            }
            Ctl::PowerOn => {
                if !self.powered {
                    self.powered = true;
                    self.hung = false;
                    self.host.reboot(now);
                }
            }
            Ctl::Hang => self.hung = true,
            Ctl::Unhang => self.hung = false,
            Ctl::Radio { on } => self.host.switch(
                nodes_comm::RADIO_SWITCH,
                csp::node::SwitchPosition::on_if(on),
                now,
            ),
            Ctl::ClockFault {
                id,
                jump_ns,
                drift_milli_ppm,
            } => {
                let jump_ns = jump_ns.clamp(-1_000_000_000_000_000_000, 1_000_000_000_000_000_000);
                let drift_ppm = (f64::from(drift_milli_ppm) * 1e-3).clamp(-1e6, 1e6);
                self.host.fault(
                    u32::from(id % 4),
                    Some(NodeFault::Clock { jump_ns, drift_ppm }),
                    now,
                );
            }
            Ctl::ClockFixed { id } => self.host.fault(u32::from(id % 4), None, now),
        }
        self.drain();
    }

    fn board(&mut self, op: &BoardOp) {
        let now = self.now;
        match op {
            BoardOp::Truth {
                q,
                w,
                sun,
                visible,
                wheels,
                mtq,
                lat,
                lon,
            } => {
                let _ = self.boards.truth.publish(&truth_snapshot(
                    now, q, w, sun, *visible, wheels, mtq, *lat, *lon,
                ));
            }
            BoardOp::Activity { what, on } => {
                let node = NETWORK[usize::from(*what / 7) % NETWORK.len()];
                let what = Activity::from_tag(*what % 7, node).unwrap_or(Activity::SbandTx);
                let _ = self.boards.activity.set(what, now, *on);
            }
            BoardOp::Burn {
                ms,
                thrust_mn,
                mass_dkg,
                dir,
            } => {
                let thrust_n = f64::from(*thrust_mn) * 1e-3;
                let dir = unit3(&dir.map(i16::from), Vector3::z());
                let _ = self.boards.burns.post(Burn {
                    posted: now,
                    start: now,
                    end: now + Duration::from_millis(u64::from(*ms)),
                    thrust_n,
                    mass_flow_kg_s: thrust_n / (220.0 * 9.80665),
                    mass_kg: 5.0 + f64::from(*mass_dkg) * 0.1,
                    dir_body: dir,
                });
            }
        }
    }

    /// Apply one operation.
    pub fn apply(&mut self, op: &Op<K::Cmd>) {
        match op {
            Op::Deliver { via, packet } => {
                let p = self.packet(packet);
                self.deliver(via, p);
            }
            Op::Frame { iface, id, data } => {
                if !self.live() {
                    return;
                }
                let n = self.kinds.len().max(1);
                let data = &data[..data.len().min(cfp::CAN_MAX_DLC)];
                if let Some(frame) = CanFrame::new(id & CAN_EFF_MASK, data) {
                    self.work += 1;
                    self.host
                        .handle_frame(usize::from(*iface) % n, &frame, self.now);
                    self.drain();
                }
            }
            Op::Advance { step } => self.step(step),
            Op::Cmd {
                via,
                src,
                sport,
                prio,
                cmd,
            } => {
                let (dport, data) = K::command(cmd, &CmdCtx { now: self.now });
                let mut header = Header::new(self.addr(src), K::ADDR, dport, 32 + sport % 32);
                header.prio = Priority::from_bits(*prio);
                let mut data = data;
                data.truncate(MAX_DATA);
                self.deliver(via, Packet::new(header, data));
            }
            Op::Answer {
                back,
                result,
                echo,
                data,
                via,
            } => {
                if self.sent.is_empty() {
                    return;
                }
                let i = self.sent.len() - 1 - usize::from(*back) % self.sent.len();
                let req = self.sent[i].clone();
                let h = req.header;
                let header = Header {
                    prio: h.prio,
                    src: h.dst,
                    dst: h.src,
                    dport: h.sport,
                    sport: h.dport,
                    flags: 0,
                };
                let cmd = req.data.first().copied().unwrap_or(0);
                let mut reply = vec![cmd, *result];
                if *echo {
                    reply.extend_from_slice(req.data.get(1..).unwrap_or_default());
                } else {
                    reply.extend_from_slice(data);
                }
                reply.truncate(MAX_DATA);
                self.deliver(via, Packet::new(header, reply));
            }
            Op::Ctl { ctl } => self.ctl(ctl),
            Op::Board { op } => self.board(op),
        }
    }

    /// The run ends: the application's final figures.
    pub fn finish(&mut self) {
        let now = self.now;
        self.host.app.finish(&mut self.host.node, now);
        self.drain();
    }
}

/// A plausible true state at `t` from small integers.
#[allow(clippy::too_many_arguments)]
fn truth_snapshot(
    t: SimTime,
    q: &[i16; 4],
    w: &[i8; 3],
    sun: &[i16; 3],
    visible: u8,
    wheels: &[i16; 4],
    mtq: &[i8; 3],
    lat: i16,
    lon: i16,
) -> TruthSnapshot {
    let qv = nalgebra::Quaternion::new(
        f64::from(q[0]),
        f64::from(q[1]),
        f64::from(q[2]),
        f64::from(q[3]),
    );
    let q = if qv.norm() > 0.0 {
        UnitQuaternion::from_quaternion(qv)
    } else {
        UnitQuaternion::identity()
    };
    let lat = f64::from(lat) / 32768.0 * std::f64::consts::FRAC_PI_2;
    let lon = f64::from(lon) / 32768.0 * std::f64::consts::PI;
    let r_hat = Vector3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
    let v_hat = unit3(&[0, 0, 1], Vector3::z())
        .cross(&r_hat)
        .try_normalize(1e-9)
        .unwrap_or_else(Vector3::x);
    TruthSnapshot {
        t,
        unix_ns: i64::try_from(START_UNIX_S).unwrap_or(0) * 1_000_000_000
            + i64::try_from(t.as_ns()).unwrap_or(i64::MAX / 2),
        r_eci_m: r_hat * 6_878_000.0,
        v_eci_m_s: v_hat * 7_612.0,
        q_eci_from_body: q,
        w_body_rad_s: Vector3::new(f64::from(w[0]), f64::from(w[1]), f64::from(w[2])) * 1e-3,
        sun_eci_unit: unit3(sun, Vector3::x()),
        in_eclipse_fraction_visible: f64::from(visible) / 255.0,
        b_eci_nt: r_hat * 30_000.0,
        wheel_speed_rad_s: wheels.map(|x| f64::from(x) / 32767.0 * 600.0),
        mtq_dipole_am2: mtq.map(|x| f64::from(x) / 127.0 * 0.2),
    }
}

fn unit3(v: &[i16; 3], fallback: Vector3<f64>) -> Vector3<f64> {
    Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
        .try_normalize(1e-12)
        .unwrap_or(fallback)
}

/// Whether `M6P_FUZZ_TRACE` is set: then [`run`] prints the setup and every operation
/// (with the simulated time) to stderr, to read what a crash input does.
fn trace() -> bool {
    static TRACE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *TRACE.get_or_init(|| std::env::var_os("M6P_FUZZ_TRACE").is_some())
}

/// Run one input against node kind `K`: the setup, then at most [`MAX_OPS`] operations.
pub fn run<K: NodeKind>(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let Ok(setup) = K::Setup::arbitrary(&mut u) else {
        return;
    };
    if trace() {
        eprintln!("setup: {setup:?}");
    }
    let mut h = Harness::<K>::new(&setup);
    for _ in 0..MAX_OPS {
        if u.is_empty() || h.spent() {
            break;
        }
        let Ok(op) = Op::<K::Cmd>::arbitrary(&mut u) else {
            break;
        };
        if trace() {
            eprintln!(
                "t = {:?} powered {} hung {}: {op:?}",
                h.now, h.powered, h.hung
            );
        }
        h.apply(&op);
    }
    h.finish();
}

/// The bytes of a seed: the setup, then the operations.
pub fn encode<K: NodeKind>(setup: &K::Setup, ops: &[Op<K::Cmd>]) -> Vec<u8> {
    let mut out = Vec::new();
    setup.enc(&mut out);
    for op in ops {
        op.enc(&mut out);
    }
    out
}

/// Decode a seed as [`run`] does (for the generator's round-trip check).
pub fn decode<K: NodeKind>(data: &[u8]) -> Option<(K::Setup, Vec<Op<K::Cmd>>)> {
    let mut u = Unstructured::new(data);
    let setup = K::Setup::arbitrary(&mut u).ok()?;
    let mut ops = Vec::new();
    while ops.len() < MAX_OPS && !u.is_empty() {
        match Op::<K::Cmd>::arbitrary(&mut u) {
            Ok(op) => ops.push(op),
            Err(_) => break,
        }
    }
    Some((setup, ops))
}
