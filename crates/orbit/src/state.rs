//! The flight computer's published truth: one snapshot per FC step that the other nodes
//! (EPS, COMM, the recorder) read without importing `nodes-fc`.
//!
//! A plain data type, no behaviour beyond [`Default`] (everything zero, identity attitude).
//! Frames and units are in the field names: ECI is J2000 (ICD 1.4), body is the BCF of
//! ICD 1.4, and `q_eci_from_body` is active (`q_eci_from_body * v_body = v_eci`).

use nalgebra::{UnitQuaternion, Vector3};

/// The spacecraft's true state at one instant, as published by the FC.
#[derive(Debug, Clone, PartialEq)]
pub struct TruthSnapshot {
    /// Simulated time since run start, ns.
    pub t_ns: u64,
    /// UTC time as nanoseconds since the Unix epoch (1970-01-01T00:00:00 UTC), ns.
    pub unix_ns: i64,
    /// Position in ECI (J2000), m.
    pub r_eci_m: Vector3<f64>,
    /// Velocity in ECI (J2000), m/s.
    pub v_eci_m_s: Vector3<f64>,
    /// Attitude: the active rotation taking body (BCF) vectors to ECI.
    pub q_eci_from_body: UnitQuaternion<f64>,
    /// Body angular rate relative to ECI, expressed in the body frame, rad/s.
    pub w_body_rad_s: Vector3<f64>,
    /// Unit vector from the satellite to the sun in ECI (dimensionless).
    pub sun_eci_unit: Vector3<f64>,
    /// Visible fraction of the solar disc: 1 in sunlight, 0 in umbra, between in penumbra.
    pub in_eclipse_fraction_visible: f64,
    /// Geomagnetic field at the satellite in ECI, nT.
    pub b_eci_nt: Vector3<f64>,
    /// Reaction wheel speeds relative to the body about their spin axes, rad/s.
    pub wheel_speed_rad_s: [f64; 4],
    /// Magnetorquer dipoles along body X, Y, Z (as applied, after limits), A m^2.
    pub mtq_dipole_am2: [f64; 3],
}

impl Default for TruthSnapshot {
    fn default() -> Self {
        Self {
            t_ns: 0,
            unix_ns: 0,
            r_eci_m: Vector3::zeros(),
            v_eci_m_s: Vector3::zeros(),
            q_eci_from_body: UnitQuaternion::identity(),
            w_body_rad_s: Vector3::zeros(),
            sun_eci_unit: Vector3::zeros(),
            in_eclipse_fraction_visible: 0.0,
            b_eci_nt: Vector3::zeros(),
            wheel_speed_rad_s: [0.0; 4],
            mtq_dipole_am2: [0.0; 3],
        }
    }
}

/// What the FC's ADCS flight software believes and does at one instant, published with each
/// [`TruthSnapshot`] (same `t_ns`) for the recorder and the scenario expectations.
///
/// Angles that compare the estimate or the target with the truth are computed by the FC,
/// which knows all three; they are `None` when they do not apply (no target, no estimate).
#[derive(Debug, Clone, PartialEq)]
pub struct AdcsSnapshot {
    /// Simulated time since run start, ns (equals the truth snapshot's).
    pub t_ns: u64,
    /// The mode in effect (the target-mode enumeration of docs/protocol.md; 1 detumble while
    /// the ADCS detumbles, whatever the commanded mode).
    pub mode_in_effect: u8,
    /// The commanded target mode (ATCMDSET or a script).
    pub mode_commanded: u8,
    /// ADCS state as TMACD reports it: 0 off, 1 detumbling, 2 acquiring, 3 tracking.
    pub state: u8,
    /// Estimated attitude (body in ECI J2000), when the estimator is initialised.
    pub q_eci_from_body_est: Option<UnitQuaternion<f64>>,
    /// Estimated body rate (gyro minus estimated bias), rad/s, body frame.
    pub w_body_rad_s_est: Vector3<f64>,
    /// Estimated gyro bias, rad/s, body frame.
    pub gyro_bias_rad_s_est: Vector3<f64>,
    /// Target attitude of the mode in effect (body in ECI), when the mode has one.
    pub q_eci_from_body_target: Option<UnitQuaternion<f64>>,
    /// Angle of the rotation from the true attitude to the target attitude, deg.
    pub pointing_error_deg: Option<f64>,
    /// Angle between the mode's pointing axis (true attitude) and its target direction, deg:
    /// body +Z to nadir / velocity / ECI vector, the panel normal to the sun, the script's
    /// body vector to the ground target; for fixed-quaternion modes the body +Z axis to its
    /// target direction.
    pub axis_error_deg: Option<f64>,
    /// Elevation of the satellite seen from the ground target, deg (earth-target modes only).
    pub target_elevation_deg: Option<f64>,
    /// Angle of the rotation from the true attitude to the estimate, deg.
    pub estimation_error_deg: Option<f64>,
    /// Reaction wheel states as TMACD reports them: 0 off, 1 on, 2 fault.
    pub rw_state: [u8; 4],
    /// Commanded wheel motor torques, N m.
    pub wheel_torque_cmd_nm: [f64; 4],
    /// Commanded magnetorquer dipoles along body X, Y, Z, A m^2.
    pub mtq_dipole_cmd_am2: [f64; 3],
    /// Magnetorquer states as TMACD reports them: 0 off, 1 positive, 2 negative.
    pub mtq_state: [u8; 3],
}

impl Default for AdcsSnapshot {
    fn default() -> Self {
        Self {
            t_ns: 0,
            mode_in_effect: 1,
            mode_commanded: 1,
            state: 1,
            q_eci_from_body_est: None,
            w_body_rad_s_est: Vector3::zeros(),
            gyro_bias_rad_s_est: Vector3::zeros(),
            q_eci_from_body_target: None,
            pointing_error_deg: None,
            axis_error_deg: None,
            target_elevation_deg: None,
            estimation_error_deg: None,
            rw_state: [1; 4],
            wheel_torque_cmd_nm: [0.0; 4],
            mtq_dipole_cmd_am2: [0.0; 3],
            mtq_state: [0; 3],
        }
    }
}

/// How many snapshots a [`TruthBoard`] keeps (a minute at the default 1 Hz, a few seconds at
/// 10 Hz: readers only ever want the latest one before their own time).
pub const TRUTH_BOARD_DEPTH: usize = 64;

/// Where the FC posts its truth snapshots and the other nodes (EPS, COMM, ECU) read them,
/// wired together by the twin (node crates never import one another).
///
/// Determinism: a reader at simulated time `t` gets the latest snapshot **strictly before**
/// `t` ([`TruthBoard::latest_before`]). Nodes run as concurrent tasks, and at an instant
/// where the FC publishes and another node reads, either may run first; excluding the
/// snapshot of the reader's own instant makes the answer independent of that order.
#[derive(Debug, Clone, Default)]
pub struct TruthBoard(std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<TruthSnapshot>>>);

impl TruthBoard {
    /// An empty board.
    pub fn new() -> Self {
        Self::default()
    }

    /// Post a snapshot (in time order; older ones beyond [`TRUTH_BOARD_DEPTH`] are dropped).
    pub fn publish(&self, s: &TruthSnapshot) {
        let mut q = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if q.len() >= TRUTH_BOARD_DEPTH {
            q.pop_front();
        }
        q.push_back(s.clone());
    }

    /// The latest snapshot with `t_ns < t_ns_now`, if any.
    pub fn latest_before(&self, t_ns_now: u64) -> Option<TruthSnapshot> {
        let q = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        q.iter().rev().find(|s| s.t_ns < t_ns_now).cloned()
    }
}

/// A thruster firing, posted by the ECU for the FC, which owns the true orbit: between
/// `start_ns` and `end_ns` (simulated time) the thruster pushes along `dir_body` (unit, BCF)
/// with `thrust_n` newtons on a spacecraft of `mass_kg` (its mass at the start; the FC
/// integrates the rocket equation with `mass_flow_kg_s`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Burn {
    /// When the ECU posted it, simulated ns (the FC takes a burn at its first tick strictly
    /// after this, so that the order of two tasks at one instant does not matter).
    pub posted_ns: u64,
    /// Start, simulated ns since the start of the run.
    pub start_ns: u64,
    /// End (exclusive), simulated ns.
    pub end_ns: u64,
    /// Thrust, N.
    pub thrust_n: f64,
    /// Propellant mass flow, kg/s (thrust / (Isp g0)).
    pub mass_flow_kg_s: f64,
    /// Spacecraft mass at the start of the burn, kg.
    pub mass_kg: f64,
    /// Thrust direction in the body frame (unit).
    pub dir_body: Vector3<f64>,
}

/// Where the ECU posts its burns and the FC takes them (see [`TruthBoard`] for the wiring).
/// The FC applies each burn's thrust from `start_ns` to `end_ns`, at its ticks after the
/// burn was posted (a part of the burn before that tick is applied at that tick); a burn cut
/// short (ECU safed) is re-posted with its new end, and the twin cuts every burn of an ECU
/// that loses power ([`BurnBoard::cut_all`]).
#[derive(Debug, Clone, Default)]
pub struct BurnBoard(std::sync::Arc<std::sync::Mutex<Vec<Burn>>>);

impl BurnBoard {
    /// An empty board.
    pub fn new() -> Self {
        Self::default()
    }

    /// Post a burn, or replace the one with the same `start_ns` (cut short).
    pub fn post(&self, b: Burn) {
        let mut v = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        match v.iter_mut().find(|x| x.start_ns == b.start_ns) {
            Some(x) => *x = b,
            None => v.push(b),
        }
    }

    /// Every burn posted strictly before `now_ns` that has not ended by `applied_until_ns`,
    /// in start order (the FC keeps `applied_until_ns`, how far it has applied them).
    pub fn pending(&self, now_ns: u64, applied_until_ns: u64) -> Vec<Burn> {
        let v = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut out: Vec<Burn> = v
            .iter()
            .filter(|b| b.posted_ns < now_ns && b.end_ns > applied_until_ns)
            .copied()
            .collect();
        out.sort_by_key(|b| b.start_ns);
        out
    }

    /// End every burn still running at `at_ns` there (the ECU lost power).
    pub fn cut_all(&self, at_ns: u64) {
        let mut v = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        for b in v.iter_mut() {
            if b.end_ns > at_ns {
                b.end_ns = b.end_ns.min(at_ns.max(b.start_ns));
                b.posted_ns = b.posted_ns.min(at_ns);
            }
        }
    }

    /// Forget burns that ended at or before `ns`.
    pub fn forget_before(&self, ns: u64) {
        let mut v = self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        v.retain(|b| b.end_ns > ns);
    }
}

/// Switched activities of the platform that cost power and that the EPS must know about:
/// posted by the node that does them (through the twin's wiring), read by the EPS.
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
    /// a load: posted by the twin from the EPS's channel switches, read by the PC).
    SbandPowerOff,
}

/// A log of [`Activity`] switches with their times; readers see the state **strictly
/// before** their own instant (see [`TruthBoard`] for why).
///
/// Switches may be posted ahead of time (the air channel posts a queued transmission when
/// it is submitted). The log forgets what no reader can ask for any more: switches more
/// than [`ActivityBoard::KEEP_BEHIND_NS`] before the latest instant any reader has asked
/// about (keeping the last one, which holds the state); only without readers does it fall
/// back to a cap of [`ActivityBoard::MAX_SWITCHES`] per activity.
#[derive(Debug, Clone, Default)]
pub struct ActivityBoard(std::sync::Arc<std::sync::Mutex<ActivityLog>>);

/// Each activity's switches, (time ns, on), and the latest instant a reader asked about.
#[derive(Debug, Default)]
struct ActivityLog {
    switches: std::collections::BTreeMap<Activity, Vec<(u64, bool)>>,
    read_ns: u64,
}

impl ActivityBoard {
    /// How far behind the most advanced reader switches are kept (readers run at the same
    /// simulated instant within a tick; 10 s is ample).
    pub const KEEP_BEHIND_NS: u64 = 10_000_000_000;
    /// Switches kept per activity when nobody reads the board.
    pub const MAX_SWITCHES: usize = 1 << 20;

    /// An empty board: every activity off.
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, ActivityLog> {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// `what` switched on or off at `t_ns` (switches of one activity come in time order).
    pub fn set(&self, what: Activity, t_ns: u64, on: bool) {
        let mut log = self.lock();
        let horizon = log.read_ns.saturating_sub(Self::KEEP_BEHIND_NS);
        let v = log.switches.entry(what).or_default();
        if v.last().is_some_and(|&(_, last)| last == on) {
            return;
        }
        if v.len() >= 4096 {
            // Everything before the last switch older than the horizon is unreachable.
            let old = v.partition_point(|&(t, _)| t < horizon);
            if old > 1 {
                v.drain(..old - 1);
            } else if v.len() >= Self::MAX_SWITCHES {
                v.drain(..Self::MAX_SWITCHES / 2);
            }
        }
        v.push((t_ns, on));
    }

    /// Whether `what` was on just before `t_ns`.
    pub fn on_before(&self, what: Activity, t_ns: u64) -> bool {
        let mut log = self.lock();
        log.read_ns = log.read_ns.max(t_ns);
        log.switches
            .get(&what)
            .and_then(|v| v.iter().rev().find(|(t, _)| *t < t_ns))
            .is_some_and(|&(_, on)| on)
    }

    /// The fraction of `[from_ns, to_ns)` during which `what` was on (0 when the interval is
    /// empty), for energy over an EPS step.
    pub fn duty(&self, what: Activity, from_ns: u64, to_ns: u64) -> f64 {
        if to_ns <= from_ns {
            return 0.0;
        }
        let mut log = self.lock();
        log.read_ns = log.read_ns.max(from_ns);
        let Some(v) = log.switches.get(&what) else {
            return 0.0;
        };
        let mut on_ns = 0u64;
        let mut state = v
            .iter()
            .rev()
            .find(|(t, _)| *t <= from_ns)
            .is_some_and(|&(_, on)| on);
        let mut since = from_ns;
        for &(t, on) in v.iter().filter(|(t, _)| *t > from_ns && *t < to_ns) {
            if state {
                on_ns += t - since;
            }
            state = on;
            since = t;
        }
        if state {
            on_ns += to_ns - since;
        }
        on_ns as f64 / (to_ns - from_ns) as f64
    }

    /// Switches held for `what` (for tests and memory checks).
    pub fn held(&self, what: Activity) -> usize {
        self.lock().switches.get(&what).map_or(0, Vec::len)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn readers_see_only_what_came_strictly_before() {
        let b = TruthBoard::new();
        let post = |k: u64| {
            b.publish(&TruthSnapshot {
                t_ns: k * 1_000_000_000,
                ..TruthSnapshot::default()
            })
        };
        (0..10).for_each(post);
        assert_eq!(b.latest_before(5_000_000_000).unwrap().t_ns, 4_000_000_000);
        assert_eq!(b.latest_before(5_000_000_001).unwrap().t_ns, 5_000_000_000);
        assert!(b.latest_before(0).is_none());
        (10..100).for_each(post);
        // Only the last TRUTH_BOARD_DEPTH are kept.
        assert!(b.latest_before(10_000_000_000).is_none());
        assert_eq!(b.latest_before(u64::MAX).unwrap().t_ns, 99_000_000_000);
    }

    #[test]
    fn burns_are_taken_after_they_are_posted_and_cut_at_power_loss() {
        let b = BurnBoard::new();
        let burn = Burn {
            posted_ns: 100,
            start_ns: 100,
            end_ns: 10_100,
            thrust_n: 1.0,
            mass_flow_kg_s: 0.001,
            mass_kg: 12.0,
            dir_body: Vector3::z(),
        };
        b.post(burn);
        assert!(
            b.pending(100, 0).is_empty(),
            "not at the instant it was posted"
        );
        assert_eq!(b.pending(101, 0), vec![burn]);
        assert!(b.pending(20_000, 10_100).is_empty(), "applied to its end");
        b.cut_all(5_000);
        assert_eq!(b.pending(101, 0)[0].end_ns, 5_000);
        b.forget_before(5_000);
        assert!(b.pending(u64::MAX, 0).is_empty());
    }

    /// A long backlog posted ahead of the reader (2100 transmissions queued back to back on
    /// the air) is all there when the reader gets to it; once the reader has moved on, the
    /// log forgets what lies behind it.
    #[test]
    fn a_backlog_posted_ahead_survives_until_read_and_is_then_forgotten() {
        let a = ActivityBoard::new();
        assert_eq!(a.duty(Activity::UhfTx, 0, 1), 0.0);
        // 250 ms on, 250 ms off, for 2100 transmissions (1050 s).
        let ms = 1_000_000u64;
        for k in 0..2100u64 {
            a.set(Activity::UhfTx, k * 500 * ms, true);
            a.set(Activity::UhfTx, k * 500 * ms + 250 * ms, false);
        }
        assert_eq!(a.held(Activity::UhfTx), 4200);
        assert_eq!(a.duty(Activity::UhfTx, 0, 1000 * ms), 0.5);
        // The reader advances; the next posts forget what is more than 10 s behind it.
        assert_eq!(a.duty(Activity::UhfTx, 1_040_000 * ms, 1_041_000 * ms), 0.5);
        a.set(Activity::UhfTx, 1_100_000 * ms, true);
        assert!(a.held(Activity::UhfTx) < 100, "{}", a.held(Activity::UhfTx));
        assert_eq!(a.duty(Activity::UhfTx, 1_041_000 * ms, 1_042_000 * ms), 0.5);
        assert!(!a.on_before(Activity::UhfTx, 1_050_100 * ms));
        assert!(a.on_before(Activity::UhfTx, 1_100_000 * ms + 1));
    }

    #[test]
    fn activity_duty_over_an_interval() {
        let a = ActivityBoard::new();
        a.set(Activity::SbandTx, 10, true);
        a.set(Activity::SbandTx, 30, false);
        a.set(Activity::SbandTx, 50, true);
        assert!(!a.on_before(Activity::SbandTx, 10));
        assert!(a.on_before(Activity::SbandTx, 11));
        assert!((a.duty(Activity::SbandTx, 0, 100) - 0.7).abs() < 1e-12);
        assert!((a.duty(Activity::SbandTx, 20, 40) - 0.5).abs() < 1e-12);
        assert_eq!(a.duty(Activity::UhfTx, 0, 100), 0.0);
    }
}
