"""Full-space FEM speed: implicit Euler steps per second for each benchmark robot and solver.

Each robot starts squashed to 80% of its height and is released under gravity
(dt = 1/200 s), so every step does real Newton work on a deforming body rather than a rigid
free fall. This is the baseline the reduced model is measured against (bench_rom.py).

Every solver of ``FEMModel.solver`` runs the same trajectory side by side in one run,
interleaved in rounds so that load from elsewhere on the machine falls on all of them alike:
``reference`` is the step as first written (the "before"), ``supernodal_llt`` the default
(the "after"); ``simplicial_llt`` and ``simplicial_ldlt`` are the fast step with Eigen's
simplicial factorisations instead. Columns: Newton iterations and numeric factorisations per
step, steps/s, speed over the reference, and the largest difference of the final positions
from the reference run's (m), which shows they compute the same solution. ``--profile`` adds
the wall milliseconds per step (ms) spent in each phase (assembly with the per-element PSD
projection, gradient, factorisation, triangular solves, line-search energy evaluations).

    python benchmarks/bench_fem.py [--steps 40] [--profile] [--json] [--robots quadruped ...]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from softrom_gym.robots import ROBOTS

DT = 1.0 / 200.0
SOLVERS = ("reference", "supernodal_llt", "simplicial_llt", "simplicial_ldlt")
PHASES = ("assemble", "gradient", "factorize", "solve", "line_search")
PHASE_LABELS = ("assemble", "gradient", "factorize", "solve", "linesearch")
ROUNDS = 4


def measure(name: str, steps: int, solvers: list[str]) -> list[dict]:
    robot = ROBOTS[name]()
    x0 = robot.nodes * np.array([1.0, 1.0, 0.8])
    runs = {}
    for solver in solvers:
        fem = robot.fem_model()
        fem.solver = solver
        x, v = fem.step(x0, np.zeros_like(x0), DT)  # warm-up: symbolic analysis happens once
        runs[solver] = {"fem": fem, "x": x, "v": v, "seconds": 0.0, "steps": 0}
        runs[solver].update({"iterations": 0, "factorizations": 0})
        runs[solver].update({phase: 0.0 for phase in PHASES})
    chunks = np.diff(np.linspace(0, steps, min(ROUNDS, steps) + 1).round().astype(int))
    for chunk in chunks:
        for solver in solvers:
            run = runs[solver]
            fem, x, v = run["fem"], run["x"], run["v"]
            for _ in range(chunk):
                start = time.perf_counter()
                x, v = fem.step(x, v, DT)
                run["seconds"] += time.perf_counter() - start
                stats = fem.last_step_stats
                run["iterations"] += stats["iterations"]
                run["factorizations"] += stats["factorizations"]
                for phase in PHASES:
                    run[phase] += stats[f"{phase}_s"]
            run["x"], run["v"], run["steps"] = x, v, run["steps"] + chunk
    reference = runs.get("reference")
    rows = []
    for solver in solvers:
        run = runs[solver]
        row = {
            "robot": name,
            "nodes": robot.num_nodes,
            "tets": robot.num_tets,
            "dt": DT,
            "steps": steps,
            "solver": solver,
            "newton_iterations_per_step": run["iterations"] / steps,
            "factorizations_per_step": run["factorizations"] / steps,
            "full_steps_per_s": steps / run["seconds"],
            "speedup_over_reference": (
                reference["seconds"] / run["seconds"] if reference is not None else None
            ),
            "max_position_difference_m": (
                float(np.abs(run["x"] - reference["x"]).max()) if reference is not None else None
            ),
        }
        row.update({f"{phase}_ms_per_step": 1e3 * run[phase] / steps for phase in PHASES})
        rows.append(row)
    return rows


def format_row(r: dict, profile: bool) -> str:
    speedup = r["speedup_over_reference"]
    diff = r["max_position_difference_m"]
    line = (
        f"{r['robot']:<10} {r['nodes']:>6} {r['tets']:>6} {r['solver']:<16} "
        f"{r['newton_iterations_per_step']:>11.2f} {r['factorizations_per_step']:>11.2f} "
        f"{r['full_steps_per_s']:>9.1f} "
        f"{'-' if speedup is None else f'{speedup:.2f}x':>12} "
        f"{'-' if diff is None else f'{diff:.1e}':>12}"
    )
    if profile:
        line += "".join(f" {r[f'{phase}_ms_per_step']:>11.2f}" for phase in PHASES)
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40, help="timed steps per robot and solver")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--profile", action="store_true", help="add ms per step in each phase")
    parser.add_argument("--robots", nargs="*", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument("--solvers", nargs="*", default=list(SOLVERS), choices=list(SOLVERS))
    args = parser.parse_args()
    if args.steps < 1:
        parser.error(f"--steps must be >= 1, got {args.steps}")
    args.solvers = list(dict.fromkeys(args.solvers))  # a solver named twice is one run
    if not args.json:
        header = (
            f"{'robot':<10} {'nodes':>6} {'tets':>6} {'solver':<16} {'newton/step':>11} "
            f"{'factor/step':>11} {'steps/s':>9} {'vs reference':>12} {'max|x-x_ref|':>12}"
        )
        if args.profile:
            header += "".join(f" {label:>11}" for label in PHASE_LABELS)
        print(header)
    for name in args.robots:
        for row in measure(name, args.steps, args.solvers):
            print(json.dumps(row) if args.json else format_row(row, args.profile), flush=True)


if __name__ == "__main__":
    main()
