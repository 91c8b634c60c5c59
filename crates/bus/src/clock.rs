//! The run's clock: tokio's paused clock, which jumps to the next timer. In virtual time it
//! runs as fast as the CPU allows; in real time (optionally sped up or slowed down, or from
//! a moment on: outside programs needed only from then on) [`crate::pace`] holds each jump
//! back until the wall clock reaches it, so that the run is the same machine either way.
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
    /// Virtual until `from`, then wall-clock pacing at `speed` (a CI run does not wait
    /// hours of simulated time for a pass).
    VirtualThenRealtime {
        /// The simulated time at which the wall clock takes over.
        from: SimTime,
        /// Simulated seconds per wall second after `from`.
        speed: f64,
    },
}

impl ClockMode {
    /// Where the wall clock paces the run: from which simulated instant, at what speed
    /// (`None` in virtual time).
    pub fn paced(&self) -> Option<(SimTime, f64)> {
        let ok = |speed: f64| {
            if speed.is_finite() && speed > 0.0 {
                speed
            } else {
                1.0
            }
        };
        match *self {
            ClockMode::Virtual => None,
            ClockMode::Realtime { speed } => Some((SimTime::ZERO, ok(speed))),
            ClockMode::VirtualThenRealtime { from, speed } => Some((from, ok(speed))),
        }
    }
}

/// The run's clock, cheap to clone and share between tasks: tokio's paused clock, whatever
/// the mode. In real time the same virtual-time machine runs, its clock held back to the
/// wall clock by [`crate::pace`], so a task never stamps anything with when it happened to
/// run: only simulated instants exist.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: Instant,
    mode: ClockMode,
}

impl Clock {
    /// A clock whose zero is now. The runtime must be built with `start_paused(true)`.
    pub fn new(mode: ClockMode) -> Self {
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
        SimTime(u64::try_from(self.start.elapsed().as_nanos()).unwrap_or(u64::MAX))
    }

    /// The tokio instant at which simulated time `t` is reached.
    pub fn instant_of(&self, t: SimTime) -> Instant {
        self.start
            .checked_add(Duration::from_nanos(t.as_ns()))
            .unwrap_or_else(|| self.start + Duration::from_secs(1 << 40))
    }

    /// Sleep until simulated time `t` (returns at once if it has passed).
    pub async fn sleep_until(&self, t: SimTime) {
        if crate::exec::in_run_task() {
            return Timer::new(*self).sleep_until(t).await;
        }
        if t == SimTime::MAX {
            std::future::pending::<()>().await;
        }
        tokio::time::sleep_until(self.instant_of(t)).await;
    }
}

impl crate::exec::RunClock for Clock {
    fn now(&self) -> SimTime {
        Clock::now(self)
    }

    fn instant_of(&self, t: SimTime) -> Instant {
        Clock::instant_of(self, t)
    }
}

/// A task's one timer, kept from one wait to the next: waiting again for the same instant
/// keeps the timer where it is (a fresh sleep registers a timer and takes it out again on
/// every turn of a task's loop, and a node task turns for every arrival). In a run's task
/// it waits in the run's ordered timers ([`crate::exec`]); elsewhere on tokio's.
#[derive(Debug)]
pub struct Timer {
    clock: Clock,
    /// Its place among the run's timers, while it waits there.
    key: Option<crate::exec::TimerKey>,
    sleep: std::pin::Pin<Box<tokio::time::Sleep>>,
    /// The instant tokio's sleep is set for, if any.
    armed: Option<SimTime>,
}

impl Timer {
    /// A timer on `clock`, not set.
    pub fn new(clock: Clock) -> Self {
        Timer {
            clock,
            key: None,
            sleep: Box::pin(tokio::time::sleep_until(clock.instant_of(SimTime::MAX))),
            armed: None,
        }
    }

    /// [`Clock::sleep_until`], with this timer.
    pub async fn sleep_until(&mut self, t: SimTime) {
        if t == SimTime::MAX {
            self.disarm();
            return std::future::pending().await;
        }
        std::future::poll_fn(|cx| self.poll_until(t, cx)).await;
    }

    fn poll_until(&mut self, t: SimTime, cx: &mut std::task::Context<'_>) -> std::task::Poll<()> {
        if let Some(p) = crate::exec::poll_timer(&mut self.key, t) {
            return p;
        }
        if self.armed != Some(t) {
            self.sleep.as_mut().reset(self.clock.instant_of(t));
            self.armed = Some(t);
        }
        self.sleep.as_mut().poll(cx)
    }

    /// Take the timer out (a task with nothing to wait for is not woken by its last
    /// instant).
    pub fn disarm(&mut self) {
        crate::exec::cancel_timer(&mut self.key);
        if self.armed.take().is_some() {
            self.sleep
                .as_mut()
                .reset(self.clock.instant_of(SimTime::MAX));
        }
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        crate::exec::cancel_timer(&mut self.key);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

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
