"""A body's frame and forces that follow it, for actuation that turns with the robot.

The reduced model's actuation, M B_d B_c f_c, is a force field fixed in the world: no net
force, and no torque at rest, but a torque once the body has deformed or turned. An actuator
built into a robot turns with it instead. :func:`best_fit_rotation` is the body's frame: the
rotation R minimising sum_i m_i |x_i - c - R X_i|^2 (X the rest nodes about the rest centre
of mass), which is the floating frame's R in ``docs/FLOATING_FRAME.md`` exactly, since B_r's
deformation columns are mass-orthogonal to the rest rotations. :func:`following_forces` turns a
field with that frame and removes the rigid rotation that would cancel its torque about the
centre of mass, so the field is internal at every configuration: it changes neither the
linear nor the angular momentum. ``FullSpaceModel(actuation_frame="body")`` applies it.
"""

from __future__ import annotations

import numpy as np

from ._validate import real_array

__all__ = ["best_fit_rotation", "following_forces"]


def _nodal(name: str, value: object, n: int | None, columns: int | None = 3) -> np.ndarray:
    """``value`` as a finite real array of n rows (``columns`` wide, or 1-D when None), or a
    ValueError naming it (a NaN node had surfaced as "SVD did not converge", a NaN field as
    NaN forces)."""
    a = real_array(name, value)
    shape = (a.shape[0] if n is None else n,) + (() if columns is None else (columns,))
    if a.shape != shape:
        want = ", ".join("N" if n is None and i == 0 else str(d) for i, d in enumerate(shape))
        raise ValueError(f"{name} has shape {a.shape}, expected ({want}{',' * (len(shape) == 1)})")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} has a non-finite entry")
    return a


def _checked(x: object, rest: object, mass: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = _nodal("x", x, None)
    n = x.shape[0]
    rest, mass = _nodal("rest", rest, n), _nodal("mass", mass, n, None)
    if not np.all(mass > 0.0):
        raise ValueError(f"mass must be > 0 at every node, got {mass[~(mass > 0.0)][0]!r}")
    return x, rest, mass


def best_fit_rotation(x: np.ndarray, rest: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """The rotation R (3, 3) minimising sum_i m_i |x_i - c - R X_i|^2 (Kabsch's algorithm).

    Parameters
    ----------
    x : (N, 3) array
        Node positions.
    rest : (N, 3) array
        Rest node positions about the rest centre of mass, X.
    mass : (N,) array
        Lumped node masses m_i (kg).

    Returns
    -------
    (3, 3) array
        A proper rotation (det +1) taking the rest shape's directions to the body's.
    """
    x, rest, mass = _checked(x, rest, mass)
    weights = np.sqrt(mass)[:, None]
    centred = x - mass @ x / mass.sum()
    u, _, vt = np.linalg.svd((centred * weights).T @ (rest * weights))
    return u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt


def following_forces(
    x: np.ndarray, rest: np.ndarray, mass: np.ndarray, field: np.ndarray
) -> np.ndarray:
    """Nodal forces m_i (R a_i - alpha x (x_i - c)) (N, 3): the field a (per unit mass, in the
    rest orientation) turned by the body's :func:`best_fit_rotation` R, less the rigid
    rotation field whose torque cancels its own about the centre of mass c, so that the
    forces have no net force (when sum_i m_i a_i = 0) and no net torque at ``x``.

    alpha = I(x)^-1 tau, with tau = sum_i m_i (x_i - c) x R a_i and I(x) the inertia tensor
    about c. At rest (x = c + X) and for a field with no torque there (B_d B_c's columns are
    mass-orthogonal to the rest rotations), R = I and alpha = 0: the world-fixed field.
    """
    x, rest, mass = _checked(x, rest, mass)
    field = _nodal("field", field, x.shape[0])
    r = x - mass @ x / mass.sum()
    push = field @ best_fit_rotation(x, rest, mass).T
    tau = np.sum(mass[:, None] * np.cross(r, push), axis=0)
    second = np.einsum("i,ij,ik->jk", mass, r, r)
    inertia = np.trace(second) * np.eye(3) - second
    # (Nodes on one line have no inertia about it: no rotation field can cancel a torque.)
    if np.linalg.cond(inertia) > 1e12:
        raise ValueError("the nodes x lie on one line (or one point): their inertia tensor is "
                         "singular, so the field's torque cannot be removed")  # fmt: skip
    alpha = np.linalg.solve(inertia, tau)
    return mass[:, None] * (push - np.cross(alpha, r))
