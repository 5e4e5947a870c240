"""Re-express the control spaces stored in RBBO runs in the machine-independent B_r.

Until softrom's cache version 4, a robot's simulation space B_r took each vibration mode's
sign from the machine's BLAS kernel (a symmetric body's modes have two largest entries of
equal size and opposite sign), so a B_c stored in a run meant another actuation on a machine
with other kernels. ``build_subspace`` now picks every mode's basis by a fixed rule
(:func:`softrom_gym.rom.eigen.canonical_eigenvectors`). This script carries the bases
that a run recorded in an old B_r into the new one, B_c' = T B_c with
T = B_new^T M B_old (deformation block), which is the same full-space actuation; it refuses
when the two spaces differ by more than a rotation (T not orthogonal).

The old B_r must be built by the code that made the run, on a machine with the same BLAS
kernels. For ``docs/reproduction-45m`` (its runs reproduce bit for bit with OpenBLAS's
Haswell kernels and softrom at 60a8781; checked on an evaluation of each run):

    git archive 60a8781 softrom_gym | tar -x -C /tmp/old
    OPENBLAS_CORETYPE=Haswell python -c "... build_subspace(robot, M, cache=False) ..."
        -> OLD/<Benchmark>-M<M>.npz with arrays basis (3N, M + 6) and mass (N,)
    python benchmarks/migrate_run_bases.py --old OLD docs/reproduction-45m/runs/*

Each run gets ``migration.json`` (the sign changes, the largest deviation of T from
orthogonal). Confirmations recorded before it were measured in the old model; measure them
again with ``rbbo confirm RUN``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np

import softrom_gym  # noqa: F401  (registers the envs)
from rbbo.store import RunStore

_IDENTITY_KIND = "confirm-init"


def transform(old: np.ndarray, new: np.ndarray, mass: np.ndarray) -> tuple[np.ndarray, float]:
    """T (M x M) with B_c' = T B_c, and max |T^T T - I|."""
    m3 = np.repeat(np.asarray(mass, dtype=float), 3)
    t = new[:, 6:].T @ (m3[:, None] * old[:, 6:])
    return t, float(np.abs(t.T @ t - np.eye(t.shape[0])).max())


def migrate(run: Path, old_dir: Path, tolerance: float = 1e-8) -> dict:
    config = json.loads((run / "config.json").read_text())
    if (run / "migration.json").exists():
        raise SystemExit(f"{run} was migrated already (migration.json)")
    env_id = config["objective"]["env_id"]
    sim_dim = int(config["rbbo"]["sim_dim"])
    kwargs = config["objective"].get("env_kwargs") or {}
    env = gym.make(env_id, sim_dim=sim_dim, **kwargs)
    new = np.asarray(env.unwrapped.subspace.basis)
    env.close()
    name = env_id.split("/")[-1]
    if not (old_dir / f"{name}-M{sim_dim}.npz").exists():
        raise SystemExit(f"{run}: --old {old_dir} has no {name}-M{sim_dim}.npz; nothing changed")
    data = np.load(old_dir / f"{name}-M{sim_dim}.npz")
    t, error = transform(data["basis"], new, data["mass"])
    if error > tolerance:
        raise SystemExit(f"{run}: the old and new B_r span different spaces (|T^T T - I| = "
                         f"{error:.1e}); nothing changed")  # fmt: skip
    identity = np.eye(sim_dim)[:, : int(config["rbbo"]["control_dim"])]

    def carry(basis) -> list:
        b = np.asarray(basis, dtype=float)
        if np.array_equal(b, identity):
            return b.tolist()  # the same span after any sign change: keep it exact
        return (t @ b).tolist()

    store = RunStore.open(run)
    lines = (run / "history.jsonl").read_text().splitlines()
    # proposals.jsonl too: a resumed run evaluates the proposals in flight from it
    for path in (run / "history.jsonl", run / "proposals.jsonl"):
        if not path.exists():  # (runs from before proposals were recorded have none)
            continue
        out = []
        for line in path.read_text().splitlines():
            record = json.loads(line)
            record["basis"] = carry(record["basis"])
            out.append(json.dumps(record))
        path.write_text("\n".join(out) + "\n")
    if (run / "best_basis.npy").exists():
        store.save_best(np.asarray(carry(np.load(run / "best_basis.npy"))))
    summary = store.summary()
    if summary and summary.get("best_basis") is not None:
        summary["best_basis"] = carry(summary["best_basis"])
        store.write_summary(summary)
    # The run now lives in the canonical B_r: record its fingerprint, so that resuming it in
    # a space built otherwise is refused (rbbo.objective.SimulationSpaceMismatch).
    record_simulation_space(run)
    note = {
        "what": "bases re-expressed in the machine-independent B_r (softrom cache version 4)",
        "sign_changes": [int(i) for i in np.flatnonzero(np.diag(t) < 0)],
        "orthogonality_error": error,
        "confirmations_before": sum(json.loads(x)["kind"].startswith("confirm") for x in lines),
    }
    (run / "migration.json").write_text(json.dumps(note, indent=2) + "\n")
    return note


def record_simulation_space(run: Path) -> list[float]:
    """Write the fingerprint of the env's B_r as built now into the run's config.json."""
    from rbbo.objective import EnvObjective

    path = run / "config.json"
    config = json.loads(path.read_text())
    spec = config["objective"]
    objective = EnvObjective(spec["env_id"], int(config["rbbo"]["sim_dim"]),
                             int(config["rbbo"]["control_dim"]),
                             env_kwargs=spec.get("env_kwargs") or {})  # fmt: skip
    spec["simulation_space"] = objective.simulation_space()
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(config, indent=2, sort_keys=True) + "\n")
    tmp.replace(path)
    return spec["simulation_space"]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--old", type=Path, required=True, help="folder of <Benchmark>-M<M>.npz")
    p.add_argument("runs", type=Path, nargs="+")
    args = p.parse_args(argv)
    if not args.old.is_dir():
        p.error(f"--old {args.old} is not a folder")
    for run in args.runs:
        if not (run / "config.json").exists() or not (run / "history.jsonl").exists():
            p.error(f"{run} has no config.json and history.jsonl: not an rbbo run")
        if "env_id" not in json.loads((run / "config.json").read_text())["objective"]:
            p.error(f"{run} is not a run of an env (no B_r): nothing to migrate")
    for run in args.runs:
        note = migrate(run, args.old)
        print(f"{run}: modes {note['sign_changes']} change sign "
              f"(|T^T T - I| = {note['orthogonality_error']:.1e})")  # fmt: skip


if __name__ == "__main__":
    main()
