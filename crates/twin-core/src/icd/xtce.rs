//! `m6p-twin icd --xtce`: the ICD as an XTCE 1.2 mission database, for mission control
//! software that imports XTCE (YAMCS, OpenC3 COSMOS), made from the same tables as
//! `icd --json`.
//!
//! The shape follows YAMCS's CSP support (`org.yamcs.tctm.csp`, CSP 1.x, big-endian header)
//! and yamcs-pymdb's CSP header, and is described in docs/operations.md:
//! - one space system `M6P`: the CSP header as parameters (`csp_pri` .. `csp_crc`, the
//!   4 reserved bits skipped), the ICD framing `command` and `result`; the root container
//!   `csp_packet` and its child `reply`; the abstract commands `csp_command` (the header as
//!   arguments, with mission control's own address [`GROUND_ADDR`] and reply port
//!   [`GROUND_PORT`] as defaults) and `icd_command` (plus the command byte);
//! - a space system per node (`/M6P/FC`), a command per ICD command (`/M6P/FC/TMGEN`) whose
//!   destination (single-address nodes), port and command id are assigned, and whose
//!   arguments are the request's fields in wire order;
//! - a space system per command (`/M6P/FC/TMGEN`) with the reply's fields as parameters
//!   and a container `reply` taken when the source address, source port, command and
//!   `result = success` match. The FC's periodic telemetry (TMPERSET) leaves from the FC's
//!   own port, an ephemeral one, so the FC's telemetry replies also match from a source
//!   port at or above [`csp::header::EPHEMERAL_PORT_MIN`]. Its failure reply is the
//!   container `failure` beside it; a command completes (YAMCS's verifier) when its `reply`
//!   comes within 10 s.
//!
//! Fields: integers wider than a byte and floats little-endian; `count > 1` an array; text
//! a fixed string; a nested layout an aggregate; a request field's range a valid range (one
//! range: the `except` holes are in the description, and the twin refuses them); named
//! values an enumeration when they name the whole range, or at least two values and there
//! is no range; a tail or a layout of varying length a binary of the bytes that remain.
//! The CRC32 of a CRC-flagged packet is the link's (YAMCS's `CspPacketPreprocessor` checks
//! it, `CspCommandPostprocessor` appends it), never a field here.

use std::fmt::Write as _;

use csp::icd::{Command, Data, Field, Port, Ty};

use super::{NodeIcd, nodes};

/// Mission control's CSP address: a ground address no simulated station takes by default,
/// the UDP link's (`--udp`).
pub const GROUND_ADDR: u8 = 17;
/// The source port of mission control's commands, where the replies come back.
pub const GROUND_PORT: u8 = 40;
/// The XTCE 1.2 namespace.
pub const NAMESPACE: &str = "http://www.omg.org/spec/XTCE/20180204";

/// The commands whose replies a node also sends unasked, from its own (ephemeral) port:
/// the FC's telemetry port (TMPERSET sends TMGEN..TMALL).
fn pushed(node: &NodeIcd, port: &Port) -> bool {
    node.addrs == [platform::addr::FC] && port.port == nodes_fc::wire::ICD_TELEMETRY.port
}

/// What the generator made: the XML and how many commands and reply containers it holds.
#[derive(Debug, Clone)]
pub struct Xtce {
    /// The mission database.
    pub xml: String,
    /// Commands (one per ICD command of every node).
    pub commands: usize,
    /// Reply containers (one per ICD command of every node).
    pub replies: usize,
}

/// The whole ICD as an XTCE 1.2 document.
pub fn to_xtce() -> Xtce {
    let mut x = Xml::default();
    x.raw("<?xml version=\"1.0\" encoding=\"UTF-8\"?>");
    x.raw(
        // No double hyphen in an XML comment.
        "<!-- Made by `m6p-twin icd` (XTCE) from the twin's ICD tables, as its JSON is: \
         regenerate it rather than edit it (docs/operations.md). -->",
    );
    x.open(
        "SpaceSystem",
        &[("xmlns", NAMESPACE.into()), ("name", "M6P".into())],
    );
    header_tm(&mut x);
    header_tc(&mut x);
    let (mut commands, mut replies) = (0, 0);
    for node in nodes() {
        x.open("SpaceSystem", &[("name", node.name.into())]);
        let mut types = Types::new(Side::Command);
        let mut cmds = Xml::at(x.depth + 2);
        for port in &node.ports {
            for c in port.commands {
                command(&mut cmds, &mut types, &node, port, c);
                commands += 1;
            }
        }
        if !cmds.out.is_empty() {
            x.open("CommandMetaData", &[]);
            if !types.xml.out.is_empty() {
                x.open("ArgumentTypeSet", &[]);
                x.out.push_str(&types.xml.out);
                x.close("ArgumentTypeSet");
            }
            x.open("MetaCommandSet", &[]);
            x.out.push_str(&cmds.out);
            x.close("MetaCommandSet");
            x.close("CommandMetaData");
        }
        for port in &node.ports {
            for c in port.commands {
                reply(&mut x, &node, port, c);
                replies += 1;
            }
        }
        x.close("SpaceSystem");
    }
    x.close("SpaceSystem");
    Xtce {
        xml: x.out,
        commands,
        replies,
    }
}

/// The CSP header and the ICD framing as telemetry: parameters, `csp_packet` and `reply`.
fn header_tm(x: &mut Xml) {
    x.open("TelemetryMetaData", &[]);
    x.open("ParameterTypeSet", &[]);
    header_types(x, Side::Telemetry);
    x.open("EnumeratedParameterType", &[("name", "result_t".into())]);
    x.leaf("IntegerDataEncoding", &int_encoding(8, false));
    enumeration(
        x,
        &[(0, Outcome::Failure.label()), (1, Outcome::Success.label())],
    );
    x.close("EnumeratedParameterType");
    x.close("ParameterTypeSet");
    x.open("ParameterSet", &[]);
    for (name, ty, doc) in HEADER_FIELDS {
        parameter(x, name, ty, doc);
    }
    parameter(
        x,
        "command",
        "u8_t",
        "ICD command id (the reply repeats it)",
    );
    parameter(x, "result", "result_t", "ICD result: 1 success, 0 failure");
    x.close("ParameterSet");
    x.open("ContainerSet", &[]);
    x.open(
        "SequenceContainer",
        &named(
            "csp_packet",
            "A CSP 1.x packet: the 32-bit header, big-endian",
        ),
    );
    x.open("EntryList", &[]);
    for (name, ..) in HEADER_FIELDS {
        if name == "csp_hmac" {
            // After the 4 reserved bits.
            x.open("ParameterRefEntry", &[("parameterRef", name.into())]);
            x.open(
                "LocationInContainerInBits",
                &[("referenceLocation", "previousEntry".into())],
            );
            x.text("FixedValue", "4");
            x.close("LocationInContainerInBits");
            x.close("ParameterRefEntry");
        } else {
            x.leaf("ParameterRefEntry", &[("parameterRef", name.into())]);
        }
    }
    x.close("EntryList");
    x.close("SequenceContainer");
    x.open(
        "SequenceContainer",
        &named("reply", "An ICD reply: command u8, result u8, data"),
    );
    x.open("EntryList", &[]);
    x.leaf("ParameterRefEntry", &[("parameterRef", "command".into())]);
    x.leaf("ParameterRefEntry", &[("parameterRef", "result".into())]);
    x.close("EntryList");
    x.leaf("BaseContainer", &[("containerRef", "csp_packet".into())]);
    x.close("SequenceContainer");
    x.close("ContainerSet");
    x.close("TelemetryMetaData");
}

/// The header's types, on either `side`: unsigned integers of 2, 5, 6
/// and 8 bits (big-endian bit fields) and a 1-bit flag.
fn header_types(x: &mut Xml, side: Side) {
    let kind = side.type_word();
    for (name, bits) in [("u2_t", 2), ("u5_t", 5), ("u6_t", 6), ("u8_t", 8)] {
        let tag = format!("Integer{kind}Type");
        x.open(
            &tag,
            &[
                ("name", name.into()),
                ("signed", "false".into()),
                ("sizeInBits", bits.to_string()),
            ],
        );
        x.leaf("IntegerDataEncoding", &int_encoding(bits, false));
        x.close(&tag);
    }
    let tag = format!("Boolean{kind}Type");
    x.open(&tag, &[("name", "flag_t".into())]);
    x.leaf("IntegerDataEncoding", &int_encoding(1, false));
    x.close(&tag);
}

/// The CSP header's fields in wire order (after `csp_sport`, 4 reserved bits).
const HEADER_FIELDS: [(&str, &str, &str); 9] = [
    ("csp_pri", "u2_t", "CSP priority (0 critical .. 3 low)"),
    ("csp_src", "u5_t", "CSP source address"),
    ("csp_dst", "u5_t", "CSP destination address"),
    ("csp_dport", "u6_t", "CSP destination port"),
    ("csp_sport", "u6_t", "CSP source port"),
    ("csp_hmac", "flag_t", "CSP HMAC flag"),
    ("csp_xtea", "flag_t", "CSP XTEA flag"),
    ("csp_rdp", "flag_t", "CSP RDP flag"),
    (
        "csp_crc",
        "flag_t",
        "CSP CRC32 flag (the link checks and appends the CRC)",
    ),
];

/// The CSP header as command arguments: `csp_command`, and `icd_command` with the command
/// byte.
fn header_tc(x: &mut Xml) {
    x.open("CommandMetaData", &[]);
    x.open("ArgumentTypeSet", &[]);
    header_types(x, Side::Command);
    x.close("ArgumentTypeSet");
    x.open("MetaCommandSet", &[]);
    x.open(
        "MetaCommand",
        &[("name", "csp_command".into()), ("abstract", "true".into())],
    );
    x.open("ArgumentList", &[]);
    for (name, ty, doc) in HEADER_FIELDS {
        let initial = match name {
            "csp_pri" => Some("2".to_owned()),
            "csp_src" => Some(GROUND_ADDR.to_string()),
            "csp_sport" => Some(GROUND_PORT.to_string()),
            "csp_hmac" | "csp_xtea" | "csp_rdp" | "csp_crc" => Some("False".to_owned()),
            _ => None,
        };
        let mut attrs = vec![
            ("name", name.into()),
            ("argumentTypeRef", ty.into()),
            ("shortDescription", doc.into()),
        ];
        if let Some(v) = initial {
            attrs.push(("initialValue", v));
        }
        x.leaf("Argument", &attrs);
    }
    x.close("ArgumentList");
    x.open("CommandContainer", &[("name", "csp_command".into())]);
    x.open("EntryList", &[]);
    for (name, ..) in HEADER_FIELDS {
        if name == "csp_hmac" {
            x.leaf(
                "FixedValueEntry",
                &[
                    ("name", "csp_reserved".into()),
                    ("binaryValue", "00".into()),
                    ("sizeInBits", "4".into()),
                ],
            );
        }
        x.leaf("ArgumentRefEntry", &[("argumentRef", name.into())]);
    }
    x.close("EntryList");
    x.close("CommandContainer");
    x.close("MetaCommand");
    x.open(
        "MetaCommand",
        &[("name", "icd_command".into()), ("abstract", "true".into())],
    );
    x.leaf(
        "BaseMetaCommand",
        &[("metaCommandRef", "csp_command".into())],
    );
    x.open("ArgumentList", &[]);
    x.leaf(
        "Argument",
        &[
            ("name", "command".into()),
            ("argumentTypeRef", "u8_t".into()),
            ("shortDescription", "ICD command id".into()),
        ],
    );
    x.close("ArgumentList");
    x.open("CommandContainer", &[("name", "icd_command".into())]);
    x.open("EntryList", &[]);
    x.leaf("ArgumentRefEntry", &[("argumentRef", "command".into())]);
    x.close("EntryList");
    x.leaf("BaseContainer", &[("containerRef", "csp_command".into())]);
    x.close("CommandContainer");
    x.close("MetaCommand");
    x.close("MetaCommandSet");
    x.close("CommandMetaData");
}

/// One ICD command as a MetaCommand of its node.
fn command(x: &mut Xml, types: &mut Types, node: &NodeIcd, port: &Port, c: &Command) {
    x.open(
        "MetaCommand",
        &[("name", c.name.into()), ("shortDescription", describe(c))],
    );
    x.open(
        "BaseMetaCommand",
        &[("metaCommandRef", "/M6P/icd_command".into())],
    );
    x.open("ArgumentAssignmentList", &[]);
    // A node of several addresses (COMM 1-2, payloads 12-15) takes `csp_dst` as an argument.
    let mut assign = Vec::new();
    if let [addr] = node.addrs[..] {
        assign.push(("csp_dst", addr));
    }
    assign.extend([("csp_dport", port.port), ("command", c.id)]);
    for (name, v) in assign {
        x.leaf(
            "ArgumentAssignment",
            &[
                ("argumentName", name.into()),
                ("argumentValue", v.to_string()),
            ],
        );
    }
    x.close("ArgumentAssignmentList");
    x.close("BaseMetaCommand");
    let (fields, tail) = data_parts(&c.request);
    let prefix = c.name;
    let mut args = Vec::new();
    for f in fields {
        let ty = types.field(&format!("{prefix}_{}", f.name), f);
        args.push((f.name, ty, describe_field(f), None));
    }
    if let Some((name, doc, min)) = tail {
        let ty = types.remaining(&format!("{prefix}_{name}"));
        let initial = (min == 0).then(String::new);
        args.push((name, ty, doc.to_owned(), initial));
    }
    if !args.is_empty() {
        x.open("ArgumentList", &[]);
        for (name, ty, doc, initial) in &args {
            let mut attrs = vec![("name", (*name).into()), ("argumentTypeRef", ty.clone())];
            if !doc.is_empty() {
                attrs.push(("shortDescription", doc.clone()));
            }
            if let Some(v) = initial {
                attrs.push(("initialValue", v.clone()));
            }
            x.leaf("Argument", &attrs);
        }
        x.close("ArgumentList");
    }
    x.open("CommandContainer", &[("name", c.name.into())]);
    entries(
        x,
        "ArgumentRefEntry",
        "argumentRef",
        args.iter().map(|a| a.0),
    );
    x.leaf(
        "BaseContainer",
        &[("containerRef", "/M6P/icd_command".into())],
    );
    x.close("CommandContainer");
    verifier(x, node, c);
    x.close("MetaCommand");
}

/// A command completes when its success reply comes within [`VERIFY_WINDOW`], and fails
/// when none does (YAMCS's `yamcs.onTimeout`). No failed verifier: YAMCS 5.13 keeps one
/// running after completion, so a later command's failure reply would turn a completed
/// command to failed; the failure reply is on the command's `failure` container instead.
fn verifier(x: &mut Xml, node: &NodeIcd, c: &Command) {
    x.open("VerifierSet", &[]);
    x.open("CompleteVerifier", &[]);
    x.open("AncillaryDataSet", &[]);
    x.text_with(
        "AncillaryData",
        &[("name", "yamcs.onTimeout".into())],
        "FAIL",
    );
    x.close("AncillaryDataSet");
    x.leaf(
        "ContainerRef",
        &[(
            "containerRef",
            format!("/M6P/{}/{}/reply", node.name, c.name),
        )],
    );
    x.leaf(
        "CheckWindow",
        &[
            ("timeToStopChecking", VERIFY_WINDOW.into()),
            ("timeWindowIsRelativeTo", "timeLastVerifierPassed".into()),
        ],
    );
    x.close("CompleteVerifier");
    x.close("VerifierSet");
}

/// How long a command waits for its reply (XML duration): the ground's default timeout
/// of a command over UHF.
const VERIFY_WINDOW: &str = "PT10S";

/// One ICD command's reply: a space system named after the command with the reply's
/// fields and its container `reply`.
fn reply(x: &mut Xml, node: &NodeIcd, port: &Port, c: &Command) {
    let (fields, tail) = data_parts(&c.reply);
    let mut types = Types::new(Side::Telemetry);
    let mut params = Vec::new();
    for f in fields {
        let ty = types.field(f.name, f);
        params.push((f.name, ty, describe_field(f)));
    }
    if let Some((name, doc, _)) = tail {
        params.push((name, types.remaining(name), doc.to_owned()));
    }
    x.open("SpaceSystem", &[("name", c.name.into())]);
    x.open("TelemetryMetaData", &[]);
    if !types.xml.out.is_empty() {
        x.open("ParameterTypeSet", &[]);
        x.out.push_str(&types.xml.out);
        x.close("ParameterTypeSet");
    }
    if !params.is_empty() {
        x.open("ParameterSet", &[]);
        for (name, ty, doc) in &params {
            parameter(x, name, ty, doc);
        }
        x.close("ParameterSet");
    }
    x.open("ContainerSet", &[]);
    x.open(
        "SequenceContainer",
        &named("reply", &format!("{} reply", c.name)),
    );
    entries(
        x,
        "ParameterRefEntry",
        "parameterRef",
        params.iter().map(|p| p.0),
    );
    x.open("BaseContainer", &[("containerRef", "/M6P/reply".into())]);
    restriction(x, node, port, c, Outcome::Success);
    x.close("BaseContainer");
    x.close("SequenceContainer");
    x.open(
        "SequenceContainer",
        &named("failure", &format!("{} failure reply", c.name)),
    );
    x.leaf("EntryList", &[]);
    x.open("BaseContainer", &[("containerRef", "/M6P/reply".into())]);
    restriction(x, node, port, c, Outcome::Failure);
    x.close("BaseContainer");
    x.close("SequenceContainer");
    x.close("ContainerSet");
    x.close("TelemetryMetaData");
    x.close("SpaceSystem");
}

/// The conditions of a reply container: the node's address(es), the command's port (or,
/// for pushed telemetry, an ephemeral port), the command id and the result (`success` or
/// `failure`).
fn restriction(x: &mut Xml, node: &NodeIcd, port: &Port, c: &Command, result: Outcome) {
    x.open("RestrictionCriteria", &[]);
    x.open("BooleanExpression", &[]);
    x.open("ANDedConditions", &[]);
    match node.addrs[..] {
        [addr] => condition(x, "csp_src", "==", &addr.to_string()),
        _ => {
            let lo = node.addrs.iter().min().copied().unwrap_or_default();
            let hi = node.addrs.iter().max().copied().unwrap_or_default();
            condition(x, "csp_src", ">=", &lo.to_string());
            condition(x, "csp_src", "<=", &hi.to_string());
        }
    }
    if pushed(node, port) {
        x.open("ORedConditions", &[]);
        condition(x, "csp_sport", "==", &port.port.to_string());
        condition(
            x,
            "csp_sport",
            ">=",
            &csp::header::EPHEMERAL_PORT_MIN.to_string(),
        );
        x.close("ORedConditions");
    } else {
        condition(x, "csp_sport", "==", &port.port.to_string());
    }
    condition(x, "command", "==", &c.id.to_string());
    condition(x, "result", "==", result.label());
    x.close("ANDedConditions");
    x.close("BooleanExpression");
    x.close("RestrictionCriteria");
}

fn condition(x: &mut Xml, param: &str, op: &str, value: &str) {
    x.open("Condition", &[]);
    x.leaf(
        "ParameterInstanceRef",
        &[("parameterRef", format!("/M6P/{param}"))],
    );
    x.text("ComparisonOperator", op);
    x.text("Value", value);
    x.close("Condition");
}

/// An entry list of references (`tag`, its attribute `attr`) to `names`, in order.
fn entries<'n>(x: &mut Xml, tag: &str, attr: &'static str, names: impl Iterator<Item = &'n str>) {
    let names: Vec<&str> = names.collect();
    if names.is_empty() {
        x.leaf("EntryList", &[]);
        return;
    }
    x.open("EntryList", &[]);
    for name in names {
        x.leaf(tag, &[(attr, name.into())]);
    }
    x.close("EntryList");
}

/// The attributes of a named, described element.
fn named(name: &str, doc: &str) -> [(&'static str, String); 2] {
    [("name", name.into()), ("shortDescription", doc.into())]
}

fn parameter(x: &mut Xml, name: &str, ty: &str, doc: &str) {
    let mut attrs = vec![("name", name.into()), ("parameterTypeRef", ty.into())];
    if !doc.is_empty() {
        attrs.push(("shortDescription", doc.into()));
    }
    x.leaf("Parameter", &attrs);
}

/// The fixed fields of `d` and its tail (name, doc, fewest bytes): a layout of varying
/// length is all tail.
fn data_parts(
    d: &Data,
) -> (
    &'static [Field],
    Option<(&'static str, &'static str, usize)>,
) {
    match *d {
        Data::None => (&[], None),
        Data::Fixed(_, f) => (f, None),
        Data::Tail(_, f, t) => (f, Some((t.name, t.doc, t.min))),
        Data::Variable(doc, min, _) => (&[], Some(("data", doc, min))),
    }
}

fn describe(c: &Command) -> String {
    let mut s = one_line(c.doc);
    if c.twin {
        s.push_str(" (the twin's own command, not in the ICD)");
    }
    s
}

fn describe_field(f: &Field) -> String {
    let mut s = f.doc_line();
    if let Some(r) = f.range_text() {
        let _ = write!(s, " Accepted: {r}.");
    }
    if !f.bits.is_empty() {
        let bits: Vec<String> = f.bits.iter().map(|(b, n)| format!("{b} {n}")).collect();
        let _ = write!(s, " Bits: {}.", bits.join(", "));
    }
    if !f.values.is_empty() && !is_enum(f) {
        let v: Vec<String> = f.values.iter().map(|(k, n)| format!("{k} {n}")).collect();
        let _ = write!(s, " Values: {}.", v.join(", "));
    }
    s
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Whether a field's named values make it an enumeration: they name every value of its
/// range, or (no range) at least two values. One named value (0 = "off") marks a special
/// value of a number.
fn is_enum(f: &Field) -> bool {
    if f.values.is_empty() || !f.bits.is_empty() || !f.unit.is_empty() || !f.ty.is_integer() {
        return false;
    }
    match f.range {
        Some((lo, hi)) => {
            let named = |v: i64| f.values.iter().any(|(k, _)| *k == v);
            (lo as i64..=hi as i64).all(named)
        }
        None => f.values.len() >= 2,
    }
}

/// Which half of the database a type belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    /// A command's argument types (`...ArgumentType`).
    Command,
    /// A reply's parameter types (`...ParameterType`).
    Telemetry,
}

impl Side {
    /// The word XTCE's type names carry (`IntegerArgumentType`, `IntegerParameterType`).
    fn type_word(self) -> &'static str {
        match self {
            Side::Command => "Argument",
            Side::Telemetry => "Parameter",
        }
    }
}

/// An ICD reply's result byte, as the database names its values.
#[derive(Debug, Clone, Copy)]
enum Outcome {
    Success,
    Failure,
}

impl Outcome {
    fn label(self) -> &'static str {
        match self {
            Outcome::Success => "success",
            Outcome::Failure => "failure",
        }
    }
}

/// The XTCE types of one command's arguments or one reply's parameters.
struct Types {
    /// `Argument` or `Parameter`.
    side: Side,
    xml: Xml,
}

impl Types {
    fn new(side: Side) -> Types {
        Types {
            side,
            xml: Xml::at(match side {
                Side::Command => 4,
                Side::Telemetry => 5,
            }),
        }
    }

    /// The type of field `f` named after `name` (`name_t`), with its element and member
    /// types; returns its name.
    fn field(&mut self, name: &str, f: &Field) -> String {
        if f.text {
            return self.string(&format!("{name}_t"), f.count);
        }
        let el = match f.ty {
            Ty::Struct(_, members) => {
                let mut list = Vec::new();
                for m in members {
                    list.push((m.name, self.field(&format!("{name}_{}", m.name), m)));
                }
                let agg = format!("{name}_agg_t");
                self.aggregate(&agg, &list);
                agg
            }
            _ => {
                let n = if f.count > 1 {
                    format!("{name}_el_t")
                } else {
                    format!("{name}_t")
                };
                self.scalar(&n, f);
                n
            }
        };
        if f.count > 1 {
            let arr = format!("{name}_t");
            self.array(&arr, &el, f.count);
            arr
        } else {
            el
        }
    }

    fn scalar(&mut self, name: &str, f: &Field) {
        let k = self.side.type_word();
        let x = &mut self.xml;
        let range = (self.side == Side::Command).then_some(f.range).flatten();
        let unit = |x: &mut Xml| {
            if !f.unit.is_empty() {
                x.open("UnitSet", &[]);
                x.text("Unit", f.unit);
                x.close("UnitSet");
            }
        };
        match f.ty {
            Ty::F32 | Ty::F64 => {
                let bits = f.ty.size() * 8;
                let tag = format!("Float{k}Type");
                x.open(
                    &tag,
                    &[("name", name.into()), ("sizeInBits", bits.to_string())],
                );
                unit(x);
                x.leaf(
                    "FloatDataEncoding",
                    &[
                        ("sizeInBits", bits.to_string()),
                        ("encoding", "IEEE754_1985".into()),
                        ("byteOrder", "leastSignificantByteFirst".into()),
                    ],
                );
                if let Some((lo, hi)) = range {
                    valid_range(x, &format!("{lo:?}"), &format!("{hi:?}"));
                }
                x.close(&tag);
            }
            _ if is_enum(f) => {
                let tag = format!("Enumerated{k}Type");
                x.open(&tag, &[("name", name.into())]);
                x.leaf(
                    "IntegerDataEncoding",
                    &int_encoding(f.ty.size() * 8, signed(f.ty)),
                );
                enumeration(x, f.values);
                x.close(&tag);
            }
            _ => {
                let bits = f.ty.size() * 8;
                let tag = format!("Integer{k}Type");
                x.open(
                    &tag,
                    &[
                        ("name", name.into()),
                        ("signed", signed(f.ty).to_string()),
                        ("sizeInBits", bits.to_string()),
                    ],
                );
                unit(x);
                x.leaf("IntegerDataEncoding", &int_encoding(bits, signed(f.ty)));
                if let Some((lo, hi)) = range {
                    valid_range(x, &(lo as i64).to_string(), &(hi as i64).to_string());
                }
                x.close(&tag);
            }
        }
    }

    fn string(&mut self, name: &str, chars: usize) -> String {
        let tag = format!("String{}Type", self.side.type_word());
        let x = &mut self.xml;
        x.open(&tag, &[("name", name.into())]);
        x.open("StringDataEncoding", &[("encoding", "US-ASCII".into())]);
        x.open("SizeInBits", &[]);
        x.open("Fixed", &[]);
        x.text("FixedValue", &(chars * 8).to_string());
        x.close("Fixed");
        x.close("SizeInBits");
        x.close("StringDataEncoding");
        x.close(&tag);
        name.to_owned()
    }

    fn aggregate(&mut self, name: &str, members: &[(&str, String)]) {
        let tag = format!("Aggregate{}Type", self.side.type_word());
        let x = &mut self.xml;
        x.open(&tag, &[("name", name.into())]);
        x.open("MemberList", &[]);
        for (m, ty) in members {
            x.leaf("Member", &[("name", (*m).into()), ("typeRef", ty.clone())]);
        }
        x.close("MemberList");
        x.close(&tag);
    }

    fn array(&mut self, name: &str, element: &str, count: usize) {
        let tag = format!("Array{}Type", self.side.type_word());
        let x = &mut self.xml;
        x.open(
            &tag,
            &[("name", name.into()), ("arrayTypeRef", element.into())],
        );
        x.open("DimensionList", &[]);
        x.open("Dimension", &[]);
        x.open("StartingIndex", &[]);
        x.text("FixedValue", "0");
        x.close("StartingIndex");
        x.open("EndingIndex", &[]);
        x.text("FixedValue", &(count - 1).to_string());
        x.close("EndingIndex");
        x.close("Dimension");
        x.close("DimensionList");
        x.close(&tag);
    }

    /// The bytes that remain in the packet: sent as given, received whole (YAMCS's idiom:
    /// a size from the `_yamcs_ignore` parameter, and for telemetry its
    /// `RemainingBinaryDecoder`).
    fn remaining(&mut self, name: &str) -> String {
        let name = format!("{name}_t");
        let tag = format!("Binary{}Type", self.side.type_word());
        let x = &mut self.xml;
        x.open(&tag, &[("name", name.clone())]);
        x.open("BinaryDataEncoding", &[]);
        x.open("SizeInBits", &[]);
        x.open("DynamicValue", &[]);
        x.leaf(
            "ParameterInstanceRef",
            &[("parameterRef", "_yamcs_ignore".into())],
        );
        x.close("DynamicValue");
        x.close("SizeInBits");
        if self.side == Side::Telemetry {
            x.open(
                "FromBinaryTransformAlgorithm",
                &[("name", "RemainingBinaryDecoder".into())],
            );
            x.text_with(
                "AlgorithmText",
                &[("language", "java".into())],
                "org.yamcs.algo.RemainingBinaryDecoder",
            );
            x.close("FromBinaryTransformAlgorithm");
        }
        x.close("BinaryDataEncoding");
        x.close(&tag);
        name
    }
}

fn signed(t: Ty) -> bool {
    matches!(t, Ty::I8 | Ty::I16 | Ty::I32)
}

/// An integer encoding: unsigned or two's complement, little-endian above a byte.
fn int_encoding(bits: usize, signed: bool) -> Vec<(&'static str, String)> {
    let mut a = vec![
        ("sizeInBits", bits.to_string()),
        (
            "encoding",
            if signed { "twosComplement" } else { "unsigned" }.into(),
        ),
    ];
    if bits > 8 {
        a.push(("byteOrder", "leastSignificantByteFirst".into()));
    }
    a
}

fn enumeration(x: &mut Xml, values: &[(i64, &str)]) {
    x.open("EnumerationList", &[]);
    for (v, label) in values {
        x.leaf(
            "Enumeration",
            &[("value", v.to_string()), ("label", (*label).into())],
        );
    }
    x.close("EnumerationList");
}

fn valid_range(x: &mut Xml, lo: &str, hi: &str) {
    x.open("ValidRangeSet", &[]);
    x.leaf(
        "ValidRange",
        &[("minInclusive", lo.into()), ("maxInclusive", hi.into())],
    );
    x.close("ValidRangeSet");
}

/// A small indenting XML writer (attributes and text escaped).
#[derive(Default)]
struct Xml {
    out: String,
    depth: usize,
}

impl Xml {
    fn at(depth: usize) -> Xml {
        Xml {
            out: String::new(),
            depth,
        }
    }
    fn indent(&mut self) {
        for _ in 0..self.depth {
            self.out.push_str("  ");
        }
    }
    fn raw(&mut self, s: &str) {
        self.indent();
        self.out.push_str(s);
        self.out.push('\n');
    }
    fn start(&mut self, tag: &str, attrs: &[(&str, String)]) {
        self.indent();
        self.out.push('<');
        self.out.push_str(tag);
        for (k, v) in attrs {
            let _ = write!(self.out, " {k}=\"{}\"", escape(v));
        }
    }
    fn open(&mut self, tag: &str, attrs: &[(&str, String)]) {
        self.start(tag, attrs);
        self.out.push_str(">\n");
        self.depth += 1;
    }
    fn leaf(&mut self, tag: &str, attrs: &[(&str, String)]) {
        self.start(tag, attrs);
        self.out.push_str("/>\n");
    }
    fn text(&mut self, tag: &str, text: &str) {
        self.text_with(tag, &[], text);
    }
    fn text_with(&mut self, tag: &str, attrs: &[(&str, String)], text: &str) {
        self.start(tag, attrs);
        let _ = writeln!(self.out, ">{}</{tag}>", escape(text));
    }
    fn close(&mut self, tag: &str) {
        self.depth -= 1;
        self.indent();
        let _ = writeln!(self.out, "</{tag}>");
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}
