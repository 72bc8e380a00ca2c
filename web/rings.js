// The split-ring test on a finished cup run (POST /api/runs/{id}/split_ring, as `q3t
// splitring`): two heights and a cut angle, a button, and the run's rings as the server lists
// them, one column each (the plots column is narrow; the quantities are the rows), its files
// to download at its foot. While a ring is cut (by this page or another), the server's word
// on how far it has got, next to the button.
"use strict";
const Rings = (() => {
  const HEIGHTS = [8, 13];  // mm: the command line's default ring (sim/apps/splitring.py)
  // ms between fetches of a run's rings while its section is on screen: a ring cut by another
  // page or by `q3t splitring` shows within this (the server caches the final state's wall)
  const REFRESH_MS = 5000;
  // ... and while a ring is being cut: its stage and time move on within seconds
  const CUTTING_MS = 1000;
  let cutting = false;  // a ring of the run shown is being cut (this page's, or as listed)
  let drawn = null;  // "run/state" of the list on screen
  let fetched = 0;  // when it was fetched (Date.now())
  let shown = null;  // the run the inputs were filled for
  let current = null;  // the run shown
  // this page's cuts, per run: {band, inputs, pending, error}; the answer for a run not on
  // screen waits here until that run is shown again
  const mine = new Map();

  const $ = (id) => document.getElementById(id);
  // lengths in mm to the µm, as the command line's table: the opening and the change of
  // diameter between formed, released and split are tens of µm on diameters of tens of mm
  const mm = (v) => {
    if (v === null || v === undefined || !Number.isFinite(+v)) return "–";
    const t = (+v).toFixed(3);
    return t === "-0.000" ? "0.000" : t;
  };

  function defaults(wall) {
    // the command line's ring where the wall holds it, else the wall's extent rounded out to
    // 0.1 mm (a small cup's wall may end below 13 mm)
    if (!wall || (wall[0] <= HEIGHTS[0] && HEIGHTS[1] <= wall[1] + 0.05)) return HEIGHTS;
    return [Math.floor(wall[0] * 10) / 10, Math.ceil(wall[1] * 10) / 10];
  }

  function clearErrors() {
    for (const id of ["ring-heights-error", "ring-angle-error", "ring-error", "ring-heights-note",
                      "ring-angle-note"]) $(id).textContent = "";
    for (const id of ["ring-z1", "ring-z2", "ring-angle"]) $(id).classList.remove("has-error");
  }

  let wallMm = null;  // the steep wall of the run shown, mm above the bottom (server's listing)
  const number = (id) => parseFloat($(id).value.replace(",", "."));
  // defaults() rounds the wall's ends out to 0.1 mm: heights that far past it are its own
  const ROUNDED = 0.1;

  function check() {
    // the inputs as typed: what the server refuses by the same rule (not numbers, not 0 <= z1 <
    // z2) is said at once; heights past the steep wall and an angle past a turn get a note (a
    // band past the wall takes flatter elements if it reaches one's centre, which only the
    // cut knows; an angle is taken modulo 360). False when the inputs cannot be sent.
    clearErrors();
    const z1 = number("ring-z1"), z2 = number("ring-z2"), angle = number("ring-angle");
    let ok = true;
    if (!Number.isFinite(z1) || !Number.isFinite(z2)) {
      showError("heights: two numbers in mm above the cup's bottom");
      ok = false;
    } else if (!(z1 >= 0 && z1 < z2)) {
      showError(`heights: ${Units.num(z1)}, ${Units.num(z2)} mm: need 0 <= z1 < z2 (mm above ` +
                "the cup's bottom)");
      ok = false;
    } else if (wallMm && (z1 < wallMm[0] - ROUNDED || z2 > wallMm[1] + ROUNDED)) {
      $("ring-heights-note").textContent =
        `${Units.num(z1)}–${Units.num(z2)} mm reaches past the steep wall ` +
        `(${Units.num(wallMm[0])}–${Units.num(wallMm[1])} mm): the cut is refused if a ` +
        "flatter element lies in the band";
    }
    if (!Number.isFinite(angle)) {
      showError("cut_angle: a number of degrees");
      ok = false;
    } else if (angle < 0 || angle >= 360) {
      const turn = ((angle % 360) + 360) % 360;
      $("ring-angle-note").textContent = `${Units.num(angle)}° is the meridian at ` +
        `${Units.num(turn)}° (taken modulo 360°)`;
    }
    return ok;
  }

  // a detail names its fields at the start of each part ("body.heights: ...; body.cut_angle:
  // ..."); a reason may hold "; " itself ("...; nothing was written")
  const PART = /; (?=(?:body\.)?(?:heights|cut_angle|run_id)\b|body\.)/;

  function showError(detail) {
    // each part next to the field it names: heights, cut_angle, else under the button
    const by = { heights: [], angle: [], other: [] };
    for (const part of detail.split(PART)) {
      const text = part.replace(/^body\./, "");
      const field = /^heights\b/.test(text) ? "heights" : /^cut_angle\b/.test(text) ? "angle"
        : "other";
      by[field].push(text);
    }
    if (by.heights.length) {
      $("ring-heights-error").textContent = by.heights.join("; ");
      $("ring-heights-note").textContent = "";  // the error says more than the note
      $("ring-z1").classList.add("has-error");
      $("ring-z2").classList.add("has-error");
    }
    if (by.angle.length) {
      $("ring-angle-error").textContent = by.angle.join("; ");
      $("ring-angle-note").textContent = "";
      $("ring-angle").classList.add("has-error");
    }
    if (by.other.length) $("ring-error").textContent = by.other.join("; ");
  }

  const band = (r) => `${Units.num(r.heights_mm[0])}–${Units.num(r.heights_mm[1])} mm`;
  const upper = (t) => t.charAt(0).toUpperCase() + t.slice(1);
  const force = (v) => Units.withUnit(v, "N", 2);

  function progressLines(p) {
    // the server's listing of a ring being cut: its stage and time (kept on one line: "under
    // 1 s elapsed" wraps whole), and in a release how far Newton has got (the out-of-balance
    // force falls to its target as it converges)
    const time = `${Units.duration(p.elapsed_s)} elapsed`.replace(/ /g, "\u00a0");
    const lines = [`${upper(p.stage)} · ${time}`];
    if (p.newton) {
      lines.push(`Newton iteration ${p.newton.iteration}: out-of-balance force ` +
                 `${force(p.newton.residual_N)}, converged once below ` +
                 `${force(p.newton.target_N)}`);
    }
    return lines;
  }

  function setBusy(on, what, progress) {
    // the run on screen only: another run's ring may be cut meanwhile. ``progress``: the
    // server's listing of the cut (none yet right after this page's click)
    cutting = on;
    const b = $("ring-cut");
    b.disabled = on;
    b.textContent = on ? "Cutting…" : "Cut ring";
    $("split-ring").setAttribute("aria-busy", String(on));
    const box = $("ring-busy");
    box.hidden = !on;
    box.dataset.stage = on && progress ? progress.stage : "";
    if (!on) {
      box.replaceChildren();
      return;
    }
    const lines = progress
      ? [`Cutting the ring ${what} at ${Units.num(progress.cut_angle_deg)}°:`,
         ...progressLines(progress)]
      : [`Cutting the ring ${what}:`, "released closed, split, released again (seconds to " +
         "minutes)…"];
    box.replaceChildren(...lines.map((text, i) => {
      const line = document.createElement("span");
      line.className = ["what", "stage", "newton"][i];
      line.textContent = text;
      return line;
    }));
  }

  // the table's rows: a label with its unit, and the value of a ring (one number a cell, so
  // a ring's column stays narrow)
  // the diameters across the cut's meridian (0°) and square to it (90°): measured from the
  // cut, so rings cut at other angles read them along other axes of the cup (a review)
  const D = { mean: "mean", d0: "0° from the cut", d90: "90° from the cut" };
  const ROWS = [
    ["Cut angle (deg)", (r) => Units.num(r.cut_angle_deg)],
    ["Section points through the thickness",
     (r) => (r.section_points == null ? "–" : String(r.section_points))],
    ["Elements", (r) => String(r.elements)],
    ["Opening at mid-height (mm)", (r) => mm(r.opening_mm.at_mid_height), "strong"],
    ["Opening along the cut, min (mm)", (r) => mm(r.opening_mm.min)],
    ["Opening along the cut, max (mm)", (r) => mm(r.opening_mm.max)],
    ...["formed", "released", "split"].flatMap((s) => Object.entries(D).map(([k, name]) => [
      `D ${s}, ${name} (mm)`, (r) => mm(r.diameters_mm[s][k]), k === "mean" ? "group" : ""])),
    // a share of the ring's quadrature points whose plastic strain grew in that release
    ["Re-yield on release, closed (% of points)", (r) => Units.num(r.reyield_pct.closed, 2),
     "group"],
    ["Re-yield on release, split (% of points)", (r) => Units.num(r.reyield_pct.split, 2)],
  ];

  // a ring's files: the row's label says what each is, the link in a ring's column is short
  // (the column stays as narrow as its numbers)
  const FILES = { vtu: ["Download VTU (ParaView)", "VTU"], npz: ["Download npz (NumPy)", "npz"] };

  function fileRows(foot, rings) {
    // a row per file the server lists for the rings, a link per ring
    const formats = [...new Set(rings.flatMap((r) => r.downloads.map((f) => f.format)))];
    for (const fmt of formats) {
      const [label, short] = FILES[fmt] || [fmt, fmt];
      const tr = foot.insertRow();
      tr.dataset.format = fmt;
      const th = document.createElement("th");
      th.scope = "row";
      th.textContent = label;
      tr.append(th);
      for (const r of rings) {
        const td = tr.insertCell();
        const f = r.downloads.find((d) => d.format === fmt);
        if (!f) {
          td.textContent = "–";
          continue;
        }
        const a = document.createElement("a");
        a.href = f.url;
        a.setAttribute("download", "");
        a.dataset.format = fmt;
        a.textContent = short;
        a.title = `${r.name}: ${f.description}`;
        td.append(a);
      }
    }
  }

  function table(rings) {
    const t = document.createElement("table");
    t.id = "ring-table";
    const head = t.createTHead().insertRow();
    const corner = document.createElement("th");
    corner.textContent = "Ring (mm above the bottom)";
    head.append(corner);
    for (const r of rings) {
      const th = document.createElement("th");
      th.textContent = `${Units.num(r.heights_mm[0])}–${Units.num(r.heights_mm[1])}`;
      th.title = `${r.name} in the run folder (its files: the column's foot)`;
      th.dataset.name = r.name;
      head.append(th);
    }
    const body = t.createTBody();
    for (const [label, value, cls] of ROWS) {
      const tr = body.insertRow();
      const th = document.createElement("th");
      th.scope = "row";
      th.textContent = label;
      tr.append(th);
      if (cls === "group") tr.className = "group";
      for (const r of rings) {
        const td = tr.insertCell();
        td.textContent = value(r);
        if (cls === "strong") td.className = cls;
      }
    }
    fileRows(t.createTFoot(), rings);
    return t;
  }

  function fill(run, wall) {
    // the inputs of a run shown anew: what this page sent for it, else the defaults; the
    // answer to a cut that came while another run was shown, now
    const own = mine.get(run);
    const [z1, z2] = defaults(wall);
    const v = own ? own.inputs : { z1, z2, angle: 0 };
    $("ring-z1").value = v.z1;
    $("ring-z2").value = v.z2;
    $("ring-angle").value = v.angle;
    check();  // the notes of inputs this page sent (past the wall, past a turn)
    if (own && !own.pending) {
      mine.delete(run);
      if (own.error) showError(own.error);
    }
  }

  function render(data) {
    const box = $("split-ring");
    box.hidden = !data.available && !data.rings.length;
    box.dataset.run = data.run;
    box.dataset.count = String(data.rings.length);
    $("ring-form").hidden = !data.available;
    wallMm = data.wall_mm || null;
    $("ring-wall").textContent = data.wall_mm
      ? `The steep wall (over 60° from the horizontal) runs ${Units.num(data.wall_mm[0])} to ` +
        `${Units.num(data.wall_mm[1])} mm above the cup's bottom.`
      : (data.reason ? `No ring can be cut: ${data.reason}.` : "");
    if (shown !== data.run) {
      shown = data.run;
      fill(data.run, data.wall_mm);
    }
    const own = mine.get(data.run);
    // this page's cut, or another page's: as far as the server says it has got
    if (data.cutting) setBusy(true, band(data.cutting), data.cutting);
    else if (own && own.pending) setBusy(true, own.band);
    else setBusy(false);
    const list = $("ring-list");
    if (!data.rings.length) {
      const p = document.createElement("p");
      p.className = "muted";
      p.textContent = "No ring cut from this run yet.";
      list.replaceChildren(p);
    } else {
      // what the server says makes an opening untrustworthy, once for the rings it concerns
      const cautions = [...new Set(data.rings.map((r) => r.caution).filter(Boolean))];
      list.replaceChildren(table(data.rings), ...cautions.map((text) => {
        const p = document.createElement("p");
        p.className = "caution";
        p.setAttribute("role", "note");
        p.textContent = text;
        return p;
      }));
    }
    box.dataset.ready = "true";
  }

  async function load(id) {
    let data;
    fetched = Date.now();
    try {
      data = await api("GET", `/api/runs/${id}/split_ring`);
    } catch (e) {
      if (e.status === 404) return;  // deleted meanwhile
      throw e;
    }
    if (id === current) render(data);
  }

  async function show(st) {
    current = st.id;
    const k = `${st.id}/${st.state}`;
    if (["starting", "building", "running", "paused", "queued"].includes(st.state)) {
      $("split-ring").hidden = true;
      drawn = null;
      return;
    }
    // again after a while while the section is on screen: a ring cut by another page or by
    // the command line shows, and one being cut shows busy, its progress each second
    const every = cutting ? CUTTING_MS : REFRESH_MS;
    if (drawn === k && ($("split-ring").hidden || document.hidden ||
                        Date.now() - fetched < every)) return;
    drawn = k;
    await load(st.id);
  }

  async function cut() {
    const id = current;
    if (!check()) return;  // said next to the fields, nothing sent
    const inputs = { z1: $("ring-z1").value, z2: $("ring-z2").value, angle: $("ring-angle").value };
    const z1 = number("ring-z1"), z2 = number("ring-z2"), angle = number("ring-angle");
    const own = { band: `${Units.num(z1)}–${Units.num(z2)} mm`, inputs, pending: true,
                  error: null };
    mine.set(id, own);
    setBusy(true, own.band);
    try {
      await api("POST", `/api/runs/${id}/split_ring`, { heights: [z1, z2], cut_angle: angle });
    } catch (e) {
      own.error = e.message;
    }
    own.pending = false;
    if (id !== current) return;  // shown when the run is shown again (fill)
    mine.delete(id);
    setBusy(false);
    if (own.error) showError(own.error);
    await load(id);
  }

  function forget() {
    drawn = shown = current = null;
    setBusy(false);
    $("split-ring").hidden = true;
    $("ring-list").replaceChildren();
    $("split-ring").dataset.ready = "false";
  }

  function init() {
    $("ring-cut").addEventListener("click", cut);
    for (const id of ["ring-z1", "ring-z2", "ring-angle"]) $(id).addEventListener("input", check);
  }

  return { show, forget, init };
})();
