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

/** fetch JSON from /api; throws ApiError on a non-2xx answer. rawBody: JSON text sent as is. */
export async function api(path, { method = "GET", body, rawBody, signal, auth = true } = {}) {
  const headers = { Accept: "application/json" };
  const payload = rawBody !== undefined ? rawBody : (body === undefined ? undefined : JSON.stringify(body));
  if (payload !== undefined) headers["Content-Type"] = "application/json";
  const token = getToken();
  if (auth && token) headers.Authorization = `Bearer ${token}`;
  let res;
  try {
    res = await fetch(API + path, {
      method, headers, signal, body: payload,
    });
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, null, `the gateway did not answer (${method} ${API}${path})`);
  }
  const text = await res.text();
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
