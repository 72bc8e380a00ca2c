// Runs compared side by side. A "Compare runs" panel under the Runs table: tick two or more
// runs (the first ticked is the reference, A), or open the cases of a q3t sweep as runs; then
// a view over the window: what differs between them, their summaries with each run's
// difference from A, their force-stroke curves and probes on shared axes, and their final
// thickness on the formed part with an A / B / A − B toggle (the camera stays where it is);
// below, A and B side by side at the same punch stroke (a slider over the strokes both saved
// frames for), their thickness on one colour scale and A − B, the cameras moving together.
// Everything drawn is the server's (/api/compare, /api/compare/thickness,
// /api/compare/frames), in mm, kN, MPa, %.
"use strict";
const Compare = (() => {
  const ACTIVE = ["starting", "building", "running", "paused"];
  const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b",
                   "#e377c2", "#17becf"];
  const DASHES = ["solid", "dash", "dot", "dashdot"];
  const CONFIG = { displaylogo: false, responsive: true,
                   modeBarButtonsToRemove: ["lasso2d", "select2d", "autoScale2d"] };
  const FONT = { family: "system-ui, sans-serif", size: 11 };
  const picked = [];  // the ticked run ids, in the order ticked: the first is A
  const view = { runs: null, data: null, thickness: null, show: "diff", shape: "formed",
                 against: 1, camera: null, timer: null, seq: 0,
                 stroke: null, strokeKey: null, strokeSeq: 0, strokeDigits: 3,
                 strokeTicks: null,
                 bounds: null };
  // the 3-D views whose cameras move together: the final thickness and the views at a stroke
  // the views at a stroke: from the front, a little to the right and above, the whole part
  // and its axes beside a colour bar
  const EYE = { x: 0.6, y: -1.3, z: 1.05 };
  // plotly's RdBu runs from blue (low) to red (high): reversed, A − B < 0 (A thinner) is red
  const THINNER_RED = { colorscale: "RdBu", reversescale: true };
  // a difference map's colour range at least ±1 um (mm): two equal parts' read "±0.000000001"
  const ZERO_MM = 1e-3;
  const VIEWS3D = ["compare-thickness", "compare-3d-a", "compare-3d-b", "compare-3d-diff"];
  const el = (tag, props = {}, ...kids) => {
    const e = Object.assign(document.createElement(tag), props);
    e.append(...kids);
    return e;
  };
  const $ = (id) => document.getElementById(id);
  const colour = (i) => COLOURS[i % COLOURS.length];
  const letter = (i) => String.fromCharCode(65 + i);

  // ---- the panel: which runs ---------------------------------------------------------------
  function panel() {
    const box = el("details", { id: "compare-box" },
      el("summary", { textContent: "Compare runs" }),
      el("p", { className: "muted hint", textContent: "Tick two or more runs; the first " +
                "ticked is the reference (A)." }),
      el("div", { id: "compare-filter", className: "row", hidden: true },
         el("label", {}, "Scene ", el("select", { id: "compare-scene" }))),
      el("div", { className: "compare-scroll" },
         el("table", { id: "compare-runs" }, el("tbody"))),
      el("div", { className: "row" },
         el("button", { id: "compare-open", className: "primary", disabled: true,
                        textContent: "Compare" }),
         el("button", { id: "compare-clear", textContent: "Clear" })),
      el("div", { id: "compare-sweeps", className: "row", hidden: true },
         el("label", {}, "Sweep ", el("select", { id: "compare-sweep" })),
         el("button", { id: "compare-import", textContent: "Open its cases as runs" })),
      el("div", { id: "compare-msg", className: "muted", role: "status" }));
    $("runs-box").after(box);
    box.addEventListener("toggle", () => { if (box.open) refreshPanel(); });
    $("compare-open").onclick = () => open([...picked]);
    $("compare-clear").onclick = () => { picked.length = 0; refreshPanel(); };
    $("compare-import").onclick = importSweep;
    $("compare-scene").onchange = refreshPanel;
  }

  function said(text, isError) {
    $("compare-msg").textContent = text;
    $("compare-msg").classList.toggle("error", !!isError);
  }

  function describe(r) {
    // what tells runs of one scene apart: the element, what it changed of the scene (as the
    // Runs table says it: overrides in the form's units, live parameters, unsaved edits), the
    // time it started
    const when = new Date(r.created * 1000).toLocaleTimeString([], { hour12: false });
    return { main: `${r.scene} · ${r.element}`,
             more: [...RunsTable.changes(r), when].join(" · ") };  // runs.js
  }

  async function refreshPanel() {
    let runs;
    try {
      runs = await api("GET", "/api/runs");
    } catch (e) { return said(e.message, true); }
    const ids = new Set(runs.map((r) => r.id));
    for (let i = picked.length - 1; i >= 0; i--) if (!ids.has(picked[i])) picked.splice(i, 1);
    const body = $("compare-runs").querySelector("tbody");
    body.replaceChildren(...shownRuns(runs).map(runRow));
    $("compare-open").disabled = picked.length < 2;
    $("compare-open").textContent = picked.length >= 2 ? `Compare ${picked.length} runs`
                                                       : "Compare";
    await refreshSweeps();
  }

  function shownRuns(runs) {
    // runs of many scenes: a scene's runs alone, those ticked of others staying in sight
    // (a comparison across scenes is allowed; what is ticked is never hidden)
    const count = new Map();
    for (const r of runs) count.set(r.scene, (count.get(r.scene) || 0) + 1);
    const sel = $("compare-scene"), was = sel.value;
    const names = [...count.keys()].sort();
    const n = (k) => `${k} run${k === 1 ? "" : "s"}`;
    sel.replaceChildren(
      el("option", { value: "", textContent: `all (${n(runs.length)})` }),
      ...names.map((name) => el("option", { value: name,
                                         textContent: `${name} (${n(count.get(name))})` })));
    sel.value = count.has(was) ? was : "";
    $("compare-filter").hidden = names.length < 2;
    return sel.value ? runs.filter((r) => r.scene === sel.value || picked.includes(r.id))
                     : runs;
  }

  function runRow(r) {
    const k = picked.indexOf(r.id);
    const box = el("input", { type: "checkbox", checked: k >= 0, value: r.id });
    box.setAttribute("aria-label", `compare ${r.id}`);
    box.onchange = () => {
      const at = picked.indexOf(r.id);
      if (box.checked && at < 0) picked.push(r.id);
      if (!box.checked && at >= 0) picked.splice(at, 1);
      refreshPanel();
    };
    const d = describe(r);
    const tag = el("span", { className: "letter", textContent: k >= 0 ? letter(k) : "" });
    if (k >= 0) tag.style.background = colour(k);
    const name = el("label", { title: r.id }, box, tag,
                    el("span", { className: "what", textContent: d.main }),
                    el("span", { className: "more", textContent: d.more }));
    return el("tr", { className: k >= 0 ? "picked" : "" },
              el("td", {}, name), el("td", { className: "state", textContent: r.state }));
  }

  async function refreshSweeps() {
    const sweeps = await api("GET", "/api/sweeps").catch(() => []);
    $("compare-sweeps").hidden = !sweeps.length;
    const sel = $("compare-sweep"), was = sel.value;
    sel.replaceChildren(...sweeps.map((s) => el("option", {
      value: s.path, selected: s.path === was,
      textContent: `${s.path} (${s.scene}, ${s.with_results} cases, ${s.imported} open)`,
      title: `${s.path}: ${s.scene}, ${s.cases} cases, ${s.with_results} with results, ` +
             `${s.imported} open as runs; grid ${Object.keys(s.grid).join(", ")}` })));
  }

  async function importSweep() {
    const path = $("compare-sweep").value;
    try {
      const r = await api("POST", "/api/sweeps/import", { path });
      const skipped = r.skipped.length ? `; ${r.skipped.length} case(s) without a result ` +
        `(${r.skipped.map((s) => `case ${s.case}: ${s.reason}`).join("; ")})` : "";
      said(`${path}: ${r.imported.length} case(s) opened as runs, ${r.present.length} ` +
           `already open${skipped}`);
      for (const id of [...r.imported, ...r.present]) if (!picked.includes(id)) picked.push(id);
      await refreshPanel();
    } catch (e) { said(`${path}: ${e.message}`, true); }
  }

  // ---- the view: the runs side by side -------------------------------------------------------
  function overlay() {
    const sec = el("section", { id: "compare-view", hidden: true },
      el("div", { className: "compare-head" },
         el("h2", { id: "compare-title" }),
         el("button", { id: "compare-close", textContent: "Close (Esc)" })),
      el("div", { id: "compare-chips" }),
      el("p", { id: "compare-differs" }),
      // in view on a laptop's window: the numbers, the force curves and the thickness map
      el("div", { className: "compare-grid" },
         el("div", { className: "compare-col" },
            el("div", { id: "compare-summary" }),
            el("figure", { id: "compare-probes-fig" },
               el("div", { id: "compare-probes", className: "plot" }))),
         el("div", { className: "compare-col" },
            el("figure", { id: "compare-force-fig" },
               el("div", { id: "compare-force", className: "plot" })),
            el("figure", {}, el("div", { id: "compare-thickness", className: "plot" }),
               el("div", { id: "compare-thickness-controls", className: "row" })))),
      strokePanel());
    document.body.append(sec);
    $("compare-close").onclick = close;
    document.addEventListener("keydown", (ev) => {
      if (ev.key === "Escape" && !$("compare-view").hidden) close();
    });
  }

  async function open(ids) {
    view.runs = ids;
    view.against = 1;
    view.show = "diff";
    view.data = view.thickness = view.camera = view.stroke = view.strokeKey = null;
    $("compare-view").hidden = false;
    document.body.classList.add("comparing");
    $("compare-title").textContent = "Comparing…";
    for (const id of ["compare-force", "compare-probes", ...VIEWS3D])
      unplot($(id));
    await refresh();
  }

  function close() {
    clearTimeout(view.timer);
    view.seq++;  // an answer on its way is for a view no longer open
    view.strokeSeq++;
    $("compare-view").hidden = true;
    document.body.classList.remove("comparing");
  }

  async function refresh() {
    // a run still going is redrawn as it goes; the others are drawn once
    clearTimeout(view.timer);
    const seq = ++view.seq;
    let data;
    try {
      data = await api("GET", `/api/compare?runs=${view.runs.map(encodeURIComponent)}`);
    } catch (e) {
      $("compare-title").textContent = "Cannot compare";
      $("compare-differs").textContent = e.message;
      return;
    }
    if (seq !== view.seq) return;
    view.data = data;
    header(data);
    summary(data);
    await forceStroke(data);
    await probes(data);
    await thickness(data);
    await atStroke(data);
    if (data.runs.some((r) => ACTIVE.includes(r.state)))
      view.timer = setTimeout(() => { if (seq === view.seq) refresh(); }, 1500);
  }

  function header(data) {
    $("compare-title").textContent = `Comparing ${data.runs.map((r) => r.letter).join(", ")}`;
    $("compare-chips").replaceChildren(...data.runs.map((r, i) => {
      const tag = el("span", { className: "letter", textContent: r.letter });
      tag.style.background = colour(i);
      const chip = el("div", { className: "chip", title: r.id }, tag,
        el("span", { className: "id", textContent: r.id }),
        el("span", { className: "muted", textContent: ` ${r.element}, ${r.state}, step ` +
                     `${r.step}/${r.n_steps ?? "?"}` }));
      if (r.note) chip.append(el("span", { className: "note", textContent: ` — ${r.note}` }));
      return chip;
    }));
    const d = $("compare-differs");
    d.textContent = data.differs.line;
    d.dataset.items = String(data.differs.items.length);
    // every differing setting, in the form's units (the line names the first few)
    d.title = data.differs.items.map((it) => `${it.what}: ${it.values
      .map((v) => (v === null ? "unset" : Array.isArray(v) && !v.length ? "none"
        : Units.sceneValue(v, it.unit || ""))).join(" | ")}`)
      .join("\n");
  }

  // ---- the summaries --------------------------------------------------------------------------
  function fmt(v, unit) {
    return v === null || v === undefined ? "–" : Units.withUnit(v, unit);
  }

  function signed(v, digits = 3) {
    if (v === null || v === undefined) return "–";
    return (v > 0 ? "+" : v < 0 ? "−" : "±") + Units.num(Math.abs(v), digits);
  }

  const MESH_FLAG = "mostly the mesh's: its six-fold wave is larger than the four ears " +
                    "(a blank meshed in one lattice)";

  function cell(row, i) {
    // the run's value; below it, for B, C, ...: its difference from A and that in % of A's
    const td = el("td", { className: "num" },
                  el("div", { className: "value", textContent: fmt(row.values[i], "") }));
    if (row.at[i]) td.title = row.at[i];
    const flag = row.flags && row.flags[i];
    if (flag) {
      td.classList.add(`flag-${flag}`);
      if (flag === "mesh") {
        td.append(el("div", { className: "flag-word", textContent: "the mesh's" }));
        td.title = [td.title, MESH_FLAG].filter(Boolean).join("\n");
      }
    }
    if (!i) return td;
    const big = row.delta_pct[i] !== null && Math.abs(row.delta_pct[i]) >= 5;
    const unit = row.unit === "%" ? " pt" : row.unit ? ` ${row.unit}` : "";
    const pct = row.delta_pct[i] === null ? "" : ` (${signed(row.delta_pct[i], 2)} %)`;
    td.append(el("div", { className: "delta" + (big ? " big" : ""),
                          textContent: row.delta[i] === null ? "–"
                                       : `${signed(row.delta[i])}${unit}${pct}` }));
    return td;
  }

  function summary(data) {
    const runs = data.runs;
    const head = el("tr", {}, el("th", { textContent: "quantity (unit)" }),
      ...runs.map((r, i) => {
        const tag = el("span", { className: "letter", textContent: r.letter });
        tag.style.background = colour(i);
        const th = el("th", { className: "num" }, tag);
        // a run that did not finish: its values are where it ended, not the stroke's end
        if (r.state !== "finished")
          th.append(el("div", { className: "sub ended", textContent: `${r.state} at step ` +
                                `${r.step}${r.n_steps ? ` of ${r.n_steps}` : ""}` }));
        if (i) th.append(el("div", { className: "sub", textContent: `${r.letter} − A (% of A)` }));
        return th;
      }));
    const rows = data.summary.map((row) => {
      const label = row.label + (row.tool ? ` (${row.tool})` : "") +
                    (row.unit ? ` (${row.unit})` : "");
      const tr = el("tr", { title: row.note || "" }, el("th", { textContent: label }),
                    ...runs.map((_, i) => cell(row, i)));
      tr.dataset.name = row.name;
      return tr;
    });
    const table = el("table", { className: "compare-table" }, el("thead", {}, head),
                     el("tbody", {}, ...rows));
    const box = $("compare-summary");
    const none = runs.filter((r) => !r.result).map((r) => r.letter);
    // the table as a file, for a report or a spreadsheet (the values as shown, in their units)
    const csv = el("a", { id: "compare-csv", textContent: "Download CSV", download: "",
                          href: "/api/compare/summary.csv?runs=" +
                                runs.map((r) => encodeURIComponent(r.id)).join(","),
                          title: "this table: each quantity per run and its difference from A" });
    box.replaceChildren(el("h3", {}, "Summary ", csv), table);
    if (none.length)
      box.append(el("p", { className: "muted", textContent: `${none.join(", ")}: no summary ` +
                           "yet (see the note above); its column shows –." }));
    // a run that ended early holds the part at its last step: no difference from A's
    const unlike = runs.filter((r, i) => i && r.result && !r.comparable);
    const ended = (r) => (r.state === "finished" ? `${r.letter} finished`
      : `${r.letter} ${r.state} at step ${r.step}` + (r.n_steps ? ` of ${r.n_steps}` : ""));
    if (unlike.length && data.summary.some((row) => row.values[0] !== null))
      box.append(el("p", { id: "compare-unlike", className: "caution", role: "note",
        textContent: `${[runs[0], ...unlike].map(ended).join("; ")}: each value is the part ` +
          "where its run ended, so no difference from A is taken for " +
          `${unlike.map((r) => r.letter).join(", ")} (–), except the mesh's size.` }));
    // every difference is from A: without A's summary the table has none to show
    if (data.summary.length && data.summary.every((row) => row.values[0] === null))
      box.append(el("p", { className: "caution", role: "note", textContent: "A has no " +
                           "summary, so no difference from it can be taken: tick a run with a " +
                           "result first to compare the others against it." }));
  }

  // ---- the curves -----------------------------------------------------------------------------
  const MARGIN = { l: 60, r: 16, t: 34, b: 42 };

  function layout(title, height, extra) {
    return { title: { text: title, font: { size: 13 }, x: 0.02, yref: "container", y: 1,
                      yanchor: "top", pad: { t: 9 } }, height, autosize: true,
             font: FONT, margin: MARGIN, hovermode: "closest",
             legend: { orientation: "h", y: -0.22, font: { size: 10 } }, ...extra };
  }

  function axis(text, extra) {
    return { title: { text, standoff: 6 }, zeroline: false, automargin: true, ...extra };
  }

  function runIndex(data, id) {
    return data.runs.findIndex((r) => r.id === id);
  }

  async function forceStroke(data) {
    const curves = data.punches.filter((p) => p.force.values.length);
    $("compare-force-fig").hidden = !curves.length;
    if (!curves.length) return;
    const tools = new Set(curves.map((p) => p.tool));
    const byStroke = curves.every((p) => p.stroke);
    const traces = curves.map((p) => {
      const i = runIndex(data, p.run);
      return { x: byStroke ? p.stroke.values : p.steps, y: p.force.values, type: "scatter",
               mode: "lines+markers", marker: { size: 4 }, customdata: p.steps,
               name: tools.size > 1 ? `${p.letter}: ${p.tool}` : p.letter,
               line: { color: colour(i), dash: DASHES[[...tools].indexOf(p.tool) % 4] },
               hovertemplate: (byStroke ? "stroke %{x:.3f} mm<br>" : "") +
                 "force %{y:.4g} kN<br>step %{customdata}<extra>%{fullData.name}</extra>" };
    });
    await plotInto($("compare-force"), traces, layout("Punch force against stroke", 300, {
      xaxis: axis(byStroke ? "punch stroke (mm)" : "step", { rangemode: "tozero" }),
      yaxis: axis(`punch force (${curves[0].force.unit})`, { rangemode: "tozero" }),
      ...liveMarks(data, curves, byStroke) }), CONFIG);
  }

  function liveMarks(data, curves, byStroke) {
    // each run's live parameter changes, in its colour, where its punch was when the change
    // took effect (the end of the step before)
    const shapes = [], annotations = [];
    data.runs.forEach((r, i) => {
      const punch = curves.find((p) => p.run === r.id);
      for (const e of (punch && data.differs.live[r.letter]) || []) {
        const k = punch.steps.indexOf(e.step - 1);
        const x = !byStroke ? e.step - 0.5 : e.step <= 1 ? 0 : k < 0 ? null
                                                              : punch.stroke.values[k];
        if (x === null) continue;
        shapes.push({ type: "line", xref: "x", yref: "paper", x0: x, x1: x, y0: 0, y1: 1,
                      line: { color: colour(i), width: 1.5, dash: "dot" } });
        annotations.push({ ...Plots.markLabel(annotations.length), x,
                           font: { size: 10, color: colour(i) },
                           text: `${r.letter}: ${e.label} ${Units.num(e.value)}` });
      }
    });
    return { shapes, annotations, margin: Plots.markRoom(MARGIN, annotations.length) };
  }

  async function probes(data) {
    // a row per quantity (the probe's kind), the runs' colours, a dash per probe
    const series = data.probes;
    $("compare-probes-fig").hidden = !series.length;
    if (!series.length) return;
    const names = [...new Set(series.map((s) => s.name))];
    const labelled = series.map((s) => ({ ...s, label: `${s.letter}: ${s.name}` }));
    const rows = Plots.quantities(labelled);
    const lay = layout("Probes", 0);
    const { layout: stack, row } = Plots.stacked($("compare-probes").clientWidth, lay.margin, rows);
    const traces = labelled.map((s) => ({
      x: s.steps, y: s.values, type: "scatter", mode: "lines+markers", marker: { size: 3 },
      name: s.label, ...row(rows.findIndex((r) => r.kind === (s.kind || "?"))),
      line: { color: colour(runIndex(data, s.run)), dash: DASHES[names.indexOf(s.name) % 4] },
      hovertemplate: `${s.letter} ${s.name}: %{y:.4g} ${s.unit}<br>step %{x}<extra></extra>` }));
    await plotInto($("compare-probes"), traces, { ...lay, ...stack }, CONFIG);
  }

  // ---- thickness on the formed part ----------------------------------------------------------
  async function thickness(data) {
    const b = view.runs[view.against];
    const key = `${view.runs[0]},${b}`;
    const ended = [0, view.against].every((i) => data.runs[i].result);
    if (!ended) return thicknessMissing(data);
    if (!view.thickness || view.thickness.key !== key) {
      try {
        const t = await api("GET", `/api/compare/thickness?runs=${encodeURIComponent(view.runs[0])},` +
                            `${encodeURIComponent(b)}`);
        // the server letters the two it was sent A and B: here B is the run chosen
        t.b.letter = data.runs[view.against].letter;
        view.thickness = { key, ...t };
      } catch (e) { return thicknessMissing(data, e.message); }
    }
    if (!view.thickness.difference.available && view.show === "diff") view.show = "a";
    thicknessControls(data);
    await drawThickness();
  }

  function thicknessMissing(data, why) {
    const r = data.runs.find((x, i) => (i === 0 || i === view.against) && !x.result);
    const text = why || `${r.letter} has no final state yet: the thickness appears when it ends`;
    unplot($("compare-thickness"));
    $("compare-thickness-controls").replaceChildren(el("p", { className: "muted",
                                                              textContent: text }));
  }

  function toggle(name, options, value, set) {
    // a row of buttons, one pressed (aria-pressed): the A / B / A − B toggle and the shape
    const group = el("span", { className: "toggle", role: "group" });
    group.setAttribute("aria-label", name);
    for (const [v, label, disabled, title] of options) {
      const b = el("button", { textContent: label, disabled: !!disabled, title: title || "" });
      b.dataset.value = v;
      b.setAttribute("aria-pressed", String(v === value));
      b.onclick = () => set(v);
      group.append(b);
    }
    return group;
  }

  function thicknessControls(data) {
    const t = view.thickness, diff = t.difference;
    const redraw = (fn) => (v) => { fn(v); thicknessControls(data); drawThickness(); };
    const shows = [["a", "A: thickness"],
                   ["b", `${t.b.letter}: thickness`],
                   ["diff", `A − ${t.b.letter}`, !diff.available, diff.reason]];
    const kids = [toggle("show", shows, view.show, redraw((v) => { view.show = v; })),
                  toggle("shape", [["formed", "formed part"], ["rest", "blank at rest"]],
                         view.shape, redraw((v) => { view.shape = v; }))];
    if (data.runs.length > 2) {
      const sel = el("select", { "aria-label": "B of the thickness map" },
        ...data.runs.slice(1).map((r, k) => el("option", { value: String(k + 1),
          textContent: `A against ${r.letter}`, selected: k + 1 === view.against })));
      sel.onchange = () => {
        view.against = +sel.value;
        view.show = "diff";
        thickness(data);
        atStroke(data);
      };
      kids.push(sel);
    }
    const note = el("span", { id: "compare-thickness-note", className: "muted" });
    note.textContent = diff.available
      ? `largest |A − ${t.b.letter}| ${Units.num(diff.max_abs)} mm`
      : `no difference map: ${diff.reason}`;
    kids.push(note);
    $("compare-thickness-controls").replaceChildren(...kids);
  }

  function meshTrace(part, values, scale) {
    // hover: [the value coloured, the run's thickness] per vertex
    const P = part[view.shape];
    const F = part.faces;
    return { type: "mesh3d", x: P.map((p) => p[0]), y: P.map((p) => p[1]),
             z: P.map((p) => p[2]), i: F.map((f) => f[0]), j: F.map((f) => f[1]),
             k: F.map((f) => f[2]), intensity: values, intensitymode: "vertex",
             flatshading: false, lighting: { ambient: 0.75, diffuse: 0.35, specular: 0.05 },
             ...scale, name: part.letter,
             customdata: values.map((v, n) => [v, part.thickness[n]]) };
  }

  async function drawThickness() {
    const t = view.thickness, d = t.difference;
    let trace, title;
    if (view.show === "diff" && d.available) {
      const m = Math.max(d.max_abs, ZERO_MM);
      trace = meshTrace(t.a, d.values, {
        ...THINNER_RED, cmin: -m, cmax: m, cmid: 0,
        colorbar: { title: { text: `A − ${t.b.letter}<br>thickness (mm)`, side: "right" },
                    len: 0.85, exponentformat: "none" },
        hovertemplate: `A − ${t.b.letter}: %{customdata[0]:.4f} mm<br>A: ` +
                       "%{customdata[1]:.4f} mm<extra></extra>" });
      title = `Thickness difference A − ${t.b.letter} (red: A thinner, blue: A thicker)`;
    } else {
      const part = view.show === "b" ? t.b : t.a;
      // one scale for A and B, thin in red: the toggle compares colours directly
      trace = meshTrace(part, part.thickness, {
        colorscale: "Jet", reversescale: true, cmin: t.range[0], cmax: t.range[1],
        colorbar: { title: { text: "thickness (mm)", side: "right" }, len: 0.85,
                    exponentformat: "none" },
        hovertemplate: `${part.letter}: %{customdata[1]:.4f} mm<extra></extra>` });
      title = `Final thickness of ${part.letter} (${part.id})`;
    }
    const div = $("compare-thickness");
    div.dataset.show = view.show;
    div.dataset.shape = view.shape;
    // a toggle keeps the camera where the user left it (view.camera, from plotly_relayout)
    const lay = layout(title, 400, {
      margin: { l: 0, r: 0, t: 34, b: 0 },
      scene: { aspectmode: "data", xaxis: { title: { text: "x (mm)" } },
               yaxis: { title: { text: "y (mm)" } }, zaxis: { title: { text: "z (mm)" } },
               camera: view.camera || { eye: { x: 0.7, y: -1.5, z: 1.3 } } } });
    if (await plotInto(div, [trace], lay, CONFIG)) linkCamera(div);
  }

  function linkCamera(div) {
    // moving one 3-D view moves the others: the camera goes to view.camera and to every
    // other view drawn whose camera is not that already (so the echo ends there)
    div.removeAllListeners("plotly_relayout");  // one listener, whether purged or not
    div.on("plotly_relayout", (ev) => {
      // a drag sends scene.camera, a script may send a part (scene.camera.eye): plotly has
      // merged either into the layout
      if (!Object.keys(ev).some((k) => k.startsWith("scene.camera"))) return;
      view.camera = JSON.parse(JSON.stringify(div.layout.scene.camera));
      const text = JSON.stringify(view.camera);
      for (const id of VIEWS3D) {
        const other = $(id);
        if (other === div || !other.data || !other.layout.scene) continue;
        if (JSON.stringify(other.layout.scene.camera) !== text)
          Plotly.relayout(other, { "scene.camera": JSON.parse(text) });
      }
    });
  }

  // ---- A and B at the same punch stroke ---------------------------------------------------
  function strokePanel() {
    const slider = el("input", { type: "range", id: "compare-stroke-slider", disabled: true });
    slider.setAttribute("list", "compare-stroke-ticks");
    slider.setAttribute("aria-label", "punch stroke (mm)");
    // the number shown follows the thumb; the frames are asked for where it is let go
    // a stroke between saved frames showed the frame nearest it under another number (11.9 mm
    // over a frame of 10 mm, a browser review): the thumb goes to the nearest stroke a frame
    // was saved at, and the number with it
    const snapped = () => {
      const ticks = view.strokeTicks || [];
      if (!ticks.length) return +slider.value;
      return ticks.reduce((a, b) => (Math.abs(b - slider.value) < Math.abs(a - slider.value)
                                     ? b : a));
    };
    slider.oninput = () => { $("compare-stroke-value").textContent = mm(snapped()); };
    slider.onchange = () => {
      slider.value = String(snapped());
      view.stroke = +slider.value;
      fetchStroke();
    };
    return el("section", { id: "compare-stroke" },
      el("h3", { textContent: "At the same punch stroke: thickness on the deformed part " +
                 "(both on one colour scale; the cameras move together)" }),
      el("div", { id: "compare-stroke-controls", className: "row stroke-controls" },
         el("label", { htmlFor: "compare-stroke-slider", textContent: "punch stroke" }),
         slider, el("datalist", { id: "compare-stroke-ticks" }),
         el("output", { id: "compare-stroke-value", htmlFor: "compare-stroke-slider" }),
         el("span", { id: "compare-stroke-shown" })),
      el("p", { id: "compare-stroke-msg", className: "muted", role: "status" }),
      el("div", { id: "compare-stroke-views", className: "stroke-views" },
         el("div", { id: "compare-3d-a", className: "plot" }),
         el("div", { id: "compare-3d-b", className: "plot" }),
         el("div", { id: "compare-3d-diff", className: "plot" })));
  }

  function mm(stroke) {
    // strokes to a micrometre up to 10 mm, to 10 µm beyond: a slider's stroke and a frame's
    // read alike
    return `${stroke.toFixed(view.strokeDigits)} mm`;
  }

  function strokeRuns() {
    return [view.runs[0], view.runs[view.against]];
  }

  async function atStroke(data) {
    // a new pair starts at the deepest stroke both reached; a run still going is asked
    // again at each refresh (it saves frames as it goes)
    const key = strokeRuns().join(",");
    const going = [0, view.against].some((i) => ACTIVE.includes(data.runs[i].state));
    if (key !== view.strokeKey) view.stroke = view.bounds = null;
    else if (!going) return;
    view.strokeKey = key;
    await fetchStroke();
  }

  async function fetchStroke() {
    // the latest request wins: an answer overtaken by a newer one is dropped
    const seq = ++view.strokeSeq;
    const q = view.stroke === null ? "" : `&stroke_mm=${view.stroke}`;
    let t;
    try {
      t = await api("GET", "/api/compare/frames?runs=" +
                    `${strokeRuns().map(encodeURIComponent)}${q}`);
    } catch (e) {
      if (seq === view.strokeSeq) strokeMissing(e.message);
      return;
    }
    if (seq !== view.strokeSeq) return;
    $("compare-stroke-controls").hidden = $("compare-stroke-views").hidden = false;
    t.b.letter = view.data.runs[view.against].letter;  // the server letters its two A, B
    strokeControls(t);
    await drawStroke(t);
  }

  function strokeMissing(why) {
    $("compare-stroke-msg").textContent = `no views at a stroke: ${why}`;
    $("compare-stroke-controls").hidden = $("compare-stroke-views").hidden = true;
    for (const id of VIEWS3D.slice(1)) unplot($(id));
  }

  function strokeControls(t) {
    const [lo, hi] = t.range, slider = $("compare-stroke-slider");
    // about 200 positions over the range, a round number of mm each
    const step = hi > lo ? 10 ** Math.floor(Math.log10((hi - lo) / 200)) : 1;
    Object.assign(slider, { min: lo, max: hi, step, disabled: !(hi > lo) });
    view.strokeDigits = hi < 10 ? 3 : 2;
    slider.value = String(t.stroke);
    const ticks = [...new Set(t.runs.flatMap((r) => r.frames.map((f) => f.stroke)))]
      .filter((v) => v >= lo && v <= hi).sort((a, b) => a - b);
    view.strokeTicks = ticks;
    $("compare-stroke-ticks").replaceChildren(...ticks.map((v) => el("option",
                                                                  { value: String(v) })));
    $("compare-stroke-value").textContent = mm(t.stroke);
    const shown = [t.a, t.b].map((p) => `${p.letter}: frame of step ${p.step} at ` +
                                      mm(p.stroke));
    $("compare-stroke-shown").textContent = `shown — ${shown.join(" · ")}`;
    const saved = t.runs.map((r, i) => `${i ? t.b.letter : "A"} ${r.frames.length}`);
    $("compare-stroke-msg").textContent = hi > lo
      ? `strokes both runs saved frames for: ${mm(lo)} to ${mm(hi)} ` +
        `(frames saved: ${saved.join(", ")}); each view shows its run's frame nearest the ` +
        "stroke chosen"
      : `both runs have saved frames only at ${mm(lo)} of stroke so far`;
  }

  function grow(box) {
    // the box every stroke is drawn in: the extent of every frame saved (the server's), grown
    // as a run still going saves more; sliding keeps the scale and the true proportions
    const b = view.bounds || box.map(([lo, hi]) => [lo, hi]);
    box.forEach(([lo, hi], c) => { b[c] = [Math.min(b[c][0], lo), Math.max(b[c][1], hi)]; });
    view.bounds = b;
  }

  function sceneBox() {
    const b = view.bounds, size = Math.max(...b.map(([lo, hi]) => hi - lo), 1e-6);
    const range = b.map(([lo, hi]) => [lo - 0.02 * size, hi + 0.02 * size]);
    const ratio = range.map(([lo, hi]) => (hi - lo) / size);
    const ax = (c, name) => ({ title: { text: `${name} (mm)` }, range: range[c],
                               autorange: false });
    return { aspectmode: "manual", aspectratio: { x: ratio[0], y: ratio[1], z: ratio[2] },
             xaxis: ax(0, "x"), yaxis: ax(1, "y"), zaxis: ax(2, "z") };
  }

  function stroke3d(div, trace, title, stroke) {
    const lay = layout(title, 380, {
      margin: { l: 0, r: 0, t: 34, b: 0 },
      scene: { ...sceneBox(), camera: view.camera || { eye: EYE } } });
    if (!div.data) div.replaceChildren();  // the note that stood in for a view
    div.dataset.step = String(stroke.step);
    div.dataset.stroke = String(stroke.stroke);
    return plotInto(div, [trace], lay, CONFIG).then((drawn) => drawn && linkCamera(div));
  }

  function strokeTrace(part, values, scale) {
    const P = part.formed, F = part.faces;
    return { type: "mesh3d", x: P.map((p) => p[0]), y: P.map((p) => p[1]),
             z: P.map((p) => p[2]), i: F.map((f) => f[0]), j: F.map((f) => f[1]),
             k: F.map((f) => f[2]), intensity: values, intensitymode: "vertex",
             lighting: { ambient: 0.75, diffuse: 0.35, specular: 0.05 }, name: part.letter,
             customdata: values.map((v, n) => [v, part.thickness[n]]), ...scale };
  }

  function drawStroke(t) {
    let [lo, hi] = t.thickness_range;
    // a scale of at least 1 % of the thickness: at rest it is even, and no colour would mean
    // anything
    const pad = Math.max(0, 0.01 * hi - (hi - lo)) / 2;
    lo -= pad;
    hi += pad;
    // a colour bar beside each: the same scale, and the two parts drawn the same size
    const thick = (part) => strokeTrace(part, part.thickness, {
      colorscale: "Jet", reversescale: true, cmin: lo, cmax: hi,
      colorbar: { title: { text: "thickness (mm)<br>A and B", side: "right" }, len: 0.85,
                  exponentformat: "none" },
      hovertemplate: `${part.letter}: %{customdata[1]:.4f} mm<extra></extra>` });
    grow(t.box);
    const head = (p) => `${p.letter}: thickness at ${mm(p.stroke)} (step ${p.step})`;
    const draws = [stroke3d($("compare-3d-a"), thick(t.a), head(t.a), t.a),
                   stroke3d($("compare-3d-b"), thick(t.b), head(t.b), t.b)];
    const d = t.difference, div = $("compare-3d-diff");
    if (d.available) {
      const m = Math.max(d.max_abs, ZERO_MM), B = t.b.letter;
      draws.push(stroke3d(div, strokeTrace(t.a, d.values, {
        ...THINNER_RED, cmin: -m, cmax: m, cmid: 0,
        colorbar: { title: { text: `A − ${B}<br>thickness (mm)`, side: "right" }, len: 0.85,
                    exponentformat: "none" },
        hovertemplate: `A − ${B}: %{customdata[0]:.4f} mm<br>A: %{customdata[1]:.4f} mm` +
                       "<extra></extra>" }),
        `A − ${B} (red: A thinner)` +
        (Math.abs(t.a.stroke - t.b.stroke) > 1e-4 ? ", at strokes that differ" : ""), t.a));
    } else {
      unplot(div);
      div.replaceChildren(el("p", { className: "muted",
                                    textContent: `no A − ${t.b.letter} map: ${d.reason}` }));
    }
    return Promise.all(draws);
  }

  function init() {
    const css = el("link", { rel: "stylesheet", href: "/static/compare.css" });
    document.head.append(css);
    panel();
    overlay();
    refreshPanel();
    // the runs come and go (new runs, deletions): the panel follows while it is open
    setInterval(() => { if ($("compare-box").open && !document.body.classList
      .contains("comparing")) refreshPanel(); }, 3000);
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", init);
  else init();
  return { open, close, picked };
})();
