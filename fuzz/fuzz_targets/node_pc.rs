//! `node_pc`: the payload controller core (CSP 6: ICD 3.1 sessions, S-band).
//!
//! Built as the twin builds it: `csp::node::Host::new(cfg, app,
//! SimTime::ZERO)` with the twin's `NodeConfig` (`m6p_twin::network::node_config`) and
//! application, driven by a sequence of operations decoded from the input
//! (`m6p_twin_fuzz::harness::Op`, at most 64, within the node's simulated time budget):
//! packets with arbitrary headers (destination biased to the node's own address, ports to
//! its ICD ports 10-12 and the service ports 0-6, any flags, CRC32 right or wrong, up to
//! 256 data bytes) delivered whole (`handle_packet`) or as CFP frames (`handle_frame`,
//! intact, with a frame lost, repeated or swapped); raw CAN frames; well-formed ICD
//! requests (`m6p_twin_fuzz::nodes::Pc`); answers to what the node sent; time
//! passing with the timers run at `poll_timeout()`; reboots, power loss and return, hangs,
//! the radio switch and clock faults; writes of the other nodes to the run's boards.
//!
//! Asserts (besides "never panics"): transmissions go to an interface of their kind,
//! frames have 29-bit ids and at most 8 bytes, packets fit the MTU, the node's own CFP
//! frames reassemble without a drop, and timers make progress (no livelock at one instant).
#![no_main]

use libfuzzer_sys::fuzz_target;
use m6p_twin_fuzz::{harness, nodes};

fuzz_target!(|data: &[u8]| harness::run::<nodes::Pc>(data));
