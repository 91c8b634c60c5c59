//! Bridge between the twin's CAN frames and a real Linux SocketCAN interface
//! (`can0`, `vcan0`, ...).
//!
//! Only compiled with the `socketcan` cargo feature, on Linux:
//! `cargo build -p m6p-links --features socketcan`.
//!
//! [`SocketCanLink`] opens a raw CAN socket bound to one interface and moves
//! [`CanFrame`]s (CFP frames: classic CAN 2.0B, 29-bit extended id) between the
//! twin and the kernel, using the `socketcan` crate's tokio API:
//!
//! - [`SocketCanLink::send`] writes a data frame with the extended-id flag set;
//! - [`SocketCanLink::recv`] returns the next extended-id data frame. Frames CFP
//!   never uses (standard 11-bit ids, remote frames, error frames) are skipped and
//!   counted in [`SocketCanStats`].
//!
//! Linux semantics worth knowing: a raw CAN socket does not receive the frames it
//! sent itself, but every other socket on the same interface does (local loopback
//! is on by default), so two links opened on one `vcan0` see each other's traffic,
//! as two nodes on one bus would.
//!
//! [`to_socketcan`] and [`from_socketcan`] are the pure conversions, usable without
//! an interface.
//!
//! [`bridge`] joins an in-process [`CanBus`] and a real interface: every frame that crosses
//! the bus goes out on the interface, and every CFP frame read from the interface is put on
//! the bus, so outside CSP nodes on `can0`/`vcan0` and the twin's nodes share one bus.

use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::SimTime;
use csp::cfp::{CAN_EFF_MASK, CAN_MAX_DLC, CanFrame};
use socketcan::{EmbeddedFrame, ExtendedId, Frame, Id};

use bus::can::CanBus;
use bus::clock::Clock;
use bus::gate::{DelayLine, LinkGate, Passage};
use bus::inbox::{Arrival, inbox};
pub use bus::outside::BridgeStats;

/// Errors of a [`SocketCanLink`]; every variant names the interface.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SocketCanError {
    /// There is no network interface of that name.
    #[error(
        "CAN interface `{ifname}` does not exist ({source}); create it first, e.g. `ip link add dev {ifname} type vcan && ip link set up {ifname}`"
    )]
    NoSuchInterface {
        /// Interface name as given to [`SocketCanLink::open`].
        ifname: String,
        /// The OS error.
        source: io::Error,
    },
    /// The kernel has no SocketCAN support (`CONFIG_CAN`/`can-raw` missing).
    #[error(
        "cannot open CAN interface `{ifname}`: this kernel has no SocketCAN support (load the `can` and `can_raw` modules): {source}"
    )]
    Unsupported {
        /// Interface name.
        ifname: String,
        /// The OS error.
        source: io::Error,
    },
    /// Any other failure to open or bind the socket (e.g. not a CAN interface).
    #[error("cannot open CAN interface `{ifname}`: {source}")]
    Open {
        /// Interface name.
        ifname: String,
        /// The OS error.
        source: io::Error,
    },
    /// Reading from the socket failed.
    #[error("receive on CAN interface `{ifname}` failed: {source}")]
    Recv {
        /// Interface name.
        ifname: String,
        /// The OS error.
        source: io::Error,
    },
    /// Writing to the socket failed (e.g. interface down: `ENETDOWN`).
    #[error("send on CAN interface `{ifname}` failed: {source}")]
    Send {
        /// Interface name.
        ifname: String,
        /// The OS error.
        source: io::Error,
    },
    /// The frame cannot be sent: id wider than 29 bits or more than 8 data bytes.
    #[error("invalid frame for CAN interface `{ifname}`: id {id:#x}, dlc {dlc}")]
    InvalidFrame {
        /// Interface name.
        ifname: String,
        /// The offending id.
        id: u32,
        /// The offending data length.
        dlc: u8,
    },
}

/// Why [`from_socketcan`] did not convert a frame: CFP only uses extended-id data frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Skipped {
    /// A data frame with a standard 11-bit id.
    StandardId,
    /// A remote transmission request frame.
    Remote,
    /// An error frame reported by the CAN controller driver.
    Error,
}

/// Counters of a [`SocketCanLink`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SocketCanStats {
    /// Extended-id data frames returned by [`SocketCanLink::recv`].
    pub frames_in: u64,
    /// Frames written by [`SocketCanLink::send`].
    pub frames_out: u64,
    /// Received standard-id data frames that were skipped.
    pub skipped_standard: u64,
    /// Received remote frames that were skipped.
    pub skipped_remote: u64,
    /// Received error frames that were skipped.
    pub skipped_error: u64,
}

impl SocketCanStats {
    /// All skipped frames.
    pub fn skipped(&self) -> u64 {
        self.skipped_standard + self.skipped_remote + self.skipped_error
    }
}

#[derive(Debug, Default)]
struct Counters {
    frames_in: AtomicU64,
    frames_out: AtomicU64,
    skipped_standard: AtomicU64,
    skipped_remote: AtomicU64,
    skipped_error: AtomicU64,
}

/// Convert a twin frame to a SocketCAN data frame with an extended id.
///
/// `None` if the id is wider than 29 bits or `dlc` exceeds 8 (possible because
/// [`CanFrame`]'s fields are public).
pub fn to_socketcan(frame: &CanFrame) -> Option<socketcan::CanFrame> {
    if frame.id > CAN_EFF_MASK || usize::from(frame.dlc) > CAN_MAX_DLC {
        return None;
    }
    let id = ExtendedId::new(frame.id)?;
    socketcan::CanDataFrame::new(id, frame.data()).map(socketcan::CanFrame::Data)
}

/// Convert a received SocketCAN frame to a twin frame.
///
/// Only extended-id data frames convert; anything else reports why it was skipped.
pub fn from_socketcan(frame: &socketcan::CanFrame) -> Result<CanFrame, Skipped> {
    match frame {
        socketcan::CanFrame::Data(data) => match data.id() {
            Id::Extended(id) => CanFrame::new(id.as_raw(), data.data()).ok_or(Skipped::Error),
            Id::Standard(_) => Err(Skipped::StandardId),
        },
        socketcan::CanFrame::Remote(_) => Err(Skipped::Remote),
        socketcan::CanFrame::Error(_) => Err(Skipped::Error),
    }
}

/// A raw CAN socket bound to one Linux CAN interface, carrying CFP frames.
///
/// Must be used inside a tokio runtime with I/O enabled.
#[derive(Debug)]
pub struct SocketCanLink {
    ifname: String,
    socket: socketcan::tokio::CanSocket,
    counters: Counters,
}

impl SocketCanLink {
    /// Open a raw CAN socket on `ifname` (e.g. `"vcan0"`).
    ///
    /// A missing interface gives [`SocketCanError::NoSuchInterface`], a kernel
    /// without SocketCAN [`SocketCanError::Unsupported`]. Must be called from
    /// within a tokio runtime.
    pub fn open(ifname: &str) -> Result<SocketCanLink, SocketCanError> {
        let socket = socketcan::tokio::CanSocket::open(ifname).map_err(|source| {
            let ifname = ifname.to_owned();
            match source.raw_os_error() {
                Some(libc_errno::ENODEV) => SocketCanError::NoSuchInterface { ifname, source },
                Some(libc_errno::EAFNOSUPPORT | libc_errno::EPROTONOSUPPORT) => {
                    SocketCanError::Unsupported { ifname, source }
                }
                _ => SocketCanError::Open { ifname, source },
            }
        })?;
        Ok(SocketCanLink {
            ifname: ifname.to_owned(),
            socket,
            counters: Counters::default(),
        })
    }

    /// The interface name this link is bound to.
    pub fn ifname(&self) -> &str {
        &self.ifname
    }

    /// Receive the next extended-id data frame.
    ///
    /// Standard-id, remote and error frames are skipped and counted. Cancel safe:
    /// dropping the future before it completes loses no frame.
    pub async fn recv(&mut self) -> Result<CanFrame, SocketCanError> {
        loop {
            let raw = self
                .socket
                .read_frame()
                .await
                .map_err(|source| SocketCanError::Recv {
                    ifname: self.ifname.clone(),
                    source,
                })?;
            match from_socketcan(&raw) {
                Ok(frame) => {
                    self.counters.frames_in.fetch_add(1, Ordering::Relaxed);
                    return Ok(frame);
                }
                Err(reason) => {
                    let counter = match reason {
                        Skipped::StandardId => &self.counters.skipped_standard,
                        Skipped::Remote => &self.counters.skipped_remote,
                        Skipped::Error => &self.counters.skipped_error,
                    };
                    counter.fetch_add(1, Ordering::Relaxed);
                    tracing::trace!(ifname = %self.ifname, ?reason, id = raw.raw_id(), "skipped CAN frame");
                }
            }
        }
    }

    /// Send one frame as an extended-id data frame.
    pub async fn send(&self, frame: &CanFrame) -> Result<(), SocketCanError> {
        let raw = to_socketcan(frame).ok_or_else(|| SocketCanError::InvalidFrame {
            ifname: self.ifname.clone(),
            id: frame.id,
            dlc: frame.dlc,
        })?;
        self.socket
            .write_frame(raw)
            .await
            .map_err(|source| SocketCanError::Send {
                ifname: self.ifname.clone(),
                source,
            })?;
        self.counters.frames_out.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }

    /// Take the socket's pending error (`SO_ERROR`), if any, as a [`SocketCanError::Recv`].
    ///
    /// The kernel reports the interface going down (`ENETDOWN`) or being deleted
    /// (`ENODEV`) to a bound socket only as a pending error (`EPOLLERR`), and tokio wakes a
    /// task waiting in [`recv`](Self::recv) only when the socket becomes readable: a
    /// task that must notice those events on a quiet bus polls this now and then.
    pub fn take_error(&self) -> Option<SocketCanError> {
        use socketcan::SocketOptions as _;
        let source = match self
            .socket
            .get_socket_option_int(libc_errno::SOL_SOCKET, libc_errno::SO_ERROR)
        {
            Ok(0) => return None,
            Ok(errno) => io::Error::from_raw_os_error(errno),
            Err(e) => e,
        };
        Some(SocketCanError::Recv {
            ifname: self.ifname.clone(),
            source,
        })
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> SocketCanStats {
        let c = &self.counters;
        SocketCanStats {
            frames_in: c.frames_in.load(Ordering::Relaxed),
            frames_out: c.frames_out.load(Ordering::Relaxed),
            skipped_standard: c.skipped_standard.load(Ordering::Relaxed),
            skipped_remote: c.skipped_remote.load(Ordering::Relaxed),
            skipped_error: c.skipped_error.load(Ordering::Relaxed),
        }
    }
}

/// Shared counters of a [`bridge`].
pub type SharedBridgeStats = Arc<Mutex<BridgeStats>>;

fn bump(stats: &SharedBridgeStats, f: impl FnOnce(&mut BridgeStats)) {
    f(&mut stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner));
}

impl SocketCanError {
    /// Whether the error means the interface is gone for good (deleted: `ENODEV`, or the
    /// socket was unbound by its removal: `ENXIO`), rather than down or busy for a while.
    pub fn interface_gone(&self) -> bool {
        match self {
            SocketCanError::NoSuchInterface { .. } => true,
            SocketCanError::Recv { source, .. } | SocketCanError::Send { source, .. } => {
                matches!(
                    source.raw_os_error(),
                    Some(libc_errno::ENODEV | libc_errno::ENXIO)
                )
            }
            _ => false,
        }
    }
}

/// Pause after a failed read, so that a persistent error cannot spin the task.
const RECV_ERROR_PAUSE: Duration = Duration::from_millis(10);
/// How often [`bridge`] looks for a pending socket error ([`SocketCanLink::take_error`]).
const ERROR_POLL: Duration = Duration::from_millis(250);

/// Logs I/O errors of one direction: the first of a series as a warning, the rest at debug
/// level, and the recovery.
#[derive(Debug)]
struct ErrorLog {
    what: &'static str,
    failing: bool,
}

impl ErrorLog {
    fn error(&mut self, name: &str, e: &SocketCanError) {
        if std::mem::replace(&mut self.failing, true) {
            tracing::debug!("{name}: {e}");
        } else {
            tracing::warn!("{name}: {e} (frames are lost while {} fails)", self.what);
        }
    }
    fn ok(&mut self, name: &str) {
        if std::mem::take(&mut self.failing) {
            tracing::info!("{name}: {} works again", self.what);
        }
    }
}

/// Bridge `bus` and the real interface of `link` until the interface goes away (or the
/// task is aborted).
///
/// The bridge attaches to `bus` as a promiscuous endpoint named `socketcan:<ifname>`:
/// - every frame that crosses the bus is written to the interface;
/// - every extended data frame read from the interface is sent on the bus at
///   `clock.now()`; the bus delivers it by CFP destination and never back to the bridge.
///   Other frames (standard id, remote, error) are skipped.
///
/// The kernel does not return a socket's own frames to it, so nothing loops. Read and
/// write errors are counted in `stats` and logged, and the frame is lost; an interface that
/// is down (`ENETDOWN`) is waited for. When the interface is deleted (seen at the next
/// write, or within 250 ms on a quiet bus) the bridge logs it, records it in
/// [`BridgeStats::ended`], leaves the bus and returns.
///
/// Every frame crossing, in either direction, passes `gate` (the link's faults and power,
/// [`bus::gate`]): it crosses now, waits out a delay, or is lost (counted by the gate).
pub async fn bridge(
    bus: CanBus,
    mut link: SocketCanLink,
    clock: Clock,
    stats: SharedBridgeStats,
    gate: Option<LinkGate>,
) {
    let ifname = link.ifname().to_owned();
    let name = format!("socketcan:{ifname}");
    let (inbox_tx, mut inbox_rx) = inbox();
    let port = bus.attach(&name, &[], true, inbox_tx, 0);
    tracing::info!(bus = %bus.name(), "{name}: bridging the in-process CAN bus");
    let mut recv_log = ErrorLog {
        what: "receiving",
        failing: false,
    };
    let mut send_log = ErrorLog {
        what: "sending",
        failing: false,
    };
    let mut poll = tokio::time::interval(ERROR_POLL);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let pass = || gate.as_ref().map_or(Passage::Now, LinkGate::pass);
    let overflow = || {
        if let Some(g) = &gate {
            g.overflowed();
        }
        tracing::warn!("{name}: delay line full: frame lost");
    };
    // Frames waiting out a `delay` fault, into the twin and out of it.
    let mut delayed_in: DelayLine<CanFrame> = DelayLine::default();
    let mut delayed_out: DelayLine<CanFrame> = DelayLine::default();
    let why = loop {
        let next_due = [delayed_in.next_due(), delayed_out.next_due()]
            .into_iter()
            .flatten()
            .min();
        tokio::select! {
            biased;
            () = clock.sleep_until(next_due.unwrap_or(SimTime::MAX)), if next_due.is_some() => {
                let now = next_due.unwrap_or(SimTime::MAX);
                while let Some((t, frame)) = delayed_in.pop_due(now) {
                    port.send(t, frame);
                }
                send_delayed(&mut delayed_out, now, &link, &stats, &mut send_log, &name).await;
            }
            // From the interface first: frames are stamped with the time they are read.
            r = link.recv() => match r {
                Ok(frame) => {
                    let t = clock.now();
                    match pass() {
                        Passage::Now => port.send(t, frame),
                        Passage::After(d) => {
                            if delayed_in.push(t + d, frame).is_err() {
                                overflow();
                            }
                        }
                        Passage::Lost(_) => {}
                    }
                    let skipped = link.stats().skipped();
                    bump(&stats, |s| { s.frames_in += 1; s.skipped = skipped; });
                    recv_log.ok(&name);
                }
                Err(e) => {
                    bump(&stats, |s| s.recv_errors += 1);
                    if e.interface_gone() {
                        break e.to_string();
                    }
                    recv_log.error(&name, &e);
                    tokio::time::sleep(RECV_ERROR_PAUSE).await;
                }
            },
            a = inbox_rx.recv() => {
                // The bus keeps a sender for as long as it exists: `None` means it is gone.
                let Some(a) = a else { break "the in-process bus was dropped".to_owned() };
                let Arrival::Can(frame) = a.what else { continue };
                match pass() {
                    Passage::Now => {}
                    Passage::After(d) => {
                        if delayed_out.push(a.t + d, frame).is_err() {
                            overflow();
                        }
                        continue;
                    }
                    Passage::Lost(_) => continue,
                }
                if let Some(why) = send_out(&link, &frame, &stats, &mut send_log, &name).await {
                    break why;
                }
            }
            _ = poll.tick() => {
                if let Some(e) = link.take_error() {
                    bump(&stats, |s| s.recv_errors += 1);
                    if e.interface_gone() {
                        break e.to_string();
                    }
                    recv_log.error(&name, &e);
                }
            }
        }
    };
    tracing::warn!("{name}: bridge stopped: {why}");
    bus.release(&port);
    let skipped = link.stats().skipped();
    bump(&stats, |s| {
        s.skipped = skipped;
        s.ended = Some(why);
    });
}

/// Write the frames whose delay fault is over by `now` to the interface (a failed write loses one).
async fn send_delayed(
    delayed: &mut DelayLine<CanFrame>,
    now: SimTime,
    link: &SocketCanLink,
    stats: &SharedBridgeStats,
    send_log: &mut ErrorLog,
    name: &str,
) {
    while let Some((_, frame)) = delayed.pop_due(now) {
        match link.send(&frame).await {
            Ok(()) => bump(stats, |s| s.frames_out += 1),
            Err(e) => {
                bump(stats, |s| s.send_errors += 1);
                send_log.error(name, &e);
            }
        }
    }
}

/// Write a frame of the bus to the interface; the reason to stop when the interface is gone.
async fn send_out(
    link: &SocketCanLink,
    frame: &CanFrame,
    stats: &SharedBridgeStats,
    send_log: &mut ErrorLog,
    name: &str,
) -> Option<String> {
    match link.send(frame).await {
        Ok(()) => {
            bump(stats, |s| s.frames_out += 1);
            send_log.ok(name);
        }
        Err(e) => {
            bump(stats, |s| s.send_errors += 1);
            if e.interface_gone() {
                return Some(e.to_string());
            }
            send_log.error(name, &e);
        }
    }
    None
}

/// The few Linux errno values `open` and [`bridge`] distinguish (x86-64/aarch64 generic values),
/// kept here to avoid a direct `libc` dependency.
mod libc_errno {
    pub const SOL_SOCKET: i32 = 1;
    pub const SO_ERROR: i32 = 4;
    pub const ENXIO: i32 = 6;
    pub const ENODEV: i32 = 19;
    pub const EPROTONOSUPPORT: i32 = 93;
    pub const EAFNOSUPPORT: i32 = 97;
}

#[cfg(test)]
mod tests {
    use super::*;
    use socketcan::{CanErrorFrame, CanRemoteFrame, StandardId};

    #[test]
    fn round_trip_sets_extended_flag() {
        let frame = CanFrame::new(0x1F12_3456 & CAN_EFF_MASK, &[1, 2, 3]).expect("valid frame");
        let raw = to_socketcan(&frame).expect("convertible");
        assert!(raw.is_extended());
        assert!(raw.is_data_frame());
        assert_eq!(raw.raw_id(), frame.id);
        assert_eq!(raw.data(), &[1, 2, 3]);
        assert_eq!(from_socketcan(&raw), Ok(frame));

        let empty = CanFrame::new(0, &[]).expect("valid frame");
        let raw = to_socketcan(&empty).expect("convertible");
        assert!(raw.is_extended());
        assert_eq!(from_socketcan(&raw), Ok(empty));
    }

    #[test]
    fn invalid_twin_frames_do_not_convert() {
        let mut frame = CanFrame::new(1, &[0; 8]).expect("valid frame");
        frame.id = CAN_EFF_MASK + 1;
        assert_eq!(to_socketcan(&frame), None);
        frame.id = 1;
        frame.dlc = 9;
        assert_eq!(to_socketcan(&frame), None);
    }

    #[test]
    fn non_cfp_frames_are_skipped() {
        let std_id = StandardId::new(0x123).expect("valid id");
        let standard = socketcan::CanDataFrame::new(std_id, &[1]).expect("frame");
        assert_eq!(from_socketcan(&standard.into()), Err(Skipped::StandardId));

        let ext = ExtendedId::new(0x1234).expect("valid id");
        let remote = CanRemoteFrame::new_remote(ext, 2).expect("frame");
        assert_eq!(from_socketcan(&remote.into()), Err(Skipped::Remote));

        let error = CanErrorFrame::new_error(0x4, &[0; 8]).expect("frame");
        assert_eq!(from_socketcan(&error.into()), Err(Skipped::Error));
    }

    #[test]
    fn missing_interface_is_an_error_naming_it() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        let err = rt
            .block_on(async { SocketCanLink::open("m6pnosuch0") })
            .expect_err("interface must not exist");
        assert!(err.to_string().contains("m6pnosuch0"), "{err}");
        assert!(
            matches!(
                err,
                SocketCanError::NoSuchInterface { .. } | SocketCanError::Unsupported { .. }
            ),
            "{err:?}"
        );
    }

    #[test]
    fn stats_sum_skipped() {
        let s = SocketCanStats {
            skipped_standard: 1,
            skipped_remote: 2,
            skipped_error: 3,
            ..Default::default()
        };
        assert_eq!(s.skipped(), 6);
    }
}
