"""REPORT.md of a reproduction: every number read from the run directories, none typed.

:func:`write_report` gathers Table I (:mod:`.tables`), the BO-vs-BOCA, direction and
perturbation figures (:mod:`.figures`) and the two studies of C, and writes them with the
commands that made them, the machine and the paper's numbers beside ours.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .figures import (
    plot_bo_vs_boca,
    plot_directions,
    plot_perturbation,
    plot_study,
    simulated_minutes,
)
from .plan import PAPER_DIRECTIONS, ReproducePlan
from .status import _rl_benchmarks, recorded_repeats, rl_bases, stage_progress
from .tables import (
    across_runs,
    confidence_interval,
    format_markdown,
    format_runs_markdown,
    read_rows,
    run_row,
    table_row,
    write_csv,
)
from .transfer import format_transfer_markdown, transfer_rows

__all__ = ["write_report"]


def _runs(out: Path, name: str) -> Path | None:
    path = out / "runs" / name
    return path if (path / "config.json").exists() else None


def _directions(out: Path, plan: ReproducePlan) -> list[dict[str, Any]]:
    from ..report import load, plot_convergence

    rows = []
    for deg in plan.direction_angles_deg():
        run = _runs(out, f"{plan.direction_env}-dir{deg:03.0f}")
        if run is None:
            continue
        row = table_row(plan.direction_env, run)
        plot_convergence(load(run), run / "convergence.png")
        rows.append({"direction_deg": deg, "R_init": row["R_init"], "R_star": row["R_star"],
                     "R_init_ci95": row["R_init_ci95"], "R_star_ci95": row["R_star_ci95"],
                     "improvement_pct": row["improvement_pct"], "apart": row["apart"],
                     "evaluations": row["evaluations"], "wall_s": row["wall_s"]})  # fmt: skip
    return rows


def _perturbation(out: Path) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = [
        {"offset_deg": float(r["offset_deg"]), "R_mean": float(r["R_mean"]),
         "run": Path(r.get("run") or "").name}
        for r in read_rows(out / "perturbation.csv")
    ]  # fmt: skip
    base = [r["R_mean"] for r in rows if r["offset_deg"] == 0.0]
    for r in rows:
        r["fraction"] = r["R_mean"] / base[0] if base and base[0] > 0 else math.nan
    return sorted(rows, key=lambda r: r["offset_deg"])


def _num(x: float | None, spec: str = ".4g") -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:{spec}}"


def _machine(sessions: list[dict[str, Any]] | None = None) -> str:
    """The machines the sessions ran on, as recorded (since 2026-12-02): a session that
    recorded none is counted as such, not taken to have run where the report is written."""
    from ..provenance import machine_description

    if not sessions:
        return machine_description()
    seen = " / ".join(dict.fromkeys(s["machine"] for s in sessions if s.get("machine")))
    missing = sum(not s.get("machine") for s in sessions)
    if not missing:
        return seen
    unrecorded = f"{missing} session{'s' if missing > 1 else ''} whose machine was not recorded"
    return f"{seen} (and {unrecorded})" if seen else f"a machine not recorded ({unrecorded})"


def _session_values(sessions: list[dict[str, Any]], key: str, current: float) -> str:
    """A setting that may change between sessions, as the report prints it: one value, or
    each distinct value in the order the sessions used them."""
    values = list(dict.fromkeys(s.get(key, current) for s in sessions)) or [current]
    if key.endswith("_s"):
        return " / ".join(f"{v / 60:g}" for v in values)
    return " / ".join(f"{v:g}" for v in values)


def _told_in_order(sessions: list[dict[str, Any]], current: bool) -> str:
    """Which sessions told the optimisation runs' results in proposal order
    (``--deterministic``), as the report says it after the workers."""
    flags = [bool(s.get("deterministic", False)) for s in sessions] or [current]
    if not any(flags):
        return ""
    if all(flags):
        return " (results told in proposal order)"
    which = ", ".join(str(i + 1) for i, flag in enumerate(flags) if flag)
    return f" (results told in proposal order in session{'s' if ',' in which else ''} {which})"


def _relink(lines: list[str], out: Path, folder: Path) -> list[str]:
    """Rewrite the report's links (relative to ``out``) to be relative to ``folder``."""
    prefix = Path(os.path.relpath(out.resolve(), folder.resolve())).as_posix()
    if prefix == ".":
        return lines
    return [re.sub(r"\]\((?![a-z]+:)", f"]({prefix}/", line) for line in lines]


def write_report(out: Path, plan: ReproducePlan, document: dict[str, Any],
                 copy_to: Path | None = None) -> dict[str, Any]:  # fmt: skip
    """Write table1.{csv,md}, the figures and REPORT.md into ``out`` (and the same report,
    its links rewritten, to ``copy_to``); returns what it wrote."""
    from ..report import load, plot_convergence

    # the runs the whole record holds, whichever number the last session asked for
    plan = replace(plan, repeats=recorded_repeats({"plan": plan.to_dict(), **document}))
    written: dict[str, Any] = {"figures": []}
    table, per_run = [], []
    panels: dict[str, dict[str, list]] = {}
    confirmed: dict[str, dict[str, tuple[float | None, bool]]] = {}
    for bench in plan.benchmarks:
        boca, bo = _runs(out, plan.table_run(bench)), _runs(out, f"{bench}-bo")
        for run in (boca, bo):
            if run is not None:
                plot_convergence(load(run), run / "convergence.png")
        if boca is not None:
            table.append(table_row(bench, boca))
        for k in range(plan.repeats) if plan.repeats > 1 else ():
            run = _runs(out, plan.table_run(bench, k))
            if run is not None:
                if k:
                    plot_convergence(load(run), run / "convergence.png")
                per_run.append(run_row(bench, k, run))
        pair = {name: (run, load(run)) for name, run in (("boca", boca), ("bo", bo))
                if run is not None}  # fmt: skip
        if len(pair) == 2:
            panels[bench] = {name: opt.evaluations for name, (_, opt) in pair.items()}
            # R* on the fresh seeds, and whether the search ran in a space carried since
            confirmed[bench] = {name: (opt.result().R_star, (run / "migration.json").exists())
                                for name, (run, opt) in pair.items()}  # fmt: skip
    lines = [f"# Reproduction of the paper's results: {', '.join(plan.benchmarks)}", ""]
    sessions = document.get("sessions", [])
    total = sum(s.get("wall_s", 0.0) for s in sessions)
    lines += ["Made by (each session of this reproduction, in order):", "", "```"]
    lines += [s["command"] + (f"  # {s['source']}" if s.get("source") else "")
              for s in sessions] + ["```", ""]  # fmt: skip
    cap = "" if plan.iterations is None else f" or {plan.iterations} evaluations"
    progress = stage_progress(out, plan)
    beside = "; the BO run beside it had the same" if progress["bo"][0] or panels else ""
    each = f", each of its {plan.repeats} runs" if plan.repeats > 1 else ""
    lines += [f"Total wall time {total / 60:.1f} min on {_machine(sessions)}. Budget per "
              f"benchmark {_session_values(sessions, 'budget_s', plan.budget_s)} min{cap} "
              f"(BOCA{each}{beside}), {_session_values(sessions, 'workers', plan.workers)} workers"
              f"{_told_in_order(sessions, plan.deterministic)}, "
              f"controller {plan.controller}, M = {plan.sim_dim}, "
              f"C = {plan.control_dim}, T in [{plan.t_min:g}, {plan.t_max:g}] s, R measured "
              f"from t = {plan.settle_time:g} s, R_init and R* each on {plan.confirm_seeds} "
              "fresh MPC seeds (mean ± 95 % t-interval).", ""]  # fmt: skip
    lines += _progress_lines(progress)
    if plan.planner_kwargs:
        lines += [f"MPC settings overridden: `{plan.planner_kwargs}`.", ""]
    runs_markdown = format_runs_markdown(per_run, plan.repeats) if per_run else ""
    if per_run:
        write_csv(per_run, out / "table1_runs.csv")
        written["runs_markdown"] = runs_markdown
        for row in table:  # table1.csv: run 0's numbers, and the spread over the runs
            row.update(across_runs([r for r in per_run if r["benchmark"] == row["benchmark"]]))
    if table:
        write_csv(table, out / "table1.csv")
        markdown = format_markdown(table)
        (out / "table1.md").write_text(markdown + "\n" + (f"\n{runs_markdown}\n" if per_run
                                                           else ""))  # fmt: skip
        written["table"] = table
        lines += ["## Table I", "", "R is the distance travelled along d per second from the "
                  "settle time (m/s); the paper's R is its own distance measure, so only the "
                  "improvement compares. `apart`: R*'s 95 % interval lies above R_init's. "
                  "Both are measured on the same fresh seeds, so `R* - R_init (paired)` is the "
                  "mean per-seed gain with its own 95 % t-interval, the sharper test of the "
                  "two. `paper`: the paper's improvement.", "", markdown, ""]  # fmt: skip
        paired = [r["benchmark"] for r in table if r["paired_apart"]]
        measured = [r for r in table if math.isfinite(r["R_star"])]
        pending = len(table) - len(measured)
        lines += [f"Intervals apart on {sum(r['apart'] for r in table)} of {len(measured)} "
                  f"benchmarks; the paired gain's interval excludes zero on {len(paired)} of "
                  f"{len(measured)}"
                  + (f" ({pending} not yet confirmed)." if pending else "."), ""]  # fmt: skip
        for r in table:
            link = f"runs/{Path(r['run']).name}"
            lines.append(f"- {r['benchmark']}: [convergence]({link}/convergence.png), "
                         f"[best basis]({link}/best_basis.npy), "
                         f"[history]({link}/history.jsonl)")  # fmt: skip
        lines.append("")
        if per_run:
            lines += _across_runs(per_run, runs_markdown, plan)
        carried = [r["benchmark"] for r in table if (Path(r["run"]) / "migration.json").exists()]
        if carried:
            lines += [f"The runs of {', '.join(carried)} searched the simulation space that "
                      "softrom built before its cache version 4, when a mode's sign came from "
                      "the BLAS kernel of the machine. Their stored bases were carried into "
                      "the machine-independent B_r (the same full-space actuations: "
                      "`migration.json` in each run, `benchmarks/migrate_run_bases.py`) and "
                      "R_init and R* above were measured again there (`rbbo confirm`; the "
                      "wall time counts both confirmations); the search itself, its "
                      "evaluation count and convergence plot, ran in the old space, whose "
                      "cubature rule differs by how it broke ties.",
                      ""]  # fmt: skip
    transfer = transfer_rows(out, table, plan.transfer_sim_dim) if table else []
    if transfer:
        write_csv(transfer, out / "transfer_table.csv")
        written["transfer"] = transfer
        m_to = plan.transfer_sim_dim
        lines += [f"## Table I's control spaces at M = {m_to}", "",
                  f"RBBO searched B_c inside the M = {plan.sim_dim} simulation space, and a "
                  "control space can win there by using what those modes cannot represent. "
                  f"Here R_init's and R*'s B_c are carried into the M = {m_to} model of the "
                  f"same robot (T B_c with T = B_{m_to}^T M B_{plan.sim_dim}, the same "
                  "full-space actuation, since the spaces nest) and measured again with the "
                  "same MPC on the same fresh seeds ([transfer.csv](transfer.csv)). A gain "
                  "that survives the richer model is less likely the truncation's; one that "
                  f"vanishes was. M = {m_to} is not the full-space robot either (the README's "
                  "known limit: distances keep changing with M), so this is a robustness "
                  "check, not a converged answer.", "", format_transfer_markdown(transfer),
                  ""]  # fmt: skip
        kept = sum(r["paired_apart"] for r in transfer)
        lines += [f"At M = {m_to} the paired gain's interval excludes zero on {kept} of "
                  f"{len(transfer)} benchmarks; intervals apart on "
                  f"{sum(r['apart'] for r in transfer)} of {len(transfer)}.", ""]  # fmt: skip
    if panels:
        lines += _bo_vs_boca(panels, confirmed, out, plan, written)
    directions = _directions(out, plan)
    if directions:
        path = plot_directions(directions, out / "directions.png")
        written["figures"].append(path)
        written["directions"] = directions
        gains = [r["improvement_pct"] for r in directions if math.isfinite(r["improvement_pct"])]
        lines += [
            f"## {len(plan.direction_angles_deg())} walking directions",
            "",
            "![directions](directions.png)",
            "",
            "| direction (deg) | R_init | R* | improvement | apart |",
            "|---|---|---|---|---|",
        ]
        lines += [f"| {r['direction_deg']:g} | {_num(r['R_init'])} ± "
                  f"{_num(r['R_init_ci95'], '.2g')} | {_num(r['R_star'])} ± "
                  f"{_num(r['R_star_ci95'], '.2g')} | "
                  f"{_num(r['improvement_pct'], '+.1f')} % | {'yes' if r['apart'] else 'no'} |"
                  for r in directions]  # fmt: skip
        if gains:
            lines += ["", f"Improvement from {min(gains):+.1f} % to {max(gains):+.1f} % (the "
                      f"paper: {PAPER_DIRECTIONS['min_improvement_pct']:+.2f} % to "
                      f"{PAPER_DIRECTIONS['max_improvement_pct']:+.2f} %)."]  # fmt: skip
        lines.append("")
    perturbation = _perturbation(out)
    if perturbation:
        path = plot_perturbation(perturbation, out / "perturbation.png")
        written["figures"].append(path)
        written["perturbation"] = perturbation
        near = [r["fraction"] for r in perturbation if 0 < abs(r["offset_deg"]) <= 10]
        runs = sorted({r["run"] for r in perturbation if r["run"]})
        lines += [
            "## Direction perturbation",
            "",
            "![perturbation](perturbation.png)",
            "",
            *(
                [
                    f"The recommended B_c of {', '.join(f'`runs/{r}`' for r in runs)} (whichever "
                    "run of the direction robot along d = 0 had finished first: the directions "
                    "stage's or Table I's), walked at each offset from d.",
                    "",
                ]
                if runs
                else []
            ),
            "| offset (deg) | R | fraction of R at 0 |",
            "|---|---|---|",
        ]
        lines += [f"| {r['offset_deg']:+g} | {_num(r['R_mean'])} | {_num(r['fraction'], '.2f')} |"
                  for r in perturbation]  # fmt: skip
        if near:
            paper = PAPER_DIRECTIONS["fraction_within_10deg"]
            lines += ["", f"Within ±10°: at least {min(near):.0%} of the unperturbed R (the "
                      f"paper: about {paper:.0%})."]  # fmt: skip
        lines.append("")
    lines += _studies(out, plan, written)
    for bench in _rl_benchmarks(out, plan):
        table_md = out / "rl" / bench / "baselines.md"
        if table_md.exists():
            methods, budget = _rl_trained(out / "rl" / bench / "baselines.csv")
            _, identity_only = rl_bases(out, plan, bench)
            bases = "on the identity basis " + (
                f"({identity_only})" if identity_only else "and on the Table I B_c (`rbbo-<hash>`)"
            )
            lines += [f"## RL baselines on {bench}", "",
                      f"{methods} (Stable-Baselines3, {budget}, "
                      f"evaluated at every checkpoint) beside MPPI, {bases}, over the same "
                      f"{plan.confirm_seeds} seeds and {plan.t_max:g}-s episodes, distance "
                      f"from t = {plan.settle_time:g} s (mean ± 95 % t-interval).", "",
                      table_md.read_text().strip(), ""]  # fmt: skip
    counts = [r["evaluations"] for r in table if math.isfinite(r["R_star"])]  # finished runs
    lines += ["## Where ours differs from the paper, and why", "",
              "- Our simulator is not theirs: our meshes have other node counts (column N), our "
              "B_r has linearised rotations and no floating frame, and contact is staggered "
              "projection in reduced coordinates; the paper's absolute R are in its own units.",
              "- Our R_init is the identity basis under our MPC (gait-seeded periodic MPPI or "
              "Gauss-Newton), which already walks; a stronger baseline leaves less to gain.",
              f"- Our budget is {_session_values(sessions, 'budget_s', plan.budget_s)} min{cap} "
              f"per benchmark on {_machine(sessions)} "
              "against the paper's 10 hours on 48 cores"
              + (f", so RBBO saw {min(counts)}"
                 + (f"-{max(counts)}" if max(counts) > min(counts) else "")
                 + " evaluations per benchmark." if counts else "."),
              "- R_init and R* are confirmed on fresh seeds not used in the search, so a lucky "
              "sample cannot make the improvement.",
              "- R* is the evaluated B_c with the highest GP posterior mean of R at T_max (in "
              "runs made before 2026-12-05, among the bases evaluated at T_max; since, among "
              "all), not the paper's Algorithm 1 answer, the highest observed R: with MPC "
              "seeds as noise the highest single sample is the luckiest one.",
              "- R is the distance along d per second"
              + (f" from t = {plan.settle_time:g} s of the episode" if plan.settle_time > 0
                 else "")
              + ", not the whole trajectory's distance: a rate compares BOCA's episodes of "
              "different T"
              + (", and the first seconds (settling on the ground, a first lunge) are not a "
                 "gait." if plan.settle_time > 0 else "."),
              *([f"- Each benchmark has one RBBO run (seed {plan.seed}), as the paper's: the ± "
                 "intervals are over MPC seeds for fixed bases, not over optimiser runs, and "
                 "an improvement over a small R_init moves by hundreds of points when the same "
                 "two bases are measured on other seeds or code."]
                if counts and plan.repeats == 1 else []),
              *([f"- Each benchmark has {plan.repeats} RBBO runs (seeds {plan.seed}-"
                 f"{plan.seed + plan.repeats - 1}) where the paper has one: Table I's ± "
                 "intervals are over MPC seeds for run 0's two bases, the table under it "
                 "gives the spread over optimiser runs, and an improvement over a small R_init "
                 "moves by hundreds of points when the same two bases are measured on other "
                 "seeds or code."] if counts and plan.repeats > 1 else []),
              f"- Every R is the M = {plan.sim_dim} reduced model's. Walking distances are not "
              "converged in M (the README's known limit: on CrossWalk-v0 a closed-loop episode "
              "walks less in M = 40 or 60), so R_init, R* and the improvement compare control "
              "spaces inside one simulation space, as the paper's do, and are not the "
              "full-space robot's distances"
              + (f" (the section at M = {plan.transfer_sim_dim} above says how much of each "
                 "gain a richer model keeps)." if transfer else "."), ""]  # fmt: skip
    (out / "REPORT.md").write_text("\n".join(lines))
    written["report"] = out / "REPORT.md"
    if copy_to is not None:
        copy_to.parent.mkdir(parents=True, exist_ok=True)
        copy_to.write_text("\n".join(_relink(lines, out, copy_to.parent)))
        written["copy"] = copy_to
    return written


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
        stats = [confidence_interval([float(r["R_m"]) for r in reward if int(r["C"]) == c])
                 for c in cs]  # fmt: skip
        sds = [float(np.std([float(r["R_m"]) for r in reward if int(r["C"]) == c])) for c in cs]
        path = plot_study(cs, [m for m, _ in stats], sds, "control-space dimension C "
                          "(identity basis)", f"distance from t = {plan.settle_time:g} s (m)",
                          f"{plan.controller} on {plan.direction_env}",
                          out / "studies" / "reward_vs_c.png")  # fmt: skip
        written["figures"].append(path)
        lines += ["## Task reward against C (identity bases)", "",
                  "![reward vs C](studies/reward_vs_c.png)", "",
                  "| C | distance mean (m) | sd | seeds |", "|---|---|---|---|"]  # fmt: skip
        lines += [f"| {c} | {m:+.4f} | {sd:.4f} | "
                  f"{sum(int(r['C']) == c for r in reward)} |"
                  for c, (m, _), sd in zip(cs, stats, sds, strict=True)]  # fmt: skip
        if len(cs) >= 2:
            best = cs[int(np.argmax([m for m, _ in stats]))]
            lines += ["", f"The mean distance is highest at C = {best}; the paper's levelled "
                      "off after C = 4, its reason for C = 3."]  # fmt: skip
        lines.append("")
    return lines


def _progress_lines(progress: dict[str, tuple[int, int]]) -> list[str]:
    """What the record does not hold yet: stages with no part finished, and stages with
    some. (A run still searching or not yet confirmed is not finished; the sections below
    show it with what it has, its R* as "-" until confirmed.)"""
    missing = [stage for stage, (done, n) in progress.items() if n and done == 0]
    partial = [f"{stage} ({done} of {n})" for stage, (done, n) in progress.items()
               if 0 < done < n]  # fmt: skip
    lines = []
    if missing:
        lines += [f"No part finished yet: {', '.join(missing)}.", ""]
    if partial:
        lines += [f"Under way (parts finished of those planned): {', '.join(partial)}.", ""]
    return lines


def _rl_trained(path: Path) -> tuple[str, str]:
    """The RL methods of a baselines.csv and the env steps each was trained to, as the
    report says them ("PPO and SAC", "PPO 301056 and SAC 60000 env steps")."""
    steps: dict[str, int] = {}
    for r in read_rows(path):
        if r["method"] != "mppi" and r["final"] == "True":
            steps[r["method"]] = max(steps.get(r["method"], 0), int(float(r["env_steps"])))
    if not steps:
        return "RL", "no training finished yet"
    names = " and ".join(m.upper() for m in steps)
    if len(set(steps.values())) == 1:
        return names, f"{next(iter(steps.values()))} env steps each"
    return names, " and ".join(f"{m.upper()} {n}" for m, n in steps.items()) + " env steps"
