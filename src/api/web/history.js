// history.js - the farm's history page (history.html): finished jobs with
// filters, name search, paging and CSV export, "print again", and each
// printer's success, hours and use per day.  It reads the same CSV the
// export gives (GET /api/jobs?format=csv, which carries each job's
// printer, print time and filament) and GET /api/stats; it logs in with
// the dashboard's session cookie (GET /api/whoami gives the CSRF token a
// POST needs).
"use strict";

const PAGE = 50;
// seq: the number of the latest loadJobs; an answer to an earlier one is dropped
const st = { csrf: "", readOnly: true, cursor: "", query: "", seq: 0 };
const $ = (id) => document.getElementById(id);

function showError(msg) {
  $("error").textContent = msg;
  $("error").hidden = !msg;
}

async function get(path) {
  const r = await fetch(path, { credentials: "same-origin" });
  if (r.status === 401) {
    $("login").hidden = false;
    throw new Error("not logged in");
  }
  if (!r.ok) throw new Error((await r.text()) || r.statusText);
  return r;
}

// RFC 4180: quoted fields, "" inside quotes, CRLF rows.
function parseCsv(text) {
  const rows = [];
  let row = [], field = "", quoted = false;
  for (let i = 0; i < text.length; i++) {
    const c = text[i];
    if (quoted) {
      if (c === '"' && text[i + 1] === '"') { field += '"'; i++; }
      else if (c === '"') quoted = false;
      else field += c;
    } else if (c === '"') quoted = true;
    else if (c === ",") { row.push(field); field = ""; }
    else if (c === "\n") { row.push(field); rows.push(row); row = []; field = ""; }
    else if (c !== "\r") field += c;
  }
  const head = rows.shift() || [];
  return rows.map((r) => Object.fromEntries(head.map((h, k) => [h, r[k] || ""])));
}

function query() {
  const q = new URLSearchParams({ state: $("f-state").value, order: "desc" });
  const name = $("f-name").value.trim(), printer = $("f-printer").value.trim();
  if (name) q.set("name", name);
  if (printer) q.set("printer", printer);
  if ($("f-since").value) q.set("since", String(Date.parse($("f-since").value)));
  if ($("f-until").value) q.set("until", String(Date.parse($("f-until").value) + 86400000));
  return q;
}

function cell(tr, text) {
  const td = document.createElement("td");
  td.textContent = text;
  tr.appendChild(td);
  return td;
}

function duration(s) {
  s = Number(s) || 0;
  const h = Math.floor(s / 3600), m = Math.round((s % 3600) / 60);
  return h ? `${h} h ${m} min` : `${m} min`;
}

async function again(id, button) {
  button.disabled = true;
  try {
    const r = await fetch(`/api/jobs/${id}/again`, {
      method: "POST", credentials: "same-origin", headers: { "X-Csrf-Token": st.csrf } });
    const body = await r.json().catch(() => null);
    if (!r.ok) throw new Error((body && body.error) || r.statusText);
    $("jobs-note").textContent = `Job #${id} queued again as job #${body.job.id}.`;
  } catch (e) {
    showError(`Print again: ${e.message}`);
  } finally {
    button.disabled = false;
  }
}

function addRow(j) {
  const tr = document.createElement("tr");
  cell(tr, j.id);
  // the export defuses a name a spreadsheet would run as a formula; show it as given
  cell(tr, /^'[=+\-@]/.test(j.name) ? j.name.slice(1) : j.name);
  cell(tr, j.state);
  cell(tr, j.finished ? new Date(j.finished).toLocaleString() : "");
  cell(tr, duration(j.print_s));
  cell(tr, j.printer);
  cell(tr, j.filament_g);
  cell(tr, j.support_saved_g);
  cell(tr, j.reason);
  const td = cell(tr, "");
  if (!st.readOnly) {
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = "Print again";
    // the name holds the words shown (WCAG 2.5.3, label in name)
    b.setAttribute("aria-label", `Print again: job #${j.id} ${j.name}`);
    b.addEventListener("click", () => again(j.id, b));
    td.appendChild(b);
  }
  $("jobs").tBodies[0].appendChild(tr);
}

// Show the finished jobs the filters select (more: the next page of them).
// Each answer is for the latest request only: a Show pressed while an
// earlier one (or Older jobs) is on its way drops that earlier answer, which
// would otherwise land in the new list, whichever of the two came last.
// While a list is on its way the table is aria-busy and the note says so,
// not what the last list held.
async function loadJobs(more) {
  const seq = ++st.seq;
  showError("");
  if (!more) {
    st.query = query().toString();
    st.cursor = "";
    $("jobs").tBodies[0].textContent = "";
    $("csv").href = `/api/jobs?${st.query}&format=csv`;
    $("more").hidden = true;
    $("jobs-note").textContent = "Loading…";
  }
  $("jobs").setAttribute("aria-busy", "true");
  const cursor = st.cursor ? `&cursor=${encodeURIComponent(st.cursor)}` : "";
  try {
    const r = await get(`/api/jobs?${st.query}&format=csv&limit=${PAGE}${cursor}`);
    const jobs = parseCsv(await r.text());
    if (seq !== st.seq) return;
    jobs.forEach(addRow);
    st.cursor = r.headers.get("X-Next-Cursor") || "";
    $("more").hidden = !st.cursor;
    const n = $("jobs").tBodies[0].rows.length;
    $("jobs-note").textContent = n ? `${n} jobs shown.` : "No finished job matches.";
  } catch (e) {
    if (seq !== st.seq) return;
    $("jobs-note").textContent = "";
    showError(`Jobs: ${e.message}`);
  }
  $("jobs").setAttribute("aria-busy", "false");
}

function useBars(values) {
  const ns = "http://www.w3.org/2000/svg", w = 6, h = 24;
  const svg = document.createElementNS(ns, "svg");
  svg.setAttribute("width", String(values.length * w));
  svg.setAttribute("height", String(h));
  svg.setAttribute("role", "img");
  svg.setAttribute("aria-label", "use per day: " + values.map((u) => `${Math.round(u * 100)} %`).join(", "));
  values.forEach((u, i) => {
    const bar = document.createElementNS(ns, "rect");
    const bh = Math.max(1, Math.round(Math.min(1, u) * h));
    bar.setAttribute("x", String(i * w));
    bar.setAttribute("y", String(h - bh));
    bar.setAttribute("width", String(w - 1));
    bar.setAttribute("height", String(bh));
    bar.setAttribute("fill", u > 0 ? "#1f6feb" : "#d9dde3");
    svg.appendChild(bar);
  });
  return svg;
}

async function loadStats() {
  try {
    const d = await (await get(`/api/stats?days=${$("days").value}`)).json();
    const body = $("stats").tBodies[0];
    body.textContent = "";
    for (const p of d.printers) {
      const tr = document.createElement("tr");
      cell(tr, p.printer);
      cell(tr, p.prints.done);
      cell(tr, p.prints.failed);
      cell(tr, p.prints.cancelled);
      cell(tr, p.success_rate === null ? "–" : `${Math.round(p.success_rate * 100)} %`);
      cell(tr, p.hours_printing);
      cell(tr, "").appendChild(useBars(p.utilisation));
      body.appendChild(tr);
    }
    if (!d.printers.length) cell(body.insertRow(), "No print in these days.");
  } catch (e) {
    showError(`Statistics: ${e.message}`);
  }
}

async function start() {
  try {
    const who = await (await get("/api/whoami")).json();
    st.csrf = who.csrf || "";
    st.readOnly = !!who.read_only;
  } catch (e) {
    return;
  }
  $("filters").addEventListener("submit", (ev) => { ev.preventDefault(); loadJobs(false); });
  $("more").addEventListener("click", () => loadJobs(true));
  $("days").addEventListener("change", loadStats);
  loadJobs(false);
  loadStats();
}

start();
