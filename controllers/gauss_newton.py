"""Gauss-Newton spline shooting (the paper's MPC in control space).

The knots x = vec(F~_c) (K C values, units of the action bound) are improved by maximising
J(x) = R(x) - |r(x)|^2 - w_d n_lost(x) (see :mod:`controllers.cost`). One iteration:

1. the Jacobians of R and of the residuals r (every per-step term: COM, orientation,
   control) with respect to the K C knots by forward differences, the K C + 1 trajectories
   in one batched ``rollout`` (a knot near the bound is perturbed inwards, so that the
   env's clipping does not flatten the difference);
2. the Gauss-Newton step with Levenberg damping mu (m per unit knot^2),
   ``dx = (2 J_r^T J_r + mu I)^-1 (grad R - 2 J_r^T r)``; R is linear in the trajectory, so
   its Hessian vanishes and Λ's Gauss-Newton term carries the curvature;
3. a batched line search: the steps for ``len(line_search)`` damping values
   ``mu * line_search[i]`` run in one rollout, and the best is taken only if it raises J.
   mu then moves to the accepted value (or, when none is accepted, to ten times the largest
   value tried: 1000 mu with the default ``line_search``; mu is kept in [1e-150, 1e150]), so
   an iteration never lowers the objective. mu carries over from replan to replan: after a run of
   rejections (where the finite-difference gradient through contact misleads) the step
   shrinks to nothing and only the exploration candidates move the plan (on the quadruped mu
   passed 1e4 after 2-4.5 s on each of 3 seeds, and reached 1e38 by 10 s on one).
   Restarting mu at each replan (``restart_damping``) was measured (``python
   benchmarks/bench_mpc.py QuadrupedWalk-v0 TripodWalk-v0 CrossWalk-v0 BeamWalk-v0 --planners
   gn --seeds 0 1 2 [--mpc restart_damping=true]``, t = 2..10 s, body lengths, mean ± sd over
   seeds; AMD EPYC, 2026-12-05): the quadruped 2.16 ± 1.07 against 1.58 ± 0.69, the tripod
   0.67 ± 0.21 against 0.89 ± 0.35, the cross 0.77 against 0.74 and the beam 1.40 against
   1.40; within the chaotic spread, so not the default. With ``max_step`` each step (and each
   exploration candidate of 4.) is first scaled into a trust region (no knot moves by more
   than ``max_step``): a gait then changes gradually from replan to replan, where a full
   step can trade it for a one-horizon lunge;
4. with ``explore > 0`` the same rollout also runs that many random candidates around the
   plan, under the same acceptance rule. A finite-difference gradient through contact sees
   one basin of a kinked objective; on the quadruped and the tripod the pure step kept the
   seed gait's basin (0.14 and 0.38 body lengths, mean of 3 seeds, t = 2..10 s) and 8
   candidates found far better gaits (1.52 and 1.05, see ``controllers/defaults.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from .cost import Evaluation
from .planner import Planner
from .settings import PlannerSettings, _check_int, _check_positive, _real_tuple

__all__ = ["GaussNewtonSettings", "GaussNewtonShooting"]

# Each rejected iteration multiplies mu by 10 max(line_search) (1000 by default), so a long
# run of them (a minute of quadruped walking) would overflow to inf and the knots to NaN. The
# step is nil long before this cap, which only keeps the arithmetic finite. The floor keeps mu
# positive: an accepted step with a tiny multiplier could underflow it to 0, where the
# rejections' "ten times the largest tried" would leave it for good (an undamped solve).
_MAX_DAMPING = 1e150
_MIN_DAMPING = 1e-150


@dataclass(frozen=True)
class GaussNewtonSettings(PlannerSettings):
    """:class:`PlannerSettings` plus

    Attributes
    ----------
    iterations : int
        Gauss-Newton iterations per replan.
    fd_step : float
        Finite-difference step on a knot, in units of the action bound.
    damping : float
        Initial Levenberg damping mu (m per unit knot^2), between 1e-150 and 1e150 (the range
        mu is kept in).
    line_search : tuple of float
        Multipliers of mu tried in one batched rollout (a product outside mu's range is
        taken at its end).
    max_step : float or None
        Trust region: each trial step, and each exploration candidate's perturbation, is
        scaled down so that no knot moves by more than this (units of the bound); None: no
        limit.
    explore : int
        Random candidates added to the line search's rollout: the plan plus Gaussian noise of
        ``explore_noise`` (units of the bound), seeded by ``reset``. They compete with the
        Gauss-Newton steps under the same rule (the best is taken only if it raises J), so
        a replan can leave a basin that the local step cannot see out of. 0: pure GN.
    explore_noise : float
        Standard deviation of the exploration candidates.
    restart_damping : bool
        Start every replan from ``damping`` instead of the mu the last one ended with (which
        a run of rejected iterations can have raised until the step is nil; see the module
        docstring for what each measured).
    """

    iterations: int = 1
    fd_step: float = 0.02
    damping: float = 0.01
    line_search: tuple[float, ...] = (0.1, 1.0, 10.0, 100.0)
    max_step: float | None = None
    explore: int = 0
    explore_noise: float = 0.15
    restart_damping: bool = False

    # Added after runs began recording their planner; at these values Gauss-Newton plans as
    # it did before they existed (see PlannerSettings.record).
    _neutral_since_records: ClassVar[dict[str, Any]] = {"restart_damping": False}

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_int("iterations", self.iterations)
        _check_positive("fd_step", self.fd_step)
        if self.fd_step > 0.5:
            raise ValueError(f"fd_step must be <= 0.5 (units of the bound), got {self.fd_step}")
        _check_positive("damping", self.damping)
        if not _MIN_DAMPING <= self.damping <= _MAX_DAMPING:
            raise ValueError(f"damping must be between {_MIN_DAMPING:g} and {_MAX_DAMPING:g} "
                             f"(m per unit knot^2), got {self.damping!r}")  # fmt: skip
        if self.max_step is not None:
            _check_positive("max_step", self.max_step)
        _check_int("explore", self.explore, low=0)
        _check_positive("explore_noise", self.explore_noise)
        if not isinstance(self.restart_damping, (bool, np.bool_)):
            raise TypeError(f"restart_damping must be True or False, got {self.restart_damping!r}")
        ls = _real_tuple(self, "line_search")
        if ls.size == 0 or not np.all(np.isfinite(ls) & (ls > 0)):
            raise ValueError(f"line_search must be positive numbers, got {self.line_search!r}")


class GaussNewtonShooting(Planner):
    """Gauss-Newton shooting over spline knots (see the module docstring)."""

    name = "gn"
    settings: GaussNewtonSettings
    settings_class = GaussNewtonSettings

    def __init__(
        self, settings: GaussNewtonSettings | None = None, *, dt: float | None = None
    ) -> None:
        settings = GaussNewtonSettings() if settings is None else settings
        if not isinstance(settings, GaussNewtonSettings):
            raise TypeError(f"settings must be GaussNewtonSettings, got {type(settings).__name__}")
        super().__init__(settings, dt=dt)

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self.damping_ = float(self.settings.damping)

    def jacobian(
        self, state: Any, knots: np.ndarray | None = None
    ) -> tuple[Evaluation, np.ndarray, np.ndarray]:
        """Forward-difference Jacobians at ``knots`` (default: the plan's), one rollout.

        Returns
        -------
        base : Evaluation of the K C + 1 rollouts (row 0 unperturbed)
        grad_reward : (K C,) dR/dx
        jac_residuals : (n, K C) dr/dx
        """
        x = (self.spline.knots if knots is None else knots).ravel()
        h = self.settings.fd_step
        steps = np.where(x + h <= 1.0, h, -h)  # stay inside the bound
        batch = np.repeat(x[None], x.size + 1, axis=0)
        batch[1:] += np.diag(steps)
        ev = self.evaluate_knots(state, batch.reshape(-1, *self.spline.knots.shape))
        grad = (ev.reward[1:] - ev.reward[0]) / steps
        jac = ((ev.residuals[1:] - ev.residuals[0]) / steps[:, None]).T
        return ev, grad, jac

    def optimise(self, state: Any) -> None:
        s, plan = self.settings, self.spline
        shape = plan.knots.shape
        if s.restart_damping:
            self.damping_ = float(s.damping)
        history, accepted = [], []
        for _ in range(s.iterations):
            ev, grad, jac = self.jacobian(state)
            j0 = float(ev.objective[0])
            x = plan.knots.ravel()
            g = grad - 2.0 * jac.T @ ev.residuals[0]
            hess = 2.0 * jac.T @ jac
            # (mu near an end of its range times a large or small multiplier leaves the
            # floats: inf would make every step NaN, and 0 an undamped solve)
            with np.errstate(over="ignore", under="ignore"):
                mus = self.damping_ * np.asarray(s.line_search, dtype=float)
            mus = np.clip(mus, _MIN_DAMPING, _MAX_DAMPING)
            eye = np.eye(x.size)
            steps = [np.linalg.solve(hess + mu * eye, g) for mu in mus]
            if s.max_step is not None:
                steps = [dx * min(1.0, s.max_step / max(np.abs(dx).max(), 1e-300))
                         for dx in steps]  # fmt: skip
            candidates = [np.clip(x + dx, -1.0, 1.0) for dx in steps]
            if s.explore:
                noise = s.explore_noise * self.rng_.standard_normal((s.explore, x.size))
                if s.max_step is not None:  # the candidates stay in the trust region too
                    largest = np.maximum(np.abs(noise).max(axis=1, keepdims=True), 1e-300)
                    noise *= np.minimum(1.0, s.max_step / largest)
                candidates.extend(np.clip(x[None] + noise, -1.0, 1.0))
            trials = np.stack(candidates)
            trial = self.evaluate_knots(state, trials.reshape(-1, *shape))
            best = int(np.argmax(trial.objective))
            if trial.objective[best] > j0:
                plan.knots = trials[best].reshape(shape)
                kind = "step" if best < len(mus) else "explore"
                if kind == "step":  # a Gauss-Newton step: its damping carries on
                    self.damping_ = float(mus[best])
                accepted.append(kind)
                history.append((j0, float(trial.objective[best])))
            else:
                self.damping_ = min(float(mus.max() * 10.0), _MAX_DAMPING)
                accepted.append("none")
                history.append((j0, j0))
        self.last_.update(
            objective_start=history[0][0],
            objective_best=history[-1][1],
            objectives=history,
            accepted=accepted,  # per iteration: "step", "explore" or "none"
            damping=self.damping_,
        )
