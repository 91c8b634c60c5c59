//! Running an independent Python decoder (`tests/*_icd_decode.py`) against a twin in real
//! time, as ground node 16 over a KISS/TCP socket, with the orbit and epoch (and the EPS,
//! ECU and COMM settings) of `scenarios/default.toml` through the scenario compiler.

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use bus::ClockMode;
use m6p_twin::network::NetworkSpec;
use m6p_twin::plan::compile;
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::{RunOptions, build_runtime};

#[path = "outside.rs"]
pub mod outside;

/// The repository root.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Real-time options for `seconds` with the default scenario's epoch, TLE and platform
/// settings, and a KISS/TCP server on a free local port.
pub fn default_scenario_options(seconds: u64) -> RunOptions {
    let file = repo_root().join("scenarios/default.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let scenario = m6p_twin::scenario::parse("scenarios/default.toml", &text).unwrap();
    let compiled = compile(&scenario).opts;
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(seconds));
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.kiss_links = vec![m6p_twin::runtime::KissLink::listen(
        "127.0.0.1:0".parse().unwrap(),
    )];
    opts.epoch_unix_s = compiled.epoch_unix_s;
    opts.tle = compiled.tle.clone();
    opts.eps = compiled.eps.clone();
    opts.ecu = compiled.ecu.clone();
    opts.comm = compiled.comm.clone();
    opts
}

/// Run the twin with `opts` and `tests/<script>` connected to its KISS server with
/// `--connect ADDR --as 17`, `--console ADDR` for each TCP console of `opts.uart`, and
/// `args`; the script's output (stdout then stderr), after
/// asserting it exited with success and printed no FAIL and at least `min_pass` PASS, and
/// the run's report.
pub fn run_decoder(
    opts: RunOptions,
    script: &str,
    args: &[String],
    min_pass: usize,
) -> (String, RunReport) {
    let script = repo_root().join("tests").join(script);
    let args = args.to_vec();
    let rt = build_runtime().unwrap();
    let (out, report) = rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        let bound = rx.await.unwrap();
        let addr = bound[0];
        // The TCP consoles (`opts.uart`) follow the KISS server.
        let consoles: Vec<String> = bound[1..]
            .iter()
            .flat_map(|c| ["--console".to_owned(), c.to_string()])
            .collect();
        let client = outside::on_thread(move || {
            Command::new("python3")
                .arg(script)
                .args(["--connect", &addr.to_string(), "--as", "17"])
                .args(consoles)
                .args(args)
                .output()
                .expect("python3 is needed for this test")
        });
        let out = client.await.unwrap();
        (out, twin.await.unwrap().unwrap())
    });
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{text}");
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("FAIL"), "{text}");
    assert!(text.matches("PASS").count() >= min_pass, "{text}");
    (text, report)
}

/// The CSP packets `from` sent on CAN bus `medium` ("main", "payload"), reassembled from the
/// run's trace (`opts.trace` on), each with the instant its last frame left the bus (when
/// its receiver took it).
#[allow(dead_code)]
pub fn packets_on(
    report: &RunReport,
    medium: &str,
    from: &str,
) -> Vec<(csp::SimTime, csp::Packet)> {
    use bus::trace::TraceFrame;
    use csp::cfp::{Reassembler, ReassemblerConfig};
    let mut cfp = Reassembler::new(ReassemblerConfig::default());
    let mut out = Vec::new();
    for ev in &report.trace {
        let TraceFrame::Can(frame) = &ev.frame else {
            continue;
        };
        if &*ev.medium == medium && &*ev.from == from && !ev.dropped {
            if let Some(Ok(p)) = cfp.handle(frame, ev.t) {
                out.push((ev.t, p));
            }
        }
    }
    out
}
