// tests/browser/lib.mjs - what the browser tests (dashboard.mjs, cards.mjs)
// share: the environment, checks, waits, the daemon's API from the test's
// side, the confirmation dialog, and the accessibility check (axe-core).
//
// Every wait is for a state (generous bounds for a loaded machine), never a
// fixed sleep.
import fs from "node:fs";
import { createRequire } from "node:module";
import os from "node:os";
import path from "node:path";
import { chromium } from "playwright-core";

export const env = (k) => {
  const v = process.env[k];
  if (!v) throw new Error(`${k} is not set (run the test's .sh)`);
  return v;
};
// ms: a slow sanitizer build on a loaded machine (SF_LONG_MS: shorter, to see
// a test fail quickly on a page without the feature it checks)
export const LONG = Number(process.env.SF_LONG_MS) || 300000;

let step = "start";
export const log = (s) => {
  step = s;
  console.log("  " + s);
};
export const where = () => step;

export function check(cond, what) {
  if (!cond) throw new Error(`${step}: ${what}`);
}

// Poll cond (async) until it holds, within LONG.
export async function until(cond, what) {
  const end = Date.now() + LONG;
  while (Date.now() < end) {
    if (await cond()) return;
    await new Promise((w) => setTimeout(w, 200));
  }
  throw new Error(`${step}: timed out waiting for ${what}`);
}

// The daemon's API with the operator's key: GET (or a method and a body).
export async function call(path, opts) {
  opts = opts || {};
  const r = await fetch(env("SF_URL") + path, Object.assign({}, opts,
    { headers: Object.assign({ "X-Api-Key": env("SF_RW") }, opts.headers || {}) }));
  const text = await r.text();
  return { status: r.status, body: text ? JSON.parse(text) : null };
}

export async function apiGet(path) {
  const r = await call(path);
  if (r.status !== 200) throw new Error(`GET ${path}: ${r.status} ${JSON.stringify(r.body)}`);
  return r.body;
}

// Submit a part file (bytes) with options; the job's id.
export async function submit(name, bytes, options) {
  const fd = new FormData();
  fd.append("file", new Blob([bytes]), name);
  fd.append("options", JSON.stringify(options));
  const r = await call("/api/jobs", { method: "POST", body: fd });
  if (r.status !== 201) throw new Error(`submit ${name}: ${r.status} ${JSON.stringify(r.body)}`);
  return r.body.job.id;
}

// A guarded button: it asks first, saying what it will do; answer with the
// button named ok.  Returns the dialog's words.
export async function confirmed(page, button, ok) {
  await button.click();
  const d = page.locator("#confirm");
  await d.waitFor({ state: "visible", timeout: 60000 });
  const text = await d.innerText();
  check((await page.locator("#confirm-ok").innerText()) === ok, `the dialog's button is not "${ok}": ${text}`);
  await page.locator("#confirm-ok").click();
  await d.waitFor({ state: "hidden", timeout: 60000 });
  return text;
}

// axe-core on what the page shows: no serious or critical violation.
const axeSource = fs.readFileSync(createRequire(import.meta.url).resolve("axe-core/axe.min.js"), "utf8");
export async function accessible(page, what) {
  // evaluated by the browser's debugger protocol: the page's CSP stays on
  if (!(await page.evaluate(() => typeof window.axe === "object"))) await page.evaluate(axeSource);
  const bad = await page.evaluate(async () => {
    const r = await window.axe.run(document, { resultTypes: ["violations"] });
    return r.violations.filter((v) => v.impact === "serious" || v.impact === "critical")
      .map((v) => `${v.id} (${v.impact}): ${v.nodes.slice(0, 3).map((n) => n.target.join(" ")).join(", ")}`);
  });
  check(bad.length === 0, `${what}: accessibility: ${bad.join("; ")}`);
  log(`${what}: axe-core finds no serious or critical violation`);
}

// Run fn(ctx) in a fresh chromium profile at 1280x800; on a failure, say
// where, keep a screenshot (SHOTS/failed) and the page's text.  Exits the
// process: 0 when fn went through.
export async function runChromium(failed, fn) {
  const userDir = fs.mkdtempSync(path.join(os.tmpdir(), "sfchromium-"));
  const ctx = await chromium.launchPersistentContext(userDir, {
    executablePath: "/usr/bin/chromium",
    headless: true,
    viewport: { width: 1280, height: 800 },
    args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
      "--disable-background-networking", "--disable-component-update", "--disable-sync"],
  });
  let code = 1;
  try {
    await fn(ctx);
    code = 0;
  } catch (e) {
    console.log(`FAIL at "${step}": ${e.message}`);
    for (const p of ctx.pages()) {
      try {
        await p.screenshot({ path: path.join(env("SF_SHOTS"), failed), fullPage: true });
        console.log("  page text: " + (await p.locator("body").innerText()).slice(0, 1500).replace(/\n+/g, " | "));
      } catch (e2) { /* the page is gone */ }
    }
  } finally {
    await ctx.close();
    fs.rmSync(userDir, { recursive: true, force: true });
  }
  process.exit(code);
}
