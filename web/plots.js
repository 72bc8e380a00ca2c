// The selected run's plots, drawn with plotly.js (served by the app: /static/vendor). Each
// draws from the server's numbers (/api/runs/{id}/plots, /forming_limits), already in the
// units shown (kN, mm, %); every axis says its quantity and unit.
"use strict";
// plotly.js is megabytes of script: parsed before the page's own, it held the whole page for
// seconds on a slow machine, so it is fetched when the first run is shown (one promise; a
// failed fetch stays failed until the page is reloaded, not retried at every poll)
let plotlyLoad = null;
function plotly() {
  plotlyLoad ||= new Promise((ok, fail) => {
    const s = document.createElement("script");
    s.src = "/static/vendor/plotly.min.js";
    s.onload = () => ok(window.Plotly);
    s.onerror = () => { s.remove(); fail(new Error("plotly.js did not load")); };
    document.head.appendChild(s);
  });
  return plotlyLoad;
}

// Every plot of the page is drawn and cleared through these two. Draws run in the order they
// were asked for, each once plotly.js is there; a clear of a div not drawn yet clears nothing.
function plotInto(div, traces, layout, config) {
  return plotly().then((P) => P.react(div, traces, layout, config));
}

function unplot(div) {
  if (div.data) Plotly.purge(div);
}

const Plots = (() => {
  // the toolbar keeps the image, box zoom and reset: with pan and the zoom steps as well it
  // covered a plot's title in a narrow column (1280 px wide)
  const CONFIG = { displaylogo: false, responsive: true,
                   modeBarButtonsToRemove: ["lasso2d", "select2d", "autoScale2d", "pan2d",
                                            "zoomIn2d", "zoomOut2d"] };
  const FONT = { family: "system-ui, sans-serif", size: 11 };
  const ZONE_COLOURS = { failure: "#d62728", marginal: "#ff9f1c", safe: "#2ca02c",
                         "insufficient stretch": "#8c8c8c", "wrinkling tendency": "#9467bd" };
  const MARK = "#b15928";
  const SCRUB = "#1f4fbf";  // the step the page's own 3-D view shows (its time slider)
  // the step this page's 3-D view was scrubbed to (null: none), and each plot drawn with
  // steps on its x axis: how to place a step, and its own marks (to add the scrub mark to)
  let scrubbed = null;
  const placed = new Map();

  function base(title, height) {
    // the title at the top, whatever room the marks' labels take under it
    return { title: { text: title, font: { size: 13 }, x: 0.02, yref: "container", y: 1,
                      yanchor: "top", pad: { t: 9 } }, height, autosize: true,
             font: FONT, margin: { l: 58, r: 16, t: 34, b: 42 }, hovermode: "closest",
             legend: { orientation: "h", y: -0.25, font: { size: 10 } } };
  }

  function axis(title, extra) {
    return { title: { text: title, standoff: 6 }, zeroline: false, automargin: true,
             ...extra };
  }

  function show(figId, on) {
    document.getElementById(figId).hidden = !on;
  }

  function draw(div, traces, layout, where) {
    // react: only what changed is redrawn (a live run redraws at every step). where(step):
    // the x of a step, for the scrub mark (plots over steps only)
    if (where) {
      placed.set(div, { where, shapes: layout.shapes || [], notes: layout.annotations || [] });
      layout = { ...layout, ...withScrub(placed.get(div)) };
      div.dataset.scrub = scrubbed === null ? "" : String(scrubbed);
    }
    return plotInto(div, traces, layout, CONFIG);
  }

  function withScrub(p) {
    // the plot's own marks and, when the 3-D view was scrubbed, a line at its step
    const x = scrubbed === null ? null : p.where(scrubbed);
    if (x === null || x === undefined) return { shapes: p.shapes, annotations: p.notes };
    return {
      shapes: [...p.shapes, { type: "line", xref: "x", yref: "paper", x0: x, x1: x, y0: 0,
                              y1: 1, line: { color: SCRUB, width: 2 } }],
      annotations: [...p.notes, { xref: "x", yref: "paper", x, y: 0, yanchor: "bottom",
                                  xanchor: "left", showarrow: false, bgcolor: "#ffffffcc",
                                  text: `3-D view: step ${scrubbed}`,
                                  font: { size: 10, color: SCRUB } }],
    };
  }

  function scrubAt(step) {
    // the page's 3-D view shows ``step`` (null: its run's latest): marked on every plot
    if (step === scrubbed) return;
    scrubbed = step;
    for (const [div, p] of placed) {
      div.dataset.scrub = step === null ? "" : String(step);
      plotly().then((P) => P.relayout(div, withScrub(p)));  // after its react
    }
  }

  // the live-parameter changes as vertical marks, at x = where(step it applies from); their
  // labels above the plot, in a top margin made that much taller (markRoom), on up to three
  // rows in turn: inside the plot they covered the curve's peak and the probes' row titles,
  // and changes a few steps apart wrote them over each other
  const markLabel = (k) => ({ xref: "x", yref: "paper", y: 1, yanchor: "bottom",
                              showarrow: false, yshift: 1 + 13 * (k % 3),
                              bgcolor: "rgba(255, 255, 255, 0.8)" });
  const markRoom = (margin, n) => (n ? { ...margin, t: margin.t + 13 * Math.min(3, n) }
                                     : margin);

  function marks(log, where, margin) {
    const shapes = [], notes = [];
    for (const e of log || []) {
      const x = where(e.step);
      if (x === null || x === undefined) continue;
      shapes.push({ type: "line", xref: "x", yref: "paper", x0: x, x1: x, y0: 0, y1: 1,
                    line: { color: MARK, width: 1.5, dash: "dot" } });
      notes.push({ ...markLabel(notes.length), x,
                   text: `${e.label} ${Units.num(e.value)} (step ${e.step})`,
                   font: { size: 10, color: MARK } });
    }
    return { shapes, annotations: notes, margin: markRoom(margin, notes.length) };
  }

  function strokeAt(punch, step) {
    // the stroke reached when the change took effect: at the end of the step before
    if (step <= 1) return 0;
    const k = punch.steps.indexOf(step - 1);
    return k < 0 ? null : punch.stroke.values[k];
  }

  function forceStroke(div, punches, log) {
    const byStroke = punches.some((p) => p.stroke);
    const traces = punches.map((p) => ({
      x: p.stroke ? p.stroke.values : p.steps, y: p.force.values, customdata: p.steps,
      name: p.tool, type: "scatter", mode: "lines+markers", marker: { size: 4 },
      hovertemplate: (p.stroke ? "stroke %{x:.3f} mm<br>" : "") +
        "force %{y:.4g} kN<br>step %{customdata}<extra>%{fullData.name}</extra>" }));
    const first = punches.find((p) => p.stroke);
    const where = first ? (s) => strokeAt(first, s) : (s) => s - 0.5;
    const b = base("Punch force against stroke", 280);
    const layout = { ...b,
                     xaxis: axis(byStroke ? "punch stroke (mm)" : "step", { rangemode: "tozero" }),
                     yaxis: axis(`punch force (${punches[0].force.unit})`, { rangemode: "tozero" }),
                     showlegend: punches.length > 1, ...marks(log, where, b.margin) };
    // a step's own point: the stroke at its end (the rest state at 0)
    const at = first ? (s) => (s === 0 ? 0 : stepValue(first, s)) : (s) => s;
    return draw(div, traces, layout, at);
  }

  function stepValue(punch, step) {
    const k = punch.steps.indexOf(step);
    return k < 0 ? null : punch.stroke.values[k];
  }

  // each quantity's row of a stacked plot over steps (px): its plot, a gap below it and
  // above it its legend: the title on a line of its own, then the names in columns of one
  // width, as many lines as they take (about 6.5 px a character of the longest name and 46
  // px for its mark). Fixed widths, not plotly's own, make the lines countable before drawing.
  const ROW = 124, GAP = 12, LINE = 21, CHAR = 6.5, SWATCH = 46;

  function stacked(width, margin, rows) {
    // a row per quantity ({kind, unit, names}), stacked, the steps shared below. Each row's
    // legend sits above it, titled with the quantity and its unit: one legend for all rows
    // put a dozen names far below the lines they name, and rotated titles longer than a row
    // overlapped their neighbours'. Returns the layout's height and axes and legends, and
    // the y axis and legend of a trace of row k.
    // the legend's room: the plot's width less the y axis's labels (a hidden div: the page's)
    const room = Math.max((width || 700) - margin.l - margin.r - 24, 120);
    const legends = rows.map((r) => {
      const entry = Math.min(room, SWATCH + CHAR * Math.max(...r.names.map((n) => n.length)));
      const lines = 1 + Math.ceil(r.names.length / Math.max(1, Math.floor(room / entry)));
      return { entry, lead: 4 + LINE * lines };
    });
    const plotted = legends.reduce((h, g) => h + g.lead + ROW + GAP, 0);
    const layout = { height: plotted + margin.t + margin.b,
                     xaxis: axis("step", { anchor: rows.length > 1 ? `y${rows.length}` : "y" }) };
    let top = plotted;  // px above the bottom margin
    rows.forEach((r, k) => {
      const { entry, lead } = legends[k];
      const unit = r.kind === "?" ? "SI" : r.unit || "count";
      const name = r.kind === "?" ? "no kind recorded" : r.kind.replaceAll("_", " ");
      layout[k ? `yaxis${k + 1}` : "yaxis"] = axis(unit, {
        anchor: "x", title: { text: unit, standoff: 4, font: { size: 10 } },
        domain: [(top - lead - ROW) / plotted, (top - lead) / plotted] });
      layout[k ? `legend${k + 1}` : "legend"] = {
        orientation: "h", x: 0, xref: "paper", xanchor: "left", y: top / plotted,
        yref: "paper", yanchor: "top", font: { size: 10 }, bgcolor: "rgba(0,0,0,0)",
        entrywidth: entry, entrywidthmode: "pixels", tracegroupgap: 0,
        title: { text: `<b>${name}</b> (${unit})`, side: "top" } };
      top -= lead + ROW + GAP;
    });
    const row = (k) => ({ yaxis: k ? `y${k + 1}` : "y", legend: k ? `legend${k + 1}` : "legend",
                          showlegend: true });
    return { layout, row };
  }

  function quantities(series) {
    // the probes' kinds in order of first appearance, each with its unit and trace names
    const rows = [];
    for (const s of series) {
      const kind = s.kind || "?";
      const r = rows.find((x) => x.kind === kind) ||
                rows[rows.push({ kind, unit: s.unit, names: [] }) - 1];
      r.names.push(s.label || s.name);
    }
    return rows;
  }

  // a probes plot's legend lines are counted at the width it was drawn at: plotly's own
  // resize keeps that layout's heights, so a new width draws it again (what it was drawn
  // from kept per div)
  const probesDrawn = new Map();
  const probesResized = new ResizeObserver((seen) => {
    for (const e of seen) {
      const d = probesDrawn.get(e.target), w = Math.round(e.contentRect.width);
      if (d && w > 0 && w !== d.width) probes(e.target, d.series, d.log);
    }
  });

  function probes(div, series, log) {
    const rows = quantities(series);
    const b = base("Probes", 0);
    const width = div.clientWidth || div.parentElement.clientWidth;
    if (!probesDrawn.has(div)) probesResized.observe(div);
    probesDrawn.set(div, { series, log, width });
    const mk = marks(log, (s) => s - 0.5, b.margin);
    const { layout, row } = stacked(width, mk.margin, rows);
    const traces = series.map((s) => ({
      x: s.steps, y: s.values, name: s.name, type: "scatter", mode: "lines+markers",
      marker: { size: 3 }, xaxis: "x", ...row(rows.findIndex((r) => r.kind === (s.kind || "?"))),
      hovertemplate: `${s.name}: %{y:.4g} ${s.unit}<br>step %{x}<extra></extra>` }));
    return draw(div, traces, { ...b, ...layout, ...mk }, (s) => s);
  }

  function sections(div, found, punch) {
    const traces = [];
    for (const sec of found) {
      for (const s of sec.steps) {
        const stroke = punch && punch.stroke ? strokeAt(punch, s.step + 1) : null;
        // to nine digits: a sheet not yet thinned is uniform but for its last bits, which the
        // axis's autoscale otherwise spread over the plot (a zigzag, ticks 0.7799999999999999)
        const y = s.thickness.values.map((t) => (Number.isFinite(t) ? +t.toPrecision(9) : t));
        traces.push({ x: s.position.values, y, type: "scatter",
                      mode: "lines+markers", marker: { size: 4 },
                      name: `${found.length > 1 ? sec.name + ", " : ""}step ${s.step}` +
                            (stroke !== null ? ` (${Units.num(stroke)} mm)` : ""),
                      hovertemplate: "radius %{x:.3g} mm<br>thickness %{y:.4g} mm" +
                                     "<extra>%{fullData.name}</extra>" });
      }
    }
    // each section by name and the direction of its ray from the x axis (an anisotropic
    // sheet's rolling direction is hill48.rolling_angle from the same axis)
    const names = found.map((s) => `"${s.name}"` + (s.angle === null || s.angle === undefined
      ? "" : ` at ${Units.num(+s.angle.toFixed(1))} deg`)).join(", ");
    // the steps' names in two columns, the plot taller by the rows they take: one below the
    // other, seven steps overflowed plotly's legend into a scroll bar
    const rows = Math.ceil(traces.length / 2), PLOT = 196;  // px: the plot area's height
    const b = base(`Thickness, section ${names}`, 0);
    const margin = { ...b.margin, b: 50 + 18 * rows };
    // the legend says each curve's step even when there is one (plotly hides a lone trace's:
    // a failed run's only section, the rest state's flat line, read as the formed part)
    const layout = { ...b, height: PLOT + margin.t + margin.b, margin, showlegend: true,
                     legend: { ...b.legend, entrywidth: 0.5, entrywidthmode: "fraction",
                               y: -44 / PLOT, yanchor: "top" },
                     xaxis: axis("rest radius (mm)"), yaxis: axis("thickness (mm)") };
    return draw(div, traces, layout);
  }

  function rim(div, profile, entries) {
    // a drawn cup's rim height around the punch axis (the summary's earing profile), with
    // its largest and smallest heights marked: ears show as crests every 90 degrees
    const order = profile.angle.display.value.map((a, i) => [a, i]).sort((a, b) => a[0] - b[0]);
    const at = (xs) => order.map(([, i]) => xs[i]);
    const unit = profile.height.display.unit;
    const traces = [{ x: at(profile.angle.display.value), y: at(profile.height.display.value),
                      type: "scatter", mode: "lines+markers", marker: { size: 4 },
                      name: "rim", hovertemplate: `%{x:.1f} deg<br>rim height %{y:.3f} ${unit}` +
                                                   "<extra></extra>" }];
    for (const e of entries) {
      if (!e.at || !e.at.angle) continue;
      traces.push({ x: [e.at.angle.display.value], y: [e.display.value], type: "scatter",
                    mode: "markers", name: e.label.replace("Rim height, ", ""),
                    marker: { size: 9, symbol: "diamond-open", line: { width: 2 } },
                    hovertemplate: `${e.label}: %{y:.3f} ${e.display.unit} at %{x:.1f} deg` +
                                   "<extra></extra>" });
    }
    const layout = { ...base("Rim height around the cup", 260),
                     xaxis: axis("angle about the punch axis from x (deg)",
                                 { range: [-5, 365], dtick: 45 }),
                     yaxis: axis(`rim height (${unit})`) };
    return draw(div, traces, layout);
  }

  function fld(div, fl) {
    const pct = (xs) => xs.map((v) => 100 * v);
    const type = fl.minor.length > 4000 ? "scattergl" : "scatter";
    const traces = [];
    const point = (name, idx, colour) => traces.push({
      x: pct(idx.map((i) => fl.minor[i])), y: pct(idx.map((i) => fl.major[i])), type,
      mode: "markers", name: `${name} (${idx.length})`, marker: { size: 4, color: colour },
      hovertemplate: "minor %{x:.2f} %<br>major %{y:.2f} %<extra>" + name + "</extra>" });
    if (fl.zone && fl.zones) {
      for (const [code, name] of Object.entries(fl.zones)) {
        const idx = [];
        fl.zone.forEach((z, i) => { if (String(z) === code) idx.push(i); });
        if (idx.length) point(name, idx, ZONE_COLOURS[name]);
      }
    } else point("elements", fl.minor.map((_, i) => i), "#1f77b4");
    if (fl.curve) {
      traces.push({ x: pct(fl.curve.minor), y: pct(fl.curve.major), type: "scatter",
                    mode: "lines", name: "forming limit curve", line: { color: "#000" },
                    hovertemplate: "FLC: minor %{x:.2f} %, major %{y:.2f} %<extra></extra>" });
      if (fl.margin)
        traces.push({ x: pct(fl.curve.minor), y: pct(fl.curve.major.map((v) => v - fl.margin)),
                      type: "scatter", mode: "lines", name: "marginal",
                      line: { color: "#000", dash: "dash", width: 1 }, hoverinfo: "skip" });
    }
    // the elements' strains and the curve's lowest point (FLC0) in view, not the curve's
    // whole span: a preview's strains are often a few per cent
    const lo = (xs) => Math.min(0, ...xs), hi = (xs) => Math.max(0, ...xs);
    const flc0 = fl.curve ? 100 * fl.curve.flc0 : 0;
    const xr = [Math.min(-10, 1.3 * lo(pct(fl.minor))), Math.max(10, 1.3 * hi(pct(fl.minor)))];
    // and the curve over the points' minor strains: a drawn cup's flange (minor -60 %) lay
    // under a curve that ran off the top (a browser review)
    const points = pct(fl.minor);
    const [m0, m1] = [Math.min(0, ...points), Math.max(0, ...points)];
    const over = [];
    if (fl.curve) {
      const cx = pct(fl.curve.minor), cy = pct(fl.curve.major);
      // the curve at the points' ends (linear between its own points, held past them) and
      // its points between
      const at = (m) => {
        const k = cx.findIndex((v) => v >= m);
        if (k <= 0) return cy[k < 0 ? cy.length - 1 : 0];
        return cy[k - 1] + (cy[k] - cy[k - 1]) * (m - cx[k - 1]) / (cx[k] - cx[k - 1]);
      };
      over.push(at(m0), at(m1), ...cy.filter((_, i) => cx[i] >= m0 && cx[i] <= m1));
    }
    const yr = [Math.min(-2, 1.2 * lo(pct(fl.major))),
                Math.max(1.3 * flc0, 1.2 * hi(pct(fl.major)), 1.1 * hi(over), 10)];
    const layout = { ...base(`Forming limit diagram (step ${fl.step})`, 320),
                     xaxis: axis("minor true strain (%)", { range: xr }),
                     yaxis: axis("major true strain (%)", { range: yr }) };
    return draw(div, traces, layout);
  }

  function solver(div, s) {
    const traces = [
      { x: s.steps, y: s.residual, name: "residual", type: "scatter", mode: "lines+markers",
        marker: { size: 3 }, hovertemplate: "residual %{y:.2e}<br>step %{x}<extra></extra>" },
      { x: s.steps, y: s.iterations, name: "Newton iterations", yaxis: "y2", type: "bar",
        opacity: 0.35, hovertemplate: "%{y} iterations<br>step %{x}<extra></extra>" }];
    // iterations are counted: whole ticks, about five (an overlaid axis's ticks are synced
    // to the residual's by default, which put them at 1.7, 3.47, ...); the residual a label
    // a decade
    const most = s.iterations.reduce((a, n) => (Number.isFinite(n) && n > a ? n : a), 1);
    const decade = 10 ** Math.floor(Math.log10(most / 5 || 1));
    const every = Math.max(1, [1, 2, 5, 10].map((f) => f * decade).find((d) => most / d <= 6));
    const layout = { ...base("", 220), margin: { l: 58, r: 50, t: 10, b: 42 },
                     xaxis: axis("step"),
                     yaxis: axis("relative residual", { type: "log", dtick: 1,
                                                        exponentformat: "power" }),
                     yaxis2: axis("Newton iterations", { overlaying: "y", side: "right",
                                                         rangemode: "tozero", tickmode: "linear",
                                                         tick0: 0, dtick: every }) };
    return draw(div, traces, layout, (x) => x);
  }

  function purge(div) {
    placed.delete(div);
    probesDrawn.delete(div);
    probesResized.unobserve(div);
    unplot(div);
  }

  return { markLabel, markRoom, forceStroke, probes, sections, rim, fld, solver, show, purge, scrubAt,
           stacked, quantities };
})();
