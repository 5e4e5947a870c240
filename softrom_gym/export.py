"""Export simulated motion as a mesh sequence (one OBJ/PLY/STL/GLB per frame) for Blender & co."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

import cpp_sim

from ._durable import fsync_dir, make_dirs, temporary_name
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
        ``~`` is the home folder (as in a robot's mesh path). Axes: .obj, .ply and .stl hold
        the simulator's coordinates as they are (metres, Z up); .glb holds them in glTF's
        frame (metres, +Y up, as the glTF specification defines it), the simulator's
        (x, y, z) written as (x, z, -y), so that a glTF viewer shows the robot upright.

        Every frame is first written (and fsynced) under a temporary name in the folder
        (``.walk_0000.ply.<random>.tmp``); only when all are written is the sequence
        published under its frames' names, replacing an earlier export to the same path
        whole: its frames are set aside, the new ones renamed in, and then the set-aside
        ones (``walk_0004.ply`` on too, after 4 frames) removed. An export that fails or is
        interrupted while writing removes its temporary files and leaves the earlier
        sequence as it was; a hard kill can leave only dot-named ``.tmp``/``.old`` files
        beside one run's frames, never two runs' frames under one numbering. Only files
        named as this export names its frames are replaced; others in the folder (another
        stem or format, ``walk_notes.txt``) are left alone.
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
    make_dirs(path.parent)
    glb = path.suffix.lower() == ".glb"
    file_type = path.suffix.lower().lstrip(".")
    finals = [path.with_name(f"{path.stem}_{i:04d}{path.suffix}") for i in range(len(frames))]
    for out in finals:
        if out.is_dir() and not out.is_symlink():
            raise ValueError(f"{os.fspath(out)!r} is a folder: frame {out.name} cannot be "
                             "written there; export to another path")  # fmt: skip
    temps: list[Path] = []
    try:
        for out, positions in zip(finals, frames, strict=True):
            if glb:
                # glTF is +Y up by its specification; the simulator is Z up: a rotation
                # (x, y, z) -> (x, z, -y) about x (det +1, so the winding stays outward)
                positions = np.stack([positions[:, 0], positions[:, 2], -positions[:, 1]], 1)
            mesh = robot.surface(positions)
            mesh.remove_unreferenced_vertices()
            temps.append(temporary_name(out, ".tmp"))
            _write_durably(temps[-1], mesh, file_type)
    except BaseException:
        # nothing published yet: the earlier sequence (if any) is untouched
        for temp in temps:
            temp.unlink(missing_ok=True)
        raise
    _publish(path, temps, finals)
    return finals


def _frame_files(path: Path) -> list[Path]:
    """The files of an earlier export to ``path``, by frame number, highest first.

    A file is one of the sequence's only if its name is exactly what
    :func:`export_trajectory` writes for some frame (``{stem}_{i:04d}{suffix}``), so a
    user's ``walk_notes.txt`` or ``walk_00005.ply`` is never touched (and a folder so named
    is not a frame).
    """
    pattern = re.compile(re.escape(path.stem) + r"_(\d{4,})" + re.escape(path.suffix))
    found = []
    for entry in path.parent.iterdir():
        match = pattern.fullmatch(entry.name)
        if match is None or f"{int(match[1]):04d}" != match[1]:
            continue
        if entry.is_symlink() or entry.is_file():
            found.append((int(match[1]), entry))
    return [entry for _, entry in sorted(found, reverse=True)]


def _publish(path: Path, temps: list[Path], finals: list[Path]) -> None:
    """Replace the earlier export to ``path`` (if any) with the written ``temps``, whole.

    Renaming each new frame over the old one left old frames past the new count, and an
    interruption part-way left the two runs' frames under one continuous numbering (a video
    encoded from ``walk_*.ply`` mixed them). Here the old frames are first set aside under
    temporary names, highest number first, so the folder holds at every moment a prefix of
    one run's frames (the old run's, then the new run's, in frame order) beside dot-named
    temporary files. An interruption while setting aside puts the old frames back; once the
    first new frame is in, the rest follow (renames only: the data is already on disk).
    """
    aside: list[tuple[Path, Path]] = []
    try:
        for entry in _frame_files(path):
            aside.append((temporary_name(entry, ".old"), entry))  # (listed before it moves)
            os.replace(entry, aside[-1][0])
    except BaseException:
        for hidden, entry in reversed(aside):
            if entry.exists() or entry.is_symlink():  # not moved yet: drop the empty name
                hidden.unlink(missing_ok=True)
            else:
                os.replace(hidden, entry)
        for temp in temps:
            temp.unlink(missing_ok=True)
        raise
    try:
        for temp, out in zip(temps, finals, strict=True):
            os.replace(temp, out)
    except BaseException:
        # every new frame is on disk: the export is completed rather than left part under
        # temporary names (should this fail too, the set-aside frames are kept as .old files)
        for temp, out in zip(temps, finals, strict=True):
            if temp.exists():
                os.replace(temp, out)
        fsync_dir(path.parent)
        _remove(hidden for hidden, _ in aside)
        raise
    fsync_dir(path.parent)
    _remove(hidden for hidden, _ in aside)


def _remove(paths: Iterable[Path]) -> None:
    for p in paths:
        p.unlink(missing_ok=True)


def _write_durably(target: Path, mesh: Any, file_type: str) -> None:
    """Write ``mesh`` to ``target`` as ``file_type`` and fsync it, so that a frame renamed
    into the sequence is whole on disk (a rename can reach the disk before the data)."""
    with open(target, "wb") as f:
        mesh.export(file_obj=f, file_type=file_type)
        f.flush()
        os.fsync(f.fileno())
