//! The ICD's request-reply framing (ICD 1.8, INTERPRETATION.md section 2), as a reusable
//! typed layer.
//!
//! - Request payload: `command id (u8) | request data (N)`.
//! - Reply payload: `command id (u8, echoed) | result code (u8) | reply data (N)`.
//! - Result 1 = success, 0 = failure. Multi-byte fields are little-endian; floats IEEE-754.
//! - Unknown command, wrong request length or out-of-range value: result 0 and no data.
//!
//! [`Request`] and [`Reply`] are the `Repr`s of the framing; [`CommandSet`] is what a node's
//! port implements to turn request bytes into a typed command (a later issue's TMGEN,
//! SETUP, ...), and [`serve`] turns any request into exactly one reply. [`crate::client::Client`] is the
//! requesting side, on a node. [`le`] has the little-endian cursor used by every layout.

use crate::Error;

/// Result code of a failed command.
pub const RESULT_FAILURE: u8 = 0;
/// Result code of a successful command.
pub const RESULT_SUCCESS: u8 = 1;

/// A request: `command | data`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Request<'a> {
    /// Command id.
    pub command: u8,
    /// Request data.
    pub data: &'a [u8],
}

impl<'a> Request<'a> {
    /// Parse request bytes; an empty payload has no command id.
    pub fn parse(buf: &'a [u8]) -> Result<Self, Error> {
        let (&command, data) = buf.split_first().ok_or(Error::Truncated)?;
        Ok(Request { command, data })
    }
    /// Length of the emitted request.
    pub fn buffer_len(&self) -> usize {
        1 + self.data.len()
    }
    /// Append the request bytes to `out`.
    pub fn emit(&self, out: &mut Vec<u8>) {
        out.push(self.command);
        out.extend_from_slice(self.data);
    }
    /// The request bytes.
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.buffer_len());
        self.emit(&mut v);
        v
    }
}

/// A reply: `command | result | data`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reply<'a> {
    /// Command id, echoed from the request.
    pub command: u8,
    /// Result code (1 success, 0 failure, or command-specific).
    pub result: u8,
    /// Reply data.
    pub data: &'a [u8],
}

impl<'a> Reply<'a> {
    /// Parse reply bytes (at least command and result).
    pub fn parse(buf: &'a [u8]) -> Result<Self, Error> {
        match buf {
            [command, result, data @ ..] => Ok(Reply {
                command: *command,
                result: *result,
                data,
            }),
            _ => Err(Error::Truncated),
        }
    }
    /// Length of the emitted reply.
    pub fn buffer_len(&self) -> usize {
        2 + self.data.len()
    }
    /// Append the reply bytes to `out`.
    pub fn emit(&self, out: &mut Vec<u8>) {
        out.push(self.command);
        out.push(self.result);
        out.extend_from_slice(self.data);
    }
    /// The reply bytes.
    pub fn to_vec(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.buffer_len());
        self.emit(&mut v);
        v
    }
    /// Whether the result is success (1).
    pub fn is_success(&self) -> bool {
        self.result == RESULT_SUCCESS
    }
}

/// The failure reply for `command`: result 0, no data.
pub fn failure(command: u8) -> Vec<u8> {
    vec![command, RESULT_FAILURE]
}

/// The success reply for `command` with `data`.
pub fn success(command: u8, data: &[u8]) -> Vec<u8> {
    Reply {
        command,
        result: RESULT_SUCCESS,
        data,
    }
    .to_vec()
}

/// Why a request was refused (every case becomes a failure reply).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RequestError {
    /// Empty payload: no command id.
    #[error("empty request (no command id)")]
    Empty,
    /// The command id is not in the port's table.
    #[error("unknown command id {0}")]
    UnknownCommand(u8),
    /// The request data has the wrong length.
    #[error("command {command}: request data is {got} bytes, expected {expected}")]
    WrongLength {
        /// Command id.
        command: u8,
        /// What the table says.
        expected: &'static str,
        /// What arrived.
        got: usize,
    },
    /// A field is outside its range.
    #[error("command {command}: {field} out of range")]
    OutOfRange {
        /// Command id.
        command: u8,
        /// Which field.
        field: &'static str,
    },
}

/// A port's command table: typed commands parsed from request bytes.
pub trait CommandSet: Sized {
    /// Parse a request into a command.
    fn parse(request: &Request<'_>) -> Result<Self, RequestError>;
}

/// Check that a request's data is exactly `len` bytes.
pub fn expect_len(
    request: &Request<'_>,
    len: usize,
    expected: &'static str,
) -> Result<(), RequestError> {
    if request.data.len() == len {
        Ok(())
    } else {
        Err(RequestError::WrongLength {
            command: request.command,
            expected,
            got: request.data.len(),
        })
    }
}

/// Answer one request: parse it with `C`, run `handler` on the command, and build the reply.
///
/// `handler` returns `Ok(data)` for success (result 1) or `Err(code)` for a result code
/// other than success. A request that does not parse gets result 0 and no data, and the
/// reason is returned for the log. An empty request is answered as command 0.
pub fn serve<C: CommandSet>(
    payload: &[u8],
    handler: impl FnOnce(C) -> Result<Vec<u8>, u8>,
) -> (Vec<u8>, Option<RequestError>) {
    let Ok(request) = Request::parse(payload) else {
        return (failure(0), Some(RequestError::Empty));
    };
    match C::parse(&request) {
        Ok(cmd) => match handler(cmd) {
            Ok(data) => (success(request.command, &data), None),
            Err(code) => (vec![request.command, code], None),
        },
        Err(e) => (failure(request.command), Some(e)),
    }
}

/// Little-endian cursors for ICD layouts.
pub mod le {
    use crate::Error;

    /// Reads little-endian fields from a byte slice; every read checks the length.
    #[derive(Debug, Clone)]
    pub struct Reader<'a> {
        buf: &'a [u8],
    }

    macro_rules! read_fn {
        ($name:ident, $t:ty) => {
            #[doc = concat!("Read a little-endian `", stringify!($t), "`.")]
            pub fn $name(&mut self) -> Result<$t, Error> {
                let bytes = self.take(std::mem::size_of::<$t>())?;
                let mut arr = [0u8; std::mem::size_of::<$t>()];
                arr.copy_from_slice(bytes);
                Ok(<$t>::from_le_bytes(arr))
            }
        };
    }

    impl<'a> Reader<'a> {
        /// A reader over `buf`.
        pub fn new(buf: &'a [u8]) -> Self {
            Reader { buf }
        }
        /// Take the next `n` bytes.
        pub fn take(&mut self, n: usize) -> Result<&'a [u8], Error> {
            if self.buf.len() < n {
                return Err(Error::Truncated);
            }
            let (head, tail) = self.buf.split_at(n);
            self.buf = tail;
            Ok(head)
        }
        /// Bytes not read yet.
        pub fn remaining(&self) -> &'a [u8] {
            self.buf
        }
        /// Fail unless everything was read.
        pub fn finish(&self) -> Result<(), Error> {
            if self.buf.is_empty() {
                Ok(())
            } else {
                Err(Error::TooLong)
            }
        }
        read_fn!(u8, u8);
        read_fn!(i8, i8);
        read_fn!(u16, u16);
        read_fn!(u32, u32);
        read_fn!(u64, u64);
        read_fn!(i32, i32);
        read_fn!(f32, f32);
        read_fn!(f64, f64);
    }

    /// Appends little-endian fields to a vector.
    #[derive(Debug, Default)]
    pub struct Writer {
        /// The bytes written so far.
        pub buf: Vec<u8>,
    }

    macro_rules! write_fn {
        ($name:ident, $t:ty) => {
            #[doc = concat!("Append a little-endian `", stringify!($t), "`.")]
            pub fn $name(&mut self, v: $t) -> &mut Self {
                self.buf.extend_from_slice(&v.to_le_bytes());
                self
            }
        };
    }

    impl Writer {
        /// An empty writer.
        pub fn new() -> Self {
            Self::default()
        }
        /// Append raw bytes.
        pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
            self.buf.extend_from_slice(b);
            self
        }
        write_fn!(u8, u8);
        write_fn!(i8, i8);
        write_fn!(u16, u16);
        write_fn!(u32, u32);
        write_fn!(u64, u64);
        write_fn!(i32, i32);
        write_fn!(f32, f32);
        write_fn!(f64, f64);
    }

    /// A fixed-size little-endian layout (an ICD table, or one the twin defines): read and
    /// written field by field, parsed only from exactly [`Repr::LEN`] bytes.
    pub trait Repr: Sized {
        /// Size in bytes.
        const LEN: usize;
        /// Read the fields from `r` (which holds at least `LEN` bytes).
        fn read(r: &mut Reader<'_>) -> Result<Self, Error>;
        /// Append the fields to `w`.
        fn write(&self, w: &mut Writer);

        /// Parse exactly `LEN` bytes.
        fn parse(buf: &[u8]) -> Result<Self, Error> {
            if buf.len() < Self::LEN {
                return Err(Error::Truncated);
            }
            if buf.len() > Self::LEN {
                return Err(Error::TooLong);
            }
            let mut r = Reader::new(buf);
            let v = Self::read(&mut r)?;
            r.finish()?;
            Ok(v)
        }
        /// Length of the emitted bytes.
        fn buffer_len(&self) -> usize {
            Self::LEN
        }
        /// Append the bytes to `out`.
        fn emit(&self, out: &mut Vec<u8>) {
            let mut w = Writer {
                buf: std::mem::take(out),
            };
            self.write(&mut w);
            *out = w.buf;
        }
        /// The bytes.
        fn to_vec(&self) -> Vec<u8> {
            let mut v = Vec::with_capacity(Self::LEN);
            self.emit(&mut v);
            v
        }
    }

    macro_rules! array_fn {
        ($name:ident, $t:ty, $read:ident) => {
            #[doc = concat!("Read `N` little-endian `", stringify!($t), "`s.")]
            pub fn $name<const N: usize>(r: &mut Reader<'_>) -> Result<[$t; N], Error> {
                let mut a = [<$t>::default(); N];
                for x in &mut a {
                    *x = r.$read()?;
                }
                Ok(a)
            }
        };
    }

    array_fn!(u8s, u8, u8);
    array_fn!(i8s, i8, i8);
    array_fn!(u16s, u16, u16);
    array_fn!(u32s, u32, u32);
    array_fn!(f32s, f32, f32);
    array_fn!(f64s, f64, f64);
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A two-command table in the style of the ICD's: GET (1, no data), SET (2, u16 LE).
    #[derive(Debug, PartialEq)]
    enum Demo {
        Get,
        Set(u16),
    }

    impl CommandSet for Demo {
        fn parse(r: &Request<'_>) -> Result<Self, RequestError> {
            match r.command {
                1 => expect_len(r, 0, "0").map(|_| Demo::Get),
                2 => {
                    expect_len(r, 2, "2")?;
                    let v = le::Reader::new(r.data)
                        .u16()
                        .map_err(|_| RequestError::Empty)?;
                    if v > 1000 {
                        return Err(RequestError::OutOfRange {
                            command: 2,
                            field: "value",
                        });
                    }
                    Ok(Demo::Set(v))
                }
                c => Err(RequestError::UnknownCommand(c)),
            }
        }
    }

    fn run(payload: &[u8]) -> (Vec<u8>, Option<RequestError>) {
        serve::<Demo>(payload, |c| match c {
            Demo::Get => Ok(vec![0x34, 0x12]),
            Demo::Set(_) => Ok(vec![]),
        })
    }

    #[test]
    fn success_echoes_command_and_result_1() {
        assert_eq!(run(&[1]), (vec![1, 1, 0x34, 0x12], None));
        assert_eq!(run(&[2, 0xe8, 0x03]), (vec![2, 1], None));
    }

    #[test]
    fn failures_have_result_0_and_no_data() {
        assert_eq!(run(&[9]).0, vec![9, 0]);
        assert_eq!(run(&[1, 0]).0, vec![1, 0]);
        assert_eq!(run(&[2, 0xe9, 0x03]).0, vec![2, 0]);
        assert_eq!(run(&[2, 0xe8]).0, vec![2, 0]);
        assert_eq!(run(&[]), (vec![0, 0], Some(RequestError::Empty)));
    }

    #[test]
    fn reply_repr_round_trip() {
        let r = Reply::parse(&[6, 1, 0xaa]).unwrap();
        assert_eq!((r.command, r.result, r.data), (6, 1, &[0xaa][..]));
        assert_eq!(r.to_vec(), vec![6, 1, 0xaa]);
        assert!(Reply::parse(&[6]).is_err());
        assert_eq!(Request::parse(&[3, 4]).unwrap().to_vec(), vec![3, 4]);
    }

    #[test]
    fn le_reader_checks_lengths() {
        let mut w = le::Writer::new();
        w.u32(1_577_836_800).f64(-1.5).u8(7);
        let mut r = le::Reader::new(&w.buf);
        assert_eq!(r.u32().unwrap(), 1_577_836_800);
        assert_eq!(r.f64().unwrap(), -1.5);
        assert_eq!(r.u8().unwrap(), 7);
        assert!(r.finish().is_ok());
        assert_eq!(r.u8(), Err(Error::Truncated));
    }
}
