//! The twin as a process, tried from outside: `m6p-twin run` in real time (its memory is
//! its own, measured from /proc) and a KISS/TCP client speaking CSP as an outside node.
//! `M6P_TWIN_BIN` runs another build instead (an older one, to see a test fail there).
#![allow(clippy::unwrap_used)]

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use csp::kiss::{Decoder, DecoderConfig, KissEvent};
use csp::{Header, Packet};

/// The twin binary as a command, logging warnings only.
pub fn twin() -> Command {
    let mut c = Command::new(twin_bin());
    c.env("RUST_LOG", "warn");
    c
}

/// A fresh folder `<test>-<pid>-<name>` in the target's temp dir.
pub fn test_dir(test: &str, name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("{test}-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).expect("creating a test folder");
    d
}

/// A finished command's stdout then stderr, as text.
pub fn output_text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

pub fn twin_bin() -> PathBuf {
    std::env::var_os("M6P_TWIN_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_m6p-twin")))
}

/// A running twin: the process, its KISS servers' addresses (in link order) and what it
/// printed.
pub struct Twin {
    pub child: Child,
    pub addrs: Vec<SocketAddr>,
    pub stderr: Arc<Mutex<String>>,
    pub stdout: Arc<Mutex<String>>,
}

impl Twin {
    /// `m6p-twin run` with `args`, waiting until `listeners` KISS servers (then the control
    /// channel, with `--control`) listen.
    pub fn start(args: &[&str], listeners: usize) -> Twin {
        let mut child = Command::new(twin_bin())
            .arg("run")
            .args(args)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = Arc::new(Mutex::new(String::new()));
        let stdout = Arc::new(Mutex::new(String::new()));
        let (tx, rx) = std::sync::mpsc::channel();
        {
            let err = BufReader::new(child.stderr.take().unwrap());
            let log = stderr.clone();
            std::thread::spawn(move || {
                for line in err.lines().map_while(Result::ok) {
                    // KISS servers, and the control channel (bound after them).
                    if let Some(rest) = line
                        .strip_prefix("KISS/TCP: listening on ")
                        .or_else(|| line.strip_prefix("control channel: on "))
                    {
                        let addr = rest.split_whitespace().next().unwrap_or_default();
                        let _ = tx.send(addr.parse::<SocketAddr>().unwrap());
                    }
                    log.lock().unwrap().push_str(&line);
                    log.lock().unwrap().push('\n');
                }
            });
        }
        {
            let mut out = child.stdout.take().unwrap();
            let log = stdout.clone();
            std::thread::spawn(move || {
                let mut s = String::new();
                let _ = out.read_to_string(&mut s);
                log.lock().unwrap().push_str(&s);
            });
        }
        let addrs = (0..listeners)
            .map(|_| rx.recv_timeout(Duration::from_secs(20)).unwrap())
            .collect();
        Twin {
            child,
            addrs,
            stderr,
            stdout,
        }
    }

    /// Resident memory now, KiB.
    pub fn rss_kib(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id()))
            .unwrap_or_default();
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.split_whitespace().next()?.parse().ok())
            .unwrap_or(0)
    }

    /// Wait for the run to end; (exit success, stdout, stderr).
    /// End the run now (SIGINT, as Ctrl-C) and collect it as [`Twin::finish`] does.
    pub fn finish_now(self) -> (bool, String, String) {
        let _ = Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status();
        self.finish()
    }

    pub fn finish(mut self) -> (bool, String, String) {
        let ok = self.child.wait().unwrap().success();
        std::thread::sleep(Duration::from_millis(200));
        let out = self.stdout.lock().unwrap().clone();
        let err = self.stderr.lock().unwrap().clone();
        (ok, out, err)
    }
}

impl Drop for Twin {
    fn drop(&mut self) {
        let _ = self.child.kill();
    }
}

/// A KISS client speaking CSP as an outside node.
pub struct Client {
    pub s: TcpStream,
    pub dec: Decoder,
    pub got: VecDeque<Packet>,
}

impl Client {
    pub fn connect(addr: SocketAddr) -> Client {
        let s = TcpStream::connect(addr).unwrap();
        s.set_nodelay(true).unwrap();
        Client {
            s,
            dec: Decoder::new(DecoderConfig::default()),
            got: VecDeque::new(),
        }
    }

    pub fn send(&mut self, p: &Packet) {
        let mut bytes = Vec::new();
        csp::kiss::encode(p, &mut bytes);
        self.s.write_all(&bytes).unwrap();
    }

    /// The first packet (read within `timeout`) that `want` accepts; the others read meanwhile
    /// are kept.
    pub fn wait(&mut self, timeout: Duration, want: impl Fn(&Packet) -> bool) -> Option<Packet> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(i) = self.got.iter().position(&want) {
                return self.got.remove(i);
            }
            let left = end.checked_duration_since(Instant::now())?;
            self.s
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))
                .unwrap();
            let mut buf = [0u8; 4096];
            match self.s.read(&mut buf) {
                Ok(0) => return None,
                Ok(n) => {
                    let mut ev = Vec::new();
                    self.dec.push(&buf[..n], &mut ev);
                    self.got.extend(ev.into_iter().filter_map(|e| match e {
                        KissEvent::Packet(p) => Some(p),
                        KissEvent::Dropped(_) => None,
                    }));
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(_) => return None,
            }
        }
    }

    /// Ping `dst` from `src` with a tag; the round trip when answered within `timeout`.
    pub fn ping(&mut self, src: u8, dst: u8, tag: u32, timeout: Duration) -> Option<Duration> {
        let t0 = Instant::now();
        self.send(&ping(src, dst, tag));
        self.wait(timeout, |p| is_reply(p, dst, src, tag))
            .map(|_| t0.elapsed())
    }

    /// Every packet read within `d`.
    pub fn drain(&mut self, d: Duration) -> Vec<Packet> {
        let _ = self.wait(d, |_| false);
        self.got.drain(..).collect()
    }
}

/// A program at `me` connected to `addr` that answers pings (and never sends first) until
/// `stop`: how many it answered.
pub fn answer_pings(
    addr: SocketAddr,
    me: u8,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<usize> {
    std::thread::spawn(move || {
        let mut c = Client::connect(addr);
        let mut answered = 0;
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            if let Some(p) = c.wait(Duration::from_millis(200), |p| p.header.dport == 1) {
                let mut h = p.header.reply(me);
                h.flags = 0;
                c.send(&Packet::new(h, p.data.clone()));
                answered += 1;
            }
        }
        answered
    })
}

pub fn ping(src: u8, dst: u8, tag: u32) -> Packet {
    Packet::new(Header::new(src, dst, 1, 40), tag.to_le_bytes().to_vec())
}

pub fn is_reply(p: &Packet, from: u8, to: u8, tag: u32) -> bool {
    p.header.src == from && p.header.dst == to && p.data == tag.to_le_bytes()
}

/// A scenario with the default network and nothing else for `secs` (the default scenario's
/// expectations need its full duration).
pub fn bare(name: &str, secs: u64) -> PathBuf {
    write_scenario(name, &bare_text(name, secs))
}

/// The text of [`bare`]'s scenario.
pub fn bare_text(name: &str, secs: u64) -> String {
    format!("name = \"{name}\"\nduration = \"{secs}s\"\n")
}

pub fn write_scenario(name: &str, text: &str) -> PathBuf {
    // Under the target directory (cargo clean takes it), not left behind in /tmp.
    let p = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("hostile-{}-{name}.toml", std::process::id()));
    std::fs::write(&p, text).unwrap();
    p
}
