//! Probes for what some tests need outside Rust, so that a test whose prerequisite is
//! missing is compiled as ignored with the reason instead of passing without checking:
//!
//! - the User-Mode Linux probe of `crates/links/build.rs`, shared rather than copied: emits
//!   `cfg(uml_available)` for `tests/socketcan_uml.rs` under the same conditions as for the
//!   links crate's `tests/vcan_uml.rs` (see `tools/uml/README.md`);
//! - `cfg(python_mcap)`: `python3` can import the `mcap` and `mcap_protobuf` packages (the
//!   generic reader and Google's protobuf decoder the recording tests decode with). Under
//!   `CI` it is always set, so a missing package fails those tests there (`.ci/run`
//!   installs them) instead of ignoring them. Set
//!   `M6P_PYTHON_PROBE=off` to force "not available" outside CI.
//! - `cfg(python_pytest)`: `python3` can import `pytest` and `zmq` (pyzmq), which the
//!   Python package's own tests need (`tests/python_package.rs`). Under `CI` it is always
//!   set (`.ci/run` installs them); `M6P_PYTHON_PROBE=off` forces "not available".
//! - `cfg(python_xtce)`: `python3` can import `lxml` and find the `xtce-lib` package, whose
//!   XTCE 1.2 schema `tools/xtce-validate.py` checks `icd --xtce` against (`tests/xtce.rs`).
//!   Under `CI` it is always set (`.ci/run` installs them); `M6P_PYTHON_PROBE=off` forces
//!   "not available".
//! - `cfg(slurm_available)`: running as root with Debian's `slurm-wlm` and `munge` installed
//!   (`tests/campaign_slurm.rs` starts a one-node cluster with `tools/slurm/cluster.sh`).
//!   Under `CI` it is always set (`.ci/run` installs them); `M6P_SLURM_PROBE=off` forces
//!   "not available" elsewhere.
//! - `cfg(libcsp_peer)`: a C compiler (`cc`) and libzmq's headers (`zmq.h`, Debian
//!   `libzmq3-dev`), to build the vendored libcsp 1.4 and `tests/libcsp/` for
//!   `tests/libcsp.rs`. Under `CI` it is always set (`.ci/run` installs them);
//!   `M6P_LIBCSP_PROBE=off` forces "not available" elsewhere.
//! - `cfg(mount_tmpfs)`: running as root on Linux, so a test may mount a 64 KiB tmpfs to
//!   see a recording run out of space (`tests/recording_safety.rs`). Under `CI` it is
//!   always set (CI runs as root).
//! - `cfg(valgrind)`: `valgrind` is on the PATH, to count a command's instructions with
//!   cachegrind (`tests/input_bounds.rs`: checking is linear in the commands). Under `CI`
//!   it is always set (`.ci/run` installs it).

#[path = "../links/build.rs"]
mod uml_probe;

fn main() {
    println!("cargo::rerun-if-changed=../links/build.rs");
    uml_probe::main();
    python_probe();
    pytest_probe();
    xtce_probe();
    slurm_probe();
    libcsp_probe();
    mount_probe();
    valgrind_probe();
}

/// `cfg(valgrind)`: valgrind runs here (always under CI, which installs it).
fn valgrind_probe() {
    println!("cargo::rustc-check-cfg=cfg(valgrind)");
    let runs = std::process::Command::new("valgrind")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if std::env::var_os("CI").is_some() || runs {
        println!("cargo::rustc-cfg=valgrind");
    }
}

/// `cfg(mount_tmpfs)`: the tests may mount a small tmpfs (Linux, as root) to see a
/// recording run out of space. Under CI it is set (CI runs as root): a test that cannot
/// mount there fails instead of being ignored.
fn mount_probe() {
    println!("cargo::rustc-check-cfg=cfg(mount_tmpfs)");
    let root = std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|l| l.split_whitespace().nth(1))
            == Some("0")
    });
    if std::env::var_os("CI").is_some() || (root && cfg!(target_os = "linux")) {
        println!("cargo::rustc-cfg=mount_tmpfs");
    }
}

fn libcsp_probe() {
    println!("cargo::rustc-check-cfg=cfg(libcsp_peer)");
    println!("cargo::rerun-if-env-changed=M6P_LIBCSP_PROBE");
    if std::env::var_os("CI").is_some() {
        println!("cargo::rustc-cfg=libcsp_peer");
        return;
    }
    if std::env::var("M6P_LIBCSP_PROBE").is_ok_and(|v| v == "off") {
        return;
    }
    // Installing libzmq3-dev adds /usr/include/zmq.h: probe again then.
    println!("cargo::rerun-if-changed=/usr/include");
    let cc = ["/usr/bin", "/bin", "/usr/local/bin"]
        .iter()
        .any(|d| std::path::Path::new(d).join("cc").exists());
    let zmq = ["/usr/include/zmq.h", "/usr/local/include/zmq.h"]
        .iter()
        .any(|f| std::path::Path::new(f).exists());
    if cc && zmq {
        println!("cargo::rustc-cfg=libcsp_peer");
    }
}

fn slurm_probe() {
    println!("cargo::rustc-check-cfg=cfg(slurm_available)");
    println!("cargo::rerun-if-env-changed=M6P_SLURM_PROBE");
    if std::env::var_os("CI").is_some() {
        println!("cargo::rustc-cfg=slurm_available");
        return;
    }
    if std::env::var("M6P_SLURM_PROBE").is_ok_and(|v| v == "off") {
        return;
    }
    let tools = ["sbatch", "slurmctld", "slurmd", "munged", "runuser"];
    let dirs = ["/usr/bin", "/usr/sbin", "/bin", "/sbin"];
    // Installing slurm-wlm adds /usr/bin/sbatch: probe again then.
    println!("cargo::rerun-if-changed=/usr/bin");
    let found = tools.iter().all(|t| {
        dirs.iter()
            .any(|d| std::path::Path::new(d).join(t).exists())
    });
    let root = std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|l| l.split_whitespace().nth(1))
            == Some("0")
    });
    if found && root {
        println!("cargo::rustc-cfg=slurm_available");
    }
}

fn python_probe() {
    println!("cargo::rustc-check-cfg=cfg(python_mcap)");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=M6P_PYTHON_PROBE");
    if std::env::var_os("CI").is_some() {
        println!("cargo::rustc-cfg=python_mcap");
        return;
    }
    if std::env::var("M6P_PYTHON_PROBE").is_ok_and(|v| v == "off") {
        return;
    }
    // Where the package is, or the directories `pip install` would put it in: watched so
    // that installing or removing it probes again.
    let out = std::process::Command::new("python3")
        .args([
            "-c",
            "import site, sys\n\
             try:\n    import mcap.reader, mcap_protobuf.decoder, os\n    print('found', os.path.dirname(mcap.__file__))\n\
             except Exception:\n    print('missing')\n\
             for d in site.getsitepackages() + [site.getusersitepackages()]:\n    print('dir', d)",
        ])
        .output();
    let Ok(out) = out else {
        return;
    };
    let text = String::from_utf8_lossy(&out.stdout);
    let mut found = false;
    for line in text.lines() {
        if let Some(dir) = line.strip_prefix("found ") {
            found = true;
            println!("cargo::rerun-if-changed={dir}");
        } else if let Some(dir) = line.strip_prefix("dir ")
            && std::path::Path::new(dir).is_dir()
        {
            println!("cargo::rerun-if-changed={dir}");
        }
    }
    if found {
        println!("cargo::rustc-cfg=python_mcap");
    }
}

/// `cfg(name)` when `python3` runs `code` successfully; always under CI (which installs
/// what it needs), never with `M6P_PYTHON_PROBE=off`.
fn python_can(name: &str, code: &str) {
    println!("cargo::rustc-check-cfg=cfg({name})");
    if std::env::var_os("CI").is_some() {
        println!("cargo::rustc-cfg={name}");
        return;
    }
    if std::env::var("M6P_PYTHON_PROBE").is_ok_and(|v| v == "off") {
        return;
    }
    let found = std::process::Command::new("python3")
        .args(["-c", code])
        .output()
        .is_ok_and(|o| o.status.success());
    if found {
        println!("cargo::rustc-cfg={name}");
    }
}

fn xtce_probe() {
    python_can(
        "python_xtce",
        "import importlib.util, lxml.etree, sys\n\
         sys.exit(importlib.util.find_spec('xtce_lib') is None)",
    );
}

fn pytest_probe() {
    python_can("python_pytest", "import pytest, zmq");
}
