"""``SplinePlan``: H env steps of controls F_c from K knots per control dimension, F_c = S F~_c.

The paper regularises a plan by a spline through K control points (its ``S`` is the
(HC x KC) interpolation matrix). We use a *piecewise* cubic rather than one polynomial of
degree K - 1: a high-degree polynomial is ill-conditioned and every knot moves the whole
horizon, while a local cubic lets a knot shape only its neighbourhood.

* ``kind="cubic"``: the Catmull-Rom spline (C1, interpolating: the control at a knot time is
  the knot). Each segment is the cubic Hermite interpolant with central-difference slopes.
  At the ends the missing neighbour is the linear extrapolation of the last two knots, so
  constant and linear signals are reproduced exactly.
* ``kind="linear"``: piecewise linear between the knots.

A plan is either *open* (the knots span the horizon, at steps ``k (H - 1) / (K - 1)``; one knot
means a constant plan) or *periodic* with a period of P env steps (the knots at
``k P / K`` and the spline wrapping around, so that the H steps may cover several cycles of
one gait). The plan has a clock (``offset``, env steps): ``controls()`` are the H steps from
it. ``shift(n)`` moves the clock n steps into the future, exactly for any n (so n calls of
``shift(1)`` send the controls the plan was scored on): a periodic plan advances its phase;
an open plan's values past its last knot hold the last value. ``rebase()``, the warm start of
receding-horizon control, then moves an open plan's knots to the clock: it re-samples them at
their times ``offset`` steps later and sets the clock to 0 (exact at the new knots;
everywhere for linear plans when ``offset`` is a multiple of the knot spacing).

Knot values are in units of the action bound a (f_c = a F_c): planners work in [-1, 1].
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["KINDS", "SplinePlan"]

KINDS = ("cubic", "linear")


def _positive_int(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _positive_number(name: str, value: Any) -> float:
    ok = isinstance(value, (int, float, np.number)) and not isinstance(value, bool)
    if not (ok and np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


class SplinePlan:
    """K knots per control dimension mapped to H env steps of controls.

    Parameters
    ----------
    horizon : int
        H, env steps of the plan.
    knots : int
        K, knots per control dimension (<= H for an open plan, <= P for a periodic one).
    control_dim : int
        C.
    kind : {"cubic", "linear"}
    period : float, optional
        P, env steps of one cycle of a periodic plan (need not be whole: 40 Hz control and a
        3 Hz gait give 13.33); None for an open plan.

    Attributes
    ----------
    knots : (K, C) array
        F~_c in units of the action bound.
    offset : float
        The plan's clock: env steps since the knots' time origin.
    """

    def __init__(
        self,
        horizon: int,
        knots: int,
        control_dim: int,
        kind: str = "cubic",
        period: float | None = None,
    ) -> None:
        self.horizon = _positive_int("horizon", horizon)
        k = _positive_int("knots", knots)
        self.control_dim = _positive_int("control_dim", control_dim)
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {list(KINDS)}, got {kind!r}")
        self.kind = kind
        self.period = None if period is None else _positive_number("period", period)
        limit: float
        if self.period is None:
            limit, what = self.horizon, "horizon"
        else:
            limit, what = self.period, "period"
        if k > limit:
            raise ValueError(f"knots = {k} exceeds the {what} ({limit:g} steps)")
        self.knots = np.zeros((k, self.control_dim))
        self.offset = 0.0

    @property
    def num_knots(self) -> int:
        """K, the knots per control dimension."""
        return self.knots.shape[0]

    @property
    def spacing(self) -> float:
        """Env steps between neighbouring knots."""
        k = self.num_knots
        if self.period is not None:
            return self.period / k
        return (self.horizon - 1) / (k - 1) if k > 1 else float("inf")

    def copy(self) -> SplinePlan:
        """An independent copy: the same knots (copied) and clock."""
        new = SplinePlan(self.horizon, self.num_knots, self.control_dim, self.kind, self.period)
        new.knots = self.knots.copy()
        new.offset = self.offset
        return new

    # ------------------------------------------------------------- interpolation
    def weights(self, times: np.ndarray) -> np.ndarray:
        """The (len(times), K) matrix W with F_c(times) = W F~_c (times in env steps from the
        knots' origin)."""
        t = np.asarray(times, dtype=float)
        k = self.num_knots
        w = np.zeros((t.size, k))
        if k == 1:
            w[:, 0] = 1.0
            return w
        u = t / self.spacing  # in knot intervals
        if self.period is not None:
            u = np.mod(u, k)
            j = np.minimum(np.floor(u).astype(int), k - 1)
        else:
            u = np.clip(u, 0.0, k - 1)  # hold the end values beyond the horizon
            j = np.minimum(np.floor(u).astype(int), k - 2)
        s = u - j
        cols: tuple[np.ndarray, ...]
        vals: tuple[np.ndarray, ...]
        if self.kind == "linear":
            cols = (j, j + 1)
            vals = (1.0 - s, s)
        else:
            cols = (j - 1, j, j + 1, j + 2)
            vals = (
                0.5 * (-s + 2 * s**2 - s**3),
                0.5 * (2 - 5 * s**2 + 3 * s**3),
                0.5 * (s + 4 * s**2 - 3 * s**3),
                0.5 * (-(s**2) + s**3),
            )
        rows = np.arange(t.size)
        for col, val in zip(cols, vals, strict=True):
            self._scatter(w, rows, col, val)
        return w

    def _scatter(self, w: np.ndarray, rows: np.ndarray, col: np.ndarray, val: np.ndarray) -> None:
        k = self.num_knots
        if self.period is not None:
            np.add.at(w, (rows, np.mod(col, k)), val)
            return
        inside = (col >= 0) & (col < k)
        np.add.at(w, (rows[inside], col[inside]), val[inside])
        # The missing neighbours are the linear extrapolations 2 p_0 - p_1 and
        # 2 p_{K-1} - p_{K-2}: lines stay lines up to the ends.
        for edge, a, b in ((col < 0, 0, 1), (col >= k, k - 1, k - 2)):
            np.add.at(w[:, a], rows[edge], 2.0 * val[edge])
            np.add.at(w[:, b], rows[edge], -val[edge])

    def matrix(self) -> np.ndarray:
        """S1, the (H, K) interpolation matrix from the plan's clock: F_c = S1 F~_c."""
        return self.weights(self.offset + np.arange(self.horizon))

    def full_matrix(self) -> np.ndarray:
        """The paper's S (HC x KC): vec(F_c) = S vec(F~_c), both row-major (step, dim)."""
        return np.kron(self.matrix(), np.eye(self.control_dim))

    def controls(self, knots: np.ndarray | None = None) -> np.ndarray:
        """F_c (H, C), or (B, H, C) for a batch of knots (B, K, C), in units of the bound."""
        x = self.knots if knots is None else np.asarray(knots, dtype=float)
        return np.einsum("hk,...kc->...hc", self.matrix(), x)

    def value(self, step: float = 0.0) -> np.ndarray:
        """F_c (C,) ``step`` env steps after the plan's clock."""
        return self.weights(np.array([self.offset + step]))[0] @ self.knots

    # ------------------------------------------------------------- warm start
    def shift(self, steps: float) -> None:
        """Move the plan's clock ``steps`` env steps into the future (see the module
        docstring); an open plan's knots stay where they are until :meth:`rebase`."""
        if not np.isfinite(steps) or steps < 0:
            raise ValueError(f"steps must be a finite number >= 0, got {steps!r}")
        if steps == 0:
            return
        if self.period is not None:
            self.offset = float(np.mod(self.offset + steps, self.period))
            return
        # (re-sampling the knots here, at every step, compounded: after n shift(1) an open plan
        # sent controls up to half the bound away from those it was scored on)
        self.offset = self.offset + steps

    def rebase(self) -> None:
        """Warm start: re-sample an open plan's knots at their times ``offset`` steps later
        and set its clock to 0, holding the last value beyond the horizon (a periodic plan's
        clock is its phase: unchanged)."""
        if self.period is not None or self.offset == 0:
            return
        if self.num_knots == 1:  # spacing is infinite: one knot holds the whole horizon
            times = np.array([self.offset])
        else:
            times = self.offset + self.spacing * np.arange(self.num_knots)
        self.knots = self.weights(times) @ self.knots
        self.offset = 0.0
