"""Where a reduced step goes: per benchmark robot, per physics configuration, per solver.

For each robot it times, on one thread, with random actuation of 0.5 body weight in the first
three deformation modes, drawn anew every step (the same sequence for every row; or, with
``--actuation gait``, one open-loop sinusoidal gait as in ``accuracy_solvers.py``, smooth as a
controller's splines are):

* ``forces`` / ``stiffness``: one cubature evaluation of the reduced elastic force f_r(q_r)
  and of the reduced stiffness K_r(q_r) at a pose taken from the actuated run;
* ``step`` in four configurations — ``free`` (no gravity, contact or drag), ``drag``
  (quadratic fluid drag), ``staggered`` (gravity + staggered-projection ground, the walkers'
  default) and ``penalty`` (gravity + penalty ground) — in µs per step, with the mean Newton
  iterations, staggers and candidate contact rows per step, the spread of the staggers over
  the steps (``p10/50/90``: a mean can hide that a few hard steps take most of them), and the
  share of steps that ended at an iteration cap (``newton cap`` / ``stagger cap``: results the
  solver did not certify);
* the split of a step's time (µs, measured inside C++ with ``profile=True``): ``dynamics``
  (the implicit solve), ``drag``, and the staggered projection's ``normal`` and ``friction``
  halves; the remainder of ``us/step`` is binding overhead and bookkeeping, and for the fast
  solver the per-call set-up of A_0's inverse (each ``step`` call forms it; a ``rollout``
  forms it once for all its steps);
* for each solver the model offers (``reference``: the exact Newton path; ``fast``: the
  default), one row each, timed one after the other in the same run; the fast row's
  ``ref/fast`` column (``--json`` key ``ref_over_fast``) is the reference row's ``us/step``
  over its own, the fast solver's speed-up on that robot and configuration. It is the ratio
  to read: the ``us/step`` themselves move with the machine and its load, the ratio much
  less.

``--warm-start converged`` is a bound, not a mode to run: each timed step is taken a second
time from the same state with the first try's converged impulses as its warm start (the
first try untimed), so the staggers read what a perfect prediction of the contact impulses
would leave to do; the default, ``previous``, warm-starts from the last step's impulses as
every step does.

    python benchmarks/profile_step.py [--robots quadruped ...] [--steps 200]
        [--actuation random|gait] [--warm-start previous|converged] [--json]

The summary it printed when committed is in ``benchmarks/PROFILE.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import cpp_sim
from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model

sys.path.insert(0, str(Path(__file__).parent))
from _actuation import KINDS, modal_forces

CONFIGS = {
    "free": {"contact": "none", "gravity": [0.0, 0.0, 0.0]},
    "drag": {"contact": "none", "gravity": [0.0, 0.0, 0.0], "fluid_density": 1000.0},
    "staggered": {"contact": "staggered"},
    "penalty": {"contact": "penalty"},
}


def solvers() -> list[str]:
    """The solver paths this build offers (older builds have only the reference path)."""
    return list(getattr(cpp_sim.ReducedModel, "SOLVERS", ("reference",)))


def time_step(model, steps: int, kind: str = "random", warm_start: str = "previous") -> dict:
    if warm_start not in ("previous", "converged"):
        raise ValueError(f"warm_start must be 'previous' or 'converged', got {warm_start!r}")
    controls = modal_forces(model, (1, steps + 10, model.C), kind=kind)[0]
    state = model.rest_state()
    for n in range(10):  # settle contact and warm the caches
        state, _ = model.step(state, controls[n])
    newton = rows = 0
    staggers = np.zeros(steps, dtype=int)
    newton_cap = stagger_cap = 0
    parts = dict.fromkeys(("time_dynamics", "time_drag", "time_normal", "time_friction"), 0.0)
    model.profile = True
    wall = 0.0
    offset = 10 if kind == "gait" else 0  # a gait goes on in time; the random draws repeat
    for n in range(steps):
        u = controls[offset + n]
        if warm_start == "converged":  # the first try, untimed, gives the warm start
            first, _ = model.step(state, u)
            state = cpp_sim.ReducedState(state.q, state.qdot, first.impulses)
        start = time.perf_counter()
        state, info = model.step(state, u)
        wall += time.perf_counter() - start
        newton += info["newton_iterations"]
        staggers[n] = info["stagger_iterations"]
        rows += info["active_rows"]
        newton_cap += not info.get("converged", True)
        stagger_cap += not info.get("contact_converged", True)
        for key in parts:
            parts[key] += info.get(key, 0.0)
    return {
        "us_per_step": 1e6 * wall / steps,
        "newton_per_step": newton / steps,
        "staggers_per_step": staggers.mean(),
        **{f"staggers_p{p}": float(np.percentile(staggers, p)) for p in (10, 50, 90)},
        "rows_per_step": rows / steps,
        "newton_cap_share": newton_cap / steps,
        "stagger_cap_share": stagger_cap / steps,
        **{key.replace("time_", "") + "_us": 1e6 * t / steps for key, t in parts.items()},
        "pose": state.q,
    }


def time_call(fn, *args, repeats: int = 200) -> float:
    fn(*args)
    best = np.inf
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            fn(*args)
        best = min(best, (time.perf_counter() - start) / repeats)
    return 1e6 * best


def profile(
    robot_name: str,
    steps: int,
    kind: str = "random",
    warm_start: str = "previous",
    configs: list[str] | None = None,
) -> list[dict]:
    robot = ROBOTS[robot_name]()
    rows = []
    pose = None
    for config in configs or list(CONFIGS):
        settings = CONFIGS[config]
        for solver in solvers():
            extra = {"solver": solver} if len(solvers()) > 1 else {}
            model = build_reduced_model(
                robot, control_basis=np.eye(20)[:, :3], **settings, **extra
            )  # fmt: skip
            r = time_step(model, steps, kind, warm_start)
            last = r.pop("pose")  # an array: not a row's value (nor JSON)
            pose = last if config == "staggered" or pose is None else pose
            rows.append(
                {
                    "robot": robot_name, "config": config, "solver": solver,
                    "actuation": kind, "warm_start": warm_start, **r,
                }
            )  # fmt: skip
        timed = {row["solver"]: row for row in rows if row.get("config") == config}
        if {"reference", "fast"} <= timed.keys():
            timed["fast"]["ref_over_fast"] = (
                timed["reference"]["us_per_step"] / timed["fast"]["us_per_step"]
            )
    model = build_reduced_model(robot, control_basis=np.eye(20)[:, :3])
    q_e = pose[3:]
    rows.append(
        {
            "robot": robot_name,
            "config": "kernels",
            "forces_us": time_call(model.elastic_forces, q_e),
            "stiffness_us": time_call(model.elastic_stiffness, q_e, repeats=50),
            "cubature_elements": model.num_cubature_elements,
        }
    )
    return rows


def spread(row: dict) -> str:
    """The staggers' 10th, 50th and 90th percentiles over the timed steps, as ``a/b/c``."""
    return "/".join(f"{row[f'staggers_p{p}']:.0f}" for p in (10, 50, 90))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="*", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument("--steps", type=int, default=200, help="timed steps per row")
    parser.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--actuation", choices=KINDS, default="random")
    parser.add_argument(
        "--warm-start",
        choices=("previous", "converged"),
        default="previous",
        help="converged: each step retaken from its own converged impulses (a bound)",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    args = parser.parse_args()
    if args.steps < 10:  # the first 10 of them also warm up each row, untimed
        parser.error(f"--steps must be >= 10, got {args.steps}")
    if not args.json:
        print(f"actuation: {args.actuation}; warm start: {args.warm_start}")
        print(
            f"{'robot':<10} {'config':<10} {'solver':<10} {'us/step':>9} {'newton':>7} "
            f"{'stagger':>8} {'p10/50/90':>10} {'rows':>6} {'newton cap':>11} "
            f"{'stagger cap':>12} "
            f"{'dynamics':>9} {'drag':>6} {'normal':>7} {'friction':>9} {'ref/fast':>9}"
        )
    for name in args.robots:
        for r in profile(name, args.steps, args.actuation, args.warm_start, args.configs):
            if args.json:
                print(json.dumps(r), flush=True)
            elif r["config"] == "kernels":
                print(
                    f"{name:<10} {'kernels':<10} forces {r['forces_us']:.1f} us, "
                    f"stiffness {r['stiffness_us']:.1f} us",
                    flush=True,
                )
            else:
                ratio = f"{r['ref_over_fast']:.2f}x" if "ref_over_fast" in r else ""
                print(
                    f"{name:<10} {r['config']:<10} {r['solver']:<10} {r['us_per_step']:>9.0f} "
                    f"{r['newton_per_step']:>7.2f} {r['staggers_per_step']:>8.2f} "
                    f"{spread(r):>10} "
                    f"{r['rows_per_step']:>6.1f} {r['newton_cap_share']:>11.1%} "
                    f"{r['stagger_cap_share']:>12.1%} {r['dynamics_us']:>9.0f} "
                    f"{r['drag_us']:>6.0f} {r['normal_us']:>7.0f} {r['friction_us']:>9.0f} "
                    f"{ratio:>9}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
