//! Build the network of [`NetworkSpec`] on its media, run every node as its own tokio task
//! on one current-thread runtime, and count what happened.
//!
//! In virtual time the runtime's clock is paused and jumps to the next timer, so a run is
//! deterministic (same options and seed, same trace) and as fast as the CPU allows. In real
//! time the same tasks follow the wall clock, which is what outside programs need; a run
//! with outside links is always in real time.
//!
//! - `build`: the media, the boards and the nodes, each node its own task.
//! - `links`: programs outside the twin (KISS/TCP, replayed input, SocketCAN).
//! - [`power`]: the shell around the platform's power rules (EPS channels, power and hang
//!   faults, the radio take-over).
//! - [`ground`]: the twin's own ground stations (their plan of requests and outcomes).
//! - [`faults`]: what a fault does at its instant (the fault director).
//! - [`counters`]: what the runtime counts, and the sink that observes a run.
//! - this module: the options and the main loop, which hands every event to the sink in
//!   the order it happens and applies the faults at their instants.

mod build;
pub use snapshot::{FaultsToCome, RUNTIME_SECTION, Resume, Sections};
pub mod control;
pub mod counters;
pub mod faults;
pub mod ground;
mod links;
pub mod power;
mod snapshot;
use snapshot::LoopState;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use ::links::kiss_tcp::KissLinkConfig;
use anyhow::Context as _;
use bus::driver::NodeCtl;
use bus::{Clock, ClockMode};
use csp::SimTime;
use platform::board::Boards;
use tokio::sync::{mpsc, oneshot};

use crate::ground::Recurring;
pub use build::fc_config;
pub use counters::{AskedBy, Interruption, NodeReport, RunCounters, RunSink, StopCause};
use faults::{FaultAction, TimedFault};
use twin_core::events::RunEvent;
use twin_core::network::NetworkSpec;

/// Everything a run needs.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// The network.
    pub network: NetworkSpec,
    /// Simulated duration; `None` runs until Ctrl-C.
    pub duration: Option<Duration>,
    /// Virtual or real time.
    pub clock: ClockMode,
    /// Seed of every random choice (CFP idents, ephemeral ports, impairments).
    pub seed: u64,
    /// KISS/TCP links to programs outside the twin, each with its own addresses and
    /// limits.
    pub kiss_links: Vec<KissLink>,
    /// Node consoles served to outside programs.
    pub uart: Vec<UartLink>,
    /// What payloads may ask of every node's platform port (`[rules] payload_access`; the
    /// FC and the PC have their own copy for their ICD ports).
    pub payload_access: platform::addr::PayloadAccess,
    /// The most wall-clock time the run may take (a campaign's `[limits] wall`): past it
    /// the run stops, as interrupted. `None`: no limit.
    pub wall_limit: Option<Duration>,
    /// Factory values of nodes' platform parameters (`[nodes.NAME] params`), by address:
    /// (parameter id, value), set before the node's first boot.
    pub params: BTreeMap<u8, Vec<(u8, f64)>>,
    /// Nodes of the network not started because an outside program takes their place
    /// (`replaces` on a link), by address.
    pub replaced: std::collections::BTreeSet<u8>,
    /// Requests each internal ground station sends, by station address.
    pub ground_plan: BTreeMap<u8, Vec<Recurring>>,
    /// Real CAN interfaces (`can0`, `vcan0`) to bridge to a bus of the twin; needs the
    /// `socketcan` cargo feature (Linux) when not empty.
    pub socketcan: Vec<(String, SocketCanBus)>,
    /// UTC unix seconds at simulated time zero.
    pub epoch_unix_s: u64,
    /// The satellite's two TLE lines (the FC propagates them); `None`: no orbit.
    pub tle: Option<(String, String)>,
    /// Keep the trace of every frame and packet in the report.
    pub trace: bool,
    /// Hand out each whole CSP packet the media deliver as a `RunEvent::Packet` after the
    /// frame that completed it (for a recording, the live view, `field` expectations): the
    /// run's one reassembly of CFP packets, which costs nothing when off.
    pub packet_events: bool,
    /// Keep every FC and EPS sample, every downlinked byte and every ground request's
    /// outcome in the report (`attitude`, `power`, each session run's `bytes`, `results`),
    /// for the programs and tests that read them. Without, the report has their summaries
    /// only (`attitude_summary`, `power_summary`, each run's `len` and `stream`,
    /// `requests`), so that memory does not grow with the simulated time;
    /// the twin's `exec::execute` runs so, its expectations judging the run as it goes.
    pub keep_series: bool,
    /// Faults to apply, in time order.
    pub faults: Vec<TimedFault>,
    /// Recorded input of outside links to feed again (`replay`), one connection per link.
    pub kiss_replay: Vec<KissReplay>,
    /// The scenario's outside links, which faults and power act on (`MediumId::Link(i)`
    /// is `outside[i]`).
    pub outside: Vec<OutsideLink>,
    /// The flight computer's models and timeline; its `epoch_unix_s`, `tle` and `seed` are
    /// taken from this run's.
    pub fc: nodes_fc::FcConfig,
    /// The payload controller's sessions, S-band and events.
    pub pc: nodes_pc::PcConfig,
    /// The simulated payloads, by address (an address missing here gets the defaults).
    pub payloads: BTreeMap<u8, nodes_payload::PayloadConfig>,
    /// The EPS: arrays, battery, loads, channels, protection, events.
    pub eps: nodes_eps::EpsConfig,
    /// The ECU: thruster, tank, limits.
    pub ecu: nodes_ecu::EcuConfig,
    /// COMM1's configuration (COMM2 takes the same with the secondary role).
    pub comm: nodes_comm::CommConfig,
    /// The run's control channel (`run --control`, or a replay's recorded requests).
    pub control: Option<control::ControlOptions>,
    /// Instants to take a snapshot at (docs/snapshots.md), each handed to the sink
    /// ([`counters::RunSink::snapshot`]) once the run has settled there.
    pub snapshot_at: Vec<SimTime>,
    /// The file the snapshots go to (the twin's `run --snapshot`; the runtime hands them
    /// to its sink, whose caller writes them).
    pub snapshot_to: Option<std::path::PathBuf>,
    /// Start from a snapshot instead of the start ([`Resume`]): the run is built from
    /// these options as any run is, then loaded, and goes on from the snapshot's instant.
    pub resume: Option<Resume>,
}

/// A link of the scenario to a program outside the twin, which faults and power act on
/// through its gate (`bus::gate`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutsideLink {
    /// Its name in the scenario (for the log).
    pub name: String,
    /// The runtime's name of the link: `listen 127.0.0.1:52001`, `connect 127.0.0.1:52002`
    /// or `socketcan vcan0` (each KISS connection adds `#n` to it).
    pub label: String,
    /// The EPS channel that powers the program behind it.
    pub powered_by: Option<nodes_eps::Channel>,
}

impl OutsideLink {
    /// Whether the runtime's link or connection `label` is this one.
    pub fn is(&self, label: &str) -> bool {
        label.split_once('#').map_or(label, |(l, _)| l) == self.label
    }
}

/// What an outside program sent on one KISS link during a recorded run.
#[derive(Debug, Clone)]
pub struct KissReplay {
    /// The link's name in the recording (for example `listen 127.0.0.1:52001#1`).
    pub link: String,
    /// What the run took in from the socket, in order: its open and its close as empty
    /// chunks.
    pub chunks: Vec<RecordedChunk>,
    /// The link's settings in the recorded run (its addresses, receiver, limits).
    pub cfg: KissLinkConfig,
}

/// One piece of recorded outside input.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedChunk {
    /// The simulated instant it was taken in at.
    pub t: SimTime,
    /// Its place among every connection's input of the run (the order the run took them
    /// in, which a replay keeps: input of one instant is taken in that order).
    pub seq: u64,
    /// The bytes (empty: the connection's open, or later its close).
    pub bytes: Vec<u8>,
}

/// Where a link to outside programs meets them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum KissMode {
    /// A KISS/TCP server for outside programs (`--kiss-listen`, `kind = "kiss-listen"`).
    Listen(SocketAddr),
    /// A KISS/TCP client of an outside server, as the platform in ICD 2.3 (`--kiss-connect`).
    Connect(SocketAddr),
    /// KISS on a pseudo-terminal linked at this path (`--kiss-pty`, `kind = "kiss-pty"`):
    /// libcsp's `usart_init(PATH)` opens it.
    Pty(std::path::PathBuf),
    /// libcsp 1.4's ZMQ hub (`--zmq-hub`, `kind = "zmq-hub"`): the twin binds its two
    /// sockets on this host, the nodes' PUB side and SUB side (`links::zmq_hub`).
    ZmqHub(::links::zmq_hub::HubAddr),
    /// CSP over UDP (`--udp`, `kind = "udp"`): the twin's socket, and where it sends
    /// (`links::udp`).
    Udp(::links::udp::UdpAddr),
}

/// A link of the run to outside programs: KISS (TCP or a pty) or the ZMQ hub.
#[derive(Debug, Clone)]
pub struct KissLink {
    /// Where it meets the programs.
    pub mode: KissMode,
    /// Its addresses, receiver and limits (the tap, log and gate are the run's).
    pub cfg: KissLinkConfig,
}

impl KissLink {
    /// A server on `addr`, learning its addresses.
    pub fn listen(addr: SocketAddr) -> Self {
        KissLink::new(KissMode::Listen(addr))
    }
    /// A client of `addr`, learning its addresses.
    pub fn connect(addr: SocketAddr) -> Self {
        KissLink::new(KissMode::Connect(addr))
    }
    /// A link meeting its programs at `mode`, learning its addresses.
    pub fn new(mode: KissMode) -> Self {
        KissLink {
            mode,
            cfg: KissLinkConfig::default(),
        }
    }
    /// With these CSP addresses behind it.
    pub fn with_addrs(mut self, addrs: &[u8]) -> Self {
        self.cfg.addrs = addrs.to_vec();
        self
    }
    /// The runtime's name of the link: `listen 127.0.0.1:52001`, `connect ...`, `pty
    /// /tmp/m6p-tty`, `zmq-hub 127.0.0.2` or `udp 127.0.0.1:10015`.
    pub fn label(&self) -> String {
        match &self.mode {
            KissMode::Listen(a) => format!("listen {a}"),
            KissMode::Connect(a) => format!("connect {a}"),
            KissMode::Pty(p) => format!("pty {}", p.display()),
            KissMode::ZmqHub(h) => format!("zmq-hub {h}"),
            KissMode::Udp(u) => format!("udp {}", u.bind),
        }
    }
}

impl RunOptions {
    /// The default network for `duration` of virtual time with seed 1.
    pub fn new(network: NetworkSpec, duration: Duration) -> Self {
        RunOptions {
            network,
            duration: Some(duration),
            clock: ClockMode::Virtual,
            seed: 1,
            kiss_links: Vec::new(),
            uart: Vec::new(),
            payload_access: platform::addr::PayloadAccess::default(),
            wall_limit: None,
            params: BTreeMap::new(),
            replaced: std::collections::BTreeSet::new(),
            ground_plan: BTreeMap::new(),
            socketcan: Vec::new(),
            epoch_unix_s: 1_577_836_800,
            tle: None,
            trace: false,
            packet_events: false,
            keep_series: true,
            faults: Vec::new(),
            kiss_replay: Vec::new(),
            outside: Vec::new(),
            fc: nodes_fc::FcConfig::default(),
            pc: nodes_pc::PcConfig::default(),
            payloads: BTreeMap::new(),
            eps: nodes_eps::EpsConfig::default(),
            ecu: nodes_ecu::EcuConfig::default(),
            comm: nodes_comm::CommConfig::default(),
            control: None,
            snapshot_at: Vec::new(),
            snapshot_to: None,
            resume: None,
        }
    }

    /// Whether the run has links to programs outside the twin.
    pub fn has_outside_links(&self) -> bool {
        !self.kiss_links.is_empty()
            || !self.socketcan.is_empty()
            || !self.uart.is_empty()
            || self.control.as_ref().is_some_and(|c| c.listen.is_some())
    }

    /// A run in virtual time with no link to the outside: nothing in it waits on the wall
    /// clock or a socket, so it runs as fast as its CPU allows, beside any other such run.
    pub fn is_self_contained(&self) -> bool {
        self.clock == ClockMode::Virtual && !self.has_outside_links()
    }
}

/// A node's text console for people and programs outside the twin (`[[links]] kind =
/// "uart"`, `--uart NODE=ADDR|PATH`; `links::console`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UartLink {
    /// The node's name (`FC`).
    pub node: String,
    /// Where it is served.
    pub at: UartAt,
}

/// Where a console is served.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UartAt {
    /// A TCP server (`nc`, `telnet`).
    Tcp(SocketAddr),
    /// A pseudo-terminal linked at the path (`screen`, `minicom`, `picocom`).
    Pty(std::path::PathBuf),
}

/// Why a `--uart` or `--socketcan` argument was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LinkArgError {
    /// `--uart` without a node or a place.
    #[error("`{arg}`: expected NODE=ADDR or NODE=PATH (FC=127.0.0.1:5010)")]
    NotNodeAt {
        /// The argument.
        arg: String,
    },
    /// `--uart`'s place is neither a socket address nor a path.
    #[error("`{at}` is neither a TCP address like 127.0.0.1:5010 nor a path like /tmp/fc-uart")]
    NotAddrOrPath {
        /// The part after `=`.
        at: String,
    },
    /// `--socketcan`'s bus is not `main` or `payload`.
    #[error("unknown bus `{bus}`: expected IFACE, IFACE:main or IFACE:payload")]
    UnknownBus {
        /// The part after the last `:`.
        bus: String,
    },
    /// `--socketcan` without an interface.
    #[error("missing interface name: expected IFACE[:main|:payload]")]
    NoInterface,
}

impl UartLink {
    /// Parse `--uart`'s `NODE=ADDR` (a TCP address) or `NODE=PATH` (a pty).
    pub fn parse_arg(s: &str) -> Result<Self, LinkArgError> {
        let not_node_at = || LinkArgError::NotNodeAt { arg: s.to_owned() };
        let (node, at) = s.split_once('=').ok_or_else(not_node_at)?;
        if node.is_empty() || at.is_empty() {
            return Err(not_node_at());
        }
        let at = match at.parse::<SocketAddr>() {
            Ok(a) => UartAt::Tcp(a),
            Err(_) if at.contains('/') => UartAt::Pty(at.into()),
            Err(_) => {
                return Err(LinkArgError::NotAddrOrPath { at: at.to_owned() });
            }
        };
        Ok(UartLink {
            node: node.to_owned(),
            at,
        })
    }
    /// The link's label in logs.
    pub fn label(&self) -> String {
        match &self.at {
            UartAt::Tcp(a) => format!("uart {} {a}", self.node),
            UartAt::Pty(p) => format!("uart {} {}", self.node, p.display()),
        }
    }
}

/// Which CAN bus of the twin a real CAN interface is bridged to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SocketCanBus {
    /// The main CAN bus (COMM, FC, EPS, ECU, PC).
    Main,
    /// The payload CAN bus (PC, payloads).
    Payload,
}

impl std::fmt::Display for SocketCanBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SocketCanBus::Main => "main",
            SocketCanBus::Payload => "payload",
        })
    }
}

impl SocketCanBus {
    /// Parse the `--socketcan` argument `IFACE[:main|:payload]` (default: the main bus).
    pub fn parse_arg(arg: &str) -> Result<(String, SocketCanBus), LinkArgError> {
        let (ifname, which) = match arg.rsplit_once(':') {
            Some((i, "main")) => (i, SocketCanBus::Main),
            Some((i, "payload")) => (i, SocketCanBus::Payload),
            Some((_, other)) => {
                return Err(LinkArgError::UnknownBus {
                    bus: other.to_owned(),
                });
            }
            None => (arg, SocketCanBus::Main),
        };
        if ifname.is_empty() {
            return Err(LinkArgError::NoInterface);
        }
        Ok((ifname.to_owned(), which))
    }
}

/// A tokio runtime for a run in any mode: current-thread, on tokio's paused clock (real time
/// is that clock held back to the wall clock), with the hook that takes outside input in
/// and paces the run ([`bus::pace`]).
pub fn build_runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .on_thread_park(bus::pace::on_idle)
        .build()
        .context("building the tokio runtime")
}

/// The runtime for the run `opts`: [`build_runtime`], without the IO driver when the run is
/// in virtual time with no link to the outside (every wake-up then costs no `epoll_wait`
/// and no eventfd write: the paused clock only needs the timer), and without the idle hook
/// too when nothing from outside is fed in either (no replayed input: the hook would only
/// note each idle point, at every park of the run).
pub fn build_runtime_for(opts: &RunOptions) -> anyhow::Result<tokio::runtime::Runtime> {
    if !opts.is_self_contained() {
        return build_runtime();
    }
    let control_replay = opts.control.as_ref().is_some_and(|c| !c.replay.is_empty());
    if opts.kiss_replay.is_empty() && !control_replay {
        return build_virtual_runtime();
    }
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        // A replay's recorded input (outside links, the control channel) is taken in at the
        // run's idle points (`bus::pace`).
        .on_thread_park(bus::pace::on_idle)
        .build()
        .context("building the tokio runtime")
}

/// The runtime of a run in virtual time with nothing from outside: tokio's paused clock and
/// its timer, no IO driver, no idle hook.
pub fn build_virtual_runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()
        .context("building the tokio runtime")
}

/// Whether SIGINT (Ctrl-C) or SIGTERM came, and which: one watcher thread for the process
/// (its own small runtime with the signal driver), so that a run in virtual time needs no
/// IO driver of its own. Once it came it stays: every run still going stops, and so does
/// any later one (a campaign ends).
pub fn stop_signal() -> tokio::sync::watch::Receiver<Option<StopCause>> {
    static SEEN: std::sync::OnceLock<tokio::sync::watch::Receiver<Option<StopCause>>> =
        std::sync::OnceLock::new();
    SEEN.get_or_init(|| {
        let (tx, rx) = tokio::sync::watch::channel(None);
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let spawned = std::thread::Builder::new()
            .name("ctrl-c".into())
            .spawn(move || {
                let rt = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build();
                if let Ok(rt) = rt {
                    rt.block_on(async {
                        // The handler is in place before the first run starts.
                        let sig = watch_signals();
                        let _ = ready_tx.send(());
                        if let Some(sig) = sig
                            && let Some(cause) = sig.await
                        {
                            let _ = tx.send(Some(cause));
                        }
                    });
                }
                // Keep the sender: without a handler the runs just never see Ctrl-C.
                std::mem::forget(tx);
            });
        match spawned {
            Ok(_) => {
                let _ = ready_rx.recv_timeout(Duration::from_secs(1));
            }
            Err(e) => tracing::warn!("no Ctrl-C watcher: {e}"),
        }
        rx
    })
    .clone()
}

/// SIGINT's and SIGTERM's handlers, installed now; their future says which came first.
fn watch_signals() -> Option<impl std::future::Future<Output = Option<StopCause>>> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let mut int = signal(SignalKind::interrupt()).ok()?;
        let mut term = signal(SignalKind::terminate()).ok()?;
        Some(async move {
            tokio::select! {
                s = int.recv() => s.map(|()| StopCause::Interrupt),
                s = term.recv() => s.map(|()| StopCause::Terminate),
            }
        })
    }
    #[cfg(not(unix))]
    {
        Some(async {
            tokio::signal::ctrl_c()
                .await
                .ok()
                .map(|()| StopCause::Interrupt)
        })
    }
}

pub use twin_core::seed::{first_ephemeral_port, mix};

impl RunOptions {
    /// The ICD on the ports this run configured.
    pub fn icd_map(&self) -> twin_core::icd::IcdMap {
        twin_core::icd::IcdMap::for_nodes(&twin_core::icd::NodePorts {
            seed: self.seed,
            fc: &self.fc,
            pc: &self.pc,
            eps: &self.eps,
            ecu: &self.ecu,
            comm: &self.comm,
        })
    }
}

/// Events the run's loop takes per wake-up (the first, then those already queued): the
/// select, its Ctrl-C check and the next fault's timer once per batch rather than per event.
const EVENTS_PER_WAKE: usize = 1024;

/// Run the twin, handing every [`RunEvent`] to `sink` in the order they happen; what the
/// runtime counted at the end. `ready` receives the bound addresses of the KISS servers
/// and UDP links (in `opts.kiss_links`' order), then those of the TCP consoles
/// (`opts.uart`), once they listen.
pub async fn run_with(
    opts: RunOptions,
    ready: Option<oneshot::Sender<Vec<SocketAddr>>>,
    sink: &mut dyn RunSink,
) -> anyhow::Result<RunCounters> {
    let clock = Clock::new(opts.clock);
    // A run from a snapshot starts at its instant: the clock is there before any task is
    // made.
    if let Some(r) = &opts.resume {
        tokio::time::advance(Duration::from_nanos(r.t.as_ns())).await;
    }
    // The run's tasks on the run's executor: those due at one instant run in an order of
    // the run's own (`bus::exec`).
    bus::exec::run(clock, run_on(clock, opts, ready, sink)).await
}

async fn run_on(
    clock: Clock,
    mut opts: RunOptions,
    ready: Option<oneshot::Sender<Vec<SocketAddr>>>,
    sink: &mut dyn RunSink,
) -> anyhow::Result<RunCounters> {
    let wall_start = Instant::now();
    let mut tapped = counters::Tapped::new(sink, opts.packet_events);
    // Outside input taken in at the run's idle points, and real time's hold (`bus::pace`).
    let _pace = bus::pace::install(clock);
    // Every event of the run goes through one channel, in the order it happens.
    let (ev_tx, mut ev_rx) = mpsc::unbounded_channel::<RunEvent>();
    let start = snapshot::start_of(opts.resume.as_ref());
    let (segs, media_tasks) = build::media(&opts, clock, &ev_tx, start);
    let mut background = Vec::new();
    // The gates of the scenario's outside links: their faults and power.
    let gates = links::gates(&opts);
    let socketcan_stats =
        links::spawn_socketcan_bridges(&opts, &segs, clock, &gates, &mut background)?;
    let boards = Boards::default();
    let (nodes, resume_at) = nodes_of_run(&mut opts, &segs, clock, &boards, &ev_tx, start)?;
    let (kiss, mut control) = outside(
        &mut opts,
        &segs,
        &nodes,
        clock,
        &gates,
        &ev_tx,
        &mut background,
        ready,
    )
    .await?;

    // Faults are applied by the main loop at their times, so that their events sit in the
    // stream exactly where they take effect.
    let ctls = nodes.ctls();
    // One truth for power: the EPS's switches and the power and hang faults go through
    // the platform's rules.
    let mut power_shell = power_shell(&opts, &nodes, &boards, &segs, &gates);
    let (mut faults, own) = snapshot::timeline(&mut opts);
    if let Some(r) = opts.resume.take() {
        LoopState::of(&mut power_shell, &gates, &mut faults, &mut tapped)
            .resume(&r, resume_at, own)?;
    }
    let mut snapshots = Snapshots::new(&opts.snapshot_at, clock);
    let end = opts.duration.map_or(SimTime::MAX, |d| SimTime::ZERO + d);
    let kiss_budget = kiss.budget.clone();
    let mut signalled = std::pin::pin!(signalled());
    let mut interrupted: Option<StopCause> = None;
    let mut fault_timer = bus::clock::Timer::new(clock);
    loop {
        let next_fault = faults.next_at().unwrap_or(SimTime::MAX).min(end);
        tokio::select! {
            biased;
            cause = &mut signalled => {
                tracing::info!("{cause:?}: stopping");
                interrupted = cause;
                break;
            }
            ev = ev_rx.recv() => {
                handle_batch(ev, &mut ev_rx, &mut power_shell, &mut tapped, &kiss_budget);
                // The wall clock's limit, looked at once a batch (a run in virtual time
                // sleeps on no wall-clock timer).
                if let Some(cause) = wall_limit_passed(opts.wall_limit, wall_start) {
                    interrupted = Some(cause);
                    break;
                }
            }
            Some(req) = control.recv(), if control.is_on() => {
                let t = req.t;
                let ev = control.answer(req, &mut faults, &mut |t| snapshots.ask(t));
                hand_on(ev, &mut tapped, &kiss_budget);
                // What it asked for at this instant takes effect now.
                let mut director = director(&segs, &ctls, &mut power_shell, &gates);
                while let Some(f) = faults.pop_due(t) {
                    apply_fault(&f, &mut director, &mut tapped, &kiss_budget);
                }
            }
            (t, by) = snapshots.due(), if snapshots.is_on() => {
                let state = LoopState::of(&mut power_shell, &gates, &mut faults, &mut tapped);
                let bytes = state.take(&segs, &boards, &nodes);
                tapped.snapshot(t, by, &mut vec![(RUNTIME_SECTION.to_owned(), bytes)]);
            }
            () = fault_timer.sleep_until(next_fault), if next_fault < SimTime::MAX => {
                if next_fault >= end && faults.next_at().is_none_or(|at| at >= end) {
                    break;
                }
                let mut director = director(&segs, &ctls, &mut power_shell, &gates);
                while let Some(f) = faults.pop_due(next_fault) {
                    apply_fault(&f, &mut director, &mut tapped, &kiss_budget);
                }
            }
        }
    }
    let (sim_time, interrupted) = ended(opts.duration, clock, interrupted);

    let node_reports = stop_nodes(nodes.tasks, sim_time, &ev_tx).await?;
    background.iter().for_each(tokio::task::JoinHandle::abort);
    media_tasks.iter().for_each(bus::exec::JoinHandle::abort);
    drop(ev_tx);
    while let Ok(ev) = ev_rx.try_recv() {
        hand_on(ev, &mut tapped, &kiss_budget);
    }
    Ok(RunCounters {
        sim_time,
        interrupted,
        wall: wall_start.elapsed(),
        nodes: node_reports,
        buses: vec![segs.main.stats(), segs.payload.stats()],
        ground: segs.ground.stats(),
        kiss: links::snapshot(kiss.stats),
        socketcan: links::snapshot(socketcan_stats),
        cfp_drops: tapped.cfp_drops(),
        control: control.stats(),
        boards: boards.stats(),
        links: link_stats(&opts, &gates),
    })
}

/// The run's nodes, each its own task, and where the loop's part of the snapshot the run
/// starts from begins: what the tasks share is loaded before any of them first runs, and
/// the nodes outside programs replace from the snapshot on leave then.
fn nodes_of_run(
    opts: &mut RunOptions,
    segs: &bus::outside::Segments,
    clock: Clock,
    boards: &Boards,
    ev_tx: &mpsc::UnboundedSender<RunEvent>,
    start: bus::exec::Start,
) -> anyhow::Result<(build::Nodes, usize)> {
    let later = snapshot::replaced_later(opts.resume.as_ref(), &opts.replaced)?;
    let mut nodes = build::nodes(opts, segs, clock, boards, ev_tx, start, &later);
    let resume_at =
        snapshot::resume_shared(opts.resume.as_ref(), segs, boards, &nodes, &opts.replaced)?;
    nodes.hand_over_replaced();
    Ok((nodes, resume_at))
}

/// The cause to stop if the run's wall-clock limit has passed since `wall_start`.
fn wall_limit_passed(limit: Option<Duration>, wall_start: Instant) -> Option<StopCause> {
    let d = limit?;
    (wall_start.elapsed() >= d).then(|| {
        tracing::warn!("the run's wall-clock limit ({d:?}) passed: stopping");
        StopCause::WallLimit(d)
    })
}

/// Each outside link's gate counts, by the link's name.
fn link_stats(
    opts: &RunOptions,
    gates: &[bus::gate::LinkGate],
) -> Vec<(String, bus::gate::GateStats)> {
    opts.outside
        .iter()
        .zip(gates)
        .map(|(l, g)| (l.name.clone(), g.stats()))
        .collect()
}

/// The links to programs outside the twin: KISS servers and UDP links, the TCP consoles,
/// the control channel and real time's pacer; `ready` is told the addresses bound (the
/// KISS servers' and UDP links', then the consoles', then the control channel's).
#[allow(clippy::too_many_arguments)]
async fn outside(
    opts: &mut RunOptions,
    segs: &bus::outside::Segments,
    nodes: &build::Nodes,
    clock: Clock,
    gates: &[bus::gate::LinkGate],
    ev_tx: &mpsc::UnboundedSender<RunEvent>,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
    ready: Option<oneshot::Sender<Vec<SocketAddr>>>,
) -> anyhow::Result<(links::KissLinks, control::Control)> {
    let mut kiss = links::kiss(opts, segs, clock, gates, ev_tx, background).await?;
    let consoles = links::uart(opts, &nodes.ctls(), clock, ev_tx, background).await?;
    kiss.bound.extend(consoles);
    let control =
        control::Control::start(opts.control.take(), clock, &mut kiss.bound, background).await?;
    spawn_pacer(opts, clock, ev_tx, background);
    if let Some(r) = ready {
        let _ = r.send(kiss.bound.clone());
    }
    Ok((kiss, control))
}

/// The instants a run takes snapshots at, those to come.
struct Snapshots {
    /// The instants, in order, and who asked for each.
    at: std::collections::VecDeque<(SimTime, AskedBy)>,
    timer: bus::clock::Timer,
}

impl Snapshots {
    fn new(at: &[SimTime], clock: Clock) -> Self {
        let now = clock.now();
        let mut at: Vec<SimTime> = at.iter().copied().filter(|&t| t > now).collect();
        at.sort_unstable();
        at.dedup();
        Snapshots {
            at: at.into_iter().map(|t| (t, AskedBy::Schedule)).collect(),
            timer: bus::clock::Timer::new(clock),
        }
    }

    fn is_on(&self) -> bool {
        !self.at.is_empty()
    }

    /// A snapshot the control channel asked for at `t` (now), taken where the run settles
    /// at `t`, before the scheduled ones of later instants.
    fn ask(&mut self, t: SimTime) {
        let i = self.at.partition_point(|(s, _)| *s <= t);
        self.at.insert(i, (t, AskedBy::Control));
    }

    /// The next instant and who asked, once the run has settled there (or after: nothing
    /// happened between).
    async fn due(&mut self) -> (SimTime, AskedBy) {
        let Some(&(t, by)) = self.at.front() else {
            return std::future::pending().await;
        };
        self.timer.sleep_until(t).await;
        bus::exec::settled().await;
        self.at.pop_front();
        (t, by)
    }
}

/// Where a run ended, and why if it was stopped before its end: a virtual run ends exactly
/// at its duration, unless it was stopped before.
fn ended(
    duration: Option<Duration>,
    clock: Clock,
    stopped: Option<StopCause>,
) -> (SimTime, Option<Interruption>) {
    let sim_time = match duration {
        Some(d) if clock.is_virtual() && stopped.is_none() => SimTime::ZERO + d,
        _ => clock.now(),
    };
    let interrupted = stopped.map(|cause| Interruption {
        cause,
        at: sim_time,
        of: duration,
    });
    (sim_time, interrupted)
}

/// The first stop signal (SIGINT, SIGTERM) of the process, once it comes; watched from
/// the call on.
fn signalled() -> impl std::future::Future<Output = Option<StopCause>> {
    let mut signal_seen = stop_signal();
    async move {
        let seen = signal_seen.wait_for(Option::is_some).await.map(|c| *c);
        match seen {
            Ok(cause) => cause,
            Err(_) => std::future::pending().await,
        }
    }
}

/// The wall clock paces the run from `from` on (0 in real time; the scenario's
/// `realtime_from` after virtual time until then), when the run is paced at all.
fn spawn_pacer(
    opts: &RunOptions,
    clock: Clock,
    ev_tx: &mpsc::UnboundedSender<RunEvent>,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
) {
    if let Some((from, speed)) = opts.clock.paced() {
        let tx = ev_tx.clone();
        let from_later = from > SimTime::ZERO;
        background.push(tokio::spawn(bus::pace::pacer(
            clock,
            from,
            speed,
            move |t| {
                if from_later {
                    tracing::info!("real time from {t} on");
                    let _ = tx.send(RunEvent::Log {
                        t,
                        source: "clock".to_owned(),
                        level: twin_core::events::Level::Info,
                        message: "virtual time ends: the wall clock paces the run from here"
                            .to_owned(),
                    });
                }
            },
        )));
    }
}

/// One truth for power: the EPS's switches and the power and hang faults go through the
/// platform's rules, which switch the nodes, the radios and the outside links' power.
fn power_shell(
    opts: &RunOptions,
    nodes: &build::Nodes,
    boards: &Boards,
    segs: &bus::outside::Segments,
    gates: &[bus::gate::LinkGate],
) -> power::PowerShell {
    let mut power_shell =
        power::PowerShell::new(nodes.ctls(), boards.activity.clone(), segs.clone());
    for (addr, ports) in &nodes.comm_ports {
        power_shell.register_comm(*addr, ports);
    }
    for (i, (link, gate)) in opts.outside.iter().zip(gates).enumerate() {
        power_shell.register_link(i, link.name.clone(), gate.clone());
        if let Some(ch) = link.powered_by {
            let on = opts.eps.channels_on & ch.bit() != 0;
            power_shell.power_link(i, link.name.clone(), ch, gate.clone(), on);
        }
    }
    power_shell
}

/// Hand one event to the sink; a chunk read from outside, once handed on (recorded, or
/// queued for the recorder's thread, whose queue is bounded), lets its link read another.
fn hand_on(ev: RunEvent, sink: &mut dyn RunSink, kiss_budget: &tokio::sync::Semaphore) {
    sink.event(&ev);
    if let RunEvent::Kiss {
        dir: twin_core::events::Direction::In,
        ..
    } = ev
    {
        kiss_budget.add_permits(1);
    }
}

/// The event that woke the loop, then those already queued behind it: a bounded batch, one
/// select per batch rather than per event. The stream's order is the select's own: with
/// `biased`, a queued event always came before the fault timer. tokio's budget (128 units a
/// poll, a `recv` one) makes the loop yield every 128 batches, so with more than 128
/// waiting, other tasks of the same instant see this loop's effects (an EPS switch's power)
/// before they run. Deterministic either way.
fn handle_batch(
    first: Option<RunEvent>,
    ev_rx: &mut mpsc::UnboundedReceiver<RunEvent>,
    power_shell: &mut power::PowerShell,
    sink: &mut dyn RunSink,
    kiss_budget: &tokio::sync::Semaphore,
) {
    let mut next = first;
    let mut left = EVENTS_PER_WAKE;
    while let Some(ev) = next {
        // An EPS channel switch takes effect through the power rules, whose news comes
        // first.
        if let RunEvent::Eps(o) = &ev
            && let nodes_eps::EpsOutput::Channel { t, channel, on, .. } = **o
        {
            for e in power_shell.eps_channel(t, channel, on) {
                hand_on(e, sink, kiss_budget);
            }
        }
        hand_on(ev, sink, kiss_budget);
        left -= 1;
        next = if left > 0 {
            ev_rx.try_recv().ok()
        } else {
            None
        };
    }
}

/// The fault director of a run's media, nodes, power and links.
fn director<'a>(
    segs: &'a bus::outside::Segments,
    ctls: &'a BTreeMap<u8, bus::driver::CtlTx>,
    power: &'a mut power::PowerShell,
    links: &'a [bus::gate::LinkGate],
) -> faults::Director<'a> {
    faults::Director {
        segs,
        ctls,
        power,
        links,
    }
}

/// Apply one fault at its instant: the fault's event, then what it did.
fn apply_fault(
    f: &TimedFault,
    director: &mut faults::Director<'_>,
    sink: &mut dyn RunSink,
    kiss_budget: &tokio::sync::Semaphore,
) {
    let effects = director.apply(f);
    if let FaultAction::Contact(on) = f.action {
        sink.contact(f.at, on);
    }
    tracing::info!(t = %f.at, "fault: {}", f.what);
    hand_on(
        RunEvent::Fault {
            t: f.at,
            what: f.what.clone(),
        },
        sink,
        kiss_budget,
    );
    for e in effects {
        hand_on(e, sink, kiss_budget);
    }
}

/// Stop every node at the end of the run and take its final report, in node order, so
/// that the final reports sit in the event stream deterministically.
async fn stop_nodes(
    tasks: Vec<build::NodeTask>,
    sim_time: SimTime,
    ev_tx: &mpsc::UnboundedSender<RunEvent>,
) -> anyhow::Result<Vec<NodeReport>> {
    for n in &tasks {
        let _ = n.ctl.send((SimTime::ZERO, NodeCtl::Stop));
    }
    let mut node_reports = Vec::new();
    for build::NodeTask {
        spec, core, handle, ..
    } in tasks
    {
        handle
            .await
            .with_context(|| format!("node {} task failed", spec.name))?;
        let mut core = bus::driver::lock_core(&core);
        let host = &mut core.host;
        host.app.finish(&mut host.node, sim_time);
        while let Some(e) = host.poll_event() {
            let _ = ev_tx.send(e);
        }
        node_reports.push(NodeReport {
            name: spec.name,
            addr: spec.addr,
            counters: host.node.counters().clone(),
        });
    }
    Ok(node_reports)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn socketcan_argument_names_interface_and_bus() {
        let parse = SocketCanBus::parse_arg;
        assert_eq!(parse("vcan0"), Ok(("vcan0".to_owned(), SocketCanBus::Main)));
        assert_eq!(
            parse("can0:main"),
            Ok(("can0".to_owned(), SocketCanBus::Main))
        );
        assert_eq!(
            parse("can1:payload"),
            Ok(("can1".to_owned(), SocketCanBus::Payload))
        );
        let e = parse("can0:ground").expect_err("no such bus");
        assert_eq!(
            e,
            LinkArgError::UnknownBus {
                bus: "ground".into()
            }
        );
        assert_eq!(
            e.to_string(),
            "unknown bus `ground`: expected IFACE, IFACE:main or IFACE:payload"
        );
        assert_eq!(parse(":main"), Err(LinkArgError::NoInterface));
        assert_eq!(parse(""), Err(LinkArgError::NoInterface));
    }

    #[test]
    fn unusable_socketcan_interface_fails_the_run_naming_it() {
        let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(1));
        opts.socketcan = vec![("m6pnosuch0".to_owned(), SocketCanBus::Main)];
        let rt = build_runtime().expect("runtime");
        let err = rt
            .block_on(run_with(opts, None, &mut |_: &RunEvent| {}))
            .expect_err("the interface does not exist");
        let msg = format!("{err:#}");
        assert!(msg.contains("m6pnosuch0"), "{msg}");
        if cfg!(not(all(feature = "socketcan", target_os = "linux"))) {
            assert!(msg.contains("rebuild with --features socketcan"), "{msg}");
        }
    }
}
