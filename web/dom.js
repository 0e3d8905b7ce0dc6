// Small DOM helpers shared by the pages.

export function h(tag, attrs = {}, ...children) {
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

// What a person should do about an API refusal, in words (the API's message stays for detail).
export function errorText(e) {
  if (e && (e.code === 'unauthorized' || e.status === 401 || e.code === 'no_token'))
    return 'This needs the API token. Paste it into the token box at the top of the page and press save: '
      + 'fringe serve printed it (and a link ending in #token=…) when it first started, and keeps it in DATA/token.';
  if (e && (e.code === 'forbidden' || e.status === 403) && e.code !== 'device_not_allowed')
    return 'The saved API token is not the one this service uses. Paste the token from DATA/token into the token box and press save.';
  return e && e.message ? e.message : String(e);
}

export const showError = (e) => h('p', { class: 'error', role: 'alert' }, e && e.field ? `${e.field}: ${errorText(e)}` : errorText(e));

// Wide tables scroll inside themselves on a narrow screen; the page does not.
export const scroller = (table) => h('div', { class: 'table-wrap' }, table);
