//! The platform model behind every fault and switch (issue 13): faults on one medium
//! compose, a node's power has one truth (its EPS channel and the power faults together),
//! the node's own core meets a power loss at its instant, and the run's seed varies the
//! world. Each test here was written against the defect first and failed on the code before
//! the fix (the closing note of issue 13 gives the figures).
#![allow(clippy::unwrap_used)]

use m6p_twin::events::RunEvent;
use m6p_twin::exec::execute_keeping;
use m6p_twin::ground::Outcome;
use m6p_twin::plan::compile;
use m6p_twin::runtime::build_runtime;

const TLE: &str = r#"
[satellite]
tle = [
  "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
  "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
]
"#;

/// Run a scenario text in virtual time: its outcome (the report keeping every request's
/// outcome) and every event.
fn run(text: &str) -> (m6p_twin::exec::Outcome, Vec<RunEvent>) {
    let s = m6p_twin::scenario::parse("t.toml", text).unwrap();
    let compiled = compile(&s);
    let rt = build_runtime().unwrap();
    let mut events = Vec::new();
    let out = rt
        .block_on(execute_keeping(compiled, true, &mut |ev| {
            events.push(ev.clone())
        }))
        .unwrap();
    (out, events)
}

/// Whether each occurrence of command `name` was answered, by send time in seconds.
fn answered(out: &m6p_twin::exec::Outcome, name: &str) -> Vec<(u64, bool)> {
    let mut v: Vec<(u64, bool)> = out
        .report
        .results
        .iter()
        .filter(|r| r.request.label == name)
        .map(|r| (r.sent.as_secs(), matches!(r.outcome, Outcome::Reply { .. })))
        .collect();
    v.sort();
    v
}

/// A drop of every frame on the main bus from 10 s to 290 s and a 50 ms delay from 40 s to
/// 60 s: the drop holds through the delay and after it is lifted; lifting the drop at 290 s
/// leaves the bus clear.
#[test]
fn faults_on_one_medium_compose_and_lifting_one_leaves_the_others() {
    let text = r#"
name = "compose"
duration = "300s"

[[commands]]
name = "ping-eps"
at = "5s"
every = "10s"
count = 30
to = "EPS"
request = "ping"
timeout = "4s"

[[faults]]
at = "10s"
until = "290s"
kind = "drop"
target = "main"
probability = 1.0

[[faults]]
at = "40s"
until = "60s"
kind = "delay"
target = "main"
delay = "50ms"
"#;
    let (out, _) = run(text);
    let got = answered(&out, "ping-eps");
    assert_eq!(got.len(), 30);
    for (t, ok) in got {
        let want = !(10..290).contains(&t);
        assert_eq!(
            ok, want,
            "ping sent at {t} s: answered {ok}, expected {want}"
        );
    }
}

/// ARM, then a 60 s FIRE at 70 s, and the ECU loses power at 75 s until 200 s, once by a
/// `power-off` fault and once by its EPS channel: the ECU's telemetry afterwards gives the
/// same impulse (the burn stopped at the loss of power), and the EPS was charged the same
/// load meanwhile.
#[test]
fn a_power_off_fault_cuts_a_burn_at_its_instant_as_the_eps_channel_does() {
    let common = format!(
        r#"
name = "burn-cut"
duration = "260s"
start = "2026-04-30T18:00:00Z"
{TLE}
[fc]
publish_hz = 0

[[commands]]
name = "arm"
at = "1s"
to = "ECU"
request = "raw"
port = 10
data = "02"

[[commands]]
name = "fire"
at = "70s"
to = "ECU"
request = "raw"
port = 10
data = "0360ea0000"

[[commands]]
name = "tmecu"
at = "250s"
to = "ECU"
request = "raw"
port = 10
data = "01"
"#
    );
    let by_fault = format!(
        "{common}\n[[faults]]\nat = \"75s\"\nuntil = \"200s\"\nkind = \"power-off\"\ntarget = \"ECU\"\n"
    );
    let by_channel = format!(
        "{common}\n[[eps.events]]\nat = \"75s\"\nchannel = \"ECU\"\non = false\n\n[[eps.events]]\nat = \"200s\"\nchannel = \"ECU\"\non = true\n"
    );
    let impulse_and_load = |text: &str| {
        let (out, events) = run(text);
        let tm = out
            .report
            .results
            .iter()
            .find(|r| r.request.label == "tmecu")
            .unwrap();
        let Outcome::Reply { data, .. } = &tm.outcome else {
            panic!("TMECU unanswered: {:?}", tm.outcome)
        };
        use nodes_ecu::wire::Repr as _;
        let tm = nodes_ecu::TmEcu::parse(&data[2..]).unwrap();
        let loads: Vec<f64> = events
            .iter()
            .filter_map(|e| match e {
                RunEvent::Eps(o) => match &**o {
                    nodes_eps::EpsOutput::Sample { t, load_w, .. }
                        if (80..190).contains(&t.as_secs()) =>
                    {
                        Some(*load_w)
                    }
                    _ => None,
                },
                _ => None,
            })
            .collect();
        let mean = loads.iter().sum::<f64>() / loads.len() as f64;
        (f64::from(tm.total_impulse_n_s), mean)
    };
    let (fault_ns, fault_w) = impulse_and_load(&by_fault);
    let (channel_ns, channel_w) = impulse_and_load(&by_channel);
    eprintln!(
        "impulse: fault {fault_ns:.4} N s, channel {channel_ns:.4} N s; EPS load while off: fault {fault_w:.3} W, channel {channel_w:.3} W"
    );
    // 5 s of a 0.3 N thrust.
    assert!(
        (channel_ns - 1.5).abs() < 0.01,
        "EPS path: {channel_ns} N s"
    );
    assert!(
        (fault_ns - channel_ns).abs() < 0.1,
        "fault path {fault_ns} N s, EPS path {channel_ns} N s"
    );
    assert!(
        (fault_w - channel_w).abs() < 0.05,
        "EPS load while the ECU is off: {fault_w} W by the fault, {channel_w} W by the channel"
    );
}

/// A `power-off` fault on the PC ends while the EPS holds the PC's channel off: the PC stays
/// off until the channel is switched on again.
#[test]
fn a_node_stays_off_while_its_channel_is_off_after_a_power_fault_ends() {
    let text = format!(
        r#"
name = "pc-held"
duration = "320s"
start = "2026-04-30T18:00:00Z"
{TLE}
[fc]
publish_hz = 0

[[eps.events]]
at = "100s"
channel = "PC"
on = false

[[eps.events]]
at = "300s"
channel = "PC"
on = true

[[faults]]
at = "50s"
until = "150s"
kind = "power-off"
target = "PC"

[[commands]]
name = "ping-pc"
at = "40s"
to = "PC"
request = "ping"
timeout = "4s"

[[commands]]
name = "ping-pc-fault"
at = "120s"
to = "PC"
request = "ping"
timeout = "4s"

[[commands]]
name = "ping-pc-channel-off"
at = "200s"
to = "PC"
request = "ping"
timeout = "4s"

[[commands]]
name = "ping-pc-back"
at = "310s"
to = "PC"
request = "ping"
timeout = "4s"
"#
    );
    let (out, _) = run(&text);
    assert_eq!(answered(&out, "ping-pc"), vec![(40, true)]);
    assert_eq!(answered(&out, "ping-pc-fault"), vec![(120, false)]);
    assert_eq!(
        answered(&out, "ping-pc-channel-off"),
        vec![(200, false)],
        "the PC answered with its channel off"
    );
    assert_eq!(answered(&out, "ping-pc-back"), vec![(310, true)]);
}

/// `run --seed N` draws the initial attitude and tumble axis from N (they were drawn from
/// the file's seed whatever `--seed` said): two seeds, two initial attitudes; the file's own
/// seed given on the command line reproduces the plain run.
#[test]
fn the_seed_on_the_command_line_draws_the_initial_attitude() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("seed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let first_attitude = |seed: Option<&str>| {
        let file = dir.join(format!("seed-{}.mcap", seed.unwrap_or("file")));
        let mut args = vec![
            "run",
            "scenarios/adcs-detumble.toml",
            "--duration",
            "2s",
            "--record",
            file.to_str().unwrap(),
        ];
        if let Some(s) = seed {
            args.extend(["--seed", s]);
        }
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
            .args(&args)
            .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
            .output()
            .unwrap();
        // Exit 1 is a failed expectation of the shortened run; 2 would be an error.
        assert!(matches!(out.status.code(), Some(0 | 1)), "{out:?}");
        let tf = m6p_twin::recording::messages(&file)
            .unwrap()
            .map(Result::unwrap)
            .find(|m| &*m.topic == "/fc/truth/tf")
            .unwrap();
        let v = tf.json().unwrap();
        let _ = std::fs::remove_file(&file);
        v["rotation"].to_string()
    };
    let plain = first_attitude(None);
    let one = first_attitude(Some("1"));
    let two = first_attitude(Some("2"));
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(plain, one, "the file's seed is 1");
    assert_ne!(one, two, "seeds 1 and 2 start from the same attitude {one}");
}

/// A `corrupt` on the main bus: CAN's CRC-15 catches every flipped bit, so no corrupted
/// frame reaches a node (no CFP or CRC32 drop anywhere, every ping echo intact); the
/// transmitters retransmit, the bus counts error frames. At 5 % per frame the error
/// counters fall back faster than they rise (+8 per error, -1 per good frame): nobody goes
/// bus-off and every ping is answered. A corrupted frame delivered would be a wire CAN never
/// produces.
#[test]
fn a_corrupted_can_frame_never_reaches_a_node() {
    let text = r#"
name = "can-corrupt"
duration = "120s"

[[commands]]
name = "ping-eps"
at = "5s"
every = "1s"
count = 100
to = "EPS"
request = "ping"
size = 100
timeout = "2s"

[[faults]]
at = "1s"
until = "110s"
kind = "corrupt"
target = "main"
probability = 0.05
"#;
    let (out, _) = run(text);
    let pings = answered(&out, "ping-eps");
    assert_eq!(pings.len(), 100);
    assert!(pings.iter().all(|(_, ok)| *ok), "{pings:?}");
    for r in out.report.results.iter() {
        if let Outcome::Reply { data, .. } = &r.outcome {
            assert_eq!(data, &r.request.data, "a ping echo came back changed");
        }
    }
    for n in &out.report.nodes {
        for reason in [csp::drop::DropReason::Cfp, csp::drop::DropReason::Crc32] {
            assert_eq!(
                n.counters.drops.get(&reason).copied().unwrap_or(0),
                0,
                "{}: {:?}",
                n.name,
                n.counters.drops
            );
        }
    }
    let main = &out.report.buses[0];
    assert!(main.error_frames > 20, "{main:?}");
    assert_eq!(main.error_frames, main.corrupted);
    assert_eq!(main.bus_off, 0);
}

/// `bit-errors` at 1 % per bit on the ECU's frames from 10 s to 20 s while the ground asks
/// it for TMECU twice a second: its frames fail (about 73 % of a 130-bit frame), each error
/// frame is retransmitted, its TEC climbs to error-passive and bus-off (its replies are
/// lost), it recovers after 128 x 11 recessive bits and goes round again until the window
/// ends; afterwards it answers every request. The other controllers count the errors as
/// receivers (they may go error-passive, never bus-off). No damaged reply reaches the
/// ground: every TMECU reply that arrives is whole.
#[test]
fn bit_errors_drive_a_node_bus_off_and_it_recovers() {
    use bus::can::{CanErrorKind, ErrorState};
    use bus::trace::TraceFrame;
    let text = r#"
name = "bit-errors"
duration = "40s"

[[commands]]
name = "tmecu"
at = "1s"
every = "500ms"
count = 70
to = "ECU"
request = "raw"
port = 10
data = "01"
timeout = "400ms"

[[faults]]
at = "10s"
until = "20s"
kind = "bit-errors"
target = "main"
node = "ECU"
ber = 0.01

[[expectations]]
name = "ecu-went-bus-off-and-came-back"
kind = "can"
bus = "main"
node = "ECU"
state = "bus-off"
min = 1
end_state = "error-active"

[[expectations]]
name = "the-fc-never-went-bus-off"
kind = "can"
bus = "main"
node = "FC"
max = 0
"#;
    let (out, events) = run(text);
    for v in &out.verdicts {
        assert!(v.passed, "{}: {}", v.name, v.observed);
    }
    assert_eq!(out.verdicts.len(), 2);
    // What the ECU's controller went through, in order.
    let mut states = Vec::new();
    let mut error_frames = 0;
    for e in &events {
        if let RunEvent::Medium(m) = e
            && let TraceFrame::CanError(c) = &m.frame
        {
            match c.kind {
                CanErrorKind::ErrorFrame { .. } => {
                    assert_eq!(&*c.node, "ECU", "only the ECU's frames fail: {c:?}");
                    error_frames += 1;
                }
                CanErrorKind::State(s) if &*c.node == "ECU" => {
                    states.push((m.t.as_secs_f64(), s, c.tec));
                }
                // The receivers count the errors too (REC +1 each): they may go
                // error-passive, never bus-off.
                CanErrorKind::State(s) => assert_ne!(s, ErrorState::BusOff, "{c:?}"),
            }
        }
    }
    assert!(error_frames > 100, "{error_frames} error frames");
    let ecu = out.report.buses[0]
        .ports
        .iter()
        .find(|p| p.name == "ECU")
        .unwrap();
    eprintln!(
        "ECU: {error_frames} error frames, states {states:?}, stats {ecu:?}, main bus {:?}",
        (
            out.report.buses[0].error_frames,
            out.report.buses[0].bus_off
        )
    );
    assert!(ecu.passive_count >= 1 && ecu.bus_off_count >= 1, "{ecu:?}");
    assert_eq!(ecu.recoveries, ecu.bus_off_count, "it came back every time");
    assert!(ecu.tec_max > 255, "{ecu:?}");
    assert_eq!(ecu.state, ErrorState::Active);
    // The order of states: error-passive before each bus-off, recovery after it.
    let first_passive = states.iter().position(|s| s.1 == ErrorState::Passive);
    let first_off = states.iter().position(|s| s.1 == ErrorState::BusOff);
    assert!(first_passive < first_off, "{states:?}");
    let off = states[first_off.unwrap()];
    let back = states[first_off.unwrap() + 1];
    assert_eq!((back.1, back.2), (ErrorState::Active, 0), "{states:?}");
    assert!(
        off.0 >= 10.0 && back.0 > off.0 && back.0 < 20.5,
        "{states:?}"
    );
    // Every state change within the window (and the recovery just after it at most).
    assert!(
        states.iter().all(|s| s.0 >= 10.0 && s.0 < 20.5),
        "{states:?}"
    );
    // Replies: all before and after the window, every one that arrived whole.
    let replies: Vec<(u64, bool)> = answered(&out, "tmecu");
    assert!(
        replies
            .iter()
            .filter(|(t, _)| *t < 10 || *t >= 21)
            .all(|(_, ok)| *ok),
        "{replies:?}"
    );
    assert!(
        replies.iter().any(|(_, ok)| !ok),
        "bus-off lost some replies"
    );
    for r in &out.report.results {
        if let Outcome::Reply { data, .. } = &r.outcome {
            assert_eq!(data.len(), 44, "a TMECU reply arrived damaged: {data:02x?}");
            assert_eq!(&data[..2], &[1, 1]);
        }
    }
    for n in &out.report.nodes {
        assert_eq!(
            n.counters
                .drops
                .get(&csp::drop::DropReason::Crc32)
                .copied()
                .unwrap_or(0),
            0,
            "{}",
            n.name
        );
    }
}

/// A babbling ECU floods the main bus from 10 s to 20 s with frame id 0x11000000 (CFP
/// source 17): arbitration is by id, and libcsp 1.4's CFP id begins with the source
/// address, so ground station 16's requests (forwarded by COMM1 with source 16, a lower
/// id) still get through while station 18's (source 18) never win the bus until the
/// babble stops; the EPS's replies (source 4) always win. The bus is saturated meanwhile.
/// COMM1 sends its frames in order (one transmit queue, as libcsp 1.4's CAN driver): once a
/// frame of station 18's waits at its head, station 16's wait behind it.
#[test]
fn a_babbling_node_starves_exactly_the_frames_with_higher_ids() {
    let scenario = |stations: &[u8]| {
        let mut text = String::from(
            "name = \"babble\"\nduration = \"30s\"\n\n[network]\nground_stations = [16, 18]\n",
        );
        for &gs in stations {
            text.push_str(&format!(
                "\n[[commands]]\nname = \"from-{gs}\"\nfrom = \"GS{gs}\"\nat = \"{}ms\"\nevery = \"1s\"\ncount = 20\nto = \"EPS\"\nrequest = \"ping\"\ntimeout = \"900ms\"\n",
                if gs == 16 { 5000 } else { 5500 }
            ));
        }
        text.push_str(
            "\n[[faults]]\nat = \"10s\"\nuntil = \"20s\"\nkind = \"babble\"\ntarget = \"main\"\nnode = \"ECU\"\ncan_id = 0x11000000\n",
        );
        run(&text)
    };
    // A request starves when the babble lasts past its 900 ms timeout: those sent in
    // [10 s, 19.1 s). Station 18's go at x.5 s.
    let in_window = |t: &u64| (10..19).contains(t);
    // Station 16 alone: every ping answered through the babble.
    let (out, events) = scenario(&[16]);
    let from16 = answered(&out, "from-16");
    assert!(from16.iter().all(|(_, ok)| *ok), "{from16:?}");
    // The babble: frames from the ECU with its id, back to back in the window.
    let (mut n, mut busy_ns, mut first, mut last) = (0u64, 0u64, f64::MAX, 0f64);
    for e in &events {
        if let RunEvent::Medium(m) = e
            && let Some(f) = m.frame.can_on_wire()
            && &*m.medium == "main"
        {
            let t = m.t.as_secs_f64();
            if f.id == 0x1100_0000 {
                assert_eq!(&*m.from, "ECU");
                n += 1;
                first = first.min(t);
                last = last.max(t);
            }
            if (10.0..20.0).contains(&t) {
                busy_ns += u64::from(bus::can::frame_bits(f)) * 1000;
            }
        }
    }
    let load = busy_ns as f64 / 10e9;
    let bits = bus::can::frame_bits(&csp::cfp::CanFrame::new(0x1100_0000, &[0; 8]).unwrap());
    let max = 10_000_000 / u64::from(bits);
    // Station 18 alone: none of its pings in the window wins the bus.
    let (out18, _) = scenario(&[18]);
    let from18 = answered(&out18, "from-18");
    for (t, ok) in &from18 {
        assert_eq!(*ok, !in_window(t), "GS18 ping at {t} s: answered {ok}");
    }
    // Both: station 16's frames queue behind station 18's at COMM1.
    let (both, _) = scenario(&[16, 18]);
    let (b16, b18) = (answered(&both, "from-16"), answered(&both, "from-18"));
    eprintln!(
        "babble: {n} frames of {bits} bits (at most {max} in 10 s) from {first:.6} s to {last:.6} s; \
         main bus load in the window {:.4} %; GS16 alone {}/{} answered; GS18 alone {}/{} answered \
         ({} of 9 in the window); both: GS16 {}/{}, GS18 {}/{}",
        load * 100.0,
        from16.iter().filter(|x| x.1).count(),
        from16.len(),
        from18.iter().filter(|x| x.1).count(),
        from18.len(),
        from18.iter().filter(|x| x.1 && in_window(&x.0)).count(),
        b16.iter().filter(|x| x.1).count(),
        b16.len(),
        b18.iter().filter(|x| x.1).count(),
        b18.len(),
    );
    assert!(load > 0.999, "load {load}");
    assert!(first >= 10.0 && last <= 20.0 + 1e-3, "{first} {last}");
    assert!(n > max * 99 / 100 && n <= max, "{n} of at most {max}");
    assert!(b18.iter().all(|(t, ok)| *ok != in_window(t)), "{b18:?}");
    // From station 18's first starved request (10.5 s) to the end of the babble, station
    // 16's wait behind it: those sent at 11 s to 19 s time out.
    for (t, ok) in &b16 {
        assert_eq!(
            *ok,
            !(11..20).contains(t),
            "GS16 ping at {t} s behind GS18's"
        );
    }
}

/// `panel-loss` of wing+Y from 1 h to 1 h 20 m in sun-max-power pointing: that panel gives
/// nothing meanwhile (the others as before), and the arrays' power in sunlight drops by its
/// share; back afterwards.
#[test]
fn a_lost_panel_gives_nothing_until_restored() {
    let text = format!(
        r#"
name = "panel-loss"
duration = "6000s"
start = "2026-04-30T18:00:00Z"
seed = 3
{TLE}
[fc]
mode = "sun-max-power"
initial_rate_deg_s = 0.5

[[faults]]
at = "3600s"
until = "4800s"
kind = "panel-loss"
target = "EPS"
panel = "wing+Y"
"#
    );
    let (_, events) = run(&text);
    let mut lost = (0, 0.0, 0.0);
    let mut kept = (0, 0.0, 0.0);
    for e in &events {
        if let RunEvent::Eps(o) = e
            && let nodes_eps::EpsOutput::Sample {
                t,
                solar_w,
                panels_w,
                ..
            } = &**o
            && *solar_w > 30.0
        {
            let s = t.as_secs();
            let wing = panels_w[1];
            if (3601..4800).contains(&s) {
                assert_eq!(wing, 0.0, "wing+Y gives {wing} W at {s} s");
                lost = (lost.0 + 1, lost.1 + solar_w, lost.2);
            } else if s > 4800 {
                assert!(wing > 10.0, "wing+Y back: {wing} W at {s} s");
                kept = (kept.0 + 1, kept.1 + solar_w, kept.2 + wing);
            }
        }
    }
    let (mean_lost, mean_kept) = (lost.1 / lost.0 as f64, kept.1 / kept.0 as f64);
    let wing_share = kept.2 / kept.1;
    eprintln!(
        "panel-loss: sunlit array power {mean_lost:.2} W without wing+Y ({} samples), {mean_kept:.2} W with it ({} samples, wing {:.1} %)",
        lost.0,
        kept.0,
        wing_share * 100.0
    );
    assert!(lost.0 > 100 && kept.0 > 100);
    assert!((mean_lost / mean_kept - (1.0 - wing_share)).abs() < 0.05);
}

/// `battery-fade` of half the capacity at 10 min: the state of charge is kept at that
/// instant, and every eclipse afterwards takes twice as much of it as it takes from the
/// fresh battery (the same energy out of half the capacity).
#[test]
fn a_faded_battery_drains_faster_in_eclipse() {
    let scenario = |fault: &str| {
        format!(
            r#"
name = "battery-fade"
duration = "7200s"
start = "2026-04-30T18:00:00Z"
seed = 3
{TLE}
[fc]
mode = "nadir"
initial_rate_deg_s = 0.5
{fault}
"#
        )
    };
    let eclipse_drop = |text: &str| {
        let (_, events) = run(text);
        let samples: Vec<(u64, f64, f64)> = events
            .iter()
            .filter_map(|e| match e {
                RunEvent::Eps(o) => match &**o {
                    nodes_eps::EpsOutput::Sample {
                        t, soc, solar_w, ..
                    } => Some((t.as_secs(), *soc, *solar_w)),
                    _ => None,
                },
                _ => None,
            })
            .collect();
        let at_fade = samples.iter().find(|s| s.0 == 600).map(|s| s.1);
        let before = samples.iter().find(|s| s.0 == 599).map(|s| s.1);
        let drop: f64 = samples
            .windows(2)
            .filter(|w| w[0].0 > 700 && w[0].2 == 0.0 && w[1].2 == 0.0)
            .map(|w| w[0].1 - w[1].1)
            .sum();
        (before, at_fade, drop)
    };
    let (b0, a0, fresh) = eclipse_drop(&scenario(""));
    let (b1, a1, faded) = eclipse_drop(&scenario(
        "\n[[faults]]\nat = \"600s\"\nkind = \"battery-fade\"\ntarget = \"EPS\"\nfraction = 0.5\n",
    ));
    eprintln!(
        "battery-fade: SOC taken by eclipses after 700 s: fresh {fresh:.5}, half capacity {faded:.5}"
    );
    assert_eq!(
        (b0, a0),
        (b1, a1),
        "the state of charge is kept at the fade"
    );
    assert!(fresh > 0.02, "an eclipse in the window: {fresh}");
    assert!((faded / fresh - 2.0).abs() < 0.01, "{faded} / {fresh}");
}

/// A `clock` fault on the FC: its RTC jumps 60 s ahead at 100 s, so a script the ground
/// timed for 300 s..400 s (true UTC) runs from 240 s to 340 s; the RTC it reports is 60 s
/// ahead; once corrected (500 s) it reads true time again. With the FC's time distribution
/// off (`[rules] time_sync_to = []`), the PC's clock, 30 s ahead from 100 s, starts a session
/// SETUP timed for 400 s at 370 s (ICD 3.1: the PC's clock). With it on (the default), the
/// PC's clock follows the FC's RTC (sent at boot and every 60 s: at 120 s it takes the FC's
/// 60 s over its own 30 s), and the session starts at 340 s.
#[test]
fn a_clock_fault_moves_what_runs_on_that_clock() {
    for (rules, session_at) in [("[rules]\ntime_sync_to = []\n", 370), ("", 340)] {
        clock_fault_run(rules, session_at);
    }
}

fn clock_fault_run(rules: &str, session_at: u64) {
    // 2026-04-30T18:00:00Z.
    let start = 1_777_572_000u64;
    let text = format!(
        r#"
name = "clock"
duration = "600s"
start = "2026-04-30T18:00:00Z"
{TLE}
{rules}[fc]
mode = "nadir"
initial_rate_deg_s = 0.5

[[fc.scripts]]
at = "10s"
line = "adcs {} {} pointLVLH 1 0 0 0"

[[commands]]
name = "rtc"
at = "200s"
to = "FC"
request = "raw"
port = 11
data = "02"

[[commands]]
name = "rtc-corrected"
at = "550s"
to = "FC"
request = "raw"
port = 11
data = "02"

[[commands]]
name = "setup"
at = "150s"
to = "PC"
request = "raw"
port = 10
data = "0101{}1e000000c8676f"

[[faults]]
at = "100s"
kind = "clock"
target = "PC"
jump_s = 30

[[faults]]
at = "100s"
until = "500s"
kind = "clock"
target = "FC"
jump_s = 60
"#,
        start + 300,
        start + 400,
        hex::encode(u32::try_from(start + 400).unwrap().to_le_bytes())
    );
    let (out, events) = run(&text);
    // The script's mode (fixed LVLH, 8) while it runs, by the published samples.
    let running: Vec<u64> = events
        .iter()
        .filter_map(|e| match e {
            RunEvent::Truth { t, adcs, .. } if adcs.mode_commanded == 8 => Some(t.as_secs()),
            _ => None,
        })
        .collect();
    eprintln!(
        "clock: the script ran from {:?} s to {:?} s",
        running.first(),
        running.last()
    );
    assert_eq!(running.first(), Some(&240));
    assert_eq!(running.last(), Some(&339));
    let rtc = |name: &str| {
        let r = out
            .report
            .results
            .iter()
            .find(|r| r.request.label == name)
            .unwrap();
        let Outcome::Reply { data, .. } = &r.outcome else {
            panic!("{name}: {:?}", r.outcome)
        };
        u64::from(u32::from_le_bytes(data[2..6].try_into().unwrap()))
    };
    let session_start = events.iter().find_map(|e| match e {
        RunEvent::Pc(o) => match &**o {
            nodes_pc::PcOutput::SessionStarted { t, .. } => Some(t.as_secs()),
            _ => None,
        },
        _ => None,
    });
    eprintln!("clock: the PC's session timed for 400 s started at {session_start:?} s");
    assert_eq!(session_start, Some(session_at), "{rules}");
    assert_eq!(rtc("rtc"), start + 200 + 60);
    assert_eq!(rtc("rtc-corrected"), start + 550);
}

/// The FC's state in TMGEN: SAFE while the ADCS's estimator monitor holds it in its
/// fallback (a 1 deg/s gyro bias jump in sunlight trips it, as `crates/adcs/tests/health.rs`
/// shows), NOMINAL before and again once the restarted estimator has relearnt the bias;
/// each change is a log line of the FC's.
#[test]
fn the_fc_is_safe_while_the_adcs_falls_back_from_its_estimator() {
    // 2026-04-30T19:06:40Z: the default orbit, in sunlight for an hour.
    let text = format!(
        r#"
name = "safe"
duration = "1500s"
start = "2026-04-30T19:06:40Z"
{TLE}
[fc]
mode = "nadir"

[[fc.faults]]
at = "600s"
sensor = "gyro"
fault = "bias:0.0174533"

[[commands]]
name = "tmgen"
at = "10s"
every = "10s"
count = 149
to = "FC"
request = "raw"
port = 10
data = "01"
"#
    );
    let (out, events) = run(&text);
    // TMGEN's current_state (reply byte 2 + 13) by send time.
    let states: Vec<(u64, u8)> = out
        .report
        .results
        .iter()
        .filter_map(|r| match &r.outcome {
            Outcome::Reply { data, .. } => Some((r.sent.as_secs(), data[15])),
            _ => None,
        })
        .collect();
    let safe_at = states.iter().find(|(_, s)| *s == 1).map(|(t, _)| *t);
    let logs: Vec<(u64, String)> = events
        .iter()
        .filter_map(|e| match e {
            RunEvent::Log {
                t, message, source, ..
            } if source == "FC" && message.starts_with("fc: ") => {
                Some((t.as_secs(), message.clone()))
            }
            _ => None,
        })
        .collect();
    eprintln!("safe: first SAFE TMGEN at {safe_at:?} s; FC state lines {logs:?}");
    assert!(states.len() > 140, "{states:?}");
    assert!(
        states.iter().all(|&(t, s)| t >= 600 || s == 0),
        "NOMINAL before the fault: {states:?}"
    );
    assert!(safe_at.is_some_and(|t| t > 600), "{states:?}");
    assert!(
        logs.iter()
            .any(|(t, m)| *t > 600 && m.contains("SAFE: the ADCS fell back from its estimator")),
        "{logs:?}"
    );
    // The monitor restarts the estimator, which relearns the bias: NOMINAL again.
    assert!(
        logs.last()
            .is_some_and(|(_, m)| m.starts_with("fc: NOMINAL")),
        "{logs:?}"
    );
    assert_eq!(states.last().map(|s| s.1), Some(0), "{states:?}");
}
