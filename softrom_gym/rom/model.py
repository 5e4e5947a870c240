"""Build a ready-to-step reduced model of a robot: B_r, cubature and the C++ ReducedModel."""

from __future__ import annotations

import os
from typing import Literal

import numpy as np

import cpp_sim

from ..robots import Robot
from .cubature import Cubature, train_cubature
from .subspace import Subspace, build_subspace

__all__ = ["build_reduced_model"]

# The settings' names live in one place, the C++ binding's table.
_SETTINGS = frozenset(cpp_sim.ReducedConfig.SETTINGS)


def build_reduced_model(
    robot: Robot,
    M: int | None = None,
    *,
    forces: Literal["cubature", "exact"] = "cubature",
    control_basis: np.ndarray | None = None,
    subspace: Subspace | None = None,
    cubature: Cubature | None = None,
    cache: bool | str | os.PathLike = True,
    verbose: bool = False,
    **settings: object,
) -> cpp_sim.ReducedModel:
    """A :class:`cpp_sim.ReducedModel` of ``robot`` in an M-mode simulation space.

    Parameters
    ----------
    robot : Robot
    M : int, optional
        Deformation coordinates of B_r (the state has M + 6 coordinates: 3 rigid translations,
        then 3 linearised rotations, then the M deformation coordinates). Default 20, or the
        ``subspace``'s M when one is given; an M that differs from the subspace's raises.
    forces : {"cubature", "exact"}
        ``"cubature"`` (default) evaluates reduced elastic forces on a trained element subset,
        O(|S|) per step; ``"exact"`` sums every tetrahedron (the reference, O(T)).
    control_basis : (M, C) array, optional
        B_c; the actuation is f_r = B_c f_c on the deformation coordinates.
    subspace, cubature : optional
        Prebuilt B_r and cubature rule (otherwise built, and cached on disk).
    cache : bool or path
        Where B_r and the cubature rule are cached: as in
        :func:`~softrom_gym.rom.build_subspace`.
    verbose : bool
        Say on stderr what is being computed and how long it took (nothing for what comes
        from the cache).
    **settings
        Any :class:`cpp_sim.ReducedModel` setting: ``dt`` (default 1/200 s), ``gravity``,
        ``contact`` ("staggered", "penalty", "none"), ``friction`` (mu, default 0.8),
        ``fluid_density`` (> 0 switches drag on), ``drag_coefficient``, ``damping_alpha``,
        ``damping_beta``, ``direction``, solver tolerances, ``frame`` ("linear", the
        default, or "floating": an exact rotation, with any of the three grounds;
        docs/FLOATING_FRAME.md).
    """
    unknown = set(settings) - _SETTINGS
    if unknown:
        raise TypeError(f"unknown setting(s) {sorted(unknown)}; valid: {sorted(_SETTINGS)}")
    if forces not in ("cubature", "exact"):
        raise ValueError(f"forces must be 'cubature' or 'exact', got {forces!r}")
    if subspace is None:
        sub = build_subspace(robot, 20 if M is None else M, cache=cache, verbose=verbose)
    else:
        # M was ignored when a subspace came with it: M=5 with a 20-mode subspace built a
        # 20-mode model without a word.
        if M is not None and M != subspace.M:
            raise ValueError(f"M = {M!r} but the subspace has M = {subspace.M} deformation "
                             "coordinates (leave M out to use the subspace's)")  # fmt: skip
        sub = subspace
    if sub.basis.shape[0] != 3 * robot.num_nodes:
        raise ValueError(
            f"subspace basis has {sub.basis.shape[0]} rows, robot has 3N = {3 * robot.num_nodes}"
        )
    if forces == "exact":
        elements = np.arange(robot.num_tets)
        weights = np.ones(robot.num_tets)
    else:
        rule = cubature if cubature is not None else train_cubature(robot, sub, cache=cache,
                                                                    verbose=verbose)  # fmt: skip
        elements, weights = rule.elements, rule.weights
    model = cpp_sim.ReducedModel(
        robot.nodes,
        robot.tets,
        robot.youngs_modulus,
        robot.poisson_ratio,
        robot.density,
        sub.basis,
        elements,
        weights,
        robot.surface_nodes,
        robot.surface_faces,
    )
    for name, value in settings.items():
        setattr(model, name, value)
    if control_basis is not None:
        model.control_basis = control_basis
    return model
