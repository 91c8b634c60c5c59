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

/// The impairments of a medium's active faults, each under its own id, and what they make
/// together: drop and corrupt probabilities combine as independent chances (a frame
/// survives only if it survives every fault), delays add, and a fault that takes the medium
/// down dominates. Lifting one fault leaves the others as they were.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImpairmentSet {
    active: std::collections::BTreeMap<u32, Impairments>,
}

impl ImpairmentSet {
    /// Fault `id` impairs with `imp` (`Some`) or is lifted (`None`).
    pub fn set(&mut self, id: u32, imp: Option<Impairments>) {
        match imp {
            Some(imp) => {
                self.active.insert(id, imp);
            }
            None => {
                self.active.remove(&id);
            }
        }
    }

    /// Whether no fault is active.
    pub fn is_empty(&self) -> bool {
        self.active.is_empty()
    }

    /// The combined impairments (exactly the fault's own when there is one).
    pub fn combined(&self) -> Impairments {
        let mut it = self.active.values();
        let Some(first) = it.next() else {
            return Impairments::default();
        };
        let mut c = *first;
        for imp in it {
            c.drop_prob = 1.0 - (1.0 - c.drop_prob) * (1.0 - imp.drop_prob);
            c.corrupt_prob = 1.0 - (1.0 - c.corrupt_prob) * (1.0 - imp.corrupt_prob);
            c.delay += imp.delay;
            c.down |= imp.down;
        }
        c
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

// The state a snapshot saves (docs/snapshots.md).
snap::fields!(Impairments {
    drop_prob,
    corrupt_prob,
    delay,
    down
});
snap::fields!(ImpairmentSet { active });
snap::tagged_enum!(Fate {
    Deliver,
    Drop,
    Corrupt { bit }
});

/// Where the generator is in its stream.
impl snap::Snap for ImpairRng {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.0.load(r)
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
    fn faults_compose_and_lifting_one_leaves_the_others() {
        let mut set = ImpairmentSet::default();
        let drop = Impairments {
            drop_prob: 0.5,
            ..Default::default()
        };
        set.set(0, Some(drop));
        assert_eq!(set.combined(), drop, "one fault: exactly its own");
        set.set(
            1,
            Some(Impairments {
                delay: Duration::from_millis(50),
                drop_prob: 0.5,
                ..Default::default()
            }),
        );
        set.set(
            2,
            Some(Impairments {
                delay: Duration::from_millis(20),
                ..Default::default()
            }),
        );
        let c = set.combined();
        assert_eq!(c.drop_prob, 0.75);
        assert_eq!(c.delay, Duration::from_millis(70));
        assert!(!c.down);
        set.set(
            3,
            Some(Impairments {
                down: true,
                ..Default::default()
            }),
        );
        assert!(set.combined().down);
        set.set(3, None);
        set.set(1, None);
        assert_eq!(set.combined().drop_prob, 0.5);
        assert_eq!(set.combined().delay, Duration::from_millis(20));
        set.set(0, None);
        set.set(2, None);
        assert!(set.is_empty() && set.combined().is_clear());
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
