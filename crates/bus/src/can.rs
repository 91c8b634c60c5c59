//! An in-process CAN segment: a shared medium that serialises frames at the bus bit rate,
//! arbitrates by CAN id, and delivers every frame to the other attached endpoints whose
//! acceptance filter takes its CFP destination.
//!
//! Model:
//! - a frame occupies the bus for its real bit length: an extended data frame is SOF, 29-bit
//!   id with SRR/IDE/RTR, control, data and CRC-15 with bit stuffing, then CRC and ACK
//!   delimiters, EOF and the 3-bit intermission ([`frame_bits`]);
//! - when the bus is free, the frame with the lowest CAN id among the frames waiting at
//!   that moment wins (each endpoint sends its own frames in order, as libcsp 1.4's driver
//!   does); ties cannot happen on a real bus and are broken by attachment order;
//! - acceptance is libcsp 1.4's `CSP_CAN_MASKED` mode: an endpoint takes frames whose CFP
//!   destination is one of its addresses; a promiscuous endpoint takes everything; the sender
//!   never receives its own frame. An outside program can claim an address exclusively
//!   ([`CanBus::claim`]): while it holds the claim, the internal node with that address no
//!   longer receives its frames;
//! - impairments (drop, corrupt, delay, down) are drawn from the bus's seeded generator.
//!
//! Time: frames carry exact nanosecond stamps (see [`crate::clock`]). The bus task picks
//! frames ahead of its tokio wake-ups by at most [`LOOKAHEAD`], so arbitration happens
//! between the frames queued when a frame is picked.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use csp::SimTime;
use csp::cfp::{CanFrame, CfpId};
use tokio::sync::Notify;

use crate::clock::Clock;
use crate::impair::{Fate, ImpairRng, ImpairmentSet, Impairments};
use crate::inbox::{Arrival, Inbound, InboxTx};
use crate::trace::{TraceEvent, TraceFrame, TraceTx};

/// How far ahead of the clock the bus may schedule frames (one tokio timer tick).
pub const LOOKAHEAD: Duration = Duration::from_millis(1);

/// Settings of a CAN segment.
#[derive(Debug, Clone, PartialEq)]
pub struct CanBusConfig {
    /// Bus name (`main`, `payload`).
    pub name: String,
    /// Bit rate in bit/s (default 1 Mbit/s).
    pub bitrate_bps: u32,
}

impl CanBusConfig {
    /// A 1 Mbit/s bus.
    pub fn new(name: &str) -> Self {
        CanBusConfig {
            name: name.to_owned(),
            bitrate_bps: 1_000_000,
        }
    }
}

/// A fault of the bus as CAN fails (set with [`CanBus::set_can_fault`], by fault id): each
/// variant is added by the scenario fault kind that needs it.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum CanFault {}

/// Counters of one attached endpoint.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PortStats {
    /// Endpoint name.
    pub name: String,
    /// Frames sent.
    pub frames_tx: u64,
    /// Frames received.
    pub frames_rx: u64,
    /// Data bytes sent.
    pub bytes_tx: u64,
    /// Data bytes received.
    pub bytes_rx: u64,
}

/// Counters of a bus.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BusStats {
    /// Bus name.
    pub name: String,
    /// Frames that crossed the bus.
    pub frames: u64,
    /// Data bytes that crossed the bus.
    pub bytes: u64,
    /// Bits on the wire, stuffing and intermission included.
    pub bits: u64,
    /// Time the bus was busy.
    pub busy: Duration,
    /// Frames lost to impairments.
    pub dropped: u64,
    /// Frames corrupted by impairments.
    pub corrupted: u64,
    /// Per-endpoint counters, in attachment order.
    pub ports: Vec<PortStats>,
}

impl BusStats {
    /// Fraction of `elapsed` the bus was busy.
    pub fn load(&self, elapsed: Duration) -> f64 {
        if elapsed.is_zero() {
            0.0
        } else {
            self.busy.as_secs_f64() / elapsed.as_secs_f64()
        }
    }
}

#[derive(Debug)]
struct Port {
    stats: PortStats,
    addrs: BTreeSet<u8>,
    /// The addresses given at attach (never taken out by an alias).
    own: BTreeSet<u8>,
    promiscuous: bool,
    enabled: bool,
    queue: VecDeque<(SimTime, CanFrame)>,
    inbox: InboxTx,
    iface: usize,
}

#[derive(Debug)]
struct Delivery {
    from: usize,
    frame: CanFrame,
    fate: Fate,
}

#[derive(Debug)]
struct State {
    cfg: CanBusConfig,
    name: Arc<str>,
    ports: Vec<Port>,
    claims: BTreeMap<u8, usize>,
    busy_until: SimTime,
    in_flight: BTreeMap<(SimTime, u64), Delivery>,
    seq: u64,
    stats: BusStats,
    impair: Impairments,
    faults: ImpairmentSet,
    can_faults: BTreeMap<u32, CanFault>,
    rng: ImpairRng,
    trace: Option<TraceTx>,
}

/// A CAN segment; clone it freely (all clones are the same bus).
#[derive(Debug, Clone)]
pub struct CanBus {
    state: Arc<Mutex<State>>,
    wake: Arc<Notify>,
}

/// An endpoint's handle for sending on the bus.
#[derive(Debug, Clone)]
pub struct CanPort {
    bus: CanBus,
    idx: usize,
}

impl CanPort {
    /// Queue `frame`, ready to go at `t`.
    pub fn send(&self, t: SimTime, frame: CanFrame) {
        {
            let mut st = self.bus.lock();
            let Some(port) = st.ports.get_mut(self.idx) else {
                return;
            };
            if !port.enabled {
                return;
            }
            port.queue.push_back((t, frame));
        }
        self.bus.wake.notify_one();
    }
    /// Index of this endpoint on its bus.
    pub fn index(&self) -> usize {
        self.idx
    }
    /// The bus.
    pub fn bus(&self) -> &CanBus {
        &self.bus
    }
}

impl CanBus {
    /// A bus; `seed` drives its impairments.
    pub fn new(cfg: CanBusConfig, seed: u64) -> Self {
        let name: Arc<str> = cfg.name.as_str().into();
        let rng = ImpairRng::new(seed, &cfg.name);
        let stats = BusStats {
            name: cfg.name.clone(),
            ..Default::default()
        };
        CanBus {
            state: Arc::new(Mutex::new(State {
                cfg,
                name,
                ports: Vec::new(),
                claims: BTreeMap::new(),
                busy_until: SimTime::ZERO,
                in_flight: BTreeMap::new(),
                seq: 0,
                stats,
                impair: Impairments::default(),
                faults: ImpairmentSet::default(),
                can_faults: BTreeMap::new(),
                rng,
                trace: None,
            })),
            wake: Arc::new(Notify::new()),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock is a bug elsewhere; keep the bus usable anyway.
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The bus name.
    pub fn name(&self) -> Arc<str> {
        self.lock().name.clone()
    }

    /// Attach an endpoint accepting frames for `addrs` (CFP destination); arrivals go to
    /// `inbox` tagged with interface index `iface`.
    pub fn attach(
        &self,
        name: &str,
        addrs: &[u8],
        promiscuous: bool,
        inbox: InboxTx,
        iface: usize,
    ) -> CanPort {
        let mut st = self.lock();
        st.ports.push(Port {
            stats: PortStats {
                name: name.to_owned(),
                ..Default::default()
            },
            addrs: addrs.iter().copied().collect(),
            own: addrs.iter().copied().collect(),
            promiscuous,
            enabled: true,
            queue: VecDeque::new(),
            inbox,
            iface,
        });
        CanPort {
            bus: self.clone(),
            idx: st.ports.len() - 1,
        }
    }

    /// Take or release an endpoint's place on the bus (power on/off). A disabled endpoint
    /// neither sends nor receives, and its queued frames are lost.
    pub fn set_enabled(&self, port: &CanPort, enabled: bool) {
        let mut st = self.lock();
        if let Some(p) = st.ports.get_mut(port.idx) {
            p.enabled = enabled;
            if !enabled {
                p.queue.clear();
            }
        }
    }

    /// Add `addr` to an endpoint's filter (`on`) or take it out again, without claiming it:
    /// the secondary COMM answering to the primary's link address while it carries the
    /// radio link. Its own address cannot be taken out this way.
    pub fn set_alias(&self, port: &CanPort, addr: u8, on: bool) {
        let mut st = self.lock();
        if let Some(p) = st.ports.get_mut(port.idx) {
            if on {
                p.addrs.insert(addr);
            } else if !p.own.contains(&addr) {
                p.addrs.remove(&addr);
            }
        }
    }

    /// Add `addr` to an endpoint's filter and make it the only internal receiver of it.
    pub fn claim(&self, port: &CanPort, addr: u8) {
        let mut st = self.lock();
        st.claims.insert(addr, port.idx);
        if let Some(p) = st.ports.get_mut(port.idx) {
            p.addrs.insert(addr);
        }
    }

    /// Give back every claim of an endpoint and disable it (an outside link went away).
    pub fn release(&self, port: &CanPort) {
        let mut st = self.lock();
        st.claims.retain(|_, idx| *idx != port.idx);
        if let Some(p) = st.ports.get_mut(port.idx) {
            p.addrs.clear();
            p.enabled = false;
            p.queue.clear();
        }
    }

    /// Set the bus's impairments (replacing every fault's).
    pub fn set_impairments(&self, imp: Impairments) {
        self.lock().impair = imp;
    }

    /// Fault `id` impairs the medium with `imp` (`Some`) or is lifted (`None`); the
    /// impairments in force are every active fault's combined
    /// ([`ImpairmentSet::combined`]).
    pub fn set_fault(&self, id: u32, imp: Option<Impairments>) {
        let mut st = self.lock();
        st.faults.set(id, imp);
        st.impair = st.faults.combined();
    }

    /// Fault `id` acts on the bus as CAN faults do (`Some`) or is lifted (`None`).
    pub fn set_can_fault(&self, id: u32, fault: Option<CanFault>) {
        let mut st = self.lock();
        match fault {
            Some(f) => {
                st.can_faults.insert(id, f);
            }
            None => {
                st.can_faults.remove(&id);
            }
        }
    }

    /// Send every frame that crosses the bus to `tx`.
    pub fn set_trace(&self, tx: TraceTx) {
        self.lock().trace = Some(tx);
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> BusStats {
        let st = self.lock();
        let mut s = st.stats.clone();
        s.ports = st.ports.iter().map(|p| p.stats.clone()).collect();
        s
    }

    /// The bus task: serialise, arbitrate and deliver until the runtime stops.
    pub async fn run(self, clock: Clock) {
        loop {
            let next_wake = {
                let mut st = self.lock();
                let now = clock.now();
                st.schedule(now);
                st.deliver_due(now);
                st.next_wake()
            };
            let notified = self.wake.notified();
            tokio::select! {
                biased;
                () = notified => {}
                () = clock.sleep_until(next_wake) => {}
            }
        }
    }
}

impl State {
    fn ns_per_bit(&self) -> u64 {
        1_000_000_000 / u64::from(self.cfg.bitrate_bps.max(1))
    }

    /// Pick and schedule frames while the bus is free within the lookahead.
    fn schedule(&mut self, now: SimTime) {
        let horizon = now + LOOKAHEAD;
        loop {
            let earliest = self
                .ports
                .iter()
                .filter_map(|p| p.queue.front().map(|(t, _)| *t))
                .min();
            let Some(earliest) = earliest else { return };
            let start = earliest.max(self.busy_until);
            if start > horizon {
                return;
            }
            // Arbitration among the frames ready when the bus becomes free.
            let Some(winner) = self
                .ports
                .iter()
                .enumerate()
                .filter_map(|(i, p)| {
                    p.queue
                        .front()
                        .filter(|(t, _)| *t <= start)
                        .map(|(_, f)| (f.id, i))
                })
                .min()
                .map(|(_, i)| i)
            else {
                return;
            };
            let Some((_, frame)) = self.ports[winner].queue.pop_front() else {
                return;
            };
            let bits = frame_bits(&frame);
            let end = start + Duration::from_nanos(u64::from(bits) * self.ns_per_bit());
            self.busy_until = end;
            self.stats.frames += 1;
            self.stats.bytes += u64::from(frame.dlc);
            self.stats.bits += u64::from(bits);
            self.stats.busy += end - start;
            let port = &mut self.ports[winner].stats;
            port.frames_tx += 1;
            port.bytes_tx += u64::from(frame.dlc);
            let fate = self.rng.fate(&self.impair);
            let at = end + self.impair.delay;
            self.seq += 1;
            self.in_flight.insert(
                (at, self.seq),
                Delivery {
                    from: winner,
                    frame,
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
            let ((t, _), d) = entry.remove_entry();
            let mut frame = d.frame;
            let dropped = match d.fate {
                Fate::Drop => {
                    self.stats.dropped += 1;
                    true
                }
                Fate::Corrupt { bit } => {
                    self.stats.corrupted += 1;
                    let nbits = u32::from(frame.dlc) * 8;
                    if nbits > 0 {
                        let b = bit % nbits;
                        frame.data[(b / 8) as usize] ^= 1 << (b % 8);
                    }
                    false
                }
                Fate::Deliver => false,
            };
            if let Some(tr) = &self.trace {
                let from = self
                    .ports
                    .get(d.from)
                    .map_or("?", |p| p.stats.name.as_str())
                    .into();
                tr.emit(TraceEvent {
                    t,
                    medium: self.name.clone(),
                    from,
                    frame: TraceFrame::Can(frame),
                    dropped,
                });
            }
            if dropped {
                continue;
            }
            let dst = CfpId::from_can_id(frame.id).dst;
            let claimed_by = self.claims.get(&dst).copied();
            for (i, p) in self.ports.iter_mut().enumerate() {
                if i == d.from || !p.enabled {
                    continue;
                }
                let wants =
                    p.promiscuous || (p.addrs.contains(&dst) && claimed_by.is_none_or(|c| c == i));
                if wants {
                    p.stats.frames_rx += 1;
                    p.stats.bytes_rx += u64::from(frame.dlc);
                    let _ = p.inbox.send(Inbound {
                        t,
                        iface: p.iface,
                        what: Arrival::Can(frame),
                    });
                }
            }
        }
    }

    fn next_wake(&self) -> SimTime {
        let delivery = self.in_flight.first_key_value().map(|((t, _), _)| *t);
        let pick = self
            .ports
            .iter()
            .filter_map(|p| p.queue.front().map(|(t, _)| *t))
            .min()
            .map(|t| {
                let start = t.max(self.busy_until);
                SimTime(start.as_ns().saturating_sub(LOOKAHEAD.as_nanos() as u64))
            });
        match (delivery, pick) {
            (Some(a), Some(b)) => a.min(b),
            (a, b) => a.or(b).unwrap_or(SimTime::MAX),
        }
    }
}

/// Bits an extended CAN data frame occupies on the bus, stuff bits and the 3-bit
/// intermission included (ISO 11898-1).
pub fn frame_bits(frame: &CanFrame) -> u32 {
    let mut bits: Vec<bool> = Vec::with_capacity(160);
    let push = |v: u64, n: u32, bits: &mut Vec<bool>| {
        for i in (0..n).rev() {
            bits.push((v >> i) & 1 == 1);
        }
    };
    let id = u64::from(frame.id & csp::cfp::CAN_EFF_MASK);
    push(0, 1, &mut bits); // SOF
    push(id >> 18, 11, &mut bits); // base id
    push(1, 1, &mut bits); // SRR
    push(1, 1, &mut bits); // IDE
    push(id & 0x3FFFF, 18, &mut bits); // extended id
    push(0, 1, &mut bits); // RTR
    push(0, 2, &mut bits); // r1, r0
    push(u64::from(frame.dlc.min(8)), 4, &mut bits);
    for &b in frame.data() {
        push(u64::from(b), 8, &mut bits);
    }
    // CRC-15, polynomial 0x4599, over SOF..data.
    let mut crc: u16 = 0;
    for &b in &bits {
        let next = b ^ ((crc >> 14) & 1 == 1);
        crc = (crc << 1) & 0x7FFF;
        if next {
            crc ^= 0x4599;
        }
    }
    push(u64::from(crc), 15, &mut bits);
    // Stuffing: after five equal bits a complementary bit is inserted (and counts itself).
    let mut stuffed = 0u32;
    let mut run = 0u32;
    let mut last: Option<bool> = None;
    for &b in &bits {
        if Some(b) == last {
            run += 1;
        } else {
            run = 1;
            last = Some(b);
        }
        if run == 5 {
            stuffed += 1;
            last = Some(!b);
            run = 1;
        }
    }
    // CRC delimiter, ACK slot, ACK delimiter, EOF (7), intermission (3).
    bits.len() as u32 + stuffed + 1 + 1 + 1 + 7 + 3
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::clock::ClockMode;
    use crate::inbox::inbox;

    #[test]
    fn frame_bits_within_physical_bounds() {
        // Unstuffed extended frame: 67 bits + 8 per data byte (+ 3 intermission).
        for dlc in 0..=8u8 {
            let data: Vec<u8> = (0..dlc).collect();
            let f = CanFrame::new(0x0618_0C00, &data).unwrap();
            let n = frame_bits(&f);
            let base = 67 + 3 + 8 * u32::from(dlc);
            assert!(
                n >= base && n <= base + (54 + 8 * u32::from(dlc)) / 4,
                "{dlc}: {n}"
            );
        }
        // All-zero data stuffs heavily.
        let zeros = CanFrame::new(0, &[0; 8]).unwrap();
        assert!(frame_bits(&zeros) > 67 + 3 + 64 + 10);
    }

    fn cfp_frame(src: u32, dst: u32, ident: u32) -> CanFrame {
        CanFrame::new(src << 24 | dst << 19 | ident, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap()
    }

    #[tokio::test(start_paused = true)]
    async fn delivers_by_cfp_destination_and_arbitrates_by_id() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("main"), 1);
        let (tx_a, _rx_a) = inbox();
        let (tx_b, _rx_b) = inbox();
        let (tx_c, mut rx_c) = inbox();
        let (tx_p, mut rx_p) = inbox();
        let a = bus.attach("A", &[1], false, tx_a, 0);
        let b = bus.attach("B", &[2], false, tx_b, 0);
        let _c = bus.attach("C", &[3], false, tx_c, 0);
        let _p = bus.attach("sniffer", &[], true, tx_p, 0);
        tokio::spawn(bus.clone().run(clock));
        // Both ready at t=0: B's lower id wins although A queued first.
        a.send(SimTime::ZERO, cfp_frame(5, 3, 2));
        b.send(SimTime::ZERO, cfp_frame(4, 3, 1));
        a.send(SimTime::ZERO, cfp_frame(5, 9, 3)); // nobody has address 9
        tokio::time::sleep(Duration::from_millis(5)).await;
        let first = rx_c.recv().await.unwrap();
        let second = rx_c.recv().await.unwrap();
        assert_eq!(first.what, Arrival::Can(cfp_frame(4, 3, 1)));
        assert_eq!(second.what, Arrival::Can(cfp_frame(5, 3, 2)));
        let bits = frame_bits(&cfp_frame(4, 3, 1));
        assert_eq!(first.t, SimTime(u64::from(bits) * 1000));
        assert!(second.t > first.t);
        assert!(rx_c.try_recv().is_err());
        let mut seen = 0;
        while rx_p.try_recv().is_ok() {
            seen += 1;
        }
        assert_eq!(seen, 3);
        let s = bus.stats();
        assert_eq!(s.frames, 3);
        assert_eq!(s.ports[0].frames_tx, 2);
        assert_eq!(s.ports[2].frames_rx, 2);
    }

    #[tokio::test(start_paused = true)]
    async fn an_alias_receives_another_link_address_until_taken_out() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("main"), 1);
        let (tx_a, _ra) = inbox();
        let (tx_b, mut rx_b) = inbox();
        let a = bus.attach("FC", &[3], false, tx_a, 0);
        let b = bus.attach("COMM2", &[2], false, tx_b, 0);
        tokio::spawn(bus.clone().run(clock));
        a.send(SimTime::ZERO, cfp_frame(3, 1, 1));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert!(rx_b.try_recv().is_err(), "no alias yet");
        bus.set_alias(&b, 1, true);
        a.send(clock.now(), cfp_frame(3, 1, 2));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert_eq!(
            rx_b.recv().await.unwrap().what,
            Arrival::Can(cfp_frame(3, 1, 2))
        );
        bus.set_alias(&b, 1, false);
        // Its own address stays whatever is asked.
        bus.set_alias(&b, 2, false);
        a.send(clock.now(), cfp_frame(3, 1, 3));
        a.send(clock.now(), cfp_frame(3, 2, 4));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert_eq!(
            rx_b.recv().await.unwrap().what,
            Arrival::Can(cfp_frame(3, 2, 4))
        );
        assert!(rx_b.try_recv().is_err());
    }

    #[tokio::test(start_paused = true)]
    async fn claims_shadow_internal_nodes_and_down_drops() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("payload"), 1);
        let (tx_a, _ra) = inbox();
        let (tx_int, mut rx_int) = inbox();
        let (tx_out, mut rx_out) = inbox();
        let a = bus.attach("PC", &[6], false, tx_a, 0);
        let _internal = bus.attach("payload12", &[12], false, tx_int, 0);
        let outside = bus.attach("kiss", &[], false, tx_out, 0);
        tokio::spawn(bus.clone().run(clock));
        bus.claim(&outside, 12);
        a.send(SimTime::ZERO, cfp_frame(6, 12, 0));
        tokio::time::sleep(Duration::from_millis(2)).await;
        assert!(rx_out.try_recv().is_ok());
        assert!(rx_int.try_recv().is_err());
        bus.release(&outside);
        bus.set_impairments(Impairments {
            down: true,
            ..Default::default()
        });
        a.send(clock.now(), cfp_frame(6, 12, 1));
        tokio::time::sleep(Duration::from_millis(2)).await;
        assert!(rx_int.try_recv().is_err());
        assert_eq!(bus.stats().dropped, 1);
        bus.set_impairments(Impairments::default());
        a.send(clock.now(), cfp_frame(6, 12, 2));
        tokio::time::sleep(Duration::from_millis(2)).await;
        assert!(rx_int.try_recv().is_ok());
    }
}
