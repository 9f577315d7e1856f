// apmcal ui: the page's behaviour (plain JavaScript, no build step, nothing from the network).
"use strict";

const $ = (id) => document.getElementById(id);
const el = (tag, attrs = {}, ...children) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v; else if (k === "html") e.innerHTML = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return e;
};
// each tab of the browser is one driver of the vehicle (sessionStorage is per tab)
const TAB = sessionStorage.getItem("apmcal-tab") || Math.random().toString(36).slice(2);
sessionStorage.setItem("apmcal-tab", TAB);
let INFO = {};

async function api(path, options = {}) {
  let response;
  try {
    response = await fetch(path, options);
  } catch (e) {
    throw new Error("apmcal ui does not answer: was it stopped? Start it again (apmcal ui)");
  }
  let data = {};
  try { data = await response.json(); } catch (e) { data = {}; }
  if (!response.ok) {
    const err = new Error(data.error || `refused (${response.status})`);
    err.status = response.status;
    throw err;
  }
  return data;
}
const post = (path, data) => api(path, { method: "POST", headers: { "content-type": "application/json" },
                                         body: JSON.stringify({ tab: TAB, ...data }) });

function showError(id, message) {
  const box = $(id);
  box.hidden = !message;
  box.textContent = message || "";
}

// ------------------------------------------------------------------ tabs
function showTab(name) {
  for (const t of document.querySelectorAll(".tab")) t.classList.toggle("active", t.dataset.tab === name);
  for (const p of document.querySelectorAll(".panel")) p.hidden = p.id !== name;
  location.hash = name;
  if (name === "live") refreshPorts();
  if (name === "fleet" && !$("folder").value) openFolder("");
}

// ------------------------------------------------------------------ site (lat, lon), shared
function site(panel) {
  const box = panel.querySelector(".site");
  return { lat: box.querySelector(".lat").value.trim(), lon: box.querySelector(".lon").value.trim() };
}
function keepSite() {
  for (const cls of ["lat", "lon"]) {
    const saved = localStorage.getItem(`apmcal-${cls}`) || "";
    for (const input of document.querySelectorAll(`.${cls}`)) {
      input.value = saved;
      input.addEventListener("change", () => {
        localStorage.setItem(`apmcal-${cls}`, input.value.trim());
        for (const other of document.querySelectorAll(`.${cls}`)) other.value = input.value.trim();
      });
    }
  }
}

// ------------------------------------------------------------------ jobs: progress and results
function followJob(job, box, onDone) {
  renderJob(job, box);
  const source = new EventSource(`/api/jobs/${job.id}/events`);
  source.onmessage = (event) => {
    const snap = JSON.parse(event.data);
    renderJob(snap, box);
    if (snap.state === "done" || snap.state === "failed") {
      source.close();
      if (onDone) onDone(snap);
    }
  };
  source.onerror = () => {
    source.close();
    // the stream ends with the job; a server gone is said once
    api(`/api/jobs/${job.id}`).then((snap) => {
      renderJob(snap, box);
      if (snap.state === "done" || snap.state === "failed") { if (onDone) onDone(snap); }
      else followJob(snap, box, onDone);
    }).catch((e) => { box.prepend(el("div", { class: "error" }, e.message)); });
  };
}

function renderJob(snap, box) {
  let head = box.querySelector(".job-head");
  if (!head) {
    box.replaceChildren();
    head = el("div", { class: "card job-head" });
    box.append(head, el("div", { class: "job-body" }));
  }
  const stages = el("ol", { class: "stages" });
  const failed = snap.failed_stages || [];
  snap.stages.forEach((name, i) => {
    const bad = failed.includes(name) || (i === snap.current && snap.state === "failed");
    const cls = bad ? "failed" : i < snap.current ? "done" : i === snap.current ? "now" : "";
    stages.append(el("li", { class: cls }, (bad ? "✗ " : i < snap.current ? "✓ " : "") + name));
  });
  const total = snap.stages.length || 1;
  const within = snap.fraction >= 0 ? snap.fraction : 0.5;
  const done = snap.state === "done" ? 1 : Math.max(0, snap.current + (snap.current >= 0 ? within : 0)) / total;
  const bar = el("div", { class: "bar" + (snap.state === "running" && snap.fraction < 0 ? " unknown" : "") },
                 el("div", { style: `width:${Math.round(100 * done)}%` }));
  const words = snap.state === "done" ? (failed.length ? "done, not all files could be used (below)" : "done")
    : snap.state === "failed" ? "stopped"
    : snap.current >= 0 ? snap.stages[snap.current] + (snap.text ? ` — ${snap.text}` : "")
    : snap.text || "starting";
  head.replaceChildren(el("div", { class: "hint" }, snap.title),
                       el("div", { class: "progress" }, bar, el("span", { class: "progress-text" }, words)),
                       stages);
  if (snap.state === "failed") head.append(el("div", { class: "error job-error" }, snap.error));
  if (snap.state === "done" && !box.querySelector(".job-body").dataset.version) {
    const body = box.querySelector(".job-body");
    body.dataset.version = snap.version;
    for (const entry of snap.result.entries || []) body.append(renderEntry(entry));
    if (snap.result.kind === "fleet") body.append(renderFleet(snap.result));
  }
}

function num(v, digits = 6) {
  if (v === null || v === undefined) return "?";
  return Number(v).toPrecision(digits).replace(/\.?0+$/, "").replace(/\.?0+e/, "e");
}

function renderEntry(e) {
  const box = el("div", { class: "entry", "data-name": e.name });
  box.append(el("h3", {}, e.name));
  if (e.error) { box.append(el("div", { class: "error entry-error" }, e.error)); return box; }
  if (e.verdict_html) box.append(el("div", { class: "verdict-block", html: e.verdict_html }));
  if (e.kind === "gap") {
    box.append(el("p", { class: "verdict" }, e.verdict));
    if (e.advice.length) box.append(el("ul", {}, ...e.advice.map((a) => el("li", {}, a))));
  }
  if (e.kind === "tcal") {
    box.append(el("ul", { class: "tcal" }, ...e.imus.map((imu) => el("li", {},
      `IMU ${imu.instance} (${imu.source}): `,
      el("span", { class: imu.proposed ? "good" : "redo" }, imu.proposed ? "proposed" : "not proposed"),
      ` — ${imu.why}`))));
  }
  for (const note of e.notes || []) box.append(el("p", { class: "hint" }, note));
  if (e.proposal) box.append(renderProposal(e.proposal));
  if (e.downloads && e.downloads.length) {
    box.append(el("p", { class: "downloads" }, e.kind === "gap" ? "Download: " : "Download the parameters: ",
      ...e.downloads.map((d) => el("a", { href: d.url, download: "" }, d.label))));
    if (e.kind !== "gap") {
      box.append(el("p", { class: "hint" }, "Load the file in Mission Planner (Config › Full Parameter List › Load from file) or QGroundControl (Vehicle Setup › Parameters › Tools › Load from file), or use the Live vehicle tab."));
    }
  }
  for (const f of e.figures || []) {
    box.append(el("figure", {}, el("img", { src: `data:image/png;base64,${f.png}`, alt: f.caption }),
                  el("figcaption", {}, f.caption)));
  }
  if (e.page) box.append(el("iframe", { class: "report", src: e.page, title: `report of ${e.name}` }));
  if (e.text) box.append(el("details", {}, el("summary", {}, "The full report (text)"), el("pre", {}, e.text)));
  return box;
}

function renderProposal(p) {
  const wrap = el("div", { class: "proposal" });
  wrap.append(el("p", {}, el("b", {}, `Parameters (ArduPilot ${p.generation}): in force → proposed`)));
  const table = el("table", { class: "params" }, el("tr", {}, el("th", {}, "parameter"),
                   el("th", {}, "in force"), el("th", {}, ""), el("th", {}, "proposed")));
  const withheld = [];
  for (const [name, old, value, why] of p.rows) {
    table.append(el("tr", { class: why ? "withheld" : "" }, el("td", {}, name),
                    el("td", { class: "num" }, num(old)), el("td", {}, "→"),
                    el("td", { class: "num" }, why ? `${value === null ? "—" : num(value)} (not written)` : num(value))));
    if (why) withheld.push([name, why]);
  }
  wrap.append(table);
  const reasons = {};
  for (const [name, why] of withheld) (reasons[why] = reasons[why] || []).push(name);
  for (const [why, names] of Object.entries(reasons)) {
    wrap.append(el("p", { class: "redo" }, `not written: ${names.join(", ")} — ${why}`));
  }
  return wrap;
}

// ------------------------------------------------------------------ logs
function setupLogs() {
  const drop = $("drop");
  $("limit").textContent = `At most ${Math.round(INFO.max_upload_bytes / 2 ** 20)} MB at a time.`;
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault(); drop.classList.remove("over");
    sendLogs([...e.dataTransfer.files]);
  });
  $("files").addEventListener("change", (e) => { sendLogs([...e.target.files]); e.target.value = ""; });
}

async function sendLogs(files) {
  showError("logs-error", "");
  if (!files.length) return;
  const total = files.reduce((s, f) => s + f.size, 0);
  if (total > INFO.max_upload_bytes) {
    showError("logs-error", `${files.map((f) => f.name).join(", ")}: too large${files.length > 1 ? " together" : ""} (${Math.round(total / 2 ** 20)} MB): at most ${Math.round(INFO.max_upload_bytes / 2 ** 20)} MB at a time`);
    return;
  }
  const form = new FormData();
  form.append("kind", document.querySelector("input[name=kind]:checked").value);
  const where = site($("logs"));
  form.append("lat", where.lat); form.append("lon", where.lon);
  for (const f of files) form.append("files", f, f.name);
  $("logs-job").replaceChildren(el("div", { class: "card" }, `sending ${files.length} file(s)…`));
  try {
    const job = await api("/api/jobs", { method: "POST", body: form });
    $("logs-job").replaceChildren();
    followJob(job, $("logs-job"));
  } catch (e) {
    $("logs-job").replaceChildren();
    showError("logs-error", e.message);
  }
}

// ------------------------------------------------------------------ live vehicle
let vehicle = { status: "disconnected" };
let liveJob = null;
let spin = 0;

async function refreshPorts() {
  try {
    const data = await api("/api/ports");
    const select = $("port"), keep = select.value;
    select.replaceChildren(el("option", { value: "" }, "— choose —"),
      ...data.ports.map((p) => el("option", { value: p.connection }, p.label)));
    if ([...select.options].some((o) => o.value === keep)) select.value = keep;
  } catch (e) { showError("live-error", e.message); }
}

async function vehicleAction(path, data = {}, takeOver = false) {
  showError("live-error", "");
  try {
    const out = await post(path, data);
    $("live-busy").hidden = true;
    return out;
  } catch (e) {
    if (e.status === 409) {
      $("live-busy").hidden = false;
      $("live-busy-text").textContent = e.message;
      $("takeover").onclick = async () => {
        await post("/api/vehicle/takeover");
        $("live-busy").hidden = true;
        vehicleAction(path, data);
      };
    } else {
      showError("live-error", e.message);
    }
    return null;
  }
}

function setupLive() {
  $("port").addEventListener("change", () => {
    const c = $("port").value;
    if (c) $("connection").value = c;
  });
  $("refresh-ports").addEventListener("click", refreshPorts);
  $("connect").addEventListener("click", () => vehicleAction("/api/vehicle/connect",
    { connection: $("connection").value, baud: $("baud").value }));
  $("disconnect").addEventListener("click", () => vehicleAction("/api/vehicle/disconnect"));
  $("start-session").addEventListener("click", () => {
    const where = site($("session-card"));
    vehicleAction("/api/vehicle/session", { faces: $("do-faces").checked, compass: $("do-compass").checked,
                                            hold_s: $("hold").value, lat: where.lat, lon: where.lon });
  });
  $("stop-guide").addEventListener("click", () => vehicleAction("/api/vehicle/stop"));
  $("stop-turn").addEventListener("click", () => vehicleAction("/api/vehicle/stop"));
  $("finish-turn").addEventListener("click", () => vehicleAction("/api/vehicle/finish"));
  $("upload").addEventListener("click", () => vehicleAction("/api/vehicle/upload"));
  $("undo").addEventListener("click", () => vehicleAction("/api/vehicle/undo"));
  if (INFO.simulator) {
    $("sim-offer").hidden = false;
    $("sim-start").addEventListener("click", async () => {
      const sim = await vehicleAction("/api/simulator/start");
      if (!sim) return;
      $("connection").value = sim.connection;
      $("sim-card").hidden = false;
      vehicleAction("/api/vehicle/connect", { connection: sim.connection, baud: 115200 });
    });
    for (const [move, words] of Object.entries(INFO.simulator_moves)) {
      $("sim-moves").append(el("button", { "data-move": move,
        onclick: () => vehicleAction("/api/simulator/move", { move }) }, words));
    }
  }
  const source = new EventSource(`/api/vehicle/events?tab=${TAB}`);
  source.onmessage = (event) => renderVehicle(JSON.parse(event.data));
  source.onerror = () => showError("live-error", "apmcal ui does not answer: was it stopped? Start it again (apmcal ui) and reload this page");
  source.onopen = () => { if ($("live-error").textContent.startsWith("apmcal ui does not answer")) showError("live-error", ""); };
  setInterval(() => {            // the compass sphere turns slowly, to be seen all round
    spin += 0.03;
    if (vehicle.compass && vehicle.status === "compass") Draw.sphere($("sphere"), vehicle.compass.covered, spin);
  }, 60);
}

function renderVehicle(s) {
  vehicle = s;
  const connected = !["disconnected", "connecting"].includes(s.status);
  $("connect-card").hidden = connected;
  $("connect").disabled = s.status === "connecting";
  $("connect").textContent = s.status === "connecting" ? "Connecting…" : "Connect";
  $("vehicle-card").hidden = !connected;
  $("session-card").hidden = !(s.status === "idle");
  $("guide-card").hidden = !(s.status === "guide" && s.guide);
  $("compass-card").hidden = s.status !== "compass";
  if (s.error) showError("live-error", s.error);
  if (s.vehicle) renderVehicleInfo(s.vehicle, s);
  $("silent").hidden = !s.silent_s;
  $("silent").textContent = s.silent_s ? `The vehicle has not answered for ${s.silent_s} s: link lost? powered off?` : "";
  if (s.status === "guide" && s.guide) renderGuide(s.guide, s.acc);
  if (s.status === "compass" && s.compass) renderCompass(s.compass, s.acc);
  if (s.status === "compass" && !s.compass) renderCompass({ covered: "0".repeat(200), fraction: 0, need_fraction: 0.5, missing: "turn the vehicle", done: false }, s.acc);
  renderMessages(s.messages || []);
  if (s.job && s.job !== liveJob) {
    liveJob = s.job;
    $("live-job").replaceChildren();
    api(`/api/jobs/${s.job}`).then((job) => followJob(job, $("live-job"), () => renderUpload(vehicle)));
  }
  if (!s.job && liveJob && s.status !== "idle") { liveJob = null; $("live-job").replaceChildren(); }
  renderUpload(s);
}

function renderVehicleInfo(v, s) {
  const rows = [["vehicle", `${v.type} (system ${v.system})`], ["connection", s.connection],
                ["firmware", v.firmware], ["parameter generation", v.generation],
                ["parameters", v.param_count]];
  const table = el("table", {}, ...rows.map(([k, val]) => el("tr", {}, el("th", {}, k), el("td", {}, val))));
  const inForce = el("table", { class: "in-force" }, el("tr", {}, el("th", {}, "calibration in force"),
                     el("th", {}, "X"), el("th", {}, "Y"), el("th", {}, "Z")));
  const groups = {};
  for (const [name, value] of Object.entries(v.in_force)) {
    const m = name.match(/^(.*)_([XYZ])$/);
    const key = m ? m[1] : name;
    groups[key] = groups[key] || {};
    groups[key][m ? m[2] : "X"] = value;
  }
  for (const [key, g] of Object.entries(groups)) {
    inForce.append(el("tr", {}, el("td", {}, key), ...["X", "Y", "Z"].map((a) =>
      el("td", { class: "num" }, a in g ? num(g[a], 5) : ""))));
  }
  $("vehicle-info").replaceChildren(el("div", { class: "side" }, table, inForce));
}

function renderGuide(g, acc) {
  $("guide-card").dataset.face = g.face;
  $("guide-card").dataset.attempt = g.attempt;
  $("guide-title").textContent = `Pose ${g.index} of ${g.of}`;
  $("guide-words").textContent = `Place the vehicle ${g.words}, and keep it still`;
  Draw.vehicle($("pose-wanted"), g.gravity.map((x) => 9.8 * x), "asked for");
  Draw.vehicle($("pose-now"), acc, "now");
  const off = acc ? Draw.angle(acc, g.gravity) : null;
  $("pose-now-caption").textContent = off === null ? "the vehicle now"
    : off <= 25 ? `the vehicle now — in the pose (${off.toFixed(0)}° off)` : `the vehicle now — ${off.toFixed(0)}° from the pose`;
  $("pose-now-caption").className = off !== null && off <= 25 ? "good" : "";
  const hold = Number($("hold").value) || 10;
  $("hold-bar").style.width = `${Math.min(100, 100 * (g.held_s || 0) / hold)}%`;
  $("hold-text").textContent = g.held_s ? `held still ${g.held_s} of ${hold} s — ${Math.max(0, hold - g.held_s)} s to go`
    : "waiting for the vehicle to be still in the pose";
  const names = { level: "level", left: "left side", right: "right side", nosedown: "nose down",
                  noseup: "nose up", back: "back" };
  $("face-list").replaceChildren(...Object.entries(names).map(([k, words]) => el("li", {
    class: g.done.includes(k) ? "done" : k === g.face ? "now" : "" }, (g.done.includes(k) ? "✓ " : "") + words)));
}

function renderCompass(c, acc) {
  Draw.sphere($("sphere"), c.covered, spin);
  Draw.vehicle($("pose-turn"), acc, "now");
  $("sphere-caption").textContent = `${Math.round(100 * c.fraction)} % of the directions seen (${Math.round(100 * c.need_fraction)} % needed)`;
  $("compass-status").textContent = c.done ? "✓ done: enough directions for the compass fit. Press Finish (or keep turning to fill more)." : c.missing;
  $("compass-status").className = "big " + (c.done ? "good" : "");
  $("finish-turn").textContent = c.done ? "Finish" : "Finish anyway";
}

function renderMessages(messages) {
  const list = $("messages");
  if (list.childElementCount === messages.length && list.dataset.last === (messages.at(-1) || {}).t + (messages.at(-1) || {}).text) return;
  list.replaceChildren(...messages.map((m) => el("li", { class: `m-${m.level}` }, `${m.t}  ${m.text}`)));
  list.dataset.last = (messages.at(-1) || {}).t + (messages.at(-1) || {}).text;
  list.scrollTop = list.scrollHeight;
}

function renderUpload(s) {
  const ready = s.job && liveJob === s.job && document.querySelector("#live-job .entry") &&
    document.querySelector("#live-job .entry .verdict-block");
  const connected = !["disconnected", "connecting"].includes(s.status);
  $("upload-card").hidden = !(connected && (ready || s.upload || s.can_restore));
  $("upload").hidden = !!(s.upload && !s.upload.undone);
  $("upload").disabled = s.status !== "idle";
  $("undo").hidden = !s.can_restore;
  $("undo").disabled = s.status !== "idle";
  $("undo").textContent = s.upload ? "Undo: restore the backup" : "Restore the backup (the upload did not finish)";
  const out = $("upload-result");
  if (s.status === "uploading") { out.replaceChildren(el("p", { class: "big" }, "writing and reading back…")); return; }
  if (s.status === "restoring") { out.replaceChildren(el("p", { class: "big" }, "restoring the backup…")); return; }
  if (!s.upload) { out.replaceChildren(); return; }
  const table = el("table", {}, el("tr", {}, el("th", {}, "parameter"), el("th", {}, "before"), el("th", {}, ""),
                   el("th", {}, s.upload.undone ? "written, then restored" : "now on the vehicle")));
  for (const [name, old, value] of s.upload.rows) {
    table.append(el("tr", {}, el("td", {}, name), el("td", { class: "num" }, num(old)), el("td", {}, "→"),
                    el("td", { class: "num" }, num(value))));
  }
  out.replaceChildren(
    el("p", { class: "good big upload-done" }, s.upload.undone
      ? `Undone: the vehicle holds its values from before again (from ${s.upload.backup}).`
      : `Written and read back: ${s.upload.rows.length} parameters. Backup of every parameter: ${s.upload.backup}`),
    table);
}

// ------------------------------------------------------------------ fleet
async function openFolder(path) {
  showError("fleet-error", "");
  try {
    const data = await api(`/api/folders?path=${encodeURIComponent(path)}`);
    $("folder").value = data.path;
    $("folder-up").disabled = !data.parent;
    $("folder-up").onclick = () => openFolder(data.parent);
    $("folder-count").textContent = `${data.logs_here} log file(s) directly in this folder; its ${data.folders.length} sub-folder(s) are searched too.`;
    $("folder-list").replaceChildren(...data.folders.map((name) => el("li", { "data-name": name,
      onclick: () => openFolder(`${data.path}/${name}`) }, `${name}/`)));
    if (data.more) $("folder-list").append(el("li", { class: "hint" }, `… and ${data.more} more: type the folder's name above`));
  } catch (e) { showError("fleet-error", e.message); }
}

function setupFleet() {
  $("folder-go").addEventListener("click", () => openFolder($("folder").value));
  $("folder").addEventListener("keydown", (e) => { if (e.key === "Enter") openFolder($("folder").value); });
  $("fleet-start").addEventListener("click", async () => {
    showError("fleet-error", "");
    try {
      const job = await post("/api/fleet", { folder: $("folder").value });
      $("fleet-job").replaceChildren();
      followJob(job, $("fleet-job"));
    } catch (e) { showError("fleet-error", e.message); }
  });
}

function renderFleet(r) {
  const box = el("div", { class: "entry fleet-result" });
  box.append(el("p", { class: "big" }, `${r.logs} logs: ${r.read} read (${r.cached} from the cache), ${r.logs - r.read} not read; ${r.vehicles} vehicles; ${r.action_flags} flag(s) needing action`));
  if (r.flags.length) {
    const table = el("table", { class: "flags" }, el("tr", {}, ...["level", "vehicle", "what", "next step"].map((h) => el("th", {}, h))));
    for (const f of r.flags) {
      table.append(el("tr", { class: f.level }, el("td", {}, f.level), el("td", {}, f.vehicle_id),
                      el("td", {}, f.reason), el("td", {}, f.next_step)));
    }
    box.append(table);
  } else {
    box.append(el("p", { class: "good" }, "No flags: nothing needs doing."));
  }
  for (const n of r.not_read) box.append(el("p", { class: "hint" }, `not read: ${n.reason}`));
  box.append(el("p", { class: "hint" }, `Results and the cache: ${r.out}`));
  box.append(el("iframe", { class: "report", src: r.page, title: "the fleet, per vehicle" }));
  return box;
}

// ------------------------------------------------------------------ start
async function start() {
  INFO = await api("/api/info");
  $("files-dir").textContent = INFO.files;
  for (const t of document.querySelectorAll(".tab")) t.addEventListener("click", () => showTab(t.dataset.tab));
  keepSite();
  setupLogs();
  setupLive();
  setupFleet();
  showTab(["logs", "live", "fleet"].includes(location.hash.slice(1)) ? location.hash.slice(1) : "logs");
}
document.addEventListener("DOMContentLoaded", () => start().catch((e) => {
  document.body.prepend(el("div", { class: "error" }, e.message));
}));
