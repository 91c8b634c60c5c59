//! What the bus's integration tests share.
#![allow(clippy::unwrap_used, dead_code)]

/// A run's runtime: one thread, tokio's clock paused (it jumps to the next timer).
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()
        .unwrap()
}
