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
//! - impairments (drop, corrupt, delay, down) are drawn from the bus's seeded generator;
//! - **CAN fails as CAN does** (ISO 11898-1, fault confinement): a frame hit by a bit error
//!   (`corrupt`, or a scenario's CAN faults) is never delivered. Every node detects the
//!   error at a bit drawn uniformly over the frame (before its end of frame) and the bus
//!   carries an error frame (6-bit error flag, 8-bit delimiter, 3-bit intermission) after
//!   it; the transmitter's transmit error counter (TEC) rises by 8 and every other
//!   controller's receive error counter (REC) by 1, and the frame stays at the head of the
//!   transmitter's queue: it is retransmitted automatically, entering arbitration again
//!   when the bus is free. A frame sent well takes 1 off the transmitter's TEC and off every
//!   receiver's REC (one above 127 goes back to 120). A controller with TEC or REC above
//!   127 is error-passive; with TEC above 255 it goes bus-off: its queue is lost, it neither
//!   sends nor receives (frames queued meanwhile are dropped and counted), and it recovers
//!   (error-active, both counters 0) after 128 occurrences of 11 consecutive recessive bits
//!   on the bus (each frame's or error frame's end gives one; an idle bus one per 11 bit
//!   times). Every error frame and change of state is a [`CanErrorEvent`] in the trace, and
//!   counted ([`PortStats`], [`BusStats::error_frames`]). Not modelled: the error-passive
//!   transmitter's 8-bit suspend, overload frames, a receiver's +8 for being first to flag.
//!
//! Time: frames carry exact nanosecond stamps (see [`crate::clock`]). The bus task picks
//! frames ahead of its tokio wake-ups by at most [`LOOKAHEAD`], so arbitration happens
//! between the frames queued when a frame is picked.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::Waker;
use std::time::Duration;

use csp::SimTime;
use csp::cfp::{CanFrame, CfpId};
use snap::{Snap, SnapError};

use crate::clock::Clock;
use crate::exec::Start;
use crate::impair::{Fate, ImpairRng, ImpairmentSet, Impairments};
use crate::inbox::{Arrival, Inbound, InboxTx};
use crate::reserve::ClaimError;
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
    /// Frames a controller's transmit queue holds ([`TX_QUEUE_FRAMES`] by default); a frame
    /// queued beyond it is lost and counted (`tx_overflow`).
    pub tx_queue_frames: usize,
}

/// The default depth of a controller's transmit queue: Linux's `txqueuelen` of a CAN
/// interface set to 1000 (the kernel's default of 10 makes libcsp 1.4's driver retry on
/// `ENOBUFS`), a little more so that a node's longest burst fits.
pub const TX_QUEUE_FRAMES: usize = 1024;

impl CanBusConfig {
    /// A 1 Mbit/s bus.
    pub fn new(name: &str) -> Self {
        CanBusConfig {
            name: name.to_owned(),
            bitrate_bps: 1_000_000,
            tx_queue_frames: TX_QUEUE_FRAMES,
        }
    }
}

/// A fault of the bus as CAN fails (set with [`CanBus::set_can_fault`], by fault id): each
/// variant is added by the scenario fault kind that needs it.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum CanFault {
    /// Bit errors at rate `ber` (per bit) on the frames that start in `[from, until)`, of
    /// every transmitter or only `node`'s (its transceiver is bad): a frame of `n` bits is
    /// hit with chance `1 - (1 - ber)^n`, and a hit frame gives an error frame (see the
    /// module doc).
    BitErrors {
        /// The chance that a bit is wrong, 0-1.
        ber: f64,
        /// Only this endpoint's transmissions (`None`: all).
        node: Option<String>,
        /// First instant.
        from: SimTime,
        /// Last instant (exclusive; `None`: until lifted).
        until: Option<SimTime>,
    },
    /// A babbling idiot: `node`'s controller sends frame `can_id` (8 zero bytes) over and
    /// over from `from` to `until`, back to back (or every `period`), entering arbitration
    /// like any frame: it starves every frame with a higher id and none with a lower one.
    Babble {
        /// The babbling endpoint.
        node: String,
        /// Its frame's 29-bit id (0: it wins every arbitration).
        can_id: u32,
        /// Time between two of its frames' starts (`None`: as often as the bus allows).
        period: Option<Duration>,
        /// First instant.
        from: SimTime,
        /// Last instant (exclusive; `None`: until lifted).
        until: Option<SimTime>,
    },
}

/// A frame that can enter arbitration: from a port's queue, or a babbler's next frame.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    ready: SimTime,
    id: u32,
    port: usize,
    /// The babble fault's id, for a babbler's frame.
    babble: Option<u32>,
}

pub use crate::trace::{CanErrorEvent, CanErrorKind, ErrorState, FrameLoss};

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
    /// Transmit error counter now.
    pub tec: u16,
    /// Receive error counter now.
    pub rec: u16,
    /// Fault confinement state now.
    pub state: ErrorState,
    /// Highest TEC reached.
    pub tec_max: u16,
    /// Its transmissions destroyed by error frames.
    pub tx_errors: u64,
    /// Times it went error-passive.
    pub passive_count: u64,
    /// Times it went bus-off.
    pub bus_off_count: u64,
    /// Times it recovered from bus-off.
    pub recoveries: u64,
    /// Frames it lost by going, or being, bus-off.
    pub bus_off_drops: u64,
    /// Frames lost because its transmit queue was full.
    pub tx_overflow: u64,
    /// Frames lost because it was off the bus (queued when it lost power, or sent while
    /// off).
    pub off_drops: u64,
    /// Frames its node handed to it to send: each is sent, lost with one of the counted
    /// reasons above, or still queued ([`PortStats::unaccounted`]).
    pub offered: u64,
    /// Frames a babble fault sent from it (not its node's).
    pub babbled: u64,
    /// Frames its node handed to it while it was off (part of `off_drops`): a node that
    /// acts while unpowered.
    pub sent_while_off: u64,
    /// When the first of those came.
    pub first_sent_while_off: Option<SimTime>,
    /// Frames in its transmit queue when the counters were read.
    pub queued: u64,
    /// Frames lost because its inbox was full (it did not take them in time).
    pub rx_overflow: u64,
    /// The most frames its transmit queue held.
    pub tx_queue_max: u64,
    /// Frames its transmit budget ([`TxBudget`]) held back before they could contend for
    /// the bus.
    pub budget_held: u64,
}

/// A transmit budget of a port: at most `frames_per_s` frames a second, up to a tenth of a
/// second's worth (at least one) back to back (a generic cell rate algorithm in simulated
/// nanoseconds, exact and deterministic). A frame the budget holds back waits in the
/// port's queue and contends for the bus when the budget allows it: a lab bench keeps a
/// runaway program with a low CAN id from stalling everyone above it. Only frames sent
/// count (a retransmission after an error frame is the same frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TxBudget {
    period_ns: u64,
    slack_ns: u64,
    /// When the next frame conforms, plus `slack_ns` (the GCRA's theoretical arrival time).
    tat: SimTime,
}

impl TxBudget {
    /// At most `frames_per_s` frames a second (at least 1).
    pub fn per_second(frames_per_s: u32) -> Self {
        let rate = u64::from(frames_per_s.max(1));
        let period_ns = 1_000_000_000 / rate;
        let burst = (rate / 10).max(1);
        TxBudget {
            period_ns,
            slack_ns: (burst - 1) * period_ns,
            tat: SimTime::ZERO,
        }
    }
    /// The earliest a frame may start.
    fn allowed(&self) -> SimTime {
        SimTime(self.tat.as_ns().saturating_sub(self.slack_ns))
    }
    /// A frame started at `t`.
    fn spend(&mut self, t: SimTime) {
        self.tat = SimTime(self.tat.max(t).as_ns() + self.period_ns);
    }
}

impl PortStats {
    /// Frames offered that are neither sent, nor lost for a counted reason, nor queued
    /// (0 unless a frame went missing; negative if one was counted twice).
    pub fn unaccounted(&self) -> i128 {
        let ended = self.frames_tx.saturating_sub(self.babbled)
            + self.tx_overflow
            + self.bus_off_drops
            + self.off_drops
            + self.queued;
        i128::from(self.offered) - i128::from(ended)
    }

    fn state_after_counters(&self) -> ErrorState {
        if self.tec > 255 {
            ErrorState::BusOff
        } else if self.tec > 127 || self.rec > 127 {
            ErrorState::Passive
        } else {
            ErrorState::Active
        }
    }
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
    /// Frames corrupted by the `corrupt` impairment (each destroyed by an error frame and
    /// retransmitted).
    pub corrupted: u64,
    /// Error frames (every destroyed transmission, whatever hit it).
    pub error_frames: u64,
    /// Times a controller went bus-off.
    pub bus_off: u64,
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
    /// `stats.name`, shared: each traced frame names its sender without an allocation.
    name: Arc<str>,
    addrs: AddrSet,
    /// The addresses given at attach (never taken out by an alias).
    own: AddrSet,
    promiscuous: bool,
    enabled: bool,
    queue: VecDeque<(SimTime, CanFrame)>,
    inbox: InboxTx,
    iface: usize,
    /// The outside link it belongs to (its reserved addresses are its own).
    link: Option<crate::reserve::LinkId>,
    /// Its transmit budget, if it has one.
    budget: Option<TxBudget>,
    /// Released (its outside connection went away): the next connection of its link
    /// takes its place, counters and budget included, so that connections coming and going
    /// leave nothing behind.
    departed: bool,
    /// Delivered, not yet handed to the inbox: each arrival, and whether it is quiet.
    arrivals: Vec<(Inbound, bool)>,
}

/// A set of addresses as a bit per address: the acceptance filter asked for every frame
/// and every endpoint (a tree's lookup was a fifth of the bus task's delivery).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct AddrSet([u64; 4]);

impl AddrSet {
    fn of(addrs: &[u8]) -> Self {
        let mut s = AddrSet::default();
        for &a in addrs {
            s.insert(a);
        }
        s
    }
    fn insert(&mut self, a: u8) {
        self.0[usize::from(a >> 6)] |= 1 << (a & 63);
    }
    fn remove(&mut self, a: u8) {
        self.0[usize::from(a >> 6)] &= !(1 << (a & 63));
    }
    fn contains(&self, a: u8) -> bool {
        self.0[usize::from(a >> 6)] & (1 << (a & 63)) != 0
    }
}

#[derive(Debug)]
enum Delivery {
    /// A frame, at the end of its last bit (plus any delay).
    Frame {
        from: usize,
        frame: CanFrame,
        fate: Fate,
    },
    /// An error frame or a change of a controller's state, for the trace.
    Error(CanErrorEvent),
}

/// Bits of an error frame after the bit where the error was detected: a 6-bit error flag,
/// the 8-bit error delimiter and the 3-bit intermission.
const ERROR_FRAME_BITS: u64 = 6 + 8 + 3;
/// Consecutive recessive bits a bus-off controller must see 128 times to recover.
const RECOVERY_BITS: u64 = 11;
/// How many times.
const RECOVERY_SEQUENCES: u64 = 128;

#[derive(Debug)]
struct State {
    cfg: CanBusConfig,
    name: Arc<str>,
    ports: snap::Fixed<Port>,
    claims: BTreeMap<u8, usize>,
    reserved: crate::reserve::Reservations,
    busy_until: SimTime,
    /// Sequences of 11 recessive bits the bus has shown (for bus-off recovery), counted up
    /// to `busy_until`.
    recessive_seqs: u64,
    /// Per bus-off port, the count of `recessive_seqs` when it went bus-off.
    bus_off_since: BTreeMap<usize, u64>,
    /// Whether any error frame has happened (until then no counter moves).
    errors_seen: bool,
    /// What is on its way, in order of (time, sequence): a queue kept sorted (nearly every
    /// entry goes at the back: frames end in order).
    in_flight: VecDeque<((SimTime, u64), Delivery)>,
    seq: u64,
    stats: BusStats,
    impair: Impairments,
    faults: ImpairmentSet,
    can_faults: BTreeMap<u32, CanFault>,
    /// When each babbler may start its next frame, by fault id.
    babble_next: BTreeMap<u32, SimTime>,
    rng: ImpairRng,
    trace: Option<TraceTx>,
    /// The last frame whose bits were counted, and its count.
    last_bits: Option<(CanFrame, u32)>,
    /// Something the bus task waits for changed (a queue that was empty has a frame, a
    /// fault came or went) since it last looked; under the state's lock, so that telling
    /// the task costs no lock of its own.
    bell: bool,
    /// The bus task, while it waits.
    bus_waker: Option<Waker>,
    /// The instant the bus task waits for.
    waiting_until: SimTime,
}

/// A CAN segment; clone it freely (all clones are the same bus).
#[derive(Debug, Clone)]
pub struct CanBus {
    state: Arc<Mutex<State>>,
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
        self.send_train(t, frame, || None);
    }

    /// Queue `first` and then each frame `more` gives until it gives none, all ready to go
    /// at `t`, under one lock of the bus (a packet's fragments).
    pub fn send_train(
        &self,
        t: SimTime,
        first: CanFrame,
        mut more: impl FnMut() -> Option<CanFrame>,
    ) {
        let waker = {
            let mut st = self.bus.lock();
            let mut ring = false;
            let mut frame = Some(first);
            while let Some(f) = frame {
                ring |= st.queue(self.idx, t, f);
                frame = more();
            }
            if ring { st.ring() } else { None }
        };
        if let Some(w) = waker {
            w.wake();
        }
    }
    /// Frames the transmit queue can still take (a sender that must not lose part of a
    /// packet checks this first).
    pub fn room(&self) -> usize {
        let st = self.bus.lock();
        let limit = st.cfg.tx_queue_frames;
        st.ports
            .get(self.idx)
            .map_or(0, |p| limit.saturating_sub(p.queue.len()))
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
                ports: snap::Fixed::default(),
                claims: BTreeMap::new(),
                reserved: Default::default(),
                busy_until: SimTime::ZERO,
                recessive_seqs: 0,
                bus_off_since: BTreeMap::new(),
                errors_seen: false,
                in_flight: VecDeque::new(),
                seq: 0,
                stats,
                impair: Impairments::default(),
                faults: ImpairmentSet::default(),
                can_faults: BTreeMap::new(),
                babble_next: BTreeMap::new(),
                rng,
                trace: None,
                last_bits: None,
                bell: false,
                bus_waker: None,
                waiting_until: SimTime::ZERO,
            })),
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
        let idx = self
            .lock()
            .push_port(name, addrs, promiscuous, inbox, iface);
        CanPort {
            bus: self.clone(),
            idx,
        }
    }

    /// Attach an endpoint of outside link `link` holding `addr` alone, unless another
    /// endpoint holds it (a node of the twin attached with it, or another claim) or another
    /// link reserved it ([`CanBus::reserve`]): refused with the holder's name, and then
    /// nothing is attached. Checked and attached under one lock, so that a refusal leaves
    /// nothing on the bus that outlives it.
    pub fn attach_claimed(
        &self,
        name: &str,
        link: crate::reserve::LinkId,
        addr: u8,
        inbox: InboxTx,
        iface: usize,
    ) -> Result<CanPort, ClaimError> {
        let mut st = self.lock();
        if let Some(why) = st.refusal(addr, None, Some(link)) {
            return Err(why);
        }
        // A departed connection's place of the same link, else a new one.
        let port = match st
            .ports
            .iter()
            .position(|p| p.departed && p.link == Some(link))
        {
            Some(i) => {
                if let Some(p) = st.ports.get_mut(i) {
                    p.stats.name = name.to_owned();
                    p.name = name.into();
                    p.enabled = true;
                    p.departed = false;
                    p.inbox = inbox;
                    p.iface = iface;
                    p.arrivals.clear();
                }
                i
            }
            None => st.push_port(name, &[], false, inbox, iface),
        };
        if let Some(p) = st.ports.get_mut(port) {
            p.link = Some(link);
        }
        st.claims.insert(addr, port);
        if let Some(p) = st.ports.get_mut(port) {
            p.addrs.insert(addr);
        }
        Ok(CanPort {
            bus: self.clone(),
            idx: port,
        })
    }

    /// Give an endpoint a transmit budget, or take it away (`None`). What its budget spent
    /// already stays spent (a connection taking a departed one's place does not start
    /// afresh).
    pub fn set_tx_budget(&self, port: &CanPort, budget: Option<TxBudget>) {
        if let Some(p) = self.lock().ports.get_mut(port.idx) {
            p.budget = budget.map(|mut b| {
                if let Some(old) = p.budget {
                    b.tat = old.tat;
                }
                b
            });
        }
    }

    /// Take or release an endpoint's place on the bus (power on/off). A disabled endpoint
    /// neither sends nor receives, and its queued frames are lost.
    pub fn set_enabled(&self, port: &CanPort, enabled: bool) {
        let mut st = self.lock();
        if let Some(p) = st.ports.get_mut(port.idx) {
            p.enabled = enabled;
        }
        if !enabled {
            st.lose_queue(port.idx, None, FrameLoss::Off);
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
            } else if !p.own.contains(addr) {
                p.addrs.remove(addr);
            }
        }
    }

    /// Add `addr` to an endpoint's filter and make it its only receiver, unless another
    /// endpoint holds it: a node of the twin attached with it, or another claim. Refused
    /// with the holder's name.
    pub fn claim(&self, port: &CanPort, addr: u8) -> Result<(), ClaimError> {
        let mut st = self.lock();
        let link = st.ports.get(port.idx).and_then(|p| p.link);
        if let Some(why) = st.refusal(addr, Some(port.idx), link) {
            return Err(why);
        }
        st.claims.insert(addr, port.idx);
        if let Some(p) = st.ports.get_mut(port.idx) {
            p.addrs.insert(addr);
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
    /// a snapshot (its place on the bus stays, its counts with it).
    pub fn release(&self, port: &CanPort) {
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

    /// Fault `id` acts on the bus as CAN faults do (`Some`) or is lifted (`None`).
    pub fn set_can_fault(&self, id: u32, fault: Option<CanFault>) {
        let mut st = self.lock();
        match fault {
            Some(f) => {
                st.can_faults.insert(id, f);
            }
            None => {
                st.can_faults.remove(&id);
                st.babble_next.remove(&id);
            }
        }
        if let Some(w) = st.ring() {
            drop(st);
            w.wake();
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
        s.ports = st
            .ports
            .iter()
            .map(|p| PortStats {
                queued: p.queue.len() as u64,
                ..p.stats.clone()
            })
            .collect();
        s
    }

    /// Ready once something the bus task waits for changed ([`State::ring`]).
    fn rung(&self) -> impl std::future::Future<Output = ()> + '_ {
        std::future::poll_fn(|cx| {
            let mut st = self.lock();
            if st.bell {
                st.bell = false;
                return std::task::Poll::Ready(());
            }
            match &mut st.bus_waker {
                Some(w) if w.will_wake(cx.waker()) => {}
                w => *w = Some(cx.waker().clone()),
            }
            std::task::Poll::Pending
        })
    }

    /// The bus task: serialise, arbitrate and deliver until the runtime stops.
    pub async fn run(self, clock: Clock) {
        self.run_from(clock, Start::Fresh).await;
    }

    /// The bus task of a bus loaded from a snapshot: it waits first, for what it waited for
    /// when the snapshot was taken.
    pub async fn resume(self, clock: Clock) {
        self.run_from(clock, Start::Resumed).await;
    }

    async fn run_from(self, clock: Clock, start: Start) {
        let mut timer = crate::clock::Timer::new(clock);
        let mut start = start;
        loop {
            let next_wake = {
                let mut st = self.lock();
                if start == Start::Resumed {
                    // What it waited for: an endpoint's change that rang no bell since may
                    // have moved what it would wait for now.
                    start = Start::Fresh;
                } else {
                    let now = clock.now();
                    // Whatever rang the bell is seen now.
                    st.bell = false;
                    st.schedule(now);
                    st.deliver_due(now);
                    st.hand_over();
                    st.waiting_until = st.next_wake();
                }
                st.waiting_until
            };
            tokio::select! {
                biased;
                () = self.rung() => {}
                () = timer.sleep_until(next_wake) => {}
            }
        }
    }
}

// The state a snapshot saves (docs/snapshots.md): everything the bus's task and its
// endpoints change. The configuration, the names, the wiring (inboxes, trace, the task's
// waker) and which endpoints are attached stay as built from the scenario.
snap::tagged_enum!(CanFault {
    BitErrors {
        ber,
        node,
        from,
        until
    },
    Babble {
        node,
        can_id,
        period,
        from,
        until
    }
});
snap::fields!(PortStats {
    name,
    frames_tx,
    frames_rx,
    bytes_tx,
    bytes_rx,
    tec,
    rec,
    state,
    tec_max,
    tx_errors,
    passive_count,
    bus_off_count,
    recoveries,
    bus_off_drops,
    tx_overflow,
    off_drops,
    offered,
    babbled,
    sent_while_off,
    first_sent_while_off,
    queued,
    rx_overflow,
    tx_queue_max,
    budget_held
});
snap::fields!(BusStats {
    name,
    frames,
    bytes,
    bits,
    busy,
    dropped,
    corrupted,
    error_frames,
    bus_off,
    ports
});
snap::fields!(TxBudget {
    period_ns,
    slack_ns,
    tat
});
snap::tagged_enum!(Delivery {
    Frame { from, frame, fate },
    Error(e)
});

impl Snap for AddrSet {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), SnapError> {
        self.0.load(r)
    }
}

snap::fields!(Port {
    stats,
    addrs,
    enabled,
    queue,
    budget,
    departed,
    arrivals,
    link;
    skip name, own, promiscuous, inbox, iface
});
snap::fields!(State {
    ports,
    claims,
    busy_until,
    recessive_seqs,
    bus_off_since,
    errors_seen,
    in_flight,
    seq,
    stats,
    impair,
    faults,
    can_faults,
    babble_next,
    rng,
    last_bits,
    bell,
    waiting_until;
    skip cfg, name, reserved, trace, bus_waker
});

impl CanBus {
    /// Whether the bus is as a settled run leaves it (`crate::exec::settled`): nothing rang
    /// that its task has not seen, nothing delivered that is not in its inbox. Its state is
    /// then whole, and a snapshot may save it.
    pub fn check_settled(&self) -> Result<(), SnapError> {
        let st = self.lock();
        if st.bell {
            return Err(SnapError::NotQuiescent("a CAN bus's bell"));
        }
        if st.ports.iter().any(|p| !p.arrivals.is_empty()) {
            return Err(SnapError::NotQuiescent("a CAN endpoint's arrivals"));
        }
        Ok(())
    }
}

/// The bus's state, under its lock; a bus loaded from a snapshot is started with
/// [`CanBus::resume`].
/// The endpoints of outside programs' connections (attached after those the run builds)
/// load into places made for them and are let go at once: a connection is no state a run
/// can take up again, so a run from a snapshot begins with its programs gone, and the
/// next connection of each link takes its place (as a program's reconnecting does). The
/// addresses the links reserve are this run's, reserved as its links start.
impl Snap for CanBus {
    fn save(&self, w: &mut snap::Writer) {
        self.lock().save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), SnapError> {
        let mut st = self.lock();
        let built = st.ports.len();
        let saved = r.clone().len(MIN_PORT_BYTES, "CAN endpoints")?;
        for _ in built..saved {
            st.push_port("", &[], false, crate::inbox::inbox().0, 0);
        }
        st.load(r)?;
        // Only connections' endpoints are taken in: a node's that this run did not build is
        // another build of the bus.
        if st.ports.iter().skip(built).any(|p| p.link.is_none()) {
            return Err(SnapError::Mismatch {
                what: "Port",
                saved: saved as u64,
                built: built as u64,
            });
        }
        for idx in built..saved {
            if let Some(p) = st.ports.get_mut(idx) {
                p.name = p.stats.name.as_str().into();
            }
            st.release(idx);
        }
        Ok(())
    }
}

/// The fewest bytes an endpoint's saved state takes (its counters alone take more).
const MIN_PORT_BYTES: usize = 64;

/// Trace a frame that never went on the wire.
fn lost(
    trace: &Option<TraceTx>,
    medium: &Arc<str>,
    from: &str,
    t: SimTime,
    f: CanFrame,
    why: FrameLoss,
) {
    if let Some(tr) = trace {
        tr.emit(TraceEvent {
            t,
            medium: medium.clone(),
            from: from.into(),
            frame: TraceFrame::CanLost(f, why),
            dropped: true,
        });
    }
}

impl State {
    /// Port `i` loses its whole transmit queue (at `t`, or each frame at its own instant),
    /// counted and traced.
    fn lose_queue(&mut self, i: usize, t: Option<SimTime>, why: FrameLoss) {
        let Some(p) = self.ports.get_mut(i) else {
            return;
        };
        let n = p.queue.len() as u64;
        match why {
            FrameLoss::BusOff => p.stats.bus_off_drops += n,
            FrameLoss::Off => p.stats.off_drops += n,
            FrameLoss::QueueFull => p.stats.tx_overflow += n,
        }
        for (r, f) in p.queue.drain(..) {
            lost(
                &self.trace,
                &self.name,
                &p.stats.name,
                t.unwrap_or(r),
                f,
                why,
            );
        }
    }

    /// [`CanBus::release`] of endpoint `idx`.
    fn release(&mut self, idx: usize) {
        self.claims.retain(|_, i| *i != idx);
        if let Some(p) = self.ports.get_mut(idx) {
            p.addrs = AddrSet::default();
            p.own = AddrSet::default();
            p.enabled = false;
            p.departed = p.link.is_some();
        }
        self.lose_queue(idx, None, FrameLoss::Off);
    }

    /// Add an endpoint; its index.
    fn push_port(
        &mut self,
        name: &str,
        addrs: &[u8],
        promiscuous: bool,
        inbox: InboxTx,
        iface: usize,
    ) -> usize {
        self.ports.push(Port {
            stats: PortStats {
                name: name.to_owned(),
                ..Default::default()
            },
            name: name.into(),
            addrs: AddrSet::of(addrs),
            own: AddrSet::of(addrs),
            promiscuous,
            enabled: true,
            queue: VecDeque::new(),
            inbox,
            arrivals: Vec::new(),
            iface,
            link: None,
            budget: None,
            departed: false,
        });
        self.ports.len() - 1
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

    /// The endpoint holding `addr`: its claimant, or a node attached with it.
    /// Why `h` keeps `addr` from a claim: a node of the twin attached with it, or another
    /// outside connection that claimed it.
    fn held_by(&self, addr: u8, h: usize) -> ClaimError {
        let name = self.ports[h].stats.name.clone();
        if self.claims.contains_key(&addr) {
            ClaimError::Held(name)
        } else {
            ClaimError::Node(name)
        }
    }

    fn holder(&self, addr: u8) -> Option<usize> {
        self.claims
            .get(&addr)
            .copied()
            .or_else(|| self.ports.iter().position(|p| p.own.contains(addr)))
    }

    /// [`frame_bits`], remembered for the last frame (a babbler sends one frame over and
    /// over, and it was a third of such a run's time).
    fn frame_bits(&mut self, frame: &CanFrame) -> u32 {
        match self.last_bits {
            Some((f, n)) if f == *frame => n,
            _ => {
                let n = frame_bits(frame);
                self.last_bits = Some((*frame, n));
                n
            }
        }
    }

    fn ns_per_bit(&self) -> u64 {
        1_000_000_000 / u64::from(self.cfg.bitrate_bps.max(1))
    }

    fn bits(&self, n: u64) -> Duration {
        Duration::from_nanos(n * self.ns_per_bit())
    }

    /// Queue a trace entry for `t`.
    fn push_event(&mut self, t: SimTime, port: usize, kind: CanErrorKind) {
        let Some(p) = self.ports.get(port) else {
            return;
        };
        let ev = CanErrorEvent {
            node: p.stats.name.as_str().into(),
            kind,
            tec: p.stats.tec,
            rec: p.stats.rec,
        };
        self.seq += 1;
        self.in_flight_insert((t, self.seq), Delivery::Error(ev));
    }

    /// Port `i`'s counters changed at `t`: move it to the state they say, with its events;
    /// going bus-off loses its queue.
    fn update_state(&mut self, i: usize, t: SimTime) {
        let Some(p) = self.ports.get_mut(i) else {
            return;
        };
        let was = p.stats.state;
        let now = p.stats.state_after_counters();
        if now == was {
            return;
        }
        p.stats.state = now;
        match now {
            ErrorState::Passive => p.stats.passive_count += 1,
            ErrorState::BusOff => {
                p.stats.bus_off_count += 1;
                self.lose_queue(i, Some(t), FrameLoss::BusOff);
                self.stats.bus_off += 1;
                self.bus_off_since.insert(i, self.recessive_seqs);
            }
            ErrorState::Active => {}
        }
        self.push_event(t, i, CanErrorKind::State(now));
    }

    /// The bus shows `n` more sequences of 11 recessive bits, the last ending at `t` (and,
    /// when idle from `idle_from`, one every 11 bits from there): bus-off controllers that
    /// have seen 128 recover, at the instant they saw the 128th.
    fn recessive(&mut self, n: u64, t: SimTime, idle_from: Option<SimTime>) {
        let before = self.recessive_seqs;
        self.recessive_seqs += n;
        let recovered: Vec<(usize, SimTime)> = self
            .bus_off_since
            .iter()
            .filter(|&(_, since)| self.recessive_seqs - since >= RECOVERY_SEQUENCES)
            .map(|(&i, since)| {
                let at = match idle_from {
                    // The k-th sequence of an idle stretch ends 11 k bits into it.
                    Some(from) => {
                        let k = (since + RECOVERY_SEQUENCES).saturating_sub(before);
                        from + self.bits(k * RECOVERY_BITS)
                    }
                    None => t,
                };
                (i, at)
            })
            .collect();
        for (i, at) in recovered {
            self.bus_off_since.remove(&i);
            if let Some(p) = self.ports.get_mut(i) {
                p.stats.tec = 0;
                p.stats.rec = 0;
                p.stats.recoveries += 1;
            }
            self.update_state(i, at);
        }
    }

    /// The instant the next bus-off controller recovers if the bus stays idle from
    /// `busy_until`.
    fn idle_recovery(&self) -> Option<SimTime> {
        let needed = self
            .bus_off_since
            .values()
            .map(|since| (since + RECOVERY_SEQUENCES).saturating_sub(self.recessive_seqs))
            .min()?;
        Some(self.busy_until + self.bits(needed * RECOVERY_BITS))
    }

    /// The bus is idle from `busy_until` to `t`: count its recessive sequences.
    fn idle_until(&mut self, t: SimTime) {
        if t <= self.busy_until {
            return;
        }
        let idle_bits = (t - self.busy_until).as_nanos() as u64 / self.ns_per_bit().max(1);
        let n = idle_bits / RECOVERY_BITS;
        if n > 0 {
            let from = self.busy_until;
            self.recessive(n, t, Some(from));
            self.busy_until = self.busy_until.max(from + self.bits(n * RECOVERY_BITS));
            // The bus is still idle up to `t`; what is left of the stretch counts later.
            self.busy_until = self.busy_until.min(t);
        }
    }

    /// Drop what bus-off controllers have queued up to `t`.
    fn purge_bus_off(&mut self, t: SimTime) {
        // A port is bus-off exactly while it is in `bus_off_since` (`update_state` puts it
        // there, `recessive` takes it out as it recovers).
        if self.bus_off_since.is_empty() {
            return;
        }
        for p in self
            .ports
            .iter_mut()
            .filter(|p| p.stats.state == ErrorState::BusOff)
        {
            while let Some(&(r, f)) = p.queue.front().filter(|(r, _)| *r <= t) {
                p.queue.pop_front();
                p.stats.bus_off_drops += 1;
                lost(
                    &self.trace,
                    &self.name,
                    &p.stats.name,
                    r,
                    f,
                    FrameLoss::BusOff,
                );
            }
        }
    }

    /// Every frame that can enter arbitration next: each port's first, and each active
    /// babbler's.
    fn candidates(&self) -> impl Iterator<Item = Candidate> + '_ {
        let queued = self
            .ports
            .iter()
            .enumerate()
            .filter(|(_, p)| p.stats.state != ErrorState::BusOff)
            .filter_map(|(i, p)| {
                p.queue.front().map(|(t, f)| Candidate {
                    // A budget holds the frame back until it allows it.
                    ready: p.budget.map_or(*t, |b| (*t).max(b.allowed())),
                    id: f.id,
                    port: i,
                    babble: None,
                })
            });
        // No walk of an empty map (this runs for every frame).
        let faults = (!self.can_faults.is_empty()).then(|| self.can_faults.iter());
        let babblers = faults.into_iter().flatten().filter_map(|(&fid, f)| {
            let CanFault::Babble {
                node,
                can_id,
                from,
                until,
                ..
            } = f
            else {
                return None;
            };
            let port = self.ports.iter().position(|p| p.stats.name == *node)?;
            let p = &self.ports[port];
            let ready = (*from).max(self.babble_next.get(&fid).copied().unwrap_or(*from));
            (p.enabled && p.stats.state != ErrorState::BusOff && until.is_none_or(|u| ready < u))
                .then_some(Candidate {
                    ready,
                    id: *can_id & csp::cfp::CAN_EFF_MASK,
                    port,
                    babble: Some(fid),
                })
        });
        queued.chain(babblers)
    }

    /// The instant the first candidate is ready, and the winner of the arbitration held
    /// when the bus is free for it: among the frames ready by then, the lowest id wins
    /// (ties, impossible on a real bus, by attachment order, a port's own queue before its
    /// babble). One pass over the candidates (a bus-off port's purge, which may come
    /// between, takes none of them).
    fn contest(&self) -> Option<(SimTime, Candidate)> {
        let key = |c: &Candidate| (c.id, c.port, c.babble.is_some());
        let better =
            |c: &Candidate, best: &Option<Candidate>| best.is_none_or(|b| key(c) < key(&b));
        // The best of those ready when the bus frees, and the best of the earliest.
        let (mut by_free, mut first): (Option<Candidate>, Option<Candidate>) = (None, None);
        for c in self.candidates() {
            if c.ready <= self.busy_until && better(&c, &by_free) {
                by_free = Some(c);
            }
            match first {
                Some(f) if c.ready > f.ready => {}
                Some(f) if c.ready == f.ready => {
                    if better(&c, &first) {
                        first = Some(c);
                    }
                }
                _ => first = Some(c),
            }
        }
        let first = first?;
        Some((first.ready, by_free.unwrap_or(first)))
    }

    /// Pick and schedule frames while the bus is free within the lookahead.
    fn schedule(&mut self, now: SimTime) {
        let horizon = now + LOOKAHEAD;
        loop {
            let contest = self.contest();
            let earliest = contest.map(|(e, _)| e);
            // Recoveries due on an idle bus before the next frame (or the horizon).
            if let Some(r) = self.idle_recovery()
                && r <= horizon
                && earliest.is_none_or(|e| r <= e.max(self.busy_until))
            {
                self.idle_until(r);
                self.purge_bus_off(r);
                continue;
            }
            let Some((earliest, w)) = contest else {
                self.purge_bus_off(horizon);
                return;
            };
            let start = earliest.max(self.busy_until);
            if start > horizon {
                self.purge_bus_off(horizon);
                return;
            }
            self.purge_bus_off(start);
            let winner = w.port;
            if !self.bus_off_since.is_empty() {
                self.idle_until(start);
            }
            let Some((ready, frame)) = self.take_winner(w, start) else {
                return;
            };
            let requeue = w.babble.is_none();
            let bits = self.frame_bits(&frame);
            let fate = self.rng.fate(&self.impair);
            if let Fate::Corrupt { bit } = fate {
                self.stats.corrupted += 1;
                self.error_frame(winner, (ready, frame), start, bits, bit, requeue);
                continue;
            }
            // Bit errors: the chance that at least one of the frame's bits is wrong.
            let survive = self.bit_error_survival(winner, start, bits);
            if survive < 1.0
                && let Fate::Corrupt { bit } = self.rng.fate(&Impairments {
                    corrupt_prob: 1.0 - survive,
                    ..Impairments::default()
                })
            {
                self.error_frame(winner, (ready, frame), start, bits, bit, requeue);
                continue;
            }
            self.transmit(winner, (ready, frame), start, bits, requeue, fate);
        }
    }

    /// The winner's frame and when it was ready: its queue's head, or a babble (the next one due).
    fn take_winner(&mut self, w: Candidate, start: SimTime) -> Option<(SimTime, CanFrame)> {
        match w.babble {
            None => self.ports[w.port].queue.pop_front(),
            Some(fid) => {
                let period = match self.can_faults.get(&fid) {
                    Some(CanFault::Babble { period, .. }) => *period,
                    _ => None,
                };
                let frame = CanFrame::new(w.id, &[0; 8])?;
                let next = match period {
                    Some(p) => start + p,
                    // Back to back: ready again as the bus frees.
                    None => {
                        let n = self.frame_bits(&frame);
                        start + self.bits(u64::from(n))
                    }
                };
                self.babble_next.insert(fid, next);
                Some((start, frame))
            }
        }
    }

    /// The chance that the bit-error faults active at `start` spare all `bits` of the frame.
    fn bit_error_survival(&self, winner: usize, start: SimTime, bits: u32) -> f64 {
        let name = self.ports[winner].stats.name.as_str();
        if self.can_faults.is_empty() {
            1.0
        } else {
            self.can_faults
                .values()
                .map(|f| match f {
                    CanFault::BitErrors {
                        ber,
                        node,
                        from,
                        until,
                    } if start >= *from
                        && until.is_none_or(|u| start < u)
                        && node.as_deref().is_none_or(|n| n == name) =>
                    {
                        (1.0 - ber.clamp(0.0, 1.0)).powi(bits as i32)
                    }
                    _ => 1.0,
                })
                .product()
        }
    }

    /// The frame crosses the bus intact from `start`: counted, budget spent, sent on its way.
    fn transmit(
        &mut self,
        winner: usize,
        (ready, frame): (SimTime, CanFrame),
        start: SimTime,
        bits: u32,
        requeue: bool,
        fate: Fate,
    ) {
        let end = start + self.bits(u64::from(bits));
        self.busy_until = end;
        self.stats.frames += 1;
        self.stats.bytes += u64::from(frame.dlc);
        self.stats.bits += u64::from(bits);
        self.stats.busy += end - start;
        let p = &mut self.ports[winner];
        if requeue && let Some(b) = p.budget.as_mut() {
            if b.allowed() > ready {
                p.stats.budget_held += 1;
            }
            b.spend(start);
        }
        let port = &mut p.stats;
        port.frames_tx += 1;
        port.babbled += u64::from(!requeue);
        port.bytes_tx += u64::from(frame.dlc);
        if self.errors_seen {
            self.good_frame_counters(winner, end);
        }
        let at = end + self.impair.delay;
        self.seq += 1;
        self.in_flight_insert(
            (at, self.seq),
            Delivery::Frame {
                from: winner,
                frame,
                fate,
            },
        );
        if !self.bus_off_since.is_empty() {
            self.recessive(1, end, None);
        }
    }

    /// A good frame: one off the transmitter's TEC and every receiver's REC, states updated.
    fn good_frame_counters(&mut self, winner: usize, end: SimTime) {
        for (i, p) in self.ports.iter_mut().enumerate() {
            let c = &mut p.stats;
            if i == winner {
                c.tec = c.tec.saturating_sub(1);
            } else if c.state != ErrorState::BusOff {
                c.rec = if c.rec > 127 {
                    120
                } else {
                    c.rec.saturating_sub(1)
                };
            }
        }
        for i in 0..self.ports.len() {
            self.update_state(i, end);
        }
    }

    /// An error destroys `winner`'s transmission of `frame` begun at `start`: the error is
    /// detected at a bit drawn from `draw` over the frame before its end of frame, an error
    /// frame follows, the counters move, and the frame goes back to the head of the queue
    /// (`requeue`; a babbler just babbles on).
    fn error_frame(
        &mut self,
        winner: usize,
        (ready, frame): (SimTime, CanFrame),
        start: SimTime,
        bits: u32,
        draw: u32,
        requeue: bool,
    ) {
        // The last 10 bits are the ACK delimiter and the end of frame.
        let span = u64::from(bits.saturating_sub(10).max(1));
        let at_bit = 1 + u64::from(draw) % span;
        let used = at_bit + ERROR_FRAME_BITS;
        let end = start + self.bits(used);
        self.busy_until = end;
        self.stats.bits += used;
        self.stats.busy += end - start;
        self.stats.error_frames += 1;
        let can_id = frame.id;
        self.errors_seen = true;
        let p = &mut self.ports[winner];
        p.stats.tx_errors += 1;
        p.stats.tec = p.stats.tec.saturating_add(8);
        p.stats.tec_max = p.stats.tec_max.max(p.stats.tec);
        if requeue {
            p.queue.push_front((ready, frame));
        }
        for (i, p) in self.ports.iter_mut().enumerate() {
            if i != winner && p.stats.state != ErrorState::BusOff {
                p.stats.rec = p.stats.rec.saturating_add(1).min(255);
            }
        }
        self.push_event(end, winner, CanErrorKind::ErrorFrame { can_id });
        // The error frame's tail counts for those already bus-off, not for one going
        // bus-off by it.
        if !self.bus_off_since.is_empty() {
            self.recessive(1, end, None);
        }
        // The transmitter first (it may go bus-off), then the receivers.
        self.update_state(winner, end);
        for i in (0..self.ports.len()).filter(|&i| i != winner) {
            self.update_state(i, end);
        }
    }

    /// Port `idx` queues `frame` at `t` (or loses it, counted and traced); whether the bus
    /// task must look again (the queue was empty: a frame behind another changes nothing it
    /// waits for, as its next wake-up counts the queue's first frame).
    fn queue(&mut self, idx: usize, t: SimTime, frame: CanFrame) -> bool {
        let limit = self.cfg.tx_queue_frames;
        let Some(port) = self.ports.get_mut(idx) else {
            return false;
        };
        port.stats.offered += 1;
        if !port.enabled {
            port.stats.off_drops += 1;
            port.stats.sent_while_off += 1;
            port.stats.first_sent_while_off.get_or_insert(t);
            lost(
                &self.trace,
                &self.name,
                &port.stats.name,
                t,
                frame,
                FrameLoss::Off,
            );
            return false;
        }
        if port.queue.len() >= limit {
            let name = &port.stats.name;
            crate::count_loss(&mut port.stats.tx_overflow, |n| {
                format!("{name}: transmit queue full ({limit} frames): frame lost ({n} so far)")
            });
            lost(
                &self.trace,
                &self.name,
                name,
                t,
                frame,
                FrameLoss::QueueFull,
            );
            return false;
        }
        port.queue.push_back((t, frame));
        port.stats.tx_queue_max = port.stats.tx_queue_max.max(port.queue.len() as u64);
        port.queue.len() == 1
    }

    /// Tell the bus task to look again: the waker to wake once the lock is let go.
    fn ring(&mut self) -> Option<Waker> {
        self.bell = true;
        self.bus_waker.take()
    }

    /// Put `d` on its way, in order.
    fn in_flight_insert(&mut self, key: (SimTime, u64), d: Delivery) {
        // Nearly always at the back: frames end in order.
        if self.in_flight.back().is_none_or(|(k, _)| *k < key) {
            self.in_flight.push_back((key, d));
            return;
        }
        let i = self.in_flight.partition_point(|(k, _)| *k < key);
        self.in_flight.insert(i, (key, d));
    }

    fn deliver_due(&mut self, now: SimTime) {
        while let Some(((t, _), _)) = self.in_flight.front() {
            if *t > now {
                return;
            }
            let Some(((t, _), d)) = self.in_flight.pop_front() else {
                return;
            };
            let (from, frame, fate) = match d {
                Delivery::Frame { from, frame, fate } => (from, frame, fate),
                Delivery::Error(ev) => {
                    if let Some(tr) = &self.trace {
                        tr.emit(TraceEvent {
                            t,
                            medium: self.name.clone(),
                            from: ev.node.clone(),
                            frame: TraceFrame::CanError(ev),
                            dropped: false,
                        });
                    }
                    continue;
                }
            };
            let dropped = matches!(fate, Fate::Drop);
            if dropped {
                self.stats.dropped += 1;
            }
            let cfp = CfpId::from_can_id(frame.id);
            let (dst, more) = (cfp.dst, self.next_on_its_way(from, &cfp));
            let claimed_by = self.claims.get(&dst).copied();
            if let Some(tr) = &self.trace {
                let sender = self
                    .ports
                    .get(from)
                    .map_or_else(|| "?".into(), |p| p.name.clone());
                // Addressed to endpoints of which none can take it: lost at the receiver.
                let addressed = self.ports.iter().enumerate().filter(|&(i, p)| {
                    i != from && p.addrs.contains(dst) && claimed_by.is_none_or(|c| c == i)
                });
                let unreceived = addressed
                    .map(|(_, p)| {
                        if !p.enabled {
                            Some(FrameLoss::Off)
                        } else if p.stats.state == ErrorState::BusOff {
                            Some(FrameLoss::BusOff)
                        } else {
                            None
                        }
                    })
                    .reduce(|a, b| a.and(b))
                    .flatten();
                tr.emit(TraceEvent {
                    t,
                    medium: self.name.clone(),
                    from: sender,
                    frame: match unreceived {
                        Some(why) if !dropped => TraceFrame::CanUnreceived(frame, why),
                        _ => TraceFrame::Can(frame),
                    },
                    dropped,
                });
            }
            if dropped {
                continue;
            }
            for (i, p) in self.ports.iter_mut().enumerate() {
                if i == from || !p.enabled || p.stats.state == ErrorState::BusOff {
                    continue;
                }
                let wants =
                    p.promiscuous || (p.addrs.contains(dst) && claimed_by.is_none_or(|c| c == i));
                if wants {
                    p.stats.frames_rx += 1;
                    p.stats.bytes_rx += u64::from(frame.dlc);
                    let a = Inbound {
                        t,
                        iface: p.iface,
                        what: Arrival::Can(frame),
                    };
                    // A frame followed on the wire wakes no node task (see
                    // `crate::inbox`).
                    p.arrivals.push((a, more));
                }
            }
        }
    }

    /// Whether the next frame of `cfp`'s packet from port `from` is on the wire, to be
    /// delivered (not dropped): a frame followed by one is quiet (see `crate::inbox`), as
    /// the next one reaches the same endpoints. Whatever else happens (the next frame
    /// dropped, not yet picked), the frame wakes its receivers, so that they meet a lost
    /// fragment's reassembly timeout in time.
    fn next_on_its_way(&self, from: usize, cfp: &CfpId) -> bool {
        if cfp.remain == 0 {
            return false;
        }
        // A port's frames cross in the order it queued them: its next frame on the wire
        // is the first of its frames in flight.
        let next = self.in_flight.iter().find_map(|(_, d)| match d {
            Delivery::Frame {
                from: f,
                frame,
                fate,
            } if *f == from => Some((frame, fate)),
            _ => None,
        });
        next.is_some_and(|(frame, fate)| {
            let n = CfpId::from_can_id(frame.id);
            matches!(fate, Fate::Deliver)
                && n.src == cfp.src
                && n.dst == cfp.dst
                && n.ident == cfp.ident
                && n.remain + 1 == cfp.remain
        })
    }

    /// Hand what [`deliver_due`](Self::deliver_due) delivered to each endpoint's inbox, in
    /// order, under one lock of each.
    fn hand_over(&mut self) {
        for p in &mut self.ports {
            if p.arrivals.is_empty() {
                continue;
            }
            for _ in 0..p.inbox.send_all(&mut p.arrivals) {
                let name = &p.stats.name;
                crate::count_loss(&mut p.stats.rx_overflow, |n| {
                    format!("{name}: inbox full: frame lost ({n} so far)")
                });
            }
        }
    }

    fn next_wake(&self) -> SimTime {
        let delivery = self.in_flight.front().map(|((t, _), _)| *t);
        let pick = self
            .candidates()
            .map(|c| c.ready)
            .min()
            .into_iter()
            .chain(self.idle_recovery())
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
///
/// A byte at a time, with no allocation: the CRC-15 (over SOF .. data) and the stuff bits
/// (SOF .. CRC) come from two tables indexed by byte ([`CRC15_TABLE`], [`STUFF_TABLE`]),
/// the few bits before the first whole byte one at a time.
pub fn frame_bits(frame: &CanFrame) -> u32 {
    let id = u64::from(frame.id & csp::cfp::CAN_EFF_MASK);
    let dlc = frame.dlc.min(8);
    // SOF 0 | base id (11) | SRR 1 | IDE 1 | extended id (18) | RTR 0 | r1 r0 00 | DLC (4).
    let header = (id >> 18) << 27 | 1 << 26 | 1 << 25 | (id & 0x3FFFF) << 7 | u64::from(dlc);
    // CRC-15 and stuffing side by side (two independent chains the CPU overlaps): the 7
    // bits before the header's last four bytes, then bytes, then the CRC's top 7 bits and
    // its last byte, each a table step.
    let top = ((header >> 32) & 0x7F) as usize;
    let mut crc = CRC15_TOP7[top];
    let e = STUFF7_TABLE[0][top];
    let mut state = e & 0xF;
    let mut stuffed = u32::from(e >> 4);
    let mut byte = |b: u8, crc: &mut u16| {
        *crc = ((*crc << 8) & 0x7FFF) ^ CRC15_TABLE[usize::from(((*crc >> 7) as u8) ^ b)];
        let e = STUFF_TABLE[usize::from(state)][usize::from(b)];
        state = e & 0xF;
        stuffed += u32::from(e >> 4);
    };
    for b in (header as u32).to_be_bytes() {
        byte(b, &mut crc);
    }
    for &b in frame.data() {
        byte(b, &mut crc);
    }
    // The CRC's 15 bits: the top 7, then a byte.
    let e = STUFF7_TABLE[usize::from(state)][usize::from((crc >> 8) as u8 & 0x7F)];
    state = e & 0xF;
    stuffed += u32::from(e >> 4);
    stuffed += u32::from(STUFF_TABLE[usize::from(state)][usize::from(crc as u8)] >> 4);
    let n = HEADER_BITS + 8 * frame.data().len() as u32 + 15;
    // CRC delimiter, ACK slot, ACK delimiter, EOF (7), intermission (3).
    n + stuffed + 1 + 1 + 1 + 7 + 3
}

/// Bits of an extended frame's header, SOF to DLC.
const HEADER_BITS: u32 = 39;

/// The CRC-15 register's change for each input byte, from a zero register.
const CRC15_TABLE: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut r = (i as u16) << 7;
        let mut k = 0;
        while k < 8 {
            r = if r & 0x4000 != 0 {
                ((r << 1) ^ 0x4599) & 0x7FFF
            } else {
                (r << 1) & 0x7FFF
            };
            k += 1;
        }
        t[i] = r;
        i += 1;
    }
    t
};

/// The stuffing state after one more bit: the state is the last bit's value (bit 3) and
/// how many equal bits end the stream (0 at the start, else 1..=4); returns the new state
/// and whether a stuff bit followed (after five equal bits a complementary bit is
/// inserted, and it starts the next run).
const fn stuff_step(state: u8, bit: u8) -> (u8, u8) {
    let (last, run) = (state >> 3, state & 7);
    let (mut last, mut run) = if run > 0 && bit == last {
        (last, run + 1)
    } else {
        (bit, 1)
    };
    let mut stuffed = 0;
    if run == 5 {
        stuffed = 1;
        last ^= 1;
        run = 1;
    }
    (last << 3 | run, stuffed)
}

/// The CRC-15 register after the frame's first 7 bits (SOF and the base id's top 6), from
/// a zero register, for each value of those bits.
const CRC15_TOP7: [u16; 128] = {
    let mut t = [0u16; 128];
    let mut i = 0;
    while i < 128 {
        let mut r = 0u16;
        let mut k = 0;
        while k < 7 {
            let bit = ((i >> (6 - k)) & 1) as u16;
            let next = (bit ^ (r >> 14)) & 1;
            r = ((r << 1) & 0x7FFF) ^ (0x4599 * next);
            k += 1;
        }
        t[i] = r;
        i += 1;
    }
    t
};

/// [`stuff_table`] for 7 bits (the header's first, the CRC's top).
const STUFF7_TABLE: [[u8; 128]; 16] = stuff_table::<128>(7);

/// [`stuff_table`] for a byte.
const STUFF_TABLE: [[u8; 256]; 16] = stuff_table::<256>(8);

/// For each stuffing state and next `bits`-bit value (`N = 2^bits` of them, most significant
/// bit first): the state after it (low 4 bits) and the stuff bits it caused (high 4 bits).
const fn stuff_table<const N: usize>(bits: usize) -> [[u8; N]; 16] {
    let mut t = [[0u8; N]; 16];
    let mut state = 0;
    while state < 16 {
        let mut v = 0;
        while v < N {
            let (mut s, mut stuffed) = (state as u8, 0);
            let mut k = 0;
            while k < bits {
                let (next, n) = stuff_step(s, ((v >> (bits - 1 - k)) & 1) as u8);
                s = next;
                stuffed += n;
                k += 1;
            }
            t[state][v] = stuffed << 4 | s;
            v += 1;
        }
        state += 1;
    }
    t
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::clock::ClockMode;
    use crate::inbox::inbox;

    /// The first implementation, bit vector and all: the reference [`frame_bits`] must match.
    fn frame_bits_reference(frame: &CanFrame) -> u32 {
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

    proptest::proptest! {
        #[test]
        fn frame_bits_equals_the_bit_vector_reference(
            id in 0u32..=csp::cfp::CAN_EFF_MASK,
            data in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..=8),
        ) {
            let f = CanFrame::new(id, &data).unwrap();
            proptest::prop_assert_eq!(frame_bits(&f), frame_bits_reference(&f));
        }

        /// Long runs of equal bits, where stuff bits chain from one run into the next.
        #[test]
        fn frame_bits_equals_the_reference_on_long_runs(
            id in proptest::sample::select(vec![0, csp::cfp::CAN_EFF_MASK, 0x1F, 0x1FFF_FFE0, 0x0F0F_0F0F, 0x1E1E_1E1E]),
            data in proptest::collection::vec(
                proptest::sample::select(vec![0x00u8, 0xFF, 0x0F, 0xF0, 0x1F, 0xF8, 0x07, 0xE0, 0x83, 0x7C]),
                0..=8,
            ),
        ) {
            let f = CanFrame::new(id, &data).unwrap();
            proptest::prop_assert_eq!(frame_bits(&f), frame_bits_reference(&f));
        }
    }

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

    /// A frame whose packet's next frame is on the wire reaches a node's inbox quietly;
    /// the packet's last frame, and a frame whose next never comes, wake the node.
    #[tokio::test(start_paused = true)]
    async fn only_a_frame_followed_on_the_wire_is_quiet() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("main"), 1);
        let (tx_a, _rx_a) = inbox();
        let (tx_b, mut rx_b) = inbox();
        rx_b.take_quiet();
        let a = bus.attach("A", &[1], false, tx_a, 0);
        let _b = bus.attach("B", &[2], false, tx_b, 0);
        tokio::spawn(bus.clone().run(clock));
        let f = |remain: u32, ident: u32, first: bool| {
            let more = u32::from(!first) << 18;
            CanFrame::new(1 << 24 | 2 << 19 | more | remain << 10 | ident, &[0; 8]).unwrap()
        };
        let frame = |a: Option<Inbound>| a.map(|a| a.what);
        a.send(SimTime::ZERO, f(1, 7, true));
        a.send(SimTime::ZERO, f(0, 7, false));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert_eq!(
            frame(rx_b.try_recv_quiet()),
            Some(Arrival::Can(f(1, 7, true)))
        );
        assert_eq!(frame(rx_b.try_recv_quiet()), None, "the last frame is loud");
        assert_eq!(
            frame(rx_b.try_recv().ok()),
            Some(Arrival::Can(f(0, 7, false)))
        );
        // The first of two frames, the second never sent (its sender lost power).
        a.send(clock.now(), f(1, 8, true));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert_eq!(frame(rx_b.try_recv_quiet()), None);
        assert_eq!(
            frame(rx_b.try_recv().ok()),
            Some(Arrival::Can(f(1, 8, true)))
        );
    }

    /// Every frame queued ends in the trace once: crossed, crossed but not taken (its
    /// receiver off), or lost before the wire (queue full, sender off), with the reason.
    #[tokio::test(start_paused = true)]
    async fn every_queued_frame_is_traced_once_with_its_fate() {
        let clock = Clock::new(ClockMode::Virtual);
        let mut cfg = CanBusConfig::new("payload");
        cfg.tx_queue_frames = 2;
        let bus = CanBus::new(cfg, 1);
        let trace = Arc::new(Mutex::new(Vec::new()));
        let sink = trace.clone();
        bus.set_trace(TraceTx::new(move |e| {
            sink.lock().unwrap().push((e.frame, e.dropped))
        }));
        let (tx_a, _ra) = inbox();
        let (tx_b, _rb) = inbox();
        let a = bus.attach("PL12", &[12], false, tx_a, 0);
        let b = bus.attach("PC", &[6], false, tx_b, 0);
        tokio::spawn(bus.clone().run(clock));
        for i in 0..3 {
            a.send(SimTime::ZERO, cfp_frame(12, 6, i));
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
        // The receiver off: its frame crosses, untaken.
        bus.set_enabled(&b, false);
        a.send(clock.now(), cfp_frame(12, 6, 3));
        tokio::time::sleep(Duration::from_millis(2)).await;
        bus.set_enabled(&b, true);
        // The sender off: queued frames and frames sent meanwhile never go out.
        a.send(clock.now(), cfp_frame(12, 6, 4));
        bus.set_enabled(&a, false);
        a.send(clock.now(), cfp_frame(12, 6, 5));
        tokio::time::sleep(Duration::from_millis(2)).await;
        let got: Vec<_> = trace.lock().unwrap().clone();
        assert_eq!(
            got,
            [
                (
                    TraceFrame::CanLost(cfp_frame(12, 6, 2), FrameLoss::QueueFull),
                    true
                ),
                (TraceFrame::Can(cfp_frame(12, 6, 0)), false),
                (TraceFrame::Can(cfp_frame(12, 6, 1)), false),
                (
                    TraceFrame::CanUnreceived(cfp_frame(12, 6, 3), FrameLoss::Off),
                    false
                ),
                (
                    TraceFrame::CanLost(cfp_frame(12, 6, 4), FrameLoss::Off),
                    true
                ),
                (
                    TraceFrame::CanLost(cfp_frame(12, 6, 5), FrameLoss::Off),
                    true
                ),
            ]
        );
        let s = bus.stats();
        assert_eq!((s.ports[0].tx_overflow, s.ports[0].off_drops), (1, 2));
        // Every frame offered is accounted for; one was handed over while off.
        assert_eq!((s.ports[0].offered, s.ports[0].unaccounted()), (6, 0));
        assert_eq!(s.ports[0].sent_while_off, 1);
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
    async fn claims_of_held_addresses_are_refused_free_ones_are_exclusive_and_down_drops() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("payload"), 1);
        let (tx_a, _ra) = inbox();
        let (tx_int, mut rx_int) = inbox();
        let (tx_out, mut rx_out) = inbox();
        let (tx_out2, mut rx_out2) = inbox();
        let a = bus.attach("PC", &[6], false, tx_a, 0);
        let _internal = bus.attach("payload12", &[12], false, tx_int, 0);
        let outside = bus.attach("kiss", &[], false, tx_out, 0);
        let outside2 = bus.attach("kiss#2", &[], false, tx_out2, 0);
        tokio::spawn(bus.clone().run(clock));
        // The twin's payload 12 keeps its address; 14 is free and becomes the link's only.
        assert_eq!(
            bus.claim(&outside, 12),
            Err(ClaimError::Node("payload12".to_owned()))
        );
        assert_eq!(bus.claim(&outside, 14), Ok(()));
        assert_eq!(
            bus.claim(&outside2, 14),
            Err(ClaimError::Held("kiss".to_owned()))
        );
        a.send(SimTime::ZERO, cfp_frame(6, 12, 0));
        a.send(SimTime::ZERO, cfp_frame(6, 14, 1));
        tokio::time::sleep(Duration::from_millis(2)).await;
        assert!(
            matches!(rx_int.try_recv().unwrap().what, Arrival::Can(f) if f == cfp_frame(6, 12, 0))
        );
        assert!(
            matches!(rx_out.try_recv().unwrap().what, Arrival::Can(f) if f == cfp_frame(6, 14, 1))
        );
        assert!(rx_out.try_recv().is_err());
        assert!(rx_out2.try_recv().is_err());
        bus.release(&outside);
        assert_eq!(bus.claim(&outside2, 14), Ok(()));
        bus.set_fault(
            0,
            Some(Impairments {
                down: true,
                ..Default::default()
            }),
        );
        a.send(clock.now(), cfp_frame(6, 12, 1));
        tokio::time::sleep(Duration::from_millis(2)).await;
        assert!(rx_int.try_recv().is_err());
        assert_eq!(bus.stats().dropped, 1);
        bus.set_fault(0, None);
        a.send(clock.now(), cfp_frame(6, 12, 2));
        tokio::time::sleep(Duration::from_millis(2)).await;
        assert!(rx_int.try_recv().is_ok());
    }

    /// A node's endpoint released (an outside program takes the node's place in a run from
    /// a snapshot) gives back the address it was attached with: a link's connection claims
    /// it, and the released place keeps its counts.
    #[test]
    fn a_released_nodes_endpoint_gives_its_address_to_a_link() {
        let bus = CanBus::new(CanBusConfig::new("payload"), 1);
        let (tx_node, _r1) = inbox();
        let (tx_link, _r2) = inbox();
        let node = bus.attach("PL12", &[12], false, tx_node, 0);
        let link = crate::reserve::LinkId(0);
        assert_eq!(
            bus.attach_claimed("hub", link, 12, tx_link.clone(), 0)
                .err(),
            Some(ClaimError::Node("PL12".to_owned()))
        );
        bus.release(&node);
        assert_eq!(bus.node_holding(12), None);
        let port = bus.attach_claimed("hub", link, 12, tx_link, 0).unwrap();
        assert_ne!(port.index(), node.index());
        assert_eq!(bus.stats().ports.len(), 2);
    }

    /// A sender whose every frame is destroyed (`corrupt` at 1.0): no frame reaches the
    /// receiver, the sender retransmits, its TEC climbs by 8 per error frame to
    /// error-passive (above 127) and bus-off (above 255), its queue is lost, and on the idle
    /// bus it recovers 128 x 11 bit times later; with the fault lifted, frames flow again.
    #[tokio::test(start_paused = true)]
    async fn a_corrupted_frame_is_never_delivered_and_its_sender_goes_bus_off_and_recovers() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("main"), 1);
        let (trace_tx, mut trace_rx) = tokio::sync::mpsc::unbounded_channel();
        bus.set_trace(TraceTx::channel(trace_tx));
        let (tx_a, _ra) = inbox();
        let (tx_b, mut rx_b) = inbox();
        let a = bus.attach("A", &[1], false, tx_a, 0);
        let _b = bus.attach("B", &[2], false, tx_b, 0);
        tokio::spawn(bus.clone().run(clock));
        bus.set_fault(
            0,
            Some(Impairments {
                corrupt_prob: 1.0,
                ..Default::default()
            }),
        );
        a.send(SimTime::ZERO, cfp_frame(1, 2, 7));
        a.send(SimTime::ZERO, cfp_frame(1, 2, 8));
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert!(rx_b.try_recv().is_err(), "a corrupted frame reached B");
        let s = bus.stats();
        let (pa, pb) = (&s.ports[0], &s.ports[1]);
        // 32 error frames take TEC from 0 to 256: bus-off, and both frames are lost.
        assert_eq!(
            (s.error_frames, s.corrupted, s.frames, s.bus_off),
            (32, 32, 0, 1)
        );
        assert_eq!((pa.tx_errors, pa.tec_max), (32, 256));
        assert_eq!(
            (pa.passive_count, pa.bus_off_count, pa.bus_off_drops),
            (1, 1, 2)
        );
        assert_eq!(pb.rec, 32);
        let mut events = Vec::new();
        while let Ok(e) = trace_rx.try_recv() {
            if let TraceFrame::CanError(c) = e.frame {
                events.push((e.t, c));
            }
        }
        assert_eq!(
            events
                .iter()
                .filter(|(_, c)| matches!(c.kind, CanErrorKind::ErrorFrame { .. }))
                .count(),
            32
        );
        let states: Vec<(SimTime, ErrorState, u16)> = events
            .iter()
            .filter_map(|(t, c)| match c.kind {
                CanErrorKind::State(s) => Some((*t, s, c.tec)),
                CanErrorKind::ErrorFrame { .. } => None,
            })
            .collect();
        assert_eq!(states.len(), 3, "{states:?}");
        assert_eq!((states[0].1, states[0].2), (ErrorState::Passive, 128));
        assert_eq!((states[1].1, states[1].2), (ErrorState::BusOff, 256));
        // Recovered on the idle bus after 128 x 11 bits (1.408 ms at 1 Mbit/s).
        assert_eq!((states[2].1, states[2].2), (ErrorState::Active, 0));
        assert_eq!(states[2].0, states[1].0 + Duration::from_micros(128 * 11));
        assert_eq!(
            (pa.state, pa.tec, pa.rec, pa.recoveries),
            (ErrorState::Active, 0, 0, 1)
        );
        // With the fault lifted, frames flow again.
        bus.set_fault(0, None);
        a.send(clock.now(), cfp_frame(1, 2, 9));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert_eq!(
            rx_b.recv().await.unwrap().what,
            Arrival::Can(cfp_frame(1, 2, 9))
        );
    }

    /// Error frames cost bus time: a half-corrupted bus carries every frame in the end
    /// (retransmitted), takes longer than a clean one, and each good frame takes one off
    /// the sender's TEC.
    #[tokio::test(start_paused = true)]
    async fn retransmissions_deliver_everything_at_the_cost_of_bus_time() {
        let run = |p: f64| async move {
            let clock = Clock::new(ClockMode::Virtual);
            let bus = CanBus::new(CanBusConfig::new("main"), 3);
            let (tx_a, _ra) = inbox();
            let (tx_b, mut rx_b) = inbox();
            let a = bus.attach("A", &[1], false, tx_a, 0);
            let _b = bus.attach("B", &[2], false, tx_b, 0);
            tokio::spawn(bus.clone().run(clock));
            bus.set_fault(
                0,
                Some(Impairments {
                    corrupt_prob: p,
                    ..Default::default()
                }),
            );
            for k in 0..20 {
                a.send(SimTime::ZERO, cfp_frame(1, 2, k));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
            let mut got = Vec::new();
            while let Ok(x) = rx_b.try_recv() {
                got.push((x.t, x.what));
            }
            (got, bus.stats())
        };
        let (clean, s0) = run(0.0).await;
        let (noisy, s1) = run(0.3).await;
        assert_eq!(clean.len(), 20);
        let frames = |v: &[(SimTime, Arrival)]| v.iter().map(|x| x.1.clone()).collect::<Vec<_>>();
        assert_eq!(
            frames(&noisy),
            frames(&clean),
            "every frame, in order, intact"
        );
        assert!(s1.error_frames > 0 && s1.ports[0].state == ErrorState::Active);
        assert!(noisy.last().unwrap().0 > clean.last().unwrap().0);
        assert!(s1.busy > s0.busy);
        // TEC: +8 per error, -1 per good frame, never below zero.
        let tec = s1.ports[0].tec;
        assert!(tec <= 8 * s1.error_frames as u16, "{tec}");
    }

    /// A babbler with id between two senders' ids: the lower one's frames win every
    /// arbitration and flow on time, the higher one's wait for the babble to stop, and the
    /// babbler fills every gap in between.
    #[tokio::test(start_paused = true)]
    async fn a_babbler_starves_higher_ids_only() {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("main"), 1);
        let (tx_a, _ra) = inbox();
        let (tx_b, _rb) = inbox();
        let (tx_c, _rc) = inbox();
        let (tx_d, mut rx_d) = inbox();
        let a = bus.attach("A", &[1], false, tx_a, 0);
        let _b = bus.attach("B", &[5], false, tx_b, 0);
        let c = bus.attach("C", &[9], false, tx_c, 0);
        let _d = bus.attach("D", &[20], false, tx_d, 0);
        tokio::spawn(bus.clone().run(clock));
        let ms = SimTime::from_ms;
        bus.set_can_fault(
            3,
            Some(CanFault::Babble {
                node: "B".into(),
                can_id: 5 << 24,
                period: None,
                from: ms(5),
                until: Some(ms(15)),
            }),
        );
        for k in 0..20u32 {
            a.send(ms(u64::from(k)), cfp_frame(1, 20, k));
            c.send(ms(u64::from(k)), cfp_frame(9, 20, k));
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
        let mut got = Vec::new();
        while let Ok(x) = rx_d.try_recv() {
            if let Arrival::Can(f) = x.what {
                got.push((x.t, CfpId::from_can_id(f.id).src, f.id & 0x3ff));
            }
        }
        for (t, src, k) in &got {
            let sent = ms(u64::from(*k));
            let late = *t - sent;
            match src {
                1 => assert!(late < Duration::from_micros(500), "A's {k} waited {late:?}"),
                _ if (5..15).contains(k) => assert!(*t >= ms(15), "C's {k} got through at {t}"),
                _ => {}
            }
        }
        assert_eq!(got.len(), 40, "everything arrives in the end");
        let s = bus.stats();
        // The babbler's frames (149 bits) fill the 10 ms but for A's 10 frames: 57.
        assert_eq!(s.ports[1].frames_tx, 57, "{:?}", s.ports[1]);
    }

    /// A sender with the lowest id and a full queue (a runaway program) holds everyone
    /// above it off the bus until its queue drains; with a transmit budget of 1000 frames a
    /// second it sends a tenth of a second's worth back to back, then one a millisecond,
    /// and a higher id's frame waits for one of its frames at most.
    #[tokio::test(start_paused = true)]
    async fn a_transmit_budget_leaves_the_bus_to_higher_ids() {
        for budget in [None, Some(TxBudget::per_second(1000))] {
            let clock = Clock::new(ClockMode::Virtual);
            let bus = CanBus::new(CanBusConfig::new("main"), 1);
            let (tx_a, _ra) = inbox();
            let (tx_b, _rb) = inbox();
            let (tx_d, mut rx_d) = inbox();
            let a = bus.attach("A", &[1], false, tx_a, 0);
            let b = bus.attach("B", &[9], false, tx_b, 0);
            let _d = bus.attach("D", &[20], false, tx_d, 0);
            bus.set_tx_budget(&a, budget);
            tokio::spawn(bus.clone().run(clock));
            for k in 0..1000u32 {
                a.send(SimTime::ZERO, cfp_frame(1, 20, k));
            }
            // A's queue takes ~150 ms unbudgeted.
            tokio::time::sleep(Duration::from_millis(50)).await;
            let sent_at = clock.now();
            b.send(sent_at, cfp_frame(9, 20, 7));
            tokio::time::sleep(Duration::from_secs(2)).await;
            let mut b_late = None;
            let mut a_last = SimTime::ZERO;
            while let Ok(x) = rx_d.try_recv() {
                if let Arrival::Can(f) = x.what {
                    match CfpId::from_can_id(f.id).src {
                        9 => b_late = Some(x.t - sent_at),
                        _ => a_last = a_last.max(x.t),
                    }
                }
            }
            let b_late = b_late.unwrap();
            let s = bus.stats();
            assert_eq!(s.ports[0].frames_tx, 1000);
            match budget {
                // 1000 frames of ~130 us: B's frame waits for the rest of A's queue.
                None => {
                    assert_eq!(s.ports[0].budget_held, 0);
                    assert!(b_late > Duration::from_millis(50), "B waited {b_late:?}");
                }
                // 100 at once, then one a millisecond: the last at 0.9 s.
                Some(_) => {
                    assert!(b_late < Duration::from_micros(300), "B waited {b_late:?}");
                    assert_eq!(s.ports[0].budget_held, 900);
                    assert!(
                        a_last > SimTime::from_ms(899) && a_last < SimTime::from_ms(901),
                        "A's last frame at {a_last}"
                    );
                }
            }
        }
    }
}
