// One model, as a model hub shows it: GET /api/models/{id} -> header (name, description, owner,
// domain), provenance (the producing task from the chain's outcome record, the experts it
// learned from), the training curve and the held-out figures of its card (validated by the
// gateway, section by section), and chain values in human units (reputation and QoS as
// fractions, prices in ETH). Every string from the API is inserted as text (dom.js).

import { api, API_BASE } from "../api.js";
import { curvePanels } from "../chart.js";
import {
  copyButton, defList, envSummary, formatTime, h, link, num, own, rawJson, shortAddr, shortCid,
} from "../dom.js";

const READING_MODELS = {
  poisson: "Poisson readings (as sampled)",
  expected: "expected readings (noise-free)",
};

/** The curve points of a model detail: the gateway's validated `curve` (workers/mdrl/curve.py). */
export function modelCurve(m) {
  return Array.isArray(m.curve) ? m.curve : [];
}

/** "5.50 [5.20, 5.80]": a mean with its 95% interval. */
export function withCi(value, ci, digits = 2) {
  if (value === null || value === undefined) return "—";
  const mean = Number(value).toFixed(digits);
  if (!Array.isArray(ci) || ci.length !== 2) return mean;
  return `${mean} [${Number(ci[0]).toFixed(digits)}, ${Number(ci[1]).toFixed(digits)}]`;
}

function percent(x) {
  return x === null || x === undefined ? "—" : `${(100 * Number(x)).toFixed(1)}%`;
}

const BASELINE_LABELS = {
  bayes: "Bayesian search (shared posterior)",
  uniform: "uniform coverage (zig-zag)",
  random: "random moves",
};

function figuresRow(reading, policy, label, f, oracleTime) {
  return h("tr", { "data-reading-model": reading, "data-policy": policy, class: `policy-${policy}` },
    h("td", {}, label),
    h("td", { class: "num success" }, percent(f.success)),
    h("td", { class: "num time" }, withCi(f.time, f.time_ci)),
    h("td", { class: "num cost" }, withCi(f.cost, f.cost_ci)),
    h("td", { class: "num ratio" }, f.time_vs_oracle === null || f.time_vs_oracle === undefined
      ? (policy === "oracle" && oracleTime ? "1.00×" : "—") : `${Number(f.time_vs_oracle).toFixed(2)}×`));
}

function heldoutTable(held) {
  return h("div", { class: "table-scroll" },
    h("table", { class: "list", id: "heldout-table" },
      h("thead", {}, h("tr", {}, ["Policy", "Success", "Time (steps, 95% CI)", "Cost (moves, 95% CI)",
        "Time / oracle"].map((c) => h("th", {}, c)))),
      held.readings.map((f) => h("tbody", { "data-reading-model": f.reading_model },
        h("tr", { class: "group" }, h("th", { colspan: 5 }, own(READING_MODELS, f.reading_model, f.reading_model))),
        figuresRow(f.reading_model, "model", h("strong", {}, "this model"), f),
        (f.baselines || []).map((b) => figuresRow(f.reading_model, b.name, own(BASELINE_LABELS, b.name, b.name), b)),
        f.oracle_time === null || f.oracle_time === undefined ? null
          : figuresRow(f.reading_model, "oracle", "oracle (knows the target)", { success: null, time: f.oracle_time }, f.oracle_time)))),
    h("p", { class: "muted" }, `Greedy policy on ${num(held.episodes)} held-out episodes`
      + `${held.seed !== null && held.seed !== undefined ? ` (seed ${held.seed})` : ""}, figures from the model's card; `
      + "the baselines and the oracle on the same episodes. The oracle knows the target and walks the closest agent "
      + "straight to it: no search is faster."));
}

function finalEval(ev) {
  return h("div", { id: "final-eval" },
    defList([["Success", percent(ev.success)], ["Time (steps)", num(ev.time, 2)], ["Cost (moves)", num(ev.cost, 2)]]),
    h("p", { class: "muted" }, "The trainer's last greedy evaluation (its own evaluation episodes, not held out)."));
}

function expertItem(x) {
  const label = x.model_id !== null && x.model_id !== undefined
    ? link(`/models/${encodeURIComponent(x.model_id)}`, `model #${x.model_id}`)
    : h("span", { class: "muted" }, x.cid ? "not on this platform" : "a local model");
  return h("li", { "data-expert": x.ref },
    label, " ", x.cid ? shortCid(x.cid) : h("code", { class: "mono" }, x.ref),
    h("span", { class: "muted" }, x.source === "task_spec" ? " · named by the task's spec" : " · listed by the card"),
    x.usage ? h("span", { class: "usage" }, ` · guided ${num(x.usage.episodes)} episode${x.usage.episodes === 1 ? "" : "s"}`
      + (x.usage.decisions ? `, its action taken in ${num(100 * x.usage.followed / x.usage.decisions, 1)}% of ${num(x.usage.decisions)} decisions` : "")
      + (x.usage.decisions && x.usage.agreed !== null && x.usage.agreed !== undefined ? ` (its first choice in ${num(100 * x.usage.agreed / x.usage.decisions, 1)}%)` : "")
      + (x.usage.selection_probability !== null && x.usage.selection_probability !== undefined ? `, picked with probability ${num(x.usage.selection_probability, 3)}` : "")) : null,
    x.usage && x.usage.trial ? expertTrial(x.usage.trial) : null);
}

/** The worker's trial of an expert on the task after the run (card training.experts.review). */
function expertTrial(t) {
  return h("div", { class: "trial" },
    `Followed by the team on ${num(t.episodes)} episodes of the task after the run: success ${percent(t.success)}, `
    + `time ${num(t.time, 2)} steps` + (t.time_vs_oracle !== null && t.time_vs_oracle !== undefined ? ` (${num(t.time_vs_oracle, 2)}× the oracle)` : "")
    + "; ", h("strong", { class: "suggested-review" }, `suggested review ${t.suggested_review}/5`),
    h("span", { class: "muted" }, " (the worker's measurement: 5 × success × oracle time / time, rounded)"));
}

/** A label in plain words; the reference for experts (an equation number) in its tooltip. */
function tip(label, title) {
  return h("span", { class: "tip", title }, label);
}

function provenance(m) {
  const p = m.produced_by;
  const task = p
    ? h("span", { id: "produced-by" }, link(`/tasks/${encodeURIComponent(p.task_id)}`, `task #${p.task_id}`),
      " by ", shortAddr(p.worker),
      p.review !== null && p.review !== undefined ? ` · reviewed ${p.review}/5${p.accepted ? ", accepted" : ", rejected"}` : "",
      h("span", { class: "muted" }, " (the chain's outcome record)"))
    : h("span", { class: "muted", id: "produced-by" }, "uploaded by its owner (no task's outcome)");
  const experts = (m.experts || []).length
    ? h("ul", { id: "model-experts" }, m.experts.map(expertItem))
    : h("span", { class: "muted", id: "model-experts" }, "none: trained from scratch");
  const trained = m.trained || {};
  return defList([
    ["Produced by", task],
    ["Experts", experts],
    ["Trained for", trained.env_steps !== null && trained.env_steps !== undefined
      ? `${num(trained.env_steps)} env steps${trained.updates ? `, ${num(trained.updates)} updates` : ""}`
        + `${trained.wall_time_s ? `, ${num(trained.wall_time_s / 60, 1)} min` : ""}` : undefined],
    ["Kept", trained.selected_by
      ? h("span", { id: "model-selected" }, `the run's best evaluated policy by ${trained.selected_by === "time" ? "episode time" : "moving cost"}, chosen at the step above (not its last one)`)
      : undefined],
  ]);
}

function requestsTable(requests) {
  if (!requests || !requests.length) return h("p", { class: "muted", id: "model-requests" }, "No model request has returned it yet.");
  return h("table", { class: "list", id: "model-requests" },
    h("thead", {}, h("tr", {}, ["Request", "Requester", "Match score", "Price", "Review"].map((c) => h("th", {}, c)))),
    h("tbody", {}, requests.map((r) => h("tr", { "data-alloc-id": r.alloc_id },
      h("td", {}, `#${r.alloc_id}`),
      h("td", {}, shortAddr(r.requester)),
      h("td", { class: "num qos", title: "the model's QoS for this request" }, num(r.qos, 3)),
      h("td", { class: "num price", title: `${r.price_wei} wei` }, `${r.price_eth} ETH`),
      h("td", { class: "num" }, r.review === null || r.review === undefined ? "—" : `${r.review}/5`)))));
}

export async function render(main, [id], ctx) {
  document.title = `Model #${id} · DRLaaS`;
  const m = await api(`/models/${encodeURIComponent(id)}`, { signal: ctx.signal });
  const card = m.card || {};
  const env = m.env_spec || m.env;
  const base = `${API_BASE}/models/${encodeURIComponent(m.id ?? id)}/download`;
  const arch = card.architecture || {};
  const obs = card.observation || {};
  const curve = modelCurve(m);
  const title = m.name || `${m.kind || "Model"} #${m.id ?? id}`;

  main.appendChild(h("section", { id: "model-page", "data-model-id": m.id ?? id },
    h("p", { class: "crumbs" }, link("/models", "Models"), " / ", `#${m.id ?? id}`),
    h("div", { class: "page-head" }, h("h1", { id: "model-title" }, title),
      h("span", { class: "muted" }, [m.kind, envSummary(env)].filter(Boolean).join(" · "))),
    m.description ? h("p", { class: "lead", id: "model-description", dir: "auto" }, m.description) : null,
    h("p", { class: "muted", id: "model-owner" }, "Shared by ", shortAddr(m.owner), ` · domain ${m.domain ?? "—"}`),

    h("div", { class: "cid-row" }, h("span", { class: "label" }, "CID"),
      h("code", { class: "mono", id: "model-cid" }, m.cid || "—"), m.cid ? copyButton(m.cid) : null),
    h("div", { class: "downloads", id: "downloads" },
      h("a", { href: `${base}?file=model.safetensors`, download: "model.safetensors", class: "button" }, "Download weights (model.safetensors)"),
      h("a", { href: `${base}?file=model.json`, download: "model.json", class: "button" }, "Download card (model.json)")),

    h("div", { class: "panel", id: "model-heldout" }, h("h2", {}, "How well it searches"),
      m.heldout ? heldoutTable(m.heldout)
        : m.final_eval ? finalEval(m.final_eval)
          : h("p", { class: "muted" }, "The card states no evaluation figures.")),

    h("div", { class: "panel" }, h("h2", {}, "Training curve"),
      h("div", { class: "charts", id: "model-curve" },
        curve.length ? curvePanels(curve) : h("p", { class: "muted" }, "This model's card has no training curve.")),
      curve.length ? h("p", { class: "muted" }, `Per update: success rate, mean episode length and mean moving cost of the episodes that ended in it`
        + `${m.curve_updates && m.curve_updates > curve.length ? ` (${num(m.curve_updates)} updates averaged into ${curve.length} points)` : ""}.`) : null),

    h("div", { class: "grid2" },
      h("div", { class: "panel", id: "model-chain" }, h("h2", {}, "On chain"), defList([
        [tip("Model reputation", "from the requesters' reviews of this model (Eq. 11)"),
          h("span", { id: "model-reputation" }, num(m.reputation, 3))],
        [tip("Owner's reputation as a sharer", "from the owner's record of shared models (Eq. 19)"),
          h("span", { id: "owner-reputation" }, num(m.owner_reputation, 3))],
        [tip("Owner's rating as a sharer", "the rating of the same record (Eq. 19)"), num(m.owner_rating, 3)],
        [tip("Owner's reputation over all its models", "the reviews of every request for the owner's models; 0.5 before any (Eq. 10)"),
          h("span", { id: "owner-model-reputation" }, num(m.owner_model_reputation, 3))],
        ["Requests", num(m.allocations)],
        ["Environment", Array.isArray(m.env) ? envSummary(m.env) : undefined],
      ])),
      h("div", { class: "panel", id: "model-provenance" }, h("h2", {}, "Provenance"), provenance(m))),
    h("div", { class: "panel" }, h("h2", {}, "Latest model requests"),
      h("div", { class: "table-scroll" }, requestsTable(m.requests))),

    h("div", { class: "panel", id: "model-card" }, h("h2", {}, "Card"), defList([
      ["Format", card.format],
      ["Created", card.created ? formatTime(card.created) : undefined],
      ["Observation", obs.kind ? `${String(obs.kind).toUpperCase()}${obs.window ? `, window ${obs.window}` : ""}` : undefined],
      ["Environment", env ? envSummary(env) : undefined],
      ["Grid area", env && Array.isArray(env.area_m) ? `${env.area_m.join(" × ")} m` : undefined],
      ["Reward", env && env.reward],
      ["Max steps", env && env.max_steps],
      ["Parameters", arch.total_parameters !== undefined ? `${num(arch.total_parameters)} (actor ${num(arch.actor_parameters)}, critic ${num(arch.critic_parameters)})` : undefined],
      ["Code", card.code && typeof card.code === "object" ? (card.code.version || card.code.git_commit) : undefined],
    ]), Object.keys(card).length ? rawJson("Full card (model.json)", card) : null)));
}
