//! A packet network: endpoints exchange whole CSP packets, addressed by the CSP
//! destination. The ground segment is one (ground stations 16-20, outside ground programs,
//! and the satellite's UHF radio as the default endpoint).
//!
//! Model:
//! - each endpoint owns a set of addresses; a packet goes to the endpoint owning its
//!   destination, else to the default endpoint (the radio), never back to its sender.
//!   An outside program's exclusive claim on an address takes it from an internal endpoint
//!   while the claim lasts ([`PacketNet::claim`]);
//! - endpoints marked `radio` share one half-duplex air channel: a packet to or from a
//!   radio endpoint occupies the channel for `(len + overhead) * 8 / rate` and arrives
//!   `air_delay` after it leaves; traffic between ground endpoints is instantaneous;
//! - the air serves the ground endpoints in turn: each has one queue for what it sends up
//!   and what the radio sends down to it, and when the air frees, the next endpoint (in the
//!   order they joined the network, after the last one served) with a packet waiting sends
//!   one. So a ground client flooding the air delays another by at most one packet each
//!   way; with one station (or one at a time) the air is first come, first served, as it
//!   always was. The next transmission is chosen [`DECIDE_AHEAD`] before the air frees, so
//!   that its air time is charged ahead of its start (the [`AirTap`]);
//! - impairments (drop, corrupt, delay, down) apply to the air channel, drawn from the
//!   net's seeded generator;
//! - the default endpoint can move to another radio ([`PacketNet::set_default`]: the
//!   secondary COMM taking the link over), and an [`AirTap`] hears every transmission by a
//!   radio endpoint (its air time, for the power budget).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use csp::{Packet, SimTime};
use snap::{Snap, SnapError};
use tokio::sync::Notify;

use crate::clock::Clock;
use crate::exec::Start;
use crate::impair::{Fate, ImpairRng, ImpairmentSet, Impairments};
use crate::inbox::{Arrival, Inbound, InboxTx};
use crate::reserve::ClaimError;
use crate::trace::{TraceEvent, TraceFrame, TraceTx};

/// Settings of a packet network.
#[derive(Debug, Clone, PartialEq)]
pub struct PacketNetConfig {
    /// Network name (`ground`).
    pub name: String,
    /// Air data rate in bit/s (UHF default 9600).
    pub air_rate_bps: u32,
    /// Framing overhead per packet on the air, bytes.
    pub air_overhead_bytes: u32,
    /// Propagation and modem delay on the air.
    pub air_delay: Duration,
    /// Bytes waiting for the air that each sender's transmit buffer holds (a radio's or a
    /// ground modem's); a packet that does not fit is lost (`air_overflow`).
    pub air_buffer_bytes: u32,
}

/// The default transmit buffer of a sender on the air: 4 KiB, about 3.4 s of a 9600 bit/s
/// channel. A ground sender has one; the radio one per ground endpoint it sends to.
pub const AIR_BUFFER_BYTES: u32 = 4096;

/// How long before the air frees the next transmission is chosen: more than a tick of
/// tokio's timer wheel (1 ms), so that the air time of a transmission reaches the [`AirTap`]
/// (and the power board behind it) before the instant it starts, whenever the network task
/// runs within its tick. A packet sent within the last 2 ms of another's transmission
/// waits for the next turn.
pub const DECIDE_AHEAD: Duration = Duration::from_millis(2);

impl PacketNetConfig {
    /// The ground segment with a 9600 bit/s UHF channel.
    pub fn ground() -> Self {
        PacketNetConfig {
            name: "ground".to_owned(),
            air_rate_bps: 9600,
            air_overhead_bytes: 0,
            air_delay: Duration::from_millis(3),
            air_buffer_bytes: AIR_BUFFER_BYTES,
        }
    }
}

/// Called with `(radio endpoint name, start, end)` of every transmission by a radio
/// endpoint, when it is chosen (at or up to [`DECIDE_AHEAD`] before its start; they come in
/// time order, the air channel being one).
#[derive(Clone)]
pub struct AirTap(Arc<AirFn>);

/// The function behind an [`AirTap`].
type AirFn = dyn Fn(EndpointId, &str, SimTime, SimTime) + Send + Sync;

impl AirTap {
    /// A tap calling `f(radio, radio's name, start, end)`.
    pub fn new(f: impl Fn(EndpointId, &str, SimTime, SimTime) + Send + Sync + 'static) -> Self {
        AirTap(Arc::new(f))
    }
}

/// An endpoint of a packet network, as [`NetPort::id`] names it (an [`AirTap`] hears a
/// transmission by it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct EndpointId(usize);

impl std::fmt::Debug for AirTap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("AirTap")
    }
}

/// Counters of a packet network.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NetStats {
    /// Network name.
    pub name: String,
    /// Packets delivered or dropped.
    pub packets: u64,
    /// Bytes of those packets.
    pub bytes: u64,
    /// Time the air channel was busy.
    pub air_busy: Duration,
    /// Packets lost to impairments.
    pub dropped: u64,
    /// Packets with no endpoint to go to.
    pub unroutable: u64,
    /// Packets sent over the air while the satellite and the ground were out of contact
    /// (lost; also counted in `dropped`).
    pub no_contact: u64,
    /// Per-endpoint (name, packets sent, packets received).
    pub endpoints: Vec<(String, u64, u64)>,
    /// Packets lost because their sender's transmit buffer was full (the air was busy).
    pub air_overflow: u64,
    /// Packets lost because the receiver's inbox was full.
    pub rx_overflow: u64,
    /// The most bytes any sender had waiting for the air (the radio: for one ground
    /// endpoint).
    pub air_backlog_max: u64,
}

#[derive(Debug)]
struct Endpoint {
    name: String,
    addrs: BTreeSet<u8>,
    /// The addresses given at attach (a node of the twin).
    own: BTreeSet<u8>,
    radio: bool,
    enabled: bool,
    inbox: InboxTx,
    iface: usize,
    tx: u64,
    rx: u64,
    /// The outside link it belongs to (its reserved addresses are its own).
    link: Option<crate::reserve::LinkId>,
    /// Released (its outside connection went away): the next connection of its link takes
    /// its place, so that connections coming and going leave nothing behind.
    departed: bool,
    /// How many connections have had this place: a packet on its way to an earlier one is
    /// not delivered to a later one.
    generation: u32,
}

#[derive(Debug)]
struct State {
    cfg: PacketNetConfig,
    name: Arc<str>,
    eps: snap::Fixed<Endpoint>,
    default_ep: Option<usize>,
    claims: BTreeMap<u8, usize>,
    reserved: crate::reserve::Reservations,
    air_busy_until: SimTime,
    /// What waits for the air, by ground endpoint: its own packets up and the radio's down
    /// to it, in the order sent.
    air_waiting: BTreeMap<usize, std::collections::VecDeque<AirPacket>>,
    /// The ground endpoint the air served last (the next turn goes to the one after it).
    air_last: Option<usize>,
    /// Each sender's transmit buffer, by (sender, ground endpoint): a ground sender has one
    /// (its own), the radio one per ground endpoint it sends to.
    air_buffers: BTreeMap<(usize, usize), AirBuffer>,
    /// On their way, by arrival time and order.
    in_flight: BTreeMap<(SimTime, u64), InFlight>,
    seq: u64,
    stats: NetStats,
    impair: Impairments,
    faults: ImpairmentSet,
    rng: ImpairRng,
    trace: Option<TraceTx>,
    air_tap: Option<AirTap>,
    /// Whether the radio link can close (a pass over a ground station); see
    /// [`PacketNet::set_contact`].
    contact: bool,
    /// The instant the network task waits for.
    waiting_until: SimTime,
}

/// A packet network; clones share it.
#[derive(Debug, Clone)]
pub struct PacketNet {
    state: Arc<Mutex<State>>,
    wake: Arc<Notify>,
}

/// An endpoint's handle for sending on the network.
#[derive(Debug, Clone)]
pub struct NetPort {
    net: PacketNet,
    idx: usize,
}

impl NetPort {
    /// Which endpoint of its network this is.
    pub fn id(&self) -> EndpointId {
        EndpointId(self.idx)
    }
    /// Send `packet`, ready at `t`.
    pub fn send(&self, t: SimTime, packet: Packet) {
        self.net.lock().submit(self.idx, t, packet);
        self.net.wake.notify_one();
    }
    /// The network.
    pub fn net(&self) -> &PacketNet {
        &self.net
    }
}

impl PacketNet {
    /// A network; `seed` drives its impairments.
    pub fn new(cfg: PacketNetConfig, seed: u64) -> Self {
        let name: Arc<str> = cfg.name.as_str().into();
        PacketNet {
            state: Arc::new(Mutex::new(State {
                rng: ImpairRng::new(seed, &cfg.name),
                stats: NetStats {
                    name: cfg.name.clone(),
                    ..Default::default()
                },
                cfg,
                name,
                eps: snap::Fixed::default(),
                default_ep: None,
                claims: BTreeMap::new(),
                reserved: Default::default(),
                air_busy_until: SimTime::ZERO,
                air_waiting: BTreeMap::new(),
                air_last: None,
                air_buffers: BTreeMap::new(),
                in_flight: BTreeMap::new(),
                seq: 0,
                impair: Impairments::default(),
                faults: ImpairmentSet::default(),
                trace: None,
                air_tap: None,
                contact: true,
                waiting_until: SimTime::ZERO,
            })),
            wake: Arc::new(Notify::new()),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Attach an endpoint owning `addrs`. A `radio` endpoint sits behind the air channel;
    /// `default` makes it the destination of every address nobody owns.
    pub fn attach(
        &self,
        name: &str,
        addrs: &[u8],
        radio: bool,
        default: bool,
        inbox: InboxTx,
        iface: usize,
    ) -> NetPort {
        let mut st = self.lock();
        let idx = st.push_endpoint(name, addrs, radio, inbox, iface);
        if default {
            st.default_ep = Some(idx);
        }
        NetPort {
            net: self.clone(),
            idx,
        }
    }

    /// Enable or disable an endpoint (power).
    pub fn set_enabled(&self, port: &NetPort, enabled: bool) {
        if let Some(e) = self.lock().eps.get_mut(port.idx) {
            e.enabled = enabled;
        }
    }

    /// Make `port` the default endpoint: the destination of every address nobody owns.
    pub fn set_default(&self, port: &NetPort) {
        self.lock().default_ep = Some(port.idx);
    }

    /// Attach an endpoint of outside link `link` that is the only receiver of `addr` until
    /// released, unless another endpoint holds it (a node of the twin attached with it, or
    /// another claim) or another link reserved it ([`PacketNet::reserve`]): refused with the
    /// holder's name, and then nothing is attached. Checked and attached under one lock, so
    /// that a refusal leaves nothing that outlives it.
    pub fn attach_claimed(
        &self,
        name: &str,
        link: crate::reserve::LinkId,
        addr: u8,
        inbox: InboxTx,
        iface: usize,
    ) -> Result<NetPort, ClaimError> {
        let mut st = self.lock();
        if let Some(why) = st.refusal(addr, None, Some(link)) {
            return Err(why);
        }
        // A departed connection's place of the same link, else a new one.
        let idx = match st
            .eps
            .iter()
            .position(|e| e.departed && e.link == Some(link))
        {
            Some(i) => {
                if let Some(e) = st.eps.get_mut(i) {
                    e.name = name.to_owned();
                    e.enabled = true;
                    e.departed = false;
                    e.generation = e.generation.wrapping_add(1);
                    e.inbox = inbox;
                    e.iface = iface;
                }
                i
            }
            None => st.push_endpoint(name, &[], false, inbox, iface),
        };
        if let Some(e) = st.eps.get_mut(idx) {
            e.link = Some(link);
        }
        st.claims.insert(addr, idx);
        if let Some(e) = st.eps.get_mut(idx) {
            e.addrs.insert(addr);
        }
        Ok(NetPort {
            net: self.clone(),
            idx,
        })
    }

    /// Make `port` the only receiver of `addr` until released, unless another endpoint
    /// holds it (a node of the twin attached with it, or another claim): refused with the
    /// holder's name.
    pub fn claim(&self, port: &NetPort, addr: u8) -> Result<(), ClaimError> {
        let mut st = self.lock();
        let link = st.eps.get(port.idx).and_then(|e| e.link);
        if let Some(why) = st.refusal(addr, Some(port.idx), link) {
            return Err(why);
        }
        st.claims.insert(addr, port.idx);
        if let Some(e) = st.eps.get_mut(port.idx) {
            e.addrs.insert(addr);
        }
        Ok(())
    }

    /// The node of the twin attached with `addr` (not an outside connection's claim), if
    /// one is.
    pub fn node_holding(&self, addr: u8) -> Option<String> {
        let st = self.lock();
        match st.held_by(addr, st.holder(addr)?) {
            ClaimError::Node(name) => Some(name),
            _ => None,
        }
    }

    /// Reserve `addr` for outside link `link` for the whole run: only that link's endpoints
    /// may claim it, its program connected or not. Refused with the holder's name when a
    /// node of the twin or another link has it.
    pub fn reserve(
        &self,
        addr: u8,
        link: crate::reserve::LinkId,
        label: &str,
    ) -> Result<(), ClaimError> {
        let mut st = self.lock();
        if let Some(h) = st.holder(addr) {
            return Err(st.held_by(addr, h));
        }
        st.reserved.reserve(addr, link, label)
    }

    /// Give back every address of an endpoint, claimed or attached with, and disable it:
    /// an outside link went away, or an outside program takes a node's place in a run from
    /// a snapshot (its place stays, its counts with it).
    pub fn release(&self, port: &NetPort) {
        self.lock().release(port.idx);
    }

    /// Fault `id` impairs the medium with `imp` (`Some`) or is lifted (`None`); the
    /// impairments in force are every active fault's combined
    /// ([`ImpairmentSet::combined`]).
    pub fn set_fault(&self, id: u32, imp: Option<Impairments>) {
        let mut st = self.lock();
        st.faults.set(id, imp);
        st.impair = st.faults.combined();
    }

    /// Contact between the radios on the air (a pass) or none: out of contact every packet
    /// that would cross the air is lost (counted in `no_contact`), whatever the
    /// impairments. On at creation.
    pub fn set_contact(&self, on: bool) {
        self.lock().contact = on;
    }

    /// Send every packet that crosses the network to `tx`.
    pub fn set_trace(&self, tx: TraceTx) {
        self.lock().trace = Some(tx);
    }

    /// Hand the air time of every radio endpoint's transmission to `tap`.
    pub fn set_air_tap(&self, tap: AirTap) {
        self.lock().air_tap = Some(tap);
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> NetStats {
        let st = self.lock();
        let mut s = st.stats.clone();
        s.endpoints = st
            .eps
            .iter()
            .map(|e| (e.name.clone(), e.tx, e.rx))
            .collect();
        s
    }

    /// The network task: put packets on the air in turn and deliver them when they arrive.
    pub async fn run(self, clock: Clock) {
        self.run_from(clock, Start::Fresh).await;
    }

    /// The network task of a network loaded from a snapshot: it waits first, for what it
    /// waited for when the snapshot was taken.
    pub async fn resume(self, clock: Clock) {
        self.run_from(clock, Start::Resumed).await;
    }

    async fn run_from(self, clock: Clock, start: Start) {
        let mut start = start;
        loop {
            let next = {
                let mut st = self.lock();
                if start == Start::Resumed {
                    start = Start::Fresh;
                } else {
                    let now = clock.now();
                    st.take_turns(now);
                    st.deliver_due(now);
                    let delivery = st
                        .in_flight
                        .first_key_value()
                        .map_or(SimTime::MAX, |((t, _), _)| *t);
                    st.waiting_until = delivery.min(st.next_turn().unwrap_or(SimTime::MAX));
                }
                st.waiting_until
            };
            let notified = self.wake.notified();
            tokio::select! {
                biased;
                () = notified => {}
                () = clock.sleep_until(next) => {}
            }
        }
    }
}

impl State {
    /// [`PacketNet::release`] of endpoint `idx`.
    fn release(&mut self, idx: usize) {
        self.claims.retain(|_, i| *i != idx);
        if self.default_ep == Some(idx) {
            self.default_ep = None;
        }
        if let Some(e) = self.eps.get_mut(idx) {
            e.addrs.clear();
            e.own.clear();
            e.enabled = false;
            e.departed = e.link.is_some();
        }
    }

    /// Add an endpoint; its index.
    fn push_endpoint(
        &mut self,
        name: &str,
        addrs: &[u8],
        radio: bool,
        inbox: InboxTx,
        iface: usize,
    ) -> usize {
        self.eps.push(Endpoint {
            name: name.to_owned(),
            addrs: addrs.iter().copied().collect(),
            own: addrs.iter().copied().collect(),
            radio,
            enabled: true,
            inbox,
            iface,
            tx: 0,
            rx: 0,
            link: None,
            departed: false,
            generation: 0,
        });
        self.eps.len() - 1
    }

    /// Why endpoint `me` of outside link `link` may not claim `addr`: another endpoint
    /// holds it (named), or another link reserved it.
    fn refusal(
        &self,
        addr: u8,
        me: Option<usize>,
        link: Option<crate::reserve::LinkId>,
    ) -> Option<ClaimError> {
        if let Some(h) = self.holder(addr).filter(|&h| Some(h) != me) {
            return Some(self.held_by(addr, h));
        }
        self.reserved.refusal(addr, link)
    }

    /// Why `h` keeps `addr` from a claim: a node of the twin attached with it, or another
    /// outside connection that claimed it.
    fn held_by(&self, addr: u8, h: usize) -> ClaimError {
        let name = self.eps[h].name.clone();
        if self.claims.contains_key(&addr) {
            ClaimError::Held(name)
        } else {
            ClaimError::Node(name)
        }
    }

    /// The endpoint holding `addr`: its claimant, or a node attached with it.
    fn holder(&self, addr: u8) -> Option<usize> {
        self.claims
            .get(&addr)
            .copied()
            .or_else(|| self.eps.iter().position(|e| e.own.contains(&addr)))
    }

    fn owner(&self, dst: u8) -> Option<usize> {
        if let Some(&i) = self.claims.get(&dst) {
            return Some(i);
        }
        self.eps
            .iter()
            .position(|e| e.enabled && e.addrs.contains(&dst))
            .or(self.default_ep)
    }

    fn submit(&mut self, from: usize, t: SimTime, packet: Packet) {
        if !self.eps.get(from).is_some_and(|e| e.enabled) {
            return;
        }
        // Never back to the sender, and never from one satellite radio to another (the
        // default endpoint is a radio: a radio's packet for an address nobody on the ground
        // owns has nowhere to go).
        let Some(to) = self
            .owner(packet.header.dst)
            .filter(|&to| to != from && !(self.eps[from].radio && self.eps[to].radio))
        else {
            self.stats.unroutable += 1;
            return;
        };
        self.eps[from].tx += 1;
        let len = 4 + packet.data.len() as u64;
        self.stats.packets += 1;
        self.stats.bytes += len;
        let over_air = self.eps[from].radio || self.eps[to].radio;
        let generation = self.eps[to].generation;
        if !over_air {
            self.seq += 1;
            self.in_flight.insert(
                (t, self.seq),
                InFlight {
                    from,
                    to,
                    generation,
                    packet,
                    fate: Fate::Deliver,
                },
            );
            return;
        }
        // The ground endpoint whose turn it is: the sender going up, the receiver coming
        // down.
        let ground = if self.eps[from].radio { to } else { from };
        let limit = u64::from(self.cfg.air_buffer_bytes);
        let buffer = self.air_buffers.entry((from, ground)).or_default();
        let Some(backlog) = buffer.takes(t, len, limit) else {
            let (net, sender, size) = (&self.name, &self.eps[from].name, limit);
            crate::count_loss(&mut self.stats.air_overflow, |n| {
                format!(
                    "{net}: {sender}: transmit buffer full ({size} bytes): packet {} lost ({n} so far)",
                    packet.header
                )
            });
            return;
        };
        self.stats.air_backlog_max = self.stats.air_backlog_max.max(backlog);
        self.air_waiting
            .entry(ground)
            .or_default()
            .push_back(AirPacket {
                ready: t,
                from,
                to,
                generation,
                len,
                packet,
            });
        self.take_turns(t);
    }

    /// When the air frees next and something waits for it: the instant the next turn is
    /// chosen ([`DECIDE_AHEAD`] before the air frees, or as the first packet waiting was
    /// sent, whichever is later).
    fn next_turn(&self) -> Option<SimTime> {
        let ready = self
            .air_waiting
            .values()
            .filter_map(|q| q.front())
            .map(|p| p.ready)
            .min()?;
        let start = ready.max(self.air_busy_until);
        Some(ready.max(SimTime(
            start.as_ns().saturating_sub(DECIDE_AHEAD.as_nanos() as u64),
        )))
    }

    /// Put on the air every transmission whose turn is chosen by `now`: when the air frees
    /// (or at once, when it is free), the first ground endpoint after the last one served,
    /// in the order they joined the network, with a packet sent by then sends its first
    /// packet.
    fn take_turns(&mut self, now: SimTime) {
        while let Some(decide) = self.next_turn().filter(|&d| d <= now) {
            let start = decide.max(self.air_busy_until);
            let after = self.air_last.map_or(0, |g| g + 1);
            let turn = self
                .air_waiting
                .range(after..)
                .chain(self.air_waiting.range(..after))
                .find(|(_, q)| q.front().is_some_and(|p| p.ready <= start))
                .map(|(&g, _)| g);
            let Some(ground) = turn else {
                return;
            };
            let Some(p) = self
                .air_waiting
                .get_mut(&ground)
                .and_then(|q| q.pop_front())
            else {
                return;
            };
            if self.air_waiting.get(&ground).is_some_and(|q| q.is_empty()) {
                self.air_waiting.remove(&ground);
            }
            self.air_last = Some(ground);
            let bits = (p.len + u64::from(self.cfg.air_overhead_bytes)) * 8;
            let dur = Duration::from_nanos(
                bits * 1_000_000_000 / u64::from(self.cfg.air_rate_bps.max(1)),
            );
            self.air_busy_until = start + dur;
            if let Some(b) = self.air_buffers.get_mut(&(p.from, ground)) {
                b.started(start, p.len);
            }
            self.stats.air_busy += dur;
            if self.eps[p.from].radio
                && let Some(tap) = &self.air_tap
            {
                (tap.0)(
                    EndpointId(p.from),
                    &self.eps[p.from].name,
                    start,
                    self.air_busy_until,
                );
            }
            let fate = if self.contact {
                self.rng.fate(&self.impair)
            } else {
                self.stats.no_contact += 1;
                Fate::Drop
            };
            let at = self.air_busy_until + self.cfg.air_delay + self.impair.delay;
            self.seq += 1;
            self.in_flight.insert(
                (at, self.seq),
                InFlight {
                    from: p.from,
                    to: p.to,
                    generation: p.generation,
                    packet: p.packet,
                    fate,
                },
            );
        }
    }

    fn deliver_due(&mut self, now: SimTime) {
        while let Some(entry) = self.in_flight.first_entry() {
            if entry.key().0 > now {
                return;
            }
            let (
                (t, _),
                InFlight {
                    from,
                    to,
                    generation,
                    mut packet,
                    fate,
                },
            ) = entry.remove_entry();
            let dropped = match fate {
                Fate::Drop => {
                    self.stats.dropped += 1;
                    true
                }
                Fate::Corrupt { bit } => {
                    let mut bytes = packet.to_bytes();
                    let nbits = bytes.len() as u32 * 8;
                    let b = bit % nbits.max(1);
                    bytes[(b / 8) as usize] ^= 1 << (b % 8);
                    if let Ok(p) = Packet::parse(&bytes) {
                        packet = p;
                    }
                    false
                }
                Fate::Deliver => false,
            };
            if let Some(tr) = &self.trace {
                tr.emit(TraceEvent {
                    t,
                    medium: self.name.clone(),
                    from: self.eps[from].name.as_str().into(),
                    frame: TraceFrame::Packet(packet.to_bytes()),
                    dropped,
                });
            }
            if dropped {
                continue;
            }
            let ep = &mut self.eps[to];
            if ep.enabled && ep.generation == generation {
                ep.rx += 1;
                let sent = ep.inbox.send(Inbound {
                    t,
                    iface: ep.iface,
                    what: Arrival::Packet(packet),
                });
                if sent == Err(crate::inbox::InboxError::Full) {
                    let (net, to) = (&self.name, &ep.name);
                    crate::count_loss(&mut self.stats.rx_overflow, |n| {
                        format!("{net}: {to}: inbox full: packet lost ({n} so far)")
                    });
                }
            }
        }
    }
}

/// A packet on its way to its receiver.
#[derive(Debug)]
struct InFlight {
    from: usize,
    to: usize,
    /// The receiver's generation when it was sent (a later connection in its place does
    /// not get it).
    generation: u32,
    packet: Packet,
    fate: Fate,
}

/// A packet waiting for its turn on the air.
#[derive(Debug)]
struct AirPacket {
    /// When it was sent.
    ready: SimTime,
    from: usize,
    to: usize,
    /// The receiver's generation when it was sent.
    generation: u32,
    /// Its bytes on the air (header and data).
    len: u64,
    packet: Packet,
}

/// A sender's transmit buffer: the bytes of its packets that have not started on the air.
#[derive(Debug, Default)]
struct AirBuffer {
    /// Bytes waiting for their turn.
    waiting: u64,
    /// Packets whose turn is chosen, not yet started: (start, bytes).
    chosen: std::collections::VecDeque<(SimTime, u64)>,
    chosen_bytes: u64,
}

impl AirBuffer {
    /// Take `len` more bytes at `t` if they fit in `limit` (what has started by `t` has left
    /// the buffer): the backlog with them.
    fn takes(&mut self, t: SimTime, len: u64, limit: u64) -> Option<u64> {
        while let Some(&(start, n)) = self.chosen.front() {
            if start > t {
                break;
            }
            self.chosen.pop_front();
            self.chosen_bytes -= n;
        }
        let backlog = self.waiting + self.chosen_bytes + len;
        (backlog <= limit).then(|| {
            self.waiting += len;
            backlog
        })
    }
    /// A packet of `len` bytes got its turn, starting at `start`.
    fn started(&mut self, start: SimTime, len: u64) {
        self.waiting -= len;
        self.chosen.push_back((start, len));
        self.chosen_bytes += len;
    }
}

// The state a snapshot saves (docs/snapshots.md): everything the network's task and its
// endpoints change. The configuration, the names, the wiring (inboxes, trace, air tap) and
// which endpoints are attached stay as built from the scenario.
snap::fields!(NetStats {
    name,
    packets,
    bytes,
    air_busy,
    dropped,
    unroutable,
    no_contact,
    endpoints,
    air_overflow,
    rx_overflow,
    air_backlog_max
});
snap::fields!(InFlight {
    from,
    to,
    generation,
    packet,
    fate
});
snap::fields!(AirPacket {
    ready,
    from,
    to,
    generation,
    len,
    packet
});
snap::fields!(AirBuffer {
    waiting,
    chosen,
    chosen_bytes
});
snap::fields!(Endpoint {
    addrs,
    enabled,
    tx,
    rx,
    departed,
    generation,
    name,
    link;
    skip own, radio, inbox, iface
});

snap::fields!(State {
    eps,
    default_ep,
    claims,
    air_busy_until,
    air_waiting,
    air_last,
    air_buffers,
    in_flight,
    seq,
    stats,
    impair,
    faults,
    rng,
    contact,
    waiting_until;
    skip cfg, name, reserved, trace, air_tap
});

/// The network's state, under its lock; a network loaded from a snapshot is started with
/// [`PacketNet::resume`].
/// Outside programs' connections are let go as they load, as on a CAN bus
/// ([`CanBus`]'s `Snap`).
impl Snap for PacketNet {
    fn save(&self, w: &mut snap::Writer) {
        self.lock().save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), SnapError> {
        let mut st = self.lock();
        let built = st.eps.len();
        let saved = r.clone().len(MIN_ENDPOINT_BYTES, "ground endpoints")?;
        for _ in built..saved {
            st.push_endpoint("", &[], false, crate::inbox::inbox().0, 0);
        }
        st.load(r)?;
        if st.eps.iter().skip(built).any(|e| e.link.is_none()) {
            return Err(SnapError::Mismatch {
                what: "Endpoint",
                saved: saved as u64,
                built: built as u64,
            });
        }
        for idx in built..saved {
            st.release(idx);
        }
        Ok(())
    }
}

/// The fewest bytes an endpoint's saved state takes.
const MIN_ENDPOINT_BYTES: usize = 16;

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::clock::ClockMode;
    use crate::inbox::inbox;
    use csp::Header;

    /// A ground client with 4 KiB waiting for the air (16 packets of 256 bytes, 3.4 s of
    /// air) and the radio with as much for it: another station's request goes up after at
    /// most one of the flooder's packets, and the radio's answer comes down after at most
    /// one of the radio's packets to the flooder. First come, first served, both waited
    /// 3.4 s behind everything queued, and the answer's could be lost to the radio's full
    /// buffer.
    #[tokio::test(start_paused = true)]
    async fn the_air_serves_ground_stations_in_turn() {
        let clock = Clock::new(ClockMode::Virtual);
        let net = PacketNet::new(PacketNetConfig::ground(), 1);
        let (tx_16, mut rx_16) = inbox();
        let (tx_17, _rx_17) = inbox();
        let (tx_sat, mut rx_sat) = inbox();
        let gs16 = net.attach("GS16", &[16], false, false, tx_16, 0);
        let gs17 = net.attach("GS17", &[17], false, false, tx_17, 0);
        let sat = net.attach("COMM1-uhf", &[], true, true, tx_sat, 1);
        tokio::spawn(net.clone().run(clock));
        // 256 bytes at 9600 bit/s: 213.3 ms on the air.
        let big = |src: u8, dst: u8| Packet::new(Header::new(src, dst, 1, 40), vec![0; 252]);
        let air = Duration::from_nanos(256 * 8 * 1_000_000_000 / 9600);
        for _ in 0..16 {
            gs17.send(SimTime::ZERO, big(17, 3));
            sat.send(SimTime::ZERO, big(3, 17));
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
        let sent = clock.now();
        gs16.send(sent, Packet::new(Header::new(16, 3, 1, 41), vec![7; 8]));
        let up = loop {
            let a = rx_sat.recv().await.unwrap();
            if matches!(&a.what, Arrival::Packet(p) if p.header.src == 16) {
                break a.t;
            }
        };
        // Behind the flooder's packet on the air when it came, and at most one more (the
        // radio's to the flooder, chosen before it came).
        assert!(
            up - sent < 2 * air + Duration::from_millis(50),
            "up after {:?}",
            up - sent
        );
        sat.send(up, Packet::new(Header::new(3, 16, 41, 1), vec![7; 8]));
        let down = rx_16.recv().await.unwrap().t;
        assert!(
            down - up < 2 * air + Duration::from_millis(50),
            "down after {:?}",
            down - up
        );
        let s = net.stats();
        assert_eq!(s.air_overflow, 0, "{s:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn routes_by_owner_then_default_over_the_air() {
        let clock = Clock::new(ClockMode::Virtual);
        let net = PacketNet::new(PacketNetConfig::ground(), 1);
        let (tx_gs, mut rx_gs) = inbox();
        let (tx_sat, mut rx_sat) = inbox();
        let gs = net.attach("GS16", &[16], false, false, tx_gs, 0);
        let sat = net.attach("COMM1-uhf", &[], true, true, tx_sat, 1);
        tokio::spawn(net.clone().run(clock));
        gs.send(
            SimTime::ZERO,
            Packet::new(Header::new(16, 3, 1, 40), vec![0; 96]),
        );
        let a = rx_sat.recv().await.unwrap();
        // 100 bytes at 9600 bit/s = 83.33 ms, plus 3 ms delay.
        assert_eq!(a.t, SimTime(83_333_333 + 3_000_000));
        assert_eq!(a.iface, 1);
        sat.send(a.t, Packet::new(Header::new(3, 16, 40, 1), vec![]));
        let b = rx_gs.recv().await.unwrap();
        assert!(b.t > a.t);
        // Unknown ground address from the satellite side: nobody owns it, default is sender.
        sat.send(b.t, Packet::new(Header::new(3, 19, 40, 1), vec![]));
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert_eq!(net.stats().unroutable, 1);
    }

    #[tokio::test(start_paused = true)]
    async fn the_default_moves_to_another_radio_and_the_tap_hears_radios_only() {
        let clock = Clock::new(ClockMode::Virtual);
        let net = PacketNet::new(PacketNetConfig::ground(), 1);
        let (tx_gs, mut rx_gs) = inbox();
        let (tx_1, mut rx_1) = inbox();
        let (tx_2, mut rx_2) = inbox();
        let gs = net.attach("GS16", &[16], false, false, tx_gs, 0);
        let _r1 = net.attach("COMM1-uhf", &[], true, true, tx_1, 1);
        let r2 = net.attach("COMM2-uhf", &[], true, false, tx_2, 1);
        let heard = Arc::new(Mutex::new(Vec::new()));
        {
            let heard = heard.clone();
            let r2 = r2.id();
            net.set_air_tap(AirTap::new(move |radio, name, a, b| {
                assert_eq!(radio, r2, "{name}");
                heard.lock().unwrap().push((name.to_owned(), a, b));
            }));
        }
        tokio::spawn(net.clone().run(clock));
        let up = |n| Packet::new(Header::new(16, 3, 1, 40), vec![n; 8]);
        gs.send(SimTime::ZERO, up(1));
        assert!(rx_1.recv().await.is_some());
        net.set_default(&r2);
        gs.send(clock.now(), up(2));
        let a = rx_2.recv().await.unwrap();
        assert!(matches!(a.what, crate::inbox::Arrival::Packet(ref p) if p.data == vec![2; 8]));
        assert!(rx_1.try_recv().is_err());
        // The ground's sends were not charged; the radio's one is, for its 12 bytes' air time.
        assert!(heard.lock().unwrap().is_empty());
        r2.send(a.t, Packet::new(Header::new(3, 16, 40, 1), vec![0; 8]));
        assert!(rx_gs.recv().await.is_some());
        // A radio's packet for a ground address nobody owns does not reach the other radio.
        r2.send(a.t, Packet::new(Header::new(3, 19, 40, 1), vec![0; 8]));
        tokio::time::sleep(Duration::from_secs(1)).await;
        assert!(rx_1.try_recv().is_err());
        assert_eq!(net.stats().unroutable, 1);
        let heard = heard.lock().unwrap().clone();
        assert_eq!(heard.len(), 1);
        assert_eq!(heard[0].0, "COMM2-uhf");
        assert_eq!(
            heard[0].2 - heard[0].1,
            Duration::from_nanos(12 * 8 * 1_000_000_000 / 9600)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn out_of_contact_nothing_crosses_the_air() {
        let clock = Clock::new(ClockMode::Virtual);
        let net = PacketNet::new(PacketNetConfig::ground(), 1);
        let (tx_gs, _rx_gs) = inbox();
        let (tx_sat, mut rx_sat) = inbox();
        let gs = net.attach("GS16", &[16], false, false, tx_gs, 0);
        let _sat = net.attach("COMM1-uhf", &[], true, true, tx_sat, 1);
        tokio::spawn(net.clone().run(clock));
        net.set_contact(false);
        gs.send(
            SimTime::ZERO,
            Packet::new(Header::new(16, 3, 1, 40), vec![1]),
        );
        tokio::time::sleep(Duration::from_secs(1)).await;
        assert!(rx_sat.try_recv().is_err());
        let st = net.stats();
        assert_eq!((st.no_contact, st.dropped), (1, 1));
        net.set_contact(true);
        gs.send(clock.now(), Packet::new(Header::new(16, 3, 1, 41), vec![2]));
        let a = rx_sat.recv().await.unwrap();
        assert!(matches!(a.what, crate::inbox::Arrival::Packet(ref p) if p.data == vec![2]));
        assert_eq!(net.stats().no_contact, 1);
    }
}
