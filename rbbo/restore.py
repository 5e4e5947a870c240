"""Rebuilding an :class:`~rbbo.optimizer.RBBO` from its run directory (:meth:`RBBO.resume`).

The run's settings come from config.json and its evaluations from history.jsonl (a line that
parses but belongs to no evaluation of this run is refused, naming it); the search proposals
in proposals.jsonl that the history does not hold, those in flight when the run stopped, are
handed out again first; and the next GP fit starts from the hyperparameters the latest
recorded proposal's fit found, so that a run told in proposal order goes on as the
uninterrupted run would have.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from .config import CONFIRM_KINDS, Proposal, RBBOConfig
from .gp import GPHyperparameters, GrassmannGP
from .grassmann import validate_basis
from .store import Evaluation, RunDirectoryError, RunStore

if TYPE_CHECKING:
    from .optimizer import RBBO

__all__ = ["resume"]


def resume(cls: type[RBBO], path, *, read_only: bool = False) -> RBBO:
    """The optimiser of run directory ``path``, rebuilt from its records (see
    :meth:`RBBO.resume`, which calls this with its class)."""
    from .optimizer import CONFIG_VERSION  # (here: the optimizer imports this module)

    store = RunStore.open(path, repair=not read_only)
    _check_version(store, CONFIG_VERSION)
    settings = store.config.get("rbbo")
    if not isinstance(settings, dict):
        raise RunDirectoryError(f"{store.path}/config.json has no 'rbbo' settings")
    try:
        config = RBBOConfig(**settings)
    except (TypeError, ValueError) as exc:
        raise RunDirectoryError(f"{store.path}/config.json has invalid settings: {exc}") from exc
    for key in ("objective", "problem", "execution"):
        # (a hand edit: their readers look keys up in them; absent in runs made without one)
        value = store.config.get(key)
        if value is not None and not isinstance(value, dict):
            raise RunDirectoryError(f"{store.path}/config.json has invalid settings: {key!r} "
                                    f"must be a JSON object, got {value!r}")  # fmt: skip
    _check_problem(store)
    opt = cls(config, store=store, objective_spec=store.config.get("objective"))
    history = store.history()
    _check_history(store, history, config)
    for evaluation in history:
        opt._record(evaluation, persist=False)
    opt._restored = _restore_proposals(store, config, {e.index for e in history})
    indices = [e.index for e in history] + [p.index for p in opt._restored]
    if indices:
        opt._next_index = max(indices) + 1
    if history:
        opt._elapsed_offset = max(e.elapsed_s for e in history)
    _warm_start_from(opt, history)
    return opt


def _check_version(store: RunStore, current: int) -> None:
    """Refuse a config.json that a newer rbbo wrote (``version`` above ``current``): its
    settings and records may mean what this code cannot know, and a resume would write its
    own into them. A run without a version (made before it was recorded) is read as the
    first."""
    version = store.config.get("version")
    if version is None:
        return
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise RunDirectoryError(f"{store.path}/config.json has invalid settings: 'version' "
                                f"must be a positive integer, got {version!r}")  # fmt: skip
    if version > current:
        raise RunDirectoryError(f"{store.path}/config.json is version {version}, written by a "
                                f"newer rbbo (this one reads versions up to {current}): "
                                "upgrade rbbo to use this run")  # fmt: skip


def _check_problem(store: RunStore) -> None:
    """Refuse a hand-edited ``problem`` (what ``rbbo optimize`` stored for the report's
    problem and N columns) whose values the report could not print, naming the value."""
    problem = store.config.get("problem") or {}
    env_id, nodes = problem.get("env_id"), problem.get("N")
    if env_id is not None and not isinstance(env_id, str):
        raise RunDirectoryError(f"{store.path}/config.json has invalid settings: problem "
                                f"env_id must be a string, got {env_id!r}")  # fmt: skip
    if nodes is not None and (isinstance(nodes, bool) or not isinstance(nodes, int)
                              or nodes < 0):  # fmt: skip
        raise RunDirectoryError(f"{store.path}/config.json has invalid settings: problem N "
                                f"must be a count of nodes (an integer >= 0) or null, got "
                                f"{nodes!r}")  # fmt: skip


def _check_history(store: RunStore, history: list[Evaluation], config: RBBOConfig) -> None:
    """Refuse, naming the line, a history line that parses but does not belong to this run
    (a basis of another shape or not orthonormal, an index recorded twice): an edited file."""
    seen: dict[int, int] = {}
    for number, evaluation in enumerate(history, start=1):  # (one line per evaluation)
        where = f"{store.history_path} line {number} is corrupted"
        try:
            validate_basis(evaluation.basis, config.sim_dim, config.control_dim, name="its basis")
        except ValueError as exc:
            raise RunDirectoryError(f"{where}: {exc}") from exc
        if evaluation.index in seen:
            raise RunDirectoryError(f"{where}: evaluation {evaluation.index} is recorded on "
                                    f"line {seen[evaluation.index]} already")  # fmt: skip
        seen[evaluation.index] = number


def _restore_proposals(store: RunStore, cfg: RBBOConfig, recorded: set[int]) -> list[Proposal]:
    """The search proposals DIR/proposals.jsonl holds and the history does not: those
    in flight when the run stopped, oldest first."""
    out: dict[int, Proposal] = {}
    for record in store.proposals():
        index = record["index"]
        if index in recorded or index in out:
            continue
        try:
            basis = np.asarray(record["basis"], dtype=float)
            if basis.shape != (cfg.sim_dim, cfg.control_dim):
                raise ValueError(f"basis of shape {basis.shape}, the run's is "
                                 f"{(cfg.sim_dim, cfg.control_dim)}")  # fmt: skip
            info = {k: record[k] for k in ("gp", "duplicates_skipped") if k in record}
            proposal = Proposal(index, basis, float(record["T"]),
                                tuple(int(x) for x in record["seeds"]), str(record["kind"]),
                                info)  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise RunDirectoryError(f"{store.path}/proposals.jsonl: proposal {index} is "
                                    f"unreadable: {exc}") from exc  # fmt: skip
        if proposal.kind not in CONFIRM_KINDS:
            out[index] = proposal
    return [out[i] for i in sorted(out)]


def _warm_start_from(opt: RBBO, history: list[Evaluation]) -> None:
    """Start the next GP fit from the hyperparameters of the latest recorded proposal's
    fit, as the session that made it would have: with one worker a resumed run then
    proposes what the uninterrupted run proposed (records made before the hyperparameters
    were recorded start from the defaults)."""
    fitted = [(e.index, e.gp) for e in history
              if e.gp is not None and e.kind not in CONFIRM_KINDS]  # fmt: skip
    # (a proposal still in flight when the run stopped was fitted after those told)
    fitted += [(p.index, p.info["gp"]) for p in opt._restored if p.info.get("gp")]
    if not fitted:
        return
    record: dict[str, Any] = max(fitted, key=lambda x: x[0])[1]  # (its keys checked here)
    try:
        hyperparameters = GPHyperparameters(**record)
    except TypeError:
        return  # another version's record: the defaults, as before the record existed
    cfg = opt.config
    opt._gp = GrassmannGP(cfg.sim_dim, cfg.control_dim, fidelity=opt._boca is not None,
                          n_restarts=cfg.gp_restarts)  # fmt: skip
    opt._gp.hyperparameters = hyperparameters
