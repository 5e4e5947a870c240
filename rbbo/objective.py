"""Objectives R(B_c, T, seed) that RBBO maximises: the MPC task reward, or a synthetic one.

An objective is any picklable callable ``objective(B_c, T, seed) -> float`` (B_c an (M, C)
orthonormal basis, T the trajectory length in seconds, seed the MPC's random seed). The
executors run it in worker processes (spawn), so it must be a module-level class instance.

Specs (what ``rbbo optimize ENV_ID`` turns into an objective, and what config.json stores so a
run can be resumed):

- ``softrom_gym/CrossWalk-v0`` (any registered env id): :class:`EnvObjective`, the MPC
  controller run on the env (needs :mod:`controllers`, imported lazily).
- ``synthetic[:key=value,...]``: :class:`SyntheticObjective`, a Grassmann objective with known
  optimum, for tests, benchmarks and trying the CLI without the simulator. Keys: ``seed``
  (which hidden optimum), ``noise`` (seed-noise scale), ``bias`` (low-fidelity bias),
  ``delay`` (seconds of sleep per evaluation at T_max, scaled by T / T_max).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, dataclass, field, is_dataclass
from typing import Any, Protocol

import numpy as np

from .grassmann import _check_dims, random_points

__all__ = [
    "EnvObjective",
    "Objective",
    "SimulationSpaceMismatch",
    "SyntheticObjective",
    "make_objective",
    "parse_objective_spec",
]


class Objective(Protocol):
    def __call__(self, basis: np.ndarray, T: float, seed: int) -> float: ...


@dataclass
class SyntheticObjective:
    r"""A noisy two-fidelity objective on Gr(M, C) with a known optimum.

    .. math::
        R(B, T, s) = \|B^T U\|_F^2 / C
                   - b (1 - T / T_{max}) (1/2 + \|B^T V\|_F^2 / C)
                   + \epsilon_s + \epsilon_{s, B}

    U (the optimum, R = 1 at T_max) and V are fixed Haar-random subspaces drawn from
    ``optimum_seed``. The noise has a part common to all bases for a given seed (what common
    random numbers cancel) of scale ``noise`` and a part particular to (seed, B) of scale
    ``noise / 2``, both deterministic functions of their arguments.

    Parameters
    ----------
    sim_dim, control_dim : int
        M and C.
    optimum_seed : int
        Chooses U and V.
    noise : float
        Noise scale.
    bias : float
        Low-fidelity bias b.
    t_max : float
        The target fidelity T_max (seconds).
    delay : float
        Sleep ``delay * T / t_max`` seconds per call (cost proportional to T).
    """

    sim_dim: int
    control_dim: int
    optimum_seed: int = 0
    noise: float = 0.0
    bias: float = 0.3
    t_max: float = 10.0
    delay: float = 0.0
    _u: np.ndarray = field(init=False, repr=False, compare=False)  # (derived from the seed)
    _v: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _check_dims(self.sim_dim, self.control_dim)
        seed = self.optimum_seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"the synthetic seed must be an integer >= 0, got {seed!r}")
        for name in ("noise", "bias", "delay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        if not (math.isfinite(self.t_max) and self.t_max > 0):
            raise ValueError(f"t_max must be finite and > 0, got {self.t_max!r}")
        rng = np.random.default_rng(self.optimum_seed)
        self._u, self._v = random_points(self.sim_dim, self.control_dim, 2, rng)

    @property
    def optimum(self) -> np.ndarray:
        """U: a basis of the best subspace (R = 1 at T_max without noise)."""
        return self._u.copy()

    def value(self, basis: np.ndarray, T: float | None = None) -> float:
        """The noise-free R(B, T) (T defaults to T_max)."""
        b = np.asarray(basis, dtype=float)
        c = self.control_dim
        t = self.t_max if T is None else float(T)
        hit = float(np.sum((b.T @ self._u) ** 2)) / c
        side = float(np.sum((b.T @ self._v) ** 2)) / c
        return hit - self.bias * (1.0 - t / self.t_max) * (0.5 + side)

    def __call__(self, basis: np.ndarray, T: float, seed: int) -> float:
        if self.delay:
            time.sleep(self.delay * float(T) / self.t_max)
        r = self.value(basis, T)
        if self.noise:
            common = np.random.default_rng([int(seed), 0]).standard_normal()
            b = np.asarray(basis, dtype=float)
            # The subspace, not its representative; + 0.0 turns the -0.0 that rounding
            # leaves of a tiny negative entry into 0.0, whose bytes differ.
            key = (np.round(b @ b.T, 8) + 0.0).tobytes()
            digest = int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little")
            own = np.random.default_rng([int(seed), 1, digest]).standard_normal()
            r += self.noise * (common + 0.5 * own)
        return float(r)

    def spec(self) -> dict[str, Any]:
        return {"kind": "synthetic", **{k: v for k, v in asdict(self).items() if k[0] != "_"}}


class SimulationSpaceMismatch(ValueError):
    """The env builds another simulation space B_r than the one a run's B_c were found in."""


class PlannerMismatch(ValueError):
    """The controllers build another planner than the one a run's evaluations used."""


# What rbbo passes to gym.make itself: an env keyword argument may not set these.
SET_BY_RBBO = {
    "sim_dim": "M: --sim-dim, RBBOConfig.sim_dim",
    "control_dim": "C: --control-dim, RBBOConfig.control_dim",
    "control_basis": "B_c: the basis being evaluated",
}


# max_episode_steps for an env whose episodes the caller times itself (gym.make's None would
# keep the registered limit)
NO_TIME_LIMIT = 10**9


def _check_env_keywords(env_id: str, kwargs: dict[str, Any], set_here=SET_BY_RBBO) -> None:
    """Refuse a keyword the env's constructor does not take, naming those it does (Gymnasium's
    own error quotes every keyword's value, the basis array too), and one that rbbo sets
    itself (``set_here``: keyword -> what it is)."""
    import inspect

    import gymnasium as gym

    clash = [k for k in set_here if k in kwargs]
    if clash:
        raise ValueError(f"env keyword {clash[0]!r} is set by rbbo itself "
                         f"({set_here[clash[0]]}); {', '.join(set_here)} cannot be given as "
                         "env keywords")  # fmt: skip

    entry = gym.spec(env_id).entry_point
    try:
        creator = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
        if creator is None:  # (an id registered without an entry point: let gym.make say it)
            return
        params = inspect.signature(creator).parameters
    except (ImportError, AttributeError, TypeError, ValueError):  # let gym.make say it
        return
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    unknown = sorted(set(kwargs) - set(params))
    if unknown:
        known = ", ".join(
            k for k, p in params.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL
        )
        raise ValueError(f"{env_id} takes no keyword {', '.join(map(repr, unknown))}; its "
                         f"keywords: {known}")  # fmt: skip


@dataclass
class EnvObjective:
    """R(B_c, T, seed): the MPC controller's task reward on a softrom env, per second.

    Runs ``controllers.run_episode(env, planner, T, seed=seed, progress=False)`` with the env
    built for B_c and the controller's default planner for the benchmark,
    and returns the reward R (the task term only, not the regulariser Lambda) collected from
    the settle time on, divided by the time it covers:

        R = sum_{t_k >= t_settle} r_k / (T - t_settle)

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
        "mppi" or "gn" (Gauss-Newton shooting).
    settle_time : float
        t_settle, seconds.
    env_kwargs, planner_kwargs : dict
        Passed to ``gym.make`` and to the planner.
    """

    env_id: str
    sim_dim: int
    control_dim: int
    controller: str = "mppi"
    settle_time: float = 2.0
    env_kwargs: dict = field(default_factory=dict)
    planner_kwargs: dict = field(default_factory=dict)

    CONTROLLERS = ("mppi", "gn")

    def __post_init__(self) -> None:
        _check_dims(self.sim_dim, self.control_dim)
        if self.controller not in self.CONTROLLERS:
            raise ValueError(
                f"unknown controller {self.controller!r}; valid: {list(self.CONTROLLERS)}"
            )
        if not self.settle_time >= 0:
            raise ValueError(f"settle_time must be >= 0, got {self.settle_time!r}")
        self._env = None
        self._signature: list[float] | None = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_env"] = None  # a worker builds its own env
        return state

    def simulation_space(self) -> list[float] | None:
        """The env's B_r fingerprint (``Subspace.signature()``), None for an env without one."""
        if self._signature is None:
            env = self.make_env(np.eye(self.sim_dim)[:, : self.control_dim])
            try:
                subspace = getattr(env.unwrapped, "subspace", None)
                if subspace is not None and hasattr(subspace, "signature"):
                    self._signature = [float(v) for v in subspace.signature()]
            finally:
                env.close()
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
        planner, replan_every = controllers.planner_for(self.env_id, self.controller, dt=dt,
                                                        **self.planner_kwargs)  # fmt: skip
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
        result = self.episode(basis, T, seed, env)
        if str(getattr(result, "stop_reason", "")).startswith("truncated"):
            # (an env of the user's own wrapping): R would read the lost seconds as zero
            raise RuntimeError(f"the env's time limit ended the T = {T:g} s episode at "
                               f"{result.seconds:g} s")  # fmt: skip
        dt = getattr(result, "dt", None) or self.step_seconds(env)
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


def planner_record(planner: Any, replan_every: int) -> dict[str, Any]:
    """A planner's name, resolved settings and replan interval as JSON (what a run, or a
    cached MPC result, records of the planner that made it; threads are left out: results do
    not depend on them)."""
    import json

    settings = getattr(planner, "settings", None)
    if is_dataclass(settings) and not isinstance(settings, type):
        record = getattr(settings, "record", None)
        if callable(record):  # controllers.PlannerSettings: less neutral new settings
            settings = record()
        else:
            settings = {k: v for k, v in asdict(settings).items() if k != "threads"}
    else:  # a planner of the user's own without dataclass settings: its name only
        settings = None
    name = getattr(planner, "name", type(planner).__name__)
    return json.loads(json.dumps({"name": name, "replan_every": replan_every,
                                  "settings": settings}, default=repr))  # fmt: skip


def settled_step(step_seconds: float, settle_time: float) -> int:
    """The first env step that R counts: the first starting at or after the settle time."""
    return int(np.ceil(settle_time / step_seconds - 1e-9))


def settled_reward_rate(result, step_seconds: float, settle_time: float, seconds: float) -> float:
    """Task reward per second from ``settle_time`` to ``seconds``, from an EpisodeResult.

    Uses ``result.task_rewards`` when the controllers report the task term R separately,
    else ``result.rewards`` (per env step). Step k covers [k dt, (k + 1) dt); steps starting
    at or after t_settle count. An episode that ended early (diverged) counts the time it
    did not survive as zero reward, so a basis that makes the simulation blow up ranks low.

    The episode runs ``round(seconds / dt)`` whole steps (``controllers.run_episode``), so a
    ``seconds`` off that grid (BOCA's T = 2.667 s at dt = 0.025 s: 107 steps, 2.675 s) is
    divided by the time simulated, not the time asked for (which read R 0.5 % high there).
    """
    rewards = getattr(result, "task_rewards", None)
    if rewards is None:
        rewards = result.rewards
    r = np.asarray(rewards, dtype=float).ravel()
    start = settled_step(step_seconds, settle_time)
    seconds = float(seconds)
    simulated = max(1, round(seconds / step_seconds)) * step_seconds
    if not math.isclose(simulated, seconds, rel_tol=1e-9):
        # (on the grid, seconds itself, as before: the same R to the bit as recorded runs')
        seconds = simulated
    span = seconds - start * step_seconds
    if span <= 0:
        raise ValueError(
            f"an episode of {seconds} s is not longer than the settle time {settle_time} s"
        )
    kept = r[start:]
    return float(kept[np.isfinite(kept)].sum() / span)


_SYNTHETIC_KEYS = {"seed": int, "noise": float, "bias": float, "delay": float}


def parse_objective_spec(env_id: str) -> dict[str, Any]:
    """Turn an ENV_ID argument into an objective spec dict (see the module docstring)."""
    if not isinstance(env_id, str) or not env_id:
        raise ValueError(f"ENV_ID must be a non-empty string, got {env_id!r}")
    if env_id == "synthetic" or env_id.startswith("synthetic:"):
        spec: dict[str, Any] = {"kind": "synthetic"}
        body = env_id.partition(":")[2]
        for item in filter(None, body.split(",")):
            key, sep, value = item.partition("=")
            if not sep or key not in _SYNTHETIC_KEYS:
                raise ValueError(
                    f"bad synthetic option {item!r}; use key=value with keys "
                    f"{sorted(_SYNTHETIC_KEYS)}"
                )
            try:
                spec["optimum_seed" if key == "seed" else key] = _SYNTHETIC_KEYS[key](value)
            except ValueError:
                raise ValueError(f"synthetic option {key} needs a number, got {value!r}") from None
        return spec
    return {"kind": "env", "env_id": env_id}


def make_objective(spec: dict[str, Any], sim_dim: int, control_dim: int, *, new: bool = False,
                   **kwargs):  # fmt: skip
    """Build the objective a spec describes (``kwargs`` fill the spec's missing fields).

    A stored spec (a run's config.json) is checked against the simulator and planner as they
    are now (:class:`SimulationSpaceMismatch`, :class:`PlannerMismatch`); ``new=True``, for a
    spec a new run is about to record, skips the planner check: it records the planner.
    """
    spec = dict(spec)
    kind = spec.pop("kind", None)
    spec.pop("sim_dim", None)
    spec.pop("control_dim", None)
    if kind == "synthetic":
        return SyntheticObjective(sim_dim, control_dim, **{**kwargs, **spec})
    if kind == "env":
        recorded = spec.pop("simulation_space", None)
        planner = spec.pop("planner", None)
        objective = EnvObjective(sim_dim=sim_dim, control_dim=control_dim, **{**kwargs, **spec})
        objective.expect_simulation_space(recorded)
        if not new:
            objective.expect_planner(planner)
        return objective
    raise ValueError(f"unknown objective kind {kind!r}; valid: ['synthetic', 'env']")
