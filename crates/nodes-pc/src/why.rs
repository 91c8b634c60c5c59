//! WHY (control port, command 4: the twin's own, not the spacecraft's, whose PC has no such
//! command): the reason for a refusal, to the one refused. The ICD's failure reply carries a
//! result byte only; the PC knows why it refused, and tells the asker when asked.
//!
//! # Model
//! - One entry per CSP 1.4 address (0-31) in a fixed array: however many requests are
//!   refused, nothing grows. An address's entry is set when the PC refuses a request of
//!   that address on its control, telemetry or files port, and overwritten by its next
//!   refusal; an accepted request leaves it as it is, and asking WHY does not clear it.
//! - Volatile, as the session table: a reboot or a loss of power clears every entry.
//! - Nothing here logs or records: a run in which nobody asks WHY is the run it was
//!   without the command (the refusals are logged where they happen, as they were).
//! - The platform port (14) is the node's, not the PC application's: its refusals are not
//!   kept here.

use std::fmt;

use csp::reqrep::RequestError;

use crate::session::Refusal;
use crate::wire::{RefusalCode, Why};

/// Addresses with an entry: CSP 1.4's 0-31.
const ADDRS: usize = csp::header::MAX_ADDR as usize + 1;

/// A command the PC refuses to payloads under ICD 3.1.1 and 3.1.5 (unless `[rules]
/// payload_access = "open"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Denied {
    /// SETUP (session configuration, ICD 3.1.1).
    Setup,
    /// ABORT (session configuration, ICD 3.1.1).
    Abort,
    /// Any command of the files port (ICD 3.1.5).
    Files,
}

impl Denied {
    /// The words of the run log's warning (`pc: payload 12 refused ...`).
    pub fn log_text(self) -> &'static str {
        match self {
            Denied::Setup => "SETUP: session configuration is the mission's (ICD 3.1.1)",
            Denied::Abort => "ABORT: session configuration is the mission's (ICD 3.1.1)",
            Denied::Files => {
                "the buffer files: the file system interface is denied to payloads (ICD 3.1.5)"
            }
        }
    }
}

impl fmt::Display for Denied {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Denied::Setup => "payloads may not SETUP (ICD 3.1.1)",
            Denied::Abort => "payloads may not ABORT (ICD 3.1.1)",
            Denied::Files => "payloads may not use the buffer files (ICD 3.1.5)",
        })
    }
}

/// Why the PC refused a request.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Reason {
    /// A rule of the session table (SETUP, STATUS, ABORT of the session `session_id`).
    Session {
        /// The session the request named.
        session_id: u8,
        /// The rule.
        refusal: Refusal,
    },
    /// A command refused to payloads.
    Denied(Denied),
    /// A buffer file asked of a payload without a buffering session.
    NoFile {
        /// The payload named.
        payload_addr: u8,
    },
    /// The request did not parse (no command id, wrong length, out of range, unknown id).
    Request(RequestError),
}

impl Reason {
    /// Its code in a WHY reply.
    pub fn code(&self) -> RefusalCode {
        match self {
            Reason::Session { refusal, .. } => match refusal {
                Refusal::UnknownSession(_) => RefusalCode::UnknownSession,
                Refusal::Busy(..) => RefusalCode::Busy,
                Refusal::Overlap(_) => RefusalCode::Overlap,
                Refusal::OtherActive(_) => RefusalCode::OtherActive,
                Refusal::NotRunning(_) => RefusalCode::NotRunning,
            },
            Reason::Denied(_) => RefusalCode::PayloadDenied,
            Reason::NoFile { .. } => RefusalCode::NoFile,
            Reason::Request(e) => match e {
                RequestError::OutOfRange { .. } => RefusalCode::OutOfRange,
                RequestError::UnknownCommand(_) => RefusalCode::UnknownCommand,
                _ => RefusalCode::Malformed,
            },
        }
    }
    /// The session the request named and the session in its way (0: none).
    pub fn sessions(&self) -> (u8, u8) {
        match self {
            Reason::Session {
                session_id,
                refusal: Refusal::Overlap(other) | Refusal::OtherActive(other),
            } => (*session_id, *other),
            Reason::Session { session_id, .. } => (*session_id, 0),
            _ => (0, 0),
        }
    }
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reason::Session { refusal, .. } => refusal.fmt(f),
            Reason::Denied(d) => d.fmt(f),
            Reason::NoFile { payload_addr } => {
                write!(f, "payload {payload_addr} has no buffering session")
            }
            Reason::Request(e) => e.fmt(f),
        }
    }
}

/// A refused request: where it went and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refused {
    /// The PC's port it went to.
    pub port: u8,
    /// Its command id (0 for an empty request).
    pub command: u8,
    /// Why.
    pub reason: Reason,
}

/// The last refusal of each address (see the module doc), as WHY tells it (made when the
/// refusal is kept: refusals are rare, WHY's text is then plain data).
#[derive(Debug, Clone)]
pub struct Refusals {
    last: [Option<Why>; ADDRS],
}

impl Default for Refusals {
    fn default() -> Self {
        Refusals {
            last: std::array::from_fn(|_| None),
        }
    }
}

impl Refusals {
    /// Keep `r` as `src`'s last refusal (an address beyond CSP's is not kept).
    pub fn record(&mut self, src: u8, r: Refused) {
        if let Some(e) = self.last.get_mut(usize::from(src)) {
            let (session_id, other_session_id) = r.reason.sessions();
            *e = Some(Why {
                code: r.reason.code(),
                port: r.port,
                command: r.command,
                session_id,
                other_session_id,
                reason: r.reason.to_string(),
            });
        }
    }

    /// `src`'s last refusal, as WHY tells it.
    pub fn last(&self, src: u8) -> Option<&Why> {
        self.last.get(usize::from(src)).and_then(Option::as_ref)
    }

    /// WHY's reply data for `src`: its last refusal, or code none.
    pub fn why(&self, src: u8) -> Why {
        match self.last(src) {
            Some(w) => w.clone(),
            None => Why {
                reason: "no request from this address refused since the PC booted".to_owned(),
                ..Why::default()
            },
        }
    }

    /// Forget every refusal (a reboot).
    pub fn clear(&mut self) {
        self.last = std::array::from_fn(|_| None);
    }
}

snap::fields!(Refusals { last });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::wire::SessionState;

    /// Each reason's code, sessions and words, within the reply's 64 bytes.
    #[test]
    fn reasons_have_codes_sessions_and_short_words() {
        let session = |session_id, refusal| Reason::Session {
            session_id,
            refusal,
        };
        let cases = [
            (
                session(9, Refusal::UnknownSession(9)),
                RefusalCode::UnknownSession,
                (9, 0),
                "no session 9 is configured",
            ),
            (
                session(1, Refusal::Busy(1, SessionState::Pending)),
                RefusalCode::Busy,
                (1, 0),
                "session 1 is Pending: ABORT it first",
            ),
            (
                session(3, Refusal::Overlap(2)),
                RefusalCode::Overlap,
                (3, 2),
                "window overlaps session 2",
            ),
            (
                session(2, Refusal::OtherActive(1)),
                RefusalCode::OtherActive,
                (2, 1),
                "immediate start while session 1 is ACTIVE",
            ),
            (
                session(1, Refusal::NotRunning(1)),
                RefusalCode::NotRunning,
                (1, 0),
                "session 1 is NOT ACTIVE",
            ),
            (
                Reason::Denied(Denied::Files),
                RefusalCode::PayloadDenied,
                (0, 0),
                "payloads may not use the buffer files (ICD 3.1.5)",
            ),
            (
                Reason::NoFile { payload_addr: 12 },
                RefusalCode::NoFile,
                (0, 0),
                "payload 12 has no buffering session",
            ),
            (
                Reason::Request(RequestError::OutOfRange {
                    command: 1,
                    field: "sessionDuration",
                }),
                RefusalCode::OutOfRange,
                (0, 0),
                "command 1: sessionDuration out of range",
            ),
            (
                Reason::Request(RequestError::UnknownCommand(9)),
                RefusalCode::UnknownCommand,
                (0, 0),
                "unknown command id 9",
            ),
            (
                Reason::Request(RequestError::WrongLength {
                    command: 1,
                    expected: "10 + N, N <= 128",
                    got: 3,
                }),
                RefusalCode::Malformed,
                (0, 0),
                "command 1: request data is 3 bytes, expected 10 + N, N <= 128",
            ),
        ];
        for (reason, code, sessions, words) in cases {
            assert_eq!(
                (reason.code(), reason.sessions(), reason.to_string()),
                (code, sessions, words.to_owned())
            );
            assert!(words.len() <= crate::wire::WHY_REASON_MAX_LEN, "{words}");
        }
        for d in [Denied::Setup, Denied::Abort] {
            assert!(d.to_string().len() <= crate::wire::WHY_REASON_MAX_LEN);
        }
    }

    /// One entry per address, overwritten by the address's next refusal, cleared at a
    /// reboot; an address outside CSP's is not kept.
    #[test]
    fn one_entry_per_address() {
        let mut r = Refusals::default();
        assert_eq!(r.why(17).code, RefusalCode::None);
        let refused = |command, reason| Refused {
            port: 10,
            command,
            reason,
        };
        r.record(17, refused(1, Reason::Denied(Denied::Setup)));
        r.record(
            17,
            refused(
                3,
                Reason::Session {
                    session_id: 1,
                    refusal: Refusal::NotRunning(1),
                },
            ),
        );
        r.record(40, refused(1, Reason::Denied(Denied::Setup)));
        let w = r.why(17);
        assert_eq!(
            (w.code, w.port, w.command, w.session_id, w.reason.as_str()),
            (RefusalCode::NotRunning, 10, 3, 1, "session 1 is NOT ACTIVE")
        );
        assert_eq!(r.why(16).code, RefusalCode::None);
        assert!(r.last(40).is_none());
        r.clear();
        assert_eq!(r.why(17).code, RefusalCode::None);
    }
}
