"""The cup scenes that restate cup_drawing.toml (the anisotropic sheet, the unstructured blank)
differ from it only where their comments say: a run of one beside the other compares that
difference and nothing else, so an edit of the shared tools, sheet or process made in one file
and not the others fails here. The shell course's beams, one scene per load case, likewise."""

import tomllib

import pytest

from tests.support import ROOT

SCENES = ROOT / "scenes"

# dotted path -> why the scene differs from cup_drawing.toml (from its own comments)
DIFFERENCES = {
    "cup_drawing_aa5754": {
        "name": "its own", "description": "its own",
        "material.hill48": "the anisotropic sheet is the point of the scene",
        "tools.0.velocity": "30 mm stroke: the flange is drawn through so the rim shows ears",
        "stepping.steps": "the longer stroke in steps of the same 0.5 mm",
        "sections": "a finer radial section for the ears",
        "mesh.kind": "a blank without a lattice, whose six waves would hide the ears",
        "mesh.circle": "its outline, a circle of the disk's radius",
        "mesh.r_outer": "a disk's field", "mesh.mesher": "MeshAdapt: no lattice",
        # cb35667 measured rtol = 1e-4 on the isotropic cup only; this scene keeps the default
        "solver.rtol": "not measured on the anisotropic cup",
    },
    "cup_drawing_outline": {
        "name": "its own", "description": "its own",
        "mesh.kind": "the unstructured blank is the point",
        "mesh.circle": "its outline, a circle of the disk's radius (checked below)",
        "mesh.r_outer": "a disk's field",
        "probes.13": "the lateral force probed (x)", "probes.14": "and (y)",
    },
}


def flat(value, path: str = "") -> dict:
    """A parsed TOML document as dotted path -> leaf (arrays of tables by index)."""
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        items = ((str(i), v) for i, v in enumerate(value))
    else:
        return {path: value}
    return {k: v for key, sub in items
            for k, v in flat(sub, f"{path}.{key}" if path else key).items()}


def differing(a: dict, b: dict, allowed: dict) -> list[str]:
    """Paths where ``a`` and ``b`` differ that are not under an ``allowed`` path."""
    fa, fb = flat(a), flat(b)
    return sorted(p for p in fa.keys() | fb.keys() if fa.get(p) != fb.get(p)
                  and not any(p == q or p.startswith(q + ".") for q in allowed))


@pytest.mark.parametrize("name", sorted(DIFFERENCES))
def test_a_cup_variant_differs_from_the_cup_only_where_it_says(name):
    base = tomllib.loads((SCENES / "cup_drawing.toml").read_text())
    variant = tomllib.loads((SCENES / f"{name}.toml").read_text())
    assert differing(base, variant, DIFFERENCES[name]) == []
    # every allowed difference is still one: a list that outlives its reason hides the next edit
    fa, fb = flat(base), flat(variant)
    for q in DIFFERENCES[name]:
        under = [p for p in fa.keys() | fb.keys() if p == q or p.startswith(q + ".")]
        assert any(fa.get(p) != fb.get(p) for p in under), f"{name}: {q} is cup_drawing's again"


def test_the_outline_cup_cuts_the_cups_blank():
    """The outline blank is the disk's: a circle of its r_outer about the z axis."""
    base = tomllib.loads((SCENES / "cup_drawing.toml").read_text())["mesh"]
    circle = tomllib.loads((SCENES / "cup_drawing_outline.toml").read_text())["mesh"]["circle"]
    assert circle["radius"] == base["r_outer"] and circle.get("center", [0, 0]) == [0, 0]


def test_the_check_sees_a_shared_value_edited_in_one_file():
    base = tomllib.loads((SCENES / "cup_drawing.toml").read_text())
    edited = tomllib.loads((SCENES / "cup_drawing_outline.toml").read_text())
    edited["tools"][2]["force"] = 2 * base["tools"][2].get("force", 1.0)
    assert differing(base, edited, DIFFERENCES["cup_drawing_outline"]) == ["tools.2.force"]


def test_the_pages_first_scene_is_shipped():
    """The page selects Settings.default_scene first; a name not in scenes/ would quietly fall
    back to the list's first scene."""
    settings = pytest.importorskip("server.settings")
    assert (SCENES / f"{settings.Settings.default_scene}.toml").is_file()


# the shell course's two load cases of one beam: the same beam, mesh, material and supports
LOAD_CASE = ("name", "description", "loads.0.vector", "probes.0.component", "study.published")


@pytest.mark.parametrize("beam", ["twisted_beam", "straight_beam"])
def test_a_beams_two_load_cases_differ_only_in_the_load(beam):
    inplane = tomllib.loads((SCENES / f"{beam}_inplane.toml").read_text())
    outofplane = tomllib.loads((SCENES / f"{beam}_outofplane.toml").read_text())
    assert differing(inplane, outofplane, dict.fromkeys(LOAD_CASE)) == []
    fa, fb = flat(inplane), flat(outofplane)
    for q in LOAD_CASE:
        under = [p for p in fa.keys() | fb.keys() if p == q or p.startswith(q + ".")]
        assert any(fa.get(p) != fb.get(p) for p in under), f"{beam}: {q} is the same in both"
