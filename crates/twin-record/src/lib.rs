//! A run on disk: MCAP writing ([`record`]: every event's channel, schema and encoder, the
//! recorder's thread), its container ([`mcap_file`]) and protobuf schemas ([`protobuf`]),
//! reading, summing up, comparing and exporting recordings ([`recording`]), their sizes by
//! channel ([`sizes`]), and the live view over Foxglove's WebSocket protocol (`live`, cargo
//! feature `live`). It knows the run's events (m6p-twin-core), not the runtime.

#[cfg(feature = "live")]
pub mod live;
#[cfg(feature = "live")]
pub mod live_front;
pub mod log_order;
pub mod mcap_file;
pub mod protobuf;
pub mod record;
pub mod recording;
pub mod sizes;
