"""Solving one increment: the fixed sparse pattern (assembly), the linear solvers (linsolve) and
projected Newton on the sum of the energy terms (newton)."""
