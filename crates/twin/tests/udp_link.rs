//! CSP over UDP (`--udp`, `kind = "udp"`; issue 43): one packet per datagram, the header in
//! network order, as YAMCS's CSP links send and read it. A ground program at 17 pings the
//! FC and asks it for TMGEN; the twin answers to the source of the latest datagram, or to
//! the peer the link names; a short datagram is counted, and a scenario's bad peer is a
//! located error.

#![allow(clippy::unwrap_used)]

use std::io::{BufRead, BufReader};
use std::net::{SocketAddr, UdpSocket};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use csp::{Header, Packet};

mod common;

/// `m6p-twin run ARGS` in real time, until it says where its UDP link is bound.
fn start(args: &[&str]) -> (Child, SocketAddr, std::thread::JoinHandle<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(["run", "--no-checks", "--duration", "30s"])
        .args(args)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let mut seen = String::new();
    let at = loop {
        let l = lines
            .next()
            .unwrap_or_else(|| panic!("the twin ended before binding: {seen}"))
            .unwrap();
        seen.push_str(&l);
        seen.push('\n');
        if let Some(rest) = l.strip_prefix("CSP/UDP: on ") {
            break rest.split([',', ' ']).next().unwrap().parse().unwrap();
        }
    };
    let mut out = child.stdout.take().unwrap();
    let rest = std::thread::spawn(move || {
        let mut s = seen;
        lines.map_while(Result::ok).for_each(|l| {
            s.push_str(&l);
            s.push('\n');
        });
        let mut o = String::new();
        let _ = std::io::Read::read_to_string(&mut out, &mut o);
        s + &o
    });
    (child, at, rest)
}

fn socket() -> UdpSocket {
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s
}

fn send(from: &UdpSocket, to: SocketAddr, p: &Packet) {
    let mut d = Vec::new();
    csp::udp::encode(p, &mut d);
    from.send_to(&d, to).unwrap();
}

fn receive(on: &UdpSocket) -> Packet {
    let mut buf = [0u8; 512];
    let (n, _) = on.recv_from(&mut buf).unwrap();
    csp::udp::decode(&buf[..n]).unwrap()
}

fn stop(mut child: Child, rest: std::thread::JoinHandle<String>) -> String {
    let _ = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status();
    let _ = child.wait();
    rest.join().unwrap()
}

#[test]
fn a_ground_program_over_udp_pings_the_fc_and_reads_tmgen() {
    let (child, twin, rest) = start(&["--udp", "127.0.0.1:0", "--kiss-addr", "17"]);
    let gs = socket();
    // A CSP ping to the FC's echo port, answered to where it came from.
    let ping = Packet::new(Header::new(17, 3, 1, 40), (1..=8).collect::<Vec<u8>>());
    send(&gs, twin, &ping);
    let echo = receive(&gs);
    assert_eq!(echo.header, ping.header.reply(3), "{echo:?}");
    assert_eq!(echo.data, ping.data);
    // FC TMGEN (telemetry port 10, command 1): the ICD's 16 bytes after command and result.
    send(&gs, twin, &Packet::new(Header::new(17, 3, 10, 41), vec![1]));
    let tm = receive(&gs);
    assert_eq!(
        (tm.header.src, tm.header.sport, tm.header.dport),
        (3, 10, 41)
    );
    assert_eq!(tm.data.len(), 2 + 16, "{tm:?}");
    assert_eq!(tm.data[..2], [1, 1]);
    // Shorter than a header: counted, nothing else. The ping after it is answered once the
    // link has read both (in order): the stop does not race the short datagram.
    gs.send_to(&[0xa2, 0x30], twin).unwrap();
    send(&gs, twin, &ping);
    assert_eq!(receive(&gs).data, ping.data);
    let said = stop(child, rest);
    assert!(said.contains("1 short"), "{said}");
}

#[test]
fn the_twin_sends_to_the_peer_its_link_names() {
    let peer = socket();
    let bind_and_peer = format!("127.0.0.1:0,{}", peer.local_addr().unwrap());
    let (child, twin, rest) = start(&["--udp", &bind_and_peer, "--kiss-addr", "17"]);
    let from = socket();
    from.set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let ping = Packet::new(Header::new(17, 3, 1, 42), vec![7; 16]);
    send(&from, twin, &ping);
    let echo = receive(&peer);
    assert_eq!(echo.header, ping.header.reply(3));
    let mut buf = [0u8; 64];
    assert!(
        from.recv_from(&mut buf).is_err(),
        "the reply went to the sender, not the peer"
    );
    let said = stop(child, rest);
    assert!(
        said.contains(&format!("sending to {}", peer.local_addr().unwrap())),
        "{said}"
    );
}

#[test]
fn a_scenarios_udp_link_is_checked() {
    let file = std::env::temp_dir().join(format!("m6p-udp-link-{}.toml", std::process::id()));
    std::fs::write(
        &file,
        "name = \"u\"\nduration = \"10s\"\n[[links]]\nkind = \"udp\"\naddr = \"127.0.0.1:10015\"\npeer = \"nowhere\"\naddrs = [17]\n",
    )
    .unwrap();
    let (code, out, err) = common::twin_cli(&["check", file.to_str().unwrap()]);
    let _ = std::fs::remove_file(&file);
    assert_ne!(code, 0, "{out}{err}");
    assert!(
        err.contains("field `links[0].peer`") && err.contains("`nowhere` is not an address"),
        "{out}{err}"
    );
}
