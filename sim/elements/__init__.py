"""The one place that knows the element types: a registry of prisms by name.

Each element module defines one :class:`Prism`; a new element is one new file, its line below,
and its tests.
"""

from __future__ import annotations

from sim.elements.base import Prism
from sim.elements.linear import LINEAR
from sim.elements.q3t import Q3T
from sim.elements.q3t_ans import Q3T_ANS
from sim.elements.quadratic import QUADRATIC
from sim.elements.quartic import QUARTIC

ELEMENTS: dict[str, Prism] = {e.name: e for e in (LINEAR, Q3T, Q3T_ANS, QUADRATIC, QUARTIC)}
# where every element is meant but each run costs (every scene, every energy term through a
# model): the routine ones, in registry order
ROUTINE: tuple[str, ...] = tuple(n for n, e in ELEMENTS.items() if e.routine)


def get_element(name: str) -> Prism:
    try:
        return ELEMENTS[name]
    except KeyError:
        raise ValueError(f"unknown element {name!r}; known: {sorted(ELEMENTS)}") from None
