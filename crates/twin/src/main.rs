//! The `m6p-twin` command line: one command a module of `cmd`.

use std::process::ExitCode;

use clap::Parser;

mod cmd {
    pub mod bench;
    pub mod campaign;
    pub mod check;
    pub mod diff;
    pub mod gs;
    pub mod icd;
    pub mod inspect;
    pub mod passes;
    pub mod replay;
    pub mod run;
    pub mod schema;
    pub mod test;
}

/// A digital twin of the NanoAvionics M6P smallsat network: every node speaks CSP 1.4 on
/// simulated CAN buses, and outside programs join over KISS/TCP.
#[derive(Debug, Parser)]
#[command(name = "m6p-twin", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Run a scenario (default: the embedded default scenario) and print what happened.
    Run(Box<cmd::run::RunArgs>),
    /// Run scenarios headless for CI: a table, JUnit XML, and a non-zero exit on failure.
    Test(cmd::test::TestArgs),
    /// Validate scenario files without running them.
    Check(cmd::check::Args),
    /// Print the JSON Schema of the scenario format, or of the campaign format (for editors).
    Schema(cmd::schema::Args),
    /// Print the ICD as data: every node, port and command, with the request and reply
    /// fields (type, offset, unit, range, named values), from the twin's own wire types.
    Icd(cmd::icd::Args),
    /// Fault campaigns: a scenario run many times with drawn values, every run checked.
    #[command(subcommand)]
    Campaign(cmd::campaign::CampaignCmd),
    /// Summarise a recording (channels, counts per node and port, expectations), export
    /// a channel to CSV, or show where its bytes go.
    Inspect(cmd::inspect::Args),
    /// Compare two recordings; exit 0 only when their bus traffic is identical.
    Diff(cmd::diff::Args),
    /// Re-run a recording's scenario with its seed and compare; exit 0 only when identical.
    Replay(cmd::replay::ReplayArgs),
    /// Measure a scenario in virtual time: real-time factor with and without recording,
    /// peak memory, and MCAP bytes per simulated hour (medians of --runs runs).
    Bench(cmd::bench::Args),
    /// One run of `bench` in a process of its own (what `bench` runs; prints its figures as
    /// JSON).
    #[command(hide = true)]
    BenchRun(cmd::bench::RunOneArgs),
    /// Join a running twin over KISS/TCP as a ground node and send requests.
    Gs(cmd::gs::GsArgs),
    /// List the passes of a scenario's orbit over its ground stations (`[comm] stations`,
    /// above `[comm] elevation_mask_deg`): rise, culmination, set (simulated seconds and
    /// UTC) and maximum elevation.
    Passes(cmd::passes::Args),
}

/// A reader that stops early (`m6p-twin run | head`) ends the process quietly, as a Unix
/// tool killed by SIGPIPE does (exit 141), instead of a panic from `println!`.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_broken_pipe();
    let matches = <Cli as clap::CommandFactory>::command().get_matches();
    let cli =
        <Cli as clap::FromArgMatches>::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // A benchmark runs the scenario many times, and `test` reports its verdicts on stdout:
    // only warnings, unless `-v` or RUST_LOG says more.
    let default_filter = match &cli.command {
        Command::Bench(_) | Command::BenchRun(_) | Command::Campaign(_) => "warn",
        Command::Test(a) => match a.verbose {
            0 => "warn",
            1 => "info,foxglove=warn",
            _ => "debug,foxglove=warn",
        },
        _ => "info,foxglove=warn",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| default_filter.into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let res = match cli.command {
        Command::Run(a) => cmd::run::cmd_run_from(&matches, *a),
        Command::Test(a) => cmd::test::cmd_test(a),
        Command::Check(a) => cmd::check::cmd_check(&a.files),
        Command::Schema(a) => cmd::schema::cmd_schema(a.campaign),
        Command::Icd(a) => cmd::icd::cmd_icd(a),
        Command::Campaign(c) => cmd::campaign::cmd_campaign(c),
        Command::Inspect(a) => cmd::inspect::cmd_inspect(&a.file, a.csv.as_deref(), a.sizes),
        Command::Diff(a) => cmd::diff::cmd_diff(&a),
        Command::Replay(a) => cmd::replay::cmd_replay(a),
        Command::Bench(a) => cmd::bench::cmd_bench(&a),
        Command::BenchRun(a) => cmd::bench::cmd_bench_run(&a),
        Command::Gs(a) => cmd::gs::cmd_gs(a),
        Command::Passes(a) => {
            cmd::passes::cmd_passes(a.scenario.as_deref(), a.station.as_deref(), a.duration)
        }
    };
    match res {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
