// Thin client for /api/v1. The bearer token lives in localStorage (this browser only).
const TOKEN_KEY = 'fringe.token';

export function token() { return localStorage.getItem(TOKEN_KEY) || ''; }
export function setToken(t) { if (t) localStorage.setItem(TOKEN_KEY, t); else localStorage.removeItem(TOKEN_KEY); }

export class ApiError extends Error {
  constructor(status, body) {
    const e = (body && body.error) || {};
    super(e.message || `HTTP ${status}`);
    this.status = status;
    this.code = e.code;
    this.field = e.field;
  }
}

async function call(method, path, body) {
  const headers = {};
  if (token()) headers.Authorization = `Bearer ${token()}`;
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const res = await fetch(`/api/v1/${path}`, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const text = await res.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = null; }
  if (!res.ok) throw new ApiError(res.status, data);
  return data;
}

export const get = (path) => call('GET', path);
export const post = (path, body) => call('POST', path, body);

// A file as the raw request body (POST captures): streamed by the browser, not JSON.
export async function upload(path, file) {
  const headers = {};
  if (token()) headers.Authorization = `Bearer ${token()}`;
  const res = await fetch(`/api/v1/${path}`, { method: 'POST', headers, body: file });
  const text = await res.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = null; }
  if (!res.ok) throw new ApiError(res.status, data);
  return data;
}

// Live progress of a run (server-sent events). onEvent(snapshot, isEnd); onError() when the
// stream cannot be opened or is lost (EventSource retries by itself); returns a closer.
export function follow(id, onEvent, onError) {
  const es = new EventSource(`/api/v1/runs/${encodeURIComponent(id)}/events`);
  const handle = (isEnd) => (ev) => {
    onEvent(JSON.parse(ev.data), isEnd);
    if (isEnd) es.close();
  };
  es.addEventListener('progress', handle(false));
  es.addEventListener('end', handle(true));
  if (onError) es.addEventListener('error', () => onError(es.readyState));
  return () => es.close();
}
