"""Shared fixtures: small meshes that make finite-difference checks cheap."""

import numpy as np
import pytest

from softrom_gym.robots.voxel import voxels_to_tets


@pytest.fixture
def small_block():
    """A 3 x 2 x 2 voxel block (36 nodes, 72 tets), 0.1 m voxels."""
    nodes, tets = voxels_to_tets(np.ones((3, 2, 2), dtype=bool), 0.1)
    return nodes, tets


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
