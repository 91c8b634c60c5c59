//! Static routing (libcsp 1.4 `src/rtable/csp_rtable_static.c`).
//!
//! A table maps each destination address to an interface and an optional next-hop MAC
//! (the CFP destination on CAN). The table is fixed for a run: the ICD says the network
//! configuration "cannot be changed during software runtime".

use crate::header::{BROADCAST, MAX_ADDR};

/// Index of an interface of a node, in the order the node's interfaces were configured.
pub type IfaceId = usize;

/// Where packets for a destination go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Route {
    /// The outgoing interface.
    pub iface: IfaceId,
    /// Next-hop MAC (CFP destination on CAN); `None` sends to the CSP destination itself.
    pub via: Option<u8>,
}

impl Route {
    /// A route straight to the destination on `iface`.
    pub fn direct(iface: IfaceId) -> Self {
        Route { iface, via: None }
    }
    /// A route through the next hop `mac` on `iface`.
    pub fn via(iface: IfaceId, mac: u8) -> Self {
        Route {
            iface,
            via: Some(mac),
        }
    }
    /// The link-layer destination for a packet to `dst`.
    pub fn next_hop(&self, dst: u8) -> u8 {
        self.via.unwrap_or(dst)
    }
}

/// A static routing table: one optional route per address plus a default route.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RoutingTable {
    routes: [Option<Route>; 32],
    default: Option<Route>,
}

impl RoutingTable {
    /// An empty table (every destination unreachable).
    pub fn new() -> Self {
        Self::default()
    }
    /// Route destination `dst` (0..=30).
    pub fn set(&mut self, dst: u8, route: Route) -> &mut Self {
        if dst < BROADCAST {
            self.routes[usize::from(dst)] = Some(route);
        }
        self
    }
    /// Route every destination in `range`.
    pub fn set_range(&mut self, range: std::ops::RangeInclusive<u8>, route: Route) -> &mut Self {
        for dst in range {
            self.set(dst, route);
        }
        self
    }
    /// The default route (`CSP_DEFAULT_ROUTE`), used when `dst` has no entry.
    pub fn set_default(&mut self, route: Route) -> &mut Self {
        self.default = Some(route);
        self
    }
    /// Look up the route for `dst`; broadcast and out-of-range addresses have none.
    pub fn lookup(&self, dst: u8) -> Option<Route> {
        if dst >= BROADCAST || dst > MAX_ADDR {
            return None;
        }
        self.routes[usize::from(dst)].or(self.default)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_prefers_specific_then_default() {
        let mut t = RoutingTable::new();
        t.set_default(Route::direct(0))
            .set_range(12..=15, Route::via(1, 6));
        assert_eq!(t.lookup(3), Some(Route::direct(0)));
        assert_eq!(t.lookup(13), Some(Route::via(1, 6)));
        assert_eq!(t.lookup(13).map(|r| r.next_hop(13)), Some(6));
        assert_eq!(t.lookup(31), None);
        assert_eq!(t.lookup(200), None);
    }
}
