//! Builds the vendored libcsp 1.4 (`third_party/libcsp-1.4/build.sh` into
//! `$OUT_DIR/libcsp`) and the C shim over it (`c/shim.c`, with the `cc` crate), and links
//! both with pthread, rt and m. Emits `cfg(libcsp_shim)` when it did.
//!
//! libcsp's SocketCAN driver is removed from this copy of the archive: the shim is the CAN
//! driver (`can_init`, `can_send`), so the link cannot pick the other one.
//!
//! Prerequisite: a C compiler (`cc`), with bash, tar and ar. Where `cc` is missing the crate
//! builds without the shim and its tests are reported as ignored with the reason; under
//! `CI` the shim is always built (a missing compiler fails the build, as for
//! `crates/twin/tests/libcsp.rs`). `M6P_LIBCSP_PROBE=off` forces "not available" outside
//! CI, as in `crates/twin/build.rs`.

use std::env;
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(libcsp_shim)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-changed=c/shim.c");
    println!("cargo::rerun-if-changed=../../third_party/libcsp-1.4");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=M6P_LIBCSP_PROBE");
    if env::var_os("CI").is_none() && !available() {
        return;
    }
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let root = manifest.join("../..");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR")).join("libcsp");

    run(Command::new("bash")
        .arg(root.join("third_party/libcsp-1.4/build.sh"))
        .arg(&out));
    // build.sh names each object after its source path (`drivers/can/can_socketcan.c`).
    run(Command::new("ar")
        .arg("d")
        .arg(out.join("libcsp.a"))
        .arg("drivers_can_can_socketcan.c.o"));

    cc::Build::new()
        .file(manifest.join("c/shim.c"))
        .include(out.join("include"))
        // libcsp's internal CAN driver header, `drivers/can/can.h`.
        .include(out.join("src/src"))
        .define("_GNU_SOURCE", None)
        .flag("-std=gnu99")
        .warnings(true)
        .extra_warnings(true)
        .warnings_into_errors(true)
        .compile("m6p_libcsp_shim");

    // After the shim, so that the linker resolves the shim's libcsp calls from it.
    println!("cargo::rustc-link-search=native={}", out.display());
    println!("cargo::rustc-link-lib=static=csp");
    for lib in ["pthread", "rt", "m"] {
        println!("cargo::rustc-link-lib=dylib={lib}");
    }
    println!("cargo::rustc-cfg=libcsp_shim");
}

/// Whether a C compiler is there (and the probe is not switched off).
fn available() -> bool {
    if env::var("M6P_LIBCSP_PROBE").is_ok_and(|v| v == "off") {
        return false;
    }
    // Installing a compiler adds /usr/bin/cc: probe again then.
    println!("cargo::rerun-if-changed=/usr/bin");
    let found = ["/usr/bin", "/bin", "/usr/local/bin"]
        .iter()
        .any(|d| Path::new(d).join("cc").exists());
    if !found {
        println!(
            "cargo::warning=no C compiler (cc): libcsp 1.4 not built, the libcsp comparison is unavailable"
        );
    }
    found
}

/// Run `cmd`, failing the build with its output when it does not succeed.
fn run(cmd: &mut Command) {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    if !out.status.success() {
        panic!(
            "{cmd:?} failed ({}):\n{}{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}
