//! Golden vectors computed by libcsp v1.4's own code (`tests/data/libcsp-1.4/`).
//!
//! One test per file; each loops over every case, collects all mismatches with the case
//! name and fails listing them, so one run shows every divergence from libcsp.
#![allow(clippy::unwrap_used)]

use std::fmt::Write as _;

use m6p_csp::cfp::{self, CanFrame, CfpId, FrameType, Reassembler};
use m6p_csp::header::Header;
use m6p_csp::kiss::{self, Decoder, DecoderConfig, KissEvent};
use m6p_csp::{Packet, Priority, SimTime, crc32};
use serde_json::Value;

const DATA_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/libcsp-1.4");

/// Load a vector file and return its cases, checking the count the README states.
fn cases(file: &str, expected: usize) -> Vec<Value> {
    let path = format!("{DATA_DIR}/{file}");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let v: Value = serde_json::from_str(&text).unwrap();
    let cases = v["cases"].as_array().unwrap().clone();
    assert_eq!(
        cases.len(),
        expected,
        "{file}: case count differs from the README"
    );
    cases
}

fn hex_bytes(v: &Value) -> Vec<u8> {
    hex::decode(v.as_str().unwrap()).unwrap()
}

fn hex_u32(v: &Value) -> u32 {
    let s = v.as_str().unwrap();
    u32::from_str_radix(s.trim_start_matches("0x"), 16).unwrap()
}

fn num(v: &Value) -> u64 {
    v.as_u64().unwrap()
}

fn header_of(f: &Value) -> Header {
    Header {
        prio: Priority::from_bits(num(&f["prio"]) as u8),
        src: num(&f["src"]) as u8,
        dst: num(&f["dst"]) as u8,
        dport: num(&f["dport"]) as u8,
        sport: num(&f["sport"]) as u8,
        flags: num(&f["flags"]) as u8,
    }
}

fn name_of(case: &Value, i: usize) -> String {
    match case["name"].as_str() {
        Some(n) => format!("#{i} {n}"),
        None => format!("#{i} {}", case["fields"]),
    }
}

/// Packets as `header | data` hex, short enough to read in a failure list.
fn show(packets: &[Packet]) -> String {
    let v: Vec<String> = packets.iter().map(|p| hex::encode(p.to_bytes())).collect();
    format!("[{}]", v.join(", "))
}

/// Fail with every collected mismatch.
fn report(file: &str, total: usize, failures: Vec<String>) {
    if !failures.is_empty() {
        let mut msg = format!(
            "{file}: {} of {total} cases differ from libcsp v1.4:\n",
            failures.len()
        );
        for f in &failures {
            let _ = writeln!(msg, "  - {f}");
        }
        panic!("{msg}");
    }
}

#[test]
fn header_vectors() {
    let cases = cases("header.json", 24);
    let mut failures = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let name = name_of(c, i);
        let h = header_of(&c["fields"]);
        let word = hex_u32(&c["word"]);
        let wire = hex_bytes(&c["wire"]);
        if h.validate().is_err() {
            failures.push(format!("{name}: fields do not validate"));
        }
        if h.to_word() != word {
            failures.push(format!(
                "{name}: word {:#010x}, libcsp {word:#010x}",
                h.to_word()
            ));
        }
        if h.to_bytes().as_slice() != wire.as_slice() {
            failures.push(format!(
                "{name}: wire {}, libcsp {}",
                hex::encode(h.to_bytes()),
                hex::encode(&wire)
            ));
        }
        match Header::parse(&wire) {
            Ok(p) if p == h => {}
            other => failures.push(format!("{name}: parse gave {other:?}")),
        }
        if Header::from_word(word) != h {
            failures.push(format!(
                "{name}: from_word gave {:?}",
                Header::from_word(word)
            ));
        }
    }
    report("header.json", cases.len(), failures);
}

#[test]
fn crc32_vectors() {
    let cases = cases("crc32.json", 12);
    let mut failures = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let name = name_of(c, i);
        let input = hex_bytes(&c["input"]);
        let want = hex_u32(&c["crc"]);
        let appended = hex_bytes(&c["appended"]);
        if input.len() as u64 != num(&c["length"]) {
            failures.push(format!("{name}: length field disagrees with input"));
        }
        let got = crc32::crc32c(&input);
        if got != want {
            failures.push(format!("{name}: crc {got:#010x}, libcsp {want:#010x}"));
        }
        let mut buf = input.clone();
        crc32::append(&mut buf);
        if buf.get(input.len()..) != Some(appended.as_slice()) {
            failures.push(format!(
                "{name}: appended {}, libcsp {}",
                hex::encode(&buf[input.len()..]),
                hex::encode(&appended)
            ));
        }
        if !crc32::verify_and_strip(&mut buf) || buf != input {
            failures.push(format!("{name}: verify_and_strip failed on its own output"));
        }
    }
    report("crc32.json", cases.len(), failures);
}

/// Decode `wire` in one go and return the packets and the decoder.
fn decode(config: DecoderConfig, wire: &[u8]) -> (Vec<Packet>, Decoder) {
    let mut d = Decoder::new(config);
    let mut events = Vec::new();
    d.push(wire, &mut events);
    let packets = events
        .into_iter()
        .filter_map(|e| match e {
            KissEvent::Packet(p) => Some(p),
            KissEvent::Dropped(_) => None,
        })
        .collect();
    (packets, d)
}

#[test]
fn kiss_encode_vectors() {
    let cases = cases("kiss_encode.json", 13);
    let v14 = DecoderConfig {
        libcsp14_rx_limit: true,
    };
    let mut failures = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let name = name_of(c, i);
        let mut data = hex_bytes(&c["data"]);
        // The CSP_FCRC32 case: csp_send_direct appended the inner CRC before the driver.
        if c["inner_crc"].as_bool().unwrap() {
            crc32::append(&mut data);
        }
        let packet = Packet::new(header_of(&c["fields"]), data);
        let wire = hex_bytes(&c["wire"]);
        let mut got = Vec::new();
        kiss::encode(&packet, &mut got);
        if got != wire {
            failures.push(format!(
                "{name}: wire {}, libcsp {}",
                hex::encode(&got),
                hex::encode(&wire)
            ));
        }
        // The unescaped body: header | data | KISS CRC.
        let mut content = packet.to_bytes();
        content.extend_from_slice(&crc32::crc32c(&packet.data).to_be_bytes());
        if content != hex_bytes(&c["content"]) {
            failures.push(format!("{name}: content {}", hex::encode(&content)));
        }
        let accepts = c["libcsp_rx_accepts"].as_bool().unwrap();
        let (packets, d) = decode(v14, &wire);
        let ok = packets == [packet.clone()];
        if ok != accepts {
            failures.push(format!(
                "{name}: v1.4-limit decoder accepted={ok} ({}, {:?}), libcsp accepted={accepts}",
                show(&packets),
                d.stats()
            ));
        }
        if !accepts && d.stats().oversize != 1 {
            failures.push(format!(
                "{name}: rejection not counted as oversize: {:?}",
                d.stats()
            ));
        }
        // The twin's default accepts the full MTU, the 256-byte payload included.
        let (packets, d) = decode(DecoderConfig::default(), &wire);
        if packets != [packet] || d.stats().rx_error != 0 {
            failures.push(format!(
                "{name}: default decoder did not accept it: {:?}",
                d.stats()
            ));
        }
    }
    report("kiss_encode.json", cases.len(), failures);
}

#[test]
fn kiss_decode_vectors() {
    let cases = cases("kiss_decode.json", 11);
    let mut failures = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let name = name_of(c, i);
        let input = hex_bytes(&c["input"]);
        let want: Vec<Packet> = c["packets"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| Packet::new(header_of(&p["fields"]), hex_bytes(&p["data"])))
            .collect();
        let (got, d) = decode(
            DecoderConfig {
                libcsp14_rx_limit: true,
            },
            &input,
        );
        let st = d.stats();
        if got != want {
            failures.push(format!(
                "{name}: packets {}, libcsp {}",
                show(&got),
                show(&want)
            ));
        }
        if st.rx_error != num(&c["rx_error"]) {
            failures.push(format!(
                "{name}: rx_error {}, libcsp {}",
                st.rx_error, c["rx_error"]
            ));
        }
        if st.discarded_bytes != num(&c["discarded_bytes"]) {
            failures.push(format!(
                "{name}: discarded_bytes {}, libcsp {}",
                st.discarded_bytes, c["discarded_bytes"]
            ));
        }
        if st.frames_ok != want.len() as u64 {
            failures.push(format!("{name}: frames_ok {}", st.frames_ok));
        }
        // Byte-at-a-time feeding must give the same result as one chunk.
        let mut d1 = Decoder::new(DecoderConfig {
            libcsp14_rx_limit: true,
        });
        let got1: Vec<Packet> = input
            .iter()
            .filter_map(|&b| match d1.push_byte(b) {
                Some(KissEvent::Packet(p)) => Some(p),
                _ => None,
            })
            .collect();
        if got1 != got || d1.stats() != st {
            failures.push(format!("{name}: byte-wise feeding differs"));
        }
    }
    report("kiss_decode.json", cases.len(), failures);
}

#[test]
fn cfp_vectors() {
    let cases = cases("cfp.json", 10);
    let mut failures = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let name = name_of(c, i);
        let header = header_of(&c["fields"]);
        let data = hex_bytes(&c["data"]);
        if data.len() as u64 != num(&c["length"]) {
            failures.push(format!("{name}: length field disagrees with data"));
        }
        if header.to_bytes().as_slice() != hex_bytes(&c["header_wire"]).as_slice() {
            failures.push(format!(
                "{name}: header_wire {}",
                hex::encode(header.to_bytes())
            ));
        }
        let packet = Packet::new(header, data);
        let ident = num(&c["cfp_ident"]) as u16;
        let mac = match &c["route_via_mac"] {
            Value::Null => header.dst,
            v => num(v) as u8,
        };
        let mut got = Vec::new();
        if let Err(e) = cfp::fragment_with_ident(&packet, mac, ident, &mut got) {
            failures.push(format!("{name}: fragment failed: {e}"));
            continue;
        }
        let want = c["frames"].as_array().unwrap();
        if got.len() != want.len() {
            failures.push(format!(
                "{name}: {} frames, libcsp {}",
                got.len(),
                want.len()
            ));
        }
        for (k, (g, w)) in got.iter().zip(want).enumerate() {
            let id = hex_u32(&w["can_id"]);
            let wdata = hex_bytes(&w["data"]);
            if g.id != id {
                failures.push(format!(
                    "{name}: frame {k} id {:#010x}, libcsp {id:#010x}",
                    g.id
                ));
            }
            if u64::from(g.dlc) != num(&w["dlc"]) || g.data() != wdata.as_slice() {
                failures.push(format!(
                    "{name}: frame {k} dlc {} data {}, libcsp dlc {} data {}",
                    g.dlc,
                    hex::encode(g.data()),
                    w["dlc"],
                    hex::encode(&wdata)
                ));
            }
            let f = &w["cfp"];
            let want_id = CfpId {
                src: num(&f["src"]) as u8,
                dst: num(&f["dst"]) as u8,
                kind: match f["type"].as_str().unwrap() {
                    "BEGIN" => FrameType::Begin,
                    _ => FrameType::More,
                },
                remain: num(&f["remain"]) as u8,
                ident: num(&f["ident"]) as u16,
            };
            if CfpId::from_can_id(id) != want_id || want_id.to_can_id() != id {
                failures.push(format!(
                    "{name}: frame {k} CfpId {:?}, libcsp {want_id:?}",
                    CfpId::from_can_id(id)
                ));
            }
        }
        // Reassemble libcsp's frames (not ours), as csp_can_process_frame did.
        let mut r = Reassembler::default();
        let mut results = Vec::new();
        for w in want {
            let frame = CanFrame::new(hex_u32(&w["can_id"]), &hex_bytes(&w["data"])).unwrap();
            if let Some(res) = r.handle(&frame, SimTime::ZERO) {
                results.push(res);
            }
        }
        let ok = results == [Ok(packet)];
        if ok != c["libcsp_reassembly_ok"].as_bool().unwrap() {
            failures.push(format!("{name}: reassembly gave {results:?}"));
        }
        if r.partial_count() != 0 {
            failures.push(format!("{name}: reassembler left a partial packet"));
        }
    }
    report("cfp.json", cases.len(), failures);
}
