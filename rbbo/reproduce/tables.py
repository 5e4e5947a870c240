"""Table I from run directories: means over fresh seeds with 95 % t-intervals; CSV and
Markdown out, and the Markdown parsed back (so a test can check the report against the runs).

R_init and R* are the means of the confirmation evaluations (the identity basis and the
recommendation, each on the run's fresh seeds at T_max, see :mod:`rbbo.optimizer`); the
interval is mean ± t_{0.975, n-1} s / sqrt(n) over those n seeds. Both are measured on the
same seeds (common random numbers), so the paired difference R* - R_init per seed has its own,
tighter interval ("paired"): the unpaired "apart" test below is the conservative one. "apart"
is true when R*'s interval lies wholly above R_init's.

With several Table I runs per benchmark (``--repeats``), :func:`run_row` gives each run's
numbers and :func:`across_runs` the improvement over the runs: mean, sample standard
deviation (n - 1) and range, over the runs confirmed so far; Table I's rows stay run 0's.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..intervals import confidence_interval
from ..report import _duration
from .csv_rows import read_rows as read_rows
from .csv_rows import write_csv as write_csv
from .plan import PAPER_TABLE1

__all__ = ["across_runs", "basis_digest", "confidence_interval", "format_markdown",
           "format_runs_markdown", "parse_markdown", "read_rows", "run_row", "table_row",
           "write_csv"]  # fmt: skip

COLUMNS = ["robot", "task", "N", "M", "C", "R_init", "R*", "improvement", "R* - R_init (paired)",
           "evaluations", "wall time", "apart", "paper"]  # fmt: skip


def compare_seeds(init: list[float], star: list[float]) -> dict[str, Any]:
    """R_init and R* from their per-seed values: means and 95 % half-widths, the improvement
    (from the means), the paired gain R* - R_init (same seeds) and whether each is apart."""
    r_init, h_init = confidence_interval(init)
    r_star, h_star = confidence_interval(star)
    done = bool(len(init)) and bool(len(star))
    paired = done and len(star) == len(init)
    delta, h_delta = confidence_interval(np.subtract(star, init) if paired else [])
    return {
        "R_init": r_init,
        "R_init_ci95": h_init,
        "R_star": r_star,
        "R_star_ci95": h_star,
        "improvement_pct": 100.0 * (r_star / r_init - 1.0) if done and r_init > 0 else math.nan,
        "apart": bool(
            done and math.isfinite(h_init + h_star) and r_star - h_star > r_init + h_init
        ),
        "delta": delta,
        "delta_ci95": h_delta,
        "paired_apart": bool(math.isfinite(h_delta) and delta - h_delta > 0),
    }


def table_row(benchmark: str, run_dir: Path) -> dict[str, Any]:
    """Table I's numbers for one benchmark from its (BOCA) run directory."""
    from ..report import load

    opt = load(run_dir)
    assert opt.store is not None  # (load resumes the run from its directory)
    result = opt.result()
    problem = opt.store.config.get("problem") or {}
    paper = PAPER_TABLE1[benchmark]
    stats = compare_seeds(result.R_init_seeds, result.R_star_seeds)
    return {
        "benchmark": benchmark,
        "robot": paper["robot"],
        "task": paper["task"],
        "N": problem.get("N"),
        "M": opt.config.sim_dim,
        "C": opt.config.control_dim,
        **{k: stats[k] for k in ("R_init", "R_init_ci95", "R_star", "R_star_ci95")},
        "seeds": len(result.R_init_seeds),
        "improvement_pct": stats["improvement_pct"],
        "apart": stats["apart"],
        "delta": stats["delta"],
        "delta_ci95": stats["delta_ci95"],
        "paired_apart": stats["paired_apart"],
        "evaluations": result.evaluations,
        "failed": result.failed,
        "wall_s": result.wall_s,
        "fidelity": opt.config.fidelity,
        "paper_improvement_pct": paper["improvement_pct"],
        "run": str(run_dir),
    }


def run_row(benchmark: str, repeat: int, run_dir: Path) -> dict[str, Any]:
    """One row of table1_runs.csv: :func:`table_row` of run ``repeat`` of ``benchmark``, with
    the run's index and the seed it was made with (read from the run)."""
    config = json.loads((run_dir / "config.json").read_text())
    row = table_row(benchmark, run_dir)
    return {"benchmark": benchmark, "repeat": repeat, "seed": config["rbbo"]["seed"],
            **{k: v for k, v in row.items() if k != "benchmark"}}  # fmt: skip


def across_runs(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The improvement of one benchmark over its runs (rows of :func:`run_row`): how many are
    confirmed, and over those the mean, the sample standard deviation (nan below two runs),
    the least and the most; R* likewise (mean and sample standard deviation)."""
    done = [r for r in rows if math.isfinite(r["improvement_pct"])]
    gains = [r["improvement_pct"] for r in done]
    stars = [r["R_star"] for r in done]
    nan = math.nan
    return {
        "runs": len(done),
        "improvement_mean_pct": float(np.mean(gains)) if gains else nan,
        "improvement_sd_pct": float(np.std(gains, ddof=1)) if len(gains) > 1 else nan,
        "improvement_min_pct": min(gains, default=nan),
        "improvement_max_pct": max(gains, default=nan),
        "R_star_mean": float(np.mean(stars)) if stars else nan,
        "R_star_sd": float(np.std(stars, ddof=1)) if len(stars) > 1 else nan,
    }


def basis_digest(basis: np.ndarray) -> str:
    """Eight hex digits naming a control basis by its bytes. A measurement of a run's best B_c
    records it, so a longer run that recommends another B_c is measured afresh instead of
    being reported with the older one's numbers."""
    data = np.ascontiguousarray(basis, dtype=np.float64).tobytes()
    return hashlib.blake2b(data, digest_size=4).hexdigest()


def _num(value: float, spec: str = ".4g") -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:{spec}}"


def _interval(mean: float, half: float) -> str:
    if not math.isfinite(mean):
        return "-"
    return _num(mean) + ("" if not math.isfinite(half) else f" ± {half:.2g}")


def format_markdown(rows: list[dict[str, Any]]) -> str:
    """Table I as a Markdown table, with an average-improvement row (ours and the paper's)."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        cells = [r["robot"], r["task"], _num(r["N"], "d") if r["N"] else "-", str(r["M"]),
                 str(r["C"]), _interval(r["R_init"], r["R_init_ci95"]),
                 _interval(r["R_star"], r["R_star_ci95"]),
                 _num(r["improvement_pct"], "+.1f") + ("" if not math.isfinite(
                     r["improvement_pct"]) else " %"),
                 _interval(r["delta"], r["delta_ci95"]),
                 str(r["evaluations"]), _duration(r["wall_s"]),
                 "-" if not math.isfinite(r["R_star"]) else "yes" if r["apart"] else "no",
                 f"+{r['paper_improvement_pct']:.1f} %"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    # both averages over the same benchmarks: those whose R_init and R* are measured
    done = [r for r in rows if math.isfinite(r["improvement_pct"])]
    ours = [r["improvement_pct"] for r in done]
    paper = [r["paper_improvement_pct"] for r in done] or [r["paper_improvement_pct"]
                                                           for r in rows]  # fmt: skip
    average = f"{np.mean(ours):+.1f} %" if ours else "-"
    lines.append("| average | | | | | | | " + average + " | | | | | "
                 f"+{np.mean(paper):.1f} % |")  # fmt: skip
    return "\n".join(lines)


RUN_COLUMNS = ["benchmark", "runs", "improvement per run (seed)", "improvement mean ± sd",
               "improvement min..max", "R* mean ± sd"]  # fmt: skip


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:+.1f} %"


def format_runs_markdown(rows: list[dict[str, Any]], repeats: int) -> str:
    """The improvement over each benchmark's ``repeats`` Table I runs (rows of
    :func:`run_row`) as a Markdown table: each run's, then the mean ± sample standard
    deviation and the range over those confirmed ("runs": confirmed, of how many planned)."""
    lines = ["| " + " | ".join(RUN_COLUMNS) + " |", "|" + "---|" * len(RUN_COLUMNS)]
    for bench in dict.fromkeys(r["benchmark"] for r in rows):
        mine = sorted((r for r in rows if r["benchmark"] == bench), key=lambda r: r["repeat"])
        stats = across_runs(mine)
        runs = str(stats["runs"]) + ("" if stats["runs"] == repeats else f" of {repeats}")
        per_run = ", ".join(f"{_pct(r['improvement_pct'])} ({r['seed']})" for r in mine)
        mean, sd = stats["improvement_mean_pct"], stats["improvement_sd_pct"]
        spread = _num(mean, "+.1f") + ("" if not math.isfinite(sd) else f" ± {sd:.1f}")
        low, high = stats["improvement_min_pct"], stats["improvement_max_pct"]
        span = "-" if not math.isfinite(low) else f"{low:+.1f} .. {high:+.1f} %"
        cells = [bench, runs, per_run, spread + ("" if not math.isfinite(mean) else " %"), span,
                 _interval(stats["R_star_mean"], stats["R_star_sd"])]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


_NUMBER = r"[-+]?[0-9][0-9.]*(?:[eE][-+]?[0-9]+)?"  # a digit first: "-" is no number
_CELL = re.compile(rf"^\s*({_NUMBER})(?:\s*±\s*({_NUMBER}))?\s*%?\s*$")


def parse_markdown(text: str) -> list[dict[str, Any]]:
    """The rows of a Table I written by :func:`format_markdown` (found anywhere in ``text``).

    Returns robot, task, N, M, C, R_init (and R_init_ci95), R_star (and R_star_ci95),
    improvement_pct, evaluations and apart per benchmark row; the average row is skipped.
    """
    header = "| " + " | ".join(COLUMNS) + " |"
    lines = text.splitlines()
    try:
        start = lines.index(header)
    except ValueError:
        raise ValueError("no Table I (its header row) in the text") from None
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0] == "average":
            continue
        row: dict[str, Any] = {"robot": cells[0], "task": cells[1]}
        row["N"] = None if cells[2] == "-" else int(cells[2])
        row["M"], row["C"] = int(cells[3]), int(cells[4])
        for key, cell in (("R_init", cells[5]), ("R_star", cells[6]),
                          ("improvement_pct", cells[7])):  # fmt: skip
            match = _CELL.match(cell)
            row[key] = float(match.group(1)) if match else math.nan
            if key != "improvement_pct":
                half = match.group(2) if match else None
                row[f"{key}_ci95"] = float(half) if half else math.nan
        match = _CELL.match(cells[8])
        row["delta"] = float(match.group(1)) if match else math.nan
        row["delta_ci95"] = float(match.group(2)) if match and match.group(2) else math.nan
        row["evaluations"] = int(cells[9])
        row["apart"] = cells[11] == "yes"
        rows.append(row)
    return rows
