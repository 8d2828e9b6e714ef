// The review page's script (pipestitch, report/review_page.py). Plain ES2017, no modules:
// it runs from file:// as well as from `pipestitch review`'s local server.
"use strict";
(function () {
const D = JSON.parse(document.getElementById("review-data").textContent);
const G = D.grid;
const served = D.editable && location.protocol.startsWith("http");
const OSD = OpenSeadragon;
const viewer = OSD({
  id: "view", tileSources: D.tiles, drawer: "canvas", showNavigationControl: false,
  showNavigator: true, navigatorPosition: "BOTTOM_RIGHT", maxZoomPixelRatio: 8,
  visibilityRatio: 0.5, constrainDuringPan: true, crossOriginPolicy: false,
  imageSmoothingEnabled: false, gestureSettingsMouse: { clickToZoom: false }
});
const $ = (id) => document.getElementById(id);
const state = { tool: "frames", ruler: [], area: [], last: null, observations: D.observations,
  version: D.version, editing: null };

// --- wall <-> image coordinates (SPEC pixel centres at integers; OSD pixel j spans [j, j+1))
const mosaic = () => viewer.world.getItemAt(0);
const colOf = (z) => (z - G.z0_mm) / G.mm_per_px;
const rowOf = (theta) => ((theta % 360) + 360) % 360 / G.deg_per_px;
const imagePoint = (z, theta) => new OSD.Point(colOf(z) + 0.5, rowOf(theta) + 0.5);
function wallAt(image) {
  const col = image.x - 0.5, row = image.y - 0.5;
  return { col, row, z: G.z0_mm + col * G.mm_per_px, theta: row * G.deg_per_px };
}
function clockText(theta) {
  const minutes = Math.round((((theta - D.crown_theta_deg) % 360 + 360) % 360) * 2 / 5) * 5 % 720;
  const hour = Math.floor(minutes / 60);
  return (hour || 12) + ":" + String(minutes % 60).padStart(2, "0");
}
const thetaOfClock = (hour) => ((D.crown_theta_deg + (hour % 12) * 30) % 360 + 360) % 360;
const screenOf = (x, y) => mosaic().imageToViewerElementCoordinates(new OSD.Point(x, y));
const fmtZ = (z) => Math.abs(z) >= 1000 ? (z / 1000).toFixed(3) + " m" : z.toFixed(1) + " mm";

// --- distances on the wall: mm_per_px along the pipe, the circumferential scale around it
function wallDelta(a, b) {
  let dr = b.row - a.row;
  if (dr > G.n_rows / 2) dr -= G.n_rows;
  if (dr < -G.n_rows / 2) dr += G.n_rows;
  const dz = (b.col - a.col) * G.mm_per_px, ds = dr * G.mm_per_px_circumferential;
  return { dz, ds, d: Math.hypot(dz, ds) };
}
function polygonArea(points) {
  let s = 0, prev = { x: 0, y: 0 };
  const xy = points.map((p, k) => {
    if (k === 0) return prev;
    const step = wallDelta(points[k - 1], p);
    prev = { x: prev.x + step.dz, y: prev.y + step.ds };
    return prev;
  });
  xy.forEach((p, k) => { const q = xy[(k + 1) % xy.length]; s += p.x * q.y - q.x * p.y; });
  return Math.abs(s) / 2;
}
function readout() {
  const r = state.ruler, a = state.area, out = $("ruler-readout");
  const api = window.pipestitchReview;
  if (state.tool === "ruler" && r.length === 2) {
    const d = wallDelta(r[0], r[1]);
    api.distanceMm = d.d;
    out.textContent = "distance " + d.d.toFixed(2) + " mm (along " + Math.abs(d.dz).toFixed(2) +
      ", around " + Math.abs(d.ds).toFixed(2) + ")";
  } else if (state.tool === "area" && a.length >= 3) {
    api.areaMm2 = polygonArea(a);
    out.textContent = "area " + api.areaMm2.toFixed(1) + " mm\u00b2 (" + a.length + " points)";
  } else {
    out.textContent = state.tool === "frames" ? "" : "click points on the wall";
  }
}

// --- overlays: defects (ellipses at their centroid) and observations (clock bands)
function overlay(el, x, y, w, h) {
  viewer.addOverlay({ element: el, location: mosaic().imageToViewportRectangle(x, y, w, h) });
}
function tagged(className, id, tag, title) {
  const el = document.createElement("div");
  el.className = className;
  el.id = id;
  el.title = title;
  const t = document.createElement("span");
  t.className = "tag";
  t.textContent = tag;
  el.appendChild(t);
  return el;
}
function defectSize(d) {
  const w = Math.max(d.diameter_mm, d.z_max_mm - d.z_min_mm) / G.mm_per_px;
  const h = Math.max(d.diameter_mm / G.mm_per_px_circumferential,
                     (d.theta_max_deg - d.theta_min_deg) / G.deg_per_px);
  return { w: 1.4 * w + 6, h: 1.4 * h + 6 };
}
function drawDefects() {
  D.defects.forEach((d, k) => {
    const c = imagePoint(d.z_mm, d.theta_deg), s = defectSize(d);
    const el = tagged("defect " + d.kind, "defect-" + (k + 1), "D" + (k + 1) + " " + d.kind +
      " \u2300" + d.diameter_mm.toFixed(1), d.kind + " at " + fmtZ(d.z_mm) + ", " + d.clock);
    overlay(el, c.x - s.w / 2, c.y - s.h / 2, s.w, s.h);
  });
}
// An observation is placed at the mosaic position its ref names ("... z=19.8mm
// theta=153.8deg ...", as coded from a defect), else at its distance (to 0.01 m).
const REF_AT = /z=(-?[0-9.]+)mm theta=([0-9.]+)deg/;
function obsZ(o) {
  const at = REF_AT.exec(o.ref);
  return at ? parseFloat(at[1]) : D.start_z_mm + 1000 * o.distance_m;
}
function obsRows(o) {          // [row0, row1] ranges of its clock band, split at the seam
  if (o.clock_from === null) return [[0, G.n_rows]];
  const a = rowOf(thetaOfClock(o.clock_from) - 15);
  const span = o.clock_to === null ? 30 : ((o.clock_to - o.clock_from + 12) % 12) * 30 + 30;
  const b = a + span / G.deg_per_px;
  return b <= G.n_rows ? [[a, b]] : [[a, G.n_rows], [0, b - G.n_rows]];
}
function drawObservations() {
  document.querySelectorAll(".obs").forEach((el) => viewer.removeOverlay(el));
  state.observations.forEach((o) => {
    const x = colOf(obsZ(o)) + 0.5, w = Math.max(3 / G.mm_per_px, 8);
    obsRows(o).forEach(([r0, r1], part) => {
      const el = tagged("obs", "obs-" + o.index + (part ? "-" + part : ""),
        part ? "" : o.code + (o.char1 || "") + (o.char2 || ""), o.code + " " + o.remark);
      overlay(el, x - w / 2, r0, w, r1 - r0);
    });
  });
}

// --- axes: z along the bottom (mm or m), clock on the left, theta on the right
function niceStep(span, pixels, minGap) {
  const raw = span * minGap / Math.max(pixels, 1);
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw);
}
function drawAxes() {
  const canvas = $("axes"), box = canvas.getBoundingClientRect();
  canvas.width = box.width;
  canvas.height = box.height;
  const g = canvas.getContext("2d"), item = mosaic();
  if (!item) return;
  g.font = "11px system-ui, sans-serif";
  const b = item.viewerElementToImageCoordinates(new OSD.Point(0, 0));
  const e = item.viewerElementToImageCoordinates(new OSD.Point(box.width, box.height));
  zTicks(g, b, e, box);
  clockTicks(g, box);
  drawMeasure(g);
}
function zTicks(g, b, e, box) {
  const z0 = G.z0_mm + (b.x - 0.5) * G.mm_per_px, z1 = G.z0_mm + (e.x - 0.5) * G.mm_per_px;
  const step = niceStep(z1 - z0, box.width, 90);
  g.fillStyle = "rgba(0,0,0,.6)";
  g.fillRect(0, box.height - 18, box.width, 18);
  g.fillStyle = "#fff";
  g.strokeStyle = "#fff";
  for (let z = Math.ceil(z0 / step) * step; z <= z1; z += step) {
    const x = screenOf(colOf(z) + 0.5, 0).x;
    g.beginPath(); g.moveTo(x, box.height - 18); g.lineTo(x, box.height - 12); g.stroke();
    const label = step >= 100 ? (z / 1000).toFixed(step >= 1000 ? 0 : 1) + " m"
      : z.toFixed(step < 1 ? 1 : 0) + " mm";
    g.fillText(label, x + 2, box.height - 3);
  }
}
function clockTicks(g, box) {
  g.fillStyle = "rgba(0,0,0,.6)";
  g.fillRect(0, 0, 44, box.height - 18);
  for (let h = 1; h <= 12; h++) {
    const y = screenOf(0, rowOf(thetaOfClock(h)) + 0.5).y;
    if (y < 0 || y > box.height - 18) continue;
    g.fillStyle = "#9cf";
    g.fillText(h + " h", 4, y + 4);
    if (h % 3 === 0) {
      g.strokeStyle = "rgba(80,160,255,.55)";
      g.setLineDash([3, 5]);
      g.beginPath(); g.moveTo(44, y); g.lineTo(box.width, y); g.stroke();
      g.setLineDash([]);
    }
  }
}
function drawMeasure(g) {
  const pts = state.tool === "ruler" ? state.ruler : state.tool === "area" ? state.area : [];
  if (!pts.length) return;
  g.strokeStyle = "#ff0";
  g.fillStyle = "#ff0";
  g.lineWidth = 1.5;
  g.beginPath();
  pts.forEach((p, k) => {
    const s = screenOf(p.col + 0.5, p.row + 0.5);
    if (k) g.lineTo(s.x, s.y); else g.moveTo(s.x, s.y);
    g.fillRect(s.x - 2, s.y - 2, 4, 4);
  });
  if (state.tool === "area" && pts.length > 2) g.closePath();
  g.stroke();
  g.lineWidth = 1;
}

// --- profile and pose tracks, x aligned with the mosaic's z
const TRACKS = [
  { title: "diameter (mm)", src: "profile", keys: ["diameter_mm"], nominal: true },
  { title: "tilt (\u00b0)", src: "poses", keys: ["alpha_deg", "beta_deg"] },
  { title: "offset (mm)", src: "poses", keys: ["dx_mm", "dy_mm"] }];
const COLOURS = ["#6cf", "#fc6"];
function drawTracks() {
  const canvas = $("tracks"), width = canvas.getBoundingClientRect().width;
  canvas.width = width;
  const g = canvas.getContext("2d"), h = canvas.height / TRACKS.length;
  g.clearRect(0, 0, width, canvas.height);
  g.font = "11px system-ui, sans-serif";
  if (!mosaic()) return;
  TRACKS.forEach((t, k) => drawTrack(g, t, k * h, h, width));
}
function trackRange(t) {
  const s = D[t.src], values = [];
  t.keys.forEach((key) => (s[key] || []).forEach((v) => { if (v !== null) values.push(v); }));
  if (t.nominal) values.push(D.nominal_diameter_mm);
  if (!values.length) return null;
  const lo = Math.min(...values), hi = Math.max(...values), pad = (hi - lo) * 0.1 || 0.5;
  return [lo - pad, hi + pad];
}
function drawTrack(g, t, top, h, width) {
  const s = D[t.src], range = trackRange(t);
  g.strokeStyle = "#333";
  g.strokeRect(0, top, width, h);
  g.fillStyle = "#aaa";
  g.fillText(t.title + (t.src === "poses" ? " at the camera's z" : " at the ring's z"), 48, top + 12);
  if (!range) return;
  const y = (v) => top + h - 4 - (v - range[0]) / (range[1] - range[0]) * (h - 16);
  g.fillText(range[1].toPrecision(4), 2, top + 12);
  g.fillText(range[0].toPrecision(4), 2, top + h - 4);
  if (t.nominal) {
    g.strokeStyle = "#777"; g.setLineDash([4, 4]);
    g.beginPath(); g.moveTo(0, y(D.nominal_diameter_mm)); g.lineTo(width, y(D.nominal_diameter_mm));
    g.stroke(); g.setLineDash([]);
  }
  t.keys.forEach((key, c) => {
    g.strokeStyle = COLOURS[c];
    g.beginPath();
    let pen = false;
    (s.z_mm || []).forEach((z, i) => {
      const v = s[key][i];
      if (v === null || z === null) { pen = false; return; }
      const x = screenOf(colOf(z) + 0.5, 0).x;
      if (pen) g.lineTo(x, y(v)); else g.moveTo(x, y(v));
      pen = true;
    });
    g.stroke();
    g.fillStyle = COLOURS[c];
    g.fillText(key, width - 120 + 60 * c, top + 12);
  });
}
function redraw() { drawAxes(); drawTracks(); }

// --- lists beside the view
function cell(row, text) { const td = document.createElement("td"); td.textContent = text; row.appendChild(td); return td; }
function table(headers) {
  const t = document.createElement("table"), head = t.createTHead().insertRow();
  headers.forEach((h) => { const th = document.createElement("th"); th.textContent = h; head.appendChild(th); });
  return t;
}
function zoomTo(z, theta, sizeMm) {
  const c = imagePoint(z, theta), w = Math.max(4 * sizeMm, 12) / G.mm_per_px;
  viewer.viewport.fitBounds(mosaic().imageToViewportRectangle(c.x - w / 2, c.y - w / 2, w, w));
}
function listDefects() {
  const box = $("defect-list");
  if (!D.defects.length) { box.textContent = "No defects found."; return; }
  const t = table(["id", "kind", "z", "clock", "\u2300 mm", "area mm\u00b2"]);
  D.defects.forEach((d, k) => {
    const r = t.insertRow();
    r.className = "pick";
    r.id = "defect-row-" + (k + 1);
    [`D${k + 1}`, d.kind, fmtZ(d.z_mm), d.clock, d.diameter_mm.toFixed(2), d.area_mm2.toFixed(1)]
      .forEach((v) => cell(r, v));
    r.onclick = () => zoomTo(d.z_mm, d.theta_deg, d.diameter_mm);
  });
  box.replaceChildren(t);
}
const q = (v) => (v === null || v === undefined ? "" : String(v));
function listObservations() {
  const box = $("obs-list"), obs = state.observations;
  if (!obs.length) { box.textContent = "No observations."; return; }
  const t = table(["m", "code", "quant.", "clock", "remark", ""]);
  obs.forEach((o) => {
    const r = t.insertRow();
    r.className = "pick";
    r.id = "obs-row-" + o.index;
    [o.distance_m.toFixed(2), o.code + " " + o.char1 + o.char2, [q(o.quant1), q(o.quant2)].filter(Boolean).join(" / "),
     o.clock_from === null ? "" : q(o.clock_from) + (o.clock_to === null ? "" : "\u2013" + o.clock_to),
     o.remark].forEach((v) => cell(r, v));
    const tools = cell(r, "");
    if (served) {
      tools.append(button("edit", () => openForm(o)), button("delete", () => removeObservation(o)));
    }
    r.onclick = () => zoomTo(obsZ(o), o.clock_from === null ? 180 : thetaOfClock(o.clock_from), 20);
  });
  box.replaceChildren(t);
}
function button(text, action) {
  const b = document.createElement("button");
  b.textContent = text;
  b.onclick = (ev) => { ev.stopPropagation(); action(); };
  return b;
}

// --- editing observations (served only): the server validates and writes observations.csv
const FIELDS = ["distance_m", "code", "char1", "char2", "quant1", "quant2", "clock_from",
  "clock_to", "continuous", "ref", "remark"];
function openForm(o) {
  const form = $("obs-form");
  state.editing = o ? o.index : null;
  $("obs-form-title").textContent = o ? "Edit observation (row " + (o.index + 1) + ")" : "New observation";
  FIELDS.forEach((f) => { form.elements[f].value = o ? q(o[f]) : ""; });
  // a generated row's ref names the row its edit supersedes: the server keeps it
  form.elements.ref.readOnly = Boolean(o) && /^(auto|reviewed):/.test(o.ref);
  form.elements.ref.title = form.elements.ref.readOnly
    ? "kept: it names the generated row this edit replaces on re-coding" : "";
  if (!o && state.last) {
    form.elements.distance_m.value = Math.max(0, (state.last.z - D.start_z_mm) / 1000).toFixed(2);
    form.elements.clock_from.value = clockText(state.last.theta).split(":")[0];
    form.elements.ref.value = "review: z=" + state.last.z.toFixed(1) + "mm theta=" + state.last.theta.toFixed(1) + "deg";
  }
  $("obs-error").textContent = "";
  form.hidden = false;
}
async function send(method, path, body) {
  const response = await fetch(path, { method, headers: { "Content-Type": "application/json" },
    body: JSON.stringify(Object.assign({ version: state.version }, body || {})) });
  const answer = await response.json();
  if (!response.ok) throw new Error(answer.error || response.statusText);
  state.observations = answer.observations;
  state.version = answer.version;
  listObservations();
  drawObservations();
  return answer;
}
async function saveForm(ev) {
  ev.preventDefault();
  const form = $("obs-form"), fields = {};
  FIELDS.forEach((f) => { fields[f] = form.elements[f].value; });
  const path = "api/observations" + (state.editing === null ? "" : "/" + state.editing);
  try {
    await send(state.editing === null ? "POST" : "PUT", path, { fields });
    form.hidden = true;
  } catch (err) { $("obs-error").textContent = err.message; }
}
async function removeObservation(o) {
  if (!window.confirm("Delete the observation " + o.code + " at " + o.distance_m + " m?")) return;
  try { await send("DELETE", "api/observations/" + o.index); }
  catch (err) { $("obs-note").textContent = err.message; }
}

// --- source frames: the frames whose window covers the point, with their pose
function framesAt(w) {
  const P = D.poses, out = [];
  (P.z_mm || []).forEach((z, i) => {
    if (z !== null && z + D.window_mm[0] <= w.z && w.z <= z + D.window_mm[1]) out.push(i);
  });
  const mid = (D.window_mm[0] + D.window_mm[1]) / 2;
  return out.sort((a, b) => Math.abs(P.z_mm[a] + mid - w.z) - Math.abs(P.z_mm[b] + mid - w.z)).slice(0, 4);
}
function showFrames(w) {
  const box = $("frames"), P = D.poses, found = framesAt(w);
  box.replaceChildren();
  const head = document.createElement("div");
  head.textContent = "point z " + fmtZ(w.z) + ", \u03b8 " + w.theta.toFixed(1) + "\u00b0, clock " +
    clockText(w.theta) + ": " + (found.length ? found.length + " nearest frames" : "no frame saw it");
  box.appendChild(head);
  found.forEach((i) => {
    const div = document.createElement("div");
    div.className = "frame";
    const f = P.frame[i], num = String(f).padStart(5, "0");
    const v = (k, n) => (P[k][i] === null ? "nan" : P[k][i].toFixed(n));
    div.textContent = `frame ${num}: z ${v("z_mm", 1)} mm, roll ${v("roll_deg", 2)}\u00b0, ` +
      `\u03b1 ${v("alpha_deg", 3)}\u00b0, \u03b2 ${v("beta_deg", 3)}\u00b0, ` +
      `\u0394x ${v("dx_mm", 3)} mm, \u0394y ${v("dy_mm", 3)} mm`;
    if (served && D.frames_url) {
      const img = document.createElement("img");
      img.alt = "LED frame " + num + " with its laser ring";
      img.src = `${D.frames_url}?frame=${f}&z=${w.z.toFixed(3)}&theta=${w.theta.toFixed(3)}`;
      div.appendChild(img);
    }
    box.appendChild(div);
  });
  if (!(served && D.frames_url)) {
    const n = document.createElement("div");
    n.className = "note";
    n.textContent = "The frame images are shown when the page is served by `pipestitch review` " +
      "and the dataset is where the run recorded it.";
    box.appendChild(n);
  }
}

// --- pointer, clicks and tools
function onClick(ev) {
  if (!ev.quick) return;
  ev.preventDefaultAction = true;
  const w = wallAt(mosaic().viewerElementToImageCoordinates(ev.position));
  state.last = w;
  if (state.tool === "ruler") {
    state.ruler = state.ruler.length >= 2 ? [w] : state.ruler.concat([w]);
  } else if (state.tool === "area") {
    state.area = state.area.concat([w]);
  } else {
    showFrames(w);
  }
  readout();
  drawAxes();
}
function onMove(ev) {
  const item = mosaic();
  if (!item) return;
  const w = wallAt(item.viewerElementToImageCoordinates(ev.position));
  $("where").textContent = "z " + fmtZ(w.z) + ", \u03b8 " + (((w.theta % 360) + 360) % 360).toFixed(1) +
    "\u00b0, clock " + clockText(w.theta) + " (col " + Math.round(w.col) + ", row " + Math.round(w.row) + ")";
}
function setTool(tool) {
  state.tool = tool;
  if (tool === "area") state.area = [];
  readout();
  drawAxes();
}
function addNoData() {
  if (!D.nodata) return;
  viewer.addTiledImage({ tileSource: { type: "image", url: D.nodata }, x: 0, y: 0, width: 1,
    opacity: 0.45, index: 1 });
  $("show-nodata").onchange = (ev) => {
    const layer = viewer.world.getItemAt(1);
    if (layer) layer.setOpacity(ev.target.checked ? 0.45 : 0);
  };
}
function setup() {
  $("zoom-in").onclick = () => viewer.viewport.zoomBy(2);
  $("zoom-out").onclick = () => viewer.viewport.zoomBy(0.5);
  $("home").onclick = () => viewer.viewport.goHome();
  $("full").onclick = () => viewer.viewport.zoomTo(mosaic().imageToViewportZoom(1));
  document.querySelectorAll("input[name=tool]").forEach((r) => { r.onchange = () => setTool(r.value); });
  $("obs-form").onsubmit = saveForm;
  $("obs-cancel").onclick = () => { $("obs-form").hidden = true; };
  $("obs-add").onclick = () => openForm(null);
  $("obs-add").hidden = !served;
  $("mode").textContent = served ? "editing: saved to observations.csv"
    : "read-only (run `pipestitch review OUT` to edit)";
  $("obs-note").textContent = "Distance from the first wall seen; 12 o'clock = crown at mosaic \u03b8 " +
    D.crown_theta_deg.toFixed(1) + "\u00b0 (" + D.reference + "). Re-coding regenerates the auto: rows," +
    " except those edited here (kept as reviewed:) or deleted here.";
  Object.entries(D.codes).forEach(([code, name]) => {
    const o = document.createElement("option"); o.value = code; o.label = code + " " + name;
    $("codes").appendChild(o);
  });
  viewer.addHandler("canvas-click", onClick);
  viewer.addHandler("update-viewport", redraw);
  new OSD.MouseTracker({ element: viewer.container, moveHandler: onMove });
  window.addEventListener("resize", redraw);
  listDefects();
  listObservations();
}
viewer.addOnceHandler("open", () => { drawDefects(); drawObservations(); addNoData(); redraw(); });
window.pipestitchReview = { viewer, data: D, state, wallDelta, polygonArea, framesAt,
  distanceMm: null, areaMm2: null };
setup();
})();
