//! The vocabulary the twin's layers share, below all of them: what a run's events are
//! ([`events`]), the network's nodes, media and routes ([`network`]), CSP packets put back
//! together from what crossed a medium ([`packets`], [`transit`]), durations as scenarios
//! write them ([`duration`]), values that keep where they were written ([`tagged`]) and
//! simulated UTC as text ([`timefmt`]), the seed's streams ([`seed`]), and the ICD as
//! the run's nodes serve it: ports, commands and reply lengths ([`icd`], [`icd_lengths`]). It knows nothing of scenarios, the runtime or
//! recordings (tools/layers.toml).

pub mod duration;
pub mod events;
pub mod icd;
pub mod icd_lengths;
pub mod network;
pub mod packets;
pub mod seed;
pub mod snapshot_file;
pub mod tagged;
pub mod timefmt;
pub mod transit;
