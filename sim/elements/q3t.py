"""9-node Q3T prism (paper Sec. 3.3): linear in-plane, quadratic through the thickness.

Through-thickness weights are w(w-1)/2 (bottom), 1 - w^2 (mid-surface), w(w+1)/2 (top). The paper
prints (1-w)^2 for the mid-surface weight, which is 4 at w = -1: neither nodal nor a partition of
unity. tests/test_elements.py checks the printed form fails and ours passes.
"""

from sim.elements import register
from sim.elements.base import Prism

Q3T = register(Prism("q3t", p=1, q=2, default_quadrature=(1, 3)))
