// tactile-gateway live page: a device made of regions (a hand) and the device's status words.
// Plain browser JavaScript, no build step; loaded before app.js, whose helpers ($, fmt, VALUED,
// transform) these functions use when called. A region device is drawn region by region, each in
// its configured place, outlined and named, with the sum of force over each region and each group
// (a finger, the palm); the status words show a state word's code and each named bit.
"use strict";

// a device made of regions: the drawing spans the regions' boxes; a cell is as wide as the
// smaller pitch of its own region (k: its place in the frame; by channel index for the disabled)
function regionGeometry(layout) {
  const boxes = layout.regions.map((r) => r.box_mm);
  const sideByIndex = new Map();
  const areaByIndex = new Map(); // a cell's area (mm^2): its region's pitch along x times along y
  for (const r of layout.regions) {
    const side = Math.min(r.pitch_mm[0], r.pitch_mm[1]);
    for (let i = 0; i < r.n_channels; i++) {
      sideByIndex.set(r.first_channel + i, side);
      areaByIndex.set(r.first_channel + i, r.pitch_mm[0] * r.pitch_mm[1]);
    }
  }
  const pitch = Math.min(...layout.regions.map((r) => Math.min(r.pitch_mm[0], r.pitch_mm[1])));
  return {
    pitch, regions: true,
    side: layout.channels.map((c) => sideByIndex.get(c.index) || pitch),
    area: layout.channels.map((c) => areaByIndex.get(c.index) || pitch * pitch),
    sideByIndex,
    frameSlot: new Map(layout.channels.map((c, k) => [c.index, k])),
    x0: Math.min(...boxes.map((b) => b[0])), y0: Math.min(...boxes.map((b) => b[1])),
    x1: Math.max(...boxes.map((b) => b[2])), y1: Math.max(...boxes.map((b) => b[3])),
  };
}

// the sum of force (N) over the channels of one region of the frame: its valued channels only
function regionSum(d, r, f) {
  let sum = 0;
  for (let i = 0; i < r.n_channels; i++) {
    const k = d.geo.frameSlot.get(r.first_channel + i);
    if (k === undefined) continue; // disabled: never polled
    const v = f.force_n[k];
    if (VALUED.has(f.status[k]) && v !== null) sum += v;
  }
  return sum;
}

// each region's outline on the map (the detail view also names them: placeRegions)
function drawRegionBoxes(ctx, d, tr) {
  ctx.save();
  ctx.strokeStyle = "#8c96a3";
  ctx.lineWidth = 1;
  for (const r of d.layout.regions) {
    const [l, t, rr, b] = r.box_mm;
    ctx.strokeRect(tr.px(l) - 1.5, tr.py(t) - 1.5, tr.s * (rr - l) + 3, tr.s * (b - t) + 3);
  }
  ctx.restore();
}

// the named outlines of the regions over the detail map (elements, so that they can be read and
// hovered), placed from the same transform as the cells; rebuilt when the layout or size changes
function placeRegions(d, canvas, margin) {
  const box = $("regions");
  const regions = d.layout.regions || [];
  const key = `${d.layout.name} ${canvas.width} ${canvas.clientWidth} ${regions.length}`;
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  const tr = transform(d.geo, canvas.width, canvas.height, margin);
  const k = canvas.clientWidth / canvas.width || 1; // CSS px per canvas px
  box.replaceChildren(...regions.map((r) => {
    const [l, t, rr, b] = r.box_mm;
    const el = document.createElement("div");
    el.className = "region";
    el.dataset.region = r.name;
    el.dataset.group = r.group;
    el.title = `${r.name} (${r.group}): ${r.rows} x ${r.columns}` +
      (r.rotation_deg ? `, turned ${r.rotation_deg}°` : "");
    el.style.left = `${k * tr.px(l)}px`;
    el.style.top = `${k * tr.py(t)}px`;
    el.style.width = `${k * tr.s * (rr - l)}px`;
    el.style.height = `${k * tr.s * (b - t)}px`;
    const label = document.createElement("span");
    label.textContent = r.name.startsWith(`${r.group}-`) ? r.name.slice(r.group.length + 1) : r.name;
    el.append(label);
    return el;
  }));
  // a group of several regions (a finger) is named under them all
  for (const g of d.layout.groups || []) {
    const parts = regions.filter((r) => r.group === g.name);
    if (parts.length < 2) continue;
    const l = Math.min(...parts.map((r) => r.box_mm[0]));
    const rr = Math.max(...parts.map((r) => r.box_mm[2]));
    const b = Math.max(...parts.map((r) => r.box_mm[3]));
    const el = document.createElement("div");
    el.className = "group-label";
    el.dataset.group = g.name;
    el.textContent = g.name;
    el.style.left = `${k * tr.px(l)}px`;
    el.style.top = `${k * tr.py(b) + 2}px`;
    el.style.width = `${k * tr.s * (rr - l)}px`;
    box.append(el);
  }
  box.hidden = regions.length === 0;
  buildSums(d);
}

// the table of sums: a row per group (a finger, the palm), then one per region of it
function buildSums(d) {
  const groups = d.layout.groups || [];
  $("sums-title").hidden = groups.length === 0;
  $("sums").hidden = groups.length === 0;
  const rows = [];
  for (const g of groups) {
    const tr = document.createElement("tr");
    tr.className = "group";
    tr.dataset.group = g.name;
    const th = document.createElement("th");
    th.textContent = g.name;
    const td = document.createElement("td");
    td.className = "sum";
    td.textContent = "–";
    tr.append(th, td);
    rows.push(tr);
    if (g.regions.length === 1 && g.regions[0] === g.name) continue;
    for (const name of g.regions) {
      const rt = document.createElement("tr");
      rt.className = "part";
      rt.dataset.region = name;
      const rh = document.createElement("th");
      rh.textContent = name;
      const rd = document.createElement("td");
      rd.className = "sum";
      rd.textContent = "–";
      rt.append(rh, rd);
      rows.push(rt);
    }
  }
  $("sums-body").replaceChildren(...rows);
}

// the device's status words: an enumerated word's code, each named bit (set bits lit, error
// bits and error codes red when set); rebuilt only when a word changes
function updateStatusWords(f) {
  const words = (f && f.device_status) || [];
  const box = $("device-status");
  const key = JSON.stringify(words);
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  $("device-status-title").hidden = words.length === 0;
  box.replaceChildren(...words.map((w) => {
    const row = document.createElement("div");
    row.className = `word${w.error ? " error" : ""}`;
    row.dataset.word = w.name;
    const name = document.createElement("span");
    name.className = "word-name";
    name.textContent = w.name;
    row.append(name);
    if (w.value === null) {
      const chip = document.createElement("span");
      chip.className = "bit unread";
      chip.textContent = "not read";
      row.append(chip);
    }
    if (w.code !== null) {
      const chip = document.createElement("span");
      chip.className = `bit code on${w.error ? " error" : ""}`;
      chip.dataset.code = w.code;
      chip.textContent = w.code;
      row.append(chip);
    }
    for (const b of w.bits) {
      const chip = document.createElement("span");
      chip.className = `bit${b.on ? " on" : ""}${b.error ? " error" : ""}`;
      chip.dataset.bit = b.label;
      chip.dataset.on = b.on ? "1" : "0";
      chip.title = `bit ${b.bit}${b.error ? " (error)" : ""}: ${b.on ? "set" : "clear"}`;
      chip.textContent = b.label;
      row.append(chip);
    }
    return row;
  }));
}

// the frame slots of a region's channels (the disabled left out: never polled)
function regionSlots(d, r) {
  const out = [];
  for (let i = 0; i < r.n_channels; i++) {
    const k = d.geo.frameSlot.get(r.first_channel + i);
    if (k !== undefined) out.push(k);
  }
  return out;
}

// the sums in N (data-n keeps the force); in a pressure unit each group's and region's figure
// is the mean pressure over its contact area (its forces in contact over their cells' area)
function updateSums(d) {
  const f = d.frame;
  if (!f || !(d.layout.groups || []).length) return;
  const pressure = view.unit !== "N";
  $("sums-title").textContent = pressure ? `Mean pressure by finger and region (${view.unit})`
    : "Force by finger and region (N)";
  const byRegion = new Map(d.layout.regions.map((r) => [r.name, regionSum(d, r, f)]));
  const slots = new Map(d.layout.regions.map((r) => [r.name, regionSlots(d, r)]));
  for (const row of $("sums-body").children) {
    let sum;
    let names;
    if (row.dataset.group !== undefined) {
      const g = d.layout.groups.find((x) => x.name === row.dataset.group);
      names = g ? g.regions : [];
      sum = g ? g.regions.reduce((a, name) => a + (byRegion.get(name) || 0), 0) : null;
    } else {
      names = [row.dataset.region];
      sum = byRegion.get(row.dataset.region);
    }
    const cell = row.querySelector(".sum");
    if (pressure) {
      const st = frameStats(d, f, names.flatMap((name) => slots.get(name) || []));
      cell.textContent = fmtU(totalInUnit(st.total_n, st.area_mm2));
    } else {
      cell.textContent = fmt(sum, 3);
    }
    cell.dataset.n = sum === null || sum === undefined ? "" : String(sum);
  }
}
