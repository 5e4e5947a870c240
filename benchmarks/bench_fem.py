"""Full-space FEM speed: implicit Euler steps per second for each benchmark robot.

Each robot starts squashed to 80% of its height and is released under gravity
(dt = 1/200 s), so every step does real Newton work on a deforming body rather than a rigid
free fall. This is the baseline the reduced model is measured against (bench_rom.py).

    python benchmarks/bench_fem.py [--steps 40] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from softrom_gym.robots import ROBOTS

DT = 1.0 / 200.0


def measure(name: str, steps: int) -> dict:
    robot = ROBOTS[name]()
    fem = robot.fem_model()
    x = robot.nodes * np.array([1.0, 1.0, 0.8])
    v = np.zeros_like(x)
    x, v = fem.step(x, v, DT)  # warm-up: symbolic factorisation happens once
    iterations = 0
    start = time.perf_counter()
    for _ in range(steps):
        x, v = fem.step(x, v, DT)
        iterations += fem.last_step_stats["iterations"]
    elapsed = time.perf_counter() - start
    return {
        "robot": name,
        "nodes": robot.num_nodes,
        "tets": robot.num_tets,
        "dt": DT,
        "steps": steps,
        "newton_iterations_per_step": iterations / steps,
        "full_steps_per_s": steps / elapsed,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="timed steps per robot")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--robots", nargs="*", default=list(ROBOTS), choices=list(ROBOTS))
    args = parser.parse_args()
    if args.steps < 1:
        parser.error(f"--steps must be >= 1, got {args.steps}")
    if not args.json:
        print(f"{'robot':<10} {'nodes':>6} {'tets':>6} {'newton/step':>11} {'steps/s':>9}")
    for name in args.robots:
        r = measure(name, args.steps)
        if args.json:
            print(json.dumps(r), flush=True)
        else:
            print(
                f"{r['robot']:<10} {r['nodes']:>6} {r['tets']:>6} "
                f"{r['newton_iterations_per_step']:>11.2f} {r['full_steps_per_s']:>9.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
