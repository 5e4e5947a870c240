"""Does the staggered ground keep every node out of it? The deepest node after a step.

Each walker (M = 20, B_c the first three modes, the staggered-projection ground, the model's
defaults otherwise) takes ``--steps`` steps from rest under a 2 Hz travelling wave of
``--amplitudes`` body weights of modal force in the three control directions (phases 0, 120,
240 degrees), in each frame. Printed per robot, frame and amplitude: the deepest any surface
node ended a step below the ground (after the step, from the exact kinematics), the same
beyond each node's own bound (the plane, or 1 - stabilization of a penetration it started
the step with) over the steps reported converged, the largest step rotation h |omega|
(floating frame), the mean staggers per step, the steps solved more than once (a ``R`` in
the stagger trace: a missed candidate, or the floating frame's drift), and the steps not
converged (Newton or contact). (The tables in docs/FLOATING_FRAME.md and
benchmarks/PROFILE.md, session 51.)

    python benchmarks/check_contact_bounds.py [--amplitudes 0.8 2 3] [--steps 400]
        [--solver fast|reference] [--frames linear floating] [--robots beam cross ...]
"""

from __future__ import annotations

import argparse

import numpy as np

from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model

G = 9.81
WALKERS = ("beam", "cross", "quadruped", "tripod")


def run(robot: str, frame: str, solver: str, amplitude: float, steps: int) -> dict:
    model = build_reduced_model(ROBOTS[robot](), frame=frame, solver=solver,
                                control_basis=np.eye(20)[:, :3])  # fmt: skip
    model.profile = True  # for the stagger trace's re-solves (the physics is the same)
    weight = np.sqrt(model.total_mass) * G
    t = np.arange(steps) * model.dt
    phase = 2.0 * np.pi * np.arange(3) / 3.0
    forces = amplitude * weight * np.sin(2.0 * np.pi * 2.0 * t[:, None] - phase[None, :])
    nodes = np.asarray(model.surface_nodes)
    state = model.rest_state()
    z0 = model.positions(state.q)[nodes, 2] - model.ground_height
    deepest = beyond = turn = 0.0
    staggers, resolved, unconverged = [], 0, 0
    for u in forces:
        state, info = model.step(state, u)
        if info["diverged"]:
            raise RuntimeError(f"{robot} ({frame}, {amplitude} body weights) diverged")
        z1 = model.positions(state.q)[nodes, 2] - model.ground_height
        deepest = max(deepest, float(-z1.min()))
        if info["contact_converged"]:
            bound = (1.0 - model.stabilization) * np.minimum(z0, 0.0)
            beyond = max(beyond, float((bound - z1).max()))
        if frame == "floating":
            turn = max(turn, model.dt * float(np.linalg.norm(state.qdot[3:6])))
        staggers.append(info["stagger_iterations"])
        resolved += "R" in info.get("stagger_trace", "").split()
        unconverged += not (info["converged"] and info["contact_converged"])
        z0 = z1
    return {"robot": robot, "frame": frame, "amplitude": amplitude, "deepest_mm": 1e3 * deepest,
            "beyond_bound_mm": 1e3 * beyond, "turn": turn, "staggers": float(np.mean(staggers)),
            "resolved": resolved, "unconverged": unconverged, "steps": steps}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--amplitudes", type=float, nargs="+", default=[0.8, 2.0, 3.0])
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--solver", choices=["fast", "reference"], default="fast")
    p.add_argument("--frames", nargs="+", choices=["linear", "floating"],
                   default=["linear", "floating"])  # fmt: skip
    p.add_argument("--robots", nargs="+", choices=WALKERS, default=list(WALKERS))
    args = p.parse_args(argv)
    if args.steps < 1 or min(args.amplitudes) <= 0.0:
        p.error(f"--steps must be at least 1 and --amplitudes positive, got {args.steps} and "
                f"{args.amplitudes}")  # fmt: skip
    print(f"{args.steps} steps of a 2 Hz stroke, solver={args.solver}; depths in mm")
    print(f"{'robot':10s} {'frame':8s} {'bw':>4s} {'deepest':>8s} {'beyond':>8s} "
          f"{'h|w|':>6s} {'staggers':>8s} {'re-solved':>9s} {'unconv':>6s}")  # fmt: skip
    for robot in args.robots:
        for frame in args.frames:
            for amplitude in args.amplitudes:
                r = run(robot, frame, args.solver, amplitude, args.steps)
                print(f"{robot:10s} {frame:8s} {amplitude:4.1f} {r['deepest_mm']:8.4f} "
                      f"{r['beyond_bound_mm']:8.4f} {r['turn']:6.3f} {r['staggers']:8.2f} "
                      f"{r['resolved']:9d} {r['unconverged']:6d}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
