//! A scenario as plain data: the file's tables and every slice's settings as written
//! ([`scenario::Scenario`] and a module per table), read with located errors (file, line,
//! column, field). What the values mean (validation beyond the fields, compilation into the
//! nodes' configurations, what a run observes) is the twin's, above this crate
//! (tools/layers.toml); it plugs its checks in as [`scenario::Check`]s.

pub mod channels;
pub mod comm;
pub mod commands;
pub mod dur;
pub mod entries;
pub mod eps;
pub mod fc;
pub mod invariants;
pub mod params;
pub mod pc;
pub mod rules;
pub mod scenario;
