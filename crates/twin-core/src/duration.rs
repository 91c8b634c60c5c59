//! Durations on the command line and in scenarios: `90` and `90s` (seconds), `500ms`, `10m`,
//! `2h`, `1.5h`, and sums of terms: `1h 30m`, `6h100s`.

use std::time::Duration;

/// Parse a duration; a bare number is seconds; terms add up (`1h 30m`, `6h100s`).
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    let hint = || format!("`{s}` is not a duration (try 90, 90s, 10m, 2h, 1h 30m)");
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
                return Err(format!(
                    "`{s}`: a number without a unit among several terms"
                ));
            }
            u => {
                return Err(format!(
                    "unknown unit `{u}` in `{s}` (use ms, s, m, h or d)"
                ));
            }
        };
        let secs = value * scale;
        if !secs.is_finite() || !(0.0..=1e9).contains(&secs) {
            return Err(format!("`{s}` is out of range"));
        }
        total_ns += (secs * 1e9).round() as u128;
        terms += 1;
        rest = after.trim_start();
    }
    if terms == 0 {
        return Err(hint());
    }
    if total_ns > 1_000_000_000 * 1_000_000_000 {
        return Err(format!("`{s}` is out of range"));
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

#[cfg(test)]
mod tests {
    use super::*;

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
    }
}
