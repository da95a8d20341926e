// tests/browser/history.mjs - the history page in Debian's chromium driven
// by playwright-core; started by history.sh (one fast simulated printer).
// A job printed to the end and one cancelled, then on the page: both
// listed with their outcome and printer, the outcome filter, the name
// search, the CSV link (its rows follow the filters), "Print again"
// creating a job, and axe-core.  Fails on any page error.
import fs from "node:fs";
import path from "node:path";
import { accessible, apiGet, call, check, env, log, runChromium, submit, until } from "./lib.mjs";

const URL = env("SF_URL"), RW = env("SF_RW"), PARTS = env("SF_PARTS"), SHOTS = env("SF_SHOTS");
const problems = [];

await runChromium("history-failure.png", async (ctx) => run(await ctx.newPage()));

// The job ids the table shows, top to bottom.
function rows(page) {
  return page.evaluate(() => [...document.querySelectorAll("#jobs tbody tr")].map((tr) => Number(tr.cells[0].textContent)));
}

async function show(page, want, what) {
  await page.getByRole("button", { name: "Show" }).click();
  await until(async () => (await rows(page)).join() === want.join(), `${what}: rows ${want} (shown: ${await rows(page)})`);
}

async function run(page) {
  page.on("pageerror", (e) => problems.push("page error: " + e.message));

  log("a job printed to the end on mk3, one cancelled while it waits");
  const done = await submit("alpha frame.stl", fs.readFileSync(path.join(PARTS, "frame.stl")), { method: "none" });
  const cut = await submit("beta.stl", "solid x\nendsolid x\n", { material: "TPU", method: "none" });
  const r = await call(`/api/jobs/${cut}/cancel`, { method: "POST" });
  check(r.status === 200, `cancel: ${r.status} ${JSON.stringify(r.body)}`);
  await until(async () => (await apiGet(`/api/jobs/${done}`)).job.state === "done", `job ${done} done`);

  log("log in on the dashboard, open the history page");
  await page.goto(URL + "/");
  await page.getByLabel("API key").fill(RW);
  await page.getByRole("button", { name: "Log in" }).click();
  await page.waitForSelector("#conn.live", { timeout: 60000 });
  // from here on the session is open: no request may fail (the dashboard's own first
  // GET /api/whoami, before the log in, is a 401 by design)
  page.on("console", (m) => { if (m.type() === "error") problems.push("console: " + m.text()); });
  await page.goto(URL + "/history.html");
  await until(async () => (await rows(page)).join() === [cut, done].join(), `both jobs listed (shown: ${await rows(page)})`);
  const cells = await page.locator(`#jobs tbody tr:nth-child(2) td`).allInnerTexts();
  check(cells[1] === "alpha frame.stl" && cells[2] === "done" && cells[5] === "mk3", "the done job's row: " + cells.join(" | "));
  const cutCells = await page.locator(`#jobs tbody tr:nth-child(1) td`).allInnerTexts();
  check(cutCells[2] === "cancelled" && /cancelled by an operator/.test(cutCells[8]), "the cancelled job's row: " + cutCells.join(" | "));
  check((await page.locator("#jobs-note").innerText()) === "2 jobs shown.", "note");
  await page.screenshot({ path: `${SHOTS}/history-1280.png`, fullPage: true });
  await accessible(page, "history page");

  log("filter by outcome, then search by name");
  await page.selectOption("#f-state", "cancelled");
  await show(page, [cut], "outcome cancelled");
  await page.selectOption("#f-state", "done");
  await show(page, [done], "outcome done");
  await page.selectOption("#f-state", "done,failed,cancelled");
  await page.fill("#f-name", "alpha");
  await show(page, [done], "name alpha");
  await page.fill("#f-name", "no such part");
  await show(page, [], "a name nothing has");
  check((await page.locator("#jobs-note").innerText()) === "No finished job matches.", "empty note");

  log("the CSV link follows the filters");
  await page.fill("#f-name", "alpha");
  await show(page, [done], "name alpha again");
  const href = await page.locator("#csv").getAttribute("href");
  check(/format=csv/.test(href) && /name=alpha/.test(href), "CSV link: " + href);
  const csv = await page.evaluate(async (h) => (await fetch(h, { credentials: "same-origin" })).text(), href);
  const lines = csv.trim().split(/\r?\n/);
  check(lines[0].startsWith("id,name,state,") && lines.length === 2 && lines[1].startsWith(`${done},alpha frame.stl,done,`),
    "CSV: " + csv.slice(0, 400));

  log("print again: a new job from the same file and options");
  await page.getByRole("button", { name: `Print again: job #${done} alpha frame.stl` }).click();
  await until(async () => /queued again as job #\d+/.test(await page.locator("#jobs-note").innerText()), "the page says the new job");
  const again = Number((await page.locator("#jobs-note").innerText()).match(/as job #(\d+)/)[1]);
  const j = (await apiGet(`/api/jobs/${again}`)).job;
  check(again > cut && j.name === "alpha frame.stl" && j.method === "none", "the new job: " + JSON.stringify(j).slice(0, 300));
  check(!(await page.locator("#error").isVisible()), "error banner: " + (await page.locator("#error").innerText()));
  check(problems.length === 0, problems.join("; "));
  log("ok");
}
