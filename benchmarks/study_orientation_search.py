"""What a last search over the orientation of RBBO's recommendation would gain.

R depends on which basis of a subspace runs, not only on the subspace the GP models
(``check_basis_representatives.py``). This tries the cheapest fix on finished runs: evaluate
the recommended basis B and ``--rotations`` random B Q on ``--search-seeds`` seeds at T_max,
keep the best, and measure the kept basis and B side by side on ``--test-seeds`` other seeds
(disjoint from the search's and from the runs' own confirmation seeds, so that picking the
best of K + 1 noisy means does not inflate the gain). It prints each run's R of B and of the
kept basis, and the paired gain over the runs.

    python benchmarks/study_orientation_search.py RUN [RUN ...] --workers 2
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from _runs import random_rotations, run_objective

SEARCH_SEED0 = 500_000  # the search's seeds: 500000, 500001, ...
TEST_SEED0 = 2_000_000  # the test's: beyond every run's CRN and confirmation seeds


def study_run(run: Path, rotations: int, search_seeds: int, test_seeds: int) -> dict:
    objective, t_max, basis, settings = run_objective(run)
    rng = np.random.default_rng([settings["seed"], 77])
    candidates = [basis, *random_rotations(basis, rotations, rng)]
    search = [SEARCH_SEED0 + k for k in range(search_seeds)]
    means = [float(np.mean([objective(b, t_max, s) for s in search])) for b in candidates]
    kept = int(np.argmax(means))
    test = [TEST_SEED0 + k for k in range(test_seeds)]
    stored_r = [objective(basis, t_max, s) for s in test]
    kept_r = stored_r if kept == 0 else [objective(candidates[kept], t_max, s) for s in test]
    return {"run": str(run), "kept": kept, "search_means": means,
            "R_stored": float(np.mean(stored_r)), "R_kept": float(np.mean(kept_r))}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", type=Path, help="finished rbbo run directories")
    p.add_argument("--rotations", type=int, default=6, help="random B Q tried (default 6)")
    p.add_argument("--search-seeds", type=int, default=3, help="seeds of the search (default 3)")
    p.add_argument("--test-seeds", type=int, default=5, help="seeds of the test (default 5)")
    p.add_argument("--workers", type=int, default=1, help="runs studied at once (default 1)")
    p.add_argument("--json", action="store_true", help="one JSON object per run")
    args = p.parse_args()
    if args.rotations < 0 or min(args.search_seeds, args.test_seeds, args.workers) < 1:
        p.error(
            f"need --rotations >= 0 and --search-seeds, --test-seeds, --workers >= 1, got "
            f"{args.rotations}, {args.search_seeds}, {args.test_seeds}, {args.workers}"
        )
    for run in args.runs:
        if not (run / "best_basis.npy").exists():
            p.error(f"{run} has no best_basis.npy: not a finished rbbo run")
    start = time.perf_counter()
    jobs = [(run, args.rotations, args.search_seeds, args.test_seeds) for run in args.runs]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(study_run, *zip(*jobs, strict=True)))
    gains = []
    for row in rows:
        gain = 100.0 * (row["R_kept"] / row["R_stored"] - 1.0)
        gains.append(gain)
        if args.json:
            print(json.dumps({**row, "gain_percent": gain}))
        else:
            print(f"{row['run']}: R of B {row['R_stored']:.4f}, kept rotation {row['kept']} "
                  f"(0: B itself) {row['R_kept']:.4f}, {gain:+.1f} %")  # fmt: skip
    if not args.json:
        sd = np.std(gains, ddof=1) if len(gains) > 1 else float("nan")
        print(f"gain over {len(gains)} runs: {np.mean(gains):+.1f} ± {sd:.1f} % (mean ± sample "
              f"sd); {time.perf_counter() - start:.0f} s")  # fmt: skip


if __name__ == "__main__":
    main()
