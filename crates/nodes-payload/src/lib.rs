//! Simulated payloads (CSP 12-15). Port 10 (SYNC/POLL) answers failure until the payload issue fills it.

use csp::node::StubApp;

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[10];

/// The node's application.
pub fn app() -> StubApp {
    StubApp::new(PORTS)
}
