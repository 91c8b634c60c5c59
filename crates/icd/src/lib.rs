//! The M6P ICD's wire types, one module per node: its ports, command ids, and the request
//! and reply layouts (`csp::wire_struct!` gives each its bytes and its description). Every
//! node crate serves its own module (re-exported there as `wire`), and a node that reads
//! another's telemetry (the FC reads the EPS's and the COMM's) uses this crate, never the
//! other node's: node crates do not import one another (tools/layers.toml).

pub mod comm;
pub mod ecu;
pub mod eps;
pub mod fc;
pub mod payload;
pub mod pc;
