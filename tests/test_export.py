"""export_trajectory: a mesh sequence published whole, durable frames, and each format's axes."""

import errno
import json
import os
import struct

import numpy as np
import pytest
import trimesh

import softrom_gym.export as export
from softrom_gym import export_trajectory


def _frames(robot, count, shift=0.0):
    """``count`` frames of ``robot`` lifted 1 mm a frame, shifted ``shift`` m along x."""
    return [robot.nodes + np.array([shift, 0.0, 0.001 * i]) for i in range(count)]


def _x_centres(folder, stem="walk", suffix=".ply"):
    """Every file in ``folder`` (hidden ones too): a frame's x centre, else None."""
    out = {}
    for name in sorted(os.listdir(folder)):
        if name.startswith(f"{stem}_") and name.endswith(suffix):
            mesh = trimesh.load(folder / name, process=False)
            out[name] = round(float(mesh.bounds.mean(axis=0)[0]), 3)
        else:
            out[name] = None
    return out


def _export_failing_at(monkeypatch, k, error):
    """Make the k-th mesh export from now on write part of its file, then raise ``error``
    (as a full disk, a file size limit or a Ctrl-C part-way would)."""
    original = trimesh.Trimesh.export
    calls = {"n": 0}

    def failing(self, file_obj=None, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == k:
            data = b"ply\nformat ascii 1.0\n"
            if hasattr(file_obj, "write"):
                file_obj.write(data)
            else:  # (a path: how the export wrote its frames before)
                with open(file_obj, "wb") as f:
                    f.write(data)
            raise error
        return original(self, file_obj, *args, **kwargs)

    monkeypatch.setattr(trimesh.Trimesh, "export", failing)


def test_an_interrupted_re_export_leaves_the_earlier_sequence_whole(bar, tmp_path, monkeypatch):
    # frames were overwritten in place one by one: an export interrupted at its 3rd frame left
    # 2 new frames followed by 4 of the earlier run, under one continuous numbering
    export_trajectory(_frames(bar, 6), tmp_path / "walk.ply", robot=bar)
    (tmp_path / "walk_notes.txt").write_text("mine")
    before = _x_centres(tmp_path)
    _export_failing_at(monkeypatch, 3, KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        export_trajectory(_frames(bar, 4, shift=5.0), tmp_path / "walk.ply", robot=bar)
    assert _x_centres(tmp_path) == before  # the earlier six, and no temporary file left
    assert sum(v == 0.15 for v in before.values()) == 6
    monkeypatch.undo()
    files = export_trajectory(_frames(bar, 4, shift=5.0), tmp_path / "walk.ply", robot=bar)
    assert [f.name for f in files] == [f"walk_{i:04d}.ply" for i in range(4)]
    assert _x_centres(tmp_path) == {**{f.name: 5.15 for f in files}, "walk_notes.txt": None}


def test_a_failed_frame_write_leaves_no_truncated_frame(bar, tmp_path, monkeypatch):
    # the mesh was written straight to its frame's name: a write that failed part-way (a file
    # size limit, a full disk) left a truncated frame that still loaded
    export_trajectory(_frames(bar, 3), tmp_path / "walk.obj", robot=bar)
    earlier = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    _export_failing_at(monkeypatch, 2, OSError(errno.EFBIG, "File too large"))
    with pytest.raises(OSError, match="File too large"):
        export_trajectory(_frames(bar, 3, shift=1.0), tmp_path / "walk.obj", robot=bar)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == earlier
    fresh = tmp_path / "fresh"
    _export_failing_at(monkeypatch, 2, OSError(errno.ENOSPC, "No space left on device"))
    with pytest.raises(OSError, match="No space left"):
        export_trajectory(_frames(bar, 3), fresh / "walk.obj", robot=bar)
    assert os.listdir(fresh) == []


def test_a_re_export_interrupted_while_publishing_is_one_runs_frames(bar, tmp_path,
                                                                     monkeypatch):  # fmt: skip
    export_trajectory(_frames(bar, 6), tmp_path / "walk.ply", robot=bar)
    before = _x_centres(tmp_path)
    replace = os.replace

    def interrupted_at(k):
        calls = {"n": 0}

        def replacing(src, dst):
            calls["n"] += 1
            if calls["n"] == k:
                raise KeyboardInterrupt
            return replace(src, dst)

        return replacing

    # while the earlier frames are set aside (6 renames): they are put back
    monkeypatch.setattr(export.os, "replace", interrupted_at(3))
    with pytest.raises(KeyboardInterrupt):
        export_trajectory(_frames(bar, 4, shift=5.0), tmp_path / "walk.ply", robot=bar)
    assert _x_centres(tmp_path) == before
    # once a new frame is in, the rest follow: all four new frames, nothing of the earlier six
    monkeypatch.setattr(export.os, "replace", interrupted_at(8))
    with pytest.raises(KeyboardInterrupt):
        export_trajectory(_frames(bar, 4, shift=5.0), tmp_path / "walk.ply", robot=bar)
    assert _x_centres(tmp_path) == {f"walk_{i:04d}.ply": 5.15 for i in range(4)}


def test_a_frame_name_taken_by_a_folder_is_refused_before_writing(bar, tmp_path):
    (tmp_path / "walk_0001.ply").mkdir()
    with pytest.raises(ValueError, match=r"walk_0001.ply' is a folder"):
        export_trajectory(_frames(bar, 3), tmp_path / "walk.ply", robot=bar)
    assert os.listdir(tmp_path) == ["walk_0001.ply"]


def test_glb_frames_are_y_up_and_the_others_the_simulators_z_up(bar, tmp_path):
    # glTF is +Y up by its specification: the simulator's Z-up vertices, stored as they were,
    # showed the robot on its edge in a glTF viewer
    lifted = bar.nodes + np.array([0.0, 0.0, 0.5])
    (glb,) = export_trajectory([lifted], tmp_path / "walk.glb", robot=bar)
    (ply,) = export_trajectory([lifted], tmp_path / "walk.ply", robot=bar)
    z_up = trimesh.load(ply, process=False).vertices
    assert z_up[:, 2].min() == pytest.approx(0.5)  # .ply as simulated
    y_up = trimesh.load(glb, force="mesh", process=False).vertices
    assert y_up[:, 1].min() == pytest.approx(0.5)  # the height on glTF's +Y
    np.testing.assert_allclose(np.sort(y_up, axis=0),
                               np.sort(np.c_[z_up[:, 0], z_up[:, 2], -z_up[:, 1]], axis=0),
                               atol=1e-6)  # fmt: skip
    raw = glb.read_bytes()  # no node transform that a viewer would apply on top
    length = struct.unpack("<I", raw[12:16])[0]
    nodes = json.loads(raw[20 : 20 + length])["nodes"]
    assert all("matrix" not in n and "rotation" not in n for n in nodes)
    # the faces still wind outward: a closed surface of positive volume
    assert trimesh.load(glb, force="mesh").volume > 0
