"""Two or more builds of the simulator core, timed side by side on identical models.

``bench_rom.py`` measures one build's solvers against each other. To measure what a change to
the core did, the builds themselves must be compared: on a shared machine the steps/s of two
runs an hour apart move by more than most changes (PROFILE.md), so this script alternates the
builds in rounds within one run and takes each build's best. Every build steps the *same*
model: B_r, the cubature rule and the mesh are built once, by the installed package, and
passed to each build's ``cpp_sim.ReducedModel`` constructor (whose arguments have not changed
since the reduced core landed), so only the step's code differs. Each build runs with its own
default settings except the task's (staggered contact for the walkers; drag, no gravity and
no contact for the swimmer), under ``bench_rom.py``'s actuation (random modal forces of 0.5
body weight in the first three modes, seed 0; ``--actuation gait`` for one smooth sinusoidal
gait instead, as ``_actuation.py`` draws it), one thread, one C++ rollout from rest.

A build is an unpacked wheel. For a commit::

    git worktree add /tmp/before COMMIT
    pip wheel /tmp/before --no-deps -w /tmp/whl_before
    mkdir /tmp/site_before && unzip -q /tmp/whl_before/*.whl -d /tmp/site_before

then::

    python benchmarks/ab_builds.py --build before=/tmp/site_before --build after=/tmp/site_after
        [--robots quadruped-walk ...] [--solver fast] [--frame linear]
        [--contact staggered] [--actuation random] [--steps 300] [--rounds 3] [--compare]
        [--json]

It prints steps/s per build and benchmark (best of ``--rounds`` alternating rounds, each the
best of three rollouts) and each build's ratio to the first. ``--solver`` picks the solver in
builds that have one (``fast``, the default, or ``reference``); a build older than the
``solver`` setting runs its only step, and says so. ``--frame floating`` steps every build in
the floating frame (a build without the setting is refused). ``--contact penalty`` gives the
walkers the penalty ground instead of staggered projection (the swimmer has no contact).
``--compare`` also reports, per
build against the first, the largest difference of the rollouts' reduced coordinates q (0
means the builds compute bit for bit the same trajectory, which is how a change that should
not alter the physics is checked).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _actuation import BENCHMARKS, modal_forces  # numpy only: not the package under test

MODEL_ARRAYS = ("nodes", "tets", "youngs_modulus", "poisson_ratio", "density", "basis",
                "elements", "weights", "surface_nodes", "surface_faces")  # fmt: skip


def save_models(robots: list[str], path: Path) -> None:
    """The constructor arguments of each benchmark's reduced model (M = 20, cubature), as built
    by the installed package, in one .npz keyed ``robot/argument``."""
    import numpy as np

    from softrom_gym.robots import ROBOTS
    from softrom_gym.rom import build_subspace, train_cubature

    arrays = {}
    for robot_name in sorted({BENCHMARKS[b][0] for b in robots}):
        robot = ROBOTS[robot_name]()
        sub = build_subspace(robot, 20)
        rule = train_cubature(robot, sub)
        values = (robot.nodes, robot.tets, robot.youngs_modulus, robot.poisson_ratio,
                  robot.density, sub.basis, rule.elements, rule.weights, robot.surface_nodes,
                  robot.surface_faces)  # fmt: skip
        for name, value in zip(MODEL_ARRAYS, values, strict=True):
            arrays[f"{robot_name}/{name}"] = np.asarray(value)
    np.savez(path, **arrays)


def child(site: str, data: str, solver: str, frame: str, contact: str, actuation: str,
          steps: int, robots: list[str], out: str) -> None:  # fmt: skip
    """Time each benchmark with the build in ``site`` (imported instead of the installed one)."""
    sys.meta_path = [f for f in sys.meta_path if not type(f).__module__.startswith("_editable")]
    sys.path.insert(0, site)
    import time

    import numpy as np

    import cpp_sim

    models = np.load(data)
    result: dict = {"rates": {}, "solver": None, "q": {}}
    trajectories = {}
    for bench in robots:
        robot_name, task = BENCHMARKS[bench]
        args = [models[f"{robot_name}/{name}"] for name in MODEL_ARRAYS]
        for i in (2, 3, 4):  # E, nu, rho are scalars
            args[i] = float(args[i])
        model = cpp_sim.ReducedModel(*args)
        if task == "swim":
            model.contact = "none"
            model.gravity = [0.0, 0.0, 0.0]
            model.fluid_density = 1000.0
        else:
            model.contact = contact
        if hasattr(model, "solver"):
            model.solver = solver
            result["solver"] = solver
        if frame != "linear":
            if not hasattr(model, "frame"):
                raise SystemExit(f"{site} has no frame setting (built before frame='floating')")
            model.frame = frame
        model.control_basis = np.eye(20)[:, :3]
        controls = modal_forces(model, (1, steps, 3), kind=actuation)
        state = model.rest_state()
        model.rollout(state, controls[:, :5], threads=1)  # warm-up
        best = np.inf
        for _ in range(3):
            start = time.perf_counter()
            rollout = model.rollout(state, controls, threads=1)
            best = min(best, time.perf_counter() - start)
        if rollout["diverged"].any():
            raise RuntimeError(f"{bench}: the timed rollout diverged in {site}")
        result["rates"][bench] = steps / best
        trajectories[bench] = rollout["q"]
    np.savez(out + ".npz", **trajectories)
    Path(out).write_text(json.dumps(result))


def run_build(site: Path, data: Path, args: argparse.Namespace, out: Path) -> dict:
    cmd = [sys.executable, __file__, "--child", str(site), "--data", str(data), "--solver",
           args.solver, "--frame", args.frame, "--contact", args.contact, "--actuation",
           args.actuation, "--steps", str(args.steps), "--out", str(out),
           "--robots", *args.robots]  # fmt: skip
    env = dict(os.environ, PYTHONNOUSERSITE="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"build {site} failed:\n{proc.stderr[-3000:]}")
    return json.loads(out.read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--build", action="append", default=[], metavar="NAME=DIR",
                        help="an unpacked wheel to time (give two or more)")  # fmt: skip
    parser.add_argument("--robots", nargs="+", default=list(BENCHMARKS), choices=list(BENCHMARKS))
    parser.add_argument("--solver", default="fast", choices=["fast", "reference"])
    parser.add_argument(
        "--frame",
        default="linear",
        choices=["linear", "floating"],
        help="the frame every build steps in (floating: builds that have it)",
    )
    parser.add_argument(
        "--contact",
        default="staggered",
        choices=["staggered", "penalty"],
        help="the walkers' ground (the swimmer has none)",
    )
    parser.add_argument(
        "--actuation",
        default="random",
        choices=["random", "gait"],
        help="random modal forces, new each step (bench_rom's), or one smooth gait",
    )
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--compare", action="store_true",
                        help="also report the trajectories' largest difference in q")  # fmt: skip
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--data", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.data, args.solver, args.frame, args.contact, args.actuation,
              args.steps, args.robots, args.out)  # fmt: skip
        return
    builds: dict[str, Path] = {}
    for spec in args.build:
        name, sep, folder = spec.partition("=")
        if not sep or not name or not folder:
            parser.error(f"--build takes NAME=DIR, got {spec!r}")
        if name in builds:
            parser.error(f"--build name {name!r} is given twice")
        if not (Path(folder) / "cpp_sim").is_dir():
            parser.error(f"--build {spec}: {folder} has no cpp_sim package (an unpacked wheel)")
        builds[name] = Path(folder).resolve()
    if len(builds) < 2:
        parser.error(f"give at least two --build NAME=DIR, got {len(builds)}")
    if args.steps < 10:
        parser.error(f"--steps must be >= 10, got {args.steps}")
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")

    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "models.npz"
        save_models(args.robots, data)
        best = {name: dict.fromkeys(args.robots, 0.0) for name in builds}
        solver_of: dict[str, str | None] = {}
        for round_ in range(args.rounds):
            for name, site in builds.items():
                res = run_build(site, data, args, Path(tmp) / f"{name}.json")
                solver_of[name] = res["solver"]
                for bench, rate in res["rates"].items():
                    best[name][bench] = max(best[name][bench], rate)
                if not args.json:
                    line = " ".join(f"{b} {r:.0f}" for b, r in res["rates"].items())
                    print(f"round {round_ + 1}/{args.rounds} {name}: {line}", flush=True)
        first = next(iter(builds))
        differences: dict[str, dict[str, float]] = {}
        if args.compare:
            reference = np.load(Path(tmp) / f"{first}.json.npz")
            for name in list(builds)[1:]:
                other = np.load(Path(tmp) / f"{name}.json.npz")
                differences[name] = {
                    b: float(np.max(np.abs(other[b] - reference[b]))) for b in args.robots
                }

    if args.json:
        print(json.dumps({"solver": solver_of, "steps_per_s": best, "max_abs_dq": differences}))
        return
    print(f"\nsteps/s, best of {args.rounds} rounds ({args.steps} steps, one thread); "
          f"ratio to {first}")  # fmt: skip
    for name in builds:
        how = f"solver={solver_of[name]}" if solver_of[name] else "its only solver"
        how += f", {args.contact} ground" if args.contact != "staggered" else ""
        how += ", a gait" if args.actuation == "gait" else ""
        print(f"  {name}: {builds[name]} ({how})")
    header = f"{'benchmark':<16}" + "".join(f"{n:>14}" for n in builds)
    print(header + "".join(f"{n + '/' + first:>16}" for n in list(builds)[1:]))
    for bench in args.robots:
        row = f"{bench:<16}" + "".join(f"{best[n][bench]:>14.0f}" for n in builds)
        row += "".join(f"{best[n][bench] / best[first][bench]:>15.2f}x" for n in list(builds)[1:])
        print(row)
    for name, diffs in differences.items():
        text = ", ".join(f"{b} {d:.3g}" + (" (bitwise)" if d == 0.0 else "")
                         for b, d in diffs.items())  # fmt: skip
        print(f"max |q_{name} - q_{first}|: {text}")


if __name__ == "__main__":
    main()
