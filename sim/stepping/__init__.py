"""Stepping a model through time: load stepping with cut-backs, friction's settling and the
release (springback) stage (simulation)."""
