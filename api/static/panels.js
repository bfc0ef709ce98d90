// The lists beside the map: drones (keyed by the map's colours), alarms to acknowledge, the mail
// (sortable, filtered by status, priority and drone), the event log; the mail form and notices.
"use strict";
(() => {
const D = (window.drona = window.drona || { state: {} });
const state = D.state;
const FINAL = new Set(["delivered", "failed", "cancelled"]);
const GPS = ["no GPS", "no fix", "2D fix", "3D fix", "DGPS", "RTK float", "RTK fixed", "static", "PPP"];
const sort = { key: "created_at", down: true };
const $ = (sel) => document.querySelector(sel);

function make(tag, props = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(props)) {
    if (k === "data") Object.assign(el.dataset, v); else el[k] = v;
  }
  el.append(...children);
  return el;
}

D.ago = (ms) => {
  const s = Math.max(0, Math.round(ms / 1000));
  return s < 120 ? `${s} s` : s < 7200 ? `${Math.round(s / 60)} min` : `${Math.round(s / 3600)} h`;
};
const clock = (iso) => new Date(iso).toLocaleTimeString([], { hour12: false });

// -------------------------------------------------------------- kept items
// Items kept while what they show is the same (the drones' are kept too): the page draws on every
// state, and a button rebuilt between the press and the release of a click loses that click.
function kept(cache, key, shows, build) {
  const held = cache.get(key);
  if (held && held[0] === shows) return held[1];
  const item = build();
  cache.set(key, [shows, item]);
  return item;
}

// The parent shows the items in order, touched only if they changed; the cache keeps only theirs.
function showKept(parent, items, cache, keys) {
  if (items.length !== parent.children.length || items.some((el, i) => parent.children[i] !== el)) {
    parent.replaceChildren(...items);
  }
  const shown = new Set(keys);
  for (const key of [...cache.keys()]) if (!shown.has(key)) cache.delete(key);
}

// ------------------------------------------------------------------ drones
function altitude(d) {
  const h = d.vehicle && d.vehicle.height_m != null ? d.vehicle.height_m : d.position.alt_m - state.ws.geo_origin.alt_m;
  return `${h.toFixed(1)} m`;
}

function facts(d) {
  const v = d.vehicle, age = D.staleFor(d);
  const battery = `${d.battery_pct.toFixed(0)}%${v && v.battery_v != null ? ` ${v.battery_v.toFixed(1)} V` : ""}`;
  const mail = [d.carrying ? `carrying ${d.carrying}` : "", d.queue.length ? `queued ${d.queue.join(", ")}` : ""];
  return [
    ["link", age != null ? `stale ${D.ago(age)}${d.lostAt ? " (left)" : ""}` : "live"],
    ["alt", altitude(d)], ["mode", v && v.mode ? v.mode : d.mode],
    ["armed", v ? (v.armed ? "armed" : "disarmed") : "?"],
    ["GPS", v ? `${GPS[v.gps_fix] || v.gps_fix}, ${v.satellites} sats` : "?"],
    ["battery", battery], ["phase", d.phase], ["mail", mail.filter(Boolean).join("; ") || "none"],
    ["vehicle", v ? `${v.status}${v.reason ? `: ${v.reason}` : ""}` : "not reported"],
    ["alarms", d.health.alarms.join("; ") || "none"],
  ];
}

function droneSummary(d) {
  return `${d.id}: ${facts(d).map(([k, v]) => `${k} ${v}`).join(" · ")}`;
}

// Each drone keeps its item while the page lives, and its command buttons (commands.js): only the facts
// are redrawn, so that a click on a button is not lost to a redraw between the press and the release.
const items = new Map();

function droneItem(d) {
  const age = D.staleFor(d);
  const head = make("div", { className: "head" }, make("i", { className: "sw" }), make("b", {}, d.id),
                    make("span", { className: "badge" }, age != null ? `stale ${D.ago(age)}` : "live"));
  head.firstChild.style.background = age != null ? "#a0aec0" : D.colour(d.id);
  const list = make("div", { className: "facts" });
  for (const [k, v] of facts(d).slice(1)) list.append(make("span", { data: { k } }, make("i", {}, k), ` ${v}`));
  let li = items.get(d.id);
  if (!li) items.set(d.id, (li = make("li", { data: { id: d.id } }, make("div", { className: "info" }))));
  Object.assign(li.dataset, { stale: String(age != null), alarm: String(!d.health.ok),
                              command: D.commands.inForce(d.id) || "" });
  li.firstChild.replaceChildren(head, list);
  if (li.lastChild === li.firstChild) li.append(D.commands.controls(d)); else D.commands.controls(d);
  return li;
}

function drawDrones() {
  const drones = [...state.drones.values()].sort((a, b) => (a.id < b.id ? -1 : 1));
  showKept($("#drones"), drones.map(droneItem), items, drones.map((d) => d.id));
  const stale = drones.filter((d) => D.staleFor(d) != null).length;
  $("#drone-count").textContent = `${drones.length - stale} live${stale ? `, ${stale} stale` : ""}`;
}

// ------------------------------------------------------------------ alarms
const alarmItems = new Map();  // n -> [what it shows, its li]

function alarmItem(a) {
  const shows = [a.acked_at, a.acked_by, a.cleared_at, a.text, a.meaning].join("\u0000");
  return kept(alarmItems, a.n, shows, () => newAlarmItem(a));
}

function newAlarmItem(a) {
  const state_ = a.cleared_at ? `cleared ${clock(a.cleared_at)}` : "active";
  const ack = a.acked_at ? make("span", { className: "acked" }, `acknowledged by ${a.acked_by} ${clock(a.acked_at)}`)
    : make("button", { type: "button", className: "ack", textContent: "acknowledge", onclick: () => acknowledge(a.n) });
  return make("li", { data: { n: a.n, active: String(!a.cleared_at), acked: String(Boolean(a.acked_at)) } },
              make("div", { className: "head" }, make("time", {}, clock(a.raised_at)), make("b", {}, a.drone),
                   make("span", { className: "kind" }, a.kind), make("span", { className: "badge" }, state_)),
              make("p", { className: "meaning" }, a.meaning), make("p", { className: "text" }, a.text), ack);
}

function drawAlarms() {
  const alarms = [...state.alarms.values()].sort((a, b) => b.n - a.n).slice(0, 100);
  showKept($("#alarms"), alarms.map(alarmItem), alarmItems, alarms.map((a) => a.n));
  const open = alarms.filter((a) => !a.acked_at).length;
  $("#alarm-count").textContent = open ? `${open} to acknowledge` : "";
}

async function acknowledge(n) {
  try {
    D.upsertAlarm(await D.api(`/v1/alarms/${n}/ack`, { method: "POST" }));
    D.render();
  } catch (err) {
    notice(err.message);
  }
}

// -------------------------------------------------------------------- mail
function buildFilters() {
  const prio = $("#f-priority");
  if (prio.options.length === 1) for (let p = 9; p >= 0; p--) prio.append(make("option", {}, String(p)));
}

function shownMail() {
  const status = $("#f-status").value, prio = $("#f-priority").value, drone = $("#f-drone").value;
  const rows = [...state.mail.values()].filter((m) => (!status || m.status === status
    || (status === "open" && !FINAL.has(m.status))) && (!prio || String(m.priority) === prio)
    && (!drone || m.drone === drone));
  const key = sort.key, sign = sort.down ? -1 : 1;
  return rows.sort((a, b) => sign * (a[key] == null ? -1 : b[key] == null ? 1 : a[key] < b[key] ? -1
    : a[key] > b[key] ? 1 : 0));
}

const mailRows = new Map();  // id -> [what it shows, its tr]

function mailRow(m) {
  const shows = [m.created_at, m.status, m.priority, m.pickup, m.dropoff, m.drone, m.reason].join("\u0000");
  return kept(mailRows, m.id, shows, () => newMailRow(m));
}

function newMailRow(m) {
  const cells = [clock(m.created_at), m.id, m.status, String(m.priority), `[${m.pickup}] → [${m.dropoff}]`,
                 m.drone || ""];
  const tr = make("tr", { data: { id: m.id, status: m.status } });
  cells.forEach((text, i) => tr.append(make("td", i === 2 ? { className: "status", title: m.reason } : {}, text)));
  const act = make("td");
  if (m.status === "queued" || m.status === "assigned") {
    act.append(make("button", { type: "button", className: "cancel", textContent: "cancel", onclick: () => cancel(m.id) }));
  }
  tr.append(act);
  return tr;
}

function drawMail() {
  const select = $("#f-drone"), chosen = select.value;
  const ids = [...new Set([...state.drones.keys(), ...[...state.mail.values()].map((m) => m.drone).filter(Boolean)])];
  if (select.options.length !== ids.length + 1) {
    select.replaceChildren(make("option", { value: "" }, "all"), ...ids.sort().map((d) => make("option", {}, d)));
    select.value = chosen;
  }
  const mail = shownMail().slice(0, 200);
  showKept($("#mail tbody"), mail.map(mailRow), mailRows, mail.map((m) => m.id));
  for (const th of document.querySelectorAll("#mail th[data-sort]")) {
    th.setAttribute("aria-sort", th.dataset.sort === sort.key ? (sort.down ? "descending" : "ascending") : "none");
  }
}

async function cancel(id) {
  try {
    D.upsertMail(await D.api(`/v1/mail/${encodeURIComponent(id)}/cancel`, { method: "POST" }));
    D.render();
  } catch (err) {
    notice(err.message);
  }
}

// --------------------------------------------------------------------- log
function drawLog() {
  $("#log").replaceChildren(...state.log.slice(0, 200).map((e) => make("li", { data: { kind: e.kind } },
    make("time", {}, clock(e.at)), ` ${e.text}`)));
}

// ------------------------------------------------------------ form, notices
let noticeTimer = 0;
function notice(text, kind = "error") { // one message at a time: a new one replaces it, and it fades
  const el = $("#form-msg");
  el.textContent = text;
  el.dataset.kind = kind;
  clearTimeout(noticeTimer);
  noticeTimer = setTimeout(() => { el.textContent = ""; el.dataset.kind = ""; }, kind === "ok" ? 6000 : 15000);
}

async function submitMail(ev) {
  ev.preventDefault();
  const f = ev.target;
  const int = (name) => Number.parseInt(f[name].value, 10);
  const body = { pickup: [int("px"), int("py"), int("pz")], dropoff: [int("dx"), int("dy"), int("dz")],
                 priority: int("priority") };
  if (f.note.value) body.note = f.note.value;
  notice("sending…", "info");
  try {
    const m = await D.api("/v1/mail", { method: "POST", body: JSON.stringify(body),
                                        headers: { "Content-Type": "application/json" } });
    D.upsertMail(m);
    D.render();
    notice(`${m.id} ${m.status}`, "ok");
  } catch (err) {
    notice(err.message);
  }
}

function wire() {
  $("#mail-form").addEventListener("submit", submitMail);
  for (const id of ["#f-status", "#f-priority", "#f-drone"]) $(id).addEventListener("change", D.render);
  for (const th of document.querySelectorAll("#mail th[data-sort]")) {
    th.addEventListener("click", () => {
      sort.down = sort.key === th.dataset.sort ? !sort.down : true;
      sort.key = th.dataset.sort;
      D.render();
    });
  }
}

function draw() {
  drawDrones();
  drawAlarms();
  drawMail();
  drawLog();
}

D.panels = { draw, wire, buildFilters, notice, droneSummary, altitude, make };
})();
