// A refinement study of the selected finished run's scene (POST /api/studies, as `q3t
// study`): its plan first, each case's size and its time predicted from the run, so that
// minutes are told from hours before anything starts; then its progress, a line per case, and
// a cancel. The study's report gives the scene's runs their error estimate (the headline's
// line under the cards), which the page's next poll shows.
"use strict";
const Studies = (() => {
  const POLL_MS = 1000;  // while a study runs: its cases take a second to hours each
  const NOTICE_MS = 10000;  // a study another page started shows within this
  let run = null;  // the finished run shown: its scene is studied, its time predicts
  let planned = null;  // the run the inputs and the plan were made for
  let plannedBody = null;  // the request of the plan on screen: what Start starts
  let following = false;  // a poll of the running study is under way
  let seen = null;  // the state of the study last drawn
  let watched = false;  // this page saw the study run: the headline says how it ended
  const $ = (id) => document.getElementById(id);
  // lists are typed separated by spaces, ";" or ", " (a comma and a space); a comma between
  // digits is a decimal comma ("17,5" is 17.5 mm)
  const list = (text) => text.split(/\s*;\s*|,\s+|\s+/).filter(Boolean)
    .map((t) => t.replace(/(\d),(\d)/, "$1.$2"));

  function duration(s) {
    if (!Number.isFinite(s)) return "–";
    if (s < 0.01) return "under 0.01 s";
    if (s < 1) return `${s.toFixed(2)} s`;
    if (s < 90) return `${Math.round(s)} s`;
    if (s < 5400) return `${(s / 60).toFixed(1)} min`;
    return `${(s / 3600).toFixed(1)} h`;
  }

  function asked() {
    // the request the inputs make: what is left empty is the server's default
    const body = { run };
    const elements = list($("study-elements").value);
    if (elements.length) body.elements = elements;
    const levels = list($("study-levels").value).map(Number);
    if (levels.length) body.levels_mm = levels;
    const el = $("study-ref-element").value.trim(), edge = $("study-ref-edge").value.trim();
    if (el || edge) body.reference = { element: el, edge_mm: Number(edge) };
    return body;
  }

  function check(body) {
    // what the server refuses by the same rule, said at once (a number it cannot read is
    // not sent as JSON: NaN has no spelling there)
    if ((body.levels_mm || []).some((v) => !Number.isFinite(v) || v <= 0))
      return "levels: mesh edge lengths in mm, positive numbers, separated by commas";
    if (body.reference && (!body.reference.element || !Number.isFinite(body.reference.edge_mm)
                           || body.reference.edge_mm <= 0))
      return "reference: an element and its mesh edge length in mm";
    return null;
  }

  function error(text) {
    $("study-error").textContent = text || "";
  }

  async function plan(fill) {
    const body = fill ? { run } : asked();
    const bad = check(body);
    $("study-start").disabled = true;
    plannedBody = null;
    if (bad) { error(bad); drawCases(null); return; }
    error("");
    const forRun = run;
    let p;
    try {
      p = await api("POST", "/api/studies/plan", body);
    } catch (e) {
      if (forRun === run) { error(e.message); drawCases(null); }
      return;
    }
    if (forRun !== run) return;  // another run was selected meanwhile
    planned = run;
    plannedBody = body;
    if (fill) {
      $("study-elements").value = p.elements.join(", ");
      $("study-levels").value = p.levels_mm.map((v) => +v.toPrecision(6)).join(", ");
      $("study-ref-element").value = p.reference ? p.reference.element : "";
      $("study-ref-edge").value = p.reference ? +p.reference.edge_mm.toPrecision(6) : "";
    }
    drawCases(p);
    $("study-start").disabled = seen === "running";
    $("study-stale").hidden = true;
  }

  function edited() {
    // a field changed since the plan on screen: Start would not run what it shows
    if (!plannedBody) return;
    plannedBody = null;
    $("study-start").disabled = true;
    $("study-stale").hidden = false;
  }

  function drawCases(p) {
    const box = $("study-cases");
    box.dataset.total = p ? String(p.predicted_s) : "";
    if (!p) { box.replaceChildren(); $("study-notes").replaceChildren(); return; }
    const table = document.createElement("table");
    table.id = "study-table";
    const head = table.createTHead().insertRow();
    const heads = { case: "element and mesh edge",
                    DoFs: "degrees of freedom, counted from the mesh parameters (an outline's " +
                          "from its area, within a few %); the run's own case has the run's",
                    time: "predicted from the run's time" };
    for (const [h, title] of Object.entries(heads)) {
      const th = document.createElement("th");
      th.textContent = h;
      th.title = title;
      head.append(th);
    }
    const tbody = table.createTBody();
    for (const c of p.cases) {
      const tr = tbody.insertRow();
      if (c.reference) tr.className = "reference";
      tr.title = `its build takes about ${c.memory_gib.toFixed(2)} GiB`;
      const cells = [`${c.element} ${+c.edge_mm.toPrecision(4)} mm` +
                     (c.reference ? " (ref.)" : c.asking_run ? " (the run's)" : ""),
                     c.dofs.toLocaleString("en"),
                     duration(c.predicted_s)];
      for (const v of cells) tr.insertCell().textContent = v;
    }
    const total = table.createTFoot().insertRow();
    const th = document.createElement("th");
    th.colSpan = 2;
    th.textContent = `whole study, warm-up included (${p.cases.length} cases` +
      (p.analytic ? `, against ${p.analytic.name}` : "") +
      `; largest build ${p.largest_gib.toFixed(2)} GiB)`;
    total.append(th);
    total.insertCell().textContent = `about ${duration(p.predicted_s)}`;
    box.replaceChildren(table);
    const notes = $("study-notes");
    notes.replaceChildren(...[`error measured on ${p.probe}`, ...p.notes,
                              `the same from the command line: ${p.command}`].map((n) => {
      const li = document.createElement("li");
      li.textContent = n;
      return li;
    }));
  }

  const caseName = (c) => `${c.element} ${+c.edge_mm.toPrecision(4)} mm` +
    (c.reference ? " (reference)" : "");

  function drawProgress(s) {
    const box = $("study-progress");
    seen = s ? s.state : null;
    box.dataset.state = seen || "";
    $("study-cancel").hidden = seen !== "running";
    if (seen === "running") $("study-start").disabled = true;
    else if (planned === run && run && plannedBody) $("study-start").disabled = false;
    if (!s) { box.replaceChildren(); headline(null); return; }
    const head = document.createElement("div");
    const when = `${duration(s.elapsed_s)} of about ${duration(s.predicted_s)} predicted`;
    const kept = s.had_report ? "the scene's last report stays" : "no report written";
    head.textContent = {
      running: `Study of ${s.scene} running: ${s.done} of ${s.cases} cases done, ${when}`,
      finished: `Study of ${s.scene} finished: ${s.cases} cases in ${duration(s.elapsed_s)} ` +
        `(predicted ${duration(s.predicted_s)}); its runs' error estimates come from it`,
      failed: `Study of ${s.scene} failed after ${s.done} of ${s.cases} cases: ${s.reason}; ` +
        kept,
      cancelled: `Study of ${s.scene} cancelled after ${s.done} of ${s.cases} cases ` +
        `(${s.reason}); ${kept}`,
    }[s.state];
    const bar = document.createElement("progress");
    bar.max = s.cases;
    bar.value = s.done;
    const lines = [];
    if (s.now) lines.push(`now: ${caseName(s.now)}, ${s.now.dofs.toLocaleString("en")} DoFs, ` +
                          `predicted ${duration(s.now.predicted_s)}`);
    const last = s.finished[s.finished.length - 1];
    if (last) lines.push(`done: ${caseName(last)}, ${last.status}, ${duration(last.seconds)}`);
    const said = lines.map((t) => {
      const d = document.createElement("div");
      d.className = "study-case";
      d.textContent = t;
      return d;
    });
    box.replaceChildren(head, bar, ...said);
    headline(s, head.textContent);
  }

  function headline(s, text) {
    // the headline's line: a study runs for the server, whichever run the page shows (the
    // panel lives under a finished run's plots), so a page opened or reloaded meanwhile
    // still shows it and can cancel it; once it has ended the line says how, until dismissed
    const line = $("study-line");
    if (s && s.state === "running") watched = true;
    line.hidden = !s || !watched;
    if (line.hidden) return;
    line.dataset.state = s.state;
    line.querySelector(".text").textContent = text;
    $("study-line-cancel").hidden = s.state !== "running";
    $("study-line-close").hidden = s.state === "running";
  }

  async function follow() {
    // the study's state, again each second while it runs; once it has ended, the page's
    // next poll brings the run's estimate from its report
    if (following) return;
    following = true;
    try {
      for (;;) {
        let s = null;
        try {
          s = (await api("GET", "/api/studies")).study;
        } catch (e) { error(e.message); }
        const was = seen;
        drawProgress(s);
        if (was === "running" && seen !== "running" && typeof pollNow === "function") pollNow();
        if (seen !== "running") break;
        await new Promise((ok) => setTimeout(ok, POLL_MS));
      }
    } finally { following = false; }
  }

  async function start() {
    const body = plannedBody;  // the plan on screen, whatever the fields say since
    if (!body) return;
    $("study-start").disabled = true;
    try {
      drawProgress(await api("POST", "/api/studies", body));
      error("");
    } catch (e) {
      error(e.message);
      $("study-start").disabled = false;
    }
    follow();
  }

  async function cancel() {
    for (const id of ["study-cancel", "study-line-cancel"]) $(id).disabled = true;
    try {
      drawProgress(await api("POST", "/api/studies/cancel"));
    } catch (e) {
      error(e.message);
      say(`study: ${e.message}`, true);  // the panel may not be on screen
    }
    for (const id of ["study-cancel", "study-line-cancel"]) $(id).disabled = false;
  }

  function show(st) {
    // a finished run's scene can be studied; other runs have no time to predict from
    const box = $("study-box");
    box.hidden = st.state !== "finished";
    if (box.hidden) return;
    if (st.id !== run) {
      run = st.id;
      planned = plannedBody = null;
      error("");
      drawCases(null);
      $("study-start").disabled = true;
      if (box.open) plan(true);
    }
  }

  function forget() {
    run = planned = null;
    $("study-box").hidden = true;
  }

  function init() {
    $("study-box").addEventListener("toggle", () => {
      if ($("study-box").open && run && planned !== run) plan(true);
      if ($("study-box").open) follow();
    });
    $("study-plan").addEventListener("click", () => plan(false));
    $("study-start").addEventListener("click", start);
    $("study-cancel").addEventListener("click", cancel);
    $("study-line-cancel").addEventListener("click", cancel);
    $("study-line-close").addEventListener("click", () => {
      watched = false;
      $("study-line").hidden = true;
    });
    $("study-line-open").addEventListener("click", () => {
      // the panel is under a finished run's plots: without one shown there is none
      const box = $("study-box");
      if (box.hidden) {
        error("");
        say("the study's panel is under a finished run's plots: select one");
        return;
      }
      box.open = true;
      box.scrollIntoView({ block: "start", behavior: "smooth" });
    });
    for (const id of ["study-elements", "study-levels", "study-ref-element", "study-ref-edge"])
      $(id).addEventListener("input", edited);
    follow();  // a study started before the page was opened
    setInterval(follow, NOTICE_MS);  // or by another page since
  }

  return { show, forget, init };
})();
