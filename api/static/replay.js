// drona replay: plays a recorded run back on its workspace's real coordinates (Leaflet, vendored).
// The document (frames, drona audit's findings, geometry) comes from `drona replay` at replay.json,
// or from the URL in ?doc=. Nothing here judges the run: the findings are the audit's.
"use strict";

const COLOURS = ["#1565c0", "#2e7d32", "#6a1b9a", "#00838f", "#ad1457", "#4e342e", "#283593", "#558b2f"];
const TRACK_STEPS = 10; // how many steps of flown track each drone trails
const LIST_LIMIT = 1000; // a long run can have thousands of steps off the plan: list the first ones

const state = { doc: null, step: 0, timer: null, map: null, drones: new Map(), marks: null, current: -1 };
const $ = (sel) => document.querySelector(sel);

// ------------------------------------------------------------------ geometry
// The local tangent plane of drona_gcs/geo.py: latitude is linear in north, longitude in east,
// so a cell's corners interpolate exactly between the grid's outer corners.
function corner(x, y) {
  const ws = state.doc.workspace, g = ws.grid;
  return [g.south + (g.north - g.south) * y / ws.size[1], g.west + (g.east - g.west) * x / ws.size[0]];
}
const cellBounds = (c) => [corner(c[0], c[1]), corner(c[0] + 1, c[1] + 1)];
const centre = (c) => corner(c[0] + 0.5, c[1] + 0.5);
const cellText = (c) => (c ? `[${c.join(", ")}]` : "none");

function frameAt(step) {
  return state.doc.frames[step - state.doc.first_step];
}

// ------------------------------------------------------------------ the map
function buildMap() {
  const map = L.map("map", { zoomSnap: 0.25, maxZoom: 24, attributionControl: false });
  state.map = map;
  // Panes bottom up: the workspace, then the findings, then the drones (Leaflet's overlay pane, 400),
  // so a marked cell never hides a drone and an obstacle never hides a mark.
  map.createPane("ground").style.zIndex = "350";
  map.createPane("findings").style.zIndex = "380";
  const ws = state.doc.workspace;
  const whole = [corner(0, 0), corner(ws.size[0], ws.size[1])];
  L.rectangle(whole, { pane: "ground", color: "#7a8391", weight: 1, fill: false, interactive: false }).addTo(map);
  gridLines(ws).forEach((line) => L.polyline(line, { pane: "ground", color: "#c3c9d1", weight: 0.5,
    interactive: false }).addTo(map));
  drawObstacles(ws);
  drawPoints(ws.charging_stations, "charger", "#2e7d32", "charging station");
  drawPoints(ws.parking, "parking", "#7a8391", "parking");
  drawPoints(ws.pickups, "pickup", "#1565c0", "pickup");
  drawPoints(ws.dropoffs, "dropoff", "#ad1457", "drop-off");
  L.control.scale({ imperial: false, maxWidth: 160 }).addTo(map);
  addControl("topright", "north", "N &uarr;");
  const coords = addControl("bottomright", "coords", "");
  map.on("mousemove", (e) => { coords.textContent = `${e.latlng.lat.toFixed(6)}, ${e.latlng.lng.toFixed(6)}`; });
  state.marks = L.layerGroup().addTo(map);
  const fit = () => map.fitBounds(whole, { padding: [12, 12], animate: false });
  fit();
  // A phone turned, or a window narrowed: the whole grid stays in view.
  new ResizeObserver(() => { map.invalidateSize(); fit(); }).observe($("#map"));
}

function gridLines(ws) {
  const [nx, ny] = ws.size, lines = [];
  for (let x = 1; x < nx; x++) lines.push([corner(x, 0), corner(x, ny)]);
  for (let y = 1; y < ny; y++) lines.push([corner(0, y), corner(nx, y)]);
  return lines;
}

// An obstacle column is darker the more of its layers it fills.
function drawObstacles(ws) {
  const columns = new Map();
  for (const [x, y, z] of ws.obstacles) {
    const key = `${x},${y}`;
    columns.set(key, [...(columns.get(key) || []), z]);
  }
  for (const [key, layers] of columns) {
    const [x, y] = key.split(",").map(Number);
    const shade = 0.3 + 0.6 * layers.length / ws.size[2];
    L.rectangle(cellBounds([x, y, 0]), { pane: "ground", className: "obstacle", weight: 0, fillOpacity: shade })
      .bindTooltip(`obstacle [${x}, ${y}], layers ${layers.sort((a, b) => a - b).join(", ")}`)
      .addTo(state.map);
  }
}

function drawPoints(cells, kind, colour, name) {
  for (const c of cells) {
    L.rectangle(cellBounds(c), { pane: "ground", className: kind, color: colour, weight: 2, fill: false,
      dashArray: "4 3" })
      .bindTooltip(`${name} ${cellText(c)}`).addTo(state.map);
  }
}

function addControl(position, className, html) {
  const control = L.control({ position });
  const div = L.DomUtil.create("div", className);
  div.innerHTML = html;
  control.onAdd = () => div;
  control.addTo(state.map);
  return div;
}

function buildDrones() {
  state.doc.drones.forEach((id, i) => {
    const colour = COLOURS[i % COLOURS.length];
    const track = L.polyline([], { className: "track", color: colour, weight: 2, opacity: 0.6 }).addTo(state.map);
    const marker = L.circleMarker([0, 0], { className: "drone", radius: 7, color: colour, fillColor: colour,
      fillOpacity: 0.85, weight: 2 }).addTo(state.map);
    marker.getElement().setAttribute("data-id", id);
    marker.bindTooltip(id, { permanent: true, direction: "right", offset: [8, 0], className: "drone-label" });
    state.drones.set(id, { colour, track, marker });
  });
}

// ------------------------------------------------------------------ one step
function show(step) {
  const doc = state.doc;
  step = Math.max(doc.first_step, Math.min(doc.last_step, step));
  state.step = step;
  $("#step").value = String(step);
  document.body.dataset.step = String(step);
  // Steps count from the fleet's epoch: time is shown from the record's first step.
  const seconds = ((step - doc.first_step) * doc.workspace.tau_s).toFixed(1);
  $("#step-label").textContent = `step ${step} (+${seconds} s) of ${doc.first_step}..${doc.last_step}`;
  const frame = frameAt(step);
  const offsets = spread(frame);
  for (const [id, d] of state.drones) moveDrone(id, d, frame.drones[id], step, offsets.get(id));
  markFindings(step);
  fillTable(frame);
  highlightListed(step);
}

// Drones sharing a cell (a collision, or one seen late) sit apart within it, so each stays visible.
function spread(frame) {
  const byCell = new Map();
  for (const id of state.drones.keys()) {
    const key = frame.drones[id].cell.join(",");
    byCell.set(key, [...(byCell.get(key) || []), id]);
  }
  const at = new Map();
  for (const ids of byCell.values()) {
    ids.forEach((id, i) => {
      const angle = (2 * Math.PI * i) / ids.length, r = ids.length > 1 ? 0.25 : 0;
      at.set(id, [r * Math.cos(angle), r * Math.sin(angle)]);
    });
  }
  return at;
}

function moveDrone(id, d, now, step, offset) {
  const z = now.cell[2], [dx, dy] = offset;
  Object.assign(d.marker.getTooltip().options, { direction: dx < 0 ? "left" : "right", offset: [dx < 0 ? -8 : 8, 0] });
  d.marker.setLatLng(corner(now.cell[0] + 0.5 + dx, now.cell[1] + 0.5 + dy));
  d.marker.getElement().classList.toggle("unseen", !now.seen);
  d.marker.setTooltipContent(state.doc.workspace.size[2] > 1 ? `${id} z${z}` : id);
  const from = Math.max(state.doc.first_step, step - TRACK_STEPS);
  const points = [];
  for (let k = from; k <= step; k++) points.push(centre(frameAt(k).drones[id].cell));
  d.track.setLatLngs(points);
}

// The audit's findings at this very step, drawn on the cells they name.
function markFindings(step) {
  state.marks.clearLayers();
  state.doc.findings.forEach((f, i) => {
    if (f.step !== step) return;
    for (const c of f.cells) {
      const mark = L.rectangle(cellBounds(c), { pane: "findings", className: `violation ${f.family} ${f.kind}`,
        weight: 3 })
        .bindTooltip(f.text);
      state.marks.addLayer(mark);
      const el = mark.getElement();
      el.setAttribute("data-finding", String(i));
      el.setAttribute("data-cell", JSON.stringify(c));
    }
  });
}

function fillTable(frame) {
  const alts = state.doc.workspace.layers_alt_m;
  const rows = [...state.drones].map(([id, d]) => {
    const now = frame.drones[id];
    const tr = document.createElement("tr");
    tr.className = now.seen ? "" : "unseen";
    tr.title = now.seen ? "" : "no record at this step: held where it was last seen";
    const cells = [id, cellText(now.cell), alts[now.cell[2]]?.toFixed(1) ?? "?", cellText(now.planned)];
    cells.forEach((text, k) => {
      const td = document.createElement("td");
      if (k === 0) {
        const dot = document.createElement("span");
        dot.className = "swatch";
        dot.style.background = d.colour;
        td.append(dot);
      }
      td.append(text);
      tr.append(td);
    });
    return tr;
  });
  $("#drones tbody").replaceChildren(...rows);
}

// ------------------------------------------------------------------ findings list
function buildList() {
  const family = $("#family").value;
  const shown = state.doc.findings.map((f, i) => [f, i]).filter(([f]) => family === "all" || f.family === family);
  const items = shown.slice(0, LIST_LIMIT).map(([f, i]) => {
    const li = document.createElement("li");
    li.dataset.step = String(f.step);
    const button = document.createElement("button");
    button.type = "button";
    button.className = `finding ${f.family} ${f.kind}`;
    button.dataset.index = String(i);
    const kind = document.createElement("span");
    kind.className = "kind";
    kind.textContent = `step ${f.step} · ${f.kind} · ${f.drones.join(", ")}`;
    const text = document.createElement("span");
    text.className = "text";
    text.textContent = f.text;
    button.append(kind, text);
    button.addEventListener("click", () => { pause(); show(f.step); });
    li.append(button);
    return li;
  });
  $("#findings").replaceChildren(...items);
  const more = $("#more");
  more.hidden = shown.length <= LIST_LIMIT;
  more.textContent = `the first ${LIST_LIMIT} of ${shown.length} listed; the slider's ticks show them all`;
  highlightListed(state.step);
}

function highlightListed(step) {
  for (const li of document.querySelectorAll("#findings li")) {
    li.classList.toggle("current", Number(li.dataset.step) === step);
  }
}

function buildTicks() {
  const doc = state.doc, span = Math.max(1, doc.last_step - doc.first_step), seen = new Set();
  const ticks = [];
  for (const f of doc.findings) {
    const key = `${f.step}/${f.family}`;
    if (seen.has(key)) continue;
    seen.add(key);
    const tick = document.createElement("span");
    tick.className = f.family;
    // the range's track is inset by half its thumb (about 8 px) at each end
    tick.style.left = `calc(8px + (100% - 16px) * ${(f.step - doc.first_step) / span})`;
    ticks.push(tick);
  }
  $("#ticks").replaceChildren(...ticks);
}

// ------------------------------------------------------------------ time
function play() {
  if (state.step >= state.doc.last_step) show(state.doc.first_step);
  const interval = (1000 * state.doc.workspace.tau_s) / Number($("#speed").value);
  state.timer = setInterval(() => {
    if (state.step >= state.doc.last_step) pause();
    else show(state.step + 1);
  }, interval);
  $("#play").textContent = "Pause";
  $("#play").setAttribute("aria-pressed", "true");
}

function pause() {
  clearInterval(state.timer);
  state.timer = null;
  $("#play").textContent = "Play";
  $("#play").setAttribute("aria-pressed", "false");
}

function wireControls() {
  const slider = $("#step");
  slider.min = String(state.doc.first_step);
  slider.max = String(state.doc.last_step);
  slider.addEventListener("input", () => show(Number(slider.value)));
  $("#play").addEventListener("click", () => (state.timer ? pause() : play()));
  $("#prev").addEventListener("click", () => { pause(); show(state.step - 1); });
  $("#next").addEventListener("click", () => { pause(); show(state.step + 1); });
  $("#speed").addEventListener("change", () => { if (state.timer) { pause(); play(); } });
  $("#family").addEventListener("change", buildList);
  document.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    if (e.key === "ArrowLeft") { pause(); show(state.step - 1); }
    if (e.key === "ArrowRight") { pause(); show(state.step + 1); }
    if (e.key === " ") { e.preventDefault(); state.timer ? pause() : play(); }
  });
}

function describe() {
  const doc = state.doc, s = doc.summary, ws = doc.workspace;
  $("#title").textContent = `${ws.name} (${ws.grid.south.toFixed(5)}, ${ws.grid.west.toFixed(5)}): ` +
    `${doc.drones.length} drones, delta ${ws.delta}`;
  const verdict = $("#verdict");
  verdict.dataset.safe = String(s.safe);
  const plural = (n, word) => `${n} ${word}${n === 1 ? "" : "s"}`;
  verdict.textContent = `${s.safe ? "safe" : plural(s.violations, "separation violation")}; ` +
    `${(100 * s.conformance).toFixed(1)}% of ${s.planned_steps} planned steps in the planned cell; ` +
    `${plural(s.jumps, "jump")}`;
  $("#count").textContent = `(${doc.findings.length})`;
}

function fail(message) {
  const box = $("#error");
  box.hidden = false;
  box.textContent = message;
  $("#verdict").textContent = "no replay";
}

async function main() {
  const url = new URLSearchParams(location.search).get("doc") || "replay.json";
  try {
    const res = await fetch(url, { cache: "no-store" });
    if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
    state.doc = await res.json();
  } catch (err) {
    fail(`could not load the replay document: ${err.message}`);
    return;
  }
  describe();
  buildMap();
  buildDrones();
  wireControls();
  buildTicks();
  buildList();
  show(state.doc.first_step);
  document.body.dataset.ready = "true";
}

main();
