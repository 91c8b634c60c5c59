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

/// A decoded telemetry as the console prints it: one `field value` line per field (the
/// fields' names carry their units: `battery_v`, `elevation_deg`), arrays on one line.
pub fn fields<T: std::fmt::Debug>(t: &T) -> String {
    let pretty = format!("{t:#?}");
    let mut out = String::new();
    let mut array: Option<String> = None;
    let lines: Vec<&str> = pretty.lines().collect();
    for line in lines.iter().skip(1).take(lines.len().saturating_sub(2)) {
        let l = line.trim().trim_end_matches(',');
        match &mut array {
            Some(a) if l == "]" => {
                let _ = writeln!(out, "{a}]");
                array = None;
            }
            Some(a) => {
                if !a.ends_with('[') {
                    a.push(' ');
                }
                a.push_str(l);
            }
            None => match l.split_once(": ") {
                Some((k, "[")) => array = Some(format!("{k} [")),
                Some((k, v)) => {
                    let _ = writeln!(out, "{k} {v}");
                }
                None => {
                    let _ = writeln!(out, "{l}");
                }
            },
        }
    }
    out
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
    #[derive(Debug)]
    #[allow(dead_code)] // read through Debug only
    struct Tm {
        battery_v: f32,
        panels_w: [f32; 3],
        flags: u8,
    }

    #[test]
    fn telemetry_fields_one_per_line_arrays_on_one() {
        let t = Tm {
            battery_v: 7.5,
            panels_w: [1.0, 2.5, 0.0],
            flags: 3,
        };
        assert_eq!(
            super::fields(&t),
            "battery_v 7.5\npanels_w [1.0 2.5 0.0]\nflags 3\n"
        );
    }
}
