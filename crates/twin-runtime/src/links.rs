//! Links to programs outside the twin: the KISS/TCP servers and clients (`links::kiss_tcp`),
//! the recorded input of a replayed run fed through the same link core, and the SocketCAN
//! bridges (cargo feature `socketcan`). Each link is a background task; its counters are
//! shared with the report.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use anyhow::Context as _;
use bus::Clock;
use bus::gate::LinkGate;
use bus::outside::{BridgeStats, LinkId, Segments};
use csp::SimTime;
use links::kiss_tcp::{self, KissLinkConfig, KissLinkStats, KissLog, KissTap};
use tokio::sync::mpsc;

use super::{KissMode, RunOptions, mix};
use twin_core::events::{Direction, Level, RunEvent};

/// The gates of the scenario's outside links (`opts.outside`), each drawing its chances
/// from its own stream of the run's seed (salt 0x700 + its index).
pub(super) fn gates(opts: &RunOptions) -> Vec<LinkGate> {
    (0..opts.outside.len())
        .map(|i| LinkGate::new(mix(opts.seed, 0x700 + i as u64)))
        .collect()
}

/// The gate of the runtime's link `label`, if it is one of the scenario's.
fn gate_of(opts: &RunOptions, gates: &[LinkGate], label: &str) -> Option<LinkGate> {
    opts.outside
        .iter()
        .position(|l| l.is(label))
        .and_then(|i| gates.get(i).cloned())
}

/// The KISS links of a run: their counters by name and the addresses the servers listen on.
pub(super) struct KissLinks {
    /// Counters by link name.
    pub(super) stats: Vec<(String, Arc<Mutex<KissLinkStats>>)>,
    /// The bound addresses of the listening servers.
    pub(super) bound: Vec<SocketAddr>,
    /// Chunks read from outside programs that the run may hold before it has handled
    /// them: the main loop gives a permit back for each `RunEvent::Kiss` into the twin.
    pub(super) budget: Arc<tokio::sync::Semaphore>,
}

/// Chunks read from outside (up to 4 KiB each) waiting for the run's main loop, over all
/// links: 256 KiB.
const KISS_EVENT_BUDGET: usize = 64;

/// Open every KISS link of `opts` (listen, connect, replayed input) on `segs`; the bytes
/// that cross them and their warnings go to `events`.
pub(super) async fn kiss(
    opts: &RunOptions,
    segs: &Segments,
    clock: Clock,
    gates: &[LinkGate],
    events: &mpsc::UnboundedSender<RunEvent>,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<KissLinks> {
    let (budget, tap, log) = tap_and_log(events);
    // The run's tap, log and gate on a link's own settings.
    let wire = |cfg: &KissLinkConfig, label: &str| KissLinkConfig {
        tap: Some(tap.clone()),
        log: Some(log.clone()),
        gate: gate_of(opts, gates, label),
        ..cfg.clone()
    };
    let replay_ids = reserve_configured(opts, segs, clock, events);
    let mut kiss_stats = Vec::new();
    let mut bound = Vec::new();
    for (i, link) in opts.kiss_links.iter().enumerate() {
        let label = link.label();
        let mut cfg = wire(&link.cfg, &label);
        cfg.link = LinkId(i as u32);
        // The hub's messages; KISS on every other link.
        cfg.framing = match link.mode {
            KissMode::ZmqHub(_) => links::kiss_tcp::Framing::ZmqHub,
            KissMode::Udp(_) => links::kiss_tcp::Framing::Udp,
            _ => links::kiss_tcp::Framing::Kiss,
        };
        kiss_stats.push(
            start_link(
                link, label, cfg, segs, clock, events, background, &mut bound,
            )
            .await?,
        );
    }
    start_replay(
        opts,
        &replay_ids,
        &wire,
        segs,
        clock,
        background,
        &mut kiss_stats,
    );
    Ok(KissLinks {
        stats: kiss_stats,
        bound,
        budget,
    })
}

/// The run's tap (the bytes that cross a link, as `RunEvent::Kiss`, within the budget of
/// chunks the main loop has not handled yet) and log (a link's warnings).
fn tap_and_log(
    events: &mpsc::UnboundedSender<RunEvent>,
) -> (Arc<tokio::sync::Semaphore>, KissTap, KissLog) {
    let budget = Arc::new(tokio::sync::Semaphore::new(KISS_EVENT_BUDGET));
    let tap = {
        let tx = events.clone();
        KissTap::with_budget(
            move |t, link, into_twin, bytes| {
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
            },
            budget.clone(),
        )
    };
    let log = {
        let tx = events.clone();
        KissLog::new(move |t, link, message| {
            let _ = tx.send(RunEvent::Log {
                t,
                source: link.to_owned(),
                level: Level::Warning,
                message,
            });
        })
    };
    (budget, tap, log)
}

/// Reserve, before any link starts, the addresses each link is configured with; the ids of
/// the replayed links (after the command line's and scenario's).
fn reserve_configured(
    opts: &RunOptions,
    segs: &Segments,
    clock: Clock,
    events: &mpsc::UnboundedSender<RunEvent>,
) -> Vec<LinkId> {
    // Before any link starts: an address a link is configured with is that link's, its
    // program connected or not (another link learning addresses cannot take it). Each
    // link is one id (labels may repeat: two servers on 127.0.0.1:0); a replayed link's
    // connections share theirs.
    let mut replayed: Vec<&str> = Vec::new();
    let replay_ids: Vec<LinkId> = opts
        .kiss_replay
        .iter()
        .map(|i| {
            let link = link_of(&i.link);
            let k = replayed.iter().position(|l| *l == link).unwrap_or_else(|| {
                replayed.push(link);
                replayed.len() - 1
            });
            LinkId((opts.kiss_links.len() + k) as u32)
        })
        .collect();
    let configured = opts
        .kiss_links
        .iter()
        .enumerate()
        .map(|(i, l)| (LinkId(i as u32), l.label(), &l.cfg.addrs))
        .chain(
            opts.kiss_replay
                .iter()
                .zip(&replay_ids)
                .map(|(i, &id)| (id, link_of(&i.link).to_owned(), &i.cfg.addrs)),
        );
    for (id, label, addrs) in configured {
        for &a in addrs {
            if let Err(holder) = segs.reserve(a, id, &label) {
                let message = format!("address {a} cannot be reserved: {holder} has it");
                tracing::warn!("{label}: {message}");
                let _ = events.send(RunEvent::Log {
                    t: clock.now(),
                    source: label.clone(),
                    level: Level::Warning,
                    message,
                });
            }
        }
    }
    replay_ids
}

/// Start one KISS link (listen, connect, pty or hub) or UDP link as a background task; its
/// counters by name. A listening server's or UDP link's bound address goes to `bound`.
#[allow(clippy::too_many_arguments)]
async fn start_link(
    link: &super::KissLink,
    label: String,
    cfg: KissLinkConfig,
    segs: &Segments,
    clock: Clock,
    events: &mpsc::UnboundedSender<RunEvent>,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
    bound: &mut Vec<SocketAddr>,
) -> anyhow::Result<(String, Arc<Mutex<KissLinkStats>>)> {
    let stats = Arc::new(Mutex::new(KissLinkStats::default()));
    let named;
    match &link.mode {
        KissMode::Listen(addr) => {
            let addr = *addr;
            let listener = tokio::net::TcpListener::bind(addr)
                .await
                .with_context(|| format!("listening for KISS/TCP on {addr}"))?;
            let local = listener.local_addr().context("reading the bound address")?;
            if !local.ip().is_loopback() {
                not_loopback(events, clock, &label, format!("KISS/TCP server on {local}"));
            }
            bound.push(local);
            named = (format!("listen {local}"), stats.clone());
            background.push(tokio::spawn(kiss_tcp::serve(
                listener,
                label,
                segs.clone(),
                cfg,
                stats,
                clock,
            )));
        }
        KissMode::Connect(addr) => {
            named = (label.clone(), stats.clone());
            background.push(tokio::spawn(kiss_tcp::connect(
                *addr,
                label,
                segs.clone(),
                cfg,
                stats,
                clock,
            )));
        }
        KissMode::Pty(path) => {
            let pty = open_pty(path)?;
            tracing::info!(
                "KISS on {} (pseudo-terminal {})",
                path.display(),
                pty.device().display()
            );
            named = (label.clone(), stats.clone());
            background.push(tokio::spawn(links::kiss_pty::serve(
                pty,
                label,
                segs.clone(),
                cfg,
                stats,
                clock,
            )));
        }
        KissMode::ZmqHub(addr) => {
            let hub = links::zmq_hub::Hub::bind(*addr).await?;
            if !addr.host.is_loopback() {
                not_loopback(events, clock, &label, format!("ZMQ hub on {addr}"));
            }
            named = (label.clone(), stats.clone());
            background.push(tokio::spawn(links::zmq_hub::serve(
                hub,
                label,
                segs.clone(),
                cfg,
                stats,
                clock,
            )));
        }
        KissMode::Udp(addr) => {
            let link = links::udp::UdpLink::bind(*addr).await?;
            let at = link.addr();
            if !at.bind.ip().is_loopback() {
                not_loopback(
                    events,
                    clock,
                    &label,
                    format!("CSP/UDP link on {}", at.bind),
                );
            }
            bound.push(at.bind);
            named = (label.clone(), stats.clone());
            background.push(tokio::spawn(links::udp::serve(
                link,
                label,
                segs.clone(),
                cfg,
                stats,
                clock,
            )));
        }
    }
    Ok(named)
}

/// Feed recorded outside input again at its recorded instants and in its recorded order
/// (one feeder for every connection: the order input of one instant is taken in is part
/// of the run); what the twin answers is recorded again and compared by `replay`.
fn start_replay(
    opts: &RunOptions,
    replay_ids: &[LinkId],
    wire: &dyn Fn(&KissLinkConfig, &str) -> KissLinkConfig,
    segs: &Segments,
    clock: Clock,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
    kiss_stats: &mut Vec<(String, Arc<Mutex<KissLinkStats>>)>,
) {
    // Recorded outside input, fed again at its recorded instants and in its recorded order
    // (one feeder for every connection: the order input of one instant is taken in is part
    // of the run); what the twin answers is recorded again and compared by `replay`.
    let mut feed: Vec<Fed> = Vec::new();
    let mut conns = Vec::new();
    for ((n, input), &id) in opts.kiss_replay.iter().enumerate().zip(replay_ids) {
        let stats = Arc::new(Mutex::new(KissLinkStats::default()));
        kiss_stats.push((format!("replayed {}", input.link), stats.clone()));
        let mut cfg = wire(&input.cfg, &input.link);
        cfg.link = id;
        // The connection number seeds its CFP ident as in the recorded run.
        let number = input
            .link
            .rsplit_once('#')
            .and_then(|(_, k)| k.parse().ok())
            .unwrap_or(n as u64 + 1);
        // A recording's first empty chunk of a connection is its open (older recordings
        // have none: the connection is open from the start, before any input).
        if input.chunks.first().is_none_or(|c| !c.bytes.is_empty()) {
            feed.push(Fed {
                seq: None,
                t: SimTime::ZERO,
                conn: n,
                bytes: Vec::new(),
            });
        }
        feed.extend(input.chunks.iter().map(|c| Fed {
            seq: Some(c.seq),
            t: c.t,
            conn: n,
            bytes: c.bytes.clone(),
        }));
        // Never full: the recorded input is fed at its instants.
        let (tx, rx) = mpsc::channel(input.chunks.len().max(1));
        conns.push(ReplayedConn {
            label: input.link.clone(),
            number,
            cfg,
            stats,
            tx,
            rx: Some(rx),
        });
    }
    // The run's order (older recordings' opens first).
    feed.sort_by_key(|f| f.seq);
    if !feed.is_empty() {
        background.push(tokio::spawn(replay_feed(feed, conns, segs.clone(), clock)));
    }
}

/// A recorded connection, fed again.
struct ReplayedConn {
    label: String,
    number: u64,
    cfg: KissLinkConfig,
    stats: Arc<Mutex<KissLinkStats>>,
    tx: mpsc::Sender<(SimTime, kiss_tcp::LinkInput)>,
    /// Until its open starts its core, which takes it.
    rx: Option<mpsc::Receiver<(SimTime, kiss_tcp::LinkInput)>>,
}

/// One piece of recorded input to feed again.
struct Fed {
    /// Its place in the recorded run's order (`None`: an older recording's open, first).
    seq: Option<u64>,
    t: SimTime,
    /// Index into the replayed connections.
    conn: usize,
    bytes: Vec<u8>,
}

/// Feed recorded input, in order, to the replayed connections: each piece queued at its
/// instant, to be taken in at the run's idle point as the original took it
/// ([`bus::pace`]). A connection's first piece is its open, which starts its core there;
/// a later empty one is its close.
async fn replay_feed(feed: Vec<Fed>, mut conns: Vec<ReplayedConn>, segs: Segments, clock: Clock) {
    for f in feed {
        clock.sleep_until(f.t).await;
        let Some(c) = conns.get_mut(f.conn) else {
            continue;
        };
        if let Some(rx) = c.rx.take() {
            let opened = kiss_tcp::edge_queued(clock, &c.cfg, &c.label).await;
            let (label, cfg, stats, segs, n) = (
                c.label.clone(),
                c.cfg.clone(),
                c.stats.clone(),
                segs.clone(),
                c.number,
            );
            tokio::spawn(async move {
                let opened = opened.await;
                let mut discard = kiss_tcp::Stream(tokio::io::sink());
                let k = kiss_tcp::Connection {
                    name: &label,
                    segs: &segs,
                    cfg: &cfg,
                    stats: &stats,
                    n,
                    clock,
                    opened,
                    live: None,
                };
                kiss_tcp::serve_link(rx, &mut discard, k).await;
            });
            continue;
        }
        let input = if f.bytes.is_empty() {
            kiss_tcp::LinkInput::End
        } else {
            kiss_tcp::LinkInput::Bytes(f.bytes)
        };
        if let Ok(slot) = c.tx.clone().reserve_owned().await {
            kiss_tcp::take_in(clock, &c.cfg, &c.label, slot, input).await;
        }
    }
    // The links stay open until the end of the run, as the recorded programs were.
    std::future::pending::<()>().await;
}

/// The link of a recorded connection's name (`listen 127.0.0.1:52001#2`: its link is
/// `listen 127.0.0.1:52001`).
fn link_of(connection: &str) -> &str {
    connection
        .rsplit_once('#')
        .map_or(connection, |(link, _)| link)
}

/// Warn that a link's server listens beyond this machine.
/// Serve every console of `opts.uart` on its node's control channel; the bound addresses
/// of the TCP ones, in order.
pub(super) async fn uart(
    opts: &RunOptions,
    ctls: &std::collections::BTreeMap<u8, bus::driver::CtlTx>,
    clock: Clock,
    events: &mpsc::UnboundedSender<RunEvent>,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<Vec<SocketAddr>> {
    let mut bound = Vec::new();
    for link in &opts.uart {
        let label = link.label();
        let node = opts
            .network
            .nodes
            .iter()
            .find(|n| n.name.eq_ignore_ascii_case(&link.node))
            .with_context(|| format!("{label}: no node {} in the network", link.node))?;
        let ctl = ctls.get(&node.addr).with_context(|| {
            format!(
                "{label}: {} is not a node of the twin (an outside program replaces it)",
                node.name
            )
        })?;
        let target = links::console::ConsoleTarget {
            node: node.name.clone(),
            addr: node.addr,
            ctl: ctl.clone(),
        };
        match &link.at {
            super::UartAt::Tcp(addr) => {
                let listener = tokio::net::TcpListener::bind(addr)
                    .await
                    .with_context(|| format!("{label}: listening on {addr}"))?;
                let local = listener.local_addr().context("reading the bound address")?;
                if !local.ip().is_loopback() {
                    not_loopback(events, clock, &label, format!("console on {local}"));
                }
                tracing::info!(
                    "console of {} on {local} (nc {} {})",
                    node.name,
                    local.ip(),
                    local.port()
                );
                bound.push(local);
                background.push(tokio::spawn(links::console::serve_tcp(
                    listener, target, clock,
                )));
            }
            #[cfg(unix)]
            super::UartAt::Pty(path) => {
                let pty = open_pty(path)?;
                tracing::info!(
                    "console of {} on {} (pseudo-terminal {}; screen {})",
                    node.name,
                    path.display(),
                    pty.device().display(),
                    path.display()
                );
                background.push(tokio::spawn(links::console::serve_pty(pty, target, clock)));
            }
            #[cfg(not(unix))]
            super::UartAt::Pty(path) => {
                anyhow::bail!(
                    "{label}: pseudo-terminals need a Unix system ({})",
                    path.display()
                )
            }
        }
    }
    Ok(bound)
}

fn not_loopback(events: &mpsc::UnboundedSender<RunEvent>, clock: Clock, label: &str, what: String) {
    let text = format!(
        "{what}: not a loopback address, so programs on other machines can connect and \
         claim addresses of the twin"
    );
    tracing::warn!("{text}");
    let _ = events.send(RunEvent::Log {
        t: clock.now(),
        source: label.to_owned(),
        level: Level::Warning,
        message: text,
    });
}

/// The pseudo-terminal of a `kiss-pty` link.
#[cfg(unix)]
fn open_pty(path: &std::path::Path) -> anyhow::Result<links::kiss_pty::Pty> {
    Ok(links::kiss_pty::Pty::open(path)?)
}

/// Shared counters of the SocketCAN bridges, by name.
pub(super) type BridgeStatsList = Vec<(String, Arc<Mutex<BridgeStats>>)>;

/// Open every interface of `links` and spawn its bridge to the chosen bus.
#[cfg(all(feature = "socketcan", target_os = "linux"))]
pub(super) fn spawn_socketcan_bridges(
    opts: &RunOptions,
    segs: &Segments,
    clock: Clock,
    gates: &[LinkGate],
    background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<BridgeStatsList> {
    let links = &opts.socketcan;
    let mut opened = Vec::new();
    for (ifname, which) in links {
        // The error names the interface and includes its OS cause (not chained: it would
        // print twice).
        let link = links::socketcan::SocketCanLink::open(ifname)
            .map_err(|e| anyhow::anyhow!("cannot bridge to a SocketCAN interface: {e}"))?;
        opened.push((link, *which));
    }
    let mut stats = Vec::new();
    for (link, which) in opened {
        let can = match which {
            super::SocketCanBus::Main => segs.main.clone(),
            super::SocketCanBus::Payload => segs.payload.clone(),
        };
        let shared = Arc::new(Mutex::new(BridgeStats::default()));
        stats.push((format!("{} ({which} bus)", link.ifname()), shared.clone()));
        let gate = gate_of(opts, gates, &format!("socketcan {}", link.ifname()));
        let task = links::socketcan::bridge(can, link, clock, shared, gate);
        background.push(tokio::spawn(task));
    }
    Ok(stats)
}

/// The final values of shared counters, by link name.
pub(super) fn snapshot<T: Clone>(stats: Vec<(String, Arc<Mutex<T>>)>) -> Vec<(String, T)> {
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

/// Without the `socketcan` feature there is nothing to bridge with.
#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
pub(super) fn spawn_socketcan_bridges(
    opts: &RunOptions,
    _segs: &Segments,
    _clock: Clock,
    _gates: &[LinkGate],
    _background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<BridgeStatsList> {
    match opts.socketcan.first() {
        None => Ok(Vec::new()),
        Some((ifname, _)) => anyhow::bail!(
            "SocketCAN interface `{ifname}`: this m6p-twin was built without SocketCAN support; rebuild with --features socketcan (Linux only)"
        ),
    }
}
