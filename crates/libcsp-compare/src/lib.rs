//! Side by side: the project's CSP stack (`m6p-csp`) against the vendored, unmodified
//! libcsp 1.4 (`third_party/libcsp-1.4/`, LGPL-2.1, linked only into this crate's tests and
//! benchmark, never into the twin), for issue 17.
//!
//! `build.rs` builds libcsp with `third_party/libcsp-1.4/build.sh` and a C shim over it
//! (`c/shim.c`). Both sides run one operation `iters` times in a loop and report the
//! elapsed time of the whole loop (libcsp: `clock_gettime(CLOCK_MONOTONIC)` inside the C
//! loop, so the call from Rust is not counted; ours: [`std::time::Instant`], the same clock,
//! around the Rust loop). One iteration is, per [`Op`]:
//!
//! | op | libcsp 1.4 | ours |
//! |---|---|---|
//! | [`Op::KissEncode`] | `csp_buffer_get`, header and data copied in, the KISS interface's transmit (`csp_kiss_tx`: CRC32C appended, header to network order, each byte through the putc callback into memory, buffer freed). It consumes the buffer, so getting and filling one is part of it. | [`csp::kiss::encode`] of the same packet into a cleared, reused `Vec` |
//! | [`Op::CfpFragment`] | `csp_buffer_get` + copy, `csp_can_tx` (timeout 0) into a dummy driver whose `can_send` copies the frame; the driver's "transmit complete" (`csp_tx_callback`) sends each next frame; libcsp frees the packet after the last | [`csp::cfp::Fragmenter::fragment`] of the same packet into a cleared, reused `Vec` |
//! | [`Op::Crc32c`] | `csp_crc32_memory` (table, a byte at a time) | [`csp::crc32::crc32c`] (the CPU's CRC instructions where present) |
//! | [`Op::LoopbackPing`] | `csp_ping` to its own address, timeout 1000 ms: connect, buffer, send through the loopback interface to the router task, a server thread accepts, reads and answers with `csp_service_handler`, the router hands the echo back, read, check, close (threads and queues: wake-up latency dominates) | a [`csp::node::Node`] with no interface pings its own address with [`csp::client::Client`] (ephemeral port, timeout 1000 ms): the request goes through the node's loopback queue to its service handler, whose echo comes back the same way; [`csp::node::Node::poll_delivery`], match, check, port released. All in the calling thread, no tokio |
//!
//! [`libcsp::buffer_cycle`] times libcsp's `csp_buffer_get` + copy + `csp_buffer_free`
//! alone, the buffer handling inside its KISS and CFP iterations, for reference.
//!
//! Both sides produce the same bytes for the same input: [`Output::same_as`] compares the
//! last iteration's KISS frame, CAN frames (the 10-bit CFP ident aside: libcsp draws its
//! first one from `rand()`) and CRC value, and the crate's tests check them exactly.

use csp::cfp::{CanFrame, IDENT_MASK};
use csp::{Header, Packet};

#[cfg(libcsp_shim)]
pub mod libcsp;
pub mod ours;

/// The CSP address of both sides' node (libcsp's `csp_init` address; the ping target).
pub const NODE_ADDR: u8 = 10;
/// Ping timeout on both sides, as the issue asks.
pub const PING_TIMEOUT_MS: u32 = 1000;

/// One operation of the comparison (see the crate documentation for what is timed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Op {
    /// One KISS frame of a packet.
    KissEncode,
    /// The CFP frames of a packet.
    CfpFragment,
    /// The CRC-32C of a buffer.
    Crc32c,
    /// A ping to the node's own address, answered through its loopback.
    LoopbackPing,
}

impl Op {
    /// Short name for tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Op::KissEncode => "kiss_encode",
            Op::CfpFragment => "cfp_fragment",
            Op::Crc32c => "crc32c",
            Op::LoopbackPing => "loopback_ping",
        }
    }
}

/// One row of the comparison: an operation on `len` data bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Case {
    /// The operation.
    pub op: Op,
    /// CSP data bytes (CRC: bytes checked).
    pub len: usize,
}

/// The rows issue 17 asks for.
pub const CASES: [Case; 7] = [
    Case {
        op: Op::KissEncode,
        len: 64,
    },
    Case {
        op: Op::KissEncode,
        len: 200,
    },
    Case {
        op: Op::CfpFragment,
        len: 64,
    },
    Case {
        op: Op::CfpFragment,
        len: 200,
    },
    Case {
        op: Op::Crc32c,
        len: 64,
    },
    Case {
        op: Op::Crc32c,
        len: 256,
    },
    Case {
        op: Op::LoopbackPing,
        len: 64,
    },
];

/// Which implementation runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Side {
    /// The vendored libcsp 1.4, through the C shim.
    Libcsp,
    /// The project's `m6p-csp`.
    Ours,
}

impl Side {
    /// Short name for tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Side::Libcsp => "libcsp",
            Side::Ours => "ours",
        }
    }
}

/// Why a measurement failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The crate was built without libcsp (no C compiler; see `build.rs`).
    #[error(
        "libcsp 1.4 was not built (no C compiler `cc`; install one, e.g. Debian's gcc, and rebuild)"
    )]
    Unavailable,
    /// The shim or libcsp reported an error (negative codes: libcsp's `CSP_ERR_*`, or the
    /// shim's own from -1001).
    #[error("libcsp {op} failed with code {code}")]
    Libcsp {
        /// The operation.
        op: &'static str,
        /// The code it returned.
        code: i64,
    },
    /// Our side failed (a send refused, a ping not answered, a wrong echo).
    #[error("our {op} failed: {detail}")]
    Ours {
        /// The operation.
        op: &'static str,
        /// What went wrong.
        detail: String,
    },
    /// The case cannot be run (data longer than the 256-byte MTU).
    #[error("{0}")]
    Argument(&'static str),
}

/// What the last iteration of a measurement produced.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Output {
    /// A KISS frame.
    Kiss(Vec<u8>),
    /// The CAN frames of one packet.
    Cfp(Vec<CanFrame>),
    /// A CRC value.
    Crc(u32),
    /// A ping was answered with the right echo.
    PingAnswered,
}

impl Output {
    /// Whether two sides produced the same: equal bytes, except that CAN ids are compared
    /// without their 10-bit CFP ident (a per-sender counter libcsp starts at `rand()`).
    pub fn same_as(&self, other: &Output) -> bool {
        match (self, other) {
            (Output::Cfp(a), Output::Cfp(b)) => {
                let strip = |f: &CanFrame| (f.id & !u32::from(IDENT_MASK), f.dlc, f.data);
                a.len() == b.len() && a.iter().map(strip).eq(b.iter().map(strip))
            }
            _ => self == other,
        }
    }
}

/// One measurement: `iters` iterations took `ns` nanoseconds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sample {
    /// Iterations run.
    pub iters: u64,
    /// Elapsed nanoseconds for all of them.
    pub ns: u64,
    /// What the last iteration produced.
    pub output: Output,
}

impl Sample {
    /// Nanoseconds per iteration.
    pub fn ns_per_iter(&self) -> f64 {
        self.ns as f64 / self.iters.max(1) as f64
    }
}

/// The packet both sides encode and fragment: node 10 to node 3, port 10, source port 40,
/// normal priority, no flags, data `0, 1, 2, ...` (from 192 bytes on it holds 0xC0, which
/// KISS escapes).
pub fn packet(len: usize) -> Packet {
    Packet::new(Header::new(NODE_ADDR, 3, 10, 40), ramp(len))
}

/// `len` bytes counting up from 0 (wrapping), as `csp_ping` fills its data.
pub fn ramp(len: usize) -> Vec<u8> {
    (0..len).map(|i| i as u8).collect()
}

/// Run `iters` iterations of `case` on `side`.
pub fn measure(side: Side, case: Case, iters: u64) -> Result<Sample, Error> {
    match side {
        Side::Ours => ours::measure(case, iters),
        Side::Libcsp => measure_libcsp(case, iters),
    }
}

fn measure_libcsp(case: Case, iters: u64) -> Result<Sample, Error> {
    #[cfg(libcsp_shim)]
    {
        libcsp::measure(case, iters)
    }
    #[cfg(not(libcsp_shim))]
    {
        let _ = (case, iters);
        Err(Error::Unavailable)
    }
}

/// Whether libcsp was built into this crate.
pub fn libcsp_available() -> bool {
    cfg!(libcsp_shim)
}

/// Set libcsp up ([`libcsp::init`]); [`Error::Unavailable`] without it.
pub fn libcsp_init() -> Result<(), Error> {
    #[cfg(libcsp_shim)]
    {
        libcsp::init()
    }
    #[cfg(not(libcsp_shim))]
    {
        Err(Error::Unavailable)
    }
}

/// libcsp's buffer handling alone ([`libcsp::buffer_cycle`]): elapsed nanoseconds for
/// `iters` cycles on `len` bytes; [`Error::Unavailable`] without libcsp.
pub fn libcsp_buffer_cycle(len: usize, iters: u64) -> Result<u64, Error> {
    #[cfg(libcsp_shim)]
    {
        libcsp::buffer_cycle(len, iters)
    }
    #[cfg(not(libcsp_shim))]
    {
        let _ = (len, iters);
        Err(Error::Unavailable)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    #[cfg_attr(
        not(libcsp_shim),
        ignore = "libcsp 1.4 not built: no C compiler `cc` (or M6P_LIBCSP_PROBE=off)"
    )]
    fn libcsp_is_built() {
        // The comparison tests proper are in `libcsp::tests`; they exist only with libcsp.
        assert!(libcsp_available());
    }

    #[test]
    fn our_side_runs_every_case() {
        for case in CASES {
            let s = measure(Side::Ours, case, 3).unwrap();
            assert_eq!(s.iters, 3);
            let expected = match case.op {
                Op::KissEncode => {
                    let mut v = Vec::new();
                    csp::kiss::encode(&packet(case.len), &mut v);
                    Output::Kiss(v)
                }
                Op::CfpFragment => {
                    // The fragmenter starts at ident 0 and counts up: the third has 2.
                    let mut v = Vec::new();
                    csp::cfp::fragment_with_ident(&packet(case.len), 3, 2, &mut v).unwrap();
                    Output::Cfp(v)
                }
                Op::Crc32c => Output::Crc(csp::crc32::crc32c(&ramp(case.len))),
                Op::LoopbackPing => Output::PingAnswered,
            };
            assert_eq!(s.output, expected, "{case:?}");
        }
    }

    #[test]
    fn same_as_ignores_only_the_cfp_ident() {
        let frames = |ident, last: u8| {
            let mut v = Vec::new();
            let mut p = packet(20);
            p.data[19] = last;
            csp::cfp::fragment_with_ident(&p, 3, ident, &mut v).unwrap();
            Output::Cfp(v)
        };
        assert!(frames(1, 0).same_as(&frames(700, 0)));
        assert!(!frames(1, 0).same_as(&frames(1, 1)));
        assert!(!Output::Crc(1).same_as(&Output::Crc(2)));
        assert!(Output::Kiss(vec![1]).same_as(&Output::Kiss(vec![1])));
    }
}
