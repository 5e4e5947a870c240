"""The planner interface (as MuJoCo MPC's): ``reset``, ``plan``, ``action`` (and ``predict``,
the plan's expected course). Their shared settings are :mod:`controllers.settings`.

A planner owns a :class:`SplinePlan` of normalised knots (units of the action bound a) and
reaches the env only through its public MPC API (``get_state``, ``rollout``,
``action_bound``, ``dt``, ``direction``, ``center_of_mass``, found with
``env.get_wrapper_attr`` through any wrappers) and its action space.

Receding-horizon use::

    planner.reset(env, seed=0)
    for t in range(steps):
        if t % replan_every == 0:
            planner.plan(env)          # optimise the knots from the env's current state
        env.step(planner.action(env))  # f_c now; the plan's clock advances one step
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from .cost import Evaluation, evaluate
from .gaits import gait_grid
from .settings import PlannerSettings, _check_positive
from .spline import SplinePlan, _positive_int

__all__ = ["EnvAPI", "Planner", "PlannerSettings", "check_physical_actions"]


def check_physical_actions(env: Any) -> None:
    """The planners return f_c in the robot's own units; an action wrapper (RescaleAction to
    [-1, 1], or one of the user's) would transform them again. ClipAction only clips to the
    robot's box, as the env itself does, so it may stay."""
    import gymnasium as gym

    layer = env
    while isinstance(layer, gym.Wrapper):
        if isinstance(layer, gym.ActionWrapper) and not isinstance(layer, gym.wrappers.ClipAction):
            raise ValueError(
                f"the env is wrapped in {type(layer).__name__}, an action wrapper: it would "
                "transform the planner's actions, which are already f_c in the robot's units "
                f"(its box {env.unwrapped.action_space}); plan on the env without it"
            )
        layer = layer.env


class EnvAPI:
    """The env's MPC API reached through any gymnasium wrappers."""

    def __init__(self, env: Any) -> None:
        try:
            get = env.get_wrapper_attr
        except AttributeError:
            raise TypeError(f"env must be a gymnasium Env, got {type(env).__name__}") from None
        for name in ("get_state", "rollout", "action_bound", "dt", "direction", "center_of_mass"):
            try:
                get(name)
            except AttributeError:
                raise TypeError(
                    f"env has no {name!r}: planners need a softrom_gym env (get_state, "
                    "rollout, action_bound, dt, direction, center_of_mass)"
                ) from None
        self.get_state = get("get_state")
        self.rollout = get("rollout")
        self.bound = float(get("action_bound"))
        self.dt = float(get("dt"))
        self.direction = np.asarray(get("direction"), dtype=float)
        self.control_dim = int(env.action_space.shape[0])
        self.center_of_mass = get("center_of_mass")
        self.unwrapped = env.unwrapped


class Planner(ABC):
    """Receding-horizon planner over a spline of knots in control space.

    Parameters
    ----------
    settings : PlannerSettings
    dt : float or None
        The control period (s) whose env steps the settings' times count: :meth:`reset`
        refuses an env that steps another (its gait would run at another frequency).
        :func:`controllers.planner_for` sets it; None leaves it unchecked.

    Subclasses implement :meth:`optimise` (one replan's update of :attr:`spline`'s knots); see
    "Writing a planner" below. After :meth:`plan`, ``last_`` holds the replan's record:
    ``objective_start`` (J of the warm-started plan), ``objective_best`` (Gauss-Newton: J of the
    plan it adopts; MPPI: J of its best sample, since the weighted mean it adopts is not rolled
    out, which would cost another rollout), ``rollouts`` and ``wall_s``; MPPI adds
    ``effective_samples`` (1 / sum of the squared weights), Gauss-Newton ``objectives`` (J
    before and after each iteration), ``accepted`` ("step", "explore" or "none" per iteration)
    and ``damping`` (mu after them). With ``gait_seed``, :meth:`reset` leaves ``seed_``: the
    gait chosen (``gait``, its label), its ``objective`` and its cycle (``period``, env steps).

    Writing a planner
    -----------------
    Subclass :class:`Planner` (and :class:`PlannerSettings`, a frozen dataclass, for settings
    of its own: ``from_shared`` copies a benchmark default's plan and objective into them; name
    it in ``settings_class``), set ``name`` (it labels :class:`~controllers.EpisodeResult` and
    the progress bar) and implement :meth:`optimise`, one replan from ``state`` (the env's, a
    ``ReducedState`` copy). :meth:`plan` has shift-warm-started the plan and reset ``last_``
    before calling it, and :meth:`action` then reads the plan. What a subclass may use:

    * ``self.spline``: the :class:`SplinePlan` (``plan_``, typed as one and raising before
      :meth:`reset`); update ``spline.knots`` (K, C), in units of the action bound a, within
      [-1, 1] (the controls are clipped to it).
    * ``self.evaluate_knots(state, knots)``: R - Λ (an :class:`~controllers.Evaluation`,
      ``objective`` (B,)) of a batch of knots (B, K, C) in one batched rollout, scored with
      the settings' weights and window as the shipped planners score theirs; it counts the
      rollouts in ``last_["rollouts"]``.
    * ``self.rng_``: a ``numpy.random.Generator`` seeded by :meth:`reset` (draw from it, and
      a seeded episode repeats).
    * ``self.api_``: the env's MPC API (``rollout``, ``get_state``, ``center_of_mass``,
      ``bound``, ``dt``, ``direction``, ``control_dim``), for a planner that rolls out
      controls of its own; :func:`controllers.evaluate` scores them.
    * ``self.last_``: add ``objective_start`` and ``objective_best`` (and terms of its own)
      for :func:`~controllers.run_episode`'s ``replan_records``.

    Leave the env's state as it was: try plans with ``rollout``, not ``step`` (which also
    counts against the env's time limit); :func:`~controllers.run_episode` raises
    RuntimeError if ``plan`` or ``action`` moved it. ``examples/cem_planner.py`` is a
    cross-entropy method written this way; :func:`controllers.register_planner` (or the
    import path ``package.module:ClassName``) lets ``python -m controllers --planner``,
    :func:`controllers.planner_for` and ``rbbo optimize --controller`` choose it by name.

    The names of before (``_optimise``, ``_evaluate``, ``_plan``) still work for this release
    with a DeprecationWarning naming their successor.
    """

    name = "planner"
    #: The settings' class: what a planner chosen by name (:func:`controllers.planner_for`)
    #: is made with. A planner with settings of its own names their class here.
    settings_class: ClassVar[type[PlannerSettings]] = PlannerSettings

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        # The hook was private before it was public: a planner written then overrides
        # _optimise, and plan() now calls optimise. Forward to it (for one release), named.
        legacy = vars(cls).get("_optimise")
        if legacy is not None and "optimise" not in vars(cls):
            warnings.warn(
                f"{cls.__qualname__} overrides Planner._optimise, which is deprecated: "
                "rename it optimise(self, state), the public hook plan() calls (_optimise "
                "stops being called in the next release)",
                DeprecationWarning,
                stacklevel=3,  # (the class statement: this, then ABCMeta.__new__)
            )

            def optimise(self: Planner, state: Any) -> None:
                legacy(self, state)

            optimise.__doc__ = f"Forwards to {cls.__qualname__}._optimise (deprecated)."
            optimise._forwards_to_optimise_ = True  # type: ignore[attr-defined]
            cls.optimise = optimise  # type: ignore[method-assign]

    def __init__(self, settings: PlannerSettings, *, dt: float | None = None) -> None:
        if not isinstance(settings, PlannerSettings):
            raise TypeError(f"settings must be a PlannerSettings, got {type(settings).__name__}")
        if dt is not None:
            _check_positive("dt (the control period the settings' env steps are of, s)", dt)
        self.settings = settings
        # The control period (s) whose env steps the settings' times count (None: unchecked):
        # on an env with another, the gait would run at another frequency, unseen.
        self.dt = None if dt is None else float(dt)
        self.plan_: SplinePlan | None = None
        self.last_: dict[str, Any] = {}

    @property
    def spline(self) -> SplinePlan:
        """The plan being optimised (``plan_``, which :meth:`reset` makes), typed as a
        :class:`SplinePlan`: raises RuntimeError before :meth:`reset`."""
        if self.plan_ is None:
            raise RuntimeError(f"{type(self).__name__}.reset(env, seed) must be called first")
        return self.plan_

    @property
    def _plan(self) -> SplinePlan:
        """Deprecated name of :attr:`spline`."""
        warnings.warn("Planner._plan is deprecated: use Planner.spline", DeprecationWarning,
                      stacklevel=2)  # fmt: skip
        return self.spline

    # ----------------------------------------------------------------- interface
    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start a new episode: an empty (or gait-seeded) plan and a fresh random stream.

        Refuses an env in an action wrapper (other than ``ClipAction``: the actions are f_c in
        the robot's units, which ``RescaleAction`` would scale again) and, for a planner made
        for a control period (``dt``), an env that steps another.
        """
        s = self.settings
        if seed is not None and (
            isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0
        ):
            raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
        check_physical_actions(env)
        api = EnvAPI(env)
        # (a float32 dt, 0.05 as 0.050000000745, is the same period: a mismatch that matters
        # is a factor of 2 or more)
        if self.dt is not None and not math.isclose(api.dt, self.dt, rel_tol=1e-6):
            raise ValueError(
                f"{type(self).__name__}'s settings count env steps of a {self.dt:.6g} s "
                f"control period, but the env steps {api.dt:.6g} s: its gait would run "
                f"{self.dt / api.dt:.3g}x as fast as planned. Make the planner for the env's "
                "period: controllers.planner_for(env_id, planner, "
                "dt=env.get_wrapper_attr('dt'))"
            )
        self._check_env(api)
        self.api_ = api
        self.rng_ = np.random.default_rng(seed)
        self.plan_ = SplinePlan(s.horizon, s.knots, self.api_.control_dim, s.kind, s.period)
        self.last_ = {}
        if s.gait_seed:
            self._seed_gait()

    def _check_env(self, api: EnvAPI) -> None:
        """Raise ValueError if the settings cannot plan for this env (before :meth:`reset`
        changes anything)."""
        self.settings.check_control_dim(api.control_dim)

    def plan(self, env: Any) -> None:
        """One replan from the env's current state: shift-warm-started, then optimised."""
        self._require_reset(env)
        start = time.perf_counter()
        state = self.api_.get_state()
        self.last_ = {"rollouts": 0}
        self.spline.rebase()  # an open plan's knots move to the steps since the last replan
        self.optimise(state)
        self.last_["wall_s"] = time.perf_counter() - start

    def action(self, env: Any) -> np.ndarray:
        """f_c (C,) for the env's current step; the plan's clock then advances one step."""
        self._require_reset(env)
        f_c = self.api_.bound * np.clip(self.spline.value(0.0), -1.0, 1.0)
        self.spline.shift(1)
        return f_c

    def predict(self, env: Any) -> dict[str, Any]:
        """The current plan rolled out from the env's state, changing neither: what the
        planner expects over its horizon (one rollout; MuJoCo MPC draws the same).

        Returns ``controls`` (H, C), the f_c that :meth:`action` would send at each step;
        ``com`` (H, 3), the centre of mass after each step; ``rewards`` (H,), R per step (m);
        and ``objective``, R - Λ over the settings' window, as a replan scores a plan.
        """
        self._require_reset(env)
        # step by step as action() reads the plan, on a copy (the batched spline matrix
        # differs from it by round-off, and then so would the course)
        plan = copy.deepcopy(self.spline)
        u = np.empty((1, plan.horizon, plan.control_dim))
        for t in range(plan.horizon):
            u[0, t] = np.clip(plan.value(0.0), -1.0, 1.0)
            plan.shift(1)
        state = self.api_.get_state()
        out = self.api_.rollout(state, self.api_.bound * u, threads=self.settings.threads)
        ev = evaluate(out, u, self.api_.center_of_mass(state), self.api_.direction, self.api_.dt,
                      self.settings.weights, self.settings.window)  # fmt: skip
        return {"controls": self.api_.bound * u[0], "com": np.asarray(out["com"][0]),
                "rewards": np.asarray(out["rewards"][0]),
                "objective": float(ev.objective[0])}  # fmt: skip

    # ----------------------------------------------------------------- for subclasses
    @abstractmethod
    def optimise(self, state: Any) -> None:
        """One replan from ``state`` (the env's, a ``ReducedState`` copy): update
        ``self.spline.knots`` and add ``objective_start`` / ``objective_best`` to ``last_``.

        The hook a planner implements; :meth:`plan` calls it after the warm start (see
        "Writing a planner" in the class docstring). Leave the env's state as it was.
        """

    def _optimise(self, state: Any) -> None:
        """Deprecated name of :meth:`optimise` (``super()._optimise(state)`` of a planner
        written before it runs its base's :meth:`optimise`)."""
        warnings.warn("Planner._optimise is deprecated: call Planner.optimise",
                      DeprecationWarning, stacklevel=2)  # fmt: skip
        for klass in type(self).__mro__:
            hook = vars(klass).get("optimise")
            if hook is not None and not getattr(hook, "_forwards_to_optimise_", False):
                hook(self, state)
                return

    def evaluate_knots(
        self, state: Any, knots: np.ndarray, horizon: int | None = None
    ) -> Evaluation:
        """R - Λ of a batch of knots (B, K, C) from ``state``, in one batched rollout.

        ``knots`` are in units of the action bound (clipped to [-1, 1] with the controls);
        ``horizon`` (default: the plan's) rolls each out over that many env steps, reading the
        same spline from the plan's clock (an open plan holds its last value past its own
        horizon; a periodic one repeats its cycle). Scored with
        the settings' weights and window, as the shipped planners score theirs; counts the
        rollouts in ``last_["rollouts"]``.
        """
        plan = self.spline
        knots = np.asarray(knots, dtype=float)
        expected = (plan.num_knots, plan.control_dim)
        # (named here: the env would name the spline's controls, not the knots given)
        if knots.ndim != 3 or knots.shape[1:] != expected:
            raise ValueError(
                f"knots has shape {knots.shape}, expected (B, {expected[0]}, {expected[1]}): "
                "a batch of B plans' knots (one plan's knots K x C: knots[None])"
            )
        if horizon is None:
            controls = plan.controls(knots)
        else:
            # The plan's own weights over the longer (or shorter) time: a new SplinePlan of
            # that horizon would space an open plan's knots over it, stretching the plan.
            horizon = _positive_int("horizon", horizon)
            weights = plan.weights(plan.offset + np.arange(horizon))
            controls = np.einsum("hk,...kc->...hc", weights, knots)
        return self._evaluate_controls(state, np.clip(controls, -1.0, 1.0), horizon)

    def _evaluate(self, state: Any, knots: np.ndarray, horizon: int | None = None) -> Evaluation:
        """Deprecated name of :meth:`evaluate_knots`."""
        warnings.warn("Planner._evaluate is deprecated: use Planner.evaluate_knots",
                      DeprecationWarning, stacklevel=2)  # fmt: skip
        return self.evaluate_knots(state, knots, horizon)

    # ----------------------------------------------------------------- helpers
    def _require_reset(self, env: Any = None) -> None:
        self.spline  # noqa: B018  (raises before reset)
        # The plan lives in the env it was reset on: planning another env's state from it
        # would be silently wrong.
        if env is not None and getattr(env, "unwrapped", env) is not self.api_.unwrapped:
            raise ValueError(
                f"{type(self).__name__} was reset on another env: call reset(env, seed) first"
            )

    def _evaluate_controls(self, state: Any, u: np.ndarray, horizon: int | None) -> Evaluation:
        """R - Λ of controls u (B, H, C) in units of the bound, in one batched rollout."""
        out = self.api_.rollout(state, self.api_.bound * u, threads=self.settings.threads)
        self.last_["rollouts"] = self.last_.get("rollouts", 0) + u.shape[0]
        window = self.settings.window
        if horizon is not None and window is not None:
            window = min(window, horizon)
        return evaluate(out, u, self.api_.center_of_mass(state), self.api_.direction, self.api_.dt,
                        self.settings.weights, window)  # fmt: skip

    def _seed_gait(self) -> None:
        """Replace the knots by the best sinusoid at the period's frequency (or at one of
        ``seed_periods``', whose cycle the plan then takes)."""
        s, plan = self.settings, self.spline
        assert s.period is not None  # (gait_seed needs one: the settings check it)
        horizon = s.seed_horizon or plan.horizon
        candidates, controls = [], []
        for period in (s.period, *s.seed_periods):
            frequency = 1.0 / (period * self.api_.dt)
            gaits = gait_grid(plan.control_dim, (frequency,), tuple(s.seed_amplitudes))
            trial = SplinePlan(horizon, plan.num_knots, plan.control_dim, plan.kind, period)
            # Knots that interpolate each sinusoid (the cubic passes through its knots).
            times = trial.spacing * np.arange(plan.num_knots) * self.api_.dt
            knots = np.stack([
                np.clip(g.amplitude * np.sin(2 * np.pi * frequency * times[:, None]
                                             + np.asarray(g.phases)), -1.0, 1.0)
                for g in gaits
            ])  # fmt: skip
            candidates += [(period, g, k) for g, k in zip(gaits, knots, strict=True)]
            controls.append(np.clip(trial.controls(knots), -1.0, 1.0))
        self.last_ = {}
        ev = self._evaluate_controls(self.api_.get_state(), np.concatenate(controls), horizon)
        best = int(np.argmax(ev.objective))
        period, gait, knots = candidates[best]
        if period != plan.period:
            self.plan_ = plan = SplinePlan(plan.horizon, plan.num_knots, plan.control_dim,
                                           plan.kind, period)  # fmt: skip
        plan.knots = knots.copy()
        self.seed_ = {"gait": gait.label(), "objective": float(ev.objective[best]),
                      "period": float(period)}  # fmt: skip
