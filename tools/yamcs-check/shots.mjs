// Screenshots of YAMCS's web UI against the twin: node shots.mjs OUT_DIR [BASE_URL]
// (tools/yamcs-check.py --screenshots DIR runs it). Headless Chromium at $CHROMIUM or
// /usr/bin/chromium through puppeteer-core (pinned in package.json; `npm ci` here first).
import fs from 'node:fs';
import path from 'node:path';
import puppeteer from 'puppeteer-core';

const [out, base = 'http://127.0.0.1:8090'] = process.argv.slice(2);
if (!out) {
  console.error('usage: node shots.mjs OUT_DIR [BASE_URL]');
  process.exit(2);
}
fs.mkdirSync(out, { recursive: true });
const c = 'c=m6p__realtime';

// The latest TMGEN in the command history, for its own page.
const hist = await (await fetch(`${base}/api/archive/m6p/commands?limit=50`)).json();
const tmgen = (hist.commands || []).find((x) => x.commandName === '/M6P/FC/TMGEN');

const pages = [
  ['01-fc-tmgen-parameters', `/telemetry/parameters?${c}&system=%2FM6P%2FFC%2FTMGEN`, 'current_mode'],
  ['02-fc-tmgen-uptime', `/telemetry/parameters/M6P/FC/TMGEN/uptime_s/-/summary?${c}`, 'Generation time'],
  ['03-packets', `/telemetry/packets?${c}`, '/M6P/FC/TMGEN/reply'],
  ['04-command-history', `/commanding/history?${c}`, '/M6P/FC/TMGEN'],
  // The example's command stack (examples/yamcs/src/main/yamcs/stacks), loaded by the UI.
  ['06-stack-payload-session', `/automation/stacks/files/payload-session.ycs?${c}`, 'Command: /M6P/PC/SETUP'],
];
if (tmgen) {
  pages.push(['05-command-tmgen', `/commanding/history/${encodeURIComponent(tmgen.id)}?${c}`, 'Verifier']);
}

const browser = await puppeteer.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  headless: true,
  args: ['--no-sandbox', '--disable-background-networking', '--disable-gpu', '--no-first-run'],
});
let failed = 0;
try {
  const page = await browser.newPage();
  await page.setViewport({ width: 1400, height: 900 });
  for (const [name, url, text] of pages) {
    await page.goto(base + url, { waitUntil: 'networkidle2', timeout: 30000 });
    let found = true;
    try {
      await page.waitForFunction((t) => document.body.innerText.includes(t), { timeout: 15000 }, text);
    } catch {
      found = false;
      failed++;
    }
    await new Promise((r) => setTimeout(r, 1000)); // let tables settle
    const file = path.join(out, `${name}.png`);
    await page.screenshot({ path: file });
    console.log(`screenshot ${file}${found ? '' : ` (MISSING: "${text}" not on the page)`}`);
  }
} finally {
  await browser.close();
}
process.exit(failed ? 1 : 0);
