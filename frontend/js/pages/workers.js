// Workers leaderboard: GET /api/workers?sort=reputation, ranked by reputation (then rating)
// on the client too, so the ranking never depends on the server's order; polled every 2 s like
// the task pages (app.js ctx.every), rows replaced in place only when their data changed.

import { api, asList, query } from "../api.js";
import { clear, errorBox, h, num, own, shortAddr, statusPill } from "../dom.js";
import { PAGE_SIZE, offsetFromUrl, pager } from "../pager.js";
import { POLL_MS } from "./tasks.js";

const GPU = { 0: "none" };
/** A worker's domains are bits of a 48-bit mask on the UMC (backend.chain.platform.MAX_DOMAIN). */
export const MAX_DOMAIN = 47;
const domainOk = (v) => v === "" || (/^\d{1,2}$/.test(v) && Number(v) <= MAX_DOMAIN);

export function rankWorkers(workers) {
  const key = (v) => (Number.isFinite(Number(v)) ? Number(v) : -Infinity);
  return [...workers].sort((a, b) => key(b.reputation) - key(a.reputation) || key(b.rating) - key(a.rating));
}

function capabilities(w) {
  const c = w.capabilities || w;
  const parts = [];
  if (c.cpu_cores !== undefined) parts.push(`${c.cpu_cores} CPU`);
  if (c.ram_gb !== undefined) parts.push(`${c.ram_gb} GB RAM`);
  if (c.gpu_series !== undefined && c.gpu_series !== null) parts.push(`GPU ${own(GPU, c.gpu_series, c.gpu_series)}`);
  const domains = c.domains ?? w.domains;
  return h("span", {}, parts.join(" · ") || "—",
    Array.isArray(domains) && domains.length ? h("div", { class: "muted" }, `domains ${domains.join(", ")}`) : null);
}

function counters(w) {
  const c = w.counters || {};
  const pick = (...ks) => ks.map((k) => c[k]).find((v) => v !== undefined);
  const assigned = pick("assigned", "offered");
  const accepted = pick("accepted");
  const completed = pick("completed");
  if ([assigned, accepted, completed].every((v) => v === undefined)) return "—";
  return `${num(assigned)} / ${num(accepted)} / ${num(completed)}`;
}

export async function render(main, _params, ctx) {
  document.title = "Workers · DRLaaS";
  const p = new URLSearchParams(location.search);
  const results = h("div", { id: "workers-results", class: "table-scroll" });
  const pages = h("div", { id: "workers-pages" });
  const countEl = h("span", { class: "muted" });
  const updated = h("span", { class: "muted", id: "workers-updated" });
  const domainError = h("small", { class: "field-error", id: "workers-domain-error", role: "alert" });
  const domain = h("input", { name: "domain", type: "text", inputmode: "numeric", size: 6, placeholder: "any",
    value: p.get("domain") || "", "aria-describedby": "workers-domain-error" });
  // A domain that is not one (a typo, an old link's "abc") was sent as is: the gateway's 422 was
  // asked for again on every 2 s poll. It is now said next to the field and not applied.
  const checkDomain = () => {
    const ok = domainOk(domain.value.trim());
    domainError.textContent = ok ? "" : `a domain is a whole number 0-${MAX_DOMAIN}; not applied`;
    if (ok) domain.removeAttribute("aria-invalid"); else domain.setAttribute("aria-invalid", "true");
    return ok;
  };
  const status = h("select", { name: "status", value: p.get("status") || "" },
    ["", "active", "idle"].map((s) => h("option", { value: s }, s || "any status")));

  // The filters applied (a half-typed domain is not), the page shown and the table's rows live
  // across polls: a poll replaces only the rows whose data changed (scroll, focus and page stay).
  let filters = { domain: checkDomain() ? domain.value.trim() : "", status: status.value };
  let offset = offsetFromUrl();
  let tbody = null;
  let pagerKey = null;
  let seq = 0;
  const load = async () => {
    const mine = ++seq;
    const url = `/workers${query({ ...filters, offset: offset || "" })}`;
    if (location.pathname + location.search !== url) history.replaceState(null, "", url);
    try {
      const { data, count } = asList(await api(
        `/workers${query({ ...filters, sort: "reputation", limit: PAGE_SIZE, offset: offset || "" })}`, { signal: ctx.signal }));
      if (mine !== seq) return; // a newer filter or page answer is on its way
      countEl.textContent = `${count} worker${count === 1 ? "" : "s"}`;
      update(rankWorkers(data));
      const key = JSON.stringify([offset, data.length, count]);
      if (key !== pagerKey) {
        pagerKey = key;
        clear(pages).appendChild(pager({ id: "workers-pager", offset, shown: data.length, count,
          onPage: (next) => { offset = next; load(); } }));
      }
      updated.textContent = `live · updated ${new Date().toLocaleTimeString("en-GB")}`;
      updated.classList.remove("warn");
    } catch (err) {
      if (err.name === "AbortError" || mine !== seq) return;
      if (!tbody) clear(results).appendChild(errorBox(err));
      updated.textContent = `update failed: ${err.message}`;
      updated.classList.add("warn");
    }
  };

  function update(workers) {
    if (!workers.length) {
      tbody = null;
      clear(results).appendChild(h("p", { class: "empty", id: "no-workers" }, "No worker matches."));
      return;
    }
    if (!tbody) {
      tbody = h("tbody");
      clear(results).appendChild(h("table", { class: "list", id: "workers-table" }, tableHead(), tbody));
    }
    const old = new Map([...tbody.children].map((tr) => [tr.dataset.address, tr]));
    const rows = workers.map((w, i) => {
      const key = JSON.stringify([offset + i, w]);
      const prev = old.get(String(w.address));
      if (prev && prev.dataset.key === key) return prev;
      const tr = row(w, offset + i + 1);
      tr.dataset.key = key;
      if (prev) tr.classList.add("changed");
      return tr;
    });
    rows.forEach((tr, i) => { if (tbody.children[i] !== tr) tbody.insertBefore(tr, tbody.children[i] || null); });
    while (tbody.children.length > rows.length) tbody.lastChild.remove();
  }

  const refilter = () => {
    filters = { domain: checkDomain() ? domain.value.trim() : filters.domain, status: status.value };
    offset = 0;
    load();
  };
  domain.addEventListener("change", refilter);
  status.addEventListener("change", refilter);

  main.appendChild(h("section", {},
    h("div", { class: "page-head" }, h("h1", {}, "Workers leaderboard"), countEl, updated),
    h("p", { class: "muted" }, "Reputation and rating come from the chain (the requesters' reviews of submitted "
      + "results); new tasks are offered first to the best-matching workers."),
    h("form", { class: "filters", onsubmit: (e) => { e.preventDefault(); refilter(); } },
      h("label", {}, h("span", {}, "Domain"), domain), h("label", {}, h("span", {}, "Status"), status), domainError),
    results, pages));
  await ctx.every(POLL_MS, load); // live, like the task pages; stops when the user navigates away
}

function tableHead() {
  return h("thead", {}, h("tr", {}, ["Rank", "Worker", "Status", "Reputation", "Rating", "Capabilities", "Offers / accepted / completed"]
    .map((c) => h("th", {}, c))));
}

function row(w, rank) {
  return h("tr", { "data-address": w.address },
    h("td", { class: "num rank" }, String(rank)),
    h("td", {}, shortAddr(w.address)),
    h("td", {}, statusPill(w.status)),
    h("td", { class: "num reputation" }, num(w.reputation, 3)),
    h("td", { class: "num rating" }, num(w.rating, 2)),
    h("td", {}, capabilities(w)),
    h("td", { class: "num" }, counters(w)));
}
