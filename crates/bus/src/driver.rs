//! The thin async shell around a node: one tokio task per node that feeds its [`Host`]
//! the frames and packets its media deliver, its timers and the run's control commands, and
//! sends what the host wants sent. All the behaviour is in the host; this loop only moves
//! things and keeps the node's time (`t = max(t, event stamp)`, never the wake-up time).

use std::sync::{Arc, Mutex, MutexGuard};

use csp::SimTime;
use csp::node::{App, Host, NodeEvent, Severity, Transmit};
use tokio::sync::mpsc;

use crate::can::CanPort;
use crate::clock::Clock;
use crate::inbox::{Arrival, Inbound, InboxRx, InboxState};
use crate::net::NetPort;

/// Where one interface of a node is attached.
#[derive(Debug, Clone)]
pub enum Attachment {
    /// A CAN bus endpoint.
    Can(CanPort),
    /// A packet network endpoint.
    Net(NetPort),
}

impl Attachment {
    fn set_enabled(&self, on: bool) {
        match self {
            Attachment::Can(p) => p.bus().set_enabled(p, on),
            Attachment::Net(p) => p.net().set_enabled(p, on),
        }
    }

    /// Give back the endpoint's addresses and disable it ([`crate::CanBus::release`]).
    pub fn release(&self) {
        match self {
            Attachment::Can(p) => p.bus().release(p),
            Attachment::Net(p) => p.net().release(p),
        }
    }
}

/// A node's control channel: each command with the simulated instant it takes effect
/// (a fault's scheduled time, the EPS's switch), so that a real-time run applies it at that
/// instant however late its task wakes, as the virtual-time replay does. A command for
/// instant T takes effect after the node's own timers due at or before T, whichever task
/// ran first at T.
pub type CtlTx = mpsc::UnboundedSender<(SimTime, NodeCtl)>;
/// The receiving end of a [`CtlTx`].
pub type CtlRx = mpsc::UnboundedReceiver<(SimTime, NodeCtl)>;

/// Commands from the run (scenario faults, shutdown).
#[derive(Debug, Clone, PartialEq)]
pub enum NodeCtl {
    /// Reboot the node (uptime from zero, volatile state lost).
    Reboot,
    /// Power the node off (it leaves its buses) or on (it boots).
    Power(bool),
    /// Hang: alive on the bus (frames are acknowledged) but silent; `false` recovers.
    Hang(bool),
    /// Flip an application's hardware switch ([`csp::node::App::switch`]); applied whether
    /// or not the node is powered (it is hardware state).
    Switch(csp::node::HwSwitch, csp::node::SwitchPosition),
    /// Fault `id` acts on the node's core (`Some`) or is lifted ([`Host::fault`]); applied
    /// whether or not the node is powered (its clock keeps its error).
    Fault(u32, Option<csp::node::NodeFault>),
    /// A console line (`m6p_links::console`): run at the command's instant when the node is
    /// powered and not hung, and answered; otherwise answered `None`.
    Console(ConsoleRequest),
    /// Stop the task and hand the host back.
    Stop,
}

/// A node's drop or log line as the run receives it: with the node's name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeLog {
    /// The node's name.
    pub node: Arc<str>,
    /// What happened.
    pub event: NodeEvent,
}

impl From<std::convert::Infallible> for NodeLog {
    fn from(never: std::convert::Infallible) -> Self {
        match never {}
    }
}

/// What a node's task pulls out of its host after an input, in order: the application's
/// events, then the node's drops and log lines.
enum Output<E> {
    App(E),
    Node(NodeEvent),
}

/// Inbox entries a node's task takes at one wake-up before it looks at its control
/// channel and its timers again.
const INBOX_BATCH: usize = 64;

/// A node's task's state between two of its wake-ups: the node, its time (the latest
/// stamp it has seen: it only moves forward), whether it is powered and hung, and its
/// inbox. The task holds it only while it works on a wake-up, so that the run can save it
/// for a snapshot (and load it before the task starts) while the task waits.
pub struct NodeCore<A: App> {
    /// The node.
    pub host: Host<A>,
    task: TaskState,
    inbox: InboxState,
}

/// What a node's task knows besides its node.
#[derive(Debug, Clone, Copy)]
struct TaskState {
    t: SimTime,
    power: Power,
    hang: Hang,
}

/// Whether a node is powered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Power {
    On,
    Off,
}

/// Whether a node hangs (alive on its buses, silent).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Hang {
    Running,
    Hung,
}

snap::unit_enum!(Power { On, Off });
snap::unit_enum!(Hang { Running, Hung });
snap::fields!(TaskState { t, power, hang });

impl<A: App> NodeCore<A> {
    /// A node as booted, its task not started yet, with the inbox it will read.
    pub fn new(host: Host<A>, inbox: &InboxRx) -> Self {
        NodeCore {
            host,
            task: TaskState {
                t: SimTime::ZERO,
                power: Power::On,
                hang: Hang::Running,
            },
            inbox: inbox.state(),
        }
    }

    /// Whether it takes what comes in and runs its timers.
    fn listening(&self) -> bool {
        self.task.power == Power::On && self.task.hang == Hang::Running
    }
}

impl<A: App> std::fmt::Debug for NodeCore<A> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NodeCore")
            .field("node", &self.host.node.name())
            .field("task", &self.task)
            .finish_non_exhaustive()
    }
}

/// Everything of a node's task between two wake-ups, its inbox's frames included.
impl<A: App + snap::Snap> snap::Snap for NodeCore<A> {
    fn save(&self, w: &mut snap::Writer) {
        let NodeCore { host, task, inbox } = self;
        host.save(w);
        task.save(w);
        inbox.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        let NodeCore { host, task, inbox } = self;
        host.load(r)?;
        task.load(r)?;
        inbox.load(r)
    }
}

/// A node's core, shared by its task and the run.
pub type SharedCore<A> = Arc<Mutex<NodeCore<A>>>;

/// The core, locked (a panic elsewhere leaves it usable: its state is whole between two
/// inputs).
pub fn lock_core<A: App>(core: &Mutex<NodeCore<A>>) -> MutexGuard<'_, NodeCore<A>> {
    core.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Run a node until [`NodeCtl::Stop`] (or every sender of `ctl` is gone); returns the host.
/// Its events go to the tracing log only.
pub async fn run_node<A: App>(
    host: Host<A>,
    ports: Vec<Attachment>,
    inbox: InboxRx,
    ctl: CtlRx,
    clock: Clock,
) -> Host<A> {
    let core = Arc::new(Mutex::new(NodeCore::new(host, &inbox)));
    run(&core, ports, inbox, ctl, clock, Discard).await;
    let core = Arc::into_inner(core).expect("the core is the task's alone");
    core.into_inner()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .host
}

/// Run the node of `core` (booted, or loaded from a snapshot: it goes on from where it
/// was) until [`NodeCtl::Stop`] (or every sender of `ctl` is gone), handing the
/// application's events and the node's drops and log lines to `out` in the order the host
/// produced them (`E` gathers every node's events in one type).
pub async fn run_node_with<A, E>(
    core: SharedCore<A>,
    ports: Vec<Attachment>,
    inbox: InboxRx,
    ctl: CtlRx,
    clock: Clock,
    out: mpsc::UnboundedSender<E>,
) where
    A: App,
    E: From<NodeLog> + From<A::Event> + Send + 'static,
{
    let name: Arc<str> = lock_core(&core).host.node.name().into();
    run(&core, ports, inbox, ctl, clock, Channel { name, out }).await;
}

/// Where a node's task hands what it pulls out of the host.
trait Outputs<Ev>: Send {
    fn emit(&mut self, o: Output<Ev>);
}

/// Nowhere (the tracing log has them already).
struct Discard;

impl<Ev> Outputs<Ev> for Discard {
    fn emit(&mut self, _: Output<Ev>) {}
}

/// Into the run's event channel.
struct Channel<E> {
    name: Arc<str>,
    out: mpsc::UnboundedSender<E>,
}

impl<Ev, E: From<NodeLog> + From<Ev> + Send> Outputs<Ev> for Channel<E> {
    fn emit(&mut self, o: Output<Ev>) {
        let e = match o {
            Output::App(e) => E::from(e),
            Output::Node(event) => E::from(NodeLog {
                node: Arc::clone(&self.name),
                event,
            }),
        };
        let _ = self.out.send(e);
    }
}

/// What woke a node's task.
enum Woke {
    Ctl(Option<(SimTime, NodeCtl)>),
    Inbox(usize),
    Timer(SimTime),
}

/// Whether a node's task goes on.
#[derive(PartialEq, Eq)]
enum Flow {
    Continue,
    Stop,
}

async fn run<A: App, O: Outputs<A::Event>>(
    core: &Mutex<NodeCore<A>>,
    ports: Vec<Attachment>,
    mut inbox: InboxRx,
    mut ctl: CtlRx,
    clock: Clock,
    mut out: O,
) {
    // Frames whose packet's next frame is on the wire need no wake-up of their own: they
    // are taken before anything else the node does (a timer, a command, the next arrival).
    inbox.take_quiet();
    let mut timer = crate::clock::Timer::new(clock);
    let mut batch = std::collections::VecDeque::with_capacity(INBOX_BATCH);
    loop {
        let deadline = {
            let mut c = lock_core(core);
            let c = &mut *c;
            flush(&mut c.host, &ports, c.task.t, &mut out);
            if c.listening() {
                c.host.poll_timeout()
            } else {
                None
            }
        };
        if deadline.is_none() {
            timer.disarm();
        }
        // What woke the task is handled with its core held (the run reads it only while
        // every task waits).
        let woke = tokio::select! {
            biased;
            c = ctl.recv() => Woke::Ctl(c),
            n = inbox.recv_many(&mut batch, INBOX_BATCH) => Woke::Inbox(n),
            () = timer.sleep_until(deadline.unwrap_or(SimTime::MAX)), if deadline.is_some() => {
                Woke::Timer(deadline.unwrap_or(SimTime::MAX))
            }
        };
        let mut c = lock_core(core);
        let c = &mut *c;
        match woke {
            Woke::Ctl(None) | Woke::Inbox(0) => break,
            Woke::Ctl(Some((at, cmd))) => {
                if command(c, &ports, &mut inbox, at, cmd, &mut out) == Flow::Stop {
                    break;
                }
            }
            Woke::Inbox(_) => {
                // Whatever was waiting in the inbox is taken now (at most INBOX_BATCH), one
                // at a time, as the biased select would take it (no control command can
                // come in meanwhile: it would come from a task of this single-threaded
                // runtime), without a select and a timer per frame. The node's timers due
                // before each arrival's instant come first: its events in the order of
                // their instants, however late the arrival woke the task (frames that came
                // quietly wake nobody).
                while let Some(m) = batch.pop_front() {
                    take(c, &ports, m, &mut out);
                }
            }
            Woke::Timer(deadline) => {
                // Frames that came quietly came before the timer's instant: they are taken
                // first (with the timers due before each), and the deadline looked at again.
                if inbox.has_quiet() {
                    while let Some(m) = inbox.try_recv_quiet() {
                        take(c, &ports, m, &mut out);
                    }
                    continue;
                }
                c.task.t = c.task.t.max(deadline);
                c.host.handle_timeout(c.task.t);
            }
        }
    }
}

/// Take an arrival at its instant, after the node's timers due before it (a node off or
/// hung takes nothing).
fn take<A: App>(
    c: &mut NodeCore<A>,
    ports: &[Attachment],
    m: Inbound,
    out: &mut impl Outputs<A::Event>,
) {
    let listening = c.listening();
    if listening {
        timers_due(&mut c.host, ports, &mut c.task.t, out, |d| d < m.t);
    }
    c.task.t = c.task.t.max(m.t);
    arrive(&mut c.host, m, c.task.t, listening);
    flush(&mut c.host, ports, c.task.t, out);
}

/// A control command at its instant `at`.
fn command<A: App>(
    c: &mut NodeCore<A>,
    ports: &[Attachment],
    inbox: &mut InboxRx,
    at: SimTime,
    cmd: NodeCtl,
    out: &mut impl Outputs<A::Event>,
) -> Flow {
    // Frames that came quietly were there before the command (had they woken the task, it
    // would have taken them then), with the timers due before each.
    while let Some(m) = inbox.try_recv_quiet() {
        take(c, ports, m, out);
    }
    // The node's own timers due by the command's instant come first, so that a command
    // meets the same node whichever task ran first at that instant (a beacon due at the
    // instant the EPS switches its COMM off goes out).
    let listening = c.listening();
    if listening && cmd != NodeCtl::Stop {
        timers_due(&mut c.host, ports, &mut c.task.t, out, |d| d <= at);
    }
    c.task.t = c.task.t.max(at);
    let t = c.task.t;
    match cmd {
        NodeCtl::Stop => return Flow::Stop,
        NodeCtl::Reboot => {
            if c.task.power == Power::On {
                c.host.reboot(t);
            }
        }
        NodeCtl::Power(on) => {
            let to = if on { Power::On } else { Power::Off };
            if to != c.task.power {
                c.task.power = to;
                if !on {
                    // The core meets the loss at its instant (a burn stops there).
                    c.host.power_lost(t);
                    flush(&mut c.host, &[], t, out);
                }
                for p in ports {
                    p.set_enabled(on);
                }
                if on {
                    c.task.hang = Hang::Running;
                    c.host.reboot(t);
                }
            }
        }
        NodeCtl::Hang(h) => c.task.hang = if h { Hang::Hung } else { Hang::Running },
        NodeCtl::Switch(switch, to) => c.host.switch(switch, to, t),
        NodeCtl::Fault(id, f) => c.host.fault(id, f, t),
        NodeCtl::Console(req) => {
            if listening {
                // The line is in the node's log (and so in the recording).
                c.host.node.log(t, format!("console: {}", req.line()));
                let text = c.host.console(req.line(), t);
                req.answer(Some(text));
            } else {
                req.answer(None);
            }
        }
    }
    Flow::Continue
}

/// Run the node's timers while the next is `due` (bounded: an application whose timer
/// never moves on cannot hang the task here).
fn timers_due<A: App>(
    host: &mut Host<A>,
    ports: &[Attachment],
    t: &mut SimTime,
    out: &mut impl Outputs<A::Event>,
    due: impl Fn(SimTime) -> bool,
) {
    for _ in 0..10_000 {
        let Some(d) = host.poll_timeout().filter(|&d| due(d)) else {
            return;
        };
        *t = (*t).max(d);
        host.handle_timeout(*t);
        flush(host, ports, *t, out);
    }
}

/// Hand an arrival to the host (a node off or hung takes nothing).
fn arrive<A: App>(host: &mut Host<A>, m: Inbound, t: SimTime, listening: bool) {
    if listening {
        match m.what {
            Arrival::Can(f) => host.handle_frame(m.iface, &f, t),
            Arrival::Packet(p) => host.handle_packet(m.iface, p, t),
        }
    }
}

fn flush<A: App>(
    host: &mut Host<A>,
    ports: &[Attachment],
    t: SimTime,
    out: &mut impl Outputs<A::Event>,
) {
    while let Some(tx) = host.node.poll_transmit() {
        match tx {
            Transmit::Can { iface, frame } => match ports.get(iface) {
                Some(Attachment::Can(p)) => {
                    p.send_train(t, frame, || host.node.poll_transmit_can(iface));
                }
                _ => tracing::warn!(
                    node = host.node.name(),
                    iface,
                    "CAN frame for a non-CAN interface"
                ),
            },
            Transmit::Packet { iface, packet } => match ports.get(iface) {
                Some(Attachment::Net(p)) => p.send(t, packet),
                _ => tracing::warn!(
                    node = host.node.name(),
                    iface,
                    "packet for a non-packet interface"
                ),
            },
        }
    }
    while let Some(e) = host.app.poll_event() {
        out.emit(Output::App(e));
    }
    while let Some(ev) = host.node.poll_event() {
        let node = host.node.name();
        match &ev {
            NodeEvent::Drop { .. } => tracing::debug!(node, t = %ev.t(), "{ev}"),
            // What an application reports (FC modes, scripts, a refused request and why) is
            // news, on the terminal too.
            NodeEvent::Log {
                severity: Severity::Info,
                ..
            } => tracing::info!(t = %ev.t(), "{node}: {ev}"),
            NodeEvent::Log { .. } => tracing::warn!(t = %ev.t(), "{node}: {ev}"),
        }
        out.emit(Output::Node(ev));
    }
}

/// One console line on its way to a node (`m6p_links::console`), with the way back for the
/// answer.
#[derive(Clone)]
pub struct ConsoleRequest(std::sync::Arc<ConsoleInner>);

struct ConsoleInner {
    line: String,
    reply: std::sync::Mutex<Option<tokio::sync::oneshot::Sender<Option<String>>>>,
}

impl ConsoleRequest {
    /// A request for `line` and the receiver of its answer (`None`: the node did not
    /// answer, being off or hung).
    pub fn new(line: String) -> (Self, tokio::sync::oneshot::Receiver<Option<String>>) {
        let (tx, rx) = tokio::sync::oneshot::channel();
        (
            ConsoleRequest(std::sync::Arc::new(ConsoleInner {
                line,
                reply: std::sync::Mutex::new(Some(tx)),
            })),
            rx,
        )
    }
    /// The line.
    pub fn line(&self) -> &str {
        &self.0.line
    }
    /// Answer it (once; later answers are ignored).
    pub fn answer(&self, text: Option<String>) {
        let tx = self
            .0
            .reply
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        if let Some(tx) = tx {
            let _ = tx.send(text);
        }
    }
}

impl std::fmt::Debug for ConsoleRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("ConsoleRequest").field(&self.0.line).finish()
    }
}

impl PartialEq for ConsoleRequest {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::clock::ClockMode;
    use crate::inbox::inbox;
    use csp::node::{NoApp, NodeConfig};
    use std::time::Duration;

    /// A command takes effect at its own instant, not when the node's task gets to it (in
    /// real time a busy task wakes late; the replay applies it at the instant).
    #[tokio::test(start_paused = true)]
    async fn a_command_takes_effect_at_its_instant_however_late_it_is_read() {
        let clock = Clock::new(ClockMode::Virtual);
        let host = Host::new(NodeConfig::new("X", 3), NoApp, SimTime::ZERO);
        let (_in_tx, in_rx) = inbox();
        let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
        let task = tokio::spawn(run_node(host, Vec::new(), in_rx, ctl_rx, clock));
        tokio::time::sleep(Duration::from_secs(10)).await;
        // Read at 10 s, meant for 4 s.
        ctl_tx
            .send((SimTime::from_secs(4), NodeCtl::Reboot))
            .unwrap();
        ctl_tx.send((SimTime::ZERO, NodeCtl::Stop)).unwrap();
        let host = task.await.unwrap();
        assert_eq!(
            host.node.uptime(SimTime::from_secs(10)),
            Duration::from_secs(6)
        );
    }

    /// An application with one timer.
    struct Timer {
        at: SimTime,
        fired: Vec<SimTime>,
    }

    impl csp::node::App for Timer {
        type Event = std::convert::Infallible;
        fn start(&mut self, _: &mut csp::node::Node, _: SimTime) {}
        fn handle_packet(&mut self, _: &mut csp::node::Node, _: csp::Packet, _: SimTime) {}
        fn poll_timeout(&self) -> Option<SimTime> {
            self.fired.is_empty().then_some(self.at)
        }
        fn handle_timeout(&mut self, _: &mut csp::node::Node, now: SimTime) {
            self.fired.push(now);
        }
    }

    /// Run a node whose one timer is `due` for 10 s, after `before` has put what it wants
    /// in its inbox and control channel before the task first runs; when its timer fired.
    async fn timer_fires(
        due: SimTime,
        before: impl FnOnce(&crate::inbox::InboxTx, &CtlTx),
    ) -> Vec<SimTime> {
        let clock = Clock::new(ClockMode::Virtual);
        let app = Timer {
            at: due,
            fired: Vec::new(),
        };
        let host = Host::new(NodeConfig::new("X", 3), app, SimTime::ZERO);
        let (in_tx, in_rx) = inbox();
        let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
        before(&in_tx, &ctl_tx);
        let task = tokio::spawn(run_node(host, Vec::new(), in_rx, ctl_rx, clock));
        tokio::time::sleep(Duration::from_secs(10)).await;
        ctl_tx.send((SimTime::ZERO, NodeCtl::Stop)).unwrap();
        task.await.unwrap().app.fired
    }

    /// A power-off for instant T read before the node's own timer at T has run (the other
    /// task ran first at T): the timer still runs, before the power goes.
    #[tokio::test(start_paused = true)]
    async fn a_timer_due_at_a_commands_instant_runs_before_the_command() {
        let t5 = SimTime::from_secs(5);
        // Queued before the task first runs: it reads the command before its timer is due.
        let fired = timer_fires(t5, |_, ctl| {
            ctl.send((t5, NodeCtl::Power(false))).unwrap();
        })
        .await;
        assert_eq!(fired, vec![t5]);
    }

    /// A node's events run in the order of their instants: a timer due before an
    /// arrival's stamp runs first and at its own instant, however the task found the two
    /// (here the arrival is already waiting when the task starts: taking it first would run
    /// the timer at the arrival's later instant).
    #[tokio::test(start_paused = true)]
    async fn a_timer_due_before_an_arrival_runs_first_at_its_own_instant() {
        let due = SimTime::from_ns(5_200_000);
        let fired = timer_fires(due, |inbox, _| {
            let packet = csp::Packet::new(csp::Header::new(16, 3, 20, 40), vec![1, 2, 3]);
            inbox
                .send(Inbound {
                    t: SimTime::from_ns(5_800_000),
                    iface: 0,
                    what: Arrival::Packet(packet),
                })
                .unwrap();
        })
        .await;
        assert_eq!(fired, vec![due]);
    }
}
