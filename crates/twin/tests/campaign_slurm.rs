//! A campaign on a real Slurm: a one-node cluster on this machine (`tools/slurm/cluster.sh`:
//! munged, slurmctld and slurmd with a generated slurm.conf), the campaign submitted as a
//! 4-task job array with `sbatch --array=0-3 --wait` (each task takes its shard from
//! `SLURM_ARRAY_TASK_ID`/`SLURM_ARRAY_TASK_COUNT`), the shards merged, and the result
//! compared with the local unsharded run.
//!
//! Needs root and Debian's `slurm-wlm` and `munge`: ignored with the reason where
//! `build.rs` does not find them, failing under `CI` (`.ci/run` installs them).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The cluster's daemons, stopped when dropped.
struct Cluster(PathBuf);

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        // A port of this process's own, so that two test runs do not meet.
        let port = 20_000 + (std::process::id() % 20_000) * 2;
        let out = Command::new(repo().join("tools/slurm/cluster.sh"))
            .arg("start")
            .arg(dir)
            .arg(port.to_string())
            .output()
            .unwrap();
        let c = Cluster(dir.to_owned());
        assert!(
            out.status.success(),
            "the cluster did not start: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        c
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(repo().join("tools/slurm/cluster.sh"))
            .arg("stop")
            .arg(&self.0)
            .status();
    }
}

#[test]
#[cfg_attr(
    not(slurm_available),
    ignore = "needs root with Debian's slurm-wlm and munge (apt-get install slurm-wlm munge; .ci/run installs them)"
)]
fn a_campaign_sharded_over_a_slurm_job_array_merges_to_the_unsharded_run() {
    let dir = std::env::temp_dir().join(format!("m6p-slurm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cluster = Cluster::start(&dir.join("cluster"));
    let twin = env!("CARGO_BIN_EXE_m6p-twin");
    let campaign = repo().join("crates/twin/tests/data/campaign-ping.toml");
    let script = dir.join("campaign.sbatch");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\n#SBATCH --array=0-3\n#SBATCH --output={out}/slurm-%A_%a.log\n\
             {twin} campaign run {campaign} --jobs 1 --out {out}/shard-$SLURM_ARRAY_TASK_ID\n\
             # A failed run is a row, not a failed task.\nexit 0\n",
            out = dir.display(),
            campaign = campaign.display()
        ),
    )
    .unwrap();
    let sbatch = Command::new("sbatch")
        .arg("--wait")
        .arg(&script)
        .env("SLURM_CONF", dir.join("cluster/slurm.conf"))
        .output()
        .unwrap();
    let logs = || {
        std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| {
                let p = e.unwrap().path();
                p.extension()
                    .is_some_and(|x| x == "log")
                    .then(|| std::fs::read_to_string(p).unwrap_or_default())
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert!(
        sbatch.status.success(),
        "sbatch: {}{}\n{}",
        String::from_utf8_lossy(&sbatch.stdout),
        String::from_utf8_lossy(&sbatch.stderr),
        logs()
    );
    drop(cluster);
    // Each task ran its own shard: 2, 2, 1 and 1 of the 6 runs.
    let mut shards = Vec::new();
    for i in 0..4 {
        let d = dir.join(format!("shard-{i}"));
        let csv = std::fs::read_to_string(d.join("results.csv"))
            .unwrap_or_else(|e| panic!("shard {i}: {e}\n{}", logs()));
        assert_eq!(csv.lines().count() - 1, if i < 2 { 2 } else { 1 }, "{csv}");
        shards.push(d);
    }
    let merged = dir.join("merged");
    let whole = dir.join("whole");
    for args in [
        vec!["campaign".into(), "merge".into()]
            .into_iter()
            .chain(shards.iter().map(|d| d.display().to_string()))
            .chain(["--out".into(), merged.display().to_string()])
            .collect::<Vec<String>>(),
        vec![
            "campaign".into(),
            "run".into(),
            campaign.display().to_string(),
            "--out".into(),
            whole.display().to_string(),
        ],
    ] {
        // Both exit 1: the campaign has failing runs by design.
        let out = Command::new(twin)
            .args(&args)
            .env_remove("SLURM_ARRAY_TASK_ID")
            .env_remove("JOB_COMPLETION_INDEX")
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?}: {out:?}");
    }
    for f in ["results.csv", "junit.xml", "rows.jsonl", "campaign.json"] {
        assert_eq!(
            std::fs::read_to_string(merged.join(f)).unwrap(),
            std::fs::read_to_string(whole.join(f)).unwrap(),
            "{f}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
