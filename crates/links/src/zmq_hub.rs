//! libcsp 1.4's ZMQ hub, played by the twin: any number of unmodified libcsp 1.4 programs
//! calling `csp_zmqhub_init(addr, "HOST")` join the twin's network.
//!
//! Each such program connects a PUB socket to `tcp://HOST:6000` and a SUB socket, subscribed
//! to its own address byte, to `tcp://HOST:7000` (`csp_if_zmqhub.c`). A hub in the middle
//! binds the other side of both: here the twin binds a SUB socket (subscribed to
//! everything) where the programs publish, and a PUB socket where they subscribe. The
//! message format is `csp::zmqhub`'s. Every message read is one chunk into the link core
//! of [`crate::kiss_tcp`] (addresses, claims, bounds, gate, tap), with the hub's framing:
//!
//! - a program's address is claimed on the segment its range decides (12-15 the payload
//!   bus, 16-20 the ground, others the main bus), so programs on one hub may sit on
//!   different segments;
//! - a packet from one program on the hub to another goes straight across the hub, as
//!   libcsp's own hub forwards it; anything else enters the twin at its sender's segment;
//! - a packet of the twin to an address the hub holds is published with that address as
//!   its first byte.
//!
//! The hub is one connection for the whole run (`zmq-hub 127.0.0.2#1`); a program joins or
//! leaves it without the twin noticing, as with a real hub. Ports are libcsp's 6000 and
//! 7000 unless set (`HOST:6000:7000`). A loopback address other than 127.0.0.1 (any
//! 127.0.0.x) lets several twins run hubs side by side.

use std::net::IpAddr;

use zeromq::{Socket, SocketRecv, SocketSend};

use crate::kiss_tcp::{
    AbortOnDrop, Connection, FrameSink, KissLinkConfig, LinkInput, SharedStats, bump, edge,
    serve_link, take_in,
};
use bus::clock::Clock;
use bus::outside::Segments;

/// Where the twin binds its hub: the host, the port the programs publish to and the port
/// they subscribe at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HubAddr {
    /// The host libcsp programs pass to `csp_zmqhub_init`.
    pub host: IpAddr,
    /// Where their PUB sockets connect (libcsp 1.4: 6000); the twin's SUB side.
    pub publish_port: u16,
    /// Where their SUB sockets connect (libcsp 1.4: 7000); the twin's PUB side.
    pub subscribe_port: u16,
}

/// libcsp 1.4's ports.
pub const PUBLISH_PORT: u16 = 6000;
/// libcsp 1.4's ports.
pub const SUBSCRIBE_PORT: u16 = 7000;

impl HubAddr {
    /// The hub of libcsp 1.4 on `host` (ports 6000 and 7000).
    pub fn new(host: IpAddr) -> Self {
        HubAddr {
            host,
            publish_port: PUBLISH_PORT,
            subscribe_port: SUBSCRIBE_PORT,
        }
    }

    fn endpoint(&self, port: u16) -> String {
        match self.host {
            IpAddr::V4(h) => format!("tcp://{h}:{port}"),
            IpAddr::V6(h) => format!("tcp://[{h}]:{port}"),
        }
    }
}

impl std::fmt::Display for HubAddr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.host)?;
        if (self.publish_port, self.subscribe_port) != (PUBLISH_PORT, SUBSCRIBE_PORT) {
            write!(f, ":{}:{}", self.publish_port, self.subscribe_port)?;
        }
        Ok(())
    }
}

/// Why a text is not a [`HubAddr`] (the text, as given).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HubAddrError {
    /// Not `HOST` or `HOST:PUB:SUB` with an IP address and two port numbers.
    #[error(
        "`{0}` is not a hub address: expected HOST (an IP address, as given to \
         csp_zmqhub_init) or HOST:PUBLISH_PORT:SUBSCRIBE_PORT"
    )]
    Syntax(String),
    /// A port 0, or the same port twice.
    #[error(
        "`{0}` is not a hub address: expected HOST (an IP address, as given to \
         csp_zmqhub_init) or HOST:PUBLISH_PORT:SUBSCRIBE_PORT: two different, non-zero ports"
    )]
    Ports(String),
}

impl std::str::FromStr for HubAddr {
    type Err = HubAddrError;
    /// `HOST` or `HOST:PUB:SUB` (an IPv4 or bracketed IPv6 address; the ports the programs
    /// publish to and subscribe at).
    fn from_str(s: &str) -> Result<Self, HubAddrError> {
        let bad = || HubAddrError::Syntax(s.to_owned());
        let (host, ports) = match s.strip_prefix('[') {
            Some(rest) => {
                let (h, tail) = rest.split_once(']').ok_or_else(bad)?;
                (h, tail.strip_prefix(':'))
            }
            None => match s.split_once(':') {
                Some((h, p)) => (h, Some(p)),
                None => (s, None),
            },
        };
        let host: IpAddr = host.parse().map_err(|_| bad())?;
        let mut addr = HubAddr::new(host);
        if let Some(p) = ports {
            let (a, b) = p.split_once(':').ok_or_else(bad)?;
            addr.publish_port = a.parse().map_err(|_| bad())?;
            addr.subscribe_port = b.parse().map_err(|_| bad())?;
            if addr.publish_port == 0
                || addr.subscribe_port == 0
                || addr.publish_port == addr.subscribe_port
            {
                return Err(HubAddrError::Ports(s.to_owned()));
            }
        }
        Ok(addr)
    }
}

/// The hub's two bound sockets.
pub struct Hub {
    addr: HubAddr,
    sub: zeromq::SubSocket,
    /// An XPUB socket: a PUB socket that also hands out its subscribers' subscriptions, so
    /// the hub sees which addresses its programs listen on.
    publ: zeromq::XPubSocket,
}

impl std::fmt::Debug for Hub {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Hub({})", self.addr)
    }
}

/// Why the hub could not be bound.
#[derive(Debug, thiserror::Error)]
#[error("cannot bind the ZMQ hub on {endpoint}: {cause}")]
pub struct BindError {
    endpoint: String,
    cause: String,
}

impl Hub {
    /// Bind both sockets of the hub at `addr`.
    pub async fn bind(addr: HubAddr) -> Result<Self, BindError> {
        let err = |endpoint: String| {
            move |e: zeromq::ZmqError| BindError {
                endpoint,
                cause: e.to_string(),
            }
        };
        let mut sub = zeromq::SubSocket::new();
        let e = addr.endpoint(addr.publish_port);
        sub.bind(&e).await.map_err(err(e))?;
        sub.subscribe("")
            .await
            .map_err(err(addr.endpoint(addr.publish_port)))?;
        let mut publ = zeromq::XPubSocket::new();
        let e = addr.endpoint(addr.subscribe_port);
        publ.bind(&e).await.map_err(err(e))?;
        Ok(Hub { addr, sub, publ })
    }

    /// Where it is bound.
    pub fn addr(&self) -> HubAddr {
        self.addr
    }
}

/// The twin's PUB side as a link's frame sink: one message per packet, handed to the task
/// that owns the socket ([`publish`]).
struct Publisher(tokio::sync::mpsc::Sender<Vec<u8>>);

impl FrameSink for Publisher {
    async fn send_frame(&mut self, frame: &[u8]) -> std::io::Result<()> {
        self.0
            .send(frame.to_vec())
            .await
            .map_err(|_| std::io::Error::other("the hub's publisher ended"))
    }
}

/// Own the hub's XPUB socket: publish what the link sends, in order, and read the programs'
/// subscriptions. A program that listens on an address a node of the twin holds (a payload
/// program at 12 while the twin runs PL12) gets nothing from the twin, which answers in its
/// place: warned once per address, naming what would give the program that address.
async fn publish(
    mut publ: zeromq::XPubSocket,
    mut frames: tokio::sync::mpsc::Receiver<Vec<u8>>,
    segs: Segments,
    cfg: KissLinkConfig,
    name: String,
    clock: Clock,
) {
    let mut warned = std::collections::BTreeSet::new();
    let mut send_failed = false;
    loop {
        tokio::select! {
            m = publ.recv() => match m {
                Ok(m) => {
                    let Some(addr) = subscribed_address(m.get(0).map(|b| &b[..])) else {
                        continue;
                    };
                    if cfg.addrs.contains(&addr) || !warned.insert(addr) {
                        continue;
                    }
                    if let Some(node) = segs.node_holding(addr) {
                        crate::kiss_tcp::warn_held(&cfg, clock.now(), &name, addr, &node);
                    }
                }
                // The library has dropped the failed subscriber already: the others go on.
                Err(e) => tracing::debug!("{name}: a subscriber failed: {e}"),
            },
            f = frames.recv() => match f {
                Some(f) => {
                    if let Err(e) = publ.send(zeromq::ZmqMessage::from(f)).await {
                        if std::mem::replace(&mut send_failed, true) {
                            tracing::debug!("{name}: publishing failed: {e}");
                        } else {
                            tracing::warn!("{name}: publishing failed: {e} (further failures at debug level)");
                        }
                    }
                }
                None => return,
            },
        }
    }
}

/// The CSP address a subscription message subscribes to: `1` then the one-byte topic a
/// libcsp 1.4 program subscribes with (`csp_if_zmqhub.c`: its own address).
fn subscribed_address(m: Option<&[u8]>) -> Option<u8> {
    match m? {
        [1, addr] if *addr < 31 => Some(*addr),
        _ => None,
    }
}

/// Serve the hub as a link for the rest of the run.
pub async fn serve(
    hub: Hub,
    label: String,
    segs: Segments,
    cfg: KissLinkConfig,
    stats: SharedStats,
    clock: Clock,
) {
    let Hub { mut sub, publ, .. } = hub;
    bump(&stats, |s| s.connections += 1);
    let name = format!("{label}#1");
    // Bounded as a KISS connection's input: when the twin has not taken `input_chunks`
    // messages the reader waits, and ZMQ queues (then drops) on its side.
    let (in_tx, in_rx) = tokio::sync::mpsc::channel(cfg.limits.input_chunks.max(1));
    let opened = edge(clock, &cfg, &name).await;
    let (reader_cfg, reader_name) = (cfg.clone(), name.clone());
    let reader = async move {
        loop {
            match sub.recv().await {
                Ok(m) => {
                    // libcsp sends one part per message; a multi-part message is taken
                    // whole, as libzmq's `zmq_msg_recv` would give its first part only.
                    // Only the socket's end ends the hub: an empty message is a malformed one,
                    // which the link drops and counts.
                    let bytes = m.get(0).map(|b| b.to_vec()).unwrap_or_default();
                    let Ok(slot) = in_tx.clone().reserve_owned().await else {
                        return;
                    };
                    // Taken in at the run's next idle point.
                    take_in(
                        clock,
                        &reader_cfg,
                        &reader_name,
                        slot,
                        LinkInput::Bytes(bytes),
                    )
                    .await;
                }
                Err(e) => {
                    tracing::warn!("ZMQ hub: receive failed: {e}");
                    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                }
            }
        }
    };
    // One frame in hand at most: the link's own output queue (`output_frames`, dropping and
    // counting) is the bound, as it was with the socket itself.
    let (frames_tx, frames_rx) = tokio::sync::mpsc::channel(1);
    let mut publisher = AbortOnDrop(tokio::spawn(publish(
        publ,
        frames_rx,
        segs.clone(),
        cfg.clone(),
        name.clone(),
        clock,
    )));
    let mut out = Publisher(frames_tx);
    let k = Connection::whole_run(&name, &segs, &cfg, &stats, clock, opened);
    let _reader = AbortOnDrop(tokio::spawn(reader));
    let why = serve_link(in_rx, &mut out, k).await;
    // What was handed to the publisher goes out before the hub closes.
    drop(out);
    let _ = tokio::time::timeout(std::time::Duration::from_secs(1), &mut publisher.0).await;
    tracing::info!("{name}: hub closed: {why}");
    bump(&stats, |s| s.disconnects += 1);
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A second hub on the same host and ports is refused with a message naming the
    /// endpoint, not a panic.
    #[tokio::test]
    async fn a_taken_port_is_a_clear_error() {
        let addr: HubAddr = "127.0.0.68:6468:7468".parse().unwrap();
        let first = Hub::bind(addr).await.unwrap();
        assert_eq!(first.addr(), addr);
        let e = Hub::bind(addr).await.unwrap_err().to_string();
        assert!(
            e.contains("cannot bind the ZMQ hub on tcp://127.0.0.68:6468"),
            "{e}"
        );
    }

    #[test]
    fn hub_addresses_parse_and_print() {
        let a: HubAddr = "127.0.0.2".parse().unwrap();
        assert_eq!(a, HubAddr::new("127.0.0.2".parse().unwrap()));
        assert_eq!(a.to_string(), "127.0.0.2");
        let b: HubAddr = "127.0.0.3:6100:7100".parse().unwrap();
        assert_eq!((b.publish_port, b.subscribe_port), (6100, 7100));
        assert_eq!(b.to_string(), "127.0.0.3:6100:7100");
        let c: HubAddr = "[::1]:6000:7001".parse().unwrap();
        assert_eq!(c.endpoint(6000), "tcp://[::1]:6000");
        for bad in ["localhost", "127.0.0.2:6000", ""] {
            assert_eq!(
                bad.parse::<HubAddr>(),
                Err(HubAddrError::Syntax(bad.to_owned())),
                "{bad}"
            );
        }
        assert_eq!(
            "127.0.0.2:0:7000".parse::<HubAddr>(),
            Err(HubAddrError::Ports("127.0.0.2:0:7000".to_owned()))
        );
        let e = "1.2.3.4:5:5".parse::<HubAddr>().unwrap_err();
        assert_eq!(e, HubAddrError::Ports("1.2.3.4:5:5".to_owned()));
        assert_eq!(
            e.to_string(),
            "`1.2.3.4:5:5` is not a hub address: expected HOST (an IP address, as given to \
             csp_zmqhub_init) or HOST:PUBLISH_PORT:SUBSCRIBE_PORT: two different, non-zero ports"
        );
    }
}
