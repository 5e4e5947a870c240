"""RBBO against the optimisers a user would otherwise reach for, at equal evaluation counts.

Part (a): synthetic Grassmann objectives with a known optimum (:class:`rbbo.SyntheticObjective`,
R = ||B^T U||_F^2 / C in [0, 1], 1 at span U, plus seed noise with common random numbers),
several seeds each. Methods: RBBO (GP-UCB on Gr(M, C), plain BO at T_max), random search on
Gr(M, C) (Haar), and CMA-ES (the ``cma`` package) on an unconstrained M x C matrix
orthonormalised by QR, started at the identity. All start from the identity basis.

The score after k evaluations is the noise-free R of the point each method would pick so far
(its best *observed* value), so noise cannot flatter anyone. Wall time includes each method's
own overhead; the objective here costs nothing, so RBBO's model time is fully visible (on the
real benchmarks an evaluation takes tens of seconds and that overhead vanishes).

    python benchmarks/bench_rbbo_vs.py                     # table + runs/bench_rbbo_vs.png
    python benchmarks/bench_rbbo_vs.py --seeds 3 --evaluations 30 --json

Part (b) (a real benchmark at a short fidelity) needs the controllers (issue 6) and is not
here yet.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from rbbo import RBBO, RBBOConfig, SyntheticObjective
from rbbo.baselines import cma_es, random_search

PROBLEMS = [(10, 2), (20, 3)]
T_MAX = 10.0


def run_rbbo(objective, m, c, n, seed):
    config = RBBOConfig(m, c, n_init=4, seed=seed, max_evaluations=n, n_confirm=0)
    opt = RBBO(config)
    start = time.perf_counter()
    opt.run(objective)
    wall = time.perf_counter() - start
    evals = opt.evaluations
    # elapsed_s is measured from the optimiser's creation: rescale to this run's clock
    scale = wall / max(evals[-1].elapsed_s, 1e-12)
    return [(e.basis, e.R, e.elapsed_s * scale) for e in evals]


def run_random(objective, m, c, n, seed):
    return random_search(objective, m, c, n, T=T_MAX, seeds=(seed,), rng=[seed, 7])


def run_cma(objective, m, c, n, seed):
    return cma_es(objective, m, c, n, T=T_MAX, seeds=(seed,), seed=seed)


METHODS = {"RBBO": run_rbbo, "random": run_random, "CMA-ES": run_cma}


def trace(objective, evaluations):
    """Noise-free value of the best-observed point after each evaluation, and wall times."""
    best_r, best_true, values, walls = -np.inf, np.nan, [], []
    for basis, r, wall in evaluations:
        if r is not None and r > best_r:
            best_r, best_true = r, objective.value(basis)
        values.append(best_true)
        walls.append(wall)
    return np.array(values), np.array(walls)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--evaluations", type=int, default=40)
    parser.add_argument("--noise", type=float, default=0.02)
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--png", type=Path, default=Path("runs/bench_rbbo_vs.png"))
    args = parser.parse_args(argv)
    n = args.evaluations
    results = {}
    for m, c in PROBLEMS:
        for name, method in METHODS.items():
            curves, walls = [], []
            for seed in range(args.seeds):
                objective = SyntheticObjective(m, c, optimum_seed=1000 + seed, noise=args.noise)
                values, wall = trace(objective, method(objective, m, c, n, seed))
                curves.append(values)
                walls.append(wall)
                if args.json:
                    print(json.dumps({"problem": f"Gr({m},{c})", "method": name, "seed": seed,
                                      "evaluations": n, "final": float(values[-1]),
                                      "wall_s": float(wall[-1])}), flush=True)  # fmt: skip
            results[(m, c, name)] = (np.array(curves), np.array(walls))
    if not args.json:
        print(f"{args.seeds} seeds, {n} evaluations each, noise {args.noise}; score = noise-free "
              "R of the best-observed point (optimum 1)")  # fmt: skip
        print(f"{'problem':>9} {'method':>7} {'R after 10':>11} {'after 20':>9} "
              f"{'final':>13} {'wins':>5} {'wall s':>7}")  # fmt: skip
        for m, c in PROBLEMS:
            finals = {k: results[(m, c, k)][0][:, -1] for k in METHODS}
            for name in METHODS:
                curves, walls = results[(m, c, name)]
                wins = int(np.sum([finals[name][s] >= max(finals[k][s] for k in METHODS)
                                   for s in range(args.seeds)]))  # fmt: skip
                print(f"{f'Gr({m},{c})':>9} {name:>7} {curves[:, 9].mean():>11.3f} "
                      f"{curves[:, min(19, n - 1)].mean():>9.3f} "
                      f"{curves[:, -1].mean():>6.3f}±{curves[:, -1].std():.3f} "
                      f"{wins:>5} {walls[:, -1].mean():>7.2f}")  # fmt: skip
    plot(results, args, args.png)
    if not args.json:
        print(f"plot: {args.png}")


def plot(results, args, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4 * len(PROBLEMS)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(PROBLEMS), 2, squeeze=False)
    for row, (m, c) in enumerate(PROBLEMS):
        for j, name in enumerate(METHODS):
            curves, walls = results[(m, c, name)]
            x = np.arange(1, curves.shape[1] + 1)
            mean, sd = curves.mean(axis=0), curves.std(axis=0)
            axes[row, 0].plot(x, mean, color=f"C{j}", label=name)
            axes[row, 0].fill_between(x, mean - sd, mean + sd, color=f"C{j}", alpha=0.15)
            axes[row, 1].plot(walls.mean(axis=0), mean, color=f"C{j}", label=name)
        axes[row, 0].set_title(f"Gr({m}, {c}): best-observed point, noise-free R")
        axes[row, 0].set_xlabel("evaluations")
        axes[row, 1].set_xlabel("wall time (s, objective free)")
        axes[row, 1].set_xscale("log")
        for ax in axes[row]:
            ax.set_ylabel("R (optimum 1)")
            ax.grid(alpha=0.3)
            ax.legend(loc="lower right")
    fig.suptitle(f"RBBO vs random search vs CMA-ES, {args.seeds} seeds (mean ± sd)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
