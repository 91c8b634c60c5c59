//! What a run did: the report (counters of every node and medium, the ground stations'
//! outcomes, the samples the expectations judge) and the [`Observer`] that gathers it from
//! the run's events as they happen ([`observe`]), above the runtime (which only counts).

pub mod observe;

use std::fmt::Write as _;

use anyhow::Context as _;
use std::time::Duration;

use bus::can::BusStats;
use bus::net::NetStats;
use bus::outside::BridgeStats;
use bus::trace::TraceEvent;
use csp::SimTime;
use links::kiss_tcp::KissLinkStats;

use crate::observe::attitude::AttitudeSample;
use crate::observe::commands::{RequestResult, RequestSummary};
use crate::observe::power::PowerSample;
use crate::observe::{Keep, Observed, Observer};
use twin_core::events::RunEvent;
pub use twin_runtime::counters::{Interruption, NodeReport, RunCounters, StopCause};
use twin_runtime::{RunOptions, RunSink};

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct RunReport {
    /// Simulated time reached.
    pub sim_time: SimTime,
    /// Why the run stopped before its end, if it did: a signal (SIGINT, SIGTERM) or its
    /// wall-clock limit. Its verdicts then judge only what ran.
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
    /// What the run's control channel counted (`run --control`), when it had one.
    pub control: Option<twin_runtime::control::ControlStats>,
    /// The boards' writes and refused writes (a write behind a reader's horizon), by board.
    pub boards: [(&'static str, platform::board::BoardStats); 3],
    /// What the gates of the scenario's outside links held back (their faults and power),
    /// by link name.
    pub links: Vec<(String, bus::gate::GateStats)>,
    /// SocketCAN bridge counters, by interface and bus (`vcan0 (main bus)`).
    pub socketcan: Vec<(String, BridgeStats)>,
    /// CFP frames or partial packets the run's packet tap could not place (lost frames),
    /// when packets were tapped (`RunOptions::packet_events`).
    pub cfp_drops: u64,
    /// Outcomes of the ground stations' requests (empty unless the run kept them:
    /// `RunOptions::keep_series`).
    pub results: Vec<RequestResult>,
    /// What the ground stations' requests came to, counted.
    pub requests: RequestSummary,
    /// Every frame and packet, when tracing was asked for.
    pub trace: Vec<TraceEvent>,
    /// The FC's published attitude samples, in time order (empty unless the run kept
    /// them: `RunOptions::keep_series`).
    pub attitude: Vec<AttitudeSample>,
    /// What every published attitude sample added up to.
    pub attitude_summary: crate::observe::attitude::AttitudeSummary,
    /// The PC's sessions, downlinked and dropped bytes, and what the payloads produced.
    pub sessions: crate::observe::sessions::SessionsReport,
    /// The EPS's samples, in time order (empty unless the run kept them).
    pub power: Vec<PowerSample>,
    /// What every EPS sample added up to.
    pub power_summary: crate::observe::power::PowerSummary,
    /// Beacons received on the ground: (time, sending COMM, sequence number).
    pub beacons: Vec<(SimTime, u8, u32)>,
    /// UHF contact switches applied (pass modelling): (time, in contact).
    pub contact: Vec<(SimTime, bool)>,
}

impl RunReport {
    /// The report of a run: what the runtime counted and what the observers gathered.
    pub fn of(c: RunCounters, o: Observed) -> Self {
        RunReport {
            sim_time: c.sim_time,
            interrupted: c.interrupted,
            wall: c.wall,
            nodes: c.nodes,
            buses: c.buses,
            ground: c.ground,
            kiss: c.kiss,
            control: c.control,
            boards: c.boards,
            links: c.links,
            socketcan: c.socketcan,
            cfp_drops: c.cfp_drops,
            results: o.results,
            requests: o.requests,
            trace: o.trace,
            attitude: o.attitude,
            attitude_summary: o.attitude_summary,
            sessions: o.sessions,
            power: o.power,
            power_summary: o.power_summary,
            beacons: o.beacons,
            contact: o.contact,
        }
    }
}

/// Run the twin ([`crate::run_with`]) and report it. `ready` receives the bound
/// addresses of the KISS servers, then those of the TCP consoles, once they listen.
pub async fn run(
    opts: RunOptions,
    ready: Option<tokio::sync::oneshot::Sender<Vec<std::net::SocketAddr>>>,
) -> anyhow::Result<RunReport> {
    run_with(opts, ready, &mut |_: &RunEvent| {}).await
}

/// The name of the report's part of a snapshot (its observers).
pub const REPORT_SECTION: &str = "report";

/// [`run`], handing every [`RunEvent`] to `sink` in the order they happen (the recorder),
/// then to the report's observers.
pub async fn run_with(
    opts: RunOptions,
    ready: Option<tokio::sync::oneshot::Sender<Vec<std::net::SocketAddr>>>,
    sink: &mut dyn RunSink,
) -> anyhow::Result<RunReport> {
    /// The sink first, then the observers.
    struct Both<'a> {
        sink: &'a mut dyn RunSink,
        observer: Observer,
    }
    impl RunSink for Both<'_> {
        fn event(&mut self, ev: &RunEvent) {
            self.sink.event(ev);
            self.observer.observe(ev);
        }
        fn contact(&mut self, t: SimTime, on: bool) {
            self.sink.contact(t, on);
            self.observer.contact(t, on);
        }
        fn snapshot(
            &mut self,
            t: SimTime,
            by: twin_runtime::AskedBy,
            sections: &mut twin_runtime::Sections,
        ) {
            sections.push((REPORT_SECTION.to_owned(), snap::to_bytes(&self.observer)));
            self.sink.snapshot(t, by, sections);
        }
    }
    let mut observer = Observer::new(
        Keep {
            trace: opts.trace,
            series: opts.keep_series,
        },
        opts.tle.as_ref(),
    );
    if let Some(r) = &opts.resume {
        snap::load_from(&mut observer, r.section(REPORT_SECTION)?)
            .context("the snapshot's report does not fit this run")?;
    }
    let mut both = Both { sink, observer };
    let counters = twin_runtime::run_with(opts, ready, &mut both).await?;
    Ok(RunReport::of(counters, both.observer.finish()))
}

impl RunReport {
    /// The end-of-run table: per node packets in/out, forwarded, drops; per bus load.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let elapsed = self.sim_time - SimTime::ZERO;
        self.table_time(&mut s);
        self.table_nodes(&mut s);
        self.table_media(&mut s, elapsed);
        self.table_can_errors(&mut s);
        self.table_kiss(&mut s);
        self.table_queues(&mut s);
        self.table_socketcan(&mut s);
        self.table_boards(&mut s);
        self.table_links(&mut s);
        self.table_requests(&mut s);
        self.table_sessions(&mut s);
        s
    }

    /// The table's head: whether the run was cut short, and how fast it ran.
    fn table_time(&self, s: &mut String) {
        if let Some(i) = &self.interrupted {
            let _ = writeln!(
                s,
                "{i}: not a whole run (any verdicts below judge only what ran)\n"
            );
        }
        let _ = writeln!(
            s,
            "simulated {:.3} s in {:.3} s wall ({:.0}x real time)",
            self.sim_time.as_secs_f64(),
            self.wall.as_secs_f64(),
            self.sim_time.as_secs_f64() / self.wall.as_secs_f64().max(1e-9)
        );
    }

    /// The per-node section: packets in, out, forwarded, to the app, and drops by reason.
    fn table_nodes(&self, s: &mut String) {
        let _ = writeln!(
            s,
            "\n{:<7} {:>3} {:>9} {:>9} {:>9} {:>9} {:>7}  drops by reason",
            "node", "id", "pkts in", "pkts out", "forwarded", "to app", "drops"
        );
        for n in &self.nodes {
            let c = &n.counters;
            let reasons: Vec<String> = c.drops.iter().map(|(k, v)| format!("{k}: {v}")).collect();
            let _ = writeln!(
                s,
                "{:<7} {:>3} {:>9} {:>9} {:>9} {:>9} {:>7}  {}",
                n.name,
                n.addr,
                c.rx_packets,
                c.tx_packets,
                c.forwarded,
                c.delivered + c.service_replies,
                c.total_drops(),
                reasons.join(", ")
            );
        }
    }

    /// The per-medium section: each bus's load over `elapsed`, then the ground network's.
    fn table_media(&self, s: &mut String, elapsed: Duration) {
        let _ = writeln!(
            s,
            "\n{:<8} {:>10} {:>11} {:>9} {:>8} {:>8}",
            "bus", "frames", "data bytes", "load %", "dropped", "corrupt"
        );
        for b in &self.buses {
            let _ = writeln!(
                s,
                "{:<8} {:>10} {:>11} {:>9.3} {:>8} {:>8}",
                b.name,
                b.frames,
                b.bytes,
                100.0 * b.load(elapsed),
                b.dropped,
                b.corrupted
            );
        }
        let g = &self.ground;
        let _ = writeln!(
            s,
            "{:<8} {:>10} {:>11} {:>9.3} {:>8} {:>8}  (packets; UHF air load)",
            g.name,
            g.packets,
            g.bytes,
            100.0 * g.air_busy.as_secs_f64() / elapsed.as_secs_f64().max(1e-9),
            g.dropped,
            "-"
        );
    }

    /// One line per bus that saw error frames, naming the ports in trouble.
    fn table_can_errors(&self, s: &mut String) {
        for b in self.buses.iter().filter(|b| b.error_frames > 0) {
            let troubled: Vec<String> = b
                .ports
                .iter()
                .filter(|p| p.tx_errors > 0 || p.bus_off_count > 0 || p.passive_count > 0)
                .map(|p| {
                    format!(
                        "{} {} errors, TEC up to {}{}{} (now {})",
                        p.name,
                        p.tx_errors,
                        p.tec_max,
                        if p.passive_count > 0 {
                            format!(", error-passive {}x", p.passive_count)
                        } else {
                            String::new()
                        },
                        if p.bus_off_count > 0 {
                            format!(
                                ", bus-off {}x ({} frames lost, {} recoveries)",
                                p.bus_off_count, p.bus_off_drops, p.recoveries
                            )
                        } else {
                            String::new()
                        },
                        p.state.name()
                    )
                })
                .collect();
            let _ = writeln!(
                s,
                "{:<8} CAN errors: {} error frames; {}",
                b.name,
                b.error_frames,
                troubled.join("; ")
            );
        }
    }

    /// One paragraph per KISS link: its connections and what it let in and out; the
    /// control channel's.
    fn table_kiss(&self, s: &mut String) {
        if let Some(c) = &self.control {
            let _ = writeln!(
                s,
                "\ncontrol channel: {} connections ({} refused: {} open), {} requests, {} lines over {} bytes refused, {} HTTP requests closed",
                c.connections,
                c.refused_connections,
                twin_runtime::control::MAX_CONNECTIONS,
                c.requests,
                c.long_lines,
                twin_runtime::control::MAX_LINE,
                c.http_closed,
            );
        }
        for (name, k) in &self.kiss {
            let _ = writeln!(
                s,
                "\nlink {name}: {} connections ({} closed idle, {} closed to make room, {} refused), {} packets in, {} out, {} garbage bytes, {} bad CRC, {} short, {} oversize, {} refused ({} claims, {} queue full), {} out dropped (not read)",
                k.connections,
                k.idle_closed,
                k.evicted,
                k.connections_refused,
                k.packets_in,
                k.packets_out,
                k.garbage_bytes,
                k.bad_crc,
                k.short,
                k.oversize,
                k.refused,
                k.claims_refused,
                k.queue_full,
                k.out_dropped
            );
        }
    }

    /// What ports' transmit budgets held back, then what full queues lost, if anything.
    fn table_queues(&self, s: &mut String) {
        let mut lost = Vec::new();
        for b in &self.buses {
            for p in &b.ports {
                if p.tx_overflow + p.rx_overflow > 0 {
                    lost.push(format!(
                        "{} {}: {} frames (transmit queue full), {} (inbox full)",
                        b.name, p.name, p.tx_overflow, p.rx_overflow
                    ));
                }
                if p.budget_held > 0 {
                    let _ = writeln!(
                        s,
                        "\n{} bus, {}: {} frames held back by its transmit budget",
                        b.name, p.name, p.budget_held
                    );
                }
            }
        }
        if self.ground.air_overflow + self.ground.rx_overflow > 0 {
            lost.push(format!(
                "ground: {} packets (transmit buffer full), {} (inbox full)",
                self.ground.air_overflow, self.ground.rx_overflow
            ));
        }
        if !lost.is_empty() {
            let _ = writeln!(s, "\nlost to full queues: {}", lost.join("; "));
        }
    }

    /// One paragraph per SocketCAN bridge: frames across it, errors, why it stopped.
    fn table_socketcan(&self, s: &mut String) {
        for (name, b) in &self.socketcan {
            let _ = writeln!(
                s,
                "\nSocketCAN {name}: {} frames in, {} out, {} skipped, {} receive errors, {} send errors{}",
                b.frames_in,
                b.frames_out,
                b.skipped,
                b.recv_errors,
                b.send_errors,
                b.ended
                    .as_ref()
                    .map(|why| format!("; stopped: {why}"))
                    .unwrap_or_default()
            );
        }
    }

    /// The boards' writes refused behind a reader's horizon, when there were any.
    fn table_boards(&self, s: &mut String) {
        let refused: Vec<String> = self
            .boards
            .iter()
            .filter(|(_, b)| b.refused > 0)
            .map(|(name, b)| format!("{name} {} of {} writes", b.refused, b.writes))
            .collect();
        if !refused.is_empty() {
            let _ = writeln!(
                s,
                "\nboards: refused behind a reader's horizon (applied there): {}",
                refused.join(", ")
            );
        }
    }

    /// One paragraph per gated link that lost or delayed anything.
    fn table_links(&self, s: &mut String) {
        for (name, g) in self
            .links
            .iter()
            .filter(|(_, g)| *g != bus::gate::GateStats::default())
        {
            let _ = writeln!(
                s,
                "\nlink {name}: {} lost at the link ({} dropped, {} while down, {} while hung, {} while unpowered, {} over the delay line), {} delayed",
                g.lost(),
                g.dropped,
                g.down,
                g.hung,
                g.unpowered,
                g.overflow,
                g.delayed
            );
        }
    }

    /// Every payload session run: when, how it ended, what reached the ground (the ground
    /// sink writes each run's bytes to `session-S-runN.bin`, N counting the session's runs
    /// that started; one that ended without starting has no number and no file).
    fn table_sessions(&self, s: &mut String) {
        let runs = &self.sessions.runs;
        if runs.is_empty() {
            return;
        }
        let _ = writeln!(
            s,
            "\npayload sessions:\n  {:>7} {:>7} {:>3} {:>10} {:>10}  {:<14} {:>8} {:>12}",
            "session", "payload", "run", "start s", "end s", "result", "packets", "downlinked"
        );
        let mut nth: std::collections::BTreeMap<u8, u32> = std::collections::BTreeMap::new();
        for r in runs {
            let n = match r.started {
                Some(_) => {
                    let n = nth.entry(r.session).or_default();
                    *n += 1;
                    n.to_string()
                }
                None => "-".to_owned(),
            };
            let payload = r.payload.map_or("-".to_owned(), |p| p.to_string());
            let start = r
                .started
                .map_or("-".to_owned(), |t| format!("{:.3}", t.as_secs_f64()));
            let (end, result, packets) = match &r.ended {
                Some((t, how, packets)) => (
                    format!("{:.3}", t.as_secs_f64()),
                    how.to_string(),
                    packets.to_string(),
                ),
                None => ("-".to_owned(), "still active".to_owned(), "-".to_owned()),
            };
            let _ = writeln!(
                s,
                "  {:>7} {payload:>7} {n:>3} {start:>10} {end:>10}  {result:<14} {packets:>8} {:>10} B",
                r.session, r.len
            );
        }
    }

    /// The ground's requests and how many were answered, when it sent any.
    fn table_requests(&self, s: &mut String) {
        let r = self.requests;
        if r.requests > 0 {
            let _ = writeln!(
                s,
                "\nground requests: {} sent, {} answered, {} unanswered{}",
                r.requests,
                r.answered,
                r.requests - r.answered - r.unfinished,
                if r.unfinished > 0 {
                    format!(", {} still waiting at the end", r.unfinished)
                } else {
                    String::new()
                }
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each session run is a row; a run that ended without starting (an ABORT of a
    /// PENDING session) has no run number, so the numbers stay those of the ground sink's
    /// files (`session-S-runN.bin`, counted as runs start).
    #[test]
    fn the_sessions_table_numbers_only_the_runs_that_started() {
        use crate::observe::sessions::SessionRun;
        use twin_scenario::pc::RunEnd;
        let run = |started: Option<u64>, result| SessionRun {
            session: 1,
            payload: started.map(|_| 12),
            started: started.map(SimTime::from_secs),
            ended: Some((SimTime::from_secs(100), RunEnd::Result(result), 3)),
            bytes: Vec::new(),
            len: 30,
            stream: Default::default(),
        };
        let mut r = RunReport::default();
        r.sessions.runs = vec![
            run(None, nodes_pc::SessionResult::Aborted),
            run(Some(10), nodes_pc::SessionResult::Done),
        ];
        let table = r.table();
        let rows: Vec<Vec<&str>> = table
            .lines()
            .skip_while(|l| *l != "payload sessions:")
            .skip(2)
            .take_while(|l| !l.is_empty())
            .map(|l| l.split_whitespace().collect())
            .collect();
        assert_eq!(rows.len(), 2, "{table}");
        assert_eq!(rows[0][..3], ["1", "-", "-"], "{table}");
        assert_eq!(rows[1][..3], ["1", "12", "1"], "{table}");
    }

    #[test]
    fn the_table_says_what_the_boards_refused_and_the_links_held_back() {
        let mut r = RunReport::default();
        assert!(!r.table().contains("boards:"), "nothing refused, no line");
        r.boards[2] = (
            "activity",
            platform::board::BoardStats {
                writes: 8024,
                refused: 2,
            },
        );
        r.links = vec![(
            "payload-sw".to_owned(),
            bus::gate::GateStats {
                dropped: 2,
                unpowered: 3,
                delayed: 1,
                ..Default::default()
            },
        )];
        let t = r.table();
        assert!(
            t.contains("boards: refused behind a reader's horizon (applied there): activity 2 of 8024 writes"),
            "{t}"
        );
        assert!(
            t.contains("link payload-sw: 5 lost at the link (2 dropped, 0 while down, 0 while hung, 3 while unpowered, 0 over the delay line), 1 delayed"),
            "{t}"
        );
    }
}
