// The signal page of a run's report (docs/signal-quality.md, "In the browser"): the signal
// figures graded against the scenario's interface profile, the way an encoder tester shows them.
// - a Lissajous drawn 1:1 (SVG, one scale for both axes) from the report's per-angle bins: the
//   mean curve, the spread of the samples' radius along each bin's direction, and the
//   interface's amplitude tolerance rings (radius Vpp / 2 of each band edge);
// - a gauge per graded figure: the specification band, the mounting band, outside them, and the
//   measured value with its grade;
// - the per-period recording against the period index, with the band edges as lines.
// Each drawing records what it drew in `el.fringe` (data coordinates), for the tests.
import uPlot from './vendor/uPlot.esm.js';
import { h } from './dom.js';
import { sig, withUnit } from './format.js';
import { color, plotWidth } from './plots.js';

const NS = 'http://www.w3.org/2000/svg';
function svg(tag, attrs = {}, ...children) {
  const el = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) if (v != null && v !== false) el.setAttribute(k, v);
  for (const c of children.flat()) if (c != null) el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return el;
}

// The figures every signal page shows, in this order; a profile's other band metrics follow.
const FIGURES = ['signal_vpp_a_v', 'signal_vpp_b_v', 'signal_ab_ratio', 'signal_phase_deg', 'signal_tv_a_deg', 'signal_tv_b_deg'];

// Names for the figures the metric table gives no column.
const SHORT = { signal_sym_a: 'SYM A', signal_sym_b: 'SYM B', signal_phase_error_deg: 'phase error', signal_offset_a_percent: 'offset A',
  signal_offset_b_percent: 'offset B' };

// Where a value lies, as the tester's colours: a region's kind is the grade a value inside it
// gets (server/engine/limits.cpp). Without a mounting band the whole specification passes.
export const REGION = {
  mounting: { fill: '#4ac26b', words: 'within mounting tolerance' },
  spec: { fill: '#eac54f', words: 'within specification, outside mounting tolerance' },
  pass: { fill: '#4ac26b', words: 'within specification' },
  out: { fill: '#d0d7de', words: 'out of specification' },
};
export const GRADE_REGION = {
  'within mounting tolerance': 'mounting',
  'within specification, outside mounting tolerance': 'spec',
  'within specification': 'pass',
  'out of specification': 'out',
};
const OUTCOME_COLOR = { PASS: '#1a7f37', MARGINAL: '#9a6700', FAIL: '#cf222e', ERROR: '#8250df' };
const SPEC_LINE = '#9a6700', MOUNT_LINE = '#1a7f37';

const finite = (v) => typeof v === 'number' && Number.isFinite(v);
const bandOf = (profile, metric) => (profile && profile.bands && profile.bands[metric]) || null;
const edge = (b, i) => (b && Array.isArray(b) && finite(b[i]) ? b[i] : null);

// A nice step for axis ticks: 1, 2 or 5 times a power of ten, near `raw`.
function niceStep(raw) {
  if (!(raw > 0)) return 1;
  const p = 10 ** Math.floor(Math.log10(raw)), f = raw / p;
  return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * p;
}

// ---- gauges ------------------------------------------------------------------------------

// The regions of a gauge's scale [lo, hi] from a band {spec: [lo, hi], mounting: [lo, hi]}
// (null sides open), left to right, each with its kind.
export function gaugeRegions(band, lo, hi) {
  const sLo = edge(band.spec, 0) ?? -Infinity, sHi = edge(band.spec, 1) ?? Infinity;
  const m = band.mounting;
  const cuts = [];
  const push = (from, to, kind) => {
    const a = Math.max(from, lo), b = Math.min(to, hi);
    if (b > a) cuts.push({ kind, from: a, to: b });
  };
  push(-Infinity, sLo, 'out');
  if (m) {
    const mLo = edge(m, 0) ?? -Infinity, mHi = edge(m, 1) ?? Infinity;
    push(sLo, mLo, 'spec');
    push(mLo, mHi, 'mounting');
    push(mHi, sHi, 'spec');
  } else push(sLo, sHi, 'pass');
  push(sHi, Infinity, 'out');
  return cuts;
}

// One figure: its scale with the bands (when graded), the value and its grade.
function gauge(parent, { metric, label, unit, value, band, measurement, profileName }) {
  const div = h('div', { class: 'gauge', 'data-metric': metric });
  parent.append(div);
  const W = 320, H = 50, x0 = 12, x1 = W - 12, y0 = 16, y1 = 30;
  const pts = [value];
  if (band) for (const b of [band.spec, band.mounting]) for (const i of [0, 1]) pts.push(edge(b, i));
  const known = pts.filter(finite);
  let lo = Math.min(...known), hi = Math.max(...known);
  if (!known.length) { lo = -1; hi = 1; }
  const span = hi - lo || Math.abs(hi) * 0.2 || 1;
  lo -= 0.15 * span; hi += 0.15 * span;
  const X = (v) => x0 + ((v - lo) / (hi - lo)) * (x1 - x0);
  const regions = band ? gaugeRegions(band, lo, hi) : [];
  const outcome = measurement ? measurement.outcome : null;
  const grade = measurement ? measurement.grade || null : null;
  const g = svg('svg', { viewBox: `0 0 ${W} ${H}`, class: 'gauge-scale', role: 'img',
    'aria-label': `${label}: ${value == null ? 'not measured' : withUnit(value, unit)}${grade ? `, ${grade}` : ''}` });
  if (!regions.length) g.append(svg('rect', { x: x0, y: y0, width: x1 - x0, height: y1 - y0, class: 'g-none', fill: '#eaeef2' }));
  for (const r of regions) {
    r.fill = REGION[r.kind].fill;
    g.append(svg('rect', { x: X(r.from), y: y0, width: X(r.to) - X(r.from), height: y1 - y0, fill: r.fill, class: `g-region g-${r.kind}`, 'data-kind': r.kind },
      svg('title', {}, `${REGION[r.kind].words}: ${sig(r.from)} … ${sig(r.to)}${unit ? ` ${unit}` : ''}`)));
  }
  // Band edges as ticks with their numbers below the scale (one label where two would touch).
  const edges = [];
  if (band) for (const [b, kind] of [[band.spec, 'spec'], [band.mounting, 'mounting']]) for (const i of [0, 1]) if (edge(b, i) != null) edges.push({ v: edge(b, i), kind });
  edges.sort((a, b) => a.v - b.v);
  let lastX = -Infinity;
  for (const e of edges) {
    const x = X(e.v);
    g.append(svg('line', { x1: x, x2: x, y1: y0, y2: y1 + 3, stroke: e.kind === 'spec' ? SPEC_LINE : MOUNT_LINE, 'stroke-width': 1 }));
    if (x - lastX >= 26) { g.append(svg('text', { x, y: H - 6, 'text-anchor': 'middle', class: 'g-tick' }, sig(e.v))); lastX = x; }
  }
  let markerX = null;
  if (finite(value)) {
    markerX = X(value);
    const c = OUTCOME_COLOR[outcome] || '#1d2329';
    g.append(svg('line', { x1: markerX, x2: markerX, y1: y0 - 3, y2: y1 + 3, stroke: c, 'stroke-width': 2.5, class: 'g-marker' }),
      svg('path', { d: `M${markerX - 5},${y0 - 9} L${markerX + 5},${y0 - 9} L${markerX},${y0 - 2} Z`, fill: c, class: 'g-marker-head' }));
  }
  div.append(h('div', { class: 'gauge-head' }, h('span', { class: 'gauge-name', title: metric }, label),
    h('span', { class: 'gauge-value num', style: outcome ? `color:${OUTCOME_COLOR[outcome] || ''}` : null }, value == null ? 'not measured' : withUnit(value, unit))), g,
  h('div', { class: `gauge-grade${outcome ? ` o-${outcome}` : ''}`, 'data-grade': grade || '' },
    measurement ? h('span', { title: `graded against ${measurement.interface || profileName}` }, grade || outcome)
      : h('span', { class: 'muted' }, band ? 'not graded' : 'no band: value only')));
  div.fringe = { kind: 'gauge', metric, unit, value: finite(value) ? value : null, outcome, grade, band: band || null, domain: [lo, hi],
    scale_px: [x0, x1], regions, marker_px: markerX };
  return div;
}

// ---- Lissajous -------------------------------------------------------------------------------

// Tolerance rings: a circle of radius Vpp / 2 at each edge of the profile's amplitude band (A's,
// else B's): what a signal of that amplitude would draw.
export function toleranceRings(profile) {
  const band = bandOf(profile, 'signal_vpp_a_v') || bandOf(profile, 'signal_vpp_b_v');
  if (!band) return [];
  const out = [];
  for (const [b, kind] of [[band.spec, 'spec'], [band.mounting, 'mounting']])
    for (const [i, side] of [[0, 'lo'], [1, 'hi']]) {
      const v = edge(b, i);
      if (v != null && v > 0) out.push({ vpp_v: v, radius_v: v / 2, band: kind, edge: side });
    }
  return out;
}

function lissajousSvg(parent, sg, profile) {
  const L = sg.lissajous;
  const div = h('div', { class: 'plot signal-liss', id: 'signal-lissajous' });
  parent.append(div);
  div.append(h('h3', {}, 'Lissajous 1:1: B (cos) across, A (sin) up'));
  const rings = toleranceRings(profile);
  const hasBins = L && Array.isArray(L.a_v) && Array.isArray(L.b_v) && L.bins > 0;
  // The extent: the widest of the curve, the spread, the rings and the extreme radius.
  let R = 0;
  const grow = (v) => { if (finite(v)) R = Math.max(R, Math.abs(v)); };
  grow(sg.radius_max_v);
  for (const r of rings) grow(r.radius_v);
  if (hasBins) for (const k of ['a_v', 'b_v', 'r_max_v']) for (const v of L[k] || []) grow(v);
  R = R > 0 ? R * 1.08 : 1;
  const S = 360, m = 24, c = S / 2, k = (S - 2 * m) / (2 * R);
  const X = (v) => c + v * k, Y = (v) => c - v * k;
  const g = svg('svg', { viewBox: `0 0 ${S} ${S}`, class: 'liss-svg', role: 'img', 'aria-label': 'Lissajous of the signals, drawn 1:1' });
  // Grid and axes through 0, ticks in volts.
  const step = niceStep(R / 2.5);
  for (let t = -Math.floor(R / step) * step; t <= R + 1e-12; t += step) {
    if (Math.abs(t) < step / 2) continue;
    g.append(svg('line', { x1: X(t), x2: X(t), y1: c - 3, y2: c + 3, class: 'liss-tick' }),
      svg('line', { x1: c - 3, x2: c + 3, y1: Y(t), y2: Y(t), class: 'liss-tick' }),
      svg('text', { x: X(t), y: c + 13, 'text-anchor': 'middle', class: 'liss-label' }, sig(t, 2)),
      svg('text', { x: c - 5, y: Y(t) + 3, 'text-anchor': 'end', class: 'liss-label' }, sig(t, 2)));
  }
  g.append(svg('line', { x1: X(-R), x2: X(R), y1: c, y2: c, class: 'liss-axis' }), svg('line', { x1: c, x2: c, y1: Y(-R), y2: Y(R), class: 'liss-axis' }),
    svg('text', { x: S - 2, y: c - 5, 'text-anchor': 'end', class: 'liss-label' }, 'B (V)'), svg('text', { x: c + 5, y: 11, class: 'liss-label' }, 'A (V)'));
  const record = { kind: 'signal-lissajous', viewbox: [S, S], center_px: [c, c], px_per_v: [k, k], range_v: [-R, R], rings: [], bins: 0, curve: null, spread: null };
  div.fringe = record;
  // The spread: the samples' radius from r_min to r_max along each bin's direction (the
  // direction of its mean point), as a ring-shaped band; bins without samples are left out.
  if (hasBins) {
    const n = L.bins;
    const dirs = [], outer = [], inner = [];
    for (let i = 0; i < n; i++) {
      const a = L.a_v[i], b = L.b_v[i];
      const dir = finite(a) && finite(b) && (a || b) ? Math.atan2(a, b) : ((i + 0.5) * 2 * Math.PI) / n;
      dirs.push(dir);
      const rMin = L.r_min_v ? L.r_min_v[i] : null, rMax = L.r_max_v ? L.r_max_v[i] : null;
      if (finite(rMin) && finite(rMax)) {
        outer.push([rMax * Math.cos(dir), rMax * Math.sin(dir)]);
        inner.push([rMin * Math.cos(dir), rMin * Math.sin(dir)]);
      }
    }
    const loop = (pts) => pts.map((p, i) => `${i ? 'L' : 'M'}${X(p[0]).toFixed(2)},${Y(p[1]).toFixed(2)}`).join(' ') + ' Z';
    if (outer.length > 2) g.append(svg('path', { d: `${loop(outer)} ${loop(inner)}`, 'fill-rule': 'evenodd', class: 'liss-spread' },
      svg('title', {}, 'spread of the samples: smallest to largest radius sqrt(A² + B²) in each angle bin')));
    // The mean curve, broken where a bin has no samples, closed when none is missing.
    let d = '', pen = false, segs = 0;
    const xs = [], ys = [];
    for (let i = 0; i < n; i++) {
      const a = L.a_v[i], b = L.b_v[i];
      if (!finite(a) || !finite(b)) { pen = false; continue; }
      xs.push(b); ys.push(a);
      d += `${pen ? 'L' : 'M'}${X(b).toFixed(2)},${Y(a).toFixed(2)} `;
      if (pen) segs++;
      pen = true;
    }
    const closed = xs.length === n && n > 2;
    if (closed) { d += 'Z'; segs++; }
    g.append(svg('path', { d: d.trim(), class: 'liss-mean', fill: 'none', stroke: color(0) }));
    Object.assign(record, { bins: n, curve: { x_v: xs, y_v: ys, segments: segs, closed }, spread: { bins: outer.length, r_min_v: L.r_min_v || [], r_max_v: L.r_max_v || [] } });
  }
  // The rings over the curve, labelled at staggered angles so that close rings stay readable.
  // Specification labels at the lower left, mounting labels at the lower right, the lower and
  // upper edge of each 20 degrees apart.
  const LABEL_DEG = { spec: { lo: 215, hi: 235 }, mounting: { lo: 325, hi: 305 } };
  rings.forEach((r) => {
    const rp = r.radius_v * k;
    const ang = LABEL_DEG[r.band][r.edge] * (Math.PI / 180);
    const el = svg('circle', { cx: c, cy: c, r: rp, class: `liss-ring ring-${r.band}`, fill: 'none', stroke: r.band === 'spec' ? SPEC_LINE : MOUNT_LINE,
      'stroke-dasharray': r.band === 'spec' ? '5 3' : null, 'data-vpp': r.vpp_v }, svg('title', {}, `${r.band === 'spec' ? 'specification' : 'mounting'} ${r.edge} ${sig(r.vpp_v)} Vpp`));
    const left = Math.cos(ang) < 0;
    g.append(el, svg('text', { x: c + rp * Math.cos(ang) + (left ? -3 : 3), y: c - rp * Math.sin(ang) + 8, 'text-anchor': left ? 'end' : 'start',
      class: `liss-ring-label ring-${r.band}` }, `${sig(r.vpp_v)} Vpp`));
    record.rings.push({ ...r, r_px: rp, dashed: r.band === 'spec' });
  });
  div.append(g);
  const words = [];
  if (hasBins) {
    let widest = null;
    for (let i = 0; i < L.bins; i++) {
      const lo = (L.r_min_v || [])[i], hi = (L.r_max_v || [])[i];
      if (finite(lo) && finite(hi) && (widest == null || hi - lo > widest)) widest = hi - lo;
    }
    words.push(`line: mean A and B in each of ${L.bins} electrical-angle bins; shaded: the samples' radius from smallest to largest in each bin${widest == null ? '' : ` (at most ${withUnit(widest, 'V')} wide)`}`);
  }
  else words.push('this report has no per-angle bins: no mean curve or spread');
  if (rings.length) words.push(`rings: ${profile.name} amplitude band as radius Vpp / 2 (dashed: specification ${rings.filter((r) => r.band === 'spec').map((r) => sig(r.vpp_v)).join(' and ')} Vpp; solid: mounting ${rings.filter((r) => r.band === 'mounting').map((r) => sig(r.vpp_v)).join(' and ') || 'none'} Vpp)`);
  else if (profile) words.push(`the interface profile ${profile.name} names no amplitude band: no tolerance rings`);
  else words.push('no interface profile: no tolerance rings');
  div.append(h('p', { class: 'muted plot-note', id: 'signal-liss-note' }, `${words.join('. ')}.`));
  return div;
}

// ---- per-period trends -----------------------------------------------------------------------

const TRENDS = [
  { id: 'trend-vpp', title: 'Amplitude A and B per period', unit: 'V', axis: 'Vpp (V)', keys: [['A', 'vpp_a_v'], ['B', 'vpp_b_v']], metrics: ['signal_vpp_a_v', 'signal_vpp_b_v'] },
  { id: 'trend-ratio', title: 'A/B amplitude ratio per period', unit: '', axis: 'A/B', keys: [['A/B', 'ab_ratio']], metrics: ['signal_ab_ratio'] },
  { id: 'trend-phase', title: 'Phase between A and B per period', unit: 'deg', axis: 'phase (deg)', keys: [['phase', 'phase_deg']], metrics: ['signal_phase_deg'] },
  { id: 'trend-tv', title: 'On/off ratio TV of A and B per period', unit: 'deg', axis: 'TV (deg)', keys: [['TV A', 'tv_a_deg'], ['TV B', 'tv_b_deg']], metrics: ['signal_tv_a_deg', 'signal_tv_b_deg'] },
  { id: 'trend-offset', title: 'Offset of A and B per period', unit: 'V', axis: 'offset (V)', keys: [['A', 'offset_a_v'], ['B', 'offset_b_v']], metrics: ['signal_offset_a_v', 'signal_offset_b_v'] },
];

// Legend values: the hovered period's value, else the mean and range over the periods.
function legend(y, unit) {
  const v = y.filter((x) => x != null), u = unit ? ` ${unit}` : '';
  const idle = v.length ? `mean ${sig(v.reduce((a, b) => a + b, 0) / v.length)}${u} (${sig(Math.min(...v))} … ${sig(Math.max(...v))})` : '';
  return (uu, val, si, di) => (di == null ? idle : val == null ? '' : `${sig(val)}${u}`);
}

// The band edges of a trend's metrics as horizontal lines (one per value and band).
function bandLines(profile, metrics) {
  const out = [];
  for (const metric of metrics) {
    const b = bandOf(profile, metric);
    if (!b) continue;
    for (const [arr, kind] of [[b.spec, 'spec'], [b.mounting, 'mounting']])
      for (const [i, side] of [[0, 'lo'], [1, 'hi']]) {
        const y = edge(arr, i);
        if (y != null && !out.some((l) => l.y === y && l.band === kind)) out.push({ y, band: kind, edge: side });
      }
  }
  return out;
}

function trend(parent, spec, rec, profile) {
  const div = h('div', { class: 'plot signal-trend', id: spec.id });
  parent.append(div);
  div.append(h('h3', {}, spec.title));
  const holder = h('div');
  const x = rec.first_period;
  const ys = spec.keys.map(([, key]) => (rec[key] || []).map((v) => (finite(v) ? v : null)));
  const lines = bandLines(profile, spec.metrics);
  div.fringe = { kind: 'signal-trend', metrics: spec.metrics, points: x.length, x, series: Object.fromEntries(spec.keys.map(([, key], i) => [key, ys[i]])),
    bands: lines, bands_drawn: [], with_bands: lines.length > 0 };
  let u = null;
  const draw = (withBands) => {
    if (u) u.destroy();
    div.fringe.with_bands = withBands;
    let lo = Infinity, hi = -Infinity;
    for (const y of ys) for (const v of y) if (v != null) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    if (withBands) for (const l of lines) { lo = Math.min(lo, l.y); hi = Math.max(hi, l.y); }
    if (!Number.isFinite(lo)) { lo = -1; hi = 1; }
    const pad = (hi - lo) * 0.08 || Math.abs(hi) * 0.01 || 1e-6;
    const yr = [lo - pad, hi + pad];
    div.fringe.y_range = yr;
    const few = x.length < 80;
    u = new uPlot({
      width: plotWidth(parent), height: 240,
      scales: { x: { time: false }, y: { auto: false, range: yr } },
      axes: [{ label: 'period' }, { label: spec.axis, size: 64, values: (uu, vals) => vals.map((v) => (v == null ? '' : sig(v))) }],
      series: [{ label: 'period', value: (uu, v) => (v == null ? '' : String(v)) },
        ...spec.keys.map(([label], i) => ({ label, stroke: color(i), width: 1.5, points: { show: few, size: 4, fill: color(i) },
          value: legend(ys[i], spec.unit) }))],
      hooks: {
        draw: [(uu) => {
          const drawn = [];
          if (withBands && lines.length) {
            const ctx = uu.ctx, dpr = devicePixelRatio || 1;
            ctx.save();
            ctx.font = `${10 * dpr}px sans-serif`;
            ctx.textAlign = 'right';
            for (const l of lines) {
              if (!(l.y >= uu.scales.y.min && l.y <= uu.scales.y.max)) continue;
              const py = uu.valToPos(l.y, 'y', true), c = l.band === 'spec' ? SPEC_LINE : MOUNT_LINE;
              ctx.strokeStyle = c; ctx.fillStyle = c; ctx.lineWidth = 1.5 * dpr;
              ctx.setLineDash(l.band === 'spec' ? [6 * dpr, 4 * dpr] : []);
              const p = new Path2D();
              p.moveTo(uu.bbox.left, py);
              p.lineTo(uu.bbox.left + uu.bbox.width, py);
              ctx.stroke(p);
              ctx.fillText(`${l.band === 'spec' ? 'spec' : 'mounting'} ${l.edge} ${sig(l.y)}`, uu.bbox.left + uu.bbox.width - 3 * dpr, py - 3 * dpr);
              drawn.push(l.y);
            }
            ctx.restore();
          }
          div.fringe.bands_drawn = drawn;
        }],
      },
    }, [x, ...ys], holder);
    div.fringe.u = u;
  };
  if (lines.length) {
    const box = h('input', { type: 'checkbox', class: 'bands-toggle' });
    box.checked = true;
    box.addEventListener('change', () => draw(box.checked));
    div.append(h('div', { class: 'plot-tools' }, h('label', {}, box, ' band edges in view')));
  }
  div.append(holder);
  draw(lines.length > 0);
  if (lines.length) div.append(h('p', { class: 'muted plot-note plot-key' }, 'dashed: specification edges; solid: mounting edges (untick to zoom to the periods).'));
  return div;
}

// Each recorded period's amplitude against the shaft angle: its place along the scale
// (recording.position_periods, from the run's start) modulo the encoder's lines per revolution.
// A dirty section of the scale, or a gap run-out, returns at the same angle every turn.
function shaftPlot(parent, rec, lines) {
  const pos = rec.position_periods;
  if (!(lines > 0) || !Array.isArray(pos) || pos.length !== rec.first_period.length) return null;
  const div = h('div', { class: 'plot signal-shaft', id: 'signal-shaft' });
  parent.append(div);
  div.append(h('h3', {}, `Amplitude per period against shaft angle (${lines} periods a revolution, from the run's start)`));
  const deg = pos.map((p) => (360 * ((((p % lines) + lines) % lines) + 0.5)) / lines);
  const series = [['A', rec.vpp_a_v || []], ['B', rec.vpp_b_v || []]];
  let lo = Infinity, hi = -Infinity;
  for (const [, ys] of series) for (const v of ys) if (finite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
  const least = Math.abs(hi) * 0.01 || 1e-6;  // at least 1 % of the level tall: three-digit ticks stay distinct
  if (hi - lo < least) { const mid = (lo + hi) / 2; lo = mid - least / 2; hi = mid + least / 2; }
  const pad = (hi - lo) * 0.08;
  lo -= pad; hi += pad;
  const W = 560, H = 240, l = 64, r = 12, t = 12, b = 34;
  const X = (v) => l + (v / 360) * (W - l - r), Y = (v) => H - b - ((v - lo) / (hi - lo)) * (H - t - b);
  const g = svg('svg', { viewBox: `0 0 ${W} ${H}`, class: 'shaft-svg', role: 'img', 'aria-label': 'amplitude per period against shaft angle' });
  g.append(svg('rect', { x: l, y: t, width: W - l - r, height: H - t - b, fill: 'none', class: 'liss-axis' }));
  for (let a = 0; a <= 360; a += 60) g.append(svg('text', { x: X(a), y: H - b + 14, 'text-anchor': 'middle', class: 'liss-label' }, String(a)));
  const step = niceStep((hi - lo) / 4);
  for (let v = Math.ceil(lo / step) * step; v <= hi; v += step)
    g.append(svg('line', { x1: l - 3, x2: W - r, y1: Y(v), y2: Y(v), class: 'liss-tick' }), svg('text', { x: l - 5, y: Y(v) + 3, 'text-anchor': 'end', class: 'liss-label' }, sig(v)));
  g.append(svg('text', { x: (l + W - r) / 2, y: H - 4, 'text-anchor': 'middle', class: 'liss-label' }, 'shaft angle (deg)'),
    svg('text', { x: 12, y: (t + H - b) / 2, transform: `rotate(-90 12 ${(t + H - b) / 2})`, 'text-anchor': 'middle', class: 'liss-label' }, 'Vpp (V)'));
  let points = 0;
  series.forEach(([name, ys], i) => {
    const grp = svg('g', { fill: color(i), class: `shaft-points shaft-${name}` });
    ys.forEach((v, k) => { if (finite(v)) { grp.append(svg('circle', { cx: X(deg[k]).toFixed(2), cy: Y(v).toFixed(2), r: 1.8 })); points++; } });
    g.append(grp, svg('text', { x: l + 8 + 30 * i, y: t + 12, fill: color(i), class: 'liss-label' }, name));
  });
  div.append(g);
  div.fringe = { kind: 'signal-shaft', lines, points, deg, y_range: [lo, hi] };
  return div;
}

// The recording as a table, folded (at most 2048 rows): each period's (or bucket's) figures.
const REC_COLS = [['first_period', 'first period'], ['position_periods', 'place (periods)'], ['t_s', 't (s)'], ['vpp_a_v', 'Vpp A (V)'],
  ['vpp_b_v', 'Vpp B (V)'], ['ab_ratio', 'A/B'], ['phase_deg', 'phase (deg)'], ['tv_a_deg', 'TV A (deg)'], ['tv_b_deg', 'TV B (deg)'],
  ['offset_a_v', 'offset A (V)'], ['offset_b_v', 'offset B (V)']];
function recordingTable(rec) {
  const cols = REC_COLS.filter(([k]) => Array.isArray(rec[k]));
  const n = rec.first_period.length;
  const cell = (v) => (Number.isInteger(v) ? String(v) : finite(v) ? String(Number(v.toPrecision(6))) : '');
  const details = h('details', { id: 'signal-recording' },
    h('summary', {}, `Per-period recording as a table (${n} rows${rec.periods_per_point > 1 ? `, each the mean of ${rec.periods_per_point} periods` : ''})`));
  // Built when opened: a closed table costs nothing.
  details.addEventListener('toggle', () => {
    if (!details.open || details.querySelector('table')) return;
    details.append(h('div', { class: 'table-wrap' }, h('table', { class: 'recording' },
      h('thead', {}, h('tr', {}, cols.map(([, t]) => h('th', {}, t)))),
      h('tbody', {}, Array.from({ length: n }, (_, i) => h('tr', {}, cols.map(([k]) => h('td', { class: 'num' }, cell(rec[k][i])))))))));
  });
  return details;
}

// ---- the section -----------------------------------------------------------------------------

// Into `section` (attached to the page, so the plots know their width): the signal page of
// report `r` with the metric table `mt` (names, units and columns of the signal_* metrics).
export function signalPage(section, r, mt) {
  const sg = r.signal;
  const profile = (r.scenario && typeof r.scenario.interface === 'object' && r.scenario.interface) || null;
  const byName = Object.fromEntries(((mt && mt.metrics) || []).map((m) => [m.name, m]));
  const graded = new Map((r.measurements || []).filter((m) => m.estimator === 'run' && m.interface && m.metric).map((m) => [m.metric, m]));
  section.fringe = { profile: profile ? profile.name : null, periods: sg ? sg.periods || 0 : null };
  section.append(h('p', { id: 'signal-interface' }, profile
    ? ['Graded against the interface profile ', h('b', {}, profile.name), profile.source ? h('span', { class: 'muted' }, ` (${profile.source})`) : '',
      ': green within the mounting tolerance, yellow within the specification only, grey outside it.']
    : h('span', { class: 'muted' }, 'No interface profile: the figures are not graded (a scenario names one with "interface", docs/signal-quality.md).')));
  if (!sg) { section.append(h('p', { class: 'muted', id: 'signal-note' }, 'This report has no signal analysis.')); return; }
  if (!sg.periods) {
    section.append(h('p', { class: 'muted', id: 'signal-note' }, `Signals not analysed: ${sg.note || 'no whole electrical period'}.`));
    if (graded.size) section.append(h('p', { class: 'muted' }, `Graded as not measured: ${[...graded.keys()].join(', ')}.`));
    return;
  }
  // Gauges: the usual six figures, then whatever else the profile names.
  const metrics = [...FIGURES, ...Object.keys((profile && profile.bands) || {}).filter((m) => !FIGURES.includes(m))];
  const gauges = h('div', { class: 'gauges', id: 'signal-gauges' });
  section.append(h('h3', {}, 'Figures against the bands'), gauges);
  for (const metric of metrics) {
    const mm = byName[metric] || {}, meas = graded.get(metric) || null;
    const v = meas ? meas.value : mm.values && mm.values.run ? mm.values.run.value : null;
    gauge(gauges, { metric, label: mm.column || SHORT[metric] || metric, unit: meas ? meas.unit : mm.unit, value: finite(v) ? v : null, band: bandOf(profile, metric) || (meas && meas.band) || null,
      measurement: meas, profileName: profile && profile.name });
  }
  if (!profile) gauges.after(h('p', { class: 'muted plot-note', id: 'signal-gauge-note' }, 'No interface profile: the gauges show the values only, without bands.'));
  const plotsBox = h('div', { class: 'plots', id: 'signal-plots' });
  section.append(h('h3', {}, 'Lissajous and per-period recording'), plotsBox);
  lissajousSvg(plotsBox, sg, profile);
  const rec = sg.recording;
  if (rec && Array.isArray(rec.first_period) && rec.first_period.length) {
    plotsBox.append(h('p', { class: 'muted plot-note signal-rec-note' }, rec.periods_per_point > 1
      ? `Per-period recording: each point is the mean of ${rec.periods_per_point} periods (${rec.first_period.length} points for ${sg.periods} periods), against the index of its first period.`
      : `Per-period recording: one point per electrical period (${rec.first_period.length}), against the period index.`));
    for (const t of TRENDS) trend(plotsBox, t, rec, profile);
    const enc = r.scenario && r.scenario.encoder;
    shaftPlot(plotsBox, rec, enc && Number.isInteger(enc.lines_per_rev) ? enc.lines_per_rev : 0);
    section.append(recordingTable(rec));
  } else plotsBox.append(h('p', { class: 'muted plot-note signal-rec-note' }, 'This report has no per-period recording.'));
}
