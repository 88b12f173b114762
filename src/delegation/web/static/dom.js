// Small DOM helpers shared by the panels.

/** `h("td", {class: "x", "data-a": 1}, child, "text")`: an element with attributes and children. */
export function h(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === null || v === undefined || v === false) continue;
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else e.setAttribute(k, v === true ? "" : String(v));
  }
  for (const c of children) if (c !== null && c !== undefined) e.append(c);
  return e;
}

/** Seconds as "75 s", "12 min 5 s", or "–". */
export function secs(v) {
  if (v === null || v === undefined || Number.isNaN(v)) return "–";
  const s = Math.round(v);
  if (s < 120) return `${s} s`;
  const m = Math.floor(s / 60);
  return `${m} min ${s % 60} s`;
}

/** Show `text` in a message element, or hide it when empty. */
export function say(el, text) {
  el.textContent = text || "";
  el.hidden = !text;
}

export function badge(status) {
  return h("span", { class: `badge st-${status || "none"}`, "data-status": status || "" }, status || "–");
}
