//! The PC's session table (ICD 3.1.2-3.1.7, INTERPRETATION.md section 7): one slot per
//! configured payload, its ICD state and last result, and the SETUP/ABORT/STATUS rules.
//!
//! # Rules
//! - SETUP (after the port's range checks: duration 5-900 s, frame size 1-254, sync message
//!   at most 128 bytes) is refused when the session id is not configured; when that session
//!   is PENDING or ACTIVE (ICD 3.1.3: reconfigured only after ABORT); when its window
//!   `[start, start + duration)` overlaps the window of any other PENDING or ACTIVE session;
//!   and when it would start at once (timestamp 0 or not in the future) while another
//!   session is ACTIVE.
//! - Times are UTC unix nanoseconds of the PC's clock (`Node::clock_unix_ns`). A future
//!   start is turned into a simulated time when SETUP is accepted; a session starting at
//!   once runs for its full duration from the SETUP.
//! - At most one session is ACTIVE. A PENDING session whose time comes while another is
//!   ACTIVE (the overlap rule rules this out; kept for safety) waits until that one ends and
//!   keeps its configured end; if the end has passed by then, it starts and ends at once
//!   with DONE and no packets.
//! - ABORT of an ACTIVE or PENDING session records ABORTED; ABORT of a NOT ACTIVE session is
//!   refused and changes nothing.
//! - STATUS reports the last configuration accepted for the session (as SETUP gave it,
//!   timestamp included) and the result of the last finished session; a session never
//!   configured reports DONE, NOT ACTIVE and zeros.

use std::fmt;
use std::time::Duration;

use csp::SimTime;

use crate::SessionSpec;
use crate::wire::{SessionConfig, SessionResult, SessionState, Status};

/// Why SETUP or ABORT was refused (the reply is the failure reply; this goes to the log).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Refusal {
    /// No session with this id is configured.
    UnknownSession(u8),
    /// SETUP of a session that is PENDING or ACTIVE.
    Busy(u8, SessionState),
    /// The window overlaps the window of another configured session.
    Overlap(u8),
    /// An immediate start while another session is ACTIVE.
    OtherActive(u8),
    /// ABORT of a session that is NOT ACTIVE.
    NotRunning(u8),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::UnknownSession(id) => write!(f, "no session {id} is configured"),
            Refusal::Busy(id, s) => write!(f, "session {id} is {s:?}: ABORT it first"),
            Refusal::Overlap(other) => write!(f, "window overlaps session {other}"),
            Refusal::OtherActive(other) => {
                write!(f, "immediate start while session {other} is ACTIVE")
            }
            Refusal::NotRunning(id) => write!(f, "session {id} is NOT ACTIVE"),
        }
    }
}

/// One session slot: its fixed specification and ICD state.
#[derive(Debug, Clone)]
pub struct Slot {
    /// The scenario's specification.
    pub spec: SessionSpec,
    /// ICD state.
    pub state: SessionState,
    /// Result of the last finished session.
    pub last_result: SessionResult,
    /// The last accepted configuration.
    pub config: Option<SessionConfig>,
    /// Simulated start time (PENDING: planned; ACTIVE: actual).
    pub start_at: SimTime,
    /// Simulated end time.
    pub end_at: SimTime,
    /// Window in unix nanoseconds, for the overlap rule.
    pub window_unix_ns: (i128, i128),
    /// Packets counted in the current (or last) session.
    pub packets: u32,
}

impl Slot {
    fn new(spec: SessionSpec) -> Self {
        Slot {
            spec,
            state: SessionState::NotActive,
            last_result: SessionResult::Done,
            config: None,
            start_at: SimTime::ZERO,
            end_at: SimTime::ZERO,
            window_unix_ns: (0, 0),
            packets: 0,
        }
    }
    /// Whether the slot is PENDING or ACTIVE.
    pub fn is_configured(&self) -> bool {
        self.state != SessionState::NotActive
    }
    /// The STATUS reply data.
    pub fn status(&self) -> Status {
        let c = self.config.clone().unwrap_or_default();
        Status {
            last_result: self.last_result,
            state: self.state,
            timestamp: c.timestamp,
            duration_s: c.duration_s,
            max_packets: c.max_packets,
            poll_frame_size: c.poll_frame_size,
            sync_message: c.sync_message,
        }
    }
}

/// What an accepted SETUP does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accepted {
    /// The session is PENDING until its start.
    Pending,
    /// The session starts now (the caller activates it).
    StartNow,
}

/// The session table (see the module doc).
#[derive(Debug, Clone)]
pub struct SessionTable {
    slots: Vec<Slot>,
}

impl SessionTable {
    /// A table of NOT ACTIVE sessions, one per spec.
    pub fn new(specs: &[SessionSpec]) -> Self {
        SessionTable {
            slots: specs.iter().cloned().map(Slot::new).collect(),
        }
    }
    /// The slots, in configuration order.
    pub fn slots(&self) -> &[Slot] {
        &self.slots
    }
    /// One slot.
    pub fn slot(&self, i: usize) -> Option<&Slot> {
        self.slots.get(i)
    }
    /// One slot, mutable.
    pub fn slot_mut(&mut self, i: usize) -> Option<&mut Slot> {
        self.slots.get_mut(i)
    }
    /// The slot of a session id (the first one if the configuration repeats an id).
    pub fn index_of(&self, session_id: u8) -> Option<usize> {
        self.slots
            .iter()
            .position(|s| s.spec.session_id == session_id)
    }
    /// The ACTIVE slot.
    pub fn active(&self) -> Option<usize> {
        self.slots
            .iter()
            .position(|s| s.state == SessionState::Active)
    }

    /// Apply the SETUP rules at `now` (clock `now_unix_ns`) to a range-checked configuration.
    pub fn setup(
        &mut self,
        cfg: &SessionConfig,
        now: SimTime,
        now_unix_ns: i128,
    ) -> Result<(usize, Accepted), Refusal> {
        let i = self
            .index_of(cfg.session_id)
            .ok_or(Refusal::UnknownSession(cfg.session_id))?;
        let state = self.slots.get(i).map(|s| s.state).unwrap_or_default();
        if state != SessionState::NotActive {
            return Err(Refusal::Busy(cfg.session_id, state));
        }
        let duration = Duration::from_secs(u64::from(cfg.duration_s));
        let requested_ns = i128::from(cfg.timestamp) * 1_000_000_000;
        let immediate = cfg.timestamp == 0 || requested_ns <= now_unix_ns;
        let start_ns = if immediate { now_unix_ns } else { requested_ns };
        let window = (
            start_ns,
            start_ns + i128::from(cfg.duration_s) * 1_000_000_000,
        );
        if immediate && let Some(a) = self.active() {
            let other = self.slots.get(a).map_or(0, |s| s.spec.session_id);
            return Err(Refusal::OtherActive(other));
        }
        if let Some(other) = self.slots.iter().enumerate().find(|(j, s)| {
            *j != i
                && s.is_configured()
                && s.window_unix_ns.0 < window.1
                && window.0 < s.window_unix_ns.1
        }) {
            return Err(Refusal::Overlap(other.1.spec.session_id));
        }
        let start_at = if immediate {
            now
        } else {
            now + Duration::from_nanos(u64::try_from(start_ns - now_unix_ns).unwrap_or(u64::MAX))
        };
        let Some(slot) = self.slots.get_mut(i) else {
            return Err(Refusal::UnknownSession(cfg.session_id));
        };
        slot.config = Some(cfg.clone());
        slot.start_at = start_at;
        slot.end_at = start_at + duration;
        slot.window_unix_ns = window;
        slot.state = SessionState::Pending;
        Ok((
            i,
            if immediate {
                Accepted::StartNow
            } else {
                Accepted::Pending
            },
        ))
    }

    /// Apply ABORT: the slot and the state it was in (the caller ends an ACTIVE one).
    pub fn abort(&mut self, session_id: u8) -> Result<(usize, SessionState), Refusal> {
        let i = self
            .index_of(session_id)
            .ok_or(Refusal::UnknownSession(session_id))?;
        let Some(slot) = self.slots.get_mut(i) else {
            return Err(Refusal::UnknownSession(session_id));
        };
        match slot.state {
            SessionState::NotActive => Err(Refusal::NotRunning(session_id)),
            SessionState::Pending => {
                slot.state = SessionState::NotActive;
                slot.last_result = SessionResult::Aborted;
                Ok((i, SessionState::Pending))
            }
            SessionState::Active => Ok((i, SessionState::Active)),
        }
    }

    /// The PENDING slot due at `now` that may start (none while one is ACTIVE).
    pub fn due_start(&self, now: SimTime) -> Option<usize> {
        if self.active().is_some() {
            return None;
        }
        self.slots
            .iter()
            .enumerate()
            .filter(|(_, s)| s.state == SessionState::Pending && s.start_at <= now)
            .min_by_key(|(_, s)| s.start_at)
            .map(|(i, _)| i)
    }

    /// The earliest table timer: the ACTIVE session's end, else the next PENDING start.
    pub fn poll_timeout(&self) -> Option<SimTime> {
        match self.active() {
            Some(a) => self.slots.get(a).map(|s| s.end_at),
            None => self
                .slots
                .iter()
                .filter(|s| s.state == SessionState::Pending)
                .map(|s| s.start_at)
                .min(),
        }
    }

    /// The PC's clock was set (it reads `now_unix_ns` at `now`): each PENDING session now
    /// starts when the clock reads its timestamp, at once if that has passed. An ACTIVE
    /// session keeps its end (its duration is elapsed time). The PENDING sessions moved.
    pub fn reanchor(&mut self, now: SimTime, now_unix_ns: i128) -> Vec<u8> {
        let mut moved = Vec::new();
        for s in self
            .slots
            .iter_mut()
            .filter(|s| s.state == SessionState::Pending)
        {
            let ahead_ns =
                u64::try_from((s.window_unix_ns.0 - now_unix_ns).max(0)).unwrap_or(u64::MAX);
            let duration_ns = s.end_at.as_ns().saturating_sub(s.start_at.as_ns());
            let start_at = now + Duration::from_nanos(ahead_ns);
            if start_at != s.start_at {
                moved.push(s.spec.session_id);
            }
            s.start_at = start_at;
            s.end_at = start_at + Duration::from_nanos(duration_ns);
        }
        moved
    }

    /// Make slot `i` ACTIVE at `now` (packet counter from zero).
    pub fn activate(&mut self, i: usize, now: SimTime) {
        if let Some(s) = self.slots.get_mut(i) {
            s.state = SessionState::Active;
            s.start_at = now;
            s.packets = 0;
        }
    }
    /// End slot `i` with `result`.
    pub fn finish(&mut self, i: usize, result: SessionResult) {
        if let Some(s) = self.slots.get_mut(i) {
            s.state = SessionState::NotActive;
            s.last_result = result;
        }
    }
    /// Forget every session (reboot).
    pub fn reset(&mut self) {
        for s in &mut self.slots {
            *s = Slot::new(s.spec.clone());
        }
    }
}

snap::fields!(Slot {
    spec,
    state,
    last_result,
    config,
    start_at,
    end_at,
    window_unix_ns,
    packets
});
snap::fields!(SessionTable { slots });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::SessionMode;

    const T0: i128 = 1_000_000 * 1_000_000_000;

    fn table() -> SessionTable {
        let spec = |id, addr| SessionSpec {
            session_id: id,
            payload_addr: addr,
            payload_port: 10,
            mode: SessionMode::Buffering,
            buffer_capacity_bytes: 1024,
        };
        SessionTable::new(&[spec(1, 12), spec(2, 13), spec(3, 14)])
    }

    fn cfg(id: u8, ts: u32, d: u16) -> SessionConfig {
        SessionConfig {
            session_id: id,
            timestamp: ts,
            duration_s: d,
            max_packets: 0,
            poll_frame_size: 10,
            sync_message: vec![],
        }
    }

    #[test]
    fn windows_overlap_only_when_they_share_time() {
        let mut t = table();
        let now = SimTime::from_secs(5);
        assert_eq!(
            t.setup(&cfg(1, 1_000_100, 60), now, T0),
            Ok((0, Accepted::Pending))
        );
        assert_eq!(t.slot(0).unwrap().start_at, SimTime::from_secs(105));
        assert_eq!(t.slot(0).unwrap().end_at, SimTime::from_secs(165));
        // Windows are half-open: starting one second before the end overlaps, at the end not.
        assert_eq!(
            t.setup(&cfg(2, 1_000_159, 10), now, T0),
            Err(Refusal::Overlap(1))
        );
        assert_eq!(
            t.setup(&cfg(2, 1_000_160, 10), now, T0),
            Ok((1, Accepted::Pending))
        );
        assert_eq!(
            t.setup(&cfg(3, 1_000_095, 5), now, T0),
            Ok((2, Accepted::Pending))
        );
        assert_eq!(t.poll_timeout(), Some(SimTime::from_secs(100)));
    }

    #[test]
    fn busy_unknown_and_abort() {
        let mut t = table();
        let now = SimTime::ZERO;
        assert_eq!(
            t.setup(&cfg(9, 0, 5), now, T0),
            Err(Refusal::UnknownSession(9))
        );
        t.setup(&cfg(1, 1_000_100, 5), now, T0).unwrap();
        assert_eq!(
            t.setup(&cfg(1, 1_000_200, 5), now, T0),
            Err(Refusal::Busy(1, SessionState::Pending))
        );
        assert_eq!(t.abort(1), Ok((0, SessionState::Pending)));
        assert_eq!(t.slot(0).unwrap().last_result, SessionResult::Aborted);
        assert_eq!(t.abort(1), Err(Refusal::NotRunning(1)));
        assert!(t.setup(&cfg(1, 1_000_200, 5), now, T0).is_ok());
    }

    #[test]
    fn immediate_start_refused_while_another_is_active() {
        let mut t = table();
        let (i, how) = t.setup(&cfg(1, 0, 5), SimTime::ZERO, T0).unwrap();
        assert_eq!(how, Accepted::StartNow);
        t.activate(i, SimTime::ZERO);
        assert_eq!(
            t.setup(&cfg(2, 999, 5), SimTime::ZERO, T0),
            Err(Refusal::OtherActive(1))
        );
        assert_eq!(t.due_start(SimTime::MAX), None);
    }
}
