// One task: GET /api/tasks/{id} (spec, status, timeline, offers, outcomes, progress, experts),
// polled every 2 s; each section is redrawn only when its data changed, so a half-filled review
// form survives the polling. Experts (MEDC): the models the spec names, with their QoS weight,
// the MMC model and allocation they came from, and the requester's review of each
// (POST /models/requests/{alloc_id}/reviews, MMC updateModelRep), started at the review the
// workers' trials of the expert suggest together (experts[].suggested_review, the middle one).
// Cancelling asks for confirmation first; the timeline's chain values are in human units (ETH,
// UTC dates, fractions); an outcome links to its model only where that model is listed.

import { api } from "../api.js";
import { curvePanels } from "../chart.js";
import {
  copyButton, defList, envSummary, errorBox, errorView, formatTime, formatWei, h, link, num, own, rawJson, shortAddr, shortCid,
  statusPill,
} from "../dom.js";
import { POLL_MS, specCid } from "./tasks.js";

/** A cancelled or closed task changes little (an outcome's model appears when its worker
 *  shares it): its page asks every 30 s, not every 2 s for as long as it stays open. */
export const FINAL_STATUSES = new Set(["cancelled", "closed"]);
export const FINAL_POLL_MS = 30000;
const isFinal = (t) => Boolean(t) && FINAL_STATUSES.has(String(t.status).toLowerCase());

const SAME = (a, b) => a.length === b.length && a.every((x, i) => Object.is(x, b[i]));

function section(id, title) {
  const body = h("div", { class: "section-body" });
  const el = h("div", { class: "panel", id }, h("h2", {}, title), body);
  el._key = null;
  return { el, body };
}

function eventName(e) {
  return e.name || e.event || e.type || "event";
}

/** The task page's times: UTC, marked so (the chain's clock; the reader's zone may differ). */
const utc = (t) => formatTime(t, { utc: true });

// Event args (TasksManager events) in human units; the raw value stays on hover.
const WEI_ARGS = new Set(["reward", "amount", "price", "weiPerHour", "weiPerModel"]);
const TIME_ARGS = new Set(["deadline", "expiry"]);
const FIXED_ARGS = new Set(["qos", "minReputation", "minRating"]); // contract fixed point, 1e6 = 1
const CID_ARGS = new Set(["cid", "description"]);
const TASK_STATUS = ["none", "open", "completed", "cancelled", "closed"]; // TasksManager.TaskStatus

function argValue(k, v) {
  if (typeof v === "string" && /^0x[0-9a-fA-F]{40}$/.test(v)) return shortAddr(v);
  if (WEI_ARGS.has(k)) return h("span", { class: "eth", title: `${v} wei` }, formatWei(v));
  if (TIME_ARGS.has(k)) return h("span", { class: "date", title: `${v} (unix time)` }, utc(v));
  if (FIXED_ARGS.has(k) && Number.isFinite(Number(v))) {
    return h("span", { title: `${v} on chain (1,000,000 = 1)` }, num(Number(v) / 1e6, 4));
  }
  if (CID_ARGS.has(k) && typeof v === "string" && v.length > 20) return shortCid(v);
  if (k === "status" && Number.isInteger(v) && v >= 0 && v < TASK_STATUS.length) return TASK_STATUS[v];
  return typeof v === "object" && v !== null ? JSON.stringify(v) : String(v);
}

// Why a task shows no spec (spec_state of GET /api/tasks/{id}); "read" and "none" need no note.
const SPEC_STATE_NOTES = {
  pending: "not read from the content store yet",
  invalid: "this document is not a task spec",
  missing: "the content store could not find it yet; it is asked for again later",
};
const ARG_LABELS = { qos: "match score", numWorkers: "workers", description: "spec", minCpuCores: "min CPU cores",
  minRamGb: "min RAM (GB)", weiPerHour: "min reward per hour" };
/** "minReputation" -> "min reputation". */
const argLabel = (k) => own(ARG_LABELS, k) ?? k.replace(/([a-z0-9])([A-Z])/g, "$1 $2").toLowerCase();

function eventDetails(e) {
  const args = e.args || e.data || {};
  return Object.entries(args)
    .filter(([k]) => !["taskId", "task_id"].includes(k))
    .map(([k, v]) => h("span", { class: "arg", "data-arg": k }, `${argLabel(k)}: `, argValue(k, v)));
}

/** An outcome's model CID: a link to its model page where it is listed (the gateway's model_id);
 *  else the full CID to copy, with a note that no shared model has it. */
function outcomeCid(cid, modelId) {
  if (!cid) return shortCid(cid);
  if (modelId !== undefined && modelId !== null) return link(`/models/${encodeURIComponent(modelId)}`, shortCid(cid));
  return h("span", { class: "cid-text" }, h("code", { class: "mono" }, cid), " ", copyButton(cid),
    h("div", { class: "muted note" }, "Not listed as a shared model (its worker has not shared it)."));
}

/** One worker's trial of an expert (its outcome card): time, ratio to the oracle, suggestion. */
function trialText(trial) {
  const ratio = trial.time_vs_oracle !== null && trial.time_vs_oracle !== undefined
    ? ` (${num(trial.time_vs_oracle, 2)}× oracle)` : "";
  return `${num(trial.time, 2)} steps${ratio}, suggests ${trial.suggested_review}/5`;
}

export async function render(main, [id], ctx) {
  document.title = `Task #${id} · DRLaaS`;
  const head = h("div", { class: "page-head" });
  const updated = h("span", { class: "muted", id: "task-updated" });
  const actions = h("div", { class: "actions", id: "task-actions" });
  const sections = {
    summary: section("task-summary", "Task"),
    curve: section("task-curve", "Live training curve"),
    offers: section("task-offers", "Offers"),
    outcomes: section("task-outcomes", "Outcomes"),
    experts: section("task-experts", "Expert models"),
    timeline: section("task-timeline", "Timeline"),
  };
  const message = h("div", { id: "task-message" });
  main.appendChild(h("section", { id: "task-page", "data-task-id": id },
    h("p", { class: "crumbs" }, link("/tasks", "Tasks"), " / ", `#${id}`),
    head, updated, message, actions,
    h("div", { class: "grid2" }, sections.summary.el, sections.timeline.el),
    sections.curve.el, sections.offers.el, sections.outcomes.el, sections.experts.el));

  let task = null;
  const draw = (name, key, build) => {
    const sct = sections[name];
    if (sct.el._key && SAME(sct.el._key, key)) return;
    sct.el._key = key;
    sct.body.replaceChildren(...[].concat(build()).filter(Boolean));
  };

  const act = async (what, path, body) => {
    message.replaceChildren();
    try {
      await api(path, { method: "POST", body });
      message.replaceChildren(h("p", { class: "ok" }, `${what}: sent.`));
      await refresh();
    } catch (err) {
      message.replaceChildren(errorBox(err.rule === "sign_locally"
        ? new Error(`${what} must be signed with your own key on this gateway (drlaas task ... with --key).`)
        : err));
    }
  };

  async function refresh() {
    let t;
    try {
      t = await api(`/tasks/${encodeURIComponent(id)}`, { signal: ctx.signal });
    } catch (err) {
      if (err.name === "AbortError") throw err;
      if (!task) {
        main.replaceChildren(errorView(err, ctx.retry, { back: "/tasks", backLabel: "Browse tasks" }));
        ctx.stopped = true;
        return;
      }
      updated.textContent = `update failed: ${err.message}`;
      return;
    }
    task = t;
    const outcomes = Array.isArray(t.outcomes) ? t.outcomes : [];
    updated.textContent = isFinal(t)
      ? `${String(t.status).toLowerCase()} · updated ${new Date().toLocaleTimeString("en-GB")}, checked every ${FINAL_POLL_MS / 1000} s`
      : `live · updated ${new Date().toLocaleTimeString("en-GB")}`;
    const spec = t.spec || {};
    const me = document.body.dataset.address || "";
    const isRequester = me && t.requester && me.toLowerCase() === String(t.requester).toLowerCase();
    head.replaceChildren(h("h1", {}, `Task #${t.id ?? id}`), h("span", { id: "task-status" }, statusPill(t.status)));
    actions.replaceChildren(...(isRequester && String(t.status).toLowerCase() === "open"
      ? [h("button", { type: "button", class: "small danger", id: "cancel-task",
          onclick: () => {
            // an on-chain transaction that cannot be undone: ask first
            if (!window.confirm(`Cancel task #${t.id ?? id}?\n\nThe task is cancelled on chain and its payment `
              + "refunded to your credit (only while no worker has accepted it). This cannot be undone.")) return;
            act("Cancel", `/tasks/${encodeURIComponent(id)}/cancel`, {});
          } }, "Cancel task…")]
      : []));

    const cid = specCid(t);
    const summaryKey = { ...t, timeline: 0, offers: 0, outcomes: 0, progress: 0, status: 0 };
    draw("summary", [JSON.stringify(summaryKey)], () => [
      defList([
        ["Requester", shortAddr(t.requester)],
        ["Spec CID", [h("code", { class: "mono", id: "task-spec-cid" }, cid || "—"),
          own(SPEC_STATE_NOTES, t.spec_state) ? h("span", { class: "muted", id: "task-spec-state" }, ` (${SPEC_STATE_NOTES[t.spec_state]})`) : null]],
        ["Domain", t.domain ?? spec.domain],
        ["Environment", envSummary(spec.env || t.env)],
        ["Observation", spec.observation ? `${String(spec.observation.kind || "").toUpperCase()}${spec.observation.window ? `, window ${spec.observation.window}` : ""}` : undefined],
        ["Budget", spec.budget ? [spec.budget.steps ? `${num(spec.budget.steps)} steps` : null, spec.budget.minutes ? `${num(spec.budget.minutes)} min` : null].filter(Boolean).join(", ") || "—" : undefined],
        ["Delivers", spec.selection && spec.selection.keep_best
          ? h("span", { id: "task-selection" }, `the best evaluated policy by ${spec.selection.keep_best === "time" ? "episode time" : "moving cost"} (evaluated every ${num(spec.selection.eval_every ?? 5)} updates)`)
          : (spec.budget ? "the final policy" : undefined)],
        ["Workers", t.num_workers ?? spec.num_workers],
        ["Offered", t.offered],
        ["Reward / worker", formatWei(t.reward_wei ?? t.payment_wei ?? spec.payment_wei)],
        ["Min reputation", t.min_reputation ?? spec.min_reputation],
        ["Min rating", t.min_rating ?? spec.min_rating],
        ["Min CPU / RAM", t.min_cpu_cores !== undefined ? `${t.min_cpu_cores} cores, ${t.min_ram_gb} GB` : undefined],
        ["Deadline", t.deadline !== undefined ? utc(t.deadline) : (spec.deadline_s !== undefined ? `${num(spec.deadline_s)} s` : undefined)],
        ["Seed", spec.seed],
      ]),
      Object.keys(spec).length ? rawJson("Task spec (JSON)", spec) : null,
    ]);

    // x is the gateway's step: an extra metric a worker named "global_step" (read first by the
    // chart) moved every point of the live curve
    const progress = (Array.isArray(t.progress) ? t.progress : [])
      .map((p) => ({ ...(p.extra || {}), ...p, global_step: p.step }));
    draw("curve", [progress.length, JSON.stringify(progress[progress.length - 1] || null)], () => {
      if (!progress.length) return h("p", { class: "muted" }, "No progress yet: points appear here while a worker trains.");
      const multi = new Set(progress.map((p) => p.worker)).size > 1;
      const last = progress[progress.length - 1];
      return [
        h("p", { class: "muted", id: "progress-summary" },
          `${progress.length} point${progress.length === 1 ? "" : "s"}; latest step ${num(last.step ?? last.global_step)}`
          + (last.success !== undefined ? `, success ${num(last.success, 3)}` : "")),
        h("div", { class: "charts" }, curvePanels(progress, multi ? { groupBy: "worker" } : {})),
      ];
    });

    const offers = Array.isArray(t.offers) ? t.offers : [];
    draw("offers", [JSON.stringify(offers)], () => offers.length
      ? h("table", { class: "list" }, h("thead", {}, h("tr", {}, ["Worker", "State", "Match score", "Expires"].map((c) => h("th", {}, c)))),
        h("tbody", {}, offers.map((o) => h("tr", { "data-worker": o.worker },
          h("td", {}, shortAddr(o.worker)), h("td", {}, statusPill(o.state ?? o.status)),
          h("td", { class: "num", title: "the worker's QoS for this task: the best are offered it first" }, num(o.qos, 4)),
          h("td", {}, utc(o.expiry ?? o.expires_at))))))
      : h("p", { class: "muted" }, "No offers yet."));

    const experts = Array.isArray(t.experts) ? t.experts : [];
    sections.experts.el.hidden = !experts.length;
    draw("experts", [JSON.stringify(experts), isRequester], () => experts.length
      ? h("table", { class: "list", id: "experts-table" },
        h("thead", {}, h("tr", {}, ["Model", "Weight", "Reputation", "Bought in request", "On the task after the run", "Review", ""].map((c) => h("th", {}, c)))),
        h("tbody", {}, experts.map((x) => {
          const reviewed = x.review !== undefined && x.review !== null;
          const trials = Array.isArray(x.trials) ? x.trials : []; // one per outcome's worker
          let cell = null;
          if (isRequester && !reviewed && x.alloc_id && x.model_id) {
            const suggested = x.suggested_review ?? 5; // the trials' middle one (gateway)
            const sel = h("select", { "aria-label": "Expert review 0-5", value: String(suggested) },
              [5, 4, 3, 2, 1, 0].map((v) => h("option", { value: String(v) }, `${v}/5`)));
            cell = h("span", {}, sel, h("button", { type: "button", class: "small", onclick: () =>
              act("Expert review", `/models/requests/${encodeURIComponent(x.alloc_id)}/reviews`, { model_id: x.model_id, review: Number(sel.value) }) }, "Review"));
          }
          return h("tr", { "data-cid": x.cid },
            h("td", {}, x.model_id ? link(`/models/${encodeURIComponent(x.model_id)}`, shortCid(x.cid)) : shortCid(x.cid)),
            h("td", { class: "num", title: "the expert's QoS weight in the task's spec" }, x.qos === null || x.qos === undefined ? "equal" : num(x.qos, 4)),
            h("td", { class: "num" }, num(x.reputation, 3)),
            h("td", {}, x.alloc_id ? `#${x.alloc_id}` : h("span", { class: "muted" }, "named by CID")),
            h("td", { class: "trial", title: "the expert followed by the team on the task's episodes after the run, "
              + "measured by the worker (the outcome's card): the suggested review is 5 × success × oracle time / time" },
              trials.length ? trials.map((trial) => h("div", { class: "trial-line", "data-worker": trial.worker },
                trials.length > 1 ? [shortAddr(trial.worker), ": "] : null, trialText(trial)))
                : h("span", { class: "muted" }, "not measured")),
            h("td", {}, reviewed ? `${x.review}/5` : h("span", { class: "muted" }, "not reviewed")),
            h("td", {}, cell));
        })))
      : null);

    const timeline = Array.isArray(t.timeline) ? t.timeline : [];
    draw("timeline", [JSON.stringify(timeline)], () => timeline.length
      ? h("ol", { class: "timeline", id: "timeline" }, timeline.map((e) => h("li", {},
        h("span", { class: "when" }, utc(e.block_time ?? e.time ?? e.timestamp)),
        h("span", { class: "what" }, eventName(e)),
        (e.block_number ?? e.block) !== undefined ? h("span", { class: "muted", title: e.tx_hash || "" }, ` block ${e.block_number ?? e.block}`) : null,
        h("span", { class: "args" }, eventDetails(e)),
        e.error ? h("span", { class: "error", title: e.error }, ` not indexed: ${e.error}`) : null)))
      : h("p", { class: "muted" }, "No events yet."));

    draw("outcomes", [JSON.stringify(outcomes), isRequester], () => outcomes.length
      ? h("table", { class: "list", id: "outcomes-table" },
        h("thead", {}, h("tr", {}, ["Worker", "Model CID", "Review", ""].map((c) => h("th", {}, c)))),
        h("tbody", {}, outcomes.map((o) => {
          const reviewed = o.review !== undefined && o.review !== null;
          const paid = !reviewed && o.accepted === true; // left unreviewed, paid at close
          let cell = null;
          if (isRequester && !reviewed && !paid) {
            const sel = h("select", { "aria-label": "Review 0-5" }, [5, 4, 3, 2, 1, 0].map((v) => h("option", { value: String(v) }, `${v}/5`)));
            cell = h("span", {}, sel, h("button", { type: "button", class: "small", onclick: () =>
              act("Review", `/tasks/${encodeURIComponent(id)}/reviews`, { worker: o.worker, review: Number(sel.value) }) }, "Review"));
          }
          return h("tr", { "data-worker": o.worker },
            h("td", {}, shortAddr(o.worker)),
            h("td", { class: "outcome-cid" }, outcomeCid(o.cid, o.model_id)),
            h("td", {}, reviewed ? `${o.review}/5${o.accepted === false ? " (rejected)" : ""}`
              : h("span", { class: "muted" }, paid ? "not reviewed: paid at close" : "not reviewed")),
            h("td", {}, cell));
        })))
      : h("p", { class: "muted" }, "No outcome submitted yet."));
  }

  await ctx.every(() => (isFinal(task) ? FINAL_POLL_MS : POLL_MS), refresh);
}
