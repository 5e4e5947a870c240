"""Where a reduced step goes, in instructions: a deterministic profile under valgrind's callgrind.

Wall-clock A/B runs on a shared 2-core machine move by 15-20 % between runs (see PROFILE.md),
so a 5 % change to the step cannot be seen in microseconds. Instruction counts do not depend on
the machine's load: this script steps a benchmark robot from rest under random actuation (0.5
body weight in the first three modes, seeded, as ``profile_step.py``) inside callgrind,
collecting only inside ``ReducedModel::step``, and prints instructions per step split by the
step's parts, with the iteration counts that explain them:

* ``stiffness``: cubature stiffness K_r(q) evaluations (and how many per step);
* ``forces``: cubature energy and force evaluations (the quasi-Newton's line search);
* ``contact``: the staggered projection (per step and per stagger), of which ``normal (LDP)``
  is the least-distance programme (NNLS) and the rest mostly the friction half and the
  impulse responses;
* ``drag``: quadratic surface drag;
* ``other``: the rest of the step (set-up, line-search bookkeeping, the state update).

Instruction counts are not time (a GEMM kernel retires several per cycle, a cache miss
none), but two builds or two settings compared on one robot are compared exactly. One trap:
glibc's memset fills large buffers (a few KB up) with ``rep stosb``, which callgrind counts
once per iteration, i.e. per byte, so a 6 KB fill reads as ~6,300 instructions (1 KB: 70) for the
few hundred cycles it takes; a saving found in ``__memset_*`` is mostly not time. It needs
``valgrind`` (Debian: ``apt install valgrind``); about 25 s per 200 steps of the quadruped.

    python benchmarks/callgrind_step.py [--robots quadruped beam] [--solver fast] [--steps 200]
        [--json]

The parts are found by the extension's symbols, which the package's Release build strips.
Build with symbols (same -O3 code, plus debug information for per-line attribution with
``callgrind_annotate --auto=yes`` on a kept output file, ``--keep``)::

    pip install --no-deps -e . -Ccmake.build-type=RelWithDebInfo

or, to compare two builds without reinstalling, unpack each wheel
(``pip wheel . --no-deps -w DIR -Ccmake.build-type=RelWithDebInfo``, then ``unzip``) and
pass its folder as ``--site DIR``: the stepping process imports the package from there.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# Function-name patterns (callgrind_annotate's demangled names) of each part; a part's cost is
# the largest inclusive count among its entries (inlined pieces are listed under the headers
# they came from, and lambdas inside a function are its callees, not the function).
PARTS = {
    "step": r"softrom::ReducedModel::step\(",
    "stiffness": r"softrom::ReducedModel::(elastic_stiffness_fast|elastic_reference)\(",
    "forces": r"softrom::ReducedModel::elastic_energy_force\(",
    "contact": r"softrom::ReducedModel::solve_contacts\((?!.*\{lambda)",
    "normal (LDP)": r"softrom::(least_distance|nnls_cholesky|nnls)\(",
    "drag": r"softrom::ReducedModel::drag(_fast)?\(",
}


def child(robot_name: str, solver: str, steps: int, task: str) -> None:
    """Step the robot (run inside callgrind); print the iteration counts as JSON."""
    site = os.environ.get("SOFTROM_PROFILE_SITE")
    if site:  # the build under test, not the installed (possibly editable) package
        sys.meta_path = [f for f in sys.meta_path if not type(f).__module__.startswith("_editable")]
        sys.path.insert(0, site)
    import numpy as np

    from softrom_gym.robots import ROBOTS
    from softrom_gym.rom import build_reduced_model

    settings = {"solver": solver}
    if task == "swim":
        settings.update(contact="none", gravity=[0.0, 0.0, 0.0], fluid_density=1000.0)
    model = build_reduced_model(ROBOTS[robot_name](), control_basis=np.eye(20)[:, :3],
                                **settings)  # fmt: skip
    sys.path.insert(1, str(Path(__file__).parent))
    from _actuation import modal_forces

    controls = modal_forces(model, (1, steps, 3))[0]
    state = model.rest_state()
    totals = dict.fromkeys(("newton_iterations", "stiffness_evaluations", "stagger_iterations",
                            "normal_iterations", "active_rows"), 0)  # fmt: skip
    for n in range(steps):
        state, info = model.step(state, controls[n])
        for key in totals:
            totals[key] += info.get(key, 0)
    print(json.dumps(totals))


def inclusive_costs(out_file: Path) -> dict[str, int]:
    """Inclusive instruction counts of each part, from callgrind_annotate."""
    text = subprocess.run(
        ["callgrind_annotate", "--inclusive=yes", "--threshold=100", str(out_file)],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    costs = dict.fromkeys(PARTS, 0)
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+)\s+(?:\([^)]*\)\s+)?(.*)$", line)
        if not m:
            continue
        count, name = int(m.group(1).replace(",", "")), m.group(2)
        for part, pattern in PARTS.items():
            if re.search(pattern, name):
                costs[part] = max(costs[part], count)
    return costs


def profile(robot: str, solver: str, steps: int, keep: Path | None, site: Path | None) -> dict:
    task = "swim" if robot == "cross-swim" else "walk"
    name = "cross" if robot.startswith("cross") else robot
    with tempfile.TemporaryDirectory() as tmp:
        out_file = (keep or Path(tmp)) / f"callgrind.{robot}.{solver}.out"
        out_file.parent.mkdir(parents=True, exist_ok=True)
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out_file}",
               "--toggle-collect=softrom::ReducedModel::step(*", sys.executable, __file__,
               "--child", name, solver, str(steps), task]  # fmt: skip
        env = dict(os.environ, SOFTROM_PROFILE_SITE=str(site.resolve()) if site else "")
        run = subprocess.run(cmd, capture_output=True, text=True, env=env)
        if run.returncode != 0:
            raise SystemExit(f"valgrind failed ({run.returncode}):\n{run.stderr[-2000:]}")
        counts = json.loads(run.stdout.strip().splitlines()[-1])
        costs = inclusive_costs(out_file)
    if costs["step"] == 0:
        raise SystemExit("no instructions were collected inside ReducedModel::step: the "
                         "extension has no symbols (a Release build is stripped); rebuild it "
                         "with pip install --no-deps -e . "
                         "-Ccmake.build-type=RelWithDebInfo")  # fmt: skip
    per = {k: v / steps for k, v in costs.items()}
    staggers = counts["stagger_iterations"] / steps
    return {
        "robot": robot, "solver": solver, "steps": steps,
        "instructions_per_step": per["step"],
        **{f"{k.split()[0]}_per_step": per[k] for k in PARTS if k != "step"},
        "other_per_step": per["step"] - per["stiffness"] - per["forces"] - per["contact"]
        - per["drag"],
        "stiffness_evaluations_per_step": counts["stiffness_evaluations"] / steps,
        "newton_iterations_per_step": counts["newton_iterations"] / steps,
        "staggers_per_step": staggers,
        "contact_per_stagger": per["contact"] / staggers if staggers else None,
        "rows_per_step": counts["active_rows"] / steps,
    }  # fmt: skip


def print_row(r: dict) -> None:
    total = r["instructions_per_step"]

    def share(key: str) -> str:
        return f"{r[key] / 1e3:>9.0f} k {r[key] / total:>6.1%}"

    print(f"{r['robot']} ({r['solver']}, {r['steps']} steps from rest): "
          f"{total / 1e6:.2f} M instructions per step")  # fmt: skip
    print(f"  stiffness     {share('stiffness_per_step')}   "
          f"{r['stiffness_evaluations_per_step']:.2f} evaluations per step")  # fmt: skip
    print(f"  forces        {share('forces_per_step')}   "
          f"{r['newton_iterations_per_step']:.2f} Newton iterations per step")  # fmt: skip
    line = f"  contact       {share('contact_per_step')}   {r['staggers_per_step']:.1f} staggers"
    if r["contact_per_stagger"]:
        line += f", {r['contact_per_stagger'] / 1e3:.0f} k per stagger, "
        line += f"{r['rows_per_step']:.0f} candidate rows"
    print(line)
    print(f"    normal LDP  {share('normal_per_step')}")
    print(f"  drag          {share('drag_per_step')}")
    print(f"  other         {share('other_per_step')}", flush=True)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        name, solver, steps, task = sys.argv[2:6]
        child(name, solver, int(steps), task)
        return
    robots = ["cross-swim", "cross-walk", "beam", "quadruped", "tripod"]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["quadruped"], choices=robots)
    parser.add_argument("--solver", nargs="+", default=["fast"], choices=["fast", "reference"])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--keep", type=Path, help="keep the callgrind output files here")
    parser.add_argument("--site", type=Path, help="import the package from this unpacked wheel")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    args = parser.parse_args()
    if args.steps < 1:
        parser.error(f"--steps must be >= 1, got {args.steps}")
    missing = [t for t in ("valgrind", "callgrind_annotate") if shutil.which(t) is None]
    if missing:
        parser.error(f"{' and '.join(missing)} not found: install valgrind (apt install valgrind)")
    if args.site is not None and not (args.site / "cpp_sim").is_dir():
        parser.error(f"--site {args.site} has no cpp_sim package (an unpacked wheel expected)")
    for robot in args.robots:
        for solver in args.solver:
            r = profile(robot, solver, args.steps, args.keep, args.site)
            print(json.dumps(r), flush=True) if args.json else print_row(r)


if __name__ == "__main__":
    main()
