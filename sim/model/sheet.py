"""The sheet of a scene: its mid-surface mesh (generated or read), the thickness at every
vertex, and the quadrature rule its elements take. Errors name the field they come from."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.elements.base import Prism
from sim.geometry import outline
from sim.geometry import trimesh as meshes
from sim.scene.fields import MAX_LENGTH
from sim.scene.load import Scene
from sim.scene.sheet import MeshSpec, OutlineMesh


def build_mesh(spec: MeshSpec) -> meshes.TriMesh:
    if spec.kind == "rectangle":
        return meshes.rectangle(spec.size, spec.edge_length, spec.origin)
    if spec.kind in ("annulus", "disk"):
        r0 = 0.0 if spec.kind == "disk" else spec.r_inner
        return meshes.annulus(r0, spec.r_outer, spec.edge_length)
    if spec.kind == "cylinder_band":
        return meshes.cylinder_band(spec.radius, spec.height, spec.edge_length)
    if spec.kind in ("cylinder_patch", "sphere_patch"):
        mesh = (meshes.cylinder_patch(spec.radius, spec.length, spec.angle, spec.cells)
                if spec.kind == "cylinder_patch" else
                meshes.sphere_patch(spec.radius, spec.hole, spec.azimuth, spec.cells))
        return mesh if spec.curved else meshes.TriMesh(mesh.vertices, mesh.faces)
    if spec.kind == "strip":
        return meshes.strip(spec.length, spec.width, spec.twist, spec.cells, spec.across)
    if spec.kind == "outline":
        return outline.mesh(outline_of(spec), spec.edge_length, spec.bands, spec.mesher)
    return meshes.load(spec.path, spec.scale, spec.merge_vertices)


def outline_of(spec: OutlineMesh) -> outline.Outline:
    """The outline of an ``outline`` mesh: its points or circle and holes, or its drawing's
    paths."""
    if spec.path is not None:
        return outline.read_drawing(spec.path, spec.scale, spec.edge_length,
                                    centre=spec.centre)
    return spec.shape()


def imperfect(mesh: meshes.TriMesh, amplitude: float) -> meshes.TriMesh:
    """``MeshSpec.imperfection``: one smooth out-of-plane bump over a flat mesh's extent."""
    if amplitude == 0.0:
        return mesh
    V = mesh.vertices
    if np.ptp(V[:, 2]) > 1e-12 * np.ptp(V, axis=0).max():
        raise ValueError("mesh.imperfection: needs a flat mesh (z = const)")
    lo, span = V.min(0), np.ptp(V, axis=0)
    # a seed of a buckle is a share of the thickness; a bump as high as half the sheet is
    # wide is a dome with flanks of 57 degrees, a mistyped unit (1 for 1 mm) rather than a seed
    if abs(amplitude) > 0.5 * span[:2].min():
        raise ValueError(
            f"mesh.imperfection: {1e3 * amplitude:.4g} mm is more than half the sheet's "
            f"narrower side ({1e3 * span[:2].min():.4g} mm): it seeds a buckle with a "
            "share of the thickness (in m: 1e-5 is 0.01 mm)")
    s, t = (V[:, 0] - lo[0]) / span[0], (V[:, 1] - lo[1]) / span[1]
    out = V.copy()
    out[:, 2] += amplitude * np.sin(np.pi * s) * np.sin(np.pi * t)
    return meshes.TriMesh(out, mesh.faces)


def read_values(path: str) -> np.ndarray:
    """A .npy array or a text file of numbers (whitespace or comma separated)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no file {path!r}")
    if p.suffix == ".npy":
        try:
            a = np.load(p, allow_pickle=False)
        except (ValueError, EOFError, OSError) as exc:  # not .npy, objects, cut short
            raise ValueError(f"{p.name} is not an array of numbers ({exc})") from None
        if a.dtype.kind not in "iuf":
            what = "text" if a.dtype.kind in "US" else f"{a.dtype.name} values"
            raise ValueError(f"{p.name} holds {what}, not numbers")
        a = a.astype(float)
    else:
        try:
            a = np.loadtxt(p, delimiter="," if p.suffix == ".csv" else None, ndmin=1)
        except ValueError as exc:
            raise ValueError(f"{p.name} is not an array of numbers "
                             f"({_not_a_number(p) or exc})") from None
    # a value per vertex: one column or one row (a table of several would be read across its
    # rows, a value of one vertex's taken for the next one's)
    if sum(n > 1 for n in a.shape) > 1:
        raise ValueError(f"{p.name} holds an array of shape {'x'.join(map(str, a.shape))}: a "
                         "value per vertex is one column or one row")
    return a.ravel()


def _not_a_number(p: Path) -> str | None:
    """Where a text file of numbers holds something else, as its editor counts: "line 3,
    value 1: 'abc'" (numpy counts data rows from 0, skipping comments and blank lines, and
    columns from 1)."""
    try:
        lines = p.read_text(errors="replace").splitlines()
    except OSError:
        return None
    for n, line in enumerate(lines, 1):
        words = line.split("#")[0].replace(",", " " if p.suffix == ".csv" else ",").split()
        for k, w in enumerate(words, 1):
            try:
                float(w)
            except ValueError:
                return f"line {n}, value {k}: {w!r} is not a number"
    return None


def mesh_and_thickness(scene: Scene) -> tuple[meshes.TriMesh, np.ndarray, dict]:
    """The mid-surface, the thickness at each of its vertices ``(n_v,)`` (m) and a report of the
    mesh (a file's: what was read, merged and dropped, sim.geometry.trimesh.load_with_values);
    errors name the field they come from."""
    sh, spec = scene.shell, scene.mesh
    field_name = "shell.thickness_file" if sh.thickness_file else "shell.thickness_attribute"
    try:
        values = read_values(sh.thickness_file) if sh.thickness_file else None
        if spec.kind == "file":
            mesh, h, report = meshes.load_with_values(spec.path, spec.scale, values,
                                                      sh.thickness_attribute,
                                                      spec.merge_vertices)
            # a file in mm read as metres: a blank 60 m across, else built and previewed
            outline.check_extent([mesh.vertices / spec.scale], spec.scale, "mesh")
        else:
            mesh, h = build_mesh(spec), values
            report = {"vertices": len(mesh.vertices), "triangles": len(mesh.faces)}
            if h is not None and len(h) != len(mesh.vertices):
                raise ValueError(f"{len(h)} values for the {len(mesh.vertices)} vertices of "
                                 f"the {spec.kind} mesh")
    except meshes.MeshFileError as exc:
        raise ValueError(f"mesh.path: {exc}") from None
    except outline.OutlineError as exc:
        raise ValueError(f"mesh.{exc.field}: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{field_name}: {exc}") from None
    mesh = imperfect(mesh, spec.imperfection)
    if h is None:
        h = sh.thickness + mesh.vertices @ np.asarray(sh.thickness_gradient)
        field_name = ("shell.thickness_gradient" if np.any(sh.thickness_gradient)
                      else "shell.thickness")
    bad = ~np.isfinite(h) | (h <= 0) | (h > MAX_LENGTH)
    if bad.any():
        v = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{field_name}: thickness must be positive (and at most "
                         f"{MAX_LENGTH:.0e} m) at every vertex ({int(bad.sum())} are not; "
                         f"vertex {v}: {h[v]:.3g} m)")
    check_sheet(mesh, h, field_name)
    return mesh, np.asarray(h, float), {"kind": spec.kind, **report}


def check_sheet(mesh: meshes.TriMesh, h: np.ndarray, field_name: str) -> None:
    """A sheet is thinner than it is long: a blank 5 m thick on a 60 mm disk is a typo (it ran,
    and "converged" with no force: the tools were inside it). Its length: the largest side of
    the mid-surface's bounding box. Not its width: a plane-strain strip one cell across, thicker
    than that cell, is a model (the springback study's). Nor is a mesh coarser than the blank
    refused: a coarse look is the user's to take."""
    length = float(np.ptp(mesh.vertices, axis=0).max())
    if h.max() > length:
        raise ValueError(f"{field_name}: {1e3 * h.max():.4g} mm thick, more than the blank's "
                         f"largest extent ({1e3 * length:.4g} mm): not a sheet")



def quadrature_rule(scene: Scene, elem: Prism, mesh: meshes.TriMesh) -> tuple[tuple[int, int], str]:
    """The scene's rule, else the element's default, unless the default has spurious
    zero-energy modes on this mesh: on edge-connected patches of one or two triangles (a lone
    element, a pair, or a patch hanging by a vertex) the paper's one-point in-plane rules
    leave some, and the mode-free rule (stiffer: it locks in transverse shear) is taken for
    the whole sheet. Every other mesh keeps the paper's rule, which has none there."""
    if scene.shell.quadrature:
        return tuple(scene.shell.quadrature), "scene"
    if elem.small_mesh_quadrature is not None:
        small = meshes.small_patches(mesh.faces)
        if len(small):
            return elem.small_mesh_quadrature, (
                f"{len(small)} triangle(s) in edge-connected patches of 1-2 triangles (first: "
                f"{small[:5].tolist()}), where the default {list(elem.default_quadrature)} "
                "admits spurious zero-energy modes")
    return elem.default_quadrature, "default"




def rule_of(scene: Scene, elem: Prism, mesh: meshes.TriMesh) -> tuple[tuple[int, int], str]:
    """:func:`quadrature_rule` with the scene's thickness point count, when it gives one."""
    rule_spec, why = quadrature_rule(scene, elem, mesh)
    if scene.shell.thickness_points:
        rule_spec = (rule_spec[0], scene.shell.thickness_points)
    return rule_spec, why
