//! Recording to MCAP and reading it back: determinism, diff, decoded CSP packets equal to
//! the bytes on the bus, summary, CSV, truncated and foreign files, and a generic reader
//! (the `mcap` Python package) decoding every channel.
#![allow(clippy::unwrap_used)]

mod common;

use common::TempFile;

use std::path::Path;
use std::sync::Arc;

use bus::trace::{TraceEvent, TraceFrame};
use csp::cfp::{CanFrame, fragment_with_ident};
use csp::{Header, Packet, SimTime};
use m6p_twin::events::{Direction, Level, RunEvent};
use m6p_twin::record::{CspPacketMsg, Recorder, RecorderThread, RecordingMeta, RecordingStats};
use m6p_twin::recording::{self, DiffResult, RecordedMessage};

fn meta() -> RecordingMeta {
    RecordingMeta {
        scenario_toml: "# a ping to the FC\nname = \"ping-fc\"\nseed = 42 # ü\n".into(),
        ..common::meta("ping-fc", 42)
    }
}

const START_NS: u64 = 1_774_008_000_000_000_000; // 2026-03-20T12:00:00Z

fn medium(t: SimTime, medium: &str, from: &str, frame: TraceFrame, dropped: bool) -> RunEvent {
    RunEvent::Medium(TraceEvent {
        t,
        medium: Arc::from(medium),
        from: Arc::from(from),
        frame,
        dropped,
    })
}

fn frames(p: &Packet, next_hop: u8, ident: u16) -> Vec<CanFrame> {
    let mut out = Vec::new();
    fragment_with_ident(p, next_hop, ident, &mut out).unwrap();
    out
}

/// The ping request GS16 -> FC (3), port 1, 20 data bytes.
fn ping() -> Packet {
    Packet::new(
        Header::new(16, 3, 1, 40),
        (0..20u8).map(|i| i * 7).collect::<Vec<_>>(),
    )
}

/// A ping of the FC from the ground and its reply, as the media see them, plus one of every
/// other event kind, and a payload-bus packet with a lost frame followed by its resend.
fn events() -> Vec<RunEvent> {
    let req = ping();
    let rep = Packet::new(req.header.reply(3), req.data.clone());
    let mut ev = Vec::new();
    let mut t = SimTime::from_secs(5);
    let step = std::time::Duration::from_micros(150);
    ev.push(RunEvent::Command {
        t,
        name: "ping FC".into(),
        dst: 3,
        dport: 1,
        data: req.data.clone(),
        timeout: std::time::Duration::from_secs(5),
    });
    t = t + step;
    ev.push(medium(
        t,
        "ground",
        "GS16",
        TraceFrame::Packet(req.to_bytes()),
        false,
    ));
    for f in frames(&req, 3, 100) {
        t = t + step;
        ev.push(medium(t, "main", "COMM1", TraceFrame::Can(f), false));
    }
    for f in frames(&rep, 1, 7) {
        t = t + step;
        ev.push(medium(t, "main", "FC", TraceFrame::Can(f), false));
    }
    t = t + step;
    ev.push(medium(
        t,
        "ground",
        "COMM1",
        TraceFrame::Packet(rep.to_bytes()),
        false,
    ));
    ev.push(RunEvent::CommandResult(Box::new(
        m6p_twin::events::CommandResult {
            t,
            name: "ping FC".into(),
            dst: 3,
            dport: 1,
            data: req.data.clone(),
            timeout: std::time::Duration::from_secs(5),
            reply: Some(rep.data.clone()),
            rtt_ns: Some(t.as_ns() - 5_000_000_000),
            sent: SimTime::from_secs(5),
            failed: None,
        },
    )));
    ev.push(RunEvent::Log {
        t,
        source: "GS16".into(),
        level: Level::Info,
        message: "ping FC answered".into(),
    });
    ev.push(RunEvent::Fault {
        t,
        what: "faults[0]: Drop on payload".into(),
    });
    // PC (6) -> PL12 (12) on the payload bus: the second frame is lost, then a resend.
    let pl = Packet::new(Header::new(6, 12, 10, 33), vec![0xAB; 14]);
    for (i, f) in frames(&pl, 12, 500).into_iter().enumerate() {
        t = t + step;
        ev.push(medium(t, "payload", "PC", TraceFrame::Can(f), i == 1));
    }
    for f in frames(&pl, 12, 501) {
        t = t + step;
        ev.push(medium(t, "payload", "PC", TraceFrame::Can(f), false));
    }
    t = t + step;
    ev.push(RunEvent::Kiss {
        t,
        link: "listen 127.0.0.1:52001".into(),
        dir: Direction::In,
        bytes: vec![0xC0, 0x00, 0x90, 0x30, 0x44, 0x00, 0xDB, 0xDC, 0xC0],
    });
    ev.push(RunEvent::Expectation {
        t: SimTime::from_secs(6),
        name: "ping FC within 1s".into(),
        passed: true,
        observed: "reply after 2.1 ms".into(),
    });
    ev
}

fn record(path: &Path, events: &[RunEvent]) -> RecordingStats {
    common::record(path, meta(), events)
}

use common::on;

/// Medium messages of `events`: a KISS frame or a packet each, and a CAN train per run of
/// frames one sender put on one bus one after the other (at most 64 frames over 100 ms).
fn medium_count(events: &[RunEvent]) -> u64 {
    events
        .iter()
        .filter(|e| {
            matches!(e, RunEvent::Kiss { .. })
                || matches!(e, RunEvent::Medium(m) if !matches!(m.frame, TraceFrame::Can(_)))
        })
        .count() as u64
        + ["main", "payload"]
            .iter()
            .map(|b| trains(events, b))
            .sum::<u64>()
}

/// The `/can/<bus>/frames` messages of `events`: one per train (see [`medium_count`]).
fn trains(events: &[RunEvent], bus: &str) -> u64 {
    let mut n = 0;
    let mut open: Option<(String, u64, usize)> = None;
    for e in events {
        let RunEvent::Medium(m) = e else { continue };
        if !matches!(m.frame, TraceFrame::Can(_)) || &*m.medium != bus {
            continue;
        }
        let t = m.t.as_ns();
        match &mut open {
            Some((from, t0, k)) if **from == *m.from && *k < 64 && t - *t0 < 100_000_000 => {
                *k += 1;
            }
            _ => {
                n += 1;
                open = Some((m.from.to_string(), t, 1));
            }
        }
    }
    n
}

/// The CAN frames recorded on `topic`, over all its trains.
fn frames_on(path: &std::path::Path, topic: &str) -> usize {
    on(path, topic)
        .iter()
        .map(|m| m.json().unwrap()["can_id"].as_array().unwrap().len())
        .sum()
}

#[test]
fn the_same_events_give_byte_identical_files() {
    let ev = events();
    let (a, b) = (TempFile::new("det-a"), TempFile::new("det-b"));
    let sa = record(a.path(), &ev);
    let sb = record(b.path(), &ev);
    assert_eq!(sa, sb);
    let (ba, bb) = (
        std::fs::read(a.path()).unwrap(),
        std::fs::read(b.path()).unwrap(),
    );
    assert_eq!(ba.len() as u64, sa.bytes);
    assert!(ba == bb, "two recordings of the same events differ");
    // The header names this project, not the mcap crate (whose identifier carries its version).
    let library = b"m6p-twin 0.1.0";
    assert!(ba.windows(library.len()).any(|w| w == library));
    assert!(!ba.windows(9).any(|w| w == b"mcap-rust"));
    eprintln!(
        "test recording: {} events, {} messages, {} chunk(s), {} bytes",
        ev.len(),
        sa.messages,
        sa.chunks,
        sa.bytes
    );
    assert_eq!(
        recording::diff(a.path(), b.path()).unwrap(),
        DiffResult::Identical {
            messages: medium_count(&ev)
        }
    );
}

/// The recorder on its own thread (as a run records) writes the bytes of the recorder
/// inline, over several chunks and batches; dropped unfinished (a failed run) it still
/// ends the file with its summary, every event sent before included.
#[test]
fn the_recorders_thread_writes_the_same_bytes() {
    let ev = many_events();
    let (a, b, c) = (
        TempFile::new("thread-a"),
        TempFile::new("thread-b"),
        TempFile::new("thread-c"),
    );
    let sa = record(a.path(), &ev);
    let mut t = RecorderThread::start(
        Recorder::create(b.path(), meta(), m6p_twin::record::Existing::Replace).unwrap(),
    )
    .unwrap();
    // As `record` does: with the packets the events complete.
    for e in &m6p_twin::packets::with_packets(ev.iter().cloned()) {
        t.write(e);
    }
    let sb = t.finish().unwrap();
    assert_eq!(sa, sb);
    assert!(sa.chunks > 1, "{sa:?}");
    let bytes = std::fs::read(a.path()).unwrap();
    assert!(bytes == std::fs::read(b.path()).unwrap());

    // Dropped unfinished: what was recorded stays in the temporary file, never at the name.
    let rc = Recorder::create(c.path(), meta(), m6p_twin::record::Existing::Replace).unwrap();
    let c_partial = TempFile(rc.partial_path().to_owned());
    let mut t = RecorderThread::start(rc).unwrap();
    for e in &ev {
        t.write(e);
    }
    drop(t);
    assert!(!c.path().exists());
    let s = recording::read_summary(c_partial.path()).unwrap();
    assert!(s.incomplete.is_none(), "{s}");
    let frames = frames_on(c_partial.path(), "/can/main/frames");
    // All but the train still open (at most 64 frames), as a recorder dropped inline.
    assert!(frames < ev.len() && frames + 64 >= ev.len(), "{frames}");
    let d = TempFile::new("thread-d");
    let mut r = Recorder::create(d.path(), meta(), m6p_twin::record::Existing::Replace).unwrap();
    let d_partial = TempFile(r.partial_path().to_owned());
    for e in &ev {
        r.write(e).unwrap();
    }
    drop(r);
    assert!(std::fs::read(c_partial.path()).unwrap() == std::fs::read(d_partial.path()).unwrap());
}

/// A write error on the recorder's thread (a full disk: Linux's `/dev/full`) comes back
/// from `finish`, naming the file; the run's side never blocks or panics on it.
#[test]
fn a_write_error_on_the_recorders_thread_is_reported_at_the_end() {
    let path = Path::new("/dev/full");
    let mut t = RecorderThread::start(
        Recorder::create(path, meta(), m6p_twin::record::Existing::Replace).unwrap(),
    )
    .unwrap();
    for e in &many_events() {
        t.write(e);
    }
    let e = format!("{:#}", t.finish().unwrap_err());
    assert!(e.contains("/dev/full"), "{e}");
    assert!(e.contains("No space left"), "{e}");
    // A device is written to, never replaced by a file.
    use std::os::unix::fs::FileTypeExt as _;
    assert!(
        std::fs::metadata(path)
            .unwrap()
            .file_type()
            .is_char_device()
    );
}

#[test]
fn stats_count_every_channel() {
    let f = TempFile::new("stats");
    let s = record(f.path(), &events());
    let count = |topic: &str| {
        s.channels
            .iter()
            .find(|c| c.topic == topic)
            .map(|c| c.messages)
    };
    // Every frame, in trains.
    let ev = events();
    assert_eq!(count("/can/main/frames"), Some(trains(&ev, "main")));
    assert_eq!(count("/can/payload/frames"), Some(trains(&ev, "payload")));
    assert_eq!(frames_on(f.path(), "/can/main/frames"), 8);
    assert_eq!(frames_on(f.path(), "/can/payload/frames"), 6);
    assert_eq!(count("/ground/packets"), Some(2));
    // Request and reply on main and on ground, the resent packet on payload; not the one
    // that lost a frame.
    assert_eq!(count("/csp/packets"), Some(5));
    assert_eq!(count("/kiss/listen_127.0.0.1:52001/in"), Some(1));
    assert_eq!(count("/log"), Some(1));
    assert_eq!(count("/faults"), Some(1));
    assert_eq!(count("/commands"), Some(2));
    assert_eq!(count("/expectations"), Some(1));
    let all_frames = 8 + 6;
    assert_eq!(
        s.messages,
        27 - all_frames + trains(&ev, "main") + trains(&ev, "payload")
    );
    assert_eq!(s.chunks, 1);
    let mut tap = m6p_twin::packets::PacketTap::new();
    for e in &ev {
        tap.event(e);
    }
    assert_eq!(
        tap.cfp_drops(),
        1,
        "the frame after the lost one is out of sequence"
    );
    let topics: Vec<&str> = s.channels.iter().map(|c| c.topic.as_str()).collect();
    assert_eq!(
        topics,
        [
            "/can/main/frames",
            "/can/payload/frames",
            "/ground/packets",
            "/csp/packets",
            "/log",
            "/faults",
            "/commands",
            "/expectations",
            "/kiss/listen_127.0.0.1:52001/in"
        ]
    );
}

#[test]
fn diff_names_the_first_divergence() {
    let ev = events();
    let a = TempFile::new("diff-a");
    record(a.path(), &ev);

    // Flip one bit in the second CAN frame of the request (a MORE frame).
    let mut changed = ev.clone();
    let mut seen = 0;
    let mut index = 0;
    for (i, e) in changed
        .iter_mut()
        .filter(|e| matches!(e, RunEvent::Medium(_) | RunEvent::Kiss { .. }))
        .enumerate()
    {
        if let RunEvent::Medium(TraceEvent {
            frame: TraceFrame::Can(f),
            ..
        }) = e
        {
            seen += 1;
            if seen == 2 {
                f.data[0] ^= 0x01;
                index = i as u64;
                break;
            }
        }
    }
    assert_eq!(
        index, 2,
        "ground packet, BEGIN, then this MORE in the event list"
    );
    // diff indexes within the channel: the BEGIN and this MORE are one train, message 0;
    // the report names the frame within it.
    let index = 0;
    let b = TempFile::new("diff-b");
    record(b.path(), &changed);
    match recording::diff(a.path(), b.path()).unwrap() {
        DiffResult::Diverged {
            index: i,
            t_ns,
            channel,
            expected,
            actual,
        } => {
            assert_eq!(i, index);
            assert_eq!(channel, "/can/main/frames");
            assert_eq!(t_ns, 5_000_000_000 + 3 * 150_000);
            // The MORE frame carries data bytes 2..10 of the ping: 7*2 = 0x0e first.
            assert!(expected.contains("data 0e151c232a31383f"), "{expected}");
            assert!(actual.contains("data 0f151c232a31383f"), "{actual}");
            assert!(expected.contains("MORE") && expected.contains("from COMM1"));
            assert!(expected.contains("(frame 2 of "), "{expected}");
        }
        other => panic!("expected a divergence, got {other:?}"),
    }

    // The reply's BEGIN frame changed: the decoded CSP header is in the report.
    let mut changed = ev.clone();
    let begin = changed
        .iter()
        .position(|e| {
            matches!(e, RunEvent::Medium(TraceEvent { from, frame: TraceFrame::Can(_), .. }) if &**from == "FC")
        })
        .unwrap();
    if let RunEvent::Medium(TraceEvent {
        frame: TraceFrame::Can(f),
        ..
    }) = &mut changed[begin]
    {
        f.data[2] ^= 0x40; // dport bit in the CSP header
    }
    let c = TempFile::new("diff-c");
    record(c.path(), &changed);
    let d = recording::diff(a.path(), c.path()).unwrap();
    let text = d.to_string();
    assert!(
        text.contains("on /can/main/frames (message 1 of that channel)"),
        "{text}"
    );
    assert!(text.contains("CSP prio 2 3:1 -> 16:40"), "{text}");
    assert!(text.contains("CSP prio 2 3:1 -> 16:41"), "{text}");

    // A recording that stops early diverges where it ends.
    let short = TempFile::new("diff-short");
    record(short.path(), &ev[..ev.len() - 2]);
    match recording::diff(a.path(), short.path()).unwrap() {
        DiffResult::Diverged {
            index,
            channel,
            actual,
            ..
        } => {
            // The KISS frame was the last event and the only one on its channel.
            assert_eq!(index, 0);
            assert_eq!(channel, "/kiss/listen_127.0.0.1:52001/in");
            assert_eq!(actual, "(end of recording)");
        }
        other => panic!("expected a divergence, got {other:?}"),
    }
}

/// Rebuild CSP packets from the recorded CAN frames of one bus without the project's
/// reassembler: BEGIN gives header and length, MOREs append, keyed by CFP src/dst/ident.
fn packets_from_frames(trains: &[RecordedMessage]) -> Vec<Vec<u8>> {
    let mut partial: Vec<(u32, usize, Vec<u8>)> = Vec::new();
    let mut done = Vec::new();
    // Each message is a train: frame i is can_id[i] with dlc[i] bytes of `data`.
    let frames = trains.iter().flat_map(|m| {
        let v = m.json().unwrap();
        let ids: Vec<u32> = serde_json::from_value(v["can_id"].clone()).unwrap();
        let dlcs: Vec<usize> = serde_json::from_value(v["dlc"].clone()).unwrap();
        let dropped: Vec<usize> = serde_json::from_value(v["dropped"].clone()).unwrap();
        let data = hex::decode(v["data"].as_str().unwrap()).unwrap();
        let mut at = 0;
        let mut out = Vec::new();
        for (i, (id, n)) in ids.into_iter().zip(dlcs).enumerate() {
            out.push((id, data[at..at + n].to_vec(), dropped.contains(&i)));
            at += n;
        }
        out
    });
    for (id, data, dropped) in frames {
        if dropped {
            continue;
        }
        let key = id & 0x1FF8_03FF;
        let pos = partial.iter().position(|p| p.0 == key);
        // CFP type bit (bit 18 of the id, docs/protocol.md): 0 BEGIN.
        if id & (1 << 18) == 0 {
            let len = usize::from(u16::from_be_bytes([data[4], data[5]]));
            let mut bytes = data[..4].to_vec();
            bytes.extend_from_slice(&data[6..]);
            if let Some(i) = pos {
                partial.remove(i);
            }
            partial.push((key, len, bytes));
        } else if let Some(i) = pos {
            partial[i].2.extend_from_slice(&data);
        }
        if let Some(i) = partial.iter().position(|p| p.0 == key)
            && partial[i].2.len() == 4 + partial[i].1
        {
            done.push(partial.remove(i).2);
        }
    }
    done
}

fn csp_bytes(p: &CspPacketMsg) -> Vec<u8> {
    let h = Header {
        prio: csp::Priority::from_bits(p.prio),
        src: p.src,
        dst: p.dst,
        dport: p.dport,
        sport: p.sport,
        flags: p.flags,
    };
    let mut out = h.to_bytes().to_vec();
    out.extend_from_slice(&p.data);
    out
}

#[test]
fn decoded_csp_packets_equal_the_bytes_on_the_bus() {
    let f = TempFile::new("csp");
    record(f.path(), &events());
    let csp: Vec<CspPacketMsg> = on(f.path(), "/csp/packets")
        .iter()
        .map(|m| m.decode().unwrap())
        .collect();
    let media: Vec<&str> = csp.iter().map(|p| p.medium.as_str()).collect();
    assert_eq!(media, ["ground", "main", "main", "ground", "payload"]);

    // The ping as sent: header fields, data, service name.
    let req = ping();
    let p = &csp[1];
    assert_eq!((p.src, p.dst, p.dport, p.sport), (16, 3, 1, 40));
    assert_eq!(hex::encode(&p.data), hex::encode(&req.data));
    assert_eq!(p.len, 20);
    assert_eq!(p.service.as_deref(), Some("ping"));
    assert_eq!(p.icd, None);
    assert_eq!(p.from, "COMM1");
    assert_eq!(
        csp[2].service.as_deref(),
        Some("ping"),
        "the reply, by sport"
    );
    assert_eq!(csp[4].service, None);

    // CAN: every decoded packet equals the frames' payload, bus by bus.
    for bus in ["main", "payload"] {
        let from_frames = packets_from_frames(&on(f.path(), &format!("/can/{bus}/frames")));
        let decoded: Vec<Vec<u8>> = csp
            .iter()
            .filter(|p| p.medium == bus)
            .map(csp_bytes)
            .collect();
        assert!(!decoded.is_empty());
        assert_eq!(decoded, from_frames, "bus {bus}");
    }
    // Ground: every decoded packet equals a delivered packet's bytes.
    let ground: Vec<Vec<u8>> = on(f.path(), "/ground/packets")
        .iter()
        .map(|m| {
            let v = m.json().unwrap();
            hex::decode(v["bytes"].as_str().unwrap()).unwrap()
        })
        .collect();
    let decoded: Vec<Vec<u8>> = csp
        .iter()
        .filter(|p| p.medium == "ground")
        .map(csp_bytes)
        .collect();
    assert_eq!(decoded, ground);
    assert_eq!(ground[0], req.to_bytes());
}

#[test]
fn messages_carry_simulated_time() {
    let f = TempFile::new("time");
    record(f.path(), &events());
    let all: Vec<RecordedMessage> = recording::messages(f.path())
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(all[0].log_time, START_NS + 5_000_000_000);
    for m in &all {
        let v = m.json().unwrap();
        let t_ns = match v.get("t_ns") {
            Some(t) => t.as_u64().unwrap(),
            // foxglove.Log has its own timestamp: simulated UTC.
            None => {
                v["timestamp"]["sec"].as_u64().unwrap() * 1_000_000_000
                    + v["timestamp"]["nsec"].as_u64().unwrap()
                    - START_NS
            }
        };
        assert_eq!(m.log_time, START_NS + t_ns, "{}", m.topic);
    }
    let log = &on(f.path(), "/log")[0];
    assert_eq!(&*log.schema, "foxglove.Log");
    let v = log.json().unwrap();
    assert_eq!(v["level"], 2);
    assert_eq!(v["name"], "GS16");
}

#[test]
fn summary_and_meta_describe_the_run() {
    let f = TempFile::new("summary");
    let ev = events();
    record(f.path(), &ev);
    assert_eq!(recording::load_meta(f.path()).unwrap(), meta());

    let s = recording::read_summary(f.path()).unwrap();
    assert_eq!(s.meta, Some(meta()));
    assert_eq!(s.scenario_name(), Some("ping-fc"));
    assert_eq!(s.seed(), Some(42));
    assert_eq!(s.library, "m6p-twin 0.1.0");
    assert_eq!(s.incomplete, None);
    assert_eq!(
        s.messages,
        27 - (8 + 6) + trains(&ev, "main") + trains(&ev, "payload")
    );
    assert_eq!(
        s.duration_ns, 6_000_000_000,
        "the expectation at 6 s is last"
    );
    assert_eq!(s.count("/can/main/frames"), trains(&ev, "main"));
    assert_eq!(s.count("/csp/packets"), 5);
    assert_eq!(s.count("/kiss/listen_127.0.0.1:52001/in"), 1);
    assert_eq!(s.channels.len(), 9);
    assert_eq!(
        s.packets_per_node.iter().collect::<Vec<_>>(),
        [(&3, &2), (&6, &1), (&16, &2)]
    );
    assert_eq!(
        s.packets_per_port.iter().collect::<Vec<_>>(),
        [(&1, &2), (&10, &1), (&40, &2)]
    );
    let c = s.commands["ping FC"];
    assert_eq!((c.sent, c.answered, c.unanswered), (1, 1, 0));
    assert_eq!(s.expectations.len(), 1);
    assert!(s.expectations[0].passed);
    let text = s.to_string();
    assert!(text.contains("scenario: ping-fc (seed 42)"), "{text}");
    assert!(
        text.contains("PASS ping FC within 1s at 6.000000000 s"),
        "{text}"
    );
}

#[test]
fn csv_export_flattens_fields() {
    let f = TempFile::new("csv");
    record(f.path(), &events());
    let mut out = Vec::new();
    let rows = recording::export_csv(f.path(), "/can/main/frames", &mut out).unwrap();
    assert_eq!(rows, 8);
    let text = String::from_utf8(out).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines[0],
        "log_time_ns,t_ns,from,can_id,dlc,data,cfp.src,cfp.dst,cfp.type,cfp.remain,\
         cfp.ident,dropped,csp.prio,csp.src,csp.dst,csp.dport,csp.sport,csp.flags,csp.len"
    );
    assert_eq!(lines.len(), 9);
    assert!(
        lines[1].ends_with(",BEGIN,3,100,false,2,16,3,1,40,0,20"),
        "{}",
        lines[1]
    );
    assert!(
        lines[2].ends_with(",MORE,2,100,false,,,,,,,"),
        "{}",
        lines[2]
    );

    let mut out = Vec::new();
    recording::export_csv(f.path(), "/log", &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    assert!(text.starts_with("log_time_ns,timestamp.sec,timestamp.nsec,level,message,name"));

    let err = recording::export_csv(f.path(), "/nope", &mut Vec::new()).unwrap_err();
    assert!(format!("{err:#}").contains("no channel /nope"), "{err:#}");
}

/// Packets of [`many_events`].
const MANY_PACKETS: u32 = 48_000;

/// Enough traffic for several 4 MiB chunks.
fn many_events() -> Vec<RunEvent> {
    let mut ev = Vec::new();
    let mut t = SimTime::ZERO;
    for i in 0..MANY_PACKETS {
        let p = Packet::new(
            Header::new(16, 3, 1, 40),
            (0..64u32)
                .map(|j| (i * 31 + j * 17) as u8)
                .collect::<Vec<_>>(),
        );
        for f in frames(&p, 3, (i % 1024) as u16) {
            t = t + std::time::Duration::from_micros(130);
            ev.push(medium(t, "main", "COMM1", TraceFrame::Can(f), false));
        }
    }
    ev
}

#[test]
fn truncated_and_foreign_files_give_errors_not_panics() {
    let f = TempFile::new("big");
    let ev = many_events();
    let stats = record(f.path(), &ev);
    assert!(stats.chunks >= 3, "{stats:?}");
    let bytes = std::fs::read(f.path()).unwrap();
    let full = recording::read_summary(f.path()).unwrap();
    assert_eq!(full.messages, stats.messages);

    let cut = TempFile::new("cut");
    let mut partial_seen = false;
    for len in [
        0,
        5,
        8,
        20,
        100,
        bytes.len() / 3,
        bytes.len() / 2,
        bytes.len() * 9 / 10,
        bytes.len() - 100,
        bytes.len() - 1,
    ] {
        std::fs::write(cut.path(), &bytes[..len]).unwrap();
        match recording::read_summary(cut.path()) {
            Ok(s) => {
                let why = s.incomplete.as_deref().unwrap_or_default();
                assert!(why.contains("truncated"), "cut at {len}: {why}");
                assert!(s.messages <= full.messages);
                if s.messages > 0 && s.messages < full.messages {
                    partial_seen = true;
                    assert!(why.contains("last complete chunk"), "{why}");
                }
            }
            Err(e) => {
                assert!(len < 100, "cut at {len}: {e:#}");
                assert!(format!("{e:#}").contains("not an MCAP file"), "{e:#}");
            }
        }
        // Meta sits before the first chunk: readable from any cut past it.
        let meta_ok = recording::load_meta(cut.path()).is_ok();
        assert_eq!(meta_ok, len >= bytes.len() / 3, "cut at {len}");
        let d = recording::diff(f.path(), cut.path());
        assert!(d.is_err() || len == bytes.len() - 1 || len == bytes.len() - 100);
        let _ = recording::export_csv(cut.path(), "/can/main/frames", &mut std::io::sink());
    }
    assert!(
        partial_seen,
        "a cut in the middle keeps the complete chunks"
    );

    // Not MCAP at all, and garbage after a valid magic.
    let junk = TempFile::new("junk");
    std::fs::write(junk.path(), b"name = \"not an mcap\"\n").unwrap();
    let e = recording::read_summary(junk.path()).unwrap_err();
    assert!(format!("{e:#}").contains("not an MCAP file"), "{e:#}");
    assert!(recording::diff(f.path(), junk.path()).is_err());
    let mut garbage = bytes[..8].to_vec();
    garbage.extend((0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8));
    std::fs::write(junk.path(), &garbage).unwrap();
    assert!(recording::load_meta(junk.path()).is_err());
    let _ = recording::read_summary(junk.path());
    // A flipped byte inside a chunk fails its CRC: reported, not decoded. (In the middle of
    // the second chunk's data: the message indexes after each chunk, half this file, are
    // not covered by a CRC.)
    let mut flipped = bytes.clone();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunk = &summary.chunk_indexes[1];
    let mid = (chunk.chunk_start_offset + chunk.chunk_length / 2) as usize;
    flipped[mid] ^= 0xFF;
    std::fs::write(junk.path(), &flipped).unwrap();
    let s = recording::read_summary(junk.path()).unwrap();
    assert!(s.incomplete.is_some());
    assert!(s.messages < full.messages);
}

/// `inspect --sizes` (`sizes::read_sizes`): every channel with its messages and their data
/// bytes as the messages themselves give them, 16 bytes of index a message, compressed data
/// that zstd made smaller than the data where it repeats, largest share first; a cut file
/// gives what it read and says why it stopped.
#[test]
fn sizes_account_for_every_message_of_every_channel() {
    use m6p_twin::sizes::{BLOCK_BYTES, INDEX_BYTES_PER_MESSAGE, read_sizes};
    for (name, ev) in [("sizes-kinds", events()), ("sizes-many", many_events())] {
        let f = TempFile::new(name);
        record(f.path(), &ev);
        let s = read_sizes(f.path()).unwrap();
        assert!(s.incomplete.is_none(), "{s}");
        let mut want: std::collections::BTreeMap<String, (u64, u64)> = Default::default();
        for m in recording::messages(f.path()).unwrap() {
            let m = m.unwrap();
            let e = want.entry(m.topic.to_string()).or_default();
            e.0 += 1;
            e.1 += m.data.len() as u64;
        }
        let got: std::collections::BTreeMap<String, (u64, u64)> = s
            .channels
            .iter()
            .map(|c| (c.topic.clone(), (c.messages, c.data_bytes)))
            .collect();
        assert_eq!(got, want);
        for c in &s.channels {
            assert_eq!(c.index_bytes, INDEX_BYTES_PER_MESSAGE * c.messages, "{s}");
            // zstd's frame adds a few bytes to data it cannot shrink, a frame per block.
            let blocks = c.data_bytes / BLOCK_BYTES as u64 + 1;
            assert!(
                c.zstd_bytes > 0 && c.zstd_bytes <= c.data_bytes + 32 * blocks,
                "{s}"
            );
        }
        assert!(
            s.channels
                .windows(2)
                .all(|w| w[0].share_bytes() >= w[1].share_bytes()),
            "{s}"
        );
        assert_eq!(s.file_bytes, std::fs::metadata(f.path()).unwrap().len());
        // The index as the writer wrote it: 16 bytes a message, plus a record header
        // (opcode, length, channel id, array length: 15 bytes) per channel per chunk.
        let bytes = std::fs::read(f.path()).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let index_in_file: u64 = summary
            .chunk_indexes
            .iter()
            .map(|c| c.message_index_length - 15 * c.message_index_offsets.len() as u64)
            .sum();
        let index_estimated: u64 = s.channels.iter().map(|c| c.index_bytes).sum();
        assert_eq!(index_estimated, index_in_file, "{s}");
        // Per hour from the run's start (the metadata's) to the last message.
        let last = recording::messages(f.path())
            .unwrap()
            .map(|m| m.unwrap().log_time)
            .max()
            .unwrap();
        assert_eq!(s.hours, (last - START_NS) as f64 / 3.6e12, "{s}");
        let text = s.to_string();
        assert!(
            text.contains("all channels") && text.contains("/can/main/frames"),
            "{text}"
        );
        if name == "sizes-many" {
            // Many similar packets: compressed well below their data, over several blocks.
            let p = s
                .channels
                .iter()
                .find(|c| c.topic == "/csp/packets")
                .unwrap();
            assert!(p.data_bytes > 2 * BLOCK_BYTES as u64, "{s}");
            assert!(p.zstd_bytes * 2 < p.data_bytes, "{s}");
            let cut = TempFile::new("sizes-cut");
            std::fs::write(cut.path(), &bytes[..bytes.len() / 2]).unwrap();
            let c = read_sizes(cut.path()).unwrap();
            let why = c.incomplete.as_deref().unwrap_or_default();
            assert!(why.contains("truncated"), "{c}");
            let read: u64 = c.channels.iter().map(|c| c.messages).sum();
            let all: u64 = s.channels.iter().map(|c| c.messages).sum();
            assert!(read > 0 && read < all, "{c}");
            // Nothing readable: an error naming why.
            std::fs::write(cut.path(), b"not a recording").unwrap();
            let e = read_sizes(cut.path()).unwrap_err();
            assert!(format!("{e:#}").contains("not an MCAP file"), "{e:#}");
        }
    }
    // A recording without messages: no channels, no hours, no error.
    let f = TempFile::new("sizes-empty");
    record(f.path(), &[]);
    let s = read_sizes(f.path()).unwrap();
    assert!(
        s.channels.is_empty() && s.hours == 0.0 && s.incomplete.is_none(),
        "{s}"
    );
    assert!(s.to_string().contains("all channels"), "{s}");
}

/// Decode a recording with the `mcap` Python package (`tests/decode_mcap.py`): a generic
/// reader with no code from this project must decode every channel, and the decoded ground
/// packets must equal the packets on the ground network.
///
/// Needs `python3` with the `mcap` package: ignored where the build probe did not find it,
/// and failing under `CI` if it is missing (`.ci/run` installs it; see `build.rs`).
#[test]
#[cfg_attr(
    not(python_mcap),
    ignore = "needs python3 with the `mcap` package (pip install mcap; .ci/run installs it)"
)]
fn python_mcap_package_decodes_every_channel() {
    let f = TempFile::new("python");
    record(f.path(), &events());
    let stdout = common::decode(f.path());
    assert!(stdout.contains("/csp/packets 5"), "{stdout}");
    assert!(stdout.contains("ground packets checked: 2"), "{stdout}");
    assert!(stdout.ends_with("ok\n"), "{stdout}");
}

/// A run killed mid-chunk (the recorder never finishes): the complete chunks are read, and
/// the summary says the file ends in an unfinished chunk.
#[test]
fn a_killed_run_reads_up_to_the_last_complete_chunk() {
    let f = TempFile::new("killed");
    let ev = many_events();
    let (first, rest) = ev.split_at(ev.len() / 2);
    let mut r = Recorder::create(f.path(), meta(), m6p_twin::record::Existing::Replace).unwrap();
    // A killed run leaves its recording in the temporary file it was written to.
    let f = TempFile(r.partial_path().to_owned());
    for e in first {
        r.write(e).unwrap();
    }
    r.flush().unwrap();
    for e in rest {
        r.write(e).unwrap();
    }
    // As if the process died: nothing more reaches the file (no summary, no footer).
    std::mem::forget(r);
    let s = recording::read_summary(f.path()).unwrap();
    // The frames of the complete chunks: at least those flushed, not all of them.
    let frames: usize = recording::messages(f.path())
        .unwrap()
        .map_while(Result::ok)
        .filter(|m| &*m.topic == "/can/main/frames")
        .map(|m| m.json().unwrap()["can_id"].as_array().unwrap().len())
        .sum();
    // The train open at the flush is handed out after it (at most 64 frames).
    assert!(frames + 64 >= first.len(), "{frames} frames\n{s}");
    assert!(frames < ev.len(), "{frames} frames\n{s}");
    let why = s.incomplete.unwrap();
    assert!(why.contains("last complete chunk"), "{why}");
    assert_eq!(recording::load_meta(f.path()).unwrap(), meta());
}

/// The file is in log-time order, as a streaming reader (and `mcap doctor
/// --strict-message-order`) wants it, though some messages are handed to the recorder late:
/// CAN trains when they close, the EPS's samples of its 30 s hang when it recovers. Each
/// keeps its own log time (the EPS's samples one a second through the hang).
#[test]
fn the_file_is_in_log_time_order() {
    let rec = TempFile::new("order");
    let out = std::process::Command::new(common::twin_process::twin_bin())
        .arg("run")
        .arg(common::repo_root().join("scenarios/node-faults.toml"))
        .arg("--record")
        .arg(rec.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let mut last = 0;
    let mut late = Vec::new();
    for m in m6p_twin::recording::messages(rec.path()).unwrap() {
        let m = m.unwrap();
        if m.log_time < last {
            late.push(format!("{} at {} after {last}", m.topic, m.log_time));
        }
        last = last.max(m.log_time);
    }
    assert!(
        late.is_empty(),
        "{} out of order: {:?}",
        late.len(),
        &late[..late.len().min(5)]
    );
    // Through the hang (60 s to 90 s), a sample each second, at its own time.
    let eps: Vec<u64> = on(rec.path(), "/eps/power")
        .iter()
        .map(|m| m.log_time)
        .collect();
    let start = eps[0] - 1_000_000_000;
    let in_hang: Vec<u64> = eps
        .iter()
        .map(|t| (t - start) / 1_000_000_000)
        .filter(|s| (61..90).contains(s))
        .collect();
    assert_eq!(in_hang, (61..90).collect::<Vec<u64>>());
}

/// `--channels` chooses what the file holds: a channel left out is not in it, a thinned one
/// keeps one message per period, the others every message, the same as a whole recording's;
/// the rules are in the file, so `replay` records the same channels and finds the run
/// identical.
#[test]
fn channel_rules_leave_out_and_thin_and_replay_keeps_them() {
    let run = |rec: &Path, channels: Option<&str>| {
        let mut cmd = std::process::Command::new(common::twin_process::twin_bin());
        cmd.args(["run", "--duration", "2m", "--record"]).arg(rec);
        if let Some(c) = channels {
            cmd.arg("--channels").arg(c);
        }
        let out = cmd.output().unwrap();
        assert!(out.status.success(), "{out:?}");
    };
    let (whole, chosen) = (TempFile::new("whole"), TempFile::new("chosen"));
    run(whole.path(), None);
    run(
        chosen.path(),
        Some("-/csp/packets,/fc/*@10s,-/fc/scene,-/can/payload/*"),
    );
    let topics = |p: &Path| -> Vec<String> {
        recording::read_summary(p)
            .unwrap()
            .channels
            .into_iter()
            .map(|c| c.topic)
            .collect()
    };
    let chosen_topics = topics(chosen.path());
    for gone in ["/csp/packets", "/fc/scene", "/can/payload/frames"] {
        assert!(topics(whole.path()).iter().any(|t| t == gone), "{gone}");
        assert!(!chosen_topics.iter().any(|t| t == gone), "{gone}");
    }
    // One a second in the whole file, one in ten seconds here: the first, then each 10 s on.
    let times =
        |p: &Path, topic: &str| -> Vec<u64> { on(p, topic).iter().map(|m| m.log_time).collect() };
    let all = times(whole.path(), "/fc/adcs");
    let thinned = times(chosen.path(), "/fc/adcs");
    assert!(all.len() >= 120, "{}", all.len());
    let mut expected: Vec<u64> = Vec::new();
    for &t in &all {
        if expected
            .last()
            .is_none_or(|&last| t >= last + 10_000_000_000)
        {
            expected.push(t);
        }
    }
    assert_eq!(thinned, expected);
    assert_eq!(thinned.len(), 12);
    for topic in ["/can/main/frames", "/ground/packets", "/eps/power"] {
        let (a, b) = (on(whole.path(), topic), on(chosen.path(), topic));
        assert_eq!(a.len(), b.len(), "{topic}");
        assert!(
            a.iter()
                .zip(&b)
                .all(|(x, y)| x.log_time == y.log_time && x.data == y.data),
            "{topic}"
        );
    }
    let meta = recording::load_meta(chosen.path()).unwrap();
    assert_eq!(
        twin_scenario_rules(&meta),
        "-/csp/packets,/fc/*@10s,-/fc/scene,-/can/payload/*"
    );
    let out = std::process::Command::new(common::twin_process::twin_bin())
        .arg("replay")
        .arg(chosen.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("identical"),
        "{out:?}"
    );
}

fn twin_scenario_rules(meta: &RecordingMeta) -> String {
    meta.channels
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(",")
}
