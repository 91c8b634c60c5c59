//! The run's control channel (`run --control ADDR`): line-delimited JSON over TCP, on the
//! loopback interface only, for a person or a script at a running twin: the simulated time
//! now, a fault of the scenario's catalogue injected now or at a later instant, a live
//! fault cleared (docs/control.md).
//!
//! A request enters the run as outside input does ([`bus::pace::take_in`]): at the first
//! idle point of a millisecond tick, in the order requests came, stamped with that tick's
//! instant. The run's loop answers it there, records it with its reply
//! ([`RunEvent::Control`]), and applies what it asked at that instant; `replay` feeds the
//! recorded requests again at their instants ([`ControlOptions::replay`]), so a live
//! session replays exactly.
//!
//! Bounded like every outside link: at most [`MAX_CONNECTIONS`] connections at once (one
//! more is told why and closed, counted and logged), lines of at most [`MAX_LINE`] bytes (a
//! longer one is refused whole, counted), one request in the run per connection at a time
//! (the next line is read after the reply), at most [`MAX_LIVE_FAULTS`] live faults and
//! [`MAX_ASKED_SNAPSHOTS`] snapshots a run.

use std::collections::{BTreeMap, VecDeque};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use anyhow::Context as _;
use csp::SimTime;
use serde::Deserialize;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot};
use twin_scenario::scenario::Dur;

use crate::faults::TimedFault;
use twin_core::events::RunEvent;

/// Connections served at once.
pub const MAX_CONNECTIONS: usize = 4;
/// Longest request line, bytes.
pub const MAX_LINE: usize = 4096;
/// Live faults a run takes (each is kept for `clear` until the run ends).
pub const MAX_LIVE_FAULTS: u32 = 10_000;
/// Snapshots a run takes on request (each some 50-400 kB on disk: docs/snapshots.md).
pub const MAX_ASKED_SNAPSHOTS: u32 = 100;
/// Fault ids of live faults start here (a scenario's faults are numbered from 0), so that
/// live and scenario faults on one medium or node compose.
pub const LIVE_FAULT_ID_BASE: u32 = 1 << 24;

/// What compiles a live fault into actions on the run's fault timeline: the scenario's
/// fault catalogue (the twin's `faults` module), given to the run by its caller.
pub trait LiveFaults: Send + Sync + std::fmt::Debug {
    /// The actions of `fault`, or why it cannot be injected.
    fn compile(&self, fault: &LiveFault) -> Result<Vec<TimedFault>, ControlError>;
}

/// Why a request on the control channel was refused (the reply's `error`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControlError {
    /// The line is not one of the requests.
    #[error("not a request: {0}")]
    NotARequest(String),
    /// [`MAX_LIVE_FAULTS`] were taken.
    #[error("this run took {MAX_LIVE_FAULTS} live faults already")]
    TooManyFaults,
    /// `at` is before the instant the request came at.
    #[error("`at` ({at}) has passed: the run is at {now}")]
    AtPassed {
        /// When the fault was to start.
        at: SimTime,
        /// The instant the request came at.
        now: SimTime,
    },
    /// Both `for` and `until`.
    #[error("give `for` or `until`, not both")]
    ForAndUntil,
    /// `for` of zero.
    #[error("`for` must be above zero")]
    ForZero,
    /// `until` at or before `at`.
    #[error("`until` must be after `at`")]
    UntilNotAfterAt,
    /// `at`, `for` or `until` among the kind's fields too.
    #[error("`{0}` given twice")]
    GivenTwice(&'static str),
    /// `clear` of a number the run did not give.
    #[error("no live fault {0} in this run")]
    NoLiveFault(u32),
    /// [`MAX_ASKED_SNAPSHOTS`] were taken.
    #[error("this run took {MAX_ASKED_SNAPSHOTS} snapshots on request already")]
    TooManySnapshots,
    /// A snapshot asked of a run with nowhere to write it.
    #[error("this run takes no snapshots on request: start it with --snapshot-dir DIR")]
    NoSnapshotDir,
    /// `clear` of a fault cleared before.
    #[error("live fault {0} was cleared already")]
    ClearedAlready(u32),
    /// The fields are not a fault entry.
    #[error("not a fault: {0}")]
    NotAFault(String),
    /// No `target`.
    #[error("a fault needs `target` (a medium, a node or a link)")]
    NoTarget,
    /// A kind that a node applies from its own timeline, set before the run.
    #[error(
        "a `{0}` fault acts on its node's own timeline, which is set before the run: put it \
         in the scenario's [[faults]]"
    )]
    NotLive(String),
    /// `for` or `until` on an instantaneous kind.
    #[error("a `{0}` fault is instantaneous: it takes no `for` or `until`")]
    Instantaneous(String),
    /// What the catalogue found wrong with its fields, as (field, why).
    #[error("{}", .0.iter().map(|(f, m)| format!("`{f}`: {m}")).collect::<Vec<_>>().join("; "))]
    Fields(Vec<(String, String)>),
}

/// One fault asked for on the control channel, its instants resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveFault {
    /// Its number in the run (`control[n]`), from 0.
    pub n: u32,
    /// When it starts.
    pub at: SimTime,
    /// When it is lifted, if it is.
    pub until: Option<SimTime>,
    /// The kind and its fields as a scenario's `[[faults]]` entry has them (`kind`,
    /// `target`, the kind's own), without `at` and `until`.
    pub fields: serde_json::Map<String, serde_json::Value>,
}

impl LiveFault {
    /// Its fault id (what composes it with the others on its medium or node).
    pub fn id(&self) -> u32 {
        LIVE_FAULT_ID_BASE.saturating_add(self.n)
    }
}

/// The control channel of a run.
#[derive(Debug, Clone)]
pub struct ControlOptions {
    /// Where to listen (a loopback address; port 0 picks one); `None`: no server (a
    /// replay).
    pub listen: Option<SocketAddr>,
    /// The fault catalogue.
    pub faults: Arc<dyn LiveFaults>,
    /// Recorded requests to feed again at their instants, in the recording's order.
    pub replay: Vec<RecordedRequest>,
    /// Where the snapshots the channel asks for go (`run --snapshot-dir`; each file named
    /// by [`snapshot_name`]); `None`: such requests are refused (a replay's too).
    pub snapshot_dir: Option<std::path::PathBuf>,
    /// Requests from within the process (the live view's clients), if any: [`inlet`].
    pub inlet: Option<Intake>,
}

/// The connection number of the requests that come through an [`Inlet`] (those of the
/// channel's TCP connections count from 1).
pub const INLET_CONN: u32 = 0;

/// Requests an [`Inlet`] holds before it refuses more (the run takes them in at its next
/// idle point: a client publishing faster than that is refused, counted).
pub const INLET_DEPTH: usize = 16;

/// Where requests from within the process come in (the live view's clients publishing on
/// `/control`): each one line of the channel's protocol, taken in as a connection's are
/// (connection [`INLET_CONN`]), its reply on `/control` with it. Bounded at
/// [`INLET_DEPTH`] and [`MAX_LINE`]; clones offer to the same run.
#[derive(Debug, Clone)]
pub struct Inlet {
    tx: mpsc::Sender<String>,
}

/// Why an [`Inlet`] refused a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum InletRefusal {
    /// [`INLET_DEPTH`] requests wait already.
    #[error("{INLET_DEPTH} requests wait already")]
    Full,
    /// Longer than [`MAX_LINE`] bytes.
    #[error("longer than {MAX_LINE} bytes")]
    TooLong,
    /// Not on one line.
    #[error("not one line")]
    NotOneLine,
    /// The run has ended (or never took the inlet).
    #[error("the run has ended")]
    Closed,
}

/// The run's side of an [`Inlet`]; a clone shares the one receiver, which the run takes.
#[derive(Debug, Clone)]
pub struct Intake(Arc<Mutex<Option<mpsc::Receiver<String>>>>);

/// An inlet and its intake (for [`ControlOptions::inlet`]).
pub fn inlet() -> (Inlet, Intake) {
    let (tx, rx) = mpsc::channel(INLET_DEPTH);
    (Inlet { tx }, Intake(Arc::new(Mutex::new(Some(rx)))))
}

impl Inlet {
    /// Hand `line` (one request) to the run, or say why not.
    pub fn offer(&self, line: String) -> Result<(), InletRefusal> {
        if line.len() > MAX_LINE {
            return Err(InletRefusal::TooLong);
        }
        if line.contains('\n') {
            return Err(InletRefusal::NotOneLine);
        }
        self.tx.try_send(line).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => InletRefusal::Full,
            mpsc::error::TrySendError::Closed(_) => InletRefusal::Closed,
        })
    }
}

/// Take in an inlet's requests for as long as the run lasts.
async fn take_inlet(
    mut rx: mpsc::Receiver<String>,
    clock: bus::Clock,
    to_run: mpsc::UnboundedSender<Admitted>,
) {
    while let Some(request) = rx.recv().await {
        let (tx, answered) = oneshot::channel();
        let to_run = to_run.clone();
        bus::pace::take_in(clock, move |t| {
            let _ = to_run.send(Admitted {
                t,
                conn: INLET_CONN,
                request,
                reply: Some(tx),
            });
        });
        // One request in the run at a time, as a connection's: the rest wait in the inlet,
        // whose bound then holds. (The reply is on `/control`, where the clients see it.)
        if answered.await.is_err() {
            return;
        }
    }
}

/// The file name of the snapshot the control channel asked for at `t`, in the run's
/// snapshot directory: the run names it, never the request.
pub fn snapshot_name(t: SimTime) -> String {
    format!("snapshot-{}ns.snap", t.as_ns())
}

/// A request as a recording keeps it (`/control`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedRequest {
    /// When the run took it in.
    pub t: SimTime,
    /// Its connection.
    pub conn: u32,
    /// The line.
    pub request: String,
}

/// What the control channel counted.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ControlStats {
    /// Connections served.
    pub connections: u64,
    /// Connections refused: [`MAX_CONNECTIONS`] were open.
    pub refused_connections: u64,
    /// Requests answered (refusals included).
    pub requests: u64,
    /// Lines longer than [`MAX_LINE`], refused whole.
    pub long_lines: u64,
    /// Connections closed because they began as an HTTP request (a browser page's
    /// `fetch` to the port: its body must not be taken for requests).
    pub http_closed: u64,
}

/// A request on its way to the run's loop.
#[derive(Debug)]
pub(crate) struct Admitted {
    pub t: SimTime,
    pub conn: u32,
    pub request: String,
    /// Where the reply goes (`None`: a replayed request).
    pub reply: Option<oneshot::Sender<String>>,
}

/// The control channel of a running run: where its requests come in, what judges them,
/// what it counted.
pub(crate) struct Control {
    rx: mpsc::UnboundedReceiver<Admitted>,
    catalogue: Option<Arc<dyn LiveFaults>>,
    stats: Arc<Mutex<ControlStats>>,
    /// Whether it takes the snapshots it is asked for.
    snapshots: OnRequest,
    /// How many it took.
    snapshots_taken: u32,
}

/// Whether a run takes the snapshots its control channel asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OnRequest {
    /// It has somewhere to write them (`run --snapshot-dir`).
    Take,
    /// It has not.
    Refuse,
}

impl Control {
    /// Start the run's control channel, if it has one: its server (its address added to
    /// `bound`) and the feed of a replay's recorded requests.
    pub async fn start(
        opts: Option<ControlOptions>,
        clock: bus::Clock,
        bound: &mut Vec<SocketAddr>,
        background: &mut Vec<tokio::task::JoinHandle<()>>,
    ) -> anyhow::Result<Control> {
        let (tx, rx) = mpsc::unbounded_channel();
        let stats = Arc::new(Mutex::new(ControlStats::default()));
        let Some(c) = opts else {
            return Ok(Control {
                rx,
                catalogue: None,
                stats,
                snapshots: OnRequest::Refuse,
                snapshots_taken: 0,
            });
        };
        if let Some(addr) = c.listen {
            bound.push(listen(addr, clock, &tx, &stats, background).await?);
        }
        let intake = c.inlet.and_then(|i| {
            i.0.lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .take()
        });
        if let Some(rx) = intake {
            background.push(tokio::spawn(take_inlet(rx, clock, tx.clone())));
        }
        if !c.replay.is_empty() {
            background.push(tokio::spawn(feed(c.replay, clock, tx)));
        }
        Ok(Control {
            rx,
            catalogue: Some(c.faults),
            stats,
            snapshots: match c.snapshot_dir {
                Some(_) => OnRequest::Take,
                None => OnRequest::Refuse,
            },
            snapshots_taken: 0,
        })
    }

    /// Whether the run has a control channel.
    pub fn is_on(&self) -> bool {
        self.catalogue.is_some()
    }

    /// The next request.
    pub fn recv(&mut self) -> impl Future<Output = Option<Admitted>> + '_ {
        self.rx.recv()
    }

    /// Answer `req` on `faults` (its actions due now are first in line): the reply goes
    /// back to its connection, and the event that records both; `asked` is told the
    /// instant of a snapshot it asked for and the run takes.
    pub fn answer(
        &mut self,
        req: Admitted,
        faults: &mut Timeline,
        asked: &mut dyn FnMut(SimTime),
    ) -> RunEvent {
        let snapshot = matches!(
            serde_json::from_str::<Request>(&req.request),
            Ok(Request::Snapshot {})
        );
        let reply = match self.catalogue.as_deref() {
            Some(_) if snapshot => {
                let taken = match self.snapshots {
                    OnRequest::Take if self.snapshots_taken < MAX_ASKED_SNAPSHOTS => {
                        self.snapshots_taken += 1;
                        asked(req.t);
                        Ok(serde_json::json!({ "snapshot": snapshot_name(req.t) }))
                    }
                    OnRequest::Take => Err(ControlError::TooManySnapshots),
                    OnRequest::Refuse => Err(ControlError::NoSnapshotDir),
                };
                reply_line(taken, req.t)
            }
            Some(c) => faults.answer(&req.request, req.t, c),
            None => String::new(),
        };
        count(&self.stats, |s| s.requests += 1);
        if let Some(tx) = req.reply {
            let _ = tx.send(reply.clone());
        }
        RunEvent::Control {
            t: req.t,
            conn: req.conn,
            request: req.request,
            reply,
        }
    }

    /// What it counted, if the run had one.
    pub fn stats(&self) -> Option<ControlStats> {
        self.catalogue.as_ref().map(|_| {
            self.stats
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .clone()
        })
    }
}

/// A request's reply line: what it gave, or why not, with `ok` and the instant.
fn reply_line(reply: Result<serde_json::Value, ControlError>, t: SimTime) -> String {
    let mut out = match reply {
        Ok(serde_json::Value::Object(m)) => m,
        Ok(_) => serde_json::Map::new(),
        Err(why) => {
            let mut m = serde_json::Map::new();
            m.insert("error".into(), why.to_string().into());
            m
        }
    };
    let ok = !out.contains_key("error");
    out.insert("ok".into(), ok.into());
    out.insert("t_ns".into(), t.as_ns().into());
    serde_json::Value::Object(out).to_string()
}

/// A request, as the JSON line says it.
#[derive(Debug, Deserialize)]
#[serde(tag = "op", rename_all = "kebab-case", deny_unknown_fields)]
enum Request {
    /// The simulated time now.
    Time {},
    /// Inject a fault.
    Fault(FaultFields),
    /// Lift live fault `id` now (and take its later actions off the timeline).
    Clear {
        /// Its number (`control[id]`).
        id: u32,
    },
    /// Take a snapshot of the run now, into its snapshot directory.
    Snapshot {},
}

/// A fault request: when, for how long, and the scenario entry's other fields.
#[derive(Debug, Deserialize)]
struct FaultFields {
    /// When it starts (simulated time since the run's start; default: now).
    #[serde(default)]
    at: Option<Dur>,
    /// How long it lasts.
    #[serde(default, rename = "for")]
    lasting: Option<Dur>,
    /// When it is lifted (simulated time).
    #[serde(default)]
    until: Option<Dur>,
    #[serde(flatten)]
    fields: serde_json::Map<String, serde_json::Value>,
}

/// A live fault the run took, for `clear`.
#[derive(Debug)]
struct Taken {
    fault: LiveFault,
    cleared: bool,
}

/// The live faults of a run and the fault timeline they share with the scenario's.
#[derive(Debug, Default)]
pub(crate) struct Timeline {
    /// Actions in time order (equal instants in the order they were put there), each with
    /// the live fault it belongs to.
    queue: VecDeque<(Option<u32>, TimedFault)>,
    live: BTreeMap<u32, Taken>,
    /// How many of the scenario's actions were taken (the first of its list).
    scenario_taken: usize,
}

impl Timeline {
    /// The scenario's timeline (in time order).
    pub fn new(faults: Vec<TimedFault>) -> Self {
        Timeline {
            queue: faults.into_iter().map(|f| (None, f)).collect(),
            live: BTreeMap::new(),
            scenario_taken: 0,
        }
    }

    /// After a snapshot of another run was loaded (a campaign's fork): the scenario's
    /// actions to come are this run's own, `own` (its whole list, in time order) less as
    /// many of its first as the snapshot's run had taken: the runs share those, and
    /// differ only after the snapshot's instant. A snapshot with live faults is refused
    /// (they are the other run's).
    pub fn take_own(&mut self, own: Vec<TimedFault>) -> Result<(), snap::SnapError> {
        if !self.live.is_empty() {
            return Err(snap::SnapError::Unsupported(
                "a fork from a snapshot with live faults".into(),
            ));
        }
        if own.len() < self.scenario_taken {
            return Err(snap::SnapError::Mismatch {
                what: "scenario fault actions taken before the fork",
                saved: self.scenario_taken as u64,
                built: own.len() as u64,
            });
        }
        self.queue = own
            .into_iter()
            .skip(self.scenario_taken)
            .map(|f| (None, f))
            .collect();
        Ok(())
    }

    /// The next action's instant.
    pub fn next_at(&self) -> Option<SimTime> {
        self.queue.front().map(|(_, f)| f.at)
    }

    /// The next action if it is due by `t`.
    pub fn pop_due(&mut self, t: SimTime) -> Option<TimedFault> {
        if self.next_at()? <= t {
            let (n, f) = self.queue.pop_front()?;
            if n.is_none() {
                self.scenario_taken += 1;
            }
            Some(f)
        } else {
            None
        }
    }

    /// Put `f` after every action at or before its instant.
    fn insert(&mut self, n: Option<u32>, f: TimedFault) {
        let i = self.queue.partition_point(|(_, g)| g.at <= f.at);
        self.queue.insert(i, (n, f));
    }

    /// Answer `req` taken in at `t`: the reply line, and the actions are on the timeline
    /// (those due at `t` first in line).
    pub fn answer(&mut self, req: &str, t: SimTime, catalogue: &dyn LiveFaults) -> String {
        let reply = match serde_json::from_str::<Request>(req) {
            Err(e) => Err(ControlError::NotARequest(e.to_string())),
            Ok(Request::Time {}) => Ok(serde_json::json!({})),
            Ok(Request::Fault(f)) => self.inject(f, t, catalogue),
            Ok(Request::Clear { id }) => self.clear(id, t, catalogue),
            // The run's control channel takes these ([`Control::answer`]).
            Ok(Request::Snapshot {}) => Err(ControlError::NoSnapshotDir),
        };
        reply_line(reply, t)
    }

    fn inject(
        &mut self,
        f: FaultFields,
        t: SimTime,
        catalogue: &dyn LiveFaults,
    ) -> Result<serde_json::Value, ControlError> {
        let n = u32::try_from(self.live.len()).unwrap_or(u32::MAX);
        if n >= MAX_LIVE_FAULTS {
            return Err(ControlError::TooManyFaults);
        }
        let at = f.at.map_or(t, |d| SimTime::ZERO + d.0);
        if at < t {
            return Err(ControlError::AtPassed { at, now: t });
        }
        let until = match (f.lasting, f.until) {
            (Some(_), Some(_)) => return Err(ControlError::ForAndUntil),
            (Some(d), None) if d.0.is_zero() => return Err(ControlError::ForZero),
            (Some(d), None) => Some(at + d.0),
            (None, Some(u)) if SimTime::ZERO + u.0 <= at => {
                return Err(ControlError::UntilNotAfterAt);
            }
            (None, Some(u)) => Some(SimTime::ZERO + u.0),
            (None, None) => None,
        };
        for k in ["at", "until", "for"] {
            if f.fields.contains_key(k) {
                return Err(ControlError::GivenTwice(k));
            }
        }
        let fault = LiveFault {
            n,
            at,
            until,
            fields: f.fields,
        };
        let actions = catalogue.compile(&fault)?;
        let what = actions.first().map(|a| a.what.clone()).unwrap_or_default();
        for a in actions {
            self.insert(Some(n), a);
        }
        let mut reply = serde_json::json!({ "id": n, "what": what, "at_ns": at.as_ns() });
        if let Some(u) = until {
            reply["until_ns"] = u.as_ns().into();
        }
        self.live.insert(
            n,
            Taken {
                fault,
                cleared: false,
            },
        );
        Ok(reply)
    }

    fn clear(
        &mut self,
        id: u32,
        t: SimTime,
        catalogue: &dyn LiveFaults,
    ) -> Result<serde_json::Value, ControlError> {
        let Some(taken) = self.live.get_mut(&id) else {
            return Err(ControlError::NoLiveFault(id));
        };
        if taken.cleared {
            return Err(ControlError::ClearedAlready(id));
        }
        taken.cleared = true;
        let fault = taken.fault.clone();
        let pending = self.queue.len();
        self.queue.retain(|(n, _)| *n != Some(id));
        let started = fault.at <= t;
        let over = fault.until.is_some_and(|u| u <= t);
        let mut lifted = Vec::new();
        if started && !over {
            // Its lift is what compiling it again with `until` now puts there: the actions
            // at `until` (strictly after `at`, so none of its start). At the instant it
            // started, a nanosecond later.
            let until = t.max(fault.at + std::time::Duration::from_nanos(1));
            let again = LiveFault {
                until: Some(until),
                ..fault
            };
            lifted = catalogue
                .compile(&again)?
                .into_iter()
                .filter(|a| a.at == until)
                .collect();
        }
        let lifts = lifted.len();
        for a in lifted {
            self.insert(Some(id), a);
        }
        let was = match (started, over) {
            (false, _) => "pending",
            (true, false) => "active",
            (true, true) => "over",
        };
        Ok(serde_json::json!({
            "id": id,
            "was": was,
            "taken_off": pending + lifts - self.queue.len(),
            "lifted": lifts > 0,
        }))
    }
}

/// Serve the run's control channel on `addr` (a loopback address: anything else is
/// refused, as the channel can cut any node's power); the bound address.
async fn listen(
    addr: SocketAddr,
    clock: bus::Clock,
    to_run: &mpsc::UnboundedSender<Admitted>,
    stats: &Arc<Mutex<ControlStats>>,
    background: &mut Vec<tokio::task::JoinHandle<()>>,
) -> anyhow::Result<SocketAddr> {
    if !addr.ip().is_loopback() {
        anyhow::bail!(
            "--control {addr}: the control channel listens on a loopback address only \
             (127.0.0.1 or ::1): it can power nodes off"
        );
    }
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("control channel: listening on {addr}"))?;
    let local = listener.local_addr().context("reading the bound address")?;
    tracing::info!("control channel on {local}");
    background.push(tokio::spawn(serve(
        listener,
        clock,
        to_run.clone(),
        stats.clone(),
    )));
    Ok(local)
}

/// Serve the control channel on `listener` for as long as the run lasts: each line handed
/// to the run at its next idle point, its reply written back.
pub(crate) async fn serve(
    listener: tokio::net::TcpListener,
    clock: bus::Clock,
    to_run: mpsc::UnboundedSender<Admitted>,
    stats: Arc<Mutex<ControlStats>>,
) {
    let open = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    let mut conns = 0u32;
    loop {
        let (mut stream, peer) = match listener.accept().await {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("control: accept failed: {e}");
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(permit) = open.clone().try_acquire_owned() else {
            count(&stats, |s| s.refused_connections += 1);
            tracing::warn!("control: {peer} refused: {MAX_CONNECTIONS} connections are open");
            let line = serde_json::json!({
                "ok": false,
                "error": format!("{MAX_CONNECTIONS} control connections are open already"),
            });
            let _ = stream.write_all(format!("{line}\n").as_bytes()).await;
            continue;
        };
        conns += 1;
        count(&stats, |s| s.connections += 1);
        tracing::info!("control: {peer} connected (connection {conns})");
        let (to_run, stats) = (to_run.clone(), stats.clone());
        tokio::spawn(async move {
            let why = connection(stream, conns, clock, &to_run, &stats).await;
            tracing::info!("control: {peer} closed ({why})");
            drop(permit);
        });
    }
}

fn count(stats: &Mutex<ControlStats>, f: impl FnOnce(&mut ControlStats)) {
    f(&mut stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner));
}

/// One connection: a line, its reply, until the peer closes.
async fn connection(
    stream: tokio::net::TcpStream,
    conn: u32,
    clock: bus::Clock,
    to_run: &mpsc::UnboundedSender<Admitted>,
    stats: &Mutex<ControlStats>,
) -> String {
    let (read, mut write) = stream.into_split();
    let mut read = tokio::io::BufReader::new(read);
    let mut line = Vec::with_capacity(256);
    let mut first = true;
    loop {
        line.clear();
        // At most MAX_LINE + 1 bytes are kept of a line: a longer one is refused whole and
        // its rest skipped.
        let n = match (&mut read)
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut line)
            .await
        {
            Ok(0) => return "end of stream".into(),
            Ok(n) => n,
            Err(e) => return e.to_string(),
        };
        let reply = if line.last() != Some(&b'\n') && n > MAX_LINE {
            count(stats, |s| s.long_lines += 1);
            if let Err(e) = skip_line(&mut read).await {
                return e.to_string();
            }
            serde_json::json!({
                "ok": false,
                "error": format!("line longer than {MAX_LINE} bytes"),
            })
            .to_string()
        } else {
            let text = String::from_utf8_lossy(&line).trim().to_owned();
            if std::mem::take(&mut first) && http_request_line(&text) {
                count(stats, |s| s.http_closed += 1);
                return "an HTTP request (a browser page's?): closed unanswered".into();
            }
            if text.is_empty() {
                continue;
            }
            let (tx, rx) = oneshot::channel();
            let to_run = to_run.clone();
            bus::pace::take_in(clock, move |t| {
                let _ = to_run.send(Admitted {
                    t,
                    conn,
                    request: text,
                    reply: Some(tx),
                });
            });
            match rx.await {
                Ok(r) => r,
                Err(_) => return "the run has ended".into(),
            }
        };
        if let Err(e) = write.write_all(format!("{reply}\n").as_bytes()).await {
            return e.to_string();
        }
    }
}

/// Whether `line` is an HTTP request line (`POST / HTTP/1.1`): any web page may send one
/// to a loopback port, with a body of its choosing, so a connection that begins so is no
/// client of the channel.
fn http_request_line(line: &str) -> bool {
    let mut words = line.split_ascii_whitespace();
    let method = words.next().unwrap_or_default();
    let version = words.nth(1).unwrap_or_default();
    !method.is_empty()
        && method.bytes().all(|b| b.is_ascii_uppercase())
        && version.starts_with("HTTP/")
}

/// Read up to the end of the current line.
async fn skip_line<R: tokio::io::AsyncBufRead + Unpin>(r: &mut R) -> std::io::Result<()> {
    loop {
        let buf = r.fill_buf().await?;
        if buf.is_empty() {
            return Ok(());
        }
        if let Some(i) = buf.iter().position(|&b| b == b'\n') {
            r.consume(i + 1);
            return Ok(());
        }
        let n = buf.len();
        r.consume(n);
    }
}

/// Feed recorded requests again at their instants (a replay): each taken in at the first
/// idle point of its tick, as it was.
pub(crate) async fn feed(
    requests: Vec<RecordedRequest>,
    clock: bus::Clock,
    to_run: mpsc::UnboundedSender<Admitted>,
) {
    for r in requests {
        clock.sleep_until(r.t).await;
        let to_run = to_run.clone();
        bus::pace::take_in(clock, move |t| {
            let _ = to_run.send(Admitted {
                t,
                conn: r.conn,
                request: r.request,
                reply: None,
            });
        });
    }
}

// The state a snapshot saves (docs/snapshots.md): the timeline's actions to come, the live
// faults taken (their fields as the JSON they came in).
impl snap::Snap for LiveFault {
    fn save(&self, w: &mut snap::Writer) {
        let LiveFault {
            n,
            at,
            until,
            fields,
        } = self;
        n.save(w);
        at.save(w);
        until.save(w);
        serde_json::Value::Object(fields.clone())
            .to_string()
            .save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        *self = <LiveFault as snap::SnapNew>::read(r)?;
        Ok(())
    }
}

impl snap::SnapNew for LiveFault {
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        let n = u32::read(r)?;
        let at = SimTime::read(r)?;
        let until = Option::read(r)?;
        let json_at = r.at();
        let fields = match serde_json::from_str(&String::read(r)?) {
            Ok(serde_json::Value::Object(m)) => m,
            _ => {
                return Err(snap::SnapError::Bad {
                    what: "a live fault's fields",
                    at: json_at,
                });
            }
        };
        Ok(LiveFault {
            n,
            at,
            until,
            fields,
        })
    }
}

snap::fields!(Taken { fault, cleared });
snap::fields!(Timeline {
    queue,
    live,
    scenario_taken
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::faults::FaultAction;

    #[test]
    fn a_connection_that_begins_as_an_http_request_is_no_client() {
        assert!(http_request_line("POST / HTTP/1.1"));
        assert!(http_request_line("GET /x?y HTTP/1.0"));
        assert!(!http_request_line(r#"{"op":"time"}"#));
        assert!(!http_request_line("post / http/1.1"));
        assert!(!http_request_line(""));
    }

    /// An inlet holds at most INLET_DEPTH requests, each one line of at most MAX_LINE
    /// bytes, and refuses once its run is gone.
    #[test]
    fn an_inlet_is_bounded_and_refuses_once_its_run_is_gone() {
        let (inlet, intake) = inlet();
        for i in 0..INLET_DEPTH {
            assert_eq!(inlet.offer(format!("{{\"n\":{i}}}")), Ok(()));
        }
        assert_eq!(inlet.offer("{}".into()), Err(InletRefusal::Full));
        assert_eq!(inlet.offer("{\n}".into()), Err(InletRefusal::NotOneLine));
        let long = format!("\"{}\"", "x".repeat(MAX_LINE));
        assert_eq!(inlet.offer(long), Err(InletRefusal::TooLong));
        drop(intake);
        assert_eq!(inlet.offer("{}".into()), Err(InletRefusal::Closed));
    }

    /// A catalogue of one kind, `power-off` of a node by address, lasting.
    #[derive(Debug)]
    struct PowerOnly;

    impl LiveFaults for PowerOnly {
        fn compile(&self, f: &LiveFault) -> Result<Vec<TimedFault>, ControlError> {
            if f.fields.get("kind").and_then(|k| k.as_str()) != Some("power-off") {
                return Err(ControlError::Fields(vec![(
                    "kind".into(),
                    "unknown kind".into(),
                )]));
            }
            let addr = f.fields["target"].as_u64().unwrap() as u8;
            let act = |off| FaultAction::Power {
                addr,
                fault: f.id(),
                off,
            };
            let what = format!("control[{}]: PowerOff on {addr}", f.n);
            let mut v = vec![TimedFault {
                at: f.at,
                action: act(true),
                what: what.clone(),
            }];
            if let Some(u) = f.until {
                v.push(TimedFault {
                    at: u,
                    action: act(false),
                    what: format!("{what} (power on)"),
                });
            }
            Ok(v)
        }
    }

    fn s(secs: u64) -> SimTime {
        SimTime::from_secs(secs)
    }

    fn reply(r: &str) -> serde_json::Value {
        serde_json::from_str(r).unwrap()
    }

    /// A fault for 5 s from now goes on the timeline with its lift, in time order with the
    /// scenario's; clearing it at once takes both off; the time request answers the
    /// instant; bad requests are refused with why.
    #[test]
    fn faults_go_on_the_timeline_and_clear_takes_them_off() {
        let scenario = TimedFault {
            at: s(7),
            action: FaultAction::Reboot(3),
            what: "faults[0]: Reboot on FC".into(),
        };
        let mut tl = Timeline::new(vec![scenario]);
        let r = reply(&tl.answer(
            r#"{"op":"fault","kind":"power-off","target":12,"for":"5s"}"#,
            s(4),
            &PowerOnly,
        ));
        assert_eq!(r["ok"], true, "{r}");
        assert_eq!(r["id"], 0);
        assert_eq!(r["until_ns"], s(9).as_ns());
        let order: Vec<_> = tl.queue.iter().map(|(n, f)| (*n, f.at)).collect();
        assert_eq!(order, [(Some(0), s(4)), (None, s(7)), (Some(0), s(9))]);
        assert_eq!(tl.pop_due(s(4)).unwrap().at, s(4));
        assert!(tl.pop_due(s(4)).is_none());
        // Cleared at 6 s: its lift moves to 6 s, before the scenario's reboot.
        let r = reply(&tl.answer(r#"{"op":"clear","id":0}"#, s(6), &PowerOnly));
        assert_eq!(r["lifted"], true, "{r}");
        let order: Vec<_> = tl.queue.iter().map(|(n, f)| (*n, f.at)).collect();
        assert_eq!(order, [(Some(0), s(6)), (None, s(7))]);
        assert!(matches!(
            tl.queue[0].1.action,
            FaultAction::Power { off: false, .. }
        ));
        let r = reply(&tl.answer(r#"{"op":"time"}"#, s(6), &PowerOnly));
        assert_eq!(
            (r["ok"].clone(), r["t_ns"].clone()),
            (true.into(), s(6).as_ns().into())
        );
        for (bad, why) in [
            (r#"{"op":"clear","id":0}"#, "cleared already"),
            (r#"{"op":"clear","id":9}"#, "no live fault 9"),
            (
                r#"{"op":"fault","kind":"power-off","target":12,"at":"1s"}"#,
                "has passed",
            ),
            (
                r#"{"op":"fault","kind":"power-off","target":12,"for":"1s","until":"9s"}"#,
                "not both",
            ),
            (
                r#"{"op":"fault","kind":"melt","target":12}"#,
                "unknown kind",
            ),
            (r#"{"op":"reboot-everything"}"#, "not a request"),
            ("power-off PL12", "not a request"),
        ] {
            let r = reply(&tl.answer(bad, s(6), &PowerOnly));
            assert_eq!(r["ok"], false, "{bad}: {r}");
            assert!(r["error"].as_str().unwrap().contains(why), "{bad}: {r}");
        }
    }

    /// A snapshot request: taken (its instant handed on, the file named by it) up to
    /// [`MAX_ASKED_SNAPSHOTS`] a run, refused after; refused by a run without a directory.
    #[test]
    fn snapshots_asked_are_named_by_their_instant_and_bounded() {
        let control = |snapshots| Control {
            rx: mpsc::unbounded_channel().1,
            catalogue: Some(Arc::new(PowerOnly)),
            stats: Arc::default(),
            snapshots,
            snapshots_taken: 0,
        };
        let ask = |c: &mut Control, t: SimTime, asked: &mut Vec<SimTime>| {
            let req = Admitted {
                t,
                conn: 0,
                request: r#"{"op":"snapshot"}"#.into(),
                reply: None,
            };
            match c.answer(req, &mut Timeline::default(), &mut |t| asked.push(t)) {
                RunEvent::Control { reply: r, .. } => reply(&r),
                other => panic!("{other:?}"),
            }
        };
        let mut c = control(OnRequest::Take);
        let mut asked = Vec::new();
        let r = ask(&mut c, s(7), &mut asked);
        assert_eq!(r["snapshot"], "snapshot-7000000000ns.snap", "{r}");
        assert_eq!(asked, [s(7)]);
        for i in 1..MAX_ASKED_SNAPSHOTS {
            assert_eq!(ask(&mut c, s(7 + u64::from(i)), &mut asked)["ok"], true);
        }
        let r = ask(&mut c, s(1000), &mut asked);
        assert_eq!(r["ok"], false);
        assert!(
            r["error"].as_str().unwrap().contains("100 snapshots"),
            "{r}"
        );
        assert_eq!(asked.len(), MAX_ASKED_SNAPSHOTS as usize);
        let r = ask(&mut control(OnRequest::Refuse), s(7), &mut asked);
        assert!(
            r["error"].as_str().unwrap().contains("--snapshot-dir"),
            "{r}"
        );
        assert_eq!(asked.len(), MAX_ASKED_SNAPSHOTS as usize);
    }
}
