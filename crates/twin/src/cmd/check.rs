//! `m6p-twin check`: validate scenario files without running them.

use std::path::PathBuf;

use m6p_twin::exec;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scenario files.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
}

pub fn cmd_check(files: &[PathBuf]) -> anyhow::Result<bool> {
    let mut ok = true;
    for f in files {
        match exec::load(f) {
            Ok(l) => println!(
                "{}: OK ({} commands, {} faults, {} expectations)",
                l.file,
                l.scenario.commands.len(),
                l.scenario.faults.len() + l.scenario.fc.faults.len(),
                l.scenario.expectations.len()
            ),
            Err(e) => {
                ok = false;
                eprintln!("{e:#}");
            }
        }
    }
    Ok(ok)
}
