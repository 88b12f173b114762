// The Gantt timeline of one mission: per unit, each task's planned interval (outline) above its
// actual one (filled; still open ones run to "now"), in seconds from the mission's start. SVG.
// A search shared among units shows each part in its unit's lane (the tree keeps one node).

import { STATUS_COLORS, unitColor } from "./colors.js";

const NS = "http://www.w3.org/2000/svg";
const ROW = 30;
const LEFT = 64;
const TOP = 18;

function el(name, attrs, text) {
  const e = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
  if (text !== undefined) e.textContent = text;
  return e;
}

/** Every task node of a tree (nodes with an execunit or plan times), depth first; a shared
 * search's parts instead of its node (each on its unit, `partOf` naming the search). */
export function taskNodes(node, out = []) {
  if (!node) return out;
  const children = node.children || [];
  if (node.parts && node.parts.length) {
    for (const p of node.parts) out.push(Object.assign({}, p, { execunit: p.unit, name: `${node.name} ${p.part}`, partOf: node.uuid }));
  } else if (children.length === 0 || node.execunit) out.push(node);
  for (const c of children) taskNodes(c, out);
  return out;
}

function niceTick(span) {
  const raw = span / 6;
  const p = Math.pow(10, Math.floor(Math.log10(raw || 1)));
  for (const f of [1, 2, 5, 10]) if (f * p >= raw) return f * p;
  return 10 * p;
}

/** Draw into `container` (replacing its content) for `tree` with `elapsed` seconds so far. */
export function renderGantt(container, tree, elapsed) {
  const tasks = taskNodes(tree);
  const units = [...new Set(tasks.map((t) => (t.execunit || "?").replace(/^\//, "")))].sort();
  let end = elapsed || 0;
  for (const t of tasks) {
    end = Math.max(end, t["plan-end"] || 0, t["actual-end"] || 0);
  }
  end = Math.max(end, 1) * 1.05;
  const width = Math.max(container.clientWidth || 400, 300);
  const height = TOP + units.length * ROW + 8;
  const x = (s) => LEFT + (s / end) * (width - LEFT - 8);
  const svg = el("svg", { width, height, viewBox: `0 0 ${width} ${height}`, id: "gantt-svg" });
  const tick = niceTick(end);
  for (let s = 0; s <= end; s += tick) {
    svg.append(el("line", { x1: x(s), x2: x(s), y1: TOP - 4, y2: height, stroke: "#e3e7ec" }));
    svg.append(el("text", { x: x(s), y: 11, "text-anchor": "middle", class: "tick" }, `${Math.round(s)}`));
  }
  units.forEach((u, i) => {
    const y = TOP + i * ROW;
    svg.append(el("text", { x: 4, y: y + ROW / 2 + 4, class: "unit", fill: unitColor(u) }, u));
    for (const t of tasks.filter((n) => (n.execunit || "?").replace(/^\//, "") === u)) {
      const ps = t["plan-start"];
      const pe = t["plan-end"];
      const g = el("g", { "data-node-uuid": t.uuid, "data-status": t.status || "" });
      g.setAttribute("data-unit", u);
      if (t.partOf) g.setAttribute("data-part-of", t.partOf);
      const title = el("title", {}, `${t.name} on ${u}: plan ${fmt(ps)}–${fmt(pe)} s, actual ${fmt(t["actual-start"])}–${fmt(t["actual-end"])} s, ${t.status || "not started"}`);
      g.append(title);
      if (ps !== null && ps !== undefined && pe !== null && pe !== undefined) {
        g.append(el("rect", {
          class: "plan", x: x(ps), y: y + 3, width: Math.max(x(pe) - x(ps), 1.5), height: 10,
          fill: "none", stroke: unitColor(u), "stroke-width": 1.5,
        }));
      }
      const as = t["actual-start"];
      if (as !== null && as !== undefined) {
        const ae = t["actual-end"] ?? elapsed ?? as;
        g.append(el("rect", {
          class: "actual", x: x(as), y: y + 15, width: Math.max(x(ae) - x(as), 1.5), height: 10,
          fill: STATUS_COLORS[t.status] || unitColor(u), opacity: t["actual-end"] == null ? 0.6 : 0.9,
        }));
      }
      svg.append(g);
    }
  });
  if (elapsed !== null && elapsed !== undefined) {
    svg.append(el("line", { x1: x(elapsed), x2: x(elapsed), y1: TOP - 4, y2: height, stroke: "#c0392b", "stroke-dasharray": "3 2", id: "gantt-now" }));
  }
  container.replaceChildren(svg);
}

function fmt(v) {
  return v === null || v === undefined ? "–" : v.toFixed(0);
}
