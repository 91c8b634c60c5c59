//! A node's text console (ICD 1.1 "text console over UART during development; integrated
//! CLI"): one line in, the answer out, at the simulated instant the line arrived.
//!
//! The node's own commands are listed here (help, uptime, counters, log, param, selftest,
//! reboot) and run by [`crate::node::Host::console`] ([`crate::node_console`]);
//! an application adds its own ([`crate::node::App::console_commands`], such as the FC's
//! `tm`). A bad command gets one line starting `error: `. The console changes the node only
//! through what its CSP ports change (a parameter set, a save, a reboot), and logs each of
//! those as they do.

use std::fmt::Write as _;

use crate::icd::{Describe, Field};

/// A console command, for `help`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Command {
    /// Its name (the first word of the line).
    pub name: &'static str,
    /// Its arguments, as `help` shows them.
    pub args: &'static str,
    /// What it does.
    pub help: &'static str,
}

/// The commands every node's console has.
pub const NODE_COMMANDS: &[Command] = &[
    Command {
        name: "help",
        args: "",
        help: "list the commands",
    },
    Command {
        name: "uptime",
        args: "",
        help: "uptime, the node's CSP clock (UTC) and reboots",
    },
    Command {
        name: "counters",
        args: "",
        help: "the node's CSP counters and drops by reason",
    },
    Command {
        name: "log",
        args: "[N]",
        help: "the node's last N log lines and drops (default 20)",
    },
    Command {
        name: "param",
        args: "[list | get NAME | set NAME VALUE | info NAME | save | defaults]",
        help: "the node's parameter table; `save` keeps it over reboots",
    },
    Command {
        name: "selftest",
        args: "",
        help: "each component's health",
    },
    Command {
        name: "reboot",
        args: "",
        help: "reboot the node (unsaved parameters are lost)",
    },
];

/// The `tm` command of a node with one telemetry (EPS, COMM, ECU, PC).
pub const TM: Command = Command {
    name: "tm",
    args: "",
    help: "the node's telemetry now (the bytes its CSP request gets, field by field)",
};

/// A layout's bytes as the console prints them: one `name value unit` line per field, in
/// wire order, with the ICD's names, units and value names ([`crate::icd::show`]); an
/// array's elements and a nested layout's fields by path (`panels_w[3]`,
/// `slots[0].state`), as `gs` and the Python package name them.
pub fn lines(fields: &'static [Field], bytes: &[u8]) -> Result<String, crate::Error> {
    let mut out = String::new();
    crate::icd::decode_each(
        fields,
        bytes,
        &mut String::new(),
        &mut |path, value, field| {
            let _ = writeln!(out, "{path} {}", crate::icd::show(&value, field));
        },
    )?;
    Ok(out)
}

/// A decoded layout as the console prints it ([`lines`] of its bytes).
pub fn layout<T: Describe>(t: &T) -> Result<String, ConsoleError> {
    Ok(lines(T::FIELDS, &t.to_vec())?)
}

/// Longest console line taken (longer ones are refused whole).
pub const MAX_LINE: usize = 256;

/// Why a console line was refused: the text after `error: COMMAND: `.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConsoleError {
    /// The line is longer than [`MAX_LINE`].
    #[error("line longer than {max} characters")]
    LineTooLong {
        /// The longest line taken.
        max: usize,
    },
    /// Neither the node nor its application has the command.
    #[error("unknown command (try help)")]
    UnknownCommand,
    /// The application lists the command but does not run it.
    #[error("unknown command {name:?}")]
    NotRun {
        /// The command's name.
        name: String,
    },
    /// The command's arguments are not what it takes.
    #[error("usage: {0}")]
    Usage(String),
    /// `log`'s argument is not a count.
    #[error("{0:?} is not a count")]
    NotACount(String),
    /// `param` on a node without a parameter table.
    #[error("this node has no parameters")]
    NoParams,
    /// `param get`, `info` or `set` without a name.
    #[error("name a parameter")]
    NameAParameter,
    /// No parameter by this name or id.
    #[error("no parameter {0:?}")]
    NoParameter(String),
    /// The table has the definition but no running value.
    #[error("no value")]
    NoValue,
    /// `param set` without a value.
    #[error("give a value")]
    GiveAValue,
    /// `param set`'s value does not parse as the parameter's type.
    #[error("{name}: {text:?} is not a value of its type")]
    NotAValue {
        /// The parameter's name.
        name: &'static str,
        /// The value as typed.
        text: String,
    },
    /// `param`'s subcommand is not one of its own.
    #[error("unknown subcommand {0:?}")]
    UnknownSubcommand(String),
    /// The parameter was not set.
    #[error(transparent)]
    Param(#[from] crate::params::ParamError),
    /// `param defaults` restored the table but these values were refused.
    #[error("{}", crate::params::join_errors(.0))]
    Defaults(Vec<crate::params::ParamError>),
    /// The command's CSP request was refused (the request's name).
    #[error("{0} refused")]
    Refused(&'static str),
    /// The reply did not decode as its telemetry.
    #[error(transparent)]
    Wire(#[from] crate::Error),
    /// An application's own error.
    #[error(transparent)]
    App(Box<dyn std::error::Error + Send + Sync>),
}

impl ConsoleError {
    /// An application's own error.
    pub fn app(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        ConsoleError::App(Box::new(e))
    }
}

/// The prompt after every answer (`fc> `).
pub fn prompt(node_name: &str) -> String {
    format!("{}> ", node_name.to_ascii_lowercase())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    crate::wire_struct! {
        /// A demo telemetry.
        #[derive(Debug, Clone, Copy, PartialEq, Default)]
        struct Tm {
            /// Battery voltage.
            battery_v: f32 { unit: "V" },
            /// Per-panel power.
            panels_w: [f32; 2] { unit: "W" },
            /// Channels on.
            on: u16 { bits: &[(0, "COMM1"), (2, "ECU")] },
            /// Mode.
            mode: u8 { values: &[(1, "detumble")] },
        }
    }

    #[test]
    fn a_layout_is_one_name_value_unit_line_per_field() {
        let t = Tm {
            battery_v: 7.5,
            panels_w: [1.0, 2.5],
            on: 5,
            mode: 1,
        };
        assert_eq!(
            super::layout(&t).unwrap(),
            "battery_v 7.5 V\npanels_w[0] 1 W\npanels_w[1] 2.5 W\non 0x5 (COMM1, ECU)\nmode 1 (detumble)\n"
        );
        let none = super::layout(&Tm::default()).unwrap();
        assert!(none.contains("\non 0x0 (none)\n"), "{none}");
        assert!(super::lines(<Tm as crate::icd::Describe>::FIELDS, &[0; 3]).is_err());
    }
}
