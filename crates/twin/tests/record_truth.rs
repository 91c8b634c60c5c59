//! Recording the FC's truth samples (`RunEvent::Truth`): the `/fc/...` channels, their
//! schemas and encodings, decoded values (transform quaternion order, the geodetic position
//! of a known ECEF point, body-frame directions in the scene), non-finite numbers as null,
//! Foxglove messages left out when their numbers are not finite, CSV columns, the summary,
//! determinism, and a generic reader (the `mcap` Python package).
#![allow(clippy::unwrap_used)]

mod common;

use common::TempFile;

use std::f64::consts::FRAC_1_SQRT_2;
use std::path::Path;

use csp::SimTime;
use m6p_twin::events::{Level, RunEvent};
use m6p_twin::record::{
    AdcsMsg, FrameTransformMsg, LocationFixMsg, RecordingMeta, RecordingStats, SceneUpdateMsg,
    TruthStateMsg,
};
use m6p_twin::recording::{self, DiffResult, RecordedMessage};
use orbit::frames::{a_ecef_from_eci, q_eci_from_body_point_eci};
use orbit::geodetic::Geodetic;
use orbit::time::UtcTime;
use platform::truth::{AdcsSnapshot, TruthSnapshot};
use serde_json::Value;

const START_NS: u64 = 1_774_008_000_000_000_000; // 2026-03-20T12:00:00Z

fn meta() -> RecordingMeta {
    RecordingMeta {
        scenario_toml: "name = \"adcs\"\n".into(),
        ..common::meta("adcs", 7)
    }
}

/// The known point of sample 2: 54.9 N, 23.9 E, 500 km above the ellipsoid.
const LAT_DEG: f64 = 54.9;
const LON_DEG: f64 = 23.9;
const ALT_M: f64 = 500e3;

/// A snapshot at `t_s` with the attitude turned 90 degrees about Z (body X is ECI Y, body Y
/// is ECI -X) and everything else zero. (The twin does not name nalgebra's types; the
/// snapshot carries them.)
fn truth_z90(t_s: u64) -> TruthSnapshot {
    TruthSnapshot {
        t: csp::SimTime::from_ns(t_s * 1_000_000_000),
        unix_ns: (START_NS + t_s * 1_000_000_000) as i64,
        q_eci_from_body: q_eci_from_body_point_eci(FRAC_1_SQRT_2, 0.0, 0.0, FRAC_1_SQRT_2).unwrap(),
        ..TruthSnapshot::default()
    }
}

/// Three samples:
/// 1. at 1 s: r = 7000 km along ECI +X, attitude 90 deg about Z, sun along ECI +Y, body
///    rate 1 deg/s about Z, wheels at 100 rad/s, no estimate, a target;
/// 2. at 2 s: over the known point, with an estimate;
/// 3. at 3 s: NaN attitude, position and errors, an infinite rate.
fn samples() -> Vec<RunEvent> {
    let mut ev = Vec::new();

    let mut truth = TruthSnapshot {
        in_eclipse_fraction_visible: 1.0,
        wheel_speed_rad_s: [100.0, -100.0, 0.0, 50.0],
        mtq_dipole_am2: [0.1, -0.2, 0.0],
        ..truth_z90(1)
    };
    truth.r_eci_m.x = 7_000_000.0;
    truth.v_eci_m_s.y = 7_500.0;
    truth.sun_eci_unit.y = 1.0;
    truth.b_eci_nt.z = 30_000.0;
    truth.w_body_rad_s.z = 1f64.to_radians();
    let adcs = AdcsSnapshot {
        t: csp::SimTime::from_ns(1_000_000_000),
        mode_in_effect: 3,
        mode_commanded: 3,
        state: 2,
        q_eci_from_body_target: q_eci_from_body_point_eci(1.0, 0.0, 0.0, 0.0),
        pointing_error_deg: Some(90.0),
        axis_error_deg: Some(12.5),
        wheel_torque_cmd_nm: [1e-4, 0.0, -1e-4, 0.0],
        ..AdcsSnapshot::default()
    };
    ev.push(RunEvent::Truth {
        t: SimTime::from_secs(1),
        truth: Box::new(truth),
        adcs: Box::new(adcs),
    });
    ev.push(RunEvent::Log {
        t: SimTime::from_secs(1),
        source: "FC".into(),
        level: Level::Info,
        message: "ADCS acquiring".into(),
    });

    let unix_ns = (START_NS + 2_000_000_000) as i64;
    let a = a_ecef_from_eci(UtcTime::from_unix_ns(unix_ns), None);
    let r_ecef = Geodetic::from_deg(LAT_DEG, LON_DEG, ALT_M).to_ecef_m();
    let truth = TruthSnapshot {
        r_eci_m: a.transpose() * r_ecef,
        ..truth_z90(2)
    };
    let adcs = AdcsSnapshot {
        t: csp::SimTime::from_ns(2_000_000_000),
        q_eci_from_body_est: q_eci_from_body_point_eci(0.9, 0.1, -0.3, 0.2),
        estimation_error_deg: Some(0.25),
        ..AdcsSnapshot::default()
    };
    ev.push(RunEvent::Truth {
        t: SimTime::from_secs(2),
        truth: Box::new(truth),
        adcs: Box::new(adcs),
    });

    let mut truth = truth_z90(3);
    let q = truth.q_eci_from_body;
    let q_nan = q.nlerp(&q, f64::NAN);
    truth.q_eci_from_body = q_nan;
    truth.r_eci_m.x = f64::NAN;
    truth.r_eci_m.y = 7_000_000.0;
    truth.sun_eci_unit.y = 1.0;
    truth.w_body_rad_s.x = f64::INFINITY;
    let adcs = AdcsSnapshot {
        t: csp::SimTime::from_ns(3_000_000_000),
        q_eci_from_body_est: Some(q_nan),
        pointing_error_deg: Some(f64::NAN),
        wheel_torque_cmd_nm: [f64::NEG_INFINITY, 0.0, 0.0, 0.0],
        ..AdcsSnapshot::default()
    };
    ev.push(RunEvent::Truth {
        t: SimTime::from_secs(3),
        truth: Box::new(truth),
        adcs: Box::new(adcs),
    });
    ev
}

fn record(path: &Path, events: &[RunEvent]) -> RecordingStats {
    common::record(path, meta(), events)
}

use common::on;

fn decode<T: serde::de::DeserializeOwned>(m: &RecordedMessage) -> T {
    m.decode().unwrap()
}

/// The message as decoded JSON text (fields in schema order).
fn text(m: &RecordedMessage) -> String {
    String::from_utf8(m.json_text().unwrap()).unwrap()
}

/// An array of the recording's numbers with the non-finite ones as `None` (null).
fn o<const N: usize>(v: [f64; N]) -> [Option<f64>; N] {
    v.map(|x| x.is_finite().then_some(x))
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// A single-precision field (format 4) within `tol` of `b`, itself at least f32's step.
fn close32(a: f32, b: f64, tol: f64) -> bool {
    (f64::from(a) - b).abs() <= tol.max(b.abs() * f64::from(f32::EPSILON))
}

fn o32<const N: usize>(v: [f32; N]) -> [Option<f32>; N] {
    v.map(|x| x.is_finite().then_some(x))
}

/// Rotate `v` by the quaternion `(x, y, z, w)`: `v + 2w (q x v) + 2 q x (q x v)`.
fn rotate([x, y, z, w]: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let t = cross([x, y, z], v).map(|c| 2.0 * c);
    let u = cross([x, y, z], t);
    [0, 1, 2].map(|i| v[i] + w * t[i] + u[i])
}

#[test]
fn truth_samples_get_their_channels_schemas_and_counts() {
    let f = TempFile::new("channels");
    let s = record(f.path(), &samples());
    let topics: Vec<(&str, u64)> = s
        .channels
        .iter()
        .map(|c| (c.topic.as_str(), c.messages))
        .collect();
    // The fixed channels first; then the /fc channels in order of first message (the
    // estimate's transform only from the second sample, the first with an estimate).
    assert_eq!(
        topics,
        [
            ("/can/main/frames", 0),
            ("/can/payload/frames", 0),
            ("/ground/packets", 0),
            ("/csp/packets", 0),
            ("/log", 1),
            ("/faults", 0),
            ("/commands", 0),
            ("/expectations", 0),
            // Sample 3's NaN attitude: no transform.
            ("/fc/truth/tf", 2),
            // Sample 3's NaN position: no fix.
            ("/fc/truth/location", 2),
            ("/fc/truth/state", 3),
            ("/fc/adcs", 3),
            ("/fc/scene", 3),
            // Sample 2 only: sample 3's estimate is NaN.
            ("/fc/estimate/tf", 1),
        ]
    );

    let bytes = std::fs::read(f.path()).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut chans: Vec<_> = summary.channels.values().collect();
    chans.sort_by_key(|c| c.id);
    // Protobuf: the schema is a FileDescriptorSet holding the message its name names.
    let schema_of = |topic: &str| {
        let c = chans.iter().find(|c| c.topic == topic).unwrap();
        assert_eq!(c.message_encoding, "protobuf", "{topic}");
        let s = c.schema.as_ref().unwrap();
        assert_eq!(s.encoding, "protobuf", "{topic}");
        let fds = <prost_types::FileDescriptorSet as prost::Message>::decode(&*s.data).unwrap();
        let (package, message) = s.name.rsplit_once('.').unwrap();
        let m = fds
            .file
            .iter()
            .filter(|f| f.package() == package)
            .flat_map(|f| f.message_type.iter())
            .find(|m| m.name() == message)
            .unwrap_or_else(|| panic!("{topic}: {} not in its schema", s.name))
            .clone();
        (s.name.clone(), s.id, m)
    };
    let (name, tf_id, _) = schema_of("/fc/truth/tf");
    assert_eq!(name, "foxglove.FrameTransform");
    let (name, est_id, _) = schema_of("/fc/estimate/tf");
    assert_eq!(name, "foxglove.FrameTransform");
    assert_eq!(tf_id, est_id, "the two transforms share one schema record");
    let (name, _, _) = schema_of("/fc/truth/location");
    assert_eq!(name, "foxglove.LocationFix");
    let (name, _, _) = schema_of("/fc/scene");
    assert_eq!(name, "foxglove.SceneUpdate");
    let (name, _, m) = schema_of("/fc/truth/state");
    assert_eq!(name, "m6p.TruthState");
    // Optional numbers have presence: a non-finite value is left out (null when read).
    let lat = m.field.iter().find(|f| f.name() == "lat_deg").unwrap();
    assert!(lat.proto3_optional(), "{lat:?}");
    let (name, _, _) = schema_of("/fc/adcs");
    assert_eq!(name, "m6p.Adcs");
    // Every schema in the file is used by a channel: none is written for kinds the run
    // never had (no KISS link here).
    let used: std::collections::BTreeSet<u16> = chans
        .iter()
        .filter_map(|c| c.schema.as_ref().map(|s| s.id))
        .collect();
    assert_eq!(summary.schemas.len(), used.len());
    assert!(!summary.schemas.values().any(|s| s.name == "m6p.KissFrame"));
}

#[test]
fn transforms_carry_the_attitude_as_x_y_z_w_with_no_translation() {
    let f = TempFile::new("tf");
    let ev = samples();
    record(f.path(), &ev);
    let tfs = on(f.path(), "/fc/truth/tf");
    let first: FrameTransformMsg = decode(&tfs[0]);
    assert_eq!(first.parent_frame_id, "eci");
    assert_eq!(first.child_frame_id, "body");
    assert_eq!(
        (first.timestamp.sec, first.timestamp.nsec),
        (START_NS / 1_000_000_000 + 1, 0)
    );
    assert_eq!(tfs[0].log_time, START_NS + 1_000_000_000);
    let t = first.translation;
    assert_eq!((t.x, t.y, t.z), (0.0, 0.0, 0.0));
    let r = first.rotation;
    assert!(close(r.x, 0.0, 1e-15) && close(r.y, 0.0, 1e-15), "{r:?}");
    assert!(close(r.z, FRAC_1_SQRT_2, 1e-15), "{r:?}");
    assert!(close(r.w, FRAC_1_SQRT_2, 1e-15), "{r:?}");
    // Foxglove's key order, vector part first.
    let raw = text(&tfs[0]);
    let rot = &raw[raw.find("\"rotation\"").unwrap()..];
    let at = |k: &str| rot.find(&format!("\"{k}\":")).unwrap();
    assert!(
        at("x") < at("y") && at("y") < at("z") && at("z") < at("w"),
        "{raw}"
    );
    // Rotating body X by the transform gives ECI Y (active q_eci_from_body).
    let v = rotate([r.x, r.y, r.z, r.w], [1.0, 0.0, 0.0]);
    assert!(close(v[0], 0.0, 1e-12) && close(v[1], 1.0, 1e-12), "{v:?}");

    // The estimate: 0.9 + 0.1i - 0.3j + 0.2k, normalised, as x, y, z, w.
    let est = on(f.path(), "/fc/estimate/tf");
    let e: FrameTransformMsg = decode(&est[0]);
    assert_eq!(
        (e.parent_frame_id.as_str(), e.child_frame_id.as_str()),
        ("eci", "body_est")
    );
    assert_eq!(est[0].log_time, START_NS + 2_000_000_000);
    let n = (0.81f64 + 0.01 + 0.09 + 0.04).sqrt();
    let q = e.rotation;
    for (got, want) in [(q.x, 0.1), (q.y, -0.3), (q.z, 0.2), (q.w, 0.9)] {
        assert!(close(got, want / n, 1e-12), "{q:?}");
    }
}

#[test]
fn location_is_the_geodetic_position_of_the_ecef_point() {
    let f = TempFile::new("location");
    record(f.path(), &samples());
    let fixes = on(f.path(), "/fc/truth/location");
    assert_eq!(fixes[1].log_time, START_NS + 2_000_000_000);
    let fix: LocationFixMsg = decode(&fixes[1]);
    assert_eq!(fix.frame_id, "earth");
    assert_eq!(fix.position_covariance_type, 0);
    assert_eq!(fix.position_covariance, [0.0; 9]);
    assert!(close(fix.latitude, LAT_DEG, 1e-9), "{fix:?}");
    assert!(close(fix.longitude, LON_DEG, 1e-9), "{fix:?}");
    assert!(close(fix.altitude, ALT_M, 1e-3), "{fix:?}");
    // The same in /fc/truth/state, with the ECEF position (precession and nutation
    // interpolated within the minute: within 1e-6 m).
    let states = on(f.path(), "/fc/truth/state");
    let s: TruthStateMsg = decode(&states[1]);
    assert!(close(s.lat_deg.unwrap(), LAT_DEG, 1e-9));
    assert!(close(s.lon_deg.unwrap(), LON_DEG, 1e-9));
    assert!(close(s.alt_m.unwrap(), ALT_M, 1e-3));
    let want = Geodetic::from_deg(LAT_DEG, LON_DEG, ALT_M).to_ecef_m();
    let off_m = (0..3)
        .map(|i| (s.r_ecef_m[i] - want[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(off_m < 2e-6, "{off_m} m: {s:?}");
    // Sample 1 (7000 km on J2000 +X) is near the equator (the equator of date has moved by
    // precession since J2000, about 0.15 deg in 2026) and 621.863 km up.
    let first: LocationFixMsg = decode(&fixes[0]);
    assert!(first.latitude.abs() < 0.3, "{first:?}");
    assert!(
        close(first.altitude, 7_000_000.0 - 6_378_137.0, 10.0),
        "{first:?}"
    );
}

#[test]
fn state_and_adcs_carry_units_in_their_names() {
    let f = TempFile::new("state");
    record(f.path(), &samples());
    let s: TruthStateMsg = decode(&on(f.path(), "/fc/truth/state")[0]);
    assert_eq!(s.t_ns, 1_000_000_000);
    assert_eq!(o(s.r_eci_m), [Some(7_000_000.0), Some(0.0), Some(0.0)]);
    assert_eq!(o(s.v_eci_m_s), [Some(0.0), Some(7_500.0), Some(0.0)]);
    // The sun is along ECI +Y, which is body +X; the field along Z is the same in both.
    let sun = s.sun_body_unit;
    assert!(
        close32(sun[0], 1.0, 1e-7) && close32(sun[1], 0.0, 1e-7),
        "{sun:?}"
    );
    assert!(close32(s.b_body_nt[2], 30_000.0, 1e-9));
    assert!(close32(s.w_body_deg_s[2], 1.0, 1e-12));
    assert!(close32(s.rate_deg_s.unwrap(), 1.0, 1e-12));
    // 100 rad/s = 100 * 60 / (2 pi) rpm.
    let rpm = 100.0 * 60.0 / std::f64::consts::TAU;
    assert!(close32(s.wheel_speed_rpm[0], rpm, 1e-9));
    assert!(close32(s.wheel_speed_rpm[1], -rpm, 1e-9));
    assert_eq!(o32(s.mtq_dipole_am2), [Some(0.1), Some(-0.2), Some(0.0)]);
    assert_eq!(s.sun_visible_fraction, Some(1.0));
    assert!(close32(s.q_eci_from_body.w.unwrap(), FRAC_1_SQRT_2, 1e-15));

    let adcs = on(f.path(), "/fc/adcs");
    let a: AdcsMsg = decode(&adcs[0]);
    assert_eq!((a.mode_in_effect, a.mode_commanded, a.state), (3, 3, 2));
    assert_eq!(a.q_eci_from_body_est, None);
    let target = a.q_eci_from_body_target.unwrap();
    assert_eq!(
        (target.w, target.x, target.y, target.z),
        (Some(1.0), Some(0.0), Some(0.0), Some(0.0))
    );
    assert_eq!(a.pointing_error_deg, Some(90.0));
    assert_eq!(a.axis_error_deg, Some(12.5));
    assert_eq!(a.estimation_error_deg, None);
    assert_eq!(a.rw_state, [1; 4]);
    assert_eq!(
        o32(a.wheel_torque_cmd_nm),
        [Some(1e-4), Some(0.0), Some(-1e-4), Some(0.0)]
    );
    let raw = text(&adcs[0]);
    assert!(raw.contains("\"q_eci_from_body_est\":null"), "{raw}");
    // The project's quaternions are scalar first: w, x, y, z.
    assert!(
        raw.contains("\"q_eci_from_body_target\":{\"w\":1.0,\"x\":0.0,\"y\":0.0,\"z\":0.0}"),
        "{raw}"
    );
    let a: AdcsMsg = decode(&adcs[1]);
    assert!(a.q_eci_from_body_est.is_some());
    assert_eq!(a.estimation_error_deg, Some(0.25));
}

#[test]
fn non_finite_numbers_are_null_and_foxglove_messages_with_them_are_left_out() {
    let f = TempFile::new("nan");
    record(f.path(), &samples());
    for topic in ["/fc/truth/state", "/fc/adcs", "/fc/scene"] {
        for m in on(f.path(), topic) {
            let raw = text(&m);
            assert!(
                serde_json::from_str::<Value>(&raw).is_ok(),
                "{topic}: {raw}"
            );
            for bad in ["NaN", "nan", "inf", "Infinity"] {
                assert!(!raw.contains(bad), "{topic}: {raw}");
            }
        }
    }
    let states = on(f.path(), "/fc/truth/state");
    let s: TruthStateMsg = decode(&states[2]);
    assert_eq!(o(s.r_eci_m), [None, Some(7_000_000.0), Some(0.0)]);
    assert_eq!((s.lat_deg, s.lon_deg, s.alt_m), (None, None, None));
    assert_eq!(s.q_eci_from_body.w, None);
    assert!(s.w_body_deg_s[0].is_nan());
    assert_eq!(s.rate_deg_s, None);
    assert_eq!(o32(s.sun_body_unit), [None, None, None]);
    let raw = text(&states[2]);
    assert!(raw.contains("\"r_eci_m\":[null,7000000.0,0.0]"), "{raw}");
    assert!(raw.contains("\"lat_deg\":null"), "{raw}");

    let a: AdcsMsg = decode(&on(f.path(), "/fc/adcs")[2]);
    assert_eq!(a.pointing_error_deg, None);
    let est = a.q_eci_from_body_est.unwrap();
    assert_eq!((est.w, est.x, est.y, est.z), (None, None, None, None));
    assert!(a.wheel_torque_cmd_nm[0].is_nan());

    // The scene keeps the box and the body axes; the sun and nadir arrows need the
    // attitude.
    let scene: SceneUpdateMsg = decode(&on(f.path(), "/fc/scene")[2]);
    assert_eq!(scene.entities[0].arrows.len(), 3);
    assert_eq!(scene.entities[0].cubes.len(), 1);
}

#[test]
fn scene_draws_the_body_its_axes_and_the_sun_and_nadir_in_body() {
    let f = TempFile::new("scene");
    record(f.path(), &samples());
    let scenes = on(f.path(), "/fc/scene");
    assert_eq!(scenes[0].log_time, START_NS + 1_000_000_000);
    let u: SceneUpdateMsg = decode(&scenes[0]);
    assert!(u.deletions.is_empty());
    assert_eq!(u.entities.len(), 1);
    let e = &u.entities[0];
    assert_eq!((e.frame_id.as_str(), e.id.as_str()), ("body", "m6p"));
    assert!(e.frame_locked);
    assert_eq!((e.lifetime.sec, e.lifetime.nsec), (0, 0));
    let size = e.cubes[0].size;
    assert_eq!((size.x, size.y, size.z), (0.2, 0.1, 0.3));
    assert_eq!(e.arrows.len(), 5);
    let dir = |i: usize| {
        let q = e.arrows[i].pose.orientation;
        rotate([q.x, q.y, q.z, q.w], [1.0, 0.0, 0.0])
    };
    let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| close(a[i], b[i], 1e-12));
    // X red, Y green, Z blue.
    assert!(near(dir(0), [1.0, 0.0, 0.0]) && e.arrows[0].color.r == 1.0);
    assert!(near(dir(1), [0.0, 1.0, 0.0]) && e.arrows[1].color.g > 0.5);
    assert!(near(dir(2), [0.0, 0.0, 1.0]) && e.arrows[2].color.b == 1.0);
    // Sun along ECI +Y = body +X; nadir along ECI -X = body +Y.
    assert!(near(dir(3), [1.0, 0.0, 0.0]), "{:?}", dir(3));
    assert!(near(dir(4), [0.0, 1.0, 0.0]), "{:?}", dir(4));
    // The primitives Foxglove's schema requires are there, empty.
    let raw: Value = scenes[0].json().unwrap();
    for k in [
        "spheres",
        "cylinders",
        "lines",
        "triangles",
        "texts",
        "models",
        "metadata",
    ] {
        assert_eq!(raw["entities"][0][k], Value::Array(vec![]), "{k}");
    }
}

#[test]
fn the_same_truth_samples_give_byte_identical_files() {
    let ev = samples();
    let (a, b) = (TempFile::new("det-a"), TempFile::new("det-b"));
    let sa = record(a.path(), &ev);
    let sb = record(b.path(), &ev);
    assert_eq!(sa, sb);
    let (ba, bb) = (
        std::fs::read(a.path()).unwrap(),
        std::fs::read(b.path()).unwrap(),
    );
    assert!(ba == bb, "two recordings of the same truth samples differ");
    // A different sample gives a different file (the comparison can fail).
    let mut other = samples();
    if let RunEvent::Truth { adcs, .. } = &mut other[0] {
        adcs.pointing_error_deg = Some(89.0);
    }
    let c = TempFile::new("det-c");
    record(c.path(), &other);
    assert!(std::fs::read(c.path()).unwrap() != ba);
    // `diff` compares the media only: no medium messages here, so identical.
    assert_eq!(
        recording::diff(a.path(), c.path()).unwrap(),
        DiffResult::Identical { messages: 0 }
    );
}

#[test]
fn csv_gives_a_column_per_vector_component_and_summary_shows_the_end() {
    let f = TempFile::new("csv");
    record(f.path(), &samples());
    let mut out = Vec::new();
    let rows = recording::export_csv(f.path(), "/fc/truth/state", &mut out).unwrap();
    assert_eq!(rows, 3);
    let text = String::from_utf8(out).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(
        lines[0].starts_with(
            "log_time_ns,t_ns,q_eci_from_body.w,q_eci_from_body.x,q_eci_from_body.y,\
             q_eci_from_body.z,r_eci_m[0],r_eci_m[1],r_eci_m[2],v_eci_m_s[0]"
        ),
        "{}",
        lines[0]
    );
    assert!(
        lines[0].ends_with(
            "wheel_speed_rpm[0],wheel_speed_rpm[1],wheel_speed_rpm[2],wheel_speed_rpm[3],\
             mtq_dipole_am2[0],mtq_dipole_am2[1],mtq_dipole_am2[2]"
        ),
        "{}",
        lines[0]
    );
    // Row 1: 7000 km on X; row 3: NaN on X is an empty cell.
    let cols: Vec<&str> = lines[0].split(',').collect();
    let col = |name: &str| cols.iter().position(|c| *c == name).unwrap();
    let cell = |row: usize, name: &str| lines[row].split(',').nth(col(name)).unwrap();
    assert_eq!(cell(1, "r_eci_m[0]"), "7000000");
    assert_eq!(cell(3, "r_eci_m[0]"), "");
    assert_eq!(cell(3, "r_eci_m[1]"), "7000000");
    assert_eq!(cell(1, "mtq_dipole_am2[1]"), "-0.2");

    // /fc/adcs: the estimate is null at first, an object later: its fields are columns.
    let mut out = Vec::new();
    recording::export_csv(f.path(), "/fc/adcs", &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    let header = text.lines().next().unwrap();
    assert!(
        header.contains(
            "state,q_eci_from_body_est.w,q_eci_from_body_est.x,q_eci_from_body_est.y,\
             q_eci_from_body_est.z,w_body_deg_s_est[0]"
        ),
        "{header}"
    );

    let s = recording::read_summary(f.path()).unwrap();
    assert_eq!(s.count("/fc/truth/state"), 3);
    assert_eq!(s.adcs_last.as_ref().map(|a| a.t_ns), Some(3_000_000_000));
    let truth = s.truth_last.as_ref().unwrap();
    assert_eq!(truth.t_ns, 3_000_000_000);
    let shown = s.to_string();
    eprintln!("{shown}");
    assert!(
        shown.contains("FC truth at the end (t = 3.000000000 s)"),
        "{shown}"
    );
    assert!(
        shown.contains("ADCS at the end: mode 1 (commanded 1), state 1; pointing error - deg"),
        "{shown}"
    );
    assert!(shown.contains("/fc/scene"), "{shown}");
}

/// Decode a truth recording with the `mcap` Python package (`tests/decode_mcap.py`, which
/// also checks the `/fc` channels: frames, unit quaternions, latitude and longitude ranges).
/// Ignored where the package is missing; fails under `CI` (see `build.rs`).
#[test]
#[cfg_attr(
    not(python_mcap),
    ignore = "needs python3 with the `mcap` package (pip install mcap; .ci/run installs it)"
)]
fn python_mcap_package_decodes_the_truth_channels() {
    let f = TempFile::new("python");
    record(f.path(), &samples());
    let stdout = common::decode(f.path());
    assert!(stdout.contains("/fc/truth/tf 2"), "{stdout}");
    assert!(stdout.contains("/fc/scene 3"), "{stdout}");
    assert!(stdout.contains("truth samples checked: 3"), "{stdout}");
    assert!(stdout.ends_with("ok\n"), "{stdout}");
}

/// Every panel of `docs/foxglove-layout.json` exists in its `configById`, and every message
/// path it plots or shows names a recorded channel and, for the `/fc` channels, a field that
/// the recorded messages have (`wheel_speed_rpm[3]`, `pointing_error_deg`, ...).
#[test]
fn the_foxglove_layout_names_recorded_topics_and_fields() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/foxglove-layout.json");
    let layout: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let configs = layout["configById"].as_object().unwrap();

    // Panel ids in the split trees (the top level and the tabs).
    fn panels(tree: &Value, out: &mut Vec<String>) {
        match tree {
            Value::String(id) => out.push(id.clone()),
            Value::Object(o) => {
                for k in ["first", "second"] {
                    if let Some(v) = o.get(k) {
                        panels(v, out);
                    }
                }
            }
            _ => {}
        }
    }
    let mut ids = Vec::new();
    panels(&layout["layout"], &mut ids);
    for c in configs.values() {
        for tab in c
            .get("tabs")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            panels(&tab["layout"], &mut ids);
        }
    }
    for id in &ids {
        assert!(configs.contains_key(id), "panel {id} has no config");
    }
    for id in [
        "3D!attitude",
        "map!track",
        "Plot!pointing",
        "Plot!wheels",
        "StateTransitions!pc",
        "Plot!downlink",
        "Plot!eps_power",
        "Plot!eps_battery",
        "Plot!tmgen_mode",
    ] {
        assert!(
            ids.iter().any(|i| i == id),
            "{id} is not placed in the layout"
        );
    }

    // Message paths.
    fn paths(v: &Value, out: &mut Vec<String>) {
        match v {
            Value::Object(o) => {
                for (k, v) in o {
                    match (k.as_str(), v) {
                        (
                            "value" | "topicPath" | "followTopic" | "topicToRender",
                            Value::String(s),
                        ) => out.push(s.clone()),
                        ("topics", Value::Object(t)) => out.extend(t.keys().cloned()),
                        _ => paths(v, out),
                    }
                }
            }
            Value::Array(a) => a.iter().for_each(|v| paths(v, out)),
            _ => {}
        }
    }
    let mut used = Vec::new();
    paths(&layout["configById"], &mut used);

    let f = TempFile::new("layout");
    let stats = record(f.path(), &samples());
    let mut fc_fields = 0;
    let mut decoded = 0;
    for p in &used {
        let (topic, field) = p.split_once('.').unwrap_or((p, ""));
        // A filter on the decoded packets (`/csp/packets{icd=="PC.TMPC"}...{name=="x"}`):
        // the command and the field must be the ICD's.
        let (topic, filters) = topic.split_once('{').unwrap_or((topic, ""));
        if !filters.is_empty() {
            let quoted = |key: &str| -> Option<String> {
                let at = p.find(&format!("{{{key}==\""))? + key.len() + 4;
                Some(p[at..].split('"').next()?.to_owned())
            };
            let (icd, name) = (quoted("icd").unwrap(), quoted("name").unwrap());
            let (_, _, c) = m6p_twin::icd::find_command(&icd).unwrap();
            let (fields, _) = c.reply.parts().unwrap();
            assert!(
                csp::icd::leaves(fields)
                    .iter()
                    .any(|(path, _)| *path == name),
                "layout path {p}: {icd}'s reply has no field {name}"
            );
            decoded += 1;
        }
        // A channel of these samples, or one of the recording's fixed topics (the PC's
        // and the EPS's, which these samples do not have).
        assert!(
            stats.channels.iter().any(|c| c.topic == topic)
                || m6p_twin::record::CHANNEL_KINDS
                    .iter()
                    .any(|k| k.topic("") == topic),
            "layout path {p}: no channel {topic}"
        );
        if !topic.starts_with("/fc/") || field.is_empty() {
            continue;
        }
        let msg: Value = on(f.path(), topic)[0].json().unwrap();
        let mut at = &msg;
        for part in field.split('.') {
            let (name, index) = match part.split_once('[') {
                Some((n, i)) => (n, Some(i.trim_end_matches(']').parse::<usize>().unwrap())),
                None => (part, None),
            };
            at = at
                .get(name)
                .unwrap_or_else(|| panic!("layout path {p}: no field {name}"));
            if let Some(i) = index {
                at = at
                    .get(i)
                    .unwrap_or_else(|| panic!("layout path {p}: no element {i}"));
            }
        }
        fc_fields += 1;
    }
    assert!(fc_fields >= 8, "{used:?}");
    assert!(decoded >= 2, "{used:?}");
}
