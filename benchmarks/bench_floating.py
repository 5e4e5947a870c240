"""The floating frame's step against the linear frame's, side by side in one run.

For each of the five benchmarks (M = 20, cubature, one thread, one C++ rollout so that no
Python overhead is counted), with the task's physics (staggered-projection ground contact and
gravity for the walkers, from rest on the ground; water without gravity for the swimmer) and
the same random actuation of 0.5 body weight in the first three modes, drawn anew every step,
it times the default linear frame (fast solver) and the floating frame (``frame="floating"``,
fast solver: Newton on M + 6 unknowns with an LU factor and the stiffness frozen at K_0, the
contact rows at the body's exact rotation), in alternating rounds, best of each. It prints
both rates, their ratio (``floating_over_linear``), the mean Newton iterations per step, and
how far each frame's centre of mass moved and the body turned over the rollout (the two
frames are different models, so these differ; the rollout is short and random, so they say
little of gaits).

``--contact penalty`` puts the walkers on the penalty ground in both frames instead.

    python benchmarks/bench_floating.py [--benchmarks CrossSwim-v0 ...] [--steps 400]
        [--rounds 3] [--contact staggered|penalty] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from softrom_gym import BENCHMARKS
from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model, build_subspace

G = 9.81


def measure(
    benchmark: str, steps: int, rounds: int, seed: int = 0, contact: str = "staggered"
) -> dict:
    """One row: ``benchmark``'s robot with its task's physics in both frames (a walker on
    ``contact``'s ground)."""
    spec = BENCHMARKS[benchmark]
    robot = ROBOTS[spec["robot"]]()
    sub = build_subspace(robot, 20)
    physics: dict = {"contact": contact}
    if spec["task"] == "swim":
        physics.update(contact="none", gravity=[0.0, 0.0, 0.0], fluid_density=1000.0)
    models = {
        frame: build_reduced_model(
            robot, subspace=sub, control_basis=np.eye(20)[:, :3], frame=frame, **physics
        )
        for frame in ("linear", "floating")
    }
    mass = models["linear"].total_mass
    rng = np.random.default_rng(seed)
    controls = 0.5 * np.sqrt(mass) * G * rng.uniform(-1.0, 1.0, size=(1, steps, 3))
    best = dict.fromkeys(models, np.inf)
    outs = {}
    for _ in range(rounds):
        for frame, model in models.items():
            start = time.perf_counter()
            outs[frame] = model.rollout(model.rest_state(), controls, threads=1)
            best[frame] = min(best[frame], time.perf_counter() - start)
            if outs[frame]["diverged"].any():
                raise RuntimeError(f"{benchmark}, {frame} frame: the rollout diverged")
    row: dict = {"benchmark": benchmark}
    for frame, model in models.items():  # (one Python pass for the counts, not timed)
        state, counts = model.rest_state(), []
        for k in range(min(steps, 100)):
            state, info = model.step(state, controls[0, k])
            counts.append(info["newton_iterations"])
        final = outs[frame]
        row[f"{frame}_steps_per_s"] = steps / best[frame]
        row[f"{frame}_newton_iterations"] = float(np.mean(counts))
        row[f"{frame}_converged"] = bool(final["converged"].all())
        start = model.com(model.rest_state().q)
        row[f"{frame}_moved_m"] = float(np.linalg.norm(final["com"][0, -1] - start))
    q = outs["floating"]["q"][0]
    row["floating_turned_rad"] = float(np.linalg.norm(q[3:6]))
    row["floating_over_linear"] = row["floating_steps_per_s"] / row["linear_steps_per_s"]
    return row


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--benchmarks", nargs="+", choices=list(BENCHMARKS), default=list(BENCHMARKS))
    p.add_argument("--steps", type=int, default=400, help="steps per timed rollout")
    p.add_argument("--rounds", type=int, default=3, help="alternating timed rounds, best kept")
    p.add_argument("--contact", choices=["staggered", "penalty"], default="staggered",
                   help="the walkers' ground (the swimmer has none)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object per row")
    args = p.parse_args(argv)
    if args.steps < 2 or args.rounds < 1:
        p.error(f"--steps must be >= 2 and --rounds >= 1, got {args.steps} and {args.rounds}")
    rows = []
    if not args.json:
        print(f"{'benchmark':<17} {'linear steps/s':>14} {'floating steps/s':>16} {'ratio':>6} "
              f"{'Newton it. lin / float':>22} {'moved lin / float (m)':>22} "
              f"{'turned (rad)':>12}")  # fmt: skip
    for name in args.benchmarks:
        row = measure(name, args.steps, args.rounds, contact=args.contact)
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(f"{name:<17} {row['linear_steps_per_s']:>14,.0f} "
                  f"{row['floating_steps_per_s']:>16,.0f} {row['floating_over_linear']:>6.2f} "
                  f"{row['linear_newton_iterations']:>10.2f} / "
                  f"{row['floating_newton_iterations']:<9.2f} "
                  f"{row['linear_moved_m']:>10.4f} / {row['floating_moved_m']:<9.4f} "
                  f"{row['floating_turned_rad']:>12.3f}", flush=True)  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
