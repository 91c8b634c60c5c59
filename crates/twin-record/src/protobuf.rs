//! The recording's message encoding: Protocol Buffers, with the schemas in the file.
//!
//! Encoding: each message type derives [`foxglove::Encode`] (the foxglove crate's own
//! protobuf encoder and schema generator; Foxglove's well-known types come from
//! `foxglove::messages`). [`schema`] turns a type's generated `FileDescriptorSet` into the
//! recording's schema under the project's name (`m6p.CanFrames`).
//!
//! Decoding: [`decode`] reads any message with nothing but its schema, into the JSON the
//! project's tools work with (`inspect --csv`, `diff`, `replay`, the tests): field names
//! as in the schema; a repeated field is an array; `bytes` are lowercase hex strings; a
//! non-finite float is null; a `google.protobuf.Timestamp` or `Duration` is `{sec, nsec}`
//! as in Foxglove's JSON schemas; an absent field with presence (`optional`, a message) is null
//! and an absent plain field its default (0, false, ""), as protobuf defines. The twin
//! writes every field it has, so null means the value was absent (`None`). A `jsonschema`
//! channel (a recording of format 2) is read as the JSON it holds.

use std::collections::BTreeMap;
use std::sync::Arc;

use anyhow::{Context, anyhow, bail};
use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{DescriptorProto, FileDescriptorSet};
use serde_json::{Number, Value};

/// The message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "protobuf";
/// The schema encoding of every channel: a binary `FileDescriptorSet`.
pub const SCHEMA_ENCODING: &str = "protobuf";
/// The package of the project's own message types.
pub const PACKAGE: &str = "m6p";

/// The schema of `T` (derived [`foxglove::Encode`]) as the recording names it:
/// `m6p.<name>`, its `FileDescriptorSet` with the package and the top message renamed.
pub fn schema<T: foxglove::Encode>(name: &str) -> anyhow::Result<Vec<u8>> {
    let s = T::get_schema().ok_or_else(|| anyhow!("{name}: no schema"))?;
    let mut fds = FileDescriptorSet::decode(&*s.data).context("the generated schema")?;
    let (_, message) = s
        .name
        .rsplit_once('.')
        .ok_or_else(|| anyhow!("{name}: schema name {}", s.name))?;
    let file = fds
        .file
        .iter_mut()
        .find(|f| f.message_type.iter().any(|m| m.name() == message))
        .ok_or_else(|| anyhow!("{name}: {message} not in its schema"))?;
    file.package = Some(PACKAGE.to_owned());
    file.name = Some(format!("{PACKAGE}/{name}.proto"));
    for m in &mut file.message_type {
        if m.name() == message {
            m.name = Some(name.to_owned());
        }
    }
    Ok(fds.encode_to_vec())
}

/// The messages of one schema, by full name (`m6p.CanFrames`, `foxglove.Time`).
#[derive(Debug)]
struct Types {
    messages: BTreeMap<String, DescriptorProto>,
    root: String,
}

impl Types {
    fn parse(schema_name: &str, data: &[u8]) -> anyhow::Result<Types> {
        let fds = FileDescriptorSet::decode(data).context("a FileDescriptorSet")?;
        let mut messages = BTreeMap::new();
        fn walk(prefix: &str, m: &DescriptorProto, out: &mut BTreeMap<String, DescriptorProto>) {
            let full = format!("{prefix}.{}", m.name());
            for n in &m.nested_type {
                walk(&full, n, out);
            }
            out.insert(full, m.clone());
        }
        for f in &fds.file {
            for m in &f.message_type {
                walk(f.package(), m, &mut messages);
            }
        }
        if !messages.contains_key(schema_name) {
            bail!("message {schema_name} is not in its schema");
        }
        Ok(Types {
            messages,
            root: schema_name.to_owned(),
        })
    }

    /// The message a field's `type_name` names, seen from message `scope` (protobuf's
    /// scoping: innermost first; a leading dot is fully qualified).
    fn resolve(&self, scope: &str, type_name: &str) -> Option<(&str, &DescriptorProto)> {
        if let Some(full) = type_name.strip_prefix('.') {
            return self
                .messages
                .get_key_value(full)
                .map(|(k, v)| (k.as_str(), v));
        }
        let mut scope = scope;
        loop {
            let candidate = format!("{scope}.{type_name}");
            if let Some((k, v)) = self.messages.get_key_value(&candidate) {
                return Some((k.as_str(), v));
            }
            match scope.rsplit_once('.') {
                Some((outer, _)) => scope = outer,
                None => {
                    return self
                        .messages
                        .get_key_value(type_name)
                        .map(|(k, v)| (k.as_str(), v));
                }
            }
        }
    }
}

/// A parsed schema: its bytes, its name and its types.
type Cached = (Arc<[u8]>, String, Arc<Types>);

thread_local! {
    /// Parsed schemas, by their bytes (a recording has a few dozen).
    static CACHE: std::cell::RefCell<Vec<Cached>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Schemas kept parsed per thread; more are parsed again each time.
const CACHE_LIMIT: usize = 256;

fn types(schema_name: &str, data: &Arc<[u8]>) -> anyhow::Result<Arc<Types>> {
    let hit = CACHE.with(|c| {
        c.borrow()
            .iter()
            .find(|(d, n, _)| n == schema_name && (Arc::ptr_eq(d, data) || **d == **data))
            .map(|(_, _, t)| t.clone())
    });
    if let Some(t) = hit {
        return Ok(t);
    }
    let t = Arc::new(Types::parse(schema_name, data)?);
    CACHE.with(|c| {
        let mut c = c.borrow_mut();
        if c.len() < CACHE_LIMIT {
            c.push((data.clone(), schema_name.to_owned(), t.clone()));
        }
    });
    Ok(t)
}

/// A decoded message with its fields in schema order (a [`Value`] object sorts them).
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// A message: its fields in order.
    Object(Vec<(String, Node)>),
    /// A repeated field.
    Array(Vec<Node>),
    /// A scalar (or null).
    Leaf(Value),
}

impl serde::Serialize for Node {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::{SerializeMap, SerializeSeq};
        match self {
            Node::Object(fields) => {
                let mut m = s.serialize_map(Some(fields.len()))?;
                for (k, v) in fields {
                    m.serialize_entry(k, v)?;
                }
                m.end()
            }
            Node::Array(items) => {
                let mut q = s.serialize_seq(Some(items.len()))?;
                for v in items {
                    q.serialize_element(v)?;
                }
                q.end()
            }
            Node::Leaf(v) => v.serialize(s),
        }
    }
}

impl From<Node> for Value {
    fn from(n: Node) -> Value {
        match n {
            Node::Object(fields) => {
                Value::Object(fields.into_iter().map(|(k, v)| (k, v.into())).collect())
            }
            Node::Array(items) => Value::Array(items.into_iter().map(Value::from).collect()),
            Node::Leaf(v) => v,
        }
    }
}

/// The JSON of message `data` on a channel whose schema is `schema_name`, encoded
/// `schema_encoding`, with schema bytes `schema_data` (see the module docs).
pub fn decode(
    schema_name: &str,
    schema_encoding: &str,
    schema_data: &Arc<[u8]>,
    data: &[u8],
) -> anyhow::Result<Value> {
    match schema_encoding {
        "jsonschema" | "" => serde_json::from_slice(data).context("a JSON message"),
        _ => Ok(decode_ordered(schema_name, schema_encoding, schema_data, data)?.into()),
    }
}

/// [`decode`] as JSON text, the fields in schema order.
pub fn decode_text(
    schema_name: &str,
    schema_encoding: &str,
    schema_data: &Arc<[u8]>,
    data: &[u8],
) -> anyhow::Result<Vec<u8>> {
    match schema_encoding {
        "jsonschema" | "" => Ok(data.to_vec()),
        _ => Ok(serde_json::to_vec(&decode_ordered(
            schema_name,
            schema_encoding,
            schema_data,
            data,
        )?)?),
    }
}

/// [`decode`], the fields in schema order.
pub fn decode_ordered(
    schema_name: &str,
    schema_encoding: &str,
    schema_data: &Arc<[u8]>,
    data: &[u8],
) -> anyhow::Result<Node> {
    if schema_encoding != SCHEMA_ENCODING {
        bail!("schema encoding {schema_encoding:?} is not read here");
    }
    let t = types(schema_name, schema_data)?;
    let root = t
        .messages
        .get(&t.root)
        .ok_or_else(|| anyhow!("no message {}", t.root))?;
    decode_message(&t, &t.root, root, data, 0)
}

/// Nested messages deeper than this are refused (a schema could recurse).
const MAX_DEPTH: usize = 32;

/// One wire value.
enum Wire<'a> {
    Varint(u64),
    Fixed64(u64),
    Bytes(&'a [u8]),
    Fixed32(u32),
}

fn varint(data: &[u8], pos: &mut usize) -> anyhow::Result<u64> {
    let mut v = 0u64;
    for shift in (0..70).step_by(7) {
        let b = *data.get(*pos).ok_or_else(|| anyhow!("truncated varint"))?;
        *pos += 1;
        v |= u64::from(b & 0x7F).checked_shl(shift).unwrap_or(0);
        if b & 0x80 == 0 {
            return Ok(v);
        }
    }
    bail!("varint longer than 10 bytes")
}

fn take<'a>(data: &'a [u8], pos: &mut usize, n: usize) -> anyhow::Result<&'a [u8]> {
    let end = pos
        .checked_add(n)
        .filter(|&e| e <= data.len())
        .ok_or_else(|| anyhow!("field of {n} bytes beyond the message"))?;
    let s = &data[*pos..end];
    *pos = end;
    Ok(s)
}

fn next_field<'a>(data: &'a [u8], pos: &mut usize) -> anyhow::Result<(u32, Wire<'a>)> {
    let key = varint(data, pos)?;
    let number = u32::try_from(key >> 3).map_err(|_| anyhow!("field number {}", key >> 3))?;
    let wire = match key & 7 {
        0 => Wire::Varint(varint(data, pos)?),
        1 => Wire::Fixed64(u64::from_le_bytes(
            take(data, pos, 8)?.try_into().unwrap_or_default(),
        )),
        2 => {
            let n = usize::try_from(varint(data, pos)?).unwrap_or(usize::MAX);
            Wire::Bytes(take(data, pos, n)?)
        }
        5 => Wire::Fixed32(u32::from_le_bytes(
            take(data, pos, 4)?.try_into().unwrap_or_default(),
        )),
        w => bail!("wire type {w} of field {number}"),
    };
    Ok((number, wire))
}

fn float(x: f64) -> Value {
    Number::from_f64(x).map_or(Value::Null, Value::Number)
}

/// A single-precision value as the double nearest its shortest decimal (0.1f32 reads 0.1,
/// not 0.10000000149011612): what was recorded, in the digits it has.
fn f32_decimal(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(f64::NAN)
}

/// A scalar of type `ty` from one wire value.
fn scalar(ty: Type, w: &Wire<'_>) -> anyhow::Result<Value> {
    Ok(match (ty, w) {
        (Type::Double, Wire::Fixed64(v)) => float(f64::from_bits(*v)),
        (Type::Float, Wire::Fixed32(v)) => float(f32_decimal(f32::from_bits(*v))),
        (Type::Uint64 | Type::Fixed64, Wire::Varint(v) | Wire::Fixed64(v)) => Value::from(*v),
        (Type::Int64 | Type::Sfixed64, Wire::Varint(v) | Wire::Fixed64(v)) => {
            Value::from(*v as i64)
        }
        (Type::Uint32 | Type::Fixed32, Wire::Varint(v)) => Value::from(*v as u32),
        (Type::Uint32 | Type::Fixed32, Wire::Fixed32(v)) => Value::from(*v),
        (Type::Int32 | Type::Enum, Wire::Varint(v)) => Value::from(*v as i32),
        (Type::Sfixed32, Wire::Fixed32(v)) => Value::from(*v as i32),
        (Type::Sint32, Wire::Varint(v)) => Value::from(((*v >> 1) as i32) ^ -((*v & 1) as i32)),
        (Type::Sint64, Wire::Varint(v)) => Value::from(((*v >> 1) as i64) ^ -((*v & 1) as i64)),
        (Type::Bool, Wire::Varint(v)) => Value::Bool(*v != 0),
        (Type::String, Wire::Bytes(b)) => Value::String(String::from_utf8_lossy(b).into_owned()),
        (Type::Bytes, Wire::Bytes(b)) => Value::String(hex::encode(b)),
        (ty, _) => bail!("a {ty:?} field with the wrong wire type"),
    })
}

/// The elements of a packed repeated scalar field.
fn packed(ty: Type, b: &[u8], out: &mut Vec<Value>) -> anyhow::Result<()> {
    let mut pos = 0;
    while pos < b.len() {
        let w = match ty {
            Type::Double | Type::Fixed64 | Type::Sfixed64 => Wire::Fixed64(u64::from_le_bytes(
                take(b, &mut pos, 8)?.try_into().unwrap_or_default(),
            )),
            Type::Float | Type::Fixed32 | Type::Sfixed32 => Wire::Fixed32(u32::from_le_bytes(
                take(b, &mut pos, 4)?.try_into().unwrap_or_default(),
            )),
            _ => Wire::Varint(varint(b, &mut pos)?),
        };
        out.push(scalar(ty, &w)?);
    }
    Ok(())
}

/// The default of an absent field without presence.
fn default_of(ty: Type) -> Value {
    match ty {
        Type::Double | Type::Float => float(0.0),
        Type::Bool => Value::Bool(false),
        Type::String | Type::Bytes => Value::String(String::new()),
        Type::Message | Type::Group => Value::Null,
        _ => Value::from(0),
    }
}

fn decode_message(
    t: &Types,
    scope: &str,
    desc: &DescriptorProto,
    data: &[u8],
    depth: usize,
) -> anyhow::Result<Node> {
    if depth > MAX_DEPTH {
        bail!("messages nested deeper than {MAX_DEPTH}");
    }
    let mut found: Vec<Option<Node>> = vec![None; desc.field.len()];
    let mut pos = 0;
    while pos < data.len() {
        let (number, wire) = next_field(data, &mut pos)?;
        let Some(i) = desc
            .field
            .iter()
            .position(|f| u32::try_from(f.number()) == Ok(number))
        else {
            continue; // unknown fields are skipped, as protobuf does
        };
        let f = &desc.field[i];
        let ty = f.r#type();
        let value = match (ty, &wire) {
            (Type::Message, Wire::Bytes(b)) => {
                let (full, sub) = t
                    .resolve(scope, f.type_name())
                    .ok_or_else(|| anyhow!("unknown type {}", f.type_name()))?;
                decode_message(t, full, sub, b, depth + 1)?
            }
            _ => Node::Leaf(Value::Null),
        };
        if f.label() == Label::Repeated {
            let slot = found[i].get_or_insert_with(|| Node::Array(Vec::new()));
            let Node::Array(items) = slot else {
                continue;
            };
            match (ty, &wire) {
                (Type::Message, _) => items.push(value),
                (Type::String | Type::Bytes, w) => items.push(Node::Leaf(scalar(ty, w)?)),
                (_, Wire::Bytes(b)) => {
                    let mut v = Vec::new();
                    packed(ty, b, &mut v)?;
                    items.extend(v.into_iter().map(Node::Leaf));
                }
                (_, w) => items.push(Node::Leaf(scalar(ty, w)?)),
            }
        } else if ty == Type::Message {
            found[i] = Some(value);
        } else {
            let v = scalar(ty, &wire).with_context(|| f.name().to_owned())?;
            found[i] = Some(Node::Leaf(v));
        }
    }
    // Foxglove's times (`google.protobuf.Timestamp`, `Duration`) read as Foxglove's own
    // JSON writes them: `{sec, nsec}`.
    let is_time = matches!(
        scope,
        "google.protobuf.Timestamp" | "google.protobuf.Duration"
    );
    let fields = desc
        .field
        .iter()
        .zip(found)
        .map(|(f, v)| {
            let v = v.unwrap_or_else(|| {
                if f.label() == Label::Repeated {
                    Node::Array(Vec::new())
                } else if f.proto3_optional() {
                    Node::Leaf(Value::Null)
                } else {
                    Node::Leaf(default_of(f.r#type()))
                }
            });
            let name = match (is_time, f.name()) {
                (true, "seconds") => "sec",
                (true, "nanos") => "nsec",
                (_, name) => name,
            };
            (name.to_owned(), v)
        })
        .collect();
    Ok(Node::Object(fields))
}

/// Serde for `bytes::Bytes` as lowercase hex (the decoded JSON's form of `bytes`).
pub mod hex_bytes {
    use serde::{Deserialize, Deserializer, Serializer};

    /// Hex of the bytes.
    pub fn serialize<S: Serializer>(b: &bytes::Bytes, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&hex::encode(b))
    }

    /// The bytes of a hex string.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<bytes::Bytes, D::Error> {
        let s = String::deserialize(d)?;
        hex::decode(s)
            .map(bytes::Bytes::from)
            .map_err(serde::de::Error::custom)
    }
}

/// Serde for `Option<bytes::Bytes>` as lowercase hex or null.
pub mod hex_bytes_opt {
    use serde::{Deserialize, Deserializer, Serializer};

    /// Hex of the bytes, or null.
    pub fn serialize<S: Serializer>(b: &Option<bytes::Bytes>, s: S) -> Result<S::Ok, S::Error> {
        match b {
            Some(b) => s.serialize_str(&hex::encode(b)),
            None => s.serialize_none(),
        }
    }

    /// The bytes of a hex string, or none.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<bytes::Bytes>, D::Error> {
        let s = Option::<String>::deserialize(d)?;
        s.map(|s| hex::decode(s).map(bytes::Bytes::from))
            .transpose()
            .map_err(serde::de::Error::custom)
    }
}

/// Serde for `[f64; N]` and `[f32; N]` whose non-finite elements are null (the decoded
/// JSON's form of a NaN in a repeated `double` or `float`).
pub mod nan_null {
    use serde::de::DeserializeOwned;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// A float that can be null in JSON.
    pub trait Float: Copy + Serialize + DeserializeOwned {
        /// Not-a-number, for null.
        const NAN: Self;
        /// Whether neither infinite nor NaN.
        fn finite(self) -> bool;
    }

    impl Float for f64 {
        const NAN: Self = f64::NAN;
        fn finite(self) -> bool {
            self.is_finite()
        }
    }

    impl Float for f32 {
        const NAN: Self = f32::NAN;
        fn finite(self) -> bool {
            self.is_finite()
        }
    }

    /// Each element, null when not finite.
    pub fn serialize<S: Serializer, T: Float, const N: usize>(
        v: &[T; N],
        s: S,
    ) -> Result<S::Ok, S::Error> {
        v.map(|x| x.finite().then_some(x)).serialize(s)
    }

    /// Each element, NaN for null.
    pub fn deserialize<'de, D: Deserializer<'de>, T: Float, const N: usize>(
        d: D,
    ) -> Result<[T; N], D::Error> {
        let v = Vec::<Option<T>>::deserialize(d)?;
        let n = v.len();
        <[Option<T>; N]>::try_from(v)
            .map(|a| a.map(|x| x.unwrap_or(T::NAN)))
            .map_err(|_| serde::de::Error::invalid_length(n, &"the array's length"))
    }
}

/// A nested message field, encoded without the derive's temporary buffer.
///
/// `#[derive(foxglove::Encode)]` writes a nested message into a fresh `Vec` to learn its
/// length, then copies it out: an allocation, its growth and a copy for every nested message
/// (every decoded field of `/csp/packets`, every quaternion of `/fc/truth/state` and
/// `/fc/adcs`). This wrapper writes the length from `encoded_len` and the fields straight
/// into the output. The schema and the bytes are the wrapped type's (tested below); in JSON
/// it is the wrapped value. A message inside `T` must be `Nested` too.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(transparent)]
pub struct Nested<T>(pub T);

impl<T> std::ops::Deref for Nested<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<T> std::ops::DerefMut for Nested<T> {
    fn deref_mut(&mut self) -> &mut T {
        &mut self.0
    }
}

impl<T> From<T> for Nested<T> {
    fn from(v: T) -> Self {
        Nested(v)
    }
}

impl<T: foxglove::Encode + foxglove::protobuf::ProtobufField> foxglove::protobuf::ProtobufField
    for Nested<T>
{
    fn field_type() -> Type {
        T::field_type()
    }
    fn wire_type() -> u32 {
        <T as foxglove::protobuf::ProtobufField>::wire_type()
    }
    fn write(&self, buf: &mut impl bytes::BufMut) {
        let len = foxglove::protobuf::ProtobufField::encoded_len(&self.0);
        foxglove::protobuf::encode_varint(len as u64, buf);
        let room = buf.remaining_mut();
        // A derived message's `encode` fails only when `buf` has less room than the
        // message; the derive's own `write` panics there too (`BufMut::put_slice`). A
        // length is never left without its message.
        foxglove::Encode::encode(&self.0, buf).expect("a buffer with room for the message");
        debug_assert_eq!(
            room - buf.remaining_mut(),
            len,
            "a Nested message holds a nested message that is not Nested"
        );
    }
    fn type_name() -> Option<String> {
        T::type_name()
    }
    fn enum_descriptor() -> Option<prost_types::EnumDescriptorProto> {
        T::enum_descriptor()
    }
    fn message_descriptor() -> Option<DescriptorProto> {
        T::message_descriptor()
    }
    fn file_descriptor() -> Option<prost_types::FileDescriptorProto> {
        T::file_descriptor()
    }
    fn file_descriptors() -> Vec<prost_types::FileDescriptorProto> {
        T::file_descriptors()
    }
    fn repeating() -> bool {
        T::repeating()
    }
    /// The length prefix and the fields. (The derive's own `encoded_len` leaves the prefix
    /// out, so the fields of `T` are counted right only when `T` holds no nested message
    /// other than a `Nested` one; `write` checks that in debug builds.)
    fn encoded_len(&self) -> usize {
        let len = foxglove::protobuf::ProtobufField::encoded_len(&self.0);
        foxglove::protobuf::encoded_len_varint(len as u64) + len
    }
}

/// A number the protobuf wire can pack: a varint or a fixed-width scalar.
pub trait PackedScalar: foxglove::protobuf::ProtobufField + Sized {
    /// The elements' packed bytes as they are in memory, when that is what the wire holds
    /// (bytes below 128 are one-byte varints of themselves): one copy, where the elements
    /// one by one cost a call each.
    fn as_wire(_elements: &[Self]) -> Option<&[u8]> {
        None
    }
}
impl PackedScalar for u8 {
    fn as_wire(elements: &[u8]) -> Option<&[u8]> {
        elements.iter().all(|&b| b < 0x80).then_some(elements)
    }
}
impl PackedScalar for u16 {}
impl PackedScalar for u32 {}
impl PackedScalar for u64 {}
impl PackedScalar for i32 {}
impl PackedScalar for i64 {}
impl PackedScalar for f32 {}
impl PackedScalar for f64 {}

/// A repeated number field written packed: one tag and one length for all the elements,
/// where the derive writes a tag before each. The schema is the same (a `repeated` scalar,
/// packed by default in proto3, and every protobuf parser reads both forms); the bytes are
/// fewer and the encoder's calls too. An empty field is left out, as the derive does.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(transparent)]
pub struct Packed<T>(pub Vec<T>);

impl<T> std::ops::Deref for Packed<T> {
    type Target = Vec<T>;
    fn deref(&self) -> &Vec<T> {
        &self.0
    }
}

impl<T> std::ops::DerefMut for Packed<T> {
    fn deref_mut(&mut self) -> &mut Vec<T> {
        &mut self.0
    }
}

impl<T> From<Vec<T>> for Packed<T> {
    fn from(v: Vec<T>) -> Self {
        Packed(v)
    }
}

impl<T: PackedScalar> Packed<T> {
    /// The elements' bytes.
    fn body_len(&self) -> usize {
        self.0
            .iter()
            .map(foxglove::protobuf::ProtobufField::encoded_len)
            .sum()
    }
}

impl<T: PackedScalar> foxglove::protobuf::ProtobufField for Packed<T> {
    fn field_type() -> Type {
        T::field_type()
    }
    fn wire_type() -> u32 {
        prost::encoding::WireType::LengthDelimited as u32
    }
    fn write_tagged(&self, field_number: u32, buf: &mut impl bytes::BufMut) {
        if self.0.is_empty() {
            return;
        }
        let tag = (field_number << 3) | Self::wire_type();
        foxglove::protobuf::encode_varint(u64::from(tag), buf);
        self.write(buf);
    }
    /// The length and the elements (without a tag).
    fn write(&self, buf: &mut impl bytes::BufMut) {
        foxglove::protobuf::encode_varint(self.body_len() as u64, buf);
        if let Some(bytes) = T::as_wire(&self.0) {
            buf.put_slice(bytes);
            return;
        }
        for v in &self.0 {
            v.write(buf);
        }
    }
    fn repeating() -> bool {
        true
    }
    fn encoded_len(&self) -> usize {
        let n = self.body_len();
        foxglove::protobuf::encoded_len_varint(n as u64) + n
    }
    fn encoded_len_tagged(&self, field_number: u32) -> usize {
        if self.0.is_empty() {
            return 0;
        }
        let tag = (field_number << 3) | Self::wire_type();
        foxglove::protobuf::encoded_len_varint(u64::from(tag)) + self.encoded_len()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use foxglove::Encode;

    #[derive(Debug, foxglove::Encode)]
    struct Inner {
        a: u8,
        b: f32,
    }

    #[derive(Debug, foxglove::Encode)]
    struct Outer {
        t_ns: u64,
        name: String,
        data: bytes::Bytes,
        opt: Option<u32>,
        none: Option<u32>,
        arr: [f32; 3],
        ids: Vec<u32>,
        inner: Inner,
        maybe: Option<Inner>,
        flag: bool,
        neg: i32,
        big: f64,
    }

    fn decode_outer(o: &Outer) -> Value {
        let schema: Arc<[u8]> = schema::<Outer>("Outer").unwrap().into();
        let mut buf = Vec::new();
        o.encode(&mut buf).unwrap();
        decode("m6p.Outer", SCHEMA_ENCODING, &schema, &buf).unwrap()
    }

    #[test]
    fn a_derived_message_decodes_to_its_fields() {
        let v = decode_outer(&Outer {
            t_ns: 1_777_572_000_000_000_001,
            name: "FC".into(),
            data: bytes::Bytes::from_static(&[0xc0, 0x00, 0xdb]),
            opt: Some(0),
            none: None,
            arr: [1.5, f32::NAN, -2.0],
            ids: vec![0x1FFF_FFFF, 0, 7],
            inner: Inner { a: 0, b: 0.0 },
            maybe: None,
            flag: false,
            neg: -5,
            big: 6_792_531.470_923_343,
        });
        assert_eq!(
            v,
            serde_json::json!({
                "t_ns": 1_777_572_000_000_000_001u64, "name": "FC", "data": "c000db",
                "opt": 0, "none": null, "arr": [1.5, null, -2.0], "ids": [536870911, 0, 7],
                "inner": {"a": 0, "b": 0.0}, "maybe": null, "flag": false, "neg": -5,
                "big": 6_792_531.470_923_343,
            })
        );
    }

    #[derive(Debug, Clone, foxglove::Encode)]
    struct Field {
        name: String,
        value: f64,
        text: Option<String>,
    }

    #[derive(Debug, foxglove::Encode)]
    struct Plain {
        t_ns: u64,
        one: Field,
        maybe: Option<Field>,
        many: Vec<Field>,
    }

    #[derive(Debug, foxglove::Encode)]
    struct Wrapped {
        t_ns: u64,
        one: Nested<Field>,
        maybe: Option<Nested<Field>>,
        many: Vec<Nested<Field>>,
    }

    #[test]
    fn a_nested_field_has_the_bytes_and_the_schema_of_the_derived_one() {
        let f = |name: &str, value: f64, text: Option<&str>| Field {
            name: name.repeat(40),
            value,
            text: text.map(str::to_owned),
        };
        let fields = vec![
            f("current_mode", 3.0, Some("nadir")),
            f("", f64::NAN, None),
            f("panels_w[3]", -0.25, Some("")),
        ];
        for (maybe, many) in [
            (None, Vec::new()),
            (Some(f("x", 1.0, None)), fields.clone()),
        ] {
            let plain = Plain {
                t_ns: 1_777_572_000_000_000_001,
                one: f("a", 0.0, Some("b")),
                maybe: maybe.clone(),
                many: many.clone(),
            };
            let wrapped = Wrapped {
                t_ns: plain.t_ns,
                one: Nested(plain.one.clone()),
                maybe: maybe.map(Nested),
                many: many.into_iter().map(Nested).collect(),
            };
            let (mut a, mut b) = (Vec::new(), Vec::new());
            plain.encode(&mut a).unwrap();
            wrapped.encode(&mut b).unwrap();
            assert_eq!(a, b);
            assert_eq!(Encode::encoded_len(&wrapped), Some(b.len()));
        }
        let mut plain = FileDescriptorSet::decode(&*schema::<Plain>("X").unwrap()).unwrap();
        let wrapped = FileDescriptorSet::decode(&*schema::<Wrapped>("X").unwrap()).unwrap();
        assert_eq!(plain.file.len(), 1);
        plain.file[0].name = wrapped.file[0].name.clone();
        assert_eq!(plain, wrapped);
    }

    #[derive(Debug, foxglove::Encode)]
    struct Unpacked {
        ids: Vec<u32>,
        dlc: Vec<u8>,
        x: Vec<f32>,
        y: Vec<f64>,
        n: u8,
    }

    #[derive(Debug, foxglove::Encode)]
    struct PackedMsg {
        ids: Packed<u32>,
        dlc: Packed<u8>,
        x: Packed<f32>,
        y: Packed<f64>,
        n: u8,
    }

    /// A packed field has the schema of the derived repeated one, decodes to the same
    /// values (here, with the project's decoder; `tests/decode_mcap.py` and Google's
    /// protobuf in the recording tests), is shorter, and is left out when empty.
    #[test]
    fn a_packed_field_decodes_as_the_derived_repeated_one() {
        let ids = vec![0x1FFF_FFFF, 0, 7, 300];
        let dlc = vec![8, 0, 3];
        let x = vec![1.5, f32::NAN, -2.0];
        let y = vec![6_792_531.470_923_343];
        let empty = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (ids, dlc, x, y) in [(ids, dlc, x, y), empty] {
            let a = Unpacked {
                ids: ids.clone(),
                dlc: dlc.clone(),
                x: x.clone(),
                y: y.clone(),
                n: 5,
            };
            let b = PackedMsg {
                ids: Packed(ids),
                dlc: Packed(dlc),
                x: Packed(x),
                y: Packed(y),
                n: 5,
            };
            let (mut ea, mut eb) = (Vec::new(), Vec::new());
            a.encode(&mut ea).unwrap();
            b.encode(&mut eb).unwrap();
            assert_eq!(Encode::encoded_len(&b), Some(eb.len()));
            let mut sa = FileDescriptorSet::decode(&*schema::<Unpacked>("X").unwrap()).unwrap();
            let sb = FileDescriptorSet::decode(&*schema::<PackedMsg>("X").unwrap()).unwrap();
            sa.file[0].name = sb.file[0].name.clone();
            sa.file[0].message_type[0].name = sb.file[0].message_type[0].name.clone();
            assert_eq!(sa, sb);
            let schema: Arc<[u8]> = schema::<PackedMsg>("X").unwrap().into();
            let va = decode("m6p.X", SCHEMA_ENCODING, &schema, &ea).unwrap();
            let vb = decode("m6p.X", SCHEMA_ENCODING, &schema, &eb).unwrap();
            assert_eq!(va, vb);
            if a.ids.is_empty() {
                assert_eq!(eb, ea, "empty fields are left out");
            } else {
                assert!(eb.len() < ea.len(), "{} >= {}", eb.len(), ea.len());
            }
        }
    }

    /// Packed bytes below 128 are copied as they are; a byte from 128 up takes two, as the
    /// crate writes it.
    #[test]
    fn packed_bytes_are_their_varints() {
        use foxglove::protobuf::ProtobufField;
        for v in [
            vec![8u8, 0, 3, 127],
            vec![0, 128],
            vec![1, 200, 127, 128, 255],
            vec![],
        ] {
            let mut want = Vec::new();
            for b in &v {
                b.write(&mut want);
            }
            let mut got = Vec::new();
            Packed(v.clone()).write(&mut got);
            assert_eq!(got[0] as usize, want.len(), "{v:?}");
            assert_eq!(&got[1..], &want[..], "{v:?}");
        }
    }

    #[test]
    fn the_schema_is_named_in_the_project_package() {
        let data = schema::<Outer>("Outer").unwrap();
        let fds = FileDescriptorSet::decode(&*data).unwrap();
        let f = &fds.file[0];
        assert_eq!(f.package(), PACKAGE);
        assert_eq!(f.message_type[0].name(), "Outer");
        assert_eq!(f.message_type[0].nested_type[0].name(), "Inner");
    }

    #[test]
    fn damaged_messages_are_errors_not_panics() {
        let schema: Arc<[u8]> = schema::<Outer>("Outer").unwrap().into();
        let mut buf = Vec::new();
        Outer {
            t_ns: 1,
            name: "x".into(),
            data: bytes::Bytes::from_static(b"abc"),
            opt: None,
            none: None,
            arr: [0.0; 3],
            ids: vec![1],
            inner: Inner { a: 1, b: 1.0 },
            maybe: Some(Inner { a: 2, b: 2.0 }),
            flag: true,
            neg: 1,
            big: 1.0,
        }
        .encode(&mut buf)
        .unwrap();
        for n in 0..buf.len() {
            // Every prefix and every one-byte change is decoded or refused, never a panic.
            let _ = decode("m6p.Outer", SCHEMA_ENCODING, &schema, &buf[..n]);
            let mut b = buf.clone();
            b[n] ^= 0xFF;
            let _ = decode("m6p.Outer", SCHEMA_ENCODING, &schema, &b);
        }
        assert!(decode("m6p.Outer", SCHEMA_ENCODING, &schema, &[0x0a, 0x7f]).is_err());
        assert!(decode("m6p.Nope", SCHEMA_ENCODING, &schema, &buf).is_err());
    }

    #[test]
    fn foxglove_well_known_messages_decode_with_defaults() {
        let s = foxglove::messages::FrameTransform::get_schema().unwrap();
        let data: Arc<[u8]> = s.data.to_vec().into();
        let m = foxglove::messages::FrameTransform {
            timestamp: Some(foxglove::messages::Timestamp::new(5, 0)),
            parent_frame_id: "eci".into(),
            child_frame_id: "body".into(),
            translation: None,
            rotation: Some(foxglove::messages::Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        };
        let mut buf = Vec::new();
        Encode::encode(&m, &mut buf).unwrap();
        let v = decode(&s.name, &s.encoding, &data, &buf).unwrap();
        assert_eq!(v["timestamp"]["sec"], 5, "{v}");
        assert_eq!(v["timestamp"]["nsec"], 0);
        assert_eq!(v["rotation"]["w"], 1.0);
        assert_eq!(v["rotation"]["x"], 0.0);
        assert_eq!(v["translation"], Value::Null);
        assert_eq!(v["child_frame_id"], "body");
    }
}
