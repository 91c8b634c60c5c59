//! Faults and power on a link to a program outside the twin (issue 13): `drop`, `delay`,
//! `link-down` and `hang` with a named `[[links]]` entry as `target`, composing as a
//! medium's faults do, and `powered_by`, without which no EPS channel switches an outside
//! program.
//!
//! The outside program is payload 14 on a KISS/TCP link, fed as a replayed run feeds it
//! (its recorded input at its recorded times, through the same link core), so the test is
//! in virtual time and exact: it pings the EPS every 10 s, and the replies that reach the
//! link (the KISS frames the twin writes to it) say what crossed.
#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;

use bus::ClockMode;
use csp::kiss::{Decoder, DecoderConfig, KissEvent};
use csp::{Header, Packet, SimTime};
use m6p_twin::events::{Direction, RunEvent};
use m6p_twin::exec::execute;
use m6p_twin::plan::compile;
use m6p_twin::runtime::{KissReplay, RecordedChunk, build_runtime};

const LINK: &str = "listen 127.0.0.1:52999";

/// A 300 s run of `extra` with payload 14 outside (link `payload-sw`), pinging the EPS at
/// 5 s, 15 s, ... 295 s. Returns the reply time of each ping (by its send second), every
/// event, and the outcome.
fn run(
    extra: &str,
) -> (
    BTreeMap<u64, Option<f64>>,
    Vec<RunEvent>,
    m6p_twin::exec::Outcome,
) {
    let text = format!(
        r#"
name = "outside-link"
duration = "300s"

[network]
payloads = [12]

{extra}
"#
    );
    let s = m6p_twin::scenario::parse("t.toml", &text).unwrap();
    let mut compiled = compile(&s);
    // As `replay` does: the recorded input instead of a socket, in virtual time.
    let link_cfg = compiled.opts.kiss_links.remove(0).cfg;
    compiled.opts.clock = ClockMode::Virtual;
    let sends: Vec<u64> = (0..30).map(|k| 5 + 10 * k).collect();
    compiled.opts.kiss_replay = vec![KissReplay {
        link: format!("{LINK}#1"),
        chunks: sends
            .iter()
            .map(|&s| {
                let p = Packet::new(Header::new(14, 4, 1, 40), (s as u32).to_le_bytes());
                let mut bytes = Vec::new();
                csp::kiss::encode(&p, &mut bytes);
                RecordedChunk {
                    t: SimTime::from_secs(s),
                    seq: s,
                    bytes,
                }
            })
            .collect(),
        cfg: link_cfg,
    }];
    let rt = build_runtime().unwrap();
    let mut events = Vec::new();
    let out = rt
        .block_on(execute(compiled, &mut |ev| events.push(ev.clone())))
        .unwrap();
    let mut replies: BTreeMap<u64, Option<f64>> = sends.iter().map(|&s| (s, None)).collect();
    let mut decoder = Decoder::new(DecoderConfig::default());
    for ev in &events {
        if let RunEvent::Kiss {
            t,
            link,
            dir: Direction::Out,
            bytes,
        } = ev
        {
            assert!(link.starts_with(LINK), "{link}");
            let mut got = Vec::new();
            decoder.push(bytes, &mut got);
            for g in got {
                let KissEvent::Packet(p) = g else { continue };
                assert_eq!((p.header.src, p.header.dst), (4, 14), "{}", p.header);
                let sent = u32::from_le_bytes(p.data[..4].try_into().unwrap());
                replies.insert(u64::from(sent), Some(t.as_secs_f64()));
            }
        }
    }
    (replies, events, out)
}

const LINK_SPEC: &str = r#"
[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:52999"
addrs = [14]
name = "payload-sw"
"#;

/// Drop (20-40 s) and delay (30-50 s) overlapping, a link-down (100-120 s), a hang from
/// 180 s without end, and PL14 off from 200 s to 220 s.
const FAULTS: &str = r#"
[[faults]]
at = "20s"
until = "40s"
kind = "drop"
target = "payload-sw"
probability = 1.0

[[faults]]
at = "30s"
until = "50s"
kind = "delay"
target = "payload-sw"
delay = "2s"

[[faults]]
at = "100s"
until = "120s"
kind = "link-down"
target = "payload-sw"

[[faults]]
at = "180s"
kind = "hang"
target = "payload-sw"

[[eps.events]]
at = "200s"
channel = "PL14"
on = false

[[eps.events]]
at = "220s"
channel = "PL14"
on = true
"#;

fn lost(replies: &BTreeMap<u64, Option<f64>>) -> Vec<u64> {
    replies
        .iter()
        .filter(|(_, r)| r.is_none())
        .map(|(s, _)| *s)
        .collect()
}

#[test]
fn faults_on_an_outside_link_compose_and_its_channel_powers_it() {
    let (replies, events, out) = run(&format!("{LINK_SPEC}powered_by = \"PL14\"\n{FAULTS}"));
    // Lost: the drop (25, 35: it holds through the delay), the link-down (105, 115), the
    // hang (185, 195), the channel off (205, 215). The power cycle at 200-220 s ended the
    // hang, which had no end of its own.
    assert_eq!(
        lost(&replies),
        vec![25, 35, 105, 115, 185, 195, 205, 215],
        "{replies:?}"
    );
    // The delay alone (40-50 s): 2 s each way.
    let rtt = |s: u64| replies[&s].unwrap() - s as f64;
    assert!((4.0..4.1).contains(&rtt(45)), "{}", rtt(45));
    for s in [15, 55, 95, 125, 225, 295] {
        assert!(rtt(s) < 0.1, "ping at {s} s: {}", rtt(s));
    }
    let (name, g) = &out.report.links[0];
    assert_eq!(name, "payload-sw");
    assert_eq!(
        (
            g.dropped,
            g.delayed,
            g.down,
            g.hung,
            g.unpowered,
            g.overflow
        ),
        (2, 2, 2, 2, 2, 0),
        "{g:?}"
    );
    // The run's log says when the link lost and regained power.
    let logs: Vec<String> = events
        .iter()
        .filter_map(|e| match e {
            RunEvent::Log {
                t, source, message, ..
            } if source == "power" => Some(format!("{} {message}", t.as_secs_f64())),
            _ => None,
        })
        .collect();
    assert_eq!(
        logs,
        vec![
            "200 link payload-sw: unpowered (PL14 off): the twin forwards nothing to or from it",
            "220 link payload-sw: powered again (PL14 on)"
        ]
    );
    assert!(
        events
            .iter()
            .any(|e| matches!(e, RunEvent::Fault { t, what }
            if *t == SimTime::from_secs(180) && what == "faults[3]: Hang on payload-sw")),
        "the hang is on the fault timeline"
    );
}

#[test]
fn an_outside_payload_is_not_switched_by_its_channel_unless_powered_by_it() {
    let (replies, events, out) = run(&format!("{LINK_SPEC}{FAULTS}"));
    // Without `powered_by`, PL14 switches nothing: 205 and 215 are answered, and the hang
    // from 180 s lasts to the end.
    let lost = lost(&replies);
    assert_eq!(&lost[..4], &[25, 35, 105, 115], "{replies:?}");
    assert_eq!(
        lost[4..].to_vec(),
        (185..300).step_by(10).collect::<Vec<_>>()
    );
    assert_eq!(out.report.links[0].1.unpowered, 0);
    assert!(
        !events
            .iter()
            .any(|e| matches!(e, RunEvent::Log { source, .. } if source == "power"))
    );
}

#[test]
fn link_faults_and_power_are_checked_with_the_scenario() {
    let bad = format!(
        "name = \"x\"\nduration = \"1m\"\n{LINK_SPEC}powered_by = \"SBAND\"\n\
         [[faults]]\nat = \"1s\"\nkind = \"corrupt\"\ntarget = \"payload-sw\"\nprobability = 0.5\n\
         [[faults]]\nat = \"1s\"\nkind = \"bit-errors\"\ntarget = \"payload-sw\"\nber = 0.001\n\
         [[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:52998\"\nname = \"FC\"\n"
    );
    let errs = m6p_twin::scenario::parse("t.toml", &bad)
        .unwrap_err()
        .to_string();
    for want in [
        "`links[0].powered_by`: `SBAND` is not an EPS channel that powers a node",
        "`faults[0].target`: `payload-sw` is an outside link: the twin does not corrupt",
        "`faults[1].target`: `payload-sw` is not a CAN bus",
        "`links[1].name`: `FC` names a node or a medium",
    ] {
        assert!(errs.contains(want), "missing `{want}` in:\n{errs}");
    }
}
