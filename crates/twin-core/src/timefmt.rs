//! UTC timestamps in scenario files, recordings and reports, through `orbit::time`
//! (one calendar implementation in the project).

use orbit::time::UtcTime;

/// Parse `2026-03-20T12:00:00Z` (fraction and `Z` optional) into Unix nanoseconds; `None`
/// for anything that is not a real UTC time.
pub fn parse_utc(s: &str) -> Option<i64> {
    UtcTime::from_iso8601(s).ok().map(|t| t.unix_ns())
}

/// Format Unix nanoseconds as `2026-03-20T12:00:00.000000Z`.
pub fn format_utc(unix_ns: i64) -> String {
    UtcTime::from_unix_ns(unix_ns).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_known_values() {
        assert_eq!(
            parse_utc("2020-01-01T00:00:00Z"),
            Some(1_577_836_800_000_000_000)
        );
        assert_eq!(
            parse_utc("2020-01-01T00:00:00.5"),
            Some(1_577_836_800_500_000_000)
        );
        assert_eq!(
            format_utc(1_577_836_800_500_000_000),
            "2020-01-01T00:00:00.500000Z"
        );
        assert_eq!(
            parse_utc("2024-02-29T23:59:59Z").map(format_utc),
            Some("2024-02-29T23:59:59.000000Z".into())
        );
    }

    #[test]
    fn rejects_bad_dates() {
        for bad in [
            "2023-02-29T00:00:00Z",
            "2026-13-01T00:00:00Z",
            "2026-01-01",
            "x",
            "2026-01-01T25:00:00Z",
            "2026-01-01T00:00:00.x",
        ] {
            assert_eq!(parse_utc(bad), None, "{bad}");
        }
    }
}
