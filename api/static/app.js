// drona-gcs dashboard: the live map, the mail form and the request list.
// Plain JS, no dependencies. Live updates come from /v1/events (server-sent events);
// EventSource cannot send headers, so the token goes as ?access_token= there only.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const FINAL = new Set(["delivered", "failed", "cancelled"]);
const SHOWN_FINISHED = 30; // finished requests kept on the map
const state = { token: "", ws: null, layer: 0, drones: new Map(), mail: new Map(), source: null, pick: "pickup" };
window.drona = state; // for the curious (and the browser test)

const $ = (sel) => document.querySelector(sel);

// ------------------------------------------------------------------ API
async function api(path, options = {}) {
  const headers = { Authorization: `Bearer ${state.token}`, ...(options.headers || {}) };
  const res = await fetch(path, { ...options, headers });
  const body = res.headers.get("content-type")?.includes("json") ? await res.json() : await res.text();
  if (!res.ok) throw new Error(describeError(res.status, body));
  return body;
}

function describeError(status, body) {
  if (body && Array.isArray(body.detail)) {
    return body.detail.map((e) => `${e.loc.filter((p) => p !== "body").join(".")}: ${e.msg}`).join("; ");
  }
  return `${status}: ${body && body.detail ? body.detail : body}`;
}

function setConn(text, live) {
  const el = $("#conn");
  el.textContent = text;
  el.dataset.state = live ? "live" : "offline";
}

// ------------------------------------------------------------- connect
async function connect() {
  if (state.source) state.source.close();
  state.drones.clear();
  state.mail.clear();
  try {
    state.ws = await api("/v1/workspace");
  } catch (err) {
    setConn(`not connected: ${err.message}`, false);
    return;
  }
  buildStatic();
  const source = new EventSource(`/v1/events?access_token=${encodeURIComponent(state.token)}`);
  state.source = source;
  source.addEventListener("open", () => { setConn("live", true); resync(); });
  source.addEventListener("error", () => setConn("reconnecting…", false));
  source.addEventListener("drone", (ev) => { const d = JSON.parse(ev.data); state.drones.set(d.id, d); render(); });
  source.addEventListener("drone_lost", (ev) => { state.drones.delete(JSON.parse(ev.data).id); render(); });
  source.addEventListener("mail", (ev) => { upsertMail(JSON.parse(ev.data)); render(); });
}

async function resync() {
  try {
    const [fleet, page] = await Promise.all([api("/v1/fleet"), api("/v1/mail?limit=200")]);
    state.drones = new Map(fleet.drones.map((d) => [d.id, d]));
    for (const m of page.items) upsertMail(m);
    render();
  } catch (err) {
    setConn(`live, but: ${err.message}`, false);
  }
}

function upsertMail(m) {
  const known = state.mail.get(m.id);
  if (!known || known.updated_at <= m.updated_at) state.mail.set(m.id, m);
}

// ----------------------------------------------------------------- map
const cellX = (c) => c[0];
const cellY = (c) => state.ws.size[1] - 1 - c[1]; // north up

function el(name, attrs = {}, parent = null) {
  const node = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (parent) parent.appendChild(node);
  return node;
}

function buildStatic() {
  const [nx, ny, nz] = state.ws.size;
  const svg = $("#map");
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${nx} ${ny}`);
  $("#ws-name").textContent = `${state.ws.name}: ${nx}×${ny}×${nz}, τ ${state.ws.tau_s} s, Δ ${state.ws.delta}`;
  const layers = $("#layers");
  layers.replaceChildren();
  for (let z = 0; nz > 1 && z < nz; z++) {
    const b = document.createElement("button");
    b.textContent = `z=${z}`;
    b.setAttribute("aria-pressed", String(z === state.layer));
    b.addEventListener("click", () => { state.layer = z; buildStatic(); render(); });
    layers.appendChild(b);
  }
  const grid = el("g", { class: "grid" }, svg);
  for (let x = 0; x <= nx; x++) el("line", { x1: x, y1: 0, x2: x, y2: ny }, grid);
  for (let y = 0; y <= ny; y++) el("line", { x1: 0, y1: y, x2: nx, y2: y }, grid);
  const onLayer = (c) => c[2] === state.layer;
  const d = state.ws.obstacles.filter(onLayer).map((c) => `M${cellX(c)} ${cellY(c)}h1v1h-1z`).join("");
  el("path", { class: "obstacles", d }, svg);
  for (const c of state.ws.parking.filter(onLayer)) {
    el("rect", { class: "parking", x: cellX(c) + 0.15, y: cellY(c) + 0.15, width: 0.7, height: 0.7 }, svg);
  }
  for (const c of state.ws.charging_stations.filter(onLayer)) {
    el("rect", { class: "charger", x: cellX(c) + 0.1, y: cellY(c) + 0.1, width: 0.8, height: 0.8, rx: 0.15 }, svg);
  }
  state.dynamic = el("g", { id: "dynamic" }, svg);
  svg.onclick = (ev) => pickCell(ev, svg);
}

let frame = 0;
function render() {
  if (!frame) frame = requestAnimationFrame(() => { frame = 0; draw(); });
}

function draw() {
  if (!state.ws) return;
  const g = state.dynamic;
  g.replaceChildren();
  drawMarkers(g);
  for (const d of state.drones.values()) drawTrajectory(g, d);
  for (const d of state.drones.values()) drawDrone(g, d);
  fillDroneTable();
  fillMailTable();
}

function shownMail() {
  const all = [...state.mail.values()].sort((a, b) => (a.created_at < b.created_at ? 1 : -1));
  const finished = all.filter((m) => FINAL.has(m.status)).slice(0, SHOWN_FINISHED);
  return all.filter((m) => !FINAL.has(m.status)).concat(finished);
}

function drawMarkers(g) {
  for (const m of shownMail()) {
    const attrs = (c) => ({ "data-id": m.id, "data-status": m.status,
                            class: `marker ${c[2] === state.layer ? "" : "other-layer"}` });
    const p = el("circle", { ...attrs(m.pickup), r: 0.28, cx: cellX(m.pickup) + 0.5, cy: cellY(m.pickup) + 0.5 }, g);
    p.classList.add("pickup");
    const q = el("rect", { ...attrs(m.dropoff), x: cellX(m.dropoff) + 0.22, y: cellY(m.dropoff) + 0.22,
                           width: 0.56, height: 0.56 }, g);
    q.classList.add("dropoff");
    for (const node of [p, q]) el("title", {}, node).textContent = `${m.id} (${m.status}) priority ${m.priority}`;
  }
}

function colour(id) {
  let h = 0;
  for (const ch of id) h = (h * 31 + ch.charCodeAt(0)) >>> 0;
  return `hsl(${Math.round((h * 137.508) % 360)}, 60%, 62%)`; // golden angle: d1, d2, d3 far apart
}

function drawTrajectory(g, d) {
  if (!d.trajectory || d.trajectory.cells.length < 2) return;
  const points = d.trajectory.cells.map((c) => `${cellX(c) + 0.5},${cellY(c) + 0.5}`).join(" ");
  el("polyline", { class: "traj", points, stroke: colour(d.id), "data-drone": d.id }, g);
}

function drawDrone(g, d) {
  const x = cellX(d.cell) + 0.5, y = cellY(d.cell) + 0.5;
  const group = el("g", { class: `drone ${d.cell[2] === state.layer ? "" : "other-layer"}`, "data-id": d.id,
                          "data-battery": d.battery_pct }, g);
  el("circle", { cx: x, cy: y, r: 0.36, fill: d.health.ok ? colour(d.id) : "#e53e3e" }, group);
  // The label goes right of the drone, or left where it would run off the map (about 0.24 a character).
  const leftward = x + 0.42 + 0.24 * d.id.length > state.ws.size[0];
  const label = leftward ? { x: x - 0.42, y: y - 0.1, "text-anchor": "end" } : { x: x + 0.42, y: y - 0.1 };
  el("text", label, group).textContent = d.id;
  el("rect", { class: "batt-bg", x: x - 0.4, y: y + 0.42, width: 0.8, height: 0.12 }, group);
  el("rect", { class: `batt ${d.battery_pct < 40 ? "low" : ""}`, x: x - 0.4, y: y + 0.42,
               width: 0.8 * Math.max(0, Math.min(100, d.battery_pct)) / 100, height: 0.12 }, group);
  el("title", {}, group).textContent = `${d.id}: ${d.battery_pct.toFixed(0)}% ${d.phase} ${d.mode}`;
}

function pickCell(ev, svg) {
  const pt = svg.createSVGPoint();
  pt.x = ev.clientX; pt.y = ev.clientY;
  const p = pt.matrixTransform(svg.getScreenCTM().inverse());
  const x = Math.floor(p.x), y = state.ws.size[1] - 1 - Math.floor(p.y);
  const form = $("#mail-form");
  const prefix = state.pick === "pickup" ? "p" : "d";
  form[`${prefix}x`].value = x; form[`${prefix}y`].value = y; form[`${prefix}z`].value = state.layer;
  state.pick = state.pick === "pickup" ? "dropoff" : "pickup";
}

// -------------------------------------------------------------- tables
function cell(c) { return `[${c.join(",")}]`; }

function fillDroneTable() {
  const rows = [...state.drones.values()].sort((a, b) => (a.id < b.id ? -1 : 1)).map((d) => {
    const tr = document.createElement("tr");
    tr.dataset.id = d.id;
    for (const text of [d.id, cell(d.cell), `${d.battery_pct.toFixed(0)}%`, d.phase,
                        d.health.ok ? "ok" : d.health.alarms.join(", ")]) {
      tr.appendChild(document.createElement("td")).textContent = text;
    }
    return tr;
  });
  $("#drones tbody").replaceChildren(...rows);
}

function fillMailTable() {
  const rows = shownMail().slice(0, 200).map((m) => {
    const tr = document.createElement("tr");
    tr.dataset.id = m.id;
    tr.dataset.status = m.status;
    const cells = [m.id, m.status, String(m.priority), `${cell(m.pickup)} → ${cell(m.dropoff)}`, m.drone || ""];
    cells.forEach((text, i) => {
      const td = tr.appendChild(document.createElement("td"));
      td.textContent = text;
      if (i === 1) { td.className = "status"; td.title = m.reason; }
    });
    const act = tr.appendChild(document.createElement("td"));
    if (m.status === "queued" || m.status === "assigned") {
      const b = act.appendChild(document.createElement("button"));
      b.textContent = "cancel";
      b.addEventListener("click", () => cancel(m.id));
    }
    return tr;
  });
  $("#mail tbody").replaceChildren(...rows);
}

// --------------------------------------------------------------- forms
function message(text, kind) {
  const el = $("#form-msg");
  el.textContent = text;
  el.dataset.kind = kind;
}

async function submitMail(ev) {
  ev.preventDefault();
  const f = ev.target;
  const int = (name) => Number.parseInt(f[name].value, 10);
  const body = { pickup: [int("px"), int("py"), int("pz")], dropoff: [int("dx"), int("dy"), int("dz")],
                 priority: int("priority") };
  if (f.note.value) body.note = f.note.value;
  try {
    const m = await api("/v1/mail", { method: "POST", body: JSON.stringify(body),
                                      headers: { "Content-Type": "application/json" } });
    upsertMail(m);
    render();
    message(`${m.id} ${m.status}`, "ok");
  } catch (err) {
    message(err.message, "error");
  }
}

async function cancel(id) {
  try {
    upsertMail(await api(`/v1/mail/${encodeURIComponent(id)}/cancel`, { method: "POST" }));
    render();
  } catch (err) {
    message(err.message, "error");
  }
}

$("#token-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.token = $("#token").value.trim();
  localStorage.setItem("drona-token", state.token);
  connect();
});
$("#mail-form").addEventListener("submit", submitMail);

state.token = new URLSearchParams(location.hash.slice(1)).get("token") || localStorage.getItem("drona-token") || "";
$("#token").value = state.token;
if (state.token) connect(); else setConn("enter a token", false);
