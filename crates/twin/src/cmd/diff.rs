//! `m6p-twin diff`: compare two recordings' bus traffic.

use std::path::PathBuf;

/// How many divergences `--all` lists unless `--max` says otherwise.
const DEFAULT_MAX_LISTED: usize = 100;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The expected recording.
    pub a: PathBuf,
    /// The actual recording.
    pub b: PathBuf,
    /// Also list every divergence of every channel in detail, earliest first, up to `--max`.
    #[arg(long)]
    pub all: bool,
    /// The most divergences `--all` lists.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_LISTED, requires = "all")]
    pub max: usize,
    /// Compare what the two hold from simulated time T on (90s, 10m, 2h): each channel's
    /// messages before T are left out of both, and indices count from the first compared.
    #[arg(long, value_name = "T", value_parser = m6p_twin::duration::parse_duration)]
    pub from: Option<std::time::Duration>,
}

/// Print the first divergence, a line per medium channel and, with `--all`, the listing;
/// `Ok(true)` when the recordings are identical (the exit code follows from it).
pub fn cmd_diff(a: &Args) -> anyhow::Result<bool> {
    let max_listed = if a.all { a.max } else { 0 };
    let from_ns = a
        .from
        .map_or(0, |t| u64::try_from(t.as_nanos()).unwrap_or(u64::MAX));
    let d = m6p_twin::recording::diff_summary_from(&a.a, &a.b, max_listed, from_ns)?;
    if let Some(t) = a.from {
        println!("from t = {} on", m6p_twin::duration::format_duration(t));
    }
    println!("{d}");
    Ok(d.is_identical())
}
