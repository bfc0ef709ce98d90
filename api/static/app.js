// drona-gcs dashboard: the connection (token, live events, readiness) and the page's state.
// Plain JS on vendored Leaflet and Chart.js; nothing is fetched from outside the service.
// map.js draws the map, panels.js the lists, commands.js the fleet commands, charts.js the charts;
// this file runs them.
// Live updates come from /v1/events (server-sent events); EventSource cannot send headers,
// so the token goes as ?access_token= there only.
"use strict";
(() => {
const D = window.drona;
const state = Object.assign(D.state, {
  token: "", ws: null, layer: 0, source: null,
  drones: new Map(), mail: new Map(), alarms: new Map(), log: [],
  tracks: new Map(), // drone -> [[lat, lon], ...]: where it was, newest last
  conn: { sse: false, fleet: null, auth: true, error: "" },
});
window.state = state; // for the curious (and the browser test)
const TRACK_STEPS = 40; // positions kept per drone
const $ = (sel) => document.querySelector(sel);

// ------------------------------------------------------------------ API
class ApiError extends Error {
  constructor(status, message) { super(message); this.status = status; }
}

async function api(path, options = {}) {
  const headers = { Authorization: `Bearer ${state.token}`, ...(options.headers || {}) };
  const res = await fetch(path, { ...options, headers });
  const body = res.headers.get("content-type")?.includes("json") ? await res.json() : await res.text();
  if (res.status === 401) tokenRefused();
  if (!res.ok) throw new ApiError(res.status, describeError(res.status, body));
  return body;
}
D.api = api;

function describeError(status, body) {
  if (body && Array.isArray(body.detail)) {
    return body.detail.map((e) => `${e.loc.filter((p) => p !== "body").join(".")}: ${e.msg}`).join("; ");
  }
  return `${status}: ${body && body.detail ? body.detail : body}`;
}

// ---------------------------------------------------------- connection
// "live" needs all three: the token taken, the event stream open, and the fleet reachable (/readyz).
function showConn() {
  const { sse, fleet, auth, error } = state.conn;
  let text = "live", kind = "live";
  if (!state.token) [text, kind] = ["enter a token", "offline"];
  else if (!auth) [text, kind] = ["token refused", "offline"];
  else if (!sse) [text, kind] = [error ? `reconnecting… (${error})` : "connecting…", "offline"];
  else if (fleet === false) [text, kind] = ["fleet unreachable", "degraded"];
  else if (fleet === null) [text, kind] = ["service unreachable", "offline"];
  const el = $("#conn");
  el.textContent = text;
  el.dataset.state = kind;
  document.body.classList.toggle("locked", !auth || !state.token);
}
D.showConn = showConn;

function askToken(message) {
  $("#token-panel").hidden = false;
  $("#token-msg").textContent = message;
  $("#token").focus();
}

function tokenRefused() {
  if (state.source) state.source.close();
  state.source = null;
  state.conn = { ...state.conn, auth: false, sse: false };
  showConn();
  askToken("The service refused this token (it may have restarted with new ones): enter it again.");
}

async function connect() {
  if (state.source) state.source.close();
  state.conn = { sse: false, fleet: state.conn.fleet, auth: true, error: "" };
  showConn();
  try {
    state.ws = await api("/v1/workspace");
  } catch (err) {
    if (err.status !== 401) retryLater(err.message);
    return;
  }
  $("#token-panel").hidden = true;
  D.map.build(state.ws);
  D.panels.buildFilters();
  openStream();
}

function openStream() {
  const source = new EventSource(`/v1/events?access_token=${encodeURIComponent(state.token)}`);
  state.source = source;
  source.addEventListener("open", () => { state.conn.sse = true; state.conn.error = ""; showConn(); resync(); });
  source.addEventListener("error", () => streamFailed(source));
  source.addEventListener("drone", (ev) => onDrone(JSON.parse(ev.data)));
  source.addEventListener("drone_lost", (ev) => onDroneLost(JSON.parse(ev.data).id));
  source.addEventListener("mail", (ev) => { upsertMail(JSON.parse(ev.data)); render(); });
  source.addEventListener("alarm", (ev) => { upsertAlarm(JSON.parse(ev.data)); render(); });
  source.addEventListener("log", (ev) => { state.log.unshift(JSON.parse(ev.data)); render(); });
  source.addEventListener("command", () => D.commands.refresh()); // another operator's, at once
}

// EventSource retries by itself after a network error, but gives up for good on an HTTP error
// (a 401 after the service restarted with new tokens): ask the service what is wrong.
async function streamFailed(source) {
  if (source !== state.source) return;
  state.conn.sse = false;
  showConn();
  try {
    await api("/v1/workspace");
    if (source.readyState === EventSource.CLOSED) retryLater("the event stream closed");
  } catch (err) {
    if (err.status !== 401) state.conn.error = err.message;
    showConn();
  }
}

let retryTimer = 0;
function retryLater(why) {
  state.conn.error = why;
  showConn();
  clearTimeout(retryTimer);
  retryTimer = setTimeout(() => { if (state.conn.auth && state.token) connect(); }, 2000);
}

async function pollReadiness() {
  try {
    const res = await fetch("/readyz");
    state.conn.fleet = (await res.json()).fleet_connected === true;
  } catch {
    state.conn.fleet = null;
  }
  showConn();
}

// After (re)connecting: the service's view replaces whatever the page held (it may be another run's).
async function resync() {
  try {
    const [fleet, page, alarms, log] = await Promise.all([
      api("/v1/fleet"), api("/v1/mail?limit=200"), api("/v1/alarms?limit=100"), api("/v1/log?limit=200")]);
    state.drones = new Map();
    for (const d of fleet.drones.concat(fleet.lost)) remember(d, d.alive ? Date.now() : d.seen_at * 1000);
    state.mail = new Map(page.items.map((m) => [m.id, m]));
    state.alarms = new Map(alarms.items.map((a) => [a.n, a]));
    state.log = log.items;
    render();
    D.charts.refresh();
    D.commands.refresh();
  } catch (err) {
    if (err.status !== 401) D.panels.notice(`could not load the fleet: ${err.message}`);
  }
}

// --------------------------------------------------------------- events
function remember(d, receivedAt) {
  d.receivedAt = Math.min(receivedAt || Date.now(), Date.now());
  d.lostAt = d.alive === false ? d.receivedAt : null;
  state.drones.set(d.id, d);
  const track = state.tracks.get(d.id) || [];
  const here = [d.position.lat, d.position.lon];
  const last = track[track.length - 1];
  if (!last || last[0] !== here[0] || last[1] !== here[1]) track.push(here);
  state.tracks.set(d.id, track.slice(-TRACK_STEPS));
}

function onDrone(d) {
  remember(d, d.alive === false ? d.seen_at * 1000 : Date.now());
  render();
}

function onDroneLost(id) {
  const d = state.drones.get(id);
  if (d) d.lostAt = Date.now();
  render();
}

function upsertMail(m) {
  const known = state.mail.get(m.id);
  if (!known || known.updated_at <= m.updated_at) state.mail.set(m.id, m);
}
D.upsertMail = upsertMail;

function upsertAlarm(a) { state.alarms.set(a.n, a); }
D.upsertAlarm = upsertAlarm;

// A drone is stale once it left, or when no state came for a while (several steps).
D.staleFor = (d) => {
  const after = Math.max(3000, 5000 * (state.ws ? state.ws.tau_s : 1));
  const age = Date.now() - d.receivedAt;
  return d.lostAt != null || d.alive === false || age > after ? age : null;
};

let frame = 0;
function render() {
  if (!frame) frame = requestAnimationFrame(() => { frame = 0; draw(); });
}
D.render = render;

function draw() {
  if (!state.ws) return;
  D.map.draw();
  D.panels.draw();
}
D.draw = draw;

// ----------------------------------------------------------------- start
function start() {
  $("#token-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    state.token = $("#token").value.trim();
    localStorage.setItem("drona-token", state.token);
    connect();
  });
  $("#token-show").addEventListener("click", () => askToken(""));
  D.panels.wire();
  D.commands.wire();
  state.token = new URLSearchParams(location.hash.slice(1)).get("token") || localStorage.getItem("drona-token") || "";
  $("#token").value = state.token;
  pollReadiness();
  setInterval(pollReadiness, 3000);
  setInterval(render, 1000); // ages and staleness move on by themselves
  setInterval(() => { if (state.conn.sse) { D.charts.refresh(); D.commands.refresh(); } }, 10000);
  if (state.token) connect(); else { showConn(); askToken("Enter an operator token."); }
}

start();
})();
