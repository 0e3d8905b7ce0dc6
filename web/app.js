// fringe browser UI: run list, new run, live progress, report with plots, compare, downloads.
// Plain ES modules; every form is built from what the API says about itself
// (GET /estimators, /drivers, /fixtures).
import * as api from './api.js';
import * as plots from './plots.js';
import { h, showError, errorText, scroller } from './dom.js';
import { sig, withUnit, limitText } from './format.js';
import { newRun } from './editor.js';
import { signalPage } from './signal.js';
import { calibrationSection } from './calibration.js';

const view = document.getElementById('view');
let cleanup = [];  // closers for the current view (event streams, timers)

const fmt = (v) => sig(v);
const verdictBadge = (v, extra = '') => h('span', { class: `verdict v-${v || 'none'} ${extra}`, 'data-verdict': v || '' }, v || '—');
const status = (msg) => { document.getElementById('status').textContent = msg; };

// The footer's run count, on every page: the run list sets it on each poll; elsewhere it is
// asked for when the page changes, every 10 s, and when a run is started from this page, so it
// never shows a count from an earlier page.
const LIST_MAX = 1000;
function showRunCount(n, filtered = false, max = 100) {
  const count = `${n >= max ? `${max}+` : n} run${n === 1 ? '' : 's'}${filtered ? ' (filtered)' : ''}`;
  status(`${count} · ${new Date().toLocaleTimeString()}`);
  document.getElementById('status').dataset.runs = String(n);
}
export async function refreshRunCount() {
  try {
    const d = await api.get(`runs?limit=${LIST_MAX}`);
    showRunCount(d.runs.length, false, LIST_MAX);
  } catch { /* the page says what failed; the footer keeps its last count */ }
}
window.addEventListener('fringe:run-started', refreshRunCount);

// ---- token ---------------------------------------------------------------------------
// The URL fringe serve prints on first start ends in #token=HEX: taken whenever the hash
// carries it (a fresh tab, or this tab with the app already open), then dropped from the URL.
function takeTokenFromHash() {
  const m = location.hash.match(/^#token=([0-9a-fA-F]+)/);
  if (!m) return false;
  api.setToken(m[1]);
  showTokenState();
  history.replaceState(null, '', '#/runs');
  return true;
}
function showTokenState() {
  const state = document.getElementById('token-state');
  state.textContent = api.token() ? 'set' : 'not set (needed to start runs)';
  state.dataset.set = api.token() ? '1' : '';
}
function initToken() {
  const input = document.getElementById('token');
  document.getElementById('token-form').addEventListener('submit', (ev) => {
    ev.preventDefault();
    api.setToken(input.value.trim());
    input.value = '';
    showTokenState();
  });
  takeTokenFromHash();
  showTokenState();
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
  const table = h('table', { id: 'runs', class: 'cards' }, h('thead', {}, h('tr', {}, ['', 'run', 'bench', 'scenario', 'DUT', 'started (UTC)', 'status', 'verdict', 'progress'].map((c) => h('th', {}, c)))), tbody);
  const pick = new Set();
  const compareBtn = h('button', { type: 'button', disabled: true, onclick: () => { const [a, b] = [...pick]; location.hash = `#/compare/${a}/${b}`; } }, 'compare selected');
  view.replaceChildren(
    h('h1', {}, 'Runs'),
    h('form', { class: 'filters', onsubmit: apply },
      h('label', { class: 'field' }, 'verdict', verdict), h('label', { class: 'field' }, 'scenario', scenario),
      h('label', { class: 'field' }, 'since', since), h('label', { class: 'field' }, 'bench', bench),
      h('label', { class: 'field' }, 'DUT', dut), h('button', { type: 'submit' }, 'filter'), compareBtn,
      h('a', { class: 'button', href: '#/new' }, 'New run')),
    scroller(table));
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
      // On a phone each row is a card: verdict and scenario first, then the id and the rest (style.css).
      const c = (cls, label, ...x) => h('td', { class: cls, 'data-label': label }, ...x);
      return h('tr', { 'data-id': r.id, 'data-status': r.status },
        c('c-pick', null, box), c('c-id', 'run', h('a', { href: `#/run/${r.id}` }, r.id)), c('c-bench', r.bench ? 'bench' : null, r.bench || ''), c('c-scenario', null, r.scenario),
        c('c-dut', r.dut ? 'DUT' : null, r.dut || ''), c('c-started', 'started', r.created_at),
        c('c-status', null, r.status), c('c-verdict', null, verdictBadge(r.verdict)),
        c('c-progress', null, frac == null || r.status !== 'running' ? '' : `${(100 * frac).toFixed(0)} %`));
    }));
    showRunCount(data.runs.length, q.toString() !== '');
    return data.runs.some((r) => r.status === 'queued' || r.status === 'running');
  };
  // Live status: poll while something is queued or running, slowly otherwise.
  let timer = null;
  const loop = async () => { const busy = await refresh(); timer = setTimeout(loop, busy ? 500 : 3000); };
  cleanup.push(() => clearTimeout(timer));
  await loop();
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
  // Ask first: an unknown id (or a bad one) gets an answer instead of a stream that never opens.
  try {
    await api.get(`runs/${encodeURIComponent(id)}`);
  } catch (e) {
    const missing = e.status === 404 || e.code === 'bad_id';
    view.replaceChildren(h('h1', {}, 'Run ', h('code', {}, id)),
      h('p', { class: 'error', role: 'alert', id: 'run-missing', 'data-code': e.code || '' },
        missing ? `Run ${id} not found: no run with this id in this service's history. ` : `${errorText(e)} `, h('a', { href: '#/runs' }, 'see the run list')));
    return;
  }
  const close = api.follow(id, (s, end) => {
    const frac = s.progress && s.progress.total ? s.progress.done / s.progress.total : 0;
    bar.style.width = `${(100 * frac).toFixed(1)}%`;
    line.textContent = `${s.scenario}: ${s.status} · ${s.progress.done} / ${s.progress.total} samples${s.error ? ` · ${s.error}` : ''}`;
    line.dataset.status = s.status;
    if (end) { cancel.remove(); report(id, body); }
  }, () => { if (!line.dataset.status) line.textContent = 'the service does not answer: is fringe serve still running?'; });
  cleanup.push(close);
}

// Each measurement with its unit, its limit and its outcome on one row. The rows that decide
// the verdict come first: FAIL, ERROR, MARGINAL, then the passing user limits, then the evidence
// checks (stable within each group); a failing row is highlighted. On a phone each row is a
// card (style.css) with value, limit and outcome on screen, each cell named by data-label.
const OUTCOME_RANK = { FAIL: 0, ERROR: 1, MARGINAL: 2 };
export function measurementOrder(ms) {
  const rank = (m) => (m.outcome in OUTCOME_RANK ? OUTCOME_RANK[m.outcome] : m.implicit ? 4 : 3);
  return (ms || []).map((m, i) => [m, i]).sort((a, b) => rank(a[0]) - rank(b[0]) || a[1] - b[1]).map((x) => x[0]);
}
// A figure's 95 % interval beside it (docs/model.md "Uncertainty"); '' when it has none.
function intervalSpan(iv) {
  if (!Array.isArray(iv) || iv.length !== 2 || typeof iv[0] !== 'number' || typeof iv[1] !== 'number') return '';
  return h('span', { class: 'muted iv', title: '95 % interval from the number of independent samples the figure rests on' }, ` (95 % ${sig(iv[0])}..${sig(iv[1])})`);
}

function measurementsTable(r) {
  const cell = (label, attrs, ...c) => h('td', { ...attrs, 'data-label': label }, ...c);
  return scroller(h('table', { id: 'measurements', class: 'cards' },
    h('thead', {}, h('tr', {}, ['estimator', 'metric', 'value', 'limit', 'outcome'].map((c) => h('th', {}, c)))),
    h('tbody', {}, measurementOrder(r.measurements).map((m) => h('tr', { class: `${m.implicit ? 'evidence' : ''} o-${m.outcome || 'none'}`, 'data-outcome': m.outcome || '' },
      cell('estimator', { class: 'est' }, m.estimator), cell('metric', { class: 'metric' }, m.metric, m.implicit ? h('span', { class: 'muted', title: 'implicit check: a verdict needs this much evidence' }, ' (evidence)') : ''),
      cell('value', { class: 'num value', 'data-value': m.value == null ? '' : String(m.value) }, m.value == null ? 'not measured' : withUnit(m.value, m.unit), intervalSpan(m.interval_95)),
      cell('limit', { class: 'num limit' }, limitText(m.limit, m.unit)),
      cell('outcome', { class: 'outcome' }, verdictBadge(m.outcome), m.reason ? h('span', { class: 'muted reason' }, ` ${m.reason}`) : ''))))));
}

// Preflight and convention warnings: what the verdict was reached under.
function warningsList(r) {
  const w = r.warnings || [];
  if (!w.length) return '';
  return h('div', {}, h('h2', {}, 'Warnings'),
    h('ul', { id: 'warnings' }, w.map((x) => h('li', {}, h('code', {}, x.code), ' ', x.message))));
}

// The metric table of a report (GET runs/{id}/metrics): every metric of every lane, read by the
// server from its one metric table (fringe metrics); the web adds no metric of its own.
function valueCell(m, v) {
  if (!v) return h('td', {}, '');
  if (v.value == null) return h('td', { class: `num m-${m.name} muted`, title: v.why || 'not measured' }, 'not measured');
  return h('td', { class: `num m-${m.name}` }, sig(v.value), intervalSpan(v.interval_95));
}
const heading = (m) => [m.column || m.name, m.unit ? h('span', { class: 'unit' }, ` (${m.unit})`) : ''];

// Without truth the self-referenced columns come first, each value labelled as such.
function estimatorsTable(mt, truthless) {
  let cols = mt.metrics.filter((m) => m.column && m.scope === 'estimator');
  const selfRef = (m) => m.name.startsWith('self_ref_');
  if (truthless) cols = [...cols.filter(selfRef), ...cols.filter((m) => !selfRef(m))];
  const lanes = mt.lanes.filter((l) => l !== 'run');
  const cell = (m, l) => {
    const td = valueCell(m, m.values[l]);
    if (selfRef(m) && m.values[l] && m.values[l].value != null)
      td.append(h('span', { class: 'self-ref-tag', title: "measured against a phase built from the signals themselves (docs/self-reference.md)" },
        truthless ? ' self-referenced (no truth)' : ' self-referenced'));
    return td;
  };
  return scroller(h('table', { id: 'estimators' },
    h('thead', {}, h('tr', {}, h('th', {}, 'estimator'), cols.map((m) => h('th', { title: `${m.name}: ${m.description}` }, ...heading(m))))),
    h('tbody', {}, lanes.map((l) => h('tr', { 'data-lane': l }, h('td', {}, l), cols.map((m) => cell(m, l)))))));
}

// A run whose capture has no truth (theta_true): nothing is scored against truth, and each
// estimator's error is self-referenced (docs/self-reference.md). What that is, then each
// estimator's rms with its 95 % interval, or why it was not measured.
function selfRefSummary(r, mt) {
  const truthless = plots.hasNoTruth(r);
  const lanes = (r.estimators || []).filter((e) => e.analysers && e.analysers.self_reference);
  if (!lanes.length) return '';
  const rms = mt.metrics.find((m) => m.name === 'self_ref_rms_rad');
  const rows = lanes.map((e) => {
    const sr = e.analysers.self_reference;
    const v = rms && rms.values[e.label];
    const measured = v && v.value != null;
    const pm = measured && typeof sr.rms_u_rad === 'number' ? 1.96 * sr.rms_u_rad : null;
    return h('tr', { 'data-lane': e.label, 'data-measured': measured ? '1' : '' },
      h('td', { 'data-label': 'estimator' }, e.label),
      h('td', { class: 'num value', 'data-label': 'rms error', 'data-value': measured ? String(v.value) : '' },
        measured ? [withUnit(v.value, 'rad'), pm != null ? h('span', { class: 'pm' }, ` ± ${withUnit(pm, 'rad')}`) : '', intervalSpan(v.interval_95)]
          : h('span', { class: 'muted' }, `not measured: ${(v && v.why) || sr.why_not || 'no self-referenced window'}`)),
      h('td', { class: 'self-ref-tag', 'data-label': 'how' }, truthless ? 'self-referenced (no truth)' : 'self-referenced'),
      h('td', { class: 'muted', 'data-label': 'rests on' }, measured ? `${sr.samples} samples, ${sig(sr.cycles)} electrical periods in ${sr.windows} windows` : ''));
  });
  return h('div', { id: 'self-ref' },
    h('p', { id: 'self-ref-note', class: truthless ? 'warn' : 'muted' }, truthless
      ? "No truth in this capture (theta_true): nothing is scored against truth. Each estimator's error is self-referenced: measured against a phase built from the signals themselves, as its rms about the mean (the mean cannot be seen) with its 95 % uncertainty (± 1.96 u). The columns that need truth read \"not measured\"."
      : 'Also self-referenced (scoring.self_reference): the error measured against the signals\' own phase, to compare with the truth-scored std.'),
    scroller(h('table', { id: 'self-ref-table', class: 'cards' },
      h('thead', {}, h('tr', {}, ['estimator', 'rms error (95 %)', '', 'rests on'].map((c) => h('th', {}, c)))), h('tbody', {}, rows))));
}

// The signals' quality, once for the run (docs/signal-quality.md): the run-level summary columns.
function signalTable(mt) {
  const cols = mt.metrics.filter((m) => m.column && m.scope === 'run' && m.group === 'signal');
  if (!cols.length) return '';
  return h('div', {}, scroller(h('table', { id: 'signal' },
    h('thead', {}, h('tr', {}, cols.map((m) => h('th', { title: `${m.name}: ${m.description}` }, ...heading(m))))),
    h('tbody', {}, h('tr', {}, cols.map((m) => valueCell(m, m.values.run)))))));
}

function allMetricsTable(mt) {
  return h('details', { id: 'all-metrics' }, h('summary', {}, `All metrics (${mt.metrics.length})`),
    scroller(h('table', { id: 'metrics' },
      h('thead', {}, h('tr', {}, ['metric', 'unit', ...mt.lanes, 'meaning'].map((c) => h('th', {}, c)))),
      h('tbody', {}, mt.metrics.map((m) => h('tr', { 'data-metric': m.name }, h('td', {}, h('code', {}, m.name)), h('td', { class: 'unit' }, m.unit),
        mt.lanes.map((l) => valueCell(m, m.values[l])), h('td', { class: 'muted' }, m.description)))))));
}

// Every fitted harmonic of each estimator's error, with its 95 % interval (the bars in the
// plots show the amplitudes scored against truth); then the self-referenced harmonics of the
// error against the electrical angle (docs/self-reference.md), interval +- 1.96 u.
function harmonicsTable(r) {
  const rows = [];
  const truthless = plots.hasNoTruth(r);
  for (const e of r.estimators || []) {
    const m = e.metrics || {}, u = (m.uncertainty || {}).harmonics || [];
    for (const x of m.harmonics || []) {
      const iv = (u.find((y) => y.order === x.order) || {}).amplitude_rad;
      rows.push(h('tr', {}, h('td', {}, e.label), h('td', { class: 'num' }, `${x.order}x`),
        h('td', { class: 'num' }, withUnit(x.amplitude && x.amplitude.rad, 'rad'), intervalSpan(iv)), h('td', { class: 'muted' }, 'against truth')));
    }
  }
  for (const e of r.estimators || []) {
    const sr = e.analysers && e.analysers.self_reference;
    if (!sr || !sr.measured) continue;
    for (const x of sr.harmonics || []) {
      const iv = typeof x.u_rad === 'number' ? [Math.max(0, x.amplitude_rad - 1.96 * x.u_rad), x.amplitude_rad + 1.96 * x.u_rad] : null;
      rows.push(h('tr', { class: 'self-ref', 'data-lane': e.label, 'data-order': x.order }, h('td', {}, e.label), h('td', { class: 'num' }, `${x.order}x`),
        h('td', { class: 'num' }, withUnit(x.amplitude_rad, 'rad'), intervalSpan(iv)),
        h('td', { class: 'self-ref-tag' }, truthless ? 'self-referenced (no truth)' : 'self-referenced')));
    }
  }
  if (!rows.length) return '';
  return h('div', {}, h('h2', {}, 'Error harmonics'), scroller(h('table', { id: 'harmonics' },
    h('thead', {}, h('tr', {}, ['estimator', 'order', 'amplitude', 'measured'].map((c) => h('th', {}, c)))), h('tbody', {}, rows))));
}

async function report(id, into) {
  let r, tr, mt;
  try {
    [r, tr, mt] = await Promise.all(['report.json', 'traces', 'metrics'].map((p) => api.get(`runs/${encodeURIComponent(id)}/${p}`)));
  } catch (e) { into.replaceChildren(showError(e)); return; }
  const base = `/api/v1/runs/${encodeURIComponent(id)}`;
  const plotBox = h('div', { class: 'plots', id: 'plots' });
  // The signal page: the figures graded against the interface profile, the Lissajous and the
  // per-period recording (signal.js), drawn once the section is on the page.
  const signals = h('section', { id: 'signal-page' }, h('h2', {}, 'Signals'), signalTable(mt));
  const truthless = plots.hasNoTruth(r);
  into.replaceChildren(
    h('p', {}, verdictBadge(r.verdict, 'banner'), ' ', h('span', { id: 'verdict-text' }, `${r.scenario.name} · ${r.status} · seed ${r.seed} · ${r.samples ? r.samples.processed : 0} samples · device ${r.device ? r.device.uri : '-'}${truthless ? " · no truth: the estimators' error is self-referenced" : ''}`)),
    r.error ? h('p', { class: 'error' }, r.error) : '',
    warningsList(r),
    h('p', { class: 'downloads' }, 'Download: ',
      h('a', { href: `${base}/report.json?download=1&traces=1`, download: '', id: 'dl-json' }, 'JSON'),
      h('a', { href: `${base}/report.xml?download=1`, download: '', id: 'dl-junit' }, 'JUnit XML'),
      h('a', { href: `${base}/report.html?download=1`, download: '', id: 'dl-html' }, 'HTML'),
      h('a', { href: `#/compare/${id}` }, 'compare with…')),
    calibrationSection(r),
    h('h2', {}, 'Measurements'), measurementsTable(r),
    h('h2', {}, 'Estimators'), selfRefSummary(r, mt), estimatorsTable(mt, truthless), signals, allMetricsTable(mt), harmonicsTable(r),
    h('h2', {}, 'Plots'), plotBox);
  try {
    signalPage(signals, r, mt);
  } catch (e) { signals.append(showError(e)); }
  const t = tr.traces || {};
  const empty = !t.t_s || !t.t_s.length;
  if (empty) { plotBox.append(h('p', { class: 'muted' }, 'no traces (the run processed no samples)')); return; }
  try {
    plots.reportPlots(plotBox, t, tr.estimators || [], r);
  } catch (e) { plotBox.append(showError(e)); }
}

// ---- compare two runs ----------------------------------------------------------------
async function compare(a, b) {
  const pickForm = h('form', { class: 'filters', onsubmit: (ev) => {
    ev.preventDefault();
    location.hash = `#/compare/${ev.target.a.value.trim()}/${ev.target.b.value.trim()}`;
  } }, h('label', { class: 'field' }, 'run A', h('input', { name: 'a', value: a || '', size: 26 })),
  h('label', { class: 'field' }, 'run B', h('input', { name: 'b', value: b || '', size: 26 })), h('button', { type: 'submit' }, 'compare'));
  view.replaceChildren(h('h1', {}, 'Compare runs'), pickForm);
  if (!a || !b) return;
  let ra, rb, ta, tb, ma0, mb0;
  try {
    [ra, rb, ta, tb, ma0, mb0] = await Promise.all([`${a}/report.json`, `${b}/report.json`, `${a}/traces`, `${b}/traces`, `${a}/metrics`, `${b}/metrics`]
      .map((p) => api.get(`runs/${p}`)));
  } catch (e) { view.append(showError(e)); return; }
  // The summary columns of the metric table, lane by lane, A beside B.
  const labels = [...new Set([...ma0.lanes, ...mb0.lanes])].filter((l) => l !== 'run');
  const byName = (mt) => Object.fromEntries(mt.metrics.map((m) => [m.name, m]));
  const na = byName(ma0), nb = byName(mb0);
  const cols = ma0.metrics.filter((m) => m.column && m.scope === 'estimator');
  const rows = [];
  const val = (m, l) => (m && m.values[l] ? m.values[l].value : null);
  for (const l of labels)
    for (const m of cols) {
      const va = val(na[m.name], l), vb = val(nb[m.name], l);
      rows.push(h('tr', {}, h('td', {}, l), h('td', {}, ...heading(m)), h('td', { class: 'num' }, fmt(va)), h('td', { class: 'num' }, fmt(vb)),
        h('td', { class: 'num' }, va && vb ? `${(vb / va).toFixed(3)}×` : '-')));
    }
  // Limits and outcomes of each run, side by side: the runs may differ in limits as well as in values.
  const key = (m) => `${m.estimator}\u0000${m.metric}`;
  const ma = new Map((ra.measurements || []).map((m) => [key(m), m])), mb = new Map((rb.measurements || []).map((m) => [key(m), m]));
  const limitOf = (m) => (m && m.limit ? limitText(m.limit, m.unit) : '-');
  const limitRows = [...new Set([...ma.keys(), ...mb.keys()])].map((k) => {
    const x = ma.get(k), y = mb.get(k), m = x || y;
    return h('tr', {}, h('td', {}, m.estimator), h('td', {}, m.metric), h('td', {}, m.unit || ''),
      h('td', { class: 'num' }, x ? fmt(x.value) : '-'), h('td', {}, limitOf(x)), h('td', {}, x ? verdictBadge(x.outcome) : '-'),
      h('td', { class: 'num' }, y ? fmt(y.value) : '-'), h('td', {}, limitOf(y)), h('td', {}, y ? verdictBadge(y.outcome) : '-'));
  });
  const plotBox = h('div', { class: 'plots compare-plots', id: 'compare-plots' });
  const nameA = (ra.scenario && ra.scenario.name) || '?', nameB = (rb.scenario && rb.scenario.name) || '?';
  const diffs = scenarioDiff(ra.scenario || {}, rb.scenario || {});
  view.append(
    h('p', { id: 'compare-names' }, h('b', {}, 'A'), ` ${nameA} (`, h('a', { href: `#/run/${a}` }, a), ') ', verdictBadge(ra.verdict), ' · ',
      h('b', {}, 'B'), ` ${nameB} (`, h('a', { href: `#/run/${b}` }, b), ') ', verdictBadge(rb.verdict)),
    h('h2', {}, 'What differs'),
    diffs.length ? scroller(h('table', { id: 'compare-diff', class: 'cards' }, h('thead', {}, h('tr', {}, ['setting', `A: ${nameA}`, `B: ${nameB}`].map((c) => h('th', {}, c)))),
      h('tbody', {}, diffs.map((d) => h('tr', { 'data-key': d.key }, h('td', { 'data-label': null, class: 'key' }, d.key),
        h('td', { 'data-label': 'A' }, d.a), h('td', { 'data-label': 'B' }, d.b))))))
      : h('p', { id: 'compare-diff', class: 'muted' }, 'The two scenarios are the same setting for setting (only the runs differ).'),
    scroller(h('table', { id: 'compare' }, h('thead', {}, h('tr', {},
      h('th', {}, 'estimator'), h('th', {}, 'metric'), h('th', {}, h('a', { href: `#/run/${a}` }, 'A '), verdictBadge(ra.verdict)),
      h('th', {}, h('a', { href: `#/run/${b}` }, 'B '), verdictBadge(rb.verdict)), h('th', {}, 'B / A'))), h('tbody', {}, rows))),
    h('h2', {}, 'Limits and outcomes'),
    scroller(h('table', { id: 'compare-limits' }, h('thead', {}, h('tr', {},
      ['estimator', 'metric', 'unit', 'A value', 'A limit', 'A outcome', 'B value', 'B limit', 'B outcome'].map((c) => h('th', {}, c)))),
    h('tbody', {}, limitRows))),
    h('h2', {}, 'Error vs time, A and B on the same axes'), plotBox);
  // Shared axes: both plots span the same time and error range, so equal errors look equal; each
  // run's errors stay on its own times (never B's errors on A's times). One colour per estimator.
  const ta_ = ta.traces || {}, tb_ = tb.traces || {};
  const common = labels.filter((l) => ta_.error_rad && ta_.error_rad[l] && tb_.error_rad && tb_.error_rad[l]);
  const span = (t) => { const v = (t.t_s || []).filter((x) => x != null); return v.length ? [v[0], v[v.length - 1]] : null; };
  const sa = span(ta_), sb = span(tb_);
  const xRange = sa && sb ? [Math.min(sa[0], sb[0]), Math.max(sa[1], sb[1])] : null;
  let lo = Infinity, hi = -Infinity, alo = Infinity, ahi = 0;
  for (const t of [ta_, tb_])
    for (const l of common) {
      const e = t.error_rad[l];
      const arrs = Array.isArray(e) ? [e] : [e.min, e.max];
      for (const arr of arrs) for (const v of arr || []) if (v != null && Number.isFinite(v)) {
        lo = Math.min(lo, v); hi = Math.max(hi, v);
        if (v !== 0) { alo = Math.min(alo, Math.abs(v)); ahi = Math.max(ahi, Math.abs(v)); }
      }
    }
  const ctxA = plots.plotContext(ra, ra.estimators, common), ctxB = plots.plotContext(rb, rb.estimators, common);
  for (const lim of [...(ctxA.limits || []), ...(ctxB.limits || [])]) for (const y of lim.ys) { lo = Math.min(lo, y); hi = Math.max(hi, y); ahi = Math.max(ahi, Math.abs(y)); }
  const pad = (hi - lo) * 0.05 || Math.abs(hi) * 0.05 || 1e-9;
  const yRange = Number.isFinite(lo) ? [lo - pad, hi + pad] : null;
  const yRangeLog = ahi > 0 ? [10 ** Math.floor(Math.log10(alo)), 10 ** Math.ceil(Math.log10(ahi))] : null;
  const colorIndex = (l) => Math.max(0, labels.indexOf(l));
  for (const l of common)
    for (const [run, t, idr, name, c] of [['A', ta_, a, nameA, ctxA], ['B', tb_, b, nameB, ctxB]]) {
      const div = plots.errorVsTime(plotBox, t, [l], `${run}: ${name} (${idr}), ${l}, error vs time`, `compare-${run}-${l}`,
        { ...c, xRange, yRange, yRangeLog, colorIndex });
      div.dataset.run = run;
    }
}

// Settings that differ between two scenarios, as dotted keys with both values ("motion.velocity_rad_s").
// Name and description are shown above, not listed as settings.
export function scenarioDiff(a, b) {
  const flat = (o, pre, out) => {
    if (o && typeof o === 'object' && !Array.isArray(o)) {
      for (const k of Object.keys(o)) flat(o[k], pre ? `${pre}.${k}` : k, out);
      if (!Object.keys(o).length && pre) out[pre] = '{}';
    } else if (Array.isArray(o) && o.length && o.every((x) => x && typeof x === 'object')) {
      o.forEach((x, i) => flat(x, `${pre}[${i}]`, out));
    } else out[pre] = JSON.stringify(o);
    return out;
  };
  const fa = flat(a, '', {}), fb = flat(b, '', {});
  const keys = [...new Set([...Object.keys(fa), ...Object.keys(fb)])].filter((k) => k !== 'name' && k !== 'description');
  return keys.filter((k) => fa[k] !== fb[k]).map((k) => ({ key: k, a: k in fa ? fa[k] : '(not set)', b: k in fb ? fb[k] : '(not set)' }));
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
    if (parts[0] !== 'runs' && parts[0]) {
      refreshRunCount();
      const t = setInterval(refreshRunCount, 10000);
      cleanup.push(() => clearInterval(t));
    }
    if (parts[0] === 'new') await newRun(view, cleanup);
    else if (parts[0] === 'run' && parts[1]) await runPage(parts[1]);
    else if (parts[0] === 'compare') await compare(parts[1], parts[2]);
    else await runList(Object.fromEntries(new URLSearchParams(query)));
  } catch (e) {
    view.replaceChildren(showError(e));
  }
}

initToken();
window.addEventListener('hashchange', () => {
  if (takeTokenFromHash()) status('API token saved from the link');
  route();
});
route();
