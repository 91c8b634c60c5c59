//! Flight computer (CSP 3): ADCS truth, sensors, control, and the FC ports of ICD 4. Ports 10-13 (telemetry, RTC, attitude control, scripts) answer failure until the FC issue fills them.

use csp::node::StubApp;

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[10, 11, 12, 13];

/// The node's application.
pub fn app() -> StubApp {
    StubApp::new(PORTS)
}
