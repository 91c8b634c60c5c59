//! KISS on a pseudo-terminal: the twin opens a pty, links its slave side at a path of the
//! user's choosing and speaks KISS on it, so that a program using libcsp 1.4's KISS driver
//! (`usart_init(PATH)` + `csp_kiss_init`) joins the twin with no `socat` in between.
//!
//! Each time a program opens the path a connection starts (numbered like a KISS/TCP
//! server's: `pty /tmp/m6p-tty#2` for the second), with the link's addresses claimed; when
//! the last opener closes it the connection ends and its addresses go back. The pty itself
//! lives as long as the link, so the program may close and reopen it any number of times
//! (libcsp 1.4's usart driver exits its process when the pty's other side goes away: the
//! twin never closes it first). The slave side is put in raw mode (no echo, no line
//! discipline, no CR/LF translation) when it is created; a program that sets its own
//! termios, as libcsp's driver does, keeps them.
//!
//! The rest (address claims, bounds, gate, tap) is the KISS link core of
//! [`crate::kiss_tcp`].

use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::task::{Context, Poll, ready};
use std::time::Duration;

use nix::errno::Errno;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::unix::pipe;

use crate::kiss_tcp::{KissLinkConfig, SharedStats, bump, run_numbered};
use bus::clock::Clock;
use bus::outside::Segments;

/// How often the link looks whether a program has opened the pty.
const OPEN_POLL: Duration = Duration::from_millis(10);

/// Why a pty link could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum PtyError {
    /// The system refused a pty.
    #[error("cannot open a pseudo-terminal: {0}")]
    Open(Errno),
    /// Setting it up (raw mode, non-blocking, its name) failed.
    #[error("cannot set up the pseudo-terminal: {0}")]
    Setup(std::io::Error),
    /// The path exists and is not a symbolic link (the twin replaces only its own links).
    #[error("{0}: exists and is not a symbolic link; choose another path or remove it")]
    PathTaken(PathBuf),
    /// The link could not be made.
    #[error("{path}: cannot link the pseudo-terminal there: {err}")]
    Link {
        /// The path.
        path: PathBuf,
        /// The cause.
        err: std::io::Error,
    },
}

/// A pty whose slave side is linked at a path; the link is removed when it is dropped.
#[derive(Debug)]
pub struct Pty {
    /// The master side, non-blocking; registered with tokio only while a program holds
    /// the pty ([`Pty::stream`]).
    master: OwnedFd,
    path: PathBuf,
    /// The slave device (`/dev/pts/N`).
    device: PathBuf,
}

impl Pty {
    /// Open a pty in raw mode and link its slave at `path` (replacing a symbolic link
    /// there, never a file). Needs a tokio runtime.
    pub fn open(path: &Path) -> Result<Self, PtyError> {
        let setup = |e: Errno| PtyError::Setup(e.into());
        let pair = nix::pty::openpty(None, None).map_err(PtyError::Open)?;
        let mut t = tcgetattr(&pair.slave).map_err(setup)?;
        cfmakeraw(&mut t);
        tcsetattr(&pair.slave, SetArg::TCSANOW, &t).map_err(setup)?;
        let device = nix::unistd::ttyname(&pair.slave).map_err(setup)?;
        let flags = fcntl(&pair.master, FcntlArg::F_GETFL).map_err(setup)?;
        fcntl(
            &pair.master,
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(setup)?;
        match std::fs::symlink_metadata(path) {
            Ok(m) if m.file_type().is_symlink() => {
                std::fs::remove_file(path).map_err(|err| PtyError::Link {
                    path: path.to_owned(),
                    err,
                })?;
            }
            Ok(_) => return Err(PtyError::PathTaken(path.to_owned())),
            Err(_) => {}
        }
        std::os::unix::fs::symlink(&device, path).map_err(|err| PtyError::Link {
            path: path.to_owned(),
            err,
        })?;
        // The slave closes here: the pty then reads as hung up until a program opens it.
        drop(pair.slave);
        Ok(Pty {
            master: pair.master,
            path: path.to_owned(),
            device,
        })
    }

    /// The path the pty is linked at.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The slave device the path links to.
    pub fn device(&self) -> &Path {
        &self.device
    }

    /// Whether a program holds the slave side open.
    fn opened(&self) -> bool {
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLOUT)];
        match poll(&mut fds, PollTimeout::ZERO) {
            Ok(_) => fds[0]
                .revents()
                .is_some_and(|r| !r.contains(PollFlags::POLLHUP)),
            Err(_) => false,
        }
    }

    /// Wait until a program opens the pty.
    pub async fn wait_open(&self) {
        while !self.opened() {
            tokio::time::sleep(OPEN_POLL).await;
        }
    }

    /// Wait until the program that had it open has closed it.
    pub async fn wait_closed(&self) {
        while self.opened() {
            tokio::time::sleep(OPEN_POLL).await;
        }
    }

    /// The pty as a stream for one connection, once a program has opened it: the master
    /// read and written through tokio's pipe ends (they assume nothing of the descriptor
    /// but that it is non-blocking), on descriptors of their own for this connection.
    ///
    /// Registered afresh each time: tokio keeps a hang-up it has seen as readable for as
    /// long as the registration lives, and a pty reads as hung up between openers, so a
    /// registration from before the open would have each read that finds nothing try
    /// again at once, holding the run's thread until the program closes.
    pub fn stream(&self) -> std::io::Result<PtyStream> {
        let rx = pipe::Receiver::from_owned_fd_unchecked(self.master.try_clone()?)?;
        let tx = pipe::Sender::from_owned_fd_unchecked(self.master.try_clone()?)?;
        Ok(PtyStream { rx, tx })
    }
}

impl Drop for Pty {
    fn drop(&mut self) {
        // Only our own link: a path the user has since pointed elsewhere stays.
        if std::fs::read_link(&self.path).is_ok_and(|d| d == self.device) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// One connection's view of the pty: reading `EIO` (the program closed its side) is the
/// end of the stream.
#[derive(Debug)]
pub struct PtyStream {
    rx: pipe::Receiver,
    tx: pipe::Sender,
}

impl AsyncRead for PtyStream {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        match ready!(Pin::new(&mut self.rx).poll_read(cx, buf)) {
            Err(e) if e.raw_os_error() == Some(Errno::EIO as i32) => Poll::Ready(Ok(())),
            r => Poll::Ready(r),
        }
    }
}

impl AsyncWrite for PtyStream {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.tx).poll_write(cx, data)
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.tx).poll_flush(cx)
    }
    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        // The pty outlives the connection: nothing to shut.
        Poll::Ready(Ok(()))
    }
}

/// Serve the pty as a KISS link for as long as the run lasts: a connection each time a
/// program opens it.
pub async fn serve(
    pty: Pty,
    label: String,
    segs: Segments,
    cfg: KissLinkConfig,
    stats: SharedStats,
    clock: Clock,
) {
    let mut n = 0u64;
    loop {
        pty.wait_open().await;
        n = n.wrapping_add(1);
        tracing::info!("{label}: a program opened {}", pty.path().display());
        let stream = match pty.stream() {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("{label}: cannot serve the program that opened it: {e}");
                pty.wait_closed().await;
                continue;
            }
        };
        bump(&stats, |s| s.connections += 1);
        let why = run_numbered(stream, &label, n, &segs, &cfg, &stats, clock, None).await;
        tracing::info!("{label}: connection closed: {why}");
        bump(&stats, |s| s.disconnects += 1);
        // The program may still hold it for a moment after its last byte: wait for the
        // hang-up before looking for the next opener.
        pty.wait_closed().await;
    }
}
