"""On-disk cache of subspaces and cubature rules: where it lives, how entries are keyed, and
atomic reads and writes (a corrupt entry is rebuilt with a warning, never fatal)."""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import threading
import warnings
import zipfile
from collections.abc import Callable
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
        # (a quoted "~/cache" reaches us unexpanded; it would make a folder named "~" here)
        return Path(os.path.expanduser(env))
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "softrom"


def _plain(value: object) -> object:
    """A numpy scalar as the Python number it equals: under NumPy 2 repr(np.int64(20)) is
    "np.int64(20)", so sim_dim=np.int64(20) (a loop over np.arange) missed the cache entry of
    sim_dim=20 and stored a duplicate."""
    return value.item() if isinstance(value, np.generic) else value


def mesh_key(robot: Robot, *extra: object) -> str:
    """Hash of mesh, material and ``extra`` parameters, for on-disk caches."""
    h = hashlib.sha256()
    h.update(CACHE_VERSION.encode())
    h.update(np.ascontiguousarray(robot.nodes).tobytes())
    h.update(np.ascontiguousarray(robot.tets).tobytes())
    material = (robot.youngs_modulus, robot.poisson_ratio, robot.density)
    key = (*(_plain(m) for m in material), tuple(_plain(e) for e in extra))
    h.update(repr(key).encode())
    return h.hexdigest()[:24]


def cache_path(cache: bool | str | os.PathLike, name: str) -> Path | None:
    """The entry ``name`` under the cache chosen by ``cache`` (True: :func:`cache_dir`, a path:
    there, False: no caching, None returned)."""
    if cache is False:
        return None
    return (cache_dir() if cache is True else Path(cache)) / name


def load_entry(
    path: Path | None, check: Callable[[dict[str, np.ndarray]], str | None] | None = None
) -> dict[str, np.ndarray] | None:
    """The arrays stored at ``path``, or None when absent or unusable: unreadable (truncated,
    not an .npz archive) or refused by ``check`` (which returns what is wrong, or None). An
    unusable entry is reported in a warning, and the caller rebuilds it."""
    if path is None or not path.exists():
        return None
    problem = None
    try:
        with open(path, "rb") as fh:  # closed here even when np.load fails half-way
            data = np.load(fh)
            if isinstance(data, np.lib.npyio.NpzFile):
                with data:
                    entry = {k: data[k] for k in data.files}
                problem = check(entry) if check is not None else None
            else:
                problem = "not an .npz archive"
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        problem = f"{type(exc).__name__}: {exc}"
    if problem is None:
        return entry
    warnings.warn(
        f"softrom_gym: ignoring the corrupt cache entry {path} ({problem}); it is rebuilt",
        RuntimeWarning,
        stacklevel=3,
    )
    return None


_UNWRITABLE: set[Path] = set()  # cache folders this process has already warned about


def save_entry(path: Path | None, **arrays: npt.ArrayLike) -> None:
    """Write ``arrays`` to ``path`` atomically: a concurrent reader never sees half a file,
    nor do two writers (processes or threads) share a temporary file, and a read-only cache
    location only costs speed (said once per folder and process in a RuntimeWarning: a new
    robot's model is then rebuilt, minutes, every time it is made)."""
    if path is None:
        return
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.{threading.get_ident()}.tmp.npz")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # (numpy's stub also matches a **dict against savez's allow_pickle: bool)
        np.savez(tmp, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if path.parent not in _UNWRITABLE:
            _UNWRITABLE.add(path.parent)
            warnings.warn(
                f"softrom_gym: cannot write the cache entry {path} ({exc.strerror or exc}): "
                "it is built again each time it is needed; set SOFTROM_CACHE_DIR to a folder "
                "you can write",
                RuntimeWarning,
                stacklevel=3,
            )
