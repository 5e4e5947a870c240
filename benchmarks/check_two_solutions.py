"""Where the solvers disagree by more than their tolerance in one step: two solutions?

``accuracy_solvers.py`` steps each state of a reference trajectory (one open-loop gait, seed
1, as its first measure) with the reference, the fast solver and a tightly converged
reference (all with the default friction law, ``friction_smoothing`` 1e-4 m/s, however
tight their stop). Where the fast or the reference step lands more than ``--threshold``
(m/s, the mass-weighted RMS node velocity) from the tight one, this asks whether the contact
problem at that state has more than one solution: the reference is warm-started from each
answer's impulses with ``--tolerance`` (default 1e-8 m/s, up to 4,000 staggers) and Newton
at 1e-11. An answer the strict reference stays at is a fixed point of staggered
projection, so a solution of the step's contact problem; two such answers far apart mean the
step has two (Coulomb friction with an exact normal constraint need not be unique), and
which one a solver takes depends on its warm start and path, not on its tolerance.

Printed per flagged step: each solver's gap to the tight step, its loaded contacts, and for
each warm start (fast, reference, tight) where the strict reference ends, its distance to the
start and to the tight answer, and a verdict on the start: a *solution* (the strict
reference stays within a tenth of the threshold), *stopped short* (it converges elsewhere:
the solver stopped while its iterates crept, each stagger changing the contact velocities by
less than the tolerance), or *left unsettled* (4,000 staggers at the strict tolerance do not
converge). Answers whose step did not report convergence, and tight steps that did not
converge themselves, are marked. The last line counts the flagged steps (and those of them
whose tight step did not converge), and the solvers' flagged answers by whether they
reported converged and by verdict.
(benchmarks/PROFILE.md, session 52.)

    python benchmarks/check_two_solutions.py [--robot tripod-walk] [--frame floating]
        [--steps 400] [--threshold 5e-3] [--tolerance 1e-8]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import cpp_sim
from softrom_gym.robots import ROBOTS

sys.path.insert(0, str(Path(__file__).parent))
from _actuation import BENCHMARKS
from accuracy_solvers import TIGHT, gaits, model, velocity_gap


def loaded(state: cpp_sim.ReducedState) -> int:
    return int((state.impulses.reshape(-1, 3)[:, 2] > 0.0).sum())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", default="tripod-walk",
                   choices=[b for b, v in BENCHMARKS.items() if v[1] == "walk"])  # fmt: skip
    p.add_argument("--frame", choices=["linear", "floating"], default="floating")
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--threshold", type=float, default=5e-3)
    p.add_argument("--tolerance", type=float, default=1e-8)
    args = p.parse_args()
    if args.steps < 1 or args.threshold <= 0.0 or args.tolerance <= 0.0:
        p.error("--steps, --threshold and --tolerance must be positive")

    robot_name, task = BENCHMARKS[args.robot][:2]
    robot = ROBOTS[robot_name]()
    mass = np.asarray(robot.fem_model().mass)
    ref = model(robot, task, "reference", args.frame)
    solvers = {"fast": model(robot, task, "fast", args.frame), "reference": ref}
    tight = model(robot, task, "reference", args.frame, **TIGHT)
    strict = model(robot, task, "reference", args.frame, newton_tolerance=1e-11,
                   contact_tolerance=args.tolerance, max_stagger_iterations=4000,
                   friction_smoothing=TIGHT["friction_smoothing"])  # fmt: skip
    u = gaits(ref, 1, args.steps * ref.dt, seed=1)[0]
    state, flagged = ref.rest_state(), 0
    print(f"{args.robot}, {args.frame} frame, {args.steps} steps of one gait (seed 1); "
          f"flagged: a solver's step > {args.threshold:g} m/s from the tight one")  # fmt: skip
    verdicts = {"solution": 0, "stopped short": 0, "left unsettled": 0}
    # The flagged answers by whether their step reported converged (Newton and contact), and
    # the flagged steps whose tight yardstick did not itself converge: both were counted alike
    # (a review, session 54).
    reported = {"reported converged": 0, "not converged": 0}
    tight_unconverged = 0
    for n in range(args.steps):
        best, best_info = tight.step(state, u[n])
        steps = {name: m.step(state, u[n]) for name, m in solvers.items()}
        answers = {name: s for name, (s, _) in steps.items()}
        converged = {name: bool(i["converged"] and i["contact_converged"])
                     for name, (_, i) in steps.items()}  # fmt: skip
        tight_ok = bool(best_info["converged"] and best_info["contact_converged"])
        gaps = {name: velocity_gap(ref, mass, s, best) for name, s in answers.items()}
        if max(gaps.values()) > args.threshold:
            flagged += 1
            tight_unconverged += not tight_ok
            for name in gaps:
                if gaps[name] > args.threshold:
                    reported["reported converged" if converged[name] else "not converged"] += 1
            print(f"step {n}: " + ", ".join(
                f"{name} {gaps[name]:.2e} m/s ({loaded(answers[name])} loaded"
                + ("" if converged[name] else ", not converged") + ")" for name in gaps
            ) + f"; tight {loaded(best)} loaded"
              + ("" if tight_ok else ", not converged itself"))  # fmt: skip
            for name, answer in {**answers, "tight": best}.items():
                warm = cpp_sim.ReducedState(state.q, state.qdot, answer.impulses)
                end, info = strict.step(warm, u[n])
                stays = velocity_gap(ref, mass, end, answer)
                settled = info["converged"] and info["contact_converged"]
                verdict = verdict_of(stays, settled, args.threshold)
                if name != "tight" and gaps[name] > args.threshold:
                    verdicts[verdict] += 1
                print(f"  strict reference warm-started from {name}'s impulses: {stays:.2e} "
                      f"from it, {velocity_gap(ref, mass, end, best):.2e} from tight, "
                      f"converged {settled}: {verdict}")  # fmt: skip
        state = answers["reference"]
    print(f"{flagged} of {args.steps} steps flagged ({tight_unconverged} with the tight step "
          "itself not converged); the answers beyond the threshold: "
          + ", ".join(f"{v} {k}" for k, v in reported.items()) + "; "
          + ", ".join(f"{v} {k}" for k, v in verdicts.items()))  # fmt: skip


def verdict_of(stays: float, settled: bool, threshold: float) -> str:
    """What the strict reference, warm-started from an answer, says of it: a solution (it
    stays within a tenth of the threshold and converges), stopped short of one (it leaves, and
    converges elsewhere), or left unsettled (4,000 staggers do not converge)."""
    if not settled:
        return "left unsettled"
    return "solution" if stays < 0.1 * threshold else "stopped short"


if __name__ == "__main__":
    main()
