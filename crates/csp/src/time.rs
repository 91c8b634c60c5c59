//! Simulated time: [`SimTime`], integer nanoseconds since the start of a run, defined by the
//! platform layer (`m6p-platform`) that every node and medium shares.

pub use platform::time::SimTime;
