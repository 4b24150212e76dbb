// rota ground station page: live data from /api/events (server-sent events, read
// with fetch so that every request carries this session's token), commands to
// /api/cmd/<name>. No external code; drawn on two canvases.
"use strict";

// Silence after which the page shows "no contact", s: as NO_CONTACT_S in
// companion/gs/view.py (the service sends telemetry at 10 Hz, status at 2 Hz).
const NO_CONTACT_S = 1.5;
const TOKEN_KEY = "rota-gs-token";
const S = { status: null, telemetry: null, map: null, plans: {}, latestPlan: null, rejected: null,
            newest: null, events: [], trail: [], hist: [], planStart: null, connected: false,
            ages: null, contact: false, heardOnce: false, silenceAtFlip: null, drawn: {} };
window.rotaGs = S;  // for people and tests to inspect
const $ = (id) => document.getElementById(id);
const fmt = (x, d = 2) => (x === null || x === undefined ? "-" : Number(x).toFixed(d));
const norm = (v) => (v ? Math.hypot(v[0], v[1], v[2]) : null);
const now = () => performance.now() / 1000;

// ------------------------------------------------------------------ the token
// Given in the address after "#" (never sent to a server), then kept in this
// tab's session storage, which only this page's origin can read.
function takeToken() {
  const m = location.hash.match(/token=([A-Za-z0-9_-]+)/);
  if (m) {
    sessionStorage.setItem(TOKEN_KEY, m[1]);
    history.replaceState(null, "", location.pathname);  // out of the address bar
  }
  return sessionStorage.getItem(TOKEN_KEY);
}
let token = takeToken();
const auth = () => ({ Authorization: `Bearer ${token}` });

function needToken(why) {
  token = null;
  sessionStorage.removeItem(TOKEN_KEY);
  $("login").hidden = false;
  $("conn").textContent = `page: ${why}`;
  enableButtons();
}
// the address with its token opened in a tab that shows the page already
window.addEventListener("hashchange", () => {
  const t = takeToken();
  if (t && t !== token) { token = t; $("login").hidden = true; stream(); }
});
$("token-use").addEventListener("click", () => {
  const t = $("token-input").value.trim();
  if (!t) return;
  token = t;
  sessionStorage.setItem(TOKEN_KEY, t);
  $("token-input").value = "";
  $("login").hidden = true;
  stream();
});

function logEvent(text, kind = "") {
  const t = new Date().toLocaleTimeString();
  S.events.push({ t, text, kind });
  const li = document.createElement("li");
  li.textContent = `${t} ${text}`;
  if (kind) li.className = kind;
  $("log").prepend(li);
  while ($("log").children.length > 200) $("log").lastChild.remove();
}

// ------------------------------------------------------------------ data in
function onStatus(s) {
  const old = S.status || {};
  S.status = s;
  if (old.state !== s.state) logEvent(`state ${s.state}`);
  if (s.trajectory_id && old.trajectory_id !== s.trajectory_id) logEvent(`flying ${s.trajectory_id}`);
  if (s.command !== old.command && s.command && s.command !== "plan")
    logEvent(`${s.command}: ${s.hold_reason || ""}`);
  const e = s.last_error;
  if (e && (!old.last_error || old.last_error.stamp !== e.stamp))
    logEvent(`error (${e.source}): ${e.message}`, "error");
  const ow = old.warnings || [];
  for (const w of (s.warnings || [])) if (!ow.includes(w)) logEvent(`warning: ${w}`, "warning");
  const plan = currentPlan();
  if (plan && s.progress !== null && s.progress !== undefined && plan.id === s.trajectory_id)
    S.planStart = now() - s.progress * plan.duration;
  else if (!s.trajectory_id) S.planStart = null;
  showStatus();
}

function onTelemetry(t) {
  S.telemetry = t;
  if (t.position) {
    S.trail.push(t.position);
    if (S.trail.length > 3000) S.trail.shift();
  }
  S.hist.push({ t: now(), v: norm(t.velocity), c: t.setpoint ? norm(t.setpoint.velocity) : null });
  while (S.hist.length && S.hist[0].t < now() - 120) S.hist.shift();
  showTelemetry();
}

function onPlan(p) {
  S.newest = p;
  if (p.status === "rejected") {  // never flown: drawn apart, without speeds or zones
    S.rejected = p;
    logEvent(`REJECTED ${p.id}: ${p.message || "no reason given"}`, "error");
    return;
  }
  S.plans[p.id] = p;
  S.latestPlan = p;
  logEvent(`re-timed ${p.id}: ${p.status}, ${fmt(p.duration)} s, ${p.zones.length} braking zone(s)`,
           p.status === "optimal" ? "" : "warning");
}

function currentPlan() {
  const id = S.status && S.status.trajectory_id;
  return (id && S.plans[id]) || S.latestPlan;
}

// The limits in force: the service's status carries them after every change.
function limits() { return S.status && S.status.limits ? S.status.limits : null; }
function vMax() { const l = limits(); return l ? l.v_max : null; }

// ------------------------------------------------------------------ contact
function age(name) {
  const a = S.ages && S.ages[name];
  return a === null || a === undefined ? null : a + (now() - S.ages.at);
}
function contactAge() {
  const a = [age("status"), age("telemetry")].filter((x) => x !== null);
  return a.length ? Math.min(...a) : null;
}
const ago = (a) => (a === null ? "never" : `${fmt(a, 1)} s ago`);

function showContact() {
  const a = contactAge(), live = a !== null && a <= NO_CONTACT_S;
  if (live !== S.contact) {
    S.contact = live;
    if (live) {
      if (S.heardOnce) logEvent("contact again");
      S.heardOnce = true;
      S.silenceAtFlip = null;
    } else if (S.heardOnce) {
      S.silenceAtFlip = a;  // how long the service had been silent when the page turned
      logEvent(`NO CONTACT: nothing from the service for ${fmt(a, 1)} s`, "error");
    }
  }
  document.body.classList.toggle("stale", !live);
  const heard = `status ${ago(age("status"))}, telemetry ${ago(age("telemetry"))}`;
  $("ages").textContent = heard;
  badge($("contact"), live ? `heard ${fmt(a, 1)} s ago` : a === null ? "no contact yet"
        : `NO CONTACT ${fmt(a, 0)} s`, live ? "ok" : "bad");
  $("stale-banner").hidden = live || a === null;
  $("stale-text").textContent = `nothing heard for ${fmt(a, 1)} s (${heard})`;
  enableButtons();
}

// Commands that need the vehicle's state known (data-live) wait for contact;
// hold, land and abort can always be tried.
function enableButtons() {
  for (const b of document.querySelectorAll("button[data-cmd]"))
    b.disabled = !token || (b.dataset.live === "1" && !S.contact);
}

// ------------------------------------------------------------------ panels
function badge(el, text, cls) { el.textContent = text; el.className = "badge " + cls; }

function showStatus() {
  const s = S.status;
  $("vehicle").textContent = s.vehicle;
  const cls = { offboard: "ok", airborne: "ok", armed: "warn", prestream: "warn", landing: "warn",
                link_lost: "bad", not_ready: "bad" }[s.state] || "";
  badge($("state"), s.state, S.contact ? cls : "stale");
  badge($("link"), s.link ? "link ok" : "link LOST", S.contact ? (s.link ? "ok" : "bad") : "stale");
  $("mode").textContent = `${s.flight_mode || "-"} (${s.landed_state || "-"})`;
  $("command").textContent = s.command ? `${s.command}${s.hold_reason ? ": " + s.hold_reason : ""}` : "not streaming";
  $("plan-id").textContent = s.trajectory_id
    ? `${s.trajectory_id}: ${Math.round(100 * (s.progress || 0))} %, ${fmt(s.remaining_s, 1)} s to go` : "-";
  const r = s.last_retime;
  $("retime").textContent = r ? `${r.id}: ${r.status}, ${r.input_duration} s → ${r.duration} s, solve ${Math.round(1000 * r.solve_time)} ms`
    + (r.status === "rejected" && r.message ? ` (${r.message})` : "") : "-";
  const l = limits();
  $("limits").textContent = l ? `v_max ${l.v_max} m/s, a_max [${l.a_max.join(", ")}] m/s²` : "-";
  $("rejected").textContent = S.rejected ? `${S.rejected.id}: ${S.rejected.message || "-"}` : "-";
  $("map-voxels").textContent = s.map_voxels ? `${s.map_voxels} occupied voxels` : "none";
  $("error").textContent = s.last_error ? `${s.last_error.source}: ${s.last_error.message}` : "-";
  const plan = currentPlan();
  if (plan && S.planStart !== null) {
    const t = now() - S.planStart;
    const ahead = plan.zone_times.filter(([, b]) => b > t);
    $("zones").textContent = ahead.length
      ? ahead.map(([a, b]) => `in ${fmt(Math.max(a - t, 0), 1)} s for ${fmt(b - Math.max(a, t), 1)} s`).join(", ")
      : `none ahead (${plan.zones.length} in ${plan.id})`;
  } else {
    $("zones").textContent = plan ? `${plan.zones.length} in ${plan.id}` : "-";
  }
}

function showTelemetry() {
  const t = S.telemetry, a = age("telemetry");
  const old = a !== null && a > NO_CONTACT_S ? ` (${fmt(a, 1)} s old)` : "";
  $("position").textContent = t.position ? `(${t.position.map((x) => fmt(x)).join(", ")}) m ENU${old}` : "-";
  const v = norm(t.velocity);
  $("speed-now").textContent = v === null ? "-" : `${fmt(v)} m/s${old}` + (vMax() ? ` (limit ${vMax()})` : "");
  $("tracking").textContent = t.tracking_error == null ? "-" : `${fmt(t.tracking_error)} m${old}`;
}

// ------------------------------------------------------------------ drawing
function speedColour(v, vmax) {
  const x = Math.max(0, Math.min(1, v / (vmax || 2)));
  const stops = [[68, 1, 84], [33, 145, 140], [170, 220, 50]];  // viridis-like; zones are orange
  const i = x < 0.5 ? 0 : 1, f = x < 0.5 ? x * 2 : (x - 0.5) * 2;
  const c = stops[i].map((a, k) => Math.round(a + f * (stops[i + 1][k] - a)));
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}

function mapBounds() {
  const xs = [], ys = [];
  const add = (p) => { xs.push(p[0]); ys.push(p[1]); };
  if (S.map) S.map.cells.forEach(add);
  Object.values(S.plans).forEach((p) => p.planned.forEach(add));
  if (S.newest && S.newest.status === "rejected") S.newest.planned.forEach(add);
  S.trail.forEach(add);
  if (!xs.length) return [-5, -5, 5, 5];
  return [Math.min(...xs) - 1, Math.min(...ys) - 1, Math.max(...xs) + 1, Math.max(...ys) + 1];
}

function drawMap() {
  const cv = $("map"), g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  const [x0, y0, x1, y1] = mapBounds();
  const k = Math.min(cv.width / (x1 - x0), cv.height / (y1 - y0));
  const X = (x) => (x - x0) * k, Y = (y) => cv.height - (y - y0) * k;
  const line = (pts, style, width, dash = []) => {
    if (pts.length < 2) return;
    g.beginPath(); g.setLineDash(dash); g.strokeStyle = style; g.lineWidth = width;
    pts.forEach((p, i) => (i ? g.lineTo(X(p[0]), Y(p[1])) : g.moveTo(X(p[0]), Y(p[1]))));
    g.stroke(); g.setLineDash([]);
  };
  g.strokeStyle = "#eef0f3"; g.lineWidth = 1;  // 1 m grid
  for (let x = Math.ceil(x0); x <= x1; x++) { g.beginPath(); g.moveTo(X(x), 0); g.lineTo(X(x), cv.height); g.stroke(); }
  for (let y = Math.ceil(y0); y <= y1; y++) { g.beginPath(); g.moveTo(0, Y(y)); g.lineTo(cv.width, Y(y)); g.stroke(); }
  if (S.map) {
    g.fillStyle = "#7b8794";
    const r = S.map.resolution * k;
    for (const c of S.map.cells) g.fillRect(X(c[0]) - r / 2, Y(c[1]) - r / 2, r + 0.5, r + 0.5);
  }
  const plan = currentPlan();
  if (plan) {
    line(plan.planned, "#9aa5b1", 1.5, [6, 4]);
    for (const z of plan.zones) { g.lineCap = "round"; line(z, "rgba(237,137,54,.55)", 14); g.lineCap = "butt"; }
    for (let i = 1; i < plan.path.length; i++)
      line([plan.path[i - 1], plan.path[i]], speedColour(plan.speed[i], vMax()), 3.5);
  }
  // the newest result rejected: its path in red dashes, no speeds, no zones, the reason
  const rej = S.newest && S.newest.status === "rejected" ? S.newest : null;
  if (rej && rej.planned.length) {
    line(rej.planned, "#c53030", 2.5, [8, 5]);
    const p = rej.planned[0], q = rej.planned[rej.planned.length - 1];
    g.strokeStyle = "#c53030"; g.lineWidth = 2.5;
    g.beginPath(); g.moveTo(X(q[0]) - 7, Y(q[1]) - 7); g.lineTo(X(q[0]) + 7, Y(q[1]) + 7);
    g.moveTo(X(q[0]) - 7, Y(q[1]) + 7); g.lineTo(X(q[0]) + 7, Y(q[1]) - 7); g.stroke();
    g.fillStyle = "#c53030"; g.font = "bold 13px system-ui";
    g.fillText(`REJECTED ${rej.id}: ${(rej.message || "").slice(0, 90)}`, 8, 18);
    g.fillText("never flown", X(p[0]) + 8, Y(p[1]) - 8);
  }
  S.drawn = { plan: plan ? plan.id : null, zones: plan ? plan.zones.length : 0,
              rejected: rej ? rej.id : null };
  line(S.trail, S.contact ? "#111" : "#9aa5b1", 1.2);
  const t = S.telemetry;
  if (t && t.setpoint) {
    const p = t.setpoint.position;
    g.strokeStyle = "#2b6cb0"; g.lineWidth = 2;
    g.beginPath(); g.moveTo(X(p[0]) - 6, Y(p[1])); g.lineTo(X(p[0]) + 6, Y(p[1]));
    g.moveTo(X(p[0]), Y(p[1]) - 6); g.lineTo(X(p[0]), Y(p[1]) + 6); g.stroke();
  }
  if (t && t.position) {
    const p = t.position, v = t.velocity || [0, 0, 0];
    const ink = S.contact ? "#111" : "#9aa5b1";  // grey: where it was when last heard
    g.fillStyle = ink; g.beginPath(); g.arc(X(p[0]), Y(p[1]), 7, 0, 2 * Math.PI); g.fill();
    line([p, [p[0] + v[0], p[1] + v[1]]], ink, 2);
  }
  g.fillStyle = "#52606d"; g.font = "12px system-ui";
  g.fillText("1 m grid, x east →, y north ↑", 8, cv.height - 8);
  $("ramp-max").textContent = vMax() === null ? "v_max" : vMax();
}

function drawSpeed() {
  const cv = $("speed"), g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  const L = 36, R = 8, T = 8, B = 22, W = cv.width - L - R, H = cv.height - T - B;
  const tn = now(), span = [-40, 10];
  const vmax = vMax() || 2, top = vmax * 1.35;
  const X = (t) => L + ((t - tn - span[0]) / (span[1] - span[0])) * W;
  const Y = (v) => T + H - (Math.min(v, top) / top) * H;
  const plan = currentPlan();
  if (plan && S.planStart !== null) {
    g.fillStyle = "rgba(237,137,54,.35)";
    for (const [a, b] of plan.zone_times) {
      const xa = X(S.planStart + a), xb = Math.max(X(S.planStart + b), xa + 3);
      g.fillRect(Math.max(xa, L), T, Math.max(Math.min(xb, L + W) - Math.max(xa, L), 0), H);
    }
  }
  g.strokeStyle = "#d9dde3"; g.lineWidth = 1; g.fillStyle = "#52606d"; g.font = "11px system-ui";
  for (let v = 0; v <= top; v += 0.5) {
    g.beginPath(); g.moveTo(L, Y(v)); g.lineTo(L + W, Y(v)); g.stroke();
    if (Math.abs(v - Math.round(v)) < 1e-9) g.fillText(v.toFixed(0), 12, Y(v) + 4);
  }
  for (let s = span[0]; s <= span[1]; s += 10) g.fillText(s === 0 ? "now" : `${s} s`, X(tn + s) - 10, cv.height - 6);
  g.beginPath(); g.strokeStyle = "#111"; g.moveTo(X(tn), T); g.lineTo(X(tn), T + H); g.setLineDash([2, 3]); g.stroke(); g.setLineDash([]);
  const series = (key, style) => {
    g.beginPath(); g.strokeStyle = style; g.lineWidth = 1.6;
    let on = false;
    for (const h of S.hist) {
      if (h[key] === null) { on = false; continue; }
      on ? g.lineTo(X(h.t), Y(h[key])) : g.moveTo(X(h.t), Y(h[key])); on = true;
    }
    g.stroke();
  };
  series("c", "#2b6cb0");
  series("v", "#111");
  if (plan && S.planStart !== null) {
    g.beginPath(); g.strokeStyle = "#805ad5"; g.setLineDash([5, 3]); g.lineWidth = 1.5;
    let on = false;
    plan.limit_t.forEach((t, i) => {
      const v = plan.limits[i];
      if (v === null) { on = false; return; }
      on ? g.lineTo(X(S.planStart + t), Y(v)) : g.moveTo(X(S.planStart + t), Y(v)); on = true;
    });
    g.stroke(); g.setLineDash([]);
  }
  g.beginPath(); g.strokeStyle = "#c53030"; g.lineWidth = 1.5; g.moveTo(L, Y(vmax)); g.lineTo(L + W, Y(vmax)); g.stroke();
  S.drawn.vMaxLine = vMax();  // the line drawn at the limit in force (null: none known, drawn at 2)
  g.fillStyle = "#c53030"; g.fillText(vMax() === null ? "v_max ?" : `v_max ${vMax()}`, L + W - 60, Y(vmax) - 4);
  g.save(); g.translate(10, T + H / 2); g.rotate(-Math.PI / 2); g.fillText("speed (m/s)", -30, -1); g.restore();
}

// ------------------------------------------------------------------ commands
async function send(name) {
  if (!token) { needToken("no token"); return; }
  logEvent(`command ${name} sent`);
  try {
    const r = await fetch(`/api/cmd/${name}`, { method: "POST", headers: auth() });
    if (r.status === 401) { needToken("the token was refused"); logEvent(`${name}: not sent (no valid token)`, "error"); return; }
    const reply = await r.json();
    logEvent(`${name}: ${reply.ok ? "ok" : "REFUSED"}${reply.message ? " - " + reply.message : ""}`,
             reply.ok ? "" : "error");
  } catch (err) {
    logEvent(`${name}: no answer (${err})`, "error");
  }
}

let pending = null;
function confirmThen(text, name) {
  pending = name;
  $("confirm-text").textContent = text;
  $("confirm").hidden = false;
  $("confirm-no").focus();
}
$("confirm-yes").addEventListener("click", () => { $("confirm").hidden = true; if (pending) send(pending); pending = null; });
$("confirm-no").addEventListener("click", () => { $("confirm").hidden = true; pending = null; });
for (const b of document.querySelectorAll("button[data-cmd]")) {
  b.addEventListener("click", () => (b.dataset.confirm ? confirmThen(b.dataset.confirm, b.dataset.cmd) : send(b.dataset.cmd)));
}

// ------------------------------------------------------------------ wiring
const handlers = { status: onStatus, telemetry: onTelemetry, plan: onPlan,
                   map: (m) => { S.map = m; logEvent(`map: ${m.cells.length} occupied cells seen from above`); },
                   ages: (a) => { S.ages = { status: a.status, telemetry: a.telemetry, at: now() }; },
                   reply: () => {} };

function dispatch(block) {
  let name = "message", data = "";
  for (const line of block.split("\n")) {
    if (line.startsWith("event: ")) name = line.slice(7);
    else if (line.startsWith("data: ")) data += line.slice(6);
  }
  if (handlers[name] && data) handlers[name](JSON.parse(data));
}

let streaming = false;
async function stream() {
  if (streaming) return;
  streaming = true;
  while (token) {
    try {
      const r = await fetch("/api/events", { headers: auth(), cache: "no-store" });
      if (r.status === 401) { needToken("the token was refused"); break; }
      if (r.status === 403) { $("conn").textContent = "page: refused (403: host or origin)"; break; }
      if (!r.ok) throw new Error(`HTTP ${r.status}`);
      S.connected = true; $("conn").textContent = "page: live";
      const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
      let buf = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buf += value;
        for (let i; (i = buf.indexOf("\n\n")) >= 0; buf = buf.slice(i + 2)) dispatch(buf.slice(0, i));
      }
    } catch (err) { /* the ground station is gone: try again */ }
    S.connected = false;
    if (token) $("conn").textContent = "page: reconnecting";
    await new Promise((res) => setTimeout(res, 1000));
  }
  streaming = false;
}

if (token) stream(); else needToken("no token");
setInterval(() => {
  showContact();
  if (S.status) showStatus();
  if (S.telemetry) showTelemetry();
  drawMap(); drawSpeed();
}, 100);
