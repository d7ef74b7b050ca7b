// Training curves as inline SVG: no chart library, crisp at any size, testable in the DOM.

import { h, s } from "./dom.js";

const W = 480, H = 240, M = { top: 14, right: 16, bottom: 38, left: 56 };
export const COLORS = ["#2563eb", "#dc2626", "#16a34a", "#9333ea", "#ea580c", "#0891b2", "#4b5563"];

/** Smallest span an axis gets around `v`: well above float resolution, so that a step of
 * it moves a tick (two values one ulp apart made `t += step` stand still for ever). */
function minSpan(v) {
  return Math.max(Math.abs(v) * 1e-9, 1e-12);
}

/** About n "nice" ticks (1, 2, 5 x 10^k steps) covering [lo, hi]; at most 4n + 2 of them. */
export function niceTicks(lo, hi, n = 5) {
  if (!Number.isFinite(lo) || !Number.isFinite(hi) || !(hi > lo)) return [lo];
  const raw = Math.max(hi - lo, minSpan(hi)) / n;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((st) => st >= raw) || 10 * mag;
  const first = Math.ceil(lo / step) * step;
  const ticks = [];
  for (let i = 0; i <= 4 * n + 1; i++) {
    const t = first + i * step; // not accumulated: each tick is computed, never stuck
    if (t > hi + step * 1e-9) break;
    ticks.push(Number(t.toPrecision(12)));
  }
  return ticks.length ? ticks : [lo];
}

/** An axis label in human units: 1.5k, 2M, 3G, 4T; past that (and below 0.001) a power of ten,
 * as 2e15 or 5e-5 (1e12 steps read "1000000M", and ticks of 5e-5 apart all read "0"). */
export function fmtTick(v) {
  const a = Math.abs(v);
  if (a >= 1e15 || (a > 0 && a < 1e-3)) return v.toExponential(1).replace(/\.0e/, "e").replace("e+", "e");
  for (const [unit, size] of [["T", 1e12], ["G", 1e9], ["M", 1e6], ["k", 1e3]]) {
    if (a >= size) return `${+(v / size).toFixed(1)}${unit}`;
  }
  return `${+v.toFixed(3)}`;
}

/** Smallest and largest of many numbers (Math.min(...xs) throws a RangeError past ~10^5). */
function extent(values) {
  let lo = Infinity, hi = -Infinity;
  for (const v of values) { if (v < lo) lo = v; if (v > hi) hi = v; }
  return [lo, hi];
}

/** At most MAX_DRAWN points of a line sorted by x, for a plot ~400 px wide: per slice of the
 * points, its first, lowest, highest and last (in x order), so that no spike disappears. A
 * card or a worker may hold 10^6 points; a polyline of all of them froze the page. */
export const MAX_DRAWN = 2000;
export function thin(points, max = MAX_DRAWN) {
  if (points.length <= max) return points;
  const slices = Math.floor(max / 4);
  const out = [];
  for (let k = 0; k < slices; k++) {
    const a = Math.floor((k * points.length) / slices), b = Math.floor(((k + 1) * points.length) / slices);
    let lo = a, hi = a;
    for (let i = a + 1; i < b; i++) {
      if (points[i][1] < points[lo][1]) lo = i;
      if (points[i][1] > points[hi][1]) hi = i;
    }
    for (const i of [...new Set([a, lo, hi, b - 1])].sort((x, y) => x - y)) out.push(points[i]);
  }
  return out;
}

/**
 * series: [{label, points: [[x, y], ...], color?}]; yDomain: [lo, hi] to fix the y axis
 * (e.g. [0, 1] for a success rate). Non-finite points are dropped; a line of more than
 * MAX_DRAWN points is drawn thinned (its data-count stays the number of points).
 */
export function lineChart({ title, series, xLabel = "environment steps", yLabel = "", yDomain }) {
  const clean = series
    .map((se, i) => ({
      ...se,
      color: se.color || COLORS[i % COLORS.length],
      points: se.points.filter(([x, y]) => Number.isFinite(x) && Number.isFinite(y))
        .sort((a, b) => a[0] - b[0]),
    }))
    .filter((se) => se.points.length > 0);
  const figure = h("figure", { class: "chart", "data-chart": title || yLabel });
  if (title) figure.appendChild(h("figcaption", {}, title));
  if (clean.length === 0) {
    figure.appendChild(h("p", { class: "muted empty-chart" }, "No points yet."));
    return figure;
  }
  const [xMin, xMax] = extent(clean.flatMap((se) => se.points.map((p) => p[0])));
  const [yMin, yMax] = extent(clean.flatMap((se) => se.points.map((p) => p[1])));
  let [x0, x1] = [xMin, xMax];
  let [y0, y1] = yDomain || [yMin, yMax];
  if (yDomain) { y0 = Math.min(y0, yMin); y1 = Math.max(y1, yMax); }
  if (x1 - x0 < minSpan(x1)) { const pad = Math.max(1, Math.abs(x1) * 1e-6); x0 -= pad; x1 += pad; }
  if (y1 - y0 < minSpan(y1)) { const pad = Math.max(0.5, Math.abs(y1) * 1e-6); y0 -= pad; y1 += pad; }
  const pw = W - M.left - M.right, ph = H - M.top - M.bottom;
  const sx = (x) => M.left + ((x - x0) / (x1 - x0)) * pw;
  const sy = (y) => M.top + ph - ((y - y0) / (y1 - y0)) * ph;

  const svg = s("svg", { viewBox: `0 0 ${W} ${H}`, class: "chart-svg", role: "img",
    "aria-label": `${title || yLabel} against ${xLabel}` });
  for (const t of niceTicks(y0, y1, 4)) {
    svg.appendChild(s("line", { class: "grid", x1: M.left, x2: W - M.right, y1: sy(t), y2: sy(t) }));
    svg.appendChild(s("text", { class: "tick", x: M.left - 6, y: sy(t) + 4, "text-anchor": "end" }, fmtTick(t)));
  }
  for (const t of niceTicks(x0, x1, 5)) {
    svg.appendChild(s("line", { class: "grid", x1: sx(t), x2: sx(t), y1: M.top, y2: M.top + ph }));
    svg.appendChild(s("text", { class: "tick", x: sx(t), y: H - M.bottom + 16, "text-anchor": "middle" }, fmtTick(t)));
  }
  svg.appendChild(s("rect", { class: "frame", x: M.left, y: M.top, width: pw, height: ph, fill: "none" }));
  svg.appendChild(s("text", { class: "axis-label", x: M.left + pw / 2, y: H - 4, "text-anchor": "middle" }, xLabel));
  if (yLabel) {
    svg.appendChild(s("text", { class: "axis-label", x: 12, y: M.top + ph / 2, "text-anchor": "middle",
      transform: `rotate(-90 12 ${M.top + ph / 2})` }, yLabel));
  }
  for (const se of clean) {
    const pts = thin(se.points).map(([x, y]) => `${sx(x).toFixed(1)},${sy(y).toFixed(1)}`).join(" ");
    svg.appendChild(s("polyline", { class: "series", points: pts, stroke: se.color, fill: "none",
      "data-series": se.label, "data-count": se.points.length }));
    if (se.points.length === 1) {
      const [x, y] = se.points[0];
      svg.appendChild(s("circle", { cx: sx(x), cy: sy(y), r: 3, fill: se.color }));
    }
  }
  figure.appendChild(svg);
  if (clean.length > 1 || clean[0].label) {
    figure.appendChild(h("div", { class: "legend" }, clean.map((se) =>
      h("span", { class: "legend-item" }, h("i", { style: `background:${se.color}` }), se.label))));
  }
  return figure;
}

const X_KEYS = ["global_step", "step", "env_steps", "steps"];
/** Which curves to draw, and which point keys feed them (first present key wins per series). */
const PANELS = [
  { title: "Success rate", yLabel: "success", yDomain: [0, 1],
    series: [["training", ["success"]], ["evaluation", ["eval_success"]]] },
  { title: "Search time", yLabel: "steps per episode",
    series: [["training", ["time", "episode_length"]], ["evaluation", ["eval_time"]]] },
  { title: "Cost", yLabel: "cost per episode",
    series: [["training", ["cost", "episode_cost"]], ["evaluation", ["eval_cost"]]] },
  // DC / MEDC tasks only: the share of each update's episodes that an expert guided (R_E)
  { title: "Expert-guided episodes", yLabel: "share of episodes", yDomain: [0, 1],
    series: [["guided", ["guided_share"]]] },
];

function xOf(p, i) {
  for (const k of X_KEYS) if (p[k] !== undefined && p[k] !== null) return Number(p[k]);
  return i;
}

/**
 * Curve panels from metric points ({global_step|step, success, time, cost, eval_*...}).
 * groupBy (e.g. "worker") draws one line per group instead of training/evaluation lines.
 */
export function curvePanels(points, { groupBy } = {}) {
  const rows = (points || []).filter((p) => p && typeof p === "object");
  const panels = [];
  for (const panel of PANELS) {
    let series = [];
    if (groupBy) {
      const keys = panel.series[0][1];
      const groups = new Map();
      rows.forEach((p, i) => {
        const key = keys.find((k) => p[k] !== undefined && p[k] !== null && p[k] !== "");
        if (!key) return;
        const g = String(p[groupBy] ?? "");
        if (!groups.has(g)) groups.set(g, []);
        groups.get(g).push([xOf(p, i), Number(p[key])]);
      });
      series = [...groups].map(([g, pts]) => ({
        label: g.length > 14 ? `${g.slice(0, 6)}…${g.slice(-4)}` : g, points: pts }));
    } else {
      for (const [label, keys] of panel.series) {
        const pts = [];
        rows.forEach((p, i) => {
          const key = keys.find((k) => p[k] !== undefined && p[k] !== null && p[k] !== "");
          if (key) pts.push([xOf(p, i), Number(p[key])]);
        });
        if (pts.length) series.push({ label, points: pts });
      }
    }
    if (panel.yDomain) { // a rate outside [0, 1] is none (an extra metric of 1e300 flattened the rest)
      const [lo, hi] = panel.yDomain;
      series = series.map((se) => ({ ...se, points: se.points.filter(([, y]) => y >= lo && y <= hi) }));
    }
    if (series.some((se) => se.points.length)) {
      panels.push(lineChart({ title: panel.title, series, yLabel: panel.yLabel, yDomain: panel.yDomain }));
    }
  }
  return panels;
}
