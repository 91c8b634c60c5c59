//! The ground stations' commands and their outcomes, from the run's events alone
//! (`Command`, `CommandResult`): every outcome counted, and each kept when asked.

use std::collections::BTreeMap;
use std::time::Duration;

use csp::SimTime;
use twin_core::events::{CommandResult, RunEvent};
use twin_runtime::ground::Outcome;

/// A command as the station sent it (or tried to).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandSent {
    /// The command's name (its scenario label).
    pub label: String,
    /// Destination node.
    pub dst: u8,
    /// Destination port.
    pub dport: u8,
    /// Request bytes.
    pub data: Vec<u8>,
    /// How long it waited for its reply.
    pub timeout: Duration,
}

/// A request and its outcome.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RequestResult {
    /// The request.
    pub request: CommandSent,
    /// When it was sent (or failed to be).
    pub sent: SimTime,
    /// What became of it.
    pub outcome: Outcome,
}

/// What the stations' requests came to: how many had an outcome, were answered, were
/// still waiting at the end.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RequestSummary {
    /// Requests with an outcome (sent or not), those still waiting included.
    pub requests: u64,
    /// Those answered.
    pub answered: u64,
    /// Those sent and still waiting for their reply or timeout when the run ended.
    pub unfinished: u64,
}

impl RequestSummary {
    /// Count `outcome` in.
    pub fn add(&mut self, outcome: &Outcome) {
        self.requests += 1;
        match outcome {
            Outcome::Reply { .. } => self.answered += 1,
            Outcome::Unfinished => self.unfinished += 1,
            Outcome::Timeout | Outcome::SendFailed(_) => {}
        }
    }
}

/// Gathers the outcomes of the ground stations' commands: the counts always, every result
/// only when kept (a result per request grows with the simulated time). A command sent and
/// without an outcome at the end is unfinished.
#[derive(Debug, Default)]
pub struct CommandObserver {
    keep: bool,
    kept: Vec<RequestResult>,
    summary: RequestSummary,
    /// Commands sent and without an outcome yet.
    waiting: u64,
    /// What is waiting, when kept: (sent, send order) -> the command (those sent at one
    /// instant under one name are alike, and decided oldest first).
    in_flight: BTreeMap<(SimTime, u64), CommandSent>,
    sends: u64,
}

impl CommandObserver {
    /// Outcomes counted, and each kept when `keep`.
    pub fn new(keep: bool) -> Self {
        CommandObserver {
            keep,
            ..Self::default()
        }
    }

    /// Take in one event.
    pub fn observe(&mut self, ev: &RunEvent) {
        match ev {
            RunEvent::Command {
                t,
                name,
                dst,
                dport,
                data,
                timeout,
            } => {
                self.waiting += 1;
                if self.keep {
                    let c = CommandSent {
                        label: name.clone(),
                        dst: *dst,
                        dport: *dport,
                        data: data.clone(),
                        timeout: *timeout,
                    };
                    self.in_flight.insert((*t, self.sends), c);
                }
                self.sends += 1;
            }
            RunEvent::CommandResult(r) => {
                let CommandResult {
                    name,
                    dst,
                    dport,
                    data,
                    timeout,
                    reply,
                    rtt_ns,
                    sent,
                    failed,
                    ..
                } = &**r;
                let outcome = Outcome::of_result(reply.as_deref(), *rtt_ns, failed.as_deref());
                if failed.is_none() {
                    self.waiting = self.waiting.saturating_sub(1);
                    if self.keep {
                        let k = self
                            .in_flight
                            .range((*sent, 0)..=(*sent, u64::MAX))
                            .find(|(_, c)| c.label == *name)
                            .map(|(k, _)| *k);
                        if let Some(k) = k {
                            self.in_flight.remove(&k);
                        }
                    }
                }
                self.summary.add(&outcome);
                if self.keep {
                    self.kept.push(RequestResult {
                        request: CommandSent {
                            label: name.clone(),
                            dst: *dst,
                            dport: *dport,
                            data: data.clone(),
                            timeout: *timeout,
                        },
                        sent: *sent,
                        outcome,
                    });
                }
            }
            _ => {}
        }
    }

    /// The results kept, in the order they were decided and then those unfinished in the
    /// order they were sent, and the counts.
    pub fn finish(mut self) -> (Vec<RequestResult>, RequestSummary) {
        for _ in 0..self.waiting {
            self.summary.add(&Outcome::Unfinished);
        }
        for ((sent, _), request) in std::mem::take(&mut self.in_flight) {
            self.kept.push(RequestResult {
                request,
                sent,
                outcome: Outcome::Unfinished,
            });
        }
        (self.kept, self.summary)
    }
}

// What a snapshot saves (docs/snapshots.md).
snap::fields!(CommandSent {
    label,
    dst,
    dport,
    data,
    timeout
});
snap::fields!(RequestResult {
    request,
    sent,
    outcome
});
snap::fields!(RequestSummary {
    requests,
    answered,
    unfinished
});
snap::fields!(CommandObserver {
    kept,
    summary,
    waiting,
    in_flight,
    sends;
    skip keep
});

#[cfg(test)]
mod tests {
    use super::*;

    fn command(t: SimTime) -> RunEvent {
        RunEvent::Command {
            t,
            name: "ping".into(),
            dst: 3,
            dport: 1,
            data: vec![0, 1],
            timeout: Duration::from_secs(1),
        }
    }

    fn result(sent: SimTime, reply: Option<Vec<u8>>, failed: Option<&str>) -> RunEvent {
        RunEvent::CommandResult(Box::new(CommandResult {
            t: sent + Duration::from_millis(5),
            name: "ping".into(),
            dst: 3,
            dport: 1,
            data: vec![0, 1],
            timeout: Duration::from_secs(1),
            rtt_ns: reply.as_ref().map(|_| 5_000_000),
            reply,
            sent,
            failed: failed.map(str::to_owned),
        }))
    }

    /// A reply, a timeout, a send that failed (no `Command`) and one still waiting: four
    /// requests, one answered, one unfinished; every result kept only when asked.
    #[test]
    fn outcomes_are_counted_and_kept_only_when_asked() {
        let s = |n| SimTime::from_secs(n);
        let events = [
            command(s(1)),
            result(s(1), Some(vec![0, 1]), None),
            command(s(2)),
            result(s(2), None, None),
            result(s(3), None, Some("no route")),
            command(s(4)),
        ];
        for keep in [false, true] {
            let mut o = CommandObserver::new(keep);
            for ev in &events {
                o.observe(ev);
            }
            let (kept, summary) = o.finish();
            assert_eq!(
                summary,
                RequestSummary {
                    requests: 4,
                    answered: 1,
                    unfinished: 1
                }
            );
            if !keep {
                assert!(kept.is_empty());
                continue;
            }
            let outcomes: Vec<(SimTime, &Outcome)> =
                kept.iter().map(|r| (r.sent, &r.outcome)).collect();
            assert_eq!(
                outcomes,
                [
                    (
                        s(1),
                        &Outcome::Reply {
                            data: vec![0, 1],
                            rtt: Duration::from_millis(5)
                        }
                    ),
                    (s(2), &Outcome::Timeout),
                    (s(3), &Outcome::SendFailed("no route".into())),
                    (s(4), &Outcome::Unfinished),
                ]
            );
            assert!(
                kept.iter()
                    .all(|r| r.request.dst == 3 && r.request.label == "ping")
            );
        }
    }
}
