//! The runtime's part of a snapshot (docs/snapshots.md): the media, every node's task, the
//! boards, the power rules, the outside links' gates, the fault timeline and the run's
//! packet tap. Saved where the run has settled at an instant asked for
//! (`RunOptions::snapshot_at`, [`bus::exec::settled`]: every task waits, every channel
//! between them is empty) and handed to the run's sink, which adds its own part; loaded
//! into a run built from the same scenario (`RunOptions::resume`) before any of its tasks
//! first runs, its clock already at the snapshot's instant.

use std::collections::BTreeSet;

use anyhow::Context as _;
use bus::driver::lock_core;
use bus::exec::Start;
use bus::gate::LinkGate;
use bus::outside::Segments;
use csp::SimTime;
use platform::board::Boards;
use snap::{Reader, Snap, SnapError, SnapNew as _, Writer};
use twin_core::packets::PacketTap;

use crate::build::{NodeTask, Nodes};
use crate::control::Timeline;
use crate::counters::Tapped;
use crate::faults::TimedFault;
use crate::power::PowerShell;

/// Where a run starts from a snapshot: the instant it was taken at and its sections, each
/// layer's part under its name ([`Sections`]; the runtime's is [`RUNTIME_SECTION`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Resume {
    /// The instant.
    pub t: SimTime,
    /// The parts.
    pub sections: Sections,
    /// Whose fault actions to come the run takes.
    pub faults: FaultsToCome,
}

/// The scenario's fault actions to come of a run from a snapshot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FaultsToCome {
    /// The snapshot's (its run is this run).
    #[default]
    Saved,
    /// This run's own, past as many as the snapshot's run had taken: a fork of a campaign,
    /// whose runs are the same up to the snapshot and differ only in faults after it.
    Own,
}

/// A snapshot's parts, in the order they were taken: each layer of the run (the runtime,
/// the report, the expectations, ...) saves its own under its name.
pub type Sections = Vec<(String, Vec<u8>)>;

/// The name of the runtime's part.
pub const RUNTIME_SECTION: &str = "runtime";

impl Resume {
    /// The part named `name`, or an error saying it is missing.
    pub fn section(&self, name: &str) -> anyhow::Result<&[u8]> {
        self.sections
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, b)| b.as_slice())
            .ok_or_else(|| anyhow::anyhow!("the snapshot has no `{name}` part"))
    }
}

/// The run's fault timeline (its scenario's actions, taken from `opts`), and a copy of
/// those actions when it starts from another run's snapshot (a fork,
/// [`FaultsToCome::Own`]: [`LoopState::resume`] puts them back after loading it).
pub(crate) fn timeline(opts: &mut crate::RunOptions) -> (Timeline, Option<Vec<TimedFault>>) {
    let own = opts
        .resume
        .as_ref()
        .is_some_and(|r| r.faults == FaultsToCome::Own)
        .then(|| opts.faults.clone());
    (Timeline::new(std::mem::take(&mut opts.faults)), own)
}

/// How a run's tasks begin: fresh, or resumed from `resume`.
pub(crate) fn start_of(resume: Option<&Resume>) -> Start {
    match resume {
        Some(_) => Start::Resumed,
        None => Start::Fresh,
    }
}

/// What a run's tasks share, saved and loaded first: the media and the boards, which tasks
/// may use as soon as they run.
fn save_shared(w: &mut Writer, segs: &Segments, boards: &Boards, nodes: &Nodes) {
    // The nodes first, each with whether its state follows: a run from it builds those an
    // outside program replaces in it, when this run built them ([`replaced_later`]).
    saved_nodes(nodes).save(w);
    segs.main.save(w);
    segs.payload.save(w);
    segs.ground.save(w);
    boards.save(w);
    for n in &nodes.tasks {
        lock_core(&n.core).save(w);
    }
}

/// Every node built, in build order, and whether its state is saved (not when an outside
/// program took its place).
fn saved_nodes(nodes: &Nodes) -> Vec<(u8, bool)> {
    nodes
        .built
        .iter()
        .map(|a| (*a, !nodes.handed_over.contains(a)))
        .collect()
}

/// Of the nodes an outside program replaces in a run from `resume`, those its snapshot's
/// run built (built again, their state loaded, then handed over:
/// `build::Nodes::hand_over_replaced`).
pub(crate) fn replaced_later(
    resume: Option<&Resume>,
    replaced: &BTreeSet<u8>,
) -> anyhow::Result<BTreeSet<u8>> {
    let Some(r) = resume else {
        return Ok(BTreeSet::new());
    };
    let saved = Vec::<(u8, bool)>::read(&mut Reader::new(r.section(RUNTIME_SECTION)?))
        .context(NOT_THIS_RUN)?;
    Ok(saved
        .into_iter()
        .map(|(a, _)| a)
        .filter(|a| replaced.contains(a))
        .collect())
}

/// Load what [`save_shared`] saved after its list of nodes (`saved`) into a run just built,
/// before its tasks first run.
fn load_shared(
    r: &mut Reader<'_>,
    segs: &Segments,
    boards: &Boards,
    nodes: &[NodeTask],
    saved: &[(u8, bool)],
) -> Result<(), SnapError> {
    segs.main.clone().load(r)?;
    segs.payload.clone().load(r)?;
    segs.ground.clone().load(r)?;
    boards.clone().load(r)?;
    for (node, (_, has_state)) in nodes.iter().zip(saved) {
        if *has_state {
            lock_core(&node.core).load(r)?;
        }
    }
    Ok(())
}

/// Load the shared part of `resume` (if the run is resumed) into a run just built, whose
/// outside programs replace the nodes `replaced`; where the loop's part begins.
pub(crate) fn resume_shared(
    resume: Option<&Resume>,
    segs: &Segments,
    boards: &Boards,
    nodes: &Nodes,
    replaced: &BTreeSet<u8>,
) -> anyhow::Result<usize> {
    let Some(r) = resume else { return Ok(0) };
    let mut rd = Reader::new(r.section(RUNTIME_SECTION)?);
    let saved = Vec::<(u8, bool)>::read(&mut rd).context(NOT_THIS_RUN)?;
    let addrs: Vec<u8> = saved.iter().map(|(a, _)| *a).collect();
    if addrs != nodes.built {
        anyhow::bail!(
            "{NOT_THIS_RUN}: its run had the nodes at {addrs:?}, this one has {:?} (a node an \
             outside program replaced when it was taken is replaced in a run from it too)",
            nodes.built
        );
    }
    if let Some((a, _)) = saved.iter().find(|(a, s)| !s && !replaced.contains(a)) {
        anyhow::bail!(
            "{NOT_THIS_RUN}: an outside program had node {a}'s place when it was taken, so \
             its state is not in it: replace it in this run too (--kiss-addr {a} after its \
             link)"
        );
    }
    load_shared(&mut rd, segs, boards, &nodes.tasks, &saved).context(NOT_THIS_RUN)?;
    Ok(rd.at())
}

const NOT_THIS_RUN: &str = "the snapshot does not fit this run";

/// The run's loop's own state, saved and loaded after [`save_shared`]'s: the power rules,
/// the gates (which the power rules switch as they are built), the fault timeline and the
/// packet tap.
pub(crate) struct LoopState<'a> {
    power: &'a mut PowerShell,
    gates: &'a [LinkGate],
    faults: &'a mut Timeline,
    tap: &'a mut Option<PacketTap>,
}

impl<'a> LoopState<'a> {
    pub(crate) fn of(
        power: &'a mut PowerShell,
        gates: &'a [LinkGate],
        faults: &'a mut Timeline,
        tapped: &'a mut Tapped<'_>,
    ) -> Self {
        LoopState {
            power,
            gates,
            faults,
            tap: tapped.tap_mut(),
        }
    }

    /// The runtime's part of a snapshot now (the run has settled).
    pub(crate) fn take(&self, segs: &Segments, boards: &Boards, nodes: &Nodes) -> Vec<u8> {
        let mut w = Writer::new();
        save_shared(&mut w, segs, boards, nodes);
        self.save(&mut w);
        w.into_bytes()
    }

    /// Load the loop's part of `r`, which begins at byte `at`; a fork's run then takes its
    /// `own` fault actions to come ([`timeline`]).
    pub(crate) fn resume(
        &mut self,
        r: &Resume,
        at: usize,
        own: Option<Vec<TimedFault>>,
    ) -> anyhow::Result<()> {
        let mut rd = Reader::new(r.section(RUNTIME_SECTION)?.get(at..).unwrap_or_default());
        self.load(&mut rd)
            .and_then(|()| rd.finish())
            .and_then(|()| own.map_or(Ok(()), |own| self.faults.take_own(own)))
            .context(NOT_THIS_RUN)
    }

    fn save(&self, w: &mut Writer) {
        self.power.save(w);
        self.gates.len().save(w);
        for g in self.gates {
            g.save(w);
        }
        self.faults.save(w);
        self.tap.is_some().save(w);
        if let Some(tap) = self.tap.as_ref() {
            tap.save(w);
        }
    }

    fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
        self.power.load(r)?;
        let n = usize::read(r)?;
        if n != self.gates.len() {
            return Err(SnapError::Mismatch {
                what: "outside links",
                saved: n as u64,
                built: self.gates.len() as u64,
            });
        }
        for g in self.gates {
            g.clone().load(r)?;
        }
        self.faults.load(r)?;
        let tapped = bool::read(r)?;
        match (tapped, self.tap.as_mut()) {
            (true, Some(tap)) => tap.load(r),
            // Taken by a run that reassembled its packets (it recorded them), loaded by one
            // that does not: read past them.
            (true, None) => PacketTap::new().load(r),
            // The other way: this run's tap starts empty at the instant (the packets then
            // on their way are not told as packets; the run's media are the same).
            (false, _) => Ok(()),
        }
    }
}
