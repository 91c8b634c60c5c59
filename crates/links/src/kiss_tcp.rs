//! KISS over TCP links (ICD 2.3): CSP packets in libcsp 1.4's KISS framing on a TCP
//! stream, for programs outside the twin.
//!
//! - [`serve`] listens (127.0.0.1 by default) and accepts any number of outside nodes, one
//!   connection each; [`connect`] is the platform's side of ICD 2.3, a client that connects
//!   to the payload's server and reconnects with back-off (0.5 s doubling to 10 s).
//! - The CSP addresses behind a connection are the link's configured ones, claimed when it
//!   connects (so a program that only answers is reachable), or, on a link without any,
//!   learned from the source of its packets; the segment follows the address range
//!   ([`bus::outside`]). An address held by a node of the twin or by another connection
//!   cannot be claimed: the packet is refused, counted and logged (WARN, once per address
//!   and connection), and on a link with configured addresses any other source is refused.
//! - Everything is bounded ([`KissLimits`]): connections per listener, chunks read ahead of
//!   the twin (the reader then stops reading: TCP back-pressure), frames waiting for a slow
//!   reader (dropped and counted, never stalling the twin or other connections).
//! - Garbage bytes, bad CRCs, short and oversize frames and disconnects are counted and
//!   logged; the twin keeps running and accepts new connections.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::SimTime;
use csp::kiss::{self, Decoder, DecoderConfig, KissDrop, KissEvent};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use bus::can::TxBudget;
use bus::clock::Clock;
use bus::gate::{DelayLine, LinkGate, Passage};
use bus::inbox::{Inbound, inbox};
use bus::outside::{OutsideEndpoint, OutsideError, SegmentKind, Segments};
use csp::udp::UdpDrop;
use csp::zmqhub::HubDrop;

/// The bounds of a KISS/TCP link, each with the real-world thing it models.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KissLimits {
    /// Connections a listener serves at once (more are accepted, logged and closed).
    pub max_connections: usize,
    /// Chunks (of up to 4 KiB) read from a connection ahead of the twin: a serial port's
    /// receive buffer. When full the reader stops reading and TCP holds the sender back.
    pub input_chunks: usize,
    /// KISS frames waiting for a connection's reader: a UART's transmit FIFO. A frame
    /// that finds it full is dropped and counted (`out_dropped`); the twin never waits for
    /// a program that does not read.
    pub output_frames: usize,
    /// How long a listener's connection that holds no address (it has sent nothing the
    /// twin took, on a link that learns its addresses) may go without a byte either way
    /// before it is closed, on the wall clock; `None`: never. A connection with an address
    /// is a node of the network and stays however quiet it is (a payload waiting for its
    /// next session); a full listener closes its longest-idle connection instead.
    pub idle_timeout: Option<Duration>,
}

impl Default for KissLimits {
    fn default() -> Self {
        KissLimits {
            max_connections: 16,
            input_chunks: 16,
            output_frames: 256,
            idle_timeout: Some(Duration::from_secs(60)),
        }
    }
}

/// Receives a link's warnings for the run's log: `(time, link or connection name, text)`.
#[derive(Clone)]
pub struct KissLog(Arc<LogFn>);

type LogFn = dyn Fn(SimTime, &str, String) + Send + Sync;

impl KissLog {
    /// A log calling `f`.
    pub fn new(f: impl Fn(SimTime, &str, String) + Send + Sync + 'static) -> Self {
        KissLog(Arc::new(f))
    }
}

impl std::fmt::Debug for KissLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("KissLog")
    }
}

/// Settings of a KISS/TCP link.
#[derive(Debug, Clone, Default)]
pub struct KissLinkConfig {
    /// Addresses behind the link, claimed when a connection opens; packets from any other
    /// source are refused. Empty: learn them from the sources of received packets.
    pub addrs: Vec<u8>,
    /// Its bounds.
    pub limits: KissLimits,
    /// Where its warnings go besides `tracing` (the run's log).
    pub log: Option<KissLog>,
    /// Receiver settings (the v1.4 248-byte limit is off by default).
    pub decoder: DecoderConfig,
    /// Where the raw bytes crossing the socket go (the recorder).
    pub tap: Option<KissTap>,
    /// The link's faults and power ([`bus::gate`]); `None`: everything crosses.
    pub gate: Option<LinkGate>,
    /// How packets are framed on it: KISS, or libcsp 1.4's ZMQ hub messages.
    pub framing: Framing,
    /// Which of the run's links it is: its configured addresses are reserved for it
    /// ([`bus::outside::Segments::reserve`]).
    pub link: bus::outside::LinkId,
    /// At most this many CAN frames a second from each of its connections on a CAN bus
    /// ([`bus::can::TxBudget`]); `None`: as many as the bus takes.
    pub tx_frames_per_s: Option<u32>,
}

/// How a link frames packets.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Framing {
    /// libcsp 1.4's KISS on a byte stream (TCP, a pty); one segment per connection.
    #[default]
    Kiss,
    /// libcsp 1.4's ZMQ hub: one message per packet (`csp::zmqhub`). Its programs may sit
    /// on several segments (an address's range decides), and a packet between two of them
    /// goes straight across the hub, as libcsp's own hub forwards it.
    ZmqHub,
    /// CSP over UDP: one datagram per packet (`csp::udp`), one segment as on KISS.
    Udp,
}

/// Where a link's frames towards the outside go: a byte stream ([`Stream`]) or a message
/// socket (the ZMQ hub).
pub trait FrameSink {
    /// Send one whole frame (a KISS frame, a hub message).
    fn send_frame(&mut self, frame: &[u8]) -> impl Future<Output = std::io::Result<()>>;
}

/// A byte stream as a [`FrameSink`].
#[derive(Debug)]
pub struct Stream<W>(pub W);

impl<W: AsyncWrite + Unpin> FrameSink for Stream<W> {
    async fn send_frame(&mut self, frame: &[u8]) -> std::io::Result<()> {
        self.0.write_all(frame).await
    }
}

/// Receives every chunk read from and every frame written to a link's socket:
/// `(time, link name, true = into the twin, bytes)`.
///
/// With a budget ([`KissTap::with_budget`]) a link takes a permit before it hands a chunk
/// read from its socket to the tap, and whoever consumes the tapped chunks gives permits
/// back: a link reads no faster than the run records (TCP holds the program back).
#[derive(Clone)]
pub struct KissTap(Arc<TapFn>, Option<Arc<tokio::sync::Semaphore>>);

type TapFn = dyn Fn(SimTime, &str, bool, &[u8]) + Send + Sync;

impl KissTap {
    /// A tap calling `f`.
    pub fn new(f: impl Fn(SimTime, &str, bool, &[u8]) + Send + Sync + 'static) -> Self {
        KissTap(Arc::new(f), None)
    }
    /// A tap calling `f` for at most `budget`'s permits of chunks into the twin not yet
    /// consumed (the consumer calls `budget.add_permits(1)` for each).
    pub fn with_budget(
        f: impl Fn(SimTime, &str, bool, &[u8]) + Send + Sync + 'static,
        budget: Arc<tokio::sync::Semaphore>,
    ) -> Self {
        KissTap(Arc::new(f), Some(budget))
    }
    /// Wait for a permit to tap a chunk into the twin (none without a budget).
    async fn reserve(&self) -> Option<tokio::sync::OwnedSemaphorePermit> {
        match &self.1 {
            Some(b) => b.clone().acquire_owned().await.ok(),
            None => None,
        }
    }
}

/// Where a chunk taken in is recorded, with its permit of the run's budget.
struct TapIn(Option<(KissTap, Option<tokio::sync::OwnedSemaphorePermit>)>);

impl TapIn {
    /// The link's tap, once a permit is free.
    async fn reserve(cfg: &KissLinkConfig) -> TapIn {
        match &cfg.tap {
            Some(tap) => TapIn(Some((tap.clone(), tap.reserve().await))),
            None => TapIn(None),
        }
    }

    /// Record `chunk` into the twin at `t`; the permit goes with it (its consumer gives
    /// one back).
    fn record(self, t: SimTime, name: &str, chunk: &[u8]) {
        if let Some((tap, permit)) = self.0 {
            (tap.0)(t, name, true, chunk);
            if let Some(p) = permit {
                p.forget();
            }
        }
    }
}

/// A connection's open or end, taken in at the run's next idle point ([`bus::pace`]):
/// recorded there as an empty chunk (a replay opens or closes the connection then, in the
/// same order with the rest of the input); returns that instant.
pub async fn edge(clock: Clock, cfg: &KissLinkConfig, name: &str) -> SimTime {
    edge_queued(clock, cfg, name).await.await
}

/// [`edge`], in two steps: once a place in the run's budget is free it is queued, and the
/// future returned resolves to the instant it is taken in.
pub async fn edge_queued(
    clock: Clock,
    cfg: &KissLinkConfig,
    name: &str,
) -> impl std::future::Future<Output = SimTime> + Send + 'static {
    let tap = TapIn::reserve(cfg).await;
    let name = name.to_owned();
    let (tx, rx) = tokio::sync::oneshot::channel();
    bus::pace::take_in(clock, move |t| {
        tap.record(t, &name, &[]);
        let _ = tx.send(t);
    });
    async move { rx.await.unwrap_or_else(|_| clock.now()) }
}

/// Take `input` into connection `name` at the run's next idle point ([`bus::pace`]),
/// stamped with that instant: recorded then (an end as an empty chunk; an empty message is
/// not recorded, since a recording's empty chunk is an open or a close) and handed to the
/// connection's core on `slot`. Waits for a place in the run's budget first.
pub async fn take_in(
    clock: Clock,
    cfg: &KissLinkConfig,
    name: &str,
    slot: tokio::sync::mpsc::OwnedPermit<(SimTime, LinkInput)>,
    input: LinkInput,
) {
    let tap = TapIn::reserve(cfg).await;
    let name = name.to_owned();
    bus::pace::take_in(clock, move |t| {
        match &input {
            LinkInput::Bytes(b) if b.is_empty() => {}
            LinkInput::Bytes(b) => tap.record(t, &name, b),
            LinkInput::End => tap.record(t, &name, &[]),
        }
        slot.send((t, input));
    });
}

impl std::fmt::Debug for KissTap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("KissTap")
    }
}

/// Counters of a KISS/TCP link, over all its connections.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct KissLinkStats {
    /// Connections accepted or made.
    pub connections: u64,
    /// Connections closed or failed.
    pub disconnects: u64,
    /// Packets taken into the twin.
    pub packets_in: u64,
    /// Packets sent to the outside program.
    pub packets_out: u64,
    /// Bytes read from the socket.
    pub bytes_in: u64,
    /// Bytes written to the socket.
    pub bytes_out: u64,
    /// Bytes outside any frame (garbage between frames).
    pub garbage_bytes: u64,
    /// Frames with a bad KISS CRC.
    pub bad_crc: u64,
    /// Frames too short for header and CRC.
    pub short: u64,
    /// Frames over the MTU.
    pub oversize: u64,
    /// Packets refused (bad source address, wrong segment, too long for CAN, an address
    /// held by someone else, a full transmit queue).
    pub refused: u64,
    /// Of those, packets whose source address is held by a node of the twin or another
    /// connection, or is not one of the link's configured addresses.
    pub claims_refused: u64,
    /// Of those, packets the CAN transmit queue could not take whole.
    pub queue_full: u64,
    /// Frames to the outside program dropped because it did not read them in time.
    pub out_dropped: u64,
    /// Connections closed for holding no address and moving no byte for `idle_timeout`.
    pub idle_closed: u64,
    /// Connections closed to make room in a full listener (the longest idle of those that
    /// hold no address).
    pub evicted: u64,
    /// Connections refused by a full listener whose every connection holds an address.
    pub connections_refused: u64,
}

/// A listener's connection as its listener sees it: when it last moved a byte (either
/// way, on the wall clock: idleness is the program's and the network's, not simulated
/// time's), whether it holds an address, and how to close it.
#[derive(Debug)]
pub struct Liveness {
    base: std::time::Instant,
    last_ns: std::sync::atomic::AtomicU64,
    named: std::sync::atomic::AtomicBool,
    close: tokio::sync::Notify,
    closing: Mutex<Option<Closing>>,
}

/// Why a listener closed one of its connections.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Closing {
    /// It held no address and moved no byte for this long.
    Idle(Duration),
    /// The listener was full, and of its connections holding no address it had been idle
    /// longest (this long): closed for a new connection from this peer.
    MadeRoom {
        /// How long it had been idle.
        idle: Duration,
        /// Who connected.
        for_peer: SocketAddr,
    },
}

impl std::fmt::Display for Closing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Closing::Idle(d) => write!(
                f,
                "closed: no address and no byte for {:.1} s",
                d.as_secs_f64()
            ),
            Closing::MadeRoom { idle, for_peer } => write!(
                f,
                "closed to make room for {for_peer}: the listener was full and this connection, holding no address, the longest idle ({:.1} s)",
                idle.as_secs_f64()
            ),
        }
    }
}

impl Default for Liveness {
    fn default() -> Self {
        Liveness {
            base: std::time::Instant::now(),
            last_ns: Default::default(),
            named: Default::default(),
            close: tokio::sync::Notify::new(),
            closing: Mutex::new(None),
        }
    }
}

impl Liveness {
    /// A byte moved now.
    fn touch(&self) {
        let ns = u64::try_from(self.base.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.last_ns.store(ns, std::sync::atomic::Ordering::Relaxed);
    }
    /// Time since the last byte (or the connection's start).
    fn idle(&self) -> Duration {
        let last = Duration::from_nanos(self.last_ns.load(std::sync::atomic::Ordering::Relaxed));
        self.base.elapsed().saturating_sub(last)
    }
    /// Whether it holds an address.
    fn named(&self) -> bool {
        self.named.load(std::sync::atomic::Ordering::Relaxed)
    }
    /// Close it, for `why` (the first reason given stands).
    fn close(&self, why: Closing) {
        let mut c = self
            .closing
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if c.is_none() {
            *c = Some(why);
            self.close.notify_one();
        }
    }
    fn closing(&self) -> Option<Closing> {
        *self
            .closing
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// A listener's live connections by number.
type Registry = Mutex<std::collections::BTreeMap<u64, Arc<Liveness>>>;

/// Close every connection of `registry` that holds no address and has been idle for
/// `limit`, looking every quarter second (or `limit`, if shorter) on a thread of its own:
/// wall-clock sleeps, which a run on tokio's paused clock never sees. Ends with the
/// listener.
fn sweep_idle(registry: std::sync::Weak<Registry>, limit: Duration) {
    let every = limit.clamp(Duration::from_millis(10), Duration::from_millis(250));
    let _ = std::thread::Builder::new()
        .name("kiss-idle".into())
        .spawn(move || {
            loop {
                std::thread::sleep(every);
                let Some(reg) = registry.upgrade() else {
                    return;
                };
                let conns = reg
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                for l in conns.values() {
                    let idle = l.idle();
                    if !l.named() && idle >= limit {
                        l.close(Closing::Idle(idle));
                    }
                }
            }
        });
}

/// Takes a connection out of its listener's registry when it ends.
struct Registered(Arc<Registry>, u64);

impl Drop for Registered {
    fn drop(&mut self) {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .remove(&self.1);
    }
}

/// What a link takes in from its socket, each stamped with the instant it was taken in.
///
/// The end of the input is its own variant, never an empty chunk: a message socket (the
/// ZMQ hub) can deliver an empty message, and that is a malformed message, not a close.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkInput {
    /// Bytes read: a piece of a stream, or one whole message.
    Bytes(Vec<u8>),
    /// The input ended: the peer closed, a read failed, or a recording's close.
    End,
}

/// A link's input channel: what it takes in, in order.
pub type InputRx = tokio::sync::mpsc::Receiver<(SimTime, LinkInput)>;

/// Shared counters of a link.
pub type SharedStats = Arc<Mutex<KissLinkStats>>;

/// A task of a link that ends with it, however the link ends (its task aborted at the end
/// of the run included).
pub(crate) struct AbortOnDrop(pub(crate) tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

pub(crate) fn bump(stats: &SharedStats, f: impl FnOnce(&mut KissLinkStats)) {
    f(&mut stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner));
}

/// Accept outside nodes on `listener` forever, `cfg.limits.max_connections` at a time: a
/// new connection to a full listener closes the longest-idle connection that holds no
/// address (logged), and a connection that holds no address is closed after
/// `cfg.limits.idle_timeout` without a byte, so idle connections never lock others out. A
/// connection holding an address (a payload waiting for its session) is never closed to
/// make room: were it, another connection could take its address. When every connection
/// holds one, the new connection is refused (logged).
pub async fn serve(
    listener: TcpListener,
    label: String,
    segs: Segments,
    cfg: KissLinkConfig,
    stats: SharedStats,
    clock: Clock,
) {
    let mut n = 0u64;
    let registry: Arc<Registry> = Arc::default();
    if let Some(limit) = cfg.limits.idle_timeout {
        sweep_idle(Arc::downgrade(&registry), limit);
    }
    loop {
        match listener.accept().await {
            Ok((stream, peer)) => {
                let limit = cfg.limits.max_connections;
                // Those closing already are on their way out: they hold no place.
                let (full, longest_idle) = {
                    let conns = registry
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner);
                    let open = conns.values().filter(|l| l.closing().is_none());
                    let full = open.count() >= limit;
                    let idle = conns
                        .iter()
                        .filter(|(_, l)| l.closing().is_none() && !l.named())
                        .max_by_key(|(_, l)| l.idle())
                        .map(|(&k, l)| (k, l.clone()));
                    (full, idle)
                };
                match (full, longest_idle) {
                    (false, _) => {}
                    (true, Some((k, l))) => {
                        let why = Closing::MadeRoom {
                            idle: l.idle(),
                            for_peer: peer,
                        };
                        l.close(why);
                        bump(&stats, |s| s.evicted += 1);
                        warn(&cfg, clock.now(), &format!("{label}#{k}"), why.to_string());
                    }
                    (true, None) => {
                        bump(&stats, |s| s.connections_refused += 1);
                        warn(
                            &cfg,
                            clock.now(),
                            &label,
                            format!(
                                "connection from {peer} refused: {limit} connections, each holding an address"
                            ),
                        );
                        drop(stream);
                        continue;
                    }
                }
                n = n.wrapping_add(1);
                tracing::info!(%peer, "KISS/TCP: outside node connected");
                bump(&stats, |s| s.connections += 1);
                let (segs, cfg, stats, label) =
                    (segs.clone(), cfg.clone(), stats.clone(), label.clone());
                let _ = stream.set_nodelay(true);
                let live = Arc::new(Liveness::default());
                registry
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .insert(n, live.clone());
                let registered = Registered(registry.clone(), n);
                tokio::spawn(async move {
                    let _registered = registered;
                    let why =
                        run_numbered(stream, &label, n, &segs, &cfg, &stats, clock, Some(&live))
                            .await;
                    tracing::info!(%peer, "KISS/TCP: connection closed: {why}");
                    bump(&stats, |s| s.disconnects += 1);
                });
            }
            Err(e) => {
                tracing::warn!("KISS/TCP: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

/// A warning of link `name` at `t`: to `tracing` and to the run's log.
fn warn(cfg: &KissLinkConfig, t: SimTime, name: &str, text: String) {
    tracing::warn!("{name}: {text}");
    if let Some(log) = &cfg.log {
        (log.0)(t, name, text);
    }
}

/// Connect to an outside server at `addr` and keep reconnecting with back-off.
pub async fn connect(
    addr: SocketAddr,
    label: String,
    segs: Segments,
    cfg: KissLinkConfig,
    stats: SharedStats,
    clock: Clock,
) {
    let mut backoff = Duration::from_millis(500);
    let mut n = 0u64;
    loop {
        match TcpStream::connect(addr).await {
            Ok(stream) => {
                n = n.wrapping_add(1);
                backoff = Duration::from_millis(500);
                tracing::info!(%addr, "KISS/TCP: connected to outside server");
                bump(&stats, |s| s.connections += 1);
                let _ = stream.set_nodelay(true);
                let why = run_numbered(stream, &label, n, &segs, &cfg, &stats, clock, None).await;
                tracing::info!(%addr, "KISS/TCP: connection closed: {why}");
                bump(&stats, |s| s.disconnects += 1);
            }
            Err(e) => tracing::debug!(%addr, "KISS/TCP: connect failed: {e}; retry in {backoff:?}"),
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(10));
    }
}

/// Serve connection `n` of link `label` (named `label#n`), opened now, until it closes (or
/// its listener closes it through `live`).
#[allow(clippy::too_many_arguments)]
pub(crate) async fn run_numbered<S: AsyncRead + AsyncWrite + Unpin>(
    stream: S,
    label: &str,
    n: u64,
    segs: &Segments,
    cfg: &KissLinkConfig,
    stats: &SharedStats,
    clock: Clock,
    live: Option<&Liveness>,
) -> String {
    let name = format!("{label}#{n}");
    let opened = edge(clock, cfg, &name).await;
    let k = Connection {
        name: &name,
        segs,
        cfg,
        stats,
        n,
        clock,
        opened,
        live,
    };
    run_connection(stream, k).await
}

/// Serve one connection of link `name`, opened already ([`edge`]), until it closes; returns
/// why it closed. Generic over the stream; what is read is taken in at the run's idle
/// points ([`take_in`]).
pub async fn run_connection<S: AsyncRead + AsyncWrite + Unpin>(
    stream: S,
    k: Connection<'_>,
) -> String {
    let (cfg, clock, live, name, stats) = (k.cfg, k.clock, k.live, k.name, k.stats);
    let (mut rd, wr) = tokio::io::split(stream);
    // Bounded: when the twin has not taken `input_chunks` chunks yet, the reader waits and
    // TCP holds the sender back.
    let (in_tx, in_rx) = tokio::sync::mpsc::channel(cfg.limits.input_chunks.max(1));
    let reader = async move {
        let mut buf = vec![0u8; 4096];
        // Each piece is taken in at the run's next idle point, with its place in the link's
        // channel held first (so that handing it over never waits).
        let hand = |input: LinkInput| {
            let tx = in_tx.clone();
            async move {
                match tx.reserve_owned().await {
                    Ok(slot) => {
                        take_in(clock, cfg, name, slot, input).await;
                        true
                    }
                    Err(_) => false,
                }
            }
        };
        loop {
            let read = match live {
                Some(l) => tokio::select! {
                    biased;
                    () = l.close.notified() => None,
                    r = rd.read(&mut buf) => Some(r),
                },
                None => Some(rd.read(&mut buf).await),
            };
            let Some(read) = read else {
                // Closed by its listener: logged, and ended as a close is.
                // An idle close is logged here (the sweeper is a thread of its own, outside
                // the run); one to make room, by the listener that decided it.
                let why = live.and_then(Liveness::closing);
                if let Some(w @ Closing::Idle(_)) = why {
                    bump(stats, |s| s.idle_closed += 1);
                    warn(cfg, clock.now(), name, w.to_string());
                }
                let why =
                    why.map_or_else(|| "closed by its listener".to_owned(), |w| w.to_string());
                hand(LinkInput::End).await;
                return why;
            };
            if let Some(l) = live {
                l.touch();
            }
            match read {
                Ok(0) => {
                    hand(LinkInput::End).await;
                    return "peer closed".to_owned();
                }
                Ok(k) => {
                    let bytes = buf.get(..k).unwrap_or_default().to_vec();
                    if !hand(LinkInput::Bytes(bytes)).await {
                        return "link closed".to_owned();
                    }
                }
                Err(e) => {
                    hand(LinkInput::End).await;
                    return format!("read error: {e}");
                }
            }
        }
    };
    let mut wr = Stream(wr);
    let link = serve_link(in_rx, &mut wr, k);
    tokio::pin!(link);
    tokio::select! {
        biased;
        why = &mut link => why,
        why = reader => {
            // The reader's end closed the link's input: let the link take what was read and
            // record the close before it gives its addresses back.
            let _ = link.await;
            why
        }
    }
}

/// The link's core: time-stamped input chunks in, KISS frames out to `stream`. Every
/// connection has its own name (`listen 127.0.0.1:52001#2` for the second one). `replay` feeds
/// it recorded chunks with their recorded times. Ends when the input ends or a write fails.
///
/// Every packet crossing, in either direction, passes the link's gate (`cfg.gate`): it
/// crosses now, waits out a delay, or is lost (counted by the gate). The bytes read are
/// recorded whatever the gate decides; a packet towards the outside is written (and
/// recorded) when it crosses. Frames towards the outside wait in a queue of
/// `cfg.limits.output_frames` for the socket: when the program does not read, they are
/// dropped and counted, and the twin goes on.
pub async fn serve_link<W: FrameSink>(input: InputRx, stream: &mut W, k: Connection<'_>) -> String {
    let (name, cfg, stats) = (k.name, k.cfg, k.stats);
    let (out_tx, mut out_rx) =
        tokio::sync::mpsc::channel::<(SimTime, Vec<u8>)>(cfg.limits.output_frames.max(1));
    let writer = async {
        while let Some((t, frame)) = out_rx.recv().await {
            if let Err(e) = write_out(stream, name, cfg, stats, t, &frame).await {
                return format!("write error: {e}");
            }
            if let Some(l) = k.live {
                l.touch();
            }
        }
        "link closed".to_owned()
    };
    let core = link_core(input, out_tx, k);
    tokio::pin!(core);
    tokio::select! {
        biased;
        why = &mut core => why,
        why = writer => {
            // A failed write ends the connection: recorded as its close (an empty chunk)
            // before the core, and with it the connection's addresses, goes (on return).
            edge(k.clock, cfg, name).await;
            why
        }
    }
}

/// One connection of a link: what its tasks share.
#[derive(Debug, Clone, Copy)]
pub struct Connection<'a> {
    /// The link's name and the connection's number: `listen 127.0.0.1:52001#2`.
    pub name: &'a str,
    /// The twin's segments it joins.
    pub segs: &'a Segments,
    /// The link's configuration.
    pub cfg: &'a KissLinkConfig,
    /// The link's counters.
    pub stats: &'a SharedStats,
    /// The connection's number (it seeds the connection's CFP idents).
    pub n: u64,
    /// The run's clock.
    pub clock: Clock,
    /// When the connection opened (a replay: when the recorded one did).
    pub opened: SimTime,
    /// How its listener sees it (a listener's connections only).
    pub live: Option<&'a Liveness>,
}

impl<'a> Connection<'a> {
    /// The one connection of a link that is a single connection for the whole run (the ZMQ
    /// hub, a UDP link): number 1, no listener.
    pub fn whole_run(
        name: &'a str,
        segs: &'a Segments,
        cfg: &'a KissLinkConfig,
        stats: &'a SharedStats,
        clock: Clock,
        opened: SimTime,
    ) -> Self {
        Connection {
            name,
            segs,
            cfg,
            stats,
            n: 1,
            clock,
            opened,
            live: None,
        }
    }
}

/// What a connection learned or refused so far.
struct Conn<'a> {
    k: Connection<'a>,
    inbox: bus::inbox::InboxTx,
    /// Released however the link ends (the future dropped too): the addresses go back.
    claims: Claims,
    /// Addresses whose refusal was logged already (once per address and connection).
    warned: std::collections::BTreeSet<u8>,
    /// Whether the output queue's overflow was logged in this episode.
    out_full: bool,
}

async fn link_core(
    mut input: InputRx,
    out: tokio::sync::mpsc::Sender<(SimTime, Vec<u8>)>,
    k: Connection<'_>,
) -> String {
    let Connection {
        name,
        cfg,
        stats,
        clock,
        ..
    } = k;
    let (inbox_tx, mut inbox_rx) = inbox();
    let mut c = Conn {
        k,
        inbox: inbox_tx,
        claims: Claims(Vec::new()),
        warned: std::collections::BTreeSet::new(),
        out_full: false,
    };
    c.claim_configured();
    let mut decoder = Decoder::new(cfg.decoder);
    let mut events = Vec::new();
    let mut frame = Vec::new();
    // Packets waiting out a `delay` fault, into the twin and out of it.
    let mut delayed_in: DelayLine<csp::Packet> = DelayLine::default();
    let mut delayed_out: DelayLine<Vec<u8>> = DelayLine::default();
    loop {
        let next_due = [delayed_in.next_due(), delayed_out.next_due()]
            .into_iter()
            .flatten()
            .min();
        tokio::select! {
            biased;
            () = clock.sleep_until(next_due.unwrap_or(SimTime::MAX)), if next_due.is_some() => {
                let now = next_due.unwrap_or(SimTime::MAX);
                while let Some((t, p)) = delayed_in.pop_due(now) {
                    c.take_in(&out, t, &p);
                }
                while let Some((t, bytes)) = delayed_out.pop_due(now) {
                    c.put_out(&out, t, bytes);
                }
            }
            r = input.recv() => {
                // The input's end (at the time the close was seen, or the channel's end) is
                // recorded as an empty chunk (the second, after the open's): a replay closes
                // the connection at that time, giving its addresses back as the original did.
                let (t, chunk) = match r {
                    Some((t, LinkInput::Bytes(chunk))) => (t, chunk),
                    // Recorded when it was taken in; a channel that ends without an end
                    // (its reader gone) ends the link now.
                    Some((_, LinkInput::End)) => break "peer closed".to_owned(),
                    None => {
                        if let Some(tap) = &cfg.tap {
                            (tap.0)(clock.now(), name, true, &[]);
                        }
                        break "peer closed".to_owned();
                    }
                };
                if chunk.is_empty() {
                    // Only a message socket gives nothing but a message (a stream's empty
                    // read is its end): a malformed hub message, dropped and counted. Not
                    // tapped: a recording's empty chunk is the connection's open or close.
                    bump(stats, |s| s.short += 1);
                    tracing::debug!("{name}: dropped an empty message");
                    continue;
                }
                // Recorded when it was taken in (`take_in`).
                decode_chunk(k, &mut decoder, &chunk, &mut events);
                c.pass_in(&out, t, &mut events, &mut delayed_in);
            }
            a = inbox_rx.recv() => {
                let Some(a) = a else { break "inbox closed".to_owned() };
                c.pass_out(&out, a, &mut frame, &mut delayed_out);
            }
        }
    }
}

/// Decode a chunk read into `events` (KISS frames or a hub message), counting bytes and drops.
fn decode_chunk(
    k: Connection<'_>,
    decoder: &mut Decoder,
    chunk: &[u8],
    events: &mut Vec<KissEvent>,
) {
    let (name, cfg, stats) = (k.name, k.cfg, k.stats);
    match cfg.framing {
        Framing::Kiss => {
            let before = decoder.stats();
            decoder.push(chunk, events);
            let after = decoder.stats();
            bump(stats, |s| {
                s.bytes_in += chunk.len() as u64;
                s.garbage_bytes += after.discarded_bytes - before.discarded_bytes;
            });
        }
        Framing::ZmqHub => {
            bump(stats, |s| s.bytes_in += chunk.len() as u64);
            match csp::zmqhub::decode(chunk) {
                Ok((_via, p)) => events.push(KissEvent::Packet(p)),
                Err(d) => {
                    tracing::debug!("{name}: dropped hub message: {d}");
                    bump(stats, |s| match d {
                        HubDrop::Short => s.short += 1,
                        HubDrop::Oversize => s.oversize += 1,
                    });
                }
            }
        }
        Framing::Udp => {
            bump(stats, |s| s.bytes_in += chunk.len() as u64);
            match csp::udp::decode(chunk) {
                Ok(p) => events.push(KissEvent::Packet(p)),
                Err(d) => {
                    tracing::debug!("{name}: dropped datagram: {d}");
                    bump(stats, |s| match d {
                        UdpDrop::Short => s.short += 1,
                        UdpDrop::Oversize => s.oversize += 1,
                    });
                }
            }
        }
    }
}

impl Conn<'_> {
    /// Claim the configured addresses on opening, so that a program that only answers is reachable.
    fn claim_configured(&mut self) {
        for &a in &self.k.cfg.addrs {
            if let Err(e) = self.claim(a) {
                self.refused(
                    self.k.clock.now(),
                    a,
                    &format!("cannot claim configured address {a}: {e}"),
                );
            }
        }
    }

    /// Pass a chunk's decoded `events` through the link's gate into the twin; drops counted.
    fn pass_in(
        &mut self,
        out: &tokio::sync::mpsc::Sender<(SimTime, Vec<u8>)>,
        t: SimTime,
        events: &mut Vec<KissEvent>,
        delayed_in: &mut DelayLine<csp::Packet>,
    ) {
        let (name, cfg, stats) = (self.k.name, self.k.cfg, self.k.stats);
        for ev in events.drain(..) {
            match ev {
                KissEvent::Packet(p) => match gate(cfg) {
                    Passage::Now => self.take_in(out, t, &p),
                    Passage::After(d) => {
                        if delayed_in.push(t + d, p).is_err() {
                            overflow(cfg, name);
                        }
                    }
                    Passage::Lost(why) => {
                        tracing::debug!(
                            "{name}: packet {} from the outside lost at the link: {why:?}",
                            p.header
                        );
                    }
                },
                KissEvent::Dropped(d) => {
                    tracing::debug!("{name}: dropped KISS frame: {d}");
                    bump(stats, |s| match d {
                        KissDrop::BadCrc => s.bad_crc += 1,
                        KissDrop::Short => s.short += 1,
                        _ => s.oversize += 1,
                    });
                }
            }
        }
    }

    /// Pass what the twin delivers to a claimed address, framed, through the gate outwards.
    fn pass_out(
        &mut self,
        out: &tokio::sync::mpsc::Sender<(SimTime, Vec<u8>)>,
        a: Inbound,
        frame: &mut Vec<u8>,
        delayed_out: &mut DelayLine<Vec<u8>>,
    ) {
        let (name, cfg, stats) = (self.k.name, self.k.cfg, self.k.stats);
        let a_t = a.t;
        let Some(ep) = self.claims.0.iter_mut().find(|e| e.iface() == a.iface) else {
            return;
        };
        match ep.receive(a) {
            Some(Ok(p)) => {
                frame.clear();
                if !encode(cfg.framing, &p, frame) {
                    bump(stats, |s| s.out_dropped += 1);
                    tracing::debug!("{name}: packet {} too long for the hub", p.header);
                    return;
                }
                match gate(cfg) {
                    Passage::Now => self.put_out(out, a_t, frame.clone()),
                    Passage::After(d) => {
                        if delayed_out.push(a_t + d, frame.clone()).is_err() {
                            overflow(cfg, name);
                        }
                    }
                    Passage::Lost(why) => {
                        tracing::debug!(
                            "{name}: packet {} to the outside lost at the link: {why:?}",
                            p.header
                        );
                    }
                }
            }
            Some(Err(e)) => tracing::debug!("{name}: CFP drop towards outside: {e}"),
            None => {}
        }
    }

    /// Take a packet from the outside into the twin at `t`: its source must be one of the
    /// link's configured addresses, or, on a link without any, an address it can claim.
    fn take_in(
        &mut self,
        out: &tokio::sync::mpsc::Sender<(SimTime, Vec<u8>)>,
        t: SimTime,
        p: &csp::Packet,
    ) {
        let src = p.header.src;
        let res = if !self.k.cfg.addrs.is_empty() && !self.k.cfg.addrs.contains(&src) {
            Err(OutsideError::NotConfigured(src))
        } else {
            // Between two programs on the hub: straight across, as libcsp's hub does.
            let across = self.k.cfg.framing == Framing::ZmqHub && self.holds(p.header.dst);
            match self.claim(src) {
                Ok(_) if across => {
                    let mut msg = Vec::new();
                    if encode(Framing::ZmqHub, p, &mut msg) {
                        self.put_out(out, t, msg);
                    }
                    Ok(())
                }
                Ok(ep) => ep.send(t, p),
                Err(e) => Err(e),
            }
        };
        match res {
            Ok(()) => bump(self.k.stats, |s| s.packets_in += 1),
            Err(e @ (OutsideError::Held { .. } | OutsideError::NotConfigured(_))) => {
                bump(self.k.stats, |s| {
                    s.refused += 1;
                    s.claims_refused += 1;
                });
                let hint = take_place_hint(&e);
                self.refused(t, src, &format!("refused packet {}: {e}{hint}", p.header));
            }
            Err(e @ OutsideError::QueueFull { .. }) => {
                bump(self.k.stats, |s| {
                    s.refused += 1;
                    s.queue_full += 1;
                });
                tracing::debug!("{}: dropped packet {}: {e}", self.k.name, p.header);
            }
            Err(e) => {
                tracing::debug!("{}: refused packet {}: {e}", self.k.name, p.header);
                bump(self.k.stats, |s| s.refused += 1);
            }
        }
    }

    /// Log a refused address, once per address and connection (when it is a node of the
    /// twin's, with the flag that gives the program that node's place).
    fn refused(&mut self, t: SimTime, addr: u8, text: &str) {
        if self.warned.insert(addr) {
            warn(
                self.k.cfg,
                t,
                self.k.name,
                format!("{text} (further packets from {addr} are counted, not logged)"),
            );
        }
    }

    /// Queue a frame for the socket; dropped and counted when the program does not read.
    fn put_out(
        &mut self,
        out: &tokio::sync::mpsc::Sender<(SimTime, Vec<u8>)>,
        t: SimTime,
        frame: Vec<u8>,
    ) {
        match out.try_send((t, frame)) {
            Ok(()) => self.out_full = false,
            Err(_) => {
                bump(self.k.stats, |s| s.out_dropped += 1);
                if !self.out_full {
                    self.out_full = true;
                    warn(
                        self.k.cfg,
                        t,
                        self.k.name,
                        format!(
                            "the outside program does not read: {} frames wait; frames to it are dropped and counted",
                            self.k.cfg.limits.output_frames
                        ),
                    );
                }
            }
        }
    }

    /// Whether one of the connection's endpoints holds `addr`.
    fn holds(&self, addr: u8) -> bool {
        self.claims.0.iter().any(|e| e.addrs().contains(&addr))
    }

    /// The connection's endpoint with `addr` claimed (attaching it on the first claim on
    /// its segment). A KISS connection joins one segment; the hub joins each its programs'
    /// addresses are on.
    fn claim(&mut self, addr: u8) -> Result<&mut OutsideEndpoint, OutsideError> {
        let at = if self.k.cfg.framing == Framing::ZmqHub {
            let kind = SegmentKind::of(addr);
            self.claims.0.iter().position(|e| e.kind() == kind)
        } else {
            (!self.claims.0.is_empty()).then_some(0)
        };
        let at = match at {
            Some(i) => {
                if let Some(ep) = self.claims.0.get_mut(i) {
                    ep.claim(addr)?;
                }
                i
            }
            None => {
                let ep = OutsideEndpoint::attach(
                    self.k.segs,
                    self.k.name,
                    self.k.cfg.link,
                    addr,
                    self.inbox.clone(),
                    (self.k.n as u16).wrapping_mul(97),
                    self.k.cfg.tx_frames_per_s.map(TxBudget::per_second),
                )?;
                tracing::info!(
                    "{}: outside node {addr} joined the {:?} segment",
                    self.k.name,
                    ep.kind()
                );
                if let Some(l) = self.k.live {
                    l.named.store(true, std::sync::atomic::Ordering::Relaxed);
                }
                self.claims.0.push(ep);
                self.claims.0.len() - 1
            }
        };
        self.claims
            .0
            .get_mut(at)
            .ok_or(OutsideError::BadSource(addr))
    }
}

/// Frame `p` for the outside in `out`; false when it does not fit the framing (more than
/// the hub's or a datagram's 256 bytes).
fn encode(framing: Framing, p: &csp::Packet, out: &mut Vec<u8>) -> bool {
    match framing {
        Framing::Kiss => kiss::encode(p, out),
        Framing::ZmqHub => {
            if p.data.len() > csp::zmqhub::HUB_MTU {
                return false;
            }
            csp::zmqhub::encode(p, p.header.dst, out);
        }
        Framing::Udp => {
            if p.data.len() > csp::udp::UDP_MTU {
                return false;
            }
            csp::udp::encode(p, out);
        }
    }
    true
}

/// The passage of one packet through the link's gate (everything crosses without one).
fn gate(cfg: &KissLinkConfig) -> Passage {
    cfg.gate.as_ref().map_or(Passage::Now, LinkGate::pass)
}

fn overflow(cfg: &KissLinkConfig, name: &str) {
    if let Some(g) = &cfg.gate {
        g.overflowed();
    }
    tracing::warn!("{name}: delay line full: packet lost");
}

/// Write one KISS frame to the outside program at `t`; the error ends the link.
async fn write_out<W: FrameSink>(
    stream: &mut W,
    name: &str,
    cfg: &KissLinkConfig,
    stats: &SharedStats,
    t: SimTime,
    frame: &[u8],
) -> std::io::Result<()> {
    if let Some(tap) = &cfg.tap {
        (tap.0)(t, name, false, frame);
    }
    stream.send_frame(frame).await?;
    bump(stats, |s| {
        s.packets_out += 1;
        s.bytes_out += frame.len() as u64;
    });
    Ok(())
}

/// An outside link's endpoints (one per segment), released when dropped.
struct Claims(Vec<OutsideEndpoint>);

impl Drop for Claims {
    fn drop(&mut self) {
        for ep in &self.0 {
            ep.release();
        }
    }
}

/// Warn that a program listens on `addr`, which node `node` of the twin holds (the twin's
/// node answers in its place), with what gives the program that node's place.
pub(crate) fn warn_held(cfg: &KissLinkConfig, t: SimTime, name: &str, addr: u8, node: &str) {
    let e = OutsideError::Held {
        addr,
        holder: bus::outside::ClaimError::Node(node.to_owned()),
    };
    let hint = take_place_hint(&e);
    warn(
        cfg,
        t,
        name,
        format!(
            "a program listens on address {addr}, but {e}: the twin's {node} answers in its place{hint}"
        ),
    );
}

/// What gives an outside program the address a node of the twin holds, for the refusal
/// of its claim (`--kiss-addr 12` after the link's flag, or the scenario link's `addrs`
/// and `replaces`); nothing for any other refusal.
fn take_place_hint(e: &OutsideError) -> String {
    match e {
        OutsideError::Held {
            addr,
            holder: bus::outside::ClaimError::Node(node),
        } => format!(
            "; to run this program in {node}'s place, give its link the address: \
             `--kiss-addr {addr}` after the link's flag, or `addrs = [{addr}]` and \
             `replaces = [\"{node}\"]` on its [[links]] entry"
        ),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use std::pin::Pin;
    use std::task::{Context, Poll};

    use super::*;
    use bus::can::{CanBus, CanBusConfig};
    use bus::clock::ClockMode;
    use bus::net::{PacketNet, PacketNetConfig};
    use csp::{Header, Packet};

    /// A socket whose every write fails, as after a peer's reset.
    struct Reset;

    impl AsyncWrite for Reset {
        fn poll_write(
            self: Pin<&mut Self>,
            _: &mut Context<'_>,
            _: &[u8],
        ) -> Poll<std::io::Result<usize>> {
            Poll::Ready(Err(std::io::ErrorKind::ConnectionReset.into()))
        }
        fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<std::io::Result<()>> {
            Poll::Ready(Ok(()))
        }
        fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<std::io::Result<()>> {
            Poll::Ready(Ok(()))
        }
    }

    /// A connection that ends because a write failed records its close (an empty chunk
    /// into the twin, after what it wrote) and gives its address back. With nothing recorded,
    /// its replay would keep the address for the rest of the run.
    #[tokio::test(start_paused = true)]
    async fn a_failed_write_is_recorded_as_the_close_and_the_address_goes_back() {
        let clock = Clock::new(ClockMode::Virtual);
        let ground = PacketNet::new(PacketNetConfig::ground(), 1);
        let segs = Segments {
            main: CanBus::new(CanBusConfig::new("main"), 1),
            payload: CanBus::new(CanBusConfig::new("payload"), 1),
            ground: ground.clone(),
        };
        let (tx_gs, _rx_gs) = inbox();
        let gs = ground.attach("GS16", &[16], false, false, tx_gs, 0);
        tokio::spawn(ground.clone().run(clock));
        let taps: Arc<Mutex<Vec<(SimTime, bool, usize)>>> = Arc::default();
        let seen = taps.clone();
        let cfg = KissLinkConfig {
            addrs: vec![17],
            tap: Some(KissTap::new(move |t, _, input, bytes| {
                seen.lock().unwrap().push((t, input, bytes.len()));
            })),
            ..Default::default()
        };
        let stats = SharedStats::default();
        let (_in_tx, in_rx) = tokio::sync::mpsc::channel(4);
        let k = Connection {
            name: "test#1",
            segs: &segs,
            cfg: &cfg,
            stats: &stats,
            n: 1,
            clock,
            opened: SimTime(5),
            live: None,
        };
        let sent = async {
            tokio::time::sleep(Duration::from_millis(10)).await;
            gs.send(
                clock.now(),
                Packet::new(Header::new(16, 17, 1, 40), vec![1, 2]),
            );
            std::future::pending::<()>().await;
        };
        let mut socket = Stream(Reset);
        let why = tokio::select! {
            why = serve_link(in_rx, &mut socket, k) => why,
            () = sent => unreachable!(),
        };
        assert!(why.contains("reset"), "{why}");
        let taps = taps.lock().unwrap().clone();
        // The open is recorded by what accepted the connection, before serving it.
        assert_eq!(
            taps,
            [
                (SimTime::from_ns(10_000_000), false, 13),
                (SimTime::from_ns(10_000_000), true, 0)
            ],
            "the packet out, then the close"
        );
        // 17 is free again: another endpoint may claim it.
        let (tx, _rx) = inbox();
        let other = ground.attach("other", &[], false, false, tx, 0);
        assert_eq!(ground.claim(&other, 17), Ok(()));
    }
}
