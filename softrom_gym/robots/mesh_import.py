"""Tetrahedral robots from any watertight surface mesh (STL, OBJ, PLY, ... via trimesh)."""

from __future__ import annotations

import os
import warnings
from fractions import Fraction
from typing import TYPE_CHECKING

import numpy as np

from .._validate import integer, real
from .robot import Robot
from .voxel import check_grid, largest_component, voxels_to_tets

if TYPE_CHECKING:
    import trimesh

__all__ = ["from_mesh"]


def _load(
    mesh: str | os.PathLike | trimesh.Trimesh | trimesh.Scene,
) -> tuple[trimesh.Trimesh, str]:
    import trimesh  # imported on use: it costs about a second at start-up

    if isinstance(mesh, trimesh.Trimesh):
        return mesh, "mesh"
    if isinstance(mesh, trimesh.Scene):
        # what trimesh.load gives for a .glb or a multi-object .obj: its geometry placed by
        # the scene's transforms and concatenated, as loading the file with force="mesh" does
        merged = mesh.to_mesh()
        if len(merged.faces) == 0:
            raise ValueError("the trimesh.Scene holds no triangle mesh")
        return merged, "mesh"
    if isinstance(mesh, (str, os.PathLike)):
        path = os.path.expanduser(os.fspath(mesh))
        if not os.path.exists(path):
            raise FileNotFoundError(f"mesh file {path!r} does not exist")
        if os.path.isdir(path):
            raise ValueError(f"{path!r} is a directory, not a mesh file")
        try:
            loaded = trimesh.load(path, force="mesh")
        except NotImplementedError:  # trimesh's word for a format it has no loader for
            raise ValueError(
                f"cannot read {path!r} as a mesh: use a surface format trimesh reads "
                "(.stl, .obj, .ply, .off, .glb, ...)"
            ) from None
        except OSError:
            raise  # (it names the file: permission denied, ...)
        except Exception as exc:
            # A malformed file fails inside trimesh's parsers with whatever they raise
            # (KeyError 'y', IndexError, "Not a ply file!", a JSONDecodeError), naming no file.
            raise ValueError(
                f"cannot read {path!r} as a mesh (the file is malformed?): "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
            raise ValueError(f"{path!r} holds no triangle mesh")
        return loaded, os.path.splitext(os.path.basename(path))[0]
    raise TypeError(
        f"mesh must be a file path, a trimesh.Trimesh or a trimesh.Scene, got {type(mesh).__name__}"
    )


# trimesh's ray test counts a hit up to 1e-6 (in the mesh's units) behind a ray's start, so
# within about that of the surface its answer is its own: centres that near are left to it.
_NEAR = 1e-6
# A bound on the rounding of _orient's determinant per unit of its two products' magnitudes
# (Shewchuk's orient2d bound is 3 eps + 16 eps**2; this leaves room to spare).
_ORIENT_ERR = 8 * float(np.finfo(np.float64).eps)


def _orient(
    ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray, px: np.ndarray, py: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which side of the line from a to b the point p lies on, in the xy-plane, exactly.

    Returns
    -------
    sign : (n,) int8
        +1 left of a -> b, -1 right. A point on the line is taken as (px + e, py + e**2) for
        an infinitesimal e > 0 (simulation of simplicity): that puts it strictly on one side
        of every line through two distinct points, and on the same side whichever triangle
        the edge is read from. 0 only where a and b coincide in xy.
    det : (n,) float
        Twice the signed area of (a, b, p), correctly rounded where it was computed exactly.
    err : (n,) float
        A bound on the rounding of ``det``.
    """
    left = (ax - px) * (by - py)
    right = (ay - py) * (bx - px)
    det = left - right
    err = _ORIENT_ERR * (np.abs(left) + np.abs(right))
    sign = np.sign(det).astype(np.int8)
    # Where the rounding could flip the sign, two triangles sharing an edge could both count a
    # column that passes along it, or neither: those (and any near underflow) are exact.
    unsure = np.flatnonzero(~(np.abs(det) > err) | (np.abs(det) < 1e-280))
    if unsure.size:
        coords = (v[unsure].tolist() for v in (ax, ay, bx, by, px, py))
        exact = [
            (Fraction(x0) - Fraction(x2)) * (Fraction(y1) - Fraction(y2))
            - (Fraction(y0) - Fraction(y2)) * (Fraction(x1) - Fraction(x2))
            for x0, y0, x1, y1, x2, y2 in zip(*coords, strict=True)
        ]
        sign[unsure] = [(e > 0) - (e < 0) for e in exact]
        det[unsure] = [float(e) for e in exact]
        err[unsure] = np.abs(det[unsure]) * np.finfo(np.float64).eps
    on_line = np.flatnonzero(sign == 0)
    if on_line.size:
        # det + e (ay - by) + e**2 (bx - ax) for the moved point: the first non-zero term
        tie = np.sign(ay[on_line] - by[on_line])
        tie = np.where(tie != 0, tie, np.sign(bx[on_line] - ax[on_line]))
        sign[on_line] = tie
    return sign, det, err


def _inside(surface: trimesh.Trimesh, axes: list[np.ndarray]) -> np.ndarray:
    """Which centres of a voxel grid lie inside a closed surface: what
    ``surface.contains`` gives for them, in a fraction of the time.

    ``contains`` casts two rays from each point and intersects them with the triangles near
    their paths: a minute for a 20k-face mesh at resolution 20. Here one vertical line per
    (x, y) column of centres is intersected with the triangles whose footprint holds it, and
    a centre is inside when an odd number of crossings lie below it (ray parity, as there).
    The footprint test is exact, with ties (a line along an edge or through a vertex) broken
    consistently, so each crossing is counted once. The centres a crossing's rounding could
    put on either side, and those within ``_NEAR`` of the surface, where the two ray tests
    need not agree (on it, ``contains`` itself is undefined), are given ``contains``'s own
    answer.

    Parameters
    ----------
    surface : trimesh.Trimesh
        A closed surface (each edge shared by two faces; winding is not used).
    axes : list of three (n_a,) float arrays
        The centres' coordinates along x, y and z, ascending.

    Returns
    -------
    (n_x, n_y, n_z) bool
    """
    xs, ys, zs = (np.asarray(a, dtype=np.float64) for a in axes)
    shape = (len(xs), len(ys), len(zs))
    tri = np.asarray(surface.triangles, dtype=np.float64)  # (T, 3, 3)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    # The columns within _NEAR of each face's footprint, as index ranges along x and y
    i0 = np.searchsorted(xs, lo[:, 0] - _NEAR, side="left")
    i1 = np.searchsorted(xs, hi[:, 0] + _NEAR, side="right")
    j0 = np.searchsorted(ys, lo[:, 1] - _NEAR, side="left")
    j1 = np.searchsorted(ys, hi[:, 1] + _NEAR, side="right")
    nj = j1 - j0
    per_face = (i1 - i0) * nj
    face = np.repeat(np.arange(len(tri)), per_face)
    rank = np.arange(len(face)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    col_i = i0[face] + rank // nj[face]
    col_j = j0[face] + rank % nj[face]
    column = col_i * shape[1] + col_j
    a, b, c = (tri[face, v] for v in range(3))
    px, py = xs[col_i], ys[col_j]
    # Each edge's side of the column, and twice the area of the triangle it makes with it:
    # the weight of the vertex opposite, for the height where the column crosses the face.
    s_ab, w_c, e_c = _orient(a[:, 0], a[:, 1], b[:, 0], b[:, 1], px, py)
    s_bc, w_a, e_a = _orient(b[:, 0], b[:, 1], c[:, 0], c[:, 1], px, py)
    s_ca, w_b, e_b = _orient(c[:, 0], c[:, 1], a[:, 0], a[:, 1], px, py)
    crosses = (s_ab == s_bc) & (s_bc == s_ca) & (s_ab != 0)

    # Faces within _NEAR of the column (of an edge's line, or a footprint that is a point)
    def off_line(w: np.ndarray, err: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        length = np.hypot(q[:, 0] - p[:, 0], q[:, 1] - p[:, 1])
        return (np.abs(w) > _NEAR * length * (1 + 1e-9) + err) | (length == 0)

    far = off_line(w_c, e_c, a, b) & off_line(w_a, e_a, b, c) & off_line(w_b, e_b, c, a)
    point = (a[:, :2] == b[:, :2]).all(axis=1) & (b[:, :2] == c[:, :2]).all(axis=1)
    seen = np.flatnonzero(crosses | ~far | point)

    # The height of each such face's plane over the column: the weights' mean of its
    # corners' heights (inside the footprint, where it crosses the face)
    w = np.stack([w_a[seen], w_b[seen], w_c[seen]], axis=1)
    w_err = e_a[seen] + e_b[seen] + e_c[seen]
    total = w.sum(axis=1)
    spread = np.abs(w).sum(axis=1)  # = |total| inside the footprint
    heights = np.stack([a[seen, 2], b[seen, 2], c[seen, 2]], axis=1)
    z_lo, z_hi = heights.min(axis=1), heights.max(axis=1)
    mid, half = 0.5 * (z_lo + z_hi), 0.5 * (z_hi - z_lo)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        z_plane = mid + ((heights - mid[:, None]) * w).sum(axis=1) / total
        # A bound on its rounding, from the weights' (w_err) and then the sums' (to first
        # order, twice over); unbounded where the footprint's area is all rounding.
        slack = np.abs(total) - w_err
        z_err = 2 * w_err * half * (1 + spread / slack) / slack
        z_err += 16 * np.finfo(np.float64).eps * (np.abs(mid) + half * (1 + spread / slack))
        z_err[~(slack > 0)] = np.inf
        # The centres within _NEAR of the face over a _NEAR-wide disc about the column lie
        # within (1 + slope) _NEAR <= 1.5 |normal| / |normal_z| _NEAR of that height.
        normal = np.cross(b[seen] - a[seen], c[seen] - a[seen])
        steep = np.linalg.norm(normal, axis=1) / np.abs(normal[:, 2])
        reach = z_err + 1.5 * _NEAR * steep
    z_plane = np.where(np.isfinite(z_plane), z_plane, mid)
    reach = np.where(np.isfinite(reach), reach, np.inf)  # (-inf, +inf): the face's heights
    d_lo = np.maximum(z_plane - reach, z_lo - _NEAR)
    d_hi = np.minimum(z_plane + reach, z_hi + _NEAR)
    # Where the column crosses the face: the plane's height, in the corners' range as the
    # exact one is (it is in doubt where rounding moved it)
    hit = crosses[seen]
    z_hit = np.clip(z_plane[hit], z_lo[hit], z_hi[hit])
    hit_col = column[seen[hit]]

    # Crossings below each centre, counted up its column
    n_col, n_z = shape[0] * shape[1], shape[2]
    above = np.searchsorted(zs, z_hit, side="right")  # the first centre above the crossing
    count = np.bincount(hit_col * (n_z + 1) + above, minlength=n_col * (n_z + 1))
    inside = (np.cumsum(count.reshape(n_col, n_z + 1), axis=1)[:, :n_z] % 2).astype(bool)

    # Centres in doubt, also counted up their columns (+1 where a window opens, -1 after)
    d_col = column[seen]
    start = np.searchsorted(zs, d_lo, side="left")
    stop = np.searchsorted(zs, d_hi, side="right")
    keep = stop > start
    marks = np.bincount(d_col[keep] * (n_z + 1) + start[keep], minlength=n_col * (n_z + 1))
    marks -= np.bincount(d_col[keep] * (n_z + 1) + stop[keep], minlength=n_col * (n_z + 1))
    doubt = np.cumsum(marks.reshape(n_col, n_z + 1), axis=1)[:, :n_z] > 0
    inside = inside.reshape(shape)
    doubt = doubt.reshape(shape)
    if doubt.any():
        ix, iy, iz = np.nonzero(doubt)
        inside[ix, iy, iz] = surface.contains(np.stack([xs[ix], ys[iy], zs[iz]], axis=1))
    return inside


def _solid_bodies(surface: trimesh.Trimesh, axes: list[np.ndarray]) -> int:
    """The number of closed shells enclosing material (a shell facing inwards, a cavity, is
    not one). Refuses shells that overlap: where they do, the surface's ray test is undefined
    (it gave another robot on each call), and a cavity that reaches outside every solid.
    Both are tested where they matter, at the voxel centres: the shells' winding number (+1
    inside an outward shell, -1 inside a cavity) exceeds 1 only inside two solids at once,
    not in a solid nested in a cavity, and is below 0 only in a cavity outside any solid."""
    shells = surface.split(only_watertight=False)
    with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by the volume
        volumes = [float(s.volume) for s in shells]
    solids = int(sum(v > 0 for v in volumes))
    if len(shells) < 2:
        return max(1, solids)
    boxes = np.array([s.bounds for s in shells])  # (S, 2, 3)
    meets = np.all(
        (boxes[:, None, 0] < boxes[None, :, 1]) & (boxes[None, :, 0] < boxes[:, None, 1]), axis=-1
    )
    np.fill_diagonal(meets, False)
    winding = np.zeros([len(a) for a in axes], dtype=int)
    # Shells alone in their box cannot overlap; a cavity is tested even alone, as it must lie
    # inside a solid.
    for k in np.flatnonzero(meets.any(axis=1) | (np.array(volumes) < 0)):
        # the centres in the shell's box (a block of the grid: the axes ascend)
        lo, hi = boxes[k]
        span = [np.flatnonzero((a >= lo[d]) & (a <= hi[d])) for d, a in enumerate(axes)]
        if all(s.size for s in span):
            block = tuple(slice(s[0], s[-1] + 1) for s in span)
            inside = _inside(shells[k], [a[s] for a, s in zip(axes, block, strict=True)])
            winding[block][inside] += 1 if volumes[k] > 0 else -1
    if winding.max(initial=0) > 1:
        raise ValueError(
            f"the mesh has {solids} closed shells, and some overlap (a voxel centre lies inside "
            "two of them): inside-outside is undefined there, so union them into one watertight "
            "surface first (e.g. in Blender, or trimesh.boolean.union with the manifold3d engine)"
        )
    if winding.min(initial=0) < 0:
        # Inside an inward shell but no solid: it is not a cavity but a solid with its faces
        # flipped (or a cavity poking out), and the ray test would hollow or cut it there.
        raise ValueError(
            "a shell wound inwards (a cavity) reaches outside every solid shell (a voxel centre "
            "lies inside it and in no solid): flip its faces if it is a solid "
            "(trimesh.Trimesh.invert on that shell), or keep a cavity inside its solid"
        )
    return max(1, solids)


def _enclosed_volume(surface: trimesh.Trimesh) -> float | None:
    """The volume a closed surface encloses, or None where its winding cannot tell it.

    A face wound against its neighbours makes trimesh's signed volume wrong (one flipped
    face of a box halved it); the voxels, filled by ray parity, do not depend on winding. One
    shell is rewound to agree with itself; several are left alone, as which of them are
    cavities is then unknown.
    """
    import trimesh

    if not surface.is_winding_consistent:
        surface = surface.copy()
        trimesh.repair.fix_winding(surface)
        if len(surface.split(only_watertight=False)) != 1:
            return None
    with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by the volume
        return abs(float(surface.volume))


def from_mesh(
    mesh: str | os.PathLike | trimesh.Trimesh | trimesh.Scene,
    resolution: int = 20,
    *,
    scale: float = 1.0,
    name: str | None = None,
    **material: float,
) -> Robot:
    """Turn a watertight surface mesh into a conforming tetrahedral :class:`Robot`.

    The mesh is voxelised on a grid of ``resolution`` voxels along its longest side; a voxel
    is filled when its centre is inside the surface (by ray parity, as
    ``trimesh.Trimesh.contains`` tells it, but with one ray per column of voxels: seconds
    for a 100k-face scan), which keeps the volume unbiased. Filled voxels are split into six
    tetrahedra each, and only the largest face-connected piece is kept. The result rests on
    z = 0, centred on the z axis.

    Parameters
    ----------
    mesh : path, trimesh.Trimesh or trimesh.Scene
        A closed (watertight) surface; units are metres after ``scale``. A scene (what
        ``trimesh.load`` gives for a .glb) is its geometry concatenated, as its file is.
    resolution : int
        Voxels along the longest side of the bounding box (>= 2).
    scale : float
        Multiplies the mesh's coordinates (e.g. 0.001 for a model in millimetres).
    name : str, optional
        Robot name (default: the file's stem, or ``"mesh"``).
    **material
        ``youngs_modulus``, ``poisson_ratio``, ``density`` overrides.

    Raises
    ------
    ValueError
        If the mesh is not watertight, has closed shells that overlap (not unioned) or a
        shell wound inwards outside every solid (flipped faces), or the resolution is too
        coarse to fill any voxel, or so fine that the grid has more than
        :data:`~softrom_gym.robots.voxel.MAX_GRID_CELLS` voxels.

    Warns when the robot is shorter than 5 mm or longer than 5 m (a model in millimetres read
    as metres), when separate bodies are dropped or joined, and when the robot's volume is
    off the mesh's by more than half again (parts thinner than a voxel: raise resolution).
    """

    surface, default_name = _load(mesh)
    integer("resolution", resolution)
    if resolution < 2:
        raise ValueError(f"resolution must be >= 2 voxels along the longest side, got {resolution}")
    scale = real("scale", scale)
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be > 0, got {scale}")
    if not np.isfinite(surface.vertices).all():
        bad = int((~np.isfinite(surface.vertices).all(axis=1)).sum())
        raise ValueError(f"the mesh has {bad} vertices with non-finite coordinates (NaN or inf)")
    if not surface.is_watertight:
        # A triangle soup (each face its own three vertices, as a Trimesh made with
        # process=False from an STL has) closes once coincident vertices are merged, and
        # zero-area triangles carry no geometry but can leave an edge count odd: without
        # either the surface may close, nor a face listed twice (its edges then count 3 or
        # 4). (One that is closed only with a sliver keeps it.)
        cleaned = surface.copy()
        cleaned.merge_vertices()
        cleaned.update_faces(cleaned.nondegenerate_faces())
        cleaned.update_faces(cleaned.unique_faces())
        cleaned.remove_unreferenced_vertices()
        if cleaned.is_watertight:
            surface = cleaned
    if not surface.is_watertight:
        _, uses = np.unique(surface.edges_sorted, axis=0, return_counts=True)
        if (uses == 1).any():
            why = f"{int((uses == 1).sum())} boundary edges"
            fix = "repair it first (e.g. trimesh.repair.fill_holes)"
        else:  # closed, but not a manifold: fill_holes finds no hole to fill
            why = (f"{int((uses > 2).sum())} edges shared by more than two faces: bodies "
                   "touching along an edge, or faces crossing one another")  # fmt: skip
            fix = "separate or union the bodies first (e.g. in Blender)"
        raise ValueError(
            f"mesh is not watertight ({why}): from_mesh needs a closed surface to tell inside "
            f"from outside; {fix}"
        )
    with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by the volume
        inside_out = surface.is_winding_consistent and float(surface.volume) < 0
    if inside_out:
        # Faces wound inwards (a mirrored export): the ray test fills the same voxels, but
        # _solid_bodies reads each shell as a cavity, so overlapping shells were not refused
        # (and were hollowed where they overlap). The solid the surface bounds is meant.
        surface = surface.copy()
        surface.invert()
    unknown = set(material) - {"youngs_modulus", "poisson_ratio", "density"}
    if unknown:
        raise TypeError(f"unknown material parameter(s) {sorted(unknown)}")
    length = float(np.ptp(surface.bounds, axis=0).max()) * scale
    if not 0.005 <= length <= 5.0:
        warnings.warn(
            f"the robot is {length:.3g} m long: units are metres after scale (a model in "
            "millimetres needs scale=0.001)",
            stacklevel=2,
        )

    lo, hi = surface.bounds
    pitch = float((hi - lo).max()) / int(resolution)
    counts = np.maximum(np.round((hi - lo) / pitch), 1)  # (float: int64 wraps at 1e19)
    check_grid(resolution, counts)
    counts = counts.astype(int)
    # Centre the grid on the mesh so the voxelisation is symmetric for symmetric shapes.
    origin = 0.5 * (lo + hi) - 0.5 * pitch * counts
    axes = [origin[a] + pitch * (np.arange(counts[a]) + 0.5) for a in range(3)]
    bodies = _solid_bodies(surface, axes)
    occ = _inside(surface, axes)
    if not occ.any():
        with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by the volume
            volume = abs(float(surface.volume))
        if not volume > 1e-9 * float((hi - lo).max()) ** 3:
            raise ValueError(
                f"the mesh encloses no volume ({volume:.3g}): it is closed but flat or folded "
                "onto itself, so no voxel lies inside it"
            )
        raise ValueError(
            f"resolution {resolution} is too coarse: no voxel centre falls inside the mesh"
        )
    kept = largest_component(occ)
    dropped = int(occ.sum() - kept.sum())
    if dropped:
        why = (f"the mesh has {bodies} separate bodies" if bodies > 1
               else "raise resolution to keep thin parts")  # fmt: skip
        warnings.warn(
            f"from_mesh kept the largest connected piece and dropped {dropped} of "
            f"{int(occ.sum())} voxels: {why}",
            stacklevel=2,
        )
    elif bodies > 1:
        warnings.warn(
            f"the mesh has {bodies} separate bodies but its voxels form one piece: bodies "
            f"closer together than a voxel ({pitch * scale:.3g} m) were joined, or one too "
            "thin to fill a voxel was left out; raise resolution to keep them apart (the "
            "largest is then kept)",
            stacklevel=2,
        )
    else:
        # A part thinner than half a voxel still fills a whole one (a 1 mm plate made a 5 mm
        # slab at the default resolution, five times the mass) or none: say so, by the volume.
        enclosed = _enclosed_volume(surface)
        ratio = float(kept.sum()) * pitch**3 / enclosed if enclosed else 1.0
        if not 1 / 1.5 <= ratio <= 1.5:
            warnings.warn(
                f"the robot has {ratio:.3g} times the mesh's volume (and mass): at resolution "
                f"{resolution} a voxel is {pitch * scale:.3g} m wide, too coarse for the mesh's "
                "thinnest parts, which fill a whole voxel or none; raise resolution",
                stacklevel=2,
            )
    nodes, tets = voxels_to_tets(kept, pitch * scale, origin * scale)
    nodes[:, :2] -= 0.5 * (nodes[:, :2].min(axis=0) + nodes[:, :2].max(axis=0))
    nodes[:, 2] -= nodes[:, 2].min()
    meta = {"resolution": int(resolution), "pitch": pitch * scale}
    return Robot(name or default_name, nodes, tets, metadata=meta, **material)
