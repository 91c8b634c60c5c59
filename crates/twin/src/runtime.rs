//! Build the network of [`NetworkSpec`] on its media, run every node as its own tokio task
//! on one current-thread runtime, and report what happened.
//!
//! In virtual time the runtime's clock is paused and jumps to the next timer, so a run is
//! deterministic (same options and seed, same trace) and as fast as the CPU allows. In real
//! time the same tasks follow the wall clock, which is what outside programs need; a run
//! with outside links is always in real time.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use bus::can::BusStats;
use bus::driver::{Attachment, CtlTx, NodeCtl, run_node_with};
use bus::inbox::inbox;
use bus::kiss_tcp::{self, KissLinkConfig, KissLinkStats, KissTap};
use bus::net::NetStats;
use bus::outside::{BridgeStats, Segments};
use bus::trace::{TraceEvent, TraceTx};
use bus::{CanBus, CanBusConfig, Clock, ClockMode, PacketNet, PacketNetConfig};
use csp::SimTime;
use csp::node::{App, Host, MapEvents, NodeCounters};
use tokio::sync::{mpsc, oneshot};

use crate::events::{Direction, RunEvent};
use crate::ground::{GroundApp, PlannedRequest, RequestResult, Results};
use crate::network::{Medium, NetworkSpec, Role, node_config};
use crate::plan::{FaultAction, MediumId, TimedFault};
use platform::board::Boards;

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
    /// KISS/TCP servers to open for outside nodes.
    pub kiss_listen: Vec<SocketAddr>,
    /// KISS/TCP servers of outside nodes to connect to.
    pub kiss_connect: Vec<SocketAddr>,
    /// Settings of every KISS link.
    pub kiss: KissLinkConfig,
    /// Requests each internal ground station sends, by station address.
    pub ground_plan: BTreeMap<u8, Vec<PlannedRequest>>,
    /// Real CAN interfaces (`can0`, `vcan0`) to bridge to a bus of the twin; needs the
    /// `socketcan` cargo feature (Linux) when not empty.
    pub socketcan: Vec<(String, SocketCanBus)>,
    /// UTC unix seconds at simulated time zero.
    pub epoch_unix_s: u64,
    /// The satellite's two TLE lines (the FC propagates them); `None`: no orbit.
    pub tle: Option<(String, String)>,
    /// Keep the trace of every frame and packet in the report.
    pub trace: bool,
    /// Faults to apply, in time order.
    pub faults: Vec<TimedFault>,
    /// Recorded input of outside links to feed again (`replay`), one connection per link.
    pub kiss_replay: Vec<KissReplay>,
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
}

/// What an outside program sent on one KISS link during a recorded run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KissReplay {
    /// The link's name in the recording (for example `listen 127.0.0.1:52001`).
    pub link: String,
    /// The bytes read from the socket, with the times they were read.
    pub chunks: Vec<(SimTime, Vec<u8>)>,
}

impl RunOptions {
    /// The default network for `duration` of virtual time with seed 1.
    pub fn new(network: NetworkSpec, duration: Duration) -> Self {
        RunOptions {
            network,
            duration: Some(duration),
            clock: ClockMode::Virtual,
            seed: 1,
            kiss_listen: Vec::new(),
            kiss_connect: Vec::new(),
            kiss: KissLinkConfig::default(),
            ground_plan: BTreeMap::new(),
            socketcan: Vec::new(),
            epoch_unix_s: 1_577_836_800,
            tle: None,
            trace: false,
            faults: Vec::new(),
            kiss_replay: Vec::new(),
            fc: nodes_fc::FcConfig::default(),
            pc: nodes_pc::PcConfig::default(),
            payloads: BTreeMap::new(),
            eps: nodes_eps::EpsConfig::default(),
            ecu: nodes_ecu::EcuConfig::default(),
            comm: nodes_comm::CommConfig::default(),
        }
    }

    /// Whether the run has links to programs outside the twin.
    pub fn has_outside_links(&self) -> bool {
        !self.kiss_listen.is_empty() || !self.kiss_connect.is_empty() || !self.socketcan.is_empty()
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
    pub fn parse_arg(arg: &str) -> Result<(String, SocketCanBus), String> {
        let (ifname, which) = match arg.rsplit_once(':') {
            Some((i, "main")) => (i, SocketCanBus::Main),
            Some((i, "payload")) => (i, SocketCanBus::Payload),
            Some((_, other)) => {
                return Err(format!(
                    "unknown bus `{other}`: expected IFACE, IFACE:main or IFACE:payload"
                ));
            }
            None => (arg, SocketCanBus::Main),
        };
        if ifname.is_empty() {
            return Err("missing interface name: expected IFACE[:main|:payload]".to_owned());
        }
        Ok((ifname.to_owned(), which))
    }
}

/// Counters of one node at the end of a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeReport {
    /// Node name.
    pub name: String,
    /// CSP address.
    pub addr: u8,
    /// Its counters.
    pub counters: NodeCounters,
}

/// What a run did.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// Simulated time reached.
    pub sim_time: SimTime,
    /// Wall-clock time taken.
    pub wall: Duration,
    /// Per-node counters, in start order.
    pub nodes: Vec<NodeReport>,
    /// Main and payload CAN bus counters.
    pub buses: Vec<BusStats>,
    /// Ground segment counters.
    pub ground: NetStats,
    /// KISS/TCP link counters, by link.
    pub kiss: Vec<(String, KissLinkStats)>,
    /// SocketCAN bridge counters, by interface and bus (`vcan0 (main bus)`).
    pub socketcan: Vec<(String, BridgeStats)>,
    /// Outcomes of the ground stations' requests.
    pub results: Vec<RequestResult>,
    /// Every frame and packet, when tracing was asked for.
    pub trace: Vec<TraceEvent>,
    /// The FC's published attitude samples, in time order (for expectations).
    pub attitude: Vec<AttitudeSample>,
    /// The PC's sessions, downlinked and dropped bytes, and what the payloads produced.
    pub sessions: crate::sessions::SessionsReport,
    /// The EPS's samples, in time order (for expectations).
    pub power: Vec<PowerSample>,
    /// Beacons received on the ground: (time, sending COMM, sequence number).
    pub beacons: Vec<(SimTime, u8, u32)>,
    /// UHF contact switches applied (pass modelling): (time, in contact).
    pub contact: Vec<(SimTime, bool)>,
}

/// The figures of one EPS sample that expectations check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PowerSample {
    /// When.
    pub t: SimTime,
    /// State of charge, 0..1.
    pub soc: f64,
    /// Battery voltage, V.
    pub battery_v: f64,
    /// Battery current, A (positive charging).
    pub battery_a: f64,
    /// Solar array power, W.
    pub solar_w: f64,
    /// Total load, W.
    pub load_w: f64,
}

/// The figures of one published FC snapshot that expectations check.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeSample {
    /// When.
    pub t: SimTime,
    /// True body rate magnitude, deg/s.
    pub rate_deg_s: f64,
    /// True attitude to target attitude, deg.
    pub pointing_error_deg: Option<f64>,
    /// The mode's pointing axis to its target direction, deg.
    pub axis_error_deg: Option<f64>,
    /// True attitude to estimate, deg.
    pub estimation_error_deg: Option<f64>,
    /// Elevation of the satellite at the ground target, deg.
    pub target_elevation_deg: Option<f64>,
    /// Fastest wheel, rpm (magnitude).
    pub max_wheel_rpm: f64,
    /// Visible fraction of the sun.
    pub sun_visible_fraction: f64,
    /// Mode in effect.
    pub mode: u8,
    /// Distance of the true position from the scenario TLE's SGP4 position, m (grows after
    /// a burn, when the truth follows the numerical orbit).
    pub tle_offset_m: Option<f64>,
    /// ADCS state.
    pub state: u8,
}

impl AttitudeSample {
    /// The sample of one published snapshot pair.
    pub fn of(
        t: SimTime,
        truth: &platform::truth::TruthSnapshot,
        adcs: &platform::truth::AdcsSnapshot,
    ) -> Self {
        AttitudeSample {
            t,
            rate_deg_s: truth.w_body_rad_s.norm().to_degrees(),
            pointing_error_deg: adcs.pointing_error_deg,
            axis_error_deg: adcs.axis_error_deg,
            estimation_error_deg: adcs.estimation_error_deg,
            target_elevation_deg: adcs.target_elevation_deg,
            max_wheel_rpm: truth
                .wheel_speed_rad_s
                .iter()
                .fold(0.0_f64, |m, w| m.max(w.abs()))
                * 60.0
                / std::f64::consts::TAU,
            sun_visible_fraction: truth.in_eclipse_fraction_visible,
            mode: adcs.mode_in_effect,
            state: adcs.state,
            tle_offset_m: None,
        }
    }
}

/// A tokio runtime for `mode`: current-thread, with a paused clock in virtual time.
pub fn build_runtime(mode: ClockMode) -> anyhow::Result<tokio::runtime::Runtime> {
    let mut b = tokio::runtime::Builder::new_current_thread();
    b.enable_all();
    if mode == ClockMode::Virtual {
        b.start_paused(true);
    }
    b.build().context("building the tokio runtime")
}

/// A well-mixed 64-bit value from the run seed and a salt (splitmix64).
pub fn mix(seed: u64, salt: u64) -> u64 {
    let mut z = seed ^ salt.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A node's application, its events turned into [`RunEvent`]s (`crate::events`).
type NodeApp = Box<dyn App<Event = RunEvent>>;

fn app_for(
    role: Role,
    addr: u8,
    opts: &RunOptions,
    boards: &Boards,
    plan: Vec<PlannedRequest>,
    results: &Results,
) -> NodeApp {
    match role {
        Role::CommPrimary | Role::CommSecondary => {
            let mut cfg = if role == Role::CommPrimary {
                opts.comm.clone()
            } else {
                nodes_comm::CommConfig {
                    role: nodes_comm::CommRole::Secondary,
                    ..opts.comm.clone()
                }
            };
            cfg.air_rate_bps = opts.network.uhf_rate_bps;
            let app = nodes_comm::CommApp::new(cfg).with_truth(boards.truth.clone());
            Box::new(MapEvents::new(app, |never| match never {}))
        }
        Role::Fc => Box::new(MapEvents::new(
            nodes_fc::FcApp::new(opts.fc.clone())
                .with_truth_board(boards.truth.clone())
                .with_burns(boards.burns.clone()),
            RunEvent::from,
        )),
        // Its channel switches go to the platform's power rules in the main loop.
        Role::Eps => Box::new(MapEvents::new(
            nodes_eps::EpsApp::new(opts.eps.clone())
                .with_truth(boards.truth.clone())
                .with_activity(boards.activity.clone()),
            RunEvent::from,
        )),
        Role::Ecu => Box::new(MapEvents::new(
            nodes_ecu::EcuApp::new(opts.ecu.clone())
                .with_burns(boards.burns.clone())
                .with_activity(boards.activity.clone()),
            RunEvent::from,
        )),
        Role::Pc => Box::new(MapEvents::new(
            nodes_pc::PcApp::new(opts.pc.clone()).with_activity(boards.activity.clone()),
            RunEvent::from,
        )),
        Role::Payload => {
            let cfg = opts.payloads.get(&addr).cloned().unwrap_or_default();
            Box::new(MapEvents::new(
                nodes_payload::PayloadApp::new(cfg),
                move |out| RunEvent::Payload { addr, out },
            ))
        }
        Role::Ground => Box::new(GroundApp::new(plan, results.clone())),
    }
}

/// Run the twin. `ready` receives the bound addresses of the KISS servers once they listen.
pub async fn run(
    opts: RunOptions,
    ready: Option<oneshot::Sender<Vec<SocketAddr>>>,
) -> anyhow::Result<RunReport> {
    run_with(opts, ready, &mut |_| {}).await
}

/// [`run`], handing every [`RunEvent`] to `sink` in the order they happen (the recorder).
pub async fn run_with(
    mut opts: RunOptions,
    ready: Option<oneshot::Sender<Vec<SocketAddr>>>,
    sink: &mut (dyn FnMut(&RunEvent) + Send),
) -> anyhow::Result<RunReport> {
    let wall_start = Instant::now();
    let clock = Clock::new(opts.clock);
    let segs = Segments {
        main: CanBus::new(
            CanBusConfig {
                name: "main".into(),
                bitrate_bps: opts.network.main_bitrate_bps,
            },
            mix(opts.seed, 0x100),
        ),
        payload: CanBus::new(
            CanBusConfig {
                name: "payload".into(),
                bitrate_bps: opts.network.payload_bitrate_bps,
            },
            mix(opts.seed, 0x101),
        ),
        ground: PacketNet::new(
            PacketNetConfig {
                air_rate_bps: opts.network.uhf_rate_bps,
                ..PacketNetConfig::ground()
            },
            mix(opts.seed, 0x102),
        ),
    };
    // Every event of the run goes through one channel, in the order it happens.
    let (ev_tx, mut ev_rx) = mpsc::unbounded_channel::<RunEvent>();
    let tracer = {
        let tx = ev_tx.clone();
        TraceTx::new(move |e| {
            let _ = tx.send(RunEvent::Medium(e));
        })
    };
    segs.main.set_trace(tracer.clone());
    segs.payload.set_trace(tracer.clone());
    segs.ground.set_trace(tracer);
    let mut background = vec![
        tokio::spawn(segs.main.clone().run(clock)),
        tokio::spawn(segs.payload.clone().run(clock)),
        tokio::spawn(segs.ground.clone().run(clock)),
    ];
    let socketcan_stats = spawn_socketcan_bridges(&opts.socketcan, &segs, clock, &mut background)?;

    let results: Results = Arc::new(Mutex::new(Vec::new()));
    opts.fc = nodes_fc::FcConfig {
        epoch_unix_s: opts.epoch_unix_s,
        tle: opts.tle.clone(),
        seed: mix(opts.seed, 0x300),
        ..opts.fc.clone()
    };
    let boards = Boards::default();
    let mut comm_ports = Vec::new();
    {
        // Every radio transmission is charged to its COMM's transmitter, at its place on the
        // air.
        let activity = boards.activity.clone();
        segs.ground
            .set_air_tap(bus::net::AirTap::new(move |radio, start, end| {
                use platform::board::Activity;
                // The radio endpoints are named `<node>-uhf` (see the attachments below).
                let what = if radio == "COMM2-uhf" {
                    Activity::UhfTxSecondary
                } else {
                    Activity::UhfTx
                };
                for (t, on) in [(start, true), (end, false)] {
                    if let Err(e) = activity.set(what, t, on) {
                        tracing::warn!(%t, "{radio}: air time not charged: {e}");
                    }
                }
            }));
    }
    let mut nodes = Vec::new();
    for spec in &opts.network.nodes {
        let (mut cfg, media) = node_config(spec);
        let salt = u64::from(spec.addr);
        cfg.cfp_first_ident = (mix(opts.seed, salt) % 1024) as u16;
        cfg.first_ephemeral_port = 32 + (mix(opts.seed, salt + 0x40) % 32) as u8;
        cfg.epoch_unix_s = opts.epoch_unix_s;
        let (inbox_tx, inbox_rx) = inbox();
        let ports: Vec<Attachment> = media
            .iter()
            .enumerate()
            .map(|(i, m)| match m {
                Medium::MainCan => Attachment::Can(segs.main.attach(
                    &spec.name,
                    &[spec.addr],
                    false,
                    inbox_tx.clone(),
                    i,
                )),
                Medium::PayloadCan => Attachment::Can(segs.payload.attach(
                    &spec.name,
                    &[spec.addr],
                    false,
                    inbox_tx.clone(),
                    i,
                )),
                Medium::GroundRadio | Medium::GroundRadioStandby => {
                    Attachment::Net(segs.ground.attach(
                        &format!("{}-uhf", spec.name),
                        &[],
                        true,
                        *m == Medium::GroundRadio,
                        inbox_tx.clone(),
                        i,
                    ))
                }
                Medium::Ground => Attachment::Net(segs.ground.attach(
                    &spec.name,
                    &[spec.addr],
                    false,
                    false,
                    inbox_tx.clone(),
                    i,
                )),
            })
            .collect();
        drop(inbox_tx);
        let plan = opts.ground_plan.remove(&spec.addr).unwrap_or_default();
        let app = app_for(spec.role, spec.addr, &opts, &boards, plan, &results);
        // Every node boots at the start of the run (in real time, not when its task is made).
        let mut host = Host::new(cfg, app, SimTime::ZERO);
        // What it reported at boot (the EPS's channels configured off) goes out now, in
        // node order, before any task runs.
        while let Some(e) = host.app.poll_event() {
            let _ = ev_tx.send(e);
        }
        let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
        if matches!(spec.role, Role::CommPrimary | Role::CommSecondary) {
            comm_ports.push((spec.addr, ports.clone()));
        }
        let out = ev_tx.clone();
        let handle =
            tokio::spawn(
                async move { run_node_with(host, ports, inbox_rx, ctl_rx, clock, out).await },
            );
        nodes.push((spec.clone(), ctl_tx, handle));
    }

    let mut kiss_cfg = opts.kiss.clone();
    {
        let tx = ev_tx.clone();
        kiss_cfg.tap = Some(KissTap::new(move |t, link, into_twin, bytes| {
            let _ = tx.send(RunEvent::Kiss {
                t,
                link: link.to_owned(),
                dir: if into_twin {
                    Direction::In
                } else {
                    Direction::Out
                },
                bytes: bytes.to_vec(),
            });
        }));
    }
    let mut kiss_stats = Vec::new();
    let mut bound = Vec::new();
    for addr in &opts.kiss_listen {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("listening for KISS/TCP on {addr}"))?;
        let local = listener.local_addr().context("reading the bound address")?;
        bound.push(local);
        let stats = Arc::new(Mutex::new(KissLinkStats::default()));
        kiss_stats.push((format!("listen {local}"), stats.clone()));
        background.push(tokio::spawn(kiss_tcp::serve(
            listener,
            format!("listen {addr}"),
            segs.clone(),
            kiss_cfg.clone(),
            stats,
            clock,
        )));
    }
    for addr in &opts.kiss_connect {
        let stats = Arc::new(Mutex::new(KissLinkStats::default()));
        kiss_stats.push((format!("connect {addr}"), stats.clone()));
        background.push(tokio::spawn(kiss_tcp::connect(
            *addr,
            format!("connect {addr}"),
            segs.clone(),
            kiss_cfg.clone(),
            stats,
            clock,
        )));
    }
    for (n, input) in opts.kiss_replay.iter().enumerate() {
        // Recorded outside input, fed through an in-memory pipe at its recorded times;
        // what the twin answers is recorded again and compared by `replay`.
        let stats = Arc::new(Mutex::new(KissLinkStats::default()));
        kiss_stats.push((format!("replayed {}", input.link), stats.clone()));
        let (in_tx, in_rx) = mpsc::unbounded_channel();
        let (segs2, cfg2, label) = (segs.clone(), kiss_cfg.clone(), input.link.clone());
        background.push(tokio::spawn(async move {
            let mut discard = tokio::io::sink();
            // The connection number seeds its CFP ident as in the recorded run.
            let conn = label
                .rsplit_once('#')
                .and_then(|(_, k)| k.parse().ok())
                .unwrap_or(n as u16 + 1);
            kiss_tcp::serve_link(in_rx, &mut discard, &label, &segs2, &cfg2, &stats, conn).await;
        }));
        let chunks = input.chunks.clone();
        background.push(tokio::spawn(async move {
            for (t, bytes) in chunks {
                clock.sleep_until(t).await;
                if in_tx.send((t, bytes)).is_err() {
                    break;
                }
            }
            // Keep the link open until the end of the run, as the recorded program was.
            std::future::pending::<()>().await;
        }));
    }
    if let Some(r) = ready {
        let _ = r.send(bound);
    }

    // Faults are applied by the main loop at their times, so that their events sit in the
    // stream exactly where they take effect.
    let ctls: BTreeMap<u8, CtlTx> = nodes
        .iter()
        .map(|(spec, ctl, _)| (spec.addr, ctl.clone()))
        .collect();
    // One truth for power: the EPS's switches and the power and hang faults go through
    // the platform's rules.
    let mut power_shell =
        crate::power::PowerShell::new(ctls.clone(), boards.activity.clone(), segs.clone());
    for (addr, ports) in &comm_ports {
        power_shell.register_comm(*addr, ports);
    }
    let mut faults = std::mem::take(&mut opts.faults).into_iter().peekable();
    let end = opts.duration.map_or(SimTime::MAX, |d| SimTime::ZERO + d);
    let mut trace = Vec::new();
    let mut attitude = Vec::new();
    let mut sessions = crate::sessions::SessionsReport::default();
    let mut power = Vec::new();
    let mut beacons = Vec::new();
    let mut contact = Vec::new();
    // The scenario TLE's own SGP4 orbit, to measure how far the truth has left it.
    let mut tle_orbit = opts.tle.as_ref().and_then(|(l1, l2)| {
        orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict)
            .ok()
            .and_then(|t| orbit::propagate::Sgp4Propagator::new(&t).ok())
    });
    let mut handle_event = |ev: RunEvent, trace: &mut Vec<TraceEvent>| {
        sink(&ev);
        sessions.observe(&ev);
        match ev {
            RunEvent::Medium(m) if opts.trace => trace.push(m),
            RunEvent::Truth { t, truth, adcs } => {
                let mut sample = AttitudeSample::of(t, &truth, &adcs);
                if let Some(p) = tle_orbit.as_mut() {
                    use orbit::propagate::Propagator as _;
                    sample.tle_offset_m = p
                        .state_j2000(orbit::time::UtcTime::from_unix_ns(truth.unix_ns))
                        .ok()
                        .map(|s| (truth.r_eci_m - s.r_km * 1e3).norm());
                }
                attitude.push(sample);
            }
            RunEvent::Beacon { t, from, data } => {
                let seq = data
                    .get(2..6)
                    .and_then(|b| <[u8; 4]>::try_from(b).ok())
                    .map_or(0, u32::from_le_bytes);
                beacons.push((t, from, seq));
            }
            RunEvent::Eps(o) => {
                if let nodes_eps::EpsOutput::Sample {
                    t,
                    soc,
                    battery_v,
                    battery_a,
                    solar_w,
                    load_w,
                    ..
                } = *o
                {
                    power.push(PowerSample {
                        t,
                        soc,
                        battery_v,
                        battery_a,
                        solar_w,
                        load_w,
                    });
                }
            }
            _ => {}
        }
    };
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    loop {
        let next_fault = faults.peek().map_or(SimTime::MAX, |f| f.at).min(end);
        tokio::select! {
            biased;
            _ = &mut ctrl_c => {
                tracing::info!("Ctrl-C: stopping");
                break;
            }
            ev = ev_rx.recv() => {
                if let Some(ev) = ev {
                    // An EPS channel switch takes effect through the power rules, whose news
                    // comes first.
                    if let RunEvent::Eps(o) = &ev
                        && let nodes_eps::EpsOutput::Channel { t, channel, on, .. } = **o
                    {
                        for e in power_shell.eps_channel(t, channel, on) {
                            handle_event(e, &mut trace);
                        }
                    }
                    handle_event(ev, &mut trace);
                }
            }
            () = clock.sleep_until(next_fault), if next_fault < SimTime::MAX => {
                if next_fault >= end && faults.peek().is_none_or(|f| f.at >= end) {
                    break;
                }
                while let Some(f) = faults.next_if(|f| f.at <= next_fault) {
                    let effects = apply_fault(&f, &segs, &ctls, &mut power_shell);
                    if let FaultAction::Contact(on) = f.action {
                        contact.push((f.at, on));
                    }
                    tracing::info!(t = %f.at, "fault: {}", f.what);
                    // The fault, then what it did.
                    handle_event(RunEvent::Fault { t: f.at, what: f.what.clone() }, &mut trace);
                    for e in effects {
                        handle_event(e, &mut trace);
                    }
                }
            }
        }
    }
    let sim_time = match opts.duration {
        Some(d) if clock.is_virtual() => SimTime::ZERO + d,
        _ => clock.now(),
    };

    for (_, ctl, _) in &nodes {
        let _ = ctl.send((SimTime::ZERO, NodeCtl::Stop));
    }
    let mut node_reports = Vec::new();
    for (spec, _, handle) in nodes {
        let mut host = handle
            .await
            .with_context(|| format!("node {} task failed", spec.name))?;
        // In node order, so that the final reports sit in the event stream deterministically.
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
    for h in background {
        h.abort();
    }
    drop(ev_tx);
    while let Ok(ev) = ev_rx.try_recv() {
        handle_event(ev, &mut trace);
    }
    let results = std::mem::take(
        &mut *results
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner),
    );
    Ok(RunReport {
        sim_time,
        wall: wall_start.elapsed(),
        nodes: node_reports,
        buses: vec![segs.main.stats(), segs.payload.stats()],
        ground: segs.ground.stats(),
        kiss: snapshot(kiss_stats),
        socketcan: snapshot(socketcan_stats),
        results,
        trace,
        attitude,
        sessions,
        power,
        beacons,
        contact,
    })
}

/// Shared counters of the SocketCAN bridges, by name.
type BridgeStatsList = Vec<(String, Arc<Mutex<BridgeStats>>)>;

/// Open every interface of `links` and spawn its bridge to the chosen bus.
#[cfg(all(feature = "socketcan", target_os = "linux"))]
fn spawn_socketcan_bridges(
    links: &[(String, SocketCanBus)],
    segs: &Segments,
    clock: Clock,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<BridgeStatsList> {
    let mut opened = Vec::new();
    for (ifname, which) in links {
        // The error names the interface and includes its OS cause (not chained: it would
        // print twice).
        let link = bus::socketcan::SocketCanLink::open(ifname)
            .map_err(|e| anyhow::anyhow!("cannot bridge to a SocketCAN interface: {e}"))?;
        opened.push((link, *which));
    }
    let mut stats = Vec::new();
    for (link, which) in opened {
        let can = match which {
            SocketCanBus::Main => segs.main.clone(),
            SocketCanBus::Payload => segs.payload.clone(),
        };
        let shared = Arc::new(Mutex::new(BridgeStats::default()));
        stats.push((format!("{} ({which} bus)", link.ifname()), shared.clone()));
        let task = bus::socketcan::bridge(can, link, clock, shared);
        background.push(tokio::spawn(task));
    }
    Ok(stats)
}

/// The final values of shared counters, by link name.
fn snapshot<T: Clone>(stats: Vec<(String, Arc<Mutex<T>>)>) -> Vec<(String, T)> {
    stats
        .into_iter()
        .map(|(n, s)| {
            (
                n,
                s.lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .clone(),
            )
        })
        .collect()
}

/// Apply one scenario fault to the media or a node; returns the log events of the power
/// rules.
fn apply_fault(
    f: &TimedFault,
    segs: &Segments,
    ctls: &BTreeMap<u8, CtlTx>,
    power: &mut crate::power::PowerShell,
) -> Vec<RunEvent> {
    match &f.action {
        FaultAction::Impair { medium, fault, imp } => {
            match medium {
                MediumId::Main => segs.main.set_fault(*fault, *imp),
                MediumId::Payload => segs.payload.set_fault(*fault, *imp),
                MediumId::Uhf => segs.ground.set_fault(*fault, *imp),
            }
            Vec::new()
        }
        FaultAction::Power { addr, fault, off } => power.power_fault(f.at, *addr, *fault, *off),
        FaultAction::Reboot(a) => {
            // A node that is off or hung does not reboot (the driver ignores it then).
            if let Some(tx) = ctls.get(a) {
                let _ = tx.send((f.at, NodeCtl::Reboot));
            }
            Vec::new()
        }
        FaultAction::Hang { addr, fault, hung } => power.hang_fault(f.at, *addr, *fault, *hung),
        // The FC applies its own faults from its timeline at its ticks.
        FaultAction::Fc => Vec::new(),
        FaultAction::Contact(on) => {
            segs.ground.set_contact(*on);
            Vec::new()
        }
    }
}

/// Without the `socketcan` feature there is nothing to bridge with.
#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
fn spawn_socketcan_bridges(
    links: &[(String, SocketCanBus)],
    _segs: &Segments,
    _clock: Clock,
    _background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<BridgeStatsList> {
    match links.first() {
        None => Ok(Vec::new()),
        Some((ifname, _)) => anyhow::bail!(
            "SocketCAN interface `{ifname}`: this m6p-twin was built without SocketCAN support; rebuild with --features socketcan (Linux only)"
        ),
    }
}

impl RunReport {
    /// The end-of-run table: per node packets in/out, forwarded, drops; per bus load.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let elapsed = self.sim_time - SimTime::ZERO;
        let _ = writeln!(
            s,
            "simulated {:.3} s in {:.3} s wall ({:.0}x real time)",
            self.sim_time.as_secs_f64(),
            self.wall.as_secs_f64(),
            self.sim_time.as_secs_f64() / self.wall.as_secs_f64().max(1e-9)
        );
        let _ = writeln!(
            s,
            "\n{:<7} {:>3} {:>9} {:>9} {:>9} {:>9} {:>7}  drops by reason",
            "node", "id", "pkts in", "pkts out", "forwarded", "to app", "drops"
        );
        for n in &self.nodes {
            let c = &n.counters;
            let reasons: Vec<String> = c.drops.iter().map(|(k, v)| format!("{k}: {v}")).collect();
            let _ = writeln!(
                s,
                "{:<7} {:>3} {:>9} {:>9} {:>9} {:>9} {:>7}  {}",
                n.name,
                n.addr,
                c.rx_packets,
                c.tx_packets,
                c.forwarded,
                c.delivered + c.service_replies,
                c.total_drops(),
                reasons.join(", ")
            );
        }
        let _ = writeln!(
            s,
            "\n{:<8} {:>10} {:>11} {:>9} {:>8} {:>8}",
            "bus", "frames", "data bytes", "load %", "dropped", "corrupt"
        );
        for b in &self.buses {
            let _ = writeln!(
                s,
                "{:<8} {:>10} {:>11} {:>9.3} {:>8} {:>8}",
                b.name,
                b.frames,
                b.bytes,
                100.0 * b.load(elapsed),
                b.dropped,
                b.corrupted
            );
        }
        let g = &self.ground;
        let _ = writeln!(
            s,
            "{:<8} {:>10} {:>11} {:>9.3} {:>8} {:>8}  (packets; UHF air load)",
            g.name,
            g.packets,
            g.bytes,
            100.0 * g.air_busy.as_secs_f64() / elapsed.as_secs_f64().max(1e-9),
            g.dropped,
            "-"
        );
        for (name, k) in &self.kiss {
            let _ = writeln!(
                s,
                "\nKISS/TCP {name}: {} connections, {} packets in, {} out, {} garbage bytes, {} bad CRC, {} short, {} oversize, {} refused",
                k.connections,
                k.packets_in,
                k.packets_out,
                k.garbage_bytes,
                k.bad_crc,
                k.short,
                k.oversize,
                k.refused
            );
        }
        for (name, b) in &self.socketcan {
            let _ = writeln!(
                s,
                "\nSocketCAN {name}: {} frames in, {} out, {} skipped, {} receive errors, {} send errors{}",
                b.frames_in,
                b.frames_out,
                b.skipped,
                b.recv_errors,
                b.send_errors,
                b.ended
                    .as_ref()
                    .map(|why| format!("; stopped: {why}"))
                    .unwrap_or_default()
            );
        }
        if !self.results.is_empty() {
            let ok = self
                .results
                .iter()
                .filter(|r| matches!(r.outcome, crate::ground::Outcome::Reply { .. }))
                .count();
            let open = self
                .results
                .iter()
                .filter(|r| matches!(r.outcome, crate::ground::Outcome::Unfinished))
                .count();
            let _ = writeln!(
                s,
                "\nground requests: {} sent, {} answered, {} unanswered{}",
                self.results.len(),
                ok,
                self.results.len() - ok - open,
                if open > 0 {
                    format!(", {open} still waiting at the end")
                } else {
                    String::new()
                }
            );
        }
        s
    }
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
        assert!(parse("can0:ground").is_err_and(|e| e.contains("ground")));
        assert!(parse(":main").is_err());
        assert!(parse("").is_err());
    }

    #[test]
    fn unusable_socketcan_interface_fails_the_run_naming_it() {
        let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(1));
        opts.socketcan = vec![("m6pnosuch0".to_owned(), SocketCanBus::Main)];
        let rt = build_runtime(opts.clock).expect("runtime");
        let err = rt
            .block_on(run(opts, None))
            .expect_err("the interface does not exist");
        let msg = format!("{err:#}");
        assert!(msg.contains("m6pnosuch0"), "{msg}");
        if cfg!(not(all(feature = "socketcan", target_os = "linux"))) {
            assert!(msg.contains("rebuild with --features socketcan"), "{msg}");
        }
    }
}
