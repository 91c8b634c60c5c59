//! `m6p-twin diff`: compare two recordings' bus traffic.

use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The expected recording.
    pub a: PathBuf,
    /// The actual recording.
    pub b: PathBuf,
}

pub fn cmd_diff(a: &std::path::Path, b: &std::path::Path) -> anyhow::Result<bool> {
    let d = m6p_twin::recording::diff(a, b)?;
    println!("{d}");
    Ok(d.is_identical())
}
