//! The Python package for payload teams (`python/`, `m6p`): it installs with pip, and its
//! own tests (pytest: libcsp 1.4's vectors, the ICD codecs, and whole payload sessions
//! against this build's twin over KISS/TCP and the ZMQ hub) pass, the plugin's fixtures
//! loaded from the installed package as a user's pytest loads them.
//!
//! A copy of `python/` is installed into a temporary directory (`pip install --target`),
//! so the source tree gets no build files. About 15 s, half of it pip.
#![allow(clippy::unwrap_used)]

use std::process::Command;

mod common;

#[test]
#[cfg_attr(
    not(python_pytest),
    ignore = "needs python3 with pytest and pyzmq (pip install pytest pyzmq; .ci/run installs them)"
)]
fn the_python_package_installs_and_its_tests_pass_against_this_twin() {
    let dir = std::env::temp_dir().join(format!("m6p-python-{}", std::process::id()));
    let (src, site) = (dir.join("src"), dir.join("site"));
    std::fs::remove_dir_all(&dir).ok();
    std::fs::create_dir_all(&src).unwrap();
    let python = common::repo_root().join("python");
    let copied = Command::new("cp")
        .arg("-r")
        .arg(python.join("pyproject.toml"))
        .arg(python.join("README.md"))
        .arg(python.join("src"))
        .arg(&src)
        .status()
        .unwrap();
    assert!(copied.success());
    let pip = Command::new("python3")
        .args(["-m", "pip", "install", "--quiet", "--no-deps", "--target"])
        .arg(&site)
        .arg(&src)
        .output()
        .unwrap();
    assert!(
        pip.status.success(),
        "pip install ./python failed:\n{}{}",
        String::from_utf8_lossy(&pip.stdout),
        String::from_utf8_lossy(&pip.stderr)
    );
    // From a directory outside the checkout, so that nothing but the installed package
    // (and the tests' own files) is imported; the plugin comes from its entry point.
    let out = Command::new("python3")
        .args([
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-W",
            "error",
        ])
        .arg(python.join("tests"))
        .env("PYTHONPATH", &site)
        .env("M6P_TWIN", env!("CARGO_BIN_EXE_m6p-twin"))
        .env_remove("PYTEST_ADDOPTS")
        .current_dir(&dir)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{text}");
    std::fs::remove_dir_all(&dir).ok();
    assert!(out.status.success(), "pytest python/tests failed:\n{text}");
    assert!(text.contains(" passed"), "{text}");
    for word in ["skipped", "xfail", "deselected", "error"] {
        assert!(!text.contains(word), "pytest said `{word}`:\n{text}");
    }
}
