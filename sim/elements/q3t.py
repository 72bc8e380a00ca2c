"""9-node Q3T prism (paper Sec. 3.3): linear in-plane, quadratic through the thickness.

Through-thickness weights are w(w-1)/2 (bottom), 1 - w^2 (mid-surface), w(w+1)/2 (top). The paper
prints (1-w)^2 for the mid-surface weight, which is 4 at w = -1: neither nodal nor a partition of
unity. tests/test_elements.py checks the printed form fails and ours passes.
"""

from sim.elements import register
from sim.elements.base import Prism

# The paper's rule is 1 in-plane x 3 thickness points. On a free two-element patch it admits one
# zero-energy mode beyond the rigid ones (tests/test_elements.py), so our default is 3 x 3; the
# paper's rule stays selectable per scene with quadrature = [1, 3].
Q3T = register(Prism("q3t", p=1, q=2, default_quadrature=(3, 3)))
