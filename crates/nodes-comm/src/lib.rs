//! UHF radio (CSP 1 and 2): bridges the main CAN bus and the ground segment. Port 10 answers failure until the COMM issue fills it.

use csp::node::StubApp;

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[10];

/// The node's application.
pub fn app() -> StubApp {
    StubApp::new(PORTS)
}
