// Small charts (vendored Chart.js) from /v1/stats: deliveries over time, waiting time by priority,
// coordination latency, battery per drone. Times run on the x axis in minutes before now.
"use strict";
(() => {
const D = (window.drona = window.drona || { state: {} });
const charts = {};
let busy = false;

const minutes = { type: "linear", min: -60, max: 0,
                  ticks: { callback: (v) => `${Math.round(v)} min`, stepSize: 15, maxRotation: 0 } };
const base = { animation: false, responsive: true, maintainAspectRatio: false,
               plugins: { legend: { display: false } } };

function make(id, config) {
  if (!charts[id]) charts[id] = new Chart(document.getElementById(id), config);
  return charts[id];
}

function deliveries(s) {
  const chart = make("c-deliveries", { type: "bar", data: { labels: [], datasets: [
    { label: "deliveries", data: [], backgroundColor: "#48bb78" }] }, options: { ...base,
    scales: { x: { ticks: { maxTicksLimit: 5 } }, y: { beginAtZero: true, ticks: { precision: 0 } } } } });
  const n = s.deliveries.length;
  chart.data.labels = s.deliveries.map((_, i) => `${Math.round(((i + 1 - n) * s.bucket_s) / 60)} min`);
  chart.data.datasets[0].data = s.deliveries;
  chart.update();
}

function waiting(s) {
  const chart = make("c-waiting", { type: "bar", data: { labels: [], datasets: [
    { label: "median", data: [], backgroundColor: "#4299e1" },
    { label: "90th percentile", data: [], backgroundColor: "#ed8936" }] },
    options: { ...base, plugins: { legend: { display: true, labels: { boxWidth: 10 } } },
               scales: { y: { beginAtZero: true } } } });
  chart.data.labels = s.waiting.map((w) => `p${w.priority} (${w.count})`);
  chart.data.datasets[0].data = s.waiting.map((w) => w.p50_s);
  chart.data.datasets[1].data = s.waiting.map((w) => w.p90_s);
  chart.update();
}

function byDrone(samples, now) {
  const series = new Map();
  for (const p of samples) {
    if (!series.has(p.drone)) series.set(p.drone, []);
    series.get(p.drone).push({ x: (p.at - now) / 60, y: p.value });
  }
  return [...series.entries()].sort().map(([drone, data]) => ({
    label: drone, data, borderColor: D.colour(drone), backgroundColor: D.colour(drone), pointRadius: 2,
    borderWidth: 1.5 }));
}

function coordination(s) {
  const chart = make("c-coordination", { type: "scatter", data: { datasets: [] },
    options: { ...base, scales: { x: minutes, y: { beginAtZero: true } } } });
  chart.data.datasets = byDrone(s.coordination_ms, s.now);
  chart.update();
}

function battery(s) {
  const chart = make("c-battery", { type: "line", data: { datasets: [] },
    options: { ...base, scales: { x: minutes, y: { min: 0, suggestedMax: 100, grace: "5%" } } } });
  chart.data.datasets = byDrone(s.battery_pct, s.now).map((d) => ({ ...d, pointRadius: 0 }));
  chart.update();
}

async function refresh() {
  if (busy || typeof Chart === "undefined") return;
  busy = true;
  try {
    const s = await D.api("/v1/stats?window_s=3600&bucket_s=60");
    deliveries(s); waiting(s); coordination(s); battery(s);
    document.getElementById("charts-panel").dataset.updated = String(s.now);
  } catch (err) {
    if (err.status !== 401) D.panels.notice(`charts: ${err.message}`);
  } finally {
    busy = false;
  }
}

D.charts = { refresh };
})();
