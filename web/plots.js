// Report plots with uPlot (vendored from npm into /vendor by scripts/setup).
// Issue 11: traces are per-bucket min/max envelopes and per-angle folds computed at the full
// rate ("kind":"envelope"); no plot joins samples that are not neighbours, and the error spectrum
// comes from the report (the scorer's full-rate Welch estimate), never from the traces.
// Each plot's container records what it drew in `div.fringe` (data coordinates), for the tests.
import uPlot from './vendor/uPlot.esm.js';
import { sig } from './format.js';

const COLORS = ['#0969da', '#cf222e', '#1a7f37', '#9a6700', '#8250df', '#bc4c00', '#57606a'];
export const color = (i) => COLORS[i % COLORS.length];

function box(parent, title, id) {
  const div = document.createElement('div');
  div.className = 'plot';
  if (id) div.id = id;
  const h = document.createElement('h3');
  h.textContent = title;
  div.append(h);
  parent.append(div);
  div.fringe = {};
  return div;
}

function note(div, text) {
  const p = document.createElement('p');
  p.className = 'muted plot-note';
  p.textContent = text;
  div.append(p);
  return p;
}

// Two plots a row on a wide screen, one on a narrow one (a phone: the plot fits the screen).
function width(parent) {
  const w = parent.clientWidth || 1100;
  return Math.round(Math.max(260, Math.min(620, w >= 1150 ? w / 2 - 40 : w - 24)));
}
export const plotWidth = width;

// A checkbox in the plot's tool row that redraws it.
function toggle(div, text, checked, onchange, cls) {
  let tools = div.querySelector('.plot-tools');
  if (!tools) {
    tools = document.createElement('div');
    tools.className = 'plot-tools';
    div.querySelector('h3').after(tools);
  }
  const box = document.createElement('input');
  box.type = 'checkbox';
  box.checked = checked;
  box.className = cls;
  box.addEventListener('change', () => onchange(box.checked));
  const label = document.createElement('label');
  label.append(box, ` ${text}`);
  tools.append(label);
  return box;
}

// Legend values: the hovered value with 3 significant digits and its unit; with nothing
// hovered, what the series amounts to (its peak, lowest or typical value), never "--".
function stat(arr, how) {
  let n = 0, acc = how === 'max' || how === 'absmax' ? -Infinity : how === 'min' ? Infinity : 0;
  for (const v of arr || []) {
    if (v == null || !Number.isFinite(v)) continue;
    n++;
    if (how === 'max') acc = Math.max(acc, v);
    else if (how === 'absmax') acc = Math.max(acc, Math.abs(v));
    else if (how === 'min') acc = Math.min(acc, v);
    else acc += v * v;
  }
  if (!n) return null;
  return how === 'rms' ? Math.sqrt(acc / n) : acc;
}
const WORD = { max: 'highest', min: 'lowest', absmax: 'peak', rms: 'rms' };
function legendValue(unit, arr, how) {
  const summary = how ? stat(arr, how) : null;
  const u = unit ? ` ${unit}` : '';
  const idle = summary == null ? '' : `${WORD[how]} ${sig(summary)}${u}`;
  return (self, v, si, di) => (di == null ? idle : v == null ? '' : `${sig(v)}${u}`);
}
const xValue = (unit, lo, hi) => (self, v, si, di) => (di == null ? `${sig(lo)} … ${sig(hi)} ${unit}` : v == null ? '' : `${sig(v)} ${unit}`);
const firstLast = (a) => {
  const f = (a || []).filter((v) => v != null);
  return [f.length ? f[0] : 0, f.length ? f[f.length - 1] : 0];
};
const absMax = (lo, hi) => lo.map((v, i) => {
  const a = v == null ? null : Math.abs(v), b = hi[i] == null ? null : Math.abs(hi[i]);
  const m = a == null ? b : b == null ? a : Math.max(a, b);
  return m > 0 ? m : null;  // log axis: a zero has no place
});
const logTicks = (u, vals) => vals.map((v) => (v == null ? '' : sig(v, 2)));

const expTicks = (u, vals) => vals.map((v) => (v == null ? '' : v.toExponential(0)));
// Error axes span 1e-6..1e-1 rad: exponents below 1e-2, else three significant digits.
const errTicks = (u, vals) => vals.map((v) => (v == null ? '' : sig(v)));
function range(arrays, pad = 0.05) {
  let lo = Infinity, hi = -Infinity;
  for (const a of arrays) for (const v of a || []) if (v != null && Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!Number.isFinite(lo)) return [-1, 1];
  const d = (hi - lo) * pad || Math.abs(hi) * pad || 1;
  return [lo - d, hi + d];
}
const noPath = () => null;

// xy mode (uPlot mode 2): samples as small squares, never joined.
function dots(u, seriesIdx) {
  const [xs, ys] = u.data[seriesIdx];
  const p = new Path2D();
  const r = 1.5 * (devicePixelRatio || 1);
  for (let i = 0; i < xs.length; i++) {
    if (xs[i] == null || ys[i] == null) continue;
    p.rect(u.valToPos(xs[i], 'x', true) - r / 2, u.valToPos(ys[i], 'y', true) - r / 2, r, r);
  }
  return { stroke: null, fill: p, clip: null, band: null, gaps: null, flags: 0 };
}

// xy mode: a line through consecutive entries, broken at nulls; `closed` joins the last entry to
// the first when nothing is missing (one folded electrical cycle). The segments drawn are kept in
// record.segments, in data coordinates.
function polyline(record, closed = false) {
  return (u, seriesIdx) => {
    const [xs, ys] = u.data[seriesIdx];
    const p = new Path2D();
    const segs = [];
    let prev = null;
    const n = xs.length;
    const full = closed && n > 2 && xs.every((v, i) => v != null && ys[i] != null);
    for (let i = 0; i < n + (full ? 1 : 0); i++) {
      const k = i % n;
      if (xs[k] == null || ys[k] == null) { prev = null; continue; }
      const x = u.valToPos(xs[k], 'x', true), y = u.valToPos(ys[k], 'y', true);
      if (prev) { p.lineTo(x, y); segs.push([prev[0], prev[1], xs[k], ys[k]]); } else p.moveTo(x, y);
      prev = [xs[k], ys[k]];
    }
    if (record) record.segments = (record.segments || []).concat(segs);
    return { stroke: p, fill: null, clip: null, band: null, gaps: null, flags: 0 };
  };
}

const isEnvelope = (t) => t && t.kind === 'envelope';

// Lissajous, cos on x and sin on y in volts: the recorded samples as points, and (envelope
// traces) the mean over one folded electrical cycle as a closed line.
export function lissajous(parent, t) {
  const env = isEnvelope(t);
  const div = box(parent, env ? 'Lissajous: samples (points), one folded electrical cycle (line)' : 'Lissajous: stride samples (points)', 'plot-lissajous');
  const pts = env ? t.lissajous.points : { cos_v: t.cos_v || [], sin_v: t.sin_v || [] };
  const cyc = env ? t.lissajous.cycle : { cos_v: [], sin_v: [] };
  const a = Math.max(...range([pts.cos_v, cyc.cos_v, pts.sin_v, cyc.sin_v], 0.05).map(Math.abs));
  // Drawn 1:1: a volt is as long across as up, so a circle stays a circle and an amplitude
  // mismatch shows as the ellipse it is. Both axes take the same room (axis size plus label)
  // and the same padding, so a square chart has a square plot area.
  const w = Math.min(width(parent), 480);
  const record = { segments: [] };
  div.fringe = { kind: 'lissajous', envelope: env, record, points: pts.cos_v.length, cycle: cyc.cos_v.length, axes: ['cos (V)', 'sin (V)'], range_v: [-a, a] };
  // The folded cycle first, the samples over it (their spread around the mean stays visible).
  const series = [{}];
  const data = [null];
  if (env) {
    series.push({ label: 'folded cycle', stroke: color(0), width: 2, paths: polyline(record, true), points: { show: false } });
    data.push([cyc.cos_v, cyc.sin_v]);
  }
  series.push({ label: 'samples', stroke: '#57606a', fill: '#57606a99', paths: dots, points: { show: false } });
  data.push([pts.cos_v, pts.sin_v]);
  const u = new uPlot({
    mode: 2, width: w, height: w,
    padding: [12, 12, 0, 0],
    // xy mode takes an x range from the first and last sample only: give both ranges (square).
    scales: { x: { time: false, auto: false, range: [-a, a] }, y: { auto: false, range: [-a, a] } },
    axes: [{ label: 'cos (V)', size: 50, labelSize: 28 }, { label: 'sin (V)', size: 50, labelSize: 28 }],
    legend: { show: false },
    series,
  }, data, div);
  div.fringe.u = u;
  return div;
}

// Error against the true electrical angle: mean per angle bin (line) and min..max (band), at the
// full rate; x in electrical radians [0, 2 pi). Old reports: the stride samples as points.
// Log option: |error| (the larger of |min| and |max| per bin, and |mean|) on a log axis, where
// small errors beside large ones stay visible.
export function errorVsAngle(parent, t, labels, opts = {}) {
  const div = box(parent, 'Error vs electrical angle', 'plot-by-angle');
  const limits = opts.limits || [];
  div.fringe = { kind: 'by_angle', log: false, axes: ['electrical angle (rad)', 'error (rad)'] };
  const holder = document.createElement('div');
  div.append(holder);
  let u = null;
  const draw = (log) => {
    if (u) u.destroy();
    div.fringe.log = log;
    div.fringe.axes = ['electrical angle (rad)', log ? '|error| (rad), log' : 'error (rad)'];
    const axes = [{ label: div.fringe.axes[0], values: errTicks }, { label: div.fringe.axes[1], size: 70, values: log ? logTicks : errTicks }];
    const yscale = { ...(log ? { distr: 3 } : {}), range: errRange(limits, log, null) };
    const dec = decorate(div, { limits }, log);
    const hooks = { draw: dec.draw };
    if (!isEnvelope(t)) {
      const th = (t.theta_true_wrapped_rad || []).map((v) => (v == null ? null : ((v % (2 * Math.PI)) + 2 * Math.PI) % (2 * Math.PI)));
      const idx = th.map((_, i) => i).filter((i) => th[i] != null).sort((a, b) => th[a] - th[b]);
      const ys = labels.map((l) => idx.map((i) => t.error_rad[l][i])).map((y) => (log ? y.map((v) => (v ? Math.abs(v) : null)) : y));
      const xs = idx.map((i) => th[i]);
      u = new uPlot({
        width: width(parent), height: 300, scales: { x: { time: false }, y: yscale }, axes, hooks,
        series: [{ label: 'angle', value: xValue('rad', 0, 2 * Math.PI) },
          ...labels.map((l, i) => ({ label: l, stroke: color(i), paths: noPath, points: { show: true, size: 3, fill: color(i) }, value: legendValue('rad', ys[i], 'absmax') }))],
      }, [xs, ...ys], holder);
    } else {
      const ba = t.by_angle;
      const data = [ba.theta_rad];
      const series = [{ label: 'angle', value: xValue('rad', 0, 2 * Math.PI) }];
      const bands = [];
      labels.forEach((l, i) => {
        const f = ba.error_rad[l];
        if (!f) return;
        const base = series.length;
        if (log) {
          const peak = absMax(f.min, f.max), mean = f.mean.map((v) => (v ? Math.abs(v) : null));
          data.push(peak, mean);
          series.push({ label: `${l} max |e|`, stroke: color(i) + '99', width: 1, value: legendValue('rad', peak, 'max') },
            { label: `${l} |mean|`, stroke: color(i), width: 1.5, value: legendValue('rad', mean, 'max') });
          return;
        }
        data.push(f.max, f.min, f.mean);
        series.push({ label: `${l} max`, stroke: color(i) + '66', width: 1, value: legendValue('rad', f.max, 'max') },
          { label: `${l} min`, stroke: color(i) + '66', width: 1, value: legendValue('rad', f.min, 'min') },
          { label: `${l} mean`, stroke: color(i), width: 1.5, value: legendValue('rad', f.mean, 'rms') });
        bands.push({ series: [base, base + 1], fill: color(i) + '22' });
      });
      u = new uPlot({ width: width(parent), height: 300, scales: { x: { time: false, auto: false, range: [0, 2 * Math.PI] }, y: yscale }, axes, series, bands, hooks }, data, holder);
    }
    div.fringe.u = u;
  };
  toggle(div, 'log |error|', false, draw, 'log-toggle');
  draw(false);
  limitNote(div, null, limits);
  return div;
}

// Each lane's self-referenced error against the electrical angle (docs/self-reference.md): the
// periodic part its harmonics give, e(s) = sum A_k cos(k s - phase_k), about the unobservable
// mean. The sub-divisional error a capture without truth still shows.
export function selfRefVsAngle(parent, estimators) {
  const lanes = (estimators || []).filter((e) => e.analysers && e.analysers.self_reference && e.analysers.self_reference.measured
    && Array.isArray(e.analysers.self_reference.harmonics));
  if (!lanes.length) return null;
  const div = box(parent, 'Self-referenced error vs electrical angle (harmonics 1-8)', 'plot-self-reference');
  const N = 256, xs = Array.from({ length: N + 1 }, (_, i) => (2 * Math.PI * i) / N);
  const ys = lanes.map((e) => xs.map((s) => e.analysers.self_reference.harmonics.reduce((acc, hk) =>
    acc + (Number.isFinite(hk.amplitude_rad) && Number.isFinite(hk.phase_rad) ? hk.amplitude_rad * Math.cos(hk.order * s - hk.phase_rad) : 0), 0)));
  div.fringe = { kind: 'self_reference', lanes: lanes.map((e) => e.label), x: xs, y: ys };
  const holder = document.createElement('div');
  div.append(holder);
  div.fringe.u = new uPlot({
    width: width(parent), height: 300, scales: { x: { time: false, auto: false, range: [0, 2 * Math.PI] }, y: { range: range(ys) } },
    axes: [{ label: 'electrical angle of the self-reference (rad)' }, { label: 'error, periodic part (rad)', size: 70, values: errTicks }],
    series: [{ label: 'angle', value: xValue('rad', 0, 2 * Math.PI) },
      ...lanes.map((e, i) => ({ label: e.label, stroke: color(estimators.indexOf(e)), width: 1.5, value: legendValue('rad', ys[i], 'absmax') }))],
  }, [xs, ...ys], holder);
  note(div, 'from each estimator\'s self-referenced harmonics 1x-8x (the curve the truth-scored error vs angle would show, less its mean, which cannot be seen without truth)');
  return div;
}

// Limits that bound every sample of the plotted error, as horizontal lines: max_abs_rad (|e| <= max,
// lines at +-max) and max_dev_rad (|e - mean| <= max, lines at mean +- max). Limits on rms, mean
// or counts bound no single sample and are not drawn. measurements: the report's rows.
export function errorLimitLines(measurements, estimators, labels) {
  const out = [];
  const meanOf = (l) => {
    const e = (estimators || []).find((x) => x.label === l);
    const m = e && e.metrics && e.metrics.mean;
    return m && typeof m.rad === 'number' ? m.rad : null;
  };
  for (const m of measurements || []) {
    if (!m.limit || m.limit.max == null || !labels.includes(m.estimator)) continue;
    if (m.metric === 'max_abs_rad') out.push({ label: m.estimator, metric: m.metric, ys: [m.limit.max, -m.limit.max], abs: m.limit.max,
      text: `${m.estimator} max_abs_rad ≤ ${sig(m.limit.max)} rad` });
    else if (m.metric === 'max_dev_rad') {
      const mu = meanOf(m.estimator);
      if (mu == null) continue;
      out.push({ label: m.estimator, metric: m.metric, ys: [mu + m.limit.max, mu - m.limit.max], abs: Math.abs(mu) + m.limit.max,
        text: `${m.estimator} max_dev_rad ≤ ${sig(m.limit.max)} rad about its mean ${sig(mu)} rad` });
    }
  }
  return out;
}

export const LIMIT_COLOR = '#d1242f';
const SETTLE_FILL = 'rgba(140,149,159,0.25)';

// The settle period (not scored) as a grey band under the series, and the limit lines over them,
// with their words in the plot and in a note below it.
function decorate(div, { settle, limits }, log) {
  const drawClear = [], draw = [];
  div.fringe.settle = settle || null;
  div.fringe.limits = (limits || []).map((l) => ({ text: l.text, ys: log ? [l.abs] : l.ys }));
  if (settle) drawClear.push((uu) => {
    const ctx = uu.ctx, dpr = devicePixelRatio || 1;
    const x0 = Math.max(uu.valToPos(settle[0], 'x', true), uu.bbox.left), x1 = Math.min(uu.valToPos(settle[1], 'x', true), uu.bbox.left + uu.bbox.width);
    if (!(x1 > x0)) return;
    ctx.save();
    ctx.fillStyle = SETTLE_FILL;
    ctx.fillRect(x0, uu.bbox.top, x1 - x0, uu.bbox.height);
    ctx.fillStyle = '#57606a';
    ctx.font = `${10 * dpr}px sans-serif`;
    ctx.textAlign = 'left';
    ctx.fillText('settle: not scored', x0 + 3 * dpr, uu.bbox.top + 11 * dpr);
    ctx.restore();
    div.fringe.settle_px = [x0 / dpr, x1 / dpr];
  });
  if (limits && limits.length) draw.push((uu) => {
    const ctx = uu.ctx, dpr = devicePixelRatio || 1;
    ctx.save();
    ctx.strokeStyle = LIMIT_COLOR;
    ctx.fillStyle = LIMIT_COLOR;
    ctx.lineWidth = 1.5 * dpr;
    ctx.setLineDash([6 * dpr, 4 * dpr]);
    ctx.font = `${10 * dpr}px sans-serif`;
    ctx.textAlign = 'right';
    const drawn = [];
    for (const l of limits)
      for (const y of log ? [l.abs] : l.ys) {
        if (!(y >= uu.scales.y.min && y <= uu.scales.y.max)) continue;
        const py = uu.valToPos(y, 'y', true);
        const p = new Path2D();
        p.moveTo(uu.bbox.left, py);
        p.lineTo(uu.bbox.left + uu.bbox.width, py);
        ctx.stroke(p);
        ctx.fillText(`limit ${y < 0 ? '-' : ''}${sig(Math.abs(y))}`, uu.bbox.left + uu.bbox.width - 3 * dpr, py - 3 * dpr);
        drawn.push(y);
      }
    ctx.restore();
    div.fringe.limits_drawn = drawn;
  });
  return { drawClear, draw };
}

// The y range of an error plot that keeps the limit lines in view when they are near the data
// (within 3x of its largest |error|); a limit far above stays off scale and the note says so.
function errRange(limits, log, fixed) {
  if (fixed) return () => fixed;
  return (u, lo, hi) => {
    if (lo == null || hi == null || !Number.isFinite(lo) || !Number.isFinite(hi)) { lo = log ? 1e-6 : -1; hi = log ? 1e-3 : 1; }
    const peak = Math.max(Math.abs(lo), Math.abs(hi));
    for (const l of limits || [])
      for (const y of log ? [l.abs] : l.ys) if (log || Math.abs(y) <= 3 * peak) { lo = Math.min(lo, y); hi = Math.max(hi, y); }
    if (log) return [10 ** Math.floor(Math.log10(lo)), 10 ** Math.ceil(Math.log10(hi))];
    const d = (hi - lo) * 0.05 || Math.abs(hi) * 0.05 || 1e-9;
    return [lo - d, hi + d];
  };
}

function limitNote(div, settle, limits) {
  const parts = [];
  if (settle) parts.push(`grey: the settle time (${sig(settle[1] - settle[0])} s from ${sig(settle[0])} s), not scored`);
  for (const l of limits || []) parts.push(`dashed red: limit ${l.text}`);
  if (parts.length) note(div, `${parts.join('; ')}.`).classList.add('plot-key');
}

// Error against time: for envelope traces the min..max of every bucket at the full rate (a band
// per estimator: a fast error fills its band instead of beating). Old reports: points only.
// Log option: the larger of |min| and |max| per bucket on a log axis.
// opts: settle [from_s, to_s] (shaded, not scored), limits (errorLimitLines), xRange/yRange
// (fixed axes shared with another plot: compare).
export function errorVsTime(parent, t, labels, title = 'Error vs time', id = 'plot-time', opts = {}) {
  const div = box(parent, title, id);
  div.fringe = { kind: 'time', envelope: isEnvelope(t), log: false, axes: ['time (s)', 'error (rad)'] };
  const holder = document.createElement('div');
  div.append(holder);
  // The x range uPlot settles on (after its deferred first layout): each plot's own time base.
  const setScale = [(uu, key) => {
    if (key === 'y') { div.fringe.ymin = uu.scales.y.min; div.fringe.ymax = uu.scales.y.max; return; }
    if (key !== 'x') return;
    div.fringe.xmin = uu.scales.x.min; div.fringe.xmax = uu.scales.x.max;
    div.dataset.xmin = uu.scales.x.min; div.dataset.xmax = uu.scales.x.max;
  }];
  const [t0, t1] = firstLast(t.t_s);
  div.fringe.data_t = [t0, t1];
  const limits = opts.limits || [];
  let u = null;
  const draw = (log) => {
    if (u) u.destroy();
    div.fringe.log = log;
    div.fringe.axes = ['time (s)', log ? '|error| (rad), log' : 'error (rad)'];
    const axes = [{ label: div.fringe.axes[0], values: errTicks }, { label: div.fringe.axes[1], size: 70, values: log ? logTicks : errTicks }];
    const dec = decorate(div, opts, log);
    const hooks = { setScale, drawClear: dec.drawClear, draw: dec.draw };
    const yscale = { ...(log ? { distr: 3 } : {}), range: errRange(limits, log, log ? (opts.yRangeLog || null) : (opts.yRange || null)) };
    const xscale = opts.xRange ? { time: false, auto: false, range: opts.xRange } : { time: false };
    const xs = { label: 'time', value: xValue('s', t0, t1) };
    if (!isEnvelope(t)) {
      const ys = labels.map((l) => (log ? t.error_rad[l].map((v) => (v ? Math.abs(v) : null)) : t.error_rad[l]));
      u = new uPlot({
        width: width(parent), height: 300, scales: { x: xscale, y: yscale }, axes, hooks,
        series: [xs, ...labels.map((l, i) => ({ label: l, stroke: color(i), paths: noPath, points: { show: true, size: 3, fill: color(i) }, value: legendValue('rad', ys[i], 'absmax') }))],
      }, [t.t_s, ...ys], holder);
    } else {
      const data = [t.t_s];
      const series = [xs];
      const bands = [];
      labels.forEach((l, i) => {
        const e = t.error_rad[l];
        if (!e) return;
        const base = series.length;
        const ci = opts.colorIndex ? opts.colorIndex(l, i) : i;
        if (log) {
          const peak = absMax(e.min, e.max);
          data.push(peak);
          series.push({ label: `${l} max |e|`, stroke: color(ci), width: 1, value: legendValue('rad', peak, 'max') });
          return;
        }
        data.push(e.max, e.min);
        series.push({ label: `${l} max`, stroke: color(ci), width: 1, value: legendValue('rad', e.max, 'max') },
          { label: `${l} min`, stroke: color(ci), width: 1, value: legendValue('rad', e.min, 'min') });
        bands.push({ series: [base, base + 1], fill: color(ci) + '55' });
      });
      u = new uPlot({ width: width(parent), height: 300, scales: { x: xscale, y: yscale }, axes, series, bands, hooks }, data, holder);
    }
    div.fringe.u = u;
  };
  toggle(div, 'log |error|', false, draw, 'log-toggle');
  draw(false);
  limitNote(div, opts.settle, limits);
  return div;
}

// Harmonics 1x..6x of the error per electrical cycle (docs/model.md, "Harmonics of the error"), grouped per estimator:
// each estimator's bar sits at its own x offset within the harmonic's slot. Log scale by
// default (harmonics span decades); linear on request.
export function harmonicBars(parent, estimators) {
  const div = box(parent, 'Error harmonics per electrical cycle', 'plot-harmonics');
  div.fringe = { kind: 'harmonics', log: true, axes: ['harmonic order (× electrical frequency)', 'amplitude (rad)'] };
  const holder = document.createElement('div');
  div.append(holder);
  // every fitted order (16 by default), at least 1x..6x
  let n = 6;
  for (const e of estimators) for (const v of e.harmonics || []) if (v && v.order > n) n = v.order;
  const k = Math.max(estimators.length, 1);
  const slot = 0.8 / k;
  const x = [];
  for (let hh = 1; hh <= n; hh++) for (let i = 0; i < k; i++) x.push(hh - 0.4 + (i + 0.5) * slot);
  const ys = estimators.map((e, i) => {
    const y = x.map(() => null);
    for (let hh = 1; hh <= n; hh++) {
      const v = (e.harmonics || [])[hh - 1];
      const amp = v == null ? null : typeof v === 'number' ? v : (v.amplitude && v.amplitude.rad);
      y[(hh - 1) * k + i] = amp > 0 ? amp : null;
    }
    return y;
  });
  let u = null;
  const draw = (log) => {
    if (u) u.destroy();
    div.fringe.log = log;
    const bars = uPlot.paths.bars({ size: [0.9, 80], align: 0 });
    const series = [{ label: 'order', value: (self, v, si, di) => (di == null ? `1x … ${n}x` : v == null ? '' : `${Math.round(v)}x`) }];
    estimators.forEach((e, i) => {
      // Idle legend: the largest harmonic and its order.
      let best = 0, at = 0;
      ys[i].forEach((v, j) => { if (v > best) { best = v; at = Math.floor(j / k) + 1; } });
      series.push({ label: e.label, stroke: color(i), fill: color(i) + 'cc', paths: bars, points: { show: false },
        value: (self, v, si, di) => (di == null ? (best ? `largest ${sig(best)} rad at ${at}x` : 'none') : v == null ? '' : `${sig(v)} rad`) });
    });
    u = new uPlot({
      width: width(parent), height: 300,
      scales: { x: { time: false, auto: false, range: [0.5, n + 0.5] }, y: log ? { distr: 3 } : { range: (self, lo, hi) => [0, hi * 1.05 || 1] } },
      axes: [{ label: div.fringe.axes[0], incrs: [1], values: (uu, v) => v.map((t) => (Number.isInteger(t) ? `${t}x` : '')) },
        { label: div.fringe.axes[1], size: 70, values: log ? expTicks : errTicks }],
      series,
    }, [x, ...ys], holder);
    div.fringe.u = u;
  };
  toggle(div, 'log scale', true, draw, 'log-toggle');
  draw(true);
  return div;
}

// A colour key in the page (HTML, readable at any width): one swatch per series.
function legendBox(div, items, cls = 'plot-legend') {
  const ul = document.createElement('ul');
  ul.className = cls;
  for (const { label, color: c, dash } of items) {
    const li = document.createElement('li');
    const sw = document.createElement('span');
    sw.className = dash ? 'swatch dash' : 'swatch';
    sw.style.borderColor = c;
    if (!dash) sw.style.background = c;
    li.dataset.color = c;
    li.append(sw, ` ${label}`);
    ul.append(li);
  }
  div.append(ul);
  return ul;
}

// Error spectrum from the report (estimators[i].spectrum: Welch at the full sample rate), log-log;
// x switchable between Hz and orders of the electrical frequency. Dashed markers at the
// harmonic orders 1x..16x, only where they lie below the Nyquist frequency (sample rate / 2):
// above it the spectrum has no bins and a marker would point at nothing. A solid line marks
// Nyquist itself. A legend names each estimator's colour.
export function errorSpectrum(parent, estimators, report) {
  const div = box(parent, 'Error spectrum (full rate)', 'plot-spectrum');
  const specs = (estimators || []).map((e, i) => ({ e, i, s: e.spectrum })).filter((x) => x.s && x.s.f_hz && x.s.f_hz.length);
  div.fringe = { kind: 'spectrum', series: specs.length };
  if (!specs.length) {
    const short = (estimators || []).find((e) => e.spectrum && e.spectrum.segments === 0);
    // A capture without truth: the spectrum is of the error against truth, which it has none of.
    // The traces' estimators carry no metrics: the report's lane of the same label does.
    const lane = short && ((report && report.estimators) || []).find((e) => e.label === short.label) || short;
    const truthless = hasNoTruth(report) || (lane && lane.metrics && lane.metrics.scored === 0 && lane.analysers && lane.analysers.self_reference);
    note(div, truthless ? 'no spectrum: it is the spectrum of the error against truth, and this capture has no truth (theta_true); the self-referenced error is in the metrics (self_ref_*)'
      : short ? `no spectrum: no run of ${short.spectrum.segment_samples} contiguous scored samples` : 'no spectrum in this report');
    return div;
  }
  const fe = (specs.find((x) => x.s.electrical_hz > 0) || {}).s?.electrical_hz || 0;
  const s0 = specs[0].s;
  // Nyquist: half the sample rate the spectrum was taken at (older reports: its last bin).
  let nyq = s0.sample_rate_hz > 0 ? s0.sample_rate_hz / 2 : 0;
  if (!nyq) for (const { s } of specs) for (const f of s.f_hz) if (f > nyq) nyq = f;
  const above = fe ? [1, 2, 3, 4, 8, 12, 16].filter((k) => k * fe > nyq * (1 + 1e-9)) : [];
  note(div, `Welch, ${s0.segment_samples}-sample Hann segments, ${s0.segments} averaged, resolution ${(+s0.resolution_hz).toPrecision(3)} Hz`
    + (fe ? `, electrical frequency ${(+fe).toPrecision(5)} Hz` : '') + `, Nyquist ${sig(nyq)} Hz`
    + (above.length ? `; harmonics from ${Math.ceil(nyq / fe * (1 + 1e-12)) }x up lie above Nyquist (not marked; they alias into the band)` : ''));
  const sel = document.createElement('select');
  sel.className = 'spectrum-axis';
  sel.innerHTML = '<option value="hz">x: frequency (Hz)</option><option value="order">x: order of the electrical frequency</option>';
  if (!fe) sel.options[1].disabled = true;
  const label = document.createElement('label');
  label.append('axis ', sel);
  div.append(label);
  const holder = document.createElement('div');
  div.append(holder);
  const legendItems = specs.map(({ e, i }) => ({ label: e.label, color: color(i) }));
  if (fe) legendItems.push({ label: 'harmonic orders (below Nyquist)', color: '#8c959f', dash: true });
  legendItems.push({ label: 'Nyquist (sample rate / 2)', color: '#57606a', dash: true });
  div.fringe.legend = legendItems.map((x) => ({ label: x.label, color: x.color }));
  div.fringe.nyquist_hz = nyq;
  div.fringe.electrical_hz = fe;
  let ymax = 0;
  for (const { s } of specs) for (const v of s.amplitude_rad) if (v > ymax) ymax = v;
  const floor = ymax > 0 ? ymax * 1e-7 : 1e-12;  // noise-free runs reach 1e-20: keep the peaks readable
  let u = null;
  const draw = () => {
    if (u) u.destroy();
    const byOrder = sel.value === 'order';
    const data = [null];
    const series = [{}];
    let lo = Infinity, hi = 0;
    for (const { e, i, s } of specs) {
      const x = byOrder ? s.order : s.f_hz;
      data.push([x, s.amplitude_rad.map((v) => Math.max(v, floor))]);
      series.push({ label: e.label, stroke: color(i), width: 1, paths: polyline(null), points: { show: false } });
      for (const v of x) if (v > 0) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    lo = 10 ** Math.floor(Math.log10(lo));  // whole decades: ticks at 1, 10, 100 ...
    hi = 10 ** Math.ceil(Math.log10(hi));
    const unit = byOrder ? 1 : fe;
    const nyqX = byOrder ? (fe ? nyq / fe : 0) : nyq;
    const marked = [];
    u = new uPlot({
      mode: 2, width: width(parent), height: 300,
      scales: { x: { time: false, distr: 3, auto: false, range: [lo, hi] }, y: { distr: 3, auto: false, range: [floor, ymax * 2 || 1] } },
      axes: [{ label: byOrder ? 'order (× electrical frequency)' : 'frequency (Hz)', values: (uu, v) => v.map((t) => (t == null ? '' : sig(t))) },
        { label: 'amplitude (rad)', size: 70, values: expTicks }],
      legend: { show: false },
      series,
      hooks: {
        draw: [(uu) => {
          const ctx = uu.ctx;
          const dpr = devicePixelRatio || 1;
          const vline = (px) => {
            const p = new Path2D();
            p.moveTo(px, uu.bbox.top);
            p.lineTo(px, uu.bbox.top + uu.bbox.height);
            ctx.stroke(p);
          };
          ctx.save();
          ctx.font = `${10 * dpr}px sans-serif`;
          ctx.textAlign = 'center';
          marked.length = 0;
          if (fe) {
            ctx.strokeStyle = '#8c959f';
            ctx.fillStyle = '#57606a';
            ctx.setLineDash([2 * dpr, 3 * dpr]);
            for (let k = 1; k <= 16; k++) {
              const x = k * unit;
              if (k * fe > nyq * (1 + 1e-9) || x < lo || x > hi) continue;
              const px = uu.valToPos(x, 'x', true);
              vline(px);
              marked.push(k);
              if (k <= 4 || k % 4 === 0) ctx.fillText(`${k}x`, px, uu.bbox.top + 10 * dpr);
            }
          }
          if (nyqX >= lo && nyqX <= hi) {
            ctx.strokeStyle = '#57606a';
            ctx.setLineDash([6 * dpr, 3 * dpr]);
            const px = uu.valToPos(nyqX, 'x', true);
            vline(px);
            ctx.textAlign = 'right';
            ctx.fillText('Nyquist', px - 3 * dpr, uu.bbox.top + uu.bbox.height - 4 * dpr);
          }
          ctx.restore();
          div.fringe.marked_orders = marked.slice();
        }],
      },
    }, data, holder);
    div.fringe.axis = sel.value;
    div.fringe.axes = [byOrder ? 'order (× electrical frequency)' : 'frequency (Hz)', 'amplitude (rad)'];
    div.fringe.u = u;
  };
  sel.addEventListener('change', draw);
  draw();
  legendBox(div, legendItems);
  return div;
}

// Labels of estimators present in the traces, in the report's order (one colour each across plots).
export function traceLabels(t, estimators) {
  return (estimators || []).map((e) => e.label).filter((l) => t.error_rad && l in t.error_rad);
}

// The settle period and error limits of a report, for its error plots.
export function plotContext(report, estimators, labels) {
  if (!report) return {};
  const sc = report.scenario || {};
  const t0 = typeof sc.t0_s === 'number' ? sc.t0_s : 0;
  const settle = typeof sc.settle_s === 'number' && sc.settle_s > 0 ? [t0, t0 + sc.settle_s] : null;
  const est = (report.estimators && report.estimators.length ? report.estimators : estimators) || [];
  return { settle, limits: errorLimitLines(report.measurements, est, labels) };
}

// A run on a capture without truth (theta_true): nothing was scored against truth.
export const hasNoTruth = (report) => !!(report && report.device && report.device.settings && report.device.settings.has_truth === false);

// All report plots into `parent`; an honest note for reports older than the envelope traces.
// report: the report (its scenario's settle time and t0, its measurements' limits), when known.
export function reportPlots(parent, t, estimators, report) {
  const labels = traceLabels(t, estimators);
  const opts = plotContext(report, estimators, labels);
  if (!isEnvelope(t)) {
    const p = document.createElement('p');
    p.className = 'muted old-traces';
    p.textContent = `Old report: traces are stride samples (every ${t.stride || '?'}th sample), drawn as points; a line through them would alias.`;
    parent.append(p);
  }
  if (hasNoTruth(report)) {
    const p = document.createElement('p');
    p.className = 'muted';
    p.id = 'plots-no-truth';
    p.textContent = 'This capture has no truth (theta_true): the error plots below (against the electrical angle, against time, its harmonics and spectrum) '
      + "need it and stay empty; the self-referenced error against the electrical angle is drawn from its harmonics. Each estimator's "
      + 'self-referenced error, with its uncertainty, is under Estimators; the signals are under Signals.';
    parent.append(p);
  }
  lissajous(parent, t);
  errorVsAngle(parent, t, labels, { limits: opts.limits });
  selfRefVsAngle(parent, (report && report.estimators) || estimators);  // the traces' list carries no analysers
  errorVsTime(parent, t, labels, 'Error vs time', 'plot-time', opts);
  harmonicBars(parent, estimators);
  errorSpectrum(parent, estimators, report);
}
