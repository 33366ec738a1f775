// The farm's page: presets and recipes (public), a grammar editor checked against the committed JSON Schema as
// you type (ajv) with the server's 422 messages on their fields, forest and render jobs with
// a live list (each running job's Server-Sent Events), previews, downloads, job logs, the
// farm's workers, and a three.js viewer of GLBs. Without a valid
// API key the page says how to make one instead of showing an empty job list.
import "./style.css";
import Ajv2020 from "ajv/dist/2020";
import grammarSchema from "../../schemas/json/grammar.schema.json";
import { api, ApiError, apiKey, jobEvents, locPath, setApiKey } from "./api.js";
import { Viewer } from "./viewer.js";

// the gallery's thumbnails (scripts/thumbs.py), by preset name; emitted as assets by vite
const GALLERY = Object.fromEntries(
  Object.entries(import.meta.glob("./gallery/*.png", { eager: true, query: "?url", import: "default" }))
    .map(([path, url]) => [path.replace(/^.*\/|\.png$/g, ""), url]),
);

const $ = (sel) => document.querySelector(sel);
const el = (tag, props = {}, ...children) => {
  const node = Object.assign(document.createElement(tag), props);
  for (const c of children) node.append(c);
  return node;
};

// ---- API key --------------------------------------------------------------------------------
const keyInput = $("#api-key");
keyInput.value = apiKey();
let keyRefused = false; // the server answered 401: no polling until another key is pasted
keyInput.addEventListener("change", () => {
  setApiKey(keyInput.value.trim());
  blobs.clear();
  keyRefused = false;
  for (const ctl of followed.values()) ctl.abort(); // another key: other jobs to follow
  refreshJobs();
  refreshWorkers();
  if (!presets.length) loadPresets();
});

const KEY_HELP = {
  needed: {
    status: "this server needs an API key",
    title: "This server needs an API key",
    why: "Jobs, renders and the 3D viewer need a key; the presets below are public.",
  },
  refused: {
    status: "the server refused this key",
    title: "The server refused this API key",
    why: "It is mistyped, revoked, or from another server's job store: make a new one.",
  },
};

/** A keyed call's outcome: a 401 shows how to make a key (none pasted) or that the pasted one
 * is refused, and hides the job table; an answer (``null``) hides the explanation. Other
 * errors say nothing about the key. Returns whether it was a 401. */
function keyOutcome(err) {
  if (err && !(err instanceof ApiError && err.status === 401)) return false;
  keyRefused = err !== null;
  const state = err === null ? null : apiKey() ? "refused" : "needed";
  $("#key-help").hidden = state === null;
  if (state === null) {
    delete document.body.dataset.key;
    $("#key-status").textContent = "";
    return false;
  }
  document.body.dataset.key = state;
  $("#key-status").textContent = KEY_HELP[state].status;
  $("#key-help-title").textContent = KEY_HELP[state].title;
  $("#key-help-why").textContent = KEY_HELP[state].why;
  return true;
}

// ---- grammar editor -------------------------------------------------------------------------
const ajv = new Ajv2020({ allErrors: true, strict: false });
const validateGrammar = ajv.compile(grammarSchema);
const grammarBox = $("#grammar");
let presets = [];

/** ajv's "/rules/S/0/weight" -> "rules.S[0].weight" (the server's spelling of a path). */
function pointerPath(pointer) {
  let out = "";
  for (const raw of pointer.split("/").slice(1)) {
    const part = raw.replaceAll("~1", "/").replaceAll("~0", "~");
    if (/^\d+$/.test(part)) out += `[${part}]`;
    else out += out ? `.${part}` : part;
  }
  return out;
}

function checkGrammar() {
  const box = $("#err-grammar");
  box.dataset.source = "schema";
  let value;
  try {
    value = JSON.parse(grammarBox.value);
  } catch (e) {
    box.textContent = `not JSON: ${e.message}`;
    grammarBox.classList.add("invalid");
    return null;
  }
  if (!validateGrammar(value)) {
    box.textContent = validateGrammar.errors
      .slice(0, 6)
      .map((e) => `${pointerPath(e.instancePath) || "grammar"}: ${e.message}`)
      .join("\n");
    grammarBox.classList.add("invalid");
    return value;
  }
  box.textContent = "";
  grammarBox.classList.remove("invalid");
  return value;
}

grammarBox.addEventListener("input", () => {
  document.querySelector("input[name=source][value=grammar]").checked = true;
  checkGrammar();
});

function choosePreset(name) {
  const p = presets.find((x) => x.name === name);
  if (!p) return;
  $("#preset").value = name;
  document.querySelector("input[name=source][value=preset]").checked = true;
  grammarBox.value = JSON.stringify(p.grammar, null, 2);
  checkGrammar();
  for (const card of document.querySelectorAll(".preset")) {
    card.classList.toggle("selected", card.dataset.name === name);
  }
}

async function loadPresets() {
  try {
    presets = (await api("/v1/presets")).items; // public: no key needed
  } catch (err) {
    $("#presets-status").textContent = err.message;
    return;
  }
  $("#presets-status").textContent = "";
  const strip = $("#presets");
  const select = $("#preset");
  strip.replaceChildren();
  select.replaceChildren();
  for (const p of presets) {
    const img = GALLERY[p.name]
      ? el("img", { src: GALLERY[p.name], alt: `${p.name} (gallery)` })
      : el("div", { className: "noimg", textContent: "no gallery image" });
    const card = el(
      "button",
      { type: "button", className: "preset", title: p.description },
      img,
      el("div", { className: "name", textContent: p.name }),
      el("div", { className: "desc", textContent: p.description }),
    );
    card.dataset.name = p.name;
    card.addEventListener("click", () => choosePreset(p.name));
    strip.append(card);
    select.append(el("option", { value: p.name, textContent: p.name }));
  }
  choosePreset(presets.some((p) => p.name === "birch") ? "birch" : presets[0]?.name);
}

$("#preset").addEventListener("change", (e) => choosePreset(e.target.value));

// ---- recipes: mixed forests (species layers over terrain), picked instead of a preset -------
let recipes = [];

function chooseRecipe(name) {
  if (!recipes.some((r) => r.name === name)) return;
  $("#recipe").value = name;
  document.querySelector("input[name=source][value=recipe]").checked = true;
  for (const card of document.querySelectorAll(".recipe")) {
    card.classList.toggle("selected", card.dataset.name === name);
  }
}

async function loadRecipes() {
  try {
    recipes = (await api("/v1/recipes")).recipes; // public: no key needed
  } catch (err) {
    $("#recipes-status").textContent = err.message;
    return;
  }
  $("#recipes-status").textContent = "";
  const strip = $("#recipes");
  const select = $("#recipe");
  strip.replaceChildren();
  select.replaceChildren();
  for (const r of recipes) {
    const card = el(
      "button",
      { type: "button", className: "recipe", title: r.description },
      ...(GALLERY[`recipe_${r.name}`] ? [el("img", { src: GALLERY[`recipe_${r.name}`], alt: `${r.name} (gallery)` })] : []),
      el("div", { className: "name", textContent: r.name }),
      el("div", { className: "desc", textContent: r.description }),
      el("ul", { className: "layers" }, ...r.layers.map((l) => el("li", { textContent: l }))),
    );
    card.dataset.name = r.name;
    card.addEventListener("click", () => chooseRecipe(r.name));
    strip.append(card);
    select.append(el("option", { value: r.name, textContent: r.name }));
  }
}

$("#recipe").addEventListener("change", (e) => chooseRecipe(e.target.value));

// ---- submitting -----------------------------------------------------------------------------
const FIELDS = ["preset", "grammar", "recipe", "seed", "trees", "area", "format", "frames"];

function clearErrors() {
  for (const f of [...FIELDS, "general"]) {
    const box = $(`#err-${f}`);
    box.textContent = "";
    delete box.dataset.source;
  }
  for (const n of document.querySelectorAll(".invalid")) n.classList.remove("invalid");
}

/** The server's answer to a bad request, each message on the field its `loc` names. */
function showServerErrors(err) {
  if (!(err instanceof ApiError) || !Array.isArray(err.errors)) {
    $("#err-general").textContent = err.message;
    keyOutcome(err);
    return;
  }
  const byField = {};
  for (const d of err.errors) {
    const loc = d.loc || [];
    const field = FIELDS.includes(loc[1]) ? loc[1] : "general";
    const path = locPath(loc);
    (byField[field] ||= []).push(path && path !== field ? `${path}: ${d.msg}` : d.msg);
  }
  for (const [field, msgs] of Object.entries(byField)) {
    const box = $(`#err-${field}`);
    box.dataset.source = "server";
    box.textContent = msgs.join("\n");
    const input = field === "grammar" ? grammarBox : $(`#${field === "area" ? "area-x" : field}`);
    input?.classList.add("invalid");
  }
}

function requestBody() {
  const source = document.querySelector("input[name=source]:checked").value;
  const body = {};
  if (source === "preset") body.preset = $("#preset").value;
  else if (source === "recipe") body.recipe = $("#recipe").value;
  else {
    try {
      body.grammar = JSON.parse(grammarBox.value);
    } catch {
      body.grammar = grammarBox.value; // the server names what is wrong with it
    }
  }
  const num = (id) => (($(id).value === "") ? undefined : Number($(id).value));
  body.seed = num("#seed");
  body.frames = num("#frames");
  return body;
}

$("#forest-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  clearErrors();
  const body = {
    ...requestBody(),
    trees: Number($("#trees").value),
    area: [Number($("#area-x").value), Number($("#area-y").value)],
    format: $("#format").value,
  };
  // the preview is a render job the server makes beside the forest, waiting for it (its
  // "then"); the renderer reads USD, so a .glb forest gets none, and the status says so
  const preview = $("#auto-render").checked;
  if (preview && body.format !== "glb") body.render = { width: 640, height: 480 };
  $("#form-status").textContent = "submitting…";
  try {
    const job = await api("/v1/forests", { method: "POST", body });
    const note = preview && body.format === "glb" ? " (no preview: the renderer reads USD, not .glb)" : "";
    $("#form-status").textContent = `forest job ${job.id.slice(0, 8)} queued${job.then.length ? " with its preview render" : ""}${note}`;
    refreshJobs();
  } catch (err) {
    $("#form-status").textContent = "";
    showServerErrors(err);
  }
});

const viewer = new Viewer($("#viewer-canvas"), $("#viewer"));
window.forestViewer = viewer; // for a console (and the tests): the scene, camera, mixer

let shownTree = null; // {body, buffer} of the tree in the viewer: what "Download" saves

// the browser saves what ``href`` names as ``name``
function clickDownload(href, name) {
  const a = el("a", { href, download: name });
  document.body.append(a);
  a.click();
  a.remove();
}

function save(blob, name) {
  const href = URL.createObjectURL(blob);
  clickDownload(href, name);
  setTimeout(() => URL.revokeObjectURL(href), 60000);
}

async function showGlb(fetchBuffer, title, tree = null) {
  $("#viewer").dataset.state = "loading";
  $("#viewer-msg").textContent = "loading…";
  $("#viewer-downloads").hidden = true;
  try {
    const buffer = await fetchBuffer();
    const info = await viewer.show(buffer);
    $("#viewer-title").textContent = title;
    const lods = info.levels > 1 ? `; ${info.levels} levels of detail by distance (scroll out)` : "";
    $("#viewer-msg").textContent =
      `${info.meshes} meshes; animation: ${info.clips.join(", ") || "none"}${lods}; drag to orbit`;
    shownTree = tree ? { ...tree, buffer } : null;
    $("#viewer-downloads").hidden = shownTree === null;
  } catch (err) {
    $("#viewer").dataset.state = "error";
    $("#viewer-msg").textContent = "";
    showServerErrors(err);
  }
}

$("#view-tree").addEventListener("click", () => {
  clearErrors();
  if (document.querySelector("input[name=source]:checked").value === "recipe") {
    $("#err-recipe").textContent = "a recipe is a forest (USD): submit it as a forest job; the viewer shows one tree of a preset or grammar";
    return;
  }
  const body = { ...requestBody(), format: "glb" };
  if (!body.frames) body.frames = 48; // the wind needs frames to play
  const name = body.preset ?? "grammar";
  const tree = { body, name: `${name}-${body.seed}` };
  showGlb(() => api("/v1/trees", { method: "POST", body, as: "arraybuffer" }), `${name}, seed ${body.seed}`, tree);
});

// the tree in the viewer, as its GLB (the very file shown) or as USD (a .usdz: one file with
// its bark and leaf pictures inside, for Blender, usdview, Omniverse, Quick Look)
$("#download-glb").addEventListener("click", () => {
  if (shownTree) save(new Blob([shownTree.buffer], { type: "model/gltf-binary" }), `${shownTree.name}.glb`);
});
$("#download-usd").addEventListener("click", async () => {
  if (!shownTree) return;
  const status = $("#viewer-msg");
  try {
    const blob = await api("/v1/trees", { method: "POST", body: { ...shownTree.body, format: "usdz" }, as: "blob" });
    save(blob, `${shownTree.name}.usdz`);
  } catch (err) {
    status.textContent = `USD download: ${err.message}`;
  }
});

// ---- jobs -----------------------------------------------------------------------------------
const blobs = new Map(); // artifact url -> object URL (fetched with the key)

async function artifactUrl(url) {
  if (!blobs.has(url)) blobs.set(url, api(url, { as: "blob" }).then((b) => URL.createObjectURL(b)));
  return blobs.get(url);
}

async function download(artifact) {
  clickDownload(await artifactUrl(artifact.url), artifact.name);
}

async function render(job) {
  try {
    await api("/v1/renders", { method: "POST", body: { forest_job: job.id, width: 640, height: 480 } });
    refreshJobs();
  } catch (err) {
    $("#jobs-status").textContent = `render of ${job.id.slice(0, 8)}: ${err.message}`;
  }
}

async function cancel(job) {
  try {
    await api(`/v1/jobs/${job.id}`, { method: "DELETE" });
    refreshJobs();
  } catch (err) {
    $("#jobs-status").textContent = `cancel ${job.id.slice(0, 8)}: ${err.message}`;
  }
}

function jobRow(job) {
  const tr = el("tr", { className: `job state-row-${job.state}` });
  tr.dataset.jobId = job.id;
  tr.dataset.kind = job.kind;
  tr.dataset.state = job.state;
  const results = el("td", { className: "results" });
  for (const a of job.artifacts) {
    if (a.name.endsWith(".png")) {
      const img = el("img", { className: "preview", alt: `${a.name} of ${job.id}` });
      artifactUrl(a.url).then((u) => (img.src = u)).catch(() => img.remove());
      results.append(img);
    } else if (/\.(mp4|webm)$/.test(a.name)) {
      const video = el("video", { className: "clip", controls: true, loop: true, muted: true });
      artifactUrl(a.url).then((u) => (video.src = u));
      results.append(video);
    }
  }
  for (const a of job.artifacts) {
    const link = el("a", { href: a.url, className: "artifact", textContent: `${a.name} (${(a.size / 1024).toFixed(0)} KiB)` });
    link.addEventListener("click", (e) => {
      e.preventDefault();
      download(a);
    });
    results.append(link);
  }
  const actions = el("td", { className: "actions" });
  const logButton = el("button", { type: "button", className: "show-log", textContent: openLogs.has(job.id) ? "Hide log" : "Log" });
  logButton.addEventListener("click", () => toggleLog(job.id));
  actions.append(logButton);
  if (job.state === "queued" || job.state === "active") {
    const b = el("button", { type: "button", className: "cancel", textContent: "Cancel" });
    b.addEventListener("click", () => cancel(job));
    actions.append(b);
  }
  const glb = job.artifacts.find((a) => a.name.endsWith(".glb"));
  if (job.state === "completed" && glb) {
    const b = el("button", { type: "button", className: "view3d", textContent: "View 3D" });
    b.addEventListener("click", () => showGlb(() => api(glb.url, { as: "arraybuffer" }), `job ${job.id.slice(0, 8)}`));
    actions.append(b);
  } else if (job.state === "completed" && job.kind === "forest") {
    const b = el("button", { type: "button", className: "render", textContent: "Render" });
    b.addEventListener("click", () => render(job));
    actions.append(b);
  }
  const progress = el("progress", { max: 1, value: job.progress });
  tr.append(
    el("td", { className: "id", textContent: job.id.slice(0, 8), title: job.id }),
    el("td", { textContent: job.kind }),
    el("td", { className: `state state-${job.state}`, textContent: job.state + (job.cancel_requested && job.state === "active" ? " (canceling)" : "") }),
    el("td", { className: "progress" }, progress, el("span", { className: "percent", textContent: ` ${Math.round(job.progress * 100)}%` })),
    el("td", { className: "stage", textContent: job.stage }),
    el("td", {
      className: "attempts",
      textContent: `${job.attempts}/${job.max_attempts}`,
      // which worker ran each attempt
      title: (job.runs || []).map((r) => `attempt ${r.attempt}: ${r.worker}`).join("\n"),
    }),
    el("td", { className: "error", textContent: job.error ?? "" }),
    results,
    actions,
  );
  return tr;
}

const shown = new Map(); // job id -> JSON of what its row shows (rebuild rows that changed)

// ---- job logs (GET /v1/jobs/{id}/log) -------------------------------------------------------
const openLogs = new Map(); // job id -> { lines: [LogLine], after, dropped }

function logRow(jobId) {
  const log = openLogs.get(jobId);
  const pre = el("pre", { className: "log-lines" });
  if (log.dropped) pre.append(el("span", { className: "hint", textContent: `(${log.dropped} older line(s) dropped)\n` }));
  for (const line of log.lines) {
    const at = new Date(line.at).toLocaleTimeString();
    pre.append(el("span", { className: line.level, textContent: `${at} #${line.attempt} ${line.level.padEnd(7)} ${line.message}\n` }));
  }
  const tr = el("tr", { className: "log" }, el("td", { colSpan: 9 }, pre));
  tr.dataset.logOf = jobId;
  return tr;
}

/** New lines of an open log (from its last id on), appended to what it shows. */
async function readLog(jobId) {
  const log = openLogs.get(jobId);
  if (!log || log.reading) return; // one read at a time: no line twice
  log.reading = true;
  try {
    const got = await api(`/v1/jobs/${jobId}/log?after=${log.after}`);
    log.lines.push(...got.items);
    log.after = got.next_after;
    log.dropped = got.dropped;
  } finally {
    log.reading = false;
  }
  placeLog(jobId);
}

function placeLog(jobId) {
  const row = document.querySelector(`#jobs tr[data-job-id="${jobId}"]`);
  document.querySelector(`#jobs tr[data-log-of="${jobId}"]`)?.remove();
  if (row && openLogs.has(jobId)) row.after(logRow(jobId));
}

function toggleLog(jobId) {
  if (openLogs.has(jobId)) openLogs.delete(jobId);
  else openLogs.set(jobId, { lines: [], after: 0, dropped: 0 });
  shown.delete(jobId); // its row's button changes
  refreshJobs();
  if (openLogs.has(jobId)) readLog(jobId).catch((err) => ($("#jobs-status").textContent = `log: ${err.message}`));
}

// ---- workers (GET /v1/workers: an admin key's) ----------------------------------------------
async function refreshWorkers() {
  let list;
  try {
    list = await api("/v1/workers");
  } catch (err) {
    $("#workers tbody").replaceChildren();
    $("#workers").hidden = true; // no empty table: the status says why
    $("#workers-status").textContent = err.status === 403 ? "an admin key shows the farm's workers here" : err.message;
    return;
  }
  $("#workers").hidden = false;
  $("#workers-status").textContent = `${list.items.length} worker(s); lost when not seen for ${list.timeout_s} s`;
  $("#workers tbody").replaceChildren(
    ...list.items.map((w) => {
      const tr = el(
        "tr",
        { className: "worker" },
        el("td", { textContent: w.name, title: w.id }),
        el("td", { textContent: w.host }),
        el("td", { textContent: w.queues.join(", ") }),
        el("td", { textContent: w.renderer ?? "(probing)" }),
        el("td", { className: `worker-${w.state}`, textContent: w.state }),
        el("td", { className: "id", textContent: w.current_job ? w.current_job.slice(0, 8) : "", title: w.current_job ?? "" }),
        el("td", { textContent: new Date(w.last_seen).toLocaleTimeString() }),
      );
      tr.dataset.workerId = w.id;
      tr.dataset.state = w.state;
      return tr;
    }),
  );
}

async function refreshJobs() {
  let page;
  try {
    page = await api("/v1/jobs?limit=50");
    keyOutcome(null);
  } catch (err) {
    $("#jobs-status").textContent = keyOutcome(err) ? "an API key shows your jobs here" : err.message;
    return;
  }
  $("#jobs-status").textContent = `${page.total} job(s)`;
  const body = $("#jobs tbody");
  const rows = [];
  for (const job of page.items) {
    const sig = JSON.stringify([job.state, job.progress, job.stage, job.attempts, job.error, job.artifacts, job.cancel_requested]);
    let row = body.querySelector(`tr[data-job-id="${job.id}"]`);
    if (!row || shown.get(job.id) !== sig) {
      row = jobRow(job);
      shown.set(job.id, sig);
    }
    rows.push(row);
    if (openLogs.has(job.id)) {
      rows.push(logRow(job.id));
      // a running job's log grows: read on from the last line shown (a followed job's lines
      // come with its events)
      if ((!FINISHED.includes(job.state) && !followed.has(job.id)) || shown.get(`log:${job.id}`) !== job.state) {
        shown.set(`log:${job.id}`, job.state);
        readLog(job.id).catch(() => {});
      }
    }
  }
  body.replaceChildren(...rows);
  for (const job of page.items) if (!FINISHED.includes(job.state)) follow(job.id);
}

// ---- live jobs: GET /v1/jobs/{id}/events ----------------------------------------------------
const FINISHED = ["completed", "failed", "canceled"];
const MAX_STREAMS = 4; // a browser opens at most 6 connections to a server over HTTP/1.1
const RECONNECT_MS = 1000; // between a job's event streams when one closes before its end
const followed = new Map(); // job id -> AbortController of its event stream

/** The job as it is now, its row rebuilt (after a state change: attempts, error, artifacts). */
async function updateJob(jobId) {
  const job = await api(`/v1/jobs/${jobId}`);
  const old = document.querySelector(`#jobs tr[data-job-id="${jobId}"]`);
  if (old) {
    old.replaceWith(jobRow(job));
    placeLog(jobId);
  }
  return job;
}

function showProgress(jobId, { stage, progress }) {
  const row = document.querySelector(`#jobs tr[data-job-id="${jobId}"]`);
  if (!row) return;
  row.querySelector("progress").value = progress;
  row.querySelector(".percent").textContent = ` ${Math.round(progress * 100)}%`;
  row.querySelector(".stage").textContent = stage;
}

function appendLog(jobId, line) {
  const log = openLogs.get(jobId);
  if (!log || log.reading || line.id <= log.after) return; // a read under way brings it
  log.lines.push(line);
  log.after = line.id;
  placeLog(jobId);
}

/** Follow an unfinished job's events (at most MAX_STREAMS at once; the rest show at the
 * list's slower refresh) until it ends; a stream the server closed at its length cap is
 * opened again, the log resumed after its last line. */
function follow(jobId) {
  if (followed.has(jobId) || followed.size >= MAX_STREAMS || keyRefused) return;
  const ctl = new AbortController();
  followed.set(jobId, ctl);
  (async () => {
    let lastEventId;
    let ended = false;
    try {
      while (!ended) {
        for await (const e of jobEvents(jobId, { lastEventId, signal: ctl.signal })) {
          if (e.event === "log") {
            lastEventId = e.id;
            appendLog(jobId, e.data);
          } else if (e.event === "progress") showProgress(jobId, e.data);
          else if (e.event === "state") await updateJob(jobId);
          else if (e.event === "end") ended = true;
        }
        // closed without its end (the server's cap, a restart): wait a little before the
        // next connection, so that a server closing at once is not asked again in a loop
        if (!ended) await new Promise((resolve) => setTimeout(resolve, RECONNECT_MS));
      }
    } catch (err) {
      if (ctl.signal.aborted) return;
      keyOutcome(err);
      await new Promise((resolve) => setTimeout(resolve, 2000)); // then the list looks again
    } finally {
      if (followed.get(jobId) === ctl) followed.delete(jobId);
    }
    if (!ctl.signal.aborted) refreshJobs(); // its end frees a stream for another job
  })();
}

loadPresets();
loadRecipes();
refreshJobs();
refreshWorkers();
// the list itself: jobs made elsewhere, and those beyond MAX_STREAMS (followed jobs update live)
setInterval(() => keyRefused || refreshJobs(), 10000);
setInterval(() => keyRefused || refreshWorkers(), 5000);
