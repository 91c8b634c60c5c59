//! Building and running the libcsp 1.4 programs of `tests/libcsp/` against a twin in real
//! time (`libcsp.rs`, and `socketcan_uml.rs` inside its guest).
// Each test binary uses a part of these.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Duration;

use bus::ClockMode;
use m6p_twin::plan::compile;
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::{RunOptions, build_runtime};

pub use crate::common::{expected_stream, readme_scenario, repo_root, same_bytes};

/// The built programs.
#[derive(Debug)]
pub struct Programs {
    /// `csp_client`.
    pub client: PathBuf,
    /// `csp_payload`.
    pub payload: PathBuf,
    /// `examples/libcsp_payload.c`, the example for users.
    pub example: PathBuf,
}

/// Build libcsp 1.4 and the programs once per test binary (about 3 s), in a directory of
/// its own under cargo's target tmpdir.
pub fn programs() -> &'static Programs {
    static BUILT: OnceLock<Programs> = OnceLock::new();
    BUILT.get_or_init(|| {
        let exe = std::env::current_exe().unwrap();
        let name = exe.file_stem().unwrap().to_string_lossy().into_owned();
        let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("libcsp-{name}"));
        let script = repo_root().join("tests/libcsp/build.sh");
        let res = Command::new("bash")
            .arg(&script)
            .arg(&out)
            .output()
            .expect("bash runs tests/libcsp/build.sh");
        assert!(
            res.status.success(),
            "building libcsp 1.4 and tests/libcsp failed (needs cc and libzmq3-dev):\n{}{}",
            String::from_utf8_lossy(&res.stdout),
            String::from_utf8_lossy(&res.stderr)
        );
        let bin = out.join("bin");
        Programs {
            client: bin.join("csp_client"),
            payload: bin.join("csp_payload"),
            example: bin.join("libcsp_payload"),
        }
    })
}

/// How a program joins the twin.
#[derive(Debug, Clone)]
pub enum Iface {
    /// KISS on a serial device (the twin's pty).
    Kiss(PathBuf),
    /// The ZMQ hub on this host.
    Zmq(String),
    /// A SocketCAN interface.
    Can(String),
}

impl Iface {
    fn args(&self) -> Vec<String> {
        match self {
            Iface::Kiss(p) => vec!["--kiss".into(), p.display().to_string()],
            Iface::Zmq(h) => vec!["--zmq".into(), h.clone()],
            Iface::Can(i) => vec!["--can".into(), i.clone()],
        }
    }
}

/// A unique path in the temp dir for this process.
pub fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("m6p-libcsp-{}-{name}", std::process::id()))
}

/// Run `csp_client` at `addr` on `iface` with `checks` (tokens) and `extra` options; its
/// success and its output (stdout, then stderr).
pub fn client(
    progs: &Programs,
    iface: &Iface,
    addr: u8,
    checks: &[String],
    extra: &[&str],
) -> (bool, String) {
    let out = Command::new(&progs.client)
        .args(iface.args())
        .args(["--addr", &addr.to_string()])
        .args(extra)
        .args(checks)
        .output()
        .expect("run csp_client");
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

/// The nodes of the default network: COMM 1 and 2, FC, EPS, ECU, PC, payloads 12 and 13,
/// ground station 16 (over the UHF link).
pub const NODES: [u8; 9] = [1, 2, 3, 4, 5, 6, 12, 13, 16];

/// Every node pinged with 1, 64 and 200 bytes, with and without CRC32; CMP ident, uptime,
/// ps, memfree and buf_free of the FC and the PC; a reserved address; the CMP clock of the
/// nodes on the buses and the FC's RTC. With `--all-icd-fc`, [`CLIENT_CHECKS`] checks.
pub const CLIENT_CHECKS: usize = 9 * 3 * 2 + 5 * 2 + 1 + 8 + 1 + 6;

/// Assert that `csp_client`'s output `text` ran [`CLIENT_CHECKS`] checks, all passed, and
/// that every CMP clock it read of a node of the twin is the simulated time of a run
/// starting at `epoch_unix_s` (within its first ten minutes), not the host's; `outside`
/// are libcsp programs (their clock is the host's, `clock_posix.c`).
pub fn assert_client_checks(ok: bool, text: &str, epoch_unix_s: u64, outside: &[u8]) {
    assert!(ok, "csp_client failed:\n{text}");
    let n = CLIENT_CHECKS;
    assert!(
        text.contains(&format!("summary checks={n} ok={n} fail=0")),
        "not every check ran and passed:\n{text}"
    );
    let secs: Vec<u64> = text
        .lines()
        .filter(|l| l.starts_with("ok clock "))
        .filter(|l| !outside.iter().any(|n| l.contains(&format!(" node={n} "))))
        .filter_map(|l| l.split_whitespace().find_map(|w| w.strip_prefix("sec=")))
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(secs.len(), 8 - outside.len(), "{text}");
    for s in secs {
        assert!(
            (epoch_unix_s..epoch_unix_s + 600).contains(&s),
            "a CMP clock read {s}, not the simulated time from {epoch_unix_s}:\n{text}"
        );
    }
}
pub fn client_checks() -> Vec<String> {
    let mut c = Vec::new();
    for node in NODES {
        for size in [1, 64, 200] {
            c.push(format!("ping {node} {size}"));
            c.push(format!("ping {node} {size} crc"));
        }
    }
    for node in [3, 6] {
        for s in ["ident", "uptime", "ps", "memfree", "buffree"] {
            c.push(format!("{s} {node}"));
        }
    }
    c.push("reserved 9".into());
    // The twin's time, simulated: CMP clock of every node on the buses, the FC's RTC
    // (RTCSTMGET, port 11: `02 01` + u32 seconds).
    for node in NODES.iter().filter(|&&n| n < 16) {
        c.push(format!("clock {node}"));
    }
    c.push("icd 3 11 02 6".into());
    c.iter()
        .flat_map(|s| s.split(' ').map(str::to_owned).collect::<Vec<_>>())
        .collect()
}

/// The default scenario (its orbit, network and platform) in real time until stopped.
pub fn default_options() -> RunOptions {
    let file = repo_root().join("scenarios/default.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let scenario = m6p_twin::scenario::parse("scenarios/default.toml", &text).unwrap();
    let mut opts = compile(&scenario).opts;
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.duration = None;
    opts.faults.clear();
    // The scenario's own ground station requests share the UHF air (half duplex, 9600
    // bit/s) with the client's checks of node 16: a 200-byte ping behind them took over the
    // client's 1 s timeout on a loaded CI machine (wall-clock timing decides whether they
    // meet). The checks are of libcsp's wire, not of the air's queueing: the air is theirs.
    opts.ground_plan.clear();
    opts
}

/// The scenario of `examples/README.md`: payload 12 outside, session 1 set up at 2 s, 25
/// POLLs of 200 bytes; 8 s of real time.
pub fn readme_options() -> RunOptions {
    let scenario = m6p_twin::scenario::parse("examples/README.md", &readme_scenario()).unwrap();
    let opts = compile(&scenario).opts;
    assert_eq!(opts.kiss_links.len(), 1);
    assert!(matches!(opts.clock, ClockMode::Realtime { .. }));
    opts
}

/// Run the twin with `opts` and `f` on a thread of its own once its links are open; the
/// report when the run has a duration (else it is stopped when `f` returns).
pub fn with_twin<T: Send + 'static>(
    opts: RunOptions,
    f: impl FnOnce() -> T + Send + 'static,
) -> (Option<RunReport>, T) {
    let bounded = opts.duration.is_some();
    let rt = build_runtime().unwrap();
    rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        rx.await.unwrap();
        // A thread of its own, not `spawn_blocking`: a blocking task of the runtime would
        // keep tokio's paused clock from advancing in a run's virtual part.
        let (done_tx, done_rx) = tokio::sync::oneshot::channel();
        std::thread::spawn(move || {
            let _ = done_tx.send(f());
        });
        let out = done_rx.await.unwrap();
        if bounded {
            (Some(twin.await.unwrap().unwrap()), out)
        } else {
            twin.abort();
            (None, out)
        }
    })
}

/// Run the README scenario `opts` with `csp_payload` as payload 12 (`api` `conn` or
/// `connless`), logging what it sent to `sent`, and with `also` a `csp_client` at 10 on
/// the same link running those checks 0.5 s into the session. The report, the payload's
/// output, the client's success and output.
pub fn run_payload_session(
    progs: &'static Programs,
    opts: RunOptions,
    iface: &Iface,
    api: &str,
    sent: &Path,
    also: Option<&[&str]>,
) -> (RunReport, String, Option<(bool, String)>) {
    let (iface, api, sent) = (iface.clone(), api.to_owned(), sent.to_owned());
    let also: Option<Vec<String>> = also.map(|c| c.iter().map(|s| (*s).to_owned()).collect());
    let (report, out) = with_twin(opts, move || {
        let client_iface = iface.clone();
        let client = also.map(|checks| {
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(2500));
                client(progs, &client_iface, 10, &checks, &[])
            })
        });
        let out = Command::new(&progs.payload)
            .args(iface.args())
            .args(["--addr", "12", "--api", &api, "--sent"])
            .arg(&sent)
            .args(["--idle", "1.5", "--seconds", "14"])
            .output()
            .expect("run csp_payload");
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (text, client.map(|c| c.join().unwrap()))
    });
    (report.expect("a bounded run"), out.0, out.1)
}
