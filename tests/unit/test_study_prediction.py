"""The study plan's time prediction (server.studies.predicted) against measured times: the
refinement study of the convergence scene (docs/results/fig8-convergence.md, `q3t study
convergence`: three elements at four levels each, 378 to 83,979 DoFs, one worker thread) from
its finest Q3T case alone. The plan claims a factor of two or three; every case is within two,
the cases of a few milliseconds (fixed costs the scaling does not see) the farthest."""

from __future__ import annotations

from server.studies import predicted
from sim.stamp import ROOT

REPORT = ROOT / "docs" / "results" / "fig8-convergence.md"


def measured() -> list[tuple[str, int, float]]:
    """(element, DoFs, time [s]) of each case of the report's table."""
    out = []
    for line in REPORT.read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 9 and cells[0] in ("linear", "q3t", "quadratic") and cells[8]:
            out.append((cells[0], int(cells[3]), float(cells[6])))
    return out


def test_each_case_is_predicted_within_a_factor_of_two_from_one_run():
    cases = measured()
    assert len(cases) == 12, cases
    el, dofs, seconds = max((c for c in cases if c[0] == "q3t"), key=lambda c: c[1])
    basis = {"element": el, "dofs": dofs, "seconds": seconds}
    ratios = {(e, d): predicted(basis, e, d) / t for e, d, t in cases}
    assert all(0.5 <= r <= 2.0 for r in ratios.values()), ratios
    # the quadratic prism four times the DoFs of the basis, the study's costliest case
    assert 0.8 <= ratios["quadratic", max(d for e, d, _ in cases if e == "quadratic")] <= 1.25
