//! A campaign's fork (docs/campaigns.md, "Forking"): runs that are the same run up to an
//! instant (one scenario seed for all, draws that only add faults acting after it) run that
//! common prefix once, and each starts from its snapshot (docs/snapshots.md) with its own
//! faults to come. The twin is deterministic, so a run from the fork is the run from the
//! start: the same rows, to the bit.
//!
//! The instant is found, not trusted: every run is compiled, and the runs' compiled form
//! (network, nodes' configurations, plans, expectations, invariants; everything but the
//! fault timeline) must be the same text for all; the fork is just before the earliest
//! fault action in which any run's timeline differs from the first run's.

use std::time::Duration;

use anyhow::Context as _;
use csp::SimTime;

use crate::campaign::{Campaign, RunSeeds};
use crate::events::RunEvent;
use crate::exec;
use crate::plan::{Compiled, TimedFault};
use crate::runtime::counters::RunSink;
use crate::runtime::{FaultsToCome, Resume, Sections};

/// The snapshot every run of a campaign starts from.
#[derive(Debug, Clone)]
pub struct Fork {
    /// Its instant.
    pub at: SimTime,
    sections: Sections,
}

impl Fork {
    /// Where a run starts from it.
    pub fn resume(&self) -> Resume {
        Resume {
            t: self.at,
            sections: self.sections.clone(),
            faults: FaultsToCome::Own,
        }
    }
}

/// Why a campaign's runs are not forked.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NoFork {
    /// The command line said so.
    #[error("--no-fork")]
    Off,
    /// Each run has its own scenario seed: they differ from the start.
    #[error("each run has its own scenario seed (`run_seeds = \"shared\"` gives them one)")]
    SeedsPerRun,
    /// A run differs from the first in more than its fault timeline.
    #[error(
        "run {run} differs from run {first} in more than its fault timeline (a dispersion, or \
         a fault kept in a node's configuration)"
    )]
    Differs {
        /// The run.
        run: u64,
        /// The first run.
        first: u64,
    },
    /// A run's draws act at the start.
    #[error("run {run}'s draws act at t = 0")]
    AtStart {
        /// The run.
        run: u64,
    },
    /// `fork_at = "0s"`.
    #[error("fork_at is 0")]
    AtZero,
}

/// Run `k` of `c`, compiled as it runs.
fn compiled(c: &Campaign, k: u64) -> anyhow::Result<Compiled> {
    // Every run resolved before (`campaign_run::check`, which tells its errors).
    let r = c.resolve(k).map_err(|e| anyhow::anyhow!("run {k}: {e}"))?;
    let file = format!("{} run {k}", c.file);
    let scenario = crate::validate::parse(&file, &r.text)?;
    let loaded = exec::Loaded {
        file,
        text: r.text,
        scenario,
    };
    Ok(exec::compile_seeded(&loaded, None))
}

/// The compiled run but its fault timeline, as text: what must be the same in every run.
fn all_but_faults(c: &Compiled) -> String {
    let mut c = c.clone();
    c.opts.faults.clear();
    c.faults.clear();
    format!("{c:?}")
}

/// The earliest instant at which two fault timelines differ (an action in one and not at
/// the same place in the other); none when they are the same.
fn first_difference(a: &[TimedFault], b: &[TimedFault]) -> Option<SimTime> {
    let same = a
        .iter()
        .zip(b)
        .take_while(|(x, y)| format!("{x:?}") == format!("{y:?}"))
        .count();
    a.get(same)
        .into_iter()
        .chain(b.get(same))
        .map(|f| f.at)
        .min()
}

/// Where the runs `runs` of `c` fork (the first of them runs the prefix): `fork_at`, or
/// the latest instant before which no run differs from the first; why not, when they do
/// not. A `fork_at` after a run's draws act is an error naming both.
pub fn plan(c: &Campaign, runs: &[u64]) -> anyhow::Result<Result<SimTime, NoFork>> {
    if c.spec.run_seeds == RunSeeds::PerRun {
        return Ok(Err(NoFork::SeedsPerRun));
    }
    let Some(&first) = runs.first() else {
        return Ok(Err(NoFork::Off));
    };
    let base = compiled(c, first)?;
    let key = all_but_faults(&base);
    let end = SimTime::ZERO + base.opts.duration.unwrap_or(Duration::MAX);
    // The earliest difference, and the run it is in.
    let mut earliest = (end, first);
    for &k in &runs[1..] {
        let run = compiled(c, k)?;
        if all_but_faults(&run) != key {
            return Ok(Err(NoFork::Differs { run: k, first }));
        }
        if let Some(t) = first_difference(&run.opts.faults, &base.opts.faults)
            && t < earliest.0
        {
            earliest = (t, k);
        }
    }
    let (t, run) = earliest;
    let Some(latest) = t.as_ns().checked_sub(1).map(SimTime::from_ns) else {
        return Ok(Err(NoFork::AtStart { run }));
    };
    match c.spec.fork_at.map(|d| SimTime::ZERO + d.0) {
        None => Ok(Ok(latest)),
        Some(at) if at == SimTime::ZERO => Ok(Err(NoFork::AtZero)),
        Some(at) if at <= latest => Ok(Ok(at)),
        Some(at) => anyhow::bail!(
            "{}: fork_at = {}: run {run} differs from run {first} from t = {} (its draws act \
             there): fork_at must be before it",
            c.file,
            crate::duration::format_instant(at),
            crate::duration::format_instant(t),
        ),
    }
}

/// What the prefix run keeps: the snapshot.
#[derive(Default)]
struct Keep {
    taken: Option<Sections>,
}

impl RunSink for Keep {
    fn event(&mut self, _: &RunEvent) {}
    fn snapshot(&mut self, _: SimTime, _: crate::runtime::AskedBy, sections: &mut Sections) {
        self.taken = Some(std::mem::take(sections));
    }
}

/// Run the common prefix of `c`'s runs (run `first`'s scenario) up to `at` and keep its
/// snapshot there, within `c`'s wall-clock limit.
pub fn take(c: &Campaign, first: u64, at: SimTime) -> anyhow::Result<Fork> {
    let mut prefix = compiled(c, first)?;
    // Compiled for the whole run (its plans are the whole run's), ended a second after
    // `at` (the snapshot is taken where the run settles at `at`, before its end).
    prefix.opts.duration = Some(Duration::from_nanos(at.as_ns()) + Duration::from_secs(1));
    prefix.opts.snapshot_at = vec![at];
    prefix.opts.clock = bus::ClockMode::Virtual;
    prefix.opts.wall_limit = Some(c.spec.limits.wall.0);
    let rt = crate::runtime::build_runtime_for(&prefix.opts)?;
    let mut keep = Keep::default();
    let outcome = rt.block_on(exec::execute_sink(prefix, false, &mut keep))?;
    if let Some(i) = outcome.report.interrupted {
        anyhow::bail!("the common prefix was stopped: {i}");
    }
    let sections = keep
        .taken
        .with_context(|| format!("the common prefix ran and took no snapshot at {at}"))?;
    Ok(Fork { at, sections })
}
