//! Propulsion control unit (CSP 5). Port 10 answers failure until the ECU issue fills it.

use csp::node::StubApp;

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[10];

/// The node's application.
pub fn app() -> StubApp {
    StubApp::new(PORTS)
}
