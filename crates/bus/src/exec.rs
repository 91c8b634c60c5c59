//! The run's own executor: the twin's tasks (the run's loop, the buses, the nodes) polled in
//! an order that is a function of the run's state alone.
//!
//! Tokio wakes the tasks due at one tick of its timer wheel in the order of the wheel's
//! slots, which depends on when each timer was set and how it cascaded: a history no
//! snapshot can hold. Here the run's timers wait in one ordered map keyed by (instant,
//! rank, id), a task's rank being the order it was spawned in (the run's loop, the root,
//! is 0): at each instant the tasks due wake in rank order, then run in the order they
//! were woken, and whatever they wake runs after them. A run restored from a snapshot whose
//! tasks are spawned in the same order and wait for the same instants runs in the same
//! order as the run it was taken from.
//!
//! The executor is one future, polled by tokio's current-thread runtime like any
//! `block_on` future: tokio keeps the paused clock (which jumps to the one tokio timer the
//! executor sets, for its earliest instant), the IO of outside links (their tasks stay
//! tokio's and wake the run's tasks through channels) and the idle hook of [`crate::pace`],
//! which runs when the executor has nothing left to do. [`spawn`] outside a run (a unit
//! test on a plain runtime) spawns on tokio, and a [`crate::clock::Timer`] polled outside a
//! run's task sleeps on tokio's timer.

use std::cell::{Cell, RefCell};
use std::collections::{BTreeMap, VecDeque};
use std::future::Future;
use std::pin::Pin;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Wake, Waker};

use csp::SimTime;

/// The run's clock as the executor reads it (`crate::clock::Clock`): simulated time now,
/// and the tokio instant a simulated instant falls at.
pub trait RunClock: Send + 'static {
    /// Simulated time now.
    fn now(&self) -> SimTime;
    /// The tokio instant at which simulated time `t` is reached.
    fn instant_of(&self, t: SimTime) -> tokio::time::Instant;
}

/// A task's place among those due at one instant: the order it was spawned in.
type Rank = u64;

/// The run's loop: the future [`run`] drives, first at every instant.
const ROOT: usize = 0;

/// A waiting timer: its place in the run's table of timers and the instant it waits for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct TimerKey {
    index: usize,
    at: SimTime,
}

/// One entry of the run's table of timers: the instant and the task it wakes
/// (`SimTime::MAX`: free). A run has a few dozen timers, each task's set again and again:
/// a table scanned once an instant costs less than an ordered map kept in order at every
/// setting.
#[derive(Debug, Clone, Copy)]
struct TimerEntry {
    at: SimTime,
    slot: usize,
    rank: Rank,
}

/// How a task of the run begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// At the run's start.
    Fresh,
    /// Loaded from a snapshot: it waits first, for what it waited for when the snapshot
    /// was taken, as if it had never stopped (its state says what that is).
    Resumed,
}

/// Why a task gave no result.
#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    /// It panicked (the message, when it was a string).
    #[error("the task panicked: {0}")]
    Panicked(String),
    /// It was aborted before it ended.
    #[error("the task was aborted")]
    Cancelled,
    /// Tokio's task failed.
    #[error(transparent)]
    Tokio(#[from] tokio::task::JoinError),
}

/// What a waker may reach from any thread: the queue of woken tasks and the runtime's
/// waker for the executor itself.
struct Shared {
    queue: Mutex<VecDeque<usize>>,
    root: Mutex<Option<Waker>>,
    /// The executor is running its queue: a wake needs no wake-up of the executor.
    polling: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

struct TaskWaker {
    slot: usize,
    /// In the queue already: woken twice before it runs, it runs once.
    queued: AtomicBool,
    shared: Arc<Shared>,
}

impl Wake for TaskWaker {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }

    fn wake_by_ref(self: &Arc<Self>) {
        if self.queued.swap(true, Ordering::SeqCst) {
            return;
        }
        lock(&self.shared.queue).push_back(self.slot);
        if !self.shared.polling.load(Ordering::SeqCst)
            && let Some(w) = lock(&self.shared.root).as_ref()
        {
            w.wake_by_ref();
        }
    }
}

struct Task {
    fut: Pin<Box<dyn Future<Output = ()>>>,
    waker: Arc<TaskWaker>,
    std_waker: Waker,
    rank: Rank,
}

struct Inner {
    clock: Rc<dyn RunClock>,
    shared: Arc<Shared>,
    /// By slot; slot 0 is the root's, held by [`Run`]. A slot is not reused.
    tasks: RefCell<Vec<Option<Task>>>,
    root_waker: Arc<TaskWaker>,
    timers: RefCell<Vec<TimerEntry>>,
    /// Free entries of `timers`.
    free_timers: RefCell<Vec<usize>>,
    /// The task being polled: its slot and rank.
    current: Cell<Option<(usize, Rank)>>,
    /// Simulated time during this poll of the executor (the paused clock moves only while
    /// the runtime parks).
    now: Cell<SimTime>,
    /// Due timers' entries, reused from instant to instant.
    due: RefCell<Vec<(SimTime, Rank, usize)>>,
    /// At or before the earliest waiting instant: the table is not scanned before.
    next_at: Cell<SimTime>,
    /// `next_at` may be before the earliest waiting instant (a timer there moved on).
    next_stale: Cell<bool>,
    /// Tasks waiting in [`settled`].
    settled_waiters: RefCell<Vec<Waker>>,
    /// How many times the run has settled with a task waiting for it.
    settlings: Cell<u64>,
}

thread_local! {
    static CURRENT: RefCell<Option<Rc<Inner>>> = const { RefCell::new(None) };
}

/// Drive `root` and every task it [`spawn`]s on `clock` until `root` ends (the tasks still
/// waiting are dropped then). The future is polled on one thread (the run's state stays on
/// the thread it was first polled on; polled on another, it panics).
pub fn run<C: RunClock + Copy + Unpin, F: Future>(
    clock: C,
    root: F,
) -> impl Future<Output = F::Output> {
    // The run's tasks share a budget with nothing: tokio's cooperative budget would make
    // their channels yield every 128 operations within the executor's one poll.
    tokio::task::unconstrained(Run {
        clock,
        root: Box::pin(root),
        id: None,
        root_waker: None,
        sleep: None,
        armed: None,
    })
}

thread_local! {
    /// The executors of this thread, by id: a run's future holds its id alone, so that it
    /// can be handed to `tokio::spawn` like any future (which asks for `Send`), and its
    /// state (tasks that need not be `Send`) stays here.
    static RUNS: RefCell<BTreeMap<u64, Rc<Inner>>> = const { RefCell::new(BTreeMap::new()) };
}

static RUN_IDS: AtomicU64 = AtomicU64::new(0);

struct Run<C, F> {
    clock: C,
    root: Pin<Box<F>>,
    /// Its state's key in [`RUNS`], from its first poll on.
    id: Option<u64>,
    root_waker: Option<Waker>,
    /// Tokio's timer for the earliest waiting instant, and that instant.
    sleep: Option<Pin<Box<tokio::time::Sleep>>>,
    armed: Option<SimTime>,
}

impl<C: RunClock + Copy + Unpin, F> Run<C, F> {
    /// The run's state, made on its first poll.
    fn inner(&mut self) -> Rc<Inner> {
        if let Some(id) = self.id {
            return RUNS
                .with_borrow(|r| r.get(&id).cloned())
                .expect("a run's executor is polled on the thread it started on");
        }
        let shared = Arc::new(Shared {
            queue: Mutex::new(VecDeque::from([ROOT])),
            root: Mutex::new(None),
            polling: AtomicBool::new(false),
        });
        let root_waker = Arc::new(TaskWaker {
            slot: ROOT,
            queued: AtomicBool::new(true),
            shared: shared.clone(),
        });
        let inner = Rc::new(Inner {
            clock: Rc::new(self.clock),
            shared,
            tasks: RefCell::new(vec![None]),
            root_waker: root_waker.clone(),
            timers: RefCell::new(Vec::new()),
            free_timers: RefCell::new(Vec::new()),
            current: Cell::new(None),
            now: Cell::new(SimTime::ZERO),
            due: RefCell::new(Vec::new()),
            next_at: Cell::new(SimTime::MAX),
            next_stale: Cell::new(false),
            settled_waiters: RefCell::new(Vec::new()),
            settlings: Cell::new(0),
        });
        let id = RUN_IDS.fetch_add(1, Ordering::Relaxed);
        RUNS.with_borrow_mut(|r| r.insert(id, inner.clone()));
        self.id = Some(id);
        self.root_waker = Some(Waker::from(root_waker));
        inner
    }
}

impl<C, F> Drop for Run<C, F> {
    fn drop(&mut self) {
        if let Some(id) = self.id {
            // Dropped outside the borrow: the tasks' drops may reach the thread's state.
            let inner = RUNS.try_with(|r| r.borrow_mut().remove(&id)).ok().flatten();
            drop(inner);
        }
    }
}

/// The executor current on this thread while it polls, restored after.
struct Entered(Option<Rc<Inner>>);

impl Entered {
    fn new(inner: &Rc<Inner>) -> Self {
        Entered(CURRENT.with_borrow_mut(|c| c.replace(inner.clone())))
    }
}

impl Drop for Entered {
    fn drop(&mut self) {
        let before = self.0.take();
        let _ = CURRENT.try_with(|c| *c.borrow_mut() = before);
    }
}

impl<C: RunClock + Copy + Unpin, F: Future> Future for Run<C, F> {
    type Output = F::Output;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<F::Output> {
        let this = self.get_mut();
        let inner = this.inner();
        let _entered = Entered::new(&inner);
        {
            let mut root = lock(&inner.shared.root);
            if !root.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
                *root = Some(cx.waker().clone());
            }
        }
        let shared = &inner.shared;
        inner.now.set(inner.clock.now());
        shared.polling.store(true, Ordering::SeqCst);
        loop {
            if let Poll::Ready(v) = this.run_queue(&inner) {
                shared.polling.store(false, Ordering::SeqCst);
                return Poll::Ready(v);
            }
            if inner.wake_due() || inner.wake_settled() {
                continue;
            }
            if this.sleep_until_next(&inner, cx).is_ready() {
                continue;
            }
            shared.polling.store(false, Ordering::SeqCst);
            if lock(&shared.queue).is_empty() {
                return Poll::Pending;
            }
            shared.polling.store(true, Ordering::SeqCst);
        }
    }
}

impl<C: RunClock + Copy + Unpin, F: Future> Run<C, F> {
    /// Poll every woken task, in the order woken, until none is left; the root's output
    /// once it ends.
    fn run_queue(&mut self, inner: &Inner) -> Poll<F::Output> {
        loop {
            let next = lock(&inner.shared.queue).pop_front();
            let Some(slot) = next else {
                return Poll::Pending;
            };
            if slot == ROOT {
                inner.root_waker.queued.store(false, Ordering::SeqCst);
                inner.current.set(Some((ROOT, 0)));
                let r = match &self.root_waker {
                    Some(w) => self.root.as_mut().poll(&mut Context::from_waker(w)),
                    None => Poll::Pending,
                };
                inner.current.set(None);
                if r.is_ready() {
                    return r;
                }
                continue;
            }
            let task = inner
                .tasks
                .borrow_mut()
                .get_mut(slot)
                .and_then(Option::take);
            let Some(mut task) = task else { continue };
            task.waker.queued.store(false, Ordering::SeqCst);
            inner.current.set(Some((slot, task.rank)));
            let r = task
                .fut
                .as_mut()
                .poll(&mut Context::from_waker(&task.std_waker));
            inner.current.set(None);
            if r.is_pending() {
                inner.tasks.borrow_mut()[slot] = Some(task);
            }
        }
    }

    /// Tokio's timer set for the earliest waiting instant; ready if it passed already.
    fn sleep_until_next(&mut self, inner: &Inner, cx: &mut Context<'_>) -> Poll<()> {
        // Tokio's timer wakes the run at the earliest waiting instant exactly: where the
        // run is idle (and outside input comes in, `crate::pace`) depends on its timers
        // alone, never on how they were set before.
        let at = inner.earliest();
        if at == SimTime::MAX {
            return Poll::Pending;
        }
        let instant = inner.clock.instant_of(at);
        let sleep = self
            .sleep
            .get_or_insert_with(|| Box::pin(tokio::time::sleep_until(instant)));
        if self.armed != Some(at) {
            sleep.as_mut().reset(instant);
            self.armed = Some(at);
        }
        sleep.as_mut().poll(cx)
    }
}

impl Inner {
    /// Wake the tasks of every timer due by now, in the order of (instant, rank); whether
    /// any. A timer that fired is free: its task finds its instant passed.
    fn wake_due(&self) -> bool {
        let now = self.now.get();
        if now < self.next_at.get() {
            return false;
        }
        let mut due = self.due.borrow_mut();
        due.clear();
        let mut next = SimTime::MAX;
        {
            let mut timers = self.timers.borrow_mut();
            let mut free = self.free_timers.borrow_mut();
            for (i, e) in timers.iter_mut().enumerate() {
                if e.at <= now {
                    due.push((e.at, e.rank, e.slot));
                    e.at = SimTime::MAX;
                    free.push(i);
                } else {
                    next = next.min(e.at);
                }
            }
        }
        self.next_at.set(next);
        self.next_stale.set(false);
        due.sort_unstable();
        let tasks = self.tasks.borrow();
        for &(_, _, slot) in due.iter() {
            if slot == ROOT {
                self.root_waker.wake_by_ref();
            } else if let Some(Some(t)) = tasks.get(slot) {
                t.waker.wake_by_ref();
            }
        }
        !due.is_empty()
    }

    /// The run has settled (nothing to run, no timer due now): wake the tasks waiting for
    /// that; whether any.
    fn wake_settled(&self) -> bool {
        let waiters = std::mem::take(&mut *self.settled_waiters.borrow_mut());
        if waiters.is_empty() {
            return false;
        }
        self.settlings.set(self.settlings.get() + 1);
        for w in waiters {
            w.wake();
        }
        true
    }

    fn spawn<F>(&self, fut: F) -> JoinHandle<F::Output>
    where
        F: Future + Send + 'static,
        F::Output: Send + 'static,
    {
        let mut tasks = self.tasks.borrow_mut();
        let slot = tasks.len();
        let waker = Arc::new(TaskWaker {
            slot,
            queued: AtomicBool::new(true),
            shared: self.shared.clone(),
        });
        let std_waker = Waker::from(waker.clone());
        let join = Arc::new(Mutex::new(JoinState {
            result: None,
            waiter: None,
            aborted: false,
            task: std_waker.clone(),
        }));
        tasks.push(Some(Task {
            fut: Box::pin(SimTask {
                fut: Box::pin(fut),
                join: join.clone(),
            }),
            waker,
            std_waker,
            rank: slot as Rank,
        }));
        lock(&self.shared.queue).push_back(slot);
        JoinHandle(Handle::Sim(join))
    }
}

/// Spawn `fut` on the run's executor when called from within a run, on tokio otherwise.
pub fn spawn<F>(fut: F) -> JoinHandle<F::Output>
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    match CURRENT.with_borrow(Clone::clone) {
        Some(inner) => inner.spawn(fut),
        None => JoinHandle(Handle::Tokio(tokio::spawn(fut))),
    }
}

/// Ready once the run has settled at the instant it is awaited at, or a later one: every
/// other task waits, for an outside input or for a timer at a later instant. The state of
/// the run is then whole (nothing half done, every channel between its tasks empty but the
/// quiet frames of nodes' inboxes), and it is what a snapshot saves (docs/snapshots.md).
/// Ready at once outside a run.
pub fn settled() -> impl Future<Output = ()> {
    let mut seen: Option<u64> = None;
    std::future::poll_fn(move |cx| {
        CURRENT.with_borrow(|c| {
            let Some(inner) = c.as_ref() else {
                return Poll::Ready(());
            };
            let now = inner.settlings.get();
            if seen.is_some_and(|s| now > s) {
                return Poll::Ready(());
            }
            seen.get_or_insert(now);
            let mut waiters = inner.settled_waiters.borrow_mut();
            if !waiters.iter().any(|w| w.will_wake(cx.waker())) {
                waiters.push(cx.waker().clone());
            }
            Poll::Pending
        })
    })
}

/// A timer at `t` of the task being polled, when a run's task is: ready if the run's time
/// reached `t`, else set (once per instant) and pending. `None` outside a run's task.
pub(crate) fn poll_timer(key: &mut Option<TimerKey>, t: SimTime) -> Option<Poll<()>> {
    CURRENT.with_borrow(|c| {
        let inner = c.as_ref()?;
        let (slot, rank) = inner.current.get()?;
        if inner.now.get() >= t {
            if let Some(k) = key.take() {
                inner.release(k);
            }
            return Some(Poll::Ready(()));
        }
        match *key {
            // Set already for this instant (and not fired: the instant is ahead).
            Some(k) if k.at == t => {}
            Some(ref mut k) => {
                let mut timers = inner.timers.borrow_mut();
                let e = &mut timers[k.index];
                if e.at == k.at && e.slot == slot {
                    inner.moved(e.at, t);
                    e.at = t;
                    k.at = t;
                } else {
                    // It fired (and was freed) for an earlier instant.
                    drop(timers);
                    *key = Some(inner.take_timer(t, slot, rank));
                }
            }
            None => *key = Some(inner.take_timer(t, slot, rank)),
        }
        Some(Poll::Pending)
    })
}

impl Inner {
    fn take_timer(&self, at: SimTime, slot: usize, rank: Rank) -> TimerKey {
        let e = TimerEntry { at, slot, rank };
        self.moved(SimTime::MAX, at);
        let mut timers = self.timers.borrow_mut();
        let index = match self.free_timers.borrow_mut().pop() {
            Some(i) => {
                timers[i] = e;
                i
            }
            None => {
                timers.push(e);
                timers.len() - 1
            }
        };
        TimerKey { index, at }
    }

    /// Free `k`'s entry unless it fired already (then it is free, or another timer's).
    fn release(&self, k: TimerKey) {
        let mut timers = self.timers.borrow_mut();
        if let Some(e) = timers.get_mut(k.index)
            && e.at == k.at
            && e.at < SimTime::MAX
        {
            self.moved(e.at, SimTime::MAX);
            e.at = SimTime::MAX;
            self.free_timers.borrow_mut().push(k.index);
        }
    }

    /// Keep `next_at` a bound of the earliest instant as a timer moves from `old` to `new`.
    fn moved(&self, old: SimTime, new: SimTime) {
        let n = self.next_at.get();
        if new <= n {
            self.next_at.set(new);
            self.next_stale.set(false);
        } else if old == n {
            self.next_stale.set(true);
        }
    }

    /// The earliest waiting instant (`SimTime::MAX`: none).
    fn earliest(&self) -> SimTime {
        if self.next_stale.get() {
            let t = self.timers.borrow().iter().map(|e| e.at).min();
            self.next_at.set(t.unwrap_or(SimTime::MAX));
            self.next_stale.set(false);
        }
        self.next_at.get()
    }
}

/// Whether a run's task is being polled on this thread (its timers wait in the run's).
pub(crate) fn in_run_task() -> bool {
    CURRENT.with_borrow(|c| c.as_ref().is_some_and(|i| i.current.get().is_some()))
}

/// Take a timer out of the current run's waiting timers (nothing outside a run).
pub(crate) fn cancel_timer(key: &mut Option<TimerKey>) {
    if let Some(k) = key.take() {
        // At a thread's exit (a run dropped late) the thread's state may be gone already.
        let _ = CURRENT.try_with(|c| {
            if let Some(inner) = c.borrow().as_ref() {
                inner.release(k);
            }
        });
    }
}

struct JoinState<T> {
    result: Option<Result<T, TaskError>>,
    waiter: Option<Waker>,
    aborted: bool,
    task: Waker,
}

impl<T> JoinState<T> {
    fn finish(&mut self, r: Result<T, TaskError>) {
        self.result = Some(r);
        if let Some(w) = self.waiter.take() {
            w.wake();
        }
    }
}

/// A run's task: its future, and where its result goes.
struct SimTask<F: Future> {
    fut: Pin<Box<F>>,
    join: Arc<Mutex<JoinState<F::Output>>>,
}

impl<F: Future> Future for SimTask<F> {
    type Output = ();

    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<()> {
        if lock(&self.join).aborted {
            lock(&self.join).finish(Err(TaskError::Cancelled));
            return Poll::Ready(());
        }
        let fut = self.fut.as_mut();
        // A task's panic ends the task, not the run: its handle says so (as tokio's does).
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| fut.poll(cx))) {
            Ok(Poll::Pending) => Poll::Pending,
            Ok(Poll::Ready(v)) => {
                lock(&self.join).finish(Ok(v));
                Poll::Ready(())
            }
            Err(panic) => {
                let msg = panic
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_owned())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                lock(&self.join).finish(Err(TaskError::Panicked(msg)));
                Poll::Ready(())
            }
        }
    }
}

/// A spawned task's handle: await it for its result, or abort it.
#[must_use = "a dropped handle leaves its task running"]
pub struct JoinHandle<T>(Handle<T>);

enum Handle<T> {
    Tokio(tokio::task::JoinHandle<T>),
    Sim(Arc<Mutex<JoinState<T>>>),
}

impl<T> std::fmt::Debug for JoinHandle<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self.0 {
            Handle::Tokio(_) => "JoinHandle(tokio)",
            Handle::Sim(_) => "JoinHandle(run)",
        })
    }
}

impl<T> JoinHandle<T> {
    /// End the task at its next turn (at once on tokio).
    pub fn abort(&self) {
        match &self.0 {
            Handle::Tokio(h) => h.abort(),
            Handle::Sim(j) => {
                let mut j = lock(j);
                j.aborted = true;
                j.task.wake_by_ref();
            }
        }
    }
}

impl<T> From<tokio::task::JoinHandle<T>> for JoinHandle<T> {
    fn from(h: tokio::task::JoinHandle<T>) -> Self {
        JoinHandle(Handle::Tokio(h))
    }
}

impl<T> Future for JoinHandle<T> {
    type Output = Result<T, TaskError>;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        match &mut self.get_mut().0 {
            Handle::Tokio(h) => Pin::new(h).poll(cx).map_err(TaskError::from),
            Handle::Sim(j) => {
                let mut j = lock(j);
                match j.result.take() {
                    Some(r) => Poll::Ready(r),
                    None => {
                        j.waiter = Some(cx.waker().clone());
                        Poll::Pending
                    }
                }
            }
        }
    }
}
