//! `m6p-twin replay`: re-run a recording's scenario with its seed and outside input, and compare.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;
use m6p_twin::exec;
use m6p_twin::runtime::build_runtime_for;

#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// The MCAP recording to reproduce.
    pub file: PathBuf,
    /// Keep the new recording here (default: a temporary file, deleted afterwards).
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Compare from simulated time T on (90s, 10m, 2h), starting from the latest snapshot
    /// the recording carries at or before T (`run --snapshot-every`), else from the start
    /// (docs/snapshots.md, "Seeking a recording").
    #[arg(long, value_name = "T", value_parser = m6p_twin::duration::parse_duration)]
    pub from: Option<Duration>,
    /// Test-only: change a node's behaviour to prove that divergences are found
    /// (`fc-uptime-icd`).
    #[arg(long, hide = true)]
    pub test_knob: Option<String>,
}

/// The bytes outside programs sent on each KISS link of a recording, with their times.
pub fn recorded_kiss_input(
    file: &std::path::Path,
) -> anyhow::Result<Vec<m6p_twin::runtime::KissReplay>> {
    let mut links: std::collections::BTreeMap<String, Vec<m6p_twin::runtime::RecordedChunk>> =
        Default::default();
    let mut seq = 0u64;
    for m in m6p_twin::recording::messages(file)? {
        let m = m?;
        if !m.topic.starts_with("/kiss/") {
            continue;
        }
        let k: m6p_twin::record::KissFrameMsg = m
            .decode()
            .with_context(|| format!("decoding a {} message", m.topic))?;
        if k.dir == "in" {
            // In the file's order: the order the run took them in.
            seq += 1;
            links
                .entry(k.link)
                .or_default()
                .push(m6p_twin::runtime::RecordedChunk {
                    t: csp::SimTime(k.t_ns),
                    seq,
                    bytes: k.bytes.to_vec(),
                });
        }
    }
    Ok(links
        .into_iter()
        .map(|(link, chunks)| m6p_twin::runtime::KissReplay {
            link,
            chunks,
            cfg: Default::default(),
        })
        .collect())
}

/// The requests a recording's control channel took (`/control`), in the order it took them.
pub fn recorded_control(
    file: &std::path::Path,
) -> anyhow::Result<Vec<m6p_twin::runtime::control::RecordedRequest>> {
    let mut out = Vec::new();
    for m in m6p_twin::recording::messages(file)? {
        let m = m?;
        if &*m.topic != m6p_twin::record::TOPIC_CONTROL {
            continue;
        }
        let c: m6p_twin::record::ControlMsg = m
            .decode()
            .with_context(|| format!("decoding a {} message", m.topic))?;
        out.push(m6p_twin::runtime::control::RecordedRequest {
            t: csp::SimTime(c.t_ns),
            conn: c.conn,
            request: c.request,
        });
    }
    Ok(out)
}

pub fn cmd_replay(a: ReplayArgs) -> anyhow::Result<bool> {
    let meta = m6p_twin::recording::load_meta(&a.file)?;
    let file = format!(
        "{} (recorded scenario `{}`)",
        a.file.display(),
        meta.scenario_name
    );
    let mut scenario = m6p_twin::scenario::parse(&file, &meta.scenario_toml)?;
    // The channels the recording chose (the command line's `--channels` is not in the
    // scenario): the replay records the same ones, to compare like with like.
    scenario.record.channels = meta.channels.clone();
    let loaded = exec::Loaded {
        file,
        text: meta.scenario_toml.clone(),
        scenario,
    };
    let mut compiled = exec::compile_seeded(&loaded, Some(meta.seed));
    if let Some(d) = meta.duration_ns {
        compiled.opts.duration = Some(Duration::from_nanos(d));
    }
    if !compiled.opts.socketcan.is_empty() {
        anyhow::bail!(
            "this recording bridged a SocketCAN interface; replaying SocketCAN input is not supported yet"
        );
    }
    // What outside programs sent (from the scenario's links or the command line's) is in
    // the recording: feed it again in virtual time instead of opening sockets.
    let mut input = recorded_kiss_input(&a.file)?;
    if compiled.opts.has_outside_links() || !input.is_empty() {
        // Each recorded connection with its link's settings (its addresses above all).
        for r in &mut input {
            let link = r.link.split_once('#').map_or(r.link.as_str(), |(l, _)| l);
            // A hub's messages or datagrams, even when the link came from the command line.
            if let Some(k) = compiled.opts.kiss_links.iter().find(|k| k.label() == link) {
                r.cfg = k.cfg.clone();
            }
            if link.starts_with("zmq-hub ") {
                r.cfg.framing = links::kiss_tcp::Framing::ZmqHub;
            } else if link.starts_with("udp ") {
                r.cfg.framing = links::kiss_tcp::Framing::Udp;
            }
            // A command-line link's configured addresses and transmit budget, which the
            // scenario lacks.
            if r.cfg.addrs.is_empty()
                && let Some(addrs) = meta.link_addrs.get(link)
            {
                r.cfg.addrs.clone_from(addrs);
            }
            if let Some(&n) = meta.link_tx_budgets.get(link) {
                r.cfg.tx_frames_per_s = Some(n);
            }
        }
        // The nodes the recorded run's outside programs replaced, the command line's
        // (`--kiss-addr`) included, which the scenario does not name.
        compiled.opts.replaced.extend(meta.replaced.iter().copied());
        compiled.opts.kiss_links.clear();
        compiled.opts.clock = bus::ClockMode::Virtual;
        compiled.opts.kiss_replay = input;
        if compiled.opts.duration.is_none() {
            anyhow::bail!("the recorded run had no fixed duration");
        }
    }
    control_input(&a.file, &loaded, &mut compiled)?;
    let from_ns = seek(&a, &loaded, &mut compiled)?;
    match a.test_knob.as_deref() {
        None => {}
        Some("fc-uptime-icd") => {
            for n in compiled
                .opts
                .network
                .nodes
                .iter_mut()
                .filter(|n| n.addr == 3)
            {
                n.uptime = csp::service::UptimeFormat::IcdMillisLe;
            }
        }
        Some(k) => anyhow::bail!("unknown test knob `{k}`"),
    }
    // Without --record, a directory of its own (created exclusively, removed with all it
    // holds), never a predictable name another program could plant a link at.
    let scratch = match &a.record {
        Some(_) => None,
        None => Some(tempfile::tempdir().context("creating a temporary directory")?),
    };
    let path = match (&a.record, &scratch) {
        (Some(p), _) => p.clone(),
        (None, Some(d)) => d.path().join("replay.mcap"),
        (None, None) => anyhow::bail!("no recording path"),
    };
    let rt = build_runtime_for(&compiled.opts)?;
    let result = rt.block_on(exec::execute_replay(
        &loaded,
        compiled,
        exec::RecordTo::new(&path),
    ));
    let d = result
        .and_then(|(_, recorded)| recorded.transpose())
        .and_then(|_| m6p_twin::recording::diff_summary_from(&a.file, &path, 0, from_ns))
        .map(|d| d.result);
    drop(scratch);
    let d = d?;
    if from_ns > 0 {
        println!(
            "from t = {} on",
            m6p_twin::duration::format_duration(Duration::from_nanos(from_ns))
        );
    }
    println!("{d}");
    Ok(d.is_identical())
}

/// What the recording's control channel took, fed again at its instants.
fn control_input(
    file: &std::path::Path,
    loaded: &exec::Loaded,
    compiled: &mut m6p_twin::plan::Compiled,
) -> anyhow::Result<()> {
    // What the control channel took, fed again at its instants.
    let control = recorded_control(file)?;
    if !control.is_empty() {
        compiled.opts.control = Some(m6p_twin::runtime::control::ControlOptions {
            listen: None,
            faults: m6p_twin::faults::live(&loaded.scenario),
            replay: control,
            // A replay writes no snapshot: the run it repeats took them.
            snapshot_dir: None,
            inlet: None,
        });
        compiled.opts.clock = bus::ClockMode::Virtual;
        if compiled.opts.duration.is_none() {
            anyhow::bail!("the recorded run had no fixed duration");
        }
    }
    Ok(())
}

/// Where the replay starts and compares from: `--from T` or, for a recording made from a
/// snapshot, its start (whichever is later); the run starts from the latest snapshot the
/// recording carries at or before that instant. A run with outside input (a link's, the
/// control channel's) starts where its recording does, from t = 0 or from the snapshot a
/// recording made from one carries: the input came after it, and the links' connections
/// are in no snapshot. Returns the instant compared from, ns.
fn seek(
    a: &ReplayArgs,
    loaded: &exec::Loaded,
    compiled: &mut m6p_twin::plan::Compiled,
) -> anyhow::Result<u64> {
    let asked = a
        .from
        .map_or(0, |t| u64::try_from(t.as_nanos()).unwrap_or(u64::MAX));
    let probe = m6p_twin::recording::replay_start(&a.file, asked)?;
    let resumed_at = probe.resumed_at_ns;
    let from_ns = resumed_at.map_or(asked, |r| r.max(asked));
    let outside = !compiled.opts.kiss_replay.is_empty() || compiled.opts.control.is_some();
    let start_ns = if outside { resumed_at } else { Some(from_ns) };
    // From t = 0, no snapshot.
    let Some(start_ns) = start_ns else {
        return Ok(from_ns);
    };
    let start = if start_ns == asked {
        probe
    } else {
        m6p_twin::recording::replay_start(&a.file, start_ns)?
    };
    match start.snapshot {
        Some((_, bytes)) => {
            let scenario = (loaded.name(), loaded.text.as_str());
            match m6p_twin::snapshots::resume_from_bytes(
                &a.file,
                &bytes,
                (&scenario.0, scenario.1),
                compiled.opts.seed,
            ) {
                Ok(resume) => {
                    eprintln!("replaying from its snapshot at {}", resume.t);
                    compiled.opts.resume = Some(resume);
                }
                // A recording from the start runs from the start instead (slower, the same).
                Err(e) if resumed_at.is_none() => {
                    eprintln!("replaying from the start: its snapshot does not serve ({e:#})");
                }
                Err(e) => return Err(e),
            }
        }
        None if resumed_at.is_some() => anyhow::bail!(
            "{}: recorded from a snapshot it does not carry: not replayable",
            a.file.display()
        ),
        None => {}
    }
    Ok(from_ns)
}
