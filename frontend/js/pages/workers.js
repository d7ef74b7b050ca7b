// Workers leaderboard: GET /api/workers?sort=reputation, ranked by reputation (then rating)
// on the client too, so the ranking never depends on the server's order.

import { api, asList, query } from "../api.js";
import { clear, errorBox, h, num, shortAddr, statusPill } from "../dom.js";
import { PAGE_SIZE, offsetFromUrl, pager } from "../pager.js";

const GPU = { 0: "none" };

export function rankWorkers(workers) {
  const key = (v) => (Number.isFinite(Number(v)) ? Number(v) : -Infinity);
  return [...workers].sort((a, b) => key(b.reputation) - key(a.reputation) || key(b.rating) - key(a.rating));
}

function capabilities(w) {
  const c = w.capabilities || w;
  const parts = [];
  if (c.cpu_cores !== undefined) parts.push(`${c.cpu_cores} CPU`);
  if (c.ram_gb !== undefined) parts.push(`${c.ram_gb} GB RAM`);
  if (c.gpu_series !== undefined && c.gpu_series !== null) parts.push(`GPU ${GPU[c.gpu_series] ?? c.gpu_series}`);
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
  const results = h("div", { id: "workers-results" });
  const countEl = h("span", { class: "muted" });
  const domain = h("input", { name: "domain", type: "text", size: 6, placeholder: "any", value: p.get("domain") || "" });
  const status = h("select", { name: "status", value: p.get("status") || "" },
    ["", "active", "idle"].map((s) => h("option", { value: s }, s || "any status")));

  let offset = offsetFromUrl();
  const load = async () => {
    const filters = { domain: domain.value.trim(), status: status.value };
    history.replaceState(null, "", `/workers${query({ ...filters, offset: offset || "" })}`);
    try {
      const { data, count } = asList(await api(
        `/workers${query({ ...filters, sort: "reputation", limit: PAGE_SIZE, offset: offset || "" })}`, { signal: ctx.signal }));
      countEl.textContent = `${count} worker${count === 1 ? "" : "s"}`;
      clear(results).appendChild(data.length ? table(rankWorkers(data), offset)
        : h("p", { class: "empty", id: "no-workers" }, "No worker matches."));
      results.appendChild(pager({ id: "workers-pager", offset, shown: data.length, count,
        onPage: (next) => { offset = next; load(); } }));
    } catch (err) {
      if (err.name !== "AbortError") clear(results).appendChild(errorBox(err));
    }
  };
  const refilter = () => { offset = 0; load(); };
  domain.addEventListener("change", refilter);
  status.addEventListener("change", refilter);

  main.appendChild(h("section", {},
    h("div", { class: "page-head" }, h("h1", {}, "Workers leaderboard"), countEl),
    h("p", { class: "muted" }, "Reputation and rating come from the chain (reviews of submitted outcomes); "
      + "recruitment offers tasks to the best QoS first."),
    h("form", { class: "filters", onsubmit: (e) => { e.preventDefault(); refilter(); } },
      h("label", {}, h("span", {}, "Domain"), domain), h("label", {}, h("span", {}, "Status"), status)),
    results));
  await load();
}

function table(workers, offset = 0) {
  return h("table", { class: "list", id: "workers-table" },
    h("thead", {}, h("tr", {}, ["Rank", "Worker", "Status", "Reputation", "Rating", "Capabilities", "Offers / accepted / completed"]
      .map((c) => h("th", {}, c)))),
    h("tbody", {}, workers.map((w, i) => h("tr", { "data-address": w.address },
      h("td", { class: "num rank" }, String(offset + i + 1)),
      h("td", {}, shortAddr(w.address)),
      h("td", {}, statusPill(w.status)),
      h("td", { class: "num reputation" }, num(w.reputation, 3)),
      h("td", { class: "num rating" }, num(w.rating, 2)),
      h("td", {}, capabilities(w)),
      h("td", { class: "num" }, counters(w))))));
}
