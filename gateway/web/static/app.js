// tactile-gateway live pressure map: plain browser JavaScript, no build step, no CDN.
// Reads /api/devices (layout) and follows /api/live (server-sent events, newest frame of each
// device at most ~30/s). Draws a colour map of forces at the channels' configured positions
// (y grows downward), channel statuses, the centre of pressure with a short trail, total
// force and contact area over the last 30 s, and the device's health.
// The colour scale is in force (N) or pressure (kPa or mmHg: force over the layout's cell area),
// its top follows the frame's peak (auto, with hysteresis) or is fixed, per device or one for all
// devices; settings come from the URL (?scale=auto|fixed&max=2.5&unit=N|kPa|mmHg&numbers=1&same=1
// &threshold=0.2) and the controls write them back. The grid, axes, units and threshold: view.js.
// A device made of regions (a hand) is drawn region by region, each in its configured place,
// outlined and named, with the sum of force over each region and each group (a finger, the palm).
// Playback (tactile-gateway view RECORD): /api/devices says "playback"; the page then reads
// every frame of the record from /api/playback and a time slider, play/pause and a speed feed
// the frame at the slider's time to the same drawing code.
"use strict";

const ST = { OK: 0, NO_CONTACT: 1, SATURATED: 2, OPEN: 3, SHORT: 4, STALE: 5, ERROR: 6, EXTRAPOLATED: 7,
             NO_ZERO: 8, UNCALIBRATED: 9 };
// the statuses whose channel carries a force (drawn in the colour of its force)
const VALUED = new Set([ST.OK, ST.NO_CONTACT, ST.SATURATED, ST.EXTRAPOLATED, ST.NO_ZERO]);
// a channel without a zero read at the converter's idle floor: a dotted grey outline
const NO_ZERO_COLOUR = "#9aa3ad";
// an extrapolated channel (a force outside its calibrated range): a dashed outline in this colour
const EXTRAPOLATED_COLOUR = "#3fd0c9";
const HISTORY_S = 30;
const TRAIL_S = 2;
// auto-range: the top is a "nice" value just above the peak; it grows at once and shrinks only
// after the peak has stayed under SHRINK_BELOW of it for SHRINK_AFTER_MS (no flicker)
const NICE = [1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10];
const AUTO_HEADROOM = 1.1;
const AUTO_FLOOR_N = 0.1;
const SHRINK_BELOW = 0.45;
const SHRINK_AFTER_MS = 1500;
// a disabled channel (off in the configuration, never polled): a crossed dark cell
const DISABLED_FILL = "#1c2026";
const DISABLED_CROSS = "#6b7480";
// a perceptual dark-to-bright map (inferno-like): 0 N is near black, the scale's top is pale yellow
const STOPS = [
  [0.0, [0, 0, 4]], [0.15, [40, 11, 84]], [0.3, [101, 21, 110]], [0.45, [159, 42, 99]],
  [0.6, [212, 72, 66]], [0.75, [245, 125, 21]], [0.9, [250, 193, 39]], [1.0, [252, 255, 164]],
];

const devices = new Map(); // name -> device state
let selected = null;
let dirty = true;
let lastDraw = 0;
let lastKey = "";
// the view's settings; read from the URL at start, written back on change
const view = { mode: "auto", max: null, unit: "N", numbers: false, same: false, threshold: null, rois: [] };
// the colours of the trend chart's lines (and of its key, style.css)
const LINE_TOTAL = "#f5a623";
const LINE_REFERENCE = "#6fd27a";
const LINE_AREA = "#5fb3ff";
// playback of a record: null when live
let playback = null;
// what the server serves: "live" (a gateway) or "playback" (a record); null before /api/devices
let source = null;

function $(id) { return document.getElementById(id); }

function colour(f, max) {
  const t = Math.max(0, Math.min(1, f / max));
  for (let i = 1; i < STOPS.length; i++) {
    if (t <= STOPS[i][0]) {
      const [t0, c0] = STOPS[i - 1];
      const [t1, c1] = STOPS[i];
      const u = (t - t0) / (t1 - t0);
      return c0.map((c, k) => Math.round(c + u * (c1[k] - c)));
    }
  }
  return STOPS[STOPS.length - 1][1];
}
function rgb(c) { return `rgb(${c[0]},${c[1]},${c[2]})`; }
function fmt(x, digits) { return x === null || x === undefined ? "–" : x.toFixed(digits); }
function niceCeil(x) {
  const e = Math.pow(10, Math.floor(Math.log10(x)));
  for (const m of NICE) if (m * e >= x * (1 - 1e-9)) return m * e;
  return 10 * e;
}
function fmtValue(v) {
  const a = Math.abs(v);
  return v.toFixed(a >= 100 ? 0 : a >= 10 ? 1 : 2);
}

// ---------------------------------------------------------------- scale and units
// (toUnit, scaleMax, the units and the threshold: view.js)
function defaultMax(d) { return toUnit(d, d.layout.scale_n[1]) || d.layout.scale_n[1]; }
function framePeak(d, f) {
  let peak = 0;
  f.status.forEach((s, k) => {
    const v = VALUED.has(s) ? toUnit(d, f.force_n[k], k) : null;
    if (v !== null && v > peak) peak = v;
  });
  return peak;
}
function updateAuto(d, now) {
  // a device that is down has no forces: its last range is kept until it answers again
  if (!d.frame || (!d.frame.up && d.auto && d.auto.unit === view.unit)) return;
  const peak = framePeak(d, d.frame);
  const floor = toUnit(d, AUTO_FLOOR_N) || AUTO_FLOOR_N;
  const want = niceCeil(Math.max(peak * AUTO_HEADROOM, floor));
  const a = d.auto;
  if (!a || a.unit !== view.unit || want > a.max) {
    d.auto = { max: want, unit: view.unit, since: null };
  } else if (peak * AUTO_HEADROOM < SHRINK_BELOW * a.max) {
    if (a.since === null) a.since = now;
    else if (now - a.since >= SHRINK_AFTER_MS) d.auto = { max: want, unit: view.unit, since: null };
  } else {
    a.since = null;
  }
}

function readView() {
  const q = new URLSearchParams(location.search);
  const unit = (q.get("unit") || "").toLowerCase();
  view.unit = UNITS.find((u) => u.toLowerCase() === unit) || "N";
  const max = Number.parseFloat(q.get("max") || "");
  view.max = Number.isFinite(max) && max > 0 ? max : null;
  const mode = q.get("scale");
  view.mode = mode === "auto" || mode === "fixed" ? mode : view.max !== null ? "fixed" : "auto";
  const yes = (v) => ["1", "true", "on", "yes"].includes((v || "").toLowerCase());
  view.numbers = yes(q.get("numbers"));
  view.same = yes(q.get("same"));
  const thr = Number.parseFloat(q.get("threshold") || "");
  view.threshold = Number.isFinite(thr) && thr > 0 ? thr : null;
  view.rois = readRois(q);
}
function writeView() {
  const q = new URLSearchParams(location.search);
  q.set("scale", view.mode);
  if (view.max !== null) q.set("max", String(view.max)); else q.delete("max");
  q.set("unit", view.unit);
  if (view.numbers) q.set("numbers", "1"); else q.delete("numbers");
  if (view.same) q.set("same", "1"); else q.delete("same");
  if (view.threshold !== null) q.set("threshold", String(view.threshold)); else q.delete("threshold");
  writeRois(q);
  history.replaceState(null, "", `${location.pathname}?${q}${location.hash}`);
}
function showControls() {
  $("scale-mode").value = view.mode;
  $("unit").value = view.unit;
  $("ov-unit").value = view.unit;
  $("same-scale").checked = view.same;
  $("numbers").checked = view.numbers;
  $("scale-max-unit").textContent = unitLabel();
  const d = selected && devices.get(selected);
  if (document.activeElement !== $("scale-max")) {
    $("scale-max").value = view.max !== null ? String(view.max) : "";
    $("scale-max").placeholder = d ? fmtValue(defaultMax(d)) : "";
  }
}

// ---------------------------------------------------------------- layout
function geometry(layout) {
  if ((layout.regions || []).length) return regionGeometry(layout);
  const all = layout.channels.concat(layout.disabled_channels || []);
  const xs = all.map((c) => c.x_mm);
  const ys = all.map((c) => c.y_mm);
  let pitch = Infinity;
  for (let i = 0; i < xs.length; i++) {
    for (let j = i + 1; j < xs.length; j++) {
      const d = Math.hypot(xs[i] - xs[j], ys[i] - ys[j]);
      if (d > 1e-9 && d < pitch) pitch = d;
    }
  }
  if (!Number.isFinite(pitch)) pitch = 1;
  return {
    pitch, xs, ys,
    x0: Math.min(...xs) - pitch / 2, x1: Math.max(...xs) + pitch / 2,
    y0: Math.min(...ys) - pitch / 2, y1: Math.max(...ys) + pitch / 2,
  };
}

function transform(geo, w, h, margin) {
  const s = Math.min((w - 2 * margin) / (geo.x1 - geo.x0), (h - 2 * margin) / (geo.y1 - geo.y0));
  const ox = (w - s * (geo.x1 - geo.x0)) / 2 - s * geo.x0;
  const oy = (h - s * (geo.y1 - geo.y0)) / 2 - s * geo.y0;
  return { s, px: (x) => ox + s * x, py: (y) => oy + s * y, mx: (px) => (px - ox) / s, my: (py) => (py - oy) / s };
}

async function loadDevices() {
  const resp = await fetch("/api/devices", { cache: "no-store" });
  if (!resp.ok) throw new Error(`/api/devices: ${resp.status}`);
  const data = await resp.json();
  const names = new Set();
  source = data.playback ? "playback" : "live";
  for (const layout of data.devices) {
    names.add(layout.name);
    const old = devices.get(layout.name);
    devices.set(layout.name, {
      layout, geo: geometry(layout), frame: old ? old.frame : null, arrived: old ? old.arrived : 0,
      auto: old ? old.auto : null, historySource: old ? old.historySource : null,
      history: old ? old.history : [], trail: old ? old.trail : [], polls: old ? old.polls : [],
    });
  }
  for (const name of [...devices.keys()]) if (!names.has(name)) devices.delete(name);
  buildOverview();
  route();
  return data;
}

// ---------------------------------------------------------------- frames
let reloading = null;
function onFrame(f) {
  const d = devices.get(f.device);
  if (!d || d.layout.channels.length !== f.force_n.length) {
    if (!reloading) reloading = loadDevices().catch(() => {}).finally(() => { reloading = null; });
    return;
  }
  const now = performance.now();
  d.frame = f;
  d.arrived = now;
  if (f.t !== null) {
    d.history.push(histPoint(f, d));
    while (d.history.length && d.history[0].t < f.t - HISTORY_S) d.history.shift();
    if (f.cop_mm) d.trail.push([f.t, f.cop_mm[0], f.cop_mm[1]]);
    while (d.trail.length && d.trail[0][0] < f.t - TRAIL_S) d.trail.shift();
  }
  updateAuto(d, now);
  d.polls.push([now, f.polls_total]);
  while (d.polls.length > 2 && d.polls[0][0] < now - 3000) d.polls.shift();
  dirty = true;
}

// a frame's reference total force (N; playback of a record with force_n), else null
function refTotal(f) {
  return f.reference_total_force_n === undefined ? null : f.reference_total_force_n;
}

function connect() {
  const es = new EventSource("/api/live");
  es.addEventListener("frame", (ev) => onFrame(JSON.parse(ev.data)));
  es.addEventListener("open", () => { $("conn").textContent = "live"; $("conn").className = "conn live"; });
  es.addEventListener("error", () => { $("conn").textContent = "reconnecting…"; $("conn").className = "conn"; });
}

// "up", "stale" (the gateway could not read it, or no frame lately) or "waiting"
function deviceState(d, now) {
  if (!d.frame) return "waiting";
  if (playback) return d.frame.up ? "up" : "stale"; // a record's frames do not age
  const limit = Math.max(1500, 5000 * (d.frame.poll_interval_s || 0.1));
  if (!d.frame.up || now - d.arrived > limit) return "stale";
  return "up";
}

// ---------------------------------------------------------------- drawing
function drawMap(canvas, d, opts) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width;
  const h = canvas.height;
  ctx.fillStyle = "#000";
  ctx.fillRect(0, 0, w, h);
  const geo = d.geo;
  const tr = transform(geo, w, h, opts.margin);
  const f = d.frame;
  const max = scaleMax(d);
  const cellSide = tr.s * geo.pitch * 0.92;
  // playback's difference or error map: signed values on a diverging key (timeline.js)
  const signed = opts.main && signedMode() ? signedValues() : null;
  const smax = signed ? signedMax(signed) : null;
  let numbers = 0;
  const stale = deviceState(d, performance.now()) === "stale";
  if (opts.smooth && f && !signed) drawSmooth(ctx, d, tr, max);
  drawGrid(ctx, d, tr);
  d.layout.channels.forEach((c, k) => {
    const side = geo.side ? tr.s * geo.side[k] * 0.92 : cellSide;
    const status = f ? f.status[k] : ST.STALE;
    const value = f ? shownValue(d, f, k) : null;
    const x = tr.px(c.x_mm) - side / 2;
    const y = tr.py(c.y_mm) - side / 2;
    let label = null;
    let number = null;
    let ink = "#fff";
    if (VALUED.has(status)) {
      const fill = signed ? divergingColour(signed[k] || 0, smax) : colour(value || 0, max);
      if (!opts.smooth || signed) {
        ctx.fillStyle = rgb(fill);
        ctx.fillRect(x, y, side, side);
      }
      if (opts.numbers && value !== null) {
        number = fmtValue(signed ? signed[k] || 0 : value);
        ink = opts.smooth || 0.3 * fill[0] + 0.59 * fill[1] + 0.11 * fill[2] < 140 ? "#fff" : "#000";
      }
      if (status === ST.SATURATED) {
        ctx.strokeStyle = "#fff";
        ctx.lineWidth = Math.max(2, side * 0.06);
        ctx.strokeRect(x + 2, y + 2, side - 4, side - 4);
        label = "SAT";
      } else if (status === ST.EXTRAPOLATED) {
        const w = Math.max(2, side * 0.06);
        ctx.save();
        ctx.strokeStyle = EXTRAPOLATED_COLOUR;
        ctx.lineWidth = w;
        ctx.setLineDash([2 * w, 1.5 * w]);
        ctx.strokeRect(x + w, y + w, side - 2 * w, side - 2 * w);
        ctx.restore();
        label = "EXT";
      } else if (status === ST.NO_ZERO) {
        const w = Math.max(1.5, side * 0.04);
        ctx.save();
        ctx.strokeStyle = NO_ZERO_COLOUR;
        ctx.lineWidth = w;
        ctx.setLineDash([w, w]);
        ctx.strokeRect(x + w, y + w, side - 2 * w, side - 2 * w);
        ctx.restore();
        label = "NO 0";
      }
    } else {
      const fill = { [ST.OPEN]: ["#555", "#222"], [ST.SHORT]: ["#d0307a", "#401020"],
                     [ST.STALE]: ["#3a4048", "#3a4048"], [ST.ERROR]: ["#000", "#000"],
                     [ST.UNCALIBRATED]: ["#2c3440", "#1c2026"] }[status] || ["#000", "#000"];
      hatch(ctx, x, y, side, fill[0], fill[1]);
      label = { [ST.OPEN]: "OPEN", [ST.SHORT]: "SHORT", [ST.STALE]: "STALE", [ST.ERROR]: "ERR",
                [ST.UNCALIBRATED]: "UNCAL" }[status];
      if (status === ST.ERROR) { ctx.strokeStyle = "#f33"; ctx.lineWidth = 2; ctx.strokeRect(x, y, side, side); }
    }
    if (stale && status !== ST.STALE) {
      ctx.fillStyle = "rgba(58,64,72,0.7)";
      ctx.fillRect(x, y, side, side);
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    if (label && side > 26) {
      ctx.fillStyle = "#fff";
      ctx.font = `${Math.max(9, Math.min(16, side / 5))}px sans-serif`;
      ctx.fillText(label, x + side / 2, y + side / (number ? 3 : 2));
    }
    if (number && side > 20) {
      ctx.fillStyle = ink;
      ctx.font = `bold ${Math.max(9, Math.min(18, side / 4.2))}px sans-serif`;
      ctx.fillText(number, x + side / 2, y + (label ? (2 * side) / 3 : side / 2));
      numbers++;
    }
  });
  (d.layout.disabled_channels || []).forEach((c) => {
    const side = geo.sideByIndex ? tr.s * (geo.sideByIndex.get(c.index) || geo.pitch) * 0.92 : cellSide;
    const x = tr.px(c.x_mm) - side / 2;
    const y = tr.py(c.y_mm) - side / 2;
    drawDisabled(ctx, x, y, side);
  });
  canvas.dataset.numbers = String(numbers);
  if (geo.regions && opts.outlines) drawRegionBoxes(ctx, d, tr);
  if (opts.main) drawRois(ctx, d, tr);
  if (f && opts.trail) drawTrail(ctx, d, tr, f);
}

// (drawDisabled, hatch, drawSmooth, drawTrail, drawScale: view.js)

function updateText(d, now) {
  const f = d.frame;
  const st = deviceState(d, now);
  $("state").textContent = st;
  $("state").className = `state ${st}`;
  $("summary").classList.toggle("stale", st === "stale");
  $("summary-old").hidden = st !== "stale";
  if (!f) return;
  const st2 = frameStats(d, f, null);
  $("total-force").textContent = fmtU(totalInUnit(st2.total_n, st2.area_mm2));
  $("total-unit").textContent = unitLabel();
  $("total-label").textContent = view.unit === "N" ? "total force" : "mean pressure over the contact area";
  $("cop-x").textContent = st2.cop ? fmt(st2.cop[0], 2) : "–";
  $("cop-y").textContent = st2.cop ? fmt(st2.cop[1], 2) : "–";
  $("area").textContent = fmt(st2.area_mm2, 2);
  $("in-contact").textContent = String(st2.in_contact);
  $("peak").textContent = st2.peak ? `${st2.peak} ${fmtU(toUnit(d, st2.peak_n, st2.peak_k))} ${unitLabel()}` : "–";
  $("health-up").textContent = f.up ? "up" : `not answering${f.error ? ": " + f.error : ""}`;
  $("health-up").title = $("health-up").textContent;
  const p = d.polls;
  const rate = playback ? (f.poll_interval_s ? 1 / f.poll_interval_s : null)
    : p.length > 1 && p[p.length - 1][0] > p[0][0]
      ? ((p[p.length - 1][1] - p[0][1]) * 1000) / (p[p.length - 1][0] - p[0][0]) : null;
  $("poll-rate").textContent = fmt(rate, 1);
  $("read-errors").textContent = String(f.read_errors_total);
  const age = f.last_success_t === null ? null
    : f.t - f.last_success_t + (playback ? 0 : (now - d.arrived) / 1000);
  $("poll-age").textContent = fmt(age, 1);
  $("summary-old").textContent = st === "stale"
    ? `old: stale${age === null ? "" : `, last good poll ${fmt(age, 1)} s ago`}` : "";
  $("seq").textContent = String(f.seq);
}

// ---------------------------------------------------------------- views
function buildOverview() {
  const cards = $("cards");
  cards.replaceChildren();
  for (const [name, d] of devices) {
    const card = document.createElement("div");
    card.className = "card";
    card.dataset.device = name;
    const title = document.createElement("h3");
    title.textContent = name;
    const canvas = document.createElement("canvas");
    canvas.width = 200;
    canvas.height = 200;
    const info = document.createElement("p");
    card.append(title, canvas, info);
    card.addEventListener("click", () => { location.hash = `#device=${encodeURIComponent(name)}`; });
    cards.append(card);
    d.card = { canvas, info };
  }
}

function route() {
  const m = /^#device=(.+)$/.exec(location.hash);
  const wanted = m ? decodeURIComponent(m[1]) : null;
  if (wanted && devices.has(wanted)) selected = wanted;
  else if (!wanted && location.hash !== "#overview" && devices.size === 1) selected = [...devices.keys()][0];
  else selected = null;
  $("overview").hidden = selected !== null;
  $("detail").hidden = selected === null;
  if (selected) {
    $("dev-name").textContent = selected;
    // a device made of regions (a hand) gets a larger map: its cells are small
    const side = (devices.get(selected).layout.regions || []).length ? 600 : 480;
    if ($("map").width !== side) { $("map").width = side; $("map").height = side; }
    $("regions").dataset.key = "";
    lastKey = "";
    showWhatIsOn(devices.get(selected).layout.what_is_on || []);
    loadHistory(devices.get(selected));
  }
  dirty = true;
}

// what the gateway does with the device (values, force, drift correction, writes), as
// check-config says it
function showWhatIsOn(lines) {
  $("what-is-on-title").hidden = lines.length === 0; // no heading over an empty list
  const list = $("what-is-on");
  list.replaceChildren(...lines.map((line) => {
    const li = document.createElement("li");
    li.textContent = line;
    return li;
  }));
}

// the colour key: redrawn when its range, unit or mode changes
function drawKey(d) {
  if (playback && signedMode()) { drawSignedKey(d); return; }
  const max = scaleMax(d);
  const title = view.unit === "N" ? "force, N" : `pressure, ${view.unit}`;
  showThreshold(d);
  const key = `${max} ${view.unit} ${rangeWords()} ${threshold()}`;
  if (key === lastKey) return;
  lastKey = key;
  drawScale($("scale"), max, title);
  $("scale").setAttribute("aria-label", `colour scale, ${title}`);
  $("scale-range").textContent = `0–${fmtValue(max)} ${unitLabel()} (${rangeWords()})`;
  markThreshold($("scale"), max);
  $("map").dataset.max = String(max);
  showControls();
}

function render() {
  const now = performance.now();
  if (playback) tickPlayback(now);
  if (dirty || now - lastDraw > 250) {
    dirty = false;
    lastDraw = now;
    if (selected && devices.has(selected)) {
      const d = devices.get(selected);
      drawKey(d);
      drawMap($("map"), d, { margin: 12, smooth: $("smooth").checked, trail: true, numbers: view.numbers, main: true });
      placeRegions(d, $("map"), 12);
      placeAxes(d, $("map"), 12);
      updateSums(d);
      updateRois(d);
      showExport(d);
      updateStatusWords(d.frame);
      drawHistory($("history"), d);
      updateText(d, now);
    } else {
      for (const d of devices.values()) {
        if (!d.card) continue;
        drawMap(d.card.canvas, d, { margin: 6, smooth: false, trail: true, outlines: true });
        const f = d.frame;
        const own = view.same ? "" : ` · key 0–${fmtValue(scaleMax(d))} ${unitLabel()}`;
        const total = f ? fmtU(totalInUnit(f.total_force_n, f.contact_area_mm2)) : "–";
        const what = view.unit === "N" ? "total" : "mean";
        d.card.info.textContent = `${deviceState(d, now)} · ${what} ${total} ${unitLabel()}${own}`;
      }
      drawOverviewKey();
    }
  }
  requestAnimationFrame(render);
}

// the key of playback's difference or error map: symmetric about zero
function drawSignedKey(d) {
  const smax = signedMax(signedValues());
  const words = signedWords();
  const key = `signed ${smax} ${view.unit} ${words}`;
  if (key === lastKey) return;
  lastKey = key;
  drawSignedScale($("scale"), smax, `${mapMode.mode === "diff" ? "B − A" : "error"}, ${unitLabel()}`);
  $("scale-range").textContent = `${fmtValue(-smax)}…${fmtValue(smax)} ${unitLabel()} (${words})`;
  $("map").dataset.max = String(smax);
}

// (playback: frameAt, seek, setPlaying, tickPlayback, startPlayback: timeline.js)

function hover(ev) {
  const tip = $("tooltip");
  const d = selected && devices.get(selected);
  if (!d || !d.frame) { tip.hidden = true; return; }
  const canvas = $("map");
  const rect = canvas.getBoundingClientRect();
  const cx = ((ev.clientX - rect.left) * canvas.width) / rect.width;
  const cy = ((ev.clientY - rect.top) * canvas.height) / rect.height;
  const tr = transform(d.geo, canvas.width, canvas.height, 12);
  const xm = tr.mx(cx);
  const ym = tr.my(cy);
  let best = -1;
  let bestD = d.geo.pitch / 2;
  d.layout.channels.forEach((c, k) => {
    const dist = Math.max(Math.abs(c.x_mm - xm), Math.abs(c.y_mm - ym));
    if (dist <= bestD) { bestD = dist; best = k; }
  });
  if (best < 0) { tip.hidden = true; return; }
  const c = d.layout.channels[best];
  const f = d.frame;
  const status = d.layout.status_labels[f.status[best]] || "?";
  const force = f.force_n[best];
  const p = view.unit === "N" ? null : toUnit(d, force, best);
  const value = force === null ? "no value"
    : `${force.toFixed(3)} N${p !== null ? `, ${p.toFixed(1)} ${view.unit}` : ""}`;
  const ref = f.reference_force_n ? f.reference_force_n[best] : null;
  const against = ref === null || ref === undefined || force === null ? ""
    : `, reference ${ref.toFixed(3)} N, error ${force - ref >= 0 ? "+" : ""}${(force - ref).toFixed(3)} N`;
  const signed = playback && signedMode() && mapMode.mode === "diff" ? signedValues()[best] : null;
  const diff = signed === null ? "" : `, B − A ${signed >= 0 ? "+" : ""}${fmtU(signed)} ${unitLabel()}`;
  tip.textContent = `${c.name} (${c.x_mm}, ${c.y_mm} mm): ${value}, ${status}${against}${diff}`;
  tip.hidden = false;
  // beside the pointer, on its left where the right would leave the map (a phone's edge)
  const x = ev.clientX - rect.left;
  tip.style.left = `${x + 14 + tip.offsetWidth > rect.width ? Math.max(0, x - 14 - tip.offsetWidth) : x + 14}px`;
  tip.style.top = `${ev.clientY - rect.top + 14}px`;
}

function main() {
  $("nav-overview").addEventListener("click", (ev) => {
    ev.preventDefault();
    history.pushState(null, "", "#overview");
    route();
  });
  window.addEventListener("hashchange", route);
  $("map").addEventListener("mousemove", hover);
  $("map").addEventListener("mouseleave", () => { $("tooltip").hidden = true; });
  $("smooth").addEventListener("change", () => { dirty = true; });
  startTools();
  readView();
  showControls();
  const changed = () => { writeView(); showControls(); lastKey = ""; dirty = true; };
  $("scale-mode").addEventListener("change", () => { view.mode = $("scale-mode").value; changed(); });
  const setUnit = (unit) => {
    const was = view.unit;
    view.unit = unit;
    view.max = null; // a maximum is in its unit
    // a threshold is kept between kPa and mmHg, else it is in its unit and dropped
    view.threshold = view.threshold === null ? null : convertPressure(view.threshold, was, unit);
    for (const d of devices.values()) updateAuto(d, performance.now());
    changed();
  };
  $("unit").addEventListener("change", () => setUnit($("unit").value));
  $("ov-unit").addEventListener("change", () => setUnit($("ov-unit").value));
  $("same-scale").addEventListener("change", () => { view.same = $("same-scale").checked; changed(); });
  const thresholdFrom = (el) => { setThreshold(Number.parseFloat(el.value)); changed(); };
  $("threshold").addEventListener("change", () => thresholdFrom($("threshold")));
  $("threshold-slider").addEventListener("input", () => thresholdFrom($("threshold-slider")));
  $("scale-max").addEventListener("change", () => {
    const v = Number.parseFloat($("scale-max").value);
    view.max = Number.isFinite(v) && v > 0 ? v : null;
    if (view.max !== null) view.mode = "fixed";
    changed();
  });
  $("numbers").addEventListener("change", () => { view.numbers = $("numbers").checked; changed(); });
  loadDevices()
    .then((data) => (data.playback ? startPlayback(data.playback) : connect()))
    .catch((err) => { $("conn").textContent = `cannot load: ${err.message}`; });
  requestAnimationFrame(render);
}

document.addEventListener("DOMContentLoaded", main);
