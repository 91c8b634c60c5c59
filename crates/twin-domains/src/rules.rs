//! `[rules]`: what the platform lets a payload (12-15) ask of it, and how the platform's
//! time is distributed.
//!
//! ```toml
//! [rules]
//! payload_access = "icd"    # the default; "open" on a lab bench
//! time_sync_to = ["PC"]     # nodes whose CSP clock follows the FC's RTC (default: the PC)
//! time_sync_period = "60s"  # and how often the FC sends it ("0s": at boot and RTCSTMSET only)
//! ```
//!
//! Under `icd` a payload gets the FC commands ICD 4.1 stars (TMGEN, TMATP, TMACD, TMSENS,
//! RTCSTMGET) and the PC's STATUS, not SETUP or ABORT (ICD 3.1.1); anything else gets the
//! failure reply, counted in the node's `denied` and logged as a warning. Of a platform
//! node's service handler it gets ping and uptime; the other services are dropped, counted
//! and logged (`csp::node`). Under `open` a payload may use every command and service.
//!
//! The FC sends its RTC as libcsp's CMP CLOCK set to each node of `time_sync_to`
//! (`nodes_fc::timesync`): at boot, right after an RTCSTMSET, and every `time_sync_period`.

use platform::addr::PayloadAccess;

use twin_core::network::NetworkSpec;
use twin_runtime::RunOptions;
use twin_scenario::scenario::{PathStep, Scenario};

pub use twin_scenario::rules::*;

/// Check `time_sync_to`: known nodes, not the FC itself.
pub fn validate(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    let path = |i| {
        vec![
            PathStep::Key("rules".into()),
            PathStep::Key("time_sync_to".into()),
            PathStep::Index(i),
        ]
    };
    for (i, r) in s.rules.time_sync_to.iter().flatten().enumerate() {
        match net.resolve(r) {
            Err(e) => err(path(i), e.to_string()),
            Ok(platform::addr::FC) => err(path(i), "the FC's own RTC is the source".into()),
            Ok(_) => {}
        }
    }
}

/// Put the scenario's rules into the FC's and the PC's configuration.
pub fn compile(s: &Scenario, net: &NetworkSpec, opts: &mut RunOptions) {
    let access = match s.rules.payload_access {
        AccessKind::Icd => PayloadAccess::Icd,
        AccessKind::Open => PayloadAccess::Open,
    };
    opts.fc.payload_access = access;
    opts.pc.payload_access = access;
    opts.payload_access = access;
    if let Some(to) = &s.rules.time_sync_to {
        opts.fc.time_sync.to = to.iter().filter_map(|r| net.resolve(r).ok()).collect();
    }
    if let Some(p) = s.rules.time_sync_period {
        opts.fc.time_sync.period = Some(p.0).filter(|d| !d.is_zero());
    }
}
