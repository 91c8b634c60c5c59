//! A ground station inside the twin: it sends planned requests (pings, uptime, ICD
//! commands) at given times and reports every outcome as a run event. Scenario command timelines drive it.

use std::collections::BTreeMap;
use std::time::Duration;

use csp::client::Client;
use csp::node::{App, Node, Outbox};
use csp::{Header, Packet, SimTime};

/// A request the station sends at a given time.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedRequest {
    /// When to send it.
    pub at: SimTime,
    /// Destination node.
    pub dst: u8,
    /// Destination port.
    pub dport: u8,
    /// Request data.
    pub data: Vec<u8>,
    /// How long to wait for the reply.
    pub timeout: Duration,
    /// A label for reports.
    pub label: String,
    /// Send only after the first outcome (reply, timeout or send failure) of the request
    /// labelled so; `at` then counts from that outcome.
    pub after: Option<String>,
}

/// A request sent `count` times, `every` apart, the first at `first.at` (a scenario command
/// with `every` and `count`). A station keeps it as it is and makes each occurrence when it
/// is due, so that a plan of a million requests costs the memory of one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Recurring {
    /// The first occurrence; occurrence `k` is this one at `first.at + every * k`.
    pub first: PlannedRequest,
    /// Time between occurrences.
    pub every: Duration,
    /// Occurrences (0: none).
    pub count: u32,
}

impl From<PlannedRequest> for Recurring {
    fn from(first: PlannedRequest) -> Self {
        Recurring {
            first,
            every: Duration::ZERO,
            count: 1,
        }
    }
}

/// A station's requests yet to be sent, in the order it sends them: by time; at the same
/// time, those planned from the start before those released by an outcome (`after`), then
/// those released earlier before those released later, then in the order of the plan,
/// then by occurrence. (That is the order of the whole plan expanded into single requests,
/// sorted by time, and of each release appended to it and sorted again, sorts that keep
/// the order of equal times; `the_plan_sends_in_the_order_of_the_expanded_plan` checks it.)
#[derive(Debug, Default)]
pub struct Plan {
    entries: Vec<Recurring>,
    /// For each entry, the time its `first.at` counts from: zero, or the outcome that
    /// released it.
    base: Vec<SimTime>,
    /// The next occurrence of each entry under way: (when, release generation (0: planned
    /// from the start), entry, occurrence).
    due: std::collections::BTreeSet<(SimTime, u64, usize, u32)>,
    /// Entries waiting for another request's outcome, in plan order.
    deferred: Vec<usize>,
    releases: u64,
}

impl Plan {
    /// The plan of `entries`, in the order given (a request with `after` waits).
    pub fn new(entries: Vec<Recurring>) -> Plan {
        let mut plan = Plan {
            base: vec![SimTime::ZERO; entries.len()],
            ..Plan::default()
        };
        for (i, e) in entries.iter().enumerate() {
            if e.first.after.is_some() {
                plan.deferred.push(i);
            } else if e.count > 0 {
                plan.due.insert((e.first.at, 0, i, 0));
            }
        }
        plan.entries = entries;
        plan
    }

    /// When the next request is due.
    pub fn next_at(&self) -> Option<SimTime> {
        self.due.first().map(|d| d.0)
    }

    /// The next request due at or before `now`, if any.
    pub fn pop_due(&mut self, now: SimTime) -> Option<PlannedRequest> {
        let &(at, generation, i, k) = self.due.first().filter(|d| d.0 <= now)?;
        self.due.pop_first();
        let e = self.entries.get(i)?;
        if k + 1 < e.count {
            let next = self.base[i] + (e.first.at - SimTime::ZERO) + e.every * (k + 1);
            self.due.insert((next, generation, i, k + 1));
        }
        Some(PlannedRequest {
            at,
            after: None,
            ..e.first.clone()
        })
    }

    /// The request labelled `label` had its outcome at `decided`: the requests waiting for
    /// it (its first outcome only) are planned from then on.
    pub fn release(&mut self, label: &str, decided: SimTime) {
        let entries = &self.entries;
        let waits = |i: &usize| {
            entries
                .get(*i)
                .is_some_and(|e| e.first.after.as_deref() == Some(label))
        };
        if !self.deferred.iter().any(waits) {
            return;
        }
        self.releases += 1;
        let (release, keep): (Vec<usize>, Vec<usize>) = std::mem::take(&mut self.deferred)
            .into_iter()
            .partition(waits);
        self.deferred = keep;
        for i in release {
            let Some(e) = self.entries.get(i) else {
                continue;
            };
            if e.count > 0 {
                self.base[i] = decided;
                self.due
                    .insert((decided + (e.first.at - SimTime::ZERO), self.releases, i, 0));
            }
        }
    }
}

/// What became of a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// A reply arrived.
    Reply {
        /// Reply data.
        data: Vec<u8>,
        /// Round-trip time.
        rtt: Duration,
    },
    /// No reply within the timeout.
    Timeout,
    /// The request could not be sent.
    SendFailed(String),
    /// Sent, but the run ended before its reply arrived or its timeout ran out.
    Unfinished,
}

impl Outcome {
    /// The outcome a [`RunEvent::CommandResult`] carries (`reply`, `rtt_ns`, `failed`).
    ///
    /// [`RunEvent::CommandResult`]: twin_core::events::RunEvent::CommandResult
    pub fn of_result(reply: Option<&[u8]>, rtt_ns: Option<u64>, failed: Option<&str>) -> Self {
        match (reply, rtt_ns, failed) {
            (_, _, Some(e)) => Outcome::SendFailed(e.to_owned()),
            (Some(data), Some(rtt), None) => Outcome::Reply {
                data: data.to_vec(),
                rtt: Duration::from_nanos(rtt),
            },
            _ => Outcome::Timeout,
        }
    }
}

/// The ground station application.
#[derive(Debug)]
pub struct GroundApp {
    plan: Plan,
    client: Client,
    in_flight: BTreeMap<u64, (PlannedRequest, SimTime)>,
    next_tag: u64,
    events: Outbox<twin_core::events::RunEvent>,
}

impl GroundApp {
    /// A station that will send the occurrences of `plan`, each at its time, each
    /// outcome a [`twin_core::events::RunEvent::CommandResult`] (a request still waiting
    /// when the run ends has none: it was sent and not decided).
    pub fn new(plan: Vec<Recurring>) -> Self {
        GroundApp {
            plan: Plan::new(plan),
            client: Client::new(),
            in_flight: BTreeMap::new(),
            next_tag: 0,
            events: Outbox::default(),
        }
    }

    fn emit(&mut self, ev: twin_core::events::RunEvent) {
        self.events.push(ev);
    }

    fn record(&mut self, request: PlannedRequest, sent: SimTime, outcome: Outcome) {
        let (reply, rtt_ns, failed) = match outcome {
            Outcome::Reply { data, rtt } => (Some(data), Some(rtt.as_nanos() as u64), None),
            Outcome::SendFailed(e) => (None, None, Some(e)),
            Outcome::Timeout | Outcome::Unfinished => (None, None, None),
        };
        let decided = sent + rtt_ns.map_or(request.timeout, std::time::Duration::from_nanos);
        // Release the requests that wait for this one (its first outcome only).
        self.plan.release(&request.label, decided);
        self.emit(twin_core::events::RunEvent::CommandResult(Box::new(
            twin_core::events::CommandResult {
                t: decided,
                name: request.label,
                dst: request.dst,
                dport: request.dport,
                data: request.data,
                timeout: request.timeout,
                reply,
                rtt_ns,
                sent,
                failed,
            },
        )));
    }
}

/// Requests a station sends in one [`App::handle_timeout`] at most; the rest are due at once
/// again.
pub const SENDS_PER_CALL: usize = 1024;

/// The port where a ground station receives the COMM's beacons.
pub const BEACON_PORT: u8 = 10;

/// Every command sent, every decided outcome and every beacon received, as run events.
impl App for GroundApp {
    type Event = twin_core::events::RunEvent;
    fn poll_event(&mut self) -> Option<Self::Event> {
        self.events.pop()
    }
    fn start(&mut self, node: &mut Node, _now: SimTime) {
        node.bind(BEACON_PORT);
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        if packet.header.dport == BEACON_PORT {
            // A beacon (nodes_comm): `04 01 | Beacon`; the ground does not reply.
            self.emit(twin_core::events::RunEvent::Beacon {
                t: now,
                from: packet.header.src,
                data: packet.data,
            });
            return;
        }
        if let Some(done) = self.client.handle_reply(node, &packet, now)
            && let Some((req, sent)) = self.in_flight.remove(&done.request.tag)
        {
            self.record(
                req,
                sent,
                Outcome::Reply {
                    data: done.reply.data,
                    rtt: done.rtt,
                },
            );
        }
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        let next = self.plan.next_at();
        match (next, self.client.poll_timeout()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        for expired in self.client.handle_timeout(node, now) {
            if let Some((req, sent)) = self.in_flight.remove(&expired.tag) {
                self.record(req, sent, Outcome::Timeout);
            }
        }
        // At most a batch per call: a station that was hung or whose clock jumped sends
        // what it missed in batches, and the node's driver hands out the batch's events
        // (each send's `Command` or `CommandResult`) before it calls again at the same
        // instant: the node's outbox holds 2^20 events, and a backlog of several
        // million-count commands would hold more.
        for _ in 0..SENDS_PER_CALL {
            let Some(req) = self.plan.pop_due(now) else {
                break;
            };
            let tag = self.next_tag;
            self.next_tag += 1;
            let header = Header::new(node.addr(), req.dst, req.dport, 0);
            match self.client.request(
                node,
                tag,
                header,
                req.dst,
                req.dport,
                req.data.clone(),
                req.timeout,
                now,
            ) {
                Ok(_) => {
                    self.emit(twin_core::events::RunEvent::Command {
                        t: now,
                        name: req.label.clone(),
                        dst: req.dst,
                        dport: req.dport,
                        data: req.data.clone(),
                        timeout: req.timeout,
                    });
                    self.in_flight.insert(tag, (req, now));
                }
                Err(e) => self.record(req, now, Outcome::SendFailed(e.to_string())),
            }
        }
    }

    fn reset(&mut self, now: SimTime) {
        self.client.clear();
        for (_, (req, sent)) in std::mem::take(&mut self.in_flight) {
            self.record(req, sent.min(now), Outcome::Timeout);
        }
    }
}

/// A ping request as `csp_ping` builds it: `size` bytes `0, 1, 2, ...` (i % 256).
pub fn ping_payload(size: usize) -> Vec<u8> {
    (0..size).map(|i| (i % 256) as u8).collect()
}

// What a snapshot keeps of a ground station (docs/snapshots.md): where its plan is (the
// entries are the scenario's), the requests in flight and their tags, the client's pending
// requests.
snap::fields!(PlannedRequest {
    at,
    dst,
    dport,
    data,
    timeout,
    label,
    after
});
snap::fields!(Plan {
    base,
    due,
    deferred,
    releases;
    skip entries
});
snap::fields!(GroundApp {
    plan,
    client,
    in_flight,
    next_tag,
    events;
    in_place
});

snap::tagged_enum!(Outcome {
    Reply { data, rtt },
    Timeout,
    SendFailed(why),
    Unfinished
});

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use super::*;
    use proptest::prelude::*;

    /// The plan as stations kept it before [`Plan`]: every occurrence made up front,
    /// those with `after` set aside; sorted by time, keeping the order of equal times; a
    /// release appended and sorted again.
    struct Expanded {
        plan: VecDeque<PlannedRequest>,
        deferred: Vec<PlannedRequest>,
    }

    impl Expanded {
        fn new(entries: &[Recurring]) -> Expanded {
            let all = entries.iter().flat_map(|e| {
                (0..e.count).map(move |k| PlannedRequest {
                    at: e.first.at + e.every * k,
                    ..e.first.clone()
                })
            });
            let (deferred, mut plan): (Vec<_>, Vec<_>) = all.partition(|r| r.after.is_some());
            plan.sort_by_key(|r| r.at);
            Expanded {
                plan: plan.into(),
                deferred,
            }
        }

        fn pop_due(&mut self, now: SimTime) -> Option<PlannedRequest> {
            if self.plan.front().is_some_and(|r| r.at <= now) {
                self.plan.pop_front()
            } else {
                None
            }
        }

        fn release(&mut self, label: &str, decided: SimTime) {
            let (release, keep): (Vec<_>, Vec<_>) = std::mem::take(&mut self.deferred)
                .into_iter()
                .partition(|d| d.after.as_deref() == Some(label));
            self.deferred = keep;
            for mut d in release {
                d.at = decided + (d.at - SimTime::ZERO);
                d.after = None;
                self.plan.push_back(d);
            }
            self.plan.make_contiguous().sort_by_key(|r| r.at);
        }
    }

    fn entry(i: usize, at_s: u64, every_s: u64, count: u32, after: Option<usize>) -> Recurring {
        Recurring {
            first: PlannedRequest {
                at: SimTime::from_secs(at_s),
                dst: i as u8,
                dport: 1,
                data: vec![i as u8],
                timeout: Duration::from_secs(1),
                label: format!("c{i}"),
                after: after.map(|j| format!("c{j}")),
            },
            every: Duration::from_secs(every_s),
            count,
        }
    }

    /// Take from both what is due at `now`, the same requests in the same order; how many.
    fn drain(plan: &mut Plan, old: &mut Expanded, now: SimTime) -> Result<usize, TestCaseError> {
        let mut n = 0;
        loop {
            let (a, b) = (plan.pop_due(now), old.pop_due(now));
            prop_assert_eq!(&a, &b);
            if a.is_none() {
                return Ok(n);
            }
            n += 1;
        }
    }

    proptest! {
        /// Entries with times, repeats (a zero period too) and `after` drawn to collide
        /// often, drained in steps of time with releases in between: the same requests, in
        /// the same order, as from the expanded plan.
        #[test]
        fn the_plan_sends_in_the_order_of_the_expanded_plan(
            specs in proptest::collection::vec(
                (0u64..6, 0u64..4, 0u32..5, proptest::option::of(0usize..8)),
                0..8,
            ),
            steps in proptest::collection::vec((0u64..4, 0usize..9, -2i64..3), 0..30),
        ) {
            let entries: Vec<Recurring> = specs
                .iter()
                .enumerate()
                .map(|(i, &(at, every, count, after))| entry(i, at, every, count, after))
                .collect();
            let mut plan = Plan::new(entries.clone());
            let mut old = Expanded::new(&entries);
            let mut now = SimTime::ZERO;
            let mut sent = 0;
            for &(dt, label, back) in &steps {
                now = now + Duration::from_secs(dt);
                sent += drain(&mut plan, &mut old, now)?;
                prop_assert_eq!(plan.next_at(), old.plan.front().map(|r| r.at));
                // An outcome releases those waiting for it: decided at or before now (a
                // reply, a timeout), or after (a send failure counts its timeout from now).
                let decided = SimTime::from_secs(now.as_secs().saturating_add_signed(-back));
                plan.release(&format!("c{label}"), decided);
                old.release(&format!("c{label}"), decided);
            }
            // Whatever is left comes out the same way too.
            sent += drain(&mut plan, &mut old, SimTime::from_secs(1_000))?;
            prop_assert!(sent <= entries.iter().map(|e| e.count as usize).sum::<usize>());
        }
    }

    #[test]
    fn a_million_occurrences_are_one_entry() {
        let mut plan = Plan::new(vec![entry(0, 10, 1, 1_000_000, None)]);
        assert_eq!(plan.due.len(), 1);
        let mut n = 0u64;
        while let Some(r) = plan.pop_due(SimTime::from_secs(2_000_000)) {
            assert_eq!(r.at, SimTime::from_secs(10 + n));
            assert_eq!(plan.due.len(), usize::from(n + 1 < 1_000_000));
            n += 1;
        }
        assert_eq!(n, 1_000_000);
    }

    #[test]
    fn a_backlog_goes_out_in_batches_in_order() {
        use csp::node::{Host, NodeConfig};
        let n = 3 * SENDS_PER_CALL as u32 + 5;
        let app = GroundApp::new(vec![entry(0, 0, 1, n, None)]);
        let mut host = Host::new(NodeConfig::new("GS16", 16), app, SimTime::ZERO);
        // Everything is overdue at once (a station back from a long hang).
        let now = SimTime::from_secs(u64::from(n) + 10);
        let mut sent = Vec::new();
        let mut calls = 0;
        while host.poll_timeout().is_some_and(|t| t <= now) {
            host.handle_timeout(now);
            calls += 1;
            let mut batch = 0;
            while let Some(ev) = host.app.poll_event() {
                match ev {
                    twin_core::events::RunEvent::Command { .. } => {}
                    twin_core::events::RunEvent::CommandResult(r) => sent.push(r.sent),
                    other => panic!("{other:?}"),
                }
                batch += 1;
            }
            assert!(batch <= SENDS_PER_CALL, "{batch} events from one call");
        }
        assert_eq!(calls, 4);
        // No interface: each send fails at once.
        assert_eq!(sent.len(), n as usize);
        assert!(sent.iter().all(|t| *t == now), "{sent:?}");
    }

    /// A station saved with a plan under way (a recurring request, one waiting for
    /// another's outcome, requests in flight) and loaded into one fresh from the same plan
    /// goes on as the original: the same requests out and outcomes, to the end.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn a_station_saved_mid_plan_and_loaded_into_a_fresh_one_goes_on_the_same() {
        let plan = || {
            vec![
                entry(3, 1, 2, 5, None),
                entry(4, 2, 0, 1, Some(0)),
                entry(5, 6, 1, 3, None),
            ]
        };
        let host = || {
            let mut c = csp::node::NodeConfig::new("GS16", 16);
            c.ifaces = vec![csp::node::IfaceConfig::packet("uhf")];
            c.routes.set_default(csp::router::Route::direct(0));
            csp::node::Host::new(c, GroundApp::new(plan()), SimTime::ZERO)
        };
        let step = |h: &mut csp::node::Host<GroundApp>, until: SimTime| {
            let mut seen = Vec::new();
            while let Some(t) = h.poll_timeout().filter(|&t| t <= until) {
                h.handle_timeout(t);
                while let Some(tx) = h.node.poll_transmit() {
                    seen.push(format!("{t:?} {tx:?}"));
                }
                while let Some(e) = h.poll_event() {
                    seen.push(format!("{e:?}"));
                }
            }
            seen
        };
        let mut a = host();
        step(&mut a, SimTime::from_ms(6_500));
        let bytes = snap::to_bytes(&a);
        let mut b = host();
        snap::load_from(&mut b, &bytes).unwrap();
        assert_eq!(snap::to_bytes(&b), bytes);
        let end = SimTime::from_secs(60);
        let (sa, sb) = (step(&mut a, end), step(&mut b, end));
        assert!(sa.len() > 5, "{sa:?}");
        assert_eq!(sa, sb);
        assert_eq!(snap::to_bytes(&a), snap::to_bytes(&b));
    }
}
