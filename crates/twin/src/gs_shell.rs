//! `m6p-twin gs --connect ADDR` with no request: the ground console, interactive. One line
//! per request, as `gs` takes them after `--connect` (`fc tmgen`, `pc status session_id=1`,
//! `ping fc 64`), with line editing, a history kept between sessions and Tab completion of
//! nodes, commands, argument names and value names, all from the ICD ([`crate::icd`]).
//!
//! With standard input not a terminal it reads the lines from it instead (a script:
//! `m6p-twin gs --connect ADDR < lines.txt`), prints each line before its answer, and ends
//! at the end of the input. `help` lists what it takes; `quit`, `exit` or end of input
//! leave. A line the console cannot take prints one `error:` line and the console goes on.
//!
//! The completion ([`complete`]) and the line's meaning ([`parse`]) are pure; the loop is
//! [`run`].

use std::io::{BufRead, IsTerminal as _};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::gs::{self, GsClient};

/// The console's own words besides `NODE COMMAND`, with their use.
pub const BUILTINS: &[(&str, &str)] = &[
    ("ping", "ping NODE [SIZE]: a CSP ping (port 1)"),
    ("uptime", "uptime NODE: CSP uptime (port 6)"),
    ("ident", "ident NODE: CMP ident (port 0)"),
    (
        "raw",
        "raw NODE PORT HEX: any request, the reply decoded where the ICD knows it, else in hex",
    ),
    (
        "help",
        "help [NODE [COMMAND]]: what the console takes, a node's commands, a command's fields",
    ),
    ("quit", "quit (or exit, or Ctrl-D): leave"),
];

/// Lines of history kept (in memory and in the file).
pub const HISTORY_LINES: usize = 1000;

/// The node names the console takes: the ICD's, with the COMMs and payloads by address.
fn node_names() -> Vec<&'static str> {
    vec![
        "COMM", "COMM1", "COMM2", "FC", "EPS", "ECU", "PC", "PL12", "PL13", "PL14", "PL15",
    ]
}

/// What one console line asks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Line {
    /// Nothing (blank, or a `#` comment).
    Empty,
    /// Leave.
    Quit,
    /// `help`, maybe about a node or a command.
    Help(Vec<String>),
    /// `ping NODE [SIZE]`.
    Ping(u8, usize),
    /// `uptime NODE`.
    Uptime(u8),
    /// `ident NODE`.
    Ident(u8),
    /// `raw NODE PORT HEX`.
    Raw(u8, u8, Vec<u8>),
    /// `NODE COMMAND [NAME=VALUE ...]` (as `gs` takes them after `--connect`).
    Icd(Vec<String>),
}

/// Why the console cannot take a line: the message of its `error:` line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ConsoleLineError {
    /// A number above 30 for a node.
    #[error("{addr} is not a CSP node address (0-30)")]
    NotAnAddress {
        /// The number.
        addr: u8,
    },
    /// A builtin's node that is none of the console's node names.
    #[error("no node `{word}` ({})", node_names().join(", "))]
    NoNode {
        /// The word.
        word: String,
    },
    /// A builtin without an argument it needs.
    #[error("{builtin}: needs {what}")]
    Missing {
        /// The builtin, as typed.
        builtin: String,
        /// What it needs (`a node`, `a port`).
        what: &'static str,
    },
    /// A builtin with words beyond its arguments.
    #[error("{builtin}: too many words (`help` shows its use)")]
    TooManyWords {
        /// The builtin, as typed.
        builtin: String,
    },
    /// `ping`'s size is not a number.
    #[error("ping: `{size}` is not a size in bytes")]
    NotASize {
        /// The word.
        size: String,
    },
    /// `raw`'s port is not 0-63.
    #[error("raw: `{port}` is not a CSP port (0-63)")]
    NotAPort {
        /// The word.
        port: String,
    },
    /// `raw`'s data is not hex. The hex error's message is part of this one's, so it is
    /// not also its `source()`.
    #[error("raw: {hex}")]
    RawNotHex {
        /// Why the data is not hex bytes.
        hex: crate::commands::HexBytesError,
    },
    /// One word that is no builtin.
    #[error(
        "`{word}`: a line is NODE COMMAND [NAME=VALUE ...] or one of {} (`help`)",
        BUILTINS.iter().map(|b| b.0).collect::<Vec<_>>().join(", ")
    )]
    NotALine {
        /// The word.
        word: String,
    },
    /// `NODE COMMAND` that the ICD does not have.
    #[error(transparent)]
    Icd(#[from] crate::icd::IcdLookupError),
}

/// A node as the builtins take it: a name (`fc`, `pl12`, `comm2`) or an address.
fn addr_of(word: &str) -> Result<u8, ConsoleLineError> {
    if let Ok(a) = word.parse::<u8>() {
        return if a <= 30 {
            Ok(a)
        } else {
            Err(ConsoleLineError::NotAnAddress { addr: a })
        };
    }
    let w = word.to_ascii_uppercase();
    let a = match w.as_str() {
        "COMM" | "COMM1" => Some(platform::addr::COMM1),
        "COMM2" => Some(platform::addr::COMM2),
        "FC" => Some(platform::addr::FC),
        "EPS" => Some(platform::addr::EPS),
        "ECU" => Some(platform::addr::ECU),
        "PC" => Some(platform::addr::PC),
        _ => w
            .strip_prefix("PL")
            .and_then(|n| n.parse().ok())
            .filter(|n| (12..=15).contains(n)),
    };
    a.ok_or_else(|| ConsoleLineError::NoNode {
        word: word.to_owned(),
    })
}

/// The meaning of one console line; the error is the message of its `error:` line.
pub fn parse(line: &str) -> Result<Line, ConsoleLineError> {
    let words: Vec<String> = line.split_whitespace().map(str::to_owned).collect();
    let Some(first) = words.first() else {
        return Ok(Line::Empty);
    };
    if first.starts_with('#') {
        return Ok(Line::Empty);
    }
    let arg = |i: usize, what: &'static str| -> Result<&str, ConsoleLineError> {
        words
            .get(i)
            .map(String::as_str)
            .ok_or_else(|| ConsoleLineError::Missing {
                builtin: first.clone(),
                what,
            })
    };
    let too_many = |n: usize| -> Result<(), ConsoleLineError> {
        if words.len() > n {
            Err(ConsoleLineError::TooManyWords {
                builtin: first.clone(),
            })
        } else {
            Ok(())
        }
    };
    match first.to_ascii_lowercase().as_str() {
        "quit" | "exit" => Ok(Line::Quit),
        "help" | "?" => Ok(Line::Help(words[1..].to_vec())),
        "ping" => {
            too_many(3)?;
            let node = addr_of(arg(1, "a node")?)?;
            let size = match words.get(2) {
                None => 16,
                Some(s) => s
                    .parse()
                    .map_err(|_| ConsoleLineError::NotASize { size: s.clone() })?,
            };
            Ok(Line::Ping(node, size))
        }
        "uptime" => {
            too_many(2)?;
            Ok(Line::Uptime(addr_of(arg(1, "a node")?)?))
        }
        "ident" => {
            too_many(2)?;
            Ok(Line::Ident(addr_of(arg(1, "a node")?)?))
        }
        "raw" => {
            let node = addr_of(arg(1, "a node")?)?;
            let port = arg(2, "a port")?;
            let port: u8 = port.parse().ok().filter(|p| *p <= 63).ok_or_else(|| {
                ConsoleLineError::NotAPort {
                    port: port.to_owned(),
                }
            })?;
            let hex: String = words[3..].concat();
            let data = crate::commands::parse_hex(&hex)
                .map_err(|hex| ConsoleLineError::RawNotHex { hex })?;
            Ok(Line::Raw(node, port, data))
        }
        _ => {
            if words.len() < 2 {
                return Err(ConsoleLineError::NotALine {
                    word: first.clone(),
                });
            }
            crate::icd::find_command(&format!("{}.{}", words[0], words[1]))?;
            Ok(Line::Icd(words))
        }
    }
}

/// `help`, `help NODE`, `help NODE COMMAND`.
pub fn help(words: &[String]) -> Result<String, crate::icd::IcdLookupError> {
    match words {
        [] => {
            let mut s = String::from(
                "NODE COMMAND [NAME=VALUE ...]   any ICD command (`help NODE` lists them; Tab completes)\n",
            );
            for (_, use_) in BUILTINS {
                s.push_str(&format!("{use_}\n"));
            }
            s.push_str(&format!("nodes: {}\n", node_names().join(", ")));
            Ok(s)
        }
        [node] => crate::icd::to_text(Some(node)),
        [node, cmd, ..] => {
            let (n, p, c) = crate::icd::find_command(&format!("{node}.{cmd}"))?;
            let text = crate::icd::to_text(Some(n.name))?;
            // The command's block of the node's text: from its line to the next command's.
            let head = format!("{:>3} {}", c.id, c.name);
            let block: Vec<&str> = text
                .lines()
                .skip_while(|l| !l.trim_start().starts_with(head.trim_start()))
                .take_while({
                    let mut first = true;
                    move |l| {
                        let start = first;
                        first = false;
                        start || l.starts_with("      ") || l.trim().is_empty()
                    }
                })
                .collect();
            if block.is_empty() {
                Ok(format!(
                    "{}.{} (port {}): {}\n",
                    n.name, c.name, p.port, c.doc
                ))
            } else {
                Ok(block.join("\n") + "\n")
            }
        }
    }
}

/// Completion of `line` (the text before the cursor): where the word being completed
/// starts, and the candidates for it, in order. Nodes first, then a node's commands, then
/// the command's argument names (`name=`, those not given yet), and after `name=` the
/// field's value names. Candidates follow the case of what was typed (`fc tm` gives
/// `tmgen`, `FC TM` gives `TMGEN`).
pub fn complete(line: &str) -> (usize, Vec<String>) {
    let start = line.rfind(char::is_whitespace).map_or(0, |i| {
        i + line[i..].chars().next().map_or(1, char::len_utf8)
    });
    let word = &line[start..];
    let before: Vec<&str> = line[..start].split_whitespace().collect();
    let upper = word.chars().any(|c| c.is_ascii_uppercase());
    let cased = |s: &str| {
        if upper {
            s.to_ascii_uppercase()
        } else {
            s.to_ascii_lowercase()
        }
    };
    let starts = |c: &str| {
        c.to_ascii_lowercase()
            .starts_with(&word.to_ascii_lowercase())
    };
    let mut out: Vec<String> = Vec::new();
    match before.as_slice() {
        [] => {
            out.extend(node_names().into_iter().filter(|n| starts(n)).map(cased));
            out.extend(
                BUILTINS
                    .iter()
                    .map(|b| b.0)
                    .filter(|b| starts(b))
                    .map(str::to_owned),
            );
        }
        [b] if ["ping", "uptime", "ident", "raw"].contains(&b.to_ascii_lowercase().as_str()) => {
            out.extend(node_names().into_iter().filter(|n| starts(n)).map(cased));
        }
        [b] if b.eq_ignore_ascii_case("help") => {
            out.extend(node_names().into_iter().filter(|n| starts(n)).map(cased));
        }
        [b, node] if b.eq_ignore_ascii_case("help") && crate::icd::node_named(node).is_some() => {
            out.extend(commands_of(node, &starts, &cased));
        }
        [node] if crate::icd::node_named(node).is_some() => {
            out.extend(commands_of(node, &starts, &cased));
        }
        [node, cmd, given @ ..] => {
            let Ok((_, _, c)) = crate::icd::find_command(&format!("{node}.{cmd}")) else {
                return (start, out);
            };
            let Some((fields, tail)) = c.request.parts() else {
                return (start, out);
            };
            if let Some((name, value)) = word.split_once('=') {
                // A field's value names (`mode=na` -> `mode=nadir`).
                if let Some(f) = fields.iter().find(|f| f.name == name) {
                    let prefix = value.to_ascii_lowercase();
                    out.extend(
                        f.values
                            .iter()
                            .chain(f.bits.iter())
                            .map(|(_, v)| *v)
                            .map(|v| v.replace(' ', "_"))
                            .filter(|v| v.to_ascii_lowercase().starts_with(&prefix))
                            .map(|v| format!("{name}={v}")),
                    );
                }
            } else {
                let given: Vec<&str> = given
                    .iter()
                    .filter_map(|w| w.split_once('='))
                    .map(|(k, _)| k)
                    .collect();
                out.extend(
                    fields
                        .iter()
                        .map(|f| f.name)
                        .chain(tail.map(|t| t.name))
                        .filter(|n| !given.contains(n) && n.starts_with(word))
                        .map(|n| format!("{n}=")),
                );
            }
        }
        _ => {}
    }
    (start, out)
}

/// A node's command names that `starts`, in `cased` case.
fn commands_of(
    node: &str,
    starts: &dyn Fn(&str) -> bool,
    cased: &dyn Fn(&str) -> String,
) -> Vec<String> {
    crate::icd::node_named(node)
        .map(|n| {
            n.ports
                .iter()
                .flat_map(|p| p.commands.iter().map(|c| c.name))
                .filter(|c| starts(c))
                .map(cased)
                .collect()
        })
        .unwrap_or_default()
}

/// The history file: `$M6P_GS_HISTORY`, else `~/.m6p-twin-gs-history` (none without a home).
fn history_path() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("M6P_GS_HISTORY") {
        return Some(PathBuf::from(p));
    }
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".m6p-twin-gs-history"))
}

/// The line editor's view of [`complete`].
struct Helper;

impl rustyline::completion::Completer for Helper {
    type Candidate = String;
    fn complete(
        &self,
        line: &str,
        pos: usize,
        _: &rustyline::Context<'_>,
    ) -> rustyline::Result<(usize, Vec<String>)> {
        Ok(complete(line.get(..pos).unwrap_or(line)))
    }
}
impl rustyline::hint::Hinter for Helper {
    type Hint = String;
}
impl rustyline::highlight::Highlighter for Helper {}
impl rustyline::validate::Validator for Helper {}
impl rustyline::Helper for Helper {}

/// Run one line against the twin; `Ok(false)` to leave.
async fn dispatch(
    client: &mut GsClient,
    line: &str,
    port: Option<u8>,
    timeout: Duration,
) -> anyhow::Result<bool> {
    match parse(line)? {
        Line::Empty => {}
        Line::Quit => return Ok(false),
        Line::Help(words) => print!("{}", help(&words)?),
        Line::Ping(node, size) => {
            gs::ping(client, node, 1, size, Duration::ZERO, timeout).await?;
        }
        Line::Uptime(node) => {
            gs::uptime(client, node, timeout, false).await?;
        }
        Line::Ident(node) => {
            gs::ident(client, node, timeout).await?;
        }
        Line::Raw(node, p, data) => {
            gs::raw(client, node, p, data, timeout).await?;
        }
        Line::Icd(words) => {
            gs::icd_command(client, &words, port, timeout).await?;
        }
    }
    Ok(true)
}

/// Whether `e` means the session cannot go on: the twin closed the connection (typed, so
/// a context added on the way does not hide it).
fn ends_session(e: &anyhow::Error) -> bool {
    e.downcast_ref::<crate::gs::Closed>().is_some()
}

/// The console on `server` as node `addr`: interactive on a terminal, else the lines of
/// standard input. Returns whether every line was taken (none got an `error:` line).
pub fn run(
    server: SocketAddr,
    addr: u8,
    port: Option<u8>,
    timeout: Duration,
) -> anyhow::Result<bool> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let mut client = rt.block_on(GsClient::connect(server, addr))?;
    let mut all_ok = true;
    let mut one = |line: &str, all_ok: &mut bool| -> anyhow::Result<bool> {
        match rt.block_on(dispatch(&mut client, line, port, timeout)) {
            Ok(go_on) => Ok(go_on),
            // The twin closed the connection: nothing more can be asked.
            Err(e) if ends_session(&e) => Err(e),
            Err(e) => {
                println!("error: {e:#}");
                *all_ok = false;
                Ok(true)
            }
        }
    };
    if !std::io::stdin().is_terminal() {
        for line in std::io::stdin().lock().lines() {
            let line = line?;
            if !line.trim().is_empty() {
                println!("> {}", line.trim());
            }
            if !one(&line, &mut all_ok)? {
                break;
            }
        }
        return Ok(all_ok);
    }
    let config = rustyline::Config::builder()
        .max_history_size(HISTORY_LINES)?
        .auto_add_history(true)
        .completion_type(rustyline::CompletionType::List)
        .build();
    let mut editor: rustyline::Editor<Helper, rustyline::history::DefaultHistory> =
        rustyline::Editor::with_config(config)?;
    editor.set_helper(Some(Helper));
    let history = history_path();
    if let Some(h) = &history {
        // No history yet is not an error.
        let _ = editor.load_history(h);
    }
    println!(
        "connected to {server} as CSP {addr}: NODE COMMAND [NAME=VALUE ...], `help`, Tab completes, Ctrl-D leaves"
    );
    loop {
        match editor.readline("gs> ") {
            Ok(line) => {
                if !one(&line, &mut all_ok)? {
                    break;
                }
            }
            Err(rustyline::error::ReadlineError::Interrupted) => continue,
            Err(rustyline::error::ReadlineError::Eof) => break,
            Err(e) => return Err(e.into()),
        }
    }
    if let Some(h) = &history
        && let Err(e) = editor.save_history(h)
    {
        eprintln!("note: could not save the history to {}: {e}", h.display());
    }
    Ok(all_ok)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_closed_connection_ends_the_session_through_any_context_and_nothing_else_does() {
        use anyhow::Context as _;
        let closed = Err::<(), _>(crate::gs::Closed)
            .context("reading the reply")
            .unwrap_err();
        assert!(ends_session(&closed));
        let other = anyhow::anyhow!("the twin closed the connection, said a node");
        assert!(!ends_session(&other));
    }

    fn names(line: &str) -> Vec<String> {
        complete(line).1
    }

    #[test]
    fn completion_goes_from_nodes_to_commands_to_arguments_and_values() {
        assert_eq!(names("f"), ["fc"]);
        assert_eq!(names("p"), ["pc", "pl12", "pl13", "pl14", "pl15", "ping"]);
        assert_eq!(
            names("fc tm"),
            [
                "tmgen",
                "tmatp",
                "tmacd",
                "tmsens",
                "tmrawsens",
                "tmall",
                "tmperset",
                "tmperget",
                "tmstoreinfo",
                "tmstoreget",
                "tmstoreclear"
            ]
        );
        assert_eq!(names("FC AT").first().map(String::as_str), Some("ATCATGET"));
        assert_eq!(
            names("pc setup "),
            [
                "session_id=",
                "timestamp=",
                "duration_s=",
                "max_packets=",
                "poll_frame_size=",
                "sync_message="
            ]
        );
        assert_eq!(
            names("pc setup session_id=1 timestamp=now d"),
            ["duration_s="]
        );
        assert_eq!(names("fc atcmdset mode=n"), ["mode=nadir"]);
        assert_eq!(names("fc atcmdset mode=v"), ["mode=velocity_pointing"]);
        assert_eq!(
            names("eps chset channel=PL"),
            [
                "channel=PL12",
                "channel=PL13",
                "channel=PL14",
                "channel=PL15"
            ]
        );
        assert_eq!(names("ping c"), ["comm", "comm1", "comm2"]);
        // After a builtin's node comes no command; after `help NODE`, its commands.
        assert!(names("ping fc ").is_empty());
        assert_eq!(names("help pc st"), ["status"]);
        assert_eq!(complete("fc tmg").0, 3);
        assert!(names("xx yy ").is_empty());
    }

    #[test]
    fn lines_are_parsed_or_refused_with_a_reason() {
        assert_eq!(parse("  "), Ok(Line::Empty));
        assert_eq!(parse("# a comment"), Ok(Line::Empty));
        assert_eq!(parse("ping fc"), Ok(Line::Ping(3, 16)));
        assert_eq!(parse("ping pl12 200"), Ok(Line::Ping(12, 200)));
        assert_eq!(parse("uptime 6"), Ok(Line::Uptime(6)));
        assert_eq!(parse("raw 6 12 01"), Ok(Line::Raw(6, 12, vec![1])));
        assert_eq!(parse("exit"), Ok(Line::Quit));
        assert!(matches!(parse("fc tmgen"), Ok(Line::Icd(w)) if w.len() == 2));
        let says = |line: &str| parse(line).unwrap_err().to_string();
        assert_eq!(
            parse("ping 40"),
            Err(ConsoleLineError::NotAnAddress { addr: 40 })
        );
        assert_eq!(says("ping 40"), "40 is not a CSP node address (0-30)");
        assert!(says("ping sat").starts_with("no node `sat` (COMM, COMM1, "));
        assert_eq!(says("raw 6 64 01"), "raw: `64` is not a CSP port (0-63)");
        assert_eq!(says("raw 6"), "raw: needs a port");
        assert_eq!(
            says("raw 6 12 0g"),
            "raw: `0g` is not hex bytes: Invalid character 'g' at position 1"
        );
        assert!(matches!(
            parse("fc tmgne"),
            Err(ConsoleLineError::Icd(
                crate::icd::IcdLookupError::NoCommand { .. }
            ))
        ));
        assert!(says("fc tmgne").starts_with("the FC has no command `tmgne`: "));
        assert!(
            says("hello")
                .starts_with("`hello`: a line is NODE COMMAND [NAME=VALUE ...] or one of ping, ")
        );
        assert_eq!(
            says("uptime fc eps"),
            "uptime: too many words (`help` shows its use)"
        );
        assert_eq!(says("ping fc x"), "ping: `x` is not a size in bytes");
    }

    #[test]
    fn help_lists_the_builtins_a_nodes_commands_and_a_commands_fields() {
        let all = help(&[]).unwrap();
        assert!(
            all.contains("ping NODE [SIZE]") && all.contains("PL15"),
            "{all}"
        );
        let fc = help(&["fc".into()]).unwrap();
        assert!(fc.contains("TMGEN") && fc.contains("ATCMDSET"), "{fc}");
        let setup = help(&["pc".into(), "setup".into()]).unwrap();
        assert!(
            setup.contains("duration_s") && !setup.contains("STATUS"),
            "{setup}"
        );
    }
}
