// One model: GET /api/models/{id} -> card (model.json), metrics curve, owner reputation, CID.

import { api, API_BASE } from "../api.js";
import { curvePanels } from "../chart.js";
import { defList, envSummary, h, link, num, rawJson, shortAddr, formatTime } from "../dom.js";

/** The curve points of a model detail, wherever the gateway put them. */
export function modelCurve(m) {
  for (const src of [m.curve, m.metrics, m.card && m.card.metrics]) {
    if (Array.isArray(src)) return src;
    if (!src || typeof src !== "object") continue;
    if (Array.isArray(src.curve)) return src.curve;
    // Columns: {global_step: [...], success: [...]} -> rows.
    const cols = Object.entries(src).filter(([, v]) => Array.isArray(v));
    if (cols.length >= 2 && cols.every(([, v]) => v.length === cols[0][1].length)) {
      return cols[0][1].map((_, i) => Object.fromEntries(cols.map(([k, v]) => [k, v[i]])));
    }
  }
  return [];
}

function ownerReputation(m) {
  if (m.owner_reputation !== undefined) return m.owner_reputation;
  if (m.owner && typeof m.owner === "object") return m.owner.reputation;
  return undefined;
}

function ownerAddress(m) {
  return m.owner && typeof m.owner === "object" ? m.owner.address : m.owner;
}

function copyButton(text) {
  return h("button", { type: "button", class: "small", onclick: async (e) => {
    try { await navigator.clipboard.writeText(text); e.target.textContent = "Copied"; }
    catch { e.target.textContent = "Select and copy"; }
  } }, "Copy");
}

export async function render(main, [id], ctx) {
  document.title = `Model #${id} · DRLaaS`;
  const m = await api(`/models/${encodeURIComponent(id)}`, { signal: ctx.signal });
  const card = m.card || {};
  const env = card.env || m.env;
  const base = `${API_BASE}/models/${encodeURIComponent(m.id ?? id)}/download`;
  const finalMetrics = card.metrics && typeof card.metrics === "object" && !Array.isArray(card.metrics)
    ? Object.entries(card.metrics).filter(([k, v]) => k !== "curve" && (typeof v === "number" || typeof v === "string"))
    : [];
  const arch = card.architecture || {};
  const obs = card.observation || {};
  const actions = card.action_space || {};
  const training = card.training || {};
  const curve = modelCurve(m);

  main.appendChild(h("section", { id: "model-page", "data-model-id": m.id ?? id },
    h("p", { class: "crumbs" }, link("/models", "Models"), " / ", `#${m.id ?? id}`),
    h("div", { class: "page-head" },
      h("h1", {}, `${card.model || obs.kind?.toUpperCase() || "Model"} · ${envSummary(env)}`)),
    m.description ? h("p", { class: "lead", id: "model-description" }, m.description) : null,

    h("div", { class: "cid-row" }, h("span", { class: "label" }, "CID"),
      h("code", { class: "mono", id: "model-cid" }, m.cid || "—"), m.cid ? copyButton(m.cid) : null),
    h("div", { class: "downloads", id: "downloads" },
      h("a", { href: `${base}?file=model.safetensors`, download: "model.safetensors", class: "button" }, "Download weights (model.safetensors)"),
      h("a", { href: `${base}?file=model.json`, download: "model.json", class: "button" }, "Download card (model.json)")),

    h("div", { class: "grid2" },
      h("div", { class: "panel" }, h("h2", {}, "On chain"), defList([
        ["Owner", shortAddr(ownerAddress(m))],
        ["Owner reputation", h("span", { id: "owner-reputation" }, num(ownerReputation(m), 3))],
        ["Model reputation", num(m.reputation, 3)],
        ["Environment (on chain)", Array.isArray(m.env) ? h("code", { class: "mono" }, `[${m.env.join(", ")}]`) : undefined],
        ["Owner rating", m.owner_rating !== undefined ? num(m.owner_rating, 3) : undefined],
        ["Rating", num(m.rating, 3)],
        ["Allocations", num(m.allocations)],
        ["Domain", m.domain ?? "—"],
      ])),
      h("div", { class: "panel", id: "model-card" }, h("h2", {}, "Card"), defList([
        ["Format", card.format],
        ["Created", card.created ? formatTime(card.created) : undefined],
        ["Observation", obs.kind ? `${obs.kind.toUpperCase()}${obs.window ? `, window ${obs.window}` : ""}` : undefined],
        ["Environment", env ? envSummary(env) : undefined],
        ["Grid area", env && env.area_m ? `${env.area_m.join(" × ")} m` : undefined],
        ["Reward", env && env.reward],
        ["Max steps", env && env.max_steps],
        ["Actions", actions.per_agent_actions !== undefined ? `${actions.per_agent_actions} per agent${actions.joint ? " (joint)" : ""}` : undefined],
        ["Parameters", arch.total_parameters !== undefined ? `${num(arch.total_parameters)} (actor ${num(arch.actor_parameters)}, critic ${num(arch.critic_parameters)})` : undefined],
        ["Trained for", training.env_steps !== undefined ? `${num(training.env_steps)} steps, ${num(training.updates)} updates, ${num(training.wall_time_s, 1)} s` : undefined],
        ["Code", card.code ? (typeof card.code === "object" ? (card.code.version || card.code.commit || JSON.stringify(card.code)) : card.code) : undefined],
      ]))),

    h("div", { class: "panel" }, h("h2", {}, "Training curve"),
      h("div", { class: "charts", id: "model-curve" },
        curve.length ? curvePanels(curve) : h("p", { class: "muted" }, "This model's card has no curve points.")),
      finalMetrics.length ? h("div", {}, h("h3", {}, "Final metrics"),
        defList(finalMetrics.map(([k, v]) => [k, num(v, 4)]), "kv compact")) : null),

    Object.keys(card).length ? rawJson("Full card (model.json)", card) : null));
}
