//! Helpers shared by the recording tests: temporary MCAP files, writing events to a
//! recording and reading a channel back, and running `tests/decode_mcap.py` (the independent
//! Python reader) on a recording; the outside-payload scenario of `examples/README.md`.
// Each test binary uses a part of these.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

/// A unique path in the temp dir, removed when dropped.
pub struct TempFile(PathBuf);

impl TempFile {
    /// `m6p-twin-<pid>-<name>-<n>.mcap` in the temp dir.
    pub fn new(name: &str) -> TempFile {
        static N: AtomicU32 = AtomicU32::new(0);
        let n = N.fetch_add(1, Ordering::Relaxed);
        TempFile(
            std::env::temp_dir().join(format!("m6p-twin-{}-{name}-{n}.mcap", std::process::id())),
        )
    }

    /// The path.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The script's standard output for `mcap_file`, after asserting it succeeded. Needs
/// `python3` with the `mcap` package: tests calling it are ignored where the build probe
/// did not find it (`cfg(python_mcap)`, `build.rs`), and fail in CI if it is missing.
pub fn decode(mcap_file: &Path) -> String {
    assert_python_mcap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/decode_mcap.py");
    let out = std::process::Command::new("python3")
        .arg(&script)
        .arg(mcap_file)
        .output()
        .expect("running python3");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// Fail, naming what to install, when `python3` cannot import the `mcap` package.
pub fn assert_python_mcap() {
    let have = std::process::Command::new("python3")
        .args(["-c", "import mcap.reader"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        have,
        "this test needs python3 with the `mcap` package: pip install mcap (.ci/run installs it)"
    );
}

/// Record `events` to `path` with `meta`.
pub fn record(
    path: &Path,
    meta: m6p_twin::record::RecordingMeta,
    events: &[m6p_twin::events::RunEvent],
) -> m6p_twin::record::RecordingStats {
    let mut r = m6p_twin::record::Recorder::create(path, meta).unwrap();
    for e in events {
        r.write(e).unwrap();
    }
    r.finish().unwrap()
}

/// The messages of `topic` in the recording at `path`, in file order.
pub fn on(path: &Path, topic: &str) -> Vec<m6p_twin::recording::RecordedMessage> {
    m6p_twin::recording::messages(path)
        .unwrap()
        .map(Result::unwrap)
        .filter(|m| &*m.topic == topic)
        .collect()
}

/// The repository's root.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The scenario of `examples/README.md`: the text of its `cat > ... <<'EOF'` block.
pub fn readme_scenario() -> String {
    let readme = std::fs::read_to_string(repo_root().join("examples/README.md")).unwrap();
    let start = readme
        .find("<<'EOF'\n")
        .expect("a <<'EOF' block in examples/README.md")
        + 8;
    let len = readme[start..]
        .find("\nEOF\n")
        .expect("the block's closing EOF");
    readme[start..start + len].to_owned()
}
