//! A node's text console (the UART of ICD 1.1) for people and scripts outside the twin:
//! over a TCP socket (`nc`, `telnet`) or a pseudo-terminal linked at a path (`screen`,
//! `minicom`, `picocom`).
//!
//! A line is taken at the instant it arrives ([`Clock::now`]) and handed to the node's
//! task as [`NodeCtl::Console`], which runs it after the node's timers due by then
//! ([`csp::node::Host::console`]); the answer goes back followed by the prompt. One line is
//! in the node at a time per connection (the next is read after the answer), lines are at
//! most [`MAX_LINE`] bytes (a longer one is refused whole), and a console serves at most
//! [`MAX_CONNECTIONS`] connections at once (more wait for TCP's accept). Lines end at CR,
//! LF or CR LF (a terminal in raw mode sends CR); answers end lines with CR LF. Nothing is
//! echoed: use the terminal program's local echo (`picocom --echo`, minicom's `E`).
//! `exit` or `quit` ends a TCP connection.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use bus::clock::Clock;
use bus::driver::{ConsoleRequest, CtlTx, NodeCtl};

/// Longest line a console takes (`csp::console::MAX_LINE`).
pub const MAX_LINE: usize = csp::console::MAX_LINE;
/// Connections a TCP console serves at once.
pub const MAX_CONNECTIONS: usize = 4;
/// How long a line waits for the node's answer before the console says so (a real-time
/// run answers in microseconds; a node's task blocked this long is stuck).
const ANSWER_TIMEOUT: Duration = Duration::from_secs(10);

/// Where a console's lines go: the node's name and control channel.
#[derive(Debug, Clone)]
pub struct ConsoleTarget {
    /// The node's name (banner and prompt).
    pub node: String,
    /// Its CSP address (banner).
    pub addr: u8,
    /// Its control channel.
    pub ctl: CtlTx,
}

/// Serve `target`'s console on `listener` for as long as the run lasts.
pub async fn serve_tcp(listener: tokio::net::TcpListener, target: ConsoleTarget, clock: Clock) {
    let slots = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    loop {
        let Ok(permit) = slots.clone().acquire_owned().await else {
            return;
        };
        let (stream, peer) = match listener.accept().await {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("console {}: accept failed: {e}", target.node);
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        tracing::info!("console {}: {peer} connected", target.node);
        let target = target.clone();
        tokio::spawn(async move {
            let why = session(stream, &target, clock, true).await;
            tracing::info!("console {}: {peer} closed ({why})", target.node);
            drop(permit);
        });
    }
}

/// Serve `target`'s console on `pty` for as long as the run lasts: a session each time a
/// program opens it.
#[cfg(unix)]
pub async fn serve_pty(pty: crate::kiss_pty::Pty, target: ConsoleTarget, clock: Clock) {
    loop {
        pty.wait_open().await;
        tracing::info!("console {}: {} opened", target.node, pty.path().display());
        let why = match pty.stream() {
            Ok(stream) => session(stream, &target, clock, false).await,
            Err(e) => format!("cannot serve it: {e}"),
        };
        tracing::info!(
            "console {}: {} closed ({why})",
            target.node,
            pty.path().display()
        );
        pty.wait_closed().await;
    }
}

/// One connection: banner, then line, answer and prompt until the stream ends.
async fn session<S: AsyncRead + AsyncWrite + Unpin>(
    mut stream: S,
    target: &ConsoleTarget,
    clock: Clock,
    can_exit: bool,
) -> String {
    let prompt = csp::console::prompt(&target.node);
    let banner = format!(
        "M6P twin: {} console (CSP {}); `help` lists the commands\r\n{prompt}",
        target.node, target.addr
    );
    if let Err(e) = stream.write_all(banner.as_bytes()).await {
        return e.to_string();
    }
    let mut line: Vec<u8> = Vec::with_capacity(MAX_LINE);
    let mut too_long = false;
    let mut after_cr = false;
    let mut buf = [0u8; 512];
    loop {
        let n = match stream.read(&mut buf).await {
            Ok(0) => return "end of stream".to_owned(),
            Ok(n) => n,
            Err(e) => return e.to_string(),
        };
        for &b in &buf[..n] {
            let end = b == b'\r' || b == b'\n';
            if b == b'\n' && after_cr {
                after_cr = false;
                continue;
            }
            after_cr = b == b'\r';
            if !end {
                if line.len() < MAX_LINE {
                    line.push(b);
                } else {
                    too_long = true;
                }
                continue;
            }
            let text = String::from_utf8_lossy(&line).trim().to_owned();
            line.clear();
            let answer = if std::mem::take(&mut too_long) {
                format!("error: line longer than {MAX_LINE} characters\n")
            } else if can_exit && (text == "exit" || text == "quit") {
                let _ = stream.write_all(b"bye\r\n").await;
                return "exit".to_owned();
            } else if text.is_empty() {
                String::new()
            } else {
                ask(target, text, clock).await
            };
            let out = format!("{}{prompt}", answer.replace('\n', "\r\n"));
            if let Err(e) = stream.write_all(out.as_bytes()).await {
                return e.to_string();
            }
        }
    }
}

/// Hand `line` to the node at the current instant and wait for its answer.
async fn ask(target: &ConsoleTarget, line: String, clock: Clock) -> String {
    let (req, rx) = ConsoleRequest::new(line);
    if target
        .ctl
        .send((clock.now(), NodeCtl::Console(req)))
        .is_err()
    {
        return "error: the run has ended\n".to_owned();
    }
    match tokio::time::timeout(ANSWER_TIMEOUT, rx).await {
        Ok(Ok(Some(text))) => text,
        Ok(Ok(None)) => format!("({} does not answer: it is off or hung)\n", target.node),
        Ok(Err(_)) => "error: the run has ended\n".to_owned(),
        Err(_) => format!("({} did not answer in {ANSWER_TIMEOUT:?})\n", target.node),
    }
}
