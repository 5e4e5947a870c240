"""Conforming tetrahedral meshes from voxel occupancy grids.

Each filled voxel is split into six tetrahedra around its main diagonal (the Kuhn /
Freudenthal split). Every voxel uses the same diagonal direction, so the face diagonals of
neighbouring voxels agree and the mesh is conforming without parity bookkeeping.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy import ndimage

from .._validate import real, real_array

__all__ = ["MAX_GRID_CELLS", "boundary_faces", "check_grid", "largest_component", "voxels_to_tets"]

MAX_GRID_CELLS = 1_000_000  # voxels in a robot's grid: resolution 100 for a cube

# Corner offsets (i, j, k) of the unit cube, corner c has bits (c & 1, c >> 1 & 1, c >> 2 & 1).
_CORNERS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=np.int64)


def _kuhn_tets() -> np.ndarray:
    """The six tetrahedra (as corner ids) along the 0 -> 7 diagonal, positively oriented."""
    tets = []
    for perm in itertools.permutations(range(3)):
        path = [0]
        for axis in perm:
            path.append(path[-1] | (1 << axis))
        p = _CORNERS[path].astype(float)
        if np.linalg.det(p[1:] - p[0]) < 0:
            path[1], path[2] = path[2], path[1]
        tets.append(path)
    return np.array(tets, dtype=np.int64)


_KUHN = _kuhn_tets()


def check_grid(resolution: int, counts: np.ndarray) -> None:
    """Refuse a voxel grid of more than :data:`MAX_GRID_CELLS` cells, naming ``resolution``.

    Parameters
    ----------
    resolution : int
        Voxels along the longest side, as the caller was given it.
    counts : (3,) array
        The grid's voxels along x, y and z (whole numbers; float before a cast to int64,
        which would wrap for an absurd resolution).

    Raises
    ------
    ValueError
        Naming the grid and the largest resolution that fits.
    """
    sides = [int(c) for c in counts]
    cells = int(np.prod(sides, dtype=object))  # (exact: int64 wraps at resolution ~ 2e6)
    if cells > MAX_GRID_CELLS:
        # Sampling the grid takes seconds to minutes, and the robot's reduced basis hours:
        # refuse before either (resolution 10^6 asked numpy for an exabyte and died in a
        # MemoryError naming no argument).
        fits = int(resolution * (MAX_GRID_CELLS / cells) ** (1 / 3))
        raise ValueError(
            f"resolution {resolution} makes a grid of {' x '.join(map(str, sides))} = "
            f"{cells:,} voxels, over the {MAX_GRID_CELLS:,} a robot is meshed from (up to "
            f"~{MAX_GRID_CELLS:,} nodes); use resolution <= {fits} (20 is the default)"
        )


def largest_component(occupancy: np.ndarray) -> np.ndarray:
    """Keep only the largest face-connected component of a boolean voxel grid."""
    labels, count = ndimage.label(occupancy)
    if count <= 1:
        return occupancy.astype(bool)
    sizes = np.bincount(labels.ravel())[1:]
    return labels == (1 + int(np.argmax(sizes)))


def voxels_to_tets(
    occupancy: np.ndarray, pitch: float, origin: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedralise a boolean voxel grid.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool array
        Voxel (i, j, k) spans ``origin + pitch * [i, i+1] x [j, j+1] x [k, k+1]``.
    pitch : float
        Voxel edge length in metres.
    origin : (3,) array, optional
        Position of the grid's corner (default zero).

    Returns
    -------
    nodes : (N, 3) float64
        Only the voxel corners that a filled voxel uses.
    tets : (6 V, 4) int64
        Positively oriented tetrahedra.
    """
    occ = np.asarray(occupancy, dtype=bool)
    if occ.ndim != 3:
        raise ValueError(f"occupancy must be a 3-D array, got shape {occ.shape}")
    if not occ.any():
        raise ValueError("occupancy grid is empty: no voxel is filled")
    pitch = real("pitch", pitch)  # a string was numpy's "ufunc 'isfinite' not supported"
    if not (np.isfinite(pitch) and pitch > 0):
        raise ValueError(f"pitch must be > 0, got {pitch}")
    # A NaN origin gave NaN nodes, one of 2 numbers a broadcasting error.
    origin = np.zeros(3) if origin is None else real_array("origin", origin)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"origin must be 3 finite numbers (m), got {origin.tolist()}")
    vox = np.argwhere(occ)  # (V, 3)
    shape = np.array(occ.shape) + 1
    corner_ijk = vox[:, None, :] + _CORNERS[None, :, :]  # (V, 8, 3)
    corner_id = np.ravel_multi_index(corner_ijk.reshape(-1, 3).T, shape).reshape(-1, 8)
    used, inverse = np.unique(corner_id, return_inverse=True)
    inverse = inverse.reshape(-1, 8)
    nodes = origin + pitch * np.column_stack(np.unravel_index(used, shape)).astype(float)
    tets = inverse[:, _KUHN].reshape(-1, 4)
    return nodes, tets


def boundary_faces(tets: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Triangles that belong to exactly one tetrahedron, wound with outward normals."""
    tets = np.asarray(tets)
    # Face a is opposite vertex a; these orderings point outward for a positive tet.
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, local].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, idx, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    out = faces[idx[counts == 1]]
    # Orientation check relative to the opposite vertex, in case of a caller's odd ordering.
    opp = tets[:, [0, 1, 2, 3]].reshape(-1)[idx[counts == 1]]
    p = nodes[out]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    inward = np.einsum("ij,ij->i", normal, nodes[opp] - p[:, 0]) > 0
    out[inward] = out[inward][:, [0, 2, 1]]
    return out
