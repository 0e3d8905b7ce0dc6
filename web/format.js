// Numbers for people: three significant digits, exponents for the very small and very large,
// counts as whole numbers, and the unit beside the value.

// 3 significant digits: 1.7e-5 stays 1.70e-5 (never 0), 0.0123 is 0.0123, 90000 samples is 90000.
export function sig(v, digits = 3) {
  if (v == null || typeof v !== 'number' || Number.isNaN(v)) return '-';
  if (!Number.isFinite(v)) return v > 0 ? '∞' : '-∞';
  if (v === 0) return '0';
  const a = Math.abs(v);
  if (Number.isInteger(v) && a < 1e7) return String(v);
  if (a >= 1e-2 && a < 1e5) return String(+v.toPrecision(digits));
  return v.toExponential(digits - 1);
}

// "1.70e-5 rad"; a unitless value alone.
export const withUnit = (v, unit) => (v == null || Number.isNaN(v) ? '-' : unit ? `${sig(v)} ${unit}` : sig(v));

// A limit as words: "≤ 1.00e-3 rad", "≥ 0.3", "0.1 … 0.2 rad", with its marginal band.
export function limitText(limit, unit) {
  if (!limit) return '-';
  const u = unit ? ` ${unit}` : '';
  const lo = limit.min, hi = limit.max;
  let s;
  if (lo != null && hi != null) s = `${sig(lo)} … ${sig(hi)}${u}`;
  else if (hi != null) s = `≤ ${sig(hi)}${u}`;
  else if (lo != null) s = `≥ ${sig(lo)}${u}`;
  else return '-';
  if (limit.marginal_fraction > 0) s += ` (marginal within ${sig(100 * limit.marginal_fraction)} %)`;
  return s;
}
