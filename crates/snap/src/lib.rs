//! The binary encoding of a running twin's state, for snapshots (docs/snapshots.md).
//!
//! A restore builds the twin from its scenario, as any run does, then overwrites the state
//! the run changed from the snapshot: [`Snap::load`] writes into a value that exists
//! (its wiring, channels and configuration stay as built), [`SnapNew::read`] makes a value
//! that is data through and through (the elements of a queue, a map, a list).
//!
//! The encoding is the build's own: a snapshot is read only by the build that wrote it
//! (the container's rule, `twin_core::snapshot_file`), so there is no schema and no
//! evolution, only what each type writes in order: integers little-endian, floats as their
//! bits (NaN, -0.0 and every last bit come back as they were), lengths as `u32`, `usize` as
//! `u64`. A reader never allocates more than what is left to read can hold.
//!
//! [`fields!`] implements both traits for a struct by naming its fields, in an exhaustive
//! destructuring: a field added to the struct and not to the list does not compile, so a
//! snapshot cannot quietly leave state out.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;

/// Why bytes could not be read back, or a state could not be saved.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SnapError {
    /// The bytes end inside a value.
    #[error("cut short reading {what} at byte {at}")]
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Where.
        at: usize,
    },
    /// Bytes are left after the last value.
    #[error("{left} bytes left after the last value")]
    Trailing {
        /// How many.
        left: usize,
    },
    /// A value no writer writes.
    #[error("not a valid {what} at byte {at}")]
    Bad {
        /// What was being read.
        what: &'static str,
        /// Where.
        at: usize,
    },
    /// Something that must be empty at a quiescent point is not.
    #[error("not at a quiescent point: {0} is not empty")]
    NotQuiescent(&'static str),
    /// A part of the twin that cannot be saved (yet).
    #[error("{0} cannot be saved in a snapshot")]
    Unsupported(String),
    /// A value built from the scenario that does not match the saved one (a list of
    /// endpoints of another length).
    #[error("{what}: {saved} saved, {built} built from the scenario")]
    Mismatch {
        /// What.
        what: &'static str,
        /// The saved count.
        saved: u64,
        /// The built count.
        built: u64,
    },
}

/// Where a state is written.
#[derive(Debug, Default, Clone)]
pub struct Writer {
    buf: Vec<u8>,
}

impl Writer {
    /// An empty writer.
    pub fn new() -> Self {
        Writer::default()
    }

    /// The bytes written.
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }

    /// Bytes, as they are.
    pub fn raw(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }

    /// A length (a `u32`; a collection longer than that is cut, which no state of the twin
    /// comes near).
    pub fn len(&mut self, n: usize) {
        self.raw(&u32::try_from(n).unwrap_or(u32::MAX).to_le_bytes());
    }
}

/// Where a state is read from.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    /// A reader of `buf` from its start.
    pub fn new(buf: &'a [u8]) -> Self {
        Reader { buf, at: 0 }
    }

    /// The next `n` bytes.
    pub fn raw(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], SnapError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.buf.len())
            .ok_or(SnapError::Truncated { what, at: self.at })?;
        let b = &self.buf[self.at..end];
        self.at = end;
        Ok(b)
    }

    /// The next `N` bytes.
    pub fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], SnapError> {
        let b = self.raw(N, what)?;
        let mut out = [0u8; N];
        out.copy_from_slice(b);
        Ok(out)
    }

    /// A length of items each at least `min_item` bytes long: refused when what is left
    /// cannot hold them, so that no length makes the reader allocate past the input.
    pub fn len(&mut self, min_item: usize, what: &'static str) -> Result<usize, SnapError> {
        let at = self.at;
        let n = u32::from_le_bytes(self.array(what)?) as usize;
        if n.saturating_mul(min_item.max(1)) > self.left() {
            return Err(SnapError::Truncated { what, at });
        }
        Ok(n)
    }

    /// Bytes not read yet.
    pub fn left(&self) -> usize {
        self.buf.len() - self.at
    }

    /// Where it is.
    pub fn at(&self) -> usize {
        self.at
    }

    /// `Err` unless everything was read.
    pub fn finish(&self) -> Result<(), SnapError> {
        match self.left() {
            0 => Ok(()),
            left => Err(SnapError::Trailing { left }),
        }
    }

    /// `Bad` at the current position.
    pub fn bad(&self, what: &'static str) -> SnapError {
        SnapError::Bad { what, at: self.at }
    }
}

/// A state that is saved and loaded over a value built from the scenario.
pub trait Snap {
    /// Write it.
    fn save(&self, w: &mut Writer);
    /// Overwrite it with what [`Snap::save`] wrote.
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError>;
}

/// A state that is data through and through: it can be made from the bytes alone.
pub trait SnapNew: Snap + Sized {
    /// The least number of bytes a value takes (bounds what a length may claim).
    const MIN_BYTES: usize = 1;
    /// Make it from what [`Snap::save`] wrote.
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError>;
}

/// Both traits for a value that is read whole: `load` is `read` put in place.
macro_rules! by_read {
    ($($t:ty),* $(,)?) => {$(
        impl Snap for $t {
            fn save(&self, w: &mut Writer) {
                <$t as SaveRaw>::save_raw(self, w)
            }
            fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
                *self = <$t as SnapNew>::read(r)?;
                Ok(())
            }
        }
    )*};
}

/// How a leaf type writes itself.
trait SaveRaw {
    fn save_raw(&self, w: &mut Writer);
}

macro_rules! ints {
    ($($t:ty),* $(,)?) => {$(
        impl SaveRaw for $t {
            fn save_raw(&self, w: &mut Writer) {
                w.raw(&self.to_le_bytes());
            }
        }
        impl SnapNew for $t {
            const MIN_BYTES: usize = std::mem::size_of::<$t>();
            fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
                Ok(<$t>::from_le_bytes(r.array(stringify!($t))?))
            }
        }
        by_read!($t);
    )*};
}

ints!(u8, u16, u32, u64, u128, i8, i16, i32, i64, i128);

impl SaveRaw for usize {
    fn save_raw(&self, w: &mut Writer) {
        w.raw(&(*self as u64).to_le_bytes());
    }
}
impl SnapNew for usize {
    const MIN_BYTES: usize = 8;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let at = r.at();
        usize::try_from(u64::from_le_bytes(r.array("usize")?))
            .map_err(|_| SnapError::Bad { what: "usize", at })
    }
}
by_read!(usize);

impl SaveRaw for bool {
    fn save_raw(&self, w: &mut Writer) {
        w.raw(&[u8::from(*self)]);
    }
}
impl SnapNew for bool {
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        match r.array::<1>("bool")? {
            [0] => Ok(false),
            [1] => Ok(true),
            _ => Err(SnapError::Bad {
                what: "bool",
                at: r.at() - 1,
            }),
        }
    }
}
by_read!(bool);

/// Floats as their bits: NaN payloads, -0.0 and every last bit come back.
macro_rules! floats {
    ($($t:ty => $bits:ty),* $(,)?) => {$(
        impl SaveRaw for $t {
            fn save_raw(&self, w: &mut Writer) {
                w.raw(&self.to_bits().to_le_bytes());
            }
        }
        impl SnapNew for $t {
            const MIN_BYTES: usize = std::mem::size_of::<$t>();
            fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
                Ok(<$t>::from_bits(<$bits>::from_le_bytes(r.array(stringify!($t))?)))
            }
        }
        by_read!($t);
    )*};
}

floats!(f64 => u64, f32 => u32);

impl SaveRaw for char {
    fn save_raw(&self, w: &mut Writer) {
        w.raw(&u32::from(*self).to_le_bytes());
    }
}
impl SnapNew for char {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let at = r.at();
        char::from_u32(u32::from_le_bytes(r.array("char")?))
            .ok_or(SnapError::Bad { what: "char", at })
    }
}
by_read!(char);

impl SaveRaw for String {
    fn save_raw(&self, w: &mut Writer) {
        w.len(self.len());
        w.raw(self.as_bytes());
    }
}
impl SnapNew for String {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let n = r.len(1, "string")?;
        let at = r.at();
        let b = r.raw(n, "string")?;
        String::from_utf8(b.to_vec()).map_err(|_| SnapError::Bad { what: "string", at })
    }
}
by_read!(String);

impl SaveRaw for Arc<str> {
    fn save_raw(&self, w: &mut Writer) {
        w.len(self.len());
        w.raw(self.as_bytes());
    }
}
impl SnapNew for Arc<str> {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        String::read(r).map(Arc::from)
    }
}
by_read!(Arc<str>);

/// Distinct texts [`SnapNew`] for `&'static str` keeps for the process at most.
pub const MAX_STATIC_TEXTS: usize = 4096;

/// A text the program holds as a constant (why a frame was lost): saved as its text, read
/// back as the same text, kept once for the whole process (each distinct text is allocated
/// once and kept, at most [`MAX_STATIC_TEXTS`] of them, so that no input makes the process
/// keep more; the program's own come to a few dozen).
impl SaveRaw for &'static str {
    fn save_raw(&self, w: &mut Writer) {
        w.len(self.len());
        w.raw(self.as_bytes());
    }
}
impl SnapNew for &'static str {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        static TEXTS: std::sync::Mutex<BTreeSet<&'static str>> =
            std::sync::Mutex::new(BTreeSet::new());
        let at = r.at();
        let text = String::read(r)?;
        let mut texts = TEXTS
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(&kept) = texts.get(text.as_str()) {
            return Ok(kept);
        }
        if texts.len() >= MAX_STATIC_TEXTS {
            return Err(SnapError::Bad { what: "text", at });
        }
        let kept: &'static str = Box::leak(text.into_boxed_str());
        texts.insert(kept);
        Ok(kept)
    }
}
by_read!(&'static str);

impl SaveRaw for Duration {
    fn save_raw(&self, w: &mut Writer) {
        w.raw(&self.as_secs().to_le_bytes());
        w.raw(&self.subsec_nanos().to_le_bytes());
    }
}
impl SnapNew for Duration {
    const MIN_BYTES: usize = 12;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let secs = u64::read(r)?;
        let at = r.at();
        let nanos = u32::read(r)?;
        if nanos >= 1_000_000_000 {
            return Err(SnapError::Bad {
                what: "Duration",
                at,
            });
        }
        Ok(Duration::new(secs, nanos))
    }
}
by_read!(Duration);

impl<T: SnapNew> Snap for Option<T> {
    fn save(&self, w: &mut Writer) {
        match self {
            None => w.raw(&[0]),
            Some(v) => {
                w.raw(&[1]);
                v.save(w);
            }
        }
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        *self = Option::read(r)?;
        Ok(())
    }
}
impl<T: SnapNew> SnapNew for Option<T> {
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        match r.array::<1>("Option")? {
            [0] => Ok(None),
            [1] => T::read(r).map(Some),
            _ => Err(SnapError::Bad {
                what: "Option",
                at: r.at() - 1,
            }),
        }
    }
}

impl<T: SnapNew> Snap for Box<T> {
    fn save(&self, w: &mut Writer) {
        (**self).save(w);
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        (**self).load(r)
    }
}
impl<T: SnapNew> SnapNew for Box<T> {
    const MIN_BYTES: usize = T::MIN_BYTES;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        T::read(r).map(Box::new)
    }
}

/// A sequence's items, each made from the bytes.
fn read_seq<T: SnapNew, C: FromIterator<T>>(
    r: &mut Reader<'_>,
    what: &'static str,
) -> Result<C, SnapError> {
    let n = r.len(T::MIN_BYTES, what)?;
    (0..n).map(|_| T::read(r)).collect()
}

macro_rules! seq {
    ($($c:ident $(: $bound:path)?),*) => {$(
        impl<T: SnapNew $(+ $bound)?> Snap for $c<T> {
            fn save(&self, w: &mut Writer) {
                w.len(self.len());
                for v in self {
                    v.save(w);
                }
            }
            fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
                *self = read_seq(r, stringify!($c))?;
                Ok(())
            }
        }
        impl<T: SnapNew $(+ $bound)?> SnapNew for $c<T> {
            const MIN_BYTES: usize = 4;
            fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
                read_seq(r, stringify!($c))
            }
        }
    )*};
}

seq!(Vec, VecDeque, BTreeSet: Ord);

impl<K: SnapNew + Ord, V: SnapNew> Snap for BTreeMap<K, V> {
    fn save(&self, w: &mut Writer) {
        w.len(self.len());
        for (k, v) in self {
            k.save(w);
            v.save(w);
        }
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        *self = Self::read(r)?;
        Ok(())
    }
}
impl<K: SnapNew + Ord, V: SnapNew> SnapNew for BTreeMap<K, V> {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let n = r.len(K::MIN_BYTES + V::MIN_BYTES, "BTreeMap")?;
        (0..n).map(|_| Ok((K::read(r)?, V::read(r)?))).collect()
    }
}

/// Arrays are loaded in place (their length is their type's).
impl<T: Snap, const N: usize> Snap for [T; N] {
    fn save(&self, w: &mut Writer) {
        for v in self {
            v.save(w);
        }
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        for v in self {
            v.load(r)?;
        }
        Ok(())
    }
}
impl<T: SnapNew, const N: usize> SnapNew for [T; N] {
    const MIN_BYTES: usize = T::MIN_BYTES * N;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let v: Vec<T> = (0..N).map(|_| T::read(r)).collect::<Result<_, _>>()?;
        let at = r.at();
        v.try_into()
            .map_err(|_| SnapError::Bad { what: "array", at })
    }
}

macro_rules! tuples {
    ($(($($n:tt $t:ident),+))*) => {$(
        impl<$($t: Snap),+> Snap for ($($t,)+) {
            fn save(&self, w: &mut Writer) {
                $(self.$n.save(w);)+
            }
            fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
                $(self.$n.load(r)?;)+
                Ok(())
            }
        }
        impl<$($t: SnapNew),+> SnapNew for ($($t,)+) {
            const MIN_BYTES: usize = 0 $(+ $t::MIN_BYTES)+;
            fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
                Ok(($($t::read(r)?,)+))
            }
        }
    )*};
}

tuples! {
    (0 A)
    (0 A, 1 B)
    (0 A, 1 B, 2 C)
    (0 A, 1 B, 2 C, 3 D)
}

/// A fixed-size matrix of `f64` (vectors, 3x3, 6x6): its entries in column order.
impl<const R: usize, const C: usize> Snap for nalgebra::SMatrix<f64, R, C> {
    fn save(&self, w: &mut Writer) {
        for v in self.iter() {
            v.save(w);
        }
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        for v in self.iter_mut() {
            v.load(r)?;
        }
        Ok(())
    }
}
impl<const R: usize, const C: usize> SnapNew for nalgebra::SMatrix<f64, R, C> {
    const MIN_BYTES: usize = 8 * R * C;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let mut m = Self::zeros();
        m.load(r)?;
        Ok(m)
    }
}

/// A quaternion: its four coordinates (x, y, z, w).
impl Snap for nalgebra::Quaternion<f64> {
    fn save(&self, w: &mut Writer) {
        self.coords.save(w);
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        self.coords.load(r)
    }
}
impl SnapNew for nalgebra::Quaternion<f64> {
    const MIN_BYTES: usize = 32;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        nalgebra::Vector4::read(r).map(nalgebra::Quaternion::from)
    }
}

/// A unit quaternion: its four coordinates as they were, not normalised again (a
/// renormalisation would change the last bits).
impl Snap for nalgebra::UnitQuaternion<f64> {
    fn save(&self, w: &mut Writer) {
        self.as_ref().save(w);
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        *self = Self::read(r)?;
        Ok(())
    }
}
impl SnapNew for nalgebra::UnitQuaternion<f64> {
    const MIN_BYTES: usize = 32;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        nalgebra::Quaternion::read(r).map(nalgebra::Unit::new_unchecked)
    }
}

/// A ChaCha8 generator: its seed, stream and position in the stream.
impl Snap for rand_chacha::ChaCha8Rng {
    fn save(&self, w: &mut Writer) {
        self.get_seed().save(w);
        self.get_stream().save(w);
        self.get_word_pos().save(w);
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        *self = Self::read(r)?;
        Ok(())
    }
}
impl SnapNew for rand_chacha::ChaCha8Rng {
    const MIN_BYTES: usize = 32 + 8 + 16;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        use rand_core::SeedableRng as _;
        let seed = <[u8; 32]>::read(r)?;
        let stream = u64::read(r)?;
        let pos = u128::read(r)?;
        let mut rng = rand_chacha::ChaCha8Rng::from_seed(seed);
        rng.set_stream(stream);
        rng.set_word_pos(pos);
        Ok(rng)
    }
}

/// A list whose length is the build's (the endpoints a medium's scenario attaches): saved
/// whole, loaded in place element by element (each keeps its wiring), and a saved list of
/// another length is refused ([`SnapError::Mismatch`]). It is a `Vec` otherwise.
#[derive(Debug, Clone, PartialEq)]
pub struct Fixed<T>(pub Vec<T>);

impl<T> Default for Fixed<T> {
    fn default() -> Self {
        Fixed(Vec::new())
    }
}

impl<T> std::ops::Deref for Fixed<T> {
    type Target = Vec<T>;
    fn deref(&self) -> &Vec<T> {
        &self.0
    }
}

impl<T> std::ops::DerefMut for Fixed<T> {
    fn deref_mut(&mut self) -> &mut Vec<T> {
        &mut self.0
    }
}

impl<'a, T> IntoIterator for &'a Fixed<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.0.iter()
    }
}

impl<'a, T> IntoIterator for &'a mut Fixed<T> {
    type Item = &'a mut T;
    type IntoIter = std::slice::IterMut<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.0.iter_mut()
    }
}

impl<T: Snap> Snap for Fixed<T> {
    fn save(&self, w: &mut Writer) {
        w.len(self.0.len());
        for v in &self.0 {
            v.save(w);
        }
    }
    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        let what = std::any::type_name::<T>();
        let what = what.rsplit("::").next().unwrap_or(what);
        let n = r.len(0, what)?;
        if n != self.0.len() {
            return Err(SnapError::Mismatch {
                what,
                saved: n as u64,
                built: self.0.len() as u64,
            });
        }
        for v in &mut self.0 {
            v.load(r)?;
        }
        Ok(())
    }
}

/// Save `value` into a byte vector.
pub fn to_bytes<T: Snap + ?Sized>(value: &T) -> Vec<u8> {
    let mut w = Writer::new();
    value.save(&mut w);
    w.into_bytes()
}

/// Load `value` from `bytes`, all of them.
pub fn load_from<T: Snap + ?Sized>(value: &mut T, bytes: &[u8]) -> Result<(), SnapError> {
    let mut r = Reader::new(bytes);
    value.load(&mut r)?;
    r.finish()
}

/// [`Snap`] and [`SnapNew`] for a struct whose every field is state, by naming them all:
/// `snap::fields!(Battery { soc, temperature_c, cycles });` (`; skip a, b` keeps fields as
/// built, `; in_place` saves every field but loads them into a built value only). The
/// names are destructured exhaustively, so a field the list leaves out does not compile:
///
/// ```
/// struct Two { a: u32, b: Vec<f64> }
/// m6p_snap::fields!(Two { a, b });
/// let bytes = m6p_snap::to_bytes(&Two { a: 7, b: vec![0.5] });
/// let mut back = Two { a: 0, b: Vec::new() };
/// m6p_snap::load_from(&mut back, &bytes).unwrap();
/// assert_eq!((back.a, back.b), (7, vec![0.5]));
/// ```
///
/// ```compile_fail
/// struct Two { a: u32, b: u32 }
/// m6p_snap::fields!(Two { a });
/// ```
///
/// With `; skip x, y` after the list, only [`Snap`] is implemented and the fields named
/// there keep what the build gave them (wiring, configuration that never changes):
/// `snap::fields!(Port { queue, stats; skip name, inbox });`.
#[macro_export]
macro_rules! fields {
    ($ty:ident { $($f:ident),* $(,)? }) => {
        impl $crate::Snap for $ty {
            fn save(&self, w: &mut $crate::Writer) {
                let $ty { $($f),* } = self;
                $( $crate::Snap::save($f, w); )*
            }
            fn load(&mut self, r: &mut $crate::Reader<'_>) -> Result<(), $crate::SnapError> {
                let $ty { $($f),* } = self;
                $( $crate::Snap::load($f, r)?; )*
                Ok(())
            }
        }
        impl $crate::SnapNew for $ty {
            fn read(r: &mut $crate::Reader<'_>) -> Result<Self, $crate::SnapError> {
                Ok($ty { $($f: $crate::SnapNew::read(r)?),* })
            }
        }
    };
    // Every field saved, loaded in place (no `SnapNew`: a field needs a value built first).
    ($ty:ident { $($f:ident),* ; in_place $(,)? }) => {
        impl $crate::Snap for $ty {
            fn save(&self, w: &mut $crate::Writer) {
                let $ty { $($f),* } = self;
                $( $crate::Snap::save($f, w); )*
            }
            fn load(&mut self, r: &mut $crate::Reader<'_>) -> Result<(), $crate::SnapError> {
                let $ty { $($f),* } = self;
                $( $crate::Snap::load($f, r)?; )*
                Ok(())
            }
        }
    };
    ($ty:ident { $($f:ident),* ; skip $($s:ident),+ $(,)? }) => {
        impl $crate::Snap for $ty {
            fn save(&self, w: &mut $crate::Writer) {
                let $ty { $($f,)* $($s: _,)+ } = self;
                $( $crate::Snap::save($f, w); )*
            }
            fn load(&mut self, r: &mut $crate::Reader<'_>) -> Result<(), $crate::SnapError> {
                let $ty { $($f,)* $($s: _,)+ } = self;
                $( $crate::Snap::load($f, r)?; )*
                Ok(())
            }
        }
    };
}

/// [`Snap`] and [`SnapNew`] for a field-less `Copy` enum, as its variant's index in the
/// list: `snap::unit_enum!(Mode { Idle, Active, Safe });`; every variant must be listed
/// (the `match` is exhaustive).
#[macro_export]
macro_rules! unit_enum {
    ($ty:ident { $($v:ident),+ $(,)? }) => {
        impl $crate::Snap for $ty {
            fn save(&self, w: &mut $crate::Writer) {
                const ALL: &[$ty] = &[$($ty::$v),+];
                // Exhaustive: a variant added to the enum and not to the list fails here.
                let this = match self { $($ty::$v => $ty::$v,)+ };
                let d = std::mem::discriminant(&this);
                let at = ALL.iter().position(|x| std::mem::discriminant(x) == d).unwrap_or(0) as u32;
                $crate::Snap::save(&at, w);
            }
            fn load(&mut self, r: &mut $crate::Reader<'_>) -> Result<(), $crate::SnapError> {
                *self = <$ty as $crate::SnapNew>::read(r)?;
                Ok(())
            }
        }
        impl $crate::SnapNew for $ty {
            const MIN_BYTES: usize = 4;
            fn read(r: &mut $crate::Reader<'_>) -> Result<Self, $crate::SnapError> {
                const ALL: &[$ty] = &[$($ty::$v),+];
                let at = r.at();
                let i = <u32 as $crate::SnapNew>::read(r)? as usize;
                ALL.get(i).copied().ok_or($crate::SnapError::Bad { what: stringify!($ty), at })
            }
        }
    };
}

/// [`Snap`] and [`SnapNew`] for an enum whose variants carry data, as the variant's index in
/// the list and then its fields in order: `snap::tagged_enum!(Fate { Deliver, Drop,
/// Corrupt { bit } })`, a tuple variant with a name for each field (`Error(e)`). Every
/// variant must be listed, and every field of each (the destructurings are exhaustive):
///
/// ```
/// #[derive(Debug, PartialEq)]
/// enum Shape { Dot, Circle { r: f64 }, Pair(u8, String) }
/// m6p_snap::tagged_enum!(Shape { Dot, Circle { r }, Pair(a, b) });
/// for s in [Shape::Dot, Shape::Circle { r: 0.5 }, Shape::Pair(3, "x".into())] {
///     let bytes = m6p_snap::to_bytes(&s);
///     let back = <Shape as m6p_snap::SnapNew>::read(&mut m6p_snap::Reader::new(&bytes));
///     assert_eq!(back.unwrap(), s);
/// }
/// ```
///
/// ```compile_fail
/// enum Shape { Dot, Circle { r: f64 } }
/// m6p_snap::tagged_enum!(Shape { Dot });
/// ```
#[macro_export]
macro_rules! tagged_enum {
    ($ty:ident { $( $v:ident $( { $($f:ident),* $(,)? } )? $( ( $($p:ident),* $(,)? ) )? ),+ $(,)? }) => {
        impl $crate::Snap for $ty {
            #[allow(unused_assignments, unused_variables)]
            fn save(&self, w: &mut $crate::Writer) {
                // Exhaustive: a variant added to the enum and not to the list fails here.
                match self { $( $ty::$v { .. } => {} )+ }
                let mut tag = 0u32;
                $(
                    if let $ty::$v $( { $($f),* } )? $( ( $($p),* ) )? = self {
                        $crate::Snap::save(&tag, w);
                        $( $( $crate::Snap::save($f, w); )* )?
                        $( $( $crate::Snap::save($p, w); )* )?
                        return;
                    }
                    tag += 1;
                )+
            }
            fn load(&mut self, r: &mut $crate::Reader<'_>) -> Result<(), $crate::SnapError> {
                *self = <$ty as $crate::SnapNew>::read(r)?;
                Ok(())
            }
        }
        impl $crate::SnapNew for $ty {
            const MIN_BYTES: usize = 4;
            #[allow(unused_assignments)]
            fn read(r: &mut $crate::Reader<'_>) -> Result<Self, $crate::SnapError> {
                let at = r.at();
                let tag = <u32 as $crate::SnapNew>::read(r)?;
                let mut i = 0u32;
                $(
                    if tag == i {
                        return Ok($ty::$v
                            $( { $( $f: $crate::SnapNew::read(r)? ),* } )?
                            $( ( $( { let $p = $crate::SnapNew::read(r)?; $p } ),* ) )?
                        );
                    }
                    i += 1;
                )+
                Err($crate::SnapError::Bad { what: stringify!($ty), at })
            }
        }
    };
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use proptest::prelude::*;

    #[derive(Debug, Clone, PartialEq)]
    struct Cell {
        soc: f64,
        cycles: u32,
        history: VecDeque<(u64, bool)>,
        name: Option<String>,
    }
    fields!(Cell {
        soc,
        cycles,
        history,
        name
    });

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Mode {
        Idle,
        Active,
        Safe,
    }
    unit_enum!(Mode { Idle, Active, Safe });

    /// A value with wiring that stays as built.
    #[derive(Debug, PartialEq)]
    struct Port {
        queue: Vec<u16>,
        mode: Mode,
        name: &'static str,
    }
    fields!(Port { queue, mode; skip name });

    fn round_trip<T: SnapNew + PartialEq + std::fmt::Debug>(v: &T) {
        let bytes = to_bytes(v);
        let mut r = Reader::new(&bytes);
        let back = T::read(&mut r).unwrap();
        r.finish().unwrap();
        assert_eq!(&back, v);
        assert_eq!(to_bytes(&back), bytes, "saved again: the same bytes");
    }

    proptest! {
        /// Every value comes back as it was, floats to the last bit.
        #[test]
        fn values_come_back_as_they_were(
            soc in proptest::num::f64::ANY,
            cycles: u32,
            history in proptest::collection::vec_deque((any::<u64>(), any::<bool>()), 0..20),
            name in proptest::option::of(".{0,12}"),
            map in proptest::collection::btree_map(any::<u8>(), any::<i64>(), 0..10),
            quat in proptest::array::uniform4(proptest::num::f64::ANY),
        ) {
            let c = Cell { soc, cycles, history, name };
            let bytes = to_bytes(&c);
            let back = Cell::read(&mut Reader::new(&bytes)).unwrap();
            prop_assert_eq!(back.soc.to_bits(), soc.to_bits());
            prop_assert_eq!(to_bytes(&back), bytes);
            round_trip(&map);
            let q = nalgebra::Quaternion::new(quat[3], quat[0], quat[1], quat[2]);
            let back = nalgebra::Quaternion::read(&mut Reader::new(&to_bytes(&q))).unwrap();
            prop_assert_eq!(back.coords.map(f64::to_bits), q.coords.map(f64::to_bits));
        }

        /// Any bytes are read or refused, never more allocated than they hold.
        #[test]
        fn any_bytes_are_read_or_refused(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = Cell::read(&mut Reader::new(&bytes));
            let _ = <Vec<Vec<String>>>::read(&mut Reader::new(&bytes));
            let _ = <BTreeMap<u64, Option<Mode>>>::read(&mut Reader::new(&bytes));
        }
    }

    /// A generator saved mid-stream goes on with the same numbers.
    #[test]
    fn a_generator_goes_on_where_it_was() {
        use rand_core::{Rng as _, SeedableRng as _};
        let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..1001 {
            a.next_u32();
        }
        let bytes = to_bytes(&a);
        let mut b = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        load_from(&mut b, &bytes).unwrap();
        let next =
            |g: &mut rand_chacha::ChaCha8Rng| (0..50).map(|_| g.next_u64()).collect::<Vec<_>>();
        assert_eq!(next(&mut a), next(&mut b));
    }

    /// A load writes the state and keeps the wiring as built.
    #[test]
    fn a_load_keeps_what_is_skipped() {
        let saved = Port {
            queue: vec![1, 2, 3],
            mode: Mode::Safe,
            name: "saved",
        };
        let mut built = Port {
            queue: Vec::new(),
            mode: Mode::Idle,
            name: "built",
        };
        load_from(&mut built, &to_bytes(&saved)).unwrap();
        assert_eq!(
            built,
            Port {
                queue: vec![1, 2, 3],
                mode: Mode::Safe,
                name: "built"
            }
        );
        let m = nalgebra::Matrix3::new(1.0, -0.0, f64::NAN, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0);
        let back = nalgebra::Matrix3::read(&mut Reader::new(&to_bytes(&m))).unwrap();
        assert_eq!(back.map(f64::to_bits), m.map(f64::to_bits));
    }

    /// Bad bytes are refused with where and why.
    #[test]
    fn bad_bytes_are_refused_with_where_and_why() {
        let mut r = Reader::new(&[2]);
        assert_eq!(
            bool::read(&mut r),
            Err(SnapError::Bad {
                what: "bool",
                at: 0
            })
        );
        // A length that the rest cannot hold.
        let huge = [0xff, 0xff, 0xff, 0x7f, 1, 2];
        assert_eq!(
            <Vec<u64>>::read(&mut Reader::new(&huge)),
            Err(SnapError::Truncated { what: "Vec", at: 0 })
        );
        assert_eq!(
            load_from(&mut 0u8, &[1, 2]),
            Err(SnapError::Trailing { left: 1 })
        );
        assert_eq!(
            Mode::read(&mut Reader::new(&3u32.to_le_bytes())),
            Err(SnapError::Bad {
                what: "Mode",
                at: 0
            })
        );
        assert_eq!(
            SnapError::Truncated { what: "f64", at: 8 }.to_string(),
            "cut short reading f64 at byte 8"
        );
    }
}
