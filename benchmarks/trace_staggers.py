"""How staggered projection spends its staggers, step by step, on the walking benchmarks.

A walking step's cost is its staggers (``PROFILE.md``): how many there are, and why, decides
what a faster contact solve must change. With ``profile=True`` each step reports
``stagger_trace``, one token per event of its stagger loop (grammar in ``StepInfo``,
``cpp_sim/src/reduced_model.h``)::

    N9(+1-2) N9(+1-1) S9 S9 w2l J S9 N8(+0-1) S8 S8 W3 S8 ok

``N<n>``: the normal half solved by NNLS over every candidate, ``n`` nodes loaded after it;
``S<n>``: solved on the held loaded set instead (a small dense solve); ``(+a-b)``: ``a``
nodes entered and ``b`` left the previous stagger's loaded set (the first stagger: the warm
start's); ``W<i>``: Newton on the held set's fixed point reached the root in ``i`` steps;
``w<i><why>``: it failed after ``i`` steps, because a node would leave the set (``l``), a load
was not positive (``r``), a step was singular (``s``) or at its iteration cap (``c``); ``J``:
an Aitken jump; ``ok`` / ``cap``: converged / stopped at the stagger cap; ``n`` (after
``ok``): a last normal solve, the friction half having left a candidate below its bound by
more than the tolerance; ``R``: the step solved again from v* (a node outside the candidates
ended below the ground, or the floating frame's drift moved), its staggers following.

This script steps each robot from rest under seeded actuation (``--actuation random``: 0.5
body weight in the first three modes, drawn anew every step, as ``profile_step.py`` and
``callgrind_step.py``; ``gait``: an open-loop sinusoidal gait), skips the first ``--settle``
steps, and prints, per robot, the staggers per step, how many of them solved the normal half
on a held set, how often the loaded set changed from one stagger to the next, and the Newton
tries (with the Newton steps they took, and why the failed ones failed) and Aitken jumps;
``--show N`` also prints the first N steps' traces.

    python benchmarks/trace_staggers.py [--robots cross-walk quadruped-walk ...] [--steps 200]
        [--settle 20] [--actuation random|gait] [--solver fast|reference] [--show 10] [--json]
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np

from softrom_gym.robots import ROBOTS
from softrom_gym.rom import build_reduced_model

sys.path.insert(0, str(Path(__file__).parent))
from _actuation import BENCHMARKS, KINDS, modal_forces

WALKERS = [name for name, (_, task) in BENCHMARKS.items() if task == "walk"]
NORMAL = re.compile(r"^([NS])(\d+)(?:\(\+(\d+)-(\d+)\))?$")
NEWTON = re.compile(r"^([Ww])(\d+)([lrsc]?)$")
FAILURES = {"l": "leave", "r": "unloaded", "s": "singular", "c": "cap"}
COUNTS = (
    "staggers", "held", "changed", "roots", "failed", "newton_steps", "jumps", "resolves",
    "last_normal",
    *(f"failed_{why}" for why in FAILURES.values()),
)  # fmt: skip


def parse(trace: str) -> dict:
    """Counts of one step's trace: staggers, held-set staggers, set changes, Newton tries (their
    steps, and the failures by reason), Aitken jumps."""
    tokens = trace.split()
    counts = dict.fromkeys(COUNTS, 0)
    counts["capped"] = bool(tokens) and tokens[-1] == "cap"
    for token in tokens:
        match, newton = NORMAL.match(token), NEWTON.match(token)
        if match:
            counts["staggers"] += 1
            counts["held"] += match.group(1) == "S"
            # The first stagger's change is from the warm start: counted like the others.
            counts["changed"] += match.group(3) is not None
        elif newton:
            root = newton.group(1) == "W"
            if root != (newton.group(3) == ""):
                raise ValueError(f"malformed Newton token {token!r} in {trace!r}")
            counts["roots" if root else "failed"] += 1
            counts["newton_steps"] += int(newton.group(2))
            if not root:
                counts[f"failed_{FAILURES[newton.group(3)]}"] += 1
        elif token == "J":
            counts["jumps"] += 1
        elif token == "R":
            counts["resolves"] += 1
        elif token == "n":
            counts["last_normal"] += 1
        elif token not in ("ok", "cap"):
            raise ValueError(f"unknown stagger trace token {token!r} in {trace!r}")
    return counts


def trace_robot(
    name: str, steps: int, settle: int, kind: str, solver: str, seed: int = 0
) -> tuple[dict, list[str]]:
    """Steps ``name`` from rest; returns the summary over the traced steps and their traces."""
    model = build_reduced_model(
        ROBOTS[BENCHMARKS[name][0]](), control_basis=np.eye(20)[:, :3], solver=solver
    )  # fmt: skip
    model.profile = True
    controls = modal_forces(model, (1, settle + steps, model.C), seed=seed, kind=kind)[0]
    state = model.rest_state()
    traces = []
    for n in range(settle + steps):
        state, info = model.step(state, controls[n])
        if n >= settle:
            traces.append(info["stagger_trace"])
    totals = dict.fromkeys(COUNTS, 0)
    capped = 0
    for trace in traces:
        counts = parse(trace)
        capped += counts.pop("capped")
        for key in totals:
            totals[key] += counts[key]
    staggers = max(totals["staggers"], 1)
    summary = {
        "robot": name,
        "solver": solver,
        "actuation": kind,
        "steps": steps,
        "staggers_per_step": totals["staggers"] / steps,
        "held_share": totals["held"] / staggers,
        "set_changed_share": totals["changed"] / staggers,
        "newton_tries_per_step": (totals["roots"] + totals["failed"]) / steps,
        "newton_roots_per_step": totals["roots"] / steps,
        "newton_steps_per_try": totals["newton_steps"] / max(totals["roots"] + totals["failed"], 1),
        **{
            f"newton_failed_{why}_per_step": totals[f"failed_{why}"] / steps
            for why in FAILURES.values()
        },
        "jumps_per_step": totals["jumps"] / steps,
        "resolves_per_step": totals["resolves"] / steps,
        "last_normal_per_step": totals["last_normal"] / steps,
        "capped_share": capped / steps,
    }
    return summary, traces


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="*", default=WALKERS, choices=WALKERS)
    parser.add_argument("--steps", type=int, default=200, help="traced steps per robot")
    parser.add_argument("--settle", type=int, default=20, help="untraced steps first")
    parser.add_argument("--actuation", choices=KINDS, default="random")
    parser.add_argument("--solver", choices=("fast", "reference"), default="fast")
    parser.add_argument("--show", type=int, default=0, help="print the first N traces")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    args = parser.parse_args()
    if args.steps < 1 or args.settle < 0 or args.show < 0:
        parser.error(
            f"need --steps >= 1, --settle >= 0, --show >= 0; got {args.steps}, "
            f"{args.settle}, {args.show}"
        )
    if not args.json:
        print(f"solver: {args.solver}; actuation: {args.actuation}; {args.steps} steps")
        print(
            f"{'robot':<15} {'staggers':>9} {'held':>6} {'changed':>8} {'newton':>7} "
            f"{'roots':>6} {'steps/try':>10} {'failed l/r/s/c':>20} {'jumps':>6} {'capped':>7} "
            f"{'re-solves':>9} {'last n':>7}"
        )
    for name in args.robots:
        s, traces = trace_robot(name, args.steps, args.settle, args.actuation, args.solver)
        if args.json:
            print(json.dumps({**s, "traces": traces[: args.show]}), flush=True)
            continue
        failed = "/".join(f"{s[f'newton_failed_{why}_per_step']:.2f}" for why in FAILURES.values())
        print(
            f"{name:<15} {s['staggers_per_step']:9.1f} {s['held_share']:6.0%} "
            f"{s['set_changed_share']:8.0%} {s['newton_tries_per_step']:7.2f} "
            f"{s['newton_roots_per_step']:6.2f} {s['newton_steps_per_try']:10.1f} "
            f"{failed:>20} {s['jumps_per_step']:6.2f} "
            f"{s['capped_share']:7.1%} {s['resolves_per_step']:9.2f} "
            f"{s['last_normal_per_step']:7.2f}",
            flush=True,
        )
        for trace in traces[: args.show]:
            print(f"    {trace}")
    if not args.json:
        print(
            "staggers: per step; held: share of staggers whose normal half ran on the held "
            "loaded set; changed: share whose loaded set differs from the stagger before; "
            "newton / roots: held-set Newton tries / roots per step; steps/try: Newton steps "
            "per try; failed l/r/s/c: failed tries per step, a node would leave the set / a "
            "load not positive / a singular step / the iteration cap; jumps: Aitken jumps per "
            "step; capped: share of steps at the stagger cap; re-solves: per step; last n: "
            "last normal solves after a converged stop, per step"
        )


if __name__ == "__main__":
    main()
