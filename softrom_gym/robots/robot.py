"""The ``Robot`` container: a tetrahedral mesh and its default material."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from .._validate import real, real_array
from .voxel import boundary_faces

if TYPE_CHECKING:
    import trimesh

    import cpp_sim

__all__ = ["Robot"]


def _node_indices(tets: object) -> np.ndarray:
    """``tets`` as int64, refusing what is not a whole number (casting truncated 4.9 to 4)."""
    raw = np.asarray(tets)
    if raw.dtype.kind == "b":
        raise ValueError("tets must be node indices (integers), got a bool array")
    if raw.dtype.kind == "f":
        whole = np.isfinite(raw) & (raw == np.round(raw))
        if not whole.all():
            at = np.argwhere(~whole)[0]
            where = f" in tets[{at[0]}]" if raw.ndim == 2 else ""
            bad = float(raw[tuple(at)])
            raise ValueError(f"tets must be node indices (integers), got {bad!r}{where}")
    try:
        return np.ascontiguousarray(raw, dtype=np.int64)
    except (TypeError, ValueError):
        raise ValueError(f"tets must be node indices (integers), got {tets!r}") from None


@dataclass(frozen=True, eq=False)
class Robot:
    """A soft robot: rest mesh (metres, z up, resting on z = 0) and material.

    Named robots and :func:`~softrom_gym.robots.from_mesh` rest on z = 0; nodes given here
    are taken as they are, and a walking env refuses a robot whose lowest node is off it.

    Attributes
    ----------
    name : str
        Short name (``"cross"``, ``"beam"``, ..., or the mesh file's stem).
    nodes : (N, 3) float64 array
        Rest positions, m.
    tets : (T, 4) int64 array
        Positively oriented tetrahedra (node indices).
    youngs_modulus : float
        E, Pa.
    poisson_ratio : float
        nu.
    density : float
        rho, kg/m^3.
    """

    name: str
    nodes: np.ndarray
    tets: np.ndarray
    youngs_modulus: float = 5.0e4
    poisson_ratio: float = 0.3
    density: float = 1000.0
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        nodes = np.ascontiguousarray(real_array("nodes", self.nodes))
        tets = _node_indices(self.tets)
        if nodes.ndim != 2 or nodes.shape[1] != 3:
            raise ValueError(f"nodes has shape {nodes.shape}, expected (N, 3)")
        if not np.all(np.isfinite(nodes)):
            row = int(np.argwhere(~np.isfinite(nodes))[0][0])
            raise ValueError(f"nodes[{row}] = {nodes[row].tolist()} is not finite")
        if tets.ndim != 2 or tets.shape[1] != 4:
            raise ValueError(f"tets has shape {tets.shape}, expected (T, 4)")
        if len(tets) == 0:
            raise ValueError("a robot needs at least one tetrahedron, got none")
        # (here, not only in the C++ model: surface() and volume index nodes with them)
        outside = (tets < 0) | (tets >= len(nodes))
        if outside.any():
            t, k = (int(i) for i in np.argwhere(outside)[0])
            raise ValueError(f"tets[{t}] = {tets[t].tolist()} has node index {tets[t, k]} out "
                             f"of range [0, {len(nodes)})")  # fmt: skip
        # A tetrahedron wound the wrong way (or flat) made volume and mass negative (or NaN)
        # and the surface inside out; only fem_model() refused it, as the C++ model does.
        p = nodes[tets]
        vol = np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0
        if not np.all(vol > 0):
            t = int(np.flatnonzero(~(vol > 0))[0])
            raise ValueError(f"tets[{t}] = {tets[t].tolist()} has non-positive rest volume "
                             f"{vol[t]:.6g} (tetrahedra must be positively oriented and "
                             "non-degenerate)")  # fmt: skip
        # A tetrahedron listed twice (in any vertex order) counted its mass twice and hid its
        # faces from the surface (each appeared twice, as an inner face does): a review,
        # session 54, found the beam's mass 14.2 -> 16.2 kg and its surface no longer closed.
        _, first, counts = np.unique(np.sort(tets, axis=1), axis=0, return_index=True,
                                     return_counts=True)  # fmt: skip
        if (counts > 1).any():
            t = int(np.sort(first[counts > 1])[0])
            same = np.flatnonzero((np.sort(tets, axis=1) == np.sort(tets[t])).all(axis=1))
            raise ValueError(f"tets[{same[0]}] and tets[{same[1]}] are the same tetrahedron "
                             f"{tets[t].tolist()}: each element must be listed once")  # fmt: skip
        nodes.flags.writeable = False
        tets.flags.writeable = False
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "tets", tets)
        for name in ("youngs_modulus", "poisson_ratio", "density"):
            object.__setattr__(self, name, real(name, getattr(self, name)))
        for name in ("youngs_modulus", "density"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not -1.0 < self.poisson_ratio < 0.5:
            raise ValueError(f"poisson_ratio must lie in (-1, 0.5), got {self.poisson_ratio!r}")
        if self.poisson_ratio > 0.45:
            # linear tetrahedra lock near incompressibility (a textbook property of the
            # element, not of this code): the robot behaves stiffer than its material
            warnings.warn(
                f"poisson_ratio = {self.poisson_ratio:g}: linear tetrahedra lock as it "
                "approaches 0.5, so this robot bends and deforms stiffer than its material "
                "would (more so on a coarse mesh); use nu <= 0.45 or a finer mesh "
                "(resolution=)",
                stacklevel=3,
            )

    @property
    def num_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def num_tets(self) -> int:
        return int(self.tets.shape[0])

    @cached_property
    def surface_faces(self) -> np.ndarray:
        """(F, 3) boundary triangles, indices into ``nodes``, outward winding."""
        return boundary_faces(self.tets, self.nodes)

    @cached_property
    def surface_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes on the boundary (the contact candidates)."""
        return np.unique(self.surface_faces)

    @property
    def volume(self) -> float:
        """Rest volume, m^3."""
        p = self.nodes[self.tets]
        return float(np.linalg.det(p[:, 1:] - p[:, :1]).sum() / 6.0)

    @property
    def mass(self) -> float:
        """Total mass, kg."""
        return self.density * self.volume

    def surface(self, positions: np.ndarray | None = None) -> trimesh.Trimesh:
        """The boundary as a ``trimesh.Trimesh``.

        Vertices are all N nodes (at ``positions`` if given, else at rest) so that vertex i is
        node i; interior nodes are unreferenced.
        """
        import trimesh

        verts = self.nodes if positions is None else np.asarray(positions, dtype=float)
        if verts.shape != self.nodes.shape:
            raise ValueError(f"positions has shape {verts.shape}, expected {self.nodes.shape}")
        return trimesh.Trimesh(vertices=verts, faces=self.surface_faces, process=False)

    def fem_model(self, **material: float) -> cpp_sim.FEMModel:
        """A full-space ``cpp_sim.FEMModel`` of this robot; keyword arguments override the
        material (``youngs_modulus``, ``poisson_ratio``, ``density``)."""
        import cpp_sim

        unknown = set(material) - {"youngs_modulus", "poisson_ratio", "density"}
        if unknown:
            raise TypeError(f"unknown material parameter(s) {sorted(unknown)}")
        # real() names a string or bool override (pybind11's "incompatible constructor
        # arguments" listing did not); the C++ model checks the ranges.
        return cpp_sim.FEMModel(
            self.nodes,
            self.tets,
            real("youngs_modulus", material.get("youngs_modulus", self.youngs_modulus)),
            real("poisson_ratio", material.get("poisson_ratio", self.poisson_ratio)),
            real("density", material.get("density", self.density)),
        )

    def __repr__(self) -> str:
        return (
            f"Robot({self.name!r}, nodes={self.num_nodes}, tets={self.num_tets}, "
            f"E={self.youngs_modulus:g} Pa, nu={self.poisson_ratio:g}, rho={self.density:g})"
        )
