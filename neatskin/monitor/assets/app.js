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
    el("text", { x: X(ex), y: Y(ey) + 4, "text-anchor": "middle", "font-size": 11, fill: "#fff" }, svg, String(num));
  }
  for (let k = 0; k < presses.press_id.length; k++) {
    if (presses.x_mm[k] === null) continue;
    el("circle", { cx: X(presses.x_mm[k]), cy: Y(presses.y_mm[k]), r: 4.5, fill: COLORS[presses.flag[k]], "fill-opacity": 0.75, "data-press": presses.press_id[k] }, svg);
  }
  if (last) el("circle", { cx: X(last.x_mm), cy: Y(last.y_mm), r: 9, fill: "none", stroke: "#1c7ed6", "stroke-width": 2.5 }, svg);
  el("text", { x: pad, y: 394, "font-size": 13, fill: "#5b6573" }, svg, `${layout.name}: x ${x0}–${x1} mm, y ${y0}–${y1} mm`);
}

// least-squares factor k with model x k closest to the measured bars (pairs where both are finite), or null
function modelScale(m, e) {
  let me = 0, ee = 0;
  for (let k = 0; k < m.length; k++) if (m[k] !== null && e[k] !== null && e[k] !== undefined) { me += m[k] * e[k]; ee += e[k] * e[k]; }
  const k = ee > 0 ? me / ee : null;
  return k !== null && isFinite(k) && k > 0 ? k : null;
}

function drawBars(svg, last) {
  clear(svg);
  if (!last) { el("text", { x: 20, y: 40, "font-size": 14 }, svg, "no press yet"); $("lastinfo").textContent = ""; return; }
  $("lastinfo").textContent = `press ${last.press_id} at (${last.x_mm.toFixed(2)}, ${last.y_mm.toFixed(2)}) mm, depth ${last.depth_mm} mm` +
    (last.flags.length ? ` · flags: ${last.flags.join(", ")}` : " · no flags");
  const m = last.measured_dr_ohm, raw = last.expected_dr_ohm || [];
  // the model leaves out the rig (placement, depth jitter, fabrication, drift): drawn scaled to the measured
  // bars when they differ by more than half, so its pattern can be compared; the legend gives the factor
  const k = modelScale(m, raw), scaled = k !== null && (k > 1.5 || k < 1 / 1.5);
  const e = raw.map((v) => (v === null ? null : scaled ? v * k : v));
  $("modellegend").textContent = !raw.length ? "no skin model for this layout"
    : scaled ? `ideal skin model × ${k.toPrecision(2)} (scaled to the measured bars by least squares: compare the pattern)`
    : "ideal skin model at this position (unscaled)";
  const vals = m.concat(e).filter((v) => v !== null);
  const lo = Math.min(0, ...vals), hi = Math.max(0, ...vals);
  const L = 62, R = 632, T = 10, B = 262, n = m.length, bw = (R - L) / n;
  const Y = (v) => B - ((v - lo) / (hi - lo || 1)) * (B - T);
  for (const t of niceTicks(lo, hi, 5)) {
    el("line", { x1: L, x2: R, y1: Y(t), y2: Y(t), stroke: "#e9ecef" }, svg);
    el("text", { x: L - 5, y: Y(t) + 5, "text-anchor": "end", "font-size": 14 }, svg, String(t));
  }
  el("text", { x: 14, y: 140, "font-size": 14, transform: "rotate(-90 14 140)", "text-anchor": "middle" }, svg, "dR (ohm)");
  for (let k2 = 0; k2 < n; k2++) {
    const x = L + k2 * bw;
    if (e[k2] !== undefined && e[k2] !== null) el("rect", { x: x + 1, y: Math.min(Y(e[k2]), Y(0)), width: bw / 2 - 1, height: Math.abs(Y(e[k2]) - Y(0)), fill: "#adb5bd" }, svg);
    if (m[k2] !== null) {
      const bar = el("rect", { x: x + bw / 2, y: Math.min(Y(m[k2]), Y(0)), width: bw / 2 - 1, height: Math.abs(Y(m[k2]) - Y(0)), fill: "#1c7ed6", "data-pair": last.pairs[k2] }, svg);
      el("title", {}, bar, `pair ${last.pairs[k2]}: measured ${m[k2].toPrecision(3)} ohm` + (raw[k2] !== null && raw[k2] !== undefined ? `, model ${raw[k2].toPrecision(3)} ohm` : ""));
    } else el("text", { x: x + bw / 2, y: Y(0) - 3, "font-size": 12, fill: "#e03131" }, svg, "∞");
    el("text", { x: x + bw / 2 + 4, y: B + 14, "text-anchor": "end", "font-size": 12, transform: `rotate(-60 ${x + bw / 2 + 4} ${B + 14})` }, svg, last.pairs[k2]);
  }
  el("line", { x1: L, x2: R, y1: Y(0), y2: Y(0), stroke: "#495057" }, svg);
}

const DRIFT_NAMED = 5; // the pairs that drifted most are named at the line's end; every line has a hover title

function drawDrift(svg, drift) {
  clear(svg);
  const ids = drift.press_id;
  if (ids.length < 1) { el("text", { x: 20, y: 40, "font-size": 14 }, svg, "no press yet"); return; }
  const series = drift.baseline_pct, vals = series.flat().filter((v) => v !== null);
  const lo = Math.min(-0.05, ...vals), hi = Math.max(0.05, ...vals);
  const L = 66, R = 580, T = 12, B = 272;
  const X = (k) => (ids.length > 1 ? L + (k / (ids.length - 1)) * (R - L) : (L + R) / 2);
  const Y = (v) => B - ((v - lo) / (hi - lo)) * (B - T);
  for (const t of niceTicks(lo, hi, 5)) {
    el("line", { x1: L, x2: R, y1: Y(t), y2: Y(t), stroke: "#e9ecef" }, svg);
    el("text", { x: L - 5, y: Y(t) + 5, "text-anchor": "end", "font-size": 14 }, svg, `${t}%`);
  }
  const lastOf = (col) => { for (let k = col.length - 1; k >= 0; k--) if (col[k] !== null) return [k, col[k]]; return null; };
  const ends = series.map((col, p) => ({ p, end: lastOf(col) })).filter((d) => d.end);
  const named = new Set(ends.sort((a, b) => Math.abs(b.end[1]) - Math.abs(a.end[1])).slice(0, DRIFT_NAMED).map((d) => d.p));
  series.forEach((col, p) => {
    const pts = col.map((v, k) => (v === null ? null : `${X(k).toFixed(1)},${Y(v).toFixed(1)}`)).filter(Boolean);
    const hue = Math.round((p * 360) / series.length), end = lastOf(col);
    const line = el("polyline", { points: pts.join(" "), fill: "none", stroke: `hsl(${hue},60%,45%)`, "stroke-width": named.has(p) ? 2.2 : 1.1, "data-pair": drift.pairs[p] }, svg);
    el("title", {}, line, `pair ${drift.pairs[p]}: ${end ? `${end[1] >= 0 ? "+" : ""}${end[1].toFixed(3)} % at the last press` : "no value"}`);
  });
  // names at the right end, nudged apart so they do not overlap
  const labels = ends.filter((d) => named.has(d.p)).map((d) => ({ p: d.p, y: Y(d.end[1]) })).sort((a, b) => a.y - b.y);
  for (let i = 1; i < labels.length; i++) labels[i].y = Math.max(labels[i].y, labels[i - 1].y + 14);
  if (labels.length) labels[labels.length - 1].y = Math.min(labels[labels.length - 1].y, B + 20); // inside the view
  for (let i = labels.length - 2; i >= 0; i--) labels[i].y = Math.min(labels[i].y, labels[i + 1].y - 14);
  for (const lab of labels) {
    const hue = Math.round((lab.p * 360) / series.length);
    el("text", { x: R + 6, y: lab.y + 5, "font-size": 13, fill: `hsl(${hue},60%,35%)`, "data-label": drift.pairs[lab.p] }, svg, drift.pairs[lab.p]);
  }
  el("text", { x: L, y: 300, "font-size": 13 }, svg, `press order (${ids.length} presses, ids ${ids[0]}–${ids[ids.length - 1]}); one line per pair`);
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
  drawResults(s.results || []);
  drawTerminalState(s);
  for (const id of ["pause", "continue", "stop"]) $(id).disabled = !s.server.controls;
  if (!s.server.controls) $("controlmsg").textContent = "read-only monitor (--read-only)";
  $("updated").textContent = `updated ${utcClock(new Date())}`;
}

function utcClock(d) { return `${d.toISOString().slice(11, 19)} UTC`; }

function drawResults(results) {
  const box = $("results"), list = $("resultlinks");
  box.hidden = results.length === 0;
  if (list.childElementCount === results.length) return; // unchanged: keep the links (and a focused one)
  while (list.firstChild) list.removeChild(list.firstChild);
  for (const r of results) {
    const item = document.createElement("li"), a = document.createElement("a");
    a.href = r.href; a.textContent = r.name; a.target = "_blank"; a.rel = "noopener";
    item.appendChild(a); list.appendChild(item);
  }
}

// the terminal: enabled when the monitor has a printer port; the server refuses while a campaign holds the folder
function drawTerminalState(s) {
  const on = !!s.server.terminal, busy = s.status === "running" && !stalled(s);
  $("terminalline").disabled = !on || busy; $("terminalsend").disabled = !on || busy;
  $("terminalstate").textContent = !on ? "no printer terminal: start the monitor with --printer-port PORT (and a token)"
    : busy ? `printer ${s.server.printer_port}: the running campaign holds it; the terminal works once no campaign runs`
    : `printer ${s.server.printer_port}: type a line and Send (the token above is needed)`;
}

async function sendLine(ev) {
  ev.preventDefault();
  const input = $("terminalline"), out = $("terminalout"), line = input.value.trim();
  if (!line) return;
  input.value = ""; // as a terminal: the line leaves the prompt when sent; the reply lands below
  const token = $("token").value.trim();
  const r = await fetch("/api/printer", { method: "POST", headers: { "X-Neatskin-Token": token, "Content-Type": "application/json" }, body: JSON.stringify({ line }) });
  const body = await r.json().catch(() => ({}));
  const stamp = utcClock(new Date()).slice(0, 8);
  const text = r.ok ? [`${stamp} → ${body.line}`, ...body.reply.map((t) => `${stamp} ← ${t}`)] : [`${stamp} refused (${r.status}): ${body.error || ""}`];
  out.textContent = (out.textContent ? out.textContent + "\n" : "") + text.join("\n");
  out.scrollTop = out.scrollHeight; out.dataset.status = String(r.status);
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
  $("terminalform").addEventListener("submit", sendLine);
  poll();
});
