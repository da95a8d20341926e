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
  down: false, // the daemon does not answer: every action button is disabled
  lastRead: new Map(), // printer name -> {t, noz, bed}: temperatures last read while online
  needs: new Map(), // printer name -> what it needs from the operator ("" none)
  notify: false, // browser notifications granted and asked for
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

// An action button's handler: run it, show its error, refresh.  A fetch
// that finds no daemon says so in words (it never reached the farm).
function act(fn) {
  return async (ev) => {
    const b = ev && ev.currentTarget;
    if (st.down) return;
    if (b) b.disabled = true;
    try {
      showError("");
      await fn();
    } catch (e) {
      if (e.status !== 401) showError(e.status ? e.message : "The farm did not answer: nothing was done. Try again once it is back.");
    } finally {
      if (b) b.disabled = st.down;
      scheduleRefresh(0);
    }
  };
}

// ---- guarded actions: a dialog says in words what will happen ----

// Ask text; resolves true when the operator presses the button named ok.
function ask(title, text, ok) {
  const d = $("#confirm");
  $("#confirm-title").textContent = title;
  $("#confirm-text").textContent = text;
  $("#confirm-ok").textContent = ok;
  return new Promise((done) => {
    d.addEventListener("close", () => done(d.returnValue === "ok"), { once: true });
    d.returnValue = "";
    d.showModal();
    $("#confirm-no").focus(); // the safe answer is the default
  });
}

// A handler that asks (what() gives [title, text, ok] at click time) and then acts.
function guarded(what, fn) {
  const go = act(fn);
  return async (ev) => {
    const b = ev.currentTarget;
    if (st.down) return;
    const [title, text, ok] = what();
    if (await ask(title, text, ok)) go({ currentTarget: b });
  };
}

function copiesLeft(j) {
  return j ? Math.max(0, j.copies - j.copies_done) : 0;
}

// "cancel job #8 (bigbox) and its 2 remaining copies"
function jobCancelText(j, id) {
  const left = copiesLeft(j);
  const name = j ? ` (${j.name})` : "";
  const on = j && (j.state === "printing" || j.state === "paused")
    ? ` The copy printing on ${j.printer} stops; its part stays on the bed.` : "";
  return [`Cancel job #${id}?`,
    `This cancels job #${id}${name} and its ${left} remaining ${left === 1 ? "copy" : "copies"}: ` +
    `none of them will be printed.${on}`, `Cancel job #${id}`];
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
  loadTempHistory().catch(() => {}); // the charts then fill from the tab alone
}

// Each chart starts from the daemon's own samples (GET /api/printers/NAME/temps: the last
// hour, one every 5 s), so a reload or a new tab keeps it; the tab adds its own from then on.
async function loadTempHistory() {
  await Promise.all([...st.printers.keys()].map(async (name) => {
    let r;
    try {
      r = await api(`/api/printers/${encodeURIComponent(name)}/temps`, { quiet: true });
    } catch (e) {
      return; // the chart fills from the tab's own samples
    }
    const mine = st.hist.get(name) || [];
    const first = mine.length ? mine[0][0] : Infinity;
    // [at_ms, nozzle, nozzle target, bed, bed target]; null while the printer was offline
    const old = r.samples.filter((s) => s[0] < first && s[1] != null && s[3] != null)
      .map((s) => [s[0], s[1], s[3]]);
    st.hist.set(name, old.concat(mine).slice(-HIST));
  }));
  renderPrinters();
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
  setDown(false);
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

// The daemon is gone (down) or back: every action button is disabled while
// it is gone, and what failed meanwhile is not left on screen once it is back.
function setDown(down) {
  st.down = down;
  document.body.classList.toggle("down", down);
  applyDown();
  if (!down) showError("");
}

function applyDown() {
  for (const b of document.querySelectorAll("#app button")) {
    if (st.down) b.disabled = true;
    else if (b.dataset.keep !== "disabled") b.disabled = false;
  }
}

const EVENT_KINDS = ["job-add", "job-priority", "job-move", "printer-state", "printer-bed", "job-prepare",
  "job-prepared", "job-prepare-failed", "job-start", "job-pause", "job-resume", "job-print-done",
  "job-print-failed", "job-cancel", "job-cancel-copy", "job-crashed", "job-restart", "job-defer",
  "printer-config"];

function connect() {
  if (st.es) st.es.close();
  const es = new EventSource("/api/events");
  st.es = es;
  es.onopen = () => {
    st.retryMs = 1000;
    $("#banner").hidden = true;
    setConn("live", "live");
    setDown(false);
    scheduleRefresh(0); // whatever happened while we were away
  };
  es.onerror = () => {
    if (st.es !== es) return;
    $("#banner").hidden = false;
    setConn("reconnecting", "lost");
    setDown(true);
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
    refreshAll().catch((e) => e.status && e.status !== 401 && showError(e.message));
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
  renderCounters();
  fillTargets();
  applyDown();
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

function drawChart(cv, hist) {
  const ctx = cv.getContext("2d");
  const w = cv.width, h = cv.height;
  ctx.clearRect(0, 0, w, h);
  cv.dataset.since = hist.length ? String(hist[0][0]) : ""; // the oldest sample drawn (tests read it)
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

function makeCard(p) {
  const name = p.name;
  const c = el("article", { class: "printer", "data-printer": name, "aria-label": "printer " + name });
  c.append(
    el("h3", {}, el("span", { class: "pname", text: name }), el("span", { class: "state" })),
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
    const job = () => st.jobs.get(st.printers.get(name).job_id) || null;
    const held = () => st.printers.get(name).interrupted_job;
    c.append(el("div", { class: "actions" },
      el("button", { type: "button", class: "big", "data-act": "cleared", "aria-label": "Bed cleared on " + name,
        onclick: guarded(() => ["Is the bed of " + name + " clear?",
          `Only if the part is off the bed: ${name} takes the next job at once and prints onto the bed as it is.`,
          "The bed is clear"], () => printerPost(name, "cleared")) }, "Bed cleared"),
      el("button", { type: "button", class: "big", "data-act": "clear-error", "aria-label": "Clear error on " + name,
        onclick: guarded(() => ["Clear the error on " + name + "?",
          `Only once the fault is fixed and the bed is clear: ${name} leaves the error when it reports ready and takes the next job.`,
          "Clear the error"], () => printerPost(name, "cleared")) }, "Clear error"),
      el("button", { type: "button", "data-act": "pause", "aria-label": "Pause " + name,
        onclick: printerAction(name, "pause") }, "Pause"),
      el("button", { type: "button", "data-act": "resume", "aria-label": "Resume " + name,
        onclick: printerAction(name, "resume") }, "Resume"),
      el("button", { type: "button", "data-act": "job-resume", "aria-label": "Resume job on " + name,
        onclick: act(() => api(`/api/jobs/${held()}/resume`, { method: "POST" })) }, "Resume job"),
      el("button", { type: "button", "data-act": "job-restart", "aria-label": "Restart the job on " + name,
        onclick: guarded(() => restartText(held(), st.jobs.get(held())),
          () => api(`/api/jobs/${held()}/restart`, { method: "POST" })) }, "Restart"),
      el("button", { type: "button", class: "danger", "data-act": "cancel", "aria-label": "Stop this copy on " + name,
        onclick: guarded(() => copyCancelText(name, job()), () => printerPost(name, "cancel-copy")) }, "Stop this copy"),
      el("button", { type: "button", class: "danger", "data-act": "job-cancel", "aria-label": "Cancel job on " + name,
        onclick: guarded(() => jobCancelText(st.jobs.get(held()), held()),
          () => api(`/api/jobs/${held()}/cancel`, { method: "POST" })) }, "Cancel job"),
      el("button", { type: "button", class: "danger", "data-act": "estop", "aria-label": "Emergency stop " + name,
        onclick: emergencyStop(name) }, "Emergency stop"),
      ...pmCardButtons(name))); // printers.js
  }
  return c;
}

function printerPost(name, action) {
  return api(`/api/printers/${encodeURIComponent(name)}/${action}`, { method: "POST" });
}

function restartText(id, j) {
  return [`Restart job #${id}?`, `This prints the interrupted copy of job #${id}${j ? ` (${j.name})` : ""} again ` +
    "from its first line: take the half-printed part off the bed first.", "Print it again"];
}

// The card's Stop: this copy only; the job goes on and prints it again.
function copyCancelText(name, j) {
  const copy = j ? `copy ${j.copies_done + 1} of ${j.copies} of job #${j.id} (${j.name})` : "the copy";
  return [`Stop the copy on ${name}?`, `This stops ${copy} on ${name} and prints it again later; ` +
    "the part stays on the bed until you clear it. The rest of the job goes on. " +
    "To cancel the whole job, use Cancel in the queue.", "Stop this copy"];
}

function pct(n, of) {
  return of > 0 ? Math.min(100, Math.round((100 * n) / of)) : 0;
}

// What a printer shows as its state: the daemon's, or what it means for
// the operator (disabled, blocked by an interrupted job, heating).
function shownState(p) {
  if (!p.enabled) return "disabled";
  if (p.interrupted_job && p.state !== "printing" && p.state !== "paused") return "blocked";
  if (p.state === "printing" && heating(p)) return "heating";
  return p.state;
}

// Printing, but the print has not begun: the heaters are on their way up
// (or not told yet).
function heating(p) {
  const t = p.temps;
  if (p.progress >= 0.05) return false; // a target raised mid-print is not a start
  const cold = (v, to) => to > 0 && v < to - 3;
  return cold(t.nozzle_c, t.nozzle_target_c) || cold(t.bed_c, t.bed_target_c) ||
    (t.nozzle_target_c === 0 && t.bed_target_c === 0);
}

// "#8 bigbox · copy 2 of 3 — cancelled at 12 %, bed not cleared": the last
// print on the printer, when that is what its bed holds.
function lastPrintLine(p) {
  const l = p.last_print;
  if (!l) return null;
  const at = l.outcome === "done" ? "done" : l.outcome
    ? `${l.outcome} at ${pct(l.lines_acked, l.gcode_lines)} %` : "printing";
  const bed = p.bed_full ? ", bed not cleared" : "";
  return [l.job_id, `${l.job_name} · copy ${l.copy} of ${l.copies} — ${at}${bed}`];
}

function jobLine(p, jp) {
  jp.textContent = "";
  const link = (id, text) => jp.append(el("a", { href: `#job/${id}` }, `#${id}`), " " + text);
  const j = p.job_id ? st.jobs.get(p.job_id) : null;
  if (p.job_id) {
    link(p.job_id, j ? `${j.name} · copy ${j.copies_done + 1} of ${j.copies}` : "");
  } else if (p.interrupted_job) {
    const h = st.jobs.get(p.interrupted_job);
    link(p.interrupted_job, (h ? h.name + " — " : "") + "interrupted" +
      (h ? ` at line ${h.lines_acked} of ${h.gcode_lines} (${pct(h.lines_acked, h.gcode_lines)} %)` : "") +
      ": its part is on the bed");
  } else if (lastPrintLine(p) && (p.bed_full || p.state === "error" || p.state === "awaiting-clear")) {
    const [id, text] = lastPrintLine(p);
    link(id, text);
  } else {
    jp.append(el("span", { class: "muted", text: p.bed_full ? "no job; a part is on the bed" : "no job" }));
  }
}

// Offline: what was last read is not now; say when it was read.
function tempsLine(p, c) {
  const t = p.temps;
  if (p.state !== "offline") {
    st.lastRead.set(p.name, { t: Date.now(), noz: t.nozzle_c, bed: t.bed_c });
    $(".t-noz", c).textContent = `nozzle ${t.nozzle_c.toFixed(0)} / ${t.nozzle_target_c.toFixed(0)} °C`;
    $(".t-bed", c).textContent = `bed ${t.bed_c.toFixed(0)} / ${t.bed_target_c.toFixed(0)} °C`;
    return "";
  }
  $(".t-noz", c).textContent = "nozzle unknown";
  $(".t-bed", c).textContent = "bed unknown";
  if (!p.enabled) return ""; // never read: the farm does not talk to it
  const r = st.lastRead.get(p.name);
  return r ? `Temperatures unknown: last read ${r.noz.toFixed(0)} / ${r.bed.toFixed(0)} °C at ${new Date(r.t).toLocaleTimeString()}.`
    : "Temperatures unknown: not read since this page opened.";
}

// What the printer needs from the operator, in words ("" nothing).
function needs(p) {
  if (!p.enabled) return "";
  if (p.interrupted_job && p.state !== "printing" && p.state !== "paused")
    return `holds interrupted job #${p.interrupted_job}: resume it, restart it or cancel it`;
  if (p.state === "awaiting-clear") return "take the part off the bed, then press Bed cleared";
  if (p.state === "error") return "error: fix the printer and clear the bed, then press Clear error";
  return "";
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
    const shown = shownState(p);
    c.className = "printer s-" + shown;
    c.dataset.state = p.state;
    c.dataset.shown = shown;
    $(".state", c).textContent = shown;
    $(".spec", c).textContent = `${p.material || "no material"} · ${p.nozzle_mm} mm nozzle` +
      (p.group ? ` · group ${p.group}` : "");
    jobLine(p, $(".job", c));
    const pc = Math.round((p.progress || 0) * 100);
    const bar = $(".bar", c);
    bar.setAttribute("aria-valuenow", String(pc));
    bar.firstChild.style.width = (p.job_id ? pc : 0) + "%";
    let eta = "";
    if (p.job_id && shown === "heating") {
      const t = p.temps;
      eta = `heating: nozzle ${t.nozzle_c.toFixed(0)} → ${t.nozzle_target_c.toFixed(0)} °C, bed ${t.bed_c.toFixed(0)} → ${t.bed_target_c.toFixed(0)} °C`;
    } else if (p.job_id) {
      // the printer's own estimate when it gives one, else the farm's (the G-code's)
      const whose = p.time_left_from === "printer" ? "the printer's estimate" : "the farm's estimate";
      eta = `${pc} %` + (p.time_left_s != null && p.time_left_from
        ? ` · about ${fmtTime(p.time_left_s)} left (${whose}), done about ${clock(Date.now() + p.time_left_s * 1000)}` : "");
    }
    $(".eta", c).textContent = eta;
    const unknown = tempsLine(p, c);
    drawChart($("canvas", c), p.state === "offline" ? [] : st.hist.get(p.name) || []);
    const need = needs(p);
    st.needs.set(p.name, need);
    $(".msg", c).textContent = [need, p.message, unknown].filter((x) => x).map(sentence).join(" ");
    if (!st.readOnly) {
      const blocked = shown === "blocked";
      const show = {
        cleared: p.state === "awaiting-clear" && !blocked,
        "clear-error": p.state === "error",
        pause: p.state === "printing" && !!p.job_id,
        resume: p.state === "paused",
        cancel: (p.state === "printing" || p.state === "paused") && !!p.job_id,
        "job-resume": blocked && p.state === "idle",
        "job-restart": blocked,
        "job-cancel": blocked,
        estop: p.state !== "offline" && p.state !== "error" && p.enabled,
        ...pmCardShow(p), // printers.js: Manage, Enable
      };
      for (const b of c.querySelectorAll("button[data-act]")) b.hidden = !show[b.dataset.act];
    }
  }
  notifyNeeds();
}

// "link lost" -> "Link lost."
function sentence(t) {
  t = t.trim();
  return t[0].toUpperCase() + t.slice(1) + (/[.!?]$/.test(t) ? "" : ".");
}

// Clock time of ms ("14:05").
function clock(ms) {
  return new Date(ms).toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" });
}

// ---- what needs the operator: the tab's title, browser notifications ----

const told = new Map(); // printer name -> the need last notified

function notifyNeeds() {
  let n = 0;
  for (const [name, need] of st.needs) {
    if (need) n++;
    if (need && told.get(name) !== need && st.notify && told.has(name))
      new Notification(`slimfarm: ${name}`, { body: need, tag: "slimfarm-" + name });
    told.set(name, need);
  }
  document.title = n ? `(${n}) slimfarm: ${n} need${n === 1 ? "s" : ""} you` : "slimfarm";
  const b = $("#notify");
  if (b) b.hidden = st.notify || !("Notification" in window) || Notification.permission === "denied";
}

async function askNotify() {
  if (!("Notification" in window)) return;
  const r = await Notification.requestPermission();
  st.notify = r === "granted";
  notifyNeeds();
}

// "9 printing · 2 need bed clear · 1 error · queue 4 h" over the grid.
function renderCounters() {
  const ps = [...st.printers.values()];
  const count = (f) => ps.filter(f).length;
  const printing = count((p) => p.state === "printing" || p.state === "paused");
  const clear = count((p) => p.state === "awaiting-clear");
  const err = count((p) => p.state === "error");
  const blocked = count((p) => shownState(p) === "blocked");
  const off = count((p) => p.state === "offline" && p.enabled);
  const idle = count((p) => p.state === "idle" && shownState(p) === "idle");
  let queue_s = 0, unknown = 0;
  for (const j of st.jobs.values()) {
    if (!["queued", "preparing", "ready"].includes(j.state)) continue;
    if (j.est_s != null) queue_s += j.est_s * copiesLeft(j);
    else unknown++;
  }
  const parts = [`${printing} printing`, `${idle} idle`];
  if (clear) parts.push(`${clear} need bed clear`);
  if (err) parts.push(`${err} error${err === 1 ? "" : "s"}`);
  if (blocked) parts.push(`${blocked} blocked`);
  if (off) parts.push(`${off} offline`);
  parts.push(`queue ${queue_s ? fmtTime(queue_s) : "empty"}${unknown ? ` + ${unknown} not sliced yet` : ""}`);
  $("#counters").textContent = parts.join(" · ");
}

// ---- queue ----

const ACTIVE = ["queued", "preparing", "ready", "printing", "paused", "interrupted"];
const WAITING = ["queued", "preparing", "ready"];

// The scheduler's rule: higher priority first, then the queue's order (first
// come, first served unless moved with ▲/▼).
function queueOrder(a, b) {
  return b.priority - a.priority || a.queue_pos - b.queue_pos || a.id - b.id;
}

function fits(j, p) {
  return (!j.target_printer || j.target_printer === p.name) && (!j.target_group || j.target_group === p.group) &&
    (!j.material || j.material === p.material);
}

// Expected start and finish (ms, NaN unknown) of each waiting job: the queue
// in its order given, copy by copy, to the printer of the job's kind that
// frees first (now for an idle one, its time left for a printing one),
// each copy taking the G-code's estimate.  A guide, not a promise: the
// scheduler decides when a printer is free.
function expectations(waiting) {
  const now = Date.now(), free = new Map(), out = new Map();
  for (const p of st.printers.values()) {
    if (!p.enabled || shownState(p) === "blocked" || p.state === "offline" || p.state === "error") continue;
    if (p.state === "idle" || p.state === "awaiting-clear") free.set(p.name, now);
    else free.set(p.name, p.job_id && p.time_left_s != null ? now + p.time_left_s * 1000 : NaN);
  }
  for (const j of waiting) {
    let start = NaN, end = NaN;
    for (let k = 0; k < copiesLeft(j); k++) {
      let best = null;
      for (const [name, t] of free)
        if (fits(j, st.printers.get(name)) && !isNaN(t) && (best === null || t < free.get(best))) best = name;
      if (best === null) break;
      if (k === 0) start = free.get(best);
      end = j.est_s != null ? free.get(best) + j.est_s * 1000 : NaN;
      free.set(best, end);
    }
    out.set(j.id, [start, end]);
  }
  return out;
}

function expectText(e) {
  if (!e || isNaN(e[0])) return "no printer free for it yet";
  const now = Date.now();
  return (e[0] <= now + 60000 ? "start now" : `start ${clock(e[0])}`) + (isNaN(e[1]) ? " · finish once sliced" : ` · done ${clock(e[1])}`);
}

function renderQueue() {
  const jobs = [...st.jobs.values()];
  const active = jobs.filter((j) => ACTIVE.includes(j.state));
  const waiting = active.filter((j) => WAITING.includes(j.state)).sort(queueOrder);
  const onPrinters = active.filter((j) => !WAITING.includes(j.state)).sort((a, b) => a.id - b.id);
  const done = jobs.filter((j) => !ACTIVE.includes(j.state)).sort((a, b) => b.id - a.id);
  const pb = $("#printing tbody");
  pb.textContent = "";
  if (!onPrinters.length) pb.append(el("tr", {}, el("td", { colspan: "7", class: "muted", text: "Nothing is printing." })));
  for (const j of onPrinters) {
    const p = [...st.printers.values()].find((x) => x.job_id === j.id || x.interrupted_job === j.id);
    const left = p && p.job_id === j.id && p.time_left_s != null ? `done about ${clock(Date.now() + p.time_left_s * 1000)}` : "";
    const tr = el("tr", { "data-job": String(j.id), "data-state": j.state },
      el("td", { "data-label": "Job" }, el("a", { href: `#job/${j.id}` }, `#${j.id}`)),
      el("td", { "data-label": "Part", class: "name", text: j.name }),
      el("td", { "data-label": "State", text: j.state }),
      el("td", { "data-label": "Copy", text: `${Math.min(j.copies_done + 1, j.copies)} of ${j.copies}` }),
      el("td", { "data-label": "Printer", text: j.printer || (p ? p.name : "") }),
      el("td", { "data-label": "Expected", text: j.state === "interrupted" ? `stopped at line ${j.lines_acked} of ${j.gcode_lines}` : left }));
    if (!st.readOnly) tr.append(el("td", { "data-label": "Actions" }, jobActions(j, null, null)));
    pb.append(tr);
  }
  const tb = $("#queue tbody");
  tb.textContent = "";
  if (!waiting.length) tb.append(el("tr", {}, el("td", { colspan: "9", class: "muted", text: "No job waits." })));
  const exp = expectations(waiting);
  waiting.forEach((j, i) => {
    const link = el("a", { href: `#job/${j.id}` }, `#${j.id}`);
    // data-label: the column's name, shown beside each cell on a phone
    const tr = el("tr", { "data-job": String(j.id), "data-state": j.state },
      el("td", { "data-label": "Job" }, link), el("td", { "data-label": "Part", class: "name", text: j.name }),
      el("td", { "data-label": "State", text: j.state }),
      el("td", { "data-label": "Copies left", text: String(copiesLeft(j)) }),
      el("td", { "data-label": "Priority", text: String(j.priority) }),
      el("td", { "data-label": "Printer", text: j.printer || j.target_printer || j.target_group || "any" }),
      el("td", { "data-label": "Expected", class: "expect", text: expectText(exp.get(j.id)) }),
      el("td", { "data-label": "Why it waits", class: "muted why", text: j.reason || "" }));
    if (!st.readOnly) tr.append(el("td", { "data-label": "Actions" }, jobActions(j, waiting[i - 1], waiting[i + 1])));
    tb.append(tr);
  });
  const fb = $("#finished tbody");
  fb.textContent = "";
  for (const j of done.slice(0, 50)) {
    fb.append(el("tr", { "data-job": String(j.id), "data-state": j.state },
      el("td", {}, el("a", { href: `#job/${j.id}` }, `#${j.id}`)), el("td", { class: "name", text: j.name }),
      el("td", { text: j.state }), el("td", { text: `${j.copies_done} / ${j.copies}` }),
      el("td", { text: j.printer || j.last_printer || "" }), el("td", { text: fmtMs(j.updated_ms) }),
      el("td", { class: "muted why", text: j.reason || "" })));
  }
}

// One place up (-1) or down (1) among the waiting jobs.
function moveJob(j, by) {
  return api(`/api/jobs/${j.id}/move`, { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ by }) });
}

function jobActions(j, above, below) {
  const d = el("div", { class: "actions" });
  const id = j.id;
  if (WAITING.includes(j.state)) {
    d.append(el("button", { type: "button", "aria-label": `Move job ${id} up`, disabled: !above, "data-keep": above ? null : "disabled",
      onclick: act(() => moveJob(j, -1)) }, "▲"));
    d.append(el("button", { type: "button", "aria-label": `Move job ${id} down`, disabled: !below, "data-keep": below ? null : "disabled",
      onclick: act(() => moveJob(j, 1)) }, "▼"));
  }
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
      onclick: guarded(() => restartText(id, j), () => api(`/api/jobs/${id}/restart`, { method: "POST" })) }, "Restart"));
  }
  d.append(el("button", { type: "button", class: "danger", "aria-label": `Cancel job ${id}`,
    onclick: guarded(() => jobCancelText(st.jobs.get(id) || j, id), () => api(`/api/jobs/${id}/cancel`, { method: "POST" })) }, "Cancel"));
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

const NAME_MAX = 127; // bytes of a part's file name (the daemon's JOB_NAME_MAX less its NUL)

// Send one part with the form's options; onprogress(fraction) while it goes
// up.  XMLHttpRequest, as fetch reports no upload progress.
function upload(file, opts, onprogress) {
  return new Promise((done, fail) => {
    const fd = new FormData();
    fd.append("file", file, file.name);
    fd.append("options", JSON.stringify(opts));
    const x = new XMLHttpRequest();
    x.open("POST", "/api/jobs");
    x.setRequestHeader("X-Csrf-Token", st.csrf);
    x.upload.onprogress = (e) => e.lengthComputable && onprogress(e.loaded / e.total);
    x.onload = () => {
      let body = null;
      try { body = JSON.parse(x.responseText); } catch (e) { body = null; }
      if (x.status === 401) loggedOut("Your session ended: log in again.");
      if (x.status >= 200 && x.status < 300) done(body);
      else fail(new HttpError(x.status, (body && body.error) || `${x.status} ${x.statusText}`));
    };
    x.onerror = () => fail(new Error("The farm did not answer: the part was not sent."));
    x.send(fd);
  });
}

function submitOptions() {
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
  return o;
}

// What is wrong with a file's name before it is sent ("" nothing).
function nameProblem(f) {
  const n = new TextEncoder().encode(f.name).length;
  if (n > NAME_MAX) return `${f.name.slice(0, 40)}…: the name is ${n} bytes; names are at most ${NAME_MAX} bytes: rename the file`;
  if (!/\.(stl|obj|3mf|gcode)$/i.test(f.name)) return `${f.name}: not an STL, OBJ, 3MF or G-code file (by its name)`;
  return "";
}

function setupSubmit() {
  const drop = $("#drop"), file = $("#file");
  let chosen = [];
  const shown = () => {
    $("#file-name").textContent = chosen.map((f) => f.name).join(", ");
    const list = $("#uploads");
    list.textContent = "";
    for (const f of chosen)
      list.append(el("li", { "data-file": f.name }, el("span", { class: "name", text: f.name }),
        el("progress", { max: "1", value: "0", "aria-label": "upload of " + f.name }),
        el("span", { class: "up-msg", text: nameProblem(f) })));
  };
  const choose = (files) => { chosen = [...files]; shown(); };
  file.addEventListener("change", () => choose(file.files));
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    if (e.dataTransfer.files.length) choose(e.dataTransfer.files);
  });
  drop.addEventListener("keydown", (e) => {
    if (e.key === "Enter" || e.key === " ") { e.preventDefault(); file.click(); }
  });
  $("#submit-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    const msg = $("#submit-msg");
    if (!chosen.length) { msg.textContent = "Choose a part first."; return; }
    const btn = $("#submit-btn");
    btn.disabled = true;
    const ids = [], bad = [];
    const o = submitOptions();
    for (const f of chosen) {
      const li = [...$("#uploads").children].find((x) => x.dataset.file === f.name);
      const say = (t) => li && ($(".up-msg", li).textContent = t);
      if (nameProblem(f)) { bad.push(nameProblem(f)); continue; }
      msg.textContent = `Uploading ${f.name}…`;
      try {
        const r = await upload(f, o, (x) => li && ($("progress", li).value = x));
        ids.push(r.job.id);
        say(`job #${r.job.id} queued`);
      } catch (err) {
        bad.push(`${f.name}: ${err.message}`);
        say(err.message);
      }
    }
    btn.disabled = false;
    msg.textContent = (ids.length ? `Queued: ${ids.map((i) => "#" + i).join(", ")}.` : "") +
      (bad.length ? ` Refused: ${bad.join("; ")}` : "");
    if (!bad.length) {
      chosen = [];
      file.value = "";
      shown();
      location.hash = ids.length === 1 ? `#job/${ids[0]}` : "#";
    }
  });
}

// ---- job page ----

let jobShown = 0; // layerData: layers.js

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

// Whether the part was changed, in words that agree with the job's fate and
// with the deviation line ("shape kept").
function partChanged(j, r) {
  if (r.optimized) {
    if (j.method === "orient" || ((j.method === "slim" || j.method === "surface") && !j.shape_changed))
      return "yes: oriented (shape kept), the oriented part saved";
    return "yes: oriented and shaped, the new part saved";
  }
  if (!j.gcode_sha) return j.state === "failed" ? "no: the job failed before it was prepared" : "not prepared yet";
  return j.method === "none" ? "no: printed as uploaded" : "no: the part as uploaded was already best";
}

function afterCaption(j, r) {
  if (!r.optimized) {
    if (!j.gcode_sha) return j.state === "failed" ? "after: none (the job failed before it was prepared)" : "after: not prepared yet";
    return "after: unchanged (the part prints as uploaded)";
  }
  return j.method === "orient" || !j.shape_changed ? "after: as it prints (oriented, shape kept)"
    : "after: as it prints (oriented and shaped)";
}

// Filament of one print: the store's figure when it has one, else the
// G-code's own for a done copy, or its share by lines for an unfinished one.
function filament(p, lines, j, g) {
  if (p.filament_mm > 0) return (p.filament_mm / 1000).toFixed(2) + " m";
  if (!g || !(g.filament_mm > 0)) return "";
  if (p.outcome === "done" && p.start_line === 0) return (g.filament_mm / 1000).toFixed(2) + " m";
  const share = j.gcode_lines > 0 ? Math.max(0, lines - p.start_line) / j.gcode_lines : 0;
  return `≈ ${((g.filament_mm * Math.min(1, share)) / 1000).toFixed(2)} m`;
}

function fmtMs(ms) {
  return ms ? new Date(ms).toLocaleString() : "";
}

async function renderJob(id, fresh) {
  let d, r;
  try {
    [d, r] = await Promise.all([api(`/api/jobs/${id}`), api(`/api/jobs/${id}/report`)]);
  } catch (e) {
    if (e.status && e.status !== 401) showError(e.message);
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
    ["Part changed", partChanged(j, r)],
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
  for (const p of prints) {
    // a running print's lines are the job's (the store closes the print with its own)
    const lines = p.outcome ? p.lines_acked : Math.max(p.lines_acked, j.lines_acked);
    pb.append(el("tr", { "data-copy": String(p.copy), "data-outcome": p.outcome || "printing" },
      el("td", { text: String(p.copy) }), el("td", { text: p.printer }),
      el("td", { text: String(p.start_line) }), el("td", { text: String(lines) }),
      el("td", { text: filament(p, lines, j, g) }), el("td", { text: fmtMs(p.started_ms) }),
      el("td", { text: fmtMs(p.ended_ms) }), el("td", { text: p.outcome || "printing" })));
  }
  if (!prints.length) pb.append(el("tr", {}, el("td", { colspan: "8", class: "muted", text: "Not printed yet." })));
  // pictures: the cookie authorizes these GETs; "after" changes once prepared
  const before = `/api/jobs/${j.id}/preview.png?stage=before`;
  const after = `/api/jobs/${j.id}/preview.png?stage=after&v=${r.optimized ? "opt" : "in"}`;
  if ($("#pic-before").getAttribute("src") !== before) $("#pic-before").src = before;
  if ($("#pic-after").getAttribute("src") !== after) $("#pic-after").src = after;
  $("#after-cap").textContent = afterCaption(j, r);
  j.last_printer = went; // the layer preview draws its bed
  if (fresh || (j.gcode_sha && (!layerData || layerData.sha !== j.gcode_sha))) loadLayers(j);
  else followLayer(j);
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
  $("#layer").addEventListener("input", () => {
    if (!$("#layer-follow-box").hidden) $("#layer-follow").checked = false; // the operator chose a layer
    drawLayer();
  });
  $("#layer-follow").addEventListener("change", () => layerJob && followLayer(layerJob));
  $("#confirm-no").addEventListener("click", () => $("#confirm").close("no"));
  $("#confirm-ok").addEventListener("click", () => $("#confirm").close("ok"));
  $("#notify").addEventListener("click", askNotify);
  $("#compact").addEventListener("click", (e) => {
    const on = document.body.classList.toggle("compact");
    e.currentTarget.setAttribute("aria-pressed", String(on));
    e.currentTarget.textContent = on ? "Card view" : "List view";
  });
  // the support model's numbers come with the pictures
  for (const img of ["#pic-before", "#pic-after"])
    $(img).addEventListener("load", () => jobShown && renderJob(jobShown, false));
  window.addEventListener("hashchange", route);
  setupSubmit();
  sessionStorage.removeItem(KEY);
  login("").catch(() => loggedOut(""));
});
