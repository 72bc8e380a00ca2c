// The scene form, generated from the scene JSON schema (GET /api/scenes/schema, pydantic's
// model_json_schema with $defs). Plain JS, no build step. Nested objects are fieldsets, tables
// of several kinds (oneOf with a discriminator) a kind select showing that kind's fields only,
// arrays lists with add/remove, enums selects, numbers text inputs with the schema's bounds,
// tuples (prefixItems) small input groups, booleans checkboxes, optional fields (anyOf with
// null) carry an "unset" box. Every field shows its description (the schema's: a tooltip, and
// below the field while it has the focus) and its unit. Every field's wrapper has
// data-path="material.nu", where the server's validation errors for that path are shown.
//
// Units: the file is SI; the form shows customary units (lengths mm, stresses MPa, forces kN,
// angles deg: units.js),
// always labelled, because an engineer reads 68000 MPa and 16.5 mm at a glance where 6.8e10
// and 0.0165 invite a slipped decimal; values are converted back to SI, and a value left as
// shown is sent back unchanged (no round-off). A decimal comma ("0,15") reads as 0.15.
//
// Files: a field the schema marks with "x-file" (mesh.path: a blank mesh or an outline drawing,
// shell.thickness_file, a mesh tool's shape.path) is a select of the scenes folder's files of
// that kind (GET /api/files) with an upload button
// beside it (POST /api/files; a name taken asks before it replaces the file).
"use strict";

const SceneForm = (() => {
  const el = (tag, props = {}, ...kids) => {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(props)) {
      if (k === "class") e.className = v;
      else if (k === "dataset") Object.assign(e.dataset, v);
      else if (k in e) e[k] = v;
      else e.setAttribute(k, v);
    }
    e.append(...kids.filter((k) => k !== null && k !== undefined));
    return e;
  };
  const clone = (v) => (v === undefined ? undefined : JSON.parse(JSON.stringify(v)));
  // SI unit -> [shown unit, factor] (units.js: the Runs table shows overrides the same way)
  const shown = (unit) => Units.sceneUnit(unit);
  // a number as the form writes it: 12 significant digits, so 0.0165 m is 16.5 mm, not
  // 16.499999999999996
  const fmt = (v) => String(Number(v.toPrecision(12)));
  // the text of a number input: a point or a single decimal comma; null when not a number
  const readNumber = (text) => {
    let t = text.trim();
    if (/^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$/.test(t)) t = t.replace(",", ".");
    if (t === "" || !/^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$/.test(t)) return null;
    return Number(t);
  };
  // a file's name as the server takes it (letters, digits, '_', '-', single dots; lower-case
  // extension): "My blank (v2).STL" -> "My_blank_v2.stl"; the server checks it again
  const fileName = (name) => {
    const dot = name.lastIndexOf(".");
    const ext = dot > 0 ? name.slice(dot).toLowerCase() : "";
    const stem = (dot > 0 ? name.slice(0, dot) : name).replace(/[^A-Za-z0-9_.-]+/g, "_")
      .replace(/\.{2,}/g, ".").replace(/^[^A-Za-z0-9]+/, "").replace(/[._]+$/, "")
      .slice(0, 80 - ext.length);
    return (stem || "upload") + ext;
  };
  // a field's name as the form shows it: the TOML key in words ("edge_length" -> "edge
  // length"); the key itself is in its tooltip and the TOML view
  const words = (key) => String(key).replaceAll("_", " ");
  const bytes = (n) => (n < 2 ** 20 ? `${(n / 1024).toFixed(1)} KiB`
                                   : `${(n / 2 ** 20).toFixed(1)} MiB`);
  // what a listed file holds, for its option (a thickness file has a value per vertex)
  const counts = (f) => (f.problem ? "unusable" : f.triangles !== null
    ? `${f.vertices} vertices, ${f.triangles} triangles` +
      (f.open ? ", open (set open: the tool behind its faces)" : "")
    : f.kind === "outline" ? `${f.holes} hole${f.holes === 1 ? "" : "s"}` : `${f.values} values`);
  // its size in its own units, which the scene's scale makes metres: a drawing in mm read
  // as metres shows when it is uploaded, before a preview refuses it
  // a drawing that says its units (an SVG's width in mm, a DXF's $INSUNITS) needs no scale
  const across = (f) => (f.extent ? `${f.extent.map((d) => +d.toPrecision(4)).join(" × ")} ` +
    "across in the file's units" + (f.units ? `, each ${+(1e3 * f.units.scale).toPrecision(4)} ` +
    `mm as it says (${f.units.said}): scale may be left empty` : " (scale: metres per unit)") +
    inMillimetres(f) + offCentre(f) : "");
  // no blank is more than 5 m across (sim.geometry.outline.EXTENT): a file that is, read as
  // metres, is most likely in mm
  const inMillimetres = (f) => (!f.units && Math.max(...f.extent) > 5
    ? `; read as metres that is ${+Math.max(...f.extent).toPrecision(4)} m across: a file in ` +
      "mm needs scale 0.001" : "");
  // a drawing whose origin is a corner lies beside the cup scenes' punch (on the z axis)
  const offCentre = (f) => (f.centre && Math.hypot(...f.centre) > 0.01 * Math.max(...f.extent)
    ? `; centred at (${f.centre.map((c) => +c.toPrecision(4)).join(", ")}), not at the ` +
      "origin: centre moves it there" : "");
  // each kind of file as an engineer says it (the server's kinds: /api/files)
  const KIND = { blank: "blank mesh", tool: "tool mesh", outline: "outline drawing",
                 thickness: "thickness file" };
  const described = (f) => `${KIND[f.kind] || f.kind}: ${counts(f)}`;
  // POST /api/files: the file's bytes as the body; the answer's JSON, or an Error with its
  // detail and status
  const upload = async (file, name, kind, replace) => {
    const q = new URLSearchParams({ name, kind, replace: String(replace) });
    let r;
    try {
      const headers = { "Content-Type": "application/octet-stream" };
      r = await fetch(`/api/files?${q}`, { method: "POST", body: file, headers });
    } catch (e) {  // a connection the server closed, e.g. past its size limit
      throw Object.assign(new Error(`upload of ${name} cut off (${e.message})`), { status: 0 });
    }
    const data = await r.json().catch(() => null);
    if (!r.ok) throw Object.assign(new Error((data && data.detail) || r.statusText),
                                   { status: r.status });
    return data;
  };

  class Form {
    // root: the container; schema: the scene schema; onChange(): called after every edit;
    // suggest(path, value): choices offered for a text field (names it may refer to), or null
    constructor(root, schema, onChange, suggest) {
      this.root = root;
      this.schema = schema;
      this.onChange = onChange || (() => {});
      this.suggest = suggest || (() => null);
      this.lists = 0;
      this.node = null;
      this.fileList = null;  // GET /api/files, once per build and after an upload
      root.addEventListener("input", () => this.onChange());
      root.addEventListener("change", () => { this.timeUnits(); this.onChange(); });
    }

    // a tool's velocity is its stroke over the run under static stepping (scene time runs
    // from 0 to 1), a speed under dynamic: its unit says which (a review read "mm/s" on the
    // static cup's punch)
    timeUnits() {
      const kind = ((this.value() || {}).stepping || {}).kind || "static";
      for (const span of this.root.querySelectorAll("span.unit[data-si='m/s']"))
        span.textContent = kind === "static" ? "mm over the run" : shown("m/s")[0];
    }

    resolve(s) {
      let guard = 0;
      while (s && s.$ref && guard++ < 32) s = this.schema.$defs[s.$ref.split("/").pop()];
      return s || {};
    }

    build(value) {
      this.fileList = null;
      this.node = this.object(this.schema, value || {}, "", "scene", true);
      this.root.replaceChildren(this.node.el);
      this.timeUnits();
    }

    value() {
      return this.node ? this.node.get() : {};
    }

    // ---- one field, any schema ------------------------------------------------------------
    // meta: the field's description and unit, from its own schema (a $ref or anyOf inside
    // carries neither)
    field(schema, value, path, key, required, meta) {
      meta = meta || { description: schema.description, unit: schema.unit,
                       file: schema["x-file"] };
      this.meta = meta;  // read by the widget made below (wrap, number)
      const s = this.resolve(schema);
      if (value === undefined && schema.default !== undefined) value = clone(schema.default);
      if (s.oneOf) return this.kinds(s, value, path, key, meta);
      if (s.anyOf) {
        const branches = s.anyOf.filter((b) => b.type !== "null");
        const nullable = branches.length < s.anyOf.length;
        if (branches.length === 1) {
          const inner = { ...this.resolve(branches[0]) };
          if (nullable) return this.optional(inner, value, path, key, meta);
          return this.field(inner, value, path, key, required, meta);
        }
        return this.json(s, value, path, key);
      }
      if (s.enum || s.const !== undefined) return this.select(s, value, path, key, required);
      if (s.type === "boolean") return this.checkbox(value, path, key);
      if (s.type === "number" || s.type === "integer") return this.number(s, value, path, key);
      if (s.type === "string") return this.text(s, value, path, key, required);
      if (s.type === "array" && s.prefixItems) return this.tuple(s, value, path, key);
      if (s.type === "array") return this.list(s, value, path, key);
      if (s.type === "object" || s.properties) return this.object(s, value, path, key, required);
      return this.json(s, value, path, key);
    }

    wrap(path, key, control, extra) {
      const { description, unit } = this.meta || {};
      const err = el("span", { class: "field-error" });
      const name = el("span", { class: "key", title: description ? `${path}: ${description}`
                                                             : path }, words(key));
      const u = shown(unit)[0];
      const label = el("label", {}, name, control,
                       u ? el("span", { class: "unit", dataset: { si: unit } }, u) : null);
      const help = description ? el("small", { class: "help" }, description) : null;
      return el("div", { class: "field", dataset: { path } }, label, extra, help, err);
    }

    // put ``extra`` next to a field's name: its legend or label (a table of several kinds:
    // that of the kind shown, and of any kind chosen later)
    byName(fieldEl, extra) {
      if (fieldEl.heads) fieldEl.heads.push(extra);
      const head = fieldEl.querySelector(":scope > legend, :scope > label, " +
                                         ":scope > fieldset > legend");
      (head || fieldEl).append(extra);
    }

    // a table of several kinds: a kind select, then the fields of that kind only (a new
    // kind keeps the values of the fields it shares with the old one)
    kinds(s, value, path, key, meta) {
      const tag = (s.discriminator || {}).propertyName || "kind";  // kind, or a law
      const members = s.oneOf.map((m) => this.resolve(m));
      const kindsOf = (m) => {
        const k = (m.properties || {})[tag] || {};
        return k.const !== undefined ? [k.const] : k.enum || [];
      };
      const all = members.flatMap(kindsOf);
      value = value && typeof value === "object" ? value : {};
      const sel = el("select", { name: `${path}.${tag}` });
      if (!all.includes(value[tag])) {
        sel.append(el("option", { value: "", textContent: `— choose a ${tag} —` }));
        if (value[tag] !== undefined)  // kept, so the server's error names it
          sel.append(el("option", { value: String(value[tag]),
                                    textContent: `${value[tag]} (unknown)` }));
      }
      for (const k of all) sel.append(el("option", { value: k, textContent: k }));
      sel.value = value[tag] === undefined ? "" : String(value[tag]);
      sel.dataset.tag = tag;
      const holder = el("div", { class: "kinds" });
      holder.heads = [];  // what others put by the name (unset, remove): kept across kinds
      let node;
      const show = (v) => {
        const member = members.find((m) => kindsOf(m).includes(v[tag]));
        const rest = Object.keys(v).filter((k) => k !== tag);
        this.meta = meta;
        if (!member && rest.length) node = this.unknownKind(v, tag, path, key, sel);
        else {
          const m = member || { properties: {} };
          node = this.object({ ...m, description: meta.description || m.description },
                             v, path, key, true, sel);
        }
        node.el.querySelector(":scope > legend").append(...holder.heads);
        holder.replaceChildren(node.el);
      };
      sel.addEventListener("change", () => show({ ...node.get(), [tag]: sel.value }));
      show(value);
      return { el: holder, get: () => {
        const v = node.get();
        if (sel.value !== "") v[tag] = all.includes(sel.value) ? sel.value : value[tag];
        return v;
      } };
    }

    // a table whose kind this schema does not know (a typo, a newer file): the form cannot
    // say which fields it has, so it shows them read-only and keeps them as they are, the
    // kind select first (choosing a known kind turns the shared ones into fields)
    unknownKind(value, tag, path, key, kindSelect) {
      const rest = clone(value);
      delete rest[tag];
      this.meta = {};
      const why = value[tag] === undefined ? `no ${tag} given`
                                           : `${tag} "${value[tag]}" is unknown here`;
      const note = el("p", { class: "unknown-kind" },
                      `${why}: its fields are kept as they are (read-only below, as the file ` +
                      `has them: SI) and saved with the scene; choose a known ${tag} to edit ` +
                      "them, or edit the TOML.");
      const kept = el("pre", { class: "kept-fields", dataset: { path: `${path}.kept` } },
                      Object.entries(rest).map(([k, v]) => `${k} = ${JSON.stringify(v)}`)
                        .join("\n"));
      const fs = el("fieldset", { class: "object", dataset: { path } },
                    el("legend", {}, words(key)),
                    this.wrap(`${path}.${tag}`, tag, kindSelect), note, kept,
                    el("div", { class: "field-error" }));
      return { el: fs, get: () => clone(rest) };
    }

    // kindSelect: a table of several kinds' select, shown as its "kind" field
    object(s, value, path, key, required, kindSelect) {
      value = value && typeof value === "object" ? value : {};
      const req = new Set(s.required || []);
      const kids = {};
      const legend = el("legend", {}, words(key));
      if (s.description) legend.title = s.description;
      const fs = el("fieldset", { class: "object", dataset: { path: path || "scene" } },
                    legend);
      for (const [k, sub] of Object.entries(s.properties || {})) {
        const sub_path = path ? `${path}.${k}` : k;
        let node;
        if (kindSelect && k === kindSelect.dataset.tag) {
          this.meta = { description: sub.description };
          node = { el: this.wrap(sub_path, k, kindSelect), get: () => undefined };
        } else node = this.field(sub, value[k], sub_path, k, req.has(k));
        if (req.has(k)) node.el.classList.add("required");
        kids[k] = node;
        fs.append(node.el);
      }
      fs.append(el("div", { class: "field-error" }));
      return {
        el: fs,
        get: () => {
          const out = {};
          for (const [k, n] of Object.entries(kids)) {
            const v = n.get();
            if (v !== undefined && v !== null) out[k] = v;
          }
          return out;
        },
      };
    }

    optional(inner, value, path, key, meta) {
      const unset = el("input", { type: "checkbox", class: "unset" });
      unset.checked = value === null || value === undefined;
      const node = this.field(inner, unset.checked ? undefined : value, path, key, false, meta);
      const tag = el("label", { class: "unset-label" }, unset, "unset");
      const show = () => {
        const outerUnset = !!(node.el.parentElement && node.el.parentElement.closest(".is-unset"));
        const off = unset.checked || outerUnset;
        node.el.classList.toggle("is-unset", unset.checked);
        unset.disabled = outerUnset;
        for (const c of node.el.querySelectorAll("input, select, textarea, button"))
          if (c !== unset) c.disabled = off;
        if (!off)  // optional fields inside keep their own state
          for (const c of node.el.querySelectorAll("input.unset")) if (c !== unset) c.show();
      };
      unset.show = show;
      unset.addEventListener("change", show);
      // the "unset" box goes next to the field's name (a fieldset's legend or label)
      this.byName(node.el, tag);
      node.el.classList.add("optional");
      show();
      return { el: node.el, get: () => (unset.checked ? null : node.get()) };
    }

    select(s, value, path, key, required) {
      const options = [...(s.enum || [s.const])];
      const sel = el("select", { name: path });
      if (value === undefined || value === null)
        sel.append(el("option", { value: "", textContent: "—" }));
      else if (!options.includes(value)) {  // kept, so the server's error names it
        options.push(value);
        sel.append(el("option", { value: String(value), textContent: `${value} (unknown)` }));
      }
      for (const o of options.slice(0, (s.enum || [s.const]).length))
        sel.append(el("option", { value: String(o), textContent: o }));
      sel.value = value === undefined || value === null ? "" : String(value);
      return {
        el: this.wrap(path, key, sel),
        get: () => (sel.value === "" ? undefined :
          options.find((o) => String(o) === sel.value)),
      };
    }

    checkbox(value, path, key) {
      const box = el("input", { type: "checkbox", name: path });
      box.checked = !!value;
      const w = this.wrap(path, key, box);
      w.classList.add("bool");
      return { el: w, get: () => box.checked };
    }

    // a text input (type=number would show what the browser's locale makes of "0,15" and
    // cut long values): the value in the shown unit, the schema's bounds checked here
    numberInput(s, value, name) {
      const si = (this.meta || {}).unit;
      const unit = shown(si)[0];
      const inp = el("input", { type: "text", name, class: "num", inputMode: "decimal",
                                autocomplete: "off", spellcheck: false });
      const first = typeof value === "number" ? String(Units.toShown(value, si)) : "";
      inp.value = first;
      const size = () => { inp.size = Math.max(6, inp.value.length + 1); };
      const u = unit ? ` ${unit}` : "";
      const ends = [["minimum", "≥"], ["exclusiveMinimum", ">"], ["maximum", "≤"],
                    ["exclusiveMaximum", "<"]].filter(([k]) => s[k] !== undefined);
      const bounds = ends.map(([k, op]) => `${op} ${Units.toShown(s[k], si)}${u}`);
      if (bounds.length) inp.title = bounds.join(", ");
      const check = () => {
        const v = readNumber(inp.value);
        let msg = "";
        if (inp.value.trim() !== "" && v === null)
          msg = `${inp.value.trim()} is not a number (write 0.15 or 0,15; 1e9)`;
        else if (v !== null && s.type === "integer" && !Number.isInteger(v))
          msg = "must be a whole number";
        else if (v !== null) {
          const x = Units.toSI(v, si);
          for (const [k, op] of ends) {
            const b = s[k];
            const out = { "≥": x < b, ">": x <= b, "≤": x > b, "<": x >= b }[op];
            if (out) msg = `must be ${op} ${Units.toShown(b, si)}${u}`;
          }
        }
        inp.setCustomValidity(msg);
        inp.title = msg || bounds.join(", ");
        size();
      };
      inp.addEventListener("input", check);
      inp.addEventListener("blur", () => {  // "0,15" shows as what it reads: 0.15
        const v = readNumber(inp.value);
        if (v !== null && inp.value.includes(",")) { inp.value = fmt(v); check(); }
      });
      check();
      // a value left as shown goes back as it came (no round-off of the unit conversion);
      // empty: null; not a number: the text, which the server names as the field's error
      const get = () => {
        if (inp.value === first && typeof value === "number") return value;
        if (inp.value.trim() === "") return null;
        const v = readNumber(inp.value);
        return v === null ? inp.value : Units.toSI(v, si);
      };
      return { inp, get };
    }

    number(s, value, path, key) {
      const { inp, get } = this.numberInput(s, value, path);
      return { el: this.wrap(path, key, inp), get: () => (inp.value === "" ? undefined : get()) };
    }

    text(s, value, path, key, required) {
      if ((this.meta || {}).file) return this.file(this.meta.file, value, path, key, required);
      const inp = el("input", { type: "text", name: path });
      if (s.pattern) inp.pattern = s.pattern;
      inp.value = value === undefined || value === null ? "" : String(value);
      // names this field may refer to (regions, tools, probes, elements), as of now
      inp.addEventListener("focus", () => {
        const choices = this.suggest(path, this.value());
        if (!choices) return;
        if (!inp.list) {
          const dl = el("datalist", { id: `scene-form-list-${++this.lists}` });
          inp.after(dl);
          inp.setAttribute("list", dl.id);
        }
        inp.list.replaceChildren(...choices.map((c) => el("option", { value: c })));
      });
      // a required name left empty is missing (the server says so), not ""
      return { el: this.wrap(path, key, inp),
               get: () => (inp.value === "" && required ? undefined : inp.value) };
    }

    files() {
      if (!this.fileList) this.fileList = api("GET", "/api/files");
      return this.fileList;
    }

    // a file of the scenes folder of ``kind``: a select of those there, an upload button and
    // a delete button (the server refuses to delete a file a saved scene names)
    file(kind, value, path, key, required) {
      const sel = el("select", { name: path, class: "file-select" });
      const status = el("span", { class: "upload-status", role: "status" });
      const say = (text, bad) => {
        status.textContent = text;
        status.classList.toggle("bad", !!bad);
      };
      // a refused upload's word goes once a file is chosen by hand (it stood under a valid
      // choice, a review)
      sel.addEventListener("change", () => {
        if (status.classList.contains("bad")) say("");
      });
      const folder = { limit: null, accept: "" };  // the server's limit and the extensions
      const fill = (list, chosen) => {
        const options = [el("option", { value: "", textContent: "— choose a file —" })];
        // by extension: a tool's surface and a blank are both meshes, the field's own kind
        // first, each labelled with its kind (the server's: what a scene uses it as)
        const exts = list.kinds[kind] || [];
        const mine = list.files.filter((f) => exts.some((x) => f.name.endsWith(x)))
          .sort((a, b) => (a.kind !== kind) - (b.kind !== kind));
        for (const f of mine)
          options.push(el("option", { value: f.name, textContent: `${f.name} (${described(f)})`,
                                      title: f.problem || [bytes(f.size), across(f)]
                                        .filter(Boolean).join(", ") }));
        if (chosen && !mine.some((f) => f.name === chosen))  // a path in a subfolder, or gone
          options.push(el("option", { value: chosen, textContent: chosen }));
        sel.replaceChildren(...options);
        sel.value = chosen || "";
        folder.accept = list.kinds[kind].join(",");
        folder.limit = list.max_upload;
      };
      // the folder as it is now, ``chosen`` selected, and the form told
      const refresh = async (chosen) => {
        this.fileList = null;
        fill(await this.files(), chosen);
        sel.dispatchEvent(new Event("change", { bubbles: true }));
      };
      fill({ files: [], kinds: { [kind]: [] } }, value);
      this.files().then((list) => fill(list, sel.value))
        .catch((e) => say(`files: ${e.message}`, true));
      const group = el("span", { class: "file-choice" }, sel,
                       ...this.uploadButton(kind, folder, say, refresh),
                       this.deleteButton(sel, say, refresh));
      const w = this.wrap(path, key, group, status);
      return { el: w, get: () => (sel.value === "" && required ? undefined : sel.value) };
    }

    // Upload…: a file chooser, then POST /api/files; a name taken asks before replacing
    uploadButton(kind, folder, say, refresh) {
      const chooser = el("input", { type: "file", hidden: true });
      const article = /^[aeiou]/.test(kind) ? "an" : "a";  // an outline file
      const button = el("button", { type: "button", class: "upload",
                                    textContent: "Upload…", title: `upload ${article} ${kind} file` });
      button.onclick = () => { chooser.accept = folder.accept; chooser.click(); };
      chooser.onchange = async () => {
        const file = chooser.files[0];
        chooser.value = "";
        if (!file) return;
        const name = fileName(file.name);
        if (folder.limit !== null && file.size > folder.limit)
          return say(`${file.name}: ${bytes(file.size)} is past the server's limit of ` +
                     `${bytes(folder.limit)}`, true);
        say(`uploading ${name} (${bytes(file.size)})…`);
        try {
          let f;
          try { f = await upload(file, name, kind, false); } catch (e) {
            if (e.status !== 409 || !confirm(`${name} exists in the scenes folder. Replace it?`))
              throw e;
            f = await upload(file, name, kind, true);
          }
          await refresh(f.name);  // then said: the select shows it when the words do
          say(`uploaded ${f.name}: ${[described(f), across(f)].filter(Boolean).join("; ")}`);
        } catch (e) { say(e.message, true); }
      };
      return [button, chooser];
    }

    // Delete: the chosen file, from the scenes folder, once confirmed
    deleteButton(sel, say, refresh) {
      const button = el("button", { type: "button", class: "delete-file", textContent: "Delete",
                                    title: "delete the chosen file from the scenes folder" });
      button.onclick = async () => {
        const name = sel.value;
        if (!name) return say("choose a file to delete", true);
        if (!confirm(`Delete ${name} from the scenes folder?`)) return;
        try {
          await api("DELETE", `/api/files/${encodeURIComponent(name)}`);
          await refresh("");
          say(`deleted ${name}`);
        } catch (e) { say(e.message, true); }
      };
      return button;
    }

    tuple(s, value, path, key) {
      value = Array.isArray(value) ? value : [];
      const group = el("span", { class: "tuple" });
      const parts = s.prefixItems.map((item, i) => {
        const it = this.resolve(item);
        if (it.type === "number" || it.type === "integer") {
          const n = this.numberInput(it, value[i], `${path}.${i}`);
          n.inp.dataset.path = `${path}.${i}`;
          group.append(n.inp);
          return n.get;
        }
        const inp = el("input", { type: "text", name: `${path}.${i}`, class: "num" });
        inp.value = value[i] === undefined ? "" : String(value[i]);
        group.append(inp);
        return () => inp.value;
      });
      const w = this.wrap(path, key, group);
      return { el: w, get: () => parts.map((g) => g()) };
    }

    list(s, value, path, key) {
      const meta = this.meta || {};
      const itemSchema = s.items || {};
      const resolved = this.resolve(itemSchema);
      const isObj = resolved.type === "object" || !!resolved.properties || !!resolved.oneOf;
      // a row of a table of several units (keyframes: t, m, rad): each number in its
      // column's unit, named, on one line
      const cols = resolved.type === "array" ? null : Units.columns(meta.unit);
      const box = el("div", { class: isObj ? "list objects" : cols ? "list scalars row"
                                                                    : "list scalars" });
      const add = el("button", { type: "button", class: "add", textContent: `+ ${words(key)}` });
      const u = shown(meta.unit)[0];
      const legend = el("legend", {}, words(key),
                        u ? el("span", { class: "unit" }, ` (${u})`) : null);
      if (meta.description) legend.title = meta.description;
      const fs = el("fieldset", { class: "array", dataset: { path } },
                    legend, box, add, el("div", { class: "field-error" }));
      let nodes = [];
      const render = (values) => {
        box.replaceChildren();
        nodes = values.map((v, i) => {
          const [colName, colUnit] = (cols && cols[i]) || ["", meta.unit];
          const label = isObj ? `${key} ${i}${v && v.name ? ` — ${v.name}` : ""}` : colName;
          // a list of numbers: each item in the list's unit (a row's: its column's)
          const n = this.field(itemSchema, v, `${path}.${i}`, label, true,
                               isObj ? undefined : { unit: cols ? colUnit : meta.unit });
          const rm = el("button", { type: "button", class: "remove", textContent: "✕",
                                    title: `remove ${key} ${i}` });
          rm.setAttribute("aria-label", `remove ${key} ${i}`);
          rm.onclick = () => {
            const vals = nodes.map((x) => x.get());
            vals.splice(i, 1);
            render(vals);
            this.onChange();
          };
          this.byName(n.el, rm);
          n.el.classList.add("item");
          box.append(n.el);
          return n;
        });
      };
      add.onclick = () => {
        const vals = nodes.map((x) => x.get());
        vals.push(isObj ? {} : clone(resolved.default));
        render(vals);
        this.onChange();
      };
      render(Array.isArray(value) ? value : []);
      return { el: fs, get: () => nodes.map((n) => n.get()) };
    }

    json(s, value, path, key) {
      // anything the form has no widget for: its JSON, as text
      const inp = el("input", { type: "text", name: path, class: "json" });
      inp.value = value === undefined ? "" : JSON.stringify(value);
      return {
        el: this.wrap(path, key, inp),
        get: () => {
          if (inp.value.trim() === "") return undefined;
          try { return JSON.parse(inp.value); } catch { return inp.value; }
        },
      };
    }

    // ---- errors from the server: [{loc: "material.nu", msg}] -------------------------------
    // shown next to the field they name (or its nearest enclosing field); returns the ones
    // that name no field of the form
    showErrors(errors) {
      for (const e of this.root.querySelectorAll(".field-error")) e.textContent = "";
      for (const e of this.root.querySelectorAll(".has-error")) e.classList.remove("has-error");
      return (errors || []).filter((e) => !this.markError(e.loc, e.msg));
    }

    // one error beside the field it names (or its nearest enclosing field), added to those
    // shown: false when it names no field of the form. The server's refusals that schema
    // validation cannot see (a drawing's size at its scale, a tool's file) go here too.
    markError(loc, msg) {
      let parts = loc.split("."), target = null;
      while (parts.length && !target) {
        target = this.root.querySelector(`[data-path="${CSS.escape(parts.join("."))}"]`);
        if (!target) parts = parts.slice(0, -1);
      }
      if (target && target.tagName === "INPUT") {  // a tuple's component
        target.classList.add("has-error");
        target = target.closest(".field");
      }
      if (!target || loc === "scene") return false;
      // a table's own rule that names its fields ("shell: give exactly one of thickness,
      // thickness_file, ...") goes beside the first of them the form shows, not under the
      // table's last field (a review emptied the thickness and saw it far below)
      // (and under the table as before: its rule is the table's)
      if (target.tagName === "FIELDSET" && parts.join(".") === loc) {
        const named = [...target.querySelectorAll(":scope > .field[data-path], " +
                                                  ":scope > fieldset[data-path]")]
          .find((f) => new RegExp(`\\b${f.dataset.path.split(".").pop()}\\b`).test(msg));
        if (named) this.markError(named.dataset.path, msg);
      }
      const left = loc.slice(parts.join(".").length + 1);
      const span = target.querySelector(":scope > .field-error");
      const text = (left ? `${left}: ` : "") + Units.shownMessage(msg);
      target.classList.add("has-error");
      if (!span.textContent.split("; ").includes(text))
        span.textContent += (span.textContent ? "; " : "") + text;
      return true;
    }
  }

  return { Form };
})();
