// The map: units (canvas markers with a heading arrow), flown tracks, the tasks and planned routes
// of running missions, and a plan preview. Everything vector is on canvas renderers and updated in
// place: 200 units at 2 Hz redraw one canvas per frame, not 200 DOM nodes.

/* global L */

import { metricGrid } from "./grid.js";
import { unitColor } from "./colors.js";
import { TrackLayer } from "./tracks.js";

const LABEL_LIMIT = 40; // names drawn beside markers up to this many units

/** A unit marker: an arrow along the heading (a disc without one), grey and crossed when lost. */
const UnitMarker = L.CircleMarker.extend({
  // The label is drawn right of the marker: it must be inside the bounds the canvas clears.
  _updateBounds() {
    const r = this._radius + 3;
    const extra = this.showLabel ? 100 : 0;
    this._pxBounds = new L.Bounds(this._point.subtract([r, r]), this._point.add([r + extra, r]));
  },

  _updatePath() {
    const r = this._renderer;
    if (!r._drawing || this._empty()) return;
    const ctx = r._ctx;
    const p = this._point;
    const u = this.unit;
    const lost = u.status === "lost";
    const color = lost ? "#8a8a8a" : unitColor(u.name);
    ctx.save();
    ctx.globalAlpha = 1; // Leaflet leaves the last path's opacity on the shared context
    ctx.translate(p.x, p.y);
    ctx.lineWidth = 1.5;
    ctx.strokeStyle = lost ? "#444" : "#fff";
    ctx.fillStyle = color;
    if (lost) ctx.setLineDash([3, 2]);
    if (u.heading === null || u.heading === undefined) {
      ctx.beginPath();
      ctx.arc(0, 0, 7, 0, Math.PI * 2);
    } else {
      ctx.rotate((u.heading * Math.PI) / 180); // heading: degrees clockwise from north
      ctx.beginPath();
      if (u.type === "air") {
        ctx.moveTo(0, -11);
        ctx.lineTo(7, 8);
        ctx.lineTo(0, 4);
        ctx.lineTo(-7, 8);
      } else {
        ctx.moveTo(0, -11);
        ctx.lineTo(6, -3);
        ctx.lineTo(6, 8);
        ctx.lineTo(-6, 8);
        ctx.lineTo(-6, -3);
      }
      ctx.closePath();
    }
    ctx.fill();
    ctx.stroke();
    ctx.restore();
    if (lost) {
      ctx.save();
      ctx.globalAlpha = 1;
      ctx.strokeStyle = "#c0392b";
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(p.x - 6, p.y - 6);
      ctx.lineTo(p.x + 6, p.y + 6);
      ctx.moveTo(p.x + 6, p.y - 6);
      ctx.lineTo(p.x - 6, p.y + 6);
      ctx.stroke();
      ctx.restore();
    }
    if (this.showLabel) {
      ctx.save();
      ctx.globalAlpha = 1;
      ctx.font = "600 11px sans-serif";
      ctx.lineJoin = "round";
      ctx.lineWidth = 3;
      ctx.strokeStyle = "rgba(255,255,255,0.9)";
      ctx.fillStyle = lost ? "#777" : "#222";
      const text = lost ? `${u.name} (lost)` : u.name;
      ctx.strokeText(text, p.x + 11, p.y + 4);
      ctx.fillText(text, p.x + 11, p.y + 4);
      ctx.restore();
    }
  },
});

function fmtPct(x) {
  return x === null || x === undefined ? "?" : `${Math.round(x * 100)} %`;
}

function esc(s) {
  return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
}

function tooltip(u) {
  const doing = (u.executing || []).map((t) => t.name).join(", ") || "idle";
  const hdg = u.heading === null || u.heading === undefined ? "?" : `${Math.round(u.heading)}°`;
  const spd = u.speed === null || u.speed === undefined ? "?" : `${u.speed.toFixed(1)} m/s`;
  return (
    `<b>${esc(u.name)}</b> (${esc(u.type || "?")}) — <b>${esc(u.status)}</b><br>` +
    `battery ${fmtPct(u.battery)}, heading ${hdg}, speed ${spd}<br>` +
    `${u.latitude.toFixed(6)}, ${u.longitude.toFixed(6)}, alt ${Math.round(u.altitude ?? 0)} m<br>` +
    `doing: ${esc(doing)}`
  );
}

export class MapView {
  /** `timings.tracks(ms)` / `timings.units(ms)`: how long each redraw of the track canvas / of
   * the units-and-geometry canvas took (figures for benchmarks/ui_load.py). */
  constructor(el, config, timings = {}) {
    this.onTracks = timings.tracks || (() => {});
    this.el = el;
    this.map = L.map(el, { preferCanvas: true, zoomSnap: 0.25, maxZoom: 22, fadeAnimation: false });
    this.map.setView([0, 0], 2);
    // Tracks on their own canvas under the rest (history, never hovered); units and mission
    // geometry share one canvas so that both answer the mouse (tooltips), units drawn on top.
    const tracksPane = this.map.createPane("tracks");
    tracksPane.style.zIndex = "390";
    tracksPane.style.pointerEvents = "none";
    this.unitRenderer = L.canvas({ padding: 0.2 });
    this.geoRenderer = this.unitRenderer;
    if (timings.units) {
      // Leaflet redraws a canvas in its own animation frame; time it where it happens
      const r = this.unitRenderer;
      const redraw = r._redraw;
      r._redraw = function timedRedraw() {
        const t0 = performance.now();
        redraw.call(this);
        timings.units(performance.now() - t0);
      };
    }
    this.tileUrl = config["tile-url"] || null;
    if (this.tileUrl) {
      L.tileLayer(this.tileUrl, {
        attribution: config["tile-attribution"] || "",
        maxZoom: 22,
        maxNativeZoom: 19,
      }).addTo(this.map);
    } else {
      this.map.attributionControl.addAttribution("local metric grid (no tile server)");
    }
    L.control.scale({ metric: true, imperial: false, maxWidth: 160 }).addTo(this.map);
    this.missionLayers = new Map(); // mission id -> L.LayerGroup
    this.previewLayer = L.layerGroup().addTo(this.map);
    this.tracks = new TrackLayer(unitColor).addTo(this.map);
    this.tracks.on("drawn", (e) => this.onTracks(e.ms));
    this.unitsLayer = L.layerGroup().addTo(this.map);
    this.units = new Map(); // name -> {marker}
    this.placed = false;
  }

  /** Centre on the units once, and lay the grid about them when there is no tile server. */
  _placeOnce(points) {
    if (this.placed || points.length === 0) return;
    this.placed = true;
    const b = L.latLngBounds(points);
    this.map.fitBounds(b.pad(0.4), { maxZoom: 17, animate: false });
    if (!this.tileUrl) metricGrid([b.getCenter().lat, b.getCenter().lng]).addTo(this.map);
  }

  /** Centre on the units once they are known (a snapshot may come before any unit). */
  placeOnUnits() {
    if (this.placed) return;
    this._placeOnce([...this.units.values()].map((e) => e.marker.getLatLng()));
  }

  /** Replace every unit (a snapshot). */
  setUnits(units) {
    for (const name of [...this.units.keys()]) {
      if (!units.some((u) => u.name === name)) this._removeUnit(name);
    }
    for (const u of units) this.updateUnit(u, u.track || []);
    this._placeOnce(units.map((u) => [u.latitude, u.longitude]));
  }

  _removeUnit(name) {
    const e = this.units.get(name);
    if (!e) return;
    this.unitsLayer.removeLayer(e.marker);
    this.tracks.remove(name);
    this.units.delete(name);
  }

  /** Create or move one unit; `track` replaces its track, `point` appends to it. */
  updateUnit(u, track, point) {
    let e = this.units.get(u.name);
    const ll = [u.latitude, u.longitude];
    if (!e) {
      const marker = new UnitMarker(ll, { renderer: this.unitRenderer, radius: 11, interactive: true });
      marker.unit = u;
      marker.bindTooltip(() => tooltip(marker.unit), { direction: "top", offset: [0, -8] });
      marker.addTo(this.unitsLayer);
      e = { marker };
      this.units.set(u.name, e);
      this._relabel();
    } else {
      e.marker.unit = u;
      e.marker.setLatLng(ll); // requests a redraw of the unit canvas (batched by Leaflet per frame)
    }
    if (track && track.length) this.tracks.set(u.name, track);
    else if (point) this.tracks.append(u.name, point);
    if (e.marker.isTooltipOpen()) e.marker.setTooltipContent(tooltip(u));
    this.el.dataset.unitsDrawn = String(this.units.size);
  }

  _relabel() {
    const show = this.units.size <= LABEL_LIMIT;
    for (const e of this.units.values()) e.marker.showLabel = show;
  }

  /** Draw a mission's tasks and planned routes (detail = GET /api/missions/{id}). */
  setMission(id, detail, { dim = false } = {}) {
    this.clearMission(id);
    const g = L.layerGroup().addTo(this.map);
    drawPlan(g, detail.tasks || [], detail.routes || {}, this.geoRenderer, dim ? 0.35 : 0.9, "route");
    this.missionLayers.set(id, g);
    this._placeOnce(boundsOf(detail));
  }

  clearMission(id) {
    const g = this.missionLayers.get(id);
    if (g) {
      this.map.removeLayer(g);
      this.missionLayers.delete(id);
    }
  }

  missionIds() {
    return [...this.missionLayers.keys()];
  }

  /** A plan preview (one strategy's plan from POST /api/plan), replacing the last. */
  setPreview(plan) {
    this.previewLayer.clearLayers();
    if (!plan) return;
    drawPlan(this.previewLayer, plan.tasks || [], plan.routes || {}, this.geoRenderer, 0.9, "preview");
    const pts = boundsOf(plan);
    this._placeOnce(pts);
    if (pts.length) this.map.fitBounds(L.latLngBounds(pts).pad(0.25), { maxZoom: 18, animate: false });
  }

  /** What is drawn, for tests and the benchmark: names, positions and statuses of the markers. */
  describe() {
    const units = {};
    for (const [name, e] of this.units) {
      const ll = e.marker.getLatLng();
      units[name] = {
        lat: ll.lat,
        lon: ll.lng,
        status: e.marker.unit.status,
        onMap: this.map.hasLayer(e.marker),
        trackPoints: this.tracks.count(name),
      };
    }
    const count = (g) => (g ? g.getLayers().length : 0);
    const missions = {};
    for (const [id, g] of this.missionLayers) missions[id] = count(g);
    // the parts of shared searches drawn (mission id or "preview" -> [{part, unit, color}])
    const parts = {};
    const partsOf = (key, g) => {
      for (const layer of g.getLayers()) {
        if (layer.task && layer.task["part-of"]) {
          (parts[key] = parts[key] || []).push({ part: layer.task.part, unit: layer.task.unit, color: layer.options.color });
        }
      }
    };
    for (const [id, g] of this.missionLayers) partsOf(id, g);
    partsOf("preview", this.previewLayer);
    return { units, missions, preview: count(this.previewLayer), parts };
  }
}

function boundsOf(detail) {
  const pts = [];
  for (const t of detail.tasks || []) pts.push(...t.coordinates);
  for (const r of Object.values(detail.routes || {})) pts.push(...r);
  return pts;
}

/** Tasks and routes into `group` (on the map already: each layer goes under the markers). */
function drawPlan(group, tasks, routes, renderer, opacity, kind) {
  const dash = kind === "preview" ? "2 6" : "5 7";
  for (const [unit, pts] of Object.entries(routes)) {
    if (pts.length < 2) continue;
    L.polyline(pts, {
      renderer,
      color: kind === "preview" ? "#7b2cbf" : unitColor(unit),
      weight: 2,
      opacity: opacity * 0.8,
      dashArray: dash,
      interactive: false,
    }).addTo(group).bringToBack();
  }
  for (const t of tasks) {
    const color = t.unit ? unitColor(t.unit) : "#555";
    // a shared search's part: which part of the operator's search, on which unit
    const part = t.part ? ` (part ${esc(t.part)} of a shared search)` : "";
    const tip = `${esc(t.name)}${part} → ${esc(t.unit || "unassigned")}`;
    let layer;
    if (t.kind === "area" && t.coordinates.length >= 3) {
      layer = L.polygon(t.coordinates, { renderer, color, weight: 1.5, opacity, fillOpacity: 0.12 * opacity });
    } else if (t.kind === "path" && t.coordinates.length >= 2) {
      layer = L.polyline(t.coordinates, { renderer, color, weight: 3, opacity });
    } else if (t.coordinates.length) {
      layer = L.circleMarker(t.coordinates[0], {
        renderer,
        radius: 6,
        color,
        weight: 2,
        opacity,
        fillColor: "#fff",
        fillOpacity: 0.8 * opacity,
      });
    }
    if (layer) {
      layer.task = t;
      layer.bindTooltip(tip).addTo(group).bringToBack(); // under the unit markers
    }
  }
}
