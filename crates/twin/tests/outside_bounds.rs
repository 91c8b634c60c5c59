//! What a program outside the twin can and cannot do to it: floods of packets the twin must
//! refuse, on every kind of outside link, cost nothing that outlives them; a malformed
//! message does not end a link. The twin runs as the `m6p-twin` binary in real time (see
//! `common::twin_process`); a test that breaks the platform stops its attack as soon as it
//! sees the damage, so an older build fails it without eating the machine.
#![allow(clippy::unwrap_used)]

use std::io::Write;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use csp::Packet;

mod common;
use common::twin_process::{Client, Twin, bare, is_reply, ping};

/// Growth of the twin's memory an attack may cost, MiB.
const RSS_BUDGET_MIB: f64 = 20.0;
/// Packets of each flood.
const FLOOD_PACKETS: u64 = 1_000_000;

/// Watches the twin's memory during an attack: the most it grew, and whether over budget.
struct RssWatch {
    before_kib: u64,
    max_kib: u64,
}

impl RssWatch {
    fn new(twin: &Twin) -> Self {
        let before_kib = twin.rss_kib();
        RssWatch {
            before_kib,
            max_kib: before_kib,
        }
    }
    /// Look again; false when the growth is over budget (stop the attack).
    fn ok(&mut self, twin: &Twin) -> bool {
        self.max_kib = self.max_kib.max(twin.rss_kib());
        self.grew_mib() < RSS_BUDGET_MIB
    }
    fn grew_mib(&self) -> f64 {
        self.max_kib.saturating_sub(self.before_kib) as f64 / 1024.0
    }
    /// The verdict on a flood of `sent` packets of `what`, whose honest ping right after
    /// took `answered`: the whole flood sent, the memory within budget, the ping answered
    /// within its second.
    fn judge(&mut self, twin: &Twin, what: &str, sent: u64, answered: Option<Duration>) {
        self.ok(twin);
        println!(
            "{sent} {what}: RSS {} -> max {} KiB (+{:.1} MiB); ping after: {answered:?}",
            self.before_kib,
            self.max_kib,
            self.grew_mib()
        );
        assert!(
            self.grew_mib() < RSS_BUDGET_MIB,
            "RSS grew by {:.1} MiB after {sent} {what}",
            self.grew_mib()
        );
        assert_eq!(sent, FLOOD_PACKETS, "the flood stopped early");
        assert!(
            answered.is_some(),
            "the ping after the flood was not answered within 1 s"
        );
    }
}

/// A million KISS frames of pings from 3 (the FC's address) to 4, from a connection that
/// claimed nothing, as fast as the socket takes them: every one is refused, the twin's
/// memory grows by less than 20 MiB, and an honest client's ping right after the flood is
/// answered within a second. Each refusal used to leave a disabled endpoint on the bus
/// (5 GB in seconds, and pings unanswered for 40 s after).
#[test]
fn a_million_impostor_packets_over_kiss_tcp_cost_nothing_that_outlives_them() {
    let scenario = bare("impostor-flood", 120);
    let twin = Twin::start(
        &[scenario.to_str().unwrap(), "--kiss-listen", "127.0.0.1:0"],
        1,
    );
    std::fs::remove_file(&scenario).ok();
    let addr = twin.addrs[0];
    let mut honest = Client::connect(addr);
    assert!(honest.ping(17, 3, 0, Duration::from_secs(3)).is_some());
    let mut rss = RssWatch::new(&twin);
    let mut burst = Vec::new();
    const BURST: u64 = 1000;
    for k in 0..BURST as u32 {
        csp::kiss::encode(&ping(3, 4, k), &mut burst);
    }
    let mut flood = TcpStream::connect(addr).unwrap();
    let (mut sent, mut last_look) = (0, Instant::now());
    while sent < FLOOD_PACKETS {
        flood.write_all(&burst).unwrap();
        sent += BURST;
        if last_look.elapsed() > Duration::from_millis(50) {
            last_look = Instant::now();
            if !rss.ok(&twin) {
                break;
            }
        }
    }
    flood.flush().unwrap();
    let answered = honest.ping(17, 3, 1, Duration::from_secs(1));
    rss.judge(&twin, "impostor packets over KISS/TCP", sent, answered);
    drop(flood);
    let (_, _, err) = twin.finish_now();
    assert!(
        err.contains("address 3 is held by FC"),
        "the refusal is logged: {err}"
    );
}

/// A program on the twin's ZMQ hub: a PUB socket where the twin subscribes and a SUB
/// socket subscribed to its own address, as libcsp's `csp_zmqhub_init` makes them.
struct HubClient {
    rt: tokio::runtime::Runtime,
    publ: zeromq::PubSocket,
    sub: zeromq::SubSocket,
}

impl HubClient {
    /// Join the hub at `host` (ports `pub_port`, `sub_port`) as `addr`.
    fn join(host: &str, pub_port: u16, sub_port: u16, addr: u8) -> HubClient {
        use zeromq::Socket;
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        // The twin binds its hub once it has started (the zeromq crate's connect does not
        // wait for a listener): wait until both ports take a TCP connection.
        let end = Instant::now() + Duration::from_secs(20);
        for port in [pub_port, sub_port] {
            while TcpStream::connect((host, port)).is_err() {
                assert!(
                    Instant::now() < end,
                    "the hub never listened on {host}:{port}"
                );
                std::thread::sleep(Duration::from_millis(50));
            }
        }
        let (publ, sub) = rt.block_on(async {
            let mut publ = zeromq::PubSocket::new();
            publ.connect(&format!("tcp://{host}:{pub_port}"))
                .await
                .unwrap();
            let mut sub = zeromq::SubSocket::new();
            sub.connect(&format!("tcp://{host}:{sub_port}"))
                .await
                .unwrap();
            let topic = String::from_utf8(vec![addr]).unwrap();
            sub.subscribe(&topic).await.unwrap();
            (publ, sub)
        });
        HubClient { rt, publ, sub }
    }

    /// Publish one raw message.
    fn send_raw(&mut self, msg: Vec<u8>) {
        use zeromq::SocketSend;
        self.rt
            .block_on(self.publ.send(zeromq::ZmqMessage::from(msg)))
            .unwrap();
    }

    /// Publish `p` (to its destination, as libcsp's hub interface does).
    fn send(&mut self, p: &Packet) {
        let mut msg = Vec::new();
        csp::zmqhub::encode(p, p.header.dst, &mut msg);
        self.send_raw(msg);
    }

    /// The first packet `want` accepts within `timeout`.
    fn wait(&mut self, timeout: Duration, want: impl Fn(&Packet) -> bool) -> Option<Packet> {
        use zeromq::SocketRecv;
        let end = Instant::now() + timeout;
        loop {
            let left = end.checked_duration_since(Instant::now())?;
            let m = self
                .rt
                .block_on(async { tokio::time::timeout(left, self.sub.recv()).await })
                .ok()?
                .ok()?;
            let bytes = m.get(0).map(|b| b.to_vec()).unwrap_or_default();
            if let Ok((_, p)) = csp::zmqhub::decode(&bytes)
                && want(&p)
            {
                return Some(p);
            }
        }
    }

    /// Ping `dst` from `src`; the round trip when answered within `timeout`.
    fn ping(&mut self, src: u8, dst: u8, tag: u32, timeout: Duration) -> Option<Duration> {
        let t0 = Instant::now();
        self.send(&ping(src, dst, tag));
        self.wait(timeout, |p| is_reply(p, dst, src, tag))
            .map(|_| t0.elapsed())
    }

    /// Ping until answered (the hub's subscriptions take a moment to reach the twin).
    fn first_ping(&mut self, src: u8, dst: u8) {
        let end = Instant::now() + Duration::from_secs(20);
        let mut tag = 9_000_000;
        while Instant::now() < end {
            if self
                .ping(src, dst, tag, Duration::from_millis(500))
                .is_some()
            {
                return;
            }
            tag += 1;
        }
        panic!("{src} never reached {dst} over the hub");
    }
}

/// The twin with a hub on `host:pub:sub`, running a bare scenario of `secs`.
fn twin_with_hub(name: &str, hub: &str, secs: u64) -> Twin {
    // Left for the twin to read (it is under the target directory): with no KISS server to
    // wait for, the twin may not have read it yet.
    let scenario = bare(name, secs);
    Twin::start(&[scenario.to_str().unwrap(), "--zmq-hub", hub], 0)
}

/// One empty message on the hub is dropped and counted: the hub stays open and a program
/// on it pings the FC as before. The link used to take the empty message for its close,
/// cutting every program on the hub off for the rest of the run.
#[test]
fn an_empty_hub_message_does_not_close_the_hub() {
    let twin = twin_with_hub("hub-empty", "127.0.0.91:6491:7491", 30);
    let mut client = HubClient::join("127.0.0.91", 6491, 7491, 17);
    client.first_ping(17, 3);
    client.send_raw(Vec::new());
    let answered = client.ping(17, 3, 1, Duration::from_secs(3));
    let (_, out, err) = twin.finish_now();
    assert!(
        answered.is_some(),
        "the FC did not answer after an empty message\n{out}{err}"
    );
}

/// A million hub messages of pings from 12 (PL12's address, a node of the twin) to 3: every
/// one refused, the twin's memory grows by less than 20 MiB, and a program on the hub is
/// answered by the FC within a second after the flood.
#[test]
fn a_million_impostor_packets_over_the_hub_cost_nothing_that_outlives_them() {
    let twin = twin_with_hub("hub-impostor", "127.0.0.92:6492:7492", 120);
    let mut honest = HubClient::join("127.0.0.92", 6492, 7492, 17);
    honest.first_ping(17, 3);
    // The flooder is a program on the hub at 18 (connected once answered), then sends as
    // 12.
    let mut flood = HubClient::join("127.0.0.92", 6492, 7492, 18);
    flood.first_ping(18, 3);
    let mut rss = RssWatch::new(&twin);
    let mut msg = Vec::new();
    csp::zmqhub::encode(&ping(12, 3, 7), 3, &mut msg);
    let (mut sent, mut last_look) = (0u64, Instant::now());
    while sent < FLOOD_PACKETS {
        flood.send_raw(msg.clone());
        sent += 1;
        if last_look.elapsed() > Duration::from_millis(50) {
            last_look = Instant::now();
            if !rss.ok(&twin) {
                break;
            }
        }
    }
    let answered = honest.ping(17, 3, 1, Duration::from_secs(1));
    rss.judge(&twin, "impostor hub messages", sent, answered);
    let (_, _, err) = twin.finish_now();
    assert!(err.contains("address 12 is held by PL12"), "{err}");
}
