//! Running a campaign ([`crate::campaign`]): its runs in parallel on J threads, each a
//! virtual-time run of its resolved scenario checked against its expectations and the
//! [`crate::invariants`], and the files a CI pipeline reads: a CSV row
//! and a JUnit test case per run, and a scenario file per failure that `m6p-twin test`
//! reproduces.
//!
//! What a row holds depends only on the campaign and the run's index (no wall-clock time,
//! no thread), so the rows of any subset of the runs are those of the whole campaign.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context as _, bail};

use crate::campaign::Campaign;
pub use crate::campaign_rows::{
    CampaignMeta, CheckKind, RunRow, RunVerdict, SessionEnd, SessionTally, session_tallies,
};
use crate::exec;
use twin_scenario::scenario::{ScenarioError, ScenarioErrors};

/// Run run `k` of `c`: resolve, compile, run in virtual time, check. A panic inside the
/// run is caught and becomes the row's error.
pub fn run_one(c: &Campaign, k: u64) -> RunRow {
    run_one_from(c, k, None)
}

/// [`run_one`], from the campaign's fork when there is one.
pub fn run_one_from(c: &Campaign, k: u64, fork: Option<&crate::campaign_fork::Fork>) -> RunRow {
    let r = match c.resolve(k) {
        Ok(r) => r,
        Err(e) => {
            return RunRow {
                run: k,
                seed: 0,
                draws: BTreeMap::new(),
                verdict: RunVerdict::Error(located(c, k, &e).to_string()),
                failed_kinds: BTreeMap::new(),
                metrics: BTreeMap::new(),
                sessions: BTreeMap::new(),
                scenario: String::new(),
            };
        }
    };
    let j = run_limited_from(&format!("{} run {k}", c.file), &r.text, c.spec.limits, fork);
    RunRow {
        run: k,
        seed: r.seed,
        draws: r.draws,
        verdict: j.verdict,
        failed_kinds: j.failed_kinds,
        metrics: j.metrics,
        sessions: j.sessions,
        scenario: r.text,
    }
}

/// Run `k`'s scenario errors for a person. An error the campaign located in its own file
/// is as it is. One located in the run's resolved scenario (the base with the run's draws
/// written in: a text in no file, whose lines are none of the user's) is moved to the
/// field's line in the base scenario (the campaign's `[scenario]`, or its scenario file)
/// when the base has that field, and says that its line is the resolved scenario's
/// otherwise.
pub fn located(c: &Campaign, k: u64, errors: &ScenarioErrors) -> LocatedErrors {
    // The name `Campaign::resolve` gives the resolved scenario in its errors.
    let resolved = format!("{} run {k}", c.file);
    LocatedErrors(
        errors
            .0
            .iter()
            .map(|e| match e.line {
                Some(line) if e.file == resolved => match in_base(c, &e.field) {
                    Some(at) => Located::InUserFile(ScenarioError {
                        message: e.message.clone(),
                        ..at
                    }),
                    None => Located::InResolved {
                        campaign: c.file.clone(),
                        run: k,
                        line,
                        error: e.clone(),
                    },
                },
                _ => Located::InUserFile(e.clone()),
            })
            .collect(),
    )
}

/// A run's scenario errors, each where the user can find it ([`located`]); one per line.
#[derive(Debug, Clone)]
pub struct LocatedErrors(pub Vec<Located>);

/// One error of a run's scenario, and where it is.
#[derive(Debug, Clone)]
pub enum Located {
    /// At a line of one of the user's files (the campaign or its scenario file).
    InUserFile(ScenarioError),
    /// At `line` of run `run`'s resolved scenario, a text in no file (a draw made the field).
    InResolved {
        campaign: String,
        run: u64,
        line: usize,
        error: ScenarioError,
    },
}

impl std::fmt::Display for Located {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Located::InUserFile(e) => write!(f, "{e}"),
            Located::InResolved {
                campaign,
                run,
                line,
                error: e,
            } => {
                write!(
                    f,
                    "{}: in the resolved scenario of run {run} (the base scenario with the run's draws written in, not a line of {campaign}), line {line}",
                    e.file
                )?;
                if let Some(c) = e.column {
                    write!(f, ", column {c}")?;
                }
                if !e.field.is_empty() {
                    write!(f, ", field `{}`", e.field)?;
                }
                write!(f, ": {}", e.message)
            }
        }
    }
}

impl std::fmt::Display for LocatedErrors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

/// Where the base scenario of `c` holds `field` (a path into the scenario): in the campaign
/// file under `scenario`, or in the scenario file. `None` when the base has no such field
/// (a draw made it).
fn in_base(c: &Campaign, field: &str) -> Option<ScenarioError> {
    use crate::campaign::{ScenarioSource, get_path, parse_path};
    use twin_scenario::scenario::{PathStep, line_col, locate};
    let steps = parse_path(field).ok()?;
    get_path(&c.base, &steps)?;
    let (file, text, steps, field) = match &c.spec.scenario {
        ScenarioSource::Inline(_) => {
            let mut under = vec![PathStep::Key("scenario".into())];
            under.extend(steps);
            (
                c.file.clone(),
                c.text.clone(),
                under,
                format!("scenario.{field}"),
            )
        }
        ScenarioSource::Path(_) => (
            c.base_file.clone(),
            std::fs::read_to_string(&c.base_file).ok()?,
            steps,
            field.to_owned(),
        ),
    };
    let (line, column) = line_col(&text, locate(&text, &steps)?.start);
    Some(ScenarioError {
        file,
        line: Some(line),
        column: Some(column),
        field,
        message: String::new(),
    })
}

/// Resolve runs `0..runs` of `c` (every problem before anything runs): the first run's
/// errors, [`located`].
pub fn check(c: &Campaign, runs: u64) -> anyhow::Result<()> {
    for k in 0..runs {
        c.resolve(k)
            .map_err(|e| anyhow::anyhow!("{}", located(c, k, &e)))?;
    }
    Ok(())
}

/// Run one complete scenario (`file` names it in errors) in virtual time and judge it:
/// its expectations and the invariants. A panic inside the run is caught and becomes the
/// error.
pub fn run_text(file: &str, text: &str) -> RunVerdict {
    run_judged(file, text).verdict
}

/// A run judged: how it ended, the kind of each check it failed, its key figures.
#[derive(Debug, Clone, PartialEq)]
pub struct Judged {
    /// How it ended.
    pub verdict: RunVerdict,
    /// The kind of each check it failed, by the check's name.
    pub failed_kinds: BTreeMap<String, CheckKind>,
    /// Its [`metrics`]: none when it did not run to its end.
    pub metrics: BTreeMap<String, f64>,
    /// What its payload sessions did ([`session_tallies`]): none when it did not run to its
    /// end.
    pub sessions: BTreeMap<u8, SessionTally>,
}

/// The key figures of a run, for `results.csv` and the report: `min_soc` (the battery's
/// lowest state of charge), `downlinked_bytes` (every session's bytes at the ground),
/// `detumble_s` (when the body rate first fell below 0.5 deg/s, in a run that started
/// tumbling),
/// `max_rate_deg_s` (the highest body rate published).
pub fn metrics(report: &crate::report::RunReport) -> BTreeMap<String, f64> {
    let mut m = BTreeMap::new();
    if let Some(min) = report.power_summary.min_soc {
        m.insert("min_soc".to_owned(), min);
    }
    if report.sessions.held.is_some() || !report.sessions.downlinked.is_empty() {
        let bytes: u64 = report.sessions.downlinked.values().sum();
        m.insert("downlinked_bytes".to_owned(), bytes as f64);
    }
    let a = &report.attitude_summary;
    if let Some(max) = a.max_rate_deg_s {
        m.insert("max_rate_deg_s".to_owned(), max);
        // A run that starts tumbling (0.5 deg/s or more): when it first fell below.
        if a.first
            .is_some_and(|f| f.rate_deg_s >= crate::adcs::DETUMBLED_DEG_S)
            && let Some(t) = a.first_detumbled
        {
            m.insert("detumble_s".to_owned(), t.as_secs_f64());
        }
    }
    m
}

/// What a caught panic said.
pub fn panic_text(p: &(dyn std::any::Any + Send)) -> &str {
    p.downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| p.downcast_ref::<&str>().copied())
        .unwrap_or("(no message)")
}

/// The threads to run on when none is asked for: one per core.
pub fn default_jobs(asked: Option<usize>) -> usize {
    asked
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
        .max(1)
}

/// [`run_text`] with the kinds of the checks that failed and the run's [`metrics`] (none
/// when it did not run to its end), within the default
/// [`RunLimits`](crate::campaign::RunLimits).
pub fn run_judged(file: &str, text: &str) -> Judged {
    run_limited(file, text, crate::campaign::RunLimits::default())
}

/// [`run_judged`] within `limits`: a scenario longer than `limits.simulated` is an error
/// row, not run; a run still going after `limits.wall` is stopped, an error row; a run a
/// signal (SIGINT, SIGTERM) cut or kept from starting is not run. The invariants are the
/// scenario's (`[invariants] check`: a campaign's resolved runs check all), judged with
/// its expectations.
pub fn run_limited(file: &str, text: &str, limits: crate::campaign::RunLimits) -> Judged {
    run_limited_from(file, text, limits, None)
}

/// [`run_limited`], from `fork` when given (a campaign's common prefix).
pub fn run_limited_from(
    file: &str,
    text: &str,
    limits: crate::campaign::RunLimits,
    fork: Option<&crate::campaign_fork::Fork>,
) -> Judged {
    use crate::runtime::StopCause;
    let outcome = std::panic::catch_unwind(|| -> anyhow::Result<exec::Outcome> {
        let scenario = crate::validate::parse(file, text)?;
        let loaded = exec::Loaded {
            file: file.to_owned(),
            text: text.to_owned(),
            scenario,
        };
        let mut compiled = exec::compile_seeded(&loaded, None);
        if let Some(d) = compiled.opts.duration.filter(|d| *d > limits.simulated.0) {
            bail!(
                "its duration, {}, is over the campaign's limit of {} ([limits] simulated)",
                crate::duration::format_duration(d),
                crate::duration::format_duration(limits.simulated.0)
            );
        }
        compiled.opts.clock = bus::ClockMode::Virtual;
        compiled.opts.wall_limit = Some(limits.wall.0);
        compiled.opts.resume = fork.map(crate::campaign_fork::Fork::resume);
        let rt = crate::runtime::build_runtime_for(&compiled.opts)?;
        rt.block_on(exec::execute(compiled, &mut |_| {}))
    });
    if let Ok(Ok(o)) = &outcome
        && let Some(i) = o.report.interrupted
    {
        let verdict = match i.cause {
            StopCause::WallLimit(_) => RunVerdict::Error(format!("{i} ([limits] wall)")),
            StopCause::Interrupt | StopCause::Terminate => RunVerdict::NotRun(i.to_string()),
        };
        return Judged {
            verdict,
            failed_kinds: BTreeMap::new(),
            metrics: BTreeMap::new(),
            sessions: BTreeMap::new(),
        };
    }
    let (figures, sessions, failed_kinds) = match &outcome {
        Ok(Ok(o)) => (
            metrics(&o.report),
            session_tallies(&o.report.sessions),
            o.verdicts
                .iter()
                .filter(|v| !v.passed)
                .map(|v| (v.name.clone(), CheckKind::from(v.kind)))
                .collect(),
        ),
        _ => (BTreeMap::new(), BTreeMap::new(), BTreeMap::new()),
    };
    let verdict = match outcome {
        Ok(Ok(o)) if o.passed() => RunVerdict::Pass,
        // The invariants first (as the verdicts of a campaign always listed them).
        Ok(Ok(o)) => {
            let mut failed: Vec<&crate::expectations::Verdict> =
                o.verdicts.iter().filter(|v| !v.passed).collect();
            failed.sort_by_key(|v| matches!(v.kind, crate::expectations::VerdictKind::Expectation));
            RunVerdict::Fail(
                failed
                    .into_iter()
                    .map(|v| {
                        let t = twin_core::duration::format_instant(v.t);
                        (v.name.clone(), format!("t = {t}: {}", v.observed))
                    })
                    .collect(),
            )
        }
        Ok(Err(e)) => RunVerdict::Error(format!("{e:#}")),
        Err(p) => RunVerdict::Error(format!("panicked: {}", panic_text(p.as_ref()))),
    };
    Judged {
        verdict,
        failed_kinds,
        metrics: figures,
        sessions,
    }
}

/// Run a failed row's scenario again, recording it to `path` (MCAP), and read the file back:
/// the recording must be complete and decodable, and the run must fail again the same way
/// (a campaign's runs are deterministic). What the recorded run said, or why not.
pub fn record_failure(file: &str, row: &RunRow, path: &Path) -> anyhow::Result<()> {
    let scenario = crate::validate::parse(file, &row.scenario)?;
    let loaded = exec::Loaded {
        file: file.to_owned(),
        text: row.scenario.clone(),
        scenario,
    };
    let mut compiled = exec::compile_seeded(&loaded, None);
    compiled.opts.clock = bus::ClockMode::Virtual;
    let rt = crate::runtime::build_runtime_for(&compiled.opts)?;
    let (outcome, recorded) = rt.block_on(exec::execute_replay(
        &loaded,
        compiled,
        exec::RecordTo::replacing(path),
    ))?;
    recorded.transpose()?;
    let summary = crate::recording::read_summary(path)?;
    if let Some(why) = summary.incomplete {
        bail!("{}: the recording is incomplete: {why}", path.display());
    }
    let again: Vec<&str> = outcome
        .verdicts
        .iter()
        .filter(|v| !v.passed)
        .map(|v| v.name.as_str())
        .collect();
    if let RunVerdict::Fail(f) = &row.verdict {
        let mut before: Vec<&str> = f.iter().map(|(n, _)| n.as_str()).collect();
        let mut again = again;
        before.sort_unstable();
        again.sort_unstable();
        if before != again {
            bail!(
                "run {} failed {before:?} in the campaign but {again:?} when recorded (not deterministic?)",
                row.run
            );
        }
    }
    Ok(())
}

/// Run `runs` (indices) of `c` on `jobs` threads; `done` is called after each run. The rows
/// come back in index order.
pub fn run_all(
    c: &Campaign,
    runs: &[u64],
    jobs: usize,
    done: &(dyn Fn(&RunRow) + Sync),
) -> Vec<RunRow> {
    run_all_from(c, runs, jobs, None, done)
}

/// [`run_all`], each run from the campaign's fork when there is one.
pub fn run_all_from(
    c: &Campaign,
    runs: &[u64],
    jobs: usize,
    fork: Option<&crate::campaign_fork::Fork>,
    done: &(dyn Fn(&RunRow) + Sync),
) -> Vec<RunRow> {
    let mut rows = in_parallel(runs, jobs, &|&k| run_one_from(c, k, fork), done);
    rows.sort_by_key(|r| r.run);
    rows
}

/// `f` of each of `items` on `jobs` threads (at least one, at most one per item), each
/// thread taking the next item not yet taken; `done` sees each result as it is made, in
/// whatever order they finish. The results come back in the order of `items`. A campaign's
/// runs and `m6p-twin test`'s scenarios run this way.
pub fn in_parallel<T: Sync, R: Send>(
    items: &[T],
    jobs: usize,
    f: &(dyn Fn(&T) -> R + Sync),
    done: &(dyn Fn(&R) + Sync),
) -> Vec<R> {
    let next = AtomicUsize::new(0);
    let made = Mutex::new(Vec::with_capacity(items.len()));
    std::thread::scope(|s| {
        for _ in 0..jobs.clamp(1, items.len().max(1)) {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(i) else { break };
                    let r = f(item);
                    done(&r);
                    made.lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner)
                        .push((i, r));
                }
            });
        }
    });
    let mut made = made
        .into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    made.sort_by_key(|(i, _)| *i);
    made.into_iter().map(|(_, r)| r).collect()
}

/// A CSV cell: quoted when it needs to be.
fn cell(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// A column of what a session did in a run: `session_<id>_<what>`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum SessionColumn {
    /// Its session runs (`session_1_runs`).
    Runs,
    /// Its session runs that ended so (`session_1_no_ack`).
    Ended(SessionEnd),
    /// Packets the PC counted (`session_1_packets`).
    Packets,
    /// Bytes downlinked (`session_1_downlinked_bytes`).
    DownlinkedBytes,
}

impl SessionColumn {
    fn name(self, session: u8) -> String {
        let what = match self {
            SessionColumn::Runs => "runs",
            SessionColumn::Ended(e) => e.column(),
            SessionColumn::Packets => "packets",
            SessionColumn::DownlinkedBytes => "downlinked_bytes",
        };
        format!("session_{session}_{what}")
    }

    /// Its value in a run where the session ran.
    fn value(self, t: &SessionTally) -> u64 {
        match self {
            SessionColumn::Runs => u64::from(t.runs()),
            SessionColumn::Ended(e) => u64::from(t.ends.get(&e).copied().unwrap_or(0)),
            SessionColumn::Packets => t.packets,
            SessionColumn::DownlinkedBytes => t.downlinked_bytes,
        }
    }
}

/// The session columns of `rows`: per session id that ran in any of them (in id order), its
/// runs, a count for each end any of its runs had (in [`SessionEnd::ALL`]'s order), packets
/// and bytes.
fn session_columns(rows: &[RunRow]) -> Vec<(u8, SessionColumn)> {
    let mut cols: std::collections::BTreeSet<(u8, SessionColumn)> = Default::default();
    for (id, t) in rows.iter().flat_map(|r| &r.sessions) {
        cols.extend([
            (*id, SessionColumn::Runs),
            (*id, SessionColumn::Packets),
            (*id, SessionColumn::DownlinkedBytes),
        ]);
        cols.extend(t.ends.keys().map(|e| (*id, SessionColumn::Ended(*e))));
    }
    cols.into_iter().collect()
}

/// `results.csv`: run, seed, every drawn value (one column per path), the run's
/// [`metrics`], what each session did (`session_<id>_runs`, `session_<id>_<end>` for each
/// end its runs had, `session_<id>_packets`, `session_<id>_downlinked_bytes`: empty where
/// it did not run), verdict, the failed expectations (or the error).
pub fn results_csv(rows: &[RunRow]) -> String {
    let mut cols: Vec<&String> = rows.iter().flat_map(|r| r.draws.keys()).collect();
    cols.sort();
    cols.dedup();
    let mut out = String::from("run,seed");
    for c in &cols {
        out.push(',');
        out.push_str(&cell(c));
    }
    let mut mcols: Vec<&String> = rows.iter().flat_map(|r| r.metrics.keys()).collect();
    mcols.sort();
    mcols.dedup();
    for c in &mcols {
        out.push(',');
        out.push_str(&cell(c));
    }
    let scols = session_columns(rows);
    for (id, c) in &scols {
        out.push(',');
        out.push_str(&c.name(*id));
    }
    out.push_str(",verdict,failed\n");
    for r in rows {
        out.push_str(&format!("{},{}", r.run, r.seed));
        for c in &cols {
            out.push(',');
            out.push_str(&cell(r.draws.get(*c).map_or("", String::as_str)));
        }
        for c in &mcols {
            out.push(',');
            if let Some(v) = r.metrics.get(*c) {
                out.push_str(&v.to_string());
            }
        }
        for (id, c) in &scols {
            out.push(',');
            if let Some(t) = r.sessions.get(id) {
                out.push_str(&c.value(t).to_string());
            }
        }
        let failed = match &r.verdict {
            RunVerdict::Pass => String::new(),
            RunVerdict::Fail(f) => f
                .iter()
                .map(|(n, _)| n.as_str())
                .collect::<Vec<_>>()
                .join("; "),
            RunVerdict::Error(e) | RunVerdict::NotRun(e) => e.clone(),
        };
        out.push_str(&format!(",{},{}\n", r.verdict.word(), cell(&failed)));
    }
    out
}

/// `junit.xml`: one test case per run.
pub fn junit(name: &str, rows: &[RunRow]) -> anyhow::Result<String> {
    use quick_junit::{NonSuccessKind, Report, TestCase, TestCaseStatus, TestSuite};
    let mut suite = TestSuite::new(name);
    for r in rows {
        let status = match &r.verdict {
            RunVerdict::Pass => TestCaseStatus::success(),
            RunVerdict::Fail(f) => {
                let mut st = TestCaseStatus::non_success(NonSuccessKind::Failure);
                st.set_message(
                    f.iter()
                        .map(|(n, o)| format!("{n}: {o}"))
                        .collect::<Vec<_>>()
                        .join("\n"),
                );
                st
            }
            RunVerdict::Error(e) => {
                let mut st = TestCaseStatus::non_success(NonSuccessKind::Error);
                st.set_message(e.clone());
                st
            }
            // No result: an error case, never a pass or a failure.
            RunVerdict::NotRun(e) => {
                let mut st = TestCaseStatus::non_success(NonSuccessKind::Error);
                st.set_message(format!("not run: {e}"));
                st
            }
        };
        let mut case = TestCase::new(format!("run {}", r.run), status);
        case.set_classname(name);
        case.set_system_out(
            r.draws
                .iter()
                .map(|(p, v)| format!("{p} = {v}"))
                .collect::<Vec<_>>()
                .join("\n"),
        );
        suite.add_test_case(case);
    }
    let mut report = Report::new(name);
    report.add_test_suite(suite);
    report.to_string().context("writing the JUnit report")
}

/// Why a text is not a shard `I/N`; each names the text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ShardError {
    /// No `/`.
    #[error("`{text}`: expected I/N, for example 0/4")]
    NotIOverN {
        /// The text.
        text: String,
    },
    /// I or N is not a number.
    #[error("`{text}`: `{part}` is not a number")]
    NotANumber {
        /// The text.
        text: String,
        /// The part that is not.
        part: String,
    },
    /// I not below N.
    #[error("`{text}`: the index must be below the count (0/4 .. 3/4)")]
    IndexNotBelowCount {
        /// The text.
        text: String,
    },
}

/// Why the environment's shard is not one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ShardEnvError {
    /// The index variable without the count variable.
    #[error("{index_var} is set but {count_var} is not")]
    NoCount {
        /// The index's variable.
        index_var: &'static str,
        /// The count's variable.
        count_var: &'static str,
    },
    /// The two do not make a shard. The shard's message is part of this one's, so it is
    /// not also its `source()`.
    #[error("from {index_var} and {count_var}: {shard}")]
    Invalid {
        /// The index's variable.
        index_var: &'static str,
        /// The count's variable.
        count_var: &'static str,
        /// Why `index/count` is not a shard.
        shard: ShardError,
    },
}

/// Which runs a shard takes: those whose index modulo `count` is `index`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// This shard, 0-based.
    pub index: u64,
    /// How many shards.
    pub count: u64,
}

impl Shard {
    /// `I/N`.
    pub fn parse(s: &str) -> Result<Shard, ShardError> {
        let text = || s.to_owned();
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| ShardError::NotIOverN { text: text() })?;
        let number = |part: &str| {
            part.trim().parse().map_err(|_| ShardError::NotANumber {
                text: text(),
                part: part.to_owned(),
            })
        };
        let (index, count) = (number(i)?, number(n)?);
        if count == 0 || index >= count {
            return Err(ShardError::IndexNotBelowCount { text: text() });
        }
        Ok(Shard { index, count })
    }

    /// The shard a cluster engine gives this process through the environment (`get` reads
    /// a variable): a Slurm job array (`SLURM_ARRAY_TASK_ID`, `SLURM_ARRAY_TASK_COUNT`), or a
    /// Kubernetes Indexed Job (`JOB_COMPLETION_INDEX`, and the count in `JOB_COMPLETIONS`,
    /// which the Job's manifest sets from its `completions`). `None` when neither is set.
    pub fn from_env(get: impl Fn(&str) -> Option<String>) -> Result<Option<Shard>, ShardEnvError> {
        for (index_var, count_var) in [
            ("SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT"),
            ("JOB_COMPLETION_INDEX", "JOB_COMPLETIONS"),
        ] {
            if let Some(index) = get(index_var) {
                let count = get(count_var).ok_or(ShardEnvError::NoCount {
                    index_var,
                    count_var,
                })?;
                return Shard::parse(&format!("{index}/{count}"))
                    .map(Some)
                    .map_err(|shard| ShardEnvError::Invalid {
                        index_var,
                        count_var,
                        shard,
                    });
            }
        }
        Ok(None)
    }

    /// This shard's run indices among 0..runs.
    pub fn runs(self, runs: u64) -> Vec<u64> {
        (self.index..runs).step_by(self.count as usize).collect()
    }
}

/// Write `campaign.json`, `rows.jsonl` (every row, for `merge`), `results.csv`, `junit.xml`,
/// `report.html` ([`crate::campaign_report`]) and `failures/run-<k>.toml` (one per failed or errored run: the complete scenario, with a
/// header saying where it comes from) into `dir`.
pub fn write_outputs(meta: &CampaignMeta, rows: &[RunRow], dir: &Path) -> anyhow::Result<()> {
    let ctx = |what: &str| format!("writing {what} in {}", dir.display());
    std::fs::create_dir_all(dir).with_context(|| ctx("the output directory"))?;
    std::fs::write(
        dir.join("campaign.json"),
        serde_json::to_string_pretty(meta)? + "\n",
    )
    .with_context(|| ctx("campaign.json"))?;
    let mut jsonl = String::new();
    for r in rows {
        let mut r = r.clone();
        if r.verdict == RunVerdict::Pass {
            r.scenario.clear();
        }
        jsonl.push_str(&serde_json::to_string(&r)?);
        jsonl.push('\n');
    }
    std::fs::write(dir.join("rows.jsonl"), jsonl).with_context(|| ctx("rows.jsonl"))?;
    std::fs::write(dir.join("results.csv"), results_csv(rows))
        .with_context(|| ctx("results.csv"))?;
    std::fs::write(dir.join("junit.xml"), junit(&meta.name, rows)?)
        .with_context(|| ctx("junit.xml"))?;
    std::fs::write(
        dir.join("report.html"),
        crate::campaign_report::report_html(meta, rows),
    )
    .with_context(|| ctx("report.html"))?;
    let failures = dir.join("failures");
    remove_stale_failures(&failures).with_context(|| ctx("failures/"))?;
    // A failure file for each result that failed: a run cut short or never started has none
    // (it would not reproduce anything).
    for r in rows
        .iter()
        .filter(|r| r.verdict != RunVerdict::Pass && r.verdict.is_result())
    {
        if r.scenario.is_empty() {
            continue;
        }
        std::fs::create_dir_all(&failures).with_context(|| ctx("failures/"))?;
        // The path as the user named the output folder: the line works from where they ran
        // the campaign.
        let file = failures.join(format!("run-{}.toml", r.run));
        let head = format!(
            "# Run {} of campaign {} (seed {}), {}: every draw resolved.\n# Reproduce: m6p-twin test {}\n",
            r.run,
            meta.file,
            meta.seed,
            r.verdict.word(),
            file.display()
        );
        std::fs::write(&file, format!("{head}{}", r.scenario))
            .with_context(|| ctx("a failure file"))?;
    }
    Ok(())
}

/// Remove what an earlier campaign left in `failures` (`run-<k>.toml`, `.min.toml`,
/// `.mcap`): a failure file must be of this run. Other files stay.
fn remove_stale_failures(failures: &Path) -> std::io::Result<()> {
    let Ok(entries) = std::fs::read_dir(failures) else {
        return Ok(());
    };
    for e in entries {
        let e = e?;
        let name = e.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix("run-")) else {
            continue;
        };
        let digits = rest.chars().take_while(char::is_ascii_digit).count();
        if digits > 0 && matches!(&rest[digits..], ".toml" | ".min.toml" | ".mcap") {
            std::fs::remove_file(e.path())?;
        }
    }
    Ok(())
}

/// The results (pass, fail, error) already in `dir` of the campaign `meta` describes: what
/// `campaign run --resume` keeps. Refused when `dir` holds another campaign's outputs.
pub fn results_in(dir: &Path, meta: &CampaignMeta) -> anyhow::Result<Vec<RunRow>> {
    let m: CampaignMeta = serde_json::from_str(
        &std::fs::read_to_string(dir.join("campaign.json"))
            .with_context(|| format!("reading {}/campaign.json", dir.display()))?,
    )
    .with_context(|| format!("{}/campaign.json", dir.display()))?;
    if m != *meta {
        bail!(
            "{} holds another campaign's results ({m:?}), not {meta:?}",
            dir.display()
        );
    }
    let text = std::fs::read_to_string(dir.join("rows.jsonl"))
        .with_context(|| format!("reading {}/rows.jsonl", dir.display()))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let r: RunRow = serde_json::from_str(line)
            .with_context(|| format!("{}/rows.jsonl:{}", dir.display(), i + 1))?;
        if r.verdict.is_result() {
            rows.push(r);
        }
    }
    Ok(rows)
}

/// Combine the outputs of shards (`dirs`) into `out`: the same files one unsharded run
/// writes. The shards must be of one campaign and must not share a run; runs missing from
/// all of them are named.
pub fn merge(
    dirs: &[std::path::PathBuf],
    out: &Path,
) -> anyhow::Result<(CampaignMeta, Vec<RunRow>)> {
    let mut meta: Option<CampaignMeta> = None;
    let mut rows: BTreeMap<u64, RunRow> = BTreeMap::new();
    for d in dirs {
        let m: CampaignMeta = serde_json::from_str(
            &std::fs::read_to_string(d.join("campaign.json"))
                .with_context(|| format!("reading {}/campaign.json", d.display()))?,
        )
        .with_context(|| format!("{}/campaign.json", d.display()))?;
        match &meta {
            Some(first) if *first != m => bail!(
                "{} is from another campaign: {m:?}, not {first:?}",
                d.display()
            ),
            _ => meta = Some(m),
        }
        let text = std::fs::read_to_string(d.join("rows.jsonl"))
            .with_context(|| format!("reading {}/rows.jsonl", d.display()))?;
        for (i, line) in text.lines().enumerate() {
            let r: RunRow = serde_json::from_str(line)
                .with_context(|| format!("{}/rows.jsonl:{}", d.display(), i + 1))?;
            if rows.contains_key(&r.run) {
                bail!("run {} is in two shards (again in {})", r.run, d.display());
            }
            rows.insert(r.run, r);
        }
    }
    let meta = meta.context("nothing to merge")?;
    let missing: Vec<u64> = (0..meta.runs).filter(|k| !rows.contains_key(k)).collect();
    if !missing.is_empty() {
        bail!(
            "{} of {} runs are in no shard (first: {:?})",
            missing.len(),
            meta.runs,
            &missing[..missing.len().min(10)]
        );
    }
    let rows: Vec<RunRow> = rows.into_values().collect();
    write_outputs(&meta, &rows, out)?;
    Ok((meta, rows))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// `tests/data/campaign-ping.toml`: runs pass or fail by a drawn ping time.
    fn campaign() -> Campaign {
        Campaign::parse("c.toml", include_str!("../tests/data/campaign-ping.toml")).unwrap()
    }

    #[test]
    fn rows_do_not_depend_on_the_threads_or_the_subset() {
        let c = campaign();
        let all: Vec<u64> = (0..6).collect();
        let one = run_all(&c, &all, 1, &|_| {});
        let two = run_all(&c, &all, 2, &|_| {});
        assert_eq!(one, two);
        let odd = run_all(&c, &[1, 3, 5], 2, &|_| {});
        assert_eq!(
            odd,
            one.iter()
                .filter(|r| r.run % 2 == 1)
                .cloned()
                .collect::<Vec<_>>()
        );
        // A ping at 5 s in a 2 s run is never answered: those runs fail, the others pass.
        for r in &one {
            let late = r.draws["commands[0].at"] == "5s";
            assert_eq!(r.verdict != RunVerdict::Pass, late, "{r:?}");
            // The failed check's kind is kept with the row, for the report's table.
            let kinds: Vec<_> = r
                .failed_kinds
                .iter()
                .map(|(n, k)| (n.as_str(), *k))
                .collect();
            let want = if late {
                vec![("fc-answers", CheckKind::Expectation)]
            } else {
                vec![]
            };
            assert_eq!(kinds, want, "{r:?}");
        }
        assert!(one.iter().any(|r| r.verdict == RunVerdict::Pass));
        assert!(one.iter().any(|r| r.verdict != RunVerdict::Pass));
    }

    /// A draw that makes a base field invalid: the error is at that field's line in the
    /// campaign file, not at a line of the resolved scenario passed off as the campaign's;
    /// where the base has no such field, the error says its line is the resolved scenario's.
    #[test]
    fn errors_in_a_resolved_scenario_are_told_in_the_users_file_or_said_to_be_resolved() {
        let text = "runs = 6\nseed = 3\n\n[dispersions]\n\"faults[0].at\" = { uniform = [\"5s\", \"30s\"] }\n\n\
                    [scenario]\nname = \"short\"\nduration = \"40s\"\n\n[[scenario.faults]]\nat = \"10s\"\n\
                    until = \"20s\"\nkind = \"clock\"\ntarget = \"FC\"\njump_s = 60\n";
        let c = Campaign::parse("c.toml", text).unwrap();
        let (k, e) = (0..6)
            .find_map(|k| c.resolve(k).err().map(|e| (k, e)))
            .unwrap();
        // `Campaign::resolve` locates it in the resolved scenario, under the campaign's name.
        assert!(
            e.to_string().starts_with(&format!("c.toml run {k}:")),
            "{e}"
        );
        let message = &e.0[0].message;
        assert!(
            message.starts_with(&format!("run {k}: must be after `at`")),
            "{e}"
        );
        // Line 13 of the campaign file: `until = "20s"`.
        assert_eq!(
            located(&c, k, &e).to_string(),
            format!("c.toml:13:9: field `scenario.faults[0].until`: {message}")
        );
        // The row of such a run says the same.
        assert_eq!(
            run_one(&c, k).verdict,
            RunVerdict::Error(located(&c, k, &e).to_string())
        );
        // A field the base does not have.
        let made = ScenarioErrors(vec![ScenarioError {
            file: "c.toml run 2".into(),
            line: Some(4),
            column: Some(1),
            field: "fc.initial_rate_deg_s".into(),
            message: "too fast".into(),
        }]);
        assert_eq!(
            located(&c, 2, &made).to_string(),
            "c.toml run 2: in the resolved scenario of run 2 (the base scenario with the run's draws written in, not a line of c.toml), line 4, column 1, field `fc.initial_rate_deg_s`: too fast"
        );
        // An error the campaign located in its own file stays as it is.
        let own = ScenarioErrors(vec![ScenarioError {
            file: "c.toml".into(),
            ..made.0[0].clone()
        }]);
        assert_eq!(located(&c, 2, &own).to_string(), own.0[0].to_string());
    }

    #[test]
    fn outputs_have_a_row_and_a_case_per_run_and_a_file_per_failure() {
        let c = campaign();
        let rows = run_all(&c, &(0..6).collect::<Vec<_>>(), 2, &|_| {});
        let dir = std::env::temp_dir().join(format!("m6p-campaign-{}", std::process::id()));
        // An earlier campaign's failure files go; other files stay.
        std::fs::create_dir_all(dir.join("failures")).unwrap();
        for f in [
            "run-999.toml",
            "run-999.min.toml",
            "run-999.mcap",
            "notes.txt",
        ] {
            std::fs::write(dir.join("failures").join(f), "old").unwrap();
        }
        write_outputs(&CampaignMeta::of(&c, 6), &rows, &dir).unwrap();
        assert!(dir.join("failures/notes.txt").exists());
        std::fs::remove_file(dir.join("failures/notes.txt")).unwrap();
        let csv = std::fs::read_to_string(dir.join("results.csv")).unwrap();
        assert_eq!(csv.lines().count(), 7, "{csv}");
        assert!(
            csv.starts_with(
                // No `max_rate_deg_s`: the scenario has no orbit, so no truth is published.
                "run,seed,commands[0].at,downlinked_bytes,min_soc,verdict,failed\n"
            ),
            "{csv}"
        );
        let junit = std::fs::read_to_string(dir.join("junit.xml")).unwrap();
        assert_eq!(junit.matches("<testcase").count(), 6);
        let failed: Vec<_> = rows
            .iter()
            .filter(|r| r.verdict != RunVerdict::Pass)
            .collect();
        for r in &failed {
            let f = dir.join(format!("failures/run-{}.toml", r.run));
            let text = std::fs::read_to_string(&f).unwrap();
            // The failure file is a scenario that fails the same way on its own.
            let s = crate::validate::parse("f", &text).unwrap();
            assert_eq!(s.seed, r.seed);
            let loaded = exec::Loaded {
                file: "f".into(),
                text: text.clone(),
                scenario: s,
            };
            let compiled = exec::compile_seeded(&loaded, None);
            let rt = crate::runtime::build_runtime_for(&compiled.opts).unwrap();
            let o = rt.block_on(exec::execute(compiled, &mut |_| {})).unwrap();
            assert!(!o.passed());
        }
        assert_eq!(
            std::fs::read_dir(dir.join("failures")).unwrap().count(),
            failed.len()
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn two_shards_merged_are_the_unsharded_run() {
        let c = campaign();
        let meta = CampaignMeta::of(&c, 6);
        let base = std::env::temp_dir().join(format!("m6p-campaign-shards-{}", std::process::id()));
        let whole = run_all(&c, &(0..6).collect::<Vec<_>>(), 2, &|_| {});
        write_outputs(&meta, &whole, &base.join("whole")).unwrap();
        let mut dirs = Vec::new();
        for i in 0..2 {
            let shard = Shard { index: i, count: 2 };
            let rows = run_all(&c, &shard.runs(6), 1, &|_| {});
            let d = base.join(format!("shard-{i}"));
            write_outputs(&meta, &rows, &d).unwrap();
            dirs.push(d);
        }
        let (_, merged) = merge(&dirs, &base.join("merged")).unwrap();
        assert_eq!(
            merged,
            whole
                .iter()
                .map(|r| {
                    let mut r = r.clone();
                    if r.verdict == RunVerdict::Pass {
                        r.scenario.clear();
                    }
                    r
                })
                .collect::<Vec<_>>()
        );
        for f in [
            "results.csv",
            "junit.xml",
            "campaign.json",
            "rows.jsonl",
            "report.html",
        ] {
            assert_eq!(
                std::fs::read(base.join("whole").join(f)).unwrap(),
                std::fs::read(base.join("merged").join(f)).unwrap(),
                "{f}"
            );
        }
        // A shard missing, or given twice, is an error naming it.
        let e = merge(&dirs[..1], &base.join("m2")).unwrap_err().to_string();
        assert!(e.contains("3 of 6 runs are in no shard"), "{e}");
        let e = merge(&[dirs[0].clone(), dirs[0].clone()], &base.join("m3"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("in two shards"), "{e}");
        std::fs::remove_dir_all(&base).ok();
    }

    /// A metric that JSON's shortest form reads back one ulp off without serde_json's
    /// `float_roundtrip` (3.7748095989378885 became 3.774809598937889): shards merged are
    /// still the unsharded run, byte for byte.
    #[test]
    fn merged_shards_keep_every_float_to_the_bit() {
        let meta = CampaignMeta::of(&campaign(), 2);
        let row = |run: u64| RunRow {
            run,
            seed: run,
            draws: BTreeMap::new(),
            verdict: RunVerdict::Pass,
            failed_kinds: BTreeMap::new(),
            metrics: [("max_rate_deg_s".to_owned(), 3.774_809_598_937_888_5)].into(),
            sessions: BTreeMap::new(),
            scenario: String::new(),
        };
        let base = std::env::temp_dir().join(format!("m6p-campaign-ulp-{}", std::process::id()));
        write_outputs(&meta, &[row(0), row(1)], &base.join("whole")).unwrap();
        let dirs: Vec<_> = (0..2)
            .map(|k| {
                let d = base.join(format!("shard-{k}"));
                write_outputs(&meta, &[row(k)], &d).unwrap();
                d
            })
            .collect();
        let (_, merged) = merge(&dirs, &base.join("merged")).unwrap();
        assert_eq!(merged, vec![row(0), row(1)]);
        for f in ["results.csv", "rows.jsonl", "report.html"] {
            assert_eq!(
                std::fs::read(base.join("whole").join(f)).unwrap(),
                std::fs::read(base.join("merged").join(f)).unwrap(),
                "{f}"
            );
        }
        std::fs::remove_dir_all(&base).ok();
    }

    /// Rows with sessions: `results.csv` has a column per session id and what it did
    /// (empty where the session did not run), and shards merged keep the sessions: the
    /// rows and every file are the unsharded run's.
    #[test]
    fn sessions_are_columns_of_the_csv_and_survive_a_merge() {
        let meta = CampaignMeta::of(&campaign(), 3);
        let tally = |ends: &[(SessionEnd, u32)], packets, bytes| SessionTally {
            payloads: [12].into(),
            ends: ends.iter().copied().collect(),
            packets,
            downlinked_bytes: bytes,
        };
        let row = |run: u64| {
            let sessions = match run {
                0 => [(1, tally(&[(SessionEnd::Done, 1)], 90, 9000))].into(),
                1 => [
                    (1, tally(&[(SessionEnd::NoAck, 1)], 0, 0)),
                    (2, tally(&[(SessionEnd::StillActive, 1)], 0, 300)),
                ]
                .into(),
                _ => BTreeMap::new(),
            };
            RunRow {
                run,
                seed: run,
                draws: BTreeMap::new(),
                verdict: RunVerdict::Pass,
                failed_kinds: BTreeMap::new(),
                metrics: BTreeMap::new(),
                sessions,
                scenario: String::new(),
            }
        };
        let rows: Vec<RunRow> = (0..3).map(row).collect();
        assert_eq!(
            results_csv(&rows),
            "run,seed,session_1_runs,session_1_done,session_1_no_ack,session_1_packets,session_1_downlinked_bytes,\
             session_2_runs,session_2_still_active,session_2_packets,session_2_downlinked_bytes,verdict,failed\n\
             0,0,1,1,0,90,9000,,,,,pass,\n\
             1,1,1,0,1,0,0,1,1,0,300,pass,\n\
             2,2,,,,,,,,,,pass,\n"
        );
        let base =
            std::env::temp_dir().join(format!("m6p-campaign-sessions-{}", std::process::id()));
        write_outputs(&meta, &rows, &base.join("whole")).unwrap();
        let dirs: Vec<_> = (0..2)
            .map(|i| {
                let d = base.join(format!("shard-{i}"));
                let part: Vec<RunRow> = Shard { index: i, count: 2 }
                    .runs(3)
                    .into_iter()
                    .map(row)
                    .collect();
                write_outputs(&meta, &part, &d).unwrap();
                d
            })
            .collect();
        let (_, merged) = merge(&dirs, &base.join("merged")).unwrap();
        assert_eq!(merged, rows);
        for f in ["results.csv", "rows.jsonl", "report.html"] {
            assert_eq!(
                std::fs::read(base.join("whole").join(f)).unwrap(),
                std::fs::read(base.join("merged").join(f)).unwrap(),
                "{f}"
            );
        }
        let html = std::fs::read_to_string(base.join("merged/report.html")).unwrap();
        assert!(
            html.contains("<td>1</td><td>12</td><td>2 of 3 runs</td>"),
            "{html}"
        );
        std::fs::remove_dir_all(&base).ok();
    }

    #[test]
    fn shards_come_from_the_flag_or_the_cluster_engine() {
        assert_eq!(Shard::parse("1/4"), Ok(Shard { index: 1, count: 4 }));
        assert!(Shard::parse("4/4").is_err() && Shard::parse("1").is_err());
        assert_eq!(
            Shard::parse("1/x"),
            Err(ShardError::NotANumber {
                text: "1/x".into(),
                part: "x".into()
            })
        );
        assert_eq!(
            Shard::parse("4/4").map_err(|e| e.to_string()),
            Err("`4/4`: the index must be below the count (0/4 .. 3/4)".to_owned())
        );
        assert_eq!(Shard { index: 1, count: 4 }.runs(10), [1, 5, 9]);
        let env = |vars: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                vars.iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| (*v).to_owned())
            }
        };
        assert_eq!(
            Shard::from_env(env(&[
                ("SLURM_ARRAY_TASK_ID", "2"),
                ("SLURM_ARRAY_TASK_COUNT", "4")
            ])),
            Ok(Some(Shard { index: 2, count: 4 }))
        );
        assert_eq!(
            Shard::from_env(env(&[
                ("JOB_COMPLETION_INDEX", "0"),
                ("JOB_COMPLETIONS", "3")
            ])),
            Ok(Some(Shard { index: 0, count: 3 }))
        );
        assert_eq!(
            Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "0")])),
            Err(ShardEnvError::NoCount {
                index_var: "JOB_COMPLETION_INDEX",
                count_var: "JOB_COMPLETIONS"
            })
        );
        assert_eq!(
            Shard::from_env(env(&[
                ("SLURM_ARRAY_TASK_ID", "4"),
                ("SLURM_ARRAY_TASK_COUNT", "4")
            ]))
            .map_err(|e| e.to_string()),
            Err(
                "from SLURM_ARRAY_TASK_ID and SLURM_ARRAY_TASK_COUNT: `4/4`: the index must be \
                 below the count (0/4 .. 3/4)"
                    .to_owned()
            )
        );
        assert_eq!(Shard::from_env(env(&[])), Ok(None));
    }

    /// A failure recorded again: a complete recording, failing the same way; a row that
    /// claims another failure is caught.
    #[test]
    fn a_recorded_failure_is_complete_and_fails_the_same_way() {
        let c = campaign();
        let rows = run_all(&c, &(0..6).collect::<Vec<_>>(), 1, &|_| {});
        let failed = rows.iter().find(|r| r.verdict != RunVerdict::Pass).unwrap();
        let dir = std::env::temp_dir().join(format!("m6p-campaign-rec-{}", std::process::id()));
        let path = dir.join("run.mcap");
        record_failure("f", failed, &path).unwrap();
        let summary = crate::recording::read_summary(&path).unwrap();
        assert!(summary.messages > 0 && summary.incomplete.is_none());
        let mut other = failed.clone();
        other.verdict = RunVerdict::Fail(vec![("something-else".into(), String::new())]);
        let e = record_failure("f", &other, &path).unwrap_err().to_string();
        assert!(e.contains("not deterministic"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
