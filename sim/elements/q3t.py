"""9-node Q3T prism (paper Sec. 3.3): linear in-plane, quadratic through the thickness.

Through-thickness weights are w(w-1)/2 (bottom), 1 - w^2 (mid-surface), w(w+1)/2 (top). The paper
prints (1-w)^2 for the mid-surface weight, which is 4 at w = -1: neither nodal nor a partition of
unity. tests/test_elements.py checks the printed form fails and ours passes.
"""

from sim.elements import register
from sim.elements.base import Prism

# The paper's rule, 1 in-plane x 3 thickness points. It admits one zero-energy mode on a free
# single-cell (two-triangle) patch only; meshes of two or more cells, free or clamped, have none
# (tests/test_elements.py). The full 3 x 3 rule has no such mode but locks in transverse shear:
# 15 % too stiff on the paper's cantilever against 5 % for 1 x 3 (README, "Quadrature").
Q3T = register(Prism("q3t", p=1, q=2, default_quadrature=(1, 3)))
