"""Discretisation: a validated Scene becomes a Model (build), and its size before it is built
(size)."""
