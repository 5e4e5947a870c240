"""Shared by the benchmark scripts: write a results table as CSV and a line plot as PNG.

Tables and figures are replaced whole or not at all (:func:`write_csv`, :func:`save_figure`):
a run interrupted while it writes leaves the last run's file, not a truncated one in its
place.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any


def write_csv(rows: list[dict], path: Path) -> None:
    """Write ``rows`` (dicts with the first row's keys) to ``path`` as CSV, replacing the file
    whole (as :func:`save_figure` does figures): an interrupted write leaves the last run's
    table, not a truncated one."""
    from rbbo.store import _atomic_write

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    _atomic_write(path, buffer.getvalue().encode())


def save_figure(fig: Any, path: Path, dpi: int) -> Path:
    """Write matplotlib figure ``fig`` to ``path`` (its format from the suffix) atomically.

    Drawn into memory, written to a temporary file in ``path``'s folder and renamed over
    ``path`` (``os.replace``), by the helper that writes rbbo's own figures, so a Ctrl-C or a
    kill mid-draw leaves the old file. Makes the folder if need be. Returns ``path``.
    """
    from rbbo.store import _atomic_savefig

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _atomic_savefig(fig, path, dpi=dpi)


def plot_lines(series: dict[str, tuple[list, list, list | None]], xlabel: str, ylabel: str,
               path: Path, logy: bool = False) -> None:  # fmt: skip
    """``series``: label -> (x, y, spread or None), drawn as lines with error bars."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"matplotlib is not installed (pip install matplotlib): no {path.name}")
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, (x, y, spread) in series.items():
        ax.errorbar(x, y, yerr=spread, fmt="o-", capsize=3, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if logy:
        ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=120)
    finally:
        plt.close(fig)
