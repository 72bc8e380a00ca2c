"""6-node linear prism (paper Eq. 4-6): two triangle layers, 2 points through the thickness.

The paper prints Eq. (6) as x = (w-1)/2 x_b + (w+1)/2 x_t; the bottom weight must be (1-w)/2 for
the interpolation to be nodal (it is -x_b at w = -1 as printed). Our basis is the correct one.
"""

from sim.elements.base import Prism

# The paper's rule, 1 in-plane x 2 thickness points. Trade-off (docs/verification.md, "Quadrature
# and spurious modes"; tests/unit/test_elements.py): one spurious zero-energy mode on a free single
# prism or a triangle hanging by a vertex, none on any other mesh of two or more triangles or under
# any clamp. The 3 x 2 rule has none anywhere but is stiffer still (0.39 against 0.53 of the
# reference cantilever deflection at 8.75 mm, nu = 0.49); it is taken for meshes with patches of one
# or two triangles (sim.model.sheet.quadrature_rule).
LINEAR = Prism("linear", p=1, q=1, default_quadrature=(1, 2), small_mesh_quadrature=(3, 2),
               note="6-node prism, linear through the thickness: it locks in bending (the "
                    "paper's counter-example), for comparison only")
