//! Arbitrary input never panics the node, the service handler or the ICD framing.
#![allow(clippy::unwrap_used)]

use m6p_csp::cfp::CanFrame;
use m6p_csp::node::{Host, IfaceConfig, NodeConfig, StubApp};
use m6p_csp::reqrep::{Reply, Request};
use m6p_csp::router::Route;
use m6p_csp::{Packet, SimTime, service};
use proptest::prelude::*;

fn host() -> Host<StubApp> {
    let mut cfg = NodeConfig::new("PC", 6);
    cfg.ifaces = vec![
        IfaceConfig::can("main"),
        IfaceConfig::can("payload"),
        IfaceConfig::packet("kiss"),
    ];
    cfg.routes
        .set_default(Route::direct(0))
        .set_range(12..=15, Route::direct(1));
    Host::new(cfg, StubApp::new(&[10, 11]), SimTime::ZERO)
}

proptest! {
    #[test]
    fn framing_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = Request::parse(&bytes);
        let _ = Reply::parse(&bytes);
        let _ = Packet::parse(&bytes);
    }

    #[test]
    fn service_handler_never_panics(port in 0u8..64, data in proptest::collection::vec(any::<u8>(), 0..300), up in any::<u64>()) {
        let cfg = service::ServiceConfig::named("FC");
        let _ = service::handle(&cfg, port, &data, std::time::Duration::from_millis(up), (0, 0));
    }

    #[test]
    fn node_survives_arbitrary_frames_and_packets(
        frames in proptest::collection::vec((any::<u32>(), proptest::collection::vec(any::<u8>(), 0..=8), 0usize..4), 0..200),
        packets in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 4..300), 0..20),
    ) {
        let mut h = host();
        let mut t = SimTime::ZERO;
        for (id, data, iface) in frames {
            t = t + std::time::Duration::from_micros(130);
            let f = CanFrame::new(id & 0x1FFF_FFFF, &data).unwrap();
            h.handle_frame(iface, &f, t);
            while h.node.poll_transmit().is_some() {}
        }
        for p in packets {
            let p = Packet::parse(&p).unwrap();
            h.handle_packet(2, p, t);
            while h.node.poll_transmit().is_some() {}
        }
        h.handle_timeout(t + std::time::Duration::from_secs(60));
    }
}
