//! Time scales: UTC instants, Julian dates, TT, UT1 and Greenwich mean sidereal time.
//!
//! # Model
//! - [`UtcTime`] is integer nanoseconds since 1970-01-01T00:00:00 UTC, POSIX style: a day is
//!   always 86 400 s of the count, so a leap second is not representable (23:59:60 is
//!   rejected by the parser) and the value maps one-to-one to a UTC calendar date and time.
//! - [`JulianDate`] is a two-part Julian date (`day + frac`), as SOFA/ERFA and Vallado use,
//!   so that a date keeps sub-microsecond resolution. [`UtcTime::jd_utc`] returns
//!   `day = JD of the preceding 0h` (always `.5`) and `frac` in `[0, 1)`.
//! - TT = UTC + (TAI - UTC) + 32.184 s. TAI - UTC comes from the embedded table of the
//!   USNO/IERS `tai-utc.dat` (IERS Bulletin C): the drift formulas of 1961-1971, then whole
//!   seconds from 1972-01-01 (10 s) to the last leap second, 2017-01-01 (37 s). None has
//!   been introduced since; IERS Bulletin C announces each one about six months ahead, and
//!   a new one needs a new entry in this table.
//! - UT1 = UTC + (UT1 - UTC), with UT1 - UTC from an [`EopTable`] (IERS `finals` format).
//!   Without a table, or outside its range, UT1 = UTC (an error of at most 0.9 s, i.e. up to
//!   about 420 m of Earth rotation at the equator); callers that need more load a table.
//! - GMST is the IAU-82 expression (Aoki et al. 1982) as in Vallado's `gstime` and ERFA's
//!   `gmst82`, evaluated from a two-part UT1 Julian date.
//!
//! # Outside the tables
//! - Before 1961-01-01 there is no UTC as such; [`UtcTime::tt_minus_utc_s`] uses the first
//!   table entry (1.4228180 s + 32.184 s), so TT is continuous but not meaningful.
//! - After the last table entry TAI - UTC stays 37 s. A future leap second (none announced)
//!   would need a new entry here.
//! - [`EopTable::at`] returns `None` before the first and after the last tabulated day with
//!   a UT1 - UTC value; [`UtcTime::jd_ut1`] then falls back to UT1 = UTC.
//!
//! # Invariants
//! - No function here panics on any input; parsers return [`TimeError`].
//! - Integer time is exact: conversions go through `i64` nanoseconds and split days before
//!   converting to `f64`, so the fraction of a day keeps about 1e-11 day (1 µs) or better.

use std::f64::consts::TAU;

/// Nanoseconds in one SI second.
const NS_PER_S: i64 = 1_000_000_000;
/// Seconds in one day.
const S_PER_DAY: i64 = 86_400;
/// Nanoseconds in one day.
const NS_PER_DAY: i64 = S_PER_DAY * NS_PER_S;
/// Julian date of 1970-01-01T00:00:00 (the Unix epoch).
const JD_UNIX_EPOCH: f64 = 2_440_587.5;
/// Julian date of the J2000.0 epoch, 2000-01-01T12:00:00 TT.
pub const JD_J2000: f64 = 2_451_545.0;
/// Days in a Julian century.
pub const DAYS_PER_JULIAN_CENTURY: f64 = 36_525.0;
/// Modified Julian date offset: MJD = JD - 2 400 000.5.
pub const MJD_OFFSET: f64 = 2_400_000.5;
/// TT - TAI, s (IAU 1991, exactly 32.184 s).
pub const TT_MINUS_TAI_S: f64 = 32.184;

/// Why a time or an EOP table could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TimeError {
    /// The text is not `YYYY-MM-DDTHH:MM:SS[.f...][Z]`.
    #[error("not an ISO-8601 UTC time (YYYY-MM-DDTHH:MM:SS[.ffffff][Z]): {0:?}")]
    BadIso8601(String),
    /// A field of the date or time is out of range (month 13, second 60, ...).
    #[error("date or time field out of range in {0:?}")]
    OutOfRange(String),
    /// An IERS finals line could not be read.
    #[error("EOP line {line}: {reason}")]
    BadEopLine {
        /// 1-based line number in the text.
        line: usize,
        /// What was wrong.
        reason: &'static str,
    },
    /// The EOP text had no line with a UT1 - UTC value.
    #[error("EOP table has no UT1-UTC values")]
    EmptyEop,
}

/// A UTC instant: integer nanoseconds since 1970-01-01T00:00:00 UTC, POSIX style (leap
/// seconds are not counted in the value; TT conversion adds them from a table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct UtcTime {
    unix_ns: i64,
}

/// A two-part Julian date: the value is `day + frac` (either part may hold any share).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JulianDate {
    /// The larger part, days (usually the JD of the preceding 0h, ending in .5).
    pub day: f64,
    /// The smaller part, days.
    pub frac: f64,
}

impl JulianDate {
    /// Build a two-part Julian date.
    pub const fn new(day: f64, frac: f64) -> Self {
        JulianDate { day, frac }
    }

    /// The Julian date as one `f64` (loses resolution to about 40 µs).
    pub fn value(&self) -> f64 {
        self.day + self.frac
    }

    /// Julian centuries since J2000.0 (`(JD - 2451545.0) / 36525`), computed without
    /// cancellation.
    pub fn centuries_since_j2000(&self) -> f64 {
        ((self.day - JD_J2000) + self.frac) / DAYS_PER_JULIAN_CENTURY
    }

    /// Days since J2000.0, computed without cancellation.
    pub fn days_since_j2000(&self) -> f64 {
        (self.day - JD_J2000) + self.frac
    }

    /// This date shifted by `seconds`.
    pub fn plus_seconds(&self, seconds: f64) -> Self {
        JulianDate {
            day: self.day,
            frac: self.frac + seconds / S_PER_DAY as f64,
        }
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (Howard Hinnant's `days_from_civil`).
const fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = if y >= 0 { y } else { y - 399 } / 400;
    let yoe = y - era * 400;
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Proleptic Gregorian (year, month, day) of a day count since 1970-01-01 (Hinnant's
/// `civil_from_days`).
const fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = if z >= 0 { z } else { z - 146_096 } / 146_097;
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (if m <= 2 { y + 1 } else { y }, m, d)
}

const fn is_leap_year(year: i64) -> bool {
    (year % 4 == 0 && year % 100 != 0) || year % 400 == 0
}

const fn days_in_month(year: i64, month: i64) -> i64 {
    match month {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        _ => {
            if is_leap_year(year) {
                29
            } else {
                28
            }
        }
    }
}

/// One line of `tai-utc.dat`: from `mjd_start` on, TAI - UTC = `offset_s + (MJD - mjd_ref) *
/// rate_s_per_day`.
struct TaiUtcEntry {
    mjd_start: i64,
    offset_s: f64,
    mjd_ref: f64,
    rate_s_per_day: f64,
}

const fn drift(mjd_start: i64, offset_s: f64, mjd_ref: f64, rate_s_per_day: f64) -> TaiUtcEntry {
    TaiUtcEntry {
        mjd_start,
        offset_s,
        mjd_ref,
        rate_s_per_day,
    }
}

const fn step(mjd_start: i64, offset_s: f64) -> TaiUtcEntry {
    drift(mjd_start, offset_s, 0.0, 0.0)
}

/// TAI - UTC, transcribed from the USNO `tai-utc.dat` (maybe.usno.navy.mil/ser7/tai-utc.dat,
/// identical to IERS Bulletin C's history; the same table as ERFA's `dat.c`). MJD = JD -
/// 2400000.5 of the 0h UTC at which each entry starts.
const TAI_UTC: [TaiUtcEntry; 42] = [
    drift(37_300, 1.422_818_0, 37_300.0, 0.001_296), // 1961 JAN  1
    drift(37_512, 1.372_818_0, 37_300.0, 0.001_296), // 1961 AUG  1
    drift(37_665, 1.845_858_0, 37_665.0, 0.001_123_2), // 1962 JAN  1
    drift(38_334, 1.945_858_0, 37_665.0, 0.001_123_2), // 1963 NOV  1
    drift(38_395, 3.240_130_0, 38_761.0, 0.001_296), // 1964 JAN  1
    drift(38_486, 3.340_130_0, 38_761.0, 0.001_296), // 1964 APR  1
    drift(38_639, 3.440_130_0, 38_761.0, 0.001_296), // 1964 SEP  1
    drift(38_761, 3.540_130_0, 38_761.0, 0.001_296), // 1965 JAN  1
    drift(38_820, 3.640_130_0, 38_761.0, 0.001_296), // 1965 MAR  1
    drift(38_942, 3.740_130_0, 38_761.0, 0.001_296), // 1965 JUL  1
    drift(39_004, 3.840_130_0, 38_761.0, 0.001_296), // 1965 SEP  1
    drift(39_126, 4.313_170_0, 39_126.0, 0.002_592), // 1966 JAN  1
    drift(39_887, 4.213_170_0, 39_126.0, 0.002_592), // 1968 FEB  1
    step(41_317, 10.0),                              // 1972 JAN  1
    step(41_499, 11.0),                              // 1972 JUL  1
    step(41_683, 12.0),                              // 1973 JAN  1
    step(42_048, 13.0),                              // 1974 JAN  1
    step(42_413, 14.0),                              // 1975 JAN  1
    step(42_778, 15.0),                              // 1976 JAN  1
    step(43_144, 16.0),                              // 1977 JAN  1
    step(43_509, 17.0),                              // 1978 JAN  1
    step(43_874, 18.0),                              // 1979 JAN  1
    step(44_239, 19.0),                              // 1980 JAN  1
    step(44_786, 20.0),                              // 1981 JUL  1
    step(45_151, 21.0),                              // 1982 JUL  1
    step(45_516, 22.0),                              // 1983 JUL  1
    step(46_247, 23.0),                              // 1985 JUL  1
    step(47_161, 24.0),                              // 1988 JAN  1
    step(47_892, 25.0),                              // 1990 JAN  1
    step(48_257, 26.0),                              // 1991 JAN  1
    step(48_804, 27.0),                              // 1992 JUL  1
    step(49_169, 28.0),                              // 1993 JUL  1
    step(49_534, 29.0),                              // 1994 JUL  1
    step(50_083, 30.0),                              // 1996 JAN  1
    step(50_630, 31.0),                              // 1997 JUL  1
    step(51_179, 32.0),                              // 1999 JAN  1
    step(53_736, 33.0),                              // 2006 JAN  1
    step(54_832, 34.0),                              // 2009 JAN  1
    step(56_109, 35.0),                              // 2012 JUL  1
    step(57_204, 36.0),                              // 2015 JUL  1
    step(57_754, 37.0),                              // 2017 JAN  1
    step(i64::MAX, 37.0),                            // sentinel, never selected
];

/// MJD (days, may be fractional) of a Unix-nanosecond UTC instant, split into whole day
/// and fraction.
const fn mjd_split(unix_ns: i64) -> (i64, i64) {
    // MJD of 1970-01-01 is 40587.
    let days = unix_ns.div_euclid(NS_PER_DAY);
    let rem_ns = unix_ns.rem_euclid(NS_PER_DAY);
    (days + 40_587, rem_ns)
}

/// TAI - UTC in seconds at a UTC instant given as Unix nanoseconds.
fn tai_minus_utc_s(unix_ns: i64) -> f64 {
    let (mjd_day, rem_ns) = mjd_split(unix_ns);
    // Last entry whose start is <= the day (the first one before 1961).
    let mut idx = 0;
    for (i, e) in TAI_UTC.iter().enumerate() {
        if e.mjd_start <= mjd_day {
            idx = i;
        } else {
            break;
        }
    }
    let e = &TAI_UTC[idx];
    if e.rate_s_per_day == 0.0 {
        e.offset_s
    } else {
        let mjd = mjd_day as f64 + rem_ns as f64 / NS_PER_DAY as f64;
        e.offset_s + (mjd - e.mjd_ref) * e.rate_s_per_day
    }
}

/// Parse `n` ASCII digits at the start of `s`.
fn digits(s: &[u8], n: usize) -> Option<i64> {
    if s.len() < n {
        return None;
    }
    let mut v: i64 = 0;
    for &c in &s[..n] {
        if !c.is_ascii_digit() {
            return None;
        }
        v = v * 10 + i64::from(c - b'0');
    }
    Some(v)
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

    /// From seconds since the Unix epoch (rounded to the nearest nanosecond, saturating).
    pub fn from_unix_s(unix_s: f64) -> Self {
        // `as` saturates on overflow and maps NaN to 0.
        UtcTime {
            unix_ns: (unix_s * NS_PER_S as f64).round() as i64,
        }
    }

    /// Seconds since the Unix epoch.
    pub fn unix_s(&self) -> f64 {
        let s = self.unix_ns.div_euclid(NS_PER_S);
        let ns = self.unix_ns.rem_euclid(NS_PER_S);
        s as f64 + ns as f64 * 1e-9
    }

    /// From a UTC calendar date and time (proleptic Gregorian); `None` if a field is out of
    /// range (seconds must be below 60: leap seconds are not representable).
    pub fn from_calendar(
        year: i64,
        month: u32,
        day: u32,
        hour: u32,
        minute: u32,
        second: u32,
        nanosecond: u32,
    ) -> Option<Self> {
        let (month, day) = (i64::from(month), i64::from(day));
        if !(1..=12).contains(&month)
            || day < 1
            || day > days_in_month(year, month)
            || hour > 23
            || minute > 59
            || second > 59
            || nanosecond >= 1_000_000_000
            || !(-200_000..=200_000).contains(&year)
        {
            return None;
        }
        let days = days_from_civil(year, month, day);
        let s =
            days * S_PER_DAY + i64::from(hour) * 3600 + i64::from(minute) * 60 + i64::from(second);
        s.checked_mul(NS_PER_S)
            .and_then(|ns| ns.checked_add(i64::from(nanosecond)))
            .map(UtcTime::from_unix_ns)
    }

    /// The UTC calendar date and time: (year, month, day, hour, minute, second, nanosecond).
    pub fn to_calendar(&self) -> (i64, u32, u32, u32, u32, u32, u32) {
        let days = self.unix_ns.div_euclid(NS_PER_DAY);
        let rem = self.unix_ns.rem_euclid(NS_PER_DAY);
        let (y, m, d) = civil_from_days(days);
        let s = rem / NS_PER_S;
        let ns = rem % NS_PER_S;
        // All casts below are of values bounded by construction (month <= 12, s < 86400).
        (
            y,
            m as u32,
            d as u32,
            (s / 3600) as u32,
            ((s / 60) % 60) as u32,
            (s % 60) as u32,
            ns as u32,
        )
    }

    /// Parse `YYYY-MM-DDTHH:MM:SS[.fraction][Z]` (a space may replace the `T`; the fraction
    /// has 1 to 9 digits, more are accepted and truncated to nanoseconds).
    pub fn from_iso8601(text: &str) -> Result<Self, TimeError> {
        let bad = || TimeError::BadIso8601(text.to_owned());
        let t = text.trim();
        let t = t.strip_suffix('Z').unwrap_or(t);
        let b = t.as_bytes();
        if b.len() < 19
            || b[4] != b'-'
            || b[7] != b'-'
            || !(b[10] == b'T' || b[10] == b' ')
            || b[13] != b':'
            || b[16] != b':'
        {
            return Err(bad());
        }
        let year = digits(b, 4).ok_or_else(bad)?;
        let month = digits(&b[5..], 2).ok_or_else(bad)?;
        let day = digits(&b[8..], 2).ok_or_else(bad)?;
        let hour = digits(&b[11..], 2).ok_or_else(bad)?;
        let minute = digits(&b[14..], 2).ok_or_else(bad)?;
        let second = digits(&b[17..], 2).ok_or_else(bad)?;
        let mut nanosecond: i64 = 0;
        let rest = &b[19..];
        if !rest.is_empty() {
            if rest[0] != b'.' || rest.len() < 2 {
                return Err(bad());
            }
            let frac = &rest[1..];
            if !frac.iter().all(u8::is_ascii_digit) {
                return Err(bad());
            }
            let mut scale = 100_000_000;
            for &c in frac.iter().take(9) {
                nanosecond += i64::from(c - b'0') * scale;
                scale /= 10;
            }
        }
        // Every field is at most 4 digits, so the casts cannot truncate.
        UtcTime::from_calendar(
            year,
            month as u32,
            day as u32,
            hour as u32,
            minute as u32,
            second as u32,
            nanosecond as u32,
        )
        .ok_or_else(|| TimeError::OutOfRange(text.to_owned()))
    }

    /// This instant plus `seconds` (rounded to the nearest nanosecond, saturating).
    pub fn plus_seconds(&self, seconds: f64) -> Self {
        let dns = (seconds * NS_PER_S as f64).round() as i64;
        UtcTime {
            unix_ns: self.unix_ns.saturating_add(dns),
        }
    }

    /// This instant plus `ns` nanoseconds (saturating).
    pub const fn plus_ns(&self, ns: i64) -> Self {
        UtcTime {
            unix_ns: self.unix_ns.saturating_add(ns),
        }
    }

    /// Seconds from `earlier` to `self` (positive if `self` is later).
    pub fn seconds_since(&self, earlier: UtcTime) -> f64 {
        let d = i128::from(self.unix_ns) - i128::from(earlier.unix_ns);
        let s = d.div_euclid(i128::from(NS_PER_S));
        let ns = d.rem_euclid(i128::from(NS_PER_S));
        s as f64 + ns as f64 * 1e-9
    }

    /// Two-part Julian date in UTC: `day` is the JD of the preceding 0h UTC, `frac` in `[0, 1)`.
    pub fn jd_utc(&self) -> JulianDate {
        let days = self.unix_ns.div_euclid(NS_PER_DAY);
        let rem = self.unix_ns.rem_euclid(NS_PER_DAY);
        JulianDate {
            day: JD_UNIX_EPOCH + days as f64,
            frac: rem as f64 / NS_PER_DAY as f64,
        }
    }

    /// Two-part Julian date in TT (Terrestrial Time): UTC + (TAI - UTC) + 32.184 s.
    pub fn jd_tt(&self) -> JulianDate {
        self.jd_utc().plus_seconds(self.tt_minus_utc_s())
    }

    /// Two-part Julian date in UT1, with UT1 - UTC from `eop` (UT1 = UTC when `eop` is
    /// `None` or does not cover this instant).
    pub fn jd_ut1(&self, eop: Option<&EopTable>) -> JulianDate {
        let dut1 = eop
            .and_then(|table| table.at(*self))
            .map_or(0.0, |e| e.ut1_minus_utc_s);
        self.jd_ut1_from_dut1(dut1)
    }

    /// Two-part Julian date in UT1 for a given UT1 - UTC in seconds.
    pub fn jd_ut1_from_dut1(&self, ut1_minus_utc_s: f64) -> JulianDate {
        self.jd_utc().plus_seconds(ut1_minus_utc_s)
    }

    /// TAI - UTC in seconds (leap seconds, from the embedded table).
    pub fn tai_minus_utc_s(&self) -> f64 {
        tai_minus_utc_s(self.unix_ns)
    }

    /// TT - UTC in seconds: the embedded TAI - UTC table plus 32.184 s.
    pub fn tt_minus_utc_s(&self) -> f64 {
        tai_minus_utc_s(self.unix_ns) + TT_MINUS_TAI_S
    }

    /// The UTC year plus the elapsed fraction of that year (the IGRF time argument:
    /// `Y + (t - Jan 1 Y) / (Jan 1 Y+1 - Jan 1 Y)`, in UTC days of 86 400 s).
    pub fn decimal_year(&self) -> f64 {
        let days = self.unix_ns.div_euclid(NS_PER_DAY);
        let (year, _, _) = civil_from_days(days);
        let start = days_from_civil(year, 1, 1);
        let len = days_from_civil(year + 1, 1, 1) - start;
        let elapsed_ns = i128::from(self.unix_ns) - i128::from(start) * i128::from(NS_PER_DAY);
        year as f64 + elapsed_ns as f64 / (len as f64 * NS_PER_DAY as f64)
    }
}

impl std::fmt::Display for UtcTime {
    /// ISO-8601 with microseconds and a `Z`: `2024-03-15T12:00:00.000000Z`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (y, mo, d, h, mi, s, ns) = self.to_calendar();
        write!(
            f,
            "{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}.{:06}Z",
            ns / 1000
        )
    }
}

/// Greenwich mean sidereal time, IAU-82 (Aoki et al. 1982; Vallado's `gstime`, ERFA's
/// `gmst82`), in radians in `[0, 2π)`, from a UT1 Julian date.
pub fn gmst82(jd_ut1: JulianDate) -> f64 {
    // Coefficients of IAU 1982 GMST-UT1 model (seconds), ERFA gmst82.c.
    const A: f64 = 24_110.548_41 - S_PER_DAY as f64 / 2.0;
    const B: f64 = 8_640_184.812_866;
    const C: f64 = 0.093_104;
    const D: f64 = -6.2e-6;
    // Seconds of time to radians.
    const S2R: f64 = 7.272_205_216_643_04e-5;
    // Order the two parts so the fraction of a day is taken from the smaller one.
    let (d1, d2) = if jd_ut1.day < jd_ut1.frac {
        (jd_ut1.day, jd_ut1.frac)
    } else {
        (jd_ut1.frac, jd_ut1.day)
    };
    let t = ((d1 - JD_J2000) + d2) / DAYS_PER_JULIAN_CENTURY;
    // Fractional part of JD(UT1), in seconds.
    let f = S_PER_DAY as f64 * (d1 % 1.0 + d2 % 1.0);
    let g = (S2R * ((A + (B + (C + D * t) * t) * t) + f)).rem_euclid(TAU);
    // rem_euclid can return TAU itself for tiny negative inputs.
    if g >= TAU { 0.0 } else { g }
}

/// Earth orientation parameters at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eop {
    /// UT1 - UTC, s.
    pub ut1_minus_utc_s: f64,
    /// Pole x coordinate, arcsec.
    pub xp_arcsec: f64,
    /// Pole y coordinate, arcsec.
    pub yp_arcsec: f64,
}

/// One tabulated day of an [`EopTable`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct EopRow {
    mjd: f64,
    /// UT1 - TAI, s: continuous across leap seconds, so it interpolates cleanly.
    ut1_minus_tai_s: f64,
    xp_arcsec: f64,
    yp_arcsec: f64,
}

/// Earth orientation parameters from an IERS `finals.all` / `finals2000A.all` (or `.data`,
/// `.daily`) text, linearly interpolated between tabulated days.
///
/// Columns read (1-based, fixed width, IERS `readme.finals2000A`): MJD 8-15, PM-x 19-27,
/// PM-y 38-46, UT1-UTC 59-68 (Bulletin A values, observed or predicted). Lines without a
/// UT1-UTC value (beyond the prediction) end the usable range. UT1 - UTC jumps by 1 s at a
/// leap second, so it is interpolated as UT1 - TAI.
#[derive(Debug, Clone, PartialEq)]
pub struct EopTable {
    rows: Vec<EopRow>,
}

/// Columns `from..=to` (1-based) of a line, trimmed; `None` if the line is too short or blank
/// there.
fn column(line: &str, from: usize, to: usize) -> Option<&str> {
    let s = line.get(from - 1..to)?.trim();
    if s.is_empty() { None } else { Some(s) }
}

impl EopTable {
    /// Parse an IERS finals-format text; blank lines are skipped, rows must be in increasing
    /// MJD order.
    pub fn parse_finals(text: &str) -> Result<Self, TimeError> {
        let mut rows: Vec<EopRow> = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let n = i + 1;
            if line.trim().is_empty() {
                continue;
            }
            if !line.is_ascii() {
                return Err(TimeError::BadEopLine {
                    line: n,
                    reason: "not ASCII",
                });
            }
            let mjd: f64 =
                column(line, 8, 15)
                    .and_then(|s| s.parse().ok())
                    .ok_or(TimeError::BadEopLine {
                        line: n,
                        reason: "no MJD in columns 8-15",
                    })?;
            let Some(dut1) = column(line, 59, 68) else {
                // Beyond the predictions: no UT1-UTC, no more usable rows.
                continue;
            };
            let dut1: f64 = dut1.parse().map_err(|_| TimeError::BadEopLine {
                line: n,
                reason: "bad UT1-UTC in columns 59-68",
            })?;
            let xp: f64 =
                column(line, 19, 27)
                    .and_then(|s| s.parse().ok())
                    .ok_or(TimeError::BadEopLine {
                        line: n,
                        reason: "bad PM-x in columns 19-27",
                    })?;
            let yp: f64 =
                column(line, 38, 46)
                    .and_then(|s| s.parse().ok())
                    .ok_or(TimeError::BadEopLine {
                        line: n,
                        reason: "bad PM-y in columns 38-46",
                    })?;
            if !(mjd.is_finite() && dut1.is_finite() && xp.is_finite() && yp.is_finite()) {
                return Err(TimeError::BadEopLine {
                    line: n,
                    reason: "non-finite value",
                });
            }
            if rows.last().is_some_and(|r| r.mjd >= mjd) {
                return Err(TimeError::BadEopLine {
                    line: n,
                    reason: "MJD not increasing",
                });
            }
            if !(-1.0e6..=1.0e6).contains(&mjd) {
                return Err(TimeError::BadEopLine {
                    line: n,
                    reason: "MJD out of range",
                });
            }
            let t = UtcTime::from_unix_ns(((mjd - 40_587.0) * NS_PER_DAY as f64).round() as i64);
            rows.push(EopRow {
                mjd,
                ut1_minus_tai_s: dut1 - t.tai_minus_utc_s(),
                xp_arcsec: xp,
                yp_arcsec: yp,
            });
        }
        if rows.is_empty() {
            return Err(TimeError::EmptyEop);
        }
        Ok(EopTable { rows })
    }

    /// First and last MJD (UTC) covered.
    pub fn mjd_range(&self) -> (f64, f64) {
        // `rows` is never empty by construction.
        let first = self.rows.first().map_or(f64::NAN, |r| r.mjd);
        let last = self.rows.last().map_or(f64::NAN, |r| r.mjd);
        (first, last)
    }

    /// The EOP at `t`, linearly interpolated; `None` outside the tabulated range.
    pub fn at(&self, t: UtcTime) -> Option<Eop> {
        let (mjd_day, rem_ns) = mjd_split(t.unix_ns);
        let mjd = mjd_day as f64 + rem_ns as f64 / NS_PER_DAY as f64;
        let (first, last) = self.mjd_range();
        if !(mjd >= first && mjd <= last) {
            return None;
        }
        // Index of the first row with mjd > t (at least 1 since rows[0].mjd <= mjd).
        let hi = self.rows.partition_point(|r| r.mjd <= mjd);
        let (a, b) = if hi >= self.rows.len() {
            let r = self.rows[self.rows.len() - 1];
            (r, r)
        } else {
            (self.rows[hi - 1], self.rows[hi])
        };
        let w = if b.mjd > a.mjd {
            (mjd - a.mjd) / (b.mjd - a.mjd)
        } else {
            0.0
        };
        let lerp = |x: f64, y: f64| x + (y - x) * w;
        Some(Eop {
            ut1_minus_utc_s: lerp(a.ut1_minus_tai_s, b.ut1_minus_tai_s) + t.tai_minus_utc_s(),
            xp_arcsec: lerp(a.xp_arcsec, b.xp_arcsec),
            yp_arcsec: lerp(a.yp_arcsec, b.yp_arcsec),
        })
    }
}

snap::fields!(UtcTime { unix_ns });

#[cfg(test)]
mod tests {
    use super::*;

    fn t(s: &str) -> UtcTime {
        UtcTime::from_iso8601(s).unwrap_or_default()
    }

    #[test]
    fn iso8601_round_trip_and_variants() {
        let a = t("2024-03-15T12:00:00.000000");
        assert_eq!(a.unix_ns(), 1_710_504_000 * NS_PER_S);
        assert_eq!(t("2024-03-15T12:00:00Z"), a);
        assert_eq!(t("2024-03-15 12:00:00.0Z"), a);
        assert_eq!(a.to_string(), "2024-03-15T12:00:00.000000Z");
        assert_eq!(
            t("1969-12-31T23:59:59.5").unix_ns(),
            -NS_PER_S / 2,
            "before the epoch"
        );
        assert!(UtcTime::from_iso8601("2024-02-30T00:00:00").is_err());
        assert!(UtcTime::from_iso8601("2016-12-31T23:59:60").is_err());
        assert!(UtcTime::from_iso8601("2024-03-15T12:00:00.").is_err());
        assert!(UtcTime::from_iso8601("2024-03-15").is_err());
        assert!(UtcTime::from_iso8601("2024-03-15T12:00:00+01:00").is_err());
        assert!(UtcTime::from_iso8601("२०२४-03-15T12:00:00").is_err());
    }

    #[test]
    fn jd_and_tt_at_j2000() {
        // J2000.0 is 2000-01-01T12:00:00 TT = 11:58:55.816 UTC (TAI-UTC = 32 s).
        let a = t("2000-01-01T11:58:55.816");
        assert_eq!(a.tt_minus_utc_s(), 64.184);
        let tt = a.jd_tt();
        assert!((tt.days_since_j2000()).abs() < 1e-12);
        assert_eq!(a.jd_utc().day, 2_451_544.5);
    }

    #[test]
    fn leap_seconds_step_at_midnight() {
        assert_eq!(t("2016-12-31T23:59:59.999").tai_minus_utc_s(), 36.0);
        assert_eq!(t("2017-01-01T00:00:00").tai_minus_utc_s(), 37.0);
        assert_eq!(t("2030-01-01T00:00:00").tai_minus_utc_s(), 37.0);
        assert_eq!(t("1972-01-01T00:00:00").tai_minus_utc_s(), 10.0);
        // 1968 FEB 1 drift formula at MJD 40000 (1968-05-24): 4.2131700 + 874 * 0.002592.
        let x = t("1968-05-24T00:00:00").tai_minus_utc_s();
        assert!((x - (4.213_17 + 874.0 * 0.002_592)).abs() < 1e-12);
        assert_eq!(
            t("1950-01-01T00:00:00").tai_minus_utc_s(),
            1.422_818 + (33_282.0 - 37_300.0) * 0.001_296
        );
    }

    #[test]
    fn decimal_year_matches_igrf_reference() {
        // igrf.csv: 2026-06-01T12:00:00 -> 2026.4150684931508.
        assert!((t("2026-06-01T12:00:00").decimal_year() - 2_026.415_068_493_150_8).abs() < 1e-12);
        assert_eq!(t("2024-01-01T00:00:00").decimal_year(), 2024.0);
        // Leap year: 2024-07-02T00:00 is day 183 of 366.
        assert!((t("2024-07-02T00:00:00").decimal_year() - (2024.0 + 183.0 / 366.0)).abs() < 1e-12);
    }

    #[test]
    fn gmst82_vallado_example() {
        // Vallado, Fundamentals of Astrodynamics, Example 3-5: 1992-08-20 12:14 UT1,
        // GMST = 152.578787886 deg (the book rounds JD(UT1) to one f64; the reference-data
        // test in tests/frames_ref.rs checks 1e-9 rad against ERFA).
        let jd = t("1992-08-20T12:14:00").jd_utc();
        let g = gmst82(jd).to_degrees();
        assert!((g - 152.578_787_886).abs() < 1e-7, "{g}");
    }

    #[test]
    fn eop_parse_and_interpolate() {
        // Two lines of finals2000A.all (2024-03-15 and 16).
        let text = "\
24 315 60384.00 I  0.037888 0.000024  0.303459 0.000029  I-0.0091563 0.0000050  0.3624 0.0036  I     0.265    0.300     0.034    0.218  0.038032  0.303440 -0.0091495   0.311     0.038
24 316 60385.00 I  0.039188 0.000025  0.303624 0.000029  I-0.0095276 0.0000068  0.3776 0.0038  I     0.265    0.300     0.034    0.218  0.039339  0.303589 -0.0095304   0.293     0.022
24 317 60386.00 P  0.040410 0.003578  0.303720 0.005108  P-0.0099050 0.0052000                 P     0.259    0.128     0.042    0.128
24 318 60387.00                                                                                                             
";
        let eop = EopTable::parse_finals(text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(eop.mjd_range(), (60_384.0, 60_386.0));
        let e = eop
            .at(t("2024-03-15T12:00:00"))
            .unwrap_or_else(|| panic!("in range"));
        assert!((e.ut1_minus_utc_s - (-0.009_156_3 - 0.009_527_6) / 2.0).abs() < 1e-12);
        assert!((e.xp_arcsec - (0.037_888 + 0.039_188) / 2.0).abs() < 1e-12);
        assert!(eop.at(t("2024-03-14T23:59:59")).is_none());
        assert!(eop.at(t("2024-03-17T00:00:01")).is_none());
        assert!(eop.at(t("2024-03-17T00:00:00")).is_some());
        let tt = t("2024-03-15T00:00:00");
        assert_eq!(tt.jd_ut1(None), tt.jd_utc());
        assert!(EopTable::parse_finals("").is_err());
        assert!(EopTable::parse_finals("garbage").is_err());
    }

    /// A finals line with MJD, PM-x, PM-y and UT1-UTC in their columns.
    fn finals_line(mjd: f64, xp: f64, yp: f64, dut1: f64) -> String {
        let mut l = vec![b' '; 78];
        let mut put = |from: usize, s: String| {
            l[from - 1..from - 1 + s.len()].copy_from_slice(s.as_bytes());
        };
        put(8, format!("{mjd:8.2}"));
        put(19, format!("{xp:9.6}"));
        put(38, format!("{yp:9.6}"));
        put(59, format!("{dut1:10.7}"));
        String::from_utf8(l).unwrap_or_default()
    }

    #[test]
    fn eop_interpolates_across_a_leap_second() {
        // 2016-12-31 UT1-UTC = -0.41 s, 2017-01-01 = +0.59 s: the leap second in between
        // makes UTC fall 1 s behind.
        let text = [
            finals_line(57_753.0, 0.1, 0.2, -0.41),
            finals_line(57_754.0, 0.1, 0.2, 0.59),
        ]
        .join("\n");
        let eop = EopTable::parse_finals(&text).unwrap_or_else(|e| panic!("{e}"));
        let e = eop
            .at(t("2016-12-31T12:00:00"))
            .unwrap_or_else(|| panic!("in range"));
        // UT1 - TAI is continuous (-36.41 s both days), so UT1 - UTC stays -0.41 s until
        // the leap second.
        assert!(
            (e.ut1_minus_utc_s + 0.41).abs() < 1e-9,
            "{}",
            e.ut1_minus_utc_s
        );
        let e = eop
            .at(t("2017-01-01T00:00:00"))
            .unwrap_or_else(|| panic!("in range"));
        assert!(
            (e.ut1_minus_utc_s - 0.59).abs() < 1e-9,
            "{}",
            e.ut1_minus_utc_s
        );
    }
}
