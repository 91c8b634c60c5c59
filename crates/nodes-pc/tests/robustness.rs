//! Malformed input on every port never panics and always gets the ICD failure reply (or a
//! counted drop on the ingest port), and the byte accounting balances after randomised
//! scenarios (payload behaviours, sessions, ingest, S-band events, reboots).
#![allow(clippy::unwrap_used)]

mod util;

use std::time::Duration;

use csp::SimTime;
use m6p_nodes_pc::{DropReason, PcEvent, PcOutput, SessionMode, TimedPcEvent};
use proptest::prelude::*;
use util::*;

#[test]
fn malformed_requests_get_failure_replies() {
    let long_setup = [vec![1u8], vec![0; 139]].concat();
    let short_setup = [vec![1u8], vec![1; 9]].concat();
    // (port, request, reply)
    let table: Vec<(u8, Vec<u8>, Vec<u8>)> = vec![
        (10, vec![], vec![0, 0]),
        (10, vec![0], vec![0, 0]),
        (10, vec![4, 1], vec![4, 0]),
        (10, vec![5], vec![5, 0]),
        (10, vec![255], vec![255, 0]),
        (10, short_setup, vec![1, 0]),
        (10, long_setup, vec![1, 0]),
        (10, vec![2], vec![2, 0]),
        (10, vec![2, 1, 0], vec![2, 0]),
        (10, vec![3], vec![3, 0]),
        (10, vec![3, 1, 0], vec![3, 0]),
        (12, vec![], vec![0, 0]),
        (12, vec![2], vec![2, 0]),
        (12, vec![1, 0], vec![1, 0]),
    ];
    for (port, req, want) in table {
        let mut s = Sim::new(cfg(), vec![]);
        assert_eq!(s.request(port, &req), want, "port {port} {req:02x?}");
        assert_eq!(s.host.app.counters().refused, 1);
    }
}

/// A port a random packet goes to: control, ingest, telemetry, an ephemeral port, other.
fn any_port() -> impl Strategy<Value = u8> {
    prop_oneof![Just(10u8), Just(11u8), Just(12u8), 32u8..=63, 0u8..=63]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    #[test]
    fn random_packets_never_panic_and_requests_are_answered(
        packets in proptest::collection::vec(
            (any_port(), 12u8..=17, 32u8..=63, proptest::collection::vec(any::<u8>(), 0..300), 0u64..500),
            1..40),
    ) {
        let mut s = Sim::new(cfg(), vec![FakePayload::normal(12), FakePayload::normal(14)]);
        // A polling session running, so that ephemeral ports are in use.
        prop_assert_eq!(s.setup(&session(1, 0, 30, 0, 64, b"x")), 1);
        for (port, src, sport, data, dt_ms) in packets {
            s.run_for(Duration::from_millis(dt_ms));
            let before = s.replies.len();
            s.send_from(src, sport, port, &data);
            let replies = &s.replies[before..];
            if (port == 10 || port == 12) && src == GS {
                prop_assert_eq!(replies.len(), 1);
                let r = &replies[0].data;
                prop_assert_eq!(r[0], data.first().copied().unwrap_or(0));
                prop_assert!(r[1] == 0 || r[1] == 1);
                if r[1] == 0 {
                    prop_assert_eq!(r.len(), 2);
                }
            } else if port == 11 {
                prop_assert!(replies.is_empty());
            }
            s.assert_balanced();
        }
        s.run_for(Duration::from_secs(40));
        s.assert_balanced();
    }
}

/// What a scripted payload does with one POLL.
fn poll_act() -> impl Strategy<Value = PollAct> {
    prop_oneof![
        4 => Just(PollAct::Full),
        2 => (0usize..=80).prop_map(PollAct::Data),
        2 => Just(PollAct::Silent),
        1 => (0usize..=64, 150u64..400).prop_map(|(n, d)| PollAct::DataAfter(n, Duration::from_millis(d))),
        1 => (0usize..100).prop_map(|n| PollAct::Raw { bytes: [vec![2, 1], vec![3; n]].concat(), delay: None, sport: None }),
        1 => proptest::collection::vec(any::<u8>(), 0..10).prop_map(|b| PollAct::Raw { bytes: b, delay: None, sport: None }),
        1 => (0usize..40).prop_map(|n| PollAct::Raw { bytes: [vec![2, 1], vec![4; n]].concat(), delay: None, sport: Some(20) }),
    ]
}

fn sync_act() -> impl Strategy<Value = SyncAct> {
    prop_oneof![
        6 => Just(SyncAct::Echo),
        1 => Just(SyncAct::Silent),
        1 => proptest::collection::vec(any::<u8>(), 0..6).prop_map(SyncAct::Raw),
    ]
}

/// One thing the ground, a payload or the scenario does at a time (ms).
#[derive(Debug, Clone)]
enum Step {
    Setup {
        id: u8,
        start_s: u64,
        duration_s: u16,
        max: u16,
        frame: u8,
        now: bool,
    },
    Abort(u8),
    Ingest {
        src: u8,
        len: usize,
    },
    Reboot,
}

fn step() -> impl Strategy<Value = (u64, Step)> {
    let s = prop_oneof![
        3 => (prop_oneof![Just(1u8), Just(2u8), Just(3u8), Just(9u8)], 0u64..60, 3u16..40, 0u16..20, 0u8..=255, any::<bool>())
            .prop_map(|(id, start_s, duration_s, max, frame, now)| Step::Setup { id, start_s, duration_s, max, frame, now }),
        1 => prop_oneof![Just(1u8), Just(2u8), Just(3u8)].prop_map(Step::Abort),
        4 => (prop_oneof![Just(13u8), Just(13u8), Just(12u8), Just(15u8)], 0usize..300)
            .prop_map(|(src, len)| Step::Ingest { src, len }),
        1 => Just(Step::Reboot),
    ];
    (0u64..60_000, s)
}

fn sband_event() -> impl Strategy<Value = TimedPcEvent> {
    (
        0u64..60_000,
        prop_oneof![
            Just(PcEvent::SbandFail),
            Just(PcEvent::SbandRestore),
            Just(PcEvent::SbandOff),
            Just(PcEvent::SbandOn)
        ],
    )
        .prop_map(|(ms, event)| TimedPcEvent {
            at: SimTime::from_ms(ms),
            event,
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn accounting_balances_after_random_scenarios(
        polls12 in proptest::collection::vec(poll_act(), 0..60),
        polls14 in proptest::collection::vec(poll_act(), 0..60),
        default12 in poll_act(),
        sync12 in sync_act(),
        steps in proptest::collection::vec(step(), 0..60),
        events in proptest::collection::vec(sband_event(), 0..6),
        rate_bps in prop_oneof![Just(1_000_000u64), Just(20_000u64), Just(2_000u64)],
        capacity in prop_oneof![Just(1_000u64), Just(100_000u64)],
        period_ms in prop_oneof![Just(0u64), Just(50u64), Just(100u64)],
    ) {
        let mut c = cfg();
        c.sband.rate_bps = rate_bps;
        c.sessions[1].buffer_capacity_bytes = capacity;
        c.sessions[0].mode = SessionMode::Polling {
            poll_period: Duration::from_millis(period_ms),
            reply_timeout: Duration::from_millis(200),
        };
        c.timeline = events;
        let p12 = FakePayload::normal(12).with_polls(polls12).with_default(default12).with_sync(sync12);
        let p14 = FakePayload::normal(14).with_polls(polls14);
        let mut s = Sim::new(c, vec![p12, p14]);
        let mut steps = steps;
        steps.sort_by_key(|(t, _)| *t);
        for (t_ms, st) in steps {
            s.run_until(SimTime::from_ms(t_ms));
            match st {
                Step::Setup { id, start_s, duration_s, max, frame, now } => {
                    let stamp = if now { 0 } else { ts(start_s) };
                    let _ = s.setup(&session(id, stamp, duration_s, max, frame, b"sync"));
                }
                Step::Abort(id) => { let _ = s.abort(id); }
                Step::Ingest { src, len } => s.send_from(src, 40, 11, &vec![7; len]),
                Step::Reboot => { let now = s.now; s.host.reboot(now); }
            }
            s.assert_balanced();
        }
        s.run_until(SimTime::from_secs(120));
        let a = s.host.app.accounting();
        prop_assert!(a.is_balanced(), "{:#?}", a);
        // The sink saw exactly what the ledgers hold.
        let mut down = 0u64;
        let mut dropped = 0u64;
        for o in s.outputs() {
            match o {
                PcOutput::Downlinked { bytes, .. } => down += bytes.len() as u64,
                PcOutput::Dropped { bytes, .. } => dropped += bytes,
                _ => {}
            }
        }
        let total = a.total();
        prop_assert_eq!(down, total.downlinked);
        prop_assert_eq!(dropped, total.dropped_total());
        // Unattributed bytes are only ever UnknownSource.
        prop_assert_eq!(a.unattributed.dropped_total(), a.unattributed.dropped(DropReason::UnknownSource));
        // No session ends without having started.
        prop_assert!(s.ends().len() <= s.starts().len());
    }
}
