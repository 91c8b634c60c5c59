//! `outside_link`: the receive path of a link to a program outside the twin (the core of
//! `links::kiss_tcp`, which KISS/TCP, the KISS pty and the ZMQ hub share: framing, claims,
//! refusals, the CAN transmit queue and budget) fed one connection's bytes in chunks (the
//! hub: one message a chunk, empty ones included), with 0-2 configured addresses, libcsp
//! 1.4's receive limit on or off, a transmit budget set or not (set on the endpoint only:
//! no bus task runs here) (`m6p_twin_fuzz::link_input`).
//! Around it: the twin's FC (3) and EPS (4) on the main bus, PL12 on the payload bus,
//! GS16 on the ground, another link's connection holding 17 and another link's
//! reservation of 15 (its program not connected).
//!
//! Asserts (besides "never panics" and "ends when its input does"):
//! - the counters agree with a reference decoder: the bytes read, the KISS drops (bad
//!   CRC, short, oversize) or the hub's short and oversize messages, and every packet
//!   decoded either taken in or refused;
//! - a refused packet costs nothing that outlives it: the connection leaves at most one
//!   endpoint on a segment (KISS: on one segment in all), and when it ends every address
//!   it took is free again, while the twin's nodes, the other connection and the other
//!   link's reservation keep theirs;
//! - its warnings are bounded (one per refused address, and a few more).
#![no_main]

use std::sync::{Arc, Mutex};

use bus::can::{CanBus, CanBusConfig};
use bus::clock::{Clock, ClockMode};
use bus::inbox::inbox;
use bus::net::{PacketNet, PacketNetConfig};
use bus::outside::{LinkId, OutsideEndpoint, OutsideError, Segments};
use csp::SimTime;
use csp::kiss::{Decoder, DecoderConfig, KissDrop, KissEvent};
use csp::zmqhub::HubDrop;
use libfuzzer_sys::fuzz_target;
use links::kiss_tcp::{
    Connection, FrameSink, Framing, KissLinkConfig, KissLog, LinkInput, SharedStats, serve_link,
};
use m6p_twin_fuzz::link_input;

/// Collects what the link writes towards the outside program.
struct Sink(usize);

impl FrameSink for Sink {
    async fn send_frame(&mut self, _frame: &[u8]) -> std::io::Result<()> {
        self.0 += 1;
        Ok(())
    }
}

thread_local! {
    static RUNTIME: tokio::runtime::Runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .expect("a current-thread runtime");
}

/// Endpoints attached to the three segments.
fn endpoints(segs: &Segments) -> [usize; 3] {
    [
        segs.main.stats().ports.len(),
        segs.payload.stats().ports.len(),
        segs.ground.stats().endpoints.len(),
    ]
}

fuzz_target!(|data: &[u8]| {
    let input = link_input::split(data);
    let segs = Segments {
        main: CanBus::new(CanBusConfig::new("main"), 1),
        payload: CanBus::new(CanBusConfig::new("payload"), 1),
        ground: PacketNet::new(PacketNetConfig::ground(), 1),
    };
    let (tx, _rx) = inbox();
    let _fc = segs.main.attach("FC", &[3], false, tx.clone(), 0);
    let _eps = segs.main.attach("EPS", &[4], false, tx.clone(), 0);
    let _pl12 = segs.payload.attach("PL12", &[12], false, tx.clone(), 0);
    let _gs16 = segs
        .ground
        .attach("GS16", &[16], false, false, tx.clone(), 0);
    let other = OutsideEndpoint::attach(&segs, "other#1", LinkId(1), 17, tx.clone(), 7, None)
        .expect("17 is free");
    segs.reserve(15, LinkId(2), "reserved").expect("15 is free");
    let before = endpoints(&segs);

    let warnings = Arc::new(Mutex::new(0usize));
    let counted = warnings.clone();
    let cfg = KissLinkConfig {
        addrs: input.addrs.clone(),
        decoder: DecoderConfig {
            libcsp14_rx_limit: input.libcsp14_rx_limit,
        },
        framing: if input.hub {
            Framing::ZmqHub
        } else {
            Framing::Kiss
        },
        link: LinkId(0),
        tx_frames_per_s: input.tx_frames_per_s,
        log: Some(KissLog::new(move |_, _, _| {
            *counted
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner) += 1;
        })),
        ..KissLinkConfig::default()
    };
    let stats = SharedStats::default();
    let (in_tx, in_rx) = tokio::sync::mpsc::channel(input.chunks.len().max(1));
    for (i, chunk) in input.chunks.iter().enumerate() {
        let t = SimTime::from_ms(i as u64);
        in_tx
            .try_send((t, LinkInput::Bytes(chunk.to_vec())))
            .expect("room for every chunk");
    }
    drop(in_tx);
    let mut sink = Sink(0);
    let left = RUNTIME.with(|rt| {
        rt.block_on(async {
            let k = Connection {
                name: "fuzz#1",
                segs: &segs,
                cfg: &cfg,
                stats: &stats,
                n: 1,
                clock: Clock::new(ClockMode::Realtime { speed: 1.0 }),
                opened: SimTime::ZERO,
                live: None,
            };
            // Returns with the connection's claims given back (its endpoints stay attached,
            // disabled, as a departed connection's do).
            serve_link(in_rx, &mut sink, k).await
        })
    });
    assert_eq!(left, "peer closed");
    let s = stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .clone();

    // The reference decoder.
    let bytes: usize = input.chunks.iter().map(|c| c.len()).sum();
    assert_eq!(s.bytes_in, bytes as u64);
    let decoded = if input.hub {
        let (mut ok, mut short, mut oversize) = (0u64, 0u64, 0u64);
        for m in &input.chunks {
            match csp::zmqhub::decode(m) {
                Ok(_) => ok += 1,
                Err(HubDrop::Short) => short += 1,
                Err(HubDrop::Oversize) => oversize += 1,
            }
        }
        assert_eq!((s.short, s.oversize, s.bad_crc), (short, oversize, 0));
        ok
    } else {
        let mut d = Decoder::new(cfg.decoder);
        let mut ev = Vec::new();
        for c in &input.chunks {
            d.push(c, &mut ev);
        }
        let (mut ok, mut bad_crc, mut short, mut oversize) = (0u64, 0u64, 0u64, 0u64);
        for e in ev {
            match e {
                KissEvent::Packet(_) => ok += 1,
                KissEvent::Dropped(KissDrop::BadCrc) => bad_crc += 1,
                KissEvent::Dropped(KissDrop::Short) => short += 1,
                KissEvent::Dropped(_) => oversize += 1,
            }
        }
        assert_eq!((s.bad_crc, s.short, s.oversize), (bad_crc, short, oversize));
        ok
    };
    assert_eq!(s.packets_in + s.refused, decoded, "{s:?}");
    assert!(s.claims_refused + s.queue_full <= s.refused, "{s:?}");

    // Nothing outlives a refused packet: at most one endpoint a segment (KISS: one in all).
    let after = endpoints(&segs);
    let added: Vec<usize> = after.iter().zip(before).map(|(a, b)| a - b).collect();
    assert!(added.iter().all(|&n| n <= 1), "endpoints added: {added:?}");
    if !input.hub {
        assert!(
            added.iter().sum::<usize>() <= 1,
            "endpoints added: {added:?}"
        );
    }
    // Every address the connection took is free again; the others keep theirs.
    for addr in 0..31u8 {
        let probe = OutsideEndpoint::attach(&segs, "probe#1", LinkId(9), addr, tx.clone(), 1, None);
        match (addr, &probe) {
            (3 | 4 | 12 | 16 | 17 | 15, Err(OutsideError::Held { .. })) => {}
            (3 | 4 | 12 | 16 | 17 | 15, Ok(_)) => panic!("{addr} was free after the link ended"),
            (_, Ok(ep)) => ep.release(),
            (_, Err(e)) => panic!("{addr} is still taken after the link ended: {e}"),
        }
    }
    other.release();
    let warned = *warnings
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    assert!(warned <= 40, "{warned} warnings");
});
