"""How far would the recorded figures move if the floating frame were the default?

For each of the five benchmarks (M = 20, cubature, the fast solver, the task's physics), the
same ``--gaits`` open-loop travelling waves (frequencies 0.5-4 Hz, random phases, 0.5-1 body
weight: ``_actuation.modal_forces(kind="gait")``, as ``accuracy_solvers.py`` drives them) run
for ``--seconds`` in the default linear frame and in the floating frame (``frame="floating"``).
It prints the mean forward speed over the gaits in each frame, ``rms(floating - linear)`` of the
per-gait speeds, next to ``rms(perturbed - linear)``: the linear frame started 1e-4 m/s away in
one deformation velocity (the contact tolerance), the spread that frictional contact's chaos
alone gives a gait, and ``rms(perturbed - floating)``, the same for the floating frame. A frame
gap within those spreads is noise; beyond both, the frames differ.
It also prints each frame's largest turn over the gaits (the floating frame's |theta| exactly;
the linear frame's linearised orientation, what the envs report), since the frames part most
where the body turns.

    python benchmarks/compare_frames.py [--robots cross-swim ...] [--gaits 8] [--seconds 5]
        [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import cpp_sim
from softrom_gym.envs.observations import orientation_rows
from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model, build_subspace

sys.path.insert(0, str(Path(__file__).parent))
from _actuation import BENCHMARKS, modal_forces


def compare(robot_name: str, task: str, count: int, seconds: float) -> dict:
    robot = ROBOTS[robot_name]()
    sub = build_subspace(robot, 20)
    physics: dict = {}
    if task == "swim":
        physics = {"contact": "none", "gravity": [0.0, 0.0, 0.0], "fluid_density": 1000.0}
    models = {
        frame: build_reduced_model(
            robot, subspace=sub, control_basis=np.eye(20)[:, :3], frame=frame, **physics
        )
        for frame in ("linear", "floating")
    }
    linear = models["linear"]
    u = modal_forces(linear, (count, round(seconds / linear.dt), 3), seed=0, kind="gait")
    mass = robot.fem_model().mass
    observe = {
        "linear": orientation_rows(robot.nodes, mass, sub.basis),
        "floating": np.eye(3, linear.dim, 3),  # q[3:6] is the rotation vector
    }
    speeds, turns, converged = {}, {}, {}
    for frame, model in models.items():
        out = model.rollout(model.rest_state(), u, threads=2, observe=observe[frame])
        if out["diverged"].any():
            raise RuntimeError(f"{robot_name} ({task}), {frame} frame: a gait diverged")
        speeds[frame] = out["rewards"].sum(axis=1) / seconds
        turns[frame] = float(np.linalg.norm(out["observed"], axis=2).max())
        converged[frame] = float(out["converged"].mean())
    spread = {}
    for frame, model in models.items():
        start = model.rest_state()
        qdot = start.qdot
        qdot[6] += model.contact_tolerance * np.sqrt(model.total_mass)
        nudged = cpp_sim.ReducedState(start.q, qdot, start.impulses)
        perturbed = model.rollout(nudged, u, threads=2)["rewards"].sum(axis=1) / seconds
        spread[frame] = rms(perturbed - speeds[frame])
    return {
        "mean_speed_linear": float(speeds["linear"].mean()),
        "mean_speed_floating": float(speeds["floating"].mean()),
        "rms_floating_minus_linear": rms(speeds["floating"] - speeds["linear"]),
        "rms_perturbed_minus_linear": spread["linear"],
        "rms_perturbed_minus_floating": spread["floating"],
        "largest_turn_linear": turns["linear"],
        "largest_turn_floating": turns["floating"],
        "converged_linear": converged["linear"],
        "converged_floating": converged["floating"],
    }


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", nargs="*", default=list(BENCHMARKS), choices=list(BENCHMARKS))
    p.add_argument("--gaits", type=int, default=8)
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    if args.gaits < 1 or not 0.05 <= args.seconds < np.inf:
        p.error(f"need --gaits >= 1 and finite --seconds >= 0.05, got {args.gaits}, "
                f"{args.seconds}")  # fmt: skip
    if not args.json:
        print(f"{'benchmark':<15} {'speed lin':>10} {'speed float':>11} {'rms f-l':>9} "
              f"{'rms p-l':>9} {'rms p-f':>9} {'turn lin':>9} {'turn float':>10}   (m/s, rad; "
              f"{args.gaits} gaits of {args.seconds:g} s)")  # fmt: skip
    rows = []
    for name in args.robots:
        row = {"benchmark": name, **compare(*BENCHMARKS[name], args.gaits, args.seconds)}
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)
            continue
        print(f"{name:<15} {row['mean_speed_linear']:>+10.5f} {row['mean_speed_floating']:>+11.5f} "
              f"{row['rms_floating_minus_linear']:>9.5f} {row['rms_perturbed_minus_linear']:>9.5f} "
              f"{row['rms_perturbed_minus_floating']:>9.5f} "
              f"{row['largest_turn_linear']:>9.3f} {row['largest_turn_floating']:>10.3f}",
              flush=True)  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
