"""18-node quadratic prism: 6-node triangle in-plane times quadratic thickness, 7 x 3 points.

The reference element of the paper (Sec. 4); edge mid-nodes are shared between neighbours.
"""

from sim.elements.base import Prism

QUADRATIC = Prism("quadratic", p=2, q=2, default_quadrature=(7, 3),
                  note="18-node quadratic prism: the reference, 4 to 5 times q3t_ans's time")
