//! libcsp 1.4's side, through the C shim (`c/shim.c`; see the crate documentation and the
//! shim's header comment for what one iteration is). Safe wrappers: the shim sets libcsp up
//! once per process and serialises its timing functions with one lock.
#![allow(unsafe_code)]

use std::ffi::c_int;

use csp::Packet;
use csp::cfp::{CAN_MAX_DLC, CanFrame};

use crate::{Case, Error, Op, Output, PING_TIMEOUT_MS, Sample, ramp};

/// Largest KISS frame: header, 256 data bytes and the CRC all escaped, plus 3.
const KISS_OUT_MAX: usize = 2 * (4 + 256 + 4) + 3;
/// Most CAN frames a 256-byte packet takes.
const CAN_OUT_MAX: usize = 40;
/// Largest data length the shim takes (libcsp's MTU).
const MAX_LEN: usize = 256;

/// `struct m6p_frame` of the shim.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
struct RawFrame {
    id: u32,
    dlc: u8,
    data: [u8; CAN_MAX_DLC],
}

mod ffi {
    use super::RawFrame;
    use std::ffi::c_int;

    unsafe extern "C" {
        pub fn m6p_shim_init() -> c_int;
        pub fn m6p_shim_address() -> u8;
        pub fn m6p_kiss_encode(
            header: u32,
            data: *const u8,
            len: u16,
            iters: u64,
            out: *mut u8,
            cap: usize,
            out_len: *mut usize,
        ) -> i64;
        pub fn m6p_cfp_fragment(
            header: u32,
            data: *const u8,
            len: u16,
            iters: u64,
            out: *mut RawFrame,
            cap: usize,
            n: *mut usize,
        ) -> i64;
        pub fn m6p_crc32(data: *const u8, len: u32, iters: u64, crc: *mut u32) -> i64;
        pub fn m6p_ping(len: u16, timeout_ms: u32, iters: u64) -> i64;
        pub fn m6p_buffer_cycle(data: *const u8, len: u16, iters: u64) -> i64;
    }
}

/// Set libcsp up (buffers, `csp_init`, the KISS and CAN interfaces, the router task and the
/// service server thread). Idempotent; every other function calls it.
pub fn init() -> Result<(), Error> {
    // SAFETY: takes no arguments; the shim runs its setup once (pthread_once).
    let r: c_int = unsafe { ffi::m6p_shim_init() };
    if r == 0 {
        Ok(())
    } else {
        Err(Error::Libcsp {
            op: "init",
            code: i64::from(r),
        })
    }
}

/// libcsp's CSP address (`csp_init`), the ping target.
pub fn address() -> u8 {
    // SAFETY: returns a constant.
    unsafe { ffi::m6p_shim_address() }
}

/// Elapsed nanoseconds, or the error a negative return means.
fn elapsed(op: Op, r: i64) -> Result<u64, Error> {
    u64::try_from(r).map_err(|_| Error::Libcsp {
        op: op.name(),
        code: r,
    })
}

/// The data length as the shim takes it, refusing more than the MTU.
fn len16(len: usize) -> Result<u16, Error> {
    if len > MAX_LEN {
        return Err(Error::Argument("data longer than the 256-byte MTU"));
    }
    u16::try_from(len).map_err(|_| Error::Argument("data longer than the 256-byte MTU"))
}

/// `iters` KISS transmits of `packet` through libcsp's KISS interface; the last frame.
pub fn kiss_encode(packet: &Packet, iters: u64) -> Result<Sample, Error> {
    let len = len16(packet.data.len())?;
    let mut out = vec![0u8; KISS_OUT_MAX];
    let mut n = 0usize;
    // SAFETY: `data` is valid for `len` bytes, `out` for `out.len()` bytes and `n` for one
    // usize; the shim writes at most `cap` bytes and does not keep any pointer.
    let r = unsafe {
        ffi::m6p_kiss_encode(
            packet.header.to_word(),
            packet.data.as_ptr(),
            len,
            iters,
            out.as_mut_ptr(),
            out.len(),
            &mut n,
        )
    };
    let ns = elapsed(Op::KissEncode, r)?;
    out.truncate(n);
    Ok(Sample {
        iters,
        ns,
        output: Output::Kiss(out),
    })
}

/// `iters` `csp_can_tx` of `packet` into the dummy driver; the last packet's frames.
pub fn cfp_fragment(packet: &Packet, iters: u64) -> Result<Sample, Error> {
    let len = len16(packet.data.len())?;
    let mut raw = vec![RawFrame::default(); CAN_OUT_MAX];
    let mut n = 0usize;
    // SAFETY: as for kiss_encode; `raw` holds `raw.len()` frames of the shim's layout
    // (`#[repr(C)]` mirror of `struct m6p_frame`).
    let r = unsafe {
        ffi::m6p_cfp_fragment(
            packet.header.to_word(),
            packet.data.as_ptr(),
            len,
            iters,
            raw.as_mut_ptr(),
            raw.len(),
            &mut n,
        )
    };
    let ns = elapsed(Op::CfpFragment, r)?;
    let frames = raw
        .iter()
        .take(n)
        .map(|f| {
            // A DLC over 8 or an id over 29 bits would be the shim's bug: refused, not cut.
            f.data
                .get(..usize::from(f.dlc))
                .and_then(|data| CanFrame::new(f.id, data))
                .ok_or(Error::Libcsp {
                    op: Op::CfpFragment.name(),
                    code: i64::from(f.dlc),
                })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Sample {
        iters,
        ns,
        output: Output::Cfp(frames),
    })
}

/// `iters` `csp_crc32_memory` calls over `data`; the value.
pub fn crc32(data: &[u8], iters: u64) -> Result<Sample, Error> {
    let len = u32::try_from(data.len()).map_err(|_| Error::Argument("data too long"))?;
    let mut crc = 0u32;
    // SAFETY: `data` is valid for `len` bytes and `crc` for one u32.
    let r = unsafe { ffi::m6p_crc32(data.as_ptr(), len, iters, &mut crc) };
    let ns = elapsed(Op::Crc32c, r)?;
    Ok(Sample {
        iters,
        ns,
        output: Output::Crc(crc),
    })
}

/// `iters` `csp_ping` calls of `len` bytes to libcsp's own address; each must be answered.
pub fn ping(len: usize, iters: u64) -> Result<Sample, Error> {
    let len = len16(len)?;
    // SAFETY: plain values; the shim does its own allocation.
    let r = unsafe { ffi::m6p_ping(len, PING_TIMEOUT_MS, iters) };
    let ns = elapsed(Op::LoopbackPing, r)?;
    Ok(Sample {
        iters,
        ns,
        output: Output::PingAnswered,
    })
}

/// `iters` times `csp_buffer_get` + copy of `len` bytes + `csp_buffer_free`: the buffer
/// handling inside libcsp's KISS and CFP iterations. Elapsed nanoseconds.
pub fn buffer_cycle(len: usize, iters: u64) -> Result<u64, Error> {
    let data = ramp(len);
    let len = len16(len)?;
    // SAFETY: `data` is valid for `len` bytes.
    let r = unsafe { ffi::m6p_buffer_cycle(data.as_ptr(), len, iters) };
    u64::try_from(r).map_err(|_| Error::Libcsp {
        op: "buffer_cycle",
        code: r,
    })
}

/// Run `iters` iterations of `case` on libcsp.
pub fn measure(case: Case, iters: u64) -> Result<Sample, Error> {
    match case.op {
        Op::KissEncode => kiss_encode(&crate::packet(case.len), iters),
        Op::CfpFragment => cfp_fragment(&crate::packet(case.len), iters),
        Op::Crc32c => crc32(&ramp(case.len), iters),
        Op::LoopbackPing => ping(case.len, iters),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::{CASES, NODE_ADDR, Side, measure as measure_side, ours};
    use csp::cfp::{self, CfpId};
    use csp::{Header, crc32 as our_crc, kiss};

    /// Packets with every kind of byte KISS cares about: FEND and FESC in the data, a
    /// header holding FEND (src 0x18 -> 0xC0 in the first byte), empty and full data.
    fn packets() -> Vec<Packet> {
        let mut v = vec![
            crate::packet(0),
            crate::packet(4),
            crate::packet(64),
            crate::packet(200),
            crate::packet(256),
            Packet::new(Header::new(NODE_ADDR, 3, 10, 40), vec![0xC0; 100]),
            Packet::new(Header::new(NODE_ADDR, 3, 10, 40), vec![0xDB; 100]),
            Packet::new(
                Header::new(NODE_ADDR, 3, 10, 40),
                [0xC0, 0xDB, 0xDC, 0xDD].repeat(40),
            ),
        ];
        let mut h = Header::new(0x18, 0x0C, 0x36, 0x1B);
        h.flags = 0xC0;
        v.push(Packet::new(h, ramp(222)));
        v
    }

    #[test]
    fn kiss_frames_are_byte_identical() {
        for p in packets() {
            let Output::Kiss(theirs) = kiss_encode(&p, 3).unwrap().output else {
                panic!("not a KISS frame")
            };
            let mut mine = Vec::new();
            kiss::encode(&p, &mut mine);
            assert_eq!(mine, theirs, "{} with {} bytes", p.header, p.data.len());
        }
    }

    #[test]
    fn crc_values_are_identical() {
        for len in [0usize, 1, 3, 4, 9, 64, 255, 256, 1000] {
            let data: Vec<u8> = (0..len).map(|i| (i * 7 + 3) as u8).collect();
            let Output::Crc(theirs) = crc32(&data, 2).unwrap().output else {
                panic!("not a CRC")
            };
            assert_eq!(our_crc::crc32c(&data), theirs, "{len} bytes");
        }
        let Output::Crc(check) = crc32(b"123456789", 1).unwrap().output else {
            panic!("not a CRC")
        };
        assert_eq!(check, 0xE306_9283);
    }

    #[test]
    fn cfp_frames_are_identical_with_libcsps_ident() {
        for p in packets() {
            let Output::Cfp(theirs) = cfp_fragment(&p, 2).unwrap().output else {
                panic!("not CAN frames")
            };
            // Same ident as libcsp's own counter used, then the frames must be equal.
            let ident = CfpId::from_can_id(theirs[0].id).ident;
            let mut mine = Vec::new();
            cfp::fragment_with_ident(&p, p.header.dst, ident, &mut mine).unwrap();
            assert_eq!(mine, theirs, "{} with {} bytes", p.header, p.data.len());
        }
    }

    #[test]
    fn libcsp_answers_its_loopback_ping() {
        assert_eq!(address(), NODE_ADDR);
        for len in [0usize, 1, 64, 200] {
            let s = ping(len, 3).unwrap();
            assert_eq!(s.output, Output::PingAnswered, "{len}");
        }
    }

    #[test]
    fn every_case_runs_on_both_sides_with_the_same_output() {
        for case in CASES {
            let theirs = measure_side(Side::Libcsp, case, 2).unwrap();
            let mine = ours::measure(case, 2).unwrap();
            assert!(mine.output.same_as(&theirs.output), "{case:?}");
            assert_eq!(theirs.iters, 2);
        }
        assert!(buffer_cycle(64, 10).is_ok());
    }

    #[test]
    fn oversized_data_is_refused() {
        assert!(matches!(
            kiss_encode(&crate::packet(257), 1),
            Err(Error::Argument(_))
        ));
    }
}
