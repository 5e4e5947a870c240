"""The control bases B_c the baselines train in, by name: ``identity``, ``best`` or a ``.npy``.

:func:`resolve_bases` turns ``--control-basis`` (with ``--run``, ``--sim-dim`` and
``--control-dim``) into the bases and the run's env keywords, refusing before any work a basis
that belongs to another robot, env, M or C, or one the env would refuse.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np


def resolve_bases(
    specs: list[str],
    env_id: str,
    run_dir: str | Path | None = None,
    sim_dim: int | None = None,
    control_dim: int | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Control bases by name: ``identity`` (first C columns of eye(M)), ``best`` (the
    best_basis.npy of RBBO run ``run_dir``) or a path to an (M, C) ``.npy``.

    M and C of ``identity`` are the run's when ``run_dir`` is given, else the first ``.npy``'s,
    else ``sim_dim`` and ``control_dim`` (``--sim-dim``, ``--control-dim``; default 20 and
    3). A ``sim_dim`` or ``control_dim`` given beside a run or a ``.npy`` of another M or C is
    refused: their bases belong to those. C = M is allowed (unlike in ``rbbo optimize``, whose
    Grassmannian Gr(M, M) is one point): a policy acting on all of B_r is the baseline that
    shows what the control space costs or buys. Returns the bases and the run's ``env_kwargs`` ({}
    without a run). Raises ValueError (RunDirectoryError for a bad run directory) naming the
    problem.
    """
    from ..store import RunDirectoryError, RunStore

    specs = [s.strip() for s in specs]
    dims = (20 if sim_dim is None else sim_dim, 3 if control_dim is None else control_dim)
    env_kwargs, store = {}, None
    if run_dir is not None:
        store = RunStore.open(run_dir, repair=False)
        settings, objective = store.config.get("rbbo") or {}, store.config.get("objective") or {}
        try:
            dims = (int(settings["sim_dim"]), int(settings["control_dim"]))
        except (KeyError, TypeError, ValueError):
            raise RunDirectoryError(f"{run_dir}/config.json has no sim_dim/control_dim") from None
        if sim_dim is not None and sim_dim != dims[0]:
            raise ValueError(f"--sim-dim {sim_dim} differs from run {run_dir}'s sim_dim "
                             f"{dims[0]}, the M its B_c was found in (leave --sim-dim out: "
                             "the run's is used)")  # fmt: skip
        if control_dim is not None and control_dim != dims[1]:
            raise ValueError(f"--control-dim {control_dim} differs from run {run_dir}'s "
                             f"control_dim {dims[1]}, the C of its B_c (leave --control-dim "
                             "out: the run's is used)")  # fmt: skip
        if objective.get("kind") != "env":
            raise ValueError(f"run {run_dir} optimised a {objective.get('kind') or 'non-env'} "
                             "objective, not an env: its bases belong to no robot")  # fmt: skip
        if objective.get("env_id") != env_id:
            raise ValueError(f"run {run_dir} optimised {objective.get('env_id')}, not {env_id}")
        env_kwargs = dict(objective.get("env_kwargs") or {})
    bases: dict[str, np.ndarray] = {}
    for spec in specs:
        if spec == "best":
            if store is None:
                raise ValueError("--control-basis best needs --run DIR (an RBBO run directory)")
            bases["best"] = store.best_basis()
            _expect_run_space(store, env_id, env_kwargs, dims)
        elif spec.endswith(".npy"):
            try:
                # (no shell expands a ~ inside the comma list of --control-basis)
                b = np.load(os.path.expanduser(spec), allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise ValueError(f"cannot read control basis {spec}: {exc}") from None
            if b.ndim != 2 or b.shape[0] < b.shape[1]:
                raise ValueError(f"control basis {spec} has shape {b.shape}, expected (M, C)")
            if sim_dim is not None and b.shape[0] != sim_dim:
                raise ValueError(f"control basis {spec} has M = {b.shape[0]} rows, not "
                                 f"--sim-dim {sim_dim}")  # fmt: skip
            if control_dim is not None and b.shape[1] != control_dim:
                raise ValueError(f"control basis {spec} has C = {b.shape[1]} columns, not "
                                 f"--control-dim {control_dim}")  # fmt: skip
            if not np.all(np.isfinite(b)):
                raise ValueError(f"control basis {spec} contains non-finite values")
            sv = np.linalg.svd(b, compute_uv=False)
            if not sv[-1] > 1e-10 * sv[0]:  # as the env's orthonormalize=True (before any work)
                raise ValueError(
                    f"control basis {spec} is rank-deficient (singular values "
                    f"{np.array2string(sv, precision=3)}): its C columns must span C directions"
                )
            if Path(spec).stem in {*bases, *specs}:
                raise ValueError(f"two control bases are named {Path(spec).stem!r}")
            bases[Path(spec).stem] = b
            dims = b.shape if store is None and len(bases) == 1 else dims
        elif spec != "identity":
            raise ValueError(f"unknown control basis {spec!r}; use identity, best or PATH.npy")
    if "identity" in specs:
        if dims[0] < dims[1]:  # (only --sim-dim / --control-dim given so can be)
            raise ValueError(f"--sim-dim {dims[0]} is below C = {dims[1]}, the identity "
                             "basis's columns")  # fmt: skip
        bases = {"identity": np.eye(dims[0])[:, : dims[1]], **bases}
    return bases, env_kwargs


def _expect_run_space(store, env_id: str, env_kwargs: dict, dims: tuple[int, int]) -> None:
    """Refuse a run's B_c when the env now builds another simulation space than the run's."""
    from ..objective import EnvObjective

    recorded = (store.config.get("objective") or {}).get("simulation_space")
    if recorded is not None:
        objective = EnvObjective(env_id, dims[0], dims[1], env_kwargs=env_kwargs)
        objective.expect_simulation_space(recorded)
