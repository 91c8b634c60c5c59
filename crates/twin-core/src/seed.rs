//! The run seed's streams: every random draw of a run has its own, derived from the one
//! seed ([`mix`]), so that adding a draw somewhere changes no other.

/// The first ephemeral port node `addr`'s allocator tries in a run of `seed` (libcsp 1.4
/// starts at `rand()`): 32 to 63.
pub fn first_ephemeral_port(seed: u64, addr: u8) -> u8 {
    32 + (mix(seed, u64::from(addr) + 0x40) % 32) as u8
}

/// A well-mixed 64-bit value from the run seed and a salt (splitmix64).
pub fn mix(seed: u64, salt: u64) -> u64 {
    let mut z = seed ^ salt.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
