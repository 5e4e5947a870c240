"""RBBO against the optimisers a user would otherwise reach for, at equal evaluation counts.

Part (a): synthetic Grassmann objectives with a known optimum (:class:`rbbo.SyntheticObjective`,
R = ||B^T U||_F^2 / C in [0, 1], 1 at span U, plus seed noise with common random numbers),
several seeds each. Methods: RBBO (GP-UCB on Gr(M, C), plain BO at T_max), random search on
Gr(M, C) (Haar), and CMA-ES (the ``cma`` package) on an unconstrained M x C matrix
orthonormalised by QR, its search distribution centred on the identity. RBBO and random
search evaluate the identity basis first; CMA-ES's evaluations are draws around it (it never
evaluates the identity itself).

The score after k evaluations is the noise-free R of the point each method would pick so far
(its best *observed* value), so noise cannot flatter anyone. Wall time includes each method's
own overhead; the objective here costs nothing, so RBBO's model time is fully visible (on the
real benchmarks an evaluation takes tens of seconds and that overhead vanishes).

    python benchmarks/bench_rbbo_vs.py                     # table + runs/bench_rbbo_vs.png
    python benchmarks/bench_rbbo_vs.py --seeds 3 --evaluations 30 --json

Part (b): one real benchmark (an :class:`rbbo.EnvObjective`, the MPC controller's task reward
per second after a settle time) at a short fidelity T. All three methods run in process,
serially, on the same objective at the same T (RBBO with T_max = T, plain BO, so every
evaluation is at that fidelity), with the same evaluation count, each starting from the
identity basis, with common random numbers: every evaluation of the method run with seed s
uses MPC seed s. There is no noise-free value, so each method run is scored by re-evaluating
the basis it would pick (its best *observed* one, for every method alike) on
``--confirm-seeds`` fresh MPC seeds 10**6 + k that no search used, at the same T: the
"confirmed R". The identity is confirmed on the same fresh seeds (R_init) for reference.
Reported per method: confirmed R (mean ± sd over the method-run seeds), how many seeds it
beats R_init and how many it is the best of the three (ties count for each), and its own wall
time (evaluations included, confirmation not). The plot shows the best observed R (search
seeds) against evaluations and against wall time. CrossSwim-v0 at T = 3 s costs about 2.6 s
an evaluation on one core, so the defaults (16 evaluations, 3 seeds, 3 confirm seeds: about
175 evaluations) take roughly 8-10 minutes. Caveat: ``rbbo.baselines.cma_es`` caps CMA-ES's
population at a quarter of the evaluations (at least 4), so at 16 evaluations it runs 4
generations of 4: little room to adapt its step size or covariance.

    python benchmarks/bench_rbbo_vs.py --real softrom_gym/CrossSwim-v0   # part (b) only
    python benchmarks/bench_rbbo_vs.py --real softrom_gym/CrossSwim-v0 --t 3 --settle-time 1 \
        --evaluations 16 --seeds 3 --confirm-seeds 3 --png runs/bench_rbbo_vs_real.png
    python benchmarks/bench_rbbo_vs.py --part both --json   # (a), then (b) on CrossSwim-v0

``--part`` is ``a`` by default, ``b`` when ``--real`` is given. ``--seeds`` and
``--evaluations`` default to 5 and 40 for (a), 3 and 16 for (b). ``--png`` names the plot of
the part being run (with ``--part both``, of (a); ``--png-real`` names (b)'s, default
runs/bench_rbbo_vs_real.png).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from rbbo import RBBO, RBBOConfig, SyntheticObjective
from rbbo.baselines import cma_es, random_search
from rbbo.grassmann import identity_basis

sys.path.insert(0, str(Path(__file__).parent))
from _results import save_figure

PROBLEMS = [(10, 2), (20, 3)]
T_MAX = 10.0
REAL_DEFAULT = "softrom_gym/CrossSwim-v0"
DEFAULTS = {"a": {"seeds": 5, "evaluations": 40}, "b": {"seeds": 3, "evaluations": 16}}


def run_rbbo(objective, m, c, n, seed, *, t=T_MAX, n_init=4):
    config = RBBOConfig(m, c, n_init=n_init, seed=seed, max_evaluations=n, n_confirm=0, t_max=t)
    opt = RBBO(config)
    start = time.perf_counter()
    opt.run(objective)
    wall = time.perf_counter() - start
    evals = opt.evaluations
    # plain BO: every evaluation at T_max = t, on the CRN seed of this run only
    assert config.fidelity == "bo" and config.crn_seeds == (seed,)
    assert all(e.T == t for e in evals), "RBBO evaluated at another fidelity"
    # elapsed_s is measured from the optimiser's creation: rescale to this run's clock
    scale = wall / max(evals[-1].elapsed_s, 1e-12)
    return [(e.basis, e.R, e.elapsed_s * scale) for e in evals]


def run_random(objective, m, c, n, seed, *, t=T_MAX, n_init=None):
    return random_search(objective, m, c, n, T=t, seeds=(seed,), rng=[seed, 7])


def run_cma(objective, m, c, n, seed, *, t=T_MAX, n_init=None):
    return cma_es(objective, m, c, n, T=t, seeds=(seed,), seed=seed)


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


def part_a(args, seeds: int, n: int, png: Path) -> None:
    results = {}
    for m, c in PROBLEMS:
        for name, method in METHODS.items():
            curves, walls = [], []
            for seed in range(seeds):
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
        print(f"{seeds} seeds, {n} evaluations each, noise {args.noise}; score = noise-free "
              "R of the best-observed point (optimum 1)")  # fmt: skip
        print(f"{'problem':>9} {'method':>7} {f'R after {min(10, n)}':>11} "
              f"{f'after {min(20, n)}':>9} "
              f"{'final':>13} {'wins':>5} {'wall s':>7}")  # fmt: skip
        for m, c in PROBLEMS:
            finals = {k: results[(m, c, k)][0][:, -1] for k in METHODS}
            for name in METHODS:
                curves, walls = results[(m, c, name)]
                wins = int(np.sum([finals[name][s] >= max(finals[k][s] for k in METHODS)
                                   for s in range(seeds)]))  # fmt: skip
                print(f"{f'Gr({m},{c})':>9} {name:>7} {curves[:, min(9, n - 1)].mean():>11.3f} "
                      f"{curves[:, min(19, n - 1)].mean():>9.3f} "
                      f"{curves[:, -1].mean():>6.3f}±{curves[:, -1].std():.3f} "
                      f"{wins:>5} {walls[:, -1].mean():>7.2f}")  # fmt: skip
    plot(results, seeds, png)
    if not args.json:
        print(f"plot: {png}")


# -- part (b): a real benchmark at a short fidelity -------------------------------------------
def best_observed(evaluations):
    """Best observed R after each evaluation, the wall times, and the final best basis."""
    best_r, best_basis, values, walls = -np.inf, None, [], []
    for basis, r, wall in evaluations:
        if r is not None and np.isfinite(r) and r > best_r:
            best_r, best_basis = r, basis
        values.append(best_r)
        walls.append(wall)
    return np.array(values), np.array(walls), best_basis


class Confirmer:
    """R of a basis averaged over the fresh seeds, at the benchmark's T (cached per subspace)."""

    def __init__(self, objective, t: float, seeds):
        self.objective, self.t, self.seeds = objective, t, tuple(seeds)
        self._cache: dict[bytes, float] = {}
        self.wall_s = 0.0

    def __call__(self, basis) -> float:
        b = np.asarray(basis, dtype=float)
        key = np.round(b @ b.T, 8).tobytes()  # the subspace, not its representative
        if key not in self._cache:
            start = time.perf_counter()
            self._cache[key] = float(np.mean([self.objective(b, self.t, s) for s in self.seeds]))
            self.wall_s += time.perf_counter() - start
        return self._cache[key]


def part_b(args, env_id: str, seeds: int, n: int, png: Path) -> None:
    from rbbo.objective import EnvObjective

    m, c, t = args.sim_dim, args.control_dim, args.t
    if not t > args.settle_time:
        raise SystemExit(f"--t {t} must exceed --settle-time {args.settle_time}")
    if n <= args.n_init + 1:  # the identity and n_init points, then one acquisition at least
        raise SystemExit(f"--evaluations {n} must exceed RBBO's initial design (--n-init + 1)")

    def make():
        return EnvObjective(env_id, m, c, controller=args.controller, settle_time=args.settle_time)

    fresh = [10**6 + k for k in range(args.confirm_seeds)]  # no search uses these seeds
    assert not set(fresh) & set(range(seeds))
    confirm = Confirmer(make(), t, fresh)
    problem = f"{env_id} Gr({m},{c}) T={t:g}s"
    if not args.json:
        print(f"{problem}: confirming the identity on {len(fresh)} fresh seeds ...", flush=True)
    r_init = confirm(identity_basis(m, c))
    results, rows = {}, []
    for seed in range(seeds):
        for name, method in METHODS.items():
            objective = make()  # each method run builds its own env (in its wall time)
            values, walls, basis = best_observed(
                method(objective, m, c, n, seed, t=t, n_init=args.n_init)
            )
            final = confirm(basis)
            row = {
                "problem": problem,
                "method": name,
                "seed": seed,
                "evaluations": len(values),
                "final": final,
                "best_observed": float(values[-1]),
                "wall_s": float(walls[-1]),
                "R_init": r_init,
                "T": t,
                "settle_time": args.settle_time,
                "confirm_seeds": fresh,
            }
            rows.append(row)
            results.setdefault(name, []).append((values, walls, final))
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(
                    f"  seed {seed} {name:>6}: best observed {values[-1]:.4f}, confirmed "
                    f"{final:.4f} (R_init {r_init:.4f}), {walls[-1]:.0f} s",
                    flush=True,
                )
    if not args.json:
        print(
            f"\n{problem}, {args.controller}, settle {args.settle_time:g} s, {seeds} seeds x "
            f"{n} evaluations (CRN: run seed s uses MPC seed s); score = R per s of the "
            f"best-observed basis re-evaluated on {len(fresh)} fresh seeds {fresh[0]}.."
        )
        print(f"R_init (identity, same fresh seeds) = {r_init:.4f}")
        print(
            f"{'method':>7} {'best obs':>9} {'confirmed R':>15} {'vs init':>8} {'>init':>6} "
            f"{'wins':>5} {'wall s':>7}"
        )
        # a basis within round-off of another (RBBO re-proposing its incumbent) ties with it
        tol = 1e-6 * max(1.0, abs(r_init))
        finals = {k: np.array([r[2] for r in results[k]]) for k in METHODS}
        for name in METHODS:
            f = finals[name]
            obs = np.mean([r[0][-1] for r in results[name]])
            wall = np.mean([r[1][-1] for r in results[name]])
            best = [max(finals[k][s] for k in METHODS) for s in range(seeds)]
            wins = int(sum(f[s] >= best[s] - tol for s in range(seeds)))
            gain = 100 * (f.mean() / r_init - 1) if r_init > 0 else float("nan")
            print(
                f"{name:>7} {obs:>9.4f} {f.mean():>8.4f}±{f.std():.4f} {gain:>+7.1f}% "
                f"{int(np.sum(f > r_init + tol)):>6} {wins:>5} {wall:>7.1f}"
            )
        print(
            "best obs: on the search seed; confirmed: mean ± sd over run seeds; >init: seeds "
            "beating R_init; wins: seeds best of the three (ties count for each)"
        )
        print(f"(confirmation evaluations: {confirm.wall_s:.0f} s, not in any method's wall time)")
    plot_real(results, r_init, problem, seeds, png)
    if not args.json:
        print(f"plot: {png}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--part",
        choices=["a", "b", "both"],
        default=None,
        help="a: synthetic (default), b: --real env (default with --real)",
    )
    parser.add_argument("--seeds", type=int, default=None, help="(a) 5, (b) 3")
    parser.add_argument("--evaluations", type=int, default=None, help="(a) 40, (b) 16")
    parser.add_argument("--noise", type=float, default=0.02, help="(a) seed-noise scale")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--png",
        type=Path,
        default=None,
        help="plot of the part run (default runs/bench_rbbo_vs.png for (a))",
    )
    parser.add_argument(
        "--real",
        metavar="ENV_ID",
        default=None,
        help=f"(b) the env benchmark (implies --part b; default {REAL_DEFAULT})",
    )
    parser.add_argument("--t", type=float, default=3.0, help="(b) T, seconds")
    parser.add_argument("--settle-time", type=float, default=1.0, help="(b) seconds")
    parser.add_argument("--confirm-seeds", type=int, default=3, help="(b) fresh MPC seeds")
    parser.add_argument("--sim-dim", type=int, default=20, help="(b) M")
    parser.add_argument("--control-dim", type=int, default=3, help="(b) C")
    parser.add_argument("--controller", default="mppi", metavar="NAME",
                        help="(b): mppi, gn, a registered planner, or an import path "
                        "package.module:ClassName")  # fmt: skip
    parser.add_argument("--n-init", type=int, default=3, help="(b) RBBO's random initial points")
    parser.add_argument(
        "--png-real",
        type=Path,
        default=None,
        help="(b) plot with --part both (default runs/bench_rbbo_vs_real.png)",
    )
    args = parser.parse_args(argv)
    part = args.part or ("b" if args.real else "a")
    if args.real and part == "a":
        parser.error("--real is for part (b); use --part b or both")
    if args.confirm_seeds < 1:
        parser.error("--confirm-seeds must be >= 1")
    for name in ("seeds", "evaluations"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    if not 0 <= args.noise < np.inf:
        parser.error(f"--noise must be finite and >= 0, got {args.noise}")

    def budget(p):
        seeds, evaluations = args.seeds, args.evaluations
        return (DEFAULTS[p]["seeds"] if seeds is None else seeds,
                DEFAULTS[p]["evaluations"] if evaluations is None else evaluations)  # fmt: skip

    if part in ("b", "both"):
        # checked before part (a) runs, as usage errors: part_b's own SystemExit came after
        # (a)'s minutes under --part both, with exit status 1
        if not args.t > args.settle_time:
            parser.error(f"--t {args.t} must exceed --settle-time {args.settle_time}")
        if budget("b")[1] <= args.n_init + 1:
            parser.error(f"--evaluations {budget('b')[1]} must exceed RBBO's initial design "
                         f"(--n-init + 1 = {args.n_init + 1})")  # fmt: skip
    if part in ("a", "both"):
        part_a(args, *budget("a"), args.png or Path("runs/bench_rbbo_vs.png"))
    if part in ("b", "both"):
        png = args.png_real or (args.png if part == "b" else None)
        part_b(
            args,
            args.real or REAL_DEFAULT,
            *budget("b"),
            png or Path("runs/bench_rbbo_vs_real.png"),
        )


def plot(results, seeds: int, path: Path) -> None:
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
    fig.suptitle(f"RBBO vs random search vs CMA-ES, {seeds} seeds (mean ± sd)")
    save_figure(fig, path, dpi=110)


def plot_real(results, r_init: float, problem: str, seeds: int, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    for j, name in enumerate(METHODS):
        curves = np.array([r[0] for r in results[name]])
        walls = np.array([r[1] for r in results[name]])
        mean, sd = curves.mean(axis=0), curves.std(axis=0)
        x = np.arange(1, curves.shape[1] + 1)
        finals = np.array([r[2] for r in results[name]])
        label = f"{name} (confirmed {finals.mean():.3f}±{finals.std():.3f})"
        for ax, xs in ((axes[0], x), (axes[1], walls.mean(axis=0))):
            ax.plot(xs, mean, color=f"C{j}", label=label)
            ax.fill_between(xs, mean - sd, mean + sd, color=f"C{j}", alpha=0.15)
    for ax in axes:
        ax.axhline(r_init, color="k", ls="--", lw=1, label=f"identity, fresh seeds ({r_init:.3f})")
        ax.set_ylabel("best observed R (per s, search seeds)")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    axes[0].set_xlabel("evaluations")
    axes[1].set_xlabel("wall time (s, evaluations included)")
    axes[0].set_title("best observed R against evaluations")
    axes[1].set_title("against wall time (mean over seeds)")
    fig.suptitle(f"{problem}: RBBO vs random search vs CMA-ES, {seeds} seeds (mean ± sd)")
    save_figure(fig, path, dpi=110)


if __name__ == "__main__":
    main()
