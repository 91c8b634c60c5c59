//! Probes for User-Mode Linux with the vcan module, which `tests/vcan_uml.rs` needs to run
//! a real SocketCAN test on kernels without SocketCAN (see `tools/uml/README.md`).
//!
//! Emits `cfg(uml_available)` when a UML kernel, its `vcan`/`can`/`can-raw` modules,
//! `modprobe` (kmod) and `ip` (iproute2) are all present; otherwise that test is
//! reported as ignored. Set `M6P_UML_PROBE=off` to force "not available".
//!
//! `crates/twin/build.rs` runs this same probe (it includes this file as a module and
//! calls `main`) for `crates/twin/tests/socketcan_uml.rs`.

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

const KERNEL_CANDIDATES: &[&str] = &["/usr/bin/linux.uml", "/usr/local/bin/linux.uml"];
const MODULES_ROOT: &str = "/usr/lib/uml/modules";
const CAN_MODULES: &[&str] = &[
    "kernel/drivers/net/can/vcan.ko",
    "kernel/net/can/can.ko",
    "kernel/net/can/can-raw.ko",
];
const MODPROBE_CANDIDATES: &[&str] = &["/usr/sbin/modprobe", "/sbin/modprobe", "/usr/bin/modprobe"];
const IP_CANDIDATES: &[&str] = &["/usr/sbin/ip", "/sbin/ip", "/usr/bin/ip", "/bin/ip"];

pub fn main() {
    println!("cargo::rustc-check-cfg=cfg(uml_available)");
    println!("cargo::rerun-if-changed=build.rs");
    for var in ["M6P_UML_PROBE", "UML_KERNEL", "UML_MODULES_DIR"] {
        println!("cargo::rerun-if-env-changed={var}");
    }
    if env::var("M6P_UML_PROBE").is_ok_and(|v| v == "off") {
        return;
    }
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("linux") {
        return;
    }

    let kernel = match env::var_os("UML_KERNEL") {
        Some(k) => Some(PathBuf::from(k)).filter(|p| p.is_file()),
        None => first_existing(KERNEL_CANDIDATES),
    };
    let modules = match env::var_os("UML_MODULES_DIR") {
        Some(d) => Some(PathBuf::from(d)).filter(|d| has_can_modules(d)),
        None => fs::read_dir(MODULES_ROOT).ok().and_then(|entries| {
            entries
                .flatten()
                .map(|e| e.path())
                .find(|d| has_can_modules(d))
        }),
    };
    let modprobe = first_existing(MODPROBE_CANDIDATES);
    let ip = first_existing(IP_CANDIDATES);

    // Re-probe when something is installed or removed: watch the files found, or the
    // directory a missing one would appear in (cargo scans such a directory recursively).
    // (`/usr/lib` itself is too big to scan; installing UML also adds to `/usr/bin`.)
    let modules_dir = if Path::new(MODULES_ROOT).is_dir() {
        MODULES_ROOT
    } else {
        "/usr/bin"
    };
    watch(kernel.as_deref(), "/usr/bin");
    watch(
        modules.as_ref().map(|d| d.join(CAN_MODULES[0])).as_deref(),
        modules_dir,
    );
    watch(modprobe.as_deref(), "/usr/sbin");
    watch(ip.as_deref(), "/usr/sbin");

    if kernel.is_some() && modules.is_some() && modprobe.is_some() && ip.is_some() {
        println!("cargo::rustc-cfg=uml_available");
    }
}

fn first_existing(candidates: &[&str]) -> Option<PathBuf> {
    candidates.iter().map(PathBuf::from).find(|p| p.is_file())
}

fn has_can_modules(dir: &Path) -> bool {
    CAN_MODULES.iter().all(|m| dir.join(m).is_file())
}

fn watch(found: Option<&Path>, fallback_dir: &str) {
    match found {
        Some(path) => println!("cargo::rerun-if-changed={}", path.display()),
        None if Path::new(fallback_dir).is_dir() => {
            println!("cargo::rerun-if-changed={fallback_dir}")
        }
        None => {}
    }
}
