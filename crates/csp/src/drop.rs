//! Why a node drops what it drops: [`DropReason`] for the node's own CSP drops (counted in
//! its [`crate::node::NodeCounters`], by reason), and [`DropCause`] for every drop a node
//! reports, its application's included (an application counts its own).

use std::borrow::Cow;

/// Why a node's CSP layer dropped a packet or a frame. Its name is what tables, logs and
/// scenarios (`drops.<reason>` counters) call it; reasons order by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum DropReason {
    /// A CAN frame on an interface that is not a CAN interface.
    FrameOnNonCanIface,
    /// CFP reassembly refused or timed out ([`crate::cfp::CfpDrop`]).
    Cfp,
    /// No route to the destination.
    NoRoute,
    /// The route leads back out of the interface the packet came in on.
    SameIface,
    /// Forwarding failed (the interface refused it).
    ForwardFailed,
    /// An answer to the port a node sends from on its own, where nobody waits.
    OwnPort,
    /// A CRC32 that does not verify.
    Crc32,
    /// XTEA encrypted (libcsp 1.4 built as the M6P's has no XTEA).
    Xtea,
    /// HMAC authenticated (no HMAC support).
    Hmac,
    /// RDP (no RDP support).
    Rdp,
    /// No socket bound to the destination port.
    UnboundPort,
    /// The service handler could not send its reply.
    ServiceReply,
    /// The node's loopback queue is full.
    LoopbackFull,
    /// The loopback's budget for one input is spent.
    LoopbackBudget,
    /// A payload's CMP request, refused (ICD 4.1).
    PayloadCmp,
    /// A payload's ps request, refused.
    PayloadPs,
    /// A payload's memfree request, refused.
    PayloadMemfree,
    /// A payload's reboot request, refused.
    PayloadReboot,
    /// A payload's buf_free request, refused.
    PayloadBufFree,
    /// A payload's request to another service port, refused.
    PayloadService,
}

impl DropReason {
    /// Every reason.
    pub const ALL: [DropReason; 20] = [
        DropReason::FrameOnNonCanIface,
        DropReason::Cfp,
        DropReason::NoRoute,
        DropReason::SameIface,
        DropReason::ForwardFailed,
        DropReason::OwnPort,
        DropReason::Crc32,
        DropReason::Xtea,
        DropReason::Hmac,
        DropReason::Rdp,
        DropReason::UnboundPort,
        DropReason::ServiceReply,
        DropReason::LoopbackFull,
        DropReason::LoopbackBudget,
        DropReason::PayloadCmp,
        DropReason::PayloadPs,
        DropReason::PayloadMemfree,
        DropReason::PayloadReboot,
        DropReason::PayloadBufFree,
        DropReason::PayloadService,
    ];

    /// Its name (`no route`, `crc32`, `payload cmp`).
    pub const fn name(self) -> &'static str {
        match self {
            DropReason::FrameOnNonCanIface => "frame on non-CAN iface",
            DropReason::Cfp => "cfp",
            DropReason::NoRoute => "no route",
            DropReason::SameIface => "same iface",
            DropReason::ForwardFailed => "forward failed",
            DropReason::OwnPort => "own port",
            DropReason::Crc32 => "crc32",
            DropReason::Xtea => "xtea",
            DropReason::Hmac => "hmac",
            DropReason::Rdp => "rdp",
            DropReason::UnboundPort => "unbound port",
            DropReason::ServiceReply => "service reply",
            DropReason::LoopbackFull => "loopback full",
            DropReason::LoopbackBudget => "loopback budget",
            DropReason::PayloadCmp => "payload cmp",
            DropReason::PayloadPs => "payload ps",
            DropReason::PayloadMemfree => "payload memfree",
            DropReason::PayloadReboot => "payload reboot",
            DropReason::PayloadBufFree => "payload buf_free",
            DropReason::PayloadService => "payload service",
        }
    }

    /// The reason named `name`.
    pub fn from_name(name: &str) -> Option<DropReason> {
        DropReason::ALL.into_iter().find(|r| r.name() == name)
    }
}

impl std::fmt::Display for DropReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl PartialOrd for DropReason {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

/// By name: a node's table of drops reads alphabetically.
impl Ord for DropReason {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.name().cmp(other.name())
    }
}

/// What a node reports it dropped: its CSP layer's [`DropReason`], or its application's own
/// drop, named by the application (`pc buffer-full`, `beacon 12`) for the run's log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DropCause {
    /// The node's CSP layer (counted in its counters).
    Node(DropReason),
    /// The application's (counted by the application).
    App(Cow<'static, str>),
}

impl DropCause {
    /// An application's drop named `what`.
    pub fn app(what: impl Into<Cow<'static, str>>) -> Self {
        DropCause::App(what.into())
    }
}

impl From<DropReason> for DropCause {
    fn from(r: DropReason) -> Self {
        DropCause::Node(r)
    }
}

impl std::fmt::Display for DropCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DropCause::Node(r) => f.write_str(r.name()),
            DropCause::App(what) => f.write_str(what),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_reason_has_a_name_of_its_own_that_names_it_back() {
        for r in DropReason::ALL {
            assert_eq!(DropReason::from_name(r.name()), Some(r));
        }
        let mut names: Vec<&str> = DropReason::ALL.iter().map(|r| r.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), DropReason::ALL.len());
        assert_eq!(DropReason::from_name("no such"), None);
    }

    #[test]
    fn reasons_order_by_name() {
        assert!(DropReason::Cfp < DropReason::Crc32);
        assert!(DropReason::UnboundPort > DropReason::NoRoute);
    }
}
