//! A run's snapshot files (docs/snapshots.md): `run --snapshot-at T --snapshot FILE` writes
//! one where the run settles at each instant, `run --from-snapshot FILE` starts a run from
//! one. The file is `twin_core::snapshot_file`'s container; its sections are the parts each
//! layer of the run saved (the runtime's, the report's, the expectations').

use std::path::{Path, PathBuf};

use csp::SimTime;
use twin_core::snapshot_file::{SnapshotFile, SnapshotHeader, build_id};
use twin_runtime::{AskedBy, Resume, Sections};

/// The name of the expectations' part of a snapshot (their watches and the invariants).
pub const EXPECTATIONS_SECTION: &str = "expectations";

/// Where a run's snapshots go, and what their header says.
#[derive(Debug)]
pub struct Taker {
    /// `--snapshot FILE`, for the instants of `--snapshot-at`.
    path: Option<PathBuf>,
    /// The instants it writes there (the run may take others, for its recording).
    at: Vec<SimTime>,
    /// More than one instant: each file is named for its instant.
    several: bool,
    /// `--snapshot-dir DIR`, for those the control channel asks for.
    dir: Option<PathBuf>,
    scenario_name: String,
    scenario_toml: String,
    seed: u64,
    /// The files written so far.
    pub written: Vec<PathBuf>,
    /// The first write that failed (the run goes on; the command fails at its end).
    pub failed: Option<anyhow::Error>,
}

impl Taker {
    /// The taker of the run of `scenario` (its name and text) with `opts`, if it takes
    /// snapshots.
    pub fn new(scenario: (String, String), opts: &twin_runtime::RunOptions) -> Option<Self> {
        let path = opts.snapshot_to.clone();
        let dir = opts.control.as_ref().and_then(|c| c.snapshot_dir.clone());
        if path.is_none() && dir.is_none() {
            return None;
        }
        let (scenario_name, scenario_toml) = scenario;
        Some(Taker {
            path,
            at: opts.snapshot_at.clone(),
            several: opts.snapshot_at.len() > 1,
            dir,
            scenario_name,
            scenario_toml,
            seed: opts.seed,
            written: Vec::new(),
            failed: None,
        })
    }

    /// Write the snapshot taken at `t`, if it is one of the taker's instants or the control
    /// channel asked for it.
    pub fn take(&mut self, t: SimTime, by: AskedBy, sections: &Sections) {
        let path = match (by, &self.path, &self.dir) {
            (AskedBy::Schedule, Some(path), _) if self.at.contains(&t) => {
                file_at(path, t, self.several)
            }
            (AskedBy::Control, _, Some(dir)) => dir.join(twin_runtime::control::snapshot_name(t)),
            _ => return,
        };
        let scenario = (self.scenario_name.as_str(), self.scenario_toml.as_str());
        let file = file_of(scenario, self.seed, t, sections);
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty())
            && let Err(e) = std::fs::create_dir_all(dir)
        {
            tracing::warn!(%t, "snapshot not written: creating {}: {e}", dir.display());
            self.failed
                .get_or_insert(anyhow::anyhow!("creating {}: {e}", dir.display()));
            return;
        }
        match file.write(&path) {
            Ok(()) => {
                tracing::info!(%t, "snapshot: {}", path.display());
                self.written.push(path);
            }
            Err(e) => {
                tracing::warn!(%t, "snapshot not written: {e}");
                self.failed.get_or_insert(e.into());
            }
        }
    }
}

/// The snapshots a recording carries (`[record] snapshot_every`, `run --snapshot-every`):
/// the instants, and what their files' headers say.
#[derive(Debug, Default)]
pub struct Carried {
    every: Option<std::time::Duration>,
    scenario_name: String,
    scenario_toml: String,
    seed: u64,
}

impl Carried {
    /// The snapshots the recording of the run of `scenario` (its name and text) with
    /// `opts` carries, one `every` (`[record] snapshot_every`): their instants, up to the
    /// run's end, join those the run takes.
    pub fn plan(
        scenario: (String, String),
        every: Option<std::time::Duration>,
        opts: &mut twin_runtime::RunOptions,
    ) -> anyhow::Result<Carried> {
        let Some(every) = every else {
            return Ok(Carried::default());
        };
        let Some(duration) = opts.duration else {
            anyhow::bail!(
                "record.snapshot_every: the run has no end (a recording carries a bounded number of snapshots)"
            );
        };
        twin_scenario::scenario::check_snapshot_every(every, duration)
            .map_err(|why| anyhow::anyhow!("record.snapshot_every: {why}"))?;
        let from = opts.resume.as_ref().map_or(SimTime::ZERO, |r| r.t);
        let mut t = SimTime::ZERO + every;
        while t < SimTime::ZERO + duration {
            if t > from {
                opts.snapshot_at.push(t);
            }
            t = t + every;
        }
        opts.snapshot_at.sort();
        opts.snapshot_at.dedup();
        Ok(Carried {
            every: Some(every),
            scenario_name: scenario.0,
            scenario_toml: scenario.1,
            seed: opts.seed,
        })
    }

    /// Whether the recording carries the snapshot at `t`.
    pub fn carries(&self, t: SimTime) -> bool {
        self.every.is_some_and(|every| {
            let every = u64::try_from(every.as_nanos()).unwrap_or(u64::MAX);
            t.as_ns() > 0 && t.as_ns() % every == 0
        })
    }

    /// The file of the snapshot at `t`, as the recording carries it.
    pub fn file(&self, t: SimTime, sections: &Sections) -> Vec<u8> {
        let scenario = (self.scenario_name.as_str(), self.scenario_toml.as_str());
        file_of(scenario, self.seed, t, sections).encode()
    }
}

/// The snapshot of the run of `scenario` (its name and text) with seed `seed` at `t`.
pub fn file_of(scenario: (&str, &str), seed: u64, t: SimTime, sections: &Sections) -> SnapshotFile {
    SnapshotFile {
        header: SnapshotHeader {
            build: build_id(),
            scenario_name: scenario.0.to_owned(),
            scenario_toml: scenario.1.to_owned(),
            seed,
            t_ns: t.as_ns(),
            sections: sections
                .iter()
                .map(|(n, b)| (n.clone(), b.len() as u64))
                .collect(),
        },
        sections: sections.iter().map(|(_, b)| b.clone()).collect(),
    }
}

/// The file of the snapshot at `t`: `path` itself, or with several instants `path` with
/// the instant in nanoseconds before its extension (`x.snap` -> `x.3600000000000ns.snap`).
pub fn file_at(path: &Path, t: SimTime, several: bool) -> PathBuf {
    if !several {
        return path.to_path_buf();
    }
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let name = match path.extension() {
        Some(ext) => format!("{stem}.{}ns.{}", t.as_ns(), ext.to_string_lossy()),
        None => format!("{stem}.{}ns", t.as_ns()),
    };
    path.with_file_name(name)
}

/// Where the run of `scenario` (its name and text) with seed `seed` starts from the
/// snapshot at `path`: refused, with the file's name and why, unless this build took it of
/// this scenario's text with this seed.
pub fn resume_from(path: &Path, scenario: (&str, &str), seed: u64) -> anyhow::Result<Resume> {
    resume_checked(path, SnapshotFile::read(path)?, scenario, seed)
}

/// [`resume_from`] a snapshot file's bytes, read from `path` (a recording carrying it).
pub fn resume_from_bytes(
    path: &Path,
    bytes: &[u8],
    scenario: (&str, &str),
    seed: u64,
) -> anyhow::Result<Resume> {
    resume_checked(path, SnapshotFile::decode(path, bytes)?, scenario, seed)
}

fn resume_checked(
    path: &Path,
    file: SnapshotFile,
    scenario: (&str, &str),
    seed: u64,
) -> anyhow::Result<Resume> {
    file.check(path, &build_id(), Some(scenario))?;
    if file.header.seed != seed {
        anyhow::bail!(
            "{}: a snapshot of the run with seed {}, not {seed}",
            path.display(),
            file.header.seed
        );
    }
    let sections = file
        .header
        .sections
        .iter()
        .map(|(n, _)| n.clone())
        .zip(file.sections)
        .collect();
    Ok(Resume {
        t: SimTime::from_ns(file.header.t_ns),
        sections,
        faults: twin_runtime::FaultsToCome::Saved,
    })
}
