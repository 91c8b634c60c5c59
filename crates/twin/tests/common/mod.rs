//! Helpers shared by the recording tests: temporary MCAP files, writing events to a
//! recording and reading a channel back, and running `tests/decode_mcap.py` (the independent
//! Python reader) on a recording; the outside-payload scenario of `examples/README.md`.
// Each test binary uses a part of these.
#![allow(dead_code)]

pub mod outside;
pub mod twin_process;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

/// A unique path in the temp dir, removed when dropped.
pub struct TempFile(pub PathBuf);

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

/// Record `events` to `path` with `meta`, and the packets they complete.
pub fn record(
    path: &Path,
    meta: m6p_twin::record::RecordingMeta,
    events: &[m6p_twin::events::RunEvent],
) -> m6p_twin::record::RecordingStats {
    let mut r = m6p_twin::record::Recorder::create(path, meta, m6p_twin::record::Existing::Replace)
        .unwrap();
    // With the packets each event completes, as a run that records hands them out.
    for e in &m6p_twin::packets::with_packets(events.iter().cloned()) {
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

/// The data stream of the script (`frame_data` in examples/outside_payload.py), written
/// again here from its description: frame `seq` is `seq` u16 LE then a byte counter from
/// `seq`, `frame_size - (seq % 3) * (frame_size / 3)` bytes long (at least 1).
pub fn expected_stream(frames: u32, frame_size: usize) -> Vec<u8> {
    let mut out = Vec::new();
    for seq in 0..frames {
        let len = frame_size
            .saturating_sub((seq as usize % 3) * (frame_size / 3))
            .max(1);
        let mut frame = (seq as u16).to_le_bytes().to_vec();
        frame.extend((0..len).map(|i| (seq as usize + i) as u8));
        frame.truncate(len);
        out.extend(frame);
    }
    out
}

/// Assert `a == b`, naming the first differing byte rather than printing kilobytes.
pub fn same_bytes(what_a: &str, a: &[u8], what_b: &str, b: &[u8]) {
    if let Some(i) = a.iter().zip(b).position(|(x, y)| x != y) {
        panic!("byte {i}: {what_a} {:#04x}, {what_b} {:#04x}", a[i], b[i]);
    }
    assert_eq!(a.len(), b.len(), "{what_a} vs {what_b}: lengths differ");
}

/// Session `session` ran once in `report` and ended DONE after `packets` packets.
pub fn assert_one_session_done(report: &m6p_twin::report::RunReport, session: u8, packets: u32) {
    let runs: Vec<_> = report
        .sessions
        .runs
        .iter()
        .filter(|r| r.session == session)
        .collect();
    assert_eq!(runs.len(), 1, "{:?}", report.sessions.runs);
    assert!(runs[0].started.is_some());
    let (_, result, n) = runs[0]
        .ended
        .unwrap_or_else(|| panic!("session {session} ended within the run"));
    assert_eq!(
        (result, n),
        (
            m6p_twin::sessions::RunEnd::Result(nodes_pc::SessionResult::Done),
            packets
        ),
        "expected DONE after {packets} packets"
    );
}

/// The metadata of a recording a test writes itself: scenario `name`, `seed`.
pub fn meta(name: &str, seed: u64) -> m6p_twin::record::RecordingMeta {
    m6p_twin::record::RecordingMeta {
        scenario_name: name.into(),
        scenario_toml: format!("name = \"{name}\"\nseed = {seed}\n"),
        seed,
        start_utc: "2026-03-20T12:00:00Z".into(),
        twin_version: "0.1.0".into(),
        duration_ns: None,
        replaced: Vec::new(),
        link_addrs: Default::default(),
        link_tx_budgets: Default::default(),
        channels: Vec::new(),
    }
}

/// Session 4 (payload 14) polls for 60 s from 5 s of a 90 s run: some 600 packets and
/// 60 kB downlinked, in a fraction of a second.
pub const ONE_SESSION_SCENARIO: &str = r#"
name = "inspect-sessions"
duration = "90s"
seed = 3

[network]
payloads = [12, 14]

[[pc.sessions]]
id = 4
payload = 14
mode = "polling"

[[commands]]
name = "setup-4"
at = "5s"
to = "PC"
command = "PC.SETUP"
args = { session_id = 4, timestamp = "now", duration_s = 60, max_packets = "no limit", poll_frame_size = 100, sync_message = "go" }
"#;

/// `m6p-twin ARGS` in the repository, with no `RUST_LOG` or `CI` of the caller's: exit
/// code, stdout, stderr.
pub fn twin_cli(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .current_dir(repo_root())
        .env_remove("RUST_LOG")
        .env_remove("CI")
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
