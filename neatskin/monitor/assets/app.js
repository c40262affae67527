// neatskin monitor page: polls /api/state every second and draws it with plain SVG (no external assets).
"use strict";
const SVGNS = "http://www.w3.org/2000/svg";
const COLORS = { ok: "#2f9e44", flagged: "#f08c00", missed: "#e03131" };
const $ = (id) => document.getElementById(id);
// ?poll=MS sets the polling period (default 1000 ms; at least 100)
const POLL_MS = Math.max(100, parseInt(new URLSearchParams(location.search).get("poll") || "1000", 10) || 1000);

function el(tag, attrs, parent, text) {
  const node = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  if (parent) parent.appendChild(node);
  return node;
}
function clear(node) { while (node.firstChild) node.removeChild(node.firstChild); }
function fmtDuration(s) {
  if (s === null || s === undefined) return "–";
  s = Math.round(s);
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
  return h ? `${h} h ${m} min` : m ? `${m} min ${sec} s` : `${sec} s`;
}
function niceTicks(lo, hi, n) {
  const span = hi - lo || 1, step0 = span / n, mag = Math.pow(10, Math.floor(Math.log10(step0)));
  const step = [1, 2, 5, 10].map((f) => f * mag).find((s) => span / s <= n) || 10 * mag;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(+v.toPrecision(10));
  return out;
}

function drawLayout(svg, layout, presses, last) {
  clear(svg);
  if (!layout) { el("text", { x: 20, y: 40 }, svg, "no layout (inputs/layout.toml missing)"); return; }
  const [x0, y0, x1, y1] = layout.bounds_mm, pad = 30, size = 400 - 2 * pad;
  const scale = size / Math.max(x1 - x0, y1 - y0, 1e-9);
  const X = (x) => pad + (x - x0) * scale, Y = (y) => 400 - pad - (y - y0) * scale;
  for (const [a, b, w] of layout.channels) {
    const [ax, ay] = layout.junctions[a], [bx, by] = layout.junctions[b];
    el("line", { x1: X(ax), y1: Y(ay), x2: X(bx), y2: Y(by), stroke: "#9fb3c8", "stroke-width": Math.max(2, w * scale), "stroke-linecap": "round" }, svg);
  }
  for (const [num, j] of layout.electrodes) {
    const [ex, ey] = layout.junctions[j];
    el("rect", { x: X(ex) - 7, y: Y(ey) - 7, width: 14, height: 14, fill: "#495057" }, svg);
    el("text", { x: X(ex), y: Y(ey) + 4, "text-anchor": "middle", "font-size": 10, fill: "#fff" }, svg, String(num));
  }
  for (let k = 0; k < presses.press_id.length; k++) {
    if (presses.x_mm[k] === null) continue;
    el("circle", { cx: X(presses.x_mm[k]), cy: Y(presses.y_mm[k]), r: 4.5, fill: COLORS[presses.flag[k]], "fill-opacity": 0.75, "data-press": presses.press_id[k] }, svg);
  }
  if (last) el("circle", { cx: X(last.x_mm), cy: Y(last.y_mm), r: 9, fill: "none", stroke: "#1c7ed6", "stroke-width": 2.5 }, svg);
  el("text", { x: pad, y: 396, "font-size": 10, fill: "#5b6573" }, svg, `${layout.name}: x ${x0}–${x1} mm, y ${y0}–${y1} mm`);
}

function drawBars(svg, last) {
  clear(svg);
  if (!last) { el("text", { x: 20, y: 40 }, svg, "no press yet"); $("lastinfo").textContent = ""; return; }
  $("lastinfo").textContent = `press ${last.press_id} at (${last.x_mm.toFixed(2)}, ${last.y_mm.toFixed(2)}) mm, depth ${last.depth_mm} mm` +
    (last.flags.length ? ` · flags: ${last.flags.join(", ")}` : " · no flags");
  const m = last.measured_dr_ohm, e = last.expected_dr_ohm || [];
  const vals = m.concat(e).filter((v) => v !== null);
  const lo = Math.min(0, ...vals), hi = Math.max(0, ...vals);
  const L = 52, R = 630, T = 10, B = 260, n = m.length, bw = (R - L) / n;
  const Y = (v) => B - ((v - lo) / (hi - lo || 1)) * (B - T);
  for (const t of niceTicks(lo, hi, 5)) {
    el("line", { x1: L, x2: R, y1: Y(t), y2: Y(t), stroke: "#e9ecef" }, svg);
    el("text", { x: L - 4, y: Y(t) + 3, "text-anchor": "end", "font-size": 10 }, svg, String(t));
  }
  el("text", { x: 12, y: 140, "font-size": 10, transform: "rotate(-90 12 140)", "text-anchor": "middle" }, svg, "dR (ohm)");
  for (let k = 0; k < n; k++) {
    const x = L + k * bw;
    if (e[k] !== undefined && e[k] !== null) el("rect", { x: x + 1, y: Math.min(Y(e[k]), Y(0)), width: bw / 2 - 1, height: Math.abs(Y(e[k]) - Y(0)), fill: "#adb5bd" }, svg);
    if (m[k] !== null) el("rect", { x: x + bw / 2, y: Math.min(Y(m[k]), Y(0)), width: bw / 2 - 1, height: Math.abs(Y(m[k]) - Y(0)), fill: "#1c7ed6", "data-pair": last.pairs[k] }, svg);
    else el("text", { x: x + bw / 2, y: Y(0) - 3, "font-size": 9, fill: "#e03131" }, svg, "∞");
    el("text", { x: x + bw / 2, y: B + 12, "text-anchor": "end", "font-size": 9, transform: `rotate(-60 ${x + bw / 2} ${B + 12})` }, svg, last.pairs[k]);
  }
  el("line", { x1: L, x2: R, y1: Y(0), y2: Y(0), stroke: "#495057" }, svg);
}

function drawDrift(svg, drift) {
  clear(svg);
  const ids = drift.press_id;
  if (ids.length < 1) { el("text", { x: 20, y: 40 }, svg, "no press yet"); return; }
  const series = drift.baseline_pct, vals = series.flat().filter((v) => v !== null);
  const lo = Math.min(-0.05, ...vals), hi = Math.max(0.05, ...vals);
  const L = 52, R = 630, T = 10, B = 270;
  const X = (k) => (ids.length > 1 ? L + (k / (ids.length - 1)) * (R - L) : (L + R) / 2);
  const Y = (v) => B - ((v - lo) / (hi - lo)) * (B - T);
  for (const t of niceTicks(lo, hi, 5)) {
    el("line", { x1: L, x2: R, y1: Y(t), y2: Y(t), stroke: "#e9ecef" }, svg);
    el("text", { x: L - 4, y: Y(t) + 3, "text-anchor": "end", "font-size": 10 }, svg, `${t}%`);
  }
  series.forEach((col, p) => {
    const pts = col.map((v, k) => (v === null ? null : `${X(k).toFixed(1)},${Y(v).toFixed(1)}`)).filter(Boolean);
    const hue = Math.round((p * 360) / series.length);
    el("polyline", { points: pts.join(" "), fill: "none", stroke: `hsl(${hue},60%,45%)`, "stroke-width": 1.2, "data-pair": drift.pairs[p] }, svg);
  });
  el("text", { x: L, y: 292, "font-size": 10 }, svg, `press order (${ids.length} presses, ids ${ids[0]}–${ids[ids.length - 1]}); one line per pair`);
}

function drawQuality(table, fsrDiv, q) {
  clear(table);
  const f = q.fsr;
  fsrDiv.textContent = `FSR: ${f.missed} presses missed (stored flagged), ${f.retried} retries, ${f.multiple} with several contacts`;
  const kinds = Object.keys(q.counts);
  const head = table.insertRow();
  head.insertCell().textContent = "pair";
  q.pairs.forEach((pair) => { head.insertCell().textContent = pair; });
  kinds.forEach((k) => {
    const row = table.insertRow();
    row.insertCell().textContent = k.replace("_", " ");
    q.pairs.forEach((pair, i) => {
      const c = row.insertCell();
      c.textContent = q.counts[k][i];
      if (q.counts[k][i] > 0) c.className = "bad";
    });
  });
}

// a running campaign with no press for 60 s and 20 presses' time: its process was likely killed
function stalled(s) {
  const per = s.rate_per_h ? 3600 / s.rate_per_h : 0;
  return s.since_last_press_s !== null && s.since_last_press_s > Math.max(60, 20 * per);
}

function update(s) {
  $("campaign").textContent = s.campaign;
  document.title = `${s.campaign} · ${s.counts.done}/${s.counts.planned} · neatskin monitor`;
  const st = $("status"); st.textContent = s.status; st.className = `badge ${s.status}`;
  const runnerState = (s.control && s.control.state) || "";
  const rs = $("runner"); rs.textContent = runnerState ? `runner: ${runnerState}` : ""; rs.className = `badge ${runnerState}`; rs.hidden = !runnerState;
  const reason = $("reason");
  reason.hidden = !(s.control && s.control.reason && runnerState !== "running");
  reason.textContent = reason.hidden ? "" : `${runnerState}: ${s.control.reason}`;
  const remote = $("remote");
  remote.hidden = !s.server.remote;
  remote.textContent = s.server.remote ? `This page is served on ${s.server.bound_to} (--allow-remote): anyone who can reach that address can see it.` : "";
  $("done").textContent = s.counts.done; $("planned").textContent = s.counts.planned; $("flagged").textContent = s.counts.flagged;
  $("progress").value = s.counts.planned ? s.counts.done / s.counts.planned : 0;
  $("rate").textContent = s.rate_per_h === null ? "–" : `${s.rate_per_h >= 100 ? Math.round(s.rate_per_h) : s.rate_per_h.toFixed(1)} /h`;
  // no ETA while nothing advances: paused, stopped, or a campaign that is not running
  $("eta").textContent = s.status === "complete" ? "done"
    : runnerState === "paused" ? "paused"
    : runnerState === "stopped" || s.status !== "running" ? "–"
    : stalled(s) ? `stalled: no press for ${fmtDuration(s.since_last_press_s)}` : fmtDuration(s.eta_s);
  const p = s.printer;
  $("possrc").textContent = p ? p.source : "–";
  $("position").textContent = p ? ["X", "Y", "Z"].map((a) => (p[a] === undefined ? `${a} ?` : `${a}${p[a]}`)).join(" ") : "–";
  drawLayout($("layout"), s.layout, s.presses, s.last_press);
  drawBars($("bars"), s.last_press);
  drawDrift($("drift"), s.drift);
  drawQuality($("quality"), $("fsr"), s.quality);
  const wire = $("wire"); wire.textContent = s.wire_tail.join("\n"); wire.scrollTop = wire.scrollHeight;
  for (const id of ["pause", "continue", "stop"]) $(id).disabled = !s.server.controls;
  if (!s.server.controls) $("controlmsg").textContent = "read-only monitor (--read-only)";
  $("updated").textContent = `updated ${new Date().toLocaleTimeString()}`;
}

async function poll() {
  try {
    const r = await fetch("/api/state", { cache: "no-store" });
    if (r.ok) update(await r.json());
    else $("updated").textContent = `state: HTTP ${r.status}`;
  } catch (err) {
    $("updated").textContent = `monitor unreachable (${err})`;
  }
  setTimeout(poll, POLL_MS);
}

async function control(action) {
  const token = $("token").value.trim();
  sessionStorage.setItem("neatskin-token", token);
  const r = await fetch(`/api/control/${action}`, { method: "POST", headers: { "X-Neatskin-Token": token } });
  const body = await r.json().catch(() => ({}));
  $("controlmsg").textContent = r.ok ? `${action} requested: acted on at the next safe point` : `refused (${r.status}): ${body.error || ""}`;
  $("controlmsg").dataset.status = String(r.status);
}

window.addEventListener("DOMContentLoaded", () => {
  const m = /token=([^&]+)/.exec(location.hash);
  if (m) { sessionStorage.setItem("neatskin-token", decodeURIComponent(m[1])); history.replaceState(null, "", location.pathname); }
  $("token").value = sessionStorage.getItem("neatskin-token") || "";
  for (const id of ["pause", "continue", "stop"]) $(id).addEventListener("click", () => control(id));
  poll();
});
