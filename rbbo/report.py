"""The report of a run directory: the paper's Table I row and a convergence plot.

Table columns (as the paper's Table I): N (nodes of the robot's mesh), M, C, R_init (identity
basis), R* (RBBO's recommendation), improvement R*/R_init - 1, plus the number of evaluations
and the wall time. R_init and R* are means over fresh seeds at T_max, shown with their
standard deviation over those seeds when there are several (see
:mod:`rbbo.optimizer`); a run still in progress shows "-" for them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from .optimizer import CONFIRM_KINDS, RBBO
from .store import Evaluation, _atomic_savefig

__all__ = ["format_table", "load", "plot_convergence", "report_row"]


def _fmt(value, spec: str = ".3g", unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:{spec}}{unit}"


def _duration(seconds: float) -> str:
    seconds = round(seconds)
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"


def _sd(values) -> float | None:
    return float(np.std(values, ddof=1)) if len(values) > 1 else None


def _mean_sd(mean, sd) -> str:
    # '#': two significant digits kept as such (0.010, not 0.01)
    return _fmt(mean, ".4g") + ("" if mean is None or sd is None else f"±{sd:#.2g}")


def report_row(opt: RBBO) -> dict[str, Any]:
    """The report's numbers for one run (an RBBO rebuilt from its directory)."""
    result = opt.result()
    problem = (opt.store.config.get("problem") or {}) if opt.store else {}
    return {
        "run": str(opt.store.path) if opt.store else "",
        "problem": problem.get("env_id", ""),
        "N": problem.get("N"),
        "M": opt.config.sim_dim,
        "C": opt.config.control_dim,
        "R_init": result.R_init,
        "R_star": result.R_star,
        "R_init_sd": _sd(result.R_init_seeds),
        "R_star_sd": _sd(result.R_star_seeds),
        "improvement_pct": result.improvement_pct,
        "evaluations": result.evaluations,
        "failed": result.failed,
        "wall_s": result.wall_s,
        "fidelity": opt.config.fidelity,
        "best_index": result.best_index,
        "best_kind": next((e.kind for e in opt.evaluations if e.index == result.best_index), None),
    }


def format_table(rows: list[dict[str, Any]]) -> str:
    """A plain-text table, one line per run, and a line saying what its ± is."""
    header = ["problem", "N", "M", "C", "R_init", "R*", "improvement", "evaluations",
              "wall time"]  # fmt: skip
    lines = [header]
    for r in rows:
        failed = f" ({r['failed']} failed)" if r["failed"] else ""
        lines.append([
            r["problem"] or "-", _fmt(r["N"], "d"), str(r["M"]), str(r["C"]),
            _mean_sd(r["R_init"], r.get("R_init_sd")), _mean_sd(r["R_star"], r.get("R_star_sd")),
            _fmt(r["improvement_pct"], ".1f", " %"), f"{r['evaluations']}{failed}",
            _duration(r["wall_s"]),
        ])  # fmt: skip
    widths = [max(len(row[i]) for row in lines) for i in range(len(header))]
    text = ["  ".join(cell.rjust(w) for cell, w in zip(row, widths, strict=True)) for row in lines]
    text.insert(1, "  ".join("-" * w for w in widths))
    if any(r.get("R_init_sd") is not None or r.get("R_star_sd") is not None for r in rows):
        text.append("(R_init, R*: mean ± sample standard deviation over the confirmation seeds)")
    for r in rows:
        if r.get("best_kind") == "initial" and r.get("R_star") is not None:
            # the GP rated none of its own proposals above the design: the improvement, if
            # any, is the random design's, not the search's
            text.append(f"(R* of {r['problem'] or r['run'] or 'the run'}: evaluation "
                        f"{r['best_index']}, a point of the initial design, not one the GP "
                        "proposed: a longer run may find better)")  # fmt: skip
    return "\n".join(text)


def plot_convergence(opt: RBBO, path: str | Path) -> Path:
    """Reward against wall time and against evaluations (PNG, matplotlib's Agg canvas)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    history: list[Evaluation] = [e for e in opt.evaluations if e.status == "ok"]
    confirm = {e.kind: e for e in opt.history if e.kind in CONFIRM_KINDS and e.status == "ok"}
    t_max = opt.config.t_max
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, sharey=True)
    if history:
        order = np.arange(1, len(history) + 1)
        elapsed = np.array([e.elapsed_s for e in history])
        minutes = elapsed.max() > 120
        elapsed = elapsed / 60.0 if minutes else elapsed
        r = np.array([e.R for e in history])
        full = np.array([math.isclose(e.T, t_max) for e in history])
        best = np.maximum.accumulate(np.where(full, r, -np.inf))
        time_label = "wall time (min)" if minutes else "wall time (s)"
        for ax, x, label in ((axes[0], elapsed, time_label), (axes[1], order, "evaluation")):
            ax.scatter(x[full], r[full], s=14, color="C0", label=f"sample at T = {t_max:g} s")
            if (~full).any():
                ax.scatter(x[~full], r[~full], s=14, color="C1", marker="x",
                           label="sample at a shorter T (BOCA)")  # fmt: skip
            ok = np.isfinite(best)
            ax.step(x[ok], best[ok], where="post", color="C0", lw=1.5, label="best sample")
            ax.set_xlabel(label)
            ax.grid(alpha=0.3)
    for kind, color, name in (("confirm-init", "0.4", "R_init"), ("confirm-best", "C3", "R*")):
        if kind in confirm:
            for ax in axes:
                ax.axhline(confirm[kind].R, color=color, ls="--", lw=1,
                           label=f"{name} = {confirm[kind].R:.3g} (fresh seeds)")  # fmt: skip
    # an env's R is the task reward per second (m/s); the synthetic objective's a number on
    # Gr(M, C), 1 at its optimum
    synthetic = (opt.objective_spec or {}).get("kind") == "synthetic"
    axes[0].set_ylabel("R (synthetic objective)" if synthetic else "reward R per second")
    if axes[1].get_legend_handles_labels()[0]:  # (none when no evaluation succeeded)
        axes[1].legend(loc="lower right", fontsize=8)
    else:
        axes[1].text(0.5, 0.5, "no successful evaluation yet", ha="center", va="center",
                     transform=axes[1].transAxes)  # fmt: skip
    problem = (opt.store.config.get("problem") or {}).get("env_id", "") if opt.store else ""
    fig.suptitle(f"RBBO {problem}  Gr({opt.config.sim_dim}, {opt.config.control_dim}), "
                 f"{opt.config.fidelity.upper()}")  # fmt: skip
    return _atomic_savefig(fig, path, dpi=110)


def load(path: str | Path) -> RBBO:
    """Rebuild a run for reporting, read-only (it may still be running)."""
    return RBBO.resume(path, read_only=True)
