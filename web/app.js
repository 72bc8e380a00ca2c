// The preview page: plain JS, no build step. Talks to /api (api.js) and embeds the viser
// viewer. Here: the scenes and their editor, the run controls, the runs and the selection;
// the selected run's headline and plots are results.js's, drawn by plots.js.
"use strict";
const $ = (id) => document.getElementById(id);
// run: the selected run of this tab's view, as the server holds it (/api/view, VIEW in
// api.js: the embedded viewer shows the same one; another browser's view its own);
// viewSeq / paramSeq / previewSeq count the page's own changes, so an answer to a request sent before one
// of them is not taken for the server's state after it; noticeSeq: the last notice shown;
// nudge(): ends the wait before the next poll; unsaved: the editor differs from the saved file
// (editorChanged: from what the selected run ran)
const state = { scene: null, run: null, config: null, form: null, syncSeq: 0,
                syncTimer: null, syncPending: null, syncRunning: null, viewSeq: 0,
                paramSeq: 0, status: null, noticeSeq: 0, editorChanged: false, nudge: null,
                unsaved: false, previewSeq: 0, previewFailed: 0 };

// a run another browser (or a script) started: an action on it asks first, once per run,
// and says whose it was; what others did to this view's runs is shown here
const Owner = (() => {
  const asked = new Set();
  const who = (r) => (r.started_by === "default" ? "a script" : "another page");
  const foreign = (r) => !!r && !!r.started_by && r.started_by !== VIEW;

  function note(r) {
    return foreign(r) ? `\nIt was started by ${who(r)}, which is told.` : "";
  }

  function allow(r, what) {
    if (!foreign(r) || asked.has(r.id)) return true;
    // a page: another browser's, or another tab or window of this one (each has its view)
    if (!confirm(`Run ${r.id} was started by ${who(r)}.\n${what} it anyway? ` +
                 "(That page is told.)")) return false;
    asked.add(r.id);
    return true;
  }

  function showTouched(st) {
    // on the page that started the run: the last thing another browser did to it
    const box = $("touched");
    const last = st && st.started_by === VIEW && (st.touched || []).slice(-1)[0];
    box.hidden = !last;
    if (last) box.textContent = `${describe(last)} by ${last.by} at step ${last.step}` +
                                ` (${new Date(last.at * 1000).toLocaleTimeString()})`;
  }

  function describe(e) {
    const done = { pause: "paused", resume: "resumed", step: "stepped", stop: "stopped" };
    return e.action.startsWith("set ") ? `${e.action.slice(4)} changed${e.detail || ""}`
                                       : done[e.action] || e.action;
  }

  function showNotices(list) {
    // what others did to this view's runs (a deleted one included), the newest first
    if (!list.length) return;
    state.noticeSeq = Math.max(state.noticeSeq, ...list.map((n) => n.seq));
    // one about the run shown is its line under the status (showTouched), unless deleted
    const shown = list.filter((n) => n.run !== state.run || n.action === "delete");
    if (!shown.length) return;
    const box = $("notice");
    box.hidden = false;
    box.querySelector(".text").textContent = shown[shown.length - 1].text;
  }

  return { note, allow, showTouched, showNotices };
})();
const ACTIVE = ["starting", "building", "running", "paused"];

// the page's ?viewer_dpr=0.5 draws the 3-D view at that many pixels per CSS pixel (viser's
// fixedDpr): without a GPU (software WebGL) every frame costs CPU in proportion to its pixels
function viewerDensity() {
  const v = new URLSearchParams(location.search).get("viewer_dpr");
  if (v === null) return "";
  const dpr = Number(v);
  if (dpr >= 0.1 && dpr <= 4) return `&fixedDpr=${dpr}`;  // NaN, and "" (0), fail it
  say(`viewer_dpr: '${v}' is no pixel density from 0.1 to 4; the 3-D view draws at the `
      + "screen's own", true);
  return "";
}

function markRefused(message) {
  // a refusal of a scene's field ("mesh.scale: absurd size ...", "tools.1.shape.path: tool
  // 'punch': ...") is marked at the field too, not only said in the header; the next edit's
  // check of the form clears it (and a preview then asked for says it again if it holds)
  const m = /^([a-z_]+(?:\.[A-Za-z0-9_]+)+): (.+)$/s.exec(message);
  if (m && state.form) state.form.markError(m[1], m[2]);
  // the form's "valid" is the scene as read; the build (a preview's) found what reading cannot
  // (a thickness file's count against the mesh): the form said "valid" beside the refusal
  $("sync").textContent = "read, but its build refuses it (see the field)";
}

function say(text, isError, run) {
  // ``run``: the message is about that run's start or control, and goes once the run has
  // ended (the status line says how it ended; "started ..." would read as still running)
  // an error names values in the form's units, as its fields do (the server's are SI)
  $("msg").textContent = isError ? Units.shownMessage(text) : text;
  $("msg").style.color = isError ? "#b00" : "#555";
  $("msg").dataset.run = run || "";
  $("msg").dataset.preview = "";
  $("msg").dataset.scene = "";
}

const KEPT_SCENE = "q3t.scene";  // the tab's open scene, for a reload

async function loadScenes() {
  const list = await api("GET", "/api/scenes");
  const ul = $("scenes");
  state.sceneList = list;
  ul.replaceChildren();
  for (const s of list) {
    const li = document.createElement("li");
    li.textContent = s.name + (s.description ? " — " + s.description : "");
    li.title = li.textContent;
    li.dataset.name = s.name;
    li.className = s.name === state.scene ? "sel" : "";
    li.tabIndex = 0;  // opened with the keyboard too (Enter or Space)
    li.onkeydown = (ev) => {
      if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); li.onclick(); }
    };
    li.onclick = () => {
      // choosing a scene (again) replaces the editor's text: unsaved edits are asked for first
      if (state.unsaved && !confirm(s.name === state.scene
        ? `${state.scene} has unsaved edits: reload it from its file and drop them?`
        : `${state.scene} has unsaved edits: open ${s.name} and drop them?`)) return;
      selectScene(s.name).then(() => previewScene(s.name));
    };
    ul.appendChild(li);
  }
  if (!state.scene && list.length) {
    // a reload keeps the scene this tab had open (a review's reload went back to the
    // server's default scene, and the run it had started read "not the editor's scene")
    const kept = list.find((s) => s.name === sessionStorage.getItem(KEPT_SCENE));
    const dflt = list.find((s) => s.name === state.config.default_scene);
    await selectScene((kept || dflt || list[0]).name);
  }
  showAbout();
}

// a scene the user chooses shows in 3-D at rest, its blank and tools, before any run (the
// solver builds it between the steps of a running run; selecting a run shows that run again);
// with ``toml``, as the editor holds it (edits not saved yet)
function previewScene(name, toml) {
  if (!$("viewer")) return;  // no viewer here to show it in
  state.previewing = name;  // before the next poll says so: the edits that follow show too
  const seq = ++state.previewSeq;  // an earlier request answered late says nothing
  // nor does a view polled before the server has taken this request: its "no preview, a
  // run" ended the previewing above, and the edits that followed asked for no preview
  state.viewSeq++;
  api("PUT", "/api/view/scene", toml === undefined ? { scene: name } : { scene: name, toml })
    .finally(() => { state.viewSeq++; })
    .then(() => {
      // a refused preview's error goes once a preview is taken: the edits that fixed it
      if (seq === state.previewSeq && $("msg").dataset.preview) say("");
    })
    .catch((e) => {
      if (seq !== state.previewSeq) return;
      state.previewFailed = seq;  // said: not again when the view says it failed
      say(`preview of ${name}: ${e.message}`, true);
      $("msg").dataset.preview = name;
      if (name === state.scene) markRefused(e.message);
    });
}

async function previewEditor() {
  // the Preview button: the editor's scene, also while the viewer shows a run
  await flushSync();
  if (state.tomlStale || Number($("scene-error").dataset.count || 0) > 0) {
    say("the scene has errors (see the fields): nothing to preview", true);
    $("msg").dataset.scene = "1";  // goes once the fields are right
    return;
  }
  previewScene(state.scene, $("toml").value);
}

function previewEdits() {
  // the editor's valid edits of the scene the viewer previews show there: a blank made
  // larger, a tool moved, without a save or a run. The solver builds each preview, so a
  // burst of edits asks for one, after the last.
  if (!$("viewer") || state.previewing !== state.scene) return;
  clearTimeout(state.previewTimer);
  state.previewTimer = setTimeout(() => previewScene(state.scene, $("toml").value), 800);
}

async function selectScene(name) {
  // the scene chosen last wins: the page's first load opens the default scene, and a click
  // on another while that one is still on its way was overwritten by it when it came
  const seq = state.selectSeq = (state.selectSeq || 0) + 1;
  const s = await api("GET", `/api/scenes/${encodeURIComponent(name)}`);
  if (seq !== state.selectSeq) return;
  if (name !== state.scene) state.sceneElement = null;  // the run's element follows its own
  state.scene = name;
  sessionStorage.setItem(KEPT_SCENE, name);
  $("scene-name").value = name;
  $("toml").value = s.toml;
  state.loadedName = s.scene ? s.scene.name : null;  // a changed name field saves a new scene
  state.base = s.toml;  // the form's edits are written into this text (comments kept)
  clearTimeout(state.syncTimer);
  state.syncTimer = null;
  state.syncSeq++;  // answers to edits of the previous scene are stale now
  state.tomlStale = false;
  state.editorChanged = false;
  state.unsaved = false;  // the editor holds the saved file
  showSlidersFor();
  if (s.scene) {
    state.form.build(s.scene);
    followElement(s.scene);
    showSceneErrors([]);
  } else {
    await syncFromToml();  // the raw tables and the errors naming the fields
  }
  for (const li of $("scenes").children) li.className = li.dataset.name === name ? "sel" : "";
  showAbout();
}

function showAbout() {
  // the list gives each scene a line, its description cut at the column: the chosen one's
  // whole, under the list (as saved)
  const listed = (state.sceneList || []).find((x) => x.name === state.scene);
  $("scene-about").textContent = listed ? listed.description : "";
}

// ---- the scene form and the TOML view, in sync through the server ---------------------------
// form -> JSON -> POST /api/scenes/render -> TOML; TOML -> POST /api/scenes/parse -> form.
function showSceneErrors(errors) {
  const rest = state.form.showErrors(errors);
  const box = $("scene-error");
  box.textContent = errors.map((e) => `${e.loc}: ${Units.shownMessage(e.msg)}`).join("\n");
  box.dataset.count = errors.length;
  box.dataset.unplaced = rest.length;
  if (!errors.length && $("msg").dataset.scene) say("");  // a refusal the edits have fixed
}

function scheduleSync(fn, ms) {
  // a newer edit makes the answer to an older one stale: a form render still on its way
  // would otherwise overwrite TOML typed since (and the form then be rebuilt from it)
  state.syncSeq++;
  clearTimeout(state.syncTimer);
  state.syncPending = fn;
  state.syncTimer = setTimeout(() => { state.syncTimer = null; fn(); }, ms);
}

async function flushSync() {
  // a pending edit is converted before the TOML is saved
  if (state.syncTimer) {
    clearTimeout(state.syncTimer);
    state.syncTimer = null;
    await state.syncPending();
  }
  await state.syncRunning;
}

async function syncFromForm() {
  const seq = ++state.syncSeq;
  $("sync").textContent = "…";
  // base: the scene's TOML before this edit, which the server writes the change into
  const job = api("POST", "/api/scenes/render", { scene: state.form.value(), base: state.base });
  state.syncRunning = job.catch(() => null);
  try {
    const r = await job;
    if (seq !== state.syncSeq) return;
    state.tomlStale = r.toml === null;  // the form holds what TOML cannot say (a null)
    if (r.toml !== null) $("toml").value = r.toml;
    if (r.ok) state.base = r.toml;  // an invalid form's TOML has lost the comments
    followElement(state.form.value());
    showSceneErrors(r.errors);
    $("sync").textContent = r.ok ? "valid" : `${r.errors.length} error(s)`;
    if (r.ok) previewEdits();
  } catch (e) { say(e.message, true); }
}

async function syncFromToml() {
  const seq = ++state.syncSeq;
  $("sync").textContent = "…";
  const job = api("POST", "/api/scenes/parse", { toml: $("toml").value });
  state.syncRunning = job.catch(() => null);
  try {
    const r = await job;
    if (seq !== state.syncSeq) return;
    state.tomlStale = false;
    if (r.ok) state.base = $("toml").value;
    if (r.scene || r.raw) state.form.build(r.scene || r.raw);
    if (r.scene) followElement(r.scene);
    showSceneErrors(r.errors);
    $("sync").textContent = r.ok ? "valid" : `${r.errors.length} error(s)`;
    if (r.ok) previewEdits();
  } catch (e) { say(e.message, true); }
}

function followElement(scene) {
  // The run's element (the Run box's choice, which the server runs) follows the scene's
  // shell.element whenever that changes, so a scene written for q3t_ans runs with it; a choice
  // made in the Run box stands until then.
  const e = scene && scene.shell && scene.shell.element;
  if (!e || e === state.sceneElement || !state.config.elements.includes(e)) return;
  state.sceneElement = e;
  $("element").value = e;
  showElementNote();
}

function showElementNote() {
  // what the chosen element is for, under the Run box's choice (the registry's note)
  $("element-note").textContent = state.config.element_notes[$("element").value] || "";
}

function suggestNames(path, scene) {
  // choices for the form's text fields that name something else in the scene
  const names = (list) => (scene[list] || []).map((x) => x && x.name).filter(Boolean);
  const p = path.split(".").filter((s) => !/^\d+$/.test(s)).join(".");
  if (["shell.element", "study.reference_element", "study.elements"].includes(p))
    return state.config.elements;
  if (/^(bcs|loads|probes)\.region$/.test(p)) return names("regions");
  if (p === "probes.tool") return names("tools");
  if (p === "study.probe") return names("probes");
  return null;
}

function showTab(which) {
  const form = which === "form";
  $("scene-form").hidden = !form;
  $("toml").hidden = form;
  $("tab-form").setAttribute("aria-selected", String(form));
  $("tab-toml").setAttribute("aria-selected", String(!form));
}

async function saveScene() {
  // One name per scene, its file's: the scene-name box names the file saved; the form's name
  // field changed (and the box not) names it too. A name other than the open scene's saves a
  // new scene (the open one stays as it was), its name field following the file's; a taken
  // name asks before it replaces that scene.
  let name = $("scene-name").value.trim();
  say("");  // a message of an earlier save must not stand over this one's outcome
  try {
    await flushSync();
    if (state.tomlStale) throw new Error("the form has errors (see the fields)");
    const field = state.form.value().name;
    if (name === state.scene && state.loadedName !== null && typeof field === "string"
        && field.trim() && field !== state.loadedName) name = field.trim();
    let toml = $("toml").value;
    if (name !== state.scene) {
      if (field !== name) toml = await renamedText(name, toml);
      try {
        await api("POST", "/api/scenes", { name, toml });
      } catch (e) {
        if (e.status !== 409) throw e;
        if (!confirm(`A scene named ${name} exists. Replace it with this one?`))
          return say(`not saved: ${name} exists (choose another name)`, true);
        await api("PUT", `/api/scenes/${encodeURIComponent(name)}`, { toml });
      }
      const from = state.scene;
      state.scene = name;
      await loadScenes();
      await selectScene(name);
      // the viewer previewed the original (with the edits now saved): it shows the new one
      if (state.previewing === from) previewScene(name);
      return say(`saved as ${name}${from ? ` (${from} unchanged)` : ""}`);
    }
    await api("PUT", `/api/scenes/${encodeURIComponent(name)}`, { toml });
    $("scene-error").textContent = "";
    state.unsaved = false;
    state.loadedName = field;
    // a preview "with its unsaved edits" shows the saved scene now
    if (state.previewing === name) previewScene(name);
    say(`saved ${name}`);
    await loadScenes();
  } catch (e) {
    say(`${name} not saved: ${e.message}`, true);
    if (e.status === 422) { $("msg").dataset.scene = "1"; markRefused(e.message); }
    $("scene-error").textContent = Units.shownMessage(e.message);
    // the error where the user looks: the first field named, else the error box
    const where = $("scene-form").querySelector(".has-error") || $("scene-error");
    where.scrollIntoView({ block: "center" });
  }
}

async function renamedText(name, toml) {
  // the editor's text with its name field set (comments kept: the server writes the change
  // into the text); a form the server cannot render saves as it is, and says why
  const r = await api("POST", "/api/scenes/render",
                      { scene: { ...state.form.value(), name }, base: toml });
  return r.toml === null ? toml : r.toml;
}

function dropPreview() {
  // a preview of the editor's edits still to be asked for would take the viewer from the run
  // about to be shown (an edit, then Start within the preview's delay); one already sent is
  // the server's to order (a run selected after it ends it)
  clearTimeout(state.previewTimer);
  state.previewing = null;
}

async function startRun() {
  // runs the scene as shown (the form's or the TOML view's edits, saved or not); the server
  // validates it as a saved scene and says whether it differs from the saved file
  dropPreview();
  try {
    await flushSync();
    dropPreview();  // the sync's own edits may have asked for one
    if (state.tomlStale)
      throw Object.assign(new Error("the form has errors (see the fields): not started"),
                          { status: 422 });
    const run = await api("POST", "/api/runs",
      { scene: state.scene, element: $("element").value, toml: $("toml").value });
    state.viewSeq++;  // the server selected the new run
    state.editorChanged = false;  // the new run runs the editor's scene as it is
    adoptRun(run.id);
    say((run.state === "queued" ? `queued ${run.id} (#${run.place} in the queue)`
                                 : `started ${run.id}`) +
        (run.edited ? " with the unsaved edits of " + run.scene : ""), false, run.id);
    await loadRuns();
  } catch (e) {
    say(e.message, true);
    // the scene's fields refused: the message goes once the fields are right again
    if (e.status === 422) { $("msg").dataset.scene = "1"; markRefused(e.message); }
  }
}

async function control(action) {
  if (!state.run) return say("no run selected", true);
  const word = action[0].toUpperCase() + action.slice(1);
  if (!Owner.allow(state.status, word)) return;
  try {
    const r = await api("POST", `/api/runs/${state.run}/${action}`);
    if (r.id === state.run && r.state) showControls(r);  // at once, not at the next poll
    // a notice (the run is another view's) stays: it says what happened to whose run
    say(r.notice || `${action}: ${state.run}`, false, r.notice ? null : state.run);
  } catch (e) { say(e.message, true); }
}

async function buildSliders() {
  // the selected run's live parameters: they show its values (its status) and change them
  // from the next step; disabled while the run is not active
  // the solver process names the live parameters a few seconds after the server is up
  while (!state.config.ready) {
    $("sliders").textContent = "live parameters: waiting for the solver process…";
    await new Promise((ok) => setTimeout(ok, 1000));
    state.config = await api("GET", "/api/config");
  }
  const box = $("sliders");
  box.replaceChildren();
  for (const [name, r] of Object.entries(state.config.parameters))
    box.appendChild(paramRow(name, r, r.label || name));
  if (state.status) showParameters(state.status);
}

function editorEdited() {
  // an edit in the form or the TOML view: the scene being edited is not what runs, nor what
  // is saved (a reload asks first)
  state.editorChanged = true;
  state.unsaved = true;
  showSlidersFor();
}

function showSlidersFor() {
  // what the live parameters act on, above them: the selected run, as it runs, never the
  // scene in the editor below (another scene loaded, or a field edited, changes only what
  // the next Start runs)
  const box = $("sliders-for");
  const st = state.status;
  const editor = `${state.scene || "the scene"}${state.editorChanged ? ", edited" : ""}`;
  box.replaceChildren();
  const line = (text, cls) => box.append(Object.assign(document.createElement("div"),
                                                       { textContent: text, className: cls }));
  if (!st) {
    line("Live parameters: no run selected. They act on a running run, not on the scene " +
         "in the editor: Start run, then move them.", "subject");
    box.classList.remove("other");
    return;
  }
  const ran = `${st.scene}${st.edited ? ", unsaved edits" : ""}`;
  line(`Live parameters of run ${st.id} (${ran}; ${st.state})`, "subject");
  const other = st.scene !== state.scene || state.editorChanged;
  box.classList.toggle("other", other);
  if (other)
    line(`Not the editor's scene (${editor}): they change run ${st.id} only. ` +
         "Start run runs the editor's scene.", "warn");
}

function paramRow(name, r, text) {
  // one live parameter: its slider, its value and the result beside it
  const row = document.createElement("div");
  row.className = "param";
  row.dataset.name = name;
  const label = document.createElement("label");
  // the value, also typed: an exact value without dragging (a tap on a touch screen's
  // slider moved a running run's holder force to wherever it landed)
  const out = Object.assign(document.createElement("input"), {
    type: "text", inputMode: "decimal", className: "param-box", value: "1", disabled: true });
  out.setAttribute("aria-label", `${text} value`);
  const result = document.createElement("span");
  const inp = document.createElement("input");
  // the whole range the server accepts (load_scale goes to 100), in about 1000 steps of a
  // round size, so that 1 (as written) is one of them whatever the lowest value
  const step = 10 ** Math.floor(Math.log10((r.max - r.min) / 1000));
  Object.assign(inp, { type: "range", name, min: r.min, max: r.max, step, value: 1,
                       disabled: true });
  inp.id = `param-${name}`;
  out.id = `param-${name}-value`;
  result.id = `param-${name}-result`;
  result.className = "param-result";
  inp.dataset.label = text;
  inp.oninput = () => {
    inp.dataset.busy = "1";
    result.classList.remove("error");
    out.value = inp.value;
    showResult(name, +inp.value, state.status);
  };
  inp.onchange = () => setParameter(inp, out);
  // typed: set on Enter only; Escape, or leaving the box, puts the run's value back (a
  // change to a running run is never made by a stray tap or a Tab)
  const revert = () => {
    delete inp.dataset.busy;
    showValue(inp, out, state.status && state.status.parameters[name], true);
    showResult(name, +inp.value, state.status);
  };
  out.oninput = () => { inp.dataset.busy = "1"; result.classList.remove("error"); };
  out.onblur = () => { if (inp.dataset.busy) revert(); };
  out.onkeydown = (ev) => {
    if (ev.key === "Escape") { revert(); return; }
    if (ev.key !== "Enter") return;
    const typed = out.value.trim(), v = Number(typed.replace(",", "."));
    if (typed === "" || !Number.isFinite(v) || v < r.min || v > r.max) {
      // said beside the box (on a phone the page's message line is far above it) and there
      const why = `${text}: ${typed || "nothing"} is not a number from ${r.min} to ${r.max}`;
      say(why, true);
      revert();
      result.textContent = why;
      result.classList.add("error");
      // the result line comes back after a while (and with the next edit, or another run),
      // and the header's line goes with it (it stood after the run had ended, a review)
      const said = $("msg").textContent;
      setTimeout(() => {
        result.classList.remove("error");
        if ($("msg").textContent === said) say("");
      }, 12000);
      return;
    }
    if (result.classList.contains("error") && $("msg").textContent === result.textContent)
      say("");  // the value typed right now: the refusal of the last one goes
    result.classList.remove("error");
    inp.value = v;
    showResult(name, v, state.status);
    setParameter(inp, out, v).then(() => out.blur());
  };
  const span = document.createElement("span");
  span.className = "param-name";
  span.textContent = text;
  label.title = `${name}: ${r.hint || ""}`;
  label.append(span, inp, out);
  row.append(label, result);
  return row;
}

function toolSliders(st) {
  // the run's per-tool parameters (friction_scale.die): a slider each, for this run's tools
  const per = state.config.tool_parameters || {};
  const names = Object.keys(st.parameters || {}).filter((k) => k.split(".")[0] in per);
  for (const row of $("sliders").querySelectorAll(".param[data-name*='.']"))
    if (!names.includes(row.dataset.name)) row.remove();
  for (const name of names) {
    if ($(`param-${name}`)) continue;
    const [base, tool] = [name.split(".")[0], name.slice(name.indexOf(".") + 1)];
    const r = per[base];
    $("sliders").appendChild(paramRow(name, r, `${r.label} ${tool}`));
  }
}

// the scene's value each multiplier scales, and the result, in the units engineers read
const SCALED_UNITS = { "m/step": ["mm/step", 1e3], N: ["kN", 1e-3], Pa: ["MPa", 1e-6],
                       "m/s^2": ["m/s²", 1], "1": ["", 1] };
const num = (v) => String(+v.toPrecision(4));

function showResult(name, value, st) {
  // friction 0.1 × 2 = 0.2 for each tool; the run's step count under tool_speed
  const box = $(`param-${name}-result`);
  if (!box || box.classList.contains("error")) return;  // a refusal stands until the next edit
  const items = (st && st.scaled && st.scaled[name]) || [];
  const parts = items.map((it) => {
    const [unit, f] = SCALED_UNITS[it.unit] || [it.unit, 1];
    const u = unit ? ` ${unit}` : "";
    // the other multipliers of the same value (a tool's friction: run-wide and its own),
    // where they are not 1
    const also = (it.also || []).map((a) => (st.parameters || {})[a] ?? 1).filter((a) => a !== 1);
    const factors = [value, ...also];
    const result = factors.reduce((p, a) => p * a, it.value * f);
    return `${it.what} ${num(it.value * f)} × ${factors.map(num).join(" × ")} = ${num(result)}${u}`;
  });
  if (name === "tool_speed" && st && st.n_steps) parts.push(`run: ${st.n_steps} steps`);
  // a multiplier of nothing in this run's scene (Load × on a cup without loads) says so
  if (st && Object.keys(st.scaled || {}).length && !parts.length)
    parts.push("nothing in this run's scene to scale");
  box.textContent = parts.join("; ");
  box.title = box.textContent;
}

async function setParameter(inp, out, value = +inp.value) {
  // ``value``: the slider's, or the one typed (the slider rounds to its step)
  const run = state.run;
  const what = inp.dataset.label;
  state.paramSeq++;
  try {
    if (!Owner.allow(state.status, `Set ${what} on`)) throw new Error("not changed");
    const r = await api("PUT", `/api/runs/${run}/parameters/${inp.name}`, { value });
    say((r.applied ? `${what} ${r.value} from step ${r.applies_from_step}`
                   : `${what} ${r.value} from the next step (the solver is mid-step)`) +
        (r.notice ? `; ${r.notice}` : ""));
  } catch (e) {
    say(e.message, true);
    showValue(inp, out, state.status && state.status.parameters[inp.name], true);  // unchanged
  } finally {
    delete inp.dataset.busy;
    state.paramSeq++;
  }
}

function showValue(inp, out, value, typed = false) {
  // ``typed``: over a value being typed too (the server refused it)
  if (value === undefined || value === null) return;
  inp.value = value;
  if (typed || document.activeElement !== out) out.value = String(+(+value).toPrecision(6));
}

function showParameters(st, paramSeq = state.paramSeq) {
  // the sliders follow the run's values, except one being moved or a change the solver has
  // not answered yet (the status would show the value before it)
  const active = ACTIVE.includes(st.state);
  const settled = paramSeq === state.paramSeq && !(st.pending || []).includes("set");
  showSlidersFor();
  toolSliders(st);
  for (const inp of document.querySelectorAll("#sliders input[type=range]")) {
    const box = $(`param-${inp.name}-value`);
    inp.disabled = box.disabled = !active;
    inp.title = box.title = active ? "" : `run ${st.id} is ${st.state}: its values, as it ended`;
    if (settled && !inp.dataset.busy)
      showValue(inp, $(`param-${inp.name}-value`), st.parameters[inp.name]);
    if (!inp.dataset.busy) showResult(inp.name, st.parameters[inp.name] ?? +inp.value, st);
  }
}

async function loadRuns() {
  RunsTable.show(await api("GET", "/api/runs"), state.run);  // runs.js
}

async function selectRun(id) {
  // a click in the Runs table: this view's selection, which its viewer shows too
  const seq = ++state.viewSeq;
  try {
    const v = await api("PUT", "/api/view", { run: id });
    if (seq === state.viewSeq) adoptRun(v.run);
    say("");  // a message about the run shown before would read as about this one
    pollNow();
    // one column (a phone): the run's headline and view are far above the Runs table
    if (matchMedia("(max-width: 820px)").matches) $("centre").scrollIntoView({ block: "start" });
  } catch (e) { say(e.message, true); }
}

function adoptRun(id) {
  // the selection the server holds for this view, from this page's click or its viewer's
  if (state.run !== id) {
    state.run = id;
    state.status = null;
    Results.forget();  // nothing of the run shown before stays on screen
    for (const r of document.querySelectorAll("#sliders .param-result.error"))
      r.classList.remove("error");  // a refusal of a value for the run shown before
  }
  for (const tr of $("runs").querySelectorAll("tbody tr"))
    tr.className = tr.dataset.id === id ? "sel" : "";
}

async function followView() {
  const seq = state.viewSeq;
  const v = await api("GET", `/api/view?since=${state.noticeSeq}`);
  Owner.showNotices(v.notices);
  if (seq !== state.viewSeq) return;
  state.previewing = v.scene;  // the scene this page's viewer previews (null: a run)
  // a preview the solver could not build (a tool inside the blank, a drawing it cannot
  // mesh) is said here as a refused one is, once; it goes with the next preview taken
  if (v.preview === "failed" && v.scene === state.scene &&
      state.previewFailed !== state.previewSeq) {
    state.previewFailed = state.previewSeq;
    say(`preview of ${v.scene}: ${v.preview_error}`, true);
    $("msg").dataset.preview = v.scene;
    markRefused(v.preview_error);
  }
  adoptRun(v.run);
  // the headline and plots are the run's; the 3-D view below them may be a scene's preview
  const other = v.scene && v.run;
  $("previewing").hidden = !other;
  if (other) $("previewing").textContent = `The 3-D view shows a preview of scene ${v.scene}, ` +
    `not this run: click the run in the Runs table to draw it there.`;
  // the step this page's 3-D view was scrubbed to: marked on the run's plots
  Plots.scrubAt(v.run === state.run && !v.scene ? v.step : null);
}

async function poll() {
  try {
    // the runs list beside the view and its run: each request waits on a browser whose
    // main thread also draws the 3-D view, and one after another they left the headline
    // several steps behind the viewer
    await Promise.all([loadRuns(), followView().then(
      () => (state.run ? showRun(state.run) : showNoRun()))]);
  } catch (e) { say(e.message, true); }
  // at most a few polls a second, however fast the run steps; sooner than half a second when
  // something happened meanwhile (a click, a step of the run shown)
  await new Promise((ok) => setTimeout(ok, 150));
  if (!state.nudged) await new Promise((ok) => { state.nudge = ok; setTimeout(ok, 350); });
  state.nudged = false;
  state.nudge = null;
  poll();
}

function pollNow() {
  // a run selected: the next poll at once, not half a second later (headline, sliders and
  // plots then follow the click together)
  state.nudged = true;
  if (state.nudge) state.nudge();
}

function followEvents(st) {
  // the run shown, while it goes: its steps as the server has them (server-sent events) wake
  // the poll, so the headline follows the 3-D view, which the solver's frames reach at once.
  // Not in a hidden tab: each stream holds one of the browser's six connections to the server
  const id = st && ACTIVE.includes(st.state) && !document.hidden ? st.id : null;
  if (state.events && state.events.run === id) return;
  if (state.events) state.events.source.close();
  state.events = null;
  if (!id) return;
  const source = new EventSource(`/api/runs/${encodeURIComponent(id)}/events?since=${st.step}`);
  for (const e of ["step", "state", "end"]) source.addEventListener(e, pollNow);
  state.events = { run: id, source };
}

async function showRun(id) {
  // the status without the records it had (the plots read theirs from /plots); a selection
  // that moved meanwhile drops what was read for the old one
  const paramSeq = state.paramSeq;
  const since = state.status && state.status.id === id ? state.status.step : 0;
  const st = await api("GET", `/api/runs/${id}?since=${since}&limit=1`);
  if (state.run !== id) return;
  state.status = st;
  followEvents(st);
  if ($("msg").dataset.run === id && !ACTIVE.includes(st.state) && st.state !== "queued")
    say("");
  Owner.showTouched(st);
  RunsTable.update(st);
  showControls(st);
  showParameters(st, paramSeq);
  await Results.show(st);
}

function showControls(st) {
  // the commands that act on the run now, as the server says (server.records.Run.controls)
  for (const a of ["pause", "resume", "step", "stop"])
    $(a).disabled = !(st.controls || []).includes(a);
}

function showNoRun() {
  Results.none();
  state.status = null;
  followEvents(null);
  showSlidersFor();
  Owner.showTouched(null);
  for (const a of ["pause", "resume", "step", "stop"]) $(a).disabled = true;
}

async function previewFirst() {
  // a first look with no run to show: the chosen scene at rest in 3-D, not an empty box
  // (once the solver process is up: it builds the preview); a run chosen meanwhile stays,
  // and a preview of another scene (this tab's before a reload) gives way to the editor's
  if (!$("viewer") || !state.scene) return;  // no viewer here (off, or not reachable)
  const v = await api("GET", "/api/view");
  if (!v.run && v.scene !== state.scene) previewScene(state.scene);
}

function viewerOff(why) {
  // no 3-D view here (--no-viewer, or a viewer this browser cannot reach): the box says why
  // and what to do where the view would be, rather than stay blank (the plots, the summary
  // and the downloads need no viewer)
  $("viewer").remove();
  $("full-window").hidden = true;
  $("preview-scene").hidden = true;  // nothing to preview in
  const box = $("viewer-box");
  box.classList.add("off");
  const p = (html) => Object.assign(document.createElement("p"), { innerHTML: html });
  box.append(...why.map(p), p("Runs, their plots, summary and downloads work without it."));
}

const OFF = [
  "<strong>The 3-D viewer is off</strong>: this server was started with " +
    "<code>q3t serve --no-viewer</code>.",
  "To see the runs in 3-D here, restart it without <code>--no-viewer</code> " +
    "(the viewer listens on <code>--viewer-port</code>, 8081 unless given)."];

const UNREACHABLE = (port) => [
  "<strong>The 3-D viewer is not reachable from this machine</strong>: it listens on the " +
    `server's own 127.0.0.1:${port} only (the viewer has no token check, so ` +
    "<code>q3t serve</code> keeps it off the network).",
  `Forward the port (<code>ssh -L ${port}:127.0.0.1:${port} SERVER</code>, and the page's ` +
    "port the same way, then open the page as <code>http://127.0.0.1:…</code>), or, on a " +
    "network you trust, restart the server with <code>--expose-viewer</code>."];

function loopbackHost(host) {
  // the page's own host: a browser on the server's machine can reach its loopback viewer
  // (0.0.0.0 and *.localhost name this machine too: browsers connect them to loopback)
  return host === "localhost" || host.endsWith(".localhost") || /^127\./.test(host) ||
    host === "[::1]" || host === "::1" || host === "0.0.0.0";
}

async function main() {
  state.config = await api("GET", "/api/config");
  for (const e of state.config.elements) {
    const o = document.createElement("option");
    o.value = o.textContent = e;
    o.selected = e === state.config.default_element;
    o.title = state.config.element_notes[e] || "";
    $("element").appendChild(o);
  }
  $("element").addEventListener("change", showElementNote);
  showElementNote();
  const solverUp = buildSliders().catch((e) => say(e.message, true));
  const vport = state.config.viewer_port;
  if (!vport) viewerOff(OFF);
  else if (state.config.viewer_loopback && !loopbackHost(location.hostname)) {
    viewerOff(UNREACHABLE(vport));
  } else {
    // the viewer's websocket path names this tab's view: it shows this page's run, colour
    // mode and step, and another browser's viewer its own
    const host = `${location.hostname}:${vport}`;
    const ws = `${location.protocol === "https:" ? "wss" : "ws"}://${host}/view/${VIEW}`;
    $("viewer").src = `${location.protocol}//${host}/?websocket=${encodeURIComponent(ws)}`
      + viewerDensity();
  }
  $("notice-close").onclick = () => { $("notice").hidden = true; };
  Layout.init();
  Results.init();
  RunsTable.init({ select: selectRun, say, reload: loadRuns });
  $("save").onclick = saveScene;
  $("preview-scene").onclick = previewEditor;
  state.form = new SceneForm.Form($("scene-form"), await api("GET", "/api/scenes/schema"),
                                  () => { editorEdited(); scheduleSync(syncFromForm, 300); },
                                  suggestNames);
  $("toml").oninput = () => { editorEdited(); scheduleSync(syncFromToml, 400); };
  $("tab-form").onclick = () => showTab("form");
  $("tab-toml").onclick = () => showTab("toml");
  $("duplicate").onclick = async () => {
    const name = prompt("name of the copy", `${state.scene}-copy`);
    if (!name) return;
    try {
      // the copy is of what the editor holds: its unsaved edits go with it, not lost
      const body = { name };
      if (state.unsaved) { await flushSync(); body.toml = $("toml").value; }
      const from = state.scene;
      await api("POST", `/api/scenes/${from}/duplicate`, body);
      state.scene = name;
      await loadScenes();
      await selectScene(name);
      // the viewer previewed the original: it shows the copy the editor now holds
      if (state.previewing === from) previewScene(name);
      say(`duplicated ${from} as ${name}`);  // in place of an earlier refusal's words
    } catch (e) { say(e.message, true); }
  };
  $("delete-scene").onclick = async () => {
    try {
      // its runs stay, each with its own copy of the scene: said, so the question is not
      // read as deleting them
      const runs = (await api("GET", "/api/runs")).filter((r) => r.scene === state.scene);
      const kept = runs.length ? ` Its ${runs.length === 1 ? "run stays" : `${runs.length} ` +
        "runs stay"} in the Runs table, with the scene as it ran.` : "";
      if (!confirm(`Delete scene ${state.scene}?${kept}`)) return;
      const previewed = state.previewing === state.scene;
      const gone = state.scene;
      await api("DELETE", `/api/scenes/${gone}`);
      state.scene = null;
      await loadScenes();
      say(`deleted scene ${gone}`);
      // not the deleted scene's preview left in the viewer; a run it shows stays
      if (previewed && state.scene) previewScene(state.scene);
    } catch (e) { say(e.message, true); }
  };
  $("start").onclick = startRun;
  for (const a of ["pause", "resume", "step", "stop"]) $(a).onclick = () => control(a);
  await loadScenes();
  poll();
  solverUp.then(previewFirst).catch((e) => say(e.message, true));
}

document.addEventListener("visibilitychange", () => followEvents(state.status));

// a reload or a closed tab would drop the editor's unsaved edits: the browser asks first
window.addEventListener("beforeunload", (ev) => {
  if (state.unsaved) ev.preventDefault();
});
main().catch((e) => say(e.message, true));
