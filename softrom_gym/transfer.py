"""A control space B_c carried from one simulation space B_r to another of the same robot.

A reduced model's actuation is the generalised force B_c f_c on its M deformation
coordinates; the full-space force field it stands for is F = M B B_c f_c (B the
mass-orthonormal deformation columns, 3N x M, M the lumped mass). The same field seen by a
second simulation space B' (3N x M') is the generalised force B'^T F = T B_c f_c with

    T = B'^T M B    (M' x M).

So ``T B_c`` is "the same control space" in the other model, exactly when span(B B_c) lies
inside span(B') (our simulation spaces nest: the span of the M space lies inside that of the
M' > M space, to round-off, though the columns differ, since modes and modal derivatives are
split differently at each M; see ``benchmarks/check_m_convergence.py``); otherwise it is the
mass-orthogonal
projection of B_c onto the other space, and :func:`map_control_basis` refuses it unless told.
This is what lets a B_c found by RBBO at M = 20 be measured in a richer model.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .robots import Robot
from .rom.subspace import build_subspace

__all__ = ["map_control_basis"]


def _robot(robot: Any) -> Robot:
    if isinstance(robot, Robot):
        return robot
    inner = getattr(getattr(robot, "unwrapped", None), "robot", None)
    if isinstance(inner, Robot):
        return inner
    raise TypeError(f"expected a Robot or a softrom_gym env, got {type(robot).__name__}")


def map_control_basis(control_basis: np.ndarray, robot: Any, source_dim: int,
                      target_dim: int, *, atol: float = 1e-6) -> np.ndarray:  # fmt: skip
    """``T B_c``: ``control_basis`` (B_c of the ``source_dim``-mode simulation space) in the
    ``target_dim``-mode simulation space of the same robot.

    Parameters
    ----------
    control_basis : (source_dim, C) array
        Orthonormal B_c, e.g. an RBBO run's ``best_basis.npy``.
    robot : Robot or softrom_gym env
        The robot (an env's ``unwrapped.robot`` is used when given an env).
    source_dim, target_dim : int
        M of the space B_c is given in and of the space it is wanted in.
    atol : float
        Largest accepted relative residual ``||B B_c - B' T B_c||_M / ||B B_c||_M``: how much
        of B_c's full-space actuation the target space cannot represent.

    Returns
    -------
    (target_dim, C) array
        Orthonormal to within the residual. Where the target's first ``source_dim`` modes are
        the source's (to 1e-9), the exact zero-padded B_c rather than its round-off image.

    Raises
    ------
    ValueError
        For a B_c of the wrong shape, with non-finite entries or not orthonormal (to 1e-8),
        for a negative or NaN ``atol``, and, naming the residual,
        when the target space cannot represent B_c (e.g. a smaller M).
    """
    robot = _robot(robot)
    basis = np.asarray(control_basis, dtype=np.float64)
    for name, value in (("source_dim", source_dim), ("target_dim", target_dim)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if basis.ndim != 2 or basis.shape[0] != source_dim or not 1 <= basis.shape[1] <= source_dim:
        raise ValueError(f"control_basis has shape {basis.shape}, expected (source_dim, C) = "
                         f"({source_dim}, C) with 1 <= C <= {source_dim}")  # fmt: skip
    if not np.isfinite(basis).all():
        raise ValueError("control_basis contains non-finite values")
    if isinstance(atol, bool) or not (isinstance(atol, (int, float, np.floating)) and atol >= 0):
        raise ValueError(f"atol must be a number >= 0, got {atol!r}")
    err = float(np.abs(basis.T @ basis - np.eye(basis.shape[1])).max())
    if err > 1e-8:  # the env's own tolerance for B_c
        raise ValueError(f"control_basis is not orthonormal: max |B_c^T B_c - I| = {err:.3g} "
                         "(tolerance 1e-8); orthonormalise it first (np.linalg.qr)")  # fmt: skip
    if basis.shape[1] > target_dim:
        raise ValueError(f"control_basis has C = {basis.shape[1]} columns, more than "
                         f"target_dim = {target_dim}")  # fmt: skip
    if target_dim == source_dim:
        return basis.copy()
    source = build_subspace(robot, source_dim).deformation
    target = build_subspace(robot, target_dim).deformation
    mass = np.repeat(robot.fem_model().mass, 3)
    field = source @ basis  # B B_c, 3N x C
    mapped = target.T @ (mass[:, None] * field)
    lost = field - target @ mapped
    norm = float(np.sqrt(np.sum(mass[:, None] * field**2)))
    residual = float(np.sqrt(np.sum(mass[:, None] * lost**2))) / max(norm, 1e-300)
    if residual > atol:
        raise ValueError(
            f"the {target_dim}-mode simulation space cannot represent this B_c of the "
            f"{source_dim}-mode one: relative residual {residual:.3g} > atol = {atol:g} "
            "(the spaces do not nest; pass a larger atol to accept the projection)"
        )
    if target_dim > source_dim:
        padded = np.zeros_like(mapped)
        padded[:source_dim] = basis
        if np.allclose(mapped, padded, rtol=0.0, atol=1e-9):
            return padded
    return mapped
