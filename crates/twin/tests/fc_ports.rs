//! The FC's ICD ports on a running twin, decoded by an independent Python decoder written
//! from the ICD tables (`tests/fc_icd_decode.py`), over a real KISS/TCP socket as ground
//! node 16. The orbit and epoch come from `scenarios/default.toml` through the scenario
//! compiler, so this also checks that the scenario's TLE reaches the FC. Real time.
#![allow(clippy::unwrap_used)]

#[path = "common/decoder.rs"]
mod decoder;

#[test]
fn python_icd_decoder_reads_fc_telemetry_rtc_and_attitude_ports() {
    let opts = decoder::default_scenario_options(14);
    assert_eq!(opts.epoch_unix_s, 1_777_572_000, "2026-04-30T18:00:00Z");
    let tle = opts.tle.clone().expect("the default scenario has a TLE");
    assert!(tle.0.starts_with("1 99903") && tle.1.starts_with("2 99903"));
    let start = opts.epoch_unix_s.to_string();
    let (_, report) =
        decoder::run_decoder(opts, "fc_icd_decode.py", &["--start".into(), start], 27);
    let fc = report.nodes.iter().find(|n| n.name == "FC").unwrap();
    assert_eq!(fc.counters.total_drops(), 0, "{:?}", fc.counters);
}
