// tests/browser/printers.mjs - printers managed at run time from the
// dashboard (src/api/web/printers.js), in Debian's chromium driven by
// playwright-core; started by printers.sh.  A printer is added through the
// Add printer form (a refused field is named in the form first), connects,
// is disabled with a reason (its card grey, saying it), enabled again and
// removed, each guarded as the other destructive actions are; the daemon's
// API agrees at each step; axe-core finds nothing serious in the dialogs.
import { LONG, accessible, apiGet, call, check, confirmed, env, log, runChromium } from "./lib.mjs";

const URL = env("SF_URL"), RW = env("SF_RW"), SHOTS = env("SF_SHOTS"), PORT = env("SF_MK_PORT");
const sel = (name) => `article.printer[data-printer="${name}"]`;
const problems = [];

await runChromium("printers-failure.png", async (ctx) => run(await ctx.newPage()));

async function printer(name) {
  const r = await call(`/api/printers/${name}`);
  return r.status === 200 ? r.body.printer : null;
}

async function run(page) {
  page.on("pageerror", (e) => problems.push("page error: " + e.message));
  log("log in; one printer from farm.ini");
  await page.goto(URL + "/");
  await page.getByLabel("API key").fill(RW);
  await page.getByRole("button", { name: "Log in" }).click();
  await page.waitForSelector("#conn.live", { timeout: 60000 });
  await page.waitForSelector(sel("seed"), { timeout: LONG });

  log("Add printer: the form has the kinds, and each kind its own fields");
  await page.getByRole("button", { name: "Add printer" }).click();
  await page.locator("#pf").waitFor({ state: "visible", timeout: 60000 });
  const kinds = await page.locator("#pf-kind option").allInnerTexts();
  check(["marlin", "octoprint", "moonraker", "prusalink", "bambu"].every((k) => kinds.includes(k)), "kinds: " + kinds);
  await page.locator("#pf-kind").selectOption("octoprint");
  check(await page.locator("#pf-url").isVisible() && await page.locator("#pf-api_key").isVisible(), "octoprint has no url/api_key fields");
  check(!(await page.locator("#pf-port").count()), "octoprint shows marlin's port");
  await page.locator("#pf-kind").selectOption("marlin");
  await page.locator("#pf-port").waitFor({ state: "visible", timeout: 60000 });
  await page.screenshot({ path: `${SHOTS}/form.png` });
  await accessible(page, "Add printer form");

  log("a bad field is refused with its name, in the form, the field marked; nothing is added");
  await page.locator("#pf-name").fill("mk");
  await page.locator("#pf-port").fill(PORT);
  await page.locator("#pf-baud").fill("1000000");
  await page.locator("#pf-nozzle_mm").fill("9");
  await page.locator("#pf-save").click();
  await page.waitForFunction(() => /nozzle_mm/.test(document.querySelector("#pf-error").textContent), null, { timeout: 60000 });
  check((await page.locator("#pf-nozzle_mm").getAttribute("aria-invalid")) === "true", "nozzle_mm not marked");
  check(await page.locator("#pf").isVisible(), "the form closed on a refusal");
  check((await printer("mk")) === null, "a refused printer was added");

  log("added: its card appears and the printer connects");
  await page.locator("#pf-nozzle_mm").fill("0.4");
  await page.locator("#pf-material").fill("PETG");
  await page.locator("#pf-save").click();
  await page.locator("#pf").waitFor({ state: "hidden", timeout: 60000 });
  await page.waitForSelector(`${sel("mk")}[data-shown="idle"]`, { timeout: LONG });
  const mk = await printer("mk");
  check(mk && mk.material === "PETG" && mk.enabled, "the API's mk: " + JSON.stringify(mk));
  const cfg = (await apiGet("/api/printers/mk/config")).printer;
  check(cfg.source === "api" && cfg.options.port === PORT && cfg.options.baud === "1000000", "mk's config: " + JSON.stringify(cfg));
  await page.screenshot({ path: `${SHOTS}/added.png` });

  log("edit: Manage shows its options; a change is saved");
  await page.getByRole("button", { name: "Manage mk" }).click();
  await page.locator("#pf").waitFor({ state: "visible", timeout: 60000 });
  check((await page.locator("#pf-port").inputValue()) === PORT, "the form does not show mk's port");
  await page.locator("#pf-more-box summary").click();
  await page.locator("#pf-group").fill("petg");
  await page.locator("#pf-save").click();
  await page.locator("#pf").waitFor({ state: "hidden", timeout: 60000 });
  await page.waitForFunction((s) => /group petg/.test(document.querySelector(s + " .spec").textContent), sel("mk"), { timeout: LONG });

  log("disabled with a reason: the card is grey and says why; the API agrees");
  await page.getByRole("button", { name: "Manage mk" }).click();
  await page.locator("#pf").waitFor({ state: "visible", timeout: 60000 });
  await page.locator("#pf-disable").click();
  const d = page.locator("#confirm");
  await d.waitFor({ state: "visible", timeout: 60000 });
  const said = await d.innerText();
  check(/takes no new job/.test(said), "the disable dialog: " + said);
  check(await page.locator("#confirm-ok").isDisabled(), "Disable without a reason is offered");
  await accessible(page, "disable dialog");
  await page.locator("#confirm-input").fill("nozzle swap");
  await page.getByRole("button", { name: "Disable mk" }).click();
  await d.waitFor({ state: "hidden", timeout: 60000 });
  await page.waitForSelector(`${sel("mk")}[data-shown="disabled"]`, { timeout: LONG });
  await page.waitForFunction((s) => /disabled: nozzle swap/i.test(document.querySelector(s + " .msg").textContent), sel("mk"), { timeout: LONG });
  const edge = await page.locator(sel("mk")).evaluate((e) => getComputedStyle(e).borderLeftColor);
  check(edge === "rgb(175, 184, 193)", "the disabled card's edge is not grey: " + edge);
  const off = await printer("mk");
  check(!off.enabled && off.disabled_reason === "nozzle swap", "the API's mk: " + JSON.stringify(off));
  await page.screenshot({ path: `${SHOTS}/disabled.png` });

  log("enabled from its card: it connects again");
  await page.getByRole("button", { name: "Enable mk" }).click();
  await page.waitForSelector(`${sel("mk")}[data-shown="idle"]`, { timeout: LONG });
  check((await printer("mk")).disabled_reason === null, "still disabled in the API");

  log("removed: it asks first, saying what it does; the card goes");
  await page.getByRole("button", { name: "Manage mk" }).click();
  await page.locator("#pf").waitFor({ state: "visible", timeout: 60000 });
  const text = await confirmed(page, page.locator("#pf-remove"), "Remove mk");
  check(/removes mk from the farm/.test(text), "the remove dialog: " + text);
  await page.waitForSelector(sel("mk"), { state: "detached", timeout: LONG });
  check((await printer("mk")) === null, "mk still in the API");
  check(problems.length === 0, problems.join("; "));
  log("ok");
}
