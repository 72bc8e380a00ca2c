"""A formed ring with a known residual moment, for the split-ring stage
(sim.stepping.split_ring): a tube (mesh ``cylinder_band``, radius R) whose rest state is its
formed state, and whose plastic state is the hoop eigen-strain of a ring of radius R' cut open.

With the hoop plastic stretch lam(zeta) = (R' + zeta) R / (R' (R + zeta)) at distance zeta
outwards from the mid-surface (and none across), the map of the tube onto a cylinder of radius
R' (radius R + zeta -> R' + zeta, angle theta -> theta R / R') has F = R_rot Fp: G = F Fp^-1 is
a rotation, stress-free. Closed, the tube cannot take that shape (it carries the residual
moment); split, it does: a ring of radius R' whose ends, the mid-surface's length 2 pi R kept,
are an angle alpha = 2 pi (1 - R / R') apart, a chord 2 R' sin(alpha / 2). No elastic constant
enters: the split ring's exact state is stress-free. At the skins the eigen-strain is about
(h / 2) (1 / R' - 1 / R), 4.9e-4 for R' = 1.02 R below: 33 MPa at E = 68 GPa, below the yield
stress, so the closed ring does not yield.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim.frames import series
from sim.scene.load import scene_from_toml
from sim.stepping.split_ring import Formed, sheet_of

R, H, THICKNESS = 0.02, 0.002, 0.001


def scene_text(edge: float, plastic: bool = True) -> str:
    material = ('model = "plastic"\nyield_stress = 102.75e6\nhardening = { law = "voce", '
                'saturation = 292.14e6, rate = 13.5 }' if plastic else 'model = "hencky"')
    return f"""name = "ring"
[mesh]
kind = "cylinder_band"
radius = {R}
height = {H}
edge_length = {edge}
[shell]
thickness = {THICKNESS}
element = "q3t"
[material]
E = 68.0e9
nu = 0.33
{material}
"""


def opened(R_after: float) -> float:
    """The exact opening (chord, m) of the ring split and relaxed to radius R_after."""
    alpha = 2 * math.pi * (1 - R / R_after)
    return 2 * R_after * math.sin(alpha / 2)


def ring(edge: float, R_after: float | None) -> Formed:
    """The tube of ``edge`` formed and held closed, carrying the eigen-strain of a ring of
    radius ``R_after`` (None: stress-free, Fp = I)."""
    scene = scene_from_toml(scene_text(edge))
    shell, rule = sheet_of(scene)
    N, _ = shell.element.basis(rule.points)
    X = np.einsum("qa,ead->eqd", N, shell.rest[shell.conn])  # the quadrature points at rest
    n_e, n_q = X.shape[:2]
    fp_inv = np.tile(np.eye(3), (n_e, n_q, 1, 1))
    if R_after is not None:
        rho = np.hypot(X[..., 0], X[..., 1])
        zeta = rho - R
        lam = (R_after + zeta) * R / (R_after * (R + zeta))
        hoop = np.stack([-X[..., 1] / rho, X[..., 0] / rho, np.zeros_like(rho)], -1)
        fp_inv += (1 / lam - 1)[..., None, None] * np.einsum("eqi,eqj->eqij", hoop, hoop)
    return Formed(scene, shell, rule, shell.rest.copy(), fp_inv, np.zeros((n_e, n_q)))


def write_run(folder: Path, formed: Formed, plastic: bool = True) -> Path:
    """A run folder whose final.npz holds ``formed`` as sim.frames.output.write writes one
    (``plastic=False``: an elastic run's, no plastic state)."""
    folder.mkdir(parents=True, exist_ok=True)
    sh = formed.shell
    scene = formed.scene if plastic else scene_from_toml(
        scene_text(formed.scene.mesh.edge_length, plastic=False))
    state = {"fp_inv": formed.fp_inv, "ep": formed.ep} if plastic else {}
    series.save_npz(folder / "final.npz", rest=sh.rest, deformed=formed.x, faces=sh.mesh.faces,
                    conn=sh.conn, scene=np.array(scene.model_dump_json()), **state)
    return folder
