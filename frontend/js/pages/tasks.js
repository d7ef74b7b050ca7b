// Tasks with live status: GET /api/tasks?status=&requester= polled every 2 s; rows whose data
// changed are replaced in place (and flash), the rest are left alone.

import { api, asList, query } from "../api.js";
import {
  clear, envSummary, errorBox, formatTime, formatWei, h, link, shortAddr, shortCid, statusPill,
} from "../dom.js";
import { PAGE_SIZE, offsetFromUrl, pager } from "../pager.js";

export const POLL_MS = 2000;
const STATUSES = ["", "open", "completed", "cancelled", "closed"];

function taskEnv(t) {
  return t.env || (t.spec && t.spec.env);
}

function count(v) {
  return Array.isArray(v) ? v.length : v;
}

/** Task spec CID: TaskPublic.description holds it (the on-chain description). */
export function specCid(t) {
  return t.spec_cid ?? t.description;
}

/** "10×10 · 3 agents · 0 walls · 4 moves · I=1e9" (grid first: what a task list is scanned for). */
export function taskEnvSummary(env) {
  const { rows, cols, ...rest } = env;
  const tail = envSummary(rest);
  return rows !== undefined && cols !== undefined ? `${rows}×${cols} · ${tail}` : tail;
}

function row(t) {
  const offered = count(t.offered);
  const env = taskEnv(t);
  return h("tr", { "data-task-id": t.id, "data-status": t.status },
    h("td", {}, link(`/tasks/${encodeURIComponent(t.id)}`, `#${t.id}`)),
    h("td", { class: "status" }, statusPill(t.status)),
    h("td", { class: "env" }, env ? taskEnvSummary(env)
      : h("span", { class: "muted", title: "the description is not a readable task spec" }, "spec ", shortCid(specCid(t)))),
    h("td", {}, shortAddr(t.requester)),
    h("td", { class: "num" }, offered !== undefined ? `${offered} / ${t.num_workers ?? "—"}` : (t.num_workers ?? "—")),
    h("td", { class: "num reward", title: t.reward_wei ? `${t.reward_wei} wei` : undefined },
      t.reward_eth ? `${t.reward_eth} ETH` : formatWei(t.reward_wei ?? t.payment_wei)),
    // UTC, marked, as on the task page: a local time without its zone read as another deadline
    h("td", { class: "deadline" }, formatTime(t.deadline ?? t.created_at, { utc: true })));
}

export async function render(main, _params, ctx) {
  document.title = "Tasks · DRLaaS";
  const p = new URLSearchParams(location.search);
  const me = document.body.dataset.address || "";
  const status = h("select", { name: "status", id: "task-status-filter", value: p.get("status") || "" },
    STATUSES.map((st) => h("option", { value: st }, st || "any status")));
  const mine = h("input", { type: "checkbox", name: "mine", id: "task-mine", checked: p.get("mine") === "1", disabled: !me });
  const updated = h("span", { class: "muted", id: "tasks-updated" });
  const body = h("div", { id: "tasks-results", class: "table-scroll" });
  let tbody = null;

  const pages = h("div", { id: "tasks-pages" });
  let offset = offsetFromUrl();
  const params = () => ({ status: status.value, requester: mine.checked && me ? me : "",
    limit: PAGE_SIZE, offset: offset || "" });
  const refresh = async () => {
    const urlParams = { status: status.value, mine: mine.checked ? "1" : "", offset: offset || "" };
    history.replaceState(null, "", `/tasks${query(urlParams)}`);
    try {
      const { data, count } = asList(await api(`/tasks${query(params())}`, { signal: ctx.signal }));
      update(data);
      clear(pages).appendChild(pager({ id: "tasks-pager", offset, shown: data.length, count,
        onPage: (next) => { offset = next; tbody = null; refresh(); } }));
      updated.textContent = `live · updated ${new Date().toLocaleTimeString("en-GB")}`;
      updated.classList.remove("warn");
    } catch (err) {
      if (err.name === "AbortError") throw err;
      if (!tbody) clear(body).appendChild(errorBox(err));
      updated.textContent = `update failed: ${err.message}`;
      updated.classList.add("warn");
    }
  };

  function update(tasks) {
    if (!tasks.length) { tbody = null; clear(body).appendChild(h("p", { class: "empty", id: "no-tasks" }, "No tasks yet.")); return; }
    if (!tbody) {
      tbody = h("tbody");
      clear(body).appendChild(h("table", { class: "list", id: "tasks-table" },
        h("thead", {}, h("tr", {}, ["#", "Status", "Environment", "Requester", "Offered / workers", "Reward / worker", "Deadline"]
          .map((c) => h("th", {}, c)))), tbody));
    }
    const old = new Map([...tbody.children].map((tr) => [tr.dataset.taskId, tr]));
    const rows = tasks.map((t) => {
      const key = JSON.stringify(t);
      const prev = old.get(String(t.id));
      if (prev && prev.dataset.key === key) return prev;
      const tr = row(t);
      tr.dataset.key = key;
      if (prev) tr.classList.add("changed");
      return tr;
    });
    rows.forEach((tr, i) => { if (tbody.children[i] !== tr) tbody.insertBefore(tr, tbody.children[i] || null); });
    while (tbody.children.length > rows.length) tbody.lastChild.remove();
  }

  const restart = () => { tbody = null; offset = 0; refresh(); };
  status.addEventListener("change", restart);
  mine.addEventListener("change", restart);

  main.appendChild(h("section", {},
    h("div", { class: "page-head" }, h("h1", {}, "Tasks"), updated),
    h("div", { class: "filters" },
      h("label", {}, h("span", {}, "Status"), status),
      h("label", { class: "inline", title: me ? "" : "sign in to filter your own tasks" }, mine, h("span", {}, "Only mine")),
      link("/submit", "Submit a task →")),
    body, pages));
  await ctx.every(POLL_MS, refresh);
}
