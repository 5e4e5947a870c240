"""The low-level objective of the paper, R - Λ, from the env's per-step rollout terms.

Over a plan of H env steps (control period dt) from a state with centre of mass c_0:

* R, the distance gained along d. With ``window = W`` only the last W steps count,
  ``R = d · (c_H - c_{H-W})``: a periodic plan whose horizon spans a lead-in plus one gait
  cycle is then scored on the cycle alone, where a lean (a pose held after a first lunge)
  gains nothing; ``window = None`` counts the whole horizon, ``d · (c_H - c_0)``, the paper's
  R. A terminal value ``w_v d · v_H`` (v_H the COM velocity over the last step) may be added.
* Λ = Σ_t dt (w_o |θ_t|^2 + w_l y_t^2 + w_u |f_c,t / a|^2) + w_d n_lost, with θ_t the
  orientation (rotation vector vs. rest, rad), y_t the offset orthogonal to d in the ground
  plane since the plan's start (m), f_c / a the control in units of the bound, and n_lost
  the steps lost to a divergence (the env's ``lost`` term: a blow-up must cost more than any
  step backwards).

The smooth part of Λ is a sum of squares ``|r|^2`` of the residuals r returned by
:func:`evaluate`, which is what Gauss-Newton linearises.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["CostWeights", "Evaluation", "evaluate"]


@dataclass(frozen=True)
class CostWeights:
    """Weights of Λ (all >= 0; R is in metres, so each term is in metres).

    Attributes
    ----------
    orientation : float
        w_o, m / (rad^2 s): a tilt or turn of 0.1 rad held for 1 s costs 0.01 w_o m.
    lateral : float
        w_l, 1 / (m s): a 0.1 m side offset held for 1 s costs 0.01 w_l m.
    effort : float
        w_u, m / s: the control at the bound in every dimension for 1 s costs C w_u m.
    divergence : float
        w_d, m per env step lost to a divergence.
    velocity : float
        w_v, s: terminal value, metres credited per m/s of COM velocity along d at the end.
    """

    orientation: float = 1.0
    lateral: float = 1.0
    effort: float = 1e-3
    divergence: float = 1.0
    velocity: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise ValueError(f"weight {f.name} must be a number, got {value!r}")
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"weight {f.name} must be finite and >= 0, got {value!r}")


@dataclass(frozen=True)
class Evaluation:
    """R - Λ of B rollouts.

    Attributes
    ----------
    objective : (B,) R - Λ (m).
    reward : (B,) R, with the terminal value (m).
    smooth : (B,) the smooth part of Λ, |r|^2 (m).
    lost : (B,) env steps lost to a divergence.
    residuals : (B, n) r.
    """

    objective: np.ndarray
    reward: np.ndarray
    smooth: np.ndarray
    lost: np.ndarray
    residuals: np.ndarray


def evaluate(
    out: dict[str, np.ndarray],
    controls: np.ndarray,
    start_com: np.ndarray,
    direction: np.ndarray,
    dt: float,
    weights: CostWeights,
    window: int | None = None,
) -> Evaluation:
    """R - Λ of a rollout's per-step terms.

    Parameters
    ----------
    out : dict
        The env's ``rollout`` output (``com`` (B, H, 3), ``theta`` (B, H, 3), ``lost``).
    controls : (B, H, C) array
        The controls in units of the action bound, clipped to [-1, 1].
    start_com : (3,) or (B, 3) array
        c_0, the COM of the start state, or of each rollout's start state (for a ``rollout``
        from a list of B states).
    direction : (3,) array
        d, unit, in the ground plane.
    dt : float
        Control period (s).
    weights : CostWeights
    window : int, optional
        Count R over the last ``window`` steps only (see the module docstring).
    """
    com = out["com"]
    b, h, _ = com.shape
    controls = np.asarray(controls)
    if controls.ndim != 3 or controls.shape[:2] != (b, h):
        raise ValueError(f"controls has shape {controls.shape}, expected ({b}, {h}, C): one "
                         "control per step of the rollout")  # fmt: skip
    if np.abs(controls).max(initial=0.0) > 1.0 + 1e-12:
        raise ValueError("controls must be in units of the action bound, within [-1, 1]; got "
                         f"|u| up to {np.abs(controls).max():.3g}")  # fmt: skip
    if window is not None and (isinstance(window, bool) or not isinstance(window, (int, np.integer))
                               or window < 1):  # fmt: skip
        raise ValueError(f"window must be an integer >= 1 or None, got {window!r}")
    # (a dt <= 0 gave NaN or -inf objectives, and a direction of length 10 scaled R and the
    # lateral term tenfold: named here, as the other arguments are)
    if isinstance(dt, bool) or not isinstance(dt, (int, float, np.number)) or not 0 < dt < np.inf:
        raise ValueError(f"dt must be a finite number > 0 (the control period, s), got {dt!r}")
    d = np.asarray(direction, dtype=float)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or abs(np.linalg.norm(d) - 1.0) > 1e-6:
        raise ValueError(f"direction must be a unit vector of shape (3,), got {direction!r}")
    direction = d
    start = np.asarray(start_com, dtype=float)
    # (a start of another shape is named here, not by numpy further on)
    if start.shape not in ((3,), (b, 3)):
        raise ValueError(f"start_com has shape {start.shape}, expected (3,) or ({b}, 3): the "
                         "start state's centre of mass, or one per rollout")  # fmt: skip
    rel = com - start.reshape(-1, 1, 3)
    along = rel @ direction
    if window is None or window >= h:
        reward = along[:, -1].copy()
    else:
        reward = along[:, -1] - along[:, h - 1 - window]
    if weights.velocity:
        last = along[:, -1] - (along[:, -2] if h > 1 else 0.0)
        reward = reward + weights.velocity * last / dt
    side = np.array([-direction[1], direction[0], 0.0])
    residuals = np.concatenate(
        [
            np.sqrt(weights.orientation * dt) * out["theta"].reshape(b, -1),
            np.sqrt(weights.lateral * dt) * (rel @ side),
            np.sqrt(weights.effort * dt) * controls.reshape(b, -1),
        ],
        axis=1,
    )
    smooth = np.sum(residuals**2, axis=1)
    lost = out["lost"].sum(axis=1)
    objective = reward - smooth - weights.divergence * lost
    return Evaluation(objective, reward, smooth, lost, residuals)
