//! A node's console lines run on its host ([`crate::console`] lists the commands): the
//! node's own, then the application's.

use std::fmt::Write as _;

use crate::SimTime;
use crate::console::{ConsoleError, MAX_LINE, NODE_COMMANDS};
use crate::node::{App, Host};
use crate::params::{self, ParamDef};

impl<A: App> Host<A> {
    /// Run one console line at `now`; the answer ends with a newline (or is empty for an
    /// empty line). Errors are one line starting `error: `.
    pub fn console(&mut self, line: &str, now: SimTime) -> String {
        let words: Vec<&str> = line.split_whitespace().collect();
        let Some(&first) = words.first() else {
            return String::new();
        };
        let answer = if line.len() > MAX_LINE {
            Err(ConsoleError::LineTooLong { max: MAX_LINE })
        } else {
            self.console_words(&words, now)
        };
        match answer {
            Ok(mut text) => {
                if !text.is_empty() && !text.ends_with('\n') {
                    text.push('\n');
                }
                text
            }
            Err(e) => format!("error: {first}: {e}\n"),
        }
    }

    fn console_words(&mut self, words: &[&str], now: SimTime) -> Result<String, ConsoleError> {
        let mut out = String::new();
        match words[0] {
            "help" => {
                let has_params = self.app.params().is_some();
                let app = self.app.console_commands();
                for c in NODE_COMMANDS
                    .iter()
                    .filter(|c| has_params || !matches!(c.name, "param" | "selftest"))
                    .chain(app)
                {
                    let _ = writeln!(out, "{:<9} {:<22} {}", c.name, c.args, c.help);
                }
            }
            "uptime" => {
                let n = &self.node;
                let up = n.uptime(now);
                let clock_s = n.clock_unix_ns(now).div_euclid(1_000_000_000);
                let _ = writeln!(
                    out,
                    "{} (CSP {}) uptime {:.3} s, clock {} unix s, reboots {}, t {}",
                    n.name(),
                    n.addr(),
                    up.as_secs_f64(),
                    clock_s,
                    n.counters().reboots,
                    now
                );
            }
            "counters" => {
                let c = self.node.counters();
                let _ = writeln!(
                    out,
                    "rx {} tx {} forwarded {} delivered {} service_replies {} platform {} (refused {}) reboots {}",
                    c.rx_packets,
                    c.tx_packets,
                    c.forwarded,
                    c.delivered,
                    c.service_replies,
                    c.platform_requests,
                    c.platform_refused,
                    c.reboots
                );
                for (reason, n) in &c.drops {
                    let _ = writeln!(out, "drop {reason}: {n}");
                }
            }
            "log" => {
                let n = match words.get(1) {
                    None => 20,
                    Some(w) => w
                        .parse::<usize>()
                        .map_err(|_| ConsoleError::NotACount((*w).to_owned()))?,
                };
                let recent: Vec<_> = self.node.recent_events().collect();
                for e in &recent[recent.len().saturating_sub(n)..] {
                    let _ = writeln!(out, "{} {e}", e.t());
                }
            }
            "param" => return self.console_param(&words[1..], now),
            "selftest" if self.app.params().is_some() => {
                let checks = self.app.self_test(&self.node, now);
                let _ = writeln!(out, "overall {}", params::overall(&checks).word());
                for c in &checks {
                    let _ = writeln!(
                        out,
                        "{:<14} {:<8} {:>12.3} {:<6} {}",
                        c.name,
                        c.health.word(),
                        c.reading,
                        c.unit,
                        c.detail
                    );
                }
            }
            "reboot" => {
                self.node.log(now, "reboot from the console".to_owned());
                self.reboot(now);
                out.push_str("rebooting\n");
            }
            name => {
                if !self.app.console_commands().iter().any(|c| c.name == name) {
                    return Err(ConsoleError::UnknownCommand);
                }
                return self.app.console(&mut self.node, words, now);
            }
        }
        Ok(out)
    }

    fn console_param(&mut self, args: &[&str], now: SimTime) -> Result<String, ConsoleError> {
        let Some(table) = self.app.params() else {
            return Err(ConsoleError::NoParams);
        };
        let defs = table.defs();
        let find = |key: Option<&&str>| -> Result<&'static ParamDef, ConsoleError> {
            let key = key.ok_or(ConsoleError::NameAParameter)?;
            params::find(defs, key).ok_or_else(|| ConsoleError::NoParameter((*key).to_owned()))
        };
        let line = |d: &ParamDef, v: f64| {
            format!(
                "{:>3} {:<24} {:>12} {:<6} [{} .. {}]\n",
                d.id,
                d.name,
                d.ty.format(v),
                d.unit,
                d.ty.format(d.min),
                d.ty.format(d.max)
            )
        };
        let mut out = String::new();
        match args.first().copied() {
            None | Some("list") => {
                for d in defs {
                    if let Some(v) = table.get(d.id) {
                        out.push_str(&line(d, v));
                    }
                }
            }
            Some("get") => {
                let d = find(args.get(1))?;
                out = line(d, table.get(d.id).ok_or(ConsoleError::NoValue)?);
            }
            Some("info") => {
                let d = find(args.get(1))?;
                let v = table.get(d.id).ok_or(ConsoleError::NoValue)?;
                let fmt_opt = |v: Option<f64>| v.map_or("-".to_owned(), |v| d.ty.format(v));
                out = format!(
                    "{}value {}, default {}, saved {}\n    {}\n",
                    line(d, v),
                    d.ty.format(v),
                    fmt_opt(self.nv.default_of(d.id)),
                    fmt_opt(self.nv.saved_of(d.id)),
                    d.help
                );
            }
            Some("set") => {
                let d = find(args.get(1))?;
                let text = args.get(2).ok_or(ConsoleError::GiveAValue)?;
                let v =
                    d.ty.parse_text(text)
                        .ok_or_else(|| ConsoleError::NotAValue {
                            name: d.name,
                            text: (*text).to_owned(),
                        })?;
                params::set_checked(table, d, v)?;
                let now_v = table.get(d.id).unwrap_or(v);
                out = line(d, now_v);
                self.node.log(
                    now,
                    format!("parameter {} set to {now_v} from the console", d.name),
                );
            }
            Some("save") => {
                self.nv.save(table);
                self.node
                    .log(now, "parameters saved from the console".to_owned());
                out.push_str("saved\n");
            }
            Some("defaults") => {
                let errors = self.nv.restore_defaults(table);
                self.node.log(
                    now,
                    "parameters reset to defaults from the console".to_owned(),
                );
                out.push_str("defaults restored\n");
                if !errors.is_empty() {
                    return Err(ConsoleError::Defaults(errors));
                }
            }
            Some(other) => return Err(ConsoleError::UnknownSubcommand(other.to_owned())),
        }
        Ok(out)
    }
}
