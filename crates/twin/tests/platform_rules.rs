//! The rules a payload and the ground live under, on a running twin, checked by an
//! independent Python client written from the ICD (`tests/rules_decode.py`) over a real
//! KISS/TCP socket as ground node 17 and, on a second connection, as payload 14: RDP-, HMAC-
//! and XTEA-flagged pings to every node go unanswered (ICD 1.6); the payload gets only the
//! FC commands ICD 4.1 stars and the PC's STATUS, not SETUP or ABORT (ICD 3.1.1); a SETUP
//! timed from RTCSTMGET after an RTCSTMSET of +1000 s starts when the platform's time reads
//! its timestamp (ICD 3.1.3). The default scenario's platform, real time, about 15 s.
#![allow(clippy::unwrap_used)]

use std::time::Duration;

use csp::SimTime;

#[path = "common/decoder.rs"]
mod decoder;

#[test]
fn python_client_finds_flags_discarded_payloads_limited_and_sessions_on_platform_time() {
    let mut opts = decoder::default_scenario_options(20);
    opts.trace = true;
    let (text, report) = decoder::run_decoder(opts, "rules_decode.py", &[], 45);

    // Every node discarded what it was sent flagged, by its reason.
    for (name, addr) in [
        ("COMM1", 1),
        ("COMM2", 2),
        ("FC", 3),
        ("EPS", 4),
        ("ECU", 5),
        ("PC", 6),
        ("PL12", 12),
        ("PL13", 13),
    ] {
        let node = report.nodes.iter().find(|n| n.addr == addr).unwrap();
        use csp::drop::DropReason;
        for reason in [DropReason::Rdp, DropReason::Xtea, DropReason::Hmac] {
            assert_eq!(
                node.counters.drops.get(&reason),
                Some(&1),
                "{name}: {:?}",
                node.counters
            );
        }
    }

    // The session starts when the PC's clock reads the SETUP's timestamp. The PC's clock is
    // what the FC's last CMP CLOCK before the start set it to, run on from the instant the
    // PC took it (the packet's last frame off the main bus).
    let timestamp_s: i128 = text
        .lines()
        .find_map(|l| l.strip_prefix("SETUP timestamp "))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    let started = report.sessions.runs.first().unwrap().started.unwrap();
    let syncs: Vec<(SimTime, i128)> = decoder::packets_on(&report, "main", "FC")
        .into_iter()
        .filter(|(_, p)| {
            p.header.dst == 6 && p.header.dport == 0 && p.data.get(..2) == Some(&[0, 6])
        })
        .map(|(t, p)| {
            let be =
                |i: usize| i128::from(u32::from_be_bytes(p.data[i..i + 4].try_into().unwrap()));
            (t, be(2) * 1_000_000_000 + be(6))
        })
        .collect();
    assert!(syncs.len() >= 2, "at boot and after RTCSTMSET: {syncs:?}");
    let (taken, clock_ns) = *syncs.iter().rev().find(|(t, _)| *t <= started).unwrap();
    let ahead_ns = u64::try_from(timestamp_s * 1_000_000_000 - clock_ns).unwrap();
    let due = taken + Duration::from_nanos(ahead_ns);
    eprintln!("session due at {due:?} by the PC's clock, started at {started:?}");
    let tick = SimTime::from_ms(100);
    assert!(
        started >= due && started.as_ns() - due.as_ns() <= tick.as_ns(),
        "due {due:?}, started {started:?}"
    );
    // The FC's RTC moved 1000 s: the PC's clock followed it.
    let true_ns = |t: SimTime| i128::from(report_epoch()) * 1_000_000_000 + i128::from(t.as_ns());
    assert!((clock_ns - true_ns(taken) - 1_000_000_000_000).abs() < 2_000_000_000);
}

/// The default scenario's start (`decoder::default_scenario_options`).
fn report_epoch() -> u64 {
    decoder::default_scenario_options(1).epoch_unix_s
}
