"""The request problems the API answers with a 4xx (or 503). Anything else that escapes a route
is a bug in the server and becomes a 500, so it cannot pass for a user's mistake."""

from __future__ import annotations


class Invalid(ValueError):
    """The request names something badly or gives a value out of range (422)."""


class NotFound(KeyError):
    """No such scene, run, frame or file (404)."""

    def __str__(self) -> str:  # KeyError's str() would add quotes
        return str(self.args[0]) if self.args else ""


class Conflict(RuntimeError):
    """The request does not fit the run's state (409)."""


class NotReady(RuntimeError):
    """The solver process has not started yet; retry in a moment (503)."""


class Busy(RuntimeError):
    """Every solver process is busy and the run queue is full (429)."""


class Unsolved(RuntimeError):
    """The solve a request asked for failed (a split ring's release): the solver's reason,
    with its numbers, and nothing written (422)."""
