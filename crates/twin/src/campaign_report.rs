//! `report.html`: a campaign's results for a person: one self-contained page (inline SVG, no
//! script, nothing fetched) with the failures by check (each expectation or invariant that
//! failed: in how many runs, and the first), the payload sessions (each session id: the runs
//! it ran in, how its session runs ended, packets and bytes, the runs where it ended other
//! than done), the pass rate per fault kind, the failures plotted against every drawn value,
//! histograms of the runs' metrics that vary (a metric with one value is one line), and the
//! failures with what they drew. Axes carry the unit the plotted name gives in its suffix
//! ([`unit_of`]). Built from the rows alone, so a merged campaign's page is the unsharded
//! one's; the failures by check and the sessions are also text, for the terminal
//! ([`failures_by_check_text`], [`sessions_text`]).

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

use crate::campaign_rows::{CampaignMeta, CheckKind, RunRow, RunVerdict, SessionEnd};

const PASS: &str = "#2e8b57";
const FAIL: &str = "#d0453a";
const ERROR: &str = "#8a2be2";
const NOT_RUN: &str = "#9e9e9e";
const WIDTH: f64 = 640.0;

/// Text for HTML.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A number for an axis: at most 4 decimals, no trailing zeros.
fn num(x: f64) -> String {
    num_to(x, 4)
}

/// A number with at most `decimals` decimals, no trailing zeros.
fn num_to(x: f64, decimals: usize) -> String {
    let s = format!("{x:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        &s
    };
    s.to_owned()
}

/// The unit a metric's or a drawn path's name gives in its suffix (`max_rate_deg_s`:
/// `deg/s`; `detumble_s`: `s`), for an axis or a value; `None` for a name without one.
pub fn unit_of(name: &str) -> Option<&'static str> {
    /// Name suffixes and their units. The longest suffix that matches wins (`_deg_s` over
    /// `_s`), so the order does not matter.
    const UNITS: &[(&str, &str)] = &[
        ("_s", "s"),
        ("_ms", "ms"),
        ("_ns", "ns"),
        ("_deg_s", "deg/s"),
        ("_rad_s", "rad/s"),
        ("_m_s", "m/s"),
        ("_km_s", "km/s"),
        ("_deg", "deg"),
        ("_m", "m"),
        ("_km", "km"),
        ("_wh", "Wh"),
        ("_w", "W"),
        ("_v", "V"),
        ("_a", "A"),
        ("_nt", "nT"),
        ("_b", "B"),
        ("_bytes", "bytes"),
        ("_bps", "bit/s"),
        ("_pct", "%"),
        ("_soc", "of full charge"),
    ];
    UNITS
        .iter()
        .filter(|(suffix, _)| name.ends_with(suffix))
        .max_by_key(|(suffix, _)| suffix.len())
        .map(|(_, unit)| *unit)
}

/// The two ends of an axis: [`num`], or with more decimals (up to 12) where 4 would show
/// different values as one.
fn ends(lo: f64, hi: f64) -> (String, String) {
    (4..=12)
        .map(|d| (num_to(lo, d), num_to(hi, d)))
        .find(|(a, b)| a != b)
        .unwrap_or_else(|| (num(lo), num(hi)))
}

/// An axis's title: the name, and its unit when there is one.
fn axis_title(name: &str, unit: Option<&str>) -> String {
    match unit {
        Some(u) => format!("{} ({})", esc(name), esc(u)),
        None => esc(name),
    }
}

fn colour(v: &RunVerdict) -> &'static str {
    match v {
        RunVerdict::Pass => PASS,
        RunVerdict::Fail(_) => FAIL,
        RunVerdict::Error(_) => ERROR,
        RunVerdict::NotRun(_) => NOT_RUN,
    }
}

/// A drawn value as a number: a number, or a duration (in seconds).
fn number(v: &str) -> Option<f64> {
    v.parse::<f64>().ok().or_else(|| {
        crate::duration::parse_duration(v)
            .ok()
            .map(|d| d.as_secs_f64())
    })
}

/// Horizontal bars: (label, passed, total) each, the pass rate drawn and written.
fn rate_bars(out: &mut String, rows: &[(String, u64, u64)]) {
    let h = 22.0;
    let label_w = 220.0;
    let bar_w = WIDTH - label_w - 120.0;
    let height = h * rows.len() as f64 + 8.0;
    let _ = writeln!(
        out,
        r#"<svg width="{WIDTH}" height="{height}" role="img" aria-label="pass rate">"#
    );
    for (i, (label, pass, total)) in rows.iter().enumerate() {
        let y = 4.0 + h * i as f64;
        let rate = if *total == 0 {
            0.0
        } else {
            *pass as f64 / *total as f64
        };
        let _ = writeln!(
            out,
            r#"<text x="{x}" y="{ty}" text-anchor="end">{l}</text><rect x="{bx}" y="{y}" width="{bw}" height="{bh}" fill="{FAIL}" opacity="0.35"/><rect x="{bx}" y="{y}" width="{pw:.1}" height="{bh}" fill="{PASS}"><title>{l}: {pass} of {total} passed</title></rect><text x="{tx}" y="{ty}">{pct:.0} % of {total}</text>"#,
            x = label_w - 6.0,
            ty = y + 14.0,
            l = esc(label),
            bx = label_w,
            bw = bar_w,
            bh = h - 6.0,
            pw = bar_w * rate,
            tx = label_w + bar_w + 6.0,
            pct = rate * 100.0,
        );
    }
    out.push_str("</svg>\n");
}

/// A strip plot of one drawn number: every run a dot at its value, passes above, failures
/// below; the axis titled with the name and `unit`.
fn strip(out: &mut String, name: &str, unit: Option<&str>, points: &[(f64, &RunRow)]) {
    let (lo, hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (x, _)| {
            (lo.min(*x), hi.max(*x))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (left, right) = (60.0, WIDTH - 20.0);
    let x_of = |x: f64| left + (x - lo) / span * (right - left);
    let ends = ends(lo, hi);
    let _ = writeln!(
        out,
        r#"<svg width="{WIDTH}" height="110" role="img" aria-label="{n}"><text x="4" y="34">pass</text><text x="4" y="74">fail</text><line x1="{left}" y1="90" x2="{right}" y2="90" stroke="gray"/><text x="{left}" y="105">{lo}</text><text x="{mid}" y="105" text-anchor="middle">{title}</text><text x="{right}" y="105" text-anchor="end">{hi}</text>"#,
        n = esc(name),
        lo = ends.0,
        hi = ends.1,
        mid = (left + right) / 2.0,
        title = axis_title(name, unit),
    );
    for (x, r) in points {
        let lane = if r.verdict == RunVerdict::Pass {
            30.0
        } else {
            70.0
        };
        // A deterministic jitter from the run's index, so that equal values stay visible.
        let jitter = ((r.run.wrapping_mul(2_654_435_761) % 17) as f64) - 8.0;
        let _ = writeln!(
            out,
            r#"<circle cx="{cx:.1}" cy="{cy:.1}" r="3" fill="{c}" opacity="0.6"><title>run {k}: {n} = {x}</title></circle>"#,
            cx = x_of(*x),
            cy = lane + jitter,
            c = colour(&r.verdict),
            k = r.run,
            n = esc(name),
        );
    }
    out.push_str("</svg>\n");
}

/// A histogram of one metric, 20 bins, passes and failures stacked; the x axis titled with
/// the name and `unit`, the y axis counting runs.
fn histogram(out: &mut String, name: &str, unit: Option<&str>, values: &[(f64, &RunRow)]) {
    const BINS: usize = 20;
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (x, _)| {
            (lo.min(*x), hi.max(*x))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let mut bins = [(0u64, 0u64); BINS];
    for (x, r) in values {
        let i = (((x - lo) / span) * BINS as f64).floor() as usize;
        let b = &mut bins[i.min(BINS - 1)];
        if r.verdict == RunVerdict::Pass {
            b.0 += 1;
        } else {
            b.1 += 1;
        }
    }
    let top = bins.iter().map(|(p, f)| p + f).max().unwrap_or(1).max(1) as f64;
    let (left, plot_h) = (60.0, 120.0);
    let bw = (WIDTH - left - 20.0) / BINS as f64;
    let ends = ends(lo, hi);
    let _ = writeln!(
        out,
        r#"<svg width="{WIDTH}" height="{h}" role="img" aria-label="{n}"><text x="4" y="14">{top}</text><text x="4" y="{my}">runs</text><text x="4" y="{b}">0</text><text x="{left}" y="{lb}">{lo}</text><text x="{mid}" y="{lb}" text-anchor="middle">{title}</text><text x="{r}" y="{lb}" text-anchor="end">{hi}</text>"#,
        lo = ends.0,
        hi = ends.1,
        h = plot_h + 30.0,
        n = esc(name),
        b = plot_h,
        my = plot_h / 2.0,
        lb = plot_h + 20.0,
        r = WIDTH - 20.0,
        mid = (left + WIDTH - 20.0) / 2.0,
        title = axis_title(name, unit),
    );
    for (i, (p, f)) in bins.iter().enumerate() {
        let x = left + bw * i as f64;
        let ph = plot_h * *p as f64 / top;
        let fh = plot_h * *f as f64 / top;
        let _ = writeln!(
            out,
            r#"<rect x="{x:.1}" y="{py:.1}" width="{w:.1}" height="{ph:.1}" fill="{PASS}"><title>{p} passed</title></rect><rect x="{x:.1}" y="{fy:.1}" width="{w:.1}" height="{fh:.1}" fill="{FAIL}"><title>{f} failed</title></rect>"#,
            py = plot_h - ph,
            fy = plot_h - ph - fh,
            w = bw - 1.0,
        );
    }
    out.push_str("</svg>\n");
}

/// The page.
pub fn report_html(meta: &CampaignMeta, rows: &[RunRow]) -> String {
    let mut out = String::new();
    page_head(&mut out, meta, rows);
    failures_by_check_html(&mut out, rows);
    sessions_html(&mut out, meta, rows);
    fault_kinds(&mut out, rows);
    drawn_values(&mut out, rows);
    metric_histograms(&mut out, rows);
    failures(&mut out, rows);
    out.push_str("</body></html>\n");
    out
}

/// The page's head and style, and the verdicts' totals.
fn page_head(out: &mut String, meta: &CampaignMeta, rows: &[RunRow]) {
    let count = |w: &str| rows.iter().filter(|r| r.verdict.word() == w).count();
    let (pass, fail, error) = (count("pass"), count("fail"), count("error"));
    let not_run = match count("not run") {
        0 => String::new(),
        k => format!(", <b class=\"not-run\">{k} not run</b> (the campaign was stopped)"),
    };
    let _ = write!(
        out,
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>campaign {name}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; max-width: 60em; color: #222; }}
svg {{ display: block; margin: 0.5em 0 1.5em; font-size: 12px; }}
table {{ border-collapse: collapse; font-size: 13px; }}
td, th {{ border: 1px solid #ccc; padding: 2px 6px; text-align: left; vertical-align: top; }}
.pass {{ color: {PASS}; }} .fail {{ color: {FAIL}; }} .error {{ color: {ERROR}; }} .not-run {{ color: {NOT_RUN}; }}
</style></head><body>
<h1>Campaign {name}</h1>
<p>{file}, seed {seed}: {n} runs, <b class="pass">{pass} passed</b>, <b class="fail">{fail} failed</b>, <b class="error">{error} errors</b>{not_run}.</p>
"#,
        name = esc(&meta.name),
        file = esc(&meta.file),
        seed = meta.seed,
        n = rows.len(),
    );
}

/// Pass rate per fault kind: which kinds of fault the failures follow.
fn fault_kinds(out: &mut String, rows: &[RunRow]) {
    let mut kinds: BTreeMap<String, (u64, u64)> = BTreeMap::new();
    for r in rows {
        if let Some(f) = r.draws.get("faults") {
            let mut seen: Vec<&str> = f
                .split_whitespace()
                .map(|k| k.split('#').next().unwrap_or(k))
                .collect();
            seen.sort_unstable();
            seen.dedup();
            for k in seen {
                let e = kinds.entry(k.to_owned()).or_default();
                e.1 += 1;
                if r.verdict == RunVerdict::Pass {
                    e.0 += 1;
                }
            }
        }
    }
    if !kinds.is_empty() {
        out.push_str("<h2>Pass rate per fault kind</h2>\n<p>Runs that drew the kind (among others), and how many of them passed.</p>\n");
        let bars: Vec<_> = kinds.into_iter().map(|(k, (p, t))| (k, p, t)).collect();
        rate_bars(out, &bars);
    }
}

/// The drawn values against the verdicts: which dispersions the failures follow.
fn drawn_values(out: &mut String, rows: &[RunRow]) {
    let mut columns: Vec<&String> = rows
        .iter()
        .flat_map(|r| r.draws.keys())
        .filter(|k| *k != "faults")
        .collect();
    columns.sort();
    columns.dedup();
    if !columns.is_empty() {
        out.push_str("<h2>Failures against the drawn values</h2>\n");
    }
    for col in columns {
        let values: Vec<(&str, &RunRow)> = rows
            .iter()
            .filter_map(|r| r.draws.get(col).map(|v| (v.as_str(), r)))
            .collect();
        let _ = writeln!(out, "<h3>{}</h3>", esc(col));
        let numbers: Option<Vec<(f64, &RunRow)>> = values
            .iter()
            .map(|(v, r)| number(v).map(|x| (x, *r)))
            .collect();
        match numbers {
            Some(points) => {
                // A duration is plotted in seconds.
                let unit = unit_of(col).or_else(|| {
                    values
                        .iter()
                        .any(|(v, _)| v.parse::<f64>().is_err())
                        .then_some("s")
                });
                strip(out, col, unit, &points);
            }
            None => {
                let mut by: BTreeMap<&str, (u64, u64)> = BTreeMap::new();
                for (v, r) in &values {
                    let e = by.entry(v).or_default();
                    e.1 += 1;
                    if r.verdict == RunVerdict::Pass {
                        e.0 += 1;
                    }
                }
                let bars: Vec<_> = by
                    .into_iter()
                    .map(|(v, (p, t))| (v.to_owned(), p, t))
                    .collect();
                rate_bars(out, &bars);
            }
        }
    }
}

/// A histogram per metric the runs measured, passes apart from the others; a metric with
/// one value in every run that has it (a body rate that stays 0) is one line.
fn metric_histograms(out: &mut String, rows: &[RunRow]) {
    let mut metrics: Vec<&String> = rows.iter().flat_map(|r| r.metrics.keys()).collect();
    metrics.sort();
    metrics.dedup();
    if !metrics.is_empty() {
        out.push_str("<h2>Metrics</h2>\n<p>Green: runs that passed; red: the others.</p>\n");
    }
    for m in metrics {
        let values: Vec<(f64, &RunRow)> = rows
            .iter()
            .filter_map(|r| r.metrics.get(m).map(|v| (*v, r)))
            .collect();
        let unit = unit_of(m);
        if let Some((first, _)) = values.first()
            && values.iter().all(|(x, _)| x == first)
        {
            let others = if values.len() < rows.len() {
                " (the other runs did not measure it)"
            } else {
                ""
            };
            let _ = writeln!(
                out,
                "<p><b>{}</b>: all {} runs: {}{}{others}</p>",
                esc(m),
                values.len(),
                num(*first),
                unit.map_or_else(String::new, |u| format!(" {}", esc(u))),
            );
            continue;
        }
        let _ = writeln!(out, "<h3>{} ({} runs)</h3>", esc(m), values.len());
        histogram(out, m, unit, &values);
    }
}

/// One check that failed in some run of a campaign.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CheckFailures {
    /// The check's name, as its verdict gives it (`invariant soc-range`, `fc-answers`).
    pub name: String,
    /// An expectation or an invariant; `None` when the rows did not keep it.
    pub kind: Option<CheckKind>,
    /// The runs that failed it.
    pub failed: u64,
    /// The runs judged: passed or failed (a run that ended in an error, or was not run,
    /// judged nothing).
    pub judged: u64,
    /// The first run (lowest index) that failed it.
    pub first: u64,
}

/// Every check that failed in any run: the most failed first, then by name.
pub fn failures_by_check(rows: &[RunRow]) -> Vec<CheckFailures> {
    let judged = rows
        .iter()
        .filter(|r| matches!(r.verdict, RunVerdict::Pass | RunVerdict::Fail(_)))
        .count() as u64;
    let mut by: BTreeMap<&str, CheckFailures> = BTreeMap::new();
    for r in rows {
        let RunVerdict::Fail(f) = &r.verdict else {
            continue;
        };
        let mut names: Vec<&str> = f.iter().map(|(n, _)| n.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        for name in names {
            let kind = r.failed_kinds.get(name).copied();
            let c = by.entry(name).or_insert_with(|| CheckFailures {
                name: name.to_owned(),
                kind,
                failed: 0,
                judged,
                first: r.run,
            });
            c.failed += 1;
            c.first = c.first.min(r.run);
            c.kind = c.kind.or(kind);
        }
    }
    let mut checks: Vec<CheckFailures> = by.into_values().collect();
    checks.sort_by(|a, b| b.failed.cmp(&a.failed).then_with(|| a.name.cmp(&b.name)));
    checks
}

/// A check's kind as a word; `?` when the rows did not keep it.
fn kind_word(kind: Option<CheckKind>) -> &'static str {
    kind.map_or("?", CheckKind::word)
}

/// The failures by check for a terminal: a title, a header and a line per check; empty when
/// no check failed.
pub fn failures_by_check_text(rows: &[RunRow]) -> String {
    let checks = failures_by_check(rows);
    if checks.is_empty() {
        return String::new();
    }
    let w = checks
        .iter()
        .map(|c| c.name.len())
        .fold("check".len(), usize::max);
    let failed: Vec<String> = checks
        .iter()
        .map(|c| format!("{} of {}", c.failed, c.judged))
        .collect();
    let fw = failed
        .iter()
        .map(String::len)
        .fold("runs failed".len(), usize::max);
    let mut out = format!(
        "failures by check:\n  {:<w$}  {:<11}  {:>fw$}  first\n",
        "check", "kind", "runs failed"
    );
    for (c, f) in checks.iter().zip(&failed) {
        let _ = writeln!(
            out,
            "  {:<w$}  {:<11}  {f:>fw$}  run {}",
            c.name,
            kind_word(c.kind),
            c.first
        );
    }
    out
}

/// The failures by check, near the top: which expectation or invariant fails, and how often.
fn failures_by_check_html(out: &mut String, rows: &[RunRow]) {
    let checks = failures_by_check(rows);
    if checks.is_empty() {
        return;
    }
    out.push_str("<h2>Failures by check</h2>\n<p>Each expectation or invariant that failed in any run, the most failed first: the runs that failed it, of the runs judged (passed or failed), and the first.</p>\n<table><tr><th>check</th><th>kind</th><th>runs failed</th><th>first failing run</th></tr>\n");
    for c in checks {
        let _ = writeln!(
            out,
            r#"<tr><td>{n}</td><td>{kind}</td><td class="fail">{f} of {t} ({pct:.0} %)</td><td><a href="failures/run-{k}.toml">run {k}</a></td></tr>"#,
            n = esc(&c.name),
            kind = kind_word(c.kind),
            f = c.failed,
            t = c.judged,
            pct = 100.0 * c.failed as f64 / c.judged.max(1) as f64,
            k = c.first,
        );
    }
    out.push_str("</table>\n");
}

/// The lowest, the median and the highest of some runs' figures. The median of an even
/// count is the lower of the two middle values: a value some run had.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Spread {
    /// The lowest.
    pub min: u64,
    /// The median.
    pub median: u64,
    /// The highest.
    pub max: u64,
}

impl Spread {
    /// The spread of `values`; `None` when there are none.
    pub fn of(mut values: Vec<u64>) -> Option<Spread> {
        values.sort_unstable();
        Some(Spread {
            min: *values.first()?,
            median: values[(values.len() - 1) / 2],
            max: *values.last()?,
        })
    }

    /// `min / median / max unit`.
    fn text(self, unit: &str) -> String {
        format!("{} / {} / {} {unit}", self.min, self.median, self.max)
    }
}

/// One payload session id over a campaign's runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionAcross {
    /// The session id.
    pub session: u8,
    /// The payloads its runs polled, in any run.
    pub payloads: BTreeSet<u8>,
    /// The campaign runs it ran in (it had a session run there).
    pub runs: u64,
    /// The campaign runs that ran to their end (passed or failed), which `runs` is of: a
    /// run that ended in an error, or was not run, kept no sessions.
    pub judged: u64,
    /// Its session runs over all the campaign's runs, by how they ended.
    pub ends: BTreeMap<SessionEnd, u64>,
    /// Packets the PC counted for it per campaign run it ran in.
    pub packets: Spread,
    /// Bytes of it downlinked per campaign run it ran in.
    pub downlinked_bytes: Spread,
    /// The campaign runs in which a session run of it ended other than `done`, by index,
    /// with those ends and how many.
    pub not_done: Vec<(u64, BTreeMap<SessionEnd, u32>)>,
}

/// Every payload session id that ran in any run, by id.
pub fn sessions_across(rows: &[RunRow]) -> Vec<SessionAcross> {
    let judged = rows
        .iter()
        .filter(|r| matches!(r.verdict, RunVerdict::Pass | RunVerdict::Fail(_)))
        .count() as u64;
    let ids: BTreeSet<u8> = rows
        .iter()
        .flat_map(|r| r.sessions.keys().copied())
        .collect();
    ids.into_iter()
        .filter_map(|session| {
            let tallies: Vec<(u64, &crate::campaign_rows::SessionTally)> = rows
                .iter()
                .filter_map(|r| r.sessions.get(&session).map(|t| (r.run, t)))
                .collect();
            let mut ends: BTreeMap<SessionEnd, u64> = BTreeMap::new();
            for (_, t) in &tallies {
                for (e, n) in &t.ends {
                    *ends.entry(*e).or_default() += u64::from(*n);
                }
            }
            Some(SessionAcross {
                session,
                payloads: tallies
                    .iter()
                    .flat_map(|(_, t)| t.payloads.iter().copied())
                    .collect(),
                runs: tallies.len() as u64,
                judged,
                ends,
                packets: Spread::of(tallies.iter().map(|(_, t)| t.packets).collect())?,
                downlinked_bytes: Spread::of(
                    tallies.iter().map(|(_, t)| t.downlinked_bytes).collect(),
                )?,
                not_done: tallies
                    .iter()
                    .filter(|(_, t)| t.any_not_done())
                    .map(|(run, t)| {
                        let ends = t
                            .ends
                            .iter()
                            .filter(|(e, n)| **e != SessionEnd::Done && **n > 0)
                            .map(|(e, n)| (*e, *n))
                            .collect();
                        (*run, ends)
                    })
                    .collect(),
            })
        })
        .collect()
}

/// The ends any session run of the campaign had, in table order: a column each.
fn end_columns(sessions: &[SessionAcross]) -> Vec<SessionEnd> {
    SessionEnd::ALL
        .into_iter()
        .filter(|e| sessions.iter().any(|s| s.ends.contains_key(e)))
        .collect()
}

/// A session's payloads: `12`, `12, 13`, or `-` (no run of it started).
fn payloads_text(p: &BTreeSet<u8>) -> String {
    if p.is_empty() {
        return "-".to_owned();
    }
    p.iter().map(u8::to_string).collect::<Vec<_>>().join(", ")
}

/// The sessions for a terminal: a title, a header and a line per session id (the runs where
/// it ended other than done: the first 10); empty when no run had a session.
pub fn sessions_text(rows: &[RunRow]) -> String {
    const RUNS_SHOWN: usize = 10;
    let sessions = sessions_across(rows);
    if sessions.is_empty() {
        return String::new();
    }
    let ends = end_columns(&sessions);
    let mut head: Vec<String> = ["session", "payload", "ran in"].map(str::to_owned).to_vec();
    head.extend(ends.iter().map(|e| e.word().to_owned()));
    head.extend(
        [
            "packets (min / median / max)",
            "downlinked (min / median / max)",
            "not done",
        ]
        .map(str::to_owned),
    );
    let mut lines = vec![head];
    for s in &sessions {
        let mut line = vec![
            s.session.to_string(),
            payloads_text(&s.payloads),
            format!("{} of {}", s.runs, s.judged),
        ];
        line.extend(
            ends.iter()
                .map(|e| s.ends.get(e).copied().unwrap_or(0).to_string()),
        );
        let runs: Vec<String> = s
            .not_done
            .iter()
            .take(RUNS_SHOWN)
            .map(|(k, _)| k.to_string())
            .collect();
        let not_done = match s.not_done.len() {
            0 => "-".to_owned(),
            n if n > RUNS_SHOWN => format!("runs {} and {} more", runs.join(", "), n - RUNS_SHOWN),
            1 => format!("run {}", runs[0]),
            _ => format!("runs {}", runs.join(", ")),
        };
        line.extend([
            s.packets.text("packets"),
            s.downlinked_bytes.text("B"),
            not_done,
        ]);
        lines.push(line);
    }
    let widths: Vec<usize> = (0..lines[0].len())
        .map(|i| lines.iter().map(|l| l[i].len()).max().unwrap_or(0))
        .collect();
    let mut out = String::from("sessions:\n");
    for l in &lines {
        let cells: Vec<String> = l
            .iter()
            .zip(&widths)
            .map(|(c, w)| format!("{c:<w$}"))
            .collect();
        let _ = writeln!(out, "  {}", cells.join("  ").trim_end());
    }
    out
}

/// Whether the run has a failure file (`failures/run-<k>.toml`): a result that did not pass,
/// as [`crate::campaign_run::write_outputs`] writes them.
fn has_failure_file(r: &RunRow) -> bool {
    r.verdict != RunVerdict::Pass && r.verdict.is_result() && !r.scenario.is_empty()
}

/// The payload sessions: each session id, in how many runs it ran, its session runs by how
/// they ended, packets and bytes per run, and the runs where it ended other than done
/// (linked to their failure file where they have one). One line when no run had a session.
fn sessions_html(out: &mut String, meta: &CampaignMeta, rows: &[RunRow]) {
    let sessions = sessions_across(rows);
    out.push_str("<h2>Sessions</h2>\n");
    if sessions.is_empty() {
        out.push_str("<p>No payload session ran in any run.</p>\n");
        return;
    }
    let _ = writeln!(
        out,
        "<p>Each payload session id, over the runs that ran to their end (passed or failed): the runs it ran in, its session runs by how they ended, the packets the PC counted and the bytes downlinked per run it ran in (min / median / max), and the runs in which a session run ended other than done. A run that failed links to its scenario; <code>m6p-twin campaign resolve {} K</code> writes run K's.</p>",
        esc(&meta.file)
    );
    let ends = end_columns(&sessions);
    out.push_str("<table><tr><th>session</th><th>payload</th><th>ran in</th>");
    for e in &ends {
        let _ = write!(out, "<th>{}</th>", esc(e.word()));
    }
    out.push_str("<th>packets per run (min / median / max)</th><th>downlinked per run (min / median / max)</th><th>runs where it ended other than done</th></tr>\n");
    let by_run: BTreeMap<u64, &RunRow> = rows.iter().map(|r| (r.run, r)).collect();
    for s in &sessions {
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{} of {} runs</td>",
            s.session,
            payloads_text(&s.payloads),
            s.runs,
            s.judged
        );
        for e in &ends {
            let _ = write!(out, "<td>{}</td>", s.ends.get(e).copied().unwrap_or(0));
        }
        // By end: `no-ack: run 2, run 3 (2)`, a run linked where it has a failure file.
        let not_done = ends
            .iter()
            .filter(|e| **e != SessionEnd::Done)
            .filter_map(|e| {
                let runs: Vec<String> = s
                    .not_done
                    .iter()
                    .filter_map(|(k, ends)| {
                        let n = ends.get(e)?;
                        let run = if by_run.get(k).is_some_and(|r| has_failure_file(r)) {
                            format!(r#"<a href="failures/run-{k}.toml">run {k}</a>"#)
                        } else {
                            format!("run {k}")
                        };
                        Some(if *n > 1 { format!("{run} ({n})") } else { run })
                    })
                    .collect();
                (!runs.is_empty()).then(|| format!("<b>{}</b>: {}", esc(e.word()), runs.join(", ")))
            })
            .collect::<Vec<_>>()
            .join("<br>");
        let _ = writeln!(
            out,
            "<td>{}</td><td>{}</td><td>{}</td></tr>",
            s.packets.text("packets"),
            s.downlinked_bytes.text("B"),
            if not_done.is_empty() {
                "-".to_owned()
            } else {
                not_done
            }
        );
    }
    out.push_str("</table>\n");
}

/// The runs that did not pass, with what they drew and why, linked to their scenarios.
fn failures(out: &mut String, rows: &[RunRow]) {
    let failed: Vec<&RunRow> = rows
        .iter()
        .filter(|r| r.verdict != RunVerdict::Pass)
        .collect();
    if !failed.is_empty() {
        out.push_str(
            "<h2>Failures</h2>\n<table><tr><th>run</th><th>drew</th><th>failed</th></tr>\n",
        );
        for r in failed {
            let drew = r
                .draws
                .iter()
                .map(|(k, v)| format!("{} = {}", esc(k), esc(v)))
                .collect::<Vec<_>>()
                .join("<br>");
            let why = match &r.verdict {
                RunVerdict::Fail(f) => f
                    .iter()
                    .map(|(n, o)| format!("<b>{}</b>: {}", esc(n), esc(o)))
                    .collect::<Vec<_>>()
                    .join("<br>"),
                RunVerdict::Error(e) => format!("<b>error</b>: {}", esc(e)),
                RunVerdict::NotRun(e) => format!("<b>not run</b>: {}", esc(e)),
                RunVerdict::Pass => String::new(),
            };
            let _ = writeln!(
                out,
                r#"<tr><td><a href="failures/run-{k}.toml">{k}</a></td><td>{drew}</td><td class="{w}">{why}</td></tr>"#,
                k = r.run,
                w = r.verdict.word(),
            );
        }
        out.push_str("</table>\n");
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Campaign `c` of 5 runs, as the reports below name it.
    fn five_run_meta() -> CampaignMeta {
        CampaignMeta {
            name: "c".into(),
            file: "c.toml".into(),
            seed: 1,
            runs: 5,
        }
    }

    fn row(run: u64, draws: &[(&str, &str)], verdict: RunVerdict, soc: f64) -> RunRow {
        RunRow {
            run,
            seed: run,
            draws: draws
                .iter()
                .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
                .collect(),
            verdict,
            failed_kinds: BTreeMap::new(),
            metrics: BTreeMap::from([("min_soc".to_owned(), soc)]),
            sessions: BTreeMap::new(),
            scenario: String::new(),
        }
    }

    /// Run `run`, failing `checks` (none: a pass), with `metrics`.
    fn judged(run: u64, checks: &[(&str, CheckKind)], metrics: &[(&str, f64)]) -> RunRow {
        let verdict = if checks.is_empty() {
            RunVerdict::Pass
        } else {
            RunVerdict::Fail(
                checks
                    .iter()
                    .map(|(n, _)| ((*n).to_owned(), "t = 1 s: no".to_owned()))
                    .collect(),
            )
        };
        RunRow {
            run,
            seed: run,
            draws: BTreeMap::new(),
            verdict,
            failed_kinds: checks.iter().map(|(n, k)| ((*n).to_owned(), *k)).collect(),
            metrics: metrics.iter().map(|(n, v)| ((*n).to_owned(), *v)).collect(),
            sessions: BTreeMap::new(),
            scenario: String::new(),
        }
    }

    /// Runs 0-4: `invariant soc-range` fails in runs 1, 3 and 4, `fc-answers` in run 3, run
    /// 2 ends in an error; `max_rate_deg_s` is 0 in every run, `detumble_s` varies.
    fn five_runs() -> Vec<RunRow> {
        let inv = ("invariant soc-range", CheckKind::Invariant);
        let exp = ("fc-answers", CheckKind::Expectation);
        let m = |d: f64| [("max_rate_deg_s", 0.0), ("detumble_s", d)];
        let mut error = judged(2, &[], &m(30.0));
        error.verdict = RunVerdict::Error("it broke".into());
        vec![
            judged(0, &[], &m(10.0)),
            judged(1, &[inv], &m(20.0)),
            error,
            judged(3, &[inv, exp], &m(40.0)),
            judged(4, &[inv], &m(50.0)),
        ]
    }

    #[test]
    fn failures_by_check_count_the_runs_that_failed_each_check_of_those_judged() {
        let rows = five_runs();
        let checks = failures_by_check(&rows);
        let c = |name: &str, kind, failed, first| CheckFailures {
            name: name.into(),
            kind: Some(kind),
            failed,
            judged: 4,
            first,
        };
        assert_eq!(
            checks,
            vec![
                c("invariant soc-range", CheckKind::Invariant, 3, 1),
                c("fc-answers", CheckKind::Expectation, 1, 3),
            ]
        );
        let text = failures_by_check_text(&rows);
        assert_eq!(
            text,
            "failures by check:\n\
             \x20 check                kind         runs failed  first\n\
             \x20 invariant soc-range  invariant         3 of 4  run 1\n\
             \x20 fc-answers           expectation       1 of 4  run 3\n",
            "{text}"
        );
        assert_eq!(failures_by_check_text(&rows[..1]), "");
        let html = report_html(&five_run_meta(), &rows);
        let table = html.find("<h2>Failures by check</h2>").unwrap();
        // Near the top: before the plots and the list of failures.
        assert!(table < html.find("<h2>Metrics</h2>").unwrap());
        assert!(html.contains(
            r#"<tr><td>invariant soc-range</td><td>invariant</td><td class="fail">3 of 4 (75 %)</td><td><a href="failures/run-1.toml">run 1</a></td></tr>"#
        ), "{html}");
        assert!(html.contains(
            r#"<tr><td>fc-answers</td><td>expectation</td><td class="fail">1 of 4 (25 %)</td>"#
        ));
    }

    /// Session `id` in a run: `ends`, `packets`, `bytes`, polling payload 12.
    fn tally(
        ends: &[(SessionEnd, u32)],
        packets: u64,
        bytes: u64,
    ) -> crate::campaign_rows::SessionTally {
        crate::campaign_rows::SessionTally {
            payloads: [12].into(),
            ends: ends.iter().copied().collect(),
            packets,
            downlinked_bytes: bytes,
        }
    }

    /// Session 1 runs in runs 0-4 (no-ack in run 1, which passed, and in run 3, which
    /// failed; lost in run 3 too), session 2 only in run 4; run 2 ended in an error (no
    /// sessions kept): the counts per end, the spreads per run it ran in, and the runs not
    /// done, linked where they have a failure file.
    #[test]
    fn sessions_are_counted_per_id_over_the_runs_with_their_spreads_and_the_runs_not_done() {
        use SessionEnd::{Done, LostPower, NoAck};
        let mut rows = five_runs();
        // Run 1 passes; an unsharded campaign's rows keep every run's scenario, a pass has
        // no failure file all the same.
        rows[1].verdict = RunVerdict::Pass;
        rows[1].failed_kinds.clear();
        for k in [1, 3] {
            rows[k].scenario = format!("name = \"run {k}\"\n");
        }
        let per_run = [
            tally(&[(Done, 1)], 90, 9000),
            tally(&[(NoAck, 1)], 0, 0),
            tally(&[(Done, 1)], 0, 0),
            tally(&[(NoAck, 2), (LostPower, 1)], 10, 1000),
            tally(&[(Done, 1)], 80, 8000),
        ];
        for (r, t) in rows.iter_mut().zip(per_run) {
            if !matches!(r.verdict, RunVerdict::Error(_)) {
                r.sessions.insert(1, t);
            }
        }
        rows[4].sessions.insert(2, tally(&[(Done, 1)], 5, 500));
        let s = sessions_across(&rows);
        assert_eq!(
            s[0],
            SessionAcross {
                session: 1,
                payloads: [12].into(),
                runs: 4,
                judged: 4,
                ends: [(Done, 2), (NoAck, 3), (LostPower, 1)].into(),
                packets: Spread {
                    min: 0,
                    median: 10,
                    max: 90
                },
                downlinked_bytes: Spread {
                    min: 0,
                    median: 1000,
                    max: 9000
                },
                not_done: vec![
                    (1, [(NoAck, 1)].into()),
                    (3, [(NoAck, 2), (LostPower, 1)].into()),
                ],
            }
        );
        assert_eq!((s[1].session, s[1].runs, s.len()), (2, 1, 2));
        let text = sessions_text(&rows);
        assert_eq!(
            text,
            "sessions:\n\
             \x20 session  payload  ran in  done  no-ack  lost (power)  packets (min / median / max)  downlinked (min / median / max)  not done\n\
             \x20 1        12       4 of 4  2     3       1             0 / 10 / 90 packets           0 / 1000 / 9000 B                runs 1, 3\n\
             \x20 2        12       1 of 4  1     0       0             5 / 5 / 5 packets             500 / 500 / 500 B                -\n",
            "{text}"
        );
        let html = report_html(&five_run_meta(), &rows);
        let at = html.find("<h2>Sessions</h2>").unwrap();
        assert!(at > html.find("<h2>Failures by check</h2>").unwrap());
        assert!(at < html.find("<h2>Metrics</h2>").unwrap());
        assert!(html.contains(
            "<tr><td>1</td><td>12</td><td>4 of 4 runs</td><td>2</td><td>3</td><td>1</td><td>0 / 10 / 90 packets</td><td>0 / 1000 / 9000 B</td><td><b>no-ack</b>: run 1, <a href=\"failures/run-3.toml\">run 3</a> (2)<br><b>lost (power)</b>: <a href=\"failures/run-3.toml\">run 3</a></td></tr>"
        ), "{html}");
        assert!(html.contains(
            "<tr><td>2</td><td>12</td><td>1 of 4 runs</td><td>1</td><td>0</td><td>0</td><td>5 / 5 / 5 packets</td><td>500 / 500 / 500 B</td><td>-</td></tr>"
        ), "{html}");
        assert!(html.contains("campaign resolve c.toml K"), "{html}");
    }

    /// No run had a session: one line, no table; nothing on the terminal.
    #[test]
    fn a_campaign_without_sessions_says_so_in_one_line() {
        let html = report_html(&five_run_meta(), &five_runs());
        let section: Vec<&str> = html
            .lines()
            .skip_while(|l| *l != "<h2>Sessions</h2>")
            .take_while(|l| !l.starts_with("<h2>Pass") && !l.starts_with("<h2>Metrics"))
            .collect();
        assert_eq!(
            section,
            [
                "<h2>Sessions</h2>",
                "<p>No payload session ran in any run.</p>"
            ],
            "{html}"
        );
        assert_eq!(sessions_text(&five_runs()), "");
        assert_eq!(Spread::of(vec![]), None);
        assert_eq!(Spread::of(vec![4, 1, 3, 2]).map(|s| s.median), Some(2));
    }

    #[test]
    fn a_metric_with_one_value_is_a_line_and_the_others_axes_carry_their_units() {
        let html = report_html(&five_run_meta(), &five_runs());
        assert!(
            html.contains("<p><b>max_rate_deg_s</b>: all 5 runs: 0 deg/s</p>"),
            "{html}"
        );
        assert!(!html.contains(r#"aria-label="max_rate_deg_s""#));
        assert!(html.contains(r#"aria-label="detumble_s""#));
        assert!(html.contains(">detumble_s (s)</text>"), "{html}");
        assert!(html.contains(r#"<text x="4" y="60">runs</text>"#), "{html}");
    }

    #[test]
    fn units_come_from_the_names_suffix_the_longest_that_matches() {
        assert_eq!(unit_of("max_rate_deg_s"), Some("deg/s"));
        assert_eq!(unit_of("detumble_s"), Some("s"));
        assert_eq!(unit_of("fc.initial_rate_deg_s"), Some("deg/s"));
        assert_eq!(unit_of("downlinked_bytes"), Some("bytes"));
        assert_eq!(unit_of("energy_wh"), Some("Wh"));
        assert_eq!(unit_of("queued_b"), Some("B"));
        assert_eq!(unit_of("min_soc"), Some("of full charge"));
        assert_eq!(unit_of("verdicts"), None);
        assert_eq!(unit_of("faults[0].at"), None);
    }

    #[test]
    fn an_axis_shows_its_ends_apart_when_they_differ() {
        assert_eq!(ends(0.5, 2.25), ("0.5".into(), "2.25".into()));
        assert_eq!(
            ends(0.799_973_04, 0.799_973_8),
            ("0.799973".into(), "0.799974".into())
        );
        assert_eq!(ends(3.0, 3.0), ("3".into(), "3".into()));
    }

    #[test]
    fn the_page_has_each_section_and_escapes_what_it_quotes() {
        let fail = || RunVerdict::Fail(vec![("fc-answers".into(), "t = 1 s: <no reply>".into())]);
        let rows = vec![
            row(
                0,
                &[("faults", "hang#1 clock#3"), ("x", "1.5"), ("b", "normal")],
                RunVerdict::Pass,
                0.8,
            ),
            row(
                1,
                &[("faults", "hang#1"), ("x", "2.5"), ("b", "no-ack")],
                fail(),
                0.4,
            ),
            row(
                2,
                &[("faults", "clock#3"), ("x", "30s"), ("b", "normal")],
                RunVerdict::Pass,
                0.6,
            ),
        ];
        let meta = CampaignMeta {
            name: "t<1>".into(),
            file: "c.toml".into(),
            seed: 1,
            runs: 3,
        };
        let html = report_html(&meta, &rows);
        assert!(html.contains("Campaign t&lt;1&gt;"));
        assert!(html.contains("2 passed") && html.contains("1 failed"));
        // hang: 1 of 2 passed; clock: 2 of 2.
        assert!(html.contains("hang: 1 of 2 passed") && html.contains("clock: 2 of 2 passed"));
        assert!(html.contains("<h3>x</h3>") && html.contains("run 2: x = 30"));
        // `30s` is a duration: the axis is in seconds.
        assert!(html.contains(">x (s)</text>"));
        assert!(html.contains("normal: 2 of 2 passed"));
        assert!(html.contains("<h3>min_soc (3 runs)</h3>"));
        assert!(html.contains(r#"<a href="failures/run-1.toml">1</a>"#));
        assert!(html.contains("&lt;no reply&gt;") && !html.contains("<no reply>"));
        assert_eq!(html, report_html(&meta, &rows));
    }
}
