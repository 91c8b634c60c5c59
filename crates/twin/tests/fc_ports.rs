//! The FC's ICD ports on a running twin, decoded by an independent Python decoder written
//! from the ICD tables (`tests/fc_icd_decode.py`), over a real KISS/TCP socket as ground
//! node 16. The orbit and epoch come from `scenarios/default.toml` through the scenario
//! compiler, so this also checks that the scenario's TLE reaches the FC. Real time.
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
fn python_icd_decoder_reads_fc_telemetry_rtc_and_attitude_ports() {
    let file = repo_root().join("scenarios/default.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let scenario = Scenario::parse("scenarios/default.toml", &text).unwrap();
    let compiled = compile(&scenario).opts;
    assert_eq!(compiled.epoch_unix_s, 1_777_572_000, "2026-04-30T18:00:00Z");
    let tle = compiled
        .tle
        .clone()
        .expect("the default scenario has a TLE");
    assert!(tle.0.starts_with("1 99903") && tle.1.starts_with("2 99903"));

    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(8));
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.kiss_listen = vec!["127.0.0.1:0".parse().unwrap()];
    opts.epoch_unix_s = compiled.epoch_unix_s;
    opts.tle = Some(tle);
    let start = opts.epoch_unix_s.to_string();
    let rt = build_runtime(opts.clock).unwrap();
    let report = rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(run(opts, Some(tx)));
        let addr = rx.await.unwrap()[0];
        let client = tokio::task::spawn_blocking(move || {
            Command::new("python3")
                .arg(repo_root().join("tests/fc_icd_decode.py"))
                .args(["--connect", &addr.to_string(), "--as", "16"])
                .args(["--start", &start])
                .output()
                .expect("python3 is needed for this test")
        });
        let out = client.await.unwrap();
        (out, twin.await.unwrap().unwrap())
    });
    let (out, report) = report;
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{text}");
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("FAIL"), "{text}");
    assert!(text.matches("PASS").count() >= 20, "{text}");
    let fc = report.nodes.iter().find(|n| n.name == "FC").unwrap();
    assert_eq!(fc.counters.total_drops(), 0, "{:?}", fc.counters);
}
