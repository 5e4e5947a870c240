"""Tetrahedral robots from any watertight surface mesh (STL, OBJ, PLY, ... via trimesh)."""

from __future__ import annotations

import os
import warnings
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


def _solid_bodies(surface: trimesh.Trimesh, centres: np.ndarray) -> int:
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
    winding = np.zeros(len(centres), dtype=int)
    # Shells alone in their box cannot overlap; a cavity is tested even alone, as it must lie
    # inside a solid.
    for k in np.flatnonzero(meets.any(axis=1) | (np.array(volumes) < 0)):
        lo, hi = boxes[k]
        near = np.flatnonzero(np.all((centres >= lo) & (centres <= hi), axis=1))
        if near.size:
            inside = shells[k].contains(centres[near])
            winding[near[inside]] += 1 if volumes[k] > 0 else -1
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
    is filled when its centre is inside the surface (``trimesh.Trimesh.contains``), which
    keeps the volume unbiased. Filled voxels are split into six tetrahedra each, and only the
    largest face-connected piece is kept. The result rests on z = 0, centred on the z axis.

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
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    bodies = _solid_bodies(surface, centres)
    occ = surface.contains(centres).reshape(counts)
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
