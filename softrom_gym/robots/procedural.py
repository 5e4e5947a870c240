"""The four benchmark robots of the paper's Table I, generated procedurally.

Each shape is a union of axis-aligned boxes in metres (the tripod's body a triangular slab on
three boxes), sampled on a voxel grid whose pitch is
``longest side / resolution`` and tetrahedralised by :func:`voxels_to_tets`. Default
resolutions give node counts within 11% of Table I (cross 555 vs 623, beam 460 vs 426,
quadruped 1412 vs 1315, tripod 1434 vs 1417). Every robot rests on z = 0, centred on the z axis.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .._validate import integer
from .robot import Robot
from .voxel import check_grid, largest_component, voxels_to_tets

__all__ = ["beam", "cross", "quadruped", "tripod"]

Box = tuple[tuple[float, float, float], tuple[float, float, float]]


def _check_resolution(resolution: int) -> int:
    integer("resolution", resolution)
    if resolution < 2:
        raise ValueError(f"resolution must be >= 2 voxels along the longest side, got {resolution}")
    return int(resolution)


def _from_boxes(name: str, boxes: Sequence[Box], resolution: int, **material: float) -> Robot:
    def inside(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        occ = np.zeros(x.shape, dtype=bool)
        for b_lo, b_hi in boxes:
            occ |= (
                (x > b_lo[0]) & (x < b_hi[0])
                & (y > b_lo[1]) & (y < b_hi[1])
                & (z > b_lo[2]) & (z < b_hi[2])
            )  # fmt: skip
        return occ

    lo = tuple(np.min([b[0] for b in boxes], axis=0))
    hi = tuple(np.max([b[1] for b in boxes], axis=0))
    return _from_function(name, inside, lo, hi, resolution, **material)


def _from_function(
    name: str,
    inside: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    lo: tuple[float, float, float],
    hi: tuple[float, float, float],
    resolution: int,
    **material: float,
) -> Robot:
    """Voxelise ``inside(x, y, z)`` (evaluated at voxel centres) over the box [lo, hi]."""
    lo_a, hi_a = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    pitch = float((hi_a - lo_a).max()) / _check_resolution(resolution)
    counts = np.maximum(np.round((hi_a - lo_a) / pitch), 1)  # (float: int64 wraps at 1e19)
    check_grid(resolution, counts)
    counts = counts.astype(int)
    centres = [lo_a[a] + pitch * (np.arange(counts[a]) + 0.5) for a in range(3)]
    occ = inside(*np.meshgrid(*centres, indexing="ij"))
    if not occ.any():
        raise ValueError(
            f"resolution {resolution} is too coarse for the {name}: no voxel centre falls "
            "inside the shape; use a larger resolution"
        )
    kept = largest_component(occ)
    if kept.sum() < occ.sum():
        # The shape is connected, so a split is the grid's doing: a part boundary on a layer
        # of voxel centres leaves that layer empty (a quadruped at resolution 10 lost its legs).
        raise ValueError(
            f"resolution {resolution} splits the {name} into pieces (a part's boundary falls on "
            f"a layer of voxel centres; the largest piece has {int(kept.sum())} of "
            f"{int(occ.sum())} voxels): use another resolution"
        )
    nodes, tets = voxels_to_tets(kept, pitch, lo_a)
    nodes[:, :2] -= 0.5 * (nodes[:, :2].min(axis=0) + nodes[:, :2].max(axis=0))
    nodes[:, 2] -= nodes[:, 2].min()
    meta = {"resolution": resolution, "pitch": pitch}
    return Robot(name, nodes, tets, metadata=meta, **material)


def cross(resolution: int = 20, **material: float) -> Robot:
    """A plus-shaped slab: four 0.4 m arms, 0.2 m wide, 0.1 m thick (1 m tip to tip).

    Swims by undulating its arms, walks by pushing them on the ground.
    """
    half, w, t = 0.5, 0.1, 0.1
    boxes = [((-half, -w, 0.0), (half, w, t)), ((-w, -half, 0.0), (w, half, t))]
    return _from_boxes("cross", boxes, resolution, **material)


def beam(resolution: int = 32, **material: float) -> Robot:
    """A 0.8 m bar, 0.075 m wide and 0.05 m thick, on two 0.075 m square feet 0.05 m tall.

    The feet lift the bar off the ground so it can inch-worm: bending the bar moves the feet
    apart and together.
    """
    length, width, thick, foot, foot_h = 0.8, 0.075, 0.05, 0.075, 0.05
    body = ((-length / 2, -width / 2, foot_h), (length / 2, width / 2, foot_h + thick))
    feet = [
        ((-length / 2, -width / 2, 0.0), (-length / 2 + foot, width / 2, foot_h)),
        ((length / 2 - foot, -width / 2, 0.0), (length / 2, width / 2, foot_h)),
    ]
    return _from_boxes("beam", [body, *feet], resolution, **material)


def quadruped(resolution: int = 20, **material: float) -> Robot:
    """A 0.6 x 0.36 x 0.09 m body on four 0.09 m square legs, 0.15 m tall."""
    bx, by, bt, leg, lh = 0.3, 0.18, 0.09, 0.09, 0.15
    body = ((-bx, -by, lh), (bx, by, lh + bt))
    legs = [
        ((-bx if sx < 0 else bx - leg, -by if sy < 0 else by - leg, 0.0),
         (-bx + leg if sx < 0 else bx, -by + leg if sy < 0 else by, lh))
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]  # fmt: skip
    return _from_boxes("quadruped", [body, *legs], resolution, **material)


def tripod(resolution: int = 20, **material: float) -> Robot:
    """An equilateral-triangle body (0.6 m sides, 0.12 m thick) on three 0.12 m square legs,
    0.15 m tall, one under each corner. The apex points along +x."""
    side, bt, leg, lh = 0.6, 0.12, 0.12, 0.15
    height = side * np.sqrt(3.0) / 2.0
    x0 = -height / 3.0  # centroid at the origin
    corners = np.array([[x0 + height, 0.0], [x0, -side / 2], [x0, side / 2]])

    def inside(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        in_body = (z > lh) & (z < lh + bt) & (x > x0)
        # The two slanted edges from the apex.
        in_body &= np.abs(y) < (x0 + height - x) / np.sqrt(3.0)
        in_legs = np.zeros_like(in_body)
        for c in corners:
            # Each leg sits inside its corner, pulled towards the centroid.
            lc = 0.72 * c
            in_legs |= (np.abs(x - lc[0]) < leg / 2) & (np.abs(y - lc[1]) < leg / 2) & (z < lh)
        return in_body | in_legs

    lo = (float(x0), -side / 2, 0.0)
    hi = (float(x0 + height), side / 2, lh + bt)
    return _from_function("tripod", inside, lo, hi, resolution, **material)
