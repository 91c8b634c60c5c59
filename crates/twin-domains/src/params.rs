//! `[nodes.NAME] params`: the factory values of a node's platform parameters (the table of
//! `csp::params`, docs/protocol.md "Platform port 14"), set from the scenario before the
//! node's first boot. They are what PDEFAULTS restores. Names, types and ranges are checked
//! against the node's table with errors naming the file, line and key; a rule between two
//! parameters (a shed threshold below its restore threshold) is the node's, checked when
//! the run starts (a value it refuses is a warning in the log, the node keeps its own).

use std::collections::BTreeMap;

use csp::params::{ParamDef, ParamType};

use twin_core::network::{NetworkSpec, Role};
use twin_runtime::RunOptions;
use twin_scenario::scenario::{PathStep, Scenario};

pub use twin_scenario::params::*;

/// The parameter table of a node of `role` (empty for the ground stations).
pub fn defs_for(role: Role) -> &'static [ParamDef] {
    match role {
        Role::Fc => nodes_fc::config::PARAMS,
        Role::Eps => nodes_eps::config::PARAMS,
        Role::Ecu => nodes_ecu::config::PARAMS,
        Role::Pc => nodes_pc::config::PARAMS,
        Role::CommPrimary | Role::CommSecondary => nodes_comm::config::PARAMS,
        Role::Payload => nodes_payload::config::PARAMS,
        Role::Ground => &[],
    }
}

/// Why a scenario's value does not fit its parameter.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ParamValueError {
    /// A number for a bool.
    #[error("{name} is a bool: true or false")]
    NotBool {
        /// The parameter.
        name: &'static str,
    },
    /// A bool for a number.
    #[error("{name} is a number, not a bool")]
    NotNumber {
        /// The parameter.
        name: &'static str,
    },
    /// A fraction for an integer.
    #[error("{name} is an integer, not {value}")]
    NotInteger {
        /// The parameter.
        name: &'static str,
        /// The value.
        value: f64,
    },
    /// Outside the table's range.
    #[error(transparent)]
    Range(#[from] csp::params::ParamError),
}

/// The value `v` gives parameter `d`, or why not.
fn value(d: &ParamDef, v: ParamValue) -> Result<f64, ParamValueError> {
    let name = d.name;
    let x = match (d.ty, v) {
        (ParamType::Bool, ParamValue::Bool(b)) => f64::from(u8::from(b)),
        (ParamType::Bool, _) => return Err(ParamValueError::NotBool { name }),
        (_, ParamValue::Bool(_)) => return Err(ParamValueError::NotNumber { name }),
        (ParamType::F32, ParamValue::Float(f)) => f,
        (_, ParamValue::Int(i)) => i as f64,
        (_, ParamValue::Float(f)) if f.fract() == 0.0 => f,
        (_, ParamValue::Float(value)) => return Err(ParamValueError::NotInteger { name, value }),
    };
    d.check(x)?;
    Ok(x)
}

/// Parameter values by id, and errors by key.
type Resolved = (Vec<(u8, f64)>, Vec<(String, String)>);

/// The node's parameter values by id, and the errors by key.
fn resolve(defs: &'static [ParamDef], params: &BTreeMap<String, ParamValue>) -> Resolved {
    let mut ok = Vec::new();
    let mut errs = Vec::new();
    for (name, v) in params {
        match defs.iter().find(|d| d.name == name) {
            None => {
                let names: Vec<&str> = defs.iter().map(|d| d.name).collect();
                errs.push((
                    name.clone(),
                    if names.is_empty() {
                        "this node has no parameters".to_owned()
                    } else {
                        format!("unknown parameter (this node's: {})", names.join(", "))
                    },
                ));
            }
            Some(d) => match value(d, *v) {
                Ok(x) => ok.push((d.id, x)),
                Err(e) => errs.push((name.clone(), e.to_string())),
            },
        }
    }
    (ok, errs)
}

/// Check every `[nodes.NAME] params`.
pub fn validate(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    for (name, o) in &s.nodes {
        let Some(node) = net.nodes.iter().find(|n| &n.name == name) else {
            continue;
        };
        for (key, e) in resolve(defs_for(node.role), &o.params).1 {
            err(
                vec![
                    PathStep::Key("nodes".into()),
                    PathStep::Key(name.clone()),
                    PathStep::Key("params".into()),
                    PathStep::Key(key),
                ],
                e,
            );
        }
    }
}

/// Each node's parameter values, by address, into `opts.params`.
pub fn compile(s: &Scenario, net: &NetworkSpec, opts: &mut RunOptions) {
    for (name, o) in &s.nodes {
        if let Some(node) = net.nodes.iter().find(|n| &n.name == name) {
            let (values, _) = resolve(defs_for(node.role), &o.params);
            if !values.is_empty() {
                opts.params.insert(node.addr, values);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::{ParamValue, ParamValueError, value};

    fn errors(nodes: &str) -> String {
        let text = format!("name = \"t\"\nduration = \"1m\"\n{nodes}");
        match crate::validate::parse("t.toml", &text) {
            Ok(_) => String::new(),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn scenario_values_are_checked_against_the_nodes_table_and_compiled_by_id() {
        let ok = "[nodes.FC.params]\nuse_horizon = true\nstore_period = 10\nbdot_gain = 0.001\n\
                  [nodes.COMM1.params]\nbeacon_period = 30\n";
        assert_eq!(errors(ok), "");
        let text = format!("name = \"t\"\nduration = \"1m\"\n{ok}");
        let opts = crate::plan::compile(&crate::validate::parse("t.toml", &text).unwrap()).opts;
        assert_eq!(opts.params[&3], vec![(1, 0.001), (14, 10.0), (16, 1.0)]);
        assert_eq!(opts.params[&1], vec![(1, 30.0)]);
        for (nodes, key, says) in [
            (
                "[nodes.FC.params]\nnothing = 1",
                "nodes.FC.params.nothing",
                "unknown parameter",
            ),
            (
                "[nodes.FC.params]\nuse_gyro = 1",
                "nodes.FC.params.use_gyro",
                "a bool",
            ),
            (
                "[nodes.FC.params]\nstore_period = 1.5",
                "nodes.FC.params.store_period",
                "an integer",
            ),
            (
                "[nodes.FC.params]\nbdot_gain = 3.0",
                "nodes.FC.params.bdot_gain",
                "out of range 0..=1",
            ),
            (
                "[nodes.FC.params]\nbdot_gain = true",
                "nodes.FC.params.bdot_gain",
                "not a bool",
            ),
            (
                "[nodes.GS16.params]\nx = 1",
                "nodes.GS16.params.x",
                "no parameters",
            ),
        ] {
            let e = errors(&format!("{nodes}\n"));
            assert!(e.contains(key) && e.contains(says), "{nodes}: {e}");
        }
    }

    #[test]
    fn a_value_that_does_not_fit_says_why_by_kind() {
        let def = |name| csp::params::find(nodes_fc::config::PARAMS, name).unwrap();
        let e = value(def("store_period"), ParamValue::Float(1.5)).unwrap_err();
        assert!(matches!(e, ParamValueError::NotInteger { value, .. } if value == 1.5));
        assert_eq!(e.to_string(), "store_period is an integer, not 1.5");
        let e = value(def("use_gyro"), ParamValue::Int(1)).unwrap_err();
        assert_eq!(e.to_string(), "use_gyro is a bool: true or false");
        let e = value(def("bdot_gain"), ParamValue::Float(3.0)).unwrap_err();
        assert!(matches!(e, ParamValueError::Range(_)), "{e:?}");
        assert!(e.to_string().starts_with("bdot_gain: "), "{e}");
        assert_eq!(
            value(def("bdot_gain"), ParamValue::Float(0.5)).unwrap(),
            0.5
        );
    }
}
