"""q3t_ans's energy, gradient and Hessian pinned to their values at commit a04c20f, so that
work on the kernel's speed (sim.terms.ans, sim.materials) changes no result beyond round-off:
every material (Neo-Hookean, Hencky, von Mises plasticity with F = Fe Fp, Hill48) and every
Hessian projection, on the cup's blank bent over a cylinder, stretched, and (plastic) with a
committed state, nine points in ten flowing. The reference is tests/unit/ans_pinned.json:
``python -m tests.unit.test_ans_pinned`` rewrites it (only from the commit named above)."""

import json
from pathlib import Path

import numpy as np
import pytest

from sim.apps.common import load
from sim.materials.hill import HILL48
from sim.model.build import build_model
from sim.model.terms import lame, material_params
from sim.solve import assembly
from sim.terms import PROJECT_ELEMENT, PROJECT_NONE, PROJECT_QP
from sim.terms.elasticity import Elasticity
from tests.support.hill import params as aa5754
from tests.support.hill import rotation_z

REFERENCE = Path(__file__).with_name("ans_pinned.json")
RTOL = 1e-12
MODELS = {"neo_hookean": 0, "hencky": 1, "plastic": 2, "hill48": HILL48}
PROJECTIONS = {"none": PROJECT_NONE, "qp": PROJECT_QP, "element": PROJECT_ELEMENT}


def _blank():
    """The cup's blank (scenes/cup_drawing.toml, coarse) as q3t_ans: shell, rule, its scene."""
    scene = load("cup_drawing", {"shell.element": "q3t_ans", "mesh.edge_length": 0.006})
    m = build_model(scene)
    return scene, m.shell, m.elasticity.rule


def _term(model: str, project: int) -> tuple[Elasticity, np.ndarray]:
    """The term and the deformed state x (n_nodes, 3): the blank bent about y to a radius of
    50 mm (+-1 % strain in its skins), stretched 0.4 % along x and narrowed 0.2 % along y,
    with a smooth ripple so that no two points are alike; plastic: a committed Fp^-1 away
    from I (det 1) and ep up to 0.3, so that nine points in ten flow and the rest do not."""
    scene, sh, rule = _blank()
    pat = assembly.build_pattern(sh.conn, sh.n_nodes)
    mid = material_params(scene.material)
    mu, lam = lame(scene.material.E, scene.material.nu)
    plastic = model in ("plastic", "hill48")
    params, frames = (mid, None) if model == "plastic" else (np.array([mu, lam]), None)
    if model == "hill48":
        params = aa5754()
        frames = np.tile(rotation_z(30.0), (len(sh.conn), 1, 1))
    el = Elasticity(sh, rule, MODELS[model], params, pat, project, plastic=plastic,
                    frames=frames)
    if plastic:
        rng = np.random.default_rng(5)
        n_e, n_q = el.ep.shape
        A = np.eye(3) + 0.002 * rng.standard_normal((n_e, n_q, 3, 3))
        el.fp_inv[:] = A / np.cbrt(np.linalg.det(A))[..., None, None]
        el.ep[:] = 0.3 * rng.random((n_e, n_q))  # the hardest points stay elastic
    X = sh.rest
    R = 0.05
    x = X.copy()
    x[:, 0] *= 1.004
    x[:, 1] *= 0.998
    x[:, 2] += 2e-5 * np.sin(400.0 * X[:, 0] + 1.0) * np.cos(300.0 * X[:, 1])
    phi = x[:, 0] / R
    rad = R - x[:, 2]
    x[:, 0] = rad * np.sin(phi)
    x[:, 2] = R - rad * np.cos(phi)
    return el, x


def _vectors(n: int) -> np.ndarray:
    return np.random.default_rng(17).standard_normal((4, n))


def measure(model: str, projection: str) -> dict:
    """Energy (as the line search, the gradient and the Hessian evaluations each give it),
    the gradient's norm and dot products with two fixed vectors, and the same of the Hessian
    times two other fixed vectors."""
    el, x = _term(model, PROJECTIONS[projection])
    n = x.size
    r = _vectors(n)
    e0 = el.energy(x)
    g = np.zeros_like(x)
    e1 = el.add_gradient(x, g)
    d = np.zeros(el.pattern.nnz)
    g2 = np.zeros_like(x)
    e2 = el.add_gradient_hessian(x, g2, d)
    Kmat = el.pattern.matrix(d)
    out = {"n": n, "energy": [e0, e1, e2], "gradient": _norm_dots(g.ravel(), r[:2]),
           "gradient_hessian_pass": _norm_dots(g2.ravel(), r[:2])}
    for i in (2, 3):
        out[f"hv{i - 1}"] = _norm_dots(Kmat @ r[i], r[:2])
    return out


def _norm_dots(v: np.ndarray, r: np.ndarray) -> list[float]:
    return [float(np.linalg.norm(v)), float(v @ r[0]), float(v @ r[1])]


CASES = [(m, p) for m in MODELS for p in PROJECTIONS]


@pytest.fixture(scope="module")
def reference() -> dict:
    return json.loads(REFERENCE.read_text())


@pytest.mark.parametrize("model, projection", CASES, ids=[f"{m}-{p}" for m, p in CASES])
def test_ans_results_are_pinned(model, projection, reference):
    """Each value to 1e-12 of its scale: the energy's own, a vector's norm for the norm, and
    for a dot product v . r its bound |v| |r|."""
    ref = reference[f"{model}/{projection}"]
    got = measure(model, projection)
    assert np.allclose(got["energy"], ref["energy"], rtol=RTOL, atol=0.0), \
        (got["energy"], ref["energy"])
    # a line search's energy alone (sim.terms.ans._point_energy) is the gradient's and the
    # Hessian's to the bit, but for Neo-Hookean under a projected Hessian, whose assembly
    # takes the principal frame where the others take the closed form (sim.terms.elasticity)
    if (model, projection) != ("neo_hookean", "qp"):
        assert got["energy"][0] == got["energy"][1] == got["energy"][2], got["energy"]
    r_norms = np.linalg.norm(_vectors(got["n"])[:2], axis=1)
    for key in ("gradient", "gradient_hessian_pass", "hv1", "hv2"):
        norm = ref[key][0]
        assert abs(got[key][0] - norm) <= RTOL * norm, (key, got[key][0], norm)
        for a, b, rn in zip(got[key][1:], ref[key][1:], r_norms, strict=True):
            assert abs(a - b) <= RTOL * norm * rn, (key, a, b)


if __name__ == "__main__":
    data = {f"{m}/{p}": measure(m, p) for m, p in CASES}
    REFERENCE.write_text(json.dumps(data, indent=1) + "\n")
