//! Time scales (in progress: the orbit issue fills this module).

/// A UTC instant: integer nanoseconds since 1970-01-01T00:00:00 UTC, POSIX style (leap
/// seconds are not counted in the value; TT conversion adds them from a table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct UtcTime {
    unix_ns: i64,
}

impl UtcTime {
    /// From integer nanoseconds since the Unix epoch.
    pub const fn from_unix_ns(unix_ns: i64) -> Self {
        UtcTime { unix_ns }
    }
    /// Integer nanoseconds since the Unix epoch.
    pub const fn unix_ns(&self) -> i64 {
        self.unix_ns
    }
}
