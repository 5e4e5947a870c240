"""On-disk cache of subspaces and cubature rules: where it lives, how entries are keyed, and
atomic reads and writes (a corrupt or half-written entry is rebuilt, never fatal)."""

from __future__ import annotations

import hashlib
import os
import sys
import zipfile
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..robots import Robot

__all__ = ["cache_dir", "cache_path", "load_entry", "mesh_key", "save_entry"]

CACHE_VERSION = "4"  # 4: machine-independent mode bases and cubature ranking (3: rotations)


def cache_dir() -> Path:
    """Where subspaces and cubature rules are cached: ``$SOFTROM_CACHE_DIR`` or the user cache."""
    env = os.environ.get("SOFTROM_CACHE_DIR")
    if env:
        return Path(env)
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "softrom"


def mesh_key(robot: Robot, *extra: object) -> str:
    """Hash of mesh, material and ``extra`` parameters, for on-disk caches."""
    h = hashlib.sha256()
    h.update(CACHE_VERSION.encode())
    h.update(np.ascontiguousarray(robot.nodes).tobytes())
    h.update(np.ascontiguousarray(robot.tets).tobytes())
    h.update(repr((robot.youngs_modulus, robot.poisson_ratio, robot.density, extra)).encode())
    return h.hexdigest()[:24]


def cache_path(cache: bool | str | os.PathLike, name: str) -> Path | None:
    """The entry ``name`` under the cache chosen by ``cache`` (True: :func:`cache_dir`, a path:
    there, False: no caching, None returned)."""
    if cache is False:
        return None
    return (cache_dir() if cache is True else Path(cache)) / name


def load_entry(path: Path | None) -> dict[str, np.ndarray] | None:
    """The arrays stored at ``path``, or None when absent or unreadable."""
    if path is None or not path.exists():
        return None
    try:
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return None


def save_entry(path: Path | None, **arrays: npt.ArrayLike) -> None:
    """Write ``arrays`` to ``path`` atomically: a concurrent reader never sees half a file,
    and a read-only cache location only costs speed."""
    if path is None:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        # (numpy's stub also matches a **dict against savez's allow_pickle: bool)
        np.savez(tmp, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
    except OSError:
        pass
