"""RBBO's model cost: GP fit and GP-UCB maximisation on Gr(20, 3) at 50, 200, 500 observations.

For each number of observations n, a GP (Grassmann x noise, fitted by marginal likelihood as
RBBO does) is built on n evaluations of a noisy synthetic objective, then the acquisition is
maximised, once with the limited-memory Riemannian BFGS and once with pymanopt's
ConjugateGradient, from the same starts, in two settings:

- ``rbbo``: exactly as :meth:`rbbo.RBBO.ask` does (128 random candidates + 3 incumbents and
  their perturbations screened, the 4 best refined, at most 60 iterations each);
- ``cold``: 4 random starts refined without screening, up to 500 iterations (a harder
  problem for the local optimiser: it starts far from a maximum).

Wall times are the median of ``--repeats`` runs, measured side by side in one process;
``evals`` counts every evaluation of (value, gradient). Target: acquisition < 1 s at 500.

    python benchmarks/bench_rbbo.py            # a table
    python benchmarks/bench_rbbo.py --json     # one JSON object per line
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from rbbo.acquisition import UCBAcquisition, maximize_on_grassmann, perturb, ucb_beta
from rbbo.gp import GrassmannGP
from rbbo.grassmann import dimension, random_points
from rbbo.objective import SyntheticObjective

M, C = 20, 3


def observations(n: int, rng: np.random.Generator):
    """n evaluations like a run's: half random, half around the optimum (as BO converges)."""
    objective = SyntheticObjective(M, C, optimum_seed=1, noise=0.02)
    k = n // 2
    near = [perturb(objective.optimum, s, rng) for s in rng.uniform(0.1, 1.0, n - k)]
    bases = np.concatenate([random_points(M, C, k, rng), np.stack(near)])
    y = np.array([objective(b, 10.0, 0) for b in bases])
    return bases, y


class Counted:
    """The acquisition, counting evaluations of its value and gradient."""

    def __init__(self, function):
        self.function = function
        self.count = 0

    def value_and_gradient(self, basis):
        self.count += 1
        return self.function.value_and_gradient(basis)

    def values(self, bases):
        return self.function.values(bases)


SETTINGS = {
    "rbbo": {},
    "cold": {"n_random": 4, "n_perturbations": 0, "n_starts": 4, "max_iterations": 500},
}


def measure(n: int, repeats: int) -> list[dict]:
    rng = np.random.default_rng(n)
    bases, y = observations(n, rng)
    fit_times = []
    for _ in range(repeats):
        start = time.perf_counter()
        gp = GrassmannGP(M, C, n_restarts=1, random_state=0).fit(bases, y)
        fit_times.append(time.perf_counter() - start)
    acquisition = UCBAcquisition(gp, ucb_beta(n, dimension(M, C)))
    incumbents = bases[np.argsort(-gp.predict_standardized(bases)[0])[:3]]
    rows = []
    for setting, kwargs in SETTINGS.items():
        for optimizer in ("lrbfgs", "cg"):
            times, values, iterations, evaluations = [], [], [], []
            for r in range(repeats):
                counted = Counted(acquisition)
                start = time.perf_counter()
                result = maximize_on_grassmann(
                    counted, M, C, incumbents=None if kwargs else incumbents, rng=100 + r,
                    optimizer=optimizer, **kwargs,
                )  # fmt: skip
                times.append(time.perf_counter() - start)
                values.append(result.value)
                iterations.append(sum(x.iterations for x in result.results))
                evaluations.append(counted.count)
            rows.append({
                "observations": n,
                "optimizer": optimizer,
                "setting": setting,
                "acq_wall_s": statistics.median(times),
                "fit_wall_s": statistics.median(fit_times),
                "acq_value": float(np.median(values)),
                "iterations": int(np.median(iterations)),
                "cost_evaluations": int(np.median(evaluations)),
                "sim_dim": M,
                "control_dim": C,
            })  # fmt: skip
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--sizes", type=int, nargs="+", default=[50, 200, 500])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    if args.repeats < 1 or min(args.sizes) < 1:
        parser.error(f"--repeats and --sizes must be >= 1, got {args.repeats}, {args.sizes}")
    if not args.json:
        print(f"GP-UCB on Gr({M}, {C}); medians of {args.repeats} runs")
        print(f"{'n':>5} {'setting':>7} {'optimizer':>9} {'fit s':>7} {'acq s':>7} "
              f"{'acq value':>12} {'iters':>6} {'evals':>6}")  # fmt: skip
    for n in args.sizes:
        rows = measure(n, args.repeats)
        for row in rows:
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                line = (f"{row['observations']:>5} {row['setting']:>7} {row['optimizer']:>9} "
                        f"{row['fit_wall_s']:>7.3f} {row['acq_wall_s']:>7.3f} "
                        f"{row['acq_value']:>12.6f} {row['iterations']:>6} "
                        f"{row['cost_evaluations']:>6}")  # fmt: skip
                print(line, flush=True)
        if not args.json:
            for qn, cg in (rows[:2], rows[2:]):
                verdict = "<" if qn["acq_wall_s"] < 1.0 else ">="
                print(f"      {qn['setting']}: lrbfgs/cg time x"
                      f"{qn['acq_wall_s'] / cg['acq_wall_s']:.2f}, evaluations x"
                      f"{qn['cost_evaluations'] / cg['cost_evaluations']:.2f}, value "
                      f"{qn['acq_value'] - cg['acq_value']:+.1e}; lrbfgs {verdict} 1 s",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
