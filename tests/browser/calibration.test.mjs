// Browser test of a calibrated run's page (docs/calibration.md "In one run"): the before/after
// section with which capture computed the correction and which verified it, each lane's rms
// before and after beside the per-sample CRB, at 1280 px and at phone width (390 px); and a run
// whose after pass failed: the section says so and keeps the before figures.
// usage: node tests/browser/calibration.test.mjs FRINGE_BINARY
import { spawn } from 'node:child_process';
import { existsSync, mkdtempSync, mkdirSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';

const bin = process.argv[2];
if (!bin) { console.error('usage: calibration.test.mjs FRINGE_BINARY'); process.exit(2); }
const artifacts = process.env.ARTIFACTS || 'build/test-artifacts/browser';
mkdirSync(artifacts, { recursive: true });
const data = mkdtempSync(join(tmpdir(), 'fringe-calib-'));
const deadline = setTimeout(() => { console.error('FAIL: browser test exceeded 280 s'); cleanup(1); }, 280000);

let server, browser;
function cleanup(code) {
  clearTimeout(deadline);
  Promise.resolve(browser && browser.close()).catch(() => {}).finally(() => {
    if (server && server.exitCode === null) server.kill('SIGTERM');
    rmSync(data, { recursive: true, force: true });
    process.exit(code);
  });
}
function check(cond, msg) { if (!cond) throw new Error(msg); console.log(`ok - ${msg}`); }

async function startServer() {
  server = spawn(bin, ['serve', '--bind', '127.0.0.1:0', '--data', data], { stdio: ['ignore', 'pipe', 'pipe'] });
  let out = '';
  server.stderr.on('data', (d) => process.stderr.write(`[serve] ${d}`));
  return new Promise((resolve, reject) => {
    server.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/serving (http:\/\/127\.0\.0\.1:\d+\/)/);
      if (m && out.includes('token')) resolve(m[1]);
    });
    server.on('exit', (c) => reject(new Error(`fringe serve exited with ${c}: ${out}`)));
  });
}

let url, token;
async function api(method, path, body) {
  const res = await fetch(`${url}api/v1/${path}`, { method, headers: { Authorization: `Bearer ${token}`, 'Content-Type': 'application/json' }, body: body ? JSON.stringify(body) : undefined });
  const j = await res.json();
  if (!res.ok) throw new Error(`${method} ${path}: ${res.status} ${JSON.stringify(j)}`);
  return j;
}
async function runScenario(sc) {
  const { id } = await api('POST', 'runs', { scenario: sc });
  for (let i = 0; i < 1200; i++) {
    const r = await api('GET', `runs/${id}`);
    if (r.status !== 'queued' && r.status !== 'running') return id;
    await new Promise((res) => setTimeout(res, 100));
  }
  throw new Error(`run ${id} did not finish`);
}

// Each lane's row as the page shows it: the numbers it carries and the text on screen.
const laneRows = (page) => page.$$eval('#calibration-lanes tbody tr', (trs) => trs.map((tr) => {
  const v = (label) => {
    const td = tr.querySelector(`td[data-label="${label}"]`);
    return { text: td ? td.textContent : '', value: td && td.dataset.value !== '' && td.dataset.value != null ? Number(td.dataset.value) : null };
  };
  return { lane: tr.dataset.lane, applied: tr.dataset.applied === '1', before: v('rms before'), after: v('rms after'), crb: v('per-sample CRB'), ratio: v('after / CRB'), correction: v('correction').text };
}));
const boxesIn = (page, sel) => page.$$eval(sel, (els) => els.map((e) => {
  const b = e.getBoundingClientRect();
  return { l: b.left, r: b.right, w: b.width, h: b.height, vw: document.documentElement.clientWidth };
}));
const inside = (bs) => bs.length > 0 && bs.every((b) => b.w > 0 && b.h > 0 && b.l >= -0.5 && b.r <= b.vw + 0.5);

try {
  url = await startServer();
  token = readFileSync(join(data, 'token'), 'utf8').trim();
  const fixture = (await api('GET', 'fixtures/paper-duty1p6-calibrate')).scenario;
  const good = await runScenario(fixture);
  const report = await api('GET', `runs/${good}/report.json`);
  check(report.calibration && report.calibration.status === 'verified', 'the service ran the fixture before and after, verified');
  const corrPath = report.calibration.correction.path;
  // (a service's reports name its data folder DATA, never the host's path)
  check(corrPath === `DATA/corrections/${good}.correction.json` && existsSync(join(data, 'corrections', `${good}.correction.json`)),
    `the service wrote the correction to DATA/corrections (${corrPath})`);
  const bad = await runScenario({ ...fixture, name: 'after-fails', limits: [], calibrate: { ...fixture.calibrate, verify: { device: 'loopback:?drop_after=50000&drop_count=10' } } });

  browser = await chromium.launch({
    executablePath: '/usr/bin/chromium', headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1'],
  });
  for (const [name, viewport] of [['desk', { width: 1280, height: 1000 }], ['phone', { width: 390, height: 844 }]]) {
    const ctx = await browser.newContext({ viewport, deviceScaleFactor: 1 });
    await ctx.addInitScript((t) => localStorage.setItem('fringe.token', t), token);
    const page = await ctx.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(e.message));
    await page.goto(`${url}#/run/${good}`);
    await page.waitForSelector('#calibration-lanes tbody tr');
    check(await page.textContent('#calibration-status') === 'verified', `${name}: the section says verified`);
    const on = await page.textContent('#computed-on'), ver = await page.textContent('#verified-on');
    check(/seed 1\b/.test(on) && /truth-scored/.test(on), `${name}: computed on the before pass, seed 1, truth-scored ("${on}")`);
    check(/seed 2\b/.test(ver), `${name}: verified on the after pass, seed 2 ("${ver}")`);
    check(/64 entries/.test(await page.textContent('#calibration-correction')), `${name}: the correction's table size is shown`);
    const rows = await laneRows(page);
    const byLane = Object.fromEntries(rows.map((r) => [r.lane, r]));
    const a = byLane.atan2, p = byLane.pll2;
    const lane = report.calibration.lanes.find((l) => l.label === 'atan2');
    check(a && a.before.value === lane.before.rms_rad && a.after.value === lane.after.rms_rad,
      `${name}: atan2's before and after are the report's (${a && a.before.text} -> ${a && a.after.text})`);
    check(a.before.value > 1.7e-2 && a.after.value < 2 * a.crb.value && a.ratio.value === lane.after.rms_over_crb,
      `${name}: atan2 after within 2x of the per-sample CRB on screen (${a.ratio.text})`);
    check(/1\.7\de-2 rad|0\.017\d rad/.test(a.before.text) && /e-4 rad/.test(a.after.text), `${name}: the figures are on screen with their unit`);
    check(p && p.applied && p.after.value < p.before.value / 20, `${name}: pll2 took the correction (${p && p.before.text} -> ${p && p.after.text})`);
    check(inside(await boxesIn(page, '#calibration-lanes td')), `${name}: every cell of the before/after table is inside the window`);
    await page.screenshot({ path: join(artifacts, `calibration-${name}.png`), fullPage: true });

    await page.goto(`${url}#/run/${bad}`);
    await page.waitForSelector('#calibration-status');
    check(await page.textContent('#calibration-status') === 'after_incomplete', `${name}: a failed after pass says after_incomplete`);
    const why = await page.textContent('#calibration');
    check(/the after pass did not complete/.test(why) && /lost/.test(why), `${name}: and why`);
    const br = await laneRows(page);
    check(br.length === 2 && br.every((r) => r.before.value > 0), `${name}: the before figures are kept`);
    check(errors.length === 0, `${name}: no page errors (${errors.join('; ')})`);
    await ctx.close();
  }
  cleanup(0);
} catch (e) {
  console.error(`FAIL: ${e.stack || e}`);
  cleanup(1);
}
