//! The payload driven through `csp::node::Host` with hand-built requests from the PC (6).
#![allow(clippy::unwrap_used)]

use std::sync::Arc;
use std::time::Duration;

use csp::node::{Host, IfaceConfig, NodeConfig, Transmit};
use csp::router::Route;
use csp::{Header, Packet, SimTime};
use m6p_nodes_payload::stream::frame_len;
use m6p_nodes_payload::{
    Behaviour, Generator, How, PayloadApp, PayloadConfig, PayloadOutput, PushConfig,
    check_counter_stream, counter_stream,
};
use proptest::prelude::*;

const ME: u8 = 12;
const PC: u8 = 6;
const SPORT: u8 = 40;
const LAT: Duration = Duration::from_millis(5);

fn host(cfg: PayloadConfig) -> Host<PayloadApp> {
    let mut c = NodeConfig::new("P12", ME);
    c.ifaces = vec![IfaceConfig::packet("payload-can")];
    c.routes.set_default(Route::direct(0));
    Host::new(c, PayloadApp::new(cfg), SimTime::ZERO)
}

fn ms(t: u64) -> SimTime {
    SimTime::from_ms(t)
}

/// Deliver request `data` from the PC to the payload's port 10 at `t`.
fn request(h: &mut Host<PayloadApp>, data: &[u8], t: SimTime) {
    h.handle_packet(
        0,
        Packet::new(Header::new(PC, ME, 10, SPORT), data.to_vec()),
        t,
    );
}

/// Everything the node sent so far.
fn drain(h: &mut Host<PayloadApp>) -> Vec<Packet> {
    std::iter::from_fn(|| h.node.poll_transmit())
        .map(|tx| match tx {
            Transmit::Packet { packet, .. } => packet,
            Transmit::Can { .. } => panic!("no CAN iface here"),
        })
        .collect()
}

/// Run every timer due up to `end`, returning what was sent and when.
fn run_until(h: &mut Host<PayloadApp>, end: SimTime) -> Vec<(SimTime, Packet)> {
    let mut out = Vec::new();
    while let Some(t) = h.poll_timeout().filter(|&t| t <= end) {
        h.handle_timeout(t);
        out.extend(drain(h).into_iter().map(|p| (t, p)));
    }
    out
}

/// Send a request at `t` and return the reply data (None if nothing came by `t + 400 ms`).
fn ask(h: &mut Host<PayloadApp>, data: &[u8], t: SimTime) -> Option<Vec<u8>> {
    request(h, data, t);
    assert!(
        drain(h).is_empty(),
        "a reply never leaves before its latency"
    );
    let sent = run_until(h, t + Duration::from_millis(400));
    assert!(sent.len() <= 1, "one reply per request: {sent:?}");
    sent.into_iter().next().map(|(_, p)| {
        assert_eq!(p.header, Header::new(ME, PC, SPORT, 10), "reply to 6:40");
        p.data
    })
}

fn with(behaviour: Behaviour) -> PayloadConfig {
    PayloadConfig {
        behaviour,
        ..PayloadConfig::default()
    }
}

#[test]
fn sync_is_echoed_identically() {
    let mut h = host(PayloadConfig::default());
    assert_eq!(
        ask(&mut h, b"\x01Send telemetry", ms(0)).unwrap(),
        b"\x01\x01Send telemetry"
    );
    assert_eq!(ask(&mut h, &[1], ms(10)).unwrap(), vec![1, 1]);
    let max: Vec<u8> = std::iter::once(1).chain(0..128u8).collect();
    let mut want = vec![1, 1];
    want.extend(0..128u8);
    assert_eq!(ask(&mut h, &max, ms(20)).unwrap(), want);
    assert_eq!(h.app.counters().syncs, 3);
    assert_eq!(h.app.counters().produced_bytes, 0, "SYNC produces no data");
}

#[test]
fn poll_returns_the_next_bytes_of_the_counter_stream() {
    let mut h = host(PayloadConfig::default());
    let r = ask(&mut h, &[2, 64], ms(0)).unwrap();
    assert_eq!(r[..2], [2, 1]);
    assert_eq!(r[2..], counter_stream(ME, 0, 64));
    // Successive POLLs of any size concatenate to the stream.
    let mut got = r[2..].to_vec();
    for (i, fs) in [1u8, 254, 17, 100, 254, 3, 200]
        .into_iter()
        .cycle()
        .take(60)
        .enumerate()
    {
        let r = ask(&mut h, &[2, fs], ms(10 * (i as u64 + 1))).unwrap();
        assert_eq!(r.len(), 2 + usize::from(fs), "unlimited rate: full frames");
        got.extend_from_slice(&r[2..]);
    }
    assert_eq!(got, counter_stream(ME, 0, got.len()));
    let c = check_counter_stream(&got);
    assert!(c.is_clean(), "{c:?}");
    assert_eq!(c.first_seq, Some(0));
    assert_eq!(h.app.counters().produced_bytes, got.len() as u64);
    assert_eq!(h.app.counters().poll_bytes, got.len() as u64);
    assert_eq!(h.app.counters().polls, 61);
}

#[test]
fn a_lost_reply_shows_as_the_missing_seqs_it_held() {
    let mut h = host(PayloadConfig::default());
    let mut replies = Vec::new();
    for i in 0..40 {
        replies.push(ask(&mut h, &[2, 200], ms(10 * i)).unwrap()[2..].to_vec());
    }
    // The ground never got reply 17: bytes [3400, 3600) of the stream.
    let (lo, hi) = (17 * 200, 18 * 200);
    let downlink: Vec<u8> = replies
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != 17)
        .flat_map(|(_, r)| r.clone())
        .collect();
    // The seqs of every frame overlapping the lost range.
    let mut start = 0;
    let mut want = Vec::new();
    for seq in 0u32.. {
        let end = start + frame_len(seq);
        if start >= hi {
            break;
        }
        if end > lo {
            want.push(seq);
        }
        start = end;
    }
    let c = check_counter_stream(&downlink);
    assert_eq!(c.missing_seqs, want);
    assert_eq!(c.frames_bad, 1, "the frame cut at the start of the gap");
    assert!(!c.is_clean());
}

#[test]
fn no_ack_never_answers_sync_but_polls() {
    let mut h = host(with(Behaviour::NoAck));
    assert_eq!(ask(&mut h, b"\x01hello", ms(0)), None);
    assert_eq!(h.poll_timeout(), None, "nothing queued");
    assert_eq!(ask(&mut h, &[2, 10], ms(10)).unwrap().len(), 12);
    assert_eq!(h.app.counters().ignored, 1);
}

#[test]
fn wrong_echo_differs() {
    let mut h = host(with(Behaviour::WrongEcho));
    let r = ask(&mut h, b"\x01hello", ms(0)).unwrap();
    assert_eq!(r[..2], [1, 1]);
    assert_eq!(r.len(), 7);
    assert_ne!(&r[2..], b"hello");
    assert_ne!(
        ask(&mut h, &[1], ms(10)).unwrap(),
        vec![1, 1],
        "empty echo differs too"
    );
}

#[test]
fn silent_for_ignores_n_polls_then_answers_from_where_it_was() {
    let mut h = host(with(Behaviour::SilentFor { polls: 2 }));
    assert_eq!(ask(&mut h, &[2, 50], ms(0)), None);
    assert_eq!(ask(&mut h, &[2, 50], ms(100)), None);
    let r = ask(&mut h, &[2, 50], ms(200)).unwrap();
    assert_eq!(
        r[2..],
        counter_stream(ME, 0, 50),
        "ignored POLLs take nothing"
    );
    assert!(ask(&mut h, &[2, 50], ms(300)).is_some());
    assert_eq!(h.app.counters().ignored, 2);
    assert_eq!(h.app.counters().polls, 4);
}

#[test]
fn silent_ignores_everything() {
    let mut h = host(with(Behaviour::Silent));
    assert_eq!(ask(&mut h, b"\x01x", ms(0)), None);
    assert_eq!(ask(&mut h, &[2, 10], ms(10)), None);
    assert_eq!(ask(&mut h, &[9, 9], ms(20)), None);
    assert_eq!(h.app.counters().ignored, 3);
    assert_eq!(h.app.counters().replies, 0);
}

#[test]
fn oversize_replies_frame_size_plus_extra() {
    let mut h = host(with(Behaviour::Oversize { extra_bytes: 10 }));
    let r = ask(&mut h, &[2, 64], ms(0)).unwrap();
    assert_eq!(r.len(), 2 + 74);
    assert_eq!(r[2..], counter_stream(ME, 0, 74));
    assert_eq!(
        h.app.counters().produced_bytes,
        74,
        "rejected data still produced"
    );
    // Capped by the CAN MTU: 2 + 254 bytes.
    assert_eq!(ask(&mut h, &[2, 250], ms(10)).unwrap().len(), 256);
}

#[test]
fn oversize_pads_when_the_stream_is_short() {
    let file: Arc<[u8]> = vec![7u8; 20].into();
    let mut h = host(PayloadConfig {
        generator: Generator::Bytes(file),
        behaviour: Behaviour::Oversize { extra_bytes: 5 },
        ..PayloadConfig::default()
    });
    let r = ask(&mut h, &[2, 30], ms(0)).unwrap();
    assert_eq!(r.len(), 2 + 35);
    assert_eq!(r[2..22], [7; 20]);
    assert_eq!(r[22..], [0; 15]);
    assert_eq!(h.app.counters().produced_bytes, 20);
    assert_eq!(h.app.counters().padding_bytes, 15);
}

#[test]
fn garbage_has_a_wrong_command_id_and_produces_nothing() {
    let mut h = host(with(Behaviour::Garbage));
    for i in 0..50 {
        let r = ask(&mut h, &[2, 64], ms(10 * i)).unwrap();
        assert_ne!(r[0], 2);
        assert!(r.len() >= 2 && r.len() <= 2 + 64);
        let s = ask(&mut h, b"\x01abc", ms(10 * i + 5)).unwrap();
        assert_ne!(s[0], 1);
    }
    assert_eq!(h.app.counters().produced_bytes, 0);
}

#[test]
fn zero_length_answers_with_no_data() {
    let mut h = host(with(Behaviour::ZeroLength));
    assert_eq!(ask(&mut h, &[2, 64], ms(0)).unwrap(), vec![2, 1]);
    assert_eq!(ask(&mut h, b"\x01ok", ms(10)).unwrap(), b"\x01\x01ok");
    assert_eq!(h.app.counters().produced_bytes, 0);
}

#[test]
fn latency_is_honoured() {
    let mut h = host(PayloadConfig::default());
    let t = ms(1000);
    request(&mut h, &[2, 8], t);
    assert_eq!(h.poll_timeout(), Some(t + LAT));
    h.handle_timeout(t + (LAT - Duration::from_nanos(1)));
    assert!(drain(&mut h).is_empty(), "not before now + latency");
    h.handle_timeout(t + LAT);
    assert_eq!(drain(&mut h).len(), 1);

    let mut h = host(with(Behaviour::Slow {
        extra: Duration::from_millis(300),
    }));
    request(&mut h, &[1], t);
    assert_eq!(h.poll_timeout(), Some(t + Duration::from_millis(305)));
}

#[test]
fn replies_keep_request_order_across_a_behaviour_change() {
    let mut h = host(PayloadConfig {
        behaviour: Behaviour::Slow {
            extra: Duration::from_millis(100),
        },
        timeline: vec![(ms(1), Behaviour::Normal)],
        ..PayloadConfig::default()
    });
    request(&mut h, b"\x01A", ms(0));
    request(&mut h, b"\x01B", ms(2));
    let sent = run_until(&mut h, ms(1000));
    let got: Vec<(SimTime, Vec<u8>)> = sent.into_iter().map(|(t, p)| (t, p.data)).collect();
    assert_eq!(
        got,
        vec![
            (ms(105), b"\x01\x01A".to_vec()),
            (ms(105), b"\x01\x01B".to_vec())
        ]
    );
    assert_eq!(h.app.behaviour(), &Behaviour::Normal);
}

#[test]
fn timeline_switches_behaviour_at_its_time() {
    let mut h = host(PayloadConfig {
        behaviour: Behaviour::NoAck,
        timeline: vec![
            (ms(2000), Behaviour::ZeroLength),
            (ms(1000), Behaviour::Normal),
        ],
        ..PayloadConfig::default()
    });
    assert_eq!(ask(&mut h, b"\x01s", ms(0)), None);
    assert_eq!(ask(&mut h, b"\x01s", ms(1000)).unwrap(), b"\x01\x01s");
    assert_eq!(ask(&mut h, &[2, 9], ms(1500)).unwrap().len(), 11);
    assert_eq!(h.app.behaviour(), &Behaviour::Normal);
    assert_eq!(ask(&mut h, &[2, 9], ms(2000)).unwrap(), vec![2, 1]);
}

#[test]
fn rate_limits_what_a_poll_gets() {
    let rate = 1000u64;
    let mut h = host(PayloadConfig {
        rate_bytes_per_s: Some(rate),
        ..PayloadConfig::default()
    });
    // Right after start: 5 ms of data by the time the reply leaves.
    let r = ask(&mut h, &[2, 64], ms(0)).unwrap();
    assert_eq!(r.len(), 2 + 5);
    let mut got = r[2..].to_vec();
    for i in 1..300u64 {
        let t = ms(37 * i);
        let r = ask(&mut h, &[2, 64], t).unwrap();
        got.extend_from_slice(&r[2..]);
        let elapsed_ns = (t + LAT).as_ns();
        let produced = h.app.counters().produced_bytes;
        assert!(
            u128::from(produced) * 1_000_000_000 <= u128::from(rate) * u128::from(elapsed_ns),
            "produced {produced} at {elapsed_ns} ns"
        );
    }
    // 37 ms of data (37 bytes) per POLL: the stream is cut short each time, yet whole.
    assert!(got.len() > 10_000);
    assert_eq!(got, counter_stream(ME, 0, got.len()));
}

#[test]
fn a_file_is_sent_once_then_zero_length() {
    let file: Arc<[u8]> = (0..=199u8).collect::<Vec<_>>().into();
    let mut h = host(PayloadConfig {
        generator: Generator::Bytes(file.clone()),
        ..PayloadConfig::default()
    });
    let a = ask(&mut h, &[2, 150], ms(0)).unwrap();
    let b = ask(&mut h, &[2, 150], ms(10)).unwrap();
    let c = ask(&mut h, &[2, 150], ms(20)).unwrap();
    assert_eq!(a[2..], file[..150]);
    assert_eq!(b[2..], file[150..]);
    assert_eq!(c, vec![2, 1]);
    assert_eq!(h.app.counters().produced_bytes, 200);
}

#[test]
fn push_sends_packets_of_the_configured_size_at_the_rate() {
    let mut h = host(PayloadConfig {
        push: Some(PushConfig {
            pc_addr: 6,
            pc_port: 11,
            packet_bytes: 100,
            rate_bytes_per_s: 1000,
            start: ms(1000),
            stop: Some(ms(2000)),
        }),
        ..PayloadConfig::default()
    });
    let sent = run_until(&mut h, ms(5000));
    assert_eq!(sent.len(), 10);
    let mut data = Vec::new();
    for (k, (t, p)) in sent.iter().enumerate() {
        assert_eq!(*t, ms(1000 + 100 * k as u64));
        // Unsolicited: from the payload's own port, never its ICD port 10.
        assert_eq!(p.header, Header::new(ME, 6, 11, h.node.own_port()));
        assert_eq!(p.data.len(), 100);
        data.extend_from_slice(&p.data);
    }
    assert_eq!(data, counter_stream(ME, 0, 1000));
    assert_eq!(h.app.counters().pushed_bytes, 1000);
    assert_eq!(h.app.counters().pushed_packets, 10);
    assert_eq!(h.poll_timeout(), None, "stopped");
}

#[test]
fn push_is_limited_by_the_generator_rate() {
    let mut h = host(PayloadConfig {
        rate_bytes_per_s: Some(500),
        push: Some(PushConfig {
            packet_bytes: 200,
            rate_bytes_per_s: 1000,
            start: ms(1000),
            stop: Some(ms(3000)),
            ..PushConfig::default()
        }),
        ..PayloadConfig::default()
    });
    let sent = run_until(&mut h, ms(5000));
    let total: usize = sent.iter().map(|(_, p)| p.data.len()).sum();
    // Slots at 1.0, 1.2, ... 2.8 s; the last one sees 2.8 s x 500 B/s = 1400 bytes made.
    assert_eq!(total, 1400);
    assert_eq!(sent[0].1.data.len(), 200, "500 bytes accumulated by 1 s");
    assert!(sent.iter().all(|(_, p)| p.data.len() <= 200));
}

#[test]
fn reboot_loses_queued_replies_but_not_the_stream() {
    let mut h = host(PayloadConfig::default());
    let a = ask(&mut h, &[2, 100], ms(0)).unwrap();
    request(&mut h, &[2, 100], ms(10));
    h.reboot(ms(12));
    assert!(
        run_until(&mut h, ms(100)).is_empty(),
        "the queued reply is lost"
    );
    assert_eq!(h.app.counters().lost_on_reset, 1);
    let b = ask(&mut h, &[2, 100], ms(200)).unwrap();
    assert_eq!(b[2..], counter_stream(ME, 100, 100), "no gap in the stream");
    assert_eq!(a[2..], counter_stream(ME, 0, 100));
}

#[test]
fn its_events_are_the_syncs_and_produced_bytes() {
    let cfg = PayloadConfig {
        push: Some(PushConfig {
            packet_bytes: 50,
            rate_bytes_per_s: 500,
            start: ms(500),
            stop: Some(ms(550)),
            ..PushConfig::default()
        }),
        ..PayloadConfig::default()
    };
    let mut c = NodeConfig::new("P13", ME);
    c.ifaces = vec![IfaceConfig::packet("p")];
    c.routes.set_default(Route::direct(0));
    let app = PayloadApp::new(cfg);
    let mut h = Host::new(c, app, SimTime::ZERO);
    request(&mut h, b"\x01go", ms(0));
    request(&mut h, &[2, 30], ms(10));
    assert_eq!(run_until(&mut h, ms(1000)).len(), 3);
    let out: Vec<PayloadOutput> = std::iter::from_fn(|| h.poll_event()).collect();
    assert_eq!(
        out,
        vec![
            PayloadOutput::SyncReceived {
                t: ms(0),
                msg: b"go".to_vec()
            },
            PayloadOutput::Produced {
                t: ms(15),
                bytes: 30,
                how: How::PollReply
            },
            PayloadOutput::Produced {
                t: ms(500),
                bytes: 50,
                how: How::Push
            },
        ]
    );
}

#[test]
fn a_flood_is_bounded_by_the_reply_queue() {
    let mut h = host(PayloadConfig::default());
    for _ in 0..40 {
        request(&mut h, &[1, 7], ms(0));
    }
    assert_eq!(run_until(&mut h, ms(100)).len(), 32);
    assert_eq!(h.app.counters().queue_full, 8);
}

#[test]
fn malformed_requests_get_failure_replies() {
    let mut h = host(PayloadConfig::default());
    assert_eq!(ask(&mut h, &[2, 0], ms(0)).unwrap(), vec![2, 0]);
    assert_eq!(ask(&mut h, &[2, 255], ms(10)).unwrap(), vec![2, 0]);
    assert_eq!(ask(&mut h, &[2], ms(20)).unwrap(), vec![2, 0]);
    assert_eq!(ask(&mut h, &[2, 5, 5], ms(30)).unwrap(), vec![2, 0]);
    assert_eq!(ask(&mut h, &[3, 1], ms(40)).unwrap(), vec![3, 0]);
    assert_eq!(ask(&mut h, &[], ms(50)).unwrap(), vec![0, 0]);
    let mut long = vec![1u8];
    long.extend([0x55; 129]);
    assert_eq!(ask(&mut h, &long, ms(60)).unwrap(), vec![1, 0]);
    assert_eq!(h.app.counters().malformed, 7);
    assert_eq!(h.app.counters().produced_bytes, 0);
}

/// A whole run's replies under `Garbage` with `seed`.
fn garbage_run(seed: u64) -> Vec<Vec<u8>> {
    let mut h = host(PayloadConfig {
        behaviour: Behaviour::Garbage,
        seed,
        ..PayloadConfig::default()
    });
    (0..20)
        .map(|i| ask(&mut h, &[2, 100], ms(10 * i)).unwrap())
        .collect()
}

#[test]
fn runs_are_deterministic_in_the_seed() {
    assert_eq!(garbage_run(7), garbage_run(7));
    assert_ne!(garbage_run(7), garbage_run(8));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn any_request_gets_exactly_one_sane_reply(
        data in proptest::collection::vec(any::<u8>(), 0..=255usize),
    ) {
        let mut h = host(PayloadConfig::default());
        let r = ask(&mut h, &data, ms(0)).unwrap();
        let cmd = data.first().copied().unwrap_or(0);
        prop_assert_eq!(r[0], cmd);
        let valid = match data.as_slice() {
            [1, msg @ ..] => msg.len() <= 128,
            [2, fs] => (1..=254).contains(fs),
            _ => false,
        };
        if valid {
            prop_assert_eq!(r[1], 1);
        } else {
            prop_assert_eq!(r, vec![cmd, 0]);
        }
    }

    #[test]
    fn any_behaviour_and_request_never_panics(
        which in 0usize..9,
        arg in any::<u8>(),
        reqs in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..=40usize), 1..20),
    ) {
        let b = [
            Behaviour::Normal,
            Behaviour::NoAck,
            Behaviour::WrongEcho,
            Behaviour::Slow { extra: Duration::from_millis(u64::from(arg)) },
            Behaviour::SilentFor { polls: u32::from(arg % 5) },
            Behaviour::Silent,
            Behaviour::Oversize { extra_bytes: arg },
            Behaviour::Garbage,
            Behaviour::ZeroLength,
        ][which].clone();
        let mut h = host(PayloadConfig {
            behaviour: b,
            rate_bytes_per_s: Some(u64::from(arg) * 10),
            ..PayloadConfig::default()
        });
        for (i, r) in reqs.iter().enumerate() {
            request(&mut h, r, ms(i as u64));
        }
        let sent = run_until(&mut h, ms(10_000));
        prop_assert!(sent.len() <= reqs.len());
        for (_, p) in &sent {
            prop_assert!(p.data.len() >= 2 && p.data.len() <= 256);
        }
    }
}

#[test]
fn push_slots_missed_while_off_are_skipped_not_burst() {
    let mut h = host(PayloadConfig {
        push: Some(PushConfig {
            packet_bytes: 100,
            rate_bytes_per_s: 1000,
            ..PushConfig::default()
        }),
        ..PayloadConfig::default()
    });
    assert_eq!(run_until(&mut h, ms(1000)).len(), 11, "slots 0.0 ..= 1.0 s");
    // Off from 1 s to 5 s: no timers run; it boots again at 5 s.
    h.reboot(ms(5000));
    let sent = run_until(&mut h, ms(5050));
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0].0, ms(5000));
    // The stream continues where it stopped.
    assert_eq!(sent[0].1.data, counter_stream(ME, 1100, 100));
}

/// A payload saved mid-push, with a POLL's reply queued behind its latency, and loaded into
/// one built from the defaults, goes on as the original: the same packets at the same
/// instants, the same stream bytes, the same counts.
#[test]
fn a_payload_saved_mid_push_and_loaded_into_a_fresh_one_goes_on_the_same() {
    let cfg = PayloadConfig {
        behaviour: Behaviour::Slow {
            extra: Duration::from_millis(20),
        },
        push: Some(PushConfig {
            pc_addr: 6,
            pc_port: 11,
            packet_bytes: 100,
            rate_bytes_per_s: 1000,
            start: ms(1000),
            stop: Some(ms(3000)),
        }),
        ..PayloadConfig::default()
    };
    let mut a = host(cfg);
    run_until(&mut a, ms(1450));
    request(&mut a, &[2, 100, 0], ms(1450));
    // As the node's task does after every input: the outputs are taken (a snapshot of an
    // outbox that holds some is refused).
    while a.poll_event().is_some() {}
    let bytes = snap::to_bytes(&a);
    let mut b = host(PayloadConfig::default());
    snap::load_from(&mut b, &bytes).unwrap();
    assert_eq!(snap::to_bytes(&b), bytes);
    let (sa, sb) = (run_until(&mut a, ms(5000)), run_until(&mut b, ms(5000)));
    assert!(sa.len() > 15, "{}", sa.len());
    assert_eq!(sa, sb);
    assert_eq!(a.app.counters(), b.app.counters());
    assert_eq!(snap::to_bytes(&a), snap::to_bytes(&b));
}
