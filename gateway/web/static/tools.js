// tactile-gateway live page: regions of interest and export. Plain browser JavaScript, no build
// step; loaded before app.js, whose globals (view, devices, selected, playback, transform, $,
// frameStats, toUnit, fmtU, ...) these functions use when called.
//
// A region of interest is a set of channels: dragged as a rectangle on the map (the channels
// whose centres it holds) or named in the gateway's configuration (the frame's `rois`, with the
// gateway's own figures). The page's regions persist in the URL (?roi=name:4,5,8,9, one `roi`
// per region, by channel index). Each region shows its sum of force (in a pressure unit: the
// mean pressure over its contact area), its peak, its contact area and its centre of pressure,
// over its channels in contact (the page's threshold applies to the page's regions).
// Export: CSV from the gateway's export (GET /api/devices/{name}/export.csv?from_s=&to_s=, the
// record format) of the shown frame or of the chart's span, and PNG of the map with its key.
"use strict";

const ROI_COLOUR = "#5fb3ff";
const ROI_CONFIGURED_COLOUR = "#f5a623";
const DRAG_MIN_PX = 6;
const FRAME_WINDOW_S = 1e-5;

// ?roi=name:4,5,8,9 (repeated) -> [{name, cells}]
function readRois(q) {
  const out = [];
  for (const v of q.getAll("roi")) {
    const m = /^([^:]{1,40}):([0-9,]+)$/.exec(v);
    if (!m) continue;
    const cells = [...new Set(m[2].split(",").filter((x) => x !== "").map(Number))].sort((a, b) => a - b);
    if (cells.length && !out.some((r) => r.name === m[1])) out.push({ name: m[1], cells });
  }
  return out;
}
function writeRois(q) {
  q.delete("roi");
  for (const r of view.rois) q.append("roi", `${r.name}:${r.cells.join(",")}`);
}

// the frame slots of channel indices (those the frame carries)
function slotsOf(d, cells) {
  const slot = new Map(d.layout.channels.map((c, k) => [c.index, k]));
  return cells.map((i) => slot.get(i)).filter((k) => k !== undefined);
}

// every region shown: the page's, then the configuration's (from the frame)
function allRois(d) {
  const mine = view.rois.map((r) => ({ name: r.name, cells: r.cells, configured: false }));
  const f = d.frame;
  const theirs = (f && f.rois) || [];
  return mine.concat(theirs.map((r) => ({ name: r.name, cells: r.channels, configured: true, figures: r })));
}

// a region's figures: the gateway's for a configured one, else over its channels in this frame
function roiStats(d, r) {
  if (r.configured) {
    const g = r.figures;
    return {
      total_n: g.force_n, peak_n: g.peak_n, peak_k: -1, area_mm2: g.area_mm2,
      cop: g.cop_x_mm === null || g.cop_x_mm === undefined ? null : [g.cop_x_mm, g.cop_y_mm],
    };
  }
  return frameStats(d, d.frame, slotsOf(d, r.cells));
}

// the table of regions: rows rebuilt when the set of regions changes, figures each draw
function updateRois(d) {
  const rois = d.frame ? allRois(d) : view.rois.map((r) => ({ ...r, configured: false }));
  const body = $("rois-body");
  const key = JSON.stringify(rois.map((r) => [r.name, r.cells, r.configured]));
  $("rois-box").hidden = rois.length === 0;
  $("rois-sum-head").textContent = view.unit === "N" ? "sum, N" : `mean, ${view.unit}`;
  $("rois-peak-head").textContent = `peak, ${view.unit}`;
  if (body.dataset.key !== key) {
    body.dataset.key = key;
    body.replaceChildren(...rois.map((r) => {
      const tr = document.createElement("tr");
      tr.dataset.roi = r.name;
      tr.dataset.cells = r.cells.join(",");
      tr.dataset.configured = r.configured ? "1" : "0";
      const th = document.createElement("th");
      th.textContent = r.configured ? `${r.name} (configured)` : r.name;
      th.title = `channels ${r.cells.join(", ")}`;
      tr.append(th);
      for (const cls of ["sum", "peak", "area", "cop"]) {
        const td = document.createElement("td");
        td.className = cls;
        tr.append(td);
      }
      const td = document.createElement("td");
      if (!r.configured) {
        const b = document.createElement("button");
        b.type = "button";
        b.className = "remove";
        b.textContent = "×";
        b.title = `remove ${r.name}`;
        b.addEventListener("click", () => {
          view.rois = view.rois.filter((x) => x.name !== r.name);
          writeView();
          updateRois(d);
          dirty = true;
        });
        td.append(b);
      }
      tr.append(td);
      return tr;
    }));
  }
  if (!d.frame) return;
  const rows = body.children;
  rois.forEach((r, i) => {
    const row = rows[i];
    const s = roiStats(d, r);
    const area = s.area_mm2 || 0;
    row.dataset.sum = String(s.total_n);
    row.dataset.peak = s.peak_n === null ? "" : String(s.peak_n);
    row.dataset.area = String(area);
    row.dataset.copx = s.cop ? String(s.cop[0]) : "";
    row.dataset.copy = s.cop ? String(s.cop[1]) : "";
    row.querySelector(".sum").textContent = fmtU(totalInUnit(s.total_n, area));
    row.querySelector(".peak").textContent = fmtU(toUnit(d, s.peak_n, s.peak_k));
    row.querySelector(".area").textContent = fmt(area, 2);
    row.querySelector(".cop").textContent = s.cop ? `${fmt(s.cop[0], 2)}, ${fmt(s.cop[1], 2)}` : "–";
  });
}

// each region's outline (around its cells) and name on the map
function drawRois(ctx, d, tr) {
  const geo = d.geo;
  ctx.save();
  ctx.lineWidth = 2;
  ctx.setLineDash([6, 4]);
  ctx.font = "12px sans-serif";
  ctx.textAlign = "left";
  ctx.textBaseline = "bottom";
  for (const r of allRois(d)) {
    const ks = slotsOf(d, r.cells);
    if (!ks.length) continue;
    let x0 = Infinity; let y0 = Infinity; let x1 = -Infinity; let y1 = -Infinity;
    for (const k of ks) {
      const c = d.layout.channels[k];
      const h = (geo.side ? geo.side[k] : geo.pitch) / 2;
      x0 = Math.min(x0, c.x_mm - h); x1 = Math.max(x1, c.x_mm + h);
      y0 = Math.min(y0, c.y_mm - h); y1 = Math.max(y1, c.y_mm + h);
    }
    const colourOf = r.configured ? ROI_CONFIGURED_COLOUR : ROI_COLOUR;
    ctx.strokeStyle = colourOf;
    ctx.strokeRect(tr.px(x0) + 1, tr.py(y0) + 1, tr.s * (x1 - x0) - 2, tr.s * (y1 - y0) - 2);
    ctx.fillStyle = colourOf;
    ctx.fillText(r.name, tr.px(x0) + 4, tr.py(y0) + 16);
  }
  ctx.restore();
}

// ---------------------------------------------------------------- dragging a region
let dragStart = null;

function canvasPoint(ev) {
  const canvas = $("map");
  const rect = canvas.getBoundingClientRect();
  return {
    css: [ev.clientX - rect.left, ev.clientY - rect.top],
    px: [((ev.clientX - rect.left) * canvas.width) / rect.width, ((ev.clientY - rect.top) * canvas.height) / rect.height],
  };
}

function onDragStart(ev) {
  if (ev.button !== 0 || !selected) return;
  dragStart = canvasPoint(ev);
  $("map").setPointerCapture(ev.pointerId);
}

function onDragMove(ev) {
  if (!dragStart) return;
  const p = canvasPoint(ev);
  const [ax, ay] = dragStart.css;
  const [bx, by] = p.css;
  const box = $("roi-rect");
  box.style.left = `${Math.min(ax, bx)}px`;
  box.style.top = `${Math.min(ay, by)}px`;
  box.style.width = `${Math.abs(bx - ax)}px`;
  box.style.height = `${Math.abs(by - ay)}px`;
  box.hidden = Math.abs(bx - ax) < DRAG_MIN_PX && Math.abs(by - ay) < DRAG_MIN_PX;
}

function onDragEnd(ev) {
  if (!dragStart) return;
  const a = dragStart;
  dragStart = null;
  $("roi-rect").hidden = true;
  const b = canvasPoint(ev);
  if (Math.abs(b.css[0] - a.css[0]) < DRAG_MIN_PX && Math.abs(b.css[1] - a.css[1]) < DRAG_MIN_PX) return;
  const d = devices.get(selected);
  if (!d) return;
  const tr = transform(d.geo, $("map").width, $("map").height, 12);
  const [x0, x1] = [tr.mx(a.px[0]), tr.mx(b.px[0])].sort((p, q) => p - q);
  const [y0, y1] = [tr.my(a.px[1]), tr.my(b.px[1])].sort((p, q) => p - q);
  const cells = d.layout.channels.filter((c) => c.x_mm >= x0 && c.x_mm <= x1 && c.y_mm >= y0 && c.y_mm <= y1)
    .map((c) => c.index).sort((p, q) => p - q);
  if (!cells.length) return;
  let n = 1;
  while (view.rois.some((r) => r.name === `roi${n}`)) n++;
  view.rois.push({ name: `roi${n}`, cells });
  writeView();
  dirty = true;
}

// ---------------------------------------------------------------- export
function download(href, filename) {
  const a = document.createElement("a");
  a.href = href;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
}

// the gateway's CSV (the record format) from from_s to to_s (s, the frames' clock)
// a live gateway that keeps no readings to export (export_s = 0 in the device's entry) has
// its CSV buttons disabled (playback's entry has no export_s: its record is there to export)
function showExport(d) {
  const none = d.layout.export_s === 0;
  $("export-frame-csv").disabled = none;
  $("export-span-csv").disabled = none;
  $("export-frame-csv").title = none ? "this gateway keeps no readings to export ([web] export_s = 0)"
    : "the shown frame, from the gateway's export";
}

function exportCsv(span) {
  const d = selected && devices.get(selected);
  if (!d || !d.frame) return;
  const t = d.frame.t;
  // the frame's time is rounded to the microsecond: its own poll lies within 10 us of it,
  // and polls are milliseconds apart
  const to = span ? t : t + FRAME_WINDOW_S;
  const from = span ? (playback ? Math.max(playback.start, t - HISTORY_S) : t - HISTORY_S) : t - FRAME_WINDOW_S;
  const name = encodeURIComponent(d.layout.name);
  download(`/api/devices/${name}/export.csv?from_s=${from}&to_s=${to}`, `${d.layout.name}.csv`);
}

// the map with its key and the key's words beside it, as a PNG file
function exportPng() {
  const d = selected && devices.get(selected);
  if (!d) return;
  const map = $("map");
  const key = $("scale");
  const out = document.createElement("canvas");
  out.width = map.width + key.width + 180;
  out.height = Math.max(map.height, key.height + 80);
  const ctx = out.getContext("2d");
  ctx.fillStyle = "#111418";
  ctx.fillRect(0, 0, out.width, out.height);
  ctx.drawImage(map, 0, 0);
  ctx.fillStyle = "#1b2027";
  ctx.fillRect(map.width + 8, 0, key.width, key.height);
  ctx.drawImage(key, map.width + 8, 0);
  ctx.fillStyle = "#e6e9ee";
  ctx.font = "12px sans-serif";
  ctx.textBaseline = "top";
  const lines = [d.layout.name, $("scale-range").textContent, $("threshold-key").textContent];
  if (d.frame && d.frame.t !== null) lines.push(playback ? $("time-readout").textContent : new Date(d.frame.t * 1000).toISOString());
  lines.forEach((line, i) => ctx.fillText(line, map.width + 8, key.height + 8 + 16 * i, key.width + 170));
  const t = d.frame && d.frame.t !== null ? d.frame.t.toFixed(2) : "0";
  out.toBlob((blob) => {
    if (!blob) return;
    const url = URL.createObjectURL(blob);
    download(url, `${d.layout.name}-${t}.png`);
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  }, "image/png");
}

function startTools() {
  const map = $("map");
  map.addEventListener("pointerdown", onDragStart);
  map.addEventListener("pointermove", onDragMove);
  map.addEventListener("pointerup", onDragEnd);
  map.addEventListener("pointercancel", () => { dragStart = null; $("roi-rect").hidden = true; });
  $("export-frame-csv").addEventListener("click", () => exportCsv(false));
  $("export-span-csv").addEventListener("click", () => exportCsv(true));
  $("export-png").addEventListener("click", exportPng);
}
