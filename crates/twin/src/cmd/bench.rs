//! `m6p-twin bench` and `bench-run`: a scenario's speed, memory and recording size.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;
use m6p_twin::duration::parse_duration;
use m6p_twin::exec;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scenario file [default: the embedded default scenario].
    pub scenario: Option<PathBuf>,
    /// Simulated duration of each run.
    #[arg(long, default_value = "1h", value_parser = parse_duration)]
    pub duration: Duration,
    /// Runs per variant.
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Print the figures as one JSON object (`cpu_s_plain`, `cpu_s_recorded`,
    /// `cpu_s_adcs_floor`, `rtf_plain`, `rtf_recorded`, `mcap_bytes_per_hour`,
    /// `messages_per_hour`, `peak_rss_mib`, the ratios and per-variant spreads).
    #[arg(long)]
    pub json: bool,
    /// The recorded runs' channels, as `run --channels` (overrides the scenario's).
    #[arg(long, value_name = "RULES", allow_hyphen_values = true, value_parser = crate::cmd::run::parse_channel_rules)]
    pub channels: Option<crate::cmd::run::ChannelRules>,
}

#[derive(Debug, clap::Args)]
pub struct RunOneArgs {
    /// Scenario file [default: the embedded default scenario].
    pub scenario: Option<PathBuf>,
    /// `plain`, `recorded`, `adcs_floor`, or `round_trips` (CSP request-reply over one
    /// timed CAN bus, `--count` of them; no scenario).
    #[arg(long)]
    pub variant: String,
    /// Simulated duration, ns.
    #[arg(long, default_value_t = 0)]
    pub duration_ns: u64,
    /// Where a recorded run records.
    #[arg(long, default_value = "bench-run.mcap")]
    pub record: PathBuf,
    /// Round trips of the `round_trips` variant.
    #[arg(long, default_value_t = 1000)]
    pub count: u64,
    /// The recorded run's channels, as `run --channels`.
    #[arg(long, value_name = "RULES", allow_hyphen_values = true, value_parser = crate::cmd::run::parse_channel_rules)]
    pub channels: Option<crate::cmd::run::ChannelRules>,
}

pub fn cmd_bench(a: &Args) -> anyhow::Result<bool> {
    let (scenario, duration, runs, json) = (a.scenario.as_deref(), a.duration, a.runs, a.json);
    let mut loaded = match scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    let channels = a.channels.as_ref().map(|c| {
        loaded.scenario.record.channels = c.0.clone();
        twin_scenario::channels::format_rules(&c.0)
    });
    let exe = std::env::current_exe().context("finding the m6p-twin executable")?;
    let report = m6p_twin::bench::run(&loaded, duration, runs, |variant, record| {
        let mut cmd = std::process::Command::new(&exe);
        cmd.arg("bench-run")
            .args(["--variant", variant.name()])
            .args(["--duration-ns", &duration.as_nanos().to_string()])
            .arg("--record")
            .arg(record);
        if let Some(c) = &channels {
            cmd.args(["--channels", c]);
        }
        if let Some(p) = scenario {
            cmd.arg(p);
        }
        let out = cmd
            .stdin(std::process::Stdio::null())
            .output()
            .with_context(|| format!("running {}", exe.display()))?;
        if !out.status.success() {
            anyhow::bail!(
                "the {} run failed ({}): {}",
                variant.name(),
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        serde_json::from_slice(&out.stdout)
            .with_context(|| format!("reading the {} run's figures", variant.name()))
    })?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.text());
    }
    Ok(true)
}

pub fn cmd_bench_run(a: &RunOneArgs) -> anyhow::Result<bool> {
    if a.variant == "round_trips" {
        let (wall, sim) = m6p_twin::bench::round_trips(a.count)?;
        let figures = serde_json::json!({
            "round_trips": a.count,
            "wall_s": wall.as_secs_f64(),
            "sim_s": sim.as_secs_f64(),
        });
        println!("{figures}");
        return Ok(true);
    }
    let variant = m6p_twin::bench::Variant::from_name(&a.variant)
        .with_context(|| format!("no bench variant {:?}", a.variant))?;
    let mut loaded = match &a.scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    if let Some(c) = &a.channels {
        loaded.scenario.record.channels = c.0.clone();
    }
    let duration = Duration::from_nanos(a.duration_ns);
    let sample = m6p_twin::bench::run_one(&loaded, duration, variant, &a.record)?;
    println!("{}", serde_json::to_string(&sample)?);
    Ok(true)
}
