//! Addresses reserved for outside links: an address a link is configured with is that
//! link's for the whole run, its program connected or not. Without a reservation, another
//! link learning addresses from its packets could take it while the program is offline:
//! the twin's traffic for it would go to the wrong connection, and the program would be
//! refused when it connects. Each medium (`crate::can`, `crate::net`) keeps one table.

use std::collections::BTreeMap;
use std::sync::Arc;

/// One outside link of a run (its index among the run's links): two links may share a
/// label (two servers on `127.0.0.1:0`), never an id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct LinkId(pub u32);

/// Why an address could not be claimed or reserved: who has it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ClaimError {
    /// A node of the twin holds it (the node's name).
    #[error("{0}, a node of the twin")]
    Node(String),
    /// Another outside connection claimed it (the endpoint's name).
    #[error("{0}")]
    Held(String),
    /// Another outside link reserved it (the link's label).
    #[error("link `{0}`")]
    Reserved(Arc<str>),
    /// Another outside link reserved it, and that link's program is not connected now (the
    /// link's label).
    #[error("link `{0}` (configured there; its program is not connected)")]
    ReservedOffline(Arc<str>),
}

/// The addresses reserved on one medium, each with its link and the link's label.
#[derive(Debug, Default)]
pub(crate) struct Reservations(BTreeMap<u8, (LinkId, Arc<str>)>);

impl Reservations {
    /// Reserve `addr` for `link` (labelled `label`); refused with the label of the link
    /// holding it already.
    pub(crate) fn reserve(
        &mut self,
        addr: u8,
        link: LinkId,
        label: &str,
    ) -> Result<(), ClaimError> {
        match self.0.get(&addr) {
            Some((l, name)) if *l != link => Err(ClaimError::Reserved(name.clone())),
            Some(_) => Ok(()),
            None => {
                self.0.insert(addr, (link, label.into()));
                Ok(())
            }
        }
    }

    /// Why an endpoint of `link` (`None`: not an outside link's) may not claim `addr`: it is
    /// reserved for another link, whose program is not connected now.
    pub(crate) fn refusal(&self, addr: u8, link: Option<LinkId>) -> Option<ClaimError> {
        let (l, name) = self.0.get(&addr)?;
        (Some(*l) != link).then(|| ClaimError::ReservedOffline(name.clone()))
    }
}

// The state a snapshot saves (docs/snapshots.md).
impl snap::Snap for LinkId {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.0.load(r)
    }
}

impl snap::SnapNew for LinkId {
    const MIN_BYTES: usize = 4;
    fn read(r: &mut snap::Reader<'_>) -> Result<Self, snap::SnapError> {
        u32::read(r).map(LinkId)
    }
}

impl snap::Snap for Reservations {
    fn save(&self, w: &mut snap::Writer) {
        self.0.save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        self.0.load(r)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_reserved_address_is_its_links_alone_whatever_the_labels() {
        let (a, b) = (LinkId(0), LinkId(1));
        let mut r = Reservations::default();
        assert_eq!(r.reserve(15, a, "listen 127.0.0.1:0"), Ok(()));
        assert_eq!(r.reserve(15, a, "listen 127.0.0.1:0"), Ok(()));
        let e = r.reserve(15, b, "listen 127.0.0.1:0").unwrap_err();
        assert_eq!(e, ClaimError::Reserved("listen 127.0.0.1:0".into()));
        assert_eq!(e.to_string(), "link `listen 127.0.0.1:0`");
        assert_eq!(r.refusal(15, Some(a)), None);
        let e = r.refusal(15, Some(b)).unwrap();
        assert_eq!(
            e.to_string(),
            "link `listen 127.0.0.1:0` (configured there; its program is not connected)"
        );
        assert!(r.refusal(15, None).is_some());
        assert_eq!(r.refusal(14, Some(b)), None);
    }
}
