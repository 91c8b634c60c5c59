//! The run's clock: virtual time (tokio's paused clock, jumping to the next timer), real
//! time (the wall clock, optionally sped up or slowed down), or virtual time until a
//! moment and real time after it (outside programs needed only from then on: a CI run does
//! not wait hours of simulated time for a pass).
//!
//! Events carry exact [`SimTime`] stamps in nanoseconds; the tokio timer wheel that wakes
//! tasks has a 1 ms granularity, so a task may run up to 1 ms (of its clock) after the stamp
//! of the event it handles. Cores always use the stamp, never the wake-up time, so the
//! simulated timeline stays exact and a virtual-time run is deterministic.

use std::time::Duration;

use csp::SimTime;
use tokio::time::Instant;

/// How simulated time relates to the wall clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClockMode {
    /// Paused tokio clock that jumps to the next timer: as fast as the CPU allows.
    Virtual,
    /// Wall-clock pacing; `speed` simulated seconds per wall second (1.0 = real time).
    Realtime {
        /// Simulated seconds per wall second.
        speed: f64,
    },
    /// Virtual until `from`, then wall-clock pacing at `speed`: the runtime starts paused
    /// and [`Clock::go_realtime`] resumes tokio's clock at `from`.
    VirtualThenRealtime {
        /// The simulated time at which the wall clock takes over.
        from: SimTime,
        /// Simulated seconds per wall second after `from`.
        speed: f64,
    },
}

impl ClockMode {
    /// Whether the run starts on tokio's paused clock.
    pub fn starts_paused(&self) -> bool {
        matches!(
            self,
            ClockMode::Virtual | ClockMode::VirtualThenRealtime { .. }
        )
    }
}

/// The granularity of tokio's timer wheel.
const TIMER_TICK: Duration = Duration::from_millis(1);

/// The run's clock, cheap to clone and share between tasks.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: Instant,
    mode: ClockMode,
}

impl Clock {
    /// A clock whose zero is now. In virtual mode the runtime must be built with
    /// `start_paused(true)`.
    pub fn new(mode: ClockMode) -> Self {
        let ok = |speed: f64| speed.is_finite() && speed > 0.0;
        let mode = match mode {
            ClockMode::Realtime { speed } if !ok(speed) => ClockMode::Realtime { speed: 1.0 },
            ClockMode::VirtualThenRealtime { from, speed } if !ok(speed) => {
                ClockMode::VirtualThenRealtime { from, speed: 1.0 }
            }
            m => m,
        };
        Clock {
            start: Instant::now(),
            mode,
        }
    }

    /// The clock's mode.
    pub fn mode(&self) -> ClockMode {
        self.mode
    }

    /// Whether time is virtual.
    pub fn is_virtual(&self) -> bool {
        self.mode == ClockMode::Virtual
    }

    /// Simulated time now.
    pub fn now(&self) -> SimTime {
        let wall = self.start.elapsed();
        let ns = u64::try_from(wall.as_nanos()).unwrap_or(u64::MAX);
        match self.mode {
            ClockMode::Virtual => SimTime(ns),
            ClockMode::Realtime { speed } => SimTime((ns as f64 * speed) as u64),
            // Until `from` the paused clock's elapsed time is simulated time; after it
            // the wall clock's, scaled.
            ClockMode::VirtualThenRealtime { from, speed } => match ns.checked_sub(from.as_ns()) {
                None | Some(0) => SimTime(ns),
                Some(after) => SimTime(from.as_ns().saturating_add((after as f64 * speed) as u64)),
            },
        }
    }

    /// The tokio instant at which simulated time `t` is reached.
    pub fn instant_of(&self, t: SimTime) -> Instant {
        let wall = match self.mode {
            ClockMode::Virtual => Duration::from_nanos(t.as_ns()),
            ClockMode::Realtime { speed } => {
                Duration::from_nanos((t.as_ns() as f64 / speed) as u64)
            }
            ClockMode::VirtualThenRealtime { from, speed } => {
                match t.as_ns().checked_sub(from.as_ns()) {
                    None | Some(0) => Duration::from_nanos(t.as_ns()),
                    Some(after) => Duration::from_nanos(
                        from.as_ns().saturating_add((after as f64 / speed) as u64),
                    ),
                }
            }
        };
        self.start
            .checked_add(wall)
            .unwrap_or_else(|| self.start + Duration::from_secs(1 << 40))
    }

    /// In [`ClockMode::VirtualThenRealtime`], wait for its `from` and let the wall clock
    /// take over there (tokio's clock resumes); returns at once in any other mode. Call it
    /// once, from a task of the run's (current-thread) runtime.
    pub async fn go_realtime(&self) -> Option<SimTime> {
        let ClockMode::VirtualThenRealtime { from, .. } = self.mode else {
            return None;
        };
        self.sleep_until(from).await;
        tokio::time::resume();
        Some(from)
    }

    /// Sleep until simulated time `t` (returns at once if it has passed).
    ///
    /// On the wall clock, tokio's timer wheel would wake the task at the first millisecond
    /// tick after `t`: up to 1 ms late at every step of an exchange with an outside program
    /// (a CAN frame's end, a node's reply). So the wheel wakes it up to 1 ms early and a
    /// blocking thread's precise sleep waits the rest (microseconds on Linux).
    pub async fn sleep_until(&self, t: SimTime) {
        if t == SimTime::MAX {
            std::future::pending::<()>().await;
        }
        let at = self.instant_of(t);
        if !self.wall_clock_at(t) {
            tokio::time::sleep_until(at).await;
            return;
        }
        if let Some(early) = at.checked_sub(TIMER_TICK) {
            tokio::time::sleep_until(early).await;
        }
        let rest = at.saturating_duration_since(Instant::now());
        if !rest.is_zero() {
            let _ = tokio::task::spawn_blocking(move || std::thread::sleep(rest)).await;
        }
    }

    /// Whether simulated time `t` is paced by the wall clock.
    fn wall_clock_at(&self, t: SimTime) -> bool {
        match self.mode {
            ClockMode::Virtual => false,
            ClockMode::Realtime { .. } => true,
            ClockMode::VirtualThenRealtime { from, .. } => t > from,
        }
    }
}

/// A task's one timer, kept from one wait to the next: waiting again for the same instant
/// keeps the timer where it is (a fresh sleep registers a timer and takes it out again on
/// every turn of a task's loop, and a node task turns for every arrival).
#[derive(Debug)]
pub struct Timer {
    clock: Clock,
    sleep: std::pin::Pin<Box<tokio::time::Sleep>>,
    /// The instant the sleep is set for, if any.
    armed: Option<SimTime>,
}

impl Timer {
    /// A timer on `clock`, not set.
    pub fn new(clock: Clock) -> Self {
        Timer {
            clock,
            sleep: Box::pin(tokio::time::sleep_until(clock.instant_of(SimTime::MAX))),
            armed: None,
        }
    }

    /// [`Clock::sleep_until`], with this timer.
    pub async fn sleep_until(&mut self, t: SimTime) {
        if t == SimTime::MAX || self.clock.wall_clock_at(t) {
            self.disarm();
            return self.clock.sleep_until(t).await;
        }
        if self.armed != Some(t) {
            self.sleep.as_mut().reset(self.clock.instant_of(t));
            self.armed = Some(t);
        }
        self.sleep.as_mut().await;
    }

    /// Take the timer out (a task with nothing to wait for is not woken by its last
    /// instant).
    pub fn disarm(&mut self) {
        if self.armed.take().is_some() {
            self.sleep
                .as_mut()
                .reset(self.clock.instant_of(SimTime::MAX));
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Virtual until `from` (10 s pass at once), then the wall clock at twice real time.
    #[test]
    fn virtual_then_realtime_jumps_to_from_then_follows_the_wall_clock() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
            .unwrap();
        rt.block_on(async {
            let from = SimTime::from_ns(10_000_000_000);
            let clock = Clock::new(ClockMode::VirtualThenRealtime { from, speed: 2.0 });
            let wall = std::time::Instant::now();
            clock.sleep_until(SimTime::from_ns(4_000_000_000)).await;
            assert_eq!(clock.now(), SimTime::from_ns(4_000_000_000));
            assert_eq!(clock.go_realtime().await, Some(from));
            assert!(wall.elapsed() < Duration::from_millis(500), "virtual part");
            assert!(clock.now() >= from);
            // 12 s is 1 s of wall clock after `from` at speed 2.
            assert_eq!(
                clock.instant_of(SimTime::from_ns(12_000_000_000)) - clock.instant_of(from),
                Duration::from_secs(1)
            );
            let w = std::time::Instant::now();
            clock.sleep_until(from + Duration::from_millis(200)).await;
            let took = w.elapsed();
            assert!(
                took >= Duration::from_millis(90) && took < Duration::from_secs(2),
                "200 ms simulated at speed 2 took {took:?} of wall clock"
            );
            assert!(clock.now() >= from + Duration::from_millis(200));
        });
    }

    /// A kept timer fires at each instant it is set for: again at once for the instant it
    /// fired at, and at the earlier of two when set for a later one first.
    #[tokio::test(start_paused = true)]
    async fn a_kept_timer_fires_at_each_instant_it_is_set_for() {
        let clock = Clock::new(ClockMode::Virtual);
        let mut timer = Timer::new(clock);
        let s = SimTime::from_secs;
        timer.sleep_until(s(2)).await;
        assert_eq!(clock.now(), s(2));
        timer.sleep_until(s(2)).await;
        assert_eq!(clock.now(), s(2), "already past: at once");
        tokio::select! {
            biased;
            () = timer.sleep_until(s(9)) => panic!("9 s is not there yet"),
            () = tokio::task::yield_now() => {}
        }
        timer.sleep_until(s(7)).await;
        assert_eq!(clock.now(), s(7));
        timer.disarm();
        timer.sleep_until(s(8)).await;
        assert_eq!(clock.now(), s(8));
    }
}
