// Report plots with uPlot (vendored from npm into /vendor by scripts/setup).
import uPlot from './vendor/uPlot.esm.js';

const COLORS = ['#0969da', '#cf222e', '#1a7f37', '#9a6700', '#8250df', '#bc4c00', '#57606a'];
const color = (i) => COLORS[i % COLORS.length];

function box(parent, title) {
  const div = document.createElement('div');
  div.className = 'plot';
  const h = document.createElement('h3');
  h.textContent = title;
  div.append(h);
  parent.append(div);
  return div;
}

function width(parent) { return Math.max(480, Math.min(620, (parent.clientWidth || 1100) / 2 - 40)); }

const pointsOnly = { show: true, size: 3 };
const expTicks = (u, vals) => vals.map((v) => (v == null ? '' : v.toExponential(0)));
// Error axes span 1e-6..1e-1 rad: exponents below 1e-3, else three significant digits.
const errTicks = (u, vals) => vals.map((v) => (v == null ? '' : v !== 0 && Math.abs(v) < 1e-3 ? v.toExponential(1) : String(+v.toPrecision(3))));
function range(a, pad = 0.05) {
  let lo = Infinity, hi = -Infinity;
  for (const v of a) if (v != null && Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!Number.isFinite(lo)) return [-1, 1];
  const d = (hi - lo) * pad || Math.abs(hi) * pad || 1;
  return [lo - d, hi + d];
}
const noPath = () => null;

// A polyline through the points in sample order: uPlot's built-in linear path decimates per
// pixel column, which assumes x sorted; a Lissajous curve is not.
function polyline(u, seriesIdx) {
  const [xs, ys] = u.data[seriesIdx];
  const p = new Path2D();
  for (let i = 0; i < xs.length; i++) {
    const x = u.valToPos(xs[i], 'x', true), y = u.valToPos(ys[i], 'y', true);
    if (i) p.lineTo(x, y); else p.moveTo(x, y);
  }
  return { stroke: p, fill: null, clip: null, band: null, gaps: null, flags: 0 };
}

// Lissajous: cos on x, sin on y, in volts.
export function lissajous(parent, tr) {
  const div = box(parent, 'Lissajous: sin vs cos (V)');
  const w = width(parent);
  return new uPlot({
    mode: 2, width: w, height: w * 0.8,
    // xy mode takes an x range from the first and last sample only: give both ranges.
    scales: { x: { time: false, auto: false, range: range(tr.cos_v) }, y: { auto: false, range: range(tr.sin_v) } },
    axes: [{ label: 'cos (V)' }, { label: 'sin (V)' }],
    legend: { show: false },
    series: [{}, { label: 'sin vs cos', stroke: color(0), paths: polyline, points: { show: false } }],
  }, [null, [tr.cos_v, tr.sin_v]], div);
}

// Error against the true electrical angle (wrapped to [0, 2 pi)), one series per estimator.
export function errorVsAngle(parent, tr, labels) {
  const div = box(parent, 'Error vs electrical angle (rad)');
  const th = tr.theta_true_wrapped_rad.map((v) => ((v % (2 * Math.PI)) + 2 * Math.PI) % (2 * Math.PI));
  const idx = th.map((_, i) => i).sort((a, b) => th[a] - th[b]);
  const data = [idx.map((i) => th[i])];
  for (const l of labels) data.push(idx.map((i) => tr.error_rad[l][i]));
  return new uPlot({
    width: width(parent), height: 300,
    scales: { x: { time: false } },
    axes: [{ label: 'theta (rad)' }, { label: 'error (rad)', size: 70, values: errTicks }],
    series: [{ label: 'theta' }, ...labels.map((l, i) => ({ label: l, stroke: color(i), paths: noPath, points: { ...pointsOnly, fill: color(i) } }))],
  }, data, div);
}

export function errorVsTime(parent, tr, labels, title = 'Error vs time (rad)') {
  const div = box(parent, title);
  return new uPlot({
    width: width(parent), height: 300,
    scales: { x: { time: false } },
    axes: [{ label: 't (s)' }, { label: 'error (rad)', size: 70, values: errTicks }],
    series: [{ label: 't' }, ...labels.map((l, i) => ({ label: l, stroke: color(i), width: 1 }))],
  }, [tr.t_s, ...labels.map((l) => tr.error_rad[l])], div);
}

// Harmonics 1x..6x of the error per electrical cycle (MODEL.md 7), grouped per estimator:
// each estimator's bar sits at its own x offset within the harmonic's slot.
export function harmonicBars(parent, estimators) {
  const div = box(parent, 'Error harmonics (amplitude, rad) per electrical cycle');
  const n = 6;
  const k = Math.max(estimators.length, 1);
  const slot = 0.8 / k;
  const x = [];
  for (let hh = 1; hh <= n; hh++) for (let i = 0; i < k; i++) x.push(hh - 0.4 + (i + 0.5) * slot);
  const bars = uPlot.paths.bars({ size: [0.9, 80], align: 0 });
  const data = [x];
  const series = [{ label: 'harmonic' }];
  estimators.forEach((e, i) => {
    const y = x.map(() => null);
    for (let hh = 1; hh <= n; hh++) {
      const v = (e.harmonics || [])[hh - 1];
      const amp = v == null ? null : typeof v === 'number' ? v : (v.amplitude && v.amplitude.rad);
      y[(hh - 1) * k + i] = amp > 0 ? amp : null;
    }
    data.push(y);
    series.push({ label: e.label, stroke: color(i), fill: color(i) + 'cc', paths: bars, points: { show: false } });
  });
  return new uPlot({
    width: width(parent), height: 300,
    scales: { x: { time: false, auto: false, range: [0.5, n + 0.5] }, y: { distr: 3 } },
    axes: [{ label: 'harmonic (x electrical)', incrs: [1], values: (u, v) => v.map((t) => (Number.isInteger(t) ? `${t}x` : '')) },
      { label: 'rad', size: 70, values: expTicks }],
    series,
  }, data, div);
}

// Amplitude spectrum of the (decimated) error trace: radix-2 FFT, Hann window.
export function spectrum(values, dt) {
  let n = 1;
  while (n * 2 <= values.length) n *= 2;
  const re = new Float64Array(n), im = new Float64Array(n);
  let mean = 0;
  for (let i = 0; i < n; i++) mean += values[i];
  mean /= n;
  for (let i = 0; i < n; i++) re[i] = (values[i] - mean) * (0.5 - 0.5 * Math.cos((2 * Math.PI * i) / (n - 1)));
  for (let i = 1, j = 0; i < n; i++) {  // bit reversal
    let bit = n >> 1;
    for (; j & bit; bit >>= 1) j ^= bit;
    j ^= bit;
    if (i < j) { [re[i], re[j]] = [re[j], re[i]]; [im[i], im[j]] = [im[j], im[i]]; }
  }
  for (let len = 2; len <= n; len <<= 1) {
    const ang = (-2 * Math.PI) / len;
    for (let i = 0; i < n; i += len)
      for (let k = 0; k < len / 2; k++) {
        const wr = Math.cos(ang * k), wi = Math.sin(ang * k);
        const a = i + k, b = i + k + len / 2;
        const tr = re[b] * wr - im[b] * wi, ti = re[b] * wi + im[b] * wr;
        re[b] = re[a] - tr; im[b] = im[a] - ti; re[a] += tr; im[a] += ti;
      }
  }
  const f = [], amp = [];
  for (let k = 1; k < n / 2; k++) { f.push(k / (n * dt)); amp.push((4 * Math.hypot(re[k], im[k])) / n); }  // Hann gain 1/2
  return { f, amp };
}

export function errorSpectrum(parent, tr, labels) {
  const div = box(parent, 'Error spectrum (decimated trace, rad)');
  const dt = tr.t_s.length > 1 ? tr.t_s[1] - tr.t_s[0] : 1;
  const specs = labels.map((l) => spectrum(tr.error_rad[l], dt));
  const f = specs.length ? specs[0].f : [];
  return new uPlot({
    width: width(parent), height: 300,
    scales: { x: { time: false }, y: { distr: 3 } },
    axes: [{ label: 'Hz' }, { label: 'rad', size: 70, values: expTicks }],
    series: [{ label: 'f' }, ...labels.map((l, i) => ({ label: l, stroke: color(i), width: 1 }))],
  }, [f, ...specs.map((s) => s.amp.map((v) => Math.max(v, 1e-12)))], div);
}
