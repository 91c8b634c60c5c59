//! `m6p-twin campaign`: run, shrink, resolve and merge fault campaigns.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use clap::Subcommand;

#[derive(Debug, Subcommand)]
pub enum CampaignCmd {
    /// Run a campaign: results.csv, junit.xml and failures/run-<k>.toml in --out; exit 1
    /// when a run failed.
    Run(CampaignRunArgs),
    /// Shrink a failing scenario (a campaign's failures/run-<k>.toml): remove faults, narrow
    /// their windows and move drawn values back to the base while it still fails.
    Shrink {
        /// The failing scenario.
        file: PathBuf,
        /// The campaign it came from (its base scenario is where values move back to).
        #[arg(long, value_name = "CAMPAIGN")]
        campaign: Option<PathBuf>,
        /// Where the smallest failing scenario goes.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
    },
    /// Print run K's complete scenario (every draw resolved), as `m6p-twin run` takes it.
    Resolve {
        /// The campaign file.
        file: PathBuf,
        /// The run's index.
        run: u64,
    },
    /// Combine shards' output directories into the files one unsharded run writes.
    Merge {
        /// The shards' output directories.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where the combined results go.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
    },
}

#[derive(Debug, clap::Args)]
pub struct CampaignRunArgs {
    /// The campaign file.
    pub file: PathBuf,
    /// Runs 0..N instead of the campaign's `runs`.
    #[arg(long)]
    pub runs: Option<u64>,
    /// Parallel runs [default: the machine's cores].
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Also shrink every failure (failures/run-<k>.min.toml).
    #[arg(long)]
    pub shrink: bool,
    /// Also record every failure again to failures/run-<k>.mcap (checked complete, and
    /// failing the same way).
    #[arg(long)]
    pub record_failures: bool,
    /// Run only the runs whose index modulo N is I [default: from SLURM_ARRAY_TASK_ID and
    /// SLURM_ARRAY_TASK_COUNT, or JOB_COMPLETION_INDEX and JOB_COMPLETIONS, when set].
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Where the results go.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Finish a campaign that was stopped: keep the results already in --out (of this
    /// campaign), run those not run.
    #[arg(long)]
    pub resume: bool,
    /// Run every run from the start, even when the runs share a prefix (docs/campaigns.md,
    /// "Forking").
    #[arg(long)]
    pub no_fork: bool,
}

pub fn cmd_campaign_run(a: CampaignRunArgs) -> anyhow::Result<bool> {
    use m6p_twin::campaign_run::{self, RunVerdict};
    let c = m6p_twin::campaign::Campaign::load(&a.file)?;
    let runs = a.runs.unwrap_or(c.spec.runs);
    // Every run's scenario is drawn and validated before anything runs; an error in a run's
    // resolved scenario says so.
    campaign_run::check(&c, runs)?;
    let jobs = campaign_run::default_jobs(a.jobs);
    let shard = match &a.shard {
        Some(s) => Some(campaign_run::Shard::parse(s)?),
        None => campaign_run::Shard::from_env(|k| std::env::var(k).ok())?,
    };
    let mut indices: Vec<u64> = shard.map_or_else(|| (0..runs).collect(), |s| s.runs(runs));
    let meta = campaign_run::CampaignMeta::of(&c, runs);
    // What an earlier, stopped run of this campaign already has: its results are kept.
    let kept: Vec<campaign_run::RunRow> = if a.resume {
        let done = campaign_run::results_in(&a.out, &meta)?;
        indices.retain(|k| !done.iter().any(|r| r.run == *k));
        println!(
            "resuming {}: {} results kept, {} runs to go",
            a.out.display(),
            done.len(),
            indices.len()
        );
        done
    } else {
        Vec::new()
    };
    let fork = fork_of(&c, runs, &indices, a.no_fork)?;
    let bar = progress_bar(indices.len() as u64);
    let failed = std::sync::atomic::AtomicU64::new(0);
    let started = std::time::Instant::now();
    let ran = campaign_run::run_all_from(&c, &indices, jobs, fork.as_ref(), &|row| {
        if row.verdict != RunVerdict::Pass {
            let n = failed.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            bar.set_message(format!("{n} failed"));
        }
        bar.inc(1);
    });
    bar.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();
    let mut rows = kept;
    rows.extend(ran);
    rows.sort_by_key(|r| r.run);
    campaign_run::write_outputs(&meta, &rows, &a.out)?;
    let mut by_verdict = std::collections::BTreeMap::<&str, u64>::new();
    for r in &rows {
        *by_verdict.entry(r.verdict.word()).or_default() += 1;
    }
    let shard_note =
        shard.map_or_else(String::new, |s| format!(" (shard {}/{})", s.index, s.count));
    println!(
        "campaign {}{shard_note}: {} runs on {jobs} jobs in {wall:.1} s ({:.2} runs/s): {} pass, {} fail, {} error, {} not run",
        c.name(),
        rows.len(),
        rows.len() as f64 / wall.max(1e-9),
        by_verdict.get("pass").unwrap_or(&0),
        by_verdict.get("fail").unwrap_or(&0),
        by_verdict.get("error").unwrap_or(&0),
        by_verdict.get("not run").unwrap_or(&0),
    );
    if by_verdict.contains_key("not run") {
        println!(
            "the campaign was stopped: `m6p-twin campaign run {} --out {} --resume` runs the runs not run",
            a.file.display(),
            a.out.display()
        );
    }
    print!(
        "{}{}",
        m6p_twin::campaign_report::failures_by_check_text(&rows),
        m6p_twin::campaign_report::sessions_text(&rows)
    );
    for r in rows.iter().filter(|r| r.verdict != RunVerdict::Pass) {
        let why = match &r.verdict {
            RunVerdict::Fail(f) => f
                .iter()
                .map(|(n, o)| format!("{n} ({o})"))
                .collect::<Vec<_>>()
                .join("; "),
            RunVerdict::Error(e) | RunVerdict::NotRun(e) => e.clone(),
            RunVerdict::Pass => String::new(),
        };
        println!("  run {} {}: {why}", r.run, r.verdict.word());
    }
    let mut recording_ok = true;
    if a.record_failures {
        for r in rows.iter().filter(|r| {
            r.verdict != RunVerdict::Pass && r.verdict.is_result() && !r.scenario.is_empty()
        }) {
            let path = a.out.join(format!("failures/run-{}.mcap", r.run));
            let file = format!("{} run {}", c.file, r.run);
            match campaign_run::record_failure(&file, r, &path) {
                Ok(()) => println!("  run {}: recorded to {}", r.run, path.display()),
                Err(e) => {
                    recording_ok = false;
                    println!("  run {}: recording failed: {e:#}", r.run);
                }
            }
        }
    }
    if a.shrink {
        for r in rows
            .iter()
            .filter(|r| r.verdict != RunVerdict::Pass && r.verdict.is_result())
        {
            let out = a.out.join(format!("failures/run-{}.min.toml", r.run));
            let file = format!("{} run {}", c.file, r.run);
            match shrink_to(&file, &r.scenario, Some(&c.base), &out) {
                Ok(line) => println!("  run {}: {line}", r.run),
                Err(e) => println!("  run {}: not shrunk: {e:#}", r.run),
            }
        }
    }
    println!("results in {}", a.out.display());
    Ok(recording_ok && rows.iter().all(|r| r.verdict == RunVerdict::Pass))
}

/// The campaign's fork for the runs `indices` (of its `runs`), said on the terminal: its
/// instant is found over all the runs (every shard forks at the same instant), its prefix
/// run here.
fn fork_of(
    c: &m6p_twin::campaign::Campaign,
    runs: u64,
    indices: &[u64],
    off: bool,
) -> anyhow::Result<Option<m6p_twin::campaign_fork::Fork>> {
    use m6p_twin::campaign_fork::{self, NoFork};
    if indices.is_empty() {
        return Ok(None);
    }
    if off {
        println!("fork: none ({})", NoFork::Off);
        return Ok(None);
    }
    let all: Vec<u64> = (0..runs).collect();
    let at = match campaign_fork::plan(c, &all)? {
        Ok(at) => at,
        Err(why) => {
            println!("fork: none ({why})");
            return Ok(None);
        }
    };
    let started = std::time::Instant::now();
    let fork = match campaign_fork::take(c, 0, at) {
        Ok(fork) => fork,
        // Every run from the start instead: its rows say what became of it.
        Err(e) => {
            println!("fork: none (the common prefix did not give its snapshot: {e:#})");
            return Ok(None);
        }
    };
    println!(
        "fork: every run starts from the common prefix's snapshot at {} (run once, {:.1} s)",
        m6p_twin::duration::format_instant(at),
        started.elapsed().as_secs_f64()
    );
    Ok(Some(fork))
}

/// A progress bar on a terminal, none in CI or when standard error is not a terminal.
fn progress_bar(runs: u64) -> indicatif::ProgressBar {
    use std::io::IsTerminal as _;
    if std::io::stderr().is_terminal() && std::env::var_os("CI").is_none() {
        let b = indicatif::ProgressBar::new(runs);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} runs, {msg} [{elapsed}]")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    } else {
        indicatif::ProgressBar::hidden()
    }
}

/// Shrink `text` and write the result to `out` with a header saying what was done; a line
/// to print.
pub fn shrink_to(
    file: &str,
    text: &str,
    base: Option<&toml::Table>,
    out: &std::path::Path,
) -> anyhow::Result<String> {
    let r = m6p_twin::campaign_shrink::shrink(file, text, base)?;
    let mut head = format!("# Shrunk from {file} in {} runs; still fails:\n", r.runs);
    for f in &r.failed {
        head.push_str(&format!("#   {f}\n"));
    }
    for st in &r.steps {
        head.push_str(&format!("# step: {st}\n"));
    }
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(out, format!("{head}{}", r.text))
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(format!(
        "{} steps kept in {} runs -> {}",
        r.steps.len(),
        r.runs,
        out.display()
    ))
}

pub fn cmd_campaign_shrink(
    file: &std::path::Path,
    campaign: Option<&std::path::Path>,
    out: &std::path::Path,
) -> anyhow::Result<bool> {
    let text =
        std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let c = campaign
        .map(m6p_twin::campaign::Campaign::load)
        .transpose()?;
    let line = shrink_to(
        &file.display().to_string(),
        &text,
        c.as_ref().map(|c| &c.base),
        out,
    )?;
    println!("{line}");
    Ok(true)
}

pub fn cmd_campaign_merge(dirs: &[PathBuf], out: &std::path::Path) -> anyhow::Result<bool> {
    use m6p_twin::campaign_run::{self, RunVerdict};
    let (meta, rows) = campaign_run::merge(dirs, out)?;
    let failed = rows
        .iter()
        .filter(|r| r.verdict != RunVerdict::Pass)
        .count();
    println!(
        "campaign {}: {} runs from {} shards, {failed} not passed; results in {}",
        meta.name,
        rows.len(),
        dirs.len(),
        out.display()
    );
    print!(
        "{}{}",
        m6p_twin::campaign_report::failures_by_check_text(&rows),
        m6p_twin::campaign_report::sessions_text(&rows)
    );
    Ok(failed == 0)
}

/// `campaign resolve`: run `run`'s complete scenario, every draw resolved.
pub fn cmd_campaign_resolve(file: &Path, run: u64) -> anyhow::Result<bool> {
    let c = m6p_twin::campaign::Campaign::load(file)?;
    let r = c
        .resolve(run)
        .map_err(|e| anyhow::anyhow!("{}", m6p_twin::campaign_run::located(&c, run, &e)))?;
    print!("# Run {run} of campaign {}\n{}", file.display(), r.text);
    Ok(true)
}

/// Run a `campaign` subcommand.
pub fn cmd_campaign(c: CampaignCmd) -> anyhow::Result<bool> {
    match c {
        CampaignCmd::Run(a) => cmd_campaign_run(a),
        CampaignCmd::Merge { dirs, out } => cmd_campaign_merge(&dirs, &out),
        CampaignCmd::Resolve { file, run } => cmd_campaign_resolve(&file, run),
        CampaignCmd::Shrink {
            file,
            campaign,
            out,
        } => cmd_campaign_shrink(&file, campaign.as_deref(), &out),
    }
}
