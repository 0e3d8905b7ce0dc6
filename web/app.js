// fringe browser UI: run list, new run, live progress, report with plots, compare, downloads.
// Plain ES modules; every form is built from what the API says about itself
// (GET /estimators, /drivers, /fixtures).
import * as api from './api.js';
import * as plots from './plots.js';

const view = document.getElementById('view');
let cleanup = [];  // closers for the current view (event streams, timers)

function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v == null || v === false) continue;
    if (k === 'class') el.className = v;
    else if (k.startsWith('on')) el.addEventListener(k.slice(2), v);
    else if (k === 'value') el.value = v;
    else el.setAttribute(k, v === true ? '' : v);
  }
  for (const c of children.flat()) if (c != null) el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return el;
}

const fmt = (v, digits = 3) => (v == null || Number.isNaN(v) ? '-' : typeof v === 'number' ? (Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0) ? v.toExponential(digits) : +v.toPrecision(digits + 1) + '') : String(v));
const verdictBadge = (v, extra = '') => h('span', { class: `verdict v-${v || 'none'} ${extra}`, 'data-verdict': v || '' }, v || '—');
const showError = (e) => h('p', { class: 'error', role: 'alert' }, e.field ? `${e.field}: ${e.message}` : e.message || String(e));
const status = (msg) => { document.getElementById('status').textContent = msg; };

// ---- token ---------------------------------------------------------------------------
function initToken() {
  const m = location.hash.match(/^#token=([0-9a-fA-F]+)/);  // the URL fringe serve prints on first start
  if (m) { api.setToken(m[1]); history.replaceState(null, '', '#/runs'); }
  const input = document.getElementById('token');
  const state = document.getElementById('token-state');
  const show = () => { state.textContent = api.token() ? 'set' : 'not set (needed to start runs)'; };
  document.getElementById('token-form').addEventListener('submit', (ev) => {
    ev.preventDefault();
    api.setToken(input.value.trim());
    input.value = '';
    show();
  });
  show();
}

// ---- run list ------------------------------------------------------------------------
async function runList(params) {
  const q = new URLSearchParams(params);
  const verdict = h('select', { name: 'outcome' }, ['', 'PASS', 'MARGINAL', 'FAIL', 'ERROR', 'ABORTED'].map((v) => h('option', { value: v }, v || 'any')));
  verdict.value = q.get('outcome') || '';
  const scenario = h('input', { name: 'scenario', value: q.get('scenario') || '', placeholder: 'scenario name' });
  const since = h('input', { name: 'since', type: 'date', value: (q.get('since') || '').slice(0, 10) });
  // With a shared store (fringe serve --store postgresql://...) the list holds every bench's runs.
  const bench = h('input', { name: 'bench', value: q.get('bench') || '', placeholder: 'bench name' });
  const dut = h('input', { name: 'dut', value: q.get('dut') || '', placeholder: 'DUT serial' });
  const apply = (ev) => {
    ev.preventDefault();
    const p = new URLSearchParams();
    if (verdict.value) p.set('outcome', verdict.value);
    if (scenario.value) p.set('scenario', scenario.value);
    if (since.value) p.set('since', `${since.value}T00:00:00Z`);
    if (bench.value) p.set('bench', bench.value);
    if (dut.value) p.set('dut', dut.value);
    location.hash = `#/runs?${p}`;
  };
  const tbody = h('tbody');
  const table = h('table', { id: 'runs' }, h('thead', {}, h('tr', {}, ['', 'run', 'bench', 'scenario', 'DUT', 'started (UTC)', 'status', 'verdict', 'progress'].map((c) => h('th', {}, c)))), tbody);
  const pick = new Set();
  const compareBtn = h('button', { type: 'button', disabled: true, onclick: () => { const [a, b] = [...pick]; location.hash = `#/compare/${a}/${b}`; } }, 'compare selected');
  view.replaceChildren(
    h('h1', {}, 'Runs'),
    h('form', { class: 'filters', onsubmit: apply },
      h('label', { class: 'field' }, 'verdict', verdict), h('label', { class: 'field' }, 'scenario', scenario),
      h('label', { class: 'field' }, 'since', since), h('label', { class: 'field' }, 'bench', bench),
      h('label', { class: 'field' }, 'DUT', dut), h('button', { type: 'submit' }, 'filter'), compareBtn,
      h('a', { class: 'button', href: '#/new' }, 'New run')),
    table);
  const refresh = async () => {
    let data;
    try { data = await api.get(`runs?${q}`); } catch (e) { view.append(showError(e)); return false; }
    tbody.replaceChildren(...data.runs.map((r) => {
      const box = h('input', { type: 'checkbox', 'aria-label': `select ${r.id}`, onchange: (ev) => {
        if (ev.target.checked) pick.add(r.id); else pick.delete(r.id);
        compareBtn.disabled = pick.size !== 2;
      } });
      box.checked = pick.has(r.id);
      const frac = r.progress && r.progress.total ? r.progress.done / r.progress.total : null;
      return h('tr', { 'data-id': r.id, 'data-status': r.status },
        h('td', {}, box), h('td', {}, h('a', { href: `#/run/${r.id}` }, r.id)), h('td', {}, r.bench || ''), h('td', {}, r.scenario),
        h('td', {}, r.dut || ''), h('td', {}, r.created_at),
        h('td', {}, r.status), h('td', {}, verdictBadge(r.verdict)),
        h('td', {}, frac == null || r.status !== 'running' ? '' : `${(100 * frac).toFixed(0)} %`));
    }));
    status(`${data.runs.length} runs · ${new Date().toLocaleTimeString()}`);
    return data.runs.some((r) => r.status === 'queued' || r.status === 'running');
  };
  // Live status: poll while something is queued or running, slowly otherwise.
  let timer = null;
  const loop = async () => { const busy = await refresh(); timer = setTimeout(loop, busy ? 500 : 3000); };
  cleanup.push(() => clearTimeout(timer));
  await loop();
}

// ---- new run -------------------------------------------------------------------------
function paramInput(p, value, path) {
  const id = `${path}.${p.name}`;
  let input;
  if (p.type === 'boolean') {
    input = h('input', { type: 'checkbox', name: id });
    input.checked = value ?? p.default ?? false;
  } else if (p.options && p.options.length) {
    input = h('select', { name: id }, p.options.map((o) => h('option', { value: o }, o)));
    input.value = value ?? p.default ?? p.options[0];
  } else {
    const numeric = p.type === 'number' || p.type === 'integer';
    input = h('input', { name: id, type: numeric ? 'number' : 'text', step: numeric ? 'any' : null, min: p.min, max: p.max,
      placeholder: p.default == null ? 'derived' : String(p.default) });
    if (value != null) input.value = value;
  }
  input.dataset.type = p.type;
  input.dataset.param = p.name;
  const unit = p.unit ? ` [${p.unit}]` : '';
  return h('label', { class: 'field', title: p.description || '' }, `${p.name}${unit}`, input);
}

function readParams(container) {
  const out = {};
  for (const el of container.querySelectorAll('[data-param]')) {
    const t = el.dataset.type;
    if (t === 'boolean') { out[el.dataset.param] = el.checked; continue; }
    if (el.value === '') continue;  // default
    out[el.dataset.param] = t === 'integer' ? parseInt(el.value, 10) : t === 'number' ? parseFloat(el.value) : el.value;
  }
  return out;
}

async function newRun() {
  let cat;
  try {
    const [fx, est, drv] = await Promise.all([api.get('fixtures'), api.get('estimators'), api.get('drivers')]);
    cat = { fixtures: fx.fixtures.filter((f) => f.runnable), estimators: est.estimators, drivers: drv.drivers };
  } catch (e) { view.replaceChildren(showError(e)); return; }
  const fixtureSel = h('select', { name: 'fixture', id: 'fixture' }, cat.fixtures.map((f) => h('option', { value: f.name }, f.name)));
  const desc = h('p', { class: 'muted' });
  const seed = h('input', { name: 'seed', type: 'number', min: 0, step: 1 });
  const duration = h('input', { name: 'duration_s', type: 'number', min: 0, step: 'any' });
  const driverSel = h('select', { name: 'driver', id: 'driver' }, cat.drivers.map((d) => h('option', { value: d.scheme }, d.scheme)));
  const devPath = h('input', { name: 'device_path', placeholder: 'path (capture: an uploaded capture id)' });
  const devParams = h('div', { class: 'params' });
  const estBox = h('div');
  const out = h('div');
  let scenario = null;

  const fillDevice = (device) => {
    // Output and input instruments ({output, input}): the form edits the generator's URI; a run
    // keeps both halves when they are one instrument (the same URI).
    const uri = typeof device === 'string' ? device : device.output;
    const [scheme, rest = ''] = [uri.slice(0, uri.indexOf(':')), uri.slice(uri.indexOf(':') + 1)];
    const [path, query = ''] = rest.split('?');
    driverSel.value = scheme;
    devPath.value = path;
    const given = Object.fromEntries(new URLSearchParams(query));
    const d = cat.drivers.find((x) => x.scheme === scheme) || cat.drivers[0];
    devParams.replaceChildren(...(d ? d.settings : []).map((p) => paramInput(p, given[p.name], 'device')));
  };
  driverSel.addEventListener('change', () => fillDevice(`${driverSel.value}:`));

  const fillEstimators = (chosen) => {
    estBox.replaceChildren(...cat.estimators.map((e) => {
      const spec = chosen.find((c) => c.name === e.name);
      const box = h('input', { type: 'checkbox', name: `est.${e.name}`, 'data-estimator': e.name });
      box.checked = !!spec;
      const params = h('div', { class: 'params', hidden: !spec }, e.params.map((p) => paramInput(p, spec && spec.params ? spec.params[p.name] : undefined, e.name)));
      box.addEventListener('change', () => { params.hidden = !box.checked; });
      return h('div', { class: 'estimator', 'data-name': e.name }, h('label', { title: e.summary }, box, ` ${e.name} `, h('span', { class: 'muted' }, e.summary)), params);
    }));
  };

  const loadFixture = async () => {
    out.replaceChildren();
    try {
      scenario = (await api.get(`fixtures/${encodeURIComponent(fixtureSel.value)}`)).scenario;
    } catch (e) { out.replaceChildren(showError(e)); return; }
    desc.textContent = scenario.description || '';
    seed.value = scenario.seed;
    duration.value = scenario.duration_s;
    fillDevice(scenario.device);
    fillEstimators(scenario.estimators);
  };
  fixtureSel.addEventListener('change', loadFixture);

  const submit = async (ev) => {
    ev.preventDefault();
    const sc = structuredClone(scenario);
    sc.seed = parseInt(seed.value, 10);
    sc.duration_s = parseFloat(duration.value);
    const dq = new URLSearchParams();
    for (const [k, v] of Object.entries(readParams(devParams))) dq.set(k, String(v));
    const qs = dq.toString();
    const uri = `${driverSel.value}:${devPath.value}${qs ? `?${qs}` : ''}`;
    const two = typeof scenario.device === 'object' && scenario.device !== null;
    if (!two) sc.device = uri;
    else if (scenario.device.output === scenario.device.input) sc.device = { ...scenario.device, output: uri, input: uri };
    const before = Object.fromEntries((scenario.estimators || []).map((e) => [e.name, e]));
    sc.estimators = [];
    for (const div of estBox.querySelectorAll('.estimator')) {
      if (!div.querySelector('[data-estimator]').checked) continue;
      const name = div.dataset.name;
      const spec = { ...(before[name] || {}), name, params: readParams(div.querySelector('.params')) };
      if (!spec.label) spec.label = name;
      sc.estimators.push(spec);
    }
    // Limits that name an estimator no longer in the run would be rejected: drop them.
    const labels = new Set(sc.estimators.map((e) => e.label));
    sc.limits = (sc.limits || []).filter((l) => l.estimator === '*' || labels.has(l.estimator));
    try {
      const r = await api.post('runs', { scenario: sc });
      location.hash = `#/run/${r.id}`;
    } catch (e) { out.replaceChildren(showError(e)); }
  };

  view.replaceChildren(
    h('h1', {}, 'New run'),
    h('form', { id: 'new-run', onsubmit: submit },
      h('fieldset', {}, h('legend', {}, 'Scenario'),
        h('div', { class: 'row' }, h('label', { class: 'field' }, 'fixture', fixtureSel), h('label', { class: 'field' }, 'seed', seed),
          h('label', { class: 'field' }, 'duration [s]', duration)), desc),
      h('fieldset', {}, h('legend', {}, 'Device'), h('div', { class: 'row' }, h('label', { class: 'field' }, 'driver', driverSel),
        h('label', { class: 'field' }, 'path', devPath)), devParams),
      h('fieldset', {}, h('legend', {}, 'Estimators under test'), estBox),
      h('button', { type: 'submit', class: 'primary', id: 'start' }, 'Start run'), out));
  if (cat.fixtures.length) {
    const pref = cat.fixtures.find((f) => f.name === 'fig10c-loopback');
    if (pref) fixtureSel.value = pref.name;
    await loadFixture();
  }
}

// ---- one run: live progress, then the report -----------------------------------------
async function runPage(id) {
  const bar = h('div', { style: 'width:0%' });
  const line = h('p', { id: 'run-state' }, 'connecting…');
  const cancel = h('button', { type: 'button', id: 'cancel', onclick: async () => {
    try { await api.post(`runs/${encodeURIComponent(id)}/cancel`); } catch (e) { line.after(showError(e)); }
  } }, 'Cancel');
  const body = h('div');
  view.replaceChildren(h('h1', {}, 'Run ', h('code', {}, id)), h('div', { class: 'progress', role: 'progressbar' }, bar), h('div', { class: 'row' }, line, cancel), body);
  const close = api.follow(id, (s, end) => {
    const frac = s.progress && s.progress.total ? s.progress.done / s.progress.total : 0;
    bar.style.width = `${(100 * frac).toFixed(1)}%`;
    line.textContent = `${s.scenario}: ${s.status} · ${s.progress.done} / ${s.progress.total} samples${s.error ? ` · ${s.error}` : ''}`;
    line.dataset.status = s.status;
    if (end) { cancel.remove(); report(id, body); }
  });
  cleanup.push(close);
}

function measurementsTable(r) {
  return h('table', { id: 'measurements' },
    h('thead', {}, h('tr', {}, ['estimator', 'metric', 'value', 'unit', 'min', 'max', 'outcome'].map((c) => h('th', {}, c)))),
    h('tbody', {}, (r.measurements || []).map((m) => h('tr', { class: m.implicit ? 'evidence' : '' },
      h('td', {}, m.estimator), h('td', {}, m.metric, m.implicit ? h('span', { class: 'muted', title: 'implicit check: a verdict needs this much evidence' }, ' (evidence)') : ''),
      h('td', { class: 'num' }, m.value == null ? 'not measured' : fmt(m.value)), h('td', {}, m.unit || ''),
      h('td', { class: 'num' }, fmt(m.limit && m.limit.min)), h('td', { class: 'num' }, fmt(m.limit && m.limit.max)),
      h('td', {}, verdictBadge(m.outcome), m.reason ? h('span', { class: 'muted reason' }, ` ${m.reason}`) : '')))));
}

// Preflight and convention warnings: what the verdict was reached under.
function warningsList(r) {
  const w = r.warnings || [];
  if (!w.length) return '';
  return h('div', {}, h('h2', {}, 'Warnings'),
    h('ul', { id: 'warnings' }, w.map((x) => h('li', {}, h('code', {}, x.code), ' ', x.message))));
}

function estimatorsTable(r) {
  return h('table', { id: 'estimators' },
    h('thead', {}, h('tr', {}, ['estimator', 'rms (rad)', 'max|e| (rad)', 'mean (rad)', 'slipped', 'scored samples', 'scored cycles', 'valid',
      'PCRB (rad)', 'efficiency', 'lock (s)'].map((c) => h('th', {}, c)))),
    h('tbody', {}, (r.estimators || []).map((e) => {
      const m = e.metrics || {}, b = e.bounds || {}, ev = m.evidence || {};
      return h('tr', {}, h('td', {}, e.label), h('td', { class: 'num' }, fmt(m.rms && m.rms.rad)), h('td', { class: 'num' }, fmt(m.max_abs && m.max_abs.rad)),
        h('td', { class: 'num' }, fmt(m.mean && m.mean.rad)), h('td', { class: 'num' }, fmt(m.slipped_samples)),
        h('td', { class: 'num' }, fmt(ev.scored_samples)), h('td', { class: 'num' }, fmt(ev.scored_cycles)),
        h('td', { class: 'num' }, ev.valid_fraction == null ? '' : `${(100 * ev.valid_fraction).toFixed(1)} %`), h('td', { class: 'num' }, fmt(b.pcrb_rad)),
        h('td', { class: 'num' }, fmt(b.efficiency)), h('td', { class: 'num' }, fmt(m.lock_time_s)));
    })));
}

async function report(id, into) {
  let r, tr;
  try {
    [r, tr] = await Promise.all([api.get(`runs/${encodeURIComponent(id)}/report.json`), api.get(`runs/${encodeURIComponent(id)}/traces`)]);
  } catch (e) { into.replaceChildren(showError(e)); return; }
  const base = `/api/v1/runs/${encodeURIComponent(id)}`;
  const plotBox = h('div', { class: 'plots', id: 'plots' });
  into.replaceChildren(
    h('p', {}, verdictBadge(r.verdict, 'banner'), ' ', h('span', { id: 'verdict-text' }, `${r.scenario.name} · ${r.status} · seed ${r.seed} · ${r.samples ? r.samples.processed : 0} samples · device ${r.device ? r.device.uri : '-'}`)),
    r.error ? h('p', { class: 'error' }, r.error) : '',
    warningsList(r),
    h('p', { class: 'downloads' }, 'Download: ',
      h('a', { href: `${base}/report.json?download=1&traces=1`, download: '', id: 'dl-json' }, 'JSON'),
      h('a', { href: `${base}/report.xml?download=1`, download: '', id: 'dl-junit' }, 'JUnit XML'),
      h('a', { href: `${base}/report.html?download=1`, download: '', id: 'dl-html' }, 'HTML'),
      h('a', { href: `#/compare/${id}` }, 'compare with…')),
    h('h2', {}, 'Measurements'), measurementsTable(r),
    h('h2', {}, 'Estimators'), estimatorsTable(r),
    h('h2', {}, 'Plots'), plotBox);
  const t = tr.traces || {};
  const empty = !t.t_s || !t.t_s.length;
  if (empty) { plotBox.append(h('p', { class: 'muted' }, 'no traces (the run processed no samples)')); return; }
  try {
    plots.reportPlots(plotBox, t, tr.estimators || []);
  } catch (e) { plotBox.append(showError(e)); }
}

// ---- compare two runs ----------------------------------------------------------------
async function compare(a, b) {
  const pickForm = h('form', { class: 'filters', onsubmit: (ev) => {
    ev.preventDefault();
    location.hash = `#/compare/${ev.target.a.value.trim()}/${ev.target.b.value.trim()}`;
  } }, h('label', { class: 'field' }, 'run A', h('input', { name: 'a', value: a || '', size: 28 })),
  h('label', { class: 'field' }, 'run B', h('input', { name: 'b', value: b || '', size: 28 })), h('button', { type: 'submit' }, 'compare'));
  view.replaceChildren(h('h1', {}, 'Compare runs'), pickForm);
  if (!a || !b) return;
  let ra, rb, ta, tb;
  try {
    [ra, rb, ta, tb] = await Promise.all([`${a}/report.json`, `${b}/report.json`, `${a}/traces`, `${b}/traces`].map((p) => api.get(`runs/${p}`)));
  } catch (e) { view.append(showError(e)); return; }
  const byLabel = (r) => Object.fromEntries((r.estimators || []).map((e) => [e.label, e]));
  const ea = byLabel(ra), eb = byLabel(rb);
  const labels = [...new Set([...Object.keys(ea), ...Object.keys(eb)])];
  const rows = [];
  const metric = (e, f) => (e ? f(e) : null);
  const defs = [['rms (rad)', (e) => e.metrics.rms && e.metrics.rms.rad], ['max|e| (rad)', (e) => e.metrics.max_abs && e.metrics.max_abs.rad],
    ['slipped', (e) => e.metrics.slipped_samples],
    ['efficiency', (e) => e.bounds && e.bounds.efficiency]];
  for (const l of labels)
    for (const [name, f] of defs) {
      const va = metric(ea[l], f), vb = metric(eb[l], f);
      rows.push(h('tr', {}, h('td', {}, l), h('td', {}, name), h('td', { class: 'num' }, fmt(va)), h('td', { class: 'num' }, fmt(vb)),
        h('td', { class: 'num' }, va && vb ? `${(vb / va).toFixed(3)}×` : '-')));
    }
  // Limits and outcomes of each run, side by side: the runs may differ in limits as well as in values.
  const key = (m) => `${m.estimator}\u0000${m.metric}`;
  const ma = new Map((ra.measurements || []).map((m) => [key(m), m])), mb = new Map((rb.measurements || []).map((m) => [key(m), m]));
  const limitText = (m) => {
    if (!m || !m.limit) return '-';
    const parts = [];
    if (m.limit.min != null) parts.push(`≥ ${fmt(m.limit.min)}`);
    if (m.limit.max != null) parts.push(`≤ ${fmt(m.limit.max)}`);
    return parts.join(' ') || '-';
  };
  const limitRows = [...new Set([...ma.keys(), ...mb.keys()])].map((k) => {
    const x = ma.get(k), y = mb.get(k), m = x || y;
    return h('tr', {}, h('td', {}, m.estimator), h('td', {}, m.metric), h('td', {}, m.unit || ''),
      h('td', { class: 'num' }, x ? fmt(x.value) : '-'), h('td', {}, limitText(x)), h('td', {}, x ? verdictBadge(x.outcome) : '-'),
      h('td', { class: 'num' }, y ? fmt(y.value) : '-'), h('td', {}, limitText(y)), h('td', {}, y ? verdictBadge(y.outcome) : '-'));
  });
  const plotBox = h('div', { class: 'plots compare-plots', id: 'compare-plots' });
  view.append(
    h('table', { id: 'compare' }, h('thead', {}, h('tr', {},
      h('th', {}, 'estimator'), h('th', {}, 'metric'), h('th', {}, h('a', { href: `#/run/${a}` }, 'A '), verdictBadge(ra.verdict)),
      h('th', {}, h('a', { href: `#/run/${b}` }, 'B '), verdictBadge(rb.verdict)), h('th', {}, 'B / A'))), h('tbody', {}, rows)),
    h('h2', {}, 'Limits and outcomes'),
    h('table', { id: 'compare-limits' }, h('thead', {}, h('tr', {},
      ['estimator', 'metric', 'unit', 'A value', 'A limit', 'A outcome', 'B value', 'B limit', 'B outcome'].map((c) => h('th', {}, c)))),
    h('tbody', {}, limitRows)),
    h('h2', {}, 'Error vs time (each run on its own time axis)'), plotBox);
  // Each run keeps its own time base: never B's errors on A's times.
  const ta_ = ta.traces || {}, tb_ = tb.traces || {};
  const common = labels.filter((l) => ta_.error_rad && ta_.error_rad[l] && tb_.error_rad && tb_.error_rad[l]);
  for (const l of common)
    for (const [run, t, idr] of [['A', ta_, a], ['B', tb_, b]]) {
      const div = plots.errorVsTime(plotBox, t, [l], `${run} (${idr}): ${l}, error vs time`, `compare-${run}-${l}`);
      div.dataset.run = run;
    }
}

// ---- router --------------------------------------------------------------------------
async function route() {
  for (const c of cleanup) c();
  cleanup = [];
  const hash = location.hash || '#/runs';
  const [path, query = ''] = hash.slice(1).split('?');
  const parts = path.split('/').filter(Boolean).map(decodeURIComponent);
  for (const a of document.querySelectorAll('nav a')) a.classList.toggle('active', a.dataset.nav === parts[0]);
  try {
    if (parts[0] === 'new') await newRun();
    else if (parts[0] === 'run' && parts[1]) await runPage(parts[1]);
    else if (parts[0] === 'compare') await compare(parts[1], parts[2]);
    else await runList(Object.fromEntries(new URLSearchParams(query)));
  } catch (e) {
    view.replaceChildren(showError(e));
  }
}

initToken();
window.addEventListener('hashchange', route);
route();
