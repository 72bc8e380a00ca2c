"""The one place that knows the element types: a registry of prisms by name.

Each element module registers itself; a new element is one new file plus its tests.
"""

from __future__ import annotations

from sim.elements.base import Prism

ELEMENTS: dict[str, Prism] = {}


def register(element: Prism) -> Prism:
    ELEMENTS[element.name] = element
    return element


def get_element(name: str) -> Prism:
    try:
        return ELEMENTS[name]
    except KeyError:
        raise ValueError(f"unknown element {name!r}; known: {sorted(ELEMENTS)}") from None


from sim.elements import linear, q3t, quadratic, quartic  # noqa: E402,F401  (registration)
