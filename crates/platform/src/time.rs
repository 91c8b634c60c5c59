//! Simulated time: integer nanoseconds since the start of a run ([`SimTime`]). Conversions to
//! UTC, TT and UT1 live in `orbit`; inside the twin time is this integer and nothing else.

use std::fmt;
use std::ops::{Add, Sub};
use std::time::Duration;

/// Simulated time in integer nanoseconds since the start of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct SimTime(pub u64);

impl SimTime {
    /// The start of the run.
    pub const ZERO: SimTime = SimTime(0);
    /// The far future (never).
    pub const MAX: SimTime = SimTime(u64::MAX);

    /// Time from whole nanoseconds.
    pub const fn from_ns(t_ns: u64) -> Self {
        SimTime(t_ns)
    }
    /// Time from whole microseconds.
    pub const fn from_us(t_us: u64) -> Self {
        SimTime(t_us.saturating_mul(1_000))
    }
    /// Time from whole milliseconds.
    pub const fn from_ms(t_ms: u64) -> Self {
        SimTime(t_ms.saturating_mul(1_000_000))
    }
    /// Time from whole seconds.
    pub const fn from_secs(t_s: u64) -> Self {
        SimTime(t_s.saturating_mul(1_000_000_000))
    }
    /// Nanoseconds since the start.
    pub const fn as_ns(self) -> u64 {
        self.0
    }
    /// Whole milliseconds since the start (truncated).
    pub const fn as_ms(self) -> u64 {
        self.0 / 1_000_000
    }
    /// Whole seconds since the start (truncated).
    pub const fn as_secs(self) -> u64 {
        self.0 / 1_000_000_000
    }
    /// Seconds as a float, for display only.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }
    /// `self - earlier`, or zero if `earlier` is later.
    pub fn saturating_since(self, earlier: SimTime) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl Add<Duration> for SimTime {
    type Output = SimTime;
    fn add(self, d: Duration) -> SimTime {
        SimTime(
            self.0
                .saturating_add(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)),
        )
    }
}

impl Sub for SimTime {
    type Output = Duration;
    fn sub(self, rhs: SimTime) -> Duration {
        self.saturating_since(rhs)
    }
}

impl fmt::Display for SimTime {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = self.0 / 1_000_000_000;
        let ns = self.0 % 1_000_000_000;
        write!(f, "{s}.{ns:09}s")
    }
}
/// Saved as its nanoseconds.
impl snap::Snap for SimTime {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.0.load(r)
    }
}

impl snap::SnapNew for SimTime {
    const MIN_BYTES: usize = 8;
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        <u64 as snap::SnapNew>::read(r).map(SimTime)
    }
}
