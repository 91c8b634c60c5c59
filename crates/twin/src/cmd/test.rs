//! `m6p-twin test`: scenarios headless for CI: a table, JUnit XML, an exit status.

use std::path::PathBuf;

use anyhow::Context as _;
use m6p_twin::duration::format_instant;
use m6p_twin::exec;
use m6p_twin::runtime::build_runtime_for;

#[derive(Debug, clap::Args)]
pub struct TestArgs {
    /// Scenario files.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Write a JUnit XML report here.
    #[arg(long, value_name = "FILE")]
    pub junit: Option<PathBuf>,
    /// Seed, overriding every scenario's.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Scenarios run at once [default: the machine's cores]; those in real time or with
    /// links to the outside run one at a time all the same.
    #[arg(long)]
    pub jobs: Option<usize>,
    /// More of the runs' logs on stderr: `-v` their news (info), `-vv` debug detail
    /// [default: warnings only; RUST_LOG, when set, decides instead].
    #[arg(short, long, action = clap::ArgAction::Count)]
    pub verbose: u8,
}

/// One scenario of `m6p-twin test`: its table row (name, passed, failed, simulated s,
/// wall s, whether it did not run), its JUnit test cases and what it has to say on stderr.
pub struct ScenarioTested {
    pub row: (String, usize, usize, f64, f64, bool),
    pub cases: Vec<quick_junit::TestCase>,
    pub errors: Vec<String>,
    pub ok: bool,
}

/// Load, run and judge one scenario file; a panic in the run is its error. A self-contained
/// run (virtual time, no outside link) shares `turns` with the others like it; one in real
/// time or with links to the outside runs alone (two may listen on one port, and a run paced
/// by the wall clock should not share the CPU).
pub fn test_one(
    f: &std::path::Path,
    seed: Option<u64>,
    turns: &std::sync::RwLock<()>,
) -> ScenarioTested {
    test_one_with(f, seed, turns, |compiled| {
        build_runtime_for(&compiled.opts)
            .and_then(|rt| rt.block_on(exec::execute(compiled, &mut |_| {})))
    })
}

/// [`test_one`] with the run given: `run` takes the compiled scenario to its outcome.
pub fn test_one_with(
    f: &std::path::Path,
    seed: Option<u64>,
    turns: &std::sync::RwLock<()>,
    run: impl FnOnce(m6p_twin::plan::Compiled) -> anyhow::Result<exec::Outcome>,
) -> ScenarioTested {
    let started = std::time::Instant::now();
    let error_case = |name: &str, classname: &str, e: String| {
        let mut case = quick_junit::TestCase::new(
            name.to_owned(),
            quick_junit::TestCaseStatus::non_success(quick_junit::NonSuccessKind::Error),
        );
        case.set_classname(classname.to_owned());
        case.set_system_err(e);
        case.set_time(started.elapsed());
        case
    };
    let loaded = match exec::load(f) {
        Ok(l) => l,
        Err(e) => {
            let file = f.display().to_string();
            return ScenarioTested {
                cases: vec![error_case(&file, "scenario file", format!("{e:#}"))],
                errors: vec![format!("{e:#}")],
                row: (file, 0, 1, 0.0, started.elapsed().as_secs_f64(), true),
                ok: false,
            };
        }
    };
    let name = loaded.name();
    // Its log lines name it: scenarios side by side write to one stderr. At error level so
    // that no filter leaves a warning without it.
    let _span = tracing::error_span!("scenario", name = %name).entered();
    let compiled = exec::compile_seeded(&loaded, seed);
    let self_contained = compiled.opts.is_self_contained();
    let _beside = self_contained.then(|| {
        turns
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    });
    let _alone = (!self_contained).then(|| {
        turns
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    });
    let ran = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(compiled)))
        .unwrap_or_else(|p| {
            Err(anyhow::anyhow!(
                "panicked: {}",
                m6p_twin::campaign_run::panic_text(p.as_ref())
            ))
        });
    let out = match ran {
        Ok(out) => out,
        Err(e) => {
            return ScenarioTested {
                cases: vec![error_case(&name, &name, format!("{e:#}"))],
                errors: vec![format!("{name}: run failed: {e:#}")],
                row: (name, 0, 1, 0.0, started.elapsed().as_secs_f64(), true),
                ok: false,
            };
        }
    };
    let mut cases = Vec::with_capacity(out.verdicts.len());
    let mut errors = Vec::new();
    // The verdicts of one run share its time: each case gets an equal part, so that the
    // cases' times add up to the run's.
    let case_time = started.elapsed() / u32::try_from(out.verdicts.len().max(1)).unwrap_or(1);
    for v in &out.verdicts {
        let status = if v.passed {
            quick_junit::TestCaseStatus::success()
        } else {
            let mut st =
                quick_junit::TestCaseStatus::non_success(quick_junit::NonSuccessKind::Failure);
            st.set_message(format!("t = {}: {}", format_instant(v.t), v.observed));
            st
        };
        let mut case = quick_junit::TestCase::new(v.name.clone(), status);
        case.set_classname(name.as_str());
        case.set_time(case_time);
        case.set_system_out(format!("t = {}: {}", format_instant(v.t), v.observed));
        cases.push(case);
        if !v.passed {
            errors.push(format!(
                "FAIL {name}: {} (t = {}): {}",
                v.name,
                format_instant(v.t),
                v.observed
            ));
        }
    }
    // A run cut short is no result: an error case, whatever held so far.
    if let Some(i) = &out.report.interrupted {
        cases.push(error_case(&name, &name, i.to_string()));
        errors.push(format!("{name}: {i}"));
    }
    let failed = out.verdicts.iter().filter(|v| !v.passed).count();
    ScenarioTested {
        row: (
            name,
            out.verdicts.len() - failed,
            failed,
            out.report.sim_time.as_secs_f64(),
            out.report.wall.as_secs_f64(),
            out.report.interrupted.is_some(),
        ),
        cases,
        errors,
        ok: failed == 0 && out.report.interrupted.is_none(),
    }
}

pub fn cmd_test(a: TestArgs) -> anyhow::Result<bool> {
    use std::io::IsTerminal as _;
    let started = std::time::Instant::now();
    let show_bar = std::io::stderr().is_terminal() && std::env::var_os("CI").is_none();
    let total = a.files.len();
    let bar = if show_bar {
        let b = indicatif::ProgressBar::new(total as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let jobs = m6p_twin::campaign_run::default_jobs(a.jobs);
    let turns = std::sync::RwLock::new(());
    let done = std::sync::atomic::AtomicUsize::new(0);
    // The scenarios run side by side; each says how it went as it ends (its failures on
    // stdout, a progress line on stderr), and the table and the JUnit report are in the
    // files' order.
    let tested = m6p_twin::campaign_run::in_parallel(
        &a.files,
        jobs,
        &|f| test_one(f, a.seed, &turns),
        &|t| {
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            bar.suspend(|| {
                for e in &t.errors {
                    println!("{e}");
                }
                if !show_bar {
                    eprintln!("[{n}/{total}] {}", progress_line(t));
                }
            });
            bar.set_message(format!("done: {}", t.row.0));
            bar.inc(1);
        },
    );
    bar.finish_and_clear();
    let all_ok = tested.iter().all(|t| t.ok);
    print_table(&tested, started.elapsed());
    if let Some(path) = &a.junit {
        let mut report = quick_junit::Report::new("m6p-twin");
        for t in tested {
            let mut suite = quick_junit::TestSuite::new(t.row.0.clone());
            suite.set_time(std::time::Duration::from_secs_f64(t.row.4));
            suite.add_test_cases(t.cases);
            report.add_test_suite(suite);
        }
        report.set_time(started.elapsed());
        let xml = report.to_string().context("serialising the JUnit report")?;
        std::fs::write(path, xml).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(all_ok)
}

/// One scenario's progress line: `name: 12 passed, 1 failed (3.2 s)`.
fn progress_line(t: &ScenarioTested) -> String {
    let (name, p, f, _, wall, broken) = &t.row;
    if *broken {
        format!("{name}: did not run ({wall:.1} s)")
    } else {
        format!("{name}: {p} passed, {f} failed ({wall:.1} s)")
    }
}

/// The table, in the files' order, and the totals line.
fn print_table(tested: &[ScenarioTested], took: std::time::Duration) {
    println!(
        "{:<36} {:>6} {:>6} {:>12} {:>10} {:>12}",
        "scenario", "passed", "failed", "sim time s", "wall s", "real-time x"
    );
    for t in tested {
        let (name, p, f, sim, wall, broken) = &t.row;
        let rtf = if *wall > 0.0 { sim / wall } else { 0.0 };
        let note = if *broken { "  (did not run)" } else { "" };
        println!("{name:<36} {p:>6} {f:>6} {sim:>12.1} {wall:>10.3} {rtf:>12.0}{note}");
    }
    let passed: usize = tested.iter().map(|t| t.row.1).sum();
    let failed: usize = tested.iter().map(|t| t.row.2).sum();
    let broken = tested.iter().filter(|t| t.row.5).count();
    let not_run = if broken > 0 {
        format!(", {broken} did not run")
    } else {
        String::new()
    };
    println!(
        "\n{passed} passed, {failed} failed ({} scenario(s){not_run}) in {:.1} s",
        tested.len(),
        took.as_secs_f64()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run that panics is its scenario's error row, and the scenarios after it still run:
    /// the lock it held, shared (a self-contained run) or whole (one in real time), is free
    /// again and not poisoned.
    #[test]
    fn a_scenario_whose_run_panics_is_an_error_row() {
        let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let default = manifest.join("../../scenarios/default.toml");
        let realtime = std::env::temp_dir().join(format!(
            "m6p-twin-panic-{}-realtime.toml",
            std::process::id()
        ));
        let text = std::fs::read_to_string(&default).expect("default scenario");
        std::fs::write(&realtime, format!("{text}\n[clock]\nmode = \"realtime\"\n"))
            .expect("temp scenario");
        for (file, alone) in [(&default, false), (&realtime, true)] {
            let turns = std::sync::RwLock::new(());
            let t = test_one_with(file, None, &turns, |c| {
                assert_eq!(c.opts.is_self_contained(), !alone, "{}", file.display());
                panic!("a bug in the run")
            });
            assert!(!t.ok);
            assert!(t.row.5, "did not run");
            assert_eq!((t.row.1, t.row.2), (0, 1));
            assert_eq!(t.errors.len(), 1);
            assert!(
                t.errors[0].ends_with("run failed: panicked: a bug in the run"),
                "{:?}",
                t.errors
            );
            assert_eq!(t.cases.len(), 1);
            assert!(!turns.is_poisoned());
            assert!(turns.try_write().is_ok(), "the lock is free");
        }
        let _ = std::fs::remove_file(&realtime);
    }
}
