//! `m6p-twin bench`: what a simulated span of a scenario costs, measured so that the
//! ratios can be trusted on a loaded machine.
//!
//! Three variants of the same simulated span run interleaved, round by round (the order
//! rotates each round, so no variant always runs first or after the same one):
//! - `plain`: the whole network in virtual time, no recording;
//! - `recorded`: the same, recorded to a temporary MCAP file (removed afterwards);
//! - `adcs_floor`: the FC's core alone (its [`Host`] stepped at its own timers: orbit,
//!   environment, sensors, flight software, the truth's integration), without the network,
//!   the other nodes or publishing. It is the floor a run of the scenario cannot go below.
//!
//! Each run is a process of its own (`m6p-twin` runs itself with a hidden `bench-run`
//! command, [`run_one`]), so that no run inherits the heap an earlier one left behind: it
//! is timed in CPU time (user + system, `getrusage`) and wall time around the run (not the
//! process's start and the scenario's loading), and its peak resident memory is the
//! process's (VmHWM). The report gives medians and spreads (min and max) per variant, the
//! ratios of the medians and the peak memory of each variant.

use std::time::{Duration, Instant};

use csp::SimTime;
use csp::node::{Host, IfaceConfig, NodeConfig};
use csp::router::Route;
use serde::{Deserialize, Serialize};

use crate::exec::{self, Loaded};

/// One variant of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// The whole network, no recording.
    Plain,
    /// The whole network, recorded.
    Recorded,
    /// The FC's core alone.
    AdcsFloor,
}

impl Variant {
    /// Every variant, in the first round's order.
    pub const ALL: [Variant; 3] = [Variant::Plain, Variant::Recorded, Variant::AdcsFloor];

    /// Its name in the report.
    pub fn name(self) -> &'static str {
        match self {
            Variant::Plain => "plain",
            Variant::Recorded => "recorded",
            Variant::AdcsFloor => "adcs_floor",
        }
    }

    /// The variant of a name.
    pub fn from_name(name: &str) -> Option<Variant> {
        Variant::ALL.into_iter().find(|v| v.name() == name)
    }
}

/// One timed run, as the `bench-run` process reports it.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Sample {
    /// CPU seconds (user + system).
    pub cpu_s: f64,
    /// Wall seconds.
    pub wall_s: f64,
    /// Peak resident memory of the run's process, MiB (when the kernel tells it).
    pub peak_rss_mib: Option<f64>,
    /// The recording's bytes (recorded runs).
    pub mcap_bytes: u64,
    /// Its messages.
    pub messages: u64,
    /// CAN frames that crossed each bus, by bus name (what the run's instructions are
    /// counted against: `tools/perf/instructions.py`).
    #[serde(default)]
    pub can_frames: std::collections::BTreeMap<String, u64>,
    /// Packets the ground segment carried.
    #[serde(default)]
    pub ground_packets: u64,
}

/// Median, minimum and maximum of a set of figures.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Spread {
    /// Median (the mean of the two middle figures for an even count).
    pub median: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
}

impl Spread {
    /// Of `xs` (empty: zeros).
    pub fn of(xs: &[f64]) -> Spread {
        let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Spread::default();
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        };
        Spread {
            median,
            min: v[0],
            max: v[n - 1],
        }
    }
}

/// The figures of one variant.
#[derive(Debug, Clone, Serialize)]
pub struct VariantReport {
    /// CPU seconds per run.
    pub cpu_s: Spread,
    /// Wall seconds per run.
    pub wall_s: Spread,
    /// Peak resident memory per run, MiB.
    pub peak_rss_mib: Option<Spread>,
}

/// What `bench` found; `--json` prints it (the flat keys first, for dashboards).
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    /// Median CPU seconds of a plain run.
    pub cpu_s_plain: f64,
    /// Median CPU seconds of a recorded run.
    pub cpu_s_recorded: f64,
    /// Median CPU seconds of the FC's core alone over the same span.
    pub cpu_s_adcs_floor: f64,
    /// Simulated seconds per wall second, plain (median wall time).
    pub rtf_plain: f64,
    /// Simulated seconds per wall second, recorded.
    pub rtf_recorded: f64,
    /// Size of the recording per simulated hour.
    pub mcap_bytes_per_hour: f64,
    /// Recorded messages per simulated hour.
    pub messages_per_hour: f64,
    /// Largest peak resident memory of any run, MiB.
    pub peak_rss_mib: Option<f64>,
    /// `cpu_s_recorded / cpu_s_plain`.
    pub ratio_recorded_plain: f64,
    /// `cpu_s_recorded / cpu_s_adcs_floor`.
    pub ratio_recorded_adcs_floor: f64,
    /// The scenario's name.
    pub scenario: String,
    /// Simulated seconds per run.
    pub duration_s: f64,
    /// Runs per variant.
    pub runs: usize,
    /// The recording of the last recorded run, bytes.
    pub mcap_bytes: u64,
    /// Its messages.
    pub messages: u64,
    /// Per variant (`plain`, `recorded`, `adcs_floor`).
    pub variants: std::collections::BTreeMap<String, VariantReport>,
}

impl BenchReport {
    /// The report as text, for a terminal.
    pub fn text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "scenario `{}`, {} simulated per run, {} runs per variant, interleaved (median [min-max])",
            self.scenario,
            crate::duration::format_duration(Duration::from_secs_f64(self.duration_s)),
            self.runs
        );
        for v in Variant::ALL {
            let Some(r) = self.variants.get(v.name()) else {
                continue;
            };
            let rss = r
                .peak_rss_mib
                .map_or(String::new(), |m| format!(", peak RSS {:.1} MiB", m.max));
            let _ = writeln!(
                s,
                "  {:<11} CPU {:>7.3} s [{:.3}-{:.3}]  wall {:>7.3} s [{:.3}-{:.3}]{rss}",
                v.name(),
                r.cpu_s.median,
                r.cpu_s.min,
                r.cpu_s.max,
                r.wall_s.median,
                r.wall_s.min,
                r.wall_s.max,
            );
        }
        let _ = writeln!(
            s,
            "  recorded / plain CPU: {:.3}; recorded / ADCS floor CPU: {:.3}",
            self.ratio_recorded_plain, self.ratio_recorded_adcs_floor
        );
        let _ = writeln!(
            s,
            "  real-time factor: {:.0}x plain, {:.0}x recorded",
            self.rtf_plain, self.rtf_recorded
        );
        let _ = writeln!(
            s,
            "  MCAP: {} bytes, {} messages per run = {:.0} bytes and {:.0} messages per simulated hour",
            self.mcap_bytes, self.messages, self.mcap_bytes_per_hour, self.messages_per_hour
        );
        s
    }
}

/// CPU seconds (user + system) the process has used so far.
#[cfg(unix)]
fn cpu_now_s() -> f64 {
    use nix::sys::resource::{UsageWho, getrusage};
    getrusage(UsageWho::RUSAGE_SELF).map_or(f64::NAN, |u| {
        let tv = |t: nix::sys::time::TimeVal| t.tv_sec() as f64 + t.tv_usec() as f64 * 1e-6;
        tv(u.user_time()) + tv(u.system_time())
    })
}

/// CPU seconds: not measured off Unix.
#[cfg(not(unix))]
fn cpu_now_s() -> f64 {
    f64::NAN
}

/// The peak resident memory (VmHWM), MiB.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Step the FC's core of `loaded` alone (no network, no publishing) for `duration`;
/// returns the number of timer events it ran.
pub fn adcs_floor(loaded: &Loaded, duration: Duration) -> u64 {
    adcs_floor_host(loaded, duration).1
}

/// [`adcs_floor`], also returning the FC.
fn adcs_floor_host(loaded: &Loaded, duration: Duration) -> (Host<nodes_fc::FcApp>, u64) {
    let compiled = exec::compile_loaded(loaded);
    let mut fc = crate::runtime::fc_config(&compiled.opts);
    fc.publish_hz = 0;
    let mut cfg = NodeConfig::new("FC", 3);
    cfg.ifaces = vec![IfaceConfig::packet("p")];
    cfg.routes.set_default(Route::direct(0));
    cfg.epoch_unix_s = fc.epoch_unix_s;
    let mut host = Host::new(cfg, nodes_fc::FcApp::new(fc), SimTime::ZERO);
    let end = SimTime::ZERO + duration;
    let mut events = 0;
    while let Some(t) = host.poll_timeout().filter(|&t| t < end) {
        host.handle_timeout(t);
        // Nothing is published; anything else the node emits is dropped here.
        while host.poll_event().is_some() {}
        while host.node.poll_transmit().is_some() {}
        events += 1;
    }
    (host, events)
}

/// One run of `variant` over `duration` in this process (recorded to `record`), timed:
/// what the hidden `bench-run` command does and prints.
pub fn run_one(
    loaded: &Loaded,
    duration: Duration,
    variant: Variant,
    record: &std::path::Path,
) -> anyhow::Result<Sample> {
    let cpu0 = cpu_now_s();
    let wall0 = Instant::now();
    let mut stats = None;
    let mut report = None;
    match variant {
        Variant::AdcsFloor => {
            std::hint::black_box(adcs_floor(loaded, duration));
        }
        Variant::Plain | Variant::Recorded => {
            let mut compiled = exec::compile_loaded(loaded);
            compiled.opts.duration = Some(duration);
            compiled.opts.clock = bus::ClockMode::Virtual;
            let rt = crate::runtime::build_runtime_for(&compiled.opts)?;
            // Each round replaces the last round's file.
            let record = (variant == Variant::Recorded).then(|| exec::RecordTo::replacing(record));
            let (outcome, recording) = rt.block_on(exec::execute_recorded_without_files(
                loaded, compiled, record,
            ))?;
            stats = recording.transpose()?;
            report = Some(outcome.report);
        }
    }
    Ok(Sample {
        cpu_s: cpu_now_s() - cpu0,
        wall_s: wall0.elapsed().as_secs_f64(),
        peak_rss_mib: peak_rss_mib(),
        mcap_bytes: stats.as_ref().map_or(0, |s| s.bytes),
        messages: stats.as_ref().map_or(0, |s| s.messages),
        can_frames: report.as_ref().map_or_else(Default::default, |r| {
            r.buses.iter().map(|b| (b.name.clone(), b.frames)).collect()
        }),
        ground_packets: report.as_ref().map_or(0, |r| r.ground.packets),
    })
}

/// Request-reply round trips over timed CAN in virtual time, as the twin runs them: node
/// 16 asks node 3 (the CSP ping service) with a 64-byte payload, each reply sending the
/// next request, on one bus with its own task, each node in its own task. Returns the wall
/// time and the simulated time the `n` round trips took. The network bench and
/// `bench-run --variant round_trips` (counted in instructions by
/// `tools/perf/instructions.py`) run it.
pub fn round_trips(n: u64) -> anyhow::Result<(Duration, SimTime)> {
    use bus::driver::{Attachment, NodeCtl, run_node};
    use bus::{CanBus, CanBusConfig, Clock, ClockMode};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};

    /// Pings node 3 back to back: each reply sends the next request.
    struct PingPong {
        client: csp::client::Client,
        left: u64,
        done: Arc<AtomicU64>,
    }
    impl PingPong {
        fn fire(&mut self, node: &mut csp::node::Node, now: SimTime) {
            if self.left == 0 {
                return;
            }
            self.left -= 1;
            let payload: Vec<u8> = (0..64u8).collect();
            let h = csp::Header::new(node.addr(), 3, 1, 0);
            let _ = self
                .client
                .request(node, 0, h, 3, 1, payload, Duration::from_secs(1), now);
        }
    }
    impl csp::node::App for PingPong {
        type Event = std::convert::Infallible;
        fn start(&mut self, node: &mut csp::node::Node, now: SimTime) {
            self.fire(node, now);
        }
        fn handle_packet(&mut self, node: &mut csp::node::Node, packet: csp::Packet, now: SimTime) {
            if self.client.handle_reply(node, &packet, now).is_some() {
                self.done.fetch_add(1, Ordering::Relaxed);
                self.fire(node, now);
            }
        }
    }
    let node_cfg = |name: &str, addr: u8| {
        let mut c = NodeConfig::new(name, addr);
        c.ifaces = vec![IfaceConfig::can("can")];
        c.routes.set_default(Route::direct(0));
        c
    };
    let rt = crate::runtime::build_virtual_runtime()?;
    Ok(rt.block_on(async move {
        let clock = Clock::new(ClockMode::Virtual);
        let bus = CanBus::new(CanBusConfig::new("bench"), 1);
        let (ta, ra) = bus::inbox::inbox();
        let (tb, rb) = bus::inbox::inbox();
        let pa = bus.attach("A", &[16], false, ta, 0);
        let pb = bus.attach("B", &[3], false, tb, 0);
        tokio::spawn(bus.clone().run(clock));
        let done = Arc::new(AtomicU64::new(0));
        let (ca, cra) = tokio::sync::mpsc::unbounded_channel();
        let (cb, crb) = tokio::sync::mpsc::unbounded_channel();
        let app = PingPong {
            client: csp::client::Client::new(),
            left: n,
            done: done.clone(),
        };
        let a = Host::new(node_cfg("A", 16), app, SimTime::ZERO);
        let b = Host::new(node_cfg("B", 3), csp::node::NoApp, SimTime::ZERO);
        let start = Instant::now();
        let ha = tokio::spawn(run_node(a, vec![Attachment::Can(pa)], ra, cra, clock));
        let hb = tokio::spawn(run_node(b, vec![Attachment::Can(pb)], rb, crb, clock));
        while done.load(Ordering::Relaxed) < n {
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let wall = start.elapsed();
        let sim = clock.now();
        let _ = ca.send((SimTime::ZERO, NodeCtl::Stop));
        let _ = cb.send((SimTime::ZERO, NodeCtl::Stop));
        let _ = ha.await;
        let _ = hb.await;
        (wall, sim)
    }))
}

/// Measure `loaded` over `duration`, `runs` runs of each variant, interleaved; `one` runs
/// one (in a process of its own: see the module docs), recording to the file it is given.
pub fn run(
    loaded: &Loaded,
    duration: Duration,
    runs: usize,
    mut one: impl FnMut(Variant, &std::path::Path) -> anyhow::Result<Sample>,
) -> anyhow::Result<BenchReport> {
    let runs = runs.max(1);
    let file = std::env::temp_dir().join(format!("m6p-twin-bench-{}.mcap", std::process::id()));
    let mut samples: std::collections::BTreeMap<&str, Vec<Sample>> = Default::default();
    let mut last_recorded = None;
    for round in 0..runs {
        for k in 0..Variant::ALL.len() {
            let v = Variant::ALL[(round + k) % Variant::ALL.len()];
            let sample = one(v, &file);
            if sample.is_err() {
                let _ = std::fs::remove_file(&file);
            }
            let sample = sample?;
            if v == Variant::Recorded {
                last_recorded = Some(sample.clone());
            }
            samples.entry(v.name()).or_default().push(sample);
        }
    }
    let _ = std::fs::remove_file(&file);
    let variants: std::collections::BTreeMap<String, VariantReport> = samples
        .iter()
        .map(|(name, s)| {
            let rss: Vec<f64> = s.iter().filter_map(|x| x.peak_rss_mib).collect();
            let r = VariantReport {
                cpu_s: Spread::of(&s.iter().map(|x| x.cpu_s).collect::<Vec<_>>()),
                wall_s: Spread::of(&s.iter().map(|x| x.wall_s).collect::<Vec<_>>()),
                peak_rss_mib: (!rss.is_empty()).then(|| Spread::of(&rss)),
            };
            ((*name).to_owned(), r)
        })
        .collect();
    let cpu = |v: Variant| variants.get(v.name()).map_or(f64::NAN, |r| r.cpu_s.median);
    let wall = |v: Variant| variants.get(v.name()).map_or(f64::NAN, |r| r.wall_s.median);
    let sim_s = duration.as_secs_f64();
    let sim_h = sim_s / 3600.0;
    let (bytes, messages) = last_recorded.map_or((0, 0), |s| (s.mcap_bytes, s.messages));
    let peak = variants
        .values()
        .filter_map(|r| r.peak_rss_mib.map(|m| m.max))
        .reduce(f64::max);
    Ok(BenchReport {
        cpu_s_plain: cpu(Variant::Plain),
        cpu_s_recorded: cpu(Variant::Recorded),
        cpu_s_adcs_floor: cpu(Variant::AdcsFloor),
        rtf_plain: sim_s / wall(Variant::Plain),
        rtf_recorded: sim_s / wall(Variant::Recorded),
        mcap_bytes_per_hour: bytes as f64 / sim_h,
        messages_per_hour: messages as f64 / sim_h,
        peak_rss_mib: peak,
        ratio_recorded_plain: cpu(Variant::Recorded) / cpu(Variant::Plain),
        ratio_recorded_adcs_floor: cpu(Variant::Recorded) / cpu(Variant::AdcsFloor),
        scenario: loaded.name(),
        duration_s: sim_s,
        runs,
        mcap_bytes: bytes,
        messages,
        variants,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_take_the_middle_and_the_ends() {
        let s = Spread::of(&[3.0, 1.0, 2.0]);
        assert_eq!((s.median, s.min, s.max), (2.0, 1.0, 3.0));
        let s = Spread::of(&[4.0, 1.0, 2.0, 3.0]);
        assert_eq!((s.median, s.min, s.max), (2.5, 1.0, 4.0));
        let s = Spread::of(&[f64::NAN]);
        assert_eq!((s.median, s.min, s.max), (0.0, 0.0, 0.0));
    }

    #[test]
    fn the_adcs_floor_steps_the_fc_at_its_own_rate() {
        let loaded = exec::load_default().expect("default scenario");
        // 10 Hz ADCS over 60 s, plus the FC's other timers.
        let (host, n) = adcs_floor_host(&loaded, Duration::from_secs(600));
        assert!((6000..7000).contains(&n), "{n} events");
        // The ADCS flew: the estimator is running and the mode's target is set.
        assert!(host.app.estimate().is_some(), "estimator initialised");
        let compiled = exec::compile_loaded(&loaded);
        assert_eq!(
            host.app.target().mode,
            crate::runtime::fc_config(&compiled.opts).initial_mode
        );
    }
}
