// The submit panel: paste or drop a mission file, preview its plan with each strategy (a dry run,
// POST /api/plan), suggest the best by the chosen objective, draw the plan the operator picks (a
// click on its row), start that very plan (POST /api/missions naming its preview-id; the Start
// button names its strategy). The service starts the plan previewed, or plans again if it no
// longer holds (a unit lost or moved) and says why: shown beside the started mission's id.

import * as api from "./api.js";
import { h, say, secs } from "./dom.js";

/** A plan's rank for the suggestion, lowest best: complete plans before plans with unassigned
 * tasks or marked infeasible (fewer tasks make a shorter plan), then the objective the operator
 * chose (makespan or total time), then the other one, then distance; unknown values last. */
function rank(p, objective) {
  const num = (v) => (typeof v === "number" && Number.isFinite(v) ? v : Infinity);
  const [first, second] = objective === "total" ? ["total-time", "makespan"] : ["makespan", "total-time"];
  return [p.feasible === false ? 1 : 0, (p.unassigned || []).length, num(p[first]), num(p[second]), num(p["total-distance"])];
}

function better(a, b) {
  for (let i = 0; i < a.length; i++) if (a[i] !== b[i]) return a[i] < b[i];
  return false;
}

/** The strategy whose previewed plan the page suggests (null when none was planned); the first
 * of equals, in the order the plans came (the order of the strategies ticked). */
export function suggest(plans, objective) {
  let best = null;
  for (const [name, p] of Object.entries(plans)) {
    if (p["fail-reason"]) continue;
    if (best === null || better(rank(p, objective), rank(plans[best], objective))) best = name;
  }
  return best;
}

function metres(v) {
  if (v === null || v === undefined) return "–";
  return v >= 10000 ? `${(v / 1000).toFixed(1)} km` : `${Math.round(v)} m`;
}

export class SubmitPanel {
  constructor(store, config) {
    this.store = store;
    this.text = document.getElementById("mission-text");
    this.error = document.getElementById("submit-error");
    this.result = document.getElementById("submit-result");
    this.busy = document.getElementById("submit-busy");
    this.table = document.getElementById("preview");
    this.plans = {};
    this.chosen = null;
    const choices = document.getElementById("strategy-choices");
    for (const s of config.strategies || []) {
      choices.append(
        h("label", { class: "strategy" }, h("input", { type: "checkbox", value: s, checked: true, "data-strategy": s }), ` ${s}`),
      );
    }
    const objective = document.getElementById("objective");
    for (const o of config.objectives || ["makespan", "total"]) objective.append(h("option", { value: o }, o));
    this.objective = objective;
    this.timeLimit = document.getElementById("time-limit");

    const zone = document.getElementById("drop-zone");
    zone.addEventListener("dragover", (ev) => {
      ev.preventDefault();
      zone.classList.add("over");
    });
    zone.addEventListener("dragleave", () => zone.classList.remove("over"));
    zone.addEventListener("drop", (ev) => {
      ev.preventDefault();
      zone.classList.remove("over");
      const f = ev.dataTransfer && ev.dataTransfer.files[0];
      if (f) this.load(f);
    });
    document.getElementById("mission-file").addEventListener("change", (ev) => {
      const f = ev.target.files[0];
      if (f) this.load(f);
    });
    this.text.addEventListener("input", () => this.forget());
    // Start starts the previewed plan (planned with the objective and time limit in the form):
    // changing either after a preview means the operator no longer compares that plan.
    this.objective.addEventListener("change", () => this.forget());
    this.timeLimit.addEventListener("input", () => this.forget());
    this.startButton = document.getElementById("btn-start");
    document.getElementById("btn-preview").addEventListener("click", () => this.preview());
    document.getElementById("btn-start").addEventListener("click", () => this.start());
    this.table.querySelector("tbody").addEventListener("change", (ev) => {
      if (ev.target.name === "chosen") this.choose(ev.target.value);
    });
    // a click anywhere on a plan's row picks it, not only on its small radio button
    this.table.querySelector("tbody").addEventListener("click", (ev) => {
      const tr = ev.target.closest("tr[data-strategy]");
      if (tr && !tr.classList.contains("unplanned")) this.choose(tr.dataset.strategy);
    });
  }

  async load(file) {
    this.text.value = await file.text();
    this.text.dataset.file = file.name;
    this.forget();
  }

  /** The mission changed: an old preview no longer describes it. */
  forget() {
    this.plans = {};
    this.chosen = null;
    this.table.hidden = true;
    this.store.map.setPreview(null);
    this.startButton.textContent = "Start";
    delete this.startButton.dataset.strategy;
  }

  request(extra) {
    const body = { mission: this.text.value, objective: this.objective.value };
    const tl = parseFloat(this.timeLimit.value);
    if (tl > 0) body["time-limit"] = tl;
    return Object.assign(body, extra);
  }

  strategies() {
    return [...document.querySelectorAll("#strategy-choices input:checked")].map((i) => i.value);
  }

  async run(what, fn) {
    say(this.error, "");
    say(this.result, "");
    if (!this.text.value.trim()) {
      say(this.error, "paste or drop a mission first");
      return;
    }
    this.busy.hidden = false;
    document.body.dataset.submitting = what;
    try {
      await fn();
    } catch (err) {
      say(this.error, `${what} failed: ${err.failReason || err.message}`);
    } finally {
      this.busy.hidden = true;
      delete document.body.dataset.submitting;
    }
  }

  preview() {
    return this.run("preview", async () => {
      const res = await api.plan(this.request({ strategies: this.strategies() }));
      this.plans = res.plans || {};
      const rows = [];
      for (const [name, p] of Object.entries(this.plans)) {
        const failed = Boolean(p["fail-reason"]) || p.feasible === false;
        const units = new Set((p.assignments || []).map((a) => a.execunit));
        const note = p["fail-reason"] || (p.unassigned && p.unassigned.length ? `${p.unassigned.length} unassigned` : p.fallback ? `= ${p.fallback}` : "");
        rows.push(
          h("tr", { "data-strategy": name, "data-makespan": p.makespan ?? "", "data-total-time": p["total-time"] ?? "",
                    class: [failed ? "failed" : "", p["fail-reason"] ? "unplanned" : ""].join(" ").trim() },
            h("td", {}, h("input", { type: "radio", name: "chosen", value: name, disabled: Boolean(p["fail-reason"]) })),
            h("td", {}, name),
            h("td", { class: "num" }, secs(p.makespan)),
            h("td", { class: "num" }, secs(p["total-time"])),
            h("td", { class: "num" }, metres(p["total-distance"])),
            h("td", { class: "num" }, units.size ? String(units.size) : "–"),
            h("td", { class: failed ? "error" : "" }, note),
          ),
        );
      }
      this.table.querySelector("tbody").replaceChildren(...rows);
      this.table.hidden = false;
      const best = suggest(this.plans, this.objective.value);
      if (best) this.choose(best);
    });
  }

  choose(name) {
    this.chosen = name;
    const radio = this.table.querySelector(`input[name=chosen][value="${CSS.escape(name)}"]`);
    if (radio) radio.checked = true;
    for (const tr of this.table.querySelectorAll("tbody tr")) tr.classList.toggle("chosen", tr.dataset.strategy === name);
    this.store.map.setPreview(this.plans[name]);
    // the button says which plan it starts
    this.startButton.textContent = `Start ${name}`;
    this.startButton.dataset.strategy = name;
  }

  start() {
    return this.run("start", async () => {
      const strategy = this.chosen; // none previewed: the service's default strategy
      const previewId = strategy ? (this.plans[strategy] || {})["preview-id"] : undefined;
      const extra = strategy ? { strategy } : {};
      if (previewId) extra.preview = previewId;
      const res = await api.start(this.request(extra));
      const said = (res.plan || {})["from-preview"];
      let text = `started ${res.id}${strategy ? ` with ${strategy}` : ""}`;
      delete this.result.dataset.replanned;
      if (said && said.started) text += " (the plan previewed)";
      else if (said) {
        text += `, planned again: ${said.reason}`;
        this.result.dataset.replanned = said.reason;
      }
      say(this.result, text);
      this.result.dataset.missionId = res.id;
      this.forget();
      this.store.select(res.id);
    });
  }
}
