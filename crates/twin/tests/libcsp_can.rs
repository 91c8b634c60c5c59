//! The real libcsp 1.4 over SocketCAN: the programs of `tests/libcsp/` on `vcan0` (the main
//! bus) and `vcan1` (the payload bus), bridged to the twin inside a User-Mode Linux guest
//! (`tools/uml/run-in-uml.sh`, as `socketcan_uml.rs`), so that it runs on hosts whose kernel
//! has no SocketCAN. libcsp 1.4's own CAN interface (`csp_can_init` with its SocketCAN
//! driver, CFP) talks to the twin's CAN buses frame by frame.
//!
//! `libcsp_over_vcan_in_uml` (on the host) builds libcsp and the programs, then boots the
//! guest, which re-executes this test binary with `--ignored --exact guest_libcsp_over_vcan`.
//! There the twin runs the scenario of `examples/README.md` with both buses bridged; the
//! libcsp payload at 12 on `vcan1` serves session 1 to DONE (what reached the ground is what
//! it sent) while the libcsp client at 10 on `vcan0` pings every node, reads CMP ident,
//! uptime, ps, memfree and buf_free of the FC and the PC, runs every FC telemetry command
//! and checks that a reserved address times out.
//!
//! Needs the `socketcan` feature, User-Mode Linux with vcan (`cfg(uml_available)`) and what
//! `libcsp.rs` needs (`cfg(libcsp_peer)`); otherwise ignored with the reason.
#![cfg(all(feature = "socketcan", target_os = "linux"))]
#![allow(clippy::unwrap_used)]

mod common;
mod libcsp_peer;
#[path = "../../../tools/uml/guest_test.rs"]
mod uml;

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use libcsp_peer::{Iface, Programs, client, client_checks, expected_stream, same_bytes};
use m6p_twin::runtime::SocketCanBus;

/// Set (to the programs' directory) only for the re-executed test binary in the guest.
const GUEST_ENV: &str = "M6P_TWIN_LIBCSP_GUEST_BIN";
const GUEST_TEST: &str = "guest_libcsp_over_vcan";

#[test]
#[cfg_attr(
    not(all(uml_available, libcsp_peer)),
    ignore = "needs User-Mode Linux with vcan (apt-get install user-mode-linux), a C compiler and libzmq3-dev"
)]
fn libcsp_over_vcan_in_uml() {
    let progs = libcsp_peer::programs();
    let bin = progs.client.parent().unwrap();
    let script = common::repo_root().join("tools/uml/run-in-uml.sh");
    let bin = bin.to_string_lossy();
    uml::run_guest_test(
        &script,
        GUEST_TEST,
        &[(GUEST_ENV, &bin), ("UML_TIMEOUT", "120")],
        "libcsp_over_vcan: OK",
    );
}

/// Runs inside the UML guest only (started by `libcsp_over_vcan_in_uml`).
#[test]
#[ignore = "runs inside the User-Mode Linux guest, started by libcsp_over_vcan_in_uml"]
fn guest_libcsp_over_vcan() {
    let bin = PathBuf::from(std::env::var(GUEST_ENV).unwrap_or_else(|_| {
        panic!(
            "{GUEST_ENV} not set: this test runs inside the UML guest via libcsp_over_vcan_in_uml"
        )
    }));
    let progs: &'static Programs = Box::leak(Box::new(Programs {
        client: bin.join("csp_client"),
        payload: bin.join("csp_payload"),
        example: bin.join("libcsp_payload"),
    }));
    // The guest has vcan0; the payload bus gets vcan1.
    for args in [
        &["link", "add", "dev", "vcan1", "type", "vcan"][..],
        &["link", "set", "dev", "vcan1", "up"][..],
    ] {
        let st = Command::new("ip").args(args).status().unwrap();
        assert!(st.success(), "ip {args:?}: {st}");
    }
    let mut opts = libcsp_peer::readme_options();
    // The libcsp programs are CAN nodes of their own: no KISS link, both buses bridged.
    opts.kiss_links.clear();
    opts.socketcan = vec![
        ("vcan0".to_owned(), SocketCanBus::Main),
        ("vcan1".to_owned(), SocketCanBus::Payload),
    ];
    opts.duration = Some(Duration::from_secs(12));
    // The default scenario's orbit: the FC's position and attitude telemetry need one.
    let default = libcsp_peer::default_options();
    (opts.tle, opts.epoch_unix_s) = (default.tle, default.epoch_unix_s);
    let epoch = opts.epoch_unix_s;
    let dir = libcsp_peer::temp_path("vcan-payload");
    std::fs::create_dir_all(&dir).unwrap();
    let sent = dir.join("sent.bin");
    let (report, (payload, client_out)) = libcsp_peer::with_twin(opts, move || {
        let checks = std::thread::spawn(move || {
            client(
                progs,
                &Iface::Can("vcan0".into()),
                10,
                &client_checks(),
                &["--all-icd-fc"],
            )
        });
        let out = Command::new(&progs.payload)
            .args(["--can", "vcan1", "--addr", "12", "--api", "conn", "--sent"])
            .arg(&sent)
            .args(["--idle", "1.5", "--seconds", "11"])
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (text, checks.join().unwrap())
    });
    let report = report.unwrap();
    println!("{payload}");
    let (ok, text) = client_out;
    println!("{text}");
    // 12 is the libcsp payload here.
    libcsp_peer::assert_client_checks(ok, &text, epoch, &[12]);
    assert!(
        payload.contains("served syncs=1 polls=25 bytes=3416 refused=0"),
        "{payload}"
    );
    let sent = std::fs::read(dir.join("sent.bin")).unwrap();
    same_bytes("sent", &sent, "frame_data", &expected_stream(25, 200));
    common::assert_one_session_done(&report, 1, 25);
    same_bytes(
        "downlinked",
        &report.sessions.session_bytes(1),
        "sent by the libcsp payload",
        &sent,
    );
    for (name, b) in &report.socketcan {
        assert_eq!((b.recv_errors, b.send_errors), (0, 0), "{name}: {b:?}");
    }
    println!(
        "libcsp_over_vcan: OK: {} client checks on vcan0, a session of 25 POLLs (3416 bytes \
         downlinked identical) from the libcsp payload on vcan1; bridges {:?}",
        libcsp_peer::CLIENT_CHECKS,
        report.socketcan
    );
}
