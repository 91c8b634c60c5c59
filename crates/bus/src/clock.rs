//! The run's clock: virtual time (tokio's paused clock, jumping to the next timer) or real
//! time (the wall clock, optionally sped up or slowed down).
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
}

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
        let mode = match mode {
            ClockMode::Realtime { speed } if !(speed.is_finite() && speed > 0.0) => {
                ClockMode::Realtime { speed: 1.0 }
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
        match self.mode {
            ClockMode::Virtual => SimTime(u64::try_from(wall.as_nanos()).unwrap_or(u64::MAX)),
            ClockMode::Realtime { speed } => SimTime((wall.as_nanos() as f64 * speed) as u64),
        }
    }

    /// The tokio instant at which simulated time `t` is reached.
    pub fn instant_of(&self, t: SimTime) -> Instant {
        let wall = match self.mode {
            ClockMode::Virtual => Duration::from_nanos(t.as_ns()),
            ClockMode::Realtime { speed } => {
                Duration::from_nanos((t.as_ns() as f64 / speed) as u64)
            }
        };
        self.start
            .checked_add(wall)
            .unwrap_or_else(|| self.start + Duration::from_secs(1 << 40))
    }

    /// Sleep until simulated time `t` (returns at once if it has passed).
    pub async fn sleep_until(&self, t: SimTime) {
        if t == SimTime::MAX {
            std::future::pending::<()>().await;
        }
        tokio::time::sleep_until(self.instant_of(t)).await;
    }
}
