//! The `m6p-twin` command line.

use std::net::SocketAddr;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context as _;
use bus::ClockMode;
use clap::{Parser, Subcommand};
use m6p_twin::duration::parse_duration;
use m6p_twin::network::NetworkSpec;
use m6p_twin::runtime::{RunOptions, SocketCanBus, build_runtime, run};
use m6p_twin::{default_plan, gs};

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
    /// Run the network (in virtual time as fast as the CPU allows, unless --realtime).
    Run(RunArgs),
    /// Join a running twin over KISS/TCP as a ground node and send requests.
    Gs(GsArgs),
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// Simulated duration: 90, 90s, 10m, 2h [default: 10m; with --realtime, until Ctrl-C].
    #[arg(long, value_parser = parse_duration)]
    duration: Option<Duration>,
    /// Follow the wall clock (needed by outside programs; implied by --kiss-* and --socketcan).
    #[arg(long)]
    realtime: bool,
    /// With --realtime: simulated seconds per wall second.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Seed of every random choice (CFP idents, ephemeral ports, impairments).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Listen for outside CSP nodes speaking KISS over TCP (for example 127.0.0.1:52001).
    #[arg(long = "kiss-listen", value_name = "ADDR")]
    kiss_listen: Vec<SocketAddr>,
    /// Connect to an outside KISS/TCP server, as the platform does in ICD 2.3.
    #[arg(long = "kiss-connect", value_name = "ADDR")]
    kiss_connect: Vec<SocketAddr>,
    /// CSP addresses behind the KISS links (default: learned from the packets they send).
    #[arg(long = "kiss-addr", value_name = "ID")]
    kiss_addr: Vec<u8>,
    /// Apply libcsp 1.4's KISS receive limit (at most 248 data bytes) to the twin's receiver.
    #[arg(long)]
    libcsp14_kiss_limit: bool,
    /// Bridge a real CAN interface (can0, vcan0) to the main or payload bus [default bus:
    /// main]. Needs a build with --features socketcan (Linux).
    #[arg(long = "socketcan", value_name = "IFACE[:main|:payload]", value_parser = SocketCanBus::parse_arg)]
    socketcan: Vec<(String, SocketCanBus)>,
}

#[derive(Debug, clap::Args)]
struct GsArgs {
    /// The twin's KISS/TCP server.
    #[arg(long, value_name = "ADDR")]
    connect: SocketAddr,
    /// This ground node's CSP address.
    #[arg(long = "as", default_value_t = 16, value_name = "ID")]
    as_addr: u8,
    /// How long to wait for each reply.
    #[arg(long, default_value = "2s", value_parser = parse_duration)]
    timeout: Duration,
    #[command(subcommand)]
    request: GsRequest,
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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let res = match cli.command {
        Command::Run(a) => cmd_run(a),
        Command::Gs(a) => cmd_gs(a),
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

fn cmd_run(a: RunArgs) -> anyhow::Result<bool> {
    let network = NetworkSpec::default_m6p();
    let outside =
        !a.kiss_listen.is_empty() || !a.kiss_connect.is_empty() || !a.socketcan.is_empty();
    if outside && !a.realtime {
        eprintln!("note: outside links need the wall clock: running in real time");
    }
    let realtime = a.realtime || outside;
    let duration = match (a.duration, realtime) {
        (Some(d), _) => Some(d),
        (None, false) => Some(Duration::from_secs(600)),
        (None, true) => None,
    };
    let mut opts = RunOptions::new(network, duration.unwrap_or(Duration::from_secs(600)));
    opts.duration = duration;
    opts.clock = if realtime {
        ClockMode::Realtime { speed: a.speed }
    } else {
        ClockMode::Virtual
    };
    opts.seed = a.seed;
    opts.kiss_listen = a.kiss_listen;
    opts.kiss_connect = a.kiss_connect;
    opts.kiss.addrs = a.kiss_addr;
    opts.kiss.decoder.libcsp14_rx_limit = a.libcsp14_kiss_limit;
    opts.socketcan = a.socketcan;
    opts.trace = false;
    let plan_for = duration.unwrap_or(Duration::from_secs(24 * 3600));
    opts.ground_plan
        .insert(16, default_plan(&opts.network, plan_for));
    let rt = build_runtime(opts.clock)?;
    let (tx, rx) = tokio::sync::oneshot::channel();
    let report = rt.block_on(async {
        let task = tokio::spawn(run(opts, Some(tx)));
        if let Ok(addrs) = rx.await {
            for a in addrs {
                eprintln!("KISS/TCP: listening on {a} (try: m6p-twin gs --connect {a} ping 3)");
            }
        }
        task.await.context("the run task failed")?
    })?;
    print!("{}", report.table());
    Ok(true)
}

fn cmd_gs(a: GsArgs) -> anyhow::Result<bool> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut client = gs::GsClient::connect(a.connect, a.as_addr).await?;
        match a.request {
            GsRequest::Ping {
                node,
                count,
                size,
                interval,
            } => gs::ping(&mut client, node, count, size, interval, a.timeout).await,
            GsRequest::Uptime { node, icd } => gs::uptime(&mut client, node, a.timeout, icd).await,
            GsRequest::Ident { node } => gs::ident(&mut client, node, a.timeout).await,
        }
    })
}
