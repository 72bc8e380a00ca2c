"""Waiting on the service and its processes: hang guards, never a clock a test races."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

from server.records import ACTIVE

# s: how long a test waits for something that must happen - a hang guard, never a clock it
# races (a run of the tiny scene takes a second; on a loaded machine, or compiling the
# kernels on a cold numba cache, a minute)
HANG = 300.0


def until(cond: Callable[[], Any], what: str, timeout: float = HANG) -> Any:
    """Poll ``cond()`` until it is true; fail past ``timeout`` s (a hang guard)."""
    deadline = time.monotonic() + timeout
    while not (out := cond()):
        assert time.monotonic() < deadline, what
        time.sleep(0.02)
    return out


def wait_state(client, run_id: str, states: set[str], timeout: float = HANG) -> dict:
    def done():
        st = client.get(f"/api/runs/{run_id}").json()
        return st if st["state"] in states else None

    return until(done, f"run {run_id} never reached {states}", timeout)


def wait_done(client, run_id: str) -> dict:
    """The status once the solver has acted on every command sent for the run."""
    def idle():
        st = client.get(f"/api/runs/{run_id}").json()
        return st if not st["pending"] else None

    return until(idle, f"the solver never acted on the commands for {run_id}")


def wait_step(client, run_id: str, step: int, timeout: float = HANG) -> dict:
    def reached():
        st = client.get(f"/api/runs/{run_id}").json()
        return st if st["step"] >= step or st["state"] not in ACTIVE else None

    return until(reached, f"run {run_id} did not reach step {step}", timeout)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
