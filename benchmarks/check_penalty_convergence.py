"""Does the penalty ground's Newton iteration converge on every step, and in how many
iterations? (The table of benchmarks/PROFILE.md, session 50.)

Each walker (M = 20, B_c the first three modes, the penalty ground, the model's defaults
otherwise) takes ``--steps`` steps from rest in each frame under one of two actuations:
``gait``, a 2 Hz travelling wave of 0.8 body weights of modal force in the three control
directions (phases 0, 120, 240 degrees), or ``random``, uniform modal forces of up to 0.5
body weights drawn anew each step (seed 0). Printed per robot and frame: the steps that ended
at the Newton cap unconverged (``info["converged"]`` False), the mean Newton iterations per
step, the mean x of the nodes at the end and the deepest sink (how far the walk went and how
far the ground let the body in).

    python benchmarks/check_penalty_convergence.py [--actuation gait|random] [--steps 300]
        [--solver fast|reference] [--frames linear floating] [--robots beam cross ...]
"""

from __future__ import annotations

import argparse

import numpy as np

from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model

G = 9.81
WALKERS = ("beam", "cross", "quadruped", "tripod")


def forces(kind: str, steps: int, dt: float, total_mass: float) -> np.ndarray:
    """Modal forces (steps, 3) of the gait or the random actuation."""
    weight = np.sqrt(total_mass) * G
    if kind == "random":
        return 0.5 * weight * np.random.default_rng(0).uniform(-1.0, 1.0, (steps, 3))
    t = np.arange(steps) * dt
    phase = 2.0 * np.pi * np.arange(3) / 3.0
    return 0.8 * weight * np.sin(2.0 * np.pi * 2.0 * t[:, None] - phase[None, :])


def run(robot: str, frame: str, solver: str, kind: str, steps: int) -> dict:
    model = build_reduced_model(ROBOTS[robot](), contact="penalty", frame=frame, solver=solver,
                                control_basis=np.eye(20)[:, :3])  # fmt: skip
    state, capped, iterations = model.rest_state(), 0, []
    for u in forces(kind, steps, model.dt, model.total_mass):
        state, info = model.step(state, u)
        if info["diverged"]:
            raise RuntimeError(f"{robot} ({frame}) diverged")
        capped += not info["converged"]
        iterations.append(info["newton_iterations"])
    x = model.positions(state.q)
    sink = model.ground_height - x[model.surface_nodes, 2].min()
    return {"robot": robot, "frame": frame, "capped": capped, "steps": steps,
            "iterations": float(np.mean(iterations)), "mean_x": float(x[:, 0].mean()),
            "sink": float(sink)}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--actuation", choices=["gait", "random"], default="gait")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--solver", choices=["fast", "reference"], default="fast")
    p.add_argument("--frames", nargs="+", choices=["linear", "floating"],
                   default=["linear", "floating"])  # fmt: skip
    p.add_argument("--robots", nargs="+", choices=WALKERS, default=list(WALKERS))
    args = p.parse_args(argv)
    if args.steps < 1:
        p.error(f"--steps must be at least 1, got {args.steps}")
    print(f"{'frame':<9} {'robot':<10} {'capped':>9} {'iterations':>10} {'mean x (m)':>11} "
          f"{'sink (mm)':>9}")  # fmt: skip
    for frame in args.frames:
        for robot in args.robots:
            r = run(robot, frame, args.solver, args.actuation, args.steps)
            print(f"{frame:<9} {robot:<10} {r['capped']:>4}/{r['steps']:<4} "
                  f"{r['iterations']:>10.2f} {r['mean_x']:>+11.5f} {1e3 * r['sink']:>9.2f}",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
