"""6-node linear prism (paper Eq. 4-6): two triangle layers, 2 points through the thickness.

The paper prints Eq. (6) as x = (w-1)/2 x_b + (w+1)/2 x_t; the bottom weight must be (1-w)/2 for
the interpolation to be nodal (it is -x_b at w = -1 as printed). Our basis is the correct one.
"""

from sim.elements import register
from sim.elements.base import Prism

LINEAR = register(Prism("linear", p=1, q=1, default_quadrature=(1, 2)))
