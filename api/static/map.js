// The map: the workspace on its real coordinates (Leaflet), the drones with their flown tracks
// and plans, the mail not yet delivered. No base map unless the service names one.
"use strict";
(() => {
const D = (window.drona = window.drona || { state: {} });
const state = D.state;
const FINAL = new Set(["delivered", "failed", "cancelled"]);
let map = null, geo = null, groups = null, labels = null, pickNext = "pickup";

// The grid is axis aligned, x east and y north, its corner at the origin (drona_gcs/geo.py):
// corner (x, y) is at lat + y * cell_dlat, lon + x * cell_dlon.
const corner = (x, y) => [geo.lat + y * geo.cell_dlat, geo.lon + x * geo.cell_dlon];
const centre = (c) => corner(c[0] + 0.5, c[1] + 0.5);
const square = (c, inset = 0) => [corner(c[0] + inset, c[1] + inset), corner(c[0] + 1 - inset, c[1] + 1 - inset)];
const heightOf = (z) => geo.layer0_alt_m + z * geo.layer_height_m; // a layer's centre above the ground

D.colour = (id) => {
  let h = 0;
  for (const ch of id) h = (h * 31 + ch.charCodeAt(0)) >>> 0;
  return `hsl(${Math.round((h * 137.508) % 360)}, 65%, 45%)`; // golden angle: d1, d2, d3 far apart
};

function tag(layer, attrs) { // data attributes on a Leaflet path (once it is on the map)
  const el = layer.getElement && layer.getElement();
  if (el) for (const [k, v] of Object.entries(attrs)) el.setAttribute(`data-${k}`, v);
  return layer;
}

// --------------------------------------------------------------- building
function build(ws) {
  geo = ws.geo_origin;
  if (!map) create(ws);
  const bounds = L.latLngBounds(corner(0, 0), corner(ws.size[0], ws.size[1]));
  map.invalidateSize();
  map.fitBounds(bounds, { padding: [8, 8] }); // first: Leaflet adds layers only to a map with a view
  map.setMinZoom(Math.max(0, map.getZoom() - 3));
  map.getContainer().querySelector(".coords").textContent = where(L.latLng(geo.lat, geo.lon));
  buildLayers(ws);
  drawStatic(ws);
  document.getElementById("origin").textContent =
    `origin ${fmtLat(geo.lat)} ${fmtLon(geo.lon)}, ${geo.alt_m} m AMSL · cells ${ws.cell_size_m} m · ` +
    `layers ${geo.layer_height_m} m from ${geo.layer0_alt_m} m`;
}

function create(ws) {
  map = L.map("map", { zoomSnap: 0.1, maxZoom: 24, attributionControl: Boolean(ws.base_map) });
  if (ws.base_map) {
    L.tileLayer(ws.base_map.url, { attribution: ws.base_map.attribution, maxZoom: 24, maxNativeZoom: 19 }).addTo(map);
  }
  L.control.scale({ imperial: false, maxWidth: 120 }).addTo(map);
  control("topright", "north", '<svg viewBox="0 0 20 28" width="18" height="25" aria-hidden="true">' +
    '<path d="M10 1 18 26 10 20 2 26z" fill="#1d2430"/></svg><b>N</b>').addTo(map);
  const coords = control("bottomleft", "coords", "").addTo(map);
  map.on("mousemove", (e) => { coords.getContainer().textContent = where(e.latlng); });
  groups = {};
  for (const name of ["cells", "mail", "tracks", "plans", "drones"]) groups[name] = L.layerGroup().addTo(map);
  labels = L.DomUtil.create("div", "labels", map.getContainer());
  map.on("click", (e) => pick(e.latlng));
  map.on("zoomend moveend resize", placeLabels);
  D.leaflet = map;
}

function control(position, className, html) {
  const c = L.control({ position });
  c.onAdd = () => { const el = L.DomUtil.create("div", `leaflet-control ${className}`); el.innerHTML = html; return el; };
  return c;
}

function buildLayers(ws) {
  const box = document.getElementById("layers");
  box.replaceChildren();
  for (let z = 0; ws.size[2] > 1 && z < ws.size[2]; z++) {
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = `z${z} · ${heightOf(z)} m`;
    b.setAttribute("aria-pressed", String(z === state.layer));
    b.addEventListener("click", () => { state.layer = z; buildLayers(ws); drawStatic(ws); D.render(); });
    box.appendChild(b);
  }
}

function drawStatic(ws) {
  const [nx, ny] = ws.size, g = groups.cells;
  g.clearLayers();
  const lines = [];
  for (let x = 0; x <= nx; x++) lines.push([corner(x, 0), corner(x, ny)]);
  for (let y = 0; y <= ny; y++) lines.push([corner(0, y), corner(nx, y)]);
  L.polyline(lines, { className: "grid", interactive: false }).addTo(g);
  drawObstacles(ws, g);
  const here = (c) => c[2] === state.layer;
  for (const c of ws.parking.filter(here)) {
    L.rectangle(square(c, 0.18), { className: "parking" }).bindTooltip(`parking [${c}]`).addTo(g);
  }
  for (const c of ws.charging_stations.filter(here)) {
    L.rectangle(square(c, 0.1), { className: "charger" }).bindTooltip(`charger [${c}]`).addTo(g);
  }
}

// Each column with an obstacle: dark where it blocks the layer shown, light where it blocks others only;
// its tooltip gives the layers it blocks and how high it reaches.
function drawObstacles(ws, g) {
  const columns = new Map();
  for (const [x, y, z] of ws.obstacles) {
    const key = `${x},${y}`;
    if (!columns.has(key)) columns.set(key, { x, y, zs: [] });
    columns.get(key).zs.push(z);
  }
  for (const { x, y, zs } of columns.values()) {
    zs.sort((a, b) => a - b);
    const top = heightOf(zs[zs.length - 1]) + geo.layer_height_m / 2;
    const here = zs.includes(state.layer);
    const text = `obstacle [${x}, ${y}]: layer${zs.length > 1 ? "s" : ""} ${zs.join(", ")} of ${ws.size[2]}, ` +
      `up to ${top.toFixed(1)} m above the ground`;
    const rect = L.rectangle(square([x, y]), { className: here ? "obstacle" : "obstacle other-layer",
                                               fillOpacity: here ? 0.85 : 0.15 + 0.5 * zs.length / ws.size[2] });
    tag(rect.bindTooltip(text).addTo(g), { x, y, layers: zs.join(" "), top: top.toFixed(1) });
  }
}

// ---------------------------------------------------------------- drawing
function draw() {
  if (!map) return;
  for (const name of ["mail", "tracks", "plans", "drones"]) groups[name].clearLayers();
  drawMail();
  const drones = [...state.drones.values()].sort((a, b) => (a.id < b.id ? -1 : 1));
  for (const d of drones) drawTrack(d);
  for (const d of drones) drawPlan(d);
  for (const d of drones) drawDrone(d);
  placeLabels();
}

function drawMail() {
  const open = [...state.mail.values()].filter((m) => !FINAL.has(m.status)).slice(0, 300);
  for (const m of open) {
    const other = (c) => (c[2] === state.layer ? "" : " other-layer");
    const p = L.circleMarker(centre(m.pickup), { radius: 6, className: `marker pickup${other(m.pickup)}` });
    const q = L.rectangle(square(m.dropoff, 0.3), { className: `marker dropoff${other(m.dropoff)}` });
    for (const layer of [p, q]) {
      layer.bindTooltip(`${m.id} (${m.status}) priority ${m.priority}`).addTo(groups.mail);
      tag(layer, { id: m.id, status: m.status });
    }
  }
}

function drawTrack(d) {
  const track = state.tracks.get(d.id) || [];
  if (track.length < 2) return;
  tag(L.polyline(track, { className: "track", color: D.colour(d.id), interactive: false }).addTo(groups.tracks),
      { drone: d.id, points: track.length });
}

function drawPlan(d) {
  if (!d.trajectory || d.trajectory.cells.length < 2 || D.staleFor(d) != null) return;
  const line = L.polyline(d.trajectory.cells.map(centre), { className: "traj", color: D.colour(d.id) });
  tag(line.bindTooltip(`${d.id}: plan from step ${d.trajectory.start_step}`).addTo(groups.plans), { drone: d.id });
}

function drawDrone(d) {
  const stale = D.staleFor(d) != null;
  const dot = L.circleMarker([d.position.lat, d.position.lon], {
    radius: 8, className: `drone${stale ? " stale" : ""}${d.cell[2] === state.layer ? "" : " other-layer"}`,
    fillColor: stale ? "#a0aec0" : D.colour(d.id), fillOpacity: 1 });
  dot.bindTooltip(() => D.panels.droneSummary(d));
  tag(dot.addTo(groups.drones), { id: d.id, stale: String(stale), battery: d.battery_pct });
}

// ------------------------------------------------------------------ labels
// One label per drone, placed where it overlaps no other label and no drone and stays inside the map;
// where no place is free it is hidden (the drone list, keyed by the same colours, still names it).
const OFFSETS = [[1, 0], [-1, 0], [0, -1], [0, 1], [1, -1], [1, 1], [-1, -1], [-1, 1]];

function placeLabels() {
  if (!map) return;
  const size = map.getSize();
  const drones = [...state.drones.values()].sort((a, b) => (a.id < b.id ? -1 : 1));
  const points = drones.map((d) => map.latLngToContainerPoint([d.position.lat, d.position.lon]));
  const taken = points.map((p) => ({ x: p.x - 9, y: p.y - 9, w: 18, h: 18 })).concat(controlBoxes());
  const keep = new Set(drones.map((d) => d.id));
  for (const el of [...labels.children]) if (!keep.has(el.dataset.id)) el.remove();
  drones.forEach((d, i) => {
    const el = labelFor(d);
    const spot = freeSpot(points[i], el.offsetWidth, el.offsetHeight, size, taken);
    el.hidden = spot === null;
    el.dataset.hidden = String(spot === null);
    if (spot) { taken.push(spot); el.style.transform = `translate(${spot.x}px, ${spot.y}px)`; }
  });
}

function controlBoxes() { // zoom, north, scale, coordinates: a label under one would be hidden
  const origin = map.getContainer().getBoundingClientRect();
  return [...map.getContainer().querySelectorAll(".leaflet-control")].map((c) => {
    const r = c.getBoundingClientRect();
    return { x: r.left - origin.left, y: r.top - origin.top, w: r.width, h: r.height };
  });
}

function labelFor(d) {
  let el = labels.querySelector(`[data-id="${CSS.escape(d.id)}"]`);
  if (!el) { el = L.DomUtil.create("div", "label", labels); el.dataset.id = d.id; }
  const age = D.staleFor(d);
  el.textContent = age != null ? `${d.id} · stale ${D.ago(age)}` : `${d.id} · ${D.panels.altitude(d)}`;
  el.hidden = false;
  el.classList.toggle("stale", age != null);
  el.style.borderColor = D.colour(d.id);
  return el;
}

function freeSpot(p, w, h, size, taken) {
  for (const reach of [12, 28, 48]) {
    for (const [ox, oy] of OFFSETS) {
      const x = p.x + ox * reach - (ox < 0 ? w : ox === 0 ? w / 2 : 0);
      const y = p.y + oy * reach - (oy < 0 ? h : oy === 0 ? h / 2 : 0);
      const box = { x, y, w, h };
      if (x >= 2 && y >= 2 && x + w <= size.x - 2 && y + h <= size.y - 2 && !taken.some((t) => overlap(t, box))) {
        return box;
      }
    }
  }
  return null;
}

const overlap = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;

// -------------------------------------------------------------------- misc
function cellAt(latlng) {
  return [Math.floor((latlng.lng - geo.lon) / geo.cell_dlon), Math.floor((latlng.lat - geo.lat) / geo.cell_dlat)];
}

function where(latlng) {
  const [x, y] = cellAt(latlng);
  const [nx, ny] = state.ws.size;
  const cell = x >= 0 && y >= 0 && x < nx && y < ny ? ` · cell [${x}, ${y}, ${state.layer}]` : "";
  return `${fmtLat(latlng.lat)} ${fmtLon(latlng.lng)}${cell}`;
}

const fmtLat = (v) => `${Math.abs(v).toFixed(6)}° ${v < 0 ? "S" : "N"}`;
const fmtLon = (v) => `${Math.abs(v).toFixed(6)}° ${v < 0 ? "W" : "E"}`;

function pick(latlng) {
  const [x, y] = cellAt(latlng);
  const [nx, ny] = state.ws.size;
  if (x < 0 || y < 0 || x >= nx || y >= ny) return;
  const form = document.getElementById("mail-form");
  const prefix = pickNext === "pickup" ? "p" : "d";
  form[`${prefix}x`].value = x; form[`${prefix}y`].value = y; form[`${prefix}z`].value = state.layer;
  pickNext = pickNext === "pickup" ? "dropoff" : "pickup";
}

D.map = { build, draw, placeLabels, corner, centre };
})();
