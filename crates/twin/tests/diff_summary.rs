//! `m6p-twin diff` past the first divergence: a line per medium channel (messages in each
//! recording, how many differ, where the first difference is) and `--all`, which lists
//! every divergence of every channel by time up to `--max`.
#![allow(clippy::unwrap_used)]

mod common;

use common::TempFile;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use bus::trace::{TraceEvent, TraceFrame};
use csp::{Header, Packet, SimTime};
use m6p_twin::events::{Direction, RunEvent};
use m6p_twin::record::RecordingMeta;
use m6p_twin::recording;

const KISS: &str = "/kiss/listen_127.0.0.1:52001/in";

fn meta() -> RecordingMeta {
    common::meta("diff-summary", 1)
}

/// A ground packet GS16 -> FC (3) at `t_ms` whose one data byte is `tag`.
fn ground(t_ms: u64, tag: u8) -> RunEvent {
    let p = Packet::new(Header::new(16, 3, 1, 40), vec![tag]);
    RunEvent::Medium(TraceEvent {
        t: SimTime::from_ns(t_ms * 1_000_000),
        medium: Arc::from("ground"),
        from: Arc::from("GS16"),
        frame: TraceFrame::Packet(p.to_bytes()),
        dropped: false,
    })
}

/// A KISS frame in from the outside program at `t_ms`, carrying `tag`.
fn kiss(t_ms: u64, tag: u8) -> RunEvent {
    RunEvent::Kiss {
        t: SimTime::from_ns(t_ms * 1_000_000),
        link: "listen 127.0.0.1:52001".into(),
        dir: Direction::In,
        bytes: vec![0xC0, 0x00, tag, 0xC0],
    }
}

fn twin(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(args)
        .current_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.."))
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn diff(a: &Path, b: &Path, extra: &[&str]) -> (i32, String) {
    let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());
    let (code, out, err) = twin(&[&["diff", a, b], extra].concat());
    (code, format!("{out}{err}"))
}

/// The summary's line for `channel`, as words.
fn channel_line<'a>(out: &'a str, channel: &str) -> Vec<&'a str> {
    out.lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .find(|w| w.first() == Some(&channel))
        .unwrap_or_else(|| panic!("no summary line for {channel}:\n{out}"))
}

/// The `t = ... s on CHANNEL (message N)` headings of an `--all` listing, in order.
fn listed(out: &str) -> Vec<&str> {
    out.lines()
        .filter(|l| l.starts_with("  t = "))
        .map(str::trim)
        .collect()
}

#[test]
fn diff_summarises_each_channel_and_lists_every_divergence() {
    // A: four ground packets and two KISS frames. B: ground packets 1 and 3 changed and a
    // fifth added; the second KISS frame changed.
    let ev_a = vec![
        ground(1000, 0),
        kiss(1500, 0x10),
        ground(2000, 1),
        kiss(2500, 0x11),
        ground(3000, 2),
        ground(4000, 3),
    ];
    let ev_b = vec![
        ground(1000, 0),
        kiss(1500, 0x10),
        ground(2000, 0x81),
        kiss(2500, 0x91),
        ground(3000, 2),
        ground(4000, 0x83),
        ground(5000, 4),
    ];
    let (a, b) = (TempFile::new("sum-a"), TempFile::new("sum-b"));
    common::record(a.path(), meta(), &ev_a);
    common::record(b.path(), meta(), &ev_b);

    // The library: typed per-channel rows, the first divergence as `diff` has it.
    let s = recording::diff_summary(a.path(), b.path(), 10).unwrap();
    assert_eq!(s.result, recording::diff(a.path(), b.path()).unwrap());
    let rows: Vec<_> = s
        .channels
        .iter()
        .map(|c| {
            (
                c.channel.as_str(),
                c.expected,
                c.actual,
                c.differing,
                c.first.map(|p| (p.index, p.t_ns)),
            )
        })
        .collect();
    assert_eq!(
        rows,
        [
            ("/ground/packets", 4, 5, 3, Some((1, 2_000_000_000))),
            (KISS, 2, 2, 1, Some((1, 2_500_000_000))),
        ]
    );
    assert_eq!(s.differing(), 4);

    // The command: the first divergence in detail as before, then a line per channel.
    let (code, out) = diff(a.path(), b.path(), &[]);
    assert_eq!(code, 1, "{out}");
    assert!(
        out.starts_with(
            "first divergence at t = 2.000000000 s on /ground/packets (message 1 of that channel)"
        ),
        "{out}"
    );
    assert!(out.contains("\n  expected: "), "{out}");
    assert!(
        out.contains("\nper channel (expected = A, actual = B):\n"),
        "{out}"
    );
    assert_eq!(
        channel_line(&out, "channel"),
        [
            "channel",
            "expected",
            "actual",
            "differing",
            "first",
            "divergence"
        ]
    );
    assert_eq!(
        channel_line(&out, "/ground/packets"),
        [
            "/ground/packets",
            "4",
            "5",
            "3",
            "message",
            "1",
            "at",
            "t",
            "=",
            "2.000000000",
            "s"
        ]
    );
    assert_eq!(
        channel_line(&out, KISS),
        [
            KISS,
            "2",
            "2",
            "1",
            "message",
            "1",
            "at",
            "t",
            "=",
            "2.500000000",
            "s"
        ]
    );
    assert!(listed(&out).is_empty(), "no listing without --all: {out}");

    // --all: every divergence of both channels, by time, each with both messages.
    let (code, out) = diff(a.path(), b.path(), &["--all"]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("\nall 4 divergences, by time:\n"), "{out}");
    assert_eq!(
        listed(&out),
        [
            "t = 2.000000000 s on /ground/packets (message 1)",
            &format!("t = 2.500000000 s on {KISS} (message 1)"),
            "t = 4.000000000 s on /ground/packets (message 3)",
            "t = 5.000000000 s on /ground/packets (message 4)",
        ]
    );
    assert_eq!(out.matches("\n    expected: ").count(), 4, "{out}");
    // The fifth packet exists only in B.
    assert!(
        out.contains("    expected: (end of recording)\n    actual:   t=5.000000000s from GS16"),
        "{out}"
    );

    // --max bounds the listing: the earliest ones, and the total said.
    let (code, out) = diff(a.path(), b.path(), &["--all", "--max", "2"]);
    assert_eq!(code, 1, "{out}");
    assert!(
        out.contains("\nthe first 2 of 4 divergences, by time:\n"),
        "{out}"
    );
    assert_eq!(listed(&out).len(), 2, "{out}");
    assert!(listed(&out)[1].contains(KISS), "{out}");
    // --max means nothing without --all: a usage error.
    let (code, out) = diff(a.path(), b.path(), &["--max", "2"]);
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("--all"), "{out}");

    // Identical recordings: exit 0, every channel `identical`.
    let (code, out) = diff(a.path(), a.path(), &["--all"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.starts_with("identical (6 medium messages)\n"), "{out}");
    assert_eq!(
        channel_line(&out, "/ground/packets"),
        ["/ground/packets", "4", "4", "0", "identical"]
    );
    assert_eq!(channel_line(&out, KISS), [KISS, "2", "2", "0", "identical"]);
    assert!(listed(&out).is_empty(), "{out}");
}

#[test]
fn diff_of_two_seeds_names_every_differing_channel_with_its_counts() {
    // Another seed changes the CFP idents on the CAN bus and the CSP ports of the ground
    // packets: both medium channels of node-faults differ.
    let (a, b) = (TempFile::new("seed-1"), TempFile::new("seed-2"));
    for (seed, f) in [("1", &a), ("2", &b)] {
        let (code, out, err) = twin(&[
            "run",
            "scenarios/node-faults.toml",
            "--seed",
            seed,
            "--record",
            f.path().to_str().unwrap(),
        ]);
        assert_eq!(code, 0, "{out}{err}");
    }
    let counts = |p: &Path| recording::read_summary(p).unwrap().channels;
    let (ca, cb) = (counts(a.path()), counts(b.path()));
    let count = |c: &[recording::ChannelSummary], topic: &str| {
        c.iter()
            .find(|c| c.topic == topic)
            .map_or(0, |c| c.messages)
    };

    let (code, out) = diff(a.path(), b.path(), &[]);
    assert_eq!(code, 1, "{out}");
    assert!(out.starts_with("first divergence at t = "), "{out}");
    let mut total = 0;
    for topic in ["/can/main/frames", "/ground/packets"] {
        let w = channel_line(&out, topic);
        let (n_a, n_b) = (count(&ca, topic), count(&cb, topic));
        assert!(n_a > 0, "{topic} recorded nothing");
        assert_eq!(w[1], n_a.to_string(), "{out}");
        assert_eq!(w[2], n_b.to_string(), "{out}");
        let differing: u64 = w[3].parse().unwrap();
        assert!(differing > 0 && differing <= n_a.max(n_b), "{out}");
        total += differing;
        assert_eq!(w[4..6], ["message", "0"], "{out}");
    }

    // --all lists more than one divergence, across both channels, in time order.
    let (code, out) = diff(a.path(), b.path(), &["--all"]);
    assert_eq!(code, 1, "{out}");
    let shown = listed(&out);
    assert_eq!(shown.len() as u64, total.min(100), "{out}");
    assert!(shown.len() > 1, "{out}");
    assert!(
        shown.iter().any(|l| l.contains("/can/main/frames")),
        "{out}"
    );
    assert!(shown.iter().any(|l| l.contains("/ground/packets")), "{out}");
    let times: Vec<f64> = shown
        .iter()
        .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
        .collect();
    assert!(times.is_sorted(), "{out}");
}

/// `diff --from T`: what two recordings hold before T is left out of both; they are
/// identical from the instant after their last difference on, and the first divergence
/// after T is found and indexed from T.
#[test]
fn diff_from_compares_what_both_hold_from_an_instant_on() {
    let ev_a = vec![
        ground(1000, 0),
        ground(2000, 1),
        ground(3000, 2),
        ground(4000, 3),
    ];
    let ev_b = vec![
        ground(1000, 9),
        ground(2000, 1),
        ground(3000, 2),
        ground(4000, 8),
    ];
    let (a, b) = (TempFile::new("from-a"), TempFile::new("from-b"));
    common::record(a.path(), meta(), &ev_a);
    common::record(b.path(), meta(), &ev_b);
    let from =
        |ms: u64| recording::diff_summary_from(a.path(), b.path(), 0, ms * 1_000_000).unwrap();
    assert_eq!(from(0).differing(), 2);
    let s = from(1500);
    assert_eq!(s.differing(), 1, "{s}");
    let c = &s.channels[0];
    assert_eq!((c.expected, c.actual), (3, 3));
    assert_eq!(c.first.map(|p| (p.index, p.t_ns)), Some((2, 4_000_000_000)));
    assert!(from(4001).result.is_identical());
    let (code, out) = diff(a.path(), b.path(), &["--from", "1.5s"]);
    assert_eq!(code, 1, "{out}");
    assert!(out.starts_with("from t = 1.5s on\n"), "{out}");
    assert!(out.contains("message 2 at t = 4.000000000 s"), "{out}");
    let (code, out) = diff(a.path(), b.path(), &["--from", "4.5s"]);
    assert_eq!(code, 0, "{out}");
}
