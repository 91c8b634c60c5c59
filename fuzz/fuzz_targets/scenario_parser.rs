//! `scenario_parser`: the scenario loader on arbitrary UTF-8 text:
//! `m6p_twin::scenario::parse(file, text)` (TOML, then the meaning of every field,
//! with errors located at line and column), `Scenario::validate_with` again on what parsed, and
//! `m6p_twin::plan::compile` of a valid scenario (network, faults, commands, expectations).
//!
//! Asserts: nothing panics; every error renders; a scenario that parsed validates again
//! (parse is deterministic); compiling a valid scenario does not panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

const FILE: &str = "fuzz.toml";

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match m6p_twin::scenario::parse(FILE, text) {
        Err(e) => {
            let _ = e.to_string();
        }
        Ok(s) => {
            if let Err(e) = s.validate_with(FILE, text, m6p_twin::validate::CHECKS) {
                panic!("parsed but does not validate again: {e}");
            }
            let _ = s.display_name(FILE);
            let _ = s.network_spec_unchecked();
            let _ = m6p_twin::plan::compile(&s);
        }
    }
});
