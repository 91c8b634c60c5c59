//! KISS over TCP links (ICD 2.3): CSP packets in libcsp 1.4's KISS framing on a TCP
//! stream, for programs outside the twin.
//!
//! - [`serve`] listens (127.0.0.1 by default) and accepts any number of outside nodes, one
//!   connection each; [`connect`] is the platform's side of ICD 2.3, a client that connects
//!   to the payload's server and reconnects with back-off (0.5 s doubling to 10 s).
//! - The CSP addresses behind a connection are configured, or learned from the source of
//!   the first packets; the segment follows the address range ([`crate::outside`]).
//! - Garbage bytes, bad CRCs, short and oversize frames and disconnects are counted and
//!   logged; the twin keeps running and accepts new connections.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::SimTime;
use csp::kiss::{self, Decoder, DecoderConfig, KissDrop, KissEvent};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use crate::clock::Clock;
use crate::gate::{DelayLine, LinkGate, Passage};
use crate::inbox::inbox;
use crate::outside::{OutsideEndpoint, Segments};

/// Settings of a KISS/TCP link.
#[derive(Debug, Clone, Default)]
pub struct KissLinkConfig {
    /// Addresses behind the link; empty = learn them from received packets.
    pub addrs: Vec<u8>,
    /// Receiver settings (the v1.4 248-byte limit is off by default).
    pub decoder: DecoderConfig,
    /// Where the raw bytes crossing the socket go (the recorder).
    pub tap: Option<KissTap>,
    /// The link's faults and power ([`crate::gate`]); `None`: everything crosses.
    pub gate: Option<LinkGate>,
}

/// Receives every chunk read from and every frame written to a link's socket:
/// `(time, link name, true = into the twin, bytes)`.
#[derive(Clone)]
pub struct KissTap(Arc<TapFn>);

type TapFn = dyn Fn(SimTime, &str, bool, &[u8]) + Send + Sync;

impl KissTap {
    /// A tap calling `f`.
    pub fn new(f: impl Fn(SimTime, &str, bool, &[u8]) + Send + Sync + 'static) -> Self {
        KissTap(Arc::new(f))
    }
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
    /// Packets refused (bad source address, wrong segment, too long for CAN).
    pub refused: u64,
}

/// Shared counters of a link.
pub type SharedStats = Arc<Mutex<KissLinkStats>>;

fn bump(stats: &SharedStats, f: impl FnOnce(&mut KissLinkStats)) {
    f(&mut stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner));
}

/// Accept outside nodes on `listener` forever.
pub async fn serve(
    listener: TcpListener,
    label: String,
    segs: Segments,
    cfg: KissLinkConfig,
    stats: SharedStats,
    clock: Clock,
) {
    let mut n = 0u16;
    loop {
        match listener.accept().await {
            Ok((stream, peer)) => {
                n = n.wrapping_add(1);
                tracing::info!(%peer, "KISS/TCP: outside node connected");
                bump(&stats, |s| s.connections += 1);
                let (segs, cfg, stats, label) =
                    (segs.clone(), cfg.clone(), stats.clone(), label.clone());
                let _ = stream.set_nodelay(true);
                tokio::spawn(async move {
                    let conn = format!("{label}#{n}");
                    let why = run_connection(stream, &conn, &segs, &cfg, &stats, clock, n).await;
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
    let mut n = 0u16;
    loop {
        match TcpStream::connect(addr).await {
            Ok(stream) => {
                n = n.wrapping_add(1);
                backoff = Duration::from_millis(500);
                tracing::info!(%addr, "KISS/TCP: connected to outside server");
                bump(&stats, |s| s.connections += 1);
                let _ = stream.set_nodelay(true);
                let conn = format!("{label}#{n}");
                let why = run_connection(stream, &conn, &segs, &cfg, &stats, clock, n).await;
                tracing::info!(%addr, "KISS/TCP: connection closed: {why}");
                bump(&stats, |s| s.disconnects += 1);
            }
            Err(e) => tracing::debug!(%addr, "KISS/TCP: connect failed: {e}; retry in {backoff:?}"),
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(10));
    }
}

/// Serve one connection of link `name` until it closes; returns why it closed. Generic over
/// the stream; the bytes read are stamped with the clock's time as they arrive.
pub async fn run_connection<S: AsyncRead + AsyncWrite + Unpin>(
    stream: S,
    name: &str,
    segs: &Segments,
    cfg: &KissLinkConfig,
    stats: &SharedStats,
    clock: Clock,
    n: u16,
) -> String {
    let (mut rd, mut wr) = tokio::io::split(stream);
    let (in_tx, in_rx) = tokio::sync::mpsc::unbounded_channel();
    let reader = async move {
        let mut buf = vec![0u8; 4096];
        loop {
            match rd.read(&mut buf).await {
                Ok(0) => return "peer closed".to_owned(),
                Ok(k) => {
                    if in_tx
                        .send((clock.now(), buf.get(..k).unwrap_or_default().to_vec()))
                        .is_err()
                    {
                        return "link closed".to_owned();
                    }
                }
                Err(e) => return format!("read error: {e}"),
            }
        }
    };
    tokio::select! {
        biased;
        why = serve_link(in_rx, &mut wr, name, segs, cfg, stats, n, clock) => why,
        why = reader => why,
    }
}

/// The link's core: time-stamped input chunks in, KISS frames out to `stream`. Every
/// connection has its own name (`listen 127.0.0.1:52001#2` for the second one). `replay` feeds
/// it recorded chunks with their recorded times. Ends when the input ends or a write fails.
///
/// Every packet crossing, in either direction, passes the link's gate (`cfg.gate`): it
/// crosses now, waits out a delay, or is lost (counted by the gate). The bytes read are
/// recorded whatever the gate decides; a packet towards the outside is written (and
/// recorded) when it crosses.
#[allow(clippy::too_many_arguments)]
pub async fn serve_link<W: AsyncWrite + Unpin>(
    mut input: tokio::sync::mpsc::UnboundedReceiver<(SimTime, Vec<u8>)>,
    stream: &mut W,
    name: &str,
    segs: &Segments,
    cfg: &KissLinkConfig,
    stats: &SharedStats,
    n: u16,
    clock: Clock,
) -> String {
    let (inbox_tx, mut inbox_rx) = inbox();
    // Released however this ends, also when the future is dropped (the connection's reader
    // ended first): the twin's own node with a claimed address gets it back.
    let mut claims = Claims(None);
    let endpoint = &mut claims.0;
    for &a in &cfg.addrs {
        if let Err(e) = claim(endpoint, segs, name, a, &inbox_tx, n) {
            tracing::warn!("{name}: cannot claim configured address {a}: {e}");
        }
    }
    let mut decoder = Decoder::new(cfg.decoder);
    let mut events = Vec::new();
    let mut out = Vec::new();
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
                    take_in(endpoint, segs, name, &inbox_tx, n, stats, t, &p);
                }
                while let Some((t, bytes)) = delayed_out.pop_due(now) {
                    if let Err(e) = write_out(stream, name, cfg, stats, t, &bytes).await {
                        return e;
                    }
                }
            }
            r = input.recv() => {
                let Some((t, chunk)) = r else { break "peer closed".to_owned() };
                let chunk = chunk.as_slice();
                let n_read = chunk.len();
                if let Some(tap) = &cfg.tap {
                    (tap.0)(t, name, true, chunk);
                }
                let before = decoder.stats();
                decoder.push(chunk, &mut events);
                let after = decoder.stats();
                bump(stats, |s| {
                    s.bytes_in += n_read as u64;
                    s.garbage_bytes += after.discarded_bytes - before.discarded_bytes;
                });
                for ev in events.drain(..) {
                    match ev {
                        KissEvent::Packet(p) => match gate(cfg) {
                            Passage::Now => {
                                take_in(endpoint, segs, name, &inbox_tx, n, stats, t, &p);
                            }
                            Passage::After(d) => {
                                if delayed_in.push(t + d, p).is_err() {
                                    overflow(cfg, name);
                                }
                            }
                            Passage::Lost(why) => {
                                tracing::debug!("{name}: packet {} from the outside lost at the link: {why:?}", p.header);
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
            a = inbox_rx.recv() => {
                let Some(a) = a else { break "inbox closed".to_owned() };
                let a_t = a.t;
                let Some(ep) = endpoint.as_mut() else { continue };
                match ep.receive(a) {
                    Some(Ok(p)) => {
                        out.clear();
                        kiss::encode(&p, &mut out);
                        match gate(cfg) {
                            Passage::Now => {
                                if let Err(e) = write_out(stream, name, cfg, stats, a_t, &out).await {
                                    break e;
                                }
                            }
                            Passage::After(d) => {
                                if delayed_out.push(a_t + d, out.clone()).is_err() {
                                    overflow(cfg, name);
                                }
                            }
                            Passage::Lost(why) => {
                                tracing::debug!("{name}: packet {} to the outside lost at the link: {why:?}", p.header);
                            }
                        }
                    }
                    Some(Err(e)) => tracing::debug!("{name}: CFP drop towards outside: {e}"),
                    None => {}
                }
            }
        }
    }
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

/// Take a packet from the outside into the twin at `t`.
#[allow(clippy::too_many_arguments)]
fn take_in(
    endpoint: &mut Option<OutsideEndpoint>,
    segs: &Segments,
    name: &str,
    inbox: &crate::inbox::InboxTx,
    n: u16,
    stats: &SharedStats,
    t: SimTime,
    p: &csp::Packet,
) {
    let res = claim(endpoint, segs, name, p.header.src, inbox, n).and_then(|ep| ep.send(t, p));
    match res {
        Ok(()) => bump(stats, |s| s.packets_in += 1),
        Err(e) => {
            tracing::debug!("{name}: refused packet {}: {e}", p.header);
            bump(stats, |s| s.refused += 1);
        }
    }
}

/// Write one KISS frame to the outside program at `t`; the error ends the link.
async fn write_out<W: AsyncWrite + Unpin>(
    stream: &mut W,
    name: &str,
    cfg: &KissLinkConfig,
    stats: &SharedStats,
    t: SimTime,
    frame: &[u8],
) -> Result<(), String> {
    if let Some(tap) = &cfg.tap {
        (tap.0)(t, name, false, frame);
    }
    stream
        .write_all(frame)
        .await
        .map_err(|e| format!("write error: {e}"))?;
    bump(stats, |s| {
        s.packets_out += 1;
        s.bytes_out += frame.len() as u64;
    });
    Ok(())
}

/// An outside link's endpoint, released when dropped.
struct Claims(Option<OutsideEndpoint>);

impl Drop for Claims {
    fn drop(&mut self) {
        if let Some(ep) = &self.0 {
            ep.release();
        }
    }
}

fn claim<'a>(
    endpoint: &'a mut Option<OutsideEndpoint>,
    segs: &Segments,
    name: &str,
    addr: u8,
    inbox: &crate::inbox::InboxTx,
    n: u16,
) -> Result<&'a mut OutsideEndpoint, crate::outside::OutsideError> {
    match endpoint {
        Some(ep) => {
            ep.claim(addr)?;
        }
        None => {
            let ep = OutsideEndpoint::attach(segs, name, addr, inbox.clone(), n.wrapping_mul(97))?;
            tracing::info!(
                "{name}: outside node {addr} joined the {:?} segment",
                ep.kind()
            );
            *endpoint = Some(ep);
        }
    }
    endpoint
        .as_mut()
        .ok_or(crate::outside::OutsideError::BadSource(addr))
}
