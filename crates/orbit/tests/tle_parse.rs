//! The TLE parser never panics, whatever the input, and its errors name a line and column.

use m6p_orbit::tle::{ChecksumMode, Tle, TleError, checksum};
use proptest::prelude::*;

const L1: &str = "1 25544U 98067A   20194.88612269 -.00002218  00000-0 -31515-4 0  9992";
const L2: &str = "2 25544  51.6461 221.2784 0001413  89.1723 280.4612 15.49507896236008";

fn names_a_place(e: &TleError) -> bool {
    let m = e.to_string();
    m.starts_with("line 1") || m.starts_with("line 2")
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn arbitrary_strings_never_panic(a in ".*", b in ".*") {
        for mode in [ChecksumMode::Strict, ChecksumMode::Lenient] {
            if let Err(e) = Tle::parse(&a, &b, mode) {
                prop_assert!(names_a_place(&e), "{e}");
            }
        }
    }

    #[test]
    fn mutated_valid_lines_never_panic(
        pos in 0usize..69,
        c in proptest::char::any(),
        which in 0u8..2,
    ) {
        let mut l1: Vec<char> = L1.chars().collect();
        let mut l2: Vec<char> = L2.chars().collect();
        if which == 0 { l1[pos] = c } else { l2[pos] = c }
        let l1: String = l1.into_iter().collect();
        let l2: String = l2.into_iter().collect();
        for mode in [ChecksumMode::Strict, ChecksumMode::Lenient] {
            match Tle::parse(&l1, &l2, mode) {
                Ok(t) => prop_assert!(t.mean_motion_rev_day.is_finite()),
                Err(e) => prop_assert!(names_a_place(&e), "{e}"),
            }
        }
    }

    #[test]
    fn printable_ascii_lines_never_panic(a in "[ -~]{60,75}", b in "[ -~]{60,75}") {
        let a = format!("1{}", &a[1..]);
        let b = format!("2{}", &b[1..]);
        for mode in [ChecksumMode::Strict, ChecksumMode::Lenient] {
            if let Err(e) = Tle::parse(&a, &b, mode) {
                prop_assert!(names_a_place(&e), "{e}");
            }
        }
    }
}

#[test]
fn checksum_of_reference_lines() {
    assert_eq!(checksum(L1), 2);
    assert_eq!(checksum(L2), 8);
}
