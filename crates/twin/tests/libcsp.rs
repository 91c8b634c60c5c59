//! The twin against the real libcsp 1.4: the vendored, unmodified library
//! (`third_party/libcsp-1.4`) built with `cc` into the small C programs of `tests/libcsp/`
//! (`build.sh`), which join a real-time run the ways libcsp connects:
//!
//! - over KISS on the twin's pseudo-terminal (`KissMode::Pty`, libcsp's `usart_init`);
//! - over the twin's ZMQ hub (`KissMode::ZmqHub`, libcsp's `csp_zmqhub_init`), each test
//!   on a loopback address of its own (127.0.0.x) so that they run side by side;
//! - over SocketCAN, in the User-Mode Linux guest of `socketcan_uml.rs` (`libcsp_can.rs`).
//!
//! `csp_client` pings every node of the default network (1, 64 and 200 bytes, with and
//! without CRC32), asks CMP ident, uptime, ps, memfree and buf_free of the FC and the PC,
//! runs a transaction with every ICD telemetry command of the FC (reply lengths of
//! `icd_lengths.rs`) and checks that a reserved address times out. `csp_payload` takes the
//! place of payload 12 and serves a whole polling session of the PC (the scenario of
//! `examples/README.md`), with libcsp's connection API and connection-less; what reached
//! the ground is byte for byte what it logged as sent.
//!
//! Needs a C compiler and libzmq's headers (Debian `gcc`, `libzmq3-dev`): without them the
//! tests are compiled as ignored with the reason (`build.rs`, `cfg(libcsp_peer)`); in CI
//! they are always compiled, so a missing prerequisite fails.
#![cfg(unix)]
#![allow(clippy::unwrap_used)]

mod common;
mod libcsp_peer;

use libcsp_peer::{
    Iface, client, client_checks, expected_stream, programs, readme_options, run_payload_session,
    same_bytes, with_twin,
};
use m6p_twin::runtime::{KissLink, KissMode};

/// A test that needs libcsp 1.4 built: ignored with the reason where it cannot be.
macro_rules! libcsp_test {
    ($(#[$m:meta])* fn $name:ident() $body:block) => {
        $(#[$m])*
        #[test]
        #[cfg_attr(
            not(libcsp_peer),
            ignore = "needs a C compiler and libzmq3-dev to build libcsp 1.4 (apt-get install gcc libzmq3-dev)"
        )]
        fn $name() $body
    };
}

/// The default scenario in real time with one link for address 10 at `mode`.
fn client_twin(mode: KissMode) -> m6p_twin::runtime::RunOptions {
    let mut opts = libcsp_peer::default_options();
    opts.kiss_links = vec![KissLink::new(mode).with_addrs(&[10])];
    opts
}

fn run_client_checks(mode: KissMode, iface: Iface) {
    let progs = programs();
    let opts = client_twin(mode);
    let epoch = opts.epoch_unix_s;
    let (_, (ok, text)) = with_twin(opts, move || {
        client(progs, &iface, 10, &client_checks(), &["--all-icd-fc"])
    });
    println!("{text}");
    libcsp_peer::assert_client_checks(ok, &text, epoch, &[]);
}

libcsp_test! {
    fn libcsp_client_over_the_kiss_pty() {
        let path = libcsp_peer::temp_path("client-tty");
        run_client_checks(KissMode::Pty(path.clone()), Iface::Kiss(path));
    }
}

libcsp_test! {
    fn libcsp_client_over_the_zmq_hub() {
        let host = "127.0.0.61";
        run_client_checks(
            KissMode::ZmqHub(host.parse().unwrap()),
            Iface::Zmq(host.to_owned()),
        );
    }
}

/// One real-time payload session at a time: each polls its payload 25 times on the
/// session's 200 ms reply timeout, and four at once beside this binary's other tests (and
/// CI's fuzz build) on two cores once lost 8 polls to late replies.
static ONE_SESSION_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The libcsp payload serves session 1 as payload 12 at `mode`/`iface` with `api`; with
/// `also` a libcsp client at 10 on the same link runs its checks during the session.
fn payload_session(mode: KissMode, iface: Iface, api: &str, also: Option<&[&str]>) {
    let _one = ONE_SESSION_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let progs = programs();
    let mut opts = readme_options();
    opts.kiss_links[0].mode = mode.clone();
    if also.is_some() {
        // The client's address on the same link.
        opts.kiss_links[0].cfg.addrs.push(10);
    }
    let link: String = opts.kiss_links[0]
        .label()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect();
    let dir = libcsp_peer::temp_path(&format!("payload-{api}-{link}"));
    std::fs::create_dir_all(&dir).unwrap();
    let sent_path = dir.join("sent.bin");
    let (report, payload, client_out) =
        run_payload_session(progs, opts, &iface, api, &sent_path, also);
    println!("{payload}");
    if let Some((ok, text)) = &client_out {
        println!("{text}");
        assert!(ok, "csp_client failed:\n{text}");
    }
    assert!(
        payload.contains("served syncs=1 polls=25 bytes=3416 refused=0"),
        "{payload}"
    );
    let sent = std::fs::read(&sent_path).unwrap();
    same_bytes("sent", &sent, "frame_data", &expected_stream(25, 200));
    common::assert_one_session_done(&report, 1, 25);
    let down = report.sessions.session_bytes(1);
    same_bytes("downlinked", &down, "sent by the libcsp payload", &sent);
    assert_eq!(report.sessions.dropped_total(12), 0);
    let _ = std::fs::remove_dir_all(&dir);
}

libcsp_test! {
    fn libcsp_payload_with_connections_serves_a_session_over_the_zmq_hub_with_a_client_beside_it() {
        let host = "127.0.0.62";
        // Beside the payload, a client on the hub pings the FC, the PC, the libcsp payload
        // (straight across the hub) and the simulated payload 13 (through the PC).
        let checks: &[&str] = &[
            "ping", "3", "64", "ping", "6", "64", "ping", "12", "64", "ping", "13", "64", "ping", "12",
            "200", "crc",
        ];
        payload_session(
            KissMode::ZmqHub(host.parse().unwrap()),
            Iface::Zmq(host.to_owned()),
            "conn",
            Some(checks),
        );
    }
}

libcsp_test! {
    fn libcsp_payload_connectionless_serves_a_session_over_the_zmq_hub() {
        let host = "127.0.0.63";
        payload_session(
            KissMode::ZmqHub(host.parse().unwrap()),
            Iface::Zmq(host.to_owned()),
            "connless",
            None,
        );
    }
}

libcsp_test! {
    fn libcsp_payload_with_connections_serves_a_session_over_the_kiss_pty() {
        let path = libcsp_peer::temp_path("payload-conn-tty");
        payload_session(KissMode::Pty(path.clone()), Iface::Kiss(path), "conn", None);
    }
}

libcsp_test! {
    fn libcsp_payload_connectionless_serves_a_session_over_the_kiss_pty() {
        let path = libcsp_peer::temp_path("payload-connless-tty");
        payload_session(
            KissMode::Pty(path.clone()),
            Iface::Kiss(path),
            "connless",
            None,
        );
    }
}

libcsp_test! {
    /// A reserved address times out, and a program on another 127.0.0.x reaches nobody:
    /// hubs side by side stay apart.
    fn a_reserved_address_times_out_and_hubs_side_by_side_stay_apart() {
        let progs = programs();
        let opts = client_twin(KissMode::ZmqHub("127.0.0.64".parse().unwrap()));
        let (_, (ok, text)) = with_twin(opts, move || {
            // A client on another hub address reaches nobody.
            let (other_ok, other) = client(
                progs,
                &Iface::Zmq("127.0.0.65".to_owned()),
                10,
                &["reserved".into(), "3".into()],
                &["--timeout", "300"],
            );
            let (ok, text) = client(
                progs,
                &Iface::Zmq("127.0.0.64".to_owned()),
                10,
                &[
                    "reserved".into(),
                    "9".into(),
                    "ping".into(),
                    "3".into(),
                    "1".into(),
                ],
                &[],
            );
            (ok && other_ok, format!("{other}{text}"))
        });
        println!("{text}");
        assert!(ok, "{text}");
    }
}

libcsp_test! {
    /// `examples/sil-pass.toml` with `examples/libcsp_payload.c` as payload 12: the session
    /// needs the pass at 13,150 s (the SETUP crosses the UHF link only then), the run is in
    /// virtual time until 13,190 s and in real time after it, and the payload's bytes reach
    /// the ground intact. The wall time is printed (docs/payload-guide.md quotes it).
    fn the_example_payload_serves_a_session_during_the_pass_at_13150s_in_seconds_of_wall_clock() {
        let progs = programs();
        let file = common::repo_root().join("examples/sil-pass.toml");
        let text = std::fs::read_to_string(&file).unwrap();
        let scenario = m6p_twin::scenario::parse("examples/sil-pass.toml", &text).unwrap();
        let compiled = m6p_twin::plan::compile(&scenario);
        let mut opts = compiled.opts;
        let host = "127.0.0.67";
        opts.kiss_links[0].mode = KissMode::ZmqHub(host.parse().unwrap());
        assert_eq!(
            opts.clock,
            bus::ClockMode::VirtualThenRealtime {
                from: csp::SimTime::from_secs(13_190),
                speed: 1.0
            }
        );
        let dir = libcsp_peer::temp_path("sil-pass");
        std::fs::create_dir_all(&dir).unwrap();
        let sent = dir.join("sent.bin");
        let sent_arg = sent.clone();
        let started = std::time::Instant::now();
        let (report, payload) = with_twin(opts, move || {
            let out = std::process::Command::new(&progs.example)
                .args(["--zmq", host, "--sent"])
                .arg(&sent_arg)
                .args(["--idle", "1.5", "--seconds", "120"])
                .output()
                .unwrap();
            String::from_utf8_lossy(&out.stdout).into_owned()
        });
        let wall = started.elapsed();
        let report = report.unwrap();
        println!("{payload}");
        println!(
            "sil-pass: {:.0} s simulated in {wall:.1?} of wall clock",
            report.sim_time.as_secs_f64()
        );
        assert!(payload.contains("served syncs=1 polls=25 bytes=3416"), "{payload}");
        let verdicts = m6p_twin::expectations::check_all(
            &compiled.expectations,
            &report,
            &opts_network(),
        );
        for v in &verdicts {
            assert!(v.passed, "{}: {}", v.name, v.observed);
        }
        let sent = std::fs::read(&sent).unwrap();
        same_bytes("sent", &sent, "frame_data", &expected_stream(25, 200));
        same_bytes(
            "downlinked",
            &report.sessions.session_bytes(1),
            "sent by the example payload",
            &sent,
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// The network of `examples/sil-pass.toml` (payload 13 only).
fn opts_network() -> m6p_twin::network::NetworkSpec {
    let text = std::fs::read_to_string(common::repo_root().join("examples/sil-pass.toml")).unwrap();
    let scenario = m6p_twin::scenario::parse("examples/sil-pass.toml", &text).unwrap();
    m6p_twin::plan::compile(&scenario).opts.network
}

libcsp_test! {
    /// The libcsp payload serves session 1 as payload 12 over the hub in a real-time run;
    /// mid-session `gs --control ... fault power-off PL12 --for 5s` cuts it (the link that
    /// holds address 12 loses power): the PC's polls go unanswered for 5 s and the downlink
    /// stops, then both resume; the session still ends done. The recording replays
    /// identically, the fault and the payload's input with it.
    fn a_live_power_cut_of_the_libcsp_payload_shows_in_its_session_and_replays() {
        use common::twin_process::{Twin, output_text, test_dir, twin};
        let _one = ONE_SESSION_AT_A_TIME
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let progs = programs();
        let host = "127.0.0.66";
        let dir = test_dir("libcsp", "live-cut");
        let scenario = common::readme_scenario()
            .replace("\"kiss-listen\"", "\"zmq-hub\"")
            .replace("\"127.0.0.1:52001\"", &format!("\"{host}\""))
            .replace("duration = \"8s\"", "duration = \"16s\"")
            .replace("/tmp/outside_payload.downlink", &dir.join("down").display().to_string());
        let file = dir.join("cut.toml");
        std::fs::write(&file, scenario).unwrap();
        let rec = dir.join("cut.mcap");
        let run = Twin::start(
            &[
                file.to_str().unwrap(),
                "--control",
                "127.0.0.1:0",
                "--record",
                rec.to_str().unwrap(),
            ],
            1,
        );
        let control = run.addrs[0].to_string();
        let payload = std::process::Command::new(&progs.payload)
            .args(["--zmq", host, "--addr", "12", "--api", "conn", "--idle", "7"])
            .args(["--seconds", "17", "--sent"])
            .arg(dir.join("sent.bin"))
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Into the session (set up at 2 s, a poll every 100 ms), then the cut.
        let now_s = || -> f64 {
            let o = twin().args(["gs", "--control", &control, "time"]).output().unwrap();
            let text = output_text(&o);
            text.trim().trim_end_matches(" s").parse().unwrap_or_else(|_| panic!("{text}"))
        };
        while now_s() < 3.0 {
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        let o = twin()
            .args(["gs", "--control", &control, "fault", "power-off", "PL12", "--for", "5s"])
            .output()
            .unwrap();
        let said = output_text(&o);
        assert!(o.status.success(), "{said}");
        assert!(said.contains("control[0]: PowerOff on PL12 (id 0): from "), "{said}");
        let (_, out, err) = run.finish();
        let served = output_text(&payload.wait_with_output().unwrap());
        println!("{out}{err}\n{served}");

        // The link's table counts what it held back. (Which frames the cut catches depends
        // on the instant the request came at, on the wall clock: that the downlink's
        // verdict fails is not asserted, the gap below is.)
        let link = out.lines().find(|l| l.contains("lost at the link")).unwrap_or_default();
        assert!(link.contains(" while unpowered") && !link.contains(" 0 while unpowered"), "{out}");
        let faults: Vec<m6p_twin::record::FaultMsg> =
            common::on(&rec, "/faults").iter().map(|m| m.decode().unwrap()).collect();
        assert_eq!(faults.len(), 2, "{faults:?}");
        let (cut, back) = (faults[0].t_ns, faults[1].t_ns);
        assert_eq!(back - cut, 5_000_000_000, "{faults:?}");
        assert!(cut >= 3_000_000_000, "{faults:?}");
        let logs: Vec<String> = common::on(&rec, "/log")
            .iter()
            .map(|m| m.json().unwrap().to_string())
            .collect();
        assert!(
            logs.iter().any(|l| l.contains("unpowered (a power-off fault)")),
            "{logs:?}"
        );
        // The downlink stops within a poll's reply time of the cut and resumes after it.
        let down: Vec<u64> = common::on(&rec, "/pc/downlink")
            .iter()
            .map(|m| m.decode::<m6p_twin::record::DownlinkMsg>().unwrap().t_ns)
            .collect();
        let during = down.iter().filter(|&&t| t > cut + 300_000_000 && t < back).count();
        assert_eq!(during, 0, "downlink during the cut: {down:?}");
        assert!(down.iter().any(|&t| t < cut), "before: {down:?}");
        assert!(down.iter().any(|&t| t > back), "after: {down:?}");
        let summary: Vec<m6p_twin::record::PcSessionSummaryMsg> =
            common::on(&rec, "/pc/sessions/summary").iter().map(|m| m.decode().unwrap()).collect();
        assert_eq!(summary.last().map(|s| (s.result.as_str(), s.packets)), Some(("done", 25)), "{summary:?}");

        let o = twin().args(["replay", rec.to_str().unwrap()]).output().unwrap();
        assert!(o.status.success(), "replay differs: {}", output_text(&o));
        let _ = std::fs::remove_dir_all(&dir);
    }
}

libcsp_test! {
    /// Software in the loop from a snapshot: the README's session with payload 12 simulated
    /// up to 15 s, saved there; a run from that snapshot with the libcsp payload taking
    /// payload 12's place on the hub (`--kiss-addr 12`) serves the session set up at 20 s,
    /// its bytes downlinked intact, and the recording of that run replays identically (from
    /// the snapshot it carries, the payload's input with it).
    fn the_libcsp_payload_takes_the_simulated_payloads_place_in_a_run_from_a_snapshot() {
        use common::twin_process::{Twin, output_text, test_dir, twin};
        let _one = ONE_SESSION_AT_A_TIME
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let progs = programs();
        let host = "127.0.0.68";
        let dir = test_dir("libcsp", "sil-from-snapshot");
        let links = "[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:52001\"\n";
        let scenario = common::readme_scenario();
        let at = scenario.find(links).unwrap();
        let end = at + scenario[at..].find("\n\n").unwrap();
        let scenario = format!("{}{}", &scenario[..at], &scenario[end + 2..])
            .replace("payloads = [13]", "payloads = [12, 13] #")
            .replace("duration = \"8s\"", "duration = \"25s\"")
            .replace("at = \"2s\"", "at = \"20s\"")
            .replace("/tmp/outside_payload.downlink", &dir.join("down").display().to_string());
        let file = dir.join("swap.toml");
        std::fs::write(&file, scenario).unwrap();
        let (file, snap, rec) = (
            file.to_str().unwrap(),
            dir.join("at-15s.snap"),
            dir.join("swap.mcap"),
        );
        let o = twin()
            .args(["run", file, "--snapshot-at", "15s", "--snapshot"])
            .arg(&snap)
            .arg("--record")
            .arg(dir.join("simulated.mcap"))
            .output()
            .unwrap();
        let text = output_text(&o);
        // The simulated payload serves the session in the run that takes the snapshot.
        assert!(text.contains("5000 B"), "{text}");
        std::fs::remove_dir_all(dir.join("down")).unwrap();

        let run = Twin::start(
            &[
                file,
                "--from-snapshot",
                snap.to_str().unwrap(),
                "--zmq-hub",
                host,
                "--kiss-addr",
                "12",
                "--record",
                rec.to_str().unwrap(),
            ],
            0,
        );
        let sent = dir.join("sent.bin");
        let payload = std::process::Command::new(&progs.payload)
            .args(["--zmq", host, "--addr", "12", "--api", "conn", "--idle", "1.5"])
            .args(["--seconds", "12", "--sent"])
            .arg(&sent)
            .output()
            .unwrap();
        let served = output_text(&payload);
        let (ok, out, err) = run.finish();
        println!("{out}{err}\n{served}");
        assert!(ok, "{out}{err}");
        assert!(err.contains("from snapshot ") && err.contains(" at 15.000000000s"), "{err}");
        assert!(served.contains("served syncs=1 polls=25 bytes=3416"), "{served}");
        assert!(out.contains("3 passed, 0 failed"), "{out}");
        let sent = std::fs::read(&sent).unwrap();
        same_bytes("sent", &sent, "frame_data", &expected_stream(25, 200));
        let down = std::fs::read(dir.join("down/session-1-run1.bin")).unwrap();
        same_bytes("downlinked", &down, "sent by the libcsp payload", &sent);

        let o = twin().args(["replay", rec.to_str().unwrap()]).output().unwrap();
        let said = output_text(&o);
        assert!(o.status.success(), "replay differs: {said}");
        assert!(said.contains("replaying from its snapshot at 15.000000000s"), "{said}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
