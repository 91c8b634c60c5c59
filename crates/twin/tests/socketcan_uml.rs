//! The twin bridged to a real `vcan0` (`RunOptions::socketcan`), with an outside CSP node on
//! the same interface, inside a User-Mode Linux guest (`tools/uml/run-in-uml.sh`), so it
//! works on hosts whose kernel has no SocketCAN.
//!
//! `twin_over_vcan_in_uml` (on the host) boots the guest, which re-executes this very test
//! binary with `--ignored --exact guest_twin_over_vcan`. That test runs the twin in real
//! time with its main bus bridged to `vcan0`, and, on its own thread and socket, an outside
//! node 10 built only from `SocketCanLink` and the CFP fragmenter/reassembler (not from the
//! twin): it pings the FC (3) and asks payload 12 (behind the PC, CFP next hop 6) for its
//! uptime, and checks both replies as they come back on `vcan0`. It then deletes `vcan0`
//! under a fresh bridge and checks that the bridge stops.
//!
//! Gated like `crates/links/tests/vcan_uml.rs`: without a UML kernel with the vcan module
//! (`build.rs`), `twin_over_vcan_in_uml` is compiled as ignored with the reason.
#![cfg(all(feature = "socketcan", target_os = "linux"))]

#[path = "../../../tools/uml/guest_test.rs"]
mod uml;

use std::path::PathBuf;
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bus::gate::LinkGate;
use bus::impair::Impairments;
use bus::outside::BridgeStats;
use bus::{CanBus, CanBusConfig, Clock, ClockMode};
use csp::cfp::{CSP_CAN_MTU, CanFrame, CfpId, Fragmenter, Reassembler};
use csp::{Header, Packet, SimTime};
use links::socketcan::{SocketCanLink, bridge};
use m6p_twin::network::{FC, NetworkSpec, PC};
use m6p_twin::report::{RunReport, run};
use m6p_twin::runtime::{RunOptions, SocketCanBus, build_runtime};

/// Set (to the interface name) only for the re-executed test binary inside the guest.
const GUEST_ENV: &str = "M6P_TWIN_VCAN_GUEST_IFNAME";
const GUEST_TEST: &str = "guest_twin_over_vcan";

/// The outside node's CSP address (reserved in the twin: no internal node has it).
const OUTSIDE: u8 = 10;
/// The payload asked for its uptime.
const PAYLOAD: u8 = 12;
const PING_SPORT: u8 = 40;
const UPTIME_SPORT: u8 = 41;
/// How long the twin runs.
const TWIN_RUN: Duration = Duration::from_secs(4);
/// How long the outside node waits after the twin starts before sending.
const SETTLE: Duration = Duration::from_millis(300);
/// Longest wait for both replies.
const REPLY_TIMEOUT: Duration = Duration::from_secs(3);

fn run_in_uml_script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tools/uml/run-in-uml.sh")
}

#[test]
#[cfg_attr(
    not(uml_available),
    ignore = "User-Mode Linux with vcan not installed (apt-get install user-mode-linux)"
)]
fn twin_over_vcan_in_uml() {
    let script = run_in_uml_script();
    assert!(script.is_file(), "{} missing", script.display());
    uml::run_guest_test(
        &script,
        GUEST_TEST,
        &[(GUEST_ENV, "vcan0")],
        "twin_over_vcan: OK",
    );
}

/// What the outside node got back.
#[derive(Debug)]
struct Outside {
    echo: Packet,
    uptime: Packet,
    frames_sent: usize,
    round_trip: Duration,
}

fn sim_now(start: Instant) -> SimTime {
    SimTime::from_ns(u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX))
}

fn ping_request() -> Packet {
    Packet::new(
        Header::new(OUTSIDE, FC, csp::service::PORT_PING, PING_SPORT),
        (0..32u8).collect::<Vec<u8>>(),
    )
}

fn uptime_request() -> Packet {
    Packet::new(
        Header::new(OUTSIDE, PAYLOAD, csp::service::PORT_UPTIME, UPTIME_SPORT),
        Vec::new(),
    )
}

/// Outside node 10 on `ifname`: its own socket, fragmenter and reassembler.
async fn outside_node(ifname: &str) -> Result<Outside, String> {
    let mut link = SocketCanLink::open(ifname).map_err(|e| e.to_string())?;
    tokio::time::sleep(SETTLE).await;
    let mut frag = Fragmenter::new(321, CSP_CAN_MTU);
    let mut frames: Vec<CanFrame> = Vec::new();
    // On the main bus the FC is a direct neighbour; payloads are reached through the PC.
    frag.fragment(&ping_request(), FC, &mut frames)
        .map_err(|e| format!("fragment ping: {e}"))?;
    frag.fragment(&uptime_request(), PC, &mut frames)
        .map_err(|e| format!("fragment uptime: {e}"))?;
    let start = Instant::now();
    for f in &frames {
        link.send(f).await.map_err(|e| e.to_string())?;
    }
    let mut reasm = Reassembler::default();
    let (mut echo, mut uptime) = (None, None);
    let collect = async {
        while echo.is_none() || uptime.is_none() {
            let frame = link.recv().await.map_err(|e| e.to_string())?;
            // The bridge puts every frame of the main bus on vcan0: keep ours.
            if CfpId::from_can_id(frame.id).dst != OUTSIDE {
                continue;
            }
            match reasm.handle(&frame, sim_now(start)) {
                Some(Ok(p)) if p.header.dport == PING_SPORT => echo = Some(p),
                Some(Ok(p)) if p.header.dport == UPTIME_SPORT => uptime = Some(p),
                Some(Ok(p)) => return Err(format!("unexpected packet {}", p.header)),
                Some(Err(drop)) => return Err(format!("CFP reassembly dropped a frame: {drop}")),
                None => {}
            }
        }
        Ok::<(), String>(())
    };
    match tokio::time::timeout(REPLY_TIMEOUT, collect).await {
        Ok(r) => r?,
        Err(_) => {
            return Err(format!(
                "timed out after {REPLY_TIMEOUT:?}: echo {}, uptime {}",
                if echo.is_some() {
                    "received"
                } else {
                    "missing"
                },
                if uptime.is_some() {
                    "received"
                } else {
                    "missing"
                },
            ));
        }
    }
    let round_trip = start.elapsed();
    Ok(Outside {
        echo: echo.ok_or("no echo")?,
        uptime: uptime.ok_or("no uptime")?,
        frames_sent: frames.len(),
        round_trip,
    })
}

/// Wait until `done` holds, 3 s at most: waited for, not slept on, since a guest on a busy
/// host takes its time.
async fn settled(done: impl Fn() -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(3);
    while !done() && tokio::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

fn node<'a>(report: &'a RunReport, name: &str) -> &'a csp::node::NodeCounters {
    &report
        .nodes
        .iter()
        .find(|n| n.name == name)
        .unwrap_or_else(|| panic!("no node {name} in the report"))
        .counters
}

/// Runs inside the UML guest only (started by `twin_over_vcan_in_uml`, which sets
/// `M6P_TWIN_VCAN_GUEST_IFNAME`); on the host it is ignored.
#[test]
#[ignore = "runs inside the User-Mode Linux guest, started by twin_over_vcan_in_uml"]
fn guest_twin_over_vcan() {
    let ifname = std::env::var(GUEST_ENV).unwrap_or_else(|_| {
        panic!("{GUEST_ENV} not set: this test runs inside the UML guest via twin_over_vcan_in_uml")
    });
    let mut opts = RunOptions::new(NetworkSpec::default_m6p(), TWIN_RUN);
    opts.clock = ClockMode::Realtime { speed: 1.0 };
    opts.socketcan = vec![(ifname.clone(), SocketCanBus::Main)];
    let rt = build_runtime().expect("tokio runtime");

    let (report, outside) = rt.block_on(async {
        let twin = tokio::spawn(run(opts, None));
        // The outside node: its own thread and runtime, nothing shared with the twin.
        let outside_if = ifname.clone();
        let outside = std::thread::spawn(move || {
            tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .map_err(|e| e.to_string())?
                .block_on(outside_node(&outside_if))
        });
        let report = twin.await.expect("twin task").expect("twin run");
        (report, outside.join().expect("outside node thread"))
    });
    print!("{}", report.table());
    let outside = outside.unwrap_or_else(|e| panic!("outside node 10 on {ifname}: {e}"));

    // The echo, byte for byte, from the FC.
    let ping = ping_request();
    assert_eq!(outside.echo.header, ping.header.reply(FC), "echo header");
    assert_eq!(outside.echo.data, ping.data, "echo data");
    // The payload's uptime, through the PC both ways.
    let up = uptime_request();
    assert_eq!(
        outside.uptime.header,
        up.header.reply(PAYLOAD),
        "uptime header"
    );
    assert_eq!(
        outside.uptime.data.len(),
        4,
        "uptime reply {:?}",
        outside.uptime
    );

    // The bridge's counters and the nodes' own view.
    let (name, b) = report
        .socketcan
        .first()
        .expect("a SocketCAN bridge in the report");
    assert!(name.contains(&ifname), "{name}");
    assert!(
        b.frames_in >= outside.frames_sent as u64 && b.frames_out > 0,
        "{name}: {b:?}"
    );
    assert_eq!(
        (b.recv_errors, b.send_errors, &b.ended),
        (0, 0, &None),
        "{b:?}"
    );
    let fc = node(&report, "FC");
    assert!(fc.rx_packets >= 1 && fc.service_replies >= 1, "FC {fc:?}");
    let pc = node(&report, "PC");
    assert!(pc.forwarded >= 2, "PC {pc:?}");
    let pl = node(&report, "PL12");
    assert!(pl.service_replies >= 1, "PL12 {pl:?}");

    // The command line's own flag (README's `m6p-twin run --socketcan vcan0[:main|:payload]`,
    // which tools/docs-walk.py leaves to this test): the binary bridges the payload bus.
    let cli = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(["run", "--no-checks", "--duration", "2s", "--socketcan"])
        .arg(format!("{ifname}:payload"))
        .output()
        .expect("run m6p-twin");
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&cli.stdout),
        String::from_utf8_lossy(&cli.stderr)
    );
    assert!(cli.status.success(), "m6p-twin run --socketcan: {said}");
    assert!(said.contains(&ifname), "no word of {ifname}: {said}");

    // A link-down fault on a bridge (its gate, as a scenario's `link-down` on a named
    // SocketCAN link sets it): a frame from the interface stops at the link, counted, and
    // crosses again once the fault is lifted.
    let (held, passed) = rt.block_on(async {
        let clock = Clock::new(ClockMode::Realtime { speed: 1.0 });
        let can = CanBus::new(CanBusConfig::new("main"), 1);
        tokio::spawn(can.clone().run(clock));
        let gate = LinkGate::new(1);
        let down = Impairments {
            down: true,
            ..Default::default()
        };
        gate.set_fault(0, Some(down));
        let link = SocketCanLink::open(&ifname).expect("reopen the interface");
        let stats = Arc::new(Mutex::new(BridgeStats::default()));
        let task = tokio::spawn(bridge(can.clone(), link, clock, stats, Some(gate.clone())));
        let writer = SocketCanLink::open(&ifname).expect("a second socket");
        let frame = CanFrame::new(0x0012_3456, &[1, 2, 3]).expect("valid frame");
        tokio::time::sleep(Duration::from_millis(50)).await;
        writer.send(&frame).await.expect("send");
        settled(|| gate.stats().down + can.stats().frames > 0).await;
        let held = (gate.stats().down, can.stats().frames);
        gate.set_fault(0, None);
        writer.send(&frame).await.expect("send");
        settled(|| can.stats().frames > 0).await;
        let passed = can.stats().frames;
        task.abort();
        (held, passed)
    });
    assert_eq!(
        held,
        (1, 0),
        "(lost at the gate, frames on the bus) while down"
    );
    assert_eq!(passed, 1, "frames on the bus once lifted");

    // A bridge whose interface is deleted stops and says why.
    let ended = rt.block_on(async {
        let clock = Clock::new(ClockMode::Realtime { speed: 1.0 });
        let can = CanBus::new(CanBusConfig::new("main"), 1);
        tokio::spawn(can.clone().run(clock));
        let link = SocketCanLink::open(&ifname).expect("reopen the interface");
        let stats = Arc::new(Mutex::new(BridgeStats::default()));
        let task = tokio::spawn(bridge(can, link, clock, stats.clone(), None));
        tokio::time::sleep(Duration::from_millis(50)).await;
        let st = Command::new("ip")
            .args(["link", "del", "dev", &ifname])
            .status()
            .expect("run ip");
        assert!(st.success(), "ip link del {ifname}: {st}");
        tokio::time::timeout(Duration::from_secs(2), task)
            .await
            .expect("the bridge did not stop when its interface was deleted")
            .expect("bridge task");
        let s = stats.lock().expect("stats").clone();
        s.ended.expect("BridgeStats::ended set")
    });

    println!(
        "twin_over_vcan: OK on {ifname}: node {OUTSIDE} pinged FC {FC} (32 B echoed) and read PL{PAYLOAD}'s uptime via PC {PC} in {:?}; bridge {b:?}; deleting {ifname} stopped a bridge: {ended}",
        outside.round_trip
    );
}
