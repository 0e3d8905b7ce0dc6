// New run: a scenario editor built from what the API says about itself (GET /schema for the
// scenario's keys, units and ranges, /estimators and /drivers for their parameters, /fixtures
// for starting points). The API is the validator: its 4xx errors name a field, and the message
// is shown at that field; POST /preflight shows the warnings before Start.
import * as api from './api.js';
import { h, errorText } from './dom.js';
import { sig } from './format.js';

const RAD_S_PER_RPM = (2 * Math.PI) / 60;

// The blank start: nothing chosen, every field empty (the inputs show the service's defaults).
const BLANK = { encoder: {}, motion: { kind: 'constant' }, device: 'loopback:', estimators: [], limits: [] };

// ---- small helpers -------------------------------------------------------------------
function getDeep(o, path) {
  return path.split('.').reduce((a, k) => (a == null ? undefined : a[k]), o);
}
function setDeep(o, path, v) {
  const ks = path.split('.');
  let a = o;
  for (const k of ks.slice(0, -1)) a = a[k] && typeof a[k] === 'object' ? a[k] : (a[k] = {});
  if (v === undefined) delete a[ks[ks.length - 1]];
  else a[ks[ks.length - 1]] = v;
}
const nice = (v) => (typeof v === 'number' && Number.isFinite(v) ? String(+v.toPrecision(8)) : v);

// One input for a self-described parameter (name, unit, type, default, min, max, options).
// The schema's keys the editor offers as fields; the others ("editor": false: model-specific,
// structured or rarely set) are kept as the fixture gives them.
const offered = (list) => list.filter((p) => p.editor !== false);

function paramInput(p, value, field, name = field) {
  let input;
  if (p.type === 'boolean') {
    input = h('input', { type: 'checkbox', name });
    input.checked = value ?? p.default ?? false;
  } else if (p.options && p.options.length) {
    input = h('select', { name }, p.options.map((o) => h('option', { value: o }, o)));
    input.value = value ?? p.default ?? p.options[0];
  } else {
    const numeric = p.type === 'number' || p.type === 'integer';
    // Ranges are the API's to check (novalidate form): it names the field and the range.
    input = h('input', { name, type: numeric ? 'number' : 'text', step: numeric ? 'any' : null,
      placeholder: p.default == null ? (p.type === 'string' ? '' : 'derived') : String(nice(p.default)) });
    if (value != null) input.value = nice(value);
  }
  input.dataset.type = p.type;
  input.dataset.param = p.name;
  input.dataset.field = field;
  const unit = p.unit ? ` [${p.unit}]` : '';
  const range = p.min != null || p.max != null ? ` (${p.min != null ? sig(p.min) : '…'} to ${p.max != null ? sig(p.max) : '…'})` : '';
  return h('label', { class: 'field', title: `${p.description || ''}${range}` }, h('span', { class: 'fname' }, `${p.name}${unit}`), input);
}

// The value an input holds, typed as its parameter; undefined when empty (the default).
function readInput(el) {
  const t = el.dataset.type;
  if (t === 'boolean') return el.checked;
  if (el.value === '') return undefined;
  if (t === 'integer' || t === 'number') {
    const x = Number(el.value);
    return Number.isFinite(x) ? x : el.value;  // the API names a non-number at its field
  }
  return el.value;
}
function readParams(container) {
  const out = {};
  for (const el of container.querySelectorAll('[data-param]')) {
    if (el.disabled) continue;  // a setting that does not apply in the chosen mode (loopback own_clock)
    const v = readInput(el);
    if (v !== undefined) out[el.dataset.param] = v;
  }
  return out;
}

// ---- the page ------------------------------------------------------------------------
export async function newRun(view, cleanup) {
  let cat;
  try {
    const [fx, est, drv, schema] = await Promise.all([api.get('fixtures'), api.get('estimators'), api.get('drivers'), api.get('schema')]);
    cat = { fixtures: fx.fixtures.filter((f) => f.runnable), encoders: fx.encoders || [], interfaces: fx.interfaces || [], estimators: est.estimators, drivers: drv.drivers, schema };
  } catch (e) {
    view.replaceChildren(h('p', { class: 'error', role: 'alert' }, errorText(e)));
    return;
  }
  const S = cat.schema;
  let base = null;  // the fixture the editor started from: keys the editor does not show stay as they are

  // Scenario: starting point, name, description. A fixture is a starting point, not an identity:
  // its name and description are shown beside the choice but are not the user's scenario's. The
  // name and description fields start empty and only what is in them is sent (empty name: the
  // service calls it "unnamed"); "keep the fixture's name and description" copies them into the
  // fields for a user who re-runs the fixture on purpose. "blank" starts from nothing.
  const fixtureSel = h('select', { name: 'fixture', id: 'fixture' }, h('option', { value: '' }, 'blank (nothing filled in)'),
    cat.fixtures.map((f) => h('option', { value: f.name }, f.name)));
  const nameIn = h('input', { name: 'name', id: 'sc-name', 'data-field': 'scenario.name', size: 24, placeholder: 'unnamed' });
  const descIn = h('textarea', { name: 'description', id: 'sc-description', 'data-field': 'scenario.description', rows: 2, cols: 48, placeholder: 'what this scenario is for (optional)' });
  const fixtureText = h('span', { id: 'sc-desc' });
  const keepBtn = h('button', { type: 'button', id: 'keep-fixture-text', hidden: true, onclick: () => {
    nameIn.value = (base && base.name) || '';
    descIn.value = (base && base.description) || '';
    schedule();
  } }, "keep the fixture's name and description");
  const desc = h('p', { class: 'muted', id: 'sc-from' }, fixtureText, ' ', keepBtn);

  // Encoder: a profile by name, or inline values.
  const encSel = h('select', { name: 'encoder_source', id: 'encoder-source', 'data-field': 'scenario.encoder' },
    h('option', { value: '' }, 'inline (the values below)'), cat.encoders.map((n) => h('option', { value: n }, `profile: ${n}`)));
  const encGrid = h('div', { class: 'params', id: 'encoder-params' });
  const fillEncoder = (enc) => {
    encSel.value = typeof enc === 'string' ? (enc.match(/([^/]+)\.json$/) || [])[1] || '' : '';
    const obj = enc && typeof enc === 'object' ? enc : {};
    encGrid.replaceChildren(...offered(S.encoder).map((p) => paramInput(p, getDeep(obj, p.name), `scenario.encoder.${p.name}`, `encoder.${p.name}`)));
    encGrid.hidden = encSel.value !== '';
  };
  encSel.addEventListener('change', () => { encGrid.hidden = encSel.value !== ''; });

  // Motion: kind, speed unit, the kind's parameters.
  const kinds = offered(S.motion);
  const kindSel = h('select', { name: 'motion.kind', id: 'motion-kind', 'data-field': 'scenario.motion.kind' },
    kinds.map((k) => h('option', { value: k.kind }, `${k.kind}: ${k.summary}`)));
  const speedUnit = h('select', { name: 'speed_unit', id: 'speed-unit' });
  const motionGrid = h('div', { class: 'params', id: 'motion-params' });
  const linesNow = () => {
    const el = encGrid.querySelector('[data-param="lines_per_rev"]');
    return (el && Number(el.value)) || 1024;
  };
  const speedFactor = (u) => (u === 'rpm' ? RAD_S_PER_RPM : u === 'hz_el' ? (2 * Math.PI) / linesNow() : 1);  // rad/s per unit
  const speedLabel = { rpm: 'rpm', rad_s: 'rad/s', hz_el: 'Hz, electrical' };
  let keptMotion = null;  // a fixture's motion of a kind the editor does not describe (a table file): sent as it is
  const fillMotion = (m) => {
    for (const o of kindSel.querySelectorAll('option.kept')) o.remove();
    keptMotion = null;
    if (m && m.kind && !kinds.some((k) => k.kind === m.kind)) {
      keptMotion = structuredClone(m);
      kindSel.append(h('option', { value: m.kind, class: 'kept' }, `${m.kind}: as in the fixture`));
      kindSel.value = m.kind;
      speedUnit.replaceChildren();
      motionGrid.replaceChildren(h('p', { class: 'muted' }, `This fixture's ${m.kind} motion is kept as it is.`));
      return;
    }
    const kind = kinds.find((k) => k.kind === (m && m.kind)) || kinds[0];
    kindSel.value = kind.kind;
    const units = kind.kind === 'constant' ? ['rpm', 'rad_s', 'hz_el'] : ['rpm', 'rad_s'];
    const keep = units.includes(speedUnit.value) ? speedUnit.value : 'rpm';
    speedUnit.replaceChildren(...units.map((u) => h('option', { value: u }, speedLabel[u])));
    speedUnit.value = m && m.electrical_freq_hz != null && kind.kind === 'constant' ? 'hz_el' : keep;
    const u = speedUnit.value;
    motionGrid.replaceChildren(...kind.params.filter((p) => p.name !== 'electrical_freq_hz').map((p) => {
      let v = m ? m[p.name] : undefined;
      if (p.name === 'velocity_rad_s') {
        if (u === 'hz_el') v = m && m.electrical_freq_hz != null ? m.electrical_freq_hz : v == null ? v : v / speedFactor(u);
        else if (v != null) v /= speedFactor(u);
        const el = paramInput({ ...p, unit: speedLabel[u] }, v, 'scenario.motion.velocity_rad_s', 'motion.velocity');
        el.querySelector('.fname').textContent = `speed [${speedLabel[u]}]`;
        el.querySelector('input').dataset.speed = '1';
        return el;
      }
      return paramInput(p, v, `scenario.motion.${p.name}`, `motion.${p.name}`);
    }));
    lastUnit = u;
  };
  let lastUnit = 'rpm';  // the unit the speed inputs show
  kindSel.addEventListener('change', () => fillMotion({ ...readMotion(), kind: kindSel.value }));
  speedUnit.addEventListener('change', () => {
    // The same speed in the new unit.
    for (const el of motionGrid.querySelectorAll('[data-speed]'))
      if (el.value !== '' && Number.isFinite(Number(el.value))) el.value = nice((Number(el.value) * speedFactor(lastUnit)) / speedFactor(speedUnit.value));
    lastUnit = speedUnit.value;
    fillMotion(readMotion());
  });
  function readMotion() {
    if (keptMotion && kindSel.value === keptMotion.kind) return structuredClone(keptMotion);
    const m = { kind: kindSel.value };
    for (const el of motionGrid.querySelectorAll('[data-param]')) {
      const v = readInput(el);
      if (v === undefined) continue;
      if (el.dataset.speed) {
        if (speedUnit.value === 'hz_el') m.electrical_freq_hz = v;
        else m.velocity_rad_s = typeof v === 'number' ? v * speedFactor(speedUnit.value) : v;
      } else m[el.dataset.param] = v;
    }
    return m;
  }

  // Sampling: sample rate, duration, settle time, seed, t0 (the schema's scenario keys).
  const sampGrid = h('div', { class: 'params open', id: 'sampling-params' });
  const fillSampling = (sc) => sampGrid.replaceChildren(...offered(S.scenario).map((p) => paramInput(p, sc[p.name], `scenario.${p.name}`, p.name)));

  // Interface profile: the limits the signals' figures are graded against (docs/signal-quality.md
  // "Interface profiles"). A shipped profile is sent as its file beside the scenarios
  // ("../interfaces/NAME.json", resolved by the service in its fixtures); a profile inline, or a
  // file the service does not list, is kept as the scenario gives it. A dropped capture gets 1 Vpp
  // unless a profile is already set or the user chose one (or none) by hand.
  const KEPT = '(kept)';
  const ifaceSel = h('select', { name: 'interface', id: 'interface', 'data-field': 'scenario.interface' });
  const ifaceNote = h('span', { class: 'muted', id: 'interface-note', role: 'status' });
  let keptInterface = null;
  let interfaceChosen = false;
  const fillInterface = (v) => {
    keptInterface = null;
    interfaceChosen = false;
    ifaceNote.textContent = '';
    const opts = [h('option', { value: '' }, 'none (the figures are not graded)'),
      ...cat.interfaces.map((i) => h('option', { value: i.name, disabled: !!i.problem, title: i.problem || `fixtures/interfaces/${i.name}.json` }, i.title || i.name))];
    let value = '';
    const m = typeof v === 'string' ? v.match(/^\.\.\/interfaces\/([^/]+)\.json$/) : null;
    if (m && cat.interfaces.some((i) => i.name === m[1] && !i.problem)) value = m[1];
    else if (v != null) {
      keptInterface = structuredClone(v);
      opts.push(h('option', { value: KEPT, class: 'kept' }, typeof v === 'object' ? `inline: ${v.name || 'unnamed'}` : `file: ${v}`));
      value = KEPT;
    }
    ifaceSel.replaceChildren(...opts);
    ifaceSel.value = value;
  };
  ifaceSel.addEventListener('change', () => { interfaceChosen = true; ifaceNote.textContent = ''; });
  const readInterface = () => (ifaceSel.value === KEPT ? structuredClone(keptInterface) : ifaceSel.value ? `../interfaces/${ifaceSel.value}.json` : undefined);
  const preselectInterface = () => {
    if (interfaceChosen || ifaceSel.value !== '') return;
    const one = cat.interfaces.find((i) => i.name === '1vpp' && !i.problem);
    if (!one) return;
    ifaceSel.value = one.name;
    ifaceNote.textContent = `${one.title || one.name} preselected for the capture: its signals are graded against it (choose another profile, or none, here).`;
  };

  // Device: driver, path, the driver's settings; capture files by picker or drop.
  const driverSel = h('select', { name: 'driver', id: 'driver', 'data-field': 'scenario.device' }, cat.drivers.map((d) => h('option', { value: d.scheme }, d.scheme)));
  const devPath = h('input', { name: 'device_path', id: 'device-path', 'data-field': 'scenario.device', placeholder: 'path (capture: an uploaded capture id)', list: 'capture-ids' });
  const captureIds = h('datalist', { id: 'capture-ids' });
  const devParams = h('div', { class: 'params open', id: 'device-params' });
  const fileIn = h('input', { type: 'file', id: 'capture-file', accept: '.csv,.fcap,text/csv,application/octet-stream' });
  const uploadState = h('span', { class: 'muted', id: 'upload-state', role: 'status' });
  const drop = h('div', { class: 'dropzone', id: 'capture-drop', hidden: true },
    h('p', {}, 'Capture file (CSV t,sin,cos[,theta_true] or .fcap): drop it here or ', h('label', { class: 'filepick' }, 'choose a file', fileIn)), uploadState);
  const uploadCapture = async (file) => {
    if (!file) return;
    uploadState.textContent = `uploading ${file.name} (${sig(file.size / 1024)} KiB)…`;
    uploadState.className = 'muted';
    try {
      const fmt = /\.fcap$/i.test(file.name) ? 'fcap' : /\.csv$/i.test(file.name) ? 'csv' : '';
      const c = await api.upload(`captures${fmt ? `?format=${fmt}` : ''}`, file);
      devPath.value = c.id;
      // The run plays the capture at its own rate: the scenario's rate must match it.
      const rate = sampGrid.querySelector('[data-param="sample_rate_hz"]');
      const dur = sampGrid.querySelector('[data-param="duration_s"]');
      if (rate && c.sample_rate_hz) rate.value = nice(c.sample_rate_hz);
      if (dur && c.sample_rate_hz && c.samples) dur.value = nice(c.samples / c.sample_rate_hz);
      uploadState.textContent = `uploaded ${file.name}: capture ${c.id}, ${c.samples} samples at ${sig(c.sample_rate_hz)} Hz, ${c.has_truth ? 'with truth'
        : "without truth: each estimator's error will be self-referenced (measured against the signals' own phase, with its uncertainty)"}`;
      uploadState.dataset.id = c.id;
      uploadState.dataset.truth = c.has_truth ? '1' : '';
      captureTruth = !!c.has_truth;
      markNeedsTruth();
      preselectInterface();
      schedule();
    } catch (e) {
      uploadState.textContent = `${file.name}: ${errorText(e)}`;
      uploadState.className = 'error';
    }
  };
  fileIn.addEventListener('change', () => uploadCapture(fileIn.files[0]));
  devPath.addEventListener('input', () => { captureTruth = null; markNeedsTruth(); });
  drop.addEventListener('dragover', (ev) => { ev.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (ev) => {
    ev.preventDefault();
    drop.classList.remove('over');
    uploadCapture(ev.dataTransfer && ev.dataTransfer.files[0]);
  });
  // Output and input instruments ({output, input}, docs/alignment.md): the form edits the
  // generator's URI; one instrument for both (the same URI) stays one, another input is kept.
  let instruments = null;
  const fillDevice = (device) => {
    captureTruth = null;
    instruments = device && typeof device === 'object' ? device : null;
    const uri = instruments ? instruments.output : device;
    const colon = uri.indexOf(':');
    const scheme = colon < 0 ? uri : uri.slice(0, colon);
    const [path, query = ''] = (colon < 0 ? '' : uri.slice(colon + 1)).split('?');
    driverSel.value = scheme;
    devPath.value = path;
    const given = Object.fromEntries(new URLSearchParams(query));
    const d = cat.drivers.find((x) => x.scheme === scheme) || cat.drivers[0];
    devParams.replaceChildren(...(d ? d.settings : []).map((p) => paramInput(p, given[p.name], `scenario.device.${p.name}`, `device.${p.name}`)));
    modeSettings(d);
    drop.hidden = scheme !== 'capture';
    markNeedsTruth();
    if (scheme === 'capture')
      api.get('captures').then((r) => captureIds.replaceChildren(...(r.captures || []).map((c) => h('option', { value: c.id }, `${c.samples} samples`)))).catch(() => {});
  };
  driverSel.addEventListener('change', () => fillDevice(`${driverSel.value}:`));
  // A driver with an own_clock mode (loopback) describes the settings of that mode as
  // "own_clock: ..." and refuses them without own_clock=1: they are hidden and left out of the
  // scenario (disabled) until own_clock is 1, with a note naming them.
  const ownNote = h('p', { class: 'muted', id: 'own-clock-note' });
  function modeSettings(d) {
    ownNote.remove();
    const own = devParams.querySelector('[data-param="own_clock"]');
    if (!d || !own) return;
    const only = d.settings.filter((p) => p.name !== 'own_clock' && /^own_clock\b/.test(p.description || '')).map((p) => p.name);
    if (!only.length) return;
    const apply = () => {
      const on = Number(readInput(own)) === 1;
      for (const n of only) {
        const el = devParams.querySelector(`[data-param="${n}"]`);
        if (!el) continue;
        el.disabled = !on;
        el.closest('label.field').hidden = !on;
      }
      ownNote.textContent = on ? '' : `${only.length} more settings (${only.join(', ')}) apply to a generator and a digitizer on separate clocks: set own_clock to 1 to show them.`;
      ownNote.hidden = on;
    };
    own.addEventListener('input', apply);
    own.addEventListener('change', apply);
    devParams.after(ownNote);
    apply();
  }
  const deviceUri = () => {
    const dq = new URLSearchParams();
    for (const [k, v] of Object.entries(readParams(devParams))) dq.set(k, String(v));
    const qs = dq.toString();
    const uri = `${driverSel.value}:${devPath.value.trim()}${qs ? `?${qs}` : ''}`;
    if (!instruments) return uri;
    return instruments.input === instruments.output ? { ...instruments, output: uri, input: uri } : { ...instruments, output: uri };
  };

  // Estimators: only the ticked ones show their parameters.
  const estBox = h('div', { id: 'estimators-box' });
  const fillEstimators = (chosen) => {
    estBox.replaceChildren(...cat.estimators.map((e) => {
      const spec = chosen.find((c) => c.name === e.name);
      const box = h('input', { type: 'checkbox', name: `est.${e.name}`, 'data-estimator': e.name });
      box.checked = !!spec;
      const params = h('div', { class: 'params', hidden: !spec }, e.params.map((p) => paramInput(p, spec && spec.params ? spec.params[p.name] : undefined, `est.${e.name}.${p.name}`)));
      box.addEventListener('change', () => { params.hidden = !box.checked; refreshLimits(); });
      const div = h('div', { class: 'estimator', 'data-name': e.name, 'data-label': (spec && spec.label) || e.name },
        h('label', { title: e.summary }, box, ` ${e.name} `, h('span', { class: 'muted' }, e.summary)), params);
      div.spec = spec || null;
      return div;
    }));
  };
  const tickedLabels = () => [...estBox.querySelectorAll('.estimator')].filter((d) => d.querySelector('[data-estimator]').checked).map((d) => d.dataset.label);

  // Limits: estimator, metric (with its unit), min, max, marginal band.
  const metrics = S.metrics;
  const unitOf = (name) => {
    const m = metrics.find((x) => x.name === name);
    return m ? m.unit : /^harmonic_\d+x_rad$/.test(name) ? 'rad' : '';
  };
  const limitBody = h('tbody');
  const limitTable = h('table', { id: 'limits', class: 'cards' }, h('thead', {}, h('tr', {}, ['estimator', 'metric', 'min', 'max', 'marginal band [% of limit]', ''].map((c) => h('th', {}, c)))), limitBody);
  const addLimit = (l = {}) => {
    const est = h('select', { class: 'l-est' });
    est.dataset.want = l.estimator || '*';
    const met = h('select', { class: 'l-metric' }, metrics.map((m) => h('option', { value: m.name, title: m.description }, m.unit ? `${m.name} [${m.unit}]` : m.name)));
    met.value = l.metric || 'rms_rad';
    const num = (cls, v, ph) => {
      const i = h('input', { class: cls, type: 'number', step: 'any', placeholder: ph, size: 9 });
      i.dataset.type = 'number';
      if (v != null) i.value = nice(v);
      return i;
    };
    const min = num('l-min', l.min, 'none'), max = num('l-max', l.max, 'none');
    const band = num('l-band', l.marginal_fraction ? 100 * l.marginal_fraction : null, '0');
    const unit = () => unitOf(met.value);
    const units = [h('span', { class: 'unit' }), h('span', { class: 'unit' })];
    const showUnits = () => { for (const u of units) u.textContent = unit() ? ` ${unit()}` : ''; };
    met.addEventListener('change', () => { showUnits(); markNeedsTruth(); });
    showUnits();
    const row = h('tr', { class: 'limit' }, h('td', { class: 'c-est' }, est), h('td', { class: 'c-metric' }, met), h('td', { class: 'c-min', 'data-label': 'min' }, min, units[0]),
      h('td', { class: 'c-max', 'data-label': 'max' }, max, units[1]), h('td', { class: 'c-band', 'data-label': 'marginal %' }, band),
      h('td', { class: 'c-del' }, h('button', { type: 'button', class: 'l-del', title: 'remove this limit', onclick: () => { row.remove(); schedule(); } }, '✕')));
    limitBody.append(row);
    refreshLimits();
    return row;
  };
  // Each limit's estimator choices follow the ticked estimators; a limit on an estimator that
  // is not in the run is kept in the editor but left out of the run (and says so).
  function refreshLimits() {
    const labels = tickedLabels();
    for (const row of limitBody.querySelectorAll('tr.limit')) {
      const sel = row.querySelector('.l-est');
      const want = sel.dataset.want;
      const opts = ['*', ...labels];
      if (!opts.includes(want)) opts.push(want);
      sel.replaceChildren(...opts.map((o) => h('option', { value: o }, o === '*' ? '* (every estimator)' : o)));
      sel.value = want;
      sel.onchange = () => { sel.dataset.want = sel.value; refreshLimits(); };
      const out = want !== '*' && !labels.includes(want);
      row.classList.toggle('inactive', out);
    }
    markNeedsTruth();  // sets each row's title
  }
  // A capture without truth: a limit on a figure that needs truth (an estimator's metric other
  // than the self-referenced ones, as the service grades them) cannot pass. Such limits are marked
  // and a note names what measures the error without truth.
  let captureTruth = null;  // the capture uploaded here: has it truth? null: none uploaded (or the path typed since)
  const truthNote = h('p', { class: 'warn-note', id: 'truth-note', hidden: true });
  const needsTruth = (metric) => {
    const m = metrics.find((x) => x.name === metric);
    return m ? m.scope === 'estimator' && !metric.startsWith('self_ref_') : /^harmonic_\d+x_rad$/.test(metric);
  };
  function markNeedsTruth() {
    const noTruth = captureTruth === false && driverSel.value === 'capture';
    const named = [];
    for (const row of limitBody.querySelectorAll('tr.limit')) {
      const metric = row.querySelector('.l-metric').value;
      const out = row.classList.contains('inactive');
      const mark = noTruth && !out && needsTruth(metric);
      row.classList.toggle('needs-truth', mark);
      if (mark) named.push(metric);
      row.title = out ? `${row.querySelector('.l-est').dataset.want} is not ticked: this limit is left out of the run`
        : mark ? `${metric} needs truth (theta_true), which this capture has not: this limit will FAIL as not measured` : '';
    }
    truthNote.hidden = !named.length;
    truthNote.textContent = named.length ? `This capture has no truth (theta_true): ${named.length === 1 ? '1 limit names a figure' : `${named.length} limits name figures`} that need it `
      + `(${[...new Set(named)].join(', ')}) and will FAIL as not measured. Without truth the error is measured by self_ref_rms_rad and self_ref_harmonic_1x_rad .. 4x_rad (self-referenced).` : '';
  }

  // ---- the scenario the form describes; each value's input gets the field the API names --
  const build = () => {
    const sc = structuredClone(base || {});
    const name = nameIn.value.trim(), text = descIn.value.trim();
    if (name) sc.name = name; else delete sc.name;
    if (text) sc.description = text; else delete sc.description;
    // encoder
    if (encSel.value) sc.encoder = `../encoders/${encSel.value}.json`;
    else {
      const b = base && base.encoder && typeof base.encoder === 'object' ? base.encoder : {};
      const model = readInput(encGrid.querySelector('[data-param="model"]'));
      // Keys of the other model (optics, front-end reference) do not carry over.
      const enc = model === b.model ? structuredClone(b) : {};
      for (const el of encGrid.querySelectorAll('[data-param]')) setDeep(enc, el.dataset.param, readInput(el));
      for (const k of ['noise', 'lissajous', 'adc']) if (enc[k] && !Object.keys(enc[k]).length) delete enc[k];
      sc.encoder = enc;
    }
    sc.motion = readMotion();
    for (const el of sampGrid.querySelectorAll('[data-param]')) {
      const v = readInput(el);
      if (v === undefined) delete sc[el.dataset.param]; else sc[el.dataset.param] = v;
    }
    sc.device = deviceUri();
    const iface = readInterface();
    if (iface === undefined) delete sc.interface; else sc.interface = iface;
    sc.estimators = [];
    for (const div of estBox.querySelectorAll('.estimator')) {
      if (!div.querySelector('[data-estimator]').checked) continue;
      const i = sc.estimators.length;
      const spec = { ...(div.spec || {}), name: div.dataset.name, params: readParams(div.querySelector('.params')) };
      if (!spec.label) spec.label = div.dataset.name;
      div.querySelector('[data-estimator]').dataset.field = `scenario.estimators[${i}].name`;
      for (const el of div.querySelectorAll('.params [data-param]')) el.dataset.field = `scenario.estimators[${i}].params.${el.dataset.param}`;
      sc.estimators.push(spec);
    }
    sc.limits = [];
    for (const row of limitBody.querySelectorAll('tr.limit')) {
      for (const el of row.querySelectorAll('[data-field]')) delete el.dataset.field;
      if (row.classList.contains('inactive')) continue;
      const i = sc.limits.length;
      const l = { estimator: row.querySelector('.l-est').value, metric: row.querySelector('.l-metric').value };
      const f = `scenario.limits[${i}]`;
      row.querySelector('.l-est').dataset.field = `${f}.estimator`;
      row.querySelector('.l-metric').dataset.field = `${f}.metric`;
      for (const [cls, key, scale] of [['.l-min', 'min', 1], ['.l-max', 'max', 1], ['.l-band', 'marginal_fraction', 0.01]]) {
        const el = row.querySelector(cls);
        el.dataset.field = `${f}.${key}`;
        const v = readInput(el);
        if (v !== undefined) l[key] = typeof v === 'number' ? v * scale : v;
      }
      sc.limits.push(l);
    }
    return sc;
  };

  // ---- errors and warnings at their fields -----------------------------------------
  const formError = h('div', { id: 'form-error' });
  const preflightBox = h('div', { id: 'preflight', 'aria-live': 'polite' });
  const clearMarks = () => {
    for (const el of view.querySelectorAll('.field-error, .field-warning')) el.remove();
    for (const el of view.querySelectorAll('[aria-invalid]')) el.removeAttribute('aria-invalid');
    formError.replaceChildren();
  };
  // The input the API's field names, or the nearest one above it (scenario.encoder.x.y ->
  // scenario.encoder.x -> scenario.encoder).
  const inputFor = (field) => {
    if (!field) return null;
    let f = field.startsWith('scenario.') || field === 'scenario' ? field : `scenario.${field}`;
    while (f) {
      const el = view.querySelector(`[data-field="${CSS.escape(f)}"]`);
      if (el && !el.closest('[hidden]')) return el;
      const cut = Math.max(f.lastIndexOf('.'), f.lastIndexOf('['));
      if (cut <= 0) break;
      f = f.slice(0, cut);
    }
    return null;
  };
  const mark = (field, text, kind) => {
    const el = inputFor(field);
    if (!el) return null;
    const note = h('span', { class: kind === 'error' ? 'field-error' : 'field-warning', role: kind === 'error' ? 'alert' : null, 'data-for': field }, text);
    if (kind === 'error') el.setAttribute('aria-invalid', 'true');
    const host = el.closest('label.field') || el.closest('td') || el.parentElement;
    host.append(note);
    return note;
  };
  const showApiError = (e) => {
    clearMarks();
    const at = e.field ? mark(e.field, errorText(e), 'error') : null;
    if (at) {
      formError.replaceChildren(h('p', { class: 'error' }, `Not started: ${e.field.replace(/^scenario\./, '')} needs fixing (marked below its field).`));
      const input = at.parentElement.querySelector('input, select');
      if (input) input.focus({ preventScroll: true });
      at.scrollIntoView({ block: 'center' });
    } else {
      formError.replaceChildren(h('p', { class: 'error', role: 'alert' }, e.field ? `${e.field}: ${errorText(e)}` : errorText(e)));
    }
  };
  const showPreflight = (r) => {
    const w = r.warnings || [];
    preflightBox.replaceChildren(
      h('p', { class: w.length ? 'warn' : 'ok' }, w.length ? `Preflight: ${w.length} warning${w.length > 1 ? 's' : ''} — the run can start, but read ${w.length > 1 ? 'them' : 'it'} first.`
        : 'Preflight: no warnings.', ` ${r.samples} samples`, r.samples_per_cycle != null ? `, ${sig(r.samples_per_cycle)} samples per electrical cycle at the peak speed.` : '.'),
      w.length ? h('ul', { class: 'warnings' }, w.map((x) => h('li', { 'data-code': x.code }, h('code', {}, x.code), ' ', x.message))) : '');
    for (const x of w) mark(x.field, x.message, 'warning');
  };

  // Preflight after each change (when the token is there), and always before Start.
  let checked = null;  // {key, result}: the scenario last checked and what the service said
  let timer = null;
  const runPreflight = async () => {
    const sc = build();
    const key = JSON.stringify(sc);
    if (checked && checked.key === key && !checked.error) return checked;  // an error is asked again (the token may be fixed since)
    try {
      const r = await api.post('preflight', { scenario: sc });
      clearMarks();
      showPreflight(r);
      checked = { key, result: r };
    } catch (e) {
      preflightBox.replaceChildren();
      showApiError(e);
      checked = { key, error: e };
    }
    return checked;
  };
  function schedule() {
    clearTimeout(timer);
    startBtn.textContent = 'Start run';
    if (!api.token()) return;
    timer = setTimeout(runPreflight, 400);
  }
  cleanup.push(() => clearTimeout(timer));

  const needToken = () => {
    clearMarks();
    formError.replaceChildren(h('p', { class: 'error', role: 'alert', id: 'need-token' }, errorText({ code: 'no_token' })));
    const t = document.getElementById('token');
    if (t) t.focus();
  };
  const startBtn = h('button', { type: 'submit', class: 'primary', id: 'start' }, 'Start run');
  let confirmed = null;  // the scenario whose warnings the user has seen and starts anyway
  const submit = async (ev) => {
    ev.preventDefault();
    clearTimeout(timer);
    if (!api.token()) { needToken(); return; }
    startBtn.disabled = true;
    try {
      const c = await runPreflight();
      if (c.error) return;
      if (c.result.warnings.length && confirmed !== c.key) {
        confirmed = c.key;
        startBtn.textContent = 'Start anyway';
        preflightBox.scrollIntoView({ block: 'center' });
        return;
      }
      const r = await api.post('runs', { scenario: JSON.parse(c.key) });
      location.hash = `#/run/${r.id}`;
    } catch (e) {
      showApiError(e);
    } finally {
      startBtn.disabled = false;
    }
  };

  const save = () => {
    const sc = build();
    const blob = new Blob([JSON.stringify(sc, null, 2) + '\n'], { type: 'application/json' });
    const a = h('a', { href: URL.createObjectURL(blob), download: `${(sc.name || 'scenario').replace(/[^A-Za-z0-9_.-]+/g, '-')}.json` });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  };

  // Loading a fixture overwrites the fields: while it loads they are disabled (what a user types
  // there meanwhile would be lost) and the form is aria-busy; a slower earlier load never
  // overwrites a later one.
  let loadSeq = 0;
  const setBusy = (busy) => {
    form.setAttribute('aria-busy', busy ? 'true' : 'false');
    for (const fs of form.querySelectorAll('fieldset')) if (!fs.contains(fixtureSel)) fs.disabled = busy;
    startBtn.disabled = busy;
  };
  const loadFixture = async () => {
    const seq = ++loadSeq;
    formError.replaceChildren();
    setBusy(true);
    let fetched;
    try {
      fetched = fixtureSel.value === '' ? structuredClone(BLANK) : (await api.get(`fixtures/${encodeURIComponent(fixtureSel.value)}`)).scenario;
    } catch (e) {
      if (seq === loadSeq) { setBusy(false); showApiError(e); }
      return;
    }
    if (seq !== loadSeq) return;
    base = fetched;
    setBusy(false);
    const from = fixtureSel.value;
    fixtureText.textContent = from ? `Started from the fixture ${from}${base.description ? `: ${base.description}` : ''}` : 'Blank: every field empty (a grey value is the default the service uses).';
    keepBtn.hidden = !from;
    nameIn.value = '';
    descIn.value = '';
    nameIn.placeholder = from ? `unnamed (the fixture is ${base.name || from})` : 'unnamed';
    fillEncoder(base.encoder);
    fillMotion(base.motion);
    fillSampling(base);
    fillDevice(base.device || 'loopback:');
    fillInterface(base.interface);
    fillEstimators(base.estimators || []);
    limitBody.replaceChildren();
    for (const l of base.limits || []) addLimit(l);
    checked = null;
    schedule();
  };
  fixtureSel.addEventListener('change', loadFixture);

  const legend = (t, hint) => h('legend', {}, t, hint ? h('span', { class: 'muted' }, ` ${hint}`) : '');
  const form = h('form', { id: 'new-run', novalidate: true, onsubmit: submit, oninput: schedule, onchange: schedule },
    h('fieldset', {}, legend('Scenario'), h('div', { class: 'row' }, h('label', { class: 'field' }, 'start from', fixtureSel),
      h('label', { class: 'field' }, h('span', { class: 'fname' }, 'name'), nameIn),
      h('label', { class: 'field' }, h('span', { class: 'fname' }, 'description'), descIn)), desc),
    h('fieldset', {}, legend('Encoder'), h('div', { class: 'row' }, h('label', { class: 'field' }, 'profile', encSel)), encGrid),
    h('fieldset', {}, legend('Motion'), h('div', { class: 'row' }, h('label', { class: 'field' }, 'kind', kindSel), h('label', { class: 'field' }, 'speed unit', speedUnit)), motionGrid),
    h('fieldset', {}, legend('Sampling'), sampGrid),
    h('fieldset', {}, legend('Device'), h('div', { class: 'row' }, h('label', { class: 'field' }, 'driver', driverSel),
      h('label', { class: 'field' }, 'path', devPath), captureIds), drop, devParams),
    h('fieldset', {}, legend('Signal quality', 'the interface profile the signals are graded against'),
      h('div', { class: 'row' }, h('label', { class: 'field' }, h('span', { class: 'fname' }, 'interface profile'), ifaceSel), ifaceNote)),
    h('fieldset', {}, legend('Estimators under test', 'tick one to see its parameters'), estBox),
    h('fieldset', {}, legend('Limits', 'the verdict: FAIL beyond min/max, MARGINAL within the band on the passing side'),
      h('div', { class: 'table-wrap' }, limitTable), truthNote, h('button', { type: 'button', id: 'add-limit', onclick: () => { addLimit({ estimator: tickedLabels()[0] || '*' }); schedule(); } }, 'add limit')),
    preflightBox,
    h('div', { class: 'row actions' }, startBtn,
      h('button', { type: 'button', id: 'check', onclick: async () => { if (!api.token()) { needToken(); return; } checked = null; await runPreflight(); } }, 'Check'),
      h('button', { type: 'button', id: 'save', onclick: save, title: 'download the scenario as a JSON file (fringe run FILE runs it)' }, 'Save JSON')),
    formError);
  view.replaceChildren(h('h1', {}, 'New run'), form);
  // The paper's example is shown first (a runnable start); "blank" is the first choice.
  const pref = cat.fixtures.find((f) => f.name === 'fig10c-loopback');
  if (pref) fixtureSel.value = pref.name;
  await loadFixture();
}
