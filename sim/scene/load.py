"""Scene files: TOML validated into a frozen :class:`Scene` of the tables (sim.scene's modules).

``load_scene(path, overrides)`` applies ``key.path=value`` overrides to the raw TOML before
validation, so an override is checked exactly like the file. Errors name the field.
"""

from __future__ import annotations

import json
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Self

from pydantic import BaseModel, ValidationError, field_validator, model_validator

from sim.analytic import reference
from sim.elements import ELEMENTS
from sim.frames.probes import PROBES
from sim.scene.boundary import BCSpec, LoadSpec, RegionSpec
from sim.scene.fields import Strict, doc
from sim.scene.footprint import ranges_needed, ring_problem, sheet_problem
from sim.scene.run import ProbeSpec, SectionSpec, SolverSpec, SteppingSpec, StudySpec
from sim.scene.shapes import ToolSpec
from sim.scene.sheet import MaterialSpec, MeshSpec, ShellSpec
from sim.scene.tree import MAX_DEPTH, tree_problem

SCENE_NAME_MAX = 100


class Scene(Strict):
    name: str = doc(f"the scene's name: 1 to {SCENE_NAME_MAX} characters, no / or \\, no "
                    "control character, not starting with a dot")
    description: str = doc("one line on what it shows", default="")
    mesh: MeshSpec = doc("the sheet's mid-surface mesh")
    shell: ShellSpec = doc("the sheet's thickness and element")
    material: MaterialSpec = doc("the sheet's material")
    regions: list[RegionSpec] = doc("named sets of nodes (BCs, loads, probes)", default=[])
    bcs: list[BCSpec] = doc("prescribed displacements of regions", default=[])
    loads: list[LoadSpec] = doc("external loads", default=[])
    stepping: SteppingSpec = doc("how the run steps", default=SteppingSpec())
    solver: SolverSpec = doc("Newton's settings", default=SolverSpec())
    tools: list[ToolSpec] = doc("rigid tools in contact with the sheet", default=[])
    probes: list[ProbeSpec] = doc("numbers recorded at every step", default=[])
    sections: list[SectionSpec] = doc("radial sections recorded (thickness along a ray)",
                                      default=[])
    study: StudySpec | None = doc("a refinement study (q3t study)", default=None)

    @field_validator("name")
    @classmethod
    def _plain_name(cls, v: str) -> str:
        """A scene's name names its runs' folders (``q3t run``'s runs/<name>-...): no path in
        it, no control character, not hidden; a space or any other letter is a user's."""
        if (not 0 < len(v) <= SCENE_NAME_MAX or v.startswith(".")
                or any(c in "/\\" or ord(c) < 32 or ord(c) == 127 for c in v)):
            raise ValueError(f"it names the runs' folders: 1 to {SCENE_NAME_MAX} characters, "
                             "no / or \\, no control character, not starting with a dot")
        return v

    @model_validator(mode="after")
    def _references(self) -> Self:
        if self.shell.element not in ELEMENTS:
            raise ValueError(f"shell.element: unknown {self.shell.element!r}, "
                             f"known: {sorted(ELEMENTS)}")
        names = self._check_regions()
        for where, items in (("bcs", self.bcs), ("loads", self.loads), ("probes", self.probes)):
            for i, it in enumerate(items):
                if getattr(it, "region", None) and it.region not in names:
                    raise ValueError(f"{where}.{i}.region: unknown region {it.region!r}")
        tools = [t.name for t in self.tools]
        if len(set(tools)) != len(tools):
            raise ValueError("tools: names must be unique")
        for i, p in enumerate(self.probes):
            if p.tool is not None and p.tool not in tools:
                raise ValueError(f"probes.{i}.tool: unknown tool {p.tool!r}")
        if self.shell.thickness_attribute and not (
                self.mesh.kind == "file" and str(self.mesh.path).lower().endswith(".ply")):
            raise ValueError("shell.thickness_attribute: needs a PLY mesh file (mesh.kind = "
                             "'file', mesh.path ending in .ply)")
        plastic = self.material.model == "plastic"
        for i, p in enumerate(self.probes):  # nothing is recorded of a quantity the scene lacks
            if PROBES[p.kind].plastic and not plastic:
                raise ValueError(f"probes.{i}: a {p.kind} probe needs material.model = "
                                 "'plastic' (an elastic scene has no plastic strain)")
        flc = self.material.flc
        if flc and flc.kind == "keeler_brazier" and flc.thickness is None \
                and self.shell.thickness is None:
            raise ValueError("material.flc.thickness: Keeler-Brazier needs the sheet thickness; "
                             "the shell's is not one constant (give flc.thickness)")
        if self.study:
            self._check_study(self.study)
        return self

    def _check_regions(self) -> list[str]:
        """The regions' names, unique; a ring that misses a blank known before the build is
        named now, not when the model is made (sim.scene.footprint)."""
        names = [r.name for r in self.regions]
        if len(set(names)) != len(names):
            raise ValueError("regions: names must be unique")
        # the blank's radial ranges once, for its rings and its thickness
        ranges = ranges_needed(self.mesh, self.regions)
        if why := ring_problem(self.mesh, self.regions, ranges):
            raise ValueError(why)
        gradient = any(self.shell.thickness_gradient or ())
        if why := sheet_problem(None if gradient else self.shell.thickness, ranges):
            raise ValueError(why)
        return names

    def _check_study(self, st: StudySpec) -> None:
        probes = [p.name for p in self.probes]
        by_cells = hasattr(self.mesh, "cells")
        if st.cells and not by_cells:
            raise ValueError(f"study.cells: mesh kind {self.mesh.kind!r} is refined by "
                             "edge_length (study.edge_lengths)")
        if by_cells and (st.edge_lengths or st.reference_edge_length):
            raise ValueError(f"study.edge_lengths: mesh kind {self.mesh.kind!r} is refined by "
                             "cells per side (study.cells)")
        if st.probe is not None and st.probe not in probes:
            raise ValueError(f"study.probe: no probe named {st.probe!r}")
        if st.measure != "profile" and st.probe is None and not probes:
            raise ValueError("study.probe: the scene has no probe to study")
        if st.measure == "curve" and st.over != "time" and st.over not in probes:
            raise ValueError(f"study.over: 'time' or a probe name, not {st.over!r}")
        if st.measure == "profile":
            sec = next((s for s in self.sections if s.name == st.section), None)
            if sec is None:
                raise ValueError(f"study.section: no section named {st.section!r}")
            if st.step is not None and sec.steps and st.step not in sec.steps:
                raise ValueError(f"study.step: section {sec.name!r} records steps {sec.steps}, "
                                 f"not {st.step}")
        if st.analytic:
            reference(self, st.analytic, st.probe or probes[0])


class SceneError(ValueError):
    """A scene that cannot be loaded; the message names the field and the reason."""


PATH_PREFIX = re.compile(r"^([A-Za-z_]\w*(?:\.\w+)*): (.+)$", re.S)


BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _key(part: str | int) -> str:
    """A part of a field's path as TOML writes it: bare when it can be, else quoted (so an
    empty key shows as "")."""
    return str(part) if BARE_KEY.fullmatch(str(part)) else json.dumps(part)


# pydantic's bound errors: their words and the bound's key in the error's context
BOUNDS = {"greater_than": ("greater than", "gt"),
          "greater_than_equal": ("greater than or equal to", "ge"),
          "less_than": ("less than", "lt"), "less_than_equal": ("less than or equal to", "le")}


def scene_errors(err: ValidationError) -> list[dict]:
    """pydantic's errors as ``{loc, msg}``, ``loc`` the field's dotted path. A check on the
    whole scene names its field in the message (``bcs.0.region: unknown region 'x'``): that
    becomes the loc; pydantic's "Value error, " is dropped."""
    out = []
    for e in err.errors():
        parts, kind, tag = _untagged(e["loc"])
        loc = ".".join(_key(p) for p in parts)
        msg = e["msg"].removeprefix("Value error, ")
        # a plain unit only: "m per file unit" is a scale's, whose kinds differ in it
        if e["type"] in BOUNDS and (unit := unit_of(loc)) not in (None, "1") \
                and " " not in unit:
            # the bound with its unit (pydantic writes 1e-12 as 0.000000000001 and no unit):
            # the page shows it in the unit of the field's box (0.1 m as 100 mm)
            words, key = BOUNDS[e["type"]]
            msg = f"Input should be {words} {e['ctx'][key]:g} {unit}"
        if e["type"] == "union_tag_not_found":  # a table of several kinds without its kind
            msg = f"give its {e['ctx']['discriminator'].strip(chr(39))} (which kind it is)"
        if e["type"] == "extra_forbidden" and kind is not None:  # a field of another kind
            tag_field = next(t for t in TAGS if t in kind.model_fields)
            takes = ", ".join(f for f in kind.model_fields if f != tag_field) or "none"
            msg = f"not a field of {tag_field} {tag!r} (it takes {takes})"
        if not loc:
            m = PATH_PREFIX.match(msg)
            if m and m.group(1).split(".")[0] in Scene.model_fields:
                loc, msg = m.group(1), m.group(2)
            else:
                loc = "scene"
        out.append({"loc": loc, "msg": msg})
    return out


def _members(tp: object) -> list[type[BaseModel]]:
    """The model classes of a field's type, through Optional, Annotated and unions."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return [tp]
    if typing.get_origin(tp) in (typing.Union, types.UnionType, typing.Annotated):
        return [m for a in typing.get_args(tp) for m in _members(a)]
    return []


def _item(tp: object) -> object:
    """A list's item type (a list of tables); else the type itself."""
    if typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    for alt in typing.get_args(tp) if typing.get_origin(tp) in (typing.Union,
                                                                 types.UnionType) else [tp]:
        if typing.get_origin(alt) is list:
            return typing.get_args(alt)[0]
    return tp


def _untagged(loc: tuple) -> tuple[list, type[BaseModel] | None, str | None]:
    """pydantic's location without the kind it inserts after a field of several kinds
    (``mesh.disk.size`` is the field ``mesh.size`` of a disk), and, when the last part is a
    field of such a table, the table's model and kind (else None, None)."""
    out, tp, table, tag = [], Scene, None, None
    for part in loc:
        models = _members(tp)
        if isinstance(part, int):
            out.append(part)
            tp = _item(tp)
        elif len(models) > 1 and any(part in _kinds(m) for m in models):
            tp = next(m for m in models if part in _kinds(m))  # the member it validated as
            tag = part
        else:
            out.append(part)
            table = models[0] if len(models) == 1 else None
            field = table.model_fields.get(part) if table is not None else None
            tp = field.annotation if field is not None else None
            if tp is not None or table is None or tag not in _kinds(table):
                table = None
    return out, table, tag if table is not None else None


def unit_of(path: str) -> str | None:
    """The SI unit the schema gives the scene field at the dotted ``path``, as an override
    names it ("mesh.edge_length" -> "m", "tools.0.friction" -> "1"; a field of a table of
    several kinds: that of the kinds which have it); None for a field without a unit or no
    such field."""
    models, field = [Scene], None
    for part in (p for p in path.split(".") if not p.isdigit()):
        found = [m.model_fields[part] for m in models if part in m.model_fields]
        if not found:
            return None
        field = found[0]
        models = [m for f in found for m in _members(_item(f.annotation))]
    extra = field.json_schema_extra if field is not None else None
    return extra.get("unit") if isinstance(extra, dict) else None


# the fields that tell the kinds of a table of several kinds apart
TAGS = ("kind", "law")


def _kinds(model: type[BaseModel]) -> tuple[str, ...]:
    """The kinds a table of several kinds validates as (``kind: Literal[...]``, or law)."""
    field = next((model.model_fields[t] for t in TAGS if t in model.model_fields), None)
    return typing.get_args(field.annotation) if field is not None else ()


def joined(errors: list[dict]) -> str:
    return "; ".join(f"{e['loc']}: {e['msg']}" for e in errors)


def parse_value(text: str) -> Any:
    """A TOML value (number, bool, array, quoted string); bare words are strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_override(raw: dict, key: str, value: Any) -> None:
    """Set ``raw[a][b]...`` for ``key = "a.b..."``; list items by index (``loads.0.vector``)."""
    parts = key.split(".")
    if not all(parts):
        raise SceneError(f"{json.dumps(key)}: an override key is a field's dotted path, e.g. "
                         "material.nu or loads.0.vector")
    node = raw
    for p in parts[:-1]:
        if isinstance(node, list):
            if not p.isdigit() or int(p) >= len(node):
                raise SceneError(f"{key}: no item {p!r}")
            node = node[int(p)]
        else:
            node = node.setdefault(p, {})
        if not isinstance(node, (dict, list)):
            raise SceneError(f"{key}: {p!r} is not a table")
    last = parts[-1]
    if isinstance(node, list):
        if not last.isdigit() or int(last) >= len(node):
            raise SceneError(f"{key}: no item {last!r}")
        node[int(last)] = value
    else:
        if last in TAGS and node.get(last) != value:
            _switch_kind(raw, parts, node, value)
        node[last] = value


def _switch_kind(raw: dict, parts: list[str], table: dict, kind: object) -> None:
    """An override of a table's kind (``mesh.kind=file``) switches the table to that kind: the
    fields of its old kind that the new one does not take go (as the page's form does), so
    that later overrides complete the new kind."""
    tp, node = Scene, raw
    for p in parts[:-1]:
        models = _members(tp)
        if isinstance(node, list):
            tp, node = _item(tp), node[int(p)]
            continue
        if len(models) > 1:  # the table's current kind says which model it is
            models = [m for m in models if node.get(_tag(m)) in _kinds(m)]
        field = models[0].model_fields.get(p) if len(models) == 1 else None
        if field is None:
            return  # not a field of the schema: validation names it
        tp, node = field.annotation, node[p]
    new = [m for m in _members(tp) if kind in _kinds(m)]
    if len(_members(tp)) > 1 and len(new) == 1:
        for k in [k for k in table if k not in new[0].model_fields]:
            del table[k]


def _tag(model: type[BaseModel]) -> str | None:
    return next((t for t in TAGS if t in model.model_fields), None)


def validate(raw: dict) -> Scene:
    """The scene of parsed TOML or JSON, every value of the type its field declares: a number
    where a number is due (an integer is one), never a boolean or a text that reads as one
    (``E = true`` would otherwise be 1 Pa, ``"1e9"`` a modulus). pydantic's strict mode does
    that, in its JSON mode, where an array is a tuple as TOML and JSON write one. Raises
    ValidationError."""
    try:
        text = json.dumps(raw, allow_nan=True)
    except (TypeError, ValueError) as exc:  # a TOML date or time: no field takes one
        raise SceneError(f"scene: {exc}") from None
    return Scene.model_validate_json(text, strict=True)


def scene_from_dict(raw: dict) -> Scene:
    try:
        return validate(raw)
    except ValidationError as err:
        raise SceneError(joined(scene_errors(err))) from None


def read_toml(text: str) -> dict:
    """The tables of a TOML text. Raises SceneError for bad TOML and for arrays or tables
    nested deeper than a scene can be (tomllib recurses once per level)."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"TOML: {err}") from None
    except RecursionError:
        raise SceneError(f"TOML: nested deeper than {MAX_DEPTH} levels") from None
    problem = tree_problem(raw)
    if problem:
        raise SceneError(problem)
    return raw


def scene_from_toml(text: str, overrides: dict | None = None,
                    folder: Path | None = None) -> Scene:
    """The scene of a TOML text with ``overrides`` applied; relative file paths are taken from
    ``folder`` when given (a scene file's own folder)."""
    raw = read_toml(text)
    for k, v in (overrides or {}).items():
        apply_override(raw, k, v)
    if folder is not None:
        _from_folder(raw, folder)
    return scene_from_dict(raw)


def _from_folder(raw: dict, folder: Path) -> None:
    """Relative file paths of a scene file are taken from its folder."""
    nodes = [(raw.get("mesh"), "path"), (raw.get("shell"), "thickness_file")]
    tools = raw.get("tools")
    shapes = [t.get("shape") for t in tools if isinstance(t, dict)] if isinstance(tools, list) \
        else []
    while shapes:  # tool shapes read a mesh file at any depth of their CSG tree
        s = shapes.pop()
        if isinstance(s, dict):
            nodes.append((s, "path"))
            shapes += s.get("shapes", []) if isinstance(s.get("shapes"), list) else []
    for node, key in nodes:
        if isinstance(node, dict) and isinstance(node.get(key), str):
            p = Path(node[key]).expanduser()
            node[key] = str(p if p.is_absolute() else folder / p)


def load_scene(path: str | Path, overrides: dict | None = None) -> Scene:
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} does not exist")
    return scene_from_toml(path.read_text(), overrides, path.resolve().parent)
