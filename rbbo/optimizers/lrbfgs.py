"""Limited-memory Riemannian BFGS as a pymanopt ``Optimizer``.

The paper maximises GP-UCB on the Grassmannian with a Riemannian quasi-Newton method (Yuan,
Huang, Absil & Gallivan 2016); pymanopt 2.x ships none, so this is one, written against
pymanopt's own manifold interface (``retraction``, ``transport``, ``inner_product``,
``norm``) so it runs on any pymanopt manifold.

Algorithm (Huang, Gallivan & Absil 2015, "A Broyden class of quasi-Newton methods for
Riemannian optimization"; the cautious update of Huang, Absil & Gallivan 2018):

1. direction d_k = -H_k grad f(x_k) from the two-loop recursion over the last ``memory``
   pairs (s_i, y_i), all transported to the tangent space at x_k (1 / <s_i, y_i> recomputed
   there, as the transport need not be isometric), with the initial scaling
   H_0 = <s, y> / <y, y> of the newest pair (steepest descent when there is none);
2. a weak-Wolfe line search along t -> R_{x_k}(t d_k) (bisection / doubling as in Lewis &
   Overton): Armijo f(R(t d)) <= f + c1 t <grad f, d>, curvature
   <grad f(R(t d)), T(d)> >= c2 <grad f, d>; an Armijo-only point is kept if the curvature
   condition cannot be met within the iteration budget;
3. s_k = T(t d_k), y_k = grad f(x_{k+1}) - T(grad f(x_k)); the pair is stored only if
   <s, y> >= 1e-4 ||grad f(x_{k+1})|| <s, s> (cautious update: keeps H positive definite
   on non-convex costs such as UCB);
4. a non-descent direction (possible after transports) clears the memory and restarts from
   steepest descent; so does a failed line search, once, with a short one (4 trials); a
   second failure ends the run ("line search failed": near a stationary point, the cost's
   round-off has been reached), as does a predicted decrease below 1e-15 |f|.

It stops with pymanopt's standard criteria (gradient norm, step size, iterations, cost
evaluations, time) and returns pymanopt's ``OptimizerResult`` with a readable
``stopping_criterion``.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np

from .._pymanopt import Optimizer, OptimizerResult, printer, pymanopt

__all__ = ["LRBFGS"]

_ROUND_OFF = 1e-15  # ~5 eps: a relative cost change this small is lost in round-off

# pymanopt manifolds whose metric is the Frobenius product of the ambient arrays
_FROBENIUS_METRIC = (
    pymanopt.manifolds.Grassmann,
    pymanopt.manifolds.Stiefel,
    pymanopt.manifolds.Sphere,
    pymanopt.manifolds.Euclidean,
)


class _Metric:
    """The manifold's inner product, with a fast path where it is the Frobenius product.

    pymanopt computes it with ``np.tensordot``, about 20 us a call on a 20 x 3 matrix; the
    two-loop recursion makes ~2 m of them per iteration, more than the acquisition itself
    costs. ``np.vdot`` on the flat arrays gives the same number in ~1 us.
    """

    def __init__(self, manifold):
        self.manifold = manifold
        self.frobenius = isinstance(manifold, _FROBENIUS_METRIC)

    def __call__(self, x, a, b) -> float:
        if self.frobenius:
            return float(np.vdot(a, b))
        return float(self.manifold.inner_product(x, a, b))


class LRBFGS(Optimizer):
    """Limited-memory Riemannian BFGS with a weak-Wolfe line search.

    Parameters
    ----------
    memory : int
        Number of (s, y) pairs kept.
    c1, c2 : float
        Armijo and curvature constants of the line search (0 < c1 < c2 < 1).
    max_line_search : int
        Trial steps per line search (12 halvings shrink the step 4096-fold: a direction
        that needs more is not worth following).
    **kwargs
        pymanopt's stopping criteria and verbosity (``max_iterations``,
        ``min_gradient_norm``, ``min_step_size``, ``max_cost_evaluations``, ``max_time``,
        ``verbosity``, ``log_verbosity``).
    """

    def __init__(
        self,
        memory: int = 10,
        c1: float = 1e-4,
        c2: float = 0.9,
        max_line_search: int = 12,
        **kwargs,
    ):
        kwargs.setdefault("verbosity", 0)
        super().__init__(**kwargs)
        for name, value in (("memory", memory), ("max_line_search", max_line_search)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not 0 < c1 < c2 < 1:
            raise ValueError(f"need 0 < c1 < c2 < 1, got c1 = {c1}, c2 = {c2}")
        self._memory = int(memory)
        self._c1 = float(c1)
        self._c2 = float(c2)
        self._max_line_search = int(max_line_search)

    def _direction(self, manifold, x, grad, pairs):
        """Two-loop recursion: -H grad with H the L-BFGS inverse Hessian approximation."""
        q = grad
        alphas = []
        for s, y, rho in reversed(pairs):
            a = rho * self._inner(x, s, q)
            alphas.append(a)
            q = q - a * y
        if pairs:
            s, y, _ = pairs[-1]
            q = (self._inner(x, s, y) / self._inner(x, y, y)) * q
        for (s, y, rho), a in zip(pairs, reversed(alphas), strict=True):
            b = rho * self._inner(x, y, q)
            q = q + (a - b) * s
        return -q

    def _transport_pairs(self, manifold, x, new_x, pairs) -> deque:
        """Move the stored pairs to the tangent space at new_x.

        pymanopt's transports need not be isometric (the Grassmannian's is a projection), so
        1 / <s, y> is recomputed after the move and pairs that lose positive curvature are
        dropped.
        """
        moved: deque = deque(maxlen=self._memory)
        for s, y, _ in pairs:
            ts, ty = manifold.transport(x, new_x, s), manifold.transport(x, new_x, y)
            sy = self._inner(new_x, ts, ty)
            if sy > 0:
                moved.append((ts, ty, 1.0 / sy))
        return moved

    def _line_search(self, problem, x, cost, d, df0, step0, max_trials):
        """Weak-Wolfe line search; returns (t, new_x, new_cost, new_grad, evaluations)."""
        manifold = problem.manifold
        lo, hi = 0.0, np.inf
        t = step0
        armijo_point = None
        evaluations = 0
        for _ in range(max_trials):
            new_x = manifold.retraction(x, t * d)
            new_cost = problem.cost(new_x)
            evaluations += 1
            if not np.isfinite(new_cost) or new_cost > cost + self._c1 * t * df0:
                hi = t
            else:
                new_grad = problem.riemannian_gradient(new_x)
                armijo_point = (t, new_x, new_cost, new_grad)
                slope = self._inner(new_x, new_grad, manifold.transport(x, new_x, d))
                if slope >= self._c2 * df0:
                    return (*armijo_point, evaluations)
                lo = t
            t = 0.5 * (lo + hi) if np.isfinite(hi) else 2.0 * lo
        if armijo_point is not None:
            return (*armijo_point, evaluations)
        return 0.0, x, cost, None, evaluations

    def run(self, problem, *, initial_point=None) -> OptimizerResult:
        """Minimise ``problem.cost`` from ``initial_point`` (random if None)."""
        manifold = problem.manifold
        self._inner = _Metric(manifold)
        x = manifold.random_point() if initial_point is None else initial_point
        cost = problem.cost(x)
        grad = problem.riemannian_gradient(x)
        gradient_norm = manifold.norm(x, grad)
        cost_evaluations = 1
        pairs: deque = deque(maxlen=self._memory)
        # pymanopt's own optimizers' output: a line at verbosity 1, a row per iteration at 2
        if self._verbosity >= 1:
            print("Optimizing...")
        if self._verbosity >= 2:
            columns = printer.ColumnPrinter(
                columns=[("Iteration", f"{len(str(self._max_iterations))}d"),
                         ("Cost", "+.16e"), ("Gradient norm", ".8e")]
            )  # fmt: skip
        else:
            columns = printer.VoidPrinter()
        columns.print_header()
        self._initialize_log(
            optimizer_parameters={"memory": self._memory, "c1": self._c1, "c2": self._c2}
        )
        iteration = 0
        step_size = np.inf
        retrying = False
        start_time = time.time()
        while True:
            columns.print_row([iteration, cost, gradient_norm])
            self._add_log_entry(
                iteration=iteration, point=x, cost=cost, gradient_norm=gradient_norm
            )
            stopping_criterion = self._check_stopping_criterion(
                start_time=start_time,
                iteration=iteration,
                gradient_norm=gradient_norm,
                step_size=step_size,
                cost_evaluations=cost_evaluations,
            )
            if stopping_criterion:
                break
            iteration += 1

            d = self._direction(manifold, x, grad, list(pairs))
            df0 = self._inner(x, grad, d)
            if not df0 < 0:
                pairs.clear()
                d, df0 = -grad, -(gradient_norm**2)
            step0 = 1.0 if pairs else min(1.0, 1.0 / max(gradient_norm, 1e-300))
            if -df0 * step0 <= _ROUND_OFF * max(1.0, abs(cost)):
                # the decrease the model promises is below the cost's round-off: done
                stopping_criterion = (
                    f"Terminated - predicted decrease below round-off after {iteration} "
                    f"iterations, {time.time() - start_time:.2f} seconds."
                )
                break
            # a retry after a failed quasi-Newton step gets a few trials only: near a
            # stationary point the failure usually means the cost's round-off was reached
            trials = 4 if retrying else self._max_line_search
            t, new_x, new_cost, new_grad, evaluations = self._line_search(
                problem, x, cost, d, df0, step0, trials
            )
            cost_evaluations += evaluations
            retrying = False
            if new_grad is None:
                if pairs:  # a poor quasi-Newton direction: retry from steepest descent
                    pairs.clear()
                    retrying = True
                    continue
                stopping_criterion = (
                    f"Terminated - line search failed after {iteration} iterations, "
                    f"{time.time() - start_time:.2f} seconds."
                )
                step_size = 0.0
                break
            step_size = t * manifold.norm(x, d)
            s = manifold.transport(x, new_x, t * d)
            y = new_grad - manifold.transport(x, new_x, grad)
            pairs = self._transport_pairs(manifold, x, new_x, pairs)
            sy = self._inner(new_x, s, y)
            new_gradient_norm = manifold.norm(new_x, new_grad)
            if sy >= 1e-4 * new_gradient_norm * self._inner(new_x, s, s) and sy > 0:
                pairs.append((s, y, 1.0 / sy))
            x, cost, grad, gradient_norm = new_x, new_cost, new_grad, new_gradient_norm

        if self._verbosity >= 1:
            print(stopping_criterion)
        return self._return_result(
            start_time=start_time,
            point=x,
            cost=cost,
            iterations=iteration,
            stopping_criterion=stopping_criterion,
            cost_evaluations=cost_evaluations,
            step_size=step_size,
            gradient_norm=gradient_norm,
        )
