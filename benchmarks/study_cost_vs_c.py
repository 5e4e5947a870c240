"""Study (a), the paper's cost figure: wall time of one Gauss-Newton iteration against C.

On CrossWalk-v0 with identity control bases B_c = the first C modes (C = 1..20 by default),
one GN iteration (the K C + 1 finite-difference rollouts and the batched line search) from
the reset state, best of ``--repeats``, on ``--threads`` threads, with the benchmark's
default horizon and knots unless overridden. The K C + 1 rollouts grow linearly in C and the
normal equations cubically, so the cost should grow at least linearly; the paper reports
superlinear growth. The Cs run in ascending order, and each row's ``x C_min`` (CSV
``relative_cost``, with ``relative_to_C`` naming the reference) is its iteration's wall time
over that of the smallest C, measured in the same run: the figure to compare between
machines and runs, where the seconds move with the machine and its load.
Writes ``cost_vs_c.csv`` and ``cost_vs_c.png`` into ``--out``.

    python benchmarks/study_cost_vs_c.py [--cs 1 2 ... 20] [--horizon H] [--knots K]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from controllers import default_planner
from controllers.studies import gn_cost_against_c

sys.path.insert(0, str(Path(__file__).parent))
from _results import plot_lines, write_csv


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env-id", default="softrom_gym/CrossWalk-v0")
    p.add_argument("--cs", type=int, nargs="+", default=list(range(1, 21)))
    p.add_argument("--horizon", type=int, help="env steps (default: the benchmark's)")
    p.add_argument("--knots", type=int, help="knots per dimension (default: the benchmark's)")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/study_cost_vs_c"))
    args = p.parse_args(argv)
    changes = {}
    if args.horizon is not None:
        changes.update(horizon=args.horizon, window=None)
    if args.knots is not None:
        changes["knots"] = args.knots
    if min(args.cs) < 1 or args.repeats < 1:
        p.error(f"need --cs and --repeats >= 1, got {args.cs}, {args.repeats}")
    try:  # an unknown id, C above M, a bad thread count or setting: named before any row
        gym.make(args.env_id, control_dim=max(args.cs)).close()
        default_planner(args.env_id, "gn", threads=args.threads, **changes)
    except (ValueError, TypeError, gym.error.Error) as exc:
        p.error(str(exc))
    # ascending, so the reference of the ratio (the smallest C) is measured first and every
    # row can print its ratio as it comes
    cs = sorted(args.cs)
    print(f"{'C':>3} {'rollouts':>9} {'GN iteration s':>15} {'per rollout ms':>15} "
          f"{f'x C={cs[0]}':>8}")  # fmt: skip
    reference: dict[str, float] = {}

    def show(row: dict) -> None:
        base = reference.setdefault("iteration_s", row["iteration_s"])
        # (the row is the one gn_cost_against_c returns: the CSV gets the ratio too)
        row.update(relative_cost=row["iteration_s"] / base, relative_to_C=cs[0])
        print(f"{row['C']:>3} {row['rollouts']:>9} {row['iteration_s']:>15.3f} "
              f"{1e3 * row['iteration_s'] / row['rollouts']:>15.2f} "
              f"{row['relative_cost']:>8.2f}", flush=True)  # fmt: skip

    rows = gn_cost_against_c(args.env_id, cs, repeats=args.repeats, threads=args.threads,
                             planner_changes=changes, on_row=show)  # fmt: skip
    write_csv(rows, args.out / "cost_vs_c.csv")
    walls = [r["iteration_s"] for r in rows]
    plot_lines({"one GN iteration": (cs, walls, None)}, "control-space dimension C",
               "wall time (s)", args.out / "cost_vs_c.png")  # fmt: skip
    if len(rows) >= 2:
        slope = np.polyfit(np.log(cs), np.log([r["iteration_s"] for r in rows]), 1)[0]
        print(f"log-log slope {slope:.2f} (1 = linear in C); CSV and PNG in {args.out}")
    return rows


if __name__ == "__main__":
    main()
