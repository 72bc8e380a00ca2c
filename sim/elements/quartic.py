"""75-node quartic prism: 15-node triangle times quartic thickness (paper Fig. 8's quartic line).

In-plane rule: collapsed Gauss with 5 x 5 points (exact to degree 9 >= 2*(4-1) + 2); 5 Gauss
points through the thickness.
"""

from sim.elements.base import Prism

# 75 nodes a prism: the reference of studies and checks, too slow to run every scene with
QUARTIC = Prism("quartic", p=4, q=4, default_quadrature=(25, 5), routine=False,
                note="quartic prism: a reference for convergence studies, far slower")
