//! A CSP node: routing, CRC32 handling, CFP per CAN interface, the service handler and port
//! bindings, as one deterministic state machine (libcsp 1.4 `csp_route.c`, `csp_io.c`).
//!
//! Inputs carry the simulated time: [`Node::handle_frame`] (a CAN frame on a CAN
//! interface), [`Node::handle_packet`] (a whole packet on a packet interface such as KISS or
//! the UHF link), [`Node::send`] (the application originates a packet) and
//! [`Node::handle_timeout`]. Outputs are pulled: [`Node::poll_transmit`] for the links and
//! [`Node::poll_delivery`] for the application's bound ports.
//!
//! Rules kept from libcsp 1.4:
//! - a packet whose destination is this node or broadcast (31) is local; broadcast is
//!   never forwarded; replies carry the node's real address;
//! - a forwarded packet is never modified (its CRC32 is left alone) and is not sent back on
//!   the interface it came from;
//! - the CRC32 is appended only by the originating node when the CRC flag is set, and
//!   verified and stripped on local delivery; a mismatch is a counted drop;
//! - ports 0-6 are answered by the service handler (on a platform node, 1-6, a payload's
//!   request gets ping and uptime only, ICD 4.1: the rest is dropped and counted); packets
//!   to unbound ports are dropped;
//! - what the node sends on its own leaves from its own ephemeral port
//!   ([`NodeConfig::own_port`]), and what arrives there is dropped, never served;
//! - built as the M6P's libcsp (ICD 1.6: CRC32 but no XTEA, HMAC or RDP), a local packet
//!   flagged XTEA, HMAC or RDP is discarded and counted (`xtea`, `hmac`, `rdp`), checked in
//!   libcsp's order: XTEA, CRC32, HMAC, RDP, after the port lookup. Forwarded packets are
//!   not checked. libcsp also leaves the connection an RDP packet opened behind (one of its
//!   `CSP_CONN_MAX`); the twin has no connection table, so that is not modelled.
//!
//! [`Host`] pairs a node with an [`App`] (the node's own behaviour: FC, PC, payload...).

use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::time::Duration;

use crate::cfp::{self as cfp, CanFrame, CfpDrop, Fragmenter, Reassembler, ReassemblerConfig};
pub use crate::drop::{DropCause, DropReason};
use crate::header::{BROADCAST, EPHEMERAL_PORT_MIN, MAX_PORT, flags};
use crate::router::{IfaceId, Route, RoutingTable};
use crate::service::{self, ServiceAction, ServiceConfig};
use crate::{Header, Packet, SimTime, crc32};

/// The kind of link an interface sits on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IfaceKind {
    /// A CAN bus: packets are fragmented with CFP.
    Can,
    /// A packet link (KISS, UHF radio, ground network): whole packets.
    Packet,
}

/// One interface of a node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IfaceConfig {
    /// Name used in logs and tables (for example `main-can`).
    pub name: String,
    /// Kind of link.
    pub kind: IfaceKind,
    /// Largest data length sent on it (256 for CAN and KISS in libcsp 1.4).
    pub mtu: usize,
}

impl IfaceConfig {
    /// A CAN interface with libcsp 1.4's MTU of 256 bytes.
    pub fn can(name: &str) -> Self {
        IfaceConfig {
            name: name.to_owned(),
            kind: IfaceKind::Can,
            mtu: crate::cfp::CSP_CAN_MTU,
        }
    }
    /// A packet interface with libcsp 1.4's KISS MTU of 256 bytes.
    pub fn packet(name: &str) -> Self {
        IfaceConfig {
            name: name.to_owned(),
            kind: IfaceKind::Packet,
            mtu: crate::kiss::KISS_MTU,
        }
    }
}

/// Static configuration of a node.
#[derive(Debug, Clone)]
pub struct NodeConfig {
    /// Node name (`FC`, `PC`, ...).
    pub name: String,
    /// CSP address, 0..=30.
    pub addr: u8,
    /// Interfaces, indexed by [`IfaceId`].
    pub ifaces: Vec<IfaceConfig>,
    /// The static routing table.
    pub routes: RoutingTable,
    /// Whether ports 0-6 run the service handler.
    pub services: bool,
    /// Service handler answers.
    pub service: ServiceConfig,
    /// First CFP ident (libcsp 1.4 starts at `rand()`; the twin draws it from the run's seed).
    pub cfp_first_ident: u16,
    /// First ephemeral port tried (32..=63; libcsp 1.4 starts at `rand()`).
    pub first_ephemeral_port: u8,
    /// CFP reassembly settings.
    pub reassembly: ReassemblerConfig,
    /// UTC unix seconds at simulated time zero (for the CMP clock).
    pub epoch_unix_s: u64,
    /// Whether payloads (12-15) may use the platform port ([`crate::params`]) and, on a
    /// platform node, the service handler beyond ping and uptime: ICD 4.1 stars none of
    /// these, so by default they are refused.
    pub payload_access: platform::addr::PayloadAccess,
}

/// The own port of a node whose allocator starts at `first_ephemeral_port`
/// ([`NodeConfig::own_port`]): the ephemeral port before it in the cycle.
pub fn own_port(first_ephemeral_port: u8) -> u8 {
    match first_ephemeral_port.clamp(EPHEMERAL_PORT_MIN, MAX_PORT) {
        EPHEMERAL_PORT_MIN => MAX_PORT,
        p => p - 1,
    }
}

impl NodeConfig {
    /// The port the node's own packets leave from: those nobody asked for (periodic
    /// telemetry, a beacon, a payload's push). It is the ephemeral port just before
    /// `first_ephemeral_port` in the allocator's cycle (a libcsp program's are ephemeral
    /// too: `csp_connect` takes one), so it is never a port anybody serves, and an answer
    /// to such a packet can never be taken for a request. Bound from boot: the allocator
    /// never hands it out, and what arrives at it is dropped and counted (`own port`).
    pub fn own_port(&self) -> u8 {
        own_port(self.first_ephemeral_port)
    }

    /// A node with services on, default CFP settings and no interfaces yet.
    pub fn new(name: &str, addr: u8) -> Self {
        NodeConfig {
            name: name.to_owned(),
            addr,
            ifaces: Vec::new(),
            routes: RoutingTable::new(),
            services: true,
            service: ServiceConfig::named(name),
            cfp_first_ident: 0,
            first_ephemeral_port: EPHEMERAL_PORT_MIN,
            reassembly: ReassemblerConfig::default(),
            epoch_unix_s: 0,
            payload_access: platform::addr::PayloadAccess::default(),
        }
    }
}

/// Something a node wants sent on one of its interfaces.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transmit {
    /// A CAN frame on a CAN interface.
    Can {
        /// The interface.
        iface: IfaceId,
        /// The frame.
        frame: CanFrame,
    },
    /// A whole packet on a packet interface.
    Packet {
        /// The interface.
        iface: IfaceId,
        /// The packet (`header | data`, CRC32 included when flagged).
        packet: Packet,
    },
}

/// Why a node could not send a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SendError {
    /// No route to the destination.
    #[error("no route to node {0}")]
    NoRoute(u8),
    /// Data longer than the interface MTU.
    #[error("{len} bytes exceed the MTU of {mtu}")]
    TooLong {
        /// Data length including the CRC32 trailer.
        len: usize,
        /// The interface MTU.
        mtu: usize,
    },
    /// A header field is out of range.
    #[error("header field out of range")]
    BadHeader,
    /// Every ephemeral port is in use.
    #[error("no free ephemeral port")]
    NoPort,
}

/// Traffic counters of a node. Drops are keyed by a short reason (ordered for tables).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NodeCounters {
    /// Packets received (local or to forward).
    pub rx_packets: u64,
    /// Packets sent (originated or forwarded).
    pub tx_packets: u64,
    /// Packets forwarded to another interface.
    pub forwarded: u64,
    /// Packets handed to the application.
    pub delivered: u64,
    /// Replies sent by the service handler.
    pub service_replies: u64,
    /// Reboots.
    pub reboots: u64,
    /// Requests answered on the platform port ([`crate::params`]), refused ones included.
    pub platform_requests: u64,
    /// Platform-port requests refused (malformed, out of range, or not for this source).
    pub platform_refused: u64,
    /// Dropped packets and frames by reason.
    pub drops: BTreeMap<DropReason, u64>,
}

impl NodeCounters {
    /// Total drops.
    pub fn total_drops(&self) -> u64 {
        self.drops.values().sum()
    }
    fn drop(&mut self, reason: DropReason) {
        *self.drops.entry(reason).or_default() += 1;
    }
}

/// A hardware switch of a node's application, flipped by the run ([`App::switch`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum HwSwitch {
    /// A COMM's radio: on = active (it carries the link), off = standby.
    Radio,
}

/// Where a hardware switch is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SwitchPosition {
    /// On.
    On,
    /// Off.
    Off,
}

impl SwitchPosition {
    /// On when `on`.
    pub fn on_if(on: bool) -> Self {
        if on {
            SwitchPosition::On
        } else {
            SwitchPosition::Off
        }
    }
    /// Whether it is on.
    pub fn is_on(self) -> bool {
        self == SwitchPosition::On
    }
}

/// How much a node's log line matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// News: a mode, a session, a refused request and why.
    Info,
    /// Something went wrong but the node goes on (a late board write, a lost activity).
    Warning,
}

/// A CSP packet a node dropped: its header and the length of its data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DroppedPacket {
    /// The packet's header.
    pub header: Header,
    /// Bytes of data (after any CRC was stripped).
    pub data_len: usize,
    /// When CFP reassembly dropped the packet (its BEGIN refused: no free buffer, too long;
    /// or the partial packet timed out): a CAN id of it (the BEGIN's, or the id bits that
    /// name the packet on its bus, [`cfp::CFP_ID_CONN_MASK`]), and why.
    pub cfp: Option<(u32, CfpDrop)>,
}

/// A drop or a log line of a node, pulled with [`Node::poll_event`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeEvent {
    /// A packet, frame or piece of data was dropped (the node's own drops are also
    /// counted in [`NodeCounters::drops`]; an application counts its own).
    Drop {
        /// When.
        t: SimTime,
        /// Why: the node's CSP layer (`no route`, `crc32`, `cfp`, ...) or its application
        /// (`pc buffer-full`, ...).
        reason: DropCause,
        /// What was dropped.
        detail: String,
        /// The packet, when a whole CSP packet was dropped by the node (for accounting).
        packet: Option<DroppedPacket>,
    },
    /// A line from the node or its application.
    Log {
        /// When.
        t: SimTime,
        /// How much it matters.
        severity: Severity,
        /// The text.
        text: String,
    },
}

impl NodeEvent {
    /// An application's news at `t`.
    pub fn info(t: SimTime, text: String) -> Self {
        NodeEvent::Log {
            t,
            severity: Severity::Info,
            text,
        }
    }
    /// An application's warning at `t`.
    pub fn warning(t: SimTime, text: String) -> Self {
        NodeEvent::Log {
            t,
            severity: Severity::Warning,
            text,
        }
    }
    /// Something an application dropped at `t` (it counts it itself).
    pub fn dropped(t: SimTime, reason: impl Into<DropCause>, detail: String) -> Self {
        NodeEvent::Drop {
            t,
            reason: reason.into(),
            detail,
            packet: None,
        }
    }
    /// When it happened.
    pub fn t(&self) -> SimTime {
        match self {
            NodeEvent::Drop { t, .. } | NodeEvent::Log { t, .. } => *t,
        }
    }
}

impl std::fmt::Display for NodeEvent {
    /// `drop (reason): detail` or the log text, as the run's log shows them.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NodeEvent::Drop { reason, detail, .. } => write!(f, "drop ({reason}): {detail}"),
            NodeEvent::Log { text, .. } => f.write_str(text),
        }
    }
}

/// One error of a node's clock: a jump, and a drift from the instant it began.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockError {
    /// The step the clock took when it began, ns (positive: the clock is ahead).
    pub jump_ns: i64,
    /// How fast it runs wrong since, parts per million (positive: it gains).
    pub drift_ppm: f64,
    /// When it began.
    pub since: SimTime,
}

/// The errors of a node's clock, by id (a scenario's clock faults): the node's clock reads
/// its true time (and any offset set through CSP) plus their sum. They are hardware's: a
/// reboot keeps them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClockErrors(BTreeMap<u32, ClockError>);

impl ClockErrors {
    /// Error `id` begins (`Some`) or is corrected (`None`).
    pub fn set(&mut self, id: u32, error: Option<ClockError>) {
        match error {
            Some(e) => {
                self.0.insert(id, e);
            }
            None => {
                self.0.remove(&id);
            }
        }
    }
    /// How far ahead of true time the clock is at `now`, ns.
    pub fn error_ns(&self, now: SimTime) -> i128 {
        self.0
            .values()
            .map(|e| {
                let since_ns = now.as_ns().saturating_sub(e.since.as_ns()) as f64;
                i128::from(e.jump_ns) + (e.drift_ppm * 1e-6 * since_ns).round() as i128
            })
            .sum()
    }
}

/// A fault of a node's core (set with [`Node::set_fault`], by fault id): each variant is
/// added by the scenario fault kind that needs it.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum NodeFault {
    /// The node's clock jumps by `jump_ns` and drifts by `drift_ppm` from the fault's
    /// instant ([`ClockError`]) until the fault is lifted (the clock is corrected).
    Clock {
        /// The step, ns (positive: ahead).
        jump_ns: i64,
        /// The drift, parts per million (positive: it gains).
        drift_ppm: f64,
    },
}

/// A bounded queue of an application's outputs, pulled with [`App::poll_event`]: the
/// node's task drains it after every input, so it holds only what one input produced; past
/// `capacity` the oldest are dropped and counted.
#[derive(Debug, Clone)]
pub struct Outbox<E> {
    queue: VecDeque<E>,
    capacity: usize,
    dropped: u64,
}

impl<E> Default for Outbox<E> {
    fn default() -> Self {
        Outbox::new(Outbox::<E>::DEFAULT_CAPACITY)
    }
}

impl<E> Outbox<E> {
    /// Room for the longest catch-up of one input (an EPS after a day-long hang at 1 Hz).
    pub const DEFAULT_CAPACITY: usize = 1 << 20;

    /// An outbox holding at most `capacity` outputs.
    pub fn new(capacity: usize) -> Self {
        Outbox {
            queue: VecDeque::new(),
            capacity: capacity.max(1),
            dropped: 0,
        }
    }
    /// Queue an output (the oldest is dropped and counted when full).
    pub fn push(&mut self, e: E) {
        if self.queue.len() >= self.capacity {
            self.queue.pop_front();
            self.dropped += 1;
        }
        self.queue.push_back(e);
    }
    /// The oldest output not yet pulled.
    pub fn pop(&mut self) -> Option<E> {
        self.queue.pop_front()
    }
    /// Outputs dropped because nobody pulled them in time.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// The CSP part of a node (see the module doc).
#[derive(Debug)]
pub struct Node {
    cfg: NodeConfig,
    frag: Vec<Option<Fragmenter>>,
    reasm: Vec<Option<Reassembler>>,
    tx: VecDeque<Transmit>,
    rx: VecDeque<Packet>,
    events: VecDeque<NodeEvent>,
    bound: [bool; 64],
    next_port: u8,
    boot: SimTime,
    clock_offset_ns: i128,
    clock_sets: u64,
    reboot_requested: bool,
    counters: NodeCounters,
    /// The last [`RECENT_EVENTS`] events, read or not (the console's `log`).
    recent: VecDeque<NodeEvent>,
    frames: Vec<CanFrame>,
    faults: BTreeMap<u32, NodeFault>,
    clock_errors: ClockErrors,
    /// Packets this node sent to itself, waiting to be routed in (libcsp's loopback
    /// interface puts them on the router's queue; nothing is handled by recursion).
    loopback: VecDeque<Packet>,
    /// Whether the loopback queue is being worked (a packet sent to itself meanwhile only
    /// joins the queue).
    looping: bool,
}

/// Keep at most this many unread events (older ones are counted, not kept).
const MAX_EVENTS: usize = 1024;

/// The node keeps its last this many events for the console's `log`.
pub const RECENT_EVENTS: usize = 64;

/// The interface index of the loopback (a packet this node sent to itself).
const LOOPBACK_IFACE: IfaceId = usize::MAX;

/// At most this many packets a node sends to itself wait in its loopback queue (libcsp
/// 1.4's router FIFO, `CSP_FIFO_INPUT`, holds 10); more are dropped (`loopback full`).
pub const LOOPBACK_QUEUE: usize = 16;

/// At most this many loopback packets are routed in for one input (a packet, a frame, a
/// timer): a node's services answering each other through its own address (a ping from
/// service port 1 to service port 1 of itself) stop there, the rest dropped
/// (`loopback budget`), instead of ping-ponging for ever.
pub const LOOPBACK_PER_INPUT: usize = 64;

impl Node {
    /// A node booting at `now`.
    pub fn new(cfg: NodeConfig, now: SimTime) -> Self {
        let mut node = Node {
            frag: Vec::new(),
            reasm: Vec::new(),
            tx: VecDeque::new(),
            rx: VecDeque::new(),
            events: VecDeque::new(),
            bound: [false; 64],
            next_port: cfg.first_ephemeral_port.clamp(EPHEMERAL_PORT_MIN, MAX_PORT),
            boot: now,
            clock_offset_ns: 0,
            clock_sets: 0,
            reboot_requested: false,
            counters: NodeCounters::default(),
            recent: VecDeque::new(),
            frames: Vec::new(),
            faults: BTreeMap::new(),
            clock_errors: ClockErrors::default(),
            loopback: VecDeque::new(),
            looping: false,
            cfg,
        };
        node.bind(node.cfg.own_port());
        node.reset_links();
        node
    }

    fn reset_links(&mut self) {
        let mut ident = self.cfg.cfp_first_ident;
        self.frag = Vec::new();
        self.reasm = Vec::new();
        for iface in &self.cfg.ifaces {
            match iface.kind {
                IfaceKind::Can => {
                    self.frag
                        .push(Some(Fragmenter::new(ident % 1024, iface.mtu)));
                    self.reasm.push(Some(Reassembler::new(self.cfg.reassembly)));
                    ident = ident.wrapping_add(331);
                }
                IfaceKind::Packet => {
                    self.frag.push(None);
                    self.reasm.push(None);
                }
            }
        }
    }

    /// The header of a packet this node sends on its own to `dst`:`dport` (nobody asked
    /// for it): from its own port ([`NodeConfig::own_port`]).
    pub fn own_header(&self, dst: u8, dport: u8) -> Header {
        Header::new(self.cfg.addr, dst, dport, self.cfg.own_port())
    }
    /// The port this node's own packets leave from ([`NodeConfig::own_port`]).
    pub fn own_port(&self) -> u8 {
        self.cfg.own_port()
    }
    /// The node's CSP address.
    pub fn addr(&self) -> u8 {
        self.cfg.addr
    }
    /// The node's name.
    pub fn name(&self) -> &str {
        &self.cfg.name
    }
    /// The node's configuration.
    pub fn config(&self) -> &NodeConfig {
        &self.cfg
    }
    /// Traffic counters.
    pub fn counters(&self) -> &NodeCounters {
        &self.counters
    }
    /// Time since the last boot.
    pub fn uptime(&self, now: SimTime) -> Duration {
        service::uptime(self.boot, now)
    }
    /// UTC unix time of the node's clock, in nanoseconds: true time, the offset set
    /// through CSP, and the clock's errors ([`ClockErrors`]).
    pub fn clock_unix_ns(&self, now: SimTime) -> i128 {
        i128::from(self.cfg.epoch_unix_s) * 1_000_000_000
            + i128::from(now.as_ns())
            + self.clock_offset_ns
            + self.clock_errors.error_ns(now)
    }
    /// How many times CMP CLOCK set the node's clock (since the start of the run).
    pub fn clock_sets(&self) -> u64 {
        self.clock_sets
    }
    /// The errors of the node's clock.
    pub fn clock_errors(&self) -> &ClockErrors {
        &self.clock_errors
    }
    /// Clock error `id` begins (`Some`) or is corrected (`None`).
    pub fn set_clock_error(&mut self, id: u32, error: Option<ClockError>) {
        self.clock_errors.set(id, error);
    }

    /// Bind `port` so packets to it are delivered to the application.
    pub fn bind(&mut self, port: u8) {
        if let Some(b) = self.bound.get_mut(usize::from(port)) {
            *b = true;
        }
    }
    /// Unbind `port`.
    pub fn unbind(&mut self, port: u8) {
        if let Some(b) = self.bound.get_mut(usize::from(port)) {
            *b = false;
        }
    }
    /// Whether `port` is bound.
    pub fn is_bound(&self, port: u8) -> bool {
        self.bound.get(usize::from(port)).copied().unwrap_or(false)
    }
    /// Take a free ephemeral source port (32..=63) and bind it, cycling as libcsp does.
    pub fn alloc_port(&mut self) -> Option<u8> {
        let span = MAX_PORT - EPHEMERAL_PORT_MIN + 1;
        for _ in 0..span {
            let p = self.next_port;
            self.next_port = if p >= MAX_PORT {
                EPHEMERAL_PORT_MIN
            } else {
                p + 1
            };
            if !self.is_bound(p) {
                self.bind(p);
                return Some(p);
            }
        }
        None
    }

    /// A CAN frame arrived on CAN interface `iface` (already accepted by its CFP dst).
    pub fn handle_frame(&mut self, iface: IfaceId, frame: &CanFrame, now: SimTime) {
        let Some(Some(reasm)) = self.reasm.get_mut(iface) else {
            self.note_drop(now, DropReason::FrameOnNonCanIface, String::new());
            return;
        };
        match reasm.handle(frame, now) {
            Some(Ok(packet)) => self.route_in(iface, packet, now),
            Some(Err(reason)) => {
                let detail = format!("{reason} (can id {:#010x})", frame.id);
                // A BEGIN refused whole: the packet it starts is lost here, and known.
                let refused = matches!(reason, CfpDrop::NoBufferFree | CfpDrop::LengthExceedsMtu);
                match (refused, cfp::begin_fields(frame)) {
                    (true, Some((header, data_len))) => {
                        self.counters.drop(DropReason::Cfp);
                        self.push_event(NodeEvent::Drop {
                            t: now,
                            reason: DropReason::Cfp.into(),
                            detail,
                            packet: Some(DroppedPacket {
                                header,
                                data_len,
                                cfp: Some((frame.id, reason)),
                            }),
                        });
                    }
                    _ => self.note_drop(now, DropReason::Cfp, detail),
                }
            }
            None => {}
        }
    }

    /// A whole packet arrived on packet interface `iface`.
    pub fn handle_packet(&mut self, iface: IfaceId, packet: Packet, now: SimTime) {
        self.route_in(iface, packet, now);
    }

    fn route_in(&mut self, iface: IfaceId, packet: Packet, now: SimTime) {
        self.counters.rx_packets += 1;
        let dst = packet.header.dst;
        if dst == self.cfg.addr || dst == BROADCAST {
            self.deliver_local(packet, now);
            return;
        }
        match self.cfg.routes.lookup(dst) {
            None => self.note_drop(now, DropReason::NoRoute, packet.header.to_string()),
            Some(route) if route.iface == iface => {
                // csp_route_work: never loop a packet back out of the interface it came in on.
                self.note_drop(now, DropReason::SameIface, packet.header.to_string())
            }
            Some(route) => {
                if let Err(e) = self.transmit(route, &packet) {
                    self.note_drop(
                        now,
                        DropReason::ForwardFailed,
                        format!("{}: {e}", packet.header),
                    );
                } else {
                    self.counters.forwarded += 1;
                }
            }
        }
    }

    fn deliver_local(&mut self, mut packet: Packet, now: SimTime) {
        let dport = packet.header.dport;
        if dport == self.cfg.own_port() {
            // An answer to a packet this node sent on its own: nobody waits for one.
            self.note_drop(now, DropReason::OwnPort, packet.header.to_string());
            return;
        }
        let service = self.cfg.services && dport <= service::MAX_SERVICE_PORT;
        if service || self.is_bound(dport) {
            // csp_route_work: a socket is found first, then csp_route_security_check (XTEA,
            // CRC32, HMAC in that order) and the transport (RDP or UDP).
            let flag = |f: u8| packet.header.flags & f != 0;
            let refused = if flag(flags::XTEA) {
                Some((DropReason::Xtea, "XTEA encrypted"))
            } else if packet.header.has_crc() && !crc32::verify_and_strip(&mut packet.data) {
                self.note_drop(now, DropReason::Crc32, packet.header.to_string());
                return;
            } else if flag(flags::HMAC) {
                Some((DropReason::Hmac, "HMAC authenticated"))
            } else if flag(flags::RDP) {
                Some((DropReason::Rdp, "RDP"))
            } else {
                None
            };
            if let Some((reason, what)) = refused {
                // libcsp 1.4 built as the M6P's (ICD 1.6: no XTEA, HMAC or RDP) logs and
                // discards these.
                self.note_drop(
                    now,
                    reason,
                    format!(
                        "{}: received {what} packet, but CSP was compiled without {} support",
                        packet.header,
                        reason.name().to_uppercase()
                    ),
                );
            } else if service
                && platform::addr::PLATFORM.contains(&self.cfg.addr)
                && self
                    .cfg
                    .payload_access
                    .refuses(packet.header.src, service::open_to_payloads(dport))
            {
                self.refuse_payload_service(&packet, now);
            } else if service {
                self.serve(packet, now);
            } else {
                self.counters.delivered += 1;
                self.rx.push_back(packet);
            }
        } else {
            self.counters.drop(DropReason::UnboundPort);
            self.push_event(NodeEvent::Drop {
                t: now,
                reason: DropReason::UnboundPort.into(),
                detail: packet.header.to_string(),
                packet: Some(DroppedPacket {
                    header: packet.header,
                    data_len: packet.data.len(),
                    cfp: None,
                }),
            });
        }
    }

    /// A payload's request for a service ICD 4.1 does not open to it (everything but ping
    /// and uptime): dropped unanswered, counted by service, and logged as a warning the 1st,
    /// 2nd, 4th, 8th, ... time, so that a flood logs a few lines.
    fn refuse_payload_service(&mut self, packet: &Packet, now: SimTime) {
        let reason = service::payload_refusal(packet.header.dport);
        self.note_drop(now, reason, packet.header.to_string());
        let n = self.counters.drops.get(&reason).copied().unwrap_or(0);
        if n.is_power_of_two() {
            self.warn(
                now,
                format!(
                    "service port {}: node {} refused, {n} so far (ICD 4.1: payloads get ping and uptime only)",
                    packet.header.dport, packet.header.src
                ),
            );
        }
    }

    fn serve(&mut self, packet: Packet, now: SimTime) {
        let clock_ns = self.clock_unix_ns(now).max(0);
        let clock = (
            u32::try_from(clock_ns / 1_000_000_000).unwrap_or(u32::MAX),
            (clock_ns % 1_000_000_000) as u32,
        );
        let action = service::handle(
            &self.cfg.service,
            packet.header.dport,
            &packet.data,
            self.uptime(now),
            clock,
        );
        let reply_header = packet.header.reply(self.cfg.addr);
        let replies = match action {
            ServiceAction::Reply(d) => vec![d],
            ServiceAction::Replies(ds) => ds,
            ServiceAction::Reboot => {
                self.reboot_requested = true;
                vec![]
            }
            // libcsp 1.4 hands any time to the platform's clock_set_time and answers with
            // clock_get_time; the twin's clock refuses nanoseconds of a second or more, as
            // POSIX clock_settime does (EINVAL), and answers with the time it keeps.
            ServiceAction::SetClock { tv_nsec, .. } if tv_nsec >= 1_000_000_000 => {
                self.log(
                    now,
                    format!("CMP CLOCK from node {}: tv_nsec {tv_nsec} is not below one second; clock unchanged", packet.header.src),
                );
                vec![service::clock_reply(clock)]
            }
            ServiceAction::SetClock { tv_sec, tv_nsec } => {
                let want = i128::from(tv_sec) * 1_000_000_000 + i128::from(tv_nsec);
                self.clock_offset_ns += want - self.clock_unix_ns(now);
                self.clock_sets += 1;
                vec![service::clock_reply((tv_sec, tv_nsec))]
            }
            ServiceAction::None => vec![],
        };
        for data in replies {
            self.counters.service_replies += 1;
            if let Err(e) = self.send(Packet::new(reply_header, data), now) {
                self.note_drop(now, DropReason::ServiceReply, e.to_string());
            }
        }
    }

    /// Originate `packet` from this node: append the CRC32 when flagged, route and queue it.
    ///
    /// A packet to this node's own address is delivered locally (libcsp's loopback).
    pub fn send(&mut self, mut packet: Packet, now: SimTime) -> Result<(), SendError> {
        packet.header.validate().map_err(|_| SendError::BadHeader)?;
        if packet.header.has_crc() {
            crc32::append(&mut packet.data);
        }
        let dst = packet.header.dst;
        if dst == self.cfg.addr {
            self.counters.tx_packets += 1;
            if self.loopback.len() >= LOOPBACK_QUEUE {
                self.note_drop(now, DropReason::LoopbackFull, packet.header.to_string());
                return Ok(());
            }
            self.loopback.push_back(packet);
            if !self.looping {
                self.run_loopback(now);
            }
            return Ok(());
        }
        let route = self.cfg.routes.lookup(dst).ok_or(SendError::NoRoute(dst))?;
        self.transmit(route, &packet)
    }

    /// Route in what this node sent to itself, in order, at most [`LOOPBACK_PER_INPUT`]
    /// packets; whatever their handling sends to this node again joins the queue (no
    /// recursion), and what is left over the budget is dropped.
    fn run_loopback(&mut self, now: SimTime) {
        self.looping = true;
        let mut budget = LOOPBACK_PER_INPUT;
        while let Some(packet) = self.loopback.pop_front() {
            if budget == 0 {
                self.note_drop(now, DropReason::LoopbackBudget, packet.header.to_string());
                continue;
            }
            budget -= 1;
            self.route_in(LOOPBACK_IFACE, packet, now);
        }
        self.looping = false;
    }

    fn transmit(&mut self, route: Route, packet: &Packet) -> Result<(), SendError> {
        let Some(iface) = self.cfg.ifaces.get(route.iface) else {
            return Err(SendError::NoRoute(packet.header.dst));
        };
        if packet.data.len() > iface.mtu {
            return Err(SendError::TooLong {
                len: packet.data.len(),
                mtu: iface.mtu,
            });
        }
        match self.frag.get_mut(route.iface) {
            Some(Some(frag)) => {
                self.frames.clear();
                frag.fragment(packet, route.next_hop(packet.header.dst), &mut self.frames)
                    .map_err(|_| SendError::TooLong {
                        len: packet.data.len(),
                        mtu: iface.mtu,
                    })?;
                for frame in self.frames.drain(..) {
                    self.tx.push_back(Transmit::Can {
                        iface: route.iface,
                        frame,
                    });
                }
            }
            _ => self.tx.push_back(Transmit::Packet {
                iface: route.iface,
                packet: packet.clone(),
            }),
        }
        self.counters.tx_packets += 1;
        Ok(())
    }

    /// The next thing to send on a link.
    pub fn poll_transmit(&mut self) -> Option<Transmit> {
        self.tx.pop_front()
    }
    /// The next CAN frame to transmit if it goes out on interface `iface` (the rest of a
    /// packet's fragments, taken together).
    pub fn poll_transmit_can(&mut self, iface: usize) -> Option<CanFrame> {
        match self.tx.front() {
            Some(Transmit::Can { iface: i, .. }) if *i == iface => match self.tx.pop_front() {
                Some(Transmit::Can { frame, .. }) => Some(frame),
                _ => None,
            },
            _ => None,
        }
    }
    /// The next packet for a bound application port.
    pub fn poll_delivery(&mut self) -> Option<Packet> {
        self.rx.pop_front()
    }
    /// The next drop or event worth logging.
    pub fn poll_event(&mut self) -> Option<NodeEvent> {
        self.events.pop_front()
    }

    /// The earliest time [`Node::handle_timeout`] has work.
    pub fn poll_timeout(&self) -> Option<SimTime> {
        self.reasm
            .iter()
            .flatten()
            .filter_map(Reassembler::poll_timeout)
            .min()
    }
    /// Purge stale partial CFP packets.
    pub fn handle_timeout(&mut self, now: SimTime) {
        let mut purged = Vec::new();
        for r in self.reasm.iter_mut().flatten() {
            r.purge_stale(now, |key, header, data_len| {
                purged.push((key, header, data_len));
            });
        }
        self.report_partials(purged, CfpDrop::Timeout, now);
    }

    /// Partial CFP packets `lost` (key, header, data length) for `why`: counted and told,
    /// with the packet, so that a ledger can place their bytes.
    fn report_partials(&mut self, lost: Vec<(u32, Header, usize)>, why: CfpDrop, now: SimTime) {
        for (key, header, data_len) in lost {
            self.counters.drop(DropReason::Cfp);
            self.push_event(NodeEvent::Drop {
                t: now,
                reason: DropReason::Cfp.into(),
                detail: why.to_string(),
                packet: Some(DroppedPacket {
                    header,
                    data_len,
                    cfp: Some((key, why)),
                }),
            });
        }
    }

    /// Fault `id` acts on the node (`Some`) from `now`, or is lifted (`None`).
    pub fn set_fault(&mut self, id: u32, fault: Option<NodeFault>, now: SimTime) {
        match fault {
            Some(f) => {
                match &f {
                    NodeFault::Clock { jump_ns, drift_ppm } => self.set_clock_error(
                        id,
                        Some(ClockError {
                            jump_ns: *jump_ns,
                            drift_ppm: *drift_ppm,
                            since: now,
                        }),
                    ),
                }
                self.faults.insert(id, f);
            }
            None => {
                if let Some(NodeFault::Clock { .. }) = self.faults.remove(&id) {
                    self.set_clock_error(id, None);
                }
            }
        }
    }
    /// Power is gone: nothing queued leaves any more, and nothing is delivered.
    pub fn power_lost(&mut self) {
        self.tx.clear();
        self.rx.clear();
    }
    /// The node's last [`RECENT_EVENTS`] events (drops and log lines), oldest first.
    pub fn recent_events(&self) -> impl Iterator<Item = &NodeEvent> {
        self.recent.iter()
    }
    /// Whether the service handler asked for a reboot (cleared by [`Node::reboot`]).
    pub fn reboot_requested(&self) -> bool {
        self.reboot_requested
    }
    /// Reboot: uptime from zero, queues, partial packets and bindings cleared.
    pub fn reboot(&mut self, now: SimTime) {
        // The partial packets go with the memory; their bytes are lost here, and said so.
        let mut lost = Vec::new();
        for r in self.reasm.iter_mut().flatten() {
            r.clear(|key, header, data_len| lost.push((key, header, data_len)));
        }
        self.report_partials(lost, CfpDrop::Reset, now);
        self.boot = now;
        self.reboot_requested = false;
        self.tx.clear();
        self.rx.clear();
        self.bound = [false; 64];
        self.bind(self.cfg.own_port());
        self.clock_offset_ns = 0;
        self.counters.reboots += 1;
        self.reset_links();
    }

    /// An application's log line (bounded like the node's own events; the driver hands them
    /// to the run's log).
    pub fn log(&mut self, t: SimTime, text: String) {
        self.log_at(t, Severity::Info, text);
    }

    /// An application's warning (a late board write, something it could not do).
    pub fn warn(&mut self, t: SimTime, text: String) {
        self.log_at(t, Severity::Warning, text);
    }

    fn log_at(&mut self, t: SimTime, severity: Severity, text: String) {
        self.push_event(NodeEvent::Log { t, severity, text });
    }

    /// Something the application dropped (it counts it itself), for the run's log.
    pub fn log_drop(&mut self, t: SimTime, reason: impl Into<DropCause>, detail: String) {
        self.push_event(NodeEvent::dropped(t, reason, detail));
    }

    /// An application's event for the run's log (bounded like the node's own).
    pub fn push_event(&mut self, e: NodeEvent) {
        if self.recent.len() == RECENT_EVENTS {
            self.recent.pop_front();
        }
        self.recent.push_back(e.clone());
        if self.events.len() < MAX_EVENTS {
            self.events.push_back(e);
        }
    }

    fn note_drop(&mut self, t: SimTime, reason: DropReason, detail: String) {
        self.counters.drop(reason);
        self.push_event(NodeEvent::dropped(t, reason, detail));
    }
}

/// A node's own behaviour on top of CSP: the FC, the PC, a payload, a ground station.
///
/// Pure like the node: it gets the node to send through and the simulated time, and what it
/// tells the run (samples, sessions, burns) is pulled as typed events with
/// [`App::poll_event`], as transmissions are pulled from the node.
pub trait App: Send + 'static {
    /// What the application tells the run (for the record and the expectations).
    type Event: Send + 'static;
    /// The next event not yet pulled (the node's task drains them after every input).
    fn poll_event(&mut self) -> Option<Self::Event> {
        None
    }
    /// Called at boot and after every reboot: bind ports, arm timers.
    fn start(&mut self, node: &mut Node, now: SimTime);
    /// A packet arrived on a bound port.
    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime);
    /// The earliest time [`App::handle_timeout`] has work.
    fn poll_timeout(&self) -> Option<SimTime> {
        None
    }
    /// Timers due at `now`.
    fn handle_timeout(&mut self, _node: &mut Node, _now: SimTime) {}
    /// Forget volatile state (reboot, or power back after a loss).
    fn reset(&mut self, _now: SimTime) {}
    /// The node loses power at `now`: apply the physical consequences at that instant (a
    /// burn stops, heaters and transmitters go off, their activities end). Nothing can be
    /// sent any more; [`App::reset`] and [`App::start`] follow when power returns.
    fn power_lost(&mut self, _node: &mut Node, _now: SimTime) {}
    /// The run flipped one of the node's hardware switches (the radio on a COMM: active or
    /// standby). Applications ignore switches they do not have.
    fn switch(&mut self, _node: &mut Node, _switch: HwSwitch, _to: SwitchPosition, _now: SimTime) {}
    /// The run ends at `now`: report final figures (accounting, counters) through the
    /// application's own outputs. Nothing is sent on the network any more.
    fn finish(&mut self, _node: &mut Node, _now: SimTime) {}
    /// The node's CSP clock was set through CMP CLOCK (service port 0) at `now`: an
    /// application that keeps times against it re-reads it.
    fn clock_set(&mut self, _node: &mut Node, _now: SimTime) {}
    /// The node's parameter table ([`crate::params`]): with one, the [`Host`] binds the
    /// platform port ([`crate::params::PORT`]) and keeps its non-volatile copy.
    fn params(&mut self) -> Option<&mut dyn crate::params::Table> {
        None
    }
    /// The node's self-test at `now`: each component's health from the twin's state.
    fn self_test(&mut self, _node: &Node, _now: SimTime) -> Vec<crate::params::Check> {
        Vec::new()
    }
    /// The application's own console commands (beyond the node's: [`crate::console`]).
    fn console_commands(&self) -> &'static [crate::console::Command] {
        &[]
    }
    /// Run one of [`App::console_commands`] (`words[0]` is its name): the text to print, or
    /// a one-line error.
    fn console(
        &mut self,
        _node: &mut Node,
        words: &[&str],
        _now: SimTime,
    ) -> Result<String, crate::console::ConsoleError> {
        Err(crate::console::ConsoleError::NotRun {
            name: words.first().unwrap_or(&"").to_string(),
        })
    }
}

/// An application that binds nothing: the node only routes and answers ports 0-6.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoApp;

impl App for NoApp {
    type Event = std::convert::Infallible;
    fn start(&mut self, _node: &mut Node, _now: SimTime) {}
    fn handle_packet(&mut self, _node: &mut Node, _packet: Packet, _now: SimTime) {}
}

/// A node and its application, driven together.
#[derive(Debug)]
pub struct Host<A> {
    /// The CSP node.
    pub node: Node,
    /// Its application.
    pub app: A,
    /// The node's non-volatile parameter memory (survives reboots and power loss).
    pub nv: crate::params::ParamStore,
}

impl<A: App> Host<A> {
    /// Boot a node with its application at `now`.
    pub fn new(cfg: NodeConfig, app: A, now: SimTime) -> Self {
        let node = Node::new(cfg, now);
        let mut host = Host {
            node,
            app,
            nv: crate::params::ParamStore::default(),
        };
        // The scenario's values are the factory defaults.
        if let Some(t) = host.app.params() {
            host.nv.capture_defaults(t);
        }
        host.start(now);
        host
    }
    /// Boot the application: the saved parameters (or the defaults) first, then its start.
    fn start(&mut self, now: SimTime) {
        if let Some(t) = self.app.params() {
            for e in self.nv.load(t) {
                self.node
                    .warn(now, format!("parameter not restored at boot: {e}"));
            }
            self.node.bind(crate::params::PORT);
        }
        self.app.start(&mut self.node, now);
    }

    /// A CAN frame arrived on `iface`.
    pub fn handle_frame(&mut self, iface: IfaceId, frame: &CanFrame, now: SimTime) {
        let sets = self.node.clock_sets();
        self.node.handle_frame(iface, frame, now);
        self.clock_check(sets, now);
        self.after_input(now);
    }
    /// A packet arrived on packet interface `iface`.
    pub fn handle_packet(&mut self, iface: IfaceId, packet: Packet, now: SimTime) {
        let sets = self.node.clock_sets();
        self.node.handle_packet(iface, packet, now);
        self.clock_check(sets, now);
        self.after_input(now);
    }
    /// Tell the application if the input set the node's clock.
    fn clock_check(&mut self, sets_before: u64, now: SimTime) {
        if self.node.clock_sets() != sets_before {
            self.app.clock_set(&mut self.node, now);
        }
    }
    /// The earliest time [`Host::handle_timeout`] has work.
    pub fn poll_timeout(&self) -> Option<SimTime> {
        match (self.node.poll_timeout(), self.app.poll_timeout()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
    /// Run timers due at `now`.
    pub fn handle_timeout(&mut self, now: SimTime) {
        self.node.handle_timeout(now);
        self.app.handle_timeout(&mut self.node, now);
        self.after_input(now);
    }
    /// Fault `id` acts on the node's core from `now` (`Some`) or is lifted.
    pub fn fault(&mut self, id: u32, fault: Option<NodeFault>, now: SimTime) {
        self.node.set_fault(id, fault, now);
        self.after_input(now);
    }
    /// The application's next event not yet pulled ([`App::poll_event`]).
    pub fn poll_event(&mut self) -> Option<A::Event> {
        self.app.poll_event()
    }
    /// Flip the application's hardware switch `switch` to `to` (see [`App::switch`]).
    pub fn switch(&mut self, switch: HwSwitch, to: SwitchPosition, now: SimTime) {
        self.app.switch(&mut self.node, switch, to, now);
        self.after_input(now);
    }
    /// The node loses power at `now` ([`App::power_lost`]); what it had queued to send is
    /// lost with it.
    pub fn power_lost(&mut self, now: SimTime) {
        self.app.power_lost(&mut self.node, now);
        self.node.power_lost();
    }
    /// Reboot node and application (service port 4, or a scenario fault).
    pub fn reboot(&mut self, now: SimTime) {
        self.node.reboot(now);
        self.app.reset(now);
        self.start(now);
    }

    /// A request on the platform port: parameters and self-test ([`crate::params`]).
    fn platform_port(&mut self, packet: Packet, now: SimTime) {
        use crate::params::Effect;
        let src = packet.header.src;
        let (reply, effect, why) = if self.node.cfg.payload_access.refuses(src, false) {
            self.node.counters.platform_refused += 1;
            let command = packet.data.first().copied().unwrap_or(0);
            self.node.warn(
                now,
                format!("platform port: node {src} refused command {command} (ICD 4.1: not for payloads)"),
            );
            (crate::reqrep::failure(command), Effect::None, None)
        } else {
            let checks = if packet.data.first() == Some(&crate::params::cmd::SELFTEST) {
                self.app.self_test(&self.node, now)
            } else {
                Vec::new()
            };
            let Some(table) = self.app.params() else {
                return;
            };
            crate::params::serve(table, &mut self.nv, || checks, &packet.data)
        };
        match effect {
            Effect::None => {}
            Effect::Set { name, value } => self.node.log(
                now,
                format!("parameter {name} set to {value} by node {src}"),
            ),
            Effect::Saved => self
                .node
                .log(now, format!("parameters saved by node {src}")),
            Effect::Defaults => self
                .node
                .log(now, format!("parameters reset to defaults by node {src}")),
        }
        if let Some(why) = why {
            self.node.counters.platform_refused += 1;
            self.node.log(now, format!("platform port: {why}"));
        }
        self.node.counters.platform_requests += 1;
        // A send failure is already counted by the node.
        let _ = self.node.send(
            Packet::new(packet.header.reply(self.node.addr()), reply),
            now,
        );
    }

    fn after_input(&mut self, now: SimTime) {
        // Deliveries can cause replies that loop back locally; bound the loop.
        for _ in 0..1024 {
            let Some(packet) = self.node.poll_delivery() else {
                break;
            };
            if packet.header.dport == crate::params::PORT && self.app.params().is_some() {
                self.platform_port(packet, now);
            } else {
                self.app.handle_packet(&mut self.node, packet, now);
            }
        }
        if self.node.reboot_requested() {
            self.reboot(now);
        }
    }
}

/// A placeholder for a node whose ICD ports are not modelled yet: it binds `ports` and
/// answers every request on them with the ICD failure reply (command echoed, result 0),
/// so a well-formed request never goes unanswered.
#[derive(Debug, Clone, Default)]
pub struct StubApp {
    ports: Vec<u8>,
}

impl StubApp {
    /// Bind `ports`.
    pub fn new(ports: &[u8]) -> Self {
        StubApp {
            ports: ports.to_vec(),
        }
    }
}

impl App for StubApp {
    type Event = std::convert::Infallible;
    fn start(&mut self, node: &mut Node, _now: SimTime) {
        for &p in &self.ports {
            node.bind(p);
        }
    }
    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        let command = packet.data.first().copied().unwrap_or(0);
        let reply = Packet::new(
            packet.header.reply(node.addr()),
            crate::reqrep::failure(command),
        );
        // A send failure is already counted by the node; nothing else to do here.
        let _ = node.send(reply, now);
    }
}

impl<T: App + ?Sized> App for Box<T> {
    type Event = T::Event;
    fn poll_event(&mut self) -> Option<T::Event> {
        (**self).poll_event()
    }
    fn start(&mut self, node: &mut Node, now: SimTime) {
        (**self).start(node, now)
    }
    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        (**self).handle_packet(node, packet, now)
    }
    fn poll_timeout(&self) -> Option<SimTime> {
        (**self).poll_timeout()
    }
    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        (**self).handle_timeout(node, now)
    }
    fn reset(&mut self, now: SimTime) {
        (**self).reset(now)
    }
    fn power_lost(&mut self, node: &mut Node, now: SimTime) {
        (**self).power_lost(node, now)
    }
    fn switch(&mut self, node: &mut Node, switch: HwSwitch, to: SwitchPosition, now: SimTime) {
        (**self).switch(node, switch, to, now)
    }
    fn finish(&mut self, node: &mut Node, now: SimTime) {
        (**self).finish(node, now)
    }
    fn clock_set(&mut self, node: &mut Node, now: SimTime) {
        (**self).clock_set(node, now)
    }
    fn params(&mut self) -> Option<&mut dyn crate::params::Table> {
        (**self).params()
    }
    fn self_test(&mut self, node: &Node, now: SimTime) -> Vec<crate::params::Check> {
        (**self).self_test(node, now)
    }
    fn console_commands(&self) -> &'static [crate::console::Command] {
        (**self).console_commands()
    }
    fn console(
        &mut self,
        node: &mut Node,
        words: &[&str],
        now: SimTime,
    ) -> Result<String, crate::console::ConsoleError> {
        (**self).console(node, words, now)
    }
}

/// An application whose events are mapped by `f` (for a run that gathers every node's
/// events in one type): [`MapEvents::new`].
pub struct MapEvents<A, F> {
    app: A,
    f: F,
}

impl<A: fmt::Debug, F> fmt::Debug for MapEvents<A, F> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("MapEvents")
            .field("app", &self.app)
            .finish_non_exhaustive()
    }
}

impl<A, F> MapEvents<A, F> {
    /// `app`, its events mapped by `f`.
    pub fn new(app: A, f: F) -> Self {
        MapEvents { app, f }
    }
}

impl<A, E, F> App for MapEvents<A, F>
where
    A: App,
    E: Send + 'static,
    F: FnMut(A::Event) -> E + Send + 'static,
{
    type Event = E;
    fn poll_event(&mut self) -> Option<E> {
        self.app.poll_event().map(&mut self.f)
    }
    fn start(&mut self, node: &mut Node, now: SimTime) {
        self.app.start(node, now)
    }
    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        self.app.handle_packet(node, packet, now)
    }
    fn poll_timeout(&self) -> Option<SimTime> {
        self.app.poll_timeout()
    }
    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        self.app.handle_timeout(node, now)
    }
    fn reset(&mut self, now: SimTime) {
        self.app.reset(now)
    }
    fn power_lost(&mut self, node: &mut Node, now: SimTime) {
        self.app.power_lost(node, now)
    }
    fn switch(&mut self, node: &mut Node, switch: HwSwitch, to: SwitchPosition, now: SimTime) {
        self.app.switch(node, switch, to, now)
    }
    fn finish(&mut self, node: &mut Node, now: SimTime) {
        self.app.finish(node, now)
    }
    fn clock_set(&mut self, node: &mut Node, now: SimTime) {
        self.app.clock_set(node, now)
    }
    fn params(&mut self) -> Option<&mut dyn crate::params::Table> {
        self.app.params()
    }
    fn self_test(&mut self, node: &Node, now: SimTime) -> Vec<crate::params::Check> {
        self.app.self_test(node, now)
    }
    fn console_commands(&self) -> &'static [crate::console::Command] {
        self.app.console_commands()
    }
    fn console(
        &mut self,
        node: &mut Node,
        words: &[&str],
        now: SimTime,
    ) -> Result<String, crate::console::ConsoleError> {
        self.app.console(node, words, now)
    }
}

/// An application whose events are pulled after every call and kept in a shared list, for
/// tests and tools that drive a [`Host`] by hand: [`Tap::new`] gives the list, and the tap
/// derefs to the application.
#[derive(Debug)]
pub struct Tap<A: App> {
    app: A,
    events: std::sync::Arc<std::sync::Mutex<Vec<A::Event>>>,
}

/// The list a [`Tap`] fills.
pub type Tapped<E> = std::sync::Arc<std::sync::Mutex<Vec<E>>>;

impl<A: App> Tap<A> {
    /// Tap `app`; its events go to the list returned with it.
    pub fn new(app: A) -> (Self, Tapped<A::Event>) {
        let events: Tapped<A::Event> = Default::default();
        (
            Tap {
                app,
                events: events.clone(),
            },
            events,
        )
    }
    fn pull(&mut self) {
        let mut v = self
            .events
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        while let Some(e) = self.app.poll_event() {
            v.push(e);
        }
    }
}

impl<A: App> std::ops::Deref for Tap<A> {
    type Target = A;
    fn deref(&self) -> &A {
        &self.app
    }
}

impl<A: App> App for Tap<A> {
    type Event = std::convert::Infallible;
    fn start(&mut self, node: &mut Node, now: SimTime) {
        self.app.start(node, now);
        self.pull();
    }
    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        self.app.handle_packet(node, packet, now);
        self.pull();
    }
    fn poll_timeout(&self) -> Option<SimTime> {
        self.app.poll_timeout()
    }
    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        self.app.handle_timeout(node, now);
        self.pull();
    }
    fn reset(&mut self, now: SimTime) {
        self.app.reset(now);
        self.pull();
    }
    fn power_lost(&mut self, node: &mut Node, now: SimTime) {
        self.app.power_lost(node, now);
        self.pull();
    }
    fn switch(&mut self, node: &mut Node, switch: HwSwitch, to: SwitchPosition, now: SimTime) {
        self.app.switch(node, switch, to, now);
        self.pull();
    }
    fn finish(&mut self, node: &mut Node, now: SimTime) {
        self.app.finish(node, now);
        self.pull();
    }
    fn clock_set(&mut self, node: &mut Node, now: SimTime) {
        self.app.clock_set(node, now);
        self.pull();
    }
    fn params(&mut self) -> Option<&mut dyn crate::params::Table> {
        self.app.params()
    }
    fn self_test(&mut self, node: &Node, now: SimTime) -> Vec<crate::params::Check> {
        self.app.self_test(node, now)
    }
    fn console_commands(&self) -> &'static [crate::console::Command] {
        self.app.console_commands()
    }
    fn console(
        &mut self,
        node: &mut Node,
        words: &[&str],
        now: SimTime,
    ) -> Result<String, crate::console::ConsoleError> {
        let r = self.app.console(node, words, now);
        self.pull();
        r
    }
}

/// ICD 4.1 on a node's own port: when `packet` comes from a payload (12-15) that the node's
/// payload access refuses ([`NodeConfig::payload_access`]) and its command is
/// not in `open` (what payloads may use there), the failure reply, with a warning in the
/// node's log; `None` to serve it.
pub fn payload_refusal(
    node: &mut Node,
    packet: &Packet,
    open: &[u8],
    now: SimTime,
) -> Option<Vec<u8>> {
    let command = packet.data.first().copied();
    let is_open = command.is_some_and(|c| open.contains(&c));
    if !node
        .config()
        .payload_access
        .refuses(packet.header.src, is_open)
    {
        return None;
    }
    let name = node.name().to_ascii_lowercase();
    node.warn(
        now,
        format!(
            "{name}: payload {} refused port {} command {}: not available to payloads (ICD 4.1)",
            packet.header.src,
            packet.header.dport,
            command.map_or("(none)".to_owned(), |c| c.to_string())
        ),
    );
    Some(crate::reqrep::failure(command.unwrap_or(0)))
}

// A node's state over the node built from its configuration (which the run never
// changes: not saved). The queues a quiescent node has emptied are saved all the same.
snap::fields!(Node {
    frag,
    reasm,
    tx,
    rx,
    events,
    bound,
    next_port,
    boot,
    clock_offset_ns,
    clock_sets,
    reboot_requested,
    counters,
    recent,
    frames,
    faults,
    clock_errors,
    loopback,
    looping;
    skip cfg
});

/// An application's outbox: empty between inputs (the node's task drains it after each),
/// so a snapshot keeps how many it held, which must be none, and how many it dropped; its
/// capacity is the built one's. A snapshot that says it held some is refused on load.
impl<E> snap::Snap for Outbox<E> {
    fn save(&self, w: &mut snap::Writer) {
        let Outbox {
            queue,
            capacity: _,
            dropped,
        } = self;
        queue.len().save(w);
        dropped.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        let Outbox {
            queue,
            capacity: _,
            dropped,
        } = self;
        if <usize as snap::SnapNew>::read(r)? != 0 {
            return Err(snap::SnapError::NotQuiescent("an application's outbox"));
        }
        queue.clear();
        dropped.load(r)
    }
}

/// A tap saves its application (what it tapped is the test's).
impl<A: App + snap::Snap> snap::Snap for Tap<A> {
    fn save(&self, w: &mut snap::Writer) {
        self.app.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.app.load(r)
    }
}

/// An application whose events are mapped saves the application (the map is wiring).
impl<A: snap::Snap, F> snap::Snap for MapEvents<A, F> {
    fn save(&self, w: &mut snap::Writer) {
        self.app.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.app.load(r)
    }
}

/// A host: its node, its application (whose state is its own to save) and its parameter
/// memory.
impl<A: snap::Snap> snap::Snap for Host<A> {
    fn save(&self, w: &mut snap::Writer) {
        let Host { node, app, nv } = self;
        node.save(w);
        app.save(w);
        nv.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        let Host { node, app, nv } = self;
        node.load(r)?;
        app.load(r)?;
        nv.load(r)
    }
}

impl snap::Snap for ClockErrors {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.0.load(r)
    }
}

impl snap::SnapNew for ClockErrors {
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        Ok(ClockErrors(snap::SnapNew::read(r)?))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::header::flags;
    use crate::{Header, cfp};

    /// A PC-like node: CAN iface 0 (main, default route), CAN iface 1 (payloads 12-15).
    fn router_node() -> Node {
        let mut cfg = NodeConfig::new("PC", 6);
        cfg.ifaces = vec![IfaceConfig::can("main"), IfaceConfig::can("payload")];
        cfg.routes
            .set_default(Route::direct(0))
            .set_range(12..=15, Route::direct(1));
        Node::new(cfg, SimTime::ZERO)
    }

    fn frames_of(p: &Packet, mac: u8) -> Vec<CanFrame> {
        let mut out = Vec::new();
        cfp::fragment_with_ident(p, mac, 5, &mut out).unwrap();
        out
    }

    fn drain(n: &mut Node) -> Vec<Transmit> {
        std::iter::from_fn(|| n.poll_transmit()).collect()
    }

    fn reassemble(tx: &[Transmit]) -> Vec<(IfaceId, Packet)> {
        let mut r = Reassembler::default();
        tx.iter()
            .filter_map(|t| match t {
                Transmit::Can { iface, frame } => {
                    r.handle(frame, SimTime::ZERO).map(|p| (*iface, p.unwrap()))
                }
                Transmit::Packet { iface, packet } => Some((*iface, packet.clone())),
            })
            .collect()
    }

    #[test]
    fn forwards_between_interfaces_without_touching_the_crc() {
        let mut n = router_node();
        let mut h = Header::new(3, 12, 10, 40);
        h.flags = flags::CRC32;
        // A deliberately wrong CRC: a router must not check or fix it.
        let p = Packet::new(h, vec![1, 2, 3, 0xde, 0xad, 0xbe, 0xef]);
        for f in frames_of(&p, 6) {
            n.handle_frame(0, &f, SimTime::ZERO);
        }
        let out = reassemble(&drain(&mut n));
        assert_eq!(out, vec![(1, p)]);
        assert_eq!(n.counters().forwarded, 1);
    }

    /// A node saved with a packet half reassembled, a forwarded one sent and a clock
    /// fault, loaded into a node fresh from the same configuration, saves the same bytes
    /// and goes on as the original: the same frames out, packets in, events and counters.
    #[test]
    fn a_node_saved_and_loaded_into_a_fresh_one_goes_on_the_same() {
        let ms = SimTime::from_ms;
        let mut a = router_node();
        let p = Packet::new(Header::new(12, 6, 10, 40), vec![7; 40]);
        let f = frames_of(&p, 6);
        a.handle_frame(1, &f[0], ms(1));
        a.handle_frame(1, &f[1], ms(2));
        let fwd = Packet::new(Header::new(3, 12, 10, 40), vec![1, 2, 3]);
        for x in frames_of(&fwd, 6) {
            a.handle_frame(0, &x, ms(3));
        }
        let fault = NodeFault::Clock {
            jump_ns: 5_000,
            drift_ppm: 2.5,
        };
        a.set_fault(1, Some(fault), ms(3));
        let bytes = snap::to_bytes(&a);
        let mut b = router_node();
        snap::load_from(&mut b, &bytes).unwrap();
        assert_eq!(
            snap::to_bytes(&b),
            bytes,
            "the loaded node saves the same bytes"
        );
        for n in [&mut a, &mut b] {
            for x in &f[2..] {
                n.handle_frame(1, x, ms(5));
            }
            n.handle_frame(1, &f[0], ms(6));
            n.handle_timeout(SimTime::from_secs(30));
        }
        assert_eq!(drain(&mut a), drain(&mut b));
        let delivered = |n: &mut Node| std::iter::from_fn(|| n.poll_delivery()).collect::<Vec<_>>();
        assert_eq!(delivered(&mut a), delivered(&mut b));
        let events = |n: &mut Node| std::iter::from_fn(|| n.poll_event()).collect::<Vec<_>>();
        assert_eq!(events(&mut a), events(&mut b));
        assert_eq!(a.counters(), b.counters());
        assert_eq!(snap::to_bytes(&a), snap::to_bytes(&b));
    }

    /// An outbox saves what it dropped; one that holds outputs (not between inputs) saves
    /// a snapshot that is refused on load.
    #[test]
    fn an_outbox_saves_its_drops_and_refuses_to_load_outputs_it_held() {
        let mut o: Outbox<u8> = Outbox::new(1);
        o.push(1);
        o.push(2);
        assert_eq!(o.pop(), Some(2));
        let mut fresh: Outbox<u8> = Outbox::new(1);
        snap::load_from(&mut fresh, &snap::to_bytes(&o)).unwrap();
        assert_eq!(fresh.dropped(), 1);
        o.push(3);
        assert_eq!(
            snap::load_from(&mut fresh, &snap::to_bytes(&o)),
            Err(snap::SnapError::NotQuiescent("an application's outbox"))
        );
    }

    /// A reboot with a packet half reassembled reports it, with its CFP key, so that a
    /// ledger can place its bytes; the frames after the reboot find no BEGIN.
    #[test]
    fn a_reboot_reports_the_packets_it_caught_half_reassembled() {
        let mut n = router_node();
        let p = Packet::new(Header::new(12, 6, 10, 40), vec![7; 40]);
        let f = frames_of(&p, 6);
        n.handle_frame(1, &f[0], SimTime::ZERO);
        n.reboot(SimTime::from_ms(3));
        let dropped: Vec<_> = std::iter::from_fn(|| n.poll_event())
            .filter_map(|e| match e {
                NodeEvent::Drop { t, packet, .. } => Some((t, packet)),
                _ => None,
            })
            .collect();
        let key = f[0].id & cfp::CFP_ID_CONN_MASK;
        assert_eq!(
            dropped,
            [(
                SimTime::from_ms(3),
                Some(DroppedPacket {
                    header: p.header,
                    data_len: 40,
                    cfp: Some((key, CfpDrop::Reset)),
                })
            )]
        );
        n.handle_frame(1, &f[1], SimTime::from_ms(4));
        assert!(n.poll_delivery().is_none());
    }

    #[test]
    fn never_sends_back_out_of_the_incoming_interface() {
        let mut n = router_node();
        let p = Packet::new(Header::new(3, 4, 1, 40), vec![1]);
        for f in frames_of(&p, 6) {
            n.handle_frame(0, &f, SimTime::ZERO);
        }
        assert!(drain(&mut n).is_empty());
        assert_eq!(n.counters().drops.get(&DropReason::SameIface), Some(&1));
    }

    #[test]
    fn broadcast_is_answered_from_the_real_address_and_not_forwarded() {
        let mut n = router_node();
        n.handle_packet(
            0,
            Packet::new(Header::new(3, 31, 1, 45), vec![6]),
            SimTime::ZERO,
        );
        let out = reassemble(&drain(&mut n));
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].1.header, Header::new(6, 3, 45, 1));
        assert_eq!(n.counters().forwarded, 0);
    }

    #[test]
    fn crc_mismatch_on_local_delivery_is_a_counted_drop() {
        let mut n = router_node();
        let mut h = Header::new(3, 6, 1, 40);
        h.flags = flags::CRC32;
        n.handle_packet(0, Packet::new(h, vec![9, 0, 0, 0, 0]), SimTime::ZERO);
        assert!(drain(&mut n).is_empty());
        assert_eq!(n.counters().drops.get(&DropReason::Crc32), Some(&1));
    }

    #[test]
    fn xtea_hmac_and_rdp_packets_are_discarded_at_their_destination_in_libcsps_order() {
        let ping = |flags_: u8, data: Vec<u8>, dport: u8| {
            let mut h = Header::new(3, 6, dport, 40);
            h.flags = flags_;
            Packet::new(h, data)
        };
        let with_crc = |d: &[u8]| {
            let mut v = d.to_vec();
            crc32::append(&mut v);
            v
        };
        let bad_crc = vec![9, 0, 0, 0, 0];
        let cases: [(u8, Vec<u8>, u8, DropReason); 8] = [
            (flags::XTEA, vec![1, 2], 1, DropReason::Xtea),
            (flags::HMAC, vec![1, 2], 1, DropReason::Hmac),
            (flags::RDP, vec![1, 2], 1, DropReason::Rdp),
            // XTEA is checked before the CRC, the CRC before HMAC, HMAC before RDP.
            (
                flags::XTEA | flags::CRC32,
                bad_crc.clone(),
                1,
                DropReason::Xtea,
            ),
            (
                flags::HMAC | flags::CRC32,
                bad_crc.clone(),
                1,
                DropReason::Crc32,
            ),
            (flags::HMAC | flags::RDP, vec![1], 1, DropReason::Hmac),
            (
                flags::RDP | flags::CRC32,
                with_crc(&[1, 2]),
                20,
                DropReason::Rdp,
            ),
            // No socket: dropped before any check, as libcsp does.
            (flags::XTEA, vec![1], 21, DropReason::UnboundPort),
        ];
        for (f, data, dport, reason) in cases {
            let mut n = router_node();
            n.bind(20);
            n.handle_packet(0, ping(f, data, dport), SimTime::ZERO);
            assert!(drain(&mut n).is_empty(), "flags {f:#04x}: no reply");
            assert!(n.poll_delivery().is_none(), "flags {f:#04x}: not delivered");
            assert_eq!(n.counters().drops.get(&reason), Some(&1), "flags {f:#04x}");
            assert_eq!(n.counters().total_drops(), 1, "flags {f:#04x}");
        }
        // The plain ping and the FRAG bit (unused in 1.4, never checked) are answered.
        for f in [0, flags::FRAG] {
            let mut n = router_node();
            n.handle_packet(0, ping(f, vec![1, 2], 1), SimTime::ZERO);
            assert_eq!(reassemble(&drain(&mut n)).len(), 1, "flags {f:#04x}");
        }
        // A router forwards flagged packets untouched: only the destination checks.
        let mut n = router_node();
        let mut h = Header::new(3, 12, 1, 40);
        h.flags = flags::XTEA | flags::HMAC | flags::RDP;
        let p = Packet::new(h, vec![7; 9]);
        for fr in frames_of(&p, 6) {
            n.handle_frame(0, &fr, SimTime::ZERO);
        }
        assert_eq!(reassemble(&drain(&mut n)), vec![(1, p)]);
        assert_eq!(n.counters().total_drops(), 0);
    }

    #[test]
    fn a_self_addressed_service_packet_ping_pongs_through_the_queue_not_the_stack() {
        // Source and destination the node's own address, service port to service port: each
        // answer is a new request to itself. Found by fuzzing: served by recursion (send ->
        // route_in -> deliver_local -> serve -> send) it would overflow the stack.
        for port in 0..=6u8 {
            let mut n = router_node();
            let mut h = Header::new(6, 6, port, port);
            h.flags = 0;
            n.handle_packet(0, Packet::new(h, vec![0x5a; 8]), SimTime::ZERO);
            let c = n.counters();
            // Answered (ports 1, 2, 3, 5, 6 reply) a bounded number of times, the rest dropped.
            assert!(
                c.service_replies <= LOOPBACK_PER_INPUT as u64 + 1,
                "port {port}: {c:?}"
            );
            if matches!(port, 1 | 2 | 3 | 5 | 6) {
                let dropped = c
                    .drops
                    .get(&DropReason::LoopbackBudget)
                    .copied()
                    .unwrap_or(0)
                    + c.drops.get(&DropReason::LoopbackFull).copied().unwrap_or(0);
                assert!(dropped >= 1, "port {port}: {c:?}");
            }
            // Nothing went out on a bus, and the node still answers others.
            assert!(drain(&mut n).is_empty(), "port {port}");
            n.handle_packet(
                0,
                Packet::new(Header::new(3, 6, 1, 40), vec![1]),
                SimTime::ZERO,
            );
            let out = reassemble(&drain(&mut n));
            assert!(
                out.iter()
                    .any(|(_, p)| p.header.dst == 3 && p.data == vec![1]),
                "port {port}: {out:?}"
            );
        }
    }

    #[test]
    fn unbound_ports_drop_and_bound_ports_deliver() {
        let mut n = router_node();
        n.handle_packet(
            0,
            Packet::new(Header::new(3, 6, 20, 40), vec![1]),
            SimTime::ZERO,
        );
        assert_eq!(n.counters().drops.get(&DropReason::UnboundPort), Some(&1));
        n.bind(20);
        n.handle_packet(
            0,
            Packet::new(Header::new(3, 6, 20, 40), vec![1]),
            SimTime::ZERO,
        );
        assert_eq!(n.poll_delivery().map(|p| p.data), Some(vec![1]));
    }

    #[test]
    fn sending_checks_route_and_mtu() {
        let mut cfg = NodeConfig::new("X", 9);
        cfg.ifaces = vec![IfaceConfig::can("main")];
        cfg.routes.set(3, Route::direct(0));
        let mut n = Node::new(cfg, SimTime::ZERO);
        let to = |dst| Packet::new(Header::new(9, dst, 1, 40), vec![0; 10]);
        assert_eq!(n.send(to(4), SimTime::ZERO), Err(SendError::NoRoute(4)));
        assert!(n.send(to(3), SimTime::ZERO).is_ok());
        let big = Packet::new(Header::new(9, 3, 1, 40), vec![0; 257]);
        assert_eq!(
            n.send(big, SimTime::ZERO),
            Err(SendError::TooLong { len: 257, mtu: 256 })
        );
        let bad = Packet::new(Header::new(40, 3, 1, 40), vec![]);
        assert_eq!(n.send(bad, SimTime::ZERO), Err(SendError::BadHeader));
    }

    /// An outbox holds its capacity of outputs; past it the oldest go first, counted. At
    /// the default capacity (2^20), filled twice over: the newest 2^20 kept, 2^20 dropped.
    #[test]
    fn an_outbox_keeps_its_newest_outputs_and_counts_the_oldest_dropped() {
        let mut small = Outbox::new(3);
        for k in 0..5 {
            small.push(k);
        }
        assert_eq!(small.dropped(), 2);
        assert_eq!(
            (small.pop(), small.pop(), small.pop(), small.pop()),
            (Some(2), Some(3), Some(4), None)
        );
        let mut full = Outbox::<u32>::default();
        let n = Outbox::<u32>::DEFAULT_CAPACITY as u32;
        for k in 0..2 * n {
            full.push(k);
        }
        assert_eq!(full.dropped(), u64::from(n));
        assert_eq!(full.pop(), Some(n));
    }

    #[test]
    fn ephemeral_ports_cycle_through_32_to_63_and_run_out() {
        let mut n = router_node();
        // 63 is the node's own port (the one before the first tried, 32): never handed out.
        assert_eq!(n.own_port(), 63);
        let ports: Vec<u8> = (0..31).map(|_| n.alloc_port().unwrap()).collect();
        let mut sorted = ports.clone();
        sorted.sort();
        assert_eq!(sorted, (32..=62).collect::<Vec<_>>());
        assert_eq!(n.alloc_port(), None);
        n.unbind(40);
        assert_eq!(n.alloc_port(), Some(40));
    }

    /// ICD 4.1 gives payloads the service handler's ping and uptime: a platform node (the
    /// PC here, on both buses) drops a payload's reboot, CMP clock set, ident, ps, memfree
    /// and buf_free unanswered, counted by service; a ground station's are served, and
    /// `payload_access = open` (a lab bench) serves a payload's too. A payload could reboot
    /// the FC or the PC and move the PC's clock.
    #[test]
    fn a_payload_gets_ping_and_uptime_of_a_platform_nodes_service_handler_only() {
        use platform::addr::PayloadAccess;
        let to_pc = |src: u8, dport: u8, data: &[u8]| {
            Packet::new(Header::new(src, 6, dport, 40), data.to_vec())
        };
        let reboot = service::REBOOT_MAGIC.to_be_bytes();
        let clock_set = [0, 6, 0x70, 0, 0, 0, 0, 0, 0, 0];
        let mut pc = router_node();
        let t = SimTime::from_secs(100);
        for (dport, data) in [
            (4, &reboot[..]),
            (0, &clock_set[..]),
            (0, &[0, 1][..]),
            (2, &[][..]),
            (3, &[][..]),
            (5, &[][..]),
        ] {
            pc.handle_packet(1, to_pc(15, dport, data), t);
        }
        assert!(drain(&mut pc).is_empty(), "nothing answered");
        assert!(!pc.reboot_requested());
        assert_eq!(pc.clock_sets(), 0);
        let drops = &pc.counters().drops;
        for (reason, n) in [
            (DropReason::PayloadReboot, 1),
            (DropReason::PayloadCmp, 2),
            (DropReason::PayloadPs, 1),
            (DropReason::PayloadMemfree, 1),
            (DropReason::PayloadBufFree, 1),
        ] {
            assert_eq!(drops.get(&reason), Some(&n), "{reason}: {drops:?}");
        }
        // Ping and uptime answer the payload.
        pc.handle_packet(1, to_pc(15, 1, &[9, 9]), t);
        pc.handle_packet(1, to_pc(15, 6, &[]), t);
        assert!(!drain(&mut pc).is_empty());
        assert_eq!(pc.counters().service_replies, 2);
        // The ground is served; so is a payload on a lab bench.
        pc.handle_packet(0, to_pc(16, 0, &clock_set), t);
        assert_eq!(pc.clock_sets(), 1);
        pc.handle_packet(0, to_pc(16, 4, &reboot), t);
        assert!(pc.reboot_requested());
        let mut open = router_node();
        open.cfg.payload_access = PayloadAccess::Open;
        open.handle_packet(1, to_pc(15, 4, &reboot), t);
        assert!(open.reboot_requested());
    }

    /// What a node sends on its own leaves from its own port, which the allocator never
    /// hands out, before or after a reboot; what arrives there is dropped and counted,
    /// never served (a service port's request, a bound port's packet).
    #[test]
    fn a_packet_to_the_own_port_is_dropped_and_the_port_is_never_allocated() {
        let mut cfg = NodeConfig::new("PC", 6);
        cfg.ifaces = vec![IfaceConfig::packet("p")];
        cfg.routes.set_default(Route::direct(0));
        cfg.first_ephemeral_port = 50;
        let mut n = Node::new(cfg, SimTime::ZERO);
        assert_eq!(n.own_port(), 49);
        assert_eq!(n.own_header(16, 10), Header::new(6, 16, 10, 49));
        for round in 0..2 {
            let ports: Vec<u8> = (0..31).map(|_| n.alloc_port().unwrap()).collect();
            assert_eq!(ports.first(), Some(&50));
            assert!(!ports.contains(&49), "{ports:?}");
            assert_eq!(n.alloc_port(), None);
            if round == 0 {
                n.reboot(SimTime::from_secs(1));
            }
        }
        n.handle_packet(
            0,
            Packet::new(Header::new(16, 6, 49, 10), vec![1, 1]),
            SimTime::from_secs(2),
        );
        assert!(n.poll_transmit().is_none());
        assert_eq!(n.poll_delivery(), None);
        assert_eq!(n.counters().drops.get(&DropReason::OwnPort), Some(&1));
    }

    #[test]
    fn reboot_magic_resets_uptime_and_bindings() {
        let mut host = Host::new(
            {
                let mut c = NodeConfig::new("FC", 3);
                c.ifaces = vec![IfaceConfig::packet("p")];
                c.routes.set_default(Route::direct(0));
                c
            },
            StubApp::new(&[10]),
            SimTime::ZERO,
        );
        let t = SimTime::from_secs(100);
        let magic = 0x8007_8007u32.to_be_bytes().to_vec();
        host.handle_packet(0, Packet::new(Header::new(16, 3, 4, 40), magic), t);
        assert!(host.node.poll_transmit().is_none(), "reboot sends no reply");
        assert_eq!(host.node.counters().reboots, 1);
        assert_eq!(host.node.uptime(SimTime::from_secs(105)).as_secs(), 5);
        assert!(host.node.is_bound(10), "the app bound its ports again");
    }

    #[test]
    fn stub_ports_answer_failure_for_anything() {
        let mut host = Host::new(
            {
                let mut c = NodeConfig::new("EPS", 4);
                c.ifaces = vec![IfaceConfig::packet("p")];
                c.routes.set_default(Route::direct(0));
                c
            },
            StubApp::new(&[10]),
            SimTime::ZERO,
        );
        for (req, want) in [(vec![5u8, 1, 2], vec![5u8, 0]), (vec![], vec![0, 0])] {
            host.handle_packet(
                0,
                Packet::new(Header::new(16, 4, 10, 40), req),
                SimTime::ZERO,
            );
            let Some(Transmit::Packet { packet, .. }) = host.node.poll_transmit() else {
                panic!("no reply")
            };
            assert_eq!(packet.data, want);
            assert_eq!(packet.header, Header::new(4, 16, 40, 10));
        }
    }

    #[test]
    fn a_clock_error_jumps_and_drifts_and_errors_add_up() {
        let mut n = router_node();
        let t0 = SimTime::from_secs(100);
        let base = n.clock_unix_ns(t0);
        n.set_clock_error(
            1,
            Some(ClockError {
                jump_ns: 5_000_000_000,
                drift_ppm: 0.0,
                since: t0,
            }),
        );
        n.set_clock_error(
            2,
            Some(ClockError {
                jump_ns: 0,
                drift_ppm: 100.0,
                since: t0,
            }),
        );
        // 1000 s later: +5 s jump, +100 ppm x 1000 s = +0.1 s.
        let t1 = SimTime::from_secs(1100);
        assert_eq!(
            n.clock_unix_ns(t1) - base,
            1_000_000_000_000 + 5_000_000_000 + 100_000_000
        );
        n.set_clock_error(1, None);
        assert_eq!(n.clock_unix_ns(t1) - base, 1_000_000_000_000 + 100_000_000);
        // A reboot keeps the oscillator's error.
        n.reboot(t1);
        assert_eq!(n.clock_errors().error_ns(t1), 100_000_000);
    }

    /// CMP CLOCK with nanoseconds of a second or more: the clock is not moved (it was moved
    /// by up to 4.3 s before) and the answer is the time the node keeps; a valid set moves
    /// it and is answered with the time set.
    #[test]
    fn a_cmp_clock_set_with_tv_nsec_of_a_second_or_more_leaves_the_clock() {
        let mut cfg = NodeConfig::new("X", 4);
        cfg.ifaces = vec![IfaceConfig::packet("p")];
        cfg.routes.set_default(Route::direct(0));
        cfg.epoch_unix_s = 1_000;
        let mut host = Host::new(cfg, NoApp, SimTime::ZERO);
        let t = SimTime::from_secs(5);
        let ask = |host: &mut Host<NoApp>, sec: u32, nsec: u32| {
            let mut d = vec![0, 6];
            d.extend(sec.to_be_bytes());
            d.extend(nsec.to_be_bytes());
            host.handle_packet(0, Packet::new(Header::new(16, 4, 0, 40), d), t);
            let Some(Transmit::Packet { packet, .. }) = host.node.poll_transmit() else {
                panic!("no reply")
            };
            packet.data
        };
        let reply = ask(&mut host, 2_000, 0xFFFF_FFFF);
        assert_eq!(host.node.clock_unix_ns(t), 1_005_000_000_000);
        assert_eq!(host.node.clock_sets(), 0);
        assert_eq!(reply[2..], [0, 0, 0x03, 0xED, 0, 0, 0, 0]);
        let reply = ask(&mut host, 2_000, 999_999_999);
        assert_eq!(host.node.clock_unix_ns(t), 2_000_999_999_999);
        assert_eq!(reply[2..6], 2_000u32.to_be_bytes());
    }
}
