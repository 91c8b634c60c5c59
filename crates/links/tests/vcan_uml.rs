//! A real SocketCAN test on a `vcan0` interface, run inside a User-Mode Linux guest
//! (`tools/uml/run-in-uml.sh`), so it works on hosts whose kernel has no SocketCAN.
//!
//! `vcan_echo_in_uml` (on the host) boots the guest, which re-executes this very test
//! binary with `--ignored --exact guest_vcan_echo`; that test runs the ping/echo of
//! `examples/vcan_echo.rs` between two `SocketCanLink`s on the guest's `vcan0`.
//!
//! When `build.rs` finds no UML kernel with the vcan module, `vcan_echo_in_uml` is
//! compiled as ignored (with the reason), never reported as passed. When UML is
//! installed, any failure to boot, set up vcan0 or pass the echo fails the test and
//! prints the guest's output.
#![cfg(all(feature = "socketcan", target_os = "linux"))]

use std::path::PathBuf;

#[path = "../../../tools/uml/guest_test.rs"]
mod uml;
#[path = "../examples/vcan_echo.rs"]
#[allow(dead_code)]
mod vcan_echo;

/// Set (to the interface name) only for the re-executed test binary inside the guest.
const GUEST_ENV: &str = "M6P_VCAN_GUEST_IFNAME";
const GUEST_TEST: &str = "guest_vcan_echo";

fn run_in_uml_script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tools/uml/run-in-uml.sh")
}

#[test]
#[cfg_attr(
    not(uml_available),
    ignore = "User-Mode Linux with vcan not installed (apt-get install user-mode-linux)"
)]
fn vcan_echo_in_uml() {
    let script = run_in_uml_script();
    assert!(script.is_file(), "{} missing", script.display());
    uml::run_guest_test(
        &script,
        GUEST_TEST,
        &[(GUEST_ENV, "vcan0")],
        "vcan_echo: OK",
    );
}

/// Runs inside the UML guest only (started by `vcan_echo_in_uml`, which sets
/// `M6P_VCAN_GUEST_IFNAME`); on the host it is ignored.
#[test]
#[ignore = "runs inside the User-Mode Linux guest, started by vcan_echo_in_uml"]
fn guest_vcan_echo() {
    let ifname = std::env::var(GUEST_ENV).unwrap_or_else(|_| {
        panic!("{GUEST_ENV} not set: this test runs inside the UML guest via vcan_echo_in_uml")
    });
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    match rt.block_on(vcan_echo::run(&ifname)) {
        Ok(r) => println!(
            "vcan_echo: OK on {}: {} request frames, {} reply frames, round trip {:?}; A {:?}; B {:?}",
            r.ifname, r.request_frames, r.reply_frames, r.round_trip, r.a, r.b
        ),
        Err(e) => panic!("vcan_echo on {ifname} failed: {e}"),
    }
}
