// eyekey operator console. Plain script, no dependencies: it builds the page from the REST API under /v1 with
// the operator token the user typed in. The token lives in this tab's sessionStorage and in memory, is sent
// only in the Authorization header, and never appears in a URL. Text from the API is always inserted as text
// (never as HTML).
"use strict";

const TOKEN_KEY = "eyekey.console.token";
const session = { token: null, me: null };

// ---------------------------------------------------------------- DOM helpers

function h(tag, attrs, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
    else if (k === "class") el.className = v;
    else if (v === true) el.setAttribute(k, "");
    else el.setAttribute(k, String(v));
  }
  for (const c of children.flat(Infinity)) {
    if (c === undefined || c === null || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

const svgNs = "http://www.w3.org/2000/svg";
function s(tag, attrs, ...children) {
  const el = document.createElementNS(svgNs, tag);
  for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, String(v));
  for (const c of children) el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return el;
}

/** Replaces an element's children, skipping null, undefined and false (replaceChildren would print them). */
function put(el, ...children) {
  el.replaceChildren(...children.flat(Infinity).filter((c) => c !== null && c !== undefined && c !== false));
}

let uid = 0;
/** A labelled input: returns [wrapper, input]. `field` names the API field errors point at. */
function field(labelText, input, hint) {
  const id = input.id || `f${++uid}`;
  input.id = id;
  const hintEl = hint ? h("p", { class: "hint", id: `${id}-hint` }, hint) : null;
  if (hintEl) input.setAttribute("aria-describedby", hintEl.id);
  return h("div", {}, h("label", { for: id }, labelText), input, hintEl);
}

function fmtTime(t) {
  if (!t) return "—";
  const d = new Date(t);
  return d.toLocaleString(undefined, { dateStyle: "medium", timeStyle: "medium" });
}

function fmt(x, digits = 2) {
  return typeof x === "number" && Number.isFinite(x) ? x.toFixed(digits) : "—";
}

/** A random UUID for Idempotency-Key (crypto.randomUUID needs a secure context; getRandomValues does not). */
function newKey() {
  if (crypto.randomUUID) return crypto.randomUUID();
  const b = crypto.getRandomValues(new Uint8Array(16));
  b[6] = (b[6] & 0x0f) | 0x40;
  b[8] = (b[8] & 0x3f) | 0x80;
  const x = [...b].map((v) => v.toString(16).padStart(2, "0")).join("");
  return `${x.slice(0, 8)}-${x.slice(8, 12)}-${x.slice(12, 16)}-${x.slice(16, 20)}-${x.slice(20)}`;
}

function short(id) {
  return String(id).slice(0, 8);
}

function stateBadge(state) {
  return h("span", { class: `state state-${state}` }, state);
}

// ---------------------------------------------------------------- API

class ApiError extends Error {
  constructor(status, code, message, field) {
    super(message);
    this.status = status;
    this.code = code;
    this.field = field;
  }
}

async function api(method, path, opts = {}) {
  const headers = { Authorization: `Bearer ${opts.token || session.token}` };
  let body;
  if (opts.json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(opts.json);
  } else if (opts.body !== undefined) {
    headers["Content-Type"] = opts.contentType;
    body = opts.body;
  }
  Object.assign(headers, opts.headers || {});
  let r;
  try {
    r = await fetch(path, { method, headers, body, cache: "no-store", signal: opts.signal });
  } catch (e) {
    if (e.name === "AbortError") throw e;
    throw new ApiError(0, "network", "the service could not be reached; nothing was changed by this attempt", null);
  }
  if (!r.ok) {
    let err = {};
    try {
      err = (await r.json()).error || {};
    } catch (_) {
      /* not JSON */
    }
    if (r.status === 401 && !opts.token) {
      signOut("The service no longer accepts this token. Sign in again.");
    }
    throw new ApiError(r.status, err.code || String(r.status), err.message || r.statusText, err.field || null);
  }
  if (opts.raw) return r;
  if (r.status === 204) return null;
  return r.json();
}

/** Object URLs of the decrypted images on the page, revoked when the page is left or the operator signs out. */
const imageUrls = new Set();

/** An image from an authorised URL, as an object URL (an <img src> cannot send the token). */
async function imageUrl(path) {
  const r = await api("GET", path, { raw: true });
  const url = URL.createObjectURL(await r.blob());
  imageUrls.add(url);
  return url;
}

function forgetImages() {
  for (const url of imageUrls) URL.revokeObjectURL(url);
  imageUrls.clear();
}

function authImage(path, alt) {
  const img = h("img", { alt, "data-state": "loading" });
  imageUrl(path)
    .then((url) => {
      img.addEventListener("load", () => img.setAttribute("data-state", "loaded"), { once: true });
      img.src = url;
    })
    .catch((e) => {
      img.setAttribute("data-state", "failed");
      img.replaceWith(h("p", { class: "error", role: "alert" }, `${alt}: ${e.message}`));
    });
  return img;
}

function has(scope) {
  const scopes = (session.me && session.me.scopes) || [];
  return scopes.includes("admin") || scopes.includes(scope);
}

// ---------------------------------------------------------------- forms

/** A form whose submit runs `action`; errors are shown in place, naming the field, and the inputs keep
 *  what was typed. `action` gets the form and returns a message to show (or nothing). */
function form(attrs, children, action) {
  const errorEl = h("p", { class: "error", role: "alert" });
  const noticeEl = h("p", { class: "notice", role: "status" });
  const f = h("form", Object.assign({ class: "card", novalidate: true }, attrs), children, errorEl, noticeEl);
  f.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    errorEl.textContent = "";
    noticeEl.textContent = "";
    for (const el of f.querySelectorAll("[aria-invalid]")) el.removeAttribute("aria-invalid");
    const buttons = f.querySelectorAll("button[type=submit]");
    buttons.forEach((b) => (b.disabled = true));
    try {
      const msg = await action(f);
      if (msg) noticeEl.textContent = msg;
    } catch (e) {
      showError(f, errorEl, e);
    } finally {
      buttons.forEach((b) => (b.disabled = false));
    }
  });
  return f;
}

function showError(f, errorEl, e) {
  const where = e.field ? `${e.field}: ` : "";
  errorEl.textContent = `${where}${e.message}`;
  if (!e.field) return;
  // The input the error names: the longest data-field that is a prefix of the error's field.
  let best = null;
  for (const el of f.querySelectorAll("[data-field]")) {
    const name = el.getAttribute("data-field");
    if ((e.field === name || e.field.startsWith(`${name}.`) || e.field.startsWith(`${name}[`)) &&
        (!best || name.length > best.getAttribute("data-field").length)) {
      best = el;
    }
  }
  if (best) {
    best.setAttribute("aria-invalid", "true");
    best.setAttribute("aria-errormessage", errorEl.id || (errorEl.id = `e${++uid}`));
    best.focus();
  }
}

class FormError extends Error {
  constructor(field, message) {
    super(message);
    this.field = field;
  }
}

function numberOrNull(input, name) {
  const v = input.value.trim();
  if (v === "") return null;
  const x = Number(v);
  if (!Number.isFinite(x)) throw new FormError(name, "must be a number");
  return x;
}

/** A delete button that asks once more in place (no dialog). */
function deleteButton(label, run) {
  const wrap = h("span", { class: "actions" });
  const ask = h("button", { type: "button", class: "secondary", "aria-label": `Delete ${label}` }, "Delete");
  ask.addEventListener("click", () => {
    const yes = h("button", { type: "button", class: "danger", "aria-label": `Confirm deleting ${label}` }, "Confirm delete");
    const no = h("button", { type: "button", class: "secondary" }, "Keep");
    const err = h("span", { class: "error", role: "alert" });
    yes.addEventListener("click", async () => {
      yes.disabled = true;
      try {
        await run();
      } catch (e) {
        err.textContent = e.message;
        yes.disabled = false;
      }
    });
    no.addEventListener("click", () => put(wrap, ask));
    put(wrap, yes, no, err);
    yes.focus();
  });
  wrap.append(ask);
  return wrap;
}

async function allPages(path, max = 5) {
  let items = [];
  let cursor = null;
  for (let i = 0; i < max; i++) {
    const sep = path.includes("?") ? "&" : "?";
    const page = await api("GET", `${path}${sep}limit=200${cursor ? `&cursor=${encodeURIComponent(cursor)}` : ""}`);
    items = items.concat(page.items);
    if (!page.next_cursor) break;
    cursor = page.next_cursor;
  }
  return items;
}

function needs(scope) {
  return h("p", { class: "hint" }, `This needs a token with the ${scope} scope (or admin).`);
}

function tokenPanel(title, token) {
  const input = h("input", { type: "text", readonly: true, value: token, "aria-label": "The new token" });
  const status = h("span", { role: "status" });
  const copy = h("button", { type: "button" }, "Copy");
  copy.addEventListener("click", async () => {
    try {
      await navigator.clipboard.writeText(token);
      status.textContent = "Copied.";
    } catch (_) {
      input.select();
      status.textContent = "Selected: press Ctrl+C to copy.";
    }
  });
  return h("section", { class: "card", "data-token-panel": true },
    h("h3", {}, title),
    h("p", {}, "Give this token to the display client now: it is shown only once and stored only as a hash."),
    h("div", { class: "token" }, input, copy, status));
}

// ---------------------------------------------------------------- pages

const main = () => document.getElementById("main");
let pageAbort = null;

/** Draws a page, unless the user has moved on since `signal`'s page began (then stops it with an AbortError). */
function render(signal, title, ...content) {
  stopIfLeft(signal);
  document.title = `${title} · eyekey console`;
  put(main(), h("h1", {}, title), ...content);
}

function stopIfLeft(signal) {
  if (signal.aborted) throw new DOMException("the page was left", "AbortError");
}

function signInPage(message) {
  const input = h("input", { type: "password", id: "token", name: "token", autocomplete: "off", "data-field": "token", spellcheck: "false" });
  const f = form({ id: "sign-in", "aria-labelledby": "sign-in-title" }, [
    field("Operator token", input, "The bootstrap token from the service's data directory (operator-token), or a scoped token made with POST /v1/tokens. It stays in this tab only."),
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Sign in")),
  ], async () => {
    const token = input.value.trim();
    if (!token) throw new FormError("token", "enter a token");
    let me;
    try {
      me = await api("GET", "/v1/me", { token });
    } catch (e) {
      if (e.status === 401) throw new FormError("token", "the service does not know this token");
      if (e.status === 403) throw new FormError("token", "this is a display's token; the console needs an operator token");
      throw e;
    }
    session.token = token;
    session.me = me;
    sessionStorage.setItem(TOKEN_KEY, token);
    const target = location.pathname.startsWith("/console/") && !location.pathname.endsWith("/sign-in") ? location.pathname : "/console/jobs";
    navigate(target, true);
  });
  document.title = "Sign in · eyekey console";
  put(main(), 
    h("h1", { id: "sign-in-title" }, "Sign in"),
    message ? h("p", { class: "notice", role: "status" }, message) : null,
    f,
  );
  updateChrome();
  input.focus();
}

// ----- profiles

async function profilesPage() {
  const signal = pageAbort.signal;
  if (!has("enrol")) return render(signal, "Profiles", needs("enrol"));
  const list = h("div", {}, h("p", {}, "Loading…"));
  render(signal, "Profiles", h("section", {}, h("h2", {}, "Enrolled people"), list), enrolFromFile(reload), enrolForm(reload));
  async function reload() {
    const items = await allPages("/v1/profiles", 5);
    put(list, items.length === 0 ? h("p", {}, "Nobody is enrolled yet.") : h("table", { id: "profiles" },
      h("thead", {}, h("tr", {}, h("th", {}, "Label"), h("th", {}, "Id"), h("th", { class: "num" }, "Version"), h("th", {}, "Updated"), h("th", {}, "Actions"))),
      h("tbody", {}, items.map((p) => profileRow(p, reload)))));
  }
  await reload();
}

function profileRow(p, reload) {
  const detail = h("td", { colspan: 5 });
  const detailRow = h("tr", { hidden: true }, detail);
  const view = h("button", { type: "button", class: "secondary", "aria-expanded": "false" }, "Versions");
  view.addEventListener("click", async () => {
    const open = detailRow.hidden;
    detailRow.hidden = !open;
    view.setAttribute("aria-expanded", String(open));
    if (open) await showVersion(p.version);
  });
  async function showVersion(v) {
    const select = h("select", {}, Array.from({ length: p.version }, (_, i) => h("option", { value: i + 1, selected: i + 1 === v }, `version ${i + 1}`)));
    select.addEventListener("change", () => showVersion(Number(select.value)));
    const d = await api("GET", `/v1/profiles/${p.id}?version=${v}`);
    put(detail, field("Version", select), h("pre", {}, JSON.stringify(d.profile, null, 2)), reenrolForm());
  }
  function reenrolForm() {
    const file = h("input", { type: "file", accept: "application/json,.json", "data-field": "profile" });
    return form({ "aria-label": `Re-enrol ${p.label || short(p.id)}` }, [
      h("h3", {}, "Re-enrol (a new version; jobs keep the version they used)"),
      field("New profile file", file),
      h("div", { class: "actions" }, h("button", { type: "submit" }, "Re-enrol")),
    ], async () => {
      const r = await api("PUT", `/v1/profiles/${p.id}`, { json: await profileBody(file) });
      await reload();
      return `Version ${r.version} enrolled.`;
    });
  }
  return [h("tr", {},
    h("td", {}, p.label || h("em", {}, "no label")),
    h("td", { class: "mono" }, p.id),
    h("td", { class: "num" }, p.version),
    h("td", {}, fmtTime(p.updated_at)),
    h("td", {}, h("div", { class: "actions" }, view, deleteButton(`profile ${p.label || short(p.id)}`, async () => {
      await api("DELETE", `/v1/profiles/${p.id}`);
      await reload();
    })))), detailRow];
}

/** An enrolment body from a chosen JSON file: a vision profile, or a whole body {"label", "profile"}. */
async function profileBody(file) {
  if (!file.files.length) throw new FormError("profile", "choose a file");
  let parsed;
  try {
    parsed = JSON.parse(await file.files[0].text());
  } catch (e) {
    throw new FormError("profile", `the file is not JSON (${e.message})`);
  }
  return parsed && parsed.profile ? parsed : { profile: parsed };
}

function enrolFromFile(reload) {
  const label = h("input", { type: "text", "data-field": "label", maxlength: 200 });
  const file = h("input", { type: "file", accept: "application/json,.json", "data-field": "profile" });
  return form({ id: "enrol-file", "aria-label": "Enrol from a JSON file" }, [
    h("h2", {}, "Enrol from a JSON file"),
    h("p", { class: "hint" }, "A vision profile as eyekey example profile writes it, or a body {\"label\", \"profile\"}."),
    h("div", { class: "row" }, field("Label", label), field("Profile file", file)),
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Enrol")),
  ], async () => {
    const body = await profileBody(file);
    if (label.value.trim()) body.label = label.value.trim();
    const p = await api("POST", "/v1/profiles", { json: body });
    await reload();
    return `Enrolled ${p.label || p.id}.`;
  });
}

function enrolForm(reload) {
  const num = (attrs) => h("input", Object.assign({ type: "number", step: "any" }, attrs));
  const label = h("input", { type: "text", "data-field": "label", maxlength: 200 });
  const pupil = num({ value: "6", min: 2, max: 9, "data-field": "profile.pupil_diameter_mm" });
  const zPupil = num({ min: 2, max: 10, "data-field": "profile.zernike_pupil_diameter_mm" });
  const refWl = num({ min: 400, max: 1000, "data-field": "profile.reference_wavelength_nm" });
  const sphere = num({ min: -20, max: 20, "data-field": "profile.prescription.sphere_d" });
  const cyl = num({ min: -10, max: 10, "data-field": "profile.prescription.cylinder_d" });
  const axis = num({ min: 0, max: 180, "data-field": "profile.prescription.axis_deg" });
  const age = num({ value: "32", min: 10, max: 90, "data-field": "profile.spectral" });
  const fieldDeg = num({ value: "2", min: 1, max: 10, "data-field": "profile.spectral" });
  const shifts = ["l", "m", "s"].map((c) => num({ value: "0", "data-field": "profile.spectral" }));
  const terms = h("tbody", {});
  function addTerm(j = "", c = "") {
    const jIn = num({ min: 0, max: 65, step: 1, value: j, "data-field": "profile.zernike_um" });
    const cIn = num({ min: -20, max: 20, value: c, "data-field": "profile.zernike_um" });
    jIn.setAttribute("aria-label", "Zernike index j (OSA/ANSI)");
    cIn.setAttribute("aria-label", "Coefficient, µm");
    const rm = h("button", { type: "button", class: "secondary", "aria-label": "Remove this term" }, "Remove");
    const tr = h("tr", {}, h("td", {}, jIn), h("td", {}, cIn), h("td", {}, rm));
    rm.addEventListener("click", () => tr.remove());
    terms.append(tr);
  }
  addTerm(4, -0.8);
  addTerm(12, 0.05);
  const add = h("button", { type: "button", class: "secondary" }, "Add a term");
  add.addEventListener("click", () => addTerm());
  return form({ id: "enrol-form", "aria-label": "Enrol from a form" }, [
    h("h2", {}, "Enrol from a form"),
    h("div", { class: "row" }, field("Label", label), field("Pupil diameter while viewing, mm", pupil),
      field("Pupil the coefficients were measured at, mm", zPupil, "Blank: the same pupil."),
      field("Wavelength of the measurement, nm", refWl, "Blank: 555 nm.")),
    h("fieldset", {}, h("legend", {}, "Zernike coefficients (OSA/ANSI index j, µm)"),
      h("table", { class: "terms" }, h("thead", {}, h("tr", {}, h("th", {}, "j"), h("th", {}, "µm"), h("th", {}, ""))), terms), add),
    h("fieldset", {}, h("legend", {}, "Prescription (optional; blank for none)"),
      h("div", { class: "row" }, field("Sphere, D", sphere), field("Cylinder, D", cyl), field("Axis, °", axis))),
    h("fieldset", {}, h("legend", {}, "Cone sensitivities (CIE 2006 with Asano's deviations)"),
      h("div", { class: "row" }, field("Age, years", age), field("Field size, °", fieldDeg),
        field("L peak shift, nm", shifts[0]), field("M peak shift, nm", shifts[1]), field("S peak shift, nm", shifts[2]))),
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Enrol")),
  ], async () => {
    const zernike = [];
    for (const tr of terms.querySelectorAll("tr")) {
      const [jIn, cIn] = tr.querySelectorAll("input");
      if (jIn.value === "" && cIn.value === "") continue;
      const j = numberOrNull(jIn, "profile.zernike_um");
      const c = numberOrNull(cIn, "profile.zernike_um");
      if (j === null || c === null || !Number.isInteger(j) || j < 0 || j > 65) {
        throw new FormError("profile.zernike_um", "each term needs an integer index j in 0..65 and a coefficient");
      }
      while (zernike.length <= j) zernike.push(0);
      zernike[j] = c;
    }
    const profile = {
      pupil_diameter_mm: numberOrNull(pupil, "profile.pupil_diameter_mm"),
      zernike_um: zernike,
      spectral: {
        kind: "parameters",
        age_years: numberOrNull(age, "profile.spectral"),
        field_size_deg: numberOrNull(fieldDeg, "profile.spectral"),
        shift_l_nm: numberOrNull(shifts[0], "profile.spectral"),
        shift_m_nm: numberOrNull(shifts[1], "profile.spectral"),
        shift_s_nm: numberOrNull(shifts[2], "profile.spectral"),
      },
    };
    const zp = numberOrNull(zPupil, "profile.zernike_pupil_diameter_mm");
    if (zp !== null) profile.zernike_pupil_diameter_mm = zp;
    const rw = numberOrNull(refWl, "profile.reference_wavelength_nm");
    if (rw !== null) profile.reference_wavelength_nm = rw;
    const rx = [sphere, cyl, axis].map((el, i) => numberOrNull(el, ["profile.prescription.sphere_d", "profile.prescription.cylinder_d", "profile.prescription.axis_deg"][i]));
    if (rx.some((v) => v !== null)) profile.prescription = { sphere_d: rx[0] || 0, cylinder_d: rx[1] || 0, axis_deg: rx[2] || 0 };
    for (const k of Object.keys(profile.spectral)) if (profile.spectral[k] === null) delete profile.spectral[k];
    const body = { profile };
    if (label.value.trim()) body.label = label.value.trim();
    const p = await api("POST", "/v1/profiles", { json: body });
    await reload();
    return `Enrolled ${p.label || p.id}.`;
  });
}

// ----- displays

async function displaysPage() {
  const signal = pageAbort.signal;
  if (!has("submit") && !has("read-evaluation")) return render(signal, "Displays", needs("submit or read-evaluation"));
  const list = h("div", {}, h("p", {}, "Loading…"));
  const shown = h("div", { id: "display-token" });
  render(signal, "Displays", shown, h("section", {}, h("h2", {}, "Registered displays"), list), has("admin") ? registerForm(reload, shown) : needs("admin"));
  async function reload() {
    const items = await allPages("/v1/displays", 5);
    put(list, items.length === 0 ? h("p", {}, "No display is registered yet.") : h("table", { id: "displays" },
      h("thead", {}, h("tr", {}, h("th", {}, "Name"), h("th", {}, "Frames"), h("th", {}, "Views told apart"), h("th", {}, "Registered"), h("th", {}, "Actions"))),
      h("tbody", {}, items.map((d) => displayRow(d, reload, shown)))));
  }
  await reload();
}

function worstBand(d) {
  const bands = d.resolvability.bands;
  return bands.reduce((a, b) => (b.resolvability < a.resolvability ? b : a), bands[0]);
}

function resolvabilityTable(d) {
  return h("table", { class: "resolvability" },
    h("caption", {}, "Resolvability per band: M ≥ 1 means diffraction lets the views be told apart at the pupil."),
    h("thead", {}, h("tr", {}, h("th", { class: "num" }, "Band, nm"), h("th", { class: "num" }, "View spacing, mm"), h("th", { class: "num" }, "Spread of one view, mm"), h("th", { class: "num" }, "M"), h("th", { class: "num" }, "Views a 4 mm pupil separates"), h("th", { class: "num" }, "6 mm pupil"))),
    h("tbody", {}, d.resolvability.bands.map((b) => h("tr", {},
      h("td", { class: "num" }, fmt(b.wavelength_nm, 0)), h("td", { class: "num" }, fmt(b.view_spacing_mm, 3)), h("td", { class: "num" }, fmt(b.view_spread_mm, 3)),
      h("td", { class: "num" }, `${fmt(b.resolvability, 2)} ${b.resolvability >= 1 ? "(resolved)" : "(not resolved)"}`),
      h("td", { class: "num" }, b.views_resolved["4mm"]), h("td", { class: "num" }, b.views_resolved["6mm"])))));
}

function displayRow(d, reload, shown) {
  const worst = worstBand(d);
  const detailRow = h("tr", { hidden: true }, h("td", { colspan: 5 }, resolvabilityTable(d), d.warnings.map((w) => h("p", { class: "hint" }, w))));
  const more = h("button", { type: "button", class: "secondary", "aria-expanded": "false" }, "Figures");
  more.addEventListener("click", () => {
    detailRow.hidden = !detailRow.hidden;
    more.setAttribute("aria-expanded", String(!detailRow.hidden));
  });
  const actions = [more];
  if (has("admin")) {
    const rotate = h("button", { type: "button", class: "secondary", "aria-label": `Rotate the token of ${d.name}` }, "Rotate token");
    rotate.addEventListener("click", async () => {
      rotate.disabled = true;
      try {
        const r = await api("POST", `/v1/displays/${d.id}/token`);
        put(shown, tokenPanel(`New token for ${d.name}`, r.token));
      } catch (e) {
        put(shown, h("p", { class: "error", role: "alert" }, e.message));
      } finally {
        rotate.disabled = false;
      }
    });
    actions.push(rotate, deleteButton(`display ${d.name}`, async () => {
      await api("DELETE", `/v1/displays/${d.id}`);
      await reload();
    }));
  }
  return [h("tr", {},
    h("td", {}, d.name, h("div", { class: "hint mono" }, d.id)),
    h("td", {}, `${d.frame_width}×${d.frame_height} px, ${d.bands} projectors`),
    h("td", {}, `worst band ${fmt(worst.wavelength_nm, 0)} nm: M = ${fmt(worst.resolvability)} ${worst.resolvability >= 1 ? "(resolved)" : "(not resolved)"}`),
    h("td", {}, fmtTime(d.created_at)),
    h("td", {}, h("div", { class: "actions" }, actions))), detailRow];
}

function registerForm(reload, shown) {
  const name = h("input", { type: "text", "data-field": "name", maxlength: 200 });
  const preset = h("select", { "data-field": "preset" },
    ["small", "lenslet", "pinhole", "secure", "paper", "dense"].map((p) => h("option", { value: p }, p)));
  const geometry = h("textarea", { "data-field": "geometry", placeholder: "{ \"holes_x\": 24, ... } as eyekey example display writes it" });
  const byPreset = h("input", { type: "radio", name: "source", value: "preset", checked: true });
  const byJson = h("input", { type: "radio", name: "source", value: "geometry" });
  return form({ id: "register-display", "aria-label": "Register a display" }, [
    h("h2", {}, "Register a display"),
    h("div", { class: "row" }, field("Name", name)),
    h("fieldset", {}, h("legend", {}, "Design"),
      h("label", { class: "inline" }, byPreset, "A built-in preset"),
      h("label", { class: "inline" }, byJson, "A geometry (JSON)"),
      field("Preset", preset), field("Geometry", geometry)),
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Register")),
  ], async () => {
    const body = { name: name.value };
    if (byPreset.checked) body.preset = preset.value;
    else {
      try {
        body.geometry = JSON.parse(geometry.value);
      } catch (e) {
        throw new FormError("geometry", `not JSON (${e.message})`);
      }
    }
    const r = await api("POST", "/v1/displays", { json: body });
    put(shown, tokenPanel(`Token for ${r.display.name}`, r.token), resolvabilityTable(r.display),
      r.display.warnings.map((w) => h("p", { class: "hint" }, w)));
    await reload();
    return `Registered ${r.display.name}.`;
  });
}

// ----- documents

async function documentsPage() {
  const signal = pageAbort.signal;
  if (!has("submit")) return render(signal, "Documents", needs("submit"));
  const list = h("div", {}, h("p", {}, "Loading…"));
  render(signal, "Documents", uploadForm(reload), renderForm(reload), h("section", {}, h("h2", {}, "Documents"), list));
  async function reload() {
    const items = await allPages("/v1/documents", 5);
    put(list, items.length === 0 ? h("p", {}, "No document yet.") : h("table", { id: "documents" },
      h("thead", {}, h("tr", {}, h("th", {}, "Id"), h("th", {}, "Image"), h("th", {}, "Stored"), h("th", {}, "Actions"))),
      h("tbody", {}, items.map((d) => documentRow(d, reload)))));
  }
  await reload();
}

function documentRow(d, reload) {
  const cell = h("td", {}, `${d.width}×${d.height} ${d.content_type}, ${d.bytes} bytes`);
  const show = h("button", { type: "button", class: "secondary" }, "Show");
  show.addEventListener("click", () => {
    show.remove();
    cell.append(h("div", {}, authImage(`/v1/documents/${d.id}/image`, `Document ${short(d.id)}`)));
    cell.lastChild.firstChild.classList.add("preview");
  });
  return h("tr", {}, h("td", { class: "mono" }, d.id), cell, h("td", {}, fmtTime(d.created_at)),
    h("td", {}, h("div", { class: "actions" }, show, deleteButton(`document ${short(d.id)}`, async () => {
      await api("DELETE", `/v1/documents/${d.id}`);
      await reload();
    }))));
}

function uploadForm(reload) {
  const file = h("input", { type: "file", accept: "image/png,image/jpeg", "data-field": "body" });
  const preview = h("div", {});
  file.addEventListener("change", () => {
    put(preview, );
    if (file.files.length) {
      const url = URL.createObjectURL(file.files[0]);
      imageUrls.add(url);
      preview.append(h("img", { class: "preview", alt: "Preview of the chosen image", src: url }));
    }
  });
  return form({ id: "upload-document", "aria-label": "Upload a document" }, [
    h("h2", {}, "Upload a document"),
    field("PNG or JPEG image", file), preview,
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Upload")),
  ], async () => {
    if (!file.files.length) throw new FormError("body", "choose an image");
    const f = file.files[0];
    const d = await api("POST", "/v1/documents", { body: f, contentType: f.type || "application/octet-stream" });
    await reload();
    return `Stored document ${d.id}.`;
  });
}

function renderForm(reload) {
  const lines = h("textarea", { "data-field": "lines", rows: 3 });
  lines.value = "PIN\n4821";
  const num = (v, f, min, max) => h("input", { type: "number", value: v, min, max, step: 1, "data-field": f });
  const width = num(192, "width", 8, 4096);
  const height = num(192, "height", 8, 4096);
  const scale = num(6, "scale", 1, 64);
  const preview = h("div", {});
  return form({ id: "render-document", "aria-label": "Render a document from text" }, [
    h("h2", {}, "Render a PIN slip or text"),
    h("p", { class: "hint" }, "Drawn in eyekey's 5×7 font, black on white: the font the known-font attacker knows."),
    field("Lines (one per row: digits, letters, space and : - . , #)", lines),
    h("div", { class: "row" }, field("Width, px", width), field("Height, px", height), field("Pixels per font dot", scale)),
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Render and store")), preview,
  ], async () => {
    const body = {
      lines: lines.value.split("\n").map((l) => l.replace(/\r$/, "")).filter((l, i, all) => l !== "" || i < all.length - 1),
      width: Number(width.value),
      height: Number(height.value),
      scale: Number(scale.value),
    };
    const d = await api("POST", "/v1/documents/text", { json: body });
    put(preview, authImage(`/v1/documents/${d.id}/image`, "The rendered document"));
    preview.firstChild.classList.add("preview");
    await reload();
    return `Stored document ${d.id}.`;
  });
}

// ----- jobs

const TERMINAL = ["succeeded", "failed", "cancelled"];

async function jobsPage() {
  const signal = pageAbort.signal;
  if (!has("submit") && !has("read-evaluation")) return render(signal, "Jobs", needs("submit or read-evaluation"));
  const list = h("div", {}, h("p", {}, "Loading…"));
  render(signal, "Jobs", has("submit") ? await jobForm() : null, h("section", {}, h("h2", {}, "Jobs"), list));
  async function reload() {
    const page = await api("GET", "/v1/jobs?limit=50");
    put(list, page.items.length === 0 ? h("p", {}, "No job yet.") : h("table", { id: "jobs" },
      h("thead", {}, h("tr", {}, h("th", {}, "Job"), h("th", {}, "State"), h("th", {}, "Progress"), h("th", {}, "Method"), h("th", {}, "Created"), h("th", {}, "Actions"))),
      h("tbody", {}, page.items.map((j) => h("tr", {},
        h("td", {}, h("a", { href: `/console/jobs/${j.id}`, class: "mono" }, short(j.id))),
        h("td", {}, stateBadge(j.state)),
        h("td", {}, progressBar(j)),
        h("td", {}, j.method),
        h("td", {}, fmtTime(j.timings.created_at)),
        h("td", {}, TERMINAL.includes(j.state) || !has("submit") ? "" : cancelButton(j, reload)))))));
    return page.items.some((j) => !TERMINAL.includes(j.state));
  }
  // Refresh while something is queued or running.
  while (!signal.aborted) {
    let active = false;
    try {
      active = await reload();
    } catch (e) {
      put(list, h("p", { class: "error", role: "alert" }, e.message));
    }
    await sleep(active ? 2000 : 10000, signal);
  }
}

function sleep(ms, signal) {
  return new Promise((resolve) => {
    const t = setTimeout(resolve, ms);
    signal && signal.addEventListener("abort", () => { clearTimeout(t); resolve(); }, { once: true });
  });
}

function progressBar(j) {
  const pct = Math.round((j.progress || 0) * 100);
  return h("span", {}, h("progress", { max: 100, value: pct, "aria-label": `Progress of job ${short(j.id)}` }), ` ${pct} %`);
}

function cancelButton(j, reload) {
  const b = h("button", { type: "button", class: "secondary", "aria-label": `Cancel job ${short(j.id)}` }, "Cancel");
  b.addEventListener("click", async () => {
    b.disabled = true;
    try {
      await api("POST", `/v1/jobs/${j.id}/cancel`);
      await reload();
    } catch (e) {
      b.replaceWith(h("span", { class: "error", role: "alert" }, e.message));
    }
  });
  return b;
}

async function jobForm() {
  const [profiles, displays, documents] = await Promise.all([
    has("enrol") ? allPages("/v1/profiles", 5) : Promise.resolve(null),
    allPages("/v1/displays", 5),
    allPages("/v1/documents", 5),
  ]);
  const choose = (items, fieldName, labelOf, optional) => h("select", { "data-field": fieldName },
    optional ? h("option", { value: "" }, "none") : null,
    items.map((x) => h("option", { value: x.id }, labelOf(x))));
  const profile = profiles ? choose(profiles, "profile_id", (p) => `${p.label || "no label"} (${short(p.id)})`)
    : h("input", { type: "text", "data-field": "profile_id", placeholder: "profile id" });
  const display = choose(displays, "display_id", (d) => `${d.name} (${short(d.id)})`);
  const docLabel = (d) => `${short(d.id)}: ${d.width}×${d.height}`;
  const documentSel = choose(documents, "document_id", docLabel);
  const decoy = choose(documents, "decoy_document_id", docLabel, true);
  const observers = h("fieldset", { "data-field": "observer_profile_ids" }, h("legend", {}, "People who must not read it (observers)"),
    profiles && profiles.length ? profiles.map((p) => h("label", { class: "inline" }, h("input", { type: "checkbox", value: p.id }), `${p.label || "no label"} (${short(p.id)})`))
      : h("p", { class: "hint" }, profiles ? "Enrol more people to name observers." : "Listing profiles needs the enrol scope."));
  const method = h("select", { "data-field": "options.method" },
    [["multiplex", "multiplex (paper Eq. 14)"], ["diffmax", "difference maximisation (Eq. 16)"], ["combined", "combined"]].map(([v, t]) => h("option", { value: v }, t)));
  const security = h("select", { "data-field": "options.security" },
    [["standard", "standard: the target reads while its focus and pupil drift"],
      ["strict", "strict: fewest people read; the target must hold its focus"]].map(([v, t]) => h("option", { value: v }, t)));
  const options = h("textarea", { "data-field": "options", rows: 4, placeholder: "{\"max_iterations\": 200, \"evaluation_population\": 100}" });
  let key = newKey();
  return form({ id: "create-job", "aria-label": "Create a job" }, [
    h("h2", {}, "Create a job"),
    h("div", { class: "row" }, field("Who must read it", profile), field("Display", display), field("Document", documentSel),
      field("Decoy shown to everybody else", decoy), field("Method", method), field("Security", security)),
    observers,
    field("Other encoder options (JSON, optional)", options, "Every option has a default; see EncodeOptions in the API documentation."),
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Create job")),
  ], async () => {
    let opts = {};
    if (options.value.trim()) {
      try {
        opts = JSON.parse(options.value);
      } catch (e) {
        throw new FormError("options", `not JSON (${e.message})`);
      }
      if (typeof opts !== "object" || Array.isArray(opts) || opts === null) throw new FormError("options", "must be a JSON object");
    }
    opts.method = method.value;
    if (!("security" in opts)) opts.security = security.value;
    const body = {
      profile_id: profile.value.trim(),
      display_id: display.value,
      document_id: documentSel.value,
      observer_profile_ids: Array.from(observers.querySelectorAll("input:checked")).map((c) => c.value),
      options: opts,
    };
    if (decoy.value) body.decoy_document_id = decoy.value;
    if (!body.display_id) throw new FormError("display_id", "register a display first");
    if (!body.document_id) throw new FormError("document_id", "upload or render a document first");
    if (!body.profile_id) throw new FormError("profile_id", "enrol the person first");
    const j = await api("POST", "/v1/jobs", { json: body, headers: { "Idempotency-Key": key } });
    key = newKey();
    navigate(`/console/jobs/${j.id}`);
  });
}

async function jobPage(id) {
  const signal = pageAbort.signal;
  if (!has("submit") && !has("read-evaluation")) return render(signal, "Job", needs("submit or read-evaluation"));
  const status = h("section", { class: "card", id: "job-status", "aria-live": "polite" }, "Loading…");
  const results = h("div", { id: "job-results" });
  const audit = h("section", { id: "job-audit" });
  render(signal, `Job ${short(id)}`, status, results, audit);
  const labels = await profileLabels();
  const who = (profileId, version) => `${labels[profileId] ? `${labels[profileId]}: ` : ""}${profileId} (version ${version})`;
  let job = await api("GET", `/v1/jobs/${id}`);
  showStatus(job);
  if (!TERMINAL.includes(job.state)) job = await follow(id, signal, showStatus);
  if (signal.aborted) return;
  showStatus(job);
  if (job.state === "succeeded") {
    if (has("read-evaluation")) await showEvaluation(job, results, labels);
    else put(results, needs("read-evaluation"));
  }
  if (has("admin")) await showAudit(id, audit);

  function showStatus(j) {
    job = j;
    const pct = Math.round((j.progress || 0) * 100);
    put(status, ...[
      h("dl", { class: "facts" },
        h("dt", {}, "State"), h("dd", { id: "job-state" }, stateBadge(j.state), j.cancel_requested && !TERMINAL.includes(j.state) ? " (cancelling)" : ""),
        h("dt", {}, "Progress"), h("dd", {}, h("progress", { max: 100, value: pct, "aria-label": "Progress" }), ` ${pct} %`),
        h("dt", {}, "Attempts"), h("dd", {}, `${j.attempts} of ${j.max_attempts}`),
        h("dt", {}, "Method"), h("dd", {}, j.method),
        h("dt", {}, "Target"), h("dd", {}, who(j.profile_id, j.profile_version)),
        h("dt", {}, "Observers"), h("dd", {}, j.observers.length ? j.observers.map((o) => who(o.profile_id, o.version)).join("; ") : "none"),
        h("dt", {}, "Display"), h("dd", { class: "mono" }, j.display_id),
        h("dt", {}, "Document"), h("dd", { class: "mono" }, j.document_id),
        h("dt", {}, "Security"), h("dd", { id: "job-security" }, (j.options && j.options.security) || "standard"),
        h("dt", {}, "Target judged by"), h("dd", { id: "job-judge" }, j.options && j.options.document_text
          ? "the known-font attacker (the document's text is known): every secret character read right"
          : "legibility (no text hint): the target must reach the level at which a reader almost surely reads"),
        h("dt", {}, "Created"), h("dd", {}, fmtTime(j.timings.created_at)),
        h("dt", {}, "Finished"), h("dd", {}, fmtTime(j.timings.finished_at)),
        j.timings.solve_seconds ? [h("dt", {}, "Solve"), h("dd", {}, `${fmt(j.timings.solve_seconds, 1)} s`)] : null,
        j.last_error ? [h("dt", {}, j.error_code === "target_cannot_read" ? "Failed: the target cannot read" : "Last error"),
          h("dd", { class: "error", id: "job-error" }, j.last_error)] : null),
      !TERMINAL.includes(j.state) && has("submit") ? h("div", { class: "actions" }, cancelButton(j, async () => {})) : null,
    ]);
  }
}

/** Follows a job's server-sent events until it ends (read with fetch, which can send the token; EventSource
 *  cannot). Falls back to polling if the stream breaks. */
async function follow(id, signal, onUpdate) {
  let last = null;
  try {
    const r = await api("GET", `/v1/jobs/${id}/events`, { raw: true, signal, headers: { Accept: "text/event-stream" } });
    const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
    let buffer = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buffer += value;
      let cut;
      while ((cut = buffer.indexOf("\n\n")) >= 0) {
        const block = buffer.slice(0, cut);
        buffer = buffer.slice(cut + 2);
        const data = block.split("\n").filter((l) => l.startsWith("data:")).map((l) => l.slice(5).trimStart()).join("\n");
        if (!data) continue;
        last = JSON.parse(data);
        onUpdate(last);
        if (TERMINAL.includes(last.state)) {
          reader.cancel().catch(() => {});
          return last;
        }
      }
    }
  } catch (e) {
    if (signal.aborted) return last;
  }
  for (;;) {
    if (signal.aborted) return last;
    last = await api("GET", `/v1/jobs/${id}`);
    onUpdate(last);
    if (TERMINAL.includes(last.state)) return last;
    await sleep(2000, signal);
  }
}

/** Whether a viewer reads the document, worded for who they are: the target should, nobody else should. */
function verdict(readable, isTarget, unknown) {
  if (unknown) return h("span", { class: "verdict-bad" }, "unknown");
  if (isTarget) {
    return readable
      ? h("span", { class: "verdict-good" }, "reads it")
      : h("span", { class: "verdict-bad" }, "cannot read it");
  }
  return readable
    ? h("span", { class: "verdict-bad" }, "can read it")
    : h("span", { class: "verdict-good" }, "cannot read it");
}

/** Which judge decided whether the target reads, and by how much. */
function targetJudge(r) {
  if (r.judge === "unknown") {
    return `no judge: without a text hint, characters ${fmt(r.score, 1)} px tall are below the ${fmt(r.bar, 0)} px the legibility judge is calibrated from`;
  }
  return r.judge === "known_font"
    ? `judged by the known-font attacker: margin ${fmt(r.score, 3)} (asked ${fmt(r.bar, 3)})`
    : `no text hint: judged by legibility, read from ${fmt(r.bar)}`;
}

function knownFont(score) {
  const k = score && score.known_font;
  if (!k) return "—";
  return `“${k.text}” ${k.correct ? "(correct)" : `(${k.characters_right} of ${k.characters} right)`}`;
}

/** Operator labels of profiles by id (listing them needs the enrol scope; without it, ids are shown). */
async function profileLabels() {
  if (!has("enrol")) return {};
  const labels = {};
  for (const p of await allPages("/v1/profiles", 5)) labels[p.id] = p.label || short(p.id);
  return labels;
}

async function showEvaluation(job, results, labels) {
  const id = job.id;
  const [report, views] = await Promise.all([api("GET", `/v1/jobs/${id}/evaluation`), api("GET", `/v1/jobs/${id}/views`)]);
  const who = (profileId) => labels[profileId] || short(profileId);
  report.target.label = who(job.profile_id);
  (report.observers || []).forEach((o, k) => {
    if (job.observers[k]) o.label = who(job.observers[k].profile_id);
  });
  const names = new Set(views.names);
  const figures = [];
  const figure = (name, title, score, isTarget) => {
    if (!names.has(name)) return;
    figures.push(h("figure", { "data-view": name },
      authImage(`/v1/jobs/${id}/views/${name}`, title),
      h("figcaption", {}, h("strong", {}, title), h("br"),
        score ? [`legibility ${fmt(score.legibility)} · `, verdict(score.readable, isTarget, isTarget && report.target_reading && report.target_reading.judge === "unknown"), h("br"),
          isTarget && report.target_reading ? targetJudge(report.target_reading) : `known-font read: ${knownFont(score)}`]
          : "what the document should look like")));
  };
  figure("objective.png", "The objective (the document)", null);
  figure("target.png", `The target (${report.target.label})`, report.target, true);
  const people = report.population && report.population.people ? report.population.people : [];
  const worst = people.reduce((a, b) => (!a || b.legibility > a.legibility ? b : a), null);
  if (worst) figure("population_worst.png", `Most legible of ${report.population.count} sampled people (${worst.label})`, worst);
  const observers = report.observers || [];
  let bestK = -1;
  observers.forEach((o, k) => { if (bestK < 0 || o.legibility > observers[bestK].legibility) bestK = k; });
  if (bestK >= 0) figure(`observer_${bestK}.png`, `Best bystander (${observers[bestK].label})`, observers[bestK]);
  if (report.camera) figure("camera_best.png", `Camera attacker's best (${report.camera.best.label})`, report.camera.best);

  const rows = [["Target", report.target]];
  observers.forEach((o) => rows.push([`Bystander ${o.label}`, o]));
  if (worst) rows.push([`Most legible sampled person (${worst.label})`, worst]);
  if (report.camera) rows.push([`Camera, best of ${report.camera.tried.length} settings (${report.camera.best.label})`, report.camera.best]);
  const p = report.population;
  put(results, 
    h("section", {}, h("h2", {}, "What each viewer sees"), h("div", { class: "views", id: "views" }, figures)),
    p ? h("section", {}, h("h2", {}, "Who else can read it"),
      h("p", { id: "population-summary" }, `${p.readable_count} of ${p.count} sampled people read it (${fmt(100 * p.readable_fraction, 1)} %, 95 % interval ${fmt(100 * p.readable_ci95[0], 1)}–${fmt(100 * p.readable_ci95[1], 1)} %), ${p.readable_at_own_focus ?? 0} of them at their own focus and the others after refocusing; ${typeof p.known_font_readers === "number" ? ` the known-font attacker read it for ${p.known_font_readers};` : ""}${typeof p.learned_readers === "number" ? ` the learned reader for ${p.learned_readers};` : ""} median legibility ${fmt(p.median_legibility)}, 95th percentile ${fmt(p.p95_legibility)}, highest ${fmt(p.max_legibility)}. ${report.target.known_font
        ? `A viewer reads it when the known-font attacker${report.learned_reader ? " or the learned reader" : ""} reads every secret character from their view; legibility is shown for reference. ${report.learned_reader ? `Learned reader: ${report.learned_reader}.` : "No learned reader was trained on this document's layout, so none was applied."}`
        : `Somebody might read it from legibility ${fmt(report.threshold)} (the job gave no text hint, so the known-font attacker did not run); the target must reach ${report.target_reading ? fmt(report.target_reading.bar) : "—"} to read it.`}`),
      populationPlot(people, report.threshold, report.target.legibility)) : null,
    h("section", {}, h("h2", {}, "The attackers' verdicts"),
      h("table", { id: "verdicts" },
        h("thead", {}, h("tr", {}, h("th", {}, "Viewer"), h("th", { class: "num" }, "Legibility"), h("th", {}, "Known-font attacker read"), h("th", {}, "Focus"), h("th", {}, "Verdict"))),
        h("tbody", {}, rows.map(([who, sc]) => h("tr", {}, h("td", {}, who), h("td", { class: "num" }, fmt(sc.legibility)), h("td", {}, knownFont(sc)), h("td", {}, focusOf(sc)), h("td", {}, verdict(sc.readable, sc === report.target, sc === report.target && report.target_reading && report.target_reading.judge === "unknown"))))))),
    h("p", { class: "hint" }, `Legibility: ${report.metric}.`));
}

/** At which focus a viewer who may refocus was judged: "own focus", "+1.25 D (nearer)", "−0.50 D (farther)", or "—". */
function focusOf(score) {
  if (typeof score.focus_d !== "number") return "—";
  if (score.focus_d === 0) return "own focus";
  return `${score.focus_d > 0 ? "+" : "−"}${fmt(Math.abs(score.focus_d), 2)} D (${score.focus_d > 0 ? "nearer" : "farther"})`;
}

/** A histogram of the sampled people's legibility with the threshold and the target marked. */
function populationPlot(people, threshold, target) {
  const W = 640, H = 236, L = 44, R = 12, T = 30, B = 36;
  const bins = 25;
  const counts = new Array(bins).fill(0);
  const readers = new Array(bins).fill(0);
  for (const q of people) {
    const i = Math.min(bins - 1, Math.max(0, Math.floor(q.legibility * bins)));
    counts[i] += 1;
    if (q.readable) readers[i] += 1;
  }
  const top = Math.max(1, ...counts);
  const x = (v) => L + v * (W - L - R);
  const y = (c) => H - B - (c / top) * (H - T - B);
  const svg = s("svg", { class: "plot", id: "population-plot", viewBox: `0 0 ${W} ${H}`, width: W, height: H, role: "img",
    "aria-label": `Histogram of the legibility of ${people.length} sampled people, ${people.filter((q) => q.readable).length} of whom read it; threshold ${fmt(threshold)}, target ${fmt(target)}` });
  // Each bar: the people in that legibility bin; the part of it who read the document is dark and outlined.
  counts.forEach((c, i) => {
    if (c === 0) return;
    const bx = x(i / bins) + 1, bw = (W - L - R) / bins - 2;
    svg.append(s("rect", { x: bx, y: y(c), width: bw, height: H - B - y(c), fill: "#b8c1ca" }));
    if (readers[i] > 0) {
      svg.append(s("rect", { x: bx, y: y(readers[i]), width: bw, height: H - B - y(readers[i]), fill: "#8a1b1b", stroke: "#16202a", "stroke-dasharray": "2 2" }));
    }
  });
  const nReaders = readers.reduce((a, b) => a + b, 0);
  svg.append(s("text", { x: W - R - 4, y: 14, "text-anchor": "end" }, `people per bin; light: cannot read it, dark and outlined: reads it (${nReaders} in all)`));
  svg.append(s("line", { x1: L, y1: H - B, x2: W - R, y2: H - B, stroke: "#16202a" }));
  svg.append(s("line", { x1: L, y1: T, x2: L, y2: H - B, stroke: "#16202a" }));
  for (const v of [0, 0.2, 0.4, 0.6, 0.8, 1]) svg.append(s("text", { x: x(v), y: H - B + 14, "text-anchor": "middle" }, fmt(v, 1)));
  svg.append(s("text", { x: (L + W - R) / 2, y: H - 4, "text-anchor": "middle" }, "legibility"));
  svg.append(s("text", { x: 4, y: T + 4 }, `${top}`));
  svg.append(s("text", { x: 4, y: H - B }, "0"));
  const marker = (v, label, dash) => {
    svg.append(s("line", { x1: x(v), y1: T, x2: x(v), y2: H - B, stroke: "#16202a", "stroke-width": 2, "stroke-dasharray": dash }));
    svg.append(s("text", { x: x(v) + 4, y: T + 10 }, label));
  };
  marker(Math.min(1, threshold), `threshold ${fmt(threshold)}`, "6 4");
  if (typeof target === "number") marker(Math.min(1, Math.max(0, target)), `target ${fmt(target)}`, "");
  return svg;
}

async function showAudit(id, section) {
  const entries = await allPages(`/v1/audit?resource=${encodeURIComponent(`jobs/${id}`)}`, 5);
  put(section, h("h2", {}, "Audit log of this job"), entries.length === 0 ? h("p", {}, "No entry.") : auditTable(entries));
}

function auditTable(entries) {
  return h("table", { class: "audit" },
    h("thead", {}, h("tr", {}, h("th", {}, "When"), h("th", {}, "Who"), h("th", {}, "Action"), h("th", {}, "Resource"))),
    h("tbody", {}, entries.map((e) => h("tr", {}, h("td", {}, fmtTime(e.at || e.created_at)), h("td", {}, e.actor), h("td", {}, e.action), h("td", { class: "mono" }, e.resource)))));
}

async function auditPage() {
  const signal = pageAbort.signal;
  if (!has("admin")) return render(signal, "Audit log", needs("admin"));
  const entries = await allPages("/v1/audit", 1);
  render(signal, "Audit log", h("p", {}, `The latest ${entries.length} entries, newest first.`), auditTable(entries));
}

// ---------------------------------------------------------------- routing and chrome

function updateChrome() {
  const signedIn = Boolean(session.me);
  document.getElementById("nav").hidden = !signedIn;
  document.getElementById("who").hidden = !signedIn;
  if (signedIn) {
    document.getElementById("who-name").textContent = `Signed in as ${session.me.name} (${session.me.scopes.join(", ")})`;
    const page = location.pathname.split("/")[2] || "jobs";
    for (const a of document.querySelectorAll("#nav a")) {
      if (a.getAttribute("data-page") === page) a.setAttribute("aria-current", "page");
      else a.removeAttribute("aria-current");
    }
  }
}

function signOut(message) {
  session.token = null;
  session.me = null;
  sessionStorage.removeItem(TOKEN_KEY);
  if (pageAbort) pageAbort.abort();
  forgetImages();
  history.replaceState(null, "", "/console/sign-in");
  signInPage(message || "Signed out. The token is forgotten by this tab.");
}

function navigate(path, replace) {
  if (replace) history.replaceState(null, "", path);
  else history.pushState(null, "", path);
  route();
}

async function route() {
  if (pageAbort) pageAbort.abort();
  pageAbort = new AbortController();
  const signal = pageAbort.signal;
  forgetImages();
  if (!session.token) return signInPage();
  updateChrome();
  const parts = location.pathname.replace(/\/+$/, "").split("/").slice(2);
  const pages = { profiles: profilesPage, displays: displaysPage, documents: documentsPage, audit: auditPage, jobs: jobsPage };
  try {
    if (parts[0] === "jobs" && parts[1]) await jobPage(parts[1]);
    else if (pages[parts[0]]) await pages[parts[0]]();
    else if (parts.length === 0 || parts[0] === "sign-in") return navigate("/console/jobs", true);
    else render(signal, "Not found", h("p", {}, "There is no such page in the console."), h("a", { href: "/console/jobs" }, "Go to the jobs"));
    if (!signal.aborted) main().focus();
  } catch (e) {
    if (e.name === "AbortError" || signal.aborted) return;
    main().append(h("p", { class: "error", role: "alert" }, e.message));
  }
}

document.addEventListener("click", (ev) => {
  const a = ev.target.closest && ev.target.closest("a[href^='/console']");
  if (!a || ev.ctrlKey || ev.metaKey || ev.shiftKey || ev.button !== 0) return;
  ev.preventDefault();
  navigate(a.getAttribute("href"));
});
window.addEventListener("popstate", route);

document.addEventListener("DOMContentLoaded", async () => {
  document.getElementById("sign-out").addEventListener("click", () => signOut());
  const saved = sessionStorage.getItem(TOKEN_KEY);
  if (saved) {
    try {
      session.me = await api("GET", "/v1/me", { token: saved });
      session.token = saved;
    } catch (e) {
      if (e.status === 401 || e.status === 403) sessionStorage.removeItem(TOKEN_KEY);
      else return signInPage(`The service could not be reached (${e.message}); sign in again when it is back.`);
    }
  }
  route();
});
