// The split-ring test on a finished cup run (POST /api/runs/{id}/split_ring, as `q3t
// splitring`): two heights and a cut angle, a button, and the run's rings as the server lists
// them, one column each (the plots column is narrow; the quantities are the rows).
"use strict";
const Rings = (() => {
  const HEIGHTS = [8, 13];  // mm: the command line's default ring (sim/apps/splitring.py)
  let drawn = null;  // "run/state" of the list on screen
  let shown = null;  // the run the inputs were filled for
  let busy = false;
  let pending = false;  // this page's own request is out
  let current = null;  // the run shown

  const $ = (id) => document.getElementById(id);
  const mm = (v) => Units.num(v, 3);

  function defaults(wall) {
    // the command line's ring where the wall holds it, else the wall's extent rounded out to
    // 0.1 mm (a small cup's wall may end below 13 mm)
    if (!wall || (wall[0] <= HEIGHTS[0] && HEIGHTS[1] <= wall[1] + 0.05)) return HEIGHTS;
    return [Math.floor(wall[0] * 10) / 10, Math.ceil(wall[1] * 10) / 10];
  }

  function clearErrors() {
    for (const id of ["ring-heights-error", "ring-angle-error", "ring-error"]) $(id).textContent = "";
    for (const id of ["ring-z1", "ring-z2", "ring-angle"]) $(id).classList.remove("has-error");
  }

  function showError(detail) {
    // next to the field the server names: heights, cut_angle, else under the button
    const field = /^(body\.)?heights/.test(detail) ? "heights"
      : /^(body\.)?cut_angle/.test(detail) ? "angle" : null;
    const text = detail.replace(/^body\./, "");
    if (field === "heights") {
      $("ring-heights-error").textContent = text;
      $("ring-z1").classList.add("has-error");
      $("ring-z2").classList.add("has-error");
    } else if (field === "angle") {
      $("ring-angle-error").textContent = text;
      $("ring-angle").classList.add("has-error");
    } else $("ring-error").textContent = text;
  }

  function setBusy(on, what) {
    busy = on;
    const b = $("ring-cut");
    b.disabled = on;
    b.textContent = on ? "Cutting…" : "Cut ring";
    $("split-ring").setAttribute("aria-busy", String(on));
    $("ring-busy").hidden = !on;
    $("ring-busy").textContent = on ? `Cutting the ring ${what}: released closed, split, ` +
      "released again (seconds to minutes)…" : "";
  }

  const band = (r) => `${Units.num(r.heights_mm[0])}–${Units.num(r.heights_mm[1])} mm`;

  // the table's rows: a label with its unit, and the value of a ring (one number a cell, so
  // a ring's column stays narrow)
  const D = { mean: "mean", d0: "0°", d90: "90°" };
  const ROWS = [
    ["Cut angle (deg)", (r) => Units.num(r.cut_angle_deg)],
    ["Elements", (r) => String(r.elements)],
    ["Opening at mid-height (mm)", (r) => mm(r.opening_mm.at_mid_height), "strong"],
    ["Opening along the cut, min (mm)", (r) => mm(r.opening_mm.min)],
    ["Opening along the cut, max (mm)", (r) => mm(r.opening_mm.max)],
    ...["formed", "released", "split"].flatMap((s) => Object.entries(D).map(([k, name]) => [
      `D ${s}, ${name} (mm)`, (r) => mm(r.diameters_mm[s][k]), k === "mean" ? "group" : ""])),
    ["Re-yield on release, closed (%)", (r) => Units.num(r.reyield_pct.closed, 2), "group"],
    ["Re-yield on release, split (%)", (r) => Units.num(r.reyield_pct.split, 2)],
  ];

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
      th.title = `${r.name} in the run folder (.npz; VTU for ParaView in the folder)`;
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
    return t;
  }

  function render(data) {
    const box = $("split-ring");
    box.hidden = !data.available && !data.rings.length;
    box.dataset.run = data.run;
    box.dataset.count = String(data.rings.length);
    $("ring-form").hidden = !data.available;
    $("ring-wall").textContent = data.wall_mm
      ? `The steep wall (over 60° from the horizontal) runs ${mm(data.wall_mm[0])} to ` +
        `${mm(data.wall_mm[1])} mm above the cup's bottom.`
      : (data.reason ? `No ring can be cut: ${data.reason}.` : "");
    if (shown !== data.run) {
      shown = data.run;
      const [z1, z2] = defaults(data.wall_mm);
      $("ring-z1").value = z1;
      $("ring-z2").value = z2;
      $("ring-angle").value = 0;
      clearErrors();
    }
    if (data.cutting && !busy) setBusy(true, band(data.cutting));
    else if (!data.cutting && busy && !pending) setBusy(false);
    const list = $("ring-list");
    if (!data.rings.length) {
      const p = document.createElement("p");
      p.className = "muted";
      p.textContent = "No ring cut from this run yet.";
      list.replaceChildren(p);
    } else list.replaceChildren(table(data.rings));
    box.dataset.ready = "true";
  }

  async function load(id) {
    let data;
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
    // again while a ring is cut elsewhere (another browser): its end shows the new ring
    if (drawn === k && !(busy && !pending)) return;
    drawn = k;
    await load(st.id);
  }

  async function cut() {
    const id = current;
    clearErrors();
    const z1 = parseFloat($("ring-z1").value.replace(",", "."));
    const z2 = parseFloat($("ring-z2").value.replace(",", "."));
    const angle = parseFloat($("ring-angle").value.replace(",", "."));
    if (!Number.isFinite(z1) || !Number.isFinite(z2)) {
      showError("heights: two numbers in mm above the cup's bottom");
      return;
    }
    if (!Number.isFinite(angle)) {
      showError("cut_angle: a number of degrees");
      return;
    }
    pending = true;
    setBusy(true, `${Units.num(z1)}–${Units.num(z2)} mm`);
    try {
      await api("POST", `/api/runs/${id}/split_ring`, { heights: [z1, z2], cut_angle: angle });
    } catch (e) {
      if (id === current) showError(e.message);
    } finally {
      pending = false;
      setBusy(false);
      if (id === current) await load(id);
    }
  }

  function forget() {
    drawn = shown = current = null;
    if (!pending) setBusy(false);
    $("split-ring").hidden = true;
    $("ring-list").replaceChildren();
    $("split-ring").dataset.ready = "false";
  }

  function init() {
    $("ring-cut").addEventListener("click", cut);
  }

  return { show, forget, init };
})();
