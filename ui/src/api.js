// The /v1 client of the page: the same routes every client uses, a bearer token held in this module's memory only
// (never in a URL, a cookie or web storage: a reload forgets it), problem+json errors turned into ApiProblem.

let token = null;
const listeners = new Set();

export function setToken(value) {
  token = value || null;
  for (const f of listeners) f(token !== null);
}

export function hasToken() {
  return token !== null;
}

export function onTokenChange(f) {
  listeners.add(f);
}

export class ApiProblem extends Error {
  constructor(status, problem, path) {
    super(problem?.detail || problem?.title || `HTTP ${status}`);
    this.status = status;
    this.problem = problem ?? {};
    this.path = path;
  }
}

/** A person-readable explanation of a problem, for the page (what happened, what to do). */
export function explain(err) {
  if (!(err instanceof ApiProblem)) return `Something went wrong: ${err?.message ?? err}`;
  const p = err.problem;
  const detail = p.detail ? `: ${p.detail}` : '';
  if (err.status === 401) {
    return `The server did not accept the token (401 Unauthorized${detail}). Enter a valid token with “Token”.`;
  }
  if (err.status === 403) {
    const scope = p.required_scope ? `the “${p.required_scope}” scope` : 'a scope it lacks';
    return (
      `The server refused (403 Forbidden${detail}). This needs a token with ${scope}; ` +
      'the token you entered can only do less. Ask an administrator for such a token and enter it with “Token”.'
    );
  }
  if (err.status === 404) return `Not found (404${detail}).`;
  if (err.status === 429) return `Too many requests (429${detail}); try again in a moment.`;
  return `${p.title || 'Error'} (${err.status}${detail}).`;
}

async function request(method, path, { accept = 'application/json', body } = {}) {
  const headers = { Accept: accept };
  if (token) headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const response = await fetch(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
    cache: 'no-cache',
    credentials: 'omit',
  });
  if (!response.ok) {
    let problem = null;
    try {
      problem = await response.json();
    } catch {
      problem = { title: response.statusText };
    }
    throw new ApiProblem(response.status, problem, path);
  }
  return response;
}

export async function getJson(path) {
  return (await request('GET', path)).json();
}

/** JSON and the response (for headers such as Retry-After or Graspgen-Released). */
export async function getWithHeaders(path, method = 'GET') {
  const response = await request(method, path);
  return { body: method === 'HEAD' ? null : await response.json(), headers: response.headers };
}

export async function getBytes(path) {
  return (await request('GET', path, { accept: 'application/octet-stream, */*' })).arrayBuffer();
}

export async function postJson(path, body) {
  return (await request('POST', path, { body })).json();
}

/** Seconds to wait before polling again, from a Retry-After header (delta seconds), else `fallback`. */
export function retryAfter(headers, fallback = 2) {
  const v = Number(headers?.get?.('Retry-After'));
  return Number.isFinite(v) && v > 0 ? v : fallback;
}

export function q(params) {
  const parts = Object.entries(params)
    .filter(([, v]) => v !== undefined && v !== null && v !== '')
    .map(([k, v]) => `${encodeURIComponent(k)}=${encodeURIComponent(v)}`);
  return parts.length ? `?${parts.join('&')}` : '';
}

export const seg = encodeURIComponent;
