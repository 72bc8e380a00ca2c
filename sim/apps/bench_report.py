"""``q3t bench``'s tables in markdown, from its rows (``bench.json``): the cost per Newton
iteration at the paper's Table 1 sizes, the targets it is held to, plasticity's cost, forming
and the factorisation comparison; each section only when its cases ran."""

from __future__ import annotations

from sim.apps.bench_calculix import calculix_md
from sim.apps.study_report import FACTOR_COLS, markdown_table

TABLE1 = ("beam", "cup")
PLASTIC = ("beam_neo_hookean", "beam_hencky", "beam_plastic")

ITERATION_COLS = [("case", "case", ""), ("element", "element", ""),
                  ("elements", "elements", ",d"), ("dofs", "DoFs", ",d"),
                  ("iteration", "iteration [s]", ".3g"), ("assembly", "evaluation", ".3g"),
                  ("factorisation", "factorisation", ".3g"), ("solve", "solve", ".3g"),
                  ("energy", "energy", ".3g"), ("share", "evaluation share", ".1%"),
                  ("projected_hessian", "projected Hessian", ""),
                  ("paper_s", "paper [s]", ".3f")]
FORMING_COLS = [("elements", "elements", ",d"), ("dofs", "DoFs", ",d"), ("steps", "steps", ""),
                ("stroke_mm", "stroke [mm]", ".1f"), ("punch_force_kN", "punch force [kN]", ".1f"),
                ("per_iteration", "per iteration [s]", ".3g"), ("assembly", "evaluation", ".3g"),
                ("factorisation", "factorisation", ".3g"), ("solve", "solve", ".3g"),
                ("line_search", "line search", ".3g"),
                ("newton_per_step", "Newton it. per step", ".1f"), ("total", "total [s]", ".1f"),
                ("converged", "converged", ""), ("runs", "runs", "d"),
                ("paper_s", "paper [s]", ".3f")]
# (what, the row's case and element, the key, the bound, its format): the targets of
# docs/performance.md
TARGETS = [("beam Q3T iteration [s]", ("beam", "q3t"), "iteration", 0.1, ".3g"),
           ("cup Q3T iteration [s]", ("cup", "q3t"), "iteration", 0.8, ".3g"),
           ("beam Q3T evaluation share", ("beam", "q3t"), "share", 0.2, ".1%"),
           ("cup Q3T evaluation share", ("cup", "q3t"), "share", 0.2, ".1%"),
           ("plastic iteration over Hencky's", ("beam_plastic", "q3t"),
            "iteration_ratio_vs_hencky", 1.5, ".2f")]


def _with_share(r: dict) -> dict:
    return {**r, "share": r["assembly"] / r["iteration"]}


def iteration_md(rows: list[dict]) -> str:
    """The per-iteration table, Q3T's ratios to the other elements per case, the targets."""
    rows = [_with_share(r) for r in rows]
    by = {(r["case"], r["element"]): r for r in rows}
    ratios = [{"case": case, "other": el,
               "ratio": by[(case, "q3t")]["iteration"] / by[(case, el)]["iteration"],
               "paper": (by[(case, "q3t")]["paper_s"] / by[(case, el)]["paper_s"]
                         if by[(case, el)]["paper_s"] else None)}
              for case in dict.fromkeys(r["case"] for r in rows) if (case, "q3t") in by
              for el in dict.fromkeys(r["element"] for r in rows)
              if el != "q3t" and (case, el) in by]
    out = ("At a smooth deflection of a tenth of the thickness. iteration = evaluation (energy, "
           "gradient and exact Hessian in one pass, the scatter into the CSR data included) + "
           "factorisation + solve; \"energy\" is the energy-only evaluation a rejected full "
           "step adds, not included. Medians of the repeats.\n\n"
           + markdown_table(rows, ITERATION_COLS))
    if ratios:
        out += ("\nQ3T's iteration over the other elements' (quadratic: same nodes, fewer "
                "elements):\n\n" + markdown_table(ratios, [
                    ("case", "case", ""), ("other", "against", ""),
                    ("ratio", "Q3T / other", ".2f"), ("paper", "paper", ".2f")]))
    return out


def targets_md(rows: list[dict]) -> str:
    by = {(r["case"], r["element"]): _with_share(r) for r in rows}
    lines = [{"target": f"{what} < {bound:{f}}", "measured": format(by[where][key], f),
              "met": "met" if by[where][key] < bound else "NOT met"}
             for what, where, key, bound, f in TARGETS if key in by.get(where, {})]
    if not lines:
        return ""
    return markdown_table(lines, [("target", "target", ""), ("measured", "measured", ""),
                                  ("met", "", "")])


def plastic_md(rows: list[dict]) -> str:
    p = next(r for r in rows if r["case"] == "beam_plastic")
    return (f"Q3T beam at the elastic case's size; the plastic sheet (Swift hardening, yield "
            f"stress {p['yield_stress']:.3g} Pa, the median von Mises stress of the deflected "
            f"state) has {p['yielding_fraction']:.0%} of its quadrature points returning to "
            "the yield surface. Runs interleaved, one iteration of each per round; ratios are "
            "medians of the per-round ratios.\n\n"
            + markdown_table([_with_share(r) for r in rows], ITERATION_COLS)
            + "\n" + markdown_table([
                {"against": "Hencky (the plastic model's elastic law)",
                 "it": p["iteration_ratio_vs_hencky"], "ev": p["assembly_ratio_vs_hencky"]},
                {"against": "Neo-Hookean (the default sheet)",
                 "it": p["iteration_ratio_vs_neo_hookean"],
                 "ev": p["assembly_ratio_vs_neo_hookean"]}],
                [("against", "plastic against", ""), ("it", "per iteration", ".2f"),
                 ("ev", "evaluation", ".2f")]))


def forming_md(rows: list[dict]) -> str:
    out = ("`cup_drawing` run to the last timed step, where the punch nose, the die shoulder "
           "and the holder are in contact, with friction and plastic flow. Seconds per Newton "
           "iteration over the timed steps (the medians of the runs, the elements taking "
           "turns), and Newton iterations per step.\n\n"
           + markdown_table(rows, [("element", "element", ""), *FORMING_COLS]))
    q3t = next((r for r in rows if r["element"] == "q3t"), None)
    others = [r for r in rows if r["element"] != "q3t"]
    if q3t is None or not others:
        return out
    # the elements' own Newton paths reach the timed steps: the states differ a little, the
    # work per iteration (the same mesh, contact set and plastic flow) is what is compared;
    # the medians of the rounds' ratios (bench.forming_rounds)
    return out + "\n" + markdown_table(
        [{"element": r["element"], "it": r["per_iteration_vs_q3t"],
          "ev": r["assembly_vs_q3t"], "ls": r["line_search_vs_q3t"]} for r in others],
        [("element", "element", ""), ("it", "per iteration / Q3T's", ".2f"),
         ("ev", "evaluation / Q3T's", ".2f"), ("ls", "line search / Q3T's", ".2f")])


def bench_md(rows: list[dict]) -> str:
    """Every section whose cases are among ``rows``."""
    table1 = [r for r in rows if r["case"] in TABLE1]
    plastic = [r for r in rows if r["case"] in PLASTIC]
    forming = [r for r in rows if r["case"] == "cup_forming"]
    fig7 = [r for r in rows if r["case"] == "fig7"]
    ccx = [r for r in rows if r["case"] == "calculix"]
    parts = []
    if table1:
        parts.append("## Cost per Newton iteration (paper Table 1 sizes)\n\n"
                     + iteration_md(table1))
    if table1 or plastic:
        t = targets_md(table1 + plastic)
        if t:
            parts.append("## Against the targets\n\n" + t)
    if plastic:
        parts.append("## Plasticity's cost\n\n" + plastic_md(plastic))
    if forming:
        parts.append("## Forming (`cup_drawing`)\n\n" + forming_md(forming))
    if fig7:
        parts.append("## Factorisation against elements (paper Fig. 7)\n\n"
                     + markdown_table(fig7, FACTOR_COLS))
    if ccx:
        parts.append(calculix_md(ccx, [r for r in rows if r["case"] == "calculix_material"]))
    return "\n".join(parts)
