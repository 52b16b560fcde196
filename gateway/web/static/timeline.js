// tactile-gateway live page: time. The trend chart (total force, peak force, contact area, the
// centre of pressure's x and y, and a record's reference total) filled on load from the
// gateway's history (GET /api/devices/{name}/history?seconds=30, asked when the device's entry
// in /api/devices has history_s; a 404 or no history_s means the gateway keeps none: the chart
// fills from the live frames alone); and playback's tools: frame steps (buttons,
// arrow keys), loop, markers, and the map's modes: the difference B - A between two chosen
// frames (a diverging key) and, where the record has a reference force per channel, the error
// (force - reference) per channel. Plain browser JavaScript, no build step; loaded before app.js,
// whose globals (playback, devices, selected, view, seek, $, fmt, ...) these functions use when
// called.
"use strict";

const LINE_PEAK = "#e84a5f";
const LINE_COP_X = "#b38cff";
const LINE_COP_Y = "#3fd09c";

// one point of the trend chart from a frame: the gateway's own figures (no page threshold)
function histPoint(f, d) {
  return {
    t: f.t, total: f.total_force_n, area: f.contact_area_mm2, ref: refTotal(f), peak: f.peak_force_n,
    peakK: slotOf(d, f.peak_channel),
    cx: f.cop_mm ? f.cop_mm[0] : null, cy: f.cop_mm ? f.cop_mm[1] : null,
  };
}
// one point of the trend chart from the history endpoint's point
function historyPoint(p) {
  return {
    t: p.t, total: p.force_n, area: p.area_mm2, ref: null, peak: p.peak_n, peakK: -1,
    cx: p.cop_x_mm === undefined ? null : p.cop_x_mm, cy: p.cop_y_mm === undefined ? null : p.cop_y_mm,
  };
}

// the gateway's history of a device, once per device and page load, put before the live points
async function loadHistory(d) {
  if (source !== "live" || d.historySource) return;
  // a gateway that keeps a history says so in the device's entry (its span, s): an older
  // gateway is not asked (its 404 would be logged by the browser as an error)
  if (!(d.layout.history_s > 0)) { d.historySource = "none"; return; }
  d.historySource = "loading";
  try {
    const name = encodeURIComponent(d.layout.name);
    const seconds = Math.min(HISTORY_S, d.layout.history_s); // the gateway refuses more than it keeps
    const resp = await fetch(`/api/devices/${name}/history?seconds=${seconds}`, { cache: "no-store" });
    if (!resp.ok) { d.historySource = "none"; return; }
    const data = await resp.json();
    const first = d.history.length ? d.history[0].t : Infinity;
    const older = (data.points || []).filter((p) => p.t < first).map(historyPoint);
    d.history = older.concat(d.history);
    d.historySource = "server";
  } catch (err) {
    d.historySource = "none";
  }
  dirty = true;
}

// the value of a point in the shown unit: totals as the mean pressure over the contact area
function chartTotal(p, v) { return view.unit === "N" ? v : totalInUnit(v, p.area); }

// the chart's canvas drawn at its shown width (a phone's narrow chart keeps 12 px text)
function fitChart(canvas) {
  const w = Math.max(280, Math.min(900, Math.round(canvas.clientWidth || 900)));
  if (canvas.width !== w) canvas.width = w;
}

function drawHistory(canvas, d) {
  fitChart(canvas);
  const ctx = canvas.getContext("2d");
  const w = canvas.width;
  const h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  const l = 56;
  const r = w - 64;
  const t = 22;
  const b = Math.round(h * 0.62);
  const t2 = b + 26;
  const b2 = h - 24;
  ctx.strokeStyle = "#444";
  ctx.strokeRect(l, t, r - l, b - t);
  ctx.strokeRect(l, t2, r - l, b2 - t2);
  const hist = d.history;
  const tEnd = hist.length ? hist[hist.length - 1].t : 0;
  const hasRef = hist.some((p) => p.ref !== null && p.ref !== undefined);
  const val = (p, key) => {
    if (key === "peak") return toUnit(d, p.peak, p.peakK);
    if (key === "total" || key === "ref") return chartTotal(p, p[key]);
    return p[key];
  };
  const fTop = Math.max(view.unit === "N" ? d.layout.scale_n[1] : 1e-9,
    ...hist.map((p) => Math.max(val(p, "total") || 0, val(p, "peak") || 0, val(p, "ref") || 0)));
  const aMax = Math.max(1, ...hist.map((p) => p.area || 0));
  const geo = d.geo;
  const cLo = Math.min(geo.x0, geo.y0);
  const cHi = Math.max(geo.x1, geo.y1);
  const u = unitLabel();
  ctx.font = "12px sans-serif";
  ctx.fillStyle = "#e6e9ee";
  ctx.textBaseline = "middle";
  ctx.textAlign = "left";
  const what = view.unit === "N" ? "total and peak force (N" : `mean and peak pressure (${u}`;
  // a narrow chart (a phone) gets the short title: the key under it names the lines
  const span = playback ? `the ${HISTORY_S} s of the record up to the frame` : `last ${HISTORY_S} s`;
  const title = `${what}, left) and contact area (mm², right), ${span}`;
  canvas.setAttribute("aria-label", title);
  ctx.fillText(w >= 600 ? title
    : `${view.unit === "N" ? "force, N" : `pressure, ${u}`} · area, mm²`, l, 10);
  ctx.fillText("centre of pressure, x and y (mm)", l, t2 - 10);
  ctx.textAlign = "right";
  ctx.fillText(fmtValue(fTop), l - 6, t);
  ctx.fillText("0", l - 6, b);
  ctx.fillText(fmtValue(cHi), l - 6, t2);
  ctx.fillText(fmtValue(cLo), l - 6, b2);
  ctx.textAlign = "left";
  ctx.fillText(aMax.toFixed(0), r + 6, t);
  ctx.fillText("0", r + 6, b);
  ctx.textAlign = "center";
  const [left, right] = timeWords(tEnd);
  ctx.fillText(left, l, b2 + 12);
  ctx.fillText(right, r, b2 + 12);
  $("history-range").textContent = `${left} … ${right}`;
  const series = (key, lo, hi, top, bottom, style, dash, width) => {
    ctx.strokeStyle = style;
    ctx.lineWidth = width || 2;
    ctx.setLineDash(dash || []);
    ctx.beginPath();
    let pen = false;
    for (const p of hist) {
      const v = val(p, key);
      if (v === null || v === undefined) { pen = false; continue; }
      const x = r - ((tEnd - p.t) / HISTORY_S) * (r - l);
      const y = bottom - ((Math.max(lo, Math.min(hi, v)) - lo) / (hi - lo)) * (bottom - top);
      if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
      pen = true;
    }
    ctx.stroke();
    ctx.setLineDash([]);
  };
  // the total wide under the peak: with one channel loaded they are equal, and both show
  series("total", 0, fTop, t, b, LINE_TOTAL, null, 4);
  series("peak", 0, fTop, t, b, LINE_PEAK, null, 1.5);
  if (hasRef) series("ref", 0, fTop, t, b, LINE_REFERENCE, [6, 4]);
  series("area", 0, aMax, t, b, LINE_AREA);
  series("cx", cLo, cHi, t2, b2, LINE_COP_X);
  series("cy", cLo, cHi, t2, b2, LINE_COP_Y, [5, 3]);
  // the key under the chart names each line drawn
  $("key-reference").hidden = !hasRef;
  for (const el of document.querySelectorAll(".chart-unit")) el.textContent = u;
  $("key-total-words").textContent = view.unit === "N" ? "total force (N, left axis)"
    : `mean pressure over the contact area (${u}, left axis)`;
  canvas.dataset.reference = hasRef ? "1" : "0";
  canvas.dataset.points = String(hist.length);
  canvas.dataset.source = playback ? "playback" : d.historySource || "";
}

// the chart's time axis in words: live, the last 30 s up to now; in playback, the record's
// times (s from its start) at the chart's two ends
function timeWords(tEnd) {
  if (!playback) return [`-${HISTORY_S} s`, "now"];
  const a = Math.max(0, tEnd - HISTORY_S - playback.start);
  return [`record ${a.toFixed(2)} s`, `playback ${(tEnd - playback.start).toFixed(2)} s`];
}

// ---------------------------------------------------------------- playback's tools
// the map's mode: "force" (the frame), "diff" (frame B - frame A) or "error" (force - reference)
const mapMode = { mode: "force", a: null, b: null };

// the diverging key of a difference: blue below zero, near black at zero, red above
const DIVERGING = [[-1, [90, 160, 255]], [-0.5, [40, 90, 200]], [0, [18, 18, 24]], [0.5, [200, 50, 50]],
  [1, [255, 140, 120]]];
function divergingColour(v, max) {
  const x = Math.max(-1, Math.min(1, v / max));
  for (let i = 1; i < DIVERGING.length; i++) {
    if (x <= DIVERGING[i][0]) {
      const [x0, c0] = DIVERGING[i - 1];
      const [x1, c1] = DIVERGING[i];
      const q = (x - x0) / (x1 - x0);
      return c0.map((c, k) => Math.round(c + q * (c1[k] - c)));
    }
  }
  return DIVERGING[DIVERGING.length - 1][1];
}

// whether the map shows a signed quantity (a difference or an error) instead of the frame
function signedMode() { return playback && mapMode.mode !== "force" && signedValues() !== null; }
// the signed values per channel (shown unit) of the map's mode, or null when it has none
function signedValues() {
  const d = devices.get(playback.device);
  if (!d) return null;
  if (mapMode.mode === "diff") {
    if (mapMode.a === null || mapMode.b === null) return null;
    const fa = playback.frames[mapMode.a];
    const fb = playback.frames[mapMode.b];
    return fb.force_n.map((v, k) => {
      const x = toUnit(d, v, k);
      const y = toUnit(d, fa.force_n[k], k);
      return x === null || y === null ? null : x - y;
    });
  }
  if (mapMode.mode === "error") {
    const f = d.frame;
    if (!f || !f.reference_force_n) return null;
    return f.force_n.map((v, k) => {
      const ref = f.reference_force_n[k];
      return v === null || ref === null ? null : toUnit(d, v, k) - toUnit(d, ref, k);
    });
  }
  return null;
}
// the symmetric range of the signed map: a nice value at or above the largest magnitude
function signedMax(values) {
  const m = Math.max(0, ...values.map((v) => Math.abs(v || 0)));
  return m > 0 ? niceCeil(m) : 1;
}
function signedWords() {
  if (mapMode.mode === "diff") {
    const ta = (playback.frames[mapMode.a].t - playback.start).toFixed(2);
    const tb = (playback.frames[mapMode.b].t - playback.start).toFixed(2);
    return `B − A: ${tb} s − ${ta} s`;
  }
  return "force − reference";
}

// the diverging key of the signed map (drawn where the colour scale is)
function drawSignedScale(canvas, max, title) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width;
  const h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  const top = 24;
  const bottom = h - 12;
  for (let y = top; y <= bottom; y++) {
    ctx.fillStyle = rgb(divergingColour((1 - (2 * (y - top)) / (bottom - top)) * max, max));
    ctx.fillRect(8, y, 22, 1);
  }
  ctx.fillStyle = "#e6e9ee";
  ctx.font = "12px sans-serif";
  ctx.textAlign = "left";
  ctx.textBaseline = "middle";
  ctx.fillText(title, 4, 10);
  for (let k = -2; k <= 2; k++) {
    const y = top + ((2 - k) / 4) * (bottom - top);
    ctx.fillRect(30, y, 5, 1);
    const v = (k / 2) * max;
    ctx.fillText(`${v > 0 ? "+" : ""}${fmtValue(v)}`, 38, y);
  }
}

// step the shown frame by n frames
function stepFrames(n) {
  const pb = playback;
  if (!pb) return;
  if (pb.playing) setPlaying(false);
  const k = Math.max(0, Math.min(pb.frames.length - 1, (pb.shown < 0 ? 0 : pb.shown) + n));
  seek(pb.frames[k].t);
}

function showMarkers() {
  const pb = playback;
  $("markers").replaceChildren(...pb.markers.map((t) => {
    const li = document.createElement("li");
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = `${(t - pb.start).toFixed(2)} s`;
    b.title = "show this frame";
    b.addEventListener("click", () => { if (pb.playing) setPlaying(false); seek(t); });
    li.append(b);
    return li;
  }));
}

function showAB() {
  const pb = playback;
  const words = (k) => (k === null ? "–" : `${(pb.frames[k].t - pb.start).toFixed(2)} s`);
  $("ab-readout").textContent = `A ${words(mapMode.a)}, B ${words(mapMode.b)}`;
}

// playback's tools, wired once its frames are in
function startPlaybackTools() {
  const pb = playback;
  pb.markers = [];
  pb.loops = 0;
  $("health-title").textContent = "Health, as recorded (playback)";
  $("poll-age-label").textContent = "last good poll before this frame";
  $("step-back").addEventListener("click", () => stepFrames(-1));
  $("step-fwd").addEventListener("click", () => stepFrames(1));
  document.addEventListener("keydown", (ev) => {
    const tag = ev.target && ev.target.tagName;
    if (tag === "INPUT" || tag === "SELECT" || tag === "TEXTAREA") return;
    if (ev.key === "ArrowLeft") { stepFrames(-1); ev.preventDefault(); }
    if (ev.key === "ArrowRight") { stepFrames(1); ev.preventDefault(); }
  });
  $("add-marker").addEventListener("click", () => {
    const t = pb.frames[Math.max(0, pb.shown)].t;
    if (!pb.markers.includes(t)) pb.markers.push(t);
    pb.markers.sort((x, y) => x - y);
    showMarkers();
  });
  $("set-a").addEventListener("click", () => { mapMode.a = Math.max(0, pb.shown); showAB(); lastKey = ""; dirty = true; });
  $("set-b").addEventListener("click", () => { mapMode.b = Math.max(0, pb.shown); showAB(); lastKey = ""; dirty = true; });
  const hasRef = pb.frames.some((f) => Array.isArray(f.reference_force_n));
  $("mode-error").hidden = !hasRef;
  $("mode-error").disabled = !hasRef;
  $("map-mode").addEventListener("change", () => { mapMode.mode = $("map-mode").value; lastKey = ""; dirty = true; });
  $("playback-tools").hidden = false;
  showAB();
}

// at the record's end: start again when looping (true: keep playing)
function loopAtEnd() {
  if (!$("loop").checked) return false;
  playback.loops++;
  $("playback").dataset.loops = String(playback.loops);
  seek(playback.start);
  return true;
}

// ---------------------------------------------------------------- playback
// the index of the last frame at or before time t (s, the record's clock), or 0
function frameAt(t) {
  const fr = playback.frames;
  let lo = 0;
  let hi = fr.length - 1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (fr[mid].t <= t) lo = mid; else hi = mid - 1;
  }
  return lo;
}

// show the record at time t: the frame then, the trend and trail up to it
function seek(t) {
  const pb = playback;
  pb.t = Math.max(pb.start, Math.min(pb.end, t));
  $("time").value = String(pb.t);
  $("time").dataset.t = String(pb.t);
  $("time-readout").textContent = `${(pb.t - pb.start).toFixed(2)} s of ${(pb.end - pb.start).toFixed(2)} s`;
  const k = frameAt(pb.t);
  if (k === pb.shown) return;
  pb.shown = k;
  const d = devices.get(pb.device);
  if (!d) return;
  const f = pb.frames[k];
  d.frame = f;
  d.arrived = performance.now();
  d.history = [];
  d.trail = [];
  for (let i = k; i >= 0 && pb.frames[i].t >= f.t - HISTORY_S; i--) {
    const g = pb.frames[i];
    d.history.unshift(histPoint(g, d));
    if (g.t >= f.t - TRAIL_S && g.cop_mm) d.trail.unshift([g.t, g.cop_mm[0], g.cop_mm[1]]);
  }
  updateAuto(d, performance.now());
  $("map").dataset.frame = String(f.seq);
  dirty = true;
}

function setPlaying(on) {
  const pb = playback;
  if (on && pb.t >= pb.end) seek(pb.start); // play at the end starts again
  pb.playing = on;
  pb.tick = null;
  $("play").disabled = on;
  $("pause").disabled = !on;
  $("playback").dataset.playing = on ? "1" : "0";
}

function tickPlayback(now) {
  const pb = playback;
  if (!pb.playing) return;
  if (pb.tick !== null) {
    seek(pb.t + ((now - pb.tick) / 1000) * pb.speed);
    if (pb.t >= pb.end) {
      if (loopAtEnd()) pb.tick = now; else setPlaying(false);
      return;
    }
  }
  pb.tick = now;
}

async function startPlayback(info) {
  const resp = await fetch("/api/playback", { cache: "no-store" });
  if (!resp.ok) throw new Error(`/api/playback: ${resp.status}`);
  const data = await resp.json();
  playback = {
    device: data.device, frames: data.frames, start: data.start_s, end: data.end_s,
    t: data.start_s, shown: -1, playing: false, tick: null, speed: 1,
  };
  $("playback").hidden = false;
  $("conn").textContent = `playback: ${info.source || "record"}`;
  $("conn").className = "conn live";
  const slider = $("time");
  slider.min = String(data.start_s);
  slider.max = String(data.end_s);
  slider.addEventListener("input", () => seek(Number.parseFloat(slider.value)));
  $("play").addEventListener("click", () => setPlaying(true));
  $("pause").addEventListener("click", () => setPlaying(false));
  $("speed").addEventListener("change", () => {
    playback.speed = Number.parseFloat($("speed").value) || 1;
    playback.tick = null;
  });
  const q = new URLSearchParams(location.search);
  const speed = q.get("speed");
  if (speed && [...$("speed").options].some((o) => o.value === speed)) {
    $("speed").value = speed;
    playback.speed = Number.parseFloat(speed);
  }
  seek(data.start_s);
  setPlaying(false);
  startPlaybackTools();
  document.body.dataset.playback = "ready";
}
