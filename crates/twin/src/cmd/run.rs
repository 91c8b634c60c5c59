//! `m6p-twin run`: run a scenario, with its outside links, recording and live view.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use bus::ClockMode;
use m6p_twin::duration::parse_duration;
use m6p_twin::exec;
use m6p_twin::runtime::{SocketCanBus, build_runtime_for};

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Scenario file (TOML) [default: the embedded scenarios/default.toml].
    pub scenario: Option<PathBuf>,
    /// Simulated duration, overriding the scenario's: 90, 90s, 10m, 2h.
    #[arg(long, value_parser = parse_duration)]
    pub duration: Option<Duration>,
    /// Seed, overriding the scenario's.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Record the run to this MCAP file (overrides the scenario's `record.file`). Written
    /// beside it and put in place when complete; a file already there is refused unless
    /// --overwrite.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Replace a file already at the recording's name (once the new one is complete; never
    /// the scenario itself).
    #[arg(long)]
    pub overwrite: bool,
    /// Which channels the recording holds (overrides the scenario's `record.channels`):
    /// comma-separated rules, the last matching a topic deciding: `TOPIC` keeps it, `-TOPIC`
    /// leaves it out, `TOPIC@PERIOD` keeps at most one message per PERIOD of simulated
    /// time; a topic may end in `*`. Default: every channel, every message
    /// (docs/recording.md, "Choosing the channels").
    #[arg(long, value_name = "RULES", allow_hyphen_values = true, value_parser = parse_channel_rules)]
    pub channels: Option<ChannelRules>,
    /// Write what the ground receives of each payload session (one file per session run)
    /// into DIR, overriding the scenario's `[pc] downlink_dir` [default: beside the
    /// recording, `x.mcap` -> `x.downlink/`; nowhere without one].
    #[arg(long, value_name = "DIR")]
    pub downlink_dir: Option<PathBuf>,
    /// Follow the wall clock (needed by outside programs; implied by --kiss-* and --socketcan).
    #[arg(long)]
    pub realtime: bool,
    /// With --realtime: simulated seconds per wall second.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Virtual time until WHEN, real time (at --speed) after it: a simulated time
    /// ("13000s"), "first pass" or "first pass over STATION" (see `m6p-twin passes`).
    /// Outside links are open from the start.
    #[arg(long, value_name = "WHEN")]
    pub realtime_from: Option<m6p_twin::clock::RealtimeFrom>,
    /// With --realtime and no --duration: run until Ctrl-C instead of the scenario's duration.
    #[arg(long)]
    pub forever: bool,
    /// Lab mode: the platform without the scenario's expectations and invariants, for
    /// interactive work, a shortened run or your own payload program in a simulated one's
    /// place. Nothing is judged; the exit status says whether the run reached its end.
    #[arg(long)]
    pub no_checks: bool,
    /// Listen for outside CSP nodes speaking KISS over TCP (for example 127.0.0.1:52001).
    #[arg(long = "kiss-listen", value_name = "ADDR")]
    pub kiss_listen: Vec<SocketAddr>,
    /// Connect to an outside KISS/TCP server, as the platform does in ICD 2.3.
    #[arg(long = "kiss-connect", value_name = "ADDR")]
    pub kiss_connect: Vec<SocketAddr>,
    /// KISS on a pseudo-terminal linked at PATH, for a program using libcsp's usart driver
    /// (`usart_init(PATH)`): no socat needed. The program may close and reopen it.
    #[arg(long = "kiss-pty", value_name = "PATH")]
    pub kiss_pty: Vec<PathBuf>,
    /// Play libcsp 1.4's ZMQ hub on HOST (programs call csp_zmqhub_init(addr, "HOST")):
    /// HOST or HOST:PUB_PORT:SUB_PORT [default ports: 6000 7000]. Any 127.0.0.x works.
    #[arg(long = "zmq-hub", value_name = "HOST")]
    pub zmq_hub: Vec<links::zmq_hub::HubAddr>,
    /// CSP over UDP, one packet per datagram (YAMCS's CSP links): the twin binds BIND
    /// (IP:PORT) and sends to PEER, or without one to the source of the latest datagram.
    #[arg(long = "udp", value_name = "BIND[,PEER]")]
    pub udp: Vec<links::udp::UdpAddr>,
    /// A CSP address behind the --kiss-listen, --kiss-connect, --kiss-pty, --zmq-hub or
    /// --udp before it (repeat for more);
    /// claimed when a program connects, and the only sources that link accepts. A link
    /// without any learns them from the packets it receives. The address of a simulated
    /// node (a payload, the FC, a ground station) replaces that node: it is not started.
    #[arg(long = "kiss-addr", value_name = "ID")]
    pub kiss_addr: Vec<u8>,
    /// Connections each --kiss-listen serves at once; a new one closes the longest-idle
    /// connection (logged).
    #[arg(long, value_name = "N", default_value_t = 16)]
    pub kiss_max_connections: usize,
    /// How long a --kiss-listen connection holding no address may go without a byte before
    /// it is closed (60s; "off": never).
    #[arg(long, value_name = "DURATION|off", default_value = "60s")]
    pub kiss_idle_timeout: m6p_twin::scenario::IdleLimit,
    /// At most N CAN frames a second from each connection of the command line's KISS links
    /// on a CAN bus (a runaway program with a low address then leaves room to others).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub kiss_tx_budget: Option<u32>,
    /// Apply libcsp 1.4's KISS receive limit (at most 248 data bytes) to the twin's receiver.
    #[arg(long)]
    pub libcsp14_kiss_limit: bool,
    /// A node's text console (its UART, ICD 1.1): NODE=ADDR serves it over TCP (`nc 127.0.0.1
    /// 5010`), NODE=PATH on a pseudo-terminal linked at PATH (`screen PATH`). Repeatable.
    #[arg(long = "uart", value_name = "NODE=ADDR|PATH", value_parser = m6p_twin::runtime::UartLink::parse_arg)]
    pub uart: Vec<m6p_twin::runtime::UartLink>,
    /// Bridge a bus to a real SocketCAN interface: IFACE[:main|:payload] [default bus:
    /// main]. Needs a build with --features socketcan (Linux).
    #[arg(long = "socketcan", value_name = "IFACE[:main|:payload]", value_parser = SocketCanBus::parse_arg)]
    pub socketcan: Vec<(String, SocketCanBus)>,
    /// Serve the run live over the Foxglove WebSocket protocol on ADDR (IP:PORT or a port)
    /// [default: 127.0.0.1:8765]; implies real time. Needs a build with --features live.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765", value_parser = parse_live_addr)]
    pub live: Option<SocketAddr>,
    /// Serve the run's control channel on ADDR (a loopback IP:PORT, or a port on
    /// 127.0.0.1): line-delimited JSON requests to inject a fault now or later, clear it,
    /// read the simulated time (`m6p-twin gs --control ADDR fault|clear|time`); each is
    /// recorded on `/control` and replayed. Implies real time (docs/control.md).
    #[arg(long, value_name = "ADDR", value_parser = parse_control_addr)]
    pub control: Option<SocketAddr>,
    /// Take a snapshot of the whole twin where the run has settled at each of these
    /// simulated instants (comma-separated: 1h,90m), into --snapshot (docs/snapshots.md).
    #[arg(long, value_name = "T[,T...]", value_parser = parse_duration, value_delimiter = ',', requires = "snapshot")]
    pub snapshot_at: Vec<Duration>,
    /// The snapshot file (with several instants, each named for its own:
    /// `x.snap` -> `x.3600000000000ns.snap`).
    #[arg(long, value_name = "FILE", requires = "snapshot_at")]
    pub snapshot: Option<PathBuf>,
    /// Carry a snapshot every T of simulated time in the recording (overrides the
    /// scenario's `record.snapshot_every`), so that `replay --from` starts near where it
    /// compares (docs/snapshots.md, "Seeking a recording").
    #[arg(long, value_name = "T", value_parser = parse_duration)]
    pub snapshot_every: Option<Duration>,
    /// Where the snapshots the control channel asks for go (`gs snapshot`), each named by
    /// its instant (`snapshot-<ns>ns.snap`); without it, such requests are refused.
    #[arg(long, value_name = "DIR", requires = "control")]
    pub snapshot_dir: Option<PathBuf>,
    /// Start from a snapshot taken by this build of this scenario with this seed, instead
    /// of from the start: the run goes on from its instant as the run that took it did.
    #[arg(long, value_name = "FILE")]
    pub from_snapshot: Option<PathBuf>,
}

/// A run's result, its error naming the snapshot it started `from` (a part of the snapshot
/// that does not fit the run is found while it runs).
fn naming_snapshot<T>(ran: anyhow::Result<T>, from: Option<&std::path::Path>) -> anyhow::Result<T> {
    match from {
        Some(p) => {
            anyhow::Context::with_context(ran, || format!("running from snapshot {}", p.display()))
        }
        None => ran,
    }
}

/// The run's snapshots: those to take, and the one it starts from.
fn snapshot_options(
    opts: &mut m6p_twin::runtime::RunOptions,
    a: &RunArgs,
    loaded: &exec::Loaded,
) -> anyhow::Result<()> {
    opts.snapshot_at = a
        .snapshot_at
        .iter()
        .map(|d| csp::SimTime::ZERO + *d)
        .collect();
    opts.snapshot_to.clone_from(&a.snapshot);
    let snapshots = a.snapshot_dir.is_some()
        || !a.snapshot_at.is_empty()
        || a.from_snapshot.is_some()
        || a.snapshot_every.is_some()
        || loaded.scenario.record.snapshot_every.is_some();
    if snapshots && !opts.socketcan.is_empty() {
        anyhow::bail!(
            "a run bridging SocketCAN takes no snapshot and starts from none: a bridge's \
             interface is not saved (docs/snapshots.md, \"Outside programs\")"
        );
    }
    let Some(path) = &a.from_snapshot else {
        return Ok(());
    };
    let scenario = (loaded.name(), loaded.text.as_str());
    let resume = m6p_twin::snapshots::resume_from(path, (&scenario.0, scenario.1), opts.seed)?;
    let records = a.record.is_some() || loaded.scenario.record.file.is_some();
    if records && resume.section(m6p_twin::record::RECORD_SECTION).is_err() {
        anyhow::bail!(
            "{}: taken by a run that did not record, so it holds no recorder state: a \
             recording goes on only from a snapshot taken with --record (or run it without \
             --record and the scenario's record.file)",
            path.display()
        );
    }
    // Real time begins where the run does.
    opts.clock = match opts.clock {
        ClockMode::Realtime { speed } => ClockMode::VirtualThenRealtime {
            from: resume.t,
            speed,
        },
        ClockMode::VirtualThenRealtime { from, speed } => ClockMode::VirtualThenRealtime {
            from: from.max(resume.t),
            speed,
        },
        ClockMode::Virtual => ClockMode::Virtual,
    };
    eprintln!("from snapshot {} at {}", path.display(), resume.t);
    opts.resume = Some(resume);
    Ok(())
}

/// `--control ADDR`: a loopback IP:PORT, or a port on 127.0.0.1.
pub fn parse_control_addr(s: &str) -> Result<SocketAddr, String> {
    let addr = match s.parse::<u16>() {
        Ok(port) => SocketAddr::from(([127, 0, 0, 1], port)),
        Err(_) => s
            .parse::<SocketAddr>()
            .map_err(|_| "expected IP:PORT or a port".to_owned())?,
    };
    if addr.ip().is_loopback() {
        Ok(addr)
    } else {
        Err(format!(
            "{addr}: the control channel listens on a loopback address only (127.0.0.1, ::1): \
             it can power nodes off"
        ))
    }
}

/// `--live ADDR`: IP:PORT, or a port on 127.0.0.1.
pub fn parse_live_addr(s: &str) -> Result<SocketAddr, String> {
    if let Ok(port) = s.parse::<u16>() {
        return Ok(SocketAddr::from(([127, 0, 0, 1], port)));
    }
    s.parse().map_err(|_| {
        "expected IP:PORT or a port (a scenario file after a bare --live: write it first, \
         or --live=127.0.0.1:8765)"
            .to_owned()
    })
}

/// The command line's KISS links, in order, each with the `--kiss-addr`s that follow it.
pub fn cli_kiss_links(
    m: &clap::ArgMatches,
    a: &RunArgs,
) -> anyhow::Result<Vec<m6p_twin::runtime::KissLink>> {
    use m6p_twin::runtime::{KissLink, KissMode};
    let at =
        |id: &str| -> Vec<usize> { m.indices_of(id).map(Iterator::collect).unwrap_or_default() };
    let mut links: Vec<(usize, KissLink)> = at("kiss_listen")
        .into_iter()
        .zip(&a.kiss_listen)
        .map(|(i, &addr)| (i, KissLink::listen(addr)))
        .chain(
            at("kiss_connect")
                .into_iter()
                .zip(&a.kiss_connect)
                .map(|(i, &addr)| (i, KissLink::connect(addr))),
        )
        .chain(
            at("kiss_pty")
                .into_iter()
                .zip(&a.kiss_pty)
                .map(|(i, p)| (i, KissLink::new(KissMode::Pty(p.clone())))),
        )
        .chain(
            at("zmq_hub")
                .into_iter()
                .zip(&a.zmq_hub)
                .map(|(i, &h)| (i, KissLink::new(KissMode::ZmqHub(h)))),
        )
        .chain(
            at("udp")
                .into_iter()
                .zip(&a.udp)
                .map(|(i, &u)| (i, KissLink::new(KissMode::Udp(u)))),
        )
        .collect();
    links.sort_by_key(|(i, _)| *i);
    for (i, &id) in at("kiss_addr").into_iter().zip(&a.kiss_addr) {
        if id >= 31 {
            anyhow::bail!("--kiss-addr {id}: not a unicast CSP address (0-30)");
        }
        let Some((_, link)) = links.iter_mut().rev().find(|(j, _)| *j < i) else {
            anyhow::bail!(
                "--kiss-addr {id} comes before any --kiss-listen, --kiss-connect, --kiss-pty, \
                 --zmq-hub or --udp: it names an address of the link before it"
            );
        };
        let first = link.cfg.addrs.first().copied();
        // The hub's programs may sit on several segments.
        if !matches!(link.mode, KissMode::ZmqHub(_))
            && let Some(f) = first
            && platform::addr::Segment::of(f) != platform::addr::Segment::of(id)
        {
            anyhow::bail!(
                "--kiss-addr {f} and {id} for {}: a KISS link joins one segment (12-15 payload \
                 bus, 16-20 ground, others main bus)",
                link.label()
            );
        }
        link.cfg.addrs.push(id);
    }
    Ok(links
        .into_iter()
        .map(|(_, mut l)| {
            l.cfg.decoder.libcsp14_rx_limit |= a.libcsp14_kiss_limit;
            l.cfg.limits.max_connections = a.kiss_max_connections.max(1);
            l.cfg.limits.idle_timeout = a.kiss_idle_timeout.duration();
            l.cfg.tx_frames_per_s = a.kiss_tx_budget;
            l
        })
        .collect())
}

pub fn cmd_run(a: RunArgs, cli_links: Vec<m6p_twin::runtime::KissLink>) -> anyhow::Result<bool> {
    let mut loaded = match &a.scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    if let Some(d) = &a.downlink_dir {
        loaded.scenario.pc.downlink_dir = Some(d.display().to_string());
    }
    if let Some(ChannelRules(rules)) = &a.channels {
        loaded.scenario.record.channels = rules.clone();
    }
    if let Some(every) = a.snapshot_every {
        if a.record.is_none() && loaded.scenario.record.file.is_none() {
            anyhow::bail!("--snapshot-every: the run is not recorded (add --record FILE)");
        }
        loaded.scenario.record.snapshot_every = Some(twin_scenario::dur::Dur(every));
    }
    let mut compiled = exec::compile_seeded(&loaded, a.seed);
    if a.no_checks {
        lab_mode(&mut compiled);
    }
    let opts = &mut compiled.opts;
    if let Some(d) = a.duration {
        opts.duration = Some(d);
    }
    add_links(opts, cli_links, &a)?;
    let inlet = control_options(opts, &a, &loaded.scenario);
    if cfg!(not(feature = "live")) && a.live.is_some() {
        anyhow::bail!(
            "--live needs the Foxglove WebSocket server, which this build leaves out: \
             rebuild with --features live (cargo build -p m6p-twin --features live)"
        );
    }
    choose_clock(opts, &a, &loaded.scenario)?;
    snapshot_options(opts, &a, &loaded)?;
    let name = loaded.name();
    eprintln!(
        "running scenario `{name}` ({}), seed {}, {}",
        loaded.file,
        opts.seed,
        match opts.duration {
            Some(d) => format!("{} simulated", m6p_twin::duration::format_duration(d)),
            None => "until Ctrl-C".into(),
        }
    );
    let record = a
        .record
        .clone()
        .or_else(|| loaded.scenario.record.file.as_ref().map(PathBuf::from));
    // The live view shows `/csp/packets` too: the run hands its packets out.
    #[cfg(feature = "live")]
    if a.live.is_some() {
        opts.packet_events = true;
    }
    let rt = build_runtime_for(opts)?;
    #[cfg(feature = "live")]
    let mut live = match a.live {
        Some(addr) => Some(start_live(addr, &compiled.opts, inlet)?),
        None => None,
    };
    // A build without the live view has refused --live above.
    #[cfg(not(feature = "live"))]
    drop(inlet);
    #[cfg(feature = "live")]
    let mut tap = |ev: &m6p_twin::events::RunEvent| {
        if let Some((l, _)) = live.as_mut() {
            l.publish(ev);
        }
    };
    #[cfg(not(feature = "live"))]
    let mut tap = |_: &m6p_twin::events::RunEvent| {};
    let record_to = record.as_deref().map(|path| exec::RecordTo {
        path,
        existing: if a.overwrite {
            m6p_twin::record::Existing::Replace
        } else {
            m6p_twin::record::Existing::Refuse
        },
    });
    let ran = rt.block_on(exec::execute_with(&loaded, compiled, record_to, &mut tap));
    let (outcome, stats) = naming_snapshot(ran, a.from_snapshot.as_deref())?;
    #[cfg(feature = "live")]
    if let Some((l, control)) = live.take() {
        eprintln!("live view: {} messages published; stopping", l.messages());
        if l.publishing() {
            let (taken, refused) = control.read();
            eprintln!(
                "live view: {taken} control request(s) from its clients taken, {refused} refused"
            );
        }
        l.finish();
    }
    print!("{}", outcome.report.table());
    print!("{}", outcome.verdict_table());
    // The report first, whatever became of the recording: a failed recording fails the run.
    let recorded = match (record, stats) {
        (Some(path), Some(Ok(stats))) => {
            println!(
                "\nrecorded {} messages in {} chunks to {} ({} bytes)",
                stats.messages,
                stats.chunks,
                path.display(),
                stats.bytes
            );
            true
        }
        (_, Some(Err(e))) => {
            eprintln!("error: the recording failed: {e:#}");
            false
        }
        _ => true,
    };
    Ok(outcome.passed() && recorded)
}

/// `--control ADDR` into `opts`; with `--live` too, the inlet through which the live
/// view's clients publish control requests.
fn control_options(
    opts: &mut m6p_twin::runtime::RunOptions,
    a: &RunArgs,
    scenario: &m6p_twin::scenario::Scenario,
) -> Option<m6p_twin::runtime::control::Inlet> {
    let addr = a.control?;
    let (inlet, intake) = match a.live {
        Some(_) => {
            let (i, t) = m6p_twin::runtime::control::inlet();
            (Some(i), Some(t))
        }
        None => (None, None),
    };
    opts.control = Some(m6p_twin::runtime::control::ControlOptions {
        listen: Some(addr),
        faults: m6p_twin::faults::live(scenario),
        replay: Vec::new(),
        snapshot_dir: a.snapshot_dir.clone(),
        inlet: intake,
    });
    inlet
}

/// `--no-checks`: no expectation and no invariant is judged (the scenario's commands and
/// faults still run: they are the platform's activity).
fn lab_mode(compiled: &mut m6p_twin::plan::Compiled) {
    let expectations = std::mem::take(&mut compiled.expectations).len();
    let invariants = std::mem::take(&mut compiled.invariants.check).len();
    eprintln!(
        "lab mode (--no-checks): the scenario's {expectations} expectation(s) and \
         {invariants} invariant(s) are not checked"
    );
}

/// The command line's outside links into `opts`: KISS links (and the nodes their
/// addresses replace), SocketCAN bridges, node consoles.
fn add_links(
    opts: &mut m6p_twin::runtime::RunOptions,
    cli_links: Vec<m6p_twin::runtime::KissLink>,
    a: &RunArgs,
) -> anyhow::Result<()> {
    let replaced =
        m6p_twin::outside::cli_replaces(&opts.network, cli_links.iter().map(|l| &l.cfg))?;
    for (addr, name) in replaced {
        if opts.replaced.insert(addr) {
            eprintln!(
                "note: --kiss-addr {addr}: the link's program takes {name}'s place (not started)"
            );
        }
    }
    opts.kiss_links.extend(cli_links);
    opts.socketcan.extend(a.socketcan.iter().cloned());
    for u in &a.uart {
        if !opts
            .network
            .nodes
            .iter()
            .any(|n| n.name.eq_ignore_ascii_case(&u.node))
        {
            let names: Vec<&str> = opts.network.nodes.iter().map(|n| n.name.as_str()).collect();
            anyhow::bail!(
                "--uart {}: no node {} (nodes: {})",
                u.label(),
                u.node,
                names.join(", ")
            );
        }
    }
    opts.uart.extend(a.uart.iter().cloned());
    Ok(())
}

/// The run's clock from the scenario's and the command line's: virtual, real time, or
/// virtual then real time; and whether it runs until Ctrl-C.
fn choose_clock(
    opts: &mut m6p_twin::runtime::RunOptions,
    a: &RunArgs,
    scenario: &m6p_twin::scenario::Scenario,
) -> anyhow::Result<()> {
    if let Some(from) = &a.realtime_from {
        let at = m6p_twin::clock::resolve(scenario, opts.epoch_unix_s, from)
            .map_err(|e| anyhow::anyhow!("--realtime-from: {e}"))?;
        let speed = match opts.clock {
            ClockMode::Realtime { speed } | ClockMode::VirtualThenRealtime { speed, .. } => speed,
            ClockMode::Virtual => a.speed,
        };
        opts.clock = ClockMode::VirtualThenRealtime { from: at, speed };
    }
    if let ClockMode::VirtualThenRealtime { from, speed } = &mut opts.clock {
        if a.speed != 1.0 {
            *speed = a.speed;
        }
        eprintln!(
            "note: virtual time until {from}, then real time at {speed}x simulated per wall second"
        );
    } else if opts.has_outside_links() && !a.realtime && opts.clock == ClockMode::Virtual {
        eprintln!("note: outside links need the wall clock: running in real time");
    } else if a.live.is_some() && !a.realtime && opts.clock == ClockMode::Virtual {
        eprintln!(
            "note: the live view follows the wall clock: running in real time (--speed sets the pace)"
        );
    } else if a.control.is_some() && !a.realtime && opts.clock == ClockMode::Virtual {
        eprintln!(
            "note: the control channel needs the wall clock: running in real time (--speed sets the pace)"
        );
    }
    if matches!(opts.clock, ClockMode::VirtualThenRealtime { .. }) {
        if a.forever && a.duration.is_none() {
            opts.duration = None;
        }
    } else if a.realtime || opts.has_outside_links() || a.live.is_some() || a.control.is_some() {
        let speed = match opts.clock {
            ClockMode::Realtime { speed } if !a.realtime => speed,
            _ => a.speed,
        };
        opts.clock = ClockMode::Realtime { speed };
        if a.forever && a.duration.is_none() {
            opts.duration = None;
        }
    } else if a.forever {
        eprintln!(
            "note: --forever needs the wall clock (--realtime); running the scenario's duration"
        );
    }
    Ok(())
}

/// Start the live view on `addr` for the run `opts`; its clients publish control requests
/// through `inlet` (the run's `--control`), counted in what it returns beside the server.
#[cfg(feature = "live")]
pub fn start_live(
    addr: SocketAddr,
    opts: &m6p_twin::runtime::RunOptions,
    inlet: Option<m6p_twin::runtime::control::Inlet>,
) -> anyhow::Result<(
    m6p_twin::live::LiveServer,
    std::sync::Arc<m6p_twin::live_control::ControlCounts>,
)> {
    use std::sync::Arc;
    if !addr.ip().is_loopback() {
        eprintln!(
            "warning: the live view on {addr} is reachable from other machines, without \
             authentication or encryption"
        );
    }
    use anyhow::Context as _;
    let start_ns = opts
        .epoch_unix_s
        .checked_mul(1_000_000_000)
        .context("the scenario's start epoch is out of range")?;
    let counts = Arc::new(m6p_twin::live_control::ControlCounts::default());
    let publish = inlet.map(|i| {
        let l = m6p_twin::live_control::ControlListener::new(i, counts.clone());
        Arc::new(l) as Arc<dyn foxglove::websocket::ServerListener>
    });
    let mut live = m6p_twin::live::LiveServer::start(addr, start_ns, publish)?;
    live.set_icd(opts.icd_map());
    eprintln!(
        "live view: ws://{} (Foxglove: Open connection, Foxglove WebSocket)",
        live.addr()
    );
    if live.publishing() {
        eprintln!(
            "live view: its clients may publish control requests on /control (JSON, \
             docs/control.md)"
        );
    }
    Ok((live, counts))
}

/// `m6p-twin run` with the command line's KISS links in the order they were given.
pub fn cmd_run_from(matches: &clap::ArgMatches, a: RunArgs) -> anyhow::Result<bool> {
    let m = matches
        .subcommand_matches("run")
        .ok_or_else(|| anyhow::anyhow!("no run arguments"))?;
    let links = cli_kiss_links(m, &a)?;
    cmd_run(a, links)
}

/// The rules of `--channels`.
#[derive(Debug, Clone)]
pub struct ChannelRules(pub Vec<twin_scenario::channels::ChannelRule>);

/// Parse `--channels` ([`twin_scenario::channels::parse_rules`]).
pub fn parse_channel_rules(
    text: &str,
) -> Result<ChannelRules, twin_scenario::channels::ChannelRuleError> {
    twin_scenario::channels::parse_rules(text).map(ChannelRules)
}
