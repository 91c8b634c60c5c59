//! The `latency` expectation on a real run: a ping repeated 60 times from the ground to the
//! FC, its p95 below a generous bound (pass) and its median below an impossible one (fail,
//! naming the measured median); a ping nobody answers fails for want of answered
//! occurrences. Judged as the run goes (`exec::execute`) and on a report that kept every
//! outcome, with the same words.
#![allow(clippy::unwrap_used)]

use m6p_twin::exec::execute_keeping;
use m6p_twin::expectations::check_all;
use m6p_twin::ground::Outcome;
use m6p_twin::plan::compile;
use m6p_twin::runtime::build_runtime;

const SCENARIO: &str = r#"
name = "latency"
duration = "75s"

[fc]
publish_hz = 0

[[commands]]
name = "ping-fc"
at = "10s"
every = "1s"
count = 60
to = "FC"
request = "ping"
timeout = "2s"

[[commands]]
name = "ping-nobody"
at = "10s"
every = "1s"
count = 3
to = 7
request = "ping"
timeout = "1s"

[[expectations]]
name = "p95 below 2 s"
kind = "latency"
command = "ping-fc"
below = "2s"
min_samples = 60

[[expectations]]
name = "median below 1 ms"
kind = "latency"
command = "ping-fc"
percentile = 50
below = "1ms"

[[expectations]]
name = "nobody answers"
kind = "latency"
command = "ping-nobody"
below = "2s"
"#;

#[test]
fn a_latency_expectation_judges_a_percentile_of_the_round_trips() {
    let s = m6p_twin::scenario::parse("latency.toml", SCENARIO).unwrap();
    let compiled = compile(&s);
    let expectations = compiled.expectations.clone();
    let net = compiled.opts.network.clone();
    let rt = build_runtime().unwrap();
    let out = rt
        .block_on(execute_keeping(compiled, true, &mut |_| {}))
        .unwrap();
    print!("{}", out.verdict_table());

    // The round trips as the ground station measured them, sorted.
    let mut rtts: Vec<std::time::Duration> = out
        .report
        .results
        .iter()
        .filter(|r| r.request.label == "ping-fc")
        .filter_map(|r| match r.outcome {
            Outcome::Reply { rtt, .. } => Some(rtt),
            _ => None,
        })
        .collect();
    rtts.sort();
    assert_eq!(rtts.len(), 60, "every ping answered");
    let ms = |d: std::time::Duration| {
        let s = format!("{:.3}", d.as_secs_f64() * 1e3);
        format!("{} ms", s.trim_end_matches('0').trim_end_matches('.'))
    };

    let v = &out.verdicts;
    assert_eq!(v.len(), 3);
    // p95 of 60 is the 57th.
    assert!(v[0].passed, "{}", v[0].observed);
    assert_eq!(
        v[0].observed,
        format!("p95 of 60 round trips {} < 2000 ms", ms(rtts[56]))
    );
    // The median of 60 is the 30th; a round trip through the UHF link takes far more
    // than 1 ms.
    assert!(rtts[29] > std::time::Duration::from_millis(1));
    assert!(!v[1].passed);
    assert_eq!(
        v[1].observed,
        format!("p50 of 60 round trips {}, not below 1 ms", ms(rtts[29]))
    );
    assert_eq!(v[1].t, out.report.sim_time, "a statistic of the whole run");
    assert!(!v[2].passed);
    assert_eq!(
        v[2].observed,
        "0 answered occurrences of `ping-nobody`, too few for a p95 (min_samples = 1; 3 unanswered, counted over the bound)"
    );

    // Judged from the kept outcomes: the same verdicts, word for word.
    let kept = check_all(&expectations, &out.report, &net);
    for (a, b) in v.iter().zip(&kept) {
        assert_eq!(
            (&a.name, a.passed, a.t, &a.observed),
            (&b.name, b.passed, b.t, &b.observed)
        );
    }
}
