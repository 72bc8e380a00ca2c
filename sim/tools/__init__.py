"""Rigid forming tools as SDF programs: the format (program), its numba evaluator (primitives,
evaluate), poses, polygon geometry, builders, the program of a scene's shape (shapes) and
display surfaces (surface, implicit)."""
