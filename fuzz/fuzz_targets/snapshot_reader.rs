//! `snapshot_reader`: the snapshot file's reader on arbitrary bytes
//! (`m6p_twin::snapshot_file::SnapshotFile::decode`), then its build and scenario check.
//!
//! Asserts: nothing panics; every problem is an `Err` naming the file; what is read, written
//! again, reads back the same.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use m6p_twin::snapshot_file::SnapshotFile;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.snap");
    match SnapshotFile::decode(path, data) {
        Ok(s) => {
            let again = SnapshotFile::decode(path, &s.encode()).expect("written again, read");
            assert_eq!(again, s);
            let _ = s.check(path, "this build", Some(("default", "name = \"default\"")));
        }
        Err(e) => assert!(e.to_string().starts_with("fuzz.snap: "), "{e}"),
    }
});
