// bulgekit studio: the page. Everything it shows comes from the local server (server.py), which
// runs the toolkit: this file only keeps the design, draws it and sends it back.
//
// The design is the placement file as JSON (design.py): items with their place on the unrolled
// wall (u along the wall, v up, mm) and the [bulges] settings. Each edit asks for a preview
// (strokes per item, the map's points, messages); when edits pause, one more preview runs the
// G-code through the reference planner to find points no move stops at.
import * as THREE from "three";
import { OrbitControls } from "/static/vendor/OrbitControls.js";

const TOKEN = document.querySelector('meta[name="studio-token"]').content;
const $ = (id) => document.getElementById(id);

const S = {                 // the page's state
  gcode: null,              // server's gcode state: walls, layers ...
  fonts: [],
  printers: [],             // the printer models' presets (server: printer_choices)
  limits: {},
  items: [],                // design items (+ label, assetKind: page only)
  selected: null,           // item id
  preview: null,            // last preview answer
  strokesAt: {},            // id -> the item's geometry when its strokes were computed
  exportKey: null,
  nextId: 1,
  busy: false,
};

// ---------------------------------------------------------------- server calls

async function api(path, opts = {}) {
  const r = await fetch(path, { ...opts, headers: { "X-Studio-Token": TOKEN, ...(opts.headers || {}) } });
  let body = null;
  const text = await r.text();
  try { body = JSON.parse(text); } catch { body = { error: text || r.statusText }; }
  if (!r.ok) throw new Error(body.error || `${r.status} ${r.statusText}`);
  return body;
}

const postJSON = (path, obj) => api(path, { method: "POST", body: JSON.stringify(obj),
  headers: { "Content-Type": "application/json" } });

// Upload a File with a progress callback (fetch has no upload progress).
function upload(path, file, onProgress) {
  return new Promise((resolve, reject) => {
    const x = new XMLHttpRequest();
    x.open("POST", `${path}?name=${encodeURIComponent(file.name)}`);
    x.setRequestHeader("X-Studio-Token", TOKEN);
    x.upload.onprogress = (e) => e.lengthComputable && onProgress(e.loaded, e.total);
    x.onload = () => {
      let b; try { b = JSON.parse(x.responseText); } catch { b = { error: x.responseText || x.statusText }; }
      x.status >= 200 && x.status < 300 ? resolve(b) : reject(new Error(b.error || x.statusText));
    };
    x.onerror = () => reject(new Error("the studio server did not answer (is it still running?)"));
    x.send(file);
  });
}

async function pollJob(job, onUpdate) {
  for (;;) {
    if (onUpdate) onUpdate(job);
    if (job.state === "done") return job.result;
    if (job.state === "error") throw new Error(job.error);
    await new Promise((r) => setTimeout(r, 200));
    job = await api(`/api/job/${job.id}`);
  }
}

function status(text, frac) {
  $("status-text").textContent = text;
  const bar = $("status-bar");
  bar.hidden = frac === undefined || frac === null;
  if (!bar.hidden) bar.value = Math.max(0, Math.min(1, frac));
}

function showError(id, err) {
  const el = $(id);
  el.hidden = !err;
  el.textContent = err ? String(err.message || err) : "";
}

const round2 = (x) => Math.round(x * 100) / 100;     // what a drag makes: 0.01 mm
const fileUrl = (u) => `${u}?t=${encodeURIComponent(TOKEN)}`;     // served as attachments

// ---------------------------------------------------------------- G-code

async function openGcode(file) {
  showError("gcode-error", null);
  const mb = file.size / 1e6;
  if (S.limits.gcode_mb && mb > S.limits.gcode_mb) {
    showError("gcode-error", `${file.name}: ${mb.toFixed(1)} MB is more than the studio takes for G-code ` +
      `(${S.limits.gcode_mb} MB; start it with a larger --max-upload)`);
    return;
  }
  try {
    const job = await upload("/api/gcode", file, (a, b) => status(`uploading ${file.name}: ${Math.round(100 * a / b)} %`, a / b));
    const res = await pollJob(job, (j) => j.total ? status(`${file.name}: ${j.label} ${Math.round(100 * j.done / j.total)} %`, j.done / j.total)
      : status(`${file.name}: ${j.label || "reading"}…`, 0));
    if (S.gcode && S.items.length && S.gcode.name !== res.name && !keepDesignFor(S.gcode.name, res.name)) {
      flushHistory();                           // Undo brings the design back
      S.items = [];
      select(null);
    }
    setGcode(res);
    status(`${res.name}: ${res.layers} layers of outer wall`);
  } catch (e) {
    showError("gcode-error", e);
    status(S.gcode ? `${S.gcode.name} stays open` : "Open a sliced G-code to start.");
  }
}

// A design made on one G-code is laid on another only when the user says so.
function keepDesignFor(from, to, n = S.items.length) {
  return window.confirm(`${to} is another G-code than ${from}.\n\nKeep the design made on ${from} ` +
    `(${n} item${n === 1 ? "" : "s"}) and lay it on ${to}?\n\nOK keeps it; Cancel starts with an empty wall.`);
}

function setGcode(g, keepSettings = false) {
  S.gcode = g;
  const w = g.walls;
  $("gcode-info").textContent = `${g.name}\n${g.layers} layers, z ${w.v_range[0].toFixed(2)}–${w.v_range[1].toFixed(2)} mm, ` +
    `wall up to ${g.length_max.toFixed(1)} mm around` + (g.geometric ? "\nno outer-wall comments: geometric mode" : "");
  for (const id of ["add-text", "add-braille", "add-file", "open-placement", "export", "placement"]) $(id).disabled = false;
  if (!keepSettings) $("bulge-form").geometric.value = g.geometric ? "true" : "false";
  for (const it of S.items) clampItem(it);
  view2d.fit();
  view3d.setWalls(w);
  requestPreview();
  flushHistory();
}

// ---------------------------------------------------------------- items

function itemName(it) {
  if (it.kind === "text" || it.kind === "braille")
    return `${it.kind === "text" ? "Text" : "Braille"} “${it.text.replace(/\n/g, " ").slice(0, 24)}”`;
  return `${it.assetKind === "image" ? "Picture" : "Drawing"} ${it.asset}`;
}

function clampItem(it) {
  if (!S.gcode) return;
  const [lo, hi] = S.gcode.walls.v_range;
  it.at[1] = Math.min(Math.max(it.at[1], lo), hi);
}

// The face of the wall under the middle of the unrolled view at height v (the faces of the run of
// layers holding v: wall_marks' runs), and that middle's u; face null on a wall without corners.
function faceInView(v) {
  const m = S.gcode.walls.marks, L = S.gcode.length_max;
  const [a, b] = view2d.uInView();
  const u = Math.min(Math.max((a + b) / 2, 0), L);
  const run = m && (m.runs.find(([v0, v1]) => v >= v0 && v <= v1) || m.runs.at(-1));
  if (!run || run[2].length < 2) return { face: null, u };
  const f = run[2].find(([, u0, u1]) => (u >= u0 && u < u1) || (u - L >= u0 && u - L < u1)) || run[2][0];
  return { face: f[0], u: (f[1] + f[2]) / 2 };
}

// Braille's size is the standard's (bulge/braille.py): a cell's dots span 5 mm up from `at` (its
// bottom dots), a cell takes 6 mm along the wall; "hello" in grade 1 is 5 cells.
const BRAILLE_CELL_HEIGHT = 5, BRAILLE_CELL_PITCH = 6, BRAILLE_DOT = 1.5;

// A text or braille item (kind), centred on the face in view (the server aligns it: face,
// align), or on the view's middle when the wall has no corners (placeNew centres it there once
// its strokes are in).
function addItem(kind) {
  flushHistory();
  const [lo, hi] = S.gcode.walls.v_range;
  const braille = kind === "braille";
  // a capital is about as wide as it is tall: the box "TEXT" will take, until its strokes are in
  const size = braille ? BRAILLE_CELL_HEIGHT : round2(Math.max(1, Math.min(6, (hi - lo) / 3)));
  const w = braille ? 5 * BRAILLE_CELL_PITCH : 4 * size;
  const v = +(lo + Math.max(braille ? BRAILLE_DOT : 0, (hi - lo - size) / 2)).toFixed(2);
  const { face, u } = faceInView(v + size / 2);
  const it = braille ? { id: `i${S.nextId++}`, kind, text: "hello", grade: 1 }
    : { id: `i${S.nextId++}`, kind, text: "TEXT", font: "futural", size, letter_spacing: 0, mirror: false, rotate: 0 };
  it.at = [face ? 0 : round2(u - w / 2), v];
  if (face) Object.assign(it, { face, align: "center" });
  else it.centreOn = u;
  placeInFreeSpace(it, w, size, u - w / 2);
  S.items.push(it);
  select(it.id);
  requestPreview();
}

// ---------------------------------------------------------------- free space for new items

// A new item goes where it touches no other and no layer gets more points than the firmware
// takes (S.limits.layer_points, 64): first by a guess at its size, then, once its first
// preview gives its strokes and points, by its real box and points (placeNew). When no such
// place is left it goes where it touches no other, or else overlaps, and the page says so.
const GAP = 3;                 // mm kept between items: about a word space at the 6 mm default
const touches = (a, b) => a.u0 < b.u1 + GAP && b.u0 < a.u1 + GAP && a.v0 < b.v1 + GAP && b.v0 < a.v1 + GAP;

// Index of the layer whose bead holds height v (as wall.layer_of_v), -1 outside the wall.
function layerOfV(v) {
  const L = S.gcode.walls.layers;
  let a = 0, b = L.length;
  while (a < b) { const m = (a + b) >> 1; if (L[m].z < v - 1e-9) a = m + 1; else b = m; }
  return a < L.length && v >= L[a].z - L[a].h - 1e-9 ? a : -1;
}

// The last preview's points per layer: the other items' (a point shared with them counts
// for them too), and `it`'s own as the heights they stand at, to count them after a move.
function layerLoad(it) {
  if (!S.preview || !S.preview.items[it.id] || !S.preview.items[it.id].strokes.length) return null;
  const L = S.gcode.walls.layers, at = new Map(L.map((l, i) => [l.z.toFixed(3), i]));
  const others = new Array(L.length).fill(0), mine = [];
  for (const q of S.preview.points) {
    const i = at.get(q[4].toFixed(3));
    if (i === undefined) continue;
    if (q[6].some((id) => id !== it.id)) others[i]++;
    if (q[6].includes(it.id)) mine.push(q[1]);
  }
  return { others, mine };
}

// Whether `it`'s points, moved dv mm up, keep every layer within the limit. A move by whole
// layers (the rows freeSpot tries) carries each layer's points to another one unchanged.
function fitsAfter(load, dv) {
  const most = S.limits.layer_points || 64, n = new Map();
  for (const v of load.mine) {
    const i = layerOfV(v + dv);
    if (i >= 0) n.set(i, (n.get(i) || 0) + 1);
  }
  for (const [i, k] of n) if (load.others[i] + k > most) return false;
  return true;
}

// The lower-left corner of the first free w x h mm on the wall whose rows `fits` accepts:
// along the row at v, then the rows above and below it in turn (a layer apart), each from
// u = 0; null when there is none.
function freeSpot(w, h, v, others, fits = () => true) {
  const [lo, hi] = S.gcode.walls.v_range, len = S.gcode.length_max, L = S.gcode.walls.layers;
  const step = L.length > 1 ? Math.max(0.05, (L.at(-1).z - L[0].z) / (L.length - 1)) : 0.5;
  const rows = [Math.min(Math.max(v, lo), hi - h)];
  for (let d = step; rows[0] - d >= lo || rows[0] + d + h <= hi; d += step) {
    if (rows[0] + d + h <= hi) rows.push(rows[0] + d);
    if (rows[0] - d >= lo) rows.push(rows[0] - d);
  }
  for (const v0 of rows) {
    if (!fits(v0)) continue;
    for (let u0 = 0; u0 + w <= len; u0 += 0.5) {
      const b = { u0, v0, u1: u0 + w, v1: v0 + h };
      if (!others.some((o) => touches(b, o))) return [u0, v0];
    }
  }
  return null;
}

// Move `it`, whose strokes span `box` (a guess or its real one), out of the others' way and,
// given its points (layerLoad), off layers it would take over the limit; the offset between
// its anchor (`at`) and its box stays. Returns "ok", "over" (placed where it touches no other,
// but some layer is over the limit) or "full" (no place touches no other).
function moveToFreeSpace(it, box, load = null) {
  const others = S.items.filter((o) => o !== it).map(itemBox);
  const fits = (v0) => !load || fitsAfter(load, v0 - box.v0);
  const free = !others.some((o) => touches(box, o));
  if (free && fits(box.v0)) return "ok";
  let spot = freeSpot(box.u1 - box.u0, box.v1 - box.v0, box.v0, others, fits), how = "ok";
  if (!spot) {
    if (free) return "over";               // as good a place as any other: it stays
    spot = freeSpot(box.u1 - box.u0, box.v1 - box.v0, box.v0, others);
    how = "over";
  }
  if (!spot) return "full";
  it.at = [round2(it.at[0] + spot[0] - box.u0), round2(it.at[1] + spot[1] - box.v0)];
  return load && how === "over" ? "over" : "ok";
}

// (u0: where its box starts, when `at` is not that: an item aligned on a face)
function placeInFreeSpace(it, w, h, u0 = it.at[0]) {
  it.placing = true;                             // placeNew looks again with its real box
  moveToFreeSpace(it, { u0, v0: it.at[1], u1: u0 + w, v1: it.at[1] + h });
}

// The items whose strokes' boxes cross this one's (both drawn already).
function overlapping(it) {
  const drawn = (x) => S.preview && S.preview.items[x.id] && S.preview.items[x.id].strokes.length;
  if (!drawn(it)) return [];
  const a = itemBox(it);
  return S.items.filter((o) => o !== it && drawn(o)).filter((o) => {
    const b = itemBox(o);
    return a.u0 < b.u1 && b.u0 < a.u1 && a.v0 < b.v1 && b.v0 < a.v1;
  });
}

// Returns whether it moved (a new preview is then on its way).
function placeNew(it) {
  delete it.placing;
  const was = String(it.at);
  if (it.centreOn !== undefined) {              // its middle where it was asked for
    const b = itemBox(it);
    it.at = [round2(it.at[0] + it.centreOn - (b.u0 + b.u1) / 2), it.at[1]];
    delete it.centreOn;
  }
  const how = moveToFreeSpace(it, itemBox(it), layerLoad(it));
  if (how === "full")                           // the list says which item it overlaps
    status(`no free space on the wall for ${itemName(it)}: it overlaps another item (move, shrink or delete one)`);
  else if (how === "over")                      // the list says which layers, beside the items
    status(`no free place on the wall keeps every layer within ${S.limits.layer_points || 64} points with ` +
      `${itemName(it)}: it is placed anyway, and layers over the limit get no bumps (move, shrink or delete an item, or increase Spacing)`);
  if (String(it.at) === was) return false;
  if (it.id === S.selected) fillItemForm(it);
  requestPreview();
  return true;
}

// Upload a drawing or picture; a refusal is shown in the element errId.
async function addFile(file, errId = "asset-error") {
  showError(errId, null);
  if (S.limits.asset_mb && file.size > S.limits.asset_mb * 1e6) {
    showError(errId, `${file.name}: ${(file.size / 1e6).toFixed(1)} MB is more than the studio takes for a drawing or picture (${S.limits.asset_mb} MB)`);
    return null;
  }
  try {
    const info = await upload("/api/asset", file, (a, b) => status(`uploading ${file.name}: ${Math.round(100 * a / b)} %`, a / b));
    status(`${info.name} loaded`);
    return info;
  } catch (e) {
    showError(errId, e);
    status(S.gcode ? `${S.gcode.name}` : "");
    return null;
  }
}

async function addDrawing(file) {
  const info = await addFile(file);
  if (!info) return;
  flushHistory();
  const [lo, hi] = S.gcode.walls.v_range;
  const it = { id: `i${S.nextId++}`, kind: "file", asset: info.name, assetKind: info.kind,
    at: [5, +(lo + 0.5).toFixed(2)], scale: 1, rotate: 0 };
  if (info.kind === "image") {
    it.image_width = round2(Math.min(20, Math.max(5, S.gcode.length_max / 4)));
    delete it.scale;
  }
  placeInFreeSpace(it, it.image_width || 10, it.image_width || 10);
  S.items.push(it);
  select(it.id);
  requestPreview();
}

// A placement file (and the drawing files it names, chosen with it) replaces the design: the
// server checks it as `bulgekit build --placement` would and hands back the items.
const BULGE_DEFAULTS = { dwell: 100, extra: 0.1, tolerance: 0.25, spacing: "", line_width: 0.45,
  geometric: false, fallback: false, stop: "move", e_steps: "", stop_e_steps: "", firmware: "" };
const DEFAULT_PRINTER = "marlin";      // what no `printer` key means (bulgekit.machine.DEFAULT)

async function openPlacement(list) {
  showError("asset-error", null);
  const files = [...list];
  const toml = files.filter((f) => /\.toml$/i.test(f.name));
  if (toml.length !== 1) {
    showError("asset-error", "choose one placement file (.toml), together with the drawing files it names");
    return;
  }
  const names = {}, kinds = {};
  for (const f of files) {
    if (f === toml[0]) continue;
    const info = await addFile(f);
    if (!info) return;
    names[f.name] = info.name; kinds[info.name] = info.kind;
  }
  try {
    const d = await postJSON("/api/import", { toml: await toml[0].text(), files: names });
    flushHistory();
    S.items = d.items.map((it) => it.kind === "text"
      ? { size: 6, font: "futural", letter_spacing: 0, mirror: false, rotate: 0, at: [0, 1], ...it, id: `i${S.nextId++}` }
      : it.kind === "braille" ? { at: [0, 1], ...it, id: `i${S.nextId++}` }
      // (the placement file's default at: 1 mm above the bed, a .json stroke list as it is)
      : { scale: 1, rotate: 0, at: /\.json$/i.test(it.asset) ? [0, 0] : [0, 1], ...it, assetKind: kinds[it.asset],
          id: `i${S.nextId++}` });
    setBulgeForm(d.bulges);
    status(`${toml[0].name}: ${S.items.length} item(s)`);
    select(S.items.length ? S.items[0].id : null);
    requestPreview();
  } catch (e) { showError("asset-error", e); }
}

function select(id) {
  S.selected = id;
  const it = S.items.find((i) => i.id === id);
  $("sec-item").hidden = !it;
  if (it) {
    itemFields(it);
    fillItemForm(it);
  }
  renderItems();
  view2d.draw();
}

// The item form shows the fields of the item's kind: an element of class for-KIND shows for
// text, braille, drawing (SVG, JSON) or image; for-table only while braille takes a table.
const kindOf = (it) => (it.kind === "file" ? (it.assetKind === "image" ? "image" : "drawing") : it.kind);

function itemFields(it) {
  for (const el of $("item-form").querySelectorAll("[class*='for-']"))
    el.hidden = !el.classList.contains(`for-${kindOf(it)}`) || (el.classList.contains("for-table") && it.table === undefined);
}

function fillItemForm(it) {
  const f = $("item-form");
  if (it.kind === "text" || it.kind === "braille")
    if (document.activeElement !== f.text) f.text.value = it.text;
  if (it.kind === "text") {
    f.font.value = it.font; f.size.value = +it.size.toFixed(2);
    f.letter_spacing.value = it.letter_spacing; f.mirror.checked = it.mirror;
  } else if (it.kind === "braille") {
    f.grade.value = it.table !== undefined ? "table" : String(it.grade || 1);
    if (document.activeElement !== f.table) f.table.value = it.table || "";
  } else if (it.assetKind === "image") f.image_width.value = +it.image_width.toFixed(2);
  else f.scale.value = +it.scale.toFixed(3);
  f.u.value = +it.at[0].toFixed(2); f.v.value = +it.at[1].toFixed(2); f.rotate.value = +(it.rotate || 0).toFixed(1);
  f.face.value = it.face || ""; f.align.value = it.align || "center"; f.align.disabled = !it.face;
  f.u.previousSibling.textContent = it.face ? "u from the aligned place, mm " : "u, mm ";
}

// Only the field edited changes: the others show rounded values, and an imported file's exact
// ones must survive an edit elsewhere.
function readItemForm(e) {
  const it = S.items.find((i) => i.id === S.selected);
  const el = e.target;
  if (!it || !el.name) return;
  const num = (dflt) => (el.value === "" || !isFinite(+el.value) ? dflt : +el.value);
  switch (el.name) {
    case "text": it.text = el.value; break;
    case "font": it.font = el.value; break;
    case "mirror": it.mirror = el.checked; break;
    case "u": it.at = [num(it.at[0]), it.at[1]]; delete it.placing; break;    // placed by hand now
    case "v": it.at = [it.at[0], num(it.at[1])]; delete it.placing; break;
    case "face":                                // on a face (u then counts from its place) or not
      if (el.value === "" || !(+el.value >= 1)) { delete it.face; delete it.align; }
      else { it.face = Math.round(+el.value); it.align = it.align || "center"; it.at = [0, it.at[1]]; }
      delete it.placing; delete it.centreOn; fillItemForm(it); break;
    case "align": if (it.face) { it.align = el.value; it.at = [0, it.at[1]]; fillItemForm(it); } break;
    case "grade":                               // braille: grade 1 or 2, or a table by name
      if (el.value === "table") { delete it.grade; it.table = it.table || ""; }
      else { it.grade = +el.value; delete it.table; }
      itemFields(it); break;
    case "table": it.table = el.value.trim(); break;
    default: it[el.name] = num(it[el.name]);      // size, letter_spacing, scale, image_width, rotate
  }
  renderItems();
  requestPreview();
}

function renderItems() {
  const ul = $("items");
  ul.textContent = "";
  const p = S.preview;
  for (const it of S.items) {
    const li = document.createElement("li");
    li.dataset.id = it.id;
    li.className = it.id === S.selected ? "selected" : "";
    const name = document.createElement("div");
    name.className = "name";
    name.textContent = itemName(it);
    li.append(name);
    const info = p && p.items[it.id];
    const n = p ? p.points.filter((q) => q[6].includes(it.id) && !q[8]).length : 0;
    const out = p ? p.points.filter((q) => q[6].includes(it.id) && q[8]).length : 0;
    const sub = document.createElement("div");
    sub.className = "info";
    sub.textContent = info ? `${n} bump${n === 1 ? "" : "s"}` + (out ? `, ${out} left out (layers over the limit)` : "") : "";
    li.append(sub);
    const over = overlapping(it);
    if (info && (info.errors.length || info.warnings.length || over.length)) {
      const m = document.createElement("ul");
      for (const e of info.errors) { const x = document.createElement("li"); x.className = "error"; x.textContent = e; m.append(x); }
      for (const w of info.warnings) { const x = document.createElement("li"); x.className = "warning"; x.textContent = w; m.append(x); }
      for (const o of over) {
        const x = document.createElement("li"); x.className = "warning overlap";
        x.textContent = `overlaps ${itemName(o)}: their bumps mix`; m.append(x);
      }
      li.append(m);
    }
    li.onclick = () => {
      select(it.id);
      if (S.preview) view3d.look(S.preview.points.filter((q) => q[6].includes(it.id)));
    };
    ul.append(li);
  }
}

// ---------------------------------------------------------------- design and preview

function bulgeSettings() {
  const f = $("bulge-form");
  const out = {};
  const n = (el) => (el.value === "" ? null : +el.value);
  if (n(f.dwell) !== null) out.dwell = Math.round(n(f.dwell));
  for (const k of ["extra", "tolerance", "spacing", "line_width"]) if (n(f[k]) !== null) out[k] = n(f[k]);
  out.geometric = f.geometric.value === "true";
  out.fallback = f.fallback.value === "true";
  // the printer and the stock file's stops (the export always writes the stock file): written
  // only when not the defaults, so a placement file without them stays as it was
  const printer = f.printer_choice.value === "file" ? f.printer_file.value.trim() : f.printer_choice.value;
  if (printer && printer !== DEFAULT_PRINTER) out.printer = printer;
  if (f.firmware.value) out.firmware = f.firmware.value;
  if (f.stop.value !== "move") out.stop = f.stop.value;
  if (n(f.e_steps) !== null) out.e_steps = n(f.e_steps);
  if (n(f.stop_e_steps) !== null) out.stop_e_steps = Math.round(n(f.stop_e_steps));
  return out;
}

function design() {
  const items = S.items.map((it) => {
    // sent as they are (an imported file's values must come back unchanged); a drag rounds
    // what it makes (round2 below)
    const o = { id: it.id, kind: it.kind, at: [...it.at] };
    if (it.kind !== "braille") o.rotate = it.rotate;          // braille is not turned
    if (it.kind === "text") Object.assign(o, { text: it.text, font: it.font, size: it.size,
      letter_spacing: it.letter_spacing, mirror: it.mirror });
    else if (it.kind === "braille") {
      o.text = it.text;
      if (it.table) o.table = it.table; else if (it.grade) o.grade = it.grade;
    } else {
      o.asset = it.asset;
      if (it.assetKind === "image") o.image_width = it.image_width; else o.scale = it.scale;
      if (it.curve_tolerance !== undefined) o.curve_tolerance = it.curve_tolerance;
    }
    if (it.face) Object.assign(o, { face: it.face, align: it.align || "center" });   // on a face
    return o;
  });
  const name = $("export-name").value.trim();
  return { name: name || (S.gcode ? S.gcode.name.replace(/\.[^.]*$/, "") : "part"), items, bulges: bulgeSettings() };
}

let inFlight = false, pending = false, checkTimer = null, checkedFor = null;

function requestPreview() {
  if (!S.gcode) return;
  pending = true;
  clearTimeout(checkTimer);
  pump();
  clearTimeout(historyTimer);
  historyTimer = setTimeout(remember, 400);
}

// ---------------------------------------------------------------- undo

// Each state the design rests in for 400 ms is kept; Ctrl+Z / Ctrl+Shift+Z (or Ctrl+Y) and the
// buttons step through them (a focused text field keeps its own undo).
const history = [], redo = [];
let historyTimer = null;
const formValues = () => Object.fromEntries([...$("bulge-form").elements].filter((e) => e.name).map((e) => [e.name, e.value]));
const snapshot = () => JSON.stringify({ items: S.items, form: formValues(), name: $("export-name").value },
  (k, v) => (k === "placing" || k === "centreOn" ? undefined : v));

function flushHistory() {        // before a discrete edit: the state it starts from is kept
  clearTimeout(historyTimer);
  remember();
}

function remember() {
  const now = snapshot();
  if (history.at(-1) === now) return;
  history.push(now);
  if (history.length > 200) history.shift();
  redo.length = 0;
  undoButtons();
}

function restore(state) {
  const d = JSON.parse(state);
  S.items = d.items;
  for (const [k, v] of Object.entries(d.form)) $("bulge-form")[k].value = v;
  printerFields();
  $("export-name").value = d.name;
  select(S.items.some((i) => i.id === S.selected) ? S.selected : null);
  requestPreview();
}

function step(back) {
  clearTimeout(historyTimer);
  remember();                                   // an edit still waiting counts first
  const from = back ? history : redo, to = back ? redo : history;
  if (back ? history.length < 2 : !redo.length) return;
  to.push(from.pop());
  restore(history.at(-1));
  clearTimeout(historyTimer);
  undoButtons();
}

function undoButtons() {
  $("undo").disabled = history.length < 2;
  $("redo").disabled = !redo.length;
}

function setBulgeForm(b) {
  const f = $("bulge-form");
  // a file without `geometric` is read the way the open G-code's walls were found
  const dflt = { ...BULGE_DEFAULTS, geometric: !!(S.gcode && S.gcode.geometric) };
  for (const [k, v] of Object.entries(dflt)) {
    const val = b[k] ?? v;
    f[k].value = typeof val === "boolean" ? String(val) : val;
  }
  const printer = b.printer ?? DEFAULT_PRINTER, preset = S.printers.some((p) => p.name === printer);
  f.printer_choice.value = preset ? printer : "file";
  f.printer_file.value = preset ? "" : printer;
  printerFields();
}

// The printer section: the stock file's fields only for stock firmware, the profile file's
// path only when one is chosen; the preset's own line and E steps as hints; the send button
// says which file it sends.
function printerFields() {
  const f = $("bulge-form"), stock = f.fallback.value === "true", file = f.printer_choice.value === "file";
  for (const el of $("sec-printer").querySelectorAll(".for-stock")) el.hidden = !stock || (el.classList.contains("for-file") && !file);
  const p = S.printers.find((x) => x.name === f.printer_choice.value);
  $("printer-describe").textContent = p ? p.describe : "";
  f.e_steps.placeholder = p ? `the model's: ${+p.e_steps.toFixed(2)}` : "the model's";
  $("send-what").textContent = `the file for ${stock ? "stock firmware (NAME.stock.gcode)" : "bulgekit firmware (NAME.bulge.gcode)"}`;
}

async function pump(check = false) {
  if (inFlight || !pending) return;
  pending = false;
  inFlight = true;
  const d = design();
  const key = JSON.stringify(d);
  const geom = Object.fromEntries(S.items.map((it) => [it.id, geomOf(it)]));
  // (a design with layers over the limit is not checked: the line keeps what placing said)
  if (check && !(S.preview && S.preview.summary && S.preview.summary.over)) status(`checking against ${S.gcode.name}…`, null);
  try {
    const p = await postJSON("/api/preview", { design: d, check });
    S.preview = p;
    S.strokesAt = geom;
    if (p.walls) { S.gcode.walls = p.walls; view3d.setWalls(p.walls); }   // the mode's own walls
    if (check) checkedFor = key;
    let moved = false;
    for (const it of S.items) if (it.placing && p.items[it.id] && geom[it.id] && geomOf(it).u === geom[it.id].u
      && geomOf(it).v === geom[it.id].v) moved = placeNew(it) || moved;     // its first strokes: now its real box
    // (a preview that moved a new item is not shown: its messages were of the place it left)
    if (!moved) showPreview(p);
    if (check && !p.summary.over)
      status(p.summary.checked ? `${S.gcode.name}: checked, ${p.summary.stops} stops` : `${S.gcode.name}: ${S.gcode.layers} layers of outer wall`);
  } catch (e) {
    S.preview = { items: {}, points: [], errors: [String(e.message || e)], warnings: [], summary: {} };
    showPreview(S.preview);
  } finally {
    inFlight = false;
  }
  if (pending) { pump(); return; }
  if (!check && checkedFor !== key) {
    clearTimeout(checkTimer);
    checkTimer = setTimeout(() => { if (!pending && !inFlight) { pending = true; pump(true); } }, 700);
  }
}

function showPreview(p) {
  const s = p.summary || {};
  let line = s.points !== undefined ? `${s.points} bumps on ${s.layers} layers, map ${s.map_bytes} bytes ` +
    `(printer arena ${s.arena})` : "no bumps";
  if (s.over) line += `; ${s.over} layer${s.over === 1 ? "" : "s"} over ${S.limits.layer_points || 64} points left out, ` +
    "drawn red: not checked against the G-code, and Export refuses until they fit";
  else if (s.checked) line += `; when printed: ${s.stops} stops, ${s.dwell_s} s dwell, about ${s.added_s} s added` +
    (s.missed ? `, ${s.missed} not reached` : "");
  else if (s.points !== undefined) line += "; checking the G-code…";
  $("summary").textContent = line;
  const ul = $("global-msgs");
  ul.textContent = "";
  for (const e of p.errors) { const li = document.createElement("li"); li.className = "error"; li.textContent = e; ul.append(li); }
  for (const w of p.warnings) { const li = document.createElement("li"); li.className = "warning"; li.textContent = w; ul.append(li); }
  renderItems();
  view2d.draw();
  view3d.setBumps(p.points);
}

// ---------------------------------------------------------------- geometry of an item on the wall

// What a drag changes: place, turn and size; strokes computed for one geometry are shown for
// another by the affine map between them (exact for moves and turns, near enough for sizes).
function geomOf(it) {
  const size = it.kind === "text" ? it.size : it.kind === "braille" ? 1 : it.assetKind === "image" ? it.image_width : it.scale;
  return { u: it.at[0], v: it.at[1], rot: it.rotate || 0, size };
}

function mapPoint(g0, g1, u, v) {
  const k = g1.size / g0.size;
  const a = ((g1.rot - g0.rot) * Math.PI) / 180;
  const du = (u - g0.u) * k, dv = (v - g0.v) * k;
  return [g1.u + du * Math.cos(a) - dv * Math.sin(a), g1.v + du * Math.sin(a) + dv * Math.cos(a)];
}

function itemStrokes(it) {
  const info = S.preview && S.preview.items[it.id];
  const g0 = S.strokesAt[it.id];
  if (!info || !g0) return [];
  const g1 = geomOf(it);
  const same = g0.u === g1.u && g0.v === g1.v && g0.rot === g1.rot && g0.size === g1.size;
  return info.strokes.map((flat) => {
    const pts = [];
    for (let i = 0; i < flat.length; i += 2) pts.push(same ? [flat[i], flat[i + 1]] : mapPoint(g0, g1, flat[i], flat[i + 1]));
    return pts;
  });
}

function itemBox(it) {
  let u0 = Infinity, v0 = Infinity, u1 = -Infinity, v1 = -Infinity;
  for (const st of itemStrokes(it)) for (const [u, v] of st) {
    u0 = Math.min(u0, u); v0 = Math.min(v0, v); u1 = Math.max(u1, u); v1 = Math.max(v1, v);
  }
  if (!isFinite(u0)) { u0 = it.at[0]; v0 = it.at[1]; u1 = u0 + 5; v1 = v0 + 5; }
  return { u0, v0, u1, v1 };
}

// ---------------------------------------------------------------- the unrolled wall (2D canvas)

const view2d = (() => {
  const cv = $("unrolled");
  const ctx = cv.getContext("2d");
  let k = 4, ou = -5, ov = 0;            // px per mm; wall point at the canvas's left/bottom edge
  let drag = null;

  const toPx = (u, v) => [(u - ou) * k, cv.height - (v - ov) * k];
  const toMm = (x, y) => [x / k + ou, (cv.height - y) / k + ov];

  function resize() {
    const r = cv.getBoundingClientRect();
    cv.width = Math.max(50, r.width | 0); cv.height = Math.max(50, r.height | 0);
    draw();
  }

  function fit() {
    if (!S.gcode) return;
    const w = S.gcode.walls, L = S.gcode.length_max;
    const [lo, hi] = w.v_range;
    // the wall fills the view: u 0..L with 5 mm each side, v from the bed (or the wall's
    // foot, if lower) with room for the u labels below. A wall wider than the view's shape
    // takes a lower view (at least 180 px), and the 3D view below gets the rest.
    const v0 = Math.min(0, lo), views = $("views");
    views.style.gridTemplateRows = "";
    resize();
    const need = 40 + (hi - v0 + 2) * (cv.width - 40) / (L + 10);
    if (need < cv.height) {
      views.style.gridTemplateRows = `${Math.max(180, Math.ceil(need))}px 1fr auto`;
      resize();
    }
    k = Math.min((cv.width - 40) / (L + 10), (cv.height - 40) / (hi - v0 + 2));
    ou = -5 - (cv.width / k - (L + 10)) / 2;
    ov = v0 - 16 / k;
    draw();
  }

  // (braille keeps the standard's size and is not turned: no handles but the frame)
  function handles(it) {
    const b = itemBox(it);
    const [x0, y0] = toPx(b.u0, b.v1), [x1, y1] = toPx(b.u1, b.v0);
    const fixed = it.kind === "braille";
    return { box: [x0 - 4, y0 - 4, x1 + 4, y1 + 4], scale: fixed ? null : [x1 + 4, y1 + 4],
      rotate: fixed ? null : [(x0 + x1) / 2, y0 - 22] };
  }

  function draw() {
    ctx.clearRect(0, 0, cv.width, cv.height);
    if (!S.gcode) {
      ctx.fillStyle = "#90a4ae"; ctx.font = "14px system-ui";
      ctx.fillText("Open a sliced G-code: its outer wall appears here, unrolled.", 20, 30);
      return;
    }
    // the wall: one band per layer, as long as that layer's outer wall
    ctx.fillStyle = "#dfe5e8";
    for (const l of S.gcode.walls.layers) {
      const a = l.closed ? 0 : l.u[0], b = l.closed ? l.length : l.u[1];
      const [x0, y0] = toPx(a, l.z), [x1, y1] = toPx(b, l.z - l.h);
      ctx.fillRect(x0, y0, Math.max(1, x1 - x0), Math.max(0.5, y1 - y0 - (k * l.h > 3 ? 0.5 : 0)));
    }
    // the corners (lines over each layer's band) and the faces' numbers
    const marks = S.gcode.walls.marks;
    if (marks) {
      ctx.strokeStyle = "#2a7a3a"; ctx.lineWidth = 1.2; ctx.beginPath();
      for (const [u, a, b] of marks.corners) {
        const [x, y0] = toPx(u, b), [, y1] = toPx(u, a);
        ctx.moveTo(x, y0); ctx.lineTo(x, y1);
      }
      ctx.stroke();
      ctx.font = "bold 12px system-ui"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
      for (const [u, v, n] of marks.faces) {
        const [x, y] = toPx(u, v);
        ctx.fillStyle = "rgba(255,255,255,.85)"; ctx.beginPath(); ctx.arc(x, y, 9, 0, 2 * Math.PI); ctx.fill();
        ctx.strokeStyle = "#2a7a3a"; ctx.lineWidth = 1; ctx.stroke();
        ctx.fillStyle = "#2a7a3a"; ctx.fillText(String(n), x, y + 0.5);
      }
      ctx.textAlign = "start"; ctx.textBaseline = "alphabetic";
    }
    // axes
    ctx.strokeStyle = "#b0bec5"; ctx.fillStyle = "#78909c"; ctx.font = "11px system-ui"; ctx.lineWidth = 1;
    const steps = [0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000];
    const ustep = steps.find((s) => s * k >= 28 + 7 * String(Math.round(S.gcode.length_max)).length) || 10000;
    const vstep = steps.find((s) => s * k >= 24) || 10000;
    const [umin] = toMm(0, 0), [umax] = toMm(cv.width, 0);
    for (let u = Math.max(0, Math.ceil(umin / ustep) * ustep); u <= Math.min(umax, S.gcode.length_max + ustep); u += ustep) {
      const [x] = toPx(u, 0);
      ctx.fillText(`${+u.toFixed(1)}`, x + 2, cv.height - 4);
    }
    const [, vtop] = toMm(0, 0), [, vbot] = toMm(0, cv.height);
    for (let v = Math.ceil(vbot / vstep) * vstep; v <= vtop; v += vstep) {
      const [, y] = toPx(0, v);
      ctx.fillText(`${+v.toFixed(1)}`, 2, y - 2);
    }
    const [xL] = toPx(S.gcode.length_max, 0);
    ctx.setLineDash([4, 4]); ctx.beginPath(); ctx.moveTo(xL, 0); ctx.lineTo(xL, cv.height); ctx.stroke(); ctx.setLineDash([]);
    // items: their strokes
    for (const it of S.items) {
      const info = S.preview && S.preview.items[it.id];
      const bad = info && info.errors.length;
      ctx.strokeStyle = bad ? "#e53935" : it.id === S.selected ? "#ef6c00" : "#546e7a";
      ctx.fillStyle = ctx.strokeStyle;
      ctx.lineWidth = 1.2;
      const dot = it.kind === "braille" ? Math.max(1, (BRAILLE_DOT / 2) * k) : 0;   // a dot's base
      for (const st of itemStrokes(it)) {
        if (dot) { const [x, y] = toPx(...st[0]); ctx.beginPath(); ctx.arc(x, y, dot, 0, 2 * Math.PI); ctx.stroke(); continue; }
        if (st.length === 1) { const [x, y] = toPx(...st[0]); ctx.fillRect(x - 1, y - 1, 2, 2); continue; }
        ctx.beginPath();
        st.forEach(([u, v], i) => { const [x, y] = toPx(u, v); i ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
        ctx.stroke();
      }
    }
    // bumps (only while the strokes shown are the ones they were made from)
    const moving = drag && drag.mode !== "pan";
    if (S.preview && !moving) {
      const r = Math.max(1.5, Math.min(6, 0.45 * k));
      for (const p of S.preview.points) {
        const [x, y] = toPx(p[0], p[1]);
        ctx.beginPath(); ctx.arc(x, y, r * (0.5 + p[5] / 510), 0, 2 * Math.PI);
        ctx.fillStyle = p[7] || p[8] ? "rgba(229,57,53,.85)" : p[6].includes(S.selected) ? "rgba(239,108,0,.8)" : "rgba(38,50,56,.55)";
        ctx.fill();
      }
    }
    // the selected item's frame and handles
    const it = S.items.find((i) => i.id === S.selected);
    if (it) {
      const h = handles(it);
      ctx.strokeStyle = "#ef6c00"; ctx.setLineDash([3, 3]); ctx.lineWidth = 1;
      ctx.strokeRect(h.box[0], h.box[1], h.box[2] - h.box[0], h.box[3] - h.box[1]);
      ctx.setLineDash([]);
      if (h.rotate) {
        ctx.beginPath(); ctx.moveTo((h.box[0] + h.box[2]) / 2, h.box[1]); ctx.lineTo(...h.rotate); ctx.stroke();
        ctx.fillStyle = "#fff";
        ctx.fillRect(h.scale[0] - 5, h.scale[1] - 5, 10, 10); ctx.strokeRect(h.scale[0] - 5, h.scale[1] - 5, 10, 10);
        ctx.beginPath(); ctx.arc(h.rotate[0], h.rotate[1], 6, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
      }
      const [ax, ay] = toPx(...it.at);
      ctx.fillStyle = "#ef6c00"; ctx.fillRect(ax - 2, ay - 2, 4, 4);
    }
  }

  function hit(x, y) {
    const sel = S.items.find((i) => i.id === S.selected);
    if (sel && sel.kind !== "braille") {
      const h = handles(sel);
      if (Math.hypot(x - h.scale[0], y - h.scale[1]) < 9) return { it: sel, mode: "scale" };
      if (Math.hypot(x - h.rotate[0], y - h.rotate[1]) < 9) return { it: sel, mode: "rotate" };
    }
    for (const it of [...S.items].reverse()) {
      const b = handles(it).box;
      if (x >= b[0] && x <= b[2] && y >= b[1] && y <= b[3]) return { it, mode: "move" };
    }
    return null;
  }

  cv.addEventListener("pointerdown", (e) => {
    const r = cv.getBoundingClientRect();
    const x = e.clientX - r.left, y = e.clientY - r.top;
    const h = hit(x, y);
    cv.setPointerCapture(e.pointerId);
    if (!h) { drag = { mode: "pan", x, y, ou, ov }; return; }
    if (h.it.id !== S.selected) select(h.it.id);
    flushHistory();
    const [u, v] = toMm(x, y);
    drag = { mode: h.mode, it: h.it, u, v, g: geomOf(h.it), at: [...h.it.at] };
    delete h.it.placing;                        // placed by hand now
  });
  cv.addEventListener("pointermove", (e) => {
    const r = cv.getBoundingClientRect();
    const x = e.clientX - r.left, y = e.clientY - r.top;
    if (!drag) { const h = hit(x, y); cv.style.cursor = h ? (h.mode === "move" ? "move" : h.mode === "scale" ? "nwse-resize" : "crosshair") : "grab"; return; }
    if (drag.mode === "pan") { ou = drag.ou - (x - drag.x) / k; ov = drag.ov + (y - drag.y) / k; draw(); return; }
    const [u, v] = toMm(x, y), it = drag.it;
    if (drag.mode === "move") it.at = [round2(drag.at[0] + u - drag.u), round2(drag.at[1] + v - drag.v)];
    else if (drag.mode === "rotate") {
      const a0 = Math.atan2(drag.v - drag.at[1], drag.u - drag.at[0]), a1 = Math.atan2(v - drag.at[1], u - drag.at[0]);
      let deg = drag.g.rot + ((a1 - a0) * 180) / Math.PI;
      if (e.shiftKey) deg = Math.round(deg / 15) * 15;
      it.rotate = Math.round((((deg % 360) + 540) % 360 - 180) * 10) / 10;
    } else {
      const d0 = Math.hypot(drag.u - drag.at[0], drag.v - drag.at[1]), d1 = Math.hypot(u - drag.at[0], v - drag.at[1]);
      const f = Math.max(0.05, d1 / Math.max(d0, 1e-6));
      if (it.kind === "text") it.size = round2(Math.max(0.5, drag.g.size * f));
      else if (it.assetKind === "image") it.image_width = round2(Math.max(1, drag.g.size * f));
      else it.scale = Math.round(Math.max(0.01, drag.g.size * f) * 1000) / 1000;
    }
    fillItemForm(it);
    draw();
  });
  cv.addEventListener("pointerup", () => {
    const was = drag;
    drag = null;
    if (was && was.mode !== "pan") { clampItem(was.it); fillItemForm(was.it); requestPreview(); }
    draw();
  });
  cv.addEventListener("wheel", (e) => {
    e.preventDefault();
    const r = cv.getBoundingClientRect();
    const [u, v] = toMm(e.clientX - r.left, e.clientY - r.top);
    k = Math.min(200, Math.max(0.2, k * Math.exp(-e.deltaY * 0.0015)));
    ou = u - (e.clientX - r.left) / k; ov = v - (cv.height - (e.clientY - r.top)) / k;
    draw();
  }, { passive: false });
  new ResizeObserver(resize).observe(cv);
  // the u range the canvas shows
  const uInView = () => [toMm(0, 0)[0], toMm(cv.width, 0)[0]];
  return { draw, fit, toPx, toMm, uInView };
})();

// ---------------------------------------------------------------- the 3D view

const view3d = (() => {
  const host = $("view3d");
  let renderer = null, scene, camera, controls, wallGroup, bumps = null;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  } catch (e) {
    const p = document.createElement("p");
    p.className = "msg warning";
    p.textContent = `No 3D view: this browser gave no WebGL (${e.message}). The unrolled view above shows the same bumps.`;
    host.append(p);
    return { setWalls() {}, setBumps() {}, look() {} };
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  host.prepend(renderer.domElement);
  scene = new THREE.Scene();
  scene.background = new THREE.Color(0xeef1f3);
  camera = new THREE.PerspectiveCamera(40, 1, 0.1, 5000);
  camera.up.set(0, 0, 1);
  controls = new OrbitControls(camera, renderer.domElement);
  scene.add(new THREE.AmbientLight(0xffffff, 0.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  sun.position.set(1, -1, 2);
  scene.add(sun);
  wallGroup = new THREE.Group();
  scene.add(wallGroup);

  function size() {
    const r = host.getBoundingClientRect();
    renderer.setSize(Math.max(10, r.width), Math.max(10, r.height));
    camera.aspect = Math.max(10, r.width) / Math.max(10, r.height);
    camera.updateProjectionMatrix();
    render();
  }
  const render = () => renderer.render(scene, camera);
  controls.addEventListener("change", render);
  new ResizeObserver(size).observe(host);

  function setWalls(w) {
    wallGroup.clear();
    const mat = new THREE.LineBasicMaterial({ color: 0x90a4ae });
    for (const l of w.layers) {
      if (!l.xy) continue;
      const pos = new Float32Array((l.xy.length / 2) * 3);
      for (let i = 0, j = 0; i < l.xy.length; i += 2, j += 3) { pos[j] = l.xy[i]; pos[j + 1] = l.xy[i + 1]; pos[j + 2] = l.z; }
      const g = new THREE.BufferGeometry();
      g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
      wallGroup.add(new THREE.Line(g, mat));
    }
    const [x0, y0, x1, y1] = w.bounds, [z0, z1] = w.v_range;
    const c = new THREE.Vector3((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2);
    const R = Math.max(x1 - x0, y1 - y0, z1 - z0);
    controls.target.copy(c);
    camera.position.set(c.x + 1.1 * R, c.y - 1.6 * R, c.z + 0.9 * R);
    camera.far = 20 * R + 100; camera.near = R / 1000 + 0.01;
    camera.updateProjectionMatrix();
    controls.update();
    size();
  }

  function setBumps(points) {
    if (bumps) { scene.remove(bumps); bumps.geometry.dispose(); bumps.material.dispose(); bumps = null; }
    if (points && points.length) {
      const geo = new THREE.SphereGeometry(0.45, 10, 8);
      const mat = new THREE.MeshStandardMaterial({ color: 0xffffff, roughness: 0.6 });   // tinted per bump
      bumps = new THREE.InstancedMesh(geo, mat, points.length);
      const m = new THREE.Matrix4(), red = new THREE.Color(0xe53935), orange = new THREE.Color(0xef6c00);
      points.forEach((p, i) => {
        const s = 0.5 + p[5] / 510;
        m.makeScale(s, s, s).setPosition(p[2], p[3], p[4] - 0.1);
        bumps.setMatrixAt(i, m);
        bumps.setColorAt(i, p[7] || p[8] ? red : orange);
      });
      scene.add(bumps);
    }
    render();
  }
  // turn the camera to face a group of bumps from outside the wall
  function look(points) {
    if (!points.length) return;
    const c = new THREE.Vector3();
    for (const p of points) c.add(new THREE.Vector3(p[2], p[3], p[4]));
    c.divideScalar(points.length);
    const t = controls.target, out = new THREE.Vector3(c.x - t.x, c.y - t.y, 0);
    if (out.lengthSq() < 1e-6) return;
    const dist = camera.position.distanceTo(t);
    out.normalize();
    camera.position.set(t.x + out.x * dist * 0.85, t.y + out.y * dist * 0.85, t.z + dist * 0.5);
    controls.update();
    render();
  }
  return { setWalls, setBumps, look };
})();

// ---------------------------------------------------------------- export and printer

async function doExport() {
  showError("export-error", null);
  $("export").disabled = true;
  const out = $("export-out");
  out.textContent = "";
  try {
    const job = await postJSON("/api/export", { design: design() });
    const res = await pollJob(job, (j) => status(`exporting: ${j.label || "…"}${j.total ? ` ${Math.round(100 * j.done / j.total)} %` : ""}`, j.total ? j.done / j.total : 0));
    S.exportKey = res.key;
    const zip = document.createElement("a");
    zip.href = fileUrl(res.zip); zip.textContent = `Download all (${res.key}.zip)`; zip.id = "export-zip";
    out.append(zip);
    for (const f of res.files) {
      const a = document.createElement("a");
      a.href = fileUrl(f.url); a.textContent = `${f.name} (${(f.bytes / 1024).toFixed(1)} KB)`;
      a.className = "export-file";
      out.append(a);
    }
    const where = document.createElement("div");
    where.className = "info"; where.textContent = `saved in ${res.folder}`;
    const pre = document.createElement("pre");
    pre.textContent = res.stats + (res.notes.length ? "\n" + res.notes.map((n) => `note: ${n}`).join("\n") : "");
    out.append(where, pre);
    $("send").disabled = false;
    status(`exported ${res.key}`);
  } catch (e) {
    showError("export-error", e);
    status("export failed");
  } finally {
    $("export").disabled = false;
  }
}

async function downloadPlacement() {
  showError("export-error", null);
  try {
    const r = await fetch("/api/placement", { method: "POST", body: JSON.stringify({ design: design() }),
      headers: { "X-Studio-Token": TOKEN, "Content-Type": "application/json" } });
    if (!r.ok) throw new Error((await r.json()).error);
    const a = document.createElement("a");
    a.href = URL.createObjectURL(await r.blob()); a.download = "placement.toml";
    a.click();
  } catch (e) { showError("export-error", e); }
}

// Sends a file through the server's Sender (line numbers, checksums, resends, the printer's
// messages); `ids` name the tab's error line, progress bar, log and button.
async function sendFile(ids, body, ready) {
  showError(ids.error, null);
  const bar = $(ids.bar), log = $(ids.log);
  log.textContent = "";
  $(ids.button).disabled = true;
  try {
    const job = await postJSON("/api/send", body);
    bar.hidden = false;
    const res = await pollJob(job, (j) => {
      bar.value = j.total ? j.done / j.total : 0;
      log.textContent = j.log.join("\n");
      status(`${j.label || "connecting"}${j.total ? `: ${j.done} of ${j.total} lines` : "…"}`, j.total ? j.done / j.total : 0);
    });
    log.textContent += `\n${res.file}: ${res.summary}`;
    status(`sent ${res.file}`);
  } catch (e) {
    showError(ids.error, e);
    status("sending stopped");
  } finally {
    $(ids.button).disabled = !ready();
  }
}

function doSend() {
  return sendFile({ error: "send-error", bar: "send-bar", log: "send-log", button: "send" },
    { export: S.exportKey, which: $("bulge-form").fallback.value === "true" ? "stock" : "bulge",
      port: $("port").value, baud: +$("baud").value },
    () => S.exportKey);
}

async function loadPorts() {
  try {
    const r = await api("/api/ports");
    const dl = $("ports");
    dl.textContent = "";
    for (const p of r.ports) { const o = document.createElement("option"); o.value = p.device; o.label = p.description; dl.append(o); }
  } catch { /* no list: the field still takes a typed port */ }
}

// ---------------------------------------------------------------- lithophane tab

const L = { asset: null, key: null, srcUrl: null, choices: null };
// the curves in the page's words (a curve the toolkit adds without one here shows its name)
const CURVE_WORDS = { linear: "linear (paper)", transmission: "transmission", perceptual: "perceptual" };
const SHAPE_WORDS = { planar: "flat plate", cylinder: "cylinder", arc: "arc (curved panel)" };
const LIGHT_GAP_WORDS = { "mid-line": "thin mid-line", walls: "walls share" };

// The form's choices and defaults come from the toolkit (litho.SHAPES, CURVES, LIGHT_GAPS,
// LithoOptions).
function lithoChoices(c) {
  if (!c) return;
  L.choices = c;
  const f = $("litho-form");
  const fill = (sel, list, words) => {
    sel.textContent = "";
    for (const v of list) { const o = document.createElement("option"); o.value = v; o.textContent = words[v] || v; sel.append(o); }
  };
  fill(f.shape, c.shapes, SHAPE_WORDS);
  fill(f.curve, c.curves, CURVE_WORDS);
  if (c.light_gaps) fill(f.light_gaps, c.light_gaps, LIGHT_GAP_WORDS);
  for (const el of f.elements) {
    if (!el.name || !(el.name in c.defaults)) continue;
    const v = c.defaults[el.name];
    if (el.type === "checkbox") el.checked = !!v;
    else if (v === null) { el.value = ""; if (!el.placeholder) el.placeholder = "automatic"; }
    else el.value = v;
  }
  lithoShape();
}

// only the chosen shape's fields show (and only they are sent)
function lithoShape() {
  const shape = $("litho-form").shape.value;
  for (const el of $("litho-form").querySelectorAll("[data-shape]")) el.hidden = !el.dataset.shape.split(" ").includes(shape);
}

async function lithoPicture(file) {
  showError("litho-error", null);
  // the picture shows at once, while it uploads (the browser reads it; nothing leaves the page)
  if (L.srcUrl) URL.revokeObjectURL(L.srcUrl);
  L.srcUrl = URL.createObjectURL(file);
  $("litho-src").src = L.srcUrl;
  $("litho-src-box").hidden = false;
  const info = await addFile(file, "litho-error");
  if (!info) return;
  if (info.kind !== "image") { showError("litho-error", `${file.name}: a lithophane needs a picture`); return; }
  L.asset = info.name;
  $("litho-pic").textContent = `${info.name}: ${info.width_px} × ${info.height_px} pixels`;
  $("litho-make").disabled = false;
}

function lithoOptions() {
  const f = $("litho-form"), o = {};
  for (const el of f.elements) {
    if (!el.name || el.closest("label").hidden) continue;
    if (el.type === "checkbox") o[el.name] = el.checked;
    else if (el.tagName === "SELECT") o[el.name] = el.value;
    else if (el.value !== "") o[el.name] = ["temp", "bed_temp"].includes(el.name) ? Math.round(+el.value) : +el.value;
  }
  return o;
}

function lithoResult(res) {
  const out = $("litho-result");
  out.textContent = "";
  const tab = document.createElement("table"); tab.id = "litho-figures";
  for (const [k, v] of res.figures) {
    const tr = tab.insertRow(), th = document.createElement("th"), td = document.createElement("td");
    th.textContent = k; td.textContent = v; tr.append(th, td);
  }
  const files = document.createElement("div"); files.className = "files";
  const h = document.createElement("h2"); h.textContent = "Files";
  files.append(h);
  for (const f of res.files) {
    const a = document.createElement("a"); a.href = fileUrl(f.url);
    a.textContent = `${f.name} (${(f.bytes / 1024).toFixed(1)} KB)`; files.append(a);
  }
  const look = document.createElement("figure"); look.style.margin = "0";
  const cap = document.createElement("figcaption"); cap.textContent = "The picture and its predicted look, flat";
  const img = document.createElement("img"); img.src = fileUrl(res.look); img.id = "litho-look"; img.alt = "predicted look";
  look.append(cap, img);
  out.append(tab, files, look);
}

// A lithophane made: its figures, files, look and 3D view, ready to send.
async function showLitho(res) {
  L.key = res.key;
  lithoResult(res);
  litho3d.show(await api(res.view));
  $("litho-send").disabled = false;
}

// After a reload: the last lithophane the server made, its picture and the form it was made with.
async function restoreLitho(last) {
  const f = $("litho-form");
  if (last.options.shape) f.shape.value = last.options.shape;
  lithoShape();
  for (const el of f.elements) {
    if (!el.name || !(el.name in last.options)) continue;
    if (el.type === "checkbox") el.checked = !!last.options[el.name]; else el.value = last.options[el.name];
  }
  const pic = last.picture;
  L.asset = pic.name;
  $("litho-pic").textContent = `${pic.original || pic.name}: ${pic.width_px} × ${pic.height_px} pixels`;
  $("litho-make").disabled = false;
  await showLitho(last);
}

async function makeLitho() {
  showError("litho-error", null);
  $("litho-make").disabled = true;
  const bar = $("litho-bar");
  bar.hidden = false;
  try {
    const job = await postJSON("/api/litho", { asset: L.asset, options: lithoOptions() });
    const res = await pollJob(job, (j) => {
      bar.value = j.total ? j.done / j.total : 0;
      status(`lithophane: ${j.label || "…"}${j.total ? ` ${j.done}/${j.total}` : ""}`, j.total ? j.done / j.total : 0);
    });
    await showLitho(res);
    status(`lithophane ${res.key} made`);
  } catch (e) {
    showError("litho-error", e);
    status("lithophane failed");
  } finally {
    bar.hidden = true;
    $("litho-make").disabled = !L.asset;
  }
}

// The same sender as the wall tab's.
function sendLitho() {
  return sendFile({ error: "litho-send-error", bar: "litho-send-bar", log: "litho-send-log", button: "litho-send" },
    { litho: L.key, which: $("litho-which").value, port: $("litho-port").value, baud: +$("litho-baud").value },
    () => L.key);
}

const b64bytes = (s) => Uint8Array.from(atob(s), (c) => c.charCodeAt(0));

// The part in 3D: the relief as the server sampled it (server.litho_view), the predicted look
// as a texture on both faces. "Backlit" shows the look glowing, with a little light on the
// relief so its shape reads; "Daylight" shows the bare plastic.
const litho3d = (() => {
  let renderer = null, scene, camera, controls, part = null, tex = null, light = "back", shape = null;
  const host = $("litho-3d");
  const mats = {};

  function init() {
    if (renderer) return true;
    try {
      renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    } catch (e) {
      host.textContent = `No 3D view: this browser gave no WebGL (${e.message}).`;
      return false;
    }
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    host.textContent = "";
    host.append(renderer.domElement);
    scene = new THREE.Scene();
    camera = new THREE.PerspectiveCamera(35, 1, 0.5, 5000);
    camera.up.set(0, 0, 1);
    controls = new OrbitControls(camera, renderer.domElement);
    controls.addEventListener("change", render);
    scene.add(new THREE.AmbientLight(0xffffff, 0.45));
    // the light turns with the camera, from its upper left: the relief shades whichever side
    // is seen
    const sun = new THREE.DirectionalLight(0xffffff, 1.6), aim = new THREE.Object3D();
    sun.position.set(-6, 7, 2);
    aim.position.set(0, 0, -10);
    camera.add(sun, aim);
    sun.target = aim;
    scene.add(camera);
    new ResizeObserver(size).observe(host);
    return true;
  }

  function size() {
    const r = host.getBoundingClientRect();
    const w = Math.max(10, r.width), h = Math.max(10, r.height);
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    render();
  }
  const render = () => renderer && renderer.render(scene, camera);

  function materials() {
    const back = light === "back";
    scene.background = new THREE.Color(back ? 0x20262b : 0xeef1f3);
    const face = back
      ? new THREE.MeshStandardMaterial({ map: tex, emissive: 0xffffff, emissiveMap: tex, emissiveIntensity: 0.8,
        color: 0x555555, roughness: 1, side: THREE.DoubleSide })
      : new THREE.MeshStandardMaterial({ color: 0xf3efe6, roughness: 0.75, side: THREE.DoubleSide });
    const rest = new THREE.MeshStandardMaterial({ color: back ? 0x6d6a64 : 0xe6e1d6, roughness: 0.8, side: THREE.DoubleSide });
    for (const m of Object.values(mats)) m.dispose();
    Object.assign(mats, { face, rest });
    if (part) for (const m of part.children) m.material = m.userData.face ? face : rest;
    render();
  }

  // vertices of one grid (rows x cols): thickness th(i, j) over the back face, mm
  function surface(v, th) {
    const R = v.rows, C = v.cols, ring = v.shape === "cylinder", n = ring ? C + 1 : C;
    const pos = new Float32Array(R * n * 3), uv = new Float32Array(R * n * 2);
    const mid = ring ? 0 : (v.s[0] + v.s[C - 1]) / 2;
    for (let i = 0; i < R; i++) {
      const z = i === 0 ? v.z_range[0] : i === R - 1 ? v.z_range[1] : v.z[i];
      for (let k = 0; k < n; k++) {
        const j = k % C, t = th(i, j), p = (i * n + k) * 3, q = (i * n + k) * 2;
        if (ring) {
          const a = k === C ? v.s[0] + 2 * Math.PI : v.s[j], r = v.r_in + t;
          pos[p] = r * Math.cos(a); pos[p + 1] = r * Math.sin(a);
        } else if (v.shape === "arc") {
          const a = v.arc_start + v.s[j], r = v.r_in + t;
          pos[p] = r * Math.cos(a); pos[p + 1] = r * Math.sin(a);
        } else { pos[p] = v.s[j] - mid; pos[p + 1] = t; }
        pos[p + 2] = z;
        uv[q] = k === C ? 1 + v.u[0] : v.u[j]; uv[q + 1] = v.v[i];
      }
    }
    return { pos, uv, R, n };
  }

  function grid(R, n) {
    const idx = [];
    for (let i = 0; i < R - 1; i++) for (let k = 0; k < n - 1; k++) {
      const a = i * n + k, b = a + 1, c = a + n + 1, d = a + n;
      idx.push(a, b, c, a, c, d);
    }
    return idx;
  }

  function mesh(pos, idx, uv, face) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    if (uv) g.setAttribute("uv", new THREE.BufferAttribute(uv, 2));
    g.setIndex(idx);
    g.computeVertexNormals();
    const m = new THREE.Mesh(g, face ? mats.face : mats.rest);
    m.userData.face = face;
    return m;
  }

  // a band of quads between two rows of points (caps and ends)
  function band(A, B) {
    const n = A.length / 3, pos = new Float32Array([...A, ...B]), idx = [];
    for (let k = 0; k < n - 1; k++) idx.push(k, k + 1, n + k + 1, k, n + k + 1, n + k);
    return mesh(pos, idx, null, false);
  }

  function show(v) {
    if (!init()) return;
    if (part) { scene.remove(part); part.traverse((o) => o.geometry && o.geometry.dispose()); }
    if (tex) tex.dispose();
    shape = v.shape;
    const lk = v.look, g = b64bytes(lk.data), rgba = new Uint8Array(g.length * 4);
    for (let i = 0; i < g.length; i++) { rgba[4 * i] = rgba[4 * i + 1] = rgba[4 * i + 2] = g[i]; rgba[4 * i + 3] = 255; }
    tex = new THREE.DataTexture(rgba, lk.width, lk.height, THREE.RGBAFormat);
    tex.colorSpace = THREE.SRGBColorSpace;
    tex.magFilter = tex.minFilter = THREE.LinearFilter;
    tex.wrapS = v.shape === "cylinder" ? THREE.RepeatWrapping : THREE.ClampToEdgeWrapping;
    tex.needsUpdate = true;
    materials();
    const t = new Uint16Array(b64bytes(v.thickness_um).buffer), C = v.cols;
    const front = surface(v, (i, j) => t[i * C + j] / 1000), back = surface(v, () => 0);
    const idx = grid(front.R, front.n);
    part = new THREE.Group();
    part.add(mesh(front.pos, idx, front.uv, true), mesh(back.pos, idx, back.uv, true));
    const row = (s, i) => s.pos.slice(i * s.n * 3, (i + 1) * s.n * 3);
    const col = (s, k) => { const o = []; for (let i = 0; i < s.R; i++) o.push(...s.pos.slice((i * s.n + k) * 3, (i * s.n + k) * 3 + 3)); return o; };
    part.add(band(row(front, 0), row(back, 0)), band(row(front, front.R - 1), row(back, back.R - 1)));
    if (v.shape !== "cylinder") part.add(band(col(front, 0), col(back, 0)), band(col(front, front.n - 1), col(back, back.n - 1)));
    if (v.foot) {             // the foot block under the plate, across its width, centred on it
      const w = v.s[C - 1] - v.s[0];
      const box = new THREE.Mesh(new THREE.BoxGeometry(w, v.foot.depth, v.foot.height), mats.rest);
      box.position.set(0, v.max_thickness / 2, v.foot.height / 2);
      part.add(box);
    }
    scene.add(part);
    // the camera in front of the picture (the picture reads from -Y: the plate's flat back,
    // the cylinder's and the arc's outside), a little to the side and above
    const bb = new THREE.Box3().setFromObject(part), c = bb.getCenter(new THREE.Vector3()), sz = bb.getSize(new THREE.Vector3());
    const R = Math.max(sz.x, sz.z, 1), d = 0.75 * R / Math.tan((camera.fov * Math.PI) / 360);
    controls.target.copy(c);
    camera.position.set(c.x - 0.25 * d, c.y + (light === "day" && shape === "planar" ? d : -d), c.z + 0.2 * d);
    camera.near = d / 100; camera.far = d * 20;
    camera.updateProjectionMatrix();
    controls.update();
    size();
  }

  // a plate's relief is on its other side: daylight turns the camera round to it
  function turn(to) {
    if (!part || shape !== "planar" || to === light) return;
    const t = controls.target;
    camera.position.set(2 * t.x - camera.position.x, 2 * t.y - camera.position.y, camera.position.z);
    controls.update();
  }
  for (const b of document.querySelectorAll("#litho-light button")) b.onclick = () => {
    turn(b.dataset.light);
    light = b.dataset.light;
    for (const x of document.querySelectorAll("#litho-light button")) x.classList.toggle("on", x === b);
    $("litho-3d-what").textContent = light === "back" ? "The part with its predicted look, backlit"
      : "The part in daylight: its relief";
    if (renderer) materials();
  };
  return { show, render: () => render() };
})();

// ---------------------------------------------------------------- wiring

function dropTarget(el, onFile) {
  el.addEventListener("dragover", (e) => { e.preventDefault(); el.classList.add("over"); });
  el.addEventListener("dragleave", () => el.classList.remove("over"));
  el.addEventListener("drop", (e) => {
    e.preventDefault(); el.classList.remove("over");
    const f = e.dataTransfer.files[0];
    if (f) onFile(f);
  });
}

async function init() {
  const st = await api("/api/state");
  S.fonts = st.fonts; S.limits = st.limits; S.printers = st.printers || [];
  const pc = $("bulge-form").printer_choice;
  pc.textContent = "";
  for (const p of [...S.printers, { name: "file", firmware: null }]) {
    const o = document.createElement("option");
    o.value = p.name; o.textContent = p.firmware ? `${p.name} (${p.firmware})` : "a profile file…";
    pc.append(o);
  }
  pc.value = DEFAULT_PRINTER;
  printerFields();
  const fs = $("item-form").font;
  for (const f of st.fonts) { const o = document.createElement("option"); o.value = o.textContent = f; fs.append(o); }
  // the tab shown stays shown over a reload (this browser tab's session)
  const showTab = (name) => {
    for (const x of document.querySelectorAll(".tab")) x.classList.toggle("active", x.dataset.tab === name);
    $("page-wall").hidden = name !== "wall";
    $("page-litho").hidden = name !== "litho";
    sessionStorage.setItem("studio-tab", name);
  };
  for (const t of document.querySelectorAll(".tab")) t.onclick = () => showTab(t.dataset.tab);
  if (sessionStorage.getItem("studio-tab") === "litho") showTab("litho");
  $("gcode-file").onchange = (e) => e.target.files[0] && openGcode(e.target.files[0]);
  dropTarget($("drop"), openGcode);
  dropTarget($("unrolled-wrap"), (f) => (/\.(gcode|gco|g)$/i.test(f.name) || !S.gcode ? openGcode(f) : addDrawing(f)));
  $("add-text").onclick = () => addItem("text");
  $("add-braille").onclick = () => addItem("braille");
  $("add-file").onchange = (e) => { const f = e.target.files[0]; e.target.value = ""; if (f) addDrawing(f); };
  $("open-placement").onchange = (e) => { const l = [...e.target.files]; e.target.value = ""; if (l.length) openPlacement(l); };
  $("item-form").addEventListener("input", readItemForm);
  $("bulge-form").addEventListener("input", requestPreview);
  $("bulge-form").addEventListener("change", requestPreview);
  // (the printer's fields are the form's, in their own section)
  $("sec-printer").addEventListener("input", () => { printerFields(); requestPreview(); });
  $("sec-printer").addEventListener("change", () => { printerFields(); requestPreview(); });
  const deleteItem = () => { flushHistory(); S.items = S.items.filter((i) => i.id !== S.selected); select(null); requestPreview(); };
  $("delete-item").onclick = deleteItem;
  // keys, when no field has the focus: Delete removes the selected item, arrows nudge it
  // 0.5 mm (with Shift 5 mm)
  window.addEventListener("keydown", (e) => {
    const free = document.activeElement === document.body || document.activeElement === null;
    if ((e.ctrlKey || e.metaKey) && free && !$("page-wall").hidden) {
      const k = e.key.toLowerCase();
      if (k === "z" || k === "y") { e.preventDefault(); step(k === "z" && !e.shiftKey); return; }
    }
    const it = S.items.find((i) => i.id === S.selected);
    if (!it || !free || $("page-wall").hidden) return;
    if (e.key === "Delete") { e.preventDefault(); deleteItem(); return; }
    const d = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1] }[e.key];
    if (!d) return;
    e.preventDefault();
    if (!e.repeat) flushHistory();              // a held key is one step
    const k = e.shiftKey ? 5 : 0.5;
    it.at = [round2(it.at[0] + d[0] * k), round2(it.at[1] + d[1] * k)];
    delete it.placing;
    clampItem(it); fillItemForm(it); view2d.draw(); requestPreview();
  });
  $("undo").onclick = () => step(true);
  $("redo").onclick = () => step(false);
  $("export").onclick = doExport;
  $("placement").onclick = downloadPlacement;
  $("send").onclick = doSend;
  $("port").addEventListener("focus", loadPorts, { once: true });
  $("litho-file").onchange = (e) => e.target.files[0] && lithoPicture(e.target.files[0]);
  dropTarget(document.querySelector('#page-litho .drop'), lithoPicture);
  $("litho-make").onclick = makeLitho;
  $("litho-form").shape.addEventListener("change", lithoShape);
  lithoChoices(st.litho);
  if (st.litho_last) restoreLitho(st.litho_last).catch((e) => showError("litho-error", e));
  $("litho-send").onclick = sendLitho;
  $("litho-port").addEventListener("focus", loadPorts, { once: true });
  window.addEventListener("dragover", (e) => e.preventDefault());
  window.addEventListener("drop", (e) => e.preventDefault());
  for (const j of st.jobs) if (j.kind === "open") {     // a G-code given on the command line
    try {
      const res = await pollJob(j, (x) => status(`${x.label || "reading"}${x.total ? ` ${Math.round(100 * x.done / x.total)} %` : ""}`, x.total ? x.done / x.total : 0));
      setGcode(res);
      status(`${res.name}: ${res.layers} layers of outer wall`);
    } catch (e) { showError("gcode-error", e); status("Open a sliced G-code to start."); }
  }
  if (st.gcode && !S.gcode) {
    // the page was reloaded: the design comes back (asked first if it was made on another G-code)
    let d = st.design;
    if (d && st.design_gcode && st.design_gcode !== st.gcode.name
        && !keepDesignFor(st.design_gcode, st.gcode.name, (d.items || []).length)) d = null;
    if (d) {
      S.items = (d.items || []).map((it) => it.kind === "file" ? { ...it, assetKind: st.assets[it.asset] } : { ...it });
      S.nextId = 1 + Math.max(0, ...S.items.map((i) => +String(i.id).replace(/\D/g, "") || 0));
      S.gcode = st.gcode;                     // for setBulgeForm's default mode
      setBulgeForm(d.bulges || {});
      if (d.name && d.name !== st.gcode.name.replace(/\.[^.]*$/, "")) $("export-name").value = d.name;
    }
    setGcode(st.gcode, !!d);
    status(`${st.gcode.name}: ${st.gcode.layers} layers of outer wall`);
  }
  document.body.dataset.ready = "1";
}

init().catch((e) => status(`the studio did not start: ${e.message}`));
// For the browser tests and the curious: idle() is true once the page's design has been
// previewed and checked against the G-code, with no edit waiting.
const idle = () => !inFlight && !pending && checkedFor === JSON.stringify(design());
window.studio = { S, design, view2d, idle, lithoKey: () => L.key };
