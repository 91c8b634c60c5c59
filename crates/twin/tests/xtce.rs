//! `m6p-twin icd --xtce`: the XTCE 1.2 mission database for YAMCS (docs/operations.md).
//! It is valid against the OMG schema (from PyPI's `xtce-lib`, checked with lxml by
//! `tools/xtce-validate.py`), it holds a command and a reply container for every command of
//! `icd --json`, and the one shipped in examples/yamcs is what the command prints today.
#![allow(clippy::unwrap_used)]

use std::process::Command;

use serde_json::Value;

mod common;

fn twin(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "{args:?}: {out:?}");
    String::from_utf8(out.stdout).unwrap()
}

/// `NODE.COMMAND` of every command of `icd --json`, sorted.
fn json_commands() -> Vec<String> {
    let icd: Value = serde_json::from_str(&twin(&["icd", "--json"])).unwrap();
    let mut names = Vec::new();
    for node in icd["nodes"].as_array().unwrap() {
        for port in node["ports"].as_array().unwrap() {
            for c in port["commands"].as_array().unwrap() {
                names.push(format!(
                    "{}.{}",
                    node["name"].as_str().unwrap(),
                    c["name"].as_str().unwrap()
                ));
            }
        }
    }
    names.sort();
    names
}

#[test]
fn the_cli_prints_the_database_and_the_example_ships_it() {
    let xml = twin(&["icd", "--xtce"]);
    let made = m6p_twin::icd::xtce::to_xtce();
    assert_eq!(xml, made.xml);
    let n = json_commands().len();
    assert_eq!((made.commands, made.replies), (n, n));
    let shipped = common::repo_root().join("examples/yamcs/src/main/yamcs/mdb/m6p.xml");
    let on_disk = std::fs::read_to_string(&shipped).unwrap();
    assert!(
        on_disk == xml,
        "{} is not what `m6p-twin icd --xtce` prints: regenerate it with \
         `m6p-twin icd --xtce > examples/yamcs/src/main/yamcs/mdb/m6p.xml`",
        shipped.display()
    );
}

#[test]
#[cfg_attr(
    not(python_xtce),
    ignore = "needs python3 with lxml and xtce-lib (pip install lxml; pip install --no-deps \
              xtce-lib==0.1.0a4; .ci/run installs them)"
)]
fn the_database_is_valid_xtce_with_every_command_and_reply() {
    let xml = twin(&["icd", "--xtce"]);
    let file = common::TempFile::new("m6p-xtce.xml");
    std::fs::write(file.path(), &xml).unwrap();
    let out = Command::new("python3")
        .arg(common::repo_root().join("tools/xtce-validate.py"))
        .arg(file.path())
        .output()
        .unwrap();
    let report: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stderr)));
    assert_eq!(report["valid"], true, "{report:#}");
    assert_eq!(out.status.code(), Some(0));

    // A command and a reply container per command of `icd --json`, by node and name.
    let names = |k: &str| -> Vec<String> {
        report[k]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_owned())
            .collect()
    };
    let expected = json_commands();
    assert_eq!(names("commands"), expected);
    assert_eq!(names("replies"), expected);
    for c in ["FC.TMALL", "FC.ATCATSET", "PC.SETUP", "EPS.TMEPS"] {
        assert!(expected.iter().any(|e| e == c), "{c}");
    }

    // The nested layouts and arrays as XTCE aggregates and arrays: TMALL's reply, ATCATSET's
    // quaternion, TMEPS's panel powers.
    for t in [
        "<AggregateParameterType name=\"attitude_control_agg_t\">",
        "<ArrayArgumentType name=\"ATCATSET_q_t\" arrayTypeRef=\"ATCATSET_q_el_t\">",
        "<ArrayParameterType name=\"panels_w_t\" arrayTypeRef=\"panels_w_el_t\">",
    ] {
        assert!(xml.contains(t), "{t} missing");
    }
    // The ICD's ranges on arguments, as integers: SETUP's duration.
    assert!(
        xml.contains("<ValidRange minInclusive=\"5\" maxInclusive=\"900\"/>"),
        "SETUP duration_s range"
    );
}
