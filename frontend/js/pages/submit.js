// Submit a training task: POST /api/tasks. Every bound of a field (min, max, enum, odd, ...)
// comes from the gateway's OpenAPI document (the core's TrainingSpec JSON Schema and TaskCreate,
// read by schema.js); the form checks them before sending and maps the gateway's 422 answer
// ({"detail": [{loc, msg}]}) back onto the fields it names. Without the document the form still
// works: it sends what it has and shows the gateway's 422 on the field.

import { api, ApiError, getToken } from "../api.js";
import { ethToWei, formatWei, h, link } from "../dom.js";
import { boundError, boundsOf, fmt, inputAttrs, requestSchema } from "../schema.js";

/** Labels of enum values; the values offered are the schema's enum (these keys only when the
 *  gateway serves no schema). */
const LABELS = {
  "env.moves": { 4: "4 (up/down/left/right)", 8: "8 (with diagonals)" },
  "observation.kind": { odmtl: "a window around each agent (ODMTL)", dmtl: "the whole map, per agent (DMTL)", cmtl: "one shared map for all agents (CMTL)" },
  "algorithm.demonstration.credit": { false: "off (every expert trusted)", true: "on (experts on probation, weighted by credit)" },
  "selection.keep_best": { "": "the final policy", time: "the best evaluated: shortest episodes", cost: "the best evaluated: lowest moving cost" },
};
/** Selects whose first option is "not set" (the spec field is nullable: null = the default). */
const UNSET_OPTION = { "selection.keep_best": "" };
/** "1 to 16" from a field's bounds ("" without both). */
const range = (b) => (b && b.min !== undefined && b.max !== undefined ? `${fmt(b.min)} to ${fmt(b.max)}` : "");

/** name -> [label, default, input, help, tip]; names are the JSON paths in the body (SCHEMA_PATH
 *  for the others). input: "int" | "real" (the schema's type wins) | "select" | "text". help: text,
 *  or (bounds) => [parts] joined with ", ". tip: the label's tooltip (the method's own terms, for
 *  experts; labels and help are plain words). No bounds here: they come from the schema. */
const FIELDS = {
  "env.agents": ["Agents", "3", "int", range],
  "env.rows": ["Grid rows", "10", "int", range],
  "env.cols": ["Grid columns", "10", "int", range],
  "env.walls_min": ["Walls (min)", "0", "int"],
  "env.walls_max": ["Walls (max)", "0", "int", () => ["a count is drawn per episode in [min, max]", "at most max(rows, cols)"]],
  "env.moves": ["Moves", "4", "select"],
  "env.intensity": ["Source intensity (photons/min)", "1e9", "text", () => ["1e9, a set 1e8,5e8,1e9 or a range 1e8:1e9"]],
  "observation.kind": ["Observation", "odmtl", "select", undefined, "what each agent sees: ODMTL, DMTL or CMTL"],
  "observation.window": ["Window size (cells)", "3", "int", (b) => [b && b.odd ? "odd" : "", range(b), "smaller than the grid's shorter side"], "w, the ODMTL window"],
  "observation.walls_embedding": ["Walls autoencoder (CID)", "", "text", () => ["a model that compresses wall maps (drlaas cae train, then drlaas model push)", "empty = wall maps only", "trained on this grid size"], "a walls CAE (Ch. 4)"],
  "observation.walls_embedding_size": ["Autoencoder code size", "", "int", (b) => [range(b), "empty = 128; must be the autoencoder's"], "d, the CAE's embedding size (Ch. 4)"],
  "budget.steps": ["Budget: environment steps", "20000", "int", (b) => [range(b), "training stops at exactly this many"]],
  "budget.minutes": ["Budget: minutes", "10", "real", (b) => [range(b), "training stops at whichever comes first"]],
  "seed": ["Seed", "0", "int"],
  "selection.keep_best": ["Deliver", "", "select", () => ["the policy the worker sends: the last one, or the best of greedy evaluations during training (its card says when)"]],
  "selection.eval_every": ["Evaluate every (updates)", "", "int", (b) => [range(b), "empty = 5; only when delivering the best policy"]],
  "domain": ["Domain", "0", "int", (b) => [`domain code ${range(b)}`.trim()]],
  "num_workers": ["Workers", "1", "int", (b) => [range(b), "each trains independently"]],
  "min_reputation": ["Min reputation", "0", "real", range],
  "min_rating": ["Min rating", "0", "real", range],
  "min_cpu_cores": ["Min CPU cores", "1", "int"],
  "min_ram_gb": ["Min RAM (GB)", "1", "int"],
  "deadline_s": ["Deadline (s)", "3600", "int", () => ["time the workers have to submit"]],
  "payment_eth": ["Payment per worker (ETH)", "0.01", "text"],
  "experts": ["Expert models (CIDs)", "", "text", () => ["model CIDs, comma-separated (Models page)", "empty = none"]],
  "experts_from_mmc": ["Or buy this many experts", "0", "int", () => [`0 to ${MAX_EXPERTS}`, "the shared models closest to this environment, each paid its price to its owner"], "K models from the MMC (the models contract)"],
  "algorithm.demonstration.rate": ["Expert-guided share", "", "real", (b) => [range(b), "share of the episodes an expert guides; empty = 0.2 with one expert, 0.1 with several"], "R_E (Alg. 5.1)"],
  "algorithm.demonstration.rate_end": ["Expert-guided share at the end", "", "real", (b) => [range(b), "the share moves linearly to this over the step budget; empty = the same share throughout"], "R_E at the end of the step budget (Alg. 5.1 with a schedule)"],
  "algorithm.demonstration.credit": ["Expert credit", "false", "select", () => ["on: learn from an expert's episodes only once it has been judged against the agents' own, weighted by its credit (guards against faulty experts)"]],
};
/** Experts (MEDC, thesis Alg. 5.1): at most this many; a CID as the content store writes it. */
const MAX_EXPERTS = 16;
const CID_RE = /^b(?:afkrei|afybei)[a-z2-7]{52}$/;
/** Form field -> its path in the request body schema, where the two differ. */
const SCHEMA_PATH = { "env.walls_min": "env.walls[0]", "env.walls_max": "env.walls[1]", payment_eth: "payment_wei" };
const GROUPS = [
  ["env", "Environment", ["env.agents", "env.rows", "env.cols", "env.walls_min", "env.walls_max", "env.moves", "env.intensity"]],
  ["observation", "Observation", ["observation.kind", "observation.window", "observation.walls_embedding", "observation.walls_embedding_size"]],
  ["budget", "Training budget", ["budget.steps", "budget.minutes", "seed", "selection.keep_best", "selection.eval_every"]],
  ["recruit", "Recruitment and payment", ["domain", "num_workers", "min_reputation", "min_rating", "min_cpu_cores", "min_ram_gb", "deadline_s", "payment_eth"]],
  ["medc", "Experts (optional: learn from the demonstrations of shared models)", ["experts", "experts_from_mmc", "algorithm.demonstration.rate", "algorithm.demonstration.rate_end", "algorithm.demonstration.credit"]],
];
/** Server loc (after "body") -> the field showing its error. */
const LOC_ALIASES = {
  "env.walls.0": "env.walls_min", "env.walls.1": "env.walls_max", "env.walls": "env.walls_max",
  "payment_wei": "payment_eth", "env": "env", "observation": "observation", "budget": "budget",
  "expert_allocation": "experts_from_mmc", "algorithm.demonstration": "algorithm.demonstration.rate",
};

const fid = (name) => `f-${name.replace(/\./g, "-")}`;
const eid = (name) => `err-${name.replace(/\./g, "-")}`;
const boundsFor = (schema, name) => (schema ? schema.bounds(SCHEMA_PATH[name] || name) : null);

/** The values a select offers: the schema's enum, else the labelled ones. */
function options(schema, name) {
  const b = boundsFor(schema, name);
  const values = b && b.enum ? b.enum : Object.keys(LABELS[name]).filter((v) => v !== UNSET_OPTION[name]);
  const unset = name in UNSET_OPTION ? [UNSET_OPTION[name]] : [];
  return [...unset, ...values].map((v) => [String(v), LABELS[name][v] || String(v)]);
}

/** Intensity text -> {kind, values}: "1e9" fixed, "1e8,5e8,1e9" a set, "1e8:1e9" a range;
 *  each value and the count checked against the schema's variant of that kind. */
function parseIntensity(text, schema) {
  const t = text.trim();
  const nums = (parts) => parts.map((p) => (/^\s*[0-9.eE+-]+\s*$/.test(p) ? Number(p) : NaN));
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
  if (schema) {
    const variant = schema.at("env.intensity").find((v) => v.properties && v.properties.kind
      && v.properties.kind.const === kind);
    if (!variant) throw new Error(`this gateway takes no ${kind === "choice" ? "set" : kind} intensity`);
    const list = schema.variants(variant.properties.values)[0] || {};
    if (list.maxItems !== undefined && values.length > list.maxItems) throw new Error(`at most ${list.maxItems} values`);
    if (list.minItems !== undefined && values.length < list.minItems) throw new Error(`at least ${list.minItems} values`);
    const item = list.items ? schema.variants(list.items)[0] : null;
    for (const v of values) {
      const why = item && boundError(boundsOf(item), v);
      if (why) throw new Error(`${v}: ${why}`);
    }
  }
  return { kind, values };
}

/** Form values (strings) -> {body, errors: {field: msg}, buyExperts: K}; `schema` (or null)
 *  gives the bounds. K > 0: ask the MMC for K experts before submitting (POST /models/requests,
 *  then the task names the allocation: `expert_allocation`). */
export function buildTask(v, schema) {
  const errors = {};
  const number = (name, { required = true } = {}) => {
    const raw = (v[name] ?? "").trim();
    if (raw === "") { if (required) errors[name] = "required"; return undefined; }
    const n = Number(raw);
    const b = boundsFor(schema, name);
    const integer = b ? b.integer : FIELDS[name][2] === "int";
    if (!Number.isFinite(n)) { errors[name] = "must be a number"; return undefined; }
    if (integer && !Number.isInteger(n)) { errors[name] = "must be a whole number"; return undefined; }
    const why = boundError(b, n);
    if (why) { errors[name] = why; return undefined; }
    return n;
  };

  // Rules across fields that JSON Schema cannot say: checked here for a quick answer, and
  // re-checked by the gateway (TrainingSpec.from_dict), whose 422 names the same field.
  const rows = number("env.rows");
  const cols = number("env.cols");
  const agents = number("env.agents");
  const grid = rows !== undefined && cols !== undefined;
  if (agents !== undefined && grid && agents + 1 > rows * cols) {
    errors["env.agents"] = `${agents} agents and a target do not fit on ${rows}×${cols}`;
  }
  const wlo = number("env.walls_min");
  const whi = number("env.walls_max");
  if (wlo !== undefined && whi !== undefined && wlo > whi) errors["env.walls_max"] = "must be at least the minimum";
  else if (whi > 0 && grid && whi > Math.max(rows, cols)) errors["env.walls_max"] = `must be at most max(rows, cols) = ${Math.max(rows, cols)}`;
  else if (whi > 0 && grid && Math.min(rows, cols) < 4) errors["env.walls_max"] = "walls need a grid of at least 4×4";
  const moves = number("env.moves");
  let intensity;
  try { intensity = parseIntensity(v["env.intensity"] ?? "", schema); } catch (err) { errors["env.intensity"] = err.message; }

  const kind = (v["observation.kind"] || "").trim();
  const kinds = options(schema, "observation.kind").map(([k]) => k);
  if (!kinds.includes(kind)) errors["observation.kind"] = `choose one of ${kinds.join(", ")}`;
  const window = kind === "odmtl" ? number("observation.window") : undefined;
  if (window !== undefined && grid && !(window < Math.min(rows, cols))) {
    errors["observation.window"] = `must be less than ${Math.min(rows, cols)} (the smaller grid side)`;
  }
  // The walls CAE (Ch. 4): a model CID the gateway checks is a CAE bundle in its store.
  const cae = (v["observation.walls_embedding"] ?? "").trim();
  if (cae && !CID_RE.test(cae)) errors["observation.walls_embedding"] = `${cae} is not a model CID (bafkrei…/bafybei…, 59 characters)`;
  const caeSize = number("observation.walls_embedding_size", { required: false });
  if (caeSize !== undefined && !cae) errors["observation.walls_embedding_size"] = "applies only with a walls autoencoder";

  const steps = number("budget.steps", { required: false });
  const minutes = number("budget.minutes", { required: false });
  const budgetRule = schema && schema.object("budget");
  const given = [steps, minutes].filter((x) => x !== undefined).length;
  if (!errors["budget.steps"] && !errors["budget.minutes"] && budgetRule && given < (budgetRule.minProperties || 0)) {
    errors.budget = "give steps and/or minutes";
  }
  const seed = number("seed", { required: false });
  const domain = number("domain");
  const numWorkers = number("num_workers");
  const minRep = number("min_reputation");
  const minRating = number("min_rating");
  const minCpu = number("min_cpu_cores");
  const minRam = number("min_ram_gb");
  const deadline = number("deadline_s");
  let paymentWei;
  try {
    paymentWei = ethToWei(v.payment_eth ?? "");
    const why = weiError(boundsFor(schema, "payment_eth"), BigInt(paymentWei));
    if (why) { errors.payment_eth = why; paymentWei = undefined; }
  } catch (err) { errors.payment_eth = err.message; }

  // Experts: named CIDs, or K bought from the MMC; R_E applies only with one of them.
  const experts = (v.experts ?? "").split(/[\s,]+/).filter(Boolean);
  const notCid = experts.find((c) => !CID_RE.test(c));
  if (notCid) errors.experts = `${notCid} is not a model CID (bafkrei…/bafybei…, 59 characters)`;
  else if (new Set(experts).size !== experts.length) errors.experts = "an expert is named twice";
  else if (experts.length > MAX_EXPERTS) errors.experts = `at most ${MAX_EXPERTS} experts`;
  const buy = number("experts_from_mmc", { required: false });
  if (buy !== undefined && !(buy >= 0 && buy <= MAX_EXPERTS)) errors.experts_from_mmc = `0 to ${MAX_EXPERTS}`;
  else if (buy > 0 && experts.length) errors.experts_from_mmc = "name experts or buy them, not both";
  const rate = number("algorithm.demonstration.rate", { required: false });
  if (rate !== undefined && !experts.length && !(buy > 0)) errors["algorithm.demonstration.rate"] = "applies only with experts";
  const rateEnd = number("algorithm.demonstration.rate_end", { required: false });
  if (rateEnd !== undefined && !experts.length && !(buy > 0)) errors["algorithm.demonstration.rate_end"] = "applies only with experts";
  else if (rateEnd !== undefined && steps === undefined) errors["algorithm.demonstration.rate_end"] = "a rate schedule needs a step budget";
  const credit = (v["algorithm.demonstration.credit"] ?? "false") === "true";
  if (credit && !experts.length && !(buy > 0)) errors["algorithm.demonstration.credit"] = "applies only with experts";

  // Which policy is delivered: the final one (no selection) or the best evaluated one.
  const keepBest = (v["selection.keep_best"] ?? "").trim();
  if (!options(schema, "selection.keep_best").some(([k]) => k === keepBest)) errors["selection.keep_best"] = "choose one of the listed policies";
  const evalEvery = number("selection.eval_every", { required: false });
  if (evalEvery !== undefined && !keepBest) errors["selection.eval_every"] = "applies only when delivering the best policy";

  if (Object.keys(errors).length) return { body: null, errors, buyExperts: 0 };
  const budget = {};
  if (steps !== undefined) budget.steps = steps;
  if (minutes !== undefined) budget.minutes = minutes;
  const body = {
    env: { agents, rows, cols, walls: [wlo, whi], moves, intensity },
    observation: {
      ...(kind === "odmtl" ? { kind, window } : { kind }),
      ...(cae ? { walls_embedding: cae } : {}),
      ...(caeSize !== undefined ? { walls_embedding_size: caeSize } : {}),
    },
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
  if (experts.length) body.experts = experts;
  if (keepBest) body.selection = { keep_best: keepBest, ...(evalEvery !== undefined ? { eval_every: evalEvery } : {}) };
  const demonstration = {};
  if (rate !== undefined) demonstration.rate = rate;
  if (rateEnd !== undefined) demonstration.rate_end = rateEnd;
  if (credit) demonstration.credit = true;
  if (Object.keys(demonstration).length) body.algorithm = { demonstration };
  return { body, errors, buyExperts: buy > 0 ? buy : 0 };
}

/** A wei amount against the schema's bounds, exactly (BigInt: wei passes 2^53). */
function weiError(b, wei) {
  if (!b) return null;
  const int = (x) => BigInt(Math.ceil(x));
  if (b.min !== undefined && wei < int(b.min)) return `must be at least ${formatWei(int(b.min))}`;
  if (b.max !== undefined && wei > BigInt(Math.floor(b.max))) return `must be at most ${formatWei(BigInt(Math.floor(b.max)))}`;
  if (b.exclusiveMax !== undefined && wei >= int(b.exclusiveMax)) return `too large: must be less than ${formatWei(int(b.exclusiveMax))}`;
  return null;
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

export async function render(main, params, ctx) {
  document.title = "Submit a task · DRLaaS";
  const schema = await requestSchema("post", "/api/tasks");
  if (ctx && ctx.stopped) return;
  const signedIn = Boolean(getToken());
  const formError = h("div", { id: "form-error", role: "alert" });
  const result = h("div", { id: "submit-result" });
  let purchase = null; // {key, answer}: the experts bought for this form's environment

  const control = (name) => {
    const [label, def, input, help, tip] = FIELDS[name];
    const b = boundsFor(schema, name);
    const common = { id: fid(name), name, "aria-describedby": eid(name) };
    let el;
    if (input === "select") {
      const opts = options(schema, name);
      const value = opts.some(([v]) => v === def) ? def : opts[0][0];
      el = h("select", { ...common, value }, opts.map(([v, text]) => h("option", { value: v }, text)));
    } else if (input === "text") {
      el = h("input", { ...common, type: "text", value: def, inputmode: name === "payment_eth" ? "decimal" : undefined });
    } else {
      el = h("input", { ...common, type: "number", step: input === "int" ? 1 : "any", ...inputAttrs(b), value: def });
    }
    const text = typeof help === "function" ? [].concat(help(b)).filter(Boolean).join(", ") : help;
    return h("div", { class: "field", "data-field": name },
      h("label", { for: fid(name), title: tip }, label), el,
      text ? h("small", { class: "help" }, text) : null,
      h("div", { class: "field-error", id: eid(name) }));
  };

  const form = h("form", { id: "task-form", novalidate: true, class: "task-form", "data-bounds": schema ? "openapi" : "none" },
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
    const { body } = buildTask(values(), schema);
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
    const { body, errors, buyExperts } = buildTask(values(), schema);
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
      let bought = null;
      if (buyExperts) { // the MMC's paid model-sharing allocation (Eq. 10-13 / 22-23)
        const request = { domain: body.domain, env: body.env, num_models: buyExperts };
        const key = JSON.stringify(request);
        if (!purchase || purchase.key !== key) { // bought once: a refused task does not buy again
          purchase = { key, answer: await api("/models/requests", { method: "POST", body: request }) };
        }
        bought = purchase.answer;
        body.expert_allocation = bought.alloc_id;
      }
      const answer = await api("/tasks", { method: "POST", rawBody: toJson(body) });
      purchase = null;
      const tid = answer.task_id ?? answer.id;
      result.replaceChildren(h("div", { class: "ok-box", role: "status" },
        bought ? h("p", { id: "bought-experts" }, `Allocation #${bought.alloc_id}: ${bought.models.length} expert(s) bought, `,
          bought.models.map((m, i) => [i ? ", " : "", h("code", { class: "mono" }, m.cid), ` (match score ${fmt(m.qos)})`]), ". ") : null,
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
        if (err.rule === "sign_locally") {
          extra.push(" This gateway holds no key for you: sign the transaction below with your own key and POST it to /api/tx, or use the drlaas CLI.");
        }
        // 401: the API's text is for API clients (a bearer header); a browser user signs in
        const message = err.status === 401 ? "Sign in first (top right): the task is created as your address." : err.message;
        formError.appendChild(h("p", { class: "warn", "data-rule": err.rule || "" }, message, extra.join("")));
        if (err.rule === "tasks_not_requester") {
          formError.appendChild(h("button", { type: "button", class: "small", id: "register-requester", onclick: async (ev) => {
            try {
              const reg = await api("/users/requesters", { method: "POST", body: {} });
              ev.target.replaceWith(reg && reg.status === "pending"
                ? h("span", { class: "warn" }, "Registered: a consortium admin must approve you before you can submit.")
                : h("span", { class: "ok" }, "Registered: submit again."));
            }
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
      + "offers the task first to the best-matching workers that meet your requirements."),
    schema ? null : h("p", { class: "muted", id: "bounds-note" },
      "The gateway's limits could not be read: they are checked when you submit."),
    form, result));
  preview();
}
