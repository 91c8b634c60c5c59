//! A ground station inside the twin: it sends planned requests (pings, uptime, ICD
//! commands) at given times and records every outcome. Scenario command timelines drive it.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::node::{App, Node, Outbox};
use csp::reqrep::Client;
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

/// A request and its outcome.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RequestResult {
    /// The request.
    pub request: PlannedRequest,
    /// When it was sent.
    pub sent: SimTime,
    /// What became of it.
    pub outcome: Outcome,
}

/// Where a station records its outcomes (shared with the run that reports them).
pub type Results = Arc<Mutex<Vec<RequestResult>>>;

/// The ground station application.
#[derive(Debug)]
pub struct GroundApp {
    plan: VecDeque<PlannedRequest>,
    client: Client,
    in_flight: BTreeMap<u64, (PlannedRequest, SimTime)>,
    next_tag: u64,
    results: Results,
    events: Outbox<crate::events::RunEvent>,
    /// Requests waiting for another request's outcome (`after`), in plan order.
    deferred: Vec<PlannedRequest>,
}

impl GroundApp {
    /// A station that will send `plan` (in time order) and record outcomes in `results`.
    pub fn new(plan: Vec<PlannedRequest>, results: Results) -> Self {
        let (deferred, mut plan): (Vec<_>, Vec<_>) =
            plan.into_iter().partition(|r| r.after.is_some());
        plan.sort_by_key(|r| r.at);
        GroundApp {
            plan: plan.into(),
            client: Client::new(),
            in_flight: BTreeMap::new(),
            next_tag: 0,
            results,
            events: Outbox::default(),
            deferred,
        }
    }

    fn emit(&mut self, ev: crate::events::RunEvent) {
        self.events.push(ev);
    }

    fn record(&mut self, request: PlannedRequest, sent: SimTime, outcome: Outcome) {
        let (reply, rtt_ns) = match &outcome {
            Outcome::Reply { data, rtt } => (Some(data.clone()), Some(rtt.as_nanos() as u64)),
            _ => (None, None),
        };
        let decided = sent + rtt_ns.map_or(request.timeout, std::time::Duration::from_nanos);
        // Release the requests that wait for this one (its first outcome only).
        if self
            .deferred
            .iter()
            .any(|d| d.after.as_deref() == Some(request.label.as_str()))
        {
            let (release, keep): (Vec<_>, Vec<_>) = std::mem::take(&mut self.deferred)
                .into_iter()
                .partition(|d| d.after.as_deref() == Some(request.label.as_str()));
            self.deferred = keep;
            for mut d in release {
                d.at = decided + (d.at - SimTime::ZERO);
                d.after = None;
                self.plan.push_back(d);
            }
            self.plan.make_contiguous().sort_by_key(|r| r.at);
        }
        self.emit(crate::events::RunEvent::CommandResult {
            t: decided,
            name: request.label.clone(),
            reply,
            rtt_ns,
        });
        self.results
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .push(RequestResult {
                request,
                sent,
                outcome,
            });
    }
}

/// The port where a ground station receives the COMM's beacons.
pub const BEACON_PORT: u8 = 10;

/// Every command sent, every decided outcome and every beacon received, as run events.
impl App for GroundApp {
    type Event = crate::events::RunEvent;
    fn poll_event(&mut self) -> Option<Self::Event> {
        self.events.pop()
    }
    fn start(&mut self, node: &mut Node, _now: SimTime) {
        node.bind(BEACON_PORT);
    }

    fn finish(&mut self, _node: &mut Node, _now: SimTime) {
        // What is still waiting was sent: say so (no event: nothing was decided in the run).
        let mut results = self
            .results
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        for (_, (request, sent)) in std::mem::take(&mut self.in_flight) {
            results.push(RequestResult {
                request,
                sent,
                outcome: Outcome::Unfinished,
            });
        }
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        if packet.header.dport == BEACON_PORT {
            // A beacon (nodes_comm): `04 01 | Beacon`; the ground does not reply.
            self.emit(crate::events::RunEvent::Beacon {
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
        let next = self.plan.front().map(|r| r.at);
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
        while self.plan.front().is_some_and(|r| r.at <= now) {
            let Some(req) = self.plan.pop_front() else {
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
                    self.emit(crate::events::RunEvent::Command {
                        t: now,
                        name: req.label.clone(),
                        dst: req.dst,
                        dport: req.dport,
                        data: req.data.clone(),
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
