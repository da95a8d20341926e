// tests/browser/cards.mjs - printer cards that tell the truth, guarded
// actions on the copy and the job, the layer preview's arcs, figures,
// notifications and accessibility, in Debian's chromium driven by
// playwright-core; started by cards.sh (24 simulated printers: see there).
import fs from "node:fs";
import path from "node:path";
import { LONG, accessible, apiGet, call, check, confirmed, env, log, runChromium, submit, until } from "./lib.mjs";

const URL = env("SF_URL"), RW = env("SF_RW"), PARTS = env("SF_PARTS"), SHOTS = env("SF_SHOTS");
const part = (n) => fs.readFileSync(path.join(PARTS, n));
const problems = [];
const sel = (name) => `article.printer[data-printer="${name}"]`;

await runChromium("cards-failure.png", async (ctx) => run(await ctx.newPage()));

// Wait until printer name's card shows (data-shown: what the page makes of it).
async function shown(page, name, what) {
  await page.waitForSelector(`${sel(name)}[data-shown="${what}"]`, { timeout: LONG });
}

async function cardText(page, name, part) {
  return page.locator(`${sel(name)} ${part}`).innerText();
}

async function waitText(page, css, re) {
  await page.waitForFunction(([c, src]) => {
    const e = document.querySelector(c);
    return e && new RegExp(src).test(e.textContent);
  }, [css, re.source], { timeout: LONG });
}

async function run(page) {
  page.on("pageerror", (e) => problems.push("page error: " + e.message));
  // browser notifications: the page asks on a click; what it shows is kept here
  await page.addInitScript(() => {
    window.__notes = [];
    window.Notification = class {
      constructor(title, o) { window.__notes.push(title + ": " + (o && o.body)); }
      static requestPermission() { return Promise.resolve("granted"); }
    };
    window.Notification.permission = "default";
  });
  log("log in; 24 printers");
  await page.goto(URL + "/");
  await page.getByLabel("API key").fill(RW);
  await page.getByRole("button", { name: "Log in" }).click();
  await page.waitForSelector("#conn.live", { timeout: 60000 });
  await until(async () => (await page.locator("article.printer").count()) === 24, "24 cards");
  await page.getByRole("button", { name: "Notify me" }).click();
  await page.waitForSelector("#notify", { state: "hidden" });

  log("a disabled printer is grey and says disabled, not a red OFFLINE");
  await shown(page, "off", "disabled");
  const edge = await page.locator(sel("off")).evaluate((e) => getComputedStyle(e).borderLeftColor);
  check(edge === "rgb(175, 184, 193)", "disabled card's edge: " + edge);
  check((await cardText(page, "off", ".state")).toLowerCase() === "disabled", "state label");

  log("an offline printer's temperatures are unknown, with when they were last read");
  await shown(page, "gone", "idle");
  process.kill(Number(env("SF_GONE_PID")), "SIGKILL");
  await shown(page, "gone", "offline");
  check(/nozzle unknown/.test(await cardText(page, "gone", ".t-noz")), "offline nozzle");
  check(/last read \d+ \/ \d+ °C at /.test(await cardText(page, "gone", ".msg")), "offline: " + await cardText(page, "gone", ".msg"));

  log("a 3-copy job on slow: the card says heating, not PRINTING 0 %");
  const j = await submit("frame.stl", part("frame.stl"), { method: "none", printer: "slow", copies: 3 });
  await shown(page, "slow", "heating");
  check(/^heating: nozzle \d+ → \d+ °C/.test(await cardText(page, "slow", ".eta")), "heating line");
  check((await cardText(page, "slow", ".job")).includes(`#${j} frame.stl · copy 1 of 3`), "job line");

  log("the card's Stop asks, then stops the copy only: the job goes on");
  const said = await confirmed(page, page.getByRole("button", { name: "Stop this copy on slow" }), "Stop this copy");
  check(said.includes(`copy 1 of 3 of job #${j} (frame.stl)`) && /prints it again/.test(said), "stop dialog: " + said);
  await shown(page, "slow", "awaiting-clear");
  const after = await apiGet(`/api/jobs/${j}`);
  check(after.job.state !== "cancelled" && after.job.copies_done === 0 && after.prints[0].outcome === "cancelled",
    "after the copy's stop: " + JSON.stringify([after.job.state, after.job.copies_done, after.prints]));
  await waitText(page, `${sel("slow")} .job`, new RegExp(`#${j} frame.stl · copy 1 of 3 — cancelled at \\d+ %, bed not cleared`));
  await page.waitForFunction(() => /^\(\d\) slimfarm/.test(document.title), null, { timeout: LONG });
  await page.waitForFunction(() => window.__notes.some((n) => /slow: take the part off the bed/.test(n)), null, { timeout: LONG });
  check(/need bed clear/.test(await page.locator("#counters").innerText()), "counters: " + await page.locator("#counters").innerText());

  log("hot: a thermal runaway is an error with its job and a Clear error that asks");
  const h = await submit("tee.stl", part("tee.stl"), { method: "none", printer: "hot", max_retries: 0 });
  await shown(page, "hot", "error");
  await waitText(page, `${sel("hot")} .job`, new RegExp(`#${h} tee.stl · copy 1 of 1 — failed at \\d+ %`));
  check(/1 error/.test(await page.locator("#counters").innerText()), "counters: " + await page.locator("#counters").innerText());
  const cleared = await confirmed(page, page.getByRole("button", { name: "Clear error on hot" }), "Clear the error");
  check(/fault is fixed/.test(cleared), "clear dialog: " + cleared);
  await waitText(page, `${sel("hot")} .msg`, /Cleared: waits for the printer|^$/);
  check(await page.locator("#error").isHidden(), "an error after Clear error: " + await page.locator("#error").innerText());

  log("fast prints an arc-fitted torus: the finished job names its printer; print history has its filament");
  const t = await submit("torus.stl", part("torus.stl"), { method: "none", printer: "fast" });
  await page.locator("#finished").evaluate((e) => (e.closest("details").open = true));
  await page.waitForSelector(`#finished tr[data-job="${t}"][data-state="done"]`, { timeout: LONG });
  check((await page.locator(`#finished tr[data-job="${t}"] td`).nth(4).innerText()) === "fast", "finished job's printer");
  await page.goto(`${URL}/#job/${t}`);
  await page.waitForSelector(`#view-job[data-job="${t}"][data-state="done"]`, { timeout: LONG });
  await page.waitForSelector('#job-prints tr[data-outcome="done"]', { timeout: LONG });
  const fil = await page.locator('#job-prints tr[data-outcome="done"] td').nth(4).innerText();
  check(/^\d+\.\d\d m$/.test(fil) && fil !== "0.00 m", "a done print's filament: " + fil);
  await waitText(page, "#layer-msg", /layers;/);
  await arcsDrawn(page, t);
  await page.locator("#layer-box").scrollIntoViewIfNeeded();
  await page.screenshot({ path: `${SHOTS}/job-torus-1280.png` });
  await accessible(page, "job page");

  log("the job page follows the layer being printed");
  await page.goto(`${URL}/#`);
  await confirmed(page, page.getByRole("button", { name: "Bed cleared on slow" }), "The bed is clear");
  await page.goto(`${URL}/#job/${j}`);
  await page.waitForSelector(`#view-job[data-job="${j}"][data-state="printing"]`, { timeout: LONG });
  await waitText(page, "#layer-out", /printing now/);
  check(await page.locator("#layer-follow").isChecked(), "follow is off");
  await waitText(page, '#job-prints tr[data-outcome="printing"] td:nth-child(4)', /^[1-9]\d*$/);

  await farmViews(page, j);
  check(problems.length === 0, "browser reported: " + problems.join("; "));
  log("ok");
}

// The arcs of the torus's busiest layer are drawn where the G-code puts
// them: the midpoint of each extruding G2/G3 (from its centre, radius and
// direction, computed here from the G-code text) is inked on the canvas.
// Chords, or arcs left out, miss them.
async function arcsDrawn(page, id) {
  const r = await fetch(`${URL}/api/jobs/${id}/gcode`, { headers: { "X-Api-Key": RW } });
  const layers = [];
  const box = [Infinity, Infinity, -Infinity, -Infinity]; // extrusions' extent, mm
  const grow = (px, py) => {
    box[0] = Math.min(box[0], px); box[1] = Math.min(box[1], py);
    box[2] = Math.max(box[2], px); box[3] = Math.max(box[3], py);
  };
  let x = 0, y = 0, cur = null;
  for (const raw of (await r.text()).split("\n")) {
    if (raw.startsWith(";LAYER_CHANGE")) { cur = []; layers.push(cur); continue; }
    const w = Object.fromEntries(raw.split(";")[0].trim().split(/\s+/).filter((s) => s).map((s) => [s[0], parseFloat(s.slice(1))]));
    if (!(w.G >= 0 && w.G <= 3)) continue;
    const nx = w.X ?? x, ny = w.Y ?? y;
    if (cur && w.E > 0) { grow(x, y); grow(nx, ny); }
    if (cur && (w.G === 2 || w.G === 3) && w.E > 0) {
      const cx = x + (w.I || 0), cy = y + (w.J || 0), rad = Math.hypot(x - cx, y - cy);
      let a0 = Math.atan2(y - cy, x - cx), a1 = Math.atan2(ny - cy, nx - cx);
      if (w.G === 3 && a1 <= a0) a1 += 2 * Math.PI; // anticlockwise
      if (w.G === 2 && a1 >= a0) a1 -= 2 * Math.PI; // clockwise
      for (let k = 1; k < 8; k++) grow(cx + rad * Math.cos(a0 + ((a1 - a0) * k) / 8), cy + rad * Math.sin(a0 + ((a1 - a0) * k) / 8));
      cur.push([cx + rad * Math.cos((a0 + a1) / 2), cy + rad * Math.sin((a0 + a1) / 2), Math.abs(a1 - a0) * rad]);
    }
    x = nx; y = ny;
  }
  // the layer with the most arcs above the first (whose arcs are the skirt's corners)
  const busiest = layers.reduce((b, L, i) => (i > 0 && L.length > layers[b].length ? i : b), 1);
  const arcs = layers[busiest];
  check(arcs.length >= 10, `the torus has ${arcs.length} arcs on its busiest layer: no arc fitting?`);
  await page.locator("#layer").evaluate((s, i) => {
    s.value = String(i);
    s.dispatchEvent(new Event("input"));
  }, busiest);
  await waitText(page, "#layer-out", new RegExp(`^${busiest + 1} of`));
  const hits = await page.evaluate((mids) => {
    const cv = document.querySelector("#layer-canvas");
    const f = JSON.parse(cv.dataset.frame), ctx = cv.getContext("2d");
    let n = 0;
    for (const [mx, my] of mids) {
      const px = Math.round(f.pad + (mx - f.x0) * f.s), py = Math.round(f.h - f.pad - (my - f.y0) * f.s);
      const d = ctx.getImageData(px - 1, py - 1, 3, 3).data;
      let ink = false;
      for (let k = 3; k < d.length; k += 4) ink = ink || d[k] > 200;
      if (ink) n++;
    }
    return n;
  }, arcs.map((a) => [a[0], a[1]]));
  check(hits >= 0.95 * arcs.length, `${hits} of ${arcs.length} arc midpoints inked on layer ${busiest + 1}`);
  // and drawn at the part's size: the frame is the extrusions' own extent
  const f = JSON.parse(await page.locator("#layer-canvas").getAttribute("data-frame"));
  const fit = (600 - 2 * f.pad) / Math.max(box[2] - box[0], box[3] - box[1]);
  check(Math.abs(f.x0 - box[0]) < 0.5 && Math.abs(f.y0 - box[1]) < 0.5 && Math.abs(f.s - fit) < 0.02 * fit,
    `the drawing's frame ${JSON.stringify(f)} is not the G-code's extent ${box.map((v) => v.toFixed(2))}`);
  const legend = await page.locator("#layer-legend").innerText();
  check(/External perimeter/.test(legend) && /travel/.test(legend), "legend: " + legend);
  check(/bed of fast: 250 × 210 mm/.test(await page.locator("#layer-bed").innerText()), "no bed outline");
  log(`layer ${busiest + 1}: ${hits} of ${arcs.length} arc midpoints of the G-code inked`);
}

// The farm at 1280x800, 1920x1080 (cards and the list view) and 390x844:
// screenshots, no sideways scrolling, 44 px targets on the phone, axe-core.
async function farmViews(page, j) {
  log("the farm view: long names wrap, name limit said, screenshots, accessibility");
  const long = "a".repeat(120) + ".stl";
  await submit(long, part("tee.stl"), { method: "none", printer: "off" });
  const refused = await call("/api/jobs", { method: "POST", body: (() => {
    const fd = new FormData();
    fd.append("file", new Blob([part("tee.stl")]), "b".repeat(200) + ".stl");
    return fd;
  })() });
  check(refused.status === 400 && /at most 127 bytes/.test(refused.body.error), "a 204-byte name: " + JSON.stringify(refused));
  await page.goto(`${URL}/#`);
  await page.waitForSelector(`#queue td.name`, { timeout: LONG });
  await waitText(page, "#queue", /aaaaaaaaaa/);
  for (const [w, h] of [[1280, 800], [1920, 1080]]) {
    await page.setViewportSize({ width: w, height: h });
    check(await page.evaluate(() => document.documentElement.scrollWidth <= innerWidth), `sideways scrolling at ${w} px`);
    await page.screenshot({ path: `${SHOTS}/farm-${w}.png` });
  }
  await page.getByRole("button", { name: "List view" }).click();
  await page.screenshot({ path: `${SHOTS}/farm-list-1920.png` });
  await accessible(page, "farm list view at 1920 px");
  await page.getByRole("button", { name: "Card view" }).click();
  await accessible(page, "farm at 1920 px");
  await page.setViewportSize({ width: 390, height: 844 });
  check(await page.evaluate(() => document.documentElement.scrollWidth <= 390), "sideways scrolling at 390 px");
  const small = await page.evaluate(() => [...document.querySelectorAll("button, .tabs a")]
    .filter((b) => b.offsetParent !== null)
    .map((b) => [b.getAttribute("aria-label") || b.textContent, b.getBoundingClientRect()])
    .filter(([, r]) => r.height < 44 || r.width < 44).map(([n, r]) => `${n} ${r.width}x${r.height}`));
  check(small.length === 0, "targets under 44 px on a phone: " + small.slice(0, 5).join(", "));
  await page.screenshot({ path: `${SHOTS}/farm-390.png` });
  await accessible(page, "farm at 390 px");
  await page.setViewportSize({ width: 1280, height: 800 });

  log("submit page: the hidden file input takes no focus; a name over 127 bytes is refused before sending");
  await page.goto(`${URL}/#submit`);
  check(await page.locator("#file").evaluate((e) => e.tabIndex === -1), "the hidden file input is a focus stop");
  await page.setInputFiles("#file", [{ name: "c".repeat(130) + ".stl", mimeType: "model/stl", buffer: part("tee.stl") },
    { name: "tee.stl", mimeType: "model/stl", buffer: part("tee.stl") }]);
  await waitText(page, "#uploads", /at most 127 bytes/);
  check((await page.locator("#uploads li").count()) === 2, "two files listed");
  await accessible(page, "submit page");
  log("a reload keeps the temperature charts: they start from the daemon's samples");
  const kept = await apiGet("/api/printers/slow/temps");
  check(kept.samples.length >= 4, "the daemon kept slow's temperatures: " + kept.samples.length + " samples");
  const reloaded = Date.now();
  await page.reload();
  const chart = page.locator('canvas[aria-label="nozzle and bed temperature history of slow"]');
  await until(async () => Number((await chart.getAttribute("data-since")) || Infinity) <= reloaded - 10000,
    "slow's chart reaches back past the reload");
  log(`job ${j}: cancelled from the queue, the dialog naming its copies`);
  await page.goto(`${URL}/#`);
  const said = await confirmed(page, page.getByRole("button", { name: `Cancel job ${j}`, exact: true }), `Cancel job #${j}`);
  check(said.includes(`cancels job #${j} (frame.stl) and its 3 remaining copies`), "cancel dialog: " + said);
  await until(async () => (await apiGet(`/api/jobs/${j}`)).job.state === "cancelled", "the job cancelled");
}
