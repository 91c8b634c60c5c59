//! Impairments a scenario can apply to a medium: drop, corrupt and delay, drawn from the
//! medium's own seeded generator so that a run is repeatable.

use std::time::Duration;

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

/// Impairments of a medium.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Impairments {
    /// Probability that a frame or packet is lost.
    pub drop_prob: f64,
    /// Probability that one bit of its data is flipped.
    pub corrupt_prob: f64,
    /// Extra delay before delivery.
    pub delay: Duration,
    /// The medium is down: everything is lost.
    pub down: bool,
}

impl Impairments {
    /// Whether nothing is impaired.
    pub fn is_clear(&self) -> bool {
        *self == Impairments::default()
    }
}

/// What the impairments decided for one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fate {
    /// Delivered as sent.
    Deliver,
    /// Lost.
    Drop,
    /// Delivered with bit `bit` of the data flipped.
    Corrupt {
        /// Bit index, modulo the data length in bits.
        bit: u32,
    },
}

/// The seeded generator behind a medium's impairments.
#[derive(Debug, Clone)]
pub struct ImpairRng(ChaCha8Rng);

impl ImpairRng {
    /// A generator from the run's seed and the medium's name.
    pub fn new(seed: u64, medium: &str) -> Self {
        // Mix the name in so two media with the same seed draw different streams.
        let mut h: u64 = seed ^ 0x9E37_79B9_7F4A_7C15;
        for b in medium.bytes() {
            h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3);
        }
        ImpairRng(ChaCha8Rng::seed_from_u64(h))
    }

    fn unit(&mut self) -> f64 {
        (self.0.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Decide one frame's fate. Draws nothing while the impairments are clear, so a run
    /// without faults does not depend on the generator at all.
    pub fn fate(&mut self, imp: &Impairments) -> Fate {
        if imp.down {
            return Fate::Drop;
        }
        if imp.drop_prob > 0.0 && self.unit() < imp.drop_prob {
            return Fate::Drop;
        }
        if imp.corrupt_prob > 0.0 && self.unit() < imp.corrupt_prob {
            return Fate::Corrupt {
                bit: self.0.next_u32(),
            };
        }
        Fate::Deliver
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clear_impairments_always_deliver() {
        let mut r = ImpairRng::new(1, "main");
        assert!((0..1000).all(|_| r.fate(&Impairments::default()) == Fate::Deliver));
    }

    #[test]
    fn drop_rate_follows_probability_and_seed() {
        let imp = Impairments {
            drop_prob: 0.25,
            ..Default::default()
        };
        let count = |seed| {
            let mut r = ImpairRng::new(seed, "main");
            (0..10_000).filter(|_| r.fate(&imp) == Fate::Drop).count()
        };
        let n = count(7);
        assert!((2200..2800).contains(&n), "{n}");
        assert_eq!(n, count(7));
        assert_ne!(n, count(8));
    }
}
