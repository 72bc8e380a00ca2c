"""9-node Q3T prism (paper Sec. 3.3): linear in-plane, quadratic through the thickness.

Through-thickness weights are w(w-1)/2 (bottom), 1 - w^2 (mid-surface), w(w+1)/2 (top). The paper
prints (1-w)^2 for the mid-surface weight, which is 4 at w = -1: neither nodal nor a partition of
unity. tests/unit/test_elements.py checks the printed form fails and ours passes.
"""

from sim.elements.base import Prism

# The paper's rule, 1 in-plane x 3 thickness points. Trade-off (docs/verification.md, "Quadrature
# and spurious modes"; tests/unit/test_elements.py): it leaves spurious zero-energy modes on a free
# mesh of one prism (4), two triangles (1), or a triangle hanging by a vertex (2); any other mesh of
# three or more triangles, or any clamp, has none. The 3 x 3 rule has no spurious mode anywhere but
# locks in transverse shear: 15 % too stiff on the paper's cantilever against 4.9 % for 1 x 3, which
# would break the 5 % accuracy claim. So 1 x 3 is the default, and 3 x 3 is taken for meshes with
# patches of one or two triangles (sim.model.sheet.quadrature_rule).
Q3T = Prism("q3t", p=1, q=2, default_quadrature=(1, 3), small_mesh_quadrature=(3, 3),
            note="the paper's 9-node Q3T prism: the fastest that bends right, but on a coarse "
                 "mesh its one in-plane point leaves a noisy thickness (the 2 mm cup thins "
                 "20 % where 8-9 % is right)")
