"""BOCA's recommendation and its T_max floor on a synthetic objective with a known optimum.

Runs RBBO with BOCA (T in [--t-min, --t-max]) on :class:`rbbo.SyntheticObjective` (M = 20,
C = 3 by default, R = 1 at its optimum, 0.094 at the identity) for several seeds and budgets,
and scores the recommendation by its noise-free R at T_max, under two recommendation rules:

- ``T_max only``: the evaluated basis with the highest posterior mean at z = 1 among those
  evaluated at T_max (the rule before 2026-12-05);
- ``any T``: the same over every evaluated basis, whatever T it ran at (the rule now).

``--no-floor`` switches off BOCA's T_max floor (rule 4 of :mod:`rbbo.boca`), as it was
before the same date. Each line: the mean noise-free R of each rule's recommendation over the
seeds, how many evaluations ran at T_max, the simulated seconds evaluated (sum of T), and in
how many seeds the current rule's recommendation is a point of the initial design.

    python benchmarks/study_boca_recommendation.py              # floor on (as shipped)
    python benchmarks/study_boca_recommendation.py --no-floor   # as before the floor
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rbbo import RBBO, RBBOConfig, SyntheticObjective, boca


def _t_max_only(opt: RBBO):
    cands = [e for e in opt.evaluations if e.status == "ok" and math.isclose(e.T, opt.config.t_max)]
    mu, _ = opt.fit().predict(np.stack([e.basis for e in cands]), 1.0)
    return cands[int(np.argmax(mu))]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--iterations", type=int, nargs="+", default=[10, 20, 40])
    p.add_argument("--sim-dim", type=int, default=20)
    p.add_argument("--control-dim", type=int, default=3)
    p.add_argument("--t-min", type=float, default=2.0)
    p.add_argument("--t-max", type=float, default=4.0)
    p.add_argument("--noise", type=float, default=0.05)
    p.add_argument("--no-floor", action="store_true", help="BOCA without its T_max floor")
    args = p.parse_args()
    if args.seeds < 1 or min(args.iterations) < 1 or not 0 < args.t_min < args.t_max:
        p.error(f"need --seeds, --iterations >= 1 and 0 < --t-min < --t-max, got {args.seeds}, "
                f"{args.iterations}, {args.t_min:g}, {args.t_max:g}")  # fmt: skip
    try:  # the objective names a bad M, C or noise
        SyntheticObjective(args.sim_dim, args.control_dim, noise=args.noise)
    except ValueError as exc:
        p.error(str(exc))
    if args.no_floor:
        boca.BOCAFidelity.below_floor = lambda self, pending=(): False
    m, c = args.sim_dim, args.control_dim
    print(f"Gr({m}, {c}), T in [{args.t_min:g}, {args.t_max:g}] s, noise {args.noise:g}, "
          f"{args.seeds} seeds, floor {'off' if args.no_floor else 'on'}; the identity's R is "
          f"{SyntheticObjective(m, c).value(np.eye(m)[:, :c]):.3f}")  # fmt: skip
    for iterations in args.iterations:
        rows = []
        for seed in range(args.seeds):
            objective = SyntheticObjective(m, c, noise=args.noise, t_max=args.t_max)
            config = RBBOConfig(m, c, fidelity="boca", t_min=args.t_min, t_max=args.t_max,
                                n_init=3, max_evaluations=iterations, n_confirm=0, seed=seed,
                                acq_random=256, acq_starts=4, gp_restarts=2)  # fmt: skip
            opt = RBBO(config)
            opt.run(objective, confirm=False)
            now = opt.recommend()
            rows.append((
                objective.value(_t_max_only(opt).basis), objective.value(now.basis),
                sum(math.isclose(e.T, args.t_max) for e in opt.evaluations),
                sum(e.T for e in opt.evaluations), now.kind == "initial",
            ))  # fmt: skip
        r = np.array(rows, dtype=float)
        print(f"{iterations:3d} evaluations: R of the recommendation, T_max only "
              f"{r[:, 0].mean():.3f}, any T {r[:, 1].mean():.3f}; at T_max {r[:, 2].mean():.1f}, "
              f"sum T {r[:, 3].mean():.1f} s; recommendation from the design in "
              f"{int(r[:, 4].sum())}/{args.seeds}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
