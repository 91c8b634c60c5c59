//! CSP over UDP (`csp::udp`: one packet per datagram, the header in network order), for
//! programs that speak it: YAMCS's CSP support (`UdpTmDataLink` and `UdpTcDataLink` with
//! `CspPacketPreprocessor` and `CspCommandPostprocessor`), libcsp's UDP interface, a script.
//!
//! The twin binds one UDP socket (`--udp 127.0.0.1:10015`). What it receives there is one
//! connection's input for the whole run (`udp 127.0.0.1:10015#1`) into the link core of
//! [`crate::kiss_tcp`]: addresses (configured, or learned from the first packets), claims,
//! bounds, gate and tap, as on a KISS link. What the twin sends to the link's addresses
//! goes to the link's peer: the address given (`--udp 127.0.0.1:10015,127.0.0.1:10016`,
//! `peer = "..."`), as YAMCS's telemetry link needs before it sends anything, or else the
//! source of the latest datagram received. Until there is a peer, frames are dropped and
//! counted as unread output (logged once). A failed send is counted the same way and never
//! ends the link.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use tokio::net::UdpSocket;

use crate::kiss_tcp::{
    AbortOnDrop, Connection, FrameSink, KissLinkConfig, LinkInput, SharedStats, bump, edge,
    serve_link, take_in,
};
use bus::clock::Clock;
use bus::outside::Segments;

/// Where the twin's UDP link is bound, and where it sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UdpAddr {
    /// The twin's socket.
    pub bind: SocketAddr,
    /// Where the twin sends; `None`: to the source of the latest datagram received.
    pub peer: Option<SocketAddr>,
}

impl std::fmt::Display for UdpAddr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.bind)?;
        if let Some(p) = self.peer {
            write!(f, ",{p}")?;
        }
        Ok(())
    }
}

/// Why a text is not a [`UdpAddr`] (the text, as given).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "`{0}` is not a UDP link's address: expected BIND (IP:PORT, where the twin listens) or \
     BIND,PEER (and IP:PORT where it sends)"
)]
pub struct UdpAddrError(pub String);

impl std::str::FromStr for UdpAddr {
    type Err = UdpAddrError;
    fn from_str(s: &str) -> Result<Self, UdpAddrError> {
        let bad = || UdpAddrError(s.to_owned());
        let (bind, peer) = match s.split_once(',') {
            Some((b, p)) => (b, Some(p)),
            None => (s, None),
        };
        Ok(UdpAddr {
            bind: bind.trim().parse().map_err(|_| bad())?,
            peer: peer
                .map(|p| p.trim().parse().map_err(|_| bad()))
                .transpose()?,
        })
    }
}

/// The link's bound socket.
#[derive(Debug)]
pub struct UdpLink {
    socket: UdpSocket,
    addr: UdpAddr,
}

/// Why the link's socket could not be bound.
#[derive(Debug, thiserror::Error)]
#[error("cannot bind the CSP/UDP link on {addr}: {cause}")]
pub struct BindError {
    addr: SocketAddr,
    cause: std::io::Error,
}

impl UdpLink {
    /// Bind the link's socket.
    pub async fn bind(addr: UdpAddr) -> Result<Self, BindError> {
        let socket = UdpSocket::bind(addr.bind)
            .await
            .map_err(|cause| BindError {
                addr: addr.bind,
                cause,
            })?;
        Ok(UdpLink { socket, addr })
    }

    /// Where it is bound (the port the system chose for port 0) and where it sends.
    pub fn addr(&self) -> UdpAddr {
        UdpAddr {
            bind: self.socket.local_addr().unwrap_or(self.addr.bind),
            peer: self.addr.peer,
        }
    }
}

/// The link's socket as a frame sink: each frame one datagram to the peer.
struct Sender {
    socket: Arc<UdpSocket>,
    /// The configured peer, or the latest source seen.
    peer: Arc<Mutex<Option<SocketAddr>>>,
    stats: SharedStats,
    name: String,
    /// Whether a drop was logged already (once per link: the count goes on).
    told: bool,
}

impl Sender {
    fn dropped(&mut self, why: String) {
        bump(&self.stats, |s| s.out_dropped += 1);
        if !std::mem::replace(&mut self.told, true) {
            tracing::warn!(
                "{}: {why} (counted as output dropped; told once)",
                self.name
            );
        }
    }
}

impl FrameSink for Sender {
    async fn send_frame(&mut self, frame: &[u8]) -> std::io::Result<()> {
        let peer = *self
            .peer
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        match peer {
            Some(p) => {
                if let Err(e) = self.socket.send_to(frame, p).await {
                    self.dropped(format!("a datagram to {p} was not sent: {e}"));
                }
            }
            None => self.dropped("no peer yet (none given, and no datagram received)".to_owned()),
        }
        Ok(())
    }
}

/// Serve the link for the rest of the run.
pub async fn serve(
    link: UdpLink,
    label: String,
    segs: Segments,
    cfg: KissLinkConfig,
    stats: SharedStats,
    clock: Clock,
) {
    let UdpLink { socket, addr } = link;
    let socket = Arc::new(socket);
    let peer = Arc::new(Mutex::new(addr.peer));
    bump(&stats, |s| s.connections += 1);
    let name = format!("{label}#1");
    // Bounded as a KISS connection's input: when the twin has not taken `input_chunks`
    // datagrams the reader waits, and the system's socket buffer drops what comes then.
    let (in_tx, in_rx) = tokio::sync::mpsc::channel(cfg.limits.input_chunks.max(1));
    let opened = edge(clock, &cfg, &name).await;
    let (reader_cfg, reader_name) = (cfg.clone(), name.clone());
    let (reader_socket, reader_peer) = (socket.clone(), peer.clone());
    let learn = addr.peer.is_none();
    let reader = async move {
        // A datagram larger than a packet is cut here and refused by its length.
        let mut buf = vec![0u8; csp::header::HEADER_LEN + csp::udp::UDP_MTU + 1];
        loop {
            match reader_socket.recv_from(&mut buf).await {
                Ok((n, from)) => {
                    if learn {
                        *reader_peer
                            .lock()
                            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(from);
                    }
                    let Ok(slot) = in_tx.clone().reserve_owned().await else {
                        return;
                    };
                    take_in(
                        clock,
                        &reader_cfg,
                        &reader_name,
                        slot,
                        LinkInput::Bytes(buf[..n].to_vec()),
                    )
                    .await;
                }
                Err(e) => {
                    // An ICMP error of an earlier send, on some systems: the link goes on.
                    tracing::debug!("{reader_name}: receive failed: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(10)).await;
                }
            }
        }
    };
    let _reader = AbortOnDrop(tokio::spawn(reader));
    let mut out = Sender {
        socket,
        peer,
        stats: stats.clone(),
        name: name.clone(),
        told: false,
    };
    let k = Connection::whole_run(&name, &segs, &cfg, &stats, clock, opened);
    let why = serve_link(in_rx, &mut out, k).await;
    tracing::info!("{name}: closed: {why}");
    bump(&stats, |s| s.disconnects += 1);
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn udp_addresses_parse_and_print() {
        let a: UdpAddr = "127.0.0.1:10015".parse().unwrap();
        assert_eq!((a.bind.port(), a.peer), (10015, None));
        assert_eq!(a.to_string(), "127.0.0.1:10015");
        let b: UdpAddr = "127.0.0.1:10015,127.0.0.1:10016".parse().unwrap();
        assert_eq!(b.peer.unwrap().port(), 10016);
        assert_eq!(b.to_string(), "127.0.0.1:10015,127.0.0.1:10016");
        for bad in ["", "localhost:1", "127.0.0.1:1,", "127.0.0.1:1,x"] {
            assert_eq!(
                bad.parse::<UdpAddr>(),
                Err(UdpAddrError(bad.to_owned())),
                "{bad}"
            );
        }
    }

    /// A taken port is a clear error, not a panic.
    #[tokio::test]
    async fn a_taken_port_is_a_clear_error() {
        let first = UdpLink::bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
        let taken = first.addr();
        let e = UdpLink::bind(taken).await.unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("cannot bind the CSP/UDP link on {}", taken.bind)),
            "{e}"
        );
    }
}
