// tactile-gateway live page: units, one scale across devices, the contact threshold, and the
// array's grid and mm axes. Plain browser JavaScript, no build step; loaded before app.js, whose
// globals (view, devices, selected, VALUED, ST, transform, niceCeil, $) these functions use when
// called.
//
// Units: force in N, or pressure in kPa or mmHg: a channel's force over its cell's area
// (1 N/mm^2 = 1000 kPa; 1 kPa = 7.50062 mmHg). In a pressure unit the total is shown as the mean
// pressure over the contact area (total force / contact area) and the peak as the peak cell's
// pressure. The contact threshold is in the shown unit: a channel below it is drawn as no contact
// and left out of the page's total, centre of pressure, contact area, count and peak.
"use strict";

const MMHG_PER_KPA = 7.50062;
const UNITS = ["N", "kPa", "mmHg"];

// the factor from N/mm^2 to the shown pressure unit
function pressureFactor() { return view.unit === "mmHg" ? 1000 * MMHG_PER_KPA : 1000; }
function unitLabel() { return view.unit; }
// the area (mm^2) of the cell of frame slot k (on a device of regions, its region's; k
// undefined or -1: the layout's cell), or null where the layout has none
function cellArea(d, k) {
  if (d.geo.area && k !== undefined && k !== null && k >= 0) return d.geo.area[k];
  return d.layout.cell_area_mm2 || (d.geo.area ? Math.min(...d.geo.area) : null);
}
// the frame slot of a channel by name, or -1
function slotOf(d, name) {
  if (!d.slotByName) d.slotByName = new Map(d.layout.channels.map((c, k) => [c.name, k]));
  const k = d.slotByName.get(name);
  return k === undefined ? -1 : k;
}
// N -> the shown unit's value for the channel of frame slot k (null where there is no value)
function toUnit(d, force, k) {
  if (force === null || force === undefined) return null;
  if (view.unit === "N") return force;
  const area = cellArea(d, k);
  return area ? (force * pressureFactor()) / area : null;
}
// a total force (N) over a contact area (mm^2) in the shown unit: the force itself, or the mean
// pressure over the contact area (null without contact)
function totalInUnit(force, area) {
  if (force === null || force === undefined) return null;
  if (view.unit === "N") return force;
  return area > 0 ? (force * pressureFactor()) / area : null;
}
// a value in the shown unit, with the digits its unit reads in
function fmtU(v) { return v === null || v === undefined ? "–" : v.toFixed(view.unit === "N" ? 3 : 1); }
// a value of unit `from` in unit `to` (kPa <-> mmHg only: N needs a cell area); null when not
function convertPressure(v, from, to) {
  if (from === to) return v;
  if (from === "kPa" && to === "mmHg") return v * MMHG_PER_KPA;
  if (from === "mmHg" && to === "kPa") return v / MMHG_PER_KPA;
  return null;
}

// ---------------------------------------------------------------- one scale for all devices
// the top of one device's own scale, in the shown unit
function ownMax(d) {
  if (view.mode === "fixed") return view.max !== null ? view.max : defaultMax(d);
  return d.auto && d.auto.unit === view.unit ? d.auto.max : defaultMax(d);
}
// the top of the colour scale for a device: its own, or the largest of all devices' (one scale)
function scaleMax(d) {
  if (!view.same) return ownMax(d);
  if (view.mode === "fixed" && view.max !== null) return view.max;
  let top = 0;
  for (const e of devices.values()) top = Math.max(top, ownMax(e));
  return top || ownMax(d);
}
function rangeWords() { return view.same ? `${view.mode}, all devices` : view.mode; }

// the key of the overview: one key for all cards when one scale is on
function drawOverviewKey() {
  $("overview-keybox").hidden = !view.same || devices.size === 0;
  if (!view.same || devices.size === 0) return;
  const d = devices.values().next().value;
  const max = scaleMax(d);
  const key = `${max} ${view.unit} ${rangeWords()}`;
  if ($("overview-key").dataset.key === key) return;
  $("overview-key").dataset.key = key;
  drawScale($("overview-key"), max, view.unit === "N" ? "force, N" : `pressure, ${view.unit}`);
  $("overview-range").textContent = `0–${fmtValue(max)} ${unitLabel()} (${rangeWords()})`;
}

// ---------------------------------------------------------------- the contact threshold
// the threshold in the shown unit (0: none, the gateway's own contact decides)
function threshold() { return view.threshold || 0; }
// whether channel k of frame f is in contact on the page
function inContact(d, f, k) {
  const s = f.status[k];
  if (!VALUED.has(s) || s === ST.NO_CONTACT) return false;
  const force = f.force_n[k];
  if (force === null || force <= 0) return false;
  const thr = threshold();
  if (thr <= 0) return true;
  const v = toUnit(d, force, k);
  return v !== null && v >= thr;
}
// the drawn value of channel k (shown unit): below the threshold a channel draws as no contact
function shownValue(d, f, k) {
  const v = toUnit(d, f.force_n[k], k);
  return v !== null && threshold() > 0 && v < threshold() ? 0 : v;
}
// the page's figures of a frame over a set of channels (frame slots; all when null): total
// force (N), contact area (mm^2), channels in contact, the peak channel and its force (N), the
// centre of pressure (mm). Without a threshold and over all channels, the gateway's own figures.
function frameStats(d, f, slots) {
  if (!slots && threshold() <= 0) {
    return {
      total_n: f.total_force_n, area_mm2: f.contact_area_mm2, in_contact: f.channels_in_contact,
      peak: f.peak_channel, peak_n: f.peak_force_n, peak_k: slotOf(d, f.peak_channel), cop: f.cop_mm,
    };
  }
  let area = 0;
  let peakK = -1;
  let total = 0;
  let n = 0;
  let peak = null;
  let peakN = null;
  let sx = 0;
  let sy = 0;
  const ks = slots || d.layout.channels.map((_c, k) => k);
  for (const k of ks) {
    if (!inContact(d, f, k)) continue;
    const force = f.force_n[k];
    const c = d.layout.channels[k];
    total += force;
    area += cellArea(d, k) || d.geo.pitch * d.geo.pitch;
    n++;
    sx += force * c.x_mm;
    sy += force * c.y_mm;
    if (peakN === null || force > peakN) { peakN = force; peak = c.name; peakK = k; }
  }
  return {
    total_n: total, area_mm2: area, in_contact: n, peak, peak_n: peakN, peak_k: peakK,
    cop: total > 0 ? [sx / total, sy / total] : null,
  };
}

function showThreshold(d) {
  const thr = threshold();
  $("threshold-key").textContent = thr > 0 ? `contact from ${fmtU(thr)} ${unitLabel()}`
    : "contact: the gateway's (no threshold set)";
  const top = d ? scaleMax(d) : 1;
  $("threshold-slider").max = String(top);
  $("threshold-slider").step = String(top / 200);
  if (document.activeElement !== $("threshold-slider")) $("threshold-slider").value = String(thr);
  if (document.activeElement !== $("threshold")) $("threshold").value = thr > 0 ? String(thr) : "";
  $("threshold").max = String(top);
  for (const el of document.querySelectorAll(".unit-label")) el.textContent = unitLabel();
}
// a threshold asked for (shown unit), clamped to 0 .. the scale's top
function setThreshold(v) {
  const d = selected && devices.get(selected);
  const top = d ? scaleMax(d) : Infinity;
  view.threshold = Number.isFinite(v) && v > 0 ? Math.min(v, top) : null;
}

// ---------------------------------------------------------------- grid, outline and mm axes
const GRID_COLOUR = "#3a424d";
const OUTLINE_COLOUR = "#5f6975";

// a line around every cell's place (loaded or not, disabled too) and the array's outline
function drawGrid(ctx, d, tr) {
  const geo = d.geo;
  ctx.save();
  ctx.strokeStyle = GRID_COLOUR;
  ctx.lineWidth = 1.5;
  const cells = d.layout.channels.map((c, k) => [c, geo.side ? geo.side[k] : geo.pitch])
    .concat((d.layout.disabled_channels || []).map(
      (c) => [c, geo.sideByIndex ? geo.sideByIndex.get(c.index) || geo.pitch : geo.pitch]));
  for (const [c, sideMm] of cells) {
    const s = tr.s * sideMm;
    ctx.strokeRect(tr.px(c.x_mm) - s / 2, tr.py(c.y_mm) - s / 2, s, s);
  }
  if (!geo.regions) {
    ctx.strokeStyle = OUTLINE_COLOUR;
    ctx.lineWidth = 2;
    ctx.strokeRect(tr.px(geo.x0), tr.py(geo.y0), tr.s * (geo.x1 - geo.x0), tr.s * (geo.y1 - geo.y0));
  }
  ctx.restore();
}

// tick positions (mm) on one axis: each column's (row's) centre when they are far enough
// apart on screen, else multiples of a round step
function ticks(centres, lo, hi, pxPerMm, minPx) {
  const uniq = [...new Set(centres.map((v) => Math.round(v * 1000) / 1000))].sort((a, b) => a - b);
  let gap = Infinity;
  for (let i = 1; i < uniq.length; i++) gap = Math.min(gap, uniq[i] - uniq[i - 1]);
  if (uniq.length > 1 && uniq.length <= 24 && gap * pxPerMm >= minPx) return uniq;
  const step = niceCeil(minPx / pxPerMm);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(Math.round(v * 1000) / 1000);
  return out;
}

// the mm axes beside the detail map (elements: text keeps its size when the canvas is scaled),
// rebuilt when the layout or the map's size changes
function placeAxes(d, canvas, margin) {
  const box = $("axes");
  const key = `${d.layout.name} ${canvas.width} ${canvas.clientWidth}`;
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  const geo = d.geo;
  const tr = transform(geo, canvas.width, canvas.height, margin);
  const k = canvas.clientWidth / canvas.width || 1; // CSS px per canvas px
  const xs = geo.regions ? [] : d.layout.channels.map((c) => c.x_mm);
  const ys = geo.regions ? [] : d.layout.channels.map((c) => c.y_mm);
  const els = [];
  const label = (cls, v, left, top) => {
    const el = document.createElement("span");
    el.className = `tick ${cls}`;
    el.dataset.mm = String(v);
    el.textContent = String(v);
    el.style.left = `${left}px`;
    el.style.top = `${top}px`;
    els.push(el);
  };
  for (const v of ticks(xs, geo.x0, geo.x1, k * tr.s, 40)) label("x", v, k * tr.px(v), k * canvas.height);
  for (const v of ticks(ys, geo.y0, geo.y1, k * tr.s, 24)) label("y", v, 0, k * tr.py(v));
  const tx = document.createElement("span");
  tx.className = "axis-title x";
  tx.textContent = "x, mm";
  const ty = document.createElement("span");
  ty.className = "axis-title y";
  ty.textContent = "y, mm";
  box.replaceChildren(...els, tx, ty);
}

// the threshold's place on the colour key (drawScale's bar: 24 px from the top to 12 from the bottom)
function markThreshold(canvas, max) {
  const thr = threshold();
  if (thr <= 0) return;
  const ctx = canvas.getContext("2d");
  const top = 24;
  const bottom = canvas.height - 12;
  const y = bottom - Math.min(1, thr / max) * (bottom - top);
  ctx.fillStyle = "#5fb3ff";
  ctx.fillRect(2, y - 1, 34, 2);
}

// ---------------------------------------------------------------- drawing helpers of the map and key
function drawDisabled(ctx, x, y, side) {
  ctx.fillStyle = DISABLED_FILL;
  ctx.fillRect(x, y, side, side);
  ctx.save();
  ctx.strokeStyle = DISABLED_CROSS;
  ctx.lineWidth = Math.max(2, side / 16);
  const m = side * 0.18;
  ctx.beginPath();
  ctx.moveTo(x + m, y + m); ctx.lineTo(x + side - m, y + side - m);
  ctx.moveTo(x + side - m, y + m); ctx.lineTo(x + m, y + side - m);
  ctx.stroke();
  ctx.strokeRect(x + 1, y + 1, side - 2, side - 2);
  ctx.restore();
  if (side > 26) {
    ctx.fillStyle = "#c8ced6";
    ctx.font = `${Math.max(9, Math.min(14, side / 5))}px sans-serif`;
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    ctx.fillText("OFF", x + side / 2, y + side / 2);
  }
}

function hatch(ctx, x, y, side, a, b) {
  ctx.fillStyle = b;
  ctx.fillRect(x, y, side, side);
  ctx.save();
  ctx.beginPath();
  ctx.rect(x, y, side, side);
  ctx.clip();
  ctx.strokeStyle = a;
  ctx.lineWidth = Math.max(2, side / 14);
  for (let k = -side; k < side; k += side / 5) {
    ctx.beginPath();
    ctx.moveTo(x + k, y + side);
    ctx.lineTo(x + k + side, y);
    ctx.stroke();
  }
  ctx.restore();
}

function drawSmooth(ctx, d, tr, max) {
  // a Gaussian-weighted interpolation of the valued channels on a coarse grid, scaled up
  const f = d.frame;
  const n = 96;
  const img = ctx.createImageData(n, n);
  const geo = d.geo;
  const sigma2 = 2 * (0.6 * geo.pitch) ** 2;
  const pts = [];
  d.layout.channels.forEach((c, k) => {
    const s = f.status[k];
    if (VALUED.has(s)) pts.push([c.x_mm, c.y_mm, shownValue(d, f, k) || 0]);
  });
  for (let j = 0; j < n; j++) {
    const ym = geo.y0 + ((j + 0.5) / n) * (geo.y1 - geo.y0);
    for (let i = 0; i < n; i++) {
      const xm = geo.x0 + ((i + 0.5) / n) * (geo.x1 - geo.x0);
      let sw = 0;
      let sv = 0;
      for (const [px, py, v] of pts) {
        const wgt = Math.exp(-((xm - px) ** 2 + (ym - py) ** 2) / sigma2);
        sw += wgt;
        sv += wgt * v;
      }
      const c = colour(sw > 1e-6 ? sv / sw : 0, max);
      const o = 4 * (j * n + i);
      img.data[o] = c[0]; img.data[o + 1] = c[1]; img.data[o + 2] = c[2]; img.data[o + 3] = 255;
    }
  }
  const off = document.createElement("canvas");
  off.width = n;
  off.height = n;
  off.getContext("2d").putImageData(img, 0, 0);
  ctx.imageSmoothingEnabled = true;
  ctx.drawImage(off, tr.px(geo.x0), tr.py(geo.y0), tr.s * (geo.x1 - geo.x0), tr.s * (geo.y1 - geo.y0));
}

function drawTrail(ctx, d, tr, f) {
  const pts = d.trail;
  ctx.lineWidth = 2;
  for (let i = 1; i < pts.length; i++) {
    const age = (f.t - pts[i][0]) / TRAIL_S;
    ctx.strokeStyle = `rgba(95,179,255,${Math.max(0.1, 1 - age)})`;
    ctx.beginPath();
    ctx.moveTo(tr.px(pts[i - 1][1]), tr.py(pts[i - 1][2]));
    ctx.lineTo(tr.px(pts[i][1]), tr.py(pts[i][2]));
    ctx.stroke();
  }
  if (f.cop_mm) {
    const x = tr.px(f.cop_mm[0]);
    const y = tr.py(f.cop_mm[1]);
    ctx.strokeStyle = "#5fb3ff";
    ctx.fillStyle = "#fff";
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.arc(x, y, 8, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
  }
}

function drawScale(canvas, max, title) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width;
  const h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  const top = 24;
  const bottom = h - 12;
  for (let y = top; y <= bottom; y++) {
    ctx.fillStyle = rgb(colour(((bottom - y) / (bottom - top)) * max, max));
    ctx.fillRect(8, y, 22, 1);
  }
  ctx.fillStyle = "#e6e9ee";
  ctx.font = "12px sans-serif";
  ctx.textAlign = "left";
  ctx.textBaseline = "middle";
  ctx.fillText(title, 4, 10);
  for (let k = 0; k <= 5; k++) {
    const y = bottom - (k / 5) * (bottom - top);
    ctx.fillRect(30, y, 5, 1);
    const v = (k / 5) * max;
    ctx.fillText(v.toFixed(max >= 50 ? 0 : max >= 5 ? 1 : max >= 0.5 ? 2 : 3), 38, y);
  }
}
