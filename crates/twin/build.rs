//! The User-Mode Linux probe of `crates/bus/build.rs`, shared rather than copied: emits
//! `cfg(uml_available)` for `tests/socketcan_uml.rs` under the same conditions as for the
//! bus crate's `tests/vcan_uml.rs` (see `tools/uml/README.md`).

#[path = "../bus/build.rs"]
mod uml_probe;

fn main() {
    println!("cargo::rerun-if-changed=../bus/build.rs");
    uml_probe::main();
}
