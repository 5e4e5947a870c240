"""How much R depends on which basis of a subspace runs, against how much the seed moves it.

RBBO's kernel sees span(B_c) only (B_c B_c^T), but an episode sees the matrix: the env bounds
each of the C coordinates of f_c and the planners sample and clip per coordinate, so B_c and
B_c Q (Q orthogonal, the same subspace) reach different forces. This measures R at T_max for
a run's recommended basis as stored, as ``rbbo.grassmann.canonical`` represents it (what RBBO
evaluates since f36e937) and under ``--rotations`` random rotations Q, each on the same
``--seeds`` (common random numbers), and prints the spread over representatives beside the
spread over seeds.

    python benchmarks/check_basis_representatives.py                       # the committed runs
    python benchmarks/check_basis_representatives.py runs/quickstart --seeds 5
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _runs import random_rotations, run_objective

from rbbo.grassmann import canonical, projection_distance

COMMITTED = Path(__file__).resolve().parents[1] / "docs" / "reproduction-45m" / "runs"


def representatives(basis: np.ndarray, rotations: int, seed: int) -> dict[str, np.ndarray]:
    """The stored basis, its canonical representative and ``rotations`` random B Q."""
    reps = {"stored": basis, "canonical": canonical(basis)}
    rotated = random_rotations(basis, rotations, np.random.default_rng(seed))
    reps.update({f"rotated {k}": b for k, b in enumerate(rotated)})
    return reps


def measure(run: Path, rotations: int, seeds: list[int], as_json: bool = False) -> None:
    objective, t_max, basis, _ = run_objective(run)
    if not as_json:
        print(f"{run.name}: best basis of {run}, T = {t_max:g} s, seeds {seeds}")
    start = time.perf_counter()
    values = {}
    for name, b in representatives(basis, rotations, seed=7).items():
        assert projection_distance(b, basis) < 1e-6  # one subspace
        row = [objective(b, t_max, s) for s in seeds]
        values[name] = row
        if not as_json:
            text = "  ".join(f"{v:.4f}" for v in row)
            print(f"  {name:<11} {text}   mean {np.mean(row):.4f}")
    r = np.asarray(list(values.values()))  # (representatives, seeds)
    if as_json:
        print(json.dumps({"run": str(run), "T": t_max, "seeds": seeds, "R": values,
                          "sd_over_representatives": float(r.std(axis=0, ddof=1).mean()),
                          "sd_over_seeds": float(r.std(axis=1, ddof=1).mean())}))  # fmt: skip
        return
    print(f"  sd over representatives (mean over seeds) {r.std(axis=0, ddof=1).mean():.4f}; "
          f"sd over seeds (mean over representatives) {r.std(axis=1, ddof=1).mean():.4f}; "
          f"representative means {r.mean(axis=1).min():.4f}..{r.mean(axis=1).max():.4f} "
          f"({time.perf_counter() - start:.0f} s)")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="*", type=Path,
                   help="run directories (default: the committed BeamWalk and CrossSwim BOCA "
                   "runs of docs/reproduction-45m)")  # fmt: skip
    p.add_argument("--rotations", type=int, default=4, help="random B Q (default 4)")
    p.add_argument("--seeds", type=int, default=3, help="episode seeds (default 3)")
    p.add_argument("--json", action="store_true", help="one JSON object per run")
    args = p.parse_args()
    if args.seeds < 2 or args.rotations < 0:  # an sd over seeds needs two
        p.error(f"need --seeds >= 2 and --rotations >= 0, got {args.seeds}, {args.rotations}")
    runs = args.runs or [COMMITTED / "BeamWalk-v0-boca", COMMITTED / "CrossSwim-v0-boca"]
    for run in runs:
        if not (run / "best_basis.npy").exists():
            p.error(f"{run} has no best_basis.npy: not a finished rbbo run")
        measure(run, args.rotations, [1001 + k for k in range(args.seeds)], args.json)


if __name__ == "__main__":
    main()
