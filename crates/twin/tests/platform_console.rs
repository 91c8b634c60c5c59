//! A node's text console and its platform port on a running twin, checked by an
//! independent Python client written from docs/protocol.md (`tests/console_decode.py`):
//! the FC's console over TCP (`--uart FC=ADDR`) beside a KISS/TCP link as ground node 17.
//! `help` lists every command; the console's telemetry is the CSP telemetry of the same
//! instant; a parameter set on the console reads back over CSP and survives a reboot once
//! saved; the self-test agrees on both. The default scenario's platform, real time, ~10 s.
#![allow(clippy::unwrap_used)]

use m6p_twin::runtime::{UartAt, UartLink};

#[path = "common/decoder.rs"]
mod decoder;

#[test]
fn python_client_finds_the_console_and_the_platform_port_agree() {
    let mut opts = decoder::default_scenario_options(16);
    opts.uart = vec![UartLink {
        node: "FC".to_owned(),
        at: UartAt::Tcp("127.0.0.1:0".parse().unwrap()),
    }];
    let (text, report) = decoder::run_decoder(opts, "console_decode.py", &[], 15);
    let fc = report.nodes.iter().find(|n| n.name == "FC").unwrap();
    assert_eq!(fc.counters.reboots, 1, "{:?}", fc.counters);
    // PLIST, PINFO for each parameter, PGETs, the refused PSET, SELFTEST, PDEFAULTS.
    assert!(fc.counters.platform_requests >= 20, "{:?}", fc.counters);
    assert_eq!(fc.counters.platform_refused, 1, "{:?}\n{text}", fc.counters);
}

/// The EPS's console on a pseudo-terminal, as `screen` would open it: the banner and prompt,
/// a line ended by CR alone (a terminal in raw mode), a line too long, and the path gone
/// at the end.
#[cfg(unix)]
#[test]
fn a_console_on_a_pty_answers_lines_ended_by_cr() {
    use std::io::{Read, Write};
    let path = std::env::temp_dir().join(format!("m6p-eps-uart-{}", std::process::id()));
    let mut opts = m6p_twin::runtime::RunOptions::new(
        m6p_twin::network::NetworkSpec::default_m6p(),
        std::time::Duration::from_secs(4),
    );
    opts.clock = bus::ClockMode::Realtime { speed: 1.0 };
    opts.uart = vec![UartLink {
        node: "EPS".to_owned(),
        at: UartAt::Pty(path.clone()),
    }];
    let rt = m6p_twin::runtime::build_runtime().unwrap();
    let p = path.clone();
    let text = rt.block_on(async move {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let twin = tokio::spawn(m6p_twin::report::run(opts, Some(tx)));
        rx.await.unwrap();
        let client = decoder::outside::on_thread(move || {
            let mut tty = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .open(&p)
                .unwrap();
            let mut seen = String::new();
            let until_prompts = |tty: &mut std::fs::File, n: usize, seen: &mut String| {
                let mut buf = [0u8; 1024];
                while seen.matches("eps> ").count() < n {
                    let k = tty.read(&mut buf).unwrap();
                    seen.push_str(&String::from_utf8_lossy(&buf[..k]));
                }
            };
            until_prompts(&mut tty, 1, &mut seen);
            tty.write_all(b"uptime\r").unwrap();
            until_prompts(&mut tty, 2, &mut seen);
            tty.write_all(b"tm\r\n").unwrap();
            until_prompts(&mut tty, 3, &mut seen);
            tty.write_all(&[b'x'; 300]).unwrap();
            tty.write_all(b"\r").unwrap();
            until_prompts(&mut tty, 4, &mut seen);
            seen
        });
        let seen = client.await.unwrap();
        twin.await.unwrap().unwrap();
        seen
    });
    assert!(text.starts_with("M6P twin: EPS console (CSP 4)"), "{text}");
    assert!(text.contains("EPS (CSP 4) uptime "), "{text}");
    // TMEPS field by field, CR LF ended (a CR LF line is one line, not two).
    assert!(text.contains("eps> battery_v "), "{text}");
    assert!(text.contains("\r\nsoc "), "{text}");
    assert_eq!(text.matches("eps> ").count(), 4, "{text}");
    assert!(
        text.contains("error: line longer than 256 characters\r\neps> "),
        "{text}"
    );
    assert!(!path.exists(), "the link goes at the end");
}
