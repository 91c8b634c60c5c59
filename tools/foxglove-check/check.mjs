#!/usr/bin/env node
// Opens a m6p-twin recording (or a live run) in the real Foxglove Studio 1.48 web app
// (@foxglove/studio-base's build) in headless Chromium, with docs/foxglove-layout.json, and
// checks what a person would see: the data source's topics, its Problems tab, and that every
// panel of every tab of the layout draws data. Writes a screenshot of each tab.
//
//   node check.mjs --recording FILE.mcap [--screenshots DIR] [--strict]
//   node check.mjs --live ws://127.0.0.1:PORT [--screenshots DIR] [--wait 120]
//
// Exit status 0 when every assertion holds; 1 with "FAIL: ..." lines otherwise; 2 for usage.
// README.md beside this file says what is asserted and how.
import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";
import puppeteer from "puppeteer-core";

import { readMcapSummary, nsToRfc3339 } from "./mcap-summary.mjs";
import { startServer } from "./server.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));

// Topics every recording and live run has (registered at the start: docs/recording.md).
const BASE_TOPICS = [
  "/can/main/frames", "/can/payload/frames", "/ground/packets", "/csp/packets",
  "/log", "/faults", "/commands", "/expectations",
];
// The FC truth topics the layout's ADCS tab uses (the 3D panel's transforms come from the
// two tf topics, which the layout does not name).
const TRUTH_TOPICS = [
  "/fc/truth/tf", "/fc/estimate/tf", "/fc/truth/location", "/fc/truth/state", "/fc/adcs", "/fc/scene",
];

// Every other topic the twin can record (docs/recording.md, "Channels"): a layout topic that is
// none of these is a typo, whatever the data.
const OTHER_TOPICS = [
  "/pc/sessions", "/pc/sessions/summary", "/pc/downlink", "/payloads", "/eps/power", "/eps/channels",
  "/ground/beacons", "/can/main/errors", "/can/payload/errors",
];
const KNOWN_TOPIC = (t) => BASE_TOPICS.includes(t) || TRUTH_TOPICS.includes(t) || OTHER_TOPICS.includes(t) || t.startsWith("/kiss/");

const USAGE = `usage: node check.mjs (--recording FILE.mcap | --live ws://127.0.0.1:PORT) [options]
  --layout FILE        layout to apply [default: docs/foxglove-layout.json of this repo]
  --screenshots DIR    write a PNG of each tab (and the Problems tab) into DIR
  --no-truth           do not require the FC truth topics (/fc/...): scenarios without them
  --every-panel        also fail on panels whose topics are not in the data (n/a): every
                       panel must draw (a scenario that has all the layout's data)
  --strict             --every-panel, and also fail on plot or state paths that draw nothing
                       while their topic has messages
  --wait SECONDS       how long a tab may take to show data [default: 60; live: 120]
  --chromium PATH      [default: /usr/bin/chromium]
  --headful            show the browser (needs a display)
  --keep-open          leave the browser and server running (Ctrl-C to end)`;

function parseArgs(argv) {
  const o = { layout: path.resolve(here, "../../docs/foxglove-layout.json"), chromium: "/usr/bin/chromium", truth: true, strict: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const val = () => {
      if (i + 1 >= argv.length) { usage(`${a} needs a value`); }
      return argv[++i];
    };
    switch (a) {
      case "--recording": o.recording = val(); break;
      case "--live": o.live = val(); break;
      case "--layout": o.layout = val(); break;
      case "--screenshots": o.screenshots = val(); break;
      case "--no-truth": o.truth = false; break;
      case "--strict": o.strict = true; break;
      case "--every-panel": o.everyPanel = true; break;
      case "--wait": o.wait = Number(val()); break;
      case "--chromium": o.chromium = val(); break;
      case "--headful": o.headful = true; break;
      case "--keep-open": o.keepOpen = true; break;
      case "-h": case "--help": console.log(USAGE); process.exit(0); break;
      default: usage(`unknown argument ${a}`);
    }
  }
  if (!o.recording === !o.live) { usage("give one of --recording FILE or --live URL"); }
  if (o.live && !/^wss?:\/\//.test(o.live)) { usage("--live takes a ws:// URL"); }
  o.wait = o.wait ?? (o.live ? 120 : 60);
  return o;
}

function usage(msg) {
  console.error(`${msg}\n${USAGE}`);
  process.exit(2);
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** The topic a message path reads: `/a/b{x==1}.c[0]` -> `/a/b`. */
function pathTopic(p) {
  const m = /^(\/[^.{[\s]*)/.exec(p);
  return m ? m[1] : undefined;
}

/** Tabs of the layout, each with its panels (ids, types, configs, the topics they read). */
function layoutTabs(layout) {
  const configs = layout.configById ?? {};
  const leaves = (node) => (typeof node === "string" ? [node] : node ? [...leaves(node.first), ...leaves(node.second)] : []);
  const panel = (id) => {
    const type = id.split("!")[0];
    const c = configs[id] ?? {};
    const paths = [];
    let topics = [];
    if (type === "Plot" || type === "StateTransitions") {
      for (const p of c.paths ?? []) {
        if (p.enabled === false) { continue; }
        paths.push({ value: p.value, label: p.label ? p.label : p.value, topic: pathTopic(p.value) });
      }
      topics = paths.map((p) => p.topic);
    } else if (type === "Table" || type === "RawMessages") {
      topics = [pathTopic(c.topicPath ?? "")];
    } else if (type === "RosOut") {
      topics = [c.topicToRender ?? "/rosout"];
    } else if (type === "map") {
      topics = [c.followTopic].filter(Boolean);
    } else if (type === "3D") {
      topics = Object.entries(c.topics ?? {}).filter(([, v]) => v.visible !== false).map(([k]) => k);
    }
    return { id, type, title: c.foxglovePanelTitle ?? id, config: c, paths, topics: [...new Set(topics.filter(Boolean))] };
  };
  const root = layout.layout;
  if (typeof root === "string" && root.startsWith("Tab!")) {
    return (configs[root]?.tabs ?? []).map((t, index) => ({ index, title: t.title, panels: leaves(t.layout).map(panel) }));
  }
  return [{ index: 0, title: "(no tabs)", panels: leaves(root).map(panel) }];
}

const slug = (s) => s.toLowerCase().replace(/[^a-z0-9]+/g, "-").replace(/^-|-$/g, "");

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const t0 = Date.now();
  const failures = [];
  const warnings = [];
  const fail = (m) => { failures.push(m); console.log(`FAIL: ${m}`); };
  const warn = (m) => { warnings.push(m); console.log(`warn: ${m}`); };

  const layout = JSON.parse(fs.readFileSync(opts.layout, "utf8"));
  const tabs = layoutTabs(layout);
  for (const tab of tabs) {
    for (const p of tab.panels) {
      for (const t of p.topics.filter((x) => !KNOWN_TOPIC(x))) { fail(`[${tab.title}] ${p.id} reads ${t}, which the twin never records`); }
    }
  }

  let summary;
  const files = {};
  let recUrlPath;
  if (opts.recording) {
    summary = readMcapSummary(opts.recording);
    recUrlPath = `/rec/${encodeURIComponent(path.basename(opts.recording))}`;
    files[decodeURIComponent(recUrlPath)] = path.resolve(opts.recording);
  }
  const srv = await startServer({ layoutFile: opts.layout, files });
  const params = new URLSearchParams();
  if (opts.recording) {
    params.set("ds", "remote-file");
    params.set("ds.url", srv.base + recUrlPath);
    // Open at the end, so the panels that show the latest message (Table, Raw Messages, Log)
    // have one; the plots show the whole file whatever the time.
    params.set("time", nsToRfc3339(summary.endNs));
  } else {
    params.set("ds", "foxglove-websocket");
    params.set("ds.url", opts.live);
  }
  params.set("layoutId", "m6p");
  const appUrl = `${srv.base}/?${params}`;

  if (opts.screenshots) { fs.mkdirSync(opts.screenshots, { recursive: true }); }
  const browser = await puppeteer.launch({
    executablePath: opts.chromium,
    headless: !opts.headful,
    args: [
      "--no-sandbox",
      "--disable-background-networking",
      "--window-size=1600,1000",
      // Nothing but this machine: the Map panel's tile server and anything else stay unresolved.
      "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
      "--enable-unsafe-swiftshader",
    ],
    defaultViewport: { width: 1600, height: 1000 },
  });
  const consoleErrors = [];
  let exitCode = 1;
  try {
    const page = await browser.newPage();
    page.on("pageerror", (e) => consoleErrors.push(`pageerror: ${String(e).split("\n")[0]}`));
    page.on("console", (m) => {
      if (m.type() === "error") { consoleErrors.push(m.text().split("\n")[0]); }
    });
    // Capture the Plot panels' "Download plot data as CSV" in the page instead of downloading.
    await page.evaluateOnNewDocument(() => {
      window.__m6pBlobs = new Map();
      const create = URL.createObjectURL.bind(URL);
      URL.createObjectURL = (obj) => {
        const url = create(obj);
        if (obj instanceof Blob && /csv/.test(obj.type)) { window.__m6pBlobs.set(url, obj); window.__m6pLastCsv = url; }
        return url;
      };
      const revoke = URL.revokeObjectURL.bind(URL);
      URL.revokeObjectURL = (url) => { if (!window.__m6pBlobs.has(url)) { revoke(url); } };
      const click = HTMLAnchorElement.prototype.click;
      HTMLAnchorElement.prototype.click = function () {
        if (this.hasAttribute("download") && window.__m6pBlobs.has(this.href)) { return; }
        return click.call(this);
      };
    });

    console.log(`Studio 1.48 at ${appUrl}`);
    await page.goto(appUrl, { waitUntil: "load" });

    // 1. The data source opens: its topic list (Data source sidebar, Topics tab).
    const topicsDeadline = Date.now() + 60000;
    let studioTopics;
    for (;;) {
      const state = await page.evaluate(() => ({
        bootError: window.__m6pBootError,
        topics: [...document.querySelectorAll('[data-topic-stat="count"]')].map((e) => [e.getAttribute("data-topic"), e.textContent]),
        text: document.body.innerText.slice(0, 2000),
      }));
      if (state.bootError) { throw new Error(`the app did not start: ${state.bootError}`); }
      const countsKnown = state.topics.length > 0 && (opts.live || state.topics.some(([, c]) => /\d/.test(c)));
      if (countsKnown) { studioTopics = new Map(state.topics.map(([t, c]) => [t, c])); break; }
      if (Date.now() > topicsDeadline) {
        fail(`the data source never listed topics within 60 s (page says: ${state.text.replace(/\s+/g, " ").slice(0, 300)})`);
        throw new Error("stop");
      }
      await sleep(500);
    }
    if (opts.live) {
      // Channels are advertised as their first message comes: give the run a moment.
      const want = [...BASE_TOPICS, ...(opts.truth ? TRUTH_TOPICS : [])];
      const until = Date.now() + Math.min(opts.wait, 60) * 1000;
      while (Date.now() < until && !want.every((t) => studioTopics.has(t))) {
        await sleep(1000);
        studioTopics = new Map(await page.evaluate(() => [...document.querySelectorAll('[data-topic-stat="count"]')].map((e) => [e.getAttribute("data-topic"), e.textContent])));
      }
    }
    const count = (t) => Number((studioTopics.get(t) ?? "").replace(/[^\d]/g, "") || 0);

    // 2. Topics: the twin's base topics, the truth topics, and (recording) every channel of
    //    the file with the file's message count.
    const required = [...BASE_TOPICS, ...(opts.truth ? TRUTH_TOPICS : [])];
    const missing = required.filter((t) => !studioTopics.has(t));
    if (missing.length) { fail(`topics missing from Studio's topic list: ${missing.join(", ")}`); }
    if (summary) {
      for (const [t, { count: n }] of summary.topics) {
        if (!studioTopics.has(t)) { fail(`recorded topic ${t} (${n} messages) not in Studio's topic list`); } else if (count(t) !== n) {
          fail(`topic ${t}: Studio counts ${studioTopics.get(t)} messages, the file ${n}`);
        }
      }
      for (const t of studioTopics.keys()) {
        if (!summary.topics.has(t)) { fail(`Studio lists ${t}, which the file's summary does not have`); }
      }
    }
    const readTopicCounts = async () => new Map((await page.evaluate(() => [...document.querySelectorAll('[data-topic-stat="count"]')].map((e) => [e.getAttribute("data-topic"), e.textContent]))).map(([t, c]) => [t, Number(c.replace(/[^\d]/g, "") || 0)]));
    // Which topics a panel must draw. A recording: those with messages in it (the panels that
    // show the latest message are opened at the end; the plots read the whole file). Live: those
    // that received messages while the tab was on screen (a panel gets nothing from before it
    // was shown), from the topic list's counts when the tab opened and now.
    let liveBefore = new Map();
    let liveNow = new Map();
    const hasData = (t) => (opts.live ? (liveNow.get(t) ?? 0) > (liveBefore.get(t) ?? 0) : studioTopics.has(t) && count(t) > 0);
    // The topics whose messages a panel must draw: those with messages here, read without a
    // filter (a filtered path such as /csp/packets{icd=="FC.TMGEN"}... may rightly match nothing).
    const expectedTopics = (p) => {
      const unfiltered = p.paths.length ? p.paths.filter((pp) => !pp.value.includes("{")).map((pp) => pp.topic) : p.topics;
      return [...new Set(unfiltered)].filter(hasData);
    };
    console.log(`topics: ${studioTopics.size} listed${summary ? `, ${summary.messageCount} messages in the file` : ""}; required ${required.length - missing.length}/${required.length} present`);

    // 3. Each tab: click it, wait until its panels show data (or the wait is over), screenshot.
    const results = [];
    for (const tab of tabs) {
      await page.evaluate((title) => {
        const el = [...document.querySelectorAll('[data-testid="toolbar-tab"]')].find((e) => e.textContent.trim() === title || e.getAttribute("title") === title);
        el?.click();
        window.getSelection()?.removeAllRanges();
      }, tab.title);
      const tabStart = Date.now();
      const deadline = Date.now() + opts.wait * 1000;
      const minimum = Date.now() + (opts.live ? 10000 : 0);
      if (opts.live) { liveBefore = await readTopicCounts(); liveNow = liveBefore; }
      let last;
      let stableFor = 0;
      let status;
      for (;;) {
        await sleep(1000);
        if (opts.live) { liveNow = await readTopicCounts(); }
        status = [];
        for (const p of tab.panels) { status.push(await panelStatus(page, p)); }
        const key = JSON.stringify(status.map((s) => [s.ok, s.points, s.detail]));
        stableFor = key === last ? stableFor + 1 : 0;
        last = key;
        const expected = status.filter((s, i) => expectedTopics(tab.panels[i]).length > 0);
        const allOk = expected.every((s) => s.ok);
        // Done when every panel that must draw does and nothing changed for 3 s; a recording
        // whose panels stay as they are for 15 s will not change either.
        if ((allOk && (opts.live || stableFor >= 3) && Date.now() > minimum) || (!opts.live && stableFor >= 15) || Date.now() > deadline) { break; }
      }
      console.log(`tab "${tab.title}": ${status.filter((x) => x.ok).length}/${tab.panels.length} panels with data after ${((Date.now() - tabStart) / 1000).toFixed(1)} s`);
      if (opts.screenshots) {
        await page.screenshot({ path: path.join(opts.screenshots, `tab-${tab.index + 1}-${slug(tab.title)}.png`) });
      }
      for (const [i, p] of tab.panels.entries()) {
        const s = status[i];
        const recorded = expectedTopics(p);
        let verdict;
        if (s.error) {
          verdict = "ERROR";
          fail(`[${tab.title}] ${p.id} "${p.title}": ${s.error}`);
        } else if (s.ok) {
          verdict = "ok";
        } else if (recorded.length === 0) {
          verdict = "n/a";
          (opts.strict || opts.everyPanel ? fail : warn)(`[${tab.title}] ${p.id} "${p.title}": no data; none of its topics (${p.topics.join(", ")}) has messages ${opts.live ? "since the tab opened" : "here"}${p.paths.some((pp) => pp.value.includes("{")) ? " that its filters match" : ""}`);
        } else {
          verdict = "EMPTY";
          fail(`[${tab.title}] ${p.id} "${p.title}": shows no data though ${recorded.join(", ")} has messages${opts.live ? " since the tab opened" : ""} (${s.detail})`);
        }
        for (const pp of s.paths ?? []) {
          if (pp.points === 0 && hasData(pp.topic) && verdict !== "EMPTY") {
            (opts.strict ? fail : warn)(`[${tab.title}] ${p.id}: path ${pp.value} draws nothing though ${pp.topic} has messages${pp.value.includes("{") ? " (none its filters match?)" : " (all null?)"}`);
          }
        }
        results.push({ tab: tab.title, id: p.id, verdict, detail: s.detail });
      }
    }

    // 4. Problems tab of the data source: "No problems found".
    const problems = await page.evaluate(async () => {
      const tab = [...document.querySelectorAll('[role="tab"]')].find((e) => e.textContent.trim().startsWith("Problems"));
      if (!tab) { return { error: "no Problems tab in the Data source sidebar" }; }
      tab.click();
      await new Promise((r) => setTimeout(r, 500));
      const panel = tab.closest('[role="tablist"]')?.parentElement?.parentElement?.parentElement ?? document.body;
      const text = panel.innerText;
      const items = [...panel.querySelectorAll("li .MuiListItemText-primary")].map((e) => e.textContent);
      return { none: /No problems found/.test(text), items, badge: tab.textContent.replace("Problems", "").trim() };
    });
    if (opts.screenshots) { await page.screenshot({ path: path.join(opts.screenshots, "problems.png") }); }
    if (problems.error) { fail(problems.error); } else if (!problems.none) {
      fail(`Problems tab lists ${problems.badge || "some"} problem(s): ${problems.items.join(" | ") || "(unreadable)"}`);
    }

    // Summary.
    console.log("\npanels:");
    for (const r of results) { console.log(`  ${r.verdict.padEnd(5)} ${r.tab.padEnd(18)} ${r.id.padEnd(28)} ${r.detail}`); }
    console.log(`problems: ${problems.none ? "No problems found" : problems.items?.join(" | ") ?? problems.error}`);
    const relevantErrors = consoleErrors.filter((e) => !/ERR_NAME_NOT_RESOLVED|tile\.openstreetmap|favicon/.test(e));
    if (relevantErrors.length) {
      console.log(`console errors (${relevantErrors.length}, not judged):`);
      for (const e of [...new Set(relevantErrors)].slice(0, 10)) { console.log(`  ${e.slice(0, 200)}`); }
    }
    const okPanels = results.filter((r) => r.verdict === "ok").length;
    console.log(`\n${failures.length === 0 ? "PASS" : "FAIL"}: ${okPanels}/${results.length} panels drew data, ${results.filter((r) => r.verdict === "n/a").length} n/a, ${failures.length} failure(s), ${warnings.length} warning(s); ${((Date.now() - t0) / 1000).toFixed(1)} s${opts.screenshots ? `; screenshots in ${opts.screenshots}` : ""}`);
    exitCode = failures.length === 0 ? 0 : 1;
    if (opts.keepOpen) {
      console.log(`keeping the browser open: ${appUrl}`);
      await new Promise(() => {});
    }
  } catch (err) {
    if (String(err.message) !== "stop") { fail(`check aborted: ${err.stack ?? err}`); }
    console.log(`\nFAIL: ${failures.length} failure(s); ${((Date.now() - t0) / 1000).toFixed(1)} s`);
    exitCode = 1;
  } finally {
    await browser.close().catch(() => {});
    await srv.close();
  }
  process.exit(exitCode);
}

/**
 * What one panel shows, read from the DOM: {ok, points, detail, paths?, error?}.
 * Panels are found by `[data-testid="panel-mouseenter-container <id>"]`.
 */
async function panelStatus(page, p) {
  const base = await page.evaluate((id) => {
    const el = document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`);
    if (!el) { return { missing: true }; }
    const text = el.innerText;
    const r = el.getBoundingClientRect();
    return {
      text,
      rect: { x: r.x, y: r.y, width: r.width, height: r.height },
      empty: /Waiting for next message|Waiting for first GPS point|No topic selected|Waiting to diff/.test(text),
      crashed: /encountered an unexpected error|Unknown panel type|An error occurred/.test(text),
    };
  }, p.id);
  if (base.missing) { return { ok: false, error: "panel not on the page (unknown panel type or not placed)" }; }
  if (base.crashed) { return { ok: false, error: base.text.replace(/\s+/g, " ").slice(0, 200) }; }
  if (base.empty) { return { ok: false, points: 0, detail: base.text.match(/Waiting[^\n]*|No topic selected/)?.[0] ?? "empty" }; }

  switch (p.type) {
    case "Plot": {
      // The panel's own "Download plot data as CSV": one row per point, the series label in column 4.
      const csv = await page.evaluate(async (id) => {
        const el = document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`);
        const button = el?.querySelector('[title="Download plot data as CSV"]');
        if (!button) { return undefined; }
        window.__m6pLastCsv = undefined;
        button.click();
        const url = window.__m6pLastCsv;
        const blob = url && window.__m6pBlobs.get(url);
        if (!blob) { return undefined; }
        window.__m6pBlobs.delete(url);
        URL.revokeObjectURL(url);
        return await blob.text();
      }, p.id);
      if (csv === undefined) { return { ok: false, error: "no CSV from the plot's download button" }; }
      if (process.env.FOXGLOVE_CHECK_DEBUG) {
        fs.mkdirSync(process.env.FOXGLOVE_CHECK_DEBUG, { recursive: true });
        fs.writeFileSync(path.join(process.env.FOXGLOVE_CHECK_DEBUG, `${p.id.replace(/!/g, "_")}.csv`), csv);
      }
      const perLabel = new Map();
      for (const line of csv.split("\n").slice(1)) {
        const f = line.split(",");
        // A series with no point still gives one row (x NaN, value empty): count real points only.
        if (f.length < 5 || !Number.isFinite(Number(f[0])) || f[f.length - 1] === "" || !Number.isFinite(Number(f[f.length - 1]))) { continue; }
        const label = f.slice(3, f.length - 1).join(",");
        perLabel.set(label, (perLabel.get(label) ?? 0) + 1);
      }
      const paths = p.paths.map((pp) => ({ ...pp, points: perLabel.get(pp.label) ?? 0 }));
      const points = paths.reduce((a, pp) => a + pp.points, 0);
      return { ok: points > 0, points, paths, detail: paths.map((pp) => `${pp.label}: ${pp.points}`).join("; ") };
    }
    case "StateTransitions": {
      // Drawn on a canvas: count coloured pixels in each path's row (its label button marks the
      // row; the rows scroll inside the panel), leaving out the label and any vertical line
      // through the whole row (the playback cursor).
      const paths = [];
      for (const pp of p.paths) {
        const row = await page.evaluate((id, label) => {
          const el = document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`);
          const b = [...el.querySelectorAll("button")].find((x) => x.textContent.trim() === label);
          if (!b) { return undefined; }
          b.parentElement.scrollIntoView({ block: "nearest" });
          const panel = el.getBoundingClientRect();
          const r = b.parentElement.getBoundingClientRect();
          const br = b.getBoundingClientRect();
          const top = Math.max(r.y, panel.y);
          const bottom = Math.min(r.bottom, panel.bottom);
          return { x: panel.x, width: panel.width, y: top, height: bottom - top, labelRight: br.right - panel.x, labelBottom: br.bottom - top };
        }, p.id, pp.label);
        if (!row || row.height < 10) { paths.push({ ...pp, points: 0, px: 0 }); continue; }
        await sleep(200);
        const px = await colouredPixels(page, row, { skipLeft: row.labelRight, skipTop: row.labelBottom });
        paths.push({ ...pp, points: px > 30 ? px : 0, px });
      }
      const points = paths.reduce((a, pp) => a + pp.points, 0);
      return { ok: points > 0, points, paths, detail: paths.map((pp) => `${pp.label}: ${pp.px} px`).join("; ") };
    }
    case "Table": {
      const rows = await page.evaluate((id) => document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`).querySelectorAll("table tr").length, p.id);
      return { ok: rows > 1, points: rows, detail: `${rows} table rows` };
    }
    case "RawMessages": {
      const lines = base.text.split("\n").filter((l) => l.trim()).length;
      return { ok: lines > 3, points: lines, detail: `${lines} lines of message` };
    }
    case "RosOut": {
      const lines = (base.text.match(/^\[\s*(DEBUG|INFO|WARN|ERROR|FATAL)\s*\]/gm) ?? []).length;
      return { ok: lines > 0, points: lines, detail: `${lines} log lines` };
    }
    case "map": {
      const marks = await page.evaluate((id) => document.querySelector(`[data-testid="panel-mouseenter-container ${id}"]`).querySelectorAll(".leaflet-overlay-pane path, .leaflet-marker-pane > *").length, p.id);
      return { ok: marks > 0, points: marks, detail: `${marks} track points` };
    }
    case "3D": {
      const toolbar = 30;
      const clip = { x: base.rect.x, y: base.rect.y + toolbar, width: base.rect.width, height: base.rect.height - toolbar };
      const px = await colouredPixels(page, clip, {});
      return { ok: px > 500, points: px, detail: `${px} coloured px` };
    }
    default: {
      const lines = base.text.split("\n").filter((l) => l.trim()).length;
      return { ok: lines > 1, points: lines, detail: `${lines} lines (type ${p.type} judged by its text)` };
    }
  }
}

/** Coloured (saturated) pixels in a clip of the page, decoded in the page itself (no PNG library). */
async function colouredPixels(page, clip, { skipLeft = 0, skipTop = 0 }) {
  const c = { x: Math.round(clip.x), y: Math.round(clip.y), width: Math.max(1, Math.round(clip.width)), height: Math.max(1, Math.round(clip.height)) };
  const b64 = await page.screenshot({ clip: c, encoding: "base64", captureBeyondViewport: false });
  if (process.env.FOXGLOVE_CHECK_DEBUG) {
    fs.mkdirSync(process.env.FOXGLOVE_CHECK_DEBUG, { recursive: true });
    fs.writeFileSync(path.join(process.env.FOXGLOVE_CHECK_DEBUG, `clip-${c.x}-${c.y}-${c.width}x${c.height}.png`), Buffer.from(b64, "base64"));
  }
  return await page.evaluate(async (b64, skipLeft, skipTop) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const cv = document.createElement("canvas");
    cv.width = img.width;
    cv.height = img.height;
    const ctx = cv.getContext("2d");
    ctx.drawImage(img, 0, 0);
    const { data, width, height } = ctx.getImageData(0, 0, img.width, img.height);
    const col = new Array(width).fill(0);
    const mask = new Uint8Array(width * height);
    for (let y = 0; y < height; y++) {
      for (let x = 0; x < width; x++) {
        if (x < skipLeft && y < skipTop) { continue; }
        const i = (y * width + x) * 4;
        const mx = Math.max(data[i], data[i + 1], data[i + 2]);
        const mn = Math.min(data[i], data[i + 1], data[i + 2]);
        if (mx - mn > 60) { mask[y * width + x] = 1; col[x] += 1; }
      }
    }
    let n = 0;
    for (let x = 0; x < width; x++) {
      if (col[x] > 0.8 * height) { continue; } // a vertical line through the whole clip
      for (let y = 0; y < height; y++) { n += mask[y * width + x]; }
    }
    return n;
  }, b64, skipLeft, skipTop);
}

main().catch((err) => {
  console.error(err);
  process.exit(1);
});
