"""The reproduction's figures (matplotlib's Agg canvas; no display needed).

- :func:`plot_bo_vs_boca`: reward of each evaluation against wall time (or against the
  simulated time evaluated), BO and BOCA, one panel per benchmark (the paper's convergence
  figure);
- :func:`plot_directions`: R_init and R* per walking direction, polar (the paper's 8Dir);
- :func:`plot_perturbation`: R of the direction-0 B_c off its direction, as a fraction of
  its unperturbed R (the paper's DirPerturb);
- :func:`plot_study`: a study's line with its spread (cost or reward against C).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..store import _atomic_savefig

__all__ = ["plot_bo_vs_boca", "plot_directions", "plot_perturbation", "plot_study"]


def _figure(*args, **kwargs):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(*args, layout="constrained", **kwargs)
    FigureCanvasAgg(fig)
    return fig


def simulated_minutes(evaluations: list) -> np.ndarray:
    """Cumulative simulated time evaluated, sum of T over evaluations and their seeds, in
    minutes, in the order the evaluations finished. One version of the code spends wall time
    in proportion to it whichever method asks, so it compares runs made with different code
    or on different machines, where wall time does not."""
    return np.cumsum([e.T * max(len(e.seeds), 1) for e in evaluations]) / 60.0


def plot_bo_vs_boca(panels: dict[str, dict[str, list]], path: Path,
                    axis: str = "wall") -> Path:  # fmt: skip
    """``panels``: benchmark -> {"bo"|"boca": [Evaluation, ...]} (finished evaluations);
    ``axis``: ``"wall"`` (the run's elapsed wall time) or ``"simulated"``
    (:func:`simulated_minutes`)."""
    if axis not in ("wall", "simulated"):
        raise ValueError(f"axis must be 'wall' or 'simulated', got {axis!r}")
    n = max(len(panels), 1)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = _figure(figsize=(4.2 * cols, 3.4 * rows))
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, (bench, runs) in zip(axes, panels.items(), strict=False):
        for color, (name, evaluations) in zip(("C0", "C1"), sorted(runs.items()), strict=False):
            ok = [e for e in evaluations if e.status == "ok"]
            if not ok:
                continue
            if axis == "wall":
                minutes = np.array([e.elapsed_s for e in ok]) / 60.0
            else:  # a failed evaluation spent its simulated time too
                spent = simulated_minutes(evaluations)
                minutes = spent[[e.status == "ok" for e in evaluations]]
            r = np.array([e.R for e in ok])
            t_max = max(e.T for e in ok)
            full = np.array([math.isclose(e.T, t_max) for e in ok])
            ax.scatter(minutes[full], r[full], s=12, color=color, label=f"{name.upper()} T max")
            if (~full).any():
                ax.scatter(minutes[~full], r[~full], s=12, color=color, marker="x",
                           label=f"{name.upper()} shorter T")  # fmt: skip
            best = np.maximum.accumulate(np.where(full, r, -np.inf))
            keep = np.isfinite(best)
            ax.step(minutes[keep], best[keep], where="post", color=color, lw=1.2)
        ax.set_title(bench, fontsize=10)
        ax.set_xlabel("wall time (min)" if axis == "wall" else "simulated time evaluated (min)")
        ax.set_ylabel("R (m/s from settle time)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle(
        "BO vs BOCA: reward of each evaluation against "
        + ("wall time" if axis == "wall" else "simulated time evaluated")
    )
    return _atomic_savefig(fig, path, dpi=110)


def plot_directions(rows: list[dict], path: Path) -> Path:
    """``rows``: direction_deg, R_init, R_star per direction (nan where not measured)."""
    fig = _figure(figsize=(5.2, 5.2))
    ax = fig.add_subplot(projection="polar")
    theta = np.radians([r["direction_deg"] for r in rows] + [rows[0]["direction_deg"]])
    for key, color, label in (("R_init", "0.4", "R_init (identity)"),
                              ("R_star", "C3", "R* (RBBO)")):  # fmt: skip
        values = np.array([r[key] for r in rows] + [rows[0][key]], dtype=float)
        ax.plot(theta, values, "o-", color=color, label=label)
    ax.set_title("cross walking along each direction: R (m/s)", fontsize=10)
    ax.legend(loc="lower right", fontsize=8, bbox_to_anchor=(1.1, -0.1))
    return _atomic_savefig(fig, path, dpi=110)


def plot_perturbation(rows: list[dict], path: Path) -> Path:
    """``rows``: offset_deg and fraction (R at the offset / R at 0) per offset."""
    rows = sorted(rows, key=lambda r: r["offset_deg"])
    fig = _figure(figsize=(5.5, 3.8))
    ax = fig.subplots()
    ax.plot([r["offset_deg"] for r in rows], [r["fraction"] for r in rows], "o-", color="C3")
    ax.axhline(0.8, color="0.6", ls="--", lw=1, label="the paper: 80 % within ±10°")
    ax.axhline(1.0, color="0.8", lw=0.8)
    ax.set_xlabel("direction offset (degrees)")
    ax.set_ylabel("R / R(offset 0)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _atomic_savefig(fig, path, dpi=110)


def plot_study(x, y, spread, xlabel: str, ylabel: str, title: str, path: Path) -> Path:
    fig = _figure(figsize=(5.5, 3.8))
    ax = fig.subplots()
    ax.errorbar(x, y, yerr=spread, fmt="o-", capsize=3)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    return _atomic_savefig(fig, path, dpi=110)
