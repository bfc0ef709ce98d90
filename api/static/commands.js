// The operator's fleet commands (/v1/fleet/...): the fleet bar (pause, resume), each drone's recall,
// land and resume in the drone list, what the drones answered, and the audit trail ("Commands").
// Recall and land ask "sure?" first and take the second click only after a moment, so that neither
// a slip nor a double click lands a drone. Each drone's buttons live as long as the page (panels.js
// keeps its list item), so that a click is not lost when its state redraws the list.
"use strict";
(() => {
const D = (window.drona = window.drona || { state: {} });
const state = D.state;
const ACTIONS = ["recall", "land", "resume"];
const CONFIRM = new Set(["recall", "land"]);
const TITLES = {
  recall: "Finish the current leg, hand back the mail not on board, and park; no mail until resumed",
  land: "Stop where it is once its peers know it stays, and land; no mail until resumed",
  resume: "Take mail again (the fleet's pause, if any, stays)",
};
const ARM_MS = 600; // the "sure?" button takes no click before this: a double click does not confirm
const DISARM_MS = 6000; // and gives up after this
const $ = (sel) => document.querySelector(sel);
const clock = (unix) => new Date(unix * 1000).toLocaleTimeString([], { hour12: false });

let history = []; // the audit trail, newest first (GET /v1/fleet/commands)
const boxes = new Map(); // drone -> its controls in the drone list
const outcomes = new Map(); // drone -> { text, kind } of its last command
const pending = new Set(); // "fleet" or a drone: a command on its way
let armed = null; // { button, timer, since }: the button asking "sure?"

// -------------------------------------------------- state from the audit trail
function fleetPaused() {
  const last = history.find((c) => c.drone === null);
  return Boolean(last && last.action === "pause");
}

// The recall or land in force for a drone (a fleet resume undoes them all), or null.
function inForce(drone) {
  for (const c of history) {
    if (c.drone === null && c.action === "resume") return null;
    if (c.drone === drone) return c.action === "resume" ? null : c.action;
  }
  return null;
}

function answers(c) {
  const yes = c.acks.filter((a) => a.accepted).map((a) => a.drone);
  const no = c.acks.filter((a) => !a.accepted).map((a) => `${a.drone} refused${a.reason ? `: ${a.reason}` : ""}`);
  const said = [yes.length ? `${yes.join(", ")} acknowledged` : "", ...no].filter(Boolean).join("; ");
  if (c.answered === false) return `${said ? `${said}; ` : ""}answers not stored`;
  return said || "no answer";
}

// --------------------------------------------------------------- sending
async function send(action, drone) {
  const key = drone || "fleet";
  const path = drone ? `/v1/fleet/drones/${encodeURIComponent(drone)}/${action}` : `/v1/fleet/${action}`;
  pending.add(key);
  show(drone, `${action}: sending…`, "info");
  try {
    const c = await D.api(path, { method: "POST" });
    // A fleet command: the live drones the page knows that did not answer are named too.
    const silent = drone ? [] : [...state.drones.values()].filter((d) => D.staleFor(d) == null)
      .map((d) => d.id).filter((id) => !c.acks.some((a) => a.drone === id)).sort();
    const text = `${action}: ${answers(c)}${silent.length ? `; no answer from ${silent.join(", ")}` : ""}`;
    show(drone, `${text} · ${clock(c.at)}`, silent.length || c.acks.some((a) => !a.accepted) ? "error" : "ok");
  } catch (err) {
    show(drone, `${action}${drone ? ` ${drone}` : ""}: ${err.message}`, "error");
  } finally {
    pending.delete(key);
    await refresh();
  }
}

function show(drone, text, kind) {
  if (drone) {
    outcomes.set(drone, { text, kind });
    D.render();
  } else {
    const el = $("#fleet-msg");
    el.textContent = text;
    el.dataset.kind = kind;
  }
  drawBar();
}

// A drone's recall or land: the first click arms the button ("sure?"), the second, a moment later, sends.
function press(button, action, drone) {
  if (!CONFIRM.has(action)) { disarm(); send(action, drone); return; }
  if (armed && armed.button === button) { disarm(); send(action, drone); return; }
  disarm();
  button.dataset.armed = "true";
  button.textContent = `sure? ${action} ${drone}`;
  button.disabled = true;
  const timer = setTimeout(disarm, DISARM_MS);
  armed = { button, timer, since: Date.now() };
  setTimeout(() => { if (armed && armed.button === button) D.render(); }, ARM_MS);
  D.render();
}

function disarm() {
  if (!armed) return;
  clearTimeout(armed.timer);
  const { button } = armed;
  armed = null;
  delete button.dataset.armed;
  button.textContent = button.dataset.action;
  D.render();
}

// ------------------------------------------------------------- drawing
// A drone's controls, made once and updated in place (panels.js puts them in the drone's item).
function controls(d) {
  let box = boxes.get(d.id);
  if (!box) {
    const { make } = D.panels;
    const buttons = ACTIONS.map((action) => make("button", {
      type: "button", className: `cmd ${action}`, textContent: action, title: TITLES[action],
      data: { action, drone: d.id } }));
    for (const b of buttons) b.addEventListener("click", () => press(b, b.dataset.action, d.id));
    box = make("div", { className: "commands" }, make("span", { className: "buttons" }, ...buttons),
               make("span", { className: "held" }), make("p", { className: "outcome", role: "status" }));
    boxes.set(d.id, box);
  }
  const busy = pending.has(d.id) || pending.has("fleet");
  for (const b of box.querySelectorAll("button")) {
    const waiting = armed && armed.button === b && Date.now() - armed.since < ARM_MS;
    b.disabled = busy || Boolean(waiting);
  }
  const held = inForce(d.id);
  setText(box.querySelector(".held"), held ? `${held} in force` : "");
  const outcome = outcomes.get(d.id) || { text: "", kind: "" };
  const p = box.querySelector(".outcome");
  setText(p, outcome.text);
  if (p.dataset.kind !== outcome.kind) p.dataset.kind = outcome.kind;
  return box;
}

function setText(el, text) { if (el.textContent !== text) el.textContent = text; }

function drawBar() {
  const paused = fleetPaused();
  const el = $("#fleet-state");
  el.dataset.state = paused ? "paused" : "running";
  el.textContent = paused ? "paused" : "running";
  const held = [...new Set(history.map((c) => c.drone).filter(Boolean))].sort()
    .map((id) => [id, inForce(id)]).filter(([, a]) => a).map(([id, a]) => `${id} (${a})`);
  $("#fleet-held").textContent = held.length ? `held: ${held.join(", ")}` : "";
  for (const b of document.querySelectorAll("#fleet-bar button")) b.disabled = pending.size > 0;
}

function drawHistory() {
  const { make } = D.panels;
  const list = $("#commands");
  const rows = history.map((c) => make("li", { data: { n: c.n, action: c.action, drone: c.drone || "" } },
    make("time", {}, clock(c.at)), " ", make("b", {}, c.by), " ", make("span", { className: "action" }, c.action),
    " ", make("span", { className: "target" }, c.drone || "fleet"), " ",
    make("span", { className: "answers", data: { ok: String(c.acks.some((a) => a.accepted)) } }, answers(c))));
  list.replaceChildren(...(rows.length ? rows : [make("li", { className: "empty" }, "no commands yet")]));
  list.dataset.loaded = "true";
}

async function refresh() {
  try {
    history = await D.api("/v1/fleet/commands?limit=100");
    drawHistory();
  } catch (err) {
    if (err.status !== 401) D.panels.notice(`could not load the commands: ${err.message}`);
  }
  drawBar();
  D.render();
}

function wire() {
  for (const action of ["pause", "resume"]) {
    $(`#fleet-${action}`).addEventListener("click", () => { disarm(); send(action, null); });
  }
  document.addEventListener("keydown", (ev) => { if (ev.key === "Escape") disarm(); });
}

D.commands = { controls, inForce, refresh, wire };
})();
