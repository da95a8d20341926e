// slimfarm dashboard: the job page's layer preview (loaded after app.js,
// whose helpers it uses; app.js calls loadLayers and drawLayer).
//
// The G-code comes from GET /api/jobs/ID/gcode and is read here: G0/G1
// lines and G2/G3 arcs (the slicer's arc fitting writes perimeters as
// arcs: X Y the end, I J the centre's offset from the start, clockwise
// for G2), absolute or relative E, ;LAYER_CHANGE and ;TYPE: comments.
// Arcs are kept as arcs and drawn with the canvas's own arc().  Each move
// remembers its command line's number (the lines the printer acknowledges
// are counted the same way: lines with a command once the comment is
// gone), so the layer being printed is found from the job's lines_acked,
// marked, and followed while "Follow the print" is on.
"use strict";

let layerData = null;

async function loadLayers(j) {
  const msg = $("#layer-msg"), slider = $("#layer");
  if (!j.gcode_sha) {
    layerData = null;
    slider.disabled = true;
    msg.textContent = "No G-code yet: the job is not sliced.";
    $("#layer-canvas").getContext("2d").clearRect(0, 0, 600, 600);
    $("#layer-legend").textContent = "";
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
  msg.textContent = n ? `${n} layers; extrusions coloured by role (the legend below), travel grey; arcs as arcs.`
    : "No layers in the G-code.";
  followLayer(j);
  drawLayer();
}

// The words of a G-code line, comment stripped: {G: 1, X: 10, ...}.
function words(line) {
  const w = {};
  for (const t of line.split(/\s+/)) if (t) w[t[0].toUpperCase()] = parseFloat(t.slice(1));
  return w;
}

// Moves of each ;LAYER_CHANGE section, each {x0, y0, x1, y1, role, line}
// (role -1: travel) plus, for an arc, its centre and direction {cx, cy, cw}.
function parseGcode(text, sha) {
  const roles = [], layers = [];
  let cur = null, x = 0, y = 0, e = 0, relE = false, role = 0, z = 0, line = 0;
  const box = [Infinity, Infinity, -Infinity, -Infinity];
  const grow = (a, b) => {
    box[0] = Math.min(box[0], a); box[1] = Math.min(box[1], b);
    box[2] = Math.max(box[2], a); box[3] = Math.max(box[3], b);
  };
  for (const raw of text.split("\n")) {
    if (raw.startsWith(";LAYER_CHANGE")) { cur = { segs: [], z, first: line + 1 }; layers.push(cur); continue; }
    if (raw.startsWith(";Z:") && cur) { cur.z = parseFloat(raw.slice(3)); continue; }
    if (raw.startsWith(";TYPE:")) {
      const name = raw.slice(6).trim();
      role = roles.indexOf(name);
      if (role < 0) { roles.push(name); role = roles.length - 1; }
      continue;
    }
    const cmdline = raw.split(";")[0].trim();
    if (!cmdline) continue;
    line++;
    const cmd = cmdline.split(/\s+/)[0].toUpperCase();
    if (cmd === "M83") relE = true;
    else if (cmd === "M82") relE = false;
    else if (cmd === "G92") { const w = words(cmdline); if (w.E !== undefined) e = w.E; }
    else if (cmd === "G0" || cmd === "G1" || cmd === "G2" || cmd === "G3") {
      const w = words(cmdline);
      const nx = w.X !== undefined ? w.X : x, ny = w.Y !== undefined ? w.Y : y;
      if (w.Z !== undefined) z = w.Z;
      let ext = false;
      if (w.E !== undefined) { ext = relE ? w.E > 0 : w.E > e; e = relE ? e : w.E; }
      const arc = cmd === "G2" || cmd === "G3";
      if (cur && (nx !== x || ny !== y || arc)) {
        const s = { x0: x, y0: y, x1: nx, y1: ny, role: ext ? role : -1, line };
        if (arc) {
          s.cx = x + (w.I || 0);
          s.cy = y + (w.J || 0);
          s.cw = cmd === "G2";
        }
        cur.segs.push(s);
        if (ext) {
          grow(x, y); grow(nx, ny);
          if (arc) for (const [px, py] of arcPoints(s, 8)) grow(px, py);
        }
      }
      x = nx; y = ny;
    }
  }
  return { sha, layers, roles, box };
}

// n points along arc g (its sweep, in its direction), for the drawing's extent.
function arcPoints(g, n) {
  const r = Math.hypot(g.x0 - g.cx, g.y0 - g.cy);
  const a0 = Math.atan2(g.y0 - g.cy, g.x0 - g.cx);
  let a1 = Math.atan2(g.y1 - g.cy, g.x1 - g.cx);
  if (g.cw && a1 >= a0) a1 -= 2 * Math.PI;
  if (!g.cw && a1 <= a0) a1 += 2 * Math.PI;
  const out = [];
  for (let k = 1; k < n; k++) {
    const a = a0 + ((a1 - a0) * k) / n;
    out.push([g.cx + r * Math.cos(a), g.cy + r * Math.sin(a)]);
  }
  return out;
}

const ROLE_COLORS = { "Perimeter": "#ffa500", "External perimeter": "#e8590c", "Internal infill": "#b03a2e",
  "Solid infill": "#9b59b6", "Top solid infill": "#e74c3c", "Bottom solid infill": "#8e44ad",
  "Support material": "#2e8b57", "Support material interface": "#2ecc71", "Skirt/Brim": "#16a085",
  "Bridge infill": "#3498db", "Gap fill": "#7f8c8d" };
const FALLBACK = ["#ff8c00", "#c0392b", "#2980b9", "#27ae60", "#8e44ad", "#d35400"];

function roleColor(r) {
  return ROLE_COLORS[layerData.roles[r]] || FALLBACK[r % FALLBACK.length];
}

// The job page's job (app.js keeps it in st.jobs only while live).
let layerJob = null;

// Printing: the layer holding the job's last acknowledged line, or -1.
function printingLayer() {
  const j = layerJob;
  if (!layerData || !j || !["printing", "paused"].includes(j.state) || !(j.lines_acked > 0)) return -1;
  let k = -1;
  layerData.layers.forEach((L, i) => { if (L.first <= j.lines_acked) k = i; });
  return k;
}

// Called on every refresh of the job page: while the job prints and
// "Follow the print" is on, the slider goes to the layer being printed.
function followLayer(j) {
  layerJob = j;
  const live = ["printing", "paused"].includes(j.state);
  $("#layer-follow-box").hidden = !live;
  const k = printingLayer();
  if (k >= 0 && $("#layer-follow").checked && Number($("#layer").value) !== k) $("#layer").value = String(k);
  if (layerData) drawLayer();
}

// The drawing's frame: the part's extent, and the printer's bed when known.
function layerFrame(cv) {
  const [x0, y0, x1, y1] = layerData.box;
  const pad = 20, s = Math.min((cv.width - 2 * pad) / Math.max(x1 - x0, 1), (cv.height - 2 * pad) / Math.max(y1 - y0, 1));
  return { x0, y0, s, pad, h: cv.height, X: (v) => pad + (v - x0) * s, Y: (v) => cv.height - pad - (v - y0) * s };
}

function strokeSeg(ctx, f, g) {
  ctx.beginPath();
  ctx.moveTo(f.X(g.x0), f.Y(g.y0));
  if (g.cx === undefined) {
    ctx.lineTo(f.X(g.x1), f.Y(g.y1));
  } else {
    // canvas y points down: a clockwise arc in the G-code is anticlockwise on screen
    const r = Math.hypot(g.x0 - g.cx, g.y0 - g.cy) * f.s;
    const a0 = Math.atan2(f.Y(g.y0) - f.Y(g.cy), f.X(g.x0) - f.X(g.cx));
    let a1 = Math.atan2(f.Y(g.y1) - f.Y(g.cy), f.X(g.x1) - f.X(g.cx));
    if (g.x0 === g.x1 && g.y0 === g.y1) a1 = a0 + (g.cw ? -2 * Math.PI : 2 * Math.PI); // a full circle
    ctx.arc(f.X(g.cx), f.Y(g.cy), r, a0, a1, !g.cw);
  }
  ctx.stroke();
}

// The bed's outline and a small map of where the part sits on it.
function drawBed(ctx, cv, f) {
  const p = layerJob && st.printers.get(layerJob.printer || layerJob.last_printer || layerJob.target_printer || "");
  const bed = p ? p.bed_mm : null;
  if (!bed || !(bed[0] > 0)) return "";
  ctx.save();
  ctx.setLineDash([6, 4]);
  ctx.strokeStyle = "#8c959f";
  ctx.lineWidth = 1;
  ctx.strokeRect(f.X(0), f.Y(bed[1]), bed[0] * f.s, bed[1] * f.s);
  ctx.setLineDash([]);
  const m = 90 / Math.max(bed[0], bed[1]), mx = cv.width - 10 - bed[0] * m, my = 10;
  ctx.fillStyle = "rgba(255,255,255,.9)";
  ctx.fillRect(mx, my, bed[0] * m, bed[1] * m);
  ctx.strokeRect(mx, my, bed[0] * m, bed[1] * m);
  const [x0, y0, x1, y1] = layerData.box;
  ctx.beginPath();
  ctx.rect(mx, my, bed[0] * m, bed[1] * m);
  ctx.clip(); // a part off the bed shows at the map's edge, not over the drawing
  ctx.fillStyle = "#1f6feb";
  ctx.fillRect(mx + x0 * m, my + (bed[1] - y1) * m, Math.max(2, (x1 - x0) * m), Math.max(2, (y1 - y0) * m));
  ctx.restore();
  return `bed of ${p.name}: ${bed[0]} × ${bed[1]} mm (dashed; the map at the top right shows where the part sits)`;
}

function drawLayer() {
  const cv = $("#layer-canvas"), ctx = cv.getContext("2d");
  ctx.clearRect(0, 0, cv.width, cv.height);
  if (!layerData || !layerData.layers.length) return;
  const i = Number($("#layer").value), n = layerData.layers.length;
  const L = layerData.layers[i];
  const now = printingLayer();
  const at = layerJob ? layerJob.lines_acked : 0;
  $("#layer-out").textContent = `${i + 1} of ${n} (z ${L.z} mm)` + (now === i ? ", printing now" : now > i ? ", printed" : "");
  $("#layer").setAttribute("aria-valuetext", `layer ${i + 1} of ${n}` + (now === i ? ", printing now" : ""));
  const f = layerFrame(cv);
  cv.dataset.frame = JSON.stringify({ x0: f.x0, y0: f.y0, s: f.s, pad: f.pad, h: f.h });
  const bedText = drawBed(ctx, cv, f);
  ctx.lineCap = "round";
  const used = new Set();
  for (const travel of [true, false]) {
    for (const g of L.segs) {
      if ((g.role < 0) !== travel) continue;
      if (!travel) used.add(g.role);
      ctx.strokeStyle = travel ? "rgba(140,149,159,.35)" : roleColor(g.role);
      // the layer being printed: what is not printed yet is faded
      ctx.globalAlpha = now === i && g.line > at ? 0.25 : 1;
      ctx.lineWidth = travel ? 0.5 : Math.max(1, 0.45 * f.s);
      strokeSeg(ctx, f, g);
    }
  }
  ctx.globalAlpha = 1;
  const leg = $("#layer-legend");
  leg.textContent = "";
  for (const r of [...used].sort((a, b) => a - b)) {
    const sw = el("span", { class: "swatch" });
    sw.style.background = roleColor(r);
    leg.append(el("li", {}, sw, layerData.roles[r]));
  }
  leg.append(el("li", {}, el("span", { class: "swatch travel" }), "travel"));
  if (now === i) leg.append(el("li", {}, el("span", { class: "swatch faded" }), "not printed yet"));
  $("#layer-bed").textContent = bedText;
}
