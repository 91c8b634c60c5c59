//! The ICD as data: every request-reply layout described field by field (name, wire type,
//! count, unit, range, enumeration, bits, text), from the same declaration that reads and
//! writes it, so the description and the bytes cannot disagree.
//!
//! A layout is declared once with [`wire_struct!`](crate::wire_struct): the macro writes the
//! struct, its [`Repr`] (read and write in the declared order, `LEN` as the sum of the
//! fields' sizes) and its [`Describe`] (the same fields, in the same order, with their wire
//! types taken from the Rust types). A port's command table ([`Port`], [`Command`]) names
//! those layouts; the twin gathers the tables of every node into one ICD (`m6p-twin icd`),
//! decodes recorded packets with it and checks commands against its ranges.
//!
//! Ranges ([`Field::range`]) are what the node accepts in a request, inclusive; a test in
//! each node crate sends the edges and one step past them and checks that the node's command
//! parser agrees. Replies carry no ranges, only units and meanings.

use crate::Error;
use crate::reqrep::le::{Reader, Repr, Writer};

/// A field's type on the wire (little-endian, IEEE-754).
#[derive(Debug, Clone, Copy)]
pub enum Ty {
    /// Unsigned 8-bit.
    U8,
    /// Signed 8-bit.
    I8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit.
    I32,
    /// Unsigned 64-bit.
    U64,
    /// IEEE-754 single.
    F32,
    /// IEEE-754 double.
    F64,
    /// A nested layout: its name and fields.
    Struct(&'static str, &'static [Field]),
}

impl Ty {
    /// Size of one element in bytes.
    pub const fn size(self) -> usize {
        match self {
            Ty::U8 | Ty::I8 => 1,
            Ty::U16 | Ty::I16 => 2,
            Ty::U32 | Ty::I32 | Ty::F32 => 4,
            Ty::U64 | Ty::F64 => 8,
            Ty::Struct(_, fields) => fields_len(fields),
        }
    }
    /// The type's name as the tables write it (`u8`, `f32`, a layout's name).
    pub fn name(self) -> &'static str {
        match self {
            Ty::U8 => "u8",
            Ty::I8 => "i8",
            Ty::U16 => "u16",
            Ty::I16 => "i16",
            Ty::U32 => "u32",
            Ty::I32 => "i32",
            Ty::U64 => "u64",
            Ty::F32 => "f32",
            Ty::F64 => "f64",
            Ty::Struct(name, _) => name,
        }
    }
    /// True for the integer types.
    pub fn is_integer(self) -> bool {
        !matches!(self, Ty::F32 | Ty::F64 | Ty::Struct(..))
    }
    /// The smallest and largest value of a numeric type.
    pub fn limits(self) -> Option<(f64, f64)> {
        Some(match self {
            Ty::U8 => (0.0, f64::from(u8::MAX)),
            Ty::I8 => (f64::from(i8::MIN), f64::from(i8::MAX)),
            Ty::U16 => (0.0, f64::from(u16::MAX)),
            Ty::I16 => (f64::from(i16::MIN), f64::from(i16::MAX)),
            Ty::U32 => (0.0, f64::from(u32::MAX)),
            Ty::I32 => (f64::from(i32::MIN), f64::from(i32::MAX)),
            Ty::U64 => (0.0, u64::MAX as f64),
            Ty::F32 => (-f64::from(f32::MAX), f64::from(f32::MAX)),
            Ty::F64 => (f64::MIN, f64::MAX),
            Ty::Struct(..) => return None,
        })
    }
}

/// Total size of a field list.
pub const fn fields_len(fields: &[Field]) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < fields.len() {
        n += fields[i].ty.size() * fields[i].count;
        i += 1;
    }
    n
}

/// One field of a layout.
#[derive(Debug, Clone, Copy)]
pub struct Field {
    /// Name (the Rust field's).
    pub name: &'static str,
    /// Wire type of one element.
    pub ty: Ty,
    /// Elements: 1 for a scalar, N for an array.
    pub count: usize,
    /// Unit (`V`, `s`, `deg`; empty for none).
    pub unit: &'static str,
    /// What it is (the Rust field's doc comment).
    pub doc: &'static str,
    /// What a node accepts in a request, inclusive (requests only).
    pub range: Option<(f64, f64)>,
    /// Values inside the range that are refused anyway, inclusive (BEACONSET's 1..=9).
    pub except: Option<(f64, f64)>,
    /// Named values (an enumeration).
    pub values: &'static [(i64, &'static str)],
    /// Named bits (a mask): bit number and meaning.
    pub bits: &'static [(i64, &'static str)],
    /// The bytes are ASCII text (NUL-padded).
    pub text: bool,
}

impl Field {
    /// A field of `shape` (type and count) with its doc text.
    pub const fn new(name: &'static str, shape: (Ty, usize), doc: &'static str) -> Field {
        Field {
            name,
            ty: shape.0,
            count: shape.1,
            unit: "",
            doc,
            range: None,
            except: None,
            values: &[],
            bits: &[],
            text: false,
        }
    }
    /// With a unit.
    pub const fn unit(mut self, unit: &'static str) -> Field {
        self.unit = unit;
        self
    }
    /// With an accepted range (inclusive).
    pub const fn range(mut self, range: (f64, f64)) -> Field {
        self.range = Some(range);
        self
    }
    /// With a gap in the range.
    pub const fn except(mut self, except: (f64, f64)) -> Field {
        self.except = Some(except);
        self
    }
    /// True when `x` is inside the range (and outside its gap); true for a field with no
    /// range.
    pub fn accepts(&self, x: f64) -> bool {
        let inside = self.range.is_none_or(|(lo, hi)| x >= lo && x <= hi);
        let gap = self.except.is_some_and(|(lo, hi)| x >= lo && x <= hi);
        inside && !gap
    }
    /// The range as the docs and error messages write it (`0..=3600 except 1..=9`).
    pub fn range_text(&self) -> Option<String> {
        let (lo, hi) = self.range?;
        let mut s = format!("{lo}..={hi}");
        if let Some((a, b)) = self.except {
            s.push_str(&format!(" except {a}..={b}"));
        }
        Some(s)
    }
    /// With named values.
    pub const fn values(mut self, values: &'static [(i64, &'static str)]) -> Field {
        self.values = values;
        self
    }
    /// With named bits.
    pub const fn bits(mut self, bits: &'static [(i64, &'static str)]) -> Field {
        self.bits = bits;
        self
    }
    /// As text.
    pub const fn text(mut self, text: bool) -> Field {
        self.text = text;
        self
    }
    /// Size in bytes.
    pub const fn len(&self) -> usize {
        self.ty.size() * self.count
    }
    /// True for a field of no bytes (never, for a declared one).
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The doc text on one line, trimmed.
    pub fn doc_line(&self) -> String {
        self.doc
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ")
            .replace("[`", "`")
            .replace("`]", "`")
    }
    /// The type as the tables write it: `u8`, `f32[3]`, `char[69]`, a layout's name.
    pub fn type_text(&self) -> String {
        if self.text {
            format!("char[{}]", self.count)
        } else if self.count > 1 {
            format!("{}[{}]", self.ty.name(), self.count)
        } else {
            self.ty.name().to_owned()
        }
    }
    /// The names of the bits set in `v` (a mask field), joined with `, `.
    pub fn bit_names(&self, v: i64) -> String {
        self.bits
            .iter()
            .filter(|(b, _)| (0..63).contains(b) && v >> b & 1 == 1)
            .map(|(_, n)| *n)
            .collect::<Vec<_>>()
            .join(", ")
    }
    /// The name of a value, if the field names its values.
    pub fn value_name(&self, v: i64) -> Option<&'static str> {
        self.values.iter().find(|(k, _)| *k == v).map(|(_, n)| *n)
    }
}

/// Values 0 off, 1 on.
pub const OFF_ON: &[(i64, &str)] = &[(0, "off"), (1, "on")];

/// A layout that describes itself field by field (written by [`wire_struct!`](crate::wire_struct)).
pub trait Describe: Repr {
    /// The layout's name.
    const NAME: &'static str;
    /// The fields in wire order.
    const FIELDS: &'static [Field];
}

/// A value that can be a field of a [`wire_struct!`](crate::wire_struct): a number, an array
/// of them, or a nested layout.
pub trait WireField: Sized {
    /// Size in bytes.
    const WIRE_LEN: usize;
    /// Wire type of one element and the count.
    const SHAPE: (Ty, usize);
    /// Read it.
    fn read_le(r: &mut Reader<'_>) -> Result<Self, Error>;
    /// Write it.
    fn write_le(&self, w: &mut Writer);
}

macro_rules! scalar {
    ($t:ty, $ty:expr) => {
        impl WireField for $t {
            const WIRE_LEN: usize = std::mem::size_of::<$t>();
            const SHAPE: (Ty, usize) = ($ty, 1);
            fn read_le(r: &mut Reader<'_>) -> Result<Self, Error> {
                let b = r.take(std::mem::size_of::<$t>())?;
                let mut a = [0u8; std::mem::size_of::<$t>()];
                a.copy_from_slice(b);
                Ok(<$t>::from_le_bytes(a))
            }
            fn write_le(&self, w: &mut Writer) {
                w.bytes(&self.to_le_bytes());
            }
        }
    };
}

scalar!(u8, Ty::U8);
scalar!(i8, Ty::I8);
scalar!(u16, Ty::U16);
scalar!(i16, Ty::I16);
scalar!(u32, Ty::U32);
scalar!(i32, Ty::I32);
scalar!(u64, Ty::U64);
scalar!(f32, Ty::F32);
scalar!(f64, Ty::F64);

impl<T: WireField, const N: usize> WireField for [T; N] {
    const WIRE_LEN: usize = T::WIRE_LEN * N;
    const SHAPE: (Ty, usize) = (T::SHAPE.0, T::SHAPE.1 * N);
    fn read_le(r: &mut Reader<'_>) -> Result<Self, Error> {
        let mut v = Vec::with_capacity(N);
        for _ in 0..N {
            v.push(T::read_le(r)?);
        }
        v.try_into().map_err(|_| Error::Truncated)
    }
    fn write_le(&self, w: &mut Writer) {
        for x in self {
            x.write_le(w);
        }
    }
}

/// Declare a fixed little-endian layout once: the struct, its [`Repr`] and its
/// [`Describe`]. Fields are read and written in the order written; each field may carry
/// `{ unit: "V", range: (0.0, 8.0), values: NAMES, bits: BITS, text: true }` (any of them).
///
/// ```
/// m6p_csp::wire_struct! {
///     /// A demo reply.
///     #[derive(Debug, Clone, Copy, PartialEq, Default)]
///     pub struct Demo {
///         /// Battery voltage.
///         pub battery_v: f32 { unit: "V" },
///         /// Channel.
///         pub channel: u8 { range: (0.0, 8.0) },
///         /// Per-panel power.
///         pub panels_w: [f32; 2] { unit: "W" },
///     }
/// }
/// use m6p_csp::reqrep::le::Repr;
/// use m6p_csp::icd::Describe;
/// assert_eq!(Demo::LEN, 13);
/// assert_eq!(Demo::FIELDS[2].count, 2);
/// ```
#[macro_export]
macro_rules! wire_struct {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $(
                $(#[doc = $doc:expr])*
                $fvis:vis $field:ident : $ty:ty $( { $( $k:ident : $v:expr ),* $(,)? } )?
            ),* $(,)?
        }
    ) => {
        $(#[$meta])*
        $vis struct $name {
            $(
                $(#[doc = $doc])*
                $fvis $field: $ty,
            )*
        }

        impl $crate::reqrep::le::Repr for $name {
            const LEN: usize = 0 $( + <$ty as $crate::icd::WireField>::WIRE_LEN )*;
            fn read(
                r: &mut $crate::reqrep::le::Reader<'_>,
            ) -> ::core::result::Result<Self, $crate::Error> {
                ::core::result::Result::Ok($name {
                    $( $field: <$ty as $crate::icd::WireField>::read_le(r)?, )*
                })
            }
            fn write(&self, w: &mut $crate::reqrep::le::Writer) {
                $( $crate::icd::WireField::write_le(&self.$field, w); )*
            }
        }

        impl $crate::icd::WireField for $name {
            const WIRE_LEN: usize = <$name as $crate::reqrep::le::Repr>::LEN;
            const SHAPE: ($crate::icd::Ty, usize) = (
                $crate::icd::Ty::Struct(
                    stringify!($name),
                    <$name as $crate::icd::Describe>::FIELDS,
                ),
                1,
            );
            fn read_le(
                r: &mut $crate::reqrep::le::Reader<'_>,
            ) -> ::core::result::Result<Self, $crate::Error> {
                <$name as $crate::reqrep::le::Repr>::read(r)
            }
            fn write_le(&self, w: &mut $crate::reqrep::le::Writer) {
                <$name as $crate::reqrep::le::Repr>::write(self, w)
            }
        }

        impl $crate::icd::Describe for $name {
            const NAME: &'static str = stringify!($name);
            const FIELDS: &'static [$crate::icd::Field] = &[
                $(
                    $crate::icd::Field::new(
                        stringify!($field),
                        <$ty as $crate::icd::WireField>::SHAPE,
                        concat!("" $(, $doc, "\n")*),
                    )
                    $( $( .$k($v) )* )?
                ),*
            ];
        }
    };
}

/// The data of a request or a reply.
#[derive(Debug, Clone, Copy)]
pub enum Data {
    /// No data.
    None,
    /// A fixed layout.
    Fixed(&'static str, &'static [Field]),
    /// A fixed head followed by a byte string of bounded length (SETUP's sync message).
    Tail(&'static str, &'static [Field], Tail),
    /// A layout of varying length, described in words (store records, file lists), with its
    /// fewest and most bytes.
    Variable(&'static str, usize, usize),
}

/// The byte string after a fixed head.
#[derive(Debug, Clone, Copy)]
pub struct Tail {
    /// Its name.
    pub name: &'static str,
    /// What it is.
    pub doc: &'static str,
    /// Fewest bytes.
    pub min: usize,
    /// Most bytes.
    pub max: usize,
}

impl Data {
    /// The fixed layout of `T`.
    pub const fn of<T: Describe>() -> Data {
        Data::Fixed(T::NAME, T::FIELDS)
    }
    /// The fixed head `T` and then `min..=max` bytes named `name`.
    pub const fn with_tail<T: Describe>(
        name: &'static str,
        doc: &'static str,
        min: usize,
        max: usize,
    ) -> Data {
        Data::Tail(
            T::NAME,
            T::FIELDS,
            Tail {
                name,
                doc,
                min,
                max,
            },
        )
    }
    /// Only a byte string (a head of no fields).
    pub const fn bytes(name: &'static str, doc: &'static str, min: usize, max: usize) -> Data {
        Data::Tail(
            "",
            &[],
            Tail {
                name,
                doc,
                min,
                max,
            },
        )
    }
    /// The fixed fields and, for a tail, the tail.
    pub fn parts(&self) -> Option<(&'static [Field], Option<Tail>)> {
        match *self {
            Data::None => Some((&[], None)),
            Data::Fixed(_, f) => Some((f, None)),
            Data::Tail(_, f, t) => Some((f, Some(t))),
            Data::Variable(..) => None,
        }
    }
    /// Fewest and most bytes.
    pub const fn bounds(&self) -> (usize, usize) {
        match self {
            Data::None => (0, 0),
            Data::Fixed(_, f) => (fields_len(f), fields_len(f)),
            Data::Tail(_, f, t) => (fields_len(f) + t.min, fields_len(f) + t.max),
            Data::Variable(_, min, max) => (*min, *max),
        }
    }
    /// Split `bytes` into the head's decoded fields and the tail; `None` when the length
    /// does not fit the layout.
    pub fn decode(&self, bytes: &[u8]) -> Option<(Vec<Decoded>, Option<Vec<u8>>)> {
        let s = self.split(bytes)?;
        Some((decode(s.fields, s.head).ok()?, s.tail.map(<[u8]>::to_vec)))
    }
    /// The fixed head's fields, the bytes they are read from, and the tail after them (a
    /// layout with a tail), when `bytes` can hold this layout: `None` for a layout of
    /// varying length, or a tail out of its bounds. (The head's own length is checked by
    /// [`decode`] and [`decode_each`].)
    pub fn split<'b>(&self, bytes: &'b [u8]) -> Option<Split<'b>> {
        let (fields, tail) = self.parts()?;
        match tail {
            None => Some(Split {
                fields,
                head: bytes,
                tail: None,
            }),
            Some(t) => {
                let n = bytes.len().checked_sub(fields_len(fields))?;
                if n < t.min || n > t.max {
                    return None;
                }
                let (head, rest) = bytes.split_at(fields_len(fields));
                Some(Split {
                    fields,
                    head,
                    tail: Some(rest),
                })
            }
        }
    }
    /// Its size when fixed.
    pub const fn fixed_len(&self) -> Option<usize> {
        match self {
            Data::None => Some(0),
            Data::Fixed(_, f) => Some(fields_len(f)),
            Data::Tail(..) | Data::Variable(..) => None,
        }
    }
}

/// Data split by its layout ([`Data::split`]).
#[derive(Debug, Clone, Copy)]
pub struct Split<'b> {
    /// The fixed head's fields.
    pub fields: &'static [Field],
    /// The bytes they are read from.
    pub head: &'b [u8],
    /// The bytes after them (a layout with a tail).
    pub tail: Option<&'b [u8]>,
}

/// Who may send a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Every node, payloads included (ICD 4.1's starred commands, and reads).
    Any,
    /// The platform and the ground; payloads (12-15) get the failure reply unless
    /// `[rules] payload_access = "open"`.
    NoPayloads,
}

/// One command of a request-reply port.
#[derive(Debug, Clone, Copy)]
pub struct Command {
    /// Command id (the request's first byte).
    pub id: u8,
    /// Name (ICD's, or the twin's for the twin's own).
    pub name: &'static str,
    /// What it does, in one line.
    pub doc: &'static str,
    /// Request data (after the command byte).
    pub request: Data,
    /// Reply data on success (after `command | result`).
    pub reply: Data,
    /// Who may send it.
    pub access: Access,
    /// True for a command the twin adds to the ICD's.
    pub twin: bool,
    /// Valid request data (the first is the one the docs show). Together they accept each
    /// end of every ranged request field (a test checks it against the node's parser).
    pub examples: &'static [&'static [u8]],
    /// When the node refuses it (the failure reply), beyond a wrong length, a value outside
    /// a field's range and the access rule (empty: nothing more).
    pub refused: &'static str,
}

impl Command {
    /// A command of the ICD's, open to every node, with no data either way.
    pub const fn new(id: u8, name: &'static str, doc: &'static str) -> Command {
        Command {
            id,
            name,
            doc,
            request: Data::None,
            reply: Data::None,
            access: Access::Any,
            twin: false,
            examples: &[],
            refused: "",
        }
    }
    /// Refused also when `text` says (the failure reply).
    pub const fn refused_when(mut self, text: &'static str) -> Command {
        self.refused = text;
        self
    }
    /// With valid request data.
    pub const fn examples(mut self, e: &'static [&'static [u8]]) -> Command {
        self.examples = e;
        self
    }
    /// With request data.
    pub const fn request(mut self, d: Data) -> Command {
        self.request = d;
        self
    }
    /// With reply data.
    pub const fn reply(mut self, d: Data) -> Command {
        self.reply = d;
        self
    }
    /// Refused to payloads.
    pub const fn no_payloads(mut self) -> Command {
        self.access = Access::NoPayloads;
        self
    }
    /// The twin's own command.
    pub const fn twin(mut self) -> Command {
        self.twin = true;
        self
    }
}

/// A request-reply port and its commands.
#[derive(Debug, Clone, Copy)]
pub struct Port {
    /// Default port number (a scenario may move it).
    pub port: u8,
    /// Name (`telemetry`, `control`).
    pub name: &'static str,
    /// Its commands.
    pub commands: &'static [Command],
}

impl Port {
    /// The command with id `id`.
    pub fn command(&self, id: u8) -> Option<&'static Command> {
        self.commands.iter().find(|c| c.id == id)
    }
    /// The command named `name` (case-insensitive).
    pub fn command_named(&self, name: &str) -> Option<&'static Command> {
        self.commands
            .iter()
            .find(|c| c.name.eq_ignore_ascii_case(name))
    }
}

/// A decoded value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// An integer field.
    Int(i64),
    /// A floating-point field.
    Float(f64),
    /// A text field.
    Text(String),
}

impl Value {
    /// As a number (text: none).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Int(i) => Some(*i as f64),
            Value::Float(f) => Some(*f),
            Value::Text(_) => None,
        }
    }
}

impl std::fmt::Display for Value {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Value::Int(i) => write!(f, "{i}"),
            Value::Float(x) => write!(f, "{x}"),
            Value::Text(s) => write!(f, "{s:?}"),
        }
    }
}

/// One decoded leaf field: its path (`general.current_mode`, `panels_w[3]`), value and
/// the field that describes it.
#[derive(Debug, Clone)]
pub struct Decoded {
    /// Path from the layout's root.
    pub path: String,
    /// Value.
    pub value: Value,
    /// Its description.
    pub field: &'static Field,
}

impl Decoded {
    /// The value as an operator reads it ([`show`]).
    pub fn show(&self) -> String {
        show(&self.value, self.field)
    }
}

/// A value of `field` as an operator reads it: the number, its unit, the name of an
/// enumerated value (`1 (detumble)`), and a mask in hex with the names of its bits set
/// (`0x5 (COMM1, ECU)`, `0x0 (none)`).
pub fn show(value: &Value, field: &Field) -> String {
    let mut s = match value {
        // A single's shortest decimal (0.3, not 0.30000001192092896).
        Value::Float(x) if matches!(field.ty, Ty::F32) => format!("{}", *x as f32),
        Value::Float(x) => format!("{x}"),
        Value::Int(i) if !field.bits.is_empty() && field.value_name(*i).is_none() => {
            format!("{i:#x}")
        }
        v => v.to_string(),
    };
    let unit = field.unit;
    if unit.starts_with(|c: char| c.is_ascii_digit()) {
        // A scaled count: `10 x 0.01 deg/s`.
        s.push_str(" x ");
        s.push_str(unit);
    } else if !unit.is_empty() {
        s.push(' ');
        s.push_str(unit);
    }
    if let Value::Int(i) = *value {
        if let Some(n) = field.value_name(i) {
            s.push_str(&format!(" ({n})"));
        } else if !field.bits.is_empty() {
            let on = field.bit_names(i);
            if i == 0 {
                s.push_str(" (none)");
            } else if !on.is_empty() {
                s.push_str(&format!(" ({on})"));
            }
        }
    }
    s
}

fn read_scalar(ty: Ty, r: &mut Reader<'_>) -> Result<Value, Error> {
    Ok(match ty {
        Ty::U8 => Value::Int(i64::from(r.u8()?)),
        Ty::I8 => Value::Int(i64::from(r.i8()?)),
        Ty::U16 => Value::Int(i64::from(r.u16()?)),
        Ty::I16 => Value::Int(i64::from(i16::read_le(r)?)),
        Ty::U32 => Value::Int(i64::from(r.u32()?)),
        Ty::I32 => Value::Int(i64::from(r.i32()?)),
        // u64 fields above i64::MAX read as the wrapped value (none of the ICD's come close).
        Ty::U64 => Value::Int(r.u64()? as i64),
        Ty::F32 => Value::Float(f64::from(r.f32()?)),
        Ty::F64 => Value::Float(r.f64()?),
        Ty::Struct(..) => return Err(Error::Truncated),
    })
}

/// Read `fields` from `r`, handing `each` every leaf's path (built in `path`), value and
/// description, in wire order. The recursion follows the static layout's nesting, never the
/// data.
fn walk(
    fields: &'static [Field],
    path: &mut String,
    r: &mut Reader<'_>,
    each: &mut dyn FnMut(&str, Value, &'static Field),
) -> Result<(), Error> {
    use std::fmt::Write as _;
    for f in fields {
        let start = path.len();
        if start > 0 {
            path.push('.');
        }
        path.push_str(f.name);
        if f.text {
            let b = r.take(f.len())?;
            let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
            each(
                path,
                Value::Text(String::from_utf8_lossy(&b[..end]).into_owned()),
                f,
            );
            path.truncate(start);
            continue;
        }
        let base = path.len();
        for i in 0..f.count {
            if f.count != 1 {
                let _ = write!(path, "[{i}]");
            }
            match f.ty {
                Ty::Struct(_, inner) => walk(inner, path, r, each)?,
                ty => each(path, read_scalar(ty, r)?, f),
            }
            path.truncate(base);
        }
        path.truncate(start);
    }
    Ok(())
}

/// [`decode`] without a [`Decoded`] per leaf: `each` gets every leaf's path, value and
/// description in wire order, the path built in `path` (whose contents are replaced), so
/// that a caller that keeps `path` allocates nothing but text values. On an error, the
/// leaves before it have been handed out.
pub fn decode_each(
    fields: &'static [Field],
    bytes: &[u8],
    path: &mut String,
    each: &mut dyn FnMut(&str, Value, &'static Field),
) -> Result<(), Error> {
    path.clear();
    let mut r = Reader::new(bytes);
    walk(fields, path, &mut r, each)?;
    r.finish()
}

/// Decode exactly `fields_len(fields)` bytes into leaf values, in wire order.
pub fn decode(fields: &'static [Field], bytes: &[u8]) -> Result<Vec<Decoded>, Error> {
    let mut out = Vec::new();
    decode_each(
        fields,
        bytes,
        &mut String::new(),
        &mut |path, value, field| {
            out.push(Decoded {
                path: path.to_owned(),
                value,
                field,
            });
        },
    )?;
    Ok(out)
}

/// Leaf fields of a layout (arrays and nested layouts flattened), with their paths:
/// what [`decode`] yields, without values.
pub fn leaves(fields: &'static [Field]) -> Vec<(String, &'static Field)> {
    fn walk(fields: &'static [Field], prefix: &str, out: &mut Vec<(String, &'static Field)>) {
        for f in fields {
            let base = if prefix.is_empty() {
                f.name.to_string()
            } else {
                format!("{prefix}.{}", f.name)
            };
            if f.text || f.count == 1 {
                match f.ty {
                    Ty::Struct(_, inner) if !f.text => walk(inner, &base, out),
                    _ => out.push((base, f)),
                }
                continue;
            }
            for i in 0..f.count {
                let path = format!("{base}[{i}]");
                match f.ty {
                    Ty::Struct(_, inner) => walk(inner, &path, out),
                    _ => out.push((path, f)),
                }
            }
        }
    }
    let mut out = Vec::new();
    walk(fields, "", &mut out);
    out
}

/// Why leaf values did not encode into a layout; all but [`EncodeError::Count`] name the
/// field by its leaf path, as [`leaves`] gives it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// Not one value per leaf field.
    #[error("{values} values for {fields} fields")]
    Count {
        /// Values given.
        values: usize,
        /// Leaf fields of the layout.
        fields: usize,
    },
    /// A text field was given a number.
    #[error("{path}: text expected")]
    TextExpected {
        /// The field's leaf path.
        path: String,
    },
    /// A text is longer than its field.
    #[error("{path}: at most {max_chars} characters")]
    TextTooLong {
        /// The field's leaf path.
        path: String,
        /// The field's length.
        max_chars: usize,
    },
    /// A number field was given a text.
    #[error("{path}: a number expected")]
    NumberExpected {
        /// The field's leaf path.
        path: String,
    },
    /// The field's type holds no number.
    #[error("{path}: not a number")]
    NotNumeric {
        /// The field's leaf path.
        path: String,
    },
    /// The value is beyond what the field's type holds.
    #[error("{path}: {value} is outside {ty} ({lo}..={hi})")]
    OutOfLimits {
        /// The field's leaf path.
        path: String,
        /// The value given.
        value: f64,
        /// The type's name.
        ty: &'static str,
        /// The type's lowest value.
        lo: f64,
        /// The type's highest value.
        hi: f64,
    },
    /// A fraction for an integer field.
    #[error("{path}: {value} is not a whole number")]
    NotWhole {
        /// The field's leaf path.
        path: String,
        /// The value given.
        value: f64,
    },
}

impl EncodeError {
    /// The leaf path of the field that failed, if the error is about one field.
    pub fn path(&self) -> Option<&str> {
        match self {
            EncodeError::Count { .. } => None,
            EncodeError::TextExpected { path }
            | EncodeError::TextTooLong { path, .. }
            | EncodeError::NumberExpected { path }
            | EncodeError::NotNumeric { path }
            | EncodeError::OutOfLimits { path, .. }
            | EncodeError::NotWhole { path, .. } => Some(path),
        }
    }
}

/// Encode leaf values (in [`leaves`] order) into the layout's bytes. A value out of its
/// type's limits, a fraction for an integer, or a value for a text field longer than it
/// is an error naming the field.
pub fn encode(fields: &'static [Field], values: &[Value]) -> Result<Vec<u8>, EncodeError> {
    let leaves = leaves(fields);
    if leaves.len() != values.len() {
        return Err(EncodeError::Count {
            values: values.len(),
            fields: leaves.len(),
        });
    }
    let mut w = Writer::new();
    for ((path, f), v) in leaves.iter().zip(values) {
        if f.text {
            let Value::Text(s) = v else {
                return Err(EncodeError::TextExpected { path: path.clone() });
            };
            if s.len() > f.len() {
                return Err(EncodeError::TextTooLong {
                    path: path.clone(),
                    max_chars: f.len(),
                });
            }
            let mut b = s.as_bytes().to_vec();
            b.resize(f.len(), 0);
            w.bytes(&b);
            continue;
        }
        let Some(x) = v.as_f64() else {
            return Err(EncodeError::NumberExpected { path: path.clone() });
        };
        let (lo, hi) =
            f.ty.limits()
                .ok_or_else(|| EncodeError::NotNumeric { path: path.clone() })?;
        if x.is_nan() && f.ty.is_integer() || x < lo || x > hi {
            return Err(EncodeError::OutOfLimits {
                path: path.clone(),
                value: x,
                ty: f.ty.name(),
                lo,
                hi,
            });
        }
        if f.ty.is_integer() && x.fract() != 0.0 {
            return Err(EncodeError::NotWhole {
                path: path.clone(),
                value: x,
            });
        }
        match f.ty {
            Ty::U8 => w.u8(x as u8),
            Ty::I8 => w.i8(x as i8),
            Ty::U16 => w.u16(x as u16),
            Ty::I16 => w.bytes(&(x as i16).to_le_bytes()),
            Ty::U32 => w.u32(x as u32),
            Ty::I32 => w.i32(x as i32),
            Ty::U64 => w.u64(x as u64),
            Ty::F32 => w.f32(x as f32),
            Ty::F64 => w.f64(x),
            Ty::Struct(..) => return Err(EncodeError::NotNumeric { path: path.clone() }),
        };
    }
    Ok(w.buf)
}

/// Check a port's request ranges against the node's own parser (`accepts(command, data)`):
/// for each command with a fixed request layout, every ranged leaf field set to either end
/// of its range must be accepted with at least one of the command's examples, and one step
/// past either end (an integer's next value, a float's 1 % of the span, where the type can
/// hold it) refused with all of them. The examples themselves must be accepted. Returns
/// one line per disagreement (empty: they agree). For the node crates' tests.
pub fn range_disagreements(port: &Port, accepts: impl Fn(u8, &[u8]) -> bool) -> Vec<String> {
    let mut out = Vec::new();
    for c in port.commands {
        let Some((fields, tail)) = c.request.parts() else {
            continue;
        };
        if fields.is_empty() && tail.is_none() {
            continue;
        }
        if c.examples.is_empty() {
            out.push(format!("{}: no example request", c.name));
            continue;
        }
        let decoded = decoded_examples(c, &accepts, &mut out);
        for (i, (path, f)) in leaves(fields).into_iter().enumerate() {
            let Some((lo, hi)) = f.range else {
                continue;
            };
            let (tlo, thi) = f.ty.limits().unwrap_or((lo, hi));
            let step = if f.ty.is_integer() {
                1.0
            } else {
                ((hi - lo) * 0.01).max(f64::MIN_POSITIVE)
            };
            let with = |base: &(Vec<Value>, Vec<u8>), x: f64| {
                let mut v = base.0.clone();
                v[i] = if f.ty.is_integer() {
                    Value::Int(x as i64)
                } else {
                    Value::Float(x)
                };
                let mut b = encode(fields, &v).ok()?;
                b.extend_from_slice(&base.1);
                Some(b)
            };
            for edge in [lo, hi] {
                let ok = decoded
                    .iter()
                    .filter_map(|b| with(b, edge))
                    .any(|d| accepts(c.id, &d));
                if !ok {
                    out.push(format!(
                        "{}.{path}: {edge} (an end of its range) is refused",
                        c.name
                    ));
                }
            }
            let mut refused = vec![lo - step, hi + step];
            if let Some((a, b)) = f.except {
                refused.extend([a, b]);
                for x in [a - step, b + step] {
                    let ok = decoded
                        .iter()
                        .filter_map(|d| with(d, x))
                        .any(|d| accepts(c.id, &d));
                    if !ok {
                        out.push(format!(
                            "{}.{path}: {x} (beside its gap) is refused",
                            c.name
                        ));
                    }
                }
            }
            for past in refused {
                if past < tlo || past > thi {
                    continue;
                }
                if decoded
                    .iter()
                    .filter_map(|b| with(b, past))
                    .any(|d| accepts(c.id, &d))
                {
                    out.push(format!(
                        "{}.{path}: {past} (outside its range) is accepted",
                        c.name
                    ));
                }
            }
        }
        if let Some(t) = tail {
            let Some(base) = decoded.first() else {
                continue;
            };
            tail_disagreements(c, fields, t, base, &accepts, &mut out);
        }
    }
    out
}

/// The examples, each checked against the parser: the bases the range checks vary a field of.
fn decoded_examples(
    c: &Command,
    accepts: &impl Fn(u8, &[u8]) -> bool,
    out: &mut Vec<String>,
) -> Vec<(Vec<Value>, Vec<u8>)> {
    let mut decoded = Vec::new();
    for e in c.examples {
        if !accepts(c.id, e) {
            out.push(format!("{}: example {e:02x?} is refused", c.name));
        }
        match c.request.decode(e) {
            Some((d, rest)) => decoded.push((
                d.into_iter().map(|x| x.value).collect::<Vec<_>>(),
                rest.unwrap_or_default(),
            )),
            None => out.push(format!("{}: example {e:02x?} has the wrong size", c.name)),
        }
    }
    decoded
}

/// A variable tail's length limits against the parser, on the first example's head.
fn tail_disagreements(
    c: &Command,
    fields: &'static [Field],
    t: Tail,
    base: &(Vec<Value>, Vec<u8>),
    accepts: &impl Fn(u8, &[u8]) -> bool,
    out: &mut Vec<String>,
) {
    let mut head = encode(fields, &base.0).unwrap_or_default();
    let at = head.len();
    for (n, want) in [(t.min, true), (t.max, true), (t.max + 1, false)] {
        head.truncate(at);
        head.resize(at + n, b'x');
        if accepts(c.id, &head) != want {
            out.push(format!(
                "{}.{}: {n} bytes {}",
                c.name,
                t.name,
                if want { "refused" } else { "accepted" }
            ));
        }
    }
    if t.min > 0 {
        head.truncate(at + t.min - 1);
        if accepts(c.id, &head) {
            out.push(format!(
                "{}.{}: {} bytes accepted",
                c.name,
                t.name,
                t.min - 1
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    crate::wire_struct! {
        /// Inner.
        #[derive(Debug, Clone, Copy, PartialEq, Default)]
        pub struct Inner {
            /// A.
            pub a: u16 { unit: "mA" },
            /// B.
            pub b: i8,
        }
    }

    const MODES: &[(i64, &str)] = &[(0, "off"), (1, "on")];

    crate::wire_struct! {
        /// Outer.
        #[derive(Debug, Clone, Copy, PartialEq, Default)]
        pub struct Outer {
            /// Voltage,
            /// in volts.
            pub v: f32 { unit: "V", range: (0.0, 10.0) },
            /// Mode.
            pub mode: u8 { values: MODES },
            /// Pair.
            pub pair: [Inner; 2],
            /// Name.
            pub name: [u8; 4] { text: true },
            /// Quaternion.
            pub q: [f64; 2],
        }
    }

    #[test]
    fn the_macro_reads_writes_and_describes_in_one_order() {
        assert_eq!(Outer::LEN, 4 + 1 + 2 * 3 + 4 + 16);
        assert_eq!(fields_len(Outer::FIELDS), Outer::LEN);
        let o = Outer {
            v: 7.5,
            mode: 1,
            pair: [Inner { a: 0x0102, b: -1 }, Inner { a: 3, b: 4 }],
            name: *b"ab\0\0",
            q: [1.0, -0.5],
        };
        let b = o.to_vec();
        assert_eq!(&b[0..4], &7.5f32.to_le_bytes());
        assert_eq!(b[4], 1);
        assert_eq!(&b[5..8], &[0x02, 0x01, 0xff]);
        assert_eq!(Outer::parse(&b).unwrap(), o);
        let d = decode(Outer::FIELDS, &b).unwrap();
        let paths: Vec<&str> = d.iter().map(|x| x.path.as_str()).collect();
        assert_eq!(
            paths,
            [
                "v",
                "mode",
                "pair[0].a",
                "pair[0].b",
                "pair[1].a",
                "pair[1].b",
                "name",
                "q[0]",
                "q[1]"
            ]
        );
        assert_eq!(d[0].show(), "7.5 V");
        assert_eq!(d[1].show(), "1 (on)");
        assert_eq!(d[2].value, Value::Int(0x0102));
        assert_eq!(d[2].show(), "258 mA");
        assert_eq!(d[3].value, Value::Int(-1));
        assert_eq!(d[6].value, Value::Text("ab".into()));
        assert_eq!(d[8].value, Value::Float(-0.5));
        assert_eq!(Outer::FIELDS[0].doc_line(), "Voltage, in volts.");
        assert_eq!(Outer::FIELDS[0].range, Some((0.0, 10.0)));
        let values: Vec<Value> = d.iter().map(|x| x.value.clone()).collect();
        assert_eq!(encode(Outer::FIELDS, &values).unwrap(), b);
        let paths: Vec<String> = leaves(Outer::FIELDS).into_iter().map(|l| l.0).collect();
        assert_eq!(paths, d.iter().map(|x| x.path.clone()).collect::<Vec<_>>());
        assert!(decode(Outer::FIELDS, &b[1..]).is_err());
    }

    #[test]
    fn decode_each_reuses_its_path_buffer_and_stops_at_the_error() {
        let b = Outer::default().to_vec();
        let mut path = String::from("left over");
        let mut seen = Vec::new();
        for _ in 0..2 {
            seen.clear();
            decode_each(Outer::FIELDS, &b, &mut path, &mut |p, v, f| {
                seen.push((p.to_owned(), v, f.name));
            })
            .unwrap();
        }
        let d = decode(Outer::FIELDS, &b).unwrap();
        let want: Vec<_> = d
            .into_iter()
            .map(|x| (x.path, x.value, x.field.name))
            .collect();
        assert_eq!(seen, want);
        // Cut inside `pair[1]`: the leaves before it are handed out, then the error.
        seen.clear();
        let r = decode_each(Outer::FIELDS, &b[..9], &mut path, &mut |p, v, f| {
            seen.push((p.to_owned(), v, f.name));
        });
        assert!(r.is_err());
        let paths: Vec<&str> = seen.iter().map(|x| x.0.as_str()).collect();
        assert_eq!(paths, ["v", "mode", "pair[0].a", "pair[0].b"]);
    }

    #[test]
    fn encode_names_the_field_and_the_type_limits() {
        let mut v: Vec<Value> = decode(Outer::FIELDS, &Outer::default().to_vec())
            .unwrap()
            .into_iter()
            .map(|d| d.value)
            .collect();
        v[1] = Value::Int(300);
        assert_eq!(
            encode(Outer::FIELDS, &v).unwrap_err().to_string(),
            "mode: 300 is outside u8 (0..=255)"
        );
        v[1] = Value::Float(1.5);
        assert_eq!(
            encode(Outer::FIELDS, &v).unwrap_err().to_string(),
            "mode: 1.5 is not a whole number"
        );
        v[1] = Value::Int(1);
        v[6] = Value::Text("abcde".into());
        assert_eq!(
            encode(Outer::FIELDS, &v).unwrap_err().to_string(),
            "name: at most 4 characters"
        );
    }
}
