// slimfarm dashboard: printers managed at run time (README "Printers
// managed at run time"): the Add printer form, and each card's Manage
// dialog (edit, disable with a reason, enable, remove).  Loaded after
// app.js, whose helpers ($, el, api, act, ask, st, scheduleRefresh) it
// uses.
//
// The form is built from GET /api/printer-kinds: a select of the driver
// kinds, each kind's own fields (its link options, with their types,
// ranges and defaults), then the options every printer takes.  Only what
// the operator filled in is sent: the daemon checks it with farm.ini's own
// rules, and its refusal, naming the field, is shown in the form with that
// field marked.  Removing asks first, as every destructive action does;
// disabling asks, in the same dialog, for the reason the card will show.
"use strict";

const pm = {
  kinds: null, // GET /api/printer-kinds
  editing: "", // the printer the dialog edits; "" when it adds one
  loaded: {}, // the edited printer's options as the daemon gave them
};
// options shown before "More options"
const PM_FRONT = ["material", "nozzle_mm", "bed_size", "auto_eject"];

async function pmKinds() {
  if (!pm.kinds) pm.kinds = await api("/api/printer-kinds");
  return pm.kinds;
}

// One option's input, labelled; bool options are a checkbox.
function pmField(o, value, secret) {
  const id = "pf-" + o.name;
  const isBool = o.type === "bool" || o.default === "true" || o.default === "false";
  const attrs = { id, name: o.name, "data-opt": o.name, "data-def": String(o.default) };
  let input;
  if (isBool) {
    input = el("input", Object.assign(attrs, { type: "checkbox", class: "check" }));
    input.checked = String(value !== undefined ? value : o.default) === "true";
  } else {
    const num = o.type === "int";
    input = el("input", Object.assign(attrs, {
      type: secret ? "password" : num ? "number" : "text",
      min: num ? o.min : null, max: num ? o.max : null, required: o.required || null,
      autocomplete: secret ? "new-password" : "off",
      placeholder: secret && pm.editing ? "(unchanged)" : o.default !== undefined ? String(o.default) : "",
    }));
    if (value !== undefined && !secret) input.value = value;
  }
  const label = el("label", { for: id, text: o.name.replace(/_/g, " ") + (o.required ? " (required)" : "") });
  return el("div", { class: isBool ? "field check-row" : "field" }, label, input);
}

// The selected kind's fields, and the common ones (values: the edited printer's).
function pmRenderFields() {
  const k = pm.kinds.kinds.find((x) => x.name === $("#pf-kind").value);
  const box = $("#pf-fields"), more = $("#pf-more");
  box.textContent = "";
  more.textContent = "";
  const secrets = pm.loaded.secrets || [];
  for (const o of k ? k.options : []) box.append(pmField(o, (pm.loaded.options || {})[o.name], o.secret));
  for (const o of pm.kinds.options) {
    const f = pmField(o, (pm.loaded.options || {})[o.name], false);
    (PM_FRONT.includes(o.name) ? box : more).append(f);
  }
  if (secrets.length) box.append(el("p", { class: "muted", text: `Set and not shown: ${secrets.join(", ")}.` }));
}

// The form's fields to send: when adding, what differs from the defaults;
// when editing, what differs from what was loaded (a secret only when
// typed; a field emptied goes back to its default: null).
function pmBody() {
  const body = {};
  const opts = pm.loaded.options || {};
  for (const i of document.querySelectorAll("#pf-form [data-opt]")) {
    const box = i.type === "checkbox";
    const v = box ? String(i.checked) : i.value.trim();
    const was = pm.editing && opts[i.name] !== undefined ? opts[i.name] : box ? i.dataset.def : "";
    if (i.type === "password" ? v !== "" : v !== was) body[i.name] = v === "" ? null : v;
  }
  const kind = $("#pf-kind").value;
  if (!pm.editing || kind !== opts.driver) body.driver = kind;
  if (!pm.editing) body.name = $("#pf-name").value.trim();
  return body;
}

function pmError(msg) {
  $("#pf-error").textContent = msg;
  for (const i of document.querySelectorAll("#pf-form [aria-invalid]")) i.removeAttribute("aria-invalid");
  // the daemon names the field: "option 'nozzle_mm' ..." or "field 'name' ..."
  const m = /(?:option|field) '([a-z_]+)'/.exec(msg || "");
  const bad = m && (m[1] === "name" ? $("#pf-name") : m[1] === "driver" ? $("#pf-kind") : $(`#pf-${m[1]}`));
  if (bad) {
    bad.setAttribute("aria-invalid", "true");
    bad.closest("details")?.setAttribute("open", "");
    bad.focus();
  }
}

// Open the dialog: add a printer (name ""), or manage printer name.
async function pmOpen(name) {
  pmError("");
  pm.editing = name;
  pm.loaded = {};
  try {
    await pmKinds();
    if (name) pm.loaded = (await api(`/api/printers/${encodeURIComponent(name)}/config`)).printer;
  } catch (e) {
    if (e.status !== 401) showError(e.message);
    return;
  }
  const kind = $("#pf-kind");
  kind.textContent = "";
  for (const k of pm.kinds.kinds) kind.append(el("option", { value: k.name, text: k.name }));
  kind.value = (pm.loaded.options || {}).driver || pm.kinds.kinds[0].name;
  $("#pf-name").value = name;
  $("#pf-name").readOnly = !!name;
  $("#pf-title").textContent = name ? `Printer ${name}` : "Add a printer";
  $("#pf-save").textContent = name ? "Save changes" : "Add printer";
  $("#pf-manage").hidden = !name;
  const off = !!pm.loaded.disabled_reason;
  $("#pf-state").textContent = name ? (off ? `Disabled: ${pm.loaded.disabled_reason}.` : "") +
    ` Its options come from ${pm.loaded.source === "api" ? "this dashboard (the API)" : "farm.ini"}.` : "";
  $("#pf-disable").hidden = off;
  $("#pf-enable").hidden = !off;
  $("#pf-more-box").open = false;
  pmRenderFields();
  $("#pf").showModal();
  (name ? $("#pf-kind") : $("#pf-name")).focus();
}

async function pmSave(e) {
  e.preventDefault();
  pmError("");
  const name = pm.editing;
  const btn = $("#pf-save");
  btn.disabled = true;
  try {
    const body = JSON.stringify(pmBody());
    await (name ? api(`/api/printers/${encodeURIComponent(name)}`, { method: "PATCH", body })
      : api("/api/printers", { method: "POST", body }));
    $("#pf").close();
    scheduleRefresh(0);
  } catch (err) {
    if (err.status !== 401) pmError(err.status ? err.message : "The farm did not answer: nothing was done.");
  } finally {
    btn.disabled = st.down;
  }
}

// Disable: the confirmation dialog says what it does and asks for the
// reason the card will show; its button waits for one.
async function pmDisable() {
  const name = pm.editing;
  $("#pf").close();
  const field = $("#confirm-field"), input = $("#confirm-input"), ok = $("#confirm-ok");
  const need = () => { ok.disabled = input.value.trim() === ""; };
  input.value = "";
  field.hidden = false;
  input.addEventListener("input", need);
  need();
  const go = act(() => api(`/api/printers/${encodeURIComponent(name)}/disable`,
    { method: "POST", body: JSON.stringify({ reason: input.value.trim() }) }));
  const yes = await ask(`Disable ${name}?`, `${name} takes no new job until it is enabled again, and the ` +
    "farm lets go of its connection. A printer that is printing cannot be disabled: let the print end " +
    "or cancel it first.", `Disable ${name}`);
  input.removeEventListener("input", need);
  field.hidden = true;
  ok.disabled = st.down;
  if (yes) await go();
}

function pmEnable(name) {
  return act(() => api(`/api/printers/${encodeURIComponent(name)}/enable`, { method: "POST" }));
}

async function pmRemove() {
  const name = pm.editing;
  $("#pf").close();
  const go = act(() => api(`/api/printers/${encodeURIComponent(name)}`, { method: "DELETE" }));
  if (await ask(`Remove ${name}?`, `This removes ${name} from the farm, for good: it is forgotten on restart ` +
    "too, even if farm.ini names it (add it again to bring it back). Its past prints stay in the history. " +
    "A printer that prints, or holds a part on its bed, cannot be removed.", `Remove ${name}`)) await go();
}

// A card's buttons (app.js makeCard): Manage, and Enable on a disabled printer.
function pmCardButtons(name) {
  return [
    el("button", { type: "button", "data-act": "manage", "aria-label": "Manage " + name,
      onclick: () => !st.down && pmOpen(name) }, "Manage"),
    el("button", { type: "button", "data-act": "enable", "aria-label": "Enable " + name,
      onclick: pmEnable(name) }, "Enable"),
  ];
}

// Which of them a card shows (app.js renderPrinters).
function pmCardShow(p) {
  return { manage: true, enable: !!p.disabled_reason };
}

document.addEventListener("DOMContentLoaded", () => {
  $("#add-printer").addEventListener("click", () => !st.down && pmOpen(""));
  $("#pf-kind").addEventListener("change", () => pmRenderFields());
  $("#pf-form").addEventListener("submit", pmSave);
  $("#pf-cancel").addEventListener("click", () => $("#pf").close());
  $("#pf-disable").addEventListener("click", pmDisable);
  $("#pf-enable").addEventListener("click", () => {
    $("#pf").close();
    pmEnable(pm.editing)();
  });
  $("#pf-remove").addEventListener("click", pmRemove);
});
