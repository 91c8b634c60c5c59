//! The live view: serve a run over the Foxglove WebSocket protocol while it goes on
//! (`m6p-twin run --live [ADDR]`, cargo feature `live`).
//!
//! The server offers the same channels as the MCAP recording ([`crate::record`]): same
//! topics, same protobuf schemas, same messages (one encoder,
//! [`EventEncoder`], feeds both). Every message's log time is simulated time (the
//! scenario's start epoch plus the event's simulated time), and the server advertises the
//! `time` capability and broadcasts the simulated time as events arrive, so Foxglove's clock
//! follows the run rather than the wall clock.
//!
//! The server is the `foxglove` crate's (`WebSocketServer`, WebSocket subprotocols
//! `foxglove.sdk.v1` and `foxglove.sdk.v1.1`) on a loopback port of its own, behind
//! [`crate::live_front`] on the asked address, which also lets in clients that offer the
//! protocol's older name `foxglove.websocket.v1` (Foxglove Studio 1.x, Lichtblick,
//! `@foxglove/ws-protocol`). It has a [`foxglove::Context`] of its own, so its
//! channels never mix with another server's or the SDK's global context, and no MCAP sink
//! is attached: the SDK writes nothing to disk (recordings are [`crate::record::Recorder`]'s).
//! It runs on a small tokio runtime of its own (one worker thread), so a busy simulation
//! and a slow client do not stall each other; each client has a queue of
//! [`BACKLOG`] messages, and the oldest are dropped when a client falls behind. Its
//! clients may publish, in [`PUBLISH_ENCODING`], to a listener its caller gives (the run's
//! control channel: `m6p_twin::live_control`).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use foxglove::websocket::{Capability, ServerListener};
use foxglove::{
    ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer,
    WebSocketServerHandle,
};

use crate::live_front::{self, FrontCounts};
use crate::record::{
    ChannelKind, Encoded, EventEncoder, FIXED_CHANNELS, MESSAGE_ENCODING, SCHEMA_ENCODING,
};
use twin_core::events::RunEvent;

/// The default address of the live view.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Messages queued per client before the oldest are dropped.
pub const BACKLOG: usize = 4096;

/// The encoding the server takes its clients' messages in, when they may publish.
pub const PUBLISH_ENCODING: &str = "json";

/// Ports above 1023 that browsers refuse to fetch from or open a WebSocket to (the Fetch
/// standard's "bad ports"): the server behind the front listens on one of them when its
/// clients may publish.
const BROWSER_REFUSED_PORTS: [u16; 19] = [
    6665, 6666, 6667, 6668, 6669, 6679, 6697, 10080, 6566, 6000, 5060, 5061, 4190, 4045, 3659,
    2049, 1723, 1720, 1719,
];

/// The least wall-clock time between two broadcasts of the simulated time.
const TIME_EVERY: Duration = Duration::from_millis(20);

/// A Foxglove WebSocket server that shows a run live.
pub struct LiveServer {
    /// Runs the server's tasks; `None` once shut down.
    rt: Option<tokio::runtime::Runtime>,
    server: Option<WebSocketServerHandle>,
    ctx: Arc<Context>,
    addr: SocketAddr,
    front: Arc<FrontCounts>,
    enc: EventEncoder,
    /// Channels by (kind, key), in order of creation.
    chans: Vec<(ChannelKind, String, Arc<RawChannel>)>,
    /// Latest simulated time seen (ns since the Unix epoch) and the last one broadcast.
    latest: u64,
    broadcast: Option<(u64, Instant)>,
    /// Messages handed to the server.
    messages: u64,
    /// Set after the first error, which is reported once; publishing then stops.
    failed: bool,
    /// Whether its clients may publish.
    publishing: bool,
}

impl std::fmt::Debug for LiveServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveServer")
            .field("addr", &self.addr)
            .field("channels", &self.chans.len())
            .field("messages", &self.messages)
            .finish_non_exhaustive()
    }
}

impl LiveServer {
    /// Start a server on `addr` (port 0: any free port) for a run that starts `start_ns`
    /// after the Unix epoch, with the channels every run has. With `publish`, its clients
    /// may publish (in [`PUBLISH_ENCODING`]) to that listener, when `addr` is a loopback
    /// address: it is the run's control channel, which can power nodes off, and the
    /// protocol has no authentication; browser pages of other sites are then turned away
    /// ([`live_front::Origins::Trusted`]). Call it outside an async runtime (it blocks on
    /// its own).
    pub fn start(
        addr: SocketAddr,
        start_ns: u64,
        publish: Option<Arc<dyn ServerListener>>,
    ) -> anyhow::Result<LiveServer> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("m6p-live")
            .enable_all()
            .build()
            .context("building the live view's runtime")?;
        let ctx = Context::new();
        let listener = rt
            .block_on(tokio::net::TcpListener::bind(addr))
            .with_context(|| format!("starting the live view on {addr}"))?;
        let addr = listener.local_addr()?;
        let builder = |port: u16, publish: Option<&Arc<dyn ServerListener>>| {
            let b = WebSocketServer::new()
                .name(format!("m6p-twin {}", env!("CARGO_PKG_VERSION")))
                .bind("127.0.0.1", port)
                .capabilities([Capability::Time])
                .message_backlog_size(BACKLOG)
                .context(&ctx);
            match publish {
                Some(l) => b
                    .capabilities([Capability::Time, Capability::ClientPublish])
                    .supported_encodings([PUBLISH_ENCODING])
                    .listener(l.clone()),
                None => b,
            }
        };
        let publish = match publish {
            Some(l) if addr.ip().is_loopback() => Some(l),
            Some(_) => {
                tracing::warn!(
                    "live view on {addr}: not a loopback address, so its clients may not \
                     publish (to the control channel, which can power nodes off)"
                );
                None
            }
            None => None,
        };
        // Started from within `rt`, the server spawns its tasks on `rt`. A server its
        // clients publish to sits on a port browsers refuse to open a WebSocket to: a page
        // of another site can find no way round the front's `Origin` check.
        let mut started = None;
        if let Some(l) = &publish {
            started = BROWSER_REFUSED_PORTS
                .iter()
                .find_map(|&port| rt.block_on(builder(port, Some(l)).start()).ok());
            if started.is_none() {
                tracing::warn!(
                    "live view: none of the ports browsers refuse ({BROWSER_REFUSED_PORTS:?}) \
                     is free on 127.0.0.1, so its clients may not publish"
                );
            }
        }
        let publishing = started.is_some();
        let server = match started {
            Some(s) => s,
            None => rt
                .block_on(builder(0, None).start())
                .context("starting the live view's server")?,
        };
        let inner = SocketAddr::from(([127, 0, 0, 1], server.port()));
        let front = Arc::new(FrontCounts::default());
        let origins = if publishing {
            live_front::Origins::Trusted
        } else {
            live_front::Origins::Any
        };
        rt.spawn(live_front::serve(listener, inner, front.clone(), origins));
        let mut live = LiveServer {
            rt: Some(rt),
            server: Some(server),
            ctx,
            addr,
            front,
            enc: EventEncoder::new(start_ns),
            chans: Vec::new(),
            latest: start_ns,
            broadcast: None,
            messages: 0,
            failed: false,
            publishing,
        };
        for (kind, key) in FIXED_CHANNELS {
            channel(&mut live.chans, &live.ctx, kind, key)?;
        }
        Ok(live)
    }

    /// Decode `/csp/packets` with the ICD on these ports (the run's; default: the ICD's
    /// default ports), as the recording does.
    pub fn set_icd(&mut self, icd: twin_core::icd::IcdMap) {
        self.enc.set_icd(icd);
    }

    /// The address the server listens on (with the actual port when 0 was asked).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Messages handed to the server so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// Whether its clients may publish.
    pub fn publishing(&self) -> bool {
        self.publishing
    }

    /// Publish one event's messages, with their simulated log times, and the simulated
    /// time (at most every 20 ms of wall-clock time). Never fails: the first error is
    /// logged and the live view stops publishing, while the run goes on.
    pub fn publish(&mut self, ev: &RunEvent) {
        if self.failed {
            return;
        }
        if let Err(e) = self.try_publish(ev) {
            self.failed = true;
            tracing::warn!("live view stopped: {e:#}");
        }
    }

    fn try_publish(&mut self, ev: &RunEvent) -> anyhow::Result<()> {
        let LiveServer {
            enc,
            chans,
            ctx,
            latest,
            messages,
            ..
        } = self;
        enc.encode(ev, &mut |m: Encoded<'_>| {
            let chan = channel(chans, ctx, m.kind, m.key)?;
            chan.log_with_meta(m.data, PartialMetadata::with_log_time(m.log_time));
            *latest = (*latest).max(m.log_time);
            *messages += 1;
            Ok(())
        })?;
        self.maybe_broadcast_time(false);
        Ok(())
    }

    /// Broadcast the latest simulated time if it advanced, and `force` or enough wall-clock
    /// time has passed since the last broadcast.
    fn maybe_broadcast_time(&mut self, force: bool) {
        let now = Instant::now();
        let due = match self.broadcast {
            None => true,
            Some((t, at)) => self.latest > t && (force || now.duration_since(at) >= TIME_EVERY),
        };
        if due && let Some(server) = &self.server {
            server.broadcast_time(self.latest);
            self.broadcast = Some((self.latest, now));
        }
    }

    /// Broadcast the final simulated time and stop the server (closing its connections),
    /// waiting at most a second for it. Call it outside an async runtime.
    pub fn finish(mut self) {
        self.maybe_broadcast_time(true);
        let legacy = self.front.legacy.load(Ordering::Relaxed);
        let full = self.front.refused_full.load(Ordering::Relaxed);
        let head = self.front.refused_head.load(Ordering::Relaxed);
        if legacy + full + head > 0 {
            tracing::info!(
                "live view: {legacy} client(s) as {}, {full} refused (full), {head} refused (bad request)",
                "foxglove.websocket.v1"
            );
        }
        self.shutdown(Duration::from_secs(1));
    }

    fn shutdown(&mut self, wait: Duration) {
        let Some(rt) = self.rt.take() else {
            return;
        };
        if let Some(server) = self.server.take() {
            let stopped = server.stop();
            if tokio::runtime::Handle::try_current().is_err() {
                rt.block_on(async {
                    let _ = tokio::time::timeout(wait, stopped.wait()).await;
                });
            }
        }
        rt.shutdown_background();
    }
}

/// The channel of (`kind`, `key`) in `chans`, created in `ctx` on first use.
fn channel<'c>(
    chans: &'c mut Vec<(ChannelKind, String, Arc<RawChannel>)>,
    ctx: &Arc<Context>,
    kind: ChannelKind,
    key: &str,
) -> anyhow::Result<&'c Arc<RawChannel>> {
    let i = match chans.iter().position(|(k, c, _)| *k == kind && c == key) {
        Some(i) => i,
        None => {
            let schema = Schema::new(kind.schema_name(), SCHEMA_ENCODING, kind.schema_data()?);
            let topic = kind.topic(key);
            let chan = ChannelBuilder::new(topic.as_str())
                .context(ctx)
                .message_encoding(MESSAGE_ENCODING)
                .schema(schema)
                .metadata(kind.metadata(key))
                .build_raw()
                .with_context(|| format!("creating live channel {topic}"))?;
            chans.push((kind, key.to_owned(), chan));
            chans.len() - 1
        }
    };
    Ok(&chans[i].2)
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.shutdown(Duration::ZERO);
    }
}
