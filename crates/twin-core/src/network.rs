//! The M6P network of INTERPRETATION.md section 1: which nodes exist, on which media, with
//! which routing tables.
//!
//! ```text
//!  ground segment (packet net)          main CAN bus                payload CAN bus
//!  GS 16 ... ── UHF air ─┬ COMM1 (1) ─┬ FC (3), EPS (4), ECU (5) ── PC (6) ── payloads 12-15
//!                        └ COMM2 (2) ─┘   (COMM2's radio on standby)
//! ```
//!
//! Routing (static for a run, ICD 1.7): main-bus nodes reach payloads through the PC (CFP
//! next hop 6) and the ground through the primary COMM (next hop 1); the PC reaches payloads
//! directly on the payload bus and everything else on the main bus; payloads reach
//! everything off their bus through the PC; each COMM sends ground traffic (16-20) over its
//! own UHF radio. Ids 7-11 are reserved: nobody answers there.
//!
//! The ground's uplink reaches the *active* radio (COMM1's at the start). When COMM2 takes
//! the link over (runtime's `RadioLink`), the tables stay as they are: COMM2 also answers
//! to link address 1 on the main bus, so what the nodes route via COMM1 reaches COMM2, and
//! the ground's uplink reaches COMM2's radio.

use csp::node::{IfaceConfig, NodeConfig};
use csp::router::{Route, RoutingTable};
use csp::service::UptimeFormat;

pub use platform::addr::{COMM1, COMM2, ECU, EPS, FC, GROUND, PAYLOADS, PC, RESERVED};

/// What a node is, which decides its media and routes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    /// Primary COMM: main CAN bus and the UHF radio.
    CommPrimary,
    /// Secondary COMM: main CAN bus and a UHF radio on standby.
    CommSecondary,
    /// Flight computer.
    Fc,
    /// Power system.
    Eps,
    /// Propulsion.
    Ecu,
    /// Payload controller: both CAN buses.
    Pc,
    /// A simulated payload on the payload bus.
    Payload,
    /// A ground station on the ground segment.
    Ground,
}

/// One node of the network.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeSpec {
    /// Display name.
    pub name: String,
    /// CSP address.
    pub addr: u8,
    /// Role.
    pub role: Role,
    /// Uptime service format.
    pub uptime: UptimeFormat,
}

/// The whole network.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NetworkSpec {
    /// Nodes in start order.
    pub nodes: Vec<NodeSpec>,
    /// Main bus bit rate, bit/s.
    pub main_bitrate_bps: u32,
    /// Payload bus bit rate, bit/s.
    pub payload_bitrate_bps: u32,
    /// UHF air data rate, bit/s.
    pub uhf_rate_bps: u32,
    /// Depth of each CAN controller's transmit queue, frames.
    pub can_tx_queue_frames: usize,
    /// Each sender's transmit buffer on the UHF air, bytes.
    pub uhf_tx_buffer_bytes: u32,
}

impl NetworkSpec {
    /// The M6P network with simulated payloads at `payloads` and ground stations at `ground`.
    pub fn m6p(payloads: &[u8], ground: &[u8]) -> Self {
        let node = |name: &str, addr, role| NodeSpec {
            name: name.to_owned(),
            addr,
            role,
            uptime: UptimeFormat::default(),
        };
        let mut nodes = vec![
            node("COMM1", COMM1, Role::CommPrimary),
            node("COMM2", COMM2, Role::CommSecondary),
            node("FC", FC, Role::Fc),
            node("EPS", EPS, Role::Eps),
            node("ECU", ECU, Role::Ecu),
            node("PC", PC, Role::Pc),
        ];
        nodes.extend(
            payloads
                .iter()
                .map(|&a| node(&format!("PL{a}"), a, Role::Payload)),
        );
        nodes.extend(
            ground
                .iter()
                .map(|&a| node(&format!("GS{a}"), a, Role::Ground)),
        );
        NetworkSpec {
            nodes,
            main_bitrate_bps: 1_000_000,
            payload_bitrate_bps: 1_000_000,
            uhf_rate_bps: 9600,
            can_tx_queue_frames: bus::can::TX_QUEUE_FRAMES,
            uhf_tx_buffer_bytes: bus::net::AIR_BUFFER_BYTES,
        }
    }

    /// The default network: payloads 12 and 13, main ground station 16.
    pub fn default_m6p() -> Self {
        Self::m6p(&[12, 13], &[16])
    }
}

/// Which medium an interface is attached to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Medium {
    /// The main CAN bus.
    MainCan,
    /// The payload CAN bus.
    PayloadCan,
    /// The ground segment, as the satellite's active radio (behind the air channel; the
    /// ground's default endpoint).
    GroundRadio,
    /// The ground segment, as a satellite radio on standby (behind the air channel; sends,
    /// but the ground's uplink goes to the active radio).
    GroundRadioStandby,
    /// The ground segment, as a ground station.
    Ground,
}

/// The interfaces (with their media) and the routing table of a node.
pub fn node_config(spec: &NodeSpec) -> (NodeConfig, Vec<Medium>) {
    let mut cfg = NodeConfig::new(&spec.name, spec.addr);
    cfg.service.uptime = spec.uptime;
    let mut rt = RoutingTable::new();
    let media = match spec.role {
        Role::CommPrimary | Role::CommSecondary => {
            cfg.ifaces = vec![IfaceConfig::can("main-can"), IfaceConfig::packet("uhf")];
            rt.set_default(Route::direct(0))
                .set_range(PAYLOADS, Route::via(0, PC))
                .set_range(GROUND, Route::direct(1));
            let radio = if spec.role == Role::CommPrimary {
                Medium::GroundRadio
            } else {
                Medium::GroundRadioStandby
            };
            vec![Medium::MainCan, radio]
        }
        Role::Fc | Role::Eps | Role::Ecu => {
            cfg.ifaces = vec![IfaceConfig::can("main-can")];
            rt.set_default(Route::direct(0))
                .set_range(PAYLOADS, Route::via(0, PC))
                .set_range(GROUND, Route::via(0, COMM1));
            vec![Medium::MainCan]
        }
        Role::Pc => {
            cfg.ifaces = vec![
                IfaceConfig::can("main-can"),
                IfaceConfig::can("payload-can"),
            ];
            rt.set_default(Route::direct(0))
                .set_range(PAYLOADS, Route::direct(1))
                .set_range(GROUND, Route::via(0, COMM1));
            vec![Medium::MainCan, Medium::PayloadCan]
        }
        Role::Payload => {
            cfg.ifaces = vec![IfaceConfig::can("payload-can")];
            rt.set_default(Route::via(0, PC))
                .set_range(PAYLOADS, Route::direct(0));
            vec![Medium::PayloadCan]
        }
        Role::Ground => {
            cfg.ifaces = vec![IfaceConfig::packet("ground")];
            rt.set_default(Route::direct(0));
            vec![Medium::Ground]
        }
    };
    cfg.routes = rt;
    (cfg, media)
}

/// A node named by name (`FC`, `PL12`, `GS16`) or by CSP address.
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum NodeRef {
    /// A CSP address, 0..=30.
    Addr(u8),
    /// A node name from the network table.
    Name(String),
}

impl std::fmt::Display for NodeRef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NodeRef::Addr(a) => write!(f, "{a}"),
            NodeRef::Name(n) => f.write_str(n),
        }
    }
}

/// Why a [`NodeRef`] names no node of the network.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum NodeRefError {
    /// No node at the address.
    #[error("no node has address {addr}")]
    NoAddress {
        /// The address.
        addr: u8,
    },
    /// No node of the name (any case).
    #[error("unknown node `{name}` (nodes: {})", .known.join(", "))]
    UnknownName {
        /// The name.
        name: String,
        /// The network's nodes.
        known: Vec<String>,
    },
}

impl NetworkSpec {
    /// The address of a node reference, or an error naming the known nodes.
    pub fn resolve(&self, r: &NodeRef) -> Result<u8, NodeRefError> {
        match r {
            NodeRef::Addr(a) => self
                .nodes
                .iter()
                .find(|n| n.addr == *a)
                .map(|n| n.addr)
                .ok_or(NodeRefError::NoAddress { addr: *a }),
            NodeRef::Name(name) => self
                .nodes
                .iter()
                .find(|n| n.name.eq_ignore_ascii_case(name))
                .map(|n| n.addr)
                .ok_or_else(|| NodeRefError::UnknownName {
                    name: name.clone(),
                    known: self.nodes.iter().map(|n| n.name.clone()).collect(),
                }),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn default_network_has_every_node_of_the_table() {
        let net = NetworkSpec::default_m6p();
        let addrs: Vec<u8> = net.nodes.iter().map(|n| n.addr).collect();
        assert_eq!(addrs, vec![1, 2, 3, 4, 5, 6, 12, 13, 16]);
        assert!(addrs.iter().all(|a| !RESERVED.contains(a)));
    }

    #[test]
    fn a_node_reference_resolves_or_names_the_nodes() {
        let net = NetworkSpec::default_m6p();
        assert_eq!(net.resolve(&NodeRef::Name("fc".into())), Ok(FC));
        assert_eq!(net.resolve(&NodeRef::Addr(12)), Ok(12));
        let e = net.resolve(&NodeRef::Addr(9)).unwrap_err();
        assert_eq!(e, NodeRefError::NoAddress { addr: 9 });
        assert_eq!(e.to_string(), "no node has address 9");
        let e = net.resolve(&NodeRef::Name("sat".into())).unwrap_err();
        assert!(
            matches!(&e, NodeRefError::UnknownName { name, known } if name == "sat" && known.len() == 9),
            "{e:?}"
        );
        assert!(
            e.to_string()
                .starts_with("unknown node `sat` (nodes: COMM1, COMM2, FC, "),
            "{e}"
        );
    }

    #[test]
    fn routes_follow_the_icd_topology() {
        let net = NetworkSpec::default_m6p();
        let route = |name: &str, dst: u8| {
            let spec = net.nodes.iter().find(|n| n.name == name).cloned();
            spec.map(|s| node_config(&s).0.routes.lookup(dst))
        };
        assert_eq!(route("FC", 12), Some(Some(Route::via(0, PC))));
        assert_eq!(route("FC", 16), Some(Some(Route::via(0, COMM1))));
        assert_eq!(route("COMM1", 16), Some(Some(Route::direct(1))));
        assert_eq!(route("COMM2", 16), Some(Some(Route::direct(1))));
        assert_eq!(route("COMM2", 3), Some(Some(Route::direct(0))));
        assert_eq!(route("PC", 13), Some(Some(Route::direct(1))));
        assert_eq!(route("PL12", 3), Some(Some(Route::via(0, PC))));
        assert_eq!(route("GS16", 3), Some(Some(Route::direct(0))));
    }
}
