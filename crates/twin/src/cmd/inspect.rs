//! `m6p-twin inspect`: a recording summed up (with its PC session runs), a channel as CSV,
//! its bytes by channel. A reader that stops early (`| head`) ends it quietly, with success.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use m6p_twin::record::{PcSessionSummaryMsg, TOPIC_PC_SESSION_SUMMARY};

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

/// Run `m6p-twin inspect` on `file`, to standard output.
pub fn cmd_inspect(file: &Path, csv: Option<&str>, sizes: bool) -> anyhow::Result<bool> {
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    match inspect(file, csv, sizes, &mut out) {
        // The reader stopped early (`inspect --csv ... | head`): it has what it wanted.
        Err(e) if closed_stdout(&e) => Ok(true),
        res => res,
    }
}

/// Whether `e` is a write to a standard output that its reader has closed.
fn closed_stdout(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// Write what `inspect` was asked for to `out`: the sizes, a channel as CSV (its row count
/// on standard error), or the summary and the session runs.
fn inspect(
    file: &Path,
    csv: Option<&str>,
    sizes: bool,
    out: &mut impl Write,
) -> anyhow::Result<bool> {
    if sizes {
        write!(out, "{}", m6p_twin::sizes::read_sizes(file)?)?;
        out.flush()?;
        return Ok(true);
    }
    match csv {
        Some(channel) => {
            let rows = m6p_twin::recording::export_csv(file, channel, out)?;
            out.flush()?;
            eprintln!("{rows} rows of {channel}");
        }
        None => {
            let summary = m6p_twin::recording::read_summary(file)?;
            write!(out, "{summary}")?;
            if summary.count(TOPIC_PC_SESSION_SUMMARY) > 0 {
                write!(out, "{}", session_runs(file)?)?;
            }
            out.flush()?;
        }
    }
    Ok(true)
}

/// The PC session runs of the recording at `file`, in the order they ended (its
/// `/pc/sessions/summary`), each with its downlink file when the recording's `.downlink/`
/// directory beside it holds it (`x.mcap` -> `x.downlink/session-4-run1.bin`). A file that
/// cannot be read to its end lists the runs before the break (the summary says where); a
/// message that does not decode as one is left out, as the summary leaves it out.
fn session_runs(file: &Path) -> anyhow::Result<String> {
    use std::fmt::Write as _;
    let dir = file.with_extension("downlink");
    // The ground sink numbers each session's runs from 1 as they start; a session's runs
    // end in the order they started. A run that ended without starting (an ABORT of a
    // PENDING session) has no number and no file.
    let mut runs_of: BTreeMap<u8, u32> = BTreeMap::new();
    let mut s = String::from(
        "PC session runs (/pc/sessions/summary, in the order they ended):\n  \
         session payload result          packets    downlinked    start s      end s  downlink file\n",
    );
    let runs = m6p_twin::recording::messages(file)?
        .map_while(Result::ok)
        .filter(|m| &*m.topic == TOPIC_PC_SESSION_SUMMARY)
        .filter_map(|m| m.decode::<PcSessionSummaryMsg>().ok());
    for run in runs {
        let path = run.start_ns.map(|_| {
            let k = runs_of.entry(run.session).or_default();
            *k += 1;
            dir.join(format!("session-{}-run{k}.bin", run.session))
        });
        let downlink = match path.as_ref().map(|p| (p, std::fs::metadata(p))) {
            Some((p, Ok(meta))) if meta.is_file() => format!("{} ({} B)", p.display(), meta.len()),
            _ => "-".to_owned(),
        };
        let result = match &run.cause {
            Some(cause) => format!("{} ({cause})", run.result),
            None => run.result.clone(),
        };
        let _ = writeln!(
            s,
            "  {:>7} {:>7} {result:<15} {:>7} {:>11} B {:>10} {:>10}  {downlink}",
            run.session,
            run.payload
                .map_or_else(|| "-".to_owned(), |p| p.to_string()),
            run.packets,
            run.downlinked_bytes,
            run.start_ns.map_or_else(|| "-".to_owned(), seconds),
            seconds(run.t_ns),
        );
    }
    Ok(s)
}

/// Simulated nanoseconds as seconds with three decimals.
fn seconds(ns: u64) -> String {
    format!(
        "{}.{:03}",
        ns / 1_000_000_000,
        ns % 1_000_000_000 / 1_000_000
    )
}
