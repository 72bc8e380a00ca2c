// The selected run's headline and plots: its state and progress, its summary (peak punch
// force, thinning, draw-in, ... as result.json has them), the solver's cost as a secondary
// line, its downloads (CSV, VTU, STL, PLY, JSON) once it has ended, a cup's split rings
// (web/rings.js), and the plots, redrawn as steps arrive. What is shown is read from the
// server.
"use strict";
const Results = (() => {
  const ACTIVE = ["starting", "building", "running", "paused"];
  const COMING = [...ACTIVE, "queued"];  // its result is still to come
  // what is drawn, so a poll redraws only what changed: "run@step/state" per part
  const drawn = { plots: null, summary: null, fld: null, downloads: null };
  let plotsData = null;
  let shown = null;  // the run whose numbers are on screen

  function key(st) {
    return `${st.id}@${st.step}/${st.state}`;
  }

  // ---- the headline ---------------------------------------------------------------------
  function showStatus(st) {
    const box = document.getElementById("status");
    const where = st.state === "queued" && st.place ? ` (#${st.place} in the queue)` : "";
    box.textContent = `${st.id}: ${st.state}${where}, step ${st.step}/${st.n_steps ?? "?"}` +
      (st.edited ? ` — ran unsaved edits of ${st.scene}` : "") +
      (st.reason ? ` — ${st.reason}` : "");
    Object.assign(box.dataset, { state: st.state, run: st.id, step: st.step,
                                 edited: String(!!st.edited) });
  }

  function showProgress(st) {
    const p = st.progress, box = document.getElementById("progress");
    box.hidden = !p;
    if (!p) return;
    const pct = p.fraction === null ? 0 : 100 * p.fraction;
    box.querySelector(".fill").style.width = `${pct}%`;
    box.setAttribute("aria-valuenow", String(Math.round(pct)));
    box.dataset.fraction = p.fraction === null ? "" : String(p.fraction);
    box.dataset.state = st.state;
    const parts = [`step ${p.step}/${p.steps ?? "?"}`, `${Math.floor(pct)} %`];
    if (st.state === "queued") {
      parts.push(`waiting for a solver, #${st.place} in the queue`);
      // a paused run keeps its solver: the queue waits for it to be resumed or stopped
      const paused = (st.waiting_for || []).filter((r) => r.state === "paused");
      if (paused.length && paused.length === (st.waiting_for || []).length)
        parts.push(`${paused.map((r) => r.id).join(", ")} ${paused.length > 1 ? "hold" :
          "holds"} it paused: resume or stop ${paused.length > 1 ? "them" : "it"} to start this run`);
    } else if (ACTIVE.includes(st.state)) {
      parts.push(`${Units.duration(p.elapsed_s)} elapsed`);
      parts.push(p.remaining_s === null ? "remaining: after the first step"
                 : `about ${Units.duration(p.remaining_s)} left` +
                   (st.state === "paused" ? " once resumed" : ""));
    } else if (p.elapsed_s !== null) {
      // the wall time holds the build and any pause; the solver's steps are what runs compare by
      const took = Units.duration(p.elapsed_s), steps = Units.duration(st.stepping_s || 0);
      parts.push(`took ${took}` + (st.stepping_s && steps !== took ? ` (${steps} of it stepping)`
                                                                   : ""));
    }
    box.querySelector(".text").textContent = parts.join(" · ");
    box.classList.toggle("ended", !ACTIVE.includes(st.state));
  }

  const m = (v) => Units.withUnit(v.display.value, v.display.unit);

  function when(at, flag) {
    // on the card: the stroke or step it happened at; for a forming limit reached, how many
    // elements reached it
    if (flag && at.over_limit) {
      return `${flag} in ${Units.num(at.over_limit)} vert${at.over_limit === 1 ? "ex" : "ices"}`;
    }
    if (flag === "mesh") return "the mesh's, not ears";  // why: the card's tooltip
    if (flag === "no_contact") return "the punch never touched the sheet";
    // a harmonic's phase is what says where the ears are (45 deg: Delta r < 0)
    if (at.first_crest) return `first crest at ${m(at.first_crest)}`;
    if (flag && at.zone_counts) {
      const n = at.zone_counts[flag];
      return `${flag} in ${Units.num(n)} element${n === 1 ? "" : "s"}`;
    }
    if (at.stroke) return `at ${m(at.stroke)} stroke` +
                          (at.step !== undefined ? ` (step ${at.step})` : "");
    return at.step !== undefined ? `at step ${at.step}` : "";
  }

  function where(at) {
    // in the card's tooltip: the place (mid-surface point, or the edge's rest point) and
    // what else the summary says of it (its notes name these)
    const lines = [];
    if (at.point) lines.push(`at ${m(at.point)} (x, y, z)`);
    else if (at.rest_point) lines.push(`the edge point at ${m(at.rest_point)} at rest`);
    if (at.angle) lines.push(`at ${m(at.angle)} about the punch axis`);
    if (at.first_crest) lines.push(`first crest at ${m(at.first_crest)}`);
    if (at.share_of_peak) lines.push(`${m(at.share_of_peak)} of the peak punch force`);
    if (at.steps_over_2_percent !== undefined) {
      lines.push(`${at.steps_over_2_percent} step(s) over 2 % of the peak` +
                 (at.steps_over_2_percent ? `, steps ${at.first_step_over}` +
                                            `–${at.last_step_over}` : ""));
    }
    if (at.holder_on_stop_from_step !== undefined && at.holder_on_stop_from_step !== null)
      lines.push(`the blank holder on its stop from step ${at.holder_on_stop_from_step}`);
    if (at.peak_to_valley) lines.push(`peak to valley ${m(at.peak_to_valley)}`);
    if (at.edge_left_die_face !== undefined && at.edge_left_die_face !== null)
      lines.push(`the flange's edge left the die face at step ${at.edge_left_die_face}`);
    if (at.major && at.minor)
      lines.push(`its element's strains: major ${m(at.major)}, minor ${m(at.minor)} (true)`);
    if (at.zone_counts) {
      lines.push("elements per zone of the forming limit diagram: " +
                 Object.entries(at.zone_counts).map(([z, n]) => `${z} ${Units.num(n)}`)
                   .join(", "));
    }
    return lines.join("\n");
  }

  function card(e, tools, last) {
    // ``last``: the run's last step, which a quantity of the part as it ended is of (the
    // least thickness: the 3-D view's scale, over every step shown, may reach lower)
    const div = document.createElement("div");
    div.className = "quantity" + (e.flag ? ` flag-${e.flag}` : "");
    Object.assign(div.dataset, { name: e.name, value: JSON.stringify(e.display.value),
                                 unit: e.display.unit, flag: e.flag || "" });
    const label = document.createElement("div");
    label.className = "label";
    label.textContent = e.label + (e.tool && tools > 1 ? ` (${e.tool})` : "");
    const value = document.createElement("div");
    value.className = "value";
    value.textContent = Units.withUnit(e.display.value, e.display.unit);
    const at = document.createElement("div");
    at.className = "at";
    const said = when(e.at || {}, e.flag);
    at.textContent = !said || said === `at step ${last}` ? `at the end (step ${last})` : said;
    div.title = [label.textContent, where(e.at || {}), e.note].filter(Boolean).join("\n");
    div.append(label, value, at);
    return div;
  }

  async function showSummary(st) {
    // a run's summary is written with its result: when it ends
    const box = document.getElementById("summary");
    if (COMING.includes(st.state)) {
      drawn.summary = null;
      Plots.show("rim-fig", false);
      box.dataset.run = st.id;
      box.dataset.ready = "false";
      box.replaceChildren(liveLine());
      return;
    }
    const k = `${st.id}/${st.state}`;
    if (drawn.summary === k) return;
    let s;
    try {
      s = await api("GET", `/api/runs/${st.id}/summary`);
    } catch (e) {
      if (e.status !== 404) throw e;
      s = { summary: [] };
    }
    if (st.id !== shown) return;
    drawn.summary = k;
    const tools = new Set(s.summary.filter((e) => e.tool).map((e) => e.tool)).size;
    const cards = s.summary.map((e) => card(e, tools, st.step));
    if (!cards.length) {
      const none = document.createElement("div");
      none.className = "muted none";  // across the cards' columns, not in one
      none.textContent = st.state === "cancelled" ? "No summary: it never ran."
                                                   : "No summary: the run ended before it " +
                                                     "had a result.";
      cards.push(none);
    }
    if (s.summary.length && st.state !== "finished") {
      // a stopped or failed run's cards are the part at its last step, not the formed part
      const ended = document.createElement("div");
      ended.className = "live ended-early";
      ended.textContent = `${st.state[0].toUpperCase()}${st.state.slice(1)} at step ` +
        `${st.step} of ${st.n_steps ?? "?"}: the values below are the part's at that step, ` +
        "not at the end of the run as planned.";
      cards.unshift(ended);
    }
    box.replaceChildren(...cards);
    Object.assign(box.dataset, { run: st.id, ready: "true", count: String(s.summary.length) });
    await showRim(s.summary);
  }

  async function showRim(summary) {
    // a drawn cup's rim heights around its axis (the earing's profile), in the summary's units
    const earing = summary.find((e) => e.profile && e.profile.height);
    Plots.show("rim-fig", !!earing);
    if (!earing) return;
    const extremes = summary.filter((e) => ["max_rim_height", "min_rim_height"]
      .includes(e.name));
    await Plots.rim(document.getElementById("rim-plot"), earing.profile, extremes);
  }

  function liveLine() {
    // while a run runs: its punch force as it goes (the summary comes at the end)
    const div = document.createElement("div");
    div.className = "live muted";
    const p = plotsData && plotsData.punches.find((c) => c.force.values.length);
    const parts = [];
    if (p) {
      const f = p.force.values, n = f.length - 1;
      const peak = f.reduce((k, v, i) => (v > f[k] ? i : k), 0);
      const at = (i) => (p.stroke ? ` at ${Units.num(p.stroke.values[i])} mm stroke` :
                                    ` at step ${p.steps[i]}`);
      parts.push(`Punch force now ${Units.num(f[n])} kN${at(n)}; peak so far ` +
                 `${Units.num(f[peak])} kN${at(peak)}.`);
    }
    // the sheet now: what the engineer watches for besides the force (the cards come at the
    // end); thinning to one decimal, as the cards show it
    const s = plotsData && plotsData.sheet;
    if (s && s.steps.length) {
      const k = s.steps.length - 1, thin = s.max_thinning.values[k];
      parts.push(`Sheet now: thinnest ${Units.num(s.min_thickness.values[k])} mm, ` +
                 `thinning up to ${thin === null ? "–" : thin.toFixed(1)} %.`);
    }
    parts.push("The summary appears when the run ends.");
    div.textContent = parts.join(" ");
    return div;
  }

  function showEstimate(st) {
    // a finished run: its error estimate from a study of the scene and its cost
    const box = document.getElementById("estimate");
    const est = st.estimate;
    box.hidden = !est;
    box.dataset.run = st.id;
    box.dataset.available = est ? String(!!est.available) : "";
    if (!est) { box.replaceChildren(); return; }
    const line = document.createElement("div");
    line.className = "estimate-text";
    // `q3t study SCENE` in backticks becomes code
    est.text.split("`").forEach((part, i) => {
      if (i % 2) {
        const c = document.createElement("code");
        c.textContent = part;
        line.append(c);
      } else line.append(part);
    });
    // no study of the scene yet (or none of this element): the page can plan one, where the
    // command line's is not a course's nor of a mesh read from a file
    if (["no_study", "element_not_studied"].includes(est.reason) && st.state === "finished" &&
        est.text.includes("`q3t study ") && !est.text.includes("--course")) {
      const open = document.createElement("a");
      open.href = "#study-box";
      open.id = "estimate-plan";
      open.textContent = "plan one under the plots";
      open.addEventListener("click", (e) => {
        e.preventDefault();
        const box = document.getElementById("study-box");
        box.open = true;
        box.scrollIntoView({ block: "nearest" });
      });
      // after the command it names: "run `q3t study tiny` (or plan one under the plots)"
      line.querySelector("code").after(" (or ", open, ")");
    }
    const kids = [line];
    if (est.notes && est.notes.length) {
      const ul = document.createElement("ul");
      for (const n of est.notes) {
        const li = document.createElement("li");
        li.textContent = n;
        ul.append(li);
      }
      kids.push(ul);
    }
    box.replaceChildren(...kids);
  }

  // ---- the downloads ----------------------------------------------------------------------
  // what each export is, on its link (the server's list says which the run has)
  const EXPORTS = { csv: "Probes CSV", vtu: "ParaView VTU (zip)", stl: "Part STL",
                    ply: "Part PLY", json: "Summary JSON", png: "3-D view PNG" };

  async function showDownloads(st) {
    // a run's results as files, once it has ended: they are complete then
    const box = document.getElementById("downloads");
    box.hidden = false;
    box.dataset.run = st.id;
    if (COMING.includes(st.state)) {  // queued too: nothing to download, nor a view to capture
      drawn.downloads = null;
      box.dataset.ready = "false";
      const wait = document.createElement("span");
      wait.className = "muted";
      wait.textContent = "Downloads (CSV, VTU, STL, PLY, JSON) when the run ends.";
      box.replaceChildren(wait);
      return;
    }
    const k = `${st.id}/${st.state}`;
    if (drawn.downloads === k) return;
    let ex;
    try {
      ex = await api("GET", `/api/runs/${st.id}/exports`);
    } catch (e) {
      if (e.status !== 404) throw e;
      return;  // the run was deleted meanwhile
    }
    if (st.id !== shown) return;
    drawn.downloads = k;
    const head = document.createElement("span");
    head.className = "muted";
    head.textContent = "Download:";
    const note = document.createElement("span");
    note.className = "note error";
    box.replaceChildren(head, ...ex.formats.map(downloadLink), note);
    box.dataset.ready = "true";
  }

  async function downloadView(ev) {
    // the PNG is rendered by a browser showing the run (this page's 3-D view, usually): asked
    // for here, so a refusal is said on the page instead of being saved as a file
    ev.preventDefault();
    const a = ev.currentTarget, note = document.querySelector("#downloads .note");
    note.textContent = "";
    a.dataset.busy = "true";
    try {
      const r = await fetch(a.href);
      if (!r.ok) {
        const d = await r.json().catch(() => null);
        note.textContent = `PNG: ${(d && d.detail) || r.statusText}`;
        return;
      }
      const url = URL.createObjectURL(await r.blob());
      const save = document.createElement("a");
      save.href = url;
      save.download = `${document.getElementById("downloads").dataset.run}.png`;
      save.click();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
    } finally {
      a.dataset.busy = "false";
    }
  }

  function downloadLink(f) {
    // an export the run has is a link; one it lacks says why on hover
    const label = EXPORTS[f.format] || f.format;
    if (!f.available) {
      const span = document.createElement("span");
      span.className = "unavailable";
      span.dataset.format = f.format;
      span.textContent = label;
      span.title = f.reason || "";
      return span;
    }
    const a = document.createElement("a");
    a.href = f.url;
    a.setAttribute("download", "");
    a.dataset.format = f.format;
    a.textContent = label;
    a.title = f.description;  // with its units: a summary's values are SI beside the page's
    if (f.format === "png") a.addEventListener("click", downloadView);
    return a;
  }

  // ---- the plots --------------------------------------------------------------------------
  async function showPlots(st) {
    const k = key(st);
    if (drawn.plots === k) return;
    const data = await api("GET", `/api/runs/${st.id}/plots`);
    if (data.run !== shown) return;  // another run was selected meanwhile
    drawn.plots = k;
    plotsData = data;
    // the live line reads the punch force from these: drawn again now, not a poll later
    const box = document.getElementById("summary");
    // (not over the summary: a poll of the running run answered after it finished drew the
    // live line over the finished run's cards)
    if (COMING.includes(st.state) && box.dataset.run === st.id && box.dataset.ready !== "true")
      box.replaceChildren(liveLine());
    const $ = (id) => document.getElementById(id);
    const force = data.punches.filter((p) => p.force.values.length);
    Plots.show("force-fig", force.length > 0);
    if (force.length) await Plots.forceStroke($("force-plot"), force, data.parameter_log);
    Plots.show("probes-fig", data.probes.length > 0);
    if (data.probes.length) await Plots.probes($("probes-plot"), data.probes,
                                                data.parameter_log);
    Plots.show("section-fig", data.sections.length > 0);
    if (data.sections.length) await Plots.sections($("section-plot"), data.sections, force[0]);
    await drawSolver();
    $("no-plots").hidden = data.solver.steps.length > 0;
    document.getElementById("plots").dataset.step = String(data.step);
  }

  async function drawSolver() {
    // only while its box is open: a live run redraws at every step
    const s = plotsData && plotsData.solver;
    if (s && s.steps.length && document.getElementById("solver-box").open)
      await Plots.solver(document.getElementById("solver-plot"), s);
  }

  async function showFld(st) {
    // the forming limit diagram of a plastic run's end of stroke
    const k = `${st.id}/${st.state}`;
    if (COMING.includes(st.state)) { Plots.show("fld-fig", false); drawn.fld = null; return; }
    if (drawn.fld === k) return;
    let fl = null;
    // the plots say whether the result has one: an elastic run's is not asked for (a 404
    // in the console of every page that shows one)
    const none = plotsData && plotsData.run === st.id && !plotsData.forming_limits;
    if (!none) try {
      fl = await api("GET", `/api/runs/${st.id}/forming_limits`);
    } catch (e) {
      if (e.status !== 404) throw e;  // an elastic run, or one without a result
    }
    if (st.id !== shown) return;
    drawn.fld = k;
    Plots.show("fld-fig", !!fl && fl.minor.length > 0);
    if (fl && fl.minor.length) await Plots.fld(document.getElementById("fld-plot"), fl);
    fldWarnings((fl && fl.warnings) || []);
  }

  function fldWarnings(warnings) {
    // why the curve may not hold for the material card (a correlation extrapolated), under
    // the diagram it qualifies
    let box = document.getElementById("fld-warnings");
    if (!box) {
      box = document.createElement("ul");
      box.id = "fld-warnings";
      box.className = "error";
      document.getElementById("fld-fig").appendChild(box);
    }
    box.replaceChildren(...warnings.map((w) => {
      const li = document.createElement("li");
      li.textContent = `Forming limit curve: ${w}`;
      return li;
    }));
    box.hidden = !warnings.length;
  }

  function forget() {
    // another run is shown: nothing of the last one may stay on screen (and an answer about
    // it that arrives later is dropped: it is no longer ``shown``)
    shown = null;
    drawn.plots = drawn.summary = drawn.fld = drawn.downloads = null;
    plotsData = null;
    for (const f of ["force", "probes", "section", "rim", "fld"]) {
      Plots.show(`${f}-fig`, false);
      Plots.purge(document.getElementById(`${f}-plot`));
    }
    Plots.purge(document.getElementById("solver-plot"));
    const none = document.getElementById("no-plots");
    none.hidden = false;
    none.textContent = "The selected run's plots appear here as its steps arrive.";
    document.getElementById("summary").replaceChildren();
    document.getElementById("estimate").hidden = true;
    document.getElementById("estimate").replaceChildren();
    document.getElementById("downloads").hidden = true;
    document.getElementById("downloads").replaceChildren();
    Rings.forget();
    Studies.forget();
  }

  async function show(st) {
    if (st.id !== shown) {
      forget();
      shown = st.id;
    }
    showStatus(st);
    showProgress(st);
    showEstimate(st);
    await showSummary(st);
    await showDownloads(st);
    await Rings.show(st);
    Studies.show(st);
    // not awaited: drawing (and fetching plotly.js the first time) never holds the status
    // line back
    plotly().then(() => refreshPlots(st), () => {
      // /static/vendor/plotly.min.js comes from the plotly Python package
      document.getElementById("no-plots").textContent = "No plots: plotly.js did not load " +
        "(the server serves it from the plotly package: pip install 'q3t-forming[service]').";
    });
  }

  // one drawing at a time; a status that arrives meanwhile is drawn next (the newest only)
  let drawing = false, next = null;

  async function refreshPlots(st) {
    if (drawing) { next = st; return; }
    drawing = true;
    try {
      await showPlots(st);
      await showFld(st);
    } catch (e) {
      document.getElementById("no-plots").textContent = `Plots: ${e.message}`;
      document.getElementById("no-plots").hidden = false;
    } finally {
      drawing = false;
      if (next) {
        const later = next;
        next = null;
        refreshPlots(later);
      }
    }
  }

  function init() {
    document.getElementById("solver-box").addEventListener("toggle", () => drawSolver());
    Rings.init();
    Studies.init();
  }

  function none() {
    forget();
    const box = document.getElementById("status");
    box.textContent = "No run selected";
    box.dataset.run = "";
    document.getElementById("progress").hidden = true;
    document.getElementById("estimate").hidden = true;
  }

  return { show, none, forget, init };
})();
