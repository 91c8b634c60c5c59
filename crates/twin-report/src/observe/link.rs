//! The radio link as a run sees it: the beacons the ground receives and the contact
//! switches of the passes ([`LinkObserver`]).

use csp::SimTime;
use twin_core::events::RunEvent;

/// A beacon received on the ground: (time, sending COMM, sequence number).
pub type BeaconSeen = (SimTime, u8, u32);

/// The beacons and contact switches of a run, gathered from its events.
#[derive(Debug, Default)]
pub struct LinkObserver {
    beacons: Vec<BeaconSeen>,
    contact: Vec<(SimTime, bool)>,
}

impl LinkObserver {
    /// Take in one event.
    pub fn observe(&mut self, ev: &RunEvent) {
        if let RunEvent::Beacon { t, from, data } = ev {
            let seq = data
                .get(2..6)
                .and_then(|b| <[u8; 4]>::try_from(b).ok())
                .map_or(0, u32::from_le_bytes);
            self.beacons.push((*t, *from, seq));
        }
    }

    /// The UHF link's contact with the ground switched at `t` (a pass began or ended).
    pub fn contact(&mut self, t: SimTime, on: bool) {
        self.contact.push((t, on));
    }

    /// Beacons (time, sending COMM, sequence number) and contact switches.
    pub fn finish(self) -> (Vec<BeaconSeen>, Vec<(SimTime, bool)>) {
        (self.beacons, self.contact)
    }
}

// What a snapshot saves (docs/snapshots.md).
snap::fields!(LinkObserver { beacons, contact });
