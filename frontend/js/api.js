// The gateway's REST API (/api, docs/platform.md) and the caller's bearer token.

const TOKEN_KEY = "drlaas.token";
const API = "/api";

/** An error answer, in one of the gateway's two shapes:
 *  422 {"detail": [{loc, msg, type}]}  -> issues
 *  4xx/5xx {"detail": {rule, msg}}     -> rule, msg (and tx for 409 sign_locally) */
export class ApiError extends Error {
  constructor(status, body, fallback) {
    const detail = body && body.detail;
    let message = fallback;
    let issues = [];
    let rule = null;
    if (Array.isArray(detail)) {
      issues = detail;
      message = detail.map((d) => `${(d.loc || []).filter((p) => p !== "body").join(".")}: ${d.msg}`).join("; ");
    } else if (detail && typeof detail === "object") {
      rule = detail.rule || null;
      message = detail.msg || rule || fallback;
    } else if (typeof detail === "string") {
      message = detail;
    }
    super(message || `HTTP ${status}`);
    this.status = status;
    this.rule = rule;
    this.issues = issues;
    this.body = body;
  }
}

export function getToken() {
  try { return localStorage.getItem(TOKEN_KEY) || ""; } catch { return ""; }
}

export function setToken(token) {
  try {
    if (token) localStorage.setItem(TOKEN_KEY, token);
    else localStorage.removeItem(TOKEN_KEY);
  } catch { /* storage disabled: the token lives for this page only */ }
  window.dispatchEvent(new CustomEvent("drlaas:auth"));
}

/** Query string from an object, dropping empty values. */
export function query(params) {
  const q = new URLSearchParams();
  for (const [k, v] of Object.entries(params || {})) {
    if (v !== undefined && v !== null && v !== "") q.set(k, String(v));
  }
  const text = q.toString();
  return text ? `?${text}` : "";
}

/** How long a request may take, answer body included. A gateway that accepted the connection
 *  and never answered left a page "loading" for ever, and a polling page stopped polling (each
 *  poll waits for the one before): now it is an error the page shows, with a retry. */
export const TIMEOUT_MS = 30000;

/** fetch JSON from /api; throws ApiError on a non-2xx answer, on no answer and on no answer
 *  within timeoutMs (status 0; reads only by default: a write given up on may still land on
 *  chain, and a retry would pay twice). rawBody: JSON text sent as is. An abort of `signal`
 *  (the user navigated away) is thrown as the AbortError it is. */
export async function api(path, { method = "GET", body, rawBody, signal, auth = true, timeoutMs } = {}) {
  if (timeoutMs === undefined) timeoutMs = method === "GET" ? TIMEOUT_MS : 0;
  const headers = { Accept: "application/json" };
  const payload = rawBody !== undefined ? rawBody : (body === undefined ? undefined : JSON.stringify(body));
  if (payload !== undefined) headers["Content-Type"] = "application/json";
  const token = getToken();
  if (auth && token) headers.Authorization = `Bearer ${token}`;
  const own = new AbortController();
  let timedOut = false;
  const onAbort = () => own.abort();
  if (signal) {
    if (signal.aborted) own.abort();
    else signal.addEventListener("abort", onAbort, { once: true });
  }
  const timer = timeoutMs > 0 ? setTimeout(() => { timedOut = true; own.abort(); }, timeoutMs) : null;
  let res;
  let text;
  try {
    res = await fetch(API + path, { method, headers, signal: own.signal, body: payload });
    text = await res.text();
  } catch (err) {
    if (timedOut) {
      throw new ApiError(0, null, `the gateway did not answer within ${Math.round(timeoutMs / 1000)} s (${method} ${API}${path})`);
    }
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, null, `the gateway did not answer (${method} ${API}${path})`);
  } finally {
    clearTimeout(timer);
    if (signal) signal.removeEventListener("abort", onAbort);
  }
  let data = null;
  if (text) {
    try { data = JSON.parse(text); } catch { data = { detail: text.slice(0, 300) }; }
  }
  if (!res.ok) throw new ApiError(res.status, data, `${method} ${API}${path}: HTTP ${res.status}`);
  return data;
}

/** A list answer {data, count} (or a bare array from an older server) -> {data, count}. */
export function asList(answer) {
  if (Array.isArray(answer)) return { data: answer, count: answer.length };
  const data = (answer && Array.isArray(answer.data)) ? answer.data : [];
  return { data, count: answer && Number.isFinite(answer.count) ? answer.count : data.length };
}

export const API_BASE = API;
