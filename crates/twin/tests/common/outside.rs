//! An outside program's blocking client on a thread of its own.

use std::future::Future;

/// Run `f` on a new OS thread; the future resolves to its value (an error when it panicked).
///
/// Not `tokio::task::spawn_blocking`: a run's runtime keeps tokio's paused clock, and a
/// blocking task of that runtime holds the clock still for as long as it runs (tokio does not
/// advance a paused clock while one is running), so the twin would never answer it.
pub fn on_thread<T: Send + 'static>(
    f: impl FnOnce() -> T + Send + 'static,
) -> impl Future<Output = Result<T, tokio::sync::oneshot::error::RecvError>> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx
}
