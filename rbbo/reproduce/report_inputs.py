"""What REPORT.md reads from the run directories beside Table I.

:func:`_runs` finds a run directory of the record; :func:`_directions` reads the walking
directions' runs (and plots each one's convergence), :func:`_perturbation` the perturbation
study's rows of the B_c it walks now, with each offset's fraction of the unperturbed R, and
:func:`_rl_trained` which RL methods a baselines.csv holds and how far each was trained.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .plan import ReproducePlan
from .status import _current_offsets
from .tables import read_rows, table_row


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


def _perturbation(out: Path, plan: ReproducePlan) -> list[dict[str, Any]]:
    # the rows the status counts: those of a B_c the base run no longer recommends stay in
    # perturbation.csv until the stage runs again, and are not its curve
    rows: list[dict[str, Any]] = [
        {"offset_deg": float(r["offset_deg"]), "R_mean": float(r["R_mean"]),
         "run": Path(r.get("run") or "").name}
        for r in _current_offsets(out, plan)
    ]  # fmt: skip
    base = [r["R_mean"] for r in rows if r["offset_deg"] == 0.0]
    for r in rows:
        r["fraction"] = r["R_mean"] / base[0] if base and base[0] > 0 else math.nan
    return sorted(rows, key=lambda r: r["offset_deg"])


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
