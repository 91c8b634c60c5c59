//! Platform configuration and diagnostics: every twin node's typed parameter table, its
//! non-volatile copy, and its self-test, on one port with one layout for all nodes (ICD 1.1
//! "platform configuration" and "hardware diagnostic"; the layout is the twin's,
//! docs/protocol.md "Platform port").
//!
//! An application lists its parameters ([`ParamDef`]: id, name, type, unit, range) and
//! reads and applies them over its own state ([`crate::node::App::param_get`],
//! [`crate::node::App::param_set`]), so a parameter that another command also sets (the
//! COMM's BEACONSET, the EPS's THRSET) has one value. [`ParamStore`] is the node's
//! non-volatile memory: the factory defaults (the scenario's values, taken at the first
//! boot), and the saved table, if any. At every boot the saved table (or the defaults) is
//! applied before the application starts: a set that was not saved is gone after a reboot,
//! as on a flight computer whose parameters live in RAM with a copy in FRAM.
//!
//! Requests on [`PORT`] (`command u8 | data`, replies `command | result | data`, ICD 1.8's
//! framing, little-endian):
//!
//! | command | id | request | reply data |
//! |---|---|---|---|
//! | PGET | 1 | `u8 id` | `u8 id, u8 type, value` |
//! | PSET | 2 | `u8 id, value` | `u8 id, u8 type, value` (the value in effect) |
//! | PINFO | 3 | `u8 id` | `u8 id, u8 type, f64 min, f64 max, f64 default, char name[24], char unit[8]` |
//! | PLIST | 4 | `u8 first_id` | `u8 next_id (0xFF: no more), u8 count, count x (u8 id, u8 type, value)` |
//! | PSAVE | 5 | - | - |
//! | PDEFAULTS | 6 | - | - |
//! | SELFTEST | 7 | - | `u8 overall, u8 count, count x (u8 health, f32 reading)` |
//!
//! `value` is sized by `type`: 1 u8, 2 u16, 3 u32, 4 i32, 5 f32, 6 bool (u8 0/1). PSET of
//! an unknown id, a value of the wrong size, NaN, or out of `min..=max` gets the failure
//! reply and changes nothing, as does one the node refuses for a rule between parameters.

use std::collections::BTreeMap;

use crate::reqrep::{self, le};

/// The platform port of every twin node (the twin's: no ICD port is given).
pub const PORT: u8 = 14;

/// Command ids on [`PORT`].
pub mod cmd {
    /// Read one parameter.
    pub const PGET: u8 = 1;
    /// Set one parameter (running value).
    pub const PSET: u8 = 2;
    /// One parameter's type, range, default, name and unit.
    pub const PINFO: u8 = 3;
    /// The running table from an id on.
    pub const PLIST: u8 = 4;
    /// Save the running table to non-volatile memory.
    pub const PSAVE: u8 = 5;
    /// Restore the factory defaults (running and saved).
    pub const PDEFAULTS: u8 = 6;
    /// The node's self-test.
    pub const SELFTEST: u8 = 7;
}

/// Largest PLIST reply data (an ICD reply within a 256-byte CAN/KISS MTU with room to spare).
pub const PLIST_MAX_BYTES: usize = 200;
/// Bytes of PINFO's name field (NUL-padded; names are shorter).
pub const NAME_BYTES: usize = 24;
/// Bytes of PINFO's unit field.
pub const UNIT_BYTES: usize = 8;
/// Length of PINFO's reply data.
pub const PINFO_LEN: usize = 2 + 3 * 8 + NAME_BYTES + UNIT_BYTES;

/// A parameter's wire type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ParamType {
    /// `u8`.
    U8 = 1,
    /// `u16`.
    U16 = 2,
    /// `u32`.
    U32 = 3,
    /// `i32`.
    I32 = 4,
    /// `f32`.
    F32 = 5,
    /// `u8` 0 or 1.
    Bool = 6,
}

impl ParamType {
    /// Bytes of a value on the wire.
    pub fn size(self) -> usize {
        match self {
            ParamType::U8 | ParamType::Bool => 1,
            ParamType::U16 => 2,
            ParamType::U32 | ParamType::I32 | ParamType::F32 => 4,
        }
    }
    /// Encode `v` (already in range) little-endian.
    pub fn encode(self, v: f64, out: &mut Vec<u8>) {
        match self {
            ParamType::U8 | ParamType::Bool => out.push(v as u8),
            ParamType::U16 => out.extend_from_slice(&(v as u16).to_le_bytes()),
            ParamType::U32 => out.extend_from_slice(&(v as u32).to_le_bytes()),
            ParamType::I32 => out.extend_from_slice(&(v as i32).to_le_bytes()),
            ParamType::F32 => out.extend_from_slice(&(v as f32).to_le_bytes()),
        }
    }
    /// Decode exactly one value.
    pub fn decode(self, bytes: &[u8]) -> Option<f64> {
        let mut r = le::Reader::new(bytes);
        let v = match self {
            ParamType::U8 | ParamType::Bool => f64::from(r.u8().ok()?),
            ParamType::U16 => f64::from(r.u16().ok()?),
            ParamType::U32 => f64::from(r.u32().ok()?),
            ParamType::I32 => f64::from(r.i32().ok()?),
            ParamType::F32 => f64::from(r.f32().ok()?),
        };
        r.finish().ok()?;
        Some(v)
    }
    /// The value a text (console) gives: a number, or for a bool also on/off, true/false.
    pub fn parse_text(self, s: &str) -> Option<f64> {
        let v = match (self, s.to_ascii_lowercase().as_str()) {
            (ParamType::Bool, "on" | "true" | "yes") => 1.0,
            (ParamType::Bool, "off" | "false" | "no") => 0.0,
            (_, t) => t.parse::<f64>().ok()?,
        };
        let integral = !matches!(self, ParamType::F32);
        (v.is_finite() && (!integral || v.fract() == 0.0)).then_some(v)
    }
    /// The value as the console prints it.
    pub fn format(self, v: f64) -> String {
        match self {
            ParamType::Bool => if v != 0.0 { "on" } else { "off" }.to_owned(),
            ParamType::F32 => format!("{}", v as f32),
            _ => format!("{v}"),
        }
    }
    /// The type for a wire code.
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => ParamType::U8,
            2 => ParamType::U16,
            3 => ParamType::U32,
            4 => ParamType::I32,
            5 => ParamType::F32,
            6 => ParamType::Bool,
            _ => return None,
        })
    }
}

/// One settable parameter of a node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamDef {
    /// Its id on the wire (unique in the node's table).
    pub id: u8,
    /// Its name (console and docs; at most [`NAME_BYTES`] - 1 characters).
    pub name: &'static str,
    /// Its wire type.
    pub ty: ParamType,
    /// Its unit (at most [`UNIT_BYTES`] - 1 characters; empty for none).
    pub unit: &'static str,
    /// Smallest value accepted.
    pub min: f64,
    /// Largest value accepted.
    pub max: f64,
    /// What it does (console `param info`, docs).
    pub help: &'static str,
}

/// A parameter definition (for a node's `const` table).
pub const fn def(
    id: u8,
    name: &'static str,
    ty: ParamType,
    unit: &'static str,
    min: f64,
    max: f64,
    help: &'static str,
) -> ParamDef {
    ParamDef {
        id,
        name,
        ty,
        unit,
        min,
        max,
        help,
    }
}

/// Why a parameter was not set.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ParamError {
    /// The value is NaN or infinite.
    #[error("{name}: not a finite number")]
    NotFinite {
        /// The parameter's name.
        name: &'static str,
    },
    /// The value is outside the definition's range (shown as its type formats values).
    #[error("{name}: {} out of range {}..={} {unit}", .ty.format(*.value), .ty.format(*.min), .ty.format(*.max))]
    OutOfRange {
        /// The parameter's name.
        name: &'static str,
        /// Its type.
        ty: ParamType,
        /// The value refused.
        value: f64,
        /// Smallest value accepted.
        min: f64,
        /// Largest value accepted.
        max: f64,
        /// Its unit.
        unit: &'static str,
    },
    /// The table has no parameter with this id.
    #[error("no parameter {id}")]
    Unknown {
        /// The id asked for.
        id: u8,
    },
    /// The node refuses the value for a rule of its own (between parameters, or nothing in
    /// the node for it to apply to); the node's error says which.
    #[error(transparent)]
    Refused(Box<dyn std::error::Error + Send + Sync>),
}

impl ParamError {
    /// A node's own reason for refusing a value.
    pub fn refused(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        ParamError::Refused(Box::new(e))
    }
}

/// Errors as one line, `; ` between them (the log's and the console's form).
pub fn join_errors(errors: &[ParamError]) -> String {
    errors
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

impl ParamDef {
    /// Why `v` is not acceptable, if it is not.
    pub fn check(&self, v: f64) -> Result<(), ParamError> {
        if !v.is_finite() {
            return Err(ParamError::NotFinite { name: self.name });
        }
        if v < self.min || v > self.max {
            return Err(ParamError::OutOfRange {
                name: self.name,
                ty: self.ty,
                value: v,
                min: self.min,
                max: self.max,
                unit: self.unit,
            });
        }
        Ok(())
    }
}

/// The health of one component in a self-test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u8)]
pub enum Health {
    /// Working.
    Ok = 0,
    /// Working with a reduced figure (a noisy sensor, a low battery).
    Degraded = 1,
    /// Not working.
    Failed = 2,
    /// Switched off (not a fault).
    Off = 3,
}

impl Health {
    /// The console's word.
    pub fn word(self) -> &'static str {
        match self {
            Health::Ok => "ok",
            Health::Degraded => "degraded",
            Health::Failed => "FAILED",
            Health::Off => "off",
        }
    }
}

/// One component's line in a self-test.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    /// Component name (the console's; the wire gives only the position, documented per node).
    pub name: &'static str,
    /// Its health.
    pub health: Health,
    /// Its reading (the wire's `f32`).
    pub reading: f64,
    /// The reading's unit.
    pub unit: &'static str,
    /// What the twin saw (console only).
    pub detail: String,
}

/// One self-test line (what [`Check`] holds, in its order).
pub fn check(
    name: &'static str,
    health: Health,
    reading: f64,
    unit: &'static str,
    detail: String,
) -> Check {
    Check {
        name,
        health,
        reading,
        unit,
        detail,
    }
}

/// A self-test's overall result: the worst component that is not merely off.
pub fn overall(checks: &[Check]) -> Health {
    checks
        .iter()
        .map(|c| c.health)
        .filter(|h| *h != Health::Off)
        .max()
        .unwrap_or(Health::Ok)
}

/// A self-test's reply data: `u8 overall, u8 count, count x (u8 health, f32 reading)`.
pub fn encode_selftest(checks: &[Check]) -> Vec<u8> {
    let mut out = vec![overall(checks) as u8, checks.len() as u8];
    for c in checks {
        out.push(c.health as u8);
        out.extend_from_slice(&(c.reading as f32).to_le_bytes());
    }
    out
}

/// The node's non-volatile parameter memory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ParamStore {
    /// Factory defaults by id (the values at the first boot).
    defaults: BTreeMap<u8, f64>,
    /// The saved table, if any was saved since the last PDEFAULTS.
    saved: Option<BTreeMap<u8, f64>>,
    /// Saves since the run began.
    pub saves: u64,
}

/// What a node's parameter table is, for [`serve`] and the console: the application's
/// definitions and live values.
pub trait Table {
    /// Parameter definitions, in id order.
    fn defs(&self) -> &'static [ParamDef];
    /// The running value of `id`.
    fn get(&self, id: u8) -> Option<f64>;
    /// Apply `v` (in the definition's range) to `id`; `Err` says why the node refuses it.
    fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError>;
}

impl ParamStore {
    /// Take the factory defaults from the table's running values (at the first boot only).
    pub fn capture_defaults(&mut self, table: &dyn Table) {
        if self.defaults.is_empty() {
            self.defaults = table
                .defs()
                .iter()
                .filter_map(|d| Some((d.id, table.get(d.id)?)))
                .collect();
        }
    }
    /// At boot: apply the saved table, or the defaults. Values a node refuses are named.
    ///
    /// Values refused for a rule between parameters (a lower threshold above the upper one
    /// still running) are tried again after the others, pass by pass, so a table that is
    /// consistent as a whole loads whatever order its values must go in.
    pub fn load(&self, table: &mut dyn Table) -> Vec<ParamError> {
        let values = self.saved.as_ref().unwrap_or(&self.defaults);
        let all: Vec<(u8, f64)> = table
            .defs()
            .iter()
            .filter_map(|d| Some((d.id, *values.get(&d.id)?)))
            .collect();
        apply(table, &all)
    }
    /// Save the running table.
    pub fn save(&mut self, table: &dyn Table) {
        self.saved = Some(
            table
                .defs()
                .iter()
                .filter_map(|d| Some((d.id, table.get(d.id)?)))
                .collect(),
        );
        self.saves += 1;
    }
    /// Restore the factory defaults to the running table and forget the saved one.
    pub fn restore_defaults(&mut self, table: &mut dyn Table) -> Vec<ParamError> {
        self.saved = None;
        self.load(table)
    }
    /// The factory default of `id`.
    pub fn default_of(&self, id: u8) -> Option<f64> {
        self.defaults.get(&id).copied()
    }
    /// The saved value of `id`, if a table was saved.
    pub fn saved_of(&self, id: u8) -> Option<f64> {
        self.saved.as_ref().and_then(|s| s.get(&id).copied())
    }
}

/// Set `values` (id, value) on `table`, those it refuses for a rule between parameters again
/// after the others, pass by pass, so that a set consistent as a whole goes in whatever order
/// its values must take; what is still refused at the end is named.
pub fn apply(table: &mut dyn Table, values: &[(u8, f64)]) -> Vec<ParamError> {
    let mut pending: Vec<(u8, f64)> = values
        .iter()
        .copied()
        .filter(|&(id, v)| table.get(id) != Some(v))
        .collect();
    let mut errors = Vec::new();
    while !pending.is_empty() {
        let before = pending.len();
        errors.clear();
        pending.retain(|&(id, v)| match table.set(id, v) {
            Ok(()) => false,
            Err(e) => {
                errors.push(e);
                true
            }
        });
        if pending.len() == before {
            break;
        }
    }
    errors
}

/// Find a parameter by name (case-insensitive) or by its id in decimal.
pub fn find(defs: &'static [ParamDef], key: &str) -> Option<&'static ParamDef> {
    defs.iter()
        .find(|d| d.name.eq_ignore_ascii_case(key))
        .or_else(|| {
            let id: u8 = key.parse().ok()?;
            defs.iter().find(|d| d.id == id)
        })
}

/// Set `def` to `v` after the range check: the error says why not.
pub fn set_checked(table: &mut dyn Table, def: &ParamDef, v: f64) -> Result<(), ParamError> {
    def.check(v)?;
    table.set(def.id, v)
}

fn value_entry(def: &ParamDef, v: f64, out: &mut Vec<u8>) {
    out.push(def.id);
    out.push(def.ty as u8);
    def.ty.encode(v, out);
}

fn fixed_text(s: &str, n: usize, out: &mut Vec<u8>) {
    let b = s.as_bytes();
    let k = b.len().min(n - 1);
    out.extend_from_slice(&b[..k]);
    out.resize(out.len() + (n - k), 0);
}

/// What a request on [`PORT`] did, besides its reply.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// Nothing changed.
    None,
    /// Parameter `name` was set to `value`.
    Set {
        /// Its name.
        name: &'static str,
        /// The new running value.
        value: f64,
    },
    /// The table was saved.
    Saved,
    /// The defaults were restored.
    Defaults,
}

/// Answer one request on [`PORT`] (SELFTEST excepted: `selftest` gives the node's checks).
/// Returns the reply bytes, what changed, and why a request was refused (for the log).
pub fn serve(
    table: &mut dyn Table,
    store: &mut ParamStore,
    selftest: impl FnOnce() -> Vec<Check>,
    request: &[u8],
) -> (Vec<u8>, Effect, Option<String>) {
    let Some((&command, data)) = request.split_first() else {
        return (
            reqrep::failure(0),
            Effect::None,
            Some("empty request".into()),
        );
    };
    let refuse = |why: String| (reqrep::failure(command), Effect::None, Some(why));
    let defs = table.defs();
    let by_id = |id: u8| defs.iter().find(|d| d.id == id);
    match (command, data) {
        (cmd::PGET, &[id]) => match (by_id(id), table.get(id)) {
            (Some(d), Some(v)) => {
                let mut out = Vec::new();
                value_entry(d, v, &mut out);
                (reqrep::success(command, &out), Effect::None, None)
            }
            _ => refuse(format!("PGET: no parameter {id}")),
        },
        (cmd::PSET, [id, value @ ..]) => {
            let Some(d) = by_id(*id) else {
                return refuse(format!("PSET: no parameter {id}"));
            };
            let Some(v) = d.ty.decode(value) else {
                return refuse(format!(
                    "PSET {}: value is {} bytes, its type takes {}",
                    d.name,
                    value.len(),
                    d.ty.size()
                ));
            };
            match set_checked(table, d, v) {
                Ok(()) => {
                    let now = table.get(d.id).unwrap_or(v);
                    let mut out = Vec::new();
                    value_entry(d, now, &mut out);
                    (
                        reqrep::success(command, &out),
                        Effect::Set {
                            name: d.name,
                            value: now,
                        },
                        None,
                    )
                }
                Err(why) => refuse(format!("PSET {why}")),
            }
        }
        (cmd::PINFO, &[id]) => {
            let Some(d) = by_id(id) else {
                return refuse(format!("PINFO: no parameter {id}"));
            };
            let mut out = vec![d.id, d.ty as u8];
            for v in [d.min, d.max, store.default_of(d.id).unwrap_or(f64::NAN)] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            fixed_text(d.name, NAME_BYTES, &mut out);
            fixed_text(d.unit, UNIT_BYTES, &mut out);
            (reqrep::success(command, &out), Effect::None, None)
        }
        (cmd::PLIST, &[first]) => {
            let mut entries = Vec::new();
            let mut count = 0u8;
            let mut next = 0xFF;
            for d in defs.iter().filter(|d| d.id >= first) {
                if entries.len() + 2 + d.ty.size() > PLIST_MAX_BYTES - 2 {
                    next = d.id;
                    break;
                }
                if let Some(v) = table.get(d.id) {
                    value_entry(d, v, &mut entries);
                    count += 1;
                }
            }
            let mut out = vec![next, count];
            out.extend_from_slice(&entries);
            (reqrep::success(command, &out), Effect::None, None)
        }
        (cmd::PSAVE, []) => {
            store.save(table);
            (reqrep::success(command, &[]), Effect::Saved, None)
        }
        (cmd::PDEFAULTS, []) => {
            let errors = store.restore_defaults(table);
            (
                reqrep::success(command, &[]),
                Effect::Defaults,
                (!errors.is_empty()).then(|| join_errors(&errors)),
            )
        }
        (cmd::SELFTEST, []) => (
            reqrep::success(command, &encode_selftest(&selftest())),
            Effect::None,
            None,
        ),
        (cmd::PGET..=cmd::SELFTEST, _) => refuse(format!(
            "command {command}: request data of {} bytes is the wrong length",
            data.len()
        )),
        _ => refuse(format!("unknown command {command}")),
    }
}

// The factory defaults are the built node's; what was saved since, and how often, is state.
snap::fields!(ParamStore { saved, saves; skip defaults });

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    const DEFS: &[ParamDef] = &[
        ParamDef {
            id: 1,
            name: "beacon_period",
            ty: ParamType::U16,
            unit: "s",
            min: 1.0,
            max: 3600.0,
            help: "",
        },
        ParamDef {
            id: 2,
            name: "gain",
            ty: ParamType::F32,
            unit: "",
            min: 0.0,
            max: 2.0,
            help: "",
        },
        ParamDef {
            id: 3,
            name: "gps",
            ty: ParamType::Bool,
            unit: "",
            min: 0.0,
            max: 1.0,
            help: "",
        },
    ];

    /// A rule of the test table's own.
    #[derive(Debug, thiserror::Error)]
    #[error("{0}")]
    struct Rule(&'static str);

    #[derive(Default)]
    struct T {
        v: BTreeMap<u8, f64>,
    }
    impl Table for T {
        fn defs(&self) -> &'static [ParamDef] {
            DEFS
        }
        fn get(&self, id: u8) -> Option<f64> {
            self.v.get(&id).copied()
        }
        fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
            if id == 2 && v == 1.5 {
                return Err(ParamError::refused(Rule("gain: 1.5 is refused by a rule")));
            }
            self.v.insert(id, v);
            Ok(())
        }
    }

    fn table() -> (T, ParamStore) {
        let mut t = T::default();
        t.v.extend([(1, 30.0), (2, 0.5), (3, 1.0)]);
        let mut s = ParamStore::default();
        s.capture_defaults(&t);
        (t, s)
    }

    fn ask(t: &mut T, s: &mut ParamStore, req: &[u8]) -> Vec<u8> {
        serve(t, s, Vec::new, req).0
    }

    #[test]
    fn get_set_and_the_failure_replies() {
        let (mut t, mut s) = table();
        assert_eq!(ask(&mut t, &mut s, &[1, 1]), [1, 1, 1, 2, 30, 0]);
        assert_eq!(ask(&mut t, &mut s, &[2, 1, 60, 0]), [2, 1, 1, 2, 60, 0]);
        assert_eq!(t.v[&1], 60.0);
        // Out of range, wrong size, unknown id, NaN, a rule: failure, nothing changed.
        assert_eq!(ask(&mut t, &mut s, &[2, 1, 0, 0]), [2, 0]);
        assert_eq!(ask(&mut t, &mut s, &[2, 1, 60]), [2, 0]);
        assert_eq!(ask(&mut t, &mut s, &[2, 9, 1]), [2, 0]);
        let mut nan = vec![2, 2];
        nan.extend_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(ask(&mut t, &mut s, &nan), [2, 0]);
        let mut rule = vec![2, 2];
        rule.extend_from_slice(&1.5f32.to_le_bytes());
        assert_eq!(ask(&mut t, &mut s, &rule), [2, 0]);
        assert_eq!(t.v[&1], 60.0);
        assert_eq!(t.v[&2], 0.5);
        assert_eq!(ask(&mut t, &mut s, &[9]), [9, 0]);
        assert_eq!(ask(&mut t, &mut s, &[]), [0, 0]);
        assert_eq!(ask(&mut t, &mut s, &[5, 0]), [5, 0]);
    }

    #[test]
    fn a_set_survives_a_boot_only_when_saved_and_defaults_restore_the_factory_table() {
        let (mut t, mut s) = table();
        ask(&mut t, &mut s, &[2, 1, 60, 0]);
        // Reboot without a save: the defaults again.
        assert!(s.load(&mut t).is_empty());
        assert_eq!(t.v[&1], 30.0);
        ask(&mut t, &mut s, &[2, 1, 60, 0]);
        assert_eq!(ask(&mut t, &mut s, &[5]), [5, 1]);
        ask(&mut t, &mut s, &[2, 1, 90, 0]);
        s.load(&mut t);
        assert_eq!(t.v[&1], 60.0, "the saved value");
        assert_eq!(ask(&mut t, &mut s, &[6]), [6, 1]);
        assert_eq!(t.v[&1], 30.0);
        s.load(&mut t);
        assert_eq!(t.v[&1], 30.0, "nothing saved any more");
    }

    /// What a snapshot keeps of the parameter memory: the saved table and the count of
    /// saves; a store built fresh and loaded with it boots with the saved values.
    #[test]
    fn the_saved_table_comes_back_from_a_snapshot() {
        let (mut t, mut s) = table();
        ask(&mut t, &mut s, &[2, 1, 60, 0]);
        assert_eq!(ask(&mut t, &mut s, &[5]), [5, 1]);
        let bytes = snap::to_bytes(&s);
        let (mut t2, mut s2) = table();
        snap::load_from(&mut s2, &bytes).unwrap();
        assert_eq!(snap::to_bytes(&s2), bytes);
        assert_eq!(s2.saves, 1);
        s2.load(&mut t2);
        assert_eq!(t2.v[&1], 60.0);
    }

    /// Two thresholds with a rule between them (lower < upper), loaded from 10/20 to 30/40:
    /// the lower one is refused while the old upper one runs, and goes in after it.
    #[test]
    fn a_table_consistent_as_a_whole_loads_whatever_the_order() {
        struct Pair {
            lo: f64,
            hi: f64,
        }
        #[derive(Debug, thiserror::Error)]
        #[error("lo {lo} not below hi {hi}")]
        struct Order {
            lo: f64,
            hi: f64,
        }
        const PAIR: &[ParamDef] = &[
            ParamDef {
                id: 1,
                name: "lo",
                ty: ParamType::U8,
                unit: "%",
                min: 0.0,
                max: 100.0,
                help: "",
            },
            ParamDef {
                id: 2,
                name: "hi",
                ty: ParamType::U8,
                unit: "%",
                min: 0.0,
                max: 100.0,
                help: "",
            },
        ];
        impl Table for Pair {
            fn defs(&self) -> &'static [ParamDef] {
                PAIR
            }
            fn get(&self, id: u8) -> Option<f64> {
                Some(if id == 1 { self.lo } else { self.hi })
            }
            fn set(&mut self, id: u8, v: f64) -> Result<(), ParamError> {
                let (lo, hi) = if id == 1 { (v, self.hi) } else { (self.lo, v) };
                if lo >= hi {
                    return Err(ParamError::refused(Order { lo, hi }));
                }
                (self.lo, self.hi) = (lo, hi);
                Ok(())
            }
        }
        let mut t = Pair { lo: 30.0, hi: 40.0 };
        let mut s = ParamStore::default();
        s.capture_defaults(&t);
        assert!(t.set(1, 10.0).is_ok() && t.set(2, 20.0).is_ok());
        assert!(s.restore_defaults(&mut t).is_empty());
        assert_eq!((t.lo, t.hi), (30.0, 40.0));
        // An inconsistent saved table: what fits goes in, the rest is named.
        s.saved = Some([(1, 50.0), (2, 45.0)].into_iter().collect());
        let e = s.load(&mut t);
        assert_eq!((t.lo, t.hi), (30.0, 45.0));
        assert_eq!(join_errors(&e), "lo 50 not below hi 45");
    }

    #[test]
    fn info_and_list_layouts() {
        let (mut t, mut s) = table();
        let info = ask(&mut t, &mut s, &[3, 2]);
        assert_eq!(info.len(), 2 + PINFO_LEN);
        assert_eq!(&info[2..4], &[2, 5]);
        assert_eq!(f64::from_le_bytes(info[4..12].try_into().unwrap()), 0.0);
        assert_eq!(f64::from_le_bytes(info[12..20].try_into().unwrap()), 2.0);
        assert_eq!(f64::from_le_bytes(info[20..28].try_into().unwrap()), 0.5);
        assert_eq!(&info[28..32], b"gain");
        assert_eq!(info[32], 0);
        let list = ask(&mut t, &mut s, &[4, 0]);
        assert_eq!(
            list,
            [4, 1, 0xFF, 3, 1, 2, 30, 0, 2, 5, 0, 0, 0, 0x3F, 3, 6, 1]
        );
        let from3 = ask(&mut t, &mut s, &[4, 3]);
        assert_eq!(from3, [4, 1, 0xFF, 1, 3, 6, 1]);
    }

    #[test]
    fn selftest_layout_and_overall() {
        let checks = vec![
            Check {
                name: "a",
                health: Health::Ok,
                reading: 1.0,
                unit: "",
                detail: String::new(),
            },
            Check {
                name: "b",
                health: Health::Off,
                reading: 0.0,
                unit: "",
                detail: String::new(),
            },
            Check {
                name: "c",
                health: Health::Degraded,
                reading: 2.5,
                unit: "",
                detail: String::new(),
            },
        ];
        let b = encode_selftest(&checks);
        assert_eq!(b[..2], [1, 3]);
        assert_eq!(b.len(), 2 + 3 * 5);
        assert_eq!(b[12], 1);
        assert_eq!(f32::from_le_bytes(b[13..17].try_into().unwrap()), 2.5);
    }

    #[test]
    fn text_values() {
        assert_eq!(ParamType::Bool.parse_text("on"), Some(1.0));
        assert_eq!(ParamType::U16.parse_text("2.5"), None);
        assert_eq!(ParamType::F32.parse_text("2.5"), Some(2.5));
        assert_eq!(ParamType::F32.parse_text("nan"), None);
        assert_eq!(ParamType::I32.parse_text("-3"), Some(-3.0));
    }
}
