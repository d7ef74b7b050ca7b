// The gateway's own description of a request body (its OpenAPI document, GET /api/openapi.json):
// the task form takes every bound from here, so the form and the gateway cannot drift apart.
// The document is JSON Schema 2020-12 as FastAPI and pydantic emit it: "$ref" into
// #/components/schemas, "allOf" wrapping a $ref, "anyOf" for a nullable or many-shaped value.

import { api } from "./api.js";

let openapi = null; // the promise of the document, asked once per page load

/** The OpenAPI document, or null when the gateway does not serve one (the form then leaves the
 *  bounds to the gateway, whose 422 names the field). A failed fetch is retried next time. */
export function loadOpenApi() {
  openapi ||= api("/openapi.json", { auth: false }).catch((err) => {
    console.warn(`no OpenAPI document (${err.message}): the gateway checks the bounds`);
    openapi = null;
    return null;
  });
  return openapi;
}

/** The request body schema of `method path` ("post", "/api/tasks"), or null. */
export async function requestSchema(method, path) {
  const doc = await loadOpenApi();
  const op = doc && doc.paths && doc.paths[path] && doc.paths[path][method];
  const body = op && op.requestBody && op.requestBody.content && op.requestBody.content["application/json"];
  return body && body.schema ? new Schema(doc, body.schema) : null;
}

/** "env.walls[0]" -> ["env", "walls", 0] (a number steps into an array's items). */
function parsePath(path) {
  return path.split(".").flatMap((part) => {
    const [name, ...idx] = part.split(/[[\]]+/).filter((x) => x !== "");
    return [name, ...idx.map(Number)];
  });
}

/** A schema inside `doc`, queried by field path. */
export class Schema {
  constructor(doc, root) {
    this.doc = doc;
    this.root = root;
  }

  /** Follow "#/..." references (JSON Pointer); a reference elsewhere, or a loop, gives {}. */
  deref(s) {
    for (let hops = 0; s && s.$ref; hops++) {
      if (hops > 32 || !s.$ref.startsWith("#/")) return {};
      s = s.$ref.slice(2).split("/")
        .map((k) => k.replace(/~1/g, "/").replace(/~0/g, "~"))
        .reduce((node, key) => (node && typeof node === "object" ? node[key] : undefined), this.doc);
    }
    return s && typeof s === "object" ? s : {};
  }

  /** The alternatives a value may take: anyOf/oneOf split into their members, allOf merged into
   *  one schema (members' keys together, properties joined), $refs resolved, "null" dropped. */
  variants(s) {
    s = this.deref(s);
    const alternatives = s.anyOf || s.oneOf;
    if (alternatives) {
      const { anyOf, oneOf, ...rest } = s;
      return alternatives.flatMap((a) => this.variants(a).map((v) => this.merge(rest, v)));
    }
    if (s.allOf) {
      const { allOf, ...rest } = s;
      const parts = allOf.map((a) => this.variants(a));
      // allOf of one-variant members is the common case (pydantic's {allOf: [{$ref}]}).
      return parts.reduce((acc, vs) => acc.flatMap((a) => vs.map((v) => this.merge(a, v))), [rest]);
    }
    return s.type === "null" ? [] : [s];
  }

  merge(a, b) {
    const out = { ...a, ...b };
    if (a.properties && b.properties) out.properties = { ...a.properties, ...b.properties };
    for (const k of ["minimum", "exclusiveMinimum", "minItems"]) {
      if (k in a && k in b) out[k] = Math.max(a[k], b[k]);
    }
    for (const k of ["maximum", "exclusiveMaximum", "maxItems"]) {
      if (k in a && k in b) out[k] = Math.min(a[k], b[k]);
    }
    return out;
  }

  /** The variants of the field at `path` ("budget.steps", "env.walls[1]"); [] if unknown. */
  at(path) {
    let here = this.variants(this.root);
    for (const key of parsePath(path)) {
      here = here.flatMap((s) => {
        if (typeof key === "number") {
          const item = (s.prefixItems && s.prefixItems[key]) || s.items;
          return item ? this.variants(item) : [];
        }
        return s.properties && key in s.properties ? this.variants(s.properties[key]) : [];
      });
    }
    return here;
  }

  /** The bounds of a number (or enum) field at `path`, or null when the schema has none. */
  bounds(path) {
    const s = this.at(path).find((v) => v.enum || v.const !== undefined
      || v.type === "integer" || v.type === "number");
    return s ? boundsOf(s) : null;
  }

  /** The schema at `path` (its first variant), e.g. for an object's minProperties. */
  object(path) {
    return this.at(path)[0] || null;
  }
}

/** The numeric rules of one schema, in the names the form uses. */
export function boundsOf(s) {
  const odd = Boolean(s.not && s.not.multipleOf === 2);
  return {
    integer: s.type === "integer",
    enum: s.enum || (s.const !== undefined ? [s.const] : undefined),
    min: s.minimum,
    max: s.maximum,
    exclusiveMin: s.exclusiveMinimum,
    exclusiveMax: s.exclusiveMaximum,
    multipleOf: s.multipleOf,
    odd,
  };
}

/** <input> attributes of bounds: min, max, step (an exclusive bound of an integer becomes the
 *  next integer inside it; of a real number it has no attribute and only the check below). */
export function inputAttrs(b) {
  if (!b) return {};
  const a = {};
  if (b.min !== undefined) a.min = b.min;
  else if (b.exclusiveMin !== undefined && b.integer) a.min = Math.floor(b.exclusiveMin) + 1;
  if (b.max !== undefined) a.max = b.max;
  else if (b.exclusiveMax !== undefined && b.integer) a.max = Math.ceil(b.exclusiveMax) - 1;
  if (b.multipleOf !== undefined) a.step = b.multipleOf;
  else if (b.odd && a.min !== undefined && Math.abs(a.min % 2) === 1) a.step = 2;
  else a.step = b.integer ? 1 : "any";
  return a;
}

/** A bound in a message: 1000, 16, 0.1, 1,000,000,000 (commas past six digits). */
export function fmt(n) {
  return Math.abs(n) >= 1e6 ? n.toLocaleString("en-US", { maximumFractionDigits: 20 }) : String(n);
}

/** Why number `n` breaks bounds `b`, or null. */
export function boundError(b, n) {
  if (!b) return null;
  if (b.enum && !b.enum.includes(n)) return `must be one of ${b.enum.join(", ")}`;
  if (b.min !== undefined && n < b.min) return `must be at least ${fmt(b.min)}`;
  if (b.exclusiveMin !== undefined && n <= b.exclusiveMin) return `must be greater than ${fmt(b.exclusiveMin)}`;
  if (b.max !== undefined && n > b.max) return `must be at most ${fmt(b.max)}`;
  if (b.exclusiveMax !== undefined && n >= b.exclusiveMax) return `must be less than ${fmt(b.exclusiveMax)}`;
  if (b.multipleOf !== undefined && !Number.isInteger(n / b.multipleOf)) return `must be a multiple of ${b.multipleOf}`;
  if (b.odd && Math.abs(n % 2) !== 1) return "must be odd";
  return null;
}
