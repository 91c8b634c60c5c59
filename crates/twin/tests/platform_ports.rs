//! The platform nodes' port 10 (EPS, ECU, COMM1, COMM2) on a running twin, decoded by an
//! independent Python decoder written from the tables in docs/protocol.md
//! (`tests/platform_icd_decode.py`), over a real KISS/TCP socket as ground node 16: exact
//! sizes, plausible values, state changes (channel switching, thresholds, ARM and SAFE,
//! beacon period) and the failure reply `cmd 00` for every malformed request. The orbit,
//! epoch, EPS and COMM configuration come from `scenarios/default.toml` through the
//! scenario compiler (the beacon's truth needs the FC's orbit). Real time, about 20 s.
#![allow(clippy::unwrap_used)]

#[path = "common/decoder.rs"]
mod decoder;

#[test]
fn python_decoder_reads_eps_ecu_and_comm_ports_and_gets_failure_replies() {
    let opts = decoder::default_scenario_options(20);
    assert!(opts.tle.is_some(), "the default scenario has a TLE");
    let (_, report) = decoder::run_decoder(opts, "platform_icd_decode.py", &[], 100);
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
