//! `m6p-twin gs`: join a running twin over KISS/TCP as a ground node.

use std::net::SocketAddr;
use std::time::Duration;

use clap::Subcommand;
use m6p_twin::duration::parse_duration;
use m6p_twin::gs;

/// What `gs --help` shows after its lists: the two forms the subcommand list cannot show
/// (an ICD command by name, the console), each with an example.
const AFTER_HELP: &str = "\
ICD commands by name (any command of any node, as `m6p-twin icd NODE` lists them):
  m6p-twin gs --connect ADDR NODE COMMAND [NAME=VALUE ...]
  The arguments are checked against the ICD before anything is sent; the reply is decoded,
  one line per field with the ICD's names and units. For example:
    m6p-twin gs --connect 127.0.0.1:52001 fc tmgen
    m6p-twin gs --connect 127.0.0.1:52001 eps chset channel=PC on=off
    m6p-twin gs --connect 127.0.0.1:52001 pc setup session_id=1 timestamp=now duration_s=10m \\
        max_packets=0 poll_frame_size=200 sync_message=go

The console (interactive): give no request. One line per request, as above without
`m6p-twin gs --connect ADDR` (`fc tmgen`, `ping fc`, `raw 6 12 01`), with history, Tab
completion of nodes, commands, argument names and values, and `help`; Ctrl-D leaves:
    m6p-twin gs --connect 127.0.0.1:52001
  With standard input not a terminal it runs the lines of standard input (a script):
    m6p-twin gs --connect 127.0.0.1:52001 < lines.txt

The run's control channel (`m6p-twin run --control ADDR`): faults now or later, the time:
    m6p-twin gs --control 127.0.0.1:7700 fault power-off PL12 --for 5s
    m6p-twin gs --control 127.0.0.1:7700 fault drop main probability=0.5 --at 20m --until 25m
    m6p-twin gs --control 127.0.0.1:7700 clear 0
    m6p-twin gs --control 127.0.0.1:7700 time";

#[derive(Debug, clap::Args)]
#[command(after_help = AFTER_HELP)]
pub struct GsArgs {
    /// The twin's KISS/TCP server (every request but `fault`, `clear` and `time`).
    #[arg(long, value_name = "ADDR", required_unless_present = "control")]
    pub connect: Option<SocketAddr>,
    /// The run's control channel (`run --control ADDR`), for `fault`, `clear` and `time`.
    #[arg(long, value_name = "ADDR")]
    pub control: Option<SocketAddr>,
    /// This ground node's CSP address (0-30).
    #[arg(long = "as", default_value_t = 17, value_name = "ID",
          value_parser = clap::value_parser!(u8).range(0..=30))]
    pub as_addr: u8,
    /// For an ICD command: the port to send it to, where the scenario moved it.
    #[arg(long, value_name = "PORT")]
    pub port: Option<u8>,
    /// How long to wait for each reply.
    #[arg(long, default_value = "2s", value_parser = parse_duration)]
    pub timeout: Duration,
    /// The request; without one, the console: interactive on a terminal (history, Tab
    /// completion), else the lines of standard input.
    #[command(subcommand)]
    pub request: Option<GsRequest>,
}

#[derive(Debug, Subcommand)]
pub enum GsRequest {
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
    /// Any request: `raw NODE PORT HEX`; the reply decoded where the ICD knows it, else in
    /// hex.
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
    /// Inject a fault into the run through its control channel (`--control`): KIND TARGET
    /// [NAME=VALUE ...] as a scenario's `[[faults]]` entry says it (`power-off PL12`, `drop
    /// main probability=0.5`, `reboot FC`), now or at `--at`; the reply gives its id.
    Fault {
        /// The fault's kind (`m6p-twin schema` lists them with their fields).
        kind: String,
        /// The medium (`main`, `payload`, `uhf`), node (`PL12`, `3`) or outside link.
        target: String,
        /// The kind's own fields, NAME=VALUE.
        fields: Vec<String>,
        /// When it starts, simulated time since the run's start (default: now).
        #[arg(long, value_name = "T")]
        at: Option<String>,
        /// How long it lasts.
        #[arg(long = "for", value_name = "DURATION")]
        lasting: Option<String>,
        /// When it is lifted, simulated time since the run's start.
        #[arg(long, value_name = "T")]
        until: Option<String>,
    },
    /// Lift a fault injected through the control channel, now, by its id.
    Clear {
        /// Its id (as `fault` answered).
        id: u32,
    },
    /// The run's simulated time, through its control channel.
    Time,
    /// Take a snapshot of the run now, through its control channel: the run writes it to
    /// its --snapshot-dir, named by its instant (docs/snapshots.md).
    Snapshot,
}

/// A control request's JSON, or `None` for a request over KISS.
fn control_request(r: &GsRequest) -> anyhow::Result<Option<serde_json::Value>> {
    Ok(Some(match r {
        GsRequest::Time => serde_json::json!({ "op": "time" }),
        GsRequest::Snapshot => serde_json::json!({ "op": "snapshot" }),
        GsRequest::Clear { id } => serde_json::json!({ "op": "clear", "id": id }),
        GsRequest::Fault {
            kind,
            target,
            fields,
            at,
            lasting,
            until,
        } => {
            let mut req = serde_json::json!({ "op": "fault", "kind": kind });
            req["target"] = match target.parse::<u8>() {
                Ok(a) => a.into(),
                Err(_) => target.clone().into(),
            };
            for (k, v) in [("at", at), ("for", lasting), ("until", until)] {
                if let Some(v) = v {
                    req[k] = v.clone().into();
                }
            }
            for f in fields {
                let Some((k, v)) = f.split_once('=') else {
                    anyhow::bail!("`{f}`: a field is NAME=VALUE");
                };
                // A number or true/false as such; anything else as text.
                req[k] = serde_json::from_str::<serde_json::Value>(v)
                    .ok()
                    .filter(|v| v.is_number() || v.is_boolean())
                    .unwrap_or_else(|| v.into());
            }
            req
        }
        _ => return Ok(None),
    }))
}

pub fn cmd_gs(a: GsArgs) -> anyhow::Result<bool> {
    if let Some(req) = a
        .request
        .as_ref()
        .map(control_request)
        .transpose()?
        .flatten()
    {
        let Some(addr) = a.control else {
            anyhow::bail!(
                "`fault`, `clear` and `time` go to the run's control channel: give --control ADDR (the address `run --control` printed)"
            );
        };
        return gs::control(addr, &req, a.timeout);
    }
    let Some(connect) = a.connect else {
        anyhow::bail!(
            "this request goes over KISS: give --connect ADDR (the twin's KISS/TCP server)"
        );
    };
    let Some(request) = a.request else {
        return m6p_twin::gs_shell::run(connect, a.as_addr, a.port, a.timeout);
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut client = gs::GsClient::connect(connect, a.as_addr).await?;
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
                let bytes = m6p_twin::commands::parse_hex(&data)?;
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
                let (_, _, cmd) = m6p_twin::icd::find_command("PC.SETUP")?;
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
            GsRequest::Fault { .. }
            | GsRequest::Clear { .. }
            | GsRequest::Time
            | GsRequest::Snapshot => {
                anyhow::bail!("a control request goes to --control")
            }
        }
    })
}
