"""The scene editor's service side: the form's edits are written into the scene file's own
TOML (comments, layout and number formats kept), through /api/scenes/render and a save; a
duplicate's name field follows its new name."""

import tomllib

from server import sceneform, tomlout
from sim.scene.load import Scene, scene_from_toml
from tests.support import ROOT

CUP = (ROOT / "scenes/cup_drawing.toml").read_text()


# ---- the form's save: the edit written into the file's own text ------------------------------
def test_an_edit_keeps_the_files_comments_and_number_formats():
    base = CUP
    scene = sceneform.parse(base)["scene"]
    scene["material"]["nu"] = 0.3
    scene["tools"][0]["friction"] = 0.15
    scene["tools"][1]["shape"]["edge_radius"] = 0.004
    out = sceneform.render(scene, base=base)
    assert out["ok"], out["error"]
    text = out["toml"]
    # every comment line of the file is still there, and the unchanged numbers as written
    comments = [ln for ln in base.splitlines() if ln.lstrip().startswith("#")]
    assert comments and all(c in text.splitlines() for c in comments)
    assert "velocity = [0.0, 0.0, -0.025]   # 25 mm stroke" in text
    for kept in ("E = 68.0e9", "yield_stress = 102.75e6", "saturation = 292.14e6"):
        assert kept in text
    assert "nu = 0.3\n" in text and "friction = 0.15" in text and "edge_radius = 0.004" in text
    # only the three edited lines differ
    changed = [(a, b) for a, b in zip(base.splitlines(), text.splitlines(), strict=True)
               if a != b]
    assert len(changed) == 3, changed
    assert scene_from_toml(text) == Scene.model_validate(scene)


def test_an_edited_line_loses_its_trailing_comment_and_the_others_keep_theirs():
    """A line's comment describes the value the file had: an edit drops it (a stroke made
    30 mm would still say 25), on a plain value and on an inline table's line alike."""
    base = CUP
    scene = sceneform.parse(base)["scene"]
    scene["tools"][0]["velocity"] = [0.0, 0.0, -0.03]
    probe = next(p for p in scene["probes"] if p["name"] == "centre_dz")  # a commented line
    probe["name"] = "centre_travel"
    out = sceneform.render(scene, base=base)
    assert out["ok"], out["error"]
    text = out["toml"]
    assert "velocity = [0.0, 0.0, -0.03]\n" in text and "25 mm stroke:" not in text
    changed = [(a, b) for a, b in zip(base.splitlines(), text.splitlines(), strict=True)
               if a != b]
    assert [b for _, b in changed] == ["velocity = [0.0, 0.0, -0.03]",
                                       'name = "centre_travel"'], changed
    # every other line as it was, its comments with it
    assert sum("#" in ln for ln in text.splitlines()) == \
        sum("#" in ln for ln in base.splitlines()) - 2
    inline = tomlout.edited('bend = { angle = 0.1, length = 0.1 }   # radius 1 m\n',
                            {"bend": {"angle": 0.1, "length": 0.1}},
                            {"bend": {"angle": 0.2, "length": 0.1}}, {})
    assert inline == "bend = { angle = 0.2, length = 0.1 }\n"
    listed = tomlout.edited('refine = [{ edge_length = 0.001 }]   # 1 mm at the die\n',
                            {"refine": [{"edge_length": 0.001}]},
                            {"refine": [{"edge_length": 0.002}]}, {})
    assert listed == "refine = [{ edge_length = 0.002 }]\n"


def test_an_edit_of_kind_tables_and_lists_reads_back_as_the_edited_scene():
    """A new mesh kind drops the old kind's fields and adds the new one's; an added tool is a
    new [[tools]] table, a removed probe is gone; the comments stay."""
    base = CUP
    scene = sceneform.parse(base)["scene"]
    scene["mesh"] = {"kind": "rectangle", "size": [0.06, 0.06], "origin": [-0.03, -0.03],
                     "edge_length": 0.002}
    scene["tools"].append({"name": "ground", "shape": {"kind": "plane"},
                           "position": [0.0, 0.0, -0.1]})
    scene["probes"].pop()
    out = sceneform.render(scene, base=base)
    assert out["ok"], out["error"]
    text = out["toml"]
    assert scene_from_toml(text) == Scene.model_validate(scene)
    assert "r_outer = 0.03" not in text and "size = [0.06, 0.06]" in text
    assert text.count("[[tools]]") == 4 and "holder_height" not in text
    assert "# Deep drawing of a cylindrical cup" in text and "E = 68.0e9" in text


def test_a_copy_takes_its_new_name_and_keeps_the_rest():
    base = CUP
    text = tomlout.renamed(base, "my cup")
    assert tomllib.loads(text)["name"] == "my cup"
    assert text.replace('name = "my cup"', 'name = "cup_drawing"', 1) == base
    assert tomlout.renamed("name = [1,", "x") == "name = [1,"  # not TOML: as it was


def test_render_with_the_base_then_save_keeps_the_file(env):
    """The page's round: the form's scene and the file's text to /api/scenes/render, its TOML
    saved with PUT; the file on disk is the old one with the one line changed."""
    client, settings = env
    assert client.post("/api/scenes", json={"name": "cup", "toml": CUP}).status_code == 201
    doc = client.get("/api/scenes/cup").json()
    scene = doc["scene"]
    scene["material"]["E"] = 7e10
    r = client.post("/api/scenes/render", json={"scene": scene, "base": doc["toml"]}).json()
    assert r["ok"], r["error"]
    assert client.put("/api/scenes/cup", json={"toml": r["toml"]}).status_code == 200
    text = (settings.scenes_dir / "cup.toml").read_text()
    changed = [(a, b) for a, b in zip(CUP.splitlines(), text.splitlines(), strict=True) if a != b]
    assert changed == [("E = 68.0e9", "E = 7e10")]
    # without a base (or with one that is no valid scene): the scene alone, defaults left out
    plain = client.post("/api/scenes/render", json={"scene": scene, "base": "name = [1,"}).json()
    assert plain["ok"] and "#" not in plain["toml"]
    assert scene_from_toml(plain["toml"]) == Scene.model_validate(scene)


def test_a_duplicate_is_named_as_its_file(env):
    client, settings = env
    client.post("/api/scenes", json={"name": "cup2", "toml": CUP})
    r = client.post("/api/scenes/cup2/duplicate", json={"name": "cup-copy"})
    assert r.status_code == 201, r.text
    assert r.json()["scene"]["name"] == "cup-copy"
    text = (settings.scenes_dir / "cup-copy.toml").read_text()
    assert tomllib.loads(text)["name"] == "cup-copy"
    assert text.replace('name = "cup-copy"', 'name = "cup_drawing"', 1) == CUP  # the rest kept


def test_a_duplicate_of_an_editors_text_copies_it_and_refuses_a_bad_one(env):
    """``toml`` in the request: the copy is of that text (a page's unsaved edits), renamed; a
    text that is no valid scene is refused naming the field, and nothing is written."""
    client, settings = env
    client.post("/api/scenes", json={"name": "cup3", "toml": CUP})
    edited = CUP.replace("nu = 0.33", "nu = 0.31")
    r = client.post("/api/scenes/cup3/duplicate", json={"name": "cup3-edited", "toml": edited})
    assert r.status_code == 201, r.text
    text = (settings.scenes_dir / "cup3-edited.toml").read_text()
    assert text.replace('name = "cup3-edited"', 'name = "cup_drawing"', 1) == edited
    assert tomllib.loads((settings.scenes_dir / "cup3.toml").read_text())["material"]["nu"] == 0.33
    bad = client.post("/api/scenes/cup3/duplicate",
                      json={"name": "cup3-bad", "toml": CUP.replace("nu = 0.33", "nu = 0.7")})
    assert bad.status_code == 422 and "material.nu" in bad.text, bad.text
    assert not (settings.scenes_dir / "cup3-bad.toml").exists()
    missing = client.post("/api/scenes/nope/duplicate", json={"name": "x", "toml": edited})
    assert missing.status_code == 404, missing.text


def test_a_sheet_made_anisotropic_is_one_edit_in_the_forms_units():
    """Hill48 set on a von Mises sheet is one change, its set fields (r-values, the defaults
    L and M, the rolling angle) in one text, not six edits (a browser review read
    it so in the comparison); a change inside it is the field's own."""
    from server.scenediff import edits

    saved = (ROOT / "scenes" / "cup_drawing.toml").read_text()
    hill = saved.replace("[material]", "[material]\nhill48 = { r0 = 0.663, r45 = 0.86, "
                         "r90 = 0.717, rolling_angle = 45.0 }", 1)
    said = "r0 0.663, r45 0.86, r90 0.717, L 1.5, M 1.5, rolling_angle 45 deg"
    assert edits(saved, hill) == [f"material.hill48 unset → {said}"]
    assert edits(hill, saved) == [f"material.hill48 {said} → unset"]
    assert edits(hill, hill.replace("r0 = 0.663", "r0 = 0.7")) == [
        "material.hill48.r0 0.663 → 0.7"]


def test_a_value_set_or_unset_has_its_unit_beside_the_number():
    """"shell.thickness 1 → unset mm" read as an unset of mm (a review): with a side unset,
    the unit goes with the number; two numbers share it."""
    from server.scenediff import shown

    assert shown({"what": "shell.thickness", "values": [0.001, None], "unit": "m"},
                 " → ") == "shell.thickness 1 mm → unset"
    assert shown({"what": "tools.die.shape.edge_radius", "values": [None, 0.005],
                  "unit": "m"}) == "tools.die.shape.edge_radius unset | 5 mm"
    assert shown({"what": "shell.thickness", "values": [0.001, 0.0008], "unit": "m"},
                 " → ") == "shell.thickness 1 → 0.8 mm"
    assert shown({"what": "material.nu", "values": [0.3, None], "unit": "1"}) == \
        "material.nu 0.3 | unset"


def test_a_removed_section_is_one_edit_that_names_it():
    """The radial section removed in the form (sections = []) read as 'sections – → []' and
    four more edits of its fields, hiding the steps changed beside it (a browser review)."""
    from server.scenediff import edits

    saved = (ROOT / "scenes" / "cup_drawing.toml").read_text()
    assert [s["name"] for s in tomllib.loads(saved)["sections"]] == ["radial"]
    start = saved.index("[[sections]]")
    bare = saved[:start] + saved[saved.index("[[probes]]", start):]  # none: the default
    bare = bare.replace("steps = 50", "steps = 20", 1)
    assert "sections" not in tomllib.loads(bare)
    assert edits(saved, bare) == ["sections radial → none", "stepping.steps 50 → 20"]
