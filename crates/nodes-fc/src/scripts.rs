//! Mission-controller scripts (ICD 1.5, INTERPRETATION.md section 6): the text line, its
//! parser, its canonical form, and the schedule of accepted scripts.
//!
//! # Grammar
//! ```text
//! adcs START END pointECI|pointLVLH|pointTNW r i j k
//! adcs START END pointGEO lat_deg lon_deg alt_m x y z
//! ```
//! - `START`, `END`: UTC unix time, seconds, floating point (fractions allowed).
//! - `r i j k`: quaternion, scalar first, the attitude of the body (BCF) in the frame
//!   (`v_frame = q v_body q^-1`, INTERPRETATION.md 5). Any non-zero quaternion is accepted
//!   and normalised (the ICD's own example `0.707106 0 0 -0.707106` is not unit).
//! - `lat_deg lon_deg alt_m`: the geodetic target (ICD 1.5 GeoLocation); `x y z` the body
//!   vector to point at it, any non-zero length, normalised. The ICD calls the altitude
//!   "above geoid"; it is stored as given and guidance decides the datum.
//!
//! # What is tolerated
//! - Keywords in any ASCII case (`adcs`, `ADCS`; `pointECI` as in the ICD's examples,
//!   `PointECI` as in its grammar, `POINTECI`).
//! - Fields separated by runs of spaces and tabs; leading and trailing whitespace.
//! - One trailing `;` (the ICD's grammar line ends with one), attached or not.
//! - Trailing NULs, CR and LF (the line arrives in a CSP packet, maybe as a C string).
//! - Numbers in Rust's `f64` syntax: `1577836800`, `1.5e9`, `+0.5`, `.5`, `5.`.
//!
//! # What is rejected ([`ScriptError`], one precise reason)
//! Lines longer than [`MAX_LINE_BYTES`] (counted as received, terminators included);
//! non-UTF-8 bytes; control characters inside the line (a CR or LF between fields, an
//! embedded NUL); a first field other than `adcs`; an unknown frame; the wrong number of
//! fields; a field that is not a number; NaN or infinity (also `1e999`); `END <= START`; an
//! all-zero quaternion or body vector; latitude outside [-90, 90] deg; longitude outside
//! [-180, 360) deg (both the signed and the 0-360 east conventions; stored as given);
//! altitude outside [[`MIN_ALT_M`], [`MAX_ALT_M`]] (from a Dead Sea shore to the Kármán
//! line; targets are on or near the ground). The first problem found, left to right, is
//! reported.
//!
//! # Canonical form
//! [`Script`]'s `Display` writes `adcs START END pointECI r i j k` (or `pointLVLH`,
//! `pointTNW`, `pointGEO ...`) with single spaces, no `;`, and every number as the shortest
//! decimal that reads back to the same `f64` (exponent notation only when the plain form
//! would be longer than 24 characters). It parses back to an equal [`Script`], bit for bit:
//! normalisation is idempotent (a quaternion or vector already unit to 4 ulp is kept as
//! is). No canonical line exceeds 213 bytes (`adcs`, `pointGEO`, nine spaces and eight
//! numbers of at most 24 characters), which is why [`MAX_LINE_BYTES`] is 256 (also
//! libcsp 1.4's CAN MTU, `CSP_CAN_MTU`, so any line a CSP packet over CAN can carry is
//! within it).
//!
//! # Schedule
//! [`Schedule`] holds accepted scripts ordered by start, pairwise disjoint as half-open
//! intervals `[START, END)`, at most [`SCHEDULE_CAPACITY`] of them by default. Times are
//! UTC unix seconds of whichever clock the caller runs the schedule on; the core has no
//! clock. A script whose `START` is already past but whose `END` is not is accepted and is
//! active at once; one whose `END` is not after `now` is rejected. The schedule only says
//! which script is active; what the FC holds between scripts is the caller's (the FC holds
//! its last commanded mode, INTERPRETATION.md 6).
//!
//! Pure: no clock, no I/O, no allocation beyond the schedule's vector and error strings;
//! nothing here panics on any input.

use std::fmt;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Longest accepted line, bytes as received (terminators included). 256 is libcsp 1.4's
/// CAN MTU (`CSP_CAN_MTU`) and holds every canonical line (at most 213 bytes).
pub const MAX_LINE_BYTES: usize = 256;
/// Default number of scripts a [`Schedule`] holds (pending and active).
pub const SCHEDULE_CAPACITY: usize = 64;
/// Lowest accepted target altitude, m (below the Dead Sea shore, about -430 m).
pub const MIN_ALT_M: f64 = -1_000.0;
/// Highest accepted target altitude, m (the Kármán line, 100 km).
pub const MAX_ALT_M: f64 = 100_000.0;
/// Latitude range, deg, inclusive.
pub const LAT_RANGE_DEG: (f64, f64) = (-90.0, 90.0);
/// Longitude range, deg: `[-180, 360)`, so both the signed and the east-only conventions.
pub const LON_RANGE_DEG: (f64, f64) = (-180.0, 360.0);

/// The command keyword, field 1.
pub const KEYWORD: &str = "adcs";

/// Tolerance on `|n² - 1|` under which a quaternion or vector counts as unit and is kept
/// bit for bit (so that normalisation is idempotent and the canonical form round-trips).
const UNIT_TOL: f64 = 4.0 * f64::EPSILON;
/// Tolerance on `|n² - 1|` for a hand-built [`Script`] to pass [`Script::validate`].
const HAND_BUILT_UNIT_TOL: f64 = 1e-9;
/// Longest plain-decimal rendering of a number in the canonical form; longer ones use
/// exponent notation (whose longest form, `-1.2345678901234567e-300`, is 24 characters).
const MAX_PLAIN_CHARS: usize = 24;

/// The reference frame of a script (field 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ScriptFrame {
    /// `pointECI`: quaternion of the body in ECI J2000.
    Eci,
    /// `pointLVLH`: quaternion of the body in LVLH.
    Lvlh,
    /// `pointTNW`: quaternion of the body in TNW.
    Tnw,
    /// `pointGEO`: a body vector pointed at a geodetic target.
    Geo,
}

impl ScriptFrame {
    /// Every frame, in keyword order.
    pub const ALL: [ScriptFrame; 4] = [
        ScriptFrame::Eci,
        ScriptFrame::Lvlh,
        ScriptFrame::Tnw,
        ScriptFrame::Geo,
    ];

    /// The keyword in the ICD examples' spelling (`pointECI`, ...).
    pub fn keyword(self) -> &'static str {
        match self {
            ScriptFrame::Eci => "pointECI",
            ScriptFrame::Lvlh => "pointLVLH",
            ScriptFrame::Tnw => "pointTNW",
            ScriptFrame::Geo => "pointGEO",
        }
    }

    /// The frame a keyword names, in any ASCII case.
    pub fn from_keyword(s: &str) -> Option<ScriptFrame> {
        Self::ALL
            .into_iter()
            .find(|f| f.keyword().eq_ignore_ascii_case(s))
    }

    /// Number of fields of a line of this frame, `adcs` included.
    pub fn field_count(self) -> usize {
        match self {
            ScriptFrame::Geo => 10,
            _ => 8,
        }
    }

    /// The line's form, for error messages.
    pub fn form(self) -> &'static str {
        match self {
            ScriptFrame::Eci => "adcs START END pointECI r i j k",
            ScriptFrame::Lvlh => "adcs START END pointLVLH r i j k",
            ScriptFrame::Tnw => "adcs START END pointTNW r i j k",
            ScriptFrame::Geo => "adcs START END pointGEO lat_deg lon_deg alt_m x y z",
        }
    }
}

impl fmt::Display for ScriptFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.keyword())
    }
}

/// The attitude a script commands.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScriptAttitude {
    /// Body attitude in ECI J2000 (`q_eci_from_body`).
    Eci(UnitQuaternion<f64>),
    /// Body attitude in LVLH (`q_lvlh_from_body`).
    Lvlh(UnitQuaternion<f64>),
    /// Body attitude in TNW (`q_tnw_from_body`).
    Tnw(UnitQuaternion<f64>),
    /// Point the unit body vector `axis_body` at a geodetic target.
    Geo {
        /// Geodetic latitude, deg, in [-90, 90].
        lat_deg: f64,
        /// Longitude, deg east, in [-180, 360), as given.
        lon_deg: f64,
        /// Altitude, m, in [[`MIN_ALT_M`], [`MAX_ALT_M`]] (ICD: above the geoid).
        alt_m: f64,
        /// Body vector to point at the target, unit.
        axis_body: Vector3<f64>,
    },
}

impl ScriptAttitude {
    /// The frame of this attitude.
    pub fn frame(&self) -> ScriptFrame {
        match self {
            ScriptAttitude::Eci(_) => ScriptFrame::Eci,
            ScriptAttitude::Lvlh(_) => ScriptFrame::Lvlh,
            ScriptAttitude::Tnw(_) => ScriptFrame::Tnw,
            ScriptAttitude::Geo { .. } => ScriptFrame::Geo,
        }
    }
}

/// One mission-controller script: an attitude held over `[start, end)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Script {
    /// Start, UTC unix seconds (inclusive).
    pub start_unix_s: f64,
    /// End, UTC unix seconds (exclusive), after the start.
    pub end_unix_s: f64,
    /// What to point.
    pub attitude: ScriptAttitude,
}

/// Why a script line or a schedule insertion was rejected.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum ScriptError {
    /// The line is longer than [`MAX_LINE_BYTES`].
    TooLong {
        /// Its length, bytes.
        len: usize,
    },
    /// The bytes are not UTF-8.
    NotUtf8 {
        /// Offset of the first invalid byte.
        offset: usize,
    },
    /// A control character inside the line (not a trailing terminator).
    ControlCharacter {
        /// Byte offset in the line as received.
        offset: usize,
        /// The character.
        ch: char,
    },
    /// Nothing but whitespace and terminators.
    Empty,
    /// Field 1 is not `adcs`.
    UnknownCommand {
        /// The field.
        text: String,
    },
    /// Fewer than 4 fields, so no frame.
    TooFewFields {
        /// Fields found.
        found: usize,
    },
    /// Field 4 is not a frame keyword.
    UnknownFrame {
        /// The field.
        text: String,
    },
    /// The wrong number of fields for the frame.
    Arity {
        /// The frame of field 4.
        frame: ScriptFrame,
        /// Fields found.
        found: usize,
    },
    /// A numeric field does not parse.
    NotANumber {
        /// Field number, 1-based (`adcs` is 1).
        field: usize,
        /// What the field is.
        name: &'static str,
        /// The field.
        text: String,
    },
    /// A numeric field is NaN or infinite.
    NonFinite {
        /// Field number, 1-based.
        field: usize,
        /// What the field is.
        name: &'static str,
        /// The field (or, for a hand-built script, the value).
        text: String,
    },
    /// `END <= START`.
    EndNotAfterStart {
        /// START, unix s.
        start_unix_s: f64,
        /// END, unix s.
        end_unix_s: f64,
    },
    /// The quaternion is all zeros.
    ZeroQuaternion,
    /// The body vector is all zeros.
    ZeroVector,
    /// A hand-built script's quaternion or vector is not unit (parsed ones always are).
    NotUnit {
        /// Which: "quaternion" or "body vector".
        what: &'static str,
    },
    /// Latitude outside [-90, 90] deg.
    Latitude {
        /// The value, deg.
        lat_deg: f64,
    },
    /// Longitude outside [-180, 360) deg.
    Longitude {
        /// The value, deg.
        lon_deg: f64,
    },
    /// Altitude outside [[`MIN_ALT_M`], [`MAX_ALT_M`]].
    Altitude {
        /// The value, m.
        alt_m: f64,
    },
    /// Schedule: the script is already over (`END <= now`).
    EndInPast {
        /// END, unix s.
        end_unix_s: f64,
        /// Now, unix s.
        now_unix_s: f64,
    },
    /// Schedule: the script overlaps an accepted one.
    Overlap {
        /// The accepted script's START, unix s.
        start_unix_s: f64,
        /// The accepted script's END, unix s.
        end_unix_s: f64,
    },
    /// Schedule: full.
    Full {
        /// The schedule's capacity.
        capacity: usize,
    },
}

impl fmt::Display for ScriptError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ScriptError::TooLong { len } => {
                write!(
                    f,
                    "line is {len} bytes, over the {MAX_LINE_BYTES}-byte limit"
                )
            }
            ScriptError::NotUtf8 { offset } => {
                write!(f, "not UTF-8: invalid byte at offset {offset}")
            }
            ScriptError::ControlCharacter { offset, ch } => {
                write!(f, "control character {ch:?} at byte {offset}")
            }
            ScriptError::Empty => write!(f, "empty line"),
            ScriptError::UnknownCommand { text } => {
                write!(f, "field 1 (command): {text:?} is not `{KEYWORD}`")
            }
            ScriptError::TooFewFields { found } => write!(
                f,
                "{found} field(s); a script is `adcs START END pointECI|pointLVLH|pointTNW r i j k` \
                 or `adcs START END pointGEO lat_deg lon_deg alt_m x y z`"
            ),
            ScriptError::UnknownFrame { text } => write!(
                f,
                "field 4 (frame): {text:?} is not pointECI, pointLVLH, pointTNW or pointGEO"
            ),
            ScriptError::Arity { frame, found } => write!(
                f,
                "{frame} takes {} fields (`{}`), found {found}",
                frame.field_count(),
                frame.form()
            ),
            ScriptError::NotANumber { field, name, text } => {
                write!(f, "field {field} ({name}): {text:?} is not a number")
            }
            ScriptError::NonFinite { field, name, text } => {
                write!(f, "field {field} ({name}): {text:?} is not finite")
            }
            ScriptError::EndNotAfterStart {
                start_unix_s,
                end_unix_s,
            } => write!(f, "END {end_unix_s} is not after START {start_unix_s}"),
            ScriptError::ZeroQuaternion => {
                write!(f, "quaternion (fields 5-8) is zero: no attitude")
            }
            ScriptError::ZeroVector => {
                write!(f, "body vector (fields 8-10) is zero: no direction")
            }
            ScriptError::NotUnit { what } => write!(f, "{what} is not unit"),
            ScriptError::Latitude { lat_deg } => write!(
                f,
                "field 5 (latitude deg): {lat_deg} is outside [{}, {}]",
                LAT_RANGE_DEG.0, LAT_RANGE_DEG.1
            ),
            ScriptError::Longitude { lon_deg } => write!(
                f,
                "field 6 (longitude deg): {lon_deg} is outside [{}, {})",
                LON_RANGE_DEG.0, LON_RANGE_DEG.1
            ),
            ScriptError::Altitude { alt_m } => write!(
                f,
                "field 7 (altitude m): {alt_m} is outside [{MIN_ALT_M}, {MAX_ALT_M}]"
            ),
            ScriptError::EndInPast {
                end_unix_s,
                now_unix_s,
            } => write!(
                f,
                "END {end_unix_s} is not after now ({now_unix_s}): the script is over"
            ),
            ScriptError::Overlap {
                start_unix_s,
                end_unix_s,
            } => write!(
                f,
                "overlaps the accepted script [{start_unix_s}, {end_unix_s})"
            ),
            ScriptError::Full { capacity } => {
                write!(f, "schedule full ({capacity} scripts)")
            }
        }
    }
}

impl std::error::Error for ScriptError {}

/// Names of fields 5-10 by frame, for error messages.
const QUAT_NAMES: [&str; 4] = [
    "quaternion r",
    "quaternion i",
    "quaternion j",
    "quaternion k",
];
const GEO_NAMES: [&str; 6] = [
    "latitude deg",
    "longitude deg",
    "altitude m",
    "body vector x",
    "body vector y",
    "body vector z",
];

/// Parse field `field` (1-based) as a finite number.
fn number(field: usize, name: &'static str, text: &str) -> Result<f64, ScriptError> {
    let v: f64 = text.parse().map_err(|_| ScriptError::NotANumber {
        field,
        name,
        text: text.to_owned(),
    })?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ScriptError::NonFinite {
            field,
            name,
            text: text.to_owned(),
        })
    }
}

fn sum_sq<const N: usize>(v: &[f64; N]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

/// Normalise a finite vector, `None` if all zeros. Idempotent bit for bit: a vector whose
/// squared norm is within [`UNIT_TOL`] of 1 is returned unchanged, and every result is such
/// a vector. Scaling by the largest component first keeps huge and tiny inputs finite.
fn normalise<const N: usize>(v: [f64; N]) -> Option<[f64; N]> {
    if (sum_sq(&v) - 1.0).abs() <= UNIT_TOL {
        return Some(v);
    }
    let m = v.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    if m == 0.0 || !m.is_finite() {
        return None;
    }
    let mut u = v.map(|x| x / m);
    // A few passes: the first does the work, the others absorb rounding (rarely needed).
    for _ in 0..4 {
        let n2 = sum_sq(&u);
        if (n2 - 1.0).abs() <= UNIT_TOL {
            break;
        }
        let n = n2.sqrt();
        u = u.map(|x| x / n);
    }
    Some(u)
}

/// Strip what the grammar tolerates around a line; `(offset of the body, body)`.
fn trim_line(s: &str) -> (usize, &str) {
    let term = |c: char| c == '\0' || c.is_whitespace();
    let t = s.trim_start();
    let lead = s.len() - t.len();
    let t = t.trim_end_matches(term);
    let t = t.strip_suffix(';').unwrap_or(t).trim_end_matches(term);
    (lead, t)
}

impl Script {
    /// Parse one script line (see the module doc for the grammar and what is tolerated).
    pub fn parse(line: &str) -> Result<Script, ScriptError> {
        if line.len() > MAX_LINE_BYTES {
            return Err(ScriptError::TooLong { len: line.len() });
        }
        let (lead, body) = trim_line(line);
        if let Some((i, ch)) = body
            .char_indices()
            .find(|&(_, c)| c.is_control() && c != '\t')
        {
            return Err(ScriptError::ControlCharacter {
                offset: lead + i,
                ch,
            });
        }
        let fields: Vec<&str> = body.split([' ', '\t']).filter(|f| !f.is_empty()).collect();
        let Some(&command) = fields.first() else {
            return Err(ScriptError::Empty);
        };
        if !command.eq_ignore_ascii_case(KEYWORD) {
            return Err(ScriptError::UnknownCommand {
                text: command.to_owned(),
            });
        }
        let [_, start, end, frame, rest @ ..] = fields.as_slice() else {
            return Err(ScriptError::TooFewFields {
                found: fields.len(),
            });
        };
        let Some(frame) = ScriptFrame::from_keyword(frame) else {
            return Err(ScriptError::UnknownFrame {
                text: (*frame).to_owned(),
            });
        };
        if fields.len() != frame.field_count() {
            return Err(ScriptError::Arity {
                frame,
                found: fields.len(),
            });
        }
        let start_unix_s = number(2, "START", start)?;
        let end_unix_s = number(3, "END", end)?;
        let names: &[&'static str] = match frame {
            ScriptFrame::Geo => &GEO_NAMES,
            _ => &QUAT_NAMES,
        };
        let mut v = [0.0; 6];
        for (k, (text, name)) in rest.iter().zip(names).enumerate() {
            v[k] = number(5 + k, name, text)?;
        }
        if end_unix_s <= start_unix_s {
            return Err(ScriptError::EndNotAfterStart {
                start_unix_s,
                end_unix_s,
            });
        }
        let attitude = match frame {
            ScriptFrame::Geo => {
                let [lat_deg, lon_deg, alt_m, x, y, z] = v;
                check_geo(lat_deg, lon_deg, alt_m)?;
                let [x, y, z] = normalise([x, y, z]).ok_or(ScriptError::ZeroVector)?;
                ScriptAttitude::Geo {
                    lat_deg,
                    lon_deg,
                    alt_m,
                    axis_body: Vector3::new(x, y, z),
                }
            }
            _ => {
                let [r, i, j, k] =
                    normalise([v[0], v[1], v[2], v[3]]).ok_or(ScriptError::ZeroQuaternion)?;
                let q = UnitQuaternion::new_unchecked(Quaternion::new(r, i, j, k));
                match frame {
                    ScriptFrame::Eci => ScriptAttitude::Eci(q),
                    ScriptFrame::Lvlh => ScriptAttitude::Lvlh(q),
                    _ => ScriptAttitude::Tnw(q),
                }
            }
        };
        Ok(Script {
            start_unix_s,
            end_unix_s,
            attitude,
        })
    }

    /// Parse one script line from bytes as received (e.g. a CSP packet's data).
    pub fn parse_bytes(b: &[u8]) -> Result<Script, ScriptError> {
        if b.len() > MAX_LINE_BYTES {
            return Err(ScriptError::TooLong { len: b.len() });
        }
        let s = std::str::from_utf8(b).map_err(|e| ScriptError::NotUtf8 {
            offset: e.valid_up_to(),
        })?;
        Script::parse(s)
    }

    /// Check a script built by hand as [`Script::parse`] checks a line: finite times with
    /// `END > START`, unit and finite quaternion or vector (to 1e-9), geodetic ranges.
    pub fn validate(&self) -> Result<(), ScriptError> {
        let finite = |field, name, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(ScriptError::NonFinite {
                    field,
                    name,
                    text: v.to_string(),
                })
            }
        };
        finite(2, "START", self.start_unix_s)?;
        finite(3, "END", self.end_unix_s)?;
        if self.end_unix_s <= self.start_unix_s {
            return Err(ScriptError::EndNotAfterStart {
                start_unix_s: self.start_unix_s,
                end_unix_s: self.end_unix_s,
            });
        }
        let unit = |what, v: &[f64]| {
            for (k, x) in v.iter().enumerate() {
                let name = match what {
                    "quaternion" => QUAT_NAMES[k],
                    _ => GEO_NAMES[3 + k],
                };
                finite(if v.len() == 4 { 5 + k } else { 8 + k }, name, *x)?;
            }
            let n2: f64 = v.iter().map(|x| x * x).sum();
            if (n2 - 1.0).abs() <= HAND_BUILT_UNIT_TOL {
                Ok(())
            } else {
                Err(ScriptError::NotUnit { what })
            }
        };
        match &self.attitude {
            ScriptAttitude::Eci(q) | ScriptAttitude::Lvlh(q) | ScriptAttitude::Tnw(q) => {
                unit("quaternion", q.as_ref().coords.as_slice())
            }
            ScriptAttitude::Geo {
                lat_deg,
                lon_deg,
                alt_m,
                axis_body,
            } => {
                finite(5, GEO_NAMES[0], *lat_deg)?;
                finite(6, GEO_NAMES[1], *lon_deg)?;
                finite(7, GEO_NAMES[2], *alt_m)?;
                check_geo(*lat_deg, *lon_deg, *alt_m)?;
                unit("body vector", axis_body.as_slice())
            }
        }
    }

    /// Whether `now_unix_s` is within `[start, end)`.
    pub fn contains(&self, now_unix_s: f64) -> bool {
        self.start_unix_s <= now_unix_s && now_unix_s < self.end_unix_s
    }
}

/// Range checks of a geodetic target (finite values).
fn check_geo(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Result<(), ScriptError> {
    if !(LAT_RANGE_DEG.0..=LAT_RANGE_DEG.1).contains(&lat_deg) {
        return Err(ScriptError::Latitude { lat_deg });
    }
    if !(LON_RANGE_DEG.0..LON_RANGE_DEG.1).contains(&lon_deg) {
        return Err(ScriptError::Longitude { lon_deg });
    }
    if !(MIN_ALT_M..=MAX_ALT_M).contains(&alt_m) {
        return Err(ScriptError::Altitude { alt_m });
    }
    Ok(())
}

/// A number in the canonical form: the shortest round-trip decimal, plain unless that is
/// longer than [`MAX_PLAIN_CHARS`].
struct Num(f64);

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let plain = self.0.to_string();
        if plain.len() <= MAX_PLAIN_CHARS {
            f.write_str(&plain)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

impl fmt::Display for Script {
    /// The canonical line (see the module doc); it parses back to an equal script.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{KEYWORD} {} {} {}",
            Num(self.start_unix_s),
            Num(self.end_unix_s),
            self.attitude.frame()
        )?;
        match &self.attitude {
            ScriptAttitude::Eci(q) | ScriptAttitude::Lvlh(q) | ScriptAttitude::Tnw(q) => {
                write!(f, " {} {} {} {}", Num(q.w), Num(q.i), Num(q.j), Num(q.k))
            }
            ScriptAttitude::Geo {
                lat_deg,
                lon_deg,
                alt_m,
                axis_body,
            } => write!(
                f,
                " {} {} {} {} {} {}",
                Num(*lat_deg),
                Num(*lon_deg),
                Num(*alt_m),
                Num(axis_body.x),
                Num(axis_body.y),
                Num(axis_body.z)
            ),
        }
    }
}

impl std::str::FromStr for Script {
    type Err = ScriptError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Script::parse(s)
    }
}

/// Accepted scripts, ordered by start, pairwise disjoint as `[start, end)` intervals, at most
/// `capacity` of them (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    scripts: Vec<Script>,
    capacity: usize,
}

impl Default for Schedule {
    fn default() -> Self {
        Schedule::new()
    }
}

impl Schedule {
    /// An empty schedule of [`SCHEDULE_CAPACITY`] scripts.
    pub fn new() -> Self {
        Schedule::with_capacity(SCHEDULE_CAPACITY)
    }

    /// An empty schedule of `capacity` scripts (a scenario override).
    pub fn with_capacity(capacity: usize) -> Self {
        Schedule {
            scripts: Vec::with_capacity(capacity.min(SCHEDULE_CAPACITY)),
            capacity,
        }
    }

    /// The most scripts it holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Accept `s` at `now_unix_s`. First drops the scripts that ended by now (as
    /// [`Schedule::expire`], whatever the verdict), then rejects, in this order, a script
    /// that fails [`Script::validate`], is already over (`END <= now`), overlaps an accepted
    /// one, or does not fit. A script already started (`START <= now < END`) is accepted
    /// and is active at once.
    pub fn add(&mut self, s: Script, now_unix_s: f64) -> Result<(), ScriptError> {
        self.expire(now_unix_s);
        s.validate()?;
        // A NaN `now` rejects rather than accepts.
        if now_unix_s.is_nan() || s.end_unix_s <= now_unix_s {
            return Err(ScriptError::EndInPast {
                end_unix_s: s.end_unix_s,
                now_unix_s,
            });
        }
        // Sorted and disjoint: only the neighbours of the insertion point can overlap.
        let at = self
            .scripts
            .partition_point(|e| e.start_unix_s < s.start_unix_s);
        let before = at.checked_sub(1).and_then(|i| self.scripts.get(i));
        let clash = before
            .filter(|e| e.end_unix_s > s.start_unix_s)
            .or_else(|| {
                self.scripts
                    .get(at)
                    .filter(|e| e.start_unix_s < s.end_unix_s)
            });
        if let Some(e) = clash {
            return Err(ScriptError::Overlap {
                start_unix_s: e.start_unix_s,
                end_unix_s: e.end_unix_s,
            });
        }
        if self.scripts.len() >= self.capacity {
            return Err(ScriptError::Full {
                capacity: self.capacity,
            });
        }
        self.scripts.insert(at, s);
        Ok(())
    }

    /// The script whose `[start, end)` contains `now_unix_s`, if any.
    pub fn active(&self, now_unix_s: f64) -> Option<&Script> {
        let at = self
            .scripts
            .partition_point(|e| e.start_unix_s <= now_unix_s);
        at.checked_sub(1)
            .and_then(|i| self.scripts.get(i))
            .filter(|e| now_unix_s < e.end_unix_s)
    }

    /// Drop the scripts that ended by `now_unix_s` (`end <= now`); how many.
    pub fn expire(&mut self, now_unix_s: f64) -> usize {
        let before = self.scripts.len();
        self.scripts
            .retain(|e| now_unix_s.is_nan() || e.end_unix_s > now_unix_s);
        before - self.scripts.len()
    }

    /// The first start or end strictly after `now_unix_s` (when to look again), if any.
    pub fn next_change_unix_s(&self, now_unix_s: f64) -> Option<f64> {
        // Sorted and disjoint: the first script not yet over holds the next change.
        self.scripts
            .iter()
            .find(|e| e.end_unix_s > now_unix_s)
            .map(|e| {
                if e.start_unix_s > now_unix_s {
                    e.start_unix_s
                } else {
                    e.end_unix_s
                }
            })
    }

    /// Number of scripts held.
    pub fn len(&self) -> usize {
        self.scripts.len()
    }

    /// Whether it holds no script.
    pub fn is_empty(&self) -> bool {
        self.scripts.is_empty()
    }

    /// Drop every script.
    pub fn clear(&mut self) {
        self.scripts.clear();
    }

    /// The scripts, by start.
    pub fn iter(&self) -> impl Iterator<Item = &Script> {
        self.scripts.iter()
    }
}

snap::fields!(Script {
    start_unix_s,
    end_unix_s,
    attitude
});
// The scripts uploaded (the capacity is the FC's).
snap::fields!(Schedule { scripts; skip capacity });

snap::tagged_enum!(ScriptAttitude {
    Eci(q),
    Lvlh(q),
    Tnw(q),
    Geo {
        lat_deg,
        lon_deg,
        alt_m,
        axis_body
    }
});
