//! The M6P network's ICD as data: every node, its request-reply ports, their commands and
//! the layouts of their requests and replies, gathered from the node crates' own tables
//! (`csp::icd`: the layouts are the wire types themselves, so the description cannot
//! disagree with the bytes). `m6p-twin icd [--json]` prints it; the recorder decodes CSP
//! packets with it ([`IcdMap::decode`]); the `icd-reply-length` invariant takes its lengths
//! from it (`icd_lengths`).
//!
//! Port numbers here are the defaults; [`IcdMap::for_nodes`] places the same tables on the
//! ports a run configured.

use std::collections::BTreeMap;

use csp::icd::{Access, Command, Data, Decoded, Field, Port, Ty};
use csp::reqrep::RESULT_SUCCESS;
use serde::Serialize;

pub mod xtce;

/// Platform port 14 (`csp::params`) as data: the same on every twin node.
pub const PLATFORM_PORT: Port = Port {
    port: csp::params::PORT,
    name: "platform",
    commands: &[
        Command::new(csp::params::cmd::PGET, "PGET", "read a parameter")
            .refused_when("an unknown id")
            .request(Data::Variable("u8 id", 1, 1))
            .reply(Data::Variable(
                "u8 id, u8 type, value (sized by type)",
                3,
                6,
            ))
            .no_payloads()
            .twin(),
        Command::new(
            csp::params::cmd::PSET,
            "PSET",
            "set a parameter (not saved)",
        )
        .refused_when(
            "an unknown id; a value not of its type's size, NaN, infinite, outside min..=max, \
             or breaking a rule between parameters",
        )
        .request(Data::Variable(
            "u8 id, value (sized by the parameter's type)",
            2,
            5,
        ))
        .reply(Data::Variable("u8 id, u8 type, value in effect", 3, 6))
        .no_payloads()
        .twin(),
        Command::new(
            csp::params::cmd::PINFO,
            "PINFO",
            "a parameter's type, range, default, name and unit",
        )
        .refused_when("an unknown id")
        .request(Data::Variable("u8 id", 1, 1))
        .reply(Data::Variable(
            "u8 id, u8 type, f64 min, f64 max, f64 default, char name[24], char unit[8]",
            csp::params::PINFO_LEN,
            csp::params::PINFO_LEN,
        ))
        .no_payloads()
        .twin(),
        Command::new(csp::params::cmd::PLIST, "PLIST", "parameters from an id on")
            .request(Data::Variable("u8 first_id", 1, 1))
            .reply(Data::Variable(
                "u8 next_id (0xFF: no more), u8 count, count x (u8 id, u8 type, value)",
                2,
                csp::params::PLIST_MAX_BYTES,
            ))
            .no_payloads()
            .twin(),
        Command::new(
            csp::params::cmd::PSAVE,
            "PSAVE",
            "save the parameters to the non-volatile store",
        )
        .no_payloads()
        .twin(),
        Command::new(
            csp::params::cmd::PDEFAULTS,
            "PDEFAULTS",
            "restore the factory values",
        )
        .no_payloads()
        .twin(),
        Command::new(
            csp::params::cmd::SELFTEST,
            "SELFTEST",
            "each component's health and reading",
        )
        .reply(Data::Variable(
            "u8 overall, u8 count, count x (u8 health, f32 reading)",
            2,
            2 + 255 * 5,
        ))
        .no_payloads()
        .twin(),
    ],
};

/// One node of the network and its ports (default numbers).
#[derive(Debug, Clone)]
pub struct NodeIcd {
    /// Name (`FC`, `PC`, `COMM`, `payload`).
    pub name: &'static str,
    /// CSP addresses it answers on.
    pub addrs: Vec<u8>,
    /// Its request-reply ports.
    pub ports: Vec<Port>,
}

/// Every node's ICD, with the default ports.
pub fn nodes() -> Vec<NodeIcd> {
    use nodes_fc::wire as fc;
    use nodes_pc::wire as pc;
    vec![
        NodeIcd {
            name: "COMM",
            addrs: vec![platform::addr::COMM1, platform::addr::COMM2],
            ports: vec![nodes_comm::wire::ICD_PORT, PLATFORM_PORT],
        },
        NodeIcd {
            name: "FC",
            addrs: vec![platform::addr::FC],
            ports: vec![
                fc::ICD_TELEMETRY,
                fc::ICD_RTC,
                fc::ICD_ATTITUDE,
                fc::ICD_SCRIPTS,
                PLATFORM_PORT,
            ],
        },
        NodeIcd {
            name: "EPS",
            addrs: vec![platform::addr::EPS],
            ports: vec![nodes_eps::wire::ICD_PORT, PLATFORM_PORT],
        },
        NodeIcd {
            name: "ECU",
            addrs: vec![platform::addr::ECU],
            ports: vec![nodes_ecu::wire::ICD_PORT, PLATFORM_PORT],
        },
        NodeIcd {
            name: "PC",
            addrs: vec![platform::addr::PC],
            ports: vec![
                pc::ICD_CONTROL,
                pc::ICD_INGEST,
                pc::ICD_TELEMETRY,
                pc::ICD_FILES,
                PLATFORM_PORT,
            ],
        },
        NodeIcd {
            name: "payload",
            addrs: vec![12, 13, 14, 15],
            ports: vec![pc::ICD_PAYLOAD, PLATFORM_PORT],
        },
    ]
}

/// The node named `name` (case-insensitive; `COMM1`/`COMM2` are the COMM, `PL12`.. a
/// payload).
pub fn node_named(name: &str) -> Option<NodeIcd> {
    let n = name.to_ascii_uppercase();
    let key = match n.as_str() {
        "COMM1" | "COMM2" => "COMM",
        s if s.starts_with("PL") || s == "PAYLOAD" => "payload",
        s => s,
    };
    nodes()
        .into_iter()
        .find(|x| x.name.eq_ignore_ascii_case(key))
}

/// The ICD placed on one run's ports: (node address, port) to the node's name and the
/// port's table; and the PC's sessions, which its commands name by id.
#[derive(Debug, Clone, Default)]
pub struct IcdMap {
    ports: BTreeMap<(u8, u8), (&'static str, Port)>,
    /// The PC's sessions as (session id, payload address), in its configuration's order.
    pc_sessions: Vec<(u8, u8)>,
}

/// The sessions of a PC's configuration as (session id, payload address).
fn pc_sessions(pc: &nodes_pc::PcConfig) -> Vec<(u8, u8)> {
    pc.sessions
        .iter()
        .map(|s| (s.session_id, s.payload_addr))
        .collect()
}

/// Request or reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// To an ICD port.
    Request,
    /// From an ICD port.
    Reply,
}

/// A CSP packet's data read with the ICD.
#[derive(Debug, Clone)]
pub struct DecodedPacket {
    /// The node's name (`FC`).
    pub node: &'static str,
    /// The command's name (`TMGEN`).
    pub command: &'static str,
    /// Request or reply.
    pub direction: Direction,
    /// The reply's result byte (replies only).
    pub result: Option<u8>,
    /// The fixed fields, decoded (empty for a failure reply, a layout of varying length,
    /// or data of the wrong length).
    pub fields: Vec<Decoded>,
    /// The byte string after a fixed head (SETUP's sync message), if any.
    pub tail: Option<Vec<u8>>,
    /// The data's length fits the layout (`false`: the fields could not be read).
    pub fits: bool,
}

/// The node configurations the ICD's ports come from, and the seed (the FC's own port is
/// drawn from it).
#[derive(Debug, Clone, Copy)]
pub struct NodePorts<'a> {
    /// The run's seed.
    pub seed: u64,
    /// The FC's configuration.
    pub fc: &'a nodes_fc::FcConfig,
    /// The PC's.
    pub pc: &'a nodes_pc::PcConfig,
    /// The EPS's.
    pub eps: &'a nodes_eps::EpsConfig,
    /// The ECU's.
    pub ecu: &'a nodes_ecu::EcuConfig,
    /// The COMMs'.
    pub comm: &'a nodes_comm::CommConfig,
}

impl IcdMap {
    /// The ICD on the default ports.
    pub fn defaults() -> Self {
        let mut ports = BTreeMap::new();
        for n in nodes() {
            for a in &n.addrs {
                for p in &n.ports {
                    ports.insert((*a, p.port), (n.name, *p));
                }
            }
        }
        IcdMap {
            ports,
            pc_sessions: pc_sessions(&nodes_pc::PcConfig::default()),
        }
    }

    /// The ICD on the ports the nodes' configurations give (a run's:
    /// `RunOptions::icd_map`).
    pub fn for_nodes(opts: &NodePorts<'_>) -> Self {
        use nodes_fc::wire as fc;
        use nodes_pc::wire as pc;
        let names: BTreeMap<u8, &'static str> = nodes()
            .iter()
            .flat_map(|n| n.addrs.iter().map(|a| (*a, n.name)))
            .collect();
        let mut ports = BTreeMap::new();
        let mut put = |addr: u8, number: u8, p: Port| {
            let name = names.get(&addr).copied().unwrap_or("?");
            ports.insert((addr, number), (name, Port { port: number, ..p }));
        };
        let f = &opts.fc.ports;
        put(platform::addr::FC, f.telemetry, fc::ICD_TELEMETRY);
        // The FC's periodic telemetry (TMPERSET) leaves from its own port with the bytes a
        // request would get: read as the telemetry port's replies.
        let fc_own = csp::node::own_port(crate::seed::first_ephemeral_port(
            opts.seed,
            platform::addr::FC,
        ));
        put(platform::addr::FC, fc_own, fc::ICD_TELEMETRY);
        put(platform::addr::FC, f.rtc, fc::ICD_RTC);
        put(platform::addr::FC, f.attitude, fc::ICD_ATTITUDE);
        put(platform::addr::FC, f.scripts, fc::ICD_SCRIPTS);
        put(platform::addr::PC, opts.pc.control_port, pc::ICD_CONTROL);
        put(platform::addr::PC, opts.pc.ingest_port, pc::ICD_INGEST);
        put(
            platform::addr::PC,
            opts.pc.telemetry_port,
            pc::ICD_TELEMETRY,
        );
        put(platform::addr::PC, opts.pc.files_port, pc::ICD_FILES);
        put(
            platform::addr::EPS,
            opts.eps.port,
            nodes_eps::wire::ICD_PORT,
        );
        put(
            platform::addr::ECU,
            opts.ecu.port,
            nodes_ecu::wire::ICD_PORT,
        );
        for a in [platform::addr::COMM1, platform::addr::COMM2] {
            put(a, opts.comm.port, nodes_comm::wire::ICD_PORT);
        }
        for a in 12..=15 {
            put(a, pc::PORT_PAYLOAD, pc::ICD_PAYLOAD);
        }
        for s in &opts.pc.sessions {
            put(s.payload_addr, s.payload_port, pc::ICD_PAYLOAD);
        }
        for a in [
            platform::addr::COMM1,
            platform::addr::COMM2,
            platform::addr::FC,
            platform::addr::EPS,
            platform::addr::ECU,
            platform::addr::PC,
            12,
            13,
            14,
            15,
        ] {
            put(a, csp::params::PORT, PLATFORM_PORT);
        }
        IcdMap {
            ports,
            pc_sessions: pc_sessions(opts.pc),
        }
    }

    /// The payload address of the PC's session `session_id` (SETUP, STATUS and ABORT name a
    /// session by id; the payload is fixed for the run), if the PC has that session.
    pub fn pc_session_payload(&self, session_id: u8) -> Option<u8> {
        self.pc_sessions
            .iter()
            .find(|(s, _)| *s == session_id)
            .map(|(_, a)| *a)
    }

    /// The port table at `addr`:`port`.
    pub fn port(&self, addr: u8, port: u8) -> Option<&Port> {
        self.ports.get(&(addr, port)).map(|(_, p)| p)
    }

    /// Every (address, port) with its table, in order.
    pub fn iter(&self) -> impl Iterator<Item = (&(u8, u8), &Port)> {
        self.ports.iter().map(|(k, (_, p))| (k, p))
    }

    /// Read a packet's data (without a CRC trailer) with the ICD: a request when it goes to
    /// an ICD port from an ephemeral port (or another node's port), a reply when it comes
    /// from an ICD port to an ephemeral port. `None` when neither end is an ICD port, or
    /// the command id is not in the port's table.
    pub fn decode(&self, header: &csp::Header, data: &[u8]) -> Option<DecodedPacket> {
        let c = self.classify(header, data)?;
        let mut out = DecodedPacket {
            node: c.node,
            command: c.command.name,
            direction: c.direction,
            result: c.result,
            fields: Vec::new(),
            tail: None,
            fits: c.fits(),
        };
        if let Some(layout) = c.layout() {
            if let Some((fields, tail)) = layout.decode(c.body) {
                out.fields = fields;
                out.tail = tail;
            }
        }
        Some(out)
    }

    /// What [`IcdMap::decode`] finds before it reads the fields: the node, the command,
    /// the direction, the result and the bytes of the layout. Allocates nothing.
    pub fn classify<'d>(&self, header: &csp::Header, data: &'d [u8]) -> Option<Classified<'d>> {
        let reply = (header.dport >= csp::header::EPHEMERAL_PORT_MIN)
            .then(|| self.ports.get(&(header.src, header.sport)))
            .flatten();
        let ((node, port), direction) = match reply {
            Some(e) => (e, Direction::Reply),
            None => (
                self.ports.get(&(header.dst, header.dport))?,
                Direction::Request,
            ),
        };
        let (&id, rest) = data.split_first()?;
        let command = port.command(id)?;
        let (result, body) = match direction {
            Direction::Request => (None, rest),
            Direction::Reply => {
                let (&r, body) = rest.split_first()?;
                (Some(r), body)
            }
        };
        Some(Classified {
            node,
            command,
            direction,
            result,
            body,
        })
    }
}

/// A packet of an ICD command, before its fields are read ([`IcdMap::classify`]).
#[derive(Debug, Clone, Copy)]
pub struct Classified<'d> {
    /// The node's name (`FC`).
    pub node: &'static str,
    /// The command.
    pub command: &'static csp::icd::Command,
    /// Request or reply.
    pub direction: Direction,
    /// The reply's result byte (replies only).
    pub result: Option<u8>,
    /// The data after the command byte (and the result byte of a reply).
    pub body: &'d [u8],
}

impl Classified<'_> {
    /// The layout the body has, `None` for a failure reply (which has no fields).
    pub fn layout(&self) -> Option<csp::icd::Data> {
        match (self.direction, self.result) {
            (Direction::Request, _) => Some(self.command.request),
            (Direction::Reply, Some(RESULT_SUCCESS)) => Some(self.command.reply),
            (Direction::Reply, _) => None,
        }
    }

    /// The body's length fits the layout (a failure reply: the body is empty).
    pub fn fits(&self) -> bool {
        match self.layout() {
            Some(layout) => {
                let (lo, hi) = layout.bounds();
                (lo..=hi).contains(&self.body.len())
            }
            None => self.body.is_empty(),
        }
    }
}

/// A field as `icd --json` prints it.
#[derive(Debug, Serialize)]
struct FieldJson {
    name: &'static str,
    #[serde(rename = "type")]
    ty: &'static str,
    count: usize,
    offset: usize,
    size: usize,
    #[serde(skip_serializing_if = "str::is_empty")]
    unit: &'static str,
    #[serde(skip_serializing_if = "String::is_empty")]
    doc: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    range: Option<[serde_json::Value; 2]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    except: Option<[serde_json::Value; 2]>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    values: BTreeMap<String, &'static str>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    bits: BTreeMap<String, &'static str>,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    text: bool,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    fields: Vec<FieldJson>,
}

/// A bound of a field of type `ty` as JSON: an integer for an integer type (a consumer
/// with integer types refuses `63.0`), a number for a float.
fn number(ty: Ty, x: f64) -> serde_json::Value {
    match ty {
        Ty::F32 | Ty::F64 | Ty::Struct(..) => serde_json::json!(x),
        _ => serde_json::json!(x as i64),
    }
}

fn fields_json(fields: &'static [Field]) -> Vec<FieldJson> {
    let mut offset = 0;
    fields
        .iter()
        .map(|f| {
            let j = FieldJson {
                name: f.name,
                ty: if f.text { "char" } else { f.ty.name() },
                count: f.count,
                offset,
                size: f.len(),
                unit: f.unit,
                doc: f.doc_line(),
                range: f.range.map(|(a, b)| [number(f.ty, a), number(f.ty, b)]),
                except: f.except.map(|(a, b)| [number(f.ty, a), number(f.ty, b)]),
                values: f.values.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
                bits: f.bits.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
                text: f.text,
                fields: match f.ty {
                    Ty::Struct(_, inner) if !f.text => fields_json(inner),
                    _ => Vec::new(),
                },
            };
            offset += f.len();
            j
        })
        .collect()
}

#[derive(Debug, Serialize)]
struct DataJson {
    #[serde(skip_serializing_if = "str::is_empty")]
    layout: &'static str,
    min_bytes: usize,
    max_bytes: usize,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    fields: Vec<FieldJson>,
    #[serde(skip_serializing_if = "Option::is_none")]
    tail: Option<TailJson>,
    #[serde(skip_serializing_if = "str::is_empty")]
    doc: &'static str,
}

#[derive(Debug, Serialize)]
struct TailJson {
    name: &'static str,
    doc: &'static str,
    min_bytes: usize,
    max_bytes: usize,
}

fn data_json(d: &Data) -> DataJson {
    let (min_bytes, max_bytes) = d.bounds();
    match *d {
        Data::None => DataJson {
            layout: "",
            min_bytes,
            max_bytes,
            fields: Vec::new(),
            tail: None,
            doc: "",
        },
        Data::Fixed(name, f) => DataJson {
            layout: name,
            min_bytes,
            max_bytes,
            fields: fields_json(f),
            tail: None,
            doc: "",
        },
        Data::Tail(name, f, t) => DataJson {
            layout: name,
            min_bytes,
            max_bytes,
            fields: fields_json(f),
            tail: Some(TailJson {
                name: t.name,
                doc: t.doc,
                min_bytes: t.min,
                max_bytes: t.max,
            }),
            doc: "",
        },
        Data::Variable(doc, ..) => DataJson {
            layout: "",
            min_bytes,
            max_bytes,
            fields: Vec::new(),
            tail: None,
            doc,
        },
    }
}

#[derive(Debug, Serialize)]
struct CommandJson {
    id: u8,
    name: &'static str,
    doc: &'static str,
    access: &'static str,
    origin: &'static str,
    request: DataJson,
    reply: DataJson,
    #[serde(skip_serializing_if = "Option::is_none")]
    example: Option<String>,
    #[serde(skip_serializing_if = "str::is_empty")]
    refused_when: &'static str,
}

#[derive(Debug, Serialize)]
struct PortJson {
    port: u8,
    name: &'static str,
    commands: Vec<CommandJson>,
}

#[derive(Debug, Serialize)]
struct NodeJson {
    name: &'static str,
    addrs: Vec<u8>,
    ports: Vec<PortJson>,
}

#[derive(Debug, Serialize)]
struct IcdJson {
    format: u32,
    framing: &'static str,
    nodes: Vec<NodeJson>,
}

fn access_name(a: Access) -> &'static str {
    match a {
        Access::Any => "any",
        Access::NoPayloads => "no-payloads",
    }
}

/// The whole ICD as JSON (`m6p-twin icd --json`): format 1.
pub fn to_json() -> String {
    let j = IcdJson {
        format: 1,
        framing: "request: command u8 | data; reply: command u8 | result u8 (1 success, 0 \
                  failure) | data on success; little-endian, IEEE-754",
        nodes: nodes()
            .into_iter()
            .map(|n| NodeJson {
                name: n.name,
                addrs: n.addrs,
                ports: n
                    .ports
                    .iter()
                    .map(|p| PortJson {
                        port: p.port,
                        name: p.name,
                        commands: p
                            .commands
                            .iter()
                            .map(|c| CommandJson {
                                id: c.id,
                                name: c.name,
                                doc: c.doc,
                                access: access_name(c.access),
                                origin: if c.twin { "twin" } else { "icd" },
                                request: data_json(&c.request),
                                reply: data_json(&c.reply),
                                example: c.examples.first().map(|e| {
                                    e.iter().map(|b| format!("{b:02x}")).collect::<String>()
                                }),
                                refused_when: c.refused,
                            })
                            .collect(),
                    })
                    .collect(),
            })
            .collect(),
    };
    serde_json::to_string_pretty(&j).unwrap_or_default()
}

fn field_lines(fields: &'static [Field], indent: &str, out: &mut String) {
    let mut offset = 0;
    for f in fields {
        let ty = f.type_text();
        let mut extra = Vec::new();
        if !f.unit.is_empty() {
            extra.push(f.unit.to_string());
        }
        if let Some(r) = f.range_text() {
            extra.push(format!("range {r}"));
        }
        if !f.values.is_empty() {
            extra.push(
                f.values
                    .iter()
                    .map(|(k, v)| format!("{k} {v}"))
                    .collect::<Vec<_>>()
                    .join(", "),
            );
        }
        if !f.bits.is_empty() {
            extra.push(format!(
                "bits: {}",
                f.bits
                    .iter()
                    .map(|(k, v)| format!("{k} {v}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        let extra = if extra.is_empty() {
            String::new()
        } else {
            format!(" [{}]", extra.join("; "))
        };
        out.push_str(&format!(
            "{indent}{offset:>3}  {:<22} {ty:<12}{extra}  {}\n",
            f.name,
            f.doc_line()
        ));
        if let Ty::Struct(_, inner) = f.ty {
            if !f.text {
                field_lines(inner, &format!("{indent}     "), out);
            }
        }
        offset += f.len();
    }
}

fn data_lines(label: &str, d: &Data, out: &mut String) {
    match *d {
        Data::None => out.push_str(&format!("      {label}: none\n")),
        Data::Fixed(name, f) => {
            out.push_str(&format!(
                "      {label}: {name}, {} bytes\n",
                csp::icd::fields_len(f)
            ));
            field_lines(f, "        ", out);
        }
        Data::Tail(name, f, t) => {
            let head = csp::icd::fields_len(f);
            if f.is_empty() {
                out.push_str(&format!(
                    "      {label}: {} ({}..={} bytes): {}\n",
                    t.name, t.min, t.max, t.doc
                ));
            } else {
                out.push_str(&format!(
                    "      {label}: {name}, {head} + {}..={} bytes\n",
                    t.min, t.max
                ));
                field_lines(f, "        ", out);
                out.push_str(&format!(
                    "        {head:>3}  {:<22} {:<12}  {}\n",
                    t.name, "bytes", t.doc
                ));
            }
        }
        Data::Variable(doc, lo, hi) => {
            out.push_str(&format!("      {label}: {lo}..={hi} bytes: {doc}\n"));
        }
    }
}

/// Why a node or a command is not in the ICD; each lists what there is.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum IcdLookupError {
    /// [`to_text`] of a node the ICD does not have.
    #[error("no node {name:?}: the nodes are {}", .known.join(", "))]
    NoNodeNamed {
        /// The name asked for.
        name: String,
        /// The ICD's nodes.
        known: Vec<&'static str>,
    },
    /// [`find_command`] of a name without a dot.
    #[error("`{name}` is not NODE.COMMAND (for example FC.TMGEN; `m6p-twin icd` lists them)")]
    NotNodeCommand {
        /// The name asked for.
        name: String,
    },
    /// [`find_command`] of a node the ICD does not have.
    #[error("no node `{node}`: {}", .known.join(", "))]
    NoNodeForCommand {
        /// The node part of the name.
        node: String,
        /// The ICD's nodes.
        known: Vec<&'static str>,
    },
    /// [`find_command`] of a command the node does not have.
    #[error("the {node} has no command `{command}`: {}", .known.join(", "))]
    NoCommand {
        /// The node.
        node: &'static str,
        /// The command part of the name.
        command: String,
        /// The node's commands.
        known: Vec<&'static str>,
    },
}

/// The names of the ICD's nodes, for errors.
fn node_names() -> Vec<&'static str> {
    nodes().iter().map(|n| n.name).collect()
}

/// The whole ICD as text (`m6p-twin icd`), or one node's.
pub fn to_text(node: Option<&str>) -> Result<String, IcdLookupError> {
    let list = match node {
        Some(n) => vec![node_named(n).ok_or_else(|| IcdLookupError::NoNodeNamed {
            name: n.to_owned(),
            known: node_names(),
        })?],
        None => nodes(),
    };
    let mut out = String::from(
        "Request: command u8 | data. Reply: command u8 | result u8 (1 success, 0 failure) | \
         data on success. Little-endian, IEEE-754. Offsets are from the start of the data.\n",
    );
    for n in list {
        let addrs: Vec<String> = n.addrs.iter().map(u8::to_string).collect();
        out.push_str(&format!("\n{} (CSP {})\n", n.name, addrs.join(", ")));
        for p in &n.ports {
            out.push_str(&format!("  port {} {}\n", p.port, p.name));
            if p.commands.is_empty() {
                out.push_str("    (no command table: see docs/protocol.md)\n");
            }
            for c in p.commands {
                let mut tags = Vec::new();
                if c.twin {
                    tags.push("the twin's");
                }
                if c.access == Access::NoPayloads {
                    tags.push("refused to payloads");
                }
                let tags = if tags.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", tags.join(", "))
                };
                out.push_str(&format!("    {} {}{tags}: {}\n", c.id, c.name, c.doc));
                if !c.refused.is_empty() {
                    out.push_str(&format!("      refused when: {}\n", c.refused));
                }
                data_lines("request", &c.request, &mut out);
                data_lines("reply", &c.reply, &mut out);
            }
        }
    }
    Ok(out)
}

/// The node and command named `NODE.COMMAND` (`PC.SETUP`, `FC.TMGEN`, case-insensitive),
/// with the port it is on (default number). The error lists what exists.
pub fn find_command(name: &str) -> Result<(NodeIcd, Port, &'static Command), IcdLookupError> {
    let (node, cmd) = name
        .split_once('.')
        .ok_or_else(|| IcdLookupError::NotNodeCommand {
            name: name.to_owned(),
        })?;
    let n = node_named(node).ok_or_else(|| IcdLookupError::NoNodeForCommand {
        node: node.to_owned(),
        known: node_names(),
    })?;
    for p in &n.ports {
        if let Some(c) = p.command_named(cmd) {
            return Ok((n.clone(), *p, c));
        }
    }
    Err(IcdLookupError::NoCommand {
        node: n.name,
        command: cmd.to_owned(),
        known: n
            .ports
            .iter()
            .flat_map(|p| p.commands.iter().map(|c| c.name))
            .collect(),
    })
}

/// Whether `typed` names the value `name`: case aside, and with `_` or `-` for a space
/// (`velocity_pointing`, which a command line splits less easily).
pub fn value_name_is(name: &str, typed: &str) -> bool {
    name.len() == typed.len()
        && name
            .bytes()
            .zip(typed.bytes())
            .all(|(a, b)| a.eq_ignore_ascii_case(&b) || (a == b' ' && (b == b'_' || b == b'-')))
}

/// Why an argument is not a number for its field.
#[derive(Debug, thiserror::Error)]
enum ArgNumberError {
    /// A JSON number with no `f64` (arbitrary precision).
    #[error("not a number")]
    NotF64,
    /// Text that is neither a number nor anything else the field takes.
    #[error("`{text}` is not a number")]
    Text {
        /// The text.
        text: String,
    },
    /// Text that is not a number nor one of the other forms the field takes.
    #[error("`{text}` is not a number or {}", .also.join(" or "))]
    TextNotAlso {
        /// The text.
        text: String,
        /// What else the field takes (`a duration such as "10m"`, `one of "nadir", ...`).
        also: Vec<String>,
    },
    /// An array, an object or null.
    #[error("{value} is not a number")]
    NotScalar {
        /// The value.
        value: serde_json::Value,
    },
}

/// A number for field `f` from an argument: a number, a value's name (`nadir`), or a
/// duration for a field in seconds or milliseconds (`"10m"`).
fn arg_number(f: &Field, v: &serde_json::Value) -> Result<f64, ArgNumberError> {
    match v {
        serde_json::Value::Number(n) => n.as_f64().ok_or(ArgNumberError::NotF64),
        serde_json::Value::Bool(b) => Ok(f64::from(u8::from(*b))),
        serde_json::Value::String(s) => {
            if let Some((k, _)) = f.values.iter().find(|(_, n)| value_name_is(n, s)) {
                return Ok(*k as f64);
            }
            let scale = match f.unit {
                "s" => Some(1.0),
                "ms" => Some(1000.0),
                _ => None,
            };
            if let Some(scale) = scale
                && let Ok(d) = crate::duration::parse_duration(s)
            {
                return Ok(d.as_secs_f64() * scale);
            }
            let mut also = Vec::new();
            if scale.is_some() {
                also.push("a duration such as \"10m\"".to_owned());
            }
            if !f.values.is_empty() {
                also.push(format!(
                    "one of {}",
                    f.values
                        .iter()
                        .map(|(_, n)| format!("\"{n}\""))
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
            Err(if also.is_empty() {
                ArgNumberError::Text { text: s.clone() }
            } else {
                ArgNumberError::TextNotAlso {
                    text: s.clone(),
                    also,
                }
            })
        }
        other => Err(ArgNumberError::NotScalar {
            value: other.clone(),
        }),
    }
}

/// Encode a command's request data from named arguments (the scenario's `args`, `gs`'s
/// `name=value`s): one per top-level field of its layout (an array field takes an array of
/// its count, a text field a string), then the tail's, as text, if the layout has one
/// (omitted: empty). Every value is checked against its type and the ICD's range. The
/// error names the argument (empty for the command as a whole) and says why, with the
/// range.
pub fn encode_args(
    command: &Command,
    args: &BTreeMap<String, serde_json::Value>,
) -> Result<Vec<u8>, (String, String)> {
    use csp::icd::Value;
    let whole = |m: String| (String::new(), m);
    let Some((fields, tail)) = command.request.parts() else {
        return Err(whole(format!(
            "{} takes request data of varying length: give it as `data` (hex) with `request = \"raw\"`",
            command.name
        )));
    };
    let known: Vec<&str> = fields
        .iter()
        .map(|f| f.name)
        .chain(tail.map(|t| t.name))
        .collect();
    if let Some(k) = args.keys().find(|k| !known.contains(&k.as_str())) {
        return Err((
            k.clone(),
            if known.is_empty() {
                format!("{} takes no arguments", command.name)
            } else {
                format!(
                    "{} has no argument `{k}`: {}",
                    command.name,
                    known.join(", ")
                )
            },
        ));
    }
    let mut values = Vec::new();
    for f in fields {
        let v = args.get(f.name).ok_or_else(|| {
            (
                f.name.to_owned(),
                format!(
                    "missing: {} needs {} ({}{})",
                    command.name,
                    f.name,
                    f.type_text(),
                    f.range_text().map_or(String::new(), |r| format!(", {r}"))
                ),
            )
        })?;
        let bad = |m: String| (f.name.to_owned(), m);
        if f.text {
            let serde_json::Value::String(t) = v else {
                return Err(bad("text expected".into()));
            };
            values.push(Value::Text(t.clone()));
            continue;
        }
        if matches!(f.ty, Ty::Struct(..)) {
            return Err(bad("a nested layout: give the request as raw data".into()));
        }
        let items: Vec<&serde_json::Value> = match (f.count, v) {
            (1, v) => vec![v],
            (n, serde_json::Value::Array(a)) if a.len() == n => a.iter().collect(),
            (n, _) => return Err(bad(format!("an array of {n} values expected"))),
        };
        for item in items {
            let x = arg_number(f, item).map_err(|e| bad(e.to_string()))?;
            if !f.accepts(x) {
                return Err(bad(format!(
                    "{x} is outside the ICD's range {}",
                    f.range_text().unwrap_or_default(),
                )));
            }
            values.push(if f.ty.is_integer() {
                if x.fract() != 0.0 {
                    return Err(bad(format!("{x} is not a whole number ({})", f.ty.name())));
                }
                Value::Int(x as i64)
            } else {
                Value::Float(x)
            });
        }
    }
    let mut data = csp::icd::encode(fields, &values).map_err(|e| {
        let m = e.to_string();
        let field = m.split(':').next().unwrap_or_default();
        let name = field
            .split(['[', '.'])
            .next()
            .unwrap_or_default()
            .to_owned();
        (name, m)
    })?;
    if let Some(t) = tail {
        let bytes = match args.get(t.name) {
            None => Vec::new(),
            Some(serde_json::Value::String(s)) => s.as_bytes().to_vec(),
            Some(_) => return Err((t.name.to_owned(), "text expected".into())),
        };
        if bytes.len() < t.min || bytes.len() > t.max {
            return Err((
                t.name.to_owned(),
                format!(
                    "{} bytes; the ICD allows {}..={}",
                    bytes.len(),
                    t.min,
                    t.max
                ),
            ));
        }
        data.extend(bytes);
    }
    Ok(data)
}

/// Markers around the generated tables in docs/protocol.md.
pub const MARKDOWN_BEGIN: &str = "<!-- BEGIN ICD tables: generated by `m6p-twin icd --markdown` from crates/icd/src; do not edit -->";
/// End marker.
pub const MARKDOWN_END: &str = "<!-- END ICD tables -->";

fn md_data(d: &Data) -> String {
    match *d {
        Data::None => "-".to_owned(),
        Data::Fixed(name, f) => format!("`{name}` {}", csp::icd::fields_len(f)),
        Data::Tail(_, [], t) => format!("`{}` {}..={}", t.name, t.min, t.max),
        Data::Tail(name, f, t) => format!(
            "`{name}` {} + `{}` {}..={}",
            csp::icd::fields_len(f),
            t.name,
            t.min,
            t.max
        ),
        Data::Variable(doc, lo, hi) => format!("{lo}..={hi}: {doc}"),
    }
}

fn md_fields(name: &str, fields: &'static [Field], tail: Option<csp::icd::Tail>, out: &mut String) {
    out.push_str(&format!(
        "\n`{name}` ({} bytes{}):\n\n| offset | field | type | unit | range, values | meaning |\n|---|---|---|---|---|---|\n",
        csp::icd::fields_len(fields),
        tail.map_or(String::new(), |t| format!(" + {} {}..={}", t.name, t.min, t.max))
    ));
    let mut offset = 0;
    for f in fields {
        let ty = f.type_text();
        let mut what = Vec::new();
        if let Some(r) = f.range_text() {
            what.push(r);
        }
        what.extend(f.values.iter().map(|(k, v)| format!("{k} {v}")));
        what.extend(f.bits.iter().map(|(k, v)| format!("bit {k} {v}")));
        out.push_str(&format!(
            "| {offset} | `{}` | {ty} | {} | {} | {} |\n",
            f.name,
            f.unit,
            what.join(", "),
            f.doc_line().replace('|', "\\|")
        ));
        offset += f.len();
    }
    if let Some(t) = tail {
        out.push_str(&format!(
            "| {offset} | `{}` | u8[{}..={}] | | | {} |\n",
            t.name, t.min, t.max, t.doc
        ));
    }
}

/// The ICD's tables as Markdown (docs/protocol.md, between [`MARKDOWN_BEGIN`] and
/// [`MARKDOWN_END`]).
pub fn to_markdown() -> String {
    let mut out = String::new();
    for n in nodes() {
        let addrs: Vec<String> = n.addrs.iter().map(u8::to_string).collect();
        out.push_str(&format!("\n### {} (CSP {})\n\n", n.name, addrs.join(", ")));
        out.push_str("| port | id | command | what it does | request data | reply data | payloads | origin | also refused when |\n|---|---|---|---|---|---|---|---|---|\n");
        let mut layouts: Vec<(&'static str, &'static [Field], Option<csp::icd::Tail>)> = Vec::new();
        for p in &n.ports {
            if p.commands.is_empty() {
                out.push_str(&format!(
                    "| {} {} | | (no command table) | | | | | | |\n",
                    p.port, p.name
                ));
            }
            for c in p.commands {
                out.push_str(&format!(
                    "| {} {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    p.port,
                    p.name,
                    c.id,
                    c.name,
                    c.doc.replace('|', "\\|"),
                    md_data(&c.request),
                    md_data(&c.reply),
                    if c.access == Access::Any {
                        "yes"
                    } else {
                        "refused"
                    },
                    if c.twin { "twin" } else { "ICD" },
                    c.refused.replace('|', "\\|"),
                ));
                for d in [c.request, c.reply] {
                    let entry = match d {
                        Data::Fixed(name, f) => Some((name, f, None)),
                        Data::Tail(name, f, t) if !f.is_empty() => Some((name, f, Some(t))),
                        _ => None,
                    };
                    if let Some(e) = entry
                        && !layouts.iter().any(|l| l.0 == e.0)
                    {
                        layouts.push(e);
                    }
                }
            }
        }
        // Nested layouts (TMALL's) after their parents.
        let mut i = 0;
        while i < layouts.len() {
            for f in layouts[i].1 {
                if let Ty::Struct(name, inner) = f.ty
                    && !f.text
                    && !layouts.iter().any(|l| l.0 == name)
                {
                    layouts.push((name, inner, None));
                }
            }
            i += 1;
        }
        for (name, f, t) in layouts {
            md_fields(name, f, t, &mut out);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use csp::icd::Value;

    #[test]
    fn every_node_and_command_is_described_and_unique() {
        let mut names = std::collections::BTreeSet::new();
        for n in nodes() {
            for p in &n.ports {
                let mut ids = std::collections::BTreeSet::new();
                for c in p.commands {
                    assert!(
                        ids.insert(c.id),
                        "{} port {}: id {} twice",
                        n.name,
                        p.port,
                        c.id
                    );
                    names.insert(c.name);
                }
            }
        }
        for want in [
            "TMGEN",
            "TMATP",
            "TMACD",
            "TMSENS",
            "TMRAWSENS",
            "TMALL",
            "RTCSTMSET",
            "ATCMDSET",
            "ATCTLESET",
            "SETUP",
            "STATUS",
            "ABORT",
            "TMPC",
            "FREAD",
            "SYNC",
            "POLL",
            "TMEPS",
            "CHSET",
            "THRSET",
            "TMECU",
            "FIRE",
            "TMCOMM",
            "BEACON",
            "PSET",
            "SELFTEST",
        ] {
            assert!(names.contains(want), "{want} missing");
        }
    }

    #[test]
    fn a_tmgen_reply_decodes_with_its_mode_named() {
        let map = IcdMap::defaults();
        let g = nodes_fc::wire::TmGen {
            rtc_timestamp: 1_777_000_000,
            uptime_s: 10,
            global_on_time_s: 10,
            current_mode: 3,
            current_state: 0,
            mcu_temp_c: 21,
            reset_cause: 0,
        };
        use csp::reqrep::le::Repr;
        let mut data = vec![1, 1];
        data.extend(g.to_vec());
        let d = map.decode(&csp::Header::new(3, 16, 40, 10), &data).unwrap();
        assert_eq!(
            (d.node, d.command, d.direction),
            ("FC", "TMGEN", Direction::Reply)
        );
        assert!(d.fits);
        let mode = d.fields.iter().find(|f| f.path == "current_mode").unwrap();
        assert_eq!(mode.value, Value::Int(3));
        assert_eq!(mode.show(), "3 (nadir)");
        // The request, and a SETUP with its sync message.
        let r = map.decode(&csp::Header::new(16, 3, 10, 40), &[1]).unwrap();
        assert_eq!((r.command, r.direction), ("TMGEN", Direction::Request));
        let s = map
            .decode(
                &csp::Header::new(20, 6, 10, 41),
                &[1, 1, 0, 0, 0, 0, 0x58, 2, 0, 0, 200, b'g', b'o'],
            )
            .unwrap();
        assert_eq!(s.command, "SETUP");
        let dur = s.fields.iter().find(|f| f.path == "duration_s").unwrap();
        assert_eq!(dur.show(), "600 s");
        assert_eq!(s.tail.as_deref(), Some(&b"go"[..]));
        // A failure reply has no fields; a short reply does not fit.
        let f = map
            .decode(&csp::Header::new(3, 16, 40, 10), &[1, 0])
            .unwrap();
        assert_eq!((f.result, f.fits, f.fields.len()), (Some(0), true, 0));
        let short = map
            .decode(&csp::Header::new(3, 16, 40, 10), &[1, 1, 0])
            .unwrap();
        assert!(!short.fits);
        // Not an ICD port.
        assert!(
            map.decode(&csp::Header::new(3, 16, 40, 1), &[1, 1])
                .is_none()
        );
    }

    /// The command tables are the generated ones: outside the generated section no table
    /// lays out a command's request and reply data again (they drifted before).
    #[test]
    fn docs_protocol_md_has_no_hand_written_command_tables() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/protocol.md");
        let doc = std::fs::read_to_string(path).unwrap();
        let (a, b) = (
            doc.find(MARKDOWN_BEGIN).unwrap(),
            doc.find(MARKDOWN_END).unwrap(),
        );
        let outside = format!("{}{}", &doc[..a], &doc[b..]);
        let tables: Vec<&str> = outside
            .lines()
            .filter(|l| l.starts_with('|') && l.contains("request data"))
            .collect();
        assert!(
            tables.is_empty(),
            "hand-written command tables in docs/protocol.md (the generated section has them): {tables:?}"
        );
    }

    /// Rust paths (`role::PRIMARY`), constants' names (`BEACON_PERIOD_MIN_S`) and rustdoc's
    /// links (``[`TargetMode`]``) in backticks: what doc comments leak into the ICD's text if
    /// written for rustdoc.
    fn rust_items(text: &str) -> Vec<&str> {
        let screaming = |w: &str| {
            w.starts_with(|c: char| c.is_ascii_uppercase())
                && w.contains('_')
                && w.chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        };
        let links = text
            .match_indices("[`")
            .filter_map(|(i, _)| text[i + 2..].split_once("`]").map(|(item, _)| item))
            .filter(|item| !item.contains('\n'));
        text.lines()
            .flat_map(|l| l.split('`').skip(1).step_by(2))
            .filter(|s| {
                s.contains("::")
                    || s.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                        .any(screaming)
            })
            .chain(links)
            .collect()
    }

    /// `m6p-twin icd` (text, `--json`, `--markdown`) is for people: it names values and
    /// their meanings, never the Rust items behind them.
    #[test]
    fn the_icd_text_names_no_rust_items() {
        assert_eq!(
            rust_items(
                "`role::PRIMARY` or 2\n0 or `BEACON_PERIOD_MIN_S`..=`3600` (`TMGEN`, `r_eci_m`), [`TargetMode`]"
            ),
            ["role::PRIMARY", "BEACON_PERIOD_MIN_S", "TargetMode"]
        );
        let text = to_text(None).unwrap();
        for (what, text) in [
            ("icd --json", to_json()),
            ("icd", text),
            ("icd --markdown", to_markdown()),
        ] {
            let found = rust_items(&text);
            assert!(
                found.is_empty(),
                "Rust items in `m6p-twin {what}` (write the value and its meaning): {found:?}"
            );
        }
    }

    #[test]
    fn the_python_package_carries_the_current_icd() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../python/src/m6p/icd.json");
        let have = std::fs::read_to_string(path).unwrap();
        assert!(
            have.trim_end() == to_json().trim_end(),
            "python/src/m6p/icd.json is not `m6p-twin icd --json`: run tools/icd-docs.sh"
        );
    }

    #[test]
    fn docs_protocol_md_has_the_generated_tables() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/protocol.md");
        let doc = std::fs::read_to_string(path).unwrap();
        let a = doc
            .find(MARKDOWN_BEGIN)
            .expect("the BEGIN marker in docs/protocol.md");
        let b = doc
            .find(MARKDOWN_END)
            .expect("the END marker in docs/protocol.md");
        let have = &doc[a + MARKDOWN_BEGIN.len()..b];
        let want = format!("\n{}\n", to_markdown());
        assert!(
            have == want,
            "docs/protocol.md's ICD tables are not what the code generates: run tools/icd-docs.sh"
        );
    }

    fn args(v: serde_json::Value) -> BTreeMap<String, serde_json::Value> {
        serde_json::from_value(v).unwrap()
    }

    #[test]
    fn typed_arguments_encode_with_units_names_and_ranges() {
        let (n, p, setup) = find_command("pc.setup").unwrap();
        assert_eq!((n.name, p.port, setup.id), ("PC", 10, 1));
        let ok = encode_args(
            setup,
            &args(
                serde_json::json!({"session_id": 1, "timestamp": "now", "duration_s": "10m",
                "max_packets": 0, "poll_frame_size": 200, "sync_message": "go"}),
            ),
        )
        .unwrap();
        assert_eq!(ok, [1, 0, 0, 0, 0, 0x58, 2, 0, 0, 200, b'g', b'o']);
        // A value's name with `_` (or `-`) for its spaces, in any case.
        let (_, _, mode) = find_command("FC.ATCMDSET").unwrap();
        for typed in [
            "velocity pointing",
            "velocity_pointing",
            "Velocity-Pointing",
        ] {
            assert_eq!(
                encode_args(mode, &args(serde_json::json!({"mode": typed}))),
                Ok(vec![2])
            );
        }
        assert!(
            encode_args(
                mode,
                &args(serde_json::json!({"mode": "velocity__pointing"}))
            )
            .is_err()
        );
        let e = encode_args(
            setup,
            &args(
                serde_json::json!({"session_id": 1, "timestamp": 0, "duration_s": 1000,
                "max_packets": 0, "poll_frame_size": 200}),
            ),
        )
        .unwrap_err();
        assert_eq!(e.0, "duration_s");
        assert!(e.1.contains("outside the ICD's range 5..=900"), "{}", e.1);
        let e = encode_args(setup, &args(serde_json::json!({"session_id": 1}))).unwrap_err();
        assert_eq!(e.0, "timestamp");
        let e = encode_args(setup, &args(serde_json::json!({"sesion_id": 1}))).unwrap_err();
        assert!(e.1.contains("no argument `sesion_id`"), "{}", e.1);
        let (_, _, mode) = find_command("FC.ATCMDSET").unwrap();
        assert_eq!(
            encode_args(mode, &args(serde_json::json!({"mode": "nadir"}))).unwrap(),
            [3]
        );
        let e = encode_args(mode, &args(serde_json::json!({"mode": "nadirr"}))).unwrap_err();
        assert!(e.1.contains("\"nadir\""), "{}", e.1);
        let (_, _, att) = find_command("FC.ATCATSET").unwrap();
        assert_eq!(
            encode_args(att, &args(serde_json::json!({"q": [1, 0, 0, 0]})))
                .unwrap()
                .len(),
            32
        );
        let (_, _, tmgen) = find_command("FC.TMGEN").unwrap();
        assert!(encode_args(tmgen, &BTreeMap::new()).unwrap().is_empty());
        let e = find_command("FC.NOPE").unwrap_err();
        assert!(
            matches!(&e, IcdLookupError::NoCommand { node: "FC", command, known }
                if command == "NOPE" && known.contains(&"TMGEN")),
            "{e:?}"
        );
        assert!(
            e.to_string().starts_with("the FC has no command `NOPE`: "),
            "{e}"
        );
        assert!(e.to_string().contains("TMGEN"), "{e}");
        let e = find_command("XX.TMGEN").unwrap_err().to_string();
        assert!(e.starts_with("no node `XX`: ") && e.contains("FC"), "{e}");
        assert_eq!(
            find_command("tmgen").unwrap_err().to_string(),
            "`tmgen` is not NODE.COMMAND (for example FC.TMGEN; `m6p-twin icd` lists them)"
        );
    }

    #[test]
    fn the_payload_port_agrees_with_the_simulated_payload() {
        use csp::reqrep::CommandSet;
        let bad = csp::icd::range_disagreements(&nodes_pc::wire::ICD_PAYLOAD, |c, d| {
            let mut b = vec![c];
            b.extend_from_slice(d);
            nodes_payload::wire::PayloadCommand::parse(&csp::reqrep::Request::parse(&b).unwrap())
                .is_ok()
        });
        assert!(bad.is_empty(), "{bad:#?}");
    }

    /// Every range and gap of an integer field is written as integers (`[1, 63]`, not
    /// `[1.0, 63.0]`, which consumers with integer types refuse), a float field's as
    /// numbers.
    #[test]
    fn json_ranges_of_integer_fields_are_integers() {
        fn walk(fields: &serde_json::Value, seen: &mut (usize, usize)) {
            for f in fields.as_array().into_iter().flatten() {
                let float = matches!(f["type"].as_str(), Some("f32" | "f64"));
                for key in ["range", "except"] {
                    for b in f[key].as_array().into_iter().flatten() {
                        if float {
                            seen.1 += 1;
                        } else {
                            assert!(b.is_i64() || b.is_u64(), "{}: {key} {b}", f["name"]);
                            seen.0 += 1;
                        }
                    }
                }
                walk(&f["fields"], seen);
            }
        }
        let j: serde_json::Value = serde_json::from_str(&to_json()).unwrap();
        let mut seen = (0, 0);
        for n in j["nodes"].as_array().unwrap() {
            for p in n["ports"].as_array().unwrap() {
                for c in p["commands"].as_array().unwrap() {
                    walk(&c["request"]["fields"], &mut seen);
                }
            }
        }
        assert!(seen.0 > 20, "integer bounds seen: {seen:?}");
        let setup = serde_json::to_string(&j).unwrap();
        assert!(setup.contains(r#""range":[1,63]"#), "PC SETUP's session_id");
    }

    #[test]
    fn the_json_has_every_node_and_the_text_every_command() {
        let j: serde_json::Value = serde_json::from_str(&to_json()).unwrap();
        assert_eq!(j["format"], 1);
        let nodes_j = j["nodes"].as_array().unwrap();
        assert_eq!(nodes_j.len(), nodes().len());
        let fc = nodes_j.iter().find(|n| n["name"] == "FC").unwrap();
        let tmgen = &fc["ports"][0]["commands"][0];
        assert_eq!(tmgen["name"], "TMGEN");
        assert_eq!(tmgen["reply"]["max_bytes"], 16);
        assert_eq!(tmgen["reply"]["fields"][3]["name"], "current_mode");
        assert_eq!(tmgen["reply"]["fields"][3]["offset"], 12);
        assert_eq!(tmgen["reply"]["fields"][3]["values"]["3"], "nadir");
        let text = to_text(None).unwrap();
        for n in nodes() {
            for p in &n.ports {
                for c in p.commands {
                    assert!(
                        text.contains(&format!(" {} {}", c.id, c.name)),
                        "{}",
                        c.name
                    );
                }
            }
        }
        assert!(to_text(Some("eps")).unwrap().contains("THRSET"));
        assert!(
            to_text(Some("ecu"))
                .unwrap()
                .contains("refused when: 0 ms; longer than max_burn")
        );
        assert!(fc["ports"][0]["commands"][0].get("refused_when").is_none());
        let md = to_markdown();
        assert!(
            md.contains(
                "| 10 telemetry | 1 | TMGEN | general telemetry | - | `TmGen` 16 | yes | ICD |  |"
            ),
            "{md}"
        );
        assert!(
            md.contains("| 12 | `current_mode` | u8 |  | 0 idle, 1 detumble"),
            "{md}"
        );
        let e = to_text(Some("nope")).unwrap_err().to_string();
        assert!(
            e.starts_with("no node \"nope\": the nodes are ") && e.contains("FC"),
            "{e}"
        );
    }

    /// A run's map names the payload of each of its PC's sessions (what the recorder's
    /// session summaries say); the default map, the default PC's.
    #[test]
    fn the_map_knows_the_payload_of_each_pc_session() {
        let defaults = IcdMap::defaults();
        assert_eq!(defaults.pc_session_payload(1), Some(12));
        assert_eq!(defaults.pc_session_payload(2), Some(13));
        assert_eq!(defaults.pc_session_payload(3), None);
        let pc = nodes_pc::PcConfig {
            sessions: vec![
                nodes_pc::SessionSpec::buffering(7, 15),
                nodes_pc::SessionSpec::polling(1, 14),
            ],
            ..nodes_pc::PcConfig::default()
        };
        let map = IcdMap::for_nodes(&NodePorts {
            seed: 1,
            fc: &nodes_fc::FcConfig::default(),
            pc: &pc,
            eps: &nodes_eps::EpsConfig::default(),
            ecu: &nodes_ecu::EcuConfig::default(),
            comm: &nodes_comm::CommConfig::default(),
        });
        assert_eq!(map.pc_session_payload(7), Some(15));
        assert_eq!(map.pc_session_payload(1), Some(14));
        assert_eq!(map.pc_session_payload(2), None);
    }
}
