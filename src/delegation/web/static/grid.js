// A plain local metric grid (no tile server): lines every 1/2/5 x 10^k metres east and north of
// an origin, drawn per tile on canvas so panning costs nothing but the tiles that come into view;
// the lines' labels once each, along the view's top (east) and left (north) edges, in one canvas
// redrawn as the view moves (labels drawn per tile repeated in the middle of the view).

/* global L */

const M_PER_DEG_LAT = 110574;
const M_PER_DEG_LON_EQ = 111320;
const LABEL_COLOR = "#7a8ba0";
const FONT = "10px sans-serif";

function niceStep(metres) {
  const p = Math.pow(10, Math.floor(Math.log10(metres)));
  for (const f of [1, 2, 5, 10]) if (f * p >= metres) return f * p;
  return 10 * p;
}

function label(m) {
  return Math.abs(m) >= 1000 ? `${(m / 1000).toFixed(m % 1000 ? 1 : 0)} km` : `${Math.round(m)} m`;
}

/** A grid layer about `origin` ([lat, lon]): `metricGrid(origin).addTo(map)`. */
export function metricGrid(origin) {
  const [lat0, lon0] = origin;
  const mPerDegLon = M_PER_DEG_LON_EQ * Math.cos((lat0 * Math.PI) / 180);
  // metres per pixel at the origin's latitude, a line roughly every 90 px
  const stepAt = (z) => niceStep(((40075016.686 * Math.cos((lat0 * Math.PI) / 180)) / (256 * Math.pow(2, z))) * 90);
  const Grid = L.GridLayer.extend({
    createTile(coords) {
      const tile = document.createElement("canvas");
      const size = this.getTileSize();
      tile.width = size.x;
      tile.height = size.y;
      const map = this._map;
      const z = coords.z;
      const nw = coords.scaleBy(size);
      const se = nw.add(size);
      const a = map.unproject(nw, z);
      const b = map.unproject(se, z);
      const step = stepAt(z);
      const ctx = tile.getContext("2d");
      const x0 = (a.lng - lon0) * mPerDegLon;
      const x1 = (b.lng - lon0) * mPerDegLon;
      const y0 = (b.lat - lat0) * M_PER_DEG_LAT;
      const y1 = (a.lat - lat0) * M_PER_DEG_LAT;
      for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
        const p = map.project([a.lat, lon0 + x / mPerDegLon], z).subtract(nw);
        const major = Math.round(x / step) % 5 === 0;
        ctx.strokeStyle = x === 0 ? LABEL_COLOR : major ? "#c2ccd8" : "#dde3ea";
        ctx.beginPath();
        ctx.moveTo(Math.round(p.x) + 0.5, 0);
        ctx.lineTo(Math.round(p.x) + 0.5, size.y);
        ctx.stroke();
      }
      for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
        const p = map.project([lat0 + y / M_PER_DEG_LAT, a.lng], z).subtract(nw);
        const major = Math.round(y / step) % 5 === 0;
        ctx.strokeStyle = y === 0 ? LABEL_COLOR : major ? "#c2ccd8" : "#dde3ea";
        ctx.beginPath();
        ctx.moveTo(0, Math.round(p.y) + 0.5);
        ctx.lineTo(size.x, Math.round(p.y) + 0.5);
        ctx.stroke();
      }
      return tile;
    },

    onAdd(map) {
      L.GridLayer.prototype.onAdd.call(this, map);
      this._labels = L.DomUtil.create("canvas", "metric-grid-labels", map.getPanes().tilePane);
      Object.assign(this._labels.style, { position: "absolute", left: "0", top: "0", pointerEvents: "none" });
      this._labels.style.zIndex = "250";
      map.on("move zoomend resize viewreset", this._drawLabels, this);
      this._drawLabels();
    },

    onRemove(map) {
      map.off("move zoomend resize viewreset", this._drawLabels, this);
      L.DomUtil.remove(this._labels);
      L.GridLayer.prototype.onRemove.call(this, map);
    },

    /** Every line in view labelled once: east at the top edge, north at the left edge. */
    _drawLabels() {
      const map = this._map;
      const canvas = this._labels;
      const size = map.getSize();
      const ratio = window.devicePixelRatio || 1;
      canvas.width = size.x * ratio;
      canvas.height = size.y * ratio;
      canvas.style.width = `${size.x}px`;
      canvas.style.height = `${size.y}px`;
      L.DomUtil.setPosition(canvas, map.containerPointToLayerPoint([0, 0]));
      const ctx = canvas.getContext("2d");
      ctx.scale(ratio, ratio);
      ctx.font = FONT;
      ctx.fillStyle = LABEL_COLOR;
      const step = stepAt(Math.round(map.getZoom()));
      const nw = map.containerPointToLatLng([0, 0]);
      const se = map.containerPointToLatLng([size.x, size.y]);
      const drawn = [];
      const corner = 60; // px kept clear at the top left, where the two edges meet
      const zoomControl = 84; // px below the top kept clear of north labels: the zoom buttons
      for (let x = Math.ceil(((nw.lng - lon0) * mPerDegLon) / step) * step; x <= (se.lng - lon0) * mPerDegLon; x += step) {
        const px = map.latLngToContainerPoint([nw.lat, lon0 + x / mPerDegLon]).x;
        const text = `${label(x)} E`;
        if (px < corner || px + 3 + ctx.measureText(text).width > size.x) continue;
        ctx.fillText(text, Math.round(px) + 3, 11);
        drawn.push(text);
      }
      for (let y = Math.ceil(((se.lat - lat0) * M_PER_DEG_LAT) / step) * step; y <= (nw.lat - lat0) * M_PER_DEG_LAT; y += step) {
        const py = map.latLngToContainerPoint([lat0 + y / M_PER_DEG_LAT, nw.lng]).y;
        if (py < zoomControl || py > size.y) continue;
        const text = `${label(y)} N`;
        ctx.fillText(text, 3, Math.round(py) - 3);
        drawn.push(text);
      }
      canvas.dataset.labels = JSON.stringify(drawn); // what is written, for tests
    },
  });
  // no minZoom/maxZoom: a layer's zoom limits become the map's and would move the view
  return new Grid({ className: "metric-grid" });
}
