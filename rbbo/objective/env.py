"""The env objective: an MPC episode on a softrom env, scored as R.

:class:`EnvObjective` (ENV_ID a registered env id) runs the controllers' planner on the env
built for B_c and returns the task reward per second from the settle time on; it records
and checks the simulation space B_r and the planner a run's evaluations used.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..grassmann import _check_dims
from .env_keywords import NO_TIME_LIMIT, _check_env_keywords
from .planner import planner_record
from .protocol import PlannerMismatch, SimulationSpaceMismatch
from .reward import measured_steps, settled_reward_rate


def _plain(value: Any) -> Any:
    """A planner setting with numpy's scalars and arrays as Python's numbers, lists and tuples
    (anything else as it is)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return type(value)(_plain(v) for v in value)
    return value


@dataclass
class EnvObjective:
    """R(B_c, T, seed): the MPC controller's task reward on a softrom env, per second.

    Runs ``controllers.run_episode(env, planner, T, seed=seed, progress=False)`` with the env
    built for B_c and the controller's default planner for the benchmark,
    and returns the reward R (the task term only, not the regulariser Lambda) collected from
    the settle time on, divided by the time it covers:

        R = sum_{t_k >= t_settle} r_k / (T - t_settle)

    on the env-step grid (:func:`settled_reward_rate`): the episode runs round(T / dt) whole
    steps, and R divides by the time they cover from the first step starting at or after
    t_settle (BOCA's T = 2.667 s at dt = 0.025 s is 107 steps, 2.675 s; a t_settle of 1.01 s
    counts from 1.025 s); a step lost to a divergence counts as zero reward.

    Why from a settle time: a robot leaning into a held pose gains about 0.2 body lengths in
    its first second (measured on the walkers), which would dominate short trajectories and
    rank bases by how far they lean rather than how well they walk; measuring from
    t_settle = 2 s (as ``python -m controllers`` reports distance) and normalising per
    second makes fidelities T comparable. T must exceed t_settle.

    The env is built once per worker process; each evaluation swaps its B_c in with the env's
    ``set_control_basis`` (an env without one is built again for each B_c).

    Parameters
    ----------
    env_id : str
        A registered Gymnasium id, e.g. ``softrom_gym/CrossWalk-v0``.
    sim_dim, control_dim : int
        M and C.
    controller : str
        The planner: "mppi", "gn" (Gauss-Newton shooting), a name registered with
        ``controllers.register_planner``, or an import path ``package.module:ClassName`` of a
        ``controllers.Planner`` subclass. The string is what a run records (config.json) and
        what worker processes and ``rbbo resume`` find the planner by: they import an import
        path themselves, and a registered name by ``registered_planner`` where the code
        registering it does not run there. A registered name whose class another process
        cannot import (defined in ``__main__``, a script or a notebook, or inside a function)
        gets a UserWarning here: it runs in this process (the serial executor) only, so
        define the class in a module for worker processes and ``rbbo resume``.
    settle_time : float
        t_settle, seconds.
    env_kwargs, planner_kwargs : dict
        Passed to ``gym.make`` and to the planner (``controllers.planner_for``'s
        ``changes``). For a registered env id the keywords' names are checked and the
        planner is made once here, so a keyword the env does not take or a setting the
        planner refuses raises its ValueError or TypeError now, not in every evaluation.
    registered_planner : dict or None
        For a registered name other than "mppi" and "gn", filled in here: where the planner's
        classes are imported from and the defaults it was registered with
        (``controllers.planner_source``), which the spec records. A process where the name is
        not registered (a worker, ``rbbo resume``) chooses the planner by it; where it is
        registered, the registration is used (and recorded). Leave it None: a recorded spec
        gives it back (one without it, from before, needs the name registered as before).
    """

    env_id: str
    sim_dim: int
    control_dim: int
    controller: str = "mppi"
    settle_time: float = 2.0
    env_kwargs: dict = field(default_factory=dict)
    planner_kwargs: dict = field(default_factory=dict)
    registered_planner: dict | None = None

    CONTROLLERS = ("mppi", "gn")  # the shipped planners (any the controllers resolve is taken)

    def __post_init__(self) -> None:
        # (numpy's integers as Python's: spec() goes into config.json)
        self.sim_dim, self.control_dim = _check_dims(self.sim_dim, self.control_dim)
        self._check_controller()
        settle = self.settle_time
        if isinstance(settle, bool) or not isinstance(settle, (int, float, np.number)):
            raise ValueError(f"settle_time must be a number of seconds >= 0, got {settle!r}")
        if not (math.isfinite(settle) and settle >= 0):  # (inf: no T could exceed it)
            raise ValueError(f"settle_time must be >= 0, got {settle!r}")
        self.settle_time = float(settle)
        for name in ("env_kwargs", "planner_kwargs"):
            if not isinstance(getattr(self, name), dict):
                raise TypeError(f"{name} must be a dict of keyword arguments, got "
                                f"{type(getattr(self, name)).__name__}")  # fmt: skip
        # numpy's numbers and arrays as Python's: the settings go into config.json, and the
        # planner's record (JSON, repr() for what JSON cannot say) read np.int64(8) as a string
        self.planner_kwargs = {k: _plain(v) for k, v in self.planner_kwargs.items()}
        self._env = None
        self._signature: list[float] | None = None
        self._signature_read = False  # an env without a signature is asked once, not per call
        self._check_keywords()

    def _check_controller(self) -> None:
        """Find the planner now, so that an unknown name (named with the registered names and
        the import-path form) or a registered class no worker could import is an error here,
        not in every evaluation; fill in ``registered_planner`` for a registered name."""
        name, source = self.controller, self.registered_planner
        if not isinstance(name, str):
            raise TypeError(f"controller must be a planner name (str), got {name!r}")
        if source is not None and not isinstance(source, dict):
            raise TypeError(f"registered_planner must be a dict (controllers.planner_source) or "
                            f"None, got {type(source).__name__}")  # fmt: skip
        shipped_or_path = name in self.CONTROLLERS or ":" in name
        if shipped_or_path and source is not None:
            raise ValueError(f"registered_planner is recorded for a registered planner name, "
                             f"not for {name!r}")  # fmt: skip
        if name in self.CONTROLLERS:
            return
        import controllers

        if shipped_or_path:
            controllers.resolve_planner(name)
            if name.partition(":")[0] == "__main__":
                warnings.warn(
                    f"controller {name!r} names a class of __main__ (this script or notebook): "
                    "it plans in this process only, with rbbo's serial executor, while worker "
                    "processes and rbbo resume have another __main__ and will not find it; "
                    "define the class in a module and name it by that module's path",
                    UserWarning,
                    stacklevel=4,
                )
        elif name in controllers.registered_planners():
            # (the registration here wins over a recorded source: a class moved since shows
            # as a difference from the run's recorded spec)
            try:
                self.registered_planner = controllers.planner_source(name)
            except controllers.PlannerNotImportable as exc:
                # Still a planner this process can run (a notebook's, with the serial
                # executor), so a warning, not a refusal: only other processes lack it.
                warnings.warn(
                    f"{exc}. Until then it plans in this process only: rbbo's serial executor "
                    "runs it, while worker processes and rbbo resume will call it unknown",
                    UserWarning,
                    stacklevel=4,  # (the EnvObjective(...) call: this, __post_init__, __init__)
                )
                # A recorded source names an importable class, so not this one: dropped, the
                # spec then lacks it, and a resume names "registered_planner absent".
                self.registered_planner = None
        elif source is not None:
            controllers.planner_from_source(name, source)
        else:
            controllers.resolve_planner(name)  # (unknown here: its ValueError)

    def _planner_choice(self) -> Any:
        """The name to plan with, or where the name is not registered in this process (a
        worker, a resume) the planner its recorded ``registered_planner`` names."""
        if self.registered_planner is None:
            return self.controller
        import controllers

        if self.controller in controllers.registered_planners():
            return self.controller
        return controllers.planner_from_source(self.controller, self.registered_planner)

    def _check_keywords(self) -> None:
        """Check the env keywords by name and make the planner once (when there are planner
        settings), so that a keyword the env does not take or a setting the controllers
        refuse (an unknown key, a bad value, a per-dimension noise of another length than C)
        is a ValueError or TypeError naming it here, not an error in every evaluation:
        RBBO.run records those as failed evaluations, in worker processes, and a short run
        returned no R at all. ``rbbo optimize`` checked its --env-kwarg and --mpc this way;
        an objective made in Python did not. Nothing is built (the env is made at the first
        evaluation). An env id that Gymnasium does not know (yet) is left to
        :meth:`make_env` to name."""
        import gymnasium as gym

        import softrom_gym  # noqa: F401  (registers the envs)

        try:
            gym.spec(self.env_id)
        except gym.error.Error:
            return
        _check_env_keywords(self.env_id, self.env_kwargs)
        if self.planner_kwargs:
            self.planner()

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_env"] = None  # a worker builds its own env
        return state

    def simulation_space(self) -> list[float] | None:
        """The env's B_r fingerprint (``Subspace.signature()``), None for an env without one."""
        if not self._signature_read:
            env = self.make_env(np.eye(self.sim_dim)[:, : self.control_dim])
            try:
                subspace = getattr(env.unwrapped, "subspace", None)
                if subspace is not None and hasattr(subspace, "signature"):
                    self._signature = [float(v) for v in subspace.signature()]
            finally:
                env.close()
            self._signature_read = True
        return self._signature

    def expect_simulation_space(self, recorded: list[float] | None) -> None:
        """Raise :class:`SimulationSpaceMismatch` unless this env's B_r is the one a run
        recorded (``recorded``: the run's ``simulation_space``; None skips the check, for
        runs made before it was recorded)."""
        if recorded is None:
            return
        current = self.simulation_space()
        rec = np.asarray(recorded, dtype=float)
        if current is None or len(current) != len(rec):
            raise SimulationSpaceMismatch(
                f"{self.env_id} at M = {self.sim_dim} has no simulation space like the one "
                "this run recorded"
            )
        cur = np.asarray(current)
        scale = float(np.abs(rec).max()) or 1.0
        bad = np.flatnonzero(np.abs(cur - rec) > 1e-6 * scale)
        if bad.size:
            which = (f"all {rec.size} of its coordinates differ from" if bad.size == rec.size
                     else f"coordinates {bad.tolist()} differ from")  # fmt: skip
            raise SimulationSpaceMismatch(
                f"{self.env_id} at M = {self.sim_dim} builds a simulation space B_r where "
                f"{which} those this run's B_c were found in (the robot's mesh or material "
                "changed since, or another softrom version built it): its bases would mean "
                "other actuations. Carry them over (benchmarks/migrate_run_bases.py) or start "
                "a new run."
            )

    def make_env(self, basis: np.ndarray, **extra):
        import gymnasium as gym

        import softrom_gym  # noqa: F401  (registers the envs)

        kwargs = {**self.env_kwargs, **extra}
        _check_env_keywords(self.env_id, kwargs)
        # The episode's T decides its length, not the registered limit: 400 env steps is
        # 10 s at the default control period but 2 s at frame_skip=1, which cut every
        # evaluation short unseen (R read the missing seconds as zero).
        return gym.make(
            self.env_id,
            sim_dim=self.sim_dim,
            control_dim=self.control_dim,
            control_basis=np.asarray(basis, dtype=float),
            max_episode_steps=NO_TIME_LIMIT,
            **kwargs,
        )

    def _env_for(self, basis: np.ndarray):
        env = self._env
        setter = getattr(getattr(env, "unwrapped", None), "set_control_basis", None)
        if setter is not None:
            setter(basis)
            return env
        if env is not None:
            env.close()
        self._env = self.make_env(basis)
        return self._env

    def planner(self):
        """The MPC planner and its replan interval (env steps).

        ``controllers.planner_for(env_id, controller, dt=..., **planner_kwargs)``: the
        benchmark's tuned settings where the controllers have them for this env, else the
        shared defaults (``controllers.GENERIC``: a 2, 3 or 4 Hz gait cycle picked at reset);
        their times in seconds kept at the env's control period (``frame_skip``, ``dt``).
        """
        import controllers
        from softrom_gym.registration import control_period

        dt = control_period(self.env_id, **self.env_kwargs)
        planner, replan_every = controllers.planner_for(self.env_id, self._planner_choice(),
                                                        dt=dt, **self.planner_kwargs)  # fmt: skip
        check = getattr(getattr(planner, "settings", None), "check_control_dim", None)
        if callable(check):  # controllers.PlannerSettings
            # (a per-dimension setting of another length fails here, not in every evaluation)
            check(self.control_dim)
        return planner, replan_every

    def episode(self, basis: np.ndarray, T: float, seed: int, env=None, **kwargs):
        """Run one MPC episode of T seconds; returns the controllers' EpisodeResult."""
        import controllers

        env = self._env_for(basis) if env is None else env
        planner, replan_every = self.planner()
        if replan_every != 1:
            kwargs["replan_every"] = replan_every
        return controllers.run_episode(env, planner, float(T), seed=int(seed), progress=False,
                                       **kwargs)  # fmt: skip

    def node_count(self) -> int | None:
        """N, the robot's mesh nodes (None for an env without a robot mesh)."""
        env = self.make_env(np.eye(self.sim_dim)[:, : self.control_dim])
        try:
            return int(env.unwrapped.robot.num_nodes)
        except AttributeError:
            return None
        finally:
            env.close()

    @staticmethod
    def step_seconds(env) -> float:
        """Seconds per env step: ``env.dt`` if the env has it (Gymnasium's convention), else
        the simulation step times ``frame_skip``."""
        u = env.unwrapped
        dt = getattr(u, "dt", None)
        if dt is None:
            dt = u.model.dt * getattr(u, "frame_skip", 1)
        return float(dt)

    def __call__(self, basis: np.ndarray, T: float, seed: int) -> float:
        if not T > self.settle_time:
            raise ValueError(f"T = {T} s must exceed the settle time {self.settle_time} s")
        env = self._env_for(basis)
        dt = self.step_seconds(env)
        if measured_steps(dt, self.settle_time, T) <= 0:
            # (named before the episode, which would be simulated for nothing)
            raise ValueError(f"T = {T} s is {max(1, round(T / dt))} steps of {dt:g} s, none "
                             f"of them from the settle time {self.settle_time} s on: R would "
                             "measure nothing")  # fmt: skip
        result = self.episode(basis, T, seed, env)
        if str(getattr(result, "stop_reason", "")).startswith("truncated"):
            # (an env of the user's own wrapping): R would read the lost seconds as zero
            raise RuntimeError(f"the env's time limit ended the T = {T:g} s episode at "
                               f"{result.seconds:g} s")  # fmt: skip
        dt = getattr(result, "dt", None) or dt
        return settled_reward_rate(result, dt, self.settle_time, T)

    def spec(self) -> dict[str, Any]:
        signature = self.simulation_space()
        return {
            "kind": "env",
            "env_id": self.env_id,
            "sim_dim": self.sim_dim,
            "control_dim": self.control_dim,
            "controller": self.controller,
            "settle_time": self.settle_time,
            "env_kwargs": self.env_kwargs,
            "planner_kwargs": self.planner_kwargs,
            "planner": self.planner_record(),
            **(
                {}
                if self.registered_planner is None
                else {"registered_planner": self.registered_planner}
            ),
            **({} if signature is None else {"simulation_space": signature}),
        }

    def planner_record(self) -> dict[str, Any]:
        """The planner's resolved settings and replan interval, as JSON: what a run records,
        so that a change of the controllers' defaults cannot change a resumed run's objective
        unseen (:func:`planner_record`)."""
        return planner_record(*self.planner())

    def expect_planner(self, recorded: dict[str, Any] | None) -> None:
        """Raise :class:`PlannerMismatch` unless the planner is the one a run recorded. A run
        from before the record (None) passes on a benchmark, whose tuned defaults are those it
        ran with; elsewhere the defaults changed with the record (controllers.GENERIC)."""
        if recorded is None:
            import controllers

            if not controllers.has_defaults(self.env_id):
                raise PlannerMismatch(
                    f"this run on {self.env_id} predates the planner record, and a robot "
                    "without tuned defaults has been planned with other settings since "
                    "(controllers.GENERIC, not the library settings replanning every step): "
                    "its R would be another objective. Start a new run, or resume with the "
                    "softrom version that made it."
                )
            from softrom_gym.registration import control_period

            dt = control_period(self.env_id, **self.env_kwargs)
            if dt is not None and not math.isclose(dt, controllers.TUNED_DT, rel_tol=1e-9):
                raise PlannerMismatch(
                    f"this run on {self.env_id} predates the planner record, and at its "
                    f"control period ({dt:g} s, not {controllers.TUNED_DT:g} s) the planner's "
                    "times have been scaled to keep their seconds since: its R would be "
                    "another objective. Start a new run, or resume with the softrom version "
                    "that made it."
                )
            return
        current = self.planner_record()
        if current != recorded:
            old, new = recorded.get("settings") or {}, current["settings"] or {}
            changed = sorted(k for k in {*old, *new} if old.get(k) != new.get(k))
            if recorded.get("replan_every") != current["replan_every"]:
                changed.append("replan_every")
            raise PlannerMismatch(
                f"{self.env_id}'s {self.controller} planner is not the one this run's "
                f"evaluations used (changed: {', '.join(changed) or 'the planner'}; this "
                "softrom's controllers defaults differ from the run's): its R would be another "
                "objective. Start a new run, or resume with the softrom version that made it."
            )
