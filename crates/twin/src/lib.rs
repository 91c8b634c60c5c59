//! m6p-twin: a digital twin of the NanoAvionics M6P smallsat network.
//!
//! - [`network`]: the nodes, media and routing tables of the M6P network.
//! - [`runtime`]: build the network, run it in virtual or real time, count.
//! - [`report`]: the run's report and the observers that gather it.
//! - [`scenario`], [`validate`], [`plan`]: read a scenario, check it, compile it.
//! - [`ground`]: the twin's own ground stations.
//! - [`gs`]: the outside ground-station client (`m6p-twin gs`).
//! - [`record`] and [`recording`]: write a run to MCAP; read, summarize and compare recordings.
//! - [`campaign`]: campaign files: a scenario run many times with drawn values.
//! - `live` (cargo feature `live`): serve a run over the Foxglove WebSocket protocol.

// The vocabulary below the twin's layers (its own crate: docs/architecture.md).
pub use twin_core::{
    duration, events, icd, icd_lengths, network, packets, seed, snapshot_file, tagged, timefmt,
    transit,
};
// The layers it is built on, by the names the twin's users know (docs/architecture.md).
pub use twin_domains::{
    adcs, can, clock, comm, commands, counters, eps, expectation_kinds, expectations, faults,
    fields, invariants, outside, params, plan, rules, sessions, validate,
};
#[cfg(feature = "live")]
pub use twin_record::live;
pub use twin_record::{mcap_file, protobuf, record, recording, sizes};
/// The run's report and the observers that gather it (m6p-twin-report).
pub use twin_report as report;
pub use twin_report::observe;
/// The runtime: build the network, run it, count (m6p-twin-runtime).
pub use twin_runtime as runtime;
pub use twin_runtime::ground;

pub mod bench;
pub mod campaign;
pub mod campaign_fork;
pub mod campaign_report;
pub mod campaign_rows;
pub mod campaign_run;
pub mod campaign_shrink;
pub mod exec;
pub mod gs;
pub mod gs_shell;
#[cfg(feature = "live")]
pub mod live_control;
pub mod snapshots;

/// The scenario: its data (m6p-twin-scenario), read and checked with every slice's check
/// ([`validate::parse`]), and its JSON schema.
pub mod scenario {
    pub use crate::validate::{parse, schema};
    pub use twin_scenario::scenario::*;
}

use std::time::Duration;

use csp::SimTime;

use crate::ground::{PlannedRequest, Recurring};
use crate::network::{NetworkSpec, Role};

/// The default run's ground activity: station 16 pings every space node once a minute,
/// from 5 s until `duration` (the last ping before it).
pub fn default_plan(net: &NetworkSpec, duration: Duration) -> Vec<Recurring> {
    let first = Duration::from_secs(5);
    let every = Duration::from_secs(60);
    let count = duration
        .saturating_sub(first)
        .as_nanos()
        .div_ceil(every.as_nanos());
    net.nodes
        .iter()
        .filter(|n| n.role != Role::Ground)
        .map(|n| Recurring {
            first: PlannedRequest {
                at: SimTime::ZERO + first,
                dst: n.addr,
                dport: csp::service::PORT_PING,
                data: ground::ping_payload(16),
                timeout: Duration::from_secs(5),
                label: format!("ping {}", n.name),
                after: None,
            },
            every,
            count: u32::try_from(count).unwrap_or(u32::MAX),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_plan_pings_each_space_node_every_minute_before_the_end() {
        let net = NetworkSpec::default_m6p();
        let space = net.nodes.iter().filter(|n| n.role != Role::Ground).count();
        for (duration_s, pings) in [(0, 0), (5, 0), (6, 1), (65, 1), (66, 2), (3600, 60)] {
            let plan = default_plan(&net, Duration::from_secs(duration_s));
            assert_eq!(plan.len(), space);
            for r in &plan {
                assert_eq!(r.count, pings, "{duration_s} s");
                assert_eq!(r.first.at, SimTime::from_secs(5));
                assert_eq!(r.every, Duration::from_secs(60));
                // The last one is before the end.
                if pings > 0 {
                    let last = r.first.at + r.every * (pings - 1);
                    assert!(last < SimTime::from_secs(duration_s));
                    assert!(last + r.every >= SimTime::from_secs(duration_s));
                }
            }
        }
    }
}
