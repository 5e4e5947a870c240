"""Export simulated motion as a mesh sequence (one OBJ/PLY/STL per frame) for Blender & co."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

import cpp_sim

from .robots import Robot

__all__ = ["export_trajectory"]

_FORMATS = (".obj", ".ply", ".stl", ".glb")


def export_trajectory(
    states: Iterable[Any],
    path: str | os.PathLike,
    *,
    env: Any = None,
    robot: Robot | None = None,
) -> list[Path]:
    """Write one surface mesh per frame.

    Parameters
    ----------
    states : iterable
        Frames (a list, or a generator): ``ReducedState`` objects (from
        ``env.unwrapped.get_state()``; needs ``env``) or node positions of shape (N, 3)
        (needs ``env`` or ``robot`` for the surface). Every frame is checked before any
        file is written: a frame of the wrong shape or with non-finite positions (a
        diverged simulation) is a ValueError naming it, and nothing is written.
    path : path
        ``frames/walk.ply`` writes ``frames/walk_0000.ply``, ``frames/walk_0001.ply``, ...;
        the extension (.obj, .ply, .stl or .glb) picks the format. Folders are created, and
        ``~`` is the home folder (as in a robot's mesh path). Exporting again to the same
        path replaces the earlier sequence: its frames are overwritten, and once the new ones
        are written, those beyond the new count (``walk_0004.ply`` on, after 4 frames) are
        removed. Only files named as this export names its frames are removed; others in the
        folder (another stem or format, ``walk_notes.txt``) are left alone.
    env : SoftRobotEnv (or a wrapper of one), optional
    robot : Robot, optional

    Returns
    -------
    list of Path
        The files written, in frame order.
    """
    base = getattr(env, "unwrapped", env)
    if base is not None and not (hasattr(base, "robot") and hasattr(base, "model")):
        raise TypeError(f"env must be a SoftRobotEnv or a wrapper of one (its robot and model "
                        f"map the frames to a surface), got {type(base).__name__}")  # fmt: skip
    if robot is None:
        if base is None:
            raise ValueError("export_trajectory needs env= or robot= to know the surface")
        robot = base.robot
    # expanded as a mesh or control_basis path is: Path() alone made a folder named "~" here
    path = Path(os.path.expanduser(os.fspath(path)))
    if path.suffix.lower() not in _FORMATS:
        raise ValueError(f"unsupported mesh format {path.suffix!r}; use one of {_FORMATS}")
    frames = []
    for i, frame in enumerate(states):
        if isinstance(frame, cpp_sim.ReducedState):
            if base is None:
                raise ValueError("ReducedState frames need env= to map them to positions")
            positions = base.model.positions(frame.q)
        else:
            positions = np.asarray(frame, dtype=float)
        if positions.shape != robot.nodes.shape:
            raise ValueError(f"frame {i} has shape {positions.shape}, expected {robot.nodes.shape}")
        if not np.all(np.isfinite(positions)):
            raise ValueError(f"frame {i} has non-finite node positions (a diverged simulation?); "
                             "no file was written")  # fmt: skip
        frames.append(positions)
    if not frames:
        raise ValueError("states is empty: nothing to export")
    path.parent.mkdir(parents=True, exist_ok=True)
    written = []
    for i, positions in enumerate(frames):
        out = path.with_name(f"{path.stem}_{i:04d}{path.suffix}")
        mesh = robot.surface(positions)
        mesh.remove_unreferenced_vertices()
        mesh.export(out)
        written.append(out)
    _remove_later_frames(path, len(written))
    return written


def _remove_later_frames(path: Path, count: int) -> None:
    """Remove frames ``count`` on of an earlier export to ``path``.

    Left in place, they followed the new frames in the folder, and a video encoded from
    ``walk_*.ply`` mixed two runs. A file is one of the sequence's only if its name is exactly
    what :func:`export_trajectory` writes for some frame (``{stem}_{i:04d}{suffix}``), so a
    user's ``walk_notes.txt`` or ``walk_00005.ply`` is never touched.
    """
    pattern = re.compile(re.escape(path.stem) + r"_(\d{4,})" + re.escape(path.suffix))
    for entry in path.parent.iterdir():
        match = pattern.fullmatch(entry.name)
        if match is None or f"{int(match[1]):04d}" != match[1] or int(match[1]) < count:
            continue
        if entry.is_symlink() or entry.is_file():  # (a folder so named is not a frame)
            entry.unlink()
