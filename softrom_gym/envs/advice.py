"""Warnings at construction for a robot the env's defaults suit poorly.

The benchmarks' defaults (an action bound of one body weight per control direction, the
linear frame) are tuned to robots 0.5-1 m long and lower than they are wide. A robot of one's
own can fall outside that in two ways that show only as a robot that does not move, or moves
wrongly, with nothing said (a review, session 55):

* small or stiff: the deformation the action bound can make shrinks with the robot's size
  (strain ~ rho g L / E), so a 9 cm star at 50 kPa moved 0.003 m under every full-bound gait;
* tall: the linear frame linearises rotations, so a tower that buckles and falls in the full
  space stood, tilted 0.14 rad, below the 0.3 rad turn warning.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["SMALL_DEFORMATION", "TALL_ASPECT", "warn_if_unsuited"]

# Below this share of its size the softest mode's static deflection under the full action
# bound is "little" (the benchmarks: 54-139 %; a 9 cm box 1.3 %, a 15 cm one 2.2 %; the review
# saw a 9 cm star move 3 mm under every full-bound gait, a 12 cm box walk 17 mm, a 15 cm fish
# swim 0.23 m: the estimate is rough, so the warning is for the clear cases).
SMALL_DEFORMATION = 0.01
# Height over the smaller horizontal extent above which a robot may tip over (the benchmarks:
# 0.1-1.3; the review's tower 7.5).
TALL_ASPECT = 2.0


def warn_if_unsuited(nodes: np.ndarray, deformation: np.ndarray, frequencies: np.ndarray,
                     action_bound: float, frame: str) -> None:  # fmt: skip
    """Warn (UserWarning, once per call) where the robot suits the env's settings poorly.

    Parameters
    ----------
    nodes : (N, 3) array
        The rest nodes (m).
    deformation : (3N, M) array
        B_r's deformation columns (mass-normalised).
    frequencies : (M,) array
        Their Rayleigh-quotient frequencies omega_j (rad/s).
    action_bound : float
        a, the bound on each component of f_c (m kg^1/2 / s^2).
    frame : str
        The model's frame ("linear" or "floating").
    """
    extent = np.ptp(nodes, axis=0)
    size = float(extent.max())
    n = len(nodes)
    # the static answer to the full bound along mode j: q_j = a / omega_j^2, its largest node
    # displacement |U_j| q_j (a linear estimate: the order of what a stroke can bend)
    reach = np.linalg.norm(deformation.reshape(n, 3, -1), axis=1).max(axis=0)
    deflection = float(np.max(action_bound / np.asarray(frequencies) ** 2 * reach))
    if deflection < SMALL_DEFORMATION * size:
        warnings.warn(f"under the full action bound this robot deforms at most about "
                      f"{deflection:.2g} m, {deflection / size:.1%} of its {size:.3g} m size "
                      "(the benchmarks: 54-139 %): it may hardly move; raise action_scale, or "
                      "lower youngs_modulus (material=)", stacklevel=3)  # fmt: skip
    aspect = float(extent[2] / max(extent[:2].min(), 1e-300))
    if frame == "linear" and aspect > TALL_ASPECT:
        warnings.warn(f"this robot is {aspect:.1f}x as tall as its narrower side: it may tip "
                      "over, which the linear frame cannot show (its rotations are "
                      "linearised); use frame='floating'", stacklevel=3)  # fmt: skip
