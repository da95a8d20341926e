// slimfarm dashboard: plain JS, no build step, served from the daemon.
//
// Log in: the API key is sent once, as X-Api-Key on GET /api/whoami, which
// makes a session on the daemon and sets its HttpOnly cookie; the page
// keeps only the session's CSRF token (in memory), never the key.  GETs
// (fetch, EventSource, <img>) go by the cookie; a change also sends the
// CSRF token as X-Csrf-Token.  A new tab of the same browser has the
// cookie: GET /api/whoami by the cookie alone gives it the CSRF token, so
// it is logged in too.  "Log out" ends the session on the daemon (POST
// /api/logout), which clears the cookie.  A session that ended (expired,
// logged out elsewhere, a restarted daemon) brings back the login form.
// Live state comes from /api/events (Server-Sent Events); each event
// refetches what it touched, so the page never reloads.  A lost stream
// shows a banner; EventSource reconnects by itself, and when the stream
// was refused the page checks its session and opens a new stream.
"use strict";

const $ = (sel, root) => (root || document).querySelector(sel);
const KEY = "slimfarm.key"; // where older pages kept the key: removed on load
const HIST = 120; // temperature samples kept per printer (about 10 minutes)

const st = {
  csrf: "", // the session's CSRF token; "" when logged out
  readOnly: true,
  printers: new Map(), // name -> printer JSON
  jobs: new Map(), // id -> job JSON
  hist: new Map(), // printer name -> [[t, nozzle, bed]]
  cards: new Map(), // printer name -> card element
  es: null,
  retryMs: 1000,
  refreshTimer: 0,
  tempTimer: 0,
  view: "",
};

function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else if (v !== null && v !== undefined && v !== false) e.setAttribute(k, v === true ? "" : v);
  }
  for (const c of kids) if (c !== null && c !== undefined) e.append(c);
  return e;
}

function showError(msg) {
  const b = $("#error");
  b.textContent = msg;
  b.hidden = !msg;
}

class HttpError extends Error {
  constructor(status, msg) {
    super(msg);
    this.status = status;
  }
}

async function api(path, opts) {
  opts = opts || {};
  const headers = Object.assign({}, opts.headers || {});
  if (opts.method && opts.method !== "GET" && opts.method !== "HEAD") headers["X-Csrf-Token"] = st.csrf;
  const r = await fetch(path, Object.assign({}, opts, { headers, credentials: "same-origin" }));
  if (r.status === 401) {
    if (!opts.quiet) loggedOut(st.csrf ? "Your session ended: log in again." : "The key was refused.");
    throw new HttpError(401, "unauthorized");
  }
  const text = await r.text();
  let body = null;
  try {
    body = text ? JSON.parse(text) : null;
  } catch (e) {
    body = null;
  }
  if (!r.ok) throw new HttpError(r.status, (body && body.error) || r.status + " " + r.statusText);
  return body;
}

// An action button's handler: run it, show its error, refresh.
function act(fn) {
  return async (ev) => {
    const b = ev && ev.currentTarget;
    if (b) b.disabled = true;
    try {
      showError("");
      await fn();
    } catch (e) {
      if (e.status !== 401) showError(e.message);
    } finally {
      if (b) b.disabled = false;
      scheduleRefresh(0);
    }
  };
}

// ---- login ----

// key: log in with it; none: the session this browser has (a new tab).
async function login(key) {
  const who = key
    ? await api("/api/whoami", { headers: { "X-Api-Key": key } })
    : await api("/api/whoami", { quiet: true });
  st.csrf = who.csrf;
  st.readOnly = !!who.read_only;
  document.body.classList.toggle("ro", st.readOnly);
  $("#who").textContent = st.readOnly ? "read-only key" : "operator key";
  $("#login").hidden = true;
  $("#app").hidden = false;
  $("#logout").hidden = false;
  await refreshAll();
  connect();
  route();
}

// The session is over (or never was): show the login form.
function loggedOut(msg) {
  st.csrf = "";
  if (st.es) st.es.close();
  st.es = null;
  clearInterval(st.tempTimer);
  $("#app").hidden = true;
  $("#logout").hidden = true;
  $("#login").hidden = false;
  $("#who").textContent = "";
  setConn("offline", "");
  $("#login-error").textContent = msg || "";
  $("#key").focus();
}

// "Log out": end the session on the daemon (it clears the cookie), then here.
async function logout() {
  try {
    await api("/api/logout", { method: "POST", quiet: true });
  } catch (e) {
    // the session had ended already, or the daemon is gone: nothing to end
  }
  loggedOut("");
}

// ---- live updates ----

function setConn(text, cls) {
  const c = $("#conn");
  c.textContent = text;
  c.className = "badge " + cls;
}

const EVENT_KINDS = ["job-add", "job-priority", "printer-state", "printer-bed", "job-prepare",
  "job-prepared", "job-prepare-failed", "job-start", "job-pause", "job-resume", "job-print-done",
  "job-print-failed", "job-cancel", "job-crashed", "job-restart", "job-defer"];

function connect() {
  if (st.es) st.es.close();
  const es = new EventSource("/api/events");
  st.es = es;
  es.onopen = () => {
    st.retryMs = 1000;
    $("#banner").hidden = true;
    setConn("live", "live");
    scheduleRefresh(0); // whatever happened while we were away
  };
  es.onerror = () => {
    if (st.es !== es) return;
    $("#banner").hidden = false;
    setConn("reconnecting", "lost");
    if (es.readyState === EventSource.CLOSED) {
      // refused (401: the session ended) or not an event stream: check
      // the session (a 401 brings back the login form), open a new stream
      es.close();
      setTimeout(async () => {
        if (st.es !== es || !st.csrf) return;
        try {
          await api("/api/whoami");
          connect();
        } catch (e) {
          st.retryMs = Math.min(st.retryMs * 2, 10000);
          if (e.status !== 401) es.onerror();
        }
      }, st.retryMs);
    }
  };
  for (const k of EVENT_KINDS) es.addEventListener(k, () => scheduleRefresh(150));
  es.addEventListener("reset", () => refreshAll());
  // temperatures move on idle printers too, where the stream is quiet:
  // sample them while the stream is up and the tab is seen
  clearInterval(st.tempTimer);
  st.tempTimer = setInterval(() => {
    if (st.es === es && es.readyState === EventSource.OPEN && !document.hidden) scheduleRefresh(0);
  }, 5000);
  es.addEventListener("progress", (ev) => {
    try {
      for (const p of JSON.parse(ev.data)) {
        const cur = st.printers.get(p.printer);
        if (cur) {
          cur.progress = p.progress;
          cur.time_left_s = p.time_left_s;
          cur.time_left_from = p.time_left_from;
          cur.job_id = p.job_id;
        }
      }
    } catch (e) {
      /* ignore a malformed snapshot */
    }
    scheduleRefresh(0);
  });
}

function scheduleRefresh(ms) {
  if (st.refreshTimer) return;
  st.refreshTimer = setTimeout(() => {
    st.refreshTimer = 0;
    refreshAll().catch((e) => e.status !== 401 && showError(e.message));
  }, ms);
}

// The jobs the dashboard shows: every live one (a page at a time, following
// "next") and the newest FINISHED_SHOWN finished ones; never the whole history.
const FINISHED_SHOWN = 50;
async function fetchJobs() {
  const jobs = [];
  for (let next = "/api/jobs?limit=500&state=" + ACTIVE.join(","); next;) {
    const r = await api(next);
    jobs.push(...r.jobs);
    next = r.next;
  }
  const done = await api(`/api/jobs?limit=${FINISHED_SHOWN}&order=desc&state=done,failed,cancelled`);
  return { jobs: jobs.concat(done.jobs) };
}

async function refreshAll() {
  const [p, j] = await Promise.all([api("/api/printers"), fetchJobs()]);
  const now = Date.now();
  st.printers.clear();
  for (const x of p.printers) {
    st.printers.set(x.name, x);
    const h = st.hist.get(x.name) || [];
    h.push([now, x.temps.nozzle_c, x.temps.bed_c]);
    while (h.length > HIST) h.shift();
    st.hist.set(x.name, h);
  }
  st.jobs.clear();
  for (const x of j.jobs) st.jobs.set(x.id, x);
  renderPrinters();
  renderQueue();
  fillTargets();
  if (st.view.startsWith("job/")) renderJob(Number(st.view.slice(4)), false);
}

// ---- printers ----

function fmtTime(s) {
  if (!(s >= 0)) return "";
  s = Math.round(s);
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
  return h ? `${h} h ${m} min` : m ? `${m} min ${sec} s` : `${sec} s`;
}

function printerAction(name, action) {
  return act(() => api(`/api/printers/${encodeURIComponent(name)}/${action}`, { method: "POST" }));
}

// The printer's own emergency stop: it halts at once (a Marlin needs a reset
// after it), the job on it fails for good; asked twice, as it cannot be undone.
function emergencyStop(name) {
  const go = printerAction(name, "emergency-stop");
  return (ev) => {
    if (window.confirm(`Emergency stop ${name}? It halts at once; the job on it fails and is not retried.`)) go(ev);
  };
}

function makeCard(p) {
  const name = p.name;
  const c = el("article", { class: "printer", "data-printer": name, "aria-label": "printer " + name });
  c.append(
    el("h3", {}, el("span", { text: name }), el("span", { class: "state" })),
    el("p", { class: "muted spec" }),
    el("p", { class: "job" }),
    el("div", { class: "bar", role: "progressbar", "aria-label": "progress of " + name,
      "aria-valuemin": "0", "aria-valuemax": "100" }, el("div")),
    el("p", { class: "muted eta" }),
    el("div", { class: "temps" }, el("span", { class: "t-noz" }), el("span", { class: "t-bed" })),
    el("canvas", { class: "chart", width: "300", height: "60", role: "img",
      "aria-label": "nozzle and bed temperature history of " + name }),
    el("p", { class: "muted msg" }));
  if (!st.readOnly) {
    c.append(el("div", { class: "actions" },
      el("button", { type: "button", class: "big", "data-act": "cleared",
        "aria-label": "Bed cleared on " + name, onclick: printerAction(name, "cleared") }, "Bed cleared"),
      el("button", { type: "button", "data-act": "pause", "aria-label": "Pause " + name,
        onclick: printerAction(name, "pause") }, "Pause"),
      el("button", { type: "button", "data-act": "resume", "aria-label": "Resume " + name,
        onclick: printerAction(name, "resume") }, "Resume"),
      el("button", { type: "button", class: "danger", "data-act": "cancel",
        "aria-label": "Cancel the print on " + name, onclick: printerAction(name, "cancel") }, "Cancel"),
      el("button", { type: "button", class: "danger", "data-act": "estop",
        "aria-label": "Emergency stop " + name, onclick: emergencyStop(name) }, "Emergency stop")));
  }
  return c;
}

function drawChart(cv, hist) {
  const ctx = cv.getContext("2d");
  const w = cv.width, h = cv.height;
  ctx.clearRect(0, 0, w, h);
  if (hist.length < 1) return;
  let hi = 60;
  for (const [, n, b] of hist) hi = Math.max(hi, n, b);
  hi = Math.ceil(hi / 50) * 50;
  const t0 = hist[0][0], t1 = Math.max(hist[hist.length - 1][0], t0 + 1);
  const x = (t) => ((t - t0) / (t1 - t0)) * (w - 2) + 1;
  const y = (v) => h - 2 - (v / hi) * (h - 4);
  ctx.font = "10px sans-serif";
  ctx.fillStyle = "#8c959f";
  ctx.fillText(hi + " °C", 2, 10);
  for (const [i, color] of [[1, "#d1242f"], [2, "#0969da"]]) {
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    hist.forEach((s, k) => (k ? ctx.lineTo(x(s[0]), y(s[i])) : ctx.moveTo(x(s[0]), y(s[i]))));
    if (hist.length === 1) ctx.lineTo(w - 1, y(hist[0][i]));
    ctx.stroke();
  }
}

function renderPrinters() {
  const grid = $("#printers");
  for (const [name, c] of st.cards) if (!st.printers.has(name)) { c.remove(); st.cards.delete(name); }
  for (const p of st.printers.values()) {
    let c = st.cards.get(p.name);
    if (!c) {
      c = makeCard(p);
      st.cards.set(p.name, c);
      grid.append(c);
    }
    c.className = "printer s-" + p.state;
    c.dataset.state = p.state;
    $(".state", c).textContent = p.state;
    $(".spec", c).textContent = `${p.material || "no material"} · ${p.nozzle_mm} mm nozzle` +
      (p.group ? ` · group ${p.group}` : "") + (p.enabled ? "" : " · disabled");
    const job = p.job_id ? st.jobs.get(p.job_id) : null;
    const jp = $(".job", c);
    jp.textContent = "";
    if (p.job_id) {
      jp.append(el("a", { href: `#job/${p.job_id}` }, `#${p.job_id} ${job ? job.name : ""}`));
    } else {
      jp.append(el("span", { class: "muted", text: "no job" }));
    }
    const pct = Math.round((p.progress || 0) * 100);
    const bar = $(".bar", c);
    bar.setAttribute("aria-valuenow", String(pct));
    bar.firstChild.style.width = (p.job_id ? pct : 0) + "%";
    let eta = "";
    if (p.job_id) {
      // the printer's own estimate when it gives one, else the farm's (the G-code's)
      const whose = p.time_left_from === "printer" ? "the printer's estimate" : "the farm's estimate";
      eta = `${pct} %` + (p.time_left_s != null && p.time_left_from
        ? ` · about ${fmtTime(p.time_left_s)} left (${whose})` : "");
    }
    $(".eta", c).textContent = eta;
    const t = p.temps;
    $(".t-noz", c).textContent = `nozzle ${t.nozzle_c.toFixed(0)} / ${t.nozzle_target_c.toFixed(0)} °C`;
    $(".t-bed", c).textContent = `bed ${t.bed_c.toFixed(0)} / ${t.bed_target_c.toFixed(0)} °C`;
    drawChart($("canvas", c), st.hist.get(p.name) || []);
    $(".msg", c).textContent = p.state === "awaiting-clear" ? "Take the part off the bed, then press Bed cleared." : p.message || "";
    if (!st.readOnly) {
      const show = {
        cleared: p.state === "awaiting-clear",
        pause: p.state === "printing",
        resume: p.state === "paused",
        cancel: p.state === "printing" || p.state === "paused",
        estop: p.state !== "offline" && p.state !== "error",
      };
      for (const b of c.querySelectorAll("button[data-act]")) b.hidden = !show[b.dataset.act];
    }
  }
}

// ---- queue ----

const ACTIVE = ["queued", "preparing", "ready", "printing", "paused", "interrupted"];

function queueOrder(a, b) {
  return b.priority - a.priority || a.id - b.id;
}

function renderQueue() {
  const jobs = [...st.jobs.values()];
  const active = jobs.filter((j) => ACTIVE.includes(j.state)).sort(queueOrder);
  const done = jobs.filter((j) => !ACTIVE.includes(j.state)).sort((a, b) => b.id - a.id);
  const tb = $("#queue tbody");
  tb.textContent = "";
  if (!active.length) tb.append(el("tr", {}, el("td", { colspan: "8", class: "muted", text: "The queue is empty." })));
  active.forEach((j, i) => {
    const link = el("a", { href: `#job/${j.id}` }, `#${j.id}`);
    // data-label: the column's name, shown beside each cell on a phone
    const tr = el("tr", { "data-job": String(j.id), "data-state": j.state },
      el("td", { "data-label": "Job" }, link), el("td", { "data-label": "Part", text: j.name }),
      el("td", { "data-label": "State", text: j.state }),
      el("td", { "data-label": "Copies left", text: String(j.copies - j.copies_done) }),
      el("td", { "data-label": "Priority", text: String(j.priority) }),
      el("td", { "data-label": "Printer", text: j.printer || j.target_printer || j.target_group || "any" }),
      el("td", { "data-label": "Why it waits", class: "muted", text: j.reason || "" }));
    if (!st.readOnly) tr.append(el("td", { "data-label": "Actions" }, jobActions(j, active[i - 1], active[i + 1])));
    tb.append(tr);
  });
  const fb = $("#finished tbody");
  fb.textContent = "";
  for (const j of done.slice(0, 50)) {
    fb.append(el("tr", { "data-job": String(j.id), "data-state": j.state },
      el("td", {}, el("a", { href: `#job/${j.id}` }, `#${j.id}`)), el("td", { text: j.name }),
      el("td", { text: j.state }), el("td", { text: `${j.copies_done} / ${j.copies}` }),
      el("td", { text: j.printer || "" }), el("td", { class: "muted", text: j.reason || "" })));
  }
}

function setPriority(j, prio) {
  prio = Math.max(-1000, Math.min(1000, prio));
  return api(`/api/jobs/${j.id}`, { method: "PATCH", headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ priority: prio }) });
}

function jobActions(j, above, below) {
  const d = el("div", { class: "actions" });
  const id = j.id;
  d.append(el("button", { type: "button", "aria-label": `Move job ${id} up`, disabled: !above,
    onclick: act(() => setPriority(j, Math.max(j.priority + 1, above.priority + 1))) }, "▲"));
  d.append(el("button", { type: "button", "aria-label": `Move job ${id} down`, disabled: !below,
    onclick: act(() => setPriority(j, Math.min(j.priority - 1, below.priority - 1))) }, "▼"));
  if (j.state === "interrupted") {
    // the last acknowledged line by default; the operator may pick another
    const line = el("input", { type: "number", min: "1", max: String(Math.max(1, j.gcode_lines - 1)),
      value: String(j.lines_acked), class: "line", "aria-label": `Line to resume job ${id} from` });
    d.append(line);
    d.append(el("button", { type: "button", "aria-label": `Resume job ${id} from the chosen line`,
      onclick: act(() => api(`/api/jobs/${id}/resume`, { method: "POST",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ line: Number(line.value) }) })) }, "Resume"));
    d.append(el("button", { type: "button", "aria-label": `Restart job ${id} from the start`,
      onclick: act(() => api(`/api/jobs/${id}/restart`, { method: "POST" })) }, "Restart"));
  }
  d.append(el("button", { type: "button", class: "danger", "aria-label": `Cancel job ${id}`,
    onclick: act(() => api(`/api/jobs/${id}/cancel`, { method: "POST" })) }, "Cancel"));
  return d;
}

// ---- submit ----

function fillTargets() {
  const sel = $("#target");
  const cur = sel.value;
  const groups = new Set(), mats = new Set();
  sel.textContent = "";
  sel.append(el("option", { value: "" }, "any printer"));
  for (const p of st.printers.values()) {
    sel.append(el("option", { value: "printer:" + p.name }, "printer " + p.name));
    if (p.group) groups.add(p.group);
    if (p.material) mats.add(p.material);
  }
  for (const g of groups) sel.append(el("option", { value: "group:" + g }, "group " + g));
  sel.value = cur;
  const dl = $("#materials");
  dl.textContent = "";
  for (const m of mats) dl.append(el("option", { value: m }));
}

function setupSubmit() {
  const drop = $("#drop"), file = $("#file");
  const shown = () => ($("#file-name").textContent = file.files[0] ? file.files[0].name : "");
  file.addEventListener("change", shown);
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    if (e.dataTransfer.files.length) {
      file.files = e.dataTransfer.files;
      shown();
    }
  });
  drop.addEventListener("keydown", (e) => {
    if (e.key === "Enter" || e.key === " ") { e.preventDefault(); file.click(); }
  });
  $("#submit-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    const msg = $("#submit-msg");
    if (!file.files[0]) { msg.textContent = "Choose a part first."; return; }
    const o = {
      method: $("#method").value,
      deviation_mm: Number($("#deviation").value),
      copies: Number($("#copies").value),
      priority: Number($("#priority").value),
    };
    const mat = $("#material").value.trim();
    if (mat) o.material = mat;
    const t = $("#target").value;
    if (t.startsWith("printer:")) o.printer = t.slice(8);
    if (t.startsWith("group:")) o.group = t.slice(6);
    const fd = new FormData();
    fd.append("file", file.files[0], file.files[0].name);
    fd.append("options", JSON.stringify(o));
    const btn = $("#submit-btn");
    btn.disabled = true;
    msg.textContent = "Uploading…";
    try {
      const r = await api("/api/jobs", { method: "POST", body: fd });
      msg.textContent = `Job ${r.job.id} queued.`;
      file.value = "";
      shown();
      location.hash = `#job/${r.job.id}`;
    } catch (err) {
      msg.textContent = err.message;
    } finally {
      btn.disabled = false;
    }
  });
}

// ---- job page ----

let jobShown = 0, layerData = null;

function fact(k, v) {
  return el("tr", {}, el("th", { scope: "row", text: k }), el("td", { text: v }));
}

// The support model's estimate for a picture (computed when it is drawn).
function model(m) {
  return m ? `${m.support_g.toFixed(2)} g, ${fmtTime(m.support_s)} of support printing` : "computing with the picture…";
}

function saving(b, a) {
  if (!b || !a || !(b.support_g > 0)) return "";
  const pct = (100 * (b.support_g - a.support_g)) / b.support_g;
  return ` (${pct >= 0 ? pct.toFixed(0) + " % less" : (-pct).toFixed(0) + " % more"})`;
}

// MNDR / ANDR: the largest and the mean vertex move over the part's bounding-box
// diagonal (src/geom/measure.h), as percentages, against the job's budget in mm
// (the move in mm is estimated from the diagonal of the part as it prints).
function deviation(j) {
  if (j.mndr === null || j.mndr === undefined) return j.size_mm[2] ? "not measured" : "not prepared yet";
  const pct = (v) => `${(100 * v).toFixed(2)} %`;
  const diag = Math.hypot(j.size_mm[0], j.size_mm[1], j.size_mm[2]);
  const head = `MNDR ${pct(j.mndr)}, ANDR ${pct(j.andr)} of the bounding-box diagonal`;
  if (!j.shape_changed) return `${head}: shape kept (reshaping did not save support)`;
  return `${head} (largest move ≈ ${(j.mndr * diag).toFixed(2)} mm of the ${j.deviation_mm} mm budget)`;
}

function fmtMs(ms) {
  return ms ? new Date(ms).toLocaleString() : "";
}

async function renderJob(id, fresh) {
  let d, r;
  try {
    [d, r] = await Promise.all([api(`/api/jobs/${id}`), api(`/api/jobs/${id}/report`)]);
  } catch (e) {
    if (e.status !== 401) showError(e.message);
    return;
  }
  if (st.view !== "job/" + id) return;
  const j = d.job;
  $("#job-h").textContent = `Job #${j.id}: ${j.name}`;
  const view = $("#view-job");
  view.dataset.job = String(j.id);
  view.dataset.state = j.state;
  const acts = $("#job-actions");
  acts.textContent = "";
  if (!st.readOnly && ACTIVE.includes(j.state)) acts.append(jobActions(j, null, null));
  for (const b of acts.querySelectorAll("button[disabled]")) b.remove();
  const g = r.gcode;
  const prints = d.prints;
  const went = j.printer || (prints.length ? prints[prints.length - 1].printer : "");
  const rows = [
    ["State", j.state + (j.reason ? ` (${j.reason})` : "")],
    ["Method", `${j.method}, deviation budget ${j.deviation_mm} mm` + (j.overhang_deg ? `, overhang ${j.overhang_deg}°` : "")],
    ["Part changed", r.optimized ? "yes: oriented/shaped part saved" : "no: printed as uploaded"],
    ["Copies", `${j.copies_done} of ${j.copies} done, ${j.failures} failed prints`],
    ["Material", j.material || "the printer's"],
    ["Printer", went || "not yet"],
    ["Size as printed", j.size_mm[2] ? j.size_mm.map((v) => v.toFixed(1)).join(" × ") + " mm" : "not prepared yet"],
    ["Print time (estimate)", g && g.time_s >= 0 ? fmtTime(g.time_s) : "not sliced yet"],
    ["Filament", g && g.filament_g >= 0 ? `${g.filament_g.toFixed(2)} g (${(g.filament_mm / 1000).toFixed(2)} m)` : ""],
    ["Support as sliced", g && g.support_g >= 0 ? `${g.support_g.toFixed(2)} g` : ""],
    ["Support before (model)", model(r.model_before)],
    ["Support after (model)", model(r.model_after) + saving(r.model_before, r.model_after)],
    ["Layers", g && g.layers >= 0 ? String(g.layers) : ""],
    ...(j.method === "slim" || j.method === "surface" ? [["Deviation (MNDR / ANDR)", deviation(j)]] : []),
    ["Progress", j.gcode_lines && ["printing", "paused", "interrupted"].includes(j.state)
      ? `line ${j.lines_acked} of ${j.gcode_lines}` : j.gcode_lines ? `${j.gcode_lines} lines` : ""],
  ];
  const tb = $("#job-facts tbody");
  tb.textContent = "";
  for (const [k, v] of rows) tb.append(fact(k, v));
  const pb = $("#job-prints tbody");
  pb.textContent = "";
  for (const p of prints)
    pb.append(el("tr", {}, el("td", { text: String(p.copy) }), el("td", { text: p.printer }),
      el("td", { text: String(p.start_line) }), el("td", { text: String(p.lines_acked) }),
      el("td", { text: (p.filament_mm / 1000).toFixed(2) + " m" }), el("td", { text: fmtMs(p.started_ms) }),
      el("td", { text: fmtMs(p.ended_ms) }), el("td", { text: p.outcome || "printing" })));
  if (!prints.length) pb.append(el("tr", {}, el("td", { colspan: "8", class: "muted", text: "Not printed yet." })));
  // pictures: the cookie authorizes these GETs; "after" changes once prepared
  const before = `/api/jobs/${j.id}/preview.png?stage=before`;
  const after = `/api/jobs/${j.id}/preview.png?stage=after&v=${r.optimized ? "opt" : "in"}`;
  if ($("#pic-before").getAttribute("src") !== before) $("#pic-before").src = before;
  if ($("#pic-after").getAttribute("src") !== after) $("#pic-after").src = after;
  $("#after-cap").textContent = !r.optimized ? "after: unchanged (the part prints as uploaded)"
    : j.method === "orient" ? "after: as it prints (oriented)" : "after: as it prints (oriented and shaped)";
  if (fresh || (j.gcode_sha && (!layerData || layerData.sha !== j.gcode_sha))) loadLayers(j);
}

async function loadLayers(j) {
  const msg = $("#layer-msg"), slider = $("#layer");
  if (!j.gcode_sha) {
    layerData = null;
    slider.disabled = true;
    msg.textContent = "No G-code yet: the job is not sliced.";
    $("#layer-canvas").getContext("2d").clearRect(0, 0, 600, 600);
    return;
  }
  if (layerData && layerData.sha === j.gcode_sha) return;
  layerData = { sha: j.gcode_sha, layers: [] };
  msg.textContent = "Loading the G-code…";
  const r = await fetch(`/api/jobs/${j.id}/gcode`, { credentials: "same-origin" });
  if (!r.ok) { msg.textContent = "Could not load the G-code: " + r.status; return; }
  layerData = parseGcode(await r.text(), j.gcode_sha);
  const n = layerData.layers.length;
  slider.max = String(Math.max(0, n - 1));
  slider.value = String(Math.floor(n / 2));
  slider.disabled = n === 0;
  slider.setAttribute("aria-valuetext", `layer ${Math.floor(n / 2) + 1} of ${n}`);
  msg.textContent = n ? `${n} layers; extrusions coloured by role, travel grey.` : "No layers in the G-code.";
  drawLayer();
}

// Moves of each ;LAYER_CHANGE section: [x0, y0, x1, y1, role] (role -1: travel).
function parseGcode(text, sha) {
  const roles = [];
  const layers = [];
  let cur = null, x = 0, y = 0, e = 0, relE = false, role = 0, z = 0;
  const box = [Infinity, Infinity, -Infinity, -Infinity];
  for (const raw of text.split("\n")) {
    if (raw.startsWith(";LAYER_CHANGE")) { cur = { segs: [], z }; layers.push(cur); continue; }
    if (raw.startsWith(";Z:") && cur) { cur.z = parseFloat(raw.slice(3)); continue; }
    if (raw.startsWith(";TYPE:")) {
      const name = raw.slice(6).trim();
      role = roles.indexOf(name);
      if (role < 0) { roles.push(name); role = roles.length - 1; }
      continue;
    }
    const line = raw.split(";")[0].trim();
    if (!line) continue;
    const w = line.split(/\s+/);
    const cmd = w[0];
    if (cmd === "M83") relE = true;
    else if (cmd === "M82") relE = false;
    else if (cmd === "G92") { for (const a of w) if (a[0] === "E") e = parseFloat(a.slice(1)); }
    else if (cmd === "G0" || cmd === "G1") {
      let nx = x, ny = y, ne = null;
      for (const a of w.slice(1)) {
        const v = parseFloat(a.slice(1));
        if (a[0] === "X") nx = v; else if (a[0] === "Y") ny = v; else if (a[0] === "E") ne = v; else if (a[0] === "Z") z = v;
      }
      let ext = false;
      if (ne !== null) { ext = relE ? ne > 0 : ne > e; e = relE ? e : ne; }
      if (cur && (nx !== x || ny !== y)) {
        cur.segs.push([x, y, nx, ny, ext ? role : -1]);
        if (ext) { box[0] = Math.min(box[0], x, nx); box[1] = Math.min(box[1], y, ny); box[2] = Math.max(box[2], x, nx); box[3] = Math.max(box[3], y, ny); }
      }
      x = nx; y = ny;
    }
  }
  return { sha, layers, roles, box };
}

const ROLE_COLORS = { "Perimeter": "#ffa500", "External perimeter": "#e8590c", "Internal infill": "#b03a2e",
  "Solid infill": "#9b59b6", "Top solid infill": "#e74c3c", "Bottom solid infill": "#8e44ad",
  "Support material": "#2e8b57", "Support material interface": "#2ecc71", "Skirt/Brim": "#16a085",
  "Bridge infill": "#3498db", "Gap fill": "#ecf0f1" };
const FALLBACK = ["#ff8c00", "#c0392b", "#2980b9", "#27ae60", "#8e44ad", "#d35400"];

function drawLayer() {
  const cv = $("#layer-canvas"), ctx = cv.getContext("2d");
  ctx.clearRect(0, 0, cv.width, cv.height);
  if (!layerData || !layerData.layers.length) return;
  const i = Number($("#layer").value);
  const L = layerData.layers[i];
  $("#layer-out").textContent = `${i + 1} of ${layerData.layers.length} (z ${L.z} mm)`;
  $("#layer").setAttribute("aria-valuetext", `layer ${i + 1} of ${layerData.layers.length}`);
  const [x0, y0, x1, y1] = layerData.box;
  const pad = 20, s = Math.min((cv.width - 2 * pad) / Math.max(x1 - x0, 1), (cv.height - 2 * pad) / Math.max(y1 - y0, 1));
  const X = (v) => pad + (v - x0) * s, Y = (v) => cv.height - pad - (v - y0) * s;
  ctx.lineCap = "round";
  for (const travel of [true, false]) {
    for (const [ax, ay, bx, by, r] of L.segs) {
      if ((r < 0) !== travel) continue;
      ctx.strokeStyle = travel ? "rgba(140,149,159,.35)" : ROLE_COLORS[layerData.roles[r]] || FALLBACK[r % FALLBACK.length];
      ctx.lineWidth = travel ? 0.5 : Math.max(1, 0.45 * s);
      ctx.beginPath();
      ctx.moveTo(X(ax), Y(ay));
      ctx.lineTo(X(bx), Y(by));
      ctx.stroke();
    }
  }
}

// ---- views ----

function route() {
  const h = location.hash.replace(/^#/, "");
  st.view = h;
  $("#view-farm").hidden = h !== "";
  $("#view-submit").hidden = h !== "submit";
  $("#view-job").hidden = !h.startsWith("job/");
  if (h.startsWith("job/")) {
    const id = Number(h.slice(4));
    if (id !== jobShown) {
      jobShown = id;
      layerData = null;
      $("#pic-before").removeAttribute("src");
      $("#pic-after").removeAttribute("src");
      $("#job-facts tbody").textContent = "";
    }
    renderJob(id, false);
  } else {
    jobShown = 0;
  }
}

document.addEventListener("DOMContentLoaded", () => {
  $("#login-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    $("#login-error").textContent = "";
    try {
      await login($("#key").value.trim());
      $("#key").value = "";
    } catch (err) {
      if (err.status !== 401) $("#login-error").textContent = err.message;
    }
  });
  $("#logout").addEventListener("click", () => logout());
  $("#layer").addEventListener("input", drawLayer);
  // the support model's numbers come with the pictures
  for (const img of ["#pic-before", "#pic-after"])
    $(img).addEventListener("load", () => jobShown && renderJob(jobShown, false));
  window.addEventListener("hashchange", route);
  setupSubmit();
  sessionStorage.removeItem(KEY);
  login("").catch(() => loggedOut(""));
});
