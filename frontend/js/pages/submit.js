// Submit a training task: POST /api/tasks. The form checks what the MDRL core's EnvSpec and
// ObservationSpec would refuse (workers/mdrl/spec.py, observations.py) before sending, and maps
// the gateway's 422 answer ({"detail": [{loc, msg}]}) back onto the fields it names.

import { api, ApiError, getToken } from "../api.js";
import { ethToWei, h, link } from "../dom.js";

// Bounds of the gateway's TaskCreate (backend/schemas/tasks.py) and TasksManager.MAX_WORKERS.
const MAX_WORKERS = 16;
const MIN_STEPS = 1000;
const MAX_STEPS = 100_000_000;
const MAX_MINUTES = 10_080;
const MIN_DEADLINE_S = 60;
const MAX_WINDOW = 63;
const MAX_WEI = 2n ** 96n;
const KINDS = [["odmtl", "ODMTL (windowed maps)"], ["dmtl", "DMTL (per-agent maps)"], ["cmtl", "CMTL (centralized)"]];

/** name -> [label, default, input attributes, help] ; names are the JSON paths in the body. */
const FIELDS = {
  "env.agents": ["Agents", "3", { type: "number", min: 1, step: 1 }],
  "env.rows": ["Grid rows", "10", { type: "number", min: 2, step: 1 }],
  "env.cols": ["Grid columns", "10", { type: "number", min: 2, step: 1 }],
  "env.walls_min": ["Walls (min)", "0", { type: "number", min: 0, step: 1 }],
  "env.walls_max": ["Walls (max)", "0", { type: "number", min: 0, step: 1 }, "a count is drawn per episode in [min, max]"],
  "env.moves": ["Moves", "4", { select: [["4", "4 (up/down/left/right)"], ["8", "8 (with diagonals)"]] }],
  "env.intensity": ["Source intensity (photons/min)", "1e9", { type: "text" }, "1e9, a set 1e8,5e8,1e9 or a range 1e8:1e9"],
  "observation.kind": ["Observation", "odmtl", { select: KINDS }],
  "observation.window": ["Window w (ODMTL)", "3", { type: "number", min: 3, step: 2 }, "odd, 1 < w < min(rows, cols)"],
  "budget.steps": ["Budget: environment steps", "20000", { type: "number", min: MIN_STEPS, step: 1 }, `at least ${MIN_STEPS.toLocaleString("en-US")}`],
  "budget.minutes": ["Budget: minutes", "10", { type: "number", min: 1, step: 1 }, "training stops at whichever comes first"],
  "seed": ["Seed", "0", { type: "number", min: 0, step: 1 }],
  "domain": ["Domain", "0", { type: "number", min: 0, max: 255, step: 1 }, "domain code 0-255"],
  "num_workers": ["Workers", "1", { type: "number", min: 1, max: MAX_WORKERS, step: 1 }, `1 to ${MAX_WORKERS}, each trains independently`],
  "min_reputation": ["Min reputation (0-1)", "0", { type: "number", min: 0, max: 1, step: "any" }],
  "min_rating": ["Min rating (0-1)", "0", { type: "number", min: 0, max: 1, step: "any" }],
  "min_cpu_cores": ["Min CPU cores", "1", { type: "number", min: 0, step: 1 }],
  "min_ram_gb": ["Min RAM (GB)", "1", { type: "number", min: 0, step: 1 }],
  "deadline_s": ["Deadline (s)", "3600", { type: "number", min: MIN_DEADLINE_S, step: 1 }, "time the workers have to submit"],
  "payment_eth": ["Payment per worker (ETH)", "0.01", { type: "text", inputmode: "decimal" }],
};
const GROUPS = [
  ["env", "Environment", ["env.agents", "env.rows", "env.cols", "env.walls_min", "env.walls_max", "env.moves", "env.intensity"]],
  ["observation", "Observation", ["observation.kind", "observation.window"]],
  ["budget", "Training budget", ["budget.steps", "budget.minutes", "seed"]],
  ["recruit", "Recruitment and payment", ["domain", "num_workers", "min_reputation", "min_rating", "min_cpu_cores", "min_ram_gb", "deadline_s", "payment_eth"]],
];
/** Server loc (after "body") -> the field showing its error. */
const LOC_ALIASES = {
  "env.walls": "env.walls_max", "payment_wei": "payment_eth", "env": "env", "observation": "observation",
  "budget": "budget",
};

const fid = (name) => `f-${name.replace(/\./g, "-")}`;
const eid = (name) => `err-${name.replace(/\./g, "-")}`;

function parseIntensity(text) {
  const t = text.trim();
  const nums = (parts) => parts.map((p) => {
    if (!/^\s*[0-9.eE+-]+\s*$/.test(p)) return NaN;
    return Number(p);
  });
  let kind = "fixed", values;
  if (t.includes(":")) { kind = "uniform"; values = nums(t.split(":")); }
  else if (t.includes(",")) { kind = "choice"; values = nums(t.split(",")); }
  else values = nums([t]);
  if (!t || values.some((v) => !(v > 0 && Number.isFinite(v)))) {
    throw new Error("expected a positive number (1e9), a set (1e8,5e8,1e9) or a range (1e8:1e9)");
  }
  if (kind === "uniform" && (values.length !== 2 || values[0] > values[1])) {
    throw new Error("a range is low:high with low <= high");
  }
  return { kind, values };
}

/** Form values (strings) -> {body, errors: {field: msg}}. */
export function buildTask(v) {
  const errors = {};
  const int = (name, { min, max, required = true } = {}) => {
    const raw = (v[name] ?? "").trim();
    if (raw === "") { if (required) errors[name] = "required"; return undefined; }
    const n = Number(raw);
    if (!Number.isInteger(n)) { errors[name] = "must be a whole number"; return undefined; }
    if (min !== undefined && n < min) { errors[name] = `must be at least ${min}`; return undefined; }
    if (max !== undefined && n > max) { errors[name] = `must be at most ${max}`; return undefined; }
    return n;
  };
  const real = (name, { min, max, required = true, positive = false } = {}) => {
    const raw = (v[name] ?? "").trim();
    if (raw === "") { if (required) errors[name] = "required"; return undefined; }
    const n = Number(raw);
    if (!Number.isFinite(n)) { errors[name] = "must be a number"; return undefined; }
    if (positive && !(n > 0)) { errors[name] = "must be greater than 0"; return undefined; }
    if (min !== undefined && n < min) { errors[name] = `must be at least ${min}`; return undefined; }
    if (max !== undefined && n > max) { errors[name] = `must be at most ${max}`; return undefined; }
    return n;
  };

  const rows = int("env.rows", { min: 2 });
  const cols = int("env.cols", { min: 2 });
  const agents = int("env.agents", { min: 1 });
  if (agents !== undefined && rows !== undefined && cols !== undefined && agents + 1 > rows * cols) {
    errors["env.agents"] = `${agents} agents and a target do not fit on ${rows}×${cols}`;
  }
  const wlo = int("env.walls_min", { min: 0 });
  const whi = int("env.walls_max", { min: 0 });
  if (wlo !== undefined && whi !== undefined && wlo > whi) errors["env.walls_max"] = "must be at least the minimum";
  if (whi > 0 && rows !== undefined && cols !== undefined && Math.min(rows, cols) < 4) {
    errors["env.walls_max"] = "walls need a grid of at least 4×4";
  }
  const moves = int("env.moves");
  if (moves !== undefined && moves !== 4 && moves !== 8) errors["env.moves"] = "must be 4 or 8";
  let intensity;
  try { intensity = parseIntensity(v["env.intensity"] ?? ""); } catch (err) { errors["env.intensity"] = err.message; }

  const kind = (v["observation.kind"] || "").trim();
  if (!KINDS.some(([k]) => k === kind)) errors["observation.kind"] = "choose ODMTL, DMTL or CMTL";
  const window = int("observation.window", { min: 3, max: MAX_WINDOW, required: kind === "odmtl" });
  if (window !== undefined && kind === "odmtl") {
    if (window % 2 === 0) errors["observation.window"] = "must be odd";
    else if (rows !== undefined && cols !== undefined && !(window > 1 && window < Math.min(rows, cols))) {
      errors["observation.window"] = `must satisfy 1 < w < ${Math.min(rows, cols)} (the smaller grid side)`;
    }
  }

  const steps = int("budget.steps", { min: MIN_STEPS, max: MAX_STEPS });
  const minutes = int("budget.minutes", { min: 1, max: MAX_MINUTES });
  const seed = int("seed", { min: 0, max: 2 ** 32 - 1, required: false });
  const domain = int("domain", { min: 0, max: 255 });
  const numWorkers = int("num_workers", { min: 1, max: MAX_WORKERS });
  const minRep = real("min_reputation", { min: 0, max: 1 });
  const minRating = real("min_rating", { min: 0, max: 1 });
  const minCpu = int("min_cpu_cores", { min: 0 });
  const minRam = int("min_ram_gb", { min: 0 });
  const deadline = int("deadline_s", { min: MIN_DEADLINE_S });
  let paymentWei;
  try {
    paymentWei = ethToWei(v.payment_eth ?? "");
    if (BigInt(paymentWei) >= MAX_WEI) { errors.payment_eth = "too large (the contract stores < 2^96 wei)"; paymentWei = undefined; }
  } catch (err) { errors.payment_eth = err.message; }

  if (Object.keys(errors).length) return { body: null, errors };
  const budget = { steps, minutes };
  const body = {
    env: { agents, rows, cols, walls: [wlo, whi], moves, intensity },
    observation: kind === "odmtl" ? { kind, window } : { kind },
    budget,
    domain,
    num_workers: numWorkers,
    min_reputation: minRep,
    min_rating: minRating,
    min_cpu_cores: minCpu,
    min_ram_gb: minRam,
    deadline_s: deadline,
    payment_wei: paymentWei, // decimal string; serialised as a bare integer (see toJson)
  };
  if (seed !== undefined) body.seed = seed;
  return { body, errors };
}

/** JSON with payment_wei as an exact integer literal: wei amounts pass 2^53, where JS numbers
 *  would silently round (0.01 ETH = 1e16 wei). */
export function toJson(body) {
  const marker = "__WEI__";
  const text = JSON.stringify({ ...body, payment_wei: marker }, null, 1);
  return text.replace(`"${marker}"`, /^\d+$/.test(body.payment_wei) ? body.payment_wei : "0");
}

function fieldFor(loc) {
  const path = (loc || []).filter((p, i) => !(i === 0 && p === "body")).map(String);
  for (let n = path.length; n > 0; n--) {
    const key = path.slice(0, n).join(".");
    if (FIELDS[key]) return key;
    if (LOC_ALIASES[key]) return LOC_ALIASES[key];
  }
  return null;
}

export async function render(main) {
  document.title = "Submit a task · DRLaaS";
  const signedIn = Boolean(getToken());
  const formError = h("div", { id: "form-error", role: "alert" });
  const result = h("div", { id: "submit-result" });

  const control = (name) => {
    const [label, def, attrs, help] = FIELDS[name];
    const common = { id: fid(name), name, "aria-describedby": eid(name) };
    const input = attrs.select
      ? h("select", { ...common, value: def }, attrs.select.map(([value, text]) => h("option", { value }, text)))
      : h("input", { ...common, ...attrs, value: def });
    return h("div", { class: "field", "data-field": name },
      h("label", { for: fid(name) }, label), input,
      help ? h("small", { class: "help" }, help) : null,
      h("div", { class: "field-error", id: eid(name) }));
  };

  const form = h("form", { id: "task-form", novalidate: true, class: "task-form" },
    GROUPS.map(([key, title, names]) => h("fieldset", { "data-group": key },
      h("legend", {}, title),
      h("div", { class: "field-error group-error", id: eid(key) }),
      h("div", { class: "fields" }, names.map(control)))),
    h("div", { class: "submit-row" },
      h("button", { type: "submit", class: "primary", id: "submit-task" }, "Submit task"),
      h("span", { class: "muted" }, signedIn ? "" : "Sign in first (top right): the task is created as your address."),
      formError),
    h("details", { class: "raw" }, h("summary", {}, "Request body (JSON)"), h("pre", { class: "mono", id: "body-preview" })));

  const values = () => Object.fromEntries(Object.keys(FIELDS).map((n) => [n, form.elements[n].value]));
  const clearErrors = () => {
    form.querySelectorAll(".field-error").forEach((el) => { el.textContent = ""; });
    form.querySelectorAll("[aria-invalid]").forEach((el) => el.removeAttribute("aria-invalid"));
    formError.replaceChildren();
  };
  const showError = (field, msg) => {
    const slot = form.querySelector(`#${eid(field)}`);
    if (!slot) return false;
    slot.textContent = slot.textContent ? `${slot.textContent}; ${msg}` : msg;
    const input = form.elements[field];
    if (input && input.setAttribute) input.setAttribute("aria-invalid", "true");
    return true;
  };
  const preview = () => {
    const { body } = buildTask(values());
    form.querySelector("#body-preview").textContent = body ? toJson(body) : "(fix the marked fields)";
  };
  form.addEventListener("input", preview);
  form.addEventListener("change", () => {
    form.querySelector(`[data-field="observation.window"]`).hidden = form.elements["observation.kind"].value !== "odmtl";
  });

  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    clearErrors();
    result.replaceChildren();
    const { body, errors } = buildTask(values());
    for (const [field, msg] of Object.entries(errors)) showError(field, msg);
    if (!body) {
      const first = form.querySelector("[aria-invalid]");
      if (first) first.focus();
      formError.replaceChildren(h("p", { class: "warn" }, `${Object.keys(errors).length} field(s) need a fix.`));
      return;
    }
    const button = form.querySelector("#submit-task");
    button.disabled = true;
    try {
      const answer = await api("/tasks", { method: "POST", rawBody: toJson(body) });
      const tid = answer.task_id ?? answer.id;
      result.replaceChildren(h("div", { class: "ok-box", role: "status" },
        h("strong", {}, `Task #${tid} created. `),
        `${Array.isArray(answer.offered) ? answer.offered.length : (answer.offered ?? 0)} worker(s) offered. Spec CID `, h("code", { class: "mono" }, answer.spec_cid || "—"), ". ",
        link(`/tasks/${encodeURIComponent(tid)}`, "Follow it live →")));
    } catch (err) {
      if (!(err instanceof ApiError)) throw err;
      let shown = 0;
      for (const issue of err.issues) {
        const field = fieldFor(issue.loc);
        if (field && showError(field, issue.msg)) shown++;
        else formError.appendChild(h("p", { class: "warn" }, `${(issue.loc || []).join(".")}: ${issue.msg}`));
      }
      if (!err.issues.length) {
        const extra = [];
        if (err.status === 401) extra.push(" Sign in first (top right).");
        if (err.rule === "sign_locally") {
          extra.push(" This gateway holds no key for you: sign the transaction below with your own key and POST it to /api/tx, or use the drlaas CLI.");
        }
        formError.appendChild(h("p", { class: "warn", "data-rule": err.rule || "" }, err.message, extra.join("")));
        if (err.rule && /requester/.test(err.rule)) {
          formError.appendChild(h("button", { type: "button", class: "small", id: "register-requester", onclick: async (ev) => {
            try { await api("/users/requesters", { method: "POST", body: {} }); ev.target.replaceWith(h("span", { class: "ok" }, "Registered: submit again.")); }
            catch (err2) { ev.target.replaceWith(h("span", { class: "warn" }, err2.message)); }
          } }, "Register as requester"));
        }
        if (err.body && err.body.detail && err.body.detail.tx) {
          formError.appendChild(h("pre", { class: "mono" }, JSON.stringify(err.body.detail.tx, null, 2)));
        }
      }
      if (shown) form.querySelector("[aria-invalid]")?.focus();
    } finally {
      button.disabled = false;
    }
  });

  main.appendChild(h("section", {},
    h("div", { class: "page-head" }, h("h1", {}, "Submit a training task")),
    h("p", { class: "muted" }, "The spec is stored in the content store and its CID goes on chain; the chain then "
      + "offers the task to the workers with the best QoS that meet your requirements."),
    form, result));
  preview();
}
