//! Mission-controller scripts (`nodes_fc::scripts`, ICD 1.5): the ICD's example lines, every
//! tolerated spelling, every rejection with its reason text, the canonical form's round
//! trip, and the schedule's time semantics.
#![allow(clippy::unwrap_used)]
// 0.707106 is the ICD 1.5 example's value, deliberately not FRAC_1_SQRT_2.
#![allow(clippy::approx_constant)]

use std::f64::consts::FRAC_1_SQRT_2;

use m6p_nodes_fc::scripts::{
    MAX_LINE_BYTES, SCHEDULE_CAPACITY, Schedule, Script, ScriptAttitude, ScriptError, ScriptFrame,
};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use proptest::prelude::*;

/// 2020-01-01T00:00:00Z, the ICD examples' START.
const T0: f64 = 1_577_836_800.0;

fn coords(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

fn quat(a: &ScriptAttitude) -> UnitQuaternion<f64> {
    match a {
        ScriptAttitude::Eci(q) | ScriptAttitude::Lvlh(q) | ScriptAttitude::Tnw(q) => *q,
        ScriptAttitude::Geo { .. } => panic!("not a quaternion attitude: {a:?}"),
    }
}

/// Bit-exact equality (PartialEq on `UnitQuaternion` also accepts `-q`, and `0.0 == -0.0`).
fn same_bits(a: &Script, b: &Script) -> bool {
    let nums = |s: &Script| -> Vec<u64> {
        let mut v = vec![s.start_unix_s.to_bits(), s.end_unix_s.to_bits()];
        match &s.attitude {
            ScriptAttitude::Eci(q) | ScriptAttitude::Lvlh(q) | ScriptAttitude::Tnw(q) => {
                v.extend(coords(q).map(f64::to_bits))
            }
            ScriptAttitude::Geo {
                lat_deg,
                lon_deg,
                alt_m,
                axis_body,
            } => v.extend(
                [
                    *lat_deg,
                    *lon_deg,
                    *alt_m,
                    axis_body.x,
                    axis_body.y,
                    axis_body.z,
                ]
                .map(f64::to_bits),
            ),
        }
        v
    };
    a.attitude.frame() == b.attitude.frame() && nums(a) == nums(b)
}

// ---------------------------------------------------------------- the ICD's examples

#[test]
fn icd_example_1_point_eci_identity_for_two_minutes() {
    let s = Script::parse("adcs 1577836800 1577836920 pointECI 1 0 0 0").unwrap();
    assert_eq!(s.start_unix_s, T0);
    assert_eq!(s.end_unix_s - s.start_unix_s, 120.0);
    assert_eq!(s.attitude.frame(), ScriptFrame::Eci);
    assert_eq!(coords(&quat(&s.attitude)), [1.0, 0.0, 0.0, 0.0]);
    assert_eq!(s.attitude, ScriptAttitude::Eci(UnitQuaternion::identity()));
}

#[test]
fn icd_example_2_is_normalised_and_puts_body_y_on_the_equinox_and_z_on_the_pole() {
    let s = Script::parse("adcs 1577836800 1577836920 pointECI 0.707106 0 0 -0.707106").unwrap();
    let ScriptAttitude::Eci(q) = s.attitude else {
        panic!("{s:?}")
    };
    let [w, i, j, k] = coords(&q);
    assert!((w - FRAC_1_SQRT_2).abs() < 1e-15, "{w}");
    assert!((k + FRAC_1_SQRT_2).abs() < 1e-15, "{k}");
    assert_eq!((i, j), (0.0, 0.0));
    assert!((q.as_ref().norm() - 1.0).abs() < 1e-15);
    // q_eci_from_body * v_body = v_eci (INTERPRETATION.md 5).
    let y_eci = q * Vector3::y();
    let z_eci = q * Vector3::z();
    let x_eci = q * Vector3::x();
    assert!((y_eci - Vector3::x()).norm() < 1e-15, "{y_eci}");
    assert!((z_eci - Vector3::z()).norm() < 1e-15, "{z_eci}");
    assert!((x_eci + Vector3::y()).norm() < 1e-15, "{x_eci}");
}

#[test]
fn icd_example_3_point_lvlh_identity() {
    let s = Script::parse("adcs 1577836800 1577836920 pointLVLH 1 0 0 0").unwrap();
    assert_eq!(
        s,
        Script {
            start_unix_s: T0,
            end_unix_s: T0 + 120.0,
            attitude: ScriptAttitude::Lvlh(UnitQuaternion::identity()),
        }
    );
}

#[test]
fn icd_example_4_point_geo_vilnius_with_body_z() {
    let s = Script::parse("adcs 1577836800 1577836920 pointGEO 54.6872 25.2797 100 0 0 1").unwrap();
    assert_eq!(
        s,
        Script {
            start_unix_s: T0,
            end_unix_s: T0 + 120.0,
            attitude: ScriptAttitude::Geo {
                lat_deg: 54.6872,
                lon_deg: 25.2797,
                alt_m: 100.0,
                axis_body: Vector3::z(),
            },
        }
    );
}

#[test]
fn tnw_and_non_unit_vectors() {
    let s = Script::parse("adcs 10 20.5 pointTNW 0 0 2 0").unwrap();
    assert_eq!(
        s.attitude,
        ScriptAttitude::Tnw(UnitQuaternion::new_unchecked(Quaternion::new(
            0.0, 0.0, 1.0, 0.0
        )))
    );
    assert_eq!(s.end_unix_s, 20.5);
    let s = Script::parse("adcs 10 20 pointGEO -33.9 -151.2 0 3 0 -4").unwrap();
    let ScriptAttitude::Geo { axis_body, .. } = s.attitude else {
        panic!()
    };
    assert!((axis_body - Vector3::new(0.6, 0.0, -0.8)).norm() < 1e-15);
    // Huge and tiny components normalise without overflow or underflow.
    let s = Script::parse("adcs 1 2 pointECI 1e300 1e300 0 0").unwrap();
    let [w, i, ..] = coords(&quat(&s.attitude));
    assert!((w - FRAC_1_SQRT_2).abs() < 1e-15 && (i - FRAC_1_SQRT_2).abs() < 1e-15);
    let s = Script::parse("adcs 1 2 pointECI 0 0 0 -5e-324").unwrap();
    assert_eq!(coords(&quat(&s.attitude)), [0.0, 0.0, 0.0, -1.0]);
}

// ---------------------------------------------------------------- tolerated spellings

#[test]
fn every_tolerated_spelling_parses_to_the_same_script() {
    let want = Script::parse("adcs 1577836800 1577836920 pointECI 1 0 0 0").unwrap();
    for line in [
        "ADCS 1577836800 1577836920 PointECI 1 0 0 0",
        "Adcs 1577836800 1577836920 POINTECI 1 0 0 0",
        "adcs 1577836800 1577836920 pointeci 1 0 0 0",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0;",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0 ;",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0 ; ",
        "  adcs  1577836800\t1577836920 \t pointECI 1   0 0 0  ",
        "\tadcs 1577836800 1577836920 pointECI 1 0 0 0\r\n",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0\n",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0\0",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0;\r\n\0\0\0",
        "adcs 1577836800 1577836920 pointECI 1 0 0 0\0;",
        "adcs 1.5778368e9 1577836920.0 pointECI +1 0.0 -0 .0",
        "adcs 1577836800 1577836920 pointECI 1. 0e0 0E5 0",
    ] {
        let got = Script::parse(line).unwrap_or_else(|e| panic!("{line:?}: {e}"));
        assert_eq!(got, want, "{line:?}");
        assert_eq!(
            Script::parse_bytes(line.as_bytes()).unwrap(),
            want,
            "{line:?}"
        );
        assert_eq!(line.parse::<Script>().unwrap(), want, "{line:?}");
    }
}

// ---------------------------------------------------------------- rejections

/// Every rejection of a line, with its exact reason text.
#[test]
fn every_rejection_has_its_reason() {
    let cases: &[(&str, &str)] = &[
        ("", "empty line"),
        ("  \t;\r\n\0", "empty line"),
        (
            "adc 1 2 pointECI 1 0 0 0",
            "field 1 (command): \"adc\" is not `adcs`",
        ),
        (
            "adcsx 1 2 pointECI 1 0 0 0",
            "field 1 (command): \"adcsx\" is not `adcs`",
        ),
        (
            "adcs 1 2",
            "3 field(s); a script is `adcs START END pointECI|pointLVLH|pointTNW r i j k` \
             or `adcs START END pointGEO lat_deg lon_deg alt_m x y z`",
        ),
        (
            "adcs 1 2 pointECEF 1 0 0 0",
            "field 4 (frame): \"pointECEF\" is not pointECI, pointLVLH, pointTNW or pointGEO",
        ),
        (
            "adcs 1 2 ECI 1 0 0 0",
            "field 4 (frame): \"ECI\" is not pointECI, pointLVLH, pointTNW or pointGEO",
        ),
        (
            "adcs 1 2 pointECI 1 0 0",
            "pointECI takes 8 fields (`adcs START END pointECI r i j k`), found 7",
        ),
        (
            "adcs 1 2 pointLVLH 1 0 0 0 0",
            "pointLVLH takes 8 fields (`adcs START END pointLVLH r i j k`), found 9",
        ),
        (
            "adcs 1 2 pointTNW",
            "pointTNW takes 8 fields (`adcs START END pointTNW r i j k`), found 4",
        ),
        (
            "adcs 1 2 pointGEO 1 0 0 0",
            "pointGEO takes 10 fields (`adcs START END pointGEO lat_deg lon_deg alt_m x y z`), \
             found 8",
        ),
        (
            "adcs 1 2 pointECI abc 0 0 0",
            "field 5 (quaternion r): \"abc\" is not a number",
        ),
        (
            "adcs x 2 pointECI 1 0 0 0",
            "field 2 (START): \"x\" is not a number",
        ),
        (
            "adcs 1 2,5 pointECI 1 0 0 0",
            "field 3 (END): \"2,5\" is not a number",
        ),
        (
            "adcs 1 2 pointECI 1 0 0 0x0",
            "field 8 (quaternion k): \"0x0\" is not a number",
        ),
        (
            "adcs 1 2 pointECI 1 0 0 0;;",
            "field 8 (quaternion k): \"0;\" is not a number",
        ),
        (
            "adcs 1 2 pointGEO 1 2 3 0 0 z",
            "field 10 (body vector z): \"z\" is not a number",
        ),
        (
            "adcs 1 2 pointGEO 1 2 3m 0 0 1",
            "field 7 (altitude m): \"3m\" is not a number",
        ),
        (
            "adcs nan 2 pointECI 1 0 0 0",
            "field 2 (START): \"nan\" is not finite",
        ),
        (
            "adcs 1 inf pointECI 1 0 0 0",
            "field 3 (END): \"inf\" is not finite",
        ),
        (
            "adcs 1 2 pointECI 1 0 -infinity 0",
            "field 7 (quaternion j): \"-infinity\" is not finite",
        ),
        (
            "adcs 1 2 pointGEO 1e999 0 0 0 0 1",
            "field 5 (latitude deg): \"1e999\" is not finite",
        ),
        (
            "adcs 1577836920 1577836800 pointECI 1 0 0 0",
            "END 1577836800 is not after START 1577836920",
        ),
        ("adcs 5 5 pointECI 1 0 0 0", "END 5 is not after START 5"),
        (
            "adcs 1 2 pointECI 0 0 0 0",
            "quaternion (fields 5-8) is zero: no attitude",
        ),
        (
            "adcs 1 2 pointTNW -0 0.0 0e9 -0",
            "quaternion (fields 5-8) is zero: no attitude",
        ),
        (
            "adcs 1 2 pointGEO 0 0 0 0 0 0",
            "body vector (fields 8-10) is zero: no direction",
        ),
        (
            "adcs 1 2 pointGEO 90.0001 0 0 0 0 1",
            "field 5 (latitude deg): 90.0001 is outside [-90, 90]",
        ),
        (
            "adcs 1 2 pointGEO -91 0 0 0 0 1",
            "field 5 (latitude deg): -91 is outside [-90, 90]",
        ),
        (
            "adcs 1 2 pointGEO 0 -180.5 0 0 0 1",
            "field 6 (longitude deg): -180.5 is outside [-180, 360)",
        ),
        (
            "adcs 1 2 pointGEO 0 360 0 0 0 1",
            "field 6 (longitude deg): 360 is outside [-180, 360)",
        ),
        (
            "adcs 1 2 pointGEO 0 0 -1000.5 0 0 1",
            "field 7 (altitude m): -1000.5 is outside [-1000, 100000]",
        ),
        (
            "adcs 1 2 pointGEO 0 0 100001 0 0 1",
            "field 7 (altitude m): 100001 is outside [-1000, 100000]",
        ),
        (
            "adcs 1 2 pointECI 1 0\n0 0",
            "control character '\\n' at byte 21",
        ),
        (
            " adcs 1 2 pointECI 1 0\r0 0",
            "control character '\\r' at byte 22",
        ),
        (
            "adcs\0 1 2 pointECI 1 0 0 0",
            "control character '\\0' at byte 4",
        ),
        (
            "\0adcs 1 2 pointECI 1 0 0 0",
            "control character '\\0' at byte 0",
        ),
        (
            "adcs 1 2 pointECI\u{1b} 1 0 0 0",
            "control character '\\u{1b}' at byte 17",
        ),
        (
            "adcs 1 2 pointECI 1 0 0 0\nadcs 3 4 pointECI 1 0 0 0",
            "control character '\\n' at byte 25",
        ),
        (
            "adcs 1 2 point\u{a0}ECI 1 0 0 0",
            "field 4 (frame): \"point\\u{a0}ECI\" is not pointECI, pointLVLH, pointTNW or pointGEO",
        ),
    ];
    for (line, why) in cases {
        let e = Script::parse(line).expect_err(line);
        assert_eq!(e.to_string(), *why, "{line:?}");
        assert_eq!(Script::parse_bytes(line.as_bytes()).unwrap_err(), e);
    }
}

#[test]
fn geodetic_and_time_bounds_are_inclusive_where_documented() {
    for line in [
        "adcs 1 2 pointGEO 90 0 0 0 0 1",
        "adcs 1 2 pointGEO -90 0 0 0 0 1",
        "adcs 1 2 pointGEO 0 -180 0 0 0 1",
        "adcs 1 2 pointGEO 0 359.999999 0 0 0 1",
        "adcs 1 2 pointGEO 0 0 -1000 0 0 1",
        "adcs 1 2 pointGEO 0 0 100000 0 0 1",
        // Any finite times with END > START: the schedule judges them against its clock.
        "adcs -10 -5 pointECI 1 0 0 0",
        "adcs 1577836800 1577836800.000001 pointECI 1 0 0 0",
    ] {
        Script::parse(line).unwrap_or_else(|e| panic!("{line:?}: {e}"));
    }
}

#[test]
fn line_length_limit_counts_bytes_as_received() {
    let base = "adcs 1577836800 1577836920 pointECI 1 0 0 0";
    let fits = format!("{base}{}", " ".repeat(MAX_LINE_BYTES - base.len()));
    assert_eq!(fits.len(), 256);
    assert!(Script::parse(&fits).is_ok());
    let over = format!("{fits} ");
    assert_eq!(
        Script::parse(&over).unwrap_err().to_string(),
        "line is 257 bytes, over the 256-byte limit"
    );
    // Terminators count: a NUL-padded buffer of 300 bytes is too long.
    let mut padded = base.as_bytes().to_vec();
    padded.resize(300, 0);
    assert_eq!(
        Script::parse_bytes(&padded).unwrap_err(),
        ScriptError::TooLong { len: 300 }
    );
    // The limit is checked before UTF-8, so a long garbage packet costs nothing.
    assert_eq!(
        Script::parse_bytes(&[0xff; 1000]).unwrap_err(),
        ScriptError::TooLong { len: 1000 }
    );
}

#[test]
fn non_utf8_bytes_are_rejected_with_the_offset() {
    let mut b = b"adcs 1 2 pointECI 1 0 0 0".to_vec();
    b[5] = 0xff;
    let e = Script::parse_bytes(&b).unwrap_err();
    assert_eq!(e, ScriptError::NotUtf8 { offset: 5 });
    assert_eq!(e.to_string(), "not UTF-8: invalid byte at offset 5");
    // A truncated multi-byte sequence at the end.
    let mut b = b"adcs 1 2 pointECI 1 0 0 0".to_vec();
    b.push(0xc3);
    assert_eq!(
        Script::parse_bytes(&b).unwrap_err(),
        ScriptError::NotUtf8 { offset: 25 }
    );
}

// ---------------------------------------------------------------- canonical form

#[test]
fn display_is_the_canonical_line() {
    for (line, canonical) in [
        (
            "adcs 1577836800 1577836920 pointECI 1 0 0 0",
            "adcs 1577836800 1577836920 pointECI 1 0 0 0",
        ),
        (
            "ADCS\t1577836800.5 1.5778369e9 PointLVLH 2 0 0 0;\r\n",
            "adcs 1577836800.5 1577836900 pointLVLH 1 0 0 0",
        ),
        (
            "adcs 1577836800 1577836920 pointtnw 0 0 0 -3",
            "adcs 1577836800 1577836920 pointTNW 0 0 0 -1",
        ),
        (
            "adcs 1577836800 1577836920 pointGEO 54.6872 25.2797 100 0 0 1",
            "adcs 1577836800 1577836920 pointGEO 54.6872 25.2797 100 0 0 1",
        ),
        (
            "adcs 1 2 pointGEO 1e-300 0.00001 -1e3 0 5 0",
            "adcs 1 2 pointGEO 1e-300 0.00001 -1000 0 1 0",
        ),
    ] {
        let s = Script::parse(line).unwrap();
        assert_eq!(s.to_string(), canonical, "{line:?}");
        assert!(same_bits(&Script::parse(canonical).unwrap(), &s));
    }
    let s = Script::parse("adcs 1577836800 1577836920 pointECI 0.707106 0 0 -0.707106").unwrap();
    let text = s.to_string();
    assert_eq!(
        text,
        "adcs 1577836800 1577836920 pointECI 0.7071067811865475 0 0 -0.7071067811865475"
    );
    assert!(same_bits(&Script::parse(&text).unwrap(), &s));
}

#[test]
fn longest_canonical_line_fits_the_limit_and_parses_back() {
    // Numbers of 24 characters (sign, 17 digits, exponent) wherever a valid script allows.
    let long = -1.234_567_890_123_456_7e-300;
    let axis = Vector3::new(-0.999_999_999_999_999_9, long, long);
    let s = Script {
        start_unix_s: long,
        end_unix_s: -1.234_567_890_123_456_6e-300,
        attitude: ScriptAttitude::Geo {
            lat_deg: long,
            lon_deg: long,
            alt_m: long,
            axis_body: axis,
        },
    };
    s.validate().unwrap();
    let text = s.to_string();
    assert_eq!(text.len(), 208, "{text}");
    assert!(text.len() <= MAX_LINE_BYTES);
    let back = Script::parse(&text).unwrap();
    assert!(same_bits(&back, &s), "{back:?}");
    // Plain notation up to 24 characters: one more digit of magnitude switches to e-notation.
    let s = Script::parse("adcs 123456789012345678901234 1e24 pointECI 1 0 0 0").unwrap();
    assert_eq!(
        s.to_string(),
        "adcs 123456789012345690000000 1e24 pointECI 1 0 0 0"
    );
}

#[test]
fn hand_built_scripts_are_validated() {
    let ok = Script::parse("adcs 1 2 pointECI 1 0 0 0").unwrap();
    assert_eq!(ok.validate(), Ok(()));
    let bad_q = Script {
        attitude: ScriptAttitude::Eci(UnitQuaternion::new_unchecked(Quaternion::new(
            2.0, 0.0, 0.0, 0.0,
        ))),
        ..ok
    };
    assert_eq!(
        bad_q.validate().unwrap_err().to_string(),
        "quaternion is not unit"
    );
    let nan_t = Script {
        start_unix_s: f64::NAN,
        ..ok
    };
    assert_eq!(
        nan_t.validate().unwrap_err().to_string(),
        "field 2 (START): \"NaN\" is not finite"
    );
    let geo = Script {
        attitude: ScriptAttitude::Geo {
            lat_deg: 0.0,
            lon_deg: 400.0,
            alt_m: 0.0,
            axis_body: Vector3::z(),
        },
        ..ok
    };
    assert_eq!(
        geo.validate().unwrap_err(),
        ScriptError::Longitude { lon_deg: 400.0 }
    );
    let geo = Script {
        attitude: ScriptAttitude::Geo {
            lat_deg: 0.0,
            lon_deg: 0.0,
            alt_m: 0.0,
            axis_body: Vector3::new(0.0, 0.0, f64::INFINITY),
        },
        ..ok
    };
    assert_eq!(
        geo.validate().unwrap_err().to_string(),
        "field 10 (body vector z): \"inf\" is not finite"
    );
    // The schedule refuses what does not validate.
    let mut sched = Schedule::new();
    assert_eq!(
        sched.add(bad_q, 0.0),
        Err(ScriptError::NotUnit { what: "quaternion" })
    );
    assert!(sched.add(nan_t, 0.0).is_err());
    assert!(sched.is_empty());
}

// ---------------------------------------------------------------- proptests

/// A number as the canonical form would write it, or in a random valid spelling.
fn spell(x: f64, style: u8) -> String {
    match style % 4 {
        0 => format!("{x:e}"),
        1 => format!("{x:E}"),
        2 if x.to_string().len() <= 40 => x.to_string(),
        _ => format!("{x:?}"),
    }
}

fn finite() -> impl Strategy<Value = f64> {
    any::<f64>().prop_filter("finite", |x| x.is_finite())
}

/// Any finite component, often small integers like the ICD's, sometimes extreme.
fn component() -> impl Strategy<Value = f64> {
    prop_oneof![
        (-3i32..=3).prop_map(f64::from),
        -1.0..1.0f64,
        finite(),
        Just(0.707106),
        Just(-0.707106),
        Just(5e-324),
    ]
}

fn start_end() -> impl Strategy<Value = (f64, f64)> {
    prop_oneof![
        (1.5e9..2.5e9f64, 1e-3..1e6f64).prop_map(|(s, d)| (s, s + d)),
        (finite(), finite()).prop_map(|(a, b)| (a.min(b), a.max(b))),
    ]
    .prop_filter("END > START", |(s, e)| e > s)
}

/// A valid script line in a random but tolerated spelling, and its frame.
fn valid_line() -> impl Strategy<Value = (String, ScriptFrame)> {
    let quat = (
        0usize..3,
        prop::array::uniform4(component()).prop_filter("non-zero", |q| q.iter().any(|x| *x != 0.0)),
    )
        .prop_map(|(f, q)| (ScriptFrame::ALL[f], q.to_vec()));
    let geo = (
        -90.0..=90.0f64,
        -180.0..360.0f64,
        -1000.0..=100_000.0f64,
        prop::array::uniform3(component()).prop_filter("non-zero", |v| v.iter().any(|x| *x != 0.0)),
    )
        .prop_map(|(la, lo, al, v)| (ScriptFrame::Geo, vec![la, lo, al, v[0], v[1], v[2]]));
    (
        start_end(),
        prop_oneof![quat, geo],
        any::<u8>(),
        prop::collection::vec(prop::sample::select(vec![" ", "\t", "  ", " \t "]), 10),
        prop::sample::select(vec!["", ";", " ;", ";\r\n", "\0", "\r\n\0\0", "\n"]),
        any::<bool>(),
    )
        .prop_map(|((s, e), (frame, v), style, seps, tail, upper)| {
            let kw = if upper {
                frame.keyword().to_ascii_uppercase()
            } else {
                frame.keyword().to_owned()
            };
            let mut fields = vec!["adcs".to_owned(), spell(s, style), spell(e, style / 4), kw];
            fields.extend(
                v.iter()
                    .enumerate()
                    .map(|(k, x)| spell(*x, style / 16 + k as u8)),
            );
            let mut line = String::new();
            for (f, sep) in fields.iter().zip(&seps) {
                line.push_str(sep);
                line.push_str(f);
            }
            line.push_str(tail);
            (line, frame)
        })
        .prop_filter("fits the line limit", |(line, _)| {
            line.len() <= MAX_LINE_BYTES
        })
}

/// Token soup: script-like lines built from keywords, numbers and junk.
fn soup() -> impl Strategy<Value = String> {
    let token = prop_oneof![
        prop::sample::select(vec![
            "adcs",
            "ADCS",
            "pointECI",
            "pointGEO",
            "pointLVLH",
            "pointTNW",
            "PointTnw",
            "0",
            "1",
            "-1",
            "nan",
            "inf",
            "1e999",
            "-0",
            ";",
            "\0",
            "\r\n",
            "0.707106",
            "90",
            "360",
            "é",
        ])
        .prop_map(str::to_owned),
        finite().prop_map(|x| format!("{x:e}")),
        "[ -~]{0,8}",
    ];
    prop::collection::vec(token, 0..12).prop_map(|t| t.join(" "))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn parse_never_panics_on_arbitrary_strings(s in any::<String>()) {
        let _ = Script::parse(&s);
    }

    #[test]
    fn parse_bytes_never_panics_on_arbitrary_bytes(b in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = Script::parse_bytes(&b);
    }

    #[test]
    fn token_soup_never_panics_and_what_parses_validates_and_round_trips(line in soup()) {
        if let Ok(s) = Script::parse(&line) {
            prop_assert_eq!(s.validate(), Ok(()));
            let back = Script::parse(&s.to_string()).unwrap();
            prop_assert!(same_bits(&back, &s), "{} -> {}", line, s);
        }
    }

    #[test]
    fn valid_lines_parse_and_display_round_trips_bit_for_bit((line, frame) in valid_line()) {
        let s = Script::parse(&line).map_err(|e| TestCaseError::fail(format!("{line:?}: {e}")))?;
        prop_assert_eq!(s.attitude.frame(), frame);
        prop_assert_eq!(s.validate(), Ok(()));
        let text = s.to_string();
        prop_assert!(text.len() <= MAX_LINE_BYTES);
        let back = Script::parse(&text).map_err(|e| TestCaseError::fail(format!("{text:?}: {e}")))?;
        prop_assert_eq!(back, s);
        prop_assert!(same_bits(&back, &s), "{} -> {}", line, text);
        // The canonical form is a fixed point.
        prop_assert_eq!(back.to_string(), text);
        // Unit to rounding.
        let n = match s.attitude {
            ScriptAttitude::Geo { axis_body, .. } => axis_body.norm(),
            a => quat(&a).as_ref().norm(),
        };
        prop_assert!((n - 1.0).abs() < 1e-15, "{}", n);
    }
}

// ---------------------------------------------------------------- schedule

fn eci(start: f64, end: f64) -> Script {
    Script {
        start_unix_s: start,
        end_unix_s: end,
        attitude: ScriptAttitude::Eci(UnitQuaternion::identity()),
    }
}

fn intervals(s: &Schedule) -> Vec<(f64, f64)> {
    s.iter().map(|e| (e.start_unix_s, e.end_unix_s)).collect()
}

#[test]
fn back_to_back_scripts_are_accepted_and_hand_over_at_the_boundary() {
    let mut s = Schedule::new();
    s.add(eci(200.0, 300.0), 0.0).unwrap();
    s.add(eci(100.0, 200.0), 0.0).unwrap();
    s.add(eci(300.0, 301.0), 0.0).unwrap();
    assert_eq!(
        intervals(&s),
        [(100.0, 200.0), (200.0, 300.0), (300.0, 301.0)],
        "ordered by start"
    );
    assert_eq!(s.active(99.999), None);
    assert_eq!(s.active(100.0), Some(&eci(100.0, 200.0)));
    assert_eq!(s.active(199.999), Some(&eci(100.0, 200.0)));
    assert_eq!(s.active(200.0), Some(&eci(200.0, 300.0)));
    assert_eq!(s.active(300.5), Some(&eci(300.0, 301.0)));
    assert_eq!(s.active(301.0), None, "END is exclusive");
    assert_eq!(s.active(f64::NAN), None);
}

#[test]
fn overlaps_are_rejected_with_the_accepted_interval() {
    let mut s = Schedule::new();
    s.add(eci(100.0, 200.0), 0.0).unwrap();
    s.add(eci(300.0, 400.0), 0.0).unwrap();
    for (start, end, with) in [
        (150.0, 250.0, (100.0, 200.0)),
        (50.0, 100.5, (100.0, 200.0)),
        (120.0, 130.0, (100.0, 200.0)),
        (0.0, 1000.0, (100.0, 200.0)),
        (100.0, 200.0, (100.0, 200.0)),
        (100.0, 100.5, (100.0, 200.0)),
        (199.0, 300.0, (100.0, 200.0)),
        (200.0, 300.5, (300.0, 400.0)),
        (399.0, 500.0, (300.0, 400.0)),
    ] {
        let e = s.add(eci(start, end), 0.0).unwrap_err();
        assert_eq!(
            e,
            ScriptError::Overlap {
                start_unix_s: with.0,
                end_unix_s: with.1
            },
            "[{start}, {end})"
        );
    }
    assert_eq!(
        s.add(eci(150.0, 250.0), 0.0).unwrap_err().to_string(),
        "overlaps the accepted script [100, 200)"
    );
    // The gap exactly, and either side, fit.
    s.add(eci(200.0, 300.0), 0.0).unwrap();
    s.add(eci(0.0, 100.0), 0.0).unwrap();
    s.add(eci(400.0, 500.0), 0.0).unwrap();
    assert_eq!(s.len(), 5);
}

#[test]
fn a_script_already_over_is_rejected_one_already_started_runs_at_once() {
    let mut s = Schedule::new();
    let now = T0 + 60.0;
    let e = s.add(eci(T0, T0 + 60.0), now).unwrap_err();
    assert_eq!(
        e.to_string(),
        "END 1577836860 is not after now (1577836860): the script is over"
    );
    assert!(matches!(
        s.add(eci(T0, T0 + 1.0), now),
        Err(ScriptError::EndInPast { .. })
    ));
    assert!(matches!(
        s.add(eci(T0, T0 + 120.0), f64::NAN),
        Err(ScriptError::EndInPast { .. })
    ));
    s.add(eci(T0, T0 + 120.0), now).unwrap();
    assert_eq!(s.active(now), Some(&eci(T0, T0 + 120.0)));
    assert_eq!(s.next_change_unix_s(now), Some(T0 + 120.0));
}

#[test]
fn full_schedule_rejects_until_a_script_expires() {
    let mut s = Schedule::new();
    assert_eq!(s.capacity(), SCHEDULE_CAPACITY);
    for k in 0..SCHEDULE_CAPACITY {
        let t = 1000.0 + 10.0 * k as f64;
        s.add(eci(t, t + 10.0), 0.0).unwrap();
    }
    assert_eq!(s.len(), 64);
    let e = s.add(eci(5000.0, 5010.0), 0.0).unwrap_err();
    assert_eq!(e, ScriptError::Full { capacity: 64 });
    assert_eq!(e.to_string(), "schedule full (64 scripts)");
    // An overlap is reported as such even when full.
    assert!(matches!(
        s.add(eci(1000.0, 1001.0), 0.0),
        Err(ScriptError::Overlap { .. })
    ));
    // At 1010 the first script has ended: add drops it and there is room.
    s.add(eci(5000.0, 5010.0), 1010.0).unwrap();
    assert_eq!(s.len(), 64);
    assert_eq!(s.iter().next().unwrap().start_unix_s, 1010.0);

    let mut small = Schedule::with_capacity(1);
    small.add(eci(1.0, 2.0), 0.0).unwrap();
    assert_eq!(
        small.add(eci(2.0, 3.0), 0.0),
        Err(ScriptError::Full { capacity: 1 })
    );
    assert_eq!(
        Schedule::with_capacity(0).add(eci(1.0, 2.0), 0.0),
        Err(ScriptError::Full { capacity: 0 })
    );
}

#[test]
fn expire_drops_ended_scripts_and_counts_them() {
    let mut s = Schedule::new();
    for (a, b) in [(0.0, 10.0), (10.0, 20.0), (25.0, 30.0), (40.0, 50.0)] {
        s.add(eci(a, b), -1.0).unwrap();
    }
    assert_eq!(s.expire(5.0), 0);
    assert_eq!(s.expire(20.0), 2, "END <= now has ended");
    assert_eq!(intervals(&s), [(25.0, 30.0), (40.0, 50.0)]);
    assert_eq!(s.expire(f64::NAN), 0);
    assert_eq!(s.expire(1e9), 2);
    assert!(s.is_empty());
    s.add(eci(1e9, 2e9), 0.0).unwrap();
    assert!(!s.is_empty());
    s.clear();
    assert_eq!(s.len(), 0);
}

#[test]
fn next_change_is_the_next_start_or_end_strictly_after_now() {
    let mut s = Schedule::new();
    assert_eq!(s.next_change_unix_s(0.0), None);
    for (a, b) in [(10.0, 20.0), (20.0, 30.0), (40.0, 50.0)] {
        s.add(eci(a, b), 0.0).unwrap();
    }
    for (now, want) in [
        (0.0, Some(10.0)),
        (10.0, Some(20.0)),
        (15.0, Some(20.0)),
        (20.0, Some(30.0)),
        (30.0, Some(40.0)),
        (35.0, Some(40.0)),
        (40.0, Some(50.0)),
        (50.0, None),
        (f64::NAN, None),
    ] {
        assert_eq!(s.next_change_unix_s(now), want, "now {now}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Random adds at random times against a brute-force model.
    #[test]
    fn schedule_matches_a_brute_force_model(
        ops in prop::collection::vec((0u32..100, 1u32..20, 0u32..100), 1..60),
        cap in 1usize..12,
        probes in prop::collection::vec(0u32..130, 10),
    ) {
        let mut s = Schedule::with_capacity(cap);
        let mut model: Vec<(f64, f64)> = Vec::new();
        let mut now = 0.0;
        for (start, len, dt) in ops {
            now += f64::from(dt) * 0.1;
            let (a, b) = (f64::from(start), f64::from(start + len));
            model.retain(|&(_, e)| e > now);
            let want_ok = b > now
                && model.iter().all(|&(x, y)| b <= x || y <= a)
                && model.len() < cap;
            let got = s.add(eci(a, b), now);
            prop_assert_eq!(got.is_ok(), want_ok, "add [{}, {}) at {}: {:?}", a, b, now, got);
            if want_ok {
                model.push((a, b));
                model.sort_by(|p, q| p.0.total_cmp(&q.0));
            }
            prop_assert_eq!(intervals(&s), model.clone());
            for w in model.windows(2) {
                prop_assert!(w[0].1 <= w[1].0);
            }
            for p in &probes {
                let t = f64::from(*p) * 1.0 + 0.5 * f64::from(p % 2);
                let want_active = model.iter().find(|&&(x, y)| x <= t && t < y).copied();
                prop_assert_eq!(
                    s.active(t).map(|e| (e.start_unix_s, e.end_unix_s)),
                    want_active
                );
                let want_next = model
                    .iter()
                    .flat_map(|&(x, y)| [x, y])
                    .filter(|&v| v > t)
                    .min_by(f64::total_cmp);
                prop_assert_eq!(s.next_change_unix_s(t), want_next);
            }
        }
    }
}
