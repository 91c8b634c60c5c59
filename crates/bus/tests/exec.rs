//! The run's executor (`bus::exec`): the order of the tasks due at one instant, and what a
//! task's panic or abort does.
#![allow(clippy::unwrap_used)]

use std::sync::{Arc, Mutex};

use csp::SimTime;
use m6p_bus::clock::{Clock, ClockMode, Timer};
use m6p_bus::exec::{TaskError, run, spawn};

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap()
}

mod common;
use common::runtime;

/// Which of the tasks due at one instant runs first is their spawn order, whatever
/// order and history their timers were set with; the root is first of all.
#[test]
fn tasks_due_at_one_instant_run_in_spawn_order_whatever_their_timers_history() {
    let ran = Arc::new(Mutex::new(Vec::new()));
    let at = SimTime::from_ms(50);
    runtime().block_on(async {
        let clock = Clock::new(ClockMode::Virtual);
        let log = ran.clone();
        run(clock, async move {
            let mut tasks = Vec::new();
            // Task 1 sets its timer last; task 3 first; task 2 set it for later, then
            // earlier; task 4 at a sub-millisecond instant before the others.
            for (name, delay_ms, detour) in [
                ("first", 3_u64, None),
                ("second", 2, Some(SimTime::from_ms(900))),
                ("third", 1, None),
            ] {
                let log = log.clone();
                tasks.push(spawn(async move {
                    let mut timer = Timer::new(clock);
                    if let Some(d) = detour {
                        tokio::select! {
                            biased;
                            () = timer.sleep_until(d) => unreachable!(),
                            () = clock.sleep_until(SimTime::ZERO) => {}
                        }
                    }
                    Timer::new(clock)
                        .sleep_until(SimTime::from_ms(delay_ms))
                        .await;
                    timer.sleep_until(at).await;
                    lock(&log).push(name);
                }));
            }
            let log2 = log.clone();
            tasks.push(spawn(async move {
                Timer::new(clock)
                    .sleep_until(SimTime::from_ns(49_700_000))
                    .await;
                lock(&log2).push("earlier instant");
            }));
            Timer::new(clock).sleep_until(at).await;
            lock(&log).push("root");
            for t in tasks {
                t.await.unwrap();
            }
        })
        .await;
    });
    assert_eq!(
        *lock(&ran),
        ["earlier instant", "root", "first", "second", "third"]
    );
}

/// A task's panic and its abort are its handle's errors; the run goes on.
#[test]
fn a_panic_or_an_abort_ends_the_task_not_the_run() {
    runtime().block_on(async {
        let clock = Clock::new(ClockMode::Virtual);
        run(clock, async move {
            let panics = spawn(async { panic!("on purpose") });
            let waits = spawn(async move { clock.sleep_until(SimTime::from_secs(5)).await });
            waits.abort();
            assert!(matches!(panics.await, Err(TaskError::Panicked(m)) if m == "on purpose"));
            assert!(matches!(waits.await, Err(TaskError::Cancelled)));
            clock.sleep_until(SimTime::from_secs(1)).await;
            assert_eq!(clock.now(), SimTime::from_secs(1));
        })
        .await;
    });
}
