//! Two-line element sets (TLE): parsing and checksums.
//!
//! # Format
//! The fixed-column NORAD format as documented by CelesTrak ("FAQs: Two-Line Element Set
//! Format") and read by Vallado's `twoline2rv` (Vallado et al., "Revisiting Spacetrack Report
//! #3", AIAA 2006-6753). Columns are 1-based and inclusive, as in those documents:
//!
//! | line | columns | field                                              |
//! |------|---------|----------------------------------------------------|
//! | 1    | 1       | line number `1`                                    |
//! | 1    | 3-7     | satellite number (Alpha-5 allowed: `A0001` = 100001)|
//! | 1    | 8       | classification                                     |
//! | 1    | 10-17   | international designator                           |
//! | 1    | 19-20   | epoch year (57-99 -> 19xx, 00-56 -> 20xx)          |
//! | 1    | 21-32   | epoch day of year with fraction (1.0 = Jan 1 0h)   |
//! | 1    | 34-43   | ṅ/2, rev/day²                                      |
//! | 1    | 45-52   | n̈/6, rev/day³, implied decimal point (` 12345-6`)  |
//! | 1    | 54-61   | B*, 1/Earth radii, implied decimal point           |
//! | 1    | 63      | ephemeris type                                     |
//! | 1    | 65-68   | element set number                                 |
//! | 2    | 1       | line number `2`                                    |
//! | 2    | 3-7     | satellite number                                   |
//! | 2    | 9-16    | inclination, deg                                   |
//! | 2    | 18-25   | right ascension of the ascending node, deg         |
//! | 2    | 27-33   | eccentricity, implied leading decimal point        |
//! | 2    | 35-42   | argument of perigee, deg                           |
//! | 2    | 44-51   | mean anomaly, deg                                  |
//! | 2    | 53-63   | mean motion, rev/day                               |
//! | 2    | 64-68   | revolution number at epoch                         |
//! | 1, 2 | 69      | checksum: sum of the digits of columns 1-68, `-` counts 1, mod 10 |
//!
//! # Modes
//! - [`ChecksumMode::Strict`] rejects a wrong or missing checksum, a line that is not exactly
//!   69 characters (after trailing whitespace is removed), a non-blank separator column and
//!   different satellite numbers on the two lines.
//! - [`ChecksumMode::Lenient`] accepts all of those (the checksum column may be missing or
//!   wrong; separators are not checked), as Vallado's `twoline2rv` does.
//!
//! Both modes accept what Vallado's reader accepts in the verification set: a blank
//! international designator, ephemeris type, element set number or revolution number (read
//! as 0) and blank digits of the implied-decimal fields (read as 0).
//!
//! # Invariants
//! No input makes the parser panic (a proptest feeds it arbitrary strings); every error names
//! the line (1 or 2) and the 1-based column or column range.

use crate::time::{JulianDate, UtcTime};

/// How strictly to check a TLE.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChecksumMode {
    /// Reject bad checksums, wrong line lengths, non-blank separators, satnum mismatch.
    #[default]
    Strict,
    /// Accept bad or missing checksums and loose layout (Vallado's `twoline2rv` behaviour).
    Lenient,
}

/// Why a TLE could not be read. Lines are 1 or 2; columns are 1-based as in the format.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TleError {
    /// A line has the wrong length.
    #[error("line {line}: {len} characters, expected {expected}")]
    Length {
        /// Line number (1 or 2).
        line: u8,
        /// Length found (after trailing whitespace is removed).
        len: usize,
        /// Length required.
        expected: &'static str,
    },
    /// A character is not printable ASCII.
    #[error("line {line}, column {column}: not printable ASCII")]
    NotAscii {
        /// Line number (1 or 2).
        line: u8,
        /// 1-based column.
        column: usize,
    },
    /// Column 1 is not the line number.
    #[error("line {line}, column 1: expected '{line}', found {found:?}")]
    LineNumber {
        /// Line number (1 or 2).
        line: u8,
        /// Character found.
        found: char,
    },
    /// The checksum in column 69 does not match.
    #[error("line {line}, column 69: checksum {found:?}, computed '{computed}'")]
    Checksum {
        /// Line number (1 or 2).
        line: u8,
        /// Character found in column 69 (`' '` if missing).
        found: char,
        /// Checksum computed over columns 1-68.
        computed: u8,
    },
    /// A column that must be blank is not.
    #[error("line {line}, column {column}: expected a blank separator, found {found:?}")]
    Separator {
        /// Line number (1 or 2).
        line: u8,
        /// 1-based column.
        column: usize,
        /// Character found.
        found: char,
    },
    /// A field does not hold a valid value.
    #[error("line {line}, columns {first}-{last} ({field}): {reason}: {text:?}")]
    Field {
        /// Line number (1 or 2).
        line: u8,
        /// First 1-based column of the field.
        first: usize,
        /// Last 1-based column of the field.
        last: usize,
        /// Field name.
        field: &'static str,
        /// What is wrong.
        reason: &'static str,
        /// The field's text.
        text: String,
    },
    /// Line 1 and line 2 name different satellites (strict mode).
    #[error("line 2, columns 3-7: satellite number {line2} differs from line 1's {line1}")]
    SatnumMismatch {
        /// Satellite number on line 1.
        line1: u32,
        /// Satellite number on line 2.
        line2: u32,
    },
}

/// The elements of one two-line element set, in the TLE's own units.
#[derive(Debug, Clone, PartialEq)]
pub struct Tle {
    /// Catalogue number (Alpha-5 decoded: `A0000` = 100000).
    pub satnum: u32,
    /// Classification character (`U`, `C`, `S`; blank read as `U`).
    pub classification: char,
    /// International designator (columns 10-17, trimmed; may be empty).
    pub intl_designator: String,
    /// Epoch, UTC.
    pub epoch: UtcTime,
    /// Epoch year, four digits.
    pub epoch_year: i32,
    /// Epoch day of year with fraction (1.0 = January 1, 0h UTC).
    pub epoch_day: f64,
    /// First time derivative of the mean motion divided by 2, rev/day².
    pub mean_motion_dot_rev_day2: f64,
    /// Second time derivative of the mean motion divided by 6, rev/day³.
    pub mean_motion_ddot_rev_day3: f64,
    /// SGP4 drag term B*, 1/Earth radii.
    pub bstar_per_earth_radii: f64,
    /// Ephemeris type (0 for SGP4 element sets).
    pub ephemeris_type: u8,
    /// Element set number.
    pub element_set_number: u16,
    /// Inclination, deg.
    pub inclination_deg: f64,
    /// Right ascension of the ascending node (TEME), deg.
    pub raan_deg: f64,
    /// Eccentricity.
    pub eccentricity: f64,
    /// Argument of perigee, deg.
    pub arg_perigee_deg: f64,
    /// Mean anomaly, deg.
    pub mean_anomaly_deg: f64,
    /// Mean motion (Kozai), rev/day.
    pub mean_motion_rev_day: f64,
    /// Revolution number at epoch.
    pub rev_number: u32,
}

/// The TLE checksum of a line: the sum of its digits over columns 1-68, each `-` counting 1,
/// modulo 10.
pub fn checksum(line: &str) -> u8 {
    let sum: u32 = line
        .bytes()
        .take(68)
        .map(|c| match c {
            b'0'..=b'9' => u32::from(c - b'0'),
            b'-' => 1,
            _ => 0,
        })
        .sum();
    // sum % 10 < 10 fits u8.
    (sum % 10) as u8
}

/// One line being read: its bytes padded with blanks to 69 columns.
struct Line<'a> {
    number: u8,
    bytes: [u8; 69],
    raw: &'a str,
}

impl<'a> Line<'a> {
    /// Check length, characters and line number; pad to 69 columns.
    fn new(raw: &'a str, number: u8, mode: ChecksumMode) -> Result<Self, TleError> {
        let raw = raw.trim_end();
        for (i, c) in raw.char_indices() {
            if !(c == ' ' || c.is_ascii_graphic()) {
                return Err(TleError::NotAscii {
                    line: number,
                    column: raw[..i].chars().count() + 1,
                });
            }
        }
        let len = raw.len();
        match mode {
            ChecksumMode::Strict if len != 69 => {
                return Err(TleError::Length {
                    line: number,
                    len,
                    expected: "exactly 69",
                });
            }
            ChecksumMode::Lenient if !(64..=69).contains(&len) => {
                return Err(TleError::Length {
                    line: number,
                    len,
                    expected: "64 to 69",
                });
            }
            _ => {}
        }
        let mut bytes = [b' '; 69];
        bytes[..len].copy_from_slice(raw.as_bytes());
        let first = char::from(bytes[0]);
        if first != char::from(b'0' + number) {
            return Err(TleError::LineNumber {
                line: number,
                found: first,
            });
        }
        Ok(Line { number, bytes, raw })
    }

    /// Columns `first..=last` (1-based) as text.
    fn text(&self, first: usize, last: usize) -> &str {
        // Only printable ASCII was admitted, so any range is valid UTF-8.
        std::str::from_utf8(&self.bytes[first - 1..last]).unwrap_or("")
    }

    fn field_error(
        &self,
        first: usize,
        last: usize,
        field: &'static str,
        reason: &'static str,
    ) -> TleError {
        TleError::Field {
            line: self.number,
            first,
            last,
            field,
            reason,
            text: self.text(first, last).to_owned(),
        }
    }

    /// Check column 69 against the computed checksum.
    fn check_checksum(&self) -> Result<(), TleError> {
        let computed = checksum(self.raw);
        let found = char::from(self.bytes[68]);
        if found.to_digit(10) == Some(u32::from(computed)) {
            Ok(())
        } else {
            Err(TleError::Checksum {
                line: self.number,
                found,
                computed,
            })
        }
    }

    /// Check that the given columns are blank.
    fn check_blank(&self, columns: &[usize]) -> Result<(), TleError> {
        for &c in columns {
            if self.bytes[c - 1] != b' ' {
                return Err(TleError::Separator {
                    line: self.number,
                    column: c,
                    found: char::from(self.bytes[c - 1]),
                });
            }
        }
        Ok(())
    }

    /// A decimal number in columns `first..=last` (blank is an error).
    fn float(&self, first: usize, last: usize, field: &'static str) -> Result<f64, TleError> {
        let t = self.text(first, last).trim();
        if t.is_empty() {
            return Err(self.field_error(first, last, field, "blank"));
        }
        // Only sign, digits and one point: f64::from_str would also take "inf" or "1e5".
        if !t
            .bytes()
            .enumerate()
            .all(|(i, c)| c.is_ascii_digit() || c == b'.' || (i == 0 && (c == b'-' || c == b'+')))
            || t.bytes().filter(|&c| c == b'.').count() > 1
        {
            return Err(self.field_error(first, last, field, "not a decimal number"));
        }
        t.parse::<f64>()
            .map_err(|_| self.field_error(first, last, field, "not a decimal number"))
    }

    /// An unsigned integer in columns `first..=last`; blank reads as 0.
    fn uint(&self, first: usize, last: usize, field: &'static str) -> Result<u32, TleError> {
        let t = self.text(first, last).trim();
        if t.is_empty() {
            return Ok(0);
        }
        if !t.bytes().all(|c| c.is_ascii_digit()) {
            return Err(self.field_error(first, last, field, "not an unsigned integer"));
        }
        t.parse::<u32>()
            .map_err(|_| self.field_error(first, last, field, "not an unsigned integer"))
    }

    /// The implied-decimal exponential field (` 12345-6` = 0.12345e-6) in 8 columns starting
    /// at `first`: sign, 5 mantissa digits (blanks read as 0), exponent sign, exponent digit.
    fn implied_exp(&self, first: usize, field: &'static str) -> Result<f64, TleError> {
        let last = first + 7;
        let b = &self.bytes[first - 1..last];
        let bad = |reason| self.field_error(first, last, field, reason);
        let sign = match b[0] {
            b' ' | b'+' => 1.0,
            b'-' => -1.0,
            _ => return Err(bad("bad mantissa sign")),
        };
        let mut mantissa = [b'0'; 7];
        mantissa[1] = b'.';
        for (k, &c) in b[1..6].iter().enumerate() {
            mantissa[2 + k] = match c {
                b' ' => b'0',
                b'0'..=b'9' => c,
                _ => return Err(bad("bad mantissa digit")),
            };
        }
        let exp_sign = match b[6] {
            b'+' | b' ' => 1,
            b'-' => -1,
            _ => return Err(bad("bad exponent sign")),
        };
        let exp_digit = match b[7] {
            b' ' => 0,
            b'0'..=b'9' => i32::from(b[7] - b'0'),
            _ => return Err(bad("bad exponent digit")),
        };
        // Parsed from "0.ddddd" then scaled, as Vallado's twoline2rv does.
        let m: f64 = std::str::from_utf8(&mantissa)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| bad("bad mantissa"))?;
        Ok(sign * m * 10f64.powi(exp_sign * exp_digit))
    }

    /// The satellite number in columns 3-7 (Alpha-5 allowed).
    fn satnum(&self) -> Result<u32, TleError> {
        let t = self.text(3, 7);
        let bad = || self.field_error(3, 7, "satellite number", "not a catalogue number");
        let first = self.bytes[2];
        if first.is_ascii_uppercase() {
            // Alpha-5: A=10 .. Z=33, skipping I and O.
            let hi = match first {
                b'A'..=b'H' => first - b'A' + 10,
                b'J'..=b'N' => first - b'J' + 18,
                b'P'..=b'Z' => first - b'P' + 23,
                _ => return Err(bad()),
            };
            let rest = &t[1..];
            if !rest.bytes().all(|c| c.is_ascii_digit()) {
                return Err(bad());
            }
            let lo: u32 = rest.parse().map_err(|_| bad())?;
            Ok(u32::from(hi) * 10_000 + lo)
        } else {
            let t = t.trim();
            if t.is_empty() || !t.bytes().all(|c| c.is_ascii_digit()) {
                return Err(bad());
            }
            t.parse().map_err(|_| bad())
        }
    }
}

/// The UTC instant of a TLE epoch (two-digit year, day of year with fraction as text), exact
/// to the nanosecond.
fn epoch_from_text(year: i32, day_text: &str) -> Option<UtcTime> {
    let (int, frac) = day_text.split_once('.').unwrap_or((day_text, ""));
    let day: i64 = int.trim().parse().ok()?;
    if !(1..=367).contains(&day) || frac.len() > 12 || !frac.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    // Fraction of a day in ns, rounded: frac_digits * 86_400e9 / 10^len (fits i128).
    let digits: i128 = if frac.is_empty() {
        0
    } else {
        frac.parse().ok()?
    };
    let scale = 10i128.pow(u32::try_from(frac.len()).ok()?);
    let ns_day: i128 = 86_400 * 1_000_000_000;
    let frac_ns = (digits * ns_day + scale / 2) / scale;
    let jan1 = UtcTime::from_calendar(i64::from(year), 1, 1, 0, 0, 0, 0)?;
    let ns = i128::from(jan1.unix_ns()) + i128::from(day - 1) * ns_day + frac_ns;
    i64::try_from(ns).ok().map(UtcTime::from_unix_ns)
}

impl Tle {
    /// Parse the two lines of a TLE (a preceding title line is the caller's business).
    pub fn parse(line1: &str, line2: &str, mode: ChecksumMode) -> Result<Tle, TleError> {
        let l1 = Line::new(line1, 1, mode)?;
        let l2 = Line::new(line2, 2, mode)?;
        if mode == ChecksumMode::Strict {
            l1.check_checksum()?;
            l2.check_checksum()?;
            l1.check_blank(&[2, 9, 18, 33, 44, 53, 62, 64])?;
            l2.check_blank(&[2, 8, 17, 26, 34, 43, 52])?;
        }

        let satnum = l1.satnum()?;
        let classification = match l1.bytes[7] {
            b' ' => 'U',
            c => char::from(c),
        };
        let intl_designator = l1.text(10, 17).trim().to_owned();
        let yy = l1.uint(19, 20, "epoch year")?;
        if l1.text(19, 20).trim().len() != 2 {
            return Err(l1.field_error(19, 20, "epoch year", "not two digits"));
        }
        // Two-digit year, 1957-2056 (the NORAD convention).
        let epoch_year = if yy < 57 { 2000 + yy } else { 1900 + yy } as i32;
        let epoch_day = l1.float(21, 32, "epoch day")?;
        let epoch = epoch_from_text(epoch_year, l1.text(21, 32).trim())
            .filter(|_| (1.0..367.0).contains(&epoch_day))
            .ok_or_else(|| l1.field_error(21, 32, "epoch day", "not a day of year"))?;
        let mean_motion_dot_rev_day2 = l1.float(34, 43, "first derivative of mean motion")?;
        let mean_motion_ddot_rev_day3 = l1.implied_exp(45, "second derivative of mean motion")?;
        let bstar_per_earth_radii = l1.implied_exp(54, "B*")?;
        let ephemeris_type = u8::try_from(l1.uint(63, 63, "ephemeris type")?).unwrap_or(0);
        let element_set_number =
            u16::try_from(l1.uint(65, 68, "element set number")?).unwrap_or(u16::MAX);

        let satnum2 = l2.satnum()?;
        if mode == ChecksumMode::Strict && satnum2 != satnum {
            return Err(TleError::SatnumMismatch {
                line1: satnum,
                line2: satnum2,
            });
        }
        let inclination_deg = l2.float(9, 16, "inclination")?;
        if !(0.0..=180.0).contains(&inclination_deg) {
            return Err(l2.field_error(9, 16, "inclination", "outside 0-180 deg"));
        }
        let raan_deg = l2.float(18, 25, "right ascension of the ascending node")?;
        let ecc_text = l2.text(27, 33);
        if !ecc_text.bytes().all(|c| c.is_ascii_digit() || c == b' ') || ecc_text.trim().is_empty()
        {
            return Err(l2.field_error(27, 33, "eccentricity", "not 7 digits"));
        }
        let ecc_digits: String = ecc_text
            .bytes()
            .map(|c| if c == b' ' { '0' } else { char::from(c) })
            .collect();
        let eccentricity: f64 = format!("0.{ecc_digits}")
            .parse()
            .map_err(|_| l2.field_error(27, 33, "eccentricity", "not 7 digits"))?;
        let arg_perigee_deg = l2.float(35, 42, "argument of perigee")?;
        let mean_anomaly_deg = l2.float(44, 51, "mean anomaly")?;
        let mean_motion_rev_day = l2.float(53, 63, "mean motion")?;
        let rev_number = l2.uint(64, 68, "revolution number")?;

        Ok(Tle {
            satnum,
            classification,
            intl_designator,
            epoch,
            epoch_year,
            epoch_day,
            mean_motion_dot_rev_day2,
            mean_motion_ddot_rev_day3,
            bstar_per_earth_radii,
            ephemeris_type,
            element_set_number,
            inclination_deg,
            raan_deg,
            eccentricity,
            arg_perigee_deg,
            mean_anomaly_deg,
            mean_motion_rev_day,
            rev_number,
        })
    }

    /// The epoch as a two-part UTC Julian date.
    pub fn epoch_jd_utc(&self) -> JulianDate {
        self.epoch.jd_utc()
    }

    /// Minutes from the epoch to `t` (SGP4's `tsince`).
    pub fn minutes_since_epoch(&self, t: UtcTime) -> f64 {
        t.seconds_since(self.epoch) / 60.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ISS1: &str = "1 25544U 98067A   20194.88612269 -.00002218  00000-0 -31515-4 0  9992";
    const ISS2: &str = "2 25544  51.6461 221.2784 0001413  89.1723 280.4612 15.49507896236008";

    fn ok(l1: &str, l2: &str, mode: ChecksumMode) -> Tle {
        Tle::parse(l1, l2, mode).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn parses_iss() {
        let t = ok(ISS1, ISS2, ChecksumMode::Strict);
        assert_eq!(t.satnum, 25_544);
        assert_eq!(t.classification, 'U');
        assert_eq!(t.intl_designator, "98067A");
        assert_eq!(t.epoch_year, 2020);
        assert_eq!(t.mean_motion_dot_rev_day2, -0.000_022_18);
        assert_eq!(t.mean_motion_ddot_rev_day3, 0.0);
        assert!((t.bstar_per_earth_radii - -0.315_15e-4).abs() < 1e-20);
        assert_eq!(t.element_set_number, 999);
        assert_eq!(t.inclination_deg, 51.6461);
        assert_eq!(t.eccentricity, 0.000_141_3);
        assert_eq!(t.mean_motion_rev_day, 15.495_078_96);
        assert_eq!(t.rev_number, 23_600);
        // Day 194.88612269 of 2020 = 2020-07-12 + 0.88612269 d = 21:16:00.5 (rounded to ns).
        assert_eq!(t.epoch.to_string(), "2020-07-12T21:16:01.000416Z");
    }

    #[test]
    fn checksum_errors_name_line_and_column() {
        let bad1 = ISS1.replace("9992", "9993");
        let e = Tle::parse(&bad1, ISS2, ChecksumMode::Strict).err();
        assert_eq!(
            e,
            Some(TleError::Checksum {
                line: 1,
                found: '3',
                computed: 2
            })
        );
        assert!(e.is_some_and(|e| e.to_string().contains("line 1, column 69")));
        assert!(Tle::parse(&bad1, ISS2, ChecksumMode::Lenient).is_ok());
    }

    #[test]
    fn field_errors_name_columns() {
        let bad = ISS2.replace("51.6461", "51.6x61");
        let e = Tle::parse(ISS1, &bad, ChecksumMode::Lenient).err();
        let msg = e.map(|e| e.to_string()).unwrap_or_default();
        assert!(msg.contains("line 2, columns 9-16 (inclination)"), "{msg}");
        let e = Tle::parse(ISS2, ISS1, ChecksumMode::Lenient).err();
        assert_eq!(
            e,
            Some(TleError::LineNumber {
                line: 1,
                found: '2'
            })
        );
        let e = Tle::parse(&ISS1[..60], ISS2, ChecksumMode::Strict).err();
        assert!(matches!(
            e,
            Some(TleError::Length {
                line: 1,
                len: 60,
                ..
            })
        ));
    }

    #[test]
    fn alpha5_satnum() {
        let mut l1 = ISS1.replacen("25544", "A0001", 1);
        let mut l2 = ISS2.replacen("25544", "A0001", 1);
        l1.replace_range(68..69, &checksum(&l1).to_string());
        l2.replace_range(68..69, &checksum(&l2).to_string());
        assert_eq!(ok(&l1, &l2, ChecksumMode::Strict).satnum, 100_001);
    }

    #[test]
    fn lenient_accepts_missing_checksum() {
        let t = ok(&ISS1[..68], &ISS2[..68], ChecksumMode::Lenient);
        assert_eq!(t.satnum, 25_544);
        assert!(Tle::parse(&ISS1[..68], ISS2, ChecksumMode::Strict).is_err());
    }
}
