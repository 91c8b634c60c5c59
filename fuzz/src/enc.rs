//! The inverse of `arbitrary`'s decoding, for the seed generator: [`Enc`] writes the bytes
//! that `arbitrary` 1.x (`Unstructured`) decodes back to the same value.
//!
//! The format (arbitrary 1.5, `derive_arbitrary` 1.5):
//! - integers: `size_of` bytes, little-endian; `bool`: one byte, bit 0;
//! - an enum: a `u32` `v` with `(v * variant_count) >> 32 == index`, then the variant's fields;
//! - a struct: its fields in order;
//! - `Vec<T>`: each element preceded by a byte with bit 0 set, then a byte `0` (end);
//! - `Option<T>`: a `bool`, then the value when `true`; arrays: their elements.
//!
//! The seed generator checks every seed by decoding it again ([`roundtrip`]), so a change
//! of the format in a later `arbitrary` shows up as a failing generator, not as silently
//! useless seeds.

use arbitrary::{Arbitrary, Unstructured};

/// Write the bytes `arbitrary` decodes to `self`.
pub trait Enc {
    /// Append the encoding to `out`.
    fn enc(&self, out: &mut Vec<u8>);
}

macro_rules! ints {
    ($($t:ty),*) => {$(
        impl Enc for $t {
            fn enc(&self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
        }
    )*};
}
ints!(u8, u16, u32, u64, i8, i16, i32, i64);

impl Enc for bool {
    fn enc(&self, out: &mut Vec<u8>) {
        out.push(u8::from(*self));
    }
}

impl Enc for () {
    fn enc(&self, _out: &mut Vec<u8>) {}
}

impl<T: Enc> Enc for Vec<T> {
    fn enc(&self, out: &mut Vec<u8>) {
        for x in self {
            out.push(1);
            x.enc(out);
        }
        out.push(0);
    }
}

impl<T: Enc> Enc for Option<T> {
    fn enc(&self, out: &mut Vec<u8>) {
        match self {
            None => out.push(0),
            Some(x) => {
                out.push(1);
                x.enc(out);
            }
        }
    }
}

impl<T: Enc, const N: usize> Enc for [T; N] {
    fn enc(&self, out: &mut Vec<u8>) {
        for x in self {
            x.enc(out);
        }
    }
}

impl<A: Enc, B: Enc> Enc for (A, B) {
    fn enc(&self, out: &mut Vec<u8>) {
        self.0.enc(out);
        self.1.enc(out);
    }
}

/// Write the discriminant of variant `index` of an enum of `count` variants.
pub fn variant(out: &mut Vec<u8>, index: usize, count: usize) {
    assert!(index < count, "variant {index} of {count}");
    let (i, n) = (index as u64, count as u64);
    // The smallest v with (v * n) >> 32 == i: ceil(i * 2^32 / n).
    let v = ((i << 32) + n - 1) / n;
    let v = u32::try_from(v).expect("fits: i < n");
    debug_assert_eq!((u64::from(v) * n) >> 32, i);
    out.extend_from_slice(&v.to_le_bytes());
}

/// Encode a sequence of values back to back (a target that decodes `T` until the input
/// runs out).
pub fn seq<T: Enc>(items: &[T]) -> Vec<u8> {
    let mut out = Vec::new();
    for x in items {
        x.enc(&mut out);
    }
    out
}

/// Decode `bytes` as back-to-back `T`s, as the targets do (stopping at the end of the input).
pub fn decode_seq<'a, T: Arbitrary<'a>>(bytes: &'a [u8]) -> Vec<T> {
    let mut u = Unstructured::new(bytes);
    let mut out = Vec::new();
    while !u.is_empty() {
        match T::arbitrary(&mut u) {
            Ok(x) => out.push(x),
            Err(_) => break,
        }
    }
    out
}

/// Check that `bytes` decodes back to `items`; panics with both when not.
pub fn roundtrip<'a, T>(items: &[T], bytes: &'a [u8])
where
    T: Arbitrary<'a> + PartialEq + std::fmt::Debug,
{
    let back: Vec<T> = decode_seq(bytes);
    assert_eq!(back.as_slice(), items, "seed encoding does not decode back");
}
