//! Durations on the command line and in scenarios: `90` and `90s` (seconds), `500ms`, `10m`,
//! `2h`, `1.5h`, and sums of terms: `1h 30m`, `6h100s`.

use std::time::Duration;

/// Why a text is not a duration; each names the text (trimmed).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DurationError {
    /// Not a number and a unit, or nothing at all.
    #[error("`{text}` is not a duration (try 90, 90s, 10m, 2h, 1h 30m)")]
    NotADuration {
        /// The text.
        text: String,
    },
    /// A bare number is seconds only when it is the whole duration.
    #[error("`{text}`: a number without a unit among several terms")]
    NoUnit {
        /// The text.
        text: String,
    },
    /// A unit other than ms, s, m (min), h, d.
    #[error("unknown unit `{unit}` in `{text}` (use ms, s, m, h or d)")]
    UnknownUnit {
        /// The unit as written.
        unit: String,
        /// The text.
        text: String,
    },
    /// A term beyond 10^9 s, or a sum beyond 10^9 s, or not finite.
    #[error("`{text}` is out of range")]
    OutOfRange {
        /// The text.
        text: String,
    },
}

/// Parse a duration; a bare number is seconds; terms add up (`1h 30m`, `6h100s`).
pub fn parse_duration(s: &str) -> Result<Duration, DurationError> {
    let s = s.trim();
    let hint = || DurationError::NotADuration { text: s.to_owned() };
    let mut rest = s;
    let mut total_ns: u128 = 0;
    let mut terms = 0;
    while !rest.is_empty() {
        let split = rest
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(rest.len());
        let (num, after) = rest.split_at(split);
        let value: f64 = num.parse().map_err(|_| hint())?;
        let after = after.trim_start();
        let unit_len = after
            .find(|c: char| !c.is_alphabetic())
            .unwrap_or(after.len());
        let (unit, after) = after.split_at(unit_len);
        let scale = match unit {
            "" if terms == 0 && after.trim().is_empty() => 1.0,
            "s" => 1.0,
            "ms" => 1e-3,
            "m" | "min" => 60.0,
            "h" => 3600.0,
            "d" => 86400.0,
            "" => {
                return Err(DurationError::NoUnit { text: s.to_owned() });
            }
            u => {
                return Err(DurationError::UnknownUnit {
                    unit: u.to_owned(),
                    text: s.to_owned(),
                });
            }
        };
        let secs = value * scale;
        if !secs.is_finite() || !(0.0..=1e9).contains(&secs) {
            return Err(DurationError::OutOfRange { text: s.to_owned() });
        }
        total_ns += (secs * 1e9).round() as u128;
        terms += 1;
        rest = after.trim_start();
    }
    if terms == 0 {
        return Err(hint());
    }
    if total_ns > 1_000_000_000 * 1_000_000_000 {
        return Err(DurationError::OutOfRange { text: s.to_owned() });
    }
    Ok(Duration::from_nanos(total_ns as u64))
}

/// Format a duration the way it is written in scenarios (`90s`, `10m`, `3h`, `1.5s`).
pub fn format_duration(d: Duration) -> String {
    let s = d.as_secs_f64();
    if d.subsec_nanos() != 0 {
        format!("{s}s")
    } else if s >= 3600.0 && s % 3600.0 == 0.0 {
        format!("{}h", s / 3600.0)
    } else if s >= 60.0 && s % 60.0 == 0.0 {
        format!("{}m", s / 60.0)
    } else {
        format!("{s}s")
    }
}

/// A simulated instant as people read it: in the scenarios' units when it is whole (`3h`,
/// `10m`, `90s`), else seconds with the digits that matter (`30.000141s`).
pub fn format_instant(t: csp::SimTime) -> String {
    let d = Duration::from_nanos(t.as_ns());
    if d.subsec_nanos() == 0 {
        return format_duration(d);
    }
    let s = format!("{}.{:09}", d.as_secs(), d.subsec_nanos());
    format!("{}s", s.trim_end_matches('0'))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn an_instant_reads_in_the_scenarios_units() {
        let at = |ns| format_instant(csp::SimTime::from_ns(ns));
        assert_eq!(at(10_800_000_000_000), "3h");
        assert_eq!(at(30_000_000_000), "30s");
        assert_eq!(at(0), "0s");
        assert_eq!(at(30_000_141_000), "30.000141s");
        assert_eq!(at(1), "0.000000001s");
    }

    #[test]
    fn accepts_the_documented_forms() {
        assert_eq!(parse_duration("90"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("10m"), Ok(Duration::from_secs(600)));
        assert_eq!(parse_duration("2h"), Ok(Duration::from_secs(7200)));
        assert_eq!(parse_duration("1.5h"), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_duration("250ms"), Ok(Duration::from_millis(250)));
        assert_eq!(parse_duration("1h 30m"), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_duration("6h100s"), Ok(Duration::from_secs(21_700)));
        assert_eq!(
            parse_duration(" 1d 2h 3m 4s 5ms "),
            Ok(Duration::from_millis(93_784_005))
        );
    }

    #[test]
    fn rejects_nonsense_with_a_message() {
        for bad in [
            "", "abc", "10x", "-5", "1e400", "s", "1h 30", "5 5", "1h x", "1..5s",
        ] {
            assert!(parse_duration(bad).is_err(), "{bad}");
        }
        let e = parse_duration(" 10x ").unwrap_err();
        assert_eq!(
            e,
            DurationError::UnknownUnit {
                unit: "x".into(),
                text: "10x".into()
            }
        );
        assert_eq!(
            e.to_string(),
            "unknown unit `x` in `10x` (use ms, s, m, h or d)"
        );
        assert_eq!(
            parse_duration("1h 30").unwrap_err().to_string(),
            "`1h 30`: a number without a unit among several terms"
        );
        assert_eq!(
            parse_duration("abc").unwrap_err().to_string(),
            "`abc` is not a duration (try 90, 90s, 10m, 2h, 1h 30m)"
        );
        assert_eq!(
            parse_duration("1..5s"),
            Err(DurationError::NotADuration {
                text: "1..5s".into()
            })
        );
        assert_eq!(
            parse_duration("2000000000s").unwrap_err().to_string(),
            "`2000000000s` is out of range"
        );
    }
}
