//! The platform model of the M6P twin: what every node, medium and fault goes through, and
//! nothing of physics or protocol.
//!
//! - [`time`]: [`time::SimTime`], integer simulated nanoseconds.
//! - [`addr`]: the network's address table (INTERPRETATION.md section 1), in one place.
//! - [`truth`]: the FC's published truth and ADCS snapshots.
//! - [`board`]: the boards where nodes meet outside the bus (truth, burns, activities),
//!   typed with [`time::SimTime`], refusing and counting writes behind a reader.
//! - [`power`]: one truth for power (EPS channels and power faults) and the radio take-over,
//!   as a pure core.

pub mod addr;
pub mod board;
pub mod power;
pub mod time;
pub mod truth;

pub use time::SimTime;
