//! Real time that replays: the run is always the virtual-time machine (tokio's paused
//! clock), and in real time its clock is held back to the wall clock; what outside programs
//! send enters it at a point the run itself defines, so that a recording's inputs and their
//! instants determine the run and `replay` reproduces it whatever the machine's load.
//!
//! Two rules, both applied by [`on_idle`], the runtime's `on_thread_park` hook (tokio calls
//! it each time the run's one thread has no task ready, before its clock jumps to the next
//! timer):
//!
//! - **Outside input is taken at the first idle point of a millisecond tick.** What a
//!   socket gives is queued ([`take_in`], [`admitted`]) and handed to the run, in the order
//!   it was queued, stamped with the tick's simulated instant, when the run first has
//!   nothing left to do at that instant: after everything the tick's timers started, never
//!   in the middle of it. Input queued after that point waits for the next tick's. A replay
//!   queues the recorded input at its recorded instant and it is handed over at the same
//!   point, in the same order.
//! - **In real time the clock does not pass the wall clock.** A pacer task keeps a timer at
//!   every millisecond tick ([`pacer`]), and at an idle point the hook sleeps the thread
//!   until the wall clock reaches the next tick; only then may tokio advance. A run too
//!   loaded to keep up falls behind the wall clock rather than changing what happens.
//!
//! The hook is configured when the runtime is built, before a run exists, and every task of
//! a run runs on the runtime's one thread: so the run's state is a thread-local,
//! [`install`]ed for the run's length. Without one (a unit test on a plain runtime) input
//! is taken at once.
//!
//! Nothing of a run may block its runtime: a `spawn_blocking` task (and `tokio::fs`, which
//! is made of them) keeps tokio from advancing the paused clock while it runs, so a run
//! holds still until it returns. Blocking work goes to a thread of its own.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::time::Duration;

use csp::SimTime;

use crate::clock::Clock;

/// One item of outside input waiting for the run: what hands it over, given the simulated
/// instant it is taken at.
type Take = Box<dyn FnOnce(SimTime)>;

/// The granularity of tokio's timer wheel, and of the instants input is taken at.
const TICK: Duration = Duration::from_millis(1);

/// The wall clock's hold on a run in real time.
#[derive(Debug, Clone, Copy)]
struct Wall {
    /// When pacing began, on the wall clock and in simulated time.
    wall0: std::time::Instant,
    sim0: SimTime,
    /// Simulated seconds per wall second.
    speed: f64,
}

impl Wall {
    /// The wall-clock instant simulated time `t` is due at.
    fn due(&self, t: SimTime) -> std::time::Instant {
        let sim = t.as_ns().saturating_sub(self.sim0.as_ns());
        self.wall0 + Duration::from_secs_f64(sim as f64 * 1e-9 / self.speed)
    }
}

struct Run {
    clock: Clock,
    /// The tick the run was last idle at: input is handed over at a tick's first.
    idle_at: Option<SimTime>,
    pending: VecDeque<Take>,
    wall: Option<Wall>,
}

thread_local! {
    static RUN: RefCell<Option<Run>> = const { RefCell::new(None) };
}

/// The run's state on this thread, while it lives.
#[derive(Debug)]
#[must_use = "the run's pacing ends when this is dropped"]
pub struct Installed(());

impl Drop for Installed {
    fn drop(&mut self) {
        RUN.with_borrow_mut(|r| *r = None);
    }
}

/// Install a run on `clock` on this thread (the thread its current-thread runtime runs
/// on), until the guard is dropped.
pub fn install(clock: Clock) -> Installed {
    RUN.with_borrow_mut(|r| {
        *r = Some(Run {
            clock,
            idle_at: None,
            pending: VecDeque::new(),
            wall: None,
        });
    });
    Installed(())
}

/// The runtime's `on_thread_park` hook: hands queued input over at a tick's first idle
/// point and, in real time, holds the thread until the wall clock reaches the next tick.
pub fn on_idle() {
    let Some((now, batch, wall)) = RUN.with_borrow_mut(|r| {
        let r = r.as_mut()?;
        let now = r.clock.now();
        let batch = if r.idle_at == Some(now) {
            VecDeque::new()
        } else {
            r.idle_at = Some(now);
            std::mem::take(&mut r.pending)
        };
        Some((now, batch, r.wall))
    }) else {
        return;
    };
    // Outside the borrow: what is handed over may queue more.
    if !batch.is_empty() {
        for take in batch {
            take(now);
        }
        // Tasks were woken: the thread does not park.
        return;
    }
    if let Some(w) = wall {
        let due = w.due(next_tick(now));
        let left = due.saturating_duration_since(std::time::Instant::now());
        if !left.is_zero() {
            std::thread::sleep(left);
        }
    }
}

/// The first tick after `t`.
fn next_tick(t: SimTime) -> SimTime {
    let tick = TICK.as_nanos() as u64;
    SimTime((t.as_ns() / tick + 1) * tick)
}

/// Queue `take` to be handed over at the run's next idle point (at once, with `clock`'s
/// time, when no run is installed on this thread).
pub fn take_in(clock: Clock, take: impl FnOnce(SimTime) + 'static) {
    let take: Take = Box::new(take);
    let left = RUN.with_borrow_mut(|r| match r {
        Some(r) => {
            r.pending.push_back(take);
            None
        }
        None => Some(take),
    });
    if let Some(take) = left {
        take(clock.now());
    }
}

/// The simulated instant the run takes an input in (a connection's open or close): queued
/// now, in order with the rest, resolved at the next idle point.
pub fn admitted(clock: Clock) -> impl std::future::Future<Output = SimTime> + Send {
    let (tx, rx) = tokio::sync::oneshot::channel();
    take_in(clock, move |t| {
        let _ = tx.send(t);
    });
    async move { rx.await.unwrap_or_else(|_| clock.now()) }
}

/// In real time, hold the run to the wall clock from `from` on at `speed` (a task of the
/// run's runtime, for the run's length): a timer at every tick, so that tokio's clock never
/// jumps further than the next one, and from `from` on the wall clock's hold at each idle
/// point. Returns when `from` is reached, after `on_start`, then paces.
pub async fn pacer(clock: Clock, from: SimTime, speed: f64, on_start: impl FnOnce(SimTime)) {
    clock.sleep_until(from).await;
    let now = clock.now();
    RUN.with_borrow_mut(|r| {
        if let Some(r) = r.as_mut() {
            r.wall = Some(Wall {
                wall0: std::time::Instant::now(),
                sim0: now,
                speed,
            });
        }
    });
    on_start(now);
    let mut timer = crate::clock::Timer::new(clock);
    loop {
        timer.sleep_until(next_tick(clock.now())).await;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::clock::ClockMode;

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .on_thread_park(on_idle)
            .build()
            .unwrap()
    }

    /// Virtual until `from` (10 s pass at once), then the wall clock at twice real time.
    #[test]
    fn virtual_until_from_then_the_wall_clock_at_its_speed() {
        runtime().block_on(async {
            let from = SimTime::from_secs(10);
            let clock = Clock::new(ClockMode::VirtualThenRealtime { from, speed: 2.0 });
            let _run = install(clock);
            let wall = std::time::Instant::now();
            tokio::spawn(pacer(clock, from, 2.0, |_| {}));
            clock.sleep_until(SimTime::from_secs(4)).await;
            assert_eq!(clock.now(), SimTime::from_secs(4));
            clock.sleep_until(from).await;
            assert!(wall.elapsed() < Duration::from_millis(500), "virtual part");
            let w = std::time::Instant::now();
            clock.sleep_until(from + Duration::from_millis(400)).await;
            let took = w.elapsed();
            assert!(
                took >= Duration::from_millis(195) && took < Duration::from_secs(2),
                "400 ms simulated at speed 2 took {took:?} of wall clock"
            );
            assert_eq!(clock.now(), from + Duration::from_millis(400));
        });
    }

    /// Input is taken at the first idle point of a tick, after all the tick's timers did,
    /// in the order it was queued; input queued after that point waits for the next tick.
    #[test]
    fn input_is_taken_at_a_ticks_first_idle_point_in_order() {
        runtime().block_on(async {
            let clock = Clock::new(ClockMode::Virtual);
            let _run = install(clock);
            let log = std::rc::Rc::new(RefCell::new(Vec::new()));
            let at = SimTime::from_ns(5_000_000);
            let local = tokio::task::LocalSet::new();
            local
                .run_until(async {
                    let l = log.clone();
                    tokio::task::spawn_local(async move {
                        clock.sleep_until(at).await;
                        l.borrow_mut().push(("timer", clock.now()));
                    });
                    clock.sleep_until(at).await;
                    for name in ["a", "b"] {
                        let l = log.clone();
                        take_in(clock, move |t| l.borrow_mut().push((name, t)));
                    }
                    let opened = admitted(clock).await;
                    assert_eq!(opened, at);
                    // After the tick's idle point: the next tick's.
                    let l = log.clone();
                    take_in(clock, move |t| l.borrow_mut().push(("late", t)));
                    clock.sleep_until(at + Duration::from_millis(3)).await;
                    admitted(clock).await;
                })
                .await;
            let later = at + Duration::from_millis(3);
            assert_eq!(
                *log.borrow(),
                [("timer", at), ("a", at), ("b", at), ("late", later)]
            );
        });
    }
}
