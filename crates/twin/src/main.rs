//! The `m6p-twin` command line.

use std::net::SocketAddr;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context as _;
use bus::ClockMode;
use clap::{Parser, Subcommand};
use m6p_twin::duration::parse_duration;
use std::path::PathBuf;

use m6p_twin::exec;
use m6p_twin::gs;
use m6p_twin::runtime::{SocketCanBus, build_runtime_for};

/// A digital twin of the NanoAvionics M6P smallsat network: every node speaks CSP 1.4 on
/// simulated CAN buses, and outside programs join over KISS/TCP.
#[derive(Debug, Parser)]
#[command(name = "m6p-twin", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a scenario (default: the embedded default scenario) and print what happened.
    Run(Box<RunArgs>),
    /// Run scenarios headless for CI: a table, JUnit XML, and a non-zero exit on failure.
    Test(TestArgs),
    /// Validate scenario files without running them.
    Check {
        /// Scenario files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Print the JSON Schema of the scenario format, or of the campaign format (for editors).
    Schema {
        /// The campaign file's schema instead of the scenario's.
        #[arg(long)]
        campaign: bool,
    },
    /// Print the ICD as data: every node, port and command, with the request and reply
    /// fields (type, offset, unit, range, named values), from the twin's own wire types.
    Icd {
        /// Only this node (FC, PC, EPS, ECU, COMM, payload).
        node: Option<String>,
        /// JSON (format 1) instead of text, for tools and codecs.
        #[arg(long, conflicts_with = "node")]
        json: bool,
        /// The Markdown tables of docs/protocol.md.
        #[arg(long, conflicts_with_all = ["node", "json"])]
        markdown: bool,
    },
    /// Fault campaigns: a scenario run many times with drawn values, every run checked.
    #[command(subcommand)]
    Campaign(CampaignCmd),
    /// Summarise a recording (channels, counts per node and port, expectations), export
    /// a channel to CSV, or show where its bytes go.
    Inspect {
        /// The MCAP recording.
        file: PathBuf,
        /// Export this channel (for example /csp/packets) as CSV to standard output.
        #[arg(long, value_name = "CHANNEL")]
        csv: Option<String>,
        /// Where the file's bytes go: each channel's messages, data, data compressed on its
        /// own (zstd 1) and MCAP message index, largest first, and per simulated hour.
        #[arg(long, conflicts_with = "csv")]
        sizes: bool,
    },
    /// Compare two recordings; exit 0 only when their bus traffic is identical.
    Diff {
        /// The expected recording.
        a: PathBuf,
        /// The actual recording.
        b: PathBuf,
    },
    /// Re-run a recording's scenario with its seed and compare; exit 0 only when identical.
    Replay(ReplayArgs),
    /// Measure a scenario in virtual time: real-time factor with and without recording,
    /// peak memory, and MCAP bytes per simulated hour (medians of --runs runs).
    Bench {
        /// Scenario file [default: the embedded default scenario].
        scenario: Option<PathBuf>,
        /// Simulated duration of each run.
        #[arg(long, default_value = "1h", value_parser = parse_duration)]
        duration: Duration,
        /// Runs per variant.
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Print the figures as one JSON object (`cpu_s_plain`, `cpu_s_recorded`,
        /// `cpu_s_adcs_floor`, `rtf_plain`, `rtf_recorded`, `mcap_bytes_per_hour`,
        /// `messages_per_hour`, `peak_rss_mib`, the ratios and per-variant spreads).
        #[arg(long)]
        json: bool,
    },
    /// One run of `bench` in a process of its own (what `bench` runs; prints its figures as
    /// JSON).
    #[command(hide = true)]
    BenchRun {
        /// Scenario file [default: the embedded default scenario].
        scenario: Option<PathBuf>,
        /// `plain`, `recorded` or `adcs_floor`.
        #[arg(long)]
        variant: String,
        /// Simulated duration, ns.
        #[arg(long)]
        duration_ns: u64,
        /// Where a recorded run records.
        #[arg(long)]
        record: PathBuf,
    },
    /// Join a running twin over KISS/TCP as a ground node and send requests.
    Gs(GsArgs),
    /// List the passes of a scenario's orbit over its ground stations (`[comm] stations`,
    /// above `[comm] elevation_mask_deg`): rise, culmination, set (simulated seconds and
    /// UTC) and maximum elevation.
    Passes {
        /// Scenario file [default: the embedded default scenario].
        scenario: Option<PathBuf>,
        /// Only the passes over this station (by name).
        #[arg(long, value_name = "NAME")]
        station: Option<String>,
        /// How far to look [default: the scenario's duration].
        #[arg(long, value_parser = parse_duration)]
        duration: Option<Duration>,
    },
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// Scenario file (TOML) [default: the embedded scenarios/default.toml].
    scenario: Option<PathBuf>,
    /// Simulated duration, overriding the scenario's: 90, 90s, 10m, 2h.
    #[arg(long, value_parser = parse_duration)]
    duration: Option<Duration>,
    /// Seed, overriding the scenario's.
    #[arg(long)]
    seed: Option<u64>,
    /// Record the run to this MCAP file (overrides the scenario's `record.file`). Written
    /// beside it and put in place when complete; a file already there is refused unless
    /// --overwrite.
    #[arg(long, value_name = "FILE")]
    record: Option<PathBuf>,
    /// Replace a file already at the recording's name (once the new one is complete; never
    /// the scenario itself).
    #[arg(long)]
    overwrite: bool,
    /// Follow the wall clock (needed by outside programs; implied by --kiss-* and --socketcan).
    #[arg(long)]
    realtime: bool,
    /// With --realtime: simulated seconds per wall second.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Virtual time until WHEN, real time (at --speed) after it: a simulated time
    /// ("13000s"), "first pass" or "first pass over STATION" (see `m6p-twin passes`).
    /// Outside links are open from the start.
    #[arg(long, value_name = "WHEN")]
    realtime_from: Option<m6p_twin::clock::RealtimeFrom>,
    /// With --realtime and no --duration: run until Ctrl-C instead of the scenario's duration.
    #[arg(long)]
    forever: bool,
    /// Listen for outside CSP nodes speaking KISS over TCP (for example 127.0.0.1:52001).
    #[arg(long = "kiss-listen", value_name = "ADDR")]
    kiss_listen: Vec<SocketAddr>,
    /// Connect to an outside KISS/TCP server, as the platform does in ICD 2.3.
    #[arg(long = "kiss-connect", value_name = "ADDR")]
    kiss_connect: Vec<SocketAddr>,
    /// KISS on a pseudo-terminal linked at PATH, for a program using libcsp's usart driver
    /// (`usart_init(PATH)`): no socat needed. The program may close and reopen it.
    #[arg(long = "kiss-pty", value_name = "PATH")]
    kiss_pty: Vec<PathBuf>,
    /// Play libcsp 1.4's ZMQ hub on HOST (programs call csp_zmqhub_init(addr, "HOST")):
    /// HOST or HOST:PUB_PORT:SUB_PORT [default ports: 6000 7000]. Any 127.0.0.x works.
    #[arg(long = "zmq-hub", value_name = "HOST")]
    zmq_hub: Vec<bus::zmq_hub::HubAddr>,
    /// A CSP address behind the --kiss-listen, --kiss-connect, --kiss-pty or --zmq-hub
    /// before it (repeat for more);
    /// claimed when a program connects, and the only sources that link accepts. A link
    /// without any learns them from the packets it receives. The address of a simulated
    /// node (a payload, the FC, a ground station) replaces that node: it is not started.
    #[arg(long = "kiss-addr", value_name = "ID")]
    kiss_addr: Vec<u8>,
    /// Connections each --kiss-listen serves at once; a new one closes the longest-idle
    /// connection (logged).
    #[arg(long, value_name = "N", default_value_t = 16)]
    kiss_max_connections: usize,
    /// How long a --kiss-listen connection holding no address may go without a byte before
    /// it is closed (60s; "off": never).
    #[arg(long, value_name = "DURATION|off", default_value = "60s")]
    kiss_idle_timeout: m6p_twin::scenario::IdleLimit,
    /// At most N CAN frames a second from each connection of the command line's KISS links
    /// on a CAN bus (a runaway program with a low address then leaves room to others).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=100_000))]
    kiss_tx_budget: Option<u32>,
    /// Apply libcsp 1.4's KISS receive limit (at most 248 data bytes) to the twin's receiver.
    #[arg(long)]
    libcsp14_kiss_limit: bool,
    /// A node's text console (its UART, ICD 1.1): NODE=ADDR serves it over TCP (`nc 127.0.0.1
    /// 5010`), NODE=PATH on a pseudo-terminal linked at PATH (`screen PATH`). Repeatable.
    #[arg(long = "uart", value_name = "NODE=ADDR|PATH", value_parser = m6p_twin::runtime::UartLink::parse_arg)]
    uart: Vec<m6p_twin::runtime::UartLink>,
    /// Bridge a bus to a real SocketCAN interface: IFACE[:main|:payload] [default bus:
    /// main]. Needs a build with --features socketcan (Linux).
    #[arg(long = "socketcan", value_name = "IFACE[:main|:payload]", value_parser = SocketCanBus::parse_arg)]
    socketcan: Vec<(String, SocketCanBus)>,
    /// Serve the run live over the Foxglove WebSocket protocol on ADDR (IP:PORT or a port)
    /// [default: 127.0.0.1:8765]; implies real time. Needs a build with --features live.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765", value_parser = parse_live_addr)]
    live: Option<SocketAddr>,
}

/// `--live ADDR`: IP:PORT, or a port on 127.0.0.1.
fn parse_live_addr(s: &str) -> Result<SocketAddr, String> {
    if let Ok(port) = s.parse::<u16>() {
        return Ok(SocketAddr::from(([127, 0, 0, 1], port)));
    }
    s.parse().map_err(|_| {
        "expected IP:PORT or a port (a scenario file after a bare --live: write it first, \
         or --live=127.0.0.1:8765)"
            .to_owned()
    })
}

#[derive(Debug, clap::Args)]
struct ReplayArgs {
    /// The MCAP recording to reproduce.
    file: PathBuf,
    /// Keep the new recording here (default: a temporary file, deleted afterwards).
    #[arg(long, value_name = "FILE")]
    record: Option<PathBuf>,
    /// Test-only: change a node's behaviour to prove that divergences are found
    /// (`fc-uptime-icd`).
    #[arg(long, hide = true)]
    test_knob: Option<String>,
}

#[derive(Debug, clap::Args)]
struct TestArgs {
    /// Scenario files.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Write a JUnit XML report here.
    #[arg(long, value_name = "FILE")]
    junit: Option<PathBuf>,
    /// Seed, overriding every scenario's.
    #[arg(long)]
    seed: Option<u64>,
    /// Scenarios run at once [default: the machine's cores]; those in real time or with
    /// links to the outside run one at a time all the same.
    #[arg(long)]
    jobs: Option<usize>,
}

#[derive(Debug, Subcommand)]
enum CampaignCmd {
    /// Run a campaign: results.csv, junit.xml and failures/run-<k>.toml in --out; exit 1
    /// when a run failed.
    Run(CampaignRunArgs),
    /// Shrink a failing scenario (a campaign's failures/run-<k>.toml): remove faults, narrow
    /// their windows and move drawn values back to the base while it still fails.
    Shrink {
        /// The failing scenario.
        file: PathBuf,
        /// The campaign it came from (its base scenario is where values move back to).
        #[arg(long, value_name = "CAMPAIGN")]
        campaign: Option<PathBuf>,
        /// Where the smallest failing scenario goes.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
    },
    /// Print run K's complete scenario (every draw resolved), as `m6p-twin run` takes it.
    Resolve {
        /// The campaign file.
        file: PathBuf,
        /// The run's index.
        run: u64,
    },
    /// Combine shards' output directories into the files one unsharded run writes.
    Merge {
        /// The shards' output directories.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where the combined results go.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
    },
}

#[derive(Debug, clap::Args)]
struct CampaignRunArgs {
    /// The campaign file.
    file: PathBuf,
    /// Runs 0..N instead of the campaign's `runs`.
    #[arg(long)]
    runs: Option<u64>,
    /// Parallel runs [default: the machine's cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Also shrink every failure (failures/run-<k>.min.toml).
    #[arg(long)]
    shrink: bool,
    /// Also record every failure again to failures/run-<k>.mcap (checked complete, and
    /// failing the same way).
    #[arg(long)]
    record_failures: bool,
    /// Run only the runs whose index modulo N is I [default: from SLURM_ARRAY_TASK_ID and
    /// SLURM_ARRAY_TASK_COUNT, or JOB_COMPLETION_INDEX and JOB_COMPLETIONS, when set].
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Where the results go.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Finish a campaign that was stopped: keep the results already in --out (of this
    /// campaign), run those not run.
    #[arg(long)]
    resume: bool,
}

#[derive(Debug, clap::Args)]
struct GsArgs {
    /// The twin's KISS/TCP server.
    #[arg(long, value_name = "ADDR")]
    connect: SocketAddr,
    /// This ground node's CSP address (0-30).
    #[arg(long = "as", default_value_t = 17, value_name = "ID",
          value_parser = clap::value_parser!(u8).range(0..=30))]
    as_addr: u8,
    /// For an ICD command: the port to send it to, where the scenario moved it.
    #[arg(long, value_name = "PORT")]
    port: Option<u8>,
    /// How long to wait for each reply.
    #[arg(long, default_value = "2s", value_parser = parse_duration)]
    timeout: Duration,
    /// The request; without one, the console: interactive on a terminal (history, Tab
    /// completion), else the lines of standard input.
    #[command(subcommand)]
    request: Option<GsRequest>,
}

#[derive(Debug, Subcommand)]
enum GsRequest {
    /// CSP ping (port 1): the node echoes the payload.
    Ping {
        /// Node address.
        node: u8,
        /// Number of pings.
        #[arg(long, default_value_t = 4)]
        count: u32,
        /// Payload size in bytes.
        #[arg(long, default_value_t = 16)]
        size: usize,
        /// Time between pings.
        #[arg(long, default_value = "1s", value_parser = parse_duration)]
        interval: Duration,
    },
    /// CSP uptime (port 6).
    Uptime {
        /// Node address.
        node: u8,
        /// Read the reply as the ICD's u32 little-endian milliseconds.
        #[arg(long)]
        icd: bool,
    },
    /// CMP ident (port 0).
    Ident {
        /// Node address.
        node: u8,
    },
    /// Any request: `raw NODE PORT HEX` (the reply is printed in hex).
    Raw {
        /// Node address.
        node: u8,
        /// Destination port.
        port: u8,
        /// Request bytes in hex (command id first).
        data: String,
    },
    /// PC SETUP (ICD 3.1.8.1): configure a payload session.
    Setup {
        /// Session id (1 for payload 12 in the default scenario).
        session: u8,
        /// Start, UTC unix seconds of the M6P clock (0: now).
        #[arg(long, default_value_t = 0)]
        start: u32,
        /// Duration: seconds, or with a unit (`10m`); the ICD allows 5 s to 15 min.
        #[arg(long, default_value = "60")]
        duration: String,
        /// Packets after which the session ends (0: no limit).
        #[arg(long, default_value_t = 0)]
        max_packets: u32,
        /// POLL frame size, bytes (1-254).
        #[arg(long, default_value_t = 64)]
        frame: u32,
        /// Sync message (text, at most 128 bytes).
        #[arg(long, default_value = "")]
        sync: String,
    },
    /// Any ICD command by name: `gs --connect ADDR NODE COMMAND [NAME=VALUE ...]`, for
    /// example `fc tmatp`, `eps chset channel=PC on=off`, `pc setup session_id=1
    /// timestamp=now duration_s=10m max_packets=0 poll_frame_size=200 sync_message=go`
    /// (`m6p-twin icd NODE` lists the commands and their fields). The reply is decoded.
    #[command(external_subcommand)]
    Icd(Vec<String>),
    /// PC STATUS: a session's state, last result and configuration.
    Status {
        /// Session id.
        session: u8,
    },
    /// PC ABORT of a PENDING or ACTIVE session.
    Abort {
        /// Session id.
        session: u8,
    },
}

/// A reader that stops early (`m6p-twin run | head`) ends the process quietly, as a Unix
/// tool killed by SIGPIPE does (exit 141), instead of a panic from `println!`.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_broken_pipe();
    let matches = <Cli as clap::CommandFactory>::command().get_matches();
    let cli =
        <Cli as clap::FromArgMatches>::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // A benchmark runs the scenario many times: only warnings, unless RUST_LOG says more.
    let default_filter = if matches!(
        cli.command,
        Command::Bench { .. } | Command::BenchRun { .. } | Command::Campaign(_)
    ) {
        "warn"
    } else {
        "info,foxglove=warn"
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| default_filter.into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let res = match cli.command {
        Command::Run(a) => matches
            .subcommand_matches("run")
            .ok_or_else(|| anyhow::anyhow!("no run arguments"))
            .and_then(|m| cli_kiss_links(m, &a))
            .and_then(|links| cmd_run(*a, links)),
        Command::Test(a) => cmd_test(a),
        Command::Check { files } => cmd_check(&files),
        Command::Schema { campaign } => cmd_schema(campaign),
        Command::Icd {
            node,
            json,
            markdown,
        } => {
            if markdown {
                print!("{}", m6p_twin::icd::to_markdown());
                Ok(true)
            } else if json {
                println!("{}", m6p_twin::icd::to_json());
                Ok(true)
            } else {
                m6p_twin::icd::to_text(node.as_deref())
                    .map(|t| {
                        print!("{t}");
                        true
                    })
                    .map_err(anyhow::Error::msg)
            }
        }
        Command::Campaign(CampaignCmd::Run(a)) => cmd_campaign_run(a),
        Command::Campaign(CampaignCmd::Merge { dirs, out }) => cmd_campaign_merge(&dirs, &out),
        Command::Campaign(CampaignCmd::Resolve { file, run }) => {
            let c = m6p_twin::campaign::Campaign::load(&file)
                .and_then(|c| c.resolve(run).map_err(anyhow::Error::from));
            c.map(|r| {
                print!("# Run {run} of campaign {}\n{}", file.display(), r.text);
                true
            })
        }
        Command::Campaign(CampaignCmd::Shrink {
            file,
            campaign,
            out,
        }) => cmd_campaign_shrink(&file, campaign.as_deref(), &out),
        Command::Inspect { file, csv, sizes } => cmd_inspect(&file, csv.as_deref(), sizes),
        Command::Diff { a, b } => cmd_diff(&a, &b),
        Command::Replay(a) => cmd_replay(a),
        Command::Bench {
            scenario,
            duration,
            runs,
            json,
        } => cmd_bench(scenario.as_deref(), duration, runs, json),
        Command::BenchRun {
            scenario,
            variant,
            duration_ns,
            record,
        } => cmd_bench_run(scenario.as_deref(), &variant, duration_ns, &record),
        Command::Gs(a) => cmd_gs(a),
        Command::Passes {
            scenario,
            station,
            duration,
        } => cmd_passes(scenario.as_deref(), station.as_deref(), duration),
    };
    match res {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

/// The command line's KISS links, in order, each with the `--kiss-addr`s that follow it.
fn cli_kiss_links(
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
        .collect();
    links.sort_by_key(|(i, _)| *i);
    for (i, &id) in at("kiss_addr").into_iter().zip(&a.kiss_addr) {
        if id >= 31 {
            anyhow::bail!("--kiss-addr {id}: not a unicast CSP address (0-30)");
        }
        let Some((_, link)) = links.iter_mut().rev().find(|(j, _)| *j < i) else {
            anyhow::bail!(
                "--kiss-addr {id} comes before any --kiss-listen, --kiss-connect, --kiss-pty or \
                 --zmq-hub: it names an address of the link before it"
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

fn cmd_run(a: RunArgs, cli_links: Vec<m6p_twin::runtime::KissLink>) -> anyhow::Result<bool> {
    let loaded = match &a.scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    let mut compiled = exec::compile_seeded(&loaded, a.seed);
    let opts = &mut compiled.opts;
    if let Some(d) = a.duration {
        opts.duration = Some(d);
    }
    let replaced = m6p_twin::outside::cli_replaces(&opts.network, cli_links.iter().map(|l| &l.cfg))
        .map_err(|e| anyhow::anyhow!(e))?;
    for (addr, name) in replaced {
        if opts.replaced.insert(addr) {
            eprintln!(
                "note: --kiss-addr {addr}: the link's program takes {name}'s place (not started)"
            );
        }
    }
    opts.kiss_links.extend(cli_links);
    opts.socketcan.extend(a.socketcan);
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
    opts.uart.extend(a.uart);
    if cfg!(not(feature = "live")) && a.live.is_some() {
        anyhow::bail!(
            "--live needs the Foxglove WebSocket server, which this build leaves out: \
             rebuild with --features live (cargo build -p m6p-twin --features live)"
        );
    }
    if let Some(from) = &a.realtime_from {
        let at = m6p_twin::clock::resolve(&loaded.scenario, opts.epoch_unix_s, from)
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
    }
    if matches!(opts.clock, ClockMode::VirtualThenRealtime { .. }) {
        if a.forever && a.duration.is_none() {
            opts.duration = None;
        }
    } else if a.realtime || opts.has_outside_links() || a.live.is_some() {
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
    let rt = build_runtime_for(opts)?;
    #[cfg(feature = "live")]
    let mut live = match a.live {
        Some(addr) => {
            let mut l = start_live(addr, compiled.opts.epoch_unix_s)?;
            l.set_icd(compiled.opts.icd_map());
            Some(l)
        }
        None => None,
    };
    #[cfg(feature = "live")]
    let mut tap = |ev: &m6p_twin::events::RunEvent| {
        if let Some(l) = live.as_mut() {
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
    let (outcome, stats) =
        rt.block_on(exec::execute_with(&loaded, compiled, record_to, &mut tap))?;
    #[cfg(feature = "live")]
    if let Some(l) = live.take() {
        eprintln!("live view: {} messages published; stopping", l.messages());
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

/// Start the live view on `addr` for a run starting at `epoch_unix_s`.
#[cfg(feature = "live")]
fn start_live(addr: SocketAddr, epoch_unix_s: u64) -> anyhow::Result<m6p_twin::live::LiveServer> {
    if !addr.ip().is_loopback() {
        eprintln!(
            "warning: the live view on {addr} is reachable from other machines, without \
             authentication or encryption"
        );
    }
    let start_ns = epoch_unix_s
        .checked_mul(1_000_000_000)
        .context("the scenario's start epoch is out of range")?;
    let live = m6p_twin::live::LiveServer::start(addr, start_ns)?;
    eprintln!(
        "live view: ws://{} (Foxglove: Open connection, Foxglove WebSocket)",
        live.addr()
    );
    Ok(live)
}

/// The bytes outside programs sent on each KISS link of a recording, with their times.
fn recorded_kiss_input(
    file: &std::path::Path,
) -> anyhow::Result<Vec<m6p_twin::runtime::KissReplay>> {
    let mut links: std::collections::BTreeMap<String, Vec<m6p_twin::runtime::RecordedChunk>> =
        Default::default();
    let mut seq = 0u64;
    for m in m6p_twin::recording::messages(file)? {
        let m = m?;
        if !m.topic.starts_with("/kiss/") {
            continue;
        }
        let k: m6p_twin::record::KissFrameMsg = m
            .decode()
            .with_context(|| format!("decoding a {} message", m.topic))?;
        if k.dir == "in" {
            // In the file's order: the order the run took them in.
            seq += 1;
            links
                .entry(k.link)
                .or_default()
                .push(m6p_twin::runtime::RecordedChunk {
                    t: csp::SimTime(k.t_ns),
                    seq,
                    bytes: k.bytes.to_vec(),
                });
        }
    }
    Ok(links
        .into_iter()
        .map(|(link, chunks)| m6p_twin::runtime::KissReplay {
            link,
            chunks,
            cfg: Default::default(),
        })
        .collect())
}

fn cmd_passes(
    scenario: Option<&std::path::Path>,
    station: Option<&str>,
    duration: Option<Duration>,
) -> anyhow::Result<bool> {
    let loaded = match scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    let s = &loaded.scenario;
    if let Some(name) = station {
        m6p_twin::comm::check_station(s, name)
            .map_err(|e| anyhow::anyhow!("{}: {e}", loaded.file))?;
    }
    if s.satellite.tle.is_empty() {
        anyhow::bail!(
            "{} has no [satellite] tle: no orbit, no passes",
            loaded.file
        );
    }
    let epoch = exec::compile_loaded(&loaded).opts.epoch_unix_s;
    let span = duration.unwrap_or(s.duration.0);
    let passes = m6p_twin::comm::station_passes(s, epoch, span, station);
    println!(
        "passes of `{}` over {} above {} deg, from {} for {}",
        loaded.name(),
        station.unwrap_or("every station"),
        s.comm.elevation_mask_deg,
        m6p_twin::timefmt::format_utc(epoch as i64 * 1_000_000_000),
        m6p_twin::duration::format_duration(span)
    );
    println!(
        "{:<12} {:>10} {:>13} {:>10} {:>9} {:>8}  rise (UTC)",
        "station", "rise (s)", "culmin. (s)", "set (s)", "max (deg)", "length"
    );
    let utc = |ns: i64| m6p_twin::timefmt::format_utc(epoch as i64 * 1_000_000_000 + ns);
    for p in &passes {
        let secs = |ns: i64| ns as f64 / 1e9;
        println!(
            "{:<12} {:>10.1} {:>13.1} {:>10.1} {:>9.1} {:>7.0}s  {}",
            p.station,
            secs(p.rise_ns),
            secs(p.culmination_ns),
            secs(p.set_ns),
            p.max_elevation_deg,
            secs(p.set_ns - p.rise_ns),
            utc(p.rise_ns)
        );
    }
    if passes.is_empty() {
        println!("(no pass in this window)");
    }
    Ok(true)
}

fn cmd_bench(
    scenario: Option<&std::path::Path>,
    duration: Duration,
    runs: usize,
    json: bool,
) -> anyhow::Result<bool> {
    let loaded = match scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    let exe = std::env::current_exe().context("finding the m6p-twin executable")?;
    let report = m6p_twin::bench::run(&loaded, duration, runs, |variant, record| {
        let mut cmd = std::process::Command::new(&exe);
        cmd.arg("bench-run")
            .args(["--variant", variant.name()])
            .args(["--duration-ns", &duration.as_nanos().to_string()])
            .arg("--record")
            .arg(record);
        if let Some(p) = scenario {
            cmd.arg(p);
        }
        let out = cmd
            .stdin(std::process::Stdio::null())
            .output()
            .with_context(|| format!("running {}", exe.display()))?;
        if !out.status.success() {
            anyhow::bail!(
                "the {} run failed ({}): {}",
                variant.name(),
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        serde_json::from_slice(&out.stdout)
            .with_context(|| format!("reading the {} run's figures", variant.name()))
    })?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.text());
    }
    Ok(true)
}

fn cmd_bench_run(
    scenario: Option<&std::path::Path>,
    variant: &str,
    duration_ns: u64,
    record: &std::path::Path,
) -> anyhow::Result<bool> {
    let variant = m6p_twin::bench::Variant::from_name(variant)
        .with_context(|| format!("no bench variant {variant:?}"))?;
    let loaded = match scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    let sample =
        m6p_twin::bench::run_one(&loaded, Duration::from_nanos(duration_ns), variant, record)?;
    println!("{}", serde_json::to_string(&sample)?);
    Ok(true)
}

fn cmd_inspect(file: &std::path::Path, csv: Option<&str>, sizes: bool) -> anyhow::Result<bool> {
    if sizes {
        print!("{}", m6p_twin::sizes::read_sizes(file)?);
        return Ok(true);
    }
    match csv {
        Some(channel) => {
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::new(stdout.lock());
            let rows = m6p_twin::recording::export_csv(file, channel, &mut out)?;
            std::io::Write::flush(&mut out)?;
            eprintln!("{rows} rows of {channel}");
        }
        None => print!("{}", m6p_twin::recording::read_summary(file)?),
    }
    Ok(true)
}

fn cmd_diff(a: &std::path::Path, b: &std::path::Path) -> anyhow::Result<bool> {
    let d = m6p_twin::recording::diff(a, b)?;
    println!("{d}");
    Ok(d.is_identical())
}

fn cmd_replay(a: ReplayArgs) -> anyhow::Result<bool> {
    let meta = m6p_twin::recording::load_meta(&a.file)?;
    let file = format!(
        "{} (recorded scenario `{}`)",
        a.file.display(),
        meta.scenario_name
    );
    let scenario = m6p_twin::scenario::parse(&file, &meta.scenario_toml)?;
    let loaded = exec::Loaded {
        file,
        text: meta.scenario_toml.clone(),
        scenario,
    };
    let mut compiled = exec::compile_seeded(&loaded, Some(meta.seed));
    if let Some(d) = meta.duration_ns {
        compiled.opts.duration = Some(Duration::from_nanos(d));
    }
    if !compiled.opts.socketcan.is_empty() {
        anyhow::bail!(
            "this recording bridged a SocketCAN interface; replaying SocketCAN input is not supported yet"
        );
    }
    // What outside programs sent (from the scenario's links or the command line's) is in
    // the recording: feed it again in virtual time instead of opening sockets.
    let mut input = recorded_kiss_input(&a.file)?;
    if compiled.opts.has_outside_links() || !input.is_empty() {
        // Each recorded connection with its link's settings (its addresses above all).
        for r in &mut input {
            let link = r.link.split_once('#').map_or(r.link.as_str(), |(l, _)| l);
            // A hub's messages, even when the hub came from the command line.
            if let Some(k) = compiled.opts.kiss_links.iter().find(|k| k.label() == link) {
                r.cfg = k.cfg.clone();
            }
            if link.starts_with("zmq-hub ") {
                r.cfg.framing = bus::kiss_tcp::Framing::ZmqHub;
            }
            // A command-line link's configured addresses and transmit budget, which the
            // scenario lacks.
            if r.cfg.addrs.is_empty()
                && let Some(addrs) = meta.link_addrs.get(link)
            {
                r.cfg.addrs.clone_from(addrs);
            }
            if let Some(&n) = meta.link_tx_budgets.get(link) {
                r.cfg.tx_frames_per_s = Some(n);
            }
        }
        // The nodes the recorded run's outside programs replaced, the command line's
        // (`--kiss-addr`) included, which the scenario does not name.
        compiled.opts.replaced.extend(meta.replaced.iter().copied());
        compiled.opts.kiss_links.clear();
        compiled.opts.clock = bus::ClockMode::Virtual;
        compiled.opts.kiss_replay = input;
        if compiled.opts.duration.is_none() {
            anyhow::bail!("the recorded run had no fixed duration");
        }
    }
    match a.test_knob.as_deref() {
        None => {}
        Some("fc-uptime-icd") => {
            for n in compiled
                .opts
                .network
                .nodes
                .iter_mut()
                .filter(|n| n.addr == 3)
            {
                n.uptime = csp::service::UptimeFormat::IcdMillisLe;
            }
        }
        Some(k) => anyhow::bail!("unknown test knob `{k}`"),
    }
    // Without --record, a directory of its own (created exclusively, removed with all it
    // holds), never a predictable name another program could plant a link at.
    let scratch = match &a.record {
        Some(_) => None,
        None => Some(tempfile::tempdir().context("creating a temporary directory")?),
    };
    let path = match (&a.record, &scratch) {
        (Some(p), _) => p.clone(),
        (None, Some(d)) => d.path().join("replay.mcap"),
        (None, None) => anyhow::bail!("no recording path"),
    };
    let rt = build_runtime_for(&compiled.opts)?;
    let result = rt.block_on(exec::execute_replay(
        &loaded,
        compiled,
        exec::RecordTo::new(&path),
    ));
    let d = result
        .and_then(|(_, recorded)| recorded.transpose())
        .and_then(|_| m6p_twin::recording::diff(&a.file, &path));
    drop(scratch);
    let d = d?;
    println!("{d}");
    Ok(d.is_identical())
}

fn cmd_check(files: &[PathBuf]) -> anyhow::Result<bool> {
    let mut ok = true;
    for f in files {
        match exec::load(f) {
            Ok(l) => println!(
                "{}: OK ({} commands, {} faults, {} expectations)",
                l.file,
                l.scenario.commands.len(),
                l.scenario.faults.len() + l.scenario.fc.faults.len(),
                l.scenario.expectations.len()
            ),
            Err(e) => {
                ok = false;
                eprintln!("{e:#}");
            }
        }
    }
    Ok(ok)
}

fn cmd_schema(campaign: bool) -> anyhow::Result<bool> {
    let schema = if campaign {
        schemars::schema_for!(m6p_twin::campaign::CampaignSpec)
    } else {
        m6p_twin::scenario::schema()
    };
    println!("{}", serde_json::to_string_pretty(&schema)?);
    Ok(true)
}

fn cmd_campaign_run(a: CampaignRunArgs) -> anyhow::Result<bool> {
    use m6p_twin::campaign_run::{self, RunVerdict};
    use std::io::IsTerminal as _;
    let c = m6p_twin::campaign::Campaign::load(&a.file)?;
    let runs = a.runs.unwrap_or(c.spec.runs);
    // Every run's scenario is drawn and validated before anything runs.
    c.check(runs)?;
    let jobs = campaign_run::default_jobs(a.jobs);
    let shard = match &a.shard {
        Some(s) => Some(campaign_run::Shard::parse(s).map_err(anyhow::Error::msg)?),
        None => {
            campaign_run::Shard::from_env(|k| std::env::var(k).ok()).map_err(anyhow::Error::msg)?
        }
    };
    let mut indices: Vec<u64> = shard.map_or_else(|| (0..runs).collect(), |s| s.runs(runs));
    let meta = campaign_run::CampaignMeta::of(&c, runs);
    // What an earlier, stopped run of this campaign already has: its results are kept.
    let kept: Vec<campaign_run::RunRow> = if a.resume {
        let done = campaign_run::results_in(&a.out, &meta)?;
        indices.retain(|k| !done.iter().any(|r| r.run == *k));
        println!(
            "resuming {}: {} results kept, {} runs to go",
            a.out.display(),
            done.len(),
            indices.len()
        );
        done
    } else {
        Vec::new()
    };
    let bar = if std::io::stderr().is_terminal() && std::env::var_os("CI").is_none() {
        let b = indicatif::ProgressBar::new(indices.len() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} runs, {msg} [{elapsed}]")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let failed = std::sync::atomic::AtomicU64::new(0);
    let started = std::time::Instant::now();
    let ran = campaign_run::run_all(&c, &indices, jobs, &|row| {
        if row.verdict != RunVerdict::Pass {
            let n = failed.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            bar.set_message(format!("{n} failed"));
        }
        bar.inc(1);
    });
    bar.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();
    let mut rows = kept;
    rows.extend(ran);
    rows.sort_by_key(|r| r.run);
    campaign_run::write_outputs(&meta, &rows, &a.out)?;
    let mut by_verdict = std::collections::BTreeMap::<&str, u64>::new();
    for r in &rows {
        *by_verdict.entry(r.verdict.word()).or_default() += 1;
    }
    let shard_note =
        shard.map_or_else(String::new, |s| format!(" (shard {}/{})", s.index, s.count));
    println!(
        "campaign {}{shard_note}: {} runs on {jobs} jobs in {wall:.1} s ({:.2} runs/s): {} pass, {} fail, {} error, {} not run",
        c.name(),
        rows.len(),
        rows.len() as f64 / wall.max(1e-9),
        by_verdict.get("pass").unwrap_or(&0),
        by_verdict.get("fail").unwrap_or(&0),
        by_verdict.get("error").unwrap_or(&0),
        by_verdict.get("not run").unwrap_or(&0),
    );
    if by_verdict.contains_key("not run") {
        println!(
            "the campaign was stopped: `m6p-twin campaign run {} --out {} --resume` runs the runs not run",
            a.file.display(),
            a.out.display()
        );
    }
    for r in rows.iter().filter(|r| r.verdict != RunVerdict::Pass) {
        let why = match &r.verdict {
            RunVerdict::Fail(f) => f
                .iter()
                .map(|(n, o)| format!("{n} ({o})"))
                .collect::<Vec<_>>()
                .join("; "),
            RunVerdict::Error(e) | RunVerdict::NotRun(e) => e.clone(),
            RunVerdict::Pass => String::new(),
        };
        println!("  run {} {}: {why}", r.run, r.verdict.word());
    }
    let mut recording_ok = true;
    if a.record_failures {
        for r in rows.iter().filter(|r| {
            r.verdict != RunVerdict::Pass && r.verdict.is_result() && !r.scenario.is_empty()
        }) {
            let path = a.out.join(format!("failures/run-{}.mcap", r.run));
            let file = format!("{} run {}", c.file, r.run);
            match campaign_run::record_failure(&file, r, &path) {
                Ok(()) => println!("  run {}: recorded to {}", r.run, path.display()),
                Err(e) => {
                    recording_ok = false;
                    println!("  run {}: recording failed: {e:#}", r.run);
                }
            }
        }
    }
    if a.shrink {
        for r in rows
            .iter()
            .filter(|r| r.verdict != RunVerdict::Pass && r.verdict.is_result())
        {
            let out = a.out.join(format!("failures/run-{}.min.toml", r.run));
            let file = format!("{} run {}", c.file, r.run);
            match shrink_to(&file, &r.scenario, Some(&c.base), &out) {
                Ok(line) => println!("  run {}: {line}", r.run),
                Err(e) => println!("  run {}: not shrunk: {e:#}", r.run),
            }
        }
    }
    println!("results in {}", a.out.display());
    Ok(recording_ok && rows.iter().all(|r| r.verdict == RunVerdict::Pass))
}

/// Shrink `text` and write the result to `out` with a header saying what was done; a line
/// to print.
fn shrink_to(
    file: &str,
    text: &str,
    base: Option<&toml::Table>,
    out: &std::path::Path,
) -> anyhow::Result<String> {
    let r = m6p_twin::campaign_shrink::shrink(file, text, base)?;
    let mut head = format!("# Shrunk from {file} in {} runs; still fails:\n", r.runs);
    for f in &r.failed {
        head.push_str(&format!("#   {f}\n"));
    }
    for st in &r.steps {
        head.push_str(&format!("# step: {st}\n"));
    }
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(out, format!("{head}{}", r.text))
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(format!(
        "{} steps kept in {} runs -> {}",
        r.steps.len(),
        r.runs,
        out.display()
    ))
}

fn cmd_campaign_shrink(
    file: &std::path::Path,
    campaign: Option<&std::path::Path>,
    out: &std::path::Path,
) -> anyhow::Result<bool> {
    let text =
        std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let c = campaign
        .map(m6p_twin::campaign::Campaign::load)
        .transpose()?;
    let line = shrink_to(
        &file.display().to_string(),
        &text,
        c.as_ref().map(|c| &c.base),
        out,
    )?;
    println!("{line}");
    Ok(true)
}

fn cmd_campaign_merge(dirs: &[PathBuf], out: &std::path::Path) -> anyhow::Result<bool> {
    use m6p_twin::campaign_run::{self, RunVerdict};
    let (meta, rows) = campaign_run::merge(dirs, out)?;
    let failed = rows
        .iter()
        .filter(|r| r.verdict != RunVerdict::Pass)
        .count();
    println!(
        "campaign {}: {} runs from {} shards, {failed} not passed; results in {}",
        meta.name,
        rows.len(),
        dirs.len(),
        out.display()
    );
    Ok(failed == 0)
}

/// One scenario of `m6p-twin test`: its table row (name, passed, failed, simulated s,
/// wall s, whether it did not run), its JUnit test cases and what it has to say on stderr.
struct ScenarioTested {
    row: (String, usize, usize, f64, f64, bool),
    cases: Vec<quick_junit::TestCase>,
    errors: Vec<String>,
    ok: bool,
}

/// Load, run and judge one scenario file; a panic in the run is its error. A self-contained
/// run (virtual time, no outside link) shares `turns` with the others like it; one in real
/// time or with links to the outside runs alone (two may listen on one port, and a run paced
/// by the wall clock should not share the CPU).
fn test_one(
    f: &std::path::Path,
    seed: Option<u64>,
    turns: &std::sync::RwLock<()>,
) -> ScenarioTested {
    test_one_with(f, seed, turns, |compiled| {
        build_runtime_for(&compiled.opts)
            .and_then(|rt| rt.block_on(exec::execute(compiled, &mut |_| {})))
    })
}

/// [`test_one`] with the run given: `run` takes the compiled scenario to its outcome.
fn test_one_with(
    f: &std::path::Path,
    seed: Option<u64>,
    turns: &std::sync::RwLock<()>,
    run: impl FnOnce(m6p_twin::plan::Compiled) -> anyhow::Result<exec::Outcome>,
) -> ScenarioTested {
    let started = std::time::Instant::now();
    let error_case = |name: &str, classname: &str, e: String| {
        let mut case = quick_junit::TestCase::new(
            name.to_owned(),
            quick_junit::TestCaseStatus::non_success(quick_junit::NonSuccessKind::Error),
        );
        case.set_classname(classname.to_owned());
        case.set_system_err(e);
        case
    };
    let loaded = match exec::load(f) {
        Ok(l) => l,
        Err(e) => {
            let file = f.display().to_string();
            return ScenarioTested {
                cases: vec![error_case(&file, "scenario file", format!("{e:#}"))],
                errors: vec![format!("{e:#}")],
                row: (file, 0, 1, 0.0, started.elapsed().as_secs_f64(), true),
                ok: false,
            };
        }
    };
    let name = loaded.name();
    // Its log lines name it: scenarios side by side write to one stderr. At error level so
    // that no filter leaves a warning without it.
    let _span = tracing::error_span!("scenario", name = %name).entered();
    let compiled = exec::compile_seeded(&loaded, seed);
    let self_contained = compiled.opts.is_self_contained();
    let _beside = self_contained.then(|| {
        turns
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    });
    let _alone = (!self_contained).then(|| {
        turns
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    });
    let ran = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(compiled)))
        .unwrap_or_else(|p| {
            Err(anyhow::anyhow!(
                "panicked: {}",
                m6p_twin::campaign_run::panic_text(p.as_ref())
            ))
        });
    let out = match ran {
        Ok(out) => out,
        Err(e) => {
            return ScenarioTested {
                cases: vec![error_case(&name, &name, format!("{e:#}"))],
                errors: vec![format!("{name}: run failed: {e:#}")],
                row: (name, 0, 1, 0.0, started.elapsed().as_secs_f64(), true),
                ok: false,
            };
        }
    };
    let mut cases = Vec::with_capacity(out.verdicts.len());
    let mut errors = Vec::new();
    for v in &out.verdicts {
        let status = if v.passed {
            quick_junit::TestCaseStatus::success()
        } else {
            let mut st =
                quick_junit::TestCaseStatus::non_success(quick_junit::NonSuccessKind::Failure);
            st.set_message(format!("t = {}: {}", v.t, v.observed));
            st
        };
        let mut case = quick_junit::TestCase::new(v.name.clone(), status);
        case.set_classname(name.as_str());
        case.set_system_out(format!("t = {}: {}", v.t, v.observed));
        cases.push(case);
        if !v.passed {
            errors.push(format!(
                "FAIL {name}: {} (t = {}): {}",
                v.name, v.t, v.observed
            ));
        }
    }
    // A run cut short is no result: an error case, whatever held so far.
    if let Some(i) = &out.report.interrupted {
        cases.push(error_case(&name, &name, i.to_string()));
        errors.push(format!("{name}: {i}"));
    }
    let failed = out.verdicts.iter().filter(|v| !v.passed).count();
    ScenarioTested {
        row: (
            name,
            out.verdicts.len() - failed,
            failed,
            out.report.sim_time.as_secs_f64(),
            out.report.wall.as_secs_f64(),
            out.report.interrupted.is_some(),
        ),
        cases,
        errors,
        ok: failed == 0 && out.report.interrupted.is_none(),
    }
}

fn cmd_test(a: TestArgs) -> anyhow::Result<bool> {
    use std::io::IsTerminal as _;
    let show_bar = std::io::stderr().is_terminal() && std::env::var_os("CI").is_none();
    let bar = if show_bar {
        let b = indicatif::ProgressBar::new(a.files.len() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let jobs = m6p_twin::campaign_run::default_jobs(a.jobs);
    let turns = std::sync::RwLock::new(());
    // The scenarios run side by side; what each says on stderr comes as it ends, and the
    // table and the JUnit report are in the files' order.
    let tested = m6p_twin::campaign_run::in_parallel(
        &a.files,
        jobs,
        &|f| test_one(f, a.seed, &turns),
        &|t| {
            bar.suspend(|| {
                for e in &t.errors {
                    eprintln!("{e}");
                }
            });
            bar.set_message(format!("done: {}", t.row.0));
            bar.inc(1);
        },
    );
    let mut suite = quick_junit::TestSuite::new("m6p-twin scenarios");
    let mut all_ok = true;
    let mut rows = Vec::with_capacity(tested.len());
    for t in tested {
        all_ok &= t.ok;
        suite.add_test_cases(t.cases);
        rows.push(t.row);
    }
    bar.finish_and_clear();
    println!(
        "{:<36} {:>6} {:>6} {:>12} {:>10} {:>12}",
        "scenario", "passed", "failed", "sim time s", "wall s", "real-time x"
    );
    for (name, p, f, sim, wall, broken) in &rows {
        let rtf = if *wall > 0.0 { sim / wall } else { 0.0 };
        let note = if *broken { "  (did not run)" } else { "" };
        println!("{name:<36} {p:>6} {f:>6} {sim:>12.1} {wall:>10.3} {rtf:>12.0}{note}");
    }
    if let Some(path) = &a.junit {
        let mut report = quick_junit::Report::new("m6p-twin");
        report.add_test_suite(suite);
        let xml = report.to_string().context("serialising the JUnit report")?;
        std::fs::write(path, xml).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(all_ok)
}

fn cmd_gs(a: GsArgs) -> anyhow::Result<bool> {
    let Some(request) = a.request else {
        return m6p_twin::gs_shell::run(a.connect, a.as_addr, a.port, a.timeout);
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut client = gs::GsClient::connect(a.connect, a.as_addr).await?;
        match request {
            GsRequest::Ping {
                node,
                count,
                size,
                interval,
            } => gs::ping(&mut client, node, count, size, interval, a.timeout).await,
            GsRequest::Uptime { node, icd } => gs::uptime(&mut client, node, a.timeout, icd).await,
            GsRequest::Ident { node } => gs::ident(&mut client, node, a.timeout).await,
            GsRequest::Icd(words) => gs::icd_command(&mut client, &words, a.port, a.timeout).await,
            GsRequest::Raw { node, port, data } => {
                let bytes = m6p_twin::commands::parse_hex(&data).map_err(anyhow::Error::msg)?;
                gs::raw(&mut client, node, port, bytes, a.timeout).await
            }
            GsRequest::Setup {
                session,
                start,
                duration,
                max_packets,
                frame,
                sync,
            } => {
                let mut words = vec![
                    format!("session_id={session}"),
                    format!("timestamp={start}"),
                    format!("duration_s={duration}"),
                    format!("max_packets={max_packets}"),
                    format!("poll_frame_size={frame}"),
                ];
                let (_, _, cmd) =
                    m6p_twin::icd::find_command("PC.SETUP").map_err(anyhow::Error::msg)?;
                let mut args = gs::parse_args(&words)?;
                args.insert("sync_message".into(), sync.into());
                words.clear();
                let data = m6p_twin::icd::encode_args(cmd, &args).map_err(|(field, m)| {
                    let flag = match field.as_str() {
                        "duration_s" => "--duration",
                        "poll_frame_size" => "--frame",
                        "max_packets" => "--max-packets",
                        "timestamp" => "--start",
                        "sync_message" => "--sync",
                        _ => "SESSION",
                    };
                    anyhow::anyhow!("SETUP {flag}: {m}")
                })?;
                let mut req = vec![nodes_pc::wire::cmd::SETUP];
                req.extend(data);
                gs::pc_request(&mut client, req, a.timeout).await
            }
            GsRequest::Status { session } => {
                gs::pc_request(
                    &mut client,
                    vec![nodes_pc::wire::cmd::STATUS, session],
                    a.timeout,
                )
                .await
            }
            GsRequest::Abort { session } => {
                gs::pc_request(
                    &mut client,
                    vec![nodes_pc::wire::cmd::ABORT, session],
                    a.timeout,
                )
                .await
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run that panics is its scenario's error row, and the scenarios after it still run:
    /// the lock it held, shared (a self-contained run) or whole (one in real time), is free
    /// again and not poisoned.
    #[test]
    fn a_scenario_whose_run_panics_is_an_error_row() {
        let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let default = manifest.join("../../scenarios/default.toml");
        let realtime = std::env::temp_dir().join(format!(
            "m6p-twin-panic-{}-realtime.toml",
            std::process::id()
        ));
        let text = std::fs::read_to_string(&default).expect("default scenario");
        std::fs::write(&realtime, format!("{text}\n[clock]\nmode = \"realtime\"\n"))
            .expect("temp scenario");
        for (file, alone) in [(&default, false), (&realtime, true)] {
            let turns = std::sync::RwLock::new(());
            let t = test_one_with(file, None, &turns, |c| {
                assert_eq!(c.opts.is_self_contained(), !alone, "{}", file.display());
                panic!("a bug in the run")
            });
            assert!(!t.ok);
            assert!(t.row.5, "did not run");
            assert_eq!((t.row.1, t.row.2), (0, 1));
            assert_eq!(t.errors.len(), 1);
            assert!(
                t.errors[0].ends_with("run failed: panicked: a bug in the run"),
                "{:?}",
                t.errors
            );
            assert_eq!(t.cases.len(), 1);
            assert!(!turns.is_poisoned());
            assert!(turns.try_write().is_ok(), "the lock is free");
        }
        let _ = std::fs::remove_file(&realtime);
    }
}
