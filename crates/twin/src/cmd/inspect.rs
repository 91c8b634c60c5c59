//! `m6p-twin inspect`: a recording summed up, a channel as CSV, its bytes by channel.

use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The MCAP recording.
    pub file: PathBuf,
    /// Export this channel (for example /csp/packets) as CSV to standard output.
    #[arg(long, value_name = "CHANNEL")]
    pub csv: Option<String>,
    /// Where the file's bytes go: each channel's messages, data, data compressed on its
    /// own (zstd 1) and MCAP message index, largest first, and per simulated hour.
    #[arg(long, conflicts_with = "csv")]
    pub sizes: bool,
}

pub fn cmd_inspect(file: &std::path::Path, csv: Option<&str>, sizes: bool) -> anyhow::Result<bool> {
    if sizes {
        print!("{}", m6p_twin::sizes::read_sizes(file)?);
        return Ok(true);
    }
    match csv {
        Some(channel) => {
            let stdout = std::io::stdout();
            let mut out = std::io::BufWriter::new(stdout.lock());
            let rows = m6p_twin::recording::export_csv(file, channel, &mut out)?;
            std::io::Write::flush(&mut out)?;
            eprintln!("{rows} rows of {channel}");
        }
        None => print!("{}", m6p_twin::recording::read_summary(file)?),
    }
    Ok(true)
}
