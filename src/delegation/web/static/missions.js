// The missions panel (one row per mission) and the detail of the selected mission: its controls,
// its tree with per-node status and its Gantt timeline.

import * as api from "./api.js";
import { ENDED } from "./colors.js";
import { badge, h, say, secs } from "./dom.js";
import { renderGantt } from "./gantt.js";

/** Mission seconds per wall second: a simulated fleet's speed-up, when the server says one. */
let timeScale = 1;

export function setTimeScale(scale) {
  timeScale = scale > 0 ? scale : 1;
}

/** Seconds since the mission started, counted on from the server's last figure. */
export function elapsedNow(m) {
  if (m.elapsed === null || m.elapsed === undefined) return null;
  if (ENDED.has(m.status) || m["ended-at"]) return m.elapsed;
  return m.elapsed + ((performance.now() - m._receivedAt) / 1000) * timeScale;
}

function makespanCell(m) {
  return `${secs(m["planned-makespan"])} / ${secs(elapsedNow(m))}`;
}

export class MissionsPanel {
  constructor(store) {
    this.store = store;
    this.body = document.querySelector("#missions tbody");
    this.empty = document.getElementById("missions-empty");
    this.rows = new Map();
    this.body.addEventListener("click", (ev) => {
      const tr = ev.target.closest("tr[data-mission-id]");
      if (tr) store.select(tr.dataset.missionId);
    });
  }

  render() {
    const missions = [...this.store.missions.values()].sort(
      (a, b) => (b["started-at"] ?? b._order) - (a["started-at"] ?? a._order) || b._order - a._order,
    );
    for (const [id, tr] of this.rows) {
      if (!this.store.missions.has(id)) {
        tr.remove();
        this.rows.delete(id);
      }
    }
    let prev = null;
    for (const m of missions) {
      let tr = this.rows.get(m.id);
      const cells = [
        h("td", { class: "name", title: m.id }, m.name || m.id.slice(0, 8)),
        h("td", {}, badge(m.status)),
        h("td", { class: "strategy" }, strategyText(m)),
        h("td", { class: "makespan" }, makespanCell(m)),
        h("td", {}, m.owner || "–"),
      ];
      if (!tr) {
        tr = h("tr", { "data-mission-id": m.id, id: `mission-${m.id}` });
        this.rows.set(m.id, tr);
      }
      tr.dataset.status = m.status;
      tr.classList.toggle("selected", this.store.selected === m.id);
      tr.replaceChildren(...cells);
      if (prev ? prev.nextSibling !== tr : this.body.firstChild !== tr) {
        if (prev) prev.after(tr);
        else this.body.prepend(tr);
      }
      prev = tr;
    }
    this.empty.hidden = missions.length > 0;
  }

  /** Once a second: the elapsed column of running missions. */
  tick() {
    for (const [id, tr] of this.rows) {
      const m = this.store.missions.get(id);
      if (m && !ENDED.has(m.status)) {
        const td = tr.querySelector("td.makespan");
        if (td) td.textContent = makespanCell(m);
      }
    }
  }
}

function treeItem(node) {
  const parts = node.parts || [];
  // a search shared among units: one node, naming its units (its parts are on the timeline)
  const unit = parts.length
    ? [...new Set(parts.map((p) => p.unit))].join(", ")
    : node.execunit ? node.execunit.replace(/^\//, "") : null;
  const li = h(
    "li",
    { "data-node-uuid": node.uuid, "data-status": node.status || "", "data-parts": parts.length || null },
    h("span", { class: "node-name" }, node.name),
    unit ? h("span", { class: "node-unit", title: parts.length ? `shared: ${parts.length} parts` : "" }, ` @ ${unit}`) : null,
    " ",
    badge(node.status),
  );
  const kids = node.children || [];
  if (kids.length) li.append(h("ul", {}, ...kids.map(treeItem)));
  return li;
}

export class MissionDetail {
  constructor(store) {
    this.store = store;
    this.panel = document.getElementById("mission-detail");
    this.error = document.getElementById("detail-error");
    this.response = document.getElementById("detail-response");
    document.getElementById("detail-close").addEventListener("click", () => store.select(null));
    for (const b of this.panel.querySelectorAll("button[data-signal]")) {
      b.addEventListener("click", () => this.act(() => api.signal(this.store.selected, b.dataset.signal), b.dataset.signal));
    }
    document.getElementById("btn-cancel").addEventListener("click", () =>
      this.act(() => api.cancel(this.store.selected), "cancel"),
    );
  }

  async act(fn, what) {
    say(this.error, "");
    say(this.response, "");
    try {
      const res = await fn();
      say(this.response, `${what}: ${res && res.response !== undefined ? res.response : "ok"}`);
    } catch (err) {
      say(this.error, `${what} refused: ${err.failReason || err.message}`);
    }
  }

  render() {
    const id = this.store.selected;
    const m = id ? this.store.missions.get(id) : null;
    this.panel.hidden = !m;
    if (!m) return;
    this.panel.dataset.missionId = m.id;
    this.panel.dataset.status = m.status;
    document.getElementById("detail-name").textContent = m.name || m.id.slice(0, 8);
    document.getElementById("detail-status").replaceWith(
      Object.assign(badge(m.status), { id: "detail-status" }),
    );
    const meta = [
      ["id", m.id],
      ["owner", m.owner],
      ["strategy", strategyText(m)],
      ["objective", m.objective],
      ["makespan plan / elapsed", makespanCell(m)],
      ["units", (m.units || []).join(", ")],
    ];
    document.getElementById("detail-meta").replaceChildren(
      h("dl", {}, ...meta.flatMap(([k, v]) => [h("dt", {}, k), h("dd", { "data-field": k }, v || "–")])),
      m["fail-reason"] ? h("p", { class: "error", id: "detail-fail-reason" }, m["fail-reason"]) : "",
    );
    const ended = ENDED.has(m.status);
    for (const b of this.panel.querySelectorAll("#detail-buttons button")) b.disabled = ended;
    const d = this.store.details.get(id);
    if (d && d.tree) {
      document.getElementById("tree").replaceChildren(treeItem(d.tree));
      renderGantt(document.getElementById("gantt"), d.tree, elapsedNow(m));
    } else {
      document.getElementById("tree").replaceChildren(h("li", { class: "empty" }, d && d.error ? d.error : "loading…"));
      document.getElementById("gantt").replaceChildren();
    }
    const notes = d && d.plan && d.plan.notes;
    const notesText = Array.isArray(notes) ? notes.join("\n") : notes || "";
    document.getElementById("detail-notes").textContent = notesText;
    document.getElementById("detail-notes-wrap").hidden = !notesText;
  }

  tick() {
    const m = this.store.selected && this.store.missions.get(this.store.selected);
    if (!m || ENDED.has(m.status)) return;
    const dd = this.panel.querySelector('dd[data-field="makespan plan / elapsed"]');
    if (dd) dd.textContent = makespanCell(m);
    const d = this.store.details.get(m.id);
    if (d && d.tree) renderGantt(document.getElementById("gantt"), d.tree, elapsedNow(m));
  }
}

/** The strategy as the plan says it: `optimal (= auction)` when it kept another's plan. */
function strategyText(m) {
  if (!m.strategy) return "–";
  return m.fallback ? `${m.strategy} (= ${m.fallback})` : m.strategy;
}
