// Stable colours: one per unit name (its marker, route and track share it), one per status.

const cache = new Map();

/** A colour for a unit name, the same on every load. */
export function unitColor(name) {
  let c = cache.get(name);
  if (c) return c;
  let h = 2166136261;
  for (let i = 0; i < name.length; i++) h = Math.imul(h ^ name.charCodeAt(i), 16777619);
  const hue = (h >>> 0) % 360;
  c = `hsl(${hue}, 70%, 42%)`;
  cache.set(name, c);
  return c;
}

export const STATUS_COLORS = {
  planned: "#6b7b8c",
  started: "#2f6fb3",
  running: "#2f6fb3",
  active: "#2f6fb3",
  succeeded: "#2e8b57",
  finished: "#2e8b57",
  failed: "#c0392b",
  aborted: "#b9770e",
  lost: "#8a8a8a",
};

export const ENDED = new Set(["succeeded", "failed", "aborted"]);
