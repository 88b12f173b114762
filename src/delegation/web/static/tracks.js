// Every unit's flown track on one canvas: a point appended costs one projection, and a redraw is
// one pass over the cached pixel points (no Leaflet path per track to re-project, clip and
// simplify on every append). Redrawn at most every REDRAW_MS while units move, at once on pan/zoom.

/* global L */

const MAX_POINTS = 300; // as the server keeps
const REDRAW_MS = 500;
const PAD = 0.3; // canvas overhang beyond the view, in view sizes: panning shows drawn track

export const TrackLayer = L.Layer.extend({
  options: { pane: "tracks", weight: 3, opacity: 0.8 },

  initialize(colorOf, options) {
    L.setOptions(this, options);
    this._colorOf = colorOf;
    this._tracks = new Map(); // name -> {ll: [[lat, lon]], px: [L.Point]}
    this._timer = null;
    this._last = 0;
  },

  onAdd(map) {
    this._canvas = L.DomUtil.create("canvas", "track-canvas leaflet-zoom-hide");
    this._canvas.style.pointerEvents = "none";
    this.getPane().appendChild(this._canvas);
    this._reproject();
  },

  onRemove() {
    L.DomUtil.remove(this._canvas);
    clearTimeout(this._timer);
    this._timer = null;
  },

  getEvents() {
    return { moveend: this._draw, zoomend: this._reproject, viewreset: this._reproject, resize: this._draw };
  },

  /** Replace a unit's track ([[lat, lon], ...]). */
  set(name, latlngs) {
    const ll = latlngs.slice(-MAX_POINTS);
    this._tracks.set(name, { ll, px: this._map ? ll.map((p) => this._map.latLngToLayerPoint(p)) : [] });
    this._soon();
  },

  /** Add a point to a unit's track (nothing when it is where the track ends). */
  append(name, point) {
    let t = this._tracks.get(name);
    if (!t) {
      t = { ll: [], px: [] };
      this._tracks.set(name, t);
    }
    const end = t.ll[t.ll.length - 1];
    if (end && end[0] === point[0] && end[1] === point[1]) return;
    t.ll.push(point);
    if (this._map) t.px.push(this._map.latLngToLayerPoint(point));
    if (t.ll.length > MAX_POINTS) {
      t.ll.shift();
      t.px.shift();
    }
    this._soon();
  },

  remove(name) {
    this._tracks.delete(name);
    this._soon();
  },

  count(name) {
    const t = this._tracks.get(name);
    return t ? t.ll.length : 0;
  },

  _soon() {
    if (!this._map || this._timer !== null) return;
    const wait = Math.max(0, this._last + REDRAW_MS - performance.now());
    this._timer = setTimeout(() => {
      this._timer = null;
      L.Util.requestAnimFrame(this._draw, this);
    }, wait);
  },

  _reproject() {
    if (!this._map) return;
    for (const t of this._tracks.values()) t.px = t.ll.map((p) => this._map.latLngToLayerPoint(p));
    this._draw();
  },

  _draw() {
    const map = this._map;
    if (!map) return;
    const t0 = performance.now();
    this._last = t0;
    const size = map.getSize();
    const origin = map.containerPointToLayerPoint(size.multiplyBy(-PAD)).round();
    const w = Math.round(size.x * (1 + 2 * PAD));
    const h = Math.round(size.y * (1 + 2 * PAD));
    const ratio = window.devicePixelRatio || 1;
    const c = this._canvas;
    if (c.width !== w * ratio || c.height !== h * ratio) {
      c.width = w * ratio;
      c.height = h * ratio;
      c.style.width = `${w}px`;
      c.style.height = `${h}px`;
    }
    L.DomUtil.setPosition(c, origin);
    const ctx = c.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, -origin.x * ratio, -origin.y * ratio);
    ctx.clearRect(origin.x, origin.y, w, h);
    ctx.lineWidth = this.options.weight;
    ctx.globalAlpha = this.options.opacity;
    ctx.lineJoin = "round";
    ctx.lineCap = "round";
    for (const [name, t] of this._tracks) {
      const px = t.px;
      if (px.length < 2) continue;
      ctx.beginPath();
      ctx.moveTo(px[0].x, px[0].y);
      for (let i = 1; i < px.length; i++) ctx.lineTo(px[i].x, px[i].y);
      ctx.strokeStyle = this._colorOf(name);
      ctx.stroke();
    }
    this.fire("drawn", { ms: performance.now() - t0 });
  },
});
