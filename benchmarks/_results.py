"""Shared by the benchmark scripts: write a results table as CSV and a line plot as PNG."""

from __future__ import annotations

import csv
from pathlib import Path


def write_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


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
    fig.savefig(path, dpi=120)
    plt.close(fig)
