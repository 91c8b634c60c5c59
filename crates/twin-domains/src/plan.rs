//! From a validated [`Scenario`] to what the runtime executes: run options, the ground
//! stations' request plans, the fault timeline, and the expectations to check.

use bus::ClockMode;

use crate::expectations::Expectation;
use twin_runtime::RunOptions;
use twin_scenario::scenario::Scenario;

pub use crate::faults::{FaultAction, MediumId, TimedFault};

/// Everything a scenario turns into.
#[derive(Debug, Clone)]
pub struct Compiled {
    /// The run.
    pub opts: RunOptions,
    /// Fault timeline, in time order.
    pub faults: Vec<TimedFault>,
    /// Expectations, in file order.
    pub expectations: Vec<Expectation>,
    /// The invariants' settings (`[invariants]`; a campaign checks them on every run).
    pub invariants: crate::invariants::InvariantSettings,
}

/// Compile a validated scenario.
pub fn compile(s: &Scenario) -> Compiled {
    let net = s.network_spec_unchecked();
    let mut opts = RunOptions::new(net.clone(), s.duration.0);
    opts.seed = s.seed;
    opts.clock = match s.clock.mode {
        twin_scenario::scenario::ClockKind::Virtual => ClockMode::Virtual,
        twin_scenario::scenario::ClockKind::Realtime => ClockMode::Realtime {
            speed: s.clock.speed,
        },
    };
    opts.epoch_unix_s =
        twin_core::timefmt::parse_utc(&s.start).map_or(0, |ns| ns.div_euclid(1_000_000_000)) as u64;
    // The last two lines are the elements (a title line may come first).
    if let [.., l1, l2] = s.satellite.tle.as_slice() {
        opts.tle = Some((l1.clone(), l2.clone()));
    }
    crate::outside::compile(s, &net, &mut opts);
    crate::params::compile(s, &net, &mut opts);
    if let Some(mode) = crate::clock::compile(s, opts.epoch_unix_s) {
        opts.clock = mode;
    } else if opts.has_outside_links() && opts.clock == ClockMode::Virtual {
        opts.clock = ClockMode::Realtime { speed: 1.0 };
    }
    opts.ground_plan = crate::commands::compile(s, &net);
    // The node configurations first: a fault may put events on a node's own timeline.
    let mut fc_faults = Vec::new();
    opts.fc = crate::adcs::compile(s, &net, &mut fc_faults);
    opts.eps = crate::eps::compile(s);
    opts.comm = crate::comm::compile(s);
    opts.pc = crate::sessions::compile_pc(s);
    opts.payloads = crate::sessions::compile_payloads(s);
    crate::rules::compile(s, &net, &mut opts);
    let mut faults = crate::faults::compile(s, &net, &mut opts);
    faults.extend(fc_faults);
    faults.extend(crate::comm::compile_passes(s, opts.epoch_unix_s));
    for p in opts.payloads.values_mut() {
        if let Some(push) = p.push.as_mut() {
            push.pc_port = opts.pc.ingest_port;
        }
    }
    faults.sort_by_key(|f| f.at);
    opts.faults = faults.clone();
    let expectations = crate::expectation_kinds::compile(s);
    Compiled {
        opts,
        faults,
        expectations,
        invariants: crate::invariants::compile(s),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    const TLE: &str = r#"
[satellite]
tle = [
  "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
  "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
]
"#;

    fn fc_of(extra: &str) -> nodes_fc::FcConfig {
        let text = format!(
            "name = \"t\"\nstart = \"2026-04-30T18:00:00Z\"\nduration = \"1m\"\n{TLE}\n{extra}"
        );
        let s = crate::validate::parse("t.toml", &text).unwrap();
        compile(&s).opts.fc
    }

    #[test]
    fn a_scenario_inertia_re_derives_the_control_gains() {
        let default = fc_of("");
        assert_eq!(
            default.adcs.control,
            nodes_fc::control::ControlConfig::default()
        );
        let big = fc_of("[fc]\ninertia_kg_m2 = [[0.4, 0, 0], [0, 0.5, 0], [0, 0, 0.2]]\n");
        let want = nodes_fc::control::ControlConfig::for_body(
            &big.body,
            15.145 * std::f64::consts::TAU / 86_400.0,
        );
        assert_eq!(big.adcs.control, want);
        assert_ne!(big.adcs.control, default.adcs.control);
    }
}
