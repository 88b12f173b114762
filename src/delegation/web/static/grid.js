// A plain local metric grid (no tile server): lines every 1/2/5 x 10^k metres east and north of
// an origin (labelled in every third tile row/column), drawn per tile on canvas so panning
// costs nothing but the tiles that come into view.

/* global L */

const M_PER_DEG_LAT = 110574;
const M_PER_DEG_LON_EQ = 111320;

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
      // metres per pixel at the origin's latitude, a line roughly every 90 px
      const mpp = (40075016.686 * Math.cos((lat0 * Math.PI) / 180)) / (256 * Math.pow(2, z));
      const step = niceStep(mpp * 90);
      const ctx = tile.getContext("2d");
      ctx.font = "10px sans-serif";
      const x0 = (a.lng - lon0) * mPerDegLon;
      const x1 = (b.lng - lon0) * mPerDegLon;
      const y0 = (b.lat - lat0) * M_PER_DEG_LAT;
      const y1 = (a.lat - lat0) * M_PER_DEG_LAT;
      for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
        const p = map.project([a.lat, lon0 + x / mPerDegLon], z).subtract(nw);
        const major = Math.round(x / step) % 5 === 0;
        ctx.strokeStyle = x === 0 ? "#7a8ba0" : major ? "#c2ccd8" : "#dde3ea";
        const labelled = coords.y % 3 === 0;
        ctx.beginPath();
        ctx.moveTo(Math.round(p.x) + 0.5, 0);
        ctx.lineTo(Math.round(p.x) + 0.5, size.y);
        ctx.stroke();
        const xText = `${label(x)} E`;
        if (labelled && p.x + 3 + ctx.measureText(xText).width < size.x) {
          ctx.fillStyle = "#7a8ba0";
          ctx.fillText(xText, Math.round(p.x) + 3, 11);
        }
      }
      for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
        const p = map.project([lat0 + y / M_PER_DEG_LAT, a.lng], z).subtract(nw);
        const major = Math.round(y / step) % 5 === 0;
        ctx.strokeStyle = y === 0 ? "#7a8ba0" : major ? "#c2ccd8" : "#dde3ea";
        const labelled = coords.x % 3 === 0;
        ctx.beginPath();
        ctx.moveTo(0, Math.round(p.y) + 0.5);
        ctx.lineTo(size.x, Math.round(p.y) + 0.5);
        ctx.stroke();
        if (labelled && p.y > 14) {
          ctx.fillStyle = "#7a8ba0";
          ctx.fillText(`${label(y)} N`, 3, Math.round(p.y) - 3);
        }
      }
      return tile;
    },
  });
  // no minZoom/maxZoom: a layer's zoom limits become the map's and would move the view
  return new Grid({ className: "metric-grid" });
}
