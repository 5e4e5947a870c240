"""The planner a robot of your own gets (``controllers.GENERIC``), on the benchmark robots run
as if they were a user's (``softrom_gym/SoftRobot-v0``), with and without the gait seed's
choice of cycle (``seed_periods``).

Prints, per robot and seed, the distance along d from t = 2 to 10 s in body lengths under
each setting, side by side, and the mean.

    python benchmarks/check_generic_planner.py
    python benchmarks/check_generic_planner.py --robots tripod --seeds 0 1 2 --planner gn
"""

from __future__ import annotations

import argparse
import time

import numpy as np

ROBOTS = {"beam": "walk", "quadruped": "walk", "tripod": "walk", "cross": "swim"}


def _distance(robot: str, seed: int, planner: str, seed_periods: tuple[float, ...]) -> float:
    import gymnasium as gym

    import controllers
    import softrom_gym  # noqa: F401  (registers the envs)

    kwargs = {"robot": robot, "task": ROBOTS[robot]}
    if ROBOTS[robot] == "swim":
        kwargs["contact"] = "none"
    env = gym.make("softrom_gym/SoftRobot-v0", **kwargs)
    mpc, every = controllers.planner_for("softrom_gym/SoftRobot-v0", planner,
                                         seed_periods=seed_periods)  # fmt: skip
    result = controllers.run_episode(env, mpc, 10.0, replan_every=every, seed=seed,
                                     progress=False)  # fmt: skip
    bl = float(env.get_wrapper_attr("body_length"))
    env.close()
    return result.distance_between(2.0) / bl


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument(
        "--planner",
        default="mppi",
        metavar="NAME",
        help="mppi, gn, a registered planner, or an import path package.module:ClassName",
    )
    p.add_argument("--periods", type=float, nargs="*", default=[40 / 3, 10.0],
                   help="seed_periods of the second column (env steps; 3 and 4 Hz)")  # fmt: skip
    args = p.parse_args()
    periods = tuple(args.periods)
    if min(args.seeds) < 0:  # gymnasium's reset refuses it, as a traceback mid-run
        p.error(f"--seeds must be >= 0, got {args.seeds}")
    import controllers

    try:  # bad --periods: named now, not as a traceback after the first 10-s episode
        controllers.planner_for("softrom_gym/SoftRobot-v0", args.planner, seed_periods=periods)
    except ValueError as exc:
        p.error(f"--periods: {exc}")
    print(f"{args.planner}, SoftRobot-v0, distance t = 2..10 s in body lengths: the 2 Hz cycle "
          f"only | also cycles of {', '.join(f'{x:.4g}' for x in periods)} env steps")  # fmt: skip
    for robot in args.robots:
        rows = []
        for seed in args.seeds:
            t0 = time.perf_counter()
            rows.append((_distance(robot, seed, args.planner, ()),
                         _distance(robot, seed, args.planner, periods)))  # fmt: skip
            print(f"  {robot:9s} seed {seed}: {rows[-1][0]:.3f} | {rows[-1][1]:.3f} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip
        r = np.array(rows)
        print(f"{robot:9s} mean {r[:, 0].mean():.3f} | {r[:, 1].mean():.3f}", flush=True)


if __name__ == "__main__":
    main()
