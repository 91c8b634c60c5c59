//! What the twin lets across an outside link: the link's faults and its power.
//!
//! A program outside the twin cannot be switched off or hung by the twin, so the twin does
//! the next best thing at the one place it controls, the link: a [`LinkGate`] decides, for
//! every packet (KISS) or frame (SocketCAN) crossing it in either direction, whether it
//! passes now, passes after a delay, or is lost, and why.
//!
//! - **Faults** (`drop`, `delay`, `link-down` with an outside link as `target`) compose as a
//!   medium's do ([`ImpairmentSet`]): drop chances combine, delays add, down dominates, and
//!   lifting one leaves the others. The chances are drawn from the link's own generator,
//!   seeded from the run's seed.
//! - **Hang** (`hang` on a link): the outside node is alive but the twin forwards nothing to
//!   or from it, until the fault ends or a power cycle.
//! - **Power** (`powered_by` on a link): while the EPS channel is off, the twin forwards
//!   nothing to or from it; turning it off ends every hang, as a power cycle does.
//!
//! Delayed traffic waits in a [`DelayLine`]: first in, first out, bounded; what does not fit
//! is lost and counted. A gate is shared between the main loop (which applies faults and
//! power at their instants) and the link's task (which asks at every packet).

use std::collections::{BTreeSet, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use csp::SimTime;

use crate::impair::{Fate, ImpairRng, ImpairmentSet, Impairments};

/// How many packets or frames a link's delay line holds in each direction (a radio's or a
/// serial adapter's buffer); more are lost and counted as [`GateStats::overflow`].
pub const DELAY_LINE_CAPACITY: usize = 1024;

/// What happens to one packet or frame at the gate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Passage {
    /// It crosses now.
    Now,
    /// It crosses after this long.
    After(Duration),
    /// It is lost.
    Lost(Loss),
}

/// Why a packet or frame was lost at the gate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loss {
    /// A `drop` fault's chance.
    Dropped,
    /// A `link-down` fault.
    Down,
    /// A `hang` fault on the link.
    Hung,
    /// The link's EPS channel is off.
    Unpowered,
}

/// What a gate did, over the run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GateStats {
    /// Packets or frames lost to a `drop` fault's chance.
    pub dropped: u64,
    /// Lost while a `link-down` fault held.
    pub down: u64,
    /// Lost while the outside node was hung.
    pub hung: u64,
    /// Lost while its EPS channel was off.
    pub unpowered: u64,
    /// Delayed by a `delay` fault.
    pub delayed: u64,
    /// Lost because the delay line was full.
    pub overflow: u64,
}

impl GateStats {
    /// Everything lost at the gate.
    pub fn lost(&self) -> u64 {
        self.dropped + self.down + self.hung + self.unpowered + self.overflow
    }
}

#[derive(Debug)]
struct State {
    faults: ImpairmentSet,
    imp: Impairments,
    hangs: BTreeSet<u32>,
    powered: bool,
    rng: ImpairRng,
    stats: GateStats,
}

/// The gate of one outside link (see the module doc). Cheap to clone; clones share it.
#[derive(Debug, Clone)]
pub struct LinkGate(Arc<Mutex<State>>);

impl LinkGate {
    /// An open, powered gate whose chances are drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        LinkGate(Arc::new(Mutex::new(State {
            faults: ImpairmentSet::default(),
            imp: Impairments::default(),
            hangs: BTreeSet::new(),
            powered: true,
            rng: ImpairRng::new(seed, "link"),
            stats: GateStats::default(),
        })))
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Fault `id` impairs the link with `imp` (`Some`) or is lifted (`None`).
    pub fn set_fault(&self, id: u32, imp: Option<Impairments>) {
        let mut st = self.lock();
        st.faults.set(id, imp);
        st.imp = st.faults.combined();
    }

    /// Hang fault `id` starts (`hung`) or ends.
    pub fn set_hang(&self, id: u32, hung: bool) {
        let mut st = self.lock();
        if hung {
            st.hangs.insert(id);
        } else {
            st.hangs.remove(&id);
        }
    }

    /// The link's EPS channel is on or off; returns whether that changed anything. Losing
    /// power ends every hang.
    pub fn set_powered(&self, on: bool) -> bool {
        let mut st = self.lock();
        if !on {
            st.hangs.clear();
        }
        std::mem::replace(&mut st.powered, on) != on
    }

    /// Whether the link is powered.
    pub fn powered(&self) -> bool {
        self.lock().powered
    }

    /// Decide one packet's or frame's passage, and count it.
    pub fn pass(&self) -> Passage {
        let mut st = self.lock();
        let st = &mut *st;
        let p = if !st.powered {
            Passage::Lost(Loss::Unpowered)
        } else if !st.hangs.is_empty() {
            Passage::Lost(Loss::Hung)
        } else if st.imp.down {
            Passage::Lost(Loss::Down)
        } else if st.imp.drop_prob > 0.0
            && st.rng.fate(&Impairments {
                drop_prob: st.imp.drop_prob,
                ..Default::default()
            }) == Fate::Drop
        {
            Passage::Lost(Loss::Dropped)
        } else if st.imp.delay > Duration::ZERO {
            Passage::After(st.imp.delay)
        } else {
            Passage::Now
        };
        let s = &mut st.stats;
        match p {
            Passage::Now => {}
            Passage::After(_) => s.delayed += 1,
            Passage::Lost(Loss::Dropped) => s.dropped += 1,
            Passage::Lost(Loss::Down) => s.down += 1,
            Passage::Lost(Loss::Hung) => s.hung += 1,
            Passage::Lost(Loss::Unpowered) => s.unpowered += 1,
        }
        p
    }

    /// Count one packet or frame lost because the delay line was full.
    pub fn overflowed(&self) {
        self.lock().stats.overflow += 1;
    }

    /// The counters so far.
    pub fn stats(&self) -> GateStats {
        self.lock().stats
    }
}

// The state a snapshot saves (docs/snapshots.md): a gate's faults, power, hangs, generator
// and counts (the delay lines are their links' tasks', outside the twin's run).
snap::fields!(GateStats {
    dropped,
    down,
    hung,
    unpowered,
    delayed,
    overflow
});
snap::fields!(State {
    faults,
    imp,
    hangs,
    powered,
    rng,
    stats;
    in_place
});

/// The gate's state, under its lock.
impl snap::Snap for LinkGate {
    fn save(&self, w: &mut snap::Writer) {
        self.lock().save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.lock().load(r)
    }
}

/// Packets or frames waiting out a delay: first in, first out, at most
/// [`DELAY_LINE_CAPACITY`].
#[derive(Debug)]
pub struct DelayLine<T> {
    queue: VecDeque<(SimTime, T)>,
}

impl<T> Default for DelayLine<T> {
    fn default() -> Self {
        DelayLine {
            queue: VecDeque::new(),
        }
    }
}

impl<T> DelayLine<T> {
    /// Hold `item` until `due`; gives it back when the line is full. An item never
    /// overtakes the one before it (a shorter delay after a longer one waits for it).
    pub fn push(&mut self, due: SimTime, item: T) -> Result<(), T> {
        if self.queue.len() >= DELAY_LINE_CAPACITY {
            return Err(item);
        }
        let due = self.queue.back().map_or(due, |(d, _)| due.max(*d));
        self.queue.push_back((due, item));
        Ok(())
    }

    /// When the first item is due.
    pub fn next_due(&self) -> Option<SimTime> {
        self.queue.front().map(|(d, _)| *d)
    }

    /// The first item, if it is due at `now`, with its due time.
    pub fn pop_due(&mut self, now: SimTime) -> Option<(SimTime, T)> {
        if self.next_due()? <= now {
            self.queue.pop_front()
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn imp(f: impl FnOnce(&mut Impairments)) -> Option<Impairments> {
        let mut i = Impairments::default();
        f(&mut i);
        Some(i)
    }

    #[test]
    fn an_open_gate_passes_everything_and_draws_nothing() {
        let g = LinkGate::new(1);
        assert!((0..100).all(|_| g.pass() == Passage::Now));
        assert_eq!(g.stats(), GateStats::default());
    }

    #[test]
    fn faults_compose_on_a_link_and_lifting_one_leaves_the_others() {
        let g = LinkGate::new(1);
        g.set_fault(0, imp(|i| i.drop_prob = 1.0));
        g.set_fault(1, imp(|i| i.delay = Duration::from_millis(50)));
        assert_eq!(g.pass(), Passage::Lost(Loss::Dropped), "the drop holds");
        g.set_fault(1, None);
        assert_eq!(g.pass(), Passage::Lost(Loss::Dropped));
        g.set_fault(0, None);
        g.set_fault(2, imp(|i| i.delay = Duration::from_millis(20)));
        g.set_fault(3, imp(|i| i.delay = Duration::from_millis(30)));
        assert_eq!(g.pass(), Passage::After(Duration::from_millis(50)));
        g.set_fault(4, imp(|i| i.down = true));
        assert_eq!(g.pass(), Passage::Lost(Loss::Down));
        g.set_fault(4, None);
        assert_eq!(g.pass(), Passage::After(Duration::from_millis(50)));
        let s = g.stats();
        assert_eq!((s.dropped, s.down, s.delayed), (2, 1, 2));
    }

    #[test]
    fn power_dominates_and_a_power_cycle_ends_a_hang() {
        let g = LinkGate::new(1);
        g.set_hang(7, true);
        assert_eq!(g.pass(), Passage::Lost(Loss::Hung));
        assert!(g.set_powered(false));
        assert!(!g.set_powered(false), "no change");
        assert_eq!(g.pass(), Passage::Lost(Loss::Unpowered));
        assert!(g.set_powered(true));
        assert_eq!(g.pass(), Passage::Now, "the power cycle ended the hang");
        let s = g.stats();
        assert_eq!((s.hung, s.unpowered, s.lost()), (1, 1, 2));
    }

    #[test]
    fn drops_follow_the_seed() {
        let count = |seed| {
            let g = LinkGate::new(seed);
            g.set_fault(0, imp(|i| i.drop_prob = 0.5));
            (0..1000).filter(|_| g.pass() != Passage::Now).count()
        };
        let n = count(3);
        assert!((400..600).contains(&n), "{n}");
        assert_eq!(n, count(3));
        assert_ne!(n, count(4));
    }

    #[test]
    fn a_delay_line_keeps_order_and_its_bound() {
        let mut l = DelayLine::default();
        let t = |ms| SimTime::ZERO + Duration::from_millis(ms);
        l.push(t(100), 'a').expect("room");
        l.push(t(60), 'b').expect("room");
        assert_eq!(l.next_due(), Some(t(100)));
        assert_eq!(l.pop_due(t(99)), None);
        assert_eq!(l.pop_due(t(100)), Some((t(100), 'a')));
        assert_eq!(l.pop_due(t(100)), Some((t(100), 'b')), "b waited for a");
        for _ in 0..DELAY_LINE_CAPACITY {
            l.push(t(200), 'c').expect("room");
        }
        assert_eq!(l.push(t(200), 'd'), Err('d'));
    }
}
