// The Runs table: every run with what an engineer compares - its scene, element and what it
// changed of the scene, its state (a queued run's place, a failed one's reason), progress,
// wall time and the headline values of its result - from one GET /api/runs per poll. A click
// on a header sorts by it (again: the other way); a click on a row selects the run; Delete
// asks first, Cancel takes a queued run out of the queue.
"use strict";
const RunsTable = (() => {
  const ACTIVE = ["starting", "building", "running", "paused"];
  // the order of states when sorted by state: what needs attention first
  const STATES = ["running", "paused", "building", "starting", "queued", "failed", "stopped",
                  "cancelled", "finished"];
  const result = (name) => (r) => (r.results[name] ? r.results[name].value : null);
  // key, header, the value sorted by, the cell; ``unit``: the header's, which the server's
  // display values are in (a value in another unit says so in its cell)
  const COLUMNS = [
    { key: "run", label: "run", sort: (r) => r.created, cell: runCell },
    { key: "scene", label: "scene", sort: (r) => r.scene, cell: (r) => r.scene },
    { key: "element", label: "element", sort: (r) => r.element, cell: (r) => r.element },
    { key: "changes", label: "changes", sort: (r) => changes(r).join("; "), cell: changesCell,
      title: "what the run changed of its saved scene: unsaved edits, overrides, live " +
             "parameters (from the step they applied)" },
    { key: "state", label: "state", cell: stateCell, sort: stateOrder },
    { key: "progress", label: "progress", sort: (r) => r.progress.fraction,
      cell: progressCell },
    { key: "wall", label: "solver time", sort: (r) => r.progress.elapsed_s === null ? null
                                                      : r.stepping_s,
      cell: timeCell,
      title: "the time its steps took on a solver process (what runs compare by); a cell's " +
             "tooltip gives the wall time from its start to its end, the build, pauses and " +
             "the viewer's pacing included (the time it waited in the queue not counted)" },
    { key: "peak_punch_force", label: "peak force", unit: "kN",
      sort: result("peak_punch_force"), cell: valueCell("peak_punch_force", "kN"),
      title: "peak punch force (the largest of its punches)" },
    { key: "min_thickness", label: "min. thickness", unit: "mm",
      sort: result("min_thickness"), cell: valueCell("min_thickness", "mm") },
    { key: "max_thinning", label: "max. thinning", unit: "%",
      sort: result("max_thinning"), cell: valueCell("max_thinning", "%") },
    { key: "forming_limit_margin", label: "FLD margin", unit: "% true strain",
      sort: result("forming_limit_margin"), cell: valueCell("forming_limit_margin", "%"),
      title: "forming limit margin: the least distance of an element's major strain below " +
             "the forming limit curve (true strain), marked where marginal or over the curve" },
    { key: "actions", label: "", cell: actionsCell },
  ];
  function stateOrder(r) {
    // by STATES, queued runs by their place
    const i = STATES.indexOf(r.state);
    return i < 0 ? null : i * 1e6 + (r.place || 0);
  }

  const sorted = { key: null, dir: -1 };  // null: as the server lists them, newest first
  let runs = [], selected = null, hooks = null;

  function text(tag, content, cls) {
    const el = document.createElement(tag);
    el.textContent = content;
    if (cls) el.className = cls;
    return el;
  }

  function runCell(r) {
    // the id without its scene and element (their own columns): its start time and tag
    const span = document.createElement("span");
    const prefix = `${r.scene}-${r.element}-`;
    const short = text("span", r.id.startsWith(prefix) ? r.id.slice(prefix.length) : r.id,
                       "run-id");
    short.title = r.id;
    span.append(short);
    if (r.edited) {
      const e = text("span", "unsaved edits", "edited");
      e.title = `it ran the page's unsaved edits of ${r.scene}, not the saved file`;
      span.append(" ", e);
    }
    return span;
  }

  // what the run changed of its saved scene, in the form's units (the server's words)
  const changes = (r) => r.changes || [];

  function changesCell(r) {
    const list = changes(r);
    const span = text("span", list.length ? list.join("; ") : "as saved",
                      list.length ? "changes" : "changes muted");
    span.title = list.join("\n");
    return span;
  }

  function stateCell(r) {
    const span = document.createElement("span");
    const word = r.state === "queued" && r.place ? `queued #${r.place}` : r.state;
    span.append(text("span", word, `state-word ${r.state}`));
    if (r.reason && ["failed", "stopped", "cancelled"].includes(r.state))
      span.append(text("span", r.reason, "reason"));
    span.title = r.state === "queued" ? `${r.place === 1 ? "next" : `number ${r.place}`} ` +
                                        "in the queue: it starts when a solver is free"
                                      : (r.reason || r.state);
    return span;
  }

  function timeCell(r) {
    // the solver's time in its steps; the wall time, which also holds the build and any
    // pause, in its tooltip
    const wall = r.progress.elapsed_s;
    if (wall === null) return "–";
    const cell = text("span", Units.duration(r.stepping_s || 0));
    cell.title = `wall time ${Units.duration(wall)}` +
      (ACTIVE.includes(r.state) ? " so far" : "") +
      " from its start on a solver process (build, pauses and pacing included)";
    return cell;
  }

  function progressCell(r) {
    const p = r.progress, span = document.createElement("span");
    span.className = "mini-progress";
    const bar = document.createElement("span");
    bar.className = "bar";
    const fill = document.createElement("span");
    fill.className = "fill";
    fill.style.width = `${100 * (p.fraction || 0)}%`;
    bar.append(fill);
    span.append(bar, text("span", `${p.step}/${p.steps ?? "?"}`));
    return span;
  }

  function valueCell(name, unit) {
    return (r) => {
      const v = r.results[name];
      if (!v) return text("span", "–", "muted");
      const span = text("span", Units.withUnit(v.value, v.unit === unit ? "" : v.unit),
                        "num" + (v.flag ? ` flag-${v.flag}` : ""));
      if (v.flag) {
        span.title = `${v.flag}: ` + (name === "max_thinning" ? "the thinning reaches the " +
                                      "material card's limit (excessive thinning)"
                                                              : "a forming limit reached");
      }
      return span;
    };
  }

  function actionsCell(r) {
    const span = document.createElement("span");
    span.className = "actions";
    // a run that never reached a solver (queued, cancelled) has its scene and nothing else
    const ran = !["queued", "cancelled"].includes(r.state);
    const links = [["scene", `/api/runs/${r.id}/scene`, "_blank"]];
    if (ran) links.unshift(["recording", `/api/runs/${r.id}/recording`, "download"],
                           ["result", `/api/runs/${r.id}/result`, "_blank"]);
    for (const [label, href, extra] of links) {
      // the recording: a file once the run has ended with a frame (a run that failed while
      // it was built has none: its link answered 404 into a failed download)
      const framed = ((r.frames || {}).received || 0) > 0;
      if (label === "recording" && (ACTIVE.includes(r.state) || !framed)) {
        const none = text("span", label, "unavailable muted");
        none.title = ACTIVE.includes(r.state)
          ? "its recording (rerun .rrd) is complete when the run ends"
          : "no recording: the run ended before its first frame";
        span.append(none, " ");
        continue;
      }
      const a = text("a", label);
      a.href = href;
      if (extra === "download") a.download = ""; else a.target = extra;
      if (label === "recording")
        a.title = "the run's recording (rerun .rrd): play it back with q3t play, or in the " +
                  "Rerun viewer; the page's 3-D view plays it when the run is selected";
      span.append(a, " ");
    }
    if (r.state === "queued") span.append(button("Cancel", "cancel", () => cancel(r)));
    const del = button("Delete", "delete", () => remove(r));
    del.disabled = ACTIVE.includes(r.state);
    del.title = del.disabled ? `run ${r.id} is ${r.state}: stop it first` : `delete run ${r.id}`;
    span.append(del);
    return span;
  }

  function button(label, cls, action) {
    const b = text("button", label, cls);
    b.type = "button";
    b.onclick = (ev) => { ev.stopPropagation(); action(); };
    return b;
  }

  async function cancel(r) {
    try {
      await api("POST", `/api/runs/${r.id}/stop`);
      hooks.say(`cancelled ${r.id}: it will not start`);
      await hooks.reload();
    } catch (e) { hooks.say(e.message, true); }
  }

  async function remove(r) {
    const what = r.state === "queued" ? "It leaves the queue and never starts."
                                      : "Its recording and result are deleted too.";
    if (!confirm(`Delete run ${r.id}?\n${what}${Owner.note(r)}`)) return;
    try {
      await api("DELETE", `/api/runs/${r.id}`);
      hooks.say(`deleted ${r.id}`);
      await hooks.reload();
    } catch (e) { hooks.say(e.message, true); }
  }

  function order(list) {
    if (!sorted.key) return list;
    const col = COLUMNS.find((c) => c.key === sorted.key);
    // runs without the value (no result yet) go last whichever the direction
    const missing = (v) => v === null || v === undefined;
    return [...list].sort((a, b) => {
      const x = col.sort(a), y = col.sort(b);
      if (missing(x) || missing(y)) return missing(x) - missing(y);
      return (x < y ? -1 : x > y ? 1 : 0) * sorted.dir;
    });
  }

  function header() {
    const tr = document.createElement("tr");
    for (const c of COLUMNS) {
      const th = text("th", c.label);
      if (c.unit) th.append(text("span", ` (${c.unit})`, "unit"));
      th.dataset.key = c.key;
      if (c.title) th.title = c.title;
      if (c.sort) {
        th.className = "sortable";
        th.tabIndex = 0;
        th.setAttribute("aria-sort", sorted.key !== c.key ? "none"
                                    : sorted.dir > 0 ? "ascending" : "descending");
        th.onclick = () => sortBy(c.key);
        th.onkeydown = (ev) => {
          if (ev.key === "Enter" || ev.key === " ") { ev.preventDefault(); sortBy(c.key); }
        };
      }
      tr.append(th);
    }
    return tr;
  }

  function sortBy(key) {
    // first click: ascending (numbers small to large, names A to Z); again: the other way
    sorted.dir = sorted.key === key ? -sorted.dir : 1;
    sorted.key = key;
    draw(true);
    // the header row is drawn anew: the keyboard's focus goes back to the header pressed
    const th = document.querySelector(`#runs thead th[data-key="${key}"]`);
    if (th) th.focus({ preventScroll: true });
  }

  function row(r) {
    const tr = document.createElement("tr");
    tr.className = r.id === selected ? "sel" : "";
    tr.tabIndex = 0;  // chosen with the keyboard too (Enter or Space)
    Object.assign(tr.dataset, { id: r.id, state: r.state, edited: String(!!r.edited) });
    for (const c of COLUMNS) {
      const td = document.createElement("td");
      td.className = `col-${c.key}`;
      const content = c.cell(r);
      if (typeof content === "string") td.textContent = content; else td.append(content);
      tr.append(td);
    }
    return tr;
  }

  // A poll rebuilds only the rows whose run changed: a row replaced between a press and its
  // release would lose the click.
  function rowFor(r, old) {
    const sig = JSON.stringify(r) + (r.id === selected ? "|sel" : "");
    const kept = old.get(r.id);
    if (kept && kept.dataset.sig === sig) return kept;
    const tr = row(r);
    tr.dataset.sig = sig;
    return tr;
  }

  function draw(headers) {
    // the headers only when the sort changed: a poll keeps the one focused
    const table = document.getElementById("runs");
    if (headers || !table.querySelector("thead th"))
      table.querySelector("thead").replaceChildren(header());
    const tbody = table.querySelector("tbody");
    const old = new Map([...tbody.rows].map((tr) => [tr.dataset.id, tr]));
    const rows = order(runs).map((r) => rowFor(r, old));
    // a row with the keyboard's focus keeps it when a poll redraws it (its selection does)
    const focused = document.activeElement;
    const kept = focused && focused.parentNode === tbody ? focused.dataset.id : null;
    if (rows.length !== tbody.rows.length || rows.some((tr, i) => tbody.rows[i] !== tr))
      tbody.replaceChildren(...rows);
    const again = kept && rows.find((tr) => tr.dataset.id === kept);
    if (again && again !== document.activeElement) again.focus({ preventScroll: true });
    const box = document.getElementById("runs-box");
    box.querySelector("summary").textContent = `Runs (${runs.length})`;
  }

  // the selected run's row says what the headline says (its state, step and progress): the
  // headline's status over the list's entry, whichever of the two was read later
  let headline = null;
  const merged = (r) => {
    if (!headline || r.id !== headline.id) return r;
    const { records, ...fresh } = headline;
    return { ...r, ...fresh };
  };

  function show(list, selectedRun) {
    selected = selectedRun;
    runs = list.map(merged);
    draw();
  }

  function update(st) {
    headline = st;
    runs = runs.map(merged);
    draw();
  }

  function init(h) {
    // h: {select(id), say(text, isError), reload()}
    hooks = h;
    // selection on press, delegated to the body: it holds whichever rows the last poll drew
    document.querySelector("#runs tbody").addEventListener("pointerdown", (ev) => {
      const tr = ev.target.closest("tr[data-id]");
      if (ev.button !== 0 || !tr || ev.target.closest("a, button")) return;
      hooks.select(tr.dataset.id);
    });
    document.querySelector("#runs tbody").addEventListener("keydown", (ev) => {
      const tr = ev.target;
      if ((ev.key !== "Enter" && ev.key !== " ") || !tr.matches("tr[data-id]")) return;
      ev.preventDefault();  // Space would scroll the page
      hooks.select(tr.dataset.id);
    });
  }

  return { init, show, update, changes };
})();
