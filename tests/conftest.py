"""Shared fixtures: small meshes that make finite-difference checks cheap."""

import numpy as np
import pytest

from softrom_gym.robots.robot import Robot
from softrom_gym.robots.voxel import voxels_to_tets


@pytest.fixture
def small_block():
    """A 3 x 2 x 2 voxel block (36 nodes, 72 tets), 0.1 m voxels."""
    nodes, tets = voxels_to_tets(np.ones((3, 2, 2), dtype=bool), 0.1)
    return nodes, tets


@pytest.fixture(scope="module")
def bar():
    """A 3 x 1 x 1 voxel bar (16 nodes, 18 tets), 0.1 m voxels, soft (E = 20 kPa)."""
    nodes, tets = voxels_to_tets(np.ones((3, 1, 1), dtype=bool), 0.1)
    return Robot("bar", nodes, tets, youngs_modulus=2e4)


@pytest.fixture(scope="module")
def box():
    """A stiff 0.2 x 0.2 x 0.1 m block: rigid-body-like answers for contact and friction."""
    import trimesh

    from softrom_gym.robots import from_mesh

    return from_mesh(trimesh.creation.box((0.2, 0.2, 0.1)), 8, youngs_modulus=1e6)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Subspace and cubature caches go to a per-session folder, never the user's cache."""
    import os

    old = os.environ.get("SOFTROM_CACHE_DIR")
    os.environ["SOFTROM_CACHE_DIR"] = str(tmp_path_factory.mktemp("softrom-cache"))
    yield
    if old is None:
        del os.environ["SOFTROM_CACHE_DIR"]
    else:
        os.environ["SOFTROM_CACHE_DIR"] = old


@pytest.fixture(scope="session", autouse=True)
def _interruptible():
    """The Ctrl-C tests need SIGINT raised as KeyboardInterrupt. A shell without job control
    starts background commands (``pytest &``, a CI step sent to the background) with SIGINT
    ignored; Python then leaves it ignored, and so do the processes it starts. Restore
    Python's handler (exec resets it to the default in those processes)."""
    import signal

    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield


@pytest.fixture
def say_warning(monkeypatch, capsys):
    """``warnings.showwarning`` restored after the test; returns ``say(message)``, which shows
    one RuntimeWarning and returns the stderr lines it printed (a command's one-line display,
    once the command has installed it)."""
    import warnings

    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # restored after

    def say(message: str) -> list[str]:
        capsys.readouterr()
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.warn(message, RuntimeWarning, stacklevel=1)
        return capsys.readouterr().err.splitlines()

    return say
