//! Electrical power system (CSP 4). Port 10 (telemetry and control) answers failure until the EPS issue fills it.

use csp::node::StubApp;

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[10];

/// The node's application.
pub fn app() -> StubApp {
    StubApp::new(PORTS)
}
