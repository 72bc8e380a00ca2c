"""What `q3t run` prints: a progress bar rewritten in place on a terminal (a pseudo-terminal
here), one plain line per step when its output goes to a pipe or a file, and at the end the run
summary of result.json as a table with units."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import select
import struct
import subprocess
import sys
import termios

import pytest

from sim.apps.cli import main
from sim.apps.progress import clock
from tests.support import ROOT
from tests.support.scenes import PRESS_TOML
from tests.support.service import HANG

pytestmark = pytest.mark.fast  # seconds: make test-fast runs it

COLUMNS = 72  # the pseudo-terminal's width: narrower than a full bar line, which must not wrap


@pytest.fixture(scope="module")
def press(tmp_path_factory):
    path = tmp_path_factory.mktemp("press") / "press.toml"
    path.write_text(PRESS_TOML)
    return path


def q3t_run(press, out, stderr) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sim.apps", "run", str(press), "--out",
                           str(out)], stdout=subprocess.PIPE, stderr=stderr,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=HANG)


def test_summary_table_has_the_results_values_and_units(press, tmp_path, capsys):
    assert main(["run", str(press), "--quiet", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    entries = json.loads((tmp_path / "result.json").read_text())["summary"]
    names = {e["name"] for e in entries}
    assert {"peak_punch_force", "min_thickness", "max_thinning", "max_draw_in"} <= names
    lines = out.splitlines()
    assert lines[0] == "Summary" and lines[1].split() == ["quantity", "value", "where"]
    assert len(lines) == 2 + len(entries)
    for e, line in zip(entries, lines[2:], strict=True):
        shown = f"{e['display']['value']:.4g} {e['display']['unit']}"
        assert line.startswith(e["label"]) and shown in line, (line, e)
    row = {e["name"]: line for e, line in zip(entries, lines[2:], strict=True)}
    for name, unit in (("peak_punch_force", "kN"), ("min_thickness", "mm"),
                       ("max_thinning", "%"), ("max_draw_in", "mm")):
        assert f" {unit}  " in row[name], row[name]
    # where: the last of 3 steps of 0.2/3 mm
    assert "(punch)" in row["peak_punch_force"] and "stroke 0.2 mm" in row["peak_punch_force"]


def test_no_punch_no_punch_force(tmp_path, capsys):
    args = ["--set", "mesh.edge_length=0.035", "--set", "stepping.steps=2"]
    assert main(["run", "cantilever", *args, "--quiet", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Minimum thickness" in out and "punch" not in out.lower()


def test_progress_on_a_terminal_is_one_bar(press, tmp_path):
    main_fd, term = pty.openpty()
    fcntl.ioctl(term, termios.TIOCSWINSZ, struct.pack("HHHH", 24, COLUMNS, 0, 0))
    proc = None
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim.apps", "run", str(press), "--out", str(tmp_path)],
            stdout=subprocess.PIPE, stderr=term, env={**os.environ, "PYTHONPATH": str(ROOT)})
        os.close(term)
        err = b""
        while chunk := _read(main_fd):
            err += chunk
        out = proc.communicate(timeout=HANG)[0].decode()
    finally:
        os.close(main_fd)
        if proc and proc.poll() is None:  # a failed wait above: leave no process behind
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    err = err.decode()
    bars = [b for line in err.split("\n") for b in line.split("\r") if b.startswith("[")]
    assert len(bars) == 3  # one frame per step, each rewriting the last in place
    assert "step 3/3" in bars[-1] and "stroke 0.20 mm" in bars[-1]
    assert bars[-1].startswith("[" + "#" * 24 + "]")
    assert all(len(b) == COLUMNS - 1 for b in bars)  # clipped and padded: never wraps
    # the bar's line ends before the next message starts
    assert "\nwrote " in err and "step 3/3: " not in err
    assert "Peak punch force" in out


def test_progress_in_a_log_is_a_plain_line_per_step(press, tmp_path):
    r = q3t_run(press, tmp_path, subprocess.PIPE)
    assert r.returncode == 0
    err = r.stderr.decode()
    assert "\r" not in err
    steps = [line for line in err.splitlines() if line.startswith("step ")]
    assert [s.split(":")[0] for s in steps] == ["step 1/3", "step 2/3", "step 3/3"]
    assert all("stroke" in s and "elapsed" in s and "left" in s for s in steps)


def _read(fd: int) -> bytes:
    """What the terminal got next, b"" once the child has closed it (Linux: EIO)."""
    assert select.select([fd], [], [], HANG)[0], "q3t run wrote nothing to its terminal"
    try:
        return os.read(fd, 4096)
    except OSError:
        return b""


@pytest.mark.parametrize("seconds,text", [(0.4, "0 s"), (59.4, "59 s"), (61, "1:01"),
                                          (3725, "1:02:05")])
def test_clock(seconds, text):
    assert clock(seconds) == text
