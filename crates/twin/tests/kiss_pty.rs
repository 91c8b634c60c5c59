//! KISS on a pseudo-terminal (`--kiss-pty PATH`, `kind = "kiss-pty"`): a program opens the
//! path as libcsp's usart driver does, pings the FC, closes it, opens it again and pings
//! again; the path goes when the run ends. The libcsp 1.4 programs on the same link are in
//! `libcsp.rs`; this test needs nothing but the twin.
#![cfg(unix)]
#![allow(clippy::unwrap_used)]

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use bus::ClockMode;

#[path = "common/outside.rs"]
mod outside;
use csp::kiss::{Decoder, DecoderConfig, KissEvent};
use csp::{Header, Packet};
use m6p_twin::network::NetworkSpec;
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::{KissLink, KissMode, RunOptions, build_runtime};

/// Run the twin in real time for `secs` with a KISS pty for address 10 at `path`, and call
/// `client` on a thread while it runs.
fn with_twin(secs: u64, path: &Path, client: impl FnOnce() + Send + 'static) -> RunReport {
    with_twin_at(1.0, secs, path, client)
}

/// [`with_twin`] at `speed` simulated seconds per wall second, for `secs` simulated.
fn with_twin_at(
    speed: f64,
    secs: u64,
    path: &Path,
    client: impl FnOnce() + Send + 'static,
) -> RunReport {
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(secs));
    opts.clock = ClockMode::Realtime { speed };
    opts.kiss_links = vec![KissLink::new(KissMode::Pty(path.to_owned())).with_addrs(&[10])];
    let rt = build_runtime().unwrap();
    rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        rx.await.unwrap();
        let th = outside::on_thread(client);
        th.await.unwrap();
        twin.await.unwrap().unwrap()
    })
}

/// Open the pty, send a 32-byte ping 10 -> `node` and wait (up to 2 s) for its echo.
fn ping_over(path: &Path, node: u8, sport: u8) -> Duration {
    let mut tty = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .unwrap();
    let ping = Packet::new(
        Header::new(10, node, 1, sport),
        (0..32u8).collect::<Vec<u8>>(),
    );
    let mut frame = Vec::new();
    csp::kiss::encode(&ping, &mut frame);
    let start = Instant::now();
    tty.write_all(&frame).unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut dec = Decoder::new(DecoderConfig::default());
        let mut buf = [0u8; 512];
        let mut events = Vec::new();
        loop {
            let n = tty.read(&mut buf).unwrap_or(0);
            if n == 0 {
                return;
            }
            dec.push(&buf[..n], &mut events);
            for e in events.drain(..) {
                if let KissEvent::Packet(p) = e {
                    let _ = tx.send(p);
                    // Dropping the file here closes the pty: the connection's end.
                    return;
                }
            }
        }
    });
    let reply = rx.recv_timeout(Duration::from_secs(2)).expect("no reply");
    let rtt = start.elapsed();
    assert_eq!(reply.header, Header::new(node, 10, sport, 1));
    assert_eq!(reply.data, ping.data);
    rtt
}

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("m6p-twin-{}-{name}", std::process::id()))
}

#[test]
fn a_program_opens_the_pty_pings_closes_and_reopens_it() {
    let path = temp_path("tty-reopen");
    let p = path.clone();
    let report = with_twin(4, &path, move || {
        assert!(
            std::fs::read_link(&p)
                .unwrap()
                .to_string_lossy()
                .starts_with("/dev/pts/")
        );
        let first = ping_over(&p, 3, 40);
        // The program is gone: the connection ends, the address goes back; it comes again.
        std::thread::sleep(Duration::from_millis(100));
        let second = ping_over(&p, 6, 41);
        println!("round trips: FC {first:?}, PC {second:?}");
    });
    let (name, stats) = &report.kiss[0];
    assert!(name.starts_with("pty "), "{name}");
    assert_eq!(stats.connections, 2, "{stats:?}");
    assert_eq!(stats.disconnects, 2, "{stats:?}");
    assert_eq!((stats.packets_in, stats.packets_out), (2, 2), "{stats:?}");
    assert_eq!(stats.bad_crc + stats.garbage_bytes, 0, "{stats:?}");
    assert!(
        std::fs::symlink_metadata(&path).is_err(),
        "the link is removed at the end of the run"
    );
}

/// At four times real time an outside program is still answered: its pings cross in a
/// quarter of the wall time of their simulated exchange, and 8 s simulated pass in 2 s.
#[test]
fn a_sped_up_run_answers_an_outside_program() {
    let path = temp_path("tty-speed");
    let p = path.clone();
    let wall = Instant::now();
    let report = with_twin_at(4.0, 8, &path, move || {
        for (i, node) in [3u8, 6, 12].into_iter().enumerate() {
            let rtt = ping_over(&p, node, 42 + i as u8);
            println!("ping {node} at speed 4: {rtt:?}");
            std::thread::sleep(Duration::from_millis(50));
        }
    });
    let wall = wall.elapsed();
    assert_eq!(report.kiss[0].1.packets_out, 3, "{:?}", report.kiss[0].1);
    assert!(
        wall < Duration::from_secs(6),
        "8 s simulated at speed 4 took {wall:?} of wall clock"
    );
}

#[test]
fn a_file_at_the_path_is_never_replaced() {
    let path = temp_path("tty-taken");
    std::fs::write(&path, b"mine").unwrap();
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(1));
    opts.kiss_links = vec![KissLink::new(KissMode::Pty(path.clone()))];
    let rt = build_runtime().unwrap();
    let err = rt.block_on(run(opts, None)).unwrap_err();
    let text = format!("{err:#}");
    assert!(text.contains("exists and is not a symbolic link"), "{text}");
    assert_eq!(std::fs::read(&path).unwrap(), b"mine");
    std::fs::remove_file(&path).unwrap();
}
