// Small DOM and formatting helpers shared by the views.

/** el("div#id.card.wide", {attr: value, onclick: fn}, child, "text", …): tag, then #id and .classes in any order. */
export function el(spec, attrs = {}, ...children) {
  const tag = spec.match(/^[a-z0-9]*/i)[0];
  const node = document.createElement(tag || "div");
  for (const [, kind, name] of spec.slice(tag.length).matchAll(/([#.])([^#.]+)/g)) {
    if (kind === "#") node.id = name;
    else node.classList.add(name);
  }
  for (const [name, value] of Object.entries(attrs || {})) {
    if (value === undefined || value === null || value === false) continue;
    if (name.startsWith("on") && typeof value === "function") node.addEventListener(name.slice(2), value);
    else if (name === "dataset") Object.assign(node.dataset, value);
    else if (name in node && typeof value !== "string") node[name] = value;
    else node.setAttribute(name, value === true ? "" : value);
  }
  for (const child of children.flat()) {
    if (child === undefined || child === null || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

export function fmtNumber(value, digits = 2) {
  return value === null || value === undefined || Number.isNaN(value) ? "–" : Number(value).toFixed(digits);
}

export function fmtSeconds(seconds) {
  if (seconds === null || seconds === undefined) return "–";
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return `${s} s`;
  const m = Math.floor(s / 60);
  if (m < 60) return `${m} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
}

export function fmtTime(iso) {
  if (!iso) return "–";
  const d = new Date(iso);
  const today = d.toDateString() === new Date().toDateString();
  return today
    ? d.toLocaleTimeString(undefined, { timeStyle: "medium" })
    : d.toLocaleString(undefined, { dateStyle: "short", timeStyle: "short" });
}

export function fmtBytes(n) {
  if (n < 1024) return `${n} B`;
  if (n < 1024 ** 2) return `${(n / 1024).toFixed(1)} KiB`;
  return `${(n / 1024 ** 2).toFixed(1)} MiB`;
}

export function stateBadge(state) {
  return el(`span.badge.state-${state}`, {}, state);
}

/** A progress bar for `value` of `total` (indeterminate when total is unknown). */
export function progressBar(value, total) {
  const bar = el("progress", { max: total || 1 });
  if (total) bar.value = Math.min(value || 0, total);
  else bar.removeAttribute("value");
  return bar;
}

/** Show `message` in the page's error banner for a while. */
export function toast(message, kind = "error") {
  let box = document.getElementById("toasts");
  if (!box) {
    box = el("div#toasts");
    document.body.append(box);
  }
  const note = el(`div.toast.${kind}`, { role: kind === "error" ? "alert" : "status" }, message);
  box.append(note);
  setTimeout(() => note.remove(), kind === "error" ? 9000 : 4000);
}
