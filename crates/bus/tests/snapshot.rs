//! The media saved for a snapshot (docs/snapshots.md): a CAN bus and a packet network saved
//! where the run has settled mid-traffic (frames queued and on the wire, error counters,
//! the impairments' generator, arrivals waiting in inboxes), loaded into media built fresh,
//! go on exactly as the media they were saved from, and saving perturbs nothing.
#![allow(clippy::unwrap_used)]

use std::sync::{Arc, Mutex};
use std::time::Duration;

use csp::cfp::CanFrame;
use csp::{Header, Packet, SimTime};
use m6p_bus::can::CanFault;
use m6p_bus::clock::{Clock, ClockMode, Timer};
use m6p_bus::exec::{run, settled, spawn};
use m6p_bus::impair::Impairments;
use m6p_bus::inbox::{InboxRx, InboxState, inbox};
use m6p_bus::trace::TraceTx;
use m6p_bus::{CanBus, CanBusConfig, CanPort, NetPort, PacketNet, PacketNetConfig};
use snap::Snap as _;

mod common;
use common::runtime;

/// Where a snapshot is taken and where the runs end.
const SNAP_AT: SimTime = SimTime::from_ms(250);
const END: SimTime = SimTime::from_ms(700);

/// Either medium, as the test drives it.
#[derive(Clone)]
enum Medium {
    Can(CanBus, Vec<CanPort>),
    Net(PacketNet, Vec<NetPort>),
}

/// A medium with three endpoints, a trace kept as text and impairments that draw from its
/// generator; the endpoints' inboxes.
fn build(kind: &str) -> (Medium, Vec<InboxRx>, Arc<Mutex<Vec<String>>>) {
    let trace = Arc::new(Mutex::new(Vec::new()));
    let log = trace.clone();
    let tracer = TraceTx::new(move |e| log.lock().unwrap().push(format!("{e:?}")));
    let mut inboxes = Vec::new();
    let lossy = Impairments {
        drop_prob: 0.1,
        corrupt_prob: 0.2,
        ..Impairments::default()
    };
    let medium = if kind == "can" {
        let bus = CanBus::new(CanBusConfig::new("main"), 7);
        bus.set_trace(tracer);
        let ports = (0..3)
            .map(|i| {
                let (tx, rx) = inbox();
                inboxes.push(rx);
                bus.attach(&format!("n{i}"), &[3 + i as u8], false, tx, 0)
            })
            .collect();
        bus.set_fault(1, Some(lossy));
        // A babbler from 200 ms to 300 ms: arbitration against it across the snapshot.
        bus.set_can_fault(
            2,
            Some(CanFault::Babble {
                node: "n2".into(),
                can_id: 0x1f00_0000,
                period: Some(Duration::from_millis(3)),
                from: SimTime::from_ms(200),
                until: Some(SimTime::from_ms(300)),
            }),
        );
        Medium::Can(bus, ports)
    } else {
        let net = PacketNet::new(PacketNetConfig::ground(), 7);
        net.set_trace(tracer);
        let ports = (0..3)
            .map(|i| {
                let (tx, rx) = inbox();
                inboxes.push(rx);
                net.attach(&format!("n{i}"), &[16 + i as u8], i == 0, i == 0, tx, 0)
            })
            .collect();
        net.set_fault(1, Some(lossy));
        Medium::Net(net, ports)
    };
    (medium, inboxes, trace)
}

/// What each endpoint sends and when: several frames at some instants, at odd nanoseconds.
fn traffic(endpoint: usize) -> Vec<SimTime> {
    (0..120u64)
        .filter(|i| (i + endpoint as u64) % 3 != 0)
        .map(|i| SimTime::from_ns(i * 5_300_017 + endpoint as u64 * 1_000_003))
        .collect()
}

impl Medium {
    fn send(&self, endpoint: usize, t: SimTime, n: u64) {
        let to = (endpoint + 1) % 3;
        match self {
            Medium::Can(_, ports) => {
                let id = (3 + endpoint as u32) << 24 | (3 + to as u32) << 19 | (n as u32 & 0x3ff);
                ports[endpoint].send(t, CanFrame::new(id, &n.to_le_bytes()).unwrap());
            }
            Medium::Net(_, ports) => {
                let h = Header::new(16 + endpoint as u8, 16 + to as u8, 10, 20);
                ports[endpoint].send(t, Packet::new(h, vec![n as u8; 40 + (n % 50) as usize]));
            }
        }
    }

    /// The medium's task: from the start, or resumed after a load.
    async fn task(self, clock: Clock, resumed: bool) {
        match (self, resumed) {
            (Medium::Can(bus, _), false) => bus.run(clock).await,
            (Medium::Can(bus, _), true) => bus.resume(clock).await,
            (Medium::Net(net, _), false) => net.run(clock).await,
            (Medium::Net(net, _), true) => net.resume(clock).await,
        }
    }

    /// The medium's and the inboxes' state.
    fn save(&self, inboxes: &[InboxState]) -> Vec<u8> {
        let mut w = snap::Writer::new();
        match self {
            Medium::Can(bus, _) => bus.save(&mut w),
            Medium::Net(net, _) => net.save(&mut w),
        }
        inboxes.iter().for_each(|i| i.save(&mut w));
        w.into_bytes()
    }

    fn load(&mut self, inboxes: &mut [InboxState], bytes: &[u8]) {
        let mut r = snap::Reader::new(bytes);
        match self {
            Medium::Can(bus, _) => bus.load(&mut r).unwrap(),
            Medium::Net(net, _) => net.load(&mut r).unwrap(),
        }
        inboxes.iter_mut().for_each(|i| i.load(&mut r).unwrap());
        r.finish().unwrap();
    }
}

/// What a run gives: the state when it settled at [`SNAP_AT`] (if asked) and how long the
/// trace was then, the state at the end and the whole trace.
struct Outcome {
    at_snap: Option<(Vec<u8>, usize)>,
    end: Vec<u8>,
    trace: Vec<String>,
}

/// Run `kind` to [`END`], from the start or from `from` (a state at [`SNAP_AT`]), taking
/// a snapshot at [`SNAP_AT`] if `snap`.
fn run_medium(kind: &str, from: Option<&[u8]>, snap: bool) -> Outcome {
    let (mut medium, inboxes, trace) = build(kind);
    let mut states: Vec<InboxState> = inboxes.iter().map(InboxRx::state).collect();
    if let Some(bytes) = from {
        medium.load(&mut states, bytes);
    }
    let begin = if from.is_some() {
        SNAP_AT
    } else {
        SimTime::ZERO
    };
    let log = trace.clone();
    let (at_snap, end) = runtime().block_on(async move {
        let clock = Clock::new(ClockMode::Virtual);
        // A restored run's clock starts where the snapshot was taken.
        tokio::time::advance(Duration::from_nanos(begin.as_ns())).await;
        run(clock, async move {
            let _media = spawn(medium.clone().task(clock, from.is_some()));
            let _senders: Vec<_> = (0..3)
                .map(|e| {
                    let m = medium.clone();
                    spawn(async move {
                        let mut timer = Timer::new(clock);
                        for (n, t) in traffic(e).into_iter().enumerate() {
                            if t > begin {
                                timer.sleep_until(t).await;
                                m.send(e, t, n as u64);
                            }
                        }
                    })
                })
                .collect();
            let mut timer = Timer::new(clock);
            let mut at_snap = None;
            if snap && begin < SNAP_AT {
                timer.sleep_until(SNAP_AT).await;
                settled().await;
                let len = log.lock().unwrap().len();
                at_snap = Some((medium.save(&states), len));
            }
            timer.sleep_until(END).await;
            settled().await;
            let end = medium.save(&states);
            drop(inboxes);
            (at_snap, end)
        })
        .await
    });
    let trace = std::mem::take(&mut *trace.lock().unwrap());
    Outcome {
        at_snap,
        end,
        trace,
    }
}

/// A medium saved mid-traffic and loaded into one built fresh goes on as the one it was
/// saved from: the same trace from the snapshot on, the same state at the end; and a run
/// that takes a snapshot is the run that does not.
fn saved_and_loaded_goes_on_the_same(kind: &str) {
    let plain = run_medium(kind, None, false);
    let taken = run_medium(kind, None, true);
    assert_eq!(
        taken.end, plain.end,
        "{kind}: taking a snapshot changes nothing"
    );
    assert_eq!(taken.trace, plain.trace);
    let (snap, len) = taken.at_snap.unwrap();
    assert!(
        len > 20 && len < plain.trace.len() - 20,
        "{kind}: traffic both sides of the snapshot ({len} of {})",
        plain.trace.len()
    );
    let resumed = run_medium(kind, Some(&snap), false);
    assert_eq!(
        resumed.trace,
        plain.trace[len..],
        "{kind}: the trace from the snapshot on"
    );
    assert_eq!(resumed.end, plain.end, "{kind}: the state at the end");
}

#[test]
fn a_can_bus_saved_mid_traffic_and_loaded_into_a_fresh_one_goes_on_the_same() {
    saved_and_loaded_goes_on_the_same("can");
}

#[test]
fn a_packet_network_saved_mid_traffic_and_loaded_into_a_fresh_one_goes_on_the_same() {
    saved_and_loaded_goes_on_the_same("net");
}

/// A state loaded into a bus with another number of endpoints is refused, naming what.
#[test]
fn a_state_of_another_build_of_the_bus_is_refused() {
    let (Medium::Can(bus, _), _, _) = build("can") else {
        unreachable!()
    };
    let bytes = snap::to_bytes(&bus);
    let mut other = CanBus::new(CanBusConfig::new("main"), 7);
    let err = snap::load_from(&mut other, &bytes).unwrap_err();
    assert_eq!(err.to_string(), "Port: 3 saved, 0 built from the scenario");
}
