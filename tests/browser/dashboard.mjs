// tests/browser/dashboard.mjs - the dashboard in Debian's chromium, driven
// by playwright-core; started by dashboard.sh, which runs the farm (two
// simulated printers, mk3 without an ejector, mini with one) and passes
// its address, keys, parts and daemon in SF_* variables.
//
// Every wait is for a state the page shows (generous bounds for a loaded
// machine), never a fixed sleep.  The page is loaded once: a sentinel set
// on window at the start must still be there at the end, so every update
// came from the event stream, not a reload.
import { spawn } from "node:child_process";
import fs from "node:fs";
import path from "node:path";
import { chromium } from "playwright-core";
import { LONG, accessible, apiGet, check, confirmed, env, log, runChromium, until } from "./lib.mjs";

const URL = env("SF_URL"), RW = env("SF_RW"), RO = env("SF_RO"), PARTS = env("SF_PARTS");
const SHOTS = env("SF_SHOTS");
const problems = [];

let refusals = 0; // 400s a step expects (the browser logs each as an error)

await runChromium("failure.png", run);

function watch(page) {
  page.on("pageerror", (e) => problems.push("page error: " + e.message));
  page.on("console", (m) => {
    if (m.type() === "error" && refusals > 0 && /status of 400/.test(m.text())) refusals--;
    else if (m.type() === "error" && !/status of 40[13]|ERR_CONNECTION_REFUSED|net::ERR/.test(m.text()))
      problems.push("console error: " + m.text());
    if (/Content Security Policy/i.test(m.text())) problems.push("CSP violation: " + m.text());
  });
}


async function waitCard(page, name, state) {
  await page.waitForSelector(`article.printer[data-printer="${name}"][data-state="${state}"]`,
    { timeout: LONG });
}

async function login(page, key) {
  await page.goto(URL + "/");
  await logIn(page, key);
}

// Fill the login form the page shows (no reload).
async function logIn(page, key) {
  await page.waitForSelector("#login:not([hidden])", { timeout: 60000 });
  await page.getByLabel("API key").fill(key);
  await page.getByRole("button", { name: "Log in" }).click();
  await page.waitForSelector("#app:not([hidden]) article.printer", { timeout: 60000 });
}

// Every visible button and form control has a name a screen reader reads.
async function checkNames(page, where) {
  const bad = await page.evaluate(() => {
    const out = [];
    const visible = (e) => e.offsetParent !== null || e.getClientRects().length > 0;
    for (const b of document.querySelectorAll("button")) {
      if (!visible(b)) continue;
      const name = (b.getAttribute("aria-label") || b.textContent || "").trim();
      if (!name) out.push("button " + b.outerHTML.slice(0, 80));
    }
    for (const c of document.querySelectorAll("input, select")) {
      if (!visible(c) && c.type !== "file") continue;
      if (!(c.labels && c.labels.length) && !c.getAttribute("aria-label")) out.push("control " + c.id);
    }
    return out;
  });
  check(bad.length === 0, `${where}: without an accessible name: ${bad.join(", ")}`);
  const n = await page.locator("button:visible").count();
  log(`${where}: ${n} visible buttons, each with an accessible name`);
}

async function dropFile(page, file) {
  const b64 = fs.readFileSync(file).toString("base64");
  await page.evaluate(([name, data]) => {
    const bytes = Uint8Array.from(atob(data), (c) => c.charCodeAt(0));
    const dt = new DataTransfer();
    dt.items.add(new File([bytes], name, { type: "model/stl" }));
    const drop = document.querySelector("#drop");
    drop.dispatchEvent(new DragEvent("dragover", { dataTransfer: dt, bubbles: true, cancelable: true }));
    drop.dispatchEvent(new DragEvent("drop", { dataTransfer: dt, bubbles: true, cancelable: true }));
  }, [path.basename(file), b64]);
}

async function submitForm(page, opts) {
  await page.getByRole("link", { name: "Submit a part" }).click();
  if (opts.drop) await dropFile(page, opts.file);
  else await page.setInputFiles("#file", opts.file);
  await page.waitForFunction((n) => document.querySelector("#file-name").textContent === n,
    path.basename(opts.file));
  await page.selectOption("#method", opts.method);
  await page.selectOption("#target", opts.target);
  await page.getByLabel("Copies").fill(String(opts.copies || 1));
  await page.getByRole("button", { name: "Submit", exact: true }).click();
  await page.waitForFunction(() => /^#job\/\d+$/.test(location.hash), null, { timeout: 60000 });
  const id = Number((await page.evaluate(() => location.hash)).slice(5));
  check(id > 0, "no job id after submitting");
  return id;
}

// GET /api/jobs/ID from here (not the page).
async function apiJob(id) {
  const r = await fetch(`${URL}/api/jobs/${id}`, { headers: { "X-Api-Key": RW } });
  if (!r.ok) throw new Error(`GET /api/jobs/${id}: ${r.status}`);
  return r.json();
}

async function jobState(page, id) {
  return (await apiJob(id)).job.state;
}

async function run(ctx) {
  const page = await ctx.newPage();
  watch(page);

  log("the page and its headers");
  const resp = await page.goto(URL + "/");
  const csp = resp.headers()["content-security-policy"] || "";
  check(/script-src 'self'/.test(csp) && !/unsafe-inline/.test(csp), "CSP: " + csp);
  check(resp.headers()["etag"], "no ETag on /");
  check(await page.getByLabel("API key").isVisible(), "no login form");

  log("a wrong key is refused");
  await page.getByLabel("API key").fill("not-a-key-0123456789");
  await page.getByRole("button", { name: "Log in" }).click();
  await page.waitForFunction(() => document.querySelector("#login-error").textContent !== "");

  log("log in with the operator key");
  await login(page, RW);
  await waitCard(page, "mk3", "idle");
  await waitCard(page, "mini", "idle");
  check(!(await page.evaluate(() => location.href)).includes(RW), "the key is in the URL");
  await page.evaluate(() => (window.__sentinel = "no reload"));
  await page.waitForSelector("#conn.live", { timeout: 60000 });
  await checkNames(page, "printer grid");
  await accessible(page, "printer grid");

  log("a text file renamed .stl is refused at upload, the page saying why");
  const jobsBefore = (await (await fetch(`${URL}/api/jobs`, { headers: { "X-Api-Key": RW } })).json()).jobs.length;
  await page.getByRole("link", { name: "Submit a part" }).click();
  await page.setInputFiles("#file", { name: "notes.stl", mimeType: "model/stl", buffer: Buffer.from("shopping list:\nmilk\n") });
  refusals = 1;
  await page.getByRole("button", { name: "Submit", exact: true }).click();
  await page.waitForFunction(() => /Refused: notes\.stl: not an STL: 'notes\.stl' holds plain text/.test(document.querySelector("#submit-msg").textContent),
    null, { timeout: 60000 });
  check(/not an STL/.test(await page.locator('#uploads li[data-file="notes.stl"] .up-msg').innerText()), "the file's line says why");
  const jobsAfter = (await (await fetch(`${URL}/api/jobs`, { headers: { "X-Api-Key": RW } })).json()).jobs.length;
  check(jobsAfter === jobsBefore, `the refused file made a job: ${jobsBefore} -> ${jobsAfter}`);

  log("submit a tee through the form (file input), oriented, to mk3");
  const j1 = await submitForm(page, { file: `${PARTS}/tee.stl`, method: "orient", target: "printer:mk3" });
  await page.waitForSelector(`#view-job[data-job="${j1}"]`);
  log(`job ${j1}: wait for it to print and be done, without reloading`);
  await page.waitForSelector(`#view-job[data-job="${j1}"][data-state="done"]`, { timeout: LONG });
  await page.waitForFunction(() => {
    const ok = (i) => i.complete && i.naturalWidth > 0;
    return ok(document.querySelector("#pic-before")) && ok(document.querySelector("#pic-after"));
  }, null, { timeout: LONG });
  await page.waitForFunction(() => /layers;/.test(document.querySelector("#layer-msg").textContent),
    null, { timeout: LONG });
  const facts = await page.locator("#job-facts").innerText();
  check(/Printer\s+mk3/.test(facts), "job page does not name mk3: " + facts);
  check(/Support as sliced/.test(facts) && /Print time/.test(facts), "job page facts: " + facts);
  // the support model's grams arrive with the pictures
  await page.waitForFunction(() => !/computing/.test(document.querySelector("#job-facts").innerText),
    null, { timeout: LONG });
  check((await page.locator("#job-prints tbody tr").first().innerText()).includes("done"), "print history");
  // the layer slider redraws the canvas
  const slider = page.getByLabel(/^Layer/);
  await slider.focus();
  await page.keyboard.press("Home");
  await page.waitForFunction(() => document.querySelector("#layer-out").textContent.startsWith("1 of"));
  await page.keyboard.press("ArrowRight");
  await page.keyboard.press("ArrowRight");
  await page.waitForFunction(() => document.querySelector("#layer-out").textContent.startsWith("3 of"));
  await page.evaluate(() => window.scrollTo(0, 0));
  await page.screenshot({ path: `${SHOTS}/job-1280.png` });
  await page.screenshot({ path: `${SHOTS}/job-full-1280.png`, fullPage: true });
  await page.locator("#layer-box").scrollIntoViewIfNeeded();
  await page.screenshot({ path: `${SHOTS}/job-layers-1280.png` });
  await checkNames(page, "job page");
  await accessible(page, "job page");

  log("mk3 waits for its bed to be cleared: press Bed cleared");
  await page.getByRole("link", { name: "back to the farm" }).click();
  await waitCard(page, "mk3", "awaiting-clear");
  // the card says what is on the bed: the job, its copy and how it ended
  await page.waitForFunction((id) => {
    const t = document.querySelector('article.printer[data-printer="mk3"] .job').textContent;
    return t.includes(`#${id}`) && /copy 1 of 1 — done, bed not cleared/.test(t);
  }, j1, { timeout: 60000 });
  // asked first; "Go back" leaves the bed as it is
  await page.getByRole("button", { name: "Bed cleared on mk3" }).click();
  await page.locator("#confirm").waitFor({ state: "visible" });
  check(/mk3 takes the next job at once/.test(await page.locator("#confirm").innerText()), "Bed cleared dialog");
  await page.getByRole("button", { name: "Go back" }).click();
  await page.locator("#confirm").waitFor({ state: "hidden" });
  check((await apiGet("/api/printers/mk3")).printer.state === "awaiting-clear", "Go back cleared the bed");
  await confirmed(page, page.getByRole("button", { name: "Bed cleared on mk3" }), "The bed is clear");
  await waitCard(page, "mk3", "idle");

  log("a job no printer can take waits, saying why; reorder the queue");
  const q = await page.evaluate(async ([u, k]) => {
    const ids = [];
    for (let i = 0; i < 3; i++) {
      const fd = new FormData();
      fd.append("file", new File(["solid x\nendsolid x\n"], `tpu${i}.stl`));
      fd.append("options", JSON.stringify({ material: "TPU", method: "none" }));
      const r = await fetch(`${u}/api/jobs`, { method: "POST", headers: { "X-Api-Key": k }, body: fd });
      ids.push((await r.json()).job.id);
    }
    return ids;
  }, [URL, RW]);
  await page.waitForFunction((id) => {
    const tr = document.querySelector(`#queue tr[data-job="${id}"]`);
    return tr && /TPU/.test(tr.innerText);
  }, q[2], { timeout: LONG });
  const order = () => page.evaluate(() => [...document.querySelectorAll("#queue tbody tr[data-job]")].map((t) => Number(t.dataset.job)));
  const ours = async () => (await order()).filter((id) => q.includes(id));
  check((await ours()).join() === q.join(), "queue order " + (await order()));
  // ▲ on the third of three jobs of equal priority: one place, to second (a
  // priority change once jumped it past both, to first)
  await page.getByRole("button", { name: `Move job ${q[2]} up` }).click();
  await page.waitForFunction(([a, b]) => {
    const ids = [...document.querySelectorAll("#queue tbody tr[data-job]")].map((t) => Number(t.dataset.job));
    return ids.indexOf(b) >= 0 && ids.indexOf(b) < ids.indexOf(a);
  }, [q[1], q[2]], { timeout: 60000 });
  check((await ours()).join() === [q[0], q[2], q[1]].join(), "▲ moved it more than one place: " + (await order()));
  const jobs = (await apiGet("/api/jobs?state=queued")).jobs.filter((j) => q.includes(j.id));
  check(jobs.every((j) => j.priority === 0), "▲ changed a priority: " + JSON.stringify(jobs.map((j) => j.priority)));

  log("submit a frame by drag and drop, to mini, two copies; pause and resume it");
  const j2 = await submitForm(page, { file: `${PARTS}/frame.stl`, method: "none", target: "printer:mini", drop: true, copies: 2 });
  await page.getByRole("link", { name: "back to the farm" }).click();
  await waitCard(page, "mini", "printing");
  await page.getByRole("button", { name: "Pause mini" }).click();
  await waitCard(page, "mini", "paused");
  check((await jobState(page, j2)) === "paused", "job not paused");
  await page.waitForSelector(`#printing tr[data-job="${j2}"][data-state="paused"]`, { timeout: 60000 });
  await page.getByRole("button", { name: "Resume mini" }).click();
  await waitCard(page, "mini", "printing");
  log("printer grid screenshots while mini prints (1280x800, 390 px)");
  await page.waitForFunction(() => {
    const bar = document.querySelector('article.printer[data-printer="mini"] .bar');
    return Number(bar.getAttribute("aria-valuenow")) > 0;
  }, null, { timeout: LONG });
  await page.screenshot({ path: `${SHOTS}/grid-1280.png` });
  await page.setViewportSize({ width: 390, height: 844 });
  const wide = await page.evaluate(() => document.documentElement.scrollWidth);
  check(wide <= 390, `the page is ${wide} px wide on a 390 px screen`);
  await page.screenshot({ path: `${SHOTS}/grid-390.png`, fullPage: true });
  await checkNames(page, "printer grid at 390 px");
  await accessible(page, "printer grid at 390 px");
  await page.setViewportSize({ width: 1280, height: 800 });

  log("cancel the waiting jobs from the queue (each asks first, naming the job and its copies)");
  for (const id of q) {
    const said = await confirmed(page, page.getByRole("button", { name: `Cancel job ${id}`, exact: true }), `Cancel job #${id}`);
    check(said.includes(`cancels job #${id} (tpu`) && said.includes("its 1 remaining copy"), "cancel dialog: " + said);
    await page.waitForSelector(`#queue tr[data-job="${id}"]`, { state: "detached", timeout: 60000 });
  }

  log(`job ${j2}: both copies print; done without a reload`);
  await page.waitForSelector(`#finished tr[data-job="${j2}"][data-state="done"]`, { state: "attached", timeout: LONG });
  check(await page.evaluate(() => window.__sentinel === "no reload"), "the page was reloaded");

  log("a new tab of the same browser is logged in by its session cookie");
  const tab = await ctx.newPage();
  watch(tab);
  await tab.goto(URL + "/");
  await tab.waitForSelector("#app:not([hidden]) article.printer", { timeout: 60000 });
  check((await tab.locator("#who").innerText()) === "operator key", "the new tab is not the operator's");
  check(await tab.evaluate(() => sessionStorage.length === 0 && localStorage.length === 0),
    "the page keeps something in storage (the key?)");
  await tab.close();

  log("a read-only key (another browser) shows the dashboard without buttons");
  const other = await chromium.launch({ executablePath: "/usr/bin/chromium", headless: true,
    args: ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run"] });
  const ro = await (await other.newContext({ viewport: { width: 1280, height: 800 } })).newPage();
  watch(ro);
  await login(ro, RO);
  await ro.waitForSelector("#who", { state: "visible" });
  check((await ro.locator("#who").innerText()) === "read-only key", "not shown as read-only");
  await ro.waitForSelector(`#finished tr[data-job="${j2}"]`, { state: "attached", timeout: 60000 });
  // only buttons that change nothing on the farm: the view, notifications, Log out
  const VIEW_ONLY = ["Log out", "Notify me", "List view"];
  const roButtons = await ro.locator("button:visible").allInnerTexts();
  check(roButtons.every((b) => VIEW_ONLY.includes(b)), "read-only page has buttons: " + roButtons);
  check(!(await ro.getByRole("link", { name: "Submit a part" }).isVisible()), "read-only page offers submit");
  await ro.goto(URL + `/#job/${j1}`);
  await ro.waitForSelector(`#view-job[data-job="${j1}"][data-state="done"]`, { timeout: 60000 });
  check((await ro.locator("button:visible").allInnerTexts()).every((b) => VIEW_ONLY.includes(b)),
    "read-only job page has buttons");
  await other.close();

  log("the daemon is killed mid-print: the page says the connection is lost, asks for the key again, recovers");
  const j3 = await submitForm(page, { file: `${PARTS}/frame.stl`, method: "none", target: "printer:mini" });
  await page.getByRole("link", { name: "back to the farm" }).click();
  await until(async () => {
    const j = await apiJob(j3);
    return j.job.state === "printing" && j.job.lines_acked > 0;
  }, `job ${j3} printing with lines acknowledged`);
  process.kill(Number(env("SF_PID")), "SIGKILL");
  await page.waitForSelector("#banner:not([hidden])", { timeout: 60000 });
  check((await page.locator("#conn").innerText()) === "reconnecting", "badge does not say reconnecting");
  // nothing can be asked of a daemon that is gone: every action button is off
  const live = await page.evaluate(() => [...document.querySelectorAll("#app button")]
    .filter((b) => !b.disabled && (b.offsetParent !== null)).map((b) => b.getAttribute("aria-label") || b.textContent));
  check(live.length === 0, "buttons still live while the daemon is down: " + live.join(", "));
  const out = fs.openSync(env("SF_LOG"), "a");
  const d = await startDaemon(out);
  fs.writeFileSync(env("SF_PIDFILE"), String(d.pid));
  // sessions live in the daemon's memory: a restarted one asks for the key
  await logIn(page, RW);
  await page.waitForSelector("#banner[hidden]", { state: "attached", timeout: LONG });
  await page.waitForSelector("#conn.live", { timeout: LONG });
  check(await page.evaluate(() => window.__sentinel === "no reload"), "the page was reloaded");
  check(await page.locator("#error").isHidden(), "an error stays on screen after the daemon is back: " +
    await page.locator("#error").innerText());

  log(`job ${j3} was interrupted: the card shows mini blocked by it, the queue offers to resume it`);
  await page.waitForSelector(`#printing tr[data-job="${j3}"][data-state="interrupted"]`, { timeout: LONG });
  await waitCard(page, "mini", "idle");
  await page.waitForSelector('article.printer[data-printer="mini"][data-shown="blocked"]', { timeout: LONG });
  const mj = await page.locator('article.printer[data-printer="mini"] .job').innerText();
  check(mj.includes(`#${j3}`) && /interrupted at line \d+/.test(mj), "blocked card: " + mj);
  check(await page.getByRole("button", { name: "Restart the job on mini" }).isVisible(), "no Restart on the blocked card");
  check((await page.title()).startsWith("(1)"), "the tab's title does not count the blocked printer: " + await page.title());
  const line = page.getByLabel(`Line to resume job ${j3} from`);
  check(Number(await line.inputValue()) > 0, "no line to resume from");
  await page.getByRole("button", { name: `Resume job ${j3} from the chosen line` }).click();
  await page.waitForSelector('article.printer[data-printer="mini"]:not([data-shown="blocked"])', { timeout: LONG });
  await page.waitForSelector(`#finished tr[data-job="${j3}"][data-state="done"]`, { state: "attached", timeout: LONG });
  const prints = (await apiJob(j3)).prints.map((p) => [p.outcome, p.start_line]);
  check(prints.length === 2 && prints[0][0] === "interrupted" && prints[1][0] === "done" && prints[1][1] > 0,
    "print history after the resume: " + JSON.stringify(prints));
  check(await page.evaluate(() => window.__sentinel === "no reload"), "the page was reloaded");

  log("Log out ends the session on the daemon, not only in the page");
  await page.getByRole("button", { name: "Log out" }).click();
  await page.waitForSelector("#login:not([hidden])", { timeout: 60000 });
  check(await page.evaluate(async () => (await fetch("/api/jobs")).status === 401),
    "the session still reads after Log out");
  check((await ctx.cookies()).every((c) => !c.name.startsWith("sf_session")), "the cookie is still there");

  check(problems.length === 0, "browser reported: " + problems.join("; "));
  log("ok");
}

// Start slimfarmd again on the same config; it refuses to start while the
// old one still holds the data dir's lock, so try until one stays up.
async function startDaemon(out) {
  for (let i = 0; i < 600; i++) {
    const d = spawn(env("SF_DAEMON"), ["-c", env("SF_CONFIG")], { stdio: ["ignore", out, out], detached: true });
    const exited = await new Promise((res) => {
      d.on("exit", () => res(true));
      d.on("spawn", async () => {
        // up when the API answers
        for (let k = 0; k < 100; k++) {
          try {
            const r = await fetch(URL + "/api/jobs", { headers: { "X-Api-Key": RW } });
            if (r.ok) return res(false);
          } catch (e) { /* not yet */ }
          if (d.exitCode !== null) return res(true);
          await new Promise((w) => setTimeout(w, 100));
        }
        res(d.exitCode !== null);
      });
    });
    if (!exited) {
      d.unref();
      return d;
    }
    await new Promise((w) => setTimeout(w, 100));
  }
  throw new Error("slimfarmd did not start again");
}
