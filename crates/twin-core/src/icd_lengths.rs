//! The reply lengths the ICD allows, for the `icd-reply-length` invariant: every reply of a
//! platform node (COMM 1/2, FC 3, EPS 4, ECU 5, PC 6) to a request (a packet from a
//! request-reply port to a client's ephemeral port) has the length its command's table
//! gives: `command | result | data`, so 2 + the ICD's size on success (result 1) and exactly
//! 2 on failure, unknown commands included (ICD 1.8, docs/INTERPRETATION.md 2). Sizes come
//! from the ICD's description (`crate::icd`, built from the node crates' own wire types),
//! the ports from the run's configuration.
//!
//! Where the ICD's size column and its types disagree (ATCATGET, ATCPTGET: 16 in the
//! column, 32 and 24 by the types), the types win, as INTERPRETATION 5 decides. Not
//! checked: payloads 12-15 (their behaviours break the ICD on purpose: oversize, wrong echo,
//! garbage), the CSP service ports (ping echoes its request), unsolicited packets (beacons,
//! pushes).

use std::collections::BTreeMap;

use csp::header::{EPHEMERAL_PORT_MIN, Header};
use csp::reqrep::RESULT_SUCCESS;

/// A reply's whole data length (`command | result | data`) allowed on success.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Len {
    /// Exactly this many bytes.
    Exact(usize),
    /// Inclusive.
    Range(usize, usize),
}

impl Len {
    fn holds(self, n: usize) -> bool {
        match self {
            Len::Exact(e) => n == e,
            Len::Range(a, b) => (a..=b).contains(&n),
        }
    }
}

impl std::fmt::Display for Len {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Len::Exact(e) => write!(f, "{e}"),
            Len::Range(a, b) => write!(f, "{a}..={b}"),
        }
    }
}

/// `command | result` before a reply's data.
const HEAD: usize = 2;

const NONE: Len = Len::Exact(HEAD);

/// What one request-reply port answers: by command, or the same for any (FC scripts).
#[derive(Debug, Clone)]
enum PortRule {
    Commands(BTreeMap<u8, Len>),
    Any(Len),
}

/// How a reply contradicts the ICD's table.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ReplyLengthError {
    /// No command byte.
    #[error("{header}: an empty reply")]
    Empty {
        /// The reply's header.
        header: Header,
    },
    /// A length the table does not give the command and result.
    #[error(
        "{header}: reply to command {command} (result {}) is {len_bytes} bytes; the ICD's table gives {allowed}",
        .result.map_or("none".to_owned(), |r| r.to_string())
    )]
    WrongLength {
        /// The reply's header.
        header: Header,
        /// The command byte.
        command: u8,
        /// The result byte, if the reply has one.
        result: Option<u8>,
        /// The reply's data length, without a CRC.
        len_bytes: usize,
        /// What the table allows.
        allowed: Len,
    },
}

/// The ICD's reply lengths of one run's platform nodes, by node address and port.
#[derive(Debug, Clone, Default)]
pub struct IcdTable {
    ports: BTreeMap<(u8, u8), PortRule>,
}

impl IcdTable {
    /// The table for the platform nodes' ports of `icd` (a run's: `RunOptions::icd_map`):
    /// the reply lengths of the ICD's description (`crate::icd`). A port with no command
    /// table (the FC's scripts, the PC's ingest) answers with no data.
    pub fn of(icd: &crate::icd::IcdMap) -> Self {
        let mut ports = BTreeMap::new();
        for (&(addr, port), table) in icd.iter() {
            if !(platform::addr::COMM1..=platform::addr::PC).contains(&addr) {
                continue;
            }
            let rule = if table.commands.is_empty() {
                PortRule::Any(NONE)
            } else {
                PortRule::Commands(
                    table
                        .commands
                        .iter()
                        .map(|c| {
                            let (lo, hi) = c.reply.bounds();
                            let len = if lo == hi {
                                Len::Exact(HEAD + lo)
                            } else {
                                Len::Range(HEAD + lo, HEAD + hi)
                            };
                            (c.id, len)
                        })
                        .collect(),
                )
            };
            ports.insert((addr, port), rule);
        }
        IcdTable { ports }
    }

    /// Check a packet with `header`, `data_len` data bytes (a CRC's 4 included when its
    /// flag is set) starting with `head`: `Ok(true)` for a platform node's reply of the
    /// table's length, `Ok(false)` for what is not such a reply, `Err` says how a reply
    /// contradicts the table.
    pub fn check(
        &self,
        header: &Header,
        data_len: usize,
        head: &[u8],
    ) -> Result<bool, ReplyLengthError> {
        if header.dport < EPHEMERAL_PORT_MIN {
            return Ok(false);
        }
        let Some(rule) = self.ports.get(&(header.src, header.sport)) else {
            return Ok(false);
        };
        let n = data_len.saturating_sub(if header.has_crc() { 4 } else { 0 });
        let (Some(&cmd), result) = (head.first(), head.get(1).copied()) else {
            return Err(ReplyLengthError::Empty { header: *header });
        };
        let want = match (rule, result) {
            (_, Some(r)) if r != RESULT_SUCCESS => NONE,
            (PortRule::Any(l), _) => *l,
            (PortRule::Commands(c), _) => c.get(&cmd).copied().unwrap_or(NONE),
        };
        if want.holds(n) {
            Ok(true)
        } else {
            Err(ReplyLengthError::WrongLength {
                header: *header,
                command: cmd,
                result,
                len_bytes: n,
                allowed: want,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn replies_are_checked_against_the_icd_and_the_configured_ports() {
        let mut fc = nodes_fc::FcConfig::default();
        fc.ports.telemetry = 20;
        let t = IcdTable::of(&crate::icd::IcdMap::for_nodes(&crate::icd::NodePorts {
            seed: 1,
            fc: &fc,
            pc: &nodes_pc::PcConfig::default(),
            eps: &nodes_eps::EpsConfig::default(),
            ecu: &nodes_ecu::EcuConfig::default(),
            comm: &nodes_comm::CommConfig::default(),
        }));
        let reply = |src, sport| Header::new(src, 16, 40, sport);
        // TMGEN: 2 + 16 bytes; a failure is 2; a refused unknown command is 2.
        assert_eq!(t.check(&reply(3, 20), 18, &[1, 1]), Ok(true));
        assert_eq!(t.check(&reply(3, 20), 2, &[1, 0]), Ok(true));
        assert_eq!(t.check(&reply(3, 20), 2, &[99, 0]), Ok(true));
        let e = t.check(&reply(3, 20), 17, &[1, 1]).unwrap_err();
        assert!(
            matches!(
                e,
                ReplyLengthError::WrongLength {
                    command: 1,
                    result: Some(1),
                    len_bytes: 17,
                    allowed: Len::Exact(18),
                    ..
                }
            ),
            "{e:?}"
        );
        let e = e.to_string();
        assert!(
            e.ends_with(": reply to command 1 (result 1) is 17 bytes; the ICD's table gives 18"),
            "{e}"
        );
        let e = t.check(&reply(3, 20), 0, &[]).unwrap_err();
        assert!(e.to_string().ends_with(": an empty reply"), "{e}");
        assert!(t.check(&reply(3, 20), 5, &[1, 0]).is_err());
        // ATCATGET by the ICD's types (32 data bytes), not its size column (16).
        assert_eq!(t.check(&reply(3, 12), 34, &[1, 1]), Ok(true));
        assert!(t.check(&reply(3, 12), 18, &[1, 1]).is_err());
        // PC STATUS: 11 + a sync message of up to 128 bytes.
        assert_eq!(t.check(&reply(6, 10), 13 + 128, &[2, 1]), Ok(true));
        assert!(t.check(&reply(6, 10), 14 + 128, &[2, 1]).is_err());
        // PC files: FREAD 8 + 0..=200, FLIST 1 + 18 per file, FSTAT 18, FDELETE 4.
        assert_eq!(t.check(&reply(6, 13), 2 + 8, &[3, 1]), Ok(true));
        assert_eq!(t.check(&reply(6, 13), 2 + 8 + 200, &[3, 1]), Ok(true));
        assert!(t.check(&reply(6, 13), 2 + 8 + 201, &[3, 1]).is_err());
        assert_eq!(t.check(&reply(6, 13), 2 + 1 + 18, &[1, 1]), Ok(true));
        assert_eq!(t.check(&reply(6, 13), 2 + 18, &[2, 1]), Ok(true));
        assert!(t.check(&reply(6, 13), 2 + 4, &[2, 1]).is_err());
        assert_eq!(t.check(&reply(6, 13), 2 + 4, &[4, 1]), Ok(true));
        // The FC's telemetry store (TMSTOREINFO 20, TMSTOREGET 5..=200) and platform port 14
        // (PGET 3..=6, PSAVE none).
        assert_eq!(t.check(&reply(3, 20), 2 + 20, &[9, 1]), Ok(true));
        assert_eq!(t.check(&reply(3, 20), 2 + 200, &[10, 1]), Ok(true));
        assert!(t.check(&reply(3, 20), 2 + 201, &[10, 1]).is_err());
        assert_eq!(t.check(&reply(4, 14), 2 + 6, &[1, 1]), Ok(true));
        assert!(t.check(&reply(4, 14), 2 + 1, &[5, 1]).is_err());
        // With a CRC, 4 more bytes.
        let mut h = reply(4, 10);
        h.flags |= csp::header::flags::CRC32;
        assert_eq!(t.check(&h, 2 + 4, &[5, 1]), Ok(true));
        // Not replies, or not the platform's: a push to the PC's ingest port, a payload's
        // reply, a ping echo, the FC's old telemetry port.
        assert_eq!(
            t.check(&Header::new(12, 6, 11, 10), 200, &[0, 0]),
            Ok(false)
        );
        assert_eq!(t.check(&reply(12, 10), 200, &[2, 1]), Ok(false));
        assert_eq!(t.check(&reply(3, 1), 100, &[0, 0]), Ok(false));
        assert_eq!(t.check(&reply(3, 10), 100, &[1, 1]), Ok(false));
    }
}
