//! `mcap_reader`: the twin's recording reader on arbitrary bytes written to a file (one
//! temporary file per fuzz process, reused; under /dev/shm when there is one, else the
//! temporary directory; files of finished fuzz processes are removed):
//! `m6p_twin::recording::messages(path)` iterated to its end (each message described as
//! `m6p-twin inspect` would), `recording::load_meta` and `recording::read_summary`.
//!
//! Asserts: nothing panics, every problem is an `Err`; an error ends the message stream
//! (nothing follows it).
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use m6p_twin::recording;

/// This process's file: `m6p-fuzz-mcap-<pid>.mcap`. The first call also removes the files
/// of fuzz processes that are gone (libFuzzer exits without running destructors, and fork
/// mode starts a process per job).
fn path() -> &'static PathBuf {
    static PATH: OnceLock<PathBuf> = OnceLock::new();
    PATH.get_or_init(|| {
        let shm = PathBuf::from("/dev/shm");
        let dir = if shm.is_dir() {
            shm
        } else {
            std::env::temp_dir()
        };
        if let Ok(entries) = std::fs::read_dir(&dir) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                let pid = name
                    .strip_prefix("m6p-fuzz-mcap-")
                    .and_then(|n| n.strip_suffix(".mcap"))
                    .and_then(|n| n.parse::<u32>().ok());
                if let Some(pid) = pid
                    && !PathBuf::from(format!("/proc/{pid}")).exists()
                {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        dir.join(format!("m6p-fuzz-mcap-{}.mcap", std::process::id()))
    })
}

fuzz_target!(|data: &[u8]| {
    let path = path();
    std::fs::write(path, data).expect("write the temporary recording");

    if let Ok(messages) = recording::messages(path) {
        let mut failed = false;
        for m in messages {
            assert!(!failed, "a message after an error");
            match m {
                Ok(m) => {
                    let _ = recording::describe(&m);
                }
                Err(e) => {
                    let _ = format!("{e:#}");
                    failed = true;
                }
            }
        }
    }
    if let Err(e) = recording::load_meta(path) {
        let _ = format!("{e:#}");
    }
    match recording::read_summary(path) {
        Ok(s) => {
            let _ = s.scenario_name();
        }
        Err(e) => {
            let _ = format!("{e:#}");
        }
    }
});
