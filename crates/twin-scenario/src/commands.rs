//! `[[commands]]`: the ground's requests as a scenario writes them (docs/scenarios.md,
//! "Commands").

use schemars::JsonSchema;
use serde::Deserialize;
use std::collections::BTreeMap;

use crate::dur::Dur;
use twin_core::network::NodeRef;

/// A request sent during the run.
#[derive(Debug, Clone, PartialEq, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CommandSpec {
    /// Name for expectations and reports (default `commands[i]`).
    #[serde(default)]
    pub name: Option<String>,
    /// When to send it: simulated time since the start, or, with `after`, since that
    /// command's first outcome.
    pub at: Dur,
    /// Send it only after the first outcome (reply or timeout) of this command, which must
    /// come from the same ground station.
    #[serde(default)]
    pub after: Option<String>,
    /// Repeat every this long (with `count`).
    #[serde(default)]
    pub every: Option<Dur>,
    /// How many times in all (default 1; with `every`).
    #[serde(default)]
    pub count: Option<u32>,
    /// The sending node (a ground station; default GS16).
    #[serde(default)]
    pub from: Option<NodeRef>,
    /// The destination node (with `command`: default the command's node; COMM1 for a COMM
    /// command; a payload command needs it).
    #[serde(default)]
    pub to: Option<NodeRef>,
    /// `ping`, `uptime`, `ident`, `memfree`, `buf-free`, `ps`, `reboot` or `raw` (or give
    /// `command`).
    #[serde(default)]
    pub request: Option<RequestKind>,
    /// An ICD command by name, `NODE.COMMAND` as `m6p-twin icd` lists them (`PC.SETUP`,
    /// `FC.TMGEN`), with its request fields in `args`; sent to the command's port (`port`
    /// overrides it where the scenario moved the port).
    #[serde(default)]
    pub command: Option<String>,
    /// The typed command's request fields by name: numbers, value names (`mode =
    /// "nadir"`), durations for fields in s or ms (`duration_s = "10m"`), arrays for array
    /// fields, text for text fields and for a trailing byte string (SETUP's `sync_message`).
    /// Checked against the ICD's types and ranges.
    #[serde(default)]
    pub args: Option<BTreeMap<String, serde_json::Value>>,
    /// Ping payload size in bytes (default 16).
    #[serde(default)]
    pub size: Option<usize>,
    /// Destination port (`raw` only).
    #[serde(default)]
    pub port: Option<u8>,
    /// Request bytes as hex (`raw` only), for example `"01"` or `"06 01 00"`.
    #[serde(default)]
    pub data: Option<String>,
    /// Request bytes as text (`raw` only, instead of `data`), for example an ICD 1.5 script
    /// line for FC port 13.
    #[serde(default)]
    pub text: Option<String>,
    /// How long to wait for the reply.
    #[serde(default)]
    pub timeout: Option<Dur>,
}

/// Request kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum RequestKind {
    /// CSP ping (port 1).
    Ping,
    /// CSP uptime (port 6).
    Uptime,
    /// CMP ident (port 0).
    Ident,
    /// CSP memfree (port 3).
    Memfree,
    /// CSP buf_free (port 5).
    BufFree,
    /// CSP ps (port 2).
    Ps,
    /// CSP reboot (port 4, magic 0x80078007).
    Reboot,
    /// Raw bytes to a port.
    Raw,
}
