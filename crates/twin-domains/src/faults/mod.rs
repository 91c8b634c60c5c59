//! Faults: the `[[faults]]` of a scenario, a registry of kinds, and the few mechanisms the
//! runtime applies them with.
//!
//! # A fault kind
//! Each kind is a struct of its own fields ([`FaultKind`]) in one file of this module, with
//! its meaning (`validate`) and what it does (`compile`: actions at instants on the fault
//! timeline, or events on a node's own timeline); the registry at the bottom of this file
//! names it. The fields every fault takes are [`Common`]: `at`, `until` (when it is lifted;
//! default never) and `target` (a medium, a node, or a named outside link). Adding a kind is its file, one line in
//! the registry, and its effect where it happens (the medium, the node's core).
//!
//! # Mechanisms ([`FaultAction`])
//! - media impairments, each fault under its own id: faults on one medium compose
//!   (`bus::impair::ImpairmentSet`);
//! - CAN faults of a bus (`bus::can::CanFault`), by id;
//! - power and hang holds, through the platform's power rules (`platform::power`);
//! - a reboot; a fault of a node's core (`csp::node::NodeFault`);
//! - the UHF link's contact (passes, `crate::comm`);
//! - record only: a fault that a node applies from its own timeline (the FC's sensor and
//!   wheel faults, the EPS's), put on the fault timeline so that the run's log and
//!   recording say when.

pub mod babble;
pub mod battery_fade;
pub mod bit_errors;
pub mod clock;
pub mod media;
pub mod node;
pub mod panel_loss;
pub mod stuck_switch;

use csp::SimTime;
use schemars::JsonSchema;
use serde::Deserialize;
use serde::de::DeserializeOwned;

use twin_core::network::NetworkSpec;
use twin_core::tagged::{Kind, Parsed, Registry, Tagged, schema_of};
use twin_runtime::RunOptions;
use twin_scenario::scenario::{Dur, NodeRef, PathStep, Scenario};

use twin_runtime::control::ControlError;
pub use twin_runtime::faults::{FaultAction, MediumId, TimedFault};

/// The fields every fault takes.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Common {
    /// When it starts.
    pub at: Dur,
    /// When it is lifted (default: never).
    #[serde(default)]
    pub until: Option<Dur>,
    /// The medium (`main`, `payload`, `uhf`), node, or named outside link it acts on.
    pub target: NodeRef,
}

/// The names of [`Common`]'s fields.
pub const COMMON: &[&str] = &["at", "until", "target"];

/// Where a fault is judged and compiled: its place in the scenario and its common fields.
#[derive(Debug)]
pub struct FaultCx<'a> {
    /// Its index in `[[faults]]` (also its id: faults compose by id).
    pub index: usize,
    /// `at`, `until`, `target`.
    pub common: &'a Common,
    /// The network.
    pub net: &'a NetworkSpec,
    /// The whole scenario.
    pub scenario: &'a Scenario,
    label: &'static str,
    /// Injected while the run goes on (`run --control`): its number there.
    live: Option<u32>,
}

impl FaultCx<'_> {
    /// The fault's id.
    pub fn id(&self) -> u32 {
        match self.live {
            Some(n) => twin_runtime::control::LIVE_FAULT_ID_BASE.saturating_add(n),
            None => u32::try_from(self.index).unwrap_or(u32::MAX),
        }
    }
    /// When it starts.
    pub fn at(&self) -> SimTime {
        SimTime::ZERO + self.common.at.0
    }
    /// When it is lifted.
    pub fn until(&self) -> Option<SimTime> {
        self.common.until.map(|u| SimTime::ZERO + u.0)
    }
    /// The medium `target` names, if it names one (a medium of the twin or a named
    /// outside link).
    pub fn medium(&self) -> Option<MediumId> {
        MediumId::of(&self.common.target).or_else(|| self.link().map(MediumId::Link))
    }
    /// The outside link `target` names, if it names one (by its `name`).
    pub fn link(&self) -> Option<u16> {
        match &self.common.target {
            NodeRef::Name(n) => self
                .scenario
                .link_named(n)
                .and_then(|i| u16::try_from(i).ok()),
            NodeRef::Addr(_) => None,
        }
    }
    /// The outside link of the scenario that holds the address `target` names (among its
    /// `addrs`, or a node it `replaces`), whether or not the network has a node there
    /// (`PL12` names the payload program of a scenario whose network has no PL12): the
    /// program behind it is that node.
    pub fn link_holding_target(&self) -> Option<u16> {
        let addr = match &self.common.target {
            NodeRef::Addr(a) => *a,
            NodeRef::Name(n) => (0..=30u8).find(|&a| {
                platform::addr::node_name(a).is_some_and(|m| m.eq_ignore_ascii_case(n))
            })?,
        };
        self.scenario
            .links
            .iter()
            .position(|l| {
                l.addrs.contains(&addr)
                    || l.replaces
                        .iter()
                        .any(|r| self.net.resolve(&NodeRef::Name(r.clone())) == Ok(addr))
            })
            .and_then(|i| u16::try_from(i).ok())
    }
    /// The node `target` names, if it names one.
    pub fn node(&self) -> Result<u8, twin_core::network::NodeRefError> {
        self.net.resolve(&self.common.target)
    }
    /// Whether the node at `addr` sits on CAN bus `bus` (the PC on both).
    pub fn on_bus(&self, addr: u8, bus: MediumId) -> bool {
        use twin_core::network::Role;
        let role = self
            .net
            .nodes
            .iter()
            .find(|n| n.addr == addr)
            .map(|n| n.role);
        match (bus, role) {
            (_, Some(Role::Pc)) => true,
            (MediumId::Payload, Some(Role::Payload)) => true,
            (MediumId::Main, Some(r)) => !matches!(r, Role::Payload | Role::Ground),
            _ => false,
        }
    }
    /// The name of the node `r` names, if it names one (a CAN controller's name).
    pub fn node_name(&self, r: &NodeRef) -> Option<String> {
        let a = self.net.resolve(r).ok()?;
        self.net
            .nodes
            .iter()
            .find(|n| n.addr == a)
            .map(|n| n.name.clone())
    }
    /// The description of the fault in the run's log (`faults[0]: Drop on main`).
    pub fn what(&self) -> String {
        match self.live {
            Some(n) => format!("control[{n}]: {} on {}", self.label, self.common.target),
            None => format!(
                "faults[{}]: {} on {}",
                self.index, self.label, self.common.target
            ),
        }
    }
}

/// What compiling a fault produces: actions on the fault timeline, and changes to the
/// run's options (a node's own timeline).
#[derive(Debug)]
pub struct FaultPlan<'a> {
    timeline: &'a mut Vec<TimedFault>,
    /// The run's options, for faults a node applies from its own timeline.
    pub opts: &'a mut RunOptions,
    what: String,
}

impl FaultPlan<'_> {
    /// `action` at `t`; `suffix` is added to the fault's description (` (lifted)`).
    pub fn at(&mut self, t: SimTime, action: FaultAction, suffix: &str) {
        self.timeline.push(TimedFault {
            at: t,
            action,
            what: format!("{}{suffix}", self.what),
        });
    }

    /// A fault that lasts: `action(true)` at its `at` and, if it is lifted, `action(false)`
    /// at its `until`, described with `lifted` (` (lifted)`).
    pub fn window(&mut self, cx: &FaultCx<'_>, lifted: &str, action: impl Fn(bool) -> FaultAction) {
        self.at(cx.at(), action(true), "");
        if let Some(u) = cx.until() {
            self.at(u, action(false), lifted);
        }
    }
}

/// A kind of fault (see the module doc).
pub trait FaultKind: DeserializeOwned + JsonSchema + std::fmt::Debug + 'static {
    /// Its name in scenarios (`drop`).
    const NAME: &'static str;
    /// Its name in the run's log and recording (`Drop`).
    const LABEL: &'static str;
    /// One line on what it does.
    const ABOUT: &'static str;
    /// Whether it lasts until `until` (`false`: instantaneous, no `until`).
    const LASTS: bool = true;
    /// Whether it can be injected while the run goes on (`run --control`): `false` for a
    /// kind that a node applies from its own timeline, which is set before the run.
    const LIVE: bool = true;
    /// Check its meaning; `err(field, message)`.
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String));
    /// Its actions.
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>);
}

/// A fault of any kind.
trait AnyFault: std::fmt::Debug {
    fn label(&self) -> &'static str;
    fn lasts(&self) -> bool;
    fn live(&self) -> bool;
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String));
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>);
}

impl<K: FaultKind> AnyFault for K {
    fn label(&self) -> &'static str {
        K::LABEL
    }
    fn lasts(&self) -> bool {
        K::LASTS
    }
    fn live(&self) -> bool {
        K::LIVE
    }
    fn validate(&self, cx: &FaultCx<'_>, err: &mut dyn FnMut(&str, String)) {
        FaultKind::validate(self, cx, err)
    }
    fn compile(&self, cx: &FaultCx<'_>, plan: &mut FaultPlan<'_>) {
        FaultKind::compile(self, cx, plan)
    }
}

pub use twin_scenario::entries::FaultEntry;

fn typed<K: FaultKind>(e: &Tagged, what: &str) -> Result<Box<dyn AnyFault>, (String, String)> {
    e.params::<K>(what, COMMON)
        .map(|k| Box::new(k) as Box<dyn AnyFault>)
}

const fn kind<K: FaultKind>() -> Kind<Box<dyn AnyFault>> {
    Kind::new(K::NAME, K::ABOUT, typed::<K>, schema_of::<K>)
}

/// The registry: every fault kind, by name (see the module doc).
static REGISTRY: Registry<Box<dyn AnyFault>> = Registry::new(
    "fault",
    COMMON,
    &[
        kind::<media::Drop>(),
        kind::<media::Corrupt>(),
        kind::<media::Delay>(),
        kind::<media::LinkDown>(),
        kind::<node::PowerOff>(),
        kind::<node::Reboot>(),
        kind::<node::Hang>(),
        kind::<bit_errors::BitErrors>(),
        kind::<babble::Babble>(),
        kind::<panel_loss::PanelLoss>(),
        kind::<battery_fade::BatteryFade>(),
        kind::<stuck_switch::StuckSwitch>(),
        kind::<clock::Clock>(),
    ],
);

/// The JSON schema of an entry: one of the kinds, each with the common fields (the
/// scenario's schema takes it as its `Fault` definition).
pub fn entry_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
    REGISTRY.entry_schema::<Common>(generator)
}

fn parse(e: &FaultEntry) -> Parsed<Common, Box<dyn AnyFault>> {
    REGISTRY.parse(&e.0)
}

/// Check every `[[faults]]` entry; `err(path, message)` for each problem.
pub fn validate(s: &Scenario, net: &NetworkSpec, err: &mut dyn FnMut(Vec<PathStep>, String)) {
    for (i, e) in s.faults.iter().enumerate() {
        let p = |f: &str| {
            vec![
                PathStep::Key("faults".into()),
                PathStep::Index(i),
                PathStep::Key(f.into()),
            ]
        };
        let (common, kind) = match parse(e) {
            Ok(x) => x,
            Err(errs) => {
                for (f, m) in errs {
                    err(p(&f), m);
                }
                continue;
            }
        };
        if common.until.is_some_and(|u| u <= common.at) {
            err(p("until"), "must be after `at`".into());
        }
        if !kind.lasts() && common.until.is_some() {
            err(
                p("until"),
                format!(
                    "a `{}` fault is instantaneous: it takes no `until`",
                    e.0.kind().unwrap_or("")
                ),
            );
        }
        let cx = FaultCx {
            index: i,
            common: &common,
            net,
            scenario: s,
            label: kind.label(),
            live: None,
        };
        kind.validate(&cx, &mut |f, m| err(p(f), m));
    }
}

/// The fault timeline of a validated scenario's `[[faults]]`, in file order (the caller
/// sorts the whole timeline by time); faults a node applies itself go on its own timeline
/// in `opts`.
pub fn compile(s: &Scenario, net: &NetworkSpec, opts: &mut RunOptions) -> Vec<TimedFault> {
    let mut timeline = Vec::new();
    for (i, e) in s.faults.iter().enumerate() {
        let Ok((common, kind)) = parse(e) else {
            continue;
        };
        let cx = FaultCx {
            index: i,
            common: &common,
            net,
            scenario: s,
            label: kind.label(),
            live: None,
        };
        let mut plan = FaultPlan {
            timeline: &mut timeline,
            opts,
            what: cx.what(),
        };
        kind.compile(&cx, &mut plan);
    }
    timeline
}

/// The scenario's fault catalogue for faults injected while its run goes on (`run
/// --control`, `gs fault`): each request judged as a `[[faults]]` entry of the scenario is,
/// and compiled into actions on the fault timeline.
#[derive(Debug)]
pub struct Live {
    scenario: Scenario,
    net: NetworkSpec,
    /// Never changed: the kinds that would change it are not live.
    opts: std::sync::Mutex<RunOptions>,
}

/// [`Live`] for scenario `s`.
pub fn live(s: &Scenario) -> std::sync::Arc<dyn twin_runtime::control::LiveFaults> {
    let net = s.network_spec_unchecked();
    let opts = RunOptions::new(net.clone(), s.duration.0);
    std::sync::Arc::new(Live {
        scenario: s.clone(),
        net,
        opts: std::sync::Mutex::new(opts),
    })
}

impl twin_runtime::control::LiveFaults for Live {
    fn compile(
        &self,
        f: &twin_runtime::control::LiveFault,
    ) -> Result<Vec<TimedFault>, ControlError> {
        let table: toml::Table =
            serde_json::from_value(serde_json::Value::Object(f.fields.clone()))
                .map_err(|e| ControlError::NotAFault(e.to_string()))?;
        let entry = Tagged(table);
        let target = entry
            .0
            .get("target")
            .ok_or(ControlError::NoTarget)?
            .clone()
            .try_into::<NodeRef>()
            .map_err(|e| ControlError::Fields(vec![("target".into(), e.to_string())]))?;
        let kind = REGISTRY
            .kind_of(&entry)
            .map_err(|fm| ControlError::Fields(vec![fm]))?;
        let name = entry.kind().unwrap_or_default().to_owned();
        if !kind.live() {
            return Err(ControlError::NotLive(name));
        }
        if !kind.lasts() && f.until.is_some() {
            return Err(ControlError::Instantaneous(name));
        }
        let common = Common {
            at: Dur(f.at.saturating_since(SimTime::ZERO)),
            until: f.until.map(|u| Dur(u.saturating_since(SimTime::ZERO))),
            target,
        };
        let cx = FaultCx {
            index: self.scenario.faults.len(),
            common: &common,
            net: &self.net,
            scenario: &self.scenario,
            label: kind.label(),
            live: Some(f.n),
        };
        let mut problems = Vec::new();
        kind.validate(&cx, &mut |field, m| problems.push((field.to_owned(), m)));
        if !problems.is_empty() {
            return Err(ControlError::Fields(problems));
        }
        let mut timeline = Vec::new();
        let mut opts = self
            .opts
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut plan = FaultPlan {
            timeline: &mut timeline,
            opts: &mut opts,
            what: cx.what(),
        };
        kind.compile(&cx, &mut plan);
        Ok(timeline)
    }
}
