//! The platform nodes' port 10 (EPS, ECU, COMM1, COMM2) on a running twin, decoded by an
//! independent Python decoder written from the tables in docs/protocol.md
//! (`tests/platform_icd_decode.py`), over a real KISS/TCP socket as ground node 16: exact
//! sizes, plausible values, state changes (channel switching, thresholds, ARM and SAFE,
//! beacon period) and the failure reply `cmd 00` for every malformed request. The orbit,
//! epoch, EPS and COMM configuration come from `scenarios/default.toml` through the
//! scenario compiler (the beacon's truth needs the FC's orbit). Real time, about 20 s.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use bus::ClockMode;
use m6p_twin::network::NetworkSpec;
use m6p_twin::plan::compile;
use m6p_twin::runtime::{RunOptions, build_runtime, run};
use m6p_twin::scenario::Scenario;

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[test]
fn python_decoder_reads_eps_ecu_and_comm_ports_and_gets_failure_replies() {
    let file = repo_root().join("scenarios/default.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let scenario = Scenario::parse("scenarios/default.toml", &text).unwrap();
    let compiled = compile(&scenario).opts;
    let tle = compiled
        .tle
        .clone()
        .expect("the default scenario has a TLE");

    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(20));
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.kiss_listen = vec!["127.0.0.1:0".parse().unwrap()];
    opts.epoch_unix_s = compiled.epoch_unix_s;
    opts.tle = Some(tle);
    opts.eps = compiled.eps.clone();
    opts.ecu = compiled.ecu.clone();
    opts.comm = compiled.comm.clone();
    let rt = build_runtime(opts.clock).unwrap();
    let (out, report) = rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        let addr = rx.await.unwrap()[0];
        let client = tokio::task::spawn_blocking(move || {
            Command::new("python3")
                .arg(repo_root().join("tests/platform_icd_decode.py"))
                .args(["--connect", &addr.to_string(), "--as", "16"])
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
    assert!(text.matches("PASS").count() >= 100, "{text}");
    for name in ["EPS", "ECU", "COMM1", "COMM2"] {
        let node = report.nodes.iter().find(|n| n.name == name).unwrap();
        assert_eq!(
            node.counters.total_drops(),
            0,
            "{name}: {:?}",
            node.counters
        );
    }
}
