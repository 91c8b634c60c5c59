//! The PC's sessions as a run sees them: session runs and their ends, downlinked bytes per
//! session, drops by reason, the accounting of every payload byte ([`SessionsReport`]).

use csp::SimTime;
use std::collections::BTreeMap;
use twin_scenario::pc::RunEnd;

/// One run of a session, as the PC reported it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionRun {
    /// Session id.
    pub session: u8,
    /// The session's payload (`None`: the run ended without starting).
    pub payload: Option<u8>,
    /// When it became ACTIVE (`None`: it ended without starting, as an ABORT of a
    /// PENDING session may report).
    pub started: Option<SimTime>,
    /// When it ended, how, and the packets counted (`None`: still ACTIVE at the end of the
    /// run).
    pub ended: Option<(SimTime, RunEnd, u32)>,
    /// Bytes downlinked while it was the session's latest run, in order (none kept when
    /// the report forgets them: [`SessionsReport::forget_bytes`]).
    pub bytes: Vec<u8>,
    /// How many bytes were downlinked while it was the session's latest run.
    pub len: u64,
    /// Those bytes checked as a Counter stream as they arrived (what `downlink`
    /// expectations judge).
    pub stream: nodes_payload::StreamChecker,
}

/// What a run's PC and payloads did, gathered from the event stream.
#[derive(Debug, Clone, Default)]
pub struct SessionsReport {
    /// Every session run, in start order.
    pub runs: Vec<SessionRun>,
    /// Bytes downlinked, by payload.
    pub downlinked: BTreeMap<u8, u64>,
    /// Bytes dropped by the PC, by payload and reason.
    pub dropped: BTreeMap<(u8, String), u64>,
    /// Bytes each simulated payload produced (sent in replies and pushes).
    pub produced: BTreeMap<u8, u64>,
    /// SYNC messages each payload received.
    pub syncs: BTreeMap<u8, u64>,
    /// Bytes the PC still held at the end of the run (buffer file and S-band queue), by
    /// payload; `None` until the PC's final accounting arrives.
    pub held: Option<BTreeMap<u8, u64>>,
    /// Whether the PC's own ledgers balanced at the end.
    pub pc_balanced: Option<bool>,
    /// Packets in transit on the CAN buses (a payload's packets lost there count as
    /// dropped, with the bus's reason).
    pub transit: twin_core::transit::Transit,
    /// Keep only each run's length and stream check, not its bytes (a long run's memory
    /// then does not grow with what it downlinks; the S-band sink's files have them).
    pub forget_bytes: bool,
}

impl SessionsReport {
    /// Take in one event of the run.
    pub fn observe(&mut self, ev: &twin_core::events::RunEvent) {
        use twin_core::events::RunEvent;
        match ev {
            RunEvent::Pc(o) => self.observe_pc(o),
            RunEvent::Payload { addr, out } => match out {
                nodes_payload::PayloadOutput::Produced { bytes, .. } => {
                    *self.produced.entry(*addr).or_default() += bytes;
                }
                nodes_payload::PayloadOutput::SyncReceived { .. } => {
                    *self.syncs.entry(*addr).or_default() += 1;
                }
            },
            // A payload's packet that lost a frame between the payload and the PC (dropped
            // on the bus, or never sent: its transmit queue full, bus-off, powered off).
            RunEvent::Medium(m) => {
                if let Some(lost) = self.transit.observe(m) {
                    self.lost_in_transit(&lost);
                }
            }
            // A packet a node's CAN reassembly dropped (its BEGIN refused for want of a
            // free buffer, the partial packet timed out or went with a reboot): lost there,
            // unless it lost a frame on the bus before.
            RunEvent::PacketDropped {
                log,
                packet:
                    csp::node::DroppedPacket {
                        cfp: Some((can_id, drop)),
                        ..
                    },
                ..
            } => {
                let why = match drop {
                    csp::cfp::CfpDrop::Timeout => "the receiver's CAN reassembly timed out",
                    csp::cfp::CfpDrop::Reset => "the receiver rebooted during its reassembly",
                    _ => "the receiver's CAN reassembly refused it",
                };
                if let Some(lost) = self.transit.receiver_dropped(*can_id, log.t(), why) {
                    self.lost_in_transit(&lost);
                }
            }
            // A payload's POLL reply that reached the PC after the PC stopped listening for
            // it (its request's ephemeral port was no longer bound): the PC's CSP dropped it
            // (an unbound port is the destination's own drop). Its
            // data (after the reply's command and result bytes) was produced: dropped here.
            RunEvent::PacketDropped { reason, packet, .. }
                if *reason == csp::drop::DropReason::UnboundPort
                    && packet.header.dst == platform::addr::PC
                    && packet.header.sport == nodes_payload::wire::PORT
                    && self.produced.contains_key(&packet.header.src) =>
            {
                let data = packet.data_len.saturating_sub(REPLY_HEAD_BYTES) as u64;
                *self
                    .dropped
                    .entry((packet.header.src, LATE_AT_CSP.to_owned()))
                    .or_default() += data;
            }
            _ => {}
        }
    }

    /// What the PC reported: a session's run starting or ending, bytes downlinked or
    /// dropped, its final accounting.
    fn observe_pc(&mut self, o: &nodes_pc::PcOutput) {
        use nodes_pc::PcOutput as O;
        match o {
            O::SessionStarted {
                t,
                session_id,
                payload_addr,
            } => self.runs.push(SessionRun {
                session: *session_id,
                payload: Some(*payload_addr),
                started: Some(*t),
                ended: None,
                bytes: Vec::new(),
                len: 0,
                stream: Default::default(),
            }),
            O::SessionEnded {
                t,
                session_id,
                result,
                packets,
            } => self.end_run(*session_id, (*t, RunEnd::Result(*result), *packets)),
            O::SessionLost {
                t,
                session_id,
                cause,
                packets,
            } => self.end_run(*session_id, (*t, RunEnd::Lost(*cause), *packets)),
            O::Downlinked {
                session_id,
                payload_addr,
                bytes,
                ..
            } => {
                *self.downlinked.entry(*payload_addr).or_default() += bytes.len() as u64;
                let keep = !self.forget_bytes;
                if let Some(r) = self
                    .runs
                    .iter_mut()
                    .rev()
                    .find(|r| r.session == *session_id)
                {
                    r.len += bytes.len() as u64;
                    r.stream.push(bytes);
                    if keep {
                        r.bytes.extend_from_slice(bytes);
                    }
                }
            }
            O::Dropped {
                payload_addr,
                reason,
                bytes,
                ..
            } => {
                *self
                    .dropped
                    .entry((*payload_addr, reason.as_str().to_owned()))
                    .or_default() += bytes;
            }
            O::Final { accounting, .. } => {
                let held = self.held.get_or_insert_with(BTreeMap::new);
                for x in &accounting.sessions {
                    *held.entry(x.payload_addr).or_default() +=
                        x.bytes.buffered_now + x.bytes.queued_now;
                }
                self.pc_balanced = Some(accounting.is_balanced());
            }
        }
    }

    /// Session `session`'s latest run ended `end` (a run of its own when none is open: the
    /// PC may report an end without a start, as an ABORT of a PENDING session).
    fn end_run(&mut self, session: u8, end: (SimTime, RunEnd, u32)) {
        match self.latest_open(session) {
            Some(r) => r.ended = Some(end),
            None => self.runs.push(SessionRun {
                session,
                payload: None,
                started: None,
                ended: Some(end),
                bytes: Vec::new(),
                len: 0,
                stream: Default::default(),
            }),
        }
    }

    /// A packet lost between its sender and its receiver: a payload's data in it counts
    /// as dropped, with where and why.
    fn lost_in_transit(&mut self, lost: &twin_core::transit::LostPacket) {
        let h = &lost.header;
        if !self.produced.contains_key(&h.src) {
            return;
        }
        // A reply to the PC's request (from the payload's ICD port to the request's
        // ephemeral port) carries the command and result before its stream bytes; a push
        // (from the payload's own port to a port the PC serves: a simulated payload sends
        // it nothing else there) is all stream bytes.
        let server_port = h.dport < csp::header::EPHEMERAL_PORT_MIN;
        let data = if h.sport == nodes_payload::wire::PORT && !server_port {
            lost.data_len.saturating_sub(REPLY_HEAD_BYTES)
        } else if h.dst == platform::addr::PC && server_port {
            lost.data_len
        } else {
            return;
        };
        let reason = format!("lost on the {} bus ({})", lost.bus, lost.reason);
        *self.dropped.entry((h.src, reason)).or_default() += data as u64;
    }

    fn latest_open(&mut self, session: u8) -> Option<&mut SessionRun> {
        self.runs
            .iter_mut()
            .rev()
            .find(|r| r.session == session)
            .filter(|r| r.ended.is_none())
    }

    /// Every byte downlinked for `session`, over all its runs (none when the report
    /// forgets them).
    pub fn session_bytes(&self, session: u8) -> Vec<u8> {
        self.runs
            .iter()
            .filter(|r| r.session == session)
            .flat_map(|r| r.bytes.iter().copied())
            .collect()
    }

    /// Bytes dropped for `payload`, all reasons.
    pub fn dropped_total(&self, payload: u8) -> u64 {
        self.dropped
            .iter()
            .filter(|((a, _), _)| *a == payload)
            .map(|(_, n)| n)
            .sum()
    }
}

/// The S-band ground sink's files, written as the bytes arrive: each session run's file
/// (`dir/session-<id>-run<k>.bin`, k from 1 per session, as [`SessionsReport::runs`]) is
/// created when the run starts and each downlinked
/// frame's bytes are appended to it when the ground receives them, so that a payload
/// engineer can watch a real-time session's data arrive (`tail -c +1 -f`). A write that
/// fails is logged once and counted; the run goes on.
#[derive(Debug)]
pub struct DownlinkFiles {
    dir: std::path::PathBuf,
    runs: BTreeMap<u8, u32>,
    /// The latest run's file of each session.
    open: BTreeMap<u8, OpenRun>,
    /// The files written, in the order their runs started.
    pub files: Vec<std::path::PathBuf>,
    /// Writes that failed (the first is logged).
    pub errors: u64,
    /// The first failure.
    pub first_error: Option<String>,
}

/// A session's latest run's file.
#[derive(Debug)]
struct OpenRun {
    path: std::path::PathBuf,
    file: Option<std::fs::File>,
    /// The run has ended.
    ended: bool,
    /// Bytes written to it.
    len: u64,
    /// Their CRC-32C: a run from a snapshot goes on in a file only if it begins with them.
    crc: u32,
}

/// `path`, under `dir`, opened to go on after its first `len` bytes (cut back to them;
/// `true`) when they are the ones written (CRC-32C `crc`), else created afresh (`false`):
/// missing, shorter, or another run's.
fn go_on_in(
    dir: &std::path::Path,
    path: &std::path::Path,
    len: u64,
    crc: u32,
) -> Result<(std::fs::File, bool), String> {
    let opened = std::fs::create_dir_all(dir).and_then(|()| {
        if begins_with(path, len, crc) {
            let f = std::fs::OpenOptions::new().append(true).open(path)?;
            f.set_len(len)?;
            Ok((f, true))
        } else {
            std::fs::File::create(path).map(|f| (f, false))
        }
    });
    opened.map_err(|e| format!("opening {}: {e}", path.display()))
}

/// Whether the file at `path` begins with `len` bytes of CRC-32C `crc`.
fn begins_with(path: &std::path::Path, len: u64, crc: u32) -> bool {
    use std::io::Read as _;
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    let mut head = Vec::new();
    match f.take(len).read_to_end(&mut head) {
        Ok(n) => n as u64 == len && crc32c::crc32c(&head) == crc,
        Err(_) => false,
    }
}

impl DownlinkFiles {
    /// Files under `dir` (created with the first run).
    pub fn new(dir: &std::path::Path) -> Self {
        DownlinkFiles {
            dir: dir.to_owned(),
            runs: BTreeMap::new(),
            open: BTreeMap::new(),
            files: Vec::new(),
            errors: 0,
            first_error: None,
        }
    }

    fn failed(&mut self, what: String) {
        self.errors += 1;
        if self.first_error.is_none() {
            tracing::warn!("downlink files: {what}");
            self.first_error = Some(what);
        }
    }

    fn start(&mut self, session: u8) {
        let k = self.runs.entry(session).or_default();
        *k += 1;
        let path = self.dir.join(format!("session-{session}-run{k}.bin"));
        let file = std::fs::create_dir_all(&self.dir)
            .and_then(|()| std::fs::File::create(&path))
            .map_err(|e| format!("creating {}: {e}", path.display()));
        self.opened(session, path, file, (0, 0));
    }

    fn opened(
        &mut self,
        session: u8,
        path: std::path::PathBuf,
        file: Result<std::fs::File, String>,
        (len, crc): (u64, u32),
    ) {
        let file = match file {
            Ok(f) => Some(f),
            Err(e) => {
                self.failed(e);
                None
            }
        };
        self.files.push(path.clone());
        self.open.insert(
            session,
            OpenRun {
                path,
                file,
                ended: false,
                len,
                crc,
            },
        );
    }

    /// Its state for a snapshot: each session's count of runs, and its latest run's
    /// bytes written and whether it has ended.
    pub fn save(&self) -> Vec<u8> {
        let open: Vec<(u8, bool, u64, u32)> = self
            .open
            .iter()
            .map(|(s, r)| (*s, r.ended, r.len, r.crc))
            .collect();
        snap::to_bytes(&(self.runs.clone(), open))
    }

    /// Go on from a snapshot's state ([`DownlinkFiles::save`]): runs are numbered on from
    /// the snapshot's, and a run under way at its instant goes on in its file, cut back to
    /// the bytes it had then (the file then ends as the uninterrupted run's did); a file
    /// that is not there, or shorter, starts again and holds what comes after the instant.
    pub fn resume(&mut self, bytes: &[u8]) -> Result<(), snap::SnapError> {
        use snap::SnapNew as _;
        let mut r = snap::Reader::new(bytes);
        let (runs, open) = <(BTreeMap<u8, u32>, Vec<(u8, bool, u64, u32)>)>::read(&mut r)?;
        r.finish()?;
        self.runs = runs;
        for (session, ended, len, crc) in open {
            let k = self.runs.get(&session).copied().unwrap_or_default();
            let path = self.dir.join(format!("session-{session}-run{k}.bin"));
            if ended {
                // An ended run's last frames may still come down (the S-band's queue): they
                // go on in its file when it is the one written, never in a file made anew.
                let file = begins_with(&path, len, crc)
                    .then(|| std::fs::OpenOptions::new().append(true).open(&path).ok())
                    .flatten()
                    .filter(|f| f.set_len(len).is_ok());
                self.open.insert(
                    session,
                    OpenRun {
                        path,
                        file,
                        ended,
                        len,
                        crc,
                    },
                );
                continue;
            }
            let file = go_on_in(&self.dir, &path, len, crc);
            let written = if file.as_ref().is_ok_and(|(_, whole)| *whole) {
                (len, crc)
            } else {
                // Info, not a warning: a replay's fresh folder always starts so.
                tracing::info!(
                    "downlink files: {} holds only what is downlinked from the snapshot on",
                    path.display()
                );
                (0, 0)
            };
            self.opened(session, path, file.map(|(f, _)| f), written);
        }
        Ok(())
    }

    /// The directory, for messages.
    pub fn dir_display(&self) -> std::path::Display<'_> {
        self.dir.display()
    }

    /// Take in one event of the run: a session's start opens its file, a downlink appends.
    pub fn observe(&mut self, ev: &twin_core::events::RunEvent) {
        use nodes_pc::PcOutput as O;
        let twin_core::events::RunEvent::Pc(o) = ev else {
            return;
        };
        match &**o {
            O::SessionStarted { session_id, .. } => self.start(*session_id),
            // As the report: an end without an open run is a run of its own; a run lost
            // with the PC's memory ends there.
            O::SessionEnded { session_id, .. } | O::SessionLost { session_id, .. } => {
                if self.open.get(session_id).is_none_or(|r| r.ended) {
                    self.start(*session_id);
                }
                if let Some(run) = self.open.get_mut(session_id) {
                    run.ended = true;
                }
            }
            O::Downlinked {
                session_id, bytes, ..
            } => {
                let res = match self.open.get_mut(session_id) {
                    Some(OpenRun {
                        path,
                        file: Some(f),
                        len,
                        crc,
                        ..
                    }) => std::io::Write::write_all(f, bytes)
                        .map(|()| {
                            *len += bytes.len() as u64;
                            *crc = crc32c::crc32c_append(*crc, bytes);
                        })
                        .map_err(|e| format!("appending to {}: {e}", path.display())),
                    _ => Ok(()),
                };
                if let Err(e) = res {
                    self.failed(e);
                }
            }
            _ => {}
        }
    }
}

/// A payload reply's bytes before its data: the command and the result (`02 01 | data`).
const REPLY_HEAD_BYTES: usize = 2;

/// The drop reason of a payload's reply that reached the PC after the PC's own memory of
/// its request (its retired ephemeral ports) and was dropped by CSP as `unbound port`.
pub const LATE_AT_CSP: &str = "late, after the PC forgot the request (unbound port)";

// What a snapshot saves (docs/snapshots.md).
snap::fields!(SessionRun {
    session,
    payload,
    started,
    ended,
    bytes,
    len,
    stream
});
snap::fields!(SessionsReport {
    runs,
    downlinked,
    dropped,
    produced,
    syncs,
    held,
    pc_balanced,
    transit;
    skip forget_bytes
});
