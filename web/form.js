// The scene form, generated from the scene JSON schema (GET /api/scenes/schema, pydantic's
// model_json_schema with $defs). Plain JS, no build step. Nested objects are fieldsets, arrays
// are lists with add/remove, enums selects, numbers number inputs with the schema's bounds,
// tuples (prefixItems) small input groups, booleans checkboxes, optional fields (anyOf with
// null) carry an "unset" box. Every field's wrapper has data-path="material.nu", where the
// server's validation errors for that path are shown.
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
      root.addEventListener("input", () => this.onChange());
      root.addEventListener("change", () => this.onChange());
    }

    resolve(s) {
      let guard = 0;
      while (s && s.$ref && guard++ < 32) s = this.schema.$defs[s.$ref.split("/").pop()];
      return s || {};
    }

    build(value) {
      this.node = this.object(this.schema, value || {}, "", "scene", true);
      this.root.replaceChildren(this.node.el);
    }

    value() {
      return this.node ? this.node.get() : {};
    }

    // ---- one field, any schema ------------------------------------------------------------
    field(schema, value, path, key, required) {
      const s = this.resolve(schema);
      if (value === undefined && schema.default !== undefined) value = clone(schema.default);
      if (s.anyOf) {
        const branches = s.anyOf.filter((b) => b.type !== "null");
        const nullable = branches.length < s.anyOf.length;
        if (branches.length === 1) {
          const inner = { ...this.resolve(branches[0]) };
          if (nullable) return this.optional(inner, value, path, key);
          return this.field(inner, value, path, key, required);
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
      const err = el("span", { class: "field-error" });
      const label = el("label", {}, el("span", { class: "key", title: path }, key), control);
      const box = el("div", { class: "field", dataset: { path } }, label, extra, err);
      return box;
    }

    object(s, value, path, key, required) {
      value = value && typeof value === "object" ? value : {};
      const req = new Set(s.required || []);
      const kids = {};
      const fs = el("fieldset", { class: "object", dataset: { path: path || "scene" } },
                    el("legend", {}, key));
      for (const [k, sub] of Object.entries(s.properties || {})) {
        const node = this.field(sub, value[k], path ? `${path}.${k}` : k, k, req.has(k));
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

    optional(inner, value, path, key) {
      const unset = el("input", { type: "checkbox", class: "unset" });
      unset.checked = value === null || value === undefined;
      const node = this.field(inner, unset.checked ? undefined : value, path, key, false);
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
      const head = node.el.querySelector(":scope > legend, :scope > label");
      (head || node.el).append(tag);
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

    numberInput(s, value, name) {
      const inp = el("input", { type: "number", name, class: "num" });
      inp.step = s.type === "integer" ? "1" : "any";
      const lo = s.minimum ?? s.exclusiveMinimum, hi = s.maximum ?? s.exclusiveMaximum;
      if (lo !== undefined) inp.min = lo;
      if (hi !== undefined) inp.max = hi;
      const bounds = [];
      if (s.minimum !== undefined) bounds.push(`≥ ${s.minimum}`);
      if (s.exclusiveMinimum !== undefined) bounds.push(`> ${s.exclusiveMinimum}`);
      if (s.maximum !== undefined) bounds.push(`≤ ${s.maximum}`);
      if (s.exclusiveMaximum !== undefined) bounds.push(`< ${s.exclusiveMaximum}`);
      if (bounds.length) inp.title = bounds.join(", ");
      if (typeof value === "number") inp.value = String(value);
      const check = () => {  // the browser checks min/max; the exclusive ends are ours
        const v = inp.value === "" ? NaN : Number(inp.value);
        let msg = "";
        if (s.exclusiveMinimum !== undefined && v <= s.exclusiveMinimum)
          msg = `must be greater than ${s.exclusiveMinimum}`;
        if (s.exclusiveMaximum !== undefined && v >= s.exclusiveMaximum)
          msg = `must be less than ${s.exclusiveMaximum}`;
        inp.setCustomValidity(msg);
      };
      inp.addEventListener("input", check);
      check();
      // empty (or not a number): null, which the server names as the field's error
      const get = () => (inp.value === "" ? null : Number(inp.value));
      return { inp, get };
    }

    number(s, value, path, key) {
      const { inp, get } = this.numberInput(s, value, path);
      return { el: this.wrap(path, key, inp), get: () => (inp.value === "" ? undefined : get()) };
    }

    text(s, value, path, key, required) {
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
      const itemSchema = s.items || {};
      const resolved = this.resolve(itemSchema);
      const isObj = resolved.type === "object" || !!resolved.properties;
      const box = el("div", { class: isObj ? "list objects" : "list scalars" });
      const add = el("button", { type: "button", class: "add", textContent: `+ ${key}` });
      const fs = el("fieldset", { class: "array", dataset: { path } },
                    el("legend", {}, key), box, add, el("div", { class: "field-error" }));
      let nodes = [];
      const render = (values) => {
        box.replaceChildren();
        nodes = values.map((v, i) => {
          const label = isObj ? `${key} ${i}${v && v.name ? ` — ${v.name}` : ""}` : "";
          const n = this.field(itemSchema, v, `${path}.${i}`, label, true);
          const rm = el("button", { type: "button", class: "remove", textContent: "✕",
                                    title: `remove ${key} ${i}` });
          rm.setAttribute("aria-label", `remove ${key} ${i}`);
          rm.onclick = () => {
            const vals = nodes.map((x) => x.get());
            vals.splice(i, 1);
            render(vals);
            this.onChange();
          };
          const head = n.el.querySelector(":scope > legend, :scope > label");
          (head || n.el).append(rm);
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
      const rest = [];
      for (const { loc, msg } of errors || []) {
        let parts = loc.split("."), target = null;
        while (parts.length && !target) {
          target = this.root.querySelector(`[data-path="${CSS.escape(parts.join("."))}"]`);
          if (!target) parts = parts.slice(0, -1);
        }
        if (target && target.tagName === "INPUT") {  // a tuple's component
          target.classList.add("has-error");
          target = target.closest(".field");
        }
        if (!target || loc === "scene") { rest.push({ loc, msg }); continue; }
        const matched = parts.join(".");
        const left = loc.slice(matched.length + 1);
        const span = target.querySelector(":scope > .field-error");
        target.classList.add("has-error");
        span.textContent += (span.textContent ? "; " : "") + (left ? `${left}: ` : "") + msg;
      }
      return rest;
    }
  }

  return { Form };
})();
