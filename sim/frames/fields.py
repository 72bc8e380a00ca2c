"""Fields of a state: the mid-surface, thickness, fibre tilt, volume and curvature the probes
read, the per-vertex fields the viewer colours by and the result holds, and radial sections."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from sim.elements.base import line_lagrange
from sim.frames import forming_limits
from sim.geometry.trimesh import TriMesh, edges, vertex_normals
from sim.materials.plasticity import net_plastic_strain
from sim.text import plan_extent

if TYPE_CHECKING:  # the scene's validation imports this module: it loads no solver term
    from sim.geometry.shell import Shell
    from sim.terms.elasticity import Elasticity


class Discretised(Protocol):
    """What the fields read of a model (sim.model.build.Model): its shell and elastic term.
    The scene's probes read these fields and the model is built from the scene, so this
    module cannot import the model."""

    shell: Shell
    elasticity: Elasticity


class Ray(Protocol):
    """A section's ray (sim.scene.run.SectionSpec: the scene imports this module through its
    probes)."""

    name: str
    direction: tuple[float, float]
    width: float


def mid_surface(model: Discretised, x: np.ndarray) -> np.ndarray:
    """Positions at w = 0 of every mid-surface vertex column ``(n_v, 3)``."""
    sh = model.shell
    L, _ = line_lagrange(sh.element.q, np.zeros(1))
    cols = [x[k * sh.n_plane: k * sh.n_plane + sh.n_vertices] for k in range(sh.element.q + 1)]
    return sum(w * c for w, c in zip(L[0], cols, strict=True))


def thickness(model: Discretised, x: np.ndarray) -> np.ndarray:
    """Fibre length between the skins at every mid-surface vertex ``(n_v,)``."""
    sh = model.shell
    return np.linalg.norm(x[sh.skin_nodes(True)] - x[sh.skin_nodes(False)], axis=1)


def thinning(h: np.ndarray, h0: np.ndarray, x: np.ndarray) -> np.ndarray:
    """1 - h / h0 (a fraction), 0 where the thickness differs from the rest thickness by no
    more than its round-off: h is a distance between two nodes whose coordinates carry an
    error of about eps times the largest coordinate of the state ``x``, so a sheet whose
    thickness did not change (a rigid motion, a linear plate) shows no thinning of 1e-14 %."""
    thin = 1.0 - h / h0
    noise = 8.0 * np.finfo(float).eps * float(np.abs(x).max()) / h0
    return np.where(np.abs(thin) <= noise, 0.0, thin)


def fibre_tilt(model: Discretised, x: np.ndarray) -> np.ndarray:
    """Angle (degrees) per vertex between the through-thickness fibre (bottom to top skin) and
    the normal of the deformed mid-surface: transverse shear, zero in pure bending and
    stretching; linear prisms escape volumetric locking by shearing (paper Fig. 11)."""
    sh = model.shell
    fibre = x[sh.skin_nodes(True)] - x[sh.skin_nodes(False)]
    n = vertex_normals(TriMesh(mid_surface(model, x), sh.mesh.faces))
    c = np.abs(np.einsum("ij,ij->i", fibre, n)) / np.linalg.norm(fibre, axis=1)
    return np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))


def volume(model: Discretised, x: np.ndarray) -> float:
    """The sheet's material volume (sim.terms.elasticity.Elasticity.volume_ratios)."""
    el = model.elasticity
    return float(np.sum(el.volume_ratios(x) * el.wdetJ))


def curvature_xz(P: np.ndarray) -> float:
    """Curvature 1/R of the least-squares circle through points ``(n, 3)`` projected on x-z
    (algebraic fit: x^2 + z^2 + D x + E z + F = 0); 0 for collinear points."""
    x, z = P[:, 0] - P[:, 0].mean(), P[:, 2] - P[:, 2].mean()
    A = np.column_stack([x, z, np.ones_like(x)])
    (D, E, F), *_ = np.linalg.lstsq(A, -(x * x + z * z), rcond=None)
    r2 = D * D / 4 + E * E / 4 - F
    return float(1.0 / np.sqrt(r2)) if r2 > 0 and np.isfinite(r2) else 0.0


def vertex_average(model: Discretised, per_qp: np.ndarray) -> np.ndarray:
    """Element means of a quadrature-point field ``(n_elem, n_qp)`` averaged onto the
    mid-surface vertices ``(n_v,)`` (element e sits on mid-surface face e)."""
    F = model.shell.mesh.faces
    elem = per_qp.mean(1)
    acc = np.zeros(model.shell.n_vertices)
    cnt = np.zeros(model.shell.n_vertices)
    for c in range(3):
        np.add.at(acc, F[:, c], elem)
        np.add.at(cnt, F[:, c], 1.0)
    return acc / np.maximum(cnt, 1)


def element_strains(model: Discretised, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Major and minor true strain of the mid-surface of each element between the rest state
    and ``x`` (sim.frames.forming_limits.membrane_strains). Shapes: (n_elem,), (n_elem,)."""
    return forming_limits.membrane_strains(mid_surface(model, model.x0), mid_surface(model, x),
                                           model.shell.mesh.faces)


def limit_fields(model: Discretised, x: np.ndarray) -> dict[str, np.ndarray]:
    """Major and minor strain (true) per element and per vertex (the mean of its elements) and,
    with a forming limit curve, the FLD zone code per element and per vertex (the worst of its
    elements; sim.frames.forming_limits). Empty for an elastic scene."""
    if not model.elasticity.plastic:
        return {}
    major, minor = element_strains(model, x)
    out = {"major_strain": vertex_average(model, major[:, None]), "major_strain_elem": major,
           "minor_strain": vertex_average(model, minor[:, None]), "minor_strain_elem": minor}
    flc = forming_limits.curve_of(model.scene.material, model.scene.shell)
    if flc is not None:
        zone = forming_limits.zones(major, minor, flc)
        out |= {"fld_zone": forming_limits.worst_per_vertex(zone, model.shell.mesh.faces,
                                                            model.shell.n_vertices),
                "fld_zone_elem": zone}
    return out


def output_fields(model: Discretised, x: np.ndarray, h0: np.ndarray) -> dict[str, np.ndarray]:
    """Result fields at state x, per mid-surface vertex ``(n_v,)`` and per element
    (``*_elem``, ``(n_elem,)``): thickness (m), thinning (% of the rest thickness ``h0``),
    von Mises stress (Pa) and, for a plastic scene, the accumulated and the net (retained)
    equivalent plastic strain and the forming limit fields (:func:`limit_fields`). Element
    values are quadrature-point means; vertex values the mean of the adjacent elements
    (thickness: measured at the vertex, as in the viewer)."""
    el, faces = model.elasticity, model.shell.mesh.faces
    h = thickness(model, x)
    per_qp = {"von_mises": el.von_mises(x)}
    if el.plastic:  # an elastic scene has no plastic state to report
        per_qp["eq_plastic_strain"] = el.ep
        per_qp["net_plastic_strain"] = net_plastic_strain(el.fp_inv)
    out = {"thickness": h, "thinning_pct": 100 * thinning(h, h0, x),
           "thickness_elem": h[faces].mean(1),
           "thinning_pct_elem": 100 * thinning(h[faces].mean(1), h0[faces].mean(1), x)}
    for name, q in per_qp.items():
        out[name] = vertex_average(model, q)
        out[f"{name}_elem"] = q.mean(1)
    return out | limit_fields(model, x)


def field_summary(fields: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """min / mean / max of each per-vertex field of :func:`output_fields` (result.json)."""
    return {k: {"min": float(v.min()), "mean": float(v.mean()), "max": float(v.max())}
            for k, v in fields.items() if not k.endswith("_elem")}


def section_points(model: Discretised, spec: Ray) -> tuple[np.ndarray, np.ndarray]:
    """Where the section's ray crosses the blank at rest, sorted by rest radius: the vertices
    within ``width`` of it and the points where it cuts an edge between two others. Returns
    each point's two vertices ``(m, 2)`` and its weight on the second ``(m,)`` (0 at a
    vertex). A value there is linear along the edge, as the mid-surface is on a triangle's
    edge: a mesh with vertices on the ray (a disk's spoke) gives its vertices, any other mesh
    (an outline's, a user's) a section as well. Two limits: elements curved in-plane
    (quadratic, quartic) are read on the chord between the edge's corners, not through its
    edge nodes; a ray that leaves the blank through a hole or notch and enters it again gives
    one list, the gap not marked. The section starts at the first vertex or cut past the
    origin, not at the origin itself."""
    V = model.shell.mesh.vertices[:, :2]
    d = np.asarray(spec.direction, float)
    d /= np.linalg.norm(d)
    side = V[:, 0] * d[1] - V[:, 1] * d[0]  # signed distance from the ray's line
    side[np.abs(side) <= spec.width] = 0.0
    E, _ = edges(model.shell.mesh.faces)
    sa, sb = side[E[:, 0]], side[E[:, 1]]
    cut = np.flatnonzero(sa * sb < 0)  # an end on the line is a vertex point, not a cut
    on = np.flatnonzero(side == 0)
    pairs = np.concatenate([np.column_stack([on, on]), E[cut]])
    t = np.concatenate([np.zeros(len(on)), sa[cut] / (sa[cut] - sb[cut])])
    along = ((1 - t)[:, None] * V[pairs[:, 0]] + t[:, None] * V[pairs[:, 1]]) @ d
    keep = along >= -1e-12  # the ray, not the line's other half
    if keep.sum() < 2:  # a blank beside the origin (a drawing in its own coordinates) too
        raise ValueError(f"sections.{spec.name}: the ray from the origin along "
                         f"{[float(x) for x in d]} crosses the blank at fewer than two points: "
                         f"the blank lies at {plan_extent(V)}")
    order = np.flatnonzero(keep)[np.argsort(along[keep], kind="stable")]
    return pairs[order], t[order]


def section(model: Discretised, x: np.ndarray,
            points: tuple[np.ndarray, np.ndarray]) -> dict[str, list[float]]:
    """Rest radius, current radius (from the z axis), height and thickness along a section
    (m): at the ``points`` of :func:`section_points`, state ``x (n, 3)``."""
    pairs, t = points

    def at(f: np.ndarray) -> np.ndarray:
        w = t.reshape(-1, *([1] * (f.ndim - 1)))
        return (1 - w) * f[pairs[:, 0]] + w * f[pairs[:, 1]]

    mid, rest = at(mid_surface(model, x)), at(model.shell.mesh.vertices)
    return {"rest_radius": np.hypot(rest[:, 0], rest[:, 1]).tolist(),
            "radius": np.hypot(mid[:, 0], mid[:, 1]).tolist(),
            "z": mid[:, 2].tolist(),
            "thickness": at(thickness(model, x)).tolist()}
