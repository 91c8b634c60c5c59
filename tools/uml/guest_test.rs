//! Run one `#[ignore]`d test of the current test binary inside the User-Mode Linux guest of
//! `run-in-uml.sh` (which boots with `vcan0` up) and check that it ran and passed. Shared
//! by the SocketCAN tests of the bus and twin crates (`#[path]`-included).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// Boot the guest, run `test` of this test binary in it with `env`, print its output and
/// assert that exactly that test ran, passed and printed `ok_line`.
pub fn run_guest_test(script: &Path, test: &str, env: &[(&str, &str)], ok_line: &str) {
    let exe = std::env::current_exe().expect("path of the test binary");
    let started = Instant::now();
    let mut cmd = Command::new("bash");
    cmd.arg(script).arg(&exe).args([
        "--ignored",
        "--exact",
        test,
        "--nocapture",
        "--test-threads=1",
    ]);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let output = cmd.output().expect("spawn tools/uml/run-in-uml.sh");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!("{stdout}");
    eprintln!("{stderr}");
    eprintln!("{test}: guest boot + test took {:?}", started.elapsed());
    assert!(
        output.status.success(),
        "`{test}` inside User-Mode Linux failed ({}); guest output above",
        output.status
    );
    // Guard against a filter that matched nothing: exactly the guest test must have run.
    assert!(
        stdout.contains(&format!("test {test} ... "))
            && stdout.contains("test result: ok. 1 passed"),
        "the guest did not run `{test}`; output above"
    );
    assert!(
        stdout.contains(ok_line),
        "no `{ok_line}` line from the guest; output above"
    );
}
