// The operator page: one live store fed by server-sent events (/api/events), panels that render
// from it in requestAnimationFrame batches, and the map. No polling: the only timer is the 1 Hz
// tick that advances the elapsed clocks on screen.

import * as api from "./api.js";
import { ENDED } from "./colors.js";
import { badge, h } from "./dom.js";
import { MapView } from "./map.js";
import { MissionDetail, MissionsPanel, setTimeScale } from "./missions.js";
import { SubmitPanel } from "./submit.js";

const EVENTS_MAX = 200;
const LAG_SAMPLES = 4000;
const DETAIL_MIN_INTERVAL = 1000; // ms between two fetches of one mission's detail

class Store {
  constructor(config) {
    this.config = config;
    this.units = new Map();
    this.missions = new Map();
    this.details = new Map(); // id -> GET /api/missions/{id} (or {error})
    this.fetching = new Map(); // id -> {at, again}
    this.events = [];
    this.selected = null;
    this.order = 0;
    this.dirty = { units: new Set(), unitsAll: false, missions: false, detail: false, events: [], eventsAll: false };
    this.pendingUnits = []; // [{u, point, at}] from `units` events, applied in the next frame
    this.frame = null;
    // for benchmarks/ui_load.py: event lag (s); ms of each frame's DOM work and canvas redraws
    this.stats = { lags: [], flushMs: [], trackMs: [], canvasMs: [], unitEvents: 0, unitsApplied: 0 };
  }

  schedule() {
    if (this.frame === null) this.frame = requestAnimationFrame(() => this.flush());
  }

  // ---- inputs

  snapshot(s) {
    this.units = new Map(s.units.map((u) => [u.name, u]));
    this.missions = new Map();
    for (const m of s.missions) this.putMission(m, false);
    this.events = s.events.slice(-EVENTS_MAX);
    this.pendingUnits = [];
    this.snapshotUnits = s.units;
    this.dirty.unitsAll = true;
    this.dirty.missions = true;
    this.dirty.detail = true;
    this.dirty.eventsAll = true;
    for (const m of this.missions.values()) if (!ENDED.has(m.status) || m.id === this.selected) this.fetchDetail(m.id);
    this.schedule();
  }

  unitsEvent(data) {
    this.stats.unitEvents += 1;
    for (const u of data.units) this.pendingUnits.push({ u, at: data.at });
    this.schedule();
  }

  putMission(m, live = true) {
    const old = this.missions.get(m.id);
    m._receivedAt = performance.now();
    m._order = old ? old._order : ++this.order;
    this.missions.set(m.id, m);
    this.dirty.missions = true;
    if (m.id === this.selected) this.dirty.detail = true;
    if (live && (!old || old.status !== m.status || !this.details.has(m.id))) {
      if (!ENDED.has(m.status) || m.id === this.selected || this.details.has(m.id)) this.fetchDetail(m.id);
    }
    this.schedule();
  }

  nodeEvent(n) {
    const d = this.details.get(n.mission);
    const node = d && d.tree ? findNode(d.tree, n.uuid) : null;
    if (node) {
      node.status = n.status;
      node["actual-start"] = n["actual-start"];
      node["actual-end"] = n["actual-end"];
      if (n.mission === this.selected) this.dirty.detail = true;
      this.schedule();
      // A detail being fetched was read before this event: when it lands it replaces the
      // detail just updated, so fetch once more after it (else the event is lost for good).
      const f = this.fetching.get(n.mission);
      if (f && f.busy) this.fetchDetail(n.mission);
    } else if (this.missions.has(n.mission)) {
      this.fetchDetail(n.mission);
    }
  }

  logEvent(e) {
    this.events.push(e);
    if (this.events.length > EVENTS_MAX) this.events.shift();
    this.dirty.events.push(e);
    // Re-delegated: tasks moved, or a lost unit's part re-shared as pieces; the detail says which.
    if (e.kind === "re-delegated" && this.details.has(e.mission)) this.fetchDetail(e.mission);
    this.schedule();
  }

  select(id) {
    this.selected = id;
    this.dirty.missions = true;
    this.dirty.detail = true;
    if (id && !this.details.has(id)) this.fetchDetail(id);
    this.schedule();
  }

  /** GET the mission's detail, at most once a second per mission (a later call re-fetches once). */
  fetchDetail(id) {
    const f = this.fetching.get(id);
    const now = performance.now();
    if (f && (f.busy || now - f.at < DETAIL_MIN_INTERVAL)) {
      if (!f.again) {
        f.again = true;
        setTimeout(() => { f.again = false; this.fetchDetail(id); }, Math.max(DETAIL_MIN_INTERVAL - (now - f.at), 50));
      }
      return;
    }
    const entry = { at: now, busy: true, again: false };
    this.fetching.set(id, entry);
    api.getMission(id).then(
      (d) => {
        entry.busy = false;
        this.details.set(id, d);
        if (d.status) this.putMission(Object.assign({}, this.missions.get(id) || {}, stripDetail(d)), false);
        this.dirty.detail = true;
        this.dirty.geometry = true;
        this.schedule();
      },
      (err) => {
        entry.busy = false;
        this.details.set(id, { error: err.failReason || err.message });
        this.dirty.detail = true;
        this.schedule();
      },
    );
  }

  // ---- one frame of DOM work

  flush() {
    this.frame = null;
    const t0 = performance.now();
    const d = this.dirty;
    if (d.unitsAll) {
      this.map.setUnits(this.snapshotUnits || []);
      this.unitsTable.renderAll(this.units);
      d.unitsAll = false;
    }
    if (this.pendingUnits.length) {
      const nowS = Date.now() / 1000;
      const seen = new Set();
      for (const { u, at } of this.pendingUnits) {
        const merged = Object.assign({}, this.units.get(u.name) || {}, u);
        this.units.set(u.name, merged);
        this.map.updateUnit(merged, null, u.point);
        d.units.add(u.name);
        if (!seen.has(at)) {
          seen.add(at);
          record(this.stats.lags, nowS - at);
        }
      }
      this.stats.unitsApplied += this.pendingUnits.length;
      this.pendingUnits = [];
      this.map.placeOnUnits();
    }
    if (d.units.size) {
      this.unitsTable.update(this.units, d.units);
      d.units.clear();
    }
    if (d.missions) {
      this.missionsPanel.render();
      d.missions = false;
      d.geometry = true;
    }
    if (d.geometry) {
      this.drawGeometry();
      d.geometry = false;
    }
    if (d.detail) {
      this.detail.render();
      d.detail = false;
    }
    if (d.eventsAll) {
      this.eventsList.renderAll(this.events);
      d.eventsAll = false;
      d.events = [];
    } else if (d.events.length) {
      this.eventsList.add(d.events);
      d.events = [];
    }
    record(this.stats.flushMs, performance.now() - t0);
  }

  /** Tasks and routes of every mission not ended, and of the selected one (dimmed once ended). */
  drawGeometry() {
    const want = new Map();
    for (const m of this.missions.values()) {
      const det = this.details.get(m.id);
      if (!det || !det.tree) continue;
      if (!ENDED.has(m.status)) want.set(m.id, false);
      else if (m.id === this.selected) want.set(m.id, true);
    }
    for (const id of this.map.missionIds()) if (!want.has(id)) this.map.clearMission(id);
    for (const [id, dim] of want) {
      const det = this.details.get(id);
      if (this.drawn.get(id) !== det || this.drawnDim.get(id) !== dim || !this.map.missionLayers.has(id)) {
        this.map.setMission(id, det, { dim });
        this.drawn.set(id, det);
        this.drawnDim.set(id, dim);
      }
    }
  }
}

function record(list, value) {
  list.push(value);
  if (list.length > LAG_SAMPLES) list.shift();
}

function stripDetail(d) {
  const m = Object.assign({}, d);
  delete m.tree;
  delete m.plan;
  delete m.routes;
  delete m.tasks;
  return m;
}

function findNode(node, uuid) {
  if (node.uuid === uuid) return node;
  for (const p of node.parts || []) if (p.uuid === uuid) return p; // a shared search's part
  for (const c of node.children || []) {
    const f = findNode(c, uuid);
    if (f) return f;
  }
  return null;
}

function pct(b) {
  return b === null || b === undefined ? null : Math.round(b * 100);
}

class UnitsTable {
  constructor() {
    this.body = document.querySelector("#units tbody");
    this.rows = new Map();
    this.count = document.getElementById("units-count");
    this.summary = document.getElementById("fleet-summary");
  }

  row(u) {
    const p = pct(u.battery);
    const doing = (u.executing || []).map((t) => t.name).join(", ");
    return [
      h("td", { class: "name", title: u["managed-by"] ? `managed by the delegator ${u["managed-by"]}` : "" },
        u.name, u["managed-by"] ? h("span", { class: "managed-by" }, ` · ${u["managed-by"]}`) : null),
      h("td", {}, u.type || "?"),
      h("td", {}, badge(u.status)),
      h("td", { class: "battery", title: p === null ? "unknown" : `${p} %` },
        p === null ? "?" : h("span", { class: `bar${p < 20 ? " low" : ""}`, style: `width:${p}%` }), p === null ? null : ` ${p}%`),
      h("td", { class: "doing" }, doing || "–"),
    ];
  }

  renderAll(units) {
    this.body.replaceChildren();
    this.rows.clear();
    this.update(units, new Set(units.keys()));
  }

  update(units, names) {
    let added = false;
    for (const name of names) {
      const u = units.get(name);
      let tr = this.rows.get(name);
      if (!tr) {
        tr = h("tr", { id: `unit-${name}`, "data-unit": name });
        this.rows.set(name, tr);
        added = true;
      }
      const key = `${u.status}|${pct(u.battery)}|${u.type}|${u["managed-by"] || ""}|${(u.executing || []).map((t) => t.name).join(",")}`;
      if (tr.dataset.status !== u.status) tr.dataset.status = u.status; // no style work when same
      if (tr._key !== key) {
        tr._key = key;
        tr.replaceChildren(...this.row(u));
      }
    }
    if (added) {
      // rows by name (re-appending moves them): new units are rare, updates are not
      const sorted = [...this.rows.keys()].sort((a, b) => a.localeCompare(b, undefined, { numeric: true }));
      this.body.append(...sorted.map((n) => this.rows.get(n)));
    }
    let alive = 0;
    for (const u of units.values()) if (u.status === "alive") alive++;
    const lost = units.size - alive;
    const text = `${units.size} units: ${alive} alive, ${lost} lost`;
    if (this.summary.textContent !== text) {
      this.count.textContent = `(${units.size})`;
      this.summary.textContent = text;
      this.summary.dataset.alive = String(alive);
      this.summary.dataset.lost = String(lost);
    }
  }
}

class EventsList {
  constructor() {
    this.list = document.getElementById("events");
  }

  item(e) {
    const t = new Date(e.at * 1000).toLocaleTimeString([], { hour12: false });
    return h("li", { "data-kind": e.kind, "data-seq": e.seq, "data-mission": e.mission || "", "data-unit": e.unit || "", class: `ev-${e.kind}` },
      h("time", {}, t), " ", h("span", { class: "kind" }, e.kind), " ", e.text);
  }

  renderAll(events) {
    this.list.replaceChildren(...events.slice().reverse().map((e) => this.item(e)));
  }

  add(events) {
    for (const e of events) this.list.prepend(this.item(e));
    while (this.list.childElementCount > EVENTS_MAX) this.list.lastElementChild.remove();
  }
}

function connect(store) {
  const conn = document.getElementById("conn");
  const es = new EventSource("/api/events");
  const on = (name, fn) =>
    es.addEventListener(name, (ev) => {
      try {
        fn(JSON.parse(ev.data));
      } catch (err) {
        console.error(`bad ${name} event`, err);
      }
    });
  es.onopen = () => {
    conn.dataset.state = "live";
    conn.textContent = "live";
  };
  es.onerror = () => {
    conn.dataset.state = es.readyState === EventSource.CLOSED ? "closed" : "reconnecting";
    conn.textContent = conn.dataset.state;
  };
  on("snapshot", (s) => {
    store.snapshot(s);
    conn.dataset.state = "live";
    conn.textContent = "live";
    document.body.dataset.ready = "1";
  });
  on("units", (d) => store.unitsEvent(d));
  on("mission", (m) => store.putMission(m));
  on("node", (n) => store.nodeEvent(n));
  on("log", (e) => store.logEvent(e));
  return es;
}

async function main() {
  let config;
  try {
    config = await api.getConfig();
  } catch (err) {
    document.getElementById("conn").textContent = err.failReason || err.message;
    document.getElementById("conn").dataset.state = "error";
    return;
  }
  document.getElementById("user").textContent = config.user ? `as ${config.user}` : "";
  setTimeScale(Number(config["time-scale"]) || 1); // optional: not in every server's config
  const store = new Store(config);
  store.map = new MapView(document.getElementById("map"), config, {
    tracks: (ms) => record(store.stats.trackMs, ms),
    units: (ms) => record(store.stats.canvasMs, ms),
  });
  store.drawn = new Map();
  store.drawnDim = new Map();
  store.unitsTable = new UnitsTable();
  store.eventsList = new EventsList();
  store.missionsPanel = new MissionsPanel(store);
  store.detail = new MissionDetail(store);
  store.submit = new SubmitPanel(store, config);
  setInterval(() => {
    store.missionsPanel.tick();
    store.detail.tick();
  }, 1000);
  window.delegationUI = { store, map: store.map, stats: store.stats, describe: () => store.map.describe() };
  store.source = connect(store);
}

main();
