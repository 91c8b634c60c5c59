//! What the runtime itself counts in a run ([`RunCounters`]: every node's and medium's
//! counters, why it stopped early), and the hook that hands every event of the run to
//! whoever observes it ([`RunSink`]).

use std::time::Duration;

use bus::can::BusStats;
use bus::net::NetStats;
use bus::outside::BridgeStats;
use csp::SimTime;
use csp::node::NodeCounters;
use links::kiss_tcp::KissLinkStats;

use twin_core::events::RunEvent;

/// Who asked for a snapshot ([`RunSink::snapshot`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AskedBy {
    /// The run's options, before it began (`RunOptions::snapshot_at`: `run --snapshot-at`,
    /// a recording's carried snapshots, a campaign's fork).
    Schedule,
    /// The run's control channel, at the instant its request came (`gs snapshot`).
    Control,
}

/// Whoever observes a run (the recorder, the report's observers, the invariants): handed
/// every event in the order it happens, on the run's loop.
pub trait RunSink: Send {
    /// One event of the run.
    fn event(&mut self, ev: &RunEvent);
    /// The UHF link's contact with the ground switched at `t` (a pass began or ended),
    /// told before the fault's event.
    fn contact(&mut self, t: SimTime, on: bool) {
        let _ = (t, on);
    }
    /// The run settled at `t`, an instant a snapshot was asked for `by` the run's options
    /// or its control channel: `sections` holds the runtime's part (media, nodes, the
    /// loop's own: [`crate::snapshot`]) and those of the sinks this one is inside; a sink
    /// that keeps state adds its part and hands them on to the sink inside it, and the one
    /// that wants the snapshot keeps them. Told between two events, every event before it
    /// handed on.
    fn snapshot(&mut self, t: SimTime, by: AskedBy, sections: &mut crate::Sections) {
        let _ = (t, by, sections);
    }
}

impl<F: FnMut(&RunEvent) + Send> RunSink for F {
    fn event(&mut self, ev: &RunEvent) {
        self(ev);
    }
}

/// A sink that also gets the [`RunEvent::Packet`] each medium event completes, right after
/// it, when packets are tapped (`RunOptions::packet_events`): the run's one reassembly.
pub(crate) struct Tapped<'a> {
    sink: &'a mut dyn RunSink,
    tap: Option<twin_core::packets::PacketTap>,
}

impl<'a> Tapped<'a> {
    pub(crate) fn new(sink: &'a mut dyn RunSink, packets: bool) -> Self {
        Tapped {
            sink,
            tap: packets.then(twin_core::packets::PacketTap::new),
        }
    }

    /// The packet tap's state, for a snapshot.
    pub(crate) fn tap_mut(&mut self) -> &mut Option<twin_core::packets::PacketTap> {
        &mut self.tap
    }

    /// CFP frames or partial packets the tap could not place (lost frames).
    pub(crate) fn cfp_drops(&self) -> u64 {
        self.tap.as_ref().map_or(0, |t| t.cfp_drops())
    }
}

impl RunSink for Tapped<'_> {
    fn snapshot(&mut self, t: SimTime, by: AskedBy, sections: &mut crate::Sections) {
        self.sink.snapshot(t, by, sections);
    }
    fn event(&mut self, ev: &RunEvent) {
        self.sink.event(ev);
        if let Some(p) = self.tap.as_mut().and_then(|tap| tap.event(ev)) {
            self.sink.event(&p);
        }
    }
    fn contact(&mut self, t: SimTime, on: bool) {
        self.sink.contact(t, on);
    }
}

/// Counters of one node at the end of a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeReport {
    /// Node name.
    pub name: String,
    /// CSP address.
    pub addr: u8,
    /// Its counters.
    pub counters: NodeCounters,
}

/// What the runtime counted in a run.
#[derive(Debug, Clone, Default)]
pub struct RunCounters {
    /// Simulated time reached.
    pub sim_time: SimTime,
    /// Why the run stopped before its end, if it did.
    pub interrupted: Option<Interruption>,
    /// Wall-clock time taken.
    pub wall: Duration,
    /// Per-node counters, in start order.
    pub nodes: Vec<NodeReport>,
    /// Main and payload CAN bus counters.
    pub buses: Vec<BusStats>,
    /// Ground segment counters.
    pub ground: NetStats,
    /// KISS/TCP link counters, by link.
    pub kiss: Vec<(String, KissLinkStats)>,
    /// The boards' writes and refused writes, by board.
    pub boards: [(&'static str, platform::board::BoardStats); 3],
    /// What the gates of the scenario's outside links held back, by link name.
    pub links: Vec<(String, bus::gate::GateStats)>,
    /// SocketCAN bridge counters, by interface and bus.
    pub socketcan: Vec<(String, BridgeStats)>,
    /// CFP frames or partial packets the run's packet tap could not place (lost frames),
    /// when packets were tapped.
    pub cfp_drops: u64,
    /// What the control channel counted, when the run had one.
    pub control: Option<crate::control::ControlStats>,
}

/// Why a run stopped before its end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopCause {
    /// SIGINT (Ctrl-C).
    Interrupt,
    /// SIGTERM (what Slurm, Kubernetes, systemd and docker send).
    Terminate,
    /// Its wall-clock limit (a campaign's `[limits] wall`).
    WallLimit(Duration),
}

/// A run cut short: why, at which simulated instant, of which duration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interruption {
    /// Why.
    pub cause: StopCause,
    /// The simulated instant it stopped at.
    pub at: SimTime,
    /// The duration it was to run, if bounded.
    pub of: Option<Duration>,
}

impl std::fmt::Display for Interruption {
    /// `interrupted at 3.000000000s of 3h (SIGTERM)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted at {}", self.at)?;
        if let Some(d) = self.of {
            write!(f, " of {}", twin_core::duration::format_duration(d))?;
        }
        match self.cause {
            StopCause::Interrupt => f.write_str(" (SIGINT)"),
            StopCause::Terminate => f.write_str(" (SIGTERM)"),
            StopCause::WallLimit(d) => write!(
                f,
                " (its wall-clock limit, {})",
                twin_core::duration::format_duration(d)
            ),
        }
    }
}
