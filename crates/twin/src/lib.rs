//! m6p-twin: a digital twin of the NanoAvionics M6P smallsat network.
//!
//! - [`network`]: the nodes, media and routing tables of the M6P network.
//! - [`runtime`]: build the network, run it in virtual or real time, report.
//! - [`ground`]: the twin's own ground stations.
//! - [`gs`]: the outside ground-station client (`m6p-twin gs`).
//! - [`record`] and [`recording`]: write a run to MCAP; read, summarize and compare recordings.
//! - [`campaign`]: campaign files: a scenario run many times with drawn values.
//! - `live` (cargo feature `live`): serve a run over the Foxglove WebSocket protocol.

pub mod adcs;
pub mod bench;
pub mod campaign;
pub mod campaign_report;
pub mod campaign_run;
pub mod campaign_shrink;
pub mod can;
pub mod clock;
pub mod comm;
pub mod commands;
pub mod counters;
pub mod duration;
pub mod eps;
pub mod events;
pub mod exec;
pub mod expectations;
pub mod faults;
pub mod fields;
pub mod ground;
pub mod gs;
pub mod gs_shell;
pub mod icd;
pub mod icd_lengths;
pub mod invariants;
#[cfg(feature = "live")]
pub mod live;
pub mod mcap_file;
pub mod network;
pub mod outside;
pub mod packets;
pub mod params;
pub mod plan;
pub mod protobuf;
pub mod record;
pub mod recording;
pub mod rules;
pub mod runtime;
pub mod scenario;
pub mod sessions;
pub mod tagged;
pub mod timefmt;
pub mod transit;

use std::time::Duration;

use csp::SimTime;

use crate::ground::PlannedRequest;
use crate::network::{NetworkSpec, Role};

/// The default run's ground activity: station 16 pings every space node once a minute.
pub fn default_plan(net: &NetworkSpec, duration: Duration) -> Vec<PlannedRequest> {
    let mut plan = Vec::new();
    let mut t = Duration::from_secs(5);
    while t < duration {
        for n in net.nodes.iter().filter(|n| n.role != Role::Ground) {
            plan.push(PlannedRequest {
                at: SimTime::ZERO + t,
                dst: n.addr,
                dport: csp::service::PORT_PING,
                data: ground::ping_payload(16),
                timeout: Duration::from_secs(5),
                label: format!("ping {}", n.name),
                after: None,
            });
        }
        t += Duration::from_secs(60);
    }
    plan
}
