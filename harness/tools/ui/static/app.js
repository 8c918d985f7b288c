// The campaign page: set up and launch, watch progress pushed by server-sent events, browse results.
"use strict";

const $ = (id) => document.getElementById(id);
let current = null;      // the campaign shown
let events = null;       // its EventSource
const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"];

async function api(path, options = {}) {
  const response = await fetch(path, options);
  if (response.status === 401) { showLogin(); throw new Error("token needed"); }
  return response;
}

function showLogin() { $("login").hidden = false; $("main").hidden = true; }

function fill(list, items, render) {
  list.replaceChildren(...items.map(render));
}

function element(tag, text, attributes = {}) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = text;
  for (const [key, value] of Object.entries(attributes)) node.setAttribute(key, value);
  return node;
}

function number(value, digits = 3) { return value === null || value === undefined ? "-" : Number(value).toFixed(digits); }

function duration(seconds) {
  if (seconds === null || seconds === undefined) return "-";
  const s = Math.round(seconds);
  return s >= 3600 ? `${Math.floor(s / 3600)} h ${Math.round((s % 3600) / 60)} min` : s >= 60 ? `${Math.floor(s / 60)} min ${s % 60} s` : `${s} s`;
}

function showProblems(list, problems) {
  fill(list, problems, (p) => element("li", p.text));
}

// The launch's problems, listed and marked on their fields.
function showLaunchProblems(problems) {
  showProblems($("launch-problems"), problems);
  for (const node of document.querySelectorAll("[data-field]")) node.classList.remove("invalid");
  for (const p of problems) for (const node of document.querySelectorAll(`[data-field="${p.field}"]`)) node.classList.add("invalid");
}

// A select's options: a blank one (the command's default) unless blank is null, then the values;
// what was chosen stays chosen, unless chosen says otherwise.
function fillSelect(select, values, blank, chosen) {
  const keep = chosen ?? select.value;
  const options = values.map((v) => (typeof v === "string" ? { value: v, text: v } : v));
  fill(select, [...(blank === null ? [] : [{ value: "", text: blank }]), ...options],
    (o) => element("option", o.text, { value: o.value, ...(o.title ? { title: o.title } : {}) }));
  if ([...select.options].some((o) => o.value === keep)) select.value = keep;
}

async function loadSetup(chosen = {}) {
  const setup = await (await api("/api/setup")).json();
  const checked = new Set([...document.querySelectorAll("#scenario-list input:checked")].map((i) => i.value));
  if (chosen.scenario) checked.add(chosen.scenario);
  fill($("scenario-list"), setup.scenarios, (choice) => {
    const label = element("label");
    const box = element("input", null, { type: "checkbox", value: choice, name: "scenario" });
    box.checked = checked.has(choice);
    label.append(box, " " + choice);
    return label;
  });
  fillSelect($("mission-plan"), setup.plans, "the scenario's route", chosen.plan);
  fillSelect($("sut-params-file"), setup.params_files, "none", chosen.params);
  if (!$("profile").options.length) {
    fillSelect($("profile"), setup.profiles, null);
    fillSelect($("executor"), setup.executors, null);
    fillSelect($("sut"), setup.suts, null, "bundled");
    fillSelect($("sut-hold"), setup.holds, "paced (default)");
    fillSelect($("sut-fault"), setup.faults.map((f) => ({ value: f.name, text: f.name, title: f.breaks })), "none");
    fillSelect($("drive"), setup.drives, "the scenario's own");
    fillSelect($("rig"), setup.rigs, "the profile's sensor");
    if (setup.px4_bin_default) $("px4-bin").placeholder = `$STELLA_PX4_BIN: ${setup.px4_bin_default}`;
    if (setup.ardupilot_bin_default) $("ardupilot-bin").placeholder = `$STELLA_ARDUPILOT_BIN: ${setup.ardupilot_bin_default}`;
    showSutFields();
  }
}

// Only the chosen SUT's own options are shown, and only shown fields are sent.
function showSutFields() {
  for (const label of document.querySelectorAll("[data-sut]")) label.hidden = label.dataset.sut !== $("sut").value;
}

function shown(id) {
  const node = $(id);
  return node.closest("[hidden]") ? "" : node.value.trim();
}

async function upload(event, path, kind, problems) {
  const file = event.target.files[0];
  if (!file) return;
  const form = new FormData();
  form.append("file", file);
  const response = await api(path, { method: "POST", body: form });
  const body = await response.json();
  if (response.ok) { showProblems(problems, []); await loadSetup({ [kind]: body[kind] }); }
  else showProblems(problems, body.problems || [{ text: body.detail }]);
  event.target.value = "";
}

async function launch(event) {
  event.preventDefault();
  const spec = {
    name: $("name").value,
    scenarios: [...document.querySelectorAll("#scenario-list input:checked")].map((i) => i.value),
    profile: $("profile").value,
    algorithms: $("algorithms").value.split(","),
    evaluations: $("evaluations").value, population: $("population").value, runs: $("runs").value, seed: $("seed").value,
    executor: $("executor").value, workers: $("workers").value || null,
    sut: $("sut").value, px4_bin: shown("px4-bin"), ardupilot_bin: shown("ardupilot-bin"), sut_command: shown("sut-command"), sut_hold: shown("sut-hold"),
    sut_fault: shown("sut-fault"), autopilot_dir: shown("autopilot-dir"), drive: $("drive").value, rig: $("rig").value, mission_plan: $("mission-plan").value,
    sut_params_file: $("sut-params-file").value, sut_params: $("sut-params").value.split("\n").map((line) => line.trim()).filter(Boolean),
  };
  const response = await api("/api/campaigns", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(spec) });
  const body = await response.json();
  if (!response.ok) { showLaunchProblems(body.problems || [{ text: body.detail, field: "" }]); return; }
  showLaunchProblems([]);
  await loadCampaigns();
  open(body.name);
}

async function loadCampaigns() {
  const campaigns = await (await api("/api/campaigns")).json();
  fill($("campaign-list"), campaigns, (c) => {
    const item = element("li");
    const link = element("a", c.name, { "data-name": c.name });
    link.addEventListener("click", () => open(c.name));
    item.append(link, ` ${c.state}, ${c.done}/${c.total} evaluations`);
    return item;
  });
}

function drawChart(progress) {
  const svg = $("chart");
  const curves = Object.entries(progress.curves);
  const points = curves.flatMap(([, curve]) => curve);
  svg.replaceChildren();
  if (!points.length) return;
  const width = 720, height = 260, pad = 40;
  const maxX = Math.max(progress.runs[0] ? progress.runs[0].total - 1 : 1, ...points.map((p) => p[0]), 1);
  const ys = points.map((p) => p[1]).filter((y) => y < 1000);
  const low = Math.min(...ys, 0), high = Math.max(...ys, 1);
  const x = (v) => pad + (width - 2 * pad) * v / maxX;
  const y = (v) => height - pad - (height - 2 * pad) * (Math.min(v, high) - low) / (high - low || 1);
  const ns = "http://www.w3.org/2000/svg";
  const add = (tag, attributes, text) => {
    const node = document.createElementNS(ns, tag);
    for (const [k, v] of Object.entries(attributes)) node.setAttribute(k, v);
    if (text) node.textContent = text;
    svg.append(node);
    return node;
  };
  add("line", { x1: pad, y1: y(0), x2: width - pad, y2: y(0), stroke: "#b00020", "stroke-dasharray": "4 3" });
  add("text", { x: width - pad - 90, y: y(0) - 4, "font-size": 11, fill: "#b00020" }, "safety distance");
  add("text", { x: pad, y: height - 8, "font-size": 11 }, "evaluations");
  add("text", { x: 4, y: 14, "font-size": 11 }, "best fitness so far (m)");
  add("text", { x: 4, y: y(high) + 4, "font-size": 10 }, number(high, 1));
  add("text", { x: 4, y: y(low) + 4, "font-size": 10 }, number(low, 1));
  curves.forEach(([runId, curve], index) => {
    const color = COLORS[index % COLORS.length];
    add("polyline", { points: curve.map((p) => `${x(p[0])},${y(p[1])}`).join(" "), fill: "none", stroke: color, "stroke-width": 1.5 });
    for (const p of curve) add("circle", { cx: x(p[0]), cy: y(p[1]), r: 2.5, fill: color, class: "point", "data-run": runId });
  });
}

function showProgress(progress) {
  $("campaign-state").textContent = progress.state;
  $("campaign-state").className = `state ${progress.state}`;
  $("overall-progress").textContent = `${progress.done}/${progress.total} evaluations`;
  fill(document.querySelector("#progress-table tbody"), progress.runs, (r) => {
    const row = element("tr");
    row.append(element("td", r.scenario), element("td", r.algorithm), element("td", r.run),
      element("td", `${r.done}/${r.total}`, { class: "number done" }), element("td", number(r.best_fitness), { class: "number" }),
      element("td", r.violations, { class: "number" }), element("td", r.evaluations_per_hour ? Math.round(r.evaluations_per_hour) : "-", { class: "number" }),
      element("td", r.finished ? "done" : duration(r.eta_s)));
    return row;
  });
  drawChart(progress);
}

async function loadDetails(name) {
  const details = await (await api(`/api/campaigns/${encodeURIComponent(name)}`)).json();
  $("command").textContent = details.command;
  $("console").textContent = details.console;
  $("console-box").open = $("campaign-state").textContent === "stopped";
  const rows = details.comparison ? [...details.comparison.scenarios, ...details.comparison.overall.map((r) => ({ ...r, scenario: "overall" }))] : [];
  fill(document.querySelector("#comparison tbody"), rows, (r) => {
    const row = element("tr");
    row.append(element("td", r.scenario), element("td", r.algorithm), element("td", r.runs), element("td", number(r.median_best_fitness), { class: "number" }),
      element("td", r.violations, { class: "number" }), element("td", number(r.relative_performance_pct, 0), { class: "number" }),
      element("td", number(r.p_value, 2), { class: "number" }), element("td", number(r.a12, 2), { class: "number" }));
    return row;
  });
  fill(document.querySelector("#evaluations tbody"), details.evaluations, (e) => {
    const row = element("tr", null, { class: e.status });
    const cell = element("td");
    if (e.has_log) cell.append(evaluationLink(name, e, "open", "open-evaluation"));
    row.append(element("td", e.id), element("td", e.scenario), element("td", e.algorithm), element("td", e.run), element("td", e.status),
      element("td", number(e.fitness), { class: "number" }), element("td", number(e.min_clearance_m), { class: "number" }), cell);
    return row;
  });
}

function evaluationLink(name, e, text, className) {
  const link = element("a", text, { href: "#", class: className, "data-id": e.id });
  link.addEventListener("click", (event) => { event.preventDefault(); showEvaluation(name, e); });
  return link;
}

async function triage() {
  const name = current;
  $("triage-summary").textContent = "reading the violations' logs...";
  const response = await api(`/api/campaigns/${encodeURIComponent(name)}/triage`);
  if (!response.ok) { $("triage-summary").textContent = (await response.json()).detail; return; }
  const report = await response.json();
  if (name !== current) return;
  const spread = report.diversity.mean_pairwise_trajectory_distance_m;
  $("triage-summary").textContent = `${report.violations} distinct violations in ${report.diversity.modes} failure modes` +
    (spread === null ? "" : `; mean pairwise trajectory distance ${number(spread, 1)} m`) +
    (report.skipped.length ? `; ${report.skipped.length} not triaged (no log)` : "");
  fill(document.querySelector("#modes tbody"), report.modes, (m) => {
    const row = element("tr", null, { class: "mode" });
    const worst = element("td"), typical = element("td");
    worst.append(evaluationLink(name, m.worst, `f ${number(m.worst.fitness)}`, "open-worst"));
    typical.append(evaluationLink(name, m.typical, `f ${number(m.typical.fitness)}`, "open-typical"));
    row.append(element("td", m.count, { class: "number count" }), element("td", m.mechanism), element("td", m.obstacle), element("td", m.approach), element("td", m.phase),
      element("td", m.speed), element("td", m.wind), element("td", m.visibility), element("td", m.contacts, { class: "number" }),
      element("td", m.near_misses, { class: "number" }), worst, typical);
    return row;
  });
}

function showEvaluation(name, e) {
  $("evaluation").hidden = false;
  $("evaluation-title").textContent = `Evaluation ${e.id} (${e.algorithm} run ${e.run}): ${e.status}, fitness ${number(e.fitness)}`;
  const base = `/api/campaigns/${encodeURIComponent(name)}/evaluations/${e.id}`;
  $("mcap-link").href = `${base}/log.mcap`;
  $("plot").src = `${base}/plot.png`;
  $("concrete").textContent = JSON.stringify(e.concrete, null, 2);
  explainEvaluation(base, e.id);
}

async function explainEvaluation(base, id) {
  $("explanation").dataset.id = id;
  $("explanation").textContent = "reading the log...";
  const response = await api(`${base}/explain`);
  const answer = await response.json();
  if ($("explanation").dataset.id !== String(id)) return;  // another evaluation was opened meanwhile
  $("explanation").textContent = response.ok ? answer.text : answer.detail;
}

function open(name) {
  current = name;
  $("campaign").hidden = false;
  $("evaluation").hidden = true;
  $("campaign-title").textContent = name;
  $("triage-summary").textContent = "";
  document.querySelector("#modes tbody").replaceChildren();
  $("report-link").href = `/api/campaigns/${encodeURIComponent(name)}/report.html`;
  if (events) events.close();
  events = new EventSource(`/api/campaigns/${encodeURIComponent(name)}/events`);
  events.onmessage = (message) => {
    const progress = JSON.parse(message.data);
    if (progress.name !== current) return;
    showProgress(progress);
    if (progress.state !== "running") { events.close(); loadDetails(name); loadCampaigns(); }
  };
  loadDetails(name);
}

async function control(action) {
  if (!current) return;
  await api(`/api/campaigns/${encodeURIComponent(current)}/${action}`, { method: "POST" });
  await loadCampaigns();
  open(current);
}

async function start() {
  try {
    await loadSetup();
  } catch (error) {
    return;
  }
  $("login").hidden = true;
  $("main").hidden = false;
  await loadCampaigns();
}

$("login-button").addEventListener("click", async () => {
  const response = await fetch("/api/login", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ token: $("token").value }) });
  if (response.ok) start(); else $("login-error").textContent = "wrong token";
});
$("upload").addEventListener("change", (event) => upload(event, "/api/scenarios", "scenario", $("upload-problems")));
$("plan-upload").addEventListener("change", (event) => upload(event, "/api/plans", "plan", $("file-problems")));
$("params-upload").addEventListener("change", (event) => upload(event, "/api/params-files", "params", $("file-problems")));
$("sut").addEventListener("change", showSutFields);
$("setup-form").addEventListener("submit", launch);
$("cancel").addEventListener("click", () => control("cancel"));
$("resume").addEventListener("click", () => control("resume"));
$("triage-button").addEventListener("click", triage);
start();
