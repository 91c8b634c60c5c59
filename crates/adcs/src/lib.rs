//! The flight computer's attitude determination and control (ADCS): the flight software of
//! ICD 1.3 and everything it is flown against, a pure and deterministic library (no clock,
//! no I/O; the sensor noise comes from a seed) driven by the FC's node (`m6p-nodes-fc`),
//! which re-exports each module under its old name (`nodes_fc::control`, ...).
//!
//! - [`adcs`]: the flight software's step: mode logic (detumble, acquisition, tracking,
//!   safe), determination, guidance and control, the estimator health monitor.
//! - [`guidance`]: the target attitude, rate and pointing axis of each pointing mode.
//! - [`estimator`]: attitude determination, the MEKF and TRIAD.
//! - [`control`]: B-dot, quaternion feedback on the reaction wheels, wheel allocation and
//!   magnetic desaturation.
//! - [`sensors`]: the FC's sensor models (raw counts and processed values, seeded noise,
//!   injected faults).
//! - [`environment`]: the space environment at the satellite (orbit, sun, shadow,
//!   geomagnetic field, drag), on the truth's orbit and on the onboard one.
//! - [`truth`]: the rigid-body attitude dynamics with reaction wheels, the truth the ADCS
//!   flies against.

pub mod adcs;
pub mod control;
pub mod environment;
pub mod estimator;
pub mod guidance;
pub mod sensors;
pub mod truth;
