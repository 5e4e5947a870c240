"""Sections of REPORT.md written by functions of their own, each returning its lines.

:func:`_across_runs` (Table I over the repeated RBBO runs), :func:`_bo_vs_boca` (the BO-vs-BOCA
figures and table, with :func:`_space_note` when the two runs of a benchmark searched different
simulation spaces) and :func:`_studies` (the two studies of C, their figures and tables).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from .figures import plot_bo_vs_boca, plot_study, simulated_minutes
from .plan import ReproducePlan
from .report_text import _num
from .tables import confidence_interval, read_rows


def _across_runs(per_run: list[dict[str, Any]], markdown: str, plan: ReproducePlan) -> list[str]:
    """Table I's improvement over each benchmark's runs (stage "table" with ``repeats``)."""
    last = plan.seed + plan.repeats - 1
    lines = [f"### Table I over {plan.repeats} RBBO runs per benchmark", "",
             f"Each benchmark's row above is its run 0 (seed {plan.seed}), whose B_c the "
             "later stages (transfer, perturbation, RL) use. Stage table made "
             f"{plan.repeats} independent RBBO runs of each benchmark, run k seeded "
             f"{plan.seed} + k (seeds {plan.seed}-{last}), each with the same budget and "
             "confirmed on its own fresh seeds. Below, each run's improvement (its seed in "
             "brackets) and over the runs confirmed so far (`runs`) the mean ± sample "
             "standard deviation (n - 1) and the range: how far another optimiser seed "
             "moves the result. Each run's R_init, R* and intervals are in "
             "[table1_runs.csv](table1_runs.csv).", "", markdown, ""]  # fmt: skip
    for bench in dict.fromkeys(r["benchmark"] for r in per_run):
        links = [f"[run {r['repeat']}](runs/{Path(r['run']).name}/convergence.png)"
                 for r in per_run if r["benchmark"] == bench]  # fmt: skip
        lines.append(f"- {bench} convergence: {', '.join(links)}")
    return [*lines, ""]


def _bo_vs_boca(panels: dict[str, dict[str, list]],
                confirmed: dict[str, dict[str, tuple[float | None, bool]]], out: Path,
                plan: ReproducePlan, written: dict[str, Any]) -> list[str]:  # fmt: skip
    """The BO-vs-BOCA figures (against wall time and against simulated time) and table."""
    written["figures"] += [plot_bo_vs_boca(panels, out / "bo_vs_boca.png"),
                           plot_bo_vs_boca(panels, out / "bo_vs_boca_simulated.png",
                                           axis="simulated")]  # fmt: skip
    lines = ["## BO vs BOCA", "",
             "Reward of every evaluation against the run's wall time (the paper's axis), and "
             "against the simulated time it evaluated (sum of T over evaluations and seeds). "
             "BOCA saves by evaluating shorter episodes first; within one version of the "
             "code both methods pay the same wall time per simulated second, but the two "
             "runs of a benchmark may have run different code or on a busier machine (the "
             "table's median wall time of one T_max evaluation says whether they did), and "
             "then only the second axis compares them. `BO within BOCA's` is BO's best R at "
             "T_max over the evaluations that fit in the simulated time the BOCA run spent "
             "in all. `R* confirmed` is each run's recommendation measured on the same fresh "
             "seeds in the current simulation space, as Table I's R*.", "",
             *_space_note(confirmed), "![BO vs BOCA](bo_vs_boca.png)", "",
             "![BO vs BOCA, simulated time](bo_vs_boca_simulated.png)", "",
             "| benchmark | BOCA best R at T_max | BO best R at T_max | BO within BOCA's "
             "simulated time | simulated time BOCA / BO (min) | wall of a T_max evaluation "
             "BOCA / BO (s, median) | BOCA evaluations | BO evaluations | R* confirmed "
             "BOCA / BO |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for bench, runs in panels.items():
        ok = {name: [e for e in evs if e.status == "ok"] for name, evs in runs.items()}
        full = {name: [e for e in evs if math.isclose(e.T, plan.t_max)]
                for name, evs in ok.items()}  # fmt: skip
        best = {name: max((e.R for e in evs), default=math.nan) for name, evs in full.items()}
        # simulated time over every evaluation, failed ones included: they spent it too
        spent = {name: float(simulated_minutes(evs)[-1]) if evs else 0.0
                 for name, evs in runs.items()}  # fmt: skip
        within = [e.R for e, t in zip(runs["bo"], simulated_minutes(runs["bo"]), strict=True)
                  if t <= spent["boca"] + 1e-9 and e.status == "ok"
                  and math.isclose(e.T, plan.t_max)]  # fmt: skip
        star = {name: value for name, (value, _) in confirmed[bench].items()}
        wall = {name: float(np.median([e.wall_s for e in evs])) if evs else math.nan
                for name, evs in full.items()}  # fmt: skip
        lines.append(
            f"| {bench} | {_num(best['boca'])} | {_num(best['bo'])} | "
            f"{_num(max(within, default=math.nan))} | {spent['boca']:.1f} / "
            f"{spent['bo']:.1f} | {_num(wall['boca'], '.3g')} / "
            f"{_num(wall['bo'], '.3g')} | {len(runs['boca'])} | "
            f"{len(runs['bo'])} | {_num(star['boca'])} / {_num(star['bo'])} |"
        )
    return [*lines, ""]


def _space_note(confirmed: dict[str, dict[str, tuple[float | None, bool]]]) -> list[str]:
    """A paragraph when a BOCA run searched another simulation space than its BO run."""
    apart = [bench for bench, runs in confirmed.items() if runs["boca"][1] != runs["bo"][1]]
    if not apart:
        return []
    return [f"The BOCA runs of {', '.join(apart)} searched the simulation space built before "
            "cache version 4 (their bases were carried into the current one afterwards, see "
            "Table I) and their BO runs the current one, so the search R of the two runs "
            "(the figures and the best-R columns) come from different reduced models: even "
            "the identity basis scores differently in them. Only `R* confirmed` compares "
            "the two methods in one model.", ""]  # fmt: skip


def _studies(out: Path, plan: ReproducePlan, written: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    cost = read_rows(out / "studies" / "cost_vs_c.csv")
    if cost:
        cs = [int(r["C"]) for r in cost]
        walls = [float(r["iteration_s"]) for r in cost]
        path = plot_study(cs, walls, None, "control-space dimension C", "wall time (s)",
                          f"one Gauss-Newton iteration, {plan.direction_env}",
                          out / "studies" / "cost_vs_c.png")  # fmt: skip
        written["figures"].append(path)
        lines += ["## Cost of one Gauss-Newton iteration against C", "",
                  "![cost vs C](studies/cost_vs_c.png)", "", "| C | rollouts | wall (s) |",
                  "|---|---|---|"]  # fmt: skip
        lines += [f"| {r['C']} | {r['rollouts']} | {float(r['iteration_s']):.3f} |" for r in cost]
        if len(cost) >= 2 and min(walls) > 0:
            slope = float(np.polyfit(np.log(cs), np.log(walls), 1)[0])
            shape = (
                "superlinear, as the paper's"
                if slope > 1
                else "not superlinear, unlike the paper's"
            )
            lines += ["", f"log-log slope {slope:.2f} (1 = linear in C): {shape}. Each C is one "
                      "timing on a shared machine, so single points move by 10-20 %."]  # fmt: skip
        lines.append("")
    reward = read_rows(out / "studies" / "reward_vs_c.csv")
    if reward:
        cs = sorted({int(r["C"]) for r in reward})
        per_c = [[float(r["R_m"]) for r in reward if int(r["C"]) == c] for c in cs]
        stats = [confidence_interval(v) for v in per_c]
        # the sample sd (n - 1), as Table I's runs spread has it; "-" for a single seed
        sds = [float(np.std(v, ddof=1)) if len(v) > 1 else math.nan for v in per_c]
        path = plot_study(cs, [m for m, _ in stats], sds, "control-space dimension C "
                          "(identity basis)", f"distance from t = {plan.settle_time:g} s (m)",
                          f"{plan.controller} on {plan.direction_env}",
                          out / "studies" / "reward_vs_c.png")  # fmt: skip
        written["figures"].append(path)
        lines += ["## Task reward against C (identity bases)", "",
                  "![reward vs C](studies/reward_vs_c.png)", "",
                  "| C | distance mean (m) | sd | seeds |", "|---|---|---|---|"]  # fmt: skip
        lines += [f"| {c} | {m:+.4f} | {'-' if math.isnan(sd) else f'{sd:.4f}'} | {len(v)} |"
                  for c, (m, _), sd, v in zip(cs, stats, sds, per_c, strict=True)]  # fmt: skip
        if len(cs) >= 2:
            best = cs[int(np.argmax([m for m, _ in stats]))]
            lines += ["", f"The mean distance is highest at C = {best}; the paper's levelled "
                      "off after C = 4, its reason for C = 3."]  # fmt: skip
        lines.append("")
    return lines
