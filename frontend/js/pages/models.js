// Models browser: GET /api/models?domain=&agents=&walls=&min_reputation=&q=
// The filters live in the page URL (/models?agents=3), so a filtered view can be shared.

import { api, asList, query } from "../api.js";
import { clear, envSummary, errorView, h, link, num, shortAddr, shortCid } from "../dom.js";
import { PAGE_SIZE, offsetFromUrl, pager } from "../pager.js";

const FILTERS = [
  { name: "q", label: "Search", type: "search", placeholder: "words of the description, CID, owner or #id" },
  { name: "domain", label: "Domain", type: "number", min: 0, max: 255, placeholder: "any" },
  { name: "agents", label: "Agents", type: "number", min: 1, placeholder: "any" },
  { name: "walls", label: "Walls", type: "number", min: 0, placeholder: "any" },
  { name: "min_reputation", label: "Min reputation (0-1)", type: "number", min: 0, max: 1, step: "any", placeholder: "0" },
];

export function filtersFromUrl() {
  const p = new URLSearchParams(location.search);
  return Object.fromEntries(FILTERS.map((f) => [f.name, p.get(f.name) || ""]));
}

export async function render(main, _params, ctx) {
  document.title = "Models · DRLaaS";
  const values = filtersFromUrl();
  const results = h("div", { id: "models-results", class: "table-scroll" });
  const countEl = h("span", { class: "muted", id: "models-count" });
  let timer = null;
  let seq = 0;
  let offset = offsetFromUrl();
  let filtersSeen = null;

  const load = async () => {
    const mine = ++seq;
    const filters = Object.fromEntries(FILTERS.map((f) => [f.name, form.elements[f.name].value.trim()]));
    const key = JSON.stringify(filters);
    if (filtersSeen !== null && key !== filtersSeen) offset = 0; // new filters: first page
    filtersSeen = key;
    history.replaceState(null, "", `/models${query({ ...filters, offset: offset || "" })}`);
    results.setAttribute("aria-busy", "true");
    try {
      const { data, count } = asList(await api(`/models${query({ ...filters, limit: PAGE_SIZE, offset: offset || "" })}`,
        { signal: ctx.signal }));
      if (mine !== seq) return; // a newer filter answer is on its way
      clear(results).appendChild(table(data, Object.values(filters).some(Boolean)));
      results.appendChild(pager({ id: "models-pager", offset, shown: data.length, count,
        onPage: (next) => { offset = next; schedule(0); } }));
      countEl.textContent = `${count} model${count === 1 ? "" : "s"}`;
    } catch (err) {
      if (err.name === "AbortError" || mine !== seq) return;
      clear(results).appendChild(errorView(err, () => schedule(0)));
      countEl.textContent = "";
    } finally {
      if (mine === seq) results.removeAttribute("aria-busy");
    }
  };
  const schedule = (delay) => { clearTimeout(timer); timer = setTimeout(load, delay); };

  const form = h("form", { class: "filters", id: "model-filters", onsubmit: (e) => { e.preventDefault(); schedule(0); } },
    FILTERS.map((f) => h("label", {}, h("span", {}, f.label),
      h("input", { name: f.name, type: f.type, min: f.min, max: f.max, step: f.step, size: f.size,
        placeholder: f.placeholder, value: values[f.name],
        oninput: () => schedule(f.type === "search" ? 300 : 150) }))),
    h("button", { type: "button", class: "small", onclick: () => {
      FILTERS.forEach((f) => { form.elements[f.name].value = ""; });
      schedule(0);
    } }, "Clear"));

  main.appendChild(h("section", {},
    h("div", { class: "page-head" }, h("h1", {}, "Models"), countEl),
    h("p", { class: "muted" }, "Trained multi-agent models shared on the platform. Each is content-addressed: "
      + "its CID is on chain and every download is verified against it."),
    form, results));
  ctx.signal.addEventListener("abort", () => clearTimeout(timer));
  await load();
}

function table(models, filtered) {
  if (!models.length) {
    return h("p", { class: "empty", id: "no-models" }, filtered
      ? "No model matches these filters."
      : "No model shared yet: models appear here once workers share what they trained.");
  }
  return h("table", { class: "list", id: "models-table" },
    h("thead", {}, h("tr", {}, ["#", "Environment", "Domain", "Owner", "Reputation", "Rating", "Allocations", "CID"]
      .map((c) => h("th", {}, c)))),
    h("tbody", {}, models.map((m) => h("tr", { "data-model-id": m.id },
      h("td", {}, link(`/models/${encodeURIComponent(m.id)}`, `#${m.id}`)),
      h("td", {}, h("div", { class: "env" }, envSummary(m.env)),
        m.description ? h("div", { class: "desc muted", dir: "auto" }, m.description) : null),
      h("td", {}, m.domain ?? "—"),
      h("td", {}, shortAddr(m.owner)),
      h("td", { class: "num reputation" }, num(m.reputation, 3)),
      h("td", { class: "num" }, num(m.rating, 2)),
      h("td", { class: "num" }, num(m.allocations)),
      h("td", {}, shortCid(m.cid))))));
}
