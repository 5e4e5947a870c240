"""Study (b), the paper's reward-vs-C figure: task reward against C for identity bases.

On CrossWalk-v0 with B_c = the first C modes (C = 1..10 by default), one closed-loop episode
of ``--seconds`` per seed with the planner's benchmark defaults; the task reward R is the
distance along d between t = ``--start`` and the end (m), without Λ. Reports mean and
standard deviation over the seeds, writes ``reward_vs_c.csv`` (one row per episode) and
``reward_vs_c.png`` (mean and spread) into ``--out``.

    python benchmarks/study_reward_vs_c.py [--cs 1 .. 10] [--seeds 0 1 2] [--seconds 10]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from controllers import default_planner
from controllers.studies import reward_against_c

sys.path.insert(0, str(Path(__file__).parent))
from _results import plot_lines, write_csv


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env-id", default="softrom_gym/CrossWalk-v0")
    p.add_argument(
        "--planner",
        default="mppi",
        metavar="NAME",
        help="mppi, gn, a registered planner, or an import path package.module:ClassName",
    )
    p.add_argument("--cs", type=int, nargs="+", default=list(range(1, 11)))
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--start", type=float, default=2.0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("runs/study_reward_vs_c"))
    args = p.parse_args(argv)
    if min(args.seeds) < 0:  # gymnasium's reset refuses it, as a traceback mid-run
        p.error(f"--seeds must be >= 0, got {args.seeds}")
    # (a negative --start was controllers.studies' ValueError traceback)
    if min(args.cs) < 1 or not 0 < args.seconds < np.inf or args.start < 0:
        p.error(f"need --cs >= 1, --seconds > 0 and --start >= 0, got {args.cs}, "
                f"{args.seconds:g}, {args.start:g}")  # fmt: skip
    try:  # an unknown id, C above M, a bad thread count or setting: named before any row
        gym.make(args.env_id, control_dim=max(args.cs)).close()
        default_planner(args.env_id, args.planner, threads=args.threads)
    except (ValueError, TypeError, gym.error.Error) as exc:
        p.error(str(exc))
    # (reward_against_c raises the registered time limit to --seconds where it is shorter)
    start = args.start if args.seconds > args.start else 0.0
    print(f"{'C':>3} {'R mean (m)':>11} {'std':>8}  per seed")
    per_seed: list[float] = []

    def show(row: dict) -> None:
        per_seed.append(row["R_m"])
        if len(per_seed) == len(args.seeds):
            print(f"{row['C']:>3} {np.mean(per_seed):>11.4f} {np.std(per_seed):>8.4f}  "
                  + " ".join(f"{r:+.4f}" for r in per_seed), flush=True)  # fmt: skip
            per_seed.clear()

    rows = reward_against_c(args.env_id, args.cs, args.seeds, planner=args.planner,
                            seconds=args.seconds, start=start, threads=args.threads,
                            on_row=show)  # fmt: skip
    write_csv(rows, args.out / "reward_vs_c.csv")
    cs = list(dict.fromkeys(r["C"] for r in rows))
    mean = [np.mean([r["R_m"] for r in rows if r["C"] == c]) for c in cs]
    std = [np.std([r["R_m"] for r in rows if r["C"] == c]) for c in cs]
    plot_lines({f"{args.planner}, {len(args.seeds)} seeds": (cs, mean, std)},
               "control-space dimension C (identity basis)",
               f"distance t = {start:g}..{args.seconds:g} s (m)",
               args.out / "reward_vs_c.png")  # fmt: skip
    print(f"CSV and PNG in {args.out}")
    return rows


if __name__ == "__main__":
    main()
