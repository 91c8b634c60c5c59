//! End-to-end behaviour of the M6P network in virtual time: reachability through COMM and
//! the PC, silence on reserved ids, service semantics, determinism.
#![allow(clippy::unwrap_used)]

use std::time::Duration;

use csp::SimTime;
use m6p_twin::ground::{Outcome, PlannedRequest, ping_payload};
use m6p_twin::network::NetworkSpec;
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::{RunOptions, build_runtime};

fn request(at_s: u64, dst: u8, dport: u8, data: Vec<u8>) -> PlannedRequest {
    PlannedRequest {
        at: SimTime::from_secs(at_s),
        dst,
        dport,
        data,
        timeout: Duration::from_secs(3),
        label: format!("{dst}:{dport}"),
        after: None,
    }
}

fn run_plan(plan: Vec<PlannedRequest>, duration_s: u64, seed: u64, trace: bool) -> RunReport {
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(duration_s));
    opts.seed = seed;
    opts.trace = trace;
    opts.ground_plan
        .insert(16, plan.into_iter().map(Into::into).collect());
    let rt = build_runtime().unwrap();
    rt.block_on(run(opts, None)).unwrap()
}

fn reply_of(report: &RunReport, dst: u8, dport: u8) -> Option<Vec<u8>> {
    report
        .results
        .iter()
        .find(|r| r.request.dst == dst && r.request.dport == dport)
        .and_then(|r| match &r.outcome {
            Outcome::Reply { data, .. } => Some(data.clone()),
            _ => None,
        })
}

#[test]
fn ground_ping_reaches_every_node_and_reserved_ids_time_out() {
    let space = [1u8, 2, 3, 4, 5, 6, 12, 13];
    let mut plan: Vec<_> = space
        .iter()
        .map(|&d| request(1, d, 1, ping_payload(64)))
        .collect();
    plan.extend((7..=11).map(|d| request(1, d, 1, ping_payload(8))));
    let report = run_plan(plan, 20, 1, false);
    for d in space {
        assert_eq!(
            reply_of(&report, d, 1),
            Some(ping_payload(64)),
            "ping to {d}"
        );
    }
    for d in 7..=11u8 {
        let r = report.results.iter().find(|r| r.request.dst == d).unwrap();
        assert_eq!(r.outcome, Outcome::Timeout, "ping to reserved id {d}");
    }
    // The ping to a payload crossed the PC: it forwarded request and reply.
    let pc = report.nodes.iter().find(|n| n.name == "PC").unwrap();
    assert!(pc.counters.forwarded >= 4, "{:?}", pc.counters);
    let comm = report.nodes.iter().find(|n| n.name == "COMM1").unwrap();
    assert!(comm.counters.forwarded >= 16);
}

#[test]
fn round_trip_time_matches_the_link_model() {
    // 16-byte ping to the FC: 20 bytes each way over 9600 bit/s UHF (16.67 ms) plus 3 ms
    // delay, plus three CAN frames each way at 1 Mbit/s.
    let report = run_plan(vec![request(1, 3, 1, ping_payload(16))], 5, 1, false);
    let Outcome::Reply { rtt, .. } = &report.results[0].outcome else {
        panic!("no reply")
    };
    let air = 2.0 * (20.0 * 8.0 / 9600.0 + 0.003);
    let got = rtt.as_secs_f64();
    assert!(
        got > air && got < air + 0.002,
        "rtt {got} s, air alone {air} s"
    );
}

#[test]
fn service_ports_answer_as_libcsp() {
    let plan = vec![
        request(1, 3, 6, vec![]),            // uptime, 10 s after boot
        request(10, 3, 0, vec![0x00, 0x01]), // CMP ident
        request(10, 4, 3, vec![]),           // memfree
        request(10, 5, 5, vec![]),           // buf_free
        request(10, 12, 2, vec![]),          // ps
        request(10, 3, 10, vec![0x07]),      // unknown FC telemetry command
    ];
    let mut plan = plan;
    plan[0].at = SimTime::from_secs(10);
    let report = run_plan(plan, 20, 1, false);
    let up = reply_of(&report, 3, 6).unwrap();
    assert_eq!(u32::from_be_bytes(up.try_into().unwrap()), 10);
    let ident = reply_of(&report, 3, 0).unwrap();
    assert_eq!(ident.len(), 93);
    assert_eq!(&ident[..4], b"\xff\x01FC");
    assert_eq!(reply_of(&report, 4, 3).unwrap().len(), 4);
    assert_eq!(reply_of(&report, 5, 5).unwrap(), vec![0, 0, 0, 10]);
    let ps = reply_of(&report, 12, 2).unwrap();
    assert!(String::from_utf8(ps).unwrap().starts_with("PL12"));
    assert_eq!(reply_of(&report, 3, 10).unwrap(), vec![0x07, 0x00]);
}

#[test]
fn reboot_service_resets_uptime_inside_the_twin() {
    let plan = vec![
        request(30, 3, 4, 0x8007_8007u32.to_be_bytes().to_vec()),
        request(40, 3, 6, vec![]),
        request(40, 4, 6, vec![]),
    ];
    let report = run_plan(plan, 50, 1, false);
    let fc = u32::from_be_bytes(reply_of(&report, 3, 6).unwrap().try_into().unwrap());
    let eps = u32::from_be_bytes(reply_of(&report, 4, 6).unwrap().try_into().unwrap());
    assert_eq!(fc, 9, "FC uptime after a reboot at 30 s (+ link delay)");
    assert_eq!(eps, 40);
    let fcn = report.nodes.iter().find(|n| n.name == "FC").unwrap();
    assert_eq!(fcn.counters.reboots, 1);
}

#[test]
fn same_seed_same_trace_and_another_seed_changes_only_random_choices() {
    let plan = || {
        let mut p: Vec<_> = [3u8, 12, 13, 6]
            .iter()
            .map(|&d| request(1, d, 1, ping_payload(100)))
            .collect();
        p.push(request(2, 4, 6, vec![]));
        p
    };
    let a = run_plan(plan(), 30, 7, true);
    let b = run_plan(plan(), 30, 7, true);
    assert!(a.trace.len() > 100, "{}", a.trace.len());
    let key = |r: &RunReport| {
        r.trace
            .iter()
            .map(|e| (e.t, e.medium.to_string(), e.bytes()))
            .collect::<Vec<_>>()
    };
    assert_eq!(key(&a), key(&b));
    // Another seed draws other CFP idents and ports, so bytes differ, and with them the
    // CAN stuff bits (a few microseconds); the same frames cross the same media in order.
    let c = run_plan(plan(), 30, 8, true);
    assert_ne!(key(&a), key(&c));
    let media = |r: &RunReport| {
        r.trace
            .iter()
            .map(|e| e.medium.to_string())
            .collect::<Vec<_>>()
    };
    assert_eq!(media(&a), media(&c));
    for (x, y) in a.trace.iter().zip(&c.trace) {
        let dt = x.t.as_ns().abs_diff(y.t.as_ns());
        assert!(dt < 100_000, "{} vs {}", x.t, y.t);
    }
}

#[test]
fn crc_flagged_request_gets_a_crc_flagged_reply() {
    // A ground node sets CSP_FCRC32: the FC verifies and strips it, and the reply mirrors
    // the flag with a CRC of its own, which the ground node verifies and strips.
    use csp::node::{App, Host, IfaceConfig, Node, NodeConfig};
    use csp::router::Route;
    use csp::{Header, Packet};
    let mut cfg = NodeConfig::new("GS", 16);
    cfg.ifaces = vec![IfaceConfig::packet("x")];
    cfg.routes.set_default(Route::direct(0));
    struct Nop;
    impl App for Nop {
        type Event = std::convert::Infallible;
        fn start(&mut self, n: &mut Node, _: SimTime) {
            n.bind(40);
        }
        fn handle_packet(&mut self, _: &mut Node, _: Packet, _: SimTime) {}
    }
    let mut gs = Host::new(cfg, Nop, SimTime::ZERO);
    let (fc_cfg, _) = m6p_twin::network::node_config(&NetworkSpec::default_m6p().nodes[2]);
    let mut fc = Host::new(fc_cfg, csp::node::NoApp, SimTime::ZERO);
    let mut h = Header::new(16, 3, 1, 40);
    h.flags = csp::header::flags::CRC32;
    gs.node
        .send(Packet::new(h, vec![9, 8, 7]), SimTime::ZERO)
        .unwrap();
    let Some(csp::node::Transmit::Packet { packet, .. }) = gs.node.poll_transmit() else {
        panic!()
    };
    assert_eq!(packet.data.len(), 7, "data + CRC32");
    fc.handle_packet(0, packet, SimTime::ZERO);
    let mut frames = Vec::new();
    while let Some(csp::node::Transmit::Can { frame, .. }) = fc.node.poll_transmit() {
        frames.push(frame);
    }
    let mut r = csp::cfp::Reassembler::default();
    let reply = frames
        .iter()
        .find_map(|f| r.handle(f, SimTime::ZERO))
        .unwrap()
        .unwrap();
    assert_eq!(reply.header.flags, csp::header::flags::CRC32);
    assert_eq!(reply.data.len(), 7);
    gs.handle_packet(0, reply, SimTime::ZERO);
    assert_eq!(gs.node.counters().delivered, 1);
    assert_eq!(gs.node.counters().total_drops(), 0);
}

/// The embedded default scenario as shipped: a SETUP for session 1 sent from the ground
/// starts a real polling session of payload 12 at once (issue #6's default).
#[test]
fn a_setup_for_session_1_on_the_default_scenario_polls_payload_12() {
    let loaded = m6p_twin::exec::load_default().unwrap();
    let mut compiled = m6p_twin::exec::compile_loaded(&loaded);
    m6p_twin::exec::with_duration(&mut compiled, Duration::from_secs(40));
    // SETUP: session 1, now, 10 s, no packet limit, 64-byte frames, "Send telemetry".
    let mut setup = vec![1, 1, 0, 0, 0, 0, 10, 0, 0, 0, 64];
    setup.extend_from_slice(b"Send telemetry");
    let plan = compiled.opts.ground_plan.entry(16).or_default();
    plan.push(request(20, 6, 10, setup).into());
    plan.push(request(25, 6, 10, vec![2, 1]).into());
    let rt = build_runtime().unwrap();
    let report = rt.block_on(run(compiled.opts, None)).unwrap();
    let reply = |label: &str| {
        report
            .results
            .iter()
            .filter(|r| r.request.label == label)
            .map(|r| match &r.outcome {
                Outcome::Reply { data, .. } => data.clone(),
                other => panic!("{label}: {other:?}"),
            })
            .collect::<Vec<_>>()
    };
    let replies = reply("6:10");
    assert_eq!(replies[0], vec![1, 1], "SETUP accepted");
    // STATUS during the session: result DONE (never run before), state ACTIVE (2).
    assert_eq!(&replies[1][..4], &[2, 1, 0, 2]);
    let runs = &report.sessions.runs;
    assert_eq!(runs.len(), 1, "{runs:?}");
    let (t_end, result, packets) = runs[0].ended.unwrap();
    assert_eq!(
        result,
        m6p_twin::sessions::RunEnd::Result(nodes_pc::SessionResult::Done),
        "DONE"
    );
    assert!(
        (95..=100).contains(&packets),
        "{packets} polls in 10 s at 100 ms"
    );
    assert!(t_end > SimTime::from_secs(30) && t_end < SimTime::from_secs(31));
    assert_eq!(runs[0].bytes.len(), packets as usize * 64);
    let check = nodes_payload::check_counter_stream(&runs[0].bytes);
    assert!(check.is_clean(), "{check:?}");
    assert_eq!(check.addr, Some(12));
}

/// The S-band's power on the EPS: transmitting frames costs power (the PC posts its
/// transmissions), and switching the S-band channel off stops the transmitter and its
/// standby load; switched on, it transmits again.
#[test]
fn the_eps_charges_the_s_band_and_its_channel_switches_the_transmitter() {
    let loaded = m6p_twin::exec::load_default().unwrap();
    let mut compiled = m6p_twin::exec::compile_loaded(&loaded);
    m6p_twin::exec::with_duration(&mut compiled, Duration::from_secs(60));
    for (at, on) in [(30, false), (40, true)] {
        compiled.opts.eps.timeline.push(nodes_eps::TimedEpsEvent {
            at: SimTime::from_secs(at),
            event: nodes_eps::EpsEvent::Channel {
                channel: nodes_eps::Channel::Sband,
                on,
            },
        });
    }
    // SETUP: session 1, now, 30 s, no packet limit, 254-byte frames, no sync message.
    let setup = vec![1, 1, 0, 0, 0, 0, 30, 0, 0, 0, 254];
    compiled
        .opts
        .ground_plan
        .entry(16)
        .or_default()
        .push(request(20, 6, 10, setup).into());
    let rt = build_runtime().unwrap();
    let report = rt.block_on(run(compiled.opts, None)).unwrap();
    let mean_load = |a: u64, b: u64| {
        let v: Vec<f64> = report
            .power
            .iter()
            .filter(|s| s.t > SimTime::from_secs(a) && s.t <= SimTime::from_secs(b))
            .map(|s| s.load_w)
            .collect();
        assert!(!v.is_empty());
        v.iter().sum::<f64>() / v.len() as f64
    };
    let (idle, tx, off, back) = (
        mean_load(10, 19),
        mean_load(22, 29),
        mean_load(32, 39),
        mean_load(42, 49),
    );
    // A 1279-byte frame (10.2 ms at 1 Mbit/s) per POLL cycle: roughly a 10 % duty of 9 W,
    // the wheels and magnetorquers aside (the ADCS is busy in all four windows).
    assert!(
        tx - idle > 0.3 && tx - idle < 2.0,
        "idle {idle} W, transmitting {tx} W"
    );
    // Off: no standby (1.2 W) and no transmissions.
    assert!(
        off < idle - 0.8,
        "idle {idle} W, S-band channel off {off} W"
    );
    // Back on: standby and transmissions again (the ADCS's own load varies between the
    // windows, so only the step up is checked).
    assert!(back > off + 0.8, "S-band off {off} W, back on {back} W");
    // Nothing was lost: the queue waited while the transmitter was unpowered.
    let run1 = &report.sessions.runs[0];
    assert_eq!(
        run1.ended.map(|e| e.1),
        Some(m6p_twin::sessions::RunEnd::Result(
            nodes_pc::SessionResult::Done
        ))
    );
    assert!(
        run1.bytes.len() > 250 * 254,
        "{:?} {} bytes {:?}",
        run1.ended,
        run1.bytes.len(),
        report.sessions.dropped
    );
}

/// The UHF transmitter is charged for every packet the satellite's radio sends, not only
/// for beacons: replies forwarded to the ground cost their air time at the transmit power.
#[test]
fn the_eps_charges_the_uhf_downlink_of_forwarded_replies() {
    let mean_load = |pings: bool| {
        let loaded = m6p_twin::exec::load_default().unwrap();
        let mut compiled = m6p_twin::exec::compile_loaded(&loaded);
        m6p_twin::exec::with_duration(&mut compiled, Duration::from_secs(40));
        if pings {
            // A 200-byte ping to the FC every second: a 204-byte reply, 170 ms on the air.
            let plan = compiled.opts.ground_plan.entry(16).or_default();
            plan.extend((10..40).map(|s| request(s, 3, 1, ping_payload(200)).into()));
        }
        let rt = build_runtime().unwrap();
        let report = rt.block_on(run(compiled.opts, None)).unwrap();
        if pings {
            let answered = report
                .results
                .iter()
                .filter(|r| r.request.data.len() == 200)
                .filter(|r| matches!(r.outcome, Outcome::Reply { .. }))
                .count();
            assert!(answered >= 30, "{answered} answered");
        }
        let v: Vec<f64> = report
            .power
            .iter()
            .filter(|s| s.t > SimTime::from_secs(12) && s.t <= SimTime::from_secs(38))
            .map(|s| s.load_w)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let (quiet, busy) = (mean_load(false), mean_load(true));
    // 3.5 W while transmitting, 17 % of the time.
    let want = 3.5 * 204.0 * 8.0 / 9600.0;
    assert!(
        (busy - quiet - want).abs() < 0.02,
        "quiet {quiet} W, pinged {busy} W: {} W more, want {want} W",
        busy - quiet
    );
}

/// The take-over with both COMMs down for a while: nobody carries the link (and the log
/// does not pretend COMM1 has it back); COMM2, back first, carries it; then COMM1.
#[test]
fn with_both_comms_down_nobody_carries_the_link_until_one_comes_back() {
    use m6p_twin::events::RunEvent;
    use m6p_twin::plan::{FaultAction, TimedFault};
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(50));
    let fault = |s: u64, addr: u8, on: bool| TimedFault {
        at: SimTime::from_secs(s),
        action: FaultAction::Power {
            addr,
            fault: u32::from(addr),
            off: !on,
        },
        what: format!("power {addr} {on}"),
    };
    opts.faults = vec![
        fault(10, 1, false),
        fault(20, 2, false),
        fault(30, 2, true),
        fault(40, 1, true),
    ];
    let plan = [5, 15, 25, 35, 45]
        .into_iter()
        .map(|s| request(s, 3, 1, ping_payload(8)).into())
        .collect();
    opts.ground_plan.insert(16, plan);
    let rt = build_runtime().unwrap();
    let mut radio = Vec::new();
    let report = rt
        .block_on(m6p_twin::report::run_with(
            opts,
            None,
            &mut |ev: &RunEvent| {
                if let RunEvent::Log {
                    t, source, message, ..
                } = ev
                    && source == "radio"
                {
                    radio.push((t.as_ns() / 1_000_000_000, message.clone()));
                }
            },
        ))
        .unwrap();
    let said: Vec<(u64, &str)> = radio.iter().map(|(t, m)| (*t, m.as_str())).collect();
    assert_eq!(
        said,
        vec![
            (10, "COMM2 takes the radio link over (COMM1 powered off)"),
            (
                20,
                "no COMM can carry the radio link (COMM1 and COMM2 down)"
            ),
            (30, "COMM2 takes the radio link over (COMM1 powered off)"),
            (40, "COMM1 has the radio link back"),
        ]
    );
    let answered: Vec<bool> = report
        .results
        .iter()
        .map(|r| matches!(r.outcome, Outcome::Reply { .. }))
        .collect();
    assert_eq!(answered, vec![true, true, false, true, true]);
}

/// In real time every node boots at the start of the run, not when its task is made: COMM1's
/// first beacon leaves exactly one period after zero (it left a few tens of microseconds
/// late before, and a real-time recording then never replayed identically past it).
#[test]
fn in_real_time_the_nodes_boot_at_zero() {
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), Duration::from_secs(11));
    opts.clock = bus::ClockMode::Realtime { speed: 2.0 };
    opts.comm.beacon_period = Duration::from_secs(10);
    let rt = build_runtime().unwrap();
    let report = rt.block_on(run(opts, None)).unwrap();
    let first = report.beacons.first().expect("a beacon").0;
    // 10 s, then 177 bytes at 9600 bit/s (147.5 ms) and 3 ms.
    assert_eq!(first, SimTime::from_ns(10_150_500_000));
}

/// A request sent before the end whose reply or timeout would come after it is reported as
/// sent and unfinished (it was left out, and its expectation said "never sent").
#[test]
fn a_request_the_run_ends_on_is_sent_and_unfinished() {
    let report = run_plan(vec![request(10, 9, 1, ping_payload(4))], 12, 1, false);
    assert_eq!(report.results.len(), 1);
    assert_eq!(report.results[0].sent, SimTime::from_secs(10));
    assert_eq!(report.results[0].outcome, Outcome::Unfinished);
    assert!(report.table().contains("1 still waiting at the end"));
}
