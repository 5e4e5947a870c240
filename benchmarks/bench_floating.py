"""The floating frame's step against the linear frame's, side by side in one run.

For each benchmark robot (M = 20, cubature, one thread, one C++ rollout so that no Python
overhead is counted) it times free flight under gravity with the same random actuation of
0.5 body weight in the first three modes from rest, in the default linear frame (fast
solver) and in the floating frame (``frame="floating"``: exact Newton on 3 + M unknowns with
an LU factor), in alternating rounds, best of each, and prints both rates, their ratio
(``floating_over_linear``) and the mean Newton iterations per step. Free flight is the only
setting the floating frame simulates today, so this is not the walkers' or the swimmer's task
physics: it says what the exact rotation costs per step, not what an env step will.

    python benchmarks/bench_floating.py [--robots beam cross] [--steps 400] [--rounds 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model, build_subspace

G = 9.81


def measure(robot_name: str, steps: int, rounds: int, seed: int = 0) -> dict:
    robot = ROBOTS[robot_name]()
    sub = build_subspace(robot, 20)
    models = {
        frame: build_reduced_model(
            robot, subspace=sub, contact="none", control_basis=np.eye(20)[:, :3], frame=frame
        )
        for frame in ("linear", "floating")
    }
    mass = models["linear"].total_mass
    rng = np.random.default_rng(seed)
    controls = 0.5 * np.sqrt(mass) * G * rng.uniform(-1.0, 1.0, size=(1, steps, 3))
    best = {frame: np.inf for frame in models}
    iterations = {}
    for _ in range(rounds):
        for frame, model in models.items():
            start = time.perf_counter()
            out = model.rollout(model.rest_state(), controls, threads=1)
            best[frame] = min(best[frame], time.perf_counter() - start)
            if out["diverged"].any() or not out["converged"].all():
                raise RuntimeError(f"{robot_name}, {frame} frame: a step did not converge")
    for frame, model in models.items():  # (one Python pass for the counts, not timed)
        state, counts = model.rest_state(), []
        for k in range(min(steps, 100)):
            state, info = model.step(state, controls[0, k])
            counts.append(info["newton_iterations"])
        iterations[frame] = float(np.mean(counts))
    linear, floating = steps / best["linear"], steps / best["floating"]
    return {
        "robot": robot_name,
        "linear_steps_per_s": linear,
        "floating_steps_per_s": floating,
        "floating_over_linear": floating / linear,
        "linear_newton_iterations": iterations["linear"],
        "floating_newton_iterations": iterations["floating"],
    }


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", nargs="+", choices=sorted(ROBOTS), default=sorted(ROBOTS))
    p.add_argument("--steps", type=int, default=400, help="steps per timed rollout")
    p.add_argument("--rounds", type=int, default=3, help="alternating timed rounds, best kept")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = p.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        p.error(f"--steps and --rounds must be >= 1, got {args.steps} and {args.rounds}")
    rows = []
    if not args.json:
        print(f"{'robot':<10} {'linear steps/s':>15} {'floating steps/s':>17} {'ratio':>7} "
              f"{'Newton it. lin / float':>23}")  # fmt: skip
    for name in args.robots:
        row = measure(name, args.steps, args.rounds)
        rows.append(row)
        if not args.json:
            print(f"{name:<10} {row['linear_steps_per_s']:>15,.0f} "
                  f"{row['floating_steps_per_s']:>17,.0f} {row['floating_over_linear']:>7.2f} "
                  f"{row['linear_newton_iterations']:>11.2f} / "
                  f"{row['floating_newton_iterations']:<9.2f}", flush=True)  # fmt: skip
    if args.json:
        json.dump(rows, sys.stdout, indent=2)
        print()
    return rows


if __name__ == "__main__":
    main()
