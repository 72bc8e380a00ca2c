"""Q3T with assumed natural strains: the 9-node prism of Q3T (linear in-plane, quadratic through
the thickness) whose transverse shear strains e_rw, e_sw are tied to their tangential values on
the triangle's edges (MITC3) and whose thickness strain e_ww is tied at its corners
(sim.terms.ans), with the full three-point in-plane rule.

Q3T's one-point in-plane rule leaves spurious zero-energy modes and a zigzag of curvature; its
three-point rule removes them but locks in transverse shear, because a linear triangle cannot
bend without shearing at points off its edges' midpoints. Sampling the shear only where the
displacement field represents it (the edge midpoints, tangentially) removes that locking, as in
Lee and Bathe's MITC3 shell (Comput. Struct. 82, 2004) and Sze's ANS solid-shell prisms; the
thickness direction keeps Q3T's quadratic field, which cures Poisson locking. On a curved sheet
the corners' directors differ, and the field's thickness strain between them takes bending for
stretching through the thickness (curvature thickness locking); tied at the corners it does not.
"""

from sim.elements.base import Prism

Q3T_ANS = Prism("q3t_ans", p=1, q=2, default_quadrature=(3, 3), assumed_strain=True,
                note="Q3T with assumed strains: no locking, no spurious modes; right thinning on "
                     "coarse meshes for about 1.5 times Q3T's time (the forming scenes' element)")
