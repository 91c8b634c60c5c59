//! Outside links tried as a hostile or simply buggy client would: impostors claiming
//! addresses of the twin or of another client, two links with their own addresses, a
//! passive payload, floods at TCP speed on the ground segment and the main bus, and a client
//! that never reads. The twin runs as the `m6p-twin` binary in real time (its memory is its
//! own, measured from /proc); `M6P_TWIN_BIN` runs another build instead (an older one, to
//! see these tests fail there). Each test takes 5-20 s of wall clock.
#![allow(clippy::unwrap_used)]

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use csp::{Header, Packet};

mod common;
use common::twin_process::{Client, Twin, answer_pings, bare, bare_text, ping, write_scenario};

/// The ground client that took an address first keeps it: a second one claiming it is
/// refused and logged, and gets nothing meant for the first.
#[test]
fn two_clients_claiming_one_address_the_first_keeps_its_replies() {
    let scenario = bare("claims", 8);
    let twin = Twin::start(
        &[scenario.to_str().unwrap(), "--kiss-listen", "127.0.0.1:0"],
        1,
    );
    let mut a = Client::connect(twin.addrs[0]);
    let mut b = Client::connect(twin.addrs[0]);
    assert!(
        a.ping(17, 3, 1, Duration::from_secs(3)).is_some(),
        "A's first ping"
    );
    assert!(
        b.ping(17, 3, 2, Duration::from_secs(2)).is_none(),
        "B, claiming A's address 17, was answered"
    );
    assert!(
        a.ping(17, 3, 3, Duration::from_secs(3)).is_some(),
        "A's ping after B's claim"
    );
    // Nothing reached B, and A never saw B's tag.
    assert!(b.drain(Duration::from_millis(500)).is_empty());
    assert!(
        a.drain(Duration::from_millis(200))
            .iter()
            .all(|p| p.data != 2u32.to_le_bytes())
    );
    let (ok, out, err) = twin.finish();
    assert!(ok, "{out}{err}");
    assert!(
        err.contains("WARN") && err.contains("#2") && err.contains("address 17 is held by"),
        "{err}"
    );
    assert!(out.contains("(1 claims"), "{out}");
}

/// A client sending as the FC (source 3) is refused and logged; the FC still answers
/// others, and the client's forged reply does not reach them.
#[test]
fn a_client_sending_as_the_fc_is_refused_and_the_fc_still_answers_others() {
    let scenario = bare("impostor", 8);
    let twin = Twin::start(
        &[scenario.to_str().unwrap(), "--kiss-listen", "127.0.0.1:0"],
        1,
    );
    let mut honest = Client::connect(twin.addrs[0]);
    let mut impostor = Client::connect(twin.addrs[0]);
    // The impostor speaks first: as the FC, a forged ping reply to 17.
    impostor.send(&Packet::new(
        Header::new(3, 17, 40, 1),
        7u32.to_le_bytes().to_vec(),
    ));
    std::thread::sleep(Duration::from_millis(300));
    for tag in 10..13 {
        let rtt = honest.ping(17, 3, tag, Duration::from_secs(3));
        assert!(rtt.is_some(), "ping {tag} to the FC not answered");
    }
    let forged = honest.drain(Duration::from_millis(300));
    assert!(
        forged.iter().all(|p| p.data != 7u32.to_le_bytes()),
        "the forged reply reached a ground client: {forged:?}"
    );
    assert!(impostor.drain(Duration::from_millis(300)).is_empty());
    let (ok, out, err) = twin.finish();
    assert!(ok, "{out}{err}");
    assert!(err.contains("address 3 is held by FC"), "{err}");
}

/// A payload link with `addrs = [14]` and a ground console on another link both work: the
/// console (learning 17) pings the payload program and the FC; the payload, which never
/// sends first, answers.
#[test]
fn a_payload_link_with_its_address_and_a_ground_console_on_another_link_both_work() {
    let scenario = write_scenario(
        "two-links",
        r#"
name = "two-links"
duration = "10s"

[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:0"
addrs = [14]

[[links]]
kind = "kiss-listen"
addr = "127.0.0.1:0"
"#,
    );
    let twin = Twin::start(&[scenario.to_str().unwrap()], 2);
    let stop = Arc::new(AtomicBool::new(false));
    // The payload program: answers pings to 14, never sends first.
    let payload = answer_pings(twin.addrs[0], 14, stop.clone());
    std::thread::sleep(Duration::from_millis(300));
    let mut console = Client::connect(twin.addrs[1]);
    for tag in 0..3 {
        assert!(
            console.ping(17, 3, tag, Duration::from_secs(3)).is_some(),
            "console ping {tag} to the FC"
        );
        assert!(
            console
                .ping(17, 14, 100 + tag, Duration::from_secs(3))
                .is_some(),
            "console ping {tag} to the outside payload 14"
        );
    }
    stop.store(true, Ordering::Relaxed);
    assert_eq!(payload.join().unwrap(), 3);
    let (ok, out, err) = twin.finish();
    assert!(ok, "{out}{err}");
    std::fs::remove_file(scenario).ok();
}

/// A passive outside payload (`examples/outside_payload.py`: it only answers) serves a whole
/// PC session of `examples/README.md`'s scenario on its link (`addrs = [12]`), while a ground
/// console on a second link (no addresses: it is learned as 17) pings the FC throughout. The
/// session runs to DONE with all 25 frames downlinked (the scenario's expectations), and
/// every console ping is answered.
#[test]
fn a_passive_payload_serves_a_whole_session_beside_a_console_on_another_link() {
    let text = common::readme_scenario()
        .replace("127.0.0.1:52001", "127.0.0.1:0")
        .replace(
            "[pc]\n",
            "[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:0\"\n\n[pc]\n",
        );
    assert_eq!(text.matches("[[links]]").count(), 2, "{text}");
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("hostile-{}-passive", std::process::id()));
    let text = text.replace("/tmp/outside_payload.downlink", dir.to_str().unwrap());
    let scenario = write_scenario("passive", &text);
    let twin = Twin::start(&[scenario.to_str().unwrap()], 2);
    // The console connects first and pings the FC every 400 ms until the payload is done.
    let stop = Arc::new(AtomicBool::new(false));
    let console = {
        let (addr, stop) = (twin.addrs[1], stop.clone());
        std::thread::spawn(move || {
            let mut c = Client::connect(addr);
            let (mut sent, mut answered) = (0u32, 0u32);
            while !stop.load(Ordering::Relaxed) {
                sent += 1;
                if c.ping(17, 3, sent, Duration::from_secs(3)).is_some() {
                    answered += 1;
                }
                std::thread::sleep(Duration::from_millis(400));
            }
            (sent, answered)
        })
    };
    std::thread::sleep(Duration::from_millis(200));
    let payload = Command::new("python3")
        .arg(common::repo_root().join("examples/outside_payload.py"))
        .args(["--connect", &twin.addrs[0].to_string()])
        .args(["--idle", "1.5", "--seconds", "12", "--wait", "5"])
        .output()
        .expect("python3 is needed for this test");
    stop.store(true, Ordering::Relaxed);
    let py = format!(
        "{}{}",
        String::from_utf8_lossy(&payload.stdout),
        String::from_utf8_lossy(&payload.stderr)
    );
    let (sent, answered) = console.join().unwrap();
    let (ok, out, err) = twin.finish();
    std::fs::remove_file(scenario).ok();
    std::fs::remove_dir_all(&dir).ok();
    assert!(payload.status.success(), "the payload: {py}");
    assert!(
        py.contains("1 SYNC, 25 POLL, 3416 data bytes sent, 0 refused, 0 damaged frames"),
        "{py}"
    );
    // The scenario's expectations: SETUP accepted, DONE after 25 packets, 3416 bytes down.
    assert!(ok, "{out}{err}");
    assert!(
        sent >= 5 && answered == sent,
        "console: {answered} of {sent} pings answered"
    );
}

/// What a flood did to another client: its round trips before, during and after.
struct Flooded {
    /// Bytes the flooder wrote.
    sent: u64,
    /// The most the twin's memory grew, MiB.
    grew_mib: f64,
    /// The median of five round trips before the flood.
    unloaded: Duration,
    /// Each ping sent during the flood: its round trip if the reply came before the flood
    /// ended.
    during: Vec<Option<Duration>>,
    /// Of five pings after the flood, how many were answered.
    answered_after: usize,
    /// What the run printed.
    out: String,
}

impl Flooded {
    /// The median round trip during the flood, a ping not answered before the flood ended
    /// counting as longer than all.
    fn median_during(&self) -> Option<Duration> {
        let mut v = self.during.clone();
        v.sort_by_key(|d| d.unwrap_or(Duration::MAX));
        v.get(v.len() / 2).copied().flatten()
    }
    fn answered_during(&self) -> usize {
        self.during.iter().flatten().count()
    }
}

/// Run `scenario` with a KISS listener (and `args`); flood `dst` from `src` as fast as TCP
/// takes it for 5 s, reading the replies or not, while another client pings the FC (one
/// ping at a time, 300 ms apart, each waiting at most until the flood ends: a reply after
/// it does not count as answered during it); then five pings after the flood.
fn flood(scenario: &str, src: u8, dst: u8, read_replies: bool, args: &[&str]) -> Flooded {
    const FLOOD: Duration = Duration::from_secs(5);
    let path = write_scenario(
        &format!("flood-{src}-{read_replies}-{}", args.len()),
        scenario,
    );
    let mut all = vec![path.to_str().unwrap(), "--kiss-listen", "127.0.0.1:0"];
    all.extend_from_slice(args);
    let twin = Twin::start(&all, 1);
    std::fs::remove_file(&path).ok();
    let addr = twin.addrs[0];
    let mut other = Client::connect(addr);
    let mut unloaded: Vec<Duration> = (0..5)
        .map(|k| other.ping(17, 3, k, Duration::from_secs(3)).unwrap())
        .collect();
    unloaded.sort();
    std::thread::sleep(Duration::from_millis(300));
    let rss_before = twin.rss_kib();
    let flooder = std::thread::spawn(move || {
        let s = TcpStream::connect(addr).unwrap();
        if read_replies {
            let mut r = s.try_clone().unwrap();
            std::thread::spawn(move || {
                let mut buf = [0u8; 65536];
                while matches!(r.read(&mut buf), Ok(n) if n > 0) {}
            });
        }
        let mut w = s;
        w.set_write_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let mut burst = Vec::new();
        for k in 0..512u32 {
            csp::kiss::encode(&ping(src, dst, k), &mut burst);
        }
        let mut sent = 0u64;
        let t0 = Instant::now();
        while t0.elapsed() < FLOOD {
            match w.write(&burst) {
                Ok(n) => sent += n as u64,
                Err(_) => std::thread::sleep(Duration::from_millis(1)),
            }
        }
        sent
    });
    let end = Instant::now() + FLOOD;
    let mut rss_max = rss_before;
    let mut during = Vec::new();
    let mut tag = 100;
    while let Some(left) = end
        .checked_duration_since(Instant::now())
        .filter(|l| *l > Duration::from_millis(50))
    {
        let sent_at = Instant::now();
        let rtt = other.ping(17, 3, tag, left);
        during.push(rtt.filter(|rtt| sent_at + *rtt <= end));
        tag += 1;
        rss_max = rss_max.max(twin.rss_kib());
        std::thread::sleep(Duration::from_millis(300));
    }
    let sent = flooder.join().unwrap();
    rss_max = rss_max.max(twin.rss_kib());
    // What was queued behind the flood drains first: the pings after it wait for that.
    let answered_after = (0..5)
        .filter(|k| {
            other
                .ping(17, 3, 1000 + k, Duration::from_secs(8))
                .is_some()
        })
        .count();
    let (_, out, err) = twin.finish_now();
    let f = Flooded {
        sent,
        grew_mib: rss_max.saturating_sub(rss_before) as f64 / 1024.0,
        unloaded: unloaded[2],
        during,
        answered_after,
        out: format!("{out}{err}"),
    };
    println!(
        "flood {src} -> {dst} (replies read: {read_replies}, {args:?}): {:.1} MiB written, RSS +{:.1} MiB; the other client's round trip: {:?} unloaded (median), {:?} median during ({} of {} answered during: {:?}), {} of 5 after",
        f.sent as f64 / 1048576.0,
        f.grew_mib,
        f.unloaded,
        f.median_during(),
        f.answered_during(),
        f.during.len(),
        f.during,
        f.answered_after
    );
    assert!(f.sent > 1 << 20, "the flood wrote only {} bytes", f.sent);
    assert!(f.grew_mib < 50.0, "RSS grew by {:.1} MiB", f.grew_mib);
    assert_eq!(f.answered_after, 5, "answered after the flood");
    f
}

/// A ground scenario: GS16 pings the FC once a second through the flood (from 2 s of the
/// run, while the other client measures the unloaded round trip, to 12 s), and expects
/// every ping answered.
const GS16_PINGS: &str = r#"
name = "gs16-pings"
duration = "30s"

[[commands]]
name = "gs16-ping"
at = "2s"
every = "1s"
count = 10
to = "FC"
request = "ping"
timeout = "5s"

[[expectations]]
kind = "reply"
command = "gs16-ping"
"#;

/// The air serves the ground stations in turn: a client flooding the uplink at full speed
/// (reading its replies, or not) delays another client's pings by at most one of its
/// packets each way: the median round trip during the flood is at most twice the unloaded
/// one plus one 256-byte packet's air time each way, and GS16 loses none of its pings.
/// First come, first served, each ping waited behind a transmit buffer of the flood each
/// way (10-13 s) and GS16 lost 7 of 8.
fn a_ground_flood_delays_others_by_one_packet_each_way(read_replies: bool) {
    let f = flood(GS16_PINGS, 18, 3, read_replies, &[]);
    let air_256 = Duration::from_secs_f64(256.0 * 8.0 / 9600.0);
    let bound = 2 * f.unloaded + 2 * air_256;
    let median = f.median_during();
    assert!(
        median.is_some_and(|m| m <= bound),
        "median round trip during the flood {median:?}, bound {bound:?}"
    );
    // The run is stopped after the flood (an interrupted run exits 1 whatever held): its
    // verdict table says how GS16's pings did.
    assert!(
        f.out.lines().any(|l| l.starts_with("  PASS ")) && !f.out.contains("  FAIL "),
        "GS16's pings: {}",
        f.out
    );
}

#[test]
fn a_flood_on_the_ground_segment_delays_others_by_one_packet_each_way() {
    a_ground_flood_delays_others_by_one_packet_each_way(true);
}

#[test]
fn a_flood_on_the_ground_segment_by_a_client_that_never_reads() {
    a_ground_flood_delays_others_by_one_packet_each_way(false);
}

/// On the main bus the lowest CAN id wins every arbitration, as on a real bus: a client at
/// 9 flooding the FC holds the ground's traffic (whose frames carry its address, 17, in
/// their id) off the bus for as long as it floods; it is answered again after.
#[test]
fn a_main_bus_flood_by_a_low_address_holds_higher_ones_off_until_it_stops() {
    let f = flood(&bare_text("flood-main", 30), 9, 3, false, &[]);
    assert_eq!(
        f.answered_during(),
        0,
        "answered during the flood: {:?}",
        f.during
    );
}

/// With a transmit budget on its link (1000 frames a second, an eighth of the bus), the
/// same flood leaves the bus to others: the other client's pings are answered during the
/// flood, the median round trip within twice the unloaded one plus 100 ms.
#[test]
fn a_transmit_budget_keeps_a_main_bus_flood_from_stalling_others() {
    let f = flood(
        &bare_text("flood-main-budget", 30),
        9,
        3,
        false,
        &["--kiss-tx-budget", "1000"],
    );
    let bound = 2 * f.unloaded + Duration::from_millis(100);
    let median = f.median_during();
    assert!(
        median.is_some_and(|m| m <= bound),
        "median round trip during the flood {median:?}, bound {bound:?}"
    );
    assert!(
        f.out.contains("frames held back by its transmit budget"),
        "{}",
        f.out
    );
}

/// A ground client that sends bursts of pings to the FC and never reads its replies
/// delays another ground client's pings by no more than the air time of what may be queued
/// ahead of them: a sender's transmit buffer each way (4 KiB, 3.4 s at 9600 bit/s), not
/// the 100 s of air its 6000 pings would take.
#[test]
fn a_client_that_never_reads_does_not_delay_others_beyond_the_bus_time() {
    let scenario = bare("stuck", 20);
    let twin = Twin::start(
        &[scenario.to_str().unwrap(), "--kiss-listen", "127.0.0.1:0"],
        1,
    );
    let addr = twin.addrs[0];
    let mut other = Client::connect(addr);
    let mut base = Vec::new();
    for tag in 0..3 {
        base.push(other.ping(17, 3, tag, Duration::from_secs(3)).unwrap());
    }
    let mut stuck = Client::connect(addr);
    // 6000 pings, whose replies are never read.
    for round in 0..20u32 {
        let mut burst = Vec::new();
        for k in 0..300u32 {
            csp::kiss::encode(&ping(18, 3, round * 1000 + k), &mut burst);
        }
        stuck.s.write_all(&burst).unwrap();
    }
    // Its burst taken in (the twin reads it at its own pace).
    std::thread::sleep(Duration::from_millis(1500));
    let t_stuck = Instant::now();
    let air = Duration::from_secs_f64(2.0 * 4096.0 * 8.0 / 9600.0);
    let mut during = Vec::new();
    for tag in 100..103 {
        during.push(
            other
                .ping(17, 3, tag, air + Duration::from_secs(3))
                .expect("answered while the stuck client is connected"),
        );
    }
    base.sort();
    during.sort();
    let (b, d) = (base[base.len() / 2], during[during.len() - 1]);
    println!(
        "ping round trip: median {b:?} before, longest {d:?} with the stuck client connected ({during:?}, {:?} after its burst)",
        t_stuck.elapsed()
    );
    assert!(
        d <= b + air + Duration::from_secs(1),
        "longest round trip {d:?} with the stuck client, median {b:?} before"
    );
    let (ok, out, err) = twin.finish();
    println!("{out}");
    assert!(ok, "{out}{err}");
    assert!(out.contains("out dropped"), "{out}");
}
