//! Building the network of a run: the media (both CAN buses and the ground segment with the
//! UHF air channel), the trace every medium hands the run, the boards, and every node of
//! [`twin_core::network::NetworkSpec`] as its own task, its application's events turned into
//! [`RunEvent`]s.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use bus::driver::{Attachment, CtlTx, NodeCore, SharedCore, run_node_with};
use bus::exec::Start;
use bus::inbox::{InboxTx, inbox};
use bus::outside::Segments;
use bus::trace::TraceTx;
use bus::{CanBus, CanBusConfig, Clock, PacketNet, PacketNetConfig};
use csp::SimTime;
use csp::node::{App, Host, MapEvents};
use platform::board::Boards;
use tokio::sync::mpsc;

use super::{RunOptions, mix};
use crate::ground::{GroundApp, Recurring};
use twin_core::events::RunEvent;
use twin_core::network::{Medium, NodeSpec, Role, node_config};

/// The media of a run, with their tasks started and their trace going to `events`.
pub(super) fn media(
    opts: &RunOptions,
    clock: Clock,
    events: &mpsc::UnboundedSender<RunEvent>,
    start: Start,
) -> (Segments, Vec<bus::exec::JoinHandle<()>>) {
    let ev_tx = events;
    let segs = Segments {
        main: CanBus::new(
            CanBusConfig {
                name: "main".into(),
                bitrate_bps: opts.network.main_bitrate_bps,
                tx_queue_frames: opts.network.can_tx_queue_frames,
            },
            mix(opts.seed, 0x100),
        ),
        payload: CanBus::new(
            CanBusConfig {
                name: "payload".into(),
                bitrate_bps: opts.network.payload_bitrate_bps,
                tx_queue_frames: opts.network.can_tx_queue_frames,
            },
            mix(opts.seed, 0x101),
        ),
        ground: PacketNet::new(
            PacketNetConfig {
                air_rate_bps: opts.network.uhf_rate_bps,
                air_buffer_bytes: opts.network.uhf_tx_buffer_bytes,
                ..PacketNetConfig::ground()
            },
            mix(opts.seed, 0x102),
        ),
    };
    let tracer = {
        let tx = ev_tx.clone();
        TraceTx::new(move |e| {
            let _ = tx.send(RunEvent::Medium(e));
        })
    };
    segs.main.set_trace(tracer.clone());
    segs.payload.set_trace(tracer.clone());
    segs.ground.set_trace(tracer);
    let background = match start {
        Start::Fresh => vec![
            bus::exec::spawn(segs.main.clone().run(clock)),
            bus::exec::spawn(segs.payload.clone().run(clock)),
            bus::exec::spawn(segs.ground.clone().run(clock)),
        ],
        Start::Resumed => vec![
            bus::exec::spawn(segs.main.clone().resume(clock)),
            bus::exec::spawn(segs.payload.clone().resume(clock)),
            bus::exec::spawn(segs.ground.clone().resume(clock)),
        ],
    };
    (segs, background)
}

/// A node's task: its spec, its control channel, its core (shared with the task) and the
/// task.
pub(super) struct NodeTask {
    pub(super) spec: NodeSpec,
    pub(super) ctl: CtlTx,
    pub(super) core: SharedCore<NodeApp>,
    pub(super) handle: bus::exec::JoinHandle<()>,
}

/// The nodes of a run, each booted and running as its own task.
pub(super) struct Nodes {
    /// In start order.
    pub(super) tasks: Vec<NodeTask>,
    /// The COMMs' attachments (for the radio take-over).
    pub(super) comm_ports: Vec<(u8, Vec<Attachment>)>,
    /// The nodes built only for their saved state to load into, and their attachments: an
    /// outside program takes their place in this run from a snapshot
    /// ([`Nodes::hand_over_replaced`]).
    replaced_later: Vec<(u8, Vec<Attachment>)>,
    /// Every node built, in build order (those handed over included: their places on the
    /// media stay, and a snapshot of this run says so).
    pub(super) built: Vec<u8>,
    /// Those handed over to outside programs.
    pub(super) handed_over: Vec<u8>,
}

impl Nodes {
    /// The nodes an outside program replaces in this run from a snapshot leave, once the
    /// snapshot has loaded: their tasks end before they first run, their endpoints give
    /// back their addresses for the program's link to claim (their places on the media
    /// stay, with what they counted). What they had under way ends with them, as a
    /// node's does when it is swapped for another at that instant.
    pub(super) fn hand_over_replaced(&mut self) {
        for (addr, ports) in std::mem::take(&mut self.replaced_later) {
            ports.iter().for_each(Attachment::release);
            self.handed_over.push(addr);
            self.tasks.retain(|t| {
                let leaves = t.spec.addr == addr;
                if leaves {
                    t.handle.abort();
                    tracing::info!(
                        "{}: an outside program takes its place from the snapshot on",
                        t.spec.name
                    );
                }
                !leaves
            });
            self.comm_ports.retain(|(a, _)| *a != addr);
        }
    }

    /// Every node's control channel by address.
    pub(super) fn ctls(&self) -> BTreeMap<u8, CtlTx> {
        self.tasks
            .iter()
            .map(|n| (n.spec.addr, n.ctl.clone()))
            .collect()
    }
}

/// The FC's configuration in the run `opts`: the scenario's, with the run's epoch, TLE,
/// the FC's seed and the run's (TWINSIM reports it).
pub fn fc_config(opts: &RunOptions) -> nodes_fc::FcConfig {
    nodes_fc::FcConfig {
        epoch_unix_s: opts.epoch_unix_s,
        tle: opts.tle.clone(),
        seed: mix(opts.seed, 0x300),
        run_seed: opts.seed,
        ..opts.fc.clone()
    }
}

/// Boot every node of `opts.network` on `segs` and start its task: those an outside
/// program replaces are not built, but for those in `replaced_later` (a run from a
/// snapshot whose run had them).
pub(super) fn nodes(
    opts: &mut RunOptions,
    segs: &Segments,
    clock: Clock,
    boards: &Boards,
    events: &mpsc::UnboundedSender<RunEvent>,
    start: Start,
    replaced_later: &std::collections::BTreeSet<u8>,
) -> Nodes {
    let ev_tx = events;

    opts.fc = fc_config(opts);
    let mut comm_ports = Vec::new();
    // The secondary COMM's radio: its air time is its own transmitter's.
    let mut secondary_radios = Vec::new();
    let mut nodes = Vec::new();
    let mut later = Vec::new();
    let mut built = Vec::new();
    for spec in &opts.network.nodes {
        if opts.replaced.contains(&spec.addr) && !replaced_later.contains(&spec.addr) {
            // An outside program takes its place (`replaces` on a link): never attached, so
            // its address is free for that link to claim.
            tracing::info!("{}: replaced by an outside program, not started", spec.name);
            continue;
        }
        let (mut cfg, media) = node_config(spec);
        let salt = u64::from(spec.addr);
        cfg.cfp_first_ident = (mix(opts.seed, salt) % 1024) as u16;
        cfg.first_ephemeral_port = super::first_ephemeral_port(opts.seed, spec.addr);
        cfg.epoch_unix_s = opts.epoch_unix_s;
        cfg.payload_access = opts.payload_access;
        let (inbox_tx, inbox_rx) = inbox();
        let ports = attach(spec, &media, segs, &inbox_tx);
        drop(inbox_tx);
        if replaced_later.contains(&spec.addr) {
            later.push((spec.addr, ports.clone()));
        }
        built.push(spec.addr);
        let plan = opts.ground_plan.remove(&spec.addr).unwrap_or_default();
        let mut app = app_for(spec.role, spec.addr, opts, boards, plan);
        // The scenario's parameter values are the node's factory values.
        if let (Some(values), Some(table)) = (opts.params.get(&spec.addr), app.params()) {
            for e in csp::params::apply(table, values) {
                tracing::warn!("{}: parameter from the scenario refused: {e}", spec.name);
            }
        }
        // Every node boots at the start of the run (in real time, not when its task is made).
        let mut host = Host::new(cfg, app, SimTime::ZERO);
        // What it reported at boot (the EPS's channels configured off) goes out now, in
        // node order, before any task runs; a run from a snapshot had it long ago.
        while let Some(e) = host.app.poll_event() {
            if start == Start::Fresh {
                let _ = ev_tx.send(e);
            }
        }
        let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
        if matches!(spec.role, Role::CommPrimary | Role::CommSecondary) {
            comm_ports.push((spec.addr, ports.clone()));
        }
        if spec.role == Role::CommSecondary {
            secondary_radios.extend(ports.iter().filter_map(|p| match p {
                Attachment::Net(n) => Some(n.id()),
                Attachment::Can(_) => None,
            }));
        }
        let out = ev_tx.clone();
        let core = Arc::new(Mutex::new(NodeCore::new(host, &inbox_rx)));
        let handle = bus::exec::spawn(run_node_with(
            core.clone(),
            ports,
            inbox_rx,
            ctl_rx,
            clock,
            out,
        ));
        nodes.push(NodeTask {
            spec: spec.clone(),
            ctl: ctl_tx,
            core,
            handle,
        });
    }

    charge_air_time(segs, boards, secondary_radios, ev_tx);

    Nodes {
        tasks: nodes,
        comm_ports,
        replaced_later: later,
        built,
        handed_over: Vec::new(),
    }
}

/// A node's ports on its media, in the order of `media` (its CSP interfaces), delivering
/// into its inbox.
fn attach(
    spec: &NodeSpec,
    media: &[Medium],
    segs: &Segments,
    inbox_tx: &InboxTx,
) -> Vec<Attachment> {
    media
        .iter()
        .enumerate()
        .map(|(i, m)| match m {
            Medium::MainCan => Attachment::Can(segs.main.attach(
                &spec.name,
                &[spec.addr],
                false,
                inbox_tx.clone(),
                i,
            )),
            Medium::PayloadCan => Attachment::Can(segs.payload.attach(
                &spec.name,
                &[spec.addr],
                false,
                inbox_tx.clone(),
                i,
            )),
            Medium::GroundRadio | Medium::GroundRadioStandby => {
                Attachment::Net(segs.ground.attach(
                    &format!("{}-uhf", spec.name),
                    &[],
                    true,
                    *m == Medium::GroundRadio,
                    inbox_tx.clone(),
                    i,
                ))
            }
            Medium::Ground => Attachment::Net(segs.ground.attach(
                &spec.name,
                &[spec.addr],
                false,
                false,
                inbox_tx.clone(),
                i,
            )),
        })
        .collect()
}

/// Charge every radio transmission to its COMM's transmitter, at its place on the air. Set
/// once the radios are attached, before any node's task has run.
fn charge_air_time(
    segs: &Segments,
    boards: &Boards,
    secondary_radios: Vec<bus::net::EndpointId>,
    ev_tx: &mpsc::UnboundedSender<RunEvent>,
) {
    let activity = boards.activity.clone();
    let log = ev_tx.clone();
    segs.ground
        .set_air_tap(bus::net::AirTap::new(move |id, radio, start, end| {
            use platform::board::Activity;
            let what = if secondary_radios.contains(&id) {
                Activity::UhfTxSecondary
            } else {
                Activity::UhfTx
            };
            for (t, on) in [(start, true), (end, false)] {
                if let Err(e) = activity.set(what, t, on) {
                    tracing::warn!(%t, "{radio}: air time not charged: {e}");
                    let _ = log.send(RunEvent::Log {
                        t,
                        source: "run".to_owned(),
                        level: twin_core::events::Level::Warning,
                        message: format!("{radio}: air time: {e}"),
                    });
                }
            }
        }));
}

/// A node's application, its events turned into [`RunEvent`]s (`twin_core::events`).
pub(super) type NodeApp = Box<dyn RunApp>;

/// An application of a run's node: its events are [`RunEvent`]s, and it saves its state
/// for snapshots.
pub(super) trait RunApp: App<Event = RunEvent> + snap::Snap {}

impl<T: App<Event = RunEvent> + snap::Snap> RunApp for T {}

/// The application's own state.
impl snap::Snap for Box<dyn RunApp> {
    fn save(&self, w: &mut snap::Writer) {
        (**self).save(w);
    }
    fn load(&mut self, r: &mut snap::Reader<'_>) -> Result<(), snap::SnapError> {
        (**self).load(r)
    }
}

fn app_for(
    role: Role,
    addr: u8,
    opts: &RunOptions,
    boards: &Boards,
    plan: Vec<Recurring>,
) -> NodeApp {
    match role {
        Role::CommPrimary | Role::CommSecondary => {
            let mut cfg = if role == Role::CommPrimary {
                opts.comm.clone()
            } else {
                nodes_comm::CommConfig {
                    role: nodes_comm::CommRole::Secondary,
                    ..opts.comm.clone()
                }
            };
            cfg.air_rate_bps = opts.network.uhf_rate_bps;
            let app = nodes_comm::CommApp::new(cfg).with_truth(boards.truth.clone());
            Box::new(MapEvents::new(app, |never| match never {}))
        }
        Role::Fc => Box::new(MapEvents::new(
            nodes_fc::FcApp::new(opts.fc.clone())
                .with_truth_board(boards.truth.clone())
                .with_burns(boards.burns.clone()),
            RunEvent::from,
        )),
        // Its channel switches go to the platform's power rules in the main loop.
        Role::Eps => Box::new(MapEvents::new(
            nodes_eps::EpsApp::new(opts.eps.clone())
                .with_truth(boards.truth.clone())
                .with_activity(boards.activity.clone()),
            RunEvent::from,
        )),
        Role::Ecu => Box::new(MapEvents::new(
            nodes_ecu::EcuApp::new(opts.ecu.clone())
                .with_burns(boards.burns.clone())
                .with_activity(boards.activity.clone()),
            RunEvent::from,
        )),
        Role::Pc => Box::new(MapEvents::new(
            nodes_pc::PcApp::new(opts.pc.clone()).with_activity(boards.activity.clone()),
            RunEvent::from,
        )),
        Role::Payload => {
            let cfg = opts.payloads.get(&addr).cloned().unwrap_or_default();
            Box::new(MapEvents::new(
                nodes_payload::PayloadApp::new(cfg),
                move |out| RunEvent::Payload { addr, out },
            ))
        }
        Role::Ground => Box::new(GroundApp::new(plan)),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use std::time::Duration;

    use csp::cfp::Fragmenter;
    use csp::node::IfaceKind;
    use csp::{Header, Packet};

    use super::*;
    use twin_core::network::NetworkSpec;

    /// Every node type of the twin, as the run builds it, given packets whose source and
    /// destination are its own address, from each service port to each service port, on
    /// each of its interfaces: answered or dropped, never a crash (each answer is a new
    /// request to itself: served through the queue, never by recursion), and the node still
    /// answers a ping from another node after.
    #[test]
    fn every_node_type_survives_self_addressed_service_packets() {
        let net = NetworkSpec::m6p(&[12, 13, 14, 15], &[16, 17]);
        let opts = RunOptions::new(net.clone(), Duration::from_secs(60));
        let boards = Boards::default();
        let mut roles = Vec::new();
        for spec in &net.nodes {
            if roles.contains(&spec.role) {
                continue;
            }
            roles.push(spec.role);
            let (cfg, _) = node_config(spec);
            let ifaces: Vec<IfaceKind> = cfg.ifaces.iter().map(|i| i.kind).collect();
            let app = app_for(spec.role, spec.addr, &opts, &boards, Vec::new());
            let mut host = Host::new(cfg, app, SimTime::ZERO);
            let mut t = SimTime::ZERO;
            for (iface, kind) in ifaces.iter().enumerate() {
                for sport in 0..=6u8 {
                    for dport in 0..=6u8 {
                        t = t + Duration::from_millis(1);
                        let mut h = Header::new(spec.addr, spec.addr, dport, sport);
                        h.flags = 0;
                        let p = Packet::new(h, vec![sport, dport, 0, 0, 0, 0, 0, 0]);
                        deliver(&mut host, iface, *kind, &p, t);
                        while host.node.poll_transmit().is_some() {}
                        while host.poll_event().is_some() {}
                    }
                }
            }
            // Still answering: a ping from an address of the node's own segment.
            let from = if spec.role == Role::Ground { 17 } else { 3 };
            let from = if from == spec.addr { 4 } else { from };
            let before = host.node.counters().service_replies;
            t = t + Duration::from_millis(1);
            let ping = Packet::new(Header::new(from, spec.addr, 1, 40), vec![7]);
            deliver(&mut host, 0, ifaces[0], &ping, t);
            assert_eq!(
                host.node.counters().service_replies,
                before + 1,
                "{}: {:?}",
                spec.name,
                host.node.counters()
            );
        }
        assert_eq!(roles.len(), 8, "every role: {roles:?}");
    }

    fn deliver(host: &mut Host<NodeApp>, iface: usize, kind: IfaceKind, p: &Packet, t: SimTime) {
        match kind {
            IfaceKind::Can => {
                let mut frames = Vec::new();
                Fragmenter::new(7, csp::cfp::CSP_CAN_MTU)
                    .fragment(p, p.header.dst, &mut frames)
                    .unwrap();
                for f in &frames {
                    host.handle_frame(iface, f, t);
                }
            }
            IfaceKind::Packet => host.handle_packet(iface, p.clone(), t),
        }
    }
}
