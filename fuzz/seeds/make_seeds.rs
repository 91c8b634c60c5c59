//! Writes the seed corpora `fuzz/corpus/<target>/` from real traffic and the project's own
//! references. Run through `fuzz/seeds/make_seeds.sh`, which first makes the recordings
//! and CAN exports this reads; every seed's file name says where it comes from:
//!
//! | prefix | source |
//! |---|---|
//! | `vec-header-*` | `shared/vectors/libcsp-1.4/header.json` (libcsp 1.4's own header words) |
//! | `vec-kiss-enc-*` | `kiss_encode.json`: the exact serial bytes of libcsp's `csp_kiss_tx` |
//! | `vec-kiss-dec-*` | `kiss_decode.json`: byte streams fed to libcsp's `csp_kiss_rx` |
//! | `vec-cfp-*` | `cfp.json`: CAN frames of libcsp's `csp_can_tx` |
//! | `can-<rec>-*` | CAN frames of a twin recording's `/can/main/frames`, `/can/payload/frames` (`m6p-twin inspect --csv`) |
//! | `icd-*` | well-formed requests of the ICD command tables (FC: ICD 4.2 and the ICD 1.5 script examples) |
//! | `svc-*` | CSP service requests (ping, uptime, ...), including a node pinging itself service port to service port |
//! | `tle-*` | the default scenario's TLE and `shared/reference/sgp4_vallado_tles.csv` (Vallado's verification set) |
//! | `scenario-*` | `scenarios/*.toml` |
//! | `rec-*` | small twin recordings (MCAP), whole and cut short |
//! | `link-*` | one outside connection's bytes: KISS frames and hub messages of packets a program sends (claims, impostors, a reserved address, a configured link, a payload filling its CAN queue), an empty hub message; `link-vec-*`: `kiss_decode.json`'s streams on a link |
//!
//! Usage: `make_seeds --out DIR [--vectors DIR] [--reference DIR] [--scenarios DIR]
//! [--can-main CSV]... [--can-payload CSV]... [--recording MCAP]... [--only TARGET]...`
//! (`--only`: write those targets' corpora alone, leaving the others as they are).
//!
//! Every node-target seed is checked by decoding it back into the same operations.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use csp::cfp::CfpId;
use csp::{Header, Priority};
use m6p_twin_fuzz::cfp_input::{CfpInput, CfpOp};
use m6p_twin_fuzz::enc::{self, Enc};
use m6p_twin_fuzz::harness::{
    self, AddrSel, Ctl, FlagSel, Mangle, NodeKind, Op, PacketSpec, PortSel, Step, Via,
};
use m6p_twin_fuzz::kiss_input;
use m6p_twin_fuzz::nodes::{
    self, CommCmd, EcuCmd, EpsCmd, FcCmd, FcSetup, PayloadCmd, PayloadSetup, PcCmd, ScriptGen,
    TleGen,
};
use serde_json::Value;

type Res<T> = Result<T, String>;

struct Args {
    out: PathBuf,
    vectors: PathBuf,
    reference: PathBuf,
    scenarios: PathBuf,
    can_main: Vec<PathBuf>,
    can_payload: Vec<PathBuf>,
    recordings: Vec<PathBuf>,
    only: Vec<String>,
}

fn args() -> Res<Args> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut a = Args {
        out: root.join("corpus"),
        vectors: root.join("../../shared/vectors/libcsp-1.4"),
        reference: root.join("../../shared/reference"),
        scenarios: root.join("../scenarios"),
        can_main: Vec::new(),
        can_payload: Vec::new(),
        recordings: Vec::new(),
        only: Vec::new(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let v = PathBuf::from(it.next().ok_or(format!("{k} needs a value"))?);
        match k.as_str() {
            "--out" => a.out = v,
            "--vectors" => a.vectors = v,
            "--reference" => a.reference = v,
            "--scenarios" => a.scenarios = v,
            "--can-main" => a.can_main.push(v),
            "--can-payload" => a.can_payload.push(v),
            "--recording" => a.recordings.push(v),
            "--only" => a.only.push(v.display().to_string()),
            _ => return Err(format!("unknown argument {k}")),
        }
    }
    Ok(a)
}

/// The seeds of every target, by target.
#[derive(Default)]
struct Corpus(BTreeMap<&'static str, BTreeMap<String, Vec<u8>>>);

impl Corpus {
    fn add(&mut self, target: &'static str, name: impl Into<String>, bytes: Vec<u8>) {
        self.0.entry(target).or_default().insert(name.into(), bytes);
    }

    fn write(&self, out: &Path, only: &[String]) -> Res<()> {
        for (target, seeds) in &self.0 {
            if !only.is_empty() && !only.iter().any(|o| o == target) {
                continue;
            }
            let dir = out.join(target);
            if dir.exists() {
                std::fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
            }
            std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
            let mut total = 0;
            for (name, bytes) in seeds {
                std::fs::write(dir.join(name), bytes).map_err(|e| format!("{name}: {e}"))?;
                total += bytes.len();
            }
            println!("{target:16} {:4} seeds {:8} bytes", seeds.len(), total);
        }
        Ok(())
    }
}

fn read_json(path: &Path) -> Res<Value> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

fn cases(v: &Value) -> &[Value] {
    v["cases"].as_array().map_or(&[], Vec::as_slice)
}

fn hex(s: &str) -> Res<Vec<u8>> {
    let s = s.trim();
    if s.len() % 2 != 0 {
        return Err(format!("odd hex {s:?}"));
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).map_err(|e| format!("{s:?}: {e}")))
        .collect()
}

fn header_of(fields: &Value) -> Header {
    let f = |k: &str| fields[k].as_u64().unwrap_or(0) as u8;
    Header {
        prio: Priority::from_bits(f("prio")),
        src: f("src"),
        dst: f("dst"),
        dport: f("dport"),
        sport: f("sport"),
        flags: f("flags"),
    }
}

fn slug(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_lowercase());
        } else if !out.ends_with('-') {
            out.push('-');
        }
    }
    out.trim_matches('-').chars().take(48).collect()
}

// ---------------------------------------------------------------------------------------
// Golden vectors: header, KISS, CFP
// ---------------------------------------------------------------------------------------

fn vectors(c: &mut Corpus, dir: &Path) -> Res<()> {
    let header = read_json(&dir.join("header.json"))?;
    for (i, case) in cases(&header).iter().enumerate() {
        let wire = hex(case["wire"].as_str().unwrap_or_default())?;
        c.add("csp_header", format!("vec-header-{i:02}"), wire);
    }
    let kenc = read_json(&dir.join("kiss_encode.json"))?;
    for (i, case) in cases(&kenc).iter().enumerate() {
        let name = slug(case["name"].as_str().unwrap_or_default());
        let wire = hex(case["wire"].as_str().unwrap_or_default())?;
        let content = hex(case["content"].as_str().unwrap_or_default())?;
        // header + data (+ inner CRC), the KISS CRC stripped: the packet as the router sees it.
        let packet = content[..content.len().saturating_sub(4)].to_vec();
        c.add("csp_header", format!("vec-kiss-enc-{i:02}-{name}"), packet);
        let sizes: &[u8] = match i % 3 {
            0 => &[64],
            1 => &[1],
            _ => &[3, 7, 2],
        };
        c.add(
            "kiss_decoder",
            format!("vec-kiss-enc-{i:02}-{name}"),
            kiss_input::join(sizes, &wire),
        );
    }
    let kdec = read_json(&dir.join("kiss_decode.json"))?;
    for (i, case) in cases(&kdec).iter().enumerate() {
        let name = slug(case["name"].as_str().unwrap_or_default());
        let input = hex(case["input"].as_str().unwrap_or_default())?;
        c.add(
            "kiss_decoder",
            format!("vec-kiss-dec-{i:02}-{name}"),
            kiss_input::join(&[5, 64], &input),
        );
    }
    let cfp = read_json(&dir.join("cfp.json"))?;
    for (i, case) in cases(&cfp).iter().enumerate() {
        let name = slug(case["name"].as_str().unwrap_or_default());
        let header = header_of(&case["fields"]);
        let data = hex(case["data"].as_str().unwrap_or_default())?;
        let mut ops = Vec::new();
        for f in case["frames"].as_array().map_or(&[][..], Vec::as_slice) {
            let id = u32::from_str_radix(
                f["can_id"].as_str().unwrap_or("0").trim_start_matches("0x"),
                16,
            )
            .map_err(|e| e.to_string())?;
            let bytes = hex(f["data"].as_str().unwrap_or_default())?;
            let mut d = [0u8; 8];
            d[..bytes.len()].copy_from_slice(&bytes);
            ops.push(CfpOp::Frame {
                id,
                dlc: bytes.len() as u8,
                data: d,
                dt_us: 100,
            });
        }
        let input = CfpInput {
            config: 9,
            word: header.to_word(),
            data: data.clone(),
            mac: case["route_via_mac"]
                .as_u64()
                .unwrap_or(u64::from(header.dst)) as u8,
            ident: case["cfp_ident"].as_u64().unwrap_or(0) as u16,
            ops,
        };
        let mut bytes = Vec::new();
        input.enc(&mut bytes);
        enc::roundtrip(std::slice::from_ref(&input), &bytes);
        c.add("cfp_reassembly", format!("vec-cfp-{i:02}-{name}"), bytes);
        let mut p = header.to_bytes().to_vec();
        p.extend_from_slice(&data);
        c.add("csp_header", format!("vec-cfp-{i:02}-{name}"), p);
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// CAN traffic from recordings
// ---------------------------------------------------------------------------------------

/// One CAN frame of a recording: time (ns), id, data.
#[derive(Debug, Clone)]
struct Row {
    t_ns: u64,
    id: u32,
    data: Vec<u8>,
}

fn read_can_csv(path: &Path) -> Res<Vec<Row>> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| {
        head.iter()
            .position(|h| *h == name)
            .ok_or(format!("{}: no column {name}", path.display()))
    };
    let (ct, cid, cdata, cdrop) = (
        col("t_ns")?,
        col("can_id")?,
        col("data_hex")?,
        col("dropped")?,
    );
    let mut rows = Vec::new();
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        if f.get(cdrop) == Some(&"true") {
            continue;
        }
        let (Some(t), Some(id), Some(d)) = (f.get(ct), f.get(cid), f.get(cdata)) else {
            continue;
        };
        rows.push(Row {
            t_ns: t.parse().map_err(|e| format!("t_ns {t:?}: {e}"))?,
            id: id.parse().map_err(|e| format!("can_id {id:?}: {e}"))?,
            data: hex(d)?,
        });
    }
    Ok(rows)
}

fn label(path: &Path) -> String {
    slug(
        &path
            .file_stem()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned()),
    )
    .trim_end_matches("-main")
    .trim_end_matches("-payload")
    .to_owned()
}

/// The time step from `prev` to `t` as one [`Step`].
fn step(prev: u64, t: u64) -> Step {
    let d = t.saturating_sub(prev);
    if d < 65_000_000 {
        Step::Micros {
            n: (d / 1_000) as u16,
        }
    } else if d < 65_000_000_000 {
        Step::Millis {
            n: (d / 1_000_000) as u16,
        }
    } else {
        Step::Seconds {
            n: (d / 1_000_000_000).min(255) as u8,
        }
    }
}

/// The frames to `addr` as node-target operations, in windows of at most 30 frames.
fn frame_ops<C>(rows: &[Row], addr: u8, iface: u8, windows: usize) -> Vec<Vec<Op<C>>> {
    let mine: Vec<&Row> = rows
        .iter()
        .filter(|r| CfpId::from_can_id(r.id).dst == addr)
        .collect();
    let mut out = Vec::new();
    for chunk in mine.chunks(30).take(windows) {
        let mut ops = Vec::new();
        let mut prev = chunk.first().map_or(0, |r| r.t_ns);
        // Start a little before the first frame so the node's timers run first.
        ops.push(Op::Advance {
            step: step(0, prev.min(5_000_000_000)),
        });
        for r in chunk {
            ops.push(Op::Advance {
                step: step(prev, r.t_ns),
            });
            prev = r.t_ns;
            ops.push(Op::Frame {
                iface,
                id: r.id,
                data: r.data.clone(),
            });
        }
        out.push(ops);
    }
    out
}

fn cfp_from_rows(c: &mut Corpus, name: &str, rows: &[Row]) {
    for (i, chunk) in rows.chunks(48).take(3).enumerate() {
        let mut prev = chunk.first().map_or(0, |r| r.t_ns);
        let ops = chunk
            .iter()
            .map(|r| {
                let mut d = [0u8; 8];
                let n = r.data.len().min(8);
                d[..n].copy_from_slice(&r.data[..n]);
                let dt_us = (r.t_ns.saturating_sub(prev) / 1000).min(u64::from(u32::MAX)) as u32;
                prev = r.t_ns;
                CfpOp::Frame {
                    id: r.id,
                    dlc: n as u8,
                    data: d,
                    dt_us,
                }
            })
            .collect();
        let first = chunk.first().map(|r| r.data.clone()).unwrap_or_default();
        let input = CfpInput {
            config: 9,
            word: Header::parse(&first).map_or(0, |h| h.to_word()),
            data: first,
            mac: 3,
            ident: 0x155,
            ops,
        };
        let mut bytes = Vec::new();
        input.enc(&mut bytes);
        enc::roundtrip(std::slice::from_ref(&input), &bytes);
        c.add("cfp_reassembly", format!("can-{name}-{i:02}"), bytes);
    }
}

// ---------------------------------------------------------------------------------------
// Node seeds
// ---------------------------------------------------------------------------------------

fn add_node<K: NodeKind>(
    c: &mut Corpus,
    target: &'static str,
    name: impl Into<String>,
    setup: &K::Setup,
    ops: &[Op<K::Cmd>],
) {
    let bytes = harness::encode::<K>(setup, ops);
    let back = harness::decode::<K>(&bytes);
    assert_eq!(
        back.as_ref().map(|(s, o)| (s, o.as_slice())),
        Some((setup, ops)),
        "seed does not decode back"
    );
    c.add(target, name, bytes);
}

fn via_can() -> Via {
    Via::Cfp {
        iface: 0,
        ident: 0x2a,
        mangle: Mangle::Intact,
    }
}

fn cmd<C>(c: C) -> Op<C> {
    Op::Cmd {
        via: via_can(),
        src: AddrSel::Peer { i: 8 }, // 16, the main ground station
        sport: 6,                    // 38
        prio: 2,
        cmd: c,
    }
}

fn wait_ms<C>(ms: u16) -> Op<C> {
    Op::Advance {
        step: Step::Millis { n: ms },
    }
}

fn wait_s<C>(s: u8) -> Op<C> {
    Op::Advance {
        step: Step::Seconds { n: s },
    }
}

/// A service request from the ground (or from the node itself).
fn service<C>(dport: u8, data: Vec<u8>, src: AddrSel, sport: PortSel) -> Op<C> {
    Op::Deliver {
        via: via_can(),
        packet: PacketSpec {
            prio: 2,
            src,
            dst: AddrSel::Own,
            sport,
            dport: PortSel::Service { p: dport },
            flags: FlagSel::None,
            data,
        },
    }
}

/// Seeds every node gets: the service ports, a CRC-flagged ping, and the service loopback.
fn service_seeds<K: NodeKind>(c: &mut Corpus, target: &'static str, setup: &K::Setup) {
    let ground = || AddrSel::Peer { i: 8 };
    let eph = || PortSel::Ephemeral { p: 6 };
    let ping = service::<K::Cmd>(1, (0..64).collect(), ground(), eph());
    add_node::<K>(c, target, "svc-ping", setup, &[ping.clone(), wait_ms(200)]);
    let all: Vec<Op<K::Cmd>> = vec![
        service(0, vec![0x00, 1], ground(), eph()), // CMP ident
        service(0, vec![0x00, 6, 0, 0, 0, 0, 0, 0, 0, 0], ground(), eph()), // CMP clock (get)
        service(2, vec![], ground(), eph()),        // ps
        service(3, vec![], ground(), eph()),        // memfree
        service(5, vec![], ground(), eph()),        // buffer free
        service(6, vec![], ground(), eph()),        // uptime
        wait_s(5),
        service(4, vec![0x80, 0x07, 0x80, 0x07], ground(), eph()), // reboot (magic)
        wait_s(1),
        service(6, vec![], ground(), eph()),
    ];
    add_node::<K>(c, target, "svc-all", setup, &all);
    let crc = Op::Deliver {
        via: Via::Packet { iface: 0 },
        packet: PacketSpec {
            prio: 2,
            src: ground(),
            dst: AddrSel::Own,
            sport: eph(),
            dport: PortSel::Service { p: 1 },
            flags: FlagSel::Crc,
            data: b"crc-flagged ping".to_vec(),
        },
    };
    add_node::<K>(c, target, "svc-ping-crc32", setup, &[crc]);
    // A node pinging itself from service port 1 to service port 1: each answer is another
    // ping (the stack overflow the lead fixed in csp::node; kept as a regression seed).
    let selfping = service::<K::Cmd>(1, vec![1, 2, 3], AddrSel::Own, PortSel::Service { p: 1 });
    add_node::<K>(
        c,
        target,
        "svc-loopback-self",
        setup,
        &[selfping, wait_s(1)],
    );
    let ctl = vec![
        wait_s(2),
        Op::Ctl { ctl: Ctl::PowerOff },
        wait_s(10),
        Op::Ctl { ctl: Ctl::PowerOn },
        wait_s(3),
        Op::Ctl {
            ctl: Ctl::ClockFault {
                id: 1,
                jump_ns: 60_000_000_000,
                drift_milli_ppm: 50_000,
            },
        },
        service(6, vec![], ground(), eph()),
        Op::Ctl { ctl: Ctl::Hang },
        wait_s(5),
        Op::Ctl { ctl: Ctl::Unhang },
        wait_s(1),
        Op::Ctl {
            ctl: Ctl::ClockFixed { id: 1 },
        },
        Op::Ctl { ctl: Ctl::Reboot },
        wait_s(2),
    ];
    add_node::<K>(c, target, "ctl-power-hang-clock", setup, &ctl);
}

fn traffic_seeds<K: NodeKind>(
    c: &mut Corpus,
    target: &'static str,
    setup: &K::Setup,
    can: &[(String, Vec<Row>)],
    iface: u8,
) {
    for (name, rows) in can {
        for (i, ops) in frame_ops::<K::Cmd>(rows, K::ADDR, iface, 3)
            .iter()
            .enumerate()
        {
            add_node::<K>(c, target, format!("can-{name}-{i:02}"), setup, ops);
        }
    }
}

fn fc_seeds(c: &mut Corpus, can: &[(String, Vec<Row>)]) {
    let t = "node_fc";
    let setup = FcSetup {
        orbit: 0,
        mode: 1,
        hz: 0,
    };
    service_seeds::<nodes::Fc>(c, t, &setup);
    traffic_seeds::<nodes::Fc>(c, t, &setup, can, 0);
    let script = |frame, start_rel_ds, dur_ds, style| ScriptGen {
        frame,
        start_rel_ds,
        dur_ds,
        q: [23170, 0, 0, -23170],
        lat_cdeg: 5469,
        lon_cdeg: 2528,
        alt_m: 1000,
        axis: [0, 0, 1],
        style,
    };
    let tle = TleGen {
        base: false,
        satnum: 25544,
        year: 0,
        day_offset_cday: -10,
        ndot: 2345,
        bstar: 12345,
        bstar_exp: 3,
        incl_cdeg: 5164,
        raan_cdeg: 22127,
        ecc: 1413,
        argp_cdeg: 8917,
        ma_cdeg: 28046,
        mm_urev: 15_495_078,
        revs: 23600,
    };
    let each: Vec<(&str, FcCmd)> = vec![
        ("tmgen", FcCmd::Telemetry { id: 0 }),
        ("tmatp", FcCmd::Telemetry { id: 1 }),
        ("tmacd", FcCmd::Telemetry { id: 2 }),
        ("tmsens", FcCmd::Telemetry { id: 3 }),
        ("tmrawsens", FcCmd::Telemetry { id: 4 }),
        ("tmall", FcCmd::Telemetry { id: 5 }),
        ("rtcstmset", FcCmd::RtcSet { t: 1_777_593_600 }),
        ("rtcstmset-near", FcCmd::RtcSetNear { dt_s: -30 }),
        ("rtcstmget", FcCmd::RtcGet),
        ("atcatget", FcCmd::GetAttitude),
        (
            "atcatset",
            FcCmd::SetAttitude {
                q: [707, 0, 0, -707],
            },
        ),
        (
            "atcatset-nan",
            FcCmd::SetAttitudeRaw {
                q: [f64::NAN.to_bits(), 0, 0, 0],
            },
        ),
        ("atcptget", FcCmd::GetPoint),
        (
            "atcptset",
            FcCmd::SetPoint {
                a_cdeg: 5469,
                b_cdeg: 2528,
                c_m: 10_000,
            },
        ),
        (
            "atcptset-inf",
            FcCmd::SetPointRaw {
                p: [f64::INFINITY.to_bits(), 0, 0],
            },
        ),
        ("atcmdget", FcCmd::GetMode),
        ("atcmdset-nadir", FcCmd::SetMode { m: 3 }),
        ("atcmdset-bad", FcCmd::SetMode { m: 10 }),
        (
            "atctleset-6u",
            FcCmd::SetTle {
                tle: TleGen {
                    base: true,
                    ..tle.clone()
                },
            },
        ),
        ("atctleset-iss", FcCmd::SetTle { tle: tle.clone() }),
        ("atctleget", FcCmd::GetTle),
        (
            "script-eci",
            FcCmd::Script {
                s: script(0, 10, 1200, 0),
            },
        ),
        (
            "script-lvlh-upper-semicolon",
            FcCmd::Script {
                s: script(1, 0, 600, 1 | 4),
            },
        ),
        (
            "script-tnw-tabs-nul",
            FcCmd::Script {
                s: script(2, 5, 300, 2 | 8),
            },
        ),
        (
            "script-geo-crlf",
            FcCmd::Script {
                s: script(3, 20, 900, 16 | 32),
            },
        ),
        (
            "script-ended",
            FcCmd::Script {
                s: script(0, -100, 50, 0),
            },
        ),
        (
            "unknown-telemetry-9",
            FcCmd::Unknown {
                port_i: 0,
                id: 9,
                data: vec![],
            },
        ),
        (
            "tmgen-extra-byte",
            FcCmd::Unknown {
                port_i: 0,
                id: 1,
                data: vec![0],
            },
        ),
    ];
    for (name, cmd_) in each {
        let ops = vec![wait_s(2), cmd(cmd_), wait_ms(500)];
        add_node::<nodes::Fc>(c, t, format!("icd-{name}"), &setup, &ops);
    }
    // The ICD 1.5 examples, word for word (2020 times: rejected as ended).
    for (i, line) in [
        "adcs 1577836800 1577836920 pointECI 1 0 0 0",
        "adcs 1577836800 1577836920 pointECI 0.707106 0 0 -0.707106",
        "adcs 1577836800 1577836920 pointLVLH 1 0 0 0",
        "adcs 1577836800 1577836920 pointGEO 54.6872 25.2797 100 0 0 1",
    ]
    .iter()
    .enumerate()
    {
        let bytes = line.as_bytes();
        let ops = vec![cmd(FcCmd::Unknown {
            port_i: 3,
            id: bytes[0],
            data: bytes[1..].to_vec(),
        })];
        add_node::<nodes::Fc>(c, t, format!("icd-1.5-example-{i}"), &setup, &ops);
    }
    // A pass of work: point, script, telemetry while the ADCS converges, a burn posted.
    let ops = vec![
        cmd(FcCmd::SetMode { m: 3 }),
        wait_s(5),
        cmd(FcCmd::Telemetry { id: 1 }),
        cmd(FcCmd::Script {
            s: script(3, 20, 600, 0),
        }),
        wait_s(30),
        cmd(FcCmd::Telemetry { id: 5 }),
        Op::Board {
            op: harness::BoardOp::Burn {
                ms: 5000,
                thrust_mn: 1000,
                mass_dkg: 60,
                dir: [0, 0, 127],
            },
        },
        wait_s(10),
        cmd(FcCmd::Telemetry { id: 2 }),
        cmd(FcCmd::SetTle { tle }),
        wait_s(5),
        cmd(FcCmd::Telemetry { id: 1 }),
        cmd(FcCmd::RtcSetNear { dt_s: 60 }),
        wait_s(5),
        cmd(FcCmd::Telemetry { id: 0 }),
    ];
    add_node::<nodes::Fc>(c, t, "icd-sequence", &setup, &ops);
    let ops = vec![
        wait_s(3),
        cmd(FcCmd::Telemetry { id: 1 }),
        cmd(FcCmd::GetTle),
    ];
    let not_uploaded = FcSetup {
        orbit: nodes::FC_TLE_NOT_UPLOADED,
        mode: 4,
        hz: 2,
    };
    add_node::<nodes::Fc>(c, t, "icd-tle-not-uploaded", &not_uploaded, &ops);
    let no_tle = FcSetup {
        orbit: nodes::FC_NO_TLE,
        mode: 7,
        hz: 3,
    };
    add_node::<nodes::Fc>(c, t, "icd-no-orbit", &no_tle, &ops);
}

fn pc_seeds(c: &mut Corpus, main: &[(String, Vec<Row>)], payload: &[(String, Vec<Row>)]) {
    let t = "node_pc";
    service_seeds::<nodes::Pc>(c, t, &());
    traffic_seeds::<nodes::Pc>(c, t, &(), main, 0);
    traffic_seeds::<nodes::Pc>(c, t, &(), payload, 1);
    let setup = |session, frame| PcCmd::Setup {
        session,
        start_rel_s: 5,
        duration_s: 55,
        max_packets: 20,
        frame,
        sync: b"hello payload".to_vec(),
    };
    for (name, cmd_) in [
        ("setup", setup(1, 200)),
        (
            "setup-now",
            PcCmd::Setup {
                session: 2,
                start_rel_s: i16::MIN,
                duration_s: 0x8003,
                max_packets: 0,
                frame: 0,
                sync: vec![],
            },
        ),
        ("status", PcCmd::Status { session: 1 }),
        ("abort", PcCmd::Abort { session: 1 }),
        ("tmpc", PcCmd::Tmpc),
        (
            "ingest",
            PcCmd::Ingest {
                data: vec![0x55; 200],
            },
        ),
    ] {
        add_node::<nodes::Pc>(c, t, format!("icd-{name}"), &(), &[cmd(cmd_), wait_s(1)]);
    }
    // A polling session: SETUP, the SYNC echoed by the payload, POLL replies, STATUS.
    let answer = |echo, data: Vec<u8>| Op::Answer {
        back: 0,
        result: 1,
        echo,
        data,
        via: Via::Cfp {
            iface: 1,
            ident: 7,
            mangle: Mangle::Intact,
        },
    };
    let mut ops = vec![
        cmd(setup(1, 100)),
        wait_s(5),
        wait_ms(10),
        answer(true, vec![]),
    ];
    for i in 0..8u8 {
        ops.push(wait_ms(50));
        ops.push(answer(false, vec![i; 100]));
    }
    ops.push(cmd(PcCmd::Status { session: 1 }));
    ops.push(wait_s(60));
    ops.push(cmd(PcCmd::Status { session: 1 }));
    add_node::<nodes::Pc>(c, t, "icd-polling-session", &(), &ops);
    // A buffering session fed by ingest packets from payload 13.
    let mut ops = vec![cmd(setup(2, 128))];
    for _ in 0..6 {
        ops.push(Op::Cmd {
            via: Via::Cfp {
                iface: 1,
                ident: 9,
                mangle: Mangle::Intact,
            },
            src: AddrSel::Peer { i: 7 }, // 13
            sport: 10,
            prio: 2,
            cmd: PcCmd::Ingest {
                data: vec![0xab; 240],
            },
        });
        ops.push(wait_s(2));
    }
    ops.push(wait_s(30));
    ops.push(cmd(PcCmd::Status { session: 2 }));
    add_node::<nodes::Pc>(c, t, "icd-buffering-session", &(), &ops);
}

fn simple_seeds<K: NodeKind>(
    c: &mut Corpus,
    target: &'static str,
    setup: &K::Setup,
    can: &[(String, Vec<Row>)],
    iface: u8,
    cmds: Vec<(&str, K::Cmd)>,
    sequence: Vec<Op<K::Cmd>>,
) {
    service_seeds::<K>(c, target, setup);
    traffic_seeds::<K>(c, target, setup, can, iface);
    for (name, cmd_) in cmds {
        add_node::<K>(
            c,
            target,
            format!("icd-{name}"),
            setup,
            &[cmd(cmd_), wait_s(1)],
        );
    }
    add_node::<K>(c, target, "icd-sequence", setup, &sequence);
}

fn node_seeds(c: &mut Corpus, main: &[(String, Vec<Row>)], payload: &[(String, Vec<Row>)]) {
    fc_seeds(c, main);
    pc_seeds(c, main, payload);
    simple_seeds::<nodes::Eps>(
        c,
        "node_eps",
        &(),
        main,
        0,
        vec![
            ("tmeps", EpsCmd::Tmeps),
            ("chget", EpsCmd::Chget),
            ("chset-pc-off", EpsCmd::Chset { ch: 3, on: 0 }),
            ("chset-bad", EpsCmd::Chset { ch: 9, on: 1 }),
            ("thrget", EpsCmd::Thrget),
            (
                "thrset",
                EpsCmd::Thrset {
                    t: [30, 40, 20, 30],
                },
            ),
        ],
        vec![
            cmd(EpsCmd::Tmeps),
            Op::Board {
                op: harness::BoardOp::Truth {
                    q: [32767, 0, 0, 0],
                    w: [0, 0, 0],
                    sun: [0, 0, 1000],
                    visible: 255,
                    wheels: [100, -100, 0, 0],
                    mtq: [0, 0, 0],
                    lat: 0,
                    lon: 0,
                },
            },
            Op::Board {
                op: harness::BoardOp::Activity { what: 0, on: true },
            },
            wait_s(30),
            cmd(EpsCmd::Chset { ch: 8, on: 1 }),
            cmd(EpsCmd::Thrset {
                t: [90, 95, 20, 30],
            }),
            Op::Advance {
                step: Step::Minutes { n: 5 },
            },
            cmd(EpsCmd::Tmeps),
            cmd(EpsCmd::Chget),
        ],
    );
    simple_seeds::<nodes::Ecu>(
        c,
        "node_ecu",
        &(),
        main,
        0,
        vec![
            ("tmecu", EcuCmd::Tmecu),
            ("arm", EcuCmd::Arm),
            ("fire-unarmed", EcuCmd::Fire { ms: 1000 }),
            ("safe", EcuCmd::Safe),
        ],
        vec![
            cmd(EcuCmd::Arm),
            wait_s(61),
            cmd(EcuCmd::Fire { ms: 2000 }),
            wait_ms(500),
            cmd(EcuCmd::Tmecu),
            wait_s(2),
            cmd(EcuCmd::Fire { ms: 60_000 }),
            wait_s(1),
            cmd(EcuCmd::Safe),
            cmd(EcuCmd::Tmecu),
        ],
    );
    simple_seeds::<nodes::Comm>(
        c,
        "node_comm",
        &(),
        main,
        0,
        vec![
            ("tmcomm", CommCmd::Tmcomm),
            ("beaconset-10", CommCmd::BeaconSet { s: 3591 }),
            ("beaconset-off", CommCmd::BeaconSet { s: 0 }),
            ("beaconget", CommCmd::BeaconGet),
            ("beacon", CommCmd::Beacon),
        ],
        vec![
            cmd(CommCmd::BeaconSet { s: 3591 }),
            Op::Board {
                op: harness::BoardOp::Truth {
                    q: [32767, 0, 0, 0],
                    w: [0, 0, 0],
                    sun: [1000, 0, 0],
                    visible: 255,
                    wheels: [0; 4],
                    mtq: [0; 3],
                    lat: 9000,
                    lon: -21000,
                },
            },
            wait_s(25),
            cmd(CommCmd::Tmcomm),
            Op::Ctl {
                ctl: Ctl::Radio { on: false },
            },
            wait_s(15),
            Op::Ctl {
                ctl: Ctl::Radio { on: true },
            },
            wait_s(15),
            cmd(CommCmd::Beacon),
        ],
    );
    let psetup = PayloadSetup {
        behaviour: 0,
        param: 20,
        later: 3,
        later_at_s: 30,
        push: false,
        rate: Some(2000),
    };
    // Payloads sit on the payload bus; the PC (6) asks.
    let from_pc = |c_: PayloadCmd| Op::Cmd {
        via: via_can(),
        src: AddrSel::Peer { i: 5 },
        sport: 12,
        prio: 2,
        cmd: c_,
    };
    let payload_rows: Vec<(String, Vec<Row>)> = payload.to_vec();
    service_seeds::<nodes::Payload>(c, "node_payload", &psetup);
    traffic_seeds::<nodes::Payload>(c, "node_payload", &psetup, &payload_rows, 0);
    for (name, cmd_) in [
        (
            "sync",
            PayloadCmd::Sync {
                msg: b"hello payload".to_vec(),
            },
        ),
        ("poll", PayloadCmd::Poll { frame: 200 }),
        ("poll-0", PayloadCmd::Poll { frame: 0 }),
        ("sync-too-long", PayloadCmd::Sync { msg: vec![7; 129] }),
    ] {
        add_node::<nodes::Payload>(
            c,
            "node_payload",
            format!("icd-{name}"),
            &psetup,
            &[from_pc(cmd_), wait_ms(100)],
        );
    }
    let mut ops = vec![
        from_pc(PayloadCmd::Sync { msg: b"s".to_vec() }),
        wait_ms(20),
    ];
    for _ in 0..10 {
        ops.push(from_pc(PayloadCmd::Poll { frame: 254 }));
        ops.push(wait_ms(300));
    }
    ops.push(wait_s(40));
    ops.push(from_pc(PayloadCmd::Poll { frame: 100 }));
    ops.push(wait_s(1));
    add_node::<nodes::Payload>(c, "node_payload", "icd-sequence", &psetup, &ops);
    let push = PayloadSetup {
        behaviour: 7,
        param: 0,
        later: 6,
        later_at_s: 10,
        push: true,
        rate: None,
    };
    add_node::<nodes::Payload>(
        c,
        "node_payload",
        "icd-push-garbage",
        &push,
        &[
            wait_s(20),
            from_pc(PayloadCmd::Poll { frame: 50 }),
            wait_s(5),
        ],
    );
}

// ---------------------------------------------------------------------------------------
// TLEs, scenarios, recordings
// ---------------------------------------------------------------------------------------

fn tle_seeds(c: &mut Corpus, reference: &Path) -> Res<()> {
    let (l1, l2) = nodes::TLE_6U;
    c.add(
        "tle_parser",
        "tle-default-6u",
        format!("{l1}\n{l2}\n").into_bytes(),
    );
    let path = reference.join("sgp4_vallado_tles.csv");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if let (Some(case), Some(satnum), Some(a), Some(b)) =
            (f.first(), f.get(1), f.get(2), f.get(3))
        {
            c.add(
                "tle_parser",
                format!("tle-vallado-{case:0>2}-{satnum}"),
                format!("{a}\n{b}\n").into_bytes(),
            );
        }
    }
    Ok(())
}

fn scenario_seeds(c: &mut Corpus, dir: &Path) -> Res<()> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    entries.sort();
    for p in entries {
        let bytes = std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))?;
        c.add("scenario_parser", format!("scenario-{}", label(&p)), bytes);
    }
    Ok(())
}

fn recording_seeds(c: &mut Corpus, recordings: &[PathBuf]) -> Res<()> {
    for p in recordings {
        let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
        let name = label(p);
        // Cut short: the header, schemas and metadata of the first few kilobytes.
        c.add(
            "mcap_reader",
            format!("rec-{name}-first-4k"),
            bytes[..bytes.len().min(4096)].to_vec(),
        );
        c.add("mcap_reader", format!("rec-{name}"), bytes);
    }
    Ok(())
}

fn main() {
    if let Err(e) = run() {
        eprintln!("make_seeds: {e}");
        std::process::exit(1);
    }
}

fn run() -> Res<()> {
    let a = args()?;
    let mut c = Corpus::default();
    vectors(&mut c, &a.vectors)?;
    let load = |paths: &[PathBuf]| -> Res<Vec<(String, Vec<Row>)>> {
        paths
            .iter()
            .map(|p| Ok((label(p), read_can_csv(p)?)))
            .collect()
    };
    let main_rows = load(&a.can_main)?;
    let payload_rows = load(&a.can_payload)?;
    for (name, rows) in main_rows.iter().chain(&payload_rows) {
        cfp_from_rows(&mut c, name, rows);
    }
    node_seeds(&mut c, &main_rows, &payload_rows);
    tle_seeds(&mut c, &a.reference)?;
    scenario_seeds(&mut c, &a.scenarios)?;
    recording_seeds(&mut c, &a.recordings)?;
    link_seeds(&mut c, &a.vectors)?;
    c.write(&a.out, &a.only)
}

// ---------------------------------------------------------------------------------------
// One outside connection's bytes
// ---------------------------------------------------------------------------------------

fn link_seeds(c: &mut Corpus, vectors: &Path) -> Res<()> {
    use csp::Packet;
    use m6p_twin_fuzz::link_input;
    let p = |src: u8, dst: u8, dport: u8, n: usize| {
        Packet::new(Header::new(src, dst, dport, 40), vec![0x5a; n])
    };
    let kiss = |packets: &[Packet]| {
        let mut out = Vec::new();
        for q in packets {
            csp::kiss::encode(q, &mut out);
        }
        out
    };
    // Hub messages are one a chunk: each packet's message as a chunk of its own size.
    let hub = |config: u8, packets: &[Packet]| {
        let mut sizes = Vec::new();
        let mut stream = Vec::new();
        for q in packets {
            let mut m = Vec::new();
            csp::zmqhub::encode(q, q.header.dst, &mut m);
            sizes.push(m.len() as u8);
            stream.extend(m);
        }
        link_input::join(config | 1, &[], &sizes, &stream)
    };
    // KISS: a ground program learns 18 and pings the FC; then as the FC (refused), as 17
    // (another link's connection holds it), as 15 (another link's reservation).
    let learn = kiss(&[p(18, 3, 1, 4), p(18, 4, 6, 0)]);
    c.add(
        "outside_link",
        "link-kiss-learn-18",
        link_input::join(0, &[], &[64], &learn),
    );
    let impostor = kiss(&vec![p(3, 4, 1, 4); 8]);
    c.add(
        "outside_link",
        "link-kiss-impostor-fc",
        link_input::join(0, &[], &[5, 33], &impostor),
    );
    let held = kiss(&[p(17, 3, 1, 4), p(15, 6, 1, 4), p(18, 3, 1, 4)]);
    c.add(
        "outside_link",
        "link-kiss-held-and-reserved",
        link_input::join(0, &[], &[7], &held),
    );
    // A link configured with 14: its packets, and one from 13 (refused).
    let configured = kiss(&[p(14, 6, 10, 2), p(13, 6, 1, 4), p(14, 3, 10, 1)]);
    c.add(
        "outside_link",
        "link-kiss-configured-14",
        link_input::join(0, &[14], &[64], &configured),
    );
    // A payload filling its CAN transmit queue with 256-byte packets, under a budget.
    let filling = kiss(&vec![p(13, 6, 11, 256); 40]);
    c.add(
        "outside_link",
        "link-kiss-payload-queue-budget",
        link_input::join(0x10, &[], &[64], &filling),
    );
    c.add(
        "outside_link",
        "link-kiss-v14-limit",
        link_input::join(0x02, &[], &[64], &kiss(&[p(18, 3, 1, 250)])),
    );
    // The hub: programs on several segments, one of them as PL12 (refused), one between
    // two programs (straight across), a short message, an empty one first.
    c.add(
        "outside_link",
        "link-hub-programs",
        hub(
            0,
            &[
                p(18, 3, 1, 4),
                p(13, 6, 10, 2),
                p(12, 3, 1, 4),
                p(18, 19, 1, 4),
            ],
        ),
    );
    c.add(
        "outside_link",
        "link-hub-empty-first",
        hub(0x20, &[p(18, 3, 1, 4)]),
    );
    c.add(
        "outside_link",
        "link-hub-short",
        link_input::join(1, &[], &[2, 5], &[18, 0x12, 0, 0, 0, 0, 1]),
    );
    let kdec = read_json(&vectors.join("kiss_decode.json"))?;
    for (i, case) in cases(&kdec).iter().enumerate() {
        let name = slug(case["name"].as_str().unwrap_or_default());
        let input = hex(case["input"].as_str().unwrap_or_default())?;
        c.add(
            "outside_link",
            format!("link-vec-{i:02}-{name}"),
            link_input::join(0, &[], &[5, 64], &input),
        );
    }
    Ok(())
}
