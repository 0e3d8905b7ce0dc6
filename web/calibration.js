// A run whose scenario has "calibrate" (docs/calibration.md "In one run"): which capture
// computed the correction and which verified it, the correction, and each lane before and after
// side by side, from the report's "calibration" (docs/schema.md "Calibration").
import { h, scroller } from './dom.js';
import { sig, withUnit } from './format.js';

const passText = (p) => {
  if (!p) return '-';
  let t = `seed ${p.seed == null ? 'not recorded' : p.seed}, device ${p.device}`;
  if (p.capture) t += `, capture ${p.capture}`;
  if (p.error_source) t += p.error_source === 'truth' ? ', truth-scored error' : ', self-referenced error';
  return t;
};

export function calibrationSection(r) {
  const c = r && r.calibration;
  if (!c) return '';
  const verified = c.status === 'verified';
  const lanes = c.lanes || [];
  const rows = lanes.map((l) => {
    const b = l.before || {}, a = l.after;
    // The error each pass was measured by: one word when both agree, else before / after.
    const word = (p) => (!p || !p.error_source ? '-' : p.error_source === 'truth' ? 'truth' : 'self-referenced');
    const src = !a || word(a) === word(b) ? word(b) : `${word(b)} / ${word(a)}`;
    const crb = a && a.per_sample_crb_rad != null ? a.per_sample_crb_rad : b.per_sample_crb_rad;
    const cor = l.correction;
    const applied = !cor ? '-' : cor.applied ? (cor.kind === 'external_env' ? 'handed to the child (external_env)' : `applied (${cor.kind})`) : `not applied: ${cor.why_not || ''}`;
    const num = (v, label, extra = {}) => h('td', { class: 'num', 'data-label': label, 'data-value': v == null ? '' : String(v), ...extra }, v == null ? '-' : withUnit(v, 'rad'));
    return h('tr', { 'data-lane': l.label, 'data-applied': cor && cor.applied ? '1' : '' },
      h('td', { 'data-label': 'lane' }, l.label),
      h('td', { 'data-label': 'error' }, src),
      num(b.rms_rad, 'rms before', { class: 'num before' }),
      num(a ? a.rms_rad : null, 'rms after', { class: 'num after' }),
      num(b.max_abs_rad, 'max before'),
      num(a ? a.max_abs_rad : null, 'max after'),
      num(crb, 'per-sample CRB'),
      h('td', { class: 'num ratio', 'data-label': 'after / CRB', 'data-value': a && a.rms_over_crb != null ? String(a.rms_over_crb) : '' }, a && a.rms_over_crb != null ? sig(a.rms_over_crb) : '-'),
      num(l.predicted_rms_rad, 'predicted'),
      h('td', { class: cor && cor.applied ? '' : 'muted', 'data-label': 'correction' }, applied));
  });
  const harm = [];
  for (const l of lanes) {
    const hb = (l.before && l.before.harmonics) || [], ha = (l.after && l.after.harmonics) || [];
    for (let i = 0; i < Math.min(8, Math.max(hb.length, ha.length)); ++i) {
      const x = hb[i] || ha[i];
      harm.push(h('tr', { 'data-lane': l.label, 'data-order': x.order }, h('td', {}, l.label), h('td', { class: 'num' }, `${x.order}x`),
        h('td', { class: 'num' }, hb[i] ? withUnit(hb[i].amplitude_rad, 'rad') : '-'), h('td', { class: 'num' }, ha[i] ? withUnit(ha[i].amplitude_rad, 'rad') : '-')));
    }
  }
  const corr = c.correction;
  return h('section', { id: 'calibration' },
    h('h2', {}, 'Calibration: before and after'),
    h('p', {}, `Lane ${c.lane}: `, h('span', { id: 'calibration-status', class: verified ? 'ok' : 'error', 'data-status': c.status }, c.status),
      c.why ? ` — ${c.why}` : ''),
    h('ul', { id: 'calibration-captures' },
      h('li', { id: 'computed-on' }, `computed on the before pass: ${passText(c.computed_on)}`),
      h('li', { id: 'verified-on' }, `verified on the after pass: ${passText(c.verified_on)}`),
      corr ? h('li', { id: 'calibration-correction' }, `correction ${corr.path} (sha256 ${String(corr.sha256).slice(0, 16)}…): ${(corr.file.table_rad || []).length} entries${corr.file.lissajous ? ', Lissajous stage' : ''}, predicted residual ${withUnit(c.predicted_rms_rad, 'rad')} rms`) : '',
      h('li', { class: 'muted' }, c.limits || '')),
    scroller(h('table', { id: 'calibration-lanes', class: 'cards' },
      h('thead', {}, h('tr', {}, ['lane', 'error', 'rms before', 'rms after', 'max before', 'max after', 'per-sample CRB', 'after / CRB', 'predicted', 'correction'].map((t) => h('th', {}, t)))),
      h('tbody', {}, rows))),
    harm.length ? h('details', { id: 'calibration-harmonics' }, h('summary', {}, 'Error harmonics before and after'),
      scroller(h('table', {}, h('thead', {}, h('tr', {}, ['lane', 'order', 'before', 'after'].map((t) => h('th', {}, t)))), h('tbody', {}, harm)))) : '');
}
