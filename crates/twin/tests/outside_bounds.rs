//! What a program outside the twin can and cannot do to it: floods of packets the twin must
//! refuse, on every kind of outside link, cost nothing that outlives them; a malformed
//! message does not end a link. The twin runs as the `m6p-twin` binary in real time (see
//! `common::twin_process`); a test that breaks the platform stops its attack as soon as it
//! sees the damage, so an older build fails it without eating the machine.
#![allow(clippy::unwrap_used)]

use std::io::Write;
use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use csp::Packet;

mod common;
use common::twin_process::{Client, Twin, answer_pings, bare, is_reply, ping, write_scenario};

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
/// answered within a second. A disabled endpoint left per refusal would grow the twin by
/// gigabytes in seconds and leave pings unanswered long after.
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
/// on it pings the FC as before. Taken for the link's close, it would cut every program on
/// the hub off for the rest of the run.
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

/// A program that joins the hub listening on 12 while the twin runs PL12 (a forgotten
/// `--kiss-addr 12`) gets nothing: the twin warns at once, naming the flag that gives the
/// program PL12's place. A program on an address nobody holds (17) brings no warning.
#[test]
fn a_program_listening_on_a_nodes_address_is_warned_with_the_flag() {
    let twin = twin_with_hub("hub-listens", "127.0.0.93:6493:7493", 30);
    let mut ground = HubClient::join("127.0.0.93", 6493, 7493, 17);
    ground.first_ping(17, 3);
    let _payload = HubClient::join("127.0.0.93", 6493, 7493, 12);
    // The subscription travels while the program waits for its requests.
    std::thread::sleep(Duration::from_millis(500));
    let (_, out, err) = twin.finish_now();
    assert!(
        err.contains("a program listens on address 12, but address 12 is held by PL12")
            && err.contains("`--kiss-addr 12` after the link's flag"),
        "{out}{err}"
    );
    assert!(!err.contains("listens on address 17"), "{err}");
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

/// A request from `src` to `dst`:`dport` from an ephemeral port; the reply within 3 s.
fn ask(c: &mut Client, src: u8, dst: u8, dport: u8, data: &[u8], sport: u8) -> Option<Packet> {
    c.send(&Packet::new(
        csp::Header::new(src, dst, dport, sport),
        data.to_vec(),
    ));
    c.wait(Duration::from_secs(3), |p| {
        p.header.src == dst && p.header.dport == sport && p.header.sport == dport
    })
}

/// The CSP uptime (libcsp's u32 big-endian seconds) of `dst`, asked by ground client 17.
fn uptime_s(gs: &mut Client, dst: u8, sport: u8) -> u32 {
    let p = ask(gs, 17, dst, 6, &[], sport).expect("uptime answered");
    u32::from_be_bytes(p.data[..4].try_into().unwrap())
}

/// The CSP clock (CMP CLOCK read: tv_sec 0) of `dst`, seconds, asked by ground client 17.
fn clock_s(gs: &mut Client, dst: u8, sport: u8) -> u32 {
    let p = ask(gs, 17, dst, 0, &[0, 6, 0, 0, 0, 0, 0, 0, 0, 0], sport).expect("clock read");
    u32::from_be_bytes(p.data[2..6].try_into().unwrap())
}

/// ICD 4.1 gives a payload the service handler's ping and uptime of the platform and nothing
/// else: a program at 15 asking the FC and the PC to reboot and setting the PC's CMP clock
/// a day ahead changes nothing (the FC's uptime keeps counting, the PC's clock is unmoved,
/// payload 12's session runs to DONE), and its ping and uptime are answered. Served, they
/// would reboot the FC or the PC (and the PC's ACTIVE session with it) and move its clock.
#[test]
fn a_payload_cannot_reboot_the_platform_or_set_its_clock() {
    let scenario = write_scenario(
        "payload-services",
        r#"
name = "payload-services"
duration = "16s"

[network]
payloads = [12]

[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:0"
addrs = [15]

[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:0"

[[commands]]
name = "setup"
at = "1s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 1, timestamp = "now", duration_s = 8, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }

[[expectations]]
kind = "session"
session = 1
session_result = "done"
"#,
    );
    let twin = Twin::start(&[scenario.to_str().unwrap()], 2);
    let mut payload = Client::connect(twin.addrs[0]);
    let mut gs = Client::connect(twin.addrs[1]);
    std::thread::sleep(Duration::from_secs(3));
    let fc_up = uptime_s(&mut gs, 3, 40);
    let pc_clock = clock_s(&mut gs, 6, 41);
    let reboot = 0x8007_8007u32.to_be_bytes();
    let mut clock_set = vec![0, 6];
    clock_set.extend_from_slice(&(pc_clock + 86_400).to_be_bytes());
    clock_set.extend_from_slice(&[0; 4]);
    for (dst, dport, data) in [
        (3, 4, &reboot[..]),
        (6, 4, &reboot[..]),
        (6, 0, &clock_set[..]),
    ] {
        payload.send(&Packet::new(
            csp::Header::new(15, dst, dport, 50),
            data.to_vec(),
        ));
    }
    let late = payload.drain(Duration::from_secs(2));
    assert!(late.is_empty(), "answered: {late:?}");
    for dst in [3, 6] {
        assert!(
            payload.ping(15, dst, 7, Duration::from_secs(3)).is_some(),
            "the payload's ping to {dst}"
        );
        assert!(
            ask(&mut payload, 15, dst, 6, &[], 51).is_some(),
            "the payload's uptime of {dst}"
        );
    }
    let fc_up_after = uptime_s(&mut gs, 3, 42);
    let pc_clock_after = clock_s(&mut gs, 6, 43);
    let (ok, out, err) = twin.finish();
    std::fs::remove_file(scenario).ok();
    assert!(
        fc_up_after > fc_up,
        "the FC's uptime went from {fc_up} s to {fc_up_after} s"
    );
    assert!(
        pc_clock_after.abs_diff(pc_clock) < 60,
        "the PC's clock went from {pc_clock} to {pc_clock_after}"
    );
    assert!(ok, "the session did not run undisturbed:\n{out}{err}");
    assert!(
        err.contains("service port 4: node 15 refused") && err.contains("service port 0"),
        "{err}"
    );
}

/// An address a link is configured with is that link's, its program connected or not: a
/// client of another link (which learns its addresses) sending as 15 while the first link's
/// program is offline is refused, and that program, connecting later, gets 15 and what the
/// twin sends it. Were the learning link to take 15, the twin's traffic for 15 would go to
/// it and the real payload would be refused when it connected.
#[test]
fn a_configured_address_is_its_links_while_its_program_is_offline() {
    let scenario = write_scenario(
        "reserved",
        r#"
name = "reserved"
duration = "14s"

[network]
payloads = [12]

[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:0"
addrs = [15]

[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:0"
"#,
    );
    let twin = Twin::start(&[scenario.to_str().unwrap()], 2);
    let mut intruder = Client::connect(twin.addrs[1]);
    let taken = intruder.ping(15, 6, 1, Duration::from_secs(2));
    // The payload's program connects now, and answers pings to 15.
    let stop = Arc::new(AtomicBool::new(false));
    let payload = answer_pings(twin.addrs[0], 15, stop.clone());
    std::thread::sleep(Duration::from_millis(300));
    let mut gs = Client::connect(twin.addrs[1]);
    let reached = gs.ping(17, 15, 2, Duration::from_secs(3));
    stop.store(true, Ordering::Relaxed);
    let answered = payload.join().unwrap();
    let (_, _, err) = twin.finish_now();
    std::fs::remove_file(scenario).ok();
    assert!(
        taken.is_none(),
        "a client of another link took 15 and was answered"
    );
    assert!(
        reached.is_some() && answered >= 1,
        "the payload's program at 15 was not reached ({answered} pings answered)\n{err}"
    );
    assert!(err.contains("configured there"), "{err}");
}

/// Sixteen connections that say nothing fill a listener (its limit); `m6p-twin gs ping 3`
/// still gets through: the longest-idle connection is closed to make room, and logged, so
/// that idle connections cannot lock everyone out.
#[test]
fn sixteen_idle_connections_do_not_lock_out_a_console() {
    let scenario = bare("idle-sixteen", 30);
    let twin = Twin::start(
        &[scenario.to_str().unwrap(), "--kiss-listen", "127.0.0.1:0"],
        1,
    );
    let idle: Vec<TcpStream> = (0..16)
        .map(|_| TcpStream::connect(twin.addrs[0]).unwrap())
        .collect();
    std::thread::sleep(Duration::from_millis(500));
    let out = std::process::Command::new(common::twin_process::twin_bin())
        .args(["gs", "--connect", &twin.addrs[0].to_string(), "ping", "3"])
        .output()
        .unwrap();
    let (_, _, err) = twin.finish_now();
    drop(idle);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && stdout.contains("reply from 3"),
        "gs ping 3: {stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(err.contains("closed to make room for"), "{err}");
}

/// A connection that holds no address and moves no byte for the idle limit (1 s here) is
/// closed; one that holds an address (it sent a ping) stays however quiet, and is answered
/// after the limit.
#[test]
fn a_connection_that_says_nothing_is_closed_after_the_idle_limit() {
    let scenario = bare("idle-limit", 30);
    let twin = Twin::start(
        &[
            scenario.to_str().unwrap(),
            "--kiss-listen",
            "127.0.0.1:0",
            "--kiss-idle-timeout",
            "1s",
        ],
        1,
    );
    let mut named = Client::connect(twin.addrs[0]);
    assert!(named.ping(17, 3, 1, Duration::from_secs(3)).is_some());
    let mut silent = TcpStream::connect(twin.addrs[0]).unwrap();
    silent
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let t0 = Instant::now();
    let mut buf = [0u8; 16];
    let closed = matches!(std::io::Read::read(&mut silent, &mut buf), Ok(0) | Err(_));
    let after = t0.elapsed();
    std::thread::sleep(Duration::from_millis(1500));
    let still = named.ping(17, 3, 2, Duration::from_secs(3));
    let (_, _, err) = twin.finish_now();
    println!("the silent connection closed {closed} after {after:?}");
    assert!(
        closed && after >= Duration::from_millis(900) && after < Duration::from_secs(4),
        "the silent connection: closed {closed} after {after:?}"
    );
    assert!(still.is_some(), "the named connection was closed\n{err}");
    assert!(err.contains("closed: no address and no byte for"), "{err}");
}

/// A connection holding an address (a payload waiting quietly for its session) is never
/// closed to make room, however long it has been idle: connections that hold nothing are,
/// and when every connection holds an address a new one is refused. Were it closed, a
/// newcomer could take its address.
#[test]
fn a_connection_holding_an_address_is_never_closed_to_make_room() {
    let scenario = bare("idle-named", 30);
    let twin = Twin::start(
        &[
            scenario.to_str().unwrap(),
            "--kiss-listen",
            "127.0.0.1:0",
            "--kiss-max-connections",
            "4",
        ],
        1,
    );
    let addr = twin.addrs[0];
    let mut named = Client::connect(addr);
    assert!(named.ping(17, 3, 1, Duration::from_secs(3)).is_some());
    std::thread::sleep(Duration::from_millis(300));
    // Twelve newcomers through a listener of four: each closes an older one that holds
    // nothing, never the named one (the longest idle of all).
    let newcomers: Vec<TcpStream> = (0..12)
        .map(|_| {
            let s = TcpStream::connect(addr).unwrap();
            std::thread::sleep(Duration::from_millis(50));
            s
        })
        .collect();
    let answered = named.ping(17, 3, 2, Duration::from_secs(3));
    // Three more named ones fill the listener: a fifth connection is refused.
    let mut others: Vec<Client> = (0..3).map(|_| Client::connect(addr)).collect();
    for (k, c) in others.iter_mut().enumerate() {
        let a = 18 + k as u8;
        assert!(c.ping(a, 3, 3, Duration::from_secs(3)).is_some(), "{a}");
    }
    let mut refused = Client::connect(addr);
    let fifth = refused.ping(20, 3, 4, Duration::from_secs(2));
    let (_, _, err) = twin.finish_now();
    drop(newcomers);
    assert!(answered.is_some(), "the named connection was closed\n{err}");
    assert!(fifth.is_none(), "a fifth connection was served");
    assert!(
        err.contains("closed to make room") && err.contains("each holding an address"),
        "{err}"
    );
}
