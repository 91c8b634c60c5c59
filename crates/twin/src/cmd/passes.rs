//! `m6p-twin passes`: the passes of a scenario's orbit over its ground stations.

use std::path::PathBuf;
use std::time::Duration;

use m6p_twin::duration::parse_duration;
use m6p_twin::exec;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scenario file [default: the embedded default scenario].
    pub scenario: Option<PathBuf>,
    /// Only the passes over this station (by name).
    #[arg(long, value_name = "NAME")]
    pub station: Option<String>,
    /// How far to look [default: the scenario's duration].
    #[arg(long, value_parser = parse_duration)]
    pub duration: Option<Duration>,
}

pub fn cmd_passes(
    scenario: Option<&std::path::Path>,
    station: Option<&str>,
    duration: Option<Duration>,
) -> anyhow::Result<bool> {
    let loaded = match scenario {
        Some(p) => exec::load(p)?,
        None => exec::load_default()?,
    };
    let s = &loaded.scenario;
    if let Some(name) = station {
        m6p_twin::comm::check_station(s, name)
            .map_err(|e| anyhow::anyhow!("{}: {e}", loaded.file))?;
    }
    if s.satellite.tle.is_empty() {
        anyhow::bail!(
            "{} has no [satellite] tle: no orbit, no passes",
            loaded.file
        );
    }
    let epoch = exec::compile_loaded(&loaded).opts.epoch_unix_s;
    let span = duration.unwrap_or(s.duration.0);
    let passes = m6p_twin::comm::station_passes(s, epoch, span, station);
    println!(
        "passes of `{}` over {} above {} deg, from {} for {}",
        loaded.name(),
        station.unwrap_or("every station"),
        s.comm.elevation_mask_deg,
        m6p_twin::timefmt::format_utc(epoch as i64 * 1_000_000_000),
        m6p_twin::duration::format_duration(span)
    );
    println!(
        "{:<12} {:>10} {:>13} {:>10} {:>9} {:>8}  rise (UTC)",
        "station", "rise (s)", "culmin. (s)", "set (s)", "max (deg)", "length"
    );
    let utc = |ns: i64| m6p_twin::timefmt::format_utc(epoch as i64 * 1_000_000_000 + ns);
    for p in &passes {
        let secs = |ns: i64| ns as f64 / 1e9;
        println!(
            "{:<12} {:>10.1} {:>13.1} {:>10.1} {:>9.1} {:>7.0}s  {}",
            p.station,
            secs(p.rise_ns),
            secs(p.culmination_ns),
            secs(p.set_ns),
            p.max_elevation_deg,
            secs(p.set_ns - p.rise_ns),
            utc(p.rise_ns)
        );
    }
    if passes.is_empty() {
        println!("(no pass in this window)");
    }
    Ok(true)
}
