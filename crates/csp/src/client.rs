//! The requesting side of the ICD's request-reply ([`crate::reqrep`]) on a node: each
//! request from an ephemeral port, its reply matched by that port and the peer, timeouts
//! reported.

use std::collections::BTreeMap;
use std::time::Duration;

use crate::node::{Node, SendError};
use crate::{Header, Packet, SimTime};

/// A request waiting for its reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pending {
    /// Caller's tag for this request.
    pub tag: u64,
    /// Destination node.
    pub dst: u8,
    /// Destination port.
    pub dport: u8,
    /// Our ephemeral source port.
    pub sport: u8,
    /// When it was sent.
    pub sent: SimTime,
    /// When it times out.
    pub deadline: SimTime,
}

/// A reply matched to its request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Completion {
    /// The request.
    pub request: Pending,
    /// The reply packet (CRC32 already stripped).
    pub reply: Packet,
    /// Round-trip time.
    pub rtt: Duration,
}

/// The requesting side of request-reply, for any port (service ports included).
///
/// Each request gets its own ephemeral source port, bound on the node until the reply
/// arrives or the request times out; replies are matched by that port and the peer's
/// address and port, as a libcsp connection matches them.
#[derive(Debug, Default)]
pub struct Client {
    pending: BTreeMap<u8, Pending>,
}

impl Client {
    /// A client with nothing pending.
    pub fn new() -> Self {
        Self::default()
    }

    /// Send `data` to `dst:dport` and wait up to `timeout` for the reply.
    #[allow(clippy::too_many_arguments)]
    pub fn request(
        &mut self,
        node: &mut Node,
        tag: u64,
        header_template: Header,
        dst: u8,
        dport: u8,
        data: Vec<u8>,
        timeout: Duration,
        now: SimTime,
    ) -> Result<u8, SendError> {
        let sport = node.alloc_port().ok_or(SendError::NoPort)?;
        let header = Header {
            src: node.addr(),
            dst,
            dport,
            sport,
            ..header_template
        };
        if let Err(e) = node.send(Packet::new(header, data), now) {
            node.unbind(sport);
            return Err(e);
        }
        self.pending.insert(
            sport,
            Pending {
                tag,
                dst,
                dport,
                sport,
                sent: now,
                deadline: now + timeout,
            },
        );
        Ok(sport)
    }

    /// Match an incoming packet; `None` if it answers no pending request.
    pub fn handle_reply(
        &mut self,
        node: &mut Node,
        packet: &Packet,
        now: SimTime,
    ) -> Option<Completion> {
        let h = packet.header;
        let p = self.pending.get(&h.dport)?;
        if p.dst != h.src || p.dport != h.sport {
            return None;
        }
        let request = self.pending.remove(&h.dport)?;
        node.unbind(request.sport);
        Some(Completion {
            rtt: now.saturating_since(request.sent),
            request,
            reply: packet.clone(),
        })
    }

    /// Whether any request is waiting.
    pub fn is_idle(&self) -> bool {
        self.pending.is_empty()
    }
    /// The earliest deadline.
    pub fn poll_timeout(&self) -> Option<SimTime> {
        self.pending.values().map(|p| p.deadline).min()
    }
    /// Expire requests whose deadline has passed, releasing their ports.
    pub fn handle_timeout(&mut self, node: &mut Node, now: SimTime) -> Vec<Pending> {
        let expired: Vec<u8> = self
            .pending
            .iter()
            .filter(|(_, p)| p.deadline <= now)
            .map(|(k, _)| *k)
            .collect();
        expired
            .into_iter()
            .filter_map(|k| self.pending.remove(&k))
            .inspect(|p| node.unbind(p.sport))
            .collect()
    }
    /// Forget everything (reboot).
    pub fn clear(&mut self) {
        self.pending.clear();
    }
}
snap::fields!(Pending {
    tag,
    dst,
    dport,
    sport,
    sent,
    deadline
});
snap::fields!(Client { pending });
