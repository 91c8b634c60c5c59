//! The UHF radio (CSP 1 and 2): COMM's own application on top of the CSP node that routes
//! between the main CAN bus and the ground segment.
//!
//! What is modelled where:
//! - Routing (COMM1: main CAN <-> UHF) is the CSP node's job, configured by the twin; the
//!   air link itself (9600 bit/s half duplex, delay, impairments, contact only during passes)
//!   is `bus::net`'s, switched by the twin at orbit-predicted rises and sets.
//! - [`CommApp`] (this crate, the same for both radios) adds port 10 ([`wire`]: TMCOMM 1,
//!   BEACONSET 2, BEACONGET 3, BEACON 4), the periodic beacon, and the link state
//!   ([`link`]) computed from the FC's truth (`TruthBoard::latest_before(now)`).
//!
//! # Roles and the radio
//! [`CommRole::Primary`] (COMM1) starts with its radio **active**; [`CommRole::Secondary`]
//! (COMM2) starts on **standby**: it answers port 10 (TMCOMM says standby) and sends no
//! beacon. The [`RADIO_SWITCH`] ([`App::switch`], or [`CommApp::set_active`] directly) is
//! what the twin flips when COMM2 takes the radio link over (COMM1 powered off or failed;
//! see `docs/platform.md`); it is hardware state and survives reboots. Only an active
//! radio beacons.
//!
//! # Beacons
//! An active radio sends a beacon every period (default 60 s, BEACONSET 0 = off, else
//! 10..=3600 s), the first one a period after boot, after a BEACONSET, or after becoming
//! active (the schedule restarts from that instant). The beacon goes to the main ground
//! station (CSP 16, port 10) from COMM's port 10, normal priority, no CRC, whether or not
//! a station is in contact: out of contact the air link loses it (`bus::net`); a ground
//! station does not reply. Its data is `04 | 01 | Beacon` ([`wire::Beacon`], 171 + 2
//! bytes): the BEACON 4 reply sent unsolicited.
//!
//! The transmitter's air time ([`platform::board::Activity::UhfTx`] for COMM1's radio,
//! `UhfTxSecondary` for COMM2's, for the EPS) is charged by the twin from the air channel
//! (`bus::net`'s air tap): every packet a radio sends, beacons and forwarded downlink alike,
//! at its real place on the half-duplex channel.
//! The application only counts its beacons' air time (TMCOMM),
//! `(4 + data) bytes x 8 / rate` (plus the configured framing overhead, 0 by default like
//! `bus::net`).
//!
//! # Reboot
//! Volatile ([`App::reset`]): the beacon sequence (restarts at 1), the period (back to the
//! saved parameter table, PSAVE, or the factory default), the schedule, the "since boot"
//! counters of TMCOMM. The role, the active flag and the run counters
//! ([`CommApp::counters`]) survive.
//!
//! # Platform port 14
//! The parameter table and self-test of [`config`] (`csp::params`): `beacon_period` is the
//! period BEACONGET reads and BEACONSET sets.

pub mod config;
pub mod link;
pub use icd::comm as wire;

use std::time::Duration;

use csp::node::{App, Node};
use csp::reqrep::serve;
use csp::{Packet, SimTime};
use orbit::geodetic::ecef_km_to_geodetic;
use orbit::passes::GroundSite;
use platform::board::TruthBoard;
use platform::truth::TruthSnapshot;

pub use crate::link::{LinkBudget, LinkState, Station};
use crate::wire::Repr;
pub use crate::wire::{Beacon, BeaconPeriod, CommCommand, TmComm};

/// The ports this node binds for its ICD services (INTERPRETATION.md section 4).
pub const PORTS: &[u8] = &[wire::PORT];
/// The main ground station, where beacons go (INTERPRETATION.md section 1).
pub const GROUND_ADDR: u8 = 16;
/// Default beacon period (the brief's; a scenario setting and BEACONSET).
pub const DEFAULT_BEACON_PERIOD: Duration = Duration::from_secs(60);
/// Default UHF data rate, bit/s (issue #7; `bus::net`'s default).
pub const DEFAULT_AIR_RATE_BPS: u32 = 9600;
/// Default elevation mask, deg (issue #7).
pub const DEFAULT_MASK_DEG: f64 = 10.0;

/// Which of the two radios this is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum CommRole {
    /// COMM1 (CSP 1): routes main CAN <-> UHF, radio active.
    #[default]
    Primary,
    /// COMM2 (CSP 2): on the main bus, radio on standby until the twin activates it.
    Secondary,
}

impl CommRole {
    /// The TMCOMM value ([`wire::role`]).
    pub fn to_u8(self) -> u8 {
        match self {
            CommRole::Primary => wire::role::PRIMARY,
            CommRole::Secondary => wire::role::SECONDARY,
        }
    }
}

/// What a COMM needs from the scenario (fixed for the run).
#[derive(Debug, Clone, PartialEq)]
pub struct CommConfig {
    /// Primary (radio active at start) or secondary (standby).
    pub role: CommRole,
    /// COMM's command port, also the beacon's source port (10).
    pub port: u8,
    /// Beacon period at boot (zero: off; else whole seconds, 10..=3600).
    pub beacon_period: Duration,
    /// Ground stations for the link state (the first is the main one).
    pub stations: Vec<Station>,
    /// Elevation mask, deg.
    pub mask_deg: f64,
    /// The downlink budget for the RSSI estimate.
    pub link: LinkBudget,
    /// Where beacons go (16).
    pub ground_addr: u8,
    /// The beacon's destination port (10).
    pub ground_port: u8,
    /// UHF data rate for the beacon's air time, bit/s.
    pub air_rate_bps: u32,
    /// Framing overhead per packet on the air, bytes (as `bus::net`'s).
    pub air_overhead_bytes: u32,
}

impl Default for CommConfig {
    /// COMM1: primary, port 10, 60 s beacons to 16:10, Vilnius with a 10 deg mask.
    fn default() -> Self {
        CommConfig {
            role: CommRole::Primary,
            port: wire::PORT,
            beacon_period: DEFAULT_BEACON_PERIOD,
            stations: vec![Station::vilnius()],
            mask_deg: DEFAULT_MASK_DEG,
            link: LinkBudget::default(),
            ground_addr: GROUND_ADDR,
            ground_port: wire::PORT,
            air_rate_bps: DEFAULT_AIR_RATE_BPS,
            air_overhead_bytes: 0,
        }
    }
}

/// What is wrong with a COMM configuration (for the scenario loader).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CommConfigError {
    /// COMM's own port is in the ephemeral range.
    #[error("COMM port {port} must be below 32")]
    Port {
        /// The port.
        port: u8,
    },
    /// The beacons' port is beyond CSP's ports.
    #[error("beacon port {port} > 63")]
    BeaconPort {
        /// The port.
        port: u8,
    },
    /// The beacons' address is not a ground station's.
    #[error("beacon address {addr} is not a ground station (16-20)")]
    BeaconAddr {
        /// The address.
        addr: u8,
    },
    /// A beacon period BEACONSET could not set.
    #[error(
        "beacon period {period:?}: 0 (off) or whole seconds {}..={}",
        wire::BEACON_PERIOD_MIN_S,
        wire::BEACON_PERIOD_MAX_S
    )]
    BeaconPeriod {
        /// The period.
        period: Duration,
    },
    /// An elevation mask outside -90..=90 deg.
    #[error("elevation mask {mask_deg} deg")]
    Mask {
        /// The mask.
        mask_deg: f64,
    },
    /// A UHF rate of 0 bit/s.
    #[error("UHF rate 0 bit/s")]
    ZeroRate,
    /// A station's latitude or longitude is out of range.
    #[error("station {name}: bad latitude/longitude")]
    Station {
        /// The station's name.
        name: String,
    },
    /// More stations than the telemetry can number.
    #[error("{count} stations (at most 254)")]
    TooManyStations {
        /// How many.
        count: usize,
    },
}

impl CommConfig {
    /// The default configuration with the secondary role (COMM2).
    pub fn secondary() -> Self {
        CommConfig {
            role: CommRole::Secondary,
            ..Self::default()
        }
    }

    /// Check the configuration (for the scenario loader); the message names the problem.
    pub fn validate(&self) -> Result<(), CommConfigError> {
        if self.port >= csp::header::EPHEMERAL_PORT_MIN {
            return Err(CommConfigError::Port { port: self.port });
        }
        if self.ground_port > csp::header::MAX_PORT {
            return Err(CommConfigError::BeaconPort {
                port: self.ground_port,
            });
        }
        if !(16..=20).contains(&self.ground_addr) {
            return Err(CommConfigError::BeaconAddr {
                addr: self.ground_addr,
            });
        }
        let p = self.beacon_period;
        let whole = p.subsec_nanos() == 0;
        let s = p.as_secs();
        let ok_range = s == 0
            || (u64::from(wire::BEACON_PERIOD_MIN_S)..=u64::from(wire::BEACON_PERIOD_MAX_S))
                .contains(&s);
        if !whole || !ok_range {
            return Err(CommConfigError::BeaconPeriod { period: p });
        }
        if !(-90.0..=90.0).contains(&self.mask_deg) {
            return Err(CommConfigError::Mask {
                mask_deg: self.mask_deg,
            });
        }
        if self.air_rate_bps == 0 {
            return Err(CommConfigError::ZeroRate);
        }
        for s in &self.stations {
            if !(-90.0..=90.0).contains(&s.lat_deg) || !s.lon_deg.is_finite() {
                return Err(CommConfigError::Station {
                    name: s.name.clone(),
                });
            }
        }
        if self.stations.len() > usize::from(wire::NO_STATION) {
            return Err(CommConfigError::TooManyStations {
                count: self.stations.len(),
            });
        }
        Ok(())
    }
}

/// Air time of a packet with `data_len` bytes of data: `(4 + data_len + overhead) x 8 /
/// rate`, in integer nanoseconds (rounded down, as `bus::net` does).
pub fn air_time(data_len: usize, rate_bps: u32, overhead_bytes: u32) -> Duration {
    let bits = (csp::header::HEADER_LEN as u64 + data_len as u64 + u64::from(overhead_bytes)) * 8;
    Duration::from_nanos(bits * 1_000_000_000 / u64::from(rate_bps.max(1)))
}

/// Run counters of a COMM (since the start of the run, reboots included).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CommCounters {
    /// Beacons handed to the radio.
    pub beacons_sent: u64,
    /// UHF air time of those beacons.
    pub beacon_air: Duration,
    /// Beacons the node could not send (no route, header): logged as drops.
    pub beacon_failures: u64,
    /// Port 10 requests answered with failure.
    pub refused: u64,
}

/// The radio's hardware switch ([`App::switch`]): on = active, off = standby.
pub const RADIO_SWITCH: csp::node::HwSwitch = csp::node::HwSwitch::Radio;

/// The COMM application (see the module doc).
#[derive(Debug)]
pub struct CommApp {
    cfg: CommConfig,
    sites: Vec<GroundSite>,
    truth: Option<TruthBoard>,
    active: bool,
    /// Became active, or the beacon period parameter changed, since the last timer: arm
    /// the schedule at the next timeout.
    arm_pending: bool,
    period: Duration,
    next_beacon: Option<SimTime>,
    /// Beacons sent since boot (the last sequence number).
    seq: u32,
    air_since_boot: Duration,
    refused_since_boot: u64,
    last_now: SimTime,
    counters: CommCounters,
}

impl CommApp {
    /// A COMM with `cfg` (the radio is active for the primary role).
    pub fn new(cfg: CommConfig) -> Self {
        CommApp {
            sites: cfg.stations.iter().map(Station::site).collect(),
            truth: None,
            active: cfg.role == CommRole::Primary,
            arm_pending: false,
            period: cfg.beacon_period,
            next_beacon: None,
            seq: 0,
            air_since_boot: Duration::ZERO,
            refused_since_boot: 0,
            last_now: SimTime::ZERO,
            counters: CommCounters::default(),
            cfg,
        }
    }

    /// Read the FC's truth from `b` (position, attitude, link geometry).
    pub fn with_truth(mut self, b: TruthBoard) -> Self {
        self.truth = Some(b);
        self
    }

    /// Switch the radio between active (beaconing, on the UHF route) and standby; the
    /// beacon schedule restarts from the next timer (the twin's take-over switch).
    pub fn set_active(&mut self, active: bool) {
        if active == self.active {
            return;
        }
        self.active = active;
        self.arm_pending = active;
        if !active {
            self.next_beacon = None;
        }
    }

    /// Whether the radio is active.
    pub fn is_active(&self) -> bool {
        self.active
    }
    /// The configured role.
    pub fn role(&self) -> CommRole {
        self.cfg.role
    }
    /// The configuration in use.
    pub fn config(&self) -> &CommConfig {
        &self.cfg
    }
    /// The beacon period in effect (zero: off).
    pub fn beacon_period(&self) -> Duration {
        self.period
    }
    /// When the next beacon goes out, if one is scheduled.
    pub fn next_beacon(&self) -> Option<SimTime> {
        self.next_beacon
    }
    /// Beacons sent since boot (the sequence number of the last one).
    pub fn beacons_since_boot(&self) -> u32 {
        self.seq
    }
    /// Run counters.
    pub fn counters(&self) -> &CommCounters {
        &self.counters
    }

    /// The FC's latest truth strictly before `now`.
    pub fn truth_at(&self, now: SimTime) -> Option<TruthSnapshot> {
        self.truth.as_ref()?.latest_before(now)
    }

    /// The link state at `now` from the latest truth; `None` without truth or stations.
    pub fn link_state(&self, now: SimTime) -> Option<LinkState> {
        let t = self.truth_at(now)?;
        self.link_of(&t)
    }

    fn link_of(&self, t: &TruthSnapshot) -> Option<LinkState> {
        link::link_state(
            &self.sites,
            self.cfg.mask_deg,
            &self.cfg.link,
            &link::r_ecef_km(t),
        )
    }

    /// The TMCOMM reply data at `now`.
    pub fn tmcomm(&self, node: &Node, now: SimTime) -> TmComm {
        let link = self.link_state(now);
        let noise = self.cfg.link.noise_dbm() as f32;
        let c = node.counters();
        TmComm {
            role: self.cfg.role.to_u8(),
            radio_active: u8::from(self.active),
            in_contact: u8::from(link.is_some_and(|l| l.in_contact)),
            station: link.map_or(wire::NO_STATION, |l| station_u8(l.station)),
            elevation_deg: link.map_or(0.0, |l| l.elevation_deg as f32),
            azimuth_deg: link.map_or(0.0, |l| l.azimuth_deg as f32),
            range_km: link.map_or(0.0, |l| l.range_km as f32),
            rssi_dbm: link.map_or(noise, |l| l.rssi_dbm as f32),
            snr_db: link.map_or(0.0, |l| l.snr_db as f32),
            uptime_s: sat32(node.uptime(now).as_secs()),
            beacons_sent: self.seq,
            beacon_period_s: period_s(self.period),
            beacon_air_ms: sat32(self.air_since_boot.as_millis() as u64),
            rx_packets: sat32(c.rx_packets),
            tx_packets: sat32(c.tx_packets),
            forwarded: sat32(c.forwarded),
            drops: sat32(c.total_drops()),
            refused: sat32(self.refused_since_boot),
        }
    }

    /// The beacon data at `now` with sequence number `seq`.
    pub fn beacon(&self, node: &Node, now: SimTime, seq: u32) -> Beacon {
        let c = node.counters();
        let utc_ns = node.clock_unix_ns(now).max(0);
        let mut b = Beacon {
            seq,
            utc_s: u32::try_from(utc_ns / 1_000_000_000).unwrap_or(u32::MAX),
            uptime_s: sat32(node.uptime(now).as_secs()),
            flags: if self.cfg.role == CommRole::Secondary {
                wire::BEACON_SECONDARY
            } else {
                0
            },
            station: wire::NO_STATION,
            rx_packets: sat32(c.rx_packets),
            tx_packets: sat32(c.tx_packets),
            forwarded: sat32(c.forwarded),
            drops: sat32(c.total_drops()),
            reboots: u16::try_from(c.reboots).unwrap_or(u16::MAX),
            beacon_period_s: period_s(self.period),
            ..Beacon::default()
        };
        let Some(t) = self.truth_at(now) else {
            return b;
        };
        let f3 = |v: nalgebra::Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
        let r_ecef_km = link::r_ecef_km(&t);
        let geo = ecef_km_to_geodetic(&r_ecef_km);
        let q = t.q_eci_from_body;
        let rpm = 60.0 / std::f64::consts::TAU;
        b.flags |= wire::BEACON_TRUTH_VALID;
        b.truth_utc_s = u32::try_from(t.unix_ns.max(0) / 1_000_000_000).unwrap_or(u32::MAX);
        b.r_eci_km = f3(t.r_eci_m * 1e-3);
        b.v_eci_km_s = f3(t.v_eci_m_s * 1e-3);
        b.lat_deg = geo.lat_deg() as f32;
        b.lon_deg = geo.lon_deg() as f32;
        b.alt_km = (geo.alt_m * 1e-3) as f32;
        b.q_eci_from_body = [q.w as f32, q.i as f32, q.j as f32, q.k as f32];
        b.w_body_deg_s = f3(t.w_body_rad_s.map(f64::to_degrees));
        b.sun_body_unit = f3(q.inverse_transform_vector(&t.sun_eci_unit));
        b.sun_visible_pct = (t.in_eclipse_fraction_visible.clamp(0.0, 1.0) * 100.0).round() as u8;
        b.b_body_nt = f3(q.inverse_transform_vector(&t.b_eci_nt));
        b.wheel_speed_rpm = t.wheel_speed_rad_s.map(|w| (w * rpm) as f32);
        b.mtq_dipole_am2 = t.mtq_dipole_am2.map(|m| m as f32);
        if let Some(l) =
            link::link_state(&self.sites, self.cfg.mask_deg, &self.cfg.link, &r_ecef_km)
        {
            if l.in_contact {
                b.flags |= wire::BEACON_IN_CONTACT;
            }
            b.station = station_u8(l.station);
            b.elevation_deg = l.elevation_deg as f32;
            b.azimuth_deg = l.azimuth_deg as f32;
            b.range_km = l.range_km as f32;
            b.rssi_dbm = l.rssi_dbm as f32;
        }
        b
    }

    fn arm(&mut self, now: SimTime) {
        self.next_beacon = (self.active && !self.period.is_zero()).then(|| now + self.period);
    }

    fn send_beacon(&mut self, node: &mut Node, now: SimTime) {
        let seq = self.seq.wrapping_add(1);
        let data = self.beacon(node, now, seq).to_packet_data();
        let air = air_time(
            data.len(),
            self.cfg.air_rate_bps,
            self.cfg.air_overhead_bytes,
        );
        let header = node.own_header(self.cfg.ground_addr, self.cfg.ground_port);
        match node.send(Packet::new(header, data), now) {
            Ok(()) => {
                self.seq = seq;
                self.air_since_boot += air;
                self.counters.beacons_sent += 1;
                self.counters.beacon_air += air;
            }
            Err(e) => {
                self.counters.beacon_failures += 1;
                node.log_drop(
                    now,
                    csp::drop::DropCause::app(format!("beacon {seq}")),
                    e.to_string(),
                );
            }
        }
    }

    fn execute(&mut self, c: CommCommand, node: &Node, now: SimTime) -> Vec<u8> {
        match c {
            CommCommand::TmComm => self.tmcomm(node, now).to_vec(),
            CommCommand::BeaconSet(p) => {
                self.period = Duration::from_secs(u64::from(p.period_s));
                self.arm(now);
                Vec::new()
            }
            CommCommand::BeaconGet => BeaconPeriod {
                period_s: period_s(self.period),
            }
            .to_vec(),
            CommCommand::Beacon => self.beacon(node, now, self.seq).to_vec(),
        }
    }
}

fn sat32(v: u64) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

fn period_s(p: Duration) -> u16 {
    u16::try_from(p.as_secs()).unwrap_or(u16::MAX)
}

fn station_u8(i: usize) -> u8 {
    u8::try_from(i).unwrap_or(wire::NO_STATION)
}

impl App for CommApp {
    type Event = std::convert::Infallible;
    fn start(&mut self, node: &mut Node, now: SimTime) {
        node.bind(self.cfg.port);
        self.last_now = now;
        self.arm_pending = false;
        self.arm(now);
    }

    fn handle_packet(&mut self, node: &mut Node, packet: Packet, now: SimTime) {
        self.last_now = self.last_now.max(now);
        if packet.header.dport != self.cfg.port {
            return;
        }
        // A payload may read the COMM, not set its beacon (ICD 4.1).
        let open = [wire::cmd::TMCOMM, wire::cmd::BEACONGET];
        let (reply, refused) = match csp::node::payload_refusal(node, &packet, &open, now) {
            Some(r) => {
                self.refused_since_boot += 1;
                self.counters.refused += 1;
                (r, None)
            }
            None => serve::<CommCommand>(&packet.data, |c| Ok(self.execute(c, node, now))),
        };
        if let Some(e) = refused {
            self.refused_since_boot += 1;
            self.counters.refused += 1;
            node.log(now, format!("comm port {}: refused: {e}", self.cfg.port));
        }
        if let Err(e) = node.send(Packet::new(packet.header.reply(node.addr()), reply), now) {
            node.log_drop(now, csp::drop::DropCause::app("comm reply"), e.to_string());
        }
    }

    fn poll_timeout(&self) -> Option<SimTime> {
        if self.arm_pending {
            return Some(self.last_now);
        }
        self.next_beacon
    }

    fn handle_timeout(&mut self, node: &mut Node, now: SimTime) {
        self.last_now = self.last_now.max(now);
        if self.arm_pending {
            self.arm_pending = false;
            self.arm(now);
        }
        let Some(due) = self.next_beacon.filter(|&t| t <= now) else {
            return;
        };
        self.send_beacon(node, now);
        // Keep the phase; a driver that wakes late sends one beacon, not a burst.
        if self.period.is_zero() {
            self.next_beacon = None;
            return;
        }
        let mut next = due + self.period;
        while next <= now {
            next = next + self.period;
        }
        self.next_beacon = Some(next);
    }

    fn switch(
        &mut self,
        _node: &mut Node,
        switch: csp::node::HwSwitch,
        to: csp::node::SwitchPosition,
        now: SimTime,
    ) {
        if switch == RADIO_SWITCH {
            self.last_now = self.last_now.max(now);
            self.set_active(to.is_on());
            if self.arm_pending {
                self.arm_pending = false;
                self.arm(now);
            }
        }
    }

    fn params(&mut self) -> Option<&mut dyn csp::params::Table> {
        Some(self)
    }

    fn console_commands(&self) -> &'static [csp::console::Command] {
        &[csp::console::TM]
    }

    fn console(
        &mut self,
        node: &mut Node,
        words: &[&str],
        now: SimTime,
    ) -> Result<String, csp::console::ConsoleError> {
        if words != ["tm"] {
            return Err(csp::console::ConsoleError::Usage("tm".to_owned()));
        }
        self.last_now = self.last_now.max(now);
        // As TMCOMM on port 10 at `now`.
        csp::console::layout(&self.tmcomm(node, now))
    }

    fn self_test(&mut self, _node: &Node, now: SimTime) -> Vec<csp::params::Check> {
        self.checks(now)
    }

    fn reset(&mut self, now: SimTime) {
        self.period = self.cfg.beacon_period;
        self.next_beacon = None;
        self.arm_pending = false;
        self.seq = 0;
        self.air_since_boot = Duration::ZERO;
        self.refused_since_boot = 0;
        self.last_now = now;
    }
}

/// The node's application with the default (primary) configuration and no truth.
pub fn app() -> CommApp {
    CommApp::new(CommConfig::default())
}

// What a snapshot keeps of COMM (docs/snapshots.md): its configuration (the parameters
// change the beacon period, the ground address and the EIRP), the radio's state, the beacon
// schedule and counts. The sites are the stations' (which the run never changes), the truth
// board the run's.
snap::unit_enum!(CommRole { Primary, Secondary });
snap::fields!(CommConfig {
    role,
    port,
    beacon_period,
    stations,
    mask_deg,
    link,
    ground_addr,
    ground_port,
    air_rate_bps,
    air_overhead_bytes
});
snap::fields!(CommCounters {
    beacons_sent,
    beacon_air,
    beacon_failures,
    refused
});
snap::fields!(CommApp {
    cfg,
    active,
    arm_pending,
    period,
    next_beacon,
    seq,
    air_since_boot,
    refused_since_boot,
    last_now,
    counters;
    skip sites, truth
});

#[cfg(test)]
mod tests;
