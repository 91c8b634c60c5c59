//! Payload controller (CSP 6): routes between the main and payload CAN buses and runs ICD 3.1 sessions. Ports 10 (session control) and 11 (data ingest) answer failure until the PC issue fills them.

use csp::node::StubApp;

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[10, 11];

/// The node's application.
pub fn app() -> StubApp {
    StubApp::new(PORTS)
}
