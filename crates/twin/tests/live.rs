//! `m6p-twin run --live`: a Foxglove WebSocket client written here (tokio-tungstenite)
//! joins a short real-time run and sees the recording's channels advertised, decoded CSP
//! packets with simulated log times, and the simulated time broadcast. Without the `live`
//! feature, `--live` says how to rebuild.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[cfg(not(feature = "live"))]
#[test]
fn live_without_the_feature_says_how_to_rebuild() {
    let out = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
        .args(["run", "--duration", "1s", "--live"])
        .current_dir(repo())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("rebuild with --features live"), "{err}");
}

#[cfg(feature = "live")]
mod with_live {
    use super::*;
    use std::io::{BufRead, BufReader};
    use std::process::{Child, Stdio};
    use std::sync::mpsc;
    use std::time::Duration;

    use futures_util::{SinkExt, StreamExt};
    use serde_json::Value;
    use tokio_tungstenite::tungstenite::Message;
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;

    fn tmp(name: &str) -> PathBuf {
        // Under the target directory (cargo clean takes it), not left behind in /tmp.
        let dir =
            PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("live-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    /// Pings of the FC every 100 ms for 3 simulated seconds, from a start epoch far from
    /// today's date, so that simulated time cannot be mistaken for the wall clock.
    const SCENARIO: &str = r#"
name = "live"
start = "2020-06-01T12:00:00Z"
duration = "3s"
[[commands]]
name = "ping-fc"
at = "100ms"
every = "100ms"
count = 28
to = "FC"
request = "ping"

# TMGEN on a port the scenario moved: the live view decodes it on the run's ports.
[fc]
ports = { telemetry = 20 }

[[commands]]
name = "tmgen"
at = "150ms"
every = "200ms"
count = 12
command = "FC.TMGEN"
port = 20
"#;

    /// Kills the child if the test fails half-way.
    struct Twin(Option<Child>);

    impl Drop for Twin {
        fn drop(&mut self) {
            if let Some(c) = self.0.as_mut() {
                let _ = c.kill();
                let _ = c.wait();
            }
        }
    }

    /// `run SCENARIO ARGS --record REC`, and its stderr's lines as they come (the twin
    /// prints the address it bound: port 0 is any free port).
    fn start(
        scenario: &std::path::Path,
        args: &[&str],
        rec: &std::path::Path,
    ) -> (Twin, mpsc::Receiver<String>) {
        let mut twin = Twin(Some(
            Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
                .arg("run")
                .arg(scenario)
                .args(args)
                .arg("--record")
                .arg(rec)
                .current_dir(repo())
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap(),
        ));
        let (tx, lines) = mpsc::channel();
        let stderr = twin.0.as_mut().unwrap().stderr.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        (twin, lines)
    }

    #[test]
    fn a_foxglove_client_sees_the_channels_packets_and_simulated_time() {
        let scenario = tmp("live.toml");
        std::fs::write(&scenario, SCENARIO).unwrap();
        let rec = tmp("live.mcap");
        let (mut twin, lines) = start(&scenario, &["--live", "127.0.0.1:0"], &rec);
        let mut seen = Vec::new();
        let addr = loop {
            let l = lines
                .recv_timeout(Duration::from_secs(30))
                .unwrap_or_else(|e| panic!("no live view address ({e}); stderr: {seen:?}"));
            if let Some(rest) = l.strip_prefix("live view: ws://") {
                break rest.split_whitespace().next().unwrap().to_owned();
            }
            seen.push(l);
        };
        assert!(
            seen.iter().any(|l| l.contains("running in real time")),
            "{seen:?}"
        );

        let start_ns = m6p_twin::timefmt::parse_utc("2020-06-01T12:00:00Z").unwrap() as u64;
        let end_ns = start_ns + 3_000_000_000;
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        // Two clients at once: one offers the protocol as the `foxglove` SDK names it, one
        // under its older name, as Foxglove Studio 1.x, Lichtblick and
        // `@foxglove/ws-protocol` do.
        let (sdk, legacy) = rt
            .block_on(async {
                tokio::time::timeout(Duration::from_secs(20), async {
                    tokio::join!(
                        client(&addr, "foxglove.sdk.v1", start_ns, end_ns),
                        client(&addr, "foxglove.websocket.v1", start_ns, end_ns)
                    )
                })
                .await
            })
            .expect("both clients saw packets and times within 20 s");
        for (packets, times) in [sdk, legacy] {
            assert!(!packets.is_empty() && !times.is_empty());
        }

        // The run ends on its own after 3 simulated (= wall) seconds, recording too.
        let (done_tx, done) = mpsc::channel();
        let child = twin.0.take().unwrap();
        std::thread::spawn(move || {
            let out = child.wait_with_output();
            let _ = done_tx.send(out);
        });
        let out = done
            .recv_timeout(Duration::from_secs(30))
            .expect("the run ended")
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr: Vec<String> = lines.try_iter().collect();
        assert_eq!(out.status.code(), Some(0), "{stdout}\n{stderr:#?}");
        assert!(stdout.contains("recorded"), "{stdout}");
        let _ = std::fs::remove_file(&rec);
        let _ = std::fs::remove_file(&scenario);
    }

    /// A Foxglove client publishes a control request on `/control` (JSON, pretty-printed
    /// as a panel may send it): the run takes it as its control channel's (connection 0),
    /// the fault is on `/faults` with its origin, the request and its reply on `/control`,
    /// and `replay` of the recording is identical.
    #[test]
    fn a_foxglove_client_publishing_on_control_cuts_a_payloads_power() {
        let scenario = tmp("live-control.toml");
        std::fs::write(&scenario, "name = \"live-control\"\nduration = \"4s\"\n").unwrap();
        let rec = tmp("live-control.mcap");
        let args = [
            "--live",
            "127.0.0.1:0",
            "--control",
            "127.0.0.1:0",
            "--no-checks",
        ];
        let (mut twin, lines) = start(&scenario, &args, &rec);
        let addr = loop {
            let l = lines.recv_timeout(Duration::from_secs(30)).unwrap();
            if let Some(rest) = l.strip_prefix("live view: ws://") {
                break rest.split_whitespace().next().unwrap().to_owned();
            }
        };
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let request = || {
                let mut req = format!("ws://{addr}").into_client_request().unwrap();
                req.headers_mut()
                    .insert("sec-websocket-protocol", "foxglove.sdk.v1".parse().unwrap());
                req
            };
            // A page of another site, whose browser says so, is turned away.
            let mut evil = request();
            evil.headers_mut()
                .insert("origin", "https://evil.example".parse().unwrap());
            let refused = tokio_tungstenite::connect_async(evil).await;
            assert!(refused.is_err(), "a page of another site joined");
            let (mut ws, _) = tokio_tungstenite::connect_async(request()).await.unwrap();
            let info = next_json(&mut ws).await;
            assert_eq!(info["op"], "serverInfo", "{info}");
            let caps = info["capabilities"].as_array().unwrap();
            assert!(caps.iter().any(|c| c == "clientPublish"), "{info}");
            assert!(
                info["supportedEncodings"].as_array().unwrap().iter().any(|e| e == "json"),
                "{info}"
            );
            let advertise = serde_json::json!({
                "op": "advertise",
                "channels": [
                    {"id": 1, "topic": "/control", "encoding": "json", "schemaName": "m6p.ControlRequest"},
                    {"id": 2, "topic": "/elsewhere", "encoding": "json", "schemaName": "x"}
                ]
            });
            ws.send(Message::text(advertise.to_string())).await.unwrap();
            let publish = |chan: u32, payload: &str| {
                let mut m = vec![0x01];
                m.extend(chan.to_le_bytes());
                m.extend(payload.as_bytes());
                Message::binary(m)
            };
            let cut = "{\n  \"op\": \"fault\",\n  \"kind\": \"power-off\",\n  \"target\": \"PL12\",\n  \"for\": \"1s\"\n}";
            ws.send(publish(2, "{\"op\":\"time\"}")).await.unwrap();
            ws.send(publish(1, "not json")).await.unwrap();
            ws.send(publish(1, cut)).await.unwrap();
            // The connection stays open until the run ends.
            while ws.next().await.is_some_and(|m| m.is_ok()) {}
        });
        let (done_tx, done) = mpsc::channel();
        let child = twin.0.take().unwrap();
        std::thread::spawn(move || {
            let _ = done_tx.send(child.wait_with_output());
        });
        let out = done.recv_timeout(Duration::from_secs(30)).unwrap().unwrap();
        let said: Vec<String> = lines.try_iter().collect();
        assert_eq!(out.status.code(), Some(0), "{said:#?}");
        assert!(
            said.iter()
                .any(|l| l.contains("1 control request(s) from its clients taken, 2 refused")),
            "{said:#?}"
        );

        let on = |topic: &str| -> Vec<m6p_twin::recording::RecordedMessage> {
            m6p_twin::recording::messages(&rec)
                .unwrap()
                .map(Result::unwrap)
                .filter(|m| &*m.topic == topic)
                .collect()
        };
        let control: Vec<m6p_twin::record::ControlMsg> =
            on("/control").iter().map(|m| m.decode().unwrap()).collect();
        assert_eq!(control.len(), 1, "{control:?}");
        assert_eq!(control[0].conn, 0);
        assert_eq!(
            control[0].request,
            r#"{"for":"1s","kind":"power-off","op":"fault","target":"PL12"}"#
        );
        assert!(control[0].reply.contains(r#""ok":true"#), "{control:?}");
        let faults: Vec<m6p_twin::record::FaultMsg> =
            on("/faults").iter().map(|m| m.decode().unwrap()).collect();
        assert_eq!(faults.len(), 2, "{faults:?}");
        assert!(
            faults[0].what.starts_with("control[0]: PowerOff on PL12"),
            "{faults:?}"
        );
        assert_eq!(faults[1].t_ns - faults[0].t_ns, 1_000_000_000, "{faults:?}");

        let o = Command::new(env!("CARGO_BIN_EXE_m6p-twin"))
            .arg("replay")
            .arg(&rec)
            .current_dir(repo())
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
        let _ = std::fs::remove_file(&rec);
        let _ = std::fs::remove_file(&scenario);
    }

    /// Join the server offering `subprotocol`, check the advertisement, subscribe to
    /// `/csp/packets`, and return the first few CSP packet messages (log time, JSON) and time
    /// broadcasts.
    async fn client(
        addr: &str,
        subprotocol: &str,
        start_ns: u64,
        end_ns: u64,
    ) -> (Vec<(u64, Value)>, Vec<u64>) {
        let mut req = format!("ws://{addr}").into_client_request().unwrap();
        req.headers_mut()
            .insert("sec-websocket-protocol", subprotocol.parse().unwrap());
        let (mut ws, resp) = tokio_tungstenite::connect_async(req)
            .await
            .unwrap_or_else(|e| panic!("{subprotocol}: {e}"));
        assert_eq!(
            resp.headers()["sec-websocket-protocol"],
            subprotocol,
            "negotiated subprotocol"
        );

        // serverInfo first, with the time capability.
        let info = next_json(&mut ws).await;
        assert_eq!(info["op"], "serverInfo", "{info}");
        let caps = info["capabilities"].as_array().unwrap();
        assert!(caps.iter().any(|c| c == "time"), "{info}");

        // Then the channels, as the recording has them.
        let mut channels: Vec<Value> = Vec::new();
        while !["/csp/packets", "/can/main/frames", "/log"]
            .iter()
            .all(|t| channels.iter().any(|c| c["topic"] == *t))
        {
            let m = next_json(&mut ws).await;
            if m["op"] == "advertise" {
                channels.extend(m["channels"].as_array().unwrap().iter().cloned());
            }
        }
        let topics: Vec<&str> = channels
            .iter()
            .map(|c| c["topic"].as_str().unwrap())
            .collect();
        for t in [
            "/can/main/frames",
            "/can/payload/frames",
            "/ground/packets",
            "/csp/packets",
            "/log",
            "/faults",
            "/commands",
            "/expectations",
        ] {
            assert!(topics.contains(&t), "{t} missing from {topics:?}");
        }
        // Protobuf, as the recording: the schema (base64, the protocol's form of a binary
        // schema) is the recording's schema of that channel kind.
        for c in &channels {
            assert_eq!(c["encoding"], "protobuf", "{c}");
            assert_eq!(c["schemaEncoding"], "protobuf", "{c}");
            let kind = m6p_twin::record::CHANNEL_KINDS
                .iter()
                .find(|k| k.schema_name() == c["schemaName"])
                .unwrap_or_else(|| panic!("unknown schema in {c}"));
            let schema = base64_decode(c["schema"].as_str().unwrap());
            assert_eq!(schema, kind.schema_data().unwrap(), "{c}");
        }
        let by_topic = |t: &str| channels.iter().find(|c| c["topic"] == t).unwrap();
        assert_eq!(by_topic("/csp/packets")["schemaName"], "m6p.CspPacket");
        assert_eq!(by_topic("/log")["schemaName"], "foxglove.Log");
        assert_eq!(by_topic("/can/main/frames")["schemaName"], "m6p.CanFrames");
        assert_eq!(by_topic("/can/main/frames")["metadata"]["bus"], "main");

        let csp = by_topic("/csp/packets")["id"].as_u64().unwrap();
        let csp_schema: std::sync::Arc<[u8]> =
            base64_decode(by_topic("/csp/packets")["schema"].as_str().unwrap()).into();
        let sub = serde_json::json!({
            "op": "subscribe",
            "subscriptions": [{"id": 7, "channelId": csp}],
        });
        ws.send(Message::text(sub.to_string())).await.unwrap();

        let mut packets = Vec::new();
        let mut times = Vec::new();
        let tmgen = |packets: &Vec<(u64, Value)>| {
            packets
                .iter()
                .any(|(_, p)| p["icd"] == "FC.TMGEN" && p["icd_kind"] == "reply")
        };
        while packets.len() < 5 || times.len() < 3 || !tmgen(&packets) {
            let Some(m) = ws.next().await else {
                panic!("the server closed the connection early");
            };
            let Message::Binary(b) = m.unwrap() else {
                continue;
            };
            match b[0] {
                // messageData: opcode, subscription id u32 LE, log time u64 LE, payload.
                0x01 => {
                    let sub_id = u32::from_le_bytes(b[1..5].try_into().unwrap());
                    let log_time = u64::from_le_bytes(b[5..13].try_into().unwrap());
                    assert_eq!(sub_id, 7);
                    let p: Value = m6p_twin::protobuf::decode(
                        "m6p.CspPacket",
                        "protobuf",
                        &csp_schema,
                        &b[13..],
                    )
                    .unwrap();
                    assert!(p["src"].is_u64() && p["dst"].is_u64(), "{p}");
                    // The log time is simulated: start epoch + the packet's t_ns.
                    assert_eq!(log_time, start_ns + p["t_ns"].as_u64().unwrap(), "{p}");
                    assert!((start_ns..=end_ns).contains(&log_time), "{log_time}");
                    packets.push((log_time, p));
                }
                // time: opcode, timestamp u64 LE.
                0x02 => {
                    let t = u64::from_le_bytes(b[1..9].try_into().unwrap());
                    assert!((start_ns..=end_ns).contains(&t), "time {t} outside the run");
                    if let Some(&last) = times.last() {
                        assert!(t >= last, "time went back: {last} then {t}");
                    }
                    times.push(t);
                }
                op => panic!("unexpected binary opcode {op}"),
            }
        }
        // The FC answers pings: packets both ways.
        assert!(packets.iter().any(|(_, p)| p["dst"] == 3), "{packets:?}");
        assert!(packets.iter().any(|(_, p)| p["src"] == 3), "{packets:?}");
        let _ = ws.close(None).await;
        (packets, times)
    }

    async fn next_json<S>(ws: &mut S) -> Value
    where
        S: StreamExt<Item = Result<Message, tokio_tungstenite::tungstenite::Error>> + Unpin,
    {
        loop {
            match ws.next().await.expect("connection open").unwrap() {
                Message::Text(t) => return serde_json::from_str(t.as_str()).unwrap(),
                Message::Binary(_) => continue, // a time broadcast before the advertisement
                _ => continue,
            }
        }
    }
}

/// Standard base64 (RFC 4648, with padding), as the Foxglove WebSocket protocol sends a
/// binary schema.
#[cfg(feature = "live")]
fn base64_decode(text: &str) -> Vec<u8> {
    const ALPHABET: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = Vec::new();
    let (mut acc, mut bits) = (0u32, 0);
    for c in text.bytes().filter(|&c| c != b'=') {
        let v = ALPHABET.iter().position(|&a| a == c).expect("base64") as u32;
        acc = acc << 6 | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    out
}
