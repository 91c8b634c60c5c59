//! A recorded run resumed from a snapshot (docs/snapshots.md) records what the run it was
//! taken from recorded after that point, byte for byte: the same messages, in the same
//! order, on channels with the same ids, with the same sequence numbers, log and publish
//! times and bytes; `diff --from T` finds the two identical.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::time::Duration;

use csp::SimTime;
use m6p_twin::exec::{RecordTo, compile_seeded, execute_recorded, load};
use m6p_twin::runtime::build_runtime_for;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// One message as the file holds it: channel id and topic, sequence, log and publish
/// times, bytes.
type Raw = (u16, String, u32, u64, u64, Vec<u8>);

fn raw_messages(path: &Path) -> Vec<Raw> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            (
                m.channel.id,
                m.channel.topic.clone(),
                m.sequence,
                m.log_time,
                m.publish_time,
                m.data.to_vec(),
            )
        })
        .collect()
}

/// A message without its bytes.
fn head(m: &Raw) -> (u16, &str, u32, u64, u64, usize) {
    (m.0, &m.1, m.2, m.3, m.4, m.5.len())
}

/// Run scenario `name` recorded to `dir/NAME.plain.mcap`; then again to
/// `dir/NAME.whole.mcap`, taking a snapshot at `at`; then from that snapshot recorded to
/// `dir/NAME.resumed.mcap`; the three recordings.
fn record_three(name: &str, span: Option<Duration>, at: SimTime, dir: &Path) -> [PathBuf; 3] {
    let loaded = load(&repo().join("scenarios").join(name)).unwrap();
    let snapshot = dir.join(format!("{name}.snap"));
    let plain = dir.join(format!("{name}.plain.mcap"));
    let whole = dir.join(format!("{name}.whole.mcap"));
    let resumed = dir.join(format!("{name}.resumed.mcap"));
    let mut compiled = compile_seeded(&loaded, None);
    if span.is_some() {
        compiled.opts.duration = span;
    }
    build_runtime_for(&compiled.opts)
        .unwrap()
        .block_on(execute_recorded(
            &loaded,
            compiled.clone(),
            Some(RecordTo::new(&plain)),
        ))
        .unwrap()
        .1
        .unwrap()
        .unwrap();
    let mut taking = compiled.clone();
    taking.opts.snapshot_at = vec![at];
    taking.opts.snapshot_to = Some(snapshot.clone());
    build_runtime_for(&taking.opts)
        .unwrap()
        .block_on(execute_recorded(
            &loaded,
            taking,
            Some(RecordTo::new(&whole)),
        ))
        .unwrap()
        .1
        .unwrap()
        .unwrap();
    let mut from = compiled;
    from.opts.resume = Some(
        m6p_twin::snapshots::resume_from(&snapshot, (&loaded.name(), &loaded.text), from.opts.seed)
            .unwrap(),
    );
    build_runtime_for(&from.opts)
        .unwrap()
        .block_on(execute_recorded(
            &loaded,
            from,
            Some(RecordTo::new(&resumed)),
        ))
        .unwrap()
        .1
        .unwrap()
        .unwrap();
    [plain, whole, resumed]
}

/// Taking the snapshot changes no message of the recording; the resumed recording's
/// messages are the last ones of the whole run's, and those before them were logged before
/// the snapshot's instant.
fn records_the_rest(name: &str, span: Option<Duration>, at: SimTime, dir: &Path) {
    let [plain, whole, resumed] = record_three(name, span, at, dir);
    let (a, b) = (raw_messages(&whole), raw_messages(&resumed));
    assert!(
        raw_messages(&plain) == a,
        "{name}: taking a snapshot changed the recording"
    );
    assert!(!b.is_empty(), "{name}: the resumed run recorded nothing");
    assert!(
        b.len() <= a.len(),
        "{name}: {} messages resumed, {} in all",
        b.len(),
        a.len()
    );
    let split = a.len() - b.len();
    let first_diff = a[split..].iter().zip(&b).position(|(x, y)| x != y);
    assert!(
        first_diff.is_none(),
        "{name} from {at}: message {} of the resumed recording differs:\n  whole:   {:?}\n  resumed: {:?}",
        first_diff.unwrap_or(0),
        first_diff.map(|i| head(&a[split + i])),
        first_diff.map(|i| head(&b[i])),
    );
    let meta = m6p_twin::recording::load_meta(&whole).unwrap();
    let base = m6p_twin::record::start_ns(&meta.start_utc).unwrap();
    if let Some(last_before) = split.checked_sub(1) {
        assert!(
            a[last_before].3 < base + at.as_ns(),
            "{name}: a message written before the snapshot's point is logged at or after it"
        );
    }
    let d = m6p_twin::recording::diff_summary_from(&whole, &resumed, 0, at.as_ns()).unwrap();
    assert!(d.is_identical(), "{name}: diff --from {at}:\n{d}");
}

#[test]
fn the_default_scenario_resumed_records_the_rest_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    records_the_rest(
        "default.toml",
        Some(Duration::from_secs(1200)),
        SimTime::from_ms(777_777),
        dir.path(),
    );
}

/// Every shipped scenario, recorded from its midpoint.
#[test]
fn every_shipped_scenario_resumed_from_its_midpoint_records_the_rest_byte_for_byte() {
    let mut names: Vec<String> = std::fs::read_dir(repo().join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 25);
    let dir = tempfile::tempdir().unwrap();
    for name in names {
        let loaded = load(&repo().join("scenarios").join(&name)).unwrap();
        let length = compile_seeded(&loaded, None).opts.duration.unwrap();
        let mid = SimTime::from_ns(u64::try_from(length.as_nanos() / 2).unwrap());
        let started = std::time::Instant::now();
        records_the_rest(&name, None, mid, dir.path());
        eprintln!("{name}: {:.1} s", started.elapsed().as_secs_f64());
    }
}
