// tests/browser/history.mjs - the history page in Debian's chromium driven
// by playwright-core; started by history.sh (one fast simulated printer).
// A job printed to the end and one cancelled, then on the page: both
// listed with their outcome and printer, the outcome filter, the name
// search (the list answers the last search, whatever order the answers
// come in; a list on its way does not show the last one's note), the CSV
// link (its rows follow the filters), "Print again" creating a job, and
// axe-core.  Fails on any page error.
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

// The table's answer is in: the page empties the table when Show is pressed,
// so an empty table alone is no answer.
async function settled(page) {
  return (await page.locator("#jobs").getAttribute("aria-busy")) !== "true";
}

function note(page) {
  return page.locator("#jobs-note").innerText();
}

async function show(page, want, what) {
  await page.getByRole("button", { name: "Show" }).click();
  await until(async () => (await rows(page)).join() === want.join() && (await settled(page)),
    `${what}: rows ${want} (shown: ${await rows(page)}, note: ${await note(page)})`);
}

// Hold the page's requests of the jobs whose name filter is name until
// release(); asked: the first one held, once the page has sent it.
async function hold(page, name) {
  let release, seen;
  const gate = new Promise((w) => (release = w));
  const asked = new Promise((w) => (seen = w));
  const match = (u) => u.pathname === "/api/jobs" && u.searchParams.get("name") === name;
  await page.route(match, async (route) => {
    seen(route.request());
    await gate;
    await route.continue();
  });
  return { asked, release, end: () => page.unroute(match) };
}

// Press Show for a name search whose answer is held.
async function search(page, name) {
  const h = await hold(page, name);
  await page.fill("#f-name", name);
  await page.getByRole("button", { name: "Show" }).click();
  h.request = await h.asked;
  return h;
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
  // its answer held: the emptied table does not keep the last list's note
  const none = await search(page, "no such part");
  check((await rows(page)).length === 0 && !(await settled(page)) && (await note(page)) === "Loading…",
    `a search on its way: rows ${await rows(page)}, note: ${await note(page)}`);
  none.release();
  await until(async () => settled(page), "the answer to 'no such part'");
  await none.end();
  check((await rows(page)).length === 0, `a name nothing has: rows ${await rows(page)}`);
  check((await note(page)) === "No finished job matches.", "empty note: " + (await note(page)));

  log("two searches in a row: the list answers the later one, the earlier answer dropped");
  const first = await search(page, "alpha");
  const second = await search(page, "beta");
  first.release(); // the earlier answer comes in first, then the later one
  await (await first.request.response()).finished();
  second.release();
  await until(async () => (await rows(page)).includes(cut) && (await settled(page)), `job ${cut} listed`);
  await first.end();
  await second.end();
  check((await rows(page)).join() === [cut].join() && (await note(page)) === "1 jobs shown.",
    `after 'alpha' then 'beta': rows ${await rows(page)}, note: ${await note(page)}`);

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
