// The live view: one WebSocket of frames (≤ 5 Hz) from the daemon, drawn on canvases.
// The page only reads: it sends nothing but the WebSocket's own control frames.
"use strict";

const tvs = {
  frames: 0, config: null, status: {}, samples: [], points: [], faults: [], spectra: null,
  floor: null, reports: [], pointsDrawn: 0, connected: false,
};
window.tvs = tvs;  // what the browser test reads

const $ = (id) => document.getElementById(id);
const COLORS = { meas: "#1f6fb4", ref: "#e67e22", p99: "#1f6fb4", max: "#8e44ad", floor: "#2e8b57" };
const AXES = { g: ["gx", "gy", "gz"], a: ["ax", "ay", "az"] };
const AXIS_COLORS = ["#1f6fb4", "#e67e22", "#2e8b57"];

function iso(tUnix) {
  // local time, ISO form with ms
  const d = new Date(tUnix * 1000), p = (n, w = 2) => String(n).padStart(w, "0");
  return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())} ` +
    `${p(d.getHours())}:${p(d.getMinutes())}:${p(d.getSeconds())}.${p(d.getMilliseconds(), 3)}`;
}

const num = (v, d = 2) => (v === null || v === undefined ? "—" : Number(v).toFixed(d));

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  // relative to this page, so a reverse proxy may serve it under a prefix (/tvs/ → /tvs/ws)
  const ws = new WebSocket(`${proto}//${location.host}${location.pathname.replace(/[^/]*$/, "")}ws`);
  ws.onopen = () => { tvs.connected = true; $("conn").textContent = "live"; };
  ws.onmessage = (e) => take(JSON.parse(e.data));
  ws.onclose = () => {
    tvs.connected = false;
    $("conn").textContent = "disconnected: retrying…";
    setTimeout(connect, 2000);
  };
}

function decodePoints(b64) {
  // rows of little-endian float32 (config.point_cols: x y z m, σ mm, flags), base64
  const bin = atob(b64), bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  const v = new Float32Array(bytes.buffer), n = tvs.config ? tvs.config.point_cols.length : 5, rows = [];
  for (let i = 0; i + n <= v.length; i += n) rows.push(Array.from(v.subarray(i, i + n)));
  return rows;
}

function take(f) {
  if (f.type === "hello") {
    tvs.config = f.config; tvs.samples = []; tvs.points = [];
  }
  tvs.frames += 1;
  tvs.status = f.status || {};
  const keepS = tvs.config ? tvs.config.history_s : 60;
  for (const row of f.samples || []) tvs.samples.push(row);
  const newest = tvs.samples.length ? tvs.samples[tvs.samples.length - 1][0] : 0;
  while (tvs.samples.length && tvs.samples[0][0] < newest - keepS) tvs.samples.shift();
  if (f.points) {
    tvs.points.push(...decodePoints(f.points));
    const cap = tvs.config ? tvs.config.cloud_points : 5000;
    if (tvs.points.length > cap) tvs.points.splice(0, tvs.points.length - cap);
  }
  tvs.pointsTotal = f.points_total;
  if (f.faults) { tvs.faults = f.faults; drawFaults(); }
  if (f.spectra) { tvs.spectra = f.spectra; drawSpectra(); }
  if (f.floor) tvs.floor = f.floor;
  if (f.reports) { tvs.reports = f.reports; drawReports(); }
  drawHeader();
  drawSpeed();
  drawLateness();
}

function drawHeader() {
  const s = tvs.status;
  const st = $("state");
  st.textContent = s.state || "?";
  st.className = `badge ${s.state || ""}`;
  const loop = s.loop || {}, pts = s.points || {};
  $("headline").textContent =
    `${num(s.rps)} rev/s (ref ${num(s.rps_setpoint)}) · loop ${num(loop.rate_hz, 0)} Hz · ` +
    `${num(pts.per_s, 1)} points/s · link ${(s.link || {}).state || "?"} · IMU ${(s.imu || {}).state || "?"}`;
  const rows = [
    ["state", s.state], ["speed", `${num(s.rps, 3)} rev/s`], ["reference", `${num(s.rps_setpoint, 3)} rev/s`],
    ["aim φ, γ", s.aim_deg ? `${num(s.aim_deg.phi, 2)}°, ${num(s.aim_deg.gamma, 2)}°` : "—"],
    ["MCU link", (s.link || {}).state], ["IMU", `${(s.imu || {}).state || "?"} ${(s.imu || {}).detail || ""}`],
    ["points", `${pts.total ?? "—"} (${pts.no_imu ?? 0} without IMU)`],
    ["pulse → point", pts.latency_p50_ms !== undefined ? `${num(pts.latency_p50_ms, 2)} ms p50, ${num(pts.latency_max_ms, 1)} max` : "—"],
    ["recording", s.recording || "no"],
  ];
  const tb = $("summary");
  tb.replaceChildren(...rows.map(([k, v]) => {
    const tr = document.createElement("tr");
    for (const t of [k, v ?? "—"]) { const td = document.createElement("td"); td.textContent = t; tr.append(td); }
    return tr;
  }));
  const counts = s.fault_counts || {};
  $("fault-counts").textContent = Object.keys(counts).length
    ? "since start: " + Object.entries(counts).map(([k, n]) => `${k} ${n}`).join(", ") : "";
}

function drawFaults() {
  const ol = $("faults");
  if (!tvs.faults.length) {
    const li = document.createElement("li"); li.className = "none"; li.textContent = "none";
    ol.replaceChildren(li);
    return;
  }
  ol.replaceChildren(...tvs.faults.slice().reverse().map((f) => {
    const li = document.createElement("li");
    const kind = document.createElement("span"); kind.className = "kind"; kind.textContent = f.kind;
    const when = document.createElement("div"); when.className = "when"; when.textContent = iso(f.t_unix);
    const cause = document.createElement("div"); cause.className = "cause"; cause.textContent = f.cause;
    const act = document.createElement("div"); act.className = "action"; act.textContent = "→ " + f.action;
    li.append(kind, when, cause, act);
    return li;
  }));
}

function drawSpeed() {
  const rows = tvs.samples, keep = tvs.config ? tvs.config.history_s : 60;
  const t1 = rows.length ? rows[rows.length - 1][0] : 0;
  $("speed-note").textContent = `last ${keep} s, ${tvs.config ? tvs.config.push_hz : 5} samples/s`;
  Plot.draw($("speed"), {
    series: [
      { x: rows.map((r) => r[0] - t1), y: rows.map((r) => r[1]), color: COLORS.meas, label: "measured" },
      { x: rows.map((r) => r[0] - t1), y: rows.map((r) => r[2]), color: COLORS.ref, label: "reference", dash: [6, 4] },
    ],
    xmin: -keep, xmax: 0, xlabel: "s (0 = now)", ylabel: "rev/s",
    empty: rows.length ? "" : "waiting for the daemon…",
  });
}

function drawLateness() {
  const rows = tvs.samples, keep = tvs.config ? tvs.config.history_s : 60;
  const t1 = rows.length ? rows[rows.length - 1][0] : 0;
  const fl = tvs.floor;
  const x = rows.map((r) => r[0] - t1);
  Plot.draw($("lateness"), {
    series: [
      { x, y: rows.map((r) => r[3]), color: COLORS.p99, label: "loop p99 since start" },
      { x, y: rows.map((r) => r[4]), color: COLORS.max, label: "loop max since start" },
    ],
    hlines: fl ? [
      { y: fl.p99_us, color: COLORS.floor, label: "floor p99", dash: [6, 4] },
      { y: fl.max_us, color: "#7dbb91", label: "floor max", dash: [2, 3] },
    ] : [],
    xmin: -keep, xmax: 0, logy: true, xlabel: "s (0 = now)", ylabel: "lateness µs",
  });
  const missed = rows.reduce((a, r) => a + (r[5] || 0), 0);
  const loop = (tvs.status || {}).loop || {};
  $("floor-note").textContent = (fl
    ? `floor: a bare ${num(fl.rate_hz, 0)} Hz sleep loop on this machine, ${fl.seconds} s at ${iso(fl.t_unix)}: ` +
      `p50 ${num(fl.p50_us, 1)} µs, p99 ${num(fl.p99_us, 1)} µs, max ${num(fl.max_us, 0)} µs. `
    : "floor: not measured yet. ") +
    `Loop (since start): p99 ${num(loop.jitter_p99_us, 1)} µs, max ${num(loop.jitter_max_us, 0)} µs; ` +
    `missed ticks ${loop.missed_ticks ?? "—"} (${missed} in the window).`;
}

function drawSpectra() {
  const sp = tvs.spectra;
  if (!sp) return;
  const kind = document.querySelector("input[name=spec]:checked").value;
  const unit = kind === "g" ? "dB re (rad/s)²/Hz" : "dB re (m/s²)²/Hz";
  $("spectra-note").textContent =
    `${sp.seconds} s, ${sp.nperseg}-sample Hann segments; shaft orders at ${num(sp.rps, 2)} rev/s`;
  for (const sensor of ["pl", "sa"]) {
    const psd = (sp.psd_db || {})[sensor];
    const fmax = sp.f.length ? sp.f[sp.f.length - 1] : 1;
    Plot.draw($(`spec-${sensor}`), {
      series: psd ? AXES[kind].map((c, i) => ({
        x: sp.f.slice(1), y: psd[c].slice(1), color: AXIS_COLORS[i], label: `${sensor.toUpperCase()} ${c}`, width: 1.2,
      })) : [],
      vlines: sp.orders.map((f, i) => ({ x: f, label: `${i + 1}×`, color: "#c0392b" })),
      xmin: 0, xmax: fmax, xlabel: "Hz", ylabel: unit,
      empty: psd ? "" : `no ${sensor.toUpperCase()} samples`,
    });
  }
}

function drawReports() {
  const ul = $("reports");
  if (!tvs.reports.length) {
    const li = document.createElement("li"); li.className = "none";
    li.textContent = "none found (tvsctl analyze FILE --report DATA_DIR/NAME)";
    ul.replaceChildren(li);
    return;
  }
  ul.replaceChildren(...tvs.reports.map((r) => {
    const li = document.createElement("li");
    const a = document.createElement("a");
    a.href = `report?path=${encodeURIComponent(r.path)}`;
    a.textContent = r.title;
    const raw = document.createElement("a");
    raw.href = `reports/${r.path.split("/").map(encodeURIComponent).join("/")}`;
    raw.textContent = "md";
    const note = document.createElement("span"); note.className = "note";
    note.textContent = ` ${r.path} · ${iso(r.mtime_unix)} · `;
    li.append(a, note, raw);
    return li;
  }));
}

let lastCloud = performance.now();
function drawCloudLoop() {
  const now = performance.now();
  tvs.pointsDrawn = Cloud.draw($("cloud"), tvs.points, (now - lastCloud) / 1000);
  $("cloud-note").textContent = `${tvs.points.length} newest of ${tvs.pointsTotal ?? 0}, coloured by σ`;
  lastCloud = now;
}

Cloud.attach($("cloud"), drawCloudLoop);
for (const r of document.querySelectorAll("input[name=spec]")) r.addEventListener("change", drawSpectra);
window.addEventListener("resize", () => { drawSpeed(); drawLateness(); drawSpectra(); drawCloudLoop(); });
setInterval(drawCloudLoop, 100);
connect();
