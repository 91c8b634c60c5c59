//! The links between the twin and programs outside it: KISS over TCP and ptys, libcsp's ZMQ
//! hub, CSP over UDP, SocketCAN and the nodes' consoles, each a thin async shell around the media of
//! `m6p-bus`. Everything a link takes in is bounded (connections, chunks read ahead, frames
//! queued for a slow reader, console lines), and what it puts on a segment first crosses
//! the link's gate (`bus::gate`: its faults and power).
//!
//! - [`kiss_tcp`]: KISS over TCP (ICD 2.3), a listening server or a reconnecting client;
//!   its link core (address claims, bounds, gate, tap) serves the other CSP links too.
//! - [`kiss_pty`] (Unix): KISS on a pseudo-terminal, for libcsp's KISS driver.
//! - [`zmq_hub`]: libcsp 1.4's ZMQ hub, played by the twin.
//! - [`udp`]: CSP over UDP, one packet per datagram (YAMCS's CSP links).
//! - `socketcan` (cargo feature `socketcan`, Linux): a bridge between a CAN segment and a
//!   real CAN interface.
//! - [`console`]: a node's text console (the UART of ICD 1.1) over TCP or a pty.

pub mod console;
#[cfg(unix)]
pub mod kiss_pty;
pub mod kiss_tcp;
#[cfg(all(feature = "socketcan", target_os = "linux"))]
pub mod socketcan;
pub mod udp;
pub mod zmq_hub;
