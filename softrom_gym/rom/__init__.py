"""Reduced-order model: simulation space B_r, cubature, reduced dynamics with contact and drag.

>>> from softrom_gym.robots import quadruped
>>> from softrom_gym.rom import build_reduced_model
>>> model = build_reduced_model(quadruped(), M=20)          # B_r and cubature cached on disk
>>> state, info = model.step(model.rest_state())             # one implicit step, dt = 1/200 s
"""

from .cache import cache_dir
from .cubature import Cubature, sample_poses, train_cubature
from .model import build_reduced_model
from .subspace import Subspace, build_subspace

__all__ = [
    "Cubature",
    "Subspace",
    "build_reduced_model",
    "build_subspace",
    "cache_dir",
    "sample_poses",
    "train_cubature",
]
