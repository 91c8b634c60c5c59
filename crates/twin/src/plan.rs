//! From a validated [`Scenario`] to what the runtime executes: run options, the ground
//! stations' request plans, the fault timeline, and the expectations to check.

use std::time::Duration;

use bus::ClockMode;
use bus::impair::Impairments;
use csp::SimTime;

use crate::ground::PlannedRequest;
use crate::runtime::RunOptions;
use crate::scenario::{
    ExpectKind, ExpectationSpec, FaultKind, LinkKind, NodeRef, Occurrence, RequestKind, Scenario,
    parse_hex,
};

/// A medium a fault applies to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MediumId {
    /// Main CAN bus.
    Main,
    /// Payload CAN bus.
    Payload,
    /// The UHF air channel of the ground segment.
    Uhf,
}

/// One change the fault director applies at a time. `fault` is the scenario fault's index:
/// faults on one medium or node compose, and each start or end changes only its own part.
#[derive(Debug, Clone, PartialEq)]
pub enum FaultAction {
    /// Fault `fault` starts impairing a medium (`Some`) or is lifted (`None`).
    Impair {
        /// The medium.
        medium: MediumId,
        /// The fault.
        fault: u32,
        /// Its impairments while active.
        imp: Option<Impairments>,
    },
    /// Power fault `fault` holds node `addr` off (`off`) or releases it.
    Power {
        /// The node.
        addr: u8,
        /// The fault.
        fault: u32,
        /// Held off or released.
        off: bool,
    },
    /// Node reboot.
    Reboot(u8),
    /// Hang fault `fault` starts (`hung`) or ends on node `addr`.
    Hang {
        /// The node.
        addr: u8,
        /// The fault.
        fault: u32,
        /// Hung or recovered.
        hung: bool,
    },
    /// A fault the FC applies itself from its timeline (sensors, wheels): recorded only.
    Fc,
    /// The UHF link's contact with the ground (a pass begins or ends).
    Contact(bool),
}

/// A fault action at a time, with a description for logs and recordings.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedFault {
    /// When.
    pub at: SimTime,
    /// What.
    pub action: FaultAction,
    /// Human-readable, for example `faults[0]: drop 0.5 on main`.
    pub what: String,
}

/// What an expectation checks, resolved.
#[derive(Debug, Clone, PartialEq)]
pub enum Check {
    /// Every (or any) occurrence of a command is answered as required.
    Reply {
        /// Command name.
        command: String,
        /// Every or any.
        occurrence: Occurrence,
        /// Longest round trip.
        within: Option<Duration>,
        /// Result code (reply byte 1).
        result: Option<u8>,
        /// The reply bytes (`??` any byte, a final `...` any further bytes).
        data: Option<crate::scenario::ReplyPattern>,
        /// Reply length.
        data_len: Option<usize>,
    },
    /// Every (or any) occurrence goes unanswered.
    NoReply {
        /// Command name.
        command: String,
        /// Every or any.
        occurrence: Occurrence,
    },
    /// Every FC snapshot in a window has a figure within bounds.
    Attitude {
        /// The figure (`scenario::ATTITUDE_QUANTITIES`).
        quantity: String,
        /// Every selected sample (default) or at least one must be within bounds.
        occurrence: Occurrence,
        /// Upper bound (exclusive).
        below: Option<f64>,
        /// Lower bound (exclusive).
        above: Option<f64>,
        /// Window start.
        from: SimTime,
        /// Window end (default: the end of the run).
        to: Option<SimTime>,
        /// Which samples count.
        when: crate::scenario::When,
        /// Elevation for `target-visible`, deg.
        min_elevation_deg: f64,
    },
    /// Every (or any) run of a PC session ended with `result`, counting `min`..=`max`
    /// packets.
    Session {
        /// Session id.
        session: u8,
        /// The required result (ICD 3.1.6 value).
        result: Option<u8>,
        /// Every or any run.
        occurrence: Occurrence,
        /// Fewest packets counted.
        min: Option<u64>,
        /// Most packets counted.
        max: Option<u64>,
    },
    /// A PC session's bytes at the ground over the whole run.
    Downlink {
        /// Session id.
        session: u8,
        /// Fewest bytes.
        min: Option<u64>,
        /// Most bytes.
        max: Option<u64>,
        /// The counter-stream check: `Some(false)` no damaged frame, `Some(true)` also no
        /// missing sequence number.
        intact: Option<bool>,
    },
    /// Every byte a payload produced is downlinked, dropped with a reason, or held.
    Accounting {
        /// One payload, or every simulated one.
        payload: Option<u8>,
        /// Most dropped bytes.
        max: Option<u64>,
    },
    /// EPS samples in a window within bounds.
    Power {
        /// The figure (`scenario::POWER_QUANTITIES`).
        quantity: String,
        /// Each sample, or the window's mean, min or max.
        statistic: crate::scenario::Statistic,
        /// Upper bound (exclusive).
        below: Option<f64>,
        /// Lower bound (exclusive).
        above: Option<f64>,
        /// Window start.
        from: SimTime,
        /// Window end (default: the end of the run).
        to: Option<SimTime>,
        /// `always`, `sunlit` (array power above zero) or `eclipse` (none).
        when: crate::scenario::When,
    },
    /// Beacons on the ground (from one COMM, in a window): every `within` during contact,
    /// `min`..=`max` in all.
    Beacon {
        /// Longest gap in contact (from acquisition, between beacons, to loss).
        within: Option<Duration>,
        /// Fewest beacons.
        min: Option<u64>,
        /// Most beacons.
        max: Option<u64>,
        /// Only beacons from this CSP address (COMM1 or COMM2); `None`: either.
        sender: Option<u8>,
        /// Window start.
        from: SimTime,
        /// Window end (default: the end of the run).
        to: Option<SimTime>,
    },
    /// A counter at the end of the run.
    Counter {
        /// Node address, or a medium name (`main`, `payload`, `ground`).
        target: CounterTarget,
        /// Counter name.
        counter: String,
        /// Lower bound.
        min: Option<u64>,
        /// Upper bound.
        max: Option<u64>,
    },
}

/// Where a counter lives.

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CounterTarget {
    /// A node.
    Node(u8),
    /// A medium.
    Medium(String),
}

/// A named expectation.
#[derive(Debug, Clone, PartialEq)]
pub struct Expectation {
    /// Its name.
    pub name: String,
    /// What it checks.
    pub check: Check,
}

/// Everything a scenario turns into.
#[derive(Debug, Clone)]
pub struct Compiled {
    /// The run.
    pub opts: RunOptions,
    /// Fault timeline, in time order.
    pub faults: Vec<TimedFault>,
    /// Expectations, in file order.
    pub expectations: Vec<Expectation>,
}

/// Compile a validated scenario.
pub fn compile(s: &Scenario) -> Compiled {
    let net = s.network_spec_unchecked();
    let mut opts = RunOptions::new(net.clone(), s.duration.0);
    opts.seed = s.seed;
    opts.clock = match s.clock.mode {
        crate::scenario::ClockKind::Virtual => ClockMode::Virtual,
        crate::scenario::ClockKind::Realtime => ClockMode::Realtime {
            speed: s.clock.speed,
        },
    };
    opts.epoch_unix_s =
        crate::timefmt::parse_utc(&s.start).map_or(0, |ns| ns.div_euclid(1_000_000_000)) as u64;
    // The last two lines are the elements (a title line may come first).
    if let [.., l1, l2] = s.satellite.tle.as_slice() {
        opts.tle = Some((l1.clone(), l2.clone()));
    }
    for l in &s.links {
        match l.kind {
            LinkKind::KissListen => opts
                .kiss_listen
                .extend(l.addr.parse::<std::net::SocketAddr>().ok()),
            LinkKind::KissConnect => opts
                .kiss_connect
                .extend(l.addr.parse::<std::net::SocketAddr>().ok()),
            LinkKind::Socketcan => {
                if let Ok(link) = crate::runtime::SocketCanBus::parse_arg(&l.addr) {
                    opts.socketcan.push(link);
                }
            }
        }
        opts.kiss.addrs.extend(&l.addrs);
        opts.kiss.decoder.libcsp14_rx_limit |= l.libcsp14_rx_limit;
    }
    if opts.has_outside_links() && opts.clock == ClockMode::Virtual {
        opts.clock = ClockMode::Realtime { speed: 1.0 };
    }
    let default_gs = net
        .nodes
        .iter()
        .find(|n| n.role == crate::network::Role::Ground)
        .map(|n| n.addr);
    for (i, c) in s.commands.iter().enumerate() {
        let name = c.name.clone().unwrap_or_else(|| format!("commands[{i}]"));
        let from = c
            .from
            .as_ref()
            .and_then(|r| net.resolve(r).ok())
            .or(default_gs)
            .unwrap_or(16);
        let to = match &c.to {
            NodeRef::Addr(a) => *a,
            r => net.resolve(r).unwrap_or(0),
        };
        let (dport, data) = match c.request {
            RequestKind::Ping => (1, crate::ground::ping_payload(c.size.unwrap_or(16))),
            RequestKind::Uptime => (6, vec![]),
            RequestKind::Ident => (0, vec![0x00, 0x01]),
            RequestKind::Memfree => (3, vec![]),
            RequestKind::BufFree => (5, vec![]),
            RequestKind::Ps => (2, vec![]),
            RequestKind::Reboot => (4, csp::service::REBOOT_MAGIC.to_be_bytes().to_vec()),
            RequestKind::Raw => (
                c.port.unwrap_or(0),
                match &c.text {
                    Some(t) => t.as_bytes().to_vec(),
                    None => c
                        .data
                        .as_deref()
                        .map(parse_hex)
                        .and_then(Result::ok)
                        .unwrap_or_default(),
                },
            ),
        };
        let timeout = c.timeout.map_or(Duration::from_secs(5), |d| d.0);
        let every = c.every.map_or(Duration::ZERO, |d| d.0);
        let plan = opts.ground_plan.entry(from).or_default();
        for k in 0..c.count.unwrap_or(1) {
            plan.push(PlannedRequest {
                at: SimTime::ZERO + c.at.0 + every * k,
                dst: to,
                dport,
                data: data.clone(),
                timeout,
                label: name.clone(),
                after: c.after.clone(),
            });
        }
    }
    let mut faults = Vec::new();
    for (i, f) in s.faults.iter().enumerate() {
        let at = SimTime::ZERO + f.at.0;
        let until = f.until.map(|u| SimTime::ZERO + u.0);
        let medium = match &f.target {
            NodeRef::Name(n) if n == "main" => Some(MediumId::Main),
            NodeRef::Name(n) if n == "payload" => Some(MediumId::Payload),
            NodeRef::Name(n) if n == "uhf" => Some(MediumId::Uhf),
            _ => None,
        };
        let node = net.resolve(&f.target).ok();
        let what = format!("faults[{i}]: {:?} on {}", f.kind, f.target);
        let mut push = |t: SimTime, action: FaultAction, suffix: &str| {
            faults.push(TimedFault {
                at: t,
                action,
                what: format!("{what}{suffix}"),
            });
        };
        match (f.kind, medium, node) {
            (
                FaultKind::Drop | FaultKind::Corrupt | FaultKind::Delay | FaultKind::LinkDown,
                Some(m),
                _,
            ) => {
                let imp = match f.kind {
                    FaultKind::Drop => Impairments {
                        drop_prob: f.probability.unwrap_or(0.0),
                        ..Default::default()
                    },
                    FaultKind::Corrupt => Impairments {
                        corrupt_prob: f.probability.unwrap_or(0.0),
                        ..Default::default()
                    },
                    FaultKind::Delay => Impairments {
                        delay: f.delay.map_or(Duration::ZERO, |d| d.0),
                        ..Default::default()
                    },
                    _ => Impairments {
                        down: true,
                        ..Default::default()
                    },
                };
                let fault = i as u32;
                push(
                    at,
                    FaultAction::Impair {
                        medium: m,
                        fault,
                        imp: Some(imp),
                    },
                    "",
                );
                if let Some(u) = until {
                    push(
                        u,
                        FaultAction::Impair {
                            medium: m,
                            fault,
                            imp: None,
                        },
                        " (lifted)",
                    );
                }
            }
            (FaultKind::PowerOff, _, Some(addr)) => {
                let fault = i as u32;
                push(
                    at,
                    FaultAction::Power {
                        addr,
                        fault,
                        off: true,
                    },
                    "",
                );
                if let Some(u) = until {
                    push(
                        u,
                        FaultAction::Power {
                            addr,
                            fault,
                            off: false,
                        },
                        " (power on)",
                    );
                }
            }
            (FaultKind::Reboot, _, Some(a)) => push(at, FaultAction::Reboot(a), ""),
            (FaultKind::Hang, _, Some(addr)) => {
                let fault = i as u32;
                push(
                    at,
                    FaultAction::Hang {
                        addr,
                        fault,
                        hung: true,
                    },
                    "",
                );
                if let Some(u) = until {
                    push(
                        u,
                        FaultAction::Hang {
                            addr,
                            fault,
                            hung: false,
                        },
                        " (recovered)",
                    );
                }
            }
            _ => {}
        }
    }
    opts.fc = compile_fc(s, &mut faults);
    faults.extend(compile_passes(s, opts.epoch_unix_s));
    opts.eps = compile_eps(s);
    opts.comm = compile_comm(s);
    opts.pc = crate::sessions::compile_pc(s);
    opts.payloads = crate::sessions::compile_payloads(s);
    for p in opts.payloads.values_mut() {
        if let Some(push) = p.push.as_mut() {
            push.pc_port = opts.pc.ingest_port;
        }
    }
    faults.sort_by_key(|f| f.at);
    opts.faults = faults.clone();
    let expectations = s
        .expectations
        .iter()
        .enumerate()
        .map(|(i, x)| compile_expectation(i, x, &net))
        .collect();
    Compiled {
        opts,
        faults,
        expectations,
    }
}

/// A unit vector drawn from `seed` (uniform on the sphere).
fn random_unit(seed: u64, salt: u64) -> nalgebra::Vector3<f64> {
    let u = |k: u64| (crate::runtime::mix(seed, salt + k) >> 11) as f64 / (1u64 << 53) as f64;
    let z = 2.0 * u(0) - 1.0;
    let phi = std::f64::consts::TAU * u(1);
    let r = (1.0 - z * z).max(0.0).sqrt();
    nalgebra::Vector3::new(r * phi.cos(), r * phi.sin(), z)
}

/// A rotation drawn uniformly from SO(3) (Shoemake, "Uniform random rotations", Graphics
/// Gems III, 1992): three uniforms from the seed.
fn random_rotation(seed: u64, salt: u64) -> nalgebra::UnitQuaternion<f64> {
    let u = |k: u64| (crate::runtime::mix(seed, salt + k) >> 11) as f64 / (1u64 << 53) as f64;
    let (u1, u2, u3) = (u(0), u(1), u(2));
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let tau = std::f64::consts::TAU;
    nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        b * (tau * u3).cos(),
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
    ))
}

/// The FC's configuration from the `[fc]` table (validated), its faults added to the
/// recorded fault timeline.
fn compile_fc(s: &Scenario, faults: &mut Vec<TimedFault>) -> nodes_fc::FcConfig {
    use nalgebra::{Quaternion, UnitQuaternion, Vector3};
    use nodes_fc::{FcEvent, TimedFcEvent};
    let f = &s.fc;
    let mut c = nodes_fc::FcConfig::default();
    if let Some(h) = f.adcs_hz {
        c.adcs_hz = h;
    }
    if let Some(h) = f.publish_hz {
        c.publish_hz = h;
    }
    if let Some(m) = f.mode {
        c.initial_mode = m.mode();
    }
    if let Some(q) = f.target_attitude {
        let n = (q.iter().map(|x| x * x).sum::<f64>()).sqrt();
        c.initial_target_attitude = Some(q.map(|x| x / n));
    }
    c.initial_target_point = f.target_point;
    c.tle_uploaded = f.tle_uploaded.unwrap_or(true);
    c.sensors.gps_enabled = f.gps.unwrap_or(false);
    let axis = f
        .initial_rate_axis
        .map(|a| Vector3::from(a).normalize())
        .unwrap_or_else(|| random_unit(s.seed, 0x310));
    c.initial.w_body_rad_s = axis * f.initial_rate_deg_s.unwrap_or(0.0).to_radians();
    c.initial.q_eci_from_body = match f.initial_attitude {
        Some([r, i, j, k]) => UnitQuaternion::from_quaternion(Quaternion::new(r, i, j, k)),
        None => random_rotation(s.seed, 0x320),
    };
    if let Some(rpm) = f.initial_wheel_rpm {
        c.initial.wheel_speed_rad_s = rpm.map(|r| r * std::f64::consts::TAU / 60.0);
    }
    if let Some(m) = f.inertia_kg_m2 {
        c.body.inertia_kg_m2 = nalgebra::Matrix3::from_fn(|r, k| m[r][k]);
        // The gains follow the body (and the orbit's rate), as the default's do.
        let n_rad_s = match s.satellite.tle.as_slice() {
            [.., l1, l2] => orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict)
                .map(|t| t.mean_motion_rev_day * std::f64::consts::TAU / 86_400.0)
                .unwrap_or(nodes_fc::control::DEFAULT_MEAN_MOTION_RAD_S),
            _ => nodes_fc::control::DEFAULT_MEAN_MOTION_RAD_S,
        };
        c.adcs.control = nodes_fc::control::ControlConfig::for_body(&c.body, n_rad_s);
    }
    if let Some(d) = f.residual_dipole_am2 {
        c.residual_dipole_am2 = Vector3::from(d);
    }
    if f.drag == Some(false) {
        c.drag = None;
    }
    if let Some(g) = f.gravity_gradient {
        c.gravity_gradient = g;
    }
    if let Some(n) = f.panel_normal_body {
        c.adcs.panel_normal_body = Vector3::from(n).normalize();
    }
    if let Some(p) = f.ports {
        let d = nodes_fc::FcPorts::default();
        c.ports = nodes_fc::FcPorts {
            telemetry: p.telemetry.unwrap_or(d.telemetry),
            rtc: p.rtc.unwrap_or(d.rtc),
            attitude: p.attitude.unwrap_or(d.attitude),
            scripts: p.scripts.unwrap_or(d.scripts),
        };
    }
    for sc in &f.scripts {
        c.timeline.push(TimedFcEvent {
            at: SimTime::ZERO + sc.at.0,
            event: FcEvent::Script(sc.line.clone()),
        });
    }
    for (i, fault) in f.faults.iter().enumerate() {
        let (set, clear) = match (&fault.sensor, fault.wheel) {
            (Some(name), _) => {
                let (Ok(id), Ok(kind)) = (
                    name.parse::<nodes_fc::sensors::SensorId>(),
                    fault.fault.parse::<nodes_fc::sensors::SensorFault>(),
                ) else {
                    continue;
                };
                (FcEvent::Sensor(id, Some(kind)), FcEvent::Sensor(id, None))
            }
            (None, Some(w)) => {
                let Ok(kind) = fault.fault.parse::<nodes_fc::WheelFault>() else {
                    continue;
                };
                (
                    FcEvent::Wheel(usize::from(w), Some(kind)),
                    FcEvent::Wheel(usize::from(w), None),
                )
            }
            (None, None) => continue,
        };
        let what = match (&fault.sensor, fault.wheel) {
            (Some(n), _) => format!("fc.faults[{i}]: {n} {}", fault.fault),
            _ => format!(
                "fc.faults[{i}]: wheel {} {}",
                fault.wheel.unwrap_or(0),
                fault.fault
            ),
        };
        let at = SimTime::ZERO + fault.at.0;
        c.timeline.push(TimedFcEvent { at, event: set });
        faults.push(TimedFault {
            at,
            action: FaultAction::Fc,
            what: what.clone(),
        });
        if let Some(u) = fault.until {
            let until = SimTime::ZERO + u.0;
            c.timeline.push(TimedFcEvent {
                at: until,
                event: clear,
            });
            faults.push(TimedFault {
                at: until,
                action: FaultAction::Fc,
                what: format!("{what} (cleared)"),
            });
        }
    }
    c
}

fn compile_expectation(
    i: usize,
    x: &ExpectationSpec,
    net: &crate::network::NetworkSpec,
) -> Expectation {
    let name = x
        .name
        .clone()
        .unwrap_or_else(|| format!("expectations[{i}]"));
    let occurrence = x.occurrence.unwrap_or(Occurrence::Every);
    let command = x.command.clone().unwrap_or_default();
    let check = match x.kind {
        ExpectKind::Reply => Check::Reply {
            command,
            occurrence,
            within: x.within.map(|d| d.0),
            result: x.result,
            data: x
                .data
                .as_deref()
                .and_then(|d| crate::scenario::ReplyPattern::parse(d).ok()),
            data_len: x.data_len,
        },
        ExpectKind::NoReply => Check::NoReply {
            command,
            occurrence,
        },
        ExpectKind::Attitude => Check::Attitude {
            quantity: x.quantity.clone().unwrap_or_default(),
            occurrence,
            below: x.below,
            above: x.above,
            from: x.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0),
            to: x.to.map(|d| SimTime::ZERO + d.0),
            when: x.when.unwrap_or(crate::scenario::When::Always),
            min_elevation_deg: x.min_elevation_deg.unwrap_or(10.0),
        },
        ExpectKind::Session => Check::Session {
            session: x.session.unwrap_or(0),
            result: x.session_result.map(|r| r.value()),
            occurrence,
            min: x.min,
            max: x.max,
        },
        ExpectKind::Downlink => Check::Downlink {
            session: x.session.unwrap_or(0),
            min: x.min,
            max: x.max,
            intact: x.intact,
        },
        ExpectKind::Accounting => Check::Accounting {
            payload: x.payload,
            max: x.max,
        },
        ExpectKind::Power => Check::Power {
            quantity: x.quantity.clone().unwrap_or_default(),
            statistic: x.statistic.unwrap_or(crate::scenario::Statistic::Every),
            below: x.below,
            above: x.above,
            from: x.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0),
            to: x.to.map(|d| SimTime::ZERO + d.0),
            when: x.when.unwrap_or(crate::scenario::When::Always),
        },
        ExpectKind::Beacon => Check::Beacon {
            within: x.within.map(|d| d.0),
            min: x.min,
            max: x.max,
            sender: x.target.as_ref().and_then(|r| net.resolve(r).ok()),
            from: x.from.map_or(SimTime::ZERO, |d| SimTime::ZERO + d.0),
            to: x.to.map(|d| SimTime::ZERO + d.0),
        },
        ExpectKind::Counter => Check::Counter {
            target: match &x.target {
                Some(NodeRef::Name(n)) if ["main", "payload", "ground"].contains(&n.as_str()) => {
                    CounterTarget::Medium(n.clone())
                }
                Some(r) => CounterTarget::Node(net.resolve(r).unwrap_or(0)),
                None => CounterTarget::Node(0),
            },
            counter: x.counter.clone().unwrap_or_default(),
            min: x.min,
            max: x.max,
        },
    };
    Expectation { name, check }
}

/// The UHF contact timeline of `[comm] passes = true`: passes over every station above the
/// mask, from the scenario's TLE through `orbit`'s SGP4 and pass prediction, merged; the
/// link is down outside them. Computed before the run from the TLE: a burn during the run
/// (which changes the true orbit slightly) does not move them.
pub fn compile_passes(s: &Scenario, epoch_unix_s: u64) -> Vec<TimedFault> {
    use orbit::passes::{GroundSite, PassOptions, predict_passes_propagator};
    use orbit::propagate::Sgp4Propagator;
    use orbit::time::UtcTime;
    let c = &s.comm;
    if !c.passes {
        return Vec::new();
    }
    let ns = |t: UtcTime| t.unix_ns() - epoch_unix_s as i64 * 1_000_000_000;
    let start = UtcTime::from_unix_ns(epoch_unix_s as i64 * 1_000_000_000);
    let end = UtcTime::from_unix_ns(
        epoch_unix_s as i64 * 1_000_000_000
            + i64::try_from(s.duration.0.as_nanos()).unwrap_or(i64::MAX / 2),
    );
    let mut windows: Vec<(i64, i64, String)> = Vec::new();
    if let [.., l1, l2] = s.satellite.tle.as_slice()
        && let Ok(tle) = orbit::tle::Tle::parse(l1, l2, orbit::tle::ChecksumMode::Strict)
        && let Ok(mut prop) = Sgp4Propagator::new(&tle)
    {
        let opts = PassOptions {
            mask_rad: c.elevation_mask_deg.to_radians(),
            ..PassOptions::default()
        };
        for st in &c.stations {
            let site = GroundSite::from_deg(st.lat_deg, st.lon_deg, st.alt_m);
            if let Ok(passes) = predict_passes_propagator(&site, start, end, &opts, &mut prop, None)
            {
                for p in passes {
                    windows.push((
                        ns(p.rise),
                        ns(p.set),
                        format!(
                            "{} (max {:.1} deg)",
                            st.name,
                            p.max_elevation_rad.to_degrees()
                        ),
                    ));
                }
            }
        }
    }
    windows.sort_by_key(|w| w.0);
    // Merge overlapping windows (two stations in view at once).
    let mut merged: Vec<(i64, i64, String)> = Vec::new();
    for w in windows {
        match merged.last_mut() {
            Some(m) if w.0 <= m.1 => {
                m.1 = m.1.max(w.1);
                m.2 = format!("{} + {}", m.2, w.2);
            }
            _ => merged.push(w),
        }
    }
    let at = |t: i64| SimTime::from_ns(t.max(0) as u64);
    let mut out = Vec::new();
    if merged.first().is_none_or(|m| m.0 > 0) {
        out.push(TimedFault {
            at: SimTime::ZERO,
            action: FaultAction::Contact(false),
            what: "comm: no pass in progress: UHF out of contact".to_owned(),
        });
    }
    for (rise, set, what) in merged {
        out.push(TimedFault {
            at: at(rise),
            action: FaultAction::Contact(true),
            what: format!("comm: pass over {what}: acquisition of signal"),
        });
        out.push(TimedFault {
            at: at(set),
            action: FaultAction::Contact(false),
            what: format!("comm: pass over {what}: loss of signal"),
        });
    }
    out
}

/// The EPS's configuration from the `[eps]` table (validated).
fn compile_eps(s: &Scenario) -> nodes_eps::EpsConfig {
    use nodes_eps::{Channel, EpsEvent, TimedEpsEvent};
    let mut c = nodes_eps::EpsConfig::default();
    let e = &s.eps;
    // A payload the network does not have draws nothing: its channel starts off.
    for addr in 12..=15u8 {
        if !s.network.payloads.contains(&addr)
            && let Some(ch) = Channel::of_node(addr)
        {
            c.channels_on &= !ch.bit();
        }
    }
    if let Some(x) = e.initial_soc {
        c.initial_soc = x;
    }
    for name in &e.channels_off {
        if let Some(ch) = Channel::from_name(name) {
            c.channels_on &= !ch.bit();
        }
    }
    for ev in &e.events {
        let event = match (&ev.channel, ev.on, ev.soc) {
            (Some(name), Some(on), _) => match Channel::from_name(name) {
                Some(channel) => EpsEvent::Channel { channel, on },
                None => continue,
            },
            (_, _, Some(x)) => EpsEvent::SetSoc(x),
            _ => continue,
        };
        c.timeline.push(TimedEpsEvent {
            at: SimTime::ZERO + ev.at.0,
            event,
        });
    }
    c.timeline.sort_by_key(|e| e.at);
    c
}

/// COMM1's configuration from the `[comm]` table (validated).
fn compile_comm(s: &Scenario) -> nodes_comm::CommConfig {
    let c = &s.comm;
    let mut cfg = nodes_comm::CommConfig {
        mask_deg: c.elevation_mask_deg,
        stations: c
            .stations
            .iter()
            .map(|st| nodes_comm::Station {
                name: st.name.clone(),
                lat_deg: st.lat_deg,
                lon_deg: st.lon_deg,
                alt_m: st.alt_m,
            })
            .collect(),
        ..nodes_comm::CommConfig::default()
    };
    if let Some(p) = c.beacon_period {
        cfg.beacon_period = p.0;
    }
    cfg
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    const TLE: &str = r#"
[satellite]
tle = [
  "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996",
  "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009",
]
"#;

    fn fc_of(extra: &str) -> nodes_fc::FcConfig {
        let text = format!("name = \"t\"\nduration = \"1m\"\n{TLE}\n{extra}");
        let s = Scenario::parse("t.toml", &text).unwrap();
        compile(&s).opts.fc
    }

    #[test]
    fn a_scenario_inertia_re_derives_the_control_gains() {
        let default = fc_of("");
        assert_eq!(
            default.adcs.control,
            nodes_fc::control::ControlConfig::default()
        );
        let big = fc_of("[fc]\ninertia_kg_m2 = [[0.4, 0, 0], [0, 0.5, 0], [0, 0, 0.2]]\n");
        let want = nodes_fc::control::ControlConfig::for_body(
            &big.body,
            15.145 * std::f64::consts::TAU / 86_400.0,
        );
        assert_eq!(big.adcs.control, want);
        assert_ne!(big.adcs.control, default.adcs.control);
    }

    #[test]
    fn the_contact_timeline_is_orbits_pass_prediction() {
        use orbit::passes::{GroundSite, PassOptions, predict_passes_propagator};
        let text = format!(
            "name = \"t\"\nstart = \"2026-04-30T18:00:00Z\"\nduration = \"13800s\"\n{TLE}\n[comm]\npasses = true\n"
        );
        let s = Scenario::parse("t.toml", &text).unwrap();
        let c = compile(&s);
        let contact: Vec<(u64, bool)> = c
            .faults
            .iter()
            .filter_map(|f| match f.action {
                FaultAction::Contact(on) => Some((f.at.as_ns(), on)),
                _ => None,
            })
            .collect();
        // Independently: orbit's passes over Vilnius above 10 deg.
        let tle = orbit::tle::Tle::parse(
            s.satellite.tle[0].as_str(),
            s.satellite.tle[1].as_str(),
            orbit::tle::ChecksumMode::Strict,
        )
        .unwrap();
        let mut prop = orbit::propagate::Sgp4Propagator::new(&tle).unwrap();
        let epoch_ns = c.opts.epoch_unix_s as i64 * 1_000_000_000;
        let start = orbit::time::UtcTime::from_unix_ns(epoch_ns);
        let end = orbit::time::UtcTime::from_unix_ns(epoch_ns + 13_800_000_000_000);
        let passes = predict_passes_propagator(
            &GroundSite::from_deg(54.6872, 25.2797, 112.0),
            start,
            end,
            &PassOptions {
                mask_rad: 10f64.to_radians(),
                ..PassOptions::default()
            },
            &mut prop,
            None,
        )
        .unwrap();
        assert_eq!(passes.len(), 2);
        let mut want = vec![(0, false)];
        for p in &passes {
            want.push(((p.rise.unix_ns() - epoch_ns) as u64, true));
            want.push(((p.set.unix_ns() - epoch_ns) as u64, false));
        }
        assert_eq!(contact, want);
        // The second pass of the comm-passes scenario: 13149.9 s to 13587.6 s.
        assert_eq!(contact[3].0 / 100_000_000, 131_499);
        assert_eq!(contact[4].0 / 100_000_000, 135_875);
    }

    #[test]
    fn seeded_initial_attitudes_are_uniform_over_rotations() {
        // For rotations uniform on SO(3) every quaternion component has E[x^2] = 1/4, and
        // the rotation angle has density (1 - cos a) / pi: mean angle pi/2 + 2/pi.
        let n = 4000;
        let mut sq = [0.0f64; 4];
        let mut angle = 0.0;
        for seed in 0..n {
            let q = random_rotation(seed, 0x320);
            for (k, x) in [q.w, q.i, q.j, q.k].into_iter().enumerate() {
                sq[k] += x * x / n as f64;
            }
            angle += q.angle() / n as f64;
        }
        for (k, m) in sq.iter().enumerate() {
            assert!((m - 0.25).abs() < 0.02, "component {k}: E[x^2] = {m}");
        }
        let want = std::f64::consts::FRAC_PI_2 + 2.0 / std::f64::consts::PI;
        assert!(
            (angle - want).abs() < 0.03,
            "mean angle {angle}, want {want}"
        );
    }
}
