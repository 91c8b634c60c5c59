//! ICD 3.1 session rules, one table or test per rule, driven through `Host<PcApp>` with
//! scripted payloads (tests/util).
#![allow(clippy::unwrap_used)]

mod util;

use std::time::Duration;

use csp::SimTime;
use csp::reqrep::le::Repr;
use m6p_nodes_pc::wire::{self, Status};
use m6p_nodes_pc::{
    DropReason, PcEvent, PcOutput, SbandConfig, SessionMode, SessionResult, SessionState,
    TimedPcEvent,
};
use util::*;

/// A PC with [`cfg`]'s sessions.
fn sim() -> Sim {
    Sim::new(
        cfg(),
        vec![FakePayload::normal(12), FakePayload::normal(14)],
    )
}

fn sim_with(p: FakePayload) -> Sim {
    Sim::new(cfg(), vec![p])
}

const MS: fn(u64) -> Duration = Duration::from_millis;

#[test]
fn setup_validation_boundaries() {
    // (duration s, frame size, sync length, accepted)
    let table: &[(u16, u8, usize, bool)] = &[
        (4, 64, 0, false),
        (5, 64, 0, true),
        (900, 64, 0, true),
        (901, 64, 0, false),
        (60, 0, 0, false),
        (60, 1, 0, true),
        (60, 254, 0, true),
        (60, 255, 0, false),
        (60, 64, 128, true),
        (60, 64, 129, false),
        (0, 64, 0, false),
        (u16::MAX, 64, 0, false),
    ];
    for &(d, f, n, ok) in table {
        let mut s = sim();
        let c = session(1, ts(100), d, 0, f, &vec![b'x'; n]);
        assert_eq!(s.setup(&c), u8::from(ok), "duration {d} frame {f} sync {n}");
        let st = s.status(1).unwrap();
        let want = if ok {
            SessionState::Pending
        } else {
            SessionState::NotActive
        };
        assert_eq!(st.state, want, "duration {d} frame {f} sync {n}");
        if ok {
            assert_eq!(st.sync_message.len(), n);
            assert_eq!((st.duration_s, st.poll_frame_size), (d, f));
        }
    }
}

#[test]
fn setup_request_lengths() {
    // The request data is 10 + N bytes; shorter is refused, whatever the content.
    for len in 0..10 {
        let mut s = sim();
        let mut req = vec![wire::cmd::SETUP];
        req.extend(std::iter::repeat_n(1u8, len));
        assert_eq!(s.request(10, &req), vec![1, 0], "{len} bytes of data");
    }
}

#[test]
fn unknown_session_id_fails_every_command() {
    let mut s = sim();
    assert_eq!(s.setup(&session(9, 0, 10, 0, 64, b"")), 0);
    assert_eq!(s.request(10, &[2, 9]), vec![2, 0]);
    assert_eq!(s.abort(9), 0);
    assert!(s.starts().is_empty());
}

#[test]
fn overlap_with_another_configured_session_is_refused() {
    // Session 1 occupies [100 s, 160 s). (start s, duration s, accepted) for session 3.
    let table: &[(u64, u16, bool)] = &[
        (40, 60, true),   // ends exactly at 100
        (41, 60, false),  // ends at 101
        (110, 5, false),  // inside
        (90, 100, false), // covers
        (159, 5, false),  // starts a second before the end
        (160, 5, true),   // starts at the end
    ];
    for &(start, d, ok) in table {
        let mut s = sim();
        assert_eq!(s.setup(&session(1, ts(100), 60, 0, 64, b"")), 1);
        assert_eq!(
            s.setup(&session(3, ts(start), d, 0, 64, b"")),
            u8::from(ok),
            "[{start}, +{d})"
        );
    }
    // Only PENDING/ACTIVE sessions count: after ABORT the window is free.
    let mut s = sim();
    assert_eq!(s.setup(&session(1, ts(100), 60, 0, 64, b"")), 1);
    assert_eq!(s.abort(1), 1);
    assert_eq!(s.setup(&session(3, ts(110), 5, 0, 64, b"")), 1);
}

#[test]
fn pending_session_is_reconfigured_only_after_abort() {
    let mut s = sim();
    assert_eq!(s.setup(&session(1, ts(100), 60, 0, 64, b"a")), 1);
    assert_eq!(s.setup(&session(1, ts(300), 60, 0, 64, b"b")), 0);
    assert_eq!(s.status(1).unwrap().sync_message, b"a");
    assert_eq!(s.abort(1), 1);
    assert_eq!(s.setup(&session(1, ts(300), 60, 0, 64, b"b")), 1);
    let st = s.status(1).unwrap();
    assert_eq!((st.state, st.timestamp), (SessionState::Pending, ts(300)));
    // An ACTIVE session is not reconfigured either.
    s.run_until(SimTime::from_secs(301));
    assert_eq!(s.status(1).unwrap().state, SessionState::Active);
    assert_eq!(s.setup(&session(1, ts(400), 60, 0, 64, b"c")), 0);
}

#[test]
fn abort_of_pending_active_and_not_active() {
    // PENDING: ABORTED recorded, it never starts.
    let mut s = sim();
    assert_eq!(s.setup(&session(1, ts(10), 30, 0, 64, b"")), 1);
    assert_eq!(s.abort(1), 1);
    let st = s.status(1).unwrap();
    assert_eq!(
        (st.state, st.last_result),
        (SessionState::NotActive, SessionResult::Aborted)
    );
    s.run_until(SimTime::from_secs(60));
    assert!(s.starts().is_empty());
    assert!(s.payload(12).requests.is_empty());

    // ACTIVE: ABORTED, polling stops.
    let mut s = sim();
    assert_eq!(s.setup(&session(1, 0, 30, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(2));
    let polls = s.payload(12).polls_received().len();
    assert!(polls >= 15, "{polls} polls in 2 s");
    assert_eq!(s.abort(1), 1);
    s.run_until(SimTime::from_secs(10));
    assert_eq!(s.payload(12).polls_received().len(), polls);
    assert_eq!(
        s.ends(),
        vec![(
            SimTime::from_secs(2),
            1,
            SessionResult::Aborted,
            polls as u32
        )]
    );
    let st = s.status(1).unwrap();
    assert_eq!(
        (st.state, st.last_result),
        (SessionState::NotActive, SessionResult::Aborted)
    );

    // NOT ACTIVE: failure, nothing changes (never run: DONE; after a run: its result).
    let mut s = sim();
    assert_eq!(s.abort(1), 0);
    assert_eq!(s.status(1).unwrap().last_result, SessionResult::Done);
    let mut s = sim_with(FakePayload::normal(12).with_sync(SyncAct::Silent));
    assert_eq!(s.setup(&session(1, 0, 30, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(1));
    assert_eq!(s.abort(1), 0);
    assert_eq!(s.status(1).unwrap().last_result, SessionResult::NoAck);
}

#[test]
fn status_layout_and_size() {
    let mut s = sim();
    // Never configured: DONE, NOT ACTIVE, zeros; 2-byte head + 11 bytes.
    let r = s.request(10, &[2, 1]);
    assert_eq!(r, [vec![2, 1], vec![0; 11]].concat());
    // Configured: 13 + N bytes, fields little-endian in ICD order.
    assert_eq!(
        s.setup(&session(3, ts(1000), 0x0102, 0x0304, 0x05, b"abc")),
        1
    );
    let r = s.request(10, &[2, 3]);
    let t = ts(1000).to_le_bytes();
    assert_eq!(
        r,
        vec![
            2, 1, 0, 1, t[0], t[1], t[2], t[3], 0x02, 0x01, 0x04, 0x03, 0x05, b'a', b'b', b'c'
        ]
    );
    assert_eq!(r.len(), 2 + wire::STATUS_FIXED_LEN + 3);
    // The same through the typed accessor.
    let st = s.host.app.status(3).unwrap();
    assert_eq!((st.state, st.payload_addr), (SessionState::Pending, 14));
    assert!(s.host.app.status(9).is_none());
}

#[test]
fn no_ack_cases() {
    // (what the payload answers to SYNC `01 | "hello"`, acknowledged)
    let table: Vec<(SyncAct, bool)> = vec![
        (SyncAct::Echo, true),
        (SyncAct::Raw(b"\x01\x00hello".to_vec()), true), // result code ignored
        (SyncAct::Raw(b"\x01\x01hellO".to_vec()), false), // wrong bytes
        (SyncAct::Raw(b"\x01\x01hell".to_vec()), false), // short
        (SyncAct::Raw(b"\x01\x01hello!".to_vec()), false), // long
        (SyncAct::Raw(b"\x02\x01hello".to_vec()), false), // wrong command id
        (SyncAct::Raw(b"\x01".to_vec()), false),         // no result byte
        (SyncAct::Silent, false),
    ];
    for (act, acked) in table {
        let mut s = sim_with(FakePayload::normal(12).with_sync(act.clone()));
        assert_eq!(s.setup(&session(1, 0, 10, 0, 64, b"hello")), 1);
        s.run_until(SimTime::from_secs(1));
        let p = s.payload(12);
        assert_eq!(p.syncs_received(), vec![b"\x01hello".to_vec()], "{act:?}");
        if acked {
            assert!(p.polls_received().len() >= 5, "{act:?}");
            assert!(s.ends().is_empty());
        } else {
            assert!(
                p.polls_received().is_empty(),
                "{act:?}: no POLL after NO ACK"
            );
            let (t, id, result, packets) = s.ends()[0];
            assert_eq!(
                (id, result, packets),
                (1, SessionResult::NoAck, 0),
                "{act:?}"
            );
            // Silence ends the session at the reply timeout, a wrong echo at once.
            let want = if matches!(act, SyncAct::Silent) {
                MS(200)
            } else {
                MS(5)
            };
            assert_eq!(t, SimTime::ZERO + want, "{act:?}");
            assert_eq!(s.status(1).unwrap().last_result, SessionResult::NoAck);
        }
    }
}

#[test]
fn sync_is_sent_once_and_not_retried() {
    let mut s = sim_with(FakePayload::normal(12).with_sync(SyncAct::Silent));
    assert_eq!(s.setup(&session(1, 0, 10, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(10));
    assert_eq!(s.payload(12).syncs_received(), vec![vec![1]]);
}

#[test]
fn three_attempt_rule() {
    // (silent attempts before data, packets counted after the first cycle, data downlinked)
    let table: &[(usize, bool)] = &[(0, true), (1, true), (2, true), (3, false)];
    for &(silent, data) in table {
        let mut polls = vec![PollAct::Silent; silent];
        polls.push(PollAct::Data(10));
        let p = FakePayload::normal(12)
            .with_polls(polls)
            .with_default(PollAct::Silent);
        let mut s = sim_with(p);
        assert_eq!(s.setup(&session(1, 0, 60, 1, 64, b"")), 1);
        s.run_until(SimTime::from_secs(5));
        // SYNC at 0, echo at 5 ms, POLL at 5 ms, retries every 200 ms.
        let times: Vec<SimTime> = s.payload(12).polls_received();
        let want: Vec<SimTime> = (0..3.min(silent + 1))
            .map(|k| SimTime::ZERO + MS(5 + 200 * k as u64))
            .collect();
        assert_eq!(times, want, "{silent} silent");
        let end = s.ends();
        assert_eq!(end.len(), 1);
        assert_eq!((end[0].2, end[0].3), (SessionResult::Done, 1));
        if data {
            assert_eq!(s.downlinked(1), stream_bytes(12, 0, 10), "{silent} silent");
            assert_eq!(end[0].0, SimTime::ZERO + MS(5 + 200 * silent as u64 + 5));
        } else {
            assert!(s.downlinked(1).is_empty());
            assert_eq!(end[0].0, SimTime::ZERO + MS(5 + 600));
            assert_eq!(s.host.app.counters().polls_given_up, 1);
        }
        s.assert_balanced();
    }
}

#[test]
fn zero_length_replies_count_but_send_nothing() {
    let p = FakePayload::normal(12).with_default(PollAct::Data(0));
    let mut s = sim_with(p);
    assert_eq!(s.setup(&session(1, 0, 60, 4, 64, b"")), 1);
    s.run_until(SimTime::from_secs(5));
    let end = s.ends();
    assert_eq!((end[0].2, end[0].3), (SessionResult::Done, 4));
    assert!(s.downlinked(1).is_empty());
    assert_eq!(s.host.app.counters().frames_sent, 0);
    assert_eq!(s.host.app.accounting().session(1).unwrap().received, 0);
}

#[test]
fn max_packets_zero_ends_on_duration_n_ends_after_n() {
    // (max packets, end time, packets)
    let table: &[(u16, SimTime, u32)] = &[
        // 5 s at one cycle per 100 ms from 5 ms: cycles start at 5, 105, ..., 4905 ms.
        (0, SimTime::from_secs(5), 50),
        (5, SimTime::from_ms(405 + 5), 5),
        (1, SimTime::from_ms(10), 1),
    ];
    for &(max, end_t, packets) in table {
        let mut s = sim();
        assert_eq!(s.setup(&session(1, 0, 5, max, 64, b"")), 1);
        s.run_until(SimTime::from_secs(10));
        assert_eq!(
            s.ends(),
            vec![(end_t, 1, SessionResult::Done, packets)],
            "max {max}"
        );
        assert_eq!(s.payload(12).polls_received().len() as u32, packets);
        assert_eq!(s.downlinked(1), stream_bytes(12, 0, 64 * packets as usize));
        let st = s.status(1).unwrap();
        assert_eq!(
            (st.state, st.last_result),
            (SessionState::NotActive, SessionResult::Done)
        );
        s.assert_balanced();
    }
}

#[test]
fn oversize_reply_is_dropped_and_counts_as_an_attempt() {
    let big = [vec![2, 1], vec![7; 65]].concat();
    let raw = PollAct::Raw {
        bytes: big,
        delay: None,
        sport: None,
    };
    // Oversize twice, then data: the third attempt (sent at once after each) counts.
    let p = FakePayload::normal(12).with_polls(vec![raw.clone(), raw.clone(), PollAct::Data(64)]);
    let mut s = sim_with(p);
    assert_eq!(s.setup(&session(1, 0, 60, 1, 64, b"")), 1);
    s.run_until(SimTime::from_secs(2));
    assert_eq!(
        s.payload(12).polls_received(),
        vec![
            SimTime::from_ms(5),
            SimTime::from_ms(10),
            SimTime::from_ms(15)
        ]
    );
    let a = s.host.app.accounting();
    let l = a.session(1).unwrap();
    assert_eq!(l.dropped(DropReason::Oversize), 130);
    assert_eq!(l.downlinked, 64);
    assert_eq!(s.ends()[0].3, 1);
    // Oversize three times: the counter advances without data.
    let p = FakePayload::normal(12).with_default(raw);
    let mut s = sim_with(p);
    assert_eq!(s.setup(&session(1, 0, 60, 2, 64, b"")), 1);
    s.run_until(SimTime::from_secs(2));
    assert_eq!(s.payload(12).polls_received().len(), 6);
    assert_eq!(s.ends()[0].3, 2);
    assert!(s.downlinked(1).is_empty());
    s.assert_balanced();
}

#[test]
fn late_and_wrong_port_replies_are_dropped() {
    // The first reply comes 250 ms after its POLL (timeout 200 ms): Late. The retry's reply
    // comes from the wrong source port: Late too; the third attempt is answered normally.
    let p = FakePayload::normal(12).with_polls(vec![
        PollAct::DataAfter(20, MS(250)),
        PollAct::Raw {
            bytes: vec![2, 1, 9, 9, 9],
            delay: None,
            sport: Some(11),
        },
        PollAct::Data(30),
    ]);
    let mut s = sim_with(p);
    assert_eq!(s.setup(&session(1, 0, 60, 1, 64, b"")), 1);
    s.run_until(SimTime::from_secs(2));
    let a = s.host.app.accounting();
    let l = a.session(1).unwrap();
    assert_eq!(l.dropped(DropReason::Late), 23);
    assert_eq!(s.downlinked(1), stream_bytes(12, 20, 30));
    assert_eq!(s.ends()[0].3, 1);
    s.assert_balanced();
}

#[test]
fn malformed_poll_reply_is_dropped_and_the_request_keeps_waiting() {
    let p = FakePayload::normal(12).with_polls(vec![PollAct::Raw {
        bytes: vec![5, 1, 1, 2, 3],
        delay: None,
        sport: None,
    }]);
    let mut s = sim_with(p);
    assert_eq!(s.setup(&session(1, 0, 60, 1, 64, b"")), 1);
    s.run_until(SimTime::from_secs(2));
    let a = s.host.app.accounting();
    assert_eq!(a.session(1).unwrap().dropped(DropReason::Malformed), 5);
    // The retry went out at the timeout, not at the malformed reply.
    assert_eq!(s.payload(12).polls_received()[1], SimTime::from_ms(205));
    s.assert_balanced();
}

#[test]
fn start_time_past_zero_and_future() {
    // (timestamp, setup at s, start at s)
    let table: &[(u32, u64, u64)] = &[
        (0, 3, 3),
        (ts(1), 3, 3),
        (ts(3), 3, 3),
        (ts(10), 3, 10),
        (1, 3, 3), // 1970: long past
    ];
    for &(stamp, at, start) in table {
        let mut s = sim();
        s.run_until(SimTime::from_secs(at));
        assert_eq!(s.setup(&session(1, stamp, 5, 0, 64, b"")), 1);
        let st = s.status(1).unwrap();
        let want = if start == at {
            SessionState::Active
        } else {
            SessionState::Pending
        };
        assert_eq!(st.state, want, "timestamp {stamp}");
        s.run_until(SimTime::from_secs(30));
        assert_eq!(
            s.starts(),
            vec![(SimTime::from_secs(start), 1)],
            "timestamp {stamp}"
        );
        // The full duration runs from the actual start.
        assert_eq!(s.ends()[0].0, SimTime::from_secs(start + 5));
        assert_eq!(s.payload(12).syncs_received().len(), 1);
    }
}

#[test]
fn second_session_cannot_start_while_one_is_active() {
    let mut s = sim();
    assert_eq!(s.setup(&session(1, 0, 30, 0, 64, b"")), 1);
    assert_eq!(s.setup(&session(3, 0, 5, 0, 64, b"")), 0);
    assert_eq!(s.setup(&session(3, ts(1), 5, 0, 64, b"")), 0);
    // A future window after the active one is fine, and starts when its time comes.
    assert_eq!(s.setup(&session(3, ts(30), 5, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(40));
    assert_eq!(
        s.starts(),
        vec![(SimTime::ZERO, 1), (SimTime::from_secs(30), 3)]
    );
    assert_eq!(s.ends()[0].0, SimTime::from_secs(30));
    assert_eq!(s.ends()[1].0, SimTime::from_secs(35));
}

#[test]
fn buffering_streams_the_file_and_flushes_it_at_the_end() {
    // 8 kbit/s with 100-byte frames of 10 bytes overhead: 110 ms per frame.
    let mut c = cfg();
    c.sband = SbandConfig {
        rate_bps: 8_000,
        frame_data_bytes: 100,
        frame_overhead_bytes: 10,
        on: true,
    };
    let mut s = Sim::new(c, vec![]);
    // 20 packets of 200 bytes before the session: 4000 bytes in the file.
    let data = stream_bytes(13, 0, 4000);
    for chunk in data.chunks(200) {
        s.send_from(13, 40, 11, chunk);
    }
    assert_eq!(
        s.host.app.accounting().session(2).unwrap().buffered_now,
        4000
    );
    assert!(
        s.downlinked(2).is_empty(),
        "nothing is sent outside a session"
    );
    // The session runs [1 s, 6 s).
    assert_eq!(s.setup(&session(2, ts(1), 5, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(20));
    let down = s.downlinked(2);
    assert_eq!(down, data[..down.len()]);
    // 40 full frames take 4.4 s of the 5 s: everything goes down, in full frames.
    assert_eq!(down.len(), 4000);
    assert_eq!(s.host.app.counters().frames_sent, 40);
    let a = s.host.app.accounting();
    let l = a.session(2).unwrap();
    assert_eq!(l.buffered_now, 0);
    // Packets of 64 bytes were cut from the file: ceil(4000 / 64) = 63.
    assert_eq!(s.ends()[0].3, 63);
    assert!(l.is_balanced());
    // A shorter session leaves bytes behind: they are flushed (SessionEnded).
    let mut c = cfg();
    c.sband = SbandConfig {
        rate_bps: 8_000,
        frame_data_bytes: 100,
        frame_overhead_bytes: 10,
        on: true,
    };
    let mut s = Sim::new(c, vec![]);
    for chunk in stream_bytes(13, 0, 10_000).chunks(250) {
        s.send_from(13, 40, 11, chunk);
    }
    assert_eq!(s.setup(&session(2, 0, 5, 0, 50, b"")), 1);
    s.run_until(SimTime::from_secs(20));
    let a = s.host.app.accounting();
    let l = a.session(2).unwrap();
    // Frames start at 0, 110, ..., 4950 ms: 46 frames; the one on the air at 5 s completes.
    assert_eq!(l.downlinked, 4600);
    assert_eq!(l.dropped(DropReason::SessionEnded), 10_000 - 4600);
    assert_eq!(s.downlinked(2), stream_bytes(13, 0, 4600));
    assert_eq!(
        s.ends(),
        vec![(SimTime::from_secs(5), 2, SessionResult::Done, 92)]
    );
    assert!(l.is_balanced());
}

#[test]
fn buffering_packet_limit_counts_frame_size_packets() {
    let mut s = Sim::new(cfg(), vec![]);
    for chunk in stream_bytes(13, 0, 1000).chunks(100) {
        s.send_from(13, 40, 11, chunk);
    }
    // 3 packets of 64 bytes: 192 bytes go down, the rest is flushed.
    assert_eq!(s.setup(&session(2, 0, 60, 3, 64, b"")), 1);
    s.run_until(SimTime::from_secs(1));
    assert_eq!(s.ends(), vec![(SimTime::ZERO, 2, SessionResult::Done, 3)]);
    assert_eq!(s.downlinked(2), stream_bytes(13, 0, 192));
    let a = s.host.app.accounting();
    assert_eq!(a.session(2).unwrap().dropped(DropReason::SessionEnded), 808);
    s.assert_balanced();
}

#[test]
fn data_arriving_during_a_buffering_session_is_streamed() {
    let mut s = Sim::new(cfg(), vec![]);
    assert_eq!(s.setup(&session(2, 0, 10, 0, 64, b"")), 1);
    for k in 0..20u64 {
        s.run_until(SimTime::from_ms(100 * k));
        s.send_from(13, 40, 11, &stream_bytes(13, k * 200, 200));
    }
    s.run_until(SimTime::from_secs(11));
    assert_eq!(s.downlinked(2), stream_bytes(13, 0, 4000));
    s.assert_balanced();
}

#[test]
fn buffer_full_drops_whole_packets() {
    let mut c = cfg();
    c.sessions[1].buffer_capacity_bytes = 1000;
    let mut s = Sim::new(c, vec![]);
    for _ in 0..5 {
        s.send_from(13, 40, 11, &[1; 256]);
    }
    s.send_from(13, 40, 11, &[2; 232]);
    s.send_from(13, 40, 11, &[2; 231]);
    s.send_from(13, 40, 11, &[2; 257]);
    let a = s.host.app.accounting();
    let l = a.session(2).unwrap();
    // 3 x 256 + 232 = 1000 fit exactly; the 4th and 5th 256 and the 231 do not; 257 is
    // oversize.
    assert_eq!(l.buffered_now, 1000);
    assert_eq!(l.dropped(DropReason::BufferFull), 256 * 2 + 231);
    assert_eq!(l.dropped(DropReason::Oversize), 257);
    assert_eq!(l.received, 5 * 256 + 232 + 231 + 257);
    assert!(l.is_balanced());
    // Drops are logged as drop lines.
    let mut drops = 0;
    while let Some(e) = s.host.node.poll_event() {
        drops += usize::from(matches!(e, csp::node::NodeEvent::Drop { .. }));
    }
    assert_eq!(drops, 4);
}

#[test]
fn ingest_from_unknown_or_polling_payloads_is_dropped() {
    let mut s = sim();
    s.send_from(15, 40, 11, &[1, 2, 3]); // not configured
    s.send_from(12, 40, 11, &[1, 2]); // a polling payload
    let a = s.host.app.accounting();
    assert_eq!(a.unattributed.dropped(DropReason::UnknownSource), 5);
    assert!(a.is_balanced());
    let dropped: Vec<_> = s
        .outputs()
        .into_iter()
        .filter(|o| {
            matches!(
                o,
                PcOutput::Dropped {
                    reason: DropReason::UnknownSource,
                    session_id: None,
                    ..
                }
            )
        })
        .collect();
    assert_eq!(dropped.len(), 2);
    assert!(s.replies.is_empty(), "ingest has no reply");
}

#[test]
fn sband_failure_ends_the_session_with_sband_failure() {
    let mut c = cfg();
    c.sband.rate_bps = 10_000; // 1.02 s per frame: bytes pile up in the queue
    c.timeline = vec![TimedPcEvent {
        at: SimTime::from_secs(3),
        event: PcEvent::SbandFail,
    }];
    let mut s = Sim::new(c, vec![FakePayload::normal(12)]);
    assert_eq!(s.setup(&session(1, 0, 60, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(10));
    let (t, id, result, _) = s.ends()[0];
    assert_eq!(
        (t, id, result),
        (SimTime::from_secs(3), 1, SessionResult::SbandFailure)
    );
    let st = s.status(1).unwrap();
    assert_eq!(st.last_result, SessionResult::SbandFailure);
    let a = s.host.app.accounting();
    let l = a.session(1).unwrap();
    assert!(l.dropped(DropReason::SbandFailure) > 0);
    assert_eq!(l.queued_now, 0);
    assert!(l.is_balanced());
    // While failed, a new session fails at once; after restore it runs.
    assert_eq!(s.setup(&session(1, 0, 5, 0, 64, b"")), 1);
    assert_eq!(s.ends()[1].2, SessionResult::SbandFailure);
    assert_eq!(
        s.payload(12).syncs_received().len(),
        1,
        "no SYNC while failed"
    );
}

#[test]
fn sband_off_keeps_the_queue_and_a_finished_polling_session_drains() {
    let mut c = cfg();
    c.sband.on = false;
    c.timeline = vec![TimedPcEvent {
        at: SimTime::from_secs(20),
        event: PcEvent::SbandOn,
    }];
    let mut s = Sim::new(c, vec![FakePayload::normal(12)]);
    assert_eq!(s.setup(&session(1, 0, 5, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(10));
    assert_eq!(s.ends()[0].2, SessionResult::Done);
    assert!(s.downlinked(1).is_empty());
    assert_eq!(
        s.host.app.accounting().session(1).unwrap().queued_now,
        50 * 64
    );
    s.run_until(SimTime::from_secs(30));
    assert_eq!(s.downlinked(1), stream_bytes(12, 0, 50 * 64));
    let down: Vec<SimTime> = s
        .outputs()
        .into_iter()
        .filter_map(|o| match o {
            PcOutput::Downlinked { t, .. } => Some(t),
            _ => None,
        })
        .collect();
    // 3200 bytes in 1109-byte frames of 10.232 ms from 20 s.
    assert_eq!(
        down,
        (1..=3)
            .map(|k| SimTime::from_secs(20) + Duration::from_nanos(10_232_000 * k))
            .collect::<Vec<_>>()
    );
    s.assert_balanced();
}

#[test]
fn downlink_happens_when_the_frame_has_left() {
    let mut s = sim();
    assert_eq!(s.setup(&session(1, 0, 5, 1, 64, b"")), 1);
    s.run_until(SimTime::from_secs(1));
    let t: Vec<SimTime> = s
        .outputs()
        .into_iter()
        .filter_map(|o| match o {
            PcOutput::Downlinked {
                t,
                payload_addr: 12,
                ..
            } => Some(t),
            _ => None,
        })
        .collect();
    // POLL reply at 10 ms; one default frame lasts 10.232 ms.
    assert_eq!(
        t,
        vec![SimTime::from_ms(10) + Duration::from_nanos(10_232_000)]
    );
}

#[test]
fn reboot_loses_volatile_state_as_power_loss() {
    let mut c = cfg();
    c.sband.rate_bps = 10_000;
    let mut s = Sim::new(c, vec![FakePayload::normal(12)]);
    s.send_from(13, 40, 11, &[5; 100]);
    assert_eq!(s.setup(&session(1, 0, 60, 0, 64, b"")), 1);
    assert_eq!(s.setup(&session(2, ts(100), 60, 0, 64, b"")), 1);
    s.run_until(SimTime::from_secs(3));
    let now = s.now;
    s.host.reboot(now);
    let a = s.host.app.accounting();
    assert!(a.is_balanced(), "{a:#?}");
    assert_eq!(a.session(2).unwrap().dropped(DropReason::PowerLoss), 100);
    assert!(a.session(1).unwrap().dropped(DropReason::PowerLoss) > 0);
    assert_eq!(a.total().queued_now + a.total().buffered_now, 0);
    for id in [1, 2] {
        assert_eq!(s.status(id).unwrap(), Status::default(), "session {id}");
    }
    let polls = s.payload(12).polls_received().len();
    s.run_until(SimTime::from_secs(200));
    assert_eq!(
        s.payload(12).polls_received().len(),
        polls,
        "no polling after reboot"
    );
    assert!(s.starts().len() == 1, "the PENDING session was lost");
    // The ports answer again after the reboot.
    assert_eq!(s.setup(&session(1, 0, 5, 0, 64, b"")), 1);
}

#[test]
fn tmpc_reports_sessions_and_sband() {
    let mut s = sim();
    s.send_from(13, 40, 11, &[5; 100]);
    assert_eq!(s.setup(&session(1, 0, 60, 0, 64, b"")), 1);
    s.run_until(SimTime::from_ms(1000));
    let r = s.request(12, &[1]);
    assert_eq!(&r[..2], &[1, 1]);
    assert_eq!(r.len(), 2 + wire::Tmpc::LEN);
    let t = wire::Tmpc::parse(&r[2..]).unwrap();
    assert_eq!((t.slots[0].session_id, t.slots[0].payload_addr), (1, 12));
    assert_eq!(t.slots[0].state, 2);
    assert_eq!(t.slots[0].packets, 10);
    assert_eq!(t.slots[0].downlinked_bytes, 640);
    assert_eq!((t.slots[1].session_id, t.slots[1].buffer_bytes), (2, 100));
    assert_eq!(t.slots[3], wire::TmpcSlot::default());
    assert_eq!(t.sband_flags & wire::SBAND_ON, wire::SBAND_ON);
    assert_eq!(t.sband_downlinked_bytes, 640);
}

/// The console's `tm` is TMPC of the same instant, one `name value unit` line per field with
/// the ICD's names (`slots[0].state`, as `gs` names them), units and value names; no Debug
/// dump of the slots.
#[test]
fn console_tm_is_tmpc_one_field_a_line() {
    let mut s = sim();
    s.send_from(13, 40, 11, &[5; 100]);
    assert_eq!(s.setup(&session(1, 0, 60, 0, 64, b"")), 1);
    s.run_until(SimTime::from_ms(1000));
    let text = s.host.console("tm", s.now);
    let fields = <wire::Tmpc as csp::icd::Describe>::FIELDS;
    let names: Vec<String> = csp::icd::leaves(fields).into_iter().map(|l| l.0).collect();
    let got: Vec<&str> = text.lines().filter_map(|l| l.split(' ').next()).collect();
    assert_eq!(got, names, "{text}");
    for want in [
        "slots[0].session_id 1",
        "slots[0].payload_addr 12",
        "slots[0].state 2 (ACTIVE)",
        "slots[0].packets 10",
        "slots[0].downlinked_bytes 640 B",
        "slots[1].buffer_bytes 100 B",
        "sband_flags 0x1 (on)",
        "sband_downlinked_bytes 640 B",
    ] {
        assert!(text.lines().any(|l| l == want), "{want:?} in\n{text}");
    }
    assert!(!text.contains('{') && !text.contains("TmpcSlot"), "{text}");
}

#[test]
fn poll_period_zero_polls_back_to_back() {
    let mut c = cfg();
    c.sessions[0].mode = SessionMode::Polling {
        poll_period: Duration::ZERO,
        reply_timeout: MS(200),
    };
    let mut s = Sim::new(c, vec![FakePayload::normal(12)]);
    assert_eq!(s.setup(&session(1, 0, 5, 0, 254, b"")), 1);
    s.run_until(SimTime::from_secs(6));
    // One cycle per 5 ms reply latency after the 5 ms SYNC: 999 cycles in 5 s.
    let end = s.ends()[0];
    assert_eq!((end.0, end.3), (SimTime::from_secs(5), 999));
    s.assert_balanced();
}

#[test]
fn finish_reports_the_final_accounting() {
    let mut s = sim();
    s.send_from(13, 40, 11, &[5; 100]);
    assert_eq!(s.setup(&session(1, 0, 5, 3, 64, b"")), 1);
    s.run_until(SimTime::from_ms(12));
    let now = s.now;
    let h = &mut s.host;
    csp::node::App::finish(&mut h.app, &mut h.node, now);
    let Some(PcOutput::Final { t, accounting }) = s.host.poll_event() else {
        panic!("no final output")
    };
    assert_eq!(t, now);
    assert!(accounting.is_balanced());
    // One POLL reply of 64 bytes came in at 10 ms; its frame is on the air until 20.232 ms.
    let l = accounting.session(1).unwrap();
    assert_eq!((l.received, l.queued_now, l.downlinked), (64, 64, 0));
    assert_eq!(accounting.session(2).unwrap().buffered_now, 100);
    assert_eq!(accounting, s.host.app.accounting());
}

#[test]
fn a_payload_is_refused_setup_and_abort_but_not_status_unless_access_is_open() {
    use platform::addr::PayloadAccess;
    for access in [PayloadAccess::Icd, PayloadAccess::Open] {
        let mut c = cfg();
        c.payload_access = access;
        let mut s = Sim::new(c, vec![FakePayload::normal(12), FakePayload::normal(14)]);
        let icd = access == PayloadAccess::Icd;
        // Payload 15 has no fake behind it: the PC's replies to it are the stray packets.
        let ask = |s: &mut Sim, sport: u8, req: &[u8]| {
            s.send_from(15, sport, wire::PORT_CONTROL, req);
            let r = s.stray.pop().unwrap();
            assert_eq!((r.header.dst, r.header.dport), (15, sport));
            r.data
        };
        let setup = session(1, ts(100), 60, 0, 64, b"").to_request();
        assert_eq!(ask(&mut s, 40, &setup), vec![1, u8::from(!icd)]);
        let want = if icd {
            SessionState::NotActive
        } else {
            SessionState::Pending
        };
        assert_eq!(s.status(1).unwrap().state, want);
        if icd {
            assert_eq!(s.setup(&session(1, ts(100), 60, 0, 64, b"")), 1);
        }
        // STATUS is answered to a payload either way.
        assert_eq!(ask(&mut s, 41, &[wire::cmd::STATUS, 1])[..2], [2, 1]);
        assert_eq!(
            ask(&mut s, 42, &[wire::cmd::ABORT, 1]),
            vec![3, u8::from(!icd)]
        );
        let want = if icd {
            SessionState::Pending
        } else {
            SessionState::NotActive
        };
        assert_eq!(s.status(1).unwrap().state, want);
        assert_eq!(s.host.app.counters().denied, if icd { 2 } else { 0 });
    }
}

/// A CMP CLOCK set of the PC's clock to `unix_s` (as the FC sends its RTC).
fn clock_set(s: &mut Sim, unix_s: u32) {
    let mut req = vec![0x00, 6];
    req.extend_from_slice(&unix_s.to_be_bytes());
    req.extend_from_slice(&0u32.to_be_bytes());
    s.send_from(3, 40, 0, &req);
    let r = s.stray.pop().unwrap();
    assert_eq!((r.header.dst, &r.data[..2]), (3, &[0xff, 6][..]));
}

#[test]
fn a_pending_session_starts_when_the_pc_clock_reads_its_timestamp_after_the_clock_is_set() {
    // A session timed for 100 s, the clock set at 10 s: 50 s ahead, it starts at 50 s (and
    // keeps its 10 s); past the timestamp, at once; back to the epoch, 100 s later.
    for (set_to_s, start_s) in [(60, 50), (150, 10), (0, 110)] {
        let mut s = sim();
        assert_eq!(s.setup(&session(1, ts(100), 10, 0, 64, b"")), 1);
        s.run_until(SimTime::from_secs(10));
        clock_set(&mut s, ts(set_to_s));
        s.run_until(SimTime::from_secs(200));
        assert_eq!(
            s.starts(),
            vec![(SimTime::from_secs(start_s), 1)],
            "set to {set_to_s}"
        );
        assert_eq!(
            s.ends()[0].0,
            SimTime::from_secs(start_s + 10),
            "set to {set_to_s}"
        );
    }
}

#[test]
fn buffer_files_are_listed_read_at_stream_offsets_and_deleted_into_the_accounting() {
    use csp::reqrep::le::Repr;
    use m6p_nodes_pc::wire::{FileRead, FileStat, PORT_FILES};
    let mut s = Sim::new(cfg(), vec![]);
    let stat = |s: &mut Sim| FileStat::parse(&s.request(PORT_FILES, &[2, 13])[2..]).unwrap();
    let read = |s: &mut Sim, offset: u64, length: u8| {
        let q = FileRead {
            payload_addr: 13,
            offset,
            length,
        };
        let r = s.request(PORT_FILES, &[[3].as_slice(), &q.to_vec()].concat());
        assert_eq!(r[..2], [3, 1]);
        (
            u64::from_le_bytes(r[2..10].try_into().unwrap()),
            r[10..].to_vec(),
        )
    };
    for chunk in stream_bytes(13, 0, 1000).chunks(100) {
        s.send_from(13, 40, 11, chunk);
    }
    // FLIST: the one buffering session's file (payload 12 polls: no file).
    let l = s.request(PORT_FILES, &[1]);
    assert_eq!(l[..3], [1, 1, 1]);
    let want = FileStat {
        payload_addr: 13,
        session_id: 2,
        size_bytes: 1000,
        capacity_bytes: u32::try_from(m6p_nodes_pc::DEFAULT_BUFFER_CAPACITY_BYTES).unwrap(),
        head_offset: 0,
    };
    assert_eq!(FileStat::parse(&l[3..]).unwrap(), want);
    assert_eq!(stat(&mut s), want);
    // Reading takes nothing; the end gives no bytes.
    assert_eq!(read(&mut s, 100, 200), (100, stream_bytes(13, 100, 200)));
    assert_eq!(read(&mut s, 900, 200), (900, stream_bytes(13, 900, 100)));
    assert_eq!(read(&mut s, 5000, 10), (1000, vec![]));
    assert_eq!(stat(&mut s).size_bytes, 1000);
    // A session takes 3 packets of 64 from the head: the offsets stay the stream's.
    assert_eq!(s.setup(&session(2, 0, 60, 3, 64, b"")), 1);
    s.run_until(SimTime::from_ms(100));
    for chunk in stream_bytes(13, 1000, 500).chunks(100) {
        s.send_from(13, 40, 11, chunk);
    }
    let st = stat(&mut s);
    assert_eq!(
        (st.head_offset, st.size_bytes),
        (1000, 500),
        "flushed at the end"
    );
    assert_eq!(read(&mut s, 0, 50), (1000, stream_bytes(13, 1000, 50)));
    assert_eq!(read(&mut s, 1450, 200), (1450, stream_bytes(13, 1450, 50)));
    // FDELETE: the bytes are dropped as deleted; the file goes on from the end.
    assert_eq!(s.request(PORT_FILES, &[4, 13]), vec![4, 1, 0xf4, 1, 0, 0]);
    let st = stat(&mut s);
    assert_eq!((st.head_offset, st.size_bytes), (1500, 0));
    let a = s.host.app.accounting();
    assert_eq!(a.session(2).unwrap().dropped(DropReason::Deleted), 500);
    s.assert_balanced();
    let c = s.host.app.counters().clone();
    assert_eq!(
        (c.file_reads, c.file_bytes_read, c.file_deletes),
        (5, 400, 1)
    );
    // Failure replies: no such file, wrong lengths, a read of 0 or 201 bytes, a payload.
    for bad in [
        vec![2, 12],
        vec![2, 14],
        vec![4, 12],
        vec![1, 0],
        vec![2],
        vec![3, 13, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        vec![3, 13, 0, 0, 0, 0, 0, 0, 0, 0, 201],
        vec![9],
    ] {
        assert_eq!(s.request(PORT_FILES, &bad), vec![bad[0], 0], "{bad:02x?}");
    }
    let denied = c.denied;
    s.send_from(13, 41, PORT_FILES, &[1]);
    let r = s.stray.pop().unwrap();
    assert_eq!((r.header.dst, r.data.clone()), (13, vec![1, 0]));
    assert_eq!(s.host.app.counters().denied, denied + 1);
}

/// The PC saved in the middle of a polling session (a POLL out, its reply on the way, the
/// S-band sending) and loaded into a host built from the default configuration ends the
/// session as the original: the same outputs, end, downlinked bytes and saved bytes.
#[test]
fn a_pc_saved_mid_session_and_loaded_into_a_fresh_one_ends_it_the_same() {
    let run = || {
        let mut s = sim();
        assert_eq!(s.setup(&session(1, 0, 5, 0, 64, b"hello")), 1);
        s.run_until(SimTime::from_ms(2_347));
        s
    };
    let mut a = run();
    let mut b = run();
    let bytes = snap::to_bytes(&a.host);
    b.host = csp::node::Host::new(
        node_cfg(),
        m6p_nodes_pc::PcApp::new(m6p_nodes_pc::PcConfig::default()),
        SimTime::ZERO,
    );
    snap::load_from(&mut b.host, &bytes).unwrap();
    assert_eq!(snap::to_bytes(&b.host), bytes);
    for s in [&mut a, &mut b] {
        s.run_until(SimTime::from_secs(10));
    }
    assert_eq!(format!("{:?}", a.outputs()), format!("{:?}", b.outputs()));
    assert_eq!(a.ends(), b.ends());
    assert_eq!(a.ends().len(), 1);
    assert_eq!(a.downlinked(1), b.downlinked(1));
    assert_eq!(snap::to_bytes(&a.host), snap::to_bytes(&b.host));
}
