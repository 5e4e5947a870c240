"""RBBO: the paper's Algorithm "RBBO" as an ask/tell optimiser with asynchronous proposals.

::

    from rbbo import RBBO, RBBOConfig, SyntheticObjective

    if __name__ == "__main__":  # workers are spawned processes, which import this script
        objective = SyntheticObjective(20, 3)  # objective(B_c, T, seed) -> float, picklable
        opt = RBBO.create("runs/demo", RBBOConfig(sim_dim=20, control_dim=3, max_evaluations=40))
        result = opt.run(objective, workers=2)
        # or drive it yourself:
        p = opt.ask(); opt.tell(p.index, objective(p.basis, p.T, p.seeds[0]))
        opt.close()  # the run directory's lock, for another process (or `with RBBO.create(...)`)

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
  :meth:`RBBO.run` refuses an objective whose ``spec()`` is not the one the run recorded
  (``objective_spec``), naming what differs, unless ``allow_objective_change=True``.
"""

# The optimiser, module by job: this module is RBBO itself (settings, the GP, ask/tell, the
# recommendation, the limits); proposing.py chooses what a proposal evaluates (the initial
# design, then the acquisition's maximiser), restore.py rebuilds an RBBO from its run
# directory (resume), run_loop.py drives one through an executor (run, confirm_again, the
# sessions) and run_result.py says what its answer is (result, finished). The names below are
# re-exported so that imports from rbbo.optimizer keep working.
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from . import restore, run_loop, run_result
from .boca import BOCAFidelity
from .config import CONFIRM_KINDS, FIDELITIES, Proposal, RBBOConfig, RBBOResult, _real
from .executors import Executor
from .gp import GrassmannGP
from .grassmann import random_points
from .proposing import DUPLICATE_DISTANCE as DUPLICATE_DISTANCE
from .proposing import initial_design, next_design_position, propose
from .run_loop import MAX_CONSECUTIVE_FAILURES as MAX_CONSECUTIVE_FAILURES
from .run_loop import EvaluationsFailing
from .run_result import _ok_R
from .store import Evaluation, RunStore
from .store.files import _signals_deferred

if TYPE_CHECKING:
    from typing_extensions import Self  # (typing's from Python 3.11)

__all__ = ["FIDELITIES", "RBBO", "EvaluationsFailing", "Proposal", "RBBOConfig", "RBBOResult"]

CONFIG_VERSION = 1


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
        self._initial = initial_design(config)
        # what summary.json holds for a run with a store: the result a session of a run in
        # memory ended with (run_result reads it, so that `finished` means the same for both)
        self._summary: dict[str, Any] | None = None
        self._closed = False

    # -- construction -------------------------------------------------------------------
    @classmethod
    def create(cls, path, config: RBBOConfig, *, objective_spec: dict | None = None,
               extra: dict | None = None) -> RBBO:  # fmt: skip
        """Start a run in directory ``path`` (config.json written; refuses an existing run).

        Parameters
        ----------
        path : str or os.PathLike
            The run directory (created; one that already holds a run is refused).
        config : RBBOConfig
        objective_spec : dict, optional
            What the objective is (an objective's ``spec()``), stored in config.json so that
            ``rbbo resume``, ``confirm`` and ``rollout`` can rebuild it; None: the run can be
            resumed from Python only, with the objective passed to :meth:`run`.
        extra : dict, optional
            More top-level entries for config.json (``rbbo optimize`` stores its executor
            settings and the problem there).
        """
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
        return restore.resume(cls, path, read_only=read_only)

    # -- releasing the run directory ------------------------------------------------------
    def close(self) -> None:
        """Release what the run holds: its run directory's lock (``DIR/.rbbo.lock``), so that
        another process, or another :meth:`resume` in this one, may write the run.

        What was recorded stays readable (``history``, :meth:`result`, :meth:`recommend`);
        :meth:`ask`, :meth:`tell`, :meth:`run`, :meth:`confirm_again` and
        :meth:`set_limits` then raise ValueError. Closing again does nothing. An RBBO is also
        a context manager that closes on leaving its block (an exception included), as a
        file is. Nothing else is held between calls: :meth:`run` shuts down the executor it
        makes before it returns, files are opened for each write, and an executor passed in
        is its caller's to shut down.
        """
        self._closed = True
        if self.store is not None:
            self.store.close()

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def _require_open(self) -> None:
        if self._closed:
            where = f"RBBO of {self.store.path}" if self.store is not None else "RBBO"
            again = (f"; RBBO.resume({str(self.store.path)!r}) opens the run again"
                     if self.store is not None else "")  # fmt: skip
            raise ValueError(f"this {where} is closed{again}")

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
        # recommendation when the run stops (run_result.record_result)

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

        A pending proposal counts against :meth:`run`'s ``max_evaluations`` as an
        evaluation, and :meth:`run` evaluates those pending when it is called first (oldest
        first), so a proposal asked and never told is neither lost nor a place of the limit
        left empty.

        A resumed run first hands out again, oldest first, the proposals its stopped session
        had handed out and not seen evaluated (DIR/proposals.jsonl), so that it evaluates
        what the uninterrupted run would have.
        """
        self._require_open()
        if self._restored:
            proposal = self._restored.pop(0)
            self.pending[proposal.index] = proposal
            return proposal
        cfg = self.config
        index = self._next_index
        info: dict[str, Any] = {}
        position = next_design_position(self)
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
                basis, t, value, skipped = propose(self, gp, rng)
                assert gp.hyperparameters is not None  # (fit() fitted it)
                info.update(acq_s=time.perf_counter() - start, acq_value=value,
                            gp=asdict(gp.hyperparameters))  # fmt: skip
                kind = "acquisition"
                if skipped:
                    info["duplicates_skipped"] = skipped
                    if value is None:  # every local optimum had been evaluated
                        kind = "random"
        proposal = Proposal(index, basis, float(t), cfg.crn_seeds, kind, info)
        # (Ctrl-C held until the record and the pending proposal agree: see signals_deferred)
        with _signals_deferred():
            if self.store is not None and self.store.writable:  # (a reader may ask, not record)
                record = {"index": index, "basis": basis.tolist(), "T": float(t),
                          "seeds": [int(x) for x in cfg.crn_seeds], "kind": kind}  # fmt: skip
                record.update({k: info[k] for k in ("gp", "duplicates_skipped") if k in info})
                self.store.append_proposal(record)
            self.pending[index] = proposal
            self._next_index += 1
        return proposal

    def tell(self, index: int, R: float | None, *, status: str = "ok", wall_s: float = 0.0,
             worker: str = "", R_seeds=(), error: str | None = None) -> Evaluation:  # fmt: skip
        """Record the outcome of proposal ``index`` (persisted before returning).

        Parameters
        ----------
        index : int
            The :class:`Proposal`'s ``index`` (it must be pending: asked and not yet told).
        R : float or None
            The objective's value, the mean over the proposal's ``seeds``; a non-finite one
            is recorded as a failure.
        status : {"ok", "failed"}
            "failed" records no R (the error says why).
        wall_s : float
            Seconds the evaluation took.
        worker : str
            Which worker ran it (for the history).
        R_seeds : sequence of float
            R on each of the proposal's seeds (a non-finite one fails the evaluation).
        error : str, optional
            Why it failed.

        Returns
        -------
        Evaluation
            The record appended to the history (and to DIR/history.jsonl).
        """
        self._require_open()
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
        # (a Ctrl-C between the history's line and the bookkeeping left the proposal pending
        # though recorded: a run going on in this process evaluated and recorded it twice)
        with _signals_deferred():
            self._record(evaluation, persist=True)
            del self.pending[index]
        return evaluation

    # -- driving a whole run ------------------------------------------------------------
    def set_limits(self, max_evaluations: int | None, budget_s: float | None) -> None:
        """Replace the run's stopping limits ``max_evaluations`` and ``budget_s`` (seconds;
        both: a limit not given becomes none), in config.json too when the run has a store,
        so that a later :meth:`run` without limits, e.g. a plain ``rbbo resume``, goes on to
        them.

        Raises ValueError for an invalid limit, as :class:`RBBOConfig` does, before anything
        is written.
        """
        self._require_open()
        if max_evaluations is None and budget_s is None:
            raise ValueError("give max_evaluations or budget_s")
        config = replace(self.config, max_evaluations=max_evaluations, budget_s=budget_s)
        if self.store is not None:
            self.store.update_config({"rbbo": {"max_evaluations": max_evaluations,
                                               "budget_s": budget_s}})  # fmt: skip
        self.config = config

    def can_submit(self, max_evaluations: int | None, budget_s: float | None) -> bool:
        """Whether a search evaluation may start under these limits: fewer than
        ``max_evaluations`` recorded and in flight, and less than ``budget_s`` seconds of run
        time spent (either None: no limit of that kind)."""
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
        allow_objective_change: bool = False,
    ) -> RBBOResult:
        """Optimise until ``max_evaluations`` or ``budget_s`` (defaults: the config's).

        Parameters
        ----------
        objective : callable
            ``objective(B_c, T, seed) -> float`` (not needed when ``executor`` is given).
        executor : Executor, optional
            Where evaluations run; default: in this process for one worker without
            ``timeout_s``, a :class:`rbbo.executors.ProcessExecutor` otherwise (spawned
            workers: the objective must pickle, and a script needs the ``if __name__ ==
            "__main__":`` guard). An executor passed in is not shut down.
        workers, timeout_s
            For the default executor.
        max_evaluations : int, optional
            Stop proposing after this many evaluations in all (those of earlier sessions
            included; confirmations not counted). Default: the config's. Proposals asked
            with :meth:`ask` and not told yet are evaluated first, oldest first, and count
            as these evaluations (those the limit leaves unevaluated stay pending).
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
        allow_objective_change : bool
            Go on with an objective other than the one the run recorded (see Raises): it
            becomes the run's objective in config.json (what ``rbbo resume`` rebuilds), and
            the one it replaces is kept there under ``"replaced_objectives"`` with the number
            of history lines evaluated under it. Default False.

        Raises
        ------
        rbbo.objective.ObjectiveMismatch
            Before anything is evaluated, when the objective (or the executor's
            ``objective``) is not the one the run recorded (``objective_spec``, config.json's
            ``"objective"``): its ``spec()`` differs in a recorded setting. The message
            names each difference. What cannot be compared is not checked: a run made
            without an ``objective_spec``, an objective without a ``spec()`` (a function, a
            wrapper), an executor without an ``objective`` attribute, and :meth:`ask` and
            :meth:`tell`, which never see the objective.
        """
        self._require_open()
        return run_loop.run(self, objective, executor=executor, workers=workers,
                            timeout_s=timeout_s, max_evaluations=max_evaluations,
                            budget_s=budget_s, confirm=confirm, callback=callback,
                            deterministic=deterministic,
                            allow_objective_change=allow_objective_change)  # fmt: skip

    def confirm_again(
        self,
        executor: Executor,
        callback: Callable[[Evaluation], None] | None = None,
        *,
        allow_objective_change: bool = False,
    ) -> RBBOResult:
        """Measure R_init and R* again on the run's fresh seeds and append the new
        confirmations; R_init and R* are then the new values, the earlier ones stay in the
        history.

        For a finished run whose numbers must be checked against the simulator as it is now
        (after an upgrade of softrom, or on another machine): the basis confirmed as R* stays
        the run's answer; the search is not resumed.

        Parameters
        ----------
        executor : Executor
            Where the confirmations run (e.g. ``rbbo.executors.ProcessExecutor(objective,
            workers)``); it is not shut down.
        callback : callable, optional
            Called with each recorded Evaluation.
        allow_objective_change : bool
            As for :meth:`run`, which refuses the executor's ``objective`` as it refuses it
            (:class:`rbbo.objective.ObjectiveMismatch`) when it is not the recorded one.
        """
        self._require_open()
        return run_loop.confirm_again(self, executor, callback, allow_objective_change)

    @property
    def finished(self) -> bool:
        """Whether the run ended (with its confirmation, if it has confirmation seeds) and
        searched no further since: its recommendation is then fixed (:meth:`result`), and a
        run directory's best_basis.npy holds it."""
        return run_result.finished(self)

    def result(self) -> RBBOResult:
        """R_init, R* and the counts so far (R values from the confirmation evaluations)."""
        return run_result.result(self)
