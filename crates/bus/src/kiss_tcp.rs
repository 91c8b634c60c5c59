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

use csp::kiss::{self, Decoder, DecoderConfig, KissDrop, KissEvent};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use crate::clock::Clock;
use crate::inbox::inbox;
use crate::outside::{OutsideEndpoint, Segments};

/// Settings of a KISS/TCP link.
#[derive(Debug, Clone, Default)]
pub struct KissLinkConfig {
    /// Addresses behind the link; empty = learn them from received packets.
    pub addrs: Vec<u8>,
    /// Receiver settings (the v1.4 248-byte limit is off by default).
    pub decoder: DecoderConfig,
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
                let (segs, cfg, stats) = (segs.clone(), cfg.clone(), stats.clone());
                tokio::spawn(async move {
                    let why = run_connection(
                        stream,
                        &segs,
                        &cfg,
                        &stats,
                        clock,
                        &format!("kiss:{peer}"),
                        n,
                    )
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

/// Connect to an outside server at `addr` and keep reconnecting with back-off.
pub async fn connect(
    addr: SocketAddr,
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
                let why = run_connection(
                    stream,
                    &segs,
                    &cfg,
                    &stats,
                    clock,
                    &format!("kiss:{addr}"),
                    n,
                )
                .await;
                tracing::info!(%addr, "KISS/TCP: connection closed: {why}");
                bump(&stats, |s| s.disconnects += 1);
            }
            Err(e) => tracing::debug!(%addr, "KISS/TCP: connect failed: {e}; retry in {backoff:?}"),
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(10));
    }
}

async fn run_connection(
    mut stream: TcpStream,
    segs: &Segments,
    cfg: &KissLinkConfig,
    stats: &SharedStats,
    clock: Clock,
    name: &str,
    n: u16,
) -> String {
    let _ = stream.set_nodelay(true);
    let (inbox_tx, mut inbox_rx) = inbox();
    let mut endpoint: Option<OutsideEndpoint> = None;
    for &a in &cfg.addrs {
        if let Err(e) = claim(&mut endpoint, segs, name, a, &inbox_tx, n) {
            tracing::warn!("{name}: cannot claim configured address {a}: {e}");
        }
    }
    let mut decoder = Decoder::new(cfg.decoder);
    let mut events = Vec::new();
    let mut buf = vec![0u8; 4096];
    let mut out = Vec::new();
    let why = loop {
        tokio::select! {
            biased;
            r = stream.read(&mut buf) => {
                let n_read = match r {
                    Ok(0) => break "peer closed".to_owned(),
                    Ok(k) => k,
                    Err(e) => break format!("read error: {e}"),
                };
                let before = decoder.stats();
                decoder.push(buf.get(..n_read).unwrap_or_default(), &mut events);
                let after = decoder.stats();
                bump(stats, |s| {
                    s.bytes_in += n_read as u64;
                    s.garbage_bytes += after.discarded_bytes - before.discarded_bytes;
                });
                let t = clock.now();
                for ev in events.drain(..) {
                    match ev {
                        KissEvent::Packet(p) => {
                            let res = claim(&mut endpoint, segs, name, p.header.src, &inbox_tx, n)
                                .and_then(|ep| ep.send(t, &p));
                            match res {
                                Ok(()) => bump(stats, |s| s.packets_in += 1),
                                Err(e) => {
                                    tracing::debug!("{name}: refused packet {}: {e}", p.header);
                                    bump(stats, |s| s.refused += 1);
                                }
                            }
                        }
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
                let Some(ep) = endpoint.as_mut() else { continue };
                match ep.receive(a) {
                    Some(Ok(p)) => {
                        out.clear();
                        kiss::encode(&p, &mut out);
                        if let Err(e) = stream.write_all(&out).await {
                            break format!("write error: {e}");
                        }
                        bump(stats, |s| { s.packets_out += 1; s.bytes_out += out.len() as u64; });
                    }
                    Some(Err(e)) => tracing::debug!("{name}: CFP drop towards outside: {e}"),
                    None => {}
                }
            }
        }
    };
    if let Some(ep) = endpoint {
        ep.release();
    }
    why
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
