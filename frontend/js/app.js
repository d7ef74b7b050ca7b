// Client-side router, navigation and the sign-in bar. Each page module exports
// render(main, params, ctx); ctx.every(ms, fn) polls until the user navigates away (and not
// while the tab is hidden).

import { api, ApiError, getToken, setToken } from "./api.js";
import { clear, errorView, h, shortAddr } from "./dom.js";
import * as models from "./pages/models.js";
import * as model from "./pages/model.js";
import * as tasks from "./pages/tasks.js";
import * as task from "./pages/task.js";
import * as workers from "./pages/workers.js";
import * as submit from "./pages/submit.js";

const ROUTES = [
  [/^\/(models)?\/?$/, models, "models"],
  [/^\/models\/(\d+)\/?$/, model, "models"], // ids are whole numbers: /models/abc is no page
  [/^\/tasks\/?$/, tasks, "tasks"],
  [/^\/tasks\/(\d+)\/?$/, task, "tasks"],
  [/^\/workers\/?$/, workers, "workers"],
  [/^\/submit\/?$/, submit, "submit"],
];

let current = null; // {controller, timers}

function stopCurrent() {
  if (!current) return;
  current.controller.abort();
  current.timers.forEach(clearTimeout);
  current.stopped = true;
  current = null;
}

function makeContext() {
  const ctx = { controller: new AbortController(), timers: new Set(), paused: new Set(), stopped: false };
  ctx.signal = ctx.controller.signal;
  /** Draw the page again (a Retry button), unless the user has navigated away meanwhile. */
  ctx.retry = () => { if (current === ctx) route(); };
  /** Run fn now and then every ms after it settles (no overlapping requests), until navigation;
   * ms may be a function, asked after each run (a page slows down once its data is final).
   * While the browser tab is hidden nothing is fetched: the poll waits and runs again as soon
   * as the tab is shown (a page left open in a background tab costs the gateway nothing). */
  ctx.every = (ms, fn) => {
    const tick = async () => {
      if (ctx.stopped) return;
      if (document.hidden) { ctx.paused.add(tick); return; }
      try { await fn(); } catch (err) { if (err.name !== "AbortError") console.error(err); }
      if (!ctx.stopped) {
        const t = setTimeout(() => { ctx.timers.delete(t); tick(); }, typeof ms === "function" ? ms() : ms);
        ctx.timers.add(t);
      }
    };
    return tick();
  };
  return ctx;
}

document.addEventListener("visibilitychange", () => {
  if (document.hidden || !current) return;
  const waiting = [...current.paused];
  current.paused.clear();
  waiting.forEach((tick) => tick());
});

export function navigate(href, { replace = false } = {}) {
  if (replace) history.replaceState(null, "", href);
  else history.pushState(null, "", href);
  route();
}

async function route() {
  stopCurrent();
  const main = document.getElementById("main");
  const path = location.pathname;
  const match = ROUTES.map(([re, mod, section]) => [path.match(re), mod, section]).find(([m]) => m);
  document.querySelectorAll("#nav a").forEach((a) =>
    a.classList.toggle("active", Boolean(match) && a.dataset.section === match[2]));
  clear(main);
  if (!match) {
    main.appendChild(h("section", {}, h("h1", {}, "Not found"),
      h("p", {}, "No page at ", h("code", {}, path), ". ", h("a", { href: "/models", "data-link": true }, "Browse models"))));
    document.title = "Not found · DRLaaS";
    return;
  }
  const [m, mod] = match;
  const ctx = makeContext();
  current = ctx;
  // Until the page's first answer: a page waiting on a slow gateway was blank (up to the
  // 30 s a read may take, api.js), as if the UI were broken.
  const loading = h("p", { class: "muted loading", role: "status", id: "page-loading" }, "Loading…");
  main.appendChild(loading);
  try {
    await mod.render(main, m.slice(1).map((x) => (x === undefined ? x : decodeURIComponent(x))), ctx);
  } catch (err) {
    if (err.name === "AbortError" || ctx.stopped) return;
    main.appendChild(errorView(err, ctx.retry, match[2] === "tasks" ? { back: "/tasks", backLabel: "Browse tasks" } : {}));
  } finally {
    loading.remove();
  }
}

// ---------------------------------------------------------------- sign-in bar

let demoUsers = null; // null = not asked yet, [] = the gateway offers none

async function loadDemoUsers() {
  try {
    const answer = await api("/auth/demo-users", { auth: false });
    demoUsers = Array.isArray(answer) ? answer : (answer && answer.data) || [];
  } catch (err) {
    demoUsers = [];
    if (!(err instanceof ApiError) || ![404, 405, 403].includes(err.status)) console.warn(err);
  }
}

async function demoSignIn(user) {
  const answer = user.access_token
    ? user
    : await api("/auth/demo-token", { method: "POST", body: { name: user.name, address: user.address }, auth: false });
  setToken(answer.access_token);
}

function curlHelp() {
  const gw = location.origin;
  return h("div", {},
    h("p", {}, "This gateway signs nothing for you: sign in with your own Ethereum key (EIP-4361). ",
      "Ask for a message, sign it with personal_sign, exchange it for a token and paste the token here."),
    h("pre", { class: "mono", id: "curl-help" },
      `curl -s -X POST ${gw}/api/auth/nonce -H 'content-type: application/json' \\\n`
      + `     -d '{"address": "0xYOUR_ADDRESS"}'\n`
      + `# sign the returned "message" with your key (personal_sign), then:\n`
      + `curl -s -X POST ${gw}/api/auth/token -H 'content-type: application/json' \\\n`
      + `     -d '{"message": "<message>", "signature": "0x<65-byte signature>"}'\n`
      + `# -> {"access_token": "...", "address": "0x..."}`));
}

async function renderAuth() {
  const bar = document.getElementById("auth");
  const help = document.getElementById("auth-help");
  clear(bar);
  const token = getToken();
  if (token) {
    let who = h("span", { class: "muted" }, "checking token…");
    bar.appendChild(h("span", { class: "signed-in" }, "Signed in as ", who));
    bar.appendChild(h("button", { type: "button", class: "small", id: "sign-out", onclick: () => setToken("") }, "Sign out"));
    try {
      const me = await api("/auth/me");
      who.replaceWith(h("span", { id: "me" }, shortAddr(me.address)));
      document.body.dataset.address = me.address;
    } catch (err) {
      who.replaceWith(h("span", { class: "warn" }, err.status === 401 ? "token expired or invalid" : err.message));
      delete document.body.dataset.address;
    }
    help.hidden = true;
    return;
  }
  delete document.body.dataset.address;
  const input = h("input", { type: "text", id: "token-input", placeholder: "bearer token", "aria-label": "Bearer token", size: 18 });
  bar.appendChild(h("form", { class: "token-form", onsubmit: (e) => {
    e.preventDefault();
    if (input.value.trim()) setToken(input.value.trim());
  } }, input, h("button", { type: "submit", class: "small" }, "Use token")));
  if (demoUsers === null) await loadDemoUsers();
  if (demoUsers.length) {
    const select = h("select", { id: "demo-user", "aria-label": "Demo user" },
      demoUsers.map((u, i) => h("option", { value: String(i) }, u.name ? `${u.name}` : u.address)));
    const status = h("span", { class: "warn", id: "demo-error" });
    bar.appendChild(h("span", { class: "demo" }, select,
      h("button", { type: "button", class: "small primary", id: "demo-sign-in", onclick: async () => {
        status.textContent = "";
        try { await demoSignIn(demoUsers[Number(select.value)]); } catch (err) { status.textContent = err.message; }
      } }, "Demo sign-in"), status));
    help.hidden = true;
  } else {
    const toggle = h("button", { type: "button", class: "small link", id: "how-sign-in", onclick: () => {
      help.hidden = !help.hidden;
    } }, "How do I get a token?");
    bar.appendChild(toggle);
    clear(help).appendChild(curlHelp());
  }
}

// ---------------------------------------------------------------- start

document.addEventListener("click", (e) => {
  const a = e.target.closest && e.target.closest("a[data-link]");
  if (!a || e.defaultPrevented || e.button !== 0 || e.metaKey || e.ctrlKey || e.shiftKey || e.altKey) return;
  const url = new URL(a.href, location.href);
  if (url.origin !== location.origin) return;
  e.preventDefault();
  navigate(url.pathname + url.search);
});
window.addEventListener("popstate", route);
// Pages read who is signed in (document.body.dataset.address), so the bar settles first.
window.addEventListener("drlaas:auth", async () => { await renderAuth(); route(); });
window.addEventListener("DOMContentLoaded", async () => {
  try { await renderAuth(); } finally { route(); }
});
