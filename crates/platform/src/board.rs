//! The boards: the deterministic meeting points between nodes that the bus does not carry
//! (physics and power, not packets). The FC posts its truth and the EPS and COMM read it;
//! the ECU posts burns and the FC applies them to the true orbit; nodes (and the air
//! channel, and the runtime's power shell) post switched activities and the EPS charges
//! them, the PC follows its S-band power.
//!
//! # Determinism: readers see only what came strictly before their instant
//! Nodes run as concurrent tasks, and at an instant where one posts and another reads,
//! either may run first. A reader at `now` is answered from what was posted for instants
//! strictly before `now`, so its answer does not depend on that order.
//!
//! # The horizon: no write behind a reader
//! Every read moves the board's *horizon* (per activity on the [`ActivityBoard`]) to the
//! reader's instant: it has integrated, applied or acted on everything before it. A write
//! for an instant before the horizon would change the past under a reader that has moved
//! on (the answer it got would differ from the one a later reader gets), so it is
//! **refused** at its instant and counted ([`BoardStats::refused`]); the writer gets a
//! [`Refused`] and logs it. So that the state *after* the horizon is still right, a refused
//! switch or cut takes effect at the horizon instead (what readers were told stays true),
//! a refused new burn counts as posted at the horizon (the FC takes it, and the thrust it
//! missed, at its next tick), and a refused truth snapshot is dropped (the next one
//! supersedes it).
//!
//! Where a late write comes from: a node posts what it does at its own `now`, and in
//! virtual time the runtime runs every task due at an instant before the clock moves on;
//! but tokio's timer wheel ticks in milliseconds, and within one tick a reader due at the
//! tick may run before a writer whose timer fell a few microseconds earlier in it. The count
//! says how often; the error is at most one tick of the activity.

use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard};

use nalgebra::Vector3;

use crate::time::SimTime;
use crate::truth::TruthSnapshot;

/// Writes and refusals of one board.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BoardStats {
    /// Writes taken.
    pub writes: u64,
    /// Writes refused because a reader had already passed their instant.
    pub refused: u64,
}

/// A write refused: it was for `at`, and a reader had already read up to `horizon`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Refused {
    /// The instant the write was for.
    pub at: SimTime,
    /// The horizon of the board (or activity) then.
    pub horizon: SimTime,
}

impl fmt::Display for Refused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "write for {} refused: a reader had already read up to {} (taken from there)",
            self.at, self.horizon
        )
    }
}

impl std::error::Error for Refused {}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding the lock is a bug elsewhere; keep the board usable anyway.
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// How many snapshots a [`TruthBoard`] keeps (a minute at the default 1 Hz, a few seconds at
/// 10 Hz: readers only ever want the latest one before their own time).
pub const TRUTH_BOARD_DEPTH: usize = 64;

#[derive(Debug, Default)]
struct TruthLog {
    snapshots: VecDeque<TruthSnapshot>,
    horizon: SimTime,
    stats: BoardStats,
}

/// Where the FC posts its truth snapshots and the other nodes (EPS, COMM) read them, wired
/// together by the twin (node crates never import one another). A reader at `now` gets the
/// latest snapshot strictly before `now` ([`TruthBoard::latest_before`]).
#[derive(Debug, Clone, Default)]
pub struct TruthBoard(Arc<Mutex<TruthLog>>);

impl TruthBoard {
    /// An empty board.
    pub fn new() -> Self {
        Self::default()
    }

    /// Post a snapshot (in time order; older ones beyond [`TRUTH_BOARD_DEPTH`] are dropped).
    /// Refused (and dropped) when a reader has already asked for an instant after `s.t`.
    pub fn publish(&self, s: &TruthSnapshot) -> Result<(), Refused> {
        let mut log = lock(&self.0);
        if s.t < log.horizon {
            log.stats.refused += 1;
            return Err(Refused {
                at: s.t,
                horizon: log.horizon,
            });
        }
        if log.snapshots.len() >= TRUTH_BOARD_DEPTH {
            log.snapshots.pop_front();
        }
        log.snapshots.push_back(s.clone());
        log.stats.writes += 1;
        Ok(())
    }

    /// The latest snapshot with `t < now`, if any (moves the horizon to `now`).
    pub fn latest_before(&self, now: SimTime) -> Option<TruthSnapshot> {
        let mut log = lock(&self.0);
        log.horizon = log.horizon.max(now);
        log.snapshots.iter().rev().find(|s| s.t < now).cloned()
    }

    /// Writes and refusals so far.
    pub fn stats(&self) -> BoardStats {
        lock(&self.0).stats
    }
}

/// A thruster firing, posted by the ECU for the FC, which owns the true orbit: between
/// `start` and `end` the thruster pushes along `dir_body` (unit, BCF) with `thrust_n`
/// newtons on a spacecraft of `mass_kg` (its mass at the start; the FC integrates the rocket
/// equation with `mass_flow_kg_s`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Burn {
    /// When the ECU posted it (the FC takes a burn at its first tick strictly after this,
    /// so that the order of two tasks at one instant does not matter).
    pub posted: SimTime,
    /// Start.
    pub start: SimTime,
    /// End (exclusive).
    pub end: SimTime,
    /// Thrust, N.
    pub thrust_n: f64,
    /// Propellant mass flow, kg/s (thrust / (Isp g0)).
    pub mass_flow_kg_s: f64,
    /// Spacecraft mass at the start of the burn, kg.
    pub mass_kg: f64,
    /// Thrust direction in the body frame (unit).
    pub dir_body: Vector3<f64>,
}

#[derive(Debug, Default)]
struct BurnLog {
    burns: Vec<Burn>,
    horizon: SimTime,
    stats: BoardStats,
}

/// Where the ECU posts its burns and the FC takes them. The FC applies each burn's thrust
/// from `start` to `end`, at its ticks after the burn was posted (a part of the burn before
/// that tick is applied at that tick); a burn cut short (SAFE, a reboot, a loss of power) is
/// re-posted with its new end.
///
/// Horizon: the FC's tick at `now` applies every burn posted before `now` up to `now`. A new
/// burn posted before the horizon, or a cut to an end before it (thrust the FC has already
/// applied), is refused.
#[derive(Debug, Clone, Default)]
pub struct BurnBoard(Arc<Mutex<BurnLog>>);

impl BurnBoard {
    /// An empty board.
    pub fn new() -> Self {
        Self::default()
    }

    /// Post a burn, or replace the one with the same `start` (cut short). A cut to an end
    /// the FC has already applied thrust past is refused and takes effect at the horizon; a
    /// new burn posted behind the horizon is refused and counts as posted at the horizon.
    pub fn post(&self, mut b: Burn) -> Result<(), Refused> {
        let mut log = lock(&self.0);
        let horizon = log.horizon;
        let i = log.burns.iter().position(|x| x.start == b.start);
        let refused = match i.map(|i| log.burns[i]) {
            Some(old) if b.end < old.end && b.end < horizon && old.posted < horizon => {
                let r = Refused { at: b.end, horizon };
                b.end = horizon.min(old.end);
                Some(r)
            }
            None if b.posted < horizon => {
                let r = Refused {
                    at: b.posted,
                    horizon,
                };
                b.posted = horizon;
                Some(r)
            }
            _ => None,
        };
        match i {
            Some(i) => log.burns[i] = b,
            None => log.burns.push(b),
        }
        match refused {
            Some(r) => {
                log.stats.refused += 1;
                Err(r)
            }
            None => {
                log.stats.writes += 1;
                Ok(())
            }
        }
    }

    /// Every burn posted strictly before `now` that has not ended by `applied_until`, in
    /// start order (the FC keeps `applied_until`, how far it has applied them); moves the
    /// horizon to `now`.
    pub fn pending(&self, now: SimTime, applied_until: SimTime) -> Vec<Burn> {
        let mut log = lock(&self.0);
        log.horizon = log.horizon.max(now);
        let mut out: Vec<Burn> = log
            .burns
            .iter()
            .filter(|b| b.posted < now && b.end > applied_until)
            .copied()
            .collect();
        out.sort_by_key(|b| b.start);
        out
    }

    /// Every burn held, in start order, without reading (for tests and reports).
    pub fn all(&self) -> Vec<Burn> {
        let mut out = lock(&self.0).burns.clone();
        out.sort_by_key(|b| b.start);
        out
    }

    /// Forget burns that ended at or before `t`.
    pub fn forget_before(&self, t: SimTime) {
        lock(&self.0).burns.retain(|b| b.end > t);
    }

    /// Writes and refusals so far.
    pub fn stats(&self) -> BoardStats {
        lock(&self.0).stats
    }
}

/// Switched activities of the platform that cost power or that a node must follow:
/// posted by whoever does them, read by the EPS (and the PC, for its S-band power).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Activity {
    /// The S-band transmitter is sending a frame.
    SbandTx,
    /// The primary COMM's UHF radio is transmitting.
    UhfTx,
    /// The secondary COMM's UHF radio is transmitting.
    UhfTxSecondary,
    /// The ECU's thruster heaters are on (armed).
    ThrusterHeater,
    /// The thruster is firing.
    Firing,
    /// The EPS has switched the S-band transmitter's power channel off (a power state, not
    /// a load: posted by the platform rules from the EPS's channel switches, read by the
    /// PC).
    SbandPowerOff,
    /// A power fault holds node `addr` off whatever its EPS channel says (posted by the
    /// platform rules, read by the EPS: the node draws nothing meanwhile).
    PowerFault(u8),
}

impl Activity {
    /// The activities other than power faults, in their order.
    const PLAIN: [Activity; 6] = [
        Activity::SbandTx,
        Activity::UhfTx,
        Activity::UhfTxSecondary,
        Activity::ThrusterHeater,
        Activity::Firing,
        Activity::SbandPowerOff,
    ];

    /// Its tag (its place in the enum) and a power fault's node (0 otherwise).
    pub fn tag(self) -> (u8, u8) {
        match self {
            Activity::PowerFault(a) => (6, a),
            plain => (
                Activity::PLAIN
                    .iter()
                    .position(|p| *p == plain)
                    .unwrap_or_default() as u8,
                0,
            ),
        }
    }

    /// The activity of tag `tag` (a power fault of node `addr` for 6), if there is one.
    pub fn from_tag(tag: u8, addr: u8) -> Option<Activity> {
        match tag {
            6 => Some(Activity::PowerFault(addr)),
            t => Activity::PLAIN.get(usize::from(t)).copied(),
        }
    }
}

/// Each activity's switches, (time, on), and how far its readers have read.
#[derive(Debug, Default)]
struct ActivityLog {
    switches: BTreeMap<Activity, Vec<(SimTime, bool)>>,
    horizons: BTreeMap<Activity, SimTime>,
    stats: BoardStats,
}

/// A log of [`Activity`] switches with their times; readers see the state strictly before
/// their own instant, and each read moves that activity's horizon.
///
/// Switches may be posted ahead of time (the air channel posts a queued transmission when
/// it is submitted). The log forgets what no reader can ask for any more: switches more
/// than [`ActivityBoard::KEEP_BEHIND`] before the activity's horizon (keeping the last one,
/// which holds the state); only without readers does it fall back to a cap of
/// [`ActivityBoard::MAX_SWITCHES`] per activity.
#[derive(Debug, Clone, Default)]
pub struct ActivityBoard(Arc<Mutex<ActivityLog>>);

impl ActivityBoard {
    /// How far behind the horizon switches are kept (a second reader of the same activity
    /// may lag the first within a tick; 10 s is ample).
    pub const KEEP_BEHIND: std::time::Duration = std::time::Duration::from_secs(10);
    /// Switches kept per activity when nobody reads the board.
    pub const MAX_SWITCHES: usize = 1 << 20;

    /// An empty board: every activity off.
    pub fn new() -> Self {
        Self::default()
    }

    /// `what` switched on or off at `t`; a switch to the state already held changes
    /// nothing. Refused when a reader of `what` has already read past `t`: the switch then
    /// takes effect at the horizon.
    pub fn set(&self, what: Activity, t: SimTime, on: bool) -> Result<(), Refused> {
        let mut log = lock(&self.0);
        let horizon = log.horizons.get(&what).copied().unwrap_or(SimTime::ZERO);
        let refused = (t < horizon).then_some(Refused { at: t, horizon });
        if refused.is_some() {
            log.stats.refused += 1;
        }
        let t = t.max(horizon);
        let keep_from = SimTime::from_ns(
            horizon
                .as_ns()
                .saturating_sub(u64::try_from(Self::KEEP_BEHIND.as_nanos()).unwrap_or(u64::MAX)),
        );
        let v = log.switches.entry(what).or_default();
        // Switches of one activity normally come in time order; one that does not is put
        // in its place.
        let at = v.partition_point(|&(x, _)| x <= t);
        let before = at.checked_sub(1).map(|i| v[i].1).unwrap_or(false);
        if before == on && at == v.len() {
            return refused.map_or(Ok(()), Err);
        }
        if v.len() >= 4096 {
            // Everything before the last switch older than the kept span is unreachable.
            let old = v.partition_point(|&(x, _)| x < keep_from);
            if old > 1 {
                v.drain(..old - 1);
            } else if v.len() >= Self::MAX_SWITCHES {
                v.drain(..Self::MAX_SWITCHES / 2);
            }
        }
        let at = v.partition_point(|&(x, _)| x <= t);
        v.insert(at, (t, on));
        match refused {
            Some(r) => Err(r),
            None => {
                log.stats.writes += 1;
                Ok(())
            }
        }
    }

    fn read(&self, what: Activity, upto: SimTime) -> MutexGuard<'_, ActivityLog> {
        let mut log = lock(&self.0);
        let h = log.horizons.entry(what).or_default();
        *h = (*h).max(upto);
        log
    }

    /// Whether `what` was on just before `t` (moves its horizon to `t`).
    pub fn on_before(&self, what: Activity, t: SimTime) -> bool {
        let log = self.read(what, t);
        log.switches
            .get(&what)
            .and_then(|v| v.iter().rev().find(|(x, _)| *x < t))
            .is_some_and(|&(_, on)| on)
    }

    /// The fraction of `[from, to)` during which `what` was on (0 when the interval is
    /// empty), for energy over an EPS step (moves its horizon to `to`).
    pub fn duty(&self, what: Activity, from: SimTime, to: SimTime) -> f64 {
        if to <= from {
            return 0.0;
        }
        let log = self.read(what, to);
        let Some(v) = log.switches.get(&what) else {
            return 0.0;
        };
        // The log is in time order: the switches inside the interval by binary search (the
        // log holds up to 4096 per activity, and the EPS asks for six at every step).
        let first = v.partition_point(|(t, _)| *t <= from);
        let last = v.partition_point(|(t, _)| *t < to).max(first);
        let mut on_ns = 0u64;
        let mut state = first.checked_sub(1).is_some_and(|i| v[i].1);
        let mut since = from;
        for &(t, on) in &v[first..last] {
            if state {
                on_ns += (t - since).as_nanos() as u64;
            }
            state = on;
            since = t;
        }
        if state {
            on_ns += (to - since).as_nanos() as u64;
        }
        on_ns as f64 / (to - from).as_nanos() as f64
    }

    /// Switches held for `what` (for tests and memory checks).
    pub fn held(&self, what: Activity) -> usize {
        lock(&self.0).switches.get(&what).map_or(0, Vec::len)
    }

    /// Writes and refusals so far.
    pub fn stats(&self) -> BoardStats {
        lock(&self.0).stats
    }
}

/// The boards of one run, shared by the nodes that meet on them.
#[derive(Debug, Clone, Default)]
pub struct Boards {
    /// The FC's true state, every tick.
    pub truth: TruthBoard,
    /// The ECU's firings.
    pub burns: BurnBoard,
    /// Switched activities (transmitting, heating, firing, power states).
    pub activity: ActivityBoard,
}

impl Boards {
    /// Writes and refusals of every board: truth, burns, activity.
    pub fn stats(&self) -> [(&'static str, BoardStats); 3] {
        [
            ("truth", self.truth.stats()),
            ("burns", self.burns.stats()),
            ("activity", self.activity.stats()),
        ]
    }
}

// What a snapshot keeps of the boards: each log whole, its horizon and counts.
snap::fields!(BoardStats { writes, refused });
snap::fields!(Burn {
    posted,
    start,
    end,
    thrust_n,
    mass_flow_kg_s,
    mass_kg,
    dir_body
});
snap::fields!(TruthLog {
    snapshots,
    horizon,
    stats
});
snap::fields!(BurnLog {
    burns,
    horizon,
    stats
});
snap::fields!(ActivityLog {
    switches,
    horizons,
    stats
});

/// An activity as a tag (its place in the enum), and a power fault's node.
impl snap::Snap for Activity {
    fn save(&self, w: &mut snap::Writer) {
        let (tag, addr) = self.tag();
        tag.save(w);
        addr.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = <Activity as snap::SnapNew>::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for Activity {
    const MIN_BYTES: usize = 2;
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let tag = u8::read(r)?;
        let addr = u8::read(r)?;
        Activity::from_tag(tag, addr).ok_or_else(|| r.bad("Activity"))
    }
}

/// The boards' contents, saved through their handles and loaded into the boards a restore
/// built (the handles every node holds stay the same).
impl snap::Snap for Boards {
    fn save(&self, w: &mut snap::Writer) {
        let Boards {
            truth,
            burns,
            activity,
        } = self;
        lock(&truth.0).save(w);
        lock(&burns.0).save(w);
        lock(&activity.0).save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        let Boards {
            truth,
            burns,
            activity,
        } = self;
        lock(&truth.0).load(r)?;
        lock(&burns.0).load(r)?;
        lock(&activity.0).load(r)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// The boards saved mid-run and loaded into fresh ones answer every reader as the
    /// originals do, and save again to the same bytes.
    #[test]
    fn boards_saved_and_loaded_answer_as_the_originals() {
        let t = SimTime::from_ms;
        let a = Boards::default();
        let snap_at = |ms| TruthSnapshot {
            t: t(ms),
            unix_ns: 7,
            ..TruthSnapshot::default()
        };
        a.truth.publish(&snap_at(100)).unwrap();
        a.truth.publish(&snap_at(200)).unwrap();
        a.burns
            .post(Burn {
                posted: t(150),
                start: t(300),
                end: t(400),
                thrust_n: 0.5,
                mass_flow_kg_s: 1e-4,
                mass_kg: 6.0,
                dir_body: Vector3::new(0.0, 0.0, -1.0),
            })
            .unwrap();
        a.activity.set(Activity::UhfTx, t(120), true).unwrap();
        a.activity
            .set(Activity::PowerFault(12), t(130), true)
            .unwrap();
        assert!(a.activity.on_before(Activity::UhfTx, t(125)));
        let bytes = snap::to_bytes(&a);
        let mut b = Boards::default();
        snap::load_from(&mut b, &bytes).unwrap();
        assert_eq!(snap::to_bytes(&b), bytes);
        for ms in [110, 150, 250] {
            assert_eq!(a.truth.latest_before(t(ms)), b.truth.latest_before(t(ms)));
        }
        for what in [Activity::UhfTx, Activity::PowerFault(12), Activity::Firing] {
            assert_eq!(
                a.activity.on_before(what, t(140)),
                b.activity.on_before(what, t(140))
            );
        }
        assert_eq!(a.stats(), b.stats());
        // A write behind the loaded horizon is refused there as it is here.
        assert_eq!(
            a.activity.set(Activity::UhfTx, t(121), false).is_err(),
            b.activity.set(Activity::UhfTx, t(121), false).is_err()
        );
    }

    fn s(x: u64) -> SimTime {
        SimTime::from_secs(x)
    }

    #[test]
    fn readers_see_only_what_came_strictly_before() {
        let b = TruthBoard::new();
        let post = |k: u64| {
            b.publish(&TruthSnapshot {
                t: s(k),
                ..TruthSnapshot::default()
            })
            .unwrap()
        };
        (0..10).for_each(post);
        assert_eq!(b.latest_before(s(5)).unwrap().t, s(4));
        assert_eq!(
            b.latest_before(s(5) + std::time::Duration::from_nanos(1))
                .unwrap()
                .t,
            s(5)
        );
        assert!(b.latest_before(SimTime::ZERO).is_none());
        (10..100).for_each(post);
        // Only the last TRUTH_BOARD_DEPTH are kept.
        assert!(b.latest_before(s(10)).is_none());
        assert_eq!(b.latest_before(SimTime::MAX).unwrap().t, s(99));
    }

    #[test]
    fn a_snapshot_behind_a_reader_is_refused() {
        let b = TruthBoard::new();
        assert!(b.latest_before(s(5)).is_none());
        let late = TruthSnapshot {
            t: s(4),
            ..TruthSnapshot::default()
        };
        assert_eq!(
            b.publish(&late),
            Err(Refused {
                at: s(4),
                horizon: s(5)
            })
        );
        assert!(b.latest_before(s(6)).is_none());
        // At the reader's own instant it is not behind it (readers see strictly before).
        b.publish(&TruthSnapshot { t: s(6), ..late }).unwrap();
        assert_eq!(
            b.stats(),
            BoardStats {
                writes: 1,
                refused: 1
            }
        );
    }

    fn burn(start: u64, end: u64) -> Burn {
        Burn {
            posted: SimTime::from_ns(start),
            start: SimTime::from_ns(start),
            end: SimTime::from_ns(end),
            thrust_n: 1.0,
            mass_flow_kg_s: 0.001,
            mass_kg: 12.0,
            dir_body: Vector3::z(),
        }
    }

    #[test]
    fn burns_are_taken_after_they_are_posted_and_cuts_behind_the_fc_are_refused() {
        let ns = SimTime::from_ns;
        let b = BurnBoard::new();
        b.post(burn(100, 10_100)).unwrap();
        assert!(
            b.pending(ns(100), SimTime::ZERO).is_empty(),
            "not at the instant it was posted"
        );
        assert_eq!(b.pending(ns(101), SimTime::ZERO), vec![burn(100, 10_100)]);
        assert!(
            b.pending(ns(20_000), ns(10_100)).is_empty(),
            "applied to its end"
        );
        // The FC has applied it to 20 000: a cut to 5 000 would rewrite applied thrust.
        assert!(b.post(burn(100, 5_000)).is_err());
        assert_eq!(b.all()[0].end, ns(10_100), "it had ended at 10 100 anyway");
        // A new burn posted behind the FC counts as posted at its horizon.
        assert!(b.post(burn(15_000, 30_000)).is_err());
        assert_eq!(b.all()[1].posted, ns(20_000));
        assert!(b.pending(ns(20_000), ns(20_000)).is_empty());
        assert_eq!(b.pending(ns(20_001), ns(20_000)).len(), 1);
        // A cut at or after the horizon is taken.
        let c = BurnBoard::new();
        c.post(burn(100, 10_100)).unwrap();
        let _ = c.pending(ns(3_000), SimTime::ZERO);
        c.post(burn(100, 3_000)).unwrap();
        assert_eq!(c.pending(ns(3_001), SimTime::ZERO)[0].end, ns(3_000));
        c.forget_before(ns(3_000));
        assert!(c.all().is_empty());
        assert_eq!(b.stats().refused, 2);
    }

    /// A long backlog posted ahead of the reader (2100 transmissions queued back to back on
    /// the air) is all there when the reader gets to it; once the reader has moved on, the
    /// log forgets what lies behind it.
    #[test]
    fn a_backlog_posted_ahead_survives_until_read_and_is_then_forgotten() {
        let ms = SimTime::from_ms;
        let a = ActivityBoard::new();
        assert_eq!(a.duty(Activity::UhfTxSecondary, ms(0), ms(1)), 0.0);
        // 250 ms on, 250 ms off, for 2100 transmissions (1050 s).
        for k in 0..2100u64 {
            a.set(Activity::UhfTx, ms(k * 500), true).unwrap();
            a.set(Activity::UhfTx, ms(k * 500 + 250), false).unwrap();
        }
        assert_eq!(a.held(Activity::UhfTx), 4200);
        assert_eq!(a.duty(Activity::UhfTx, ms(0), ms(1000)), 0.5);
        // The reader advances; the next posts forget what is more than 10 s behind it.
        assert_eq!(a.duty(Activity::UhfTx, ms(1_040_000), ms(1_041_000)), 0.5);
        a.set(Activity::UhfTx, ms(1_100_000), true).unwrap();
        assert!(a.held(Activity::UhfTx) < 100, "{}", a.held(Activity::UhfTx));
        assert_eq!(a.duty(Activity::UhfTx, ms(1_041_000), ms(1_042_000)), 0.5);
        assert!(!a.on_before(Activity::UhfTx, ms(1_050_100)));
        assert!(a.on_before(
            Activity::UhfTx,
            ms(1_100_000) + std::time::Duration::from_nanos(1)
        ));
    }

    /// Duty by binary search equals the integral of the switches taken one by one, at
    /// interval ends on, between and beside switches.
    #[test]
    fn duty_equals_the_switches_summed_one_by_one() {
        let ns = SimTime::from_ns;
        let a = ActivityBoard::new();
        let mut log = Vec::new();
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut t = 0;
        for _ in 0..300 {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            t += (seed >> 40) % 50;
            let on = (seed >> 20) & 1 == 1;
            a.set(Activity::SbandTx, ns(t), on).unwrap();
            log.push((t, on));
        }
        let reference = |from: u64, to: u64| {
            let on_at = |x: u64| log.iter().rev().find(|(t, _)| *t <= x).is_some_and(|l| l.1);
            let on = (from..to).filter(|&x| on_at(x)).count();
            on as f64 / (to - from) as f64
        };
        for (from, to) in [
            (0, 1),
            (0, t + 10),
            (7, 93),
            (100, 100),
            (250, 1000),
            (t, t + 5),
        ] {
            let d = ActivityBoard::duty(&a, Activity::SbandTx, ns(from), ns(to));
            let r = if to > from { reference(from, to) } else { 0.0 };
            assert!((d - r).abs() < 1e-12, "[{from}, {to}): {d} vs {r}");
        }
    }

    #[test]
    fn activity_duty_over_an_interval() {
        let ns = SimTime::from_ns;
        let a = ActivityBoard::new();
        a.set(Activity::SbandTx, ns(10), true).unwrap();
        a.set(Activity::SbandTx, ns(30), false).unwrap();
        a.set(Activity::SbandTx, ns(50), true).unwrap();
        assert!(!a.on_before(Activity::SbandTx, ns(10)));
        assert!(a.on_before(Activity::SbandTx, ns(11)));
        assert!((a.duty(Activity::SbandTx, ns(0), ns(100)) - 0.7).abs() < 1e-12);
        assert!((a.duty(Activity::SbandTx, ns(20), ns(40)) - 0.5).abs() < 1e-12);
        assert_eq!(a.duty(Activity::UhfTx, ns(0), ns(100)), 0.0);
    }

    /// A reader that has integrated `[0, 10 s)` must never be told afterwards that the
    /// interval was different: a switch posted in its past is refused (and counted), not
    /// slipped in behind it. (Failed before the horizon: the second answer was 0.3.)
    #[test]
    fn a_write_behind_a_readers_horizon_is_refused() {
        let a = ActivityBoard::new();
        a.set(Activity::Firing, s(2), true).unwrap();
        let before = a.duty(Activity::Firing, s(0), s(10));
        assert!((before - 0.8).abs() < 1e-12);
        // An end posted long after the activity's last change (as an ECU reset at its power
        // loss would) is refused: it would rewrite what was already read.
        assert_eq!(
            a.set(Activity::Firing, s(5), false),
            Err(Refused {
                at: s(5),
                horizon: s(10)
            })
        );
        assert_eq!(a.duty(Activity::Firing, s(0), s(10)), before);
        assert_eq!(
            a.stats(),
            BoardStats {
                writes: 1,
                refused: 1
            }
        );
        // It takes effect from the horizon on: the state after it is right.
        assert!(!a.on_before(Activity::Firing, s(11)));
        assert_eq!(a.duty(Activity::Firing, s(10), s(12)), 0.0);
        // Another activity has its own horizon: nobody has read it.
        a.set(Activity::ThrusterHeater, s(5), true).unwrap();
        // At the horizon itself the write is in the reader's future.
        a.set(Activity::Firing, s(12), true).unwrap();
        assert!(a.on_before(Activity::Firing, s(13)));
    }
}
