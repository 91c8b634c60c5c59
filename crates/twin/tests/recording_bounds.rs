//! Reading a damaged recording is bounded: a truncated file or one whose length fields were
//! mutated gives an error (or the part that could be read), never a huge allocation. A
//! global allocator wrapper notes, per thread, the largest single request while reading.
#![allow(clippy::unwrap_used)]
// The only unsafe code of the project: a test's allocator that forwards to the system's and
// notes sizes; nothing else can see an allocation's size.
#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use bus::trace::{TraceEvent, TraceFrame};
use common::TempFile;
use csp::cfp::fragment_with_ident;
use csp::{Header, Packet, SimTime};
use m6p_twin::events::RunEvent;
use m6p_twin::record::{Recorder, RecordingMeta};
use m6p_twin::recording;

struct Tracking;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: every call is forwarded to the system allocator unchanged; the wrapper only reads
// the layout's size into a thread-local `Cell` (no allocation, no reentrancy).
unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

#[global_allocator]
static ALLOC: Tracking = Tracking;

/// Read `path` every way the CLI does (inspect's summary, meta, messages, CSV, diff with
/// itself); the largest single allocation made meanwhile.
fn largest_allocation_reading(path: &Path) -> usize {
    LARGEST.with(|l| l.set(0));
    let _ = recording::read_summary(path);
    let _ = recording::load_meta(path);
    if let Ok(msgs) = recording::messages(path) {
        for m in msgs {
            if m.is_err() {
                break;
            }
        }
    }
    LARGEST.with(Cell::get)
}

/// The same, also through CSV export and diff (the same reader underneath).
fn largest_allocation_every_way(path: &Path) -> usize {
    let first = largest_allocation_reading(path);
    LARGEST.with(|l| l.set(0));
    let _ = recording::export_csv(path, "/can/main/frames", &mut std::io::sink());
    let _ = recording::diff(path, path);
    first.max(LARGEST.with(Cell::get))
}

fn small_recording(path: &Path) {
    let meta = RecordingMeta {
        scenario_name: "bounds".into(),
        scenario_toml: "name = \"bounds\"\nduration = \"1s\"\n".into(),
        seed: 7,
        start_utc: "2026-01-01T00:00:00Z".into(),
        twin_version: "test".into(),
        duration_ns: Some(1_000_000_000),
        replaced: Vec::new(),
        link_addrs: Default::default(),
        link_tx_budgets: Default::default(),
        channels: Vec::new(),
    };
    let mut r = Recorder::create(path, meta, m6p_twin::record::Existing::Replace).unwrap();
    let mut t = SimTime::ZERO;
    for i in 0..20u8 {
        let p = Packet::new(Header::new(16, 3, 1, 40), vec![i; 20]);
        let mut frames = Vec::new();
        fragment_with_ident(&p, 3, u16::from(i), &mut frames).unwrap();
        for f in frames {
            t = t + std::time::Duration::from_micros(130);
            r.write(&RunEvent::Medium(TraceEvent {
                t,
                medium: "main".into(),
                from: "COMM1".into(),
                frame: TraceFrame::Can(f),
                dropped: false,
            }))
            .unwrap();
        }
    }
    r.finish().unwrap();
}

/// 4-byte windows of a small recording overwritten with huge lengths (all ones, 2 GiB,
/// 256 MiB, 64 MiB, 16 MiB): each read ends in an error or a partial read, and no single
/// allocation exceeds 8 MiB (the file is a few KB; a chunk is at most about 4 MiB): a
/// reader trusting a string's length prefix inside a record would ask for 4 GiB.
#[test]
fn mutated_length_fields_give_errors_not_allocations() {
    let f = TempFile::new("bounds-src");
    small_recording(f.path());
    let bytes = std::fs::read(f.path()).unwrap();
    assert!(bytes.len() < 32 * 1024, "{}", bytes.len());
    let clean = largest_allocation_reading(f.path());
    let m = TempFile::new("bounds-mut");
    let mut worst = (0usize, 0usize, [0u8; 4]);
    // Every window over the records before the first chunk (header, metadata, scenario
    // attachment) and the chunk headers; every seventh one further on (a chunk's body is
    // guarded by its CRC).
    let windows = (8..bytes.len().saturating_sub(4)).filter(|&o| o < 1500 || o % 7 == 0);
    for off in windows {
        for val in [
            [0xff, 0xff, 0xff, 0xff],
            [0x00, 0x00, 0x00, 0x80],
            [0x00, 0x00, 0x00, 0x10],
            [0x00, 0x00, 0x00, 0x04],
            [0x00, 0x00, 0x00, 0x01],
        ] {
            let mut b = bytes.clone();
            b[off..off + 4].copy_from_slice(&val);
            std::fs::write(m.path(), &b).unwrap();
            let largest = largest_allocation_reading(m.path());
            if largest > worst.0 {
                worst = (largest, off, val);
            }
        }
    }
    assert!(
        worst.0 <= 8 << 20,
        "largest allocation {} bytes with {:02x?} at offset {} (clean file: {clean})",
        worst.0,
        worst.2,
        worst.1
    );
}

/// A recording cut anywhere, and one whose record length points far beyond its end: errors
/// naming where, and no allocation of the claimed length.
#[test]
fn a_record_length_beyond_the_file_is_an_error_naming_the_offset() {
    let f = TempFile::new("bounds-len");
    small_recording(f.path());
    let mut bytes = std::fs::read(f.path()).unwrap();
    // The header record: opcode at 8, its u64 length at 9..17. Claim 100 MiB.
    bytes[9..17].copy_from_slice(&(100u64 << 20).to_le_bytes());
    std::fs::write(f.path(), &bytes).unwrap();
    let largest = largest_allocation_every_way(f.path());
    assert!(largest <= 8 << 20, "largest allocation {largest}");
    let e = format!("{:#}", recording::load_meta(f.path()).unwrap_err());
    assert!(e.contains("offset"), "{e}");
    let cut = TempFile::new("bounds-cut");
    small_recording(cut.path());
    let whole = std::fs::read(cut.path()).unwrap();
    for len in (0..whole.len()).step_by(7) {
        std::fs::write(cut.path(), &whole[..len]).unwrap();
        let largest = largest_allocation_reading(cut.path());
        assert!(
            largest <= 8 << 20,
            "cut at {len}: largest allocation {largest}"
        );
    }
}

/// A small MCAP file written by the mcap crate with uncompressed chunks (the recorder's
/// are zstd): a JSON channel and five messages.
fn uncompressed_recording(path: &Path) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .create(file)
        .unwrap();
    let schema = w.add_schema("m6p.Test", "jsonschema", b"{}").unwrap();
    let channel = w
        .add_channel(schema, "/test", "json", &Default::default())
        .unwrap();
    for i in 0..5u32 {
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: i,
            log_time: u64::from(i) * 1000,
            publish_time: u64::from(i) * 1000,
        };
        w.write_to_known_channel(&header, format!("{{\"i\":{i}}}").as_bytes())
            .unwrap();
    }
    w.finish().unwrap();
}

/// Every message of `path` up to the first error, and that error.
fn read_all(path: &Path) -> (Vec<recording::RecordedMessage>, Option<String>) {
    let mut got = Vec::new();
    for m in recording::messages(path).unwrap() {
        match m {
            Ok(m) => got.push(m),
            Err(e) => return (got, Some(format!("{e:#}"))),
        }
    }
    (got, None)
}

/// Uncompressed chunks are read like compressed ones.
#[test]
fn uncompressed_chunks_are_read() {
    let f = TempFile::new("bounds-plain");
    uncompressed_recording(f.path());
    let (got, err) = read_all(f.path());
    assert_eq!(err, None);
    let data: Vec<_> = got.iter().map(|m| m.data.as_slice()).collect();
    assert_eq!(data[0], b"{\"i\":0}");
    assert_eq!(data.len(), 5);
    assert!(
        got.iter()
            .all(|m| &*m.topic == "/test" && &*m.schema == "m6p.Test")
    );
}

/// A record inside an uncompressed chunk whose length runs past the end of its chunk is an
/// error naming where. The mcap crate's reader subtracted the record's length from what is
/// left of the chunk without a check: an overflow panic in debug builds (`m6p-twin inspect`
/// exited 101), a read past the chunk in release builds. Found by `fuzz/`'s `mcap_reader`;
/// its two inputs are in tests/data/mcap.
#[test]
fn a_chunk_record_running_past_its_chunk_is_an_error() {
    let f = TempFile::new("bounds-chunk");
    uncompressed_recording(f.path());
    let mut bytes = std::fs::read(f.path()).unwrap();
    // The chunk: opcode 0x06 after the header record; its records follow a fixed part of
    // 8 + 8 + 8 + 4 bytes, the compression string (empty: 4 bytes) and the records' u64
    // length. The first inner record's length claims 64 bytes more than the chunk has.
    let header_len = u64::from_le_bytes(bytes[9..17].try_into().unwrap()) as usize;
    let chunk = 8 + 1 + 8 + header_len;
    assert_eq!(bytes[chunk], 0x06);
    let records = chunk + 1 + 8 + 8 + 8 + 8 + 4 + 4 + 8;
    let records_len = u64::from_le_bytes(bytes[records - 8..records].try_into().unwrap());
    let inner_len = records_len - 9 + 64;
    bytes[records + 1..records + 9].copy_from_slice(&inner_len.to_le_bytes());
    // The chunk's CRC (over its uncompressed records) would catch the change; 0 means none.
    bytes[chunk + 1 + 8 + 24..chunk + 1 + 8 + 28].copy_from_slice(&[0; 4]);
    std::fs::write(f.path(), &bytes).unwrap();
    let (got, err) = read_all(f.path());
    assert!(got.is_empty());
    let err = err.expect("an error");
    assert!(err.contains("chunk") && err.contains("offset"), "{err}");
    assert!(recording::load_meta(f.path()).is_err());
    let summary = recording::read_summary(f.path()).unwrap();
    assert!(summary.incomplete.is_some_and(|e| e.contains("chunk")));

    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/mcap");
    for name in [
        "fuzz-chunk-record-past-chunk.bin",
        "fuzz-chunk-record-past-chunk-2.bin",
    ] {
        let path = dir.join(name);
        let (_, err) = read_all(&path);
        assert!(err.is_some(), "{name}");
        assert!(recording::load_meta(&path).is_err(), "{name}");
        let _ = recording::read_summary(&path);
    }
}
