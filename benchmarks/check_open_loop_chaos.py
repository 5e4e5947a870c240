"""How far does one open-loop gait walk when its start moves by 1e-9? Chaos in walking.

Frictional contact makes a walking trajectory sensitive to its start: a node that sticks in
one run slips in another, and the gait can settle into another rhythm. This replays one
sinusoid gait (:class:`controllers.gaits.SinusoidGait`) open loop from ``reset(seed)``,
unperturbed and with ``--perturbations`` (m/s) added to one deformation velocity of the
start (mode 1, 2, 3, 1, ... in turn), for each solver, and prints the distance along d
between t = ``--start`` and ``--seconds`` in body lengths. When the spread over perturbations
is as large as the distances, a single run's distance (or a mean over a few seeds) is not a
property of the gait, and two builds whose arithmetic differs only at round-off can print
different tables.

    python benchmarks/check_open_loop_chaos.py [ENV_ID] [--frequency 3] [--amplitude 1]
        [--phases 0 180 180] [--seed 0] [--solvers fast reference] [--json]
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from controllers.gaits import SinusoidGait


def distances(env, gait: SinusoidGait, args: argparse.Namespace, solver: str) -> list[float]:
    """Distance (body lengths) unperturbed, then with each perturbation of the start."""
    from cpp_sim import ReducedState

    base = env.unwrapped
    base.model.solver = solver
    dt = env.get_wrapper_attr("dt")
    steps, first = round(args.seconds / dt), round(args.start / dt)
    controls = gait.controls(steps, dt, env.get_wrapper_attr("action_bound"))[None]
    env.reset(seed=args.seed)
    start = env.get_wrapper_attr("get_state")()
    out = []
    for k, eps in enumerate([0.0, *args.perturbations]):
        qdot = start.qdot.copy()
        if eps:
            qdot[6 + (k - 1) % 3] += eps  # a deformation velocity (after the 6 rigid ones)
        state = ReducedState(start.q, qdot, start.impulses)
        res = env.get_wrapper_attr("rollout")(state, controls, threads=1)
        gained = (res["com"][0, -1] - res["com"][0, first - 1]) @ base.direction
        out.append(float(gained / env.get_wrapper_attr("body_length")))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("env_id", nargs="?", default="softrom_gym/TripodWalk-v0")
    p.add_argument("--frequency", type=float, default=3.0, help="Hz")
    p.add_argument("--amplitude", type=float, default=1.0, help="fraction of the action bound")
    p.add_argument("--phases", type=float, nargs="+", default=[0.0, 180.0, 180.0],
                   help="degrees, one per control dimension")  # fmt: skip
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--perturbations", type=float, nargs="+",
                   default=[1e-9, -1e-9, 1e-7, -1e-7, 1e-5])  # fmt: skip
    p.add_argument("--solvers", nargs="+", choices=["fast", "reference"],
                   default=["fast", "reference"])  # fmt: skip
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--start", type=float, default=2.0, help="distance counts from this time (s)")
    p.add_argument("--json", action="store_true", help="one JSON object per solver")
    args = p.parse_args()
    if args.seed < 0:  # gymnasium's reset refuses it, as a traceback
        p.error(f"--seed must be >= 0, got {args.seed}")
    if not 0 < args.start < args.seconds:
        p.error(f"--start {args.start} must lie inside (0, --seconds {args.seconds})")
    try:
        env = gym.make(args.env_id, control_dim=len(args.phases))
    except (ValueError, gym.error.Error) as exc:  # an unknown id, more phases than M
        p.error(str(exc))
    dt = env.get_wrapper_attr("dt")
    if not 1 <= round(args.start / dt) < round(args.seconds / dt):  # (else the end minus itself)
        p.error(f"--start {args.start:g} and --seconds {args.seconds:g} must round to at least "
                f"one control period ({dt:g} s) from 0 and from each other")  # fmt: skip
    gait = SinusoidGait(args.frequency, args.amplitude, tuple(np.radians(args.phases)))
    if not args.json:
        print(f"{args.env_id}, {gait.label()}, seed {args.seed}: distance (BL) from "
              f"t = {args.start:g} to {args.seconds:g} s, unperturbed | perturbed by "
              f"{', '.join(f'{e:g}' for e in args.perturbations)} m/s")  # fmt: skip
    for solver in args.solvers:
        d = distances(env, gait, args, solver)
        if args.json:
            print(json.dumps({"env_id": args.env_id, "gait": gait.label(), "seed": args.seed,
                              "solver": solver, "unperturbed": d[0], "perturbed": d[1:],
                              "perturbations": args.perturbations}))  # fmt: skip
        else:
            spread = f"range {min(d):.3f} .. {max(d):.3f}"
            print(f"  {solver:<9} {d[0]:7.3f} | {' '.join(f'{x:7.3f}' for x in d[1:])}   {spread}")
    env.close()


if __name__ == "__main__":
    main()
