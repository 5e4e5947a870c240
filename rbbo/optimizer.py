"""RBBO: the paper's Algorithm "RBBO" as an ask/tell optimiser with asynchronous proposals.

::

    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    if __name__ == "__main__":  # workers are spawned processes, which import this script
        objective = SyntheticObjective(20, 3)  # objective(B_c, T, seed) -> float, picklable
        opt = RBBO.create("runs/demo", RBBOConfig(sim_dim=20, control_dim=3, max_evaluations=40))
        result = opt.run(objective, workers=2)
        # or drive it yourself:
        p = opt.ask(); opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))

- Initial design: the identity basis (the first C modes of B_r) at T_max, then ``n_init``
  Haar-random points of Gr(M, C) (with BOCA, alternately at T_min and T_max).
- Each proposal fits the GP (marginal likelihood, WhiteKernel noise) on all successful
  evaluations, adds the proposals still in flight as kriging-believer fantasies (observed at
  their posterior mean, so parallel workers are sent to different places), maximises GP-UCB
  at the target fidelity on the Grassmannian, and picks T by BOCA (``fidelity="boca"``) or
  uses T_max (``"bo"``).
- The GP models R as a function of the subspace (the kernel sees B_c B_c^T), as the paper
  does, but an episode runs the matrix the acquisition's optimiser stopped at: the env bounds
  each of the C coordinates of f_c and the planners sample and clip per coordinate, so
  B_c Q reaches other forces than B_c. Measured (``benchmarks/check_basis_representatives.py``)
  R moves 3-4x more over representatives of one subspace than over seeds, and the GP takes
  that for noise. Proposals near an incumbent start from its basis and keep its
  orientation; one fixed representative per subspace (``grassmann.canonical``) was tried and
  not kept (README, "Which basis of a subspace runs").
- Every evaluation uses the same seeds (common random numbers), so bases are compared under
  the same MPC noise. A repeat would return the same R, so a proposal within
  ``DUPLICATE_DISTANCE`` of a basis evaluated or in flight at the same T is replaced by the
  next-best local optimum of the acquisition, or failing those by a random point (its
  history records ``duplicates_skipped``). A proposal is handed out as soon as a worker is
  free, so with several workers the data a proposal sees depends on which evaluation
  finished first and two runs differ; with one worker (or ask/tell in a fixed order) a run
  repeats bitwise. With ``run(..., deterministic=True)`` results are told in the order they
  were proposed: a worker that finishes before an older evaluation waits for it, so proposal
  k sees the results of proposals 0 .. k - W and fantasies for the W - 1 after them (W
  workers) whatever the timing, and a run with a given W and evaluation count repeats
  bitwise.
- Recommendation: among the evaluated bases (at any T), the one with the highest GP
  posterior mean at T_max. Where the GP has fitted a noise level this discounts a lucky
  sample; where the marginal likelihood cannot tell noise from short-range signal (few,
  far-apart points in a 51-dimensional space) it fits the noise floor and the mean
  interpolates the samples, so the recommendation is then near the best sample. Either way
  the confirmation decides R*: at the end of :meth:`RBBO.run` the recommendation and the
  identity are evaluated on ``n_confirm`` fresh seeds at T_max: R* and R_init.
- With a run directory every finished evaluation is fsynced to history.jsonl before the next
  proposal, and every proposal to proposals.jsonl before it is evaluated;
  :meth:`RBBO.resume` rebuilds the optimiser from them, the proposals in flight included.
"""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from .acquisition import UCBAcquisition, maximize_on_grassmann, ucb_beta
from .boca import BOCAFidelity
from .config import (
    CONFIRM_KINDS,
    FIDELITIES,
    Proposal,
    RBBOConfig,
    RBBOResult,
    _positive_int,
    _real,
)
from .executors import Executor, ProcessExecutor, SerialExecutor
from .gp import GPHyperparameters, GrassmannGP
from .grassmann import (
    dimension,
    identity_basis,
    projection_sq_distances,
    random_points,
    validate_basis,
)
from .store import Evaluation, RunDirectoryError, RunStore

__all__ = ["FIDELITIES", "RBBO", "EvaluationsFailing", "Proposal", "RBBOConfig", "RBBOResult"]

CONFIG_VERSION = 1
MAX_CONSECUTIVE_FAILURES = 10
# Two bases closer than this (projection distance ||P_1 - P_2||_F) at the same T are one
# evaluation: under common random numbers the MPC sees actuation directions within a
# thousandth of each other, and R differs by far less than its noise across seeds.
DUPLICATE_DISTANCE = 1e-3


def _is_duplicate(basis: np.ndarray, t: float, taken: list[tuple[np.ndarray, float]]) -> bool:
    same_t = [b for b, t_b in taken if abs(t_b - t) <= 1e-9 * max(1.0, abs(t))]
    if not same_t:
        return False
    d2 = projection_sq_distances(basis[None], np.stack(same_t))
    return bool(d2.min() < DUPLICATE_DISTANCE**2)


def _ok_R(evaluation: Evaluation) -> float:
    """R of an 'ok' evaluation (which Evaluation checks is a finite number)."""
    assert evaluation.R is not None
    return evaluation.R


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


class EvaluationsFailing(RuntimeError):
    """Every evaluation of the last stretch of a run failed, so :meth:`RBBO.run` stopped."""


class RBBO:
    """Riemannian Bayesian bilevel optimisation of the control space B_c (see module doc).

    Parameters
    ----------
    config : RBBOConfig
    store : RunStore or None
        Where evaluations are recorded (None: in memory only).
    objective_spec : dict or None
        What the objective is (for resuming from the command line); stored in config.json.
    """

    def __init__(self, config: RBBOConfig, *, store: RunStore | None = None,
                 objective_spec: dict | None = None):  # fmt: skip
        self.config = config
        self.store = store
        self.objective_spec = objective_spec
        self.history: list[Evaluation] = []
        self.pending: dict[int, Proposal] = {}
        # proposals a stopped session handed out and never saw evaluated (resume): ask()
        # hands them out again, in index order, before it proposes anything new
        self._restored: list[Proposal] = []
        self._next_index = 0
        self._elapsed_offset = 0.0
        self._t0 = time.monotonic()
        self._boca = (
            BOCAFidelity(config.t_min, config.t_max, n_candidates=config.boca_candidates)
            if config.fidelity == "boca"
            else None
        )
        self._gp: GrassmannGP | None = None
        self._gp_count = -1
        self._session: tuple[str, dict[str, Any]] | None = None  # recorded at its first submit
        self._session_started: str | None = None  # its start's stamp, once recorded
        self._initial = self._initial_design()

    # -- construction -------------------------------------------------------------------
    @classmethod
    def create(cls, path, config: RBBOConfig, *, objective_spec: dict | None = None,
               extra: dict | None = None) -> RBBO:  # fmt: skip
        """Start a run in directory ``path`` (config.json written; refuses an existing run)."""
        document = {"version": CONFIG_VERSION, "rbbo": asdict(config),
                    "objective": objective_spec, **(extra or {})}  # fmt: skip
        return cls(config, store=RunStore.create(path, document), objective_spec=objective_spec)

    @classmethod
    def resume(cls, path, *, read_only: bool = False) -> RBBO:
        """Rebuild the optimiser of run directory ``path`` from its history.

        Everything recorded is kept. The evaluations in flight when the run stopped have no
        result; their proposals (DIR/proposals.jsonl) are handed out again first, so a run
        told in proposal order (one worker, or ``deterministic``) resumed with as many
        workers goes on as the uninterrupted run would have. A truncated last line is dropped
        with a warning (with ``read_only``, for looking at a run that may still be going, it
        is skipped and the directory is left untouched).
        """
        store = RunStore.open(path, repair=not read_only)
        settings = store.config.get("rbbo")
        if not isinstance(settings, dict):
            raise RunDirectoryError(f"{store.path}/config.json has no 'rbbo' settings")
        try:
            config = RBBOConfig(**settings)
        except (TypeError, ValueError) as exc:
            raise RunDirectoryError(
                f"{store.path}/config.json has invalid settings: {exc}"
            ) from exc
        opt = cls(config, store=store, objective_spec=store.config.get("objective"))
        history = store.history()
        _check_history(store, history, config)
        for evaluation in history:
            opt._record(evaluation, persist=False)
        opt._restored = opt._restore_proposals(store, {e.index for e in history})
        indices = [e.index for e in history] + [p.index for p in opt._restored]
        if indices:
            opt._next_index = max(indices) + 1
        if history:
            opt._elapsed_offset = max(e.elapsed_s for e in history)
        opt._warm_start_from(history)
        return opt

    def _restore_proposals(self, store: RunStore, recorded: set[int]) -> list[Proposal]:
        """The search proposals DIR/proposals.jsonl holds and the history does not: those
        in flight when the run stopped, oldest first."""
        cfg = self.config
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

    def _warm_start_from(self, history: list[Evaluation]) -> None:
        """Start the next GP fit from the hyperparameters of the latest recorded proposal's
        fit, as the session that made it would have: with one worker a resumed run then
        proposes what the uninterrupted run proposed (records made before the hyperparameters
        were recorded start from the defaults)."""
        fitted = [(e.index, e.gp) for e in history
                  if e.gp is not None and e.kind not in CONFIRM_KINDS]  # fmt: skip
        # (a proposal still in flight when the run stopped was fitted after those told)
        fitted += [(p.index, p.info["gp"]) for p in self._restored if p.info.get("gp")]
        if not fitted:
            return
        record: dict[str, Any] = max(fitted, key=lambda x: x[0])[1]  # (its keys checked here)
        try:
            hyperparameters = GPHyperparameters(**record)
        except TypeError:
            return  # another version's record: the defaults, as before the record existed
        cfg = self.config
        self._gp = GrassmannGP(cfg.sim_dim, cfg.control_dim, fidelity=self._boca is not None,
                               n_restarts=cfg.gp_restarts)  # fmt: skip
        self._gp.hyperparameters = hyperparameters

    def _initial_design(self) -> list[tuple[np.ndarray, float, str]]:
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, 1])
        design = [(identity_basis(cfg.sim_dim, cfg.control_dim), cfg.t_max, "initial")]
        for i in range(cfg.n_init):
            t = cfg.t_max if cfg.fidelity == "bo" or i % 2 == 1 else cfg.t_min
            design.append((random_points(cfg.sim_dim, cfg.control_dim, rng=rng), t, "initial"))
        return design

    # -- bookkeeping --------------------------------------------------------------------
    @property
    def elapsed_s(self) -> float:
        """Run time so far, over all sessions of the run."""
        return self._elapsed_offset + (time.monotonic() - self._t0)

    @property
    def evaluations(self) -> list[Evaluation]:
        """Recorded evaluations of the optimisation proper (confirmations excluded)."""
        return [e for e in self.history if e.kind not in CONFIRM_KINDS]

    def _observations(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.status == "ok"]

    def _record(self, evaluation: Evaluation, persist: bool) -> None:
        if persist and self.store is not None:
            self.store.append(evaluation)
        self.history.append(evaluation)
        if evaluation.kind in CONFIRM_KINDS:
            return
        if self._boca is not None:
            self._boca.record(evaluation.T)
        # best_basis.npy is not the best sample so far (one noisy R): it is written with the
        # recommendation when the run stops (_record_result)

    # -- the model ----------------------------------------------------------------------
    def _z(self, t) -> np.ndarray | None:
        return None if self._boca is None else np.asarray(self._boca.z(t), dtype=float)

    def fit(self) -> GrassmannGP | None:
        """The GP on all successful evaluations (None with fewer than 2); refitted only
        when new data arrived."""
        data = self._observations()
        if len(data) < 2:
            return None
        if len(data) != self._gp_count:
            cfg = self.config
            if self._gp is None:
                self._gp = GrassmannGP(cfg.sim_dim, cfg.control_dim,
                                       fidelity=self._boca is not None,
                                       n_restarts=cfg.gp_restarts)  # fmt: skip
            self._gp.random_state = cfg.seed * 7919 + len(data)
            bases = np.stack([e.basis for e in data])
            y = np.array([e.R for e in data])
            self._gp.fit(bases, y, self._z([e.T for e in data]))
            self._gp_count = len(data)
        return self._gp

    def _with_fantasies(self, gp: GrassmannGP) -> GrassmannGP:
        pending = [p for p in self.pending.values() if p.kind not in CONFIRM_KINDS]
        if not pending:
            return gp
        bases = np.stack([p.basis for p in pending])
        z = self._z([p.T for p in pending])
        mu, _ = gp.predict(bases, 1.0 if z is None else z)
        return gp.conditioned_on(bases, mu, z)

    def recommend(self) -> Evaluation | None:
        """The evaluated basis with the highest posterior mean of R at T_max (z = 1).

        Every successful evaluation is a candidate, whatever T it ran at: under BOCA a short
        run may have evaluated none of the GP's proposals at T_max, and the confirmation
        measures the recommendation at T_max on fresh seeds anyway. (BoTorch's multi-fidelity
        tutorials recommend the maximiser of the posterior mean at the target fidelity over
        the whole domain; this keeps to bases that were evaluated.) On the
        synthetic objective (M = 20, C = 3, T in [2, 4] s, 8 seeds, BOCA without its T_max
        floor: ``benchmarks/study_boca_recommendation.py --no-floor``) the recommendation's
        noise-free R after 10 / 20 / 40 evaluations is 0.176 / 0.211 / 0.421 this way and
        0.153 / 0.153 / 0.327 from the bases evaluated at T_max alone.
        """
        data = self._observations()
        gp = self.fit()
        if gp is None:  # fewer than two observations: the best one at T_max
            cands = [e for e in data if math.isclose(e.T, self.config.t_max)]
            return max(cands, key=_ok_R) if cands else None
        mu, _ = gp.predict(np.stack([e.basis for e in data]), 1.0)
        return data[int(np.argmax(mu))]

    # -- ask / tell ---------------------------------------------------------------------
    def ask(self) -> Proposal:
        """The next (B_c, T) to evaluate; it stays pending until :meth:`tell`.

        A resumed run first hands out again, oldest first, the proposals its stopped session
        had handed out and not seen evaluated (DIR/proposals.jsonl), so that it evaluates
        what the uninterrupted run would have.
        """
        if self._restored:
            proposal = self._restored.pop(0)
            self.pending[proposal.index] = proposal
            return proposal
        cfg = self.config
        index = self._next_index
        info: dict[str, Any] = {}
        position = self._next_design_position()
        if position is not None:
            basis, t, kind = self._initial[position]
        else:
            rng = np.random.default_rng([cfg.seed, 2, index])
            start = time.perf_counter()
            gp = self.fit()
            info["fit_s"] = time.perf_counter() - start
            if gp is None:
                basis, kind = random_points(cfg.sim_dim, cfg.control_dim, rng=rng), "random"
                t = cfg.t_max if self._boca is None else cfg.t_min
            else:
                start = time.perf_counter()
                basis, t, value, skipped = self._propose(gp, rng)
                assert gp.hyperparameters is not None  # (fit() fitted it)
                info.update(acq_s=time.perf_counter() - start, acq_value=value,
                            gp=asdict(gp.hyperparameters))  # fmt: skip
                kind = "acquisition"
                if skipped:
                    info["duplicates_skipped"] = skipped
                    if value is None:  # every local optimum had been evaluated
                        kind = "random"
        proposal = Proposal(index, basis, float(t), cfg.crn_seeds, kind, info)
        if self.store is not None and self.store.writable:  # (a reader may ask, not record)
            record = {"index": index, "basis": basis.tolist(), "T": float(t),
                      "seeds": [int(x) for x in cfg.crn_seeds], "kind": kind}  # fmt: skip
            record.update({k: info[k] for k in ("gp", "duplicates_skipped") if k in info})
            self.store.append_proposal(record)
        self.pending[index] = proposal
        self._next_index += 1
        return proposal

    def _propose(self, gp: GrassmannGP, rng: np.random.Generator):
        cfg = self.config
        believer = self._with_fantasies(gp)
        n = len(self._observations())
        acquisition = UCBAcquisition(believer, ucb_beta(n, dimension(cfg.sim_dim, cfg.control_dim)))
        # incumbents: the observed bases the model rates best at the target fidelity
        observed = np.stack([e.basis for e in self._observations()])
        mu, _ = gp.predict_standardized(observed, 1.0)
        incumbents = observed[np.argsort(-mu)[:3]]
        result = maximize_on_grassmann(
            acquisition, cfg.sim_dim, cfg.control_dim, incumbents=incumbents, rng=rng,
            optimizer=cfg.optimizer, n_random=cfg.acq_random, n_starts=cfg.acq_starts,
            max_iterations=cfg.acq_max_iterations,
        )  # fmt: skip
        # Under common random numbers an evaluation repeated at the same T returns the same R:
        # it costs a worker, teaches the GP nothing and drags its noise fit to the floor. So a
        # maximiser that lands on a basis evaluated (or in flight) at that T gives way to the
        # next-best local optimum, and failing those to a random point (as GPyOpt's
        # de-duplication does).
        in_flight = [p for p in self.pending.values() if p.kind not in CONFIRM_KINDS]
        taken = [(e.basis, e.T) for e in self.evaluations] + [(p.basis, p.T) for p in in_flight]
        optima = sorted(
            ((-float(r.cost), r.point) for r in result.results
             if not np.array_equal(r.point, result.basis)),
            key=lambda v: -v[0],
        )  # fmt: skip
        choices = [(result.value, result.basis), *optima, (None, None)]
        for skipped, (value, point) in enumerate(choices):
            if point is None:
                point = random_points(cfg.sim_dim, cfg.control_dim, rng=rng)
            u, _, vt = np.linalg.svd(point, full_matrices=False)
            basis = u @ vt  # orthonormal to round-off, as the env requires
            if self._boca is None:
                t = cfg.t_max
            else:
                t = self._boca.choose(believer, basis, [p.T for p in in_flight]).T
            if value is None or not _is_duplicate(basis, t, taken):
                return basis, t, value, skipped
        raise AssertionError("unreachable: the last choice is always taken")

    def tell(self, index: int, R: float | None, *, status: str = "ok", wall_s: float = 0.0,
             worker: str = "", R_seeds=(), error: str | None = None) -> Evaluation:  # fmt: skip
        """Record the outcome of proposal ``index`` (persisted before returning)."""
        if index not in self.pending:
            raise ValueError(f"no pending proposal with index {index}")
        if R is not None:
            # numpy's scalars (np.float32 from a torch model) as Python's: the history is JSON
            R = _real("R", R)
        wall_s = _real("wall_s", wall_s)
        if not math.isfinite(wall_s):
            raise ValueError(f"wall_s must be a finite number of seconds, got {wall_s!r}")
        r_seeds = [float(r) for r in R_seeds]
        if not all(math.isfinite(r) for r in r_seeds):
            # (the history is JSON, which has no NaN): a failure, as evaluate_task reports one
            if status == "ok":
                status, error = "failed", error or f"non-finite R over seeds: {tuple(r_seeds)}"
            r_seeds = []
        if status == "ok" and (R is None or not math.isfinite(R)):
            status, error = "failed", error or f"non-finite R {R!r}"
        proposal = self.pending[index]
        index = proposal.index  # (an np.int64 that matched it would not serialise)
        # built (and so validated) before the proposal leaves `pending`: a bad status or R
        # raises with the proposal still there to be told again
        evaluation = Evaluation(
            index=index, basis=proposal.basis, T=proposal.T, R=R if status == "ok" else None,
            status=status, seeds=list(proposal.seeds), wall_s=wall_s,
            elapsed_s=self.elapsed_s, worker=str(worker), kind=proposal.kind, error=error,
            R_seeds=r_seeds, gp=proposal.info.get("gp"),
            duplicates_skipped=int(proposal.info.get("duplicates_skipped", 0)),
        )  # fmt: skip
        self._record(evaluation, persist=True)
        del self.pending[index]
        return evaluation

    def _next_design_position(self) -> int | None:
        """The first initial-design point neither recorded nor pending, if any.

        Matched by basis, not by index: confirmations share the index sequence, and a point
        lost in flight when a run stopped is proposed again when it resumes.
        """
        started = [e.basis for e in self.history if e.kind == "initial"]
        started += [p.basis for p in self.pending.values() if p.kind == "initial"]
        for position, (basis, _, _) in enumerate(self._initial):
            if not any(b.shape == basis.shape and np.array_equal(b, basis) for b in started):
                return position
        return None

    # -- driving a whole run ------------------------------------------------------------
    def set_limits(self, max_evaluations: int | None, budget_s: float | None) -> None:
        """Replace the run's stopping limits (both: a limit not given becomes none), in
        config.json too when the run has a store, so that a later :meth:`run` without limits,
        e.g. a plain ``rbbo resume``, goes on to them.

        Raises ValueError for an invalid limit, as :class:`RBBOConfig` does, before anything
        is written.
        """
        if max_evaluations is None and budget_s is None:
            raise ValueError("give max_evaluations or budget_s")
        config = replace(self.config, max_evaluations=max_evaluations, budget_s=budget_s)
        if self.store is not None:
            self.store.update_config({"rbbo": {"max_evaluations": max_evaluations,
                                               "budget_s": budget_s}})  # fmt: skip
        self.config = config

    def can_submit(self, max_evaluations: int | None, budget_s: float | None) -> bool:
        """Whether a search evaluation may start under these limits (None: no limit)."""
        started = len(self.evaluations) + sum(
            p.kind not in CONFIRM_KINDS for p in self.pending.values()
        )
        if max_evaluations is not None and started >= max_evaluations:
            return False
        return budget_s is None or self.elapsed_s < budget_s

    def run(
        self,
        objective: Callable | None = None,
        *,
        executor: Executor | None = None,
        workers: int = 1,
        timeout_s: float | None = None,
        max_evaluations: int | None = None,
        budget_s: float | None = None,
        confirm: bool = True,
        callback: Callable[[Evaluation], None] | None = None,
        deterministic: bool = False,
    ) -> RBBOResult:
        """Optimise until ``max_evaluations`` or ``budget_s`` (defaults: the config's).

        Parameters
        ----------
        objective : callable
            ``objective(B_c, T, seed) -> float`` (not needed when ``executor`` is given).
        executor : Executor, optional
            Where evaluations run; default: in this process for one worker, a
            :class:`ProcessExecutor` otherwise. An executor passed in is not shut down.
        workers, timeout_s
            For the default executor.
        max_evaluations : int, optional
            Stop proposing after this many evaluations in all (those of earlier sessions
            included; confirmations not counted). Default: the config's.
        budget_s : float, optional
            Stop proposing once this much wall time (seconds, earlier sessions included) is
            spent. Default: the config's.
        confirm : bool
            Measure R_init and R* on fresh seeds at the end.
        callback : callable, optional
            Called with each recorded Evaluation.
        deterministic : bool
            Tell results in proposal order (see module doc): the run repeats bitwise for a
            given number of workers and ``max_evaluations`` (not under ``budget_s``, which is
            wall time), at the cost of a worker idling while an older evaluation finishes.
            Default False: a free worker gets a new point at once.
        """
        cfg = self.config
        max_evaluations = cfg.max_evaluations if max_evaluations is None else max_evaluations
        budget_s = cfg.budget_s if budget_s is None else budget_s
        if max_evaluations is None and budget_s is None:
            raise ValueError("give max_evaluations or budget_s (here or in the config)")
        # (math.inf stands for "no limit of this kind", as the command line passes it)
        if max_evaluations is not None and max_evaluations != math.inf:
            _positive_int("max_evaluations", max_evaluations)
        if budget_s is not None and not _real("budget_s", budget_s) > 0:
            raise ValueError(f"budget_s must be > 0 seconds, got {budget_s!r}")
        own = executor is None
        if executor is None:
            if objective is None:
                raise ValueError("give an objective or an executor")
            if not callable(objective):
                raise TypeError(f"objective must be callable as objective(B_c, T, seed), got "
                                f"{type(objective).__name__}")  # fmt: skip
            executor = (
                SerialExecutor(objective)
                if workers == 1 and timeout_s is None
                else ProcessExecutor(objective, workers, timeout_s)
            )
        # A run whose every evaluation fails (a broken objective or executor) stops instead of
        # spending its budget on failures; one failure among successes is only recorded.
        # the session is recorded with its first evaluation: a call that evaluates nothing
        # (a finished run run again) leaves no record
        self._session = ("search", {"max_evaluations": max_evaluations, "budget_s": budget_s,
                                    "workers": executor.workers})  # fmt: skip
        failure_limit = max(MAX_CONSECUTIVE_FAILURES, 2 * executor.workers)
        failed_in_a_row, last_error = 0, None
        ok = False
        with self._session_ending():
            try:
                in_flight: dict[Future, Proposal] = {}
                while True:
                    while (
                        len(in_flight) < executor.workers
                        and failed_in_a_row < failure_limit
                        and self.can_submit(max_evaluations, budget_s)
                    ):
                        proposal = self.ask()
                        in_flight[self._submit(executor, proposal)] = proposal
                    if not in_flight:
                        break
                    # in_flight keeps submission order: its first entry is the oldest proposal
                    waiting = [next(iter(in_flight))] if deterministic else list(in_flight)
                    done, _ = wait(waiting, timeout=1.0, return_when=FIRST_COMPLETED)
                    for future in done:
                        proposal = in_flight.pop(future)
                        evaluation = self._tell_outcome(proposal, future.result(), callback)
                        failed = evaluation.status == "failed"
                        failed_in_a_row = failed_in_a_row + 1 if failed else 0
                        last_error = evaluation.error
                if failed_in_a_row >= failure_limit:
                    self._record_result()
                    raise EvaluationsFailing(
                        f"the last {failed_in_a_row} evaluations all failed, the last with: "
                        f"{last_error}; the run stopped (its record is kept"
                        + (f"; resume it with: rbbo resume {self.store.path}" if self.store else "")
                        + ")"
                    )
                if confirm:
                    self._confirm(executor, callback)
                ok = True
            finally:
                if own:
                    executor.shutdown(wait=ok)
            return self._record_result()

    def _submit(self, executor: Executor, proposal: Proposal):
        """Submit ``proposal``, first appending this session's code and machine to
        DIR/sessions.jsonl if nothing was submitted in it yet."""
        if self._session is not None and self.store is not None:
            from .provenance import session_record

            command, settings = self._session
            limits = {k: (None if v == math.inf else v) for k, v in settings.items()}
            record = {**session_record(command), **limits}
            self.store.append_session(record)
            self._session_started = record["started"]
        self._session = None
        return executor.submit(proposal.task())

    @contextlib.contextmanager
    def _session_ending(self):
        """Append the end of the session whose start :meth:`_submit` recorded (a call that
        evaluated nothing recorded neither) to DIR/sessions.jsonl when the block is left:
        when, and how (finished, interrupted by Ctrl-C or SIGTERM, or an error, named)."""
        status, error = "error", None
        try:
            yield
            status = "finished"
        except KeyboardInterrupt:
            status = "interrupted"
            raise
        except BaseException as exc:
            error = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]  # one line of it
            raise
        finally:
            started, self._session_started = self._session_started, None
            if started is not None and self.store is not None:
                from .provenance import session_end_record

                try:
                    self.store.append_session(session_end_record(started, status, error))
                except OSError as exc:
                    # (a full disk): the session's evaluations are recorded; what is raised
                    # already, or the result, matters more than its end's line
                    warnings.warn(f"{self.store.path}: the end of this session was not "
                                  f"recorded in sessions.jsonl: {exc}", RuntimeWarning,
                                  stacklevel=3)  # fmt: skip

    def _record_result(self) -> RBBOResult:
        """The result so far, also written to summary.json and best_basis.npy."""
        result = self.result()
        if self.store is not None:
            self.store.write_summary(result.summary())
            if result.best_basis is not None:
                self.store.save_best(result.best_basis)
        return result

    def _tell_outcome(self, proposal: Proposal, outcome, callback) -> Evaluation:
        evaluation = self.tell(proposal.index, outcome.R, status=outcome.status,
                               wall_s=outcome.wall_s, worker=outcome.worker,
                               R_seeds=outcome.R_seeds, error=outcome.error)  # fmt: skip
        if callback is not None:
            callback(evaluation)
        return evaluation

    def _final_confirmation(self) -> Evaluation | None:
        """The last successful confirm-best if no search evaluation was recorded after it.

        That basis was the recommendation when the search ended, and it stays the run's
        answer: a GP refitted when the run is reloaded (from other starting hyperparameters)
        may rank near-equal candidates differently, which must not unmake a finished run.
        """
        for e in reversed(self.history):
            if e.kind == "confirm-best" and e.status == "ok":
                return e
            if e.kind not in CONFIRM_KINDS:
                return None
        return None

    @property
    def finished(self) -> bool:
        """Whether the run ended (with its confirmation, if it has confirmation seeds) and
        searched no further since: its recommendation is then fixed (:meth:`result`), and
        best_basis.npy holds it."""
        if self._final_confirmation() is not None:
            return True
        # a session that searched on and kept its confirmed recommendation (nothing new to
        # confirm) ended with a summary of it
        summary = self._current_summary()
        return summary is not None and (
            self.config.n_confirm == 0 or summary.get("R_star") is not None
        )

    def _current_summary(self) -> dict[str, Any] | None:
        """summary.json if no evaluation was recorded since a session wrote it."""
        if self.store is None:
            return None
        try:
            summary = self.store.summary()
        except RunDirectoryError:
            return None
        if not summary or summary.get("evaluations") != len(self.evaluations):
            return None
        return summary

    def _summary_recommendation(self) -> Evaluation | None:
        """The recommendation summary.json recorded when a session ended, if no evaluation was
        recorded since (a GP refitted in another process may rank near-equal bases
        otherwise, and best_basis.npy holds this one)."""
        summary = self._current_summary()
        if summary is None:
            return None
        return next((e for e in self._observations() if e.index == summary.get("best_index")),
                    None)  # fmt: skip

    def _final_recommendation(self) -> Evaluation | None:
        """The searched evaluation that a final confirmation measured, else the one the last
        session's summary named (nothing recorded since), else :meth:`recommend`."""
        final = self._final_confirmation()
        if final is None:
            return self._summary_recommendation() or self.recommend()
        # (recommended at any T since BOCA's recommendation looks at every fidelity; the
        # longest evaluation of the basis where it ran at several)
        matches = [e for e in self._observations() if np.array_equal(e.basis, final.basis)]
        return max(matches, key=lambda e: e.T) if matches else self.recommend()

    def confirm_again(
        self, executor: Executor, callback: Callable[[Evaluation], None] | None = None
    ) -> RBBOResult:
        """Measure R_init and R* again on the run's fresh seeds and append the new
        confirmations; R_init and R* are then the new values, the earlier ones stay in the
        history.

        For a finished run whose numbers must be checked against the simulator as it is now
        (after an upgrade of softrom, or on another machine): the basis confirmed as R* stays
        the run's answer; the search is not resumed.
        """
        if self._final_recommendation() is None:
            raise ValueError("the run has no evaluation to confirm yet")
        if self.config.n_confirm == 0:
            raise ValueError("the run was made with no confirmation seeds (n_confirm = 0)")
        self._session = ("confirm", {"workers": executor.workers})
        with self._session_ending():
            self._confirm(executor, callback, again=True)
            return self._record_result()

    def _confirm(self, executor: Executor, callback, again: bool = False) -> None:
        """Evaluate the identity and the recommendation on fresh seeds at T_max (``again``:
        even where the same basis was measured before)."""
        cfg = self.config
        best = self._final_recommendation()
        if best is None or cfg.n_confirm == 0:
            return
        wanted = {"confirm-init": identity_basis(cfg.sim_dim, cfg.control_dim),
                  "confirm-best": best.basis}  # fmt: skip
        done = {e.kind: e for e in self.history if e.kind in CONFIRM_KINDS and e.status == "ok"}
        futures = {}
        for kind, basis in wanted.items():
            if not again and kind in done and np.array_equal(done[kind].basis, basis):
                continue  # already measured (a resumed, finished run)
            proposal = Proposal(self._next_index, basis, cfg.t_max, cfg.fresh_seeds, kind)
            self.pending[proposal.index] = proposal
            self._next_index += 1
            futures[self._submit(executor, proposal)] = proposal
        for future in futures:
            self._tell_outcome(futures[future], future.result(), callback)

    def result(self) -> RBBOResult:
        """R_init, R* and the counts so far (R values from the confirmation evaluations)."""
        best = self._final_recommendation()
        confirmations = {}
        for e in self.history:
            if e.kind in CONFIRM_KINDS and e.status == "ok":
                confirmations[e.kind] = e
        r_init = confirmations.get("confirm-init")
        r_star = confirmations.get("confirm-best")
        if r_star is not None and (best is None or not np.array_equal(r_star.basis, best.basis)):
            r_star = None  # measured for an earlier recommendation
        improvement = None
        if r_init is not None and r_star is not None and _ok_R(r_init) > 0:
            improvement = 100.0 * (_ok_R(r_star) / _ok_R(r_init) - 1.0)
        evaluations = self.evaluations
        return RBBOResult(
            best_basis=None if best is None else best.basis,
            R_star=None if r_star is None else r_star.R,
            R_init=None if r_init is None else r_init.R,
            improvement_pct=improvement,
            evaluations=len(evaluations),
            failed=sum(e.status == "failed" for e in evaluations),
            wall_s=max([e.elapsed_s for e in self.history], default=0.0),
            R_star_seeds=[] if r_star is None else list(r_star.R_seeds),
            R_init_seeds=[] if r_init is None else list(r_init.R_seeds),
            best_index=None if best is None else best.index,
        )
