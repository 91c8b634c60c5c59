//! The `field` expectation: a field of an ICD reply, decoded from the run's traffic, over
//! time (`field = "FC.TMGEN.current_mode"`, `equals = "idle"`, `when = "eventually"`).
//!
//! It reads every successful reply of the command that crosses a medium of the run (the
//! scenario's requests, a ground program's, the FC's periodic telemetry, the PC's own
//! polls), decoded with the ICD on the run's ports ([`twin_core::icd::IcdMap`]). A reply of a
//! node of the twin counts once, on the medium it leaves that node by (a reply the COMM
//! forwards to the ground is the same reply); one from an outside program counts on each
//! medium it crosses, which changes no verdict. See docs/scenarios.md ("Fields over time").

use csp::SimTime;
use csp::icd::{Field, Value};
use schemars::JsonSchema;
use serde::Deserialize;

use crate::expectations::{CheckCx, ExpectCx, ExpectKind, Grade, Judgement, Watch, WatchCx};
use twin_core::events::RunEvent;
use twin_core::icd::{Direction, IcdMap};
use twin_core::network::NetworkSpec;
use twin_scenario::scenario::Dur;

/// A value to compare with: a number, or the name the ICD gives a value (`"idle"`).
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum FieldValue {
    /// A number.
    Number(f64),
    /// A value's name.
    Name(String),
}

/// Which replies must hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum FieldWhen {
    /// Every reply in the window (at least one).
    #[default]
    Always,
    /// At least one reply in the window.
    Eventually,
    /// The latest reply at or before `at`.
    At,
}

/// `field`: a field of an ICD reply equals a value, or lies above / below bounds, in
/// every reply of a window, in one of them, or in the latest at an instant.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FieldExpect {
    /// `NODE.COMMAND.FIELD` with the field's path in the reply (`FC.TMGEN.current_mode`,
    /// `PC.TMPC.slots[0].state`, `FC.TMALL.general.current_mode`; `m6p-twin icd` lists them).
    pub field: String,
    /// The value it must have: a number or the ICD's name for it.
    #[serde(default)]
    pub equals: Option<FieldValue>,
    /// Lower bound (exclusive).
    #[serde(default)]
    pub above: Option<f64>,
    /// Upper bound (exclusive).
    #[serde(default)]
    pub below: Option<f64>,
    /// `always` (default: every reply in the window, and at least one), `eventually` (one
    /// of them) or `at` (the latest reply at or before `at`).
    #[serde(default)]
    pub when: FieldWhen,
    /// The instant of `when = "at"`.
    #[serde(default)]
    pub at: Option<Dur>,
    /// Start of the window (default: the start of the run).
    #[serde(default)]
    pub from: Option<Dur>,
    /// End of the window (default: the end of the run).
    #[serde(default)]
    pub to: Option<Dur>,
    /// Only replies from this address (the COMMs are 1 and 2); default any of the node's.
    #[serde(default)]
    pub src: Option<u8>,
}

/// The resolved `field`: the command, the leaf and the value as a number.
#[derive(Debug, Clone)]
struct Target {
    node: &'static str,
    command: &'static str,
    path: String,
    leaf: &'static Field,
    equals: Option<f64>,
}

impl FieldExpect {
    /// Resolve `field` and `equals` against the ICD; `Err((field, message))`.
    fn target(&self) -> Result<Target, (&'static str, String)> {
        let mut parts = self.field.splitn(3, '.');
        let (Some(node), Some(cmd), Some(path)) = (parts.next(), parts.next(), parts.next()) else {
            return Err((
                "field",
                format!(
                    "`{}` is not NODE.COMMAND.FIELD (for example FC.TMGEN.current_mode)",
                    self.field
                ),
            ));
        };
        let (n, _, c) = twin_core::icd::find_command(&format!("{node}.{cmd}"))
            .map_err(|e| ("field", e.to_string()))?;
        let leaves = c
            .reply
            .parts()
            .map(|(fields, _)| csp::icd::leaves(fields))
            .unwrap_or_default();
        let Some((path, leaf)) = leaves.iter().find(|(p, _)| p == path) else {
            let names: Vec<&str> = leaves.iter().map(|(p, _)| p.as_str()).collect();
            return Err((
                "field",
                if names.is_empty() {
                    format!("{}.{}'s reply has no fields", n.name, c.name)
                } else {
                    format!(
                        "{}.{}'s reply has no field `{path}`: {}",
                        n.name,
                        c.name,
                        names.join(", ")
                    )
                },
            ));
        };
        if leaf.text {
            return Err(("field", format!("`{path}` is text, not a number")));
        }
        let equals = match &self.equals {
            None => None,
            Some(FieldValue::Number(x)) => Some(*x),
            Some(FieldValue::Name(s)) => {
                let v = leaf
                    .values
                    .iter()
                    .find(|(_, name)| twin_core::icd::value_name_is(name, s));
                match v {
                    Some((k, _)) => Some(*k as f64),
                    None => {
                        let names: Vec<&str> = leaf.values.iter().map(|(_, n)| *n).collect();
                        return Err((
                            "equals",
                            if names.is_empty() {
                                format!("`{s}`: `{path}` has no named values; give a number")
                            } else {
                                format!("`{s}` is not a value of `{path}`: {}", names.join(", "))
                            },
                        ));
                    }
                }
            }
        };
        Ok(Target {
            node: n.name,
            command: c.name,
            path: path.clone(),
            leaf,
            equals,
        })
    }

    fn holds(&self, t: &Target, x: f64) -> bool {
        t.equals.is_none_or(|e| x == e)
            && self.above.is_none_or(|a| x > a)
            && self.below.is_none_or(|b| x < b)
    }

    /// What the value must be, as the verdict says it.
    fn wanted(&self, t: &Target) -> String {
        let mut w = Vec::new();
        if let Some(e) = t.equals {
            w.push(format!("= {}", show(t.leaf, e)));
        }
        if let Some(a) = self.above {
            w.push(format!("> {a}"));
        }
        if let Some(b) = self.below {
            w.push(format!("< {b}"));
        }
        w.join(" and ")
    }
}

/// `3 (nadir)`, `1.5 V`.
fn show(leaf: &Field, x: f64) -> String {
    let mut s = format!("{x}");
    if !leaf.unit.is_empty() {
        s.push(' ');
        s.push_str(leaf.unit);
    }
    if let Some((_, name)) = leaf.values.iter().find(|(k, _)| *k as f64 == x) {
        s.push_str(&format!(" ({name})"));
    }
    s
}

impl ExpectKind for FieldExpect {
    const NAME: &'static str = "field";
    const ABOUT: &'static str = "a field of an ICD reply (`FC.TMGEN.current_mode`) equals a value or lies above / below bounds: always, eventually, or at an instant";

    fn validate(&self, cx: &ExpectCx<'_>, err: &mut dyn FnMut(&str, String)) {
        if let Err((f, m)) = self.target() {
            err(f, m);
        }
        if self.equals.is_none() && self.above.is_none() && self.below.is_none() {
            err(
                "kind",
                "a `field` expectation needs `equals`, `above` or `below`".into(),
            );
        }
        match (self.when, self.at) {
            (FieldWhen::At, None) => err("at", "`when = \"at\"` needs `at`".into()),
            (FieldWhen::At, Some(at)) if at.0 > cx.scenario.duration.0 => err(
                "at",
                format!(
                    "after the end of the run ({})",
                    twin_core::duration::format_duration(cx.scenario.duration.0)
                ),
            ),
            (FieldWhen::Always | FieldWhen::Eventually, Some(_)) => {
                err("at", "only `when = \"at\"` takes `at`".into());
            }
            _ => {}
        }
        if self.when == FieldWhen::At && (self.from.is_some() || self.to.is_some()) {
            err(
                "from",
                "`when = \"at\"` looks at one instant: no `from` or `to`".into(),
            );
        }
        cx.window(self.from, self.to, err);
    }

    fn check(&self, _cx: &CheckCx<'_>) -> Judgement {
        // The replies are read from the run's traffic as it goes (`watch`); a report
        // keeps no packets to judge from afterwards.
        Judgement::fail(
            SimTime::ZERO,
            "a `field` expectation is judged while the run goes",
        )
    }

    fn watch(&self, cx: &WatchCx<'_>) -> Option<Box<dyn Watch>> {
        let target = self.target().ok()?;
        let net = cx.net.cloned().unwrap_or_else(NetworkSpec::default_m6p);
        let icd = cx.icd.cloned().unwrap_or_else(IcdMap::defaults);
        Some(Box::new(FieldWatch {
            expect: self.clone(),
            target,
            icd,
            net,
            tally: Tally::default(),
        }))
    }

    fn describe(&self) -> String {
        self.field.clone()
    }
}

/// What a `field` expectation saw of its replies in the window.
#[derive(Debug, Default)]
struct Tally {
    n: u64,
    /// The first reply that held (eventually) or failed (always): when, its value.
    first_held: Option<(SimTime, f64)>,
    first_failed: Option<(SimTime, f64)>,
    /// The latest reply (at: at or before the instant).
    last: Option<(SimTime, f64)>,
    lo: f64,
    hi: f64,
}

#[derive(Debug)]
struct FieldWatch {
    expect: FieldExpect,
    target: Target,
    icd: IcdMap,
    net: NetworkSpec,
    tally: Tally,
}

impl FieldWatch {
    /// The value of the watched field in the reply event `ev` completes, if any.
    fn value(&mut self, ev: &RunEvent) -> Option<(SimTime, f64)> {
        let RunEvent::Packet(m) = ev else { return None };
        let p = &m.packet;
        let h = &p.header;
        if self.expect.src.is_some_and(|s| s != h.src) {
            return None;
        }
        // A twin node's reply counts on its first hop only.
        if let Some(n) = self.net.nodes.iter().find(|n| n.addr == h.src)
            && *n.name != *m.from
        {
            return None;
        }
        let body = if h.has_crc() && p.data.len() >= 4 {
            &p.data[..p.data.len() - 4]
        } else {
            &p.data[..]
        };
        let d = self.icd.decode(h, body)?;
        if d.direction != Direction::Reply
            || d.result != Some(csp::reqrep::RESULT_SUCCESS)
            || d.node != self.target.node
            || d.command != self.target.command
        {
            return None;
        }
        let f = d.fields.iter().find(|f| f.path == self.target.path)?;
        match f.value {
            Value::Int(i) => Some((m.t, i as f64)),
            Value::Float(x) => Some((m.t, x)),
            Value::Text(_) => None,
        }
    }
}

impl Watch for FieldWatch {
    fn kinds(&self) -> twin_core::events::Kinds {
        twin_core::events::Kinds::of(&[twin_core::events::EventKind::Packet])
    }

    fn observe(&mut self, ev: &RunEvent) {
        let Some((t, x)) = self.value(ev) else { return };
        let e = &self.expect;
        let inside = match e.when {
            FieldWhen::At => e.at.is_some_and(|at| t <= SimTime::ZERO + at.0),
            _ => {
                e.from.is_none_or(|f| t >= SimTime::ZERO + f.0)
                    && e.to.is_none_or(|to| t <= SimTime::ZERO + to.0)
            }
        };
        if !inside {
            return;
        }
        let held = e.holds(&self.target, x);
        let k = &mut self.tally;
        if k.n == 0 {
            (k.lo, k.hi) = (x, x);
        }
        k.n += 1;
        k.lo = k.lo.min(x);
        k.hi = k.hi.max(x);
        k.last = Some((t, x));
        if held && k.first_held.is_none() {
            k.first_held = Some((t, x));
        }
        if !held && k.first_failed.is_none() {
            k.first_failed = Some((t, x));
        }
    }

    fn judge(&self, cx: &CheckCx<'_>) -> Judgement {
        let (e, t, k) = (&self.expect, &self.target, &self.tally);
        let name = format!("{}.{}.{}", t.node, t.command, t.path);
        let wanted = self.expect.wanted(t);
        let end = cx.report.sim_time;
        if k.n == 0 {
            return Judgement::fail(
                end,
                format!(
                    "no successful {}.{} reply {}",
                    t.node,
                    t.command,
                    match e.when {
                        FieldWhen::At => "at or before the instant".to_owned(),
                        _ => "in the window".to_owned(),
                    }
                ),
            );
        }
        let seen = if k.lo == k.hi {
            format!("{} replies, seen: {}", k.n, show(t.leaf, k.lo))
        } else {
            format!("{} replies, seen: {}..={}", k.n, k.lo, k.hi)
        };
        match e.when {
            FieldWhen::Always => match k.first_failed {
                None => Judgement::pass(end, format!("{name} {wanted} in all {seen}")),
                Some((at, x)) => Judgement::fail(
                    at,
                    format!(
                        "{name} = {} at {at}, not {wanted} ({seen})",
                        show(t.leaf, x)
                    ),
                ),
            },
            FieldWhen::Eventually => match k.first_held {
                Some((at, x)) => {
                    Judgement::pass(at, format!("{name} = {} at {at} ({seen})", show(t.leaf, x)))
                }
                None => Judgement::fail(end, format!("{name} never {wanted} ({seen})")),
            },
            FieldWhen::At => {
                let (at, x) = k.last.unwrap_or((end, f64::NAN));
                Judgement::new(
                    Grade::of(e.holds(t, x)),
                    at,
                    format!(
                        "{name} = {} in the latest reply, at {at} (wanted {wanted})",
                        show(t.leaf, x)
                    ),
                )
            }
        }
    }
}

// What a snapshot saves (docs/snapshots.md): the tally so far.
snap::fields!(Tally {
    n,
    first_held,
    first_failed,
    last,
    lo,
    hi
});
snap::fields!(FieldWatch {
    tally;
    skip expect, target, icd, net
});

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use twin_core::events::SeenPacket;

    /// A TMGEN reply from CSP 3 with mode `mode`, as the ground network carries it, sent by
    /// `from`.
    fn tmgen_reply(from: &str, t_s: u64, mode: u8) -> RunEvent {
        let mut data = vec![1, 1];
        data.extend([0u8; 12]);
        data.extend([mode, 0, 20, 0]);
        let packet = csp::Packet::new(csp::Header::new(3, 17, 40, 10), data);
        RunEvent::Packet(std::sync::Arc::new(SeenPacket {
            t: SimTime::from_secs(t_s),
            medium: "ground".into(),
            from: from.into(),
            packet,
        }))
    }

    fn watch(net: &NetworkSpec) -> FieldWatch {
        let e: FieldExpect = toml::from_str(
            "field = \"FC.TMGEN.current_mode\"\nequals = \"nadir\"\nwhen = \"eventually\"\n",
        )
        .unwrap();
        FieldWatch {
            target: e.target().unwrap(),
            expect: e,
            icd: IcdMap::defaults(),
            net: net.clone(),
            tally: Tally::default(),
        }
    }

    #[test]
    fn a_twin_nodes_reply_counts_on_its_first_hop_and_an_outside_programs_everywhere() {
        let mut net = NetworkSpec::default_m6p();
        let mut w = watch(&net);
        // The FC's own reply counts where the FC sends it, not where the COMM forwards it.
        w.observe(&tmgen_reply("FC", 1, 1));
        w.observe(&tmgen_reply("COMM1", 1, 1));
        assert_eq!(w.tally.n, 1);
        // An outside program in the FC's place sends under its link's name: with the FC
        // still listed as a running node, its replies were never counted.
        w.observe(&tmgen_reply("listen 127.0.0.1:5000#1", 2, 3));
        assert_eq!(w.tally.n, 1);
        net.nodes.retain(|n| n.addr != 3);
        let mut w = watch(&net);
        w.observe(&tmgen_reply("listen 127.0.0.1:5000#1", 2, 3));
        assert_eq!(w.tally.n, 1);
        assert_eq!(w.tally.first_held.map(|(_, x)| x), Some(3.0));
    }
}
