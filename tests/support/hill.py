"""Hill48 material points for the tests: AA5754-O's constants, its parameter vector, a rotation
about the sheet normal, and uniaxial tension driven through any Kirchhoff stress (the material
alone in tests/unit/test_hill_kernel.py, the q3t_ans element in tests/unit/test_ans.py)."""

import math

import numpy as np
from scipy.optimize import fsolve

from sim.materials.hill import coefficients, hill_matrix, hill_params

E_MOD, NU = 68e9, 0.33  # AA5754-O (scenes/cup_drawing.toml)
MU = E_MOD / (2.0 * (1.0 + NU))
LAM = E_MOD * NU / ((1.0 + NU) * (1.0 - 2.0 * NU))
LAWS = {"perfect": (0, [102.75e6]), "linear": (1, [102.75e6, 1e9]),
        "swift": (2, [400e6, 0.01, 0.25]), "voce": (3, [102.75e6, 292.14e6, 13.5])}
R_AA5754 = (0.663, 0.860, 0.717)  # Coer et al. 2018 as quoted in docs/anisotropy.md


def params(r=R_AA5754, law="voce"):
    code, hp = LAWS[law]
    return hill_params(MU, LAM, code, hp, hill_matrix(*coefficients(*r)))


def rotation_z(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                     [0.0, 0.0, 1.0]])


FREE = [(1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]  # the components solved for in tension


def symmetric_f(u, f11):
    """F = diag(f11, 1, 1) plus the FREE components ``u (5,)``, symmetric."""
    F = np.diag([f11, 1.0, 1.0])
    for k, (i, j) in enumerate(FREE):
        F[i, j] += u[k]
        if i != j:
            F[j, i] += u[k]
    return F


def tension(kirchhoff, commit, strain=0.1, steps=20):
    """Tension along x, stress-free otherwise: per step solve the FREE components of a
    symmetric F for a Kirchhoff stress ``kirchhoff(F)`` = tau_11 e1 e1 (its FREE components
    over MU to 1e-12), then ``commit(F)``."""
    u = np.zeros(5)
    for k in range(1, steps + 1):
        f11 = math.exp(strain * k / steps)

        def residual(u, f11=f11):
            tau = kirchhoff(symmetric_f(u, f11))
            return [tau[i, j] / MU for i, j in FREE]

        # fsolve's first step is bounded by factor times the scaled |u|: from a state entering
        # plastic flow its default (100) can leap past the solution and stall; a shorter one
        # then reaches it (which one is needed changes with the stress's last bits)
        for factor in (100.0, 1.0, 0.1):
            trial = fsolve(residual, u, xtol=1e-12, factor=factor)
            if np.abs(residual(trial)).max() < 1e-12:
                break
        u = trial
        assert np.abs(residual(u)).max() < 1e-12
        commit(symmetric_f(u, f11))
