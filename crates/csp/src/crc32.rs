//! CRC-32C (Castagnoli) as libcsp 1.4 computes it (`src/csp_crc32.c`).
//!
//! Reflected, polynomial 0x1EDC6F41, init and xorout 0xFFFFFFFF; check value
//! `crc32c(b"123456789") == 0xE3069283`. In CSP 1.x the CRC covers the packet data only,
//! never the header, and is appended big-endian.
//!
//! Computed with the CPU's CRC-32C instructions where it has them (SSE4.2 on x86-64, the
//! CRC extension on ARMv8; the `crc32c` crate, detected at run time) and a table elsewhere:
//! the same values as libcsp's table code (checked against the `crc` crate's table
//! implementation in the tests).

/// Compute the CRC-32C of `data` as `csp_crc32_memory` does.
pub fn crc32c(data: &[u8]) -> u32 {
    crc32c::crc32c(data)
}

/// Append the big-endian CRC-32C of `data` to it (`csp_crc32_append`).
pub fn append(data: &mut Vec<u8>) {
    let crc = crc32c(data);
    data.extend_from_slice(&crc.to_be_bytes());
}

/// Verify and strip a trailing big-endian CRC-32C (`csp_crc32_verify`).
///
/// Returns `false` (and leaves `data` untouched) when it is shorter than 4 bytes or the
/// CRC does not match.
pub fn verify_and_strip(data: &mut Vec<u8>) -> bool {
    let Some(split) = data.len().checked_sub(4) else {
        return false;
    };
    let (body, tail) = data.split_at(split);
    let want = u32::from_be_bytes([tail[0], tail[1], tail[2], tail[3]]);
    if crc32c(body) != want {
        return false;
    }
    data.truncate(split);
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The iSCSI CRC-32C of the `crc` crate's table code, the reference.
    fn reference(data: &[u8]) -> u32 {
        crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(data)
    }

    proptest! {
        #[test]
        fn hardware_and_table_agree(data in proptest::collection::vec(any::<u8>(), 0..600)) {
            prop_assert_eq!(crc32c(&data), reference(&data));
        }
    }

    #[test]
    fn check_value() {
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[]), 0);
    }

    #[test]
    fn append_then_verify() {
        let mut d = vec![0, 1, 2, 3];
        append(&mut d);
        assert_eq!(&d[4..], &[0xd9, 0x33, 0x1a, 0xa3]);
        assert!(verify_and_strip(&mut d));
        assert_eq!(d, vec![0, 1, 2, 3]);
        d[0] ^= 1;
        let before = d.clone();
        assert!(!verify_and_strip(&mut d));
        assert_eq!(d, before);
        assert!(!verify_and_strip(&mut vec![1, 2]));
    }
}
