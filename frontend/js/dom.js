// Small DOM and formatting helpers. Data from the API is only ever inserted as text (never
// innerHTML): model descriptions and task specs are user content.

/** map[key] if map has that key of its own, else fallback: a name from the data ("constructor",
 *  "toString") must not find Object's members (a baseline named "constructor" was labelled
 *  "function Object() { [native code] }"). */
export function own(map, key, fallback) {
  return Object.hasOwn(map, String(key)) ? map[key] : fallback;
}

/** h("a", {href: "/x", class: "c", onclick: fn}, "text", child, [more]) -> Element */
export function h(tag, attrs = {}, ...children) {
  const el = document.createElementNS(
    attrs && attrs.svg ? "http://www.w3.org/2000/svg" : "http://www.w3.org/1999/xhtml", tag);
  let late = null; // value/checked are set after the children (a <select> needs its options)
  for (const [key, value] of Object.entries(attrs || {})) {
    if (key === "svg" || value === undefined || value === null || value === false) continue;
    if (key.startsWith("on") && typeof value === "function") {
      el.addEventListener(key.slice(2), value);
    } else if (key === "dataset") {
      Object.assign(el.dataset, value);
    } else if (key === "style") {
      el.style.cssText = String(value); // the CSSOM: the gateway's policy refuses style attributes
    } else if ((key === "value" || key === "checked") && key in el) {
      (late ||= {})[key] = value;
    } else {
      el.setAttribute(key, value === true ? "" : String(value));
    }
  }
  append(el, children);
  if (late) Object.assign(el, late);
  return el;
}

function append(el, children) {
  for (const child of children) {
    if (child === undefined || child === null || child === false) continue;
    if (Array.isArray(child)) append(el, child);
    else if (child instanceof Node) el.appendChild(child);
    else el.appendChild(document.createTextNode(String(child)));
  }
}

/** SVG element shorthand. */
export function s(tag, attrs = {}, ...children) {
  return h(tag, { ...attrs, svg: true }, ...children);
}

export function clear(el) {
  while (el.firstChild) el.removeChild(el.firstChild);
  return el;
}

/** An internal link handled by the client router. */
export function link(href, ...children) {
  return h("a", { href, "data-link": true }, ...children);
}

/** 0x1234…abcd with the full address as tooltip. */
export function shortAddr(addr) {
  if (!addr || typeof addr !== "string") return h("span", { class: "muted" }, "—");
  const text = addr.length > 14 ? `${addr.slice(0, 6)}…${addr.slice(-4)}` : addr;
  return h("span", { class: "addr mono", title: addr }, text);
}

/** Same for a CID: keep enough to recognise it, full value on hover and in a copyable field. */
export function shortCid(cid) {
  if (!cid) return h("span", { class: "muted" }, "—");
  const text = cid.length > 20 ? `${cid.slice(0, 10)}…${cid.slice(-6)}` : cid;
  return h("span", { class: "cid mono", title: cid }, text);
}

/** A "Copy" button putting text on the clipboard (where the browser refuses: says to select it). */
export function copyButton(text) {
  return h("button", { type: "button", class: "small", onclick: async (e) => {
    try { await navigator.clipboard.writeText(text); e.target.textContent = "Copied"; }
    catch { e.target.textContent = "Select and copy"; }
  } }, "Copy");
}

export function num(value, digits = 2) {
  if (value === undefined || value === null || value === "") return "—";
  const n = Number(value);
  if (!Number.isFinite(n)) return String(value);
  if (Number.isInteger(n)) return n.toLocaleString("en-US");
  return n.toLocaleString("en-US", { maximumFractionDigits: digits });
}

const WEI_PER_ETH = 10n ** 18n;

/** wei (string|number|bigint) -> "0.05 ETH" without floating-point loss. */
export function formatWei(wei) {
  if (wei === undefined || wei === null || wei === "") return "—";
  let v;
  try { v = BigInt(wei); } catch { return String(wei); }
  const neg = v < 0n; if (neg) v = -v;
  const whole = v / WEI_PER_ETH;
  let frac = (v % WEI_PER_ETH).toString().padStart(18, "0").replace(/0+$/, "");
  return `${neg ? "-" : ""}${whole}${frac ? "." + frac : ""} ETH`;
}

/** "0.05" ETH (decimal string) -> wei as a decimal string; throws Error with a readable msg. */
export function ethToWei(text) {
  const t = String(text).trim();
  if (!/^\d+(\.\d+)?$/.test(t)) throw new Error("enter an amount like 0.01");
  const [whole, frac = ""] = t.split(".");
  if (frac.length > 18) throw new Error("at most 18 decimals (1 wei)");
  return (BigInt(whole) * WEI_PER_ETH + BigInt(frac.padEnd(18, "0"))).toString();
}

/** ISO date or unix seconds (a number or a string of digits) -> local "2025-01-02 13:04:05";
 *  {utc: true}: the same in UTC, marked "UTC". */
export function formatTime(t, { utc = false } = {}) {
  if (t === undefined || t === null || t === "") return "—";
  const seconds = typeof t === "number" || (typeof t === "string" && /^\d+$/.test(t));
  const d = seconds ? new Date(Number(t) * 1000) : new Date(t);
  if (Number.isNaN(d.getTime())) return String(t);
  const pad = (x) => String(x).padStart(2, "0");
  const [y, mo, day, hh, mi, ss] = utc
    ? [d.getUTCFullYear(), d.getUTCMonth(), d.getUTCDate(), d.getUTCHours(), d.getUTCMinutes(), d.getUTCSeconds()]
    : [d.getFullYear(), d.getMonth(), d.getDate(), d.getHours(), d.getMinutes(), d.getSeconds()];
  return `${y}-${pad(mo + 1)}-${pad(day)} ${pad(hh)}:${pad(mi)}:${pad(ss)}${utc ? " UTC" : ""}`;
}

/** A status pill; the class lets CSS colour it (open, completed, cancelled, ...). */
export function statusPill(status) {
  const text = status === undefined || status === null ? "unknown" : String(status);
  return h("span", { class: `pill status-${text.toLowerCase().replace(/[^a-z0-9]+/g, "-")}` }, text);
}

/** One-line summary of an environment spec dict (or the raw value if it is not one). */
export function envSummary(env) {
  if (Array.isArray(env) && env.length >= 6) {
    // The chain's env vector (backend.services.specs.env_attributes).
    const [rows, cols, agents, moves, walls0, walls1] = env;
    return envSummary({ rows, cols, agents, moves, walls: [walls0, walls1] });
  }
  if (!env || typeof env !== "object" || Array.isArray(env)) {
    return env === undefined || env === null ? "—" : JSON.stringify(env);
  }
  const parts = [];
  if (env.agents !== undefined) parts.push(`${env.agents} agent${env.agents === 1 ? "" : "s"}`);
  if (env.rows !== undefined && env.cols !== undefined) parts.push(`${env.rows}×${env.cols}`);
  if (Array.isArray(env.walls)) {
    const [lo, hi] = env.walls;
    parts.push(lo === hi ? `${lo} wall${lo === 1 ? "" : "s"}` : `${lo}–${hi} walls`);
  } else if (env.walls !== undefined) {
    parts.push(`${env.walls} walls`);
  }
  if (env.moves !== undefined) parts.push(`${env.moves} moves`);
  if (env.intensity && typeof env.intensity === "object" && Array.isArray(env.intensity.values)) {
    const sep = own({ fixed: "", choice: ",", uniform: ":" }, env.intensity.kind, ",");
    parts.push(`I=${env.intensity.values.map((v) => Number(v).toExponential(0).replace("e+", "e")).join(sep)}`);
  }
  return parts.join(" · ") || JSON.stringify(env);
}

/** A <dl> from [label, value] pairs; values may be nodes. Pairs with undefined values are skipped. */
export function defList(pairs, cls = "kv") {
  return h("dl", { class: cls }, pairs
    .filter(([, v]) => v !== undefined)
    .map(([k, v]) => [h("dt", {}, k), h("dd", {}, v === null ? "—" : v)]));
}

/** A <details> with pretty JSON, for fields the page does not lay out itself. */
export function rawJson(title, value) {
  return h("details", { class: "raw" }, h("summary", {}, title),
    h("pre", { class: "mono" }, JSON.stringify(value, null, 2)));
}

export function errorBox(err) {
  return h("div", { class: "error-box", role: "alert" }, err && err.message ? err.message : String(err));
}

/** What a page shows when its data could not be read: a 404 is a "Not found" view (heading,
 *  the gateway's message, a way back); any other failure (5xx, no answer, a timeout) says so
 *  with a Retry button calling retry(). A bare message on an empty page read as a broken UI. */
export function errorView(err, retry, { back = "/models", backLabel = "Browse models" } = {}) {
  if (err && err.status === 404) {
    return h("section", { class: "not-found" }, h("h1", {}, "Not found"), errorBox(err),
      h("p", {}, link(back, backLabel)));
  }
  return h("section", { class: "load-failed" }, errorBox(err),
    retry ? h("button", { type: "button", class: "small retry", onclick: retry }, "Retry") : null);
}
