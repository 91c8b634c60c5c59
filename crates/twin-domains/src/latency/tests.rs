//! The `latency` expectation's unit tests: the nearest rank, the percentile with the
//! unanswered ranked above every answered one, the verdict's words, the watch against the
//! report, and the validation errors at their fields.
#![allow(clippy::unwrap_used)]

use super::*;
use std::time::Duration;

fn expect(percentile: Option<f64>, below_ms: u64, min_samples: Option<u64>) -> LatencyExpect {
    LatencyExpect {
        command: "ping".into(),
        percentile,
        below: Dur(Duration::from_millis(below_ms)),
        min_samples,
    }
}

fn trips(answered_ms: &[u64], unanswered: u64, unfinished: u64) -> RoundTrips {
    RoundTrips {
        answered_ns: answered_ms.iter().map(|m| m * 1_000_000).collect(),
        unanswered,
        unfinished,
    }
}

#[test]
fn the_nearest_rank_is_exact_in_whole_numbers() {
    assert_eq!(nearest_rank(95.0, 20), 19);
    assert_eq!(nearest_rank(95.0, 60), 57);
    assert_eq!(nearest_rank(95.0, 1), 1);
    assert_eq!(nearest_rank(50.0, 4), 2);
    assert_eq!(nearest_rank(50.0, 5), 3);
    assert_eq!(nearest_rank(100.0, 7), 7);
    assert_eq!(nearest_rank(0.0001, 7), 1);
    // 99.9 % of 1000 is the 999th, not the 1000th a float product might give.
    assert_eq!(nearest_rank(99.9, 1000), 999);
    assert_eq!(nearest_rank(99.9, 1001), 1000);
}

#[test]
fn the_percentile_is_a_measured_round_trip_with_the_unanswered_above_all() {
    // 1..=20 ms in scrambled order: p95 is the 19th, p100 the 20th, p50 the 10th.
    let mut ms_: Vec<u64> = (1..=20).collect();
    ms_.reverse();
    ms_.swap(3, 11);
    let t = trips(&ms_, 0, 0);
    let at = |p| t.at_percentile(p).unwrap();
    assert_eq!(at(95.0), AtRank::RoundTrip { rtt_ns: 19_000_000 });
    assert_eq!(at(100.0), AtRank::RoundTrip { rtt_ns: 20_000_000 });
    assert_eq!(at(50.0), AtRank::RoundTrip { rtt_ns: 10_000_000 });
    // One timeout among 20: 21 occurrences, p95 is the 20th, still answered; p100 the
    // unanswered one.
    let t = trips(&ms_, 1, 0);
    assert_eq!(
        t.at_percentile(95.0),
        Some(AtRank::RoundTrip { rtt_ns: 20_000_000 })
    );
    assert_eq!(t.at_percentile(100.0), Some(AtRank::Unanswered));
    // Two: the 20th of 22 ... p95 is rank 21, an unanswered one.
    assert_eq!(
        trips(&ms_, 2, 0).at_percentile(95.0),
        Some(AtRank::Unanswered)
    );
    // The unfinished are left out.
    assert_eq!(
        trips(&ms_, 0, 5).at_percentile(95.0),
        Some(AtRank::RoundTrip { rtt_ns: 19_000_000 })
    );
    assert_eq!(trips(&[], 0, 3).at_percentile(95.0), None);
}

#[test]
fn the_verdict_names_the_percentile_the_count_and_the_bound() {
    let end = SimTime::from_secs(100);
    let sixty: Vec<u64> = (1..=60).collect();
    let j = expect(None, 250, None).judge(trips(&sixty, 0, 0), end);
    assert!(j.passed(), "{}", j.detail);
    assert_eq!(j.detail, "p95 of 60 round trips 57 ms < 250 ms");
    assert_eq!(j.at, end);

    let j = expect(Some(99.5), 57, None).judge(trips(&sixty, 0, 0), end);
    assert!(!j.passed());
    assert_eq!(j.detail, "p99.5 of 60 round trips 60 ms, not below 57 ms");

    // Strictly below: a bound equal to the percentile fails.
    let j = expect(Some(95.0), 57, None).judge(trips(&sixty, 0, 0), end);
    assert_eq!(j.detail, "p95 of 60 round trips 57 ms, not below 57 ms");
    assert!(!j.passed());

    let mut t = trips(&sixty, 4, 1);
    t.answered_ns[0] = 41_300_000;
    let j = expect(Some(90.0), 250, None).judge(t.clone(), end);
    assert!(j.passed(), "{}", j.detail);
    assert_eq!(
        j.detail,
        "p90 of 64 occurrences 58 ms < 250 ms (60 answered; 4 unanswered, counted over the bound; 1 unfinished at the end, left out)"
    );
    let j = expect(None, 250, None).judge(t, end);
    assert!(!j.passed());
    assert_eq!(
        j.detail,
        "p95 of 64 occurrences falls on an unanswered one, not below 250 ms (60 answered; 4 unanswered, counted over the bound; 1 unfinished at the end, left out)"
    );
    assert_eq!(ms(41_312_345), "41.312 ms");
}

#[test]
fn too_few_answered_or_none_sent_fails_saying_so() {
    let end = SimTime::from_secs(10);
    let j = expect(None, 250, Some(10)).judge(trips(&[5, 6, 7], 2, 0), end);
    assert!(!j.passed());
    assert_eq!(
        j.detail,
        "3 answered occurrences of `ping`, too few for a p95 (min_samples = 10; 2 unanswered, counted over the bound)"
    );
    // Every occurrence timed out: none answered, fewer than the default 1.
    let j = expect(None, 250, None).judge(trips(&[], 5, 0), end);
    assert!(!j.passed());
    assert!(
        j.detail.starts_with(
            "0 answered occurrences of `ping`, too few for a p95 (min_samples = 1; 5 unanswered"
        ),
        "{}",
        j.detail
    );
    let j = expect(None, 250, None).judge(RoundTrips::default(), end);
    assert!(!j.passed());
    assert_eq!(
        j.detail,
        "command `ping` was never sent before the end of the run"
    );
}

#[test]
fn the_watch_counts_what_the_report_counts() {
    let ev = |name: &str, rtt_ms: Option<u64>, failed: bool| {
        RunEvent::CommandResult(Box::new(twin_core::events::CommandResult {
            t: SimTime::ZERO,
            name: name.into(),
            dst: 3,
            dport: 1,
            data: vec![],
            timeout: Duration::from_secs(1),
            reply: rtt_ms.map(|_| vec![1]),
            rtt_ns: rtt_ms.map(|m| m * 1_000_000),
            sent: SimTime::ZERO,
            failed: failed.then(|| "no route".to_owned()),
        }))
    };
    let send = |name: &str| RunEvent::Command {
        t: SimTime::ZERO,
        name: name.into(),
        dst: 3,
        dport: 1,
        data: vec![],
        timeout: Duration::from_secs(1),
    };
    let x = expect(None, 250, None);
    let mut w = LatencyWatch {
        expect: x,
        trips: RoundTrips::default(),
        sent: 0,
        decided: 0,
    };
    for e in [
        send("ping"),
        ev("ping", Some(3), false),
        send("other"),
        ev("other", Some(900), false),
        send("ping"),
        ev("ping", None, false),
        ev("ping", None, true),
        send("ping"),
    ] {
        w.observe(&e);
    }
    let mut want = trips(&[3], 2, 0);
    assert_eq!(w.trips, want);
    want.unfinished = 1;
    let report = twin_report::RunReport::default();
    let net = twin_core::network::NetworkSpec::default_m6p();
    let j = w.judge(&CheckCx {
        report: &report,
        net: &net,
    });
    assert_eq!(j, w.expect.judge(want, report.sim_time));
    assert!(!j.passed(), "two of three unanswered: {}", j.detail);
}

/// The problems of a scenario with one ping and the expectation `x`, each as
/// (field, line, message).
fn problems(x: &str) -> Vec<(String, Option<usize>, String)> {
    let text = format!(
        "name = \"t\"\nduration = \"1m\"\n\
         [[commands]]\nname = \"ping\"\nat = \"1s\"\nevery = \"1s\"\ncount = 20\nto = \"FC\"\nrequest = \"ping\"\n\
         [[expectations]]\nkind = \"latency\"\n{x}"
    );
    match crate::validate::parse("t.toml", &text) {
        Ok(_) => Vec::new(),
        Err(e) => {
            e.0.into_iter()
                .map(|e| (e.field, e.line, e.message))
                .collect()
        }
    }
}

#[test]
fn a_latency_expectation_is_checked_at_its_fields() {
    assert_eq!(problems("command = \"ping\"\nbelow = \"250ms\"\n"), vec![]);
    assert_eq!(
        problems("command = \"ping\"\nbelow = \"250ms\"\npercentile = 99.9\nmin_samples = 20\n"),
        vec![]
    );
    let at = |field: &str, x: &str| {
        let p = problems(x);
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].0, format!("expectations[0].{field}"), "{p:?}");
        assert!(p[0].1.is_some(), "located at a line: {p:?}");
        p[0].2.clone()
    };
    assert_eq!(
        at("command", "command = \"pong\"\nbelow = \"250ms\"\n"),
        "no command is named `pong` (commands: ping)"
    );
    assert_eq!(
        at(
            "percentile",
            "command = \"ping\"\nbelow = \"250ms\"\npercentile = 0\n"
        ),
        "must be more than 0 and at most 100 (got 0)"
    );
    assert_eq!(
        at(
            "percentile",
            "command = \"ping\"\nbelow = \"250ms\"\npercentile = 100.5\n"
        ),
        "must be more than 0 and at most 100 (got 100.5)"
    );
    assert!(at("below", "command = \"ping\"\nbelow = \"0s\"\n").starts_with("must be more than 0"));
    assert_eq!(
        at(
            "min_samples",
            "command = \"ping\"\nbelow = \"1s\"\nmin_samples = 0\n"
        ),
        "must be at least 1"
    );
    assert_eq!(
        at(
            "min_samples",
            "command = \"ping\"\nbelow = \"1s\"\nmin_samples = 21\n"
        ),
        "`ping` is sent at most 20 times"
    );
    // `below` is required; an unknown field is refused.
    let p = problems("command = \"ping\"\n");
    assert!(p.iter().any(|(_, _, m)| m.contains("below")), "{p:?}");
    let p = problems("command = \"ping\"\nbelow = \"1s\"\nwithin = \"1s\"\n");
    assert!(p.iter().any(|(f, _, _)| f.contains("within")), "{p:?}");
}
