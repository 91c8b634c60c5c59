//! The CSP state a snapshot saves (docs/snapshots.md): [`snap::Snap`] for the wire types
//! and a node's counters and events. Types with private fields have theirs in their modules
//! (`cfp`: fragmenter and reassembler; `node`: the node, its outbox and clock errors).

use snap::{Reader, Snap, SnapError, SnapNew, Writer};

use crate::Header;
use crate::cfp::{CanFrame, CfpDrop, CfpStats, ReassemblerConfig};
use crate::drop::{DropCause, DropReason};
use crate::header::Priority;
use crate::node::{
    ClockError, DroppedPacket, NodeCounters, NodeEvent, NodeFault, Severity, Transmit,
};
use crate::packet::Packet;

snap::unit_enum!(Priority {
    Critical,
    High,
    Norm,
    Low
});
snap::fields!(Header {
    prio,
    src,
    dst,
    dport,
    sport,
    flags
});
snap::fields!(CanFrame { id, dlc, data });
snap::fields!(Packet { header, data });
snap::unit_enum!(CfpDrop {
    BeginTooShort,
    LengthExceedsMtu,
    NoBufferFree,
    UnexpectedMore,
    RemainMismatch,
    Overflow,
    Restarted,
    Timeout,
    Reset,
});
snap::fields!(CfpStats {
    frames,
    packets_ok,
    begin_too_short,
    length_exceeds_mtu,
    no_buffer_free,
    unexpected_more,
    remain_mismatch,
    overflow,
    restarted,
    timeout,
    reset,
});
snap::fields!(ReassemblerConfig {
    slots,
    timeout,
    mtu
});
snap::unit_enum!(Severity { Info, Warning });
snap::fields!(NodeCounters {
    rx_packets,
    tx_packets,
    forwarded,
    delivered,
    service_replies,
    reboots,
    platform_requests,
    platform_refused,
    drops,
});
snap::fields!(DroppedPacket {
    header,
    data_len,
    cfp
});
snap::fields!(ClockError {
    jump_ns,
    drift_ppm,
    since
});

/// Save an enum's variant tag.
fn tag(w: &mut Writer, t: u8) {
    t.save(w);
}

/// Load by reading anew (an enum: its variant may change).
macro_rules! load_by_read {
    () => {
        fn load(&mut self, r: &mut Reader<'_>) -> Result<(), SnapError> {
            *self = SnapNew::read(r)?;
            Ok(())
        }
    };
}

/// By its place in [`DropReason::ALL`] (which its tests keep complete).
impl Snap for DropReason {
    fn save(&self, w: &mut Writer) {
        let at = DropReason::ALL.iter().position(|x| x == self).unwrap_or(0);
        (at as u8).save(w);
    }
    load_by_read!();
}

impl SnapNew for DropReason {
    const MIN_BYTES: usize = 1;
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        let at = r.at();
        let i = usize::from(u8::read(r)?);
        DropReason::ALL.get(i).copied().ok_or(SnapError::Bad {
            what: "DropReason",
            at,
        })
    }
}

impl Snap for DropCause {
    fn save(&self, w: &mut Writer) {
        match self {
            DropCause::Node(reason) => {
                tag(w, 0);
                reason.save(w);
            }
            // Saved as text: read back as an owned string, which displays the same.
            DropCause::App(what) => {
                tag(w, 1);
                what.to_string().save(w);
            }
        }
    }
    load_by_read!();
}

impl SnapNew for DropCause {
    fn read(r: &mut Reader<'_>) -> Result<Self, SnapError> {
        match u8::read(r)? {
            0 => Ok(DropCause::Node(SnapNew::read(r)?)),
            1 => Ok(DropCause::App(String::read(r)?.into())),
            _ => Err(r.bad("DropCause")),
        }
    }
}

snap::tagged_enum!(NodeEvent {
    Drop {
        t,
        reason,
        detail,
        packet
    },
    Log { t, severity, text }
});

snap::tagged_enum!(Transmit {
    Can { iface, frame },
    Packet { iface, packet }
});

snap::tagged_enum!(NodeFault {
    Clock { jump_ns, drift_ppm }
});
