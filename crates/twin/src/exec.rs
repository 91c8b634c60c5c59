//! Running a scenario: load and validate the file, compile it, apply command-line
//! overrides, run, check the expectations, and report.

use std::path::Path;
use std::time::Duration;

use anyhow::Context as _;
use csp::SimTime;

use crate::events::RunEvent;
use crate::expectations::{Verdict, WatchCx, check_watched};
use crate::plan::{Compiled, compile};
use crate::report::{RunReport, run_with};
use crate::runtime::counters::RunSink;
use snap::Snap as _;
use twin_scenario::scenario::Scenario;

/// The embedded default scenario (`scenarios/default.toml`).
pub const DEFAULT_SCENARIO: &str = include_str!("../../../scenarios/default.toml");
/// The name the default scenario is reported under.
pub const DEFAULT_SCENARIO_FILE: &str = "scenarios/default.toml (embedded)";

/// A scenario file's text and its parsed form.
#[derive(Debug, Clone)]
pub struct Loaded {
    /// The file name as given.
    pub file: String,
    /// The exact text.
    pub text: String,
    /// The validated scenario.
    pub scenario: Scenario,
}

impl Loaded {
    /// The scenario's report name.
    pub fn name(&self) -> String {
        self.scenario.display_name(&self.file)
    }
}

/// Read and validate a scenario file.
pub fn load(path: &Path) -> anyhow::Result<Loaded> {
    let file = path.display().to_string();
    let text = twin_scenario::scenario::read_input(path)
        .with_context(|| format!("reading scenario {file}"))?;
    let scenario = crate::validate::parse(&file, &text)?;
    Ok(Loaded {
        file,
        text,
        scenario,
    })
}

/// The embedded default scenario.
pub fn load_default() -> anyhow::Result<Loaded> {
    let scenario = crate::validate::parse(DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO)?;
    Ok(Loaded {
        file: DEFAULT_SCENARIO_FILE.to_owned(),
        text: DEFAULT_SCENARIO.to_owned(),
        scenario,
    })
}

/// A `gs` command that works through a KISS link holding the CSP addresses `ids`: a
/// program there may only send from them, so `gs` takes one (a ground station's, if the
/// link holds one) and pings a node its segment reaches.
fn gs_hint(at: std::net::SocketAddr, ids: &[u8]) -> String {
    use platform::addr::Segment;
    let Some(&me) = ids
        .iter()
        .find(|&&id| Segment::of(id) == Segment::Ground)
        .or(ids.first())
    else {
        // A link holding no address learns its program's: `gs`'s own (17) will do.
        return format!("m6p-twin gs --connect {at} ping 3");
    };
    let target = match Segment::of(me) {
        Segment::Payload => 6,
        Segment::Ground => 3,
        _ if me == 3 => 4,
        _ => 3,
    };
    format!("m6p-twin gs --connect {at} --as {me} ping {target}")
}

/// What a scenario run produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The run's report.
    pub report: RunReport,
    /// One verdict per expectation, in file order.
    pub verdicts: Vec<Verdict>,
}

impl Outcome {
    /// Whether the run went to its end and every expectation (and checked invariant)
    /// held: an interrupted run passes nothing, whatever held so far.
    pub fn passed(&self) -> bool {
        self.report.interrupted.is_none() && self.verdicts.iter().all(|v| v.passed)
    }

    /// A table of the verdicts.
    pub fn verdict_table(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        if self.verdicts.is_empty() {
            return s;
        }
        let _ = writeln!(s, "\nexpectations:");
        for v in &self.verdicts {
            let _ = writeln!(
                s,
                "  {} {} (t = {}): {}",
                if v.passed { "PASS" } else { "FAIL" },
                v.name,
                crate::duration::format_instant(v.t),
                v.observed
            );
        }
        let failed = self.verdicts.iter().filter(|v| !v.passed).count();
        let _ = writeln!(
            s,
            "  {} passed, {} failed",
            self.verdicts.len() - failed,
            failed
        );
        if let Some(i) = &self.report.interrupted {
            let _ = writeln!(s, "  {i}: not a result");
        }
        s
    }
}

/// Run a compiled scenario, handing every event (expectation verdicts last) to `sink`.
/// The expectations that can judge the run as it goes do, and the report keeps only the
/// summaries of the samples, of the downlinked bytes and of the ground requests' outcomes,
/// so that memory does not grow with the simulated time.
pub async fn execute(
    compiled: Compiled,
    sink: &mut (dyn FnMut(&RunEvent) + Send),
) -> anyhow::Result<Outcome> {
    execute_keeping(compiled, false, sink).await
}

/// Say where the run's servers are bound, once the runtime has bound them (`ready`): each
/// KISS server with a hint that works, each UDP link and where it sends, each TCP console.
fn announce_bound(
    opts: &crate::runtime::RunOptions,
    ready: tokio::sync::oneshot::Receiver<Vec<std::net::SocketAddr>>,
) -> impl std::future::Future<Output = ()> + use<> {
    // The links that bind (KISS servers, UDP links) with their CSP addresses, in the order
    // the runtime binds them, so that a program starting the twin can tell its links apart
    // (`m6p.Twin` does).
    let listen_addrs: Vec<(crate::runtime::KissMode, Vec<u8>)> = opts
        .kiss_links
        .iter()
        .filter(|l| {
            matches!(
                l.mode,
                crate::runtime::KissMode::Listen(_) | crate::runtime::KissMode::Udp(_)
            )
        })
        .map(|l| (l.mode.clone(), l.cfg.addrs.clone()))
        .collect();
    // The TCP consoles' nodes, bound after the KISS servers.
    let consoles: Vec<String> = opts
        .uart
        .iter()
        .filter(|u| matches!(u.at, crate::runtime::UartAt::Tcp(_)))
        .map(|u| u.node.clone())
        .collect();
    let control = opts.control.as_ref().is_some_and(|c| c.listen.is_some());
    async move {
        if let Ok(mut addrs) = ready.await {
            // The control channel's, bound last.
            if control && let Some(a) = addrs.pop() {
                eprintln!(
                    "control channel: on {a} (try: m6p-twin gs --control {a} time); \
                     see docs/control.md"
                );
            }
            let (kiss, rest) = addrs.split_at(listen_addrs.len().min(addrs.len()));
            for (a, (mode, ids)) in kiss.iter().zip(&listen_addrs) {
                let csp = if ids.is_empty() {
                    String::new()
                } else {
                    format!(
                        " for CSP {}",
                        ids.iter().map(u8::to_string).collect::<Vec<_>>().join(", ")
                    )
                };
                match mode {
                    crate::runtime::KissMode::Udp(u) => eprintln!(
                        "CSP/UDP: on {a}{csp}, sending to {}",
                        u.peer
                            .map_or("the source of the latest datagram".to_owned(), |p| p
                                .to_string())
                    ),
                    _ => eprintln!(
                        "KISS/TCP: listening on {a}{csp} (try: {})",
                        gs_hint(*a, ids)
                    ),
                }
            }
            for (a, node) in rest.iter().zip(&consoles) {
                eprintln!(
                    "console of {node} (UART): on {a} (try: nc {} {}, then `help`)",
                    a.ip(),
                    a.port()
                );
            }
        }
    }
}

/// [`execute`], the report keeping every sample, downlinked byte and request outcome when
/// `keep` (`RunOptions::keep_series`), for the tests and programs that read them; the
/// verdicts are the same.
pub async fn execute_keeping(
    compiled: Compiled,
    keep: bool,
    sink: &mut (dyn FnMut(&RunEvent) + Send),
) -> anyhow::Result<Outcome> {
    execute_sink(compiled, keep, &mut |ev: &RunEvent| sink(ev)).await
}

/// The expectations' watches and the invariants, judging the run as it goes, then the
/// sink; their state is the expectations' part of a snapshot
/// ([`crate::snapshots::EXPECTATIONS_SECTION`]).
struct Watched<'a> {
    invariants: Option<crate::invariants::Invariants>,
    watches: Vec<Option<Box<dyn crate::expectations::Watch>>>,
    /// The kinds of event each watch looks at (it is handed only those: a virtual call per
    /// watch per frame otherwise).
    kinds: Vec<crate::events::Kinds>,
    sink: &'a mut dyn RunSink,
}

impl Watched<'_> {
    fn save(&self) -> Vec<u8> {
        let mut w = snap::Writer::new();
        if let Some(i) = &self.invariants {
            i.save(&mut w);
        }
        self.watches.iter().flatten().for_each(|x| x.save(&mut w));
        w.into_bytes()
    }

    fn load(&mut self, bytes: &[u8]) -> Result<(), snap::SnapError> {
        let mut r = snap::Reader::new(bytes);
        if let Some(i) = self.invariants.as_mut() {
            i.load(&mut r)?;
        }
        for x in self.watches.iter_mut().flatten() {
            x.load(&mut r)?;
        }
        r.finish()
    }
}

impl RunSink for Watched<'_> {
    fn event(&mut self, ev: &RunEvent) {
        if let Some(i) = self.invariants.as_mut() {
            i.observe(ev);
        }
        let kind = ev.kind();
        for (w, k) in self.watches.iter_mut().zip(&self.kinds) {
            if k.has(kind)
                && let Some(w) = w
            {
                w.observe(ev);
            }
        }
        self.sink.event(ev);
    }
    fn contact(&mut self, t: SimTime, on: bool) {
        self.sink.contact(t, on);
    }
    fn snapshot(
        &mut self,
        t: SimTime,
        by: twin_runtime::AskedBy,
        sections: &mut twin_runtime::Sections,
    ) {
        let part = self.save();
        sections.push((crate::snapshots::EXPECTATIONS_SECTION.to_owned(), part));
        self.sink.snapshot(t, by, sections);
    }
}

/// [`execute_keeping`] into any sink (one that takes snapshots too).
pub(crate) async fn execute_sink(
    mut compiled: Compiled,
    keep: bool,
    sink: &mut dyn RunSink,
) -> anyhow::Result<Outcome> {
    let (tx, rx) = tokio::sync::oneshot::channel::<Vec<std::net::SocketAddr>>();
    let print_listen = announce_bound(&compiled.opts, rx);
    let net = compiled.opts.network.clone();
    let icd = compiled.opts.icd_map();
    // The nodes that run: an outside program in a replaced node's place sends under its
    // link's name, not the node's.
    let mut running = net.clone();
    running
        .nodes
        .retain(|n| !compiled.opts.replaced.contains(&n.addr));
    let cx = WatchCx {
        tle: compiled.opts.tle.as_ref(),
        net: Some(&running),
        icd: Some(&icd),
    };
    let watches: Vec<_> = compiled.expectations.iter().map(|x| x.watch(&cx)).collect();
    let kinds: Vec<crate::events::Kinds> = watches
        .iter()
        .map(|w| {
            w.as_ref()
                .map_or(crate::events::Kinds::of(&[]), |w| w.kinds())
        })
        .collect();
    compiled.opts.keep_series = keep;
    // A watch that reads whole packets (`field`) gets the run's own (`RunEvent::Packet`).
    compiled.opts.packet_events |= kinds
        .iter()
        .any(|k| k.has(crate::events::EventKind::Packet));
    // The invariants the scenario checks (`[invariants] check`; a campaign's runs: all).
    let invariants = (!compiled.invariants.check.is_empty())
        .then(|| crate::invariants::Invariants::for_run(&compiled.opts, &compiled.invariants));
    let mut watched = Watched {
        invariants,
        watches,
        kinds,
        sink,
    };
    if let Some(r) = &compiled.opts.resume {
        watched
            .load(r.section(crate::snapshots::EXPECTATIONS_SECTION)?)
            .context("the snapshot's expectations do not fit this run")?;
    }
    let (report, ()) = tokio::join!(
        run_with(compiled.opts, Some(tx), &mut watched),
        print_listen
    );
    let report = report?;
    let Watched {
        invariants,
        watches,
        sink,
        ..
    } = watched;
    let mut verdicts = check_watched(&compiled.expectations, &watches, &report, &net);
    if let Some(i) = invariants {
        verdicts.extend(i.verdicts(&report));
    }
    for v in &verdicts {
        sink.event(&RunEvent::Expectation {
            t: v.t.min(report.sim_time),
            name: v.name.clone(),
            passed: v.passed,
            observed: v.observed.clone(),
        });
    }
    Ok(Outcome { report, verdicts })
}

/// Apply a different duration: commands after the end are simply not sent.
pub fn with_duration(c: &mut Compiled, d: Duration) {
    c.opts.duration = Some(d);
}

/// The simulated end of a compiled run, if bounded.
pub fn end_of(c: &Compiled) -> Option<SimTime> {
    c.opts.duration.map(|d| SimTime::ZERO + d)
}

/// Where a run records: the recording's name, and what it may do to a file already there.
#[derive(Debug, Clone, Copy)]
pub struct RecordTo<'a> {
    /// The recording's name.
    pub path: &'a Path,
    /// A file already at it: refused, or replaced when the recording is complete.
    pub existing: crate::record::Existing,
}

impl<'a> RecordTo<'a> {
    /// `path`, refusing a file already there.
    pub fn new(path: &'a Path) -> Self {
        RecordTo {
            path,
            existing: crate::record::Existing::Refuse,
        }
    }
    /// `path`, replacing a file already there (the twin's own: a benchmark's round, a
    /// campaign's failure run).
    pub fn replacing(path: &'a Path) -> Self {
        RecordTo {
            path,
            existing: crate::record::Existing::Replace,
        }
    }
}

/// What a recording came to: its figures, or why it stopped (the run went on without it).
pub type RecordingResult = Option<anyhow::Result<crate::record::RecordingStats>>;

/// Run a compiled scenario, recording everything to `record` when given. A recorder
/// error stops the recording (warned when it happens, returned with the outcome) but never
/// the run.
pub async fn execute_recorded(
    loaded: &Loaded,
    compiled: Compiled,
    record: Option<RecordTo<'_>>,
) -> anyhow::Result<(Outcome, RecordingResult)> {
    execute_with(loaded, compiled, record, &mut |_| {}).await
}

/// [`execute_recorded`] without writing the S-band downlink files (the benchmark's runs).
pub async fn execute_recorded_without_files(
    loaded: &Loaded,
    compiled: Compiled,
    record: Option<RecordTo<'_>>,
) -> anyhow::Result<(Outcome, RecordingResult)> {
    execute_inner(loaded, compiled, record, None, &mut |_| {}).await
}

/// [`execute_recorded`], also handing every event to `live` after the recorder (the live
/// view, `crate::live::LiveServer::publish`, with the `live` feature).
pub async fn execute_with(
    loaded: &Loaded,
    compiled: Compiled,
    record: Option<RecordTo<'_>>,
    live: &mut (dyn FnMut(&RunEvent) + Send),
) -> anyhow::Result<(Outcome, RecordingResult)> {
    let dir = downlink_dir(loaded, record.map(|r| r.path));
    execute_inner(loaded, compiled, record, dir.as_deref(), live).await
}

/// [`execute_recorded`] of a run that repeats another (a replay, a campaign's failure run):
/// its downlink goes beside its own recording `record` (`x.mcap` -> `x.downlink/`), never
/// into the scenario's `[pc] downlink_dir`, which holds the original run's. (The recording
/// keeps only each downlinked frame's length and CRC: the bytes are in those files.)
pub async fn execute_replay(
    loaded: &Loaded,
    compiled: Compiled,
    record: RecordTo<'_>,
) -> anyhow::Result<(Outcome, RecordingResult)> {
    let dir = record.path.with_extension("downlink");
    execute_inner(loaded, compiled, Some(record), Some(&dir), &mut |_| {}).await
}

async fn execute_inner(
    loaded: &Loaded,
    compiled: Compiled,
    record: Option<RecordTo<'_>>,
    downlink: Option<&Path>,
    live: &mut (dyn FnMut(&RunEvent) + Send),
) -> anyhow::Result<(Outcome, RecordingResult)> {
    // The ground sink's files grow as the bytes arrive.
    let mut files = downlink.map(crate::sessions::DownlinkFiles::new);
    if let (Some(f), Some(r)) = (files.as_mut(), &compiled.opts.resume)
        && let Ok(state) = r.section(DOWNLINK_SECTION)
    {
        f.resume(state)
            .context("the snapshot's downlink files' part")?;
    }
    let scenario = (loaded.name(), loaded.text.clone());
    let mut taker = crate::snapshots::Taker::new(scenario, &compiled.opts);
    let Some(RecordTo { path, existing }) = record else {
        let mut sink = Taking {
            events: live,
            files: files.as_mut(),
            recorder: None,
            taker: taker.as_mut(),
        };
        let outcome = execute_sink(compiled, false, &mut sink).await?;
        downlink_written(files)?;
        snapshots_written(taker)?;
        return Ok((outcome, None));
    };
    // The scenario is never recorded over, whatever `--overwrite` says.
    if let (Ok(a), Ok(b)) = (
        std::fs::canonicalize(path),
        std::fs::canonicalize(&loaded.file),
    ) && a == b
    {
        anyhow::bail!(
            "{} is the scenario itself: not recorded over",
            path.display()
        );
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let start_utc = crate::timefmt::format_utc(compiled.opts.epoch_unix_s as i64 * 1_000_000_000);
    let meta = crate::record::RecordingMeta {
        scenario_name: loaded.name(),
        scenario_toml: loaded.text.clone(),
        seed: compiled.opts.seed,
        start_utc,
        twin_version: env!("CARGO_PKG_VERSION").to_owned(),
        duration_ns: compiled
            .opts
            .duration
            .filter(|d| *d != loaded.scenario.duration.0)
            .map(|d| d.as_nanos() as u64),
        replaced: compiled.opts.replaced.iter().copied().collect(),
        link_addrs: compiled
            .opts
            .kiss_links
            .iter()
            .map(|l| (l.label(), l.cfg.addrs.clone()))
            .collect(),
        link_tx_budgets: compiled
            .opts
            .kiss_links
            .iter()
            .filter_map(|l| Some((l.label(), l.cfg.tx_frames_per_s?)))
            .collect(),
        channels: loaded.scenario.record.channels.clone(),
    };
    let mut recorder = crate::record::Recorder::create(path, meta, existing)?;
    recorder.set_icd(compiled.opts.icd_map());
    if let Some(r) = &compiled.opts.resume {
        let state = r.section(crate::record::RECORD_SECTION).context(
            "the snapshot was taken by a run that did not record (or whose recording had \
             stopped): a recording goes on only from a snapshot taken with --record",
        )?;
        let file = crate::snapshots::file_of(
            (&loaded.name(), &loaded.text),
            compiled.opts.seed,
            r.t,
            &r.sections,
        );
        recorder.resume(state, r.t, &file.encode())?;
    }
    // The recorder runs on a thread of its own, fed copies of the events in order; on the
    // wall clock its file is flushed every second (a process killed loses at most that).
    let every = (compiled.opts.clock != bus::ClockMode::Virtual)
        .then_some(std::time::Duration::from_secs(1));
    let mut recorder = crate::record::RecorderThread::start_flushing(recorder, every)?;
    // `/csp/packets` is the run's packets (`RunEvent::Packet`): reassembled for it unless
    // the recording leaves it out (an expectation or the live view may still want them).
    let mut compiled = compiled;
    compiled.opts.packet_events |=
        twin_scenario::channels::action(&loaded.scenario.record.channels, crate::record::TOPIC_CSP)
            != twin_scenario::channels::ChannelAction::Omit;
    let carried = crate::snapshots::Carried::plan(
        (loaded.name(), loaded.text.clone()),
        loaded.scenario.record.snapshot_every.map(|d| d.0),
        &mut compiled.opts,
    )?;
    let mut sink = Taking {
        events: live,
        files: files.as_mut(),
        recorder: Some((&mut recorder, carried)),
        taker: taker.as_mut(),
    };
    let outcome = execute_sink(compiled, false, &mut sink).await?;
    let stats = recorder.finish();
    downlink_written(files)?;
    snapshots_written(taker)?;
    Ok((outcome, Some(stats)))
}

/// A run's last sink: its events go to the recorder, then to `events`; its snapshots, with
/// the recorder's part, to their files and, those the recording carries, into it.
struct Taking<'a, F> {
    events: F,
    /// The ground sink's files.
    files: Option<&'a mut crate::sessions::DownlinkFiles>,
    recorder: Option<(
        &'a mut crate::record::RecorderThread,
        crate::snapshots::Carried,
    )>,
    taker: Option<&'a mut crate::snapshots::Taker>,
}

impl<F: FnMut(&RunEvent) + Send> RunSink for Taking<'_, F> {
    fn event(&mut self, ev: &RunEvent) {
        if let Some((r, _)) = self.recorder.as_mut() {
            r.write(ev);
        }
        if let Some(f) = self.files.as_mut() {
            f.observe(ev);
        }
        (self.events)(ev);
    }
    fn snapshot(
        &mut self,
        t: SimTime,
        by: twin_runtime::AskedBy,
        sections: &mut twin_runtime::Sections,
    ) {
        if let Some(f) = self.files.as_ref() {
            sections.push((DOWNLINK_SECTION.to_owned(), f.save()));
        }
        if let Some((r, carried)) = self.recorder.as_mut()
            && let Some(state) = r.snapshot()
        {
            sections.push((crate::record::RECORD_SECTION.to_owned(), state));
            if by == twin_runtime::AskedBy::Schedule && carried.carries(t) {
                r.attach_snapshot(t, carried.file(t, sections));
            }
        }
        if let Some(taker) = self.taker.as_mut() {
            taker.take(t, by, sections);
        }
    }
}

/// The name of the downlink files' part of a snapshot.
const DOWNLINK_SECTION: &str = "downlink";

/// Say where the snapshots went; a write that failed fails the command, after the run.
fn snapshots_written(taker: Option<crate::snapshots::Taker>) -> anyhow::Result<()> {
    let Some(taker) = taker else { return Ok(()) };
    for f in &taker.written {
        eprintln!("snapshot: {}", f.display());
    }
    match taker.failed {
        Some(e) => Err(e.context("writing a snapshot")),
        None => Ok(()),
    }
}

/// Where the S-band sink's files go: `[pc] downlink_dir`, else beside the recording
/// (`out/run.mcap` -> `out/run.downlink/`), else nowhere.
pub fn downlink_dir(loaded: &Loaded, record: Option<&Path>) -> Option<std::path::PathBuf> {
    match (&loaded.scenario.pc.downlink_dir, record) {
        (Some(d), _) => Some(d.into()),
        (None, Some(r)) => Some(r.with_extension("downlink")),
        (None, None) => None,
    }
}

/// Say where the downlinked data went (nothing when no session ran); a write that failed
/// fails the command, after the run and its recording are complete.
fn downlink_written(files: Option<crate::sessions::DownlinkFiles>) -> anyhow::Result<()> {
    let Some(f) = files else { return Ok(()) };
    if let Some(e) = f.first_error {
        anyhow::bail!(
            "writing the downlinked data: {e} ({} write(s) failed)",
            f.errors
        );
    }
    if !f.files.is_empty() {
        eprintln!(
            "downlink: {} session file(s) in {}",
            f.files.len(),
            f.dir_display()
        );
    }
    Ok(())
}

/// Compile a loaded scenario.
pub fn compile_loaded(l: &Loaded) -> Compiled {
    compile(&l.scenario)
}

/// Compile a loaded scenario with the run's seed `seed` (`--seed`, or a recording's) in
/// place of the file's: every random draw, the initial attitude and tumble axis included,
/// derives from it (docs/scenarios.md, "Seeds").
pub fn compile_seeded(l: &Loaded, seed: Option<u64>) -> Compiled {
    match seed {
        Some(seed) if seed != l.scenario.seed => {
            let mut s = l.scenario.clone();
            s.seed = seed;
            compile(&s)
        }
        _ => compile(&l.scenario),
    }
}
